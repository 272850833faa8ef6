"""Arena layouts: the YAML format of DESIGN.md section 2, validation, random obstacles.

A layout is 2D: origin at the arena's lower-left corner, x right, y up, metres and radians.
`Layout` objects are immutable; `with_random_obstacles` returns a new one whose random
obstacles are resolved into concrete boxes and cylinders.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Mapping, Sequence, Union

import numpy as np
import yaml

from .configio import ConfigError, found_beside, key_hint, number_text, read_text, safe_dump, safe_load, shown, yaml_error_text
from .file_kinds import refuse_another_kind
from .geometry import ObstacleSet, boundary_segments
from .shipped import shipped_dir

LAYOUT_DIR = shipped_dir("configs") / "layouts"
N_BUILTIN = 4
#: most random obstacles per episode (a file's random_obstacles.count, or task.random_obstacles):
#: the physics reserves a geom for each in every world's model
MAX_RANDOM_OBSTACLES = 64


class LayoutError(ConfigError):
    """A malformed or impossible layout; the message names the file and the entry."""


@dataclasses.dataclass(frozen=True)
class Box:
    """A rectangle: centre (m), full extents (m), yaw about +z (rad)."""

    center: tuple[float, float]
    size: tuple[float, float]
    yaw: float = 0.0


@dataclasses.dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder: centre (m), radius (m)."""

    center: tuple[float, float]
    radius: float


@dataclasses.dataclass(frozen=True)
class Wall:
    """A thin wall from `start` to `end` (m) of full `thickness` (m)."""

    start: tuple[float, float]
    end: tuple[float, float]
    thickness: float = 0.05

    def as_box(self) -> Box:
        (x0, y0), (x1, y1) = self.start, self.end
        length = math.hypot(x1 - x0, y1 - y0)
        return Box(((x0 + x1) / 2, (y0 + y1) / 2), (length, self.thickness), math.atan2(y1 - y0, x1 - x0))


Obstacle = Union[Box, Cylinder, Wall]


@dataclasses.dataclass(frozen=True)
class Boundary:
    """The flyable region: 'rectangle' (the arena), a polygon, or a circle."""

    kind: str = "rectangle"
    points: tuple[tuple[float, float], ...] = ()
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0


@dataclasses.dataclass(frozen=True)
class RandomObstacles:
    """Random obstacles drawn per episode: how many, which kinds, size range (m): each one's size
    is drawn uniformly from it and is a cylinder's diameter or a box's longer side (the shorter
    side 0.5-1 times that, the yaw uniform in [0, pi))."""

    count: int = 5
    kinds: tuple[str, ...] = ("box", "cylinder")
    size: tuple[float, float] = (0.15, 0.4)


@dataclasses.dataclass(frozen=True)
class Region:
    """An axis-aligned spawn region: x range and y range (m), low <= high. Equal ends make it a
    line or, in both, a point: a fixed start that holds one drone."""

    x: tuple[float, float]
    y: tuple[float, float]

    @property
    def is_point(self) -> bool:
        """Whether the region is a single point (a fixed start position)."""
        return self.x[0] == self.x[1] and self.y[0] == self.y[1]


