"""`pursuit-mj fly`: fly a team of Crazyflies through cflib, or rehearse the flight on virtual ones.

    pursuit-mj fly --flight configs/flight/example.yaml --policy heuristic --virtual
    pursuit-mj fly --flight configs/flight/example.yaml --model runs/full_obs/best.pt
    pursuit-mj fly check --flight configs/flight/example.yaml
    pursuit-mj fly align --flight configs/flight/lighthouse.yaml --virtual --spots "0.5,0.5 3.1,0.5 1.8,4.5"
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import sys
from pathlib import Path

from .common import (add_shield_arg, finite_float, load_model, once_flag, path_arg, refuse_writing_an_input,
                     seed_arg, shield_each_if_asked, task_input_files)

KEYS_HELP = "during a flight: e or space = emergency stop (motors off), l = land everyone, Ctrl-C or Ctrl-Z = land everyone (twice: motors off), Ctrl-\\ = motors off"


def register(sub) -> None:
    p = sub.add_parser(
        "fly",
        help="fly Crazyflies (or virtual ones) with a policy; also: fly check, fly align",
        description="Fly a real team through cflib, or with --virtual rehearse the same flight on virtual "
        "Crazyflies that speak cflib's protocol over udp://. " + KEYS_HELP,
    )
    _flight_args(p)
    once = once_flag("fly flies one policy (eval takes several, a row each)")
    p.add_argument("--policy", action=once, help="hand-made team by name (heuristic, random), or FILE.py:NAME for a policy of your own (docs/env_api.md); rehearse it with --virtual first")
    p.add_argument("--model", action=once, help="trained model file (e.g. runs/full_obs/best.pt)")
    add_shield_arg(p)
    p.add_argument("--virtual", action="store_true", help="fly virtual Crazyflies on udp://127.0.0.1 instead of the radio URIs")
    p.add_argument("--fault", action="append", default=[], metavar="KIND:DRONE@S[=V]",
                   help="virtual only: inject a fault S seconds into the chase: drop_link:p1@3, freeze:p0@2, battery:e0@4=3.1, lose_fix:p0@2 (Lighthouse/Loco) (repeatable)")
    p.add_argument("--rerun", metavar="FILE.rrd", help="record the flight for the rerun viewer")
    p.add_argument("--events", type=path_arg, metavar="FILE.jsonl", help="event log, appended to (default flights/<name>-<time>.events.jsonl)")
    p.add_argument("--max-time", type=finite_float, help="end the chase after this many seconds (overrides the flight file's max_time)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the sensing and escape-model randomness")
    p.add_argument("--yes", action="store_true", help="take off without asking after the preflight checks (real flights)")
    p.add_argument("--verbose", action="store_true", help="also print cflib's own log messages")
    p.set_defaults(func=run, fly_action=None)

    actions = p.add_subparsers(dest="fly_action", metavar="[check | align]")
    c = actions.add_parser("check", help="validate a flight file and show the plan; no radio is touched")
    _flight_args(c, given_before=True)
    c.set_defaults(func=run_check)
    a = actions.add_parser("align", help="measure the lab -> layout transform from drones placed at known layout spots (Lighthouse/Loco)")
    _flight_args(a, given_before=True)
    a.add_argument("--spots", required=True, help="the layout spots of the drones, flight-file order: 'x,y x,y ...' (m)")
    a.add_argument("--lab", help="lab positions 'x,y x,y ...' (m) measured otherwise; skips the radio")
    a.add_argument("--virtual", action="store_true", default=argparse.SUPPRESS, help="measure virtual drones standing at their starts")
    a.add_argument("--window", type=finite_float, default=1.0, help="seconds of estimates averaged per drone")
    a.add_argument("--write", metavar="OUT.yaml", help="write a copy of the flight file with the measured transform (comments are not kept)")
    a.set_defaults(func=run_align)


def _flight_args(p, given_before: bool = False) -> None:
    """--flight and --set; on `check` and `align` (given_before) they default to what was given
    before the action (`fly --flight F check`), which argparse would otherwise drop."""
    flight_default, set_default = (argparse.SUPPRESS, argparse.SUPPRESS) if given_before else (None, [])
    p.add_argument("--flight", required=False, default=flight_default, metavar="FILE.yaml|PRESET",
                   help="the flight file, or a preset of configs/flight/ by name: example, lighthouse (see configs/flight/example.yaml)")
    p.add_argument("--set", dest="overrides", action="append", default=set_default, metavar="KEY=VALUE",
                   help="override a task key of the flight, e.g. --set pursuer_speed=0.25 (repeatable)")


def _quiet_cflib(verbose: bool) -> None:
    """cflib logs link errors with tracebacks; the flight reports them itself, in one line."""
    if verbose:
        logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    else:
        logging.getLogger("cflib").addHandler(logging.NullHandler())


def _need_flight(args) -> str:
    if not args.flight:
        raise ValueError("--flight FILE.yaml is required")
    return args.flight


def _echo(record: dict) -> None:
    if record["kind"] == "plan_warning":
        return  # printed with the plan, before the flight
    details = ", ".join(f"{k}={v}" for k, v in record.items() if k not in ("t", "time", "kind", "level"))
    print(f"[{record['t']:8.3f}] {record['kind']}" + (f": {details}" if details else ""), flush=True)


def _describe(plan) -> str:
    t, s = plan.transform, plan.safety
    lines = [
        f"flight {plan.spec.name} ({plan.spec.source}): {plan.spec.positioning} positioning, layout {plan.layout.name} ({plan.layout.source})",
        f"  height {plan.height:g} m, decision rate {1 / plan.dt:g} Hz, max time {plan.spec.max_time:g} s",
        f"  transform lab -> layout: origin {list(t.origin)} m, yaw {t.yaw:g} rad, scale {t.scale:g}; lab x {list(plan.lab.x)} y {list(plan.lab.y)} m",
        _speeds(plan),
        f"  safety: fence margin {s.geofence_margin:g} m, separation {s.min_separation:g} m, stale {s.stale_hover:g}/{s.stale_land:g} s, "
        f"battery {s.battery_takeoff:g}/{s.battery_land:g} V",
    ]
    for d in plan.drones:
        lines.append(f"  {d.name:>10}  {d.role:<8} {d.uri:<32} start {list(d.start)}")
    lines += [f"  warning: {w}" for w in plan.warnings]
    return "\n".join(lines)


def _speeds(plan) -> str:
    """The plan's speeds line: the task speeds (layout m/s) of the roles the flight flies (evaders
    only where an evader drone is flown; a target is flown by someone else) and the lab's limit."""
    flown = f"pursuers {plan.task.pursuer_speed:g} m/s" + (f", evaders {plan.task.evader_speed:g} m/s" if plan.flown_evaders.any() else "")
    targets = int((plan.roles == "target").sum())
    by_hand = f", {'the target' if targets == 1 else f'{targets} targets'} flown by someone else" if targets else ""
    return f"  speeds: {flown} (layout){by_hand}; safety limit {plan.safety.max_speed:g} m/s (lab)"


