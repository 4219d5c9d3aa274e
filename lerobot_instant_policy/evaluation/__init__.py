"""Measuring policies. Offline, on held-out pseudo-tasks: the action error against holding still with the
context-swap reference, with intervals over tasks and paired differences of two checkpoints (``action_error``), and
the diffusion loss per checkpoint against the prior-only level (``loss_curve``), on checkpoints found and loaded by
``checkpoints``. In ``bullet_tabletop`` and LeRobot's MetaWorld env: the suite protocol of demonstration sets,
evaluation seeds and the context swap through ``lerobot-eval`` (``suite``; what differs in MetaWorld in
``metaworld_suite``; the command line both envs' commands share in ``suite_command``; each episode's seed kept by
``lerobot_eval_seeds``), each column's record of its cells, seeds and conditions (``manifest``), its success tables
with cluster intervals over tasks and per-episode Wilson ones (``success_table``) and paired differences
(``paired``), every cluster interval drawn by one bootstrap (``bootstrap``), ``make demo`` (``demo``) with its
side-by-side episodes and contact sheet (``side_by_side``), and a policy's predictions drawn along a recorded episode
(``dry_run``). The ``lerobot-ip-*`` commands in ``cli/`` are their command lines."""
