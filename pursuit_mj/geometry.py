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


@dataclasses.dataclass(frozen=True)
class ObstacleSet:
    """Obstacles as arrays. boxes (..., NB, 5) [cx, cy, hx, hy, yaw]; cylinders (..., NC, 3) [cx, cy, r]."""

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

    def with_extra_cylinders(self, centers: np.ndarray, radius: float, valid: np.ndarray) -> "ObstacleSet":
        """Append cylinders (..., K, 2) of one radius (captured evaders), valid (..., K)."""
        r = np.full(centers.shape[:-1] + (1,), radius)
        cyl = np.concatenate([self.cylinders, np.concatenate([centers, r], -1)], axis=-2)
        cv = np.concatenate([self.cylinder_valid, valid], axis=-1)
        return ObstacleSet(self.boxes, self.box_valid, cyl, cv, self.border, self.border_valid)

    @functools.cached_property
    def ray_targets(self) -> tuple[np.ndarray, ...]:
        """Everything rays can hit, split by component for speed (computed once per set).

        Segments (box edges and border) as ax, ay, ex, ey (..., 1, S): start and edge vector,
        invalid ones collapsed to a far point so they are never hit; cylinders as cx, cy, r2
        (..., 1, C), invalid ones with r2 = -1 so they are never hit.
        """
        seg, sv = self.segments()
        seg = np.concatenate([seg, self.border], axis=-2)
        sv = np.concatenate([sv, self.border_valid], axis=-1)
        seg = np.where(sv[..., None], seg, FAR)
        ax, ay = seg[..., None, :, 0], seg[..., None, :, 1]
        ex, ey = seg[..., None, :, 2] - ax, seg[..., None, :, 3] - ay
        cyl = self.cylinders
        r2 = np.where(self.cylinder_valid, cyl[..., 2] ** 2, -1.0)
        return ax, ay, ex, ey, cyl[..., None, :, 0], cyl[..., None, :, 1], r2[..., None, :]

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Box edges as segments (..., 4*NB, 4) [x0, y0, x1, y1] and their validity (..., 4*NB)."""
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
        return seg, valid


def boundary_segments(layout: "Layout", circle_segments: int = 48) -> np.ndarray:
    """The border as segments (S, 4) [x0, y0, x1, y1], counter-clockwise (inside on the left)."""
    b = layout.boundary
    if b.kind == "polygon":
        pts = np.array(b.points, dtype=np.float64)
    elif b.kind == "circle":
        a = np.linspace(0, 2 * math.pi, circle_segments, endpoint=False)
        pts = np.stack([b.center[0] + b.radius * np.cos(a), b.center[1] + b.radius * np.sin(a)], -1)
    else:
        pts = np.array([[0, 0], [layout.width, 0], [layout.width, layout.height], [0, layout.height]], dtype=np.float64)
    return np.concatenate([pts, np.roll(pts, -1, axis=0)], -1)


def inside_boundary(layout: "Layout", points: np.ndarray) -> np.ndarray:
    """Whether each point (..., 2) lies inside the layout's border, (...) bool."""
    b = layout.boundary
    if b.kind == "circle":
        return np.linalg.norm(points - np.asarray(b.center), axis=-1) < b.radius
    seg = boundary_segments(layout)
    return _inside_polygon(points, seg)


def _inside_polygon(points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    x, y = points[..., 0:1], points[..., 1:2]
    x0, y0, x1, y1 = seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.sum(crosses & (x < xi), axis=-1) % 2) == 1