def _landed(result, plan) -> str:
    """'yes' or 'no', and what that is based on: the drones' last height estimates."""
    from pursuit_mj.flight.bridge import LANDED_HEIGHT

    if result.landed:
        return f"yes (every commanded drone's last height estimate below {LANDED_HEIGHT:g} m)"
    heights = result.heights if result.heights is not None else [math.nan] * plan.n_drones
    up = [f"{name} {z:.2f} m" if math.isfinite(z) else f"{name} unknown"
          for name, z, ours in zip(plan.names, heights, plan.commanded) if ours and not z < LANDED_HEIGHT]
    return "no" + (f" (last height estimates: {', '.join(up)}; landed means below {LANDED_HEIGHT:g} m)" if up else "")


def _note_idle_settings(plan) -> None:
    """One `note:` line on stderr per task setting of the flight that its combination never reads
    (TaskConfig.idle_settings: the perception keys under full observability), as the task commands print."""
    for line in plan.task.idle_settings():
        print(f"note: {line}", file=sys.stderr)


def run_check(args) -> int:
    from pursuit_mj.flight.plan import load_plan

    plan = load_plan(_need_flight(args), args.overrides)
    _note_idle_settings(plan)
    print(_describe(plan))
    print("ok: the flight file is valid (no radio was touched)")
    return 0


