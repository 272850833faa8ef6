"""The `pursuit-mj` console command. Each subcommand lives in its own module of this package.

A subcommand module defines `register(subparsers)`, which adds its parser and sets
`func=run` on it; `run(args) -> int` does the work. Bad input raises ValueError (ConfigError,
LayoutError ...), which `main` prints as one clear line with exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import re
import select
import signal
import sys
import threading

#: subcommand modules, in the order `--help` lists them
SUBCOMMANDS = [
    "demo",
    "config_cmd",
    "layout_cmd",
    "simulate",
    "bench",
    "eval_cmd",
    "pool_cmd",
    "train_cmd",
    "study",
    "render_cmd",
    "plot_cmd",
    "fly_cmd",
]


#: negative numbers argparse takes for flags: it knows only -12 and -1.5 as numbers, not -1e5, -inf or nan
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*[eE][-+]?\d+|\.\d+[eE][-+]?\d+|inf|infinity|nan)$", re.IGNORECASE)
#: a point X,Y whose X is negative (layout new --points -1,0): argparse took it for an unknown flag
_NEGATIVE_POINT = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?,[^=\s]*$")


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse, with a usage error printed as one line (the usage block buried the message), and
    negative numbers like -1e-1 and -inf read as values, also among a flag's several values
    (`--box 1 2 0.2 0.2 -1e-1`) and as the X of a point (`--points -1,0`), so the flag's own
    check reports a bad one."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        self._given = list(sys.argv[1:] if args is None else args)  # for _check_value
        return super().parse_known_args(args, namespace)

    def _check_value(self, action, value):
        """A value that is no subcommand (or action: fly check | align) right after a flag this
        parser does not know is that flag's value ('fly --speed 2'), not a misspelt action: refused
        as the unknown flag, as refuse_unrecognized refuses one, not as "invalid choice: '2'"."""
        if isinstance(action, argparse._SubParsersAction) and value not in action.choices:
            given = getattr(self, "_given", [])
            stray = next((before for before, arg in zip(given, given[1:]) if arg == value and self._may_take_next(before)), None)
            if stray is not None:
                raise argparse.ArgumentError(None, f"unrecognized arguments: {stray} {value}" + unknown_flag_hint(self, stray))
        super()._check_value(action, value)

    def _may_take_next(self, arg: str) -> bool:
        """Whether `arg` is a flag this parser does not take (nor its abbreviation: '--virt' is
        --virtual) whose value could be the next argument: not one with its value after '=', nor a
        negative number (a value itself)."""
        parsed = self._parse_optional(arg)  # None: a value; else (action or None, ...) ([...] from Python 3.12)
        action = (parsed[0][0] if isinstance(parsed, list) else parsed[0]) if parsed else None
        return parsed is not None and action is None and "=" not in arg

    def _parse_optional(self, arg_string):
        if ((_NEGATIVE_NUMBER.match(arg_string) or _NEGATIVE_POINT.match(arg_string))
                and arg_string not in self._option_string_actions):
            return None  # a value, as argparse takes -12 (it would read -1e5 as an unknown flag, -inf as -i nf)
        return super()._parse_optional(arg_string)


class VersionAction(argparse.Action):
    """--version: this package's version and git commit, and the versions of the libraries that
    decide results (read from the installed metadata, nothing imported), for bug reports."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        import platform
        from importlib import metadata

        from pursuit_mj.provenance import provenance

        def version(dist: str) -> str:
            try:
                return metadata.version(dist)
            except metadata.PackageNotFoundError:
                return "not installed"

        p = provenance()
        if p["git_commit"] is None:
            where = "no git checkout"
        else:
            where = f"git {str(p['git_commit'])[:10]}" + (", with local changes" if p["git_dirty"] else "")
        libs = ", ".join(f"{d} {version(d)}" for d in ("mujoco", "numpy", "torch", "rerun-sdk", "cflib"))
        print(f"pursuit-mj {p['version'] or version('pursuit-mj')} ({where})\npython {platform.python_version()}, {libs}")
        parser.exit(0)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="pursuit-mj",
        description="Quadrotor pursuit-evasion in MuJoCo: layouts, physics, training, evaluation, rendering, flights.",
    )
    parser.add_argument("--version", action=VersionAction, help="show the version, git commit and library versions, and exit")
    sub = parser.add_subparsers(dest="command", metavar="<command>")
    sub.required = True
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # a subcommand still being written
            raise
        module.register(sub)
    return parser


