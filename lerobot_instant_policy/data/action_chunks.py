"""Every frame's action of a training dataset, read once, for the ``T``-step action chunks of training rows.

A training row at global frame ``index`` ``i`` of an episode needs the actions ``i … i + T − 1``; past the episode's
last frame the last action is held (the EE holds still), as LeRobot's delta timestamps give them with
``action_is_pad``. LeRobot 0.6 answers a delta-timestamp query by formatting every column of the ``T`` queried rows,
the 2,048-point clouds included: about 30 ms per training row on the 2-core CPU, so data loading, not the network,
set the training speed. The policy therefore asks LeRobot for the current frame only
(``InstantPolicyConfig.action_delta_indices`` is None) and reads the chunks here: one vectorised lookup per batch in
a table of ``F × 8`` floats (1.7 MB for 54,000 frames).
"""

from __future__ import annotations

import numpy as np

from ..contract import ACTION_KEY
from .demonstrations import DemonstrationError, open_demo_dataset


class ActionChunks:
    """The action column of a dataset, by global frame ``index``.

    Args:
        index: ``(F,)`` the frames' global indices (unique).
        episode_index: ``(F,)`` the frames' episodes; an episode's frames must have consecutive indices.
        action: ``(F, A)`` the frames' actions.
    """

    def __init__(self, index: np.ndarray, episode_index: np.ndarray, action: np.ndarray):
        index = np.asarray(index, dtype=np.int64)
        episode_index = np.asarray(episode_index, dtype=np.int64)
        action = np.asarray(action, dtype=np.float32)
        if not (len(index) == len(episode_index) == len(action)) or action.ndim != 2 or len(index) == 0:
            raise DemonstrationError(
                f"action chunks need F ≥ 1 frames with index (F,), episode_index (F,) and action (F, A), got "
                f"{index.shape}, {episode_index.shape} and {action.shape}"
            )
        if not np.isfinite(action).all():
            raise DemonstrationError(f"{ACTION_KEY!r} contains NaN or infinite values")
        order = np.argsort(index, kind="stable")
        index, episode_index, self.action = index[order], episode_index[order], action[order]
        if index[0] < 0 or np.any(np.diff(index) != 1):
            raise DemonstrationError("frame indices must be unique, consecutive and non-negative")
        starts = np.flatnonzero(np.r_[True, episode_index[1:] != episode_index[:-1]])
        if len(np.unique(episode_index[starts])) != len(starts):
            raise DemonstrationError("an episode's frames must have consecutive indices")
        self.first_index = int(index[0])
        ends = np.r_[starts[1:], len(index)] - 1
        self._last_row = np.repeat(ends, np.diff(np.r_[starts, len(index)]))  # (F,) last row of each row's episode

    @classmethod
    def from_dataset(cls, repo_id: str, root) -> ActionChunks:
        """The action table of the LeRobotDataset at ``root`` (read offline; three columns, no clouds)."""
        dataset = open_demo_dataset(repo_id, root)
        frames = dataset.hf_dataset.with_format("numpy", columns=["index", "episode_index", ACTION_KEY])[:]
        return cls(frames["index"], frames["episode_index"], frames[ACTION_KEY])

    def __len__(self) -> int:
        return len(self.action)

    def chunks(self, indices, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """The actions of frames ``indices (B,)`` and the ``horizon − 1`` after each.

        Returns:
            ``actions (B, T, A)`` float32, held at the episode's last action past its end, and ``is_pad (B, T)``,
            True where an action was held.
        """
        rows = np.asarray(indices, dtype=np.int64).reshape(-1) - self.first_index
        if len(rows) and (rows.min() < 0 or rows.max() >= len(self)):
            raise IndexError(
                f"frame indices {np.asarray(indices).reshape(-1).tolist()} are outside the dataset's "
                f"{self.first_index}…{self.first_index + len(self) - 1}"
            )
        steps = rows[:, None] + np.arange(horizon)
        last = self._last_row[rows][:, None]
        return self.action[np.minimum(steps, last)], steps > last
