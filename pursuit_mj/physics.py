"""Many worlds stepped together on `mujoco.batch`, in either fidelity, driven by velocity commands.

`BatchedPhysics.step(commands)` advances every world by one decision interval (control_dt).
In quadrotor fidelity the cascaded controller runs every `substeps_per_control` physics
steps, vectorised over all drones of all worlds, between MuJoCo calls that each advance all
worlds by those physics steps. In point fidelity a planar force per drone is set at the
same ticks (a first-order velocity response whose acceleration is capped in norm, as the
quadrotor's tilt limit caps it in every direction). Either way MuJoCo records each drone's
contact sensor after every physics step, so that no touch is missed.

State arrays are shaped (n_worlds, n_drones, ...): drones in `drone_names` order (pursuers
first), positions and linear velocities in the world (= layout) frame, m and m/s.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import warnings
from typing import Callable, Iterator, Sequence

import mujoco
import mujoco.batch
import numpy as np

from .config import TaskConfig, checked_task_config
from .controller import VelocityController, check_symmetric_drag, linear_drag, quat_to_rotmat
from .layout import Layout
from .planar import clip_norm
from .scene import DroneIds, SceneSpec, build_model, drone_names, drone_parameters

UNIT_QUAT = np.array([1.0, 0.0, 0.0, 0.0])
WARNING_NAMES = {int(v): k.removeprefix("mjWARN_") for k, v in mujoco.mjtWarning.__members__.items() if k != "mjNWARNING"}
#: spare static geoms per world beyond the largest layout given, for new random obstacles
SPARE_SLOTS = 4
#: MuJoCo's own words quoted per report of a diverged world (one per kind of warning and world at most)
KEPT_MESSAGES = 4
_quiet_lock = threading.Lock()
_quiet_depth = 0  # contexts of mujoco_log_quiet open now (steps in several threads)
_quiet_saved = (True, True)  # MuJoCo's logto_console, logto_file before the first of them


@contextlib.contextmanager
def mujoco_log_quiet() -> Iterator[None]:
    """While inside, MuJoCo neither prints its warnings nor appends them to MUJOCO_LOG.TXT in the
    current folder (its global log settings, as they were, come back after); callers read the
    warnings from MuJoCo's counters instead (`warning_texts`). Contexts open at once in several
    threads share it: the first turns the log off, the last turns it back. (Not a warning handler
    in Python: MuJoCo calls handlers from C++, and an exception there, Ctrl-C's among them, ends
    the process.) A handler of the user's own (`mujoco.set_mju_user_warning`) still gets them."""
    global _quiet_depth, _quiet_saved
    with _quiet_lock:
        if _quiet_depth == 0:
            config = mujoco.MjLogConfig.get()
            _quiet_saved = (config.logto_console, config.logto_file)
            config.logto_console = config.logto_file = False
            config.set()
        _quiet_depth += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_depth -= 1
            if _quiet_depth == 0:
                config = mujoco.MjLogConfig.get()
                config.logto_console, config.logto_file = _quiet_saved
                config.set()