def refuse_unrecognized(parser: argparse.ArgumentParser, args: argparse.Namespace, extras: list[str]) -> None:
    """Exit 2 naming `extras` (arguments no flag took) by the (sub)command they were given to, with
    a hint about the first unknown flag (unknown_flag_hint: '--layouts' -> '--layout'). Those
    given before a subcommand (`pursuit-mj --foo eval`, `bench --foo env`) are that parser's."""
    target = parser
    while True:  # down to the innermost command chosen: `layout show`, `bench env`, `fly check`
        sub = next((a for a in target._actions if isinstance(a, argparse._SubParsersAction)), None)
        chosen = getattr(args, sub.dest, None) if sub is not None else None
        if chosen not in (sub.choices if sub is not None else {}):
            break
        given = getattr(target, "_given", [])  # what this parser was given, its subcommand among it
        early = [e for e in extras if e in given[:given.index(chosen)]] if chosen in given else []
        if early:
            extras = early
            break
        target = sub.choices[chosen]
    unknown = [e.split("=", 1)[0] for e in extras if e.startswith("-")]
    target.error(f"unrecognized arguments: {' '.join(extras)}" + (unknown_flag_hint(target, unknown[0]) if unknown else ""))


def unknown_flag_hint(parser: argparse.ArgumentParser, flag: str) -> str:
    """What to say after 'unrecognized arguments: ...' about `flag`, which `parser` does not take:
    for a task flag of the other commands (any spelling, '-ev', '--delta_t'), the --set key that
    sets it there ('; -ev is a task flag, which train does not take: --set task.evader_speed=VALUE';
    task. where --set takes train keys, as beside --config), or that command's own spelling of it
    (train's --layout for -i); else the closest of its listed flags ('; did you mean --seed?');
    else ''. To a parser that needs a subcommand yet (pursuit-mj, bench, layout) the flag came
    before it: it says so."""
    import difflib

    from .common import TASK_FLAG_NAMES

    if any(isinstance(a, argparse._SubParsersAction) and a.required for a in parser._actions):
        return f"; give flags after the command ({parser.prog} COMMAND {flag} ...)"  # `pursuit-mj --layout 2 eval`
    options = parser._option_string_actions
    key = _task_flag_keys().get(flag)
    if key is not None:
        if TASK_FLAG_NAMES[key] in options:
            return f"; did you mean {TASK_FLAG_NAMES[key]}?"
        command = parser.prog.removeprefix("pursuit-mj ")
        if "--set" not in options:
            return f"; {flag} is a task flag, which {command} does not take"
        return f"; {flag} is a task flag, which {command} does not take: --set {'task.' if '--config' in options else ''}{key}=VALUE"
    listed = [s for action in parser._actions if action.help != argparse.SUPPRESS for s in action.option_strings]
    close = difflib.get_close_matches(flag, listed, n=1)
    return f"; did you mean {close[0]}?" if close else ""


def _task_flag_keys() -> dict[str, str]:
    """Every spelling of the common task flags (common.add_task_args, the reference study's hidden
    ones included) -> the task key it sets ('-ev' -> 'evader_speed')."""
    from .common import TASK_FLAG_KEYS, add_task_args

    scratch = argparse.ArgumentParser(add_help=False)
    add_task_args(scratch)
    return {s: a.dest for a in scratch._actions if a.dest in TASK_FLAG_KEYS for s in a.option_strings}


def mujoco_import_error() -> str | None:
    """Why `import mujoco` fails here, as one line naming MUJOCO_GL, or None when it imports.

    mujoco reads MUJOCO_GL as it is imported, and a value it rejects (or a backend whose
    library is missing) breaks every command, --help included, with a traceback."""
    try:
        import mujoco  # noqa: F401
    except Exception as exc:  # the GL loaders raise RuntimeError, ImportError, AttributeError ...
        value = os.environ.get("MUJOCO_GL")
        where = f"environment variable MUJOCO_GL={value!r}" if value is not None else "import mujoco"
        others = [b for b in ("egl", "osmesa") if b != (value or "").strip().lower()]  # not the one that failed
        return (f"{where}: mujoco cannot start with it ({type(exc).__name__}: {exc}); "
                f"set MUJOCO_GL to {' or '.join(others)}{' (whichever is installed)' if len(others) > 1 else ' if it is installed'}, "
                f"or unset it")
    return None


