"""Generalised advantage estimation that tells terminations from truncations.

For each step t of a rollout (T steps, B parallel agent streams):
    delta_t = r_t + gamma * (1 - terminated_t) * V_next_t - V_t
    A_t     = delta_t + gamma * lambda * (1 - done_t) * A_{t+1}
V_next_t is the value of the observation that followed step t: V(obs_{t+1}) normally, the
value of info["final_obs"] when the episode was truncated there (the env auto-resets, so
obs_{t+1} belongs to the next episode), and irrelevant when it terminated. `done` (either end)
stops the recursion so no advantage leaks across episodes. `gamma` may be a 0-d tensor that
requires grad (learnable discount); the result is then differentiable in it.
"""

from __future__ import annotations

import torch


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    done: torch.Tensor,
    gamma: float | torch.Tensor,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(advantages, returns), both (T, B), from rewards/values/next_values (T, B) and bool flags (T, B).

    returns = advantages + values (the value targets).
    """
    shape = rewards.shape
    for name, x in (("values", values), ("next_values", next_values), ("terminated", terminated), ("done", done)):
        if x.shape != shape:
            raise ValueError(f"compute_gae: {name} has shape {tuple(x.shape)}, rewards {tuple(shape)}")
    not_term = 1.0 - terminated.to(rewards.dtype)
    not_done = 1.0 - done.to(rewards.dtype)
    deltas = rewards + gamma * not_term * next_values - values
    carry = torch.zeros_like(rewards[0])
    out = []
    for t in range(shape[0] - 1, -1, -1):
        carry = deltas[t] + gamma * lam * not_done[t] * carry
        out.append(carry)
    advantages = torch.stack(out[::-1])
    return advantages, advantages + values


def next_values_from(values: torch.Tensor, last_value: torch.Tensor, truncated: torch.Tensor,
                     final_values: torch.Tensor) -> torch.Tensor:
    """V_next (T, B): values shifted by one with last_value (B,) at the end, and final_values
    (T, B) (the values of info["final_obs"]) where truncated (T, B) is set."""
    shifted = torch.cat([values[1:], last_value.unsqueeze(0)], dim=0)
    return torch.where(truncated, final_values, shifted)
