"""Measuring a trained policy offline on held-out pseudo-tasks: the action error against holding still with the
context-swap reference (``action_error``) and the diffusion loss per checkpoint against the prior-only level
(``loss_curve``). The ``lerobot-ip-action-error`` and ``lerobot-ip-loss-curve`` commands are their command lines."""
