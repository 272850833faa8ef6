"""Learning from a teacher team by DAgger (Ross et al. 2011): `algo: dagger`.

A warm start for PPO. Every update the worlds are driven by a per-world, per-step mixture
of teacher and student (the teacher's share `beta` falls linearly from `beta_start` to 0
over `beta_updates` updates); the teacher labels every observation the pursuers met with
the action it would take there, and the pairs go into a bounded dataset (the oldest are
dropped first). The student's mean action is then fitted to the teacher's by mean-squared
error (or, with `imitation.loss: heading_speed`, by heading and speed apart: cloning_loss) on
minibatches drawn from the whole dataset, so it learns to recover from its own
mistakes, not only to copy the teacher's trajectories. The critic learns the value of the
driving mixture from the same rollouts (GAE returns), so a PPO run started from this
checkpoint (`init_from`) gets a critic that already means something.

The student's log std is not fitted: it stays at `net.init_log_std`, the exploration noise
of the PPO run that follows. By default the teacher (a hand-made team, see pursuit_mj.policies) sees
the very observations the student sees, so what the student can learn is bounded by what
the teacher does from them; the teacher's memory (last seen evaders, its coverage map) is
the part a memoryless network can only approximate. With `imitation.teacher_sees` the
teacher is privileged (learning by cheating, Chen et al. 2019): it acts on the same state
perceived with an all-round, exact view (or fully observed), and the student learns to do
from its own, poorer observations what the teacher does knowing more.

The dataset is kept beside the checkpoints (train/demonstration_files.py): a resumed run
goes on with the pairs its last checkpoint had, as it goes on with its weights, optimiser,
counters and random streams.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from .agent import ActorCritic
from .config import ImitationConfig, PPOConfig
from .critic_worker import CriticWorker
from .losses import scaled_value_loss
from .networks import flush_tiny, gaussian_log_prob
from .ppo import advantages_and_returns, explained_variance
from .rollout import ActionPath, RolloutStats, forget_ended
from .storage import Rollout


class Demonstrations:
    """A ring buffer of (observation (D,) float32, teacher action (2,) in [-1, 1]: fraction of
    pursuer_speed, world x/y) pairs.

    total counts the pairs ever added (also those dropped since); the pairs added since
    `mark_saved` are what `unsaved` gives to be kept on disk (demonstration_files.py)."""

    def __init__(self, capacity: int, obs_dim: int):
        self.obs = torch.zeros(capacity, obs_dim)
        self.actions = torch.zeros(capacity, 2)
        self.capacity = capacity
        self.size = 0
        self.total = 0
        self._saved = 0
        self._next = 0

    def newest(self, count: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The newest min(count, size) pairs, oldest first: obs (n, D) and actions (n, 2) (copies)."""
        count = min(count, self.size)
        idx = (self._next - count + torch.arange(count)) % self.capacity
        return self.obs[idx], self.actions[idx]

    def unsaved(self) -> tuple[int, torch.Tensor, torch.Tensor]:
        """(index in total of the first, obs, actions) of the pairs added since mark_saved and still held."""
        obs, actions = self.newest(self.total - self._saved)
        return self.total - obs.shape[0], obs, actions

    def mark_saved(self) -> None:
        self._saved = self.total

    def refill(self, obs: torch.Tensor, actions: torch.Tensor, total: int) -> None:
        """Hold exactly these pairs, obs (n, D) and actions (n, 2) (oldest first, at most capacity), the
        newest of `total` ever added."""
        n = obs.shape[0]
        self.obs[:n], self.actions[:n] = obs, actions
        self.size, self._next, self.total, self._saved = n, n % self.capacity, int(total), int(total)

    def add(self, obs: torch.Tensor, actions: torch.Tensor) -> None:
        """obs (B, D), actions (B, 2); the oldest pairs make room when full."""
        n = obs.shape[0]
        self.total += n
        if n >= self.capacity:
            obs, actions, n = obs[-self.capacity :], actions[-self.capacity :], self.capacity
        idx = (self._next + torch.arange(n)) % self.capacity
        self.obs[idx] = obs
        self.actions[idx] = actions
        self._next = int((self._next + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """n stored pairs drawn with replacement: obs (n, obs_dim) float32 and the teacher's
        actions (n, 2) (fractions of pursuer_speed, layout frame)."""
        idx = torch.randint(0, self.size, (n,), generator=generator)
        return self.obs[idx], self.actions[idx]


def teacher_share(cfg: ImitationConfig, update: int) -> float:
    """beta for the update about to run (0-based count of finished updates)."""
    if cfg.beta_updates <= 0:
        return 0.0
    return max(cfg.beta_start * (1.0 - update / cfg.beta_updates), 0.0)


class DaggerCollector:
    """Drives the training env with the teacher/student mixture and records the teacher's labels.

    Same contract as rollout.Collector (fills a Rollout, returns RolloutStats) plus the
    demonstrations. `beta` is set by the trainer before each collect.
    """

    def __init__(self, env, model: ActorCritic, teacher, demos: Demonstrations, generator: torch.Generator,
                 path: ActionPath | None = None, teacher_task=None):
        self.env = env
        # a privileged teacher (imitation.teacher_sees) acts on the env's state as perceived
        # under teacher_task (env.observe_as), without the student's belief features
        self.teacher_task = teacher_task
        self.teacher_spec = getattr(env, "raw_spec", env.obs_spec)
        self.path = path or ActionPath()
        self.model = model
        self.teacher = teacher
        self.demos = demos
        self.generator = generator
        self.beta = 1.0
        self.obs_np = env.reset()
        self.teacher.reset(env.n_worlds)
        self.path.reset(env.n_worlds)
        self.obs = flush_tiny(torch.as_tensor(self.obs_np))

    @torch.no_grad()
    def collect(self, buf: Rollout) -> RolloutStats:
        stats = RolloutStats()
        term_sums: dict[str, float] = {}
        spec, W = self.model.spec, self.env.n_worlds
        for t in range(buf.T):
            obs = self.obs
            label = torch.as_tensor(self._teacher_actions(spec), dtype=torch.float32)  # (W, N, 2)
            mean, log_std = self.model.actor(obs, spec)
            student = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
            use_teacher = torch.rand(W, generator=self.generator) < self.beta
            action = torch.where(use_teacher[:, None, None], label, student.clamp(-1.0, 1.0))
            buf.obs[t] = obs
            buf.actions[t] = action
            buf.logp[t] = gaussian_log_prob(mean, log_std.exp(), action).sum(-1)
            buf.values[t] = self.model.value(obs, None)
            self.demos.add(obs.reshape(-1, obs.shape[-1]), label.reshape(-1, 2))
            # every action goes through the run's path (its shield, with shield: true); the teacher's
            # labels already carry the team's built-in shield, so for them that changes nothing (measured
            # at most 3e-8)
            next_obs, reward, terminated, truncated, info = self.env.step(self.path(action, obs, spec))
            buf.rewards[t] = torch.as_tensor(reward)
            buf.terminated[t] = torch.as_tensor(terminated)
            buf.truncated[t] = torch.as_tensor(truncated)
            buf.final_values[t] = 0.0
            if truncated.any():
                idx = torch.as_tensor(np.flatnonzero(truncated))
                buf.final_values[t, idx] = self.model.value(flush_tiny(torch.as_tensor(info["final_obs"])[idx]), None)
            forget_ended(self.teacher, terminated | truncated)
            self.path.forget_ended(terminated | truncated)
            for k, v in info["reward_terms"].items():
                term_sums[k] = term_sums.get(k, 0.0) + float(v.mean())
            stats.episodes.extend(info["episodes"])
            self.obs_np = next_obs
            self.obs = flush_tiny(torch.as_tensor(next_obs))
        buf.last_value.copy_(self.model.value(self.obs, None))  # in place, as Collector: the buffer may be shared
        stats.reward_terms = {k: v / buf.T for k, v in term_sums.items()}
        return stats

    def _teacher_actions(self, spec) -> np.ndarray:
        """The teacher's actions (W, N, 2) in the current state, from its own view of it."""
        if self.teacher_task is None:
            return self.teacher.act(self.obs_np, spec)
        return self.teacher.act(self.env.observe_as(self.teacher_task), self.teacher_spec)


HEADING_EPS = 0.05  # fraction of max speed: below it a heading is soft (no 1/|a| blow-up near rest)
STILL = 0.05  # a teacher action slower than this has no heading to learn


def cloning_loss(mean: torch.Tensor, target: torch.Tensor, kind: str) -> torch.Tensor:
    """How far the student's mean actions (B, 2) are from the teacher's (B, 2), averaged over B.

    mse: squared distance. Where the observation leaves the teacher's direction open (several
    ways round a wall), its minimiser is the average of the teacher's actions, which is
    shorter than any of them: the student slows down. heading_speed: the squared distance of
    the unit headings (where the teacher moves at all) plus the squared difference of the
    speeds, so the speed is learnt as the teacher's speed, not as the length of an average.
    heading_median_speed: the same with the absolute difference of the speeds, whose minimiser
    is the median of the teacher's speeds for an observation, not their mean: a teacher at
    full speed most of the time is copied at full speed.
    """
    if kind == "mse":
        return ((mean - target) ** 2).sum(-1).mean()
    if kind not in ("heading_speed", "heading_median_speed"):
        raise ValueError(f"imitation.loss: {kind!r} is not one of mse, heading_speed, heading_median_speed")
    speed_s, speed_t = mean.norm(dim=-1), target.norm(dim=-1)
    heading_s = mean / torch.sqrt(speed_s.unsqueeze(-1) ** 2 + HEADING_EPS**2)
    heading_t = target / speed_t.clamp_min(1e-9).unsqueeze(-1)
    moving = (speed_t > STILL).to(mean.dtype)
    heading = (((heading_s - heading_t) ** 2).sum(-1) * moving).mean()
    if kind == "heading_median_speed":
        return heading + (speed_s - speed_t).abs().mean()
    return heading + ((speed_s - speed_t) ** 2).mean()


def imitation_update(model: ActorCritic, optimizer: torch.optim.Optimizer, demos: Demonstrations, buf: Rollout,
                     cfg: ImitationConfig, ppo: PPOConfig, gamma: float, generator: torch.Generator,
                     critic_worker: CriticWorker | None = None) -> dict[str, float]:
    """cfg.grad_steps steps, each on a minibatch of demonstrations (behaviour cloning) and one of
    the rollout's transitions (value regression to GAE returns); returns mean loss statistics.
    critic_worker: computes the value regression's gradient in its own process meanwhile
    (train/critic_worker.py), as in ppo_update."""
    _, ret, _ = advantages_and_returns(buf, gamma, ppo.gae_lambda)
    n = buf.n_transitions
    obs = buf.obs.reshape(n, -1)
    ret = ret.reshape(n)
    target_std = float(ret.std(unbiased=False)) if ppo.value_scaling else None
    mb = min(cfg.minibatch_size, n)
    if critic_worker is not None:
        critic_worker.load(obs, None, ret, target_std, ppo.vf_coef)
    sums = {"bc_loss": 0.0, "value_loss": 0.0, "grad_norm": 0.0}
    params = list(model.parameters())  # once, not at every step (ppo.ParameterLists)
    for _ in range(cfg.grad_steps):
        d_obs, d_act = demos.sample(cfg.minibatch_size, generator)
        idx = torch.randint(0, n, (mb,), generator=generator)
        if critic_worker is not None:
            critic_worker.request(idx)
        mean, _ = model.actor(d_obs, model.spec)
        bc = cloning_loss(mean, d_act, cfg.loss)
        if critic_worker is None:
            v_loss = scaled_value_loss(model.raw_value(obs[idx], None), ret[idx], target_std)
            loss = bc + ppo.vf_coef * v_loss
        else:
            loss = bc
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if critic_worker is not None:
            v_loss = critic_worker.collect()
        grad_norm = nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
        optimizer.step()
        for k, x in (("bc_loss", bc), ("value_loss", v_loss), ("grad_norm", grad_norm)):
            sums[k] += float(x.detach())
    out = {k: v / max(cfg.grad_steps, 1) for k, v in sums.items()}
    out["explained_variance"] = explained_variance(buf.values.reshape(n), ret)
    out["demonstrations"] = float(demos.size)
    return out
