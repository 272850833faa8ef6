"""A rerun stream written to a visible unfinished file until it is renamed into place."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Callable

import rerun as rr

from ..io_utils import CannotWrite, unfinished_path


def stream_to_unfinished(stream: rr.RecordingStream, path: Path, write_first: Callable[[], None], name: str) -> Path:
    """Point `stream` at a new unfinished file of `path` (io_utils.unfinished_path), log what
    `write_first` logs and flush; returns that file. On a full disk nothing is left and
    CannotWrite names `name` (what the user gave, e.g. '--rerun out.rrd')."""
    tmp = unfinished_path(path)
    try:
        stream.save(tmp)
        write_first()
        stream.flush()
    except RuntimeError as exc:  # rerun's file writer failed
        with contextlib.suppress(RuntimeError):
            stream.disconnect()
        tmp.unlink(missing_ok=True)
        raise CannotWrite(f"{name}: cannot write it (rerun: {exc})") from None
    return tmp
