"""The flight loop: take off, chase at the decision rate with the simulator's observations, land.

    plan = load_plan("configs/flight/example.yaml")
    result = FlightBridge(plan, policy, EventLog("flight.jsonl")).run()

Every decision step (1 / decision_rate s):
1. the latest estimates of all drones (StateBoard) -> lab frame -> layout frame;
2. abort checks, each ending the run with everyone landing: emergency stop (motors cut
   instead), Ctrl-C, a land request, any link lost, a drone without a fresh estimate for
   `stale_land`, a lost position fix (Lighthouse/Loco: a Kalman position variance above
   `fix_variance`), a low battery, a fence breach (also a virtual obstacle entered or
   crossed between two estimates) or too high, capture of every evader, the time limit;
3. captures by the simulator's rule; observations by the simulator's code (observe.py);
4. the policy's actions in [-1, 1]^2 times pursuer_speed, clipped (the simulator's action
   interface), and the escape model for evader drones; targets are only tracked;
5. layout -> lab velocities, then the safety filters (speed clamp, separation guard,
   geofence; judged at the positions the drones' measured motion takes them to by the time
   a command acts, the fence from each drone's own side of every surface), a vertical
   speed that holds the flight height, each drone's own frame;
6. `send_velocity_world_setpoint` for every commanded drone, or a hover setpoint at the
   flight height for a drone whose estimate is stale or an evader that was caught. Between
   decisions `keepalive.SetpointStream` repeats them every 0.2 s, and when a decision is
   late by `stall_hover` s it sends hover setpoints instead, so the firmware's setpoint
   watchdog (level after 0.5 s, motors off after 2 s) never takes over in the chase.
Take-off and landing go through the high-level commander. Every event is logged with its
time (events.py); `FlightResult.steps` keeps what each step saw and sent.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import sys
import threading
import time
from typing import Callable

import numpy as np

from ..io_utils import interrupt_handled
from ..planar import clip_norm
from ..policy import NonFiniteAction, Policy
from .board import BoardSnapshot, StateBoard
from .events import EventLog
from .keepalive import SetpointStream
from .links import CrazyflieFactory, LinkError, LinkSet
from .observe import EvaderPilot, FlightObserver
from .plan import FlightPlan
from .preflight import RECHECK_AFTER, PreflightError, preflight, recheck, wait_fresh_states
from .safety import Fence, altitude_speed, clamp_speed, keep_apart_and_inside
from .spec import LANDED_HEIGHT  # m: a drone whose last height estimate is below this counts as landed

STATE_PERIOD = 0.02  # s between state-estimate log packets (50 Hz)
HEALTH_PERIOD = 0.05  # s between health log packets
LANDING_CEILING_MARGIN = 0.5  # m above safety.max_altitude: the highest height a landing is timed for
# s: the most a take-off or landing waits past its own time (duration + settle) for drones that are
# late (a drone's clock or radio behind the computer's: a loaded computer's virtual drones) but still
# reporting: the take-off for them to reach the flight height, the landing for them to be down
LATE_GRACE = 1.0


def landing_duration(heights: np.ndarray, commanded: np.ndarray, flight_height: float, landing_speed: float,
                     ceiling: float) -> float:
    """s for the landing: the highest commanded drone (heights (D,) m, lab; not finite: unknown,
    taken as flight_height) comes down at landing_speed m/s. Targets are carried by someone else:
    one held high must not slow everyone's descent. A height above `ceiling` m (no drone flies
    there: the altitude check lands everyone well below it) is a broken estimate, timed as
    `ceiling`: an infinite or absurd one must not hold every drone in the air for days."""
    z = np.asarray(heights, np.float64)[commanded]
    z = np.minimum(np.where(np.isfinite(z), z, flight_height), ceiling)
    return max(float(z.max(initial=0.0)), 0.1) / landing_speed


@dataclasses.dataclass
class StepRecord:
    """One decision step. D drones (plan order), N pursuers, M evaders.

    t (s, event-log clock); est_pos (D, 3) m and est_vel (D, 3) m/s as the drones estimated
    them (their own frames); pos (D, 2) m and vel (D, 2) m/s in the layout frame; obs
    (N, dim) the pursuers' observations; actions (N, 2) the policy's output in [-1, 1];
    wanted (D, 2) m/s lab: the task's commands before the safety filters; sent (D, 3) m/s
    in each drone's frame (vx, vy, vz), NaN rows for drones not given a velocity;
    mode (D,) 'velocity' | 'hover' | 'none'; filtered (D,) bool: a safety filter changed the
    command; captured (M,) bool.
    """

    t: float
    est_pos: np.ndarray
    est_vel: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    obs: np.ndarray
    actions: np.ndarray
    wanted: np.ndarray
    sent: np.ndarray
    mode: np.ndarray
    filtered: np.ndarray
    captured: np.ndarray


@dataclasses.dataclass
class FlightResult:
    """How a flight ended. outcome: captured | timeout | interrupted | land_requested |
    link_lost | stale | fix_lost | low_battery | fence_breach | altitude | takeoff_failed |
    emergency_stop | error; reason: a sentence; chase_time (s); captures; steps; landed:
    the landing ran for every commanded drone and each one's last height estimate is below
    LANDED_HEIGHT; heights (D,) m: the last height estimates at the end (NaN: none);
    interrupted_by: the stop signal (`interrupt`'s reason: Ctrl-C, SIGTERM, ...) that came after
    take-off, whatever ended the run (one during a landing begun for another reason, a capture
    or the time limit, lets that landing go on and the outcome stays), else None."""

    outcome: str
    reason: str
    chase_time: float
    captures: int
    steps: list[StepRecord]
    landed: bool
    heights: np.ndarray | None = None
    interrupted_by: str | None = None


def _checked_commands(answer, shape: tuple[int, ...], who: str, names: list[str], axes: str) -> np.ndarray:
    """`answer` of a policy or escape model as a float array of `shape`, whose second-to-last
    axis runs over the drones `names` ('pursuer p0', ...), read as the env and eval read actions
    (a torch tensor by its values, with or without grad); ValueError naming `who`, the drone and
    the value when it is not real numbers (bools, text and complex numbers are refused, not cast:
    True would fly at full speed), a masked array with masked entries, not of that shape, or not finite."""
    from ..env import MaskedValues, plain_array  # here: the bridge's import stays free of the simulator

    try:
        raw = plain_array(answer, who)
    except MaskedValues:
        raise
    except (TypeError, ValueError):  # ragged lists
        raise ValueError(f"{who}: expected numbers of shape {shape} {axes}, got {type(answer).__name__} {answer!r:.80}") from None
    if raw.dtype.kind not in "fiu":
        raise ValueError(f"{who}: expected real numbers {axes}, got an array of dtype {raw.dtype}: {answer!r:.80}")
    out = raw.astype(np.float64)
    if out.shape != shape:
        raise ValueError(f"{who}: expected an answer of shape {shape} {axes}, got shape {out.shape}")
    bad = ~np.isfinite(out).all(axis=-1)
    if bad.any():
        at = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(f"{who}: the answer for {names[at[-1]]} is {out[at].tolist()}, not a pair of finite numbers")
    return out


@dataclasses.dataclass(frozen=True)
class InFlightFailure:
    """An exception that ended a flight after its take-off was sent, the drones landed first:
    `part` the policy's or escape model's part that raised or answered wrongly ('policy NAME',
    'escape model MODEL'; None: the flight's own code), `landed` and `interrupted_by` (a stop
    signal that came meanwhile, during that landing too) as FlightResult's."""

    error: BaseException
    part: str | None
    landed: bool
    interrupted_by: str | None = None


class _Abort(Exception):
    def __init__(self, outcome: str, reason: str):
        super().__init__(reason)
        self.outcome, self.reason = outcome, reason


def guard_details(fence: Fence, pos_lab: np.ndarray, asked: np.ndarray, clearance_ahead: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
    """What the event of each safety filter reports about drones at pos_lab (D, 2) m (lab), each
    (D,): speed_clamped the `speed` asked (m/s, lab); separation the `gap` to the nearest other
    drone (m, centre to centre, now); geofence the `clearance` to the nearest border or obstacle
    surface (m, lab, now; negative outside the arena or inside an obstacle) and `clearance_ahead`,
    the one the fence judged, where the drone's motion takes it (Fence.judged)."""
    apart = np.linalg.norm(pos_lab[:, None, :] - pos_lab[None, :, :], axis=-1)
    np.fill_diagonal(apart, np.inf)
    return {"speed_clamped": {"speed": asked}, "separation": {"gap": apart.min(axis=1)},
            "geofence": {"clearance": fence.clearance(pos_lab), "clearance_ahead": clearance_ahead}}


class _Edges:
    """Logs a per-drone condition when it starts (rising edge), not on every step."""

    def __init__(self, events: EventLog, names: list[str]):
        self.events, self.names = events, names
        self.state: dict[str, np.ndarray] = {}

    def update(self, kind: str, flags: np.ndarray, **details: np.ndarray) -> None:
        before = self.state.get(kind, np.zeros_like(flags))
        for i in np.flatnonzero(flags & ~before):
            self.events.log(kind, drone=self.names[i], level="warn", **{k: v[i] for k, v in details.items()})
        self.state[kind] = flags.copy()


class _SignalRelay:
    """Runs what a signal asks for in a thread of its own: `post(signum)` from a signal handler,
    `act(signum)` on the relay's thread. A Python signal handler runs on the main thread between
    any two of its steps, also while that thread holds a lock: inside Event.wait (where the
    flight loop sleeps between decisions) it holds the Event's. A handler that set that Event
    itself waited for the lock forever, and the run hung with every drone hovering. `post`
    writes one byte to a pipe and takes no lock."""

    def __init__(self, act: Callable[[int], None]):
        self._act = act
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        self._thread = threading.Thread(target=self._run, name="signal-relay", daemon=True)
        self._thread.start()

    def post(self, signum: int) -> None:
        try:
            os.write(self._write, bytes([signum]))
        except OSError:  # a full pipe: thousands of signals not yet acted on, one more changes nothing
            pass

    def close(self) -> None:
        """After the handlers are given back: the thread acts on what came, then ends."""
        os.close(self._write)
        self._thread.join(1.0)

    def _run(self) -> None:
        try:
            while data := os.read(self._read, 64):  # b"": the write end closed
                for signum in data:
                    try:
                        self._act(signum)
                    except Exception as exc:  # the thread must live on: a later signal may be the one that cuts the motors
                        print(f"flight: acting on signal {signum} failed: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        finally:
            os.close(self._read)


class FlightBridge:
    """One flight of a plan with a policy (module docstring).

    factory: builds cflib's SyncCrazyflie per URI (default: TOC-cached, see links.py);
    recorder: optional FlightRecorder; seed: sensing and escape-model randomness;
    handle_signals: in the main thread, Ctrl-C, Ctrl-Z, SIGTERM and SIGHUP (a closed terminal; not
    when started under nohup) land everyone (a second one cuts the motors), before take-off they
    end the run at once, and Ctrl-\\ cuts the motors. Without it (handle_signals False, or another
    thread) a KeyboardInterrupt during the chase lands everyone, and one during the landing lets
    the landing finish before it goes on up (closing the links would cut the motors in the air):
    use emergency_stop() to cut them. confirm(): asked after the preflight checks, False refuses
    the take-off (an operator's go / no-go).
    """

    def __init__(self, plan: FlightPlan, policy: Policy, events: EventLog, factory: CrazyflieFactory | None = None,
                 recorder=None, seed: int = 0, handle_signals: bool = True, clock: Callable[[], float] = time.monotonic,
                 confirm: Callable[[], bool] | None = None):
        self.plan = plan
        self.policy = policy
        self.events = events
        self.factory = factory
        self.recorder = recorder
        self.seed = seed
        self.handle_signals = handle_signals
        self.clock = clock
        self.confirm = confirm
        limits = plan.safety
        self.fence = Fence(plan.layout, plan.transform, limits.geofence_margin, limits.lookahead, limits.breach_distance)
        self.edges = _Edges(events, plan.names)
        self.links: LinkSet | None = None
        self.board: StateBoard | None = None
        self._last_xy = np.full((plan.n_drones, 2), np.nan)  # lab m: each drone's previous estimate, for crossings
        self._stop = threading.Event()  # wakes the loop for any request below
        self._estop = threading.Event()
        self._interrupt = threading.Event()
        self._interrupt_reason = "Ctrl-C"
        self._interrupt_logged = False  # an `interrupt` event for it is in the log
        self._land_request = ""
        self._airborne = False
        self._took_off = False  # the take-off was sent
        self._landing = False
        self._lost_logged: set[int] = set()  # drones whose link_lost event is in the log
        self._in_flight = False  # past the checks: a stop signal lands instead of aborting
        self._stream: SetpointStream | None = None  # the chase's setpoints (keepalive.py)
        self._thinking: threading.Thread | None = None  # the latest decision: policy and escape model (_decision)
        self._answering: str | None = None  # the part whose answer the flight is asking for or checking, if any
        #: set when an exception ends the flight after take-off (run() raises it after the landing)
        self.failure: InFlightFailure | None = None
        if recorder is not None:
            events.add_sink("rerun", recorder.log_event)

    # ------------------------------------------------------------------ requests (any thread)

    def emergency_stop(self, reason: str = "emergency stop requested") -> None:
        """Cut every drone's motors now, from the calling thread, and end the run."""
        if self._estop.is_set():
            return
        self._estop.set()
        self._stop.set()
        self._cut_motors_and_log(reason)

    def _emergency_stop_soon(self, reason: str) -> None:
        """emergency_stop from a signal handler: the run ends now, the motors are cut from a
        thread of its own. The handler runs on the main thread, which may be inside a link's
        send and hold that link's lock."""
        if self._estop.is_set():
            return
        self._estop.set()
        self._stop.set()
        threading.Thread(target=self._cut_motors_and_log, args=(reason,), name="emergency-stop", daemon=True).start()

    def _second_during_landing(self) -> bool:
        """A stop signal now would be the second: the drones are landing and one came before."""
        return self._landing and self._interrupt.is_set()

    def _cut_motors_and_log(self, reason: str) -> None:
        self._cut_motors()
        self.events.log("emergency_stop", reason=reason, level="error")

    def _cut_motors(self) -> None:
        """Every link's emergency stop at once, each from a thread of its own (a link whose radio
        hangs must not hold back the others), after the chase's setpoints are stopped for good."""
        stream = self._stream
        if stream is not None:
            stream.close(timeout=0.2)
        links = self.links  # may be cleared by the flight thread meanwhile
        if links is None:
            return
        threads = [threading.Thread(target=link.emergency_stop, name=f"emergency-stop-{link.name}", daemon=True) for link in links]
        for th in threads:
            th.start()
        for th in threads:
            th.join(2.0)

    def request_land(self, reason: str = "landing requested") -> None:
        """End the run: everyone lands."""
        self._land_request = reason
        self._stop.set()

    def interrupt(self, reason: str = "Ctrl-C") -> None:
        """What Ctrl-C does: everyone lands. A second one during the landing (after an earlier
        stop signal) cuts the motors; a first one during a landing begun for another reason
        (capture, time-out, ...) lets that landing go on."""
        if self._second_during_landing():
            self.emergency_stop(f"second {reason} during the landing")
            return
        self._interrupt_reason = reason
        self._interrupt.set()
        self._stop.set()

    # ------------------------------------------------------------------ the flight

    def run(self) -> FlightResult:
        """Connect, check, take off, chase, land. Raises LinkError/PreflightError (ValueError)
        when the flight is refused before take-off; links are always closed."""
        plan = self.plan
        self.events.log("start", flight=plan.spec.name, source=plan.spec.source, drones=plan.names, uris=plan.uris,
                        layout=plan.layout.source, positioning=plan.spec.positioning, decision_rate=1.0 / plan.dt)
        for warning in plan.warnings:  # what the plan found risky, on record with the flight
            self.events.log("plan_warning", warning=warning, level="warn")
        self.board = StateBoard(plan.n_drones, self.clock)
        try:
            with self._signals(), LinkSet(plan.names, plan.uris, self.board, self.factory, plan.safety.connect_timeout) as links:
                self.links = links
                self.events.log("links_up", uris=plan.uris)
                for link in links:
                    link.start_logs(STATE_PERIOD, HEALTH_PERIOD)
                # before the flight is under way: Ctrl-C still ends the run if a reset hangs, and a slow
                # one delays the checks, not the take-off after them
                self.policy.reset(1)
                preflight(links, self.board, plan, self.events, self.clock)
                if self.confirm is not None:
                    asked = self.clock()
                    if not self.confirm():
                        raise PreflightError("take-off declined by the operator")
                    if self.clock() - asked > RECHECK_AFTER:
                        recheck(self.board, plan, self.events, self.clock)
                # whatever the wait: a drone whose estimates stopped since the checks does not take off
                wait_fresh_states(self.board, plan, self.events, plan.safety.estimator_timeout, self.clock)
                self._in_flight = True
                return self._fly()
        except (LinkError, PreflightError) as exc:
            self.events.log("refused", reason=str(exc), level="error")
            raise
        except KeyboardInterrupt:  # before take-off: nothing to land
            self.events.log("interrupt", reason=self._interrupt_reason, before_takeoff=True, level="warn")
            raise
        finally:
            self.links = None
            self.events.log("links_closed")
            if self._thinking is not None and self._thinking.is_alive():  # a hung decision the flight stopped waiting for
                self.events.log("policy_still_running", level="warn",
                                why="its last decision (the policy, then the escape model) never returned; do not fly this "
                                    "policy object again in this process (a new act or reset would run beside the old one)")

    @contextlib.contextmanager
    def _signals(self):
        """Stop signals from the connection to the end: before take-off they raise KeyboardInterrupt
        (the run ends, links close), once flying they land everyone (`interrupt`). SIGINT is taken
        even where the shell started us ignoring it (a background job): a flight must be stoppable.
        Ctrl-Z (SIGTSTP) is a stop signal too: suspended, the process would send no setpoint and
        the firmware's watchdog would stop every motor in the air."""
        if not (self.handle_signals and threading.current_thread() is threading.main_thread()):
            yield
            return
        names = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP", signal.SIGTSTP: "Ctrl-Z"}

        def act(signum: int) -> None:  # on the relay's thread: it may wait for any lock
            if signum == signal.SIGQUIT:
                self._emergency_stop_soon("Ctrl-\\ pressed")
                return
            reason = names.get(signum, f"signal {signum}")
            if self._second_during_landing():
                self._emergency_stop_soon(f"second {reason} during the landing")
            else:
                self.interrupt(reason)

        relay = _SignalRelay(act)

        def on_stop(signum, frame):  # on the main thread, wherever it is: no lock taken here
            if not self._in_flight:
                self._interrupt_reason = names.get(signum, f"signal {signum}")
                raise KeyboardInterrupt(self._interrupt_reason)
            relay.post(signum)

        previous = {sig: signal.getsignal(sig) for sig in (*names, signal.SIGQUIT)}
        try:
            for sig in names:
                if sig == signal.SIGHUP and previous[sig] == signal.SIG_IGN:
                    continue  # nohup: the operator asked to outlive the terminal
                signal.signal(sig, on_stop)
            signal.signal(signal.SIGQUIT, lambda signum, frame: relay.post(signum))
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            relay.close()

    def _fly(self) -> FlightResult:
        steps: list[StepRecord] = []
        observer = FlightObserver(self.plan.task, self.plan.layout, self.seed)
        pilot = EvaderPilot(self.plan.task, self.seed)
        outcome, reason, chase_start = "", "", None
        try:
            self._takeoff()
            chase_start = self.clock()
            self.events.log("chase", policy=getattr(self.policy, "name", type(self.policy).__name__))
            outcome, reason = self._chase(observer, pilot, steps, chase_start)
        except _Abort as stop:
            outcome, reason = stop.outcome, stop.reason
        except KeyboardInterrupt:
            interrupt_handled()  # an outcome the result reports: the process must not end by SIGINT for it
            outcome, reason = "interrupted", self._interrupt_reason
        except BaseException as exc:  # SystemExit from a policy too: the links closing would cut every motor
            landed = False
            try:
                landed = self._land_all("error")  # first: nothing may come between an error and the landing
            finally:
                self.events.log("error", reason=f"{type(exc).__name__}: {exc}", level="error")
                if self._took_off:
                    stop = self._interrupt_reason if self._interrupt.is_set() else None
                    self.failure = InFlightFailure(exc, self._answering, landed, stop)
            raise
        chase_time = self.clock() - chase_start if chase_start is not None else 0.0
        self.events.log("end_of_run", outcome=outcome, reason=reason, chase_time=chase_time, level="info" if outcome == "captured" else "warn")
        landed = False
        if outcome != "emergency_stop" and not self._estop.is_set():
            landed = self._land_all(outcome)
        if outcome == "emergency_stop" or self._estop.is_set():  # also one during the landing
            outcome = "emergency_stop"
            self._cut_motors()  # once more, in case a packet was lost
        heights = self._lab_state(self.board.snapshot())[0][:, 2]
        signal_name = self._interrupt_reason if self._interrupt.is_set() else None
        return FlightResult(outcome, reason, chase_time, int(observer.captured.sum()), steps, landed, heights, signal_name)

    # ------------------------------------------------------------------ take-off and landing

    def _takeoff(self) -> None:
        plan, limits = self.plan, self.plan.safety
        self._check_abort(self.board.snapshot(), None)  # e.g. an emergency stop during the checks
        duration = plan.height / limits.takeoff_speed
        self.events.log("takeoff", height=plan.height, duration=duration)
        self._airborne = self._took_off = True
        for link, ours in zip(self.links, plan.commanded):
            if ours:
                link.takeoff(plan.height, duration)
        self._watch(duration + limits.settle)
        # drones running late (a late radio, virtual drones on a loaded computer) are judged once they are up
        self._watch(LATE_GRACE, until=lambda snap: not self._off_height(snap).any())
        snap = self.board.snapshot()
        z = self._lab_state(snap)[0][:, 2]
        off = self._off_height(snap, z)
        if off.any():
            i = int(np.argmax(np.where(off, np.abs(z - plan.height), -1.0)))
            raise _Abort("takeoff_failed", f"drone {plan.names[i]} is at {z[i]:.2f} m after take-off, not {plan.height:g} m")
        self.events.log("airborne", heights=z)

    def _off_height(self, snap: BoardSnapshot, z: np.ndarray | None = None) -> np.ndarray:
        """(D,) bool: commanded drones whose height estimate (z (D,) m lab, default from `snap`) is
        further than safety.height_tolerance from the flight height."""
        plan = self.plan
        z = self._lab_state(snap)[0][:, 2] if z is None else z
        return plan.commanded & (np.abs(z - plan.height) > plan.safety.height_tolerance)

    def _watch(self, duration: float, until: Callable[[BoardSnapshot], bool] | None = None) -> None:
        """Wait `duration` s (take-off), or less once until(snapshot) holds, while applying the
        abort checks; records states at the decision rate."""
        end = self.clock() + duration
        while self.clock() < end:
            snap = self.board.snapshot()
            self._check_abort(snap, None)
            self._record_only(snap)
            if until is not None and until(snap):
                return
            self._stop.wait(min(self.plan.dt, max(0.0, end - self.clock())))

    def _land_all(self, why: str) -> bool:
        """Everyone with a link lands through the high-level commander: for the landing's
        duration plus settle, and up to LATE_GRACE s more while a drone whose estimates go on
        coming is not yet down (its motors are stopped after that); returns whether every
        commanded drone was landed and its last height estimate is below LANDED_HEIGHT."""
        if not self._airborne or self.links is None or self._estop.is_set():  # after an emergency stop: no landing
            return False
        self._landing = True
        plan, limits = self.plan, self.plan.safety
        snap = self.board.snapshot()
        duration = landing_duration(self._lab_state(snap)[0][:, 2], plan.commanded, plan.height, limits.landing_speed,
                                    limits.max_altitude + LANDING_CEILING_MARGIN)
        up = [link for link, ours in zip(self.links, plan.commanded) if ours and link.up]
        self.events.log("land", reason=why, duration=duration, drones=[l.name for l in up])
        for link in up:
            link.land(0.0, duration)
        began = self.clock()
        end = began + duration + limits.settle
        ours = np.zeros(plan.n_drones, bool)
        ours[[link.index for link in up]] = True
        try:
            while not self._estop.is_set():
                now, snap = self.clock(), self.board.snapshot()
                last = end if now < end else end + LATE_GRACE
                if now >= last or (now >= end and not self._still_landing(snap, ours, began).any()):
                    break
                self._stop.clear()  # earlier requests are served by this landing; an emergency stop sets it again
                if self._interrupt.is_set() and not self._interrupt_logged:  # not the signal that began this landing
                    self._log_interrupt(during="landing")
                self._record_only(snap)
                self._stop.wait(min(self.plan.dt, max(0.0, last - self.clock())))
        except BaseException:
            # the landing is under way in the drones' own commanders: let it finish before anything
            # closes the links (closing one sends zero thrust), unless the motors are cut meanwhile
            self._estop.wait(max(0.0, end - self.clock()))
            raise
        if self._estop.is_set():
            return False
        for link in up:
            link.stop_motors()
        snap = self.board.snapshot()
        silent = snap.lost | (snap.silence > limits.link_timeout)
        for i in np.flatnonzero(silent):  # links that dropped during the landing
            self._log_link_lost(int(i), snap.lost_reason[i] or f"nothing heard for {snap.silence[i]:.2f} s", during="landing")
        z = self._lab_state(snap)[0][:, 2]
        # a missing estimate (NaN) does not count as down, nor one from before the landing began (estimates
        # that stopped, a link gone silent): it says nothing of where the drone is now
        down = (z < LANDED_HEIGHT) & ~silent & (snap.state_time >= began)
        not_down = [n for n, ok, ours in zip(plan.names, down, plan.commanded) if ours and not ok]
        # heights of every drone by name: `drones` (those landed) may be fewer, a list beside it would pair them wrongly
        self.events.log("landed", heights=dict(zip(plan.names, z)), drones=[l.name for l in up], not_down=not_down,
                        level="warn" if not_down else "info")
        self._airborne = False
        return len(up) == int(plan.commanded.sum()) and bool(down[plan.commanded].all())

    def _log_interrupt(self, **extra) -> None:
        """The `interrupt` event of the stop signal that came, once."""
        self._interrupt_logged = True
        self.events.log("interrupt", reason=self._interrupt_reason, level="warn", **extra)

    def _still_landing(self, snap: BoardSnapshot, ours: np.ndarray, began: float) -> np.ndarray:
        """(D,) bool: drones in `ours` (landing on a live link) not yet shown down (no estimate
        since the landing `began` (clock s) below LANDED_HEIGHT) whose estimates have not stopped
        (none for safety.stale_land s) and whose link is not silent: late, worth waiting for before
        their motors are stopped. One whose estimates or link stopped cannot show it came down."""
        limits = self.plan.safety
        silent = snap.lost | (snap.silence > limits.link_timeout)
        z = self._lab_state(snap)[0][:, 2]
        shown_down = (snap.state_time >= began) & (z < LANDED_HEIGHT)
        return ours & ~silent & (snap.state_age <= limits.stale_land) & ~shown_down

    def _log_link_lost(self, i: int, why: str, **extra) -> None:
        """One `link_lost` event per drone and flight."""
        if i not in self._lost_logged:
            self._lost_logged.add(i)
            self.events.log("link_lost", drone=self.plan.names[i], uri=self.plan.uris[i], reason=why, level="error", **extra)

    # ------------------------------------------------------------------ the chase

    def _chase(self, observer: FlightObserver, pilot: EvaderPilot, steps: list[StepRecord], start: float) -> tuple[str, str]:
        plan = self.plan
        names = plan.names
        self._stream = SetpointStream(
            list(self.links), self.clock, plan.dt, plan.safety.stall_hover, plan.height,
            on_stall=lambda age, drones: self.events.log("stall_hover", since_decision=age, drones=[names[i] for i in drones], level="warn"),
            on_resume=lambda age: self.events.log("stall_end", since_decision=age, level="warn"))
        if self._estop.is_set():  # an emergency stop that came as the stream started
            self._stream.close()
        try:
            next_t = self.clock()
            while True:
                snap = self.board.snapshot()
                self._check_abort(snap, start)
                step = self._decide(snap, observer, pilot, start)
                steps.append(step)
                if observer.captured.all():
                    return "captured", f"all {plan.n_evaders} evader(s) captured after {self.clock() - start:.1f} s"
                next_t += plan.dt
                delay = next_t - self.clock()
                if delay < -plan.dt:
                    self.events.log("overrun", late=-delay, level="warn")
                    next_t = self.clock()
                self._stop.wait(max(0.0, delay))
        finally:
            self._stream.close()  # before the landing: nothing may follow its notify_setpoint_stop

    def _lab_state(self, snap: BoardSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """(pos (D, 3) m, vel (D, 3) m/s) in the lab frame from the drones' estimates."""
        f = self.plan.frames
        pos = snap.pos.copy()
        vel = snap.vel.copy()
        pos[:, :2] = f.to_lab(snap.pos[:, :2])
        vel[:, :2] = f.velocity_to_lab(snap.vel[:, :2])
        return pos, vel

    def _check_abort(self, snap: BoardSnapshot, start: float | None) -> None:
        """Raise _Abort for the first reason to end the run (module docstring, step 2)."""
        plan, limits, names = self.plan, self.plan.safety, self.plan.names
        if self._estop.is_set():
            raise _Abort("emergency_stop", "emergency stop")
        if self._interrupt.is_set():
            self._log_interrupt()
            raise _Abort("interrupted", self._interrupt_reason)
        if self._land_request:
            self.events.log("land_requested", reason=self._land_request, level="warn")
            raise _Abort("land_requested", self._land_request)
        silent = snap.lost | (snap.silence > limits.link_timeout)
        if silent.any():
            i = int(np.flatnonzero(silent)[0])
            why = snap.lost_reason[i] or f"nothing heard for {snap.silence[i]:.2f} s"
            self._log_link_lost(i, why)
            raise _Abort("link_lost", f"link to {names[i]} ({plan.uris[i]}) lost: {why}")
        stale = snap.state_age > limits.stale_land
        if stale.any():
            i = int(np.flatnonzero(stale)[0])
            self.events.log("stale_land", drone=names[i], age=snap.state_age[i], level="error")
            raise _Abort("stale", f"no fresh estimate from {names[i]} for {snap.state_age[i]:.2f} s")
        recent = snap.vbat[:, -limits.battery_samples:]
        low = (recent < limits.battery_land).all(axis=1)
        if low.any():
            i = int(np.flatnonzero(low)[0])
            self.events.log("low_battery", drone=names[i], vbat=snap.vbat[i, -1], threshold=limits.battery_land, level="error")
            raise _Abort("low_battery", f"battery of {names[i]} at {snap.vbat[i, -1]:.2f} V, below {limits.battery_land:g} V")
        self._check_fix(snap)
        pos, vel = self._lab_state(snap)
        broken = (snap.state_count > 0) & ~(np.isfinite(pos).all(axis=1) & np.isfinite(vel).all(axis=1))
        if broken.any():  # a NaN passes every comparison below and would reach the commands
            i = int(np.flatnonzero(broken)[0])
            self.events.log("stale_land", drone=names[i], reason="estimate not finite", pos=pos[i], vel=vel[i], level="error")
            raise _Abort("stale", f"the estimate of {names[i]} is not a number (pos {pos[i].tolist()}, vel {vel[i].tolist()})")
        ours = (snap.state_count > 0) & plan.commanded  # targets are flown by someone else
        before, self._last_xy = self._last_xy, np.where(np.isfinite(pos[:, :2]), pos[:, :2], self._last_xy)
        crossed = self.fence.crossed(before, pos[:, :2]) & ours
        breach = (self.fence.breached(pos[:, :2]) & ours) | crossed
        if breach.any() and self._airborne:
            i = int(np.flatnonzero(breach)[0])
            self.events.log("fence_breach", drone=names[i], pos=pos[i], crossed=bool(crossed[i]), level="error")
            where = f"entered or crossed a virtual obstacle since lab {np.round(before[i], 2).tolist()}" if crossed[i] else "is beyond the geofence"
            raise _Abort("fence_breach", f"{names[i]} at lab {np.round(pos[i, :2], 2).tolist()} {where}")
        high = (pos[:, 2] > limits.max_altitude) & ours
        if high.any():
            i = int(np.flatnonzero(high)[0])
            self.events.log("altitude", drone=names[i], z=pos[i, 2], level="error")
            raise _Abort("altitude", f"{names[i]} at {pos[i, 2]:.2f} m, above {limits.max_altitude:g} m")
        if start is not None and self.clock() - start > plan.spec.max_time:
            raise _Abort("timeout", f"no capture within {plan.spec.max_time:g} s")

    def _check_fix(self, snap: BoardSnapshot) -> None:
        """Lighthouse/Loco: raise _Abort when a drone's latest Kalman position variance (m^2, any
        axis) is above safety.fix_variance: its base stations or anchors are out of sight, and
        the estimate it flies by (and the fence and separation judge) drifts. It goes on
        arriving, so the stale check never sees it. Flow-deck position variance grows by design."""
        if self.plan.spec.positioning == "flow":
            return
        limit = self.plan.safety.fix_variance
        worst = np.max(np.where(np.isfinite(snap.var[:, -1, :]), snap.var[:, -1, :], 0.0), axis=-1)  # no sample yet: 0
        lost = worst > limit
        if lost.any():
            i = int(np.flatnonzero(lost)[0])
            name = self.plan.names[i]
            self.events.log("fix_lost", drone=name, variance=worst[i], threshold=limit, level="error")
            raise _Abort("fix_lost", f"{name} lost its position fix: Kalman position variance {worst[i]:.3g} m^2, above "
                                     f"safety.fix_variance {limit:g} m^2")

    def _decide(self, snap: BoardSnapshot, observer: FlightObserver, pilot: EvaderPilot, start: float) -> StepRecord:
        """One decision step: task commands, safety filters, radio (module docstring, steps 3-6)."""
        plan, N = self.plan, self.plan.n_pursuers
        pos_lab, vel_lab = self._lab_state(snap)
        pos = plan.transform.to_layout(pos_lab[:, :2])
        vel = plan.transform.velocity_to_layout(vel_lab[:, :2])
        newly = observer.update_captures(pos[:N], pos[N:])
        for m in np.flatnonzero(newly):
            d = np.linalg.norm(pos[:N] - pos[N + m], axis=-1)
            self.events.log("capture", evader=plan.names[N + m], by=plan.names[int(np.argmin(d))], distance=float(d.min()))
        asked = self.clock()
        obs, actions, wanted = self._task_commands(pos, vel, observer, pilot, start)
        now = snap
        if self.clock() - asked > plan.safety.stall_hover:  # a slow decision: judged where the drones are now
            now = self.board.snapshot()
            self._check_abort(now, start)
        now_lab, now_vel = self._lab_state(now) if now is not snap else (pos_lab, vel_lab)
        v, filtered, measured = self._guard(wanted, now_lab, now_vel)

        stale = now.state_age > plan.safety.stale_hover
        caught = np.concatenate([np.zeros(N, bool), observer.captured[0] & (plan.roles[N:] == "evader")])
        hover = plan.commanded & (stale | caught)
        fly = plan.commanded & ~hover
        vz = altitude_speed(now_lab[:, 2], plan.height, plan.safety.altitude_gain, plan.safety.max_vertical_speed)
        sent = np.full((plan.n_drones, 3), np.nan)
        sent[fly] = np.column_stack([plan.frames.velocity_to_drone(v), vz])[fly]
        unsendable = fly & ~np.isfinite(sent).all(axis=1)  # never a NaN setpoint: hold height instead
        hover, fly = hover | unsendable, fly & ~unsendable
        sent[unsendable] = np.nan
        self._stream.send({int(i): sent[i] for i in np.flatnonzero(fly)}, [int(i) for i in np.flatnonzero(hover)])
        for kind, flags in filtered.items():
            self.edges.update(kind, flags & fly, pos=now_lab[:, :2], **measured[kind])
        self.edges.update("stale_hover", stale & plan.commanded, age=now.state_age)

        changed = np.any([flags for flags in filtered.values()], axis=0) & fly
        mode = np.where(fly, "velocity", np.where(hover, "hover", "none"))
        t = self.events.now()
        step = StepRecord(t, snap.pos.copy(), snap.vel.copy(), pos, vel, obs[0].copy(), actions, wanted, sent, mode, changed, observer.captured[0].copy())
        self.events.log("step", pos=pos, vel=vel, actions=actions, wanted=wanted, sent=np.where(np.isfinite(sent), sent, 0.0), mode=mode,
                        filtered=changed, captured=step.captured)
        self._record(t, np.column_stack([pos, pos_lab[:, 2]]), np.column_stack([vel, vel_lab[:, 2]]),
                     plan.transform.velocity_to_layout(v), snap.vbat[:, -1])
        return step

    def _record(self, *step) -> None:
        """One step to the rerun recorder, if any. A recorder that fails (a full disk) is logged and
        dropped: the flight, and above all its landing, goes on as it would without one."""
        if self.recorder is None:
            return
        try:
            self.recorder.log_step(*step)
        except Exception as exc:  # noqa: BLE001 - whatever the recording hit, the drones come first
            self.recorder = None
            self.events.log("recorder_failed", reason=f"{type(exc).__name__}: {exc}", level="error")

    def _task_commands(self, pos: np.ndarray, vel: np.ndarray, observer: FlightObserver, pilot: EvaderPilot, start: float):
        """The task's commands from layout-frame states pos, vel (D, 2): (obs (1, N, dim),
        actions (N, 2) in [-1, 1], wanted (D, 2) m/s in the lab frame; targets 0)."""
        plan, task, N = self.plan, self.plan.task, self.plan.n_pursuers
        obs = observer.observe(pos[:N], vel[:N], pos[N:], vel[N:])
        flown = plan.flown_evaders & ~observer.captured[0]
        who, escape = f"policy {getattr(self.policy, 'name', type(self.policy).__name__)}", f"escape model {task.evader.model}"

        def decide():
            """The policy's actions and the escape model's commands (None: no evader to fly);
            both may be code of one's own (--policy FILE.py:NAME, task.evader.model FILE.py)."""
            self._answering = who
            acts = self.policy.act(obs, observer.spec)
            if not flown.any():
                return acts, None
            self._answering = escape
            return acts, pilot.command(observer, pos[N:], vel[N:], pos[:N], vel[:N])

        try:
            actions, ev = self._decision(decide, start)
        except NonFiniteAction as exc:  # a policy file's or the shield's own check: named by its index there
            if not 0 <= exc.pursuer < N:
                raise
            raise ValueError(exc.naming(f"pursuer {plan.names[exc.pursuer]} (index {exc.pursuer})")) from None
        except _Abort:  # a stop while the policy thought: no part of it failed
            self._answering = None
            raise
        self._answering = who
        actions = np.clip(_checked_commands(actions, (1, N, 2), who, [f"pursuer {n}" for n in plan.names[:N]], "(worlds, pursuers, vx and vy)")[0], -1.0, 1.0)
        wanted = np.zeros((plan.n_drones, 2))
        wanted[:N] = clip_norm(actions * task.pursuer_speed, task.pursuer_speed)
        if ev is not None:
            self._answering = escape
            ev = _checked_commands(ev, (plan.n_evaders, 2), escape, [f"evader {n}" for n in plan.names[N:]],
                                   "(evaders, vx and vy in m/s)")
            wanted[N:] = np.where(flown[:, None], clip_norm(ev, task.evader_speed), 0.0)
        self._answering = None
        return obs, actions, plan.transform.velocity_to_lab(wanted)

    def _decision(self, decide: Callable[[], tuple], start: float) -> tuple:
        """decide() (the policy, then the escape model), asked in a thread of its own while this one
        goes on with the abort checks at the decision rate: a policy or escape model that hangs (or
        takes seconds) must not keep Ctrl-C, a land request, a lost link or a low battery from
        landing the drones (the setpoint stream holds them in a hover meanwhile). A late answer
        after such a stop is never used."""
        answer: dict = {}

        def ask() -> None:
            try:
                answer["actions"] = decide()
            except BaseException as exc:  # noqa: BLE001 - raised again in the flight's thread
                answer["error"] = exc

        thinking = threading.Thread(target=ask, name="policy", daemon=True)
        self._thinking = thinking
        thinking.start()
        thinking.join(self.plan.dt)
        while thinking.is_alive():
            self._check_abort(self.board.snapshot(), start)
            thinking.join(self.plan.dt)
        if "error" in answer:
            raise answer["error"]
        if self._stop.is_set():  # a stop that came as the answer did: it is served first
            self._check_abort(self.board.snapshot(), start)
        return answer["actions"]

    def _guard(self, wanted: np.ndarray, pos_lab: np.ndarray, vel_lab: np.ndarray):
        """Safety filters on lab commands (D, 2) m/s: (commands, {filter: changed (D,) bool},
        {filter: {detail: (D,)}}: what each filter's event reports beside the drone's position,
        guard_details). Judged where each drone will be when the command acts."""
        limits = self.plan.safety
        ahead = pos_lab[:, :2] + vel_lab[:, :2] * (self.plan.dt + limits.response_time)
        v, clamped = clamp_speed(wanted, limits.max_speed)
        v, separating, fencing, clearance_ahead = keep_apart_and_inside(v, pos_lab[:, :2], self.fence, limits.min_separation,
                                                                        limits.lookahead, self.plan.commanded, ahead_lab=ahead)
        asked = np.maximum(np.linalg.norm(wanted, axis=-1), np.linalg.norm(v, axis=-1))  # a push back out may be the fast one
        v, clamped_again = clamp_speed(v, limits.max_speed)
        filtered = {"speed_clamped": clamped | clamped_again, "separation": separating, "geofence": fencing}
        return v, filtered, guard_details(self.fence, pos_lab[:, :2], asked, clearance_ahead)

    def _record_only(self, snap: BoardSnapshot) -> None:
        """States for the recorder outside the chase (take-off, landing)."""
        if self.recorder is None or not (snap.state_count > 0).all():
            return
        pos_lab, vel_lab = self._lab_state(snap)
        tr = self.plan.transform
        pos = np.column_stack([tr.to_layout(pos_lab[:, :2]), pos_lab[:, 2]])
        vel = np.column_stack([tr.velocity_to_layout(vel_lab[:, :2]), vel_lab[:, 2]])
        self._record(self.events.now(), pos, vel, np.zeros((self.plan.n_drones, 2)), snap.vbat[:, -1])
