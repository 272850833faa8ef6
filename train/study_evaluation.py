"""The study's evaluation, kept cell by cell so that `study --resume` plays only what is missing.

A cell is one policy on one layout (one `evaluation.Row` with its episodes). As each ends it
is written into <out>/study.json under "evaluation", with the seconds it took, beside what
makes it valid: the evaluation task (an evader model of one's own with its file's sha256), seed,
layouts (and their files' sha256), the episodes
asked for, the code (package version, the hash of its source, drone model; not the git commit,
so a docs-only commit keeps the cells and an uncommitted edit does not), the episode count the study
chose, and for each trained arm the sha256 of the best.pt it was played with. A resumed study takes a kept cell back only
when all of those are unchanged and its episodes are the ones it would play
(`evaluation.row_from_record`); everything else is played again. The heuristic team's kept
cells also say how long an evaluation takes, which the study's budget is planned from.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

from pursuit_mj.configio import to_dict
from pursuit_mj.evader_models import evader_model_sha256
from pursuit_mj.evaluation import Row, layout_label, row_from_record, row_record
from pursuit_mj.io_utils import file_sha256
from pursuit_mj.layout import resolve_layout_ref
from pursuit_mj.provenance import provenance

HEURISTIC = "heuristic"  # the key of the heuristic team's cells; trained arms are keyed by their names




def identity(plan) -> dict:
    """What every kept cell of a study depends on besides its policy (a StudyPlan's evaluation)."""
    code = provenance()
    evader = evader_model_sha256(plan.eval_task)
    # an evader file named alike but edited since flies other evaders (nothing added for janosov:
    # the cells kept by earlier studies stay theirs)
    evaders = {} if evader is None else {"evader_model_sha256": evader}
    return json.loads(json.dumps({
        "task": to_dict(plan.eval_task), "seed": plan.seed, "layouts": [layout_label(l) for l in plan.layouts],
        # a layout file is named by its path: edited since, its kept cells are another arena's
        "layouts_sha256": [file_sha256(resolve_layout_ref(l)) for l in plan.layouts],
        "episodes_asked": plan.episodes,
        "code": {k: code[k] for k in ("version", "source_sha256", "drone_model_sha256")}, **evaders,
    }))


class KeptEvaluation:
    """The cells of a study's evaluation, kept in `state["evaluation"]` (written by `save`).

    A fresh study, or a resumed one whose kept evaluation was made with another task, seed,
    layouts, --episodes or code, starts empty (`episodes` None until `start` sets it).
    """

    def __init__(self, plan, state: dict, save: Callable[[], None], log: Callable[[str], None] = print):
        self._plan, self._save = plan, save
        wanted = identity(plan)
        stored = state.get("evaluation")
        if plan.resume and isinstance(stored, dict) and stored.get("identity") == wanted and _well_formed(stored):
            self._data = stored
        else:
            if plan.resume and stored is not None:
                log("[study] the evaluation kept from the earlier session was made with another task, seed, layouts, "
                    "--episodes or code (or its record is damaged): every policy is evaluated again")
            self._data = {"identity": wanted, "episodes": None, "checkpoints": {}, "cells": {}}
        state["evaluation"] = self._data

    @property
    def episodes(self) -> int | None:
        """Episodes per policy and layout chosen by the session that started this evaluation."""
        return self._data["episodes"]

    def start(self, episodes: int) -> None:
        """A new evaluation of `episodes` per cell; nothing kept from before counts."""
        self._data.update(episodes=int(episodes), checkpoints={}, cells={})
        self._save()

    def use_checkpoint(self, key: str, path: Path) -> None:
        """The arm `key` is evaluated from `path`: its cells kept from another file are dropped."""
        sha = file_sha256(path)
        if self._data["checkpoints"].get(key) != sha:
            self._data["checkpoints"][key] = sha
            self._data["cells"].pop(key, None)
            self._save()

    def row(self, key: str, label: str, layout) -> Row | None:
        """The kept Row of policy `key` (labelled `label`) on `layout`, None unless it is one this
        evaluation would play there."""
        cell = self._cell(key, layout_label(layout))
        if cell is None:
            return None
        row = row_from_record(cell.get("row"), self._plan.eval_task, self._plan.seed, self.episodes)
        if row is None or row.policy != label or row.layout != layout_label(layout):
            return None
        return row

    def keep(self, key: str, row: Row, seconds: float) -> None:
        """Record a finished cell (and write the record)."""
        self._data["cells"].setdefault(key, {})[row.layout] = {"row": row_record(row), "seconds": round(float(seconds), 3)}
        self._save()

    def seconds(self, key: str) -> float:
        """Seconds the kept cells of `key` took when they were played."""
        return sum(self._cell(key, label)["seconds"] for label in self._data["cells"].get(key, {}) if self._cell(key, label))

    def covers(self, key: str, checkpoint: Path | None = None) -> bool:
        """Whether a cell of `key` is kept for every layout (played from `checkpoint`, when given);
        for planning: whether each is valid is checked when it is taken (`row`)."""
        if checkpoint is not None and (not Path(checkpoint).is_file()
                                       or self._data["checkpoints"].get(key) != file_sha256(checkpoint)):
            return False
        return all(self._cell(key, layout_label(ref)) is not None for ref in self._plan.layouts)

    def _cell(self, key: str, label: str) -> dict | None:
        """The kept cell of `key` on layout `label` if it has a row and its seconds (else None)."""
        cell = self._data["cells"].get(key, {}).get(label)
        if not isinstance(cell, dict) or not isinstance(cell.get("row"), dict):
            return None
        seconds = cell.get("seconds")
        ok = isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and math.isfinite(seconds) and seconds >= 0
        return cell if ok else None


def _well_formed(stored: dict) -> bool:
    episodes = stored.get("episodes")
    return ((episodes is None or (isinstance(episodes, int) and not isinstance(episodes, bool) and episodes >= 1))
            and isinstance(stored.get("checkpoints"), dict) and isinstance(stored.get("cells"), dict)
            and all(isinstance(v, dict) for v in stored["cells"].values()))
