"""Controller quality on the quadrotor model (through BatchedPhysics), the mixer, the point fidelity.

Every flight is checked at every controller tick (a read-only physics observer), not only at
decision steps: altitude within 3 cm of flight_height and tilt never past 20 degrees.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from conftest import SPREAD_XY, make_physics

from pursuit_mj.config import DRONE_MAX_MASS
from pursuit_mj.controller import ControllerGains, VelocityController, mixer_matrix, quat_to_rotmat, tilt_angle
from pursuit_mj.scene import DRONE_FILE, drone_parameters

MAX_ALT_ERROR = 0.03  # m
MAX_TILT = math.radians(20.0)


class FlightLog:
    """Observer: per controller tick, time (s), velocity (D, 3), position (D, 3), tilt (D,) of world 0."""

    def __init__(self, physics):
        self.t, self.vel, self.pos, self.tilt = [], [], [], []
        physics.observers.append(self)

    def __call__(self, p) -> None:
        self.t.append((len(self.t) + 1) * p.config.substeps_per_control * p.config.physics_dt)
        self.vel.append(p.velocities()[0])
        self.pos.append(p.positions()[0])
        self.tilt.append(tilt_angle(p.quaternions()[0]))

    def arrays(self):
        return np.array(self.t), np.array(self.vel), np.array(self.pos), np.array(self.tilt)


def fly(physics, commands) -> FlightLog:
    """Run the decision-step commands (K, D, 2) m/s in world 0 and log every controller tick."""
    log = FlightLog(physics)
    for cmd in commands:
        physics.step(cmd[None])
    return log


def assert_safe(log: FlightLog, height: float) -> None:
    _, vel, pos, tilt = log.arrays()
    assert np.isfinite(vel).all() and np.isfinite(pos).all()
    worst_dz = np.abs(pos[..., 2] - height).max()
    assert worst_dz < MAX_ALT_ERROR, f"altitude error {worst_dz:.4f} m"
    assert tilt.max() < MAX_TILT, f"tilt {math.degrees(tilt.max()):.1f} deg"


# ----------------------------------------------------------------------------- step response


#: the default controller rate (the lowest of the design's 100-500 Hz), and 250 Hz
RATES = [pytest.param({}, id="default-rate"), pytest.param({"controller_hz": 250.0}, id="250Hz")]


#: a lab Crazyflie with a deck, markers and a bigger battery (33 g), and the heaviest drone_mass accepted
HEAVY = [pytest.param({"drone_mass": 0.033}, id="33g"), pytest.param({"drone_mass": DRONE_MAX_MASS}, id="max-mass")]


@pytest.mark.parametrize("rate", RATES + HEAVY)
def test_step_response_of_0_3_m_s_meets_rise_overshoot_and_steady_error(rate):
    physics = make_physics(**rate)
    step = np.zeros((30, 4, 2))  # 3 s
    step[:, 0] = [0.3, 0.0]  # pursuer_0 along x
    step[:, 1] = [0.0, -0.3]  # pursuer_1 along -y
    step[:, 2] = [0.3 / math.sqrt(2)] * 2  # pursuer_2 diagonally
    step[:, 3] = [-0.3, 0.0]  # the evader, below its max speed
    log = fly(physics, step)
    t, vel, _, _ = log.arrays()
    for d in range(4):
        target = step[0, d]
        along = vel[:, d, :2] @ target / 0.3  # velocity along the command (m/s)
        t90 = t[np.argmax(along >= 0.9 * 0.3)]
        assert along.max() >= 0.9 * 0.3 and t90 <= 0.8, f"drone {d}: 90 % reached at {t90:.3f} s"
        assert along.max() < 1.15 * 0.3, f"drone {d}: overshoot {along.max() / 0.3 - 1:.1%}"
        steady = vel[t >= 2.0, d, :2].mean(0)
        assert np.linalg.norm(steady - target) < 0.02 * 0.3, f"drone {d}: steady velocity {steady}"
    assert_safe(log, physics.config.flight_height)


@pytest.mark.parametrize("rate", RATES)
def test_full_speed_reversal_stays_stable(rate):
    physics = make_physics(**rate)
    cmd = np.zeros((40, 4, 2))
    cmd[:20, :, 0] = physics.max_speed  # +0.3 pursuers, +0.6 evader
    cmd[20:, :, 0] = -physics.max_speed
    log = fly(physics, cmd)
    assert_safe(log, physics.config.flight_height)
    _, vel, _, _ = log.arrays()
    np.testing.assert_allclose(vel[-1, :, 0], -physics.max_speed, rtol=0.02)


@pytest.mark.parametrize("rate", RATES + HEAVY)
def test_random_command_sequence_stays_stable(rate):
    """With a new command every 0.1 s the rotors run out of headroom first on a heavy drone:
    at the heaviest drone_mass (thrust-to-weight 1.5) it sags 1.4 cm; at 1.36 (45 g) it
    would sag 3.5 cm, past MAX_ALT_ERROR, and at 1.22 (50 g) 18 cm."""
    physics = make_physics(**rate)
    rng = np.random.default_rng(7)
    cmd = rng.uniform(-1.0, 1.0, (100, 4, 2)) * physics.max_speed[:, None]  # a new command every 0.1 s
    log = fly(physics, cmd)
    assert_safe(log, physics.config.flight_height)
    _, vel, _, _ = log.arrays()
    assert np.linalg.norm(vel[..., :2], axis=-1).max() < 1.2 * physics.max_speed.max()


@pytest.mark.parametrize("mass", [0.027, 0.033, DRONE_MAX_MASS], ids=["27g", "33g", "max-mass"])
def test_a_drone_of_the_configured_mass_hovers_at_flight_height_on_its_weight(mass):
    """The scene's body and the controller's weight feed-forward both take drone_mass: the
    rotors carry that weight (not the model file's 27 g) and the height holds from the start."""
    physics = make_physics(drone_mass=mass)
    assert [physics.model().body(f"{n}/body").mass[0] for n in physics.names] == [mass] * 4
    log = fly(physics, np.zeros((20, 4, 2)))
    assert_safe(log, physics.config.flight_height)
    np.testing.assert_allclose(physics.state().thrust[0].sum(-1), mass * 9.81, rtol=1e-3)
    np.testing.assert_allclose(physics.positions()[0, :, 2], physics.config.flight_height, atol=1e-3)


def test_hover_from_rest_drifts_under_1_cm_in_5_s():
    physics = make_physics()
    log = fly(physics, np.zeros((50, 4, 2)))
    assert_safe(log, physics.config.flight_height)
    drift = np.linalg.norm(physics.positions()[0, :, :2] - SPREAD_XY, axis=-1)
    assert drift.max() < 0.01
    yaw = np.arctan2(quat_to_rotmat(physics.quaternions()[0].T)[3], quat_to_rotmat(physics.quaternions()[0].T)[0])
    assert np.abs(yaw).max() < 1e-3


# ----------------------------------------------------------------------------- mixer


@pytest.fixture(scope="module")
def params():
    return drone_parameters()


def test_mixer_matches_hand_computed_allocation(params):
    """The signs are the Crazyflie firmware's (powerDistributionForceTorque in
    power_distribution_quadrotor.c): M1 = T/4 - roll - pitch - yaw, M2 = + pitch + yaw - roll,
    M3 = + roll + pitch - yaw, M4 = + roll - pitch + yaw. So M1 and M3 spin counter-clockwise
    seen from above (their reaction torque is clockwise, -z) and M2 and M4 clockwise."""
    arm = 0.046 / math.sqrt(2)  # motors on the diagonals, 46 mm from the centre
    ratio = 0.006  # reaction torque per newton of thrust (m)
    inv = VelocityController(params, 0.5).mixer_inv
    cases = {  # wrench [T, tau_x, tau_y, tau_z] -> rotor thrusts (M1 front-right, then clockwise from above)
        (0.28, 0, 0, 0): [0.07, 0.07, 0.07, 0.07],
        (0, 1e-3, 0, 0): np.array([-1, -1, 1, 1]) * 1e-3 / (4 * arm),  # roll right-side-down: left rotors push
        (0, 0, 1e-3, 0): np.array([-1, 1, 1, -1]) * 1e-3 / (4 * arm),  # pitch nose-down: rear rotors push
        (0, 0, 0, 1e-4): np.array([-1, 1, -1, 1]) * 1e-4 / (4 * ratio),  # yaw left: clockwise rotors M2, M4 push
    }
    for wrench, expected in cases.items():
        np.testing.assert_allclose(inv @ np.array(wrench), expected, rtol=1e-3, atol=1e-9, err_msg=str(wrench))


def test_mixer_matches_mujoco_actuator_forces(params):
    """The allocation the controller inverts is the one MuJoCo applies to the body."""
    model = mujoco.MjModel.from_xml_path(str(DRONE_FILE))
    data = mujoco.MjData(model)
    allocation = mixer_matrix(params["motor_xy"], params["yaw_ratio"])
    rng = np.random.default_rng(1)
    for f in rng.uniform(0.0, params["max_thrust"], (5, 4)):
        data.act[:] = f  # the filtered thrust is what the actuator applies
        mujoco.mj_forward(model, data)
        wrench = data.qfrc_actuator[[2, 3, 4, 5]]  # world z force and body torques (identity attitude)
        np.testing.assert_allclose(wrench, allocation @ f, rtol=1e-9, atol=1e-12)


def test_controller_treats_every_drone_independently(params):
    """Computing N drones at once equals computing each alone (no mixing across the batch)."""
    rng = np.random.default_rng(2)
    n = 6
    q = rng.normal(size=(4, n)) + np.array([[3.0], [0], [0], [0]])
    q /= np.linalg.norm(q, axis=0)
    state = (rng.normal(0.5, 0.05, (3, n)), rng.normal(0, 0.3, (3, n)), q, rng.normal(0, 1.0, (3, n)), rng.normal(0, 0.3, (2, n)))
    together = VelocityController(params, 0.5).compute(*state, 0.004)
    for i in range(n):
        alone = VelocityController(params, 0.5).compute(*(a[:, i : i + 1] for a in state), 0.004)
        np.testing.assert_allclose(together[:, i : i + 1], alone, rtol=1e-12, atol=1e-15)
    assert (together >= 0).all() and (together <= params["max_thrust"]).all()


@pytest.mark.parametrize("held_at", [0.5, 1.5], ids=["held-down", "pushed-up"])
def test_altitude_integral_does_not_wind_up_while_the_rotors_saturate(params, held_at):
    """Held 0.5 m off its flight height for 5 s (all rotors at full thrust, or the thrust at its
    floor), a drone released at its height at rest asks for its hover thrust, not the clamp of
    an integral gathered meanwhile (0.2 m s x int_z x mass = 0.02 N, a slow 3 cm overshoot)."""
    ctrl = VelocityController(params, 1.0)
    level = np.array([[1.0], [0.0], [0.0], [0.0]])
    still = (np.zeros((3, 1)), level, np.zeros((3, 1)), np.zeros((2, 1)))
    held = np.array([[0.0], [0.0], [held_at]])
    for _ in range(500):
        thrusts = ctrl.compute(held, *still, 0.01)
    saturated = params["max_thrust"] if held_at < 1.0 else 0.0
    np.testing.assert_allclose(thrusts, saturated, atol=0.02)  # the rotors are at their limit
    released = ctrl.compute(np.array([[0.0], [0.0], [1.0]]), *still, 0.01)
    assert abs(released.sum() - params["mass"] * 9.81) < 1e-3


def test_saturated_rotors_keep_the_torques_and_give_up_collective_thrust_as_the_firmware_does(params):
    """Held 0.5 m below its height and tilted 20 deg in roll, a drone asks for more than full thrust.
    Clipping each rotor alone (as before) left all four at full thrust: no torque to level it.
    The firmware lowers all four by the excess instead (powerDistributionCap), keeping the
    rotors' differences, so the righting torque survives and the collective thrust gives."""
    ctrl = VelocityController(params, 1.0)
    angle = math.radians(20.0)
    tilted = np.array([[math.cos(angle / 2)], [math.sin(angle / 2)], [0.0], [0.0]])  # rolled about x
    thrusts = ctrl.compute(np.array([[0.0], [0.0], [0.5]]), np.zeros((3, 1)), tilted, np.zeros((3, 1)), np.zeros((2, 1)), 0.01)
    assert thrusts.max() == pytest.approx(params["max_thrust"]) and thrusts.min() < 0.9 * params["max_thrust"]
    torque = mixer_matrix(params["motor_xy"], params["yaw_ratio"]) @ thrusts[:, 0]
    assert torque[1] < -1e-4  # a negative roll torque, back toward level
    assert (thrusts >= 0).all()


def test_altitude_integral_still_removes_a_small_steady_offset(params):
    """Unsaturated, the integral grows at the rate of its gain: 1 cm below for 5 s adds mass x int_z x 0.05 m s
    of thrust beyond the P term (without the time step in the sum it grew 100 times faster)."""
    ctrl = VelocityController(params, 1.0)
    still = (np.zeros((3, 1)), np.array([[1.0], [0.0], [0.0], [0.0]]), np.zeros((3, 1)), np.zeros((2, 1)))
    first = ctrl.compute(np.array([[0.0], [0.0], [0.99]]), *still, 0.01).sum()
    for _ in range(500):
        last = ctrl.compute(np.array([[0.0], [0.0], [0.99]]), *still, 0.01).sum()
    g = ControllerGains()
    assert last - first == pytest.approx(params["mass"] * g.int_z * 0.01 * 5.0, rel=0.02)


def test_rotation_matrix_matches_mujoco(params):
    rng = np.random.default_rng(3)
    q = rng.normal(size=(4, 8))
    q /= np.linalg.norm(q, axis=0)
    ours = quat_to_rotmat(q)
    for i in range(8):
        ref = np.zeros(9)
        mujoco.mju_quat2Mat(ref, q[:, i])
        np.testing.assert_allclose(ours[:, i], ref, atol=1e-12)


# ----------------------------------------------------------------------------- point fidelity


def test_point_fidelity_is_a_first_order_lag(params):
    physics = make_physics("point")
    tau = params["point_time_constant"]
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0] = [0.3, 0.0]
    cmd[0, 3] = [0.0, -0.4]  # below tau x the acceleration limit: the lag alone shapes the response
    assert 0.4 / tau < params["point_max_accel"]
    for k in range(1, 8):
        physics.step(cmd)
        expected = cmd[0, :, :] * (1 - math.exp(-k * physics.config.control_dt / tau))
        np.testing.assert_allclose(physics.velocities()[0, :, :2], expected, atol=1e-9, err_msg=f"after {k} steps")
    assert np.all(physics.positions()[..., 2] == physics.config.flight_height)


