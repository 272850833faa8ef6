"""What drives the pursuers: any object with `reset` and `act` over batched observations.

Policies see exactly what the environment gives a pursuer (its observation vector, see
`obs_spec.py`), so a hand-made team, a random team and a trained network are used the same
way in evaluation, rendering and real flights.
"""

from __future__ import annotations

import zlib
from typing import Protocol

import numpy as np

from .obs_spec import ObsSpec


class Policy(Protocol):
    name: str

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget any memory of the listed worlds (all if None); called at episode starts."""

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1] (fraction of max speed, world x/y) from obs (W, N, spec.dim).

        Real numbers, finite (evaluate and render name the policy otherwise: `checked_actions`);
        beyond [-1, 1] they are clipped. Called every step for every world of the batch, those
        frozen at an episode's end included (their actions are ignored)."""


def check_policy(policy, where: str) -> None:
    """ValueError naming `where` unless `policy` can act as a Policy (callable act and reset): a
    string or a class handed in by mistake is named at once, not after episodes have run."""
    if not (callable(getattr(policy, "act", None)) and callable(getattr(policy, "reset", None))) or isinstance(policy, type):
        raise ValueError(f"{where}: expected a Policy (with act and reset), got {policy!r}; make one with "
                         f"pursuit_mj.policies.make_policy(name, config) or train.load_policy(path, spec)")


def check_observations(obs, spec: ObsSpec, who: str) -> np.ndarray:
    """obs as a float64 array (W, N, spec.dim), or ValueError naming policy `who`."""
    a = np.asarray(obs, dtype=np.float64)
    if a.ndim != 3 or a.shape[1] != spec.n_pursuers or a.shape[2] != spec.dim:
        raise ValueError(f"{who}: expected observations (worlds, {spec.n_pursuers}, {spec.dim}), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{who}: observations contain NaN or inf")
    return a


def check_world_ids(world_ids, n_worlds: int, who: str) -> np.ndarray | None:
    """world_ids as an int64 array (None stays None), or ValueError naming `who` for ids that are
    not worlds 0..n_worlds-1 (a world whose memory a wrong id leaves would go on remembering), or
    for an n_worlds that is no integer >= 1 (2.5 went on as 2 worlds, 0 until the first act())."""
    if isinstance(n_worlds, (bool, np.bool_)) or not isinstance(n_worlds, (int, np.integer)) or n_worlds < 1:
        raise ValueError(f"{who}: reset n_worlds: expected an integer >= 1, got {n_worlds!r}")
    if world_ids is None:
        return None
    ids = np.asarray(world_ids)
    if ids.ndim != 1 or not (np.issubdtype(ids.dtype, np.integer) or ids.size == 0):
        raise ValueError(f"{who}: world ids must be a 1-D list of integers, got {world_ids!r}")
    ids = ids.astype(np.int64)
    bad = ids[(ids < 0) | (ids >= n_worlds)]
    if bad.size:
        raise ValueError(f"{who}: world ids {bad.tolist()} are not among the {n_worlds} worlds (0-{n_worlds - 1})")
    return ids


def check_world_count(n_obs: int, n_reset: int | None, who: str) -> None:
    """ValueError naming `who` when observations come for n_obs worlds but reset() was called
    for n_reset (None: never reset, any count is taken): a policy with memory would mix worlds up."""
    if n_reset is not None and n_obs != n_reset:
        raise ValueError(f"{who}: got observations of {n_obs} world{'' if n_obs == 1 else 's'}, but reset() was "
                         f"called for {n_reset} (call reset({n_obs}) first)")


class NonFiniteAction(ValueError):
    """checked_actions' refusal of an action that is not a finite number, and where it is: the
    policy `who`, the `value`, its `world`, `pursuer` (index) and `component` ('vx' or 'vy').
    `naming(label)` is the message with the pursuer called `label` ('pursuer p1 (index 1)': a
    flight names it by the flight file's drone)."""

    def __init__(self, who: str, value: float, world: int, pursuer: int, component: str):
        self.who, self.value, self.world, self.pursuer, self.component = who, value, world, pursuer, component
        super().__init__(self.naming(f"pursuer {pursuer}"))

    def naming(self, pursuer: str) -> str:
        return f"{self.who}: act() gave {self.value} for world {self.world}, {pursuer}, {self.component}"


def checked_actions(actions, n_worlds: int, n_pursuers: int, who: str) -> np.ndarray:
    """What a policy's act() returned, as a float64 array (n_worlds, n_pursuers, 2), or ValueError
    naming policy `who` and what is wrong: another shape (a transposed (N, W, 2) included), values
    that are no real numbers, NaN or inf (a NonFiniteAction). Values beyond [-1, 1] are kept: the env clips them
    (docs/env_api.md), as it would a policy called outside this check."""
    from .env import MaskedValues, plain_array  # not at the top: this module stays free of the simulator

    want = (int(n_worlds), int(n_pursuers), 2)
    try:  # as the env reads actions: a torch tensor (grad, GPU, bfloat16) by its values, a masked array refused
        raw = plain_array(actions, f"{who}: act() gave actions")
    except MaskedValues:
        raise
    except ValueError:  # nested lists of unequal lengths
        raise ValueError(f"{who}: act() gave a ragged list, expected actions of shape {want} (worlds, pursuers, vx vy)") from None
    if raw.dtype.kind not in "fiu":
        raise ValueError(f"{who}: act() gave actions of dtype {raw.dtype}, expected real numbers (worlds, pursuers, vx vy)")
    if raw.shape != want:
        raise ValueError(f"{who}: act() gave actions of shape {raw.shape}, expected {want} (worlds, pursuers, vx vy)")
    a = raw.astype(np.float64)
    if not np.isfinite(a).all():
        w, i, c = (int(k) for k in np.argwhere(~np.isfinite(a))[0])
        raise NonFiniteAction(who, float(a[w, i, c]), w, i, ("vx", "vy")[c])
    return a


class RandomPolicy:
    """Uniform random actions; a floor every policy must beat.

    Each world's actions are drawn from a generator keyed by the policy's seed, the step of
    the world's episode and that world's observation, never from one stream shared by the
    batch: so an episode is the same whichever world of however many plays it (eval's
    --worlds), as it is for every other policy. `make_policy("random", ...)` gives seed 0
    whatever its seed, so that an episode replays by its episode seed alone.
    """

    name = "random"

    def __init__(self, seed: int = 0):
        self.seed = int(seed)
        self._steps = np.zeros(0, np.int64)  # (W,) decision steps since each world's reset

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        world_ids = check_world_ids(world_ids, n_worlds, f"policy {self.name}")
        if world_ids is None or len(self._steps) != n_worlds:
            self._steps = np.zeros(n_worlds, np.int64)
        else:
            self._steps[np.asarray(world_ids, dtype=np.int64)] = 0

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) uniform in [-1, 1] (fraction of max speed, world x/y) for obs (W, N, spec.dim)."""
        a = np.ascontiguousarray(check_observations(obs, spec, f"policy {self.name}"), dtype=np.float32)
        W = a.shape[0]
        if len(self._steps) != W:
            self.reset(W)
        out = np.empty(a.shape[:-1] + (2,))
        for w in range(W):  # one small draw per world: a baseline, not a hot path
            key = [self.seed, int(self._steps[w]), zlib.crc32(a[w].tobytes())]
            out[w] = np.random.default_rng(key).uniform(-1.0, 1.0, size=a.shape[1:-1] + (2,))
        self._steps += 1
        return out
