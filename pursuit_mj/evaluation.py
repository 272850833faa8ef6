"""The evaluation table: outcome rates and episode lengths per policy and layout, with 95 % CIs.

`evaluate(policy, config, layouts, episodes, seed, n_worlds)` runs exactly `episodes`
episodes per layout in parallel worlds of a `PursuitEnv` and returns one `Row` per layout.
Every started episode is counted (no bias toward short episodes). Episode k of a layout has
a seed that follows from (`seed`, layout, k) alone, and an episode depends only on its seed,
so the same seed gives the same table whatever the number of parallel worlds.
Formatting, CSV, JSON and bar-chart helpers are here too, for the CLI, training and studies.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import zlib
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Iterable, Protocol, Sequence

import numpy as np

from .config import TaskConfig, checked_task_config
from .configio import to_dict
from .env import EpisodeRecord, PursuitEnv, check_seed
from .io_utils import atomic_write_text
from .layout import N_BUILTIN, Layout, builtin_layout_path, is_index_text, load_layout
from .policy import Policy, check_policy, checked_actions
from .stats import Mean, Rate, mean_interval, percent_text, rate  # percent_text: the table's rates, and the charts'

OUTCOMES = ("success", "collision", "timeout")


@dataclasses.dataclass(frozen=True)
class Row:
    """One policy on one layout. Rates are fractions with 95 % Wilson intervals; steps are decision steps."""

    policy: str
    layout: str
    fidelity: str
    episodes: int
    success: Rate
    collision: Rate
    timeout: Rate
    steps: Mean  # over all episodes
    steps_success: Mean  # over successful episodes only
    seed: int
    # per episode k (episode order, the same seeds for every policy of a table): its steps if it
    # ended in success, else max_steps; what pursuit_mj.comparison pairs (not in CSV / JSON rows)
    capture_steps: tuple[float, ...] = dataclasses.field(default=(), repr=False, compare=False)
    # per episode k: (seed, outcome, steps, evaders caught), kept in JSON files so that others
    # can pair or pool them
    episode_log: tuple[tuple[int, str, int, int], ...] = dataclasses.field(default=(), repr=False, compare=False)

    def flat(self) -> dict[str, object]:
        """One flat record (percentages for rates), the CSV and JSON row format."""
        out: dict[str, object] = {"policy": self.policy, "layout": self.layout, "fidelity": self.fidelity,
                                  "episodes": self.episodes, "seed": self.seed}
        for name in OUTCOMES:
            r: Rate = getattr(self, name)
            out[f"{name}_count"] = r.count
            out[f"{name}_pct"] = percent_value(r.p)
            out[f"{name}_ci_lo"] = percent_value(r.lo)
            out[f"{name}_ci_hi"] = percent_value(r.hi)
        for name, m in (("mean_steps", self.steps), ("mean_steps_success", self.steps_success)):
            out[name] = None if m.mean is None else round(m.mean, 3)
            out[f"{name}_ci_lo"] = None if m.lo is None else round(m.lo, 3)
            out[f"{name}_ci_hi"] = None if m.hi is None else round(m.hi, 3)
        return out


def percent_value(fraction: float) -> float:
    """A fraction as percent rounded to 3 decimals, or to as many more as keep a value that is
    neither 0 nor 1 from becoming 0.0 or 100.0 (as percent_text prints it: one collision in
    300,000 episodes is 0.0003, not 0.0; the CSV and JSON rows say what the table says)."""
    value = 100.0 * fraction
    decimals = 3
    while 0.0 < fraction < 1.0 and round(value, decimals) in (0.0, 100.0) and decimals < 15:
        decimals += 1
    return round(value, decimals)


#: the column order of CSV files (and the keys of `Row.flat`)
FIELDS = (
    ("policy", "layout", "fidelity", "episodes", "seed")
    + tuple(f"{o}_{k}" for o in OUTCOMES for k in ("count", "pct", "ci_lo", "ci_hi"))
    + tuple(f"{m}{k}" for m in ("mean_steps", "mean_steps_success") for k in ("", "_ci_lo", "_ci_hi"))
)


def layout_label(ref: int | str | Path) -> str:
    """How a layout reference is named in tables: its index, or the file path as given."""
    return str(ref).strip()


def layout_identity(ref: int | str | Path) -> str:
    """What a layout reference names, the same however it is spelled: a built-in index, or a path
    that is the same file as a built-in layout, as its index ('0'); any other path in its normal
    form ('./x.yaml' and 'x.yaml' as 'x.yaml'; relative paths stay relative, so that it does not
    depend on the machine). A path that is not a file now (a row read back) keeps its normal form."""
    label = layout_label(ref)
    if is_index_text(label):
        return str(int(label))
    for index in range(N_BUILTIN):
        try:
            if os.path.samefile(label, builtin_layout_path(index)):
                return str(index)
        except (OSError, ValueError):  # no such file, or an unreadable one: not that built-in
            continue
    return Path(os.path.normpath(label)).as_posix()


def layout_seed(seed: int, label: int | str | Path) -> int:
    """The environment seed for one layout of a table, from the table seed and the layout's
    identity (`layout_identity`), so that `0` and the built-in's file path, or `./x.yaml` and
    `x.yaml`, play the same episodes; an index seeds as it always has (its label's digits)."""
    ident = layout_identity(label)
    return int(np.random.SeedSequence([int(seed), zlib.crc32(ident.encode())]).generate_state(1)[0])


def episode_seeds(seed: int, count: int) -> np.ndarray:
    """Seeds (count,) int64 of episodes 0..count-1 of one table row, from the row's env seed."""
    return np.array([np.random.SeedSequence([int(seed), k]).generate_state(1)[0] for k in range(count)], np.int64)


def capture_steps(records: Sequence[EpisodeRecord], max_steps: float = math.inf) -> tuple[float, ...]:
    """Per record: its steps if it ended in success, else max_steps (a failure gains nothing by
    ending early; with max_steps infinite, its own steps)."""
    return tuple(float(r.steps) if r.outcome == "success" or math.isinf(max_steps) else float(max_steps) for r in records)


def summarise(policy: str, layout: str, fidelity: str, seed: int, records: Sequence[EpisodeRecord],
              max_steps: float = math.inf) -> Row:
    """Rates with Wilson intervals and mean steps with t intervals (cut to [0, max_steps]) over
    finished episodes, given in episode order."""
    n = len(records)
    counts = {k: sum(r.outcome == k for r in records) for k in OUTCOMES}
    steps = [float(r.steps) for r in records]
    steps_ok = [float(r.steps) for r in records if r.outcome == "success"]
    bounds = (0.0, float(max_steps))
    capture = capture_steps(records, max_steps)
    return Row(policy, layout, fidelity, n, rate(counts["success"], n), rate(counts["collision"], n),
               rate(counts["timeout"], n), mean_interval(steps, bounds), mean_interval(steps_ok, bounds), int(seed),
               capture, tuple((int(r.seed), r.outcome, int(r.steps), int(r.captured)) for r in records))


class Watcher(Protocol):
    """Something that reads the environment along the way (a recorder): see recording.EnvRecorder."""

    def started(self, world_ids: Iterable[int]) -> None: ...

    def stepped(self, info: dict) -> None: ...


def run_episodes(
    policy: Policy,
    config: TaskConfig,
    episodes: int,
    seed: int,
    n_worlds: int,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    watch: Callable[[PursuitEnv], Watcher] | None = None,
) -> list[EpisodeRecord]:
    """Run exactly `episodes` episodes of `config` in up to `n_worlds` parallel worlds.

    Episode k (0..episodes-1) runs with seed `episode_seeds(seed, episodes)[k]` in whichever
    world is free: a world that finishes starts the next unstarted episode; worlds with
    nothing left to start stay frozen until all are done. Returns the records in episode
    order (k), so the result does not depend on `n_worlds`; `on_episode` hears of them in
    order of completion. `watch(env)` may return a watcher told of every episode start and
    step (read only).
    """
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes: expected an integer >= 1, got {episodes!r}")
    if isinstance(n_worlds, bool) or not isinstance(n_worlds, (int, np.integer)) or n_worlds < 1:
        raise ValueError(f"worlds: expected an integer >= 1, got {n_worlds!r}")
    W = int(min(n_worlds, episodes))
    env = PursuitEnv(config, n_worlds=W, seed=seed, auto_reset=False)
    return play(env, policy, episode_seeds(seed, int(episodes)), on_episode, watch(env) if watch is not None else None)


def play(env: PursuitEnv, policy: Policy, seeds: np.ndarray, on_episode: Callable[[EpisodeRecord], None] | None = None,
         watcher: Watcher | None = None) -> list[EpisodeRecord]:
    """Episode k with seed seeds[k] (K,), for every k, in the worlds of `env` (auto_reset off);
    the `run_episodes` contract for an env the caller keeps (validation replays the same
    episodes in one env, its models built once)."""
    episodes, W = len(seeds), env.n_worlds
    if env.auto_reset or W > episodes:
        raise ValueError(f"play: needs an env without auto_reset and at most {episodes} worlds, got {W}")
    obs = env.reset(seeds=seeds[:W])
    running = np.arange(W)  # the episode index k each world runs
    policy.reset(W)
    if watcher is not None:
        watcher.started(range(W))
    started = W
    records: list[tuple[int, EpisodeRecord]] = []
    while len(records) < episodes:
        actions = checked_actions(policy.act(obs, env.obs_spec), W, env.n_pursuers, f"policy {getattr(policy, 'name', '?')}")
        obs, _, _, _, info = env.step(actions)
        if watcher is not None:
            watcher.stepped(info)
        finished = [rec.world for rec in info["episodes"]]
        for rec in info["episodes"]:
            records.append((int(running[rec.world]), rec))
            if on_episode is not None:
                on_episode(rec)
        restart = np.array(finished[: max(episodes - started, 0)], dtype=np.int64)
        if len(restart):
            ks = np.arange(started, started + len(restart))
            obs = env.reset_worlds(restart, seeds[ks])
            running[restart] = ks
            policy.reset(W, restart)
            if watcher is not None:
                watcher.started(restart)
            started += len(restart)
    return [rec for _, rec in sorted(records, key=lambda kr: kr[0])]


def evaluate(
    policy: Policy,
    config: TaskConfig,
    layouts: Sequence[int | str | Path] | None = None,
    episodes: int = 150,
    seed: int = 0,
    n_worlds: int = 32,
    label: str | None = None,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    watch: Callable[[PursuitEnv], Watcher] | None = None,
) -> list[Row]:
    """One Row per layout (default: config.layout) for `policy`, `episodes` episodes each.

    Layouts are indices or layout files; all are loaded (and refused if bad) before any
    episode runs. `random_layout` is switched off: each row is one layout.
    """
    check_seed(seed, "evaluate seed")
    check_policy(policy, "evaluate policy")
    config = checked_task_config(config, "evaluate config")
    name = label or getattr(policy, "name", None)
    if not isinstance(name, str) or not name:
        raise ValueError(f"evaluate label: the policy has no name; give label=... (the name its rows carry), got {label!r}")
    if layouts is not None and (isinstance(layouts, (str, bytes, Path, int, Layout)) or not isinstance(layouts, Sequence)):
        raise ValueError(f"layouts: expected a list of layouts (indices or layout files), got {layouts!r}; for one "
                         f"layout, give [{layouts!r}]")
    refs = [config.layout] if layouts is None else list(layouts)
    if not refs:
        raise ValueError("layouts: the list of layouts is empty")
    for ref in refs:
        load_layout(ref)
    rows = []
    for ref in refs:
        layout = layout_label(ref)
        cfg = dataclasses.replace(config, layout=int(layout) if is_index_text(layout) else layout, random_layout=False)
        records = run_episodes(policy, cfg, episodes, layout_seed(seed, layout), n_worlds, on_episode, watch)
        rows.append(summarise(name, layout, cfg.fidelity, seed, records, cfg.max_steps))
    return rows


# ---------------------------------------------------------------------- output


def _pct(r: Rate) -> str:
    return f"{percent_text(r.p):>5} [{percent_text(r.lo):>5}, {percent_text(r.hi):>5}]"


def _steps(m: Mean) -> str:
    if m.mean is None:
        return "-"
    if m.lo is None:
        return f"{m.mean:6.1f} [no interval: 1 episode]"
    return f"{m.mean:6.1f} [{m.lo:6.1f}, {m.hi:6.1f}]"


def format_table(rows: Sequence[Row]) -> str:
    """A plain-text table, one line per row; brackets hold 95 % confidence intervals. A fidelity
    column when the rows are of several fidelities (a pooled table's may be)."""
    several = len({r.fidelity for r in rows}) > 1
    head = ["policy", "layout", *(["fidelity"] if several else []), "episodes", "success % [95% CI]",
            "collision % [95% CI]", "timeout % [95% CI]", "mean steps [95% CI]", "steps if success [95% CI]"]
    body = [[r.policy, r.layout, *([r.fidelity] if several else []), str(r.episodes), _pct(r.success), _pct(r.collision),
             _pct(r.timeout), _steps(r.steps), _steps(r.steps_success)] for r in rows]
    widths = [max(len(x) for x in col) for col in zip(head, *body)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in [head] + body]
    return "\n".join(lines)


def one_fidelity(items, lead: str) -> str:
    """', every row in point fidelity' (lead, then the fidelity) when every row or pair of `items` is of one
    fidelity, which the table then shows in no column (format_table, comparison.format_pairs); '' otherwise."""
    fidelities = {item.fidelity for item in items}
    return f"{lead} in {fidelities.pop()} fidelity" if len(fidelities) == 1 else ""


def table_heading(rows: Sequence[Row], task: str = "") -> str:
    """The line above a table of `rows` (eval's, demo's, a study's): 'evaluated 2 policies on 4
    layouts, every row in point fidelity, task hard', the fidelity named as the paired table's
    heading names it (one_fidelity; rows of several fidelities have a column of it instead), then
    `task`, how the task the rows ran in is named (pursuit_cli.common.task_named), when given."""
    policies = len(dict.fromkeys(r.policy for r in rows))
    layouts = len(dict.fromkeys(r.layout for r in rows))
    return (f"evaluated {policies} {'policy' if policies == 1 else 'policies'} on {layouts} "
            f"layout{'' if layouts == 1 else 's'}{one_fidelity(rows, ', every row')}{f', {task}' if task else ''}")


def rows_to_csv(rows: Sequence[Row]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(FIELDS), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: "" if v is None else v for k, v in r.flat().items()})
    return buf.getvalue()


