"""Virtual Crazyflies for a flight plan: one `udp://127.0.0.1:PORT` link per drone, one thread for all.

    with VirtualFleet(plan) as fleet:
        bridge_plan = plan.with_uris(fleet.uris)     # the same flight, virtual links
        ...                                          # cflib connects as to real drones
        fleet.drop_link(1); fleet.freeze_estimates(0); fleet.set_battery(2, 3.1); fleet.lose_fix(0)

Each drone is a `VirtualFirmware` (cflib's protocol) over a shared `Commander` (the
firmware's setpoint rules) over an `Airframe` (pursuit_mj's quadrotor physics in a MuJoCo
world of the lab). The thread steps the physics in real time in ticks of `tick` seconds,
answers packets as they come and streams log blocks on their period. Estimates are the
true state seen from each drone's estimate frame (flow deck: from where the estimator was
last reset, at the drone's start heading); the battery discharges while the motors run.
The thread stops on `stop()`/exit, or by itself after `max_duration` seconds; sockets bind
to 127.0.0.1 only.
"""

from __future__ import annotations

import dataclasses
import queue
import selectors
import socket
import threading
import time
from typing import Callable, Sequence

import numpy as np

from ...planar import rotate
from ..plan import FlightPlan
from . import commander as cmd
from .airframe import Airframe
from .firmware import Received, VirtualFirmware

MAX_CATCH_UP = 0.1  # s: a thread that falls further behind real time lets its clock lag instead


@dataclasses.dataclass(frozen=True)
class VirtualDrone:
    """How one virtual Crazyflie is built; the defaults make a healthy drone.

    decks: positioning decks it detects (None: the flight's own); battery: resting voltage
    at power-on (V); converges: whether its estimator settles after a reset.
    """

    decks: tuple[str, ...] | None = None
    battery: float = 4.1
    converges: bool = True


@dataclasses.dataclass(frozen=True)
class VirtualPhysics:
    """Constants of the virtual drones' sensors and battery (SI units)."""

    estimator_settle: float = 0.15  # s: time constant of the position variance after a reset
    variance_floor: float = 1e-5  # m^2: settled position variance
    fix_loss_growth: float = 0.1  # m^2/s: growth of the position variance after the fix is lost (lose_fix)
    drain_flying: float = 1.0e-3  # V/s of resting voltage while the motors run
    drain_idle: float = 1.0e-5  # V/s otherwise
    sag: float = 0.25  # V the loaded voltage drops at full thrust
    battery_empty: float = 3.0  # V: battery level 0 %
    battery_full: float = 4.2  # V: battery level 100 %


