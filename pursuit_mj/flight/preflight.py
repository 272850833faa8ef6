"""Checks before take-off; any failure refuses the flight with the drone, its URI and the reason.

In order: every drone has its positioning deck; none is locked, tumbled or crashed; the
estimators are reset and converge; every battery is above the take-off threshold;
shared positioning systems (Lighthouse, Loco) put each drone near its declared start
(swapped URIs or a drone in the wrong place show up here). All links being up is checked
when they open (`LinkSet`).

Estimator convergence: over the last `WINDOW` health samples after the reset, the spread
(max - min) of each of kalman.varPX/PY/PZ stays below `estimator_variance` (cflib's own
criterion, which also holds for flow decks, whose position variance stays large), and for
Lighthouse and Loco the variances themselves are below it.
"""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from ..controller import ControllerGains
from .board import StateBoard
from .events import EventLog
from .links import LinkSet
from .plan import FlightPlan

DECK_PARAMS = {"flow": ("deck.bcFlow2", "deck.bcFlow"), "lighthouse": ("deck.bcLighthouse4",), "loco": ("deck.bcLoco", "deck.bcDWM1000")}
DECK_NAMES = {"flow": "Flow deck", "lighthouse": "Lighthouse deck", "loco": "Loco deck"}
WINDOW = 5  # health samples that must agree
BAD_STATES = {5: "tumbled (upside down)", 6: "locked (after an emergency stop: restart it)", 7: "crashed"}
POLL = 0.01  # s


class PreflightError(ValueError):
    """The flight is refused before take-off; the message names the drone and the reason."""


def _refuse(events: EventLog, check: str, reason: str) -> None:
    events.log("preflight_failed", check=check, reason=reason)
    raise PreflightError(f"preflight {check}: {reason}")


def check_decks(links: LinkSet, plan: FlightPlan, events: EventLog) -> None:
    names = DECK_PARAMS[plan.spec.positioning]
    for link in links:
        values = {n: link.param(n) for n in names}
        known = {n: v for n, v in values.items() if v is not None}
        if not known:
            _refuse(events, "deck", f"drone {link.label} reports none of {', '.join(names)} (firmware without deck detection?)")
        if not any(v >= 1 for v in known.values()):
            shown = ", ".join(f"{n} = {v:g}" for n, v in known.items())
            _refuse(events, "deck", f"drone {link.label}: no {DECK_NAMES[plan.spec.positioning]} detected ({shown})")


SUPERVISOR_TRIES = 3


def read_supervisor_state(link) -> int:
    """The supervisor's state bits. cflib answers 0 when no reply came within its 0.2 s, and 0
    would pass every check, so a 0 is asked again (a drone that is up always has a state bit
    set: ready to arm, armed or auto-armed)."""
    bits = 0
    for _ in range(SUPERVISOR_TRIES):
        bits = int(link.cf.supervisor.read_bitfield())
        if bits:
            break
        time.sleep(0.15)  # past cflib's 0.1 s cache of the last answer
    return bits


def check_supervisor(links: LinkSet, events: EventLog) -> None:
    """Refuse drones the firmware reports locked, tumbled or crashed (protocol 12 and newer)."""
    for link in links:
        if link.cf.platform.get_protocol_version() < 12:
            continue
        bits = read_supervisor_state(link)
        if bits == 0:
            _refuse(events, "state", f"drone {link.label}: its supervisor state did not arrive ({SUPERVISOR_TRIES} tries); "
                                     f"a drone that is up reports at least one state bit")
        for bit, what in BAD_STATES.items():
            if bits >> bit & 1:
                _refuse(events, "state", f"drone {link.label} is {what}")


TILT_PARAMS = ("posCtlPid.rLimit", "posCtlPid.pLimit")  # deg: the firmware velocity loop's roll and pitch limits


