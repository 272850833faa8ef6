"""Pooling evaluation tables: the episodes of several `pursuit-mj eval --out` JSON files as one table.

An episode is known by its seed (evaluation.episode_seeds: the table seed and the layout fix
it). So a row can gather the episodes of tables run with different `--seed`s, an episode met
twice (the heuristic team in every table of one seed) counts once, and two policies from
different files are paired on the episodes both played. The files must hold one task (their
configs equal but for the layout and fidelity, which each row names; a key that a table from
before it existed lacks is at its default), a policy label must
name one model (or policy file of one's own) throughout, a layout one arena (its file's sha256, where the tables record it) and
an evader model of one's own one file (its sha256, "evader_model_sha256", likewise).
A layout is known as the eval that played it knew it (its "layout_identity", which seeded its
episodes), so the folder `pool` runs from does not matter.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Sequence

from .comparison import Paired, pair_matches
from .config import TaskConfig, default_config
from .configio import first_difference, to_dict
from .evaluation import OUTCOMES, Row, layout_identity, summarise
from .io_utils import first_line_is_json_object

#: the fidelities a row can name (TaskConfig.fidelity's choices)
FIDELITIES = tuple(next(f for f in dataclasses.fields(TaskConfig) if f.name == "fidelity").metadata["choices"])
POOLED_SEED = -1  # Row.seed of a pooled row: its episodes come from tables of several seeds
PER_ROW_KEYS = ("layout", "fidelity")  # config keys a table's rows may set apart from the task


@dataclasses.dataclass(frozen=True)
class Pooled:
    """rows: one per policy, layout and fidelity, episodes in seed order; max_steps: the task's
    episode limit (decision steps); config: the task (as the first file holds it); notes: what
    a reader should know (tables from several code versions); task_name: how the tables' headings
    named their task (eval's "task_name", pursuit_cli.common.task_named; the first table's where
    they name it differently), '' where none records it."""

    rows: list[Row]
    max_steps: int
    config: dict
    notes: list[str]
    meta: dict = dataclasses.field(default_factory=dict)  # what a pooled JSON records, so that it can be pooled again
    task_name: str = ""


def _read(path: Path) -> dict:
    """The JSON of one `pursuit-mj eval --out/--json` table; ValueError naming the file, and for the
    files met beside such tables (its CSV, a run folder, a training log) what pool reads instead."""
    if path.is_dir():
        raise ValueError(f"{path}: a folder, not an evaluation table (pool reads the PREFIX.json files that "
                         f"`pursuit-mj eval --out PREFIX` writes)")
    if path.suffix.lower() == ".csv" and path.is_file():
        raise ValueError(f"{path}: an evaluation CSV, which lacks the per-episode seeds that pooling needs; "
                         f"{_json_instead(path)}")
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        if exc.msg == "Extra data" and first_line_is_json_object(path):
            raise _training_log(path) from None
        raise ValueError(f"{path}: not a JSON file ({exc})") from None
    except ValueError as exc:  # text that is not UTF-8
        raise ValueError(f"{path}: not a JSON file ({exc})") from None
    if isinstance(data, dict) and "update" in data and "rows" not in data:  # a log of one update
        raise _training_log(path)
    if not (isinstance(data, dict) and isinstance(data.get("rows"), list) and isinstance(data.get("config"), dict)):
        raise ValueError(f"{path}: not an evaluation table written by `pursuit-mj eval --out/--json` (no 'rows' and 'config')")
    return data


def _training_log(path: Path) -> ValueError:
    """The refusal of a training run's metrics.jsonl, saying what reads it."""
    return ValueError(f"{path}: a training log (one JSON object a line), not an evaluation table; "
                      f"plot it with `pursuit-mj plot --log {path}`")


def _json_instead(csv: Path) -> str:
    """What to pool instead of an eval CSV: the JSON beside it where there is one."""
    beside = csv.with_suffix(".json")
    if beside.is_file():
        return f"pool the JSON written beside it ({beside})"
    return (f"pool the JSON table of that eval (eval --out PREFIX writes PREFIX.json beside PREFIX.csv, --json FILE "
            f"one alone; there is no {beside.name} beside this CSV)")


