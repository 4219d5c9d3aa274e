"""The training curve of an ``instant_policy`` run: each checkpoint's training loss on fixed frames of a dataset.

``lerobot-train --save_freq=S`` writes ``OUTPUT_DIR/checkpoints/<step, 6 digits>/pretrained_model``. For each of
them, :func:`evaluate_loss` computes ``InstantPolicyPolicy.forward``'s loss (translation + rotation flow + gripper,
each a mean squared error in the model's normalised units) in eval mode without gradients, on a fixed, seeded sample
of frames of a pseudo-demonstration dataset loaded as ``lerobot-train`` loads it (the policy's delta timestamps, the
checkpoint's preprocessor) with that dataset as the context bank. Everything random in ``forward`` (diffusion
timesteps and noise, the number N of context demonstrations and which episodes, gripper flips) is drawn from a torch
RNG seeded the same way for every checkpoint, so two checkpoints are compared on the same frames and the same noise.

On the training dataset this is the training loss; on a dataset of held-out pseudo-tasks (objects of the library's
held-out split) it is the validation loss. Two references tell whether the network reads its demonstrations:

- the **context swap** (``evaluate_loss(..., swap_context=True)``): the same frames, timesteps, noise and N, with the
  context drawn from the next pseudo-task's episodes (``ContextBank.with_swapped_contexts``); swap loss / own loss is
  the context gain, about 1 for a network that ignores its context;
- the **prior-only** level (:func:`prior_only_loss`): the translation and rotation losses of the best denoiser that
  knows only the statistics of the actions (a Gaussian prior per normalised action coordinate and horizon step, its
  mean and variance from the evaluated frames), not the observation nor the demonstrations. :class:`LossCurveCache` keeps per-checkpoint results in a JSON file, valid
only for the same sample settings and the same datasets, and :func:`draw_loss_curve` plots them. :func:`loss_curve`
does it all for a run (``lerobot-ip-loss-curve``): it evaluates the checkpoints not yet in the cache and draws the
picture.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from dataclasses import asdict, dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from ..contract import ACTION_KEY
from ..data.context_bank import ContextBank
from ..data.demonstrations import check_dataset_features
from ..modeling_instant_policy import InstantPolicyPolicy
from ..pseudo_demos.generation import DEMOS_FILE, TASKS_FILE
from ..training.batches import dataset_frame_encodings, training_targets
from .checkpoints import (
    Checkpoint,
    EvaluationError,
    checkpoint_config,
    find_checkpoints,
    load_checkpoint,
    weights_fingerprint,
)

LOSS_PARTS = ("loss", "translation", "rotation", "gripper")
CACHE_FORMAT = 2
#: Legend label of each curve of :func:`loss_curve`: the training set, the held-out set, and the held-out set with
#: swapped contexts.
CURVE_LABELS = {"train": "training", "val": "validation (held-out)", "val_swap": "held-out, swapped context"}


@dataclass(frozen=True)
class LossEstimate:
    """Mean loss and parts over ``samples`` frames (batch means weighted by batch size)."""

    loss: float
    translation: float
    rotation: float
    gripper: float
    samples: int


class EvaluationSet:
    """A fixed sample of frames of one pseudo-demonstration dataset (build it with :func:`load_evaluation_set`).

    ``indices (S,)``: the frames, sorted. ``dataset`` (a ``LeRobotDataset`` with the policy's delta timestamps) and
    ``bank`` (its episodes' context waypoints, without clouds) are loaded on first use, so a run whose checkpoints are
    all cached reads only the metadata. The frozen encoder's output for its frames comes from frame encodings stored
    beside the dataset (:mod:`..frame_encodings`, built on first use for each encoder), as in training.
    """

    def __init__(self, name: str, repo_id: str, meta, config, indices: np.ndarray):
        self.name, self.repo_id, self.root, self.meta, self.config = name, repo_id, Path(meta.root), meta, config
        self.indices = indices
        self.fingerprint = pseudo_demo_digest(self.root)

    @cached_property
    def dataset(self):
        from lerobot.datasets import LeRobotDataset

        # The policy's action chunks as LeRobot's delta timestamps give them (few rows here, so their cost is moot).
        delta_timestamps = {ACTION_KEY: [step / self.meta.fps for step in range(self.config.horizon)]}
        return LeRobotDataset(self.repo_id, root=self.root, delta_timestamps=delta_timestamps)

    @cached_property
    def bank(self) -> ContextBank:
        return ContextBank.from_dataset_meta(self.meta, self.config.num_waypoints, read_points=False)

    def describe(self) -> dict:
        """Root, content fingerprint and sizes (episodes, pseudo-tasks, frames, sampled frames)."""
        return {"root": str(self.root), "fingerprint": self.fingerprint, "episodes": self.meta.total_episodes,
                "tasks": self.meta.total_tasks, "frames": self.meta.total_frames, "samples": len(self.indices)}


# ---------------------------------------------------------------------------------------------------- datasets
def check_pseudo_demo_root(root: str | Path) -> Path:
    """``root`` if it holds a pseudo-demonstration dataset written by ``lerobot-ip-generate`` (a LeRobotDataset with
    ``meta/pseudo_tasks.jsonl`` and ``meta/pseudo_demos.jsonl``), else ``EvaluationError`` saying what is missing."""
    root = Path(root)
    if not root.is_dir():
        raise EvaluationError(f"dataset root {root} does not exist")
    missing = [name for name in ("info.json", TASKS_FILE, DEMOS_FILE) if not (root / "meta" / name).is_file()]
    if missing:
        raise EvaluationError(
            f"{root} is not a pseudo-demonstration dataset (written by lerobot-ip-generate): meta/ lacks {missing}"
        )
    return root


def pseudo_demo_digest(root: Path) -> str:
    """SHA-256 of the dataset's ``meta/info.json``, ``pseudo_tasks.jsonl`` and ``pseudo_demos.jsonl``: the same
    content wherever the dataset lies, different for a regenerated or resized dataset."""
    digest = hashlib.sha256()
    for name in ("info.json", TASKS_FILE, DEMOS_FILE):
        digest.update((root / "meta" / name).read_bytes())
    return digest.hexdigest()


def load_evaluation_set(name: str, root: str | Path, config, samples: int, seed: int,
                        repo_id: str | None = None) -> EvaluationSet:
    """``samples`` frames (all when the dataset has fewer) drawn without replacement with ``seed`` from the
    pseudo-demonstration dataset at ``root`` (repo id ``local/<root name>`` unless given), for policies with the
    ``InstantPolicyConfig`` ``config`` (its horizon and number of waypoints). ``EvaluationError`` or
    ``DemonstrationError`` when ``root`` is missing, not a pseudo-demonstration dataset or outside the data contract.
    """
    from lerobot.datasets import LeRobotDatasetMetadata

    if samples < 1:
        raise EvaluationError(f"samples must be at least 1, got {samples}")
    root = check_pseudo_demo_root(root)
    repo_id = repo_id or f"local/{root.name}"
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    check_dataset_features(meta.features, root)
    rng = np.random.default_rng(seed)
    indices = np.sort(rng.choice(meta.total_frames, size=min(samples, meta.total_frames), replace=False))
    return EvaluationSet(name, repo_id, meta, config, indices)


# ---------------------------------------------------------------------------------------------------- evaluation
def _loader(evaluation: EvaluationSet, batch_size: int):
    return torch.utils.data.DataLoader(
        torch.utils.data.Subset(evaluation.dataset, evaluation.indices.tolist()), batch_size=batch_size,
        shuffle=False, num_workers=0,
    )


@torch.no_grad()
def evaluate_loss(policy: InstantPolicyPolicy, preprocessor, evaluation: EvaluationSet, batch_size: int = 16,
                  seed: int = 0, swap_context: bool = False) -> LossEstimate:
    """The mean of ``policy.forward``'s loss and parts over ``evaluation``'s frames, in batches of ``batch_size``.

    The policy's training bank becomes ``evaluation.bank``, with the frame encodings of ``evaluation``'s dataset for
    the policy's encoder (``training.batches.dataset_frame_encodings``: loaded from beside the dataset, built there once). Torch's RNG is seeded with ``seed`` inside ``torch.random.fork_rng``, so the
    caller's RNG state is untouched and every call with the same frames, ``batch_size`` and ``seed`` draws the same
    timesteps, noise, context episodes and gripper flips. With ``swap_context`` every frame's context comes from the
    next pseudo-task instead of its own (everything else drawn the same). The policy is left in the mode it was in.
    """
    if batch_size < 1:
        raise EvaluationError(f"batch_size must be at least 1, got {batch_size}")
    bank = evaluation.bank.with_swapped_contexts() if swap_context else evaluation.bank
    policy.set_training_bank(bank, dataset_frame_encodings(policy.network, evaluation.meta))
    loader = _loader(evaluation, batch_size)
    device = next(policy.parameters()).device
    sums = dict.fromkeys(LOSS_PARTS, 0.0)
    was_training = policy.training
    policy.eval()
    try:
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            torch.manual_seed(seed)
            for batch in loader:
                count = len(batch["episode_index"])
                loss, parts = policy.forward(preprocessor(batch))
                sums["loss"] += float(loss) * count
                for part in LOSS_PARTS[1:]:
                    sums[part] += parts[part] * count
    finally:
        policy.train(was_training)
    total = len(evaluation.indices)
    means = {part: value / total for part, value in sums.items()}
    if not all(math.isfinite(value) for value in means.values()):
        raise EvaluationError(f"non-finite loss on {evaluation.name} frames: {means}")
    return LossEstimate(**means, samples=total)


@torch.no_grad()
def prior_only_loss(policy: InstantPolicyPolicy, preprocessor, evaluation: EvaluationSet, batch_size: int = 16,
                    seed: int = 0) -> dict[str, float]:
    """Translation and rotation losses of the prior-only denoiser on ``evaluation``'s frames (module docstring).

    With ``x₀ (S, T, 7)`` the clean normalised actions of the S frames, ``μ``, ``s²`` their mean and variance per
    horizon step and coordinate, and ``x_t = √ᾱ x₀ + √(1−ᾱ) ε`` at a uniform timestep, the prior-only prediction is the
    Gaussian posterior mean ``x̂₀ = μ + √ᾱ s² (x_t − √ᾱ μ) / (ᾱ s² + 1 − ᾱ)``; its flows are scored as the network's.
    The timesteps and noise come from a torch RNG seeded with ``seed`` (the caller's RNG untouched).
    """
    diffusion = policy.network.diffusion
    clean = []
    for batch in _loader(evaluation, batch_size):
        targets = training_targets(preprocessor(batch), policy.config.horizon, policy.config.num_points,
                                   policy.training_data)
        clean.append(diffusion.normalize(targets.T_ee_actions.double(), targets.action_gripper.double()))
    x0 = torch.cat(clean)
    mean, variance = x0.mean(dim=0), x0.var(dim=0, unbiased=False)
    with torch.random.fork_rng(devices=[]):  # drawn on the CPU: the same figure on every device
        torch.manual_seed(seed)
        timesteps = torch.randint(0, diffusion.num_train_timesteps, (len(x0),))
        noise = torch.randn(x0.shape, dtype=x0.dtype)
    timesteps, noise = timesteps.to(x0.device), noise.to(x0.device)
    x_t = diffusion.add_noise(x0, noise, timesteps)
    alpha_bar = diffusion.train_scheduler.alphas_cumprod.to(x0.device, x0.dtype)[timesteps][:, None, None]
    gain = alpha_bar.sqrt() * variance / (alpha_bar * variance + 1.0 - alpha_bar)
    x0_prior = mean + gain * (x_t - alpha_bar.sqrt() * mean)
    T_noisy, _ = diffusion.unnormalize(x_t)
    target = diffusion.flow_targets(diffusion.unnormalize(x0)[0], T_noisy)
    predicted = diffusion.flow_targets(diffusion.unnormalize(x0_prior)[0], T_noisy)
    return {
        "translation": float(torch.nn.functional.mse_loss(predicted[..., :3], target[..., :3])),
        "rotation": float(torch.nn.functional.mse_loss(predicted[..., 3:6], target[..., 3:6])),
        "samples": len(x0),
    }


# ---------------------------------------------------------------------------------------------------- cache
class LossCurveCache:
    """Per-checkpoint results in a JSON file, valid for one ``settings`` dict (samples, batch size, seed) and one
    ``datasets`` description (``name → EvaluationSet.describe()`` minus the root): a file written with other settings
    or other datasets starts empty. A checkpoint's entry is reused only while its weights' SHA-256 is the same."""

    def __init__(self, path: str | Path, settings: dict, datasets: dict[str, dict]):
        self.path = Path(path)
        self.header = {"format": CACHE_FORMAT, "settings": settings,
                       "datasets": {name: _cache_key(description) for name, description in datasets.items()}}
        self.descriptions = datasets
        self.entries: dict[int, dict] = {}
        self.prior: dict | None = None  # the prior-only level on the held-out frames (depends on the data only)
        self.discarded = False
        if self.path.is_file():
            try:
                stored = json.loads(self.path.read_text())
            except json.JSONDecodeError:
                stored = {}
            if {key: stored.get(key) for key in self.header} == self.header:
                self.entries = {int(entry["step"]): entry for entry in stored.get("checkpoints", [])}
                self.prior = stored.get("prior_only")
            else:
                self.discarded = True

    def get(self, step: int, weights: str) -> dict | None:
        entry = self.entries.get(step)
        return entry if entry is not None and entry.get("weights") == weights else None

    def put(self, step: int, weights: str, results: dict[str, LossEstimate]) -> dict:
        entry = {"step": step, "weights": weights, **{name: asdict(result) for name, result in results.items()}}
        self.entries[step] = entry
        return entry

    def save(self, steps: list[int]) -> None:
        """Write the entries of ``steps`` (atomically: a killed run never leaves half a file)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        document = {**self.header, "dataset_details": self.descriptions, "prior_only": self.prior,
                    "checkpoints": [self.entries[step] for step in sorted(steps) if step in self.entries]}
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text(json.dumps(document, indent=2))
        os.replace(temporary, self.path)


def _cache_key(description: dict) -> dict:
    return {key: value for key, value in description.items() if key != "root"}


# ---------------------------------------------------------------------------------------------------- picture
def draw_loss_curve(entries: list[dict], datasets: dict[str, dict], labels: dict[str, str], out: str | Path,
                    title: str, levels: dict[str, float] | None = None) -> Path:
    """PNG at ``out``: total loss vs training step for every dataset (left) and its three parts (right).

    ``entries``: cache entries ``{"step", name: {"loss", "translation", …}}`` in step order; ``datasets``:
    ``name → EvaluationSet.describe()``; ``labels``: ``name →`` its legend label. The loss axis is logarithmic when
    the values span more than a factor of 10. ``levels``: horizontal reference lines on the parts' axes, ``label →
    value`` (e.g. the prior-only translation loss).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    steps = [entry["step"] for entry in entries]
    figure, (total_axes, parts_axes) = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    for name, line_style in zip(datasets, ("-", "--", ":", "-.")):
        total_axes.plot(steps, [entry[name]["loss"] for entry in entries], line_style, marker="o", label=labels[name])
        for part, colour in zip(LOSS_PARTS[1:], ("tab:blue", "tab:orange", "tab:green")):
            parts_axes.plot(steps, [entry[name][part] for entry in entries], line_style, color=colour, marker=".",
                            label=f"{part}, {labels[name]}")
    for (label, value), line_style in zip((levels or {}).items(), (":", "-.", "--")):
        parts_axes.axhline(value, color="black", linestyle=line_style, linewidth=1.2, label=label)
    total_ylabel = "loss = translation + rotation + w · gripper"
    for axes, ylabel in ((total_axes, total_ylabel), (parts_axes, "loss part (flow MSE, gripper BCE)")):
        values = [value for line in axes.get_lines() for value in line.get_ydata()]
        if min(values) > 0 and max(values) / min(values) > 10:
            axes.set_yscale("log")
        axes.set_xlabel("training step", fontsize=12)
        axes.set_ylabel(ylabel, fontsize=12)
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=9)
    total_axes.set_title("diffusion training loss", fontsize=12)
    parts_axes.set_title("its parts", fontsize=12)
    figure.suptitle(title, fontsize=12)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    plt.close(figure)
    return out


# ---------------------------------------------------------------------------------------------------- a run's curve
def loss_curve(run_dir: str | Path, train_root: str | Path, val_root: str | Path, out: str | Path,
               json_path: str | Path | None = None, train_repo_id: str | None = None, val_repo_id: str | None = None,
               samples: int = 256, batch_size: int = 16, seed: int = 0, device: str = "cpu") -> dict:
    """The curve of the ``lerobot-train`` run at ``run_dir``: every checkpoint not already in the cache at
    ``json_path`` (default: ``out`` with suffix ``.json``) is evaluated on ``samples`` frames of the training set,
    of the held-out set and of the held-out set with swapped contexts (progress on stderr), the cache is saved after
    each, and the PNG is drawn at ``out``. Returns a JSON-ready summary: the files, the datasets, the settings,
    which checkpoints were evaluated and reused, the prior-only level, the curve and the best validation step."""
    checkpoints = find_checkpoints(run_dir)
    config = checkpoint_config(checkpoints[-1])
    evaluations = {
        "train": load_evaluation_set("train", train_root, config, samples, seed, train_repo_id),
        "val": load_evaluation_set("val", val_root, config, samples, seed, val_repo_id),
    }
    descriptions = {name: evaluation.describe() for name, evaluation in evaluations.items()}
    json_path = Path(json_path) if json_path else Path(out).with_suffix(".json")
    settings = {"samples": samples, "batch_size": batch_size, "seed": seed}
    cache = LossCurveCache(json_path, settings, descriptions)
    evaluated, reused = [], []
    steps = [checkpoint.step for checkpoint in checkpoints]
    for checkpoint in checkpoints:
        weights = weights_fingerprint(checkpoint)
        if cache.get(checkpoint.step, weights) is not None:
            reused.append(checkpoint.step)
            continue
        results, cache.prior = _evaluate_checkpoint(checkpoint, config, evaluations, batch_size, seed, device,
                                                    cache.prior)
        cache.put(checkpoint.step, weights, results)
        cache.save(steps)
        evaluated.append(checkpoint.step)
        print(f"step {checkpoint.step}: " + ", ".join(f"{name} loss {result.loss:.4f}"
                                                     for name, result in results.items()), file=sys.stderr)
    cache.save(steps)
    entries = [cache.entries[step] for step in steps]
    prior = cache.prior
    lines = {**descriptions, "val_swap": descriptions["val"]}
    levels = {"prior-only translation, held-out": prior["translation"]} if prior else None
    picture = draw_loss_curve(entries, lines, CURVE_LABELS, out, _curve_title(Path(run_dir), descriptions), levels)
    best = min(entries, key=lambda entry: entry["val"]["loss"])
    return {
        "run": str(run_dir), "png": str(picture), "json": str(json_path), "datasets": descriptions,
        "settings": settings, "cache_discarded": cache.discarded, "evaluated": evaluated, "reused": reused,
        "prior_only_val": prior, "curve": [_curve_point(entry) for entry in entries],
        "best_val": {"step": best["step"], "val_loss": best["val"]["loss"]},
    }


def _evaluate_checkpoint(checkpoint: Checkpoint, config, evaluations: dict[str, EvaluationSet], batch_size: int,
                         seed: int, device: str, prior: dict | None) -> tuple[dict[str, LossEstimate], dict]:
    """The checkpoint's losses on every evaluation set and on ``val`` with swapped contexts, and the prior-only level
    on ``val`` (``prior`` when already known). ``EvaluationError`` when its data layout differs from ``config``'s."""
    policy, preprocessor = load_checkpoint(checkpoint, device)
    for name in ("num_waypoints", "horizon", "num_points"):
        if getattr(policy.config, name) != getattr(config, name):
            raise EvaluationError(
                f"checkpoint {checkpoint.path} has {name}={getattr(policy.config, name)}, the run's last "
                f"checkpoint {getattr(config, name)}: evaluate runs with one data layout"
            )
    results = {name: evaluate_loss(policy, preprocessor, evaluation, batch_size, seed)
               for name, evaluation in evaluations.items()}
    results["val_swap"] = evaluate_loss(policy, preprocessor, evaluations["val"], batch_size, seed, swap_context=True)
    if prior is None:
        prior = prior_only_loss(policy, preprocessor, evaluations["val"], batch_size, seed)
    return results, prior


def _curve_title(run_dir: Path, datasets: dict[str, dict]) -> str:
    """The picture's title: the run, the datasets' sizes and the evaluated samples."""
    sizes = "; ".join(
        f"{CURVE_LABELS[name]}: {info['tasks']} pseudo-tasks, {info['episodes']} episodes, {info['frames']} frames"
        for name, info in datasets.items()
    )
    samples = ", ".join(f"{info['samples']} {CURVE_LABELS[name].split()[0]}" for name, info in datasets.items())
    return f"Instant Policy training curve, run {run_dir}\n{sizes}\nloss on fixed frames ({samples})"


def _curve_point(entry: dict) -> dict:
    """One checkpoint's point of the summary's curve: losses, and the context gains where the swap was evaluated."""
    return {"step": entry["step"], "train_loss": entry["train"]["loss"], "val_loss": entry["val"]["loss"],
            "val_translation": entry["val"]["translation"],
            "val_swap_translation": entry.get("val_swap", {}).get("translation"),
            "context_gain_translation": _context_gain(entry, "translation"),
            "context_gain_rotation": _context_gain(entry, "rotation")}


def _context_gain(entry: dict, part: str) -> float | None:
    """Held-out loss with a swapped context / with the frame's own context (``None`` for an entry without a swap)."""
    if "val_swap" not in entry or entry["val"][part] <= 0:
        return None
    return round(entry["val_swap"][part] / entry["val"][part], 3)
