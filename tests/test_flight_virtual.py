"""The virtual Crazyflie speaks cflib's protocol, and whole flights run on it through real cflib.

No mock of cflib: every test connects with cflib's SyncCrazyflie over udp:// to virtual
drones backed by pursuit_mj's quadrotor physics.
"""

from __future__ import annotations

import copy
import math
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from flight_rehearsal import FAST, fly_virtual, kinds_in_order, quick_plan, quick_spec, wait_for
from pursuit_cli import main
from pursuit_mj.flight.board import StateBoard
from pursuit_mj.flight.events import read_events
from pursuit_mj.planar import rotate
from pursuit_mj.flight.links import CachedFactory, LinkSet
from pursuit_mj.flight.observe import EvaderPilot, FlightObserver
from pursuit_mj.flight.plan import load_plan, resolve_flight
from pursuit_mj.flight.spec import flight_from_dict
from pursuit_mj.flight.virtual import commander as cmd
from pursuit_mj.flight.virtual.fleet import VirtualFleet
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.planar import clip_norm
from pursuit_mj.recording.rrd_read import read_entities


@pytest.fixture
def two_drones():
    """A 1-vs-1 plan (p0 chases e0), flow decks."""
    data = quick_spec()
    data["drones"] = [data["drones"][0], data["drones"][3]]
    plan = resolve_flight(flight_from_dict(data, "two.yaml"))
    return plan


def test_cflib_connects_reads_params_streams_logs_and_caches_the_tocs(two_drones, tmp_path):
    plan = two_drones
    with VirtualFleet(plan, physics=FAST) as fleet:
        board = StateBoard(2)
        console: list[str] = []
        links = LinkSet(plan.names, fleet.uris, board, CachedFactory(tmp_path / "toc"), timeout=5.0)
        links[0].cf.console.receivedChar.add_callback(console.append)
        with links:
            assert wait_for(lambda: "virtual Crazyflie 0" in "".join(console), 2.0)
            assert links[0].param("deck.bcFlow2") == 1.0 and links[0].param("deck.bcLighthouse4") == 0.0
            assert links[0].param("no.such") is None
            links[0].set_param("commander.enHighLevel", 0, timeout=2.0)
            assert wait_for(lambda: not fleet.commander.hl_enabled[0], 2.0)
            links[0].set_param("commander.enHighLevel", 1, timeout=2.0)
            for link in links:
                link.start_logs(0.02, 0.05)
            assert wait_for(lambda: (board.snapshot().state_count >= 5).all() and (board.snapshot().health_count >= 3).all(), 5.0)
            snap = board.snapshot()
            truth = fleet.true_state()["pos"]
            # flow decks estimate from their start: the drones sit at their starts
            np.testing.assert_allclose(snap.pos[:, :2], 0.0, atol=1e-6)
            np.testing.assert_allclose(snap.pos[:, 2], truth[:, 2], atol=1e-5)
            assert 3.9 < snap.vbat[0, -1] < 4.2
        cached = sorted(p.name for p in (tmp_path / "toc").glob("*.json"))
        assert len(cached) == 2  # log and param TOCs, named by their CRC
        with LinkSet(plan.names, fleet.uris, StateBoard(2), CachedFactory(tmp_path / "toc"), timeout=5.0) as links:
            assert links[1].param("deck.bcFlow2") == 1.0  # the second connection works from the cache
        assert fleet.error is None


