"""Speed of the pseudo-task stream (``pseudo_demos.stream``): fresh-task samples per second of the stream alone, and
of the stream feeding ``instant_policy``'s training update for each preset (width), with the share of each update
spent generating. Every sample's task is new unless ``samples_per_task`` > 1.

The update is ``lerobot-train``'s (forward, backward, gradient clipping, the preset's optimizer) on the batches the
stream hands out (N, L, T, P of the preset's config), on the GPU when there is one. Timings are medians over
``batches`` batches after one warm-up batch (which also builds the objects' surface samples).
"""

from __future__ import annotations

import statistics
import time

import torch

from ..configuration_instant_policy import InstantPolicyConfig
from ..pseudo_demos.stream import PseudoTaskStream, StreamConfig
from ..stream_training import stream_config_for


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _batches(stream: PseudoTaskStream, batch_size: int):
    loader = torch.utils.data.DataLoader(stream, batch_size=batch_size, num_workers=0)
    return iter(loader)


def _timed_batches(batches, count: int, device: torch.device) -> list[float]:
    """Seconds per batch of ``count`` batches (after one warm-up batch)."""
    next(batches)
    times = []
    for _ in range(count):
        start = time.perf_counter()
        next(batches)
        _synchronize(device)
        times.append(time.perf_counter() - start)
    return times


def stream_benchmark(stream_config: StreamConfig, presets: tuple[str, ...] = ("small",), batch_size: int = 8,
                     batches: int = 3, device: str | None = None) -> dict:
    """The stream alone and the stream plus one training update per preset (module docstring), as JSON-ready
    figures: samples per second (fresh tasks per second beside them) and the generating share of each update."""
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    result = {"device": str(device), "batch": batch_size, "batches": batches,
              "samples_per_task": stream_config.samples_per_task, "torch_threads": torch.get_num_threads(),
              "stream": _stream_summary(stream_config), "presets": {}}
    alone_config = stream_config_for(InstantPolicyConfig(preset=presets[0], device=str(device)), stream_config)
    times = _timed_batches(_batches(PseudoTaskStream(alone_config, device=device), batch_size), batches, device)
    median = statistics.median(times)
    result["stream_alone"] = {"batch_s": median, "samples_per_s": batch_size / median,
                              "tasks_per_s": batch_size / median / stream_config.samples_per_task,
                              "N": alone_config.num_demos, "L": alone_config.num_waypoints}
    for preset in presets:
        result["presets"][preset] = _with_update(preset, stream_config, batch_size, batches, device)
    return result


def _stream_summary(stream_config: StreamConfig) -> dict:
    """What the stream draws (for the JSON)."""
    generation = stream_config.generation
    return {"family": generation.family, "object_split": generation.object_split, "seed": generation.seed,
            "shared_layout_fraction": generation.demo.shared_layout_fraction,
            "tasks_per_render": stream_config.tasks_per_render}


def _with_update(preset: str, stream_config: StreamConfig, batch_size: int, batches: int, device: torch.device) -> dict:
    from ..modeling_instant_policy import InstantPolicyPolicy

    config = InstantPolicyConfig(preset=preset, device=str(device))
    if config.pretrained_encoder and not config.encoder_weights_path().is_file():
        config = InstantPolicyConfig(preset=preset, device=str(device), pretrained_encoder=False)  # times the same
    policy = InstantPolicyPolicy(config).to(device).train()
    optimizer_config = config.get_optimizer_preset()
    optimizer = optimizer_config.build(policy.get_optim_params())
    stream = PseudoTaskStream(stream_config_for(config, stream_config), device=device)
    loader = _batches(stream, batch_size)
    generate_s, update_s = [], []
    for index in range(batches + 1):
        start = time.perf_counter()
        batch = {key: value.to(device) for key, value in next(loader).items()}
        _synchronize(device)
        generated = time.perf_counter()
        loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_config.grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        _synchronize(device)
        if index > 0:  # the first batch warms up
            generate_s.append(generated - start)
            update_s.append(time.perf_counter() - generated)
    generate, update = statistics.median(generate_s), statistics.median(update_s)
    return {"hidden_dim": config.hidden_dim, "parameters": sum(p.numel() for p in policy.parameters()),
            "generate_s": generate, "update_s": update, "samples_per_s": batch_size / (generate + update),
            "generating_share": generate / (generate + update)}
