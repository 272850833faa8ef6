"""`pursuit-mj eval`: the evaluation table (success / collision / timeout, mean steps, 95 % CIs).

    pursuit-mj eval --policy heuristic --layouts 0 1 2 3 --episodes 150
    pursuit-mj eval --policy heuristic --policy random --model runs/a/best.pt --out results/table --plots results/plots
    pursuit-mj eval --task hard --fidelity point --layouts 3 --episodes 20 --rerun hard3.rrd
    pursuit-mj eval --model runs/a/best.pt --policy random --shield --layouts 0 1
    pursuit-mj eval --policy heuristic --model runs/a/best.pt --versus heuristic --layouts 0 1 2 3
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

from pursuit_mj.io_utils import check_writable, check_writable_folder
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policies import POLICY_NAMES, make_policy
from .common import SHIELD_HELP, add_shield_arg, add_task_args, checked_layouts, load_model, seed_arg, shield_if_asked, task_config_from_args


def register(sub) -> None:
    p = sub.add_parser(
        "eval",
        help="evaluate policies over layouts: outcome rates and episode lengths with 95%% CIs",
        description="Run episodes in parallel worlds and print, per policy and layout, success / collision / "
                    "timeout rates (95 % Wilson intervals) and mean episode steps (95 % t intervals).",
    )
    p.add_argument("--policy", action="append", default=[], metavar="NAME",
                   help=f"a hand-made team: {', '.join(POLICY_NAMES)} (repeatable; default heuristic if no --model)")
    p.add_argument("-m", "--model", action="append", default=[], metavar="FILE",
                   help="a trained checkpoint (loaded with train.policy.load_policy; repeatable)")
    add_shield_arg(p, SHIELD_HELP.replace("on the policy", "on every --model and --policy given"))
    p.add_argument("--layouts", nargs="+", metavar="LAYOUT",
                   help="layout indices 0-3 and/or layout files (default: the task's layout)")
    p.add_argument("--episodes", type=int, default=150, help="episodes per policy and layout (default 150)")
    p.add_argument("--worlds", type=int, default=32, help="parallel worlds (default 32)")
    p.add_argument("--seed", type=seed_arg, default=0, help="table seed: same seed, same table, whatever --worlds (default 0)")
    p.add_argument("--versus", metavar="POLICY",
                   help="also compare every other policy with this one episode by episode (paired capture times, "
                        "95 %% CI; default: heuristic when it is in the table with others; 'none': no comparison)")
    p.add_argument("--out", metavar="PREFIX", help="write PREFIX.csv and PREFIX.json")
    p.add_argument("--csv", metavar="FILE", help="write the table as CSV")
    p.add_argument("--json", metavar="FILE", help="write the table and the resolved config as JSON")
    p.add_argument("--plots", metavar="DIR", help="write one bar chart per metric (PNG) into DIR")
    p.add_argument("--rerun", metavar="FILE.rrd", help="record the first episodes of each policy and layout for the rerun viewer")
    p.add_argument("--rerun-episodes", type=int, default=3, metavar="N",
                   help="episodes recorded per policy and layout with --rerun (default 3)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted eval: take the rows it finished from PREFIX.interrupted.json (--out "
                        "PREFIX or --json FILE) and run only the rest, with the same command otherwise")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_task_args(p)
    p.set_defaults(func=run)


def _outputs(args) -> tuple[Path | None, Path | None]:
    csv_path = Path(args.csv) if args.csv else (Path(f"{args.out}.csv") if args.out else None)
    json_path = Path(args.json) if args.json else (Path(f"{args.out}.json") if args.out else None)
    for path, what in ((csv_path, "--csv"), (json_path, "--json")):
        if path is not None:
            check_writable(path, what)
    if args.rerun:
        from pursuit_mj.recording import check_rrd_path

        check_rrd_path(args.rerun)
    files = [(p, flag) for p, flag in ((csv_path, "--csv"), (json_path, "--json"), (args.rerun and Path(args.rerun), "--rerun")) if p]
    for i, (path, flag) in enumerate(files):
        for other, other_flag in files[i + 1:]:
            if path.resolve() == other.resolve():
                raise ValueError(f"{flag} and {other_flag}: both name {path}; one output would overwrite the other")
    if args.plots:
        check_writable_folder(args.plots, f"--plots {args.plots}")
    return csv_path, json_path


def _policies(args, config) -> list[tuple[str, object]]:
    """(label, policy) pairs in command-line order: hand-made teams first, then models (shielded with --shield)."""
    names = args.policy or ([] if args.model else ["heuristic"])
    out = [(name, make_policy(name, config, args.seed)) for name in names]
    spec = ObsSpec.make(config.n_pursuers, config.n_evaders, config.n_rays)
    out += [(getattr(pol, "name", Path(m).stem), pol) for m, pol in ((m, load_model(m, spec, config)) for m in args.model)]
    shielded = [shield_if_asked(args, pol, label, config) for label, pol in out]
    out = [(label, pol) for pol, label in shielded]
    seen: dict[str, int] = {}
    labelled = []
    for label, pol in out:
        seen[label] = seen.get(label, 0) + 1
        labelled.append((label if seen[label] == 1 else f"{label}#{seen[label]}", pol))
    return labelled


def _report_interrupted(recording) -> None:
    if recording.kept != recording.path:  # a whole run says so with the table
        print(recording.summary(), file=sys.stderr, flush=True)


def interrupted_path(path: Path) -> Path:
    """Where an interrupted eval keeps its finished rows: table.json -> table.interrupted.json."""
    return path.with_name(f"{path.stem}.interrupted{path.suffix}")


def _keep_finished(rows: list, csv_path: Path | None, json_path: Path | None, config, meta: dict) -> None:
    """After an interrupt: show the rows of the finished policy-layout cells and write them beside
    the asked-for files (interrupted_path), so that an earlier whole table there stays whole."""
    from pursuit_mj.evaluation import format_table, write_csv, write_json

    if not rows:
        return
    print(f"[eval] interrupted; the {len(rows)} finished policy-layout cells:\n{format_table(rows)}", file=sys.stderr, flush=True)
    if csv_path:
        print(f"[eval] wrote {write_csv(rows, interrupted_path(csv_path))}", file=sys.stderr, flush=True)
    if json_path:
        print(f"[eval] wrote {write_json(rows, interrupted_path(json_path), config, {**meta, 'interrupted': True})}",
              file=sys.stderr, flush=True)


def _run_table(args, config, layouts, policies, recording, rows: list, done: dict | None = None) -> list:
    """Evaluate every policy on every layout, appending each finished cell's row to `rows`
    (which holds the finished ones if this is interrupted); a cell in `done` (by (policy,
    layout label), see finished_rows) is taken from there instead."""
    from pursuit_mj.evaluation import evaluate, layout_label

    for label, policy in policies:
        for ref in layouts:
            if done and (label, layout_label(ref)) in done:
                rows.append(done[(label, layout_label(ref))])
                continue
            watch = None
            if recording is not None:
                from pursuit_mj.recording import EnvRecorder

                tags = {"policy": label, "layout": str(ref)}
                watch = lambda env, tags=tags: EnvRecorder(recording, env, label=tags, max_episodes=args.rerun_episodes)
            t0 = time.perf_counter()
            rows.extend(evaluate(policy, config, [ref], args.episodes, args.seed, args.worlds, label=label, watch=watch))
            if not args.quiet:
                r = rows[-1]
                print(f"[eval] {label} layout {r.layout}: {r.episodes} episodes in {time.perf_counter() - t0:.1f} s, "
                      f"success {100 * r.success.p:.1f} %", file=sys.stderr, flush=True)
    return rows


def _meta(args, policies, code: dict) -> dict:
    return {"episodes": args.episodes, "worlds": args.worlds, "seed": args.seed, "policies": [label for label, _ in policies],
            "models": list(args.model), "model_sha256": [_sha256(m) for m in args.model], "shield": bool(args.shield),
            "code": code}


def _sha256(path: str) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


#: what an interrupted eval and its resumption must share, so that the finished rows are what this run would play
RESUME_KEYS = ("episodes", "seed", "policies", "model_sha256", "shield")


def finished_rows(json_path: Path | None, config, meta: dict) -> dict[tuple[str, str], object]:
    """--resume: the rows (as evaluation.Row, by (policy, layout)) of the interrupted eval kept in
    interrupted_path(json_path); ValueError naming what differs if it is not this eval's."""
    import json
    from types import SimpleNamespace

    from pursuit_mj.configio import to_dict
    from pursuit_mj.evaluation import summarise

    if json_path is None:
        raise ValueError("--resume: needs --out PREFIX or --json FILE, where the interrupted eval kept its rows")
    kept = interrupted_path(json_path)
    if not kept.is_file():
        raise ValueError(f"--resume: no interrupted eval at {kept} (an eval stopped by Ctrl-C or SIGTERM leaves one)")
    try:
        data = json.loads(kept.read_text())
        stored = {k: data.get(k) for k in RESUME_KEYS}
        rows = data["rows"]
    except (ValueError, KeyError, TypeError, AttributeError):
        raise ValueError(f"--resume: {kept} is not an interrupted eval's JSON") from None
    for key in RESUME_KEYS:
        if stored[key] != meta[key]:
            raise ValueError(f"--resume: {key} differs from the interrupted eval's ({stored[key]!r} in {kept}, "
                             f"{meta[key]!r} now): give the same command, or run it again without --resume")
    if data.get("config") != json.loads(json.dumps(to_dict(config))):
        raise ValueError(f"--resume: the task config differs from the interrupted eval's (its config in {kept}): "
                         f"give the same task flags, or run it again without --resume")
    code, was = meta["code"], data.get("code") or {}
    for key in ("git_commit", "drone_model_sha256"):
        if was.get(key) != code.get(key):
            raise ValueError(f"--resume: the code changed since the interrupted eval ({key} {was.get(key)} there, "
                             f"{code.get(key)} now), so its rows need not be what this code plays: run it again without --resume")
    out = {}
    try:
        for r in rows:
            log = r["per_episode"]
            records = [SimpleNamespace(seed=sd, outcome=o, steps=st, captured=c)
                       for sd, o, st, c in zip(log["seed"], log["outcome"], log["steps"], log["captured"])]
            out[(r["policy"], r["layout"])] = summarise(r["policy"], r["layout"], r["fidelity"], r["seed"], records,
                                                        config.max_steps)
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"--resume: {kept} lacks the episodes of its rows (per_episode)") from None
    return out