def test_point_fidelity_accelerates_no_harder_than_the_quadrotor_may_tilt(params):
    assert params["point_max_accel"] == pytest.approx(9.81 * math.tan(ControllerGains().max_tilt), rel=1e-3)
    physics = make_physics("point", pursuer_speed=0.6)  # pursuers' commands are clipped to their speed
    cmd = np.zeros((1, 4, 2))
    cmd[0, :, 0] = 0.6
    for _ in range(20):
        physics.step(cmd)
    v0 = physics.velocities()[0, :, 0].copy()
    physics.step(-cmd)  # a reversal asks for 1.2 m/s at once: the limit, not the lag, sets the pace
    dv = v0 - physics.velocities()[0, :, 0]
    np.testing.assert_allclose(dv, params["point_max_accel"] * physics.config.control_dt, rtol=0.02)


def test_point_fidelity_acceleration_limit_holds_in_every_direction(params):
    # per-axis force limits let a diagonal reversal reach sqrt(2) times the limit
    physics = make_physics("point", pursuer_speed=0.6)
    diagonal = np.zeros((1, 4, 2))
    diagonal[0, :] = 0.6 / math.sqrt(2)
    for _ in range(20):
        physics.step(diagonal)
    v0 = physics.velocities()[0, :, :2].copy()
    physics.step(-diagonal)
    dv = np.linalg.norm(v0 - physics.velocities()[0, :, :2], axis=-1)
    np.testing.assert_allclose(dv, params["point_max_accel"] * physics.config.control_dt, rtol=0.02)


