"""The critic's half of a PPO update, computed in a child process (`run.split_update`).

Actor and critic are separate networks, so each minibatch step's gradient splits in two
independent halves: the policy loss and entropy for the actor, the value loss for the
critic. The trainer computes the actor's half while this child computes the critic's: on
two cores the update ran 1.15-1.8x faster at minibatches of 256, and stayed
fast beside other work, where two torch threads in one process slow down threefold
(docs/training.md, "Training speed").

Nothing of the learner moves into the child. The critic's parameters live in shared memory
and stay the trainer's (its optimiser, checkpoints and rollouts use them as before); per
minibatch step the child reads them, writes the critic's gradient into shared tensors and
answers with the value loss, and the trainer clips both halves' gradients together and
steps its one optimiser. The parameters change only between a step's answer and the next
request, so the child never sees them half-written. Results equal those of the update in
one process up to float rounding (tests/test_critic_worker.py).
"""

from __future__ import annotations

import weakref

import torch

from .agent import ActorCritic
from .child_process import POLL_S, WorkerExited, how_it_ended, ignore_ctrl_c, report_error, shutdown, spawn
from .config import TrainConfig
from .losses import scaled_value_loss

def _shapes(params) -> list[tuple[int, ...]]:
    return [tuple(p.shape) for p in params]


def _serve(conn, cfg: TrainConfig, spec, state_dim: int, threads: int, params, grads, obs, states, targets, index) -> None:
    """The child: a critic built like the trainer's, on the shared parameters; one gradient per request."""
    ignore_ctrl_c()
    torch.set_num_threads(threads)
    try:
        model = ActorCritic(spec, state_dim, cfg)
        own = list(model.critic.parameters())
        if _shapes(own) != _shapes(params):
            raise ValueError(f"critic process: the model's critic has shapes {_shapes(params)}, "
                             f"the config {cfg.name!r} builds {_shapes(own)}")
        for p, shared in zip(own, params):
            p.data = shared  # read the trainer's weights in place, as its optimiser leaves them
        target_std = vf_coef = None
        while True:
            request = conn.recv()
            if request[0] == "stop":
                return
            if request[0] == "load":  # a new rollout's value-loss scale and weight
                _, target_std, vf_coef = request
                continue
            idx = index[: request[1]]  # ("grad", k): the minibatch is the first k shared indices
            v = model.raw_value(obs[idx], states[idx] if states is not None else None)
            v_loss = scaled_value_loss(v, targets[idx], target_std)
            for shared, g in zip(grads, torch.autograd.grad(vf_coef * v_loss, own)):
                shared.copy_(g)
            conn.send(("done", float(v_loss.detach())))
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return  # the parent is gone
    except BaseException:  # noqa: BLE001 - everything goes back to the parent, which raises it
        report_error(conn)
        _wait_for_close(conn)


def _wait_for_close(conn) -> None:
    """After reporting an error: keep the pipe open until the parent has read it and closes."""
    try:
        while conn.recv()[0] != "stop":
            pass
    except (EOFError, OSError):
        return


class CriticWorker:
    """A child process that computes the critic's gradient for `ppo_update` and `imitation_update`, step by step.

    model: the trainer's ActorCritic; its critic's parameters are moved into shared memory in
    place (the optimiser keeps the same Parameter objects). n: transitions per rollout.
    `load(...)` once per update, then `request(idx)` and `collect()` per minibatch step;
    `close()` stops the child (also done when the worker is garbage-collected).
    """

    def __init__(self, model: ActorCritic, cfg: TrainConfig, n: int, threads: int):
        model.critic.share_memory()
        self.params = list(model.critic.parameters())
        self.grads = [torch.zeros_like(p).share_memory_() for p in self.params]
        self.obs = torch.zeros(n, model.spec.dim).share_memory_()
        self.states = torch.zeros(n, model.critic.state_dim).share_memory_() if model.algo == "mappo" else None
        self.targets = torch.zeros(n).share_memory_()
        self.index = torch.zeros(n, dtype=torch.int64).share_memory_()
        state_dim = self.states.shape[1] if self.states is not None else 0
        self.process, self._conn = spawn(
            _serve, (cfg, model.spec, state_dim, threads, self.params, self.grads, self.obs, self.states, self.targets,
                     self.index), f"critic-{cfg.name}")
        self._pending = False
        self._finalizer = weakref.finalize(self, shutdown, self.process, self._conn)

    def load(self, obs: torch.Tensor, states: torch.Tensor | None, targets: torch.Tensor,
             target_std: float | None, vf_coef: float) -> None:
        """One update's inputs: obs (n, obs_dim), states (n, state_dim) or None, value targets (n,)
        in the critic's units, the value-loss scale (losses.scaled_value_loss) and weight."""
        n = self.obs.shape[0]
        if obs.shape[0] != n or targets.shape != (n,):
            raise ValueError(f"critic process: made for rollouts of {n} transitions, given {obs.shape[0]}")
        self.obs.copy_(obs)
        self.targets.copy_(targets)
        if self.states is not None:
            self.states.copy_(states)
        self._send(("load", target_std, float(vf_coef)))

    def request(self, idx: torch.Tensor) -> None:
        """Start the critic's gradient on the minibatch rows idx (k,) int64, at the current weights."""
        if self._pending:
            raise RuntimeError("critic process: a gradient is already being computed")
        self.index[: len(idx)] = idx
        self._send(("grad", len(idx)))
        self._pending = True

    def collect(self) -> torch.Tensor:
        """Wait for the requested gradient, put it in the critic parameters' .grad; returns the value loss."""
        while not self._conn.poll(POLL_S):  # (a dead child's closed pipe polls as readable)
            if not self.process.is_alive():
                raise self._exited()
        try:
            kind, payload = self._conn.recv()
        except (EOFError, ConnectionResetError):
            self.process.join(1.0)
            raise self._exited() from None
        self._pending = False
        if kind == "error":
            raise RuntimeError(f"critic process {self.process.name} failed:\n{payload}")
        for p, g in zip(self.params, self.grads):
            p.grad = g
        return torch.tensor(payload)

    def _send(self, message: tuple) -> None:
        try:
            self._conn.send(message)
        except (BrokenPipeError, ConnectionResetError):
            self.process.join(1.0)
            raise self._exited() from None

    def _exited(self) -> WorkerExited:
        return WorkerExited(f"critic process {self.process.name} {how_it_ended(self.process)} during an update")

    def close(self) -> None:
        self._finalizer()
