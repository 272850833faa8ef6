"""The flight file (YAML): which drones fly, where, with what limits. Validated before any radio is touched.

```yaml
name: lab-3v1
layout: 0                    # built-in index or layout file; its obstacles are virtual
positioning: flow            # flow | lighthouse | loco
flight_height: 0.5           # m above the lab floor
decision_rate: 10            # Hz; default 1 / the task's control_dt
transform: {origin: [0.0, 0.0], yaw: 0.0, scale: 1.0}   # lab -> layout, see frames.py
lab: {x: [-0.5, 4.1], y: [-0.5, 5.5]}                   # optional: the physical flight space
drones:
  - {uri: radio://0/80/2M/E7E7E7E701, role: pursuer, start: [0.6, 0.5]}
  - {uri: radio://0/80/2M/E7E7E7E704, role: evader, start: [1.8, 4.5]}
safety: {max_speed: 0.5, geofence_margin: 0.2}         # any SafetyLimits key
task: {pursuer_speed: 0.3}                              # any TaskConfig key
```
Roles: `pursuer` (flown by the policy), `evader` (flown by the escape model), `target`
(an evader that is only tracked, flown by someone else). `start` is where the drone sits
before take-off, in lab coordinates (m), facing `start_yaw` (rad); flow-deck drones
measure from there. Errors name the file and the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from pathlib import Path
from typing import Any, Mapping

from ..config import DRONE_CONTACT_DISTANCE, preset_or_file
from ..configio import ConfigError, build, key_where, load_yaml, shown, spec
from ..file_kinds import refuse_another_kind
from .board import HISTORY

ROLES = ("pursuer", "evader", "target")
NAME = r"[\w\-]+"  # a drone name: what `--fault KIND:NAME@S` can address
POSITIONING = ("flow", "lighthouse", "loco")

LANDED_HEIGHT = 0.1  # m: a drone whose height estimate is below this is on the floor (counts as landed)
#: m: the farthest a lab bound may lie from the lab's origin. No flight space is this big, and the
#: starts, checked to lie inside the lab before anything is computed from them, stay far from float overflow
LAB_EXTENT = 1000.0
#: layout metres per lab metre a transform may have: a lab 20 times smaller or larger than the
#: arena is no flight anyone plans; a scale near 100 or 1000 (or 0.01, 0.001) is cm or mm read as m
SCALE_RANGE = (0.05, 20.0)

#: V: what a Crazyflie's one-cell LiPo reads at rest, empty to overfull: the range of the battery
#: limits and of a virtual battery fault (3100 there is millivolts)
BATTERY_VOLTS = (2.5, 4.4)

DATA_RATES = ("250K", "1M", "2M")  # spelled as cflib's radio driver compares them
DEFAULT_RADIO_ADDRESS = 0xE7E7E7E7E7  # what cflib uses for a radio URI without an address

_URI_PATTERNS = {
    # dongle: an index (fewer than 10 digits) or a 10-character serial, as cflib's radiodriver.parse_uri
    "radio": re.compile(r"^radio://(\d{1,9}|[0-9A-Fa-f]{10})/(\d{1,3})/(\w+)(?:/([0-9A-Fa-f]{1,10}))?(\?[\w=&]*)?$"),
    "udp": re.compile(r"^udp://([\w.\-]+):(\d{1,5})$"),
    "usb": re.compile(r"^usb://(\d+)$"),
    "tcp": re.compile(r"^tcp://([\w.\-]+):(\d{1,5})$"),
}


def check_uri(uri: str, where: str) -> str:
    """Return `uri` if cflib can open it (radio://, udp://, usb://, tcp://); else ConfigError naming `where`."""
    link_key(uri, where)
    return uri


def link_key(uri: str, where: str) -> tuple:
    """What `uri` reaches, as cflib parses it, so that two spellings of one link compare equal;
    ConfigError naming `where` if cflib cannot open it.

    radio: ("radio", channel, data rate, address): the channel as a number (080 is 80), the
    address as a number (any case, zero-padded as cflib pads it; none is 0xE7E7E7E7E7). The
    dongle is left out: one Crazyflie answers every dongle on its channel and address.
    udp/tcp: (scheme, host in lower case, port); usb: ("usb", index).
    """
    scheme = uri.split("://", 1)[0] if "://" in uri else ""
    pattern = _URI_PATTERNS.get(scheme)
    m = pattern.match(uri) if pattern else None
    if m is None:
        raise ConfigError(
            f"{where}: '{uri}' is not a Crazyflie URI (expected radio://0/80/2M/E7E7E7E7E7, "
            f"udp://127.0.0.1:19850, usb://0 or tcp://host:port)"
        )
    if scheme == "radio":
        channel, rate, address = int(m.group(2)), m.group(3), m.group(4)
        if channel > 125:
            raise ConfigError(f"{where}: '{uri}': radio channel {m.group(2)} is out of range (0-125)")
        if rate not in DATA_RATES:
            raise ConfigError(f"{where}: '{uri}': data rate '{rate}' is not one of {', '.join(DATA_RATES)}, written "
                              f"exactly so (cflib reads any other spelling, '2m' or '1m' too, as 2M)")
        return ("radio", channel, rate, int(address, 16) if address else DEFAULT_RADIO_ADDRESS)
    if scheme == "usb":
        return ("usb", int(m.group(1)))
    port = int(m.group(2))
    if not 1 <= port <= 65535:
        raise ConfigError(f"{where}: '{uri}': port {m.group(2)} is out of range (1-65535)")
    return (scheme, m.group(1).lower(), port)


def _describe_link(key: tuple) -> str:
    if key[0] == "radio":
        return f"channel {key[1]}, {key[2]}, address {key[3]:010X}"
    return ":".join(str(k) for k in key[1:])


@dataclasses.dataclass(frozen=True)
class DroneSpec:
    """One drone: radio URI, role, start spot (m, lab frame) and heading there (rad)."""

    uri: str = spec(help="cflib URI, e.g. radio://0/80/2M/E7E7E7E701 or udp://127.0.0.1:19850")
    role: str = spec(choices=ROLES, help="pursuer | evader (escape model) | target (only tracked)")
    start: tuple[float, float] = spec(help="take-off spot [x, y] in the lab frame (m)")
    start_yaw: float = spec(0.0, lo=-2 * math.pi, hi=2 * math.pi,
                            help="heading at the start spot in the lab frame (rad, not degrees); flow-deck estimates rotate by it")
    name: str = spec("", help="a label for logs; default role + index")

    def validate(self, source: str) -> None:
        check_uri(self.uri, key_where(source, 'uri'))
        if self.name and not re.fullmatch(NAME, self.name):
            raise ConfigError(f"{key_where(source, 'name')}: {self.name!r} is not a plain label (letters, digits, _ and -; "
                              f"no spaces): it names the drone in --fault KIND:NAME@S and in the records")


@dataclasses.dataclass(frozen=True)
class TransformSpec:
    """lab -> layout: layout = scale * R(-yaw) (lab - origin). See frames.py."""

    origin: tuple[float, float] = spec((0.0, 0.0), help="the layout's lower-left corner in lab coordinates (m)")
    yaw: float = spec(0.0, lo=-2 * math.pi, hi=2 * math.pi, help="angle of the layout's x axis in the lab frame (rad, not degrees; counter-clockwise)")
    scale: float = spec(1.0, lo=0.0, lo_open=True, help="layout metres per lab metre")

    def validate(self, source: str) -> None:
        lo, hi = SCALE_RANGE
        if not lo <= self.scale <= hi:
            raise ConfigError(f"{key_where(source, 'scale')}: {self.scale} is not a plausible scale ({lo:g} to {hi:g} layout m per lab m)")


@dataclasses.dataclass(frozen=True)
class LabBounds:
    """The physical flight space: x and y ranges (m, lab frame)."""

    x: tuple[float, float] = spec(help="[min, max] (m)")
    y: tuple[float, float] = spec(help="[min, max] (m)")

    def validate(self, source: str) -> None:
        for key, (lo, hi) in (("x", self.x), ("y", self.y)):
            if not lo < hi:
                raise ConfigError(f"{key_where(source, key)}: expected [min, max] with min < max, got {[lo, hi]}")
            far = max((lo, hi), key=abs)
            if abs(far) > LAB_EXTENT:
                raise ConfigError(f"{key_where(source, key)}: {far:g} m in {[lo, hi]} is farther than {LAB_EXTENT:g} m from "
                                  f"the lab's origin: no flight space is that big (lab coordinates are metres)")


@dataclasses.dataclass(frozen=True)
class SafetyLimits:
    """What keeps drones and people safe. Lab frame, SI units (m, s, m/s, V)."""

    max_speed: float = spec(0.5, lo=0.0, lo_open=True, hi=2.0, help="horizontal speed limit of every command (m/s)")
    max_vertical_speed: float = spec(0.3, lo=0.0, lo_open=True, hi=1.0, help="vertical speed limit (m/s)")
    geofence_margin: float = spec(0.2, lo=0.0, hi=1.0, help="keep this far inside the arena border and from virtual obstacles (m); at least the task's obstacle_clearance, better the braking distance (docs/flight.md)")
    breach_distance: float = spec(0.15, lo=0.0, hi=1.0, help="beyond the border or inside an obstacle by more than this: everyone lands (m)")
    max_altitude: float = spec(1.5, lo=0.2, hi=5.0, help="above this height everyone lands (m)")
    min_separation: float = spec(0.25, lo=0.1, hi=10.0, help=f"keep drone centres this far apart (m); more than {DRONE_CONTACT_DISTANCE:g} m, where two Crazyflies' propellers touch")
    lookahead: float = spec(0.5, lo=0.05, hi=5.0, help="braking horizon of the geofence and separation guard (s)")
    response_time: float = spec(0.3, lo=0.0, hi=2.0, help="how long a drone takes to follow a new command; the guards judge positions this far ahead of its measured motion, plus one decision interval (s)")
    stale_hover: float = spec(0.3, lo=0.01, hi=5.0, help="no fresh estimate for this long: the drone hovers (s)")
    stale_land: float = spec(1.0, lo=0.02, hi=10.0, help="no fresh estimate for this long: everyone lands (s)")
    stall_hover: float = spec(0.2, lo=0.01, hi=1.0, help="no decision for this long past its interval (a stalled policy or process): every commanded drone hovers until the next one (s)")
    link_timeout: float = spec(1.0, lo=0.05, hi=10.0, help="nothing heard from a drone for this long: link lost, everyone lands (s)")
    battery_takeoff: float = spec(3.8, lo=BATTERY_VOLTS[0], hi=BATTERY_VOLTS[1], help="refuse to take off below this battery voltage (V)")
    battery_land: float = spec(3.3, lo=BATTERY_VOLTS[0], hi=BATTERY_VOLTS[1], help="in flight below this voltage the drone lands and the run ends (V)")
    battery_samples: int = spec(3, lo=1, hi=HISTORY, help=f"consecutive low readings before the low-battery landing (the board keeps {HISTORY})")
    estimator_variance: float = spec(1e-3, lo=0.0, lo_open=True, help="kalman.varPX/PY/PZ must be steady within this and, for Lighthouse/Loco, below it (m^2)")
    fix_variance: float = spec(0.01, lo=0.0, lo_open=True, hi=1.0, help="Lighthouse/Loco: in flight, a kalman.varPX/PY/PZ above this means the drone lost its position fix (base stations or anchors out of sight): everyone lands (m^2; above estimator_variance)")
    estimator_timeout: float = spec(10.0, lo=0.1, help="wait this long for the estimators to converge (s)")
    start_tolerance: float = spec(0.3, lo=0.0, lo_open=True, help="Lighthouse/Loco: a drone's estimate must be this close to its start (m)")
    connect_timeout: float = spec(10.0, lo=0.1, help="open every link within this time (s)")
    takeoff_speed: float = spec(0.3, lo=0.05, hi=1.0, help="climb speed of the take-off (m/s)")
    landing_speed: float = spec(0.25, lo=0.05, hi=1.0, help="descent speed of the landing (m/s)")
    height_tolerance: float = spec(0.15, lo=0.01, hi=1.0, help=f"after take-off every drone must be this close to the flight height (m); flight_height minus this must not reach below {LANDED_HEIGHT:g} m, where a drone counts as landed")
    settle: float = spec(0.5, lo=0.0, hi=10.0, help="wait this long after a take-off or landing trajectory ends (s)")
    altitude_gain: float = spec(1.5, lo=0.0, hi=10.0, help="vertical speed per metre of height error while chasing (1/s)")

    def validate(self, source: str) -> None:
        if self.min_separation <= DRONE_CONTACT_DISTANCE:
            raise ConfigError(f"{key_where(source, 'min_separation')}: {self.min_separation:g} m is not beyond {DRONE_CONTACT_DISTANCE:g} m, "
                              f"where two Crazyflies' propellers touch (the simulator counts a collision): the separation "
                              f"guard would hold drones in contact")
        if self.stale_land <= self.stale_hover:
            raise ConfigError(f"{key_where(source, 'stale_land')}: {self.stale_land} s must be longer than stale_hover {self.stale_hover} s")
        if self.fix_variance <= self.estimator_variance:
            raise ConfigError(f"{key_where(source, 'fix_variance')}: {self.fix_variance:g} m^2 must be above estimator_variance "
                              f"{self.estimator_variance:g} m^2, which the take-off asks for: every drone would count as having lost its fix")
        if self.battery_land >= self.battery_takeoff:
            raise ConfigError(f"{key_where(source, 'battery_land')}: {self.battery_land} V must be below battery_takeoff {self.battery_takeoff} V")


@dataclasses.dataclass(frozen=True)
class FlightSpec:
    """A whole flight file (module docstring). `source` is the file it came from."""

    layout: int | str = spec(help="layout index 0-3 or layout file (relative paths: to the flight file)")
    positioning: str = spec(choices=POSITIONING, help="flow | lighthouse | loco")
    drones: tuple[DroneSpec, ...] = spec(help="the drones, each {uri, role, start}")
    name: str = spec("flight", help="a label for logs")
    flight_height: float = spec(0.5, lo=0.1, hi=3.0, help="height of the chase above the lab floor (m)")
    decision_rate: float | None = spec(None, help="policy decisions per second (Hz); default 1 / task control_dt")
    max_time: float = spec(120.0, lo=1.0, hi=3600.0, help="the chase ends (timeout) after this long (s)")
    transform: TransformSpec = spec(default_factory=TransformSpec, help="lab frame -> layout frame")
    lab: LabBounds | None = spec(None, help="physical flight space; default: the arena's bounding box in the lab")
    safety: SafetyLimits = spec(default_factory=SafetyLimits, help="safety limits")
    task: dict = spec(default_factory=dict, help="task config keys (pursuer_speed, capture_radius ...)")
    source: str = spec("<flight>", help="where this spec came from")

    def validate(self, source: str) -> None:
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", self.name) or ".." in self.name:
            raise ConfigError(f"{key_where(source, 'name')}: {self.name!r} is not a plain label (letters, digits, _ . -): "
                              f"it names the default event log file")
        if not self.drones:
            raise ConfigError(f"{key_where(source, 'drones')}: the list is empty")
        roles = [d.role for d in self.drones]
        if "pursuer" not in roles:
            raise ConfigError(f"{key_where(source, 'drones')}: no drone has role 'pursuer'")
        if not ({"evader", "target"} & set(roles)):
            raise ConfigError(f"{key_where(source, 'drones')}: no drone has role 'evader' or 'target' (nothing to chase)")
        seen: dict[tuple, int] = {}
        for i, d in enumerate(self.drones):
            key = link_key(d.uri, f"{source}: drones[{i}]: key 'uri'")
            if key in seen:
                j = seen[key]
                spelled = "" if d.uri == self.drones[j].uri else f" as '{self.drones[j].uri}' (cflib reads both as {_describe_link(key)})"
                raise ConfigError(f"{source}: drones[{i}]: uri '{d.uri}' is also used by drones[{j}]{spelled}")
            seen[key] = i
        names = drone_names(self)
        if len(set(names)) != len(names):
            raise ConfigError(f"{key_where(source, 'drones')}: two drones share the name '{_first_duplicate(names)}'")
        if self.decision_rate is not None and not (math.isfinite(self.decision_rate) and 1.0 <= self.decision_rate <= 100.0):
            raise ConfigError(f"{key_where(source, 'decision_rate')}: {self.decision_rate} Hz is out of range (1 to 100)")
        if self.flight_height - self.safety.height_tolerance < LANDED_HEIGHT - 1e-9:
            raise ConfigError(
                f"{key_where(source, 'flight_height')}: {self.flight_height} m is within safety.height_tolerance "
                f"{self.safety.height_tolerance} m of {LANDED_HEIGHT:g} m, below which a drone counts as landed: the "
                f"take-off check would pass a drone that never left the floor (raise flight_height or lower height_tolerance)"
            )
        if self.flight_height + 0.1 > self.safety.max_altitude:
            raise ConfigError(
                f"{key_where(source, 'flight_height')}: {self.flight_height} m leaves less than 0.1 m below "
                f"safety.max_altitude {self.safety.max_altitude} m"
            )


def drone_names(spec_: FlightSpec) -> list[str]:
    """Each drone's label in file order: its `name`, else role + index within the role."""
    counts: dict[str, int] = {}
    out = []
    for d in spec_.drones:
        k = counts.get(d.role, 0)
        counts[d.role] = k + 1
        out.append(d.name or f"{d.role}_{k}")
    return out


def _first_duplicate(names: list[str]) -> str:
    seen = set()
    for n in names:
        if n in seen:
            return n
        seen.add(n)
    return ""


def _check_keys(cls: type, data: Mapping[str, Any], where: str) -> None:
    """Name an unknown key (with the nearest valid one) or a missing required key."""
    valid = [f.name for f in dataclasses.fields(cls) if f.name != "source"]
    for key in data:
        if key not in valid:
            close = difflib.get_close_matches(str(key), valid, n=1, cutoff=0.5)
            hint = f" (did you mean '{close[0]}'?)" if close else f" (valid keys: {', '.join(valid)})"
            raise ConfigError(f"{where}: unknown key '{key}'{hint}")
    for f in dataclasses.fields(cls):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING and f.name not in data:
            raise ConfigError(f"{where}: missing key '{f.name}'")


def _build(cls: type, data: Any, where: str):
    """configio.build after `_check_keys`, so that a missing key is reported as such."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {shown(data)}")
    _check_keys(cls, data, where)
    return build(cls, data, where)


def flight_from_dict(data: Mapping[str, Any], source: str = "<flight>") -> FlightSpec:
    """Parse and validate a flight mapping; every error names `source` and the key."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    data = dict(data)
    _check_keys(FlightSpec, data, source)
    raw_drones = data["drones"]
    if not isinstance(raw_drones, (list, tuple)):
        raise ConfigError(f"{key_where(source, 'drones')}: expected a list of {{uri, role, start}}, got {raw_drones!r}")
    data["drones"] = tuple(_build(DroneSpec, d, f"{source}: drones[{i}]") for i, d in enumerate(raw_drones))
    for key, cls in (("transform", TransformSpec), ("safety", SafetyLimits)):
        if key in data:
            data[key] = _build(cls, data[key] if data[key] is not None else {}, f"{source}: {key}")
    if data.get("lab") is not None:
        data["lab"] = _build(LabBounds, data["lab"], f"{source}: lab")
    if data.get("task") is not None and not isinstance(data["task"], Mapping):  # empty (null): no task keys, as for safety
        raise ConfigError(f"{key_where(source, 'task')}: expected a mapping of task keys, got {data['task']!r}")
    data["task"] = dict(data.get("task") or {})
    data["source"] = source
    return build(FlightSpec, data, source)


def load_flight(path: str | Path) -> FlightSpec:
    """Read and validate a flight file, or a preset of configs/flight/ by bare name ('example').
    Raises ConfigError naming the file and the key."""
    found = preset_or_file(path, "flight")
    data = load_yaml(found)
    if not data:  # empty, or every line commented out
        raise ConfigError(f"{found}: the file is empty (no flight key); a flight file sets at least layout, positioning "
                          f"and drones (see configs/flight/example.yaml)")
    refuse_another_kind(data, str(found), "flight")
    return flight_from_dict(data, str(found))


__all__ = ["DroneSpec", "TransformSpec", "LabBounds", "SafetyLimits", "FlightSpec", "load_flight", "flight_from_dict", "check_uri", "link_key", "drone_names", "ROLES", "POSITIONING"]