def write_csv(rows: Sequence[Row], path: str | Path) -> Path:
    """The table as CSV (one row per policy and layout, percentages for rates), written atomically."""
    return atomic_write_text(path, rows_to_csv(rows))


def write_json(rows: Sequence[Row], path: str | Path, config: TaskConfig | None = None, meta: dict | None = None) -> Path:
    """{"rows": [flat rows], "config": resolved task config, **meta}, written atomically.

    Each row also lists its episodes, "per_episode": {"seed": [...], "outcome": [...],
    "steps": [...], "captured": [...]} in episode order (the same seeds for every policy on a
    layout; captured: how many evaders were caught, which tells a timeout with some caught).
    """
    data: dict[str, object] = dict(meta or {})
    if config is not None:
        data["config"] = to_dict(config)
    data["rows"] = [row_record(r) for r in rows]
    return atomic_write_text(path, json.dumps(data, indent=2) + "\n")


def row_record(row: Row) -> dict[str, object]:
    """A row as JSON files hold it: `Row.flat` and, when it has them, its episodes ("per_episode")."""
    flat = row.flat()
    if row.episode_log:
        seeds, outcomes, steps, caught = zip(*row.episode_log)
        flat["per_episode"] = {"seed": list(seeds), "outcome": list(outcomes), "steps": list(steps), "captured": list(caught)}
    return flat


