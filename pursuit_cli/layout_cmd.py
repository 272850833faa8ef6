"""`pursuit-mj layout new|show|check`: write, picture and validate layout files (DESIGN.md section 2)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np

from pursuit_mj.config import default_config
from pursuit_mj.io_utils import check_writable, no_new_empty_folders
from pursuit_mj.layout import MAX_NAME_BYTES, MAX_RANDOM_OBSTACLES, Layout, LayoutError, layout_from_dict, layout_to_dict, load_layout, save_layout
from pursuit_mj.geometry import inside_polygon
from pursuit_mj.layout_check import check_spawn_capacity, free_spawn_points
from .common import ListFlag, finite_float, path_arg, seed_arg

#: how many seeds `layout check` and `layout new` try when placing the per-episode random obstacles
CHECK_SEEDS = 100
#: `layout show --obstacle-clearance` default (m): the reference task's
DEFAULT_OBSTACLE_CLEARANCE = default_config().obstacle_clearance


def register(sub) -> None:
    p = sub.add_parser("layout", help="write a new layout file, save a top-down PNG of one, or check one")
    lsub = p.add_subparsers(dest="layout_command", metavar="<action>")
    lsub.required = True
    _register_new(lsub)
    _register_show(lsub)
    _register_check(lsub)


# ----------------------------------------------------------------------------- new


def _register_new(lsub) -> None:
    p = lsub.add_parser(
        "new",
        help="write a new, validated layout file",
        description="Write a layout file: arena, border shape, obstacles, random obstacles, spawn regions. "
        "Lengths in m, angles in rad. The layout is validated before it is written.",
        epilog="example: pursuit-mj layout new arena.yaml --border circle --width 4 --height 4 "
        "--cylinder 2 2.6 0.3 --wall 1 2 1.6 2 --random 2 --seed 7 --episode-obstacles 2",
    )
    p.add_argument("out", metavar="OUT.yaml", help="file to write")
    p.add_argument("--name", help="layout name (default: the file name)")
    p.add_argument("--pursuers", type=int, default=3, help="team size whose spawn room is checked (1-16, default 3)")
    p.add_argument("--evaders", type=int, default=1, help="evaders whose spawn room is checked (1-8, default 1)")
    p.add_argument("--width", type=finite_float, help="arena width along x (m; default 3.6, with --points their largest x)")
    p.add_argument("--height", type=finite_float, help="arena height along y (m; default 5.0, with --points their largest y)")
    p.add_argument("--border", choices=("rectangle", "polygon", "circle"), default="rectangle", help="border shape")
    p.add_argument("--points", nargs="+", action=ListFlag, metavar="X,Y", help="polygon corners for --border polygon (default: the arena with its corners cut)")
    p.add_argument("--center", nargs=2, type=finite_float, metavar=("X", "Y"), help="circle centre for --border circle (default: arena centre)")
    p.add_argument("--radius", type=finite_float, help="circle radius for --border circle (default: fits the arena)")
    p.add_argument("--box", nargs="+", type=finite_float, action="append", default=[], metavar="V",
                   help="add a box: CX CY SX SY [YAW] (centre, full size, yaw in rad); repeatable")
    p.add_argument("--cylinder", nargs=3, type=finite_float, action="append", default=[], metavar=("CX", "CY", "R"),
                   help="add a cylinder: centre and radius; repeatable")
    p.add_argument("--wall", nargs="+", type=finite_float, action="append", default=[], metavar="V",
                   help="add a thin wall: X0 Y0 X1 Y1 [THICKNESS] (default thickness 0.05); repeatable")
    p.add_argument("--random", type=int, default=0, metavar="N", help="add N fixed obstacles (0-64) placed at random (with --seed)")
    p.add_argument("--seed", type=seed_arg, help="seed for --random (default 0)")
    p.add_argument("--episode-obstacles", type=int, default=5, metavar="K",
                   help="random obstacles drawn per episode (the file's random_obstacles.count, default 5)")
    p.add_argument("--obstacle-size", nargs=2, type=finite_float, default=(0.15, 0.4), metavar=("MIN", "MAX"),
                   help="size range of random obstacles (m, default 0.15 0.4): a cylinder's diameter, a box's longer side "
                        "(its shorter side 0.5-1 times that)")
    p.add_argument("--obstacle-kinds", nargs="+", action=ListFlag, choices=("box", "cylinder"), default=["box", "cylinder"],
                   help="kinds of random obstacles (default: box cylinder)")
    p.add_argument("--spawn-pursuers", nargs=4, type=finite_float, metavar=("X0", "X1", "Y0", "Y1"),
                   help="pursuer spawn region (default: a band along the bottom of the border)")
    p.add_argument("--spawn-evaders", nargs=4, type=finite_float, metavar=("X0", "X1", "Y0", "Y1"),
                   help="evader spawn region (default: a band along the top of the border)")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    p.set_defaults(func=run_new)


def _finite(values, flag: str) -> list[float]:
    for v in values:
        if not math.isfinite(v):
            raise ValueError(f"{flag}: {v} is not a finite number")
    return list(values)


def _parse_points(texts: list[str]) -> list[list[float]]:
    points = []
    for t in texts:
        parts = t.split(",")
        try:
            xy = [float(parts[0]), float(parts[1])] if len(parts) == 2 else None
        except ValueError:
            xy = None
        if xy is None or not all(math.isfinite(v) for v in xy):
            raise ValueError(f"--points: '{t}' is not X,Y (two numbers separated by a comma)")
        points.append(xy)
    return points


def _boundary(args) -> tuple[object, tuple[float, float, float, float]]:
    """The YAML boundary entry and its bounding box (x0, x1, y0, y1)."""
    w, h = args.width, args.height
    if args.border != "polygon" and args.points:
        raise ValueError("--points: only used with --border polygon")
    if args.border != "circle" and (args.center is not None or args.radius is not None):
        raise ValueError("--center/--radius: only used with --border circle")
    if args.border == "circle":
        cx, cy = _finite(args.center, "--center") if args.center else (w / 2, h / 2)
        r = args.radius if args.radius is not None else min(w, h) / 2
        if not (math.isfinite(r) and r > 0):
            raise ValueError(f"--radius: must be a number > 0, got {r}")
        return {"circle": {"center": [cx, cy], "radius": r}}, (cx - r, cx + r, cy - r, cy + r)
    if args.border == "polygon":
        if args.points:
            pts = _parse_points(args.points)
        else:
            cut = 0.15 * min(w, h)
            pts = [[cut, 0.0], [w - cut, 0.0], [w, cut], [w, h - cut], [w - cut, h], [cut, h], [0.0, h - cut], [0.0, cut]]
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        return {"polygon": pts}, (min(xs), max(xs), min(ys), max(ys))
    return "rectangle", (0.0, w, 0.0, h)


def _polygon_band(corners, bbox, inset: float, band: float, from_top: bool) -> dict | None:
    """The spawn band nearest the bottom (or top) of a polygon whose corners of the band all lie
    `inset` inside it and which is at least MIN_BAND_WIDTH wide; None if there is none."""
    x0, x1, y0, y1 = bbox
    xs = np.linspace(x0, x1, 181)
    for shift in np.arange(0.0, (y1 - y0) / 2 - band, 0.05):
        lo = (y1 - inset - band - shift) if from_top else (y0 + inset + shift)
        rows = [np.stack([xs, np.full_like(xs, y)], -1) for y in (lo, lo + band / 2, lo + band)]
        ok = np.ones_like(xs, dtype=bool)
        for pts in rows:
            ok &= inside_polygon(pts, corners)
            ok &= inside_polygon(pts + [inset, 0.0], corners) & inside_polygon(pts - [inset, 0.0], corners)
        runs = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
        if len(runs):
            starts, ends = runs[0::2], runs[1::2] - 1
            k = int(np.argmax(xs[ends] - xs[starts]))
            if xs[ends[k]] - xs[starts[k]] >= MIN_BAND_WIDTH:
                return {"x": [round(float(xs[starts[k]]), 3), round(float(xs[ends[k]]), 3)], "y": [round(float(lo), 3), round(float(lo + band), 3)]}
    return None


MIN_BAND_WIDTH = 1.0  # m: a default spawn band holds a team of 3, 0.4 m apart


def _default_spawn(border: str, bbox: tuple[float, float, float, float], corners=None) -> tuple[dict, dict]:
    """Bands along the bottom (pursuers) and top (evaders) of the border: inside a polygon's
    corners when given, else of its bounding box."""
    x0, x1, y0, y1 = bbox
    width, height = x1 - x0, y1 - y0
    if border == "circle":  # keep the bands inside the round border
        cx, cy, r = (x0 + x1) / 2, (y0 + y1) / 2, width / 2
        xs = [round(cx - 0.45 * r, 3), round(cx + 0.45 * r, 3)]
        return ({"x": xs, "y": [round(cy - 0.8 * r, 3), round(cy - 0.5 * r, 3)]},
                {"x": xs, "y": [round(cy + 0.5 * r, 3), round(cy + 0.8 * r, 3)]})
    inset = min(0.2, 0.1 * width)
    band = min(0.6, 0.25 * height)
    if border == "polygon" and corners is not None:
        bottom = _polygon_band(corners, bbox, inset, band, from_top=False)
        top = _polygon_band(corners, bbox, inset, band, from_top=True)
        if bottom is not None and top is not None:
            return bottom, top
    xs = [round(x0 + inset + (0.1 * width if border == "polygon" else 0.0), 3), round(x1 - inset - (0.1 * width if border == "polygon" else 0.0), 3)]
    return ({"x": xs, "y": [round(y0 + inset, 3), round(y0 + inset + band, 3)]},
            {"x": xs, "y": [round(y1 - inset - band, 3), round(y1 - inset, 3)]})


def _obstacles(args) -> list[dict]:
    out: list[dict] = []
    for values in args.box:
        if len(values) not in (4, 5):
            raise ValueError(f"--box: expected CX CY SX SY [YAW], got {len(values)} numbers {values}")
        v = _finite(values, "--box")
        out.append({"box": {"center": v[:2], "size": v[2:4], "yaw": v[4] if len(v) == 5 else 0.0}})
    for values in args.cylinder:
        v = _finite(values, "--cylinder")
        out.append({"cylinder": {"center": v[:2], "radius": v[2]}})
    for values in args.wall:
        if len(values) not in (4, 5):
            raise ValueError(f"--wall: expected X0 Y0 X1 Y1 [THICKNESS], got {len(values)} numbers {values}")
        v = _finite(values, "--wall")
        wall = {"from": v[:2], "to": v[2:4]}
        if len(v) == 5:
            wall["thickness"] = v[4]  # left out, the layout loader's default (layout.Wall.thickness)
        out.append({"wall": wall})
    return out


def _obstacle_flag(args, index: int) -> str:
    """Which flag made obstacle `index` of `_obstacles(args)` (boxes, then cylinders, then walls),
    as the user typed it: 'the 2nd --box'."""
    for flag, given in (("--box", args.box), ("--cylinder", args.cylinder), ("--wall", args.wall)):
        if index < len(given):
            n = index + 1
            suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
            return f"the {n}{suffix} {flag} {' '.join(f'{v:g}' for v in given[index])}"
        index -= len(given)
    return f"obstacles[{index}]"


def build_new_layout(args) -> Layout:
    """The validated layout that `layout new` would write (fixed random obstacles placed)."""
    _check_team_size(args.pursuers, args.evaders)
    _default_arena(args)
    for flag, value in (("--width", args.width), ("--height", args.height)):
        if not math.isfinite(value) or value <= 0:
            raise ValueError(f"{flag}: must be a number > 0, got {value}")
    if not 0 <= args.random <= MAX_RANDOM_OBSTACLES:
        raise ValueError(f"--random: {args.random} is out of range (0 to {MAX_RANDOM_OBSTACLES})")
    if not 0 <= args.episode_obstacles <= MAX_RANDOM_OBSTACLES:
        raise ValueError(f"--episode-obstacles: {args.episode_obstacles} is out of range (0 to {MAX_RANDOM_OBSTACLES})")
    boundary, bbox = _boundary(args)
    pursuers, evaders = _default_spawn(args.border, bbox, boundary["polygon"] if args.border == "polygon" else None)
    if args.spawn_pursuers:
        x0, x1, y0, y1 = _finite(args.spawn_pursuers, "--spawn-pursuers")
        pursuers = {"x": [x0, x1], "y": [y0, y1]}
    if args.spawn_evaders:
        x0, x1, y0, y1 = _finite(args.spawn_evaders, "--spawn-evaders")
        evaders = {"x": [x0, x1], "y": [y0, y1]}
    data = {
        "name": args.name if args.name is not None else Path(args.out).stem,
        "arena": {"width": args.width, "height": args.height},
        "boundary": boundary,
        "obstacles": _obstacles(args),
        "random_obstacles": {"count": args.random, "kinds": list(args.obstacle_kinds), "size": _finite(args.obstacle_size, "--obstacle-size")},
        "spawn": {"pursuers": pursuers, "evaders": evaders},
    }
    source = f"layout new {args.out}"
    try:
        layout = layout_from_dict(data, source)
    except LayoutError as exc:
        if args.points and "boundary polygon point" in str(exc):
            raise LayoutError(f"{exc} (--width and --height set the arena; left out, they fit the points)") from None
        said = re.sub(r"obstacles\[(\d+)\]", lambda m: _obstacle_flag(args, int(m.group(1))), str(exc))
        raise LayoutError(said) from None
    if args.random:  # place the --random obstacles for good: they become fixed obstacles
        layout = layout.with_random_obstacles(np.random.default_rng(args.seed or 0), args.random,
                                              count_source="--random or --obstacle-size")
    data = layout_to_dict(layout)
    n_given = len(data["obstacles"]) - args.random
    data["obstacles"][n_given:] = [_round_floats(o) for o in data["obstacles"][n_given:]]
    data["random_obstacles"]["count"] = args.episode_obstacles
    layout = layout_from_dict(data, source)
    _check_team_fits(layout, args.pursuers, args.evaders,  # first: spawn regions that overlap leave no room either
                     " (with --spawn-pursuers and --spawn-evaders" + ("" if args.spawn_pursuers or args.spawn_evaders
                                                                        else ", or a longer arena") + ")")
    _check_random_fits(layout, "--episode-obstacles or --obstacle-size, or make room")
    return layout


def _default_arena(args) -> None:
    """Fill in --width and --height left out: the largest x and y of --points, else 3.6 x 5.0 m."""
    xs, ys = [3.6], [5.0]
    if args.border == "polygon" and args.points:
        pts = _parse_points(args.points)
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    for flag, axis, values in (("width", "x", xs), ("height", "y", ys)):
        if getattr(args, flag) is None and not max(values) > 0:  # no --width or --height to blame: the points
            raise ValueError(f"--points {' '.join(args.points)}: their largest {axis} is {max(values):g} m, so the arena "
                             f"they size (--{flag} left out) has no {flag}; give the corners of an area")
    args.width = max(xs) if args.width is None else args.width
    args.height = max(ys) if args.height is None else args.height


def _check_team_fits(layout: Layout, n_pursuers: int, n_evaders: int, how_to_move: str = "") -> None:
    """What every task on `layout` needs: room to spawn the team, and the two teams' regions
    farther apart than the default capture_radius. LayoutError naming the flags otherwise
    (`how_to_move` added to the advice to move the regions apart: the flags that do it)."""
    from pursuit_mj.config import default_config
    from pursuit_mj.layout_check import SPAWN_SEPARATION, check_spawn_gap

    try:
        check_spawn_capacity(layout, n_pursuers, n_evaders, SPAWN_SEPARATION)
    except LayoutError as exc:
        raise LayoutError(f"{exc} (checked for --pursuers {n_pursuers} --evaders {n_evaders})") from None
    try:
        check_spawn_gap(layout, default_config().capture_radius, "default capture_radius")
    except LayoutError as exc:
        raise LayoutError(f"{exc}{how_to_move}") from None


def _check_team_size(n_pursuers: int, n_evaders: int) -> None:
    """ValueError naming the flag if a team size is outside what every task allows (TaskConfig's bounds)."""
    from pursuit_mj.config import TaskConfig

    meta = {f.name: f.metadata for f in dataclasses.fields(TaskConfig)}
    for flag, key, n in (("--pursuers", "n_pursuers", n_pursuers), ("--evaders", "n_evaders", n_evaders)):
        lo, hi = meta[key]["lo"], meta[key]["hi"]
        if not lo <= n <= hi:
            raise ValueError(f"{flag}: {n} is out of range ({lo} to {hi}, the task's {key})")


def _round_floats(value, digits: int = 3):
    """A copy of a nested YAML value with floats rounded to mm (placed obstacles read better)."""
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, dict):
        return {k: _round_floats(v, digits) for k, v in value.items()}
    if isinstance(value, list):
        return [_round_floats(v, digits) for v in value]
    return value


