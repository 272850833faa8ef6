"""The discount factor, fixed or learned by meta-gradient (the reference study's "learnable gamma").

The reference study made gamma a network parameter without saying what objective moves it;
gamma cannot be learned by the PPO loss itself (a smaller gamma always makes value targets
easier). Here it is learned the way Xu et al. (2018, "Meta-Gradient Reinforcement Learning")
do it: gamma = sigmoid(logit) shapes the advantages of the inner policy-gradient step
    L_in(theta, gamma) = -mean(log pi_theta(a|s) * A_gamma),
and gamma is judged by how much one such step would improve a fixed outer objective
    L_out(theta) = -mean(log pi_theta(a|s) * A_outer),  A_outer from the fixed gamma_outer.
To first order, theta' = theta - lr * grad_theta L_in, so
    L_out(theta') ~ L_out(theta) - lr * <grad_theta L_out, grad_theta L_in(gamma)>,
and its derivative in gamma needs one second-order backward pass through grad_theta L_in.
The logit takes one Adam step (gamma_meta_lr) per update down that derivative, and is then
held within the logits of LEARNABLE_START: gamma stays in [1e-4, 1 - 1e-4], where the float32
sigmoid neither rounds to 1 (it does past a logit of about 16.6, where its gradient is 0 and
gamma would stay at 1 for good) nor creeps toward 0 where a step hardly moves it. The current
gamma is logged every update (metrics.jsonl key `gamma`) so one can watch it move.
"""

from __future__ import annotations

import math

import torch

from .gae import compute_gae
from .losses import normalise


#: where a learned gamma may start: sigmoid(logit) reaches 0 and 1 only at an infinite logit,
#: and near them one Adam step on the logit hardly moves gamma
LEARNABLE_START = (1e-4, 1.0 - 1e-4)


def logit(p: float) -> float:
    """log(p / (1 - p)) for p in (0, 1): the logit whose sigmoid is p."""
    return math.log(p / (1.0 - p))


#: the logit is held within these after every meta step, so a learned gamma stays in LEARNABLE_START
LOGIT_BOUNDS = (logit(LEARNABLE_START[0]), logit(LEARNABLE_START[1]))


class Discount:
    """gamma as a float (fixed) or sigmoid(logit) with an Adam optimiser (learned)."""

    def __init__(self, gamma: float, learnable: bool, meta_lr: float, outer_gamma: float):
        lo, hi = LEARNABLE_START
        if learnable and not lo <= gamma <= hi:
            raise ValueError(f"learnable discount: start gamma {gamma:g} lies outside [{lo:g}, {hi:g}]")
        self.learnable = learnable
        self.outer_gamma = outer_gamma
        g = min(max(gamma, 1e-4), 1.0 - 1e-4)
        self.logit = torch.nn.Parameter(torch.tensor(logit(g), dtype=torch.float32))
        self._fixed = gamma
        self.optimizer = torch.optim.Adam([self.logit], lr=meta_lr) if learnable else None

    @property
    def value(self) -> float:
        return float(torch.sigmoid(self.logit).item()) if self.learnable else self._fixed

    def meta_step(self, actor, spec, obs, actions, rewards, values, next_values, terminated, done,
                  lam: float, inner_lr: float, sample: torch.Tensor) -> float:
        """One meta-gradient step on the logit, then the logit held within LOGIT_BOUNDS; returns
        the meta-gradient d L_out / d gamma at the gamma the step started from.

        obs (T, B, D), actions (T, B, 2), rewards/values/next_values (T, B), terminated/done (T, B)
        bool; `sample` indexes the flattened T*B transitions used for the policy terms.
        """
        gamma = torch.sigmoid(self.logit)
        adv_in, _ = compute_gae(rewards, values, next_values, terminated, done, gamma, lam)
        with torch.no_grad():
            adv_out, _ = compute_gae(rewards, values, next_values, terminated, done, self.outer_gamma, lam)
        adv_in = normalise(adv_in.reshape(-1)[sample])
        adv_out = normalise(adv_out.reshape(-1)[sample])
        flat_obs = obs.reshape(-1, obs.shape[-1])[sample]
        flat_act = actions.reshape(-1, actions.shape[-1])[sample]
        params = [p for p in actor.parameters() if p.requires_grad]
        logp = actor.distribution(flat_obs, spec).log_prob(flat_act).sum(-1)
        g_in = torch.autograd.grad(-(logp * adv_in).mean(), params, create_graph=True)
        g_out = torch.autograd.grad(-(logp * adv_out.detach()).mean(), params, retain_graph=True)
        inner_product = sum((a * b.detach()).sum() for a, b in zip(g_in, g_out))
        meta_loss = -inner_lr * inner_product
        d_logit, d_gamma = torch.autograd.grad(meta_loss, [self.logit, gamma])
        self.optimizer.zero_grad()
        self.logit.grad = d_logit
        self.optimizer.step()
        with torch.no_grad():
            self.logit.clamp_(*LOGIT_BOUNDS)
        return float(d_gamma)

    def state_dict(self) -> dict:
        out = {"logit": self.logit.detach().clone(), "fixed": self._fixed}
        if self.optimizer is not None:
            out["optimizer"] = self.optimizer.state_dict()
        return out

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            self.logit.copy_(state["logit"])
        if self.optimizer is not None and "optimizer" in state:
            self.optimizer.load_state_dict(state["optimizer"])
