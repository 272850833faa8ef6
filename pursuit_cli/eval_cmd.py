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

from pursuit_mj.io_utils import CannotWrite, check_writable, check_writable_folder, file_sha256, no_new_empty_folders
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policies import POLICY_NAMES, make_policy
from pursuit_mj.evader_models import evader_model_sha256
from pursuit_mj.policy_file import is_policy_file, policy_file_name, policy_file_sha256
from .common import (SHIELD_HELP, ListFlag, add_shield_arg, add_task_args, check_episodes, check_out_prefix, counted, load_model,
                     pick_versus, refuse_replacing_what_is_no_table, refuse_writing_an_input,
                     sweep_dead_parts, seed_arg, shield_each_if_asked, table_layouts, task_config_from_args, task_named,
                     task_input_files)
from .eval_resume import check_nothing_kept, drop_finished, finished_rows, interrupted_path, keep_finished, write_finished


RERUN_EPISODES = 3  # recorded per policy and layout with --rerun


def register(sub) -> None:
    p = sub.add_parser(
        "eval",
        help="evaluate policies over layouts: outcome rates and episode lengths with 95%% CIs",
        description="Run episodes in parallel worlds and print, per policy and layout, success / collision / "
                    "timeout rates (95 % Wilson intervals) and mean episode steps (95 % t intervals).",
    )
    p.add_argument("--policy", action="append", default=[], metavar="NAME|FILE.py:NAME",
                   help=f"a hand-made team: {', '.join(POLICY_NAMES)}, or a policy of your own: NAME(config, seed) "
                        "from a Python file (docs/env_api.md, 'Policies') (repeatable; default heuristic if no --model)")
    p.add_argument("-m", "--model", action="append", default=[], metavar="FILE",
                   help="a trained checkpoint (loaded with train.policy.load_policy; repeatable)")
    add_shield_arg(p, SHIELD_HELP.replace("on the policy", "on every --model and --policy given"))
    p.add_argument("--layouts", nargs="+", action=ListFlag, metavar="LAYOUT",
                   help="layout indices 0-3 and/or layout files (default: the task's layout; given again, the lists add up)")
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
    p.add_argument("--rerun-episodes", type=int, metavar="N",
                   help=f"episodes recorded per policy and layout with --rerun (default {RERUN_EPISODES})")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted eval: take the rows it finished from PREFIX.interrupted.json (--out "
                        "PREFIX or --json FILE) and run only the rest, with the same command otherwise")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_task_args(p)
    p.set_defaults(func=run)


def _check_output_flags(args) -> None:
    """Refuse an output path that would be ignored (an empty one) or turned into hidden files."""
    for flag in ("out", "csv", "json", "plots", "rerun"):
        value = getattr(args, flag)
        if value is not None and not value.strip():
            raise ValueError(f"--{flag} {value!r}: an empty path; give a file name or leave the flag out")
    if args.out:
        check_out_prefix(args.out)


def _outputs(args, config, layouts) -> tuple[Path | None, Path | None]:
    _check_output_flags(args)
    csv_path = Path(args.csv) if args.csv else (Path(f"{args.out}.csv") if args.out else None)
    json_path = Path(args.json) if args.json else (Path(f"{args.out}.json") if args.out else None)
    _refuse_writing_an_input(args, config, layouts, csv_path, json_path)
    named = (("--csv" if args.csv else f"--out {args.out}", csv_path), ("--json" if args.json else f"--out {args.out}", json_path))
    refuse_replacing_what_is_no_table([(flag, path) for flag, path in named if path is not None])
    for path, given, what in ((csv_path, args.csv, "--csv" if args.csv else f"--out {args.out}"),
                              (json_path, args.json, "--json" if args.json else f"--out {args.out}")):
        if path is not None:
            check_writable(given or path, what)  # as typed: 'tables/' names a folder, Path('tables/') a file
    if args.rerun:
        from pursuit_mj.recording import check_rrd_path

        check_rrd_path(args.rerun, episodes=True)
    files = [(p, flag) for p, flag in ((csv_path, "--csv"), (json_path, "--json"), (args.rerun and Path(args.rerun), "--rerun")) if p]
    for i, (path, flag) in enumerate(files):
        for other, other_flag in files[i + 1:]:
            if path.resolve() == other.resolve():
                raise ValueError(f"{flag} and {other_flag}: both name {path}; one output would overwrite the other")
    if args.plots:
        check_writable_folder(args.plots, f"--plots {args.plots}")
    return csv_path, json_path


