"""Seeded placement of random obstacles that avoid spawn regions, the border and each other."""

from __future__ import annotations

import numpy as np

from .geometry import ObstacleSet, border_distance, inside_boundary, obstacle_distance

MAX_TRIES = 1000  # draws for one obstacle
RESTARTS = 10  # placements of all obstacles, before no room is reported


def _spawn_distance(layout, pts: np.ndarray) -> np.ndarray:
    """Distance (P,) from points to the nearest spawn rectangle (0 inside)."""
    out = np.full(len(pts), np.inf)
    for r in (layout.spawn_pursuers, layout.spawn_evaders):
        dx = np.maximum(np.maximum(r.x[0] - pts[:, 0], pts[:, 0] - r.x[1]), 0)
        dy = np.maximum(np.maximum(r.y[0] - pts[:, 1], pts[:, 1] - r.y[1]), 0)
        out = np.minimum(out, np.hypot(dx, dy))
    return out


def place_random_obstacles(layout, rng: np.random.Generator, count: int, clearance: float, count_source: str | None = None) -> list:
    """Draw `count` obstacles of the layout's kinds and size range; LayoutError if no room, naming
    `count_source` (where the count came from; default: the file's random_obstacles.count).

    Obstacles are placed one by one; when one finds no room, the placement starts over (up to
    RESTARTS times, drawing on from the same rng): early obstacles can block the rest in one
    draw and leave room in another, and one episode's unlucky draw must not stop a run.
    """
    from .layout import LayoutError

    spec = layout.random_obstacles
    border = layout.border()
    for _ in range(RESTARTS):
        placed = _place_once(layout, rng, count, clearance, border)
        if len(placed) == count:
            return placed
    raise LayoutError(
        f"{layout.source}: no room for random obstacle {len(placed) + 1} of {count} "
        f"(sizes {list(spec.size)} m, clearance {clearance} m); "
        + (f"lower {count_source}" if count_source else "lower random_obstacles.count or .size")
    )


def _place_once(layout, rng: np.random.Generator, count: int, clearance: float, border: np.ndarray) -> list:
    """Up to `count` obstacles placed one by one; fewer if one finds no room in MAX_TRIES draws."""
    from .layout import Box, Cylinder

    spec = layout.random_obstacles
    placed: list = []
    others = ObstacleSet.from_layout(layout, include_border=False)
    for _ in range(count):
        for _ in range(MAX_TRIES):
            kind = spec.kinds[rng.integers(len(spec.kinds))]
            size = rng.uniform(spec.size[0], spec.size[1])
            center = np.array([rng.uniform(0, layout.width), rng.uniform(0, layout.height)])
            if kind == "cylinder":
                cand = Cylinder((float(center[0]), float(center[1])), float(size / 2))
                reach = size / 2
            else:
                aspect = rng.uniform(0.5, 1.0)
                cand = Box((float(center[0]), float(center[1])), (float(size), float(size * aspect)), float(rng.uniform(0, np.pi)))
                reach = 0.5 * np.hypot(size, size * aspect)
            pts = center[None]
            if not inside_boundary(layout, pts)[0]:
                continue
            if border_distance(pts, border)[0] < reach + clearance:
                continue
            if _spawn_distance(layout, pts)[0] < reach + clearance:
                continue
            if obstacle_distance(pts, others, with_border=False)[0] < reach + clearance:
                continue
            placed.append(cand)
            others = ObstacleSet.from_layout(_with(layout, placed), include_border=False)
            break
        else:
            return placed
    return placed


def _with(layout, extra: list):
    import dataclasses

    return dataclasses.replace(layout, obstacles=layout.obstacles + tuple(extra))
