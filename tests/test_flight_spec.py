"""The flight file, frames, the transform fit and the safety filters: everything decided before a radio opens."""

from __future__ import annotations

import copy
import math
import socket

import numpy as np
import pytest
import yaml

from pursuit_mj.configio import ConfigError
from pursuit_mj.flight.frames import DroneFrames, LabTransform, fit_similarity
from pursuit_mj.flight.links import CachedFactory
from pursuit_mj.flight.plan import load_plan, resolve_flight
from pursuit_mj.flight.safety import Fence, altitude_speed, clamp_speed, keep_apart_and_inside, separate
from pursuit_mj.flight.session import parse_fault, run_flight
from pursuit_mj.flight.spec import flight_from_dict, link_key, load_flight
from pursuit_mj.layout import load_layout

EXAMPLE = "configs/flight/example.yaml"

BASE = {
    "layout": 0,
    "positioning": "lighthouse",
    "drones": [
        {"name": "p0", "uri": "radio://0/80/2M/E7E7E7E701", "role": "pursuer", "start": [1.0, 1.0]},
        {"name": "e0", "uri": "radio://0/80/2M/E7E7E7E702", "role": "evader", "start": [2.0, 4.0]},
        {"name": "p1", "uri": "radio://0/80/2M/E7E7E7E703", "role": "pursuer", "start": [2.5, 1.0]},
    ],
}


def flight(**changes) -> dict:
    data = copy.deepcopy(BASE)
    data.update(changes)
    return data


class RecordingFactory(CachedFactory):
    """cflib's own factory, counting links built: none may be built for a refused flight."""

    def __init__(self, cache_dir):
        super().__init__(cache_dir)
        self.built: list[str] = []

    def construct(self, uri):
        self.built.append(uri)
        return super().construct(uri)


def test_example_flight_resolves_with_pursuers_first_and_flow_frames_at_the_starts():
    plan = load_plan(EXAMPLE)
    assert plan.names == ["p0", "p1", "p2", "e0"] and plan.n_pursuers == 3 and plan.n_evaders == 1
    assert plan.task.control_dt == pytest.approx(0.1) and plan.task.flight_height == 0.5 and plan.task.random_obstacles == 0
    np.testing.assert_allclose(plan.frames.offset, [[0.8, 0.5], [1.8, 0.5], [2.8, 0.5], [1.8, 4.5]])
    assert plan.obs_spec.dim == plan.obs_spec.make(3, 1, plan.task.n_rays).dim


@pytest.mark.parametrize("rate", [1.0, 7.0, 20.0, 30.0, 100.0])
def test_any_decision_rate_in_range_makes_a_valid_task(rate):
    plan = resolve_flight(flight_from_dict(flight(decision_rate=rate), "f.yaml"))
    assert plan.dt == pytest.approx(1.0 / rate)


def test_drone_order_is_pursuers_first_whatever_the_file_order():
    plan = resolve_flight(flight_from_dict(flight(), "f.yaml"))
    assert plan.names == ["p0", "p1", "e0"]
    assert plan.commanded.tolist() == [True, True, True] and plan.flown_evaders.tolist() == [True]
    data = flight()
    data["drones"][1]["role"] = "target"
    plan = resolve_flight(flight_from_dict(data, "f.yaml"))
    assert plan.commanded.tolist() == [True, True, False] and plan.flown_evaders.tolist() == [False]


def test_uris_compare_as_cflib_reads_them():
    key = lambda uri: link_key(uri, "f.yaml")  # noqa: E731
    assert key("radio://0/080/2M/e7e7e7e701") == key("radio://1/80/2M/E7E7E7E701") == ("radio", 80, "2M", 0xE7E7E7E701)
    assert key("radio://0/80/2M") == key("radio://0/80/2M/E7E7E7E7E7") and key("radio://0/80/2M/E701") == key("radio://0/80/2M/000000E701")
    assert key("radio://0/80/2M/E7E7E7E701") != key("radio://0/90/2M/E7E7E7E701") != key("radio://0/90/1M/E7E7E7E701")
    assert key("udp://LocalHost:19850") == key("udp://localhost:19850") != key("udp://localhost:19851")
    assert key("usb://00") == key("usb://0")


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda d: d["drones"][0].update(uri="radio://0/180/2M/E7E7E7E701"), ["drones[0]", "uri", "channel 180"]),
        (lambda d: d["drones"][0].update(uri="bluetooth://cf1"), ["drones[0]", "uri", "not a Crazyflie URI"]),
        (lambda d: d["drones"][1].update(uri="radio://0/80/2M/E7E7E7E701"), ["drones[1]", "also used by drones[0]"]),
        (lambda d: d["drones"][1].update(uri="radio://0/80/2M/e7e7e7e701"), ["drones[1]", "also used by drones[0]", "address E7E7E7E701"]),
        (lambda d: d["drones"][1].update(uri="radio://0/080/2M/E7E7E7E701"), ["drones[1]", "also used by drones[0]", "channel 80"]),
        (lambda d: d["drones"][1].update(uri="radio://1/80/2M/E7E7E7E701"), ["drones[1]", "also used by drones[0]"]),  # another dongle, same drone
        (lambda d: (d["drones"][0].update(uri="radio://0/80/2M/E7E701"), d["drones"][1].update(uri="radio://0/80/2M/0000e7e701")),
         ["drones[1]", "also used by drones[0]", "address 0000E7E701"]),  # cflib pads short addresses with zeros
        (lambda d: (d["drones"][0].update(uri="radio://0/80/2M"), d["drones"][1].update(uri="radio://0/80/2M/E7E7E7E7E7")),
         ["drones[1]", "also used by drones[0]", "address E7E7E7E7E7"]),
        (lambda d: (d["drones"][0].update(uri="udp://LocalHost:19850"), d["drones"][1].update(uri="udp://localhost:19850")),
         ["drones[1]", "also used by drones[0]", "localhost:19850"]),
        (lambda d: d["drones"][0].update(uri="radio://0/80/2m/E7E7E7E701"), ["drones[0]", "uri", "data rate '2m'", "250K, 1M, 2M"]),
        (lambda d: d["drones"][0].update(name="p 0"), ["drones[0]", "name", "'p 0'", "--fault"]),
        (lambda d: d["drones"][0].update(name="p0@1"), ["drones[0]", "name", "'p0@1'"]),
        (lambda d: d["drones"][1].update(role="chaser"), ["drones[1]", "role", "'chaser'"]),
        (lambda d: d["drones"][0].pop("start"), ["drones[0]", "missing key 'start'"]),
        (lambda d: d.pop("positioning"), ["missing key 'positioning'"]),
        (lambda d: d.update(positionning="flow"), ["unknown key 'positionning'", "did you mean 'positioning'"]),
        (lambda d: d.update(transform={"scale": 0.0}), ["transform", "scale"]),
        (lambda d: d.update(transform={"origin": [0, 0], "yaw": "north"}), ["transform", "yaw"]),
        (lambda d: d.update(safety={"stale_hover": 2.0, "stale_land": 1.0}), ["stale_land", "longer than stale_hover"]),
        (lambda d: d.update(safety={"estimator_variance": 0.02}), ["fix_variance", "0.01 m^2", "above estimator_variance 0.02"]),
        (lambda d: d["drones"].__setitem__(1, dict(d["drones"][1], role="pursuer")), ["no drone has role 'evader' or 'target'"]),
    ],
)
def test_a_bad_flight_file_is_refused_naming_file_and_key(edit, words):
    data = flight()
    edit(data)
    with pytest.raises(ConfigError) as err:
        resolve_flight(flight_from_dict(data, "lab.yaml"))
    message = str(err.value)
    assert message.startswith("lab.yaml"), message
    for w in words:
        assert w in message, (w, message)


@pytest.mark.parametrize(
    "changes, words",
    [
        ({"transform": {"origin": [0, 0], "yaw": 0.5}, "lab": {"x": [0, 4], "y": [0, 5.2]}}, ["transform", "leaves the lab"]),
        ({"transform": {"origin": [0, 0], "scale": 0.5}, "lab": {"x": [0, 4], "y": [0, 5]}}, ["transform", "leaves the lab"]),
        # a far origin is printed as a number, not as 300 digits
        ({"transform": {"origin": [1e308, 0]}, "lab": {"x": [0, 4], "y": [0, 5.2]}}, ["transform", "lab x [1e+308, 1e+308]", "leaves the lab"]),
        ({"transform": {"origin": [5, 5]}, "lab": {"x": [0, 9], "y": [0, 11]}}, ["drone p0", "start", "outside the arena"]),
        ({"transform": {"origin": [5, 5]}}, ["drone p0", "start", "outside the lab"]),
        ({"transform": {"scale": 0.1}, "safety": {"min_separation": 3.5}}, ["min_separation", "no capture"]),
        ({"safety": {"min_separation": 0.29}, "transform": {"scale": 1.2}}, ["min_separation", "capture distance"]),
        ({"task": {"n_pursuers": 5}}, ["task", "n_pursuers", "set by the flight"]),
        ({"task": {"random_obstacles": 3}}, ["task", "random_obstacles", "none drawn at random"]),
        ({"task": {"fidelity": "point"}}, ["task", "'fidelity' means nothing in a flight"]),
        # the real loop's delay is the real one; at 7 Hz it was refused naming a controller_hz the flight set itself
        ({"task": {"command_latency": 0.05}}, ["task", "'command_latency' means nothing in a flight", "real"]),
        ({"task": {"command_latency": 0.05}, "decision_rate": 7}, ["task", "'command_latency' means nothing in a flight"]),
        ({"decision_rate": 0.5}, ["decision_rate", "out of range"]),
        # a geofence margin of zero or inside the task's collision clearance
        ({"safety": {"geofence_margin": 0.0}}, ["lab.yaml: safety: key 'geofence_margin'", "0 m leaves the fence no room", "any depth lands everyone"]),
        ({"safety": {"geofence_margin": 0.05}}, ["key 'geofence_margin'", "0.05 m is below the task's obstacle_clearance 0.1 m", "collision"]),
        # in a scaled lab the clearance is compared in lab metres: 0.1 layout m is 0.125 lab m at scale 0.8
        ({"safety": {"geofence_margin": 0.11}, "transform": {"scale": 0.8}}, ["0.11 m is below", "(0.125 m in the lab, scale 0.8)"]),
        ({"safety": {"geofence_margin": 0.12}, "task": {"obstacle_clearance": 0.15}}, ["0.12 m is below the task's obstacle_clearance 0.15 m"]),
    ],
)
def test_impossible_transforms_and_settings_are_refused(changes, words):
    with pytest.raises(ConfigError) as err:
        resolve_flight(flight_from_dict(flight(**changes), "lab.yaml"))
    for w in words:
        assert w in str(err.value), (w, str(err.value))


@pytest.mark.parametrize(
    "changes, words",
    [
        # a start far out, with the lab given or taken from the arena: refused before the geometry squares it
        ({"lab": {"x": [0, 4], "y": [0, 5.2]}, "drones": [dict(BASE["drones"][0], start=[1e308, 1.0])] + BASE["drones"][1:]},
         ["drone p0", "key 'start'", "[1e+308, 1.0] is outside the lab"]),
        ({"drones": BASE["drones"][:2] + [dict(BASE["drones"][2], start=[2.5, -1e308])]},
         ["drone p1", "key 'start'", "[2.5, -1e+308] is outside the lab"]),
        # a lab that big would let such a start in
        ({"lab": {"x": [-1e308, 1e308], "y": [0, 5.2]}, "drones": [dict(BASE["drones"][0], start=[1e308, 1.0])] + BASE["drones"][1:]},
         ["lab: key 'x'", "-1e+308 m in [-1e+308, 1e+308] is farther than 1000 m"]),
        ({"lab": {"x": [0, 4], "y": [0, 1e300]}}, ["lab: key 'y'", "1e+300 m in [0.0, 1e+300] is farther than 1000 m"]),
    ],
)
def test_a_far_start_or_lab_is_refused_clearly_without_an_overflow_warning(changes, words):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's RuntimeWarning: overflow encountered ... would fail here
        with pytest.raises(ConfigError) as err:
            resolve_flight(flight_from_dict(flight(**changes), "lab.yaml"))
    message = str(err.value)
    assert message.startswith("lab.yaml"), message
    for w in words:
        assert w in message, (w, message)


