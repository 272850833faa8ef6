"""A hand-made pursuer team after Janosov et al. 2017 ("Group chasing tactics"): the baseline.

`HeuristicTeam` is a `Policy`: it acts from the observation vectors alone (see obs_spec.py),
so it works under partial observability and noise, in either fidelity, and in real flights.
Per pursuer, every decision step:

1. remember each free evader it knows (position, velocity, age; per world, reset per episode);
2. pick a target among the fresh or remembered evaders: the nearest, unless enough visible
   teammates are closer to it (spreads the team over several evaders);
3. chase a predicted position of the target (lead by its velocity, the more the farther
   away), shifted around the target so that teammates close in from different sides;
4. without a target, go to where an evader was last seen, else sweep: fly straight toward
   open, unvisited space (the longest free rays, away from teammates and from where it
   has been);
5. stay safe: repel from teammates within `mate_radius` and from close walls, and cap the
   speed toward any wall ray, teammate or captured evader so that the gap closes
   gradually (a collision fails the episode, so safety wins over speed).

Everything is vectorised over worlds, pursuers and rays; loops run only over a fixed
number of projection passes, never over drones.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .obs_spec import ObsSpec

_TINY = 1e-9


@dataclasses.dataclass(frozen=True)
class HeuristicParams:
    """Tuning of the team. Distances in m, times in s, gains dimensionless unless stated."""

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
    safety_buffer: float = 0.1  # keep this much beyond each clearance (m)
    approach_rate: float = 1.5  # max closing speed toward a hazard = rate * (gap - buffer) (1/s)
    safety_passes: int = 4  # projection passes of the closing-speed limits
    explore_persist: float = 0.6  # weight of keeping the current sweep heading
    explore_spread: float = 0.5  # weight of heading away from visible teammates
    explore_novelty: float = 0.8  # weight of heading away from where it has been
    explore_blocked: float = 0.8  # a ray shorter than this (m) is not a sweep heading
    trace_time: float = 12.0  # time constant of the "where it has been" average (s)


class HeuristicTeam:
    """Group chasing from observations only; `act` gives (W, N, 2) in [-1, 1] (fraction of max speed).

    pursuer_speed (m/s) scales actions; capture_radius (m) sizes captured evaders as
    hazards; teammate/obstacle clearance (m) are the collision distances of the task;
    control_dt (s) is the decision interval; ray_range (m) the cap of range readings.
    """

    name = "heuristic"

    def __init__(
        self,
        pursuer_speed: float = 0.3,
        capture_radius: float = 0.3,
        obstacle_clearance: float = 0.1,
        teammate_clearance: float = 0.2,
        control_dt: float = 0.1,
        ray_range: float = 2.0,
        params: HeuristicParams | None = None,
    ):
        for key, value in (("pursuer_speed", pursuer_speed), ("control_dt", control_dt), ("ray_range", ray_range)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"HeuristicTeam: {key} must be a positive number, got {value!r}")
        self.speed = float(pursuer_speed)
        self.capture_radius = float(capture_radius)
        self.obstacle_clearance = float(obstacle_clearance)
        self.teammate_clearance = float(teammate_clearance)
        self.dt = float(control_dt)
        self.ray_range = float(ray_range)
        self.p = params or HeuristicParams()
        self._n_worlds: int | None = None
        self._mem: dict[str, np.ndarray] = {}

    @classmethod
    def from_config(cls, config, params: HeuristicParams | None = None) -> "HeuristicTeam":
        """A team tuned to a TaskConfig's speeds, clearances and timing (not its state)."""
        return cls(config.pursuer_speed, config.capture_radius, config.obstacle_clearance,
                   config.teammate_clearance, config.control_dt, config.ray_range, params)

    # ------------------------------------------------------------------ memory

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget the listed worlds (all, and resize, when world_ids is None)."""
        if world_ids is None or self._n_worlds != n_worlds:
            self._n_worlds = int(n_worlds)
            self._mem = {}
            return
        ids = np.asarray(world_ids, dtype=np.int64)
        if self._mem:
            self._mem["fresh"][ids] = True

    def _memory(self, W: int, N: int, M: int) -> dict[str, np.ndarray]:
        """Per-world, per-pursuer memory; allocated on the first observation of a reset batch.

        last_pos (W, N, M, 2) m world: where each evader was last known; last_vel (W, N, M, 2)
        m/s; age (W, N, M) s since then (inf: nothing to go to); heading (W, N) rad: sweep
        heading; trace (W, N, 2) m: slow average of own position; fresh (W,) bool: episode
        just started (initialise from the next observation).
        """
        m = self._mem
        if not m or m["last_pos"].shape[:3] != (W, N, M):
            self._mem = m = {
                "last_pos": np.zeros((W, N, M, 2)),
                "last_vel": np.zeros((W, N, M, 2)),
                "age": np.full((W, N, M), np.inf),
                "heading": np.zeros((W, N)),
                "trace": np.zeros((W, N, 2)),
                "fresh": np.ones(W, bool),
            }
        return m

    # ------------------------------------------------------------------ acting

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) in [-1, 1]: desired world-frame velocity / pursuer_speed."""
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim != 3 or obs.shape[1] != spec.n_pursuers or obs.shape[2] != spec.dim:
            raise ValueError(f"HeuristicTeam.act: expected observations (worlds, {spec.n_pursuers}, {spec.dim}), got {obs.shape}")
        if not np.isfinite(obs).all():
            raise ValueError("HeuristicTeam.act: observations contain NaN or inf")
        W, N = obs.shape[:2]
        if self._n_worlds is None:
            self._n_worlds = W
        if W != self._n_worlds:
            raise ValueError(f"HeuristicTeam.act: got {W} worlds, but reset() was called for {self._n_worlds}")
        o = _parse(obs, spec)
        mem = self._memory(W, N, spec.n_evaders)
        self._start_episodes(mem, o)
        self._remember(mem, o)
        target, has_target = self._choose_target(mem, o)
        v = np.where(has_target[..., None], self._chase(mem, o, target), self._sweep(mem, o))
        v = v + self._repulsion(o)
        v = self._limit_closing(v, o)
        return _clip_unit(v / self.speed)

    def _start_episodes(self, mem: dict, o: dict) -> None:
        fresh = mem["fresh"]
        if not fresh.any():
            return
        mem["age"][fresh] = np.inf
        mem["trace"][fresh] = o["pos"][fresh]
        away = _unit(-(o["mate_rel"] * o["mate_vis"][..., None]).sum(2))
        mem["heading"][fresh] = _best_heading(o["rays"], o["ray_dirs"], away, None, self.p, self.ray_range)[fresh]
        fresh[:] = False

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
        rate = self.dt / self.p.trace_time
        mem["trace"] += rate * (o["pos"] - mem["trace"])

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
        """(W, N, 2) m/s: toward a predicted target position, shifted to encircle it."""
        take = target[..., None, None]
        est = np.take_along_axis(self._estimate(mem), np.broadcast_to(take, target.shape + (1, 2)), 2)[:, :, 0]
        vel = np.take_along_axis(mem["last_vel"], np.broadcast_to(take, target.shape + (1, 2)), 2)[:, :, 0]
        age = np.take_along_axis(mem["age"], target[..., None], 2)[..., 0]
        rel = est - o["pos"]
        d = np.linalg.norm(rel, axis=-1)
        lead = np.minimum(self.p.lead_gain * d / self.speed, self.p.lead_time_max) * (age <= self.dt)
        pred = rel + vel * lead[..., None]
        aim = pred + self._encircle_offset(o, pred, d)
        return self.speed * _unit(aim)

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

    def _sweep(self, mem: dict, o: dict) -> np.ndarray:
        """(W, N, 2) m/s: keep a heading toward open space, away from teammates and the past."""
        away_mates = _unit(-(o["mate_rel"] * o["mate_vis"][..., None]).sum(2))
        away_past = _unit(o["pos"] - mem["trace"])
        bias = self.p.explore_spread * away_mates + self.p.explore_novelty * away_past
        heading = np.stack([np.cos(mem["heading"]), np.sin(mem["heading"])], -1)
        mem["heading"] = _best_heading(o["rays"], o["ray_dirs"], bias, heading, self.p, self.ray_range)
        return self.speed * np.stack([np.cos(mem["heading"]), np.sin(mem["heading"])], -1)

    # ------------------------------------------------------------------ safety

    def _repulsion(self, o: dict) -> np.ndarray:
        """(W, N, 2) m/s: push away from close teammates and close walls."""
        p = self.p
        d_mate = np.linalg.norm(o["mate_rel"], axis=-1)
        span = max(p.mate_radius - self.teammate_clearance, _TINY)
        w_mate = np.clip((p.mate_radius - d_mate) / span, 0.0, 1.0) ** 2 * o["mate_vis"]
        v = -(w_mate[..., None] * _unit(o["mate_rel"])).sum(2) * p.mate_gain * self.speed
        if o["rays"].shape[-1]:
            span = max(p.wall_margin - self.obstacle_clearance, _TINY)
            w_wall = np.clip((p.wall_margin - o["rays"]) / span, 0.0, 1.0) ** 2  # (W, N, K)
            push = -(w_wall[..., None] * o["ray_dirs"]).sum(2)
            v = v + p.wall_gain * self.speed * _unit(push) * w_wall.max(-1, keepdims=True)
        return v

    def _limit_closing(self, v: np.ndarray, o: dict) -> np.ndarray:
        """Cap the speed toward each hazard to approach_rate * (gap - buffer), by projection.

        Hazards: every ray (gap = range - obstacle clearance), every visible teammate (gap =
        distance - teammate clearance, half each since both move) and every captured evader
        (gap = distance - capture radius - obstacle clearance).
        """
        p = self.p
        dirs, limits = [], []
        if o["rays"].shape[-1]:
            dirs.append(o["ray_dirs"])
            limits.append(p.approach_rate * (o["rays"] - self.obstacle_clearance - p.safety_buffer))
        if o["mate_rel"].shape[2]:
            d = np.linalg.norm(o["mate_rel"], axis=-1)
            gap = np.where(o["mate_vis"], d - self.teammate_clearance - p.safety_buffer, np.inf)
            dirs.append(_unit(o["mate_rel"]))
            limits.append(0.5 * p.approach_rate * gap)
        d = np.linalg.norm(o["ev_rel"], axis=-1)
        gap = np.where(o["ev_cap"] & o["ev_vis"], d - self.capture_radius - self.obstacle_clearance - p.safety_buffer, np.inf)
        dirs.append(_unit(o["ev_rel"]))
        limits.append(p.approach_rate * gap)
        u = np.concatenate(dirs, axis=2)  # (W, N, H, 2)
        cap = np.concatenate(limits, axis=2)  # (W, N, H) m/s, may be negative (back off)
        for _ in range(p.safety_passes):
            excess = np.einsum("wnhk,wnk->wnh", u, v) - cap
            worst = np.argmax(excess, axis=-1)[..., None]
            amount = np.maximum(np.take_along_axis(excess, worst, -1), 0.0)
            v = v - amount * np.take_along_axis(u, worst[..., None], 2)[:, :, 0]
        return v


