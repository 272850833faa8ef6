"""Training scalars streamed into a rerun recording: `RerunScalarLogger(path).log(step, metrics)`.

Each metric becomes a time series `train/<key>` on the timeline `env_steps` (nested dicts
flatten to `train/<outer>/<inner>`; non-numbers and non-finite values are skipped). The file
is written as the run goes, not renamed at the end, so that a run that dies still leaves its
curves behind; open it with `rerun FILE` during or after training.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import rerun as rr

from ..io_utils import CannotWrite
from ..plots import flatten
from .rerun_episodes import APPLICATION_ID, check_rrd_path
from .unfinished import cannot_write, flush


def flatten_numbers(metrics: Mapping[str, Any]) -> dict[str, float]:
    """{'a': 1, 'b': {'c': 2.0}} -> {'a': 1.0, 'b/c': 2.0}; bools, strings, None and NaN/inf dropped."""
    return flatten(metrics, sep="/")


class RerunScalarLogger:
    """Stream training metrics to an .rrd file on the `env_steps` timeline."""

    def __init__(self, path: str | Path, run_name: str | None = None, timeline: str = "env_steps", source: str = "rerun log"):
        self.path = check_rrd_path(path, source)
        self.timeline = timeline
        self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        self.stream.save(self.path)
        if run_name:
            self.stream.send_recording_name(run_name)
        self.source = source
        self._closed = False
        self._failed = False

    def log(self, step: int, metrics: Mapping[str, Any]) -> None:
        """Record every numeric entry of `metrics` (nested dicts allowed) at `step` env steps.
        CannotWrite (a ValueError) naming the file if it cannot be written (a full disk); the rows
        logged before stay in it."""
        if self._closed:
            raise RuntimeError(f"rerun log {self.path}: log after close")
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or not 0 <= step < 2 ** 63:
            raise ValueError(f"rerun log {self.path}: step must be an integer in 0..2^63-1, got {step!r}")
        step = int(step)
        if not isinstance(metrics, Mapping):
            raise ValueError(f"rerun log {self.path}: metrics must be a mapping of names to numbers, got {metrics!r}")
        self.stream.set_time(self.timeline, sequence=step)
        for key, value in flatten_numbers(metrics).items():
            self.stream.log(f"train/{key}", rr.Scalars(value))
        self._flush()  # on disk before the next row: a run killed (kill -9) keeps every logged row

    def _flush(self) -> None:
        try:
            flush(self.stream, self.path)
        except RuntimeError as exc:  # rerun's file writer stopped (a full disk) or stalled
            self._failed = True
            raise CannotWrite(cannot_write(f"{self.source} {self.path}", exc)) from None

    def close(self) -> Path:
        """Finish the file; CannotWrite if its last rows cannot be written. After a failed `log`
        it only lets the stream go (the error was given then)."""
        if not self._closed:
            self._closed = True
            if self._failed:  # rerun's disconnect would wait forever on the dead writer: the stream is left
                return self.path
            self._flush()
            self.stream.disconnect()
        return self.path

    def __enter__(self) -> "RerunScalarLogger":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
