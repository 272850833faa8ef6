"""Guards that act during a flight, on virtual Crazyflies through real cflib: the speed clamp,
the geofence and the separation guard (commands filtered, drones kept inside and apart),
Ctrl-C (everyone lands) and the emergency stop (every motor cut at once)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from flight_rehearsal import ScriptedTeam, fly_virtual, kinds_in_order, quick_plan, wait_for
from pursuit_mj.heuristic import HeuristicTeam


def down(fleet) -> bool:
    """Every drone sits on the floor with its motors off, within 3 s: the bridge judges a landing
    done from estimates under 0.1 m, and the last few cm the drones drop on their own clock, which
    a loaded computer runs late (as test_flight_safety.settle waits for)."""

    def now() -> bool:
        state = fleet.true_state()
        return bool((state["pos"][:, 2] < 0.03).all() and not state["motors"].any())

    return wait_for(now, 3.0)


def _lab_flight_file(fleet, folder):
    """A flight file (folder/lab.yaml) of quick_spec's drones on the udp:// links of `fleet`'s
    virtual drones: what a real flight's file names, so fly treats it as one (it asks for a go)."""
    import yaml

    from flight_rehearsal import quick_spec

    data = quick_spec()
    for drone, uri in zip(data["drones"], fleet.uris):  # file order is plan order here
        drone["uri"] = uri
    flight = folder / "lab.yaml"
    flight.write_text(yaml.safe_dump(data))
    return flight


def test_speed_clamp_geofence_and_separation_guard_keep_drones_slow_inside_and_apart(tmp_path):
    # p0 flies at the left border, p1 and p2 at each other, all asked for 1 m/s (limit 0.4 m/s)
    plan = quick_plan(max_time=2.4, task={"pursuer_speed": 1.0}, safety={"max_speed": 0.4, "geofence_margin": 0.3, "min_separation": 0.25})
    team = ScriptedTeam([[-1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])
    track = []

    def watch(fleet, bridge):
        end = time.monotonic() + 2.3
        while time.monotonic() < end:
            track.append(fleet.true_state()["pos"].copy())
            time.sleep(0.02)

    result, events, fleet = fly_virtual(plan, team, tmp_path, during=watch)
    assert result.outcome == "timeout" and result.landed
    names = lambda kind: {r["drone"] for r in events.of_kind(kind)}  # noqa: E731
    assert {"p0", "p1", "p2"} <= names("speed_clamped")
    assert "p0" in names("geofence") and {"p1", "p2"} <= names("separation")
    # each event says what its guard measured (the separation events gave the fence's clearance,
    # which read as the drones' gap): lab m and m/s, the open layout's arena at lab [0, 3.6] x [0, 5]
    for r in events.of_kind("speed_clamped"):
        assert r["speed"] > 0.4 and "clearance" not in r
    for r in events.of_kind("separation"):
        assert 0 < r["gap"] < 1.0 and "clearance" not in r
    for r in events.of_kind("geofence"):
        x, y = r["pos"]
        assert r["clearance"] == pytest.approx(min(x, y, 3.6 - x, 5.0 - y), abs=1e-4)
        assert r["clearance_ahead"] < r["clearance"]  # flying toward the fence
    sent = np.array([s.sent[:3, :2] for s in result.steps])
    assert np.linalg.norm(sent, axis=-1).max() <= 0.4 + 1e-9
    track = np.array(track)
    assert track[:, 0, 0].min() > 0.3 - 0.08  # held at the margin (the arena starts at lab x = 0) ...
    assert track[-1, 0, 0] < 0.45  # ... after flying there from x = 0.8
    gap = np.linalg.norm(track[:, 1, :2] - track[:, 2, :2], axis=-1)
    assert gap.min() > 0.25 - 0.05 and gap[-1] < 0.45  # they came close, not closer
    assert down(fleet)


@pytest.mark.parametrize("sig, reason", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_ctrl_c_or_sigterm_lands_everyone_and_restores_the_signal_handler(tmp_path, sig, reason):
    plan = quick_plan(max_time=8.0)
    before = signal.getsignal(sig)

    def send(fleet, bridge):
        time.sleep(0.3)
        os.kill(os.getpid(), sig)

    result, events, fleet = fly_virtual(plan, HeuristicTeam.from_config(plan.task), tmp_path, during=send, handle_signals=True)
    assert result.outcome == "interrupted" and result.reason == reason and result.landed
    assert kinds_in_order(events, "chase", "interrupt", "land", "landed")
    assert events.of_kind("interrupt")[0]["reason"] == reason
    assert signal.getsignal(sig) is before
    assert down(fleet)


def test_ctrl_c_that_comes_while_the_flight_loop_holds_a_lock_still_lands_everyone(tmp_path):
    """The handler set the flight's threading.Events itself, on the main thread, which a signal
    interrupts anywhere: inside Event.wait (the flight loop sleeps in it between decisions)
    that thread holds the Event's lock for a moment, the handler waited for that lock forever
    and the run hung with every drone hovering (the Ctrl-C test under load). Here the main
    thread holds it, as Event.wait does, when Ctrl-C comes; a timer frees it after 3 s."""
    box, seen = {}, {}

    def ctrl_c_holding_the_lock(record):  # on the main thread, which logs the chase's start
        if record["kind"] != "chase":
            return
        lock = box["bridge"]._stop._cond  # what Event.wait and Event.set take
        lock.acquire()
        rescue = threading.Timer(3.0, lambda: (seen.setdefault("rescued", True), lock.release()))
        rescue.start()
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler runs here, on this thread, with the lock held
        rescue.cancel()
        if not seen.setdefault("rescued", False):
            lock.release()

    result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.0, 0.0]]), tmp_path, handle_signals=True,
                                        on_bridge=lambda bridge: box.setdefault("bridge", bridge), sink=ctrl_c_holding_the_lock)
    assert seen == {"rescued": False}, "the Ctrl-C handler waited for a lock the interrupted thread held"
    assert result.outcome == "interrupted" and result.reason == "Ctrl-C" and result.landed
    assert kinds_in_order(events, "chase", "interrupt", "land", "landed")
    assert down(fleet)


