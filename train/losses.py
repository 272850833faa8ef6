"""The PPO loss terms, each a small pure function of tensors (tested on hand-computed numbers)."""

from __future__ import annotations

import torch


def clipped_policy_loss(new_logp: torch.Tensor, old_logp: torch.Tensor, advantages: torch.Tensor,
                        clip: float, weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, clip fraction): -mean(w min(r A, clip(r, 1-eps, 1+eps) A)), r = exp(new - old).

    All inputs (B,); w = 1 unless `weights` are given (the decoupled objective for lagged
    samples, see behaviour_weights). The clip fraction is the share of samples whose ratio
    left [1-eps, 1+eps].
    """
    ratio = torch.exp(new_logp - old_logp)
    unclipped = ratio * advantages
    clipped = torch.clamp(ratio, 1.0 - clip, 1.0 + clip) * advantages
    surrogate = torch.minimum(unclipped, clipped)
    loss = -(surrogate if weights is None else weights * surrogate).mean()
    clip_frac = ((ratio - 1.0).abs() > clip).float().mean()
    return loss, clip_frac


BEHAVIOUR_WEIGHT_CAP = 1.0  # truncation of pi_prox / pi_behaviour (IMPALA's rho-bar)


def behaviour_weights(prox_logp: torch.Tensor, behaviour_logp: torch.Tensor, cap: float = BEHAVIOUR_WEIGHT_CAP) -> torch.Tensor:
    """min(pi_prox(a) / pi_behaviour(a), cap), all (B,): the importance weight of a sample drawn by
    an older policy, for PPO's decoupled objective (Hilton et al. 2021, "Batch size-invariance
    for policy optimization"): the clip range is centred on the proximal policy (the weights
    at the start of the update), and the weight accounts for the policy that really acted.
    Truncated at `cap` so that one unlikely old sample cannot dominate."""
    return torch.exp(prox_logp - behaviour_logp).clamp(max=cap)


def gaussian_kl(mean_p: torch.Tensor, log_std_p: torch.Tensor, mean_q: torch.Tensor, log_std_q: torch.Tensor) -> torch.Tensor:
    """KL(p || q) (...,) of two diagonal Gaussians given as means and log stds (..., D), summed over D."""
    var_ratio = torch.exp(2.0 * (log_std_p - log_std_q))
    mean_term = ((mean_p - mean_q) * torch.exp(-log_std_q)) ** 2
    return 0.5 * (var_ratio + mean_term - 1.0).sum(-1) + (log_std_q - log_std_p).sum(-1)


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
