"""A training batch as the network's loss reads it: the checked live frames, the action targets in each row's EE frame,
the context from one of three sources, and the replay prior a share of the rows starts from.

Every batch row is a frame with ``observation.pointcloud (P, 3)`` and ``observation.state (8,)`` (world frame). Its
``horizon`` actions come with the batch (``action (B, T, 8)``: the stream's and the pool's) or, as ``lerobot-train``
delivers a dataset's rows (``action (B, 8)`` and ``index (B,)``), from the training dataset's action table
(:mod:`..data.action_chunks`). One N in ``min_demos … max_demos`` is drawn per batch, so every row has the same graph.
The context comes

1. carried as clouds (``contract.CONTEXT_KEYS``, the pseudo-task stream's): the frozen encoder runs once per distinct
   context id, each waypoint's cloud in its own EE frame (:func:`carried_context`);
2. carried already encoded (``contract.ENCODED_KEYS``, the task pool's, whose live frames come encoded too, in place of
   their clouds): read as they are (:func:`encoded_context`);
3. or drawn from the training dataset: per row, N other episodes of the row's task from the :class:`TrainingData`'s
   context bank, through :class:`~.context_encoder.ContextEncoder` (with the dataset's frame encodings, the live
   frames' scene nodes are read by ``index`` too).

With ``refine_fraction`` > 0 each row starts, with that probability, from its replay prior
(``observation.replay_prior (B, T, 8)``), among the rows whose prior the stream kept
(``observation.replay_prior_kept`` where the batch has it): :func:`refinement`.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..contract import (
    ACTION_KEY,
    CONTEXT_GRIPPER_OPEN_KEY,
    CONTEXT_ID_KEY,
    CONTEXT_KEYS,
    CONTEXT_POINTCLOUD_KEY,
    CONTEXT_SCENE_FEATURES_KEY,
    CONTEXT_SCENE_POSITIONS_KEY,
    CONTEXT_T_WORLD_EE_KEY,
    ENCODED_KEYS,
    POINTCLOUD_KEY,
    REPLAY_PRIOR_KEPT_KEY,
    REPLAY_PRIOR_KEY,
    SCENE_FEATURES_KEY,
    SCENE_POSITIONS_KEY,
    STATE_KEY,
    checked_observation,
    poses_from_vectors_torch,
)
from ..data.action_chunks import ActionChunks
from ..data.context_bank import ContextBank
from ..data.demonstrations import open_demo_dataset
from ..geometry.rigid_torch import compose, invert_rigid
from ..model.action_diffusion import ActionDiffusion
from ..model.bounds import SUPPORTED_WAYPOINTS, check_range
from ..model.fingerprint import encoder_fingerprint
from ..model.instant_policy_network import DemoTensors, InstantPolicyNetwork
from .context_encoder import ContextEncoder
from .frame_encodings import FrameEncodings, build_frame_encodings, load_frame_encodings

logger = logging.getLogger(__name__)


class TrainingData:
    """The training dataset's side of a batch drawn from it: its context bank (waypoints of every episode), its
    action table and, with ``cache_frame_encodings``, the frozen encoder's output for every frame (loaded from beside
    the dataset, or built there at first use: :func:`dataset_frame_encodings`). Nothing of it is part of the weights.

    Args:
        network: the network whose frozen encoder makes the scene nodes.
        bank: the context bank (its ``num_waypoints`` is the network config's L).
        action_chunks: every frame's action, for batches that carry only their own row's.
        frame_encodings: the frame encodings of the dataset ``bank`` was read from; None: built or loaded at first
            use from ``dataset_meta`` when given, else the bank's clouds are encoded.
        dataset_meta: the dataset's ``LeRobotDatasetMetadata`` (its ``root`` and ``repo_id``).
    """

    def __init__(self, network: InstantPolicyNetwork, bank: ContextBank, action_chunks: ActionChunks | None = None,
                 frame_encodings: FrameEncodings | None = None, dataset_meta=None):
        self.network, self.bank, self.action_chunks = network, bank, action_chunks
        self.dataset_meta = dataset_meta
        self._frame_encodings = frame_encodings
        self._context_encoder: ContextEncoder | None = None

    @classmethod
    def from_dataset_meta(cls, network: InstantPolicyNetwork, dataset_meta, cache_frame_encodings: bool) -> TrainingData:
        """The bank and action table of the dataset ``dataset_meta`` describes; ``ValueError`` when its clouds do not
        have the network's size. With ``cache_frame_encodings`` the bank holds no clouds (their scene nodes come from
        the frame encodings)."""
        num_points = network.config.num_points
        shape = tuple(dataset_meta.features.get(POINTCLOUD_KEY, {}).get("shape", ()))
        if shape[:1] != (num_points,):
            raise ValueError(f"point clouds of the wrong size: the training dataset's {POINTCLOUD_KEY!r} has shape "
                             f"{shape}, the policy expects ({num_points}, 3)")
        bank = ContextBank.from_dataset_meta(dataset_meta, network.config.num_waypoints,
                                             read_points=not cache_frame_encodings)
        return cls(network, bank, ActionChunks.from_dataset(dataset_meta.repo_id, dataset_meta.root),
                   dataset_meta=dataset_meta if cache_frame_encodings else None)

    def context_encoder(self) -> ContextEncoder:
        """The bank's path to the network, with the dataset's frame encodings where there are any."""
        if self._context_encoder is None:
            if self._frame_encodings is None and self.dataset_meta is not None:
                self._frame_encodings = dataset_frame_encodings(self.network, self.dataset_meta)
            self._context_encoder = ContextEncoder(self.network, self.bank, self._frame_encodings)
        return self._context_encoder

    def forget_encodings(self) -> None:
        """Drop what the frozen encoder made (its weights changed): rebuilt or reloaded at next use."""
        self._context_encoder = None
        self._frame_encodings = None


def dataset_frame_encodings(network: InstantPolicyNetwork, dataset_meta) -> FrameEncodings:
    """The frozen encoder's output for every frame of the dataset ``dataset_meta`` describes (its local ``root``),
    for the encoder's current weights: loaded from beside the dataset, or built there once (minutes on a CPU)."""
    encoder = network.geometry_encoder
    fingerprint = encoder_fingerprint(encoder, encoder.config.to_dict())
    encodings = load_frame_encodings(dataset_meta.root, fingerprint)
    if encodings is None:
        logger.info("instant_policy: encoding every frame of %s once with the frozen encoder", dataset_meta.root)
        device = next(network.parameters()).device
        encodings = build_frame_encodings(open_demo_dataset(dataset_meta.repo_id, dataset_meta.root), fingerprint,
                                          functools.partial(encode_frames, network), device)
    return encodings