def test_ctrl_z_lands_everyone_instead_of_suspending_the_flight(tmp_path):
    """Ctrl-Z (SIGTSTP) by default suspends the process: no setpoint leaves it, and the
    firmware's watchdog stops every motor 2 s later, in the air. During a flight it lands
    everyone, as Ctrl-C does."""
    before = signal.getsignal(signal.SIGTSTP)
    taken = []

    def send(fleet, bridge):
        time.sleep(0.3)
        taken.append(signal.getsignal(signal.SIGTSTP) not in (signal.SIG_DFL, None))
        # never suspend the test run itself: where Ctrl-Z is not taken, Ctrl-C ends the flight
        os.kill(os.getpid(), signal.SIGTSTP if taken[0] else signal.SIGINT)

    result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.0, 0.0]]), tmp_path, during=send,
                                        handle_signals=True)
    assert taken == [True], "Ctrl-Z would suspend the flight process"
    assert result.outcome == "interrupted" and result.reason == "Ctrl-Z" and result.landed
    assert kinds_in_order(events, "chase", "interrupt", "land", "landed")
    assert signal.getsignal(signal.SIGTSTP) is before
    assert down(fleet)


def test_a_keyboard_interrupt_inside_the_loop_lands_everyone(tmp_path):
    result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.2, 0.0]], raise_at=4), tmp_path)
    assert result.outcome == "interrupted" and result.landed and len(result.steps) == 3
    assert kinds_in_order(events, "chase", "end_of_run", "land", "landed")
    assert down(fleet)


def test_a_landing_asked_for_by_key_is_logged_and_everyone_lands(tmp_path):
    """Key `l` ended the run with no event of its own in the log, unlike every other stop."""

    def press_l(fleet, bridge):
        time.sleep(0.3)
        bridge.request_land("key pressed")

    result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.0, 0.0]]), tmp_path, during=press_l)
    assert result.outcome == "land_requested" and result.landed
    assert kinds_in_order(events, "chase", "land_requested", "land", "landed")
    assert events.of_kind("land_requested")[0]["reason"] == "key pressed"
    assert down(fleet)