def _time_to_90_percent(physics, start: float, target: float, steps: int) -> float:
    """Seconds until pursuer_0's x velocity, commanded from `start` to `target` (m/s), has covered 90 % of the change."""
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0, 0] = start
    for _ in range(20 if start else 0):
        physics.step(cmd)
    log = FlightLog(physics)
    cmd[0, 0, 0] = target
    for _ in range(steps):
        physics.step(cmd)
    t, vel, _, _ = log.arrays()
    progress = (vel[:, 0, 0] - start) / (target - start)
    assert progress.max() >= 0.9
    return float(t[np.argmax(progress >= 0.9)])


@pytest.mark.parametrize("mass", [0.027, DRONE_MAX_MASS], ids=["27g", "max-mass"])
@pytest.mark.parametrize("start, target", [(0.0, 0.3), (0.6, -0.6)], ids=["step", "reversal"])
def test_point_fidelity_matches_the_quadrotor_closed_loop(start, target, mass):
    """DESIGN.md section 3: the point drone's lag and acceleration limit are matched to the
    quadrotor's closed loop (in distance it still stops sooner; see the test below):
    the time to 90 % of a velocity step (lag-bound) or of a reversal (limit-bound) agrees
    within 0.05 s (measured: 0.46 vs 0.47 s and 0.58 vs 0.56 s at the default rates). The
    match holds for any accepted drone_mass (0.45 and 0.58 s at 40.8 g): the controller scales
    its forces with the mass and the tilt limit, not the thrust, caps the acceleration while
    the rotors lift 1.5 times the weight (a 15 deg tilt needs 1.035 times)."""
    times = {fid: _time_to_90_percent(make_physics(fid, pursuer_speed=0.6, drone_mass=mass), start, target, 15)
             for fid in ("quadrotor", "point")}
    assert abs(times["point"] - times["quadrotor"]) <= 0.05, times


