"""Data in the project's contract (docs/design.md §4): LeRobotDataset reading and writing (``lerobot_format``),
demonstrations of a task (``demonstrations``), their reduction to waypoints (``waypoints``), the training context
bank (``context_bank``) and action chunks read from a dataset's action table (``action_chunks``)."""