def _check_random_fits(layout: Layout, hint: str, seeds: int = CHECK_SEEDS) -> int:
    """Place the per-episode random obstacles with `seeds` seeds; LayoutError naming the seeds that
    found no room (up to MAX_FAILED_SEEDS) if any did. Returns seeds tried.

    An episode that draws no room stops the run it belongs to, so a count that fits most draws
    but not all is refused too (20 obstacles in an open 3.6 x 5 m arena: 2 of 100 seeds)."""
    if layout.random_obstacles.count == 0:
        return 0
    failed, first = [], None
    for seed in range(seeds):
        try:
            layout.with_random_obstacles(np.random.default_rng(seed), count_source=hint)
        except LayoutError as exc:
            first = first or exc
            failed.append(seed)
            if len(failed) == MAX_FAILED_SEEDS:
                break
    if failed:
        which = ", ".join(str(s) for s in failed) + (" and maybe more (the check stopped there)" if len(failed) == MAX_FAILED_SEEDS else "")
        raise LayoutError(f"{first} (the check places the {layout.random_obstacles.count} per-episode random obstacles "
                          f"with placement seeds 0-{seeds - 1}: seed{'s' if len(failed) > 1 else ''} {which} found no room; "
                          f"an episode whose draw finds no room stops its run)") from None
    return seeds


