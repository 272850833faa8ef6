"""`pursuit-mj bench train`: training throughput, rollout and update apart, against the bare env.

Imports the train package only when run (pursuit_mj itself never depends on it).
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from . import format_table

HELP = "training throughput: agent-steps/s of rollout and of update, time per update, vs the bare env"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="classic", help="train config file or preset (default classic)")
    p.add_argument("--fidelity", nargs="+", default=["point", "quadrotor"], choices=("point", "quadrotor"),
                   help="fidelities to measure (default both)")
    p.add_argument("--n-envs", type=int, default=None, help="worlds (default: the config's)")
    p.add_argument("--updates", type=int, default=3, help="measured updates after one warm-up (default 3)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="train config override")


def _bare_env(trainer, steps: int) -> float:
    """Agent-steps per second of the same env driven by uniform random actions."""
    env = trainer.env
    rng = np.random.default_rng(0)
    env.reset()
    shape = (env.n_worlds, env.n_pursuers, 2)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(-1.0, 1.0, shape))
    return steps * env.n_worlds * env.n_pursuers / (time.perf_counter() - t0)


def measure(config: str, fidelity: str, n_envs: int | None, updates: int, overrides: list[str]) -> dict:
    from train.config import load_train_config
    from train.trainer import Trainer

    if updates < 1:
        raise ValueError(f"--updates: expected an integer >= 1, got {updates}")
    with tempfile.TemporaryDirectory() as tmp:
        extra = [f"task.fidelity={fidelity}", f"run.runs_dir={tmp}", "run.progress=false", "run.validate_every=0"]
        if n_envs is not None:
            extra.append(f"n_envs={n_envs}")
        cfg = load_train_config([config], extra + list(overrides))
        trainer = Trainer(cfg, log=lambda s: None)
        trainer.train_one_update()  # warm-up: first forward/backward, allocator, caches
        rows = [trainer.train_one_update() for _ in range(updates)]
        env_rate = _bare_env(trainer, trainer.buffer.T)
    rollout_s = sum(r["rollout_s"] for r in rows)
    update_s = sum(r["update_s"] for r in rows)
    n = trainer.buffer.n_transitions * updates
    return {
        "fidelity": fidelity, "worlds": cfg.n_envs, "pursuers": cfg.task.n_pursuers, "batch": trainer.buffer.n_transitions,
        "rollout": n / rollout_s, "update": n / update_s, "update_s": update_s / updates,
        "train": n / (rollout_s + update_s), "env": env_rate,
    }


def run(args: argparse.Namespace) -> int:
    results = [measure(args.config, f, args.n_envs, args.updates, args.overrides) for f in args.fidelity]
    head = ["fidelity", "worlds x pursuers", "batch", "rollout ag-steps/s", "update ag-steps/s", "s per update",
            "training ag-steps/s", "bare env ag-steps/s", "env / training"]
    rows = [[r["fidelity"], f"{r['worlds']} x {r['pursuers']}", r["batch"], f"{r['rollout']:.0f}", f"{r['update']:.0f}",
             f"{r['update_s']:.2f}", f"{r['train']:.0f}", f"{r['env']:.0f}", f"{r['env'] / r['train']:.2f}x"] for r in results]
    print(format_table(head, rows))
    return 0
