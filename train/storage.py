"""Preallocated rollout storage: T decision steps of W worlds with N pursuers each."""

from __future__ import annotations

import torch


class Rollout:
    """Tensors filled step by step by the collector, read whole by the update.

    obs (T, W, N, D) float32 observations; actions (T, W, N, 2) sampled (unclipped) Gaussian
    actions (fractions of pursuer_speed, world x/y); logp (T, W, N) their log-probabilities; values (T, W, N) value estimates (reward
    units); rewards (T, W, N); terminated / truncated (T, W) bool episode ends after the step;
    final_values (T, W, N) values of info["final_obs"] where truncated (else 0);
    states (T, W, S) global states (MAPPO only, S = 0 otherwise); last_value (W, N) value of
    the observation after the last step (the bootstrap); teacher_actions (T, W, N, 2) the
    teacher team's actions for the stored observations, in [-1, 1] (ppo.teacher_coef; else 0);
    teacher_mask (T, W) 1 where those labels count, 0 where not (ppo.teacher_from_step).
    """

    def __init__(self, T: int, W: int, N: int, obs_dim: int, state_dim: int = 0):
        self.T, self.W, self.N = T, W, N
        self.obs = torch.zeros(T, W, N, obs_dim)
        self.actions = torch.zeros(T, W, N, 2)
        self.logp = torch.zeros(T, W, N)
        self.values = torch.zeros(T, W, N)
        self.rewards = torch.zeros(T, W, N)
        self.terminated = torch.zeros(T, W, dtype=torch.bool)
        self.truncated = torch.zeros(T, W, dtype=torch.bool)
        self.final_values = torch.zeros(T, W, N)
        self.states = torch.zeros(T, W, state_dim)
        self.last_value = torch.zeros(W, N)
        self.teacher_actions = torch.zeros(T, W, N, 2)
        self.teacher_mask = torch.ones(T, W)

    def share_memory(self) -> "Rollout":
        """Moves every tensor into shared memory (a rollout filled by another process); returns self."""
        for value in vars(self).values():
            if isinstance(value, torch.Tensor):
                value.share_memory_()
        return self

    @property
    def n_transitions(self) -> int:
        return self.T * self.W * self.N

    def flat_streams(self) -> dict[str, torch.Tensor]:
        """Per-step tensors as (T, B) streams, B = W * N (world-level flags repeated per pursuer)."""
        T, B = self.T, self.W * self.N

        def rep(x: torch.Tensor) -> torch.Tensor:
            return x.unsqueeze(-1).expand(T, self.W, self.N).reshape(T, B)

        return {
            "rewards": self.rewards.reshape(T, B),
            "values": self.values.reshape(T, B),
            "final_values": self.final_values.reshape(T, B),
            "terminated": rep(self.terminated),
            "truncated": rep(self.truncated),
            "last_value": self.last_value.reshape(B),
        }