def table_task(config: dict) -> dict:
    """The task of an evaluation table's config: all but the keys its rows may set apart; a task
    key the table lacks (written before the key existed) at today's default, which plays as before."""
    return {k: v for k, v in _with_defaults(config, to_dict(default_config())).items() if k not in PER_ROW_KEYS}


def _with_defaults(config: dict, defaults: dict) -> dict:
    """`config` with the keys of `defaults` it lacks, nested sections (evader) key by key."""
    out = dict(config)
    for key, value in defaults.items():
        if key not in out:
            out[key] = value
        elif isinstance(value, dict) and isinstance(out[key], dict):
            out[key] = _with_defaults(out[key], value)
    return out


def _task_name(data: dict) -> str:
    """How a table's heading named its task (eval's "task_name"); '' for a table that does not say
    (one from before eval recorded it, or written by a script)."""
    name = data.get("task_name")
    return name if isinstance(name, str) else ""


def _models(data: dict) -> dict[str, str]:
    """label -> sha256 of the checkpoint behind it: a pooled table's "model_sha256_of"; eval lists
    the models last among its policies, in order."""
    if isinstance(data.get("model_sha256_of"), dict):
        return {str(k): str(v) for k, v in data["model_sha256_of"].items()}
    labels, shas = data.get("policies") or [], data.get("model_sha256") or []
    return dict(zip(labels[len(labels) - len(shas):], shas)) if shas else {}


def _policy_files(data: dict) -> dict[str, str]:
    """label -> sha256 of the file of a policy of one's own (--policy FILE.py:NAME) behind it: eval's
    and a pooled table's "policy_file_sha256_of" (empty for tables written before it)."""
    value = data.get("policy_file_sha256_of")
    return {str(k): str(v) for k, v in value.items()} if isinstance(value, dict) else {}


def _trained_layouts(path: Path, data: dict) -> dict[str, list[str]]:
    """label -> the layouts its checkpoint trained on, as rows name layouts: eval's and a pooled
    table's "trained_layouts" (empty for tables written before it); ValueError naming the file
    where it is no such map."""
    value = data.get("trained_layouts")
    if value is None:
        return {}
    if not isinstance(value, dict) or not all(isinstance(v, list) and all(isinstance(x, str) for x in v) for v in value.values()):
        raise ValueError(f"{path}: trained_layouts is {value!r}, not a map of model labels to lists of layout names")
    return {str(k): list(v) for k, v in value.items()}


def _kinds(data: dict) -> dict[str, tuple[str, str]]:
    """label -> (kind, how to say it) of each policy of a table's rows: 'checkpoint' or 'policy file'
    (with its sha256), 'hand-made' where the table records policy files (policy_file_sha256_of),
    else 'not a checkpoint' (a table from before that key: a team or a policy file). A table that
    records no models either (written by a script) says nothing: its labels are left out."""
    if "model_sha256" not in data and "model_sha256_of" not in data:
        return {}
    models, files = _models(data), _policy_files(data)
    out = {}
    for record in data["rows"]:
        label = str(record.get("policy")) if isinstance(record, dict) else None
        if label is None or label in out:
            continue
        if label in models:
            out[label] = ("checkpoint", f"a checkpoint (sha256 {models[label][:12]})")
        elif label in files:
            out[label] = ("policy file", f"a policy file (sha256 {files[label][:12]})")
        elif "policy_file_sha256_of" in data:
            out[label] = ("hand-made", "a hand-made team")
        else:
            out[label] = ("not a checkpoint", "not a checkpoint")
    return out


def _one_kind(a: str, b: str) -> bool:
    """Whether two tables' kinds of one label (_kinds) can be one policy: the same kind, or 'not a
    checkpoint' (an older table's) beside a policy file or a hand-made team."""
    return a == b or "checkpoint" not in (a, b) and "not a checkpoint" in (a, b)


def _per_layout(data: dict, key: str) -> dict[str, str]:
    """A {layout label: text} map of a table's meta (empty when it has none, as older tables)."""
    value = data.get(key)
    return {str(k): v for k, v in value.items() if isinstance(v, str)} if isinstance(value, dict) else {}


