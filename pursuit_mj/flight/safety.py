"""Safety filters on the velocity commands of every drone at once (lab frame, m and m/s).

Each filter returns the filtered commands (D, 2) and which drones it changed (D,) bool:
- `clamp_speed`: no command faster than the limit;
- `Fence`: the arena minus a margin, and the virtual obstacles. A drone may approach the
  fence only as fast as it can stop within `lookahead` seconds before the margin; inside
  the margin it is pushed back out. So a drone about to leave brakes and holds at the
  margin, and may still slide along it. The nearest surface is one hazard, and a fan of
  rays finds the others (a second wall in a corner, an obstacle beside the border). A
  drone is judged where its motion takes it, but on its own side of every surface: a path
  that meets a surface on the way there is judged just before that surface, as far
  beyond it as the path goes (a thin wall is never mistaken for its far side);
- `separate`: the same closing-speed limit between drones (half each when both move);
- `keep_apart_and_inside`: fence and separation solved together (planar.limit_closing), so
  that neither undoes the other; where no command keeps both, the fence wins;
- `altitude_speed`: the vertical speed that holds the flight height.
"""

from __future__ import annotations

import numpy as np

from ..geometry import FAR, ObstacleSet, border_distance, cast_fan, cast_rays, inside_boundary, obstacle_distance
from ..layout import Layout
from ..planar import EPS, clip_norm, dot, limit_closing, norm, rotate
from .frames import LabTransform

_EPS = 1e-3  # m (layout frame): finite-difference step of the clearance gradient
# m (layout frame): a path that meets a surface is judged this far before it, so that the
# clearance gradient there is measured on the drone's side
_BEFORE_SURFACE = 4 * _EPS
FENCE_RAYS = 16  # directions of the fan that finds every surface near a drone, not only the nearest


def clamp_speed(v: np.ndarray, max_speed: float) -> tuple[np.ndarray, np.ndarray]:
    """Commands (D, 2) m/s scaled down to at most max_speed, keeping direction."""
    out = clip_norm(v, max_speed)
    return out, np.linalg.norm(v, axis=-1) > max_speed * (1 + 1e-9)


