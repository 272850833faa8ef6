"""Validation on a fixed seed set: the same episodes every time, the deterministic (mean) policy.

The episodes are evaluation's (`pursuit_mj.evaluation.play`, the episode seeds of
`episode_seeds(seed, n_episodes)`), one per world of an env kept between calls (models built
once): the episode set depends only on (task, layouts, seed, n_episodes), never on the policy
or on timing. Rates and means are evaluation's `summarise`, the pairing with a reference is
`pursuit_mj.comparison.pair`, flattened into the numbers a metrics log holds.
"""

from __future__ import annotations

from typing import Sequence

from pursuit_mj import evaluation
from pursuit_mj.comparison import pair
from pursuit_mj.config import TaskConfig
from pursuit_mj.env import EpisodeRecord, PursuitEnv


def summarise(records: Sequence[EpisodeRecord]) -> dict[str, float]:
    """success / collision / timeout rates (0-1), mean steps over all episodes and over successes."""
    row = _row("policy", records)
    return {
        "episodes": row.episodes,
        "success": row.success.p,
        "collision": row.collision.p,
        "timeout": row.timeout.p,
        "mean_steps": _number(row.steps.mean),
        "success_steps": _number(row.steps_success.mean),
    }


def versus(records: Sequence[EpisodeRecord], reference: Sequence[EpisodeRecord], max_steps: int,
           name: str = "heuristic") -> dict[str, float]:
    """A validation paired with a reference policy's run of the same episodes (both in episode order).

    {name}_success, {name}_mean_steps: the reference's rates; vs_{name}_steps with _lo / _hi:
    the mean per-episode difference in capture steps (policy - reference; negative: sooner)
    with its 95 % t interval; vs_{name}_only_policy / vs_{name}_only_{name}: episodes only that
    one won, and vs_{name}_success_p the exact McNemar p on them (comparison.Paired).
    ValueError if the two did not play the same episodes.
    """
    if [(r.world, r.seed) for r in records] != [(r.world, r.seed) for r in reference]:
        raise ValueError("validation: the policy and its reference did not play the same episodes")
    ref = _row(name, reference, max_steps)
    paired = pair(_row("policy", records, max_steps), ref, max_steps)
    return {f"{name}_success": ref.success.p, f"{name}_mean_steps": _number(ref.steps.mean),
            f"vs_{name}_steps": paired.steps.mean, f"vs_{name}_lo": paired.steps.lo, f"vs_{name}_hi": paired.steps.hi,
            f"vs_{name}_only_policy": paired.only_policy, f"vs_{name}_only_{name}": paired.only_reference,
            f"vs_{name}_success_p": paired.success_p}


def _row(policy: str, records: Sequence[EpisodeRecord], max_steps: float = float("inf")) -> evaluation.Row:
    return evaluation.summarise(policy, "validation", "", 0, records, max_steps)


def _number(value: float | None) -> float:
    return float("nan") if value is None else float(value)


class FixedSeedValidator:
    """Keeps one env (models built once) and replays the same n_episodes at every call."""

    def __init__(self, task: TaskConfig, layouts: Sequence[int | str] | None, n_episodes: int, seed: int,
                 nthread: int = 0):
        self.seeds = evaluation.episode_seeds(seed, n_episodes)
        self.env = PursuitEnv(task, n_worlds=n_episodes, seed=seed, auto_reset=False,
                              layouts=list(layouts) if layouts else None, nthread=nthread)

    def run(self, policy) -> tuple[dict[str, float], list[EpisodeRecord]]:
        """(summary, the records in episode order) of `policy` on the fixed episodes."""
        records = evaluation.play(self.env, policy, self.seeds)
        return summarise(records), records
