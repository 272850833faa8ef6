"""Cascaded velocity-tracking controller for quadrotors, vectorised over any number of drones.

velocity error -> desired acceleration -> desired thrust vector (tilt + collective thrust,
altitude held at a reference height) -> attitude error on SO(3) -> desired body rates ->
rate error -> body torques -> mixer -> four rotor thrusts.

It knows nothing of MuJoCo: `compute(state arrays, command) -> thrusts`. Arrays are
component-major: (components, N) for N drones (any flattening of worlds x drones), so that
every operation runs over long contiguous rows; this code runs hundreds of times per
simulated second inside the physics loop. Frames: world z up; quaternions w, x, y, z
(body to world, unit norm); angular velocity in the body frame. Rotation matrices are
(9, N): row 3 i + j holds R[i, j], so R.reshape(3, 3, N)[:, j] is body axis j in the world.
"""

from __future__ import annotations

import dataclasses

import numpy as np

GRAVITY = 9.81  # m/s^2

# R (9, N) = _QQ_TO_R @ (q_i q_j for the 10 pairs i <= j) + _R_OFFSET, for unit quaternions
_PAIR_I = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 3])
_PAIR_J = np.array([0, 1, 2, 3, 1, 2, 3, 2, 3, 3])
_PAIR = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(_PAIR_I, _PAIR_J))}
_QQ_TO_R = np.zeros((9, 10))
_R_OFFSET = np.array([1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0])[:, None]
for _entry, _terms in {
    0: ((2, 2, -2), (3, 3, -2)),  # R00 = 1 - 2 (y^2 + z^2)
    1: ((1, 2, 2), (0, 3, -2)),  # R01 = 2 (x y - w z)
    2: ((1, 3, 2), (0, 2, 2)),  # R02 = 2 (x z + w y)
    3: ((1, 2, 2), (0, 3, 2)),  # R10 = 2 (x y + w z)
    4: ((1, 1, -2), (3, 3, -2)),  # R11 = 1 - 2 (x^2 + z^2)
    5: ((2, 3, 2), (0, 1, -2)),  # R12 = 2 (y z - w x)
    6: ((1, 3, 2), (0, 2, -2)),  # R20 = 2 (x z - w y)
    7: ((2, 3, 2), (0, 1, 2)),  # R21 = 2 (y z + w x)
    8: ((1, 1, -2), (2, 2, -2)),  # R22 = 1 - 2 (x^2 + y^2)
}.items():
    for _i, _j, _c in _terms:
        _QQ_TO_R[_entry, _PAIR[_i, _j]] += _c


# cyclic index shifts for cross products written per component: (a x b)_i = a_{i+1} b_{i+2} - a_{i+2} b_{i+1}
_NEXT1 = np.array([1, 2, 0])
_NEXT2 = np.array([2, 0, 1])