def test_fly_align_refuses_a_far_point_without_an_overflow_warning(capsys):
    import warnings

    from pursuit_cli import main

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    for flag, points, item in (("--lab", "1e308,0 1,0 0,1", "'1e308,0'"), ("--spots", "0.5,0.625 1.75,-1e308 1.875,4.0", "'1.75,-1e308'")):
        argv = ["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--spots", spots, "--lab", "1,1 2,1 1,3"]
        argv[argv.index(flag) + 1] = points
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{flag}: {item}: " in err and "e+308 m is farther than 1000 m" in err, err


def test_a_start_inside_a_virtual_obstacle_or_too_close_to_another_is_refused():
    data = flight(layout=1)  # a wall along y = 1.9 from x = 0 to 2.2
    data["drones"][0]["start"] = [1.0, 1.9]
    with pytest.raises(ConfigError, match="drone p0.*inside or touching a virtual obstacle"):
        resolve_flight(flight_from_dict(data, "f.yaml"))
    data = flight()
    data["drones"][2]["start"] = [1.1, 1.0]
    with pytest.raises(ConfigError, match="p0 and p1 start 0.100 m apart"):
        resolve_flight(flight_from_dict(data, "f.yaml"))


def test_a_refused_flight_file_touches_no_radio(tmp_path):
    bad = flight()
    bad["drones"][1]["role"] = "bystander"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    factory = RecordingFactory(tmp_path / "cache")
    with pytest.raises(ConfigError, match="bystander"):
        run_flight(path, policy_name="heuristic", factory=factory, events_path=tmp_path / "ev.jsonl")
    assert factory.built == [] and not (tmp_path / "ev.jsonl").exists()
    impossible = flight(transform={"origin": [0, 0], "yaw": 1.0}, lab={"x": [0, 3.6], "y": [0, 5.0]})
    path.write_text(yaml.safe_dump(impossible))
    with pytest.raises(ConfigError, match="leaves the lab"):
        run_flight(path, policy_name="heuristic", factory=factory)
    assert factory.built == []


def test_layout_files_are_found_beside_the_flight_file(tmp_path):
    layout = yaml.safe_load(open("configs/layouts/1_walls.yaml"))
    (tmp_path / "arena.yaml").write_text(yaml.safe_dump(layout))
    (tmp_path / "f.yaml").write_text(yaml.safe_dump(flight(layout="arena.yaml")))
    plan = load_plan(tmp_path / "f.yaml")
    assert plan.layout.name == "walls" and len(plan.layout.obstacles) == 2
    assert load_flight(tmp_path / "f.yaml").source == str(tmp_path / "f.yaml")


# ---------------------------------------------------------------------- frames and the fit


def test_lab_transform_round_trips_and_rotates_velocities():
    t = LabTransform((1.0, -2.0), math.pi / 2, 2.0)
    p = np.array([[1.0, -2.0], [1.0, -1.0], [3.0, -2.0]])
    q = t.to_layout(p)
    np.testing.assert_allclose(q, [[0, 0], [2, 0], [0, -4]], atol=1e-12)  # lab +y is layout +x
    np.testing.assert_allclose(t.to_lab(q), p, atol=1e-12)
    np.testing.assert_allclose(t.velocity_to_lab(t.velocity_to_layout(np.array([0.3, -0.1]))), [0.3, -0.1], atol=1e-12)
    f = DroneFrames(np.array([[1.0, 1.0]]), np.array([math.pi / 2]))
    np.testing.assert_allclose(f.to_lab(np.array([[1.0, 0.0]])), [[1.0, 2.0]], atol=1e-12)  # forward = lab +y
    np.testing.assert_allclose(f.velocity_to_drone(f.velocity_to_lab(np.array([[0.2, 0.1]]))), [[0.2, 0.1]], atol=1e-12)


def test_similarity_fit_recovers_a_transform_from_noisy_spots():
    rng = np.random.default_rng(3)
    truth = LabTransform((0.7, -0.4), 0.35, 1.25)
    spots = rng.uniform([0.3, 0.3], [3.3, 4.7], size=(5, 2))
    lab = truth.to_lab(spots) + rng.normal(0, 0.005, size=(5, 2))
    fit = fit_similarity(lab, spots)
    assert fit.transform.yaw == pytest.approx(0.35, abs=0.01)
    assert fit.transform.scale == pytest.approx(1.25, rel=0.01)
    np.testing.assert_allclose(fit.transform.origin, truth.origin, atol=0.02)
    assert fit.rms < 0.02 and fit.residuals.shape == (5,)
    with pytest.raises(ValueError, match="at least 2 spots"):
        fit_similarity(lab[:1], spots[:1])
    with pytest.raises(ValueError, match="coincide"):
        fit_similarity(np.ones((3, 2)), spots[:3])


# ---------------------------------------------------------------------- safety filters


def test_speed_clamp_keeps_direction_and_reports_who_was_clamped():
    v, clamped = clamp_speed(np.array([[0.3, 0.4], [0.1, 0.0]]), 0.25)
    np.testing.assert_allclose(v, [[0.15, 0.2], [0.1, 0.0]])
    assert clamped.tolist() == [True, False]


def test_the_fence_brakes_a_drone_driven_at_the_border_and_holds_it_at_the_margin():
    layout = load_layout(1)
    t = LabTransform((0.5, 0.5), 0.0, 1.0)
    fence = Fence(layout, t, margin=0.25, lookahead=0.5, breach=0.15)
    p = t.to_lab(np.array([[1.8, 2.5], [3.0, 1.0]]))  # in the middle; near the right border
    v_push = np.array([[0.0, 0.0], [0.5, 0.2]])  # the second one drives at the right border
    dt, lowest = 0.02, np.inf
    for _ in range(400):
        v, braking, clearance = fence.filter(v_push, p)
        p = p + v * dt
        lowest = min(lowest, fence.clearance(p)[1])
    assert braking[1] and not braking[0]
    assert 0.22 < lowest and fence.clearance(p)[1] == pytest.approx(0.25, abs=0.02)
    assert p[1, 1] > 1.0 + 0.5 + 1.0  # it slid along the border
    # inside the margin it is pushed back out; beyond the border by breach_distance, or in a
    # virtual obstacle at any depth (a 0.05 m wall is thinner than breach_distance), is a breach
    v, _, c = fence.filter(np.zeros((1, 2)), t.to_lab(np.array([[3.5, 1.0]])))
    assert v[0, 0] < -0.1 and c[0] == pytest.approx(0.1)
    assert fence.breached(t.to_lab(np.array([[3.9, 1.0], [3.7, 1.0], [1.0, 1.9], [1.0, 1.87]]))).tolist() == [True, False, True, False]


def test_the_fence_keeps_drones_out_of_virtual_obstacles():
    layout = load_layout(1)  # wall from (0, 1.9) to (2.2, 1.9)
    fence = Fence(layout, LabTransform(), margin=0.2, lookahead=0.5, breach=0.15)
    p = np.array([[1.0, 1.2]])
    for _ in range(300):
        v, _, _ = fence.filter(np.array([[0.0, 0.5]]), p)
        p = p + v * 0.02
    assert p[0, 1] == pytest.approx(1.9 - 0.025 - 0.2, abs=0.02)
    assert fence.clearance(np.array([[1.0, 1.9]]))[0] == pytest.approx(-0.025)  # inside the wall: negative


def test_the_fence_judges_a_thin_wall_from_the_drones_own_side_never_pushing_it_through():
    """Judged at its predicted point alone, a drone whose prediction passed the middle of a
    0.05 m wall was nearest the wall's far side and was pushed on, through the wall."""
    fence = Fence(load_layout(1), LabTransform(), margin=0.2, lookahead=0.5, breach=0.15)  # wall y 1.875-1.925, x 0-2.2
    y = np.linspace(1.70, 1.87, 18)
    p = np.column_stack([np.full_like(y, 0.8), y])
    ahead = p + np.array([0.0, 0.3]) * 0.4  # asking +0.3 m/s, prediction 0.4 s on: up to 0.12 m into or past the wall
    v, _, braking, clearance = keep_apart_and_inside(np.tile([0.0, 0.3], (len(y), 1)), p, fence, 0.25, 0.5, np.ones(len(y), bool), ahead)
    assert braking.all() and (v[:, 1] < 0).all()  # every one backs off ...
    assert (np.diff(v[:, 1]) < 0).all()  # ... the harder the further its path goes into or past the wall
    assert clearance[-1] == pytest.approx(1.875 - 1.99, abs=0.005)  # measured from its side: 0.115 m beyond the near face
    # a drone already past the wall is judged from its side too: it may fly on, away from the wall
    v, _ = fence.filter(np.array([[0.0, 0.3]]), np.array([[0.8, 2.2]]), np.array([[0.8, 2.32]]))[:2]
    assert v.tolist() == [[0.0, 0.3]]
    # flying at it too fast to stop short (1 m/s from 0.3 m), with a lagging response: turned back, never across
    p, vel, top = np.array([[0.8, 1.575]]), np.array([[0.0, 1.0]]), 0.0
    for _ in range(100):
        cmd, _, _ = fence.filter(np.array([[0.0, 1.0]]), p, p + vel * 0.4)
        for _ in range(10):
            vel = vel + (cmd - vel) * 0.01 / 0.3
            p = p + vel * 0.01
            top = max(top, p[0, 1])
    assert top < 1.875 and p[0, 1] == pytest.approx(1.875 - 0.2, abs=0.02)


def test_a_path_between_two_estimates_that_meets_a_virtual_obstacle_is_a_crossing():
    fence = Fence(load_layout(1), LabTransform(), margin=0.2, lookahead=0.5, breach=0.15)
    before = np.array([[0.8, 1.85], [0.8, 1.5], [2.5, 1.85], [np.nan, np.nan], [0.8, 1.88]])
    after = np.array([[0.8, 1.95], [0.8, 1.6], [2.5, 1.95], [0.8, 1.95], [0.8, 1.88]])
    # across the wall; short of it; beside its end; no previous estimate; still
    assert fence.crossed(before, after).tolist() == [True, False, False, False, False]


def test_the_fence_holds_a_drone_sliding_into_a_corner_at_both_margins():
    """Braking toward the nearest wall alone let a drone sliding along one margin reach the
    other wall at full speed (to 0.07 m of it, with a 0.2 m margin)."""
    fence = Fence(load_layout(0), LabTransform(), margin=0.2, lookahead=0.5, breach=0.15)  # border x 0-3.6, y 0-5
    p = np.array([[1.0, 0.22]])
    for _ in range(400):
        v, _, _ = fence.filter(np.array([[-0.7, -0.05]]), p)
        p = p + v * 0.02
        assert p[0, 0] > 0.2 - 0.02 and p[0, 1] > 0.2 - 0.02
    assert p[0] == pytest.approx([0.2, 0.2], abs=0.03)  # held in the corner of the margins


def test_fence_and_separation_are_kept_together_not_one_after_the_other():
    """p0 inside the south margin must back out north, but p1 sits at min_separation to its
    north-east: the fence alone sends p0 north, toward p1; the joint solve sends it north-west."""
    fence = Fence(load_layout(0), LabTransform(), margin=0.2, lookahead=0.5, breach=0.15)
    d = 0.25
    p = np.array([[1.0, 0.10], [1.0 + d / math.sqrt(2), 0.10 + d / math.sqrt(2)], [1.8, 3.0]])
    movable = np.array([True, True, False])
    v, separating, fencing, clearance = keep_apart_and_inside(np.zeros((3, 2)), p, fence, d, 0.5, movable)
    toward_p1 = (p[1] - p[0]) / d
    assert float(v[0] @ toward_p1) <= 1e-9  # no closer to p1 ...
    assert v[0, 1] >= (0.2 - 0.10) / 0.5 - 1e-9  # ... while backing out of the margin as fast as the fence asks
    assert fencing.tolist() == [True, False, False] and clearance[0] == pytest.approx(0.10)
    assert v[2].tolist() == [0.0, 0.0]  # not ours: never moved
    alone, _, _ = fence.filter(np.zeros((3, 2)), p)
    assert float(alone[0] @ toward_p1) > 0.1  # what applying the fence last did