def _inputs(args, config, layouts) -> list[tuple[str, str]]:
    """The files this eval reads, as (what names it, path): checkpoints, policy files, layout
    files, task files and the evaders' model file."""
    from pursuit_mj.layout import is_index_text
    from pursuit_mj.policy_file import policy_file_path

    layout_flag = "--layouts" if args.layouts else "layout"
    return ([(f"--model {m}", m) for m in args.model]
            + [(f"--policy {p}", str(policy_file_path(p))) for p in args.policy if is_policy_file(p)]
            + [(f"{layout_flag} {ref}", str(ref)) for ref in layouts if isinstance(ref, str) and not is_index_text(ref)]
            + task_input_files(args, config))


def _refuse_writing_an_input(args, config, layouts, csv_path: Path | None, json_path: Path | None) -> None:
    """ValueError naming an output of this eval that is one of its input files (common.refuse_writing_an_input)."""
    def typed(flag: str, path: Path) -> str:
        given = getattr(args, flag.lstrip("-"))
        return f"{flag} {given}" if given else f"--out {args.out} (it writes {path})"

    outputs = [(typed(flag, path), path) for flag, path in (("--csv", csv_path), ("--json", json_path)) if path]
    if args.rerun:
        outputs.append((f"--rerun {args.rerun}", Path(args.rerun)))
    refuse_writing_an_input(outputs, _inputs(args, config, layouts))


def _policies(args, config, layouts) -> list[tuple[str, object]]:
    """(label, policy) pairs in command-line order: hand-made teams first, then models (shielded with
    --shield); a model that trained on none of the table's `layouts` says so in a note."""
    names = args.policy or ([] if args.model else ["heuristic"])
    made = [(name, make_policy(name, config, args.seed, "--policy")) for name in names]
    out = [(policy.name if is_policy_file(name) else name, policy) for name, policy in made]
    spec = ObsSpec.make(config.n_pursuers, config.n_evaders, config.n_rays)
    out += [(getattr(pol, "name", Path(m).stem), pol) for m, pol in ((m, load_model(m, spec, config, layouts=layouts)) for m in args.model)]
    out = [(label, pol) for pol, label in shield_each_if_asked(args, [(pol, label) for label, pol in out], config)]
    seen: dict[str, int] = {}
    labelled = []
    for label, pol in out:
        seen[label] = seen.get(label, 0) + 1
        labelled.append((label if seen[label] == 1 else f"{label}#{seen[label]}", pol))
    return labelled


def _report_interrupted(recording) -> None:
    if recording.kept != recording.path:  # a whole run says so with the table
        print(recording.summary(), file=sys.stderr, flush=True)


def _run_table(args, config, layouts, policies, recording, rows: list, done: dict | None = None,
               finished=lambda rows: None) -> list:
    """Evaluate every policy on every layout, appending each finished cell's row to `rows`
    (which holds the finished ones if this is interrupted) and calling finished(rows); a cell in
    `done` (by (policy, layout label), see finished_rows) is taken from there instead."""
    from pursuit_mj.evaluation import evaluate, layout_label
    from pursuit_mj.stats import percent_text

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
            finished(rows)
            if not args.quiet:
                r = rows[-1]
                print(f"[eval] {label} layout {r.layout}: {counted(r.episodes, 'episode')} in {time.perf_counter() - t0:.1f} s, "
                      f"success {percent_text(r.success.p)} %", file=sys.stderr, flush=True)  # as the table says it
    return rows


