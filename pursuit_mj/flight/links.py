"""cflib links to every drone of a flight: opened together, always closed, commands in SI units.

`LinkSet` is a context manager in the manner of cflib's `Swarm`: it builds one
`SyncCrazyflie` per URI through an injected factory (anything with `construct(uri)`,
cflib's own factory protocol), opens them in parallel within a timeout, and closes every
one on exit whatever happened. The same code flies real drones (radio://) and virtual
ones (udp://): only the URIs differ.

`DroneLink` wraps one drone: it streams two log blocks into the `StateBoard` (state:
stateEstimate.x/y/z/vx/vy/vz; health: pm.vbat and kalman.varPX/PY/PZ) and sends commands.
Units at this edge: positions m, velocities m/s in the drone's own world frame, yaw rate
rad/s here converted to the deg/s cflib expects, durations s.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Protocol, Sequence

import cflib.crtp
import numpy as np
from cflib.crazyflie import Crazyflie
from cflib.crazyflie.log import LogConfig
from cflib.crazyflie.syncCrazyflie import SyncCrazyflie

from .board import StateBoard

STATE_VARIABLES = tuple(f"stateEstimate.{k}" for k in ("x", "y", "z", "vx", "vy", "vz"))
HEALTH_VARIABLES = ("pm.vbat", "kalman.varPX", "kalman.varPY", "kalman.varPZ")
DEFAULT_CACHE = Path.home() / ".cache" / "pursuit_mj" / "cflib_toc"

_drivers_lock = threading.Lock()


def init_drivers() -> None:
    """Initialise cflib's link drivers once per process (cflib appends them on every call)."""
    with _drivers_lock:
        if not cflib.crtp.CLASSES:
            cflib.crtp.init_drivers()


class LinkError(ValueError):
    """A link could not be opened or set up; the message names the drone and its URI."""


class CrazyflieFactory(Protocol):
    def construct(self, uri: str) -> SyncCrazyflie: ...


class CachedFactory:
    """Builds SyncCrazyflie objects whose Crazyflie caches TOCs (by CRC) in `cache_dir`."""

    def __init__(self, cache_dir: str | Path | None = None):
        self.cache_dir = Path(cache_dir) if cache_dir is not None else DEFAULT_CACHE

    def construct(self, uri: str) -> SyncCrazyflie:
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        return SyncCrazyflie(uri, cf=Crazyflie(rw_cache=str(self.cache_dir)))


