"""Synthetic demonstrations for the demonstration-loader and ``demo_replay`` tests, and random poses for the tests of
what maps or moves poses.

A scene is one library object at a pose ``T_world_object`` (its cloud sampled from the mesh surface with noise).
A demonstration approaches the object from above, closes the gripper and lifts: its EE poses are fixed in the
object frame, so moving the object by ``T`` moves every correct action by ``T``.

Two-object scenes: a carry (a mug onto a duck, :func:`carry_demo`) and a push (a square block slid onto a square
plate, :func:`push_demo`: both objects look alike turned a quarter, so only their layout tells which face to push).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.contract import NUM_POINTS
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.data.lerobot_format import create_dataset, write_episode
from lerobot_instant_policy.geometry.se3 import look_rotation, make_pose, pose_to_pos_quat, transform_points
from lerobot_instant_policy.objects.library import load_object

OBJECT_ID = "pb/mug"
MUG, DUCK = "pb/mug", "pb/duck"  # the two objects of the carry scenes (scene_cloud, carry_demo)
NUM_FRAMES = 12


def object_pose(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """``T_world_object (4, 4)``: the object upright on the table at ``(x, y)`` turned by ``yaw_deg`` about z."""
    return make_pose(np.array([x, y, 0.0]), Rotation.from_euler("z", yaw_deg, degrees=True))


def object_cloud(T_world_object: np.ndarray, seed: int, noise: float = 0.001, object_id: str = OBJECT_ID) -> np.ndarray:
    """``(NUM_POINTS, 3)`` float32 world-frame surface samples of the object at ``T_world_object`` with noise."""
    model = load_object(object_id)
    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
    rng = np.random.default_rng(seed)
    points = np.asarray(mesh.sample(NUM_POINTS, seed=seed)) + rng.normal(0.0, noise, (NUM_POINTS, 3))
    return transform_points(T_world_object, points).astype(np.float32)


def ee_poses_in_object() -> np.ndarray:
    """``(NUM_FRAMES, 4, 4)`` EE poses in the object frame: descend from 25 cm to 8 cm above it, then lift."""
    down = look_rotation(np.array([0.0, 0.0, -1.0]), yaw=0.3)
    heights = np.concatenate([np.linspace(0.25, 0.08, NUM_FRAMES // 2), np.linspace(0.08, 0.2, NUM_FRAMES - NUM_FRAMES // 2)])
    offsets = np.linspace(0.04, 0.0, NUM_FRAMES)
    return np.stack([make_pose(np.array([offset, 0.02, height]), down) for offset, height in zip(offsets, heights)])


def gripper_commands() -> np.ndarray:
    """``(NUM_FRAMES,)``: open (1) while descending, closed (0) from the lowest frame on."""
    return (np.arange(NUM_FRAMES) < NUM_FRAMES // 2 - 1).astype(np.float32)


def expected_actions(T_world_object: np.ndarray) -> np.ndarray:
    """``(NUM_FRAMES, 8)`` world-frame actions of the demonstration for the object at ``T_world_object``."""
    rows = []
    for pose, gripper in zip(T_world_object @ ee_poses_in_object(), gripper_commands()):
        position, quat = pose_to_pos_quat(pose)
        rows.append(np.concatenate([position, quat, [gripper]]))
    return np.asarray(rows, dtype=np.float32)


def make_demonstration(T_world_object: np.ndarray, task: str, seed: int, object_id: str = OBJECT_ID) -> Demonstration:
    """A demonstration of ``task`` with the object at ``T_world_object``; state k is action k - 1 (start: action 0)."""
    action = expected_actions(T_world_object)
    state = np.concatenate([action[:1], action[:-1]])
    state[:, 7] = np.concatenate([[1.0], action[:-1, 7]])
    cloud = object_cloud(T_world_object, seed, object_id=object_id)
    points = np.repeat(cloud[None], NUM_FRAMES, axis=0)
    return Demonstration(points_world=points, state=state, action=action, task=task)


def write_demo_dataset(root, repo_id: str, episodes: list[tuple[str, np.ndarray]], seed: int = 0) -> list[Demonstration]:
    """Write a LeRobotDataset at ``root`` with one episode per ``(task, T_world_object)``; return what was written."""
    dataset = create_dataset(repo_id, root)
    demos = []
    for index, (task, T_world_object) in enumerate(episodes):
        demo = make_demonstration(T_world_object, task, seed + index)
        write_episode(dataset, demo.points_world, demo.state, demo.action, task)
        demos.append(demo)
    dataset.finalize()
    return demos


def random_poses(count: int, seed: int = 0, extent_m: float = 2.0) -> np.ndarray:
    """``(count, 4, 4)`` poses: rotations uniform on SO(3), translations uniform in ``[-extent_m, extent_m]³``."""
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    return np.stack([make_pose(rng.uniform(-extent_m, extent_m, 3), rotation) for rotation in rotations])


def scene_cloud(T_world_mug: np.ndarray, T_world_duck: np.ndarray, seed: int) -> np.ndarray:
    """``(NUM_POINTS, 3)``: half the points on the mug, half on the duck."""
    half = NUM_POINTS // 2
    return np.concatenate([object_cloud(T_world_mug, seed, object_id=MUG)[:half],
                           object_cloud(T_world_duck, seed + 1, object_id=DUCK)[:half]])


def carry_actions(T_world_mug: np.ndarray, T_world_duck: np.ndarray, grasp_open: bool = False) -> np.ndarray:
    """``(9, 8)``: down onto the mug, close (frame 2), lift, carry over the duck, lower, open (frame 7), up.
    ``grasp_open``: the gripper never closes (no grasp and release)."""
    mug, duck = T_world_mug[:3, 3], T_world_duck[:3, 3]
    waypoints = [(mug, 0.20, 1), (mug, 0.06, 1), (mug, 0.06, 0), (mug, 0.20, 0), ((mug + duck) / 2, 0.20, 0),
                 (duck, 0.20, 0), (duck, 0.12, 0), (duck, 0.12, 1), (duck, 0.25, 1)]
    down = look_rotation(np.array([0.0, 0.0, -1.0]), yaw=0.0)
    rows = []
    for xy, height, gripper in waypoints:
        position, quat = pose_to_pos_quat(make_pose(np.array([xy[0], xy[1], height]), down))
        rows.append(np.concatenate([position, quat, [1.0 if grasp_open else gripper]]))
    return np.asarray(rows, dtype=np.float32)


def carry_demo(T_world_mug: np.ndarray, T_world_duck: np.ndarray, seed: int, grasp_open: bool = False) -> Demonstration:
    action = carry_actions(T_world_mug, T_world_duck, grasp_open)
    state = np.concatenate([action[:1], action[:-1]])
    points = np.repeat(scene_cloud(T_world_mug, T_world_duck, seed)[None], len(action), axis=0)
    return Demonstration(points_world=points, state=state, action=action, task="put_on_duck")


def box_cloud(extents: tuple[float, float, float], T_world_box: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``(count, 3)`` world-frame surface samples (0.5 mm noise) of a box of ``extents`` (m) standing on the table at
    ``T_world_box``."""
    mesh = trimesh.creation.box(extents=extents)
    points = np.asarray(mesh.sample(count, seed=seed)) + np.array([0.0, 0.0, extents[2] / 2])
    points += np.random.default_rng(seed).normal(0.0, 0.0005, points.shape)
    return transform_points(T_world_box, points)


