"""An interrupted `pursuit-mj eval`: its finished rows kept on a stop, and taken back by --resume.

A row is one policy on one layout. As each row is finished, the finished rows go to
PREFIX.interrupted.csv / .json beside the files asked for (so a kill -9 keeps them too), and a
whole table removes them; `--resume` reads the JSON back,
checks that it is this eval's (RESUME_KEYS, the task config, the code, the layout files'
contents), and the rows it holds are not played again. Episodes follow from the seed, so the
table is an uninterrupted run's.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def interrupted_path(path: Path) -> Path:
    """Where an interrupted eval keeps its finished rows: table.json -> table.interrupted.json."""
    return path.with_name(f"{path.stem}.interrupted{path.suffix}")


def kept_beside(path: Path | None) -> bool:
    """Whether an eval writing its table to `path` keeps its finished cells beside it
    (interrupted_path): not without a path, nor for a device or named pipe (eval --csv /dev/stdout
    | ...), which holds no earlier table to keep whole and no file for --resume to read, and
    beside which (in /dev) no file may be made."""
    from pursuit_mj.io_utils import is_stream

    return path is not None and not is_stream(path)


def write_finished(rows: list, csv_path: Path | None, json_path: Path | None, config, meta: dict) -> list[Path]:
    """Write the finished policy-layout cells beside the asked-for files (interrupted_path), so
    that an earlier whole table there stays whole; called as each cell ends, so that even a
    kill -9 leaves them for --resume. Returns the paths written (none beside a pipe or device:
    kept_beside)."""
    from pursuit_mj.evaluation import write_csv, write_json

    out = []
    if kept_beside(csv_path):
        out.append(write_csv(rows, interrupted_path(csv_path)))
    if kept_beside(json_path):
        out.append(write_json(rows, interrupted_path(json_path), config, {**meta, "interrupted": True}))
    return out


def check_nothing_kept(csv_path: Path | None, json_path: Path | None) -> None:
    """ValueError if an interrupted eval's finished rows are kept where this one (not resuming)
    would write its own: they are the user's until resumed or deleted (another eval to the same
    prefix, or one running beside it, would overwrite them, and its whole table remove them)."""
    kept = [interrupted_path(p) for p in (json_path, csv_path) if p is not None and interrupted_path(p).is_file()]
    if kept:
        how = "give --resume to go on from them, or delete " if json_path is not None and kept[0] == interrupted_path(json_path) else "delete "
        raise ValueError(f"{kept[0]}: the finished rows of an interrupted eval are kept there; {how}"
                         f"{' and '.join(str(p) for p in kept)} to start over")


def drop_finished(csv_path: Path | None, json_path: Path | None) -> None:
    """Remove the kept cells once the whole table is written (it holds them)."""
    for path in (csv_path, json_path):
        if path is not None:
            interrupted_path(path).unlink(missing_ok=True)


def keep_finished(rows: list, csv_path: Path | None, json_path: Path | None, config, meta: dict, task: str = "") -> None:
    """After an interrupt: show the rows of the finished policy-layout cells, under a line naming
    their fidelity and `task` (common.task_named, when given) as the whole table's heading does,
    and say where they are kept (written again: the last cell may have ended as the stop came);
    with none finished, say that nothing is kept."""
    from pursuit_mj.evaluation import format_table, one_fidelity

    if not rows:
        print("[eval] interrupted before any policy-layout cell finished: nothing is kept for --resume", file=sys.stderr,
              flush=True)
        return
    cells = f"{len(rows)} finished policy-layout cell{'' if len(rows) == 1 else 's'}"
    named = f"{cells}{one_fidelity(rows, ', every row')}{f', {task}' if task else ''}"
    print(f"[eval] interrupted; the {named}:\n{format_table(rows)}", file=sys.stderr, flush=True)
    written = write_finished(rows, csv_path, json_path, config, meta)
    for path in written:
        print(f"[eval] wrote {path}", file=sys.stderr, flush=True)
    if not written and (csv_path or json_path):
        print("[eval] the table goes to a pipe or device: nothing is kept for --resume", file=sys.stderr, flush=True)


#: what an interrupted eval and its resumption must share, so that the finished rows are what this run would play
RESUME_KEYS = ("episodes", "seed", "policies", "model_sha256", "shield", "policy_file_sha256", "policy_file_names",
               "evader_model_sha256")
#: compared per policy (_edited_policies) where the kept file names whose file each hash is
PER_POLICY_KEYS = ("model_sha256", "policy_file_sha256")
RESUME_DEFAULTS = {"policy_file_sha256": [], "policy_file_names": [], "evader_model_sha256": None}  # what an interrupted eval written before the keys had


def finished_rows(json_path: Path | None, config, meta: dict, csv_path: Path | None = None) -> dict[tuple[str, str], object]:
    """--resume: the rows (as evaluation.Row, by (policy, layout)) of the interrupted eval kept in
    interrupted_path(json_path); ValueError naming what differs if it is not this eval's, and how
    to start over (the kept files refuse an eval without --resume there too)."""
    from pursuit_mj.configio import first_difference, to_dict
    from pursuit_mj.evaluation import row_from_record

    if json_path is None:
        raise ValueError("--resume: needs --out PREFIX or --json FILE, where the interrupted eval kept its rows")
    if not kept_beside(json_path):
        raise ValueError(f"--resume: {json_path} is a pipe or device, beside which an eval keeps no finished rows; give the "
                         "--out PREFIX or --json FILE that the interrupted eval wrote to")
    kept = interrupted_path(json_path)
    kept_files = [p for p in (kept, interrupted_path(csv_path) if csv_path else None) if p is not None and p.is_file()]
    again = (f"run it again without --resume after deleting {' and '.join(str(p) for p in kept_files)}, or with "
             f"another --out")
    if not kept.is_file():
        raise ValueError(f"--resume: no interrupted eval at {kept} (an eval stopped after its first policy-layout cell leaves one)")
    try:
        data = json.loads(kept.read_text())
        stored = {k: data.get(k, RESUME_DEFAULTS.get(k)) for k in RESUME_KEYS}
        rows = data["rows"]
    except (ValueError, KeyError, TypeError, AttributeError):
        raise ValueError(f"--resume: {kept} is not an interrupted eval's JSON") from None
    changed = _edited_policies(data, meta)  # None: the kept file cannot say whose file changed
    for key in RESUME_KEYS:
        if key in PER_POLICY_KEYS and changed is not None:
            continue
        if stored[key] != meta[key]:
            raise ValueError(f"--resume: {key} differs from the interrupted eval's ({stored[key]!r} in {kept}, "
                             f"{meta[key]!r} now): give the same command, or {again}")
    diff = first_difference(data.get("config"), json.loads(json.dumps(to_dict(config))))
    if diff:
        key, was, now = diff
        raise ValueError(f"--resume: the task config differs from the interrupted eval's at {key or 'config'} ({was!r} "
                         f"in {kept}, {now!r} now): give the same task flags, or {again}")
    code, was = meta["code"], data.get("code") or {}
    for key in ("source_sha256", "drone_model_sha256"):  # not git_commit: a docs-only commit keeps the rows
        if was.get(key) != code.get(key):
            raise ValueError(f"--resume: the code changed since the interrupted eval ({key} {was.get(key)} there, "
                             f"{code.get(key)} now), so its rows need not be what this code plays: {again}")
    out = {}
    for k, r in enumerate(rows):
        row = row_from_record(r, config, meta["seed"], meta["episodes"])
        if row is None:
            raise ValueError(f"--resume: {kept}, row {k + 1}: its episodes (per_episode) are not those this eval "
                             f"would play (a damaged or edited file): {again}")
        out[(row.policy, row.layout)] = row
    _check_layout_files(out, data.get("layout_sha256"), meta["layout_sha256"], again)
    for label in changed or ():
        print(f"--resume: the {'checkpoint' if label in meta['model_of'] else 'policy file'} of {label} changed since "
              f"the interrupted eval: its rows are played again", file=sys.stderr, flush=True)
    return {key: row for key, row in out.items() if key[0] not in (changed or ())}


def _edited_policies(data: dict, meta: dict) -> list[str] | None:
    """Labels of the --model checkpoints and --policy files whose bytes changed since the kept rows
    (a policy file fixed after it failed mid-table: the other policies' rows stay good); None
    where the kept file does not say which file was whose (kept before the labels were)."""
    was_files, now_files = data.get("policy_file_sha256_of"), meta["policy_file_sha256_of"]
    was_models, was_sha = data.get("model_of"), data.get("model_sha256")
    now_models, now_sha = meta["model_of"], meta["model_sha256"]
    if not (isinstance(was_files, dict) and list(was_files) == list(now_files)
            and was_models == now_models and isinstance(was_sha, list) and len(was_sha) == len(now_sha)):
        return None
    return ([label for label in now_files if was_files[label] != now_files[label]]
            + [label for label, was, now in zip(now_models, was_sha, now_sha) if was != now])


def _check_layout_files(rows: dict, was: object, now: dict[str, str], again: str) -> None:
    """ValueError naming a layout file of this eval whose kept rows were played on other contents
    (a file is named by its path alone: edited since, its rows are another arena's)."""
    was = was if isinstance(was, dict) else {}
    for label in dict.fromkeys(layout for _, layout in rows):
        if label in now and was.get(label) != now[label]:
            raise ValueError(f"--resume: the layout file {label} changed since the interrupted eval (sha256 "
                             f"{was.get(label)} there, {now[label]} now), so its kept rows are another arena's: "
                             f"{again}")
