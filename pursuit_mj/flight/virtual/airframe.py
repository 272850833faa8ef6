"""The bodies of virtual Crazyflies: pursuit_mj's quadrotor physics in one MuJoCo world of the lab.

The scene is pursuit_mj's own (`scene.build_model`: the Crazyflie model of
models/crazyflie.xml with motor lag and rotor torques, the floor, the lab walls) and the
rotors are driven by pursuit_mj's cascaded `VelocityController` with the same linear drag
as `BatchedPhysics`. What a real Crazyflie adds, and this class provides per drone: it
sits on the floor with its motors off, climbs and descends to a height reference, and its
motors can be cut at any time (then it falls).

Frame: the world of this scene is the lab frame shifted so that the lab's lower-left
corner is the origin (MuJoCo layouts start at 0, 0). Drones are in the flight plan's order.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ...controller import VelocityController, linear_drag, quat_to_rotmat
from ...layout import Layout, layout_from_dict
from ...physics import WARNING_NAMES, mujoco_log_quiet, warning_texts
from ...scene import DroneIds, SceneSpec, build_model, drone_names, drone_parameters

REST_HEIGHT = 0.012  # m: centre height of a drone standing on the floor (half its collision cylinder)


def lab_layout(x: tuple[float, float], y: tuple[float, float]) -> Layout:
    """An empty arena the size of the lab (the real lab has no obstacles: they are virtual)."""
    w, h = x[1] - x[0], y[1] - y[0]
    spawn = {"x": [0.05 * w, 0.95 * w], "y": [0.05 * h, 0.95 * h]}
    return layout_from_dict({"name": "virtual_lab", "arena": {"width": w, "height": h}, "spawn": {"pursuers": spawn, "evaders": spawn}}, "virtual lab")


class Airframe:
    """D drones in one MuJoCo world, stepped in fixed ticks of `tick` seconds.

    `mass` (kg): every drone's take-off mass, as the task key drone_mass sets it (body, inertia
    and controller alike); None: the model file's.

    Commands per tick: v_xy (D, 2) m/s world, z_ref (D,) m, vz_ff (D,) m/s, motors (D,) bool. State:
    pos (D, 3) m, vel (D, 3) m/s (world = shifted lab), quat (D, 4) w x y z, thrust (D, 4) N.
    """

    def __init__(self, n_pursuers: int, n_others: int, lab_x: tuple[float, float], lab_y: tuple[float, float],
                 starts: np.ndarray, physics_dt: float = 0.002, controller_hz: float = 250.0, mass: float | None = None):
        self.offset = np.array([lab_x[0], lab_y[0]])
        self.n = n_pursuers + n_others
        layout = lab_layout(lab_x, lab_y)
        self.model = build_model(SceneSpec(layout, n_pursuers, n_others, "quadrotor", physics_dt, 0.5, drone_mass=mass))
        self.data = mujoco.MjData(self.model)
        self.ids = DroneIds.lookup(self.model, drone_names(n_pursuers, n_others), "quadrotor")
        self.params = drone_parameters(mass)
        self.drag = np.asarray(self.params["drag"], np.float64)
        self.controller = VelocityController(self.params, 1.0)
        self.controller.reset(self.n)
        gains = self.controller.gains
        self._vz_lead = gains.vel_z / gains.pos_z  # s: height lead that feeds a climb rate forward
        self.physics_dt = physics_dt
        self.steps_per_control = max(1, int(round(1.0 / (controller_hz * physics_dt))))
        self._qpos = self.ids.qpos_adr[:, None] + np.arange(7)  # (D, 7)
        self._qvel = self.ids.qvel_adr[:, None] + np.arange(6)  # (D, 6)
        self._ctrl = self.ids.ctrl_adr[:, None] + np.arange(4)  # (D, 4)
        self.motors = np.zeros(self.n, bool)
        self.time = 0.0
        self.place(np.asarray(starts, np.float64))

    def place(self, starts_lab: np.ndarray) -> None:
        """Every drone at rest on the floor at starts_lab (D, 2) m lab, motors off."""
        mujoco.mj_resetData(self.model, self.data)
        xy = starts_lab - self.offset
        q = np.zeros((self.n, 7))
        q[:, :2] = xy
        q[:, 2] = REST_HEIGHT
        q[:, 3] = 1.0
        self.data.qpos[self._qpos] = q
        mujoco.mj_forward(self.model, self.data)
        self.motors[:] = False
        self.controller.reset(self.n)

    @property
    def pos(self) -> np.ndarray:
        """(D, 3) m, lab frame."""
        p = self.data.qpos[self._qpos[:, :3]].copy()
        p[:, :2] += self.offset
        return p

    @property
    def vel(self) -> np.ndarray:
        """(D, 3) m/s, lab frame."""
        return self.data.qvel[self._qvel[:, :3]].copy()

    @property
    def quat(self) -> np.ndarray:
        """(D, 4) w, x, y, z body -> lab."""
        return self.data.qpos[self._qpos[:, 3:7]].copy()

    @property
    def thrust(self) -> np.ndarray:
        """(D, 4) N per rotor (after the motor lag)."""
        return self.data.actuator_force[self._ctrl].copy()

    def step(self, tick: float, v_xy: np.ndarray, z_ref: np.ndarray, vz_ff: np.ndarray, motors: np.ndarray) -> None:
        """Advance by `tick` s (rounded to controller periods) under the commands of the class docstring.

        vz_ff (D,) m/s: vertical speed of the height reference (feed-forward).
        """
        started = motors & ~self.motors
        if started.any():
            self.controller.reset(self.n, started)
        self.motors = motors.copy()
        k = self.steps_per_control
        n_ctrl = max(1, int(round(tick / (k * self.physics_dt))))
        d = self.data
        warned = np.array([w.number for w in d.warning])
        with mujoco_log_quiet():
            self._run(n_ctrl, k, v_xy, z_ref, vz_ff, motors)
        self.time += n_ctrl * k * self.physics_dt
        risen = np.flatnonzero(np.array([w.number for w in d.warning]) > warned)
        if len(risen) or not np.isfinite(d.qpos).all():
            # MuJoCo resets a state gone bad: flying on would teleport the drones
            kinds = ("MuJoCo warnings: " + ", ".join(WARNING_NAMES[int(k)] for k in risen)) if len(risen) else "non-finite state"
            said = "".join(f"; MuJoCo: {t}" for t in warning_texts(risen, [d.warning[k].lastinfo for k in risen]))
            raise FloatingPointError(f"virtual lab physics diverged ({kinds}{said})")

    def _run(self, n_ctrl: int, k: int, v_xy: np.ndarray, z_ref: np.ndarray, vz_ff: np.ndarray, motors: np.ndarray) -> None:
        """n_ctrl controller periods of k physics steps each."""
        d = self.data
        for _ in range(n_ctrl):
            q = d.qpos[self._qpos].T  # (7, D)
            v = d.qvel[self._qvel].T  # (6, D)
            rot = quat_to_rotmat(q[3:7])
            # the controller holds its own flight height; shift the altitude it sees so that it
            # tracks each drone's reference, with the reference's climb rate fed forward
            pos = q[:3].copy()
            pos[2] -= z_ref + self._vz_lead * vz_ff - self.controller.flight_height
            thrust = self.controller.compute(pos, v[:3], q[3:7], v[3:6], v_xy.T, k * self.physics_dt, rot).T
            d.ctrl[self._ctrl] = np.where(motors[:, None], thrust, 0.0)
            d.xfrc_applied[self.ids.body, :3] = linear_drag(rot, v[:3], self.drag).T
            mujoco.mj_step(self.model, d, nstep=k)


__all__ = ["Airframe", "lab_layout", "REST_HEIGHT"]