def push_layout(x: float, y: float, heading_deg: float, block_yaw_deg: float, plate_yaw_deg: float,
                distance: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """``T_world_block, T_world_plate``: the block at ``(x, y)``, the plate ``distance`` (m) from it towards
    ``heading_deg``, each turned by its own yaw."""
    heading = np.deg2rad(heading_deg)
    return (object_pose(x, y, block_yaw_deg),
            object_pose(x + distance * np.cos(heading), y + distance * np.sin(heading), plate_yaw_deg))


def push_cloud(T_world_block: np.ndarray, T_world_plate: np.ndarray, seed: int) -> np.ndarray:
    """``(NUM_POINTS, 3)``: half the points on a 5 cm block, half on a 12 × 12 × 1 cm plate."""
    half = NUM_POINTS // 2
    return np.concatenate([box_cloud((0.05, 0.05, 0.05), T_world_block, half, seed),
                           box_cloud((0.12, 0.12, 0.01), T_world_plate, half, seed + 1)]).astype(np.float32)


def push_actions(T_world_block: np.ndarray, T_world_plate: np.ndarray) -> np.ndarray:
    """``(8, 8)``: down behind the block (on the far side from the plate), stop, push it onto the plate, stop, up;
    the gripper closed throughout."""
    block, plate = T_world_block[:3, 3], T_world_plate[:3, 3]
    towards = (plate - block) / np.linalg.norm(plate - block)
    down = look_rotation(np.array([0.0, 0.0, -1.0]), yaw=float(np.arctan2(towards[1], towards[0])))
    behind_block, behind_plate = block - 0.07 * towards, plate - 0.07 * towards
    waypoints = [(behind_block, 0.15)] + [(behind_block, 0.03)] * 3 + [(behind_plate, 0.03)] * 3 + [(behind_plate, 0.15)]
    rows = []
    for xy, height in waypoints:
        position, quat = pose_to_pos_quat(make_pose(np.array([xy[0], xy[1], height]), down))
        rows.append(np.concatenate([position, quat, [0.0]]))
    return np.asarray(rows, dtype=np.float32)


def push_demo(T_world_block: np.ndarray, T_world_plate: np.ndarray, seed: int) -> Demonstration:
    action = push_actions(T_world_block, T_world_plate)
    points = np.repeat(push_cloud(T_world_block, T_world_plate, seed)[None], len(action), axis=0)
    return Demonstration(points_world=points, state=np.concatenate([action[:1], action[:-1]]), action=action,
                         task="slide_block")