def _first_time(fleet, condition, timeout: float) -> float | None:
    """The virtual clock (s) at which `condition(state)` first held, polling the fleet; None if never."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with fleet.lock:
            state = {"source": fleet.commander.source.copy(), "motors": fleet.airframe.motors.copy(), "z": fleet.airframe.pos[:, 2], "time": fleet.time}
        if condition(state):
            return state["time"]
        time.sleep(0.005)
    return None


def _record_ticks(fleet) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """A list that the fleet fills, each tick, with (virtual clock s, source (D,), motors (D,)) as
    its commander computes them: the times of its switches, however late a test thread polls."""
    ticks = []
    compute = fleet.commander.compute

    def recorded(t, *args):
        out = compute(t, *args)
        ticks.append((t, fleet.commander.source.copy(), out[3].copy()))
        return out

    fleet.commander.compute = recorded
    return ticks


def _first_tick(ticks, condition, since: float) -> float | None:
    """The virtual clock (s) of the first recorded tick from `since` (s) on with condition(source,
    motors); None if none."""
    return next((t for t, source, motors in list(ticks) if t >= since and condition(source, motors)), None)


def test_virtual_firmware_watchdog_levels_then_stops_and_emergency_stop_cuts_and_locks(two_drones, tmp_path):
    plan = two_drones
    with VirtualFleet(plan, physics=FAST) as fleet:
        ticks = _record_ticks(fleet)
        with LinkSet(plan.names, fleet.uris, StateBoard(2), CachedFactory(tmp_path / "toc"), timeout=5.0) as links:
            for link in links:
                link.takeoff(0.4, 0.4)
            assert _first_time(fleet, lambda s: (s["z"] > 0.3).all() and (s["source"] == cmd.SRC_HL).all(), 5.0) is not None
            # drone 1: emergency stop -> motors off at once, it falls, it stays locked
            links[1].emergency_stop()
            assert _first_time(fleet, lambda s: not s["motors"][1], 1.0) is not None
            # drone 0: velocity setpoints for half a second, then silence
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                links[0].velocity((0.3, 0.0, 0.0))
                time.sleep(0.02)
            assert fleet.commander.source[0] == cmd.SRC_VELOCITY
            bits = links[1].cf.supervisor.read_bitfield()
            assert bits >> 6 & 1 and not bits >> 4 & 1  # locked, not flying
            links[1].takeoff(0.4, 0.4)  # a locked drone stays down
            assert _first_time(fleet, lambda s: not s["motors"][0], 5.0) is not None
            last = [r.t for r in fleet.received(0) if r.kind == "velocity"][-1]  # virtual clock
            # when the commander switched, not when this thread saw it (late on a loaded machine)
            levelled = _first_tick(ticks, lambda source, motors: source[0] == cmd.SRC_LEVEL, last)
            stopped = _first_tick(ticks, lambda source, motors: not motors[0], last)
            assert levelled is not None and 0.5 <= levelled - last <= 0.5 + 0.03
            assert stopped is not None and 2.0 <= stopped - last <= 2.0 + 0.03
            assert _first_time(fleet, lambda s: (s["z"] < 0.03).all() and not s["motors"].any(), 3.0) is not None  # both fell
            assert [r.kind for r in fleet.received(1)][-3:] == ["emergency_stop", "stop", "takeoff"]


def _replay_pursuers(plan, result):
    """Observations and commands the simulator's code gives for the estimates the bridge received."""
    observer = FlightObserver(plan.task, plan.layout, seed=0)
    team = HeuristicTeam.from_config(plan.task)
    team.reset(1)
    N = plan.n_pursuers
    starts = np.array([d.start for d in plan.drones])
    yaws = np.array([d.start_yaw for d in plan.drones])
    t = plan.transform
    out = []
    for step in result.steps:
        lab = starts + rotate(step.est_pos[:, :2], yaws)  # flow decks: from their start, at their start heading
        lab_v = rotate(step.est_vel[:, :2], yaws)
        pos = t.scale * rotate(lab - np.array(t.origin), -t.yaw)
        vel = t.scale * rotate(lab_v, -t.yaw)
        observer.update_captures(pos[:N], pos[N:])
        obs = observer.observe(pos[:N], vel[:N], pos[N:], vel[N:])
        actions = team.act(obs, observer.spec)[0]
        v_layout = clip_norm(actions * plan.task.pursuer_speed, plan.task.pursuer_speed)
        v_lab = rotate(v_layout, t.yaw) / t.scale
        out.append((pos, obs[0], actions, rotate(v_lab, -yaws[:N])))
    return out


def test_a_whole_virtual_flight_takes_off_chases_captures_lands_and_sends_what_the_simulator_would(tmp_path):
    # a rotated, scaled lab; one pursuer turned 90 degrees at its start; a target that only sits there
    spec = quick_spec(
        transform={"origin": [4.0, 0.0], "yaw": math.pi / 2, "scale": 1.25},
        max_time=12.0,
        safety={"min_separation": 0.2},  # below the capture distance 0.3 / 1.25 m
        drones=[
            {"name": "p0", "uri": "radio://0/80/2M/E7E7E7E701", "role": "pursuer", "start": [3.5, 0.4], "start_yaw": math.pi / 2},
            {"name": "p1", "uri": "radio://0/80/2M/E7E7E7E702", "role": "pursuer", "start": [3.5, 1.4]},
            {"name": "p2", "uri": "radio://0/80/2M/E7E7E7E703", "role": "pursuer", "start": [3.5, 2.4]},
            {"name": "t0", "uri": "radio://0/80/2M/E7E7E7E704", "role": "target", "start": [2.9, 1.4]},
        ],
    )
    plan = resolve_flight(flight_from_dict(spec, "whole.yaml"))
    result, events, fleet = fly_virtual(plan, HeuristicTeam.from_config(plan.task), tmp_path)
    assert result.outcome == "captured", (result.outcome, result.reason)
    assert kinds_in_order(events, "links_up", "preflight_ok", "takeoff", "airborne", "chase", "capture", "end_of_run", "land", "landed")
    assert result.landed and result.captures == 1 and len(result.steps) > 5
    final = fleet.true_state()
    assert (final["pos"][:, 2] < 0.03).all() and not final["motors"].any()
    assert not any(r.kind == "takeoff" for r in fleet.received(3))  # the target is never commanded
    for i in range(3):  # take-off and landing keep each drone's yaw (cflib's default turns it to 0)
        assert [r.values[3] for r in fleet.received(i) if r.kind in ("takeoff", "land")] == [1.0, 1.0]

    # the simulator's own observation and policy code, fed the same estimates, gives the same commands
    replay = _replay_pursuers(plan, result)
    N = plan.n_pursuers
    compared = 0
    for step, (pos, obs, actions, v_drone) in zip(result.steps, replay):
        np.testing.assert_allclose(step.pos, pos, atol=1e-9)
        np.testing.assert_allclose(step.obs, obs, atol=1e-6)
        np.testing.assert_allclose(step.actions, actions, atol=1e-9)
        fly = (step.mode[:N] == "velocity") & ~step.filtered[:N]
        np.testing.assert_allclose(step.sent[:N][fly, :2], v_drone[fly], atol=1e-9)
        compared += int(fly.sum())
    assert compared >= 2 * len(result.steps)
    # ... and what left the bridge is what each drone received (as float32 on the wire); a
    # decision late by more than 0.1 s has the last setpoint repeated (keepalive.py): runs of
    # one value count once
    def runs(values: np.ndarray) -> np.ndarray:
        return values[np.r_[True, (np.diff(values, axis=0) != 0).any(axis=1)]] if len(values) else values

    for i in range(N):
        got = runs(np.array([r.values[:3] for r in fleet.received(i) if r.kind == "velocity"]))
        sent = runs(np.array([s.sent[i] for s in result.steps if s.mode[i] == "velocity"]).astype(np.float32))
        assert got.shape == sent.shape
        np.testing.assert_allclose(got, sent.astype(np.float32), rtol=0, atol=1e-6)