def warning_texts(kinds: np.ndarray, infos: np.ndarray) -> list[str]:
    """MuJoCo's words for warnings of kinds (K,) (mjtWarning) with their last info values (K,)
    (a DOF index, a count), distinct ones first come, at most KEPT_MESSAGES."""
    texts = dict.fromkeys(mujoco.mju_warningText(int(k), int(i)) for k, i in zip(kinds, infos))
    return list(texts)[:KEPT_MESSAGES]


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
    """Validate a command array of `shape` (W, D, 2), velocities m/s world frame: real numbers
    (ints or floats; not bools, text or complex numbers, which numpy would turn into
    velocities), exact shape, finite values. Returns it as float64; raises ValueError naming
    the problem."""
    try:
        raw = np.asarray(commands)
    except (TypeError, ValueError):  # ragged nesting
        raise ValueError(f"{source}: expected a numeric array of shape {shape}, got {type(commands).__name__}") from None
    if raw.dtype.kind not in "fiu":
        raise ValueError(f"{source}: expected a numeric array of shape {shape} (real numbers), got an array of dtype {raw.dtype}")
    arr = raw.astype(np.float64)
    if arr.shape != shape:
        raise ValueError(f"{source}: expected shape {shape} (worlds, drones, vx vy), got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{source}: non-finite value {arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
    return arr


def _layout_slots(layout: Layout) -> int:
    return len(layout.obstacles) + len(layout.border())


class BatchedPhysics:
    """n_worlds MuJoCo worlds of one task; each world may carry its own layout instance.

    All worlds share model sizes: layouts are padded to `obstacle_slots` static geoms,
    enough for the largest layout given plus its random ones (`config.random_obstacle_count`, or
    `obstacle_slots` if given). A later `set_layouts` with a larger layout rebuilds the
    batch with more slots, carrying every world's state over.

    `observers`: callables f(physics) run after every controller tick of `step`. They may
    read state; they must not change it.
    """

    def __init__(self, config: TaskConfig, layouts: Sequence[Layout], nthread: int = 0, obstacle_slots: int | None = None):
        # a TaskConfig made directly or changed with dataclasses.replace skips the loader's
        # checks; unchecked, a latency between ticks, a controller rate that does not divide the
        # physics rate or a negative speed would be rounded or obeyed silently (ConfigError naming the key)
        checked_task_config(config, "BatchedPhysics config")
        self.config = config
        self.n_worlds = len(layouts)
        if self.n_worlds < 1:
            raise ValueError("BatchedPhysics: layouts is empty; it needs one layout per world (at least one)")
        self.names = drone_names(config.n_pursuers, config.n_evaders)
        self.n_drones = len(self.names)
        self.fidelity = config.fidelity
        self.nthread = nthread
        self.params = drone_parameters(config.drone_mass)  # mass and inertia as configured
        self.drag = np.asarray(self.params["drag"], dtype=np.float64)
        check_symmetric_drag(self.drag, "models/crazyflie.xml numeric 'drag'")
        self.layouts = list(layouts)
        needed = max(_layout_slots(l) + config.random_obstacle_count(l) for l in self.layouts) + SPARE_SLOTS
        self.obstacle_slots = max(needed, obstacle_slots or 0)
        self.models = self._build_all(self.layouts)
        self.max_speed = np.array([config.pursuer_speed] * config.n_pursuers + [config.evader_speed] * config.n_evaders)
        self.commands = np.zeros((self.n_worlds, self.n_drones, 2))  # last command given, m/s world
        ticks_per_step = config.substeps // config.substeps_per_control
        self._latency_ticks = config.command_latency_ticks
        # the pursuers' commands of the last steps still on their way (steps, W, P, 2) m/s world, oldest first
        self._pending = np.zeros((-(-self._latency_ticks // ticks_per_step), self.n_worlds, config.n_pursuers, 2))
        self.contacts = np.zeros((self.n_worlds, self.n_drones), bool)  # any contact in the last step
        self.time = np.zeros(self.n_worlds)  # s since each world's reset
        self.observers: list[Callable[["BatchedPhysics"], None]] = []
        if self.fidelity == "quadrotor":
            self.controller = VelocityController(self.params, config.flight_height)
            self.controller.reset(self.n_worlds * self.n_drones)
        self._make_batch()
        self.reset_all_default()

    # ------------------------------------------------------------------ models and layouts

    def _build(self, layout: Layout) -> mujoco.MjModel:
        return build_model(SceneSpec.for_task(self.config, layout, self.obstacle_slots))

    def _build_all(self, layouts: Sequence[Layout]) -> list[mujoco.MjModel]:
        """One model per world; worlds given the same Layout object share one model."""
        built: dict[int, mujoco.MjModel] = {}
        for layout in layouts:
            if id(layout) not in built:
                built[id(layout)] = self._build(layout)
        return [built[id(layout)] for layout in layouts]

    def _make_batch(self, state: np.ndarray | None = None) -> None:
        """(Re)create the batch on self.models, optionally restoring state rows, and bind arrays.

        The drone ids are looked up again: more obstacle slots move the drones' geom ids."""
        self.ids = DroneIds.lookup(self.models[0], self.names, self.fidelity)
        self.batch = mujoco.batch.Batch(self.models[0], self.n_worlds, nthread=self.nthread)
        self._set_models()
        if state is not None:
            self.batch.state[:] = state
        b = self.batch
        # state fields only: an output field bound here would be copied out after every call
        self.qpos, self.qvel, self.ctrl = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl")
        self._mj_time = b.bind("time")
        self._warnings = b.warning[:, :, 1].copy()  # MuJoCo warning counts (W, kinds) at the last check
        self.diverged = np.zeros(self.n_worlds, bool)  # worlds whose last step went bad (strict=False)
        self.divergence: str | None = None  # what the last step's warning says of them (strict=False), else None
        base, D = self.models[0], self.n_drones
        self._state = b.state

        def column(view: np.ndarray) -> int:  # first state column of a bound state field
            return (view.__array_interface__["data"][0] - self._state.__array_interface__["data"][0]) // self._state.itemsize

        if self.fidelity == "quadrotor":
            self.act, self.xfrc = b.bind("act"), b.bind("xfrc_applied")
            self._qpos_idx = self.ids.qpos_adr[:, None] + np.arange(7)  # (D, 7)
            self._qvel_idx = self.ids.qvel_adr[:, None] + np.arange(6)  # (D, 6)
            self._ctrl_idx = self.ids.ctrl_adr[:, None] + np.arange(4)  # (D, 4)
            self._act_idx = base.actuator_actadr[self._ctrl_idx]  # (D, 4)
            # One gather of (qpos 7, qvel 6) and one scatter of (rotor thrust 4, drag force 3)
            # per tick, through the transposed state: arrays (components, D, W), drone-major.
            read = np.concatenate([column(self.qpos) + self._qpos_idx, column(self.qvel) + self._qvel_idx], 1)
            self._read_cols = np.ascontiguousarray(read.T)  # (13, D)
            force_cols = column(self.xfrc) + 6 * self.ids.body[:, None] + np.arange(3)
            self._write_cols = np.ascontiguousarray(np.concatenate([column(self.ctrl) + self._ctrl_idx, force_cols], 1).T)  # (7, D)
            self._out = np.empty((7, D * self.n_worlds))
            per_tick = self.config.substeps_per_control
            self._record = {"sensordata": np.empty((self.n_worlds, per_tick, base.nsensordata))}
        else:
            self._qpos_idx = self.ids.qpos_adr[:, None] + np.arange(2)
            self._qvel_idx = self.ids.qvel_adr[:, None] + np.arange(2)
            self._ctrl_idx = self.ids.ctrl_adr[:, None] + np.arange(2)
            self._write_cols = (column(self.ctrl) + self._ctrl_idx).ravel()
            self._record = {"sensordata": np.empty((self.n_worlds, self.config.substeps_per_control, base.nsensordata))}

    def _set_models(self) -> None:
        if self.n_worlds == 1 or all(m is self.models[0] for m in self.models):
            self.batch.set_models(self.models[0])
        else:
            self.batch.set_models(self.models)

    def set_layouts(self, world_ids: Sequence[int], layouts: Sequence[Layout]) -> None:
        """Give the listed worlds new layout instances (new random obstacles); reset them after."""
        ids = self._world_ids(world_ids, "set_layouts world_ids")
        layouts = list(layouts)
        if len(layouts) != len(ids):
            raise ValueError(f"set_layouts: {len(ids)} world ids but {len(layouts)} layouts")
        need = max([_layout_slots(l) for l in layouts] + [0])
        for w, layout in zip(ids, layouts):
            self.layouts[w] = layout
        if need > self.obstacle_slots:
            # more static geoms than the models have: rebuild every world at the new size
            self.obstacle_slots = need + SPARE_SLOTS
            state = self._state.copy()
            self.models = self._build_all(self.layouts)
            self._make_batch(state)
            return
        for w, model in zip(ids, self._build_all(layouts)):
            self.models[w] = model
        self._set_models()

    def model(self, world: int = 0) -> mujoco.MjModel:
        """The compiled MjModel of one world (its layout's obstacles; same sizes in every world)."""
        return self.models[world]

    def _world_ids(self, world_ids: Sequence[int] | np.ndarray, source: str) -> np.ndarray:
        ids = np.asarray(world_ids)
        if ids.ndim != 1 or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
            raise ValueError(f"{source}: expected a 1-D list of world indices, got {world_ids!r}")
        ids = ids.astype(np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= self.n_worlds):
            raise ValueError(f"{source}: world index out of range 0..{self.n_worlds - 1} in {ids.tolist()}")
        if len(np.unique(ids)) != len(ids):
            raise ValueError(f"{source}: repeated world index in {ids.tolist()}")
        return ids

    def _drone_ids(self, worlds, drones, source: str) -> tuple[np.ndarray, np.ndarray]:
        """(worlds, drones) as equal-length 1-D int arrays in range (negative indices would wrap)."""
        w, d = np.asarray(worlds), np.asarray(drones)
        if w.ndim != 1 or d.shape != w.shape or (w.size and not (np.issubdtype(w.dtype, np.integer) and np.issubdtype(d.dtype, np.integer))):
            raise ValueError(f"{source}: expected two 1-D integer arrays of equal length (worlds, drones), got {worlds!r} and {drones!r}")
        w, d = w.astype(np.int64), d.astype(np.int64)
        if w.size and (w.min() < 0 or w.max() >= self.n_worlds or d.min() < 0 or d.max() >= self.n_drones):
            raise ValueError(f"{source}: index out of range (worlds 0..{self.n_worlds - 1}, drones 0..{self.n_drones - 1}) "
                             f"in worlds {w.tolist()}, drones {d.tolist()}")
        return w, d

    # ------------------------------------------------------------------ reset

    def reset_all_default(self) -> None:
        """Every world at rest with its drones on a row near the lower-left corner."""
        xy = np.zeros((self.n_worlds, self.n_drones, 2))
        xy[..., 0] = 0.3 + 0.3 * np.arange(self.n_drones)
        xy[..., 1] = 0.3
        self.reset(np.arange(self.n_worlds), xy)

    def reset(self, world_ids: Sequence[int] | np.ndarray, xy: np.ndarray) -> None:
        """Place the drones of the listed worlds at rest at xy (k, D, 2) m, at flight height.

        Other worlds are untouched.
        """
        ids = self._world_ids(world_ids, "reset world_ids")
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape != (len(ids), self.n_drones, 2):
            raise ValueError(f"reset positions: expected shape {(len(ids), self.n_drones, 2)} (worlds, drones, x y), got {xy.shape}")
        if not np.isfinite(xy).all():
            raise ValueError(f"reset positions: non-finite value in {xy.tolist()}")
        if len(ids) == 0:
            return
        order = np.argsort(ids)  # MuJoCo's batch takes its worlds in increasing order only
        ids, xy = ids[order], xy[order]
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE)
        qpos = self.qpos[ids]
        if self.fidelity == "quadrotor":
            height = np.full(xy.shape[:-1] + (1,), self.config.flight_height)
            qpos[:, self._qpos_idx] = np.concatenate([xy, height, np.broadcast_to(UNIT_QUAT, xy.shape[:-1] + (4,))], -1)
            hover = self._hover_thrust()  # rotors already spinning at hover thrust
            act = self.act[ids]
            act[:, self._act_idx] = hover
            self.act[ids] = act
            ctrl = self.ctrl[ids]
            ctrl[:, self._ctrl_idx] = hover
            self.ctrl[ids] = ctrl
            mask = np.zeros((self.n_drones, self.n_worlds), bool)  # the controller's drone-major order
            mask[:, ids] = True
            self.controller.reset(self.n_worlds * self.n_drones, mask.ravel())
        else:
            qpos[:, self._qpos_idx] = xy
        self.qpos[ids] = qpos
        self.qvel[ids] = 0.0
        self.batch.forward(ids)
        self._warnings[ids] = self.batch.warning[ids, :, 1]
        self.commands[ids] = 0.0
        self._pending[:, ids] = 0.0
        self.contacts[ids] = False
        self.time[ids] = 0.0

    def _hover_thrust(self) -> float:
        """N per rotor that holds a drone's weight."""
        return self.params["mass"] * 9.81 / 4

    def halt(self, worlds: np.ndarray, drones: np.ndarray) -> None:
        """Stop drone drones[k] of world worlds[k] dead (all its velocities 0), where it is.

        For a caught evader: commanded to stop, it would coast on for a few tenths of a second,
        into the pursuer that just caught it. A quadrotor is also levelled (its yaw kept) and its
        rotors set to hover thrust: caught while tilted, it would accelerate off again."""
        worlds, drones = self._drone_ids(worlds, drones, "halt")
        touched, row = np.unique(worlds, return_inverse=True)  # row[k]: drone k's world among the touched ones
        rows = row[:, None]
        qvel = self.qvel[touched]
        qvel[rows, self._qvel_idx[drones]] = 0.0
        self.qvel[touched] = qvel
        if self.fidelity == "quadrotor":
            qpos = self.qpos[touched]
            quat_cols = self._qpos_idx[drones, 3:7]  # (K, 4): w, x, y, z
            qw, qx, qy, qz = np.moveaxis(qpos[rows, quat_cols], -1, 0)
            half_yaw = 0.5 * np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy**2 + qz**2))
            level = np.zeros((len(drones), 4))
            level[:, 0], level[:, 3] = np.cos(half_yaw), np.sin(half_yaw)
            qpos[rows, quat_cols] = level
            self.qpos[touched] = qpos
            act, ctrl = self.act[touched], self.ctrl[touched]
            act[rows, self._act_idx[drones]] = ctrl[rows, self._ctrl_idx[drones]] = self._hover_thrust()
            self.act[touched], self.ctrl[touched] = act, ctrl
        if self.fidelity == "quadrotor":
            self.batch.forward(touched)

    # ------------------------------------------------------------------ state

    def positions(self) -> np.ndarray:
        """(W, D, 3) m world (a copy)."""
        if self.fidelity == "quadrotor":
            return self.qpos[:, self._qpos_idx[:, :3]]
        p = np.empty((self.n_worlds, self.n_drones, 3))
        p[..., :2] = self.qpos[:, self._qpos_idx]
        p[..., 2] = self.config.flight_height
        return p

    def velocities(self) -> np.ndarray:
        """(W, D, 3) m/s world (a copy)."""
        if self.fidelity == "quadrotor":
            return self.qvel[:, self._qvel_idx[:, :3]]
        v = np.zeros((self.n_worlds, self.n_drones, 3))
        v[..., :2] = self.qvel[:, self._qvel_idx]
        return v

    def quaternions(self) -> np.ndarray:
        """(W, D, 4) w, x, y, z body->world (a copy; identity in point fidelity)."""
        if self.fidelity == "quadrotor":
            return self.qpos[:, self._qpos_idx[:, 3:7]]
        return np.broadcast_to(UNIT_QUAT, (self.n_worlds, self.n_drones, 4)).copy()

    def state(self) -> DroneState:
        """Every drone of every world now (copies); see DroneState for shapes and frames."""
        W, D = self.n_worlds, self.n_drones
        if self.fidelity == "quadrotor":
            q = self.qpos[:, self._qpos_idx]
            v = self.qvel[:, self._qvel_idx]
            return DroneState(q[..., :3], v[..., :3], q[..., 3:7], v[..., 3:6], self.act[:, self._act_idx])
        return DroneState(self.positions(), self.velocities(), self.quaternions(), np.zeros((W, D, 3)), np.zeros((W, D, 4)))

    # ------------------------------------------------------------------ stepping

    def step(self, commands: np.ndarray, strict: bool = True, worlds: np.ndarray | None = None, warn: bool = True) -> np.ndarray:
        """Advance every world by control_dt under velocity commands (W, D, 2) m/s world.

        Commands are clipped to each drone's max speed. The pursuers' commands take effect
        config.command_latency later (until then the ones given before, zero after a reset).
        Returns contacts (W, D) bool: the
        drone touched a wall, an obstacle or another drone during the step. A world whose
        physics went bad raises FloatingPointError, or with strict=False is flagged in
        `self.diverged` (W,) bool for the caller to end and reset and told in `self.divergence`
        (the text, else None), and as a RuntimeWarning unless warn=False (a caller that tells it
        once its own step is whole, as PursuitEnv does). With `worlds` (W,) bool
        only those worlds are simulated; the others keep their drones' state and their clock
        (no contacts), and the stepped ones move exactly as in a step of all. A paused world
        keeps its memory too: its last commands (`self.commands`), the pursuers' commands still
        on their way and its quadrotor controller's integrator, so that stepped again (without a
        reset) it flies on as if it had never been paused; its commands in this call are unused.
        """
        cmd = check_commands(commands, (self.n_worlds, self.n_drones, 2))
        cmd = clip_norm(cmd, self.max_speed)
        ids = self._stepped_ids(worlds)
        if ids is None:
            self.commands[:] = cmd
        else:
            self.commands[ids] = cmd[ids]
        tick_cmds = self._tick_commands(cmd, ids)
        if ids is not None and len(ids) == 0:
            self.contacts[:] = False
        else:
            with mujoco_log_quiet():
                (self._step_quadrotor if self.fidelity == "quadrotor" else self._step_point)(tick_cmds, ids)
        if ids is None:
            self.time += self.config.control_dt
        else:
            self.time[ids] += self.config.control_dt
        self._check_health(strict, warn)
        return self.contacts.copy()

    def _tick_commands(self, cmd: np.ndarray, ids: np.ndarray | None = None) -> list[np.ndarray]:
        """The command (W, D, 2) m/s world in force at each controller tick of this step: the
        evaders' as given, the pursuers' as given command_latency ticks earlier. Then `cmd` joins
        the pending ones of the worlds stepped, ids (None: all); a paused world's wait."""
        T = self.config.substeps // self.config.substeps_per_control
        L = self._latency_ticks
        if L == 0:
            return [cmd] * T
        P = self.config.n_pursuers
        by_lag: dict[int, np.ndarray] = {}
        for i in range(min(L, T)):  # ticks before this step's own command arrives
            lag = -(-(L - i) // T)  # steps back to the command in force at tick i
            if lag not in by_lag:
                by_lag[lag] = cmd.copy()
                by_lag[lag][:, :P] = self._pending[-lag]
        ticks = [by_lag[-(-(L - i) // T)] for i in range(min(L, T))] + [cmd] * max(T - L, 0)
        if ids is None:
            self._pending[:-1] = self._pending[1:]
            self._pending[-1] = cmd[:, :P]
        else:
            self._pending[:-1, ids] = self._pending[1:, ids]
            self._pending[-1, ids] = cmd[ids, :P]
        return ticks

    def _stepped_ids(self, worlds: np.ndarray | None) -> np.ndarray | None:
        """The indices of the worlds to simulate, or None for all of them."""
        if worlds is None:
            return None
        mask = np.asarray(worlds)
        if mask.shape != (self.n_worlds,) or mask.dtype != bool:
            raise ValueError(f"worlds: expected a ({self.n_worlds},) bool mask, got {mask.dtype} of shape {mask.shape}")
        return None if mask.all() else np.flatnonzero(mask)

    def _rollout_contacts(self, k: int, ids: np.ndarray | None) -> np.ndarray:
        """Run k physics steps of the worlds ids (None: all); (W, D) bool: drones in contact
        in any of them (False in the worlds not run)."""
        if ids is None:
            rec = self.batch.rollout(k, record=("sensordata",), out=self._record)["sensordata"]
            return (rec[:, :, self.ids.contact_adr] > 0).any(axis=1)
        rec = self.batch.rollout(k, record=("sensordata",), ids=ids)["sensordata"]
        touched = np.zeros((self.n_worlds, self.n_drones), bool)
        touched[ids] = (rec[:, :, self.ids.contact_adr] > 0).any(axis=1)
        return touched

    def _step_point(self, tick_cmds: list[np.ndarray], ids: np.ndarray | None = None) -> None:
        """Every controller tick: the force that moves each drone's velocity toward its command
        in force (tick_cmds, see _tick_commands) as a
        first-order lag of point_time_constant would over the tick (exact for an unlimited
        one), its acceleration capped in norm at point_max_accel. Neither follows drone_mass:
        the quadrotor's controller scales its forces with the mass, and its tilt limit, not its
        thrust, caps the acceleration while the rotors lift config.MIN_THRUST_TO_WEIGHT times
        the weight (tests/test_controller.py checks the match at the heaviest mass accepted)."""
        k = self.config.substeps_per_control
        tick = k * self.config.physics_dt
        rate = -np.expm1(-tick / self.params["point_time_constant"]) / tick  # 1/s
        mass, limit = self.params["mass"], self.params["point_max_accel"]
        contacts = self.contacts
        contacts[:] = False
        for cmd in tick_cmds:
            accel = clip_norm(rate * (cmd - self.qvel[:, self._qvel_idx]), limit)  # (W, D, 2) m/s^2
            self._state[:, self._write_cols] = (mass * accel).reshape(self.n_worlds, -1)
            contacts |= self._rollout_contacts(k, ids)
            for observer in self.observers:
                observer(self)

    def _step_quadrotor(self, tick_cmds: list[np.ndarray], ids: np.ndarray | None = None) -> None:
        k = self.config.substeps_per_control
        dt = k * self.config.physics_dt
        state_t, out, W, D = self._state.T, self._out, self.n_worlds, self.n_drones
        out_t = out.reshape(7, D, W)
        contacts = self.contacts
        contacts[:] = False
        cmd = None
        keep = None  # (D*W,) drone-major: the drones of the paused worlds, whose controller memory stays
        if ids is not None:
            keep = np.ones((D, W), bool)
            keep[:, ids] = False
            keep = keep.ravel()
        for tick_cmd in tick_cmds:
            if tick_cmd is not cmd:
                cmd = tick_cmd
                cmd_t = np.ascontiguousarray(cmd.transpose(2, 1, 0)).reshape(2, -1)  # (2, D*W)
            x = state_t[self._read_cols].reshape(13, -1)  # pos 3, quat 4, vel 3, angvel 3 (x D*W)
            rot = quat_to_rotmat(x[3:7])
            out[4:] = linear_drag(rot, x[7:10], self.drag)  # held for the k physics steps
            out[:4] = self.controller.compute(x[:3], x[7:10], x[3:7], x[10:13], cmd_t, dt, rot, out[4:], keep)
            state_t[self._write_cols] = out_t
            contacts |= self._rollout_contacts(k, ids)
            for observer in self.observers:
                observer(self)

    def _check_health(self, strict: bool = True, warn: bool = True) -> None:
        """Raise FloatingPointError naming the worlds where MuJoCo raised a warning, in MuJoCo's
        words; with strict=False set `self.divergence` to that text instead and, if `warn`, warn
        it (a RuntimeWarning, once per step).

        MuJoCo resets a simulation whose state goes bad (BADQPOS, BADQVEL, BADQACC) and a
        batch rollout stops one whose warnings rise (e.g. CONTACTFULL): either way that
        world's step did not happen as asked. A MuJoCo clock out of step with ours is the
        last line of defence.
        """
        warning = self.batch.warning  # (W, kinds, 2): last info, count
        counts = warning[:, :, 1]
        risen = counts > self._warnings
        off = risen.any(axis=1) | (np.abs(self._mj_time - self.time) > 0.5 * self.config.physics_dt)
        self._warnings = counts.copy()
        self.diverged = off
        self.divergence = None
        if not off.any():
            return
        kinds = "MuJoCo warnings: " + (", ".join(sorted({WARNING_NAMES[k] for k in np.flatnonzero(risen.any(axis=0))})) or "none")
        w, k = np.nonzero(risen)
        said = "".join(f"; MuJoCo: {t}" for t in warning_texts(k, warning[w, k, 0]))
        worlds = np.flatnonzero(off).tolist()
        if strict:
            raise FloatingPointError(f"physics diverged in worlds {worlds} ({kinds}{said}; MuJoCo reset or stopped them): reset those worlds")
        self.divergence = (f"physics diverged in worlds {worlds} ({kinds}{said}): MuJoCo reset or stopped them; "
                           "a PursuitEnv ends their episodes as collisions")
        if warn:
            warnings.warn(self.divergence, RuntimeWarning, stacklevel=3)