def test_the_separation_guard_stops_two_drones_flying_at_each_other():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 5.0]])
    movable = np.array([True, True, False])
    closest = np.inf
    for _ in range(300):
        v, changed = separate(np.array([[0.4, 0.0], [-0.4, 0.0], [0.0, 0.0]]), p, 0.25, 0.5, movable)
        p = p + v * 0.02
        closest = min(closest, np.linalg.norm(p[0] - p[1]))
    assert changed[:2].all() and not changed[2]
    assert 0.24 < closest < 0.3
    # a drone we do not command is a hazard but never moved
    v, changed = separate(np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]), np.array([[0.0, 0.0], [0.1, 0.0], [5.0, 5.0]]), 0.25, 0.5, np.array([True, False, False]))
    assert v[0, 0] < 0 and v[1, 0] == 0.0
    # two drones at one spot: no direction to part them along, but the log must say they are too close
    _, changed = separate(np.array([[0.3, 0.0], [0.0, 0.0]]), np.zeros((2, 2)), 0.5, 0.5, np.array([True, True]))
    assert changed.all()


def test_altitude_speed_holds_the_height_within_the_vertical_limit():
    vz = altitude_speed(np.array([0.2, 0.5, 0.9]), 0.5, 1.5, 0.3)
    np.testing.assert_allclose(vz, [0.3, 0.0, -0.3])


def test_faults_parse_with_drone_names_and_values():
    plan = load_plan(EXAMPLE)
    f = parse_fault("battery:e0@4.5=3.1", plan)
    assert (f.kind, f.drone, f.at, f.value) == ("battery", 3, 4.5, 3.1)
    assert parse_fault("drop_link:p1@.5", plan).at == 0.5 and parse_fault("battery:e0@3.=3", plan).value == 3.0
    for bad, words in (("explode:p0@1", "unknown fault"), ("drop_link:p9@1", "no drone named 'p9'"), ("battery:p0@1", "needs a voltage"), ("freeze:p0@2=3", r"'freeze' takes no value \(freeze:p0@2\)"), ("p0", "expected KIND"),
                       ("drop_link:p0@1.2.3", "'drop_link:p0@1.2.3': expected KIND"), ("battery:e0@4=.", "'battery:e0@4=.': expected KIND")):
        with pytest.raises(ValueError, match=words):
            parse_fault(bad, plan)
    with pytest.raises(ValueError, match=r"--fault 'freeze:p0@90': 90 s into the chase is not before its end \(max time 90 s\); "
                                         r"the fault would never happen"):
        parse_fault("freeze:p0@90", plan)  # the example's max_time is 90 s
    with pytest.raises(ValueError, match=r"'lose_fix:p0@2': 'lose_fix' rehearses a Lighthouse or Loco drone .* flow decks"):
        parse_fault("lose_fix:p0@2", plan)  # the example flies flow decks
    lighthouse = load_plan("configs/flight/lighthouse.yaml")
    assert parse_fault(f"lose_fix:{lighthouse.names[0]}@2", lighthouse).kind == "lose_fix"


def test_keys_cut_the_motors_or_land_and_other_keys_do_nothing():
    import os
    import time

    from pursuit_mj.flight.keys import KeyWatcher

    calls = []
    r, w = os.pipe()
    with KeyWatcher(lambda: calls.append("estop"), lambda: calls.append("land"), r):
        for key in (b"x", b"l", b" ", b"E"):
            os.write(w, key)
            time.sleep(0.15)
    os.close(w)
    os.close(r)
    assert calls == ["land", "estop", "estop"]


