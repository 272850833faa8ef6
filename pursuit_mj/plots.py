"""PNG charts of training logs (curves) and evaluation results (bars), for `pursuit-mj plot`.

Training logs are JSONL files, one JSON object per line (train/metrics_log.py writes
`metrics.jsonl`); nested objects are flattened to dotted keys ('train.success',
'validation.success', 'episode_returns.capture'). Evaluation results are the JSON files of
`pursuit-mj eval --json` ({"rows": [...]}) or a bare list of such rows: policy, layout,
<outcome>_pct with _ci_lo/_ci_hi, mean_steps with its CI.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .io_utils import CannotWrite, atomic_path, first_line_is_json_object
from .stats import percent_text

X_KEYS = ("env_steps", "world_steps", "agent_steps", "update")
#: default curves: (file stem, y label, accepted final key components)
CURVES = (
    ("success", "success rate", ("success", "success_rate")),
    ("collision", "collision rate", ("collision", "collision_rate")),
    ("mean_steps", "mean episode length (steps)", ("mean_steps",)),
)
REWARD_PREFIXES = ("episode_returns.", "reward_terms_per_step.", "reward_terms.", "returns.", "reward.")
EVAL_METRICS = (
    ("success", "success rate (%)", "success_pct", "success_ci_lo", "success_ci_hi"),
    ("collision", "collision rate (%)", "collision_pct", "collision_ci_lo", "collision_ci_hi"),
    ("timeout", "timeout rate (%)", "timeout_pct", "timeout_ci_lo", "timeout_ci_hi"),
    ("mean_steps", "mean episode length (steps)", "mean_steps", "mean_steps_ci_lo", "mean_steps_ci_hi"),
    ("steps_success", "mean steps of the successes (steps)", "mean_steps_success", "mean_steps_success_ci_lo",
     "mean_steps_success_ci_hi"),
)

#: the keys of an evaluation row that hold numbers (or null)
NUMBER_KEYS = ("episodes",) + tuple(k for m in EVAL_METRICS for k in m[2:])


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    """Write `fig` as a PNG atomically and close it; CannotWrite naming `path` if it cannot be (a full disk)."""
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=120)
    except OSError as exc:
        raise CannotWrite(f"{path}: cannot write it ({exc.strerror or exc})") from None
    finally:
        _plt().close(fig)
    return path


def flatten(row: Mapping[str, Any], prefix: str = "", sep: str = ".") -> dict[str, float]:
    """Numeric leaves of a nested mapping as {outer<sep>inner: float}; null, NaN, bools and strings dropped."""
    out: dict[str, float] = {}
    for k, v in row.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, f"{key}{sep}", sep))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out[key] = float(v)
    return out


# ---------------------------------------------------------------------- training curves


def _text(path: Path, what: str) -> str:
    """The UTF-8 text of `path`, or ValueError naming it (a binary file given by mistake)."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{what} {path}: not a text file (expected JSON)") from None
    except OSError as exc:
        raise ValueError(f"{what} {path}: cannot be read ({exc.strerror})") from None


def read_training_log(path: str | Path) -> list[dict[str, float]]:
    """Flattened rows of a JSONL log (or of a run folder's metrics.jsonl). A malformed line is a ValueError naming file and line,
    except a cut-off last line (a run killed mid-write), which is skipped. Rows are those of
    the latest session: see `latest_session`."""
    path = Path(path)
    if path.is_dir():  # a run folder
        if not (path / "metrics.jsonl").is_file():
            raise ValueError(f"training log {path}: a folder without metrics.jsonl (give a run folder of pursuit-mj train "
                             "or a metrics file)")
        path = path / "metrics.jsonl"
    if not path.is_file():
        raise ValueError(f"training log {path}: file not found")
    text = _text(path, "training log")
    _refuse_an_evaluation_table(text, path)
    lines = text.splitlines()
    rows = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            if i == len(lines):
                break
            raise ValueError(f"training log {path}, line {i}: not JSON ({exc.msg})") from None
        if not isinstance(obj, Mapping):
            raise ValueError(f"training log {path}, line {i}: expected a JSON object, got {type(obj).__name__}")
        rows.append(flatten(obj))
    if not rows:
        raise ValueError(f"training log {path}: no rows (a metrics.jsonl of pursuit-mj train has one JSON object per line)")
    return latest_session(rows)


