"""``InstantPolicyPolicy``: the Instant Policy network as a LeRobot policy (``--policy.type=instant_policy``).

Training (``lerobot-train``): every batch row is a frame of an episode with ``observation.pointcloud (P, 3)`` and
``observation.state (8,)`` (world frame), its ``episode_index`` and ``index``; the ``horizon`` actions that follow it
come from the dataset's action table (:mod:`.data.action_chunks`). The policy draws one N in ``min_demos …
max_demos`` per batch (so every row has the same graph) and, per row, N other episodes of the row's task from a
:class:`ContextBank` of the training dataset. The bank and the action table are read when the policy is built with
the training dataset's ``dataset_meta`` (as ``lerobot-train`` does). The frozen encoder's output for every frame of
that dataset is cached beside it (:mod:`.frame_encodings`; loaded, or built once, at the first ``forward``, on the
policy's device), so a training step reads the scene nodes of its frames and of their context waypoints. None of
this is part of ``model.safetensors``.

Evaluation (``lerobot-eval``) and deployment: the demonstrations of each batch row's ``task`` come from the
dataset ``demo_repo_id`` at ``demo_root`` (``num_demos`` episodes), or from :meth:`set_demonstrations`. They take
the training context's path (a bank of their waypoints → :class:`ContextEncoder` → :class:`DemoTensors`) once per
task, and the result is reused at every control step. With ``context="language"`` a task whose demonstrations were
not handed in is said in words instead: its ``task`` string through the language head (:mod:`.language.task_language`).

Actions: the network predicts ``T_EA``, the action poses in the current EE frame; the policy returns them as
absolute world-frame EE targets ``(B, T, 8)`` in the layout of docs/design.md §4 (xyz, quaternion xyzw with ``w ≥ 0``,
gripper 1 open / 0 closed).
"""

import logging
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from .configuration_instant_policy import InstantPolicyConfig
from .contract import (
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
    poses_from_vectors_torch,
    vectors_from_poses_torch,
)
from .data.action_chunks import ActionChunks
from .data.context_bank import ContextBank
from .data.demonstrations import Demonstration, DemonstrationSource, batch_task_names, open_demo_dataset
from .data.replay_plan import REPLAY_REGISTRATION, ReplayPlan, plan_replay
from .geometry.rigid_torch import compose, invert_rigid
from .language.task_language import TaskLanguage
from .model.bounds import SUPPORTED_DEMOS, SUPPORTED_WAYPOINTS, check_range
from .model.instant_policy_network import DemoTensors, InstantPolicyContext, InstantPolicyNetwork
from .model.occupancy import load_encoder_weights
from .policy.context_encoder import ContextEncoder
from .policy.frame_encodings import FrameEncodings, build_frame_encodings, encoder_fingerprint, load_frame_encodings

logger = logging.getLogger(__name__)


class CheckpointMismatchError(ValueError):
    """A checkpoint's tensors do not match the network its ``config.json`` describes."""


@dataclass
class TaskContext:
    """One task's context at inference: its demonstrations reduced to ``num_waypoints`` (L) waypoints, handed in with
    :meth:`InstantPolicyPolicy.set_demonstrations` (``handed_in``) or read from ``demo_repo_id``. Computed on first
    use and kept until the weights change: ``demos``, their :class:`DemoTensors` with a batch of one on the
    policy's device, and ``waypoint_features (1, N, L, G, H)``, σ's output on their local graphs, valid for the
    weights identified by ``weights_version``."""

    num_waypoints: int
    handed_in: bool
    demos: DemoTensors | None = None
    waypoint_features: Tensor | None = None
    weights_version: tuple | None = None