@dataclasses.dataclass(frozen=True)
class Layout:
    name: str
    width: float
    height: float
    boundary: Boundary
    obstacles: tuple[Obstacle, ...]
    random_obstacles: RandomObstacles
    spawn_pursuers: Region
    spawn_evaders: Region
    source: str = "<layout>"
    n_random: int = 0  # how many of `obstacles`, the last ones, were placed at random (with_random_obstacles)

    def obstacle_set(self) -> ObstacleSet:
        """All obstacles and the border as arrays for vectorised geometry (geometry.ObstacleSet)."""
        return ObstacleSet.from_layout(self)

    def border(self) -> np.ndarray:
        """Border segments, shape (S, 4): x0, y0, x1, y1 (m); the inside is on the left."""
        return boundary_segments(self)

    def with_random_obstacles(self, rng: np.random.Generator, count: int | None = None, clearance: float = 0.3,
                              count_source: str | None = None, passage_clearance: float = 0.0,
                              passage_source: str = "passage_clearance", restarts: int | None = None) -> "Layout":
        """A copy with `count` (default: the layout's) random obstacles placed and made concrete.

        Random obstacles keep `clearance` (m) from spawn regions, fixed obstacles, the
        border and each other. Raises LayoutError if there is no room for them, naming
        `count_source` (where `count` came from) or else the file's random_obstacles.count.
        With `passage_clearance` (m) over clearance / 2, they are drawn again (same rng) while
        they cut a spawn point off from the other team for a drone centre keeping that far from
        obstacles; LayoutError naming `passage_source` if no placement leaves the passages open.
        `restarts`: placements tried before no room is reported (default layout_random.RESTARTS).
        """
        from .layout_random import RESTARTS, place_random_obstacles

        n = self.random_obstacles.count if count is None else count
        extra = place_random_obstacles(self, rng, n, clearance, count_source, passage_clearance, passage_source,
                                       RESTARTS if restarts is None else restarts)
        return dataclasses.replace(self, obstacles=self.obstacles + tuple(extra), n_random=self.n_random + len(extra),
                                   random_obstacles=dataclasses.replace(self.random_obstacles, count=0))


# ----------------------------------------------------------------------------- parsing