def test_fly_align_from_given_lab_points_prints_and_writes_the_transform(tmp_path, capsys):
    from pursuit_cli import main

    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    lab = truth.to_lab(spots) + np.array([[0.004, 0.0], [0.0, -0.003], [0.002, 0.002]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    out = tmp_path / "aligned.yaml"
    rc = main(["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--lab", fmt(lab), "--spots", fmt(spots), "--write", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "transform:" in printed and "rms residual" in printed
    t = load_plan(out).transform
    assert t.yaw == pytest.approx(math.pi / 2, abs=0.01) and t.scale == pytest.approx(1.25, rel=0.01)
    assert main(["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--lab", "1,1 2,2", "--spots", fmt(spots)]) == 2
    assert "--lab: 2 points for the flight's 3 drones" in capsys.readouterr().err


@pytest.mark.parametrize("lab, window, expected", [
    ("1,1 1,1 1,1", "1", "--lab: the lab positions coincide"),
    ("1,1 1.01,1 3,3", "1", "--lab: drones p0 and p1 stand 0.010 m apart in the lab"),
    ("1,1 2,2 nan,3", "1", "--lab: 'nan,3' is not a point x,y"),
    (None, "0", "--window 0.0: expected seconds in (0, 60]"),
    (None, "-1", "--window -1.0: expected seconds in (0, 60]"),
])
def test_fly_align_names_the_flag_of_bad_lab_points_or_window(capsys, lab, window, expected):
    from pursuit_cli import main

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    argv = ["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--spots", spots, "--window", window]
    argv += ["--lab", lab] if lab else ["--virtual"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert expected in err and "--spots" not in err.split("error:")[1], err
    assert main(["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--spots", spots + " 3,3", "--lab", "1,1 2,2 3,1 4,4"]) == 2
    assert "--spots: 4 spots for the flight's 3 drones" in capsys.readouterr().err


def test_fly_align_does_not_write_a_transform_the_flight_cannot_resolve_with(tmp_path, capsys):
    from pursuit_cli import main

    far = LabTransform((9.0, 9.0), 0.0, 1.0)  # the arena moved out of the lab
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    out = tmp_path / "aligned.yaml"
    rc = main(["fly", "align", "--flight", "configs/flight/lighthouse.yaml", "--lab", fmt(far.to_lab(spots)), "--spots", fmt(spots),
               "--write", str(out)])
    assert rc == 2 and not out.exists()
    err = capsys.readouterr().err
    assert "the measured transform does not make a valid flight" in err and "which leaves the lab" in err, err


def test_flight_set_overrides_take_a_section_and_a_repair_as_the_task_commands_do():
    """fly's --set built the task after each one and put a mapping in place of its section:
    --set evader={panic_distance: 2} reset the flight file's other evader keys to their defaults, and
    --set evader.panic_distance=4.5 --set evader.calm_distance=5 was refused at the first one."""
    spec = flight_from_dict(flight(task={"evader": {"calm_distance": 4.0}}), "lab.yaml")
    evader = resolve_flight(spec, ["evader={panic_distance: 2}"]).task.evader
    assert (evader.panic_distance, evader.calm_distance) == (2.0, 4.0)
    evader = resolve_flight(spec, ["evader.panic_distance=4.5", "evader.calm_distance=5"]).task.evader
    assert (evader.panic_distance, evader.calm_distance) == (4.5, 5.0)
    with pytest.raises(ConfigError, match=r"^--set evader.panic_distance=4.5: key 'evader': evader.calm_distance 4.0 must exceed"):
        resolve_flight(spec, ["evader.panic_distance=4.5"])
    # the flight file's own task keys, completed by a --set
    spec = flight_from_dict(flight(task={"evader": {"panic_distance": 3.5}}), "lab.yaml")
    assert resolve_flight(spec, ["evader.calm_distance=5"]).task.evader.calm_distance == 5.0
    with pytest.raises(ConfigError, match=r"^lab.yaml: task: key 'evader': evader.calm_distance 3.0 must exceed"):
        resolve_flight(spec, ["evader_speed=0.5"])


def test_fly_check_and_bad_command_lines_fail_with_one_clear_line(capsys):
    from pursuit_cli import main

    assert main(["fly", "check", "--flight", EXAMPLE]) == 0
    out = capsys.readouterr().out
    assert "no radio was touched" in out and "warning" not in out
    assert main(["fly", "check", "--flight", EXAMPLE, "--set", "evader_speed=0.9"]) == 0
    assert "warning: the evaders' task speed 0.9 m/s is 0.9 m/s in the lab, above the safety limit" in capsys.readouterr().out
    assert main(["fly", "--flight", EXAMPLE]) == 2
    assert "exactly one of --policy" in capsys.readouterr().err
    assert main(["fly", "--flight", EXAMPLE, "--model", "no/such/best.pt"]) == 2
    assert "--model no/such/best.pt: no such checkpoint file" in capsys.readouterr().err
    assert main(["fly", "--flight", EXAMPLE, "--policy", "genius"]) == 2
    assert "unknown policy" in capsys.readouterr().err
    assert main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--fault", "drop_link:p0@1"]) == 2
    assert "virtual drones only" in capsys.readouterr().err
    assert main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--fault", "drop_link:zz@1"]) == 2
    assert "no drone named 'zz'" in capsys.readouterr().err


@pytest.mark.parametrize("events", ["notes.yaml", EXAMPLE])
def test_fly_refuses_a_bad_event_log_before_it_prints_the_flight_plan(tmp_path, capsys, events):
    """`fly --events X.yaml` printed the whole flight plan and the keys' help, then refused the
    file as no event log (or as the flight file itself): a refusal comes first, alone."""
    from pursuit_cli import main

    if events == "notes.yaml":
        events = tmp_path / events
        events.write_text("notes: mine\n")
    assert main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--events", str(events)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1, captured
    assert captured.err.startswith(f"pursuit-mj fly: error: --events {events}: "), captured.err


@pytest.mark.parametrize("flag, value, said", [
    ("--events", "/dev/new.jsonl", "--events path /dev/new.jsonl: a name in /dev"),
    ("--rerun", "made/flight.txt", "--rerun made/flight.txt: expected a file name ending in .rrd"),
])
def test_fly_refuses_an_events_or_rerun_path_it_cannot_write_before_it_prints_the_flight_plan(tmp_path, capsys, monkeypatch,
                                                                                             flag, value, said):
    """Since e2e8cdf a --events file that is no event log is refused before the plan; one that cannot
    be written (a name in /dev no device holds) or a --rerun name that is no .rrd still came after
    the whole plan and the keys' help, which run_flight printed nothing between. Refused first
    now, alone, and no folder made for --events (made/) is left behind."""
    from pathlib import Path

    from pursuit_cli import main

    flight = str(Path(EXAMPLE).resolve())
    monkeypatch.chdir(tmp_path)
    events = ["--events", "made/f.jsonl"] if flag == "--rerun" else []
    assert main(["fly", "--flight", flight, "--policy", "heuristic", "--virtual", *events, flag, value]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and len(captured.err.splitlines()) == 1, captured
    assert captured.err.startswith(f"pursuit-mj fly: error: {said}"), captured.err
    assert list(tmp_path.iterdir()) == []


def test_the_speed_warning_is_about_flown_roles_only_a_target_is_flown_by_someone_else(capsys):
    from pursuit_cli import main

    assert main(["fly", "check", "--flight", "configs/flight/lighthouse.yaml"]) == 0  # pursuers and a target: no evader flown
    out = capsys.readouterr().out
    assert "warning" not in out
    # the plan gave 'evaders 0.6 m/s' here too, a speed nothing in this flight flies at
    assert "  speeds: pursuers 0.3 m/s (layout), the target flown by someone else; safety limit 0.4 m/s (lab)\n" in out
    assert main(["fly", "check", "--flight", EXAMPLE]) == 0
    assert "  speeds: pursuers 0.3 m/s, evaders 0.6 m/s (layout); safety limit 0.7 m/s (lab)\n" in capsys.readouterr().out
    data = flight(safety={"max_speed": 0.4, "geofence_margin": 0.25})
    data["drones"][1]["role"] = "target"
    assert resolve_flight(flight_from_dict(data, "lab.yaml")).warnings == ()
    data["drones"][1]["role"] = "evader"
    [warning] = resolve_flight(flight_from_dict(data, "lab.yaml")).warnings
    assert warning.startswith("the evaders' task speed 0.6 m/s is 0.6 m/s in the lab, above the safety limit 0.4 m/s")


def test_flight_observations_equal_the_simulators_for_the_same_states():
    from pursuit_mj.config import default_config
    from pursuit_mj.env import PursuitEnv
    from pursuit_mj.flight.observe import FlightObserver
    from pursuit_mj.heuristic import HeuristicTeam

    config = default_config(fidelity="point", layout=1, random_obstacles=0, field_of_view=2.0, perception_radius=1.5)
    env = PursuitEnv(config, n_worlds=1, seed=5)
    team = HeuristicTeam.from_config(config)
    obs = env.reset()
    observer = FlightObserver(config, env.world_layouts[0])
    N = config.n_pursuers
    compared = 0
    for _ in range(25):
        pos, vel = env.physics.positions()[0, :, :2], env.physics.velocities()[0, :, :2]
        observer.update_captures(pos[:N], pos[N:])
        np.testing.assert_array_equal(observer.observe(pos[:N], vel[:N], pos[N:], vel[N:]), obs)
        compared += 1
        obs, _, terminated, truncated, _ = env.step(team.act(obs, env.obs_spec))
        if terminated[0] or truncated[0]:
            break
    assert compared >= 10
    assert not np.all(observer.heading == np.pi / 2)  # headings followed the motion, as in the simulator


@pytest.mark.parametrize("path, value, words", [
    (("drones", 0, "start_yaw"), 90.0, "start_yaw"),  # degrees where radians are meant
    (("transform", "yaw"), -180.0, "yaw"),
    (("safety", "battery_samples"), 50, "battery_samples"),  # the board keeps 16 readings
])
def test_flight_values_out_of_their_range_are_refused_naming_the_key(path, value, words):
    from flight_rehearsal import QUICK

    data = copy.deepcopy(QUICK)
    node = data
    for key in path[:-1]:
        node = node.setdefault(key, {}) if isinstance(key, str) else node[key]
    node[path[-1]] = value
    with pytest.raises(ConfigError, match=words):
        flight_from_dict(data, "test.yaml")


@pytest.mark.parametrize("changes, words", [
    ({"name": "../../etc/x"}, "not a plain label"),
    ({"safety": {"min_separation": 0.0}}, "min_separation"),  # would switch the separation guard off
    ({"safety": {"link_timeout": 1e6}}, "link_timeout"),  # would never notice a lost link
    ({"safety": {"breach_distance": 50.0}}, "breach_distance"),
])
def test_values_that_would_switch_a_guard_off_or_write_elsewhere_are_refused(changes, words):
    from flight_rehearsal import QUICK

    data = copy.deepcopy(QUICK)
    for key, value in changes.items():
        data[key] = {**data.get(key, {}), **value} if isinstance(value, dict) else value
    with pytest.raises(ConfigError, match=words):
        flight_from_dict(data, "test.yaml")


@pytest.mark.parametrize("separation", [0.1, 0.12, 0.137])
def test_a_separation_guard_that_lets_two_crazyflies_touch_is_refused(separation):
    """Drone centres closer than DRONE_CONTACT_DISTANCE (0.137 m, where the simulator counts a
    collision) put two real Crazyflies' propellers into each other: the guard would hold them there."""
    from flight_rehearsal import quick_spec

    with pytest.raises(ConfigError, match=r"rehearsal.yaml: safety: key 'min_separation'.*0.137"):
        flight_from_dict(quick_spec(safety={"min_separation": separation}), "rehearsal.yaml")
    flight_from_dict(quick_spec(safety={"min_separation": 0.15}), "rehearsal.yaml")


@pytest.mark.parametrize("height, tolerance", [(0.15, None), (0.2, None), (0.3, 0.25)])
def test_a_flight_height_the_take_off_check_cannot_tell_from_the_floor_is_refused(height, tolerance):
    """After take-off every drone must be within height_tolerance of the flight height; where
    that band reaches below LANDED_HEIGHT, a drone that never left the floor passes (seen on
    virtual drones: at 0.15 m a drone that missed its take-off, at 0.012 m, was logged airborne)."""
    from flight_rehearsal import quick_spec

    safety = {} if tolerance is None else {"height_tolerance": tolerance}
    with pytest.raises(ConfigError, match=r"rehearsal.yaml: key 'flight_height'.*height_tolerance.*landed"):
        flight_from_dict(quick_spec(flight_height=height, safety=safety), "rehearsal.yaml")
    flight_from_dict(quick_spec(flight_height=0.25), "rehearsal.yaml")  # 0.25 - 0.15 m: a drone on the floor fails the check


# ---------------------------------------------------------------------- the geofence margin and the starts


def _start(data: dict, i: int, xy) -> dict:
    data["drones"][i]["start"] = list(xy)
    return data


def margin_warnings(plan) -> list[str]:
    """The plan's warnings about the geofence margin (BASE also warns that its evader is slowed to max_speed)."""
    return [w for w in plan.warnings if "geofence_margin" in w]


def test_a_geofence_margin_shorter_than_the_braking_distance_is_warned_about():
    # defaults: 0.5 m/s (max_speed; the evader asks 0.6) * (0.1 s decision + 0.3 s response) = 0.2 m = the margin
    plan = resolve_flight(flight_from_dict(flight(), "lab.yaml"))
    assert plan.braking_distance == pytest.approx(0.2) and margin_warnings(plan) == []
    plan = resolve_flight(flight_from_dict(flight(safety={"max_speed": 0.7}), "lab.yaml"))  # the evader's 0.6 m/s now flies
    assert plan.fastest_command == pytest.approx(0.6) and plan.braking_distance == pytest.approx(0.24)
    [warning] = margin_warnings(plan)
    for w in ["safety.geofence_margin 0.2 m", "braking distance 0.240 m", "0.6 m/s", "response_time 0.3 s"]:
        assert w in warning, (w, warning)
    assert resolve_flight(flight_from_dict(flight(safety={"max_speed": 0.7, "geofence_margin": 0.25}), "lab.yaml")).warnings == ()
    # a slower decision rate lengthens it: 0.5 m/s * (0.5 + 0.3) s = 0.4 m
    plan = resolve_flight(flight_from_dict(flight(decision_rate=2.0), "lab.yaml"))
    assert plan.braking_distance == pytest.approx(0.4) and "braking distance 0.400 m" in plan.warnings[0]


@pytest.mark.parametrize("drone, xy, words", [
    (0, [0.15, 1.0], ["drone p0: start [0.15, 1.0] is 0.150 m from the arena border", "inside safety.geofence_margin 0.2 m"]),
    (2, [2.5, 4.9 - 0.03], ["drone p1", "0.130 m from the arena border"]),  # the top border, y = 5
])
def test_a_start_inside_the_geofence_margin_of_the_border_is_warned_about(drone, xy, words):
    plan = resolve_flight(flight_from_dict(_start(flight(), drone, xy), "lab.yaml"))
    [warning] = margin_warnings(plan)
    for w in words:
        assert w in warning, (w, warning)


def test_a_start_inside_the_geofence_margin_of_a_virtual_obstacle_is_warned_about_and_touching_one_refused():
    wall = 1.9 - 0.025  # layout 1: a 0.05 m wall along y = 1.9 from x = 0 to 2.2; its lower face
    plan = resolve_flight(flight_from_dict(_start(flight(layout=1), 0, [1.0, wall - 0.15]), "lab.yaml"))
    [warning] = margin_warnings(plan)
    assert "drone p0: start [1.0, 1.725] is 0.150 m from a virtual obstacle, inside safety.geofence_margin 0.2 m" in warning
    assert margin_warnings(resolve_flight(flight_from_dict(_start(flight(layout=1), 0, [1.0, wall - 0.25]), "lab.yaml"))) == []
    with pytest.raises(ConfigError, match=r"drone p0 .*key 'start'.*inside or touching a virtual obstacle"):
        resolve_flight(flight_from_dict(_start(flight(layout=1), 0, [1.0, wall - 0.05]), "lab.yaml"))


@pytest.mark.parametrize("xy", [[0.0, 1.0], [0.05, 1.0], [3.55, 2.0]])
def test_a_start_on_or_touching_the_arena_border_is_refused(xy):
    with pytest.raises(ConfigError) as err:
        resolve_flight(flight_from_dict(_start(flight(), 0, xy), "lab.yaml"))
    message = str(err.value)
    for w in ["lab.yaml: drone p0", "key 'start'", f"lab {[float(v) for v in xy]}", "from the border of the arena", "on or touching it"]:
        assert w in message, (w, message)


def test_a_target_starting_inside_the_margin_is_no_warning_the_fence_does_not_steer_it():
    data = flight()
    data["drones"][1].update(role="target", start=[2.0, 4.85])
    assert margin_warnings(resolve_flight(flight_from_dict(data, "lab.yaml"))) == []


def test_starts_closer_than_the_separation_minimum_are_refused_naming_both_drones():
    data = flight(safety={"min_separation": 0.28})
    _start(data, 2, [1.25, 1.05])  # 0.255 m from p0: clear of 0.25, not of 0.28
    with pytest.raises(ConfigError, match=r"lab.yaml: drones p0 and p1 start 0.255 m apart, closer than safety.min_separation 0.28 m"):
        resolve_flight(flight_from_dict(data, "lab.yaml"))
    data["safety"]["min_separation"] = 0.25
    assert margin_warnings(resolve_flight(flight_from_dict(data, "lab.yaml"))) == []


def test_a_guard_lookahead_under_half_a_decision_interval_is_refused_under_one_warned_about():
    """The guards cap the closing speed at (gap - margin) / lookahead for a whole decision
    interval dt: the gap beyond the margin is multiplied by 1 - dt / lookahead each decision,
    which overshoots for lookahead < dt and swings ever wider for lookahead < dt / 2."""
    data = flight(safety={"lookahead": 0.06}, decision_rate=5)  # decisions every 0.2 s
    with pytest.raises(ConfigError, match=r"lab.yaml: safety: key 'lookahead': 0.06 s is shorter than half a decision interval \(0.1 s of 0.2 s\).*at least 0.1 s; under 0.2 s, one interval, the plan warns"):
        resolve_flight(flight_from_dict(data, "lab.yaml"))
    data = flight(safety={"lookahead": 0.05})  # decisions every 0.1 s: half of one is allowed
    resolve_flight(flight_from_dict(data, "lab.yaml"))
    data["safety"]["lookahead"] = 0.08
    assert any("safety.lookahead 0.08 s is shorter than one decision interval 0.1 s" in w
               for w in resolve_flight(flight_from_dict(data, "lab.yaml")).warnings)
    data["safety"]["lookahead"] = 0.1
    assert not any("lookahead" in w for w in resolve_flight(flight_from_dict(data, "lab.yaml")).warnings)


@pytest.mark.parametrize("role", ["evader", "target"])
def test_a_quarry_starting_within_the_capture_distance_of_a_pursuer_is_refused(role):
    data = flight()
    data["drones"][1]["role"] = role
    _start(data, 1, [2.5, 1.28])  # 0.28 m from p1: apart enough, but caught (capture_radius 0.3)
    with pytest.raises(ConfigError, match=rf"lab.yaml: {role} e0 starts 0.280 m from pursuer p1, within the capture distance 0.300 m"):
        resolve_flight(flight_from_dict(data, "lab.yaml"))
    _start(data, 1, [2.5, 1.31])
    resolve_flight(flight_from_dict(data, "lab.yaml"))


def test_plan_warnings_are_printed_once_with_the_plan_and_logged_in_the_event_log(tmp_path, capsys):
    """`fly` prints the plan's warnings before the flight and logs them as it starts; here the
    links never come up (nothing answers on them), so the run ends there."""
    from pursuit_cli import main
    from pursuit_mj.flight.events import read_events

    silent = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in BASE["drones"]]
    try:
        for s in silent:
            s.bind(("127.0.0.1", 0))
        data = _start(flight(safety={"connect_timeout": 0.3}, task={"evader_speed": 0.5}), 0, [0.15, 1.0])
        for d, s in zip(data["drones"], silent):
            d["uri"] = f"udp://127.0.0.1:{s.getsockname()[1]}"
        path = tmp_path / "lab.yaml"
        path.write_text(yaml.safe_dump(data))
        assert main(["fly", "check", "--flight", str(path)]) == 0
        out = capsys.readouterr().out
        assert out.count("warning:") == 1 and "warning: drone p0: start [0.15, 1.0] is 0.150 m from the arena border" in out
        rc = main(["fly", "--flight", str(path), "--policy", "heuristic", "--yes", "--events", str(tmp_path / "ev.jsonl")])
        captured = capsys.readouterr()
        assert rc == 2 and "cannot open" in captured.err
        assert captured.out.count("warning:") == 1 and captured.out.count("0.150 m from the arena border") == 1
    finally:
        for s in silent:
            s.close()
    records = read_events(tmp_path / "ev.jsonl")
    warned = [r for r in records if r["kind"] == "plan_warning"]
    assert [r["kind"] for r in records][:2] == ["start", "plan_warning"] and len(warned) == 1
    assert warned[0]["level"] == "warn" and "inside safety.geofence_margin 0.2 m" in warned[0]["warning"]


def test_a_flight_preset_is_found_by_name_from_any_folder(tmp_path, monkeypatch, capsys):
    from pursuit_cli import main

    monkeypatch.chdir(tmp_path)  # configs/flight/ is not below here: found beside the code
    assert main(["fly", "check", "--flight", "lighthouse"]) == 0
    assert "no radio was touched" in capsys.readouterr().out
    assert main(["fly", "check", "--flight", "examples"]) == 2
    assert "examples: no such file, nor a flight preset of that name (presets: example, lighthouse)" in capsys.readouterr().err
    assert main(["fly", "check", "--flight", "lab.yaml"]) == 2
    assert "lab.yaml: no such file" in capsys.readouterr().err


def test_fly_align_writes_a_copy_elsewhere_that_still_finds_a_layout_kept_beside_the_flight_file(tmp_path, capsys):
    from pursuit_cli import main

    lab_dir, out_dir = tmp_path / "lab", tmp_path / "aligned"
    lab_dir.mkdir()
    (lab_dir / "arena.yaml").write_text(open("configs/layouts/1_walls.yaml").read())
    data = yaml.safe_load(open("configs/flight/lighthouse.yaml"))
    data["layout"] = "arena.yaml"  # beside the flight file
    (lab_dir / "lab.yaml").write_text(yaml.safe_dump(data))
    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    out = out_dir / "aligned.yaml"
    rc = main(["fly", "align", "--flight", str(lab_dir / "lab.yaml"), "--lab", fmt(truth.to_lab(spots)), "--spots", fmt(spots),
               "--write", str(out)])
    assert rc == 0, capsys.readouterr().err
    plan = load_plan(out)
    assert plan.layout.name == "walls" and plan.transform.scale == pytest.approx(1.25, rel=1e-4)


def test_an_event_log_that_cannot_be_opened_is_refused_in_one_line_naming_it(tmp_path, capsys):
    """A folder that can be written but a file that cannot be opened for appending (here a
    link to a missing folder; for a user, a read-only log of an earlier flight)."""
    from pursuit_cli import main

    log = tmp_path / "earlier.events.jsonl"
    log.symlink_to(tmp_path / "gone" / "x.jsonl")
    rc = main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--events", str(log)])
    err = capsys.readouterr().err
    assert rc == 2 and f"--events {log}" in err and "cannot be opened" in err, err


@pytest.mark.parametrize("argv, words", [
    (["fly", "check", "--flight", "example", "--set", "fidelity=point"], ["--set fidelity=point", "means nothing in a flight"]),
    (["fly", "check", "--flight", "example", "--set", "command_latency=0.05"],
     ["--set command_latency=0.05", "means nothing in a flight"]),
    (["fly", "--flight", "example", "--policy", "heuristic", "--virtual", "--max-time", "0.5"],
     ["--max-time 0.5", "[1, 3600]"]),  # what the flight file's max_time takes
    (["fly", "align", "--flight", "lighthouse", "--virtual", "--window", "-1", "--spots", "0.5,0.6 1.7,0.6 1.8,4.0"],
     ["--window -1.0", "(0, 60]"]),
])
def test_flight_flags_take_what_the_flight_file_takes(argv, words, capsys):
    """--set fidelity, --max-time below a second and a --window of no time were taken and ended
    in a silent no-op, a chase shorter than the file allows, or 'sent no position within -1 s'."""
    from pursuit_cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, (w, err)


@pytest.mark.parametrize("key", ["task", "safety", "transform"])
def test_an_empty_section_means_its_defaults(key):
    """`task:` with every line below it commented out (YAML null) was refused while an empty
    `safety:` or `transform:` meant their defaults: all three now mean their defaults."""
    assert flight_from_dict(flight(**{key: None}), "f.yaml") == flight_from_dict({k: v for k, v in flight().items() if k != key}, "f.yaml")


def test_flight_options_given_before_check_or_align_are_kept(capsys):
    """`fly --flight F check` said --flight was required, and `fly --set K=V check --flight F`
    showed the plan without the override: the action's own defaults replaced them."""
    from pursuit_cli import main

    assert main(["fly", "--flight", EXAMPLE, "check"]) == 0
    assert main(["fly", "--set", "pursuer_speed=0.2", "check", "--flight", EXAMPLE]) == 0
    assert "pursuers 0.2 m/s" in capsys.readouterr().out
    assert main(["fly", "--flight", "lighthouse", "align", "--spots", "0.5,0.625 1.75,0.625 1.875,4.0",
                 "--lab", "0.5,0.625 1.75,0.625 1.875,4.0"]) == 0


@pytest.mark.parametrize("reason, code", [("Ctrl-C", 130), ("SIGTERM", 143), ("SIGHUP", 129)])
def test_a_flight_landed_after_a_stop_signal_exits_as_a_stopped_command_does(reason, code, monkeypatch):
    """It exited 1, as after a failure; before take-off the same signal gave 130."""
    from pursuit_cli import main
    import pursuit_mj.flight.session as session
    from pursuit_mj.flight.bridge import FlightResult

    def landed_on(plan, policy, **kwargs):
        return FlightResult("interrupted", reason, 3.0, 0, [], True, np.zeros(4)), None

    monkeypatch.setattr(session, "run_flight", landed_on)
    assert main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--events", "/dev/null"]) == code


def test_fly_align_warns_of_a_fit_no_placement_mistake_would_leave(capsys):
    """A mirrored placement printed 'rms residual 1335.6 mm' and its transform without a word."""
    from pursuit_cli import main

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    assert main(["fly", "align", "--flight", "lighthouse", "--spots", spots, "--lab", "0,0 -1,0 -1,1"]) == 0
    out = capsys.readouterr().out
    assert "warning: no rotation, scale and shift brings the drones within 50 mm of their spots" in out
    assert main(["fly", "align", "--flight", "lighthouse", "--spots", spots, "--lab", spots]) == 0
    assert "warning" not in capsys.readouterr().out


def test_fly_align_with_two_drones_says_the_fit_cannot_be_checked(tmp_path, capsys):
    """Two spots fit any placement exactly: swapped drones gave a transform turned by 180 deg and
    'rms residual 0.0 mm' without a word."""
    from pursuit_cli import main

    data = yaml.safe_load(open("configs/flight/lighthouse.yaml"))
    data["drones"] = [data["drones"][0], data["drones"][2]]  # p0 and the target
    data["layout"] = str(load_flight("lighthouse").layout)
    path = tmp_path / "pair.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main(["fly", "align", "--flight", str(path), "--spots", "0.5,0.625 1.875,4.0", "--lab", "1.0,1.6 3.7,0.5"]) == 0
    out = capsys.readouterr().out
    assert "rms residual 0.0 mm" in out
    assert "warning: two spots fit any placement exactly" in out and "180 deg" in out, out


@pytest.mark.parametrize("which", ["rerun", "flight", "layout"])
def test_an_event_log_named_as_the_recording_or_an_input_file_is_refused_before_any_radio(tmp_path, capsys, which):
    """--events flight.rrd --rerun flight.rrd flew, then the recording replaced the event log
    when it was renamed into place; --events naming the flight or layout file appended JSON lines to it."""
    from pursuit_cli import main

    data = yaml.safe_load(open(EXAMPLE))
    layout = tmp_path / "arena.yaml"
    layout.write_text(open(load_plan(EXAMPLE).layout.source).read())
    data["layout"] = "arena.yaml"
    flight_file = tmp_path / "lab.yaml"
    flight_file.write_text(yaml.safe_dump(data))
    rrd = tmp_path / "flight.rrd"
    events = {"rerun": rrd, "flight": flight_file, "layout": layout}[which]
    before = {p: p.read_bytes() for p in (flight_file, layout)}
    rc = main(["fly", "--flight", str(flight_file), "--policy", "heuristic", "--virtual", "--max-time", "1",
               "--events", str(events), "--rerun", str(rrd)])
    err = capsys.readouterr().err
    what = {"rerun": "the --rerun recording", "flight": "the flight file", "layout": "the flight's layout file"}[which]
    assert rc == 2 and f"--events {events}: is also {what}" in err, err
    assert {p: p.read_bytes() for p in (flight_file, layout)} == before and not rrd.exists()


def test_fly_align_refuses_a_fit_whose_scale_no_flight_file_takes_points_in_cm(capsys):
    """Lab positions in cm printed 'scale: 0.0125' with exit 0: a transform that every flight file
    refuses (transform.scale is 0.05 to 20), and nothing said that the units were mixed up."""
    from pursuit_cli import main
    from pursuit_mj.flight.align import fit_transform

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    assert main(["fly", "align", "--flight", "lighthouse", "--spots", spots, "--lab", "370,50 370,150 100,160"]) == 2
    captured = capsys.readouterr()
    assert "transform:" not in captured.out
    err = captured.err
    assert "a scale of 0.0125 layout m per lab m" in err and "0.05 to 20" in err and "--spots" in err and "--lab" in err, err
    assert "metres" in err and "cm" in err and "mm" in err, err
    # spots in cm (fly align refuses them first, as outside the arena), lab positions in m
    lab = np.array([[3.7, 0.5], [3.7, 1.5], [1.0, 1.6]])
    with pytest.raises(ValueError, match="a scale of 125 layout m per lab m"):
        fit_transform(lab, np.array([[50.0, 62.5], [175.0, 62.5], [187.5, 400.0]]), lab_source="--lab")


def test_fly_align_refuses_spots_outside_the_arena_before_any_radio(capsys):
    """Spots and lab positions both in cm fit with a plausible scale (1.25) and zero residuals:
    fly align printed 'origin: [420.0, 10.0]' with exit status 0, an arena 420 m away."""
    from pursuit_cli import main

    rc = main(["fly", "align", "--flight", "lighthouse", "--spots", "50,62.5 175,62.5 187.5,400", "--lab", "370,50 370,150 100,160"])
    captured = capsys.readouterr()
    assert rc == 2 and "transform:" not in captured.out
    err = captured.err
    assert "--spots: drone p0's spot [50, 62.5] is outside the 3.6 x 5 m arena" in err and "metres" in err, err
    # the measuring waits for no drone: the spots are refused before any link opens
    rc = main(["fly", "align", "--flight", "lighthouse", "--spots", "0.5,0.625 1.75,0.625 1.875,-0.2", "--window", "0.1"])
    assert rc == 2 and "--spots: drone t0's spot [1.875, -0.2] is outside" in capsys.readouterr().err


def test_fly_align_refuses_two_spots_where_no_two_crazyflies_stand(capsys):
    """Two drones given one spot (a typo) fitted a transform between the other points with a
    warning about the residuals only; the spots themselves were never looked at."""
    from pursuit_cli import main

    rc = main(["fly", "align", "--flight", "lighthouse", "--spots", "0.5,0.625 0.5,0.625 1.875,4.0", "--lab", "3.7,0.5 3.7,1.5 1.0,1.6"])
    captured = capsys.readouterr()
    assert rc == 2 and "transform:" not in captured.out
    assert "--spots: drones p0 and p1 have spots 0.000 m apart" in captured.err, captured.err


BARS_STARTS = [[1.2, 0.6], [1.8, 4.4], [2.4, 0.6]]  # layout 2 (bars): pursuers below the bars, the evader above


@pytest.mark.parametrize("scale, margin, refused", [(1.0, 0.3, False), (1.0, 0.45, True), (1.5, 0.3, True)])
def test_a_geofence_margin_that_closes_every_passage_between_the_teams_is_refused(scale, margin, refused):
    """On layout 2 the fence's margin (lab m; scale times that in the layout) keeps drones that far
    from the bars, the pillars and the border. At 0.45 layout m no gap is wide enough: a flight
    resolved without a word, and pursuers driven from below at the evader stopped at y 1.5 for good
    (measured with Fence.filter); 0.3 m at scale 1.5 is the same 0.45 layout m."""
    data = flight(layout=2, transform={"origin": [0.0, 0.0], "yaw": 0.0, "scale": scale},
                  safety={"geofence_margin": margin, "min_separation": 0.15, "max_speed": 0.7})
    for drone, xy in zip(data["drones"], BARS_STARTS):
        drone["start"] = [v / scale for v in xy]
    spec = flight_from_dict(data, "bars.yaml")
    if not refused:
        resolve_flight(spec)
        return
    with pytest.raises(ConfigError) as caught:
        resolve_flight(spec)
    msg = str(caught.value)
    assert "bars.yaml: safety: key 'geofence_margin'" in msg and f"geofence_margin {margin:g} m" in msg, msg
    assert "evader e0" in msg and "pursuer" in msg and "2_bars.yaml" in msg, msg
    data["drones"][1]["role"] = "target"  # flown by someone else, who may fly it out: a warning
    plan = resolve_flight(flight_from_dict(data, "bars.yaml"))
    assert any("closes every passage between target e0 and the pursuers" in w for w in plan.warnings), plan.warnings


def test_fly_align_warns_that_spots_turned_about_their_centre_fit_as_well():
    """Drones at the corners of a rectangle (or a regular triangle, a square) fit exactly when each
    stands on another's spot, turned about the centre: 'rms residual 0.0 mm' and a transform turned
    by 180 deg (120, 90 ...) without a word, as with two drones, which were warned about."""
    from pursuit_mj.flight.align import spot_turns

    rectangle = np.array([[0.6, 0.6], [3.0, 0.6], [3.0, 4.4], [0.6, 4.4]])
    assert spot_turns(rectangle, 0.05) == [180]
    assert spot_turns(np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]]), 0.05) == [90, 180, 270]
    triangle = 1.8 + 1j * 2.5 + np.exp(1j * np.radians([90, 210, 330]))
    assert spot_turns(np.column_stack([triangle.real, triangle.imag]), 0.05) == [120, 240]
    assert spot_turns(np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]]), 0.05) == []  # lighthouse.yaml's
    assert spot_turns(rectangle + [[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.3, 0.0]], 0.05) == []  # one corner moved


