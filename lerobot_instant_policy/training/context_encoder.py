"""The one way from demonstrations to the network, for training and inference alike (docs/design.md §6).

A :class:`~.data.context_bank.ContextBank` holds waypoint data only: poses, gripper states, world-frame clouds or the
waypoint frames' dataset ``index``. A :class:`ContextEncoder` turns the waypoints of chosen episodes into the
network's :class:`~.model.instant_policy_network.DemoTensors`. It owns

- the frozen encoder's view of every waypoint: each cloud in its own EE frame through
  :meth:`~.model.instant_policy_network.InstantPolicyNetwork.encode_observation`, the same call that fills the
  training dataset's per-frame cache (:mod:`.frame_encodings`);
- the frozen encoder's cache: with frame encodings of the bank's dataset, the waypoints' scene nodes are read from
  them by dataset ``index``; without, each episode is encoded on first use and kept;
- the assembly of the tensors on the network's device.

Training draws ``(B, N)`` context episodes from the training dataset's bank per batch; inference builds a bank of
one task's demonstrations and takes all of them, ``(1, N)``, once per task.
"""

from __future__ import annotations

import numpy as np
import torch

from ..data.context_bank import ContextBank
from ..model.instant_policy_network import DemoTensors, InstantPolicyNetwork
from .frame_encodings import FrameEncodings

# Episodes per frozen-encoder call when waypoints are encoded without frame encodings (L clouds each).
ENCODE_CHUNK_EPISODES = 4


class ContextEncoder:
    """Waypoints of a :class:`ContextBank` → :class:`DemoTensors` for ``network``.

    Args:
        network: the network whose frozen encoder makes the scene nodes.
        bank: the waypoint data.
        frame_encodings: the frozen encoder's output for every frame of the dataset ``bank`` was read from (then
            the bank needs no clouds); None encodes the bank's waypoint clouds, each episode once.
    """

    def __init__(self, network: InstantPolicyNetwork, bank: ContextBank,
                 frame_encodings: FrameEncodings | None = None):
        if frame_encodings is not None and not bank.has_dataset_indices:
            raise ValueError("frame encodings need a bank read from their dataset (ContextBank.from_dataset)")
        if frame_encodings is None and bank.points_world is None:
            raise ValueError("this context bank was read without its clouds: give the frame encodings of its dataset")
        self.network, self.bank, self.frame_encodings = network, bank, frame_encodings
        self._encoded: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def demos(self, episodes: np.ndarray, device: torch.device | str) -> DemoTensors:
        """The waypoints of the context episodes ``episodes (B, N)`` as float32 tensors on ``device``."""
        episodes = np.asarray(episodes, dtype=np.int64)
        if episodes.ndim != 2:
            raise ValueError(f"context episodes must have shape (B, N), got {episodes.shape}")
        arrays = self.bank.gather(episodes)
        positions, features = self._scene_nodes(episodes, device)
        return DemoTensors(
            T_world_ee=torch.from_numpy(arrays.T_world_ee).to(device),
            gripper_open=torch.from_numpy(arrays.gripper_open).to(device),
            scene_positions=positions,
            scene_features=features,
        )

    def frames(self, indices: np.ndarray, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Scene nodes of the dataset frames ``indices (B,)`` (a training batch's current frames) from the frame
        encodings, ``(B, M, 3)`` and ``(B, M, D)``; None without frame encodings (the network then encodes them)."""
        return None if self.frame_encodings is None else self.frame_encodings.lookup(indices, device)

    def clear(self) -> None:
        """Forget the episodes encoded with the previous encoder weights (a checkpoint was loaded)."""
        self._encoded.clear()

    def _scene_nodes(self, episodes: np.ndarray, device) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions ``(B, N, L, M, 3)`` and features ``(B, N, L, M, D)`` of the waypoints of ``episodes (B, N)``."""
        if self.frame_encodings is not None:
            return self.frame_encodings.lookup(self.bank.dataset_indices(episodes), device)
        wanted = list(dict.fromkeys(episodes.reshape(-1).tolist()))
        missing = [episode for episode in wanted if episode not in self._encoded]
        for start in range(0, len(missing), ENCODE_CHUNK_EPISODES):
            chunk = np.array(missing[start : start + ENCODE_CHUNK_EPISODES])
            arrays = self.bank.gather(chunk)
            positions, features = self.network.encode_observation(
                torch.from_numpy(arrays.points_world).to(device), torch.from_numpy(arrays.T_world_ee).to(device)
            )
            for episode, episode_positions, episode_features in zip(chunk.tolist(), positions, features):
                self._encoded[episode] = (episode_positions, episode_features)
        flat = episodes.reshape(-1).tolist()
        positions = torch.stack([self._encoded[episode][0] for episode in flat]).to(device)
        features = torch.stack([self._encoded[episode][1] for episode in flat]).to(device)
        return positions.view(*episodes.shape, *positions.shape[1:]), features.view(*episodes.shape, *features.shape[1:])