@dataclasses.dataclass(frozen=True)
class ControllerGains:
    """Loop gains (SI). Tuned on models/crazyflie.xml; see tests/test_controller.py."""

    vel_xy: float = 4.0  # 1/s: desired horizontal acceleration per m/s of velocity error
    pos_z: float = 30.0  # 1/s^2: vertical acceleration per m of altitude error
    vel_z: float = 11.0  # 1/s: vertical acceleration per m/s of vertical velocity (about critical damping)
    int_z: float = 4.0  # 1/s^3: integral of altitude error (battery, lag, drag bias)
    max_tilt: float = float(np.radians(15.0))  # rad: limit on the commanded tilt
    att: tuple[float, float, float] = (10.0, 10.0, 6.0)  # 1/s: rate per rad of attitude error
    rate: tuple[float, float, float] = (40.0, 40.0, 15.0)  # 1/s: angular acceleration per rad/s of rate error
    max_rate: float = 6.0  # rad/s: limit on the commanded body rates


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (9, N), row 3 i + j = R[i, j], from unit quaternions (4, N) w, x, y, z."""
    return _QQ_TO_R @ (q[_PAIR_I] * q[_PAIR_J]) + _R_OFFSET


def tilt_angle(q: np.ndarray) -> np.ndarray:
    """Angle (...) rad between body z and world z for unit quaternions (..., 4) w, x, y, z."""
    cos_tilt = 1.0 - 2.0 * (q[..., 1] ** 2 + q[..., 2] ** 2)
    return np.arccos(np.clip(cos_tilt, -1.0, 1.0))


def check_symmetric_drag(coeff: np.ndarray, source: str = "drag coefficients") -> None:
    """ValueError unless the body-frame drag coefficients (3,) N s/m have equal x and y."""
    coeff = np.asarray(coeff)
    if coeff.shape != (3,) or coeff[0] != coeff[1] or not np.isfinite(coeff).all():
        raise ValueError(f"{source}: expected 3 finite body-frame values with x == y, got {coeff.tolist()}")


def linear_drag(rot: np.ndarray, vel: np.ndarray, coeff: np.ndarray) -> np.ndarray:
    """World-frame drag force (3, N) N: -R diag(coeff) R^T v.

    rot (9, N) body->world, vel (3, N) m/s world, coeff (3,) N s/m along body x, y, z with
    x == y (a rotor-symmetric airframe; see check_symmetric_drag), so that
    R diag(coeff) R^T = c_xy I + (c_z - c_xy) b3 b3^T with b3 the body z axis.
    """
    b3 = rot[2::3]
    along = (vel * b3).sum(0) * (coeff[0] - coeff[2])
    out = vel * -coeff[0]
    out += along * b3
    return out


def mixer_matrix(motor_xy: np.ndarray, yaw_ratio: np.ndarray) -> np.ndarray:
    """Allocation A (4, 4): [T, tau_x, tau_y, tau_z] = A @ f for rotor thrusts f (N).

    motor_xy (4, 2) m in the body frame; yaw_ratio (4,) m, signed reaction torque per N.
    """
    return np.stack([np.ones(4), motor_xy[:, 1], -motor_xy[:, 0], yaw_ratio])


def cap_thrusts(thrusts: np.ndarray, max_thrust: float) -> np.ndarray:
    """Rotor thrusts (4, N) N brought within [0, max_thrust] as the Crazyflie firmware does
    (powerDistributionCap): where a rotor asks for more than max_thrust, all four are lowered
    by its excess, so their differences (the torques that hold the attitude) are kept and the
    collective thrust gives; then any below 0 is raised to 0. Works in place; returns thrusts."""
    excess = thrusts.max(0)
    excess -= max_thrust
    np.maximum(excess, 0.0, out=excess)
    thrusts -= excess
    np.maximum(thrusts, 0.0, out=thrusts)
    return np.minimum(thrusts, max_thrust, out=thrusts)  # a - (a - max) may round one ulp above max


def _checked_angles(value: float | np.ndarray, method: str, what: str) -> np.ndarray:
    """value as a float64 array, or ValueError naming method and what unless every angle is in (0, pi/2) rad."""
    angles = np.asarray(value, dtype=np.float64)
    if not (np.isfinite(angles).all() and (angles > 0).all() and (angles < np.pi / 2).all()):
        raise ValueError(f"VelocityController.{method}: {what} limits must be in (0, pi/2) rad, got {angles}")
    return angles


def _limit_roll_pitch(force: np.ndarray, max_roll: float | np.ndarray, max_pitch: float | np.ndarray,
                      heading: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Bring the desired force (3, N) N, world frame, fz > 0, within roll and pitch limits (rad)
    each, keeping its vertical part, in place. A thrust direction of roll r and pitch p (ZYX
    Euler angles, yaw 0) is (cos r sin p, -sin r, cos r cos p); so p = atan2(fx, fz) and
    r = atan2(-fy, hypot(fx, fz)), and the limited force is (fz tan p, -fz tan r / cos p, fz).
    heading: (cos, sin) of the yaw whose axes the limits hold along (the firmware turns its
    velocity loop's output into the drone's own frame first); None: the world's axes."""
    fz = force[2]
    if heading is None:
        fx, fy = force[0], force[1]
    else:  # into the frame of the drone's heading
        c, s = heading
        fx, fy = c * force[0] + s * force[1], c * force[1] - s * force[0]
    pitch = np.arctan2(fx, fz)
    roll = np.arctan2(-fy, np.hypot(fx, fz))
    np.clip(pitch, -max_pitch, max_pitch, out=pitch)
    np.clip(roll, -max_roll, max_roll, out=roll)
    fx = fz * np.tan(pitch)
    fy = -fz * np.tan(roll) / np.cos(pitch)
    if heading is None:
        force[0], force[1] = fx, fy
    else:  # back to the world frame
        force[0], force[1] = c * fx - s * fy, s * fx + c * fy