class DroneLink:
    """One drone's link (module docstring). Commands are silently skipped once the link is down."""

    def __init__(self, index: int, name: str, uri: str, scf: SyncCrazyflie, board: StateBoard):
        self.index, self.name, self.uri = index, name, uri
        self.scf = scf
        self.cf = scf.cf
        self.board = board
        self.error = ""
        self.cf.packet_received.add_callback(lambda pk: board.on_packet(index))
        self.cf.connection_lost.add_callback(lambda uri, msg: board.on_link_lost(index, msg))

    @property
    def label(self) -> str:
        return f"{self.name} ({self.uri})"

    @property
    def up(self) -> bool:
        return self.cf.link is not None and not self.board.lost[self.index]

    def open(self) -> None:
        """Blocking: connect and download the TOCs (cflib's connection sequence)."""
        try:
            self.scf.open_link()
        except Exception as exc:  # cflib raises a bare Exception carrying its reason
            self.error = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise
        # cflib's latency pings (unused here) deadlock a link that fails under a command of
        # ours: the send holds cflib's send lock while its error handler joins the ping
        # thread, which waits for that lock (seen landing a team after one link dropped)
        self.cf.link_statistics.stop()

    def abort_open(self, reason: str) -> None:
        """Make a pending `open` give up (cflib waits for a result without a timeout)."""
        self.cf.connection_failed.call(self.uri, reason)

    def wait_params(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not self.scf.is_params_updated():
            if time.monotonic() > deadline:
                raise LinkError(f"drone {self.label}: parameter values did not arrive within {timeout:g} s")
            time.sleep(0.01)

    def start_logs(self, state_period: float, health_period: float) -> None:
        """Stream the state and health blocks into the board; periods in s (10 ms steps)."""
        for name, variables, period, sink in (
            ("pursuit_state", STATE_VARIABLES, state_period, self.board.on_state),
            ("pursuit_health", HEALTH_VARIABLES, health_period, self.board.on_health),
        ):
            conf = LogConfig(name=name, period_in_ms=max(10, int(round(period * 1000))))
            for v in variables:
                conf.add_variable(v, "float")
            try:
                self.cf.log.add_config(conf)
            except KeyError as exc:
                raise LinkError(f"drone {self.label}: cannot log {exc} (firmware without it?)") from None
            except AttributeError as exc:
                raise LinkError(f"drone {self.label}: log block '{name}' refused ({exc})") from None
            conf.data_received_cb.add_callback(lambda ts, data, c, sink=sink: sink(self.index, data))
            conf.start()

    def param(self, name: str) -> float | None:
        """A parameter's value, or None if the drone has no such parameter."""
        group, _, short = name.partition(".")
        if self.cf.param.toc.get_element(group, short) is None:
            return None
        return float(self.cf.param.get_value(name))

    def set_param(self, name: str, value: float, timeout: float | None = None) -> None:
        """Set a parameter; with a timeout (s), wait until the drone confirms the new value."""
        if timeout is None:
            self.cf.param.set_value(name, str(value))
            return
        group, _, short = name.partition(".")
        done = threading.Event()

        def confirmed(full_name: str, value_s: str) -> None:
            if np.float32(value_s) == np.float32(value):  # float parameters travel as float32
                done.set()

        self.cf.param.add_update_callback(group=group, name=short, cb=confirmed)
        try:
            self.cf.param.set_value(name, str(value))
            if not done.wait(timeout):
                raise LinkError(f"drone {self.label}: no confirmation of {name} = {value} within {timeout:g} s")
        finally:
            self.cf.param.remove_update_callback(group=group, name=short, cb=confirmed)

    # ------------------------------------------------------------------ commands

    def velocity(self, v: Sequence[float], yaw_rate: float = 0.0) -> None:
        """Velocity setpoint: v (3,) m/s in the drone's world frame, yaw_rate rad/s."""
        if self.up:
            self.cf.commander.send_velocity_world_setpoint(float(v[0]), float(v[1]), float(v[2]), math.degrees(yaw_rate))

    def hover(self, z: float) -> None:
        """Hover at height z (m): a hover setpoint of zero velocity (not a position hold: the drone
        may drift as its velocity estimate does)."""
        if self.up:
            self.cf.commander.send_hover_setpoint(0.0, 0.0, 0.0, float(z))

    def takeoff(self, height: float, duration: float) -> None:
        """Rise to height (m) in duration (s), keeping the yaw the drone has (cflib's default,
        yaw 0, would turn a drone placed at another heading toward the estimator's +x)."""
        if self.up:
            self.cf.high_level_commander.takeoff(float(height), float(duration), yaw=None)

    def land(self, height: float, duration: float) -> None:
        """Hand control back to the high-level commander and land on it, keeping the yaw."""
        if self.up:
            self.cf.commander.send_notify_setpoint_stop()
            self.cf.high_level_commander.land(float(height), float(duration), yaw=None)

    def stop_motors(self) -> None:
        """After a landing: stop the planner and the motors."""
        if self.up:
            self.cf.high_level_commander.stop()
            self.cf.commander.send_stop_setpoint()

    def emergency_stop(self) -> None:
        """Cut the motors now (supervisor emergency stop, and a stop setpoint for older firmware)."""
        if self.up:
            self.cf.supervisor.send_emergency_stop()
            self.cf.commander.send_stop_setpoint()

    def close(self) -> None:
        # no latency pings (see open; again here for links whose open failed): one sent while
        # the link closes would make its thread handle the link error and try to join itself
        self.cf.link_statistics.stop()
        self._wake_packet_thread()
        self.scf.close_link()

    def _wake_packet_thread(self) -> None:
        """Stop cflib's packet thread and wake it. close_link waits for that thread, which polls
        the link's queue for a packet once a second and only then sees it was stopped: every
        close took a second after the last packet. Stopped first and woken by an empty item
        (which it skips), it ends at once. Nothing is done where cflib lacks either part."""
        incoming = getattr(self.cf, "incoming", None)
        packets = getattr(self.cf.link, "in_queue", None)
        if incoming is None or packets is None or not hasattr(incoming, "stop"):
            return
        incoming.stop()
        packets.put(None)


class LinkSet:
    """The links of one flight (module docstring). `links[i]` is drone i of the plan."""

    def __init__(self, names: Sequence[str], uris: Sequence[str], board: StateBoard,
                 factory: CrazyflieFactory | None = None, timeout: float = 10.0):
        init_drivers()
        factory = factory or CachedFactory()
        self.board = board
        self.timeout = timeout
        self.links = [DroneLink(i, n, u, factory.construct(u), board) for i, (n, u) in enumerate(zip(names, uris))]
        self._abandoned = False  # open() ended early: links that come up later are closed at once

    def __enter__(self) -> "LinkSet":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __iter__(self):
        return iter(self.links)

    def __len__(self) -> int:
        return len(self.links)

    def __getitem__(self, i: int) -> DroneLink:
        return self.links[i]

    def open(self) -> None:
        """Open every link in parallel; LinkError naming each failed drone if any fails or times
        out. Whatever ends it early (a failure, Ctrl-C) closes the links it opened."""
        threads: list[threading.Thread] = []
        try:
            self._open_all(threads)
        except BaseException:
            self._abandoned = True  # a link still connecting closes itself once it is up
            for link, th in zip(self.links, threads):
                if th.is_alive():
                    link.abort_open("the flight ended while connecting")
            self.close()
            raise

    def _open_all(self, threads: list[threading.Thread]) -> None:
        for link in self.links:
            th = threading.Thread(target=self._open_one, args=(link,), name=f"open-{link.name}", daemon=True)
            th.start()
            threads.append(th)
        deadline = time.monotonic() + self.timeout
        for link, th in zip(self.links, threads):
            th.join(max(0.0, deadline - time.monotonic()))
            if th.is_alive():
                link.error = f"no answer within {self.timeout:g} s"
                link.abort_open(link.error)
                th.join(2.0)
        failed = [l for l in self.links if not l.scf.is_link_open()]
        if failed:
            raise LinkError("cannot open " + "; ".join(f"drone {l.label}: {l.error or 'link failed'}" for l in failed))
        for link in self.links:
            link.wait_params(max(1.0, deadline - time.monotonic()))

    def _open_one(self, link: DroneLink) -> None:
        try:
            link.open()
        except Exception:  # recorded in link.error, reported by open()
            return
        if self._abandoned:
            self._close_one(link)

    def close(self) -> None:
        """Close every open link, in parallel (one whose packet thread cannot be woken,
        DroneLink._wake_packet_thread, takes a second); one failure does not keep the others open."""
        threads = [threading.Thread(target=self._close_one, args=(link,), name=f"close-{link.name}", daemon=True) for link in self.links]
        for th in threads:
            th.start()
        for th in threads:
            th.join(5.0)

    @staticmethod
    def _close_one(link: DroneLink) -> None:
        try:
            link.close()
        except Exception as exc:  # closing must reach every link
            link.error = f"close failed: {exc}"
