"""The latest word from every drone: written by cflib's threads, read by the flight loop as one snapshot.

Estimates are kept in each drone's own estimate frame, as the drone logs them (m, m/s);
`flight/frames.py` maps them to the lab. Times come from the board's monotonic clock (s).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Callable

import numpy as np

HISTORY = 16  # recent health samples kept per drone


@dataclasses.dataclass(frozen=True)
class BoardSnapshot:
    """Copies of everything the board knows at time `now` (s). D drones, K = HISTORY.

    pos (D, 3) m and vel (D, 3) m/s: latest state estimate (estimate frame); state_time (D,) s
    of its arrival (-inf: none yet); state_count (D,); vbat (D, K) V and var (D, K, 3) m^2
    (kalman.varPX/PY/PZ): recent health samples, newest last, NaN where none;
    health_count (D,); last_packet (D,) s: arrival of any packet; lost (D,) bool: cflib
    reported the link lost; lost_reason (D,) str.
    """

    now: float
    pos: np.ndarray
    vel: np.ndarray
    state_time: np.ndarray
    state_count: np.ndarray
    vbat: np.ndarray
    var: np.ndarray
    health_count: np.ndarray
    last_packet: np.ndarray
    lost: np.ndarray
    lost_reason: tuple[str, ...]

    @property
    def state_age(self) -> np.ndarray:
        """(D,) s since each drone's last state estimate (inf if none)."""
        return self.now - self.state_time

    @property
    def silence(self) -> np.ndarray:
        """(D,) s since anything was heard from each drone."""
        return self.now - self.last_packet


class StateBoard:
    """Thread-safe latest state of n drones (see BoardSnapshot)."""

    def __init__(self, n: int, clock: Callable[[], float] = time.monotonic):
        self.n = n
        self.clock = clock
        self._lock = threading.Lock()
        self.pos = np.zeros((n, 3))
        self.vel = np.zeros((n, 3))
        self.state_time = np.full(n, -np.inf)
        self.state_count = np.zeros(n, np.int64)
        self.vbat = np.full((n, HISTORY), np.nan)
        self.var = np.full((n, HISTORY, 3), np.nan)
        self.health_count = np.zeros(n, np.int64)
        self.last_packet = np.full(n, clock())
        self.lost = np.zeros(n, bool)
        self.lost_reason = [""] * n

    def on_state(self, i: int, data: dict) -> None:
        """A state log sample: stateEstimate.x/y/z (m), vx/vy/vz (m/s)."""
        now = self.clock()
        with self._lock:
            self.pos[i] = (data["stateEstimate.x"], data["stateEstimate.y"], data["stateEstimate.z"])
            self.vel[i] = (data["stateEstimate.vx"], data["stateEstimate.vy"], data["stateEstimate.vz"])
            self.state_time[i] = now
            self.state_count[i] += 1
            self.last_packet[i] = now

    def on_health(self, i: int, data: dict) -> None:
        """A health log sample: pm.vbat (V), kalman.varPX/PY/PZ (m^2)."""
        with self._lock:
            self.vbat[i] = np.roll(self.vbat[i], -1)
            self.vbat[i, -1] = data["pm.vbat"]
            self.var[i] = np.roll(self.var[i], -1, axis=0)
            self.var[i, -1] = (data["kalman.varPX"], data["kalman.varPY"], data["kalman.varPZ"])
            self.health_count[i] += 1
            self.last_packet[i] = self.clock()

    def on_packet(self, i: int) -> None:
        """Any packet from drone i (keeps the link alive)."""
        self.last_packet[i] = self.clock()

    def on_link_lost(self, i: int, reason: str) -> None:
        with self._lock:
            self.lost[i] = True
            self.lost_reason[i] = reason.strip().splitlines()[0] if reason.strip() else "link lost"

    def snapshot(self) -> BoardSnapshot:
        with self._lock:
            return BoardSnapshot(
                self.clock(), self.pos.copy(), self.vel.copy(), self.state_time.copy(), self.state_count.copy(),
                self.vbat.copy(), self.var.copy(), self.health_count.copy(), self.last_packet.copy(), self.lost.copy(),
                tuple(self.lost_reason),
            )