def _refuse_an_evaluation_table(text: str, path: Path) -> None:
    """ValueError pointing to --eval when `text` is the JSON of an evaluation table (pursuit-mj eval
    --json) rather than a training log (one JSON object per line)."""
    if not text.lstrip().startswith("{"):
        return
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        return
    if isinstance(data, Mapping) and "rows" in data and "update" not in data:
        raise ValueError(f"training log {path}: an evaluation table (pursuit-mj eval --json), not a training log: "
                         f"plot it with --eval {path}")


def latest_session(rows: Sequence[dict[str, float]]) -> list[dict[str, float]]:
    """`rows` where an 'update' that is not past the previous one replaces the rows from that
    update on: a run killed before its first checkpoint and started again in the same folder
    logs its updates anew after the old ones, and a curve must not run back over itself."""
    out: list[dict[str, float]] = []
    for r in rows:
        while "update" in r and out and out[-1].get("update", -math.inf) >= r["update"]:
            out.pop()
        out.append(r)
    return out


def x_key(runs: Mapping[str, Sequence[Mapping[str, float]]], requested: str | None = None) -> str:
    """The x axis: `requested`, else the first of X_KEYS that every run has."""
    keys = [requested] if requested else list(X_KEYS)
    for k in keys:
        if all(any(k in r for r in rows) for rows in runs.values()):
            return k
    have = sorted(set().union(*(r.keys() for rows in runs.values() for r in rows)))
    if requested:
        raise ValueError(f"--x {requested!r}: not in every log (keys: {', '.join(have)})")
    raise ValueError(f"training logs: none of {', '.join(X_KEYS)} found in every log for the x axis")


def null_keys(path: str | Path) -> set[str]:
    """Flattened keys of a training log (or run folder) that hold null in every row where they
    appear (e.g. train.success_steps before a first success): `read_training_log` drops them."""
    path = Path(path)
    path = path / "metrics.jsonl" if path.is_dir() else path
    seen: set[str] = set()
    numbers: set[str] = set()
    for line in _text(path, "training log").splitlines():
        try:
            obj = json.loads(line)
        except json.JSONDecodeError:
            continue  # read_training_log has judged the lines already
        if isinstance(obj, Mapping):
            seen |= _leaf_keys(obj)
            numbers |= set(flatten(obj))
    return seen - numbers


def _leaf_keys(row: Mapping[str, Any], prefix: str = "") -> set[str]:
    """Every leaf key of a nested mapping, flattened as `flatten` does, whatever its value."""
    out: set[str] = set()
    for k, v in row.items():
        out |= _leaf_keys(v, f"{prefix}{k}.") if isinstance(v, Mapping) else {f"{prefix}{k}"}
    return out


def runs_without(runs: Mapping[str, Sequence[Mapping[str, float]]], key: str, x: str) -> list[str]:
    """Labels of the runs with no row holding both `x` and `key`: they get no line on key's chart."""
    return [label for label, rows in runs.items() if not any(x in r and key in r for r in rows)]


def curve_keys(runs: Mapping[str, Sequence[Mapping[str, float]]], wanted: Sequence[str] | None = None) -> list[str]:
    """Which flattened keys to plot: `wanted` (a key or its last component), else success,
    collision, mean steps and every reward term found."""
    keys = sorted(set().union(*(r.keys() for rows in runs.values() for r in rows)))
    if wanted:
        out = []
        for w in wanted:
            match = [k for k in keys if k == w or k.rsplit(".", 1)[-1] == w]
            if not match:
                raise ValueError(f"--metric {w!r}: no such key in the logs (keys: {', '.join(keys)})")
            out += [m for m in match if m not in out]
        return out
    out = []
    for _, _, finals in CURVES:
        out += [k for k in keys if k.rsplit(".", 1)[-1] in finals]
    out += [k for k in keys if k.startswith(REWARD_PREFIXES) and k not in out]
    if not out:
        raise ValueError(f"training logs: no success/collision/mean_steps/reward keys found (keys: {', '.join(keys)})")
    return out


