"""``lerobot-eval`` with the seed of every episode kept in its ``eval_info.json``.

LeRobot's ``eval_policy`` reports each episode's seed (its ``per_episode`` entries), but ``eval_one`` keeps only the
rewards, successes and videos for ``eval_info.json``. :func:`install` wraps both so that each ``per_task`` entry's
``metrics`` also holds ``seeds``: the seed of each episode in order, as ``eval_policy`` reported it (``None`` for an
episode ``lerobot-eval`` did not seed). Nothing else changes. ``python -m
lerobot_instant_policy.evaluation.lerobot_eval_seeds ARGS`` runs LeRobot's own ``lerobot-eval ARGS`` (its ``main``)
with the wrapper installed; the suite (``evaluation.suite``) runs every cell this way, and the manifests
(``evaluation.manifest``) read the seeds back.
"""

from __future__ import annotations

import functools
import threading

SEEDS_KEY = "seeds"  # in each per_task entry's metrics


def install() -> None:
    """Wrap ``lerobot_eval.eval_policy`` and ``lerobot_eval.eval_one`` (once per process): ``eval_one``'s metrics gain
    ``SEEDS_KEY``, read from the ``per_episode`` report of the ``eval_policy`` call it made (in the same thread)."""
    from lerobot.scripts import lerobot_eval

    if getattr(lerobot_eval.eval_one, "keeps_seeds", False):
        return
    eval_policy, eval_one = lerobot_eval.eval_policy, lerobot_eval.eval_one
    reported = threading.local()

    @functools.wraps(eval_policy)
    def eval_policy_reporting_seeds(*args, **kwargs):
        info = eval_policy(*args, **kwargs)
        reported.seeds = [episode.get("seed") for episode in info["per_episode"]]
        return info

    @functools.wraps(eval_one)
    def eval_one_keeping_seeds(*args, **kwargs):
        reported.seeds = None
        metrics = eval_one(*args, **kwargs)
        metrics[SEEDS_KEY] = reported.seeds
        return metrics

    eval_one_keeping_seeds.keeps_seeds = True
    lerobot_eval.eval_policy = eval_policy_reporting_seeds
    lerobot_eval.eval_one = eval_one_keeping_seeds


def main() -> None:
    """``lerobot-eval`` (``sys.argv[1:]``) with :func:`install`'s wrapper."""
    from lerobot.scripts import lerobot_eval

    install()
    lerobot_eval.main()


if __name__ == "__main__":
    main()
