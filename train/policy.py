"""Trained actors as pursuit_mj.policy.Policy objects; `load_policy` is what eval and render import.

    from train.policy import load_policy      # lazily, only when a model file is given
    policy = load_policy("runs/full_obs/best.pt", env.obs_spec)
    actions = policy.act(obs, env.obs_spec)   # (W, N, 2) in [-1, 1]
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from pursuit_mj.belief import Belief, BeliefPolicy, BeliefTeam, belief_spec
from pursuit_mj.config import TaskConfig
from pursuit_mj.configio import build
from pursuit_mj.layout import N_BUILTIN
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policy import Policy, check_world_ids
from pursuit_mj.policies import make_policy
from pursuit_mj.residual import acting_team
from pursuit_mj.shield import SafetyShield

from .checkpoint import check_obs_spec, load_checkpoint, load_error
from .config import NetConfig, ResidualConfig
from .networks import Actor, flush_tiny, team_mismatch


def spec_from_dict(data: dict) -> ObsSpec:
    """The environment's spec (without belief groups) a stored spec (ObsSpec.to_dict) was made for."""
    return ObsSpec.make(int(data["n_pursuers"]), int(data["n_evaders"]), int(data["n_rays"]))


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """Run torch on one thread inside the block, then restore the previous count.

    A policy step is a forward pass over a few dozen rows: more threads only add
    synchronisation, and on a busy machine (training beside it) two threads made eval's
    forwards 3x slower than one. Switching costs well under a microsecond.
    """
    before = torch.get_num_threads()
    if before != 1:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if before != 1:
            torch.set_num_threads(before)


ROWS_PER_FORWARD = 64  # pursuers (rows) per forward pass of a loaded actor, see ActorPolicy._forward


class ActorPolicy:
    """A trained actor driving every pursuer (shared parameters); mean action unless stochastic.

    A stochastic one adds Gaussian noise drawn from one generator (`seed`) across the batch, so
    its episodes depend on the number of worlds and on what it played before (the commands act
    on the mean, and their tables do not)."""

    def __init__(self, actor: Actor, name: str, stochastic: bool = False, seed: int = 0):
        self.actor = actor.eval()
        self.name = name
        self.stochastic = stochastic
        self.generator = torch.Generator().manual_seed(seed)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """The reference actor has no memory; nothing to forget (the ids are checked all the same)."""
        check_world_ids(world_ids, n_worlds, f"policy {self.name}")

    def _forward(self, rows: torch.Tensor, spec: ObsSpec) -> tuple[torch.Tensor, torch.Tensor]:
        """The actor on rows (R, dim) in blocks of exactly ROWS_PER_FORWARD (the last padded).

        Float32 matrix products give a row a result that depends on how many rows share the
        product (the library picks its kernels by shape; 1e-7 apart here), and a chase
        amplifies that into another episode. Fixed-size blocks make every row's action the
        same whatever the batch, so eval's episodes do not depend on --worlds.
        """
        R = rows.shape[0]
        pad = (-R) % ROWS_PER_FORWARD
        if pad:
            rows = torch.cat([rows, rows.new_zeros(pad, rows.shape[1])])
        parts = [self.actor(rows[k : k + ROWS_PER_FORWARD], spec) for k in range(0, rows.shape[0], ROWS_PER_FORWARD)]
        return torch.cat([m for m, _ in parts])[:R], torch.cat([s for _, s in parts])[:R]

    @torch.no_grad()
    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """obs (W, N, spec.dim) -> actions (W, N, 2) in [-1, 1] (fraction of max speed, world x/y)."""
        x = flush_tiny(torch.as_tensor(np.asarray(obs, dtype=np.float32)))
        if x.shape[-1] != spec.dim:
            raise ValueError(f"policy {self.name}: observation width {x.shape[-1]} does not match its spec ({spec.dim})")
        if not torch.isfinite(x).all():  # NaN actions would be blamed on the policy
            raise ValueError(f"policy {self.name}: observations contain NaN or inf")
        with one_torch_thread():
            mean, log_std = self._forward(x.reshape(-1, spec.dim), spec)
            mean, log_std = mean.reshape(x.shape[:-1] + (2,)), log_std.reshape(x.shape[:-1] + (2,))
        if self.stochastic:
            mean = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
        return mean.clamp(-1.0, 1.0).numpy().astype(np.float64)


def actor_from_checkpoint(data: dict, spec: ObsSpec, source: str) -> Actor:
    """Build the stored network for `spec` and load its weights (ValueError if they do not fit,
    or if the network reads slots by place and `spec` is of another team: networks.team_mismatch).

    Only the stored `net` settings are read, so a model outlives changes to the task config's keys.
    """
    net = build(NetConfig, data["train_config"].get("net", {}), f"checkpoint {source}: train_config.net")
    why = team_mismatch(net.kind, data["obs_spec"], spec)
    if why is not None:
        raise ValueError(f"checkpoint {source}: {why}")
    actor = Actor(spec, net)
    try:
        actor.load_state_dict(data["actor"])
    except RuntimeError as exc:
        raise ValueError(f"checkpoint {source}: actor weights do not fit net {net.kind} for this environment ({load_error(exc)})") from None
    return actor