def _episodes(path: Path, record: dict) -> tuple[str, str, str, list[tuple[int, str, int, int]]]:
    """(policy, layout, fidelity, episodes as (seed, outcome, steps, caught)) of one row record."""
    policy, layout, fidelity = record.get("policy"), record.get("layout"), record.get("fidelity")
    log = record.get("per_episode")
    if not isinstance(log, dict):
        raise ValueError(f"{path}: row {policy} on layout {layout} has no per-episode records; run that evaluation "
                         "again with this version of pursuit-mj")
    try:
        episodes = list(zip(*(log[k] for k in ("seed", "outcome", "steps", "captured")), strict=True))
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{path}: row {policy} on layout {layout}: per_episode needs lists 'seed', 'outcome', "
                         "'steps' and 'captured' of one length") from None
    if not episodes:
        raise ValueError(f"{path}: row {policy} on layout {layout} holds no episodes")
    if fidelity not in FIDELITIES:
        raise ValueError(f"{path}: row {policy} on layout {layout}: fidelity {fidelity!r}, not one of {', '.join(FIDELITIES)}")
    bad = [o for _, o, _, _ in episodes if o not in OUTCOMES]
    if bad:
        raise ValueError(f"{path}: row {policy} on layout {layout}: outcome {bad[0]!r} is not one of {', '.join(OUTCOMES)}")
    counts = [v for seed, _, steps, caught in episodes for v in (seed, steps, caught)]
    bad_count = next((v for v in counts if not isinstance(v, int) or isinstance(v, bool) or v < 0), None)
    if bad_count is not None:
        raise ValueError(f"{path}: row {policy} on layout {layout}: per_episode holds {bad_count!r} where a seed, "
                         "step count or evaders caught (a whole number >= 0) belongs")
    return str(policy), str(layout), str(fidelity), episodes


