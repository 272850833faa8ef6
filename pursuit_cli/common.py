"""Flags shared by subcommands: the task config (files, --set, the common task flags)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
from pathlib import Path
from typing import Any

from pursuit_mj.config import (SIMULATION_ONLY_TRAINED_KEYS, TRAINED_TASK_KEYS, TaskConfig, dump_yaml, load_task_config,
                               preset_or_file, task_differences)
from pursuit_mj.configio import ConfigError, load_yaml, parse_override
from pursuit_mj.layout import is_index_text


def seed_arg(text: str) -> int:
    """argparse type of --seed: an integer in 0 .. 2**63 - 1 (numpy's seeding refuses negative
    ones; episode seeds are int64, so a larger one failed deep in the run, after folders were made)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    if value >= 2**63:
        raise argparse.ArgumentTypeError(f"expected an integer below 2**63, got {value}")
    return value


def finite_float(text: str) -> float:
    """argparse type of a number flag: finite (nan and inf would slip past checks like `x <= 0`)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


class ListFlag(argparse.Action):
    """A flag of several values (nargs="+") whose lists add up when it is given again: argparse kept
    the last list alone, so `eval --layouts 0 --layouts 1` played layout 1 only, without a word,
    while --policy given twice counts both. A default list is replaced by the first list given."""

    def __call__(self, parser, namespace, values, option_string=None):
        current = getattr(namespace, self.dest, None)
        fresh = current is None or current is self.default
        setattr(namespace, self.dest, list(values) if fresh else [*current, *values])


def once_flag(why: str) -> type[argparse.Action]:
    """An argparse action for a flag the command takes once, where another command takes it
    several times (render -m a.pt -m b.pt rendered b.pt alone, as argparse keeps the last value):
    given twice, it is a usage error naming both values and `why` ('render plays one policy')."""
    class OnceFlag(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            before = getattr(namespace, self.dest, None)
            if before is not None and before is not self.default:
                raise argparse.ArgumentError(self, f"given twice ({before}, then {values}); {why}")
            setattr(namespace, self.dest, values)

    return OnceFlag


def path_arg(text: str) -> str:
    """argparse type of a file or folder flag: not empty (an empty path was taken as the current
    folder, or as no path at all, without a word)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"an empty path ({text!r}); give a path or leave the flag out")
    return text


MAX_EPISODES = 1_000_000  # per policy and layout; more would run for weeks (and listing their seeds alone takes minutes)


def check_out_prefix(prefix: str) -> None:
    """--out is a file name prefix: one that ends in a folder (tables/, tables/.) would write the
    hidden files tables/.csv and tables/.json; ValueError naming it and a prefix that would do."""
    if os.path.basename(prefix) in ("", ".", ".."):
        raise ValueError(f"--out {prefix}: names a folder, not a file name prefix (PREFIX.csv, PREFIX.json are "
                         f"written); give e.g. --out {os.path.normpath(os.path.join(prefix, 'table'))}")
    _refuse_a_stream_prefix(prefix)
    stem, ext = os.path.splitext(prefix)
    if ext.lower() in (".csv", ".json"):  # PREFIX.json.csv and PREFIX.json.json would be written
        raise ValueError(f"--out {prefix}: a file name prefix, to which .csv and .json are added ({prefix}.csv, "
                         f"{prefix}.json); give --out {stem}")