@contextlib.contextmanager
def termination_as_interrupt(stops: list[str] | None = None, then_ignore_ctrl_c: bool = False):
    """Within: SIGTERM and SIGHUP (kill, a closed terminal) stop a command as Ctrl-C does, so
    its half-written outputs are removed and its checkpoints saved the same way. Signals
    already handled or ignored (nohup) are left alone; off the main thread, nothing changes.
    Ctrl-C is taken too, only to append each stop signal's name (SIGINT for it) to `stops`:
    a library call can report the interrupt as its own error, and `main` then tells it apart.
    then_ignore_ctrl_c: on the way out, Ctrl-C is ignored rather than given back to Python's
    handler (the process is ending: a second Ctrl-C while it says so would only be a traceback)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    owner = os.getpid()
    stops = [] if stops is None else stops

    def raise_interrupt(signum, frame):
        if os.getpid() != owner:  # a forked worker (a pool's) inherits this: it must die as told
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        name = signal.Signals(signum).name
        stops.append(name)
        raise KeyboardInterrupt(*([] if signum == signal.SIGINT else [name]))  # Ctrl-C: Python's own, no name

    from pursuit_mj.io_utils import give_back_handlers  # (no mujoco: it imports the standard library alone)

    taken = {}
    try:  # a stop can land between any two of these steps: whatever was taken by then is given back
        for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None), signal.SIGINT):
            default = signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL
            if sig is not None and signal.getsignal(sig) == default:
                taken[sig] = default  # noted before it is replaced
                signal.signal(sig, raise_interrupt)
        yield
    finally:
        give_back_handlers({sig: signal.SIG_IGN if then_ignore_ctrl_c and sig == signal.SIGINT else previous
                            for sig, previous in taken.items()})


def main(argv: list[str] | None = None) -> int:
    """The `pursuit-mj` command: `argv` (default sys.argv[1:]) -> exit code."""
    code = 1
    # the process itself (not a caller in Python) ends with the command: a Ctrl-C once the command
    # has ended (while it says so, during Python's exit) is ignored; handlers would only print a traceback
    whole_process = argv is None and threading.current_thread() is threading.main_thread()
    try:
        code = _run(argv, whole_process)
        return code
    finally:
        from pursuit_mj.io_utils import interrupt_handled

        # whatever interrupt came, the code says so (or argparse's exit, --help or a bad flag, which
        # leaves main as SystemExit, does): the process must not end by SIGINT
        interrupt_handled()
        if whole_process:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            _exit_past_a_dead_rerun_writer(code)


def _exit_past_a_dead_rerun_writer(code: int) -> None:
    """End the process at once (os._exit) when a rerun recording of it failed to write (a full
    disk): rerun's shutdown at exit would wait on that recording's dead writer forever, deaf to
    Ctrl-C (pursuit_mj/recording/unfinished.py). Whatever the command wrote is closed by then."""
    unfinished = sys.modules.get("pursuit_mj.recording.unfinished")
    if unfinished is None or not unfinished.any_failed():
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _run(argv: list[str] | None, whole_process: bool = False) -> int:
    """Start up (imports, arguments) and run the command, stop signals taken throughout
    (termination_as_interrupt): a Ctrl-C or kill at any moment is one line and 128 + its number."""
    stops: list[str] = []
    args = None
    try:  # the imports take a second or more: a Ctrl-C or kill meanwhile is a stop, not a crash
        with termination_as_interrupt(stops, then_ignore_ctrl_c=whole_process):
            broken = mujoco_import_error()
            if stops:  # mujoco's start-up reports an interrupt as its own ImportError
                raise KeyboardInterrupt(stops[0])
            if broken is not None:
                print(f"pursuit-mj: error: {broken}", file=sys.stderr)
                return 2
            parser = build_parser()
            argv = sys.argv[1:] if argv is None else list(argv)
            if not argv:  # a bare `pursuit-mj`: show what there is
                parser.print_help(sys.stderr)
                if stops:  # a usage error after a stop taken by an import: it stops the command, as below
                    raise KeyboardInterrupt(stops[0])
                return 2
            try:
                parsed, extras = parser.parse_known_args(argv)
                if extras:
                    refuse_unrecognized(parser, parsed, extras)
            except SystemExit:  # argparse's exit: --help, --version or a usage error (said already)
                if stops:  # a stop came meanwhile, its interrupt taken by an import for its own error: it stops
                    raise KeyboardInterrupt(stops[0]) from None  # the command, as anywhere else in start-up
                raise
            if stops:  # an interrupt that an import took for its own error: it still stops the command
                raise KeyboardInterrupt(stops[0])
            args = parsed
            args.stop_signals = stops  # read by commands that end gracefully on a stop (train)
            return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        if args is None:
            by = f" by {stops[0]}" if stops and stops[0] != "SIGINT" else ""
            print(f"pursuit-mj: interrupted{by} while starting", file=sys.stderr)
            return stop_exit_code(stops[0] if stops else "SIGINT")
        _tell_the_failure_under(exc, args)
        return _interrupted(args, str(exc.args[0]) if exc.args else "")
    except BrokenPipeError as exc:
        if args is None:
            raise
        if _stdout_is_broken():  # output piped into `head` and the like: the reader has all it wanted
            sys.stderr.close()  # (and no word about the output Python cannot flush at exit)
            return 0
        # another pipe or socket (an encoder's, a link's) closed under the command: a failure
        print(f"pursuit-mj {_command_name(args)}: error: {exc} {_where(exc)} (a pipe or socket other than the "
              "standard output closed: the process or peer reading it ended)", file=sys.stderr)
        return 1
    except Exception as exc:
        if args is None:
            raise
        if stops:  # the interrupt raised inside a library call, which reported it as its own error (pybind11: TypeError)
            return _interrupted(args, stops[0])
        if isinstance(exc, OSError) and exc.errno == errno.ENAMETOOLONG and exc.filename:
            # a name the user gave (or one made from it) that no file system here can hold: bad input
            print(f"pursuit-mj {_command_name(args)}: error: {exc.filename}: {exc.strerror}", file=sys.stderr)
            return 2
        if not isinstance(exc, ValueError):
            raise
        print(f"pursuit-mj {_command_name(args)}: error: {_with_source(exc, args)}", file=sys.stderr)
        return 2


def _with_source(exc: ValueError, args: argparse.Namespace) -> str:
    """The error's message, naming the flag or task file that gave a task value it refuses."""
    from pursuit_mj.configio import TaskValueError

    if not isinstance(exc, TaskValueError):
        return str(exc)
    from .common import task_key_source, train_task_key_source

    try:
        # the source of that value, not of another: a task flag or file, else a train key (task.KEY)
        source = task_key_source(args, exc.key, exc.value) or train_task_key_source(args, exc.key, exc.value)
    except (OSError, ValueError):  # a task file changed since it was read: the message as it is
        source = None
    if source is None:
        return str(exc)
    if source.startswith("task file"):
        return f"{source}: {exc.key} {exc.value}: {exc.reason}"
    return f"{source}: {exc.reason}"