def pool_tables(paths: Sequence[str | Path]) -> Pooled:
    """The rows of all `paths` pooled by policy, layout and fidelity; ValueError naming the file
    for a file that is no table, a task that differs (an evader model of one's own by its file's
    sha256 too), a label naming two models or two policy files (or a checkpoint in one table and a
    team in another, _kinds, or two lists of layouts its model trained on), an episode (same seed) that ended differently in two files,
    or one that no eval of the task plays (steps outside 1..max_steps, more evaders caught than
    n_evaders, a fidelity that is none of FIDELITIES)."""
    if not paths:
        raise ValueError("pool: name at least one evaluation JSON file")
    first_path, first = None, None
    model_of: dict[str, tuple[str, Path]] = {}
    file_of: dict[str, tuple[str, Path]] = {}  # label -> (its policy file's sha256, the table that said so)
    trained_of: dict[str, tuple[list[str], Path]] = {}  # label -> (the layouts its model trained on, the table that said so)
    kind_of: dict[str, tuple[str, str, Path]] = {}  # label -> (_kinds' kind, how to say it, the table that said so)
    knows_files = True  # every table records its policy files (policy_file_sha256_of)
    episodes: dict[tuple[str, str, str], dict[int, tuple[tuple[str, int, int], Path]]] = {}
    labels: dict[tuple[str, str, str], str] = {}
    commits: dict[str, Path] = {}
    sources: dict[str, Path] = {}  # the source_sha256 of the code that made each table (where recorded)
    unchecked: list[Path] = []  # tables that record no checkpoints: their labels cannot be checked
    arena_of: dict[str, tuple[str, Path]] = {}  # layout identity -> (its file's sha256, the table that said so)
    identity_of: dict[str, tuple[str, Path]] = {}  # layout label -> (its identity, the table that said so)
    code_of_first: dict | None = None
    named_as: dict[str, Path] = {}  # each name the tables give their task -> the first table that gives it
    for path in map(Path, paths):
        data = _read(path)
        if first is None:
            first_path, first = path, data
        else:
            diff = first_difference(table_task(first["config"]), table_task(data["config"]))
            if diff:
                key, a, b = diff
                names = (f"; {_task_name(data)!r} there, {_task_name(first)!r} in {first_path}"
                         if _task_name(data) and _task_name(first) else "")
                raise ValueError(f"{path}: its task differs from {first_path}'s at {key} ({b!r} there, {a!r} in "
                                 f"{first_path}{names}); pool only tables of one task")
            _check_evaders(first_path, first, path, data)
        if _task_name(data):
            named_as.setdefault(_task_name(data), path)
        for label, sha in _models(data).items():
            seen = model_of.setdefault(label, (sha, path))
            if seen[0] != sha:
                raise ValueError(f"policy {label!r} is two different models: checkpoint {seen[0][:12]} in {seen[1]} and "
                                 f"{sha[:12]} in {path}")
        for label, sha in _policy_files(data).items():
            seen = file_of.setdefault(label, (sha, path))
            if seen[0] != sha:
                raise ValueError(f"policy {label!r} is two different policy files: sha256 {seen[0][:12]} in {seen[1]} and "
                                 f"{sha[:12]} in {path} (edited between the tables?); pool only tables of one policy per label")
        for label, layouts in _trained_layouts(path, data).items():
            seen = trained_of.setdefault(label, (layouts, path))
            if seen[0] != layouts:
                raise ValueError(f"policy {label!r} trained on layouts {seen[0]} in {seen[1]} but {layouts} in {path}; "
                                 "pool only tables where a label names one model")
        for label, (kind, said) in _kinds(data).items():
            was, was_said, where = kind_of.setdefault(label, (kind, said, path))
            if not _one_kind(was, kind):
                raise ValueError(f"policy {label!r} is {said} in {path} but {was_said} in {where}; pool only tables "
                                 "where a label names one policy")
        knows_files = knows_files and "policy_file_sha256_of" in data
        if "model_sha256" not in data and "model_sha256_of" not in data:
            unchecked.append(path)
        code = data.get("code") if isinstance(data.get("code"), dict) else {}
        code_of_first = code if code_of_first is None else code_of_first
        for commit in code.get("git_commits") or [code.get("git_commit", "unknown")]:  # a pooled table's: all of them
            commits.setdefault(str(commit), path)
        # one commit can be two codes: a table made from uncommitted edits (git_dirty) has another source hash
        for source in code.get("source_sha256s") or ([code["source_sha256"]] if code.get("source_sha256") else []):
            sources.setdefault(str(source), path)
        identities, arenas = _per_layout(data, "layout_identity"), _per_layout(data, "layout_sha256")
        for record in data["rows"]:
            policy, layout, fidelity, eps = _episodes(path, record if isinstance(record, dict) else {})
            ident = identities.get(layout) or layout_identity(layout)
            named, where = identity_of.setdefault(layout, (ident, path))
            if named != ident:  # one relative path, two files: a built-in from one folder, another file from another
                raise ValueError(f"layout {layout}: names another layout in {path} than in {where} ({ident!r} there, "
                                 f"{named!r} in {where}); pool only tables of one arena per layout")
            if layout in arenas:
                sha, where = arena_of.setdefault(ident, (arenas[layout], path))
                if sha != arenas[layout]:
                    raise ValueError(f"layout {layout}: {path} played another arena under it than {where} (its file's "
                                     f"sha256 {arenas[layout][:12]} there, {sha[:12]} in {where}); pool only tables "
                                     f"of one arena per layout")
            key = (policy, ident, fidelity)
            labels.setdefault(key, layout)
            known = episodes.setdefault(key, {})
            for seed, outcome, steps, caught in eps:
                end = (outcome, int(steps), int(caught))
                if seed in known and known[seed][0] != end:
                    was, where = known[seed]
                    raise ValueError(f"{policy} on layout {layout}: episode seed {seed} ended {was[0]} after {was[1]} "
                                     f"steps in {where} but {end[0]} after {end[1]} in {path}; these tables were not "
                                     "made by the same code and task")
                known.setdefault(seed, (end, path))
    max_steps = first["config"].get("max_steps")
    if not isinstance(max_steps, int) or isinstance(max_steps, bool) or max_steps < 1:
        raise ValueError(f"{first_path}: its config's max_steps is {max_steps!r}, not a whole number >= 1")
    n_evaders = table_task(first["config"]).get("n_evaders")
    if not isinstance(n_evaders, int) or isinstance(n_evaders, bool) or n_evaders < 1:
        raise ValueError(f"{first_path}: its config's n_evaders is {n_evaders!r}, not a whole number >= 1")
    for key, known in episodes.items():
        _check_played(key[0], labels[key], known, max_steps, n_evaders)
    rows = []
    for key, known in episodes.items():
        records = [SimpleNamespace(seed=s, outcome=end[0], steps=end[1], captured=end[2]) for s, (end, _) in sorted(known.items())]
        rows.append(summarise(key[0], labels[key], key[2], POOLED_SEED, records, max_steps))
    notes = []
    if len(commits) > 1:
        notes.append("note: the tables come from several code versions (git commits "
                     + ", ".join(f"{c[:10]} in {p}" for c, p in commits.items()) + ")")
    elif len(sources) > 1:
        notes.append("note: the tables come from different source code under one git commit (local changes; source "
                     "sha256 " + ", ".join(f"{c[:10]} in {p}" for c, p in sources.items()) + ")")
    if unchecked and len(paths) > 1:
        notes.append(f"note: {', '.join(map(str, unchecked))} record{'s' if len(unchecked) == 1 else ''} no checkpoint "
                     "hashes (written by a script, or a study's table.json before 2026-12-07): a label there is taken "
                     "for the same policy as in the other tables, unchecked")
    if len(named_as) > 1:  # one config under two names (a preset, and its values as flags): the heading gives the first
        notes.append("note: the tables name their task differently, its config the same in all: "
                     + ", ".join(f"{name} in {p}" for name, p in named_as.items()))
    layouts = {labels[key]: key[1] for key in episodes}
    meta = {"model_sha256_of": {label: sha for label, (sha, _) in model_of.items()},
            "layout_identity": layouts,
            "layout_sha256": {label: arena_of[ident][0] for label, ident in layouts.items() if ident in arena_of},
            "code": (dict(code_of_first or {}) if len(commits) == 1 and len(sources) <= 1
                     else {"git_commits": list(commits), **({"source_sha256s": list(sources)} if sources else {})})}
    if trained_of:  # eval's note on layouts a model never trained on works from it
        meta["trained_layouts"] = {label: layouts for label, (layouts, _) in trained_of.items()}
    if knows_files:  # else a label of an older table, a policy file perhaps, would read as a hand-made team
        meta["policy_file_sha256_of"] = {label: sha for label, (sha, _) in file_of.items()}
    if "evader_model_sha256" in first:  # so that the pooled table is checked alike when pooled again
        meta["evader_model_sha256"] = first["evader_model_sha256"]
    task_name = next(iter(named_as), "")
    if task_name:  # so that the pooled table, pooled again, is named alike
        meta["task_name"] = task_name
    return Pooled(rows, max_steps, first["config"], notes, meta, task_name)