# ---------------------------------------------------------------------- helpers


def _parse(obs: np.ndarray, spec: ObsSpec) -> dict[str, np.ndarray]:
    """Named views of observations (W, N, dim); see obs_spec.py for units and frames."""
    W, N = obs.shape[:2]
    own = spec.group("self").view(obs)[:, :, 0]
    mates = spec.group("teammates").view(obs)
    ev = spec.group("evaders").view(obs)
    rays = spec.group("rays").view(obs)[:, :, 0] if spec.n_rays else np.zeros((W, N, 0))
    angles = 2 * np.pi * np.arange(spec.n_rays) / max(spec.n_rays, 1)
    # teammate j of pursuer i is stored in index order skipping i: the lower index yields
    tie = np.array([[1.0 if j < i else -1.0 for j in range(N) if j != i] for i in range(N)]).reshape(N, N - 1)
    return {
        "pos": own[..., 0:2],
        "vel": own[..., 2:4],
        "mate_rel": mates[..., 0:2],
        "mate_vis": mates[..., 4] > 0.5,
        "ev_rel": ev[..., 0:2],
        "ev_vel": ev[..., 2:4],
        "ev_vis": ev[..., 4] > 0.5,
        "ev_cap": ev[..., 6] > 0.5,
        "rays": rays,
        "ray_dirs": np.stack([np.cos(angles), np.sin(angles)], -1),  # (K, 2) world frame
        "tie_side": tie,
    }


def _best_heading(rays: np.ndarray, ray_dirs: np.ndarray, bias: np.ndarray, current: np.ndarray | None,
                  p: HeuristicParams, ray_range: float) -> np.ndarray:
    """(W, N) rad: the ray direction scoring best on openness, persistence and a bias vector (W, N, 2)."""
    W, N = bias.shape[:2]
    if ray_dirs.shape[0] == 0:
        b = bias if current is None else bias + p.explore_persist * current
        return np.arctan2(b[..., 1], b[..., 0])
    score = rays / ray_range + np.einsum("kc,wnc->wnk", ray_dirs, bias)
    if current is not None:
        score = score + p.explore_persist * np.einsum("kc,wnc->wnk", ray_dirs, current)
    score = np.where(rays < p.explore_blocked, score - 10.0, score)
    best = np.argmax(score, axis=-1)
    return np.arctan2(ray_dirs[best, 1], ray_dirs[best, 0])


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > _TINY, v / np.maximum(n, _TINY), 0.0)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _clip_unit(a: np.ndarray) -> np.ndarray:
    """Scale (..., 2) down to at most unit norm (direction kept), so both axes lie in [-1, 1]."""
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return a / np.maximum(n, 1.0)
