"""Instant Policy (Vosylius & Johns, ICLR 2025) as a LeRobot policy plugin.

Ground floor: ``contract`` (the LeRobot feature keys and the one codec of the 8-number pose + gripper vector) and
``geometry`` (SE(3) in numpy and torch, point sampling, registration). On it: ``data`` (LeRobot dataset I/O,
demonstrations, waypoints, the context bank, action chunks; pure data), ``objects`` (the object library and the
segmented-cloud renderer); on them ``replay`` (a demonstration replayed in the live scene: plans, segments, the one
timing model and the replay priors); then ``pseudo_demos`` (pseudo-tasks, trajectories, generation, shard merging,
preview), ``model`` (geometry encoder, graph, σ / φ / ψ transformers, action diffusion; no LeRobot), ``perception``
(depth → segmented clouds for real robots) and ``sim`` (the ``bullet_tabletop`` env). Then the policy: the LeRobot
trio at this root (``configuration_instant_policy``, ``modeling_instant_policy``, ``processor_instant_policy``) and
what it is built from in ``policy`` (features, processors); ``training`` (the stream's seam into ``lerobot-train``,
the task pool, the moving average, the optimizer, batch assembly, the context encoder, frame encodings, the language
head's targets and training; it never imports the policy); ``baselines``
(``demo_replay``, ``do_nothing``), ``pretraining`` (the geometry encoder's occupancy pretraining), ``evaluation``
(offline action error, loss curves, the suite), ``benchmarks`` (speed on the user's machine) and ``cli`` (the
``lerobot-ip-*`` commands: parsers). Nothing low imports anything high. The repository's research tooling (training
in rounds, development benchmarks) is ``workbench/`` beside this package, not installed: it imports the package, which
never imports it.
"""

__version__ = "0.1.0"

from . import video_backend  # noqa: E402

video_backend.install()

# registrations: the ``instant_policy``, ``demo_replay`` and ``do_nothing`` policy configs, the ``bullet_tabletop`` env
# config, and the point-cloud batch step that saved preprocessors name (``ip_pointcloud_to_batch``)
from . import baselines, configuration_instant_policy, processor_instant_policy, sim  # noqa: E402,F401
