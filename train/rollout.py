"""Collect rollouts from a PursuitEnv with the current actor: one batched forward per decision step."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from pursuit_mj.belief import Belief, BeliefEnv, BeliefTeam
from pursuit_mj.custom_rewards import load_reward_files
from pursuit_mj.env import PursuitEnv
from pursuit_mj.policies import make_policy
from pursuit_mj.policy import Policy
from pursuit_mj.residual import acting_team
from pursuit_mj.shield import SafetyShield

from .agent import ActorCritic
from .config import TrainConfig
from .networks import flush_tiny, gaussian_log_prob
from .storage import Rollout


def env_seed(seed: int, update: int) -> int:
    """Training-env seed for a run (re)started at `update`: fresh episodes after a resume."""
    return int(np.random.SeedSequence([seed, update, 7]).generate_state(1)[0])


def make_training_env(cfg: TrainConfig, start_update: int):
    """The auto-resetting env a run (re)started at `start_update` trains in (belief features
    appended when cfg.belief; the reward terms of cfg.rewards paid beside the task's)."""
    env = PursuitEnv(cfg.task, n_worlds=cfg.n_envs, seed=env_seed(cfg.seed, start_update),
                     layouts=list(cfg.layouts) or None, nthread=cfg.run.sim_threads,
                     extra_rewards=load_reward_files(cfg.rewards, "rewards"))
    return BeliefEnv(env, Belief.from_config(cfg.task)) if cfg.belief else env


def hand_made_team(name: str, cfg: TrainConfig, env=None, source: str = "--policy") -> Policy:
    """The hand-made team `name` (pursuit_mj.policies) for the run's task, to act in `env`.

    In a BeliefEnv the heuristic team acts from the belief's memory (BeliefTeam): the belief
    is that team's memory of the same observations, so a second copy would compute the same
    coverage map again each step.
    """
    if name == "heuristic" and isinstance(env, BeliefEnv):
        return BeliefTeam(env.belief)
    return make_policy(name, cfg.task, seed=cfg.seed, source=source)


def make_action_path(cfg: TrainConfig, env=None) -> "ActionPath":
    """What stands between the actor's samples and the env in this run: base team, shield.
    `env`: the training env the path steps (lets the base team share a belief's memory)."""
    shield = SafetyShield.from_config(cfg.task) if cfg.shield else None
    base = None if cfg.residual.base == "none" else hand_made_team(cfg.residual.base, cfg, env, "residual.base")
    return ActionPath(shield, base, cfg.residual.scale)


def make_collector(cfg: TrainConfig, env, model: ActorCritic, generator: torch.Generator) -> "Collector":
    """The PPO / MAPPO collector of this run: its action path, and with ppo.teacher_coef the
    heuristic team labelling each observation (kickstarting)."""
    teacher = hand_made_team("heuristic", cfg, env, "ppo.teacher_coef") if cfg.ppo.teacher_coef > 0 else None
    return Collector(env, model, generator, make_action_path(cfg, env), teacher=teacher,
                     teacher_from_step=cfg.ppo.teacher_from_step)


@dataclasses.dataclass
class RolloutStats:
    """What one rollout saw: finished episodes and the mean per-step reward terms (per pursuer)."""

    episodes: list = dataclasses.field(default_factory=list)
    reward_terms: dict[str, float] = dataclasses.field(default_factory=dict)
    seconds: float = 0.0
    teacher_steps: int = 0  # decision steps the teacher labelled


class Collector:
    """Owns the running observation of a training env between updates (episodes span updates).

    Observations come from the env already free of denormal floats (pursuit_mj.observations);
    the MAPPO global state is flushed here. The env is stepped with what `path` makes of the
    samples (a base team's actions added, a shield); the buffer keeps the policy's own samples,
    so to PPO both are part of the environment. A `teacher` (a Policy with memory) only labels:
    its action for every stored observation goes to buf.teacher_actions, and buf.teacher_mask
    says whether the observation's episode had run `teacher_from_step` decision steps or more.
    Set `teaching` False when no update will use the labels (the teacher's weight has reached
    0): the team is then not stepped, and no label counts.
    """

    def __init__(self, env, model: ActorCritic, generator: torch.Generator, path: "ActionPath | None" = None,
                 teacher: Policy | None = None, teacher_from_step: int = 0):
        self.env = env
        self.model = model
        self.generator = generator
        self.path = path or ActionPath()
        self.teacher = teacher
        self.teacher_from_step = teacher_from_step
        self.teaching = teacher is not None
        self._teacher_behind = False  # it skipped steps: its memory no longer matches the worlds
        self.needs_state = model.algo == "mappo"
        self.obs_np = env.reset()
        self.obs = torch.as_tensor(self.obs_np)
        self.path.reset(env.n_worlds)
        if teacher is not None:
            teacher.reset(env.n_worlds)
        self.state = self._state()

    def _state(self) -> torch.Tensor | None:
        return flush_tiny(torch.as_tensor(self.env.global_state())) if self.needs_state else None

    @torch.inference_mode()
    def collect(self, buf: Rollout) -> RolloutStats:
        stats = RolloutStats()
        term_sums: dict[str, float] = {}
        labelling = self.teacher is not None and self.teaching
        if labelling and self._teacher_behind:
            self.teacher.reset(self.env.n_worlds)
        self._teacher_behind = self.teacher is not None and not labelling
        if not labelling:
            buf.teacher_mask.zero_()
        for t in range(buf.T):
            obs, state = self.obs, self.state
            mean, log_std = self.model.actor(obs, self.model.spec)
            std = log_std.exp()
            action = mean + std * torch.randn(mean.shape, generator=self.generator)
            buf.obs[t] = obs
            buf.actions[t] = action
            buf.logp[t] = gaussian_log_prob(mean, std, action).sum(-1)
            if state is not None:
                buf.states[t] = state
            if labelling:  # before the step: the team's memory takes this observation in
                buf.teacher_actions[t] = torch.as_tensor(self.teacher.act(self.obs_np, self.model.spec))
                buf.teacher_mask[t] = torch.as_tensor(self.env.steps >= self.teacher_from_step)
            next_obs, reward, terminated, truncated, info = self.env.step(self.path(action, obs, self.model.spec))
            buf.rewards[t] = torch.as_tensor(reward)
            buf.terminated[t] = torch.as_tensor(terminated)
            buf.truncated[t] = torch.as_tensor(truncated)
            buf.final_values[t] = 0.0
            if truncated.any():
                idx = np.flatnonzero(truncated)
                f_state = flush_tiny(torch.as_tensor(info["final_state"][idx])) if state is not None else None
                buf.final_values[t, torch.as_tensor(idx)] = self.model.world_value(torch.as_tensor(info["final_obs"][idx]), f_state)
            for k, v in info["reward_terms"].items():
                term_sums[k] = term_sums.get(k, 0.0) + float(v.mean())
            stats.episodes.extend(info["episodes"])
            self.path.forget_ended(terminated | truncated)
            if labelling:
                forget_ended(self.teacher, terminated | truncated)
            self.obs_np = next_obs
            self.obs = torch.as_tensor(next_obs)
            self.state = self._state()
        buf.last_value.copy_(self.model.world_value(self.obs, self.state))
        # the critic once over the whole rollout, not once per step: its values are not needed
        # to act, and one large product costs a fraction of T small ones
        T, W = buf.obs.shape[:2]
        states = buf.states.flatten(0, 1) if self.needs_state else None
        buf.values.copy_(self.model.world_value(buf.obs.flatten(0, 1), states).view(T, W, -1))
        stats.reward_terms = {k: v / buf.T for k, v in term_sums.items()}
        stats.teacher_steps = buf.T if labelling else 0
        return stats


class ActionPath:
    """What the env is stepped with, from the actor's samples (W, N, 2) and the observations
    (W, N, D) they answer: the samples clipped to [-1, 1]; with a `base` team (residual
    learning, pursuit_mj.residual) its actions plus `scale` x the samples; then, with a
    `shield` (pursuit_mj.shield.SafetyShield), shielded. The same `acting_team` a trained
    model is loaded into, around the samples. Base and shield keep per-world memory:
    `forget_ended` clears it for worlds whose episode ended.
    """

    def __init__(self, shield: SafetyShield | None = None, base: Policy | None = None, scale: float = 1.0):
        self.shield = shield
        self.base = base
        self._samples = Samples()
        self.team = acting_team(self._samples, base, scale, shield)

    def reset(self, n_worlds: int) -> None:
        self.team.reset(n_worlds)

    def __call__(self, action: torch.Tensor, obs: torch.Tensor, spec) -> np.ndarray:
        """The env's actions (W, N, 2) (fraction of pursuer_speed, world x/y) for the actor's
        samples `action` (W, N, 2) and the observations obs (W, N, D) they answer."""
        self._samples.actions = action.clamp(-1.0, 1.0).numpy()
        if self.team is self._samples:
            return self._samples.actions
        return self.team.act(obs.numpy(), spec)

    def forget_ended(self, ended: np.ndarray) -> None:
        """Reset the memory of worlds whose episode ended (W,) bool."""
        forget_ended(self.team, ended)


class Samples:
    """A `Policy` that acts with the actions (W, N, 2) last put in `actions`: the actor's
    samples of this decision step, as the actor inside an `ActionPath`."""

    name = "actor"

    def __init__(self):
        self.actions: np.ndarray | None = None

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        pass

    def act(self, obs: np.ndarray, spec) -> np.ndarray:
        """The samples (W, N, 2) in `actions`, as ActionPath put them (clipped to [-1, 1]); obs is not read."""
        return self.actions


def forget_ended(memory, ended: np.ndarray) -> None:
    """Reset the per-world memory (a shield or a teacher team) of worlds whose episode ended (W,) bool."""
    ids = np.flatnonzero(ended)
    if len(ids):
        memory.reset(len(ended), ids)
