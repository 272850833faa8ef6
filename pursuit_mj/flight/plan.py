"""A flight file resolved into everything the bridge needs, with the cross-checks that need the layout.

`resolve_flight` loads the layout, builds the task config (the flight file's `task` keys
<- `--set` overrides <- what the flight itself fixes: drone counts, layout, height, rate),
and refuses flights that cannot work: an arena that does not fit the lab, a drone that
starts outside the arena or inside a virtual obstacle, drones that start too close, a
separation guard that would forbid every capture, a geofence margin below the task's
obstacle clearance (zero included) or one that closes every passage between an evader
and the pursuers (for a target, flown by someone else, a warning). Flights that can work
but are risky resolve with `FlightPlan.warnings`: a geofence margin shorter than the
braking distance at the fastest command, a separation guard below the task's teammate
clearance (in the lab), a drone that starts inside the geofence margin, a task speed above
the safety limit. `fly` and `fly check` print them with the plan, the bridge logs each as a
`plan_warning` event. Nothing here touches a radio.

Drone order in a plan (and in every array of the bridge): pursuers first, then evaders
and targets, each group in file order; this is the simulator's state order.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..config import TaskConfig, found_code_ref
from ..configio import ConfigError, build, check_values, load, parse_override, to_dict
from ..evader_models import make_evader_model
from ..geometry import border_distance, inside_boundary, obstacle_distance
from ..layout import Layout, found_layout_ref, load_layout
from ..layout_check import free_cells, grid_components, grid_step
from ..obs_spec import ObsSpec
from ..user_file import is_file_reference
from .frames import DroneFrames, LabTransform
from .spec import FlightSpec, LabBounds, SafetyLimits, check_uri, drone_names

#: task keys a flight fixes itself (from its drones, layout, height and rate; its physics is the real world's)
FIXED_TASK_KEYS = ("n_pursuers", "n_evaders", "layout", "flight_height", "control_dt", "random_obstacles", "random_layout",
                   "physics_dt", "controller_hz")


#: task keys that mean nothing in a flight, and why: the simulator's stand-ins for what the real world has
SIMULATION_ONLY_KEYS = {
    "fidelity": "the physics is the real world's (the policy is trained in either fidelity)",
    "command_latency": "the delay from decision to motion is the real loop's own (motion capture, policy, radio); "
                       "the key stands in for it in simulation",
}


TASK_FIELDS = frozenset(f.name for f in dataclasses.fields(TaskConfig))
#: keys of the flight file and of its safety section, which `--set` (task keys) does not take
FLIGHT_FIELDS = frozenset(f.name for f in dataclasses.fields(FlightSpec) if f.name != "source")
SAFETY_FIELDS = frozenset(f.name for f in dataclasses.fields(SafetyLimits))


def _why_fixed(key: str) -> str:
    """Why a flight does not take task key `key` (one of FIXED_TASK_KEYS)."""
    if key in ("random_obstacles", "random_layout"):
        return ("a flight flies the layout file's own walls and obstacles, none drawn at random (put virtual "
                "obstacles in the layout file)")
    return "it is set by the flight file itself (drones, layout, flight_height, decision_rate)"


def _not_a_task_key(text: str, path: Sequence[str], source: str) -> str | None:
    """Why `--set text` (key path `path`) is no task key of the flight, when it is a key of the
    flight file itself (its sections, `max_time` ...), one of its safety limits or a task key
    written with the `task.` prefix of a train config; else None (the task config judges it)."""
    key = path[0]
    if key in TASK_FIELDS:
        return None
    if key == "task" and len(path) > 1:
        return f"fly's --set takes the task's keys themselves: --set {text.split('.', 1)[1]}"
    where = f"set it in {source}"
    if key in SAFETY_FIELDS:
        return f"'{key}' is a safety limit of the flight file (safety: {key}), not a task key: --set changes the flight's task keys only; {where}"
    if key in FLIGHT_FIELDS:
        what = "a section" if key in ("safety", "transform", "lab", "drones") else "a key"
        extra = ""
        if key == "max_time" and len(path) == 1:
            extra = f"; --max-time {text.split('=', 1)[1]} ends the chase after {text.split('=', 1)[1]} s"
        return f"'{key}' is {what} of the flight file, not a task key: --set changes the flight's task keys only; {where}{extra}"
    return None


@dataclasses.dataclass(frozen=True)
class FlightDrone:
    """One drone of a plan: label, link, role, start spot (m, lab) and heading there (rad)."""

    name: str
    uri: str
    role: str
    start: tuple[float, float]
    start_yaw: float


@dataclasses.dataclass(frozen=True)
class FlightPlan:
    """A validated flight: drones in state order, task, layout, frames and limits; warnings:
    sentences about what can work but is risky (module docstring), each naming the key."""

    spec: FlightSpec
    task: TaskConfig
    layout: Layout
    transform: LabTransform
    lab: LabBounds
    drones: tuple[FlightDrone, ...]
    warnings: tuple[str, ...] = ()

    @property
    def safety(self):
        return self.spec.safety

    @property
    def n_drones(self) -> int:
        return len(self.drones)

    @property
    def n_pursuers(self) -> int:
        return self.task.n_pursuers

    @property
    def n_evaders(self) -> int:
        return self.task.n_evaders

    @property
    def names(self) -> list[str]:
        return [d.name for d in self.drones]

    @property
    def uris(self) -> list[str]:
        return [d.uri for d in self.drones]

    @property
    def dt(self) -> float:
        """Decision interval (s)."""
        return self.task.control_dt

    @property
    def height(self) -> float:
        """Flight height above the lab floor (m)."""
        return self.spec.flight_height

    @property
    def obs_spec(self) -> ObsSpec:
        return ObsSpec.make(self.task.n_pursuers, self.task.n_evaders, self.task.n_rays)

    @property
    def roles(self) -> np.ndarray:
        """(D,) str: each drone's role."""
        return np.array([d.role for d in self.drones])

    @property
    def flown_evaders(self) -> np.ndarray:
        """(M,) bool: evaders flown by the escape model (targets are only tracked)."""
        return self.roles[self.n_pursuers :] == "evader"

    @property
    def commanded(self) -> np.ndarray:
        """(D,) bool: drones this flight sends velocity commands to (pursuers and evaders, not targets)."""
        return self.roles != "target"

    @property
    def fastest_command(self) -> float:
        """m/s (lab): the fastest horizontal command of the flight: the task speed of each
        flown role (targets are flown by someone else) in the lab, at most safety.max_speed."""
        speeds = [self.task.pursuer_speed] + ([self.task.evader_speed] if self.flown_evaders.any() else [])
        return min(self.safety.max_speed, max(speeds) / self.transform.scale)

    @property
    def braking_distance(self) -> float:
        """m (lab): how far a drone at the fastest command goes before a stop takes effect:
        up to one decision interval until the command is sent, then `response_time` to follow it."""
        return self.fastest_command * (self.dt + self.safety.response_time)

    @property
    def frames(self) -> DroneFrames:
        """Where each drone's estimate frame sits in the lab (flow deck: at its start)."""
        D = self.n_drones
        if self.spec.positioning != "flow":
            return DroneFrames(np.zeros((D, 2)), np.zeros(D))
        return DroneFrames(np.array([d.start for d in self.drones], np.float64), np.array([d.start_yaw for d in self.drones]))

    def with_uris(self, uris: Sequence[str]) -> "FlightPlan":
        """The same flight over other links (e.g. virtual Crazyflies); uris in plan order."""
        if len(uris) != self.n_drones:
            raise ValueError(f"with_uris: expected {self.n_drones} URIs, got {len(uris)}")
        drones = tuple(dataclasses.replace(d, uri=check_uri(u, f"link for {d.name}")) for d, u in zip(self.drones, uris))
        return dataclasses.replace(self, drones=drones)


