"""A hand-made pursuer team after Janosov et al. 2017 ("Group chasing tactics"): the baseline.

`HeuristicTeam` is a `Policy`: it acts from the observation vectors alone (see obs_spec.py),
so it works under partial observability and noise, in either fidelity, and in real flights.
Per pursuer, every decision step:

1. remember each free evader it knows (position, velocity, age; per world, reset per episode);
2. pick a target among the fresh or remembered evaders: the nearest, unless enough visible
   teammates are closer to it (spreads the team over several evaders);
3. chase a predicted position of the target (lead by its velocity, the more the farther
   away), shifted around the target so that teammates close in from different sides;
4. without a target, go to where an evader was last seen, else sweep: head for the part of
   the arena it has not seen for longest (a coverage map built from its own rays and its
   teammates' positions, see coverage.py), away from teammates;
5. steer around what the rays see (a tangent-bug: follow an obstacle on one side until the
   way to the aim point opens);
6. stay safe: repel from teammates within `mate_radius` and from close walls, then pass
   the velocity through the `SafetyShield` (shield.py), which caps the speed toward any
   recent wall ray hit, teammate or captured evader so that the gap closes gradually (a
   collision fails the episode, so safety wins over speed).

Everything is vectorised over worlds, pursuers and rays; loops run only over a fixed
number of projection passes, never over drones.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from .coverage import CoverageMap, CoverageParams, check_tuning
from .obs_spec import ObsSpec, named_views
from .policy import check_observations, check_world_count, check_world_ids
from .planar import clip_unit, unit
from .shield import MIN_RAYS, SafetyShield, ShieldParams, check_rays

_TINY = 1e-9


@dataclasses.dataclass(frozen=True)
class HeuristicParams:
    """Tuning of the team. Distances in m, times in s, gains dimensionless unless stated.

    safety_buffer .. noise_margin tune the team's SafetyShield (see ShieldParams, same defaults).
    """

    lead_time_max: float = 1.5  # longest prediction horizon for a visible target (s)
    lead_gain: float = 0.6  # prediction horizon = lead_gain * distance / pursuer speed, capped
    encircle_gain: float = 1.2  # how hard a pursuer shifts around the target away from teammates
    encircle_ring: float = 0.7  # offset point on a ring of this fraction of the distance
    encircle_fade: float = 0.6  # within this distance (m) beyond capture the shift fades out
    memory_time: float = 15.0  # forget a last known position after this long (s)
    extrapolate_time: float = 1.0  # extrapolate a lost target along its velocity at most this long (s)
    reached_radius: float = 0.35  # a last known position closer than this is searched (m)
    assign_penalty: float = 3.0  # extra cost (m) of a target that enough closer teammates chase
    mate_radius: float = 0.5  # teammate repulsion starts here (m)
    mate_gain: float = 1.5  # teammate repulsion at contact, in units of pursuer speed
    wall_margin: float = 0.35  # wall repulsion starts here (m, ray range)
    wall_gain: float = 1.2  # wall repulsion at contact, in units of pursuer speed
    safety_buffer: float = ShieldParams.safety_buffer
    approach_rate: float = ShieldParams.approach_rate
    response_time: float = ShieldParams.response_time
    safety_passes: int = ShieldParams.safety_passes
    hit_memory: int = ShieldParams.hit_memory
    mate_memory: float = ShieldParams.mate_memory
    noise_margin: float = ShieldParams.noise_margin
    open_distance: float = 0.6  # a direction is open if its ray reaches this far (or the goal) (m)
    side_timeout: float = 10.0  # follow an obstacle on one side at most this long, then the other (s)
    coverage: CoverageParams = dataclasses.field(default_factory=CoverageParams)

    def __post_init__(self):
        shield_fields = tuple(f.name for f in dataclasses.fields(ShieldParams))  # checked by ShieldParams
        check_tuning(self, positive=("encircle_fade",), skip=shield_fields + ("coverage",))
        if not isinstance(self.coverage, CoverageParams):
            raise ValueError(f"HeuristicParams.coverage: expected CoverageParams, got {self.coverage!r}")

    @property
    def shield(self) -> ShieldParams:
        """The safety-shield fields as ShieldParams."""
        return ShieldParams(**{f.name: getattr(self, f.name) for f in dataclasses.fields(ShieldParams)})


class HeuristicTeam:
    """Group chasing from observations only; `act` gives (W, N, 2) in [-1, 1] (fraction of max speed).

    pursuer_speed (m/s) scales actions; capture_radius (m) sizes captured evaders as
    hazards; teammate/obstacle clearance (m) are the collision distances of the task;
    control_dt (s) is the decision interval; ray_range (m) the cap of range readings;
    perception_radius (m) bounds what the coverage map counts as seen; field_of_view (rad) is
    the teammates' view, which the shield needs to know who gives way; position_noise (m) is
    the std of perceived positions, which the shield keeps a margin for around teammates;
    share_teammates (task key) says teammates broadcast their positions (both rules then moot).
    """

    name = "heuristic"
    has_shield = True  # its own SafetyShield is built in: eval/render/fly do not add another

    def __init__(
        self,
        pursuer_speed: float = 0.3,
        capture_radius: float = 0.3,
        obstacle_clearance: float = 0.1,
        teammate_clearance: float = 0.2,
        control_dt: float = 0.1,
        ray_range: float = 2.0,
        perception_radius: float = 2.0,
        params: HeuristicParams | None = None,
        field_of_view: float = 2 * math.pi,
        position_noise: float = 0.0,
        share_teammates: bool = False,
    ):
        if not isinstance(pursuer_speed, numbers.Real):  # HeuristicTeam(config) failed deep in math.isfinite
            raise TypeError(f"HeuristicTeam: pursuer_speed must be a number, got {type(pursuer_speed).__name__}; "
                            f"for a task config use HeuristicTeam.from_config(config)")
        for key, value in (("pursuer_speed", pursuer_speed), ("control_dt", control_dt), ("ray_range", ray_range)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"HeuristicTeam: {key} must be a positive number, got {value!r}")
        self.speed = float(pursuer_speed)
        self.capture_radius = float(capture_radius)
        self.obstacle_clearance = float(obstacle_clearance)
        self.teammate_clearance = float(teammate_clearance)
        self.dt = float(control_dt)
        self.ray_range = float(ray_range)
        self.perception_radius = float(perception_radius)
        self.p = params or HeuristicParams()
        self.shield = SafetyShield(pursuer_speed, capture_radius, obstacle_clearance, teammate_clearance, ray_range, self.p.shield,
                                   control_dt, field_of_view, perception_radius, position_noise, share_teammates)
        self._n_worlds: int | None = None
        self._mem: dict = {}  # see _memory

    @classmethod
    def from_config(cls, config, params: HeuristicParams | None = None) -> "HeuristicTeam":
        """A team tuned to a TaskConfig's speeds, clearances, timing and perception (not its state).
        Under full observability the perception keys (radius, view, noise) take no part: every
        entity is known exactly there (sensing.perceive), so the team is the same whatever they say."""
        check_rays(config.n_rays, "the heuristic team")
        full = config.observability == "full"
        team = cls(config.pursuer_speed, config.capture_radius, config.obstacle_clearance,
                   config.teammate_clearance, config.control_dt, config.ray_range,
                   math.inf if full else config.perception_radius, params,
                   2 * math.pi if full else config.field_of_view, 0.0 if full else config.position_noise,
                   config.share_teammates)
        team.shield = SafetyShield.from_config(config, team.p.shield)  # the task's teammate sight (full observability)
        return team

    # ------------------------------------------------------------------ memory

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget the listed worlds (all, and resize, when world_ids is None)."""
        world_ids = check_world_ids(world_ids, n_worlds, f"policy {self.name}")
        self.shield.reset(n_worlds, world_ids)
        if world_ids is None or self._n_worlds != n_worlds:
            self._n_worlds = int(n_worlds)
            self._mem = {}
            return
        if self._mem:
            ids = np.asarray(world_ids, dtype=np.int64)
            self._mem["age"][ids] = np.inf
            self._mem["time"][ids] = 0.0
            self._mem["side"][ids] = 0
            self._mem["side_time"][ids] = 0.0
            self._mem["map"].reset(ids)

    def _memory(self, W: int, N: int, M: int, K: int) -> dict:
        """Per-world, per-pursuer memory, allocated on the first observation after a full reset.

        last_pos (W, N, M, 2) m world: where each evader was last known; last_vel (W, N, M, 2)
        m/s; age (W, N, M) s since then (inf: nothing to go to); time (W,) s since the
        episode started; side (W, N) +1/-1 while following an obstacle counter-/clockwise, 0
        otherwise; side_time (W, N) s on that side; map: the CoverageMap of every pursuer.
        The shield's hit memory is reset with it.
        """
        m = self._mem
        if not m or m["age"].shape != (W, N, M) or m["n_rays"] != K:
            self.shield.reset(W)
            self._mem = m = {
                "last_pos": np.zeros((W, N, M, 2)),
                "last_vel": np.zeros((W, N, M, 2)),
                "age": np.full((W, N, M), np.inf),
                "time": np.zeros(W),
                "side": np.zeros((W, N), np.int64),
                "side_time": np.zeros((W, N)),
                "map": CoverageMap(W, N, self.p.coverage),
                "n_rays": K,
            }
        return m

    # ------------------------------------------------------------------ acting

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1]: desired world-frame velocity / pursuer_speed."""
        o, mem, sweep, planned = self.observe(obs, spec)
        actions = self.decide(o, mem, sweep, planned)
        self.tick()
        return actions

    def decide(self, o: dict, mem: dict, sweep: np.ndarray, planned: np.ndarray) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1] from what `observe` returned for this decision step.

        Reads the evader memory and the sweep aim, not the episode clock, so it may come before
        or after `tick`; it updates only the obstacle-following side and the shield's memory.
        """
        target, has_target = self._choose_target(mem, o)
        aim = np.where(has_target[..., None], self._chase(mem, o, target), sweep)
        direction = np.where((planned & ~has_target)[..., None], unit(aim), self._steer(mem, o, aim))
        v = self.speed * direction
        v = v + self._repulsion(o)
        v = self.shield.filter(v, o)
        return clip_unit(v / self.speed)

    def observe(self, obs: np.ndarray, spec: ObsSpec) -> tuple[dict, dict, np.ndarray, np.ndarray]:
        """Take in one decision step's observations (W, N, spec.dim): update the memory of
        evaders and the coverage map, choose the sweep goal. Returns (named observation views,
        the memory (see _memory), sweep aim (W, N, 2) m relative, planned (W, N) bool).
        Call `tick` once the step is decided (act does both)."""
        obs = check_observations(obs, spec, "HeuristicTeam")
        _check_spec(spec)
        W, N = obs.shape[:2]
        if self._n_worlds is None:
            self._n_worlds = W
        check_world_count(W, self._n_worlds, f"policy {self.name}")
        o = _parse(obs, spec)
        mem = self._memory(W, N, spec.n_evaders, spec.n_rays)
        mate_abs = o["pos"][:, :, None] + o["mate_rel"]
        see = min(self.p.coverage.see_radius, self.perception_radius)
        mem["map"].update(o["pos"], o["rays"], o["ray_dirs"], self.ray_range, mate_abs, o["mate_vis"], mem["time"], see)
        self._remember(mem, o)
        sweep, planned = self._sweep(mem, o, mate_abs)
        return o, mem, sweep, planned

    def tick(self) -> None:
        """Advance the episode clock by one decision interval."""
        self._mem["time"] += self.dt

    def evader_estimates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """From the memory: (estimated evader positions (W, N, M, 2) m layout frame, their last
        velocities (W, N, M, 2) m/s, age (W, N, M) s since known, inf where nothing is known)."""
        mem = self._mem
        return self._estimate(mem), mem["last_vel"], mem["age"]

    def _remember(self, mem: dict, o: dict) -> None:
        """Update the last known positions; forget the ones that were searched or are too old."""
        known = o["ev_vis"] & ~o["ev_cap"]
        mem["last_pos"] = np.where(known[..., None], o["pos"][:, :, None] + o["ev_rel"], mem["last_pos"])
        mem["last_vel"] = np.where(known[..., None], o["ev_vel"], mem["last_vel"])
        mem["age"] = np.where(known, 0.0, mem["age"] + self.dt)
        gone = o["ev_cap"] | (mem["age"] > self.p.memory_time)
        est = self._estimate(mem)
        searched = ~known & (np.linalg.norm(est - o["pos"][:, :, None], axis=-1) < self.p.reached_radius)
        mem["age"] = np.where(gone | searched, np.inf, mem["age"])

    def _estimate(self, mem: dict) -> np.ndarray:
        """(W, N, M, 2) m world: last known evader positions moved along their velocity a while."""
        lag = np.minimum(np.where(np.isfinite(mem["age"]), mem["age"], 0.0), self.p.extrapolate_time)
        return mem["last_pos"] + mem["last_vel"] * lag[..., None]

    def _choose_target(self, mem: dict, o: dict) -> tuple[np.ndarray, np.ndarray]:
        """Target evader index (W, N) and whether there is one (W, N)."""
        valid = np.isfinite(mem["age"])
        rel = self._estimate(mem) - o["pos"][:, :, None]  # (W, N, M, 2)
        d_me = np.linalg.norm(rel, axis=-1)
        # distance of each visible teammate to each evader estimate: (W, N, N-1, M)
        d_mate = np.linalg.norm(rel[:, :, None] - o["mate_rel"][:, :, :, None], axis=-1)
        closer = (d_mate < d_me[:, :, None]) & o["mate_vis"][..., None]
        rank = closer.sum(2)
        team = 1 + o["mate_vis"].sum(2)
        n_targets = np.maximum(valid.sum(-1), 1)
        capacity = np.ceil(team / n_targets)[..., None]
        cost = d_me + self.p.assign_penalty * (rank >= capacity) + np.where(valid, 0.0, np.inf)
        target = np.argmin(cost, axis=-1)
        return target, valid.any(-1)

    def _chase(self, mem: dict, o: dict, target: np.ndarray) -> np.ndarray:
        """(W, N, 2) m relative: a predicted target position, shifted to encircle it."""
        take = np.broadcast_to(target[..., None, None], target.shape + (1, 2))
        est = np.take_along_axis(self._estimate(mem), take, 2)[:, :, 0]
        vel = np.take_along_axis(mem["last_vel"], take, 2)[:, :, 0]
        age = np.take_along_axis(mem["age"], target[..., None], 2)[..., 0]
        rel = est - o["pos"]
        d = np.linalg.norm(rel, axis=-1)
        lead = np.minimum(self.p.lead_gain * d / self.speed, self.p.lead_time_max) * (age <= self.dt)
        pred = rel + vel * lead[..., None]
        return pred + self._encircle_offset(o, pred, d)

    def _encircle_offset(self, o: dict, pred: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(W, N, 2) m: shift of the aim point around the target, away from teammates' bearings.

        Teammates within 1.5 x my distance of the target count as chasing it too; each pushes
        my bearing (seen from the target) away from its own until they are 2*pi/n apart.
        """
        mine = np.arctan2(-pred[..., 1], -pred[..., 0])  # my bearing seen from the target
        from_target = o["mate_rel"] - pred[:, :, None]  # teammates seen from the target
        theirs = np.arctan2(from_target[..., 1], from_target[..., 0])
        dist_t = np.linalg.norm(from_target, axis=-1)
        chasing = o["mate_vis"] & (dist_t < 1.5 * np.maximum(d, 0.5)[..., None])
        n = 1 + chasing.sum(-1)
        sep = 2 * np.pi / n
        diff = _wrap(mine[..., None] - theirs)
        overlap = np.clip(sep[..., None] - np.abs(diff), 0.0, None) / sep[..., None]
        # identical bearings have no side to go to: break the tie by pursuer order
        side = np.where(np.abs(diff) > 1e-6, np.sign(diff), o["tie_side"])
        push = (side * overlap * chasing).sum(-1)
        fade = np.clip((d - self.capture_radius) / self.p.encircle_fade, 0.0, 1.0)
        shift = np.clip(self.p.encircle_gain * push, -np.pi / 2, np.pi / 2) * fade
        ring = self.p.encircle_ring * d
        want = mine + shift
        now = np.stack([np.cos(mine), np.sin(mine)], -1)
        new = np.stack([np.cos(want), np.sin(want)], -1)
        return ring[..., None] * (new - now)

    def _sweep(self, mem: dict, o: dict, mate_abs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Aim (W, N, 2) m relative toward the stalest part of the arena this pursuer knows, and
        whether it follows a planned path there (W, N) bool (else it steers straight at it)."""
        cover: CoverageMap = mem["map"]
        cover.choose_goal(o["pos"], mate_abs, o["mate_vis"], mem["time"], self.dt)
        return cover.waypoint(o["pos"], mem["time"])

    def _steer(self, mem: dict, o: dict, aim: np.ndarray) -> np.ndarray:
        """(W, N, 2) unit direction toward `aim` (relative, m), around obstacles the rays see.

        Straight at the aim when its direction is open to min(distance, open_distance);
        otherwise along the first open ray turning to one side (kept while blocked, switched
        after side_timeout): a tangent-bug that follows walls to their ends and doors.
        """
        K = o["rays"].shape[-1]
        direct = unit(aim)
        if K == 0:
            mem["side"][:] = 0
            return direct
        rays = o["rays"]
        dist = np.linalg.norm(aim, axis=-1)
        need = np.minimum(dist, self.p.open_distance)
        step = 2 * np.pi / K
        phi = np.arctan2(aim[..., 1], aim[..., 0])
        lo = np.floor(phi / step).astype(np.int64) % K
        hi = (lo + 1) % K
        blocked = np.minimum(np.take_along_axis(rays, lo[..., None], -1), np.take_along_axis(rays, hi[..., None], -1))[..., 0] < need
        is_open = rays >= need[..., None]  # (W, N, K)
        # rays in order of turning away from phi: ccw starts at hi, cw at lo
        turn = np.arange(K)
        ccw = (hi[..., None] + turn) % K
        cw = (lo[..., None] - turn) % K
        first_ccw = _first_true(np.take_along_axis(is_open, ccw, -1))
        first_cw = _first_true(np.take_along_axis(is_open, cw, -1))
        side = mem["side"]
        fresh = blocked & (side == 0)
        side = np.where(fresh, np.where(first_ccw <= first_cw, 1, -1), side)
        mem["side_time"] = np.where(blocked & ~fresh, mem["side_time"] + self.dt, 0.0)
        flip = mem["side_time"] > self.p.side_timeout
        side = np.where(flip, -side, side)
        mem["side_time"] = np.where(flip, 0.0, mem["side_time"])
        side = np.where(blocked, side, 0)
        mem["side"] = side
        k = np.where(side > 0, np.take_along_axis(ccw, np.minimum(first_ccw, K - 1)[..., None], -1)[..., 0],
                     np.take_along_axis(cw, np.minimum(first_cw, K - 1)[..., None], -1)[..., 0])
        none_open = np.where(side > 0, first_ccw, first_cw) >= K
        k = np.where(none_open, np.argmax(rays, -1), k)
        around = o["ray_dirs"][k]
        return np.where(blocked[..., None], around, direct)

    # ------------------------------------------------------------------ safety

    def _repulsion(self, o: dict) -> np.ndarray:
        """(W, N, 2) m/s: push away from close teammates and close walls."""
        p = self.p
        d_mate = np.linalg.norm(o["mate_rel"], axis=-1)
        span = max(p.mate_radius - self.teammate_clearance, _TINY)
        w_mate = np.clip((p.mate_radius - d_mate) / span, 0.0, 1.0) ** 2 * o["mate_vis"]
        v = -(w_mate[..., None] * unit(o["mate_rel"])).sum(2) * p.mate_gain * self.speed
        if o["rays"].shape[-1]:
            span = max(p.wall_margin - self.obstacle_clearance, _TINY)
            w_wall = np.clip((p.wall_margin - o["rays"]) / span, 0.0, 1.0) ** 2  # (W, N, K)
            push = -(w_wall[..., None] * o["ray_dirs"]).sum(2)
            v = v + p.wall_gain * self.speed * unit(push) * w_wall.max(-1, keepdims=True)
        return v


# ---------------------------------------------------------------------- helpers


def _check_spec(spec: ObsSpec) -> None:
    """ValueError unless observations of `spec` hold an evader to chase and MIN_RAYS range readings."""
    if spec.n_evaders < 1:
        raise ValueError(f"HeuristicTeam: the observations hold no evaders (spec n_evaders {spec.n_evaders}): nothing to chase")
    if spec.n_rays < MIN_RAYS:
        raise ValueError(f"HeuristicTeam: the observations hold {spec.n_rays} range readings (spec n_rays); the team sees "
                         f"walls only through them and needs at least {MIN_RAYS}")


def _parse(obs: np.ndarray, spec: ObsSpec) -> dict[str, np.ndarray]:
    """Named views of observations (W, N, dim) (obs_spec.named_views), plus tie_side (N, N-1)."""
    N = obs.shape[1]
    # teammate slot k of pursuer i holds pursuer k if k < i, else k + 1 (index order skipping i):
    # the lower index yields, so +1 exactly where the slot is below i
    tie = np.where(np.arange(N - 1)[None, :] < np.arange(N)[:, None], 1.0, -1.0)
    return {**named_views(obs, spec), "tie_side": tie}


def _first_true(a: np.ndarray) -> np.ndarray:
    """Index of the first True along the last axis; the axis length where there is none."""
    return np.where(a.any(-1), np.argmax(a, -1), a.shape[-1])


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi
