"""The pursuit task over many worlds at once: arrays in, arrays out, auto-reset.

See docs/env_api.md for the contract. One `PursuitEnv` owns a `BatchedPhysics`, an
evader model (`evader_models.make_evader_model`), perception and rewards. Shapes: W worlds, N pursuers,
M evaders; positions and velocities in the layout frame (m, m/s).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Mapping, Sequence

import numpy as np

from .config import TaskConfig, checked_task_config
from .evader_models import checked_evader_model, make_evader_model
from .geometry import ObstacleSet
from .layout import N_BUILTIN, Layout, LayoutError, layout_from_dict, layout_to_dict, load_layout
from .layout_random import EPISODE_RESTARTS
from .layout_check import (PASSAGE_CLEARANCE, SPAWN_SEPARATION, check_passages, check_spawn_capacity, check_spawn_gap,
                           free_spawn_points, sample_separated)
from .observations import build_global_state, build_observations, global_state_dim
from .obs_spec import ObsSpec
from .physics import BatchedPhysics
from .randomness import WorldRandom, world_keys
from .custom_rewards import RewardTerm, StepView, checked_extra_rewards, term_values
from .rewards import REWARD_TERMS, detect_events, reward_terms
from .sensing import CAUGHT_BODY_RADIUS, INITIAL_HEADING, PERCEPTION_KEYS, Perception, WorldView, heading_min_speed, perceive, update_heading

SENSING_DOMAIN = 1  # keeps perception's random streams apart from the evaders' (same episode seed)


@dataclasses.dataclass
class EpisodeRecord:
    """One finished episode. returns: per term, summed over steps, mean over pursuers.

    outcome: success | collision | timeout; a collision in the step of the last capture is a
    collision (failure) though both reward terms are paid. captured: evaders caught (a failed
    episode may have some); time_to_capture (s): set for successes only, else None.
    """

    world: int
    episode: int
    seed: int
    outcome: str
    steps: int
    time_to_capture: float | None
    returns: dict[str, float]
    captured: int
    layout: str


@dataclasses.dataclass
class Snapshot:
    """One world now, for recorders (copies); N pursuers, M evaders, K rays; world (layout) frame.

    step (decision steps), time (s); pursuer_pos (N, 3) m, pursuer_vel (N, 3) m/s,
    pursuer_quat (N, 4) w, x, y, z body->world; evader_pos (M, 3) m, evader_vel (M, 3) m/s,
    evader_quat (M, 4); captured (M,) bool; seen (N, M) bool (direct sighting); known (N, M)
    bool (direct, relayed or caught); heading (N,) rad from world +x; commands (N + M, 2) m/s
    (last given, clipped to max speed); thrust (N + M, 4) N per rotor (zeros in point
    fidelity); rays (N, K) m; reward_terms {term: (N,) float32} of the last step.
    """

    step: int
    time: float
    layout: Layout
    pursuer_pos: np.ndarray
    pursuer_vel: np.ndarray
    pursuer_quat: np.ndarray
    evader_pos: np.ndarray
    evader_vel: np.ndarray
    evader_quat: np.ndarray
    captured: np.ndarray
    seen: np.ndarray
    known: np.ndarray
    heading: np.ndarray
    commands: np.ndarray
    thrust: np.ndarray
    rays: np.ndarray
    reward_terms: dict[str, np.ndarray]
    outcome: str
    config: TaskConfig


def episode_seed(seed: int, world: int, episode: int) -> int:
    """The default seed of a world's n-th episode (from the env seed); see `reset_worlds` for explicit ones."""
    return int(np.random.SeedSequence([seed, world, episode]).generate_state(1)[0])


def check_seeds(seeds, count: int, source: str) -> np.ndarray:
    """Episode seeds as (count,) int64, or ValueError naming `source`: non-negative integers below 2**63."""
    s = np.asarray(seeds)
    if s.shape != (count,) or (count and not np.issubdtype(s.dtype, np.integer)):
        raise ValueError(f"{source}: expected {count} integer episode seeds, got {seeds!r}")
    if count and (s.min() < 0 or (s.dtype == np.uint64 and s.max() >= 2**63)):
        raise ValueError(f"{source}: episode seeds must be non-negative integers below 2**63, got {seeds!r}")
    return s.astype(np.int64)