def resolve_layout(spec: FlightSpec) -> Layout:
    """The flight's layout (a built-in index, a file beside the flight file or as given); ConfigError naming the key."""
    ref = found_layout_ref(spec.layout, spec.source, "layout")
    try:
        return load_layout(ref)
    except ConfigError as exc:
        raise ConfigError(f"{spec.source}: key 'layout': {exc}") from None


def check_task_overrides(spec: FlightSpec, overrides: Sequence[str]) -> None:
    """The flight's task with `overrides` (--set), checked as resolve_flight checks it, without
    the transform or the drones' starts (fly align, which measures the transform): ConfigError
    naming the --set (or the file) of a bad one."""
    layout = resolve_layout(spec)
    _task_config(spec, spec.layout if isinstance(spec.layout, int) else layout.source, overrides)


def _task_config(spec: FlightSpec, layout_ref, overrides: Sequence[str]) -> TaskConfig:
    """Task keys of the flight file <- overrides <- the keys the flight fixes."""
    src = f"{spec.source}: task"
    for key in spec.task:
        if key in SIMULATION_ONLY_KEYS:
            raise ConfigError(f"{src}: key '{key}' means nothing in a flight: {SIMULATION_ONLY_KEYS[key]}")
        if key in FIXED_TASK_KEYS:
            raise ConfigError(f"{src}: key '{key}': {_why_fixed(key)}")
    task_keys = dict(spec.task)
    if isinstance(task_keys.get("evader"), dict) and "model" in task_keys["evader"]:  # FILE.py beside the flight file
        task_keys["evader"] = {**task_keys["evader"], "model": found_code_ref(task_keys["evader"]["model"], spec.source, "task.evader.model")}
    for text in overrides:
        path, value = parse_override(text, f"--set {text}")
        not_task = _not_a_task_key(text, path, spec.source)
        if not_task:
            raise ConfigError(f"--set {text}: {not_task}")
        if path[0] in SIMULATION_ONLY_KEYS:
            raise ConfigError(f"--set {text}: '{path[0]}' means nothing in a flight: {SIMULATION_ONLY_KEYS[path[0]]}")
        if path[0] in FIXED_TASK_KEYS:
            raise ConfigError(f"--set {text}: '{path[0]}': {_why_fixed(path[0])}")
    # as every task command: a --set mapping updates its section, and a later --set may complete an earlier one
    check_values(TaskConfig, task_keys, src)
    values = to_dict(load(TaskConfig, (), overrides, base=task_keys, base_source=src))
    roles = [d.role for d in spec.drones]
    values.update(
        n_pursuers=roles.count("pursuer"),
        n_evaders=len(roles) - roles.count("pursuer"),
        layout=layout_ref,
        flight_height=spec.flight_height,
        random_obstacles=0,
        random_layout=False,
    )
    if spec.decision_rate is not None:
        values["control_dt"] = 1.0 / spec.decision_rate
    # simulator stepping does not apply to a flight; keep it consistent with any decision rate
    substeps = max(1, round(values["control_dt"] / 0.002))
    values["physics_dt"] = values["control_dt"] / substeps
    values["controller_hz"] = 1.0 / values["physics_dt"]
    task = build(TaskConfig, values, src)
    if is_file_reference(task.evader.model):  # made once now: a bad file is refused before any drone connects
        make_evader_model(task, 1, 0, f"{src}: evader.model")
    return task