def test_fly_virtual_on_the_command_line_writes_its_event_log_and_rerun_file(tmp_path, capsys):
    flight = tmp_path / "quick.yaml"
    flight.write_text(yaml.safe_dump(quick_spec(task={"evader_speed": 0.3})))
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    killed = tmp_path / f"f.unfinished-{int(dead.stdout)}.rrd"  # what a flight killed mid-way (kill -9) left
    killed.write_bytes(b"an earlier flight's episodes")
    rc = main(["fly", "--flight", str(flight), "--policy", "heuristic", "--virtual", "--max-time", "1.5",
               "--events", str(tmp_path / "f.jsonl"), "--rerun", str(tmp_path / "f.rrd")])
    out = capsys.readouterr().out
    assert f"rerun_unfinished_kept: path={killed}" in out and killed.read_bytes() == b"an earlier flight's episodes"
    assert sorted(p.name for p in tmp_path.glob("f.*.rrd")) == [killed.name]
    assert rc == 0 and "outcome: timeout" in out and "landed: yes (every commanded drone's last height estimate below 0.1 m)" in out
    records = read_events(tmp_path / "f.jsonl")
    times = [r["t"] for r in records]
    assert times == sorted(times)
    assert kinds_in_order([r["kind"] for r in records], "virtual_fleet", "links_up", "preflight_ok", "takeoff", "chase", "end_of_run", "land", "landed")
    steps = [r for r in records if r["kind"] == "step"]
    assert len(steps) >= 10 and len(steps[0]["pos"]) == 4
    # the evader was flown by the simulator's escape model: replay it from the logged states
    plan = load_plan(flight)
    pilot, observer = EvaderPilot(plan.task, 0), FlightObserver(plan.task, plan.layout, 0)
    for r in steps:
        pos, vel = np.array(r["pos"]), np.array(r["vel"])
        observer.update_captures(pos[:3], pos[3:])
        observer.observe(pos[:3], vel[:3], pos[3:], vel[3:])
        v = clip_norm(pilot.command(observer, pos[3:], vel[3:], pos[:3], vel[:3]), plan.task.evader_speed)
        np.testing.assert_allclose(r["wanted"][3], v[0], atol=1e-4)
    assert max(np.linalg.norm(r["wanted"][3]) for r in steps) > 0.1
    entities = read_entities(tmp_path / "f.rrd")
    assert {"/drones/p0", "/drones/e0/command", "/battery/p1", "/events", "/arena/border"} <= set(entities)
    assert entities["/drones/p0"].n_rows >= len(steps)
    texts = [t for row in entities["/events"].rows["TextLog:text"] for t in row]
    assert any(t.startswith("takeoff") for t in texts) and any(t.startswith("landed") for t in texts)


def test_fly_says_landed_only_when_every_drone_reports_a_height_near_the_floor(tmp_path, capsys):
    flight = tmp_path / "quick.yaml"
    flight.write_text(yaml.safe_dump(quick_spec()))
    rc = main(["fly", "--flight", str(flight), "--policy", "heuristic", "--virtual", "--max-time", "1.0",
               "--events", str(tmp_path / "f.jsonl"), "--fault", "freeze:p0@0.2"])
    out = capsys.readouterr().out
    assert rc == 0 and "outcome: timeout" in out
    assert "landed: no (last height estimates: p0 0.3" in out and "landed means below 0.1 m" in out  # its estimates stopped in the air


