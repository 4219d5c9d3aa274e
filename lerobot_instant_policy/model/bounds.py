"""The sizes the Instant Policy network is built for: each range is inclusive, ``(low, high)``.

Any N and L in these ranges work without retraining. Each value is checked once, where it enters: the config's
fields when the config is built, and a set of demonstrations handed to the policy when it is handed in.
"""

from __future__ import annotations

SUPPORTED_DEMOS = (1, 8)  # N, demonstrations in one context
SUPPORTED_WAYPOINTS = (2, 32)  # L, waypoints per demonstration
SUPPORTED_HORIZON = (1, 32)  # T, actions predicted per step
SUPPORTED_INFERENCE_STEPS = (1, 8)  # K, DDIM steps per prediction
MAX_SAMPLES_PER_PREDICTION = 64  # S, samples averaged per prediction (1…64: a batch of S × rows)


def check_range(name: str, value: int, bounds: tuple[int, int]) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is an integer in ``bounds``."""
    low, high = bounds
    if not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{name} must be an integer in the supported range {low}…{high}, got {value!r}")
