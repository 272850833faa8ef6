"""Refuse layouts that cannot work, naming the offending entry."""

from __future__ import annotations

import numpy as np

from .configio import TaskValueError
from .geometry import ObstacleSet, boundary_segments, inside_boundary, obstacle_distance
from .layout import LayoutError

#: a spawn point needs this much room to the nearest obstacle or border (m)
SPAWN_CLEARANCE = 0.2
#: spawned drones of one team are at least this far apart (m)
SPAWN_SEPARATION = 0.4
#: a drone centre this far from every wall and obstacle can pass (the task's obstacle_clearance default, m)
PASSAGE_CLEARANCE = 0.1
#: grid pitch of the reachability check (m); coarser for big arenas, at most GRID_CELLS cells a side
GRID_STEP = 0.05
GRID_CELLS = 300


def _obstacle_points(obstacles) -> list[np.ndarray]:
    """Outline sample points (K, 2) of each obstacle, its centre last, for inside-the-arena checks.
    A point beyond the float range (an absurd size in a file) is inf: outside, without a warning."""
    with np.errstate(over="ignore"):
        return [_outline(o) for o in obstacles]


def _outline(o) -> np.ndarray:
    """Outline sample points (K, 2) m of one obstacle, its centre last."""
    from .layout import Box, Wall

    if isinstance(o, Wall):
        o = o.as_box()
    if isinstance(o, Box):
        hx, hy = o.size[0] / 2, o.size[1] / 2
        c, s = np.cos(o.yaw), np.sin(o.yaw)
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy], [0, 0]])
        return np.asarray(o.center) + local @ np.array([[c, s], [-s, c]])
    a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    rim = np.asarray(o.center) + o.radius * np.stack([np.cos(a), np.sin(a)], -1)
    return np.vstack([rim, o.center])


def free_spawn_points(layout, region, clearance: float = SPAWN_CLEARANCE, step: float = 0.05) -> np.ndarray:
    """Grid points (K, 2) m, layout frame, of `region` inside the border and `clearance` (m) away
    from obstacles and border. A point exactly `clearance` away counts (to 1 nm: a start written
    0.2 m from the border lies 0.19999999999999996 m from it in floats)."""
    xs = np.arange(region.x[0], region.x[1] + 1e-9, step)
    ys = np.arange(region.y[0], region.y[1] + 1e-9, step)
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    ok = inside_boundary(layout, pts)
    ok &= obstacle_distance(pts, ObstacleSet.from_layout(layout)) >= clearance - 1e-9
    return pts[ok]


def sample_separated(points: np.ndarray, n: int, rng: np.random.Generator, separation: float, tries: int = 200) -> np.ndarray | None:
    """n of `points` (K, 2) m drawn at random, pairwise at least `separation` (m) apart, as (n, 2); None if no draw fits.

    Each try walks a random permutation of the points and takes every point at least
    `separation` from those taken before, until it has n. A point taken rules out, at once,
    every point closer to it than that, so the walk jumps from one still-allowed point to the
    next: a team that does not fit is told in milliseconds, not seconds, with the same draws.
    """
    for _ in range(tries):
        order = rng.permutation(len(points))
        allowed = np.ones(len(points), bool)  # not within `separation` of a point taken in this try
        chosen: list[np.ndarray] = []
        at = 0
        while len(chosen) < n:
            ahead = allowed[order[at:]]
            if not ahead.any():
                break
            at += int(np.argmax(ahead))
            q = points[order[at]]
            chosen.append(q)
            allowed &= np.hypot(points[:, 0] - q[0], points[:, 1] - q[1]) >= separation
            at += 1
        if len(chosen) == n:
            return np.array(chosen)
    return None


class SpawnCapacityError(LayoutError, TaskValueError):
    """A team size (task key n_pursuers or n_evaders) that a layout's spawn region cannot hold.
    The message is 'KEY=N: REASON'; a CLI names the flag that gave the size instead."""

    def __init__(self, key: str, value: int, reason: str):
        ValueError.__init__(self, f"{key}={value}: {reason}")
        self.key, self.value, self.reason = key, value, reason