def test_fly_align_measures_a_rotated_scaled_transform_from_virtual_lighthouse_drones(tmp_path, capsys):
    spots = "0.5,0.625 1.75,0.625 1.875,4.0"  # the layout spots of configs/flight/lighthouse.yaml's starts
    out_file = tmp_path / "aligned.yaml"
    assert main(["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--virtual", "--window", "1.0", "--spots", spots, "--write", str(out_file)]) == 0
    out = capsys.readouterr().out
    assert "rms residual 0.0 mm" in out
    t = load_plan(out_file).transform
    assert t.yaw == pytest.approx(math.pi / 2, abs=1e-5) and t.scale == pytest.approx(1.25, abs=1e-5)
    np.testing.assert_allclose(t.origin, [4.2, 0.1], atol=1e-4)


def test_virtual_crazyflies_weigh_the_flight_tasks_drone_mass():
    """A flight file's task key drone_mass (say, decked drones of 35 g) makes the rehearsal's
    bodies that heavy, and their controller carries that weight: climbed to 0.5 m, the rotors
    hold 0.035 kg x g."""
    plan = quick_plan(task={"drone_mass": 0.035})
    fleet = VirtualFleet(plan, physics=FAST)
    try:
        airframe = fleet.airframe
        assert [airframe.model.body(f"{n}/body").mass[0] for n in airframe.ids.names] == [0.035] * plan.n_drones
        assert airframe.params["mass"] == 0.035
        on = np.ones(plan.n_drones, bool)
        for _ in range(300):  # 3 s
            airframe.step(0.01, np.zeros((plan.n_drones, 2)), np.full(plan.n_drones, 0.5), np.zeros(plan.n_drones), on)
        np.testing.assert_allclose(airframe.pos[:, 2], 0.5, atol=0.03)
        np.testing.assert_allclose(airframe.thrust.sum(1), 0.035 * 9.81, rtol=0.01)
    finally:
        fleet.stop()


def test_a_virtual_lab_whose_physics_diverges_says_so_in_mujocos_words_and_writes_no_log(tmp_path, monkeypatch):
    """MuJoCo resets a state gone bad (finite again, drones back at the origin): the step used to
    fly on from there, and MuJoCo's own handler wrote MUJOCO_LOG.TXT into the current folder."""
    from pursuit_mj.flight.virtual.airframe import Airframe

    monkeypatch.chdir(tmp_path)
    airframe = Airframe(1, 1, (0.0, 2.0), (0.0, 2.0), np.array([[0.5, 0.5], [1.5, 1.5]]))
    airframe.data.qvel[:] = 1e12
    on = np.ones(2, bool)
    with pytest.raises(FloatingPointError, match=r"virtual lab physics diverged \(MuJoCo warnings: BADQVEL; MuJoCo: Nan, Inf or huge value in QVEL"):
        airframe.step(0.01, np.zeros((2, 2)), np.full(2, 0.5), np.zeros(2), on)
    assert list(tmp_path.iterdir()) == []


def test_virtual_crazyflies_tilt_as_far_as_their_firmware_velocity_loop_allows():
    """The firmware's velocity loop tilts up to posCtlPid.rLimit / pLimit (20 deg by default); the
    virtual drones honour those parameters, so a rehearsal without the bridge's setting shows the
    faster reversals a real drone would fly."""
    plan = quick_plan()
    fleet = VirtualFleet(plan, physics=FAST)
    try:
        n = plan.n_drones
        assert [fw.params["posCtlPid.rLimit"] for fw in fleet.firmware] == [20.0] * n  # the firmware's default
        for fw in fleet.firmware[: n // 2]:
            fw.params["posCtlPid.rLimit"] = fw.params["posCtlPid.pLimit"] = 10.0
        fleet.apply_firmware_limits()  # what each tick of the running fleet does
        on, airframe = np.ones(n, bool), fleet.airframe
        for _ in range(200):  # up to 0.5 m first
            airframe.step(0.01, np.zeros((n, 2)), np.full(n, 0.5), np.zeros(n), on)
        push = np.tile([1.0, 0.0], (n, 1))
        for _ in range(30):  # 0.3 s at a 1 m/s command
            airframe.step(0.01, push, np.full(n, 0.5), np.zeros(n), on)
        q = airframe.quat
        tilt = np.degrees(np.arccos(np.clip(1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))  # body z from vertical
        assert (tilt[: n // 2] < 10.5).all() and (tilt[n // 2 :] > 14.0).all(), tilt
    finally:
        fleet.stop()


def fleet_limited_to(plan, degrees: float) -> VirtualFleet:
    """A virtual fleet of `plan` whose firmware limits roll and pitch to `degrees` each."""
    fleet = VirtualFleet(plan, physics=FAST)
    for fw in fleet.firmware:
        fw.params["posCtlPid.rLimit"] = fw.params["posCtlPid.pLimit"] = degrees
    fleet.apply_firmware_limits()
    return fleet


def test_virtual_crazyflies_limit_roll_and_pitch_each_as_their_firmware_does():
    """The firmware limits roll (posCtlPid.rLimit) and pitch (pLimit) each, not the tilt: pushed
    along a diagonal at 10 deg each, a virtual drone tilts its thrust up to 14 deg (a real one
    would), with neither roll nor pitch past 10. They flew a 10 deg tilt limit instead, so a
    rehearsal turned slower on a diagonal than the real drones would."""
    plan = quick_plan()
    fleet = fleet_limited_to(plan, 10.0)
    try:
        n = plan.n_drones
        on, airframe = np.ones(n, bool), fleet.airframe
        for _ in range(200):  # up to 0.5 m first
            airframe.step(0.01, np.zeros((n, 2)), np.full(n, 0.5), np.zeros(n), on)
        push = np.tile([1.0, 1.0], (n, 1)) / math.sqrt(2)
        worst_tilt, worst_axis = np.zeros(n), np.zeros(n)
        for _ in range(50):  # 0.5 s at a 1 m/s command
            airframe.step(0.01, push, np.full(n, 0.5), np.zeros(n), on)
            w, x, y, z = airframe.quat.T
            tilt = np.arccos(np.clip(1 - 2 * (x**2 + y**2), -1, 1))
            roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x**2 + y**2))
            pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1, 1))
            worst_tilt = np.maximum(worst_tilt, np.degrees(tilt))
            worst_axis = np.maximum(worst_axis, np.degrees(np.maximum(np.abs(roll), np.abs(pitch))))
        assert (worst_tilt > 13.0).all() and (worst_axis < 10.5).all(), (worst_tilt, worst_axis)
    finally:
        fleet.stop()


