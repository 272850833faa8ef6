"""The learner's networks in one module: a shared actor plus a per-agent or centralised critic.

`ppo` (independent PPO with parameter sharing): the critic sees what the actor sees.
`mappo`: the critic sees env.global_state() and the pursuer's own observation, and predicts
values normalised by running return statistics (value normalisation).
"""

from __future__ import annotations

import torch
from torch import nn

from pursuit_mj.obs_spec import ObsSpec

from .config import TrainConfig
from .networks import Actor, CentralCritic, Critic
from .running_norm import RunningMeanStd


class ActorCritic(nn.Module):
    def __init__(self, spec: ObsSpec, state_dim: int, cfg: TrainConfig):
        super().__init__()
        self.spec = spec
        self.algo = cfg.algo
        self.actor = Actor(spec, cfg.net)
        if cfg.algo == "mappo":
            self.critic: nn.Module = CentralCritic(spec, state_dim, cfg.net)
            self.value_norm: RunningMeanStd | None = RunningMeanStd()
        else:
            self.critic = Critic(spec, cfg.net)
            self.value_norm = None

    def raw_value(self, obs: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """Critic output (...,): reward units for ppo, normalised units for mappo.

        obs (..., obs_dim); state (..., state_dim) for mappo (same leading shape), else unused.
        """
        if self.algo == "mappo":
            if state is None:
                raise ValueError("mappo critic needs the global state")
            return self.critic(state, obs)
        return self.critic(obs, self.spec)

    def world_value(self, obs: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """Values (W, N) in reward units of obs (W, N, obs_dim); state (W, S) is one per world (mappo)."""
        if state is not None:
            state = state.unsqueeze(1).expand(-1, obs.shape[1], -1)
        return self.value(obs, state)

    def value(self, obs: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """Value estimate (...,) in reward units."""
        v = self.raw_value(obs, state)
        return self.value_norm.denormalise(v) if self.value_norm is not None else v