class VirtualFleet:
    """The virtual Crazyflies of a flight plan (module docstring). Drones in plan order."""

    def __init__(self, plan: FlightPlan, drones: Sequence[VirtualDrone] | None = None, tick: float = 0.01,
                 ports: Sequence[int] | None = None, max_duration: float = 3600.0, physics: VirtualPhysics | None = None):
        n = plan.n_drones
        drones = list(drones) if drones is not None else [VirtualDrone() for _ in range(n)]
        if len(drones) != n:
            raise ValueError(f"VirtualFleet: {n} drones in the plan, {len(drones)} VirtualDrone options given")
        self.plan = plan
        self.tick = float(tick)
        self.max_duration = float(max_duration)
        self.constants = physics or VirtualPhysics()
        starts = np.array([d.start for d in plan.drones], np.float64)
        self.airframe = Airframe(plan.n_pursuers, n - plan.n_pursuers, plan.lab.x, plan.lab.y, starts, mass=plan.task.drone_mass)
        self.commander = cmd.Commander(n)
        # estimate frames: flow decks measure from their last reset, at their start heading
        self.est_yaw = np.array([d.start_yaw for d in plan.drones]) if plan.spec.positioning == "flow" else np.zeros(n)
        self.est_origin = starts.copy() if plan.spec.positioning == "flow" else np.zeros((n, 2))
        self.shared_frame = plan.spec.positioning != "flow"
        self.reset_time = np.zeros(n)  # estimators start converging at power-on
        self.converges = np.array([d.converges for d in drones])
        self.fix_lost_at = np.full(n, np.inf)  # s (fleet time): when each drone lost its position fix (lose_fix)
        self.battery = np.array([d.battery for d in drones], np.float64)
        self.time = 0.0
        self.sensors: dict[str, np.ndarray] = {}
        self.firmware = [
            VirtualFirmware(i, self.commander, (lambda name, i=i: float(self.sensors[name][i])), self._estimate,
                            self._reset_estimator, d.decks if d.decks is not None else (plan.spec.positioning,))
            for i, d in enumerate(drones)
        ]
        self.sockets: list[socket.socket | None] = []
        self.clients: list[tuple | None] = [None] * n
        if ports is not None and len(ports) != n:
            raise ValueError(f"VirtualFleet ports: {len(ports)} given for {n} drones")
        for i in range(n):
            port = ports[i] if ports is not None else 0
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                s.bind(("127.0.0.1", port))
            except OSError as exc:
                s.close()
                for other in self.sockets:
                    other.close()
                raise ValueError(f"virtual drone {plan.drones[i].name}: cannot listen on udp://127.0.0.1:{port} ({exc.strerror})") from None
            s.setblocking(False)
            self.sockets.append(s)
        self.uris = [f"udp://127.0.0.1:{s.getsockname()[1]}" for s in self.sockets]
        self.lock = threading.Lock()
        self._requests: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self._selector: selectors.BaseSelector | None = None
        self._update_sensors(np.zeros(n, bool))

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> "VirtualFleet":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("VirtualFleet: already started")
        self._thread = threading.Thread(target=self._run, name="virtual-crazyflies", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for s in self.sockets:
            if s is not None:
                s.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ------------------------------------------------------------------ faults and inspection

    def drop_link(self, i: int) -> None:
        """Drone i goes silent: its socket closes (cflib's sends then fail), its firmware flies on."""
        self._requests.put(lambda: self._close_socket(i))

    def freeze_estimates(self, i: int, frozen: bool = True) -> None:
        """Drone i stops (or resumes) sending its state-estimate log blocks; the link stays up."""
        self._requests.put(lambda: setattr(self.firmware[i], "state_frozen", frozen))

    def lose_fix(self, i: int) -> None:
        """Drone i loses its position fix (Lighthouse base stations or Loco anchors out of
        sight): its Kalman position variance grows by `fix_loss_growth` m^2/s from now; its
        estimates go on coming (still the true state: the drift is not modelled)."""
        self._requests.put(lambda: self.fix_lost_at.__setitem__(i, self.time))

    def set_battery(self, i: int, volts: float) -> None:
        """Drone i's resting battery voltage becomes `volts` (V)."""
        self._requests.put(lambda: self.battery.__setitem__(i, float(volts)))

    def received(self, i: int) -> list[Received]:
        """Everything drone i received so far (setpoints, HLC commands, param writes), in order."""
        with self.lock:
            return list(self.firmware[i].received)

    def true_state(self) -> dict[str, np.ndarray]:
        """pos (D, 3) m lab, vel (D, 3) m/s lab, motors (D,) bool, locked (D,) bool, time (s)."""
        with self.lock:
            a = self.airframe
            return {"pos": a.pos, "vel": a.vel, "motors": a.motors.copy(), "locked": self.commander.locked.copy(), "time": self.time}

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        self._selector = sel = selectors.DefaultSelector()
        for i, s in enumerate(self.sockets):
            sel.register(s, selectors.EVENT_READ, i)
        start = time.monotonic()
        next_tick = start
        try:
            while not self._stop.is_set() and time.monotonic() - start < self.max_duration:
                for key, _ in sel.select(max(0.0, next_tick - time.monotonic())):
                    self._receive(key.data)
                while True:
                    try:
                        self._requests.get_nowait()()
                    except queue.Empty:
                        break
                now = time.monotonic()
                if now >= next_tick:
                    self._step()
                    next_tick += self.tick
                    if now - next_tick > MAX_CATCH_UP:
                        next_tick = now
        except BaseException as exc:  # the error is kept for the owner; the drones go silent
            self.error = exc
        finally:
            for i in range(len(self.sockets)):
                self._close_socket(i)
            sel.close()

    def _close_socket(self, i: int) -> None:
        s = self.sockets[i]
        if s is None:
            return
        if self._selector is not None:
            try:
                self._selector.unregister(s)
            except (KeyError, ValueError, OSError):  # never registered, or the selector is gone
                pass
        s.close()
        self.sockets[i] = None

    def _receive(self, i: int) -> None:
        s = self.sockets[i]
        while s is not None:
            try:
                data, addr = s.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP "port unreachable" from a client that left
                return
            self.clients[i] = addr
            with self.lock:
                replies = self.firmware[i].handle(self.time, data)
            self._send(i, replies)

    def _send(self, i: int, datagrams: list[bytes]) -> None:
        s, addr = self.sockets[i], self.clients[i]
        if s is None or addr is None:
            return
        for d in datagrams:
            try:
                s.sendto(d, addr)
            except OSError:
                return

    def _step(self) -> None:
        with self.lock:
            a = self.airframe
            pos_est, vel_est = self._estimates()
            # the airframe holds yaw 0 in the lab while the drone it stands for faces its start
            # heading, which is its estimate frame's x axis: its yaw in that frame is the airframe's
            yaw_est = _attitude(a.quat)[2]
            self.apply_firmware_limits()
            v_est, z_ref, vz_ff, motors = self.commander.compute(self.time, pos_est, vel_est, yaw_est, self.tick)
            a.step(self.tick, rotate(v_est, self.est_yaw), z_ref, vz_ff, motors)
            self.time += self.tick
            c = self.constants
            self.battery -= np.where(motors, c.drain_flying, c.drain_idle) * self.tick
            self._update_sensors(motors)
            logs = [fw.due_logs(self.time) for fw in self.firmware]
        for i, packets in enumerate(logs):
            self._send(i, packets)

    def apply_firmware_limits(self) -> None:
        """Fly each airframe with the roll and pitch limits its firmware's velocity loop has
        now (posCtlPid.rLimit and pLimit, deg), each on its own axis as the firmware limits
        them: on a diagonal the thrust tilts further than either. The axes are those of the
        drone the airframe stands for, which faces est_yaw in the lab (the airframe holds yaw 0)."""
        roll = [fw.params["posCtlPid.rLimit"] for fw in self.firmware]
        pitch = [fw.params["posCtlPid.pLimit"] for fw in self.firmware]
        # the firmware takes any value; the controller, angles in (0, 90) deg
        self.airframe.controller.set_roll_pitch_limits(np.radians(np.clip(roll, 1.0, 60.0)), np.radians(np.clip(pitch, 1.0, 60.0)),
                                                       heading=self.est_yaw)

    # ------------------------------------------------------------------ estimates and sensors

    def _estimates(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions (D, 3) m and velocities (D, 3) m/s in each drone's estimate frame."""
        a = self.airframe
        pos, vel = a.pos, a.vel
        pos[:, :2] = rotate(pos[:, :2] - self.est_origin, -self.est_yaw)
        vel[:, :2] = rotate(vel[:, :2], -self.est_yaw)
        return pos, vel

    def _estimate(self, i: int) -> np.ndarray:
        return self._estimates()[0][i]

    def _reset_estimator(self, i: int, t: float) -> None:
        self.reset_time[i] = t
        if not self.shared_frame:
            self.est_origin[i] = self.airframe.pos[i, :2]

    def _update_sensors(self, motors: np.ndarray) -> None:
        a, c = self.airframe, self.constants
        pos, vel = self._estimates()
        roll, pitch, yaw, tilt = _attitude(a.quat)
        since = self.time - self.reset_time
        var = np.where(self.converges, c.variance_floor + np.exp(-np.maximum(since, 0) / c.estimator_settle), 1.0 + 0.1 * np.sin(7.0 * self.time + np.arange(a.n)))
        var = var + c.fix_loss_growth * np.maximum(self.time - self.fix_lost_at, 0.0)  # none lost: time - inf, 0
        thrust = a.thrust
        load = thrust.sum(1) / (4 * a.params["max_thrust"])
        vbat = self.battery - c.sag * load
        level = np.clip((vbat - c.battery_empty) / (c.battery_full - c.battery_empty) * 100, 0, 100)
        com = self.commander
        bits = (
            (~com.locked) * 1 + com.armed * 2 + 4 + (com.armed & ~com.locked) * 8 + motors * 16 + (tilt > np.pi / 3) * 32
            + com.locked * 64 + (com.source == cmd.SRC_HL) * 256 + com.hl_finished * 512 + (~com.hl_enabled) * 1024
        )
        pwm = thrust / a.params["max_thrust"] * 65535
        self.sensors = {
            "stateEstimate.x": pos[:, 0], "stateEstimate.y": pos[:, 1], "stateEstimate.z": pos[:, 2],
            "stateEstimate.vx": vel[:, 0], "stateEstimate.vy": vel[:, 1], "stateEstimate.vz": vel[:, 2],
            "stateEstimate.roll": np.degrees(roll), "stateEstimate.pitch": np.degrees(pitch),
            "stateEstimate.yaw": np.degrees(yaw),
            "kalman.varPX": var, "kalman.varPY": var, "kalman.varPZ": var,
            "pm.vbat": vbat, "pm.batteryLevel": level, "pm.state": np.where(vbat < 3.2, 3, 0),
            "supervisor.info": bits,
            "motor.m1": pwm[:, 0], "motor.m2": pwm[:, 1], "motor.m3": pwm[:, 2], "motor.m4": pwm[:, 3],
        }


def _attitude(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (ZYX Euler) and tilt from quaternions (D, 4) w x y z; each (D,) rad."""
    w, x, y, z = q.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    tilt = np.arccos(np.clip(1 - 2 * (x * x + y * y), -1, 1))
    return roll, pitch, yaw, tilt


__all__ = ["VirtualFleet", "VirtualDrone", "VirtualPhysics"]