def _arena_corners(layout: Layout) -> np.ndarray:
    return np.array([[0.0, 0.0], [layout.width, 0.0], [layout.width, layout.height], [0.0, layout.height]])


def _lab_bounds(spec: FlightSpec, transform: LabTransform, layout: Layout) -> LabBounds:
    """The given lab bounds, checked to contain the arena; else the arena's bounding box."""
    corners = transform.to_lab(_arena_corners(layout))
    lo, hi = corners.min(0), corners.max(0)
    if spec.lab is None:
        return LabBounds((float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1])))
    lab = spec.lab
    tol = 1e-6
    if lo[0] < lab.x[0] - tol or hi[0] > lab.x[1] + tol or lo[1] < lab.y[0] - tol or hi[1] > lab.y[1] + tol:
        raise ConfigError(
            f"{spec.source}: key 'transform': the {layout.width} x {layout.height} m arena maps to lab x "
            f"[{lo[0]:.4g}, {hi[0]:.4g}], y [{lo[1]:.4g}, {hi[1]:.4g}] m, which leaves the lab "
            f"(lab: x {list(lab.x)}, y {list(lab.y)}): check origin, yaw and scale"
        )
    return lab


def _check_margin(spec: FlightSpec, task: TaskConfig, transform: LabTransform) -> None:
    """Refuse a geofence margin of zero or below the task's obstacle clearance (in the lab):
    the fence would hold drones where the simulator counts a collision, and with no margin
    on the surface of virtual obstacles, where entering one at any depth lands everyone."""
    margin = spec.safety.geofence_margin
    floor = task.obstacle_clearance / transform.scale
    where = f"{spec.source}: safety: key 'geofence_margin'"
    if margin <= 0.0:
        raise ConfigError(f"{where}: {margin:g} m leaves the fence no room: it would hold drones with their centre on the "
                          f"arena border and on the virtual obstacles, where entering one at any depth lands everyone "
                          f"(use at least the task's obstacle_clearance, {floor:.3f} m in the lab)")
    if margin < floor - 1e-9:
        raise ConfigError(f"{where}: {margin:g} m is below the task's obstacle_clearance {task.obstacle_clearance:g} m "
                          f"({floor:.3f} m in the lab, scale {transform.scale:g}): the fence would hold drones where "
                          f"the simulator counts a collision with a wall or obstacle")


