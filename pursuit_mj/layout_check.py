"""Refuse layouts that cannot work, naming the offending entry."""

from __future__ import annotations

import numpy as np

from .geometry import ObstacleSet, inside_boundary, obstacle_distance

#: a spawn point needs this much room to the nearest obstacle or border (m)
SPAWN_CLEARANCE = 0.2


def _obstacle_points(layout, obstacles) -> list[np.ndarray]:
    """Outline sample points (K, 2) of each obstacle, for inside-the-arena checks."""
    from .layout import Box, Cylinder, Wall

    out = []
    for o in obstacles:
        if isinstance(o, Wall):
            o = o.as_box()
        if isinstance(o, Box):
            hx, hy = o.size[0] / 2, o.size[1] / 2
            c, s = np.cos(o.yaw), np.sin(o.yaw)
            local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy], [0, 0]])
            out.append(np.asarray(o.center) + local @ np.array([[c, s], [-s, c]]))
        else:
            a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            out.append(np.asarray(o.center) + o.radius * np.stack([np.cos(a), np.sin(a)], -1))
    return out


def free_spawn_points(layout, region, clearance: float = SPAWN_CLEARANCE, step: float = 0.05) -> np.ndarray:
    """Grid points (K, 2) of `region` inside the border and `clearance` away from obstacles and border."""
    xs = np.arange(region.x[0], region.x[1] + 1e-9, step)
    ys = np.arange(region.y[0], region.y[1] + 1e-9, step)
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    ok = inside_boundary(layout, pts)
    ok &= obstacle_distance(pts, ObstacleSet.from_layout(layout)) >= clearance
    return pts[ok]


def check_layout(layout) -> None:
    """Raise LayoutError if an obstacle leaves the arena or a spawn region has no free room."""
    from .layout import LayoutError

    src = layout.source
    for i, pts in enumerate(_obstacle_points(layout, layout.obstacles)):
        in_arena = (pts[:, 0] >= -1e-9) & (pts[:, 0] <= layout.width + 1e-9) & (pts[:, 1] >= -1e-9) & (pts[:, 1] <= layout.height + 1e-9)
        if not in_arena.all():
            raise LayoutError(f"{src}: obstacles[{i}] lies (partly) outside the {layout.width} x {layout.height} m arena")
        if layout.boundary.kind != "rectangle" and not inside_boundary(layout, pts[-1:]).all():
            raise LayoutError(f"{src}: obstacles[{i}] has its centre outside the {layout.boundary.kind} boundary")
    b = layout.boundary
    if b.kind == "circle":
        if b.center[0] - b.radius < -1e-9 or b.center[0] + b.radius > layout.width + 1e-9 or b.center[1] - b.radius < -1e-9 or b.center[1] + b.radius > layout.height + 1e-9:
            raise LayoutError(f"{src}: boundary circle (centre {list(b.center)}, radius {b.radius}) leaves the arena")
    if b.kind == "polygon":
        p = np.array(b.points)
        if (p[:, 0] < -1e-9).any() or (p[:, 0] > layout.width + 1e-9).any() or (p[:, 1] < -1e-9).any() or (p[:, 1] > layout.height + 1e-9).any():
            raise LayoutError(f"{src}: boundary polygon has a point outside the {layout.width} x {layout.height} m arena")
    for name, region in (("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)):
        if region.x[0] < 0 or region.y[0] < 0 or region.x[1] > layout.width or region.y[1] > layout.height:
            raise LayoutError(f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} leaves the arena")
        if len(free_spawn_points(layout, region)) == 0:
            raise LayoutError(
                f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} has no free point "
                f"{SPAWN_CLEARANCE} m away from obstacles and the border (spawn region inside an obstacle?)"
            )