def encode_frames(network: InstantPolicyNetwork, points_world: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
    """The frozen encoder's scene nodes of frames ``points_world (B, P, 3)`` with ``state (B, 8)``, each in its own
    EE frame: positions ``(B, M, 3)`` and features ``(B, M, D)``."""
    return network.encode_observation(points_world, poses_from_vectors_torch(state)[0])


@dataclass
class TrainingTargets:
    """The checked live frames and targets of a training batch.

    Attributes:
        points_world: ``(B, P, 3)`` world-frame clouds; None for a batch whose live frames come encoded.
        state: ``(B, 8)`` EE poses and gripper states, world frame.
        T_world_ee: ``(B, 4, 4)`` the EE poses.
        T_ee_actions: ``(B, T, 4, 4)`` the action poses in each row's current EE frame.
        action_gripper: ``(B, T)`` gripper commands in [0, 1]; padded actions past the episode's end are held.
    """

    points_world: Tensor | None
    state: Tensor
    T_world_ee: Tensor
    T_ee_actions: Tensor
    action_gripper: Tensor


def training_targets(batch: dict[str, Tensor], horizon: int, num_points: int,
                     data: TrainingData | None = None) -> TrainingTargets:
    """The :class:`TrainingTargets` of ``batch`` (module docstring): ``action (B, T, 8)`` with optional
    ``action_is_pad (B, T)``, or each row's own ``action (B, 8)`` with ``index (B,)``, whose chunk is read from
    ``data``'s action table. ``ValueError`` naming a wrong shape or a non-finite value; ``RuntimeError`` when the
    chunks must be read and there is no table."""
    points_world, state = checked_observation(batch, num_points, cloud_required=SCENE_FEATURES_KEY not in batch)
    actions = batch.get(ACTION_KEY)
    batch_size = len(state)
    if actions is not None and tuple(actions.shape) == (batch_size, 8) and "index" in batch:
        # lerobot-train delivers each row's own action (action_delta_indices is None): read the chunks.
        if data is None or data.action_chunks is None:
            raise RuntimeError(
                f"instant_policy training needs {ACTION_KEY!r} chunks of shape (B, horizon, 8): give them in the "
                "batch, or build the policy with dataset_meta (lerobot-train does) to read them by 'index'"
            )
        chunks, _ = data.action_chunks.chunks(batch["index"].detach().cpu().numpy(), horizon)
        actions = torch.from_numpy(chunks).to(device=state.device, dtype=state.dtype)
    if actions is None or tuple(actions.shape) != (batch_size, horizon, 8):
        got = None if actions is None else tuple(actions.shape)
        raise ValueError(f"{ACTION_KEY!r} must have shape (B, horizon, 8) = ({batch_size}, {horizon}, 8), got {got}")
    actions = hold_padded(actions, batch.get(f"{ACTION_KEY}_is_pad"))
    if not torch.isfinite(actions).all():
        raise ValueError(f"{ACTION_KEY!r} contains NaN or infinite values")
    T_world_ee, _ = poses_from_vectors_torch(state)
    T_world_actions, action_gripper = poses_from_vectors_torch(actions)
    T_ee_actions = compose(invert_rigid(T_world_ee)[:, None], T_world_actions)
    return TrainingTargets(points_world, state, T_world_ee, T_ee_actions, action_gripper.clamp(0.0, 1.0))


@dataclass
class TrainingBatch:
    """What the network's training loss reads of a batch: its :class:`TrainingTargets`, the live gripper states
    ``gripper (B,)`` (1 open, some flipped), the context ``demos`` of ``num_demos`` demonstrations, the live frames'
    scene nodes where they come encoded or cached (``scene_geometry``: ``(B, M, 3)`` positions, ``(B, M, D)``
    features), and the replay ``prior (B, T, 7)`` with the ``refined_rows (B,)`` that start from it (both None when
    not training to refine)."""

    targets: TrainingTargets
    gripper: Tensor
    demos: DemoTensors
    num_demos: int
    scene_geometry: tuple[Tensor, Tensor] | None
    prior: Tensor | None
    refined_rows: Tensor | None


def training_batch(batch: dict[str, Tensor], config, network: InstantPolicyNetwork,
                   data: TrainingData | None = None) -> TrainingBatch:
    """The :class:`TrainingBatch` of ``batch`` for ``network`` under ``config`` (an ``InstantPolicyConfig``: horizon,
    cloud size, N range, gripper flips, refinement), drawn from torch's RNG (module docstring for the context's three
    sources; ``data`` serves the third). ``KeyError`` when the batch has no context and no ``episode_index``."""
    targets = training_targets(batch, config.horizon, config.num_points, data)
    state = targets.state
    batch_size, device = len(state), state.device
    gripper = (state[:, 7] > 0.5).to(state.dtype)
    flip = torch.rand(batch_size, device=device) < config.gripper_flip_probability
    gripper = torch.where(flip, 1.0 - gripper, gripper)

    rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, (1,)).item()))
    encoded = CONTEXT_SCENE_FEATURES_KEY in batch
    carried = encoded or any(key in batch for key in CONTEXT_KEYS)
    if carried:
        available = batch[CONTEXT_T_WORLD_EE_KEY].shape[1] if CONTEXT_T_WORLD_EE_KEY in batch else 0
    else:
        if "episode_index" not in batch:
            raise KeyError("instant_policy training needs 'episode_index' in the batch to draw context "
                           "demonstrations, or the context itself (contract.CONTEXT_KEYS or ENCODED_KEYS)")
        if data is None:
            raise RuntimeError(
                "instant_policy training draws context demonstrations from the training dataset: build the policy "
                "with dataset_meta (lerobot-train does) or call set_training_bank()"
            )
        encoder = data.context_encoder()
        episodes = batch["episode_index"].detach().cpu().numpy().reshape(-1).astype(np.int64)
        # N is capped at the fewest other episodes of a row's task: a demonstration never repeats in one context.
        available = int(encoder.bank.other_episode_counts(episodes).min())
    num_demos = min(int(rng.integers(config.min_demos, config.max_demos + 1)), max(available, 1))
    scene_geometry = None
    if encoded:
        demos = encoded_context(batch, num_demos)
        scene_geometry = (batch[SCENE_POSITIONS_KEY].to(device=device, dtype=torch.float32),
                          batch[SCENE_FEATURES_KEY].to(device=device, dtype=torch.float32))
    elif carried:
        demos = carried_context(batch, num_demos, network)
    else:
        context_episodes = np.stack([encoder.bank.sample_context(int(episode), num_demos, rng)
                                     for episode in episodes])
        demos = encoder.demos(context_episodes, device)
        scene_geometry = encoder.frames(batch["index"].detach().cpu().numpy(), device) if "index" in batch else None
    prior, refined_rows = refinement(batch, targets.T_world_ee, config.refine_fraction, config.horizon,
                                     network.diffusion)
    return TrainingBatch(targets, gripper, demos, num_demos, scene_geometry, prior, refined_rows)


