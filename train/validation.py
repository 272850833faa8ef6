"""Validation on a fixed seed set: the same episodes every time, the deterministic (mean) policy.

Each world of a non-auto-resetting env plays exactly one episode per `run`, so the episode
set depends only on (task, layouts, seed, n_episodes), never on the policy or on timing.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from pursuit_mj.config import TaskConfig
from pursuit_mj.env import EpisodeRecord, PursuitEnv
from pursuit_mj.evaluation import capture_steps
from pursuit_mj.stats import mean_interval


def summarise(records: Sequence[EpisodeRecord]) -> dict[str, float]:
    """success / collision / timeout rates (0-1), mean steps over all episodes and over successes."""
    n = max(len(records), 1)
    steps = [r.steps for r in records]
    won = [r.steps for r in records if r.outcome == "success"]
    return {
        "episodes": len(records),
        "success": sum(r.outcome == "success" for r in records) / n,
        "collision": sum(r.outcome == "collision" for r in records) / n,
        "timeout": sum(r.outcome == "timeout" for r in records) / n,
        "mean_steps": float(np.mean(steps)) if steps else float("nan"),
        "success_steps": float(np.mean(won)) if won else float("nan"),
    }


def versus(records: Sequence[EpisodeRecord], reference: Sequence[EpisodeRecord], max_steps: int,
           name: str = "heuristic") -> dict[str, float]:
    """A validation paired with a reference policy's run of the same episodes (both in world order).

    {name}_success, {name}_mean_steps: the reference's rates; vs_{name}_steps with _lo / _hi:
    the mean per-episode difference in capture steps (policy - reference; negative: sooner)
    with its 95 % t interval. ValueError if the two did not play the same episodes.
    """
    if [(r.world, r.seed) for r in records] != [(r.world, r.seed) for r in reference]:
        raise ValueError("validation: the policy and its reference did not play the same episodes")
    diffs = [a - b for a, b in zip(capture_steps(records, max_steps), capture_steps(reference, max_steps))]
    m = mean_interval(diffs, (-float(max_steps), float(max_steps)))
    ref = summarise(reference)
    return {f"{name}_success": ref["success"], f"{name}_mean_steps": ref["mean_steps"],
            f"vs_{name}_steps": m.mean, f"vs_{name}_lo": m.lo, f"vs_{name}_hi": m.hi}


class FixedSeedValidator:
    """Keeps one env (models built once) and replays the same n_episodes at every call."""

    def __init__(self, task: TaskConfig, layouts: Sequence[int | str] | None, n_episodes: int, seed: int,
                 nthread: int = 0):
        self.seed = seed
        self.env = PursuitEnv(task, n_worlds=n_episodes, seed=seed, auto_reset=False,
                              layouts=list(layouts) if layouts else None, nthread=nthread)

    def run(self, policy) -> tuple[dict[str, float], list[EpisodeRecord]]:
        env = self.env
        obs = env.reset(seed=self.seed)
        policy.reset(env.n_worlds)
        records: list[EpisodeRecord] = []
        while not env.done.all():
            obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
            records.extend(info["episodes"])
        records.sort(key=lambda r: r.world)
        return summarise(records), records