def test_the_emergency_stop_cuts_every_motor_at_once_and_nobody_lands(tmp_path):
    seen = {}

    def estop(fleet, bridge):
        time.sleep(0.3)
        t0 = time.monotonic()
        bridge.emergency_stop("test command")
        seen["off_after"] = time.monotonic() - t0 if wait_for(lambda: not fleet.true_state()["motors"].any(), 1.0) else None

    def aftermath(fleet):
        seen["fell"] = wait_for(lambda: down(fleet), 2.0)

    result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.0, 0.0]]), tmp_path, during=estop, aftermath=aftermath)
    assert result.outcome == "emergency_stop" and not result.landed
    assert seen["off_after"] is not None and seen["off_after"] < 0.2
    assert "land" not in events.kinds() and events.of_kind("emergency_stop")[0]["reason"] == "test command"
    assert fleet.true_state()["locked"].all() and seen["fell"]


def test_ctrl_c_before_take_off_ends_the_run_and_is_logged(tmp_path):
    import json

    def press_ctrl_c_at_the_go_no_go():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # the handler runs here
        return True

    with pytest.raises(KeyboardInterrupt):
        fly_virtual(quick_plan(max_time=8.0), HeuristicTeam.from_config(quick_plan().task), tmp_path,
                    handle_signals=True, confirm=press_ctrl_c_at_the_go_no_go)
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert "takeoff" not in kinds and kinds.index("interrupt") < kinds.index("links_closed")


def test_a_log_that_can_no_longer_be_written_or_echoed_does_not_keep_the_drones_from_landing(tmp_path):
    """A full disk under the event log and a closed pipe under its echo (`fly ... | tee`,
    then Ctrl-C) used to raise out of the flight loop before the landing."""

    def break_the_log(fleet, bridge):
        time.sleep(0.3)
        bridge.events._file = open("/dev/full", "a")  # what a full disk does to the next write

        def closed_pipe(record):
            raise BrokenPipeError(32, "Broken pipe")

        bridge.events.add_sink("echo", closed_pipe)

    result, events, fleet = fly_virtual(quick_plan(max_time=1.5), ScriptedTeam([[0.0, 0.0]]), tmp_path, during=break_the_log)
    assert result.outcome == "timeout" and result.landed
    assert kinds_in_order(events, "chase", "end_of_run", "land", "landed")  # every record kept in memory
    assert len(events.failures) == 2 and "events.jsonl" in events.failures[0] and "Broken pipe" in events.failures[1]
    assert down(fleet)


def test_a_failing_event_sink_is_dropped_alone():
    from pursuit_mj.flight.events import EventLog

    got = []

    def closed_pipe(record):
        raise BrokenPipeError(32, "Broken pipe")

    events = EventLog(echo=closed_pipe)
    events.add_sink("rerun", got.append)
    events.log("takeoff")
    events.log("step")  # routine: no sink sees it
    events.log("land")
    assert [r["kind"] for r in got] == ["takeoff", "land"] and events.sinks == ("rerun",)
    assert len(events.failures) == 1 and "'echo'" in events.failures[0]
    with pytest.raises(ValueError, match="'rerun' is already attached"):
        events.add_sink("rerun", got.append)


def test_a_broken_terminal_echo_keeps_the_fault_injection_and_the_rerun_recording_going(tmp_path):
    """`fly ... | head -n 13`: the echo's first failure dropped the whole chain built on it
    (the rerun recorder and the fault injector), so the fault never came."""
    from pursuit_mj.flight.session import run_flight
    from pursuit_mj.recording.rrd_read import read_entities

    from flight_rehearsal import FAST

    printed = []

    def head(record):  # a pipe that closes after three lines
        if len(printed) == 3:
            raise BrokenPipeError(32, "Broken pipe")
        printed.append(record["kind"])

    result, events = run_flight(quick_plan(max_time=1.5), ScriptedTeam([[0.0, 0.0]]), virtual=True, virtual_physics=FAST,
                                faults=["freeze:p0@0.3"], events_path=tmp_path / "e.jsonl", rerun_path=tmp_path / "f.rrd",
                                echo=head, handle_signals=False)
    assert result.outcome == "timeout" and len(printed) == 3
    assert kinds_in_order(events, "chase", "fault_injected", "end_of_run", "land", "landed")
    texts = [t for row in read_entities(tmp_path / "f.rrd")["/events"].rows["TextLog:text"] for t in row]
    assert any(t.startswith("fault_injected") for t in texts) and any(t.startswith("landed") for t in texts)
    assert len(events.failures) == 1 and "'echo'" in events.failures[0] and "Broken pipe" in events.failures[0]
    assert events.sinks == ("faults", "rerun")