def _refuse_events_over_an_input(events_path, args, plan) -> None:
    """ValueError naming --events when the event log, appended to (so through a link too), would be the --model checkpoint,
    the --policy file or the evaders' model file (the flight and layout files are refused by
    run_flight)."""
    from pursuit_mj.policy_file import is_policy_file, policy_file_path

    inputs = [(f"--model {args.model}", args.model)] if args.model else []
    if args.policy and is_policy_file(args.policy):
        inputs.append((f"--policy {args.policy}", str(policy_file_path(args.policy))))
    inputs += task_input_files(args, plan.task)
    refuse_writing_an_input([(f"--events {events_path}", Path(events_path))], inputs, appends=True)


def run(args) -> int:
    """fly. Refused before it flies (its --events or --rerun path checked before the plan is
    printed), it leaves none of the folders it made for them (io_utils.no_new_empty_folders)."""
    from pursuit_mj.io_utils import no_new_empty_folders

    with no_new_empty_folders():
        return _run(args)


def _refuse_outputs(events_path, args, plan) -> None:
    """ValueError naming --events or --rerun when the flight could not write it, or --events would
    damage a file (refuse_events_path): asked before the plan is printed, so that a refusal comes
    alone (run_flight asks again)."""
    from pursuit_mj.flight.session import refuse_events_path
    from pursuit_mj.io_utils import check_writable

    _refuse_events_over_an_input(events_path, args, plan)
    check_writable(events_path, "--events", appended=True)  # /dev/stdout to a file: appended to
    refuse_events_path(events_path, plan, args.rerun)
    if args.rerun is not None:
        from pursuit_mj.recording import check_rrd_path

        check_rrd_path(args.rerun)


def _run(args) -> int:
    from pursuit_mj.flight.plan import load_plan
    from pursuit_mj.flight.session import choose_policy, default_events_path, parse_fault, run_flight

    _quiet_cflib(args.verbose)
    plan = load_plan(_need_flight(args), args.overrides)
    _note_idle_settings(plan)
    if args.max_time is not None:
        if not 1 <= args.max_time <= 3600:  # as the flight file's max_time
            raise ValueError(f"--max-time {args.max_time}: expected seconds in [1, 3600]")
        plan = dataclasses.replace(plan, spec=dataclasses.replace(plan.spec, max_time=args.max_time))
    events_path = args.events or default_events_path(plan)
    if (args.policy is None) == (args.model is None):
        raise ValueError("give exactly one of --policy NAME (e.g. heuristic) or --model FILE")
    _refuse_outputs(events_path, args, plan)  # before the plan is printed: a refusal comes alone
    chosen = load_model(args.model, plan.obs_spec, plan.task, flight=True) if args.model else choose_policy(plan, args.policy, args.seed)
    [(policy, _)] = shield_each_if_asked(args, [(chosen, args.policy or args.model)], plan.task, "fly flies one policy")
    if args.fault and not args.virtual:
        raise ValueError("--fault rehearses failures on virtual drones only; add --virtual")
    for text in args.fault:
        parse_fault(text, plan)
    print(_describe(plan))
    interactive = sys.stdin.isatty()
    ask = not args.virtual and not args.yes
    if ask and not interactive:
        raise ValueError("a real flight asks for a go after the preflight checks; without a terminal pass --yes")
    watcher = None
    bridges = []

    def wire(bridge) -> None:
        bridges.append(bridge)

        def watch_keys() -> None:
            nonlocal watcher
            if interactive:  # after the go: the watcher takes the terminal's keys from here on
                from pursuit_mj.flight.keys import KeyWatcher

                watcher = KeyWatcher(lambda: bridge.emergency_stop("key pressed"), lambda: bridge.request_land("key pressed"), sys.stdin.fileno())
                watcher.start()

        def confirm() -> bool:
            """The operator's go: 'fly' typed; anything else, or the end of input (Ctrl-D), is a no."""
            try:
                go = input("preflight ok. Type 'fly' to take off: ").strip().lower() == "fly"
            except EOFError:
                print()
                return False
            if go:
                watch_keys()
            return go

        if ask:
            bridge.confirm = confirm
        else:
            watch_keys()

    print(KEYS_HELP)
    try:
        result, _ = run_flight(plan, policy, virtual=args.virtual, faults=args.fault,
                               events_path=events_path, rerun_path=args.rerun, seed=args.seed, echo=_echo, on_bridge=wire)
    except Exception as exc:
        failure = bridges[0].failure if bridges else None
        if failure is None or failure.error is not exc:  # refused or failed before take-off: bad input (2) or a bug
            raise
        print(f"pursuit-mj fly: error: {_failed_in_flight(failure)}; events: {events_path}", file=sys.stderr)
        if not isinstance(exc, ValueError):  # a bug (a torch error, ours), not a refusal: its traceback too, exit 1
            raise
        if failure.interrupted_by in STOP_SIGNALS:  # a stop after take-off (during the landing): exits as the stop, as after a capture
            from . import stop_exit_code

            return stop_exit_code(STOP_SIGNALS[failure.interrupted_by])
        return 1
    finally:
        if watcher is not None:
            watcher.stop()
    stopped_by = _stop_signal(result)
    late = f"; {stopped_by} during the landing" if stopped_by and stopped_by != result.reason else ""
    print(f"outcome: {result.outcome} ({result.reason}){late}; chase {result.chase_time:.1f} s, {result.captures} capture(s), "
          f"{len(result.steps)} decision steps; landed: {_landed(result, plan)}")
    print(f"events: {events_path}" + (f"; rerun: {args.rerun}" if args.rerun else ""))
    if stopped_by:
        from . import stop_exit_code

        return stop_exit_code(STOP_SIGNALS[stopped_by])
    return 0 if result.outcome in ("captured", "timeout") else 1