def test_the_bridge_sets_the_firmware_tilt_limit_to_the_simulators(tmp_path):
    """A policy learned with the simulator's 15 deg tilt limit flies real drones whose firmware
    allows 20 deg: the bridge sets posCtlPid.rLimit and pLimit of every commanded drone to the
    simulator's limit before take-off, and logs it."""
    from flight_rehearsal import ScriptedTeam
    from pursuit_mj.controller import ControllerGains

    plan = quick_plan(max_time=1.0)
    result, events, fleet = fly_virtual(plan, ScriptedTeam([[0.0, 0.0]]), tmp_path)
    assert result.outcome == "timeout" and result.landed, result
    limit = math.degrees(ControllerGains().max_tilt)
    for fw, commanded in zip(fleet.firmware, plan.commanded):
        want = limit if commanded else 20.0
        assert (fw.params["posCtlPid.rLimit"], fw.params["posCtlPid.pLimit"]) == pytest.approx((want, want))
    logged = events.of_kind("tilt_limit")
    assert len(logged) == 1 and logged[0]["degrees"] == pytest.approx(limit)
    assert kinds_in_order(events, "links_up", "tilt_limit", "preflight_ok", "takeoff")


def test_fly_virtual_flies_a_policy_of_ones_own_from_a_file(tmp_path, capsys):
    """--policy FILE.py:NAME reaches the flight as it reaches eval: the drones fly what its act() says."""
    team = tmp_path / "team.py"
    team.write_text("import numpy as np\n"
                    "class East:\n"
                    "    name = 'east'\n"
                    "    def __init__(self, config, seed): pass\n"
                    "    def reset(self, n_worlds, world_ids=None): pass\n"
                    "    def act(self, obs, spec): return np.tile([1.0, 0.0], obs.shape[:2] + (1,))\n")
    flight = tmp_path / "quick.yaml"
    flight.write_text(yaml.safe_dump(quick_spec(task={"evader_speed": 0.3})))
    rc = main(["fly", "--flight", str(flight), "--policy", f"{team}:East", "--virtual", "--max-time", "2.0",
               "--events", str(tmp_path / "f.jsonl")])
    assert rc == 0, capsys.readouterr().err
    steps = [r for r in read_events(tmp_path / "f.jsonl") if r["kind"] == "step"]
    wanted = np.array([r["wanted"][:3] for r in steps])  # (steps, pursuers, 2) m/s asked of the pursuers
    assert len(steps) >= 5 and np.all(wanted[..., 0] > 0.0) and np.allclose(wanted[..., 1], 0.0, atol=1e-6)