def _check_passages(spec: FlightSpec, plan: FlightPlan) -> list[str]:
    """Refuse a geofence margin that leaves an evader no way to any pursuer: the fence keeps
    every commanded drone `geofence_margin` (lab m; times the scale in the layout) from the
    border and every virtual obstacle, so a passage narrower than twice that is closed to them,
    and an evader beyond closed passages can never be caught. A target so placed is a warning
    (returned): someone else flies it, and may fly it out. The free space is the layout's
    reachability grid (layout_check) at that clearance; a drone starting inside the margin
    counts in the free space nearest it, where the fence pushes it."""
    layout, keep = plan.layout, spec.safety.geofence_margin * plan.transform.scale
    margin = f"safety.geofence_margin {spec.safety.geofence_margin:g} m ({keep:g} layout m at scale {plan.transform.scale:g})"
    step = grid_step(layout, keep)
    xs, ys = np.arange(step / 2, layout.width, step), np.arange(step / 2, layout.height, step)
    free = free_cells(layout, xs, ys, keep)
    where = f"{spec.source}: safety: key 'geofence_margin'"
    if not free.any():
        raise ConfigError(f"{where}: {margin} from every wall, obstacle and the border leaves no room at all in the arena of {layout.source}")
    label = grid_components(free)
    cells = np.argwhere(free)  # (F, 2) grid indices
    centres = np.column_stack([xs[cells[:, 0]], ys[cells[:, 1]]])
    starts = plan.transform.to_layout(np.array([d.start for d in plan.drones], np.float64))
    nearest = np.argmin(np.linalg.norm(starts[:, None] - centres[None], axis=-1), axis=1)
    region = label[cells[nearest, 0], cells[nearest, 1]]  # (D,) the free space each drone starts in
    N = plan.n_pursuers
    warnings = []
    for k in range(N, plan.n_drones):
        if region[k] in region[:N]:
            continue
        d = plan.drones[k]
        why = (f"{margin} closes every passage between {d.role} {d.name} and the pursuers ({', '.join(plan.names[:N])}) in "
               f"{layout.source}: the fence keeps them that far from walls, obstacles and the border, so a passage needs "
               f"{2 * keep:g} layout m")
        if d.role == "target":
            warnings.append(f"{why}; the pursuers reach target {d.name} only if it is flown out to them")
            continue
        raise ConfigError(f"{where}: {why}, and {d.name} could never be caught (lower the margin, or start the drones on one side)")
    return warnings