def test_ctrl_backslash_cuts_the_motors_from_another_thread_than_the_signal_handler(tmp_path):
    """The handler runs on the main thread, which may be inside a link's send holding its lock:
    cutting the motors there could wait on that lock for ever."""
    from pursuit_mj.flight.bridge import FlightBridge

    cut_on = []
    real = FlightBridge._cut_motors

    def record_thread(self):
        cut_on.append(threading.current_thread().name)
        real(self)

    def send(fleet, bridge):
        time.sleep(0.3)
        os.kill(os.getpid(), signal.SIGQUIT)

    FlightBridge._cut_motors = record_thread
    try:
        result, events, fleet = fly_virtual(quick_plan(max_time=8.0), ScriptedTeam([[0.0, 0.0]]), tmp_path, during=send,
                                            handle_signals=True)
    finally:
        FlightBridge._cut_motors = real
    assert result.outcome == "emergency_stop" and not result.landed
    # from its own thread (started by the signal's relay), and once more from the flight's; which runs
    # first depends on when a loaded machine schedules the new thread
    assert wait_for(lambda: "emergency-stop" in cut_on, 2.0), cut_on
    assert events.of_kind("emergency_stop")[0]["reason"] == "Ctrl-\\ pressed"
    assert wait_for(lambda: not fleet.true_state()["motors"].any(), 1.0)


def test_one_stop_signal_during_a_landing_for_another_reason_lets_it_land_a_second_cuts_the_motors(tmp_path):
    """A single SIGTERM (`timeout`, a supervisor) or SIGHUP (the terminal closed) that arrives while a
    capture or time-out landing runs is a first signal: everyone lands, as they are doing; only a
    second one cuts the motors."""
    sent = []

    def signal_during_landing(fleet, bridge, count):
        assert wait_for(lambda: "land" in bridge.events.kinds(), 10.0)
        for _ in range(count):
            time.sleep(0.15)
            os.kill(os.getpid(), signal.SIGTERM)
            sent.append(time.monotonic())

    result, events, fleet = fly_virtual(quick_plan(max_time=1.0), ScriptedTeam([[0.0, 0.0]]), tmp_path / "one",
                                        during=lambda f, b: signal_during_landing(f, b, 1), handle_signals=True)
    assert len(sent) == 1
    assert result.outcome == "timeout" and result.landed, (result.outcome, result.reason)
    assert "emergency_stop" not in events.kinds() and not fleet.true_state()["locked"].any()
    assert events.of_kind("interrupt")[0]["during"] == "landing"
    assert down(fleet)

    result, events, fleet = fly_virtual(quick_plan(max_time=1.0), ScriptedTeam([[0.0, 0.0]]), tmp_path / "two",
                                        during=lambda f, b: signal_during_landing(f, b, 2), handle_signals=True)
    assert result.outcome == "emergency_stop" and not result.landed
    assert events.of_kind("emergency_stop")[0]["reason"] == "second SIGTERM during the landing"


class _TerminalAtEnd:
    """stdin of a terminal whose operator pressed Ctrl-D at the prompt (end of input)."""

    def isatty(self) -> bool:
        return True

    def readline(self, *args) -> str:
        return ""


def test_end_of_input_at_the_go_no_go_prompt_declines_the_take_off_in_one_line(tmp_path, monkeypatch, capsys):
    """A real flight (its radio links: here the udp:// links of virtual drones) asks for a go;
    Ctrl-D there is a no, never a traceback, and nothing takes off."""

    from flight_rehearsal import FAST
    from pursuit_cli import main
    from pursuit_mj.flight.virtual.fleet import VirtualFleet

    with VirtualFleet(quick_plan(), physics=FAST) as fleet:
        flight = _lab_flight_file(fleet, tmp_path)
        monkeypatch.setattr("sys.stdin", _TerminalAtEnd())
        rc = main(["fly", "--flight", str(flight), "--policy", "heuristic", "--events", str(tmp_path / "f.jsonl")])
        assert not any(r.kind == "takeoff" for i in range(4) for r in fleet.received(i))
    err = capsys.readouterr().err
    assert rc == 2 and "take-off declined" in err and "Traceback" not in err


