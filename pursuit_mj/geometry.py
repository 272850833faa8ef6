"""Vectorised 2D geometry of layouts: signed distances, ray casts and line of sight.

All functions broadcast over leading batch dimensions (worlds, drones, rays). Positions
are in the layout frame (m). Obstacles of one or many worlds are held by `ObstacleSet`:
boxes (..., NB, 5) = cx, cy, half_x, half_y, yaw; cylinders (..., NC, 3) = cx, cy, r; and
the border as segments (..., NS, 4) = x0, y0, x1, y1 (inside on the left). Each comes with a
validity mask so that worlds with different layouts stack into one padded set.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import TYPE_CHECKING, Sequence

import numpy as np

if TYPE_CHECKING:
    from .layout import Layout

FAR = 1e6
#: how far past its ends (a fraction of its length) a segment still counts as hit: a ray through a
#: box corner computes u a rounding error outside [0, 1] on both edges there and would miss both
U_SLACK = 1e-9


@dataclasses.dataclass(frozen=True)
class ObstacleSet:
    """Obstacles as arrays, layout frame (leading dims ... = worlds, or none for one layout).

    boxes (..., NB, 5) [cx, cy, hx, hy, yaw] m, rad (hx, hy half extents); box_valid (..., NB) bool;
    cylinders (..., NC, 3) [cx, cy, r] m; cylinder_valid (..., NC) bool;
    border (..., NS, 4) [x0, y0, x1, y1] m (inside on the left); border_valid (..., NS) bool.
    """

    boxes: np.ndarray
    box_valid: np.ndarray
    cylinders: np.ndarray
    cylinder_valid: np.ndarray
    border: np.ndarray
    border_valid: np.ndarray

    @staticmethod
    def from_layout(layout: "Layout", include_border: bool = True) -> "ObstacleSet":
        from .layout import Box, Cylinder, Wall

        boxes, cyls = [], []
        for o in layout.obstacles:
            if isinstance(o, Wall):
                o = o.as_box()
            if isinstance(o, Box):
                boxes.append([o.center[0], o.center[1], o.size[0] / 2, o.size[1] / 2, o.yaw])
            elif isinstance(o, Cylinder):
                cyls.append([o.center[0], o.center[1], o.radius])
        b = np.array(boxes, dtype=np.float64).reshape(-1, 5)
        c = np.array(cyls, dtype=np.float64).reshape(-1, 3)
        s = boundary_segments(layout) if include_border else np.zeros((0, 4))
        return ObstacleSet(b, np.ones(len(b), bool), c, np.ones(len(c), bool), s, np.ones(len(s), bool))

    @staticmethod
    def stack(sets: Sequence["ObstacleSet"], n_boxes: int | None = None, n_cylinders: int | None = None) -> "ObstacleSet":
        """Stack per-world sets into (W, ...) arrays padded with invalid entries."""
        nb = max([len(s.boxes) for s in sets] + [n_boxes or 0])
        nc = max([len(s.cylinders) for s in sets] + [n_cylinders or 0])
        ns = max(len(s.border) for s in sets)
        W = len(sets)
        boxes = np.zeros((W, max(nb, 1), 5))
        bv = np.zeros((W, max(nb, 1)), bool)
        cyl = np.zeros((W, max(nc, 1), 3))
        cv = np.zeros((W, max(nc, 1)), bool)
        seg = np.zeros((W, max(ns, 1), 4))
        sv = np.zeros((W, max(ns, 1)), bool)
        for i, s in enumerate(sets):
            boxes[i, : len(s.boxes)] = s.boxes
            bv[i, : len(s.boxes)] = s.box_valid
            cyl[i, : len(s.cylinders)] = s.cylinders
            cv[i, : len(s.cylinders)] = s.cylinder_valid
            seg[i, : len(s.border)] = s.border
            sv[i, : len(s.border)] = s.border_valid
        return ObstacleSet(boxes, bv, cyl, cv, seg, sv)

    def with_rows(self, worlds: np.ndarray, sets: Sequence["ObstacleSet"]) -> "ObstacleSet":
        """This (W, ...) set with world worlds[i]'s obstacles replaced by the unbatched sets[i]
        (k,): the arrays `stack` of every world's set gives, at the cost of k worlds instead of a
        Python loop over all W (for sets whose entries are all valid, as `from_layout`'s are)."""
        pairs = (("boxes", "box_valid"), ("cylinders", "cylinder_valid"), ("border", "border_valid"))
        rows = ObstacleSet.stack(sets)
        fields = {}
        for name, valid_name in pairs:
            mine, mine_valid = getattr(self, name), getattr(self, valid_name)
            theirs, theirs_valid = getattr(rows, name), getattr(rows, valid_name)
            width = max(mine.shape[1], theirs.shape[1])
            values = np.zeros((mine.shape[0], width) + mine.shape[2:])
            valid = np.zeros((mine.shape[0], width), bool)
            values[:, : mine.shape[1]], valid[:, : mine.shape[1]] = mine, mine_valid
            values[worlds], valid[worlds] = 0.0, False
            values[worlds, : theirs.shape[1]], valid[worlds, : theirs.shape[1]] = theirs, theirs_valid
            cols = np.flatnonzero(valid.any(axis=0))
            used = int(cols[-1]) + 1 if len(cols) else 1  # stack's width: the widest world's, at least 1
            fields[name], fields[valid_name] = np.ascontiguousarray(values[:, :used]), np.ascontiguousarray(valid[:, :used])
        return ObstacleSet(**fields)

    def take(self, worlds: np.ndarray) -> "ObstacleSet":
        """The set of the listed worlds (k,) only, as (k, ...) arrays padded as this (W, ...) set is."""
        return ObstacleSet(self.boxes[worlds], self.box_valid[worlds], self.cylinders[worlds],
                           self.cylinder_valid[worlds], self.border[worlds], self.border_valid[worlds])

    def with_extra_cylinders(self, centers: np.ndarray, radius: float, valid: np.ndarray) -> "ObstacleSet":
        """Append cylinders (..., K, 2) of one radius (captured evaders), valid (..., K)."""
        r = np.full(centers.shape[:-1] + (1,), radius)
        cyl = np.concatenate([self.cylinders, np.concatenate([centers, r], -1)], axis=-2)
        cv = np.concatenate([self.cylinder_valid, valid], axis=-1)
        return ObstacleSet(self.boxes, self.box_valid, cyl, cv, self.border, self.border_valid)

    # Cached per set (read only), in the layout the hot queries use: targets first, (T, ...)
    # for T obstacles, against queries moved to (Q, ...) with the worlds last. Every operation
    # then runs over contiguous rows of worlds and the minimum over targets is an elementwise
    # minimum of whole rows: numpy is many times slower at broadcasts along a short last axis
    # and at minima over one. Invalid entries are moved out of reach instead of masked.

    @functools.cached_property
    def ray_targets(self) -> tuple[np.ndarray, ...]:
        """Everything rays can hit, split by component (computed once per set).

        Segments (box edges and border) as ax, ay, ex, ey (S, ...): start and edge vector,
        invalid ones collapsed to a far point so they are never hit; cylinders as cx, cy, r2
        (C, ...), invalid ones shrunk to a point beyond FAR.
        """
        seg, sv = self.segments()
        seg = np.concatenate([seg, self.border], axis=-2)
        sv = np.concatenate([sv, self.border_valid], axis=-1)
        seg = np.where(sv[..., None], seg, FAR)
        ax, ay = seg[..., 0], seg[..., 1]
        ex, ey = seg[..., 2] - ax, seg[..., 3] - ay
        cyl = np.where(self.cylinder_valid[..., None], self.cylinders, [10 * FAR, 10 * FAR, 0.0])
        return tuple(_targets_first(v) for v in (ax, ay, ex, ey, cyl[..., 0], cyl[..., 1], cyl[..., 2] ** 2))

    @functools.cached_property
    def distance_targets(self) -> tuple[tuple[np.ndarray, ...], ...]:
        """Boxes (cx, cy, cos yaw, sin yaw, hx, hy), cylinders (cx, cy, r) and border segments
        (x0, y0, dx, dy), each (T, ...); invalid ones placed beyond FAR (computed once per set)."""
        beyond = 10 * FAR
        b = np.where(self.box_valid[..., None], self.boxes, [beyond, beyond, 0.0, 0.0, 0.0])
        boxes = (b[..., 0], b[..., 1], np.cos(b[..., 4]), np.sin(b[..., 4]), b[..., 2], b[..., 3])
        c = np.where(self.cylinder_valid[..., None], self.cylinders, [beyond, beyond, 0.0])
        g = np.where(self.border_valid[..., None], self.border, [beyond, beyond, beyond, beyond])
        border = (g[..., 0], g[..., 1], g[..., 2] - g[..., 0], g[..., 3] - g[..., 1])
        return tuple(tuple(_targets_first(v) for v in group) for group in (boxes, (c[..., 0], c[..., 1], c[..., 2]), border))

    @functools.cached_property
    def distance_constants(self) -> tuple[np.ndarray, np.ndarray]:
        """What `obstacle_distance` derives from `distance_targets` alone, each (T, ...): the boxes'
        -sin yaw and the border segments' squared lengths, at least 1e-12 m^2 (computed once per set)."""
        _, _, _, s, _, _ = self.distance_targets[0]
        _, _, dx, dy = self.distance_targets[2]
        out = (-s, np.maximum(dx * dx + dy * dy, 1e-12))
        for v in out:
            v.flags.writeable = False
        return out

    def fan_targets(self, dirs: np.ndarray) -> tuple[np.ndarray, ...]:
        """What `cast_fan` needs about this set for fixed ray directions dirs (K, 2) (cached per K).

        With segment start a, edge e and d_k x e_s = 1 / inv[s, k], a ray from o along d_k hits
        segment s at t = ((a - o) x e) inv and u = ((a - o) x d_k) inv along it. Returns inv
        (S, K, ...) and c . d_k (C, K, ...) for the cylinders (invalid entries as in ray_targets).
        (Splitting u into a x d_k inv - o x d_k inv, fixed for the set, cancels catastrophically
        where d_k is all but parallel to e and inv is huge: a ray along +y, whose x is cos(pi/2) =
        6e-17, from a point level with a wall's end read 0 or missed the wall.)
        """
        dirs = np.asarray(dirs, dtype=np.float64)
        cache = self.__dict__.setdefault("_fan_cache", {})
        key = dirs.tobytes()
        if key not in cache:
            ax, ay, ex, ey, cx, cy, _ = self.ray_targets  # (T, *B)
            k = (None, slice(None)) + (None,) * (ax.ndim - 1)  # dirs (K,) -> (1, K, 1...)
            dx, dy = dirs[:, 0][k], dirs[:, 1][k]
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / (dx * ey[:, None] - dy * ex[:, None])  # (S, K, *B)
            c_d = cx[:, None] * dx + cy[:, None] * dy  # (C, K, *B)
            out = (inv, c_d)
            for v in out:
                v.flags.writeable = False
            cache[key] = out
        return cache[key]

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Box edges as segments (..., 4*NB, 4) [x0, y0, x1, y1] and their validity (..., 4*NB).

        Computed once per set: the arrays are shared, do not change them."""
        return self._segments

    @functools.cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray]:
        cx, cy, hx, hy, yaw = np.moveaxis(self.boxes, -1, 0)
        c, s = np.cos(yaw), np.sin(yaw)
        corners_local = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
        lx = corners_local[:, 0] * hx[..., None]
        ly = corners_local[:, 1] * hy[..., None]
        px = cx[..., None] + c[..., None] * lx - s[..., None] * ly
        py = cy[..., None] + s[..., None] * lx + c[..., None] * ly
        p = np.stack([px, py], -1)  # (..., NB, 4, 2)
        q = np.roll(p, -1, axis=-2)
        seg = np.concatenate([p, q], -1).reshape(self.boxes.shape[:-2] + (-1, 4))
        valid = np.repeat(self.box_valid, 4, axis=-1)
        seg.flags.writeable = valid.flags.writeable = False
        return seg, valid


def last_axis_first(v: np.ndarray) -> np.ndarray:
    """A view of v (..., T) as (T, ...) (np.moveaxis(v, -1, 0) without its overhead)."""
    return v.transpose((v.ndim - 1,) + tuple(range(v.ndim - 1)))


def first_axis_last(v: np.ndarray) -> np.ndarray:
    """A view of v (T, ...) as (..., T)."""
    return v.transpose(tuple(range(1, v.ndim)) + (0,))


def _targets_first(v: np.ndarray) -> np.ndarray:
    """(..., T) -> (T, ...), contiguous and read only."""
    out = np.ascontiguousarray(last_axis_first(v))
    out.flags.writeable = False
    return out


def _align(targets: np.ndarray, query_ndim: int) -> np.ndarray:
    """Targets (T, *B) shaped to broadcast against queries (Q, ...) of query_ndim dims:
    (T, 1, ..., 1, *B), the batch dims B aligned with the trailing dims of `...`."""
    pad = query_ndim - targets.ndim + 1
    if pad < 1:
        raise ValueError(f"queries of {query_ndim} dims cannot broadcast against obstacle arrays of batch shape {targets.shape[1:]}")
    return targets.reshape(targets.shape[:1] + (1,) * pad + targets.shape[1:])


def _align_fan(table: np.ndarray, query_ndim: int) -> np.ndarray:
    """A per-direction table (T, K, *B) shaped against queries (K, N, ...): (T, K, 1, ..., *B)."""
    return table.reshape(table.shape[:2] + (1,) * (query_ndim + 1 - table.ndim) + table.shape[2:])


def _queries_first(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x and y (P, ...) of points (..., P, 2): the query axis first, the batch dims last.

    C order (copies): numpy lays results out like its inputs, and rows must stay contiguous."""
    return np.ascontiguousarray(last_axis_first(points[..., 0])), np.ascontiguousarray(last_axis_first(points[..., 1]))


def boundary_segments(layout: "Layout", circle_segments: int = 48) -> np.ndarray:
    """The border as segments (S, 4) [x0, y0, x1, y1], counter-clockwise (inside on the left).

    A polygon is taken counter-clockwise whichever way its points run: the loader stores it so,
    but a Layout made directly may hold it clockwise, and the scene builds its walls on the right."""
    b = layout.boundary
    if b.kind == "polygon":
        pts = np.array(b.points, dtype=np.float64)
        x, y = pts[:, 0], pts[:, 1]
        if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:  # twice the signed area: clockwise
            pts = pts[::-1]
    elif b.kind == "circle":
        a = np.linspace(0, 2 * math.pi, circle_segments, endpoint=False)
        pts = np.stack([b.center[0] + b.radius * np.cos(a), b.center[1] + b.radius * np.sin(a)], -1)
    else:
        pts = np.array([[0, 0], [layout.width, 0], [layout.width, layout.height], [0, layout.height]], dtype=np.float64)
    return np.concatenate([pts, np.roll(pts, -1, axis=0)], -1)


#: full thickness (m) of the walls a scene builds outside each border segment
BORDER_THICKNESS = 0.05


def border_walls(segments: np.ndarray, thickness: float = BORDER_THICKNESS) -> np.ndarray:
    """The boxes a scene builds along border segments (S, 4) (counter-clockwise, inside on the
    left), as (S, 5) [cx, cy, hx, hy, yaw] (m, rad): each wall `thickness` thick, just outside
    (right of) its segment, lengthened by `thickness` past its convex (or straight) ends to close
    the corner, but not past reflex ones, where the lengthened part would stand in the flyable region."""
    seg = np.asarray(segments, dtype=np.float64)
    d = seg[:, 2:4] - seg[:, 0:2]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    nxt = np.roll(d, -1, axis=0)
    convex_end = d[:, 0] * nxt[:, 1] - d[:, 1] * nxt[:, 0] > -1e-9  # a left (convex) turn at each segment's end
    convex_start = np.roll(convex_end, 1)
    out = np.empty((len(seg), 5))
    for k, (x0, y0, x1, y1) in enumerate(seg.tolist()):
        length, yaw = math.hypot(x1 - x0, y1 - y0), math.atan2(y1 - y0, x1 - x0)
        ux, uy = math.cos(yaw), math.sin(yaw)
        e0, e1 = thickness * bool(convex_start[k]), thickness * bool(convex_end[k])
        shift = (e1 - e0) / 2  # along the segment; the wall's centre thickness / 2 to its right (uy, -ux)
        out[k] = ((x0 + x1) / 2 + uy * thickness / 2 + ux * shift, (y0 + y1) / 2 - ux * thickness / 2 + uy * shift,
                  length / 2 + (e0 + e1) / 2, thickness / 2, yaw)
    return out


def inside_boundary(layout: "Layout", points: np.ndarray) -> np.ndarray:
    """Whether each point (..., 2) lies inside the layout's border, (...) bool."""
    b = layout.boundary
    if b.kind == "circle":
        return np.linalg.norm(points - np.asarray(b.center), axis=-1) < b.radius
    seg = boundary_segments(layout)
    return _inside_polygon(points, seg)


def inside_polygon(points: np.ndarray, corners) -> np.ndarray:
    """Whether each point (..., 2) lies inside the polygon of `corners` (K, 2) m, (...) bool."""
    pts = np.asarray(corners, dtype=np.float64)
    return _inside_polygon(np.asarray(points, dtype=np.float64), np.concatenate([pts, np.roll(pts, -1, axis=0)], -1))


def _inside_polygon(points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    x, y = points[..., 0:1], points[..., 1:2]
    x0, y0, x1, y1 = seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(crosses & (x < xi), axis=-1) % 2) == 1


def segment_distance(points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance from points (..., P, 2) to segments (..., S, 4): (..., P, S)."""
    # x and y apart: numpy is slow at sums over a last axis of length 2
    ax, ay = seg[..., None, :, 0], seg[..., None, :, 1]
    abx, aby = seg[..., None, :, 2] - ax, seg[..., None, :, 3] - ay
    apx, apy = points[..., :, None, 0] - ax, points[..., :, None, 1] - ay
    t = np.clip((apx * abx + apy * aby) / np.maximum(abx * abx + aby * aby, 1e-12), 0.0, 1.0)
    return np.hypot(apx - t * abx, apy - t * aby)


def box_sdf(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Signed distance from points (..., P, 2) to boxes (..., NB, 5): (..., P, NB); < 0 inside."""
    dx = points[..., :, None, 0] - boxes[..., None, :, 0]
    dy = points[..., :, None, 1] - boxes[..., None, :, 1]
    yaw = boxes[..., None, :, 4]
    c, s = np.cos(yaw), np.sin(yaw)
    lx = np.abs(c * dx + s * dy) - boxes[..., None, :, 2]
    ly = np.abs(-s * dx + c * dy) - boxes[..., None, :, 3]
    outside = np.hypot(np.maximum(lx, 0), np.maximum(ly, 0))
    inside = np.minimum(np.maximum(lx, ly), 0)
    return outside + inside


def cylinder_sdf(points: np.ndarray, cylinders: np.ndarray) -> np.ndarray:
    """Signed distance from points (..., P, 2) to cylinders (..., NC, 3): (..., P, NC)."""
    dx = points[..., :, None, 0] - cylinders[..., None, :, 0]
    dy = points[..., :, None, 1] - cylinders[..., None, :, 1]
    return np.hypot(dx, dy) - cylinders[..., None, :, 2]


def obstacle_distance(points: np.ndarray, obstacles: ObstacleSet, with_border: bool = True) -> np.ndarray:
    """Distance from points (..., P, 2) to the nearest obstacle surface or border (..., P); FAR if none.

    Negative inside an obstacle. The border counts as a surface (distance >= 0).
    """
    # the minimum of box_sdf, cylinder_sdf and segment_distance, with obstacles on the first axis
    boxes, cylinders, border = obstacles.distance_targets
    neg_s, length2 = obstacles.distance_constants
    q = points.ndim - 1
    px, py = _queries_first(points)  # (P, ...)
    cx, cy, c, s, hx, hy = (_align(v, q) for v in boxes)
    neg_s = _align(neg_s, q)
    dx, dy = px - cx, py - cy  # (NB, P, ...)
    lx = np.abs(c * dx + s * dy) - hx
    ly = np.abs(neg_s * dx + c * dy) - hy
    d = np.hypot(np.maximum(lx, 0), np.maximum(ly, 0)) + np.minimum(np.maximum(lx, ly), 0)
    d = d.min(0, initial=FAR)
    cx, cy, r = (_align(v, q) for v in cylinders)
    d = np.minimum(d, (np.hypot(px - cx, py - cy) - r).min(0, initial=FAR))
    if with_border:
        ax, ay, abx, aby = (_align(v, q) for v in border)
        apx, apy = px - ax, py - ay  # (NS, P, ...)
        t = np.clip((apx * abx + apy * aby) / _align(length2, q), 0.0, 1.0)
        d = np.minimum(d, np.hypot(apx - t * abx, apy - t * aby).min(0, initial=FAR))
    return first_axis_last(d)


def border_distance(points: np.ndarray, border: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Distance from points (..., P, 2) to border segments (..., S, 4): (..., P); FAR if none."""
    seg = np.broadcast_to(border, points.shape[:-2] + border.shape[-2:]) if border.ndim == 2 else border
    d = segment_distance(points, seg)
    if valid is not None:
        d = np.where(valid[..., None, :], d, FAR)
    return d.min(-1, initial=FAR)


def cast_rays(origins: np.ndarray, dirs: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """Distance (m) along each ray (..., R, 2) (unit dirs) to the nearest obstacle or border: (..., R).

    The leading dims of origins/dirs must match those of the obstacle set's arrays (or the
    set is unbatched). FAR where nothing is hit; 0 for a ray starting inside a cylinder.
    """
    q = origins.ndim - 1
    ax, ay, ex, ey, cx, cy, r2 = (_align(v, q) for v in obstacles.ray_targets)  # (S, 1, ...) and (C, 1, ...)
    ox, oy = _queries_first(origins)  # (R, ...)
    dx, dy = _queries_first(dirs)
    # segments: o + t d = a + u e, solved by 2D cross products; parallel ones give inf/nan
    aox, aoy = ax - ox, ay - oy  # (S, R, ...)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / (dx * ey - dy * ex)
        t = (aox * ey - aoy * ex) * inv
        u = (aox * dy - aoy * dx) * inv
    # the nearest hit: a minimum over the hits only (`where`), FAR if none (NaNs never hit)
    hit = t.min(0, initial=FAR, where=(t >= 0) & (u >= -U_SLACK) & (u <= 1 + U_SLACK))
    # cylinders: |o + t d - c|^2 = r^2
    ocx, ocy = ox - cx, oy - cy  # (C, R, ...)
    b = ocx * dx + ocy * dy
    cterm = ocx * ocx + ocy * ocy - r2
    disc = b * b - cterm
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
    t0 = -b - sq
    tc = np.fmax(t0, ~((disc >= 0) & (t0 >= 0)) * FAR) * (cterm > 0)  # 0 from inside a cylinder
    return first_axis_last(np.minimum(hit, tc.min(0, initial=FAR)))


def cast_fan(origins: np.ndarray, dirs: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """`cast_rays` for the same K directions dirs (K, 2) (unit) from every origin (..., N, 2):
    distances (..., N, K) m, equal to cast_rays' up to float rounding, about twice as fast
    (what does not depend on the origins is computed once per obstacle set and kept)."""
    q = origins.ndim  # queries (K, N, ...)
    inv, c_d = obstacles.fan_targets(dirs)
    inv, c_d = _align_fan(inv, q), _align_fan(c_d, q)
    ax, ay, ex, ey, cx, cy, r2 = (_align(v, q) for v in obstacles.ray_targets)  # (T, 1, 1.., *B)
    ox, oy = (v[None] for v in _queries_first(origins))  # (1, N, ...)
    d = np.asarray(dirs, dtype=np.float64)
    k = (slice(None),) + (None,) * (q - 1)
    dx, dy = d[:, 0][k], d[:, 1][k]  # (K, 1, ...)
    aox, aoy = ax - ox, ay - oy  # (S, 1, N, ...): a - o first, as cast_rays (see fan_targets)
    with np.errstate(invalid="ignore"):
        t = (aox * ey - aoy * ex) * inv  # (S, K, N, ...)
        u = (aox * dy - aoy * dx) * inv
    hit = t.min(0, initial=FAR, where=(t >= 0) & (u >= -U_SLACK) & (u <= 1 + U_SLACK))  # (K, N, ...), as cast_rays
    ocx, ocy = ox - cx, oy - cy  # (C, 1, N, ...)
    b = (ox * dx + oy * dy) - c_d  # (o - c) . d: (C, K, N, ...)
    cterm = ocx * ocx + ocy * ocy - r2
    disc = b * b - cterm
    with np.errstate(invalid="ignore"):
        t0 = -b - np.sqrt(disc)
    tc = np.fmax(t0, ~((disc >= 0) & (t0 >= 0)) * FAR) * (cterm > 0)  # 0 from inside a cylinder
    out = np.minimum(hit, tc.min(0, initial=FAR))  # (K, N, ...)
    return out.transpose(tuple(range(2, out.ndim)) + (1, 0))


def line_of_sight(a: np.ndarray, b: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """Whether the segment a -> b (..., P, 2) is free of obstacles and border: (..., P) bool."""
    delta = b - a
    dist = np.linalg.norm(delta, axis=-1)
    dirs = delta / np.maximum(dist, 1e-9)[..., None]
    hit = cast_rays(a, dirs, obstacles)
    return hit >= dist - 1e-9


def pairwise_line_of_sight(observer: np.ndarray, target: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """(W, N, T) bool: line_of_sight from each observer (W, N, 2) m to each target (W, T, 2) m."""
    W, N, T = observer.shape[0], observer.shape[1], target.shape[1]
    a = np.broadcast_to(observer[:, :, None, :], (W, N, T, 2)).reshape(W, N * T, 2)
    b = np.broadcast_to(target[:, None, :, :], (W, N, T, 2)).reshape(W, N * T, 2)
    return line_of_sight(a, b, obstacles).reshape(W, N, T)
