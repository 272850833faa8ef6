"""`pursuit-mj bench train`: training throughput, rollout and update apart, against the bare env.

For each fidelity, the command builds a `train.trainer.Trainer` from the train config (the
reference hyperparameters unless --set changes them), runs one warm-up update, then
`--updates` measured updates. A second env of the same task, reward terms (the run's
`rewards`, part of the task) and worlds (its own seed) steps as many decision steps as a
rollout with uniform random actions, the bare env rate: in turn, one such block after each update, so that both meet the machine in the same state
(on a shared machine wall time swings, and the ratio of paired blocks swings less than
either rate); with `run.overlap` a rollout worker runs beside the update, so the bare env
steps after training instead. Rates are agent-steps per second (decision steps x worlds x pursuers)
from the median times over the measured updates (wall clock); a training step is what the
run waits for: rollout + update in turn, about the longer of them with overlap. Aims
(issue 4): the update takes less time than the rollout it learns from, and training runs
within 2x of the bare env. On a shared machine wall time swings with other work; the CPU
ratio (process time of training, rollout worker included, over that of the bare env, per
agent-step) is steadier, and shows what overlap costs in work rather than in waiting.
Imports the train package only when run.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import tempfile
import time

import numpy as np

from ..common import counted
from . import against_aim, format_table, given_task, profile_call

HELP = "training throughput: agent-steps/s of rollout and of update, time per update, vs the bare env"
AIM_UPDATE_OVER_ROLLOUT = 1.0  # the update must take less time than the rollout
AIM_ENV_OVER_TRAINING = 2.0  # training at least half as fast as the bare env


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="classic", help="train config file or preset (default classic)")
    p.add_argument("--fidelity", nargs="+", default=["point", "quadrotor"], choices=("point", "quadrotor"),
                   help="fidelities to measure (default both)")
    p.add_argument("--n-envs", type=int, default=None, help="worlds (default: the config's)")
    p.add_argument("--updates", type=int, default=5, help="measured updates after one warm-up (default 5)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="train config override")
    p.add_argument("--collection", choices=("both", "in-turn", "overlapped"), default="both",
                   help="collect rollouts in turn with the update, overlapped with it in a child process "
                        "(run.overlap), or measure both (default)")
    p.add_argument("--profile", type=int, default=0, metavar="N",
                   help="also print the N functions with the most own time in one rollout and one update (cProfile)")


@dataclasses.dataclass
class TrainBench:
    """One fidelity: median seconds per update of each part, and CPU seconds in total."""

    fidelity: str
    collection: str  # "in turn" or "overlapped"
    worlds: int
    pursuers: int
    batch: int  # agent-steps (transitions) per update
    settings: str
    rollout_s: float
    update_s: float
    wall_s: float  # one training step as the run sees it: rollout + update, or the longer of them with overlap
    env_s: float  # bare env, the same number of decision steps as one rollout
    train_cpu_s: float
    env_cpu_s: float
    profile: str = ""
    update_threads: int = 1  # torch threads of the update (the rollout's forwards use one)
    split: bool = False  # the critic's half of the update ran in a child process with as many threads (run.split_update)

    @property
    def threads(self) -> str:
        return f"{self.update_threads} + {self.update_threads} (split)" if self.split else str(self.update_threads)

    def rate(self, seconds: float) -> float:
        return self.batch / seconds

    @property
    def update_over_rollout(self) -> float:
        return self.update_s / self.rollout_s

    @property
    def env_over_training(self) -> float:
        return self.wall_s / self.env_s

    @property
    def env_over_training_cpu(self) -> float:
        return self.train_cpu_s / self.env_cpu_s


def _bare_env_block(env, steps: int, rng: np.random.Generator) -> tuple[float, float]:
    """(wall s, CPU s) of `steps` decision steps of all worlds with uniform random actions."""
    shape = (env.n_worlds, env.n_pursuers, 2)
    actions = [rng.uniform(-1.0, 1.0, shape) for _ in range(steps)]
    w0, c0 = time.perf_counter(), time.process_time()
    for a in actions:
        env.step(a)
    return time.perf_counter() - w0, time.process_time() - c0


def _settings(cfg, trainer) -> str:
    p, im, buf = cfg.ppo, cfg.imitation, trainer.buffer
    learner = (f"DAgger: {im.grad_steps} gradient steps of minibatch {im.minibatch_size}" if cfg.algo == "dagger"
               else f"{cfg.algo.upper()}: epochs {p.epochs}, minibatch {p.minibatch_size}")
    return (f"{learner}, batch {buf.n_transitions} = {buf.T} steps x {buf.W} worlds x {buf.N} pursuers, "
            f"net {cfg.net.kind} {cfg.net.encoder_width}/{list(cfg.net.hidden)}")


def _child_cpu_s(pid: int | None) -> float:
    """CPU seconds used so far by a live child process (Linux /proc; 0 elsewhere or without one)."""
    if pid is None:
        return 0.0
    try:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def _watch_worker_cpu(worker) -> list[float]:
    """The rollout worker's CPU seconds (`_child_cpu_s`) read each time `worker.result` hands
    over a rollout, when it has just finished one and has not yet started the next: successive
    readings hold whole rollouts. Empty, and nothing watched, without a worker."""
    readings: list[float] = []
    if worker is None:
        return readings
    take = worker.result

    def result(model):
        out = take(model)
        readings.append(_child_cpu_s(worker.process.pid))
        return out

    worker.result = result
    return readings


def measure(config: str, fidelity: str, n_envs: int | None, updates: int, overrides: list[str], profile_top: int = 0) -> TrainBench:
    import torch

    from pursuit_mj.custom_rewards import load_reward_files
    from pursuit_mj.env import PursuitEnv
    from train.config import load_train_config
    from train.ppo import ppo_update, teacher_weight
    from train.rollout import make_collector
    from train.trainer import Trainer

    with tempfile.TemporaryDirectory() as tmp:
        extra = [f"task.fidelity={fidelity}", f"run.runs_dir={tmp}", "run.progress=false", "run.validate_every=0"]
        flags = {"n_envs": n_envs} if n_envs is not None else None  # a flag, so that an error names --n-envs
        cfg = load_train_config([config], extra + list(overrides), flags, f"--n-envs {n_envs}")
        trainer = Trainer(cfg, log=lambda s: None)
        # the bare env: the same task, reward terms and worlds, its own seed
        env = PursuitEnv(cfg.task, n_worlds=cfg.n_envs, seed=cfg.seed + 1, layouts=list(cfg.layouts) or None,
                         nthread=cfg.run.sim_threads, extra_rewards=load_reward_files(cfg.rewards, "rewards"))
        env.reset()
        rng = np.random.default_rng(0)
        _bare_env_block(env, 2, rng)
        bare, env_cpu = [], 0.0
        try:
            trainer.train_one_update()  # warm-up: first forward/backward, allocator, caches, the rollout worker
            # in turn, a bare-env block follows each update, so both see the machine as it is then
            # (their ratio is then steadier than either rate); with a rollout worker, which runs
            # beside the update, the bare env steps after training instead
            interleave = trainer.worker is None
            rollout, update, wall = [], [], []
            idle = _watch_worker_cpu(trainer.worker)
            critic_pid = trainer.critic_worker.process.pid if trainer.critic_worker is not None else None
            train_cpu = -_child_cpu_s(critic_pid)  # the critic's process works only inside updates
            for _ in range(updates):
                c0 = time.process_time()
                row = trainer.train_one_update()
                train_cpu += time.process_time() - c0
                rollout.append(row["rollout_s"])
                update.append(row["update_s"])
                wall.append(row["wall_s"])
                if interleave:
                    wall_s, cpu = _bare_env_block(env, trainer.buffer.T, rng)
                    bare.append(wall_s)
                    env_cpu += cpu
            train_cpu += _child_cpu_s(critic_pid)
            if trainer.worker is not None:
                c0 = time.process_time()
                trainer.worker.result(trainer.model)  # the rollout collected meanwhile, to the end of its CPU
                train_cpu += time.process_time() - c0
            # the worker's CPU between its first and last idle moments: `updates` whole rollouts (the
            # 2nd to the last collected; the 1st began during the warm-up update, before any reading)
            train_cpu += idle[-1] - idle[0] if idle else 0.0
        finally:
            trainer.close()
        if not interleave:
            for _ in range(updates):  # as many rollouts as the CPU above holds
                wall_s, cpu = _bare_env_block(env, trainer.buffer.T, rng)
                bare.append(wall_s)
                env_cpu += cpu
        profile = ""
        if profile_top > 0:
            torch.set_num_threads(1)
            collector = trainer.collector or make_collector(cfg, trainer.env, trainer.model, trainer.generator)
            roll = profile_call(lambda: collector.collect(trainer.buffer), profile_top)
            torch.set_num_threads(trainer.update_threads)
            upd = profile_call(lambda: ppo_update(trainer.model, trainer.optimizer, trainer.buffer, cfg.ppo,
                                              trainer.discount.value, trainer.generator,
                                              teacher_weight=teacher_weight(cfg.ppo, trainer.counters.update)), profile_top)
            whole = " (actor and critic in this process)" if trainer.split_update else ""
            profile = f"rollout:\n{roll}\n\nupdate{whole}:\n{upd}"
        med = statistics.median
        collection = "overlapped" if trainer.overlap else "in turn"
        return TrainBench(fidelity, collection, cfg.n_envs, cfg.task.n_pursuers, trainer.buffer.n_transitions, _settings(cfg, trainer),
                          med(rollout), med(update), med(wall), med(bare), train_cpu, env_cpu, profile, trainer.update_threads,
                          trainer.split_update)


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def aim_line(r: TrainBench) -> str:
    """The verdicts on both aims for one measured fidelity and collection."""
    return (f"aims {r.fidelity}, {r.collection}: update faster than its rollout (ratio < {AIM_UPDATE_OVER_ROLLOUT:g}): "
            f"{against_aim(r.update_over_rollout, AIM_UPDATE_OVER_ROLLOUT, 2)}, "
            f"{_verdict(r.update_over_rollout < AIM_UPDATE_OVER_ROLLOUT)}; training within {AIM_ENV_OVER_TRAINING:g}x "
            f"of the bare env: {against_aim(r.env_over_training, AIM_ENV_OVER_TRAINING, 2)}x, "
            f"{_verdict(r.env_over_training <= AIM_ENV_OVER_TRAINING)}")


def _check_resolved(args: argparse.Namespace, modes: list[str]) -> list[str]:
    """The collection modes to measure, after checking the resolved config: a --set that changes
    task.fidelity or run.overlap in another spelling (`task={fidelity: quadrotor}`) is refused as
    the dotted key is, and a DAgger config, which always collects in turn, is measured in turn once
    (`--collection both` measured it twice, the second row labelled in turn too)."""
    from train.config import load_train_config

    def changed(f: str, overrides) -> str | None:
        cfg = load_train_config([args.config], [f"task.fidelity={f}", "run.overlap=false", *overrides])
        return "task.fidelity" if cfg.task.fidelity != f else "run.overlap" if cfg.run.overlap else None

    for f in args.fidelity:
        if changed(f, args.overrides):
            text = next((t for t in args.overrides if changed(f, [t])), " ".join(args.overrides))
            key = changed(f, [text]) or changed(f, args.overrides)
            flag = {"task.fidelity": "--fidelity", "run.overlap": "--collection"}[key]
            raise ValueError(f"--set {text}: this benchmark sets {key} from {flag}; use {flag}")
    cfg = load_train_config([args.config], list(args.overrides))
    if cfg.algo != "dagger":
        return modes
    if args.collection == "overlapped":
        raise ValueError(f"--collection overlapped: config {args.config} trains by DAgger, which always collects in turn "
                         f"(the teacher's labels feed the update); use --collection in-turn")
    if args.collection == "both":
        print(f"  note: config {args.config} trains by DAgger, which always collects in turn: measured in turn only",
              flush=True)
    return ["false"]


def run(args: argparse.Namespace) -> int:
    if args.updates < 1:
        raise ValueError(f"--updates: expected an integer >= 1, got {args.updates}")
    if args.profile < 0:
        raise ValueError(f"--profile: must be >= 0, got {args.profile}")
    if args.n_envs is not None and args.n_envs < 1:
        raise ValueError(f"--n-envs: expected an integer >= 1, got {args.n_envs}")
    again = next((f for f in args.fidelity if args.fidelity.count(f) > 1), None)
    if again is not None:  # it was measured twice, two rows and two verdicts of one configuration
        raise ValueError(f"--fidelity: {again} given twice; give each fidelity once")
    if args.n_envs is not None:  # a --set of another count would win over the flag, dropping it without a word
        from pursuit_mj.configio import parse_override

        for text in args.overrides:
            path, value = parse_override(text, f"--set {text}")
            if [part.strip() for part in path] == ["n_envs"] and value != args.n_envs:
                raise ValueError(f"--set {text}: beside --n-envs {args.n_envs}, which it would override; give the world "
                                 f"count once")
    own = {"task.fidelity": "--fidelity", "run.overlap": "--collection"}  # measure() sets these; a --set would win and mislabel the row
    for text in args.overrides:
        flag = own.get(text.split("=", 1)[0].strip())
        if flag:
            raise ValueError(f"--set {text}: this benchmark sets that key from {flag}; use {flag}")
    modes = {"both": ["false", "true"], "in-turn": ["false"], "overlapped": ["true"]}[args.collection]
    modes = _check_resolved(args, modes)
    results = []
    for f in args.fidelity:
        for overlap in modes:
            results.append(measure(args.config, f, args.n_envs, args.updates, args.overrides + [f"run.overlap={overlap}"],
                                   args.profile))
            when = "between them" if results[-1].collection == "in turn" else "after them"
            print(f"  measured {f}, {results[-1].collection}: {counted(args.updates, 'update')} after one warm-up, bare env stepped "
                  f"{when}", flush=True)
    print(f"train benchmark, config {args.config}{given_task([], args.overrides)}: {results[0].settings}")
    print("rates in agent-steps/s (decision steps x worlds x pursuers) from median wall times; bare env = the same task "
          "with random actions, stepped between updates (in turn) or after training (overlapped); cpu = process time of training (rollout worker and critic process included) over that of the bare env; "
          "update threads: torch threads of the update, and of the critic's process when the update is split (run.split_update)")
    head = ["fidelity", "collection", "worlds x pursuers", "update threads", "rollout ag-steps/s", "update ag-steps/s", "s per update",
            "training ag-steps/s", "bare env ag-steps/s", "update / rollout", "env / training", "cpu: env / training"]
    rows = [[r.fidelity, r.collection, f"{r.worlds} x {r.pursuers}", r.threads, f"{r.rate(r.rollout_s):.0f}", f"{r.rate(r.update_s):.0f}",
             f"{r.update_s:.2f}", f"{r.rate(r.wall_s):.0f}", f"{r.rate(r.env_s):.0f}",
             f"{r.update_over_rollout:.2f}", f"{r.env_over_training:.2f}x", f"{r.env_over_training_cpu:.2f}x"] for r in results]
    print(format_table(head, rows))
    for r in results:
        print(aim_line(r))
    for r in results:
        if r.profile:
            print(f"\nwhere training spends its time ({r.fidelity}, {r.collection}; own time, cProfile):\n{r.profile}")
    return 0
