"""From depth cameras to the segmented world-frame point clouds of the data contract, without learned weights.

``calibration`` (camera intrinsics and extrinsics, checked), ``depth`` (back-projection, unit checks),
``segmentation`` (workspace box, table plane, gripper box), ``robot_model`` (URDF kinematics and link surfaces),
``steps`` (LeRobot ``ProcessorStep``s), ``pipeline`` (``PerceptionConfig`` → a processor pipeline), ``convert`` (a
recorded depth dataset → a dataset in the data contract, ``lerobot-ip-convert``), ``hand`` (a human hand's landmarks
→ the gripper's EE pose and state), ``hand_mask`` (the hand removed from the clouds).
"""