def _refuse_a_stream_prefix(prefix: str) -> None:
    """ValueError naming --out when the prefix is a device, a named pipe or a socket (links followed:
    /dev/null, /dev/stdout to a terminal), or lies in /dev itself (/dev/stdout to a file): the user
    means to write to it, and PREFIX.csv and PREFIX.json would be made beside it, among the devices.
    A regular file of that name is left as it is (PREFIX.csv is another file)."""
    import stat

    try:
        mode = os.stat(prefix).st_mode
    except OSError:  # not there (or unreadable): a prefix as any
        mode = 0
    kind = ("a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a named pipe" if stat.S_ISFIFO(mode)
            else "a socket" if stat.S_ISSOCK(mode) else None)
    written = f"--out writes PREFIX.csv and PREFIX.json ({prefix}.csv, {prefix}.json)"
    if kind is not None:
        raise ValueError(f"--out {prefix}: {kind}, not a file name prefix; {written}: leave --out out to write no "
                         f"table, or give a prefix in a folder of yours")
    if os.path.realpath(os.path.dirname(prefix) or ".") == os.path.realpath("/dev") and os.path.isdir("/dev"):
        raise ValueError(f"--out {prefix}: a prefix in /dev, the folder of devices; {written}: give a prefix in a "
                         f"folder of yours")


def pick_versus(flag: str | None, labels: list[str], where: str, add: str) -> str | None:
    """The policy label the others of a table are paired against: --versus `flag`, else heuristic
    when others are there too; None for 'none'. ValueError when the flag names no policy of
    `where` (e.g. "this table"), or the only one; `add` says how to add another."""
    if flag is None:
        return "heuristic" if "heuristic" in labels and len(labels) > 1 else None
    if flag == "none":
        return None
    if flag not in labels:
        raise ValueError(f"--versus {flag!r}: not a policy of {where} (policies: {', '.join(labels)})")
    if len(labels) == 1:
        raise ValueError(f"--versus {flag!r}: {where} has no other policy to pair with it; add one {add} "
                         "or leave --versus out")
    return flag


def check_episodes(episodes: int, flag: str = "--episodes") -> None:
    """ValueError naming `flag` unless 1 <= episodes <= MAX_EPISODES."""
    if not 1 <= episodes <= MAX_EPISODES:
        raise ValueError(f"{flag}: expected an integer in 1..{MAX_EPISODES:,}, got {episodes}")


def checked_layouts(refs: list[str], flag: str = "--layouts") -> list[int | str]:
    """Layout references from a CLI flag, each loaded once to refuse a bad one before any work,
    with digits read as built-in indices; the same layout given twice (0 and 00, a.yaml and
    ./a.yaml) is refused, since each layout is one column of a table."""
    from pursuit_mj.layout import load_layout, resolve_layout_ref

    layouts: list[int | str] = []
    seen: dict = {}
    for text in refs:
        ref = int(text) if is_index_text(text) else text
        try:
            load_layout(ref)
        except ValueError as exc:
            raise ValueError(f"{flag}: {exc}") from None
        where = resolve_layout_ref(ref).resolve()
        if where in seen:
            raise ValueError(f"{flag}: {text} is given twice (as {seen[where]} and {text}); each layout is one "
                             f"column of the table")
        seen[where] = text
        layouts.append(ref)
    return layouts


def table_layouts(args: argparse.Namespace, config: TaskConfig, default: list[str] | None = None) -> list[int | str]:
    """The layouts of a table (eval, demo), each one column: --layouts, else the layout named by
    --layout or --set layout=, else `default` (None: the task's layout), checked as
    `checked_layouts` does. ValueError when --layouts and a single layout are both named (one
    would be ignored), or when the task draws a layout per episode (random_layout), which a
    table of one layout per column does not play."""
    if config.random_layout:
        raise ValueError("random_layout: the task draws a layout per episode, and a table plays each layout as a "
                         "column of its own; give them with --layouts 0 1 2 3 and leave random_layout out")
    named = [f"--set {o.strip()}" for o in args.overrides if o.split("=", 1)[0].strip() == "layout"]
    named = ([f"--layout {args.layout}"] if args.layout is not None else []) + named
    if args.layouts and named:
        raise ValueError(f"{named[-1]} beside --layouts {' '.join(args.layouts)}: the table's layouts are --layouts; "
                         "leave the single layout out (or give it among --layouts)")
    if args.layouts:
        return checked_layouts(args.layouts)
    return [config.layout] if named or default is None else checked_layouts(default)