_FAILS_AFTER_TAKEOFF = """
import numpy as np


class FailsOnItsThirdStep:
    name = "fails-third"

    def __init__(self, config, seed):
        self.calls = 0

    def reset(self, n_worlds, world_ids=None):
        pass

    def act(self, obs, spec):
        self.calls += 1
        if self.calls >= 3:
            raise ValueError("no answer for this state")
        return np.zeros(obs.shape[:-1] + (2,))
"""


def test_a_policy_that_fails_after_take_off_exits_1_saying_it_failed_in_flight_and_the_drones_landed(tmp_path, capsys):
    """README's exit codes: 2 is bad input or a flight refused before take-off, 1 a flight that
    ended otherwise than by a capture or its time limit. A policy file's error in its third
    decision (a ValueError, as every failure of a policy file is) made `fly` exit 2 as bad input,
    after the drones had flown and landed. It exits 1 now, saying the policy failed in flight,
    naming its error and that the drones landed; the same file failing at load stays 2."""

    from flight_rehearsal import FAST
    from pursuit_cli import main
    from pursuit_mj.flight.events import read_events
    from pursuit_mj.flight.virtual.fleet import VirtualFleet

    mine = tmp_path / "mine.py"
    mine.write_text(_FAILS_AFTER_TAKEOFF)
    with VirtualFleet(quick_plan(), physics=FAST) as fleet:
        flight = _lab_flight_file(fleet, tmp_path)
        events = tmp_path / "f.jsonl"
        rc = main(["fly", "--flight", str(flight), "--policy", f"{mine}:FailsOnItsThirdStep", "--yes", "--events", str(events)])
        err = capsys.readouterr().err
        assert rc == 1, (rc, err)
        assert down(fleet)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"pursuit-mj fly: error: the policy fails-third failed in flight (the drones landed): --policy {mine}:"
                          "FailsOnItsThirdStep: act(obs, spec) raised ValueError: no answer for this state"), err
    assert err.rstrip().endswith(f"; events: {events}"), err
    assert kinds_in_order([r["kind"] for r in read_events(events)], "chase", "land", "landed", "error")
    rc = main(["fly", "--flight", str(flight), "--policy", f"{mine}:NoSuchName", "--yes", "--events", str(events)])
    assert rc == 2 and "NoSuchName" in capsys.readouterr().err


def test_a_ctrl_c_during_the_landing_after_a_policy_failed_in_flight_exits_as_the_stop(tmp_path, capsys):
    """README's exit codes: a stop signal that comes while a flight lands for another reason lets
    it land, and the command exits 128 + its number. After a policy failed in flight fly said the
    failure and exited 1, the Ctrl-C during that landing (in the event log) lost: it exits 130 now,
    and its line says a Ctrl-C came."""

    from flight_rehearsal import FAST
    from pursuit_cli import main
    from pursuit_mj.flight.events import read_events
    from pursuit_mj.flight.virtual.fleet import VirtualFleet

    mine = tmp_path / "mine.py"
    mine.write_text(_FAILS_AFTER_TAKEOFF)
    events = tmp_path / "f.jsonl"

    def ctrl_c_once_landing() -> None:  # as an operator who sees the drones come down
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            if events.exists() and any(r["kind"] == "land" for r in read_events(events)):
                os.kill(os.getpid(), signal.SIGINT)
                return
            time.sleep(0.01)

    with VirtualFleet(quick_plan(), physics=FAST) as fleet:
        flight = _lab_flight_file(fleet, tmp_path)
        threading.Thread(target=ctrl_c_once_landing, daemon=True).start()
        rc = main(["fly", "--flight", str(flight), "--policy", f"{mine}:FailsOnItsThirdStep", "--yes", "--events", str(events)])
        err = capsys.readouterr().err
        assert down(fleet)
    interrupt = [r for r in read_events(events) if r["kind"] == "interrupt"]
    assert [r.get("during") for r in interrupt] == ["landing"], interrupt
    assert rc == 130, (rc, err)
    assert err.startswith("pursuit-mj fly: error: the policy fails-third failed in flight (the drones landed; a Ctrl-C came "
                          "too): "), err
    assert len(err.strip().splitlines()) == 1, err


