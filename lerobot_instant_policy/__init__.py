"""Instant Policy (Vosylius & Johns, ICLR 2025) as a LeRobot policy plugin.

Subpackages: ``geometry`` (SE(3), point sampling), ``data`` (object library, pseudo-demonstrations, LeRobot
datasets), ``cli`` (``lerobot-ip-*`` commands).
"""

__version__ = "0.1.0"

from . import video_backend  # noqa: E402

video_backend.install()

# registrations: the ``instant_policy``, ``demo_replay`` and ``do_nothing`` policy configs, the ``bullet_tabletop`` env config
from . import baselines, configuration_instant_policy, sim  # noqa: E402,F401