def match_tilt_limit(links: LinkSet, plan: FlightPlan, events: EventLog, timeout: float = 2.0) -> None:
    """Give the velocity loop of every commanded drone the simulator's tilt limit
    (ControllerGains.max_tilt, 15 deg; the firmware's default is 20), so that it turns as fast
    as the drones the policy learned with, not faster. Set in RAM only: a restart undoes it.
    A drone without these parameters (other firmware) flies as it is, with a warning."""
    degrees = round(math.degrees(ControllerGains().max_tilt), 3)
    ours = [link for link, c in zip(links, plan.commanded) if c]
    has = {link.label: all(link.param(n) is not None for n in TILT_PARAMS) for link in ours}
    for link in ours:
        if has[link.label]:
            for name in TILT_PARAMS:
                link.set_param(name, degrees, timeout=timeout)
    missing = [label for label, ok in has.items() if not ok]
    if missing:
        events.log("tilt_limit_unknown", drones=missing, level="warn",
                   reason=f"no {' / '.join(TILT_PARAMS)} parameters: their velocity loop keeps its own tilt limit")
    if len(missing) < len(has):
        events.log("tilt_limit", degrees=degrees, drones=[label for label, ok in has.items() if ok])


def reset_estimators(links: LinkSet, plan: FlightPlan, timeout: float = 2.0) -> None:
    """Select the Kalman estimator and the high-level commander, then reset the estimators
    of the drones this flight flies (targets are only read: someone else flies them).

    Waits for each drone to confirm the last write, so that later health samples are from
    after the reset.
    """
    ours = [link for link, c in zip(links, plan.commanded) if c]
    for link in ours:
        link.set_param("stabilizer.estimator", 2)  # the Kalman filter: needed by every deck here
        link.set_param("commander.enHighLevel", 1)
        link.set_param("kalman.resetEstimation", 1)
    for link in ours:
        link.set_param("kalman.resetEstimation", 0, timeout=timeout)


def wait_converged(board: StateBoard, plan: FlightPlan, events: EventLog, clock: Callable[[], float] = time.monotonic) -> None:
    """Wait for WINDOW fresh health samples per drone after the reset, then for convergence."""
    limits = plan.safety
    start = board.snapshot().health_count.copy()
    deadline = clock() + limits.estimator_timeout
    shared = plan.spec.positioning != "flow"
    while True:
        snap = board.snapshot()
        fresh = snap.health_count - start
        recent = snap.var[:, -WINDOW:, :]
        complete = np.isfinite(recent).all(axis=(1, 2))
        filled = np.where(np.isfinite(recent), recent, 0.0)
        spread = filled.max(axis=1) - filled.min(axis=1)
        ok = complete & (fresh >= WINDOW) & np.all(spread < limits.estimator_variance, axis=-1)
        if shared:
            ok &= np.all(recent[:, -1, :] < limits.estimator_variance, axis=-1)
        if ok.all():
            events.log("estimators_converged", variance=snap.var[:, -1, :])
            return
        if clock() > deadline:
            bad = int(np.flatnonzero(~ok)[0])
            name = plan.drones[bad].name
            last = snap.var[bad, -1]
            if fresh[bad] < WINDOW:
                _refuse(events, "estimator", f"drone {name} ({plan.drones[bad].uri}) sent only {int(fresh[bad])} health samples in {limits.estimator_timeout:g} s")
            _refuse(events, "estimator", f"drone {name} ({plan.drones[bad].uri}): the position estimate did not converge within "
                    f"{limits.estimator_timeout:g} s (kalman variances {np.round(last, 5).tolist()} m^2, threshold {limits.estimator_variance:g})")
        time.sleep(POLL)


def check_battery(board: StateBoard, plan: FlightPlan, events: EventLog) -> None:
    """Refuse the take-off naming every drone whose battery reads no voltage or is below battery_takeoff."""
    vbat = board.snapshot().vbat[:, -1]
    silent = [f"drone {d.name} ({d.uri}) reported no battery voltage" for d, v in zip(plan.drones, vbat) if not np.isfinite(v)]
    low = [f"drone {d.name} ({d.uri}): battery {v:.2f} V" for d, v in zip(plan.drones, vbat) if v < plan.safety.battery_takeoff]
    if low:
        silent.append(f"{', '.join(low)} {'is' if len(low) == 1 else 'are'} below {plan.safety.battery_takeoff:g} V "
                      f"(charge or swap {'it' if len(low) == 1 else 'them'})")
    if silent:
        _refuse(events, "battery", "; ".join(silent))


