"""One whole flight from a flight file: what `pursuit-mj fly` runs, real or virtual.

`run_flight` resolves the flight file (refusing bad ones before any radio is touched),
checks the output paths, builds the policy, opens the event log and the optional rerun
recording, starts virtual Crazyflies when asked (then the bridge simply flies their
udp:// links), and runs the bridge. Faults can be injected into virtual flights to
rehearse the safety behaviours: `drop_link:p1@3` (p1's link goes silent 3 s into the
chase), `freeze:p0@2` (p0's estimates stop coming), `battery:e0@4=3.1` (e0's battery
drops to 3.1 V), `lose_fix:p0@2` (Lighthouse/Loco: p0's position variance grows, as with its
base stations out of sight).
"""

from __future__ import annotations

import dataclasses
import re
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

from ..io_utils import check_writable, no_new_empty_folders, no_reader, no_reader_message
from ..policies import make_policy
from ..policy import Policy
from .bridge import FlightBridge, FlightResult
from .events import EventLog
from .links import CrazyflieFactory
from .plan import FlightPlan, load_plan
from .spec import BATTERY_VOLTS, NAME

FAULT_KINDS = ("drop_link", "freeze", "battery", "lose_fix")
_NUMBER = r"\d+(?:\.\d*)?|\.\d+"  # 3, 3., 3.1, .5: what float() reads, no sign or exponent
_FAULT = re.compile(rf"^(\w+):({NAME})@({_NUMBER})(?:=({_NUMBER}))?$")


@dataclasses.dataclass(frozen=True)
class Fault:
    """A fault for a virtual drone: kind, drone index (plan order), seconds after the chase starts, value."""

    kind: str
    drone: int
    at: float
    value: float | None = None


def parse_fault(text: str, plan: FlightPlan, source: str = "--fault") -> Fault:
    """'kind:drone@seconds[=value]' -> Fault; ValueError naming `source` if malformed."""
    m = _FAULT.match(text.strip())
    if not m:
        raise ValueError(f"{source} {text!r}: expected KIND:DRONE@SECONDS (e.g. drop_link:p1@3, battery:e0@4=3.1)")
    kind, name, at, value = m.group(1), m.group(2), float(m.group(3)), m.group(4)
    if kind not in FAULT_KINDS:
        raise ValueError(f"{source} {text!r}: unknown fault '{kind}' (valid: {', '.join(FAULT_KINDS)})")
    if name not in plan.names:
        raise ValueError(f"{source} {text!r}: no drone named '{name}' (drones: {', '.join(plan.names)})")
    if (kind == "battery") != (value is not None):
        raise ValueError(f"{source} {text!r}: " + (f"'battery' needs a voltage (battery:{name}@{at:g}=3.1)" if kind == "battery"
                         else f"'{kind}' takes no value ({kind}:{name}@{at:g})"))
    if kind == "battery" and not BATTERY_VOLTS[0] <= float(value) <= BATTERY_VOLTS[1]:
        volts = float(value)
        hint = f"; {value} reads as millivolts: write {volts / 1000:g}" if volts >= 1000 else ""
        raise ValueError(f"{source} {text!r}: {volts:g} V is not the resting voltage of a Crazyflie's one-cell battery "
                         f"({BATTERY_VOLTS[0]:g} to {BATTERY_VOLTS[1]:g} V){hint}")
    if kind == "lose_fix" and plan.spec.positioning == "flow":
        raise ValueError(f"{source} {text!r}: 'lose_fix' rehearses a Lighthouse or Loco drone losing its position fix; "
                         f"this flight flies flow decks, whose position variance grows by design")
    if at >= plan.spec.max_time:
        raise ValueError(f"{source} {text!r}: {at:g} s into the chase is not before its end (max time "
                         f"{plan.spec.max_time:g} s); the fault would never happen")
    return Fault(kind, plan.names.index(name), at, float(value) if value is not None else None)