@pytest.mark.parametrize("second_corner_deg", [210.0, 209.5])
def test_fly_align_prints_the_turn_of_symmetric_spots_as_a_warning(capsys, second_corner_deg):
    """A regular triangle of spots fits as well turned by 120 deg; so do spots 9 mm off one (209.5
    deg), within the 5 cm align tolerates: the warning is printed for both."""
    from pursuit_cli import main

    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)  # configs/flight/lighthouse.yaml's
    triangle = 1.8 + 1j * 2.5 + np.exp(1j * np.radians([90, second_corner_deg, 330]))
    spots = np.column_stack([triangle.real, triangle.imag])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    assert main(["fly", "align", "--flight", "lighthouse", "--spots", fmt(spots), "--lab", fmt(truth.to_lab(spots))]) == 0
    out = capsys.readouterr().out
    assert "warning: the spots look the same turned by 120 or 240 deg about their centre" in out, out
    assert "p0, p1, t0" in out and "transform:" in out


@pytest.mark.parametrize("scale, separation, warned", [(1.0, 0.25, False), (1.0, 0.15, True), (0.8, 0.2, True), (1.25, 0.2, False)])
def test_a_separation_guard_that_lets_pursuers_closer_than_the_simulators_teammate_clearance_is_warned_about(scale, separation, warned):
    """The simulator counts two pursuers closer than teammate_clearance (0.2 layout m) as a collision;
    a separation guard below that in the lab (0.2 / scale m) let them come closer without a word
    (the fence's margin is held to obstacle_clearance the same way)."""
    data = flight(transform={"origin": [0.0, 0.0], "yaw": 0.0, "scale": scale}, safety={"min_separation": separation},
                  task={"capture_radius": 0.3, "evader_speed": 0.4})
    for drone in data["drones"]:
        drone["start"] = [v / scale for v in drone["start"]]
    plan = resolve_flight(flight_from_dict(data, "lab.yaml"))
    found = [w for w in plan.warnings if "teammate_clearance" in w]
    if not warned:
        assert found == [], found
        return
    [warning] = found
    lab = 0.2 / scale
    for w in [f"safety.min_separation {separation:g} m", "teammate_clearance 0.2 m", f"{lab:.3f} m in the lab", "collision"]:
        assert w in warning, (w, warning)


