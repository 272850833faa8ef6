"""Many worlds stepped together on `mujoco.batch`, in either fidelity, driven by velocity commands.

`BatchedPhysics.step(commands)` advances every world by one decision interval (control_dt).
In quadrotor fidelity the cascaded controller runs every `substeps_per_control` physics
steps, vectorised over all drones of all worlds; in point fidelity the planar velocity
actuators need no Python between steps. Contacts are read from each drone's contact sensor
at every controller tick and reported per drone.

State arrays are shaped (n_worlds, n_drones, ...): drones in `drone_names` order (pursuers
first), positions and linear velocities in the world (= layout) frame, m and m/s.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import mujoco
import mujoco.batch
import numpy as np

from .config import TaskConfig
from .controller import VelocityController
from .layout import Layout
from .scene import DroneIds, SceneSpec, build_model, drone_names, drone_parameters

UNIT_QUAT = np.array([1.0, 0.0, 0.0, 0.0])


@dataclasses.dataclass
class DroneState:
    """A snapshot of every drone in every world (copies, safe to keep).

    pos (W, D, 3) m world; vel (W, D, 3) m/s world; quat (W, D, 4) w,x,y,z body->world;
    angvel (W, D, 3) rad/s body frame; thrust (W, D, 4) N per rotor (zeros in point fidelity).
    """

    pos: np.ndarray
    vel: np.ndarray
    quat: np.ndarray
    angvel: np.ndarray
    thrust: np.ndarray


def check_commands(commands: np.ndarray, shape: tuple[int, ...], source: str = "commands") -> np.ndarray:
    """Validate a command array: exact shape, finite values. Raises ValueError naming the problem."""
    arr = np.asarray(commands, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{source}: expected shape {shape} (worlds, drones, vx vy), got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{source}: non-finite value {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    return arr


def clip_speed(v: np.ndarray, max_speed: np.ndarray) -> np.ndarray:
    """Scale planar velocities (..., 2) down to at most max_speed (...,) m/s, keeping direction."""
    norm = np.linalg.norm(v, axis=-1)
    scale = np.minimum(1.0, max_speed / np.maximum(norm, 1e-12))
    return v * scale[..., None]


class BatchedPhysics:
    """n_worlds MuJoCo worlds of one task; each world may carry its own layout instance.

    All worlds must share model sizes: layouts are padded to `obstacle_slots` static geoms.
    """

    def __init__(self, config: TaskConfig, layouts: Sequence[Layout], nthread: int = 0):
        self.config = config
        self.n_worlds = len(layouts)
        if self.n_worlds < 1:
            raise ValueError("BatchedPhysics needs at least one world")
        self.names = drone_names(config.n_pursuers, config.n_evaders)
        self.n_drones = len(self.names)
        self.fidelity = config.fidelity
        self.params = drone_parameters()
        self.obstacle_slots = max(len(l.obstacles) + len(l.border()) for l in layouts) + 8
        self.layouts = list(layouts)
        self.models = [self._build(l) for l in layouts]
        base = self.models[0]
        self.ids = DroneIds.lookup(base, self.names, self.fidelity)
        self.batch = mujoco.batch.Batch(base, self.n_worlds, nthread=nthread)
        self._set_models()
        self.qpos = self.batch.bind("qpos")
        self.qvel = self.batch.bind("qvel")
        self.ctrl = self.batch.bind("ctrl")
        self.sensordata = self.batch.bind("sensordata")
        D = self.n_drones
        if self.fidelity == "quadrotor":
            self.act = self.batch.bind("act")
            self.xfrc = self.batch.bind("xfrc_applied")
            self._qpos_idx = self.ids.qpos_adr[:, None] + np.arange(7)  # (D, 7)
            self._qvel_idx = self.ids.qvel_adr[:, None] + np.arange(6)  # (D, 6)
            self._ctrl_idx = self.ids.ctrl_adr[:, None] + np.arange(4)  # (D, 4)
            self._act_idx = np.array([base.actuator_actadr[a] for a in self._ctrl_idx.ravel()]).reshape(D, 4)
            self.controller = VelocityController(self.params, config.flight_height)
            self.controller.reset(self.n_worlds * D)
        else:
            self._qpos_idx = self.ids.qpos_adr[:, None] + np.arange(2)
            self._qvel_idx = self.ids.qvel_adr[:, None] + np.arange(2)
            self._ctrl_idx = self.ids.ctrl_adr[:, None] + np.arange(2)
        self.max_speed = np.array([config.pursuer_speed] * config.n_pursuers + [config.evader_speed] * config.n_evaders)
        self.commands = np.zeros((self.n_worlds, D, 2))  # last applied command, m/s world
        self.contacts = np.zeros((self.n_worlds, D), bool)  # any contact in the last step
        self.time = np.zeros(self.n_worlds)  # s since each world's reset
        self.reset_all_default()

    # ------------------------------------------------------------------ models and layouts

    def _build(self, layout: Layout) -> mujoco.MjModel:
        c = self.config
        return build_model(SceneSpec(layout, c.n_pursuers, c.n_evaders, c.fidelity, c.physics_dt, c.flight_height, self.obstacle_slots))

    def _set_models(self) -> None:
        if self.n_worlds == 1 or all(m is self.models[0] for m in self.models):
            self.batch.set_models(self.models[0])
        else:
            self.batch.set_models(self.models)

    def set_layouts(self, world_ids: Sequence[int], layouts: Sequence[Layout]) -> None:
        """Give the listed worlds new layout instances (new random obstacles); reset them after."""
        for w, layout in zip(world_ids, layouts):
            if len(layout.obstacles) + len(layout.border()) > self.obstacle_slots:
                raise ValueError(f"layout {layout.source}: {len(layout.obstacles)} obstacles exceed the {self.obstacle_slots} slots this batch was built with")
            self.layouts[w] = layout
            self.models[w] = self._build(layout)
        self._set_models()

    def model(self, world: int = 0) -> mujoco.MjModel:
        return self.models[world]

    # ------------------------------------------------------------------ reset

    def reset_all_default(self) -> None:
        xy = np.zeros((self.n_worlds, self.n_drones, 2))
        xy[..., 0] = 0.3 + 0.3 * np.arange(self.n_drones)
        xy[..., 1] = 0.3
        self.reset(np.arange(self.n_worlds), xy)

    def reset(self, world_ids: Sequence[int] | np.ndarray, xy: np.ndarray) -> None:
        """Place the drones of the listed worlds at rest at xy (k, D, 2) m, at flight height."""
        ids = np.asarray(world_ids, dtype=np.int64)
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape != (len(ids), self.n_drones, 2):
            raise ValueError(f"reset positions: expected shape {(len(ids), self.n_drones, 2)}, got {xy.shape}")
        if len(ids) == 0:
            return
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE)
        qpos = self.qpos[ids]
        if self.fidelity == "quadrotor":
            full = np.concatenate([xy, np.full(xy.shape[:-1] + (1,), self.config.flight_height), np.broadcast_to(UNIT_QUAT, xy.shape[:-1] + (4,))], -1)
            qpos[:, self._qpos_idx] = full
            hover = self.params["mass"] * 9.81 / 4
            act = self.act[ids]
            act[:, self._act_idx] = hover
            self.act[ids] = act
            ctrl = self.ctrl[ids]
            ctrl[:, self._ctrl_idx] = hover
            self.ctrl[ids] = ctrl
            mask = np.zeros((self.n_worlds, self.n_drones), bool)
            mask[ids] = True
            self.controller.reset(self.n_worlds * self.n_drones, mask.ravel())
        else:
            qpos[:, self._qpos_idx] = xy
        self.qpos[ids] = qpos
        self.qvel[ids] = 0.0
        self.batch.forward(ids)
        self.commands[ids] = 0.0
        self.contacts[ids] = False
        self.time[ids] = 0.0

    # ------------------------------------------------------------------ state

    def positions(self) -> np.ndarray:
        """(W, D, 3) m world."""
        if self.fidelity == "quadrotor":
            return self.qpos[:, self._qpos_idx[:, :3]]
        p = np.empty((self.n_worlds, self.n_drones, 3))
        p[..., :2] = self.qpos[:, self._qpos_idx]
        p[..., 2] = self.config.flight_height
        return p

    def velocities(self) -> np.ndarray:
        """(W, D, 3) m/s world."""
        if self.fidelity == "quadrotor":
            return self.qvel[:, self._qvel_idx[:, :3]]
        v = np.zeros((self.n_worlds, self.n_drones, 3))
        v[..., :2] = self.qvel[:, self._qvel_idx]
        return v

    def state(self) -> DroneState:
        W, D = self.n_worlds, self.n_drones
        if self.fidelity == "quadrotor":
            q = self.qpos[:, self._qpos_idx]
            v = self.qvel[:, self._qvel_idx]
            return DroneState(q[..., :3].copy(), v[..., :3].copy(), q[..., 3:7].copy(), v[..., 3:6].copy(), self.act[:, self._act_idx].copy())
        return DroneState(self.positions(), self.velocities(), np.broadcast_to(UNIT_QUAT, (W, D, 4)).copy(), np.zeros((W, D, 3)), np.zeros((W, D, 4)))

    # ------------------------------------------------------------------ stepping

    def step(self, commands: np.ndarray) -> np.ndarray:
        """Advance every world by control_dt under velocity commands (W, D, 2) m/s world.

        Commands are clipped to each drone's max speed. Returns contacts (W, D) bool: the
        drone touched a wall, an obstacle or another drone during the step.
        """
        cmd = check_commands(commands, (self.n_worlds, self.n_drones, 2))
        cmd = clip_speed(cmd, self.max_speed)
        self.commands[:] = cmd
        self.contacts[:] = False
        k = self.config.substeps_per_control
        ticks = self.config.substeps // k
        if self.fidelity == "point":
            self.ctrl[:, self._ctrl_idx] = cmd
        for _ in range(ticks):
            if self.fidelity == "quadrotor":
                self._control_tick(cmd, k * self.config.physics_dt)
            self.batch.step(nstep=k)
            self.contacts |= self.sensordata[:, self.ids.contact_adr] > 0
        self._check_finite()
        self.time += self.config.control_dt
        return self.contacts.copy()

    def _control_tick(self, cmd: np.ndarray, dt: float) -> None:
        W, D = self.n_worlds, self.n_drones
        q = self.qpos[:, self._qpos_idx].reshape(W * D, 7)
        v = self.qvel[:, self._qvel_idx].reshape(W * D, 6)
        thrust = self.controller.compute(q[:, :3], v[:, :3], q[:, 3:7], v[:, 3:6], cmd.reshape(W * D, 2), dt)
        self.ctrl[:, self._ctrl_idx] = thrust.reshape(W, D, 4)
        # linear drag, body-frame coefficients, applied as a world-frame force at the COM
        from .controller import quat_to_rotmat

        R = quat_to_rotmat(q[:, 3:7])
        drag = -np.einsum("nij,j,nkj,nk->ni", R, self.params["drag"], R, v[:, :3])
        self.xfrc[:, self.ids.body, :3] = drag.reshape(W, D, 3)

    def _check_finite(self) -> None:
        if not np.isfinite(self.qpos).all():
            bad = np.where(~np.isfinite(self.qpos).all(axis=1))[0]
            raise FloatingPointError(f"physics diverged (non-finite state) in worlds {bad.tolist()}")
