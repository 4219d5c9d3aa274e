"""Training loops and training measurements that join data and model: the geometry encoder's occupancy pretraining
and the instant_policy training curve (loss per checkpoint on training and held-out pseudo-tasks)."""