class StoreAsTyped(argparse.Action):
    """Store the value, and remember the flag as typed in `typed_flags` (dest -> option string), so a
    refusal names the spelling the user wrote (`--r_velocity`, not its synonym `--pursuer-speed`)."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, values)
        namespace.typed_flags = {**(getattr(namespace, "typed_flags", None) or {}), self.dest: option_string}



def add_task_args(p: argparse.ArgumentParser) -> None:
    """Task config flags. Speeds and radii in m and m/s (the reference study used mm)."""
    g = p.add_argument_group("task")
    g.add_argument("-ec", "--env-config", "--task", dest="task_files", action="append", default=[], metavar="FILE|PRESET",
                   help="task YAML file or preset name (reference, easy, hard); repeatable, later wins")
    g.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override any task key, e.g. --set evader.panic_distance=1.2 (repeatable)")
    g.add_argument("-i", "--layout", "--env-idx", dest="layout", help="layout index 0-3 or layout file", action=StoreAsTyped)
    g.add_argument("--fidelity", choices=("point", "quadrotor"), help="physics fidelity", action=StoreAsTyped)
    g.add_argument("--pursuers", type=int, dest="n_pursuers", help="number of pursuers", action=StoreAsTyped)
    g.add_argument("--evaders", type=int, dest="n_evaders", help="number of evaders", action=StoreAsTyped)
    g.add_argument("-rv", "--pursuer-speed", "--r-velocity", type=finite_float, dest="pursuer_speed", help="pursuer max speed (m/s)", action=StoreAsTyped)
    g.add_argument("-ev", "--evader-speed", "--e-velocity", type=finite_float, dest="evader_speed", help="evader speed (m/s; above 0.9 it brakes near walls and obstacles)", action=StoreAsTyped)
    g.add_argument("--perception-radius", "--r-perception", type=finite_float, dest="perception_radius", help="perception radius (m)", action=StoreAsTyped)
    g.add_argument("--random-obstacles", "--obstacle-num", type=int, dest="random_obstacles", help="random obstacles per episode (default: the layout file's random_obstacles.count)", action=StoreAsTyped)
    g.add_argument("--delta-t", "--control-dt", type=finite_float, dest="control_dt", help="decision interval (s)", action=StoreAsTyped)
    g.add_argument("--observability", choices=("partial", "full"), help="observability", action=StoreAsTyped)
    g.add_argument("-sc", "--show-config", action="store_true", help="print the resolved task config")
    # the reference study's run_sim.py spellings, accepted everywhere but not listed in --help
    hidden = argparse.SUPPRESS
    g.add_argument("--env_config", dest="task_files", action="append", help=hidden)
    g.add_argument("--show_config", dest="show_config", action="store_true", help=hidden)
    g.add_argument("--env_idx", dest="layout", help=hidden, action=StoreAsTyped)
    g.add_argument("--delta_t", dest="control_dt", type=finite_float, help=hidden, action=StoreAsTyped)
    g.add_argument("--r_velocity", dest="pursuer_speed", type=finite_float, help=hidden, action=StoreAsTyped)
    g.add_argument("--e_velocity", dest="evader_speed", type=finite_float, help=hidden, action=StoreAsTyped)
    g.add_argument("--r_perception", dest="perception_radius", type=finite_float, help=hidden, action=StoreAsTyped)
    g.add_argument("--obstacle_num", dest="random_obstacles", type=int, help=hidden, action=StoreAsTyped)


TASK_FLAG_NAMES = {"layout": "--layout", "fidelity": "--fidelity", "n_pursuers": "--pursuers", "n_evaders": "--evaders",
                   "pursuer_speed": "--pursuer-speed", "evader_speed": "--evader-speed",
                   "perception_radius": "--perception-radius", "random_obstacles": "--random-obstacles",
                   "control_dt": "--delta-t", "observability": "--observability"}
TASK_FLAG_KEYS = tuple(TASK_FLAG_NAMES)


def flags_typed(pairs) -> str:
    """How config errors name the flags given, e.g. 'flag --pursuers -2' or 'flags --pursuers -2 --fidelity point'."""
    typed = [f"{flag} {value}" for flag, value in pairs]
    return ("flag " if len(typed) == 1 else "flags ") + " ".join(typed)


def task_flags_given(args: argparse.Namespace) -> tuple[dict, dict]:
    """The task keys the command's flags gave -> their values (a layout index as int), and
    key -> the flag as the user typed it (its documented name where the spelling is unknown)."""
    typed = getattr(args, "typed_flags", None) or {}
    flags, names = {}, {}
    for key in TASK_FLAG_KEYS:
        value = getattr(args, key, None)
        if value is not None:
            flags[key] = int(value) if key == "layout" and is_index_text(value) else value
            names[key] = typed.get(key, TASK_FLAG_NAMES[key])
    return flags, names


# keys the reference study's run_sim.py took in millimetres (DESIGN.md section 7): SI unit here, its unit there
REFERENCE_STUDY_MM = {"pursuer_speed": ("m/s", "mm/s"), "evader_speed": ("m/s", "mm/s"), "perception_radius": ("m", "mm")}


def task_flag_error(exc: ValueError, typed: str, flags: dict, names: dict) -> ValueError:
    """`exc` of a task config loaded with `flags` (key -> value, named together as `typed`), naming
    the one flag it is about as typed (one_flag_named); a speed or radius out of range says its
    unit, since the reference study's users give them in millimetres."""
    error = one_flag_named(exc, typed, {names[k]: v for k, v in flags.items()}, {k: names.get(k, f) for k, f in TASK_FLAG_NAMES.items()})
    text = str(error)
    highest = {f.name: f.metadata.get("hi") for f in dataclasses.fields(TaskConfig)}
    for key, (unit, study_unit) in REFERENCE_STUDY_MM.items():
        value = flags.get(key)
        if value is not None and f"key '{key}': " in text and value >= 10 * highest[key] >= value / 1000:  # clearly mm
            return ValueError(f"{text}; {unit} here, where the reference study's run_sim.py took {study_unit} "
                              f"({value:g} {study_unit} is {value / 1000:g} {unit})")
    return error


