"""`pursuit-mj train`: train pursuers with PPO or MAPPO (train/ package, imported lazily)."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from pursuit_mj.layout import is_index_text

from .common import counted, finite_float


def steps_arg(text: str) -> int:
    """An integer count that may be written 2e6 or 2_000_000."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of steps") from None
    if not math.isfinite(value) or value < 1 or value != int(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of steps >= 1")
    return int(value)


def minutes_arg(text: str) -> float:
    """A training time limit in minutes: finite, >= 0 (0: none)."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of minutes >= 0 (0: no limit)")
    return value


def register(sub) -> None:
    from pursuit_mj.config import preset_names

    presets = ", ".join(preset_names("train"))
    p = sub.add_parser(
        "train",
        allow_abbrev=False,  # scripts pass train flags on: --see 4 must not quietly be --seed 4
        help="train pursuers: PPO / MAPPO in the regimes classic, full_obs, fine_tune; imitation; residual",
        description="Train a shared pursuer policy. Settings: defaults <- --config files <- flags <- --set. "
        "Outputs go to <run.runs_dir>/<name>/: last.pt (every update), best.pt (best validation success), "
        f"metrics.jsonl, config.yaml. Presets (configs/train/): {presets}.",
        epilog="examples:\n"
        "  pursuit-mj train --config configs/train/full_obs.yaml\n"
        "  pursuit-mj train --config classic --set ppo.lr=1e-4 --set task.fidelity=point --total-steps 2e5\n"
        "  pursuit-mj train --config fine_tune --init-from runs/full_obs/best.pt\n"
        "  pursuit-mj train --resume runs/classic",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("-c", "--config", action="append", default=[], metavar="FILE|PRESET",
                   help=f"train YAML file or preset name ({presets}); repeatable, later wins")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override any train key, e.g. ppo.lr=1e-4, task.fidelity=point, run.validate_every=5")
    p.add_argument("--name", help="run name: its folder is <run.runs_dir>/<name> (runs/<name> by default)")
    p.add_argument("--total-steps", type=steps_arg, help="world decision steps to train for (e.g. 2e6)")
    p.add_argument("--max-minutes", type=minutes_arg, help="stop after this much training time (0 = no limit; the LR decays over whichever of it and --total-steps ends first)")
    p.add_argument("--n-envs", type=int, help="worlds stepped together")
    p.add_argument("--seed", type=int, help="seed of networks, sampling and episodes")
    p.add_argument("--fidelity", choices=("point", "quadrotor"), help="physics fidelity (task.fidelity)")
    p.add_argument("--layout", action="append", metavar="INDEX|FILE",
                   help="training layout; repeat for a list (one per world in turn)")
    p.add_argument("--random-layout", action="store_true", help="a random built-in layout per episode (with several --layout: one of those)")
    p.add_argument("--init-from", metavar="CHECKPOINT", help="start from this checkpoint's weights (key init_from; used by fine_tune, belief_ppo, finetune_ppo)")
    p.add_argument("--reward", action="append", metavar="FILE.py:NAME",
                   help="a reward term of your own: the function NAME in FILE, called every step with a StepView, paid "
                        "beside the task's terms and logged under NAME (docs/training.md); repeat for several (key rewards)")
    p.add_argument("--learnable-gamma", action="store_true", help="learn the discount by meta-gradient")
    p.add_argument("--resume", nargs="?", const=True, metavar="RUN_DIR",
                   help="continue the run in RUN_DIR (default: the configured run) from its last.pt")
    p.add_argument("--export", nargs=2, metavar=("CHECKPOINT", "OUT"),
                   help="write a small policy-only copy of CHECKPOINT (actor, config, spec) to OUT and exit")
    p.add_argument("--rerun", action="store_true", help="also stream the logged scalars to <run.runs_dir>/<name>/metrics.rrd (run.rerun); a resumed run rewrites it "
                        "from the whole metrics log first")
    bar = p.add_mutually_exclusive_group()
    bar.add_argument("--no-progress", action="store_true", help="no progress bar (logs still go to metrics.jsonl)")
    bar.add_argument("--progress", action="store_true", help="a progress bar (the default; on --resume, turns it back on "
                                                           "for a run started with --no-progress)")
    p.add_argument("-sc", "--show-config", action="store_true", help="print the resolved config and exit")
    p.set_defaults(func=run)


def _flags(args) -> dict:
    flags: dict = {}
    for key in ("name", "total_steps", "max_minutes", "n_envs", "seed", "init_from"):
        value = getattr(args, key)
        if value is not None:
            flags[key] = value
    task: dict = {}
    if args.fidelity:
        task["fidelity"] = args.fidelity
    if args.random_layout:
        task["random_layout"] = True
    if args.layout:
        refs = [int(x) if is_index_text(x) else x for x in args.layout]
        _check_loads(args.layout, refs)
        if len(refs) == 1 and args.random_layout:  # the env would draw from every built-in layout, ignoring it
            from pursuit_mj.layout import N_BUILTIN

            raise ValueError(f"--layout {args.layout[0]} with --random-layout: each episode's layout is drawn from the "
                             f"built-in 0-{N_BUILTIN - 1}, so --layout would be ignored; give one or the other, or "
                             f"several --layout to draw among them")
        if len(refs) == 1:
            task["layout"] = refs[0]
            flags["layouts"] = []
        else:
            flags["layouts"] = refs
    if task:
        flags["task"] = task
    if args.reward:
        from pursuit_mj.custom_rewards import load_reward_files

        load_reward_files(args.reward, "--reward")  # a bad file named by the flag, before anything starts
        flags["rewards"] = list(args.reward)
    if args.learnable_gamma:
        flags["ppo"] = {"learnable_gamma": True}
    if args.no_progress or args.progress:
        flags.setdefault("run", {})["progress"] = bool(args.progress)
    if args.rerun:
        flags.setdefault("run", {})["rerun"] = True
    return flags


def _check_loads(texts: list[str], refs: list) -> None:
    """Each --layout loaded once: ValueError naming the flag and the value of one that cannot be
    (a repeat is allowed: the list gives the worlds their layouts in turn)."""
    from pursuit_mj.layout import load_layout

    for text, ref in zip(texts, refs):
        try:
            load_layout(ref)
        except ValueError as exc:
            raise ValueError(f"--layout {text}: {exc}") from None


FLAG_KEYS = {"name": "--name", "total_steps": "--total-steps", "max_minutes": "--max-minutes", "n_envs": "--n-envs",
             "seed": "--seed", "init_from": "--init-from", "fidelity": "--fidelity"}  # attribute (and key) -> flag


def _load_naming_one_flag(args):
    """load_train_config of the command; an error of one flag's key names that flag alone, not
    every flag typed (which is all the config loader knows of where the flags' values came from)."""
    from train.config import load_train_config
    from .common import one_flag_named

    typed = _flags_typed(args)
    try:
        return load_train_config(args.config, args.overrides, _flags(args), typed)
    except ValueError as exc:
        given = {flag: getattr(args, key) for key, flag in FLAG_KEYS.items() if getattr(args, key) is not None}
        raise one_flag_named(exc, typed, given, FLAG_KEYS) from None


def _flags_typed(args) -> str:
    """The value-carrying flags given, as config errors name them (e.g. 'flag --seed -1')."""
    from .common import flags_typed

    pairs = [(flag, getattr(args, key)) for key, flag in FLAG_KEYS.items() if getattr(args, key) is not None]
    pairs += [("--layout", ref) for ref in args.layout or []]
    pairs += [("--reward", ref) for ref in args.reward or []]
    return flags_typed(pairs) if pairs else "command-line flag"


RESUMABLE_FLAGS = "--total-steps, --max-minutes, --no-progress, --progress, --rerun"


def _check_same(asked, stored) -> None:
    """Refuse a --resume whose config differs from the stored one in anything but the run length."""
    from pursuit_mj.configio import to_dict

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
        return out

    a, b = flat(to_dict(asked)), flat(to_dict(stored))
    # runs before 2026-12-07 stored init_from as typed: read from here, as the command that started them did
    for d in (a, b):
        if d.get("init_from"):
            d["init_from"] = os.path.abspath(d["init_from"])
    # task_file: its keys are compared one by one as task.*; runs before 2026-12-07 stored its path relative
    for key in ("total_steps", "max_minutes", "run.progress", "run.rerun", "name", "run.runs_dir", "task_file"):
        a.pop(key, None), b.pop(key, None)
    diff = [f"{k} {a.get(k)!r} (asked) vs {b.get(k)!r} (stored)" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    if diff:
        more = f" and {len(diff) - 4} more" if len(diff) > 4 else ""
        raise ValueError(f"--resume: the config differs from the stored run's: {'; '.join(diff[:4])}{more}. "
                         f"A run continues with its stored config: repeat the command that started it, or give the "
                         f"folder alone (--resume RUN_DIR); only {RESUMABLE_FLAGS} can change")


def _flag_key_sources(args) -> dict[str, str]:
    """The train keys the flags that a config check across keys names gave, as typed ('--init-from a.pt')."""
    given = {"init_from": f"--init-from {args.init_from}"} if args.init_from is not None else {}
    if args.learnable_gamma:
        given["ppo.learnable_gamma"] = "--learnable-gamma"
    return given


def _given(value) -> bool:
    """Whether a flag was given: its default is None, False or an empty list (a value of 0, which
    equals False, is given: --seed 0)."""
    return value is not None and value is not False and not (isinstance(value, (list, tuple)) and not value)


def _refuse_with_export(args) -> None:
    """--export only copies a checkpoint: a training flag beside it would be silently ignored."""
    given = [flag for flag, value in (("--config", args.config), ("--set", args.overrides), ("--name", args.name),
                                      ("--total-steps", args.total_steps), ("--max-minutes", args.max_minutes),
                                      ("--n-envs", args.n_envs), ("--seed", args.seed), ("--fidelity", args.fidelity),
                                      ("--layout", args.layout), ("--random-layout", args.random_layout),
                                      ("--init-from", args.init_from), ("--reward", args.reward),
                                      ("--learnable-gamma", args.learnable_gamma),
                                      ("--resume", args.resume), ("--rerun", args.rerun), ("-sc", args.show_config))
             if _given(value)]
    if given:
        raise ValueError(f"--export writes a policy-only copy and exits; {', '.join(given)} would be ignored: "
                         f"export in a command of its own")


def _resumable_given(args) -> set[str]:
    """The keys a resume may change (total_steps, max_minutes, run.progress, run.rerun) that this
    command gives, by flag or by --set: the run takes their resolved values, the others stay stored."""
    from pursuit_mj.configio import parse_override

    given = {".".join(parse_override(text, f"--set {text}")[0]) for text in args.overrides}
    for key, flag in (("total_steps", args.total_steps is not None), ("max_minutes", args.max_minutes is not None),
                      ("run.progress", args.no_progress or args.progress), ("run.rerun", args.rerun)):
        if flag:
            given.add(key)
    return given & {"total_steps", "max_minutes", "run.progress", "run.rerun"}


def _runs_inside(folder: Path, shown: int = 8) -> str:
    """'; it holds the runs a, b: give one, e.g. --resume folder/a' for a folder of run folders
    (runs/, which --resume was given instead of runs/NAME); '' when none in it has a last.pt."""
    try:
        names = sorted(p.name for p in folder.iterdir() if (p / "last.pt").is_file())
    except OSError:
        return ""
    if not names:
        return ""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return (f"; it holds the run{'s' if len(names) > 1 else ''} {', '.join(names[:shown])}{more}: give one, "
            f"e.g. --resume {folder / names[0]}")


def _progress(args) -> bool | None:
    """The progress bar a resume asks for: off, on, or as the run had it (None)."""
    return False if args.no_progress else (True if args.progress else None)


def run(args) -> int:
    """The train command. A run refused, or failed in its first update, leaves none of the folders it
    made (run.runs_dir=a/b: a/ and a/b/ too; io_utils.no_new_empty_folders, Trainer)."""
    from pursuit_mj.io_utils import no_new_empty_folders

    with no_new_empty_folders():
        return _run(args)


def _run(args) -> int:
    from pursuit_mj.configio import dump_yaml
    from train.config import key_sources_of, layout_key_sources
    from train.run_checks import best_instead
    from train.trainer import Trainer

    if args.export:
        from pursuit_mj.io_utils import check_writable, no_new_empty_folders

        _refuse_with_export(args)
        from train.checkpoint import export_actor, load_checkpoint

        if not Path(args.export[0]).is_file():  # before OUT's folder is made: a refused export leaves nothing
            load_checkpoint(args.export[0])  # names what is wrong with it (missing, a folder)
        if Path(args.export[1]).is_dir():
            raise ValueError(f"--export OUT {args.export[1]}: is a folder; give the file to write (e.g. {Path(args.export[1]) / 'policy.pt'})")
        with no_new_empty_folders():  # a checkpoint found unusable now leaves no folder made for OUT
            check_writable(args.export[1], "--export OUT")
            path = export_actor(*args.export)
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB, policy only)")
        return 0
    if args.resume not in (None, True):
        changed = [flag for flag, value in (("--config", args.config), ("--set", args.overrides), ("--name", args.name),
                                           ("--n-envs", args.n_envs), ("--seed", args.seed), ("--fidelity", args.fidelity),
                                           ("--layout", args.layout), ("--init-from", args.init_from),
                                           ("--reward", args.reward), ("--random-layout", args.random_layout),
                                           ("--learnable-gamma", args.learnable_gamma))
                   if _given(value)]
        if changed:
            raise ValueError(f"--resume {args.resume}: a run continues with its stored config; {', '.join(changed)} "
                             f"cannot change it (only {RESUMABLE_FLAGS} can)")
        if args.show_config:
            stored = Path(args.resume) / "config.yaml"
            raise ValueError(f"--resume {args.resume}: -sc/--show-config does not resume; the run's config is in "
                             f"{stored} (shown resolved by: pursuit-mj train --config {stored} -sc)")
        run_dir = Path(args.resume)
        if run_dir.suffix == ".pt":
            if run_dir.name != "last.pt":
                raise ValueError(f"--resume {args.resume}: a run resumes from its last.pt, not {run_dir.name}; "
                                 f"give the folder ({run_dir.parent}), or start a new run from it with --init-from")
            run_dir = run_dir.parent
        if run_dir.is_file():
            raise ValueError(f"--resume {args.resume}: a file, not a run folder; give its folder ({run_dir.parent}) "
                             f"if that is the run")
        if not run_dir.is_dir():
            raise ValueError(f"--resume {args.resume}: no such run folder")
        if not (run_dir / "last.pt").is_file():
            raise ValueError(f"--resume {args.resume}: no last.pt in {run_dir}{best_instead(run_dir) or _runs_inside(run_dir)}")
        trainer = Trainer.resume(run_dir, args.total_steps, max_minutes=args.max_minutes, progress=_progress(args),
                                 rerun=True if args.rerun else None)
    else:
        cfg = _load_naming_one_flag(args)
        if args.show_config and args.resume:
            raise ValueError(f"--resume: -sc/--show-config does not resume; the run's config is in "
                             f"{cfg.run_dir / 'config.yaml'}")
        sources = key_sources_of(args.overrides, _flag_key_sources(args))
        if args.show_config:
            cfg.check_complete(key_sources=sources)  # what training would refuse, -sc refuses too
            cfg.check_layouts(key_sources=layout_key_sources(args.overrides))
            cfg.check_code()
            print(dump_yaml(cfg), end="")
            return 0
        last = cfg.run_dir / "last.pt"
        if args.resume:
            if not last.is_file():
                named = ("" if args.config or args.name or best_instead(cfg.run_dir) else
                         f" (with no --config or --name, --resume continues the run named {cfg.name!r}, the default; "
                         f"give the run's folder instead: --resume {cfg.run.runs_dir}/NAME)")
                raise ValueError(f"--resume: no checkpoint {last} to continue from{best_instead(cfg.run_dir)}{named}")
            given = _resumable_given(args)
            trainer = Trainer.resume(cfg.run_dir, cfg.total_steps if "total_steps" in given else None,
                                     max_minutes=cfg.max_minutes if "max_minutes" in given else None,
                                     progress=cfg.run.progress if "run.progress" in given else None,
                                     check=lambda stored: _check_same(cfg.with_absolute_files(), stored),
                                     rerun=cfg.run.rerun if "run.rerun" in given else None)
        else:
            if last.exists():
                raise ValueError(f"run folder {cfg.run_dir} already has a checkpoint: continue it with --resume, "
                                 f"or start another run with --name")
            cfg.check_complete(key_sources=sources)  # Trainer would name no flag
            cfg.check_layouts(key_sources=layout_key_sources(args.overrides))
            trainer = Trainer(cfg)
    # SIGTERM stops it like Ctrl-C (pursuit_cli.termination_as_interrupt): the last finished update is kept
    seconds_before = trainer.counters.seconds  # a resumed run's counters hold its earlier sessions too
    stops = getattr(args, "stop_signals", [])
    result = trainer.train(stop_requested=lambda: bool(stops))
    from pursuit_mj.comparison import p_value_text
    from pursuit_mj.stats import percent_text

    c = result["counters"]
    earlier = f"; {c['seconds'] - seconds_before:.0f} s of it in this session" if seconds_before > 0 else ""
    print(f"{result['status']}: {counted(c['update'], 'update')}, {c['world_steps']} world steps, "
          f"{c['agent_steps']} agent steps, {counted(c['episodes'], 'episode')} in {c['seconds']:.0f} s "
          f"({c['seconds'] - c.get('validation_seconds', 0.0):.0f} s training, {c.get('validation_seconds', 0.0):.0f} s validating"
          f"{earlier})")
    if c["best_update"] >= 0:
        print(f"best validation success {percent_text(c['best_success'])} % (update {c['best_update']}): {Path(result['run_dir']) / 'best.pt'}")
    val = result["validation"]
    if "vs_heuristic_steps" in val:
        print(f"last validation ({counted(val['episodes'], 'fixed episode')}, {_validated_on(trainer.cfg)}): success {percent_text(val['success'])} %, {val['mean_steps']:.1f} mean steps; "
              f"the heuristic team {percent_text(val['heuristic_success'])} %, {val['heuristic_mean_steps']:.1f}; paired, "
              f"{val['vs_heuristic_steps']:+.1f} "
              + ("[no interval: 1 episode]" if val["vs_heuristic_lo"] is None else
                 f"[{val['vs_heuristic_lo']:+.1f}, {val['vs_heuristic_hi']:+.1f}]") + " capture steps "
              "per episode (negative: sooner)"
              + (f"; caught by one side only: policy {val['vs_heuristic_only_policy']}, team {val['vs_heuristic_only_heuristic']} "
                 f"(McNemar p {p_value_text(val['vs_heuristic_success_p'])})" if "vs_heuristic_success_p" in val else ""))
    last = Path(result["run_dir"]) / "last.pt"
    print(f"last checkpoint: {last}; metrics: {Path(result['run_dir']) / 'metrics.jsonl'}" if last.is_file()
          else f"no checkpoint yet in {result['run_dir']}")
    if result["status"] != "interrupted":
        return 0
    from . import stop_exit_code

    return stop_exit_code(stops[0] if stops else "SIGINT")


def _validated_on(cfg) -> str:
    """'point fidelity, layouts 1, 2': where a run's validation episodes are played (its task's
    fidelity; run.validation_layouts, else its training layouts, else task.layout), for the line
    that reports the last validation."""
    layouts = list(cfg.run.validation_layouts or cfg.layouts)
    if layouts:
        where = f"layout{'s' if len(layouts) > 1 else ''} {', '.join(str(r) for r in layouts)}"
    elif cfg.task.random_layout:
        where = "a built-in layout drawn per episode"
    else:
        where = f"layout {cfg.task.layout}"
    return f"{cfg.task.fidelity} fidelity, {where}"
