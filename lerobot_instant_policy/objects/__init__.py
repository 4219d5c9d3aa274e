"""The objects of the tabletop world and how a camera sees them: the mesh library with its train / held-out split
(``library``) and segmented point clouds rendered from simulated depth cameras (``rendering``). Pseudo-demonstrations,
the occupancy pretraining and the ``bullet_tabletop`` simulator all build on them."""