class FaultInjector:
    """Applies faults to a VirtualFleet, timed from the 'chase' event of the flight's event log."""

    def __init__(self, fleet, faults: Sequence[Fault], events: EventLog):
        self.fleet, self.faults, self.events = fleet, list(faults), events
        self.timers: list[threading.Timer] = []
        events.add_sink("faults", self._on_event)

    def _on_event(self, record: dict) -> None:
        if record["kind"] != "chase":
            return
        for f in self.faults:
            t = threading.Timer(f.at, self._apply, args=(f,))
            t.daemon = True
            t.start()
            self.timers.append(t)

    def _apply(self, f: Fault) -> None:
        name = self.fleet.plan.names[f.drone]
        if f.kind == "drop_link":
            self.fleet.drop_link(f.drone)
        elif f.kind == "freeze":
            self.fleet.freeze_estimates(f.drone)
        elif f.kind == "lose_fix":
            self.fleet.lose_fix(f.drone)
        else:
            self.fleet.set_battery(f.drone, f.value)
        self.events.log("fault_injected", fault=f.kind, drone=name, value=f.value, level="warn")

    def cancel(self) -> None:
        for t in self.timers:
            t.cancel()


def _same_file(a: str | Path, b: str | Path) -> bool:
    """Whether paths a and b name one file (links and relative spellings resolved)."""
    try:
        return Path(a).resolve() == Path(b).resolve()
    except (OSError, RuntimeError):  # a name too long, a link loop: not resolvable, not compared
        return False


def _check_events_apart(events_path: str | Path, plan: FlightPlan, rerun_path: str | Path | None) -> None:
    """ValueError naming --events when it names the rerun recording (renamed into place when the
    flight ends, it would replace the event log) or a file the flight reads (the flight or layout
    file: the log is appended to it)."""
    others = [(rerun_path, "the --rerun recording"), (plan.spec.source, "the flight file"), (plan.layout.source, "the flight's layout file")]
    for other, what in others:
        if other is not None and _same_file(events_path, other):
            raise ValueError(f"--events {events_path}: is also {what}; give the event log a name of its own "
                             f"(default flights/<name>-<time>.events.jsonl)")


def _is_event_log(head: bytes, whole: bool) -> bool:
    """Whether a file whose first bytes are `head` is an event log: its first line is a JSON
    record with a 'kind' (events.EventLog writes every line so)."""
    import json

    first = head.split(b"\n", 1)[0]
    if not first.strip():  # a blank first line: nothing of the user's there
        return True
    try:
        record = json.loads(first)
    except ValueError:  # UnicodeDecodeError too
        return False
    return isinstance(record, dict) and "kind" in record


def _check_events_is_a_log(events_path: str | Path) -> None:
    """ValueError naming --events when it names an existing file that is not an event log
    (_is_event_log, from its first 64 KiB): the flight's records are appended to it, and a
    layout, notes or any other file would be damaged for good. An empty file is taken."""
    from ..io_utils import holds_another_kind

    if holds_another_kind(events_path, _is_event_log):
        raise ValueError(f"--events {events_path}: an existing file that is not an event log (its first line is no "
                         f"flight record); the log is appended to: give a new name, or an earlier flight's .events.jsonl")


def refuse_events_path(events_path: str | Path, plan: FlightPlan, rerun_path: str | Path | None = None) -> None:
    """ValueError naming --events when it names the rerun recording, a file the flight reads, or
    an existing file that is not an event log; reads only, so a command may ask before it says
    anything of the flight (run_flight asks again)."""
    _check_events_apart(events_path, plan, rerun_path)
    _check_events_is_a_log(events_path)


def choose_policy(plan: FlightPlan, policy: str | None, seed: int = 0) -> Policy:
    """`--policy NAME` (pursuit_mj.policies). A trained model is loaded by the caller
    (`train.load_policy`; the simulator package never imports the learning one) and handed
    to `run_flight` as a Policy."""
    if policy is None:
        raise ValueError("give a policy: --policy NAME (e.g. heuristic) or --model FILE")
    return make_policy(policy, plan.task, seed, "--policy")