def _run_on(fidelity: str, speed: float, then: float) -> float:
    """m pursuer_0 travels on along +x after flying at `speed` m/s and being commanded to
    `then` x speed (0: stop, -1: reverse), measured at every controller tick."""
    physics = make_physics(fidelity, pursuer_speed=max(speed, 0.3))
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0, 0] = speed
    for _ in range(20):
        physics.step(cmd)
    start, xs = physics.positions()[0, 0, 0], []
    physics.observers.append(lambda p: xs.append(p.positions()[0, 0, 0]))
    cmd[0, 0, 0] = then * speed
    for _ in range(15):
        physics.step(cmd)
    return max(xs) - start


def test_design_md_states_how_much_sooner_a_point_drone_stops_than_the_quadrotor():
    """DESIGN.md section 3 said the matched lag and limit keep a point drone from turning or
    dodging faster than a Crazyflie; in distance it does both faster (the quadrotor first has to
    tilt: about 0.1 s before its velocity moves). The run-on distances it states now are these
    flights' (cm, within 0.3 cm)."""
    import re
    from pathlib import Path

    text = " ".join((Path(__file__).resolve().parent.parent / "docs" / "DESIGN.md").read_text().split())
    found = re.search(r"commanded to stop from 0\.3 m/s a point drone runs on ([0-9.]+) cm, a quadrotor ([0-9.]+); "
                      r"reversed, ([0-9.]+) and ([0-9.]+) cm \(from 0\.6 m/s: ([0-9.]+) and ([0-9.]+), ([0-9.]+) and ([0-9.]+)\)", text)
    assert found, "DESIGN.md section 3 does not state the point and quadrotor run-on distances"
    stated = [float(x) / 100 for x in found.groups()]
    measured = [_run_on(fid, speed, then) for speed in (0.3, 0.6) for then in (0.0, -1.0) for fid in ("point", "quadrotor")]
    np.testing.assert_allclose(measured, stated, atol=0.003)


