"""Speed of training on fresh pseudo-tasks: the stream (``pseudo_demos.stream``, every cloud rendered and encoded in
the update's process) or the rolling pool of encoded tasks (``training.task_pool``, rendered and encoded in generator
processes), each feeding ``instant_policy``'s training update.

Both are timed by wall time over the whole run, from before the first task is planned (the pool's generator
processes start inside the span) to the last update, so that no render, encoding or wait falls outside it: samples
per second are the samples updated on over that span, fresh tasks per second the distinct tasks that entered
training over it. The update is ``lerobot-train``'s (forward, backward, gradient clipping, the preset's optimizer) on
the preset's N, L, T and P, on the GPU when there is one.
"""

from __future__ import annotations

import dataclasses
import itertools
import time

import numpy as np
import torch

from ..configuration_instant_policy import InstantPolicyConfig
from ..contract import CONTEXT_ID_KEY
from ..pseudo_demos.stream import PseudoTaskStream, StreamConfig
from ..training.stream_seam import policy_encoder_source, stream_config_for
from ..training.task_pool import PoolConfig, TaskPool, encode_task


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _policy(preset: str, device: torch.device):
    from ..modeling_instant_policy import InstantPolicyPolicy

    config = InstantPolicyConfig(preset=preset, device=str(device), reencode_action_clouds=False)
    policy = InstantPolicyPolicy(config).to(device).train()
    optimizer_config = config.get_optimizer_preset()
    return policy, optimizer_config.build(policy.get_optim_params()), optimizer_config.grad_clip_norm


def _train(source, policy, optimizer, grad_clip: float, batch_size: int, seconds: float, steps: int | None,
           device: torch.device) -> dict:
    """Updates on batches of ``source`` until ``seconds`` of wall time or ``steps`` updates, whichever comes first."""
    batches = iter(torch.utils.data.DataLoader(source, batch_size=batch_size, num_workers=0))
    started = time.perf_counter()
    update_s, done, task_ids = 0.0, 0, set()
    for done in itertools.count(1):
        batch = {key: value.to(device) for key, value in next(batches).items()}
        task_ids.update(batch[CONTEXT_ID_KEY].tolist())
        updating = time.perf_counter()
        loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), grad_clip)
        optimizer.step()
        optimizer.zero_grad()
        _synchronize(device)
        update_s += time.perf_counter() - updating
        if time.perf_counter() - started >= seconds or (steps is not None and done >= steps):
            break
    wall = time.perf_counter() - started
    return {"wall_s": wall, "steps": done, "samples": done * batch_size, "samples_per_s": done * batch_size / wall,
            "distinct_tasks": len(task_ids), "fresh_tasks_per_s": len(task_ids) / wall,
            "update_share": update_s / wall, "update_samples_per_s": done * batch_size / update_s}


def _stream_summary(stream_config: StreamConfig) -> dict:
    generation = stream_config.generation
    width, height = stream_config.zbuffer_resolution
    return {"family": generation.family, "object_split": generation.object_split, "seed": generation.seed,
            "shared_layout_fraction": generation.demo.shared_layout_fraction,
            "samples_per_task": stream_config.samples_per_task, "tasks_per_render": stream_config.tasks_per_render,
            "zbuffer": f"{width}x{height}", "surface_samples": stream_config.surface_samples}


def stream_benchmark(stream_config: StreamConfig, preset: str = "small", batch_size: int = 8, seconds: float = 60.0,
                     steps: int | None = None, device: str | None = None) -> dict:
    """The stream feeding the update (module docstring), as JSON-ready figures."""
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    policy, optimizer, grad_clip = _policy(preset, device)
    config = stream_config_for(policy.config, stream_config)
    stream = PseudoTaskStream(config, device=device)
    result = _train(stream, policy, optimizer, grad_clip, batch_size, seconds, steps, device)
    return {"source": "stream", "device": str(device), "preset": preset, "hidden_dim": policy.config.hidden_dim,
            "batch": batch_size, "torch_threads": torch.get_num_threads(), "stream": _stream_summary(config),
            "skipped_tasks": stream.skipped_tasks, **result}


def pool_benchmark(stream_config: StreamConfig, pool_config: PoolConfig, preset: str = "small", batch_size: int = 8,
                   seconds: float = 600.0, steps: int | None = None, device: str | None = None) -> dict:
    """The task pool feeding the update (module docstring), as JSON-ready figures with the pool's own account
    (tasks received, uses per task, seconds waited for tasks)."""
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    policy, optimizer, grad_clip = _policy(preset, device)
    config = stream_config_for(policy.config, stream_config)
    pool = TaskPool(dataclasses.replace(pool_config, stream=config), policy_encoder_source(policy.config))
    try:
        result = _train(pool, policy, optimizer, grad_clip, batch_size, seconds, steps, device)
        stats = pool.stats().to_dict()
    finally:
        pool.close()
    return {"source": "pool", "device": str(device), "preset": preset, "hidden_dim": policy.config.hidden_dim,
            "batch": batch_size, "torch_threads": torch.get_num_threads(), "stream": _stream_summary(config),
            "generators": pool_config.generators, "generator_threads": pool_config.generator_threads,
            "generator_device": pool_config.device, "capacity": pool_config.capacity, "pool": stats, **result}


def replay_prior_benchmark(stream_config: StreamConfig, tasks: int = 24, preset: str = "small",
                           device: str | None = None) -> dict:
    """What replay priors (training to refine) cost a pool generator: the seconds per task of its work (plan, render
    and encode, :func:`~..training.task_pool.encode_task`) without and with the priors, on the same task indices, in
    blocks of ``tasks_per_render`` whose order alternates, so that both variants share the machine's load. Figures:
    the median seconds per task of each and their ratio, the pool's task rate with priors relative to without."""
    device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    policy_config = InstantPolicyConfig(preset=preset, device=str(device))
    base = dataclasses.replace(stream_config_for(policy_config, stream_config), replay_priors=False)
    variants = {"without": base, "with": dataclasses.replace(base, replay_priors=True, replay_plan="per_object")}
    streams = {name: PseudoTaskStream(config, device=device) for name, config in variants.items()}
    encoder = policy_encoder_source(policy_config).build().to(device)
    per_task: dict[str, list[float]] = {name: [] for name in variants}
    indices = streams["without"].task_indices()
    block = base.tasks_per_render
    for round_index in range(max(1, tasks // block)):
        chunk = list(itertools.islice(indices, block))
        order = ("without", "with") if round_index % 2 == 0 else ("with", "without")
        for name in order:
            started = time.perf_counter()
            rendered = streams[name].render_tasks(chunk)
            for task in rendered:
                encode_task(task, encoder, base.horizon)
            _synchronize(device)
            if rendered:
                per_task[name].append((time.perf_counter() - started) / len(rendered))
    medians = {name: float(np.median(values)) for name, values in per_task.items()}
    return {"device": str(device), "torch_threads": torch.get_num_threads(), "stream": _stream_summary(base),
            "blocks": len(per_task["with"]), "seconds_per_task": medians,
            "ratio_with_to_without": medians["with"] / medians["without"],
            "task_rate_with_priors": medians["without"] / medians["with"]}
