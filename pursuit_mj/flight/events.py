"""The flight's event log: every event with its time, one JSON object per line, written as it happens.

A line is {"t": s since the log opened (monotonic clock), "time": wall-clock ISO 8601 UTC,
"kind": ..., ...fields}, strict JSON: a value that is not a finite number is null. Lines are appended and flushed one by one (safety events are also
fsync'ed), so a crash or a power cut leaves every event written before it readable.
Thread-safe: cflib's threads, key watchers and the flight loop all log here. Sinks (the
terminal echo, the rerun recorder, the fault injector) each receive every non-routine
record, independently. Logging never raises into the flight: a log file that cannot be
written (disk full) or a sink that fails (a closed pipe or terminal under the echo) is
reported once on stderr and dropped alone; the other sinks go on, and the records stay in
memory, so a failing log cannot keep the drones from landing.
"""

from __future__ import annotations

import datetime
import json
import os
import stat
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..io_utils import open_for_appending

#: events that are not safety-relevant (no fsync)
ROUTINE = frozenset({"step"})


def _plain(value: Any) -> Any:
    """`value` as plain JSON types; a float that is not finite becomes None (JSON has no NaN)."""
    if isinstance(value, np.ndarray):
        return _plain(value.tolist()) if value.dtype.kind == "f" else value.tolist()
    if isinstance(value, (np.floating, float)):
        return round(float(value), 6) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


class EventLog:
    """Append-only JSONL event log (module docstring); `path` None keeps events in memory only.

    `echo(record)`, if given, is the first sink, named "echo" (e.g. a terminal print).
    """

    def __init__(self, path: str | Path | None = None, clock: Callable[[], float] = time.monotonic,
                 echo: Callable[[dict], None] | None = None):
        self.path = Path(path) if path is not None else None
        self.clock = clock
        self.t0 = clock()
        self.records: list[dict] = []
        self._lock = threading.RLock()  # re-entrant: a signal handler may log while the main thread is logging
        self._file = None
        self._sinks: dict[str, Callable[[dict], None]] = {}
        self.failures: list[str] = []  # what stopped being written, and why
        if echo is not None:
            self.add_sink("echo", echo)
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open_for_appending(self.path)  # a pipe no program reads: OSError, not a wait forever
        # only a file on disk can be fsync'ed: /dev/null or a pipe refuse it (EINVAL), and are written all the same
        self._syncs = self._file is not None and stat.S_ISREG(os.fstat(self._file.fileno()).st_mode)

    def add_sink(self, name: str, sink: Callable[[dict], None]) -> None:
        """Call sink(record) for every non-routine event from now on, after the file is written.
        A sink that raises is removed (others are not) and named on stderr once; ValueError if
        `name` is taken."""
        with self._lock:
            if name in self._sinks:
                raise ValueError(f"event log: a sink named {name!r} is already attached")
            self._sinks[name] = sink

    @property
    def sinks(self) -> tuple[str, ...]:
        """Names of the sinks still attached."""
        with self._lock:
            return tuple(self._sinks)

    def now(self) -> float:
        """Seconds since the log opened."""
        return self.clock() - self.t0

    def log(self, kind: str, **fields: Any) -> dict:
        record = {"t": round(self.now(), 4), "time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="milliseconds"), "kind": kind}
        record.update({k: _plain(v) for k, v in fields.items()})
        with self._lock:
            self.records.append(record)
            if self._file is not None:
                try:
                    self._file.write(json.dumps(record) + "\n")
                    self._file.flush()
                    if kind not in ROUTINE and self._syncs:
                        os.fsync(self._file.fileno())
                except (OSError, ValueError) as exc:
                    self._drop_file(f"event log {self.path} no longer written ({type(exc).__name__}: {exc})")
        if kind not in ROUTINE:
            with self._lock:
                sinks = tuple(self._sinks.items())
            for name, sink in sinks:
                try:
                    sink(record)
                except Exception as exc:  # e.g. a closed pipe under the echo: the flight goes on without that sink
                    self._drop_sink(name, f"events no longer sent to '{name}' ({type(exc).__name__}: {exc})")
        return record

    def _drop_file(self, why: str) -> None:
        """Stop writing the file after its first failure (called with the lock held)."""
        file, self._file = self._file, None
        try:
            file.close()
        except (OSError, ValueError):
            pass
        self._report(why)

    def _drop_sink(self, name: str, why: str) -> None:
        """Remove the sink `name` after its first failure; the others stay."""
        with self._lock:
            if self._sinks.pop(name, None) is None:
                return  # another thread dropped it first
        self._report(why)

    def _report(self, why: str) -> None:
        """Keep `why` in `failures` and say it once on stderr, if stderr is there."""
        with self._lock:
            self.failures.append(why)
        try:
            print(f"pursuit-mj fly: {why}; records are kept in memory", file=sys.stderr, flush=True)
        except (OSError, ValueError):
            pass

    def of_kind(self, *kinds: str) -> list[dict]:
        with self._lock:
            return [r for r in self.records if r["kind"] in kinds]

    def kinds(self) -> list[str]:
        with self._lock:
            return [r["kind"] for r in self.records]

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def __enter__(self) -> "EventLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_events(path: str | Path) -> list[dict]:
    """All records of an event log file, in order."""
    with open(path, encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]