def _right_tipped_drones(rate_des: np.ndarray, cols: np.ndarray, z_des: np.ndarray, max_rate: float) -> None:
    """Body rates (3, N) rad/s asked of drones whose body z is more than 90 deg from the thrust
    direction asked, z_des (3, N) world (a drone a collision tipped over), set in place to turn
    it back up at max_rate, about the horizontal body axis e3 x (R^T z_des) that does so the
    shorter way, yaw left for later; cols (3, 3, N): body axes x, y, z in the world.

    The attitude error on SO(3) fades as the rotation from the desired frame nears 180 deg:
    tipped 100 deg and turned 90 or 180 deg in yaw, a drone fell upside down to the floor.
    Drones within 90 deg of z_des (every drone in normal flight) are left as they are."""
    tipped = (cols[2] * z_des).sum(0) < 0.0
    if not tipped.any():
        return
    z_body = (cols[:, :, tipped] * z_des[:, tipped]).sum(1)  # z_des in the body frame (3, K)
    axis = np.stack([-z_body[1], z_body[0]])  # e3 x z_body, horizontal in the body frame
    norm = np.hypot(axis[0], axis[1])
    level = norm < 1e-9  # exactly upside down: any horizontal axis will do; roll
    axis[:, level] = [[1.0], [0.0]]
    norm[level] = 1.0
    rate_des[:2, tipped] = max_rate * axis / norm
    rate_des[2, tipped] = 0.0


