"""Atomic file writes: a crash or Ctrl-C never leaves a half-written file under the final name."""

from __future__ import annotations

import contextlib
import contextvars
import errno
import glob
import hashlib
import os
import re
import secrets
import shlex
import shutil
import signal
import stat
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Callable, Iterator


class CannotWrite(ValueError):
    """A file could not be written (its message names the file and the reason)."""


#: the folder of devices: a name there that is no device or pipe is never written (see device_folder_fault)
DEVICES_FOLDER = "/dev"


def device_folder_fault(path: str | Path, appended: bool = False) -> str | None:
    """Why `path` must not be written as a file: 'PATH: a name in /dev ...' when it lies in the folder
    of devices and is no device or named pipe there (/dev/stdout while the shell sends the output to
    a file is a link to that file; /dev/new.json is not there). Replacing it would put a regular
    file among the devices, for every program on the machine (run as root), and the file the link
    leads to would get nothing. None elsewhere, and for a device or pipe (written in place); with
    `appended` (the file is opened where the name leads and appended to, never replaced) also for a
    name that leads to a regular file."""
    parent = os.path.dirname(os.path.abspath(path))
    if os.path.realpath(parent) != os.path.realpath(DEVICES_FOLDER) or is_stream(Path(path)):
        return None
    try:
        regular = stat.S_ISREG(os.stat(path).st_mode)
        what = "leads to a regular file" if regular else "is no device or named pipe"
    except OSError:
        regular, what = False, "is not there"
    if appended and regular:
        return None
    return (f"{path}: a name in {DEVICES_FOLDER}, the folder of devices, that {what}: writing it would put a file "
            f"among the devices; give a file in a folder of yours (for output redirected to a file, that file's name)")


#: the stop signals stops_held holds back (SIGHUP where the system has it)
STOP_SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)