def test_fly_align_refuses_a_write_path_that_names_a_folder_before_it_measures(tmp_path, capsys):
    # 'fly align --write aligned/' wrote the flight file to a plain file called 'aligned' (Path
    # drops the slash), as eval --json and train --export did before they were mended
    from pursuit_cli import main

    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    for out in (f"{tmp_path / 'aligned'}/", str(tmp_path)):
        rc = main(["fly", "align", "--flight", "lighthouse", "--lab", fmt(truth.to_lab(spots)), "--spots", fmt(spots), "--write", out])
        captured = capsys.readouterr()
        assert rc == 2 and captured.out == "", captured.out  # refused before the fit is printed (or any drone measured)
        assert f"--write path {out}" in captured.err and "folder" in captured.err, captured.err
    assert not (tmp_path / "aligned").exists()


@pytest.mark.parametrize("clearance, scale", [(0.25, 1.0), (0.35, 1.0), (0.2, 0.9)])
def test_the_separation_warning_advises_only_a_min_separation_the_flight_takes(clearance, scale):
    """With a teammate_clearance at or above the capture distance the warning advised 'raise
    min_separation to 0.350 m, below the capture distance 0.300 m', a value the flight then
    refuses ('not below the capture distance: no capture could happen')."""
    import re

    data = flight(transform={"origin": [0.0, 0.0], "yaw": 0.0, "scale": scale}, safety={"min_separation": 0.2},
                  task={"capture_radius": 0.3, "evader_speed": 0.4, "teammate_clearance": clearance})
    for drone in data["drones"]:
        drone["start"] = [v / scale for v in drone["start"]]
    [warning] = [w for w in resolve_flight(flight_from_dict(data, "lab.yaml")).warnings if "teammate_clearance" in w]
    advised = re.search(r"raise min_separation to ([0-9.]+) m", warning)
    if clearance < 0.3:  # at scale 0.9 the clearance is 0.2222 m in the lab: 0.222 left the warning standing
        data["safety"]["min_separation"] = float(advised.group(1))
        assert not [w for w in resolve_flight(flight_from_dict(data, "lab.yaml")).warnings if "teammate_clearance" in w]
    else:
        assert advised is None, warning
        assert "no min_separation" in warning and "capture_radius" in warning, warning


def test_fly_align_refuses_a_bad_set_before_it_measures(capsys):
    # fly align took --set and judged it only with --virtual or --write, after the fit: without them
    # 'fly align ... --set bogus=1' printed the transform and exited 0, the --set never read
    from pursuit_cli import main

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    for bad, said in (("bogus=1", "--set bogus=1: unknown key 'bogus'"), ("layout=1", "--set layout=1: 'layout'")):
        assert main(["fly", "align", "--flight", "lighthouse", "--spots", spots, "--lab", spots, "--set", bad]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and said in captured.err, captured
    assert main(["fly", "align", "--flight", "lighthouse", "--spots", spots, "--lab", spots, "--set", "pursuer_speed=0.3"]) == 0


def test_fly_align_refused_for_its_input_makes_no_write_folder(tmp_path, capsys):
    # since --write was checked first (6aa70ee), its folder was made before the flight file,
    # --set, --spots and --lab were read: 'fly align --flight nope.yaml ... --write new/out.yaml'
    # was refused but left 'new/' behind, where eval refuses bad input before making any folder
    from pursuit_cli import main

    spots = "0.5,0.625 1.75,0.625 1.875,4.0"
    for bad in (["--flight", str(tmp_path / "nope.yaml"), "--spots", spots],
                ["--flight", "lighthouse", "--spots", spots, "--lab", "0.5,0.625 1.75,0.625"],
                ["--flight", "lighthouse", "--spots", spots, "--lab", spots, "--set", "bogus=1"],
                ["--flight", "lighthouse", "--spots", "50,62.5 175,62.5 187.5,400", "--lab", spots]):  # spots in cm
        out = tmp_path / "new" / "out.yaml"
        assert main(["fly", "align", *bad, "--write", str(out)]) == 2
        assert capsys.readouterr().out == ""
        assert not (tmp_path / "new").exists(), bad


def test_a_flight_or_align_refused_after_its_output_checks_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch):
    """fly checks --rerun and then --events (each check makes its folder) and only then that they
    name other files; fly align makes --write's folder before it measures and fits. Each refused
    after those checks left the empty n1/x/: '--rerun n1/x/r.rrd --events FILE/e.jsonl', '--events
    n1/x/r.rrd --rerun n1/x/r.rrd', an align whose lab points coincide or whose transform moves the
    arena out of the lab, and an align stopped (Ctrl-C) while it measured."""
    import pursuit_mj.flight.align
    from pursuit_cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("mine")
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    far = fmt(LabTransform((9.0, 9.0), 0.0, 1.0).to_lab(spots))
    fly = ["fly", "--flight", "lighthouse", "--policy", "heuristic", "--virtual"]
    align = ["fly", "align", "--flight", "lighthouse", "--spots", fmt(spots), "--write", "n1/x/out.yaml"]
    for argv, said in ((fly + ["--rerun", "n1/x/r.rrd", "--events", "mine.txt/e.jsonl"], "exists and is not a folder"),
                       (fly + ["--events", "n1/x/r.rrd", "--rerun", "n1/x/r.rrd"], "--events n1/x/r.rrd"),
                       (align + ["--lab", "1,1 1,1 1,1"], "coincide"),
                       (align + ["--lab", far], "does not make a valid flight")):
        assert main(argv) == 2
        assert said in capsys.readouterr().err, argv
        assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"], argv

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pursuit_mj.flight.align, "measure_lab_positions", stop)
    assert main(align) == 130
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