CAPACITY_DRAWS = 50  # spawn draws that must all fit for a team size to be accepted


def check_spawn_capacity(layout, n_pursuers: int, n_evaders: int, separation: float) -> None:
    """LayoutError unless each spawn region holds its team `separation` (m) apart."""
    rng = np.random.default_rng(0)
    for name, region, n in (("pursuers", layout.spawn_pursuers, n_pursuers), ("evaders", layout.spawn_evaders, n_evaders)):
        if region.is_point and n > 1:
            raise SpawnCapacityError(
                f"n_{name}", n, f"spawn.{name} of {layout.source} is a single point (x={region.x[0]:g}, y={region.y[0]:g}), "
                f"which holds one drone; {n} {name} need room {separation} m apart: give spawn.{name} ranges with "
                f"low < high, or use n_{name}=1")
        points = free_spawn_points(layout, region)
        # every episode draws its own spawn: a team that fits only some draws would stop a
        # run partway, so CAPACITY_DRAWS draws must all fit
        if any(sample_separated(points, n, rng, separation) is None for _ in range(CAPACITY_DRAWS)):
            raise SpawnCapacityError(
                f"n_{name}", n, f"the spawn region of {layout.source} (x={list(region.x)}, y={list(region.y)}) cannot "
                f"reliably hold {n} {name} {separation} m apart (some random spawns find no room); make the layout's "
                f"spawn region larger or use fewer {name}")


def spawn_gap(layout) -> float:
    """Shortest distance (m) between the pursuers' and the evaders' spawn rectangles; 0 when they overlap."""
    a, b = layout.spawn_pursuers, layout.spawn_evaders
    dx = max(0.0, a.x[0] - b.x[1], b.x[0] - a.x[1])
    dy = max(0.0, a.y[0] - b.y[1], b.y[0] - a.y[1])
    return float(np.hypot(dx, dy))


class SpawnGapError(LayoutError, TaskValueError):
    """Spawn regions within the task's capture_radius of each other: the layout or the radius is
    at fault, so a CLI names where the radius was given (TaskValueError), the message the layout."""

    def __init__(self, value: float, reason: str):
        ValueError.__init__(self, reason)
        self.key, self.value, self.reason = "capture_radius", value, reason


def check_spawn_gap(layout, capture_radius: float, source: str = "capture_radius") -> None:
    """SpawnGapError (a LayoutError) unless the two spawn regions lie more than `capture_radius`
    (m) apart: an evader spawned within it of a pursuer would count as caught on the first step."""
    gap = spawn_gap(layout)
    if gap <= capture_radius:
        where = "overlap" if gap == 0 else f"are {gap:g} m apart"
        raise SpawnGapError(capture_radius, f"{layout.source}: the pursuers' and the evaders' spawn regions {where}, "
                            f"within the {source} of {capture_radius:g} m: an episode could start with its evader "
                            f"caught; move the regions apart")


def grid_components(free: np.ndarray) -> np.ndarray:
    """Labels (X, Y) of the 8-connected components of the True cells of `free` (X, Y): each
    component's cells carry the smallest flat index among them; -1 on cells not free.

    Vectorised: every free cell takes the smallest label in its 3 x 3 neighbourhood, then
    follows its label to that cell's label (pointer jumping), until nothing changes. A label
    is always a cell of the same component, no larger than the cell's own index, so the
    fixed point labels each component with its smallest index.
    """
    nx, ny = free.shape
    none = free.size  # the label of cells not free: larger than every index
    label = np.where(free, np.arange(free.size).reshape(free.shape), none)
    while True:
        padded = np.pad(label, 1, constant_values=none)
        low = label.copy()
        for di in range(3):
            for dj in range(3):
                np.minimum(low, padded[di:di + nx, dj:dj + ny], out=low)
        low[~free] = none
        flat = np.append(low.ravel(), none)  # flat[none] == none
        jumped = flat[flat[:-1]]
        while True:  # a label's own label is no larger: follow the chain
            again = flat[jumped]
            if np.array_equal(again, jumped):
                break
            jumped = again
        jumped = jumped.reshape(free.shape)
        if np.array_equal(jumped, label):
            return np.where(free, label, -1)
        label = jumped