def check_seed(seed, source: str) -> int:
    """`seed` as an int, or ValueError naming `source`: a non-negative integer below 2**63."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise ValueError(f"{source}: expected a non-negative integer below 2**63, got {seed!r}")
    return int(seed)


MAX_NTHREAD = 1024  # simulation threads a PursuitEnv may ask for (MuJoCo's batch takes a C int)


class MaskedValues(ValueError):
    """An array given with masked (missing) entries."""


def plain_array(value, what: str) -> np.ndarray:
    """`value` as a numpy array: a torch tensor (on any device, with or without grad, of any float
    type) as its values; a masked array with masked entries is refused naming `what` (its hidden
    values would be used as if they were given)."""
    if type(value).__module__.split(".")[0] == "torch" and hasattr(value, "detach"):
        value = value.detach().cpu()
        if not value.dtype.is_complex and value.dtype.is_floating_point:
            value = value.double()  # bfloat16 and half have no numpy type
        return value.numpy()
    if isinstance(value, np.ma.MaskedArray) and np.ma.getmaskarray(value).any():
        raise MaskedValues(f"{what}: a masked array with {int(np.ma.getmaskarray(value).sum())} masked entries; give "
                         f"every value (np.ma.filled(a, value) fills them)")
    return np.asarray(value)


def _layout_pool(config: TaskConfig, layouts: Sequence[int | str | Layout] | None) -> list[Layout]:
    if layouts is not None:
        if isinstance(layouts, (str, bytes, Layout)) or not isinstance(layouts, Sequence):
            raise ValueError(f"layouts: expected a list of layouts (indices, files or Layout objects), got {layouts!r}")
        refs = list(layouts)
    elif config.random_layout:
        refs = list(range(N_BUILTIN))
    else:
        refs = [config.layout]
    if not refs:
        raise ValueError("layouts: the list of layouts is empty")
    return [_checked_layout(r) if isinstance(r, Layout) else load_layout(r) for r in refs]


def _check_pool_fits_worlds(n_layouts: int, n_worlds: int, random_layout: bool) -> None:
    """ValueError unless every layout of the pool runs: world w plays layouts[w % n_layouts], so with
    fewer worlds than layouts the last ones would never be played (unless random_layout draws an
    episode's layout from the whole pool)."""
    if random_layout or n_layouts <= n_worlds:
        return
    idle = ", ".join(f"layouts[{i}]" for i in range(n_worlds, n_layouts))
    raise ValueError(f"layouts: {n_layouts} layouts for {n_worlds} world{'s' if n_worlds > 1 else ''} (world w plays "
                     f"layouts[w % {n_layouts}]), so {idle} would never run; give n_worlds >= {n_layouts}, fewer "
                     f"layouts, or random_layout=True (each episode draws its layout from the pool)")


def check_task_fits_layout(config: TaskConfig, layout: Layout) -> None:
    """LayoutError (naming the layout's file) unless `layout` can hold the task `config`: its spawn
    regions the teams, far enough apart for the capture radius, its passages wide enough for the
    task's obstacle_clearance. What every PursuitEnv checks of each of its layouts as it is made."""
    check_spawn_capacity(layout, config.n_pursuers, config.n_evaders, SPAWN_SEPARATION)
    check_spawn_gap(layout, config.capture_radius)
    if config.obstacle_clearance > PASSAGE_CLEARANCE:  # the layout's own check allowed narrower passages
        check_passages(layout, config.obstacle_clearance, "task.obstacle_clearance")


def check_task_layouts(config: TaskConfig) -> None:
    """check_task_fits_layout for every layout the task plays (its layout, or every built-in one
    with random_layout), each loaded once: a task a PursuitEnv of it would refuse is refused now."""
    for layout in _layout_pool(config, None):
        check_task_fits_layout(config, layout)


def _with_caught(obstacles: ObstacleSet, captured: np.ndarray, evader_xy: np.ndarray, radius: float) -> ObstacleSet:
    """`obstacles` (W, ...) plus a cylinder of `radius` (m) at each caught evader (captured (W, M),
    evader_xy (W, M, 2) m); the set itself while none is caught."""
    if not captured.any():
        return obstacles
    return obstacles.with_extra_cylinders(evader_xy, radius, captured)


def _checked_layout(layout: Layout) -> Layout:
    """`layout` itself, once it passes every check its file would (a Layout made directly or
    with dataclasses.replace skips the loader's); LayoutError naming its source otherwise."""
    try:
        data = layout_to_dict(layout)
    except (AttributeError, TypeError) as exc:  # a field replaced by something of another kind
        raise LayoutError(f"{getattr(layout, 'source', 'layout')}: not a well-formed Layout ({exc}); load one with "
                          f"pursuit_mj.layout.load_layout") from None
    layout_from_dict(data, layout.source)
    return layout


class PursuitEnv:
    """N pursuers chase M evaders in W independent worlds (see module docstring).

    Per-world state (read only): episode (W,) int64, each world's episode index in its seed
    sequence; steps (W,) int64, decision steps of the current episode; starts (W,) int64,
    episodes begun; captured (W, M) bool; heading (W, N) rad from world +x; done (W,) bool;
    outcome (W,) str ('' while running); capture_time (W,) s (NaN until a success);
    returns {term: (W,)} summed over steps, mean over pursuers; last_terms {term: (W, N) float32}.
    """

    def __init__(
        self,
        config: TaskConfig,
        n_worlds: int = 1,
        seed: int = 0,
        auto_reset: bool = True,
        layouts: Sequence[int | str | Layout] | None = None,
        nthread: int = 0,
        extra_rewards: Mapping[str, RewardTerm] | None = None,
    ):
        config = checked_task_config(config, "PursuitEnv config")
        if isinstance(n_worlds, (bool, np.bool_)) or not isinstance(n_worlds, (int, np.integer)) or n_worlds < 1:
            raise ValueError(f"n_worlds: expected an integer >= 1, got {n_worlds!r}")
        if not isinstance(auto_reset, (bool, np.bool_)):
            raise ValueError(f"auto_reset: expected True or False, got {auto_reset!r}")
        if isinstance(nthread, (bool, np.bool_)) or not isinstance(nthread, (int, np.integer)) or not 0 <= nthread <= MAX_NTHREAD:
            raise ValueError(f"nthread: expected an integer in 0..{MAX_NTHREAD} (0: MuJoCo's choice), got {nthread!r}")
        self.extra_rewards = checked_extra_rewards(extra_rewards, "PursuitEnv extra_rewards")
        self.reward_names = (*REWARD_TERMS, *self.extra_rewards)  # every term paid, the task's first
        self.config = config
        self.n_worlds = int(n_worlds)
        n_worlds = self.n_worlds
        self.n_pursuers = config.n_pursuers
        self.n_evaders = config.n_evaders
        self.auto_reset = bool(auto_reset)
        self.seed = check_seed(seed, "PursuitEnv seed")
        self.pool = _layout_pool(config, layouts)
        _check_pool_fits_worlds(len(self.pool), self.n_worlds, config.random_layout)
        self._random_obstacles = any(config.random_obstacle_count(l) for l in self.pool)
        self._spawn_points = {id(l): (free_spawn_points(l, l.spawn_pursuers), free_spawn_points(l, l.spawn_evaders)) for l in self.pool}
        for layout in self.pool:
            self._check_capacity(layout)
        self.obs_spec = ObsSpec.make(self.n_pursuers, self.n_evaders, config.n_rays)
        self.obs_dim = self.obs_spec.dim
        self.state_dim = global_state_dim(self.n_pursuers, self.n_evaders)
        W, N, M = n_worlds, self.n_pursuers, self.n_evaders
        self.episode = np.zeros(W, np.int64)
        self.world_layouts: list[Layout] = [self.pool[w % len(self.pool)] for w in range(W)]
        self._base_index = np.array([w % len(self.pool) for w in range(W)])
        self._nthread = int(nthread)
        self._physics: BatchedPhysics | None = BatchedPhysics(config, self.world_layouts, nthread=nthread)
        self.closed = False  # close() freed the physics; the next reset() builds it anew
        self.evader_model = make_evader_model(config, W, self.seed)
        self.steps = np.zeros(W, np.int64)
        self.starts = np.zeros(W, np.int64)  # episodes begun in each world, however (reset, reset_worlds, auto_reset)
        self.captured = np.zeros((W, M), bool)
        self.heading = np.full((W, N), INITIAL_HEADING)
        self.done = np.zeros(W, bool)
        self.outcome = np.full(W, "", dtype=object)
        self.capture_time = np.full(W, np.nan)
        self.returns = {k: np.zeros(W) for k in self.reward_names}
        self.last_terms = {k: np.zeros((W, N), np.float32) for k in self.reward_names}
        self._episode_seeds = np.zeros(W, np.int64)
        self._sensing_keys = np.zeros(W, np.uint64)  # per-world keys of perception noise (randomness.py)
        self._world_obstacles = [l.obstacle_set() for l in self.world_layouts]  # each world's, kept between its episodes
        self._obstacles = ObstacleSet.stack(self._world_obstacles)
        self._perception: Perception | None = None
        self._obs: np.ndarray | None = None

    # ------------------------------------------------------------------ episodes

    def _check_capacity(self, layout: Layout) -> None:
        """Refuse a task whose spawn regions cannot hold its drones (clear error, early)."""
        check_task_fits_layout(self.config, layout)

    def _start_episodes(self, ids: np.ndarray, seeds: np.ndarray | None = None) -> None:
        """Begin a new episode in each listed world: new random obstacles, spawn, counters.

        seeds (k,) int64: the episodes' seeds (default: `episode_seed` of the world's count).
        Everything random in an episode (layout, obstacles, spawn, evader zigzag, perception
        noise and misses) follows from its seed alone.
        """
        if len(ids) == 0:
            return
        if seeds is None:
            seeds = np.array([episode_seed(self.seed, int(w), int(self.episode[w])) for w in ids], np.int64)
        layouts, xy = [], []
        changed = []  # worlds whose obstacles are new
        for w, s in zip(ids, seeds):
            rng = np.random.default_rng(int(s))
            base_i = int(rng.integers(len(self.pool))) if self.config.random_layout else int(self._base_index[w])
            base = self.pool[base_i]
            count = self.config.random_obstacle_count(base)
            given = None if self.config.random_obstacles is None else f"task.random_obstacles (now {count})"
            inst = base.with_random_obstacles(rng, count, count_source=given, passage_clearance=self.config.obstacle_clearance,
                                              passage_source="task.obstacle_clearance", restarts=EPISODE_RESTARTS) if count else base
            pts_p, pts_e = self._spawn_points[id(base)]
            pur = sample_separated(pts_p, self.n_pursuers, rng, SPAWN_SEPARATION)
            eva = sample_separated(pts_e, self.n_evaders, rng, SPAWN_SEPARATION)
            for team, drawn, n in (("pursuers", pur, self.n_pursuers), ("evaders", eva, self.n_evaders)):
                if drawn is None:  # the capacity check passed on other draws: this episode's seed found no room
                    raise LayoutError(f"{base.source}: episode seed {int(s)} found no room for {n} {team} "
                                      f"{SPAWN_SEPARATION} m apart in the spawn region; make it larger or use fewer {team}")
            layouts.append(inst)
            xy.append(np.concatenate([pur, eva]))
            if inst is not self.world_layouts[w]:  # new random obstacles or another layout: its arrays anew
                self._world_obstacles[w] = inst.obstacle_set()
                changed.append(int(w))
            self.world_layouts[w] = inst
        if self._random_obstacles or self.config.random_layout:
            self.physics.set_layouts(ids, layouts)
        self.physics.reset(ids, np.array(xy))
        self._episode_seeds[ids] = seeds
        self._sensing_keys[ids] = world_keys(seeds, SENSING_DOMAIN)
        self._evader_checked.reset(ids, seeds)
        self.steps[ids] = 0
        self.starts[ids] += 1
        self.captured[ids] = False
        self.heading[ids] = INITIAL_HEADING
        self.done[ids] = False
        self.outcome[ids] = ""
        self.capture_time[ids] = np.nan
        for k in self.reward_names:
            self.returns[k][ids] = 0.0
            self.last_terms[k][ids] = 0.0
        if changed:  # only their rows anew: restacking every world was a loop over all W in most steps
            self._obstacles = self._obstacles.with_rows(np.array(changed), [self._world_obstacles[w] for w in changed])

    def reset(self, seed: int | None = None, seeds: Sequence[int] | None = None) -> np.ndarray:
        """Start new episodes in every world. Obs (W, N, dim).

        A new `seed` restarts the default seed sequence at episode 0; without one each world
        takes the next episode of its sequence (the first reset after construction takes
        episode 0), so repeated `reset()` calls never replay an episode.
        seeds (W,) non-negative integers: explicit episode seeds, one per world (as in `reset_worlds`).
        """
        explicit = None if seeds is None else check_seeds(seeds, self.n_worlds, "reset seeds")
        if seed is not None:
            self.seed = check_seed(seed, "reset seed")
        if self.closed:
            self._reopen()
        if seed is not None:
            self.episode[:] = 0
        elif self._obs is not None:
            self.episode += 1
        self._start_episodes(np.arange(self.n_worlds), explicit)
        self._obs = self._observe()
        return self._obs.copy()

    def reset_worlds(self, world_ids: Sequence[int], seeds: Sequence[int] | None = None) -> np.ndarray:
        """Start new episodes in the listed worlds only; returns the full obs (W, N, dim).

        seeds (k,) non-negative integers: the new episodes' seeds. An episode is a function of
        its seed and the actions taken: the same seed replays it exactly in any world, however
        many worlds run. Without seeds each world takes the next of its default sequence.
        """
        self._check_open("reset_worlds()")
        if self._obs is None:
            raise RuntimeError("call reset() before reset_worlds(): the other worlds have no episode yet")
        raw = np.asarray(world_ids).reshape(-1)
        if raw.size and (raw.dtype == bool or not np.issubdtype(raw.dtype, np.integer)):
            raise ValueError(f"reset_worlds world_ids: expected integer world indices, got {world_ids!r}")
        ids = raw.astype(np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= self.n_worlds or len(np.unique(ids)) != ids.size):
            raise ValueError(f"reset_worlds world_ids: expected distinct indices in 0..{self.n_worlds - 1}, got {ids.tolist()}")
        explicit = None if seeds is None else check_seeds(seeds, len(ids), "reset_worlds seeds")
        self.episode[ids] += 1
        self._start_episodes(ids, explicit)
        self._obs = self._reobserve(ids, self._obs)
        return self._obs.copy()

    @property
    def evader_model(self):
        """What flies the evaders: the task's model (an EscapeModel, or a FileEvaderModel for
        `evader.model: FILE.py:NAME`), or any object with reset and compute set here before the
        first reset (docs/env_api.md), whose answers are then checked as a file model's are."""
        return self._evader_model

    @evader_model.setter
    def evader_model(self, model) -> None:
        self._evader_checked = checked_evader_model(model, (self.n_worlds, self.n_evaders, 2))
        self._evader_model = model

    @property
    def physics(self) -> BatchedPhysics:
        """The worlds' MuJoCo simulation (RuntimeError between close() and the next reset())."""
        self._check_open("physics")
        return self._physics

    def close(self) -> None:
        """Free the MuJoCo batch (its worker threads and simulation memory); harmless to call again.

        Until the next reset(), step(), reset_worlds(), the state views and `physics` raise
        RuntimeError saying close() came first. reset() builds a new batch and plays on as if the
        env had never been closed: reset() the next episode of each world, reset(seed=s) episode 0
        of seed s, bit for bit the episodes of an env never closed. Also `with PursuitEnv(...) as env:`.
        """
        self._physics = None
        self.closed = True

    def __enter__(self) -> "PursuitEnv":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check_open(self, what: str) -> None:
        if self.closed:
            raise RuntimeError(f"PursuitEnv {what} called after close(): call reset() to start again")

    def _reopen(self) -> None:
        """A new batch on the worlds' base layouts, as __init__ made it; the reset that follows
        places every world (and gives each its episode's layout when they change per episode)."""
        self._physics = BatchedPhysics(self.config, [self.pool[i] for i in self._base_index], nthread=self._nthread)
        self.closed = False

    @property
    def started(self) -> bool:
        """Whether reset() has started episodes (step, reset_worlds and the state views need them)."""
        return self._obs is not None

    # ------------------------------------------------------------------ state views

    def _view(self, ids: np.ndarray | None = None) -> WorldView:
        """The true state of every world, or of the listed worlds ids (k,) only (rows in that order)."""
        N = self.n_pursuers
        pos = self.physics.positions()
        vel = self.physics.velocities()
        heading, captured, obstacles = self.heading, self.captured, self._obstacles
        if ids is not None:
            pos, vel, heading, captured, obstacles = pos[ids], vel[ids], heading[ids], captured[ids], obstacles.take(ids)
        obstacles = _with_caught(obstacles, captured, pos[:, N:, :2], CAUGHT_BODY_RADIUS)
        return WorldView(pos[:, :N, :2], vel[:, :N, :2], heading, pos[:, N:, :2], vel[:, N:, :2], captured, obstacles)

    def _obstacles_with_captured(self, evader_xy: np.ndarray, radius: float) -> ObstacleSet:
        """The layout's obstacles plus a cylinder of `radius` (m) at each caught evader: the
        drone's body for perception, its capture disc for the free evaders' escape."""
        return _with_caught(self._obstacles, self.captured, evader_xy, radius)

    def _observe(self, view: WorldView | None = None) -> np.ndarray:
        """Observations of the current state (view: `_view()`'s, if already taken)."""
        view = self._view() if view is None else view
        # draws keyed by (episode, step): the same whether or not other worlds restart now
        self._perception = perceive(view, self.config, WorldRandom(self._sensing_keys, self.steps))
        return build_observations(view, self._perception, self.obs_spec)

    def _reobserve(self, ids: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """`obs` (W, N, obs_dim), the observation of the current state of every world but the
        listed ones ids (k,), with those worlds perceived anew (say, as their episodes restart);
        self._perception gets their rows too. The same numbers `_observe` gives (perception is
        per world, its draws keyed by each world's episode and step), at the cost of k worlds
        instead of W: with many worlds some episode ends in nearly every step. No ids: `obs`
        as it is (reset_worlds([]) restarts nothing)."""
        if len(ids) == 0:  # an empty obstacle batch has no shape to perceive with
            return obs
        view = self._view(ids)
        part = perceive(view, self.config, WorldRandom(self._sensing_keys[ids], self.steps[ids]))
        rows = {}
        for f in dataclasses.fields(Perception):
            whole = getattr(self._perception, f.name).copy()  # new arrays: views taken before keep their values
            whole[ids] = getattr(part, f.name)
            rows[f.name] = whole
        self._perception = Perception(**rows)
        obs = obs.copy()
        obs[ids] = build_observations(view, part, self.obs_spec)
        return obs

    def observe_as(self, config: TaskConfig) -> np.ndarray:
        """Observations (W, N, obs_dim) float32 of the current state as perceived under `config`,
        which may differ from the env's task only in its perception keys (sensing.PERCEPTION_KEYS).

        For a privileged teacher in training: what the pursuers would observe now with, say, an
        all-round view. It changes nothing in the env; noise and misses, if `config` has any,
        are drawn from the same per-world streams as the env's own observations.
        """
        self._check_open("observe_as()")
        if self._obs is None:
            raise RuntimeError("call reset() before observe_as(): no episode has started")
        config = checked_task_config(config, "observe_as config")
        changed = [f.name for f in dataclasses.fields(TaskConfig)
                   if f.name not in PERCEPTION_KEYS and getattr(config, f.name) != getattr(self.config, f.name)]
        if changed:
            raise ValueError(f"observe_as: the config differs from the env's task in {', '.join(changed)}; "
                             f"only perception keys may ({', '.join(PERCEPTION_KEYS)})")
        view = self._view()
        perception = perceive(view, config, WorldRandom(self._sensing_keys, self.steps))
        return build_observations(view, perception, self.obs_spec)

    def global_state(self) -> np.ndarray:
        """(W, state_dim) float32: the true state for centralised critics (layout of
        `observations.build_global_state`: positions m, velocities m/s, world frame)."""
        self._check_open("global_state()")
        if self._obs is None:
            raise RuntimeError("call reset() before global_state(): no episode has started")
        return build_global_state(self._view(), self.steps / self.config.max_steps)

    # ------------------------------------------------------------------ stepping

    def _check_actions(self, actions: np.ndarray) -> np.ndarray:
        shape = (self.n_worlds, self.n_pursuers, 2)
        try:
            raw = plain_array(actions, "actions")
        except MaskedValues:
            raise
        except ValueError:  # nested lists of unequal lengths
            raise ValueError(f"actions: expected shape {shape} (worlds, pursuers, vx vy), got a ragged list") from None
        if raw.dtype.kind not in "fiu":  # bools, text, objects and complex numbers are no velocities
            raise ValueError(f"actions: expected real numbers (worlds, pursuers, vx vy), got an array of dtype {raw.dtype}")
        a = raw.astype(np.float64)
        if a.shape != shape:
            raise ValueError(f"actions: expected shape {shape} (worlds, pursuers, vx vy), got {a.shape}")
        if not np.isfinite(a).all():
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
            raise ValueError(f"actions: non-finite value {a[bad]} at index {bad}")
        return np.clip(a, -1.0, 1.0)

    def step(self, actions: np.ndarray):
        """Advance every world one decision step (docs/env_api.md has the whole contract).

        actions (W, N, 2): desired velocity of each pursuer, world (layout) frame, as a
        fraction of pursuer_speed. Returns obs (W, N, obs_dim) float32, reward (W, N)
        float32, terminated (W,) bool, truncated (W,) bool, and info: "reward_terms"
        {term: (W, N) float32}, "outcome" (W,) str, "episodes" [EpisodeRecord],
        "final_obs" (W, N, obs_dim), "final_state" (W, state_dim).
        """
        self._check_open("step()")
        if self._obs is None:
            raise RuntimeError("call reset() before step()")
        a = self._check_actions(actions)
        cfg = self.config
        N = self.n_pursuers
        active = ~self.done
        pos0 = self.physics.positions()[..., :2]
        vel0 = self.physics.velocities()[..., :2]
        free_before = ~self.captured
        evader_cmd = self._evader_checked.compute(
            pos0[:, N:], vel0[:, N:], pos0[:, :N], vel0[:, :N], free_before & active[:, None], self._obstacles_with_captured(pos0[:, N:], cfg.capture_radius), cfg.control_dt
        )
        evader_cmd = np.where((free_before & active[:, None])[..., None], evader_cmd, 0.0)
        pursuer_cmd = a * cfg.pursuer_speed * active[:, None, None]
        # an ended episode's world (no auto_reset) waits for its reset unsimulated
        # a divergence is warned once this step is whole: a warnings filter of "error" raises it then
        contacts = self.physics.step(np.concatenate([pursuer_cmd, evader_cmd], axis=1), strict=False, worlds=active, warn=False)
        # a world whose physics went bad (a violent crash) ends as a collision
        diverged = self.physics.diverged & active
        contacts[diverged] = True

        pos = self.physics.positions()[..., :2]
        vel = self.physics.velocities()[..., :2]
        self.heading = update_heading(self.heading, vel[:, :N], heading_min_speed(cfg.pursuer_speed))
        events = detect_events(pos[:, :N], pos[:, N:], self.captured, contacts[:, :N], self._obstacles, cfg)
        # a diverged world's positions are MuJoCo's reset (a point world's drones all on one
        # spot), not the drones': no captures from them, no terms measured on them
        events.new_captures &= ~diverged[:, None]
        terms = reward_terms(cfg, events, pos0[:, :N], pos[:, :N], pos[:, N:], pos0[:, N:], free_before)
        for k in ("progress", "proximity", "spread"):
            terms[k] = np.where(diverged[:, None], np.float32(0.0), terms[k])
        for k in terms:  # ended worlds get 0.0 (multiplying a negative term by False would give -0.0)
            terms[k] = np.where(active[:, None], terms[k], np.float32(0.0))
        self.captured |= events.new_captures & active[:, None]
        self.steps += active
        success = self.captured.all(-1) & active
        collision = events.collided.any(-1) & active
        terminated = success | collision
        truncated = (self.steps >= cfg.max_steps) & active & ~terminated
        self.capture_time = np.where(success & ~collision & np.isnan(self.capture_time), np.round(self.steps * cfg.control_dt, 9), self.capture_time)  # 16.4, not 16.400000000000002
        outcome = np.full(self.n_worlds, "", dtype=object)
        outcome[success] = "success"
        outcome[collision] = "collision"  # a collision in the step of a capture still fails
        outcome[truncated] = "timeout"
        finished = terminated | truncated
        caught_w, caught_e = np.nonzero(events.new_captures & (active & ~finished)[:, None])
        if len(caught_w):  # caught evaders stop where they are (DESIGN.md section 1), at once
            self.physics.halt(caught_w, caught_e + N)
        self.outcome = np.where(finished, outcome, self.outcome)
        self.done |= finished

        known_before = self._perception.known
        view = self._view()  # the state the observation and info's final_state describe
        obs = self._observe(view)
        if self.extra_rewards:  # after the observation: a term may pay for what the pursuers now know
            step = StepView(cfg, a, pos0[:, :N], pos[:, :N], vel[:, :N], pos0[:, N:], pos[:, N:], vel[:, N:], free_before,
                            events.new_captures & active[:, None], self.captured, events.collided & active[:, None],
                            events.obstacle_gap, events.nearest_mate, known_before, self._perception.known,
                            self._perception.seen, self.steps, outcome)
            kept = active & ~diverged
            for k, term in self.extra_rewards.items():
                values = term_values(k, term, step, (self.n_worlds, N), "PursuitEnv extra_rewards", paid=kept)
                terms[k] = values + np.float32(0.0)  # + 0: no -0.0 (term_values gives 0 where not kept)
        reward = sum(terms.values()).astype(np.float32)
        for k in self.reward_names:
            self.returns[k] += terms[k].mean(-1)
            self.last_terms[k] = terms[k].copy()
        info = {"reward_terms": terms, "outcome": outcome, "episodes": [], "final_obs": obs.copy(),
                "final_state": build_global_state(view, self.steps / cfg.max_steps)}
        ids = np.flatnonzero(finished)
        for w in ids:
            info["episodes"].append(self._record(int(w), str(outcome[w])))
        if self.auto_reset and len(ids):
            self.episode[ids] += 1
            self._start_episodes(ids)
            obs = self._reobserve(ids, obs)
        self._obs = obs
        if self.physics.divergence is not None:
            warnings.warn(self.physics.divergence, RuntimeWarning, stacklevel=2)
        return obs.copy(), reward, terminated, truncated, info

    def _record(self, w: int, outcome: str) -> EpisodeRecord:
        t = self.capture_time[w]
        return EpisodeRecord(
            world=w,
            episode=int(self.episode[w]),
            seed=int(self._episode_seeds[w]),
            outcome=outcome,
            steps=int(self.steps[w]),
            time_to_capture=None if np.isnan(t) else float(t),
            returns={k: float(self.returns[k][w]) for k in self.reward_names},
            captured=int(self.captured[w].sum()),
            layout=self.world_layouts[w].name,
        )

    # ------------------------------------------------------------------ recorders

    def snapshot(self, world: int = 0) -> Snapshot:
        """Everything a recorder needs about one world now (copies; reading never steers)."""
        if isinstance(world, (bool, np.bool_)) or not isinstance(world, (int, np.integer)) or not 0 <= world < self.n_worlds:
            raise ValueError(f"world: {world!r} is not a world index in 0..{self.n_worlds - 1}")
        self._check_open("snapshot()")
        if self._perception is None:
            raise RuntimeError("call reset() before snapshot(): no episode has started, nothing has been perceived")
        world = int(world)
        N = self.n_pursuers
        st = self.physics.state()
        per = self._perception
        return Snapshot(
            step=int(self.steps[world]),
            time=float(self.steps[world] * self.config.control_dt),
            layout=self.world_layouts[world],
            pursuer_pos=st.pos[world, :N],
            pursuer_vel=st.vel[world, :N],
            pursuer_quat=st.quat[world, :N],
            evader_pos=st.pos[world, N:],
            evader_vel=st.vel[world, N:],
            evader_quat=st.quat[world, N:],
            captured=self.captured[world].copy(),
            seen=per.seen[world].copy(),
            known=per.known[world].copy(),
            heading=self.heading[world].copy(),
            commands=self.physics.commands[world].copy(),
            thrust=st.thrust[world],
            rays=per.rays[world].copy(),
            reward_terms={k: v[world].copy() for k, v in self.last_terms.items()},
            outcome=str(self.outcome[world]),
            config=self.config,
        )
