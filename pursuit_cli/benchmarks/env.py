"""`pursuit-mj bench env`: the whole task environment against physics alone and the raw MuJoCo ceiling.

For each fidelity and world count, one fresh process builds a `PursuitEnv` of the task
(defaults, changed by --task/--set; layout 0 with its random obstacles, different in each
world) and alternates timed blocks of three kinds on the same worlds:
  - raw: `batch.step(nstep=substeps)` of the env's own MuJoCo batch (no Python per physics
    step): the ceiling;
  - physics: `BatchedPhysics.step(commands)`: physics + controller (+ contact read-out);
  - env: `PursuitEnv.step(actions)`: physics + controller + evader + sensing +
    observations + rewards + outcomes. Blocks are kept shorter than max_steps, so that
    resets are not in it (about 5 ms per episode start at 64 worlds, 2026-12-06); a block
    in which an episode still ended (a capture or collision) is counted and reported.
Pursuer commands are zero in all three (they hover; the evader flies in `env` only), so the
difference between env and physics is the task's own per-step work. Every block starts
from `env.reset()` with the same seed. Rates are from the fastest block of each kind (the
least disturbed by other work on the machine). Aim: the task adds at most 30 % on top of
physics at 64 worlds. --profile N prints the N functions with the most own time inside
`PursuitEnv.step` at the last configuration, to show where the time goes.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Sequence

import numpy as np

from ..common import finite_float, seed_arg
from pursuit_mj.config import TaskConfig, load_task_config
from pursuit_mj.env import check_task_layouts
from pursuit_mj.layout import load_layout
from . import UNRELIABLE, against_aim, check_common_args, format_table, given_task, peak_rss_mb, profile_call, run_isolated

HELP = "decision steps/s of the whole environment vs physics+controller and the raw MuJoCo ceiling"
BLOCK_SECONDS = 0.25  # wall time of one timed block
MAX_BLOCK_STEPS = 40  # decision steps per block at most
AIM_OVERHEAD = 0.30  # the task may add at most this fraction on top of physics at 64 worlds


@dataclasses.dataclass
class EnvBench:
    """One configuration: seconds per decision step of all worlds (fastest block of each kind)."""

    fidelity: str
    n_worlds: int
    n_pursuers: int
    raw_s: float
    physics_s: float
    env_s: float
    blocks: int
    peak_rss_mb: float
    profile: str = ""
    ended_blocks: int = 0  # env blocks in which an episode ended (its reset is then in the env time)

    @property
    def overhead(self) -> float:
        """The task's time on top of physics + controller, as a fraction of the latter."""
        return self.env_s / self.physics_s - 1.0


def add_arguments(p) -> None:
    p.add_argument("--worlds", nargs="+", type=int, default=[1, 16, 64], metavar="W", help="world counts, 1-4096 (default 1 16 64)")
    p.add_argument("--seconds", type=finite_float, default=4.0, help="measuring time per configuration, all kinds together (default 4, at most 3600)")
    p.add_argument("--fidelity", nargs="+", choices=("quadrotor", "point"), default=None,
                   help="fidelities (default: the one a --task file names, else both)")
    p.add_argument("--seed", type=seed_arg, default=0, help="environment seed (default 0)")
    p.add_argument("--task", dest="task_files", action="append", default=[], metavar="FILE|PRESET",
                   help="task YAML file or preset name (reference, easy, hard); repeatable")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a task setting, e.g. --set n_rays=32 (repeatable)")
    p.add_argument("--profile", type=int, default=0, metavar="N",
                   help="print the N functions with the most own time in env.step at the last configuration")


def task_config(fidelity: str, files: Sequence[str] = (), overrides: Sequence[str] = ()) -> TaskConfig:
    config = load_task_config(files, overrides, {"fidelity": fidelity})
    if config.fidelity != fidelity:
        raise ValueError(f"--set fidelity={config.fidelity}: this benchmark measures the fidelities given by --fidelity; "
                         f"use --fidelity {config.fidelity}")
    return config


def measure(fidelity: str, n_worlds: int, seconds: float, seed: int, files: Sequence[str],
            overrides: Sequence[str], profile_top: int = 0) -> EnvBench:
    """Time raw, physics and env stepping of one configuration in alternating blocks."""
    from pursuit_mj.env import PursuitEnv

    config = task_config(fidelity, files, overrides)
    env = PursuitEnv(config, n_worlds=n_worlds, seed=seed)
    physics = env.physics
    commands = np.zeros((n_worlds, physics.n_drones, 2))
    actions = np.zeros((n_worlds, config.n_pursuers, 2))
    ended = [False]

    def env_step() -> None:
        _, _, terminated, truncated, _ = env.step(actions)
        ended[0] |= bool(np.any(terminated) or np.any(truncated))

    kinds = {
        "raw": lambda: physics.batch.step(nstep=config.substeps),
        "physics": lambda: physics.step(commands),
        "env": env_step,
    }
    ended_blocks = 0

    def block(fn, n: int) -> float:
        nonlocal ended_blocks
        env.reset(seed=seed)
        ended[0] = False
        start = time.perf_counter()
        for _ in range(n):
            fn()
        seconds = (time.perf_counter() - start) / n
        ended_blocks += ended[0]
        return seconds

    first = block(kinds["env"], min(2, config.max_steps))  # also warms up
    ended_blocks = 0
    # a block ends before the time limit: its timeouts' resets would be timed as env work
    n = int(np.clip(round(BLOCK_SECONDS / first), 1, max(1, min(MAX_BLOCK_STEPS, config.max_steps - 1))))
    times: dict[str, list[float]] = {k: [block(fn, n)] for k, fn in kinds.items()}  # a first round sizes the rest
    per_round = n * sum(t[0] for t in times.values())
    rounds = max(2, int(round(seconds / per_round)))
    for _ in range(rounds - 1):
        for k, fn in kinds.items():
            times[k].append(block(fn, n))
    profile = ""
    if profile_top > 0:
        env.reset(seed=seed)
        profile = profile_call(lambda: [env.step(actions) for _ in range(max(n, 10))], profile_top)
    return EnvBench(fidelity, n_worlds, config.n_pursuers, min(times["raw"]), min(times["physics"]), min(times["env"]),
                    rounds, peak_rss_mb(), profile, ended_blocks)


