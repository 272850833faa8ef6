"""The evaders' escape model, after Janosov et al. 2017 ("Group chasing tactics: how to catch a
faster prey", New J. Phys. 19 053003), vectorised over worlds and evaders.

Each decision step every free evader picks a world-frame direction and flies it at the
constant `evader_speed`, through the same velocity interface as the pursuers:

1. panic: 0 while the nearest sensed chaser is beyond `calm_distance`, rising linearly to 1
   at `panic_distance`;
2. the wanted direction blends, by panic, fleeing (away from the chasers sensed within
   `sense_radius`, positions extrapolated by `lead_time`, each weighted by 1/distance**2)
   with a calm zigzag (a seeded random heading turned by about +-`zigzag_angle`, alternating
   sides, `zigzag_rate` times per second);
3. gap escape: when cornered (the flee direction has less than `follow_distance` of room, or
   the chasers within `panic_distance` surround it) it heads for the midpoint of two chasers
   and on through, if along that path it stays `capture_radius + gap_margin` beyond the reach
   of every chaser flying anywhere at `pursuer_speed`; it keeps to a chosen gap until it is
   across or the gap closes;
4. wall following: when the wanted direction meets an obstacle within `follow_distance`, it
   turns toward the obstacle's tangent (the flee direction projected onto the wall), on the
   side the chasers push it to;
5. repulsion from obstacles within `wall_margin` and, weakly, from other free evaders, then
   smoothing with the last heading;
6. look-ahead: RING directions around the wanted one are measured (the free length of a
   corridor `2 * clearance` wide: one ray each against obstacles grown by `clearance`, cut
   short where it comes within `DRONE_CONTACT_DISTANCE + APART_BUFFER` of another free
   evader) and scored by alignment with it, room (`room_weight`) and, when panicked, how far
   the evader stays out of every chaser's reach along them (`safety_weight`); a direction
   whose corridor is not free for `clearance + evader_speed * lookahead_time` is flown only
   if all are blocked. A gap escape skips 4 to 6 (its path is already checked);
7. braking (only when `evader_speed` exceeds WALL_SPEED): the fixed margins above keep an
   evader off walls up to WALL_SPEED, though not by a fixed distance. Measured 2026-12-07 in
   point fidelity at 0.9 m/s, chased by the heuristic team: 512 whole episodes (PursuitEnv
   with 32 worlds, auto_reset off, seeds 0-3 on each of layouts 0-3, each with its 5 random
   obstacles), the evader's centre to the nearest obstacle surface or border
   (geometry.obstacle_distance, from a physics observer) at every controller tick until
   capture or timeout, the closest per episode: lowest 0.070 m (layout 0; 0.086,
   0.084, 0.104 m on layouts 1-3), 1 % of episodes below 0.091 m, 5 % below 0.119 m, median
   0.216 m. The body's radius is 0.0685 m (DRONE_CONTACT_DISTANCE / 2): the closest passed
   about 1 mm from touching, and no evader contact was reported in that run (an earlier note
   said ">= 0.11 m", from fewer episodes). In quadrotor fidelity chased evaders at 0.9 m/s
   brushed cylinders on layouts 2 and 3, their centres 0.07 m from the surface, 2026-12-06;
   an evader's contacts end nothing. A faster evader cannot shed its speed within the
   margins (a Crazyflie tilted 15 deg stops from v in
   v**2 / (2 * 2.6 m/s**2): 0.43 m from 1.5 m/s, 1.7 m from 3) and touched walls from 1.5 m/s
   on, its momentum carrying it on while it turned. So its speed along the chosen
   direction is lowered until, along every RING direction, the velocity component is at most
   sqrt(floor**2 + 2 * BRAKE_ACCEL * left): left the free length of that direction's corridor
   less BRAKE_MARGIN and what the evader's current closing speed along it covers in
   BRAKE_RESPONSE, floor = WALL_SPEED**2 / evader_speed (the closing speed it may keep at the
   margin falls as its speed grows: turning a faster flight takes more of its thrust). Flying
   away from or along an obstacle is not slowed. Measured against the heuristic team (16
   worlds on layouts 0-3, 40 s): >= 0.13 m from walls at 1.5-3 m/s in both fidelities
   (0.01-0.065 m before); in these small arenas such an evader then averages 0.8-0.9 m/s,
   about as a 0.9 m/s one does, and is caught more often than before;
8. keeping apart: each free evader's closing speed toward every other free evader is capped
   (planar.limit_closing, half the budget each, as the pursuers' shield does for teammates),
   so evaders slow down rather than fly into each other; only steps 7 and 8 make them fly
   slower than `evader_speed`.

Captured evaders output zero. Chasers are sensed through walls (by distance only). Random
numbers come from a counter-based hash of (episode seed, step, evader, stream), so a
world's path depends only on its own seed and inputs, however many worlds run together.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .config import DRONE_CONTACT_DISTANCE, TaskConfig, checked_task_config
from .geometry import FAR, ObstacleSet, first_axis_last, last_axis_first, obstacle_distance
from .planar import EPS, clip_norm, dot, limit_closing, norm, perp, rotate, unit
from .randomness import TICK as _TICK, hash_uniform, hash_uniforms, splitmix64 as _splitmix64

RING = 16  # survey directions around the wanted direction
RING_ANGLES = 2 * math.pi * np.arange(RING) / RING  # rad, relative to the wanted direction
ROOM_CAP = 1.0  # m, room beyond this counts as open
FOLLOW_SIDE_MIN = 0.1  # chasers' tangential push below this leaves the wall side to the heading
FOLLOW_SWITCH = 0.5  # chasers' push against the side it follows a wall on that makes it turn
PERSIST = 1.0  # weight (times panic) of keeping the current heading among candidates
BLOCKED = -10.0  # score of a candidate the look-ahead refuses (plus up to 5 for its room)
GAP_CHASERS = 4  # gaps are looked for between the nearest this many chasers
PATH_SAMPLES = 6  # points checked along a path against the chasers' reach
HORIZON = 1.5  # m, how far along a candidate the safety score looks
SLACK_SCALE = 1.0  # m, safety margins beyond this count as safe
DANGER = 3.0  # factor on negative safety margins: entering a chaser's reach costs more than room gains
NORMAL_STEP = 0.02  # m, finite-difference step of obstacle normals
# step 8: two evaders' closing speed is at most APART_RATE * (gap - APART_BUFFER), the gap
# (m) between their collision volumes shortened by what the closing speed covers in
# APART_RESPONSE (s): a drone does not stop at once
APART_RATE = 1.5  # 1/s
APART_BUFFER = 0.1  # m
APART_RESPONSE = 0.35  # s
# step 7: braking near obstacles, for evaders faster than WALL_SPEED only (slower ones are unchanged)
WALL_SPEED = 0.9  # m/s, the fastest evader the fixed margins keep off walls (closest measured: 0.070 m, step 7)
BRAKE_ACCEL = 1.3  # m/s^2, about half a Crazyflie's 15 deg tilt limit (2.6): the rest is left for turning
BRAKE_MARGIN = 0.1  # m beyond the look-ahead corridor's edge where braking ends
BRAKE_RESPONSE = 0.3  # s, a decision interval plus the drone's lag: closing speed covers this before braking acts
_PATH_FRACTIONS = np.linspace(0.0, 1.0, PATH_SAMPLES)  # where along a path its samples lie
_HORIZON_SAMPLES = np.linspace(0.0, HORIZON, PATH_SAMPLES)  # m flown at the samples of a candidate

_STREAM_TURN, _STREAM_AMPLITUDE, _STREAM_START, _STREAM_SIDE = range(4)


# ----------------------------------------------------------------------------- small maths


def panic_level(distance: np.ndarray, panic_distance: float, calm_distance: float) -> np.ndarray:
    """Panic in [0, 1] from the nearest chaser's distance (...) m: 1 within panic_distance,
    0 beyond calm_distance, linear between (non-increasing in distance; inf gives 0)."""
    return np.clip((calm_distance - distance) / (calm_distance - panic_distance), 0.0, 1.0)


def flee_vector(away: np.ndarray, sensed: np.ndarray) -> np.ndarray:
    """Sum over sensed chasers of unit vectors chaser -> evader weighted by 1/distance**2.

    away (W, M, N, 2) m, evader minus chaser position; sensed (W, M, N) bool -> (W, M, 2).
    """
    d = norm(away)
    w = np.where(sensed, 1.0 / np.maximum(d, 1e-3) ** 3, 0.0)  # unit vector / d**2
    return np.sum(away * w[..., None], axis=-2)


def surrounded(toward: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Whether the evader lies inside the chasers' angular cover: every open half-plane around
    it holds a chaser (the largest gap between chaser bearings is below pi).

    toward (W, M, N, 2) m, chaser minus evader position; mask (W, M, N) bool, chasers that count.
    Returns (W, M) bool.
    Fewer than 3 chasers never surround: the bearings are sorted only where 3 or more count
    (most steps none; each evader's answer is its own, so the others need not be looked at).
    """
    out = mask.sum(-1) >= 3
    if not out.any():
        return out
    toward, mask = toward[out], mask[out]  # (K, N, 2), (K, N): the evaders with 3 or more
    ang = np.where(mask, np.arctan2(toward[..., 1], toward[..., 0]), np.inf)
    ang = np.sort(ang, axis=-1)
    first = ang[..., :1] + 2 * math.pi
    filled = np.where(np.isinf(ang), first, ang)
    with np.errstate(invalid="ignore"):  # no chaser counts: inf - inf, masked below
        gaps = np.diff(np.concatenate([filled, first], axis=-1), axis=-1)
    out[out] = np.nan_to_num(gaps, nan=2 * math.pi).max(-1) < math.pi
    return out


