"""The run's metrics log: one JSON object per update, appended and flushed at once (metrics.jsonl)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from pursuit_mj.io_utils import atomic_write_text


def json_ready(value: Any) -> Any:
    """`value` with non-finite floats (nested in dicts) as None, which JSON can hold."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    return value


class MetricsLog:
    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def append(self, row: dict[str, Any]) -> None:
        """Append one row; ValueError naming the file if it cannot be written (a line cut short
        by a full disk is skipped by `rows`)."""
        try:
            with open(self.path, "a") as f:
                f.write(json.dumps(json_ready(row)) + "\n")
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise ValueError(f"metrics log {self.path}: cannot append to it ({exc.strerror or exc})") from None

    def rows(self) -> list[dict[str, Any]]:
        """Every complete row, a JSON object whose update (if any) is an integer (a line cut short by
        a crash is skipped, and so is a line of other JSON, [1], 7 or {"update": null}, garbled or
        hand-edited: readers take each row as a dict and compare its update)."""
        if not self.path.exists():
            return []
        out = []
        for line in self.path.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict) and _is_count(row.get("update", 0)):
                out.append(row)
        return out

    def truncate_after(self, update: int) -> None:
        """Drop rows of updates after `update` (written before a crash lost their checkpoint) and a
        last line cut short. When what goes is the file's tail (the usual case: rows are appended in
        update order) the file is cut in place, which needs no free space, so a full disk does not
        stop a resume; otherwise it is rewritten."""
        if not self.path.exists():
            return
        data = self.path.read_bytes()
        lines = data.splitlines(keepends=True)
        numbers = [_row_update(line) for line in lines]
        tail = len(lines)  # lines[tail:] all go: cut short, or of later updates
        while tail and (numbers[tail - 1] is None or numbers[tail - 1] > update):
            tail -= 1
        if any(n is not None and n > update for n in numbers[:tail]):
            rows = [r for r in self.rows() if r.get("update", 0) <= update]  # a later row inside the file
            atomic_write_text(self.path, "".join(json.dumps(r) + "\n" for r in rows))
            return
        keep = sum(len(line) for line in lines[:tail])
        try:
            if keep < len(data):
                os.truncate(self.path, keep)
            if keep and not data[:keep].endswith((b"\n", b"\r")):  # a whole last row without its newline
                with open(self.path, "ab") as f:  # the next row must not join its line
                    f.write(b"\n")
        except OSError as exc:
            raise ValueError(f"metrics log {self.path}: cannot cut it back to update {update} "
                             f"({exc.strerror or exc})") from None


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _row_update(line: bytes) -> int | None:
    """The update number of a whole row line (0 if it names none, as `rows` readers take it); None
    for a line that is no row of `rows` (cut short by a crash, garbled)."""
    try:
        row = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return None
    if not isinstance(row, dict):
        return None
    number = row.get("update", 0)
    return number if _is_count(number) else None  # {"update": null}: garbled, as `rows` takes it


def missing_updates(present: set[int], logged: int) -> tuple[int, int, int] | None:
    """The updates 1..logged without a row in `present`, as (first, last, how many), or None if
    none is missing. Costs O(len(present)), whatever `logged` is (a damaged count may be huge)."""
    have = {u for u in present if isinstance(u, int) and 1 <= u <= logged}
    count = logged - len(have)
    if count <= 0:
        return None
    first = 1
    while first in have:
        first += 1
    last = logged
    while last in have:
        last -= 1
    return first, last, count
