"""The shipped checkpoint predicts the same actions as when this reference was recorded (issue 13: refactors change no
behaviour). ``tests/data/shipped_actions.npz`` holds the inputs' seeds and the ``(B, T, 8)`` actions that
``predict_action_chunk`` gave for them; regenerate it only for a deliberate change of behaviour:
``python tests/test_shipped_actions.py`` (and say why in the commit)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_demos import make_demonstration, object_cloud, object_pose

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

REFERENCE = Path(__file__).parent / "data" / "shipped_actions.npz"
TASK = "reach_the_mug"

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def predict_reference_actions() -> np.ndarray:
    """Two demonstrations of a synthetic task, two live observations of it with the object moved, 4 DDIM steps
    from a seeded generator: ``(2, T, 8)`` world-frame actions of the shipped checkpoint."""
    policy = InstantPolicyPolicy.from_pretrained(SHIPPED_CHECKPOINT)
    demonstrations = [make_demonstration(object_pose(0.5, 0.0, 10.0), TASK, seed=1),
                      make_demonstration(object_pose(0.45, 0.1, -20.0), TASK, seed=2)]
    policy.set_demonstrations(demonstrations)
    live = [object_pose(0.55, -0.05, 30.0), object_pose(0.4, 0.05, 0.0)]
    states = np.stack([demonstrations[0].state[0], demonstrations[1].state[3]])
    batch = {
        POINTCLOUD_KEY: torch.from_numpy(np.stack([object_cloud(pose, seed=10 + i) for i, pose in enumerate(live)])),
        STATE_KEY: torch.from_numpy(states),
        "task": [TASK, TASK],
    }
    generator = torch.Generator().manual_seed(0)
    return policy.predict_action_chunk(batch, generator=generator).numpy()


def test_the_shipped_checkpoint_predicts_the_recorded_actions():
    recorded = np.load(REFERENCE)["actions"]
    actions = predict_reference_actions()
    assert actions.shape == recorded.shape
    # Positions within 1e-4 m, quaternions and gripper within 1e-4: float32 arithmetic in a different order may
    # move the last digits, a change of behaviour moves millimetres.
    np.testing.assert_allclose(actions, recorded, atol=1e-4, rtol=0)


if __name__ == "__main__":
    torch.set_num_threads(1)
    REFERENCE.parent.mkdir(exist_ok=True)
    np.savez(REFERENCE, actions=predict_reference_actions())
    print(f"wrote {REFERENCE}")