def refinement(batch: dict[str, Tensor], T_world_ee: Tensor, refine_fraction: float, horizon: int,
               diffusion: ActionDiffusion) -> tuple[Tensor | None, Tensor | None]:
    """With ``refine_fraction`` > 0: the replay prior of the batch as a diffusion variable in each row's EE frame
    ``(B, T, 7)`` and the rows that start from it ``(B,)`` (each with probability ``refine_fraction``, among the rows
    whose prior the stream kept: ``observation.replay_prior_kept`` where the batch has it); else ``(None, None)``.
    ``KeyError`` saying how to get priors when the batch has none."""
    if not refine_fraction:
        return None, None
    if REPLAY_PRIOR_KEY not in batch:
        raise KeyError(
            f"refine_fraction={refine_fraction} trains on replay priors, but the batch has no "
            f"{REPLAY_PRIOR_KEY!r}: train on the pseudo-task stream or pool (lerobot-ip-train), which plans them "
            "when refine_fraction > 0, or set --policy.refine_fraction=0"
        )
    prior = planned_in_ee_frame(REPLAY_PRIOR_KEY, batch[REPLAY_PRIOR_KEY], T_world_ee, horizon, diffusion)
    refined_rows = torch.rand(len(T_world_ee), device=T_world_ee.device) < refine_fraction
    if REPLAY_PRIOR_KEPT_KEY in batch:
        refined_rows &= batch[REPLAY_PRIOR_KEPT_KEY].to(device=refined_rows.device, dtype=torch.bool)
    return prior, refined_rows