def test_a_bug_after_take_off_says_the_drones_landed_and_keeps_its_traceback(tmp_path, capsys, monkeypatch):
    """An in-flight error that is no refusal (not a ValueError: a torch error, a bug of ours) is
    told in the same line (the drones landed, the events file) and then raised on, so that the
    traceback shows where it came from and the process exits 1 as any failure does."""

    from flight_rehearsal import FAST
    from pursuit_cli import main
    from pursuit_mj.flight.bridge import FlightBridge
    from pursuit_mj.flight.virtual.fleet import VirtualFleet

    def broken_chase(self, *args):
        raise RuntimeError("a bug in the chase")

    monkeypatch.setattr(FlightBridge, "_chase", broken_chase)
    with VirtualFleet(quick_plan(), physics=FAST) as fleet:
        flight = _lab_flight_file(fleet, tmp_path)
        events = tmp_path / "f.jsonl"
        with pytest.raises(RuntimeError, match="a bug in the chase"):
            main(["fly", "--flight", str(flight), "--policy", "heuristic", "--yes", "--events", str(events)])
        assert down(fleet)
    err = capsys.readouterr().err
    assert "failed after take-off (the drones landed): RuntimeError: a bug in the chase" in err, err


def test_event_log_lines_are_strict_json_a_value_that_is_not_a_number_is_null(tmp_path):
    """The diverged-estimate event carries NaN positions; a NaN or Infinity token is not JSON
    (jq and other strict readers refuse the whole log)."""
    import json

    from pursuit_mj.flight.events import EventLog

    def refuse(token):
        raise ValueError(f"not JSON: {token}")

    with EventLog(tmp_path / "e.jsonl") as log:
        log.log("stale_land", pos=np.array([np.nan, 1.0, np.inf]), z=float("nan"), heights=[np.float32("nan"), 0.5], level="error")
    record = json.loads((tmp_path / "e.jsonl").read_text().splitlines()[0], parse_constant=refuse)
    assert record["pos"] == [None, 1.0, None] and record["z"] is None and record["heights"] == [None, 0.5]


def test_a_slow_go_has_the_batteries_and_states_checked_again_before_take_off(tmp_path, monkeypatch):
    """The checks ran once, before the go/no-go prompt: a battery that sagged while the operator
    took their time was flown on."""
    import json

    from pursuit_mj.flight import bridge as bridge_module

    monkeypatch.setattr(bridge_module, "RECHECK_AFTER", 0.1)
    fleet_box = {}

    def go_after_the_battery_sagged():
        fleet_box["fleet"].set_battery(1, 3.5)  # below battery_takeoff 3.8 V
        time.sleep(0.5)  # the operator thinks; new health samples arrive
        return True

    plan = quick_plan(max_time=2.0)
    from flight_rehearsal import VirtualFleet

    original_init = VirtualFleet.__init__

    def remember(self, *a, **k):
        original_init(self, *a, **k)
        fleet_box["fleet"] = self

    monkeypatch.setattr(VirtualFleet, "__init__", remember)
    result, events, fleet = fly_virtual(plan, ScriptedTeam([[0.0, 0.0]]), tmp_path, confirm=go_after_the_battery_sagged)
    assert isinstance(result, Exception) and "battery 3.50 V is below 3.8 V" in str(result), result
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert "preflight_ok" in kinds and "takeoff" not in kinds and kinds.index("preflight_failed") > kinds.index("preflight_ok")

    # a quick go, or a slow one with nothing changed, takes off as before
    fleet_box.clear()
    result, events, fleet = fly_virtual(plan, ScriptedTeam([[0.0, 0.0]]), tmp_path / "ok", confirm=lambda: time.sleep(0.3) or True)
    assert result.outcome == "timeout" and result.landed
    assert "preflight_recheck_ok" in [json.loads(x)["kind"] for x in (tmp_path / "ok" / "events.jsonl").read_text().splitlines()]


def test_an_event_log_on_a_device_that_cannot_be_fsynced_goes_on_being_written():
    """`--events /dev/null` was dropped at the first safety event, whose fsync failed (EINVAL)."""
    from pursuit_mj.flight.events import EventLog

    log = EventLog("/dev/null")
    log.log("geofence", drone="p0")  # safety-relevant: fsync'ed where the log is a file on disk
    log.log("geofence", drone="p1")
    assert log.failures == [] and len(log.records) == 2