def _versus(args, policies) -> str | None:
    """The label the others are paired against: --versus, else heuristic when others are there too."""
    labels = [label for label, _ in policies]
    if args.versus is None:
        return "heuristic" if "heuristic" in labels and len(labels) > 1 else None
    if args.versus == "none":
        return None
    if args.versus not in labels:
        raise ValueError(f"--versus {args.versus!r}: not a policy of this table (policies: {', '.join(labels)})")
    return args.versus


def run(args) -> int:
    from pursuit_mj.comparison import paired_report, pairs_to_dicts
    from pursuit_mj.evaluation import format_table, plot_rows, write_csv, write_json
    from pursuit_mj.provenance import provenance

    if args.episodes < 1:
        raise ValueError(f"--episodes: expected an integer >= 1, got {args.episodes}")
    if args.worlds < 1:
        raise ValueError(f"--worlds: expected an integer >= 1, got {args.worlds}")
    if args.rerun_episodes < 1:
        raise ValueError(f"--rerun-episodes: expected an integer >= 1, got {args.rerun_episodes}")
    config = task_config_from_args(args)
    # a bad or repeated layout refused before any episode runs
    layouts = checked_layouts(args.layouts) if args.layouts else [config.layout]
    policies = _policies(args, config)
    versus = _versus(args, policies)
    if args.resume and args.rerun:
        raise ValueError("--resume with --rerun: the recording would hold only the rows run now; record in an eval of its own")
    csv_path, json_path = _outputs(args)  # makes folders: after every other check, so that bad input leaves none
    done = finished_rows(json_path, config, _meta(args, policies, provenance())) if args.resume else None
    if done is not None and not args.quiet:
        print(f"[eval] resuming: {len(done)} finished rows from {interrupted_path(json_path)}", file=sys.stderr, flush=True)
    with contextlib.ExitStack() as stack:
        recording = None
        if args.rerun:
            from pursuit_mj.recording import RerunEpisodeRecording

            recording = RerunEpisodeRecording(args.rerun)
            stack.callback(_report_interrupted, recording)  # runs after the recording is closed
            stack.enter_context(recording)
        rows: list = []
        try:
            _run_table(args, config, layouts, policies, recording, rows, done)
        except (KeyboardInterrupt, Exception) as exc:
            # Ctrl-C, SIGTERM, or a stop signal a library call reported as its own error (pursuit_cli.main)
            if isinstance(exc, KeyboardInterrupt) or getattr(args, "stop_signals", None):
                _keep_finished(rows, csv_path, json_path, config, _meta(args, policies, provenance()))
            raise
    print(format_table(rows))
    meta = _meta(args, policies, provenance())
    if versus is not None:
        text, pairs = paired_report(rows, versus, config.max_steps)
        print(f"\n{text}")
        meta["paired"] = pairs_to_dicts(pairs)
    if csv_path:
        print(f"wrote {write_csv(rows, csv_path)}")
    if json_path:
        print(f"wrote {write_json(rows, json_path, config, meta)}")
    if args.plots:
        for path in plot_rows(rows, args.plots):
            print(f"wrote {path}")
    if args.rerun:
        print(f"wrote {args.rerun} (view with: rerun {args.rerun})")
    if done is not None:  # the whole table holds them now
        for path in (csv_path, json_path):
            if path is not None:
                interrupted_path(path).unlink(missing_ok=True)
    return 0