RATE_KEYS = ("success", "collision", "timeout", "success_rate", "collision_rate")


REWARD_UNITS = {"episode_returns": "return per episode", "reward_terms_per_step": "reward per step"}


def is_rate(key: str) -> bool:
    """Whether a flattened log key is a 0-1 rate ('train.collision'), not a reward term ('episode_returns.collision')."""
    return key.rsplit(".", 1)[-1] in RATE_KEYS and not key.startswith(REWARD_PREFIXES)


def _curve_label(key: str) -> str:
    """'train.success' -> 'train: success rate (fraction)' (labels from CURVES); a reward term ->
    'collision term (return per episode)'; other keys as they are."""
    group, _, last = key.rpartition(".")
    if key.startswith(REWARD_PREFIXES):
        return f"{last} term ({REWARD_UNITS.get(group, group.replace('_', ' '))})"
    label = next((f"{lab} (fraction)" if last in RATE_KEYS else lab for _, lab, finals in CURVES if last in finals),
                 "timeout rate (fraction)" if last == "timeout" else None)
    return key if label is None else (f"{group}: {label}" if group else label)


def curve_file_name(key: str) -> str:
    """The chart file of a flattened log key: 'train.success' -> 'curve_train_success.png'."""
    return f"curve_{key.replace('.', '_').replace('/', '_')}.png"


def plot_training(runs: Mapping[str, Sequence[Mapping[str, float]]], folder: str | Path,
                  metrics: Sequence[str] | None = None, x: str | None = None,
                  fidelities: Mapping[str, str | None] | None = None) -> list[Path]:
    """One PNG per metric with a line per run (label -> flattened rows) against the x key.
    `fidelities` (label -> the fidelity the run trained in, None where not known) names it: under
    the title when every run is known to be of one, else beside each known run's name."""
    plt = _plt()
    folder = Path(folder)
    xk = x_key(runs, x)
    known = {label: f for label, f in (fidelities or {}).items() if f and label in runs}
    one = len(known) == len(runs) and len(set(known.values())) == 1
    about = f"\n{next(iter(known.values()))} fidelity" if one else ""
    paths = []
    for key in curve_keys(runs, metrics):
        fig, ax = plt.subplots(figsize=(6.4, 3.8))
        for label, rows in runs.items():
            pts = np.array([(r[xk], r[key]) for r in rows if xk in r and key in r]).reshape(-1, 2)
            shown = label if one or label not in known else f"{label} ({known[label]})"
            if len(pts):
                ax.plot(pts[:, 0], pts[:, 1], marker="." if len(pts) < 30 else None, label=shown)
        ax.set_xlabel(xk.replace("_", " "))
        ax.set_ylabel(_curve_label(key))
        if is_rate(key):
            ax.set_ylim(-0.03, 1.03)  # markers at 0 and 1 whole
        ax.set_title(f"{key}{about}", fontsize="small")
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
        fig.tight_layout()
        paths.append(_save(fig, folder / curve_file_name(key)))
    return paths


# ---------------------------------------------------------------------- evaluation bars


def bar_label(value: float, percent: bool) -> str:
    """A bar's value as its table shows it: a rate (`value` in %) as the table's text
    (stats.percent_text: 6.25 as 6.2, 0.04 as 0.04 and 99.96 as 99.96, not 0 and 100), without
    a trailing '.0' (62.5, 100); a mean step count whole, halves rounded up, not to even."""
    if percent:
        text = percent_text(value / 100.0)
        return text.removesuffix(".0")
    return str(math.floor(value + 0.5))



