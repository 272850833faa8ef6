"""Exclusive locks on run and study folders, so that two processes never write one folder.

A lock is an flock on a file in the folder holding the holder's pid; the kernel releases it
when the file closes or the process dies, so a killed run leaves no stale lock behind.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


class FolderInUse(ValueError):
    """Another process holds the folder's lock (a trainer its run folder, a study its --out)."""


def lock_run_folder(run_dir: Path):
    """An open file holding an exclusive lock on `run_dir` (released when closed, or when the
    process dies); ValueError if another trainer holds it: two runs in one folder would
    interleave their metrics rows and overwrite each other's checkpoints."""
    return lock_folder(run_dir, ".lock", "run folder", "trainer", "train under another name")


def lock_folder(folder: Path, lock_name: str, what: str, holder_kind: str, advice: str):
    """An open file `folder`/`lock_name` holding an exclusive lock (made with the folder if need be;
    released when closed, or when the process dies). FolderInUse if another process holds it:
    '<what> <folder> is in use by another <holder_kind> (pid N): wait for it to end or stop it, or
    <advice>'; ValueError if the lock file cannot be written."""
    import fcntl

    while True:  # again if the file locked was removed meanwhile (by a holder that could not start): lock the one there
        try:
            folder.mkdir(parents=True, exist_ok=True)
            handle = open(folder / lock_name, "a+")
        except OSError as exc:
            raise ValueError(f"{what} {folder}: cannot write its lock file ({exc.strerror or exc})") from None
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise FolderInUse(f"{what} {folder} is in use by another {holder_kind} ({holder}): wait for it to end or stop "
                              f"it, or {advice}") from None
        if _names_file(folder / lock_name, handle):
            break
        handle.close()
    try:  # unbuffered: nothing is left to flush (and fail) when the handle closes
        os.ftruncate(handle.fileno(), 0)
        os.pwrite(handle.fileno(), f"pid {os.getpid()}".encode(), 0)
    except OSError as exc:  # a full disk: the lock is held, but the holder's pid could not be written
        handle.close()
        raise ValueError(f"{what} {folder}: cannot write its lock file ({exc.strerror or exc})") from None
    return handle


def release_lock(handle, lock_file: Path, remove_file: bool) -> None:
    """Release the lock `handle` (lock_folder) whose file is `lock_file`, removing that file first when
    `remove_file` (one this process made, for a run or study that could not start): while the lock is
    still held, so that no other holder's lock file is taken away. A file already gone is no error."""
    if remove_file:
        with contextlib.suppress(OSError):
            lock_file.unlink()
    handle.close()


def _names_file(path: Path, handle) -> bool:
    """Whether `path` is (still) the file open as `handle`."""
    try:
        return os.path.samestat(os.stat(path), os.fstat(handle.fileno()))
    except OSError:  # removed
        return False