def _check_played(policy: str, layout: str, known: dict[int, tuple[tuple[str, int, int], Path]], max_steps: int,
                  n_evaders: int) -> None:
    """ValueError naming the file of an episode that no eval of the task plays: steps outside
    1..max_steps, or more evaders caught than the task has (an edited or damaged table)."""
    for seed, ((_, steps, caught), path) in known.items():
        if not 1 <= steps <= max_steps:
            raise ValueError(f"{path}: row {policy} on layout {layout}: episode seed {seed} took steps {steps}, outside "
                             f"1..{max_steps} (the task's max_steps); no eval of this task plays it")
        if caught > n_evaders:
            raise ValueError(f"{path}: row {policy} on layout {layout}: episode seed {seed} has captured {caught}, outside "
                             f"0..{n_evaders} (the task's n_evaders); no eval of this task plays it")


def _check_evaders(first_path: Path, first: dict, path: Path, data: dict) -> None:
    """ValueError unless the tables' evaders (of one evader.model, which the task compares) are one
    file's: their "evader_model_sha256" equal where both record it (a table written before it has none)."""
    if "evader_model_sha256" not in first or "evader_model_sha256" not in data:
        return
    a, b = first["evader_model_sha256"], data["evader_model_sha256"]
    if a != b:
        ref = (first["config"].get("evader") or {}).get("model")
        raise ValueError(f"{path}: its evaders are another model than {first_path}'s (evader.model {ref}, its file's "
                         f"sha256 {str(b)[:12]} there, {str(a)[:12]} in {first_path}: edited between the two, or "
                         f"another folder's file); pool only tables of one task")