def test_fly_align_waits_for_the_estimators_and_refuses_a_drone_without_a_position_fix(tmp_path):
    """align averaged whatever the drones estimated: one that saw no base station (its Kalman
    variance never settles), or a window begun before the estimates converged, went into the fit."""
    from pursuit_mj.flight.align import align
    from pursuit_mj.flight.virtual.fleet import VirtualDrone

    spec = flight_from_dict(quick_spec(positioning="lighthouse", safety={"estimator_timeout": 1.0}), "rehearsal.yaml")
    plan = resolve_flight(spec)
    spots = [d.start for d in plan.drones]
    healthy = [VirtualDrone()] * plan.n_drones
    # time to spare for the healthy fleet (a loaded machine's virtual drones may send nothing for 0.2 s)
    patient = flight_from_dict(quick_spec(positioning="lighthouse", safety={"estimator_timeout": 5.0}), "rehearsal.yaml")
    with VirtualFleet(plan, healthy, physics=FAST) as fleet:
        fit, _ = align(patient, spots, uris=fleet.uris, factory=CachedFactory(tmp_path / "toc"), window=1.0)
    assert fit.rms < 1e-3
    blind = [VirtualDrone(), VirtualDrone(converges=False)] + [VirtualDrone()] * (plan.n_drones - 2)
    with VirtualFleet(plan, blind, physics=FAST) as fleet:
        with pytest.raises(ValueError, match=r"drone p1 \(udp://127.0.0.1:\d+\): its position estimate did not settle within 1 s "
                                             r"\(Kalman variances \[.*\] m\^2, above safety.estimator_variance 0.001\)"):
            align(spec, spots, uris=fleet.uris, factory=CachedFactory(tmp_path / "toc"), window=0.2)


def test_a_flight_recording_that_cannot_replace_its_file_is_kept_beside_it_under_a_name_saying_so(tmp_path):
    """A folder made under the name during the flight: the recording was left under its
    unfinished name, which the next recording then reported as one killed before it finished;
    now it is kept as f.new.rrd and the error, naming --rerun, says so."""
    from pursuit_mj.flight.rerun_log import FlightRecorder
    from pursuit_mj.io_utils import CannotWrite

    path = tmp_path / "f.rrd"
    recorder = FlightRecorder(path, quick_plan())
    recorder.log_event({"t": 0.5, "kind": "takeoff"})
    path.mkdir()
    with pytest.raises(CannotWrite, match=f"^--rerun {path}: cannot replace it \\(Is a directory\\); what was written is kept in {tmp_path / 'f.new.rrd'}$"):
        recorder.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.new.rrd", "f.rrd"]
    assert "/events" in read_entities(tmp_path / "f.new.rrd")


def test_virtual_crazyflies_limit_roll_and_pitch_along_the_axes_of_the_drone_they_stand_for():
    """The firmware turns the velocity loop's output into the drone's own frame by its yaw before
    it limits roll and pitch (position_controller_pid.c), but the airframe holds yaw 0 in the lab
    while the drone it stands for faces its start heading: a flow-deck drone set out at 45 deg
    was limited along the lab's axes, so pushed along the lab's x (its own diagonal) it tilted
    10 deg where the real one tilts 14, and along its own axis (the lab's diagonal) 14 where
    the real one tilts 10."""
    drones = [dict(d, start_yaw=math.pi / 4) for d in quick_spec()["drones"]]
    plan = quick_plan(drones=drones)
    fleet = fleet_limited_to(plan, 10.0)
    try:
        n = plan.n_drones
        on, airframe = np.ones(n, bool), fleet.airframe
        worst = {}
        for name, push in (("lab x", [1.0, 0.0]), ("own x", [1.0, 1.0])):
            for _ in range(200):  # still, at 0.5 m, first
                airframe.step(0.01, np.zeros((n, 2)), np.full(n, 0.5), np.zeros(n), on)
            command = np.tile(push, (n, 1)) / np.linalg.norm(push)
            worst[name] = np.zeros(n)
            for _ in range(50):  # 0.5 s at a 1 m/s command
                airframe.step(0.01, command, np.full(n, 0.5), np.zeros(n), on)
                x, y = airframe.quat[:, 1], airframe.quat[:, 2]
                worst[name] = np.maximum(worst[name], np.degrees(np.arccos(np.clip(1 - 2 * (x**2 + y**2), -1, 1))))
        assert (worst["lab x"] > 13.0).all() and (worst["own x"] < 10.5).all(), worst
    finally:
        fleet.stop()


def test_a_virtual_flight_whose_fleet_cannot_start_leaves_no_empty_log_or_folder_it_made(tmp_path, monkeypatch):
    """The event log is opened (its folder made) before the virtual fleet starts: a fleet that could
    not start (its ports taken) left new/x/e.jsonl, empty, and the folders made for it. A log
    that holds events, and one that was there before, stay."""
    from pursuit_mj.flight.session import run_flight

    def no_ports(self):
        raise OSError("address already in use")

    monkeypatch.setattr(VirtualFleet, "start", no_ports)
    log = tmp_path / "new" / "x" / "e.jsonl"
    with pytest.raises(OSError, match="address already in use"):
        run_flight(quick_plan(), policy_name="heuristic", virtual=True, events_path=log, handle_signals=False)
    assert list(tmp_path.iterdir()) == []
    kept = tmp_path / "kept.jsonl"
    kept.write_text("")
    with pytest.raises(OSError, match="address already in use"):
        run_flight(quick_plan(), policy_name="heuristic", virtual=True, events_path=kept, handle_signals=False)
    assert kept.is_file()


