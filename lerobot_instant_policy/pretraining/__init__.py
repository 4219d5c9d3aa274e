"""The geometry encoder's occupancy pretraining (paper §3.2): scenes and occupancy queries (``occupancy_data``), the
training loop (``encoder_pretraining``, ``lerobot-ip-pretrain-encoder``) and a picture of the learnt occupancy
(``occupancy_picture``)."""