def _failed_in_flight(failure) -> str:
    """What ended a flight after take-off (bridge.InFlightFailure): the part that failed, whether the
    drones landed (and a stop signal that came meanwhile), the exception by type (a policy file's
    error names its own) and message. A flight, not the input: exit code 1 (or the stop's)."""
    from pursuit_mj.user_file import UserCodeError

    part = f"the {failure.part} failed in flight" if failure.part else "the flight failed after take-off"
    landed = "the drones landed" if failure.landed else "not every drone is shown landed: see the events"
    if failure.interrupted_by is not None:
        landed += f"; a {failure.interrupted_by} came too"
    error = failure.error
    return f"{part} ({landed}): " + (str(error) if isinstance(error, UserCodeError) else f"{type(error).__name__}: {error}")


def _stop_signal(result) -> str | None:
    """The stop signal (a key of STOP_SIGNALS) that came during the flight, else None: one that
    landed it (its motors cut by a second one during that landing), or one that came during a
    landing begun for another reason (a capture, the time limit), which let it land."""
    if result.outcome in ("interrupted", "emergency_stop") and result.reason in STOP_SIGNALS:
        return result.reason
    return result.interrupted_by if result.interrupted_by in STOP_SIGNALS else None


ALIGN_WARN_RMS = 0.05  # m: a fit worse than this is a placement or ordering mistake, not measurement noise

#: the flight's names of the stop signals it lands on (flight.bridge), as signal names
STOP_SIGNALS = {"Ctrl-C": "SIGINT", "SIGTERM": "SIGTERM", "SIGHUP": "SIGHUP", "Ctrl-Z": "SIGTSTP"}


#: a flight file is a page of YAML; a larger file given to --write is no flight file, and is not read whole
MAX_FLIGHT_FILE_BYTES = 1 << 20


def _is_flight_file(head: bytes, whole: bool) -> bool:
    """Whether a file whose first bytes are `head` (all of it when `whole`) is a flight file: a
    YAML mapping with drones."""
    import yaml

    from pursuit_mj.configio import safe_load

    if not whole:
        return False
    try:
        data = safe_load(head.decode("utf-8"))
    except (UnicodeDecodeError, yaml.YAMLError):  # not text, not YAML: no flight file either
        return False
    return isinstance(data, dict) and "drones" in data


def _refuse_replacing_what_is_no_flight_file(path: str) -> None:
    """ValueError naming --write when it names an existing, non-empty file that is no flight file
    (no drones key, or over MAX_FLIGHT_FILE_BYTES): the aligned copy would replace a task file, a
    layout or notes of the user's. An earlier aligned copy (a flight file) is replaced, as
    aligning again is meant to."""
    from pursuit_mj.io_utils import holds_another_kind

    if holds_another_kind(path, _is_flight_file, limit=MAX_FLIGHT_FILE_BYTES):
        raise ValueError(f"--write path {path}: exists and is not a flight file, which the aligned copy would replace; "
                         f"choose another file, or delete it first")


