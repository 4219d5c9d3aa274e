"""Training loops that join data and model: the geometry encoder's occupancy pretraining."""