def load_policy(path: str | Path, env_spec: ObsSpec | None = None, stochastic: bool = False, name: str | None = None,
                task: TaskConfig | None = None) -> Policy:
    """A Policy from a checkpoint file, checked against the environment's observation spec.

    env_spec None means the spec the model was trained with. The name defaults to the run name
    (for `runs/<name>/best.pt`) or the file stem. A model trained behind the safety shield
    (train config `shield: true`) comes back behind it (named NAME+shield), one trained as a
    correction of a base team (`residual.base`) comes back added to that team (named
    NAME@heuristic); both sized for `task` (the TaskConfig it will run in; None: the task it
    was trained on). A model trained with belief features (train config `belief: true`) comes
    back with its Belief in front, so it takes the environment's own observations.
    """
    _check_spec_and_task(env_spec, task)
    data = load_checkpoint(path)
    stored = data["train_config"]
    belief = bool(stored.get("belief", False))
    spec = env_spec if env_spec is not None else spec_from_dict(data["obs_spec"])
    if env_spec is not None and env_spec.has_belief:
        raise ValueError("load_policy: env_spec must be the environment's own spec (without belief features)")
    actor_spec = belief_spec(spec) if belief else spec
    check_obs_spec(data, actor_spec, path)
    actor = actor_from_checkpoint(data, actor_spec, str(path))
    label = name or stored.get("name") or Path(path).stem
    policy = ActorPolicy(actor, str(label), stochastic=stochastic)
    source = f"checkpoint {path}: train_config"
    residual = build(ResidualConfig, stored.get("residual", {}), f"{source}.residual")
    if not stored.get("shield", False) and residual.base == "none" and not belief:
        team = policy
    else:
        run_task = task if task is not None else build(TaskConfig, stored.get("task", {}), f"{source}.task")
        team = trained_team(policy, run_task, bool(stored.get("shield", False)), residual, belief)
    team.trained_task = dict(stored.get("task", {}))  # the task it learned in, for callers to compare with theirs
    team.trained_layouts = trained_layouts(stored)
    return team


def trained_layouts(train_config: dict) -> list:
    """The layouts (indices or file paths, as the run's stored config names them) whose episodes a
    run trained on: its `layouts` (one per world, or drawn from per episode with random_layout),
    else the built-in ones with task.random_layout, else task.layout (default 0)."""
    task = train_config.get("task", {}) or {}
    if train_config.get("layouts"):
        return list(train_config["layouts"])
    if task.get("random_layout", False):
        return list(range(N_BUILTIN))
    return [task.get("layout", 0)]


def _check_spec_and_task(env_spec, task) -> None:
    """ValueError unless env_spec is an ObsSpec and task a TaskConfig (or None) of one team: a
    shield or belief sized for one team and observations of another would act without a word."""
    if env_spec is not None and not isinstance(env_spec, ObsSpec):
        raise ValueError(f"load_policy: env_spec must be the environment's ObsSpec (env.obs_spec), got {type(env_spec).__name__}")
    if task is not None and not isinstance(task, TaskConfig):
        raise ValueError(f"load_policy: task must be a TaskConfig, got {type(task).__name__}")
    if env_spec is not None and task is not None:
        differ = [f"{k} {getattr(task, k)} (task) vs {getattr(env_spec, k)} (env_spec)"
                  for k in ("n_pursuers", "n_evaders", "n_rays") if getattr(task, k) != getattr(env_spec, k)]
        if differ:
            raise ValueError(f"load_policy: task and env_spec are of different teams: {'; '.join(differ)}")


def base_team(residual: ResidualConfig, task: TaskConfig) -> Policy | None:
    """The hand-made team a residual actor corrects (residual.base), sized for `task`; None
    when the actor drives alone."""
    if residual.base == "none":
        return None
    return make_policy(residual.base, task, source="residual.base")


def trained_team(actor: Policy, task: TaskConfig, shield: bool, residual: ResidualConfig, belief: bool = False) -> Policy:
    """The policy a trained actor stands for, as it acted in training: fed belief features,
    added to its base team (residual learning) and behind the shield when its train config
    says so, all sized for `task`."""
    if belief:
        actor = BeliefPolicy(actor, Belief.from_config(task))
    if belief and residual.base == "heuristic":
        base = BeliefTeam(actor.belief)  # the belief is that team's memory: act from it
    else:
        base = base_team(residual, task)
    return acting_team(actor, base, residual.scale, SafetyShield.from_config(task) if shield else None)