def _capped(v: np.ndarray, directions: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v (D, 2) with v . u <= limit for every hazard direction u (D, H, 2), limit (D, H)
    where that is possible (planar.limit_closing), changed (D,) bool: the command moved, or a
    limit says back off along no direction (two drones at one spot), which no command fixes
    but the log must show)."""
    out, _ = limit_closing(v, directions, limits, passes=3)
    stuck = np.any((limits < 0) & (np.abs(directions).sum(-1) <= 1e-9), axis=-1)
    return out, np.any(np.abs(out - v) > 1e-12, axis=-1) | stuck


class Fence:
    """Signed clearance of lab positions from the arena border and virtual obstacles, and the fence filter.

    margin (m): how far inside the fence keeps drones; lookahead (s): braking horizon;
    breach (m): how far beyond the border counts as a breach (in a virtual obstacle, any depth).
    """

    def __init__(self, layout: Layout, transform: LabTransform, margin: float, lookahead: float, breach: float):
        self.layout = layout
        self.transform = transform
        self.obstacles = layout.obstacle_set()
        self.border = layout.border()
        self.margin = margin
        self.lookahead = lookahead
        self.breach = breach
        self.solids = ObstacleSet.from_layout(layout, include_border=False)  # the virtual obstacles alone
        angles = np.arange(FENCE_RAYS) * (2 * np.pi / FENCE_RAYS)
        self._fan = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (K, 2) layout frame

    def clearance(self, p_lab: np.ndarray) -> np.ndarray:
        """(D,) m (lab): distance to the nearest border or obstacle surface; negative outside
        the arena or inside an obstacle."""
        q = self.transform.to_layout(p_lab)
        d = obstacle_distance(q, self.obstacles)
        outside = ~inside_boundary(self.layout, q)
        d = np.where(outside, -border_distance(q, self.border), d)
        return d / self.transform.scale

    def normal(self, p_lab: np.ndarray) -> np.ndarray:
        """(D, 2) unit vectors (lab): the direction of growing clearance."""
        q = self.transform.to_layout(p_lab)
        e = np.array([[_EPS, 0.0], [-_EPS, 0.0], [0.0, _EPS], [0.0, -_EPS]])
        samples = self.transform.to_lab(q[:, None, :] + e[None]).reshape(-1, 2)
        c = self.clearance(samples).reshape(-1, 4)
        g = np.stack([c[:, 0] - c[:, 1], c[:, 2] - c[:, 3]], -1)  # layout-frame gradient
        g = rotate(g, self.transform.yaw)
        n = np.linalg.norm(g, axis=-1, keepdims=True)
        return np.where(n > 1e-12, g / np.maximum(n, 1e-12), 0.0)

    def judged(self, p_lab: np.ndarray, ahead_lab: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where to judge drones at p_lab (D, 2) whose motion takes them to ahead_lab (D, 2):
        (points (D, 2) lab, clearance (D,) m, the way clearance grows there (D, 2) unit, lab).

        A drone in free space whose path meets a surface is judged `_BEFORE_SURFACE` short of
        it, its clearance minus how far ahead_lab lies beyond that surface (along the normal):
        the way out is always back. Otherwise at ahead_lab; a drone already outside the arena
        or inside an obstacle where its clearance is lower, now or ahead."""
        tr = self.transform
        q0, q1 = tr.to_layout(p_lab), tr.to_layout(ahead_lab)
        length = norm(q1 - q0)
        way = (q1 - q0) / np.maximum(length, EPS)[:, None]
        c_now = self.clearance(p_lab)
        hit = cast_rays(q0, way, self.obstacles)
        crossed = (c_now > 0) & (length > EPS) & (hit <= length)
        along = np.where(crossed, np.maximum(hit - _BEFORE_SURFACE, 0.0), length)
        points = tr.to_lab(q0 + way * along[:, None])
        c = self.clearance(points)
        back = (c_now <= 0) & (c_now < c)
        points = np.where(back[:, None], p_lab, points)
        c = np.where(back, c_now, c)
        normal = self.normal(points)
        beyond = (length - along) / tr.scale * np.abs(dot(rotate(way, tr.yaw), normal))
        return points, np.where(crossed, c - beyond, c), normal

    def hazards(self, p_lab: np.ndarray, ahead_lab: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For drones at p_lab (D, 2) heading for ahead_lab (D, 2) (default: judged where they
        are; see `judged`): (directions (D, 1 + FENCE_RAYS, 2) unit, lab frame; closing speed
        limits (D, 1 + FENCE_RAYS) m/s; clearance (D,) m at the judged points). First the way
        to the nearest surface, then the rays of a fan that hit something; a drone judged
        outside the arena or inside an obstacle has only the first (its way back in crosses
        a surface)."""
        at, c, normal = self.judged(p_lab, p_lab if ahead_lab is None else ahead_lab)
        toward = -normal[:, None, :]  # (D, 1, 2): the way to the fence
        limit = ((c - self.margin) / self.lookahead)[:, None]
        hit = cast_fan(self.transform.to_layout(at), self._fan, self.obstacles)  # (D, K) layout m
        seen = (self.clearance(at)[:, None] > 0) & (hit < FAR / 2)
        # at most "come no closer" along a ray: a slanted ray's negative limit would demand more
        # than the way out of the margin, which the nearest surface's limit already sets
        ray_limit = np.where(seen, np.maximum((hit / self.transform.scale - self.margin) / self.lookahead, 0.0), np.inf)
        rays = np.broadcast_to(rotate(self._fan, self.transform.yaw), (len(c), FENCE_RAYS, 2))
        return np.concatenate([toward, rays], axis=1), np.concatenate([limit, ray_limit], axis=1), c

    def filter(self, v: np.ndarray, p_lab: np.ndarray, ahead_lab: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(filtered v (D, 2), braking (D,) bool, clearance (D,) m) for commands v to drones at
        p_lab (D, 2) heading for ahead_lab (D, 2) (default: judged where they are)."""
        toward, limit, c = self.hazards(p_lab, ahead_lab)
        v, braking = _capped(v, toward, limit)
        return v, braking, c

    def breached(self, p_lab: np.ndarray) -> np.ndarray:
        """(D,) bool: beyond the border by more than `breach`, or inside a virtual obstacle
        (at any depth: a thin wall is thinner than `breach`)."""
        q = self.transform.to_layout(p_lab)
        inside = obstacle_distance(q, self.solids, with_border=False) < 0
        return (self.clearance(p_lab) < -self.breach) | inside

    def crossed(self, before_lab: np.ndarray, p_lab: np.ndarray) -> np.ndarray:
        """(D,) bool: the straight path from before_lab to p_lab (D, 2) (consecutive
        estimates) meets a virtual obstacle; False where either is not finite."""
        q0, q1 = self.transform.to_layout(before_lab), self.transform.to_layout(p_lab)
        length = norm(q1 - q0)
        ok = np.isfinite(length) & (length > EPS)
        q0, step = np.where(ok[:, None], q0, 0.0), np.where(ok[:, None], q1 - q0, 1.0)
        hit = cast_rays(q0, step / norm(step)[:, None], self.solids)
        return ok & (hit <= length)


def separate(v: np.ndarray, p_lab: np.ndarray, min_separation: float, lookahead: float, movable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Limit each movable drone's closing speed toward every other drone (see module docstring).

    v (D, 2) m/s, p_lab (D, 2) m, movable (D,) bool: drones whose commands we set (the
    others only count as hazards). Returns (v, changed (D,) bool).
    """
    if len(v) < 2:
        return v, np.zeros(len(v), bool)
    u, limit = separation_hazards(p_lab, min_separation, lookahead, movable)
    out, changed = _capped(v, u, limit)
    out = np.where(movable[:, None], out, v)
    return out, changed & movable


def separation_hazards(p_lab: np.ndarray, min_separation: float, lookahead: float, movable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(directions (D, D, 2) from each drone to every other, unit, lab; closing speed limits
    (D, D) m/s, inf for a drone and itself) for drones at p_lab (D, 2): a drone closing on a
    movable one takes half the room, on one we do not command all of it."""
    D = len(p_lab)
    delta = p_lab[None, :, :] - p_lab[:, None, :]  # (D, D, 2): from i to j
    dist = np.linalg.norm(delta, axis=-1)
    u = delta / np.maximum(dist, 1e-9)[..., None]
    share = np.where(movable[None, :], 0.5, 1.0)
    limit = share * (dist - min_separation) / lookahead
    return u, np.where(np.eye(D, dtype=bool), np.inf, limit)


def keep_apart_and_inside(v: np.ndarray, p_lab: np.ndarray, fence: Fence, min_separation: float, lookahead: float,
                          movable: np.ndarray, ahead_lab: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Commands v (D, 2) m/s for drones at p_lab (D, 2) m kept within the fence's and the
    separation's closing-speed limits at once: (v, separating (D,) bool, fencing (D,) bool,
    clearance (D,) m). Both are judged at ahead_lab (D, 2) m, where the drones' motion takes
    them (default p_lab), the fence from each drone's side of every surface (Fence.judged).
    A flag says the command broke one of that filter's limits (or, for separation, two
    drones share one spot). Where no command keeps every limit (a drone pressed against the
    fence by another), the fence's limits alone are kept. Drones not `movable` keep their
    command and count only as hazards."""
    ahead_lab = p_lab if ahead_lab is None else ahead_lab
    u_f, lim_f, clearance = fence.hazards(p_lab, ahead_lab)
    if len(v) < 2:
        out, fencing = _capped(v, u_f, lim_f)
        return out, np.zeros(len(v), bool), fencing, clearance
    u_s, lim_s = separation_hazards(ahead_lab, min_separation, lookahead, movable)
    out, met = limit_closing(v, np.concatenate([u_f, u_s], axis=1), np.concatenate([lim_f, lim_s], axis=1), passes=3)
    if not met.all():
        fence_only, _ = limit_closing(v, u_f, lim_f, passes=3)
        out = np.where(met[:, None], out, fence_only)
    out = np.where(movable[:, None], out, v)
    _, fencing = _capped(v, u_f, lim_f)
    _, separating = _capped(v, u_s, lim_s)
    return out, separating & movable, fencing & movable, clearance


def altitude_speed(z: np.ndarray, height: float, gain: float, max_vz: float) -> np.ndarray:
    """(D,) m/s: vertical speed toward `height` (m) from heights z (D,) m, clipped to max_vz."""
    return np.clip(gain * (height - z), -max_vz, max_vz)