def _row(r: EnvBench) -> list[str]:
    dec = {k: r.n_worlds / getattr(r, f"{k}_s") for k in ("raw", "physics", "env")}
    return [r.fidelity, str(r.n_worlds), f"{dec['raw']:,.0f}", f"{dec['physics']:,.0f}", f"{dec['env']:,.0f}",
            f"{dec['env'] * r.n_pursuers:,.0f}", f"{r.env_s * 1e3:.2f}", f"{100 * r.overhead:+.0f} %",
            f"{r.raw_s / r.env_s:.2f}", f"{r.peak_rss_mb:.0f}"]


def aim_line(r: EnvBench) -> str:
    """The verdict on the overhead aim for one configuration (64 worlds)."""
    if r.overhead < 0.0:  # the env steps the same physics and more: it cannot be faster
        return (f"aim {r.fidelity} at {r.n_worlds} worlds: task overhead over physics <= {100 * AIM_OVERHEAD:.0f} %: "
                f"{100 * r.overhead:+.0f} %, unreliable (below 0: the env does more work than physics; {UNRELIABLE})")
    verdict = "met" if r.overhead <= AIM_OVERHEAD else "NOT met"
    return (f"aim {r.fidelity} at {r.n_worlds} worlds: task overhead over physics <= {100 * AIM_OVERHEAD:.0f} %: "
            f"{against_aim(100 * r.overhead, 100 * AIM_OVERHEAD, 0, '+')} %, {verdict}")


def task_files_fidelity(files: Sequence[str]) -> str | None:
    """The fidelity the last of the task `files` (paths or preset names) that names one gives, else None."""
    from pursuit_mj.config import load_task_yaml, preset_or_file

    named = None
    for ref in files:
        data = load_task_yaml(preset_or_file(ref, "task"))
        if isinstance(data, dict) and "fidelity" in data:
            named = data["fidelity"]
    return named


def run(args) -> int:
    if args.fidelity is None:  # a default must not outrank a task file: files <- flags, as everywhere
        named = task_files_fidelity(args.task_files)
        if named is not None and named not in ("quadrotor", "point"):
            load_task_config(args.task_files)  # refuses it, naming the file
        args.fidelity = [named] if named is not None else ["quadrotor", "point"]
    check_common_args(args)
    if args.profile < 0:
        raise ValueError(f"--profile: must be >= 0, got {args.profile}")
    cfg = [task_config(f, args.task_files, args.overrides) for f in args.fidelity][0]  # refuses bad settings before any work
    check_task_layouts(cfg)  # and a team its layouts cannot hold, before the header (the env it measures would)
    arena = ("a built-in layout drawn per episode (random_layout)" if cfg.random_layout else
             f"layout {cfg.layout} with {cfg.random_obstacle_count(load_layout(cfg.layout))} random obstacles")
    print(f"env benchmark{given_task(args.task_files, args.overrides)}: {cfg.n_pursuers} pursuers + {cfg.n_evaders} evader(s) per world, {arena}, {cfg.observability} "
          f"observability, {cfg.n_rays} rays; a decision step is {cfg.control_dt:g} s = {cfg.substeps} physics steps")
    print("rates in decision steps/s summed over worlds (agent-steps/s = env x pursuers); raw = batch.step(nstep), "
          "physics = BatchedPhysics.step, env = PursuitEnv.step; fastest of alternating blocks; one process per configuration")
    headers = ["fidelity", "worlds", "raw dec/s", "physics dec/s", "env dec/s", "env agent-steps/s", "env ms/step",
               "task overhead", "env/raw", "peak RSS MiB"]
    results = []
    last = (args.fidelity[-1], args.worlds[-1])
    for fidelity in args.fidelity:
        for w in args.worlds:
            top = args.profile if (fidelity, w) == last else 0
            results.append(run_isolated(measure, fidelity, w, args.seconds, args.seed, args.task_files, args.overrides, top))
            r = results[-1]
            print(f"  measured {fidelity} x {w} worlds ({r.blocks} blocks of each kind)", flush=True)
            if r.ended_blocks:
                print(f"  note: an episode ended in {r.ended_blocks} of the {r.blocks} env blocks ({fidelity} x {w} "
                      f"worlds); their resets are in its env time, so it reads slower than the task's stepping alone",
                      flush=True)
    print(format_table(headers, [_row(r) for r in results]))
    for fidelity in args.fidelity:
        at64 = [r for r in results if r.fidelity == fidelity and r.n_worlds == 64]
        if at64:
            print(aim_line(at64[0]))
    if results and results[-1].profile:
        r = results[-1]
        print(f"\nwhere env.step spends its time ({r.fidelity}, {r.n_worlds} worlds; own time, cProfile):")
        print(r.profile)
    return 0