def row_from_record(record: object, config: TaskConfig, seed: int, episodes: int) -> Row | None:
    """The Row of a `row_record` read back, rebuilt from its episodes; None unless they are the
    episodes `evaluate(..., episodes, seed)` plays on its layout under `config`: the count and
    seeds, known outcomes, steps within 1..max_steps and evaders caught within 0..n_evaders (so
    a damaged or edited record is not taken for a finished one)."""
    def whole(v, hi: int) -> bool:  # an integer in 0..hi (JSON true/false are no counts)
        return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= hi

    try:
        log, policy, label = record["per_episode"], record["policy"], record["layout"]
        if not (isinstance(policy, str) and isinstance(label, str)):
            return None
        seeds, outcomes, steps, caught = (list(log[f]) for f in ("seed", "outcome", "steps", "captured"))
        want_seeds = episode_seeds(layout_seed(seed, label), episodes).tolist()
        fidelity, row_seed = record.get("fidelity"), record.get("seed")
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    if (seeds != want_seeds or fidelity != config.fidelity or row_seed != seed
            or not all(isinstance(o, str) and o in OUTCOMES for o in outcomes)
            or not all(whole(n, config.max_steps) and n >= 1 for n in steps)
            or not all(whole(c, config.n_evaders) for c in caught)
            or not len(outcomes) == len(steps) == len(caught) == len(seeds)):
        return None
    records = [SimpleNamespace(seed=sd, outcome=o, steps=n, captured=c) for sd, o, n, c in zip(seeds, outcomes, steps, caught)]
    return summarise(policy, label, config.fidelity, seed, records, config.max_steps)