def _last_first(v: np.ndarray) -> np.ndarray:
    """v (..., T) as (T, ...) in C order (a copy): numpy lays results out like their inputs,
    and the rows reduced over must stay contiguous."""
    return np.ascontiguousarray(last_axis_first(v))


def _rows(v: np.ndarray) -> np.ndarray:
    """(T, W, M) -> (T, 1, W*M) float32 in C order: one row of (world, evader) pairs per target."""
    return np.ascontiguousarray(v, dtype=np.float32).reshape(v.shape[0], 1, -1)


def _flat_rows(mask: np.ndarray) -> np.ndarray | None:
    """The flat indices w * M + m (R,) of the (world, evader) pairs where mask (W, M) holds, or
    None (every pair, taken without gathering) where more than half of them do."""
    flat = np.flatnonzero(mask)
    return None if 2 * len(flat) > mask.size else flat


def _take(x: np.ndarray, flat: np.ndarray | None) -> np.ndarray:
    """The rows (R, ...) of x (W, M, ...) at the flat (world, evader) indices (`_flat_rows`), or
    all of them (W * M, ...) for None."""
    x = x.reshape((-1,) + x.shape[2:])
    return x if flat is None else x[flat]


def reach_slack(
    origin: np.ndarray, dirs: np.ndarray, s: np.ndarray, reach: np.ndarray, chasers: np.ndarray, sensed: np.ndarray
) -> np.ndarray:
    """How far (m) the evader stays outside every sensed chaser's reach along straight paths.

    origin (W, M, 1, 2) m; dirs (W, M, K, 2) unit; at sample times the evader has flown
    s (W, M, K, S) m along its path while a chaser flying anywhere at full speed covers
    reach (broadcastable to s) m. chasers (W, N, 2) m; sensed (W, M, N) bool.
    Returns min over samples and sensed chasers of |x - chaser| - reach: (W, M, K), inf
    where no chaser is sensed.
    """
    # samples and chasers first, (S, N, W, M, K): the minimum over them is then taken row by row
    oc = origin - chasers[:, None, :, :]  # (W, M, N, 2) chaser -> evader
    ocx, ocy = (_last_first(oc[..., i])[None, ..., None] for i in (0, 1))  # (1, N, W, M, 1)
    along = np.ascontiguousarray(dirs[..., 0]) * ocx + np.ascontiguousarray(dirs[..., 1]) * ocy  # (1, N, W, M, K)
    s_first = _last_first(s)[:, None]  # (S, 1, W, M, K)
    reach_first = last_axis_first(np.broadcast_to(reach, s.shape))[:, None]
    # |oc + s dir|^2 expanded, so that no (S, N, W, M, K, 2) array is made
    d = np.sqrt(np.maximum((ocx * ocx + ocy * ocy) + s_first * (2.0 * along + s_first), 0.0))
    unsensed = np.where(last_axis_first(sensed), 0.0, np.inf)[None, ..., None]  # (1, N, W, M, 1)
    margin = d - reach_first + unsensed
    return margin.reshape((-1,) + margin.shape[2:]).min(0)