@pytest.mark.parametrize("what", ["model", "policy", "evader", "hard link"])
def test_an_event_log_naming_the_model_or_a_code_file_of_the_flight_is_refused(what, tmp_path, capsys):
    """fly --model m.pt --events m.pt appended the flight's event log to the checkpoint (and
    --events team.py to the policy file): the user's file was damaged for good. The flight and
    layout files were refused already."""
    import os
    import shutil

    from pursuit_cli import main
    from pursuit_mj.shipped import shipped_dir

    model = tmp_path / "m.pt"
    shutil.copy(shipped_dir("pretrained") / "pursuers.pt", model)
    code = tmp_path / "team.py"
    code.write_text("from pursuit_mj.heuristic import HeuristicTeam\n"
                    "def team(config, seed):\n    t = HeuristicTeam.from_config(config)\n    t.name = 'mine'\n    return t\n"
                    "class Still:\n    def __init__(self, config, n_worlds, seed): pass\n"
                    "    def reset(self, world_ids, seeds): pass\n"
                    "    def compute(self, evader_pos, *rest): return 0 * evader_pos\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    given, events = {"model": (["--model", str(model)], model),
                     "policy": (["--policy", f"{code}:team"], code),
                     "evader": (["--policy", "heuristic", "--set", f"evader.model={code}:Still"], code),
                     # appended to, a hard link of the checkpoint writes into its bytes
                     "hard link": (["--model", str(model)], tmp_path / "hard.pt")}[what]
    if what == "hard link":
        os.link(model, tmp_path / "hard.pt")
        before["hard.pt"] = before["m.pt"]
    rc = main(["fly", "--flight", EXAMPLE, *given, "--virtual", "--yes", "--max-time", "1", "--events", str(events)])
    err = capsys.readouterr().err
    assert rc == 2 and f"--events {events}: the same file as " in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_fly_align_refuses_to_write_its_copy_over_the_flight_file(tmp_path, capsys):
    """fly align --flight lab.yaml --write lab.yaml replaced the flight file with the 'copy', whose
    comments are not kept: the user's notes (drone placement, the lab) were gone."""
    from pursuit_cli import main
    from pursuit_mj.shipped import shipped_dir

    flight = tmp_path / "lab.yaml"
    flight.write_text((shipped_dir("configs") / "flight" / "lighthouse.yaml").read_text())
    before = flight.read_bytes()
    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    rc = main(["fly", "align", "--flight", str(flight), "--lab", fmt(truth.to_lab(spots)), "--spots", fmt(spots),
               "--write", f"{tmp_path}/./lab.yaml"])
    err = capsys.readouterr().err
    assert rc == 2 and f"--write {tmp_path}/./lab.yaml: the same file as --flight {flight}" in err, err
    assert len(err.strip().splitlines()) == 1 and flight.read_bytes() == before


@pytest.mark.parametrize("text, ok", [
    ("name: notes\narena: {width: 3.6, height: 5.0}\n", False),  # a layout file of another flight, say
    ("some notes\n", False),
    ("", True),  # an empty file: nothing to damage
    ("\n", True),  # a blank line only: nothing to damage either
    ('{"t": 0.0, "time": "2026-12-07T08:00:00+00:00", "kind": "links_up"}\n', True),  # an earlier flight's log
])
def test_an_event_log_is_appended_only_to_an_event_log(text, ok, tmp_path, capsys):
    """fly --events notes.yaml appended the flight's JSON records to a file that was no event log
    (any YAML or text file not read by the flight), damaging it for good."""
    from pursuit_cli import main

    from flight_rehearsal import quick_spec

    log = tmp_path / "notes.yaml"
    log.write_text(text)
    flight = tmp_path / "quick.yaml"  # a low, quick take-off and landing: the log is what is tested
    flight.write_text(yaml.safe_dump(quick_spec()))
    rc = main(["fly", "--flight", str(flight), "--policy", "heuristic", "--virtual", "--yes", "--max-time", "1",
               "--events", str(log)])
    err = capsys.readouterr().err
    if ok:
        assert rc == 0, err
        assert log.read_text().startswith(text) and "links_closed" in log.read_text()
        return
    assert rc == 2 and f"--events {log}: an existing file that is not an event log" in err, err
    assert len(err.strip().splitlines()) == 1 and log.read_text() == text


def test_fly_align_refuses_to_write_its_copy_over_a_file_that_is_no_flight_file(tmp_path, capsys):
    """fly align --write task.yaml replaced a task file of the user's with a flight file, without a
    word; an earlier aligned copy under the name is replaced as before."""
    from pursuit_cli import main

    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    argv = ["fly", "align", "--flight", "lighthouse", "--lab", fmt(truth.to_lab(spots)), "--spots", fmt(spots), "--write"]
    task = tmp_path / "task.yaml"
    task.write_text("evader_speed: 0.45\n")
    assert main([*argv, str(task)]) == 2
    err = capsys.readouterr().err
    assert f"--write path {task}: exists and is not a flight file" in err and len(err.strip().splitlines()) == 1, err
    assert task.read_text() == "evader_speed: 0.45\n"
    aligned = tmp_path / "aligned.yaml"
    assert main([*argv, str(aligned)]) == 0 and main([*argv, str(aligned)]) == 0  # an earlier copy: replaced