def one_flag_named(exc: ValueError, typed: str, given: dict, flag_of: dict) -> ValueError:
    """`exc` of a config loaded with several flags (named together as `typed`, e.g. 'flags
    --seed -1 --name x'), naming only the flag of the key it is about when that key has one.
    given: flag -> value typed; flag_of: config key -> flag."""
    import re

    text = str(exc)
    # "key 'n_pursuers': ..." of one key, or a check across keys that starts with the one it is about
    found = re.match(re.escape(typed) + r": (?:key ')?(?:task\.)?(\w+)", text)
    flag = flag_of.get(found.group(1)) if found else None
    if flag is None or flag not in given or not typed.startswith("flags "):
        return exc
    return ValueError(flags_typed([(flag, given[flag])]) + text[len(typed):])


# task keys that a table's heading and columns name already (the fidelity, the layout of each row)
TABLE_NAMES = ("fidelity", "layout")


def task_named(args: argparse.Namespace, base: str = "") -> str:
    """How a table's heading names the task its rows ran in (evaluation.table_heading): 'task
    hard', 'task easy + mine.yaml' (task files and presets as given, the later winning), 'task
    reference' without any (the defaults are the reference preset's values), then 'with' the task
    flags given with their parsed values (`-rv 1.50` reads `-rv 1.5`) and the --set overrides as typed
    ('task hard with --pursuers 2, --set max_steps=5').
    Those of TABLE_NAMES are left out: the heading names the fidelity, the table each layout.
    `base` names the task the files apply on where it is not the defaults, first (render's -mc
    run: 'of -mc classic' gives 'task of -mc classic + hard')."""
    files = [base] if base else []
    files += list(getattr(args, "task_files", None) or []) or ([] if base else ["reference"])
    flags, names = task_flags_given(args)
    given = [f"{names[k]} {getattr(args, k)}" for k in flags if k not in TABLE_NAMES]
    given += [f"--set {o.strip()}" for o in getattr(args, "overrides", None) or []
              if o.split("=", 1)[0].strip() not in TABLE_NAMES]
    return f"task {' + '.join(files)}" + (f" with {', '.join(given)}" if given else "")