@pytest.mark.parametrize("yaw_deg", [90.0, 170.0, 180.0, -135.0])
def test_a_drone_facing_away_from_yaw_zero_turns_back_and_follows_the_command(yaw_deg):
    """The attitude error of the yaw-0 frame vanishes at a yaw of 180 deg: a drone turned round
    ignored every velocity command, and at 170 deg still flew sideways half a second on."""
    physics = make_physics("quadrotor")
    yaw = math.radians(yaw_deg)
    qpos = physics.qpos[[0]]
    qpos[0, physics._qpos_idx[0, 3:7]] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    physics.qpos[[0]] = qpos
    physics.batch.forward(np.array([0]))
    commands = np.zeros((1, physics.n_drones, 2))
    commands[0, 0] = [0.3, 0.0]
    for _ in range(15):  # 1.5 s
        physics.step(commands)
    state = physics.state()
    w, x, y, z = state.quat[0, 0]
    assert abs(math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))) < 5.0
    assert state.vel[0, 0, 0] > 0.25 and abs(state.vel[0, 0, 1]) < 0.05
    assert abs(state.pos[0, 0, 2] - physics.config.flight_height) < 0.05


def _roll_pitch(quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll and pitch (rad, ZYX Euler angles as the Crazyflie firmware has them) of quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(quat, -1, 0)
    return np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)), np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))


def _reversals(physics) -> dict[str, tuple[float, float, float]]:
    """Pursuer_0 reversed from 0.6 m/s along the diagonal (1, 1), pursuer_1 along x: for each,
    its time to 90 % of the change (s), its largest tilt and its largest roll or pitch (rad)."""
    directions = {"diagonal": np.array([1.0, 1.0]) / math.sqrt(2), "x": np.array([1.0, 0.0])}
    cmd = np.zeros((1, 4, 2))
    cmd[0, :2] = 0.6 * np.array(list(directions.values()))
    for _ in range(20):
        physics.step(cmd)
    log, quats = FlightLog(physics), []
    physics.observers.append(lambda p: quats.append(p.quaternions()[0, :2]))
    for _ in range(15):
        physics.step(-cmd)
    t, vel, _, tilt = log.arrays()
    roll, pitch = _roll_pitch(np.array(quats))
    out = {}
    for d, (name, direction) in enumerate(directions.items()):
        progress = (0.6 - vel[:, d, :2] @ direction) / 1.2
        out[name] = (float(t[np.argmax(progress >= 0.9)]), float(tilt[:, d].max()), float(max(np.abs(roll[:, d]).max(), np.abs(pitch[:, d]).max())))
    return out


