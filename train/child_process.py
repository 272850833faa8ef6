"""What the trainer's child processes share: how they are spawned, stopped, waited for and reported.

A child is spawned (a fresh interpreter: no forked MuJoCo or torch thread state) without
re-running the parent's main script, ignores Ctrl-C from its start (the parent handles it and
stops the child), and exits when the parent's end of its pipe closes, so a killed parent leaves
nothing running. Used by train/rollout_worker.py and train/critic_worker.py.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import traceback

import torch.multiprocessing as mp

POLL_S = 0.2  # how often a waiting parent checks that the child is alive
STOP_TIMEOUT_S = 5.0


class WorkerExited(RuntimeError):
    """The child process ended (killed, or crashed before it could report an error)."""


@contextlib.contextmanager
def _main_script_hidden():
    """While a child is spawned, hide where the parent's __main__ came from.

    A spawned child normally re-imports the parent's main script or module before it runs
    its target, and a user's training script without an `if __name__ == "__main__":` guard
    would then start another training run inside the child. The children need only train.*
    modules, so they are told of no main script at all (multiprocessing.spawn reads
    __main__.__spec__ and __main__.__file__ while Process.start() runs, and only then).
    """
    main = sys.modules.get("__main__")
    saved = {k: main.__dict__[k] for k in ("__spec__", "__file__") if main is not None and k in main.__dict__}
    try:
        if "__spec__" in saved:
            main.__spec__ = None
        if "__file__" in saved:
            del main.__file__
        yield
    finally:
        if main is not None:
            main.__dict__.update(saved)


@contextlib.contextmanager
def _ctrl_c_ignored_by_new_processes():
    """While a child is spawned, Ctrl-C is ignored (SIG_IGN), a disposition a new process inherits
    and keeps through exec: the child ignores Ctrl-C from its first instant, while it still imports
    torch, instead of only once its target runs (a Ctrl-C then printed a KeyboardInterrupt traceback
    from the child). A Ctrl-C in the parent during these milliseconds is ignored too."""
    import threading

    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is None:
        yield  # only the main thread may set handlers, and a handler set outside Python cannot be put back
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def spawn(target, args: tuple, name: str):
    """Start `target(child_conn, *args)` in a spawned daemon process; returns (process, parent_conn)."""
    ctx = mp.get_context("spawn")
    conn, child_conn = ctx.Pipe()
    process = ctx.Process(target=target, args=(child_conn, *args), name=name, daemon=True)
    with _main_script_hidden(), _ctrl_c_ignored_by_new_processes():
        process.start()
    child_conn.close()
    return process, conn


def ignore_ctrl_c() -> None:
    """In a child: Ctrl-C reaches the whole process group, but only the parent acts on it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def report_error(conn) -> None:
    """In a child, inside `except`: send the traceback to the parent (if it still listens)."""
    try:
        conn.send(("error", traceback.format_exc()))
    except (BrokenPipeError, ConnectionResetError):
        pass


def report_refusal(conn, message: str) -> None:
    """In a child: send a one-line error of the user's own making (no traceback) to the parent."""
    try:
        conn.send(("refused", message))
    except (BrokenPipeError, ConnectionResetError):
        pass


def shutdown(process, conn) -> None:
    """Ask the child to stop, wait for it, terminate it if it does not, close the pipe."""
    try:
        conn.send(("stop",))
    except (BrokenPipeError, ConnectionResetError, OSError):
        pass
    process.join(STOP_TIMEOUT_S)
    if process.is_alive():
        process.terminate()
        process.join(STOP_TIMEOUT_S)
    conn.close()


def how_it_ended(process) -> str:
    """How a dead child ended: 'was killed by SIGKILL (...)' or 'exited (code N)'."""
    code = process.exitcode
    if code is None or code >= 0:
        return f"exited (code {code})"
    try:
        name = signal.Signals(-code).name
    except ValueError:
        name = f"signal {-code}"
    return f"was killed by {name}" + (" (the system's out-of-memory killer, or kill -9)" if -code == signal.SIGKILL else "")