@contextlib.contextmanager
def stops_held() -> Iterator[None]:
    """Within: a stop signal (Ctrl-C, SIGTERM, SIGHUP) that has a Python handler is held back and
    delivered to that handler as the block ends, so that outputs that belong together (an
    episode's video and its entry in a rerun recording) are put in place together or not at all.
    The first stop held is delivered (its handler raises KeyboardInterrupt, as it would have at
    once), also when the block raised. When the block failed (an Exception: a file that could not
    be written) and the handler raises (for a stop held, or one that lands as the handlers go
    back), the handler's exception is raised with that failure as its cause (`__cause__`), so
    that the stop is not lost and the failure is still told (pursuit_cli.main prints it before
    'interrupted'). Keep the block short: it is deaf to stops while it runs.
    Signals ignored or at the system's default, and any block off the main thread, are left alone."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum, frame):
        held.append(signum)

    taken = {}
    failure = None
    try:  # a stop can land between any two of these steps: whatever was taken by then is given back
        for sig in STOP_SIGNALS:
            handler = signal.getsignal(sig)
            if callable(handler):
                taken[sig] = handler  # noted before it is replaced, so that `hold` is never left behind
                signal.signal(sig, hold)
        yield
    except Exception as exc:
        failure = exc
        raise
    finally:
        # a stop landing as the handlers go back (not held) raises there, the block's failure its cause too
        _with_cause(give_back_handlers, taken, failure=failure)
        if held:
            _deliver(held[0], failure)


def _deliver(signum: int, failure: Exception | None) -> None:
    """Run the handler of the stop `signum` now, as if it had just arrived; an exception it raises
    has `failure` (what the held block raised, if anything) as its cause."""
    _with_cause(signal.raise_signal, signum, failure=failure)


def _with_cause(call, *args, failure: Exception | None) -> None:
    """call(*args); an exception it raises (a stop's handler ran) has `failure`, if any, as its cause."""
    try:
        call(*args)
    except BaseException as stop:
        if failure is None or stop is failure:
            raise
        raise stop from failure


def give_back_handlers(handlers: dict) -> None:
    """Install each signal's handler of `handlers` {signal: handler}, all of them even when a stop
    lands meanwhile: a handler already back may raise for it (KeyboardInterrupt) at the next
    bytecode, and that exception is raised once every handler is back (else the signals after
    it stay on what was to be replaced, for good)."""
    pending = list(handlers.items())
    stopped = None
    for _ in range(len(pending) + 8):  # bounded: a signal.signal that fails itself would fail on every try
        try:
            while pending:
                signal.signal(*pending[0])
                del pending[0]
            break
        except BaseException as exc:  # a handler raised: carry on, raise it after
            stopped = stopped or exc
    if stopped is not None:
        raise stopped


def interrupt_handled() -> None:
    """Say that a KeyboardInterrupt caught by the caller was handled, so that the process still
    ends with its own exit code (130 after Ctrl-C, as the CLI says it stopped).

    CPython (3.11 at least) marks an interrupt unhandled whenever a KeyboardInterrupt leaves code
    run by exec() or eval() of a string, and keeps that mark even when the exception is caught
    further up; a process run with `python -m` (or a script that ends without sys.exit) then ends
    by SIGINT at exit, whatever its exit code. A Ctrl-C lands in such code now and then while
    modules import (dataclasses and namedtuple generate their methods with exec and eval).
    Running any string clears the mark: the interpreter resets it before each one."""
    exec("pass", {})


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is renamed onto `path`, else removed.
    CannotWrite (a ValueError) naming `path` if the temporary file cannot be made, or if the
    finished file cannot replace `path` (then it is kept as NAME.new.SUFFIX, see keep_beside,
    and the message says where). A character device or named pipe (/dev/null, a pipe to a
    reader) is yielded itself and written in place: a rename would put a file in its stead, for
    every program that uses it."""
    path = Path(path)
    if is_stream(path):
        with _reader_held(path):
            yield path
        return
    if (fault := device_folder_fault(path)) is not None:
        raise CannotWrite(fault)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # the extension in lower case: writers that pick or check the format by it (mediapy's gif) take .GIF too
        # the writer's pid in the name: a later write of `path` removes what a killed one left (_remove_dead_parts)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=".part" + path.suffix.lower(),
                                   dir=path.parent)
    except OSError as exc:  # a folder that passes the access check but takes no new file (/proc), a full disk
        raise CannotWrite(f"{path}: cannot write it ({exc.strerror or exc})") from None
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
    try:
        yield tmp_path
        with open(tmp_path, "rb") as f:
            os.fsync(f.fileno())
        try:
            os.replace(tmp_path, path)
        except OSError as exc:  # a folder or an immutable file under the name: the finished file is kept
            raise CannotWrite(not_replaced_message(path, exc, keep_beside(tmp_path, path))) from None
        _fsync_folder(path.parent)  # the rename itself survives a power cut only once its folder is on disk
        _remove_dead_parts(path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def is_stream(path: Path) -> bool:
    """Whether `path` (symbolic links followed) is a character device or a named pipe."""
    try:
        mode = os.stat(path).st_mode
    except OSError:  # not there yet, or not reachable: atomic_path says why when it writes
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)


@contextlib.contextmanager
def _reader_held(path: Path) -> Iterator[None]:
    """For a named pipe: CannotWrite naming it at once when no program reads it (a writer's open()
    would wait for a reader forever); else a write end of it held open while the body writes, so that
    a reader that opened it before does not take the end of this check for the end of the data.
    Nothing for a device."""
    try:
        fifo = stat.S_ISFIFO(os.stat(path).st_mode)
    except OSError:
        fifo = False
    if not fifo or not hasattr(os, "O_NONBLOCK"):
        yield
        return
    try:
        fd = _open_writing(path, os.O_WRONLY)
    except OSError as exc:
        if no_reader(exc, path):
            raise CannotWrite(no_reader_message(path)) from None
        raise CannotWrite(f"{path}: cannot write it ({exc.strerror or exc})") from None
    try:
        yield
    finally:
        os.close(fd)


#: the temporary files atomic_path makes: `.NAME.PID-XXXXXXXX.partSUFFIX` (mkstemp's eight random
#: characters; `.NAME.XXXXXXXX.partSUFFIX` before the writer's pid was part of it)
_PART = re.compile(r"\.(?P<name>.+)\.((?P<pid>\d+)-)?[a-z0-9_]{8}\.part(\.[^.]*)?")


def _remove_dead_parts(path: Path) -> None:
    """Remove the temporary files of earlier writes of `path` whose writer has died (kill -9, a
    power cut); those of a live process (another write of the same file going on) stay."""
    try:
        siblings = list(path.parent.glob(f".{glob.escape(path.name)}.*.part*"))
    except OSError:
        return
    for part in siblings:
        match = _PART.fullmatch(part.name)
        if match is not None and match["name"] == path.name and _writer_died(match):
            _unlink_quietly(part)


def _writer_died(match: re.Match) -> bool:
    return match["pid"] is not None and not _alive(int(match["pid"]))


def _unlink_quietly(path: Path) -> bool:
    try:
        path.unlink()
    except OSError:
        return False
    return True


DEAD_PART_AGE = 600.0  # s: remove_dead_parts_in leaves younger ones (a writer on another machine sharing the folder)


def remove_dead_parts_in(folder: str | Path, min_age: float = DEAD_PART_AGE) -> list[Path]:
    """Remove the temporary files of atomic writes of any name in `folder` whose writer died (a render
    or an eval killed mid-file leaves one as large as the file it was to become, and the file's
    name, which holds a seed or digest, may never be written again to sweep it). Only those of
    a pid that no longer runs here and untouched for `min_age` s: a writer on another machine that
    shares the folder has a pid unknown here. Returns those removed."""
    removed = []
    now = time.time()
    try:
        candidates = list(Path(folder).glob(".*.part*"))
    except OSError:
        return removed
    for part in candidates:
        match = _PART.fullmatch(part.name)
        try:  # the entry itself (a link is not ours: atomic_path makes plain files)
            info = part.lstat()
        except OSError:
            continue
        old = stat.S_ISREG(info.st_mode) and now - info.st_mtime >= min_age
        if match is not None and old and _writer_died(match) and _unlink_quietly(part):
            removed.append(part)
    return sorted(removed)


#: the unfinished recordings this process streams to (a file of its pid that is not among them was left
#: by an earlier process that had the same pid: pids come round again, in a container on every start)
_OURS: set[Path] = set()


def unfinished_path(path: str | Path) -> Path:
    """A new name for this process to stream a recording of `path` to until it is finished (then
    renamed onto it): `NAME.unfinished-PID-XXXXXX.SUFFIX`, visible and readable by the viewer, so
    that a writer killed mid-way (kill -9, a power cut) leaves what it had recorded for the user.
    Each call gives another name (two recordings of one name in a process do not share a file)."""
    path = Path(path)
    while True:
        tmp = path.with_name(f"{path.stem}.unfinished-{os.getpid()}-{secrets.token_hex(3)}{path.suffix}")
        if not tmp.exists() and tmp.absolute() not in _OURS:
            _OURS.add(tmp.absolute())
            return tmp


def killed_unfinished(path: str | Path) -> list[Path]:
    """The unfinished recordings of `path` (unfinished_path) whose writer has died: kept for the
    user, never removed here."""
    path = Path(path)
    pattern = re.compile(re.escape(path.stem) + r"\.unfinished-(\d+)(-[0-9a-f]+)?" + re.escape(path.suffix))
    try:
        siblings = sorted(path.parent.glob(f"{glob.escape(path.stem)}.unfinished-*{glob.escape(path.suffix)}"))
    except OSError:
        return []

    def dead(p: Path, pid: int) -> bool:
        return p.absolute() not in _OURS if pid == os.getpid() else not _alive(pid)

    return [p for p in siblings if (m := pattern.fullmatch(p.name)) and p.is_file() and dead(p, int(m[1]))]


def move_into_place(tmp: str | Path, path: str | Path) -> Path:
    """Rename the finished file `tmp` onto `path` durably: its data, then the folder's entry.

    A character device or named pipe under the name (a pipe to a viewer) gets the file's bytes
    written into it instead, and `tmp` is removed: a rename would put a file in its stead. A pipe
    that no program opens for reading within PIPE_READER_WAIT_S is OSError ENXIO (`no_reader`),
    and `tmp` is left for the caller to keep."""
    if is_stream(Path(path)):
        fd = _open_writing(path, os.O_WRONLY)
        try:
            with open(tmp, "rb") as src, os.fdopen(fd, "wb", closefd=False) as dst:
                shutil.copyfileobj(src, dst)
        finally:
            os.close(fd)
        Path(tmp).unlink()
        return Path(path)
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_folder(Path(path).parent)
    return Path(path)


def keep_beside(tmp: str | Path, path: str | Path) -> Path | None:
    """Keep the finished file `tmp` that could not be renamed onto `path` under a visible sibling,
    `NAME.new.SUFFIX` (`NAME.new-K.SUFFIX` when that is taken: nothing there is replaced), so
    that what the user made survives; returns it, `tmp` itself if it cannot be renamed, or None
    if `tmp` is gone (its folder removed)."""
    tmp, path = Path(tmp), Path(path)
    for k in range(1, 1000):
        kept = path.with_name(f"{path.stem}.new{'' if k == 1 else f'-{k}'}{path.suffix}")
        try:
            os.link(tmp, kept)  # never replaces a file already there (os.rename would)
        except FileExistsError:
            continue
        except OSError:  # no hard links here (some file systems), or the folder is gone
            if os.path.lexists(kept):
                continue
            try:
                os.rename(tmp, kept)
            except OSError:
                break
            return kept
        _unlink_quietly(tmp)
        return kept
    return tmp if tmp.exists() else None


def not_replaced_message(path: Path, exc: OSError, kept: Path | None) -> str:
    """'PATH: cannot replace it (REASON); what was written is kept in KEPT' (or '...: it is lost')."""
    where = f"what was written is kept in {kept}" if kept is not None else "what was written is lost (its folder is gone)"
    if no_reader(exc, path):
        return f"{no_reader_message(path)}; {where}"
    return f"{path}: cannot replace it ({exc.strerror or exc}); {where}"


def _alive(pid: int) -> bool:
    """Whether a process with this pid exists (one of another user's counts as alive)."""
    if os.name == "nt":  # os.kill would end the process there, not probe it
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    return True


def remove_leftover_parts(folder: str | Path) -> list[Path]:
    """Remove the temporary files of atomic writes into `folder` that a kill -9 or a power cut left
    behind (each as large as the file it was to become); only for a folder that no other process
    writes in (a locked run folder). Returns those removed."""
    removed = []
    for path in Path(folder).iterdir():
        if _PART.fullmatch(path.name) and path.is_file():
            try:
                path.unlink()
            except OSError:
                continue
            removed.append(path)
    return removed


def _fsync_folder(folder: Path) -> None:
    """Flush a folder's entries to disk where the platform allows it (not on Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: s a write to a named pipe waits for a program to open it for reading before it is refused
#: (a plain open() would wait forever, with no word)
PIPE_READER_WAIT_S = 5.0


def _open_writing(path: str | Path, flags: int) -> int:
    """os.open(path, flags) without waiting forever for the reader of a named pipe: tried again for
    PIPE_READER_WAIT_S while none has it open, then OSError ENXIO (no_reader). The descriptor is
    blocking, as os.open's, and a file is opened as os.open opens it."""
    nonblocking = getattr(os, "O_NONBLOCK", 0)
    deadline = time.monotonic() + PIPE_READER_WAIT_S
    while True:
        try:
            fd = os.open(path, flags | nonblocking, 0o666)
            break
        except OSError as exc:
            if exc.errno != errno.ENXIO or time.monotonic() >= deadline:
                raise
        time.sleep(0.05)
    if nonblocking:
        import fcntl

        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~nonblocking)
    return fd


def open_for_appending(path: str | Path) -> IO[str]:
    """`path` opened to append text to (made if missing), as open(path, "a") does, except that a named
    pipe that no program reads is OSError ENXIO after PIPE_READER_WAIT_S (open() would wait for a
    reader forever; see no_reader): writes to a pipe that has one wait for it as they would have."""
    fd = _open_writing(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    try:
        return os.fdopen(fd, "a", encoding="utf-8")
    except BaseException:
        os.close(fd)
        raise


def no_reader(exc: OSError, path: str | Path) -> bool:
    """Whether `exc`, raised opening `path` to write (open_for_appending), says it is a named pipe
    that no program reads."""
    try:
        return exc.errno == errno.ENXIO and stat.S_ISFIFO(os.stat(path).st_mode)
    except OSError:
        return False


def no_reader_message(path: str | Path, what: str = "") -> str:
    """'[WHAT ]PATH: a named pipe that no program opened for reading within N s; ...' (no_reader)."""
    return (f"{what + ' ' if what else ''}{path}: a named pipe that no program opened for reading within "
            f"{PIPE_READER_WAIT_S:g} s, so what is written would wait forever; start its reader first "
            f"(e.g. cat {shlex.quote(str(path))}), or give a file")


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write `text` to `path` atomically; ValueError naming the file if it cannot be written
    (a full disk, a folder made read-only or removed)."""
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(text)
    except OSError as exc:
        raise ValueError(f"{path}: cannot write it ({exc.strerror or exc})") from None
    return Path(path)


_FOLDERS_MADE: contextvars.ContextVar[list[Path] | None] = contextvars.ContextVar("folders_made", default=None)


def make_folders(folder: Path) -> None:
    """`folder` and those of its parents that are missing made, as mkdir -p does (OSError as mkdir raises
    it), each one this call made itself noted (absolute, as it named it) for the enclosing
    no_new_empty_folders: one that another process made meanwhile, or that was there, is not noted."""
    try:
        try:
            folder.mkdir()
        except FileNotFoundError:  # a folder above it is missing: that one first
            if folder.parent == folder:
                raise
            make_folders(folder.parent)
            folder.mkdir()
    except OSError:
        if not folder.is_dir():  # a file, a dangling link, a folder above that is a file
            raise
        return  # there already ('new/..'), or made meanwhile by another process: not this call's
    made = _FOLDERS_MADE.get()
    if made is not None:
        made.append(folder.absolute())


def made_here(folder: str | Path) -> bool:
    """Whether make_folders (check_writable_folder) made `folder` itself within the enclosing
    no_new_empty_folders (False outside one): a folder that was there, or that another process
    made meanwhile, was not (a name such as 'new/../keep' cannot tell: it is missing until new/ is)."""
    made = _FOLDERS_MADE.get()
    return made is not None and Path(folder).absolute() in made


@contextlib.contextmanager
def no_new_empty_folders() -> Iterator[None]:
    """Within: if the body raises (a refusal, a failure mid-run, Ctrl-C), every folder that
    check_writable_folder (make_folders) made within it, in this thread, and that is empty then is
    removed, innermost first, where it was made (a chdir meanwhile changes nothing). One that holds
    anything (a partial table, a log, a recording) stays, and with it the folders above it: what a
    command made and left empty goes, what it wrote is never lost, and a folder that was there or
    that another process made is never touched. Nothing is removed when the body succeeds (an
    enclosing no_new_empty_folders takes over the folders made)."""
    outer = _FOLDERS_MADE.get()
    made: list[Path] = []
    token = _FOLDERS_MADE.set(made)
    try:
        yield
    except BaseException:
        for folder in reversed(made):  # a folder is made after the one it is in
            with contextlib.suppress(OSError):
                folder.rmdir()  # only an empty folder (a non-empty one stays)
        raise
    finally:
        _FOLDERS_MADE.reset(token)
    if outer is not None:
        outer.extend(made)


def check_writable_folder(folder: str | Path, what: str) -> Path:
    """Create `folder` if needed, or ValueError starting with `what` (e.g. the flag and its
    value) if it is a file, cannot be created or cannot be written."""
    folder = Path(folder)
    try:
        is_file = folder.exists() and not folder.is_dir()
    except OSError as exc:  # a name too long for the file system, say
        raise ValueError(f"{what}: cannot use the folder {folder} ({exc.strerror or exc})") from None
    if is_file:
        raise ValueError(f"{what}: {folder} exists and is not a folder")
    try:
        make_folders(folder)
    except OSError as exc:
        raise ValueError(f"{what}: cannot create the folder {folder} ({exc.strerror})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{what}: folder {folder} is not writable")
    return folder


def check_writable(path: str | Path, what: str = "output", appended: bool = False) -> Path:
    """Fail early with a clear message if `path` cannot be written (before any work is done). A
    path given as text that ends in a separator ('tables/') names a folder, which Path would
    quietly turn into a file of that name, so it is refused too, as is one that ends in '/.' or
    '/..' (Path('tables/.') is 'tables'), and a name in /dev that no device or pipe holds
    (device_folder_fault; one that leads to a file is taken where the file is `appended` to)."""
    if isinstance(path, str) and path.endswith(("/", os.sep)):
        raise ValueError(f"{what} path {path}: ends in '{path[-1]}', which names a folder; give the name of the "
                         f"file to write in it")
    if isinstance(path, str) and os.path.basename(path) in (".", ".."):
        raise ValueError(f"{what} path {path}: ends in '{os.path.basename(path)}', which names a folder; give the name "
                         f"of the file to write in it")
    if (fault := device_folder_fault(path, appended)) is not None:
        raise ValueError(f"{what} path {fault}")
    path = Path(path)
    check_writable_folder(path.parent if str(path.parent) else Path("."), f"{what} path {path}")
    try:
        is_dir = path.is_dir()
    except OSError as exc:  # a name too long for the file system, say
        raise ValueError(f"{what} path {path}: cannot use it ({exc.strerror or exc})") from None
    if is_dir:
        raise ValueError(f"{what} path {path}: is a folder, expected a file name")
    return path


def file_sha256(path: str | Path) -> str:
    """The hex sha256 of a file's bytes (to tell whether a file changed since it was used)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def first_line_is_json_object(path: str | Path) -> bool:
    """Whether the file's first line alone is a JSON object, as in a JSON-lines log (False when
    it cannot be read or parsed): tells a training log from a JSON table that fails to parse."""
    import json

    try:
        with open(path, encoding="utf-8") as f:
            return isinstance(json.loads(f.readline()), dict)
    except (OSError, ValueError):
        return False


#: how much of an existing output file is read to tell whether the command may replace or append
#: to it (a multi-GB file given as an output by mistake is not read whole)
PEEK_BYTES = 1 << 16


def holds_another_kind(path: str | Path, is_kind: Callable[[bytes, bool], bool], limit: int = PEEK_BYTES) -> bool:
    """Whether writing to `path` would replace or extend a file of the user's that is not of the
    kind the command writes there: `path` is an existing, non-empty regular file (symbolic links
    followed) and `is_kind(head, whole)` is false, where head is its first `limit` bytes and whole
    says whether that is all of it. False where nothing is there to lose (no file yet, an empty
    one, a folder, a device such as /dev/null) or it cannot be read (writing it says why)."""
    try:
        if not os.path.isfile(path) or os.stat(path).st_size == 0:
            return False
        with open(path, "rb") as f:
            head = f.read(limit + 1)
    except OSError:
        return False
    return not is_kind(head[:limit], len(head) <= limit)
