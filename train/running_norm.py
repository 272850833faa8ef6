"""Running mean and variance (parallel Welford merge), for MAPPO's value normalisation."""

from __future__ import annotations

import torch


class RunningMeanStd:
    """Mean and std of every value seen so far; state is three floats, saved in checkpoints.

    Cumulative, not a moving average: MAPPO's own ValueNorm (Yu et al. 2022) is a debiased
    exponential average with beta = 0.99999 per update, whose memory of 1e5 updates is longer
    than any run here; with equal batches both weight every update alike."""

    def __init__(self, epsilon: float = 1e-4):
        self.mean = 0.0
        self.var = 1.0
        self.count = epsilon

    def update(self, x: torch.Tensor) -> None:
        x = x.detach().double().reshape(-1)
        if x.numel() == 0:
            return
        b_mean, b_var, b_count = x.mean().item(), x.var(unbiased=False).item(), x.numel()
        delta = b_mean - self.mean
        total = self.count + b_count
        self.mean += delta * b_count / total
        m2 = self.var * self.count + b_var * b_count + delta**2 * self.count * b_count / total
        self.var = m2 / total
        self.count = total

    @property
    def std(self) -> float:
        return max(self.var, 1e-8) ** 0.5

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        """(x - mean) / std, elementwise, any shape (values in reward units -> normalised units)."""
        return (x - self.mean) / self.std

    def denormalise(self, x: torch.Tensor) -> torch.Tensor:
        """x * std + mean, elementwise, any shape (the inverse of `normalise`)."""
        return x * self.std + self.mean

    def state_dict(self) -> dict[str, float]:
        return {"mean": float(self.mean), "var": float(self.var), "count": float(self.count)}

    def load_state_dict(self, state: dict[str, float]) -> None:
        self.mean, self.var, self.count = float(state["mean"]), float(state["var"]), float(state["count"])