def planned_in_ee_frame(name: str, planned: Tensor, T_world_ee: Tensor, horizon: int,
                        diffusion: ActionDiffusion) -> Tensor:
    """Planned world-frame actions ``planned (B, T, 8)`` (``name`` in errors) as the diffusion variable ``(B, T, 7)``
    of actions relative to the current EE poses ``T_world_ee (B, 4, 4)``; ``ValueError`` for another shape or a
    non-finite value. Training's replay priors and inference's denoising starts take this one path."""
    expected = (len(T_world_ee), horizon, 8)
    if tuple(planned.shape) != expected:
        raise ValueError(f"{name!r} must have shape (B, horizon, 8) = {expected}, got {tuple(planned.shape)}")
    if not torch.isfinite(planned).all():
        raise ValueError(f"{name!r} contains NaN or infinite values")
    planned = planned.to(device=T_world_ee.device, dtype=T_world_ee.dtype)
    T_world_planned, planned_gripper = poses_from_vectors_torch(planned)
    T_ee_planned = compose(invert_rigid(T_world_ee)[:, None], T_world_planned)
    return diffusion.normalize(T_ee_planned, planned_gripper.clamp(0.0, 1.0))


def encoded_context(batch: dict[str, Tensor], num_demos: int) -> DemoTensors:
    """The first ``num_demos`` demonstrations of an already encoded context (``contract.ENCODED_KEYS``:
    ``(B, N, L, 4, 4)`` EE poses, ``(B, N, L)`` gripper states, the frozen encoder's scene nodes of each waypoint in
    its own EE frame, ``(B, N, L, M, 3)`` positions and ``(B, N, L, M, D)`` features), checked: ``KeyError`` for a
    missing key, ``ValueError`` naming a wrong shape or a non-finite value."""
    missing = [key for key in ENCODED_KEYS if key not in batch]
    if missing:
        raise KeyError(f"an encoded training batch needs all of {list(ENCODED_KEYS)}; missing {missing}")
    T_world_ee = batch[CONTEXT_T_WORLD_EE_KEY]
    if T_world_ee.ndim != 5 or tuple(T_world_ee.shape[-2:]) != (4, 4) or len(T_world_ee) != len(batch[STATE_KEY]):
        raise ValueError(f"{CONTEXT_T_WORLD_EE_KEY!r} must have shape (B, N, L, 4, 4) with B = "
                         f"{len(batch[STATE_KEY])}, got {tuple(T_world_ee.shape)}")
    check_range("the number of demonstrations N", num_demos, (1, T_world_ee.shape[1]))
    check_range("num_waypoints (L)", T_world_ee.shape[2], SUPPORTED_WAYPOINTS)
    device = batch[STATE_KEY].device

    def first(key: str) -> Tensor:
        return batch[key][:, :num_demos].to(device=device, dtype=torch.float32)

    return DemoTensors(T_world_ee=first(CONTEXT_T_WORLD_EE_KEY), gripper_open=first(CONTEXT_GRIPPER_OPEN_KEY),
                       scene_positions=first(CONTEXT_SCENE_POSITIONS_KEY),
                       scene_features=first(CONTEXT_SCENE_FEATURES_KEY))


