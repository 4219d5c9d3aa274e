"""Instant Policy (Vosylius & Johns, ICLR 2025) as a LeRobot policy plugin.

Ground floor: ``contract`` (the LeRobot feature keys and the one codec of the 8-number pose + gripper vector) and
``geometry`` (SE(3) in numpy and torch, point sampling, registration). On it: ``data`` (object library,
pseudo-tasks and pseudo-demonstrations, LeRobot dataset I/O, demonstrations, waypoints, the context bank, action
chunks), ``model`` (geometry encoder, graph, σ / φ / ψ transformers, action diffusion), ``perception`` (depth →
segmented clouds for real robots) and ``sim`` (the ``bullet_tabletop`` env). Then the policy
(``configuration_instant_policy``, ``modeling_instant_policy``, ``processor_instant_policy``, ``frame_encodings``),
``baselines`` (``demo_replay``, ``do_nothing``), ``training`` (encoder pretraining, loss curves) and ``cli``
(``lerobot-ip-*`` commands). Nothing low imports anything high.
"""

__version__ = "0.1.0"

from . import video_backend  # noqa: E402

video_backend.install()

# registrations: the ``instant_policy``, ``demo_replay`` and ``do_nothing`` policy configs, the ``bullet_tabletop`` env config
from . import baselines, configuration_instant_policy, sim  # noqa: E402,F401
