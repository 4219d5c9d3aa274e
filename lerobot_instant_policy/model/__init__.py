"""Networks of Instant Policy: point operations, the geometry encoder and its occupancy pretraining head."""