def _meta(args, policies, layouts, code: dict, config) -> dict:
    from pursuit_mj.evaluation import layout_identity, layout_label
    from pursuit_mj.layout import resolve_layout_ref

    return {"episodes": args.episodes, "worlds": args.worlds, "seed": args.seed, "policies": [label for label, _ in policies],
            "models": list(args.model), "model_sha256": [file_sha256(m) for m in args.model], "shield": bool(args.shield),
            "policy_file_sha256": [policy_file_sha256(p) for p in args.policy if is_policy_file(p)],
            # and what in each file made the policy: two factories of one file can give policies of one name
            "policy_file_names": [policy_file_name(p) for p in args.policy if is_policy_file(p)],
            # and under which label: pool refuses a label that names two files (one edited between tables)
            "policy_file_sha256_of": _policy_file_labels(args, policies),
            "model_of": _model_labels(args, policies),
            # the layouts each model's checkpoint trained on (the note on stderr names them when the table plays none)
            "trained_layouts": _trained_layouts(args, policies),
            "layout_sha256": {layout_label(ref): file_sha256(resolve_layout_ref(ref)) for ref in layouts},
            # what seeded each layout's episodes here (a relative path is a built-in or not by where eval ran): for pool
            "layout_identity": {layout_label(ref): layout_identity(ref) for ref in layouts}, "code": code,
            # the evaders' model of one's own (evader.model FILE.py:NAME) by its bytes: edited, it flies other evaders
            "evader_model_sha256": evader_model_sha256(config),
            # how the heading names the task (common.task_named): pool's heading names it as this table's does
            "task_name": task_named(args)}


def _policy_file_labels(args, policies) -> dict[str, str]:
    """{label: sha256 of its file} of the --policy FILE.py:NAME policies (the first of `policies`,
    in the order of --policy)."""
    return {label: policy_file_sha256(name) for name, (label, _) in zip(args.policy, policies) if is_policy_file(name)}


def _model_labels(args, policies) -> dict[str, str]:
    """{label: model file as given} of the --model policies (the last of `policies`, in order)."""
    labels = [label for label, _ in policies][len(policies) - len(args.model):]
    return dict(zip(labels, args.model))


def _trained_layouts(args, policies) -> dict[str, list[str]]:
    """{label: the layouts its checkpoint trained on, as table rows name layouts} of the --model
    policies (train.policy.trained_layouts, read through a --shield around it); a model whose
    checkpoint does not say is left out."""
    from pursuit_mj.evaluation import layout_label

    out = {}
    for label, policy in policies[len(policies) - len(args.model):]:
        while policy is not None and not hasattr(policy, "trained_layouts"):
            policy = getattr(policy, "policy", None)  # a Shielded wraps the loaded model
        if policy is not None and policy.trained_layouts:
            out[label] = [layout_label(ref) for ref in policy.trained_layouts]
    return out


def _models_legend(args, policies) -> str | None:
    """Which file each model's label stands for, when two models share a run name (best.pt and
    last.pt of one run are labelled NAME and NAME#2), else None."""
    labels = _model_labels(args, policies)
    if not any("#" in label for label in labels):
        return None
    return "models: " + "; ".join(f"{label} = {path}" for label, path in labels.items())


def _versus(args, policies) -> str | None:
    """The label the others are paired against (common.pick_versus)."""
    return pick_versus(args.versus, [label for label, _ in policies], "this table", "(--policy NAME, --model FILE)")


def run(args) -> int:
    """The eval command. Refused or failed before it kept anything, it leaves none of the folders it
    made for --out, --csv, --json, --plots or --rerun (what it wrote stays: io_utils.no_new_empty_folders)."""
    with no_new_empty_folders():
        return _run(args)


