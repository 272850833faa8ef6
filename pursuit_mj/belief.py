"""Belief features: what a pursuer remembers, added to its observation for a memoryless network.

A reactive network sees only the present: an evader that slipped behind a wall is gone, and
it cannot know which parts of the arena nobody has looked at lately. The heuristic team
keeps that memory (heuristic.py: last known evaders, a coverage map built from its rays).
`Belief` runs that same memory from each pursuer's own observations and appends it to the
observation vector as two groups (obs_spec.py):

- `memory` (M, 6): per evader, where it probably is now (last known position moved along its
  last velocity for at most `extrapolate_time`), relative to the pursuer (m), that velocity
  (m/s), the age of the knowledge (s, capped at AGE_CAP), and a known flag (0: never seen,
  searched without finding it, or too old; the other values are then 0);
- `goal` (1, 3): the next waypoint of the pursuer's coverage search, relative (m), and 1
  when it lies on a path planned around the walls it has mapped.

The features are a function of the pursuer's observation history only (its rays, what it and
its teammates' relays saw), so the belief is as available on a real drone as the
observation itself. The decision (chase, encircle, avoid) stays with the network.

`BeliefPolicy` puts a belief in front of a policy (evaluation, rendering, flights);
`BeliefEnv` puts it in front of a PursuitEnv's observations (training).
"""

from __future__ import annotations

import numpy as np

from .heuristic import HeuristicTeam
from .obs_spec import ObsSpec
from .policy import Policy, check_observations, check_world_count, check_world_ids

AGE_CAP = 5.0  # s: older knowledge reads as this old (keeps the input in a tanh encoder's range)


def belief_spec(spec: ObsSpec) -> ObsSpec:
    """The spec of observations `spec` with the belief groups appended."""
    return ObsSpec.make(spec.n_pursuers, spec.n_evaders, spec.n_rays, belief=True)


