"""A learned correction on top of a hand-made team: residual policy learning.

A residual team acts with

    a = clip(base(obs) + scale * correction(obs))        (W, N, 2), fraction of max speed

where `base` is a `Policy` with memory (the heuristic team: last-seen evaders, coverage map,
obstacle following) and `correction` a memoryless one (a trained actor, each axis in
[-1, 1]). The base supplies what a reactive network cannot (search, recall); the correction
is trained by PPO with the base inside the environment, so it starts where the base is
(a zero correction is the base exactly) and keeps only what improves the return.
`clip` scales a vector longer than 1 back onto the unit disc (direction kept).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .obs_spec import ObsSpec
from .policy import Policy, check_world_count, check_world_ids
from .planar import clip_unit
from .shield import SafetyShield, Shielded


def combine(base_actions: np.ndarray, correction: np.ndarray, scale: float) -> np.ndarray:
    """clip_unit(base + scale * clip(correction, -1, 1)); all (W, N, 2) fractions of max speed."""
    return clip_unit(np.asarray(base_actions, dtype=np.float64) + scale * np.clip(correction, -1.0, 1.0))


class ResidualTeam:
    """A `Policy`: the base team's actions plus `scale` x the correction policy's (see module doc).

    Named "<correction name>@<base name>", so that tables say what drove.
    Not shielded by itself: wrap it with shield.shield_policy when its training was.
    """

    has_shield = False

    def __init__(self, base: Policy, correction: Policy, scale: float):
        if isinstance(scale, bool) or not isinstance(scale, numbers.Real) or not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"ResidualTeam: scale must be a positive number, got {scale!r}")
        self.base = base
        self.correction = correction
        self.scale = float(scale)
        self.name = f"{correction.name}@{base.name}"
        self._n_worlds: int | None = None  # as reset() was last called (None: not yet)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        world_ids = check_world_ids(world_ids, n_worlds, f"policy {self.name}")
        self._n_worlds = int(n_worlds)
        self.base.reset(n_worlds, world_ids)
        self.correction.reset(n_worlds, world_ids)

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) within the unit disc from obs (W, N, spec.dim)."""
        check_world_count(np.shape(obs)[0], self._n_worlds, f"policy {self.name}")
        correction = self.correction.act(obs, spec)  # first: a base acting from the correction's belief (BeliefTeam) needs it
        return combine(self.base.act(obs, spec), correction, self.scale)


def acting_team(actor: Policy, base: Policy | None, scale: float, shield: SafetyShield | None) -> Policy:
    """What drives the env from an actor's actions: the actor alone, or added to `base` with
    `scale` (a ResidualTeam), then behind `shield` when one is given. Training (the actor is
    the rollout's samples, train/rollout.py) and every use of a trained model (the actor is
    the network, train/policy.py) build it here, so the two cannot drift apart."""
    team = actor if base is None else ResidualTeam(base, actor, scale)
    return team if shield is None else Shielded(team, shield)
