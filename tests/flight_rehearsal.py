"""Helpers of the flight tests: short flights on virtual Crazyflies, through real cflib over udp://."""

from __future__ import annotations

import copy
import threading
import time
from typing import Callable

import numpy as np

from pursuit_mj.flight.bridge import FlightBridge
from pursuit_mj.flight.events import EventLog
from pursuit_mj.flight.links import CachedFactory
from pursuit_mj.flight.plan import FlightPlan, resolve_flight
from pursuit_mj.flight.spec import flight_from_dict
from pursuit_mj.flight.virtual.fleet import VirtualFleet, VirtualPhysics
from pursuit_mj.obs_spec import ObsSpec

#: virtual estimators that settle fast, so that preflight takes a fraction of a second
FAST = VirtualPhysics(estimator_settle=0.03)

#: a short, forgiving flight: low, quick take-off and landing, generous timing for a busy machine
QUICK = {
    "name": "rehearsal",
    "layout": 0,
    "positioning": "flow",
    "flight_height": 0.3,
    "max_time": 3.0,
    "drones": [
        {"name": "p0", "uri": "radio://0/80/2M/E7E7E7E701", "role": "pursuer", "start": [0.8, 0.5]},
        {"name": "p1", "uri": "radio://0/80/2M/E7E7E7E702", "role": "pursuer", "start": [1.8, 0.5]},
        {"name": "p2", "uri": "radio://0/80/2M/E7E7E7E703", "role": "pursuer", "start": [2.8, 0.5]},
        {"name": "e0", "uri": "radio://0/80/2M/E7E7E7E704", "role": "evader", "start": [1.8, 3.0]},
    ],
    "safety": {
        "takeoff_speed": 1.0, "landing_speed": 1.0, "settle": 0.2, "max_speed": 0.8, "estimator_timeout": 5.0,
        "connect_timeout": 5.0, "stale_hover": 0.5, "stale_land": 2.0, "link_timeout": 2.0,
    },
}


def quick_spec(**changes) -> dict:
    """QUICK with top-level keys replaced (mappings such as safety are merged)."""
    data = copy.deepcopy(QUICK)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key].update(value)
        else:
            data[key] = value
    return data


def quick_plan(**changes) -> FlightPlan:
    return resolve_flight(flight_from_dict(quick_spec(**changes), "rehearsal.yaml"))


class ScriptedTeam:
    """A Policy that flies each pursuer along a fixed action (N, 2) in [-1, 1]; counts its calls."""

    name = "scripted"

    def __init__(self, actions, raise_at: int | None = None):
        self.actions = np.asarray(actions, np.float64)
        self.raise_at = raise_at
        self.calls = 0

    def reset(self, n_worlds: int, world_ids=None) -> None:
        pass

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        self.calls += 1
        if self.raise_at is not None and self.calls >= self.raise_at:
            raise KeyboardInterrupt
        return np.broadcast_to(self.actions, obs.shape[:-1] + (2,)).copy()


def fly_virtual(plan: FlightPlan, policy, tmp_path, drones=None, during: Callable[[VirtualFleet, FlightBridge], None] | None = None,
                aftermath: Callable[[VirtualFleet], None] | None = None, uris: Callable[[list[str]], list[str]] | None = None,
                sink: Callable[[dict], None] | None = None, on_bridge: Callable[[FlightBridge], None] | None = None,
                **bridge_kwargs):
    """Fly `plan` on virtual drones. `during(fleet, bridge)` runs in a thread once the chase starts;
    `aftermath(fleet)` runs after the flight while the drones still live; `uris` may change the links flown;
    `sink(record)` sees every event but the routine ones (steps) as it is logged (in the logging thread);
    `on_bridge(bridge)` is called once the bridge exists, before it flies.

    Returns (result or the exception raised by run(), events, fleet); the fleet is stopped.
    """
    events = EventLog(tmp_path / "events.jsonl")
    if sink is not None:
        events.add_sink("test", sink)
    fleet = VirtualFleet(plan, drones, physics=FAST)
    bridge_kwargs.setdefault("handle_signals", False)
    links = uris(list(fleet.uris)) if uris is not None else fleet.uris
    bridge = FlightBridge(plan.with_uris(links), policy, events, factory=CachedFactory(tmp_path / "toc"), **bridge_kwargs)
    if on_bridge is not None:
        on_bridge(bridge)
    worker: list[threading.Thread] = []
    if during is not None:
        def echo(record: dict) -> None:
            if record["kind"] == "chase":
                th = threading.Thread(target=during, args=(fleet, bridge), daemon=True)
                th.start()
                worker.append(th)

        events.add_sink("during", echo)
    with fleet:
        try:
            result = bridge.run()
        except Exception as exc:  # refusals are what some tests look for
            result = exc
        for th in worker:
            th.join(5.0)
        if aftermath is not None:
            aftermath(fleet)
    events.close()
    assert fleet.error is None, f"the virtual fleet failed: {fleet.error!r}"
    return result, events, fleet


def wait_for(condition: Callable[[], bool], timeout: float) -> bool:
    """Poll `condition` until it holds (True) or `timeout` s pass (False)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return False


class RacingClock:
    """time.monotonic until `race(rate)`, then `rate` times as fast: a flight whose clock runs ahead
    of its drones' own, as a loaded computer's virtual drones (or a late radio) fall behind it.
    Pass it as the bridge's `clock`; race() from an event sink starts it at that event."""

    def __init__(self):
        self._lock = threading.Lock()
        self._t0 = self._base = time.monotonic()
        self._rate = 1.0

    def race(self, rate: float) -> None:
        with self._lock:
            now = time.monotonic()
            self._base, self._t0, self._rate = self._base + (now - self._t0) * self._rate, now, float(rate)

    def __call__(self) -> float:
        with self._lock:
            return self._base + (time.monotonic() - self._t0) * self._rate


def kinds_in_order(events: EventLog | list[str], *kinds: str) -> bool:
    """Whether the listed event kinds all occur (first occurrences), in this order."""
    seen = [k for k in (events.kinds() if isinstance(events, EventLog) else events) if k in kinds]
    pos = [seen.index(k) if k in seen else -1 for k in kinds]
    return all(p >= 0 for p in pos) and pos == sorted(pos)
