"""`pursuit-mj plot`: training curves and evaluation bar charts as PNG.

    pursuit-mj plot --log runs/classic/metrics.jsonl --log runs/mappo -o plots/
    pursuit-mj plot --log classic=runs/classic/metrics.jsonl --metric validation.success -o plots/
    pursuit-mj plot --eval results/table.json -o plots/
    pursuit-mj plot --eval results/table.csv -o plots/
"""

from __future__ import annotations

import sys
from pathlib import Path

from pursuit_mj.io_utils import check_writable_folder, no_new_empty_folders
from .common import path_arg, refuse_a_file_given_twice


def register(sub) -> None:
    p = sub.add_parser(
        "plot",
        help="training curves (JSONL logs) and evaluation bar charts (eval JSON or CSV) as PNG",
        description="Training logs: one chart per metric with a line per run (success, collision, mean steps "
                    "and reward terms by default). Evaluation results: one bar chart per metric, a bar per "
                    "policy and layout with 95 % confidence intervals.",
    )
    p.add_argument("--log", action="append", default=[], metavar="[LABEL=]FILE",
                   help="training log (JSONL, e.g. runs/NAME/metrics.jsonl) or a run folder (runs/NAME); repeatable, one line per run")
    p.add_argument("--eval", action="append", default=[], metavar="FILE",
                   help="evaluation JSON or CSV written by `pursuit-mj eval --json/--csv` (repeatable; rows are combined)")
    p.add_argument("--metric", action="append", default=[], metavar="KEY",
                   help="training metric to plot: a dotted key or its last part, e.g. validation.success or success "
                        "(repeatable; default: success, collision, mean steps and reward terms)")
    p.add_argument("--x", metavar="KEY", help="x axis key of training logs (default: env_steps, world_steps, agent_steps or update)")
    p.add_argument("-o", "--out", type=path_arg, default="plots", metavar="DIR", help="output folder (default plots/)")
    p.set_defaults(func=run)


def _label_and_path(text: str) -> tuple[str, Path]:
    label, sep, path = text.partition("=")
    if sep and label and not Path(text).exists():
        return label, Path(path)
    p = Path(text)
    if p.is_dir():  # a run folder: named as its run
        return p.resolve().name, p
    return (p.parent.name if p.name == "metrics.jsonl" and p.parent.name else p.stem), p


def run(args) -> int:
    from pursuit_mj.plots import curve_keys, plot_eval, plot_training, read_eval_rows, read_training_log, x_key

    if not args.log and not args.eval:
        raise ValueError("nothing to plot: give --log FILE (training) and/or --eval FILE (evaluation)")
    if not args.log and (args.metric or args.x):
        flag = f"--metric {args.metric[0]}" if args.metric else f"--x {args.x}"
        raise ValueError(f"{flag}: chooses what training logs (--log) are drawn by; there are none, and evaluation "
                         "charts always show every rate and mean steps")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    refuse_a_file_given_twice("--log", [(text, _label_and_path(text)[1]) for text in args.log])
    refuse_a_file_given_twice("--eval", [(text, Path(text)) for text in args.eval])
    runs, fidelities = {}, {}
    for text in args.log:
        label, path = _label_and_path(text)
        if label in runs:
            label = f"{label} ({path})"
        runs[label] = read_training_log(path)
        fidelities[label] = run_fidelity(path)
    tables = [(f, read_eval_rows(f)) for f in args.eval]
    _refuse_one_table_as_json_and_csv(tables)
    rows = _combined_rows(tables)
    _check_one_task(args.eval)
    if runs:  # refused before any chart is written
        x_key(runs, args.x)
        _refuse_a_metric_null_everywhere(runs, args.metric or [], args.log)
        _note_runs_without_a_metric(runs, curve_keys(runs, args.metric or None) if args.metric else [], x_key(runs, args.x))
    paths = []
    with no_new_empty_folders():  # stopped or failed before its first chart: no empty --out folder left
        check_writable_folder(out, f"--out {out}")
        if rows:  # first: it refuses a bar given twice before drawing
            paths += plot_eval(rows, out)
        if runs:
            paths += plot_training(runs, out, args.metric or None, args.x, fidelities)
    for p in paths:
        print(f"wrote {p}")
    return 0