def read_eval_rows(path: str | Path) -> list[dict[str, Any]]:
    """Rows of an evaluation JSON ({"rows": [...]} or a list) or CSV (*.csv, of `pursuit-mj eval
    --csv`); ValueError naming what is missing."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"evaluation results {path}: a folder, expected the JSON or CSV file of pursuit-mj eval")
    if not path.is_file():
        raise ValueError(f"evaluation results {path}: file not found")
    if path.suffix.lower() == ".csv":  # the CSV of pursuit-mj eval --csv
        from .evaluation import read_csv

        rows: Any = read_csv(path)
    else:
        try:
            data = json.loads(_text(path, "evaluation results"))
        except json.JSONDecodeError as exc:
            if exc.msg == "Extra data" and first_line_is_json_object(path):
                raise ValueError(f"evaluation results {path}: a training log (one JSON object a line), not an evaluation "
                                 f"table: plot it with --log {path}") from None
            raise ValueError(f"evaluation results {path}: not JSON ({exc.msg}, line {exc.lineno})") from None
        rows = data.get("rows") if isinstance(data, Mapping) else data
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"evaluation results {path}: expected a non-empty list of rows (or {{\"rows\": [...]}})")
    seen: dict[tuple[str, str], int] = {}
    for i, r in enumerate(rows):
        if not isinstance(r, Mapping) or "policy" not in r or "layout" not in r:
            raise ValueError(f"evaluation results {path}: row {i} lacks 'policy' or 'layout'")
        # one policy and layout in two fidelities (a pooled table's rows) are two bars, not one given twice
        pair = (str(r["policy"]), layout_key(r["layout"]), str(r.get("fidelity") or ""))
        if pair in seen:
            where = f" ({pair[2]})" if pair[2] else ""
            raise ValueError(f"evaluation results {path}: rows {seen[pair]} and {i} both hold policy {pair[0]} on layout "
                             f"{pair[1]}{where}")
        seen[pair] = i
        for key in NUMBER_KEYS:
            v = r.get(key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
                raise ValueError(f"evaluation results {path}: row {i} ({r['policy']} on layout {r['layout']}): "
                                 f"{key} is {v!r}, expected a number or null")
        _check_intervals(r, f"evaluation results {path}: row {i} ({r['policy']} on layout {r['layout']})")
    if not any(r.get(m[2]) is not None for r in rows for m in EVAL_METRICS):
        raise ValueError(f"evaluation results {path}: no row has any of {', '.join(m[2] for m in EVAL_METRICS)}")
    return [dict(r) for r in rows]


def _check_intervals(row: Mapping[str, Any], where: str) -> None:
    """ValueError naming a metric of `row` whose value lies outside its interval, or a rate
    outside 0-100 % (matplotlib refused them as "'yerr' must not contain negative values")."""
    for _, _, key, lo_key, hi_key in EVAL_METRICS:
        value, lo, hi = row.get(key), row.get(lo_key), row.get(hi_key)
        if value is None:
            continue
        if key.endswith("_pct") and not 0.0 <= value <= 100.0:
            raise ValueError(f"{where}: {key} is {value!r}, expected a percentage in 0-100")
        if lo is not None and hi is not None and not lo <= value <= hi:
            raise ValueError(f"{where}: {key} {value!r} is outside its interval [{lo_key} {lo!r}, {hi_key} {hi!r}]")


def _layout_names(layouts: Sequence[str]) -> list[str]:
    """Axis labels of layout keys: 'layout 2' for a built-in one, a file's stem, or its path where
    two files share a stem (v1/arena.yaml and v2/arena.yaml are two layouts, not one 'arena')."""
    stems = [Path(s).stem for s in layouts]
    return [f"layout {s}" if s.isdigit() else (stem if stems.count(stem) == 1 else s) for s, stem in zip(layouts, stems)]


def layout_order(key: str) -> tuple:
    """Sort key of a layout_key: built-in layouts by index (0, 1, 2, 3), then layout files by
    name (then by path, for two files of one name)."""
    return (0, int(key), "") if key.isdigit() else (1, Path(key).name, key)


def layout_key(layout: Any) -> str:
    """One name per layout, however a table named it: a built-in index ('0', '00' or its file
    configs/layouts/0_open.yaml) as the index, another file as its normalised path."""
    from .layout import LayoutError, builtin_layout_path, is_index_text

    s = str(layout).strip()
    if is_index_text(s):
        return str(int(s))
    path = Path(os.path.normpath(s))
    index = path.name.split("_", 1)[0]
    if is_index_text(index):
        try:
            if builtin_layout_path(int(index)).resolve() == path.resolve():
                return str(int(index))
        except LayoutError:
            pass
    return str(path)


def _fit_legend(fig, ax, tries: int = 4) -> None:
    """Lay `fig` out (tight_layout), first widening it until the legend to the right of `ax` fits
    inside it beside the axes: labels that are file paths ('heuristic (results/a/eval.json)') ran
    off the right edge, and tight_layout gave up with a warning."""
    renderer = fig.canvas.get_renderer()
    legend = ax.get_legend()
    for _ in range(tries):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fig.tight_layout()
        gave_up = any("Tight layout not applied" in str(w.message) for w in caught)
        box = legend.get_window_extent(renderer)
        over = max(0.0, box.x1 - fig.bbox.width) / fig.dpi  # inches past the right edge
        if not gave_up and over <= 0:
            return
        w, h = fig.get_size_inches()
        fig.set_size_inches(w + max(over, box.width / fig.dpi) + 0.1, h)


def _fit_title(fig, ax) -> None:
    """Widen `fig` until the title of `ax` fits in it (a chart of one layout is narrower than its title)."""
    for _ in range(3):
        box = ax.title.get_window_extent(fig.canvas.get_renderer())
        over = max(0.0, -box.x0, box.x1 - fig.bbox.width) / fig.dpi
        if over <= 0:
            return
        w, h = fig.get_size_inches()
        fig.set_size_inches(w + 2 * over + 0.1, h)
        fig.tight_layout()


def by_fidelity(rows: list[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """`rows`, each policy labelled 'NAME (fidelity)' when two of them hold one policy and layout in
    different fidelities (a pooled table's, pursuit-mj pool), so that each is a bar of its own, as
    pool --plots draws them; else as they are."""
    keys = [(str(r["policy"]), layout_key(r["layout"])) for r in rows]
    fidelities = {(k, str(r.get("fidelity") or "")) for k, r in zip(keys, rows)}
    if len(fidelities) == len(set(keys)):
        return rows
    return [dict(r, policy=f"{r['policy']} ({r.get('fidelity') or 'fidelity unknown'})") for r in rows]


def _episodes_per_bar(episodes: list[int]) -> str:
    """'1 episode per bar', 'N episodes per bar' or 'N-M episodes per bar' for the sorted episode
    counts of a chart's rows; '' for none."""
    if not episodes:
        return ""
    if len(episodes) > 1:
        return f"{episodes[0]}-{episodes[-1]} episodes per bar"
    return "1 episode per bar" if episodes[0] == 1 else f"{episodes[0]} episodes per bar"


def plot_eval(rows: Iterable[Mapping[str, Any]], folder: str | Path, prefix: str = "eval_") -> list[Path]:
    """Bar charts, one PNG (<prefix><metric>.png) per metric the rows hold: layouts on x (in
    layout_order, whatever the order of the rows), a bar per policy with its 95 % CI whiskers
    ("none" where its value is null), each layout's bars centred on it (a policy without a row
    there leaves no gap), one colour per policy in every chart; rows of one
    policy and layout in several fidelities are bars 'NAME (fidelity)' (by_fidelity). A (policy, layout)
    pair given twice is a ValueError: which of the two would the bar show?"""
    plt = _plt()
    rows = by_fidelity(list(rows))
    folder = Path(folder)
    policies = list(dict.fromkeys(str(r["policy"]) for r in rows))
    layouts = sorted({layout_key(r["layout"]) for r in rows}, key=layout_order)
    table: dict[tuple[str, str], Mapping[str, Any]] = {}
    for r in rows:
        pair = (str(r["policy"]), layout_key(r["layout"]))
        if pair in table:
            raise ValueError(f"evaluation results: policy {pair[0]} on layout {pair[1]} is given twice; "
                             f"rename one (e.g. eval --model with another run name) or plot them apart")
        table[pair] = r
    palette = plt.get_cmap("tab10" if len(policies) <= 10 else "tab20")
    colour = {pol: palette(i % palette.N) for i, pol in enumerate(policies)}
    slots = max(sum((pol, lay) in table for pol in policies) for lay in layouts)
    width = 0.8 / slots
    episodes = sorted({int(r["episodes"]) for r in rows if r.get("episodes") is not None})
    per_bar = _episodes_per_bar(episodes)
    about = [per_bar] if per_bar else []
    fidelities = sorted({str(r["fidelity"]) for r in rows if r.get("fidelity")})
    if fidelities:
        about.append(f"{', '.join(fidelities)} fidelity")
    n_text = "" if not about else "\n" + ", ".join(about)  # a second title line: narrow charts clip long titles
    if not any(r.get(m[2]) is not None for r in rows for m in EVAL_METRICS):
        raise ValueError("evaluation results: rows have none of success_pct, collision_pct, timeout_pct, mean_steps")
    paths = []
    values: list[tuple[float, float, float | None]] = []
    for stem, label, key, lo_key, hi_key in EVAL_METRICS:
        # a metric the rows hold is drawn even where every value is null (no success: no steps
        # of the successes), so that a chart left in the folder by an earlier table is replaced
        if not any(key in r for r in rows):
            continue
        fig, ax = plt.subplots(figsize=(2.6 + 1.2 * len(layouts) * max(slots, 2) / 2, 3.8))
        shown: set[str] = set()
        top = 0.0
        for x, lay in enumerate(layouts):
            here = [pol for pol in policies if (pol, lay) in table]
            for i, pol in enumerate(here):
                r = table[(pol, lay)]
                v = r.get(key)
                centre = x + (i - (len(here) - 1) / 2) * width
                if v is None:  # no value (no success to average): marked "none", not left blank
                    ax.bar(centre, 0.0, width, color=colour[pol], label=None if pol in shown else pol)
                    values.append((centre, 0.0, None))
                    shown.add(pol)
                    continue
                lo, hi = r.get(lo_key), r.get(hi_key)
                # a mean of one episode has no interval: no whisker, rather than one of width 0 (a sure value)
                err = None if lo is None and hi is None else [[0.0 if lo is None else float(v) - float(lo)],
                                                              [0.0 if hi is None else float(hi) - float(v)]]
                ax.bar(centre, float(v), width, yerr=err, capsize=3, color=colour[pol], label=None if pol in shown else pol)
                tip = float(v) + (0.0 if err is None else err[1][0])
                values.append((centre, tip, float(v)))  # each bar's value written above its whisker: a 0 % bar shows "0"
                top = max(top, tip)
                shown.add(pol)
        pad = 0.02 * (100.0 if key.endswith("_pct") else max(top, 1.0))
        for centre, tip, v in values:
            ax.text(centre, tip + pad, "none" if v is None else bar_label(v, key.endswith("_pct")), ha="center", va="bottom", fontsize=7)
        values.clear()
        ax.set_xticks(np.arange(len(layouts)), _layout_names(layouts))
        ax.set_ylabel(label)
        about_bars = n_text
        if key == "mean_steps_success" and per_bar:
            about_bars = n_text.replace(per_bar, f"{per_bar}, the successes among them")
        ax.set_title(f"{label.split(' (')[0]} by layout{about_bars}", fontsize="medium")
        if key.endswith("_pct"):
            ax.set_ylim(0, 112)  # room above 100 for the whisker caps and values
            ax.set_yticks(range(0, 101, 20))
        else:
            ax.set_ylim(0, max(top, 1.0) * 1.12)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        _fit_legend(fig, ax)
        _fit_title(fig, ax)
        paths.append(_save(fig, folder / f"{prefix}{stem}.png"))
    return paths