def _command_name(args: argparse.Namespace) -> str:
    """The command as typed, e.g. 'layout show', as argparse's own errors say."""
    action = next((getattr(args, d) for d in ("layout_command", "bench_target", "fly_action") if getattr(args, d, None)), None)
    return " ".join(filter(None, (args.command, action)))


def _stdout_is_broken() -> bool:
    """Whether standard output's reader has gone (`| head` ended): flushing it fails with a broken
    pipe, or the system reports its descriptor in error (nothing left to flush). False for a
    BrokenPipeError of anything else while standard output is still read."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        return True
    except (OSError, ValueError, AttributeError):  # closed or replaced: ask the descriptor
        pass
    try:
        fd = sys.stdout.fileno()
    except (OSError, ValueError, AttributeError):
        return False
    if not hasattr(select, "poll"):  # Windows: the flush is all there is to go by
        return False
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    # a pipe's (or socket's) write end whose reader closed polls as in error (Linux) or hung up
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


def _where(exc: BaseException) -> str:
    """Where an exception was raised: the innermost line of this project's code, and the
    innermost of all when that is a library's, e.g. 'in pursuit_mj/render/video.py:N, add
    (raised in __init__.py:M, add_image)' (a library's file by its name only)."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return ""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

    def shown(f: traceback.FrameSummary) -> str:
        path = os.path.relpath(f.filename, root) if f.filename.startswith(root + os.sep) else os.path.basename(f.filename)
        return f"{path}:{f.lineno}, {f.name}"

    here = os.path.abspath(__file__)  # main's own frame, which called the command
    ours = [f for f in frames if f.filename.startswith(root + os.sep) and os.path.abspath(f.filename) != here]
    if ours and ours[-1] is not frames[-1]:
        return f"in {shown(ours[-1])} (raised in {shown(frames[-1])})"
    return f"in {shown(frames[-1])}"


def _tell_the_failure_under(stop: KeyboardInterrupt, args: argparse.Namespace) -> None:
    """Print, as an error line, the failure a stop was delivered over (its `__cause__`: a stop held
    by io_utils.stops_held while the block failed, a file that could not be written): without it
    the user would be told 'interrupted' alone."""
    failure = stop.__cause__
    if not isinstance(failure, Exception):
        return
    said = _with_source(failure, args) if isinstance(failure, ValueError) else f"{type(failure).__name__}: {failure}"
    print(f"pursuit-mj {_command_name(args)}: error: {said}", file=sys.stderr)


def _interrupted(args: argparse.Namespace, signal_name: str) -> int:
    """Say that the command was stopped (by SIGTERM/SIGHUP when one of them did it); returns its
    exit code (stop_exit_code)."""
    by = f" by {signal_name}" if signal_name.startswith("SIG") and signal_name != "SIGINT" else ""
    print(f"pursuit-mj {_command_name(args)}: interrupted{by}", file=sys.stderr)  # named as its errors name it
    return stop_exit_code(signal_name)


def stop_exit_code(signal_name: str) -> int:
    """The exit code of a command stopped by a signal, as a shell reports a process it ended:
    128 + its number (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP); 130 when no signal is named."""
    try:
        return 128 + signal.Signals[signal_name].value
    except KeyError:
        return 130


if __name__ == "__main__":
    sys.exit(main())