def segment_distance(points: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance from points (..., P, 2) to segments (..., S, 4): (..., P, S)."""
    p = points[..., :, None, :]
    a = seg[..., None, :, 0:2]
    b = seg[..., None, :, 2:4]
    ab = b - a
    t = np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12)
    t = np.clip(t, 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p - closest, axis=-1)


def box_sdf(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Signed distance from points (..., P, 2) to boxes (..., NB, 5): (..., P, NB); < 0 inside."""
    d = points[..., :, None, :] - boxes[..., None, :, 0:2]
    yaw = boxes[..., None, :, 4]
    c, s = np.cos(yaw), np.sin(yaw)
    lx = np.abs(c * d[..., 0] + s * d[..., 1]) - boxes[..., None, :, 2]
    ly = np.abs(-s * d[..., 0] + c * d[..., 1]) - boxes[..., None, :, 3]
    outside = np.hypot(np.maximum(lx, 0), np.maximum(ly, 0))
    inside = np.minimum(np.maximum(lx, ly), 0)
    return outside + inside


def cylinder_sdf(points: np.ndarray, cylinders: np.ndarray) -> np.ndarray:
    """Signed distance from points (..., P, 2) to cylinders (..., NC, 3): (..., P, NC)."""
    d = points[..., :, None, :] - cylinders[..., None, :, 0:2]
    return np.linalg.norm(d, axis=-1) - cylinders[..., None, :, 2]


def obstacle_distance(points: np.ndarray, obstacles: ObstacleSet, with_border: bool = True) -> np.ndarray:
    """Distance from points (..., P, 2) to the nearest obstacle surface or border (..., P); FAR if none.

    Negative inside an obstacle. The border counts as a surface (distance >= 0).
    """
    db = np.where(obstacles.box_valid[..., None, :], box_sdf(points, obstacles.boxes), FAR)
    dc = np.where(obstacles.cylinder_valid[..., None, :], cylinder_sdf(points, obstacles.cylinders), FAR)
    d = np.minimum(db.min(-1, initial=FAR), dc.min(-1, initial=FAR))
    if with_border:
        d = np.minimum(d, border_distance(points, obstacles.border, obstacles.border_valid))
    return d


def border_distance(points: np.ndarray, border: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Distance from points (..., P, 2) to border segments (..., S, 4): (..., P); FAR if none."""
    seg = np.broadcast_to(border, points.shape[:-2] + border.shape[-2:]) if border.ndim == 2 else border
    d = segment_distance(points, seg)
    if valid is not None:
        d = np.where(valid[..., None, :], d, FAR)
    return d.min(-1, initial=FAR)


def ray_segment_hits(origins: np.ndarray, dirs: np.ndarray, seg: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Hit distance along rays (..., R, 2) (unit dirs) to segments (..., S, 4): (..., R); FAR if none."""
    o = origins[..., :, None, :]
    d = dirs[..., :, None, :]
    a = seg[..., None, :, 0:2]
    e = seg[..., None, :, 2:4] - a
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    ao = a - o
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ao[..., 0] * e[..., 1] - ao[..., 1] * e[..., 0]) / denom
        u = (ao[..., 0] * d[..., 1] - ao[..., 1] * d[..., 0]) / denom
    ok = (np.abs(denom) > 1e-12) & (t >= 0) & (u >= 0) & (u <= 1) & valid[..., None, :]
    return np.where(ok, t, FAR).min(-1, initial=FAR)


def ray_circle_hits(origins: np.ndarray, dirs: np.ndarray, circles: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Hit distance along rays (..., R, 2) (unit dirs) to circles (..., C, 3): (..., R); FAR if none."""
    oc = origins[..., :, None, :] - circles[..., None, :, 0:2]
    b = np.sum(oc * dirs[..., :, None, :], -1)
    cterm = np.sum(oc * oc, -1) - circles[..., None, :, 2] ** 2
    disc = b * b - cterm
    sq = np.sqrt(np.maximum(disc, 0))
    t0 = -b - sq
    t1 = -b + sq
    t = np.where(t0 >= 0, t0, np.where(cterm <= 0, 0.0, FAR))  # origin inside: hit at 0
    ok = (disc >= 0) & (t1 >= 0) & valid[..., None, :]
    return np.where(ok, t, FAR).min(-1, initial=FAR)


def cast_rays(origins: np.ndarray, dirs: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """Distance (m) along each ray (..., R, 2) (unit dirs) to the nearest obstacle or border: (..., R).

    The leading dims of origins/dirs must match those of the obstacle set's arrays (or the
    set is unbatched). FAR where nothing is hit; 0 for a ray starting inside a cylinder.
    """
    ax, ay, ex, ey, cx, cy, r2 = obstacles.ray_targets
    ox, oy = origins[..., 0, None], origins[..., 1, None]  # (..., R, 1)
    dx, dy = dirs[..., 0, None], dirs[..., 1, None]
    # segments: o + t d = a + u e, solved by 2D cross products; parallel ones give inf/nan
    aox, aoy = ax - ox, ay - oy  # (..., R, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / (dx * ey - dy * ex)
        t = (aox * ey - aoy * ex) * inv
        u = (aox * dy - aoy * dx) * inv
    hit = np.where((t >= 0) & (u >= 0) & (u <= 1), t, FAR).min(-1, initial=FAR)
    # cylinders: |o + t d - c|^2 = r^2
    ocx, ocy = ox - cx, oy - cy  # (..., R, C)
    b = ocx * dx + ocy * dy
    cterm = ocx * ocx + ocy * ocy - r2
    disc = b * b - cterm
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
    t0 = -b - sq
    tc = np.where(cterm <= 0, 0.0, np.where((disc >= 0) & (t0 >= 0), t0, FAR))
    tc = np.where(r2 >= 0, tc, FAR)
    return np.minimum(hit, tc.min(-1, initial=FAR))


def line_of_sight(a: np.ndarray, b: np.ndarray, obstacles: ObstacleSet) -> np.ndarray:
    """Whether the segment a -> b (..., P, 2) is free of obstacles and border: (..., P) bool."""
    delta = b - a
    dist = np.linalg.norm(delta, axis=-1)
    dirs = delta / np.maximum(dist, 1e-9)[..., None]
    hit = cast_rays(a, dirs, obstacles)
    return hit >= dist - 1e-9
