"""Geometry every layer shares: SE(3) maps in numpy (``se3``) and torch (``rigid_torch``), point sampling
(``sampling``), rigid registration (``registration``) and the gripper's keypoints (``gripper``)."""
