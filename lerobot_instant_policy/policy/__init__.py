"""What the LeRobot policy (``configuration_instant_policy``, ``modeling_instant_policy``) is built from besides the
network: its input and output features (``features``), the pre/post-processors' steps (``processors``), the optimizer
(``optimizer``), the frozen encoder's per-frame cache of a training dataset (``frame_encodings``), the demonstrations'
path to the network (``context_encoder``), and what training keeps beside it: the rolling pool of encoded fresh
tasks (``task_pool``) and the moving average of the trained weights (``weight_average``)."""