def run_fidelity(log: Path) -> str | None:
    """The fidelity the training run of `log` (a run folder, or its metrics.jsonl) trained and
    validated in: task.fidelity of the config.yaml pursuit-mj train writes beside its log; None
    for a log outside a run folder, or a config.yaml that does not say (the chart then names none)."""
    import yaml

    if not (log.is_dir() or log.name == "metrics.jsonl"):
        return None
    try:
        data = yaml.safe_load((log if log.is_dir() else log.parent).joinpath("config.yaml").read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    task = data.get("task") if isinstance(data, dict) else None
    fidelity = task.get("fidelity") if isinstance(task, dict) else None
    return fidelity if fidelity in ("point", "quadrotor") else None


def _refuse_a_metric_null_everywhere(runs, metrics: list[str], logs: list[str]) -> None:
    """ValueError for a --metric that the logs hold only as null (no success yet: train.success_steps),
    which would otherwise be refused as a key the logs do not have."""
    from pursuit_mj.plots import null_keys

    if not metrics:  # the default charts: nothing asked for by name
        return
    numeric = set().union(*(r.keys() for rows in runs.values() for r in rows))
    nulls = set().union(*(null_keys(_label_and_path(text)[1]) for text in logs)) - numeric
    for w in metrics:
        if any(k == w or k.rsplit(".", 1)[-1] == w for k in numeric):
            continue
        match = sorted(k for k in nulls if k == w or k.rsplit(".", 1)[-1] == w)
        if match:
            raise ValueError(f"--metric {w!r}: null in every row of the logs (nothing to draw): {', '.join(match)}")


def _note_runs_without_a_metric(runs, keys: list[str], x: str) -> None:
    """A note on stderr for each asked-for metric and run that has no numbers of it (no line on its chart)."""
    from pursuit_mj.plots import curve_file_name, runs_without

    for key in keys:
        for label in runs_without(runs, key, x):
            print(f"note: --metric {key}: no numbers under it in run {label}, so {curve_file_name(key)} has no line "
                  f"for it", file=sys.stderr)


def _check_one_task(paths: list[str]) -> None:
    """ValueError naming the --eval file whose task differs from the first's (JSON tables carry
    their task; a CSV does not and is taken as it is)."""
    import json

    from pursuit_mj.configio import first_difference
    from pursuit_mj.pooling import table_task

    first = None
    for path in paths:
        if Path(path).suffix.lower() == ".csv":
            continue
        data = json.loads(Path(path).read_text())  # read_eval_rows read it already
        config = data.get("config") if isinstance(data, dict) else None
        if not isinstance(config, dict):
            continue
        if first is None:
            first = (path, table_task(config))
            continue
        diff = first_difference(first[1], table_task(config))
        if diff:
            key, a, b = diff
            raise ValueError(f"--eval {path}: its task differs from {first[0]}'s at {key} ({b!r} there, {a!r} in "
                             f"{first[0]}); one chart compares policies on one task: plot them apart")


def _refuse_one_table_as_json_and_csv(tables: list[tuple[str, list[dict]]]) -> None:
    """ValueError naming a --eval file that is the CSV (or JSON) of a table another --eval gives:
    the same path but for .csv/.json, with the same rows (the JSON's per-episode lists aside).
    Both are what one `eval --out PREFIX` writes; drawn together every bar came twice."""
    def plain(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if k != "per_episode"} for r in rows]

    seen: dict[Path, tuple[str, list[dict]]] = {}
    for f, rows in tables:
        path = Path(f).resolve()
        if path.suffix.lower() not in (".json", ".csv"):
            continue
        prefix = path.with_suffix("")
        if prefix in seen and plain(seen[prefix][1]) == plain(rows):
            raise ValueError(f"--eval {f}: the same table as --eval {seen[prefix][0]} (the CSV and JSON of one eval), "
                             f"given twice")
        seen.setdefault(prefix, (f, rows))


def _combined_rows(files: list[tuple[str, list[dict]]]) -> list[dict]:
    """The rows of several eval files; a policy name that more than one file holds (the
    heuristic team, typically) is labelled 'NAME (file stem)' in each, or 'NAME (file path)'
    where two of those files share a stem (a/eval.json, b/eval.json), so no bar hides another."""
    holders: dict[str, set[Path]] = {}  # by resolved path: one file named twice (x.json, ./x.json) stays one
    for f, rows in files:
        for r in rows:
            holders.setdefault(str(r["policy"]), set()).add(Path(f).resolve())
    out = []
    for f, rows in files:
        for r in rows:
            name = str(r["policy"])
            if len(holders[name]) > 1:
                stems = [h.stem for h in holders[name]]
                r = dict(r, policy=f"{name} ({Path(f).stem if stems.count(Path(f).stem) == 1 else f})")
            out.append(r)
    return out
