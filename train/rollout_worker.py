"""Rollouts collected in a child process while the parent learns (`run.overlap`).

Plain PPO alternates: collect a rollout, then learn from it, each waiting for the other.
With overlap, a child process owns the training env, its action path (shield, base team) and
a copy of the networks, and collects the next rollout while the parent runs the update on
the last one; on two cores a training step then costs about the longer of the two instead
of their sum. (Threads cannot do this: the env's Python code and the update fight over the
GIL, and the pair ran only 8 % faster than in turn.)

The price is one update of policy lag: the rollout an update learns from was collected with
the weights from before the previous update. The update corrects for it with PPO's
decoupled objective (train.ppo.ppo_update(lagged=True), losses.behaviour_weights); the
stored values (GAE) come from the critic of one update earlier. Off by default: on the easy
learning task the lag cost as many samples as the overlap saved time (docs/training.md).

Two rollout buffers live in shared memory: the parent reads one while the child fills the
other. Weights go to the child as numpy arrays with each request. The child ignores Ctrl-C
(the parent handles it and stops the child) and exits when the parent's end of the pipe
closes, so a killed parent leaves nothing running.
"""

from __future__ import annotations

import itertools
import time
import weakref

import numpy as np
import torch

from pursuit_mj.user_file import UserCodeError

from .agent import ActorCritic
from .child_process import (POLL_S, STOP_TIMEOUT_S, WorkerExited, how_it_ended, ignore_ctrl_c, report_error, report_refusal,
                            shutdown, spawn)
from .config import TrainConfig
from .ppo import teacher_labels_needed
from .rollout import RolloutStats, make_collector, make_training_env
from .storage import Rollout


def sampler_seed(seed: int, update: int) -> int:
    """Seed of the child's action noise for a run (re)started at `update`."""
    return int(np.random.SeedSequence([seed, update, 11]).generate_state(1)[0])


def model_weights(model: ActorCritic) -> dict:
    """What the child needs to act like `model`: parameters as numpy arrays, value normaliser state."""
    nets = {k: v.detach().numpy().copy() for k, v in model.state_dict().items()}
    return {"nets": nets, "value_norm": model.value_norm.state_dict() if model.value_norm is not None else None}


def _load_weights(model: ActorCritic, weights: dict) -> None:
    model.load_state_dict({k: torch.from_numpy(v) for k, v in weights["nets"].items()})
    if model.value_norm is not None:
        model.value_norm.load_state_dict(weights["value_norm"])


def _serve(conn, cfg: TrainConfig, start_update: int, buffers: list[Rollout]) -> None:
    """The child: build the env and networks, then fill buffers on request until told to stop."""
    ignore_ctrl_c()
    torch.set_num_threads(1)
    try:
        env = make_training_env(cfg, start_update)
        model = ActorCritic(env.obs_spec, env.state_dim, cfg)
        generator = torch.Generator().manual_seed(sampler_seed(cfg.seed, start_update))
        collector = make_collector(cfg, env, model, generator)
        for served in itertools.count():  # rollout k feeds update start_update + k
            request = conn.recv()
            if request[0] == "stop":
                return
            _, index, weights = request
            _load_weights(model, weights)
            collector.teaching = teacher_labels_needed(cfg.ppo, start_update + served)
            t0 = time.perf_counter()
            stats = collector.collect(buffers[index])
            stats.seconds = time.perf_counter() - t0
            conn.send(("done", stats))
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return  # the parent is gone
    except UserCodeError as exc:  # the user's reward term or evader model, not this code: its one line, as without overlap
        report_refusal(conn, str(exc))
    except BaseException:  # noqa: BLE001 - everything goes back to the parent, which raises it
        report_error(conn)


class RolloutWorker:
    """A child process that collects rollouts of `cfg`'s training env, one request at a time.

    `start(model)` asks for the next rollout with `model`'s current weights and returns at
    once; `result(model)` waits for it (starting one first if none is running) and returns
    (buffer, stats); the buffer stays valid until the request after next. `close()` stops the
    child (also done when the worker is garbage-collected or the interpreter exits).
    """

    def __init__(self, cfg: TrainConfig, start_update: int, T: int, W: int, N: int, obs_dim: int, state_dim: int):
        self.buffers = [Rollout(T, W, N, obs_dim, state_dim).share_memory() for _ in range(2)]
        self.process, self._conn = spawn(_serve, (cfg, start_update, self.buffers), f"rollout-{cfg.name}")
        self._next = 0  # the buffer the next request fills
        self._pending: int | None = None
        self._served = 0  # rollouts returned so far
        self._finalizer = weakref.finalize(self, shutdown, self.process, self._conn)

    def start(self, model: ActorCritic) -> None:
        if self._pending is not None:
            raise RuntimeError("rollout worker: a rollout is already being collected")
        try:
            self._conn.send(("collect", self._next, model_weights(model)))
        except (BrokenPipeError, ConnectionResetError):
            self.process.join(STOP_TIMEOUT_S)
            self._raise_report()  # it failed before reading the request: what it sent says why
            if self._served == 0 and (self.process.exitcode or 0) > 0:  # it failed to start: its traceback is the news
                raise RuntimeError(f"rollout worker {self.process.name} exited (code {self.process.exitcode}) before "
                                   "its first rollout; its error is printed above (run.overlap=false collects in this "
                                   "process instead)") from None
            raise WorkerExited(f"rollout worker {self.process.name} {self._ended()} between two rollouts") from None
        self._pending, self._next = self._next, 1 - self._next

    def result(self, model: ActorCritic) -> tuple[Rollout, RolloutStats]:
        if self._pending is None:
            self.start(model)
        while not self._conn.poll(POLL_S):  # (a dead child's closed pipe polls as readable)
            if not self.process.is_alive():
                raise WorkerExited(f"rollout worker {self.process.name} {self._ended()} without finishing its rollout")
        try:
            kind, payload = self._conn.recv()
        except (EOFError, ConnectionResetError):
            self.process.join(STOP_TIMEOUT_S)
            raise WorkerExited(f"rollout worker {self.process.name} {self._ended()} without finishing its rollout") from None
        self._raise_failure(kind, payload)
        index, self._pending = self._pending, None
        self._served += 1
        return self.buffers[index], payload

    def _raise_report(self) -> None:
        """Raise the error a dead child sent before it went, if it sent one (nothing otherwise)."""
        try:
            if not self._conn.poll(0):
                return
            kind, payload = self._conn.recv()
        except (EOFError, OSError):
            return
        self._raise_failure(kind, payload)

    def _raise_failure(self, kind: str, payload) -> None:
        """RuntimeError with the child's traceback ('error'), or UserCodeError with its one line ('refused')."""
        if kind == "error":
            raise RuntimeError(f"rollout worker {self.process.name} failed:\n{payload}")
        if kind == "refused":
            raise UserCodeError(payload)

    def _ended(self) -> str:
        return how_it_ended(self.process)

    def close(self) -> None:
        self._finalizer()
