"""A rerun stream written to a visible unfinished file until it is renamed into place."""

from __future__ import annotations

import ctypes
import time
from pathlib import Path
from typing import Callable

import rerun as rr

from ..io_utils import CannotWrite, unfinished_path

#: the longest a flush may go on with nothing reaching its file (s): it has stalled then. Once
#: rerun's file writer has died (a full disk), rerun 0.41's flush reports it (RuntimeError) at once
#: or, depending on when it died, waits: without a bound forever, deaf to Ctrl-C and SIGTERM. Its
#: disconnect() waits the same way with no bound, so a stream whose writer failed is dropped, never
#: disconnected. A flush writes an episode or a row; one that is slow but still writing (a slow
#: disk, a network folder) is waited for as long as its file grows.
FLUSH_TIMEOUT_S = 30.0

#: how long each of a flush's waits lasts before its file is looked at again (s)
FLUSH_POLL_S = 1.0


#: streams whose flush failed, kept alive to the end of the process (`_keep_for_good`): dropping
#: one, or rerun's own shutdown at exit, can wait on its dead writer forever (see FLUSH_TIMEOUT_S)
FAILED_STREAMS: list = []


def _keep_for_good(stream: rr.RecordingStream) -> None:
    """Keep `stream`, whose writer failed, from ever being dropped, and take rerun's shutdown off
    the exit: either would wait on the dead writer forever (rerun 0.41: the stream's __del__ as the
    interpreter ends, `rerun_shutdown` at exit), and a Python caller's process, having got the
    error, hung at exit. Its reference in FAILED_STREAMS is cleared as the interpreter ends, so one
    more is taken that is never given back. Other streams are left to their owners to close (this
    project's recorders all close theirs); rerun's exit would only have flushed them."""
    FAILED_STREAMS.append(stream)
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(stream))
    rr.unregister_shutdown()


class FlushStalled(RuntimeError):
    """A flush during which nothing reached the stream's file for FLUSH_TIMEOUT_S."""


def flush(stream: rr.RecordingStream, path: Path | None = None) -> None:
    """Flush `stream` to its file `path`; RuntimeError if rerun's file writer failed (a full disk),
    FlushStalled if nothing reached `path` for FLUSH_TIMEOUT_S (without `path`: if the flush took
    that long). The stream is then kept for good (FAILED_STREAMS, `_keep_for_good`)."""
    limit, poll = FLUSH_TIMEOUT_S, min(FLUSH_POLL_S, FLUSH_TIMEOUT_S)  # read here: a test may lower them
    size, since = _size(path), time.monotonic()
    while True:
        try:
            stream.flush(timeout_sec=poll if path is not None else limit)
            return
        except RuntimeError as exc:
            now = time.monotonic()
            if "timed out" not in str(exc).lower():  # the writer failed
                _keep_for_good(stream)
                raise
            grown = _size(path)
            if grown != size:  # still writing: wait on
                size, since = grown, now
            elif now - since >= limit:
                _keep_for_good(stream)
                raise FlushStalled(f"nothing reached it for {limit:g} s (rerun: {exc})") from None


def _size(path: Path | None) -> int | None:
    """The size of `path` in bytes (None without one, or when it cannot be read)."""
    try:
        return path.stat().st_size if path is not None else None
    except OSError:
        return None


def cannot_write(name: str, exc: RuntimeError) -> str:
    """The message for a stream that `flush` gave up on: '{name}: cannot write it (rerun: ...)',
    or for FlushStalled '{name}: cannot write it: the flush timed out, nothing reached it for 30 s
    (rerun: ...)' (a dead writer, a full disk, looks the same to rerun's flush as a hung one)."""
    if isinstance(exc, FlushStalled):
        return f"{name}: cannot write it: the flush timed out, {exc}"
    return f"{name}: cannot write it (rerun: {exc})"


def any_failed() -> bool:
    """Whether a stream of this process failed to write: its exit must skip rerun's shutdown."""
    return bool(FAILED_STREAMS)


def stream_to_unfinished(stream: rr.RecordingStream, path: Path, write_first: Callable[[], None], name: str) -> Path:
    """Point `stream` at a new unfinished file of `path` (io_utils.unfinished_path), log what
    `write_first` logs and flush; returns that file. On a full disk nothing is left and
    CannotWrite names `name` (what the user gave, e.g. '--rerun out.rrd')."""
    tmp = unfinished_path(path)
    try:
        stream.save(tmp)
        write_first()
        flush(stream, tmp)
    except RuntimeError as exc:  # rerun's file writer failed (the stream is not disconnected: FLUSH_TIMEOUT_S)
        tmp.unlink(missing_ok=True)
        raise CannotWrite(cannot_write(name, exc)) from None
    return tmp