def task_config_from_args(args: argparse.Namespace) -> TaskConfig:
    """Resolve defaults <- task files <- flags <- --set, its evader model made once (check_evader_model),
    and print it if asked; a `note:` line on stderr names each setting the combination never reads
    (TaskConfig.idle_settings)."""
    flags, names = task_flags_given(args)
    typed = flags_typed((names[k], v) for k, v in flags.items())
    try:
        cfg = load_task_config(args.task_files, args.overrides, flags, typed)
    except ValueError as exc:
        raise task_flag_error(exc, typed, flags, names) from None
    check_evader_model(cfg, "evader.model")  # before -sc prints it: a config refused is not shown as the one run
    check_layout_given(args, cfg)
    for line in cfg.idle_settings():  # accepted (a preset sets them), but the run goes as without them
        print(f"note: {line}", file=sys.stderr)
    if getattr(args, "show_config", False):
        print(dump_yaml(cfg))
    return cfg


def check_layout_given(args: argparse.Namespace, config: TaskConfig) -> None:
    """The task's layout reference, when a flag or --set gave it, resolved now: ValueError naming
    that flag or --set for one that names no file or built-in layout (it was 'layout 'x.yaml': no
    such file ...', naming neither). A file that is there but malformed is named by its path where
    it loads; a task file's layout is found, or refused naming its file and key, as the file is read."""
    from pursuit_mj.layout import resolve_layout_ref

    source = task_key_source(args, "layout")
    if source is None or source.startswith("task file"):
        return
    try:
        resolve_layout_ref(config.layout)
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None


def check_evader_model(config: TaskConfig, source: str) -> None:
    """An evader model of one's own (evader.model FILE.py:NAME) made once, now: a missing file or an
    error in it is one line naming `source`, before any episode or output file."""
    from pursuit_mj.evader_models import make_evader_model
    from pursuit_mj.user_file import is_file_reference

    if is_file_reference(config.evader.model):
        make_evader_model(config, 1, 0, source)


_ANY = object()


def task_key_source(args: argparse.Namespace, key: str, value: Any = _ANY) -> str | None:
    """Where the task value of top-level `key` came from, as the user gave it: '--set KEY=V',
    the flag, or 'task file F' (the last that names it wins, as in task_config_from_args);
    None when it is the default or the command takes no task flags. Given `value`, None also
    where the source that wins gives another value (the value came from elsewhere: a study's
    --train-set, a model's own config)."""
    def gives(given: Any) -> bool:
        return value is _ANY or given == value

    for override in reversed(getattr(args, "overrides", None) or []):
        if override.split("=", 1)[0].strip() == key:
            try:
                given = parse_override(override, f"--set {override}")[1]
            except ConfigError:
                return None
            return f"--set {override.strip()}" if gives(given) else None
    flag = (getattr(args, "typed_flags", None) or {}).get(key) or TASK_FLAG_NAMES.get(key)  # as typed
    if flag is not None and getattr(args, key, None) is not None:
        return f"{flag} {getattr(args, key)}" if gives(getattr(args, key)) else None
    for file in reversed(getattr(args, "task_files", None) or []):
        path = preset_or_file(file, "task")
        data = load_yaml(path)
        if key in data:
            return f"task file {file}" if gives(data[key]) else None
    return None


def train_task_key_source(args: argparse.Namespace, key: str, value: Any) -> str | None:
    """Where a train override gave the task value of top-level `key` the value `value`: '--set
    task.KEY=V' of train, '--train-set task.KEY=V' of a study (the last that names it wins);
    None where none names it or the last gives another value."""
    flag, attribute = {"train": ("--set", "overrides"), "study": ("--train-set", "train_overrides")}.get(
        getattr(args, "command", None), (None, None))
    overrides = (getattr(args, attribute, None) or []) if attribute else []
    for override in reversed(overrides):
        if override.split("=", 1)[0].strip() == f"task.{key}":
            try:
                given = parse_override(override, f"{flag} {override}")[1]
            except ConfigError:
                return None
            return f"{flag} {override.strip()}" if given == value else None
    return None