def default_events_path(plan: FlightPlan, folder: str | Path = "flights") -> Path:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(folder) / f"{plan.spec.name}-{stamp}.events.jsonl"


def _remove_if_empty(path: Path) -> None:
    """Remove the file `path` if it is empty (nothing if it is not, or cannot be removed)."""
    try:
        if path.is_file() and path.stat().st_size == 0:
            path.unlink()
    except OSError:
        pass


def run_flight(
    flight: str | Path | FlightPlan,
    policy: Policy | None = None,
    *,
    policy_name: str | None = None,
    overrides: Sequence[str] = (),
    virtual: bool = False,
    virtual_drones=None,
    virtual_physics=None,
    faults: Sequence[str] = (),
    events_path: str | Path | None = None,
    rerun_path: str | Path | None = None,
    factory: CrazyflieFactory | None = None,
    seed: int = 0,
    handle_signals: bool = True,
    echo: Callable[[dict], None] | None = None,
    on_bridge: Callable[[FlightBridge], None] | None = None,
) -> tuple[FlightResult, EventLog]:
    """Fly (module docstring). Everything that can be refused is refused before a link opens.

    policy: a Policy object (a trained one: train.load_policy(path, plan.obs_spec,
    task=plan.task)), or else policy_name picks a hand-made one; faults need virtual=True;
    virtual_drones / virtual_physics: VirtualDrone options and VirtualPhysics constants;
    on_bridge(bridge) is called once the bridge exists (e.g. to wire an emergency-stop key).
    """
    plan = flight if isinstance(flight, FlightPlan) else load_plan(flight, overrides)
    if faults and not virtual:
        raise ValueError("--fault rehearses failures on virtual drones only; add --virtual")
    fault_list = [parse_fault(f, plan) for f in faults]
    # refused or failed before it recorded anything: no folder made for --rerun or --events is left
    with no_new_empty_folders():
        if rerun_path is not None:
            from ..recording import check_rrd_path

            check_rrd_path(rerun_path)
        if events_path is not None:
            check_writable(events_path, "--events", appended=True)  # /dev/stdout to a file: appended to
            refuse_events_path(events_path, plan, rerun_path)
        if policy is None:
            policy = choose_policy(plan, policy_name, seed)
        new_log = events_path is not None and not Path(events_path).exists()
        try:
            events = EventLog(events_path, echo=echo)
        except OSError as exc:  # a writable folder, a file that is not (read-only, a broken link)
            if no_reader(exc, events_path):
                raise ValueError(no_reader_message(events_path, "--events")) from None
            raise ValueError(f"--events {events_path}: cannot be opened for appending ({exc.strerror or exc})") from None
        recorder = None
        fleet = None
        injector = None
        finished = False
        try:
            if rerun_path is not None:
                from .rerun_log import FlightRecorder

                recorder = FlightRecorder(rerun_path, plan)
                for left in recorder.killed_before:
                    events.log("rerun_unfinished_kept", path=str(left), level="warn",
                               why="a recording of this name killed before it finished (kill -9?) left it: open it with rerun")
            if virtual:
                from .virtual.fleet import VirtualFleet

                fleet = VirtualFleet(plan, virtual_drones, physics=virtual_physics)
                fleet.start()
                events.log("virtual_fleet", uris=fleet.uris)
                injector = FaultInjector(fleet, fault_list, events)
                plan = plan.with_uris(fleet.uris)
            bridge = FlightBridge(plan, policy, events, factory=factory, recorder=recorder, seed=seed, handle_signals=handle_signals)
            if on_bridge is not None:
                on_bridge(bridge)
            result = bridge.run()
            finished = True
            return result, events
        finally:
            if injector is not None:
                injector.cancel()
            if fleet is not None:
                fleet.stop()
            if recorder is not None:
                recorder.close()
            events.close()
            if new_log and not finished:  # failed before its first event (a fleet that cannot start): no empty log
                _remove_if_empty(Path(events_path))