def _margin_warnings(plan: FlightPlan) -> list[str]:
    """A margin shorter than the braking distance at the fastest command; task speeds above the safety
    limit; a separation guard that lets pursuers closer than the simulator's teammate_clearance."""
    s, t = plan.safety, plan.transform
    out = []
    if s.geofence_margin < plan.braking_distance - 1e-9:
        out.append(
            f"safety.geofence_margin {s.geofence_margin:g} m is shorter than the braking distance "
            f"{plan.braking_distance:.3f} m of a drone at {plan.fastest_command:g} m/s (one decision interval "
            f"{plan.dt:g} s + response_time {s.response_time:g} s): the fence relies on its prediction alone, "
            f"and a drone that responds slower than that crosses the border or a virtual obstacle before it stops "
            f"(raise the margin or lower safety.max_speed)"
        )
    if s.lookahead < plan.dt - 1e-9:
        out.append(f"safety.lookahead {s.lookahead:g} s is shorter than one decision interval {plan.dt:g} s: near the "
                   f"margin or a teammate a drone overshoots the guards' limit and is pushed back the next decision "
                   f"(use at least {plan.dt:g} s for a smooth approach)")
    flown = [("pursuers", "pursuer", plan.task.pursuer_speed)]
    if plan.flown_evaders.any():  # targets are flown by someone else, at their own speed
        flown.append(("evaders", "evader", plan.task.evader_speed))
    for who, key, speed in flown:
        lab_speed = speed / t.scale
        if lab_speed > s.max_speed + 1e-9:
            out.append(f"the {who}' task speed {speed:g} m/s is {lab_speed:g} m/s in the lab, above the safety "
                       f"limit {s.max_speed:g} m/s: they will fly slower than the policy expects (raise safety.max_speed "
                       f"or lower task.{key}_speed)")
    mates = plan.task.teammate_clearance / t.scale  # lab m: where the simulator counts two pursuers as collided
    capture = plan.task.capture_radius / t.scale  # lab m: min_separation must stay below it (_check_separation)
    if plan.n_pursuers > 1 and s.min_separation < mates - 1e-9:
        enough = math.ceil(mates * 1000 - 1e-6) / 1000  # mm, rounded up: the value advised clears the warning
        if enough < capture:
            fix = f"raise min_separation to {enough:.3f} m, below the capture distance {capture:.3f} m"
        else:  # no guard both keeps them that far apart and lets a capture happen
            fix = (f"no min_separation does, below the capture distance {capture:.3f} m: lower the task's "
                   f"teammate_clearance below its capture_radius {plan.task.capture_radius:g} m")
        out.append(f"safety.min_separation {s.min_separation:g} m is below the task's teammate_clearance "
                   f"{plan.task.teammate_clearance:g} m ({mates:.3f} m in the lab, scale {t.scale:g}): the separation guard "
                   f"lets two pursuers come closer than the simulator lets them, where it counts a collision ({fix})")
    return out


def _check_starts(spec: FlightSpec, plan_drones: Sequence[FlightDrone], plan: FlightPlan) -> list[str]:
    """Every start inside the lab and the arena, outside virtual obstacles, and far enough
    apart (else ConfigError); returns warnings for starts inside the geofence margin."""
    starts = np.array([d.start for d in plan_drones], np.float64)
    lab = plan.lab
    for d, p in zip(plan_drones, starts):  # before any arithmetic on them: a start of 1e308 overflows it
        if not (lab.x[0] <= p[0] <= lab.x[1] and lab.y[0] <= p[1] <= lab.y[1]):
            raise ConfigError(f"{spec.source}: drone {d.name} ({d.uri}): key 'start': {p.tolist()} is outside the lab "
                              f"(x {list(lab.x)}, y {list(lab.y)})")
    margin = spec.safety.geofence_margin
    layout_xy = plan.transform.to_layout(starts)
    inside = inside_boundary(plan.layout, layout_xy)
    gap = obstacle_distance(layout_xy, plan.layout.obstacle_set(), with_border=False) / plan.transform.scale
    to_border = border_distance(layout_xy, plan.layout.border()) / plan.transform.scale
    touching = plan.task.obstacle_clearance / plan.transform.scale  # what the simulator counts as a collision (lab m)
    warnings = []
    for d, p, q, ok, g, b in zip(plan_drones, starts, layout_xy, inside, gap, to_border):
        where = f"{spec.source}: drone {d.name} ({d.uri}): key 'start'"
        if not ok:
            raise ConfigError(f"{where}: lab {p.tolist()} is layout [{q[0]:.3f}, {q[1]:.3f}], outside the arena of {plan.layout.source}")
        if g < touching:
            raise ConfigError(f"{where}: lab {p.tolist()} is layout [{q[0]:.3f}, {q[1]:.3f}], inside or touching a virtual obstacle of {plan.layout.source}")
        if b < touching:
            raise ConfigError(f"{where}: lab {p.tolist()} is {b:.3f} m from the border of the arena of {plan.layout.source}, "
                              f"closer than the task's obstacle_clearance ({touching:.3f} m in the lab): on or touching it")
        if d.role == "target":
            continue  # flown by someone else: the fence does not steer it
        near = [(what, dist) for what, dist in (("the arena border", b), ("a virtual obstacle", g)) if dist < margin - 1e-9]
        if near:
            what, dist = min(near, key=lambda n: n[1])
            warnings.append(f"drone {d.name}: start {p.tolist()} is {dist:.3f} m from {what}, inside safety.geofence_margin "
                            f"{margin:g} m: the fence pushes it out as the chase begins, before the policy steers it")
    if len(starts) > 1:
        d = np.linalg.norm(starts[:, None] - starts[None], axis=-1) + np.eye(len(starts)) * 1e9
        i, j = np.unravel_index(np.argmin(d), d.shape)
        if d[i, j] < spec.safety.min_separation:
            raise ConfigError(
                f"{spec.source}: drones {plan_drones[i].name} and {plan_drones[j].name} start {d[i, j]:.3f} m apart, "
                f"closer than safety.min_separation {spec.safety.min_separation} m"
            )
        capture_lab = plan.task.capture_radius / plan.transform.scale
        chasers = [k for k, dr in enumerate(plan_drones) if dr.role == "pursuer"]
        for k in (k for k, dr in enumerate(plan_drones) if dr.role != "pursuer"):
            c = min(chasers, key=lambda c: d[c, k], default=None)
            if c is not None and d[c, k] <= capture_lab:
                raise ConfigError(
                    f"{spec.source}: {plan_drones[k].role} {plan_drones[k].name} starts {d[c, k]:.3f} m from pursuer "
                    f"{plan_drones[c].name}, within the capture distance {capture_lab:.3f} m (task capture_radius "
                    f"{plan.task.capture_radius} / scale {plan.transform.scale}): the chase would end before it began"
                )
    return warnings