MAX_FAILED_SEEDS = 5


def run_new(args) -> int:
    out = Path(args.out)
    with no_new_empty_folders():  # refused (a bad flag, a layout that cannot work): no folder left for OUT
        check_writable(out, "OUT")  # a folder is named as one, not taken for a file --force would overwrite
        if out.suffix.lower() not in (".yaml", ".yml"):
            raise ValueError(f"OUT {out}: expected a .yaml file name (a layout file is YAML)")
        if out.exists() and not args.force:
            raise ValueError(f"OUT {out}: exists already (use --force to overwrite)")
        if args.seed is not None and not args.random:  # it would change nothing in the file
            raise ValueError(f"--seed {args.seed}: seeds the obstacles that --random places, and none is asked for; "
                             f"give --random N, or leave --seed out")
        layout = build_new_layout(args)
        save_layout(layout, out)
    print(f"wrote {out}: {_summary_line(layout)}")
    return 0


# ----------------------------------------------------------------------------- show


def _register_show(lsub) -> None:
    p = lsub.add_parser("show", help="save a top-down PNG of a layout (file or built-in index)")
    p.add_argument("layout", metavar="FILE|INDEX", help="layout file or built-in index 0-3")
    p.add_argument("-o", "--out", type=path_arg, help="PNG to write (default: layout_<name>.png)")
    p.add_argument("--seed", type=seed_arg,
                   help="seed of the random obstacles drawn (default 0); an episode's own seed, which render reports "
                        "(e.g. 'episode 0: success after 168 steps (seed 3013895268)'), draws that episode's, unless the task "
                        "drew its layout too (random_layout) or set its own random_obstacles count (then give it with --count) "
                        "or an obstacle_clearance over 0.15 m (then give it with --obstacle-clearance)")
    p.add_argument("--count", type=int, help="random obstacles to draw (default: the layout's random_obstacles.count)")
    p.add_argument("--obstacle-clearance", type=finite_float, metavar="M",
                   help=f"the task's obstacle_clearance (m; default {DEFAULT_OBSTACLE_CLEARANCE:g}, the reference task's): above 0.15 m an episode "
                        "draws random obstacles that close a passage between the spawn regions again, and so does this")
    p.add_argument("--no-random", action="store_true", help="draw no random obstacles")
    p.set_defaults(func=run_show)


