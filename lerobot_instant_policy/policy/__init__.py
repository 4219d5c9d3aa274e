"""What the LeRobot policy (``configuration_instant_policy``, ``modeling_instant_policy``) is built from besides the
network and training (:mod:`..training`): its input and output features (``features``) and the pre/post-processors'
steps (``processors``)."""