def wait_states(board: StateBoard, plan: FlightPlan, events: EventLog, timeout: float, clock: Callable[[], float] = time.monotonic) -> None:
    deadline = clock() + timeout
    while (board.snapshot().state_count == 0).any():
        if clock() > deadline:
            bad = int(np.flatnonzero(board.snapshot().state_count == 0)[0])
            _refuse(events, "state", f"drone {plan.drones[bad].name} ({plan.drones[bad].uri}) sent no state estimate within {timeout:g} s")
        time.sleep(POLL)


def check_starts(board: StateBoard, plan: FlightPlan, events: EventLog) -> None:
    """Lighthouse/Loco: each drone's estimate must be within start_tolerance of its start."""
    if plan.spec.positioning == "flow":
        return
    snap = board.snapshot()
    lab = plan.frames.to_lab(snap.pos[:, :2])
    starts = np.array([d.start for d in plan.drones])
    off = np.linalg.norm(lab - starts, axis=-1)
    for d, p, e in zip(plan.drones, lab, off):
        if e > plan.safety.start_tolerance:
            _refuse(events, "start", f"drone {d.name} ({d.uri}) is at lab [{p[0]:.2f}, {p[1]:.2f}], {e:.2f} m from its start "
                    f"{list(d.start)} (tolerance {plan.safety.start_tolerance:g} m): wrong spot or swapped URIs?")


def wait_fresh_states(board: StateBoard, plan: FlightPlan, events: EventLog, timeout: float,
                      clock: Callable[[], float] = time.monotonic) -> None:
    """Wait up to `timeout` s until every drone's latest state estimate is at most
    safety.stale_hover s old; refuse naming the first that stays older (its estimates stopped)."""
    deadline = clock() + timeout
    while True:
        age = board.snapshot().state_age
        stale = ~(age <= plan.safety.stale_hover)  # never sent one: infinite or NaN age
        if not stale.any():
            return
        if clock() > deadline:
            bad = int(np.flatnonzero(stale)[0])
            _refuse(events, "state", f"drone {plan.drones[bad].name} ({plan.drones[bad].uri}) sent no fresh state estimate "
                    f"within {timeout:g} s (the latest is {age[bad]:.1f} s old)")
        time.sleep(POLL)


RECHECK_AFTER = 10.0  # s: a go given later than this after the checks has them looked at again


def recheck(board: StateBoard, plan: FlightPlan, events: EventLog, clock: Callable[[], float] = time.monotonic) -> None:
    """What can change while the operator decides, checked again before take-off: fresh states,
    every battery above the take-off threshold, each drone still at its start (a drone moved or
    a battery that sagged during a long wait at the go/no-go prompt). Raises PreflightError."""
    wait_fresh_states(board, plan, events, plan.safety.estimator_timeout, clock)
    check_battery(board, plan, events)
    check_starts(board, plan, events)
    events.log("preflight_recheck_ok", battery=board.snapshot().vbat[:, -1])


def preflight(links: LinkSet, board: StateBoard, plan: FlightPlan, events: EventLog, clock: Callable[[], float] = time.monotonic) -> None:
    """Every check of the module docstring, in order; raises PreflightError on the first failure."""
    check_decks(links, plan, events)
    check_supervisor(links, events)
    match_tilt_limit(links, plan, events)
    reset_estimators(links, plan)
    wait_converged(board, plan, events, clock)
    check_battery(board, plan, events)
    wait_states(board, plan, events, plan.safety.estimator_timeout, clock)
    check_starts(board, plan, events)
    events.log("preflight_ok", battery=board.snapshot().vbat[:, -1])
