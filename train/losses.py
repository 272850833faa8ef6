"""The PPO loss terms, each a small pure function of tensors (tested on hand-computed numbers)."""

from __future__ import annotations

import torch


def clipped_policy_loss(new_logp: torch.Tensor, old_logp: torch.Tensor, advantages: torch.Tensor,
                        clip: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, clip fraction): -mean(min(r A, clip(r, 1-eps, 1+eps) A)), r = exp(new - old).

    All inputs (B,); the clip fraction is the share of samples whose ratio left [1-eps, 1+eps].
    """
    ratio = torch.exp(new_logp - old_logp)
    unclipped = ratio * advantages
    clipped = torch.clamp(ratio, 1.0 - clip, 1.0 + clip) * advantages
    loss = -torch.minimum(unclipped, clipped).mean()
    clip_frac = ((ratio - 1.0).abs() > clip).float().mean()
    return loss, clip_frac


def scaled_value_loss(values: torch.Tensor, targets: torch.Tensor, target_std: float | torch.Tensor | None) -> torch.Tensor:
    """mean((V - target)^2) / std(targets) (the reference study's scaling); unscaled when target_std is None.

    target_std is the std of the whole rollout's targets, fixed for the update, so the scale does
    not jump between minibatches; values below 1e-8 count as 1e-8.
    """
    mse = ((values - targets) ** 2).mean()
    if target_std is None:
        return mse
    std = torch.as_tensor(target_std, dtype=mse.dtype).clamp_min(1e-8)
    return mse / std


def normalise(x: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Zero mean, unit std (population std); a single element becomes 0."""
    return (x - x.mean()) / (x.std(unbiased=False) + eps)