def resolve_flight(spec: FlightSpec, overrides: Sequence[str] = ()) -> FlightPlan:
    """Check a flight against its layout and task; raises ConfigError naming the file and key."""
    layout = resolve_layout(spec)
    layout_ref = spec.layout if isinstance(spec.layout, int) else layout.source
    task = _task_config(spec, layout_ref, overrides)
    t = spec.transform
    transform = LabTransform(t.origin, t.yaw, t.scale)
    names = drone_names(spec)
    order = [i for i, d in enumerate(spec.drones) if d.role == "pursuer"] + [i for i, d in enumerate(spec.drones) if d.role != "pursuer"]
    drones = tuple(
        FlightDrone(names[i], spec.drones[i].uri, spec.drones[i].role, spec.drones[i].start, spec.drones[i].start_yaw) for i in order
    )
    capture_lab = task.capture_radius / transform.scale
    if spec.safety.min_separation >= capture_lab:
        raise ConfigError(
            f"{spec.source}: safety.min_separation {spec.safety.min_separation} m is not below the capture distance "
            f"{capture_lab:.3f} m (task capture_radius {task.capture_radius} / scale {transform.scale}): no capture could happen"
        )
    _check_margin(spec, task, transform)
    if spec.safety.lookahead < task.control_dt / 2 - 1e-9:
        raise ConfigError(
            f"{spec.source}: safety: key 'lookahead': {spec.safety.lookahead:g} s is shorter than half a decision interval "
            f"({task.control_dt / 2:g} s of {task.control_dt:g} s): each decision the guards would let a drone cover over twice its way to the margin, "
            f"so it would overshoot by more than it corrected and swing ever wider (at least {task.control_dt / 2:g} s; under {task.control_dt:g} s, one interval, the plan warns)"
        )
    lab = _lab_bounds(spec, transform, layout)
    plan = FlightPlan(spec, task, layout, transform, lab, drones)
    warnings = _margin_warnings(plan) + _check_starts(spec, drones, plan)
    warnings += _check_passages(spec, plan)  # after the starts: each lies in the arena, clear of the obstacles
    return dataclasses.replace(plan, warnings=tuple(warnings))


def load_plan(path: str | Path, overrides: Sequence[str] = ()) -> FlightPlan:
    """Read, validate and resolve a flight file."""
    from .spec import load_flight

    return resolve_flight(load_flight(path), overrides)
