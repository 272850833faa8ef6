"""`pursuit-mj simulate`: fly a scripted pattern in each built-in layout, in both fidelities, and report.

Every drone flies toward the middle of the border, then circles it on a radius of its own
(0.5 m + 0.3 m per drone, or spread evenly inside the border where it leaves less room), at
its max speed, steering away from drones closer than 0.25 m. For each layout and fidelity it
prints the simulated and wall-clock time, the real-time factor, the largest altitude error and tilt
(sampled at every controller tick), the contacts and where the drones ended up.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from pursuit_mj.config import BUILTIN_EVADER, TaskConfig, default_config, load_task_yaml, preset_or_file
from pursuit_mj.controller import tilt_angle
from pursuit_mj.geometry import border_distance
from pursuit_mj.layout import N_BUILTIN, Layout, load_layout
from pursuit_mj.layout_check import check_spawn_capacity, free_spawn_points, sample_separated
from pursuit_mj.physics import BatchedPhysics
from pursuit_mj.sensing import PERCEPTION_KEYS
from .common import add_task_args, finite_float, seed_arg, task_config_from_args

SPAWN_SEPARATION = 0.35  # m between spawned drones
SEPARATION = 0.25  # m: drones closer than this steer apart
BORDER_MARGIN = 0.25  # m kept between the outermost circle and the border
#: task keys a scripted flight does not use: what a pursuer perceives, and a layout drawn per episode
UNUSED_KEYS = PERCEPTION_KEYS + ("random_layout",)
MAX_SECONDS = 86400.0  # --seconds at most (a simulated day per run): far larger values overflowed the step count


@dataclasses.dataclass
class FlightReport:
    """What happened in one scripted flight. Lengths m, angles rad, times s."""

    layout: str
    fidelity: str
    sim_time: float
    wall_time: float
    max_altitude_error: float
    max_tilt: float
    contact_steps: np.ndarray  # (D,) decision steps in which each drone touched something
    final_xy: np.ndarray  # (D, 2) m
    names: list[str]

    @property
    def real_time_factor(self) -> float:
        return self.sim_time / max(self.wall_time, 1e-9)


def spawn_positions(layout: Layout, n_pursuers: int, n_evaders: int, rng: np.random.Generator) -> np.ndarray:
    """Start positions (n_pursuers + n_evaders, 2) m in the spawn regions, SPAWN_SEPARATION apart,
    drawn as the env draws them (layout_check.sample_separated: the draw that
    check_spawn_capacity makes sure of)."""
    out = []
    for region, n, role in ((layout.spawn_pursuers, n_pursuers, "pursuers"), (layout.spawn_evaders, n_evaders, "evaders")):
        chosen = sample_separated(free_spawn_points(layout, region), n, rng, SPAWN_SEPARATION)
        if chosen is None:
            raise ValueError(f"layout {layout.source}: the {role} spawn region has no room for {n} drones {SPAWN_SEPARATION} m apart")
        out.extend(chosen)
    return np.array(out)


def circle_commands(xy: np.ndarray, center: np.ndarray, radii: np.ndarray, speed: np.ndarray, separation: float = 0.0) -> np.ndarray:
    """Velocities (W, D, 2) m/s that bring drones at xy (W, D, 2) onto circles around center (2,)
    of radii (D,) m, counter-clockwise, at speed (D,) m/s: radial when far, tangential on the circle.

    Drones closer than `separation` (m) to each other also steer apart, more the closer they are.
    """
    d = xy - center
    rho = np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-6)
    radial = d / rho[..., None]
    tangent = np.stack([-radial[..., 1], radial[..., 0]], -1)
    direction = tangent + (2.0 * (radii - rho) / radii)[..., None] * radial
    if separation > 0:
        apart = xy[:, :, None, :] - xy[:, None, :, :]  # (W, D, D, 2): from each other drone to this one
        gap = np.maximum(np.hypot(apart[..., 0], apart[..., 1]), 1e-6)
        push = np.where(gap < separation, 3.0 * (separation / gap - 1.0), 0.0)
        direction += (apart / gap[..., None] * push[..., None]).sum(axis=2)
    direction /= np.maximum(np.hypot(direction[..., 0], direction[..., 1]), 1e-9)[..., None]
    return direction * speed[:, None]


def circle_radii(n_drones: int, room: float) -> np.ndarray:
    """Radii (n_drones,) m of the drones' circles: 0.5 m + 0.3 m per drone while the outermost
    fits within `room` (m, from the middle to the border less a margin), else `room` shared
    evenly (room / n, 2 room / n, ..., room), so that no drone circles beyond the border."""
    radii = 0.5 + 0.3 * np.arange(n_drones)
    if radii[-1] <= room:
        return radii
    return room * np.arange(1, n_drones + 1) / n_drones


def fly(config: TaskConfig, layout: Layout, seconds: float, seed: int = 0) -> FlightReport:
    """Fly the scripted pattern for `seconds` in one world of `layout` (random obstacles of `seed`)."""
    rng = np.random.default_rng(seed)
    given = None if config.random_obstacles is None else f"the task's random_obstacles (now {config.random_obstacles})"
    world = layout.with_random_obstacles(rng, config.random_obstacles, count_source=given)
    physics = BatchedPhysics(config, [world], nthread=1)
    physics.reset([0], spawn_positions(world, config.n_pursuers, config.n_evaders, rng)[None])
    seg = world.border()
    center = 0.5 * (seg[:, :2].min(0) + seg[:, :2].max(0))
    # the outermost circle keeps BORDER_MARGIN from the border (at least 5 cm of radius where
    # the middle lies closer to it, as in a polygon that bends around it)
    room = max(float(border_distance(center[None], seg)[0]) - BORDER_MARGIN, 0.05)
    radii = circle_radii(physics.n_drones, room)
    h = config.flight_height
    worst = {"dz": 0.0, "tilt": 0.0}

    def track(p: BatchedPhysics) -> None:
        worst["dz"] = max(worst["dz"], float(np.abs(p.positions()[..., 2] - h).max()))
        worst["tilt"] = max(worst["tilt"], float(tilt_angle(p.quaternions()).max()))

    physics.observers.append(track)
    contact_steps = np.zeros(physics.n_drones, np.int64)
    n_steps = max(1, int(round(seconds / config.control_dt)))
    start = time.perf_counter()
    for _ in range(n_steps):
        cmd = circle_commands(physics.positions()[..., :2], center, radii, physics.max_speed, separation=SEPARATION)
        contact_steps += physics.step(cmd)[0]
    wall = time.perf_counter() - start
    return FlightReport(world.name, config.fidelity, n_steps * config.control_dt, wall, worst["dz"], worst["tilt"],
                        contact_steps, physics.positions()[0, :, :2], physics.names)


def register(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="fly a scripted pattern in each built-in layout in both fidelities and print what happened",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
    )
    p.add_argument("--seconds", type=finite_float, default=5.0, help="simulated seconds per layout and fidelity (default 5, at most 86400)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the random obstacles and spawn points (default 0)")
    add_task_args(p)
    p.set_defaults(func=run)


def _format(r: FlightReport) -> list[str]:
    touched = [f"{n} x{c}" for n, c in zip(r.names, r.contact_steps) if c]
    planar = r.fidelity == "point"
    line = (f"{r.layout:<10} {r.fidelity:<9} {r.sim_time:6.1f} {r.wall_time:7.2f} {r.real_time_factor:7.1f} "
            f"{'-' if planar else f'{100 * r.max_altitude_error:.2f}':>10} {'-' if planar else f'{np.degrees(r.max_tilt):.1f}':>9}  "
            f"{', '.join(touched) if touched else 'none'}")
    final = "  ".join(f"{n} ({x:.2f}, {y:.2f})" for n, (x, y) in zip(r.names, r.final_xy))
    return [line, f"{'':<10} final xy (m): {final}"]


def _chosen(args, config: TaskConfig, key: str) -> bool:
    """Whether the user picked `key` (by its flag, --set or a task file, even at its default
    value): then only that value is flown."""
    named = {o.split("=", 1)[0].strip() for o in args.overrides}
    for ref in args.task_files or []:
        data = load_task_yaml(preset_or_file(ref, "task"))
        named |= set(data) if isinstance(data, dict) else set()
    return getattr(args, key, None) is not None or key in named or getattr(config, key) != getattr(default_config(), key)


def run(args) -> int:
    if not np.isfinite(args.seconds) or args.seconds <= 0:
        raise ValueError(f"--seconds: must be > 0, got {args.seconds}")
    if args.seconds > MAX_SECONDS:
        raise ValueError(f"--seconds: must be at most {MAX_SECONDS:g} (a simulated day per run), got {args.seconds:g}")
    base = task_config_from_args(args)
    if args.seconds < base.control_dt:  # fly() flies whole decision steps: this would be rounded up to one
        raise ValueError(f"--seconds: {args.seconds:g} is shorter than one decision step (control_dt {base.control_dt:g} s)")
    n_steps = int(round(args.seconds / base.control_dt))
    if base.evader.model != BUILTIN_EVADER:  # accepted (a task file shared with eval may name it), but not flown
        print(f"note: evader.model {base.evader.model} plays no part in simulate: every drone, the evaders too, flies "
              f"the scripted pattern (eval, render or fly --virtual fly the evaders by it)", file=sys.stderr)
    unused = [key for key in UNUSED_KEYS if _chosen(args, base, key)]
    if unused:
        print(f"note: {', '.join(unused)} play{'s' if len(unused) == 1 else ''} no part in simulate: the scripted pattern "
              f"perceives nothing and flies each layout it names (eval or render play the task with them)", file=sys.stderr)
    layouts = [base.layout] if _chosen(args, base, "layout") else list(range(N_BUILTIN))
    fidelities = [base.fidelity] if _chosen(args, base, "fidelity") else ["quadrotor", "point"]
    team = f"{base.n_pursuers} pursuer{'s' if base.n_pursuers > 1 else ''} + {base.n_evaders} evader{'s' if base.n_evaders > 1 else ''}"
    loaded = [load_layout(ref) for ref in layouts]  # a bad layout is refused before the table starts
    for layout in loaded:  # and so is a spawn region the team does not fit
        check_spawn_capacity(layout, base.n_pursuers, base.n_evaders, SPAWN_SEPARATION)
    print(f"scripted flight: {team} fly to the middle, then circle it; "
          f"{n_steps * base.control_dt:g} s ({n_steps} decision steps) per run, control_dt {base.control_dt:g} s, physics_dt {base.physics_dt:g} s")
    print(f"{'layout':<10} {'fidelity':<9} {'sim s':>6} {'wall s':>7} {'RTF':>7} {'max|dz| cm':>10} {'tilt deg':>9}  contacts (drone x steps)")
    total = time.perf_counter()
    for layout in loaded:
        for fidelity in fidelities:
            config = dataclasses.replace(base, fidelity=fidelity)
            for line in _format(fly(config, layout, args.seconds, args.seed)):
                print(line, flush=True)
    print(f"total wall time {time.perf_counter() - total:.1f} s")
    return 0