class InstantPolicyPolicy(PreTrainedPolicy):
    """Instant Policy (see :class:`InstantPolicyConfig` and the module docstring)."""

    config_class = InstantPolicyConfig
    name = "instant_policy"

    def __init__(self, config: InstantPolicyConfig, dataset_stats=None, dataset_meta=None,
                 load_encoder_weights: bool = True, **kwargs):
        """Build the policy; with ``dataset_meta`` of a training dataset (a ``LeRobotDatasetMetadata``) read that
        dataset's context bank and action table (other metadata, the pseudo-task stream's, describes no files: its
        batches carry their context and action chunks). ``load_encoder_weights``: load the frozen encoder's pretrained
        weights (:meth:`load_encoder_weights`) when ``config.pretrained_encoder``; ``from_pretrained`` passes False,
        since a checkpoint carries its encoder."""
        super().__init__(config)
        config.validate_features()
        self.config: InstantPolicyConfig = config
        self.network = InstantPolicyNetwork(config)
        self._dataset_meta = dataset_meta
        self._training_bank: ContextBank | None = None
        self._training_frame_encodings: FrameEncodings | None = None
        self._context_encoder: ContextEncoder | None = None
        self._action_chunks: ActionChunks | None = None
        self._task_contexts: dict[str, TaskContext] = {}
        if config.pretrained_encoder and load_encoder_weights:
            self.load_encoder_weights(config.encoder_weights_path())
        if isinstance(dataset_meta, LeRobotDatasetMetadata):
            self._training_bank = self._read_training_bank(dataset_meta)
            self._action_chunks = ActionChunks.from_dataset(dataset_meta.repo_id, dataset_meta.root)
        self._queue: deque[Tensor] = deque()
        self._last_gripper: Tensor | None = None
        self._replay_plans: list[ReplayPlan] | None = None
        self._episode_step = 0
        self._demonstrations = DemonstrationSource(
            "instant_policy", config.demo_repo_id, config.demo_root, config.num_demos
        )
        self._language = (TaskLanguage(config.language_head_path, config.language_paraphrase,
                                       instruction=config.language_instruction)
                          if config.context == "language" else None)

    def load_encoder_weights(self, path: str | Path) -> None:
        """Load the frozen geometry encoder's weights from a ``lerobot-ip-pretrain-encoder`` file: a
        ``FileNotFoundError`` that says how to get them when there is none, a ``ValueError`` when they were trained
        for another architecture than the network's encoder."""
        if not Path(path).is_file():
            raise FileNotFoundError(
                f"no geometry encoder weights at {path}: train them with `lerobot-ip-pretrain-encoder --preset "
                f"{self.config.encoder_preset} --out FILE.safetensors` and pass --policy.encoder_weights=FILE.safetensors, "
                "or set --policy.pretrained_encoder=false for a randomly initialised frozen encoder"
            )
        load_encoder_weights(self.network.geometry_encoder, path)
        self.clear_context_caches()

    # ------------------------------------------------------------------ LeRobot interface
    def get_optim_params(self) -> list[Tensor]:
        """The trainable parameters (the frozen geometry encoder excluded)."""
        return [parameter for parameter in self.parameters() if parameter.requires_grad]

    def reset(self) -> None:
        """Start a new episode: drop queued actions, the last gripper command and the replay plans (demo contexts are
        kept)."""
        self._queue.clear()
        self._last_gripper = None
        self._replay_plans = None
        self._episode_step = 0

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Training loss of a batch from the training dataset, the pseudo-task stream or the encoded task pool.

        Args:
            batch: ``observation.pointcloud (B, P, 3)`` and ``observation.state (B, 8)`` in the world frame, and
                either ``action (B, T, 8)`` absolute EE targets (``action_is_pad (B, T)`` optional: padded actions
                past the episode's end are replaced by its last action, i.e. the EE holds still) or, as
                ``lerobot-train`` delivers it from a dataset, the row's own ``action (B, 8)`` and ``index (B,)``: the
                chunk is then read from the training dataset's action table (:meth:`training_action_chunks`). The
                context: the batch's own, as clouds (``contract.CONTEXT_KEYS``, the stream's: :meth:`batch_context`)
                or already encoded (``contract.ENCODED_KEYS``, the task pool's, whose live frame comes encoded too
                in place of its cloud: :meth:`encoded_batch_context`), or else ``episode_index (B,)``, whose task's
                other episodes in the training dataset are drawn. With ``config.refine_fraction`` > 0 also
                ``observation.replay_prior (B, T, 8)`` (the stream's and the pool's with
                ``StreamConfig.replay_priors``): that share of the rows, drawn per row, starts from it
                (:meth:`~.model.instant_policy_network.InstantPolicyNetwork.training_loss`).

        Returns:
            The loss (sum of the parts) and ``{"translation", "rotation", "gripper", "num_demos"}`` as floats, and
            ``"refined"``, the share of refined rows, when training to refine.
        """
        points_world, state, T_world_ee, T_ee_actions, action_gripper = self.training_targets(batch)
        batch_size = len(state)
        gripper = (state[:, 7] > 0.5).to(state.dtype)
        flip = torch.rand(batch_size, device=state.device) < self.config.gripper_flip_probability
        gripper = torch.where(flip, 1.0 - gripper, gripper)

        rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, (1,)).item()))
        device = state.device
        encoded = CONTEXT_SCENE_FEATURES_KEY in batch
        carried = encoded or any(key in batch for key in CONTEXT_KEYS)
        if carried:
            available = batch[CONTEXT_T_WORLD_EE_KEY].shape[1] if CONTEXT_T_WORLD_EE_KEY in batch else 0
        else:
            if "episode_index" not in batch:
                raise KeyError("instant_policy training needs 'episode_index' in the batch to draw context "
                               "demonstrations, or the context itself (contract.CONTEXT_KEYS or ENCODED_KEYS)")
            encoder = self.training_context_encoder()
            episodes = batch["episode_index"].detach().cpu().numpy().reshape(-1).astype(np.int64)
            # N is capped at the fewest other episodes of a row's task: a demonstration never repeats in one context.
            available = int(encoder.bank.other_episode_counts(episodes).min())
        num_demos = min(int(rng.integers(self.config.min_demos, self.config.max_demos + 1)), max(available, 1))
        scene_geometry = None
        if encoded:
            demos = self.encoded_batch_context(batch, num_demos)
            scene_geometry = (batch[SCENE_POSITIONS_KEY].to(device=device, dtype=torch.float32),
                              batch[SCENE_FEATURES_KEY].to(device=device, dtype=torch.float32))
        elif carried:
            demos = self.batch_context(batch, num_demos)
        else:
            context_episodes = np.stack([encoder.bank.sample_context(int(episode), num_demos, rng)
                                         for episode in episodes])
            demos = encoder.demos(context_episodes, device)
            scene_geometry = encoder.frames(batch["index"].detach().cpu().numpy(), device) if "index" in batch else None
        context = self.network.encode_context(demos, points_world, T_world_ee, gripper, scene_geometry=scene_geometry)
        prior, refined_rows = self._refinement(batch, T_world_ee)
        losses = self.network.training_loss(context, T_ee_actions, action_gripper, prior=prior,
                                            refined_rows=refined_rows)
        parts = {name: float(losses[name].detach()) for name in ("translation", "rotation", "gripper")}
        if refined_rows is not None:
            parts["refined"] = float(refined_rows.float().mean())
        return losses["loss"], {**parts, "num_demos": float(num_demos)}

    def _refinement(self, batch: dict[str, Tensor], T_world_ee: Tensor) -> tuple[Tensor | None, Tensor | None]:
        """With ``config.refine_fraction`` > 0: the replay prior of the batch as a diffusion variable in each row's
        EE frame ``(B, T, 7)`` and the rows that start from it ``(B,)`` (each with probability ``refine_fraction``,
        among the rows whose prior the stream kept: ``observation.replay_prior_kept`` where the batch has it);
        else ``(None, None)``. ``KeyError`` saying how to get priors when the batch has none."""
        if not self.config.refine_fraction:
            return None, None
        if REPLAY_PRIOR_KEY not in batch:
            raise KeyError(
                f"refine_fraction={self.config.refine_fraction} trains on replay priors, but the batch has no "
                f"{REPLAY_PRIOR_KEY!r}: train on the pseudo-task stream or pool (lerobot-ip-train), which plans them "
                "when refine_fraction > 0, or set --policy.refine_fraction=0"
            )
        prior = self._in_ee_frame(REPLAY_PRIOR_KEY, batch[REPLAY_PRIOR_KEY], T_world_ee)
        refined_rows = torch.rand(len(T_world_ee), device=T_world_ee.device) < self.config.refine_fraction
        if REPLAY_PRIOR_KEPT_KEY in batch:
            refined_rows &= batch[REPLAY_PRIOR_KEPT_KEY].to(device=refined_rows.device, dtype=torch.bool)
        return prior, refined_rows

    def _in_ee_frame(self, name: str, planned: Tensor, T_world_ee: Tensor) -> Tensor:
        """Planned world-frame actions ``planned (B, T, 8)`` (``name`` in errors) as the diffusion variable
        ``(B, T, 7)`` of actions relative to the current EE poses ``T_world_ee (B, 4, 4)``; ``ValueError`` for another
        shape or a non-finite value."""
        expected = (len(T_world_ee), self.config.horizon, 8)
        if tuple(planned.shape) != expected:
            raise ValueError(f"{name!r} must have shape (B, horizon, 8) = {expected}, got {tuple(planned.shape)}")
        if not torch.isfinite(planned).all():
            raise ValueError(f"{name!r} contains NaN or infinite values")
        planned = planned.to(device=T_world_ee.device, dtype=T_world_ee.dtype)
        T_world_planned, planned_gripper = poses_from_vectors_torch(planned)
        T_ee_planned = compose(invert_rigid(T_world_ee)[:, None], T_world_planned)
        return self.network.diffusion.normalize(T_ee_planned, planned_gripper.clamp(0.0, 1.0))

    def encoded_batch_context(self, batch: dict[str, Tensor], num_demos: int) -> DemoTensors:
        """The first ``num_demos`` demonstrations of an already encoded context (``contract.ENCODED_KEYS``:
        ``(B, N, L, 4, 4)`` EE poses, ``(B, N, L)`` gripper states, the frozen encoder's scene nodes of each
        waypoint in its own EE frame, ``(B, N, L, M, 3)`` positions and ``(B, N, L, M, D)`` features), checked:
        ``KeyError`` for a missing key, ``ValueError`` naming a wrong shape or a non-finite value."""
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

    def batch_context(self, batch: dict[str, Tensor], num_demos: int) -> DemoTensors:
        """The first ``num_demos`` demonstrations of the context a batch carries (``contract.CONTEXT_KEYS``:
        ``(B, N, L, P, 3)`` world-frame clouds, ``(B, N, L, 4, 4)`` EE poses, ``(B, N, L)`` gripper states, ``(B,)``
        ids), checked: ``ValueError`` naming the problem. The frozen encoder runs once per distinct id, each
        waypoint's cloud in its own EE frame, as :class:`ContextEncoder` does for a dataset's waypoints."""
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
        expected = {CONTEXT_POINTCLOUD_KEY: (*leading, self.config.num_points, 3), CONTEXT_GRIPPER_OPEN_KEY: leading,
                    CONTEXT_ID_KEY: (batch_size,)}
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
        positions, features = self.network.encode_observation(points[first], T_world_ee[first])
        return DemoTensors(
            T_world_ee=T_world_ee,
            gripper_open=gripper_open[:, :num_demos].to(device=device, dtype=torch.float32),
            scene_positions=positions[row_of_id],
            scene_features=features[row_of_id],
        )

    def training_targets(self, batch: dict[str, Tensor]) -> tuple[Tensor | None, Tensor, Tensor, Tensor, Tensor]:
        """The checked inputs and targets of a training batch (see :meth:`forward`): ``points_world (B, P, 3)`` (None
        for a batch whose live frames come encoded, ``contract.SCENE_FEATURES_KEY``),
        ``state (B, 8)``, ``T_world_ee (B, 4, 4)``, the action poses in the current EE frame ``T_ee_actions
        (B, T, 4, 4)`` and the gripper commands ``action_gripper (B, T)`` in [0, 1] (padded actions held)."""
        points_world, state = self._observation(batch, cloud_required=SCENE_FEATURES_KEY not in batch)
        actions = batch.get(ACTION_KEY)
        batch_size, horizon = len(state), self.config.horizon
        if actions is not None and tuple(actions.shape) == (batch_size, 8) and "index" in batch:
            # lerobot-train delivers each row's own action (action_delta_indices is None): read the chunks.
            chunks, _ = self.training_action_chunks().chunks(batch["index"].detach().cpu().numpy(), horizon)
            actions = torch.from_numpy(chunks).to(device=state.device, dtype=state.dtype)
        if actions is None or tuple(actions.shape) != (batch_size, horizon, 8):
            got = None if actions is None else tuple(actions.shape)
            raise ValueError(f"{ACTION_KEY!r} must have shape (B, horizon, 8) = ({batch_size}, {horizon}, 8), got {got}")
        actions = _hold_padded(actions, batch.get(f"{ACTION_KEY}_is_pad"))
        if not torch.isfinite(actions).all():
            raise ValueError(f"{ACTION_KEY!r} contains NaN or infinite values")
        T_world_ee, _ = poses_from_vectors_torch(state)
        T_world_actions, action_gripper = poses_from_vectors_torch(actions)
        T_ee_actions = compose(invert_rigid(T_world_ee)[:, None], T_world_actions)
        return points_world, state, T_world_ee, T_ee_actions, action_gripper.clamp(0.0, 1.0)

    @torch.inference_mode()
    def predict_action_chunk(self, batch: dict[str, Tensor], generator: torch.Generator | None = None,
                             num_inference_steps: int | None = None, initial_actions: Tensor | None = None,
                             **kwargs) -> Tensor:
        """``(B, T, 8)`` absolute world-frame EE targets (xyz, quaternion xyzw with ``w ≥ 0``, gripper 1/0).

        Each row uses the demonstrations of its ``batch["task"]`` (rows of one task are denoised together), or with
        ``config.context="language"`` the task said in words (:meth:`rows_context`), with ``num_inference_steps`` DDIM
        steps (K; None: ``config.inference_steps``); ``generator`` seeds the DDIM noise.
        With ``config.replay_init_strength`` the denoising starts from ``initial_actions (B, T, 8)`` (absolute
        world-frame actions in the same layout, a plan made elsewhere), or without them from the episode's replay
        plan at the current step (:meth:`replay_guess`); with ``config.samples_per_prediction`` > 1 each row is the
        mean of that many samples.
        """
        points_world, state = self._observation(batch)
        tasks = self._batch_tasks(batch, len(state))
        T_world_ee, gripper_open = poses_from_vectors_torch(state)
        gripper = (gripper_open > 0.5).to(state.dtype)
        steps = self.config.inference_steps if num_inference_steps is None else num_inference_steps
        guess = None
        if initial_actions is not None:
            if not self.config.replay_init_strength:
                raise ValueError("initial_actions are a denoising start: set replay_init_strength to use them")
            guess = self._in_ee_frame("initial_actions", initial_actions, T_world_ee)
        elif self.config.replay_init_strength:
            guess = self.replay_guess(points_world, T_world_ee, tasks)
        chunk = torch.empty(len(state), self.config.horizon, 8, dtype=state.dtype, device=state.device)
        for task in dict.fromkeys(tasks):
            rows = torch.tensor([row for row, name in enumerate(tasks) if name == task], device=state.device)
            context = self.rows_context(task, points_world[rows], T_world_ee[rows], gripper[rows])
            T_ee_actions, action_gripper = self.network.sample_actions(
                context, num_inference_steps=steps, generator=generator,
                initial=None if guess is None else guess[rows], strength=self.config.replay_init_strength or 1.0,
                num_samples=self.config.samples_per_prediction,
            )
            chunk[rows] = vectors_from_poses_torch(compose(T_world_ee[rows][:, None], T_ee_actions), action_gripper)
        return chunk

    def rows_context(self, task: str, points_world: Tensor, T_world_ee: Tensor,
                     gripper: Tensor) -> InstantPolicyContext:
        """The context of ``B`` rows of ``task`` at a control step, from their clouds ``points_world (B, P, 3)``, EE
        poses ``T_world_ee (B, 4, 4)`` and gripper states ``gripper (B,)`` (1 open): with ``config.context="language"``
        and no demonstrations of ``task`` handed in, the task said in words through the language head
        (:class:`~.language.task_language.TaskLanguage`); else its demonstrations (:meth:`task_context`)."""
        if self._language is not None and task not in self._demonstrations.tasks:
            return self._language.context(self.network, task, points_world, T_world_ee, gripper)
        task_context = self.task_context(task)
        count, waypoint_features = len(points_world), task_context.waypoint_features
        return self.network.encode_context(
            task_context.demos.expand(count), points_world, T_world_ee, gripper,
            demo_waypoint_features=waypoint_features.expand(count, *waypoint_features.shape[1:]),
        )

    @torch.inference_mode()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """The action ``(B, 8)`` to run now: the next of ``n_action_steps`` queued actions of the last prediction.

        With ``replan_on_gripper_change`` the rest of the queue is dropped after an action whose gripper command
        differs from the previous one (the observed state before the first action) in any row, so the next call
        predicts again from an observation taken after the gripper acted.
        """
        _, state = self._observation(batch)
        if self._queue and len(self._queue[0]) != len(state):
            raise ValueError(
                f"batch size changed from {len(self._queue[0])} to {len(state)} within an episode; call reset() "
                "between episodes"
            )
        if not self._queue:
            chunk = self.predict_action_chunk(batch, **kwargs)
            self._queue.extend(chunk[:, : self.config.n_action_steps].transpose(0, 1))
        action = self._queue.popleft()
        self._episode_step += 1
        previous = state[:, 7] if self._last_gripper is None or len(self._last_gripper) != len(state) else self._last_gripper
        if self.config.replan_on_gripper_change and bool(((action[:, 7] > 0.5) != (previous > 0.5)).any()):
            self._queue.clear()
        self._last_gripper = action[:, 7].clone()
        return action

    @torch.no_grad()
    def replay_guess(self, points_world: Tensor, T_world_ee: Tensor, tasks: list[str]) -> Tensor:
        """The denoising start of ``config.replay_init_strength``: the diffusion variable ``(B, T, 7)`` of each row's
        replay plan at the episode's current step, in the row's current EE frame.

        The plans (:func:`~.data.replay_plan.plan_replay` of each row's task demonstrations onto its cloud
        ``points_world (B, P, 3)``) are made at the episode's first prediction and kept until :meth:`reset`;
        ``T_world_ee (B, 4, 4)`` is the current EE pose. Planned action ``step + j`` is the guess for action ``j``."""
        if self._replay_plans is None or len(self._replay_plans) != len(tasks):
            clouds = points_world.detach().cpu().numpy()
            self._replay_plans = [
                plan_replay(task, self._demonstrations.get(task), cloud, REPLAY_REGISTRATION, self.config.replay_plan())
                for task, cloud in zip(tasks, clouds, strict=True)
            ]
        planned = np.stack([plan.actions_from(self._episode_step, self.config.horizon) for plan in self._replay_plans])
        return self._in_ee_frame("the replay plan", torch.from_numpy(planned), T_world_ee)

    # ------------------------------------------------------------------ checkpoints
    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, **kwargs) -> "InstantPolicyPolicy":
        """LeRobot's ``from_pretrained``, with strict key checking; the frozen encoder comes from the checkpoint's
        tensors, so no encoder weights file is read."""
        return super().from_pretrained(pretrained_name_or_path, load_encoder_weights=False, **kwargs)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        """Refuse a checkpoint whose tensors are not exactly the network's (LeRobot loads with strict=False)."""
        from safetensors import safe_open

        with safe_open(model_file, framework="pt") as handle:
            found = set(handle.keys())
        expected = set(model.state_dict())
        missing, unexpected = sorted(expected - found), sorted(found - expected)
        if missing or unexpected:
            raise CheckpointMismatchError(
                f"checkpoint {model_file} does not match its config: {len(missing)} missing tensors "
                f"{missing[:5]}, {len(unexpected)} unexpected tensors {unexpected[:5]}"
            )
        try:
            super()._load_as_safetensor(model, model_file, map_location, strict=True)
        except RuntimeError as error:
            raise CheckpointMismatchError(f"checkpoint {model_file} does not match its config: {error}") from error
        model.clear_context_caches()
        return model

    def clear_context_caches(self) -> None:
        """Forget what was computed with the previous weights: the training context's encoder outputs and frame
        encodings, and every task's encoded demonstrations (their waypoints and N, L are kept)."""
        self._context_encoder = None
        self._training_frame_encodings = None
        for task_context in self._task_contexts.values():
            task_context.demos = task_context.waypoint_features = task_context.weights_version = None

    # ------------------------------------------------------------------ training context
    def _read_training_bank(self, dataset_meta) -> ContextBank:
        shape = tuple(dataset_meta.features.get(POINTCLOUD_KEY, {}).get("shape", ()))
        if shape[:1] != (self.config.num_points,):
            raise ValueError(
                f"point clouds of the wrong size: the training dataset's {POINTCLOUD_KEY!r} has shape {shape}, "
                f"the policy expects ({self.config.num_points}, 3)"
            )
        # With frame encodings the bank needs no clouds: their scene nodes come from the cache.
        read_points = not self.config.cache_frame_encodings
        return ContextBank.from_dataset_meta(dataset_meta, self.config.num_waypoints, read_points=read_points)

    def training_context_encoder(self) -> ContextEncoder:
        """The training context: the training bank's waypoints with the frame encodings of its dataset (loaded from
        beside the dataset, or built there on first use, with ``cache_frame_encodings``)."""
        if self._context_encoder is None:
            if self._training_bank is None:
                raise RuntimeError(
                    "instant_policy training draws context demonstrations from the training dataset: build the policy "
                    "with dataset_meta (lerobot-train does) or call set_training_bank()"
                )
            encodings = self._training_frame_encodings
            if encodings is None and self.config.cache_frame_encodings and self._dataset_meta is not None:
                encodings = self._training_frame_encodings = self.frame_encodings(self._dataset_meta)
            self._context_encoder = ContextEncoder(self.network, self._training_bank, encodings)
        return self._context_encoder

    def frame_encodings(self, dataset_meta) -> FrameEncodings:
        """The frozen encoder's output for every frame of the dataset ``dataset_meta`` describes (its local ``root``),
        for the current encoder weights: loaded from beside the dataset, or built there once (minutes on a CPU)."""
        root, repo_id = dataset_meta.root, dataset_meta.repo_id
        encoder = self.network.geometry_encoder
        fingerprint = encoder_fingerprint(encoder, encoder.config.to_dict())
        encodings = load_frame_encodings(root, fingerprint)
        if encodings is None:
            logger.info("instant_policy: encoding every frame of %s once with the frozen encoder", root)
            encodings = build_frame_encodings(
                open_demo_dataset(repo_id, root), fingerprint, self._encode_frames, self._device()
            )
        return encodings

    def training_action_chunks(self) -> ActionChunks:
        """Every frame's action of the training dataset (read from ``dataset_meta`` when the policy was built)."""
        if self._action_chunks is None:
            raise RuntimeError(
                f"instant_policy training needs {ACTION_KEY!r} chunks of shape (B, horizon, 8): give them in the "
                "batch, or build the policy with dataset_meta (lerobot-train does) to read them by 'index'"
            )
        return self._action_chunks

    def set_training_bank(self, bank: ContextBank, frame_encodings: FrameEncodings | None = None) -> None:
        """Use ``bank`` for the training context (its waypoint count must be ``num_waypoints``), and
        ``frame_encodings`` of the dataset it was read from for its waypoints and the batches' frames (``index``)."""
        if bank.num_waypoints != self.config.num_waypoints:
            raise ValueError(f"the bank has L={bank.num_waypoints} waypoints, the config {self.config.num_waypoints}")
        if bank.num_points is not None and bank.num_points != self.config.num_points:
            raise ValueError(
                f"point clouds of the wrong size: the training dataset has {bank.num_points} points per cloud, the "
                f"policy expects {self.config.num_points}"
            )
        self._context_encoder = ContextEncoder(self.network, bank, frame_encodings)
        self._training_bank, self._training_frame_encodings = bank, frame_encodings

    # ------------------------------------------------------------------ inference context
    def set_demonstrations(self, demonstrations: list[Demonstration], num_waypoints: int | None = None) -> None:
        """Use ``demonstrations`` (N of them, all of one task) as that task's context, each reduced to
        ``num_waypoints`` (L; ``None``: the config's). Any N and L in the network's ranges
        (:mod:`~.model.bounds`: 1…8, 2…32) work without retraining."""
        check_range("the number of demonstrations N", len(demonstrations), SUPPORTED_DEMOS)
        check_range("num_waypoints (L)", num_waypoints or self.config.num_waypoints, SUPPORTED_WAYPOINTS)
        self._check_demonstrations(demonstrations)
        task = self._demonstrations.hand_in(demonstrations)
        self._task_contexts[task] = TaskContext(num_waypoints or self.config.num_waypoints, handed_in=True)
        self.task_context(task)
        self.reset()

    @torch.no_grad()
    def task_context(self, task: str) -> TaskContext:
        """The context of ``task`` with its tensors for the current weights: its demonstrations (handed in, or read
        from ``demo_repo_id`` on first use) through the training context's path, :class:`ContextEncoder`, and σ on
        their waypoints. Both depend on the weights and not on the live observation, so they are computed once per
        task and reused at every control step until the weights change (an optimizer step or a checkpoint load
        changes the parameters' versions)."""
        task_context = self._task_contexts.setdefault(task, TaskContext(self.config.num_waypoints, handed_in=False))
        if task_context.demos is not None and task_context.demos.T_world_ee.device != self._device():
            task_context.demos = None  # the policy moved to another device since
        if task_context.demos is None:
            demonstrations = self._demonstrations.get(task)
            self._check_demonstrations(demonstrations)
            bank = ContextBank.from_demonstrations(demonstrations, task_context.num_waypoints)
            task_context.demos = ContextEncoder(self.network, bank).demos(
                np.arange(len(demonstrations))[None], self._device()
            )
            logger.info("instant_policy: %d demonstrations of task %r encoded", len(demonstrations), task)
        version = tuple((p.device, p.dtype, p._version) for p in self.network.parameters())
        if task_context.waypoint_features is None or task_context.weights_version != version:
            task_context.waypoint_features = self.network.encode_demo_waypoints(task_context.demos)
            task_context.weights_version = version
        return task_context

    def _check_demonstrations(self, demonstrations: list[Demonstration]) -> None:
        for index, demo in enumerate(demonstrations):
            if demo.points_world.shape[1] != self.config.num_points:
                raise ValueError(
                    f"point clouds of the wrong size: demonstration {index} of {demo.task!r} has "
                    f"{demo.points_world.shape[1]} points per cloud, the policy expects {self.config.num_points}"
                )

    def _encode_frames(self, points_world: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        T_world_ee, _ = poses_from_vectors_torch(state)
        return self.network.encode_observation(points_world, T_world_ee)

    def _device(self) -> torch.device:
        return next(self.parameters()).device

    # ------------------------------------------------------------------ input checks
    def _observation(self, batch: dict[str, Tensor], cloud_required: bool = True) -> tuple[Tensor | None, Tensor]:
        """``points_world (B, P, 3)`` and ``state (B, 8)`` of ``batch``, checked: ``ValueError`` naming the problem.
        Without ``cloud_required`` a batch without ``observation.pointcloud`` gives ``points_world`` None."""
        required = (POINTCLOUD_KEY, STATE_KEY) if cloud_required or POINTCLOUD_KEY in batch else (STATE_KEY,)
        for key in required:
            if key not in batch:
                raise KeyError(f"instant_policy needs {key!r} in the batch, got keys {sorted(batch)}")
        state = batch[STATE_KEY]
        if state.ndim != 2 or state.shape[1] != 8:
            raise ValueError(f"{STATE_KEY!r} must have shape (B, 8), got {tuple(state.shape)}")
        if not torch.isfinite(state).all():
            raise ValueError(f"{STATE_KEY!r} contains NaN or infinite values")
        if POINTCLOUD_KEY not in required:
            return None, state.float()
        points = batch[POINTCLOUD_KEY]
        expected = (len(state), self.config.num_points, 3)
        if tuple(points.shape) != expected:
            raise ValueError(
                f"point clouds of the wrong size: {POINTCLOUD_KEY!r} must have shape (B, P, 3) = {expected}, got "
                f"{tuple(points.shape)}; resample each cloud to {self.config.num_points} points"
            )
        if not torch.isfinite(points).all():
            raise ValueError(f"{POINTCLOUD_KEY!r} contains NaN or infinite values")
        return points.float(), state.float()

    def _batch_tasks(self, batch: dict, batch_size: int) -> list[str]:
        """Each row's task: ``batch["task"]``, or without it the one task of the demonstrations (handed in, or the
        demonstration dataset's); a ``KeyError`` that says what to pass where there are several."""
        if self._language is None:
            return self._demonstrations.batch_tasks(batch.get("task"), batch_size)
        return batch_task_names(batch.get("task"), batch_size, "instant_policy with context='language'",
                                self._demonstrations.default_task, "; it says each row's task in words")


def _first_rows(ids: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The distinct values of ``ids (B,)``, each row's position among them ``(B,)`` and each value's first row."""
    unique, row_of_id = torch.unique(ids, return_inverse=True)
    rows = torch.arange(len(ids), device=ids.device)
    first = torch.full((len(unique),), len(ids), device=ids.device, dtype=rows.dtype).scatter_reduce(
        0, row_of_id, rows, reduce="amin")
    return unique, row_of_id, first


def _hold_padded(actions: Tensor, is_pad: Tensor | None) -> Tensor:
    """Replace padded actions ``(B, T, 8)`` (``is_pad (B, T)`` True past the episode's end) by the row's last real one."""
    if is_pad is None or not bool(is_pad.any()):
        return actions
    steps = torch.arange(actions.shape[1], device=actions.device).expand_as(is_pad)
    last_real = torch.where(is_pad, torch.zeros_like(steps), steps).amax(dim=1)
    held = actions.gather(1, last_real[:, None, None].expand(-1, actions.shape[1], actions.shape[2]))
    return torch.where(is_pad[..., None], held, actions)