def test_fly_align_tells_a_multi_gb_write_target_without_reading_it_whole(tmp_path):
    """fly align --write big.yaml read the whole of an existing big.yaml (a 6 GB file given by
    mistake) to tell whether it was a flight file: MemoryError under a memory cap, instead of
    the one-line refusal. A file that large is no flight file, and only its head is read."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    truth = LabTransform((4.2, 0.1), math.pi / 2, 1.25)
    spots = np.array([[0.5, 0.625], [1.75, 0.625], [1.875, 4.0]])
    fmt = lambda pts: " ".join(f"{x:.4f},{y:.4f}" for x, y in pts)  # noqa: E731
    big = tmp_path / "big.yaml"
    big.write_text("drones:\n")
    with open(big, "r+b") as f:
        f.truncate(6 << 30)  # sparse: no disk used
    cap = ("import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30)); "
           "sys.argv = ['pursuit-mj', *sys.argv[1:]]; runpy.run_module('pursuit_cli', run_name='__main__')")
    root = str(Path(__file__).resolve().parents[1])
    proc = subprocess.run([sys.executable, "-c", cap, "fly", "align", "--flight", "lighthouse", "--lab", fmt(truth.to_lab(spots)),
                           "--spots", fmt(spots), "--write", str(big)], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": root, "OPENBLAS_NUM_THREADS": "1"})
    assert proc.returncode == 2, proc.stderr
    assert f"--write path {big}: exists and is not a flight file" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and big.stat().st_size == 6 << 30


def test_align_refuses_lab_positions_or_spots_closer_than_two_crazyflies_can_stand():
    """Two Crazyflies touch at 2 x 0.0685 = 0.137 m: lab positions 0.13 m apart are refused, 0.15 m
    apart taken; spots are judged in lab metres, layout distance / scale (layout m per lab m): at
    scale 2 two spots 0.2 m apart in the layout stand 0.1 m apart in the lab."""
    from pursuit_mj.flight.align import fit_transform

    lab = np.array([[1.0, 1.0], [1.13, 1.0], [2.0, 3.0]])
    with pytest.raises(ValueError, match=r"^--lab: drones #0 and #1 stand 0.130 m apart in the lab, closer than two Crazyflies can"):
        fit_transform(lab, lab.copy(), lab_source="--lab")
    lab[1, 0] = 1.15
    assert fit_transform(lab, lab.copy()).transform.scale == pytest.approx(1.0)
    lab = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0], [1.0, 1.0]])
    spots = 2.0 * lab
    spots[4] = spots[2] + [0.0, -0.2]  # the last spot typed next to the third
    with pytest.raises(ValueError, match=r"^--spots: drones #2 and #4 have spots 0.200 m apart \(0.100 m in the lab\), closer than two"):
        fit_transform(lab, spots)


def test_align_waits_only_for_drones_whose_every_position_variance_is_below_the_limit():
    """The Kalman variances of x, y and z must each be below safety.estimator_variance: one axis
    above it (0.011 against 0.01) is no fix; all three just below it are."""
    from types import SimpleNamespace

    from pursuit_mj.flight.align import _wait_fixed

    def judge(*variances):
        snap = SimpleNamespace(var=np.array([[[1.0, 1.0, 1.0], v] for v in variances]))  # (D, history 2, xyz): the latest is last
        _wait_fixed(None, ["p0", "p1"], ["u0", "u1"], 0.01, 0.0, 1.0, snap)

    judge([0.009, 0.009, 0.009], [0.001, 0.002, 0.003])
    for bad in ([0.009, 0.011, 0.009], [0.011, 0.011, 0.011], [0.001, float("nan"), 0.001]):
        with pytest.raises(ValueError, match=r"drone p1 \(u1\): its position estimate lost its fix during the 1 s window"):
            judge([0.001, 0.001, 0.001], bad)


def test_the_fence_measures_in_lab_metres_under_a_scaled_and_turned_transform():
    """With 2 layout m per lab m and the layout's x axis along lab +y, a drone 0.5 layout m from
    the right border (x = 3.6) stands 0.25 lab m from it, the way back in is lab -y, and a
    command of 1 m/s at the border is cut to (0.25 - margin 0.1) / lookahead 0.5 = 0.3 m/s.
    A breach (0.15 lab m) is 0.3 layout m beyond the border."""
    t = LabTransform((1.0, 2.0), math.pi / 2, 2.0)
    fence = Fence(load_layout(0), t, margin=0.1, lookahead=0.5, breach=0.15)  # open arena 3.6 x 5 m
    p = t.to_lab(np.array([[3.1, 2.5]]))
    np.testing.assert_allclose(p, [[-0.25, 3.55]], atol=1e-12)  # origin + R(90 deg) q / 2
    np.testing.assert_allclose(fence.clearance(p), [0.25], atol=1e-9)
    np.testing.assert_allclose(fence.normal(p), [[0.0, -1.0]], atol=1e-6)
    v, braking, c = fence.filter(np.array([[0.0, 1.0]]), p)
    np.testing.assert_allclose(v, [[0.0, 0.3]], atol=1e-6)
    assert braking.tolist() == [True] and c == pytest.approx([0.25])
    v, braking, _ = fence.filter(np.array([[0.0, -1.0]]), p)  # back inside: untouched
    np.testing.assert_allclose(v, [[0.0, -1.0]], atol=1e-12)
    assert braking.tolist() == [False]
    assert fence.breached(t.to_lab(np.array([[3.8, 2.5], [4.0, 2.5]]))).tolist() == [False, True]
    # in the corner 0.3 layout m below the top border (the nearest surface, lab -x of the drone)
    # the fan's ray along layout +x still finds the right border 0.25 lab m away: 0.3 m/s again
    corner = t.to_lab(np.array([[3.1, 4.7]]))
    np.testing.assert_allclose(fence.clearance(corner), [0.15], atol=1e-9)
    np.testing.assert_allclose(fence.filter(np.array([[0.0, 1.0]]), corner)[0], [[0.0, 0.3]], atol=1e-6)


def test_a_drone_beyond_the_border_is_sent_back_at_the_speed_its_depth_asks_judged_at_its_worse_point():
    """0.1 m beyond the right border (clearance -0.1) with margin 0.1 and lookahead 0.5 s, the
    way back in is at least (0.1 + 0.1) / 0.5 = 0.4 m/s along -x, whatever it was commanded;
    heading 0.3 m beyond, it is judged there, the deeper point: 0.8 m/s."""
    fence = Fence(load_layout(0), LabTransform(), margin=0.1, lookahead=0.5, breach=0.15)  # border x 0-3.6
    p = np.array([[3.7, 2.5]])
    for command in ([0.0, 0.0], [1.0, 0.0]):
        v, braking, c = fence.filter(np.array([command]), p)
        np.testing.assert_allclose(v, [[-0.4, 0.0]], atol=1e-9)
        assert braking.tolist() == [True] and c == pytest.approx([-0.1])
    v, _, c = fence.filter(np.zeros((1, 2)), p, np.array([[3.9, 2.5]]))
    np.testing.assert_allclose(v, [[-0.8, 0.0]], atol=1e-9)
    assert c == pytest.approx([-0.3])


def test_a_drone_flown_by_someone_else_keeps_its_command_and_ours_takes_all_the_room():
    """keep_apart_and_inside: 0.5 m apart, closing at 1 m/s each, separation 0.3 m, lookahead 0.5 s.
    The target is not ours (movable False): its command stays, and our pursuer alone brakes, to
    (0.5 - 0.3) / 0.5 = 0.4 m/s (two of ours would each take half: 0.2 m/s)."""
    fence = Fence(load_layout(0), LabTransform(), margin=0.1, lookahead=0.5, breach=0.15)
    p = np.array([[1.0, 2.5], [1.5, 2.5]])
    v = np.array([[1.0, 0.0], [-1.0, 0.0]])
    out, separating, fencing, _ = keep_apart_and_inside(v, p, fence, 0.3, 0.5, np.array([True, False]))
    np.testing.assert_allclose(out, [[0.4, 0.0], [-1.0, 0.0]], atol=1e-9)
    assert separating.tolist() == [True, False] and fencing.tolist() == [False, False]
    out, separating, _, _ = keep_apart_and_inside(v, p, fence, 0.3, 0.5, np.array([True, True]))
    np.testing.assert_allclose(out, [[0.2, 0.0], [-0.2, 0.0]], atol=1e-9)
    assert separating.tolist() == [True, True]


def test_each_injected_fault_does_its_own_kind_to_its_drone_at_its_time_after_the_chase_starts():
    """FaultInjector: drop_link, freeze, lose_fix and battery (with its voltage) each reach the
    fleet as that fault, for the named drone, `at` s after the 'chase' event (not at once, not
    before it); a negative time is refused as malformed."""
    import dataclasses
    import time as clock
    from types import SimpleNamespace

    from pursuit_mj.flight.events import EventLog
    from pursuit_mj.flight.session import FaultInjector

    plan = load_plan(EXAMPLE)  # p0 p1 p2 e0
    calls = []

    def note(name):
        return lambda *args: calls.append((name, *args, clock.monotonic()))

    fleet = SimpleNamespace(plan=plan, drop_link=note("drop_link"), freeze_estimates=note("freeze"),
                            lose_fix=note("lose_fix"), set_battery=note("battery"))
    faults = [parse_fault(text, plan) for text in ("drop_link:p1@0.3", "freeze:p2@0.2", "battery:e0@0.1=3.1")]
    faults.append(dataclasses.replace(faults[0], kind="lose_fix", drone=0, at=0.25))  # the example flies flow decks
    events = EventLog(None)
    injector = FaultInjector(fleet, faults, events)
    events.log("takeoff")
    clock.sleep(0.4)
    assert calls == []  # timed from the chase, not before it
    began = clock.monotonic()
    events.log("chase")
    deadline = began + 10.0  # all four, however loaded the machine (timer threads may run late)
    while len(calls) < 4 and clock.monotonic() < deadline:
        clock.sleep(0.02)
    clock.sleep(0.1)  # none more
    injector.cancel()
    events.close()
    assert sorted(c[:-1] for c in calls) == [("battery", 3, 3.1), ("drop_link", 1), ("freeze", 2), ("lose_fix", 0)], calls
    at = {"battery": 0.1, "freeze": 0.2, "lose_fix": 0.25, "drop_link": 0.3}
    for name, *_, t in calls:  # each at its own time: never early, late by a loaded computer's scheduling at most
        assert at[name] - 0.01 <= t - began <= at[name] + 3.0, (name, t - began)
    with pytest.raises(ValueError, match="expected KIND"):
        parse_fault("drop_link:p1@-1", plan)


def test_a_fault_for_a_real_flight_is_refused_before_any_radio_not_ignored(tmp_path):
    """Faults are injected into virtual drones only: a real flight given one is refused, naming
    --fault and --virtual, before any link is built (else it would fly with the fault ignored)."""
    factory = RecordingFactory(tmp_path / "toc")
    with pytest.raises(ValueError, match=r"^--fault rehearses failures on virtual drones only; add --virtual$"):
        run_flight(EXAMPLE, policy_name="heuristic", faults=["drop_link:p0@1"], factory=factory, handle_signals=False,
                   events_path=tmp_path / "e.jsonl")
    assert factory.built == [] and not (tmp_path / "e.jsonl").exists()


def test_spot_turns_are_found_with_a_spot_at_the_centre_and_within_tolerance_of_symmetry():
    """A drone on the centre of a square (listed first) turns onto itself: the corners still make
    [90, 180, 270]. Spots symmetric within the tolerance (a corner 4 cm further out, a triangle's
    corner 0.5 deg short of 120) give the whole turns they are nearest; two spots give none (warned
    about on their own)."""
    from pursuit_mj.flight.align import spot_turns

    square = np.array([[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]])
    assert spot_turns(np.vstack([[2.0, 2.0], square]), 0.05) == [90, 180, 270]
    pushed = square.copy()
    pushed[2] += 0.04 / math.sqrt(2)  # 4 cm further from the centre
    assert spot_turns(pushed, 0.05) == [90, 180, 270]
    short = 1.8 + 1j * 2.5 + np.exp(1j * np.radians([90, 209.5, 330]))  # 119.5 deg from the first corner
    assert spot_turns(np.column_stack([short.real, short.imag]), 0.05) == [120, 240]
    assert spot_turns(square[:2], 0.05) == [] and spot_turns(square[:1], 0.05) == []


def test_spot_turns_needs_every_spot_reached_not_only_every_turned_spot_near_one():
    """Eight spots (pairs 8 cm apart) whose turn by 120 deg lands every spot within 5 cm of some
    spot, but two of them near the same one, leaving a spot no drone would stand on: not a turn
    that fits as well. Only their point reflection (180) is."""
    from pursuit_mj.flight.align import spot_turns

    turn = np.exp(2j * np.pi / 3)
    top, side = 1.5j, 0.04  # a spot 1.5 m above the centre; 4 cm either side of it
    # a pair about the top; the top turned once; the pair's right spot turned twice, a little further out
    # (the farthest spot, so the one turns are measured from): turned once more it lands on the right spot
    half = np.array([turn**2 * (top + side) * 1.005, top - side, top + side, turn * top])
    z = np.concatenate([half, -half]) + (1.9 + 2.5j)
    spots = np.column_stack([z.real, z.imag])
    assert np.min(np.linalg.norm(spots[:, None] - spots[None], axis=-1) + 9 * np.eye(8)) >= 0.08 - 1e-9
    assert spot_turns(spots, 0.05) == [180]


def test_fly_check_notes_the_task_settings_a_flight_never_reads(capsys):
    """`fly --set observability=full --set miss_probability=0.2` flew on exact observations, the
    misses unread, without a word (eval, render and the other task commands say so)."""
    from pursuit_cli import main

    assert main(["fly", "check", "--flight", "example", "--set", "observability=full", "--set", "miss_probability=0.2"]) == 0
    assert capsys.readouterr().err.splitlines() == [
        "note: miss_probability 0.2 does nothing under observability full (every evader and teammate is known exactly)"]
    assert main(["fly", "check", "--flight", "example", "--set", "miss_probability=0.2"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("reason, code", [("Ctrl-C", 130), ("SIGTERM", 143), ("SIGHUP", 129)])
def test_a_flight_stopped_by_a_second_stop_signal_during_its_landing_exits_as_a_stopped_command_does(reason, code, monkeypatch, tmp_path):
    """A second Ctrl-C or SIGTERM during the landing cuts the motors (docs/flight.md): the flight
    ends as `emergency_stop` with the signal as its reason, and it exited 1, as after a safety stop,
    where README.md has a command stopped by Ctrl-C, SIGTERM or SIGHUP exit 128 + the signal's number.
    An emergency stop for another reason (a key, Ctrl-\\) still exits 1."""
    from pursuit_cli import main
    import pursuit_mj.flight.session as session
    from pursuit_mj.flight.bridge import FlightResult

    why = {"reason": reason}

    def cut_on(plan, policy, **kwargs):
        return FlightResult("emergency_stop", why["reason"], 3.0, 0, [], False, np.full(4, 0.4)), None

    monkeypatch.setattr(session, "run_flight", cut_on)
    argv = ["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--events", str(tmp_path / "e.jsonl")]
    assert main(argv) == code
    why["reason"] = "emergency stop"
    assert main(argv) == 1


@pytest.mark.parametrize("value, shown", [("3100", "3100 V"), ("0", "0 V"), ("12", "12 V"), ("4.5", "4.5 V")])
def test_a_battery_fault_of_no_single_cell_voltage_is_refused(value, shown):
    """`--fault battery:e0@2=3100` (millivolts) was taken as 3100 V: the drone flew on, the chase
    ended by its time limit, and the rehearsal of the low-battery landing passed without one; `=0`
    flew a battery of -0.11 V under load. The value is a Crazyflie's one-cell battery at rest, in
    volts, as safety.battery_takeoff and battery_land are (2.5 to 4.4 V)."""
    plan = load_plan(EXAMPLE)
    with pytest.raises(ValueError, match=rf"--fault 'battery:e0@2={value}': {shown} is not the resting voltage of a "
                                         rf"Crazyflie's one-cell battery \(2.5 to 4.4 V\)"):
        parse_fault(f"battery:e0@2={value}", plan)
    with pytest.raises(ValueError, match=r"\(2.5 to 4.4 V\); 3100 reads as millivolts: write 3.1$"):
        parse_fault("battery:e0@2=3100", plan)
    for ok in ("2.5", "3.1", "4.4"):
        assert parse_fault(f"battery:e0@2={ok}", plan).value == float(ok)


@pytest.mark.parametrize("override, words", [
    ("safety.max_speed=0.3", r"--set safety.max_speed=0.3: 'safety' is a section of the flight file, not a task key: --set "
                             r"changes the flight's task keys only; set it in .*mylab.yaml"),
    ("max_speed=0.3", r"--set max_speed=0.3: 'max_speed' is a safety limit of the flight file \(safety: max_speed\), not a task "
                      r"key: --set changes the flight's task keys only; set it in .*mylab.yaml"),
    ("task.pursuer_speed=0.3", r"--set task.pursuer_speed=0.3: fly's --set takes the task's keys themselves: --set pursuer_speed=0.3"),
    ("max_time=5", r"--set max_time=5: 'max_time' is a key of the flight file, not a task key: .*; --max-time 5 ends the chase after 5 s"),
    ("transform.yaw=1.0", r"--set transform.yaw=1.0: 'transform' is a section of the flight file"),
])
def test_fly_set_of_a_flight_file_key_says_set_takes_task_keys(override, words, tmp_path, capsys):
    """`fly --set safety.max_speed=0.3` said "unknown key 'safety' (did you mean 'fidelity'?)", and
    `--set max_speed=0.3` "did you mean 'max_steps'?": hints toward task keys a flight refuses or never
    reads, for a user tightening a safety limit. --set takes task keys (docs/flight.md); a key of the
    flight file, its safety limits or a `task.` prefix is named as such."""
    from pursuit_cli import main

    path = tmp_path / "mylab.yaml"
    path.write_text(yaml.safe_dump(flight()))
    assert main(["fly", "check", "--flight", str(path), "--set", override]) == 2
    err = capsys.readouterr().err
    assert __import__("re").search(words, err), err
    assert len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("text", ["", "# a flight file, all commented out\n# layout: 0\n"])
def test_an_empty_flight_file_is_named_empty(text, tmp_path, capsys):
    """An empty flight file (or one whose every line is commented out) said "missing key 'layout'",
    as if one key were left out; a task or layout file that holds nothing says it is empty."""
    from pursuit_cli import main

    path = tmp_path / "lab.yaml"
    path.write_text(text)
    assert main(["fly", "check", "--flight", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"pursuit-mj fly check: error: {path}: the file is empty (no flight key); a flight file sets at least "
                   f"layout, positioning and drones (see configs/flight/example.yaml)"), err


@pytest.mark.parametrize("outcome, code", [("timeout", 143), ("captured", 143), ("land_requested", 143)])
def test_a_flight_given_a_stop_signal_during_a_landing_for_another_reason_exits_as_a_stopped_command_does(outcome, code, monkeypatch,
                                                                                                             tmp_path, capsys):
    """A first SIGTERM while the drones land on time-out lets them land (docs/flight.md), but `fly` then
    exited 0 (1 after a land request): nothing said a signal came, where README.md has a command stopped
    by Ctrl-C, SIGTERM or SIGHUP exit 128 + its number. The summary line names it too."""
    from pursuit_cli import main
    import pursuit_mj.flight.session as session
    from pursuit_mj.flight.bridge import FlightResult

    def landed_on(plan, policy, **kwargs):
        return FlightResult(outcome, "no capture within 2 s", 2.0, 0, [], True, np.zeros(4), interrupted_by="SIGTERM"), None

    monkeypatch.setattr(session, "run_flight", landed_on)
    assert main(["fly", "--flight", EXAMPLE, "--policy", "heuristic", "--virtual", "--events", str(tmp_path / "e.jsonl")]) == code
    assert f"outcome: {outcome} (no capture within 2 s); SIGTERM during the landing; chase 2.0 s" in capsys.readouterr().out
