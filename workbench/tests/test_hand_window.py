"""The hand mapping's measurement against the script's command (``workbench.hand_window``)."""

from __future__ import annotations

import numpy as np

from workbench.hand_window import change_delays


def test_change_delays_pair_the_changes_in_order_and_refuse_a_different_count():
    commanded = np.array([1, 1, 0, 0, 0, 0, 1, 1], dtype=float)
    assert change_delays(np.array([1, 1, 1, 0, 0, 0, 0, 1], dtype=float), commanded) == [1, 1]
    assert change_delays(np.array([1, 0, 0, 0, 0, 0, 0, 1], dtype=float), commanded) == [-1, 1]
    assert change_delays(np.array([1, 1, 1, 0, 0, 0, 0, 0], dtype=float), commanded) is None  # the release missed
    assert change_delays(np.ones(8), np.ones(8)) == []
