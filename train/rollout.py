"""Collect rollouts from a PursuitEnv with the current actor: one batched forward per decision step."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .agent import ActorCritic
from .networks import flush_tiny
from .storage import Rollout


@dataclasses.dataclass
class RolloutStats:
    """What one rollout saw: finished episodes and the mean per-step reward terms (per pursuer)."""

    episodes: list = dataclasses.field(default_factory=list)
    reward_terms: dict[str, float] = dataclasses.field(default_factory=dict)
    seconds: float = 0.0


class Collector:
    """Owns the running observation of a training env between updates (episodes span updates)."""

    def __init__(self, env, model: ActorCritic, generator: torch.Generator):
        self.env = env
        self.model = model
        self.generator = generator
        self.needs_state = model.algo == "mappo"
        self.obs = flush_tiny(torch.as_tensor(env.reset()))
        self.state = self._state()

    def _state(self) -> torch.Tensor | None:
        return flush_tiny(torch.as_tensor(self.env.global_state())) if self.needs_state else None

    def _values(self, obs: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """obs (W, N, D), state (W, S) -> values (W, N) in reward units."""
        if state is not None:
            state = state.unsqueeze(1).expand(-1, obs.shape[1], -1)
        return self.model.value(obs, state)

    @torch.no_grad()
    def collect(self, buf: Rollout) -> RolloutStats:
        stats = RolloutStats()
        term_sums: dict[str, float] = {}
        spec = self.model.spec
        for t in range(buf.T):
            obs, state = self.obs, self.state
            mean, log_std = self.model.actor(obs, spec)
            action = mean + log_std.exp() * torch.randn(mean.shape, generator=self.generator)
            logp = torch.distributions.Normal(mean, log_std.exp()).log_prob(action).sum(-1)
            buf.obs[t] = obs
            buf.actions[t] = action
            buf.logp[t] = logp
            buf.values[t] = self._values(obs, state)
            if state is not None:
                buf.states[t] = state
            next_obs, reward, terminated, truncated, info = self.env.step(action.clamp(-1.0, 1.0).numpy())
            buf.rewards[t] = torch.as_tensor(reward)
            buf.terminated[t] = torch.as_tensor(terminated)
            buf.truncated[t] = torch.as_tensor(truncated)
            buf.final_values[t] = 0.0
            if truncated.any():
                idx = torch.as_tensor(np.flatnonzero(truncated))
                f_obs = flush_tiny(torch.as_tensor(info["final_obs"])[idx])
                f_state = flush_tiny(torch.as_tensor(info["final_state"])[idx]) if state is not None else None
                buf.final_values[t, idx] = self._values(f_obs, f_state)
            for k, v in info["reward_terms"].items():
                term_sums[k] = term_sums.get(k, 0.0) + float(v.mean())
            stats.episodes.extend(info["episodes"])
            self.obs = flush_tiny(torch.as_tensor(next_obs))
            self.state = self._state()
        buf.last_value = self._values(self.obs, self.state)
        stats.reward_terms = {k: v / buf.T for k, v in term_sums.items()}
        return stats
