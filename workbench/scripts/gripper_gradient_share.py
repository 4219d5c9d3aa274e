"""Gradient norm of each loss term on φ (context network) and ψ (action network and heads) of a freshly initialised
small network: translation and rotation flows, the old gripper term (squared error of the head's output against the
clean command ±1, weight 1) and the new one (``gripper_loss_weight`` × cross-entropy of the head's logit), all from
the same forward pass (same frames, context, timesteps and noise). Prints JSON: medians over batches.

Usage: python workbench/scripts/gripper_gradient_share.py DATASET_ROOT REPO_ID [BATCHES]
"""

import json
import statistics
import sys

import torch
from lerobot.datasets import LeRobotDataset, LeRobotDatasetMetadata

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.batches import training_targets

root, repo_id = sys.argv[1], sys.argv[2]
batches = int(sys.argv[3]) if len(sys.argv) > 3 else 8
torch.manual_seed(0)
config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, max_demos=2)
meta = LeRobotDatasetMetadata(repo_id, root=root)
policy = InstantPolicyPolicy(config, dataset_meta=meta).train()
dataset = LeRobotDataset(repo_id, root=root, delta_timestamps={"action": [i / meta.fps for i in range(8)]})
loader = torch.utils.data.DataLoader(dataset, batch_size=16, shuffle=True, generator=torch.Generator().manual_seed(0))
network = policy.network
groups = {
    "phi": list(network.context_network.parameters()),
    "psi": [p for module in (network.action_network, network.translation_head, network.rotation_head,
                             network.gripper_head) for p in module.parameters()],
}
captured = {}
denoise, training_loss = network.denoise, network.training_loss
network.denoise = lambda *args, **kwargs: captured.setdefault("prediction", denoise(*args, **kwargs))
network.training_loss = lambda *args, **kwargs: captured.setdefault("losses", training_loss(*args, **kwargs))
norms: dict[str, dict[str, list[float]]] = {}
for _, batch in zip(range(batches), loader):
    captured.clear()
    policy.forward(batch)
    logit = captured["prediction"][..., 6]
    targets = training_targets(batch, config.horizon, config.num_points, policy.training_data)
    gripper_open = targets.action_gripper[:, :, None].expand_as(logit)
    terms = {
        "translation": captured["losses"]["translation"],
        "rotation": captured["losses"]["rotation"],
        "gripper_old_mse": torch.nn.functional.mse_loss(logit, 2 * gripper_open - 1),
        "gripper_new_weighted_bce": config.gripper_loss_weight * captured["losses"]["gripper"],
    }
    for term, value in terms.items():
        for group, parameters in groups.items():
            grads = torch.autograd.grad(value, parameters, retain_graph=True, allow_unused=True)
            norm = float(torch.sqrt(sum(g.square().sum() for g in grads if g is not None)))
            norms.setdefault(term, {}).setdefault(group, []).append(norm)
result = {term: {group: round(statistics.median(values), 4) for group, values in by_group.items()}
          for term, by_group in norms.items()}
for group in groups:
    flow = max(result["translation"][group], result["rotation"][group])
    result[f"{group}_gripper_over_largest_flow"] = {
        "old": round(result["gripper_old_mse"][group] / flow, 2),
        "new": round(result["gripper_new_weighted_bce"][group] / flow, 2),
    }
print(json.dumps({"dataset": str(root), "batches": batches, "batch_size": 16, "medians": result}, indent=2))