def run_align(args) -> int:
    """fly align. Refused or stopped after it made --write's folder (a fit refused, a Ctrl-C while it
    measures), it leaves none of the folders it made for it (io_utils.no_new_empty_folders)."""
    from pursuit_mj.io_utils import no_new_empty_folders

    with no_new_empty_folders():
        return _run_align(args)


def _run_align(args) -> int:
    from pursuit_mj.flight.align import align, parse_points, spot_turns, transform_yaml, write_with_transform
    from pursuit_mj.flight.spec import drone_names, load_flight

    _quiet_cflib(False)
    if not 0 < args.window <= 60:
        raise ValueError(f"--window {args.window}: expected seconds in (0, 60]")
    spec = load_flight(_need_flight(args))
    if args.overrides:  # judged now, not only with --virtual or --write after the drones are measured
        from pursuit_mj.flight.plan import check_task_overrides

        check_task_overrides(spec, args.overrides)
    spots = parse_points(args.spots, "--spots")
    lab = parse_points(args.lab, "--lab") if args.lab else None
    if lab is not None and args.virtual:
        raise ValueError("--lab and --virtual exclude each other")
    n_drones = len(drone_names(spec))
    for flag, points, what in (("--spots", spots, "spots"), ("--lab", lab, "points")):
        if points is not None and len(points) != n_drones:
            raise ValueError(f"{flag}: {len(points)} {what} for the flight's {n_drones} drones (one per drone, flight-file order)")
    if args.write:  # before any drone is measured, after the input is judged (it makes the folder); 'aligned/' names a folder
        from pursuit_mj.flight.align import check_spots_in_arena
        from pursuit_mj.flight.plan import resolve_layout
        from pursuit_mj.io_utils import check_writable

        layout = resolve_layout(spec)
        check_spots_in_arena(spots, layout, names=drone_names(spec))  # align's first check, before the folder
        # a copy without the comments over the flight file (or its layout) would lose them
        refuse_writing_an_input([(f"--write {args.write}", Path(args.write))],
                                [(f"--flight {args.flight}", spec.source), ("the flight's layout file", layout.source)])
        _refuse_replacing_what_is_no_flight_file(args.write)
        check_writable(args.write, "--write")
    if args.virtual:
        from pursuit_mj.flight.plan import resolve_flight
        from pursuit_mj.flight.virtual.fleet import VirtualFleet

        plan = resolve_flight(spec, args.overrides)
        with VirtualFleet(plan) as fleet:
            uris = [fleet.uris[plan.names.index(n)] for n in drone_names(spec)]
            fit, lab_pts = align(spec, spots, uris=uris, window=args.window)
    else:
        fit, lab_pts = align(spec, spots, lab, window=args.window)
    for name, p, q, r in zip(drone_names(spec), lab_pts, spots, fit.residuals):
        print(f"  {name:>10}: lab [{p[0]:.3f}, {p[1]:.3f}] -> spot [{q[0]:.3f}, {q[1]:.3f}], residual {r * 1000:.1f} mm")
    print(f"rms residual {fit.rms * 1000:.1f} mm (layout frame)")
    if len(spots) == 2:  # four numbers, four unknowns: nothing left over to check the fit with
        print("warning: two spots fit any placement exactly (the residuals are zero whatever the drones' places): "
              f"two drones swapped give a transform turned by 180 deg; check that {' and '.join(drone_names(spec))} "
              "stand on their own spots, or measure with three or more drones")
    elif fit.rms > ALIGN_WARN_RMS:
        print(f"warning: no rotation, scale and shift brings the drones within {ALIGN_WARN_RMS * 1000:.0f} mm of their "
              f"spots: check that --spots follow the flight file's drone order ({', '.join(drone_names(spec))}) and "
              f"that each drone stands on its spot")
    turns = spot_turns(spots, ALIGN_WARN_RMS)
    if turns:  # the residuals cannot tell: a placement turned so fits as well as the right one
        print(f"warning: the spots look the same turned by {' or '.join(str(a) for a in turns)} deg about their centre: "
              f"drones each standing on another's spot so turned fit as well as on their own, and turn the transform by as "
              f"much; check that {', '.join(drone_names(spec))} stand on their own spots, or place them less evenly")
    print(transform_yaml(fit), end="")
    if args.write:
        out = write_with_transform(spec, fit, args.write, args.overrides)
        print(f"wrote {out}")
    return 0
