"""LeRobot's MetaWorld env with the data contract (``--env.type=metaworld_pointcloud``): point clouds from MuJoCo
depth and segmentation cameras, the Sawyer's EE pose, EE-target actions, and MetaWorld's scripted experts as
demonstrations.

Importing this package registers the LeRobot ``EnvConfig`` only (``configuration_metaworld``); MetaWorld, MuJoCo
and rendering load when envs are built (``env``, which needs the ``metaworld`` extra: ``dependencies``).
"""

from .configuration_metaworld import MetaworldPointCloudEnvConfig

__all__ = ["MetaworldPointCloudEnvConfig"]