@pytest.mark.parametrize("fault, words", [
    ("freeze_estimates", "its other packets came but its state-estimate log stopped"),
    ("drop_link", "nothing at all came from it in that time (link down, or the drone off)"),
])
def test_fly_align_names_a_drone_that_goes_silent_in_the_window_and_says_what_to_do(tmp_path, monkeypatch, fault, words):
    """A drone whose estimates stop once the estimators settled (its log stream stalls, or its
    link drops) sent nothing to average: the error said only 'sent no position within 0.2 s';
    now it names the drone, its URI, which of the two happened and what to check before aligning again."""
    import pursuit_mj.flight.align as align_module

    spec = flight_from_dict(quick_spec(positioning="lighthouse", safety={"estimator_timeout": 1.0}), "rehearsal.yaml")
    plan = resolve_flight(spec)
    settle = align_module._wait_fixed
    with VirtualFleet(plan, physics=FAST) as fleet:
        def settle_then_silence(*args):
            settle(*args)
            if len(args) == 6:  # the wait before the window (within it a snapshot comes too): p1 goes silent now
                getattr(fleet, fault)(1)
                time.sleep(0.2)  # what was in flight has arrived before the window begins

        monkeypatch.setattr(align_module, "_wait_fixed", settle_then_silence)
        with pytest.raises(ValueError) as err:
            align_module.align(spec, [d.start for d in plan.drones], uris=fleet.uris, factory=CachedFactory(tmp_path / "toc"), window=0.2)
    message = str(err.value)
    assert message.startswith(f"drone p1 ({fleet.uris[1]}) sent no position during the 0.2 s measuring window (--window): "), message
    assert words in message and "then run align again" in message and "\n" not in message, message


def test_closing_the_links_does_not_wait_out_cflibs_one_second_packet_poll(two_drones, tmp_path):
    """Every flight ended a second after its drones landed: cflib's close_link waits for its
    packet thread, which polls the link for a packet once a second and only then sees it was
    stopped. Woken as the link closes, it ends at once; the links close as before (their packet
    threads have ended, a second connection works)."""
    plan = two_drones
    with VirtualFleet(plan, physics=FAST) as fleet:
        links = LinkSet(plan.names, fleet.uris, StateBoard(2), CachedFactory(tmp_path / "toc"), timeout=5.0)
        with links:
            for link in links:
                link.start_logs(0.02, 0.05)
            time.sleep(0.2)
            handlers = [link.cf.incoming for link in links]
            start = time.monotonic()
        took = time.monotonic() - start
        assert not any(h.is_alive() for h in handlers)
        assert took < 0.9, f"closing two links took {took:.2f} s: the poll's 1 s timeout, not the wake-up"  # 1.0 s before
        with LinkSet(plan.names, fleet.uris, StateBoard(2), CachedFactory(tmp_path / "toc"), timeout=5.0) as again:
            assert again[0].param("deck.bcFlow2") == 1.0
        assert fleet.error is None


def test_each_drone_command_reaches_the_drone_in_si_units_and_in_cflib_s_order(two_drones, tmp_path):
    """What DroneLink sends, as the drone receives it: a velocity setpoint with its yaw rate in
    deg/s (given in rad/s), a hover setpoint at the height, a take-off and a landing keeping the
    yaw (use_current_yaw), the landing after notify_setpoint_stop (which hands control back to the
    high-level commander: cflib's order), and the planner and the motors stopped after it."""
    plan = two_drones
    with VirtualFleet(plan, physics=FAST) as fleet:
        with LinkSet(plan.names, fleet.uris, StateBoard(2), CachedFactory(tmp_path / "toc"), timeout=5.0) as links:
            link = links[0]
            link.velocity((0.1, -0.2, 0.05), yaw_rate=math.pi / 4)
            link.hover(0.35)
            link.takeoff(0.4, 0.8)
            link.land(0.0, 1.5)
            link.stop_motors()
            kinds = ("velocity", "hover", "takeoff", "notify_stop", "land", "hl_stop", "stop")
            sent = lambda: [r.kind for r in fleet.received(0) if r.kind in kinds]  # noqa: E731
            assert wait_for(lambda: len(sent()) == len(kinds), 3.0), fleet.received(0)
            assert sent()[:5] == list(kinds[:5]) and set(sent()[5:]) == {"hl_stop", "stop"}, sent()  # the two stops in either order
    got = {r.kind: r.values for r in fleet.received(0)}
    np.testing.assert_allclose(got["velocity"], [0.1, -0.2, 0.05, 45.0], rtol=1e-6)
    np.testing.assert_allclose(got["hover"], [0.0, 0.0, 0.0, 0.35], rtol=1e-6)
    assert got["takeoff"][:2] == pytest.approx((0.4, 0.8)) and got["takeoff"][3] == 1.0
    assert got["land"][:2] == pytest.approx((0.0, 1.5)) and got["land"][3] == 1.0