def test_a_late_go_is_refused_when_a_drone_sent_no_fresh_estimate_while_the_operator_decided(tmp_path, monkeypatch):
    """The recheck asked only that some estimate had ever arrived: a drone whose estimates had
    stopped during the wait was sent its take-off, and the flight then ended in takeoff_failed."""
    import json

    from pursuit_mj.flight import bridge as bridge_module
    from flight_rehearsal import VirtualFleet

    monkeypatch.setattr(bridge_module, "RECHECK_AFTER", 0.1)
    fleet_box = {}
    original_init = VirtualFleet.__init__

    def remember(self, *a, **k):
        original_init(self, *a, **k)
        fleet_box["fleet"] = self

    def go_after_p2_froze():
        fleet_box["fleet"].freeze_estimates(2)
        time.sleep(0.6)
        return True

    monkeypatch.setattr(VirtualFleet, "__init__", remember)
    plan = quick_plan(max_time=2.0, safety={"stale_hover": 0.3, "estimator_timeout": 1.0})
    result, events, fleet = fly_virtual(plan, ScriptedTeam([[0.0, 0.0]]), tmp_path, confirm=go_after_p2_froze)
    assert isinstance(result, Exception) and "drone p2" in str(result) and "no fresh state estimate" in str(result), result
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert "takeoff" not in kinds and "preflight_failed" in kinds


def test_ctrl_c_while_the_policy_resets_before_take_off_ends_the_run_at_once(tmp_path):
    """policy.reset ran after the flight counted as under way: Ctrl-C then only asked for a
    landing, so a reset that hung (a policy file of one's own) kept the run from ending; one
    that returned 20 s later led to a take-off check that ended it only then."""

    class SlowReset(ScriptedTeam):
        def reset(self, n_worlds, world_ids=None):
            threading.Timer(0.3, os.kill, args=(os.getpid(), signal.SIGINT)).start()
            time.sleep(20.0)

    began = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        fly_virtual(quick_plan(max_time=8.0), SlowReset([[0.0, 0.0]]), tmp_path, handle_signals=True)
    assert time.monotonic() - began < 15.0
    kinds = [json.loads(line)["kind"] for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert "takeoff" not in kinds and kinds.index("interrupt") < kinds.index("links_closed")


def test_the_signal_relay_still_acts_on_later_signals_after_acting_on_one_failed(capfd):
    """Acting on a signal runs on the relay's thread; an exception there ended the thread, and
    every later Ctrl-C (the second one that cuts the motors included) went unheard."""
    from pursuit_mj.flight.bridge import _SignalRelay

    acted = []

    def act(signum):
        acted.append(signum)
        if len(acted) == 1:
            raise RuntimeError("the landing request failed")

    relay = _SignalRelay(act)
    relay.post(signal.SIGINT)
    assert wait_for(lambda: len(acted) == 1, 5.0)
    relay.post(signal.SIGQUIT)
    wait_for(lambda: len(acted) == 2, 5.0)
    relay.close()
    assert acted == [signal.SIGINT, signal.SIGQUIT]
    assert "acting on signal 2 failed: RuntimeError: the landing request failed" in capfd.readouterr().err


def _alarm(seconds: int):
    """SIGALRM after `seconds`, raising TimeoutError in the main thread (a test that would hang fails)."""
    def ring(signum, frame):
        raise TimeoutError(f"still waiting after {seconds} s")

    before = signal.signal(signal.SIGALRM, ring)
    signal.alarm(seconds)
    return before


def test_an_event_log_on_a_named_pipe_with_no_reader_is_refused_in_one_line_and_one_with_a_reader_is_written(tmp_path, capsys, monkeypatch):
    """`fly --events FIFO` with no program reading the pipe waited for a reader forever, before the
    flight (open() of a pipe blocks until its other end opens). Refused now, naming the pipe; a
    pipe with a reader takes the records as before."""
    from pursuit_cli import main
    from pursuit_mj.flight.events import EventLog

    import pursuit_mj.io_utils as io_utils

    monkeypatch.setattr(io_utils, "PIPE_READER_WAIT_S", 0.3)
    fifo = tmp_path / "events.pipe"
    os.mkfifo(fifo)
    before = _alarm(20)
    try:
        rc = main(["fly", "--flight", "example", "--policy", "heuristic", "--virtual", "--max-time", "1", "--events", str(fifo)])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, before)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert f"--events {fifo}: a named pipe that no program opened for reading within 0.3 s" in err, err
    assert fifo.exists() and not list(tmp_path.glob("*.jsonl"))
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    before = _alarm(20)
    try:
        monkeypatch.setattr(io_utils, "PIPE_READER_WAIT_S", 10.0)  # the reader's open() may come a little later
        log = EventLog(fifo)
        log.log("geofence", drone="p0")
        log.close()
        reader.join(10)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, before)
    assert json.loads(got[0])["kind"] == "geofence"