def run_show(args) -> int:
    from pursuit_mj.layout_preview import save_layout_png

    layout = load_layout(args.layout)
    if args.count is not None and not 0 <= args.count <= MAX_RANDOM_OBSTACLES:
        raise ValueError(f"--count: {args.count} is out of range (0 to {MAX_RANDOM_OBSTACLES}, the task's random_obstacles)")
    for flag, value in (("--count", args.count), ("--seed", args.seed), ("--obstacle-clearance", args.obstacle_clearance)):
        if value is not None and args.no_random:  # it would change nothing in the picture
            raise ValueError(f"{flag} {value:g}: draws random obstacles, which --no-random leaves out; give one of them")
    args.seed = 0 if args.seed is None else args.seed
    if args.obstacle_clearance is None:
        args.obstacle_clearance = DEFAULT_OBSTACLE_CLEARANCE
    if args.obstacle_clearance < 0:
        raise ValueError(f"--obstacle-clearance: must be >= 0, got {args.obstacle_clearance:g}")
    try:  # a clearance no task takes (the task's own checks: spawned drones would collide at once)
        default_config(obstacle_clearance=args.obstacle_clearance)
    except ValueError as exc:
        raise ValueError(f"--obstacle-clearance {args.obstacle_clearance:g}: {str(exc).split(': ', 2)[-1]}") from None
    # a name taken from a long file name (a name of its own is at most MAX_NAME_BYTES) is cut to fit a file name
    out = Path(args.out or f"layout_{layout.name.encode()[:MAX_NAME_BYTES].decode(errors='ignore')}.png")
    if out.suffix.lower() != ".png":
        raise ValueError(f"--out {out}: expected a .png file name")
    try:
        with no_new_empty_folders():  # the drawing refused (no room for --count obstacles): no folder left for --out
            check_writable(out, "--out")
            save_layout_png(layout, out, seed=None if args.no_random else args.seed, count=args.count,
                            passage_clearance=args.obstacle_clearance, passage_source="--obstacle-clearance",
                            count_source=None if args.count is None else f"--count {args.count}")
    except LayoutError as exc:
        if args.count is None or "no room for random obstacle" not in str(exc):
            raise  # the fixed walls close a passage, or the placements' message names --count already
        found = str(exc).split(" (sizes")[0]  # the file's own advice does not apply to a count from the flag
        raise LayoutError(f"--count {args.count}: {found}; draw fewer") from None
    print(f"wrote {out}")
    return 0


