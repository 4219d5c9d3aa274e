"""Training: what ``lerobot-train`` needs of this package besides the policy's loss.

``stream_seam`` (LeRobot's training loop on the pseudo-task stream or the pool), ``task_pool`` (the rolling pool of
encoded fresh tasks, rendered by generator processes), ``weight_average`` (the moving average of the trained weights,
saved beside each checkpoint), ``optimizer`` (the ``instant_policy_adamw`` optimizer config), ``batches`` (a training
batch as the network's loss reads it: targets, the context's three sources, the replay priors), ``context_encoder``
(the one way from a context bank's waypoints to the network, which inference takes too), ``frame_encodings`` (the
frozen encoder's per-frame cache beside a training dataset), and the language head's ``language_targets`` and
``language_head_training``. It imports the model, data and pseudo-task rooms, never the policy.
"""
