"""Procedurally generated pseudo-demonstrations (paper §3.3), the only training data of Instant Policy, on the objects
and renderer of :mod:`..objects`: pseudo-tasks and the ladder of task families (``tasks``), gripper trajectories with
disturbances (``trajectory``), replaying a task as demonstrations (``replay``), parallel generation into a LeRobotDataset (``generation``, ``merge``) and a picture of
the first tasks (``preview``)."""
