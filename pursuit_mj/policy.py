"""What drives the pursuers: any object with `reset` and `act` over batched observations.

Policies see exactly what the environment gives a pursuer (its observation vector, see
`obs_spec.py`), so a hand-made team, a random team and a trained network are used the same
way in evaluation, rendering and real flights.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .obs_spec import ObsSpec


class Policy(Protocol):
    name: str

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget any memory of the listed worlds (all if None); called at episode starts."""

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1] (fraction of max speed, world x/y) from obs (W, N, spec.dim)."""


def check_observations(obs, spec: ObsSpec, who: str) -> np.ndarray:
    """obs as a float64 array (W, N, spec.dim), or ValueError naming policy `who`."""
    a = np.asarray(obs, dtype=np.float64)
    if a.ndim != 3 or a.shape[1] != spec.n_pursuers or a.shape[2] != spec.dim:
        raise ValueError(f"{who}: expected observations (worlds, {spec.n_pursuers}, {spec.dim}), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{who}: observations contain NaN or inf")
    return a


class RandomPolicy:
    """Uniform random actions; a floor every policy must beat."""

    name = "random"

    def __init__(self, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        pass

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, size=obs.shape[:-1] + (2,))