def _started_fleets(monkeypatch) -> list:
    """Record every VirtualFleet that run_flight starts (the real start runs)."""
    fleets = []
    real_start = VirtualFleet.start

    def start(self):
        fleets.append(self)
        real_start(self)

    monkeypatch.setattr(VirtualFleet, "start", start)
    return fleets


def test_a_virtual_flight_that_ends_early_leaves_no_fault_to_fire_and_no_fleet_running(tmp_path, monkeypatch):
    """A chase interrupted long before its fault's time: once run_flight returns the virtual drones
    are stopped (their thread and sockets) and the fault's timer is cancelled, not left to fire
    into the finished flight (a 'fault_injected' after its 'landed', a drone of a stopped fleet)."""
    import threading

    from flight_rehearsal import ScriptedTeam
    from pursuit_mj.flight.session import run_flight

    fleets = _started_fleets(monkeypatch)
    timers_before = {t for t in threading.enumerate() if isinstance(t, threading.Timer)}
    result, events = run_flight(quick_plan(max_time=30.0), ScriptedTeam([[0.0, 0.0]], raise_at=2), virtual=True,
                                virtual_physics=FAST, faults=["drop_link:p1@25"], events_path=tmp_path / "e.jsonl",
                                handle_signals=False)
    assert result.outcome == "interrupted", (result.outcome, result.reason)
    assert len(fleets) == 1 and not fleets[0].running
    pending = lambda: [t for t in threading.enumerate() if isinstance(t, threading.Timer) and t not in timers_before]  # noqa: E731
    assert wait_for(lambda: not pending(), 1.0), pending()
    assert "fault_injected" not in events.kinds() and kinds_in_order(events, "chase", "landed", "links_closed"), events.kinds()


def test_a_virtual_flight_that_fails_after_its_fleet_started_stops_it_and_keeps_the_log_it_wrote(tmp_path, monkeypatch):
    """A failure once the virtual drones are up (here a callback of one's own): the fleet is
    stopped, and the new event log, which holds the fleet's record, is kept (only an empty new log
    is removed)."""
    from pursuit_mj.flight.session import run_flight

    fleets = _started_fleets(monkeypatch)

    def broken(bridge):
        raise RuntimeError("a callback that fails")

    log = tmp_path / "e.jsonl"
    with pytest.raises(RuntimeError, match="a callback that fails"):
        run_flight(quick_plan(), policy_name="heuristic", virtual=True, virtual_physics=FAST, faults=["freeze:p0@0.5"],
                   events_path=log, handle_signals=False, on_bridge=broken)
    assert len(fleets) == 1 and not fleets[0].running
    assert [r["kind"] for r in read_events(log)] == ["virtual_fleet"]


@pytest.mark.parametrize("border", ["polygon", "circle"])
def test_a_flight_recording_draws_the_fence_inside_a_polygon_or_circle_border_at_the_margin(border, tmp_path):
    """The recording's `arena/fence` was the arena's rectangle moved in by the margin whatever the
    border: in layout 2's octagon its corners (0.25, 0.25) stood outside the border, beyond the cut
    corner the real fence keeps drones 0.25 m inside, and in a circle arena it was a square. Each
    fence vertex now lies inside the border, the margin away from it (docs/flight.md "Records":
    the fence; rerun_log: the border moved in by the margin)."""
    from pursuit_mj.flight.rerun_log import FlightRecorder
    from pursuit_mj.geometry import border_distance, inside_boundary

    drones = copy.deepcopy(quick_spec()["drones"])
    if border == "circle":
        (tmp_path / "round.yaml").write_text(yaml.safe_dump({
            "name": "round", "arena": {"width": 3.6, "height": 3.6}, "boundary": {"circle": {"center": [1.8, 1.8], "radius": 1.8}},
            "obstacles": [], "spawn": {"pursuers": {"x": [1.0, 2.6], "y": [0.4, 0.9]}, "evaders": {"x": [1.0, 2.6], "y": [2.7, 3.2]}}}))
        layout = str(tmp_path / "round.yaml")
        for d, start in zip(drones, ([1.2, 0.6], [1.8, 0.6], [2.4, 0.6], [1.8, 3.0])):
            d["start"] = start
    else:
        layout = 2
        drones[3]["start"] = [1.8, 4.4]
    plan = resolve_flight(flight_from_dict(quick_spec(layout=layout, drones=drones, safety={"geofence_margin": 0.25}),
                                           str(tmp_path / "rehearsal.yaml")))
    path = tmp_path / "f.rrd"
    recorder = FlightRecorder(path, plan)
    recorder.close()
    strips = read_entities(path)["/arena/fence"].static["LineStrips3D:strips"]
    points = np.array([p[:2] for strip in strips for p in strip])
    assert inside_boundary(plan.layout, points).all(), points
    np.testing.assert_allclose(border_distance(points, plan.layout.border()), 0.25, atol=0.01)
