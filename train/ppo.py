"""One PPO / MAPPO update over a filled rollout: GAE, then epochs of shuffled minibatches."""

from __future__ import annotations

import torch
from torch import nn

from .agent import ActorCritic
from .config import PPOConfig
from .critic_worker import CriticWorker
from .gae import compute_gae, next_values_from
from .losses import behaviour_weights, clipped_policy_loss, gaussian_kl, normalise, scaled_value_loss
from .networks import gaussian_entropy, gaussian_log_prob
from .storage import Rollout


STAT_NAMES = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac", "grad_norm")


def advantages_and_returns(buf: Rollout, gamma: float, lam: float) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """(advantages (T, B), returns (T, B), the (T, B) streams used), B = W * N."""
    s = buf.flat_streams()
    s["next_values"] = next_values_from(s["values"], s["last_value"], s["truncated"], s["final_values"])
    s["done"] = s["terminated"] | s["truncated"]
    adv, ret = compute_gae(s["rewards"], s["values"], s["next_values"], s["terminated"], s["done"], gamma, lam)
    return adv, ret, s


#: with ppo.grad_clip "separate", the per-step statistics logged beside STAT_NAMES (whose
#: grad_norm stays the norm of both networks' gradients together, as with "joint")
SEPARATE_NORM_NAMES = ("actor_grad_norm", "critic_grad_norm")


class ParameterLists:
    """A model's parameters as lists, made once per update: every one, the actor's, the critic's.

    clip_gradients needs them at every minibatch step; walking the module tree for them each
    time (model.parameters()) cost about 75 us of the step's 4 ms (docs/experiments.md, section 7).
    The lists hold the Parameter objects themselves, which the optimiser changes in place, so
    they stay right for as long as the model keeps its parameters.
    """

    def __init__(self, model: ActorCritic):
        self.every = list(model.parameters())
        self.actor = list(model.actor.parameters())
        actor_ids = {id(p) for p in self.actor}
        self.critic = [p for p in self.every if id(p) not in actor_ids]


def clip_gradients(model: ActorCritic, cfg: PPOConfig, params: ParameterLists | None = None) -> tuple[torch.Tensor, ...]:
    """Clip the gradients now in `model` by cfg.max_grad_norm and return their norms before it.

    "joint": one norm over every parameter, scaled down together (a large value gradient then
    shrinks the policy's step too); returns (norm,). "separate": the actor's parameters and the
    rest (the critic) each by their own norm; returns (norm of both, actor's norm, critic's norm).
    params: the model's ParameterLists, where the caller keeps them (made here otherwise).
    """
    params = params or ParameterLists(model)
    if cfg.grad_clip == "joint":
        return (nn.utils.clip_grad_norm_(params.every, cfg.max_grad_norm),)
    actor_norm = nn.utils.clip_grad_norm_(params.actor, cfg.max_grad_norm)
    critic_norm = nn.utils.clip_grad_norm_(params.critic, cfg.max_grad_norm)
    return torch.hypot(actor_norm, critic_norm), actor_norm, critic_norm


def explained_variance(pred: torch.Tensor, target: torch.Tensor) -> float:
    var = target.var(unbiased=False)
    return float("nan") if var < 1e-12 else float(1.0 - (target - pred).var(unbiased=False) / var)


def teacher_labels_needed(cfg: PPOConfig, update: int) -> bool:
    """Whether the update about to run uses the teacher's labels (its rollout must carry them)."""
    return teacher_weight(cfg, update) > 0


def teacher_weight(cfg: PPOConfig, update: int) -> float:
    """The teacher's weight in the update about to run (0-based count of finished updates):
    cfg.teacher_coef, falling linearly to 0 over cfg.teacher_updates updates when that is set."""
    if cfg.teacher_updates <= 0:
        return cfg.teacher_coef
    return cfg.teacher_coef * max(1.0 - update / cfg.teacher_updates, 0.0)


