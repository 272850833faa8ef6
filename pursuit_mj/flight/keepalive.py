"""Setpoints that keep flowing while the chase loop is late.

The Crazyflie firmware levels a drone 0.5 s after its last low-level setpoint and stops its
motors after 2 s. The chase loop sends one setpoint per drone per decision, so a decision
interval over 0.5 s (decision rates under 2 Hz), or one decision that stalls (a slow policy,
a garbage-collection or swap pause of the process), would hand the drones to that watchdog
in mid-air. `SetpointStream` sends every decision's setpoints and, from a thread of its own,
sends each commanded drone's last one again whenever nothing went to it for `period` s; once
no decision came for its interval plus `stall_hover` s it sends hover setpoints at the flight
height instead (zero velocity at that height: the drone drifts only as its velocity estimate
does; it is not a position hold), until the next decision. All sends go through one lock, so a
repeated setpoint never overtakes a newer one, and after `close()` nothing more is sent: the
landing and an emergency stop are never followed by a stray setpoint (a send that hangs past
close's wait finishes only its own drone's setpoint; the drones after it get none).
"""

from __future__ import annotations

import threading
from typing import Callable, Sequence

import numpy as np

KEEPALIVE_PERIOD = 0.2  # s without a setpoint to a drone before its last one is repeated (firmware: levels after 0.5 s)


class SetpointStream:
    """links: DroneLink per drone (velocity(v), hover(z)); decision_interval, stall_hover s;
    height: m, the hover height; on_stall(age s, drones) / on_resume(age s) report a stall
    (from the keepalive thread / the caller of `send`, outside the lock)."""

    def __init__(self, links: Sequence, clock: Callable[[], float], decision_interval: float, stall_hover: float,
                 height: float, on_stall: Callable[[float, list[int]], None], on_resume: Callable[[float], None],
                 period: float = KEEPALIVE_PERIOD):
        self.links = links
        self.clock = clock
        self.decision_interval = decision_interval
        self.stall_hover = stall_hover
        self.height = height
        self.period = period
        self.on_stall, self.on_resume = on_stall, on_resume
        self._lock = threading.Lock()
        self._last: list[tuple[str, tuple[float, ...]] | None] = [None] * len(links)  # per drone: ("velocity", v) | ("hover", (z,))
        self._sent_at = np.full(len(links), -np.inf)  # clock s of the last setpoint to each drone
        self._decided_at = clock()
        self._stalled = False
        self._open = True
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoint-keepalive", daemon=True)
        self._thread.start()

    def send(self, velocities: dict[int, np.ndarray], hovers: Sequence[int]) -> bool:
        """One decision's setpoints: velocity (3,) m/s for the drones in `velocities`, a hover at
        the flight height for those in `hovers`; the others get nothing from now on. Returns
        False (and sends nothing) once closed."""
        resumed = None
        with self._lock:
            if not self._open:
                return False
            now = self.clock()
            if self._stalled:
                self._stalled, resumed = False, now - self._decided_at
            self._decided_at = now
            self._last = [None] * len(self.links)
            for i, v in velocities.items():
                self._last[i] = ("velocity", tuple(float(x) for x in v))
            for i in hovers:
                self._last[i] = ("hover", (self.height,))
            for i, last in enumerate(self._last):
                if last is not None:
                    self._emit(i, last, now)
        if resumed is not None:
            self.on_resume(resumed)
        return True

    def close(self, timeout: float = 1.0) -> None:
        """Nothing is sent after this returns (waits up to `timeout` s for a send in progress)."""
        got = self._lock.acquire(timeout=timeout)
        try:
            self._open = False
        finally:
            if got:
                self._lock.release()
        self._wake.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _emit(self, i: int, setpoint: tuple[str, tuple[float, ...]], now: float) -> None:
        if not self._open:  # closed while an earlier send of this round hung (close gave up waiting for the lock)
            return
        kind, values = setpoint
        if kind == "velocity":
            self.links[i].velocity(values)
        else:
            self.links[i].hover(values[0])
        self._sent_at[i] = now

    def _run(self) -> None:
        while not self._wake.wait(self.period / 4):
            try:
                self.tick()
            except Exception:  # a link that fails here is the chase loop's to notice (link_lost)
                pass

    def tick(self) -> None:
        """Repeat (or, in a stall, replace by a hover) every setpoint older than `period`."""
        stall = None
        with self._lock:
            if not self._open:
                return
            now = self.clock()
            age = now - self._decided_at
            stalled = age > self.decision_interval + self.stall_hover
            if stalled and not self._stalled:
                self._stalled = True
                stall = (age, [i for i, last in enumerate(self._last) if last is not None])
            for i, last in enumerate(self._last):
                if last is not None and now - self._sent_at[i] >= self.period:
                    self._emit(i, ("hover", (self.height,)) if stalled else last, now)
        if stall is not None:
            self.on_stall(*stall)