# ----------------------------------------------------------------------------- obstacle queries


# where distance_and_normal measures: the point itself, then +x, -x, +y, -y by NORMAL_STEP
_NORMAL_OFFSETS = np.array([[0.0, 0.0], [NORMAL_STEP, 0.0], [-NORMAL_STEP, 0.0], [0.0, NORMAL_STEP], [0.0, -NORMAL_STEP]])


def distance_and_normal(points: np.ndarray, obstacles: ObstacleSet) -> tuple[np.ndarray, np.ndarray]:
    """Distance (W, P) m from points (W, P, 2) to the nearest obstacle or border, and the unit
    normal (W, P, 2) pointing away from it (zeros where nothing is near enough to tell)."""
    d = _offset_distances(points, obstacles, _NORMAL_OFFSETS)
    return d[..., 0], _normal(d[..., 1:])


def obstacle_normal(points: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """The normal of `distance_and_normal` alone (the same numbers), without measuring the
    distance at the points themselves: four queries per point instead of five."""
    return _normal(_offset_distances(points, obstacles, _NORMAL_OFFSETS[1:]))


def _offset_distances(points: np.ndarray, obstacles: ObstacleSet, offsets: np.ndarray) -> np.ndarray:
    """Obstacle distances (W, P, K) m at points (W, P, 2) moved by each of offsets (K, 2) m."""
    W, P, _ = points.shape
    K = len(offsets)
    q = (points[:, :, None, :] + offsets).reshape(W, P * K, 2)
    return obstacle_distance(q, obstacles).reshape(W, P, K)


def _normal(d: np.ndarray) -> np.ndarray:
    """The unit normal (W, P, 2) from distances (W, P, 4) at +x, -x, +y, -y of each point."""
    grad = np.stack([d[..., 0] - d[..., 1], d[..., 2] - d[..., 3]], -1)
    return unit(grad)


def _left_normals(seg: np.ndarray) -> np.ndarray:
    """Unit normals (..., S, 2) to the left of segments (..., S, 4)."""
    d = seg[..., 2:4] - seg[..., 0:2]
    return np.stack([-d[..., 1], d[..., 0]], -1) / np.maximum(norm(d)[..., None], EPS)


@dataclasses.dataclass(frozen=True)
class _CorridorTargets:
    """What `Corridors` needs of an obstacle set (W, ...) that no evader changes, targets first,
    each coordinate apart (contiguous (T, W, 1) arrays): the segments, box edges (4 NB,
    counter-clockwise: outside on the right) then border (NS, inside on the left), as start
    x0, y0 and end x1, y1 (m), the unit normals (nx, ny) they are moved along as they grow (a
    box edge's right one, out of the box; a border segment's left one, into the arena), their
    validity (S, W, 1); the circles' centres cx, cy (m), segment starts (the corners) then
    cylinders, their radii before growing (0 for a corner, the cylinder's) and validity (C, W, 1)."""

    x0: np.ndarray
    y0: np.ndarray
    x1: np.ndarray
    y1: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    seg_valid: np.ndarray
    cx: np.ndarray
    cy: np.ndarray
    radius: np.ndarray
    circle_valid: np.ndarray


def _corridor_targets(obstacles: ObstacleSet) -> _CorridorTargets:
    """`_CorridorTargets` of `obstacles`, computed once per set (an env's set lives from one
    episode start to the next, or one step where a caught evader joins it) and kept on it."""
    cached = obstacles.__dict__.get("_corridor_targets")
    if cached is not None:
        return cached
    box, box_valid = obstacles.segments()  # (W, 4 NB, 4)
    box = box.swapaxes(0, 1)[:, :, None]  # (4 NB, W, 1, 4)
    border = obstacles.border.swapaxes(0, 1)[:, :, None]  # (NS, W, 1, 4)
    seg = np.concatenate([box, border], axis=0)  # (S, W, 1, 4)
    # a box edge moves by -radius along its left normal: by radius along the negated one (the same
    # products: a product's sign is its factors' signs)
    normal = np.concatenate([-_left_normals(box), _left_normals(border)], axis=0)  # (S, W, 1, 2)
    cyl = obstacles.cylinders.swapaxes(0, 1)[:, :, None]  # (NC, W, 1, 3)
    centres = np.concatenate([seg[..., 0:2], cyl[..., 0:2]], axis=0)  # (C, W, 1, 2)
    radius = np.concatenate([np.zeros(seg.shape[:-1]), cyl[..., 2]], axis=0)  # (C, W, 1)
    parts = [seg[..., i] for i in range(4)] + [normal[..., 0], normal[..., 1]]
    parts += [np.concatenate([box_valid, obstacles.border_valid], -1).T[:, :, None], centres[..., 0], centres[..., 1], radius,
              np.concatenate([box_valid, obstacles.border_valid, obstacles.cylinder_valid], -1).T[:, :, None]]
    out = _CorridorTargets(*(np.ascontiguousarray(v) for v in parts))
    obstacles.__dict__["_corridor_targets"] = out  # a frozen dataclass: as functools.cached_property stores
    return out


class Corridors:
    """Free flight lengths of a disc of radius (W, M) m around each evader (its corridor).

    The obstacles are grown by each evader's radius once (box edges pushed out and border
    segments pushed in by it, circles of that radius at their corners, cylinder radii grown),
    so that one ray per direction measures the whole corridor. Keep each radius below the
    evader's distance to the nearest obstacle, so that every ray starts in free space.
    """

    def __init__(self, obstacles: ObstacleSet, pos: np.ndarray, radius: np.ndarray):
        W, M = radius.shape
        self.shape = (W, M)
        # Targets (segments, circles) first and (world, evader) pairs last, (T, W*M), against
        # directions (Q, W*M): numpy then runs every operation over contiguous rows, and the
        # minimum over targets is an elementwise minimum of rows (many times faster than
        # broadcasting along, or reducing over, a short last axis).
        g = _corridor_targets(obstacles)  # what does not depend on the evaders, once per obstacle set
        r = radius[None]  # (1, W, M)
        sx, sy = g.nx * r, g.ny * r  # (S, W, M): each segment grown by its evader's radius
        x0, y0, x1, y1 = g.x0 + sx, g.y0 + sy, g.x1 + sx, g.y1 + sy
        # everything relative to each evader, once; rays then differ only in direction.
        # float32 (micrometre rounding on metre offsets) halves the memory traffic of the hot loop.
        px, py = pos[None, ..., 0], pos[None, ..., 1]  # (1, W, M)
        valid = g.seg_valid
        self._ax, self._ay = _rows(np.where(valid, x0 - px, 0.0)), _rows(np.where(valid, y0 - py, 0.0))  # segment start
        self._ex, self._ey = _rows(np.where(valid, x1 - x0, 0.0)), _rows(np.where(valid, y1 - y0, 0.0))  # segment vector
        self._t_num = self._ax * self._ey - self._ay * self._ex  # a x e: the hit distance times (d x e)
        cx, cy = g.cx - px, g.cy - py  # (C, W, M) circle centre
        self._cx, self._cy = _rows(cx), _rows(cy)  # (C, 1, W*M)
        radii = g.radius + r  # corners of the evader's radius, cylinders grown by it
        self._c2 = _rows(np.where(g.circle_valid, (cx * cx + cy * cy) - radii**2, np.inf))  # |c|^2 - r^2

    def free(self, dirs: np.ndarray) -> np.ndarray:
        """Free length (W, M, Q) m along unit dirs (W, M, Q, 2) from each evader; FAR if open."""
        W, M = self.shape
        Q = dirs.shape[2]
        return first_axis_last(self._free(dirs.reshape(W * M, Q, 2), None).reshape(Q, W, M))

    def free_rows(self, dirs: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
        """`free` for some evaders only: rows their flat indices w * M + m (R,) (None: every
        evader, in that order), dirs (R, Q, 2) unit; free lengths (R, Q) m, the numbers `free`
        gives those evaders (each evader's corridor is its own)."""
        return self._free(dirs, rows).T

    def _free(self, dirs: np.ndarray, cols: np.ndarray | None) -> np.ndarray:
        """Free lengths (Q, P) m along dirs (P, Q, 2) of the (world, evader) pairs cols (P,) (flat
        indices w * M + m; None: all of them, in that order)."""
        d = dirs.astype(np.float32).transpose(1, 0, 2)  # (Q, P, 2)
        dx, dy = np.ascontiguousarray(d[..., 0]), np.ascontiguousarray(d[..., 1])  # (Q, P)
        ax, ay, ex, ey, t_num, cx, cy, c2 = (self._ax, self._ay, self._ex, self._ey, self._t_num, self._cx, self._cy, self._c2)
        if cols is not None:
            ax, ay, ex, ey, t_num, cx, cy, c2 = (v[..., cols] for v in (ax, ay, ex, ey, t_num, cx, cy, c2))
        denom = dx * ey - dy * ex  # (S, Q, P)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = t_num / denom
            u = (ax * dy - ay * dx) / denom
        # minima over the hits only (`where`), FAR if none: no (S, Q, P) array of refused ones set to FAR
        seg_hit = t.min(0, initial=FAR, where=(np.abs(denom) > EPS) & (t >= 0) & (u >= 0) & (u <= 1))
        b = dx * cx + dy * cy  # (C, Q, P) projection of centre
        disc = b * b - c2
        with np.errstate(invalid="ignore"):
            t0 = b - np.sqrt(disc)  # origins lie outside every grown circle, so the near root is the hit
        circle_hit = t0.min(0, initial=FAR, where=(disc >= 0) & (t0 >= 0))
        return np.minimum(seg_hit, circle_hit).astype(np.float64)  # (Q, P)


# ----------------------------------------------------------------------------- the model


class EscapeModel:
    """Desired velocities for every evader of every world; see the module docstring.

    State per (world, evader): heading (unit, the last direction flown), the zigzag wander
    direction and its next side, and the gap it is committed to. `reset` starts new episodes.
    After each `compute`, `panic` (W, M), `gap` (W, M) bool (slipping through a gap) and
    `following` (W, M) bool (turned along an obstacle) tell recorders and tests what it did.
    """

    def __init__(self, config: TaskConfig, n_worlds: int, seed: int):
        if isinstance(n_worlds, bool) or not isinstance(n_worlds, (int, np.integer)) or n_worlds < 1:
            raise ValueError(f"EscapeModel n_worlds: expected an integer >= 1, got {n_worlds!r}")
        config = checked_task_config(config, "EscapeModel config")  # one made with dataclasses.replace skips the loader's checks
        self.config = config
        self.cfg = config.evader
        self.n_worlds = int(n_worlds)
        self.n_evaders = config.n_evaders
        self.n_pursuers = config.n_pursuers
        if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"EscapeModel seed: expected a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self._need = self.cfg.clearance + config.evader_speed * self.cfg.lookahead_time  # m of free corridor ahead
        W, M = self.n_worlds, self.n_evaders
        # (world, evader) index arrays (W, 1) and (1, M): a[self._wm + (k,)] picks a[w, m, k[w, m]]
        # (what np.take_along_axis does, without its cost of building these every call)
        self._wm = (np.arange(W)[:, None], np.arange(M)[None, :])
        self._pair_i, self._pair_j = np.triu_indices(min(GAP_CHASERS, self.n_pursuers), k=1)  # among the nearest
        self.heading = np.zeros((W, M, 2))
        self.wander = np.zeros((W, M, 2))
        self.zig_side = np.ones((W, M))
        self.has_heading = np.zeros((W, M), bool)
        self.gap_pair = np.full((W, M, 2), -1)  # the two chasers of the gap it is slipping through
        self.gap_side = np.zeros((W, M))
        self.world_seed = np.zeros(W, np.uint64)
        self.tick = np.zeros(W, np.uint64)
        self.episode = np.zeros(W, np.uint64)
        self.panic = np.zeros((W, M))
        self.gap = np.zeros((W, M), bool)
        self.following = np.zeros((W, M), bool)
        self.follow_side = np.zeros((W, M))  # +1 obstacle on the left, -1 on the right, 0 not following
        self.reset(np.arange(W))

    # ------------------------------------------------------------------ episodes

    def reset(self, world_ids: np.ndarray, seeds: np.ndarray | None = None) -> None:
        """New episodes in the listed worlds: forget headings, zigzag and gap state.

        seeds (k,) non-negative integers make each world's randomness reproducible; without
        them a seed is derived from (model seed, world, episode count of that world).
        """
        ids = np.asarray(world_ids)
        if ids.ndim != 1 or (ids.size and (not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0 or ids.max() >= self.n_worlds)):
            raise ValueError(f"EscapeModel.reset world_ids: expected world indices in [0, {self.n_worlds}), got {world_ids!r}")
        ids = ids.astype(np.int64)
        if seeds is None:
            base = _splitmix64(np.array([self.seed & 0xFFFFFFFFFFFFFFFF], np.uint64))
            key = _splitmix64(ids.astype(np.uint64) * _TICK + self.episode[ids])
            self.world_seed[ids] = _splitmix64(base ^ key)
        else:
            s = np.asarray(seeds)
            if s.shape != ids.shape or (s.size and (not np.issubdtype(s.dtype, np.integer) or s.min() < 0)):
                raise ValueError(f"EscapeModel.reset seeds: expected {ids.size} non-negative integers, got {seeds!r}")
            self.world_seed[ids] = _splitmix64(s.astype(np.uint64))
        self.episode[ids] += np.uint64(1)
        self.tick[ids] = 0
        self.has_heading[ids] = False
        self.heading[ids] = 0.0
        self.wander[ids] = 0.0
        side = hash_uniform(self.world_seed[ids], self.tick[ids], self.n_evaders, _STREAM_SIDE)
        self.zig_side[ids] = np.where(side < 0.5, -1.0, 1.0)
        self.gap_pair[ids] = -1
        self.gap_side[ids] = 0.0
        self.panic[ids] = 0.0
        self.gap[ids] = False
        self.following[ids] = False
        self.follow_side[ids] = 0.0

    # ------------------------------------------------------------------ one decision

    def compute(
        self,
        evader_pos: np.ndarray,
        evader_vel: np.ndarray,
        pursuer_pos: np.ndarray,
        pursuer_vel: np.ndarray,
        active: np.ndarray,
        obstacles: ObstacleSet,
        dt: float,
    ) -> np.ndarray:
        """evader_pos/vel (W, M, 2) m, m/s world; pursuer_pos/vel (W, N, 2); active (W, M) bool
        (not captured); obstacles: ObstacleSet stacked over worlds (arrays (W, ...)), border
        included; dt decision interval (s).

        Returns desired velocities (W, M, 2) m/s world: norm evader_speed where active (less only
        where step 7 brakes an evader faster than WALL_SPEED near an obstacle, or step 8 slows
        an evader near another free one), else 0.
        """
        e, ev, pp, pv, active = self._check(evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt)
        cfg = self.cfg
        away = e[:, :, None, :] - pp[:, None, :, :]  # (W, M, N, 2) chaser -> evader
        dist = norm(away)
        sensed = dist < cfg.sense_radius
        self.panic = panic_level(np.where(sensed, dist, np.inf).min(-1), cfg.panic_distance, cfg.calm_distance)
        flee = flee_vector(e[:, :, None, :] - (pp + pv * cfg.lead_time)[:, None, :, :], sensed)
        self._start_headings(ev, flee)
        self._turn_wander(dt)
        flee_dir = unit(flee, self.heading)
        p = self.panic[..., None]
        want = unit(p * flee_dir + (1.0 - p) * self.wander, flee_dir)

        d0, n0 = distance_and_normal(e, obstacles)
        corridors = Corridors(obstacles, e, np.clip(np.minimum(cfg.clearance, d0 - 0.005), 0.0, None))
        gap_dir, gap_length, side, ci, cj = self._gap_paths(e, pp, dist, flee_dir)
        if _flat_rows(self._may_take_gap()) is None:  # most evaders' gaps are looked at: all in one go
            free = corridors.free(np.concatenate([flee_dir[:, :, None, :], want[:, :, None, :], gap_dir], axis=2))
            gap_free = free[..., 2:]
        else:  # a few evaders' gaps (or none): only theirs
            free = corridors.free(np.stack([flee_dir, want], axis=2))  # (W, M, 2): room to flee, room ahead
            gap_free = lambda rows: corridors.free_rows(_take(gap_dir, rows), rows)  # noqa: E731
        gap_on, through = self._gap_escape(dist, sensed, gap_dir, gap_length, side, ci, cj, gap_free, free[..., 0], -away, pp, e, active)
        want = self._follow_walls(e, want, free[..., 1], flee, obstacles, ~gap_on)

        push = cfg.wall_gain * np.clip((cfg.wall_margin - d0) / cfg.wall_margin, 0.0, 1.0)[..., None] * n0
        want = unit(want + push + self._evader_push(e, active), want)
        want = unit((1.0 - cfg.smoothing) * want + cfg.smoothing * self.heading, want)
        survey = rotate(want[:, :, None, :], RING_ANGLES)  # (W, M, RING, 2); survey[:, :, 0] is want
        obstacle_room = corridors.free(survey)
        room = np.minimum(obstacle_room, self._evader_room(e, active, survey))
        best = self._choose(e, pp, sensed, want, survey, room)
        chosen = survey[self._wm + (best,)]
        final = np.where(gap_on[..., None], through, chosen)

        self.heading = np.where(active[..., None], final, self.heading)
        self.has_heading |= active
        self.gap = gap_on
        self.tick += np.uint64(1)
        speed = self._braking_speed(final, ev, survey, obstacle_room)
        return self._keep_apart(e, ev, final * (speed * active)[..., None], active, n0)

    # ------------------------------------------------------------------ behaviours

    def _braking_speed(self, final: np.ndarray, evader_vel: np.ndarray, survey: np.ndarray, room: np.ndarray):
        """The speed (W, M) m/s to fly unit direction final (W, M, 2) at (module docstring, step 7),
        given the evader's velocity (W, M, 2) m/s and the obstacles' room (W, M, RING) m along the
        RING unit directions survey (W, M, RING, 2). The plain evader_speed (a float) when it is
        at most WALL_SPEED: slower evaders are unchanged."""
        speed = self.config.evader_speed
        if speed <= WALL_SPEED:
            return speed
        closing = np.maximum(dot(survey, evader_vel[:, :, None, :]), 0.0)  # (W, M, RING) m/s
        left = np.maximum(room - BRAKE_MARGIN - BRAKE_RESPONSE * closing, 0.0)
        floor = WALL_SPEED * WALL_SPEED / speed
        cap = np.sqrt(floor * floor + 2.0 * BRAKE_ACCEL * left)  # (W, M, RING) m/s along each direction
        along = dot(survey, final[:, :, None, :])
        limit = np.where(along > EPS, cap / np.maximum(along, EPS), np.inf).min(-1)
        return np.minimum(speed, limit)

    def _start_headings(self, evader_vel: np.ndarray, flee: np.ndarray) -> None:
        """Evaders new to an episode start along their velocity, else away from the chasers
        they sense, else in a random direction."""
        if self.has_heading.all():
            return
        u = hash_uniform(self.world_seed, self.tick, self.n_evaders, _STREAM_START)
        start = np.stack([np.cos(2 * math.pi * u), np.sin(2 * math.pi * u)], -1)
        start = unit(flee, start)
        start = np.where((norm(evader_vel) > 0.05)[..., None], unit(evader_vel, start), start)
        new = ~self.has_heading[..., None]
        self.heading = np.where(new, start, self.heading)
        self.wander = np.where(new, start, self.wander)

    def _turn_wander(self, dt: float) -> None:
        """At random times (rate zigzag_rate) turn the wander direction from the heading by
        zigzag_angle * U(0.5, 1) to alternate sides."""
        cfg = self.cfg
        u_turn, u_amp = hash_uniforms(self.world_seed, self.tick, self.n_evaders, (_STREAM_TURN, _STREAM_AMPLITUDE))
        turn = u_turn < -math.expm1(-cfg.zigzag_rate * dt)
        angle = self.zig_side * cfg.zigzag_angle * (0.5 + 0.5 * u_amp)
        self.wander = np.where(turn[..., None], rotate(self.heading, angle), self.wander)
        self.zig_side = np.where(turn, -self.zig_side, self.zig_side)

    def _gap_paths(self, e, pp, dist, fallback):
        """Paths through the gaps between pairs of the GAP_CHASERS chasers nearest each evader:
        to the pair's midpoint and on to `capture_radius + gap_margin` beyond their line, on
        the far side. With P pairs, returns unit directions (W, M, P, 2), path lengths
        (W, M, P) m, the side (W, M, P) of the line chaser i -> chaser j the evader is on (+1
        left, -1 right) and the chaser indices i and j (W, M, P)."""
        W = self.n_worlds
        near = np.argsort(dist, axis=-1, kind="stable")[..., : min(GAP_CHASERS, self.n_pursuers)]  # (W, M, K)
        a, b = near[..., self._pair_i], near[..., self._pair_j]  # (W, M, P)
        # each pair by chaser index, not by which of the two is nearer: the gap it is committed
        # to (chasers and side) must be recognised when their distances cross on the way through
        ci, cj = np.minimum(a, b), np.maximum(a, b)
        world = np.arange(W)[:, None, None]
        pi, pj = pp[world, ci], pp[world, cj]  # (W, M, P, 2)
        edge, rel = pj - pi, e[:, :, None] - pi
        side = np.sign(edge[..., 0] * rel[..., 1] - edge[..., 1] * rel[..., 0])
        beyond = self.config.capture_radius + self.cfg.gap_margin
        target = 0.5 * (pi + pj) - beyond * side[..., None] * perp(unit(edge))
        to_target = target - e[:, :, None]
        return unit(to_target, fallback[:, :, None, :]), norm(to_target), side, ci, cj

    def _gap_escape(self, dist, sensed, gap_dir, gap_length, side, ci, cj, gap_free, flee_room, toward, pp, e, active):
        """(on (W, M) bool, direction (W, M, 2)): the gap between two chasers it slips through.

        A gap is open when both chasers are sensed, its path (see `_gap_paths`) is free of
        obstacles (gap_free: the paths' free lengths (W, M, P) m, or a function giving them
        (R, P) for the evaders of `_flat_rows`' answer) and long enough for the look-ahead, and
        along it the evader stays `capture_radius + gap_margin` outside every sensed chaser's
        reach. It is taken when cornered: the flee direction has less than follow_distance of
        room (flee_room (W, M) m), or the chasers within panic_distance surround it (toward
        (W, M, N, 2) chaser minus evader). It is kept while open until the evader is across
        the chasers' line. Where no gap is taken, direction is the first gap's.

        Only an evader that panics (being cornered needs panic) or keeps to the gap it is
        committed to can take one: the gaps of the others are not looked at (in most steps
        most evaders are calm). Each evader's answer depends on its own rows only.
        """
        W, M = self.n_worlds, self.n_evaders
        cfg = self.cfg
        if len(self._pair_i) == 0 or not cfg.gap_escape:
            self.gap_pair[:] = -1
            return np.zeros((W, M), bool), np.zeros((W, M, 2))
        rows = _flat_rows(self._may_take_gap())
        if rows is not None and len(rows) == 0:
            self.gap_pair, self.gap_side = np.full((W, M, 2), -1, np.result_type(ci, cj)), np.zeros((W, M))
            return np.zeros((W, M), bool), gap_dir[:, :, 0].copy()
        free = gap_free(rows) if callable(gap_free) else _take(gap_free, rows)
        chasers = np.broadcast_to(pp[:, None], (W, M) + pp.shape[1:])
        got = self._gaps_of(*(_take(x, rows) for x in (
            dist, sensed, gap_dir, gap_length, side, ci, cj)), free, *(_take(x, rows) for x in (
            flee_room, toward, chasers, e, active, self.panic, self.gap_pair, self.gap_side)))
        if rows is None:  # every evader's
            on, through, gap_pair, gap_side = (x.reshape((W, M) + x.shape[1:]) for x in got)
        else:
            on, through = np.zeros(W * M, bool), _take(gap_dir[:, :, 0], None).copy()  # flat (W * M, ...)
            gap_pair, gap_side = np.full((W * M, 2), -1, got[2].dtype), np.zeros(W * M)
            for whole, part in zip((on, through, gap_pair, gap_side), got):
                whole[rows] = part
            on, through, gap_pair, gap_side = (x.reshape((W, M) + x.shape[1:]) for x in (on, through, gap_pair, gap_side))
        self.gap_pair, self.gap_side = gap_pair, gap_side
        return on, through

    def _may_take_gap(self) -> np.ndarray:
        """(W, M) bool: the evaders that can take a gap now (`_gap_escape`): those that panic
        and those committed to a gap."""
        return (self.panic > 0) | (self.gap_pair[..., 0] >= 0)

    def _gaps_of(self, dist, sensed, gap_dir, gap_length, side, ci, cj, gap_free, flee_room, toward, pp, e, active,
                 panic, committed_pair, committed_side):
        """`_gap_escape` for R evaders, given their rows (R, ...) of its arrays, their chasers pp
        (R, N, 2), panic (R,) and the gap each is committed to (pair (R, 2), side (R,)): on (R,),
        direction (R, 2), the chosen pair (R, 2) (-1 where none) and its side (R,) (0 where none)."""
        cfg, task = self.cfg, self.config
        reach = task.capture_radius + cfg.gap_margin
        s = _PATH_FRACTIONS * gap_length[..., None]  # (R, P, S)
        slack = reach_slack(e[:, None, None, :], gap_dir[:, None], s[:, None], (s * (task.pursuer_speed / task.evader_speed))[:, None],
                            pp, sensed[:, None])[:, 0] - reach
        clear = gap_free >= np.maximum(gap_length, self._need)
        r = np.arange(len(e))[:, None]  # against (R, P) indices
        both_sensed = sensed[r, ci] & sensed[r, cj]
        feasible = both_sensed & clear & (slack > 0)

        close = sensed & (dist < cfg.panic_distance)
        cornered = (panic > 0) & ((flee_room < cfg.follow_distance) | surrounded(toward, close))
        same_pair = (ci == committed_pair[:, :1]) & (cj == committed_pair[:, 1:])
        committed = same_pair & (committed_side[:, None] == side)
        candidate = feasible & (cornered[:, None] | committed)
        score = np.where(candidate, slack + committed, -np.inf)  # keep to a chosen gap
        best = (r[:, 0], np.argmax(score, axis=-1))  # the best gap of each evader
        on = candidate.any(-1) & active
        pair = np.stack([ci[best], cj[best]], -1)
        return on, gap_dir[best], np.where(on[:, None], pair, -1), np.where(on, side[best], 0.0)

    def _follow_walls(self, e, want, ahead, flee, obstacles, allowed):
        """Turn a wanted direction (W, M, 2) that meets an obstacle within follow_distance
        (ahead (W, M) m along it) toward that obstacle's tangent, fully once the obstacle is
        `clearance` away. The side (which hand the wall is on) is chosen when following starts:
        where the chasers push the evader (the tangential part of the flee vector, times
        panic), else where it already flies; it is kept while following goes on, so corners
        are followed round, unless the chasers push back harder than FOLLOW_SWITCH."""
        cfg = self.cfg
        probe = e + want * np.clip(ahead - 0.05, 0.0, cfg.follow_distance)[..., None]
        normal = obstacle_normal(probe, obstacles)
        into = allowed & (ahead < cfg.follow_distance) & (dot(want, normal) < -EPS)
        tangent = perp(normal)  # flying along it keeps the obstacle on the left
        pushed = self.panic * dot(tangent, unit(flee))
        kept = np.where(dot(tangent, self.heading) < 0, -1.0, 1.0)
        fresh = np.where(np.abs(pushed) > FOLLOW_SIDE_MIN, np.sign(pushed), kept)
        keep = self.following & (pushed * self.follow_side > -FOLLOW_SWITCH)
        self.follow_side = np.where(into, np.where(keep, self.follow_side, fresh), 0.0)
        self.following = into
        tangent = tangent * self.follow_side[..., None]
        span = max(cfg.follow_distance - cfg.clearance, 1e-6)
        beta = np.clip((cfg.follow_distance - ahead) / span, 0.0, 1.0)[..., None]
        return np.where(into[..., None], unit((1.0 - beta) * want + beta * tangent, tangent), want)

    def _choose(self, e, pp, sensed, want, candidates, room):
        """Index (W, M) of the candidate direction (W, M, K, 2) to fly, given its room (W, M, K) m.

        Each candidate is judged along its path of up to HORIZON m (shorter where an obstacle
        stops it). Score: alignment with want, + PERSIST * panic * alignment with the heading,
        + room_weight * room (relative to ROOM_CAP), + safety_weight * panic * the margin it
        keeps from the chasers' reach while flying that path and then waiting at its end until
        HORIZON m of flight time have passed (relative to SLACK_SCALE, times DANGER if
        negative). Candidates the look-ahead refuses score BLOCKED (plus their room), so they
        are flown only when all are.
        """
        cfg = self.cfg
        panic = self.panic[..., None]
        score = (
            dot(candidates, want[:, :, None, :])
            + PERSIST * panic * dot(candidates, self.heading[:, :, None, :])
            + cfg.room_weight * np.minimum(room, ROOM_CAP) / ROOM_CAP
        )
        # the safety term is times panic: a calm evader's is 0 (or -0.0, which ranks alike), so
        # it is measured only for the evaders that panic (in most steps a few)
        rows = _flat_rows(self.panic > 0)
        if rows is None:
            score = score + self._safety(*self._safety_rows(rows, e, pp, sensed, candidates, room)).reshape(score.shape)
        elif len(rows):
            flat = score.reshape(-1, score.shape[-1])
            flat[rows] += self._safety(*self._safety_rows(rows, e, pp, sensed, candidates, room))
            score = flat.reshape(score.shape)
        score = np.where(room >= self._need, score, BLOCKED + 5.0 * np.minimum(room / self._need, 1.0))
        return np.argmax(score, axis=-1)

    def _safety_rows(self, rows, e, pp, sensed, candidates, room):
        """The rows (`_take`) of `_safety`'s inputs for the evaders rows (`_flat_rows`)."""
        chasers = np.broadcast_to(pp[:, None], sensed.shape + (2,))
        return tuple(_take(x, rows) for x in (self.panic, e, chasers, sensed, candidates, room))

    def _safety(self, panic, e, pp, sensed, candidates, room):
        """`_choose`'s safety term (R, K) of R evaders, given their panic (R,), positions e (R, 2)
        m, chasers pp (R, N, 2) m, sensed (R, N), candidate directions (R, K, 2) and room (R, K)
        m along them."""
        cfg, task = self.cfg, self.config
        length = np.clip(room - cfg.clearance, 0.0, HORIZON)
        flown = _HORIZON_SAMPLES  # (S,) m
        chaser_reach = flown * (task.pursuer_speed / task.evader_speed)
        slack = reach_slack(e[:, None, None, :], candidates[:, None], np.minimum(flown, length[..., None])[:, None], chaser_reach, pp,
                            sensed[:, None])[:, 0]
        slack = slack - task.capture_radius
        return cfg.safety_weight * panic[:, None] * np.clip(slack / SLACK_SCALE, -1.0, 1.0) * np.where(slack < 0, DANGER, 1.0)

    def _keep_apart(self, e: np.ndarray, ev: np.ndarray, v: np.ndarray, active: np.ndarray, wall_normal: np.ndarray) -> np.ndarray:
        """v (W, M, 2) m/s with every free pair's closing speed capped (module docstring, step 8),
        never turned further toward the nearest obstacle (wall_normal (W, M, 2), pointing away
        from it) than v already was; where both cannot hold within evader_speed (caps whose
        lines cross almost in parallel meet far out: 110 m/s was returned), the obstacle wins
        and the pair only stops closing in. The result is at most evader_speed long."""
        if self.n_evaders < 2:
            return v
        rel = e[:, None, :, :] - e[:, :, None, :]  # (W, M, M, 2) m: from evader i to evader j
        u = unit(rel)
        closing = np.maximum(-dot(u, ev[:, None, :, :] - ev[:, :, None, :]), 0.0)  # (W, M, M) m/s
        gap = norm(rel) - DRONE_CONTACT_DISTANCE - APART_BUFFER - APART_RESPONSE * closing
        pair = active[:, :, None] & active[:, None, :] & ~np.eye(self.n_evaders, dtype=bool)
        pair_cap = np.where(pair, 0.5 * APART_RATE * gap, np.inf)
        to_wall = -wall_normal[:, :, None, :]
        wall_cap = np.maximum(dot(v, -wall_normal), 0.0)[..., None]
        dirs = np.concatenate([u, to_wall], axis=2)
        speed = self.config.evader_speed
        capped, met = limit_closing(v, dirs, np.concatenate([pair_cap, wall_cap], axis=2))
        met &= norm(capped) <= speed * (1.0 + 1e-9)
        if not met.all():  # backing off a pressing evader would mean flying into the obstacle, or too fast
            held, _ = limit_closing(v, dirs, np.concatenate([np.maximum(pair_cap, 0.0), wall_cap], axis=2))
            capped = np.where(met[..., None], capped, held)
        # caps of 0 or more allow standing still, so the nearest allowed velocity is no longer
        # than v; limit_closing does not always find the nearest one
        return np.where(active[..., None], clip_norm(capped, speed), 0.0)

    def _evader_room(self, e: np.ndarray, active: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Free length (W, M, K) m along unit dirs (W, M, K, 2) from each evader before it comes
        within DRONE_CONTACT_DISTANCE + APART_BUFFER of another free evader: FAR where none is
        ahead, 0 along directions toward one already that close."""
        if self.n_evaders < 2:
            return np.full(dirs.shape[:-1], FAR)
        rel = e[:, None, :, :] - e[:, :, None, :]  # (W, M, M, 2) m: from evader i to evader j
        ahead = np.einsum("wikc,wijc->wikj", dirs, rel)  # (W, M, K, M) m along each direction
        excess = (dot(rel, rel) - (DRONE_CONTACT_DISTANCE + APART_BUFFER) ** 2)[:, :, None, :]
        disc = ahead * ahead - excess
        t = np.where(excess > 0, ahead - np.sqrt(np.maximum(disc, 0.0)), 0.0)
        other = (active[:, None, :] & ~np.eye(self.n_evaders, dtype=bool))[:, :, None, :]
        return np.where(other & (ahead > 0) & (disc >= 0), t, FAR).min(-1)

    def _evader_push(self, e: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Weak repulsion (W, M, 2) between free evaders closer than evader_spacing."""
        cfg = self.cfg
        if self.n_evaders < 2 or cfg.evader_spacing <= 0 or cfg.evader_gain <= 0:
            return np.zeros_like(e)
        rel = e[:, :, None, :] - e[:, None, :, :]
        d = norm(rel)
        near = active[:, None, :] & ~np.eye(self.n_evaders, dtype=bool) & (d < cfg.evader_spacing)
        w = np.where(near, (1.0 - d / cfg.evader_spacing) / np.maximum(d, 1e-6), 0.0)
        return cfg.evader_gain * np.sum(rel * w[..., None], axis=2)

    # ------------------------------------------------------------------ input checks

    def _check(self, evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt):
        W, M, N = self.n_worlds, self.n_evaders, self.n_pursuers
        out = []
        for name, arr, shape in (
            ("evader_pos", evader_pos, (W, M, 2)),
            ("evader_vel", evader_vel, (W, M, 2)),
            ("pursuer_pos", pursuer_pos, (W, N, 2)),
            ("pursuer_vel", pursuer_vel, (W, N, 2)),
        ):
            a = np.asarray(arr, dtype=np.float64)
            if a.shape != shape:
                raise ValueError(f"EscapeModel.compute {name}: expected shape {shape} (worlds, drones, x y), got {a.shape}")
            if not np.isfinite(a).all():
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
                raise ValueError(f"EscapeModel.compute {name}: non-finite value {a[bad]} at index {bad}")
            out.append(a)
        act = np.asarray(active)
        if act.shape != (W, M) or act.dtype != bool:
            raise ValueError(f"EscapeModel.compute active: expected a bool array of shape {(W, M)}, got {act.dtype} {act.shape}")
        if not isinstance(obstacles, ObstacleSet) or any(
            a.ndim != 3 or a.shape[0] != W for a in (obstacles.boxes, obstacles.cylinders, obstacles.border)
        ):
            got = getattr(getattr(obstacles, "boxes", None), "shape", type(obstacles).__name__)
            raise ValueError(
                f"EscapeModel.compute obstacles: expected an ObstacleSet stacked over {W} worlds "
                f"(ObstacleSet.stack: boxes (W, NB, 5), cylinders (W, NC, 3), border (W, NS, 4)), got boxes {got}"
            )
        if isinstance(dt, (bool, np.bool_)) or not (isinstance(dt, (int, float, np.integer, np.floating)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"EscapeModel.compute dt: expected a decision interval > 0 s, got {dt!r}")
        return (*out, act)