def thinnest_obstacle(layout) -> float:
    """The smallest extent (m) of any of the layout's obstacles: a wall's thickness, a box's
    shorter side, a cylinder's diameter (inf without obstacles)."""
    from .layout import Cylinder, Wall

    sizes = [o.thickness if isinstance(o, Wall) else 2 * o.radius if isinstance(o, Cylinder) else min(o.size)
             for o in layout.obstacles]
    return min(sizes, default=np.inf)


def grid_step(layout, clearance: float) -> float:
    """Pitch (m) of the reachability grid: GRID_STEP, coarser in big arenas (GRID_CELLS a side),
    but never so coarse that a diagonal move between two free cells hops over an obstacle. The
    cells a wall of thickness t blocks form a band t + 2 x clearance wide; a diagonal step spans
    sqrt(2) x pitch of it, so the pitch stays under (t + 2 x clearance) / sqrt(2)."""
    from .layout import LayoutError

    coarse = max(GRID_STEP, max(layout.width, layout.height) / GRID_CELLS)
    thinnest = thinnest_obstacle(layout)
    step = min(coarse, 0.99 * (thinnest + 2 * clearance) / np.sqrt(2))
    if max(layout.width, layout.height) / step > MAX_GRID_CELLS:
        raise LayoutError(f"{layout.source}: its {thinnest:g} m thin obstacle, with {clearance:g} m of "
                          f"clearance, needs a reachability grid over {MAX_GRID_CELLS} cells a side in a "
                          f"{max(layout.width, layout.height):g} m arena; make the obstacle thicker")
    return step


MAX_GRID_CELLS = 3000  # a side: 9 million cells, about a minute of checking