class Belief:
    """Per-world, per-pursuer memory of W worlds; `augment` takes one decision step's
    observations (W, N, D) and returns them with the belief features appended (W, N, D + 6M + 3).

    Call it exactly once per decision step, and `reset` the worlds whose episode ended.
    `memory` is a HeuristicTeam whose evader memory and coverage map are used (not its actions).
    """

    def __init__(self, memory: HeuristicTeam):
        self.memory = memory
        self.last: tuple | None = None  # (raw obs, what memory.observe returned) of the last step

    @classmethod
    def from_config(cls, config) -> "Belief":
        """A belief sized to a TaskConfig's speeds, ranges and timing."""
        return cls(HeuristicTeam.from_config(config))

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget the listed worlds (all, and resize, when world_ids is None)."""
        self.memory.reset(n_worlds, world_ids)

    def features(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Belief features (W, N, 6M + 3) float32 after taking in obs (W, N, spec.dim)."""
        if spec.has_belief:
            raise ValueError("Belief: these observations already carry belief features")
        o, mem, sweep, planned = self.memory.observe(obs, spec)
        self.memory.tick()
        self.last = (obs, (o, mem, sweep, planned))
        est, vel, age = self.memory.evader_estimates()
        known = np.isfinite(age)
        rel = np.where(known[..., None], est - o["pos"][:, :, None], 0.0)
        vel = np.where(known[..., None], vel, 0.0)
        age = np.where(known, np.minimum(age, AGE_CAP), 0.0)
        memory = np.concatenate([rel, vel, age[..., None], known[..., None]], -1)  # (W, N, M, 6)
        goal = np.concatenate([sweep, planned[..., None]], -1)  # (W, N, 3)
        W, N = obs.shape[:2]
        return np.concatenate([memory.reshape(W, N, -1), goal], -1).astype(np.float32)

    def augment(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """obs (W, N, spec.dim) with the belief features appended, float32, for belief_spec(spec)."""
        return np.concatenate([np.asarray(obs, dtype=np.float32), self.features(obs, spec)], -1)


class BeliefTeam:
    """The heuristic team acting from a Belief's memory: a `Policy` for the observations that
    belief just augmented, without keeping (and updating) a second copy of the same memory.

    A heuristic teacher (DAgger) or base team (residual learning) fed the same observations as
    the belief would build exactly the belief's memory, its coverage map included, which is
    most of its cost. `act` decides from the belief's last observation (HeuristicTeam.decide)
    and refuses observations the belief has not just taken in; `reset` does nothing, because
    the belief's owner (BeliefEnv) resets the memory.
    """

    has_shield = True  # HeuristicTeam.decide ends in its shield

    def __init__(self, belief: Belief):
        self.belief = belief
        self.name = "heuristic"

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        pass

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1] for obs (W, N, D), with or without belief features."""
        if self.belief.last is None:
            raise RuntimeError("BeliefTeam: the belief has taken in no observations yet")
        raw, observed = self.belief.last
        if np.shape(obs)[:2] != raw.shape[:2] or not np.array_equal(np.asarray(obs)[..., : raw.shape[-1]], raw):
            raise RuntimeError("BeliefTeam: these are not the observations the belief took in last")
        return self.belief.memory.decide(*observed)


class BeliefPolicy:
    """A `Policy` over the environment's observations: a belief, then `policy` on the augmented ones."""

    def __init__(self, policy: Policy, belief: Belief):
        self.policy = policy
        self.belief = belief
        self.name = policy.name
        self.has_shield = bool(getattr(policy, "has_shield", False))
        self._n_worlds: int | None = None  # as reset() was last called (None: not yet)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        world_ids = check_world_ids(world_ids, n_worlds, f"policy {self.name}")
        self._n_worlds = int(n_worlds)
        self.belief.reset(n_worlds, world_ids)
        self.policy.reset(n_worlds, world_ids)

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1] from obs (W, N, spec.dim) without belief features."""
        check_observations(obs, spec, f"policy {self.name}")  # checked only: the belief reads them as given
        if not isinstance(obs, np.ndarray):  # a list: as the env would give it
            obs = np.asarray(obs, np.float32)
        check_world_count(obs.shape[0], self._n_worlds, f"policy {self.name}")
        return self.policy.act(self.belief.augment(obs, spec), belief_spec(spec))


class BeliefEnv:
    """A PursuitEnv whose observations carry belief features (for training).

    `obs_spec`/`obs_dim` describe the augmented observations; everything else is the env's.
    `info["final_obs"]` of a step is augmented too; there the belief part of worlds whose
    episode just ended is the one of the step before (one decision step old), because their
    memory is already cleared for the next episode. It only enters bootstrap values at timeouts.
    """

    def __init__(self, env, belief: Belief):
        self.env = env
        self.belief = belief
        self.raw_spec = env.obs_spec
        self.obs_spec = belief_spec(env.obs_spec)
        self.obs_dim = self.obs_spec.dim
        self._features: np.ndarray | None = None

    def __getattr__(self, name):
        if name == "env":  # not set yet (copy.copy builds the object without __init__): no endless recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    def _augment(self, obs: np.ndarray) -> np.ndarray:
        self._features = self.belief.features(obs, self.raw_spec)
        return np.concatenate([obs.astype(np.float32), self._features], -1)

    def reset(self, *args, **kwargs) -> np.ndarray:
        """The env's reset with a fresh belief: obs (W, N, obs_dim + belief features) float32."""
        obs = self.env.reset(*args, **kwargs)
        self.belief.reset(self.env.n_worlds)
        return self._augment(obs)

    def reset_worlds(self, world_ids, seeds=None):
        """Refused: the belief takes in every world's observation at once and counts time by
        it, so it cannot restart some worlds between steps without ageing the others' memory.
        Training restarts worlds by auto-reset inside `step`."""
        raise RuntimeError("BeliefEnv.reset_worlds: not supported (the belief memory advances all worlds "
                           "together); let episodes restart by auto_reset, or call reset() for all worlds")

    def step(self, actions: np.ndarray):
        """The env's step, actions (W, N, 2); obs and info["final_obs"] get the belief features
        appended (W, N, obs_dim + belief features); a world's belief restarts at its episode's end."""
        obs, reward, terminated, truncated, info = self.env.step(actions)
        previous = self._features
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):
            self.belief.reset(self.env.n_worlds, ended)
        aug = self._augment(obs)
        final = aug.copy()
        final[ended, :, : obs.shape[-1]] = info["final_obs"][ended]
        final[ended, :, obs.shape[-1] :] = previous[ended]
        info = dict(info, final_obs=final)
        return aug, reward, terminated, truncated, info