SHIELD_HELP = ("put the safety shield on the policy (pursuit_mj/shield.py): from the pursuer's own observation it caps "
               "the speed toward walls, teammates and captured evaders; results are labelled NAME+shield. The heuristic "
               "team has the same shield built in and is left as is")


def add_shield_arg(p: argparse.ArgumentParser, help: str = SHIELD_HELP) -> None:
    p.add_argument("--shield", action="store_true", help=help)


def shield_if_asked(args: argparse.Namespace, policy, label: str, config: TaskConfig) -> tuple[object, str]:
    """(policy, label) behind a SafetyShield when --shield is given, unless it has one built in (the heuristic)."""
    from pursuit_mj.shield import shield_policy

    if not getattr(args, "shield", False):
        return policy, label
    wrapped = shield_policy(policy, config)
    return (policy, label) if wrapped is policy else (wrapped, f"{label}+shield")


def shield_each_if_asked(args: argparse.Namespace, chosen: list[tuple[object, str]], config: TaskConfig,
                         plays_one: str = "") -> list[tuple[object, str]]:
    """shield_if_asked on each (policy, label) of `chosen`, in order. ValueError naming --shield
    when it was given and every policy has the shield built in (the heuristic team, a model trained
    behind it): the run would be the one without the flag, which a user would take for a shielded
    one. The policies are named by their name, else their label. `plays_one` ('render plays one
    policy'), for a command that takes one policy, gives the advice to give another in its place;
    without it, the advice is eval's: the others given are shielded."""
    shielded = [shield_if_asked(args, policy, label, config) for policy, label in chosen]
    if getattr(args, "shield", False) and chosen and all(new is policy for (new, _), (policy, _) in zip(shielded, chosen)):
        kept = list(dict.fromkeys(getattr(policy, "name", label) for policy, label in chosen))
        advice = (f"leave it out, or give the policy to shield with --model or --policy ({plays_one})" if plays_one
                  else "leave it out (it shields the other --model and --policy given)")
        raise ValueError(f"--shield: {', '.join(kept)} {'has' if len(kept) == 1 else 'have'} the shield built in, so --shield "
                         f"changes nothing; {advice}")
    return shielded


def load_model(path, spec, task: TaskConfig, flag: str = "--model", flight: bool = False, layouts=None):
    """A trained policy for `task` via train.policy.load_policy (imported lazily: the library never
    needs torch); a model trained behind the safety shield comes back behind it. A note on stderr
    names the TRAINED_TASK_KEYS it learned with other values (for a `flight`, not the simulation-only ones;
    a key the checkpoint predates counts at its default), and, given the `layouts` the command plays,
    the layouts it trained on when it plays none of them."""
    from pathlib import Path

    if Path(path).is_dir():
        hint = next((f"; did you mean {Path(path) / n}?" for n in ("best.pt", "last.pt") if (Path(path) / n).is_file()), "")
        raise ValueError(f"{flag} {path}: a folder, not a checkpoint file{hint}")
    refuse_a_python_file(path, flag)
    if not Path(path).is_file():
        raise ValueError(f"{flag} {path}: no such checkpoint file")
    try:
        from train.policy import load_policy
    except ImportError as exc:
        raise ValueError(f"{flag} {path}: cannot load trained models, the train package is not importable ({exc})") from None
    policy = load_policy(path, spec, task=task)
    keys = [k for k in TRAINED_TASK_KEYS if not (flight and k in SIMULATION_ONLY_TRAINED_KEYS)]
    differ = [f"{k} {then} (this task: {now})" for k, then, now in task_differences(getattr(policy, "trained_task", {}), task, keys)]
    if differ:  # legitimate (the study judges full_obs under partial observability), but worth knowing
        print(f"note: {flag} {path} was trained with {', '.join(differ)}", file=sys.stderr)
    if layouts is not None:
        note_layouts_not_trained_on(f"{flag} {path}", getattr(policy, "trained_layouts", None), layouts)
    return policy


