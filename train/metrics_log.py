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
        """Every complete row (a line cut short by a crash is skipped)."""
        if not self.path.exists():
            return []
        out = []
        for line in self.path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return out

    def truncate_after(self, update: int) -> None:
        """Drop rows of updates after `update` (written before a crash lost their checkpoint)."""
        rows = [r for r in self.rows() if r.get("update", 0) <= update]
        atomic_write_text(self.path, "".join(json.dumps(r) + "\n" for r in rows))