def _finite_number(v: Any) -> bool:
    """Whether v is an int or float (not a bool) that a float holds finitely; an integer too
    long for a float (a 400-digit literal) is not, rather than an OverflowError."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def _pair(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise LayoutError(f"{where}: expected [x, y], got {shown(value)}")
    out = []
    for v in value:
        if not _finite_number(v):
            raise LayoutError(f"{where}: expected two finite numbers, got {shown(value)}")
        out.append(float(v))
    return out[0], out[1]


def _range(value: Any, where: str, one: str, ends: str = "low, high") -> tuple[float, float]:
    """A range [`ends`] in m (ordered by the caller's check), or LayoutError naming `where`; a
    single number is told how to write it as a range whose ends meet, `one` saying what that
    range means (e.g. 'a fixed start')."""
    if _finite_number(value):
        raise LayoutError(f"{where}: expected a range [{ends}] (m; [{shown(value)}, {shown(value)}] for {one}), got {shown(value)}")
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise LayoutError(f"{where}: expected a range [{ends}] (m), got {shown(value)}")
    return _pair(value, where)


def _number(value: Any, where: str, positive: bool = False) -> float:
    if not _finite_number(value):
        raise LayoutError(f"{where}: expected a number, got {shown(value)}")
    if positive and value <= 0:
        raise LayoutError(f"{where}: must be > 0, got {shown(value)}")
    return float(value)


def _mapping(value: Any, where: str, keys: Sequence[str], required: Sequence[str]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise LayoutError(f"{where}: expected a mapping, got {shown(value)}")
    for k in value:
        if k not in keys:
            raise LayoutError(f"{where}: unknown key {shown(k)}{key_hint(k, keys)}")
    for k in required:
        if k not in value:
            raise LayoutError(f"{where}: missing key '{k}'")
    return value


def _parse_obstacle(entry: Any, where: str) -> Obstacle:
    if not isinstance(entry, Mapping) or len(entry) != 1:
        raise LayoutError(f"{where}: expected one of {{box: ...}}, {{cylinder: ...}}, {{wall: ...}}, got {shown(entry)}")
    kind, body = next(iter(entry.items()))
    w = f"{where} ({kind})"
    if kind == "box":
        m = _mapping(body, w, ("center", "size", "yaw"), ("center", "size"))
        size = _pair(m["size"], f"{w}.size")
        if min(size) <= 0:
            raise LayoutError(f"{w}.size: extents must be > 0, got {list(size)}")
        yaw = _number(m.get("yaw", 0.0), f"{w}.yaw")
        if abs(yaw) > 2 * math.pi:  # as the flight transform's yaw: a larger angle is degrees by mistake
            raise LayoutError(f"{w}.yaw: {yaw:g} is beyond +-2 pi: yaw is in radians, not degrees")
        return Box(_pair(m["center"], f"{w}.center"), size, yaw)
    if kind == "cylinder":
        m = _mapping(body, w, ("center", "radius"), ("center", "radius"))
        return Cylinder(_pair(m["center"], f"{w}.center"), _number(m["radius"], f"{w}.radius", positive=True))
    if kind == "wall":
        m = _mapping(body, w, ("from", "to", "thickness"), ("from", "to"))
        start, end = _pair(m["from"], f"{w}.from"), _pair(m["to"], f"{w}.to")
        if start == end:
            raise LayoutError(f"{w}: 'from' and 'to' are the same point {list(start)}")
        return Wall(start, end, _number(m.get("thickness", Wall.thickness), f"{w}.thickness", positive=True))
    raise LayoutError(f"{where}: unknown obstacle kind {shown(kind)}{key_hint(kind, ('box', 'cylinder', 'wall'))}")


def _parse_boundary(value: Any, where: str, arena: tuple[float, float] | None = None) -> Boundary:
    """The boundary entry `value` read at `where`; `arena` (width, height) m, when given, refuses a
    polygon point outside it before the shape checks, whose arithmetic overflows far outside."""
    if value is None or value == "rectangle":
        return Boundary()
    if isinstance(value, Mapping) and len(value) == 1:
        kind, body = next(iter(value.items()))
        if kind == "polygon":
            if not isinstance(body, (list, tuple)) or len(body) < 3:
                raise LayoutError(f"{where}.polygon: expected at least 3 [x, y] points, got {shown(body)}")
            pts = tuple(_pair(p, f"{where}.polygon[{i}]") for i, p in enumerate(body))
            if arena is not None:
                _refuse_points_outside(pts, arena, where)
            from .layout_check import polygon_crossing, polygon_touch

            if len(pts) > 3 and pts[-1] == pts[0]:  # a ring closed as GeoJSON closes it
                raise LayoutError(f"{where}.polygon: the last point {list(pts[-1])} repeats the first: the border "
                                  f"closes by itself; leave the last point out")
            for i, p in enumerate(pts):
                if p in pts[:i]:
                    raise LayoutError(f"{where}.polygon: point {i} {list(p)} repeats point {pts.index(p)}: "
                                      f"the border must not touch itself")
            for i in range(len(pts)):  # a border that turns straight back runs over itself
                a, b, c = (np.array(pts[(i + k) % len(pts)]) for k in range(3))
                u, v = b - a, c - b
                if abs(u[0] * v[1] - u[1] * v[0]) < 1e-12 and float(u @ v) < 0:
                    raise LayoutError(f"{where}.polygon: at {list(pts[(i + 1) % len(pts)])} the border turns straight "
                                      f"back along itself")
            crossing = polygon_crossing(pts)
            if crossing is not None:
                i, j = crossing
                raise LayoutError(f"{where}.polygon: edge {list(pts[i])} -> {list(pts[(i + 1) % len(pts)])} crosses edge "
                                  f"{list(pts[j])} -> {list(pts[(j + 1) % len(pts)])}: the border must not cross itself")
            touch = polygon_touch(pts)
            if touch is not None:  # its walls, built outside each edge, would stand in the flyable region
                i, k = touch
                raise LayoutError(f"{where}.polygon: point {k} {list(pts[k])} lies on edge {list(pts[i])} -> "
                                  f"{list(pts[(i + 1) % len(pts)])}: the border must not touch itself")
            area = _signed_area(pts)
            if abs(area) < 1e-6:
                raise LayoutError(f"{where}.polygon: the points enclose no area")
            if area < 0:  # keep counter-clockwise so the inside is on the left of each edge
                pts = pts[::-1]
            _refuse_sharp_reflex_corners(pts, where)
            _refuse_narrow_gaps_outside(pts, where)
            return Boundary("polygon", points=pts)
        if kind == "circle":
            m = _mapping(body, f"{where}.circle", ("center", "radius"), ("center", "radius"))
            return Boundary("circle", center=_pair(m["center"], f"{where}.circle.center"), radius=_number(m["radius"], f"{where}.circle.radius", positive=True))
    raise LayoutError(f"{where}: expected 'rectangle', {{polygon: [...]}} or {{circle: {{center, radius}}}}, got {shown(value)}")


def _refuse_points_outside(pts: Sequence[tuple[float, float]], arena: tuple[float, float], where: str) -> None:
    """LayoutError at the first polygon point (m) outside the arena of (width, height) m; with
    `where` "<file>: boundary" the message is the one check_layout gives."""
    width, height = arena
    for p in pts:
        if not (-1e-9 <= p[0] <= width + 1e-9 and -1e-9 <= p[1] <= height + 1e-9):
            raise LayoutError(f"{where} polygon point {list(p)} lies outside the {width} x {height} m arena")


def _refuse_sharp_reflex_corners(pts: Sequence[tuple[float, float]], where: str) -> None:
    """LayoutError at a reflex corner sharper than a right angle (an inside angle over 270 deg;
    pts counter-clockwise): the scene's border walls are boxes outside each edge, and there any
    such box stands partly inside the flyable region, where the 2D geometry sees free space."""
    n = len(pts)
    for i in range(n):
        a, b, c = (np.array(pts[(i + k) % n]) for k in range(3))
        u, v = (b - a) / np.linalg.norm(b - a), (c - b) / np.linalg.norm(c - b)
        if u[0] * v[1] - u[1] * v[0] < 0 and float(u @ v) < -1e-9:
            inside = 180.0 + math.degrees(math.acos(max(-1.0, min(1.0, float(u @ v)))))
            raise LayoutError(f"{where}.polygon: at {list(pts[(i + 1) % n])} the border turns into the arena at an inside "
                              f"angle of {inside:.0f} deg, over 270: its walls cannot be built there without standing in "
                              f"the flyable region; widen that notch to a right angle or more, or use a wall obstacle")


#: m: how far a border wall may reach into the flyable region past another part of the border
BORDER_TOLERANCE = 1e-3


def _refuse_narrow_gaps_outside(pts: Sequence[tuple[float, float]], where: str) -> None:
    """LayoutError where the border runs past itself, outside the flyable region, closer than the
    scene's border walls are thick (a slit or notch narrower than BORDER_THICKNESS; pts
    counter-clockwise): a wall built outside one side would stand in the flyable region on the
    other, where the 2D geometry sees free space. Found as a border edge entering a wall's box
    deeper than BORDER_TOLERANCE: the edge a wall stands on and its neighbours only touch its
    faces, and on a finely sampled curve a wall lengthened past a corner grazes the next few
    edges by a fraction of a millimetre."""
    from .geometry import BORDER_THICKNESS, border_walls

    seg = np.array([[*pts[i], *pts[(i + 1) % len(pts)]] for i in range(len(pts))])
    walls = border_walls(seg)
    eps = BORDER_TOLERANCE
    for k, (cx, cy, hx, hy, yaw) in enumerate(walls):
        c, s = math.cos(yaw), math.sin(yaw)
        px, py = seg[:, 0] - cx, seg[:, 1] - cy  # every edge in the wall's frame: p + t d, t in [0, 1]
        qx, qy = seg[:, 2] - cx, seg[:, 3] - cy
        p = np.stack([c * px + s * py, -s * px + c * py], -1)
        d = np.stack([c * qx + s * qy, -s * qx + c * qy], -1) - p
        lo, hi = np.zeros(len(seg)), np.ones(len(seg))
        for axis, half in ((0, hx - eps), (1, hy - eps)):  # clip each edge to the open box (Liang-Barsky)
            with np.errstate(divide="ignore", invalid="ignore"):
                t0, t1 = (-half - p[:, axis]) / d[:, axis], (half - p[:, axis]) / d[:, axis]
            flat = np.abs(d[:, axis]) < 1e-15
            inside = np.abs(p[:, axis]) < half
            lo = np.where(flat, np.where(inside, lo, np.inf), np.maximum(lo, np.minimum(t0, t1)))
            hi = np.where(flat, np.where(inside, hi, -np.inf), np.minimum(hi, np.maximum(t0, t1)))
        enters = hi > lo
        enters[k] = False
        if enters.any():
            j = int(np.argmax(enters))
            a, b = list(pts[k]), list(pts[(k + 1) % len(pts)])
            raise LayoutError(f"{where}.polygon: outside edge {a} -> {b} the border comes back within {BORDER_THICKNESS:g} m "
                              f"(edge {list(pts[j])} -> {list(pts[(j + 1) % len(pts)])}): the scene's {BORDER_THICKNESS:g} m "
                              f"border wall there would stand in the flyable region on the other side; widen that gap to "
                              f"{BORDER_THICKNESS:g} m or more, or close it and use a wall obstacle")


def _signed_area(pts: Sequence[tuple[float, float]]) -> float:
    x = np.array([p[0] for p in pts])
    y = np.array([p[1] for p in pts])
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _parse_region(value: Any, where: str) -> Region:
    m = _mapping(value, where, ("x", "y"), ("x", "y"))
    x, y = _range(m["x"], f"{where}.x", "a fixed start"), _range(m["y"], f"{where}.y", "a fixed start")
    if x[0] > x[1] or y[0] > y[1]:
        raise LayoutError(f"{where}: ranges must be [low, high] with low <= high (low == high in both for a fixed "
                          f"start point), got x={list(x)} y={list(y)}")
    return Region(x, y)


def _parse_random(value: Any, where: str) -> RandomObstacles:
    if value is None:
        return RandomObstacles(count=0)
    m = _mapping(value, where, ("count", "kinds", "size"), ())
    count = m.get("count", 5)
    if isinstance(count, float) and count.is_integer():  # 3.0 or 3e0: a count, as the task's counts take it
        count = int(count)
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise LayoutError(f"{where}.count: expected an integer >= 0, got {shown(count)}")
    if count > MAX_RANDOM_OBSTACLES:
        raise LayoutError(f"{where}.count: {number_text(count)} is more than {MAX_RANDOM_OBSTACLES}, the most random obstacles per "
                          f"episode (as for task.random_obstacles)")
    raw_kinds = m.get("kinds", ("box", "cylinder"))
    if not isinstance(raw_kinds, (list, tuple)):
        raise LayoutError(f"{where}.kinds: expected a list such as [box, cylinder], got {shown(raw_kinds)}")
    kinds = tuple(raw_kinds)
    for k in kinds:
        if k not in ("box", "cylinder"):
            raise LayoutError(f"{where}.kinds: unknown kind {shown(k)}{key_hint(k, ('box', 'cylinder'))}")
    if not kinds:
        raise LayoutError(f"{where}.kinds: must name at least one kind")
    size = _range(m.get("size", (0.15, 0.4)), f"{where}.size", "one size", "min, max")
    if not 0 < size[0] <= size[1]:
        raise LayoutError(f"{where}.size: expected [min, max] with 0 < min <= max, got {list(size)}")
    return RandomObstacles(count, kinds, size)


MAX_ARENA_SIDE = 50.0  # m: the checks grid the arena, and Crazyflie arenas are far smaller
MAX_NAME_BYTES = 100  # a layout name: output files are named after it (with room for what `layout show` adds)


def layout_from_dict(data: Mapping[str, Any], source: str = "<layout>") -> Layout:
    """Parse and validate a layout mapping; errors name `source` and the entry."""
    if data is None:  # YAML of nothing but comments or blank lines
        raise LayoutError(f"{source}: the file holds no layout; a layout sets at least arena and spawn "
                          f"(see configs/layouts/*.yaml, or write one with `pursuit-mj layout new`)")
    m = _mapping(data, source, ("name", "arena", "boundary", "obstacles", "random_obstacles", "spawn"), ("arena", "spawn"))
    arena = _mapping(m["arena"], f"{source}: arena", ("width", "height"), ("width", "height"))
    width = _number(arena["width"], f"{source}: arena.width", positive=True)
    height = _number(arena["height"], f"{source}: arena.height", positive=True)
    for key, side in (("width", width), ("height", height)):
        if side > MAX_ARENA_SIDE:
            raise LayoutError(f"{source}: arena.{key}: {side:g} m is beyond the {MAX_ARENA_SIDE:g} m this simulator "
                              f"handles (an indoor flight arena is a few metres)")
    obstacles_raw = m.get("obstacles")
    if obstacles_raw is None:  # `obstacles:` with nothing after it
        obstacles_raw = []
    if not isinstance(obstacles_raw, list):
        raise LayoutError(f"{source}: obstacles: expected a list, got {shown(obstacles_raw)}")
    obstacles = tuple(_parse_obstacle(o, f"{source}: obstacles[{i}]") for i, o in enumerate(obstacles_raw))
    spawn = _mapping(m["spawn"], f"{source}: spawn", ("pursuers", "evaders"), ("pursuers", "evaders"))
    name = m.get("name", Path(source).stem)
    if not isinstance(name, str):
        raise LayoutError(f"{source}: name {shown(name)}: expected text (quote it in YAML)")
    if not name.strip(" .") or any(c in name for c in "/\\") or not name.isprintable():  # '..': no file name
        raise LayoutError(f"{source}: name {shown(name)}: must be a plain label (no slashes; output files are named after it)")
    if "name" in m and len(name.encode()) > MAX_NAME_BYTES:  # a file name holds at most 255 bytes, and `layout show` adds to it
        raise LayoutError(f"{source}: name '{name[:40]}...': {len(name.encode())} bytes long; at most {MAX_NAME_BYTES} "
                          f"(output files are named after it)")
    layout = Layout(
        name=name,
        width=width,
        height=height,
        boundary=_parse_boundary(m.get("boundary", "rectangle"), f"{source}: boundary", (width, height)),
        obstacles=obstacles,
        random_obstacles=_parse_random(m.get("random_obstacles"), f"{source}: random_obstacles"),
        spawn_pursuers=_parse_region(spawn["pursuers"], f"{source}: spawn.pursuers"),
        spawn_evaders=_parse_region(spawn["evaders"], f"{source}: spawn.evaders"),
        source=source,
    )
    from .layout_check import check_layout

    check_layout(layout)
    return layout


def layout_to_dict(layout: Layout) -> dict[str, Any]:
    """The YAML-ready mapping of a layout (inverse of `layout_from_dict`)."""

    def obstacle(o: Obstacle) -> dict[str, Any]:
        if isinstance(o, Box):
            return {"box": {"center": list(o.center), "size": list(o.size), "yaw": o.yaw}}
        if isinstance(o, Cylinder):
            return {"cylinder": {"center": list(o.center), "radius": o.radius}}
        return {"wall": {"from": list(o.start), "to": list(o.end), "thickness": o.thickness}}

    b = layout.boundary
    boundary: Any = "rectangle"
    if b.kind == "polygon":
        boundary = {"polygon": [list(p) for p in b.points]}
    elif b.kind == "circle":
        boundary = {"circle": {"center": list(b.center), "radius": b.radius}}
    r = layout.random_obstacles
    return {
        "name": layout.name,
        "arena": {"width": layout.width, "height": layout.height},
        "boundary": boundary,
        "obstacles": [obstacle(o) for o in layout.obstacles],
        "random_obstacles": {"count": r.count, "kinds": list(r.kinds), "size": list(r.size)},
        "spawn": {
            "pursuers": {"x": list(layout.spawn_pursuers.x), "y": list(layout.spawn_pursuers.y)},
            "evaders": {"x": list(layout.spawn_evaders.x), "y": list(layout.spawn_evaders.y)},
        },
    }


def builtin_layout_path(index: int) -> Path:
    matches = sorted(LAYOUT_DIR.glob(f"{index}_*.yaml"))
    if not matches:
        raise LayoutError(f"layout {index}: no built-in layout with this index (valid: 0-{N_BUILTIN - 1})")
    return matches[0]


def is_index_text(ref: Any) -> bool:
    """Whether `ref` is text of a built-in index ('2'; not '²', which str.isdigit also takes)."""
    return isinstance(ref, str) and ref.strip().isascii() and ref.strip().isdigit()


def resolve_layout_ref(ref: int | str | Path) -> Path:
    """A layout index ('2', 2) or a file path -> the file path; errors name the reference."""
    if isinstance(ref, (int, np.integer)) and not isinstance(ref, (bool, np.bool_)) or is_index_text(ref):
        return builtin_layout_path(int(ref))
    if isinstance(ref, str) and not ref.strip():
        raise LayoutError(f"layout '{ref}': empty; expected a built-in index 0-{N_BUILTIN - 1} or a file path")
    if not isinstance(ref, (str, Path)):
        raise LayoutError(f"layout {shown(ref)}: expected a built-in index 0-{N_BUILTIN - 1} or a file path")
    path = Path(ref)
    try:
        is_dir, is_file = path.is_dir(), path.is_file()
    except OSError as exc:  # a name too long for the file system, say
        raise LayoutError(f"layout {shown(str(ref))}: cannot use this path ({exc.strerror or exc})") from None
    if is_dir:
        raise LayoutError(f"layout '{ref}': a folder, not a layout file (or a built-in index 0-{N_BUILTIN - 1})")
    if not is_file:
        where = f" in the current folder ({Path.cwd()})" if not path.is_absolute() else ""
        raise LayoutError(f"layout '{ref}': no such file{where}, and not a built-in index 0-{N_BUILTIN - 1}")
    return path


def found_layout_ref(ref: Any, file: str | Path, key: str) -> Any:
    """A layout reference read as `key` of `file` (a task, train or flight file): a built-in index
    as it is, a file path as configio.found_beside finds it (beside `file` when not from the
    current folder). A path found in neither place is a ConfigError naming `file` and `key`, not
    left to fail when the layout loads, where the file that named it is no longer known."""
    if is_index_text(ref):
        return ref
    found = found_beside(ref, file)
    if isinstance(found, str) and found and not Path(found).exists():
        folder, here = Path(file).parent, Path.cwd()
        beside = "" if folder.resolve() == here.resolve() else f" or beside {folder}"
        where = "" if Path(found).is_absolute() else f" in the current folder ({here}){beside}"
        raise ConfigError(f"{file}: key '{key}': layout '{ref}': no such file{where}, "
                          f"and not a built-in index 0-{N_BUILTIN - 1}")
    return found


def load_layout(ref: int | str | Path) -> Layout:
    """Load a built-in layout by index or any layout file by path."""
    path = resolve_layout_ref(ref)
    try:
        data = safe_load(read_text(path, str(path)))
    except yaml.YAMLError as exc:
        raise LayoutError(f"{path}: not valid YAML, {yaml_error_text(exc)}") from None
    try:
        refuse_another_kind(data, str(path), "layout")
    except ConfigError as exc:
        raise LayoutError(str(exc)) from None
    return layout_from_dict(data, str(path))


def save_layout(layout: Layout, path: str | Path) -> Path:
    """Write a layout file atomically (a temp file renamed into place)."""
    from .io_utils import atomic_write_text

    text = safe_dump(layout_to_dict(layout), sort_keys=False, default_flow_style=None)
    return atomic_write_text(Path(path), text)
