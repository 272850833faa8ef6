"""`pursuit-mj study`: the reference experiment end to end within a time budget (train/ imported lazily)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .common import (ListFlag, add_task_args, check_episodes, counted, checked_layouts, finite_float, seed_arg, task_config_from_args,
                     task_key_source, task_named)


MAX_BUDGET_MINUTES = 525600.0  # a year; far larger budgets overflowed the plan's seconds (1e308 min: an OverflowError)


def register(sub) -> None:
    p = sub.add_parser(
        "study",
        help="the whole reference experiment (full_obs, fine_tune, classic, MAPPO) and this project's recipes "
        "(imitate, imitate_ppo, residual, belief, belief_ppo) beside the heuristic team: table and charts",
        description="Train on layout 0, within one wall-clock budget: the reference study's four (full_obs, then "
        "fine_tune from it, classic, MAPPO) and this project's recipes (imitate, then imitate_ppo from it, residual, "
        "belief, then belief_ppo from it). Evaluate them and the heuristic team on the layouts, each paired with the "
        "team on the same episodes, and write the table (txt, csv, json), bar charts and timings into --out. "
        "Training runs in --train-fidelity (point by default: same actions, much faster); evaluation uses the "
        "task flags below (the reference task in quadrotor fidelity by default). Arms trained behind the safety "
        "shield are labelled NAME+shield; --train-set shield=true puts every arm behind it (without it the full_obs arm collided in about 90 % of its episodes; docs/training.md).",
        epilog="examples:\n  pursuit-mj study --budget-minutes 120 --episodes 150 --out runs/study\n"
               "  pursuit-mj study --budget-minutes 120 --train-set shield=true",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--budget-minutes", type=finite_float, required=True, help="wall-clock budget for everything (at most 525600, a year)")
    p.add_argument("--episodes", type=int, default=150, help="episodes per policy and layout (fewer if the budget is short)")
    p.add_argument("--layouts", nargs="+", action=ListFlag, default=["0", "1", "2", "3"], metavar="LAYOUT", help="evaluation layouts (default 0 1 2 3)")
    p.add_argument("--worlds", type=int, default=32, help="parallel worlds in evaluation")
    p.add_argument("--seed", type=seed_arg, default=0, help="evaluation table seed")
    p.add_argument("--out", default="runs/study", help="output folder (default runs/study)")
    p.add_argument("--train-fidelity", choices=("point", "quadrotor"), default="point", help="fidelity for training (default point)")
    p.add_argument("--train-set", dest="train_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a train key in every regime, e.g. n_envs=16 (repeatable; not name, run.runs_dir, "
                        "max_minutes or init_from, which the study sets for each arm)")
    p.add_argument("--resume", action="store_true",
                   help="continue the interrupted study in --out: finished arms and evaluations are kept, the interrupted one resumes "
                        "from its last checkpoint, the rest train; --budget-minutes is the time for what is left")
    add_task_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from train.study import STATE_FILE, StudyPlan, format_timings, run_study

    if args.budget_minutes <= 0:
        raise ValueError(f"--budget-minutes: expected a positive number, got {args.budget_minutes}")
    if args.budget_minutes > MAX_BUDGET_MINUTES:
        raise ValueError(f"--budget-minutes: must be at most {MAX_BUDGET_MINUTES:g} (a year), got {args.budget_minutes:g}")
    check_episodes(args.episodes)
    if args.worlds < 1:
        raise ValueError(f"--worlds: expected an integer >= 1, got {args.worlds}")
    if not args.task_files:
        args.task_files = ["reference"]
    task = task_config_from_args(args)
    named = [f"--set {o.strip()}" for o in args.overrides if o.split("=", 1)[0].strip() == "layout"]
    named = ([f"--layout {args.layout}"] if args.layout is not None else []) + named
    if named or task.layout != 0:  # it was accepted and ignored: every arm trains on 0, the table plays --layouts
        given = named[-1] if named else f"layout {task.layout} (from --task)"
        raise ValueError(f"{given}: the study trains every arm on layout 0 and evaluates on --layouts; give a layout "
                         f"to evaluate among --layouts (--layouts 0 1 2 3 FILE)")
    if task.random_layout:  # it was accepted and ignored: evaluation plays each of --layouts as a column of its own
        given = task_key_source(args, "random_layout") or "random_layout"
        raise ValueError(f"{given}: the task draws a layout per episode, and the study's table plays each layout as a "
                         f"column of its own; give them with --layouts 0 1 2 3 and leave random_layout out")
    layouts = tuple(checked_layouts(args.layouts))  # refused before any folder is made or any arm trains
    out = Path(args.out)
    plan = StudyPlan(
        budget_minutes=args.budget_minutes, out=out, eval_task=task, layouts=layouts, episodes=args.episodes,
        worlds=args.worlds, seed=args.seed,
        train_overrides=(f"task.fidelity={args.train_fidelity}", *args.train_overrides), resume=args.resume,
        eval_task_name=task_named(args),
    )
    stops = getattr(args, "stop_signals", [])  # a stop signal can surface as a library's own error
    try:
        result = run_study(plan, stop_requested=lambda: bool(stops))
    except (KeyboardInterrupt, Exception) as exc:
        if not (isinstance(exc, KeyboardInterrupt) or stops):
            raise
        if (out / STATE_FILE).is_file():
            print(f"[study] interrupted; the finished arms and evaluations are kept: continue with pursuit-mj study --resume "
                  f"--out {out} --budget-minutes M (the time for what is left) and the same task, --train-fidelity and "
                  f"--train-set flags", file=sys.stderr)
        else:  # stopped while it checked its arms' configs: a --resume would find no study to continue
            print(f"[study] interrupted before it kept anything in {out}: run the same command again to start", file=sys.stderr)
        if stops and not (isinstance(exc, KeyboardInterrupt) and exc.args):  # the run stopped itself on the signal
            raise KeyboardInterrupt(*([] if stops[-1] == "SIGINT" else [stops[-1]])) from None
        raise
    print((out / "table.txt").read_text(), end="")
    print(f"\n{counted(result['episodes'], 'episode')} per policy and layout; time per part:")
    print(format_timings(result["timings"], args.budget_minutes))
    print(f"table, charts and runs in {out}/")
    return 0
