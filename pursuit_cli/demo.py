"""`pursuit-mj demo`: evaluate a trained policy (the shipped pretrained one by default; a model
trained without the safety shield is shown bare and behind it, one trained behind it, like the
shipped one, with it only) and the heuristic team on the four layouts.

Needs nothing trained: the model is pretrained/pursuers.pt (made by this project's training
pipeline, see pretrained/README.md). A few minutes on two cores with the default settings.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from pursuit_mj.shipped import shipped_dir
from .common import (ListFlag, add_task_args, check_episodes, counted, load_model, once_flag, refuse_a_python_file, seed_arg,
                     table_layouts, task_config_from_args, task_named)

PRETRAINED = shipped_dir("pretrained") / "pursuers.pt"
REFERENCE_EPISODES = 150  # episodes per layout in the reference study's table

HOW_TO_TRAIN = """\
Next steps:
  pursuit-mj train --config belief --set task.n_evaders=2        # DAgger with belief features (how the shipped pretrained/pursuers.pt was made)
  pursuit-mj train --config belief_ppo --set init_from=runs/belief/best.pt   # ... then PPO from it
  pursuit-mj demo --model pretrained/belppo_kick.pt              # PPO at issue 4's reference numbers (pretrained/README.md)
  pursuit-mj train --config imitate                              # DAgger from the heuristic team (a warm start)
  pursuit-mj train --config finetune_ppo --set init_from=runs/imitate/best.pt --set task.fidelity=quadrotor
  pursuit-mj train --config residual                             # PPO learns a correction to the heuristic team
  pursuit-mj train --config full_obs                             # the reference regimes (configs/train/): PPO from scratch
  pursuit-mj train --config fine_tune                            # ... then fine-tune it under partial observability
  pursuit-mj train --config classic --set task.fidelity=point    # faster physics, same actions
  pursuit-mj eval --model runs/fine_tune/best.pt --policy heuristic --layouts 0 1 2 3 --plots results/plots
  pursuit-mj study --budget-minutes 120                          # the whole reference experiment
"""


def register(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="evaluate the shipped pretrained policy and the heuristic team on layouts 0-3 (no training needed)",
        description="Runs a modest evaluation of a trained policy (default: the small pretrained one shipped in "
        "pretrained/) beside the hand-made heuristic team on the built-in layouts, prints the table and says how to train.",
    )
    p.add_argument("-m", "--model", default=str(PRETRAINED), action=once_flag("demo shows one model (eval takes several)"), help="checkpoint to show (default: pretrained/pursuers.pt)")
    p.add_argument("--episodes", type=int, default=16, help="episodes per policy and layout (default 16)")
    p.add_argument("--layouts", nargs="+", action=ListFlag, metavar="LAYOUT", help="layouts (default 0 1 2 3, or the one named by --layout)")
    p.add_argument("--worlds", type=int, default=16, help="parallel worlds (default 16)")
    p.add_argument("--seed", type=seed_arg, default=0, help="table seed")
    p.add_argument("--no-heuristic", action="store_true", help="evaluate the model only")
    p.add_argument("--no-shield", action="store_true",
                   help="for a model trained without the safety shield (pursuit_mj/shield.py), skip the extra row "
                        "of it behind the shield (shown by default beside the bare model, labelled NAME+shield). A "
                        "model trained behind the shield, like the shipped one, always runs with it")
    add_task_args(p)
    p.set_defaults(func=run)


def _shown(path: Path) -> str:
    """path relative to the working folder when it lies within it (pretrained/README.md in a checkout), else whole."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def run(args) -> int:
    from pursuit_mj.comparison import paired_report
    from pursuit_mj.evaluation import evaluate, format_table, table_heading
    from pursuit_mj.stats import percent_text
    from pursuit_mj.policies import make_policy

    check_episodes(args.episodes)
    if args.worlds < 1:
        raise ValueError(f"--worlds: expected an integer >= 1, got {args.worlds}")
    config = task_config_from_args(args)
    # a typo in the last layout must not cost the earlier ones' minutes
    layouts = table_layouts(args, config, default=["0", "1", "2", "3"])
    model = Path(args.model)
    refuse_a_python_file(args.model, "--model", takes_policy=False)  # demo has no --policy: eval's is named
    if not model.exists():
        raise ValueError(f"--model {model}: no such file (the pretrained policy ships as {_shown(PRETRAINED)})")
    policy = load_model(model, _spec(config), config, layouts=layouts)
    # the training run's name, as eval and render call it; the hand-made team keeps its own (the
    # paired table is keyed on it), a model trained as run 'heuristic' gets eval's label for a repeat
    name = f"{policy.name}#2" if policy.name == "heuristic" and not args.no_heuristic else policy.name
    policies = [(name, policy)]
    if getattr(policy, "has_shield", False):  # trained behind the shield: it comes with it (NAME+shield)
        if args.no_shield:
            print(f"demo: {model} was trained behind the safety shield and always runs with it; "
                  f"--no-shield has no extra row to skip", file=sys.stderr)
    elif not args.no_shield:
        from pursuit_mj.shield import shield_policy

        policies.append((f"{name}+shield", shield_policy(policy, config)))
    if not args.no_heuristic:
        policies.append(("heuristic", make_policy("heuristic", config)))
    print(f"demo: {counted(len(policies), 'policy', 'policies')} x {counted(len(layouts), 'layout')} x "
          f"{counted(args.episodes, 'episode')}, "
          f"{config.fidelity} fidelity, {config.n_pursuers} pursuers ({config.pursuer_speed} m/s) vs "
          f"{config.n_evaders} evader{'s' if config.n_evaders > 1 else ''} ({config.evader_speed} m/s), {config.observability} observability", file=sys.stderr)
    shipped = model.resolve() == PRETRAINED.resolve()
    print(f"model: {name} = {model}" + (" (the small policy shipped with the repository, nothing trained needed; "
          f"{_shown(PRETRAINED.parent / 'README.md')} gives the command that made it)" if shipped else ""), file=sys.stderr)
    rows = []
    t_all = time.perf_counter()
    for label, pol in policies:
        for ref in layouts:
            t0 = time.perf_counter()
            rows += evaluate(pol, config, [ref], args.episodes, args.seed, args.worlds, label=label)
            print(f"[demo] {label} layout {ref}: {time.perf_counter() - t0:.1f} s, success "
                  f"{percent_text(rows[-1].success.p)} %", file=sys.stderr, flush=True)  # as the table says it
    print(table_heading(rows, task_named(args)))
    print(format_table(rows))
    paired, _ = paired_report(rows, "heuristic", config.max_steps)
    if paired:
        print(f"\n{paired}")
    more = "" if args.episodes >= REFERENCE_EPISODES else f"; use --episodes {REFERENCE_EPISODES} for the reference study's sample size"
    print(f"\n({took(time.perf_counter() - t_all)}; brackets are 95 % confidence intervals{more})\n")
    print(HOW_TO_TRAIN, end="")
    return 0


def took(seconds: float) -> str:
    """A run's duration in whole seconds, 'under 1 s' below one (rounded, half a second read '0 s')."""
    return "under 1 s" if seconds < 1.0 else f"{seconds:.0f} s"


def _spec(config):
    from pursuit_mj.obs_spec import ObsSpec

    return ObsSpec.make(config.n_pursuers, config.n_evaders, config.n_rays)