_TEXT_FIELDS = ("policy", "layout", "fidelity")
_INT_FIELDS = ("episodes", "seed") + tuple(f"{o}_count" for o in OUTCOMES)


def read_csv(path: str | Path) -> list[dict[str, object]]:
    """The flat rows of a CSV written by `write_csv`, typed as `Row.flat` has them (read back
    equals written; an empty cell is None); ValueError naming the file and line of a bad one."""
    path = Path(path)
    rows: list[dict[str, object]] = []
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            head = next(reader, [])
            if "policy" not in head or "layout" not in head:
                raise ValueError(f"evaluation CSV {path}: line 1 is not a header with policy and layout columns "
                                 f"(as pursuit-mj eval --csv writes)")
            for cells in reader:
                if not cells:
                    continue
                if len(cells) != len(head):
                    raise ValueError(f"evaluation CSV {path}, line {reader.line_num}: {len(cells)} values under "
                                     f"{len(head)} columns (a file cut short?)")
                rows.append({k: _cell(k, v, f"evaluation CSV {path}, line {reader.line_num}") for k, v in zip(head, cells)})
    except UnicodeDecodeError:
        raise ValueError(f"evaluation CSV {path}: not a text file") from None
    except csv.Error as exc:
        raise ValueError(f"evaluation CSV {path}: not CSV ({exc})") from None
    except OSError as exc:
        raise ValueError(f"evaluation CSV {path}: cannot be read ({exc.strerror})") from None
    return rows


def _cell(key: str, text: str, where: str) -> object:
    """A CSV cell as `Row.flat` holds it: text columns as they are, numbers typed, '' None."""
    if key in _TEXT_FIELDS or key not in FIELDS:
        return text
    if text == "":
        return None
    try:
        return int(text) if key in _INT_FIELDS else float(text)
    except ValueError:
        raise ValueError(f"{where}: {key} is {text!r}, expected {'an integer' if key in _INT_FIELDS else 'a number'}") from None


def plot_rows(rows: Sequence[Row], folder: str | Path) -> list[Path]:
    """Bar charts, one PNG per metric (success.png ...), as `pursuit-mj plot --eval` draws them
    (pursuit_mj.plots.plot_eval): layouts on x, a bar per policy, 95 % CI whiskers."""
    from .plots import plot_eval

    return plot_eval([r.flat() for r in rows], folder, prefix="")
