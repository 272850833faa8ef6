"""`pursuit-mj bench physics`: the batched physics against the raw MuJoCo ceiling.

For each fidelity and world count, one fresh process builds a `BatchedPhysics` of the
default task (3 pursuers + 1 evader, changed by --set; layout 0 with its random obstacles, different in each
world) and alternates timed blocks of
  - raw: `batch.step(nstep=substeps)` with the controls left as they are (no Python per
    physics step): the most MuJoCo can do on this model, the ceiling;
  - ours: `BatchedPhysics.step(commands)` with the controller in the loop in quadrotor
    fidelity and the contacts read out.
Both do the same physical work: the drones hold their place (hover thrust held fixed in
raw, zero velocity commands through the whole controller in ours) away from walls, so
that the ratio is the cost of our per-step work alone, not of extra contacts.
Rates are from the fastest block of each kind (the least disturbed by other work on the
machine), summed over worlds; the ratio of the median blocks is shown beside. Each block
starts from a reset.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Sequence

import numpy as np

from ..common import finite_float, seed_arg
from pursuit_mj.config import TaskConfig, load_task_config
from pursuit_mj.layout import load_layout
from pursuit_mj.layout_check import check_spawn_capacity
from ..simulate import SPAWN_SEPARATION
from . import UNRELIABLE, against_aim, check_common_args, format_table, given_task, peak_rss_mb, run_isolated

HELP = "raw MuJoCo step rate (the ceiling) vs BatchedPhysics with the controller in the loop"
BLOCK_SECONDS = 0.2  # wall time of one timed block
MAX_BLOCK_STEPS = 40  # decision steps per block at most (4 s simulated)
#: DESIGN aim for the ratio ours/raw at 64 worlds
AIM = {"quadrotor": 0.70, "point": 0.50}
MAX_NTHREAD = 256  # as the train config's run.sim_threads; MuJoCo refused 2**31 and more with a TypeError traceback


@dataclasses.dataclass
class PhysicsBench:
    """One measured configuration: times in s per decision step of all worlds (fastest and
    median block), memory MiB."""

    fidelity: str
    n_worlds: int
    substeps: int
    raw_s: float
    ours_s: float
    raw_median_s: float
    ours_median_s: float
    blocks: int
    peak_rss_mb: float

    @property
    def ratio(self) -> float:
        return self.raw_s / self.ours_s

    @property
    def median_ratio(self) -> float:
        return self.raw_median_s / self.ours_median_s


def add_arguments(p) -> None:
    p.add_argument("--worlds", nargs="+", type=int, default=[1, 16, 64], metavar="W", help="world counts, 1-4096 (default 1 16 64)")
    p.add_argument("--seconds", type=finite_float, default=3.0, help="measuring time per configuration, raw and ours together (default 3, at most 3600)")
    p.add_argument("--fidelity", nargs="+", choices=("quadrotor", "point"), default=["quadrotor", "point"], help="fidelities (default both)")
    p.add_argument("--nthread", type=int, default=0, help="MuJoCo batch threads, 0-256 (default 0: all CPUs)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the random obstacles and start positions (default 0)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="change a task setting from its default, e.g. --set controller_hz=250 (repeatable)")


def task_config(fidelity: str, overrides: Sequence[str] = ()) -> TaskConfig:
    """The default task in `fidelity`, with --set overrides."""
    config = load_task_config([], overrides, {"fidelity": fidelity})
    if config.random_layout:
        raise ValueError("--set random_layout=true: this benchmark steps one layout (--set layout=...); "
                         "`pursuit-mj bench env` plays random layouts")
    if config.fidelity != fidelity:
        raise ValueError(f"--set fidelity={config.fidelity}: this benchmark measures the fidelities given by --fidelity; "
                         f"use --fidelity {config.fidelity}")
    return config


def measuring_rounds(seconds: float, n: int, ours_s: float, raw_s: float) -> int:
    """Rounds of one block of n steps each way (ours_s and raw_s s per step) that fill `seconds`
    (at least 2). Sizing them by ours alone, twice, measured for less than asked: raw is faster."""
    return max(2, int(round(seconds / (n * (ours_s + raw_s)))))


def measure(fidelity: str, n_worlds: int, seconds: float, nthread: int = 0, seed: int = 0, overrides: Sequence[str] = ()) -> PhysicsBench:
    """Time raw and controlled stepping of one configuration in alternating blocks."""
    from ..simulate import spawn_positions
    from pursuit_mj.physics import BatchedPhysics

    config = task_config(fidelity, overrides)
    rng = np.random.default_rng(seed)
    base = load_layout(config.layout)
    given = None if config.random_obstacles is None else f"the task's random_obstacles (now {config.random_obstacles})"
    layouts = [base.with_random_obstacles(rng, config.random_obstacles, count_source=given) for _ in range(n_worlds)]
    physics = BatchedPhysics(config, layouts, nthread=nthread)
    worlds = np.arange(n_worlds)
    xy = np.stack([spawn_positions(l, config.n_pursuers, config.n_evaders, rng) for l in layouts])
    cmd = np.zeros((n_worlds, physics.n_drones, 2))

    def ours() -> None:
        physics.step(cmd)

    def raw() -> None:
        physics.batch.step(nstep=config.substeps)

    def block(fn, n: int) -> float:
        physics.reset(worlds, xy)
        start = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - start) / n

    block(ours, 2), block(raw, 2)  # warm-up
    first_ours, first_raw = block(ours, 2), block(raw, 2)
    n = int(np.clip(round(BLOCK_SECONDS / first_ours), 1, MAX_BLOCK_STEPS))
    rounds = measuring_rounds(seconds, n, first_ours, first_raw)
    t_ours, t_raw = [], []
    for _ in range(rounds):
        t_ours.append(block(ours, n))
        t_raw.append(block(raw, n))
    return PhysicsBench(fidelity, n_worlds, config.substeps, min(t_raw), min(t_ours), float(np.median(t_raw)),
                        float(np.median(t_ours)), rounds, peak_rss_mb())


def _row(r: PhysicsBench) -> list[str]:
    dec_raw, dec_ours = r.n_worlds / r.raw_s, r.n_worlds / r.ours_s
    return [r.fidelity, str(r.n_worlds), f"{dec_raw * r.substeps:,.0f}", f"{dec_ours * r.substeps:,.0f}",
            f"{dec_raw:,.0f}", f"{dec_ours:,.0f}", f"{r.ratio:.2f}", f"{r.median_ratio:.2f}", f"{r.peak_rss_mb:.0f}"]


def aim_line(r: PhysicsBench) -> str:
    """The verdict on the ours/raw aim for one configuration (64 worlds)."""
    aim = AIM[r.fidelity]
    if r.ratio > 1.0:  # ours steps the same MuJoCo batch and more: it cannot be faster
        return (f"aim {r.fidelity} at {r.n_worlds} worlds: ours/raw >= {aim:.2f}: {r.ratio:.2f}, unreliable (above 1: "
                f"ours does more work than raw; {UNRELIABLE})")
    verdict = "met" if r.ratio >= aim else "NOT met"
    return f"aim {r.fidelity} at {r.n_worlds} worlds: ours/raw >= {aim:.2f}: {against_aim(r.ratio, aim, 2)}, {verdict}"


def run(args) -> int:
    check_common_args(args)
    if not 0 <= args.nthread <= MAX_NTHREAD:
        raise ValueError(f"--nthread: must be in 0..{MAX_NTHREAD}, got {args.nthread}")
    cfg = [task_config(f, args.overrides) for f in args.fidelity][0]  # refuses bad --set values before any work
    # and a team the layout's spawn regions cannot hold (as spawn_positions would), before the header
    check_spawn_capacity(load_layout(cfg.layout), cfg.n_pursuers, cfg.n_evaders, SPAWN_SEPARATION)
    print(f"physics benchmark{given_task([], args.overrides)}: {cfg.n_pursuers} pursuers + {cfg.n_evaders} evader(s) per world, layout {cfg.layout} with "
          f"{cfg.random_obstacle_count(load_layout(cfg.layout))} random obstacles per world; a decision step is control_dt {cfg.control_dt:g} s = "
          f"{cfg.substeps} physics steps of {cfg.physics_dt:g} s; controller {cfg.controller_hz:g} Hz")
    print("rates summed over worlds; raw = batch.step(nstep) with fixed controls, ours = BatchedPhysics.step; fastest of "
          "alternating blocks (ratio of the median blocks beside); each configuration in its own process (peak RSS is its own)")
    headers = ["fidelity", "worlds", "raw phys steps/s", "ours phys steps/s", "raw dec/s", "ours dec/s", "ours/raw", "(median)", "peak RSS MiB"]
    results = []
    for fidelity in args.fidelity:
        for w in args.worlds:
            results.append(run_isolated(measure, fidelity, w, args.seconds, args.nthread, args.seed, args.overrides))
            print(f"  measured {fidelity} x {w} worlds ({results[-1].blocks} blocks each)", flush=True)
    print(format_table(headers, [_row(r) for r in results]))
    for fidelity in args.fidelity:
        at64 = [r for r in results if r.fidelity == fidelity and r.n_worlds == 64]
        if at64:
            print(aim_line(at64[0]))
    return 0