def _layout_key(ref) -> str:
    """What a layout reference names, for telling whether two name the same layout: a built-in's
    index, else the file's real path (a relative path from the current folder)."""
    from pursuit_mj.evaluation import layout_identity

    ident = layout_identity(ref)
    return ident if is_index_text(ident) else os.path.realpath(ident)


def note_layouts_not_trained_on(what: str, trained, played) -> None:
    """A note on stderr when none of the `played` layouts (indices or files) is one of the layouts
    `trained` on (None: not known, no note): the model plays arenas it never met, which may be
    meant (a test of generalisation) or not (a layout left out, so the task's layout 0 is played)."""
    if not trained:
        return
    if {_layout_key(r) for r in trained} & {_layout_key(r) for r in played}:
        return
    def listed(refs) -> str:
        return f"layout{'s' if len(refs) > 1 else ''} {', '.join(str(r) for r in refs)}"
    print(f"note: {what} was trained on {listed(list(trained))}, which this run does not play ({listed(list(played))})",
          file=sys.stderr)


def refuse_a_python_file(given, flag: str = "--model", takes_policy: bool = True) -> None:
    """ValueError naming `flag` when `given` is a Python file (FILE.py or FILE.py:NAME of an existing
    file) where a checkpoint goes, saying how a policy of one's own is played: by --policy, or, where
    the command has none (`takes_policy` False: demo), by eval's."""
    python_file = _python_file_of(str(given))
    if python_file is None:
        return
    how = (f"goes through --policy {python_file}:NAME" if takes_policy else
           f"is played beside the heuristic team by eval: pursuit-mj eval --policy {python_file}:NAME --policy heuristic")
    raise ValueError(f"{flag} {given}: a Python file, not a checkpoint; a policy of your own {how} (docs/env_api.md)")