def ppo_update(model: ActorCritic, optimizer: torch.optim.Optimizer, buf: Rollout, cfg: PPOConfig,
               gamma: float, generator: torch.Generator, lagged: bool = False,
               anchor: nn.Module | None = None, critic_worker: CriticWorker | None = None,
               critic_only: bool = False, teacher_weight: float = 0.0) -> dict[str, float]:
    """Run cfg.epochs passes of minibatch gradient steps; returns mean loss statistics.

    lagged: the rollout was sampled by an older policy than the model's (run.overlap); the
    update then uses the decoupled objective (losses.behaviour_weights): ratios against the
    model as it is now, each sample weighted by how much likelier the model finds it than
    the policy that acted. Without lag the two policies are one and this is plain PPO.
    critic_worker: computes the critic's half of every gradient step in its own process, on
    the model's (shared) critic, while this one computes the actor's (train/critic_worker.py).
    critic_only: the actor is held (no gradient reaches it, so Adam leaves it and its moments
    alone) and only the critic learns: ppo.critic_warmup, after a start with a fresh critic.
    The policy statistics are still computed, on the held actor.
    teacher_weight: adds weight x the squared distance of the actor's mean from the teacher's
    action stored with each transition (buf.teacher_actions): kickstarting (Schmitt et al.
    2018), a pull toward the team in the states the policy itself visits. Only where
    buf.teacher_mask is 1: elsewhere the label pulls on nothing (ppo.teacher_from_step).
    """
    adv, ret, _ = advantages_and_returns(buf, gamma, cfg.gae_lambda)
    n = buf.n_transitions
    obs = buf.obs.reshape(n, -1)
    actions = buf.actions.reshape(n, 2)
    old_logp = buf.logp.reshape(n)
    weights = None
    if lagged:
        with torch.no_grad():
            mean, log_std = model.actor(obs, model.spec)
            prox_logp = gaussian_log_prob(mean, log_std.exp(), actions).sum(-1)
        weights = behaviour_weights(prox_logp, old_logp)
        old_logp = prox_logp
    adv, ret = adv.reshape(n), ret.reshape(n)
    anchored = anchor is not None and cfg.anchor_coef > 0
    if anchored:
        with torch.no_grad():  # the anchor never moves: its outputs are computed once per update
            anchor_mean, anchor_log_std = anchor(obs, model.spec)
    anchor_kls: list[torch.Tensor] = []
    taught = teacher_weight > 0
    teacher_actions = buf.teacher_actions.reshape(n, 2)
    teacher_mask = buf.teacher_mask.unsqueeze(-1).expand(-1, -1, buf.N).reshape(n)
    teacher_errors: list[torch.Tensor] = []
    states = None
    if model.algo == "mappo":
        states = buf.states.unsqueeze(2).expand(-1, -1, buf.N, -1).reshape(n, -1)
        model.value_norm.update(ret)
        targets, target_std = model.value_norm.normalise(ret), None
    else:
        targets = ret
        target_std = float(ret.std(unbiased=False)) if cfg.value_scaling else None
    if critic_worker is not None:
        critic_worker.load(obs, states, targets, target_std, cfg.vf_coef)
    # n // minibatch_size minibatches per epoch; a remainder (1026 = 4 x 256 + 2 in classic) is
    # shared among them (sizes differ by at most one), so every transition is used once per epoch
    n_minibatches = max(n // cfg.minibatch_size, 1)
    params = ParameterLists(model)
    stats: list[torch.Tensor] = []  # per gradient step, the STAT_NAMES values (and SEPARATE_NORM_NAMES)
    for _ in range(cfg.epochs):
        perm = torch.randperm(n, generator=generator)
        for idx in torch.tensor_split(perm, n_minibatches):
            if critic_worker is not None:
                critic_worker.request(idx)  # the critic's gradient, computed meanwhile in its process
            mb_obs, mb_old_logp = obs[idx], old_logp[idx]
            mean, log_std = model.actor(mb_obs, model.spec)
            std = log_std.exp()
            new_logp = gaussian_log_prob(mean, std, actions[idx]).sum(-1)
            entropy = gaussian_entropy(std).sum(-1).mean()
            a = normalise(adv[idx]) if cfg.norm_adv else adv[idx]
            pg_loss, clip_frac = clipped_policy_loss(new_logp, mb_old_logp, a, cfg.clip,
                                                     weights[idx] if weights is not None else None)
            actor_loss = pg_loss - cfg.ent_coef * entropy
            if anchored:
                anchor_kl = gaussian_kl(mean, log_std, anchor_mean[idx], anchor_log_std[idx]).mean()
                actor_loss = actor_loss + cfg.anchor_coef * anchor_kl
                anchor_kls.append(anchor_kl.detach())
            if taught:
                # the mean over the whole minibatch: a label that counts pulls as hard however
                # few others count beside it
                mask = teacher_mask[idx]
                squared = ((mean - teacher_actions[idx]) ** 2).sum(-1)
                actor_loss = actor_loss + teacher_weight * (mask * squared).mean()
                teacher_errors.append(torch.stack([(mask * squared).sum().detach(), mask.sum()]))
            loss = None if critic_only else actor_loss
            if critic_worker is None:
                v = model.raw_value(mb_obs, states[idx] if states is not None else None)
                v_loss = scaled_value_loss(v, targets[idx], target_std)
                loss = cfg.vf_coef * v_loss if loss is None else loss + cfg.vf_coef * v_loss
            optimizer.zero_grad(set_to_none=True)
            if loss is not None:
                loss.backward()
            if critic_worker is not None:
                v_loss = critic_worker.collect()  # and the critic's .grad is set
            grad_norms = clip_gradients(model, cfg, params)
            optimizer.step()
            with torch.no_grad():
                log_ratio = new_logp - mb_old_logp
                approx_kl = ((log_ratio.exp() - 1.0) - log_ratio).mean()
                stats.append(torch.stack([pg_loss, v_loss, entropy, approx_kl, clip_frac, *grad_norms]))
    means = torch.stack(stats).double().mean(0).tolist()  # at least one step per epoch
    out = dict(zip(STAT_NAMES + SEPARATE_NORM_NAMES, means))
    with torch.no_grad():
        pred = buf.values.reshape(n)
    out["explained_variance"] = explained_variance(pred, ret)
    out["return_std"] = float(ret.std(unbiased=False))
    out["log_std"] = float(model.actor.log_std.detach().mean())
    out["critic_only"] = float(critic_only)
    if anchored:
        out["anchor_kl"] = float(torch.stack(anchor_kls).mean())
    if taught:
        error_sum, counted = torch.stack(teacher_errors).sum(0).tolist()
        if counted > 0:  # the squared distance where labels count
            out["teacher_mse"] = error_sum / counted
        out["teacher_coverage"] = float(teacher_mask.mean())
    if weights is not None:
        out["behaviour_weight"] = float(weights.mean())  # 1: the lag changed nothing
    return out