class VelocityController:
    """Tracks a world-frame planar velocity at a constant altitude with yaw held at zero.

    `params` as scene.drone_parameters(mass) gives them for the drones flown. The controller
    knows their mass: the weight is fed forward (the hover thrust) and every force gain and the
    rate loop's inertia scale with it, so a heavier drone (task key drone_mass) flies the same
    closed loop while its rotors have the headroom. We take it that a flyer who sets drone_mass
    to their drones' weight also sets the firmware's base thrust (posCtlPid.thrustBase of its PID
    controller) to match; the altitude integrator only removes small biases (lag, drag).
    """

    def __init__(self, params: dict, flight_height: float, gains: ControllerGains | None = None):
        g = self.gains = gains or ControllerGains()
        self.mass = float(params["mass"])
        self.inertia = np.asarray(params["inertia"], dtype=np.float64)  # (3,) kg m^2, body axes
        self.max_thrust = float(params["max_thrust"])
        self.drag = np.asarray(params["drag"], dtype=np.float64)  # (3,) N s/m, body frame
        check_symmetric_drag(self.drag, "controller drag parameters")
        self.flight_height = float(flight_height)
        self.mixer_inv = np.linalg.inv(mixer_matrix(np.asarray(params["motor_xy"]), np.asarray(params["yaw_ratio"])))
        m = self.mass
        self._k_xy = m * g.vel_xy
        self._k_z = (m * g.pos_z, m * g.vel_z, m * g.int_z, m * GRAVITY)
        self._min_fz = 0.2 * m * GRAVITY
        self._max_fz = 4.0 * self.max_thrust  # N: the most vertical force all four rotors give, level
        self._tan_tilt: float | np.ndarray = float(np.tan(g.max_tilt))
        # (roll, pitch) limits rad as the firmware's velocity loop has them, instead of the tilt limit, and the
        # (cos, sin) of the heading they hold along (None: the world's axes); see set_roll_pitch_limits
        self._roll_pitch: tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None] | None = None
        self._att = -0.5 * np.asarray(g.att, dtype=np.float64)[:, None]  # the 1/2 of vee(P - P^T) / 2
        self._rate_inertia = (self.inertia * np.asarray(g.rate, dtype=np.float64))[:, None]
        # omega x (I omega) = omega[_NEXT1] * omega[_NEXT2] * (I[_NEXT2] - I[_NEXT1])
        self._gyro = (self.inertia[_NEXT2] - self.inertia[_NEXT1])[:, None]
        self._z_integral = np.zeros(0)

    def set_max_tilt(self, max_tilt: float | np.ndarray) -> None:
        """Limit the commanded tilt to max_tilt rad: one value, or (n,) one per drone (as a
        firmware parameter may differ between drones); 0 < max_tilt < pi/2. Replaces any
        roll and pitch limits (set_roll_pitch_limits)."""
        tilt = _checked_angles(max_tilt, "set_max_tilt", "tilt")
        self._tan_tilt = float(np.tan(tilt)) if tilt.ndim == 0 else np.tan(tilt)
        self._roll_pitch = None

    def set_roll_pitch_limits(self, roll: float | np.ndarray, pitch: float | np.ndarray,
                              heading: float | np.ndarray | None = None) -> None:
        """Limit the commanded roll and pitch (rad, ZYX Euler angles) each, as the Crazyflie
        firmware's velocity loop does (posCtlPid.rLimit and pLimit, position_controller_pid.c),
        instead of the tilt: one value each, or (n,) one per drone; each in (0, pi/2). With
        yaw held at 0, pitch tilts the thrust toward world x and roll toward world y, so on a
        diagonal the thrust tilts further than either limit (up to 21.1 deg at 15 deg each).
        heading (rad, one or (n,); default 0): the yaw of the drone the limits stand for, whose
        own axes they hold along (the firmware turns its loop's output by the drone's yaw
        before it limits), while this controller holds yaw 0 (a virtual Crazyflie's airframe).
        set_max_tilt returns to a limit on the tilt."""
        limits = (_checked_angles(roll, "set_roll_pitch_limits", "roll"), _checked_angles(pitch, "set_roll_pitch_limits", "pitch"))
        turn = None
        if heading is not None:
            yaw = np.asarray(heading, dtype=np.float64)
            if not np.isfinite(yaw).all():
                raise ValueError(f"VelocityController.set_roll_pitch_limits: heading must be finite (rad), got {yaw}")
            turn = None if not yaw.any() else (np.cos(yaw), np.sin(yaw))  # yaw 0: the world's axes, as without
        self._roll_pitch = (*limits, turn)

    def reset(self, n: int, mask: np.ndarray | None = None) -> None:
        """Clear the altitude integrator of all N drones, or of those where mask (N,) is True."""
        if self._z_integral.shape[0] != n or mask is None:
            self._z_integral = np.zeros(n)
        else:
            self._z_integral[mask] = 0.0

    def compute(
        self,
        pos: np.ndarray,
        vel: np.ndarray,
        quat: np.ndarray,
        angvel: np.ndarray,
        v_cmd: np.ndarray,
        dt: float,
        rot: np.ndarray | None = None,
        drag: np.ndarray | None = None,
        keep: np.ndarray | None = None,
    ) -> np.ndarray:
        """Rotor thrusts (4, N) in N, within [0, max_thrust] (cap_thrusts).

        pos (3, N) m world, vel (3, N) m/s world, quat (4, N) body->world, angvel (3, N)
        rad/s body, v_cmd (2, N) m/s world; dt (s) is the time since the last call;
        rot (9, N) the rotation matrices of quat (see quat_to_rotmat) and drag (3, N) N the
        drag force on each drone now (see linear_drag), if the caller already has them;
        keep (N,) bool: drones whose memory (the altitude integrator) this call leaves as it is
        (drones not being simulated; their thrusts are computed all the same).
        """
        n = pos.shape[1]
        if self._z_integral.shape[0] != n:
            self.reset(n)
        R = quat_to_rotmat(quat) if rot is None else rot
        b3 = R[2::3]  # body z axis in the world (3, N)

        # 1. velocity loop -> desired force (world), with the drag at the current velocity cancelled
        z_err = self.flight_height - pos[2]
        zi = self._z_integral + z_err * dt
        np.minimum(np.maximum(zi, -0.2, out=zi), 0.2, out=zi)
        force = linear_drag(R, vel, -self.drag) if drag is None else -drag
        force[:2] += self._k_xy * (v_cmd - vel[:2])
        kp, kd, ki, weight = self._k_z
        fz = kp * z_err
        fz -= kd * vel[2]
        # anti-windup: where the vertical force asked for is beyond what the rotors give (all of
        # them at full thrust, or the floor on fz below) the integral keeps its value instead
        # of growing further into the saturation, so a drone held down or pushed up does not
        # overshoot by the integral it gathered meanwhile once released
        asked = fz + ki * zi + weight + force[2]
        held = ((asked > self._max_fz) & (zi > self._z_integral)) | ((asked < self._min_fz) & (zi < self._z_integral))
        zi[held] = self._z_integral[held]
        if keep is not None:
            zi[keep] = self._z_integral[keep]
        self._z_integral = zi
        fz += ki * zi
        fz += weight
        fz += force[2]

        # 2. limit the tilt of the desired thrust direction (and keep some thrust upward)
        np.maximum(fz, self._min_fz, out=fz)
        force[2] = fz
        if self._roll_pitch is None:
            fxy = np.hypot(force[0], force[1])
            scale = np.minimum(1.0, fz * self._tan_tilt / np.maximum(fxy, 1e-12))
            force[:2] *= scale
            z_des = force / np.hypot(fxy * scale, fz)
        else:
            _limit_roll_pitch(force, *self._roll_pitch)
            z_des = force / np.sqrt((force * force).sum(0))
        thrust = (force * b3).sum(0)  # collective thrust along the current body z

        # 3. attitude error e_R = vee(Rd^T R - R^T Rd) / 2 for the desired frame of yaw 0:
        # x_des = (s, -a b / s, -a c / s), y_des = (0, c / s, -b / s), z_des = (a, b, c)
        a = z_des[0]
        inv_s = 1.0 / np.hypot(z_des[1], z_des[2])
        des = np.empty((3, 3, n))  # rows x_des, y_des, z_des
        des[0, 0] = 1.0 / inv_s
        des[0, 1:] = z_des[1:] * (-a * inv_s)
        des[1, 0] = 0.0
        des[1, 1] = z_des[2] * inv_s
        des[1, 2] = -z_des[1] * inv_s
        des[2] = z_des
        cols = R.reshape(3, 3, n).transpose(1, 0, 2)  # body axes x, y, z in the world
        # vee(P - P^T) with P_ij = des_i . col_j: (P21 - P12, P02 - P20, P10 - P01)
        e2 = (des[_NEXT2] * cols[_NEXT1]).sum(1)
        e2 -= (des[_NEXT1] * cols[_NEXT2]).sum(1)
        # that error's yaw part is 2 sin(yaw): it fades beyond 90 deg and vanishes at 180, where
        # a drone turned round would hold its yaw and ignore the tilt asked of it; there the
        # yaw part is held at its 90 deg value, so the drone turns back the shorter way
        away = cols[0, 0] < 0.0  # body x pointing against world x: |yaw| > 90 deg
        if away.any():
            e2[2, away] = np.where(cols[0, 1, away] >= 0.0, 2.0, -2.0)
        rate_des = self._att * e2
        max_rate = self.gains.max_rate
        np.minimum(np.maximum(rate_des, -max_rate, out=rate_des), max_rate, out=rate_des)
        _right_tipped_drones(rate_des, cols, z_des, max_rate)

        # 4. rates -> torques (with the gyroscopic term), then the mixer
        wrench = np.empty((4, n))
        wrench[0] = thrust
        rate_des -= angvel
        wrench[1:] = self._rate_inertia * rate_des
        gyro = angvel[_NEXT1] * angvel[_NEXT2]
        gyro *= self._gyro
        wrench[1:] += gyro
        return cap_thrusts(self.mixer_inv @ wrench, self.max_thrust)