def free_cells(layout, xs: np.ndarray, ys: np.ndarray, clearance: float) -> np.ndarray:
    """(X, Y) bool: which grid points (xs[i], ys[j]) (m) lie inside the border and at least
    `clearance` (m) from it and from every obstacle.

    The same test as `inside_boundary(p) & (obstacle_distance(p, ObstacleSet.from_layout(layout))
    >= clearance)` on every point, cell for cell, without arrays of points x border segments
    (gigabytes for a border of a thousand points): the inside test runs row by row, and each
    border segment is measured only against the cells near it.
    """
    X, Y = len(xs), len(ys)
    if layout.boundary.kind == "circle":
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        free = inside_boundary(layout, np.stack([gx, gy], -1))
    else:
        free = np.zeros((X, Y), bool)
        x0, y0, x1, y1 = boundary_segments(layout).T
        for j, y in enumerate(ys):  # crossing number of a ray to the right, as geometry._inside_polygon counts it
            crosses = (y0 > y) != (y1 > y)
            with np.errstate(divide="ignore", invalid="ignore"):
                xi = np.sort((x0 + (y - y0) * (x1 - x0) / (y1 - y0))[crosses])
            free[:, j] = (len(xi) - np.searchsorted(xi, xs, side="right")) % 2 == 1
    obstacles = ObstacleSet.from_layout(layout)
    rows = max(1, CHUNK_POINTS // max(Y, 1))
    for i in range(0, X, rows):  # fixed obstacles, a block of rows at a time
        gx, gy = np.meshgrid(xs[i:i + rows], ys, indexing="ij")
        free[i:i + rows] &= obstacle_distance(np.stack([gx, gy], -1).reshape(-1, 2), obstacles, with_border=False).reshape(gx.shape) >= clearance
    ax, ay, abx, aby = (np.ravel(v) for v in obstacles.distance_targets[2])
    for a_x, a_y, ab_x, ab_y in zip(ax, ay, abx, aby):  # each border segment, on the cells within reach of it
        lo_x, hi_x = min(a_x, a_x + ab_x) - clearance, max(a_x, a_x + ab_x) + clearance
        lo_y, hi_y = min(a_y, a_y + ab_y) - clearance, max(a_y, a_y + ab_y) + clearance
        i0, i1 = np.searchsorted(xs, lo_x, side="left"), np.searchsorted(xs, hi_x, side="right")
        j0, j1 = np.searchsorted(ys, lo_y, side="left"), np.searchsorted(ys, hi_y, side="right")
        if i0 >= i1 or j0 >= j1:
            continue
        apx, apy = xs[i0:i1, None] - a_x, ys[None, j0:j1] - a_y
        t = np.clip((apx * ab_x + apy * ab_y) / max(ab_x * ab_x + ab_y * ab_y, 1e-12), 0.0, 1.0)
        free[i0:i1, j0:j1] &= ~(np.hypot(apx - t * ab_x, apy - t * ab_y) < clearance)
    return free


CHUNK_POINTS = 1 << 16  # grid points measured against the obstacles at once


def spawn_components(layout, clearance: float = PASSAGE_CLEARANCE) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Which connected free space each free spawn point lies in, for a drone centre keeping
    `clearance` (m) from the border and the layout's obstacles (8-connected grid).

    Returns {"pursuers": (points (K, 2) m layout frame, labels (K,) int), "evaders": ...}:
    points with the same label can fly to each other; -1 for a point whose grid cell is not free (coarse grids only).
    """
    step = grid_step(layout, clearance)
    xs = np.arange(step / 2, layout.width, step)
    ys = np.arange(step / 2, layout.height, step)
    free = free_cells(layout, xs, ys, clearance)
    label = grid_components(free)
    nx, ny = free.shape
    out = {}
    for name, region in (("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)):
        # the cells the spawn points lie in (a region thinner than a cell holds no cell centre)
        pts = free_spawn_points(layout, region)
        i = np.clip((pts[:, 0] // step).astype(int), 0, nx - 1)
        j = np.clip((pts[:, 1] // step).astype(int), 0, ny - 1)
        out[name] = (pts, label[i, j])
    return out


def check_passages(layout, clearance: float = PASSAGE_CLEARANCE, source: str | None = None) -> None:
    """LayoutError unless every free spawn point of both teams lies in one free space for a drone
    centre keeping `clearance` (m) from walls and obstacles; `source` names where it came from."""
    from .layout import LayoutError

    fault = passage_fault(layout, clearance, source)
    if fault is not None:
        raise LayoutError(fault)


def passage_fault(layout, clearance: float = PASSAGE_CLEARANCE, source: str | None = None) -> str | None:
    """What `check_passages` would refuse (its message), or None when every free spawn point can
    reach the other team keeping `clearance` (m) from walls and obstacles.

    A grid misses a gap whose free band (its width less 2 x clearance) holds no cell centre; big
    arenas are gridded coarser (GRID_CELLS a side), and the message then says how wide a gap the
    grid surely sees."""
    src = layout.source
    step = grid_step(layout, clearance)
    needs = (f"a passage needs {2 * clearance:g} m" + (f" at {source} {clearance:g} m" if source else "")
             + f", found on a grid of {step * 100:.3g} cm")
    if step > GRID_STEP * 1.001:
        needs += (f"; in an arena this big the grid surely sees a gap of {2 * clearance + np.sqrt(2) * step:.2f} m "
                  f"or wider, so widen a narrower one")
    comp = spawn_components(layout, clearance)
    shared = set(comp["pursuers"][1].tolist()) & set(comp["evaders"][1].tolist()) - {-1}
    if not shared:
        return (f"{src}: the evaders' spawn region cannot be reached from the pursuers': walls or obstacles "
                f"cut the arena in two ({needs})")
    # every spawn point must lie in the space both teams share: an evader spawned in a closed
    # pocket of its region could never be caught, a pursuer spawned in one never help
    labels = np.concatenate([comp["pursuers"][1], comp["evaders"][1]])
    main = max(shared, key=lambda k: int(np.sum(labels == k)))
    for (name, region), (pts, lab) in zip((("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)), comp.values()):
        cut = (lab != main) & (lab >= 0)
        if cut.any():
            p = [round(float(v), 3) for v in pts[np.flatnonzero(cut)[0]]]
            return (f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} reaches into a pocket cut off "
                    f"from the other team by walls or obstacles (e.g. at {p}; {needs}): a drone spawned there "
                    f"could never meet the other team; open the pocket or keep the spawn region out of it")
    return None


def polygon_crossing(points) -> tuple[int, int] | None:
    """The first pair (i, j) of non-adjacent edges that cross (edge i runs from point i to i+1), or None;
    points (n, 2) m, the polygon's corners in order.

    One numpy pass per edge i over all later edges j, so a border of thousands of points is
    checked in well under a second (a pair at a time took 25 s for 2000 points)."""
    p = np.asarray(points, dtype=float)
    n = len(p)
    a, b = p, np.roll(p, -1, axis=0)  # (n, 2) start and end of every edge

    def side(o, q, r):  # sign of the turn o -> q -> r; any operand may be (n, 2) or (2,)
        return np.sign((q[..., 0] - o[..., 0]) * (r[..., 1] - o[..., 1]) - (q[..., 1] - o[..., 1]) * (r[..., 0] - o[..., 0]))

    for i in range(n - 2):
        j = np.arange(i + 2, n - 1 if i == 0 else n)  # not i's neighbours (edge n-1 closes onto edge 0)
        if len(j) == 0:
            continue
        cross = (side(a[i], b[i], a[j]) * side(a[i], b[i], b[j]) < 0) & (side(a[j], b[j], a[i]) * side(a[j], b[j], b[i]) < 0)
        if cross.any():
            return i, int(j[np.argmax(cross)])
    return None


def polygon_touch(points, tol: float = 1e-9) -> tuple[int, int] | None:
    """The first (i, k) where corner k of points (n, 2) m lies on edge i (from point i to i+1) without
    being one of its ends, within `tol` m: a border that touches or runs along itself without crossing; or None."""
    p = np.asarray(points, dtype=float)
    n = len(p)
    a, ab = p[:, None], (np.roll(p, -1, axis=0) - p)[:, None]  # edges (n, 1, 2)
    aq = p[None] - a  # (n edges, n corners, 2)
    length = np.hypot(ab[..., 0], ab[..., 1])
    along = (ab * aq).sum(-1)
    on = (np.abs(ab[..., 0] * aq[..., 1] - ab[..., 1] * aq[..., 0]) <= tol * length) & (along >= -tol * length) & (along <= length * (length + tol))
    ends = np.arange(n)
    on[ends, ends] = on[ends, (ends + 1) % n] = False
    hits = np.argwhere(on)
    return None if len(hits) == 0 else (int(hits[0][0]), int(hits[0][1]))


def _metres(v: float) -> str:
    """A coordinate (m) for a message: mm digits, or 4 significant ones beyond a kilometre (an
    absurd size in a file), where mm digits ran to hundreds of characters."""
    return f"{v:.3f}" if abs(v) < 1e3 else f"{v:.4g}"


def _describe(o) -> str:
    from .layout import Box, Cylinder, Wall

    if isinstance(o, Cylinder):
        return f"cylinder centre {list(o.center)} radius {o.radius}"
    if isinstance(o, Wall):
        return f"wall from {list(o.start)} to {list(o.end)}"
    if isinstance(o, Box):
        return f"box centre {list(o.center)} size {list(o.size)}"
    return repr(o)


def _what_covers(layout, region, shown: int = 3) -> str:
    """What leaves spawn `region` no point SPAWN_CLEARANCE from obstacles and the border, for a
    refusal: the obstacles within that of some grid point of it inside the border, up to `shown`
    of them described ('obstacles[1] (box ...) covers it'), else the border alone."""
    import dataclasses

    pts = free_spawn_points(layout, region, clearance=-np.inf)  # the region's grid points inside the border
    near = [i for i, o in enumerate(layout.obstacles)
            if (obstacle_distance(pts, ObstacleSet.from_layout(dataclasses.replace(layout, obstacles=(o,)), include_border=False))
                < SPAWN_CLEARANCE - 1e-9).any()]
    if not near:
        return f"all of it lies within {SPAWN_CLEARANCE} m of the border"
    named = [f"obstacles[{i}] ({_describe(layout.obstacles[i])})" for i in near[:shown]]
    more = len(near) - len(named)
    if more:
        listed = ", ".join(named) + f" and {more} more"
    else:
        listed = named[0] if len(named) == 1 else ", ".join(named[:-1]) + " and " + named[-1]
    return f"{listed} cover{'s' if len(near) == 1 else ''} it"


def check_layout(layout) -> None:
    """Raise LayoutError if an obstacle leaves the arena, a spawn region has no free room, or some
    free spawn point cannot be reached from the other team's spawn region past the fixed obstacles."""
    from .layout import LayoutError

    src = layout.source
    for i, pts in enumerate(_obstacle_points(layout.obstacles)):
        in_arena = (pts[:, 0] >= -1e-9) & (pts[:, 0] <= layout.width + 1e-9) & (pts[:, 1] >= -1e-9) & (pts[:, 1] <= layout.height + 1e-9)
        if not in_arena.all():
            out = pts[np.flatnonzero(~in_arena)[0]]  # a corner or rim point (thickness counts), not only the centre line
            raise LayoutError(f"{src}: obstacles[{i}] ({_describe(layout.obstacles[i])}) lies (partly) outside "
                              f"the {layout.width} x {layout.height} m arena: its edge reaches "
                              f"({_metres(out[0])}, {_metres(out[1])}) m, its thickness or size included")
        if layout.boundary.kind != "rectangle" and not inside_boundary(layout, pts[-1:]).all():
            raise LayoutError(f"{src}: obstacles[{i}] ({_describe(layout.obstacles[i])}) has its centre outside the {layout.boundary.kind} boundary")
    b = layout.boundary
    if b.kind == "circle":
        if b.center[0] - b.radius < -1e-9 or b.center[0] + b.radius > layout.width + 1e-9 or b.center[1] - b.radius < -1e-9 or b.center[1] + b.radius > layout.height + 1e-9:
            raise LayoutError(f"{src}: boundary circle (centre {list(b.center)}, radius {b.radius}) leaves the arena")
    if b.kind == "polygon":
        p = np.array(b.points)
        out = (p[:, 0] < -1e-9) | (p[:, 0] > layout.width + 1e-9) | (p[:, 1] < -1e-9) | (p[:, 1] > layout.height + 1e-9)
        if out.any():
            k = int(np.flatnonzero(out)[0])
            raise LayoutError(f"{src}: boundary polygon point {list(b.points[k])} lies outside the {layout.width} x {layout.height} m arena")
    for name, region in (("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)):
        if region.x[0] < 0 or region.y[0] < 0 or region.x[1] > layout.width or region.y[1] > layout.height:
            raise LayoutError(f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} leaves the arena")
        if len(free_spawn_points(layout, region)) == 0:
            if b.kind != "rectangle" and len(free_spawn_points(layout, region, clearance=-np.inf)) == 0:  # no point inside
                raise LayoutError(f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} lies outside the "
                                  f"{b.kind} boundary")
            raise LayoutError(
                f"{src}: spawn.{name} x={list(region.x)} y={list(region.y)} has no free point "
                f"{SPAWN_CLEARANCE} m away from obstacles and the border: {_what_covers(layout, region)}"
            )
    check_passages(layout)