# ----------------------------------------------------------------------------- check


def _register_check(lsub) -> None:
    p = lsub.add_parser("check", help="validate a layout file and print a summary")
    p.add_argument("layout", metavar="FILE|INDEX", help="layout file or built-in index 0-3")
    p.add_argument("--pursuers", type=int, default=3, help="team size whose spawn room is checked (1-16, default 3)")
    p.add_argument("--evaders", type=int, default=1, help="evaders whose spawn room is checked (1-8, default 1)")
    p.set_defaults(func=run_check)


def _summary_line(layout: Layout) -> str:
    kinds: dict[str, int] = {}
    for o in layout.obstacles:
        kinds[type(o).__name__.lower()] = kinds.get(type(o).__name__.lower(), 0) + 1
    plural = {"box": "boxes", "cylinder": "cylinders", "wall": "walls"}
    obstacles = ", ".join(f"{n} {plural[k] if n > 1 else k}" for k, n in kinds.items()) or "no obstacles"
    return (f"'{layout.name}' {layout.width:g} x {layout.height:g} m, {layout.boundary.kind} border, {obstacles}, "
            f"{layout.random_obstacles.count} random per episode")


def run_check(args) -> int:
    from pursuit_mj.layout_check import SPAWN_SEPARATION
    from pursuit_mj.scene import SceneSpec, build_model

    _check_team_size(args.pursuers, args.evaders)
    layout = load_layout(args.layout)
    _check_team_fits(layout, args.pursuers, args.evaders)  # first: spawn regions that overlap leave no room either
    tried = _check_random_fits(layout, "random_obstacles.count or size in the file, or make room")
    placed = layout.with_random_obstacles(np.random.default_rng(0))
    models = {f: build_model(SceneSpec(placed, args.pursuers, args.evaders, f)) for f in ("point", "quadrotor")}
    print(f"layout {layout.source}: valid")
    print(f"  {_summary_line(layout)}")
    r = layout.random_obstacles
    print(f"  random obstacles: {r.count} of {', '.join(r.kinds)}, size {r.size[0]:g}-{r.size[1]:g} m")
    for name, region in (("pursuers", layout.spawn_pursuers), ("evaders", layout.spawn_evaders)):
        free = free_spawn_points(layout, region)
        if region.is_point:  # a fixed start (the checks above refused one that is not free)
            print(f"  spawn {name}: the point ({region.x[0]:g}, {region.y[0]:g}) m, a fixed start for one drone")
        else:
            print(f"  spawn {name}: x {region.x[0]:g}-{region.x[1]:g}, y {region.y[0]:g}-{region.y[1]:g} m, {len(free)} free points on a 5 cm grid")
    print(f"  room for {args.pursuers} pursuers and {args.evaders} evader(s) {SPAWN_SEPARATION} m apart; "
          f"the evaders' spawn region is reachable from the pursuers'")
    if tried:
        print(f"  random obstacles placed with seeds 0-{tried - 1}: ok")
    for fidelity, model in models.items():
        print(f"  MuJoCo scene ({fidelity}, {args.pursuers}+{args.evaders} drones, seed 0): compiles, {model.ngeom} geoms")
    return 0


