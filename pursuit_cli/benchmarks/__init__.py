"""Speed benchmarks run by `pursuit-mj bench <target>`; one module per target (see pursuit_cli/bench.py).

Shared helpers: run a measurement in a fresh child process (so that its peak memory is its
own), read the peak resident memory, and print an aligned table.
"""

from __future__ import annotations

import math
import multiprocessing
import resource
import signal
import sys
from typing import Any, Callable, Sequence

MAX_WORLDS = 4096  # as the train config's n_envs; about 1 MiB each, and far more hung building layouts
MAX_SECONDS = 3600.0  # --seconds at most (an hour per configuration): far larger values overflowed block counts


def check_common_args(args: Any) -> None:
    """Refuse a --seconds outside (0, MAX_SECONDS] or a world count outside 1..MAX_WORLDS before any work."""
    if not math.isfinite(args.seconds) or args.seconds <= 0:
        raise ValueError(f"--seconds: must be > 0, got {args.seconds}")
    if args.seconds > MAX_SECONDS:
        raise ValueError(f"--seconds: must be at most {MAX_SECONDS:g} (an hour per configuration), got {args.seconds:g}")
    bad = [w for w in args.worlds if w < 1]
    if bad:
        raise ValueError(f"--worlds: world counts must be >= 1, got {bad[0]}")
    huge = [w for w in args.worlds if w > MAX_WORLDS]
    if huge:
        raise ValueError(f"--worlds: world counts must be at most {MAX_WORLDS}, got {huge[0]}")
    twice = sorted({w for w in args.worlds if args.worlds.count(w) > 1})
    if twice:  # the verdict would judge the first of them only
        raise ValueError(f"--worlds: {twice[0]} given twice; give each world count once")
    fidelities = list(getattr(args, "fidelity", None) or [])
    again = next((f for f in fidelities if fidelities.count(f) > 1), None)
    if again is not None:
        raise ValueError(f"--fidelity: {again} given twice; give each fidelity once")


def given_task(task_files: Sequence[str], overrides: Sequence[str]) -> str:
    """' (--task hard --set evader_speed=0.8)': the task flags a benchmark was given, for its header
    line (a preset or value changes the figures; the header's own list does not name every key);
    '' when none was given."""
    import shlex

    flags = [f"--task {shlex.quote(f)}" for f in task_files] + [f"--set {shlex.quote(o)}" for o in overrides]
    return f" ({' '.join(flags)})" if flags else ""


UNRELIABLE = "the machine's speed changed between blocks; run it again on an idle machine"


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MiB)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes on macOS, KiB on Linux


def _run_and_send(send, fn: Callable[..., Any], args: tuple) -> None:
    try:
        outcome = (True, fn(*args))
    except BaseException as exc:  # the parent re-raises it
        outcome = (False, exc)
    try:
        send.send(outcome)
    except Exception as exc:  # an unpicklable result or exception
        send.send((False, RuntimeError(f"benchmark process: {type(exc).__name__}: {exc}")))


def run_isolated(fn: Callable[..., Any], *args: Any) -> Any:
    """fn(*args) in a fresh forked process that exits after it; its result, or its exception raised here.
    An interrupt that reaches this process while it waits kills that one at once and is raised here.

    One plain process and a pipe: a Pool starts a replacement worker after the task and
    then has to stop it, which could hang its exit."""
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_run_and_send, args=(send, fn, args), daemon=True)
    proc.start()
    send.close()
    try:
        ok, value = recv.recv()
    except EOFError:
        proc.join()
        code = proc.exitcode
        how = f"killed by {signal.Signals(-code).name}" if code is not None and code < 0 else f"exit code {code}"
        # a ValueError, so the command ends in one line (pursuit_cli.main) rather than a traceback
        raise ValueError(f"the benchmark process died ({how}); if the machine ran out of memory, measure fewer worlds "
                         f"or a shorter run") from None
    except BaseException:  # stopped while waiting (Ctrl-C, or SIGTERM and SIGHUP, which reach this process only)
        proc.kill()  # its measurement is not wanted any more: waiting for it kept the command alive for 10 s
        proc.join()
        raise
    finally:
        recv.close()
        if proc.is_alive() and proc.exitcode is None:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
                proc.join()
    if not ok:
        raise value
    return value


def against_aim(value: float, aim: float, decimals: int, sign: str = "") -> str:
    """`value` as text beside a verdict on `aim`: with `decimals` decimals, or up to four more
    where fewer would print it equal to an aim it misses or only just meets (1.003 beside "ratio
    < 1 ... NOT met", not 1.00). `sign`: "+" to show it always."""
    for d in range(decimals, decimals + 5):
        text = f"{value:{sign}.{d}f}"
        if value == aim or text != f"{aim:{sign}.{d}f}":
            return text
    return text


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Right-aligned columns, the first left-aligned; floats as given by the caller (pre-formatted strings)."""
    cells = [list(map(str, headers))] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = []
    for r in cells:
        lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    return "\n".join(lines)


def profile_call(fn: Callable[[], Any], top: int) -> str:
    """The `top` functions with the most own time while fn() runs (cProfile), as text."""
    import cProfile
    import io
    import pstats

    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(top)
    lines = [l for l in out.getvalue().splitlines() if l.strip()]
    start = next((i for i, l in enumerate(lines) if l.lstrip().startswith("ncalls")), 0)
    return "\n".join(lines[start:])