def test_an_emergency_stop_at_the_go_no_go_sends_no_take_off(tmp_path):
    """The operator hits the emergency stop while asked to confirm, then answers go: the flight
    ends as an emergency stop and no drone is ever sent a take-off (one sent after the motors
    were cut would lift the drones the operator just stopped)."""
    bridges = []

    def stop_then_go():
        bridges[0].emergency_stop("operator")
        return True

    result, events, fleet = fly_virtual(quick_plan(max_time=2.0), ScriptedTeam([[0.0, 0.0]]), tmp_path,
                                        on_bridge=bridges.append, confirm=stop_then_go)
    assert result.outcome == "emergency_stop", result
    assert not events.of_kind("takeoff")
    assert not any(r.kind == "takeoff" for i in range(fleet.plan.n_drones) for r in fleet.received(i))


def test_a_stop_signal_as_a_time_out_landing_begins_is_logged_and_kept_in_the_result(tmp_path):
    """A SIGTERM that came between the `land` event and the landing's first look went unlogged (the
    landing took it for the signal that began it), and a first stop signal during a landing for
    another reason left no trace in the result, so `fly` exited 0 where README.md has a command
    stopped by a signal exit 128 + its number. The landing goes on; the result keeps the signal."""
    held = {}

    def signal_as_landing_begins(record):
        if record["kind"] == "land":
            held["bridge"].interrupt("SIGTERM")  # what the signal relay does, at the worst moment

    result, events, fleet = fly_virtual(quick_plan(max_time=1.0), ScriptedTeam([[0.0, 0.0]]), tmp_path,
                                        sink=signal_as_landing_begins, on_bridge=lambda b: held.setdefault("bridge", b))
    assert result.outcome == "timeout" and result.landed, (result.outcome, result.reason)
    assert [r["during"] for r in events.of_kind("interrupt")] == ["landing"]
    assert result.interrupted_by == "SIGTERM"
    assert "emergency_stop" not in events.kinds() and down(fleet)


_FLIGHT_STOPPED_IN_GENERATED_CODE = """
import sys
from pathlib import Path
from flight_rehearsal import ScriptedTeam, fly_virtual, quick_plan

class StoppedInGeneratedCode(ScriptedTeam):
    def act(self, obs, spec):
        if self.calls >= 2:
            exec("raise KeyboardInterrupt")  # a Ctrl-C inside code made by exec
        return super().act(obs, spec)

result, events, fleet = fly_virtual(quick_plan(max_time=8.0), StoppedInGeneratedCode([[0.0, 0.0]]), Path(sys.argv[1]))
print(result.outcome, result.landed)
"""


def test_a_script_whose_flight_was_interrupted_ends_normally_not_by_sigint(tmp_path):
    """The bridge handles a Ctrl-C in its chase (everyone lands, the result says 'interrupted');
    one that left code run by exec() still ended the script by SIGINT once it finished (CPython
    keeps such an interrupt marked unhandled), so the script's caller saw -2 instead of 0."""
    import subprocess
    import sys
    from pathlib import Path

    from conftest import stop_signals_at_their_defaults

    tests = Path(__file__).resolve().parent
    env = dict(os.environ, MUJOCO_GL="egl", PYTHONPATH=os.pathsep.join([str(tests), str(tests.parent)]))
    out = subprocess.run([sys.executable, "-c", _FLIGHT_STOPPED_IN_GENERATED_CODE, str(tmp_path)], cwd=tests.parent,
                         capture_output=True, text=True, timeout=120, env=env, preexec_fn=stop_signals_at_their_defaults)
    assert (out.returncode, out.stdout.splitlines()[-1:]) == (0, ["interrupted True"]), out.stderr[-2000:]
