"""Cascaded velocity-tracking controller for quadrotors, vectorised over any number of drones.

velocity error -> desired acceleration -> desired thrust vector (tilt + collective thrust,
altitude held at a reference height) -> attitude error on SO(3) -> desired body rates ->
rate error -> body torques -> mixer -> four rotor thrusts.

It knows nothing of MuJoCo: `compute(state arrays, command) -> thrusts`. Arrays have a
leading drone dimension N (any flattening of worlds x drones). Frames: world z up;
quaternions w, x, y, z (body to world); angular velocity in the body frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np

GRAVITY = 9.81  # m/s^2


@dataclasses.dataclass(frozen=True)
class ControllerGains:
    """Loop gains (SI). Tuned on models/crazyflie.xml; see tests/test_controller.py."""

    vel_xy: float = 4.0  # 1/s: desired horizontal acceleration per m/s of velocity error
    pos_z: float = 12.0  # 1/s^2: vertical acceleration per m of altitude error
    vel_z: float = 7.0  # 1/s: vertical acceleration per m/s of vertical velocity
    int_z: float = 4.0  # 1/s^3: integral of altitude error (battery, lag, drag bias)
    max_tilt: float = np.radians(15.0)  # rad: limit on the commanded tilt
    att: np.ndarray = dataclasses.field(default_factory=lambda: np.array([12.0, 12.0, 6.0]))  # 1/s: rate per rad of attitude error
    rate: np.ndarray = dataclasses.field(default_factory=lambda: np.array([40.0, 40.0, 15.0]))  # 1/s: angular acceleration per rad/s of rate error
    max_rate: float = 6.0  # rad/s: limit on the commanded body rates


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) from quaternions (N, 4) w, x, y, z (body to world)."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def mixer_matrix(motor_xy: np.ndarray, yaw_ratio: np.ndarray) -> np.ndarray:
    """Allocation A (4, 4): [T, tau_x, tau_y, tau_z] = A @ f for rotor thrusts f (N).

    motor_xy (4, 2) m in the body frame; yaw_ratio (4,) m, signed reaction torque per N.
    """
    return np.stack([np.ones(4), motor_xy[:, 1], -motor_xy[:, 0], yaw_ratio])


class VelocityController:
    """Tracks a world-frame planar velocity at a constant altitude with yaw held at zero."""

    def __init__(self, params: dict, flight_height: float, gains: ControllerGains | None = None):
        self.gains = gains or ControllerGains()
        self.mass = float(params["mass"])
        self.inertia = np.asarray(params["inertia"], dtype=np.float64)  # (3,)
        self.max_thrust = float(params["max_thrust"])
        self.drag = np.asarray(params["drag"], dtype=np.float64)  # (3,) N s/m, body frame
        self.flight_height = float(flight_height)
        self.mix_inv = np.linalg.inv(mixer_matrix(np.asarray(params["motor_xy"]), np.asarray(params["yaw_ratio"])))
        self._z_integral: np.ndarray | None = None

    def reset(self, n: int, mask: np.ndarray | None = None) -> None:
        """Clear the altitude integrator of all N drones, or of those where mask (N,) is True."""
        if self._z_integral is None or self._z_integral.shape[0] != n or mask is None:
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
    ) -> np.ndarray:
        """Rotor thrusts (N, 4) in N, clipped to [0, max_thrust].

        pos (N, 3) m world, vel (N, 3) m/s world, quat (N, 4) body->world, angvel (N, 3)
        rad/s body, v_cmd (N, 2) m/s world; dt (s) is the time since the last call.
        """
        g = self.gains
        n = pos.shape[0]
        if self._z_integral is None or self._z_integral.shape[0] != n:
            self.reset(n)
        R = quat_to_rotmat(quat)

        # 1. velocity loop -> desired acceleration (world), drag compensated at the command
        z_err = self.flight_height - pos[:, 2]
        self._z_integral = np.clip(self._z_integral + z_err * dt, -0.2, 0.2)
        acc = np.empty((n, 3))
        acc[:, :2] = g.vel_xy * (v_cmd - vel[:, :2])
        acc[:, 2] = g.pos_z * z_err - g.vel_z * vel[:, 2] + g.int_z * self._z_integral
        drag_world = np.einsum("nij,j,nkj,nk->ni", R, self.drag, R, vel)  # R diag(d) R^T v
        force = self.mass * (acc + np.array([0.0, 0.0, GRAVITY])) + drag_world

        # 2. limit the tilt of the desired thrust direction
        fz = np.maximum(force[:, 2], 0.2 * self.mass * GRAVITY)
        fxy = force[:, :2]
        fxy_max = fz * np.tan(g.max_tilt)
        scale = np.minimum(1.0, fxy_max / np.maximum(np.linalg.norm(fxy, axis=1), 1e-9))
        force = np.column_stack([fxy * scale[:, None], fz])
        z_des = force / np.linalg.norm(force, axis=1, keepdims=True)
        thrust = np.einsum("ni,ni->n", force, R[:, :, 2])  # collective thrust along body z

        # 3. attitude: desired frame with yaw 0 (x_c = world x), error e_R = vee(Rd^T R - R^T Rd)/2
        y_des = np.cross(z_des, np.array([1.0, 0.0, 0.0]))
        y_des /= np.linalg.norm(y_des, axis=1, keepdims=True)
        x_des = np.cross(y_des, z_des)
        Rd = np.stack([x_des, y_des, z_des], -1)
        E = np.einsum("nji,njk->nik", Rd, R) - np.einsum("nji,njk->nik", R, Rd)
        e_R = 0.5 * np.stack([E[:, 2, 1], E[:, 0, 2], E[:, 1, 0]], -1)
        rate_des = np.clip(-g.att * e_R, -g.max_rate, g.max_rate)

        # 4. rates -> torques (with gyroscopic term), then the mixer
        Iw = self.inertia * angvel
        torque = self.inertia * (g.rate * (rate_des - angvel)) + np.cross(angvel, Iw)
        wrench = np.column_stack([thrust, torque])
        return np.clip(wrench @ self.mix_inv.T, 0.0, self.max_thrust)
