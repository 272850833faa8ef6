"""A rerun stream written to a visible unfinished file until it is renamed into place."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import rerun as rr

from ..io_utils import CannotWrite, unfinished_path

#: the longest a flush may wait for rerun's file writer (s). Once that writer has died (a full disk),
#: rerun 0.41's flush reports it (RuntimeError) at once or, depending on when it died, waits: without
#: a bound forever, deaf to Ctrl-C and SIGTERM. Its disconnect() waits the same way with no bound, so
#: a stream whose writer failed is dropped, never disconnected. A flush writes an episode or a row.
FLUSH_TIMEOUT_S = 30.0


#: streams whose flush failed, kept alive: dropping one, or rerun's own shutdown at exit, can wait
#: on its dead writer forever (see FLUSH_TIMEOUT_S); a process that holds one ends by os._exit
#: (pursuit_cli.main, `any_failed`)
FAILED_STREAMS: list = []


def flush(stream: rr.RecordingStream) -> None:
    """Flush `stream` to its file; RuntimeError if rerun's file writer failed (a full disk) or took
    longer than FLUSH_TIMEOUT_S (the stream is then kept in FAILED_STREAMS)."""
    try:
        stream.flush(timeout_sec=FLUSH_TIMEOUT_S)  # read here: a test may lower it
    except RuntimeError:
        FAILED_STREAMS.append(stream)
        raise


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
        flush(stream)
    except RuntimeError as exc:  # rerun's file writer failed (the stream is not disconnected: FLUSH_TIMEOUT_S)
        tmp.unlink(missing_ok=True)
        raise CannotWrite(f"{name}: cannot write it (rerun: {exc})") from None
    return tmp