def _restricted(row: Row, seeds: set[int], max_steps: int) -> Row:
    records = [SimpleNamespace(seed=s, outcome=o, steps=n, captured=c) for s, o, n, c in row.episode_log if s in seeds]
    return summarise(row.policy, row.layout, row.fidelity, POOLED_SEED, records, max_steps)


def pooled_pairs(rows: Sequence[Row], reference: str, max_steps: int, identity_of: dict[str, str] | None = None) -> list[Paired]:
    """Every other policy against `reference`, per layout and fidelity, on the episodes both
    played, and over all layouts where there are two or more (comparison.pair_matches on
    those); ValueError if `reference` is not among the rows. `identity_of` maps a row's layout
    label to its identity (Pooled.meta["layout_identity"]); a label not in it is looked at here.
    A row that shares no episode with the reference is left out (not_paired names it)."""
    matches, _ = _matched(rows, reference, max_steps, identity_of)
    return pair_matches(matches, max_steps)


def not_paired(rows: Sequence[Row], reference: str, max_steps: int, identity_of: dict[str, str] | None = None) -> list[Row]:
    """The rows of other policies than `reference` that pooled_pairs leaves out: the reference
    played none of their episodes (tables of another --seed, another layout or fidelity)."""
    return _matched(rows, reference, max_steps, identity_of)[1]


def _matched(rows: Sequence[Row], reference: str, max_steps: int,
             identity_of: dict[str, str] | None) -> tuple[list[tuple[Row, Row]], list[Row]]:
    """((row, reference row) restricted to the episodes both played, for every other policy's row
    that shares one; the rows that share none)."""
    identity_of = identity_of or {}

    def ident(row: Row) -> str:
        return identity_of.get(row.layout) or layout_identity(row.layout)

    refs = {(ident(r), r.fidelity): r for r in rows if r.policy == reference}
    if not refs:
        names = ", ".join(dict.fromkeys(r.policy for r in rows))
        raise ValueError(f"--versus {reference!r}: no such policy in the tables (policies: {names})")
    matches, alone = [], []
    for row in rows:
        if row.policy == reference:
            continue
        ref = refs.get((ident(row), row.fidelity))
        common = set() if ref is None else {e[0] for e in row.episode_log} & {e[0] for e in ref.episode_log}
        if common:  # the reference under the row's label: one arena, however each table spelled it
            matches.append((_restricted(row, common, max_steps),
                            dataclasses.replace(_restricted(ref, common, max_steps), layout=row.layout)))
        else:
            alone.append(row)
    return matches, alone


def not_paired_text(rows: Sequence[Row], reference: str, all_rows: Sequence[Row],
                    identity_of: dict[str, str] | None = None) -> str:
    """Lines naming `rows` (not_paired's) left out of the pairing with `reference` ('' when none is),
    by why: the reference played that layout (and fidelity) on other episodes (tables of another
    --seed), or did not play it at all (its rows among `all_rows`, the pooled table's)."""
    identity_of = identity_of or {}

    def where(row: Row) -> tuple[str, str]:
        return identity_of.get(row.layout) or layout_identity(row.layout), row.fidelity

    played = {where(r) for r in all_rows if r.policy == reference}
    several = len({r.fidelity for r in rows}) > 1

    def named(group: list[Row]) -> str:
        return "; ".join(f"{r.policy} on layout {r.layout}" + (f" ({r.fidelity})" if several else "") for r in group)

    other_seeds = [r for r in rows if where(r) in played]
    unplayed = [r for r in rows if where(r) not in played]
    lines = []
    if other_seeds:
        lines.append(f"not paired with {reference}: {named(other_seeds)} (no episode both played: tables of another "
                     f"--seed hold other episodes; pool a table of {reference} on the same --seed to pair them)")
    if unplayed:
        lines.append(f"not paired with {reference}: {named(unplayed)} ({reference} has no row there)")
    return "\n".join(lines)