def test_roll_and_pitch_limits_hold_each_axis_as_the_firmware_velocity_loop_does():
    """The Crazyflie firmware's velocity loop (position_controller_pid.c) limits roll and pitch each
    (posCtlPid.rLimit, pLimit), not the tilt: at 15 deg each a drone tilts up to 20-21 deg on a
    diagonal and reverses there sooner than under the simulator's 15 deg tilt limit (0.49 s
    against 0.58 to 90 % of a reversal from 0.6 m/s); along an axis the two limits are the same.
    The virtual Crazyflies fly their firmware's limits so."""
    cone = _reversals(make_physics(pursuer_speed=0.6))
    box_physics = make_physics(pursuer_speed=0.6)
    box_physics.controller.set_roll_pitch_limits(math.radians(15.0), math.radians(15.0))
    box = _reversals(box_physics)
    assert box["x"][0] == cone["x"][0] and math.degrees(box["x"][1]) < 15.5
    assert math.degrees(cone["diagonal"][1]) < 15.5 and math.degrees(box["diagonal"][1]) > 19.5
    assert math.degrees(box["diagonal"][2]) < 15.5  # neither roll nor pitch past its limit
    assert box["diagonal"][0] <= cone["diagonal"][0] - 0.07, (box, cone)


def test_roll_and_pitch_limits_are_checked_like_the_tilt_limit(params):
    ctrl = VelocityController(params, 0.5)
    with pytest.raises(ValueError, match=r"set_roll_pitch_limits: roll limits must be in \(0, pi/2\) rad, got \[0.2 2. \]"):
        ctrl.set_roll_pitch_limits(np.array([0.2, 2.0]), 0.2)
    with pytest.raises(ValueError, match=r"set_roll_pitch_limits: pitch limits must be in \(0, pi/2\) rad, got nan"):
        ctrl.set_roll_pitch_limits(0.2, float("nan"))


def test_a_drone_tipped_past_90_deg_rights_itself_whatever_its_yaw():
    """The attitude error on SO(3) fades as the rotation from the desired frame nears 180 deg:
    tipped 100 deg about its pitch axis while turned 90 or 180 deg from yaw 0 (as a collision
    may leave it), a drone fell upside down to the floor, where at yaw 0 it rights itself in
    0.3 s. Tipped past 90 deg, it now turns its thrust back up first, the shorter way."""
    yaws = [0.0, 90.0, 180.0, -90.0, 135.0]
    physics = make_physics(n_worlds=len(yaws), flight_height=1.5)
    pitch = math.radians(100.0)
    for w, yaw in enumerate(np.radians(yaws)):
        qw, qz, pw, py = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
        qpos = physics.qpos[[w]]
        qpos[0, physics._qpos_idx[0, 3:7]] = [qw * pw, -qz * py, qw * py, qz * pw]  # yaw, then pitch about the body's y
        physics.qpos[[w]] = qpos
    physics.batch.forward(np.arange(len(yaws)))
    assert np.degrees(tilt_angle(physics.quaternions()[:, 0])) == pytest.approx([100.0] * len(yaws))
    for _ in range(25):  # 2.5 s
        physics.step(np.zeros((len(yaws), physics.n_drones, 2)))
    assert (np.degrees(tilt_angle(physics.quaternions()[:, 0])) < 2.0).all()
    assert (physics.positions()[:, 0, 2] > 1.0).all(), physics.positions()[:, 0, 2]


# ----------------------------------------------------------------------------- mutation audit


def test_linear_drag_is_minus_r_diag_c_r_transpose_v():
    from pursuit_mj.controller import linear_drag

    rng = np.random.default_rng(0)
    q = rng.normal(size=(4, 6))
    q /= np.linalg.norm(q, axis=0)
    rot = quat_to_rotmat(q)
    vel = rng.normal(size=(3, 6))
    coeff = np.array([0.01, 0.01, 0.03])  # z unlike x and y, as it may be
    got = linear_drag(rot, vel, coeff)
    for i in range(6):
        R = rot[:, i].reshape(3, 3)
        np.testing.assert_allclose(got[:, i], -R @ np.diag(coeff) @ R.T @ vel[:, i], rtol=1e-12, atol=1e-15)


def _roll_pitch_of(force: np.ndarray) -> tuple[float, float]:
    """(roll, pitch) rad of a thrust direction (3,), ZYX Euler angles at yaw 0."""
    return math.atan2(-force[1], math.hypot(force[0], force[2])), math.atan2(force[0], force[2])