def _run(args) -> int:
    from pursuit_mj.comparison import paired_report, pairs_to_dicts
    from pursuit_mj.evaluation import format_table, plot_rows, table_heading, write_csv, write_json
    from pursuit_mj.provenance import provenance

    check_episodes(args.episodes)
    if args.worlds < 1:
        raise ValueError(f"--worlds: expected an integer >= 1, got {args.worlds}")
    if args.rerun_episodes is not None and not args.rerun:
        raise ValueError(f"--rerun-episodes {args.rerun_episodes}: records nothing without --rerun FILE.rrd")
    args.rerun_episodes = RERUN_EPISODES if args.rerun_episodes is None else args.rerun_episodes
    if args.rerun_episodes < 1:
        raise ValueError(f"--rerun-episodes: expected an integer >= 1, got {args.rerun_episodes}")
    config = task_config_from_args(args)
    # a bad, repeated or ignored layout refused before any episode runs
    layouts = table_layouts(args, config)
    policies = _policies(args, config, layouts)
    versus = _versus(args, policies)
    if args.resume and args.rerun:
        raise ValueError("--resume with --rerun: the recording would hold only the rows run now; record in an eval of its own")
    csv_path, json_path = _outputs(args, config, layouts)  # makes folders: after every other check, so that bad input leaves none
    folders: dict[Path, tuple[Path, str]] = {}  # each folder once, named as the user gave it
    for path, flag in ((csv_path, "--csv"), (json_path, "--json")):
        if path:
            folders.setdefault(path.parent.resolve(), (path.parent, "--out" if args.out else flag))
    for folder, flag in folders.values():
        sweep_dead_parts(folder, flag)
    if args.plots:
        sweep_dead_parts(Path(args.plots), "--plots")
    if not args.resume:
        check_nothing_kept(csv_path, json_path)
    done = finished_rows(json_path, config, _meta(args, policies, layouts, provenance(), config), csv_path) if args.resume else None
    if done is not None and not args.quiet:
        print(f"[eval] resuming: {counted(len(done), 'finished row')} from {interrupted_path(json_path)}",
              file=sys.stderr, flush=True)
    with contextlib.ExitStack() as stack:
        recording = None
        if args.rerun:
            from pursuit_mj.recording import RerunEpisodeRecording

            recording = RerunEpisodeRecording(args.rerun)
            stack.callback(_report_interrupted, recording)  # runs after the recording is closed
            stack.enter_context(recording)
        rows: list = []
        meta = _meta(args, policies, layouts, provenance(), config)
        try:
            _run_table(args, config, layouts, policies, recording, rows, done,
                       finished=lambda rows: write_finished(rows, csv_path, json_path, config, meta))
        except (KeyboardInterrupt, Exception) as exc:
            # Ctrl-C, SIGTERM, or a stop signal a library call reported as its own error (pursuit_cli.main)
            if isinstance(exc, KeyboardInterrupt) or getattr(args, "stop_signals", None):
                keep_finished(rows, csv_path, json_path, config, meta, task_named(args))
                raise
            # a policy of one's own failed mid-table: say that the finished rows wait for --resume
            if isinstance(exc, ValueError) and rows and json_path and interrupted_path(json_path).is_file():
                kept = f"{len(rows)} finished row{' is' if len(rows) == 1 else 's are'} kept in {interrupted_path(json_path)}"
                raise ValueError(f"{exc}; {kept}: run the same command with --resume once the cause is mended, "
                                 f"to play only the rest") from None
            raise
        recording_error = None
        try:
            stack.close()  # the recording is finished: its failure to save must not cost the table
        except CannotWrite as exc:  # it says where its episodes are kept
            recording_error = exc
    print(table_heading(rows, task_named(args)))
    print(format_table(rows))
    legend = _models_legend(args, policies)
    if legend:
        print(legend)
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
    if recording is not None and recording_error is None:
        print(recording.summary())  # also names what a recording killed before it finished left beside it
    drop_finished(csv_path, json_path)  # the whole table holds them now
    if recording_error is not None:
        raise recording_error
    return 0
