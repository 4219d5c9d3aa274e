"""``InstantPolicyPolicy``: the Instant Policy network as a LeRobot policy (``--policy.type=instant_policy``).

Training (``lerobot-train``): :meth:`InstantPolicyPolicy.forward` is the network's loss on a batch assembled by
:mod:`.training.batches`: frames of the training dataset with N other episodes of their task from its context bank
(read when the policy is built with the training dataset's ``dataset_meta``, as ``lerobot-train`` does; the frozen
encoder's output for every frame is cached beside the dataset, :mod:`.training.frame_encodings`), or the pseudo-task
stream's and pool's batches, which carry their context. None of this is part of ``model.safetensors``.

Evaluation (``lerobot-eval``) and deployment: the demonstrations of each batch row's ``task`` come from the
dataset ``demo_repo_id`` at ``demo_root`` (``num_demos`` episodes), or from :meth:`set_demonstrations`. They take
the training context's path (a bank of their waypoints → :class:`~.training.context_encoder.ContextEncoder` →
:class:`DemoTensors`) once per task, and the result is reused at every control step. With ``context="language"`` a
task whose demonstrations were not handed in is said in words instead: its ``task`` string through the language head
(:mod:`.language.task_language`).

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
    checked_observation,
    poses_from_vectors_torch,
    vectors_from_poses_torch,
)
from .data.context_bank import ContextBank
from .data.demonstrations import Demonstration, DemonstrationSource, batch_task_names
from .geometry.rigid_torch import compose
from .language.task_language import TaskLanguage
from .model.bounds import SUPPORTED_DEMOS, SUPPORTED_WAYPOINTS, check_range
from .model.instant_policy_network import DemoTensors, InstantPolicyContext, InstantPolicyNetwork
from .model.occupancy import load_encoder_weights
from .replay.plan import ReplayPlan
from .replay.priors import plan_onto_live, plan_onto_live_trusted, replay_priors
from .replay.trust import trusted_strength
from .training.batches import TrainingData, planned_in_ee_frame, training_batch
from .training.context_encoder import ContextEncoder
from .training.frame_encodings import FrameEncodings

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
        # the training dataset's bank, action table and frame encodings (training.batches), when built with one
        self.training_data: TrainingData | None = None
        self._task_contexts: dict[str, TaskContext] = {}
        if config.pretrained_encoder and load_encoder_weights:
            self.load_encoder_weights(config.encoder_weights_path())
        if isinstance(dataset_meta, LeRobotDatasetMetadata):
            self.training_data = TrainingData.from_dataset_meta(self.network, dataset_meta,
                                                                config.cache_frame_encodings)
        self._queue: deque[Tensor] = deque()
        self._last_gripper: Tensor | None = None
        self._replay_plans: list[ReplayPlan] | None = None
        self._replay_strengths: list[float | None] | None = None
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
        self._replay_strengths = None
        self._episode_step = 0

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Training loss of a batch from the training dataset, the pseudo-task stream or the encoded task pool.

        Args:
            batch: ``observation.pointcloud (B, P, 3)`` and ``observation.state (B, 8)`` in the world frame, the
                actions (``action (B, T, 8)``, or each row's own ``action (B, 8)`` with ``index (B,)``) and the
                context: carried as clouds (the pseudo-task stream's), carried encoded (the task pool's), or drawn
                from the training dataset by ``episode_index (B,)``; with ``config.refine_fraction`` > 0 also
                ``observation.replay_prior (B, T, 8)``. Assembled and checked by
                :func:`~.training.batches.training_batch`.

        Returns:
            The loss (sum of the parts) and ``{"translation", "rotation", "gripper", "num_demos"}`` as floats, and
            ``"refined"``, the share of refined rows, when training to refine.
        """
        drawn = training_batch(batch, self.config, self.network, self.training_data)
        targets = drawn.targets
        context = self.network.encode_context(drawn.demos, targets.points_world, targets.T_world_ee, drawn.gripper,
                                              scene_geometry=drawn.scene_geometry)
        losses = self.network.training_loss(context, targets.T_ee_actions, targets.action_gripper, prior=drawn.prior,
                                            refined_rows=drawn.refined_rows)
        parts = {name: float(losses[name].detach()) for name in ("translation", "rotation", "gripper")}
        if drawn.refined_rows is not None:
            parts["refined"] = float(drawn.refined_rows.float().mean())
        return losses["loss"], {**parts, "num_demos": float(drawn.num_demos)}

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
        plan at the current step (:meth:`replay_guess`), noised to the strength its trust gives with
        ``config.replay_trust_m`` (a row trusted not at all starts from noise, as the paper's); with
        ``config.samples_per_prediction`` > 1 each row is the mean of that many samples.
        """
        points_world, state = self._observation(batch)
        tasks = self._batch_tasks(batch, len(state))
        T_world_ee, gripper_open = poses_from_vectors_torch(state)
        gripper = (gripper_open > 0.5).to(state.dtype)
        steps = self.config.inference_steps if num_inference_steps is None else num_inference_steps
        guess, strengths = None, [self.config.replay_init_strength or 1.0] * len(state)
        if initial_actions is not None:
            if not self.config.replay_init_strength:
                raise ValueError("initial_actions are a denoising start: set replay_init_strength to use them")
            guess = self._planned_variable("initial_actions", initial_actions, T_world_ee)
        elif self.config.replay_init_strength:
            guess = self.replay_guess(points_world, T_world_ee, tasks)
            strengths = self._replay_strengths
        chunk = torch.empty(len(state), self.config.horizon, 8, dtype=state.dtype, device=state.device)
        for task, strength in dict.fromkeys(zip(tasks, strengths, strict=True)):
            rows = torch.tensor([row for row, name in enumerate(tasks) if (name, strengths[row]) == (task, strength)],
                                device=state.device)
            context = self.rows_context(task, points_world[rows], T_world_ee[rows], gripper[rows])
            start = None if guess is None or strength is None else guess[rows]
            T_ee_actions, action_gripper = self.network.sample_actions(
                context, num_inference_steps=steps, generator=generator,
                initial=start, strength=1.0 if start is None else strength,
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

        The plans (:func:`~.replay.priors.plan_onto_live` of each row's task demonstrations onto its cloud
        ``points_world (B, P, 3)``) are made at the episode's first prediction and kept until :meth:`reset`;
        ``T_world_ee (B, 4, 4)`` is the current EE pose. The robot has followed the plan, so its control step is its
        plan step: the guess for action ``j`` is planned action ``step + j`` (:func:`~.replay.priors.replay_priors`).
        Each row's start strength is kept beside its plan: ``config.replay_init_strength``, or with
        ``config.replay_trust_m`` the plan's :func:`~.replay.trust.trusted_strength`, None where it rises to 1 (the
        row starts from noise)."""
        if self._replay_plans is None or len(self._replay_plans) != len(tasks):
            clouds = points_world.detach().cpu().numpy()
            plan, trust_range = self.config.replay_plan(), self.config.replay_trust_m
            self._replay_plans, self._replay_strengths = [], []
            for task, cloud in zip(tasks, clouds, strict=True):
                demonstrations = self._demonstrations.get(task)
                if trust_range is None:
                    replay = plan_onto_live(task, demonstrations, cloud, plan)
                    strength = self.config.replay_init_strength
                else:
                    replay, trust = plan_onto_live_trusted(task, demonstrations, cloud, plan)
                    strength = trusted_strength(trust, self.config.replay_init_strength, trust_range)
                    strength = None if strength >= 1.0 else strength
                self._replay_plans.append(replay)
                self._replay_strengths.append(strength)
        step = np.array([self._episode_step])
        planned = np.concatenate([replay_priors(plan, step, self.config.horizon) for plan in self._replay_plans])
        return self._planned_variable("the replay plan", torch.from_numpy(planned), T_world_ee)

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
        if self.training_data is not None:
            self.training_data.forget_encodings()
        for task_context in self._task_contexts.values():
            task_context.demos = task_context.waypoint_features = task_context.weights_version = None

    # ------------------------------------------------------------------ training context
    def set_training_bank(self, bank: ContextBank, frame_encodings: FrameEncodings | None = None) -> None:
        """Use ``bank`` for the training context (its waypoint count must be ``num_waypoints``), and
        ``frame_encodings`` of the dataset it was read from for its waypoints and the batches' frames (``index``);
        the action table read from ``dataset_meta``, if any, is kept."""
        if bank.num_waypoints != self.config.num_waypoints:
            raise ValueError(f"the bank has L={bank.num_waypoints} waypoints, the config {self.config.num_waypoints}")
        if bank.num_points is not None and bank.num_points != self.config.num_points:
            raise ValueError(
                f"point clouds of the wrong size: the training dataset has {bank.num_points} points per cloud, the "
                f"policy expects {self.config.num_points}"
            )
        chunks = None if self.training_data is None else self.training_data.action_chunks
        training_data = TrainingData(self.network, bank, chunks, frame_encodings)
        training_data.context_encoder()  # refuses pieces that do not fit before the policy takes them
        self.training_data = training_data

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

    def _planned_variable(self, name: str, planned: Tensor, T_world_ee: Tensor) -> Tensor:
        return planned_in_ee_frame(name, planned, T_world_ee, self.config.horizon, self.network.diffusion)

    def _device(self) -> torch.device:
        return next(self.parameters()).device

    # ------------------------------------------------------------------ input checks
    def _observation(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        return checked_observation(batch, self.config.num_points)

    def _batch_tasks(self, batch: dict, batch_size: int) -> list[str]:
        """Each row's task: ``batch["task"]``, or without it the one task of the demonstrations (handed in, or the
        demonstration dataset's); a ``KeyError`` that says what to pass where there are several."""
        if self._language is None:
            return self._demonstrations.batch_tasks(batch.get("task"), batch_size)
        return batch_task_names(batch.get("task"), batch_size, "instant_policy with context='language'",
                                self._demonstrations.default_task, "; it says each row's task in words")