def carried_context(batch: dict[str, Tensor], num_demos: int, network: InstantPolicyNetwork) -> DemoTensors:
    """The first ``num_demos`` demonstrations of the context a batch carries (``contract.CONTEXT_KEYS``:
    ``(B, N, L, P, 3)`` world-frame clouds, ``(B, N, L, 4, 4)`` EE poses, ``(B, N, L)`` gripper states, ``(B,)``
    ids), checked: ``ValueError`` naming the problem. ``network``'s frozen encoder runs once per distinct id, each
    waypoint's cloud in its own EE frame, as :class:`~.context_encoder.ContextEncoder` does for a dataset's
    waypoints."""
    missing = [key for key in CONTEXT_KEYS if key not in batch]
    if missing:
        raise KeyError(f"a batch that carries its context needs all of {list(CONTEXT_KEYS)}; missing {missing}")
    points, T_world_ee = batch[CONTEXT_POINTCLOUD_KEY], batch[CONTEXT_T_WORLD_EE_KEY]
    gripper_open, ids = batch[CONTEXT_GRIPPER_OPEN_KEY], batch[CONTEXT_ID_KEY]
    batch_size = len(batch[STATE_KEY])
    if T_world_ee.ndim != 5 or tuple(T_world_ee.shape[-2:]) != (4, 4) or len(T_world_ee) != batch_size:
        raise ValueError(f"{CONTEXT_T_WORLD_EE_KEY!r} must have shape (B, N, L, 4, 4) with B = {batch_size}, "
                         f"got {tuple(T_world_ee.shape)}")
    leading = tuple(T_world_ee.shape[:3])
    check_range("the number of demonstrations N", num_demos, (1, leading[1]))
    check_range("num_waypoints (L)", leading[2], SUPPORTED_WAYPOINTS)
    expected = {CONTEXT_POINTCLOUD_KEY: (*leading, network.config.num_points, 3),
                CONTEXT_GRIPPER_OPEN_KEY: leading, CONTEXT_ID_KEY: (batch_size,)}
    for key, shape in expected.items():
        if tuple(batch[key].shape) != shape:
            raise ValueError(f"{key!r} must have shape {shape}, got {tuple(batch[key].shape)}")
    for key in (CONTEXT_POINTCLOUD_KEY, CONTEXT_T_WORLD_EE_KEY, CONTEXT_GRIPPER_OPEN_KEY):
        if not torch.isfinite(batch[key]).all():
            raise ValueError(f"{key!r} contains NaN or infinite values")
    device = batch[STATE_KEY].device
    points = points[:, :num_demos].to(device=device, dtype=torch.float32)
    T_world_ee = T_world_ee[:, :num_demos].to(device=device, dtype=torch.float32)
    _, row_of_id, first = _first_rows(ids.to(device))
    positions, features = network.encode_observation(points[first], T_world_ee[first])
    return DemoTensors(
        T_world_ee=T_world_ee,
        gripper_open=gripper_open[:, :num_demos].to(device=device, dtype=torch.float32),
        scene_positions=positions[row_of_id],
        scene_features=features[row_of_id],
    )


def hold_padded(actions: Tensor, is_pad: Tensor | None) -> Tensor:
    """Replace padded actions ``(B, T, 8)`` (``is_pad (B, T)`` True past the episode's end) by the row's last real one."""
    if is_pad is None or not bool(is_pad.any()):
        return actions
    steps = torch.arange(actions.shape[1], device=actions.device).expand_as(is_pad)
    last_real = torch.where(is_pad, torch.zeros_like(steps), steps).amax(dim=1)
    held = actions.gather(1, last_real[:, None, None].expand(-1, actions.shape[1], actions.shape[2]))
    return torch.where(is_pad[..., None], held, actions)


def _first_rows(ids: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The distinct values of ``ids (B,)``, each row's position among them ``(B,)`` and each value's first row."""
    unique, row_of_id = torch.unique(ids, return_inverse=True)
    rows = torch.arange(len(ids), device=ids.device)
    first = torch.full((len(unique),), len(ids), device=ids.device, dtype=rows.dtype).scatter_reduce(
        0, row_of_id, rows, reduce="amin")
    return unique, row_of_id, first
