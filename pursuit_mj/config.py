"""The task config: every setting of DESIGN.md section 1, plus physics and evader settings.

One frozen dataclass; YAML files under configs/task/ and command-line overrides go through
`load_task_config`. SI units throughout (m, s, rad, N).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from .configio import ConfigError, build, dump_yaml, found_beside, key_where, load, load_yaml, spec, to_dict
from .file_kinds import refuse_another_kind
from .layout import MAX_RANDOM_OBSTACLES, N_BUILTIN, found_layout_ref

from .shipped import shipped_dir
from .user_file import is_file_reference, split_reference

BUILTIN_EVADER = "janosov"  # evader.model of the built-in escape model (pursuit_mj/evader.py)

CONFIG_DIR = shipped_dir("configs")
#: m between two drone centres when their collision cylinders touch (2 x the 0.0685 m radius
#: of the "collision" geom in models/crazyflie.xml; a test checks the two agree)
DRONE_CONTACT_DISTANCE = 2 * 0.0685
#: kg, the take-off mass of models/crazyflie.xml (a bare Crazyflie 2.1; a test checks the two agree)
DRONE_FILE_MASS = 0.027
DRONE_MIN_MASS = 0.01  # kg: well under the bare Crazyflie 2.1 (0.027); a tiny mass made every quadrotor episode diverge
#: N, the thrust of all four rotors at their limit in models/crazyflie.xml (4 x 0.15 N; a test checks)
DRONE_MAX_THRUST = 4 * 0.15
#: the least thrust-to-weight ratio accepted: the rotors must lift this many times the drone's
#: weight (see TaskConfig.validate for why)
MIN_THRUST_TO_WEIGHT = 1.5
#: kg, the heaviest drone_mass accepted: DRONE_MAX_THRUST / (g MIN_THRUST_TO_WEIGHT)
DRONE_MAX_MASS = DRONE_MAX_THRUST / (9.81 * MIN_THRUST_TO_WEIGHT)
#: DRONE_MAX_MASS as messages write it: rounded down, so that the mass named is accepted (0.0408 is not)
DRONE_MAX_MASS_TEXT = f"{math.floor(DRONE_MAX_MASS * 1e5) / 1e5:.5f}"
#: m, the largest distance setting: twice the largest arena (layout.MAX_ARENA_SIDE); far more is a
#: unit slip (the reference study's perception radius of 2000 was in mm)
MAX_DISTANCE = 100.0
# every reward scale's magnitude limit: rewards are float32, and an episode's sum of steps of
# the largest terms must stay finite and far from overflow
REWARD_SCALE_LIMIT = 1e6


@dataclasses.dataclass(frozen=True)
class EvaderConfig:
    """Escape model after Janosov et al. 2017 (pursuit_mj/evader.py); distances in m, times in s.
    `model` may name a model of one's own instead (pursuit_mj/evader_models.py), which the other
    keys do not tune."""

    model: str = spec("janosov", help="what flies the evaders: janosov (the escape model these keys tune) or FILE.py:NAME, "
                                      "NAME(config, n_worlds, seed) from FILE giving a model with reset and compute "
                                      "(docs/env_api.md, \"Evaders of your own\")")
    panic_distance: float = spec(1.5, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="chaser distance at which panic is full (m)")
    calm_distance: float = spec(3.0, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="chaser distance beyond which the evader is calm (m)")
    sense_radius: float = spec(4.0, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="how far the evader senses chasers (m)")
    lead_time: float = spec(0.3, lo=0.0, hi=2.0, help="how far ahead the evader extrapolates chasers' motion when fleeing (s)")
    zigzag_rate: float = spec(1.0, lo=0.0, help="rate of random heading changes when calm (1/s)")
    zigzag_angle: float = spec(0.8, lo=0.0, hi=math.pi, help="amplitude of random heading changes (rad)")
    room_weight: float = spec(1.0, lo=0.0, help="preference for directions with free room (up to 1 m) over the wanted one")
    safety_weight: float = spec(1.0, lo=0.0, help="preference for directions that stay out of the chasers' reach over fleeing straight")
    wall_margin: float = spec(0.45, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="distance from walls and obstacles at which repulsion starts (m)")
    wall_gain: float = spec(1.5, lo=0.0, help="weight of wall repulsion against fleeing")
    follow_distance: float = spec(0.8, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="an obstacle closer than this ahead turns the evader along it (m)")
    gap_escape: bool = spec(True, help="slip between two closing chasers when it can get there first")
    gap_margin: float = spec(0.1, lo=0.0, hi=MAX_DISTANCE, help="clearance beyond capture_radius it keeps from chasers while slipping through (m)")
    clearance: float = spec(0.15, lo=0.07, hi=1.0, help="half-width of the look-ahead corridor; closest approach to obstacles it plans for (m)")
    lookahead_time: float = spec(0.5, lo=0.0, hi=5.0, help="seconds of flight the corridor ahead must be free for")
    evader_spacing: float = spec(0.6, lo=0.0, hi=MAX_DISTANCE, help="distance below which evaders push each other apart (m)")
    evader_gain: float = spec(0.4, lo=0.0, help="weight of the push between evaders")
    smoothing: float = spec(0.25, lo=0.0, hi=0.9, help="weight of the previous heading in each new heading")

    def validate(self, source: str = "config") -> None:
        """Cross-field checks; raises ConfigError naming the offending keys."""
        if self.model != BUILTIN_EVADER and not is_file_reference(self.model):
            raise ConfigError(f"{key_where(source, 'model')}: {self.model!r} is neither {BUILTIN_EVADER} (the built-in "
                              f"escape model) nor FILE.py:NAME (a model of your own from a Python file)")
        if self.calm_distance <= self.panic_distance:
            raise ConfigError(
                f"{source}: evader.calm_distance {self.calm_distance} must exceed evader.panic_distance "
                f"{self.panic_distance} (panic rises from calm_distance down to panic_distance)"
            )


#: perception keys that full observability never reads (sensing.perceive knows every entity exactly there)
FULL_OBSERVABILITY_IDLE = ("perception_radius", "field_of_view", "share_detections", "share_teammates",
                           "position_noise", "miss_probability")


def _setting_text(key: str, value) -> str:
    """A task value as a note shows it: the field of view in degrees (stored in rad), numbers short."""
    if key == "field_of_view":
        return f"{math.degrees(value):.4g} deg"
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """Everything that defines one pursuit task. Defaults reproduce the reference study."""

    n_pursuers: int = spec(3, lo=1, hi=16, help="number of pursuers")
    n_evaders: int = spec(1, lo=1, hi=8, help="number of evaders")
    pursuer_speed: float = spec(0.3, lo=0.0, lo_open=True, hi=3.0, help="pursuer max speed (m/s)")
    evader_speed: float = spec(0.6, lo=0.0, lo_open=True, hi=3.0, help="evader speed (m/s); above 0.9 it brakes near walls and obstacles (pursuit_mj/evader.py, step 7)")
    perception_radius: float = spec(2.0, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="pursuer perception radius (m)")
    field_of_view: float = spec(2 * math.pi, lo=0.0, lo_open=True, hi=2 * math.pi, help="pursuer field of view (rad)")
    capture_radius: float = spec(0.3, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="capture distance pursuer-evader (m)")
    obstacle_clearance: float = spec(0.1, lo=0.0, hi=MAX_DISTANCE, help="collision if a pursuer centre comes closer to an obstacle (m)")
    teammate_clearance: float = spec(0.2, lo=0.0, hi=MAX_DISTANCE, help="collision if two pursuer centres come closer (m)")
    control_dt: float = spec(0.1, lo=0.0, lo_open=True, hi=1.0, help="decision interval (s)")
    max_steps: int = spec(1000, lo=1, hi=100_000, help="decision steps before timeout")
    flight_height: float = spec(0.5, lo=0.1, hi=3.0, help="altitude the drones hold (m)")
    layout: int | str = spec(0, help="built-in layout index 0-3 or a layout file path")
    random_obstacles: int | None = spec(None, lo=0, hi=MAX_RANDOM_OBSTACLES, help="random obstacles added per episode; null: each layout's own random_obstacles.count (5 in the built-in layouts)")
    random_layout: bool = spec(False, help="draw a random built-in layout per episode")
    observability: str = spec("partial", choices=("partial", "full"), help="partial or full observability")
    share_detections: bool = spec(True, help="an evader seen by one pursuer is known to all (relayed)")
    share_teammates: bool = spec(False, help="pursuers broadcast their own positions: every teammate is known exactly, whatever the radius, view and walls")
    n_rays: int = spec(16, lo=0, hi=128, help="range readings around each pursuer")
    ray_range: float = spec(2.0, lo=0.0, lo_open=True, hi=MAX_DISTANCE, help="max range of the range readings (m)")
    position_noise: float = spec(0.0, lo=0.0, hi=1.0, help="std of noise on perceived positions (m)")
    miss_probability: float = spec(0.0, lo=0.0, hi=1.0, help="chance a visible evader is missed per step")
    capture_reward: float = spec(10.0, lo=0.0, hi=REWARD_SCALE_LIMIT, help="team reward per captured evader (>= 0)")
    progress_reward: float = spec(1.0, lo=-REWARD_SCALE_LIMIT, hi=REWARD_SCALE_LIMIT, help="scale of (d_prev - d)/0.3 toward the nearest free evader")
    collision_penalty: float = spec(-10.0, lo=-REWARD_SCALE_LIMIT, hi=0.0, help="reward on collision (<= 0)")
    proximity_penalty: float = spec(-0.1, lo=-REWARD_SCALE_LIMIT, hi=0.0, help="soft penalty scale near walls/teammates (<= 0)")
    proximity_distance: float = spec(0.3, lo=0.0, hi=MAX_DISTANCE, help="width of the soft zone beyond obstacle_clearance and teammate_clearance (centre distances) in which the proximity penalty grows from 0 to proximity_penalty (m)")
    spread_reward: float = spec(0.0, lo=-REWARD_SCALE_LIMIT, hi=REWARD_SCALE_LIMIT, help="reward for spreading out (more_r); 0 = off")
    fidelity: str = spec("quadrotor", choices=("point", "quadrotor"), help="physics fidelity")
    physics_dt: float = spec(0.002, lo=0.0002, hi=0.01, help="MuJoCo timestep (s)")
    command_latency: float = spec(0.0, lo=0.0, hi=1.0, help="s from a pursuer's velocity command to its taking effect, as in real flights (motion capture, policy, radio; measure your own loop); a whole number of controller ticks (1/controller_hz); the evaders' commands are not delayed; 0: none")
    controller_hz: float = spec(100.0, lo=100.0, hi=1000.0, help="quadrotor controller rate (Hz); at 50 Hz a full-speed reversal tilted to 22 deg, past the 15 deg limit")
    drone_mass: float = spec(DRONE_FILE_MASS, lo=DRONE_MIN_MASS, help=f"every drone's take-off mass (kg): the quadrotor's body (inertia scaled with it) and its controller's weight feed-forward; default the bare Crazyflie 2.1 of models/crazyflie.xml; set it to your drones' weighed mass (with decks, markers, battery); at least {DRONE_MIN_MASS:g} kg (lighter is no Crazyflie-scale airframe, and far lighter ones make the quadrotor simulation diverge: docs/DESIGN.md); at most {DRONE_MAX_MASS_TEXT} kg, where the rotors lift {MIN_THRUST_TO_WEIGHT:g} times the weight")
    evader: EvaderConfig = spec(default_factory=EvaderConfig, help="escape model settings")

    def idle_settings(self, prefix: str = "") -> list[str]:
        """Settings changed from their defaults that this combination never reads, one line each, keys
        written with `prefix` (a train config's "task."): the perception keys under full observability,
        where every entity is known exactly (sensing.perceive), and drone_mass under point fidelity.
        Not errors: a preset (hard) sets perception keys that a full-observability run keeps."""
        default, idle = TaskConfig(), []
        if self.observability == "full":
            changed = [k for k in FULL_OBSERVABILITY_IDLE if getattr(self, k) != getattr(default, k)]
            if changed:
                shown = ", ".join(f"{prefix}{k} {_setting_text(k, getattr(self, k))}" for k in changed)
                verb = "does" if len(changed) == 1 else "do"
                idle.append(f"{shown} {verb} nothing under {prefix}observability full (every evader and teammate is "
                            "known exactly)")
        if self.fidelity == "point" and self.drone_mass != default.drone_mass:
            idle.append(f"{prefix}drone_mass {self.drone_mass:g} does nothing under {prefix}fidelity point (the point "
                        "model's response does not follow the mass; quadrotor fidelity flies it)")
        return idle

    def validate(self, source: str = "config") -> None:
        """Cross-field checks; raises ConfigError naming the offending keys."""
        if self.perception_radius < self.capture_radius:
            raise ConfigError(
                f"{source}: perception_radius {self.perception_radius} is below capture_radius "
                f"{self.capture_radius}: a pursuer could capture what it cannot see"
            )
        if self.capture_radius <= DRONE_CONTACT_DISTANCE:
            raise ConfigError(
                f"{source}: capture_radius {self.capture_radius} m is not beyond {DRONE_CONTACT_DISTANCE:g} m, where two "
                f"drones' collision volumes touch: every capture would be a collision")
        from .layout_check import SPAWN_CLEARANCE, SPAWN_SEPARATION

        for key, value, room, what in (("obstacle_clearance", self.obstacle_clearance, SPAWN_CLEARANCE, "from walls"),
                                       ("teammate_clearance", self.teammate_clearance, SPAWN_SEPARATION, "apart")):
            if value >= room:
                raise ConfigError(f"{key_where(source, key)}: {value} m is not below the {room} m that drones spawn "
                                  f"{what}: episodes would end in a collision before any action")
        if isinstance(self.layout, int) and not 0 <= self.layout < N_BUILTIN:
            raise ConfigError(f"{key_where(source, 'layout')}: {self.layout} is not a built-in layout index "
                              f"(0-{N_BUILTIN - 1}) or a file")
        # an index other than the default 0 would be ignored too (it only changed a table's episode seeds)
        if self.random_layout and (not isinstance(self.layout, int) or self.layout != 0):
            raise ConfigError(f"{key_where(source, 'random_layout')} draws each episode's layout from the built-in 0-"
                              f"{N_BUILTIN - 1}, so layout {self.layout} would be ignored: set one or the other")
        if self.drone_mass > DRONE_MAX_MASS:
            raise ConfigError(
                f"{key_where(source, 'drone_mass')}: {self.drone_mass} kg is more than the rotors can fly: their "
                f"{DRONE_MAX_THRUST:g} N at full thrust must lift at least {MIN_THRUST_TO_WEIGHT:g} times the "
                f"weight (at most {DRONE_MAX_MASS_TEXT} kg), keeping thrust in reserve to tilt, climb back and "
                f"turn at once")
        substeps = self.control_dt / self.physics_dt
        if round(substeps) < 1:  # 1e-9 s is "a whole number" (0) of physics steps within the tolerance below
            raise ConfigError(
                f"{source}: control_dt {self.control_dt} is shorter than physics_dt {self.physics_dt}: "
                f"a decision step would advance no physics"
            )
        if abs(substeps - round(substeps)) > 1e-6:
            raise ConfigError(
                f"{source}: control_dt {self.control_dt} is not a whole number of physics_dt {self.physics_dt}"
            )
        per_ctrl = 1.0 / (self.controller_hz * self.physics_dt)
        if abs(per_ctrl - round(per_ctrl)) > 1e-6 or round(per_ctrl) < 1:
            raise ConfigError(
                f"{source}: controller_hz {self.controller_hz} does not divide the physics rate "
                f"{1.0 / self.physics_dt:g} Hz into whole substeps"
            )
        if round(substeps) % round(per_ctrl) != 0:
            raise ConfigError(
                f"{source}: control_dt {self.control_dt} is not a whole number of controller periods "
                f"(controller_hz {self.controller_hz})"
            )

        ticks = self.command_latency * self.controller_hz
        if abs(ticks - round(ticks)) > 1e-6:
            tick = 1.0 / self.controller_hz
            below, above = math.floor(ticks) * tick, math.ceil(ticks) * tick
            raise ConfigError(
                f"{key_where(source, 'command_latency')}: {self.command_latency:g} s is not a whole number of controller "
                f"ticks ({tick:g} s at controller_hz {self.controller_hz:g}); use {below:g} or {above:g}")

    def random_obstacle_count(self, layout) -> int:
        """Random obstacles drawn per episode in `layout` (a Layout): this config's count, else the layout's."""
        return layout.random_obstacles.count if self.random_obstacles is None else self.random_obstacles

    @property
    def n_drones(self) -> int:
        return self.n_pursuers + self.n_evaders

    @property
    def substeps(self) -> int:
        """Physics steps per decision step."""
        return int(round(self.control_dt / self.physics_dt))

    @property
    def command_latency_ticks(self) -> int:
        """Controller ticks from a pursuer's command to its taking effect."""
        return int(round(self.command_latency * self.controller_hz))

    @property
    def substeps_per_control(self) -> int:
        """Physics steps per quadrotor controller update."""
        return int(round(1.0 / (self.controller_hz * self.physics_dt)))


def preset_or_file(ref: str | Path, kind: str) -> Path:
    """The YAML file `ref` names: an existing path, or a bare name of a preset in configs/<kind>/.

    A reference that is neither is a ConfigError listing the presets there.
    """
    if not str(ref).strip():  # Path('') is the current folder: 'a folder, not a file' would puzzle
        raise ConfigError(f"{str(ref)!r}: empty; give a {kind} file or preset (presets: {', '.join(preset_names(kind))})")
    path = Path(ref)
    if path.is_file():
        return path
    bare = not (path.suffix or len(path.parts) > 1)
    preset = CONFIG_DIR / kind / f"{ref}.yaml"
    if bare and preset.is_file():  # a preset's name, even beside a folder of that name
        return preset
    if path.is_dir():
        raise ConfigError(f"{ref}: a folder, not a {kind} file")
    if not bare:
        raise ConfigError(f"{ref}: no such file")
    raise ConfigError(f"{ref}: no such file, nor a {kind} preset of that name (presets: {', '.join(preset_names(kind))})")


def preset_names(kind: str) -> list[str]:
    """Names of the presets in configs/<kind>/ ('task', 'train' or 'flight'), sorted."""
    return sorted(p.stem for p in (CONFIG_DIR / kind).glob("*.yaml"))


def load_task_yaml(path: str | Path, source: str | None = None) -> dict[str, Any]:
    """A task YAML file's mapping (configio.load_yaml), its `layout` found beside the file when it
    is not found from the current folder (layout.found_layout_ref: ConfigError if found nowhere).
    An empty file (or one of comments only) is a ConfigError."""
    data = load_yaml(path, source)
    if not data and not isinstance(data, (list, str)):  # a list or text is refused as not a mapping by the loader
        # an empty train config or layout file is refused too: a file cut to nothing ran the defaults without a word
        raise ConfigError(f"{source or path}: the file is empty (no task key); a task file sets at least one (see "
                          f"configs/task/*.yaml), and none at all means the defaults: leave the file out")
    refuse_another_kind(data, source or str(path), "task")
    if "layout" in data:
        data["layout"] = found_layout_ref(data["layout"], path, "layout")
    evader = data.get("evader")
    if isinstance(evader, dict) and "model" in evader:
        evader["model"] = found_code_ref(evader["model"], path, "evader.model")
    return data


def found_code_ref(ref: Any, file: str | Path, key: str) -> Any:
    """A FILE.py:NAME read from `key` of the config file `file`, its FILE found beside `file` when it
    is not found from the current folder (configio.found_beside); ConfigError naming `file` and
    `key` when it is found in neither place. Anything but FILE.py:NAME is returned as it is."""
    if not is_file_reference(ref):
        return ref  # refused with its key by the config's own checks
    path, name = split_reference(ref, key)
    found = found_beside(path, file)
    if not Path(found).is_file():
        folder, here = Path(file).parent, Path.cwd()
        beside = "" if folder.resolve() == here.resolve() else f" or beside {folder}"
        where = "" if Path(found).is_absolute() else f" in the current folder ({here}){beside}"
        raise ConfigError(f"{file}: key '{key}': file '{path}' (of {ref}): no such file{where}")
    return f"{found}:{name}"


def load_task_config(
    files: Sequence[str | Path] = (),
    overrides: Sequence[str] = (),
    flags: dict | None = None,
    flags_source: str = "command-line flag",
) -> TaskConfig:
    """Defaults <- YAML files (a bare name like 'hard' means configs/task/hard.yaml) <- flags <- --set.

    `files` and `overrides` are lists; a single string is taken as a list of one.
    `flags_source` names the flags in errors (a CLI passes what was typed, e.g. '--pursuers -2')."""
    files = [files] if isinstance(files, (str, Path)) else files
    overrides = [overrides] if isinstance(overrides, str) else overrides
    for what, given, kinds in (("files", files, (str, Path)), ("overrides", overrides, str)):
        if not isinstance(given, (list, tuple)) or not all(isinstance(g, kinds) for g in given):
            raise ConfigError(f"load_task_config {what}: expected a list of {'paths or preset names' if what == 'files' else 'KEY=VALUE texts'}, got {given!r}")
    resolved = [preset_or_file(f, "task") for f in files]
    return load(TaskConfig, resolved, overrides, extra=flags, extra_source=flags_source, read=load_task_yaml)


def default_config(**changes) -> TaskConfig:
    """The defaults, with keyword changes validated as if from a config file."""
    return build(TaskConfig, changes, "default_config()")


def checked_task_config(config, source: str) -> TaskConfig:
    """`config` with every value checked as if it came from a file (a TaskConfig made directly,
    or changed with dataclasses.replace, skips the checks); ConfigError names `source`."""
    if not isinstance(config, TaskConfig):
        raise ConfigError(f"{source}: expected a TaskConfig (pursuit_mj.config.default_config(...) or "
                          f"load_task_config(...)), got {type(config).__name__}")
    return build(TaskConfig, to_dict(config), source)


def task_config_from(value, source: str) -> TaskConfig:
    """A checked TaskConfig from a TaskConfig, a mapping of task keys (as a task YAML file holds
    them) or a task file path or preset name ('hard'); a mapping and a path as text are plain
    data, which a gymnasium spec can serialise (a pathlib.Path is not JSON). ConfigError names `source` and what was wrong."""
    if isinstance(value, TaskConfig):
        return checked_task_config(value, source)
    if isinstance(value, Mapping):
        return build(TaskConfig, dict(value), source)
    if isinstance(value, (str, Path)):
        try:
            return load_task_config([value])
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    raise ConfigError(f"{source}: expected a TaskConfig, task keys or a task file (a mapping such as "
                      f"{{'evader_speed': 0.3}}, or a path or preset name such as 'hard'), got {type(value).__name__}")


__all__ = ["EvaderConfig", "TaskConfig", "load_task_config", "checked_task_config", "task_config_from", "preset_or_file", "default_config", "dump_yaml", "ConfigError"]


#: task keys whose change between training and use a trained model's user is told of: what the
#: pursuers see (and what their observations mean), how fast everyone flies, how long an action lasts
TRAINED_TASK_KEYS = ("observability", "pursuer_speed", "evader_speed", "perception_radius", "field_of_view", "fidelity",
                     "n_pursuers", "n_evaders", "drone_mass", "command_latency", "control_dt", "ray_range",
                     "share_detections", "share_teammates", "position_noise", "miss_probability")
#: of those, the keys a real flight has no value of (its latency is the real loop's, its physics the
#: real world's: pursuit_mj.flight.plan.SIMULATION_ONLY_KEYS)
SIMULATION_ONLY_TRAINED_KEYS = ("command_latency", "fidelity")
#: what a run that continues a checkpoint is told of beside those: the episode's rules and its pay,
#: which the checkpoint's critic learned the values of
LEARNED_TASK_KEYS = TRAINED_TASK_KEYS + ("capture_radius", "obstacle_clearance", "teammate_clearance", "max_steps",
                                         "capture_reward", "progress_reward", "collision_penalty", "proximity_penalty",
                                         "proximity_distance", "spread_reward")


def task_differences(trained: Mapping[str, Any], task: TaskConfig, keys: Sequence[str]) -> list[tuple[str, str, str]]:
    """(key, value as trained, value in `task`) as text for each of `keys` whose value in the task dict
    `trained` (a checkpoint's, to_dict form) differs from `task`'s, in the order of `keys`, then
    evader.model if it names another model, else (both the built-in escape model) each evader.KEY
    tuning it that differs. A key `trained` lacks counts at its default (the code
    before the key existed did that); an empty `trained` (a checkpoint that stores no task) differs
    in nothing. The field of view shows in degrees."""
    if not trained:
        return []
    default = TaskConfig()
    trained = {**{k: getattr(default, k) for k in keys}, **trained}
    out = [(k, _trained_text(k, trained[k]), _trained_text(k, getattr(task, k))) for k in keys
           if trained[k] != getattr(task, k)]
    evader = trained.get("evader") if isinstance(trained.get("evader"), Mapping) else {}
    if "model" in evader and not _same_evader_model(evader["model"], task.evader.model):
        out.append(("evader.model", str(evader["model"]), str(task.evader.model)))
    elif task.evader.model == BUILTIN_EVADER and evader.get("model", BUILTIN_EVADER) == BUILTIN_EVADER:
        out += _escape_model_differences(evader, task.evader)
    return out


def _escape_model_differences(trained: Mapping[str, Any], now: EvaderConfig) -> list[tuple[str, str, str]]:
    """(evader.KEY, as trained, now) for each key tuning the built-in escape model on which the
    trained evader dict (to_dict form; a key it lacks at its default) and `now` differ."""
    default = EvaderConfig()
    out = []
    for f in dataclasses.fields(EvaderConfig):
        if f.name == "model":
            continue
        then = trained.get(f.name, getattr(default, f.name))
        if then != getattr(now, f.name):
            out.append((f"evader.{f.name}", str(then), str(getattr(now, f.name))))
    return out


def _trained_text(key: str, value) -> str:
    """A task value as a note shows it: the field of view in degrees (stored in rad)."""
    if key == "field_of_view" and isinstance(value, (int, float)):
        return f"{math.degrees(value):.4g} deg"
    return str(value)


def _same_evader_model(trained: str, now: str) -> bool:
    """Whether two evader.model values name one model: janosov, or FILE.py:NAME of one file
    (the trained one absolute, this task's perhaps relative to the current folder) and NAME."""
    if not (is_file_reference(trained) and is_file_reference(now)):
        return trained == now
    (a, name_a), (b, name_b) = split_reference(trained, "evader.model"), split_reference(now, "evader.model")
    return name_a == name_b and Path(a).resolve() == Path(b).resolve()