def test_roll_and_pitch_limits_bring_a_steep_force_to_both_limits_exactly():
    from pursuit_mj.controller import _limit_roll_pitch

    force = np.array([[2.0], [-3.0], [1.0]])  # pitch 63 deg, roll 53 deg asked
    _limit_roll_pitch(force, math.radians(15.0), math.radians(10.0))
    assert force[2, 0] == 1.0  # the vertical part is kept
    roll, pitch = _roll_pitch_of(force[:, 0])
    assert math.degrees(roll) == pytest.approx(15.0) and math.degrees(pitch) == pytest.approx(10.0)


@pytest.mark.parametrize("yaw_deg", [30.0, 90.0, -120.0])
def test_roll_and_pitch_limits_hold_along_the_axes_of_the_drone_s_heading(yaw_deg):
    # a force limited for a drone facing yaw is the force turned into its frame, limited there
    # as for yaw 0, and turned back
    from pursuit_mj.controller import _limit_roll_pitch

    yaw = math.radians(yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    force = np.array([[0.5], [1.0], [1.0]])
    own = np.array([[c * 0.5 + s * 1.0], [c * 1.0 - s * 0.5], [1.0]])  # in the drone's frame
    _limit_roll_pitch(own, math.radians(40.0), math.radians(5.0))
    _limit_roll_pitch(force, math.radians(40.0), math.radians(5.0), (np.array([c]), np.array([s])))
    np.testing.assert_allclose(force[:, 0], [c * own[0, 0] - s * own[1, 0], s * own[0, 0] + c * own[1, 0], 1.0], atol=1e-12)


def test_a_tilt_of_90_deg_or_more_is_refused(params):
    ctrl = VelocityController(params, 0.5)
    for bad in (math.pi / 2, 2.0, 0.0):
        with pytest.raises(ValueError, match=r"set_max_tilt: tilt limits must be in \(0, pi/2\) rad"):
            ctrl.set_max_tilt(bad)


LEVEL = np.array([[1.0], [0.0], [0.0], [0.0]])


def _still(quat: np.ndarray = LEVEL, angvel: np.ndarray | None = None) -> tuple:
    """(vel, quat, angvel, v_cmd) of one drone at rest, asked to stay."""
    return np.zeros((3, 1)), quat, np.zeros((3, 1)) if angvel is None else angvel, np.zeros((2, 1))


def test_the_altitude_integral_is_clamped_at_0_2_m_s(params):
    # 1 cm low for 50 s (unsaturated throughout) would gather 0.5 m s: the clamp holds 0.2
    ctrl = VelocityController(params, 1.0)
    low = np.array([[0.0], [0.0], [0.99]])
    for _ in range(5000):
        thrust = ctrl.compute(low, *_still(), 0.01).sum()
    g, m = ControllerGains(), params["mass"]
    assert thrust == pytest.approx(m * (9.81 + g.pos_z * 0.01 + g.int_z * 0.2), rel=1e-9)


def test_drones_kept_out_of_a_call_and_a_plain_reset_leave_no_integral_behind(params):
    low = np.tile([[0.0], [0.0], [0.99]], (1, 2))
    still = tuple(np.tile(a, (1, 2)) for a in _still())
    fresh = VelocityController(params, 1.0).compute(low, *still, 0.01)
    ctrl = VelocityController(params, 1.0)
    for _ in range(100):
        ctrl.compute(low, *still, 0.01, keep=np.array([True, False]))
    after = ctrl.compute(low, *still, 0.01)
    np.testing.assert_allclose(after[:, 0], fresh[:, 0], rtol=1e-12)  # drone 0 was kept: nothing gathered
    assert after[:, 1].sum() > fresh[:, 1].sum() + 1e-4  # drone 1 gathered an integral
    ctrl.reset(2)  # the same size, no mask: every drone is cleared
    np.testing.assert_allclose(ctrl.compute(low, *still, 0.01), fresh, rtol=1e-12)


def test_a_tilted_drone_asks_for_the_thrust_along_its_own_z_axis(params):
    # hovering at its height, at rest, rolled 10 deg: the force wanted is its weight, straight
    # up; the rotors can only push along body z, so the collective thrust is weight * cos(10 deg)
    ctrl = VelocityController(params, 1.0)
    angle = math.radians(10.0)
    rolled = np.array([[math.cos(angle / 2)], [math.sin(angle / 2)], [0.0], [0.0]])
    thrusts = ctrl.compute(np.array([[0.0], [0.0], [1.0]]), *_still(rolled), 0.01)
    assert thrusts.sum() == pytest.approx(params["mass"] * 9.81 * math.cos(angle), rel=1e-9)


def test_the_rate_loop_feeds_the_gyroscopic_torque_forward(params):
    # level, at rest in position, spinning at w: the torque asked is I k (0 - w) + w x (I w)
    ctrl = VelocityController(params, 1.0)
    w = np.array([0.3, -0.2, 0.5])
    thrusts = ctrl.compute(np.array([[0.0], [0.0], [1.0]]), *_still(angvel=w[:, None]), 0.01)
    assert (thrusts > 0).all() and (thrusts < params["max_thrust"]).all()  # no rotor clipped
    torque = (mixer_matrix(params["motor_xy"], params["yaw_ratio"]) @ thrusts[:, 0])[1:]
    inertia = np.asarray(params["inertia"])
    want = inertia * np.asarray(ControllerGains().rate) * -w + np.cross(w, inertia * w)
    np.testing.assert_allclose(torque, want, rtol=1e-9, atol=1e-14)


def test_set_max_tilt_replaces_roll_and_pitch_limits(params):
    state = (np.array([[0.0], [0.0], [1.0]]), np.zeros((3, 1)), LEVEL, np.zeros((3, 1)), np.array([[0.6], [0.6]]))
    tilt = VelocityController(params, 1.0)
    tilt.set_max_tilt(math.radians(15.0))
    switched = VelocityController(params, 1.0)
    switched.set_roll_pitch_limits(math.radians(15.0), math.radians(15.0))
    switched.set_max_tilt(math.radians(15.0))
    np.testing.assert_array_equal(switched.compute(*state, 0.01), tilt.compute(*state, 0.01))


@pytest.mark.parametrize("yaw_deg", [0.0, 70.0])
def test_a_tipped_drone_is_turned_back_at_max_rate_about_a_horizontal_body_axis(yaw_deg):
    from pursuit_mj.controller import _right_tipped_drones

    yaw, pitch = math.radians(yaw_deg), math.radians(120.0)
    q = np.array([[math.cos(yaw / 2) * math.cos(pitch / 2)], [-math.sin(yaw / 2) * math.sin(pitch / 2)],
                  [math.cos(yaw / 2) * math.sin(pitch / 2)], [math.sin(yaw / 2) * math.cos(pitch / 2)]])
    cols = quat_to_rotmat(q).reshape(3, 3, 1).transpose(1, 0, 2)
    rate = np.array([[0.1], [0.2], [0.3]])  # what the attitude loop asked
    _right_tipped_drones(rate, cols, np.array([[0.0], [0.0], [1.0]]), 6.0)
    assert np.hypot(rate[0, 0], rate[1, 0]) == pytest.approx(6.0) and rate[2, 0] == 0.0
    assert rate[1, 0] < 0  # pitched +120 deg about body y: back the shorter way, negative about y


def test_no_rotor_thrust_outside_0_to_max_reaches_mujoco_even_in_a_head_on_crash(params):
    """Two drones meet head on at 3 m/s each (the fastest speed accepted) and tumble past 90 deg;
    at every physics step (the controller ticks at each: 1 kHz on 1 ms steps) every rotor's
    command (ctrl) and the filtered thrust MuJoCo applies (act) stay within [0, max_thrust]."""
    xy = SPREAD_XY.copy()
    xy[0], xy[3] = [9.0, 10.0], [11.0, 10.02]  # a little off centre, so that they tumble
    physics = make_physics(xy=xy, pursuer_speed=3.0, evader_speed=3.0, physics_dt=0.001, controller_hz=1000.0)
    seen = {"act": [], "ctrl": [], "tilt": []}

    def record(p):
        seen["act"].append(p.act[0, p._act_idx])
        seen["ctrl"].append(p.ctrl[0, p._ctrl_idx])
        seen["tilt"].append(tilt_angle(p.quaternions()[0]))

    physics.observers.append(record)
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0], cmd[0, 3] = [3.0, 0.0], [-3.0, 0.0]
    touched = np.zeros(4, bool)
    for _ in range(15):
        touched |= physics.step(cmd)[0]
    assert touched[0] and touched[3] and math.degrees(np.max(seen["tilt"])) > 90.0  # a real crash
    for name in ("act", "ctrl"):
        values = np.array(seen[name])
        assert values.min() >= 0.0 and values.max() <= params["max_thrust"], (name, values.min(), values.max())
    assert np.array(seen["act"]).max() > 0.99 * params["max_thrust"]  # the limit was reached, and held