def _python_file_of(given: str) -> str | None:
    """The Python file a --model value names, FILE.py or FILE.py:NAME of an existing file (a policy
    file given where a checkpoint goes), else None."""
    from pathlib import Path

    from pursuit_mj.user_file import is_file_reference, split_reference

    file = split_reference(given, "--model")[0] if is_file_reference(given) else given
    return file if file.endswith(".py") and Path(file).is_file() else None


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """'1 update', '2 updates' (`plural` for nouns that do not take an s: policy, policies)."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def sweep_dead_parts(folder, flag: str) -> None:
    """Remove, and say so, the temporary files that writes killed mid-file left in the output folder
    `folder` of `flag` (io_utils.remove_dead_parts_in: each as large as the file it was to become)."""
    from pursuit_mj.io_utils import DEAD_PART_AGE, remove_dead_parts_in

    removed = remove_dead_parts_in(folder)
    if removed:
        print(f"note: {flag}: removed {counted(len(removed), 'temporary file')} of writes cut short (their process is gone, "
              f"untouched for {DEAD_PART_AGE / 60:.0f} min or more) in {folder}: {', '.join(p.name for p in removed)}",
              file=sys.stderr)


def refuse_a_file_given_twice(flag: str, given: list[tuple[str, Path]]) -> None:
    """ValueError naming the second of two `flag` values (text as typed, path it reads; flag "" for
    a positional argument) that read one file: a run folder is its metrics.jsonl, and other names
    of a file (./x, a/../a/x) are that file. The same log twice would be drawn as two runs, the
    same table twice as bars given twice, or pooled as two tables."""
    def named(typed: str) -> str:
        return f"{flag} {typed}" if flag else typed

    seen: dict[Path, str] = {}
    for text, path in given:
        target = path / "metrics.jsonl" if path.is_dir() else path
        try:
            key = target.resolve()
        except OSError:  # unreadable: the reader names it
            continue
        if key in seen:
            raise ValueError(f"{named(text)}: the same file as {named(seen[key])}, given twice")
        seen[key] = text


def refuse_writing_an_input(outputs: list[tuple[str, Path]], inputs: list[tuple[str, str | Path]], appends: bool = False) -> None:
    """ValueError naming the first output (flag as typed, path it writes) that is one of the files
    the command reads (`inputs`: what names it, e.g. '--model m.pt', and its path): a table
    written there would replace a checkpoint, a policy or layout file, or a table being pooled.
    An output replaced whole (io_utils.atomic_path: written beside, renamed onto its name) is the
    input when its name is the input's file (./x, a/../x, or the file an input's link reaches):
    an output that is itself a link to an input (symbolic or hard) has the link replaced and the
    input left whole. An output appended to (`appends`: fly --events) writes into whatever file
    its name reaches, so any name of the input's file counts. An input that does not exist is
    left to its reader."""
    read: dict[tuple, str] = {}
    for said, path in inputs:
        try:
            key = _file_key(Path(path).resolve(), appends) if Path(path).is_file() else None
        except OSError:  # a name too long, say: its reader names it
            key = None
        if key is not None:
            read.setdefault(key, said)
    for flag, path in outputs:
        key = _file_key(Path(path), appends)
        if key is not None and key in read:
            raise ValueError(f"{flag}: the same file as {read[key]}, which writing there would destroy; give another output name")


def _file_key(path: Path, appends: bool) -> tuple | None:
    """What a write to `path` changes: the file its name reaches when appended to (device and
    inode), else the name itself (its folder's device and inode, and the name); None where it
    cannot be told (not there, unreadable: its reader or writer says why)."""
    try:
        if appends:
            found = os.stat(path)
            return found.st_dev, found.st_ino
        folder = os.stat(path.parent)
        return folder.st_dev, folder.st_ino, path.name
    except OSError:
        return None


def is_table(head: bytes, whole: bool) -> bool:
    """Whether a file whose first bytes are `head` (all of it when `whole`) is an evaluation
    table: the CSV of eval, pool or study (its header starts policy,layout), or their JSON, an
    object with rows. A JSON too large to read here is told by its head, where the writers put
    the task config ahead of the rows (evaluation.write_json, indented by 2)."""
    import json

    if head.startswith(b"policy,layout,"):
        return True
    if not whole:
        return head.lstrip().startswith(b"{") and b'\n  "config": {' in head
    try:
        data = json.loads(head)
    except ValueError:  # UnicodeDecodeError too
        return False
    return isinstance(data, dict) and "rows" in data


def refuse_replacing_what_is_no_table(outputs: list[tuple[str, Path]]) -> None:
    """ValueError naming the first output (flag as typed, path) that exists, is not empty and is
    no evaluation table (is_table): the table would replace a file of the user's (eval --json
    notes.json). An earlier table under the name is replaced, as a run again is meant to. A
    multi-GB file is not read whole (io_utils.holds_another_kind)."""
    from pursuit_mj.io_utils import holds_another_kind

    for flag, path in outputs:
        if holds_another_kind(path, is_table, limit=1 << 20):
            raise ValueError(f"{flag} path {path}: exists and is not an evaluation table (the JSON or CSV that eval and pool "
                             f"write), which the table would replace; choose another file, or delete it first")


def task_input_files(args: argparse.Namespace, config: TaskConfig) -> list[tuple[str, str]]:
    """The files a command that plays the task reads, as (what names it, path): its --task files
    and the evaders' model file (presets and the built-in model are no files of the user's)."""
    from pursuit_mj.user_file import is_file_reference, split_reference

    files = [(f"--task {t}", t) for t in getattr(args, "task_files", [])]
    if is_file_reference(config.evader.model):
        files.append((f"evader.model {config.evader.model}", split_reference(config.evader.model, "evader.model")[0]))
    return files
