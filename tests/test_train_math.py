"""The maths of train/: GAE against a plain loop, PPO losses on hand-computed numbers, pooling."""

import math

import numpy as np
import pytest
import torch

from pursuit_mj.obs_spec import ObsSpec
from train.config import NetConfig
from train.gae import compute_gae, next_values_from
from train.losses import behaviour_weights, clipped_policy_loss, gaussian_kl, normalise, scaled_value_loss
from train.networks import Actor, Critic, EntityEncoder, gaussian_entropy, gaussian_log_prob, masked_mean, tanh
from train.running_norm import RunningMeanStd


def reference_gae(rewards, values, obs_values_next, final_values, terminated, truncated, gamma, lam):
    """One stream, written the slow obvious way: walk back, restart at every episode end."""
    T = len(rewards)
    adv = np.zeros(T)
    running = 0.0
    for t in reversed(range(T)):
        if terminated[t]:
            bootstrap = 0.0
        elif truncated[t]:
            bootstrap = final_values[t]
        else:
            bootstrap = obs_values_next[t]
        delta = rewards[t] + gamma * bootstrap - values[t]
        if terminated[t] or truncated[t]:
            running = delta
        else:
            running = delta + gamma * lam * running
        adv[t] = running
    return adv, adv + values


def test_gae_matches_plain_loop_with_terminations_and_truncations():
    rng = np.random.default_rng(3)
    T, B = 17, 5
    rewards = rng.normal(size=(T, B))
    values = rng.normal(size=(T, B))
    last = rng.normal(size=B)
    final = rng.normal(size=(T, B))
    term = rng.random((T, B)) < 0.12
    trunc = (rng.random((T, B)) < 0.12) & ~term
    term[T - 1, 0] = True  # an episode end on the last step
    trunc[3, 1] = True
    term[3, 1] = False
    gamma, lam = 0.97, 0.9
    t = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
    nv = next_values_from(t(values), t(last), torch.as_tensor(trunc), t(final))
    adv, ret = compute_gae(t(rewards), t(values), nv, torch.as_tensor(term), torch.as_tensor(term | trunc), gamma, lam)
    for b in range(B):
        obs_next = np.append(values[1:, b], last[b])
        ref_adv, ref_ret = reference_gae(rewards[:, b], values[:, b], obs_next, final[:, b], term[:, b], trunc[:, b], gamma, lam)
        np.testing.assert_allclose(adv[:, b].numpy(), ref_adv, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ret[:, b].numpy(), ref_ret, rtol=1e-12, atol=1e-12)


def test_gae_hand_computed_truncation_bootstraps_from_final_obs():
    # two steps; step 0 truncated (bootstrap from final value 2.0), step 1 runs on (last value 4.0)
    rewards = torch.tensor([[1.0], [0.5]])
    values = torch.tensor([[0.0], [1.0]])
    trunc = torch.tensor([[True], [False]])
    term = torch.tensor([[False], [False]])
    nv = next_values_from(values, torch.tensor([4.0]), trunc, torch.tensor([[2.0], [0.0]]))
    adv, _ = compute_gae(rewards, values, nv, term, trunc, 0.5, 1.0)
    assert adv[1, 0].item() == pytest.approx(0.5 + 0.5 * 4.0 - 1.0)
    assert adv[0, 0].item() == pytest.approx(1.0 + 0.5 * 2.0 - 0.0)  # no leak from step 1


def test_gae_is_differentiable_in_gamma():
    gamma = torch.tensor(0.9, requires_grad=True)
    adv, _ = compute_gae(torch.ones(3, 1), torch.zeros(3, 1), torch.ones(3, 1), torch.zeros(3, 1, dtype=torch.bool),
                         torch.zeros(3, 1, dtype=torch.bool), gamma, 1.0)
    adv.sum().backward()
    assert gamma.grad is not None and gamma.grad.item() > 0


def test_clipped_policy_loss_hand_computed():
    old = torch.zeros(4)
    new = torch.log(torch.tensor([1.5, 0.5, 1.1, 0.7]))
    adv = torch.tensor([1.0, 1.0, -2.0, -1.0])
    loss, frac = clipped_policy_loss(new, old, adv, clip=0.2)
    # min(r A, clip(r) A): 1.5 -> min(1.5, 1.2) = 1.2; 0.5 -> min(0.5, 0.8) = 0.5;
    # 1.1, A=-2 -> min(-2.2, -2.2) = -2.2; 0.7, A=-1 -> min(-0.7, -0.8) = -0.8
    assert loss.item() == pytest.approx(-(1.2 + 0.5 - 2.2 - 0.8) / 4)
    assert frac.item() == pytest.approx(0.75)


def test_gaussian_kl_hand_computed_and_as_torch_computes_it():
    # KL(N(0, 1) || N(1, 2)) = log 2 + (1 + 1) / 8 - 1/2 per dimension; identical Gaussians: 0
    mean_p, log_std_p = torch.zeros(1, 2), torch.zeros(1, 2)
    mean_q, log_std_q = torch.ones(1, 2), torch.full((1, 2), math.log(2.0))
    kl = gaussian_kl(mean_p, log_std_p, mean_q, log_std_q)
    assert kl.shape == (1,)
    assert kl.item() == pytest.approx(2 * (math.log(2.0) + 2 / 8 - 0.5))
    assert gaussian_kl(mean_q, log_std_q, mean_q, log_std_q).item() == 0.0
    g = torch.Generator().manual_seed(0)
    mp, mq, sp, sq = (torch.randn(5, 2, generator=g) for _ in range(4))
    expected = torch.distributions.kl_divergence(torch.distributions.Normal(mp, sp.exp()),
                                                 torch.distributions.Normal(mq, sq.exp())).sum(-1)
    torch.testing.assert_close(gaussian_kl(mp, sp, mq, sq), expected)


def test_decoupled_objective_weights_each_sample_by_its_capped_importance():
    behaviour = torch.log(torch.tensor([0.5, 0.2, 0.4, 0.1]))
    prox = torch.log(torch.tensor([0.25, 0.2, 0.8, 0.1]))  # the model now: half as likely, same, twice, same
    w = behaviour_weights(prox, behaviour)
    torch.testing.assert_close(w, torch.tensor([0.5, 1.0, 1.0, 1.0]))  # 2.0 is capped at 1
    new = prox + torch.log(torch.tensor([1.5, 0.5, 1.1, 0.7]))  # ratios against the model now, as above
    adv = torch.tensor([1.0, 1.0, -2.0, -1.0])
    loss, frac = clipped_policy_loss(new, prox, adv, clip=0.2, weights=w)
    assert loss.item() == pytest.approx(-(0.5 * 1.2 + 0.5 - 2.2 - 0.8) / 4)
    assert frac.item() == pytest.approx(0.75)


def _random_rollout(spec: ObsSpec, T: int, W: int = 2, N: int = 2):
    """A rollout (T, W, N) of uniform observations and normal rewards, seeded; actions unset."""
    from train.storage import Rollout

    torch.manual_seed(0)
    buf = Rollout(T, W, N, spec.dim)
    buf.obs.uniform_(-1, 1)
    buf.rewards.normal_()
    return buf


def _model_that_acted(buf, spec: ObsSpec, cfg):
    """A seeded ActorCritic; buf's actions and log-probs become samples of its own actor."""
    from train.agent import ActorCritic

    torch.manual_seed(1)
    model = ActorCritic(spec, 0, cfg)
    with torch.no_grad():
        mean, log_std = model.actor(buf.obs, spec)
        buf.actions.copy_(mean + 0.3 * torch.randn(mean.shape, generator=torch.Generator().manual_seed(2)))
        buf.logp.copy_(gaussian_log_prob(mean, log_std.exp(), buf.actions).sum(-1))
    return model


def test_a_lagged_update_of_fresh_samples_is_plain_ppo():
    """When the policy that acted is the model itself, every weight is 1 and the decoupled update
    moves the weights as plain PPO does."""
    from train.config import load_train_config
    from train.ppo import ppo_update

    cfg = load_train_config([], ["ppo.epochs=2", "ppo.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]"])
    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    buf.terminated[3, 0] = True
    results = []
    for lagged in (False, True):
        model = _model_that_acted(buf, spec, cfg)
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)
        stats = ppo_update(model, opt, buf, cfg.ppo, 0.99, torch.Generator().manual_seed(3), lagged=lagged)
        results.append((model.state_dict(), stats))
    (plain, _), (decoupled, stats) = results
    assert stats["behaviour_weight"] == pytest.approx(1.0)
    for k in plain:
        torch.testing.assert_close(decoupled[k], plain[k], rtol=1e-4, atol=1e-5)


def test_an_anchored_update_stays_nearer_the_anchor_and_logs_its_kl():
    """ppo.anchor_coef adds coef x KL(policy || anchor) to the loss: from the same start and
    rollout, the anchored update ends nearer the anchor (the start) than the plain one."""
    import copy

    from train.config import load_train_config
    from train.ppo import ppo_update

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=16)
    drift = {}
    for coef in (0.0, 50.0):
        cfg = load_train_config([], ["ppo.epochs=8", "ppo.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]",
                                     f"ppo.anchor_coef={coef}"])
        model = _model_that_acted(buf, spec, cfg)
        anchor = copy.deepcopy(model.actor).requires_grad_(False)
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        stats = ppo_update(model, opt, buf, cfg.ppo, 0.99, torch.Generator().manual_seed(3), anchor=anchor)
        with torch.no_grad():
            drift[coef] = float(gaussian_kl(*model.actor(buf.obs, spec), *anchor(buf.obs, spec)).mean())
        assert ("anchor_kl" in stats) == (coef > 0)  # an update without anchor logs none
    assert drift[50.0] < 0.5 * drift[0.0]


def test_clipped_loss_gradient_vanishes_outside_the_trust_region():
    new = torch.log(torch.tensor([1.5])).requires_grad_()
    loss, _ = clipped_policy_loss(new, torch.zeros(1), torch.tensor([1.0]), 0.2)
    loss.backward()
    assert new.grad.item() == 0.0


def test_value_loss_scaled_by_target_std():
    v = torch.tensor([1.0, 2.0, 3.0])
    targets = torch.tensor([2.0, 2.0, 5.0])
    mse = (1.0 + 0.0 + 4.0) / 3
    std = float(torch.tensor([2.0, 2.0, 5.0]).std(unbiased=False))  # sqrt(2)
    assert scaled_value_loss(v, targets, None).item() == pytest.approx(mse)
    assert scaled_value_loss(v, targets, std).item() == pytest.approx(mse / math.sqrt(2.0))
    assert torch.isfinite(scaled_value_loss(v, targets, 0.0))


def test_normalise():
    x = normalise(torch.tensor([1.0, 2.0, 3.0, 6.0]))
    assert x.mean().item() == pytest.approx(0.0, abs=1e-6)
    assert x.std(unbiased=False).item() == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("shape", [(3, 5), (256, 128)])  # torch.tanh below the size threshold, sigmoid above
def test_network_tanh_matches_torch_tanh_in_value_and_gradient(shape):
    x = (torch.randn(shape, generator=torch.Generator().manual_seed(1)) * 4).requires_grad_()
    y = tanh(x)
    torch.testing.assert_close(y, torch.tanh(x), atol=3e-7, rtol=0)
    weights = torch.randn(shape, generator=torch.Generator().manual_seed(2))
    (g,) = torch.autograd.grad((y * weights).sum(), x)
    torch.testing.assert_close(g, weights * (1 - torch.tanh(x.detach()) ** 2), atol=1e-6, rtol=1e-5)
    with torch.inference_mode():
        torch.testing.assert_close(tanh(x.detach()), torch.tanh(x.detach()), atol=3e-7, rtol=0)
    assert tanh(torch.tensor([-50.0, 0.0, 50.0])).tolist() == [-1.0, 0.0, 1.0]


def test_masked_mean_ignores_hidden_and_gives_zero_when_none_visible():
    codes = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]]])
    mask = torch.tensor([[1.0, 1.0, 0.0]])
    assert masked_mean(codes, mask).tolist() == [[2.0, 3.0]]
    assert masked_mean(codes, torch.zeros(1, 3)).tolist() == [[0.0, 0.0]]


def _obs(spec, rng, visible_teammates, visible_evaders):
    obs = rng.normal(size=(spec.dim,)).astype(np.float32)
    for group, vis in (("teammates", visible_teammates), ("evaders", visible_evaders)):
        for i, v in enumerate(vis):
            obs[spec.index(group, i, "visible")] = float(v)
    return obs


def test_pooled_actor_and_critic_ignore_hidden_entities():
    torch.manual_seed(0)
    spec = ObsSpec.make(4, 2, 8)
    actor, critic = Actor(spec, NetConfig()), Critic(spec, NetConfig())
    rng = np.random.default_rng(1)
    obs = _obs(spec, rng, [1, 0, 1], [0, 1])
    changed = obs.copy()
    for group, idx in (("teammates", 1), ("evaders", 0)):
        g = spec.group(group)
        lo = g.start + idx * g.width
        keep = changed[lo + g.mask_feature]
        changed[lo : lo + g.width] = rng.normal(size=g.width) * 5
        changed[lo + g.mask_feature] = keep  # still hidden
    x, y = torch.as_tensor(obs)[None], torch.as_tensor(changed)[None]
    assert torch.equal(actor(x, spec)[0], actor(y, spec)[0])
    assert torch.equal(critic(x, spec), critic(y, spec))
    visible = torch.as_tensor(_obs(spec, np.random.default_rng(1), [1, 1, 1], [0, 1]))[None]
    assert not torch.equal(actor(x, spec)[0], actor(visible, spec)[0])  # the flag does matter


def test_caught_evaders_are_left_out_of_the_pool():
    torch.manual_seed(0)
    spec = ObsSpec.make(3, 2, 8)
    actor = Actor(spec, NetConfig())
    obs = _obs(spec, np.random.default_rng(2), [1, 1], [1, 1])
    obs[spec.index("evaders", 0, "captured")] = 1.0  # caught where it stopped, still visible
    obs[spec.index("evaders", 1, "captured")] = 0.0
    moved = obs.copy()
    moved[spec.index("evaders", 0, "dx")] += 3.0
    hidden = obs.copy()
    hidden[spec.index("evaders", 0, "visible")] = 0.0
    out = [actor(torch.as_tensor(o)[None], spec)[0] for o in (obs, moved, hidden)]
    assert torch.equal(out[0], out[1]) and torch.equal(out[0], out[2])
    free = obs.copy()
    free[spec.index("evaders", 0, "captured")] = 0.0
    assert not torch.equal(out[0], actor(torch.as_tensor(free)[None], spec)[0])


def test_pooled_actor_runs_for_other_team_sizes_with_the_same_weights():
    torch.manual_seed(0)
    trained = Actor(ObsSpec.make(3, 1, 16), NetConfig())
    for n, m in ((2, 1), (6, 3)):
        spec = ObsSpec.make(n, m, 16)
        actor = Actor(spec, NetConfig())
        actor.load_state_dict(trained.state_dict())
        mean, _ = actor(torch.zeros(5, n, spec.dim), spec)
        assert mean.shape == (5, n, 2) and bool((mean.abs() <= 1).all())


def test_orthogonal_init_and_zero_biases():
    torch.manual_seed(0)
    actor = Actor(ObsSpec.make(3, 1, 16), NetConfig())
    w = actor.trunk.fuse[0].weight  # (128, 512): rows orthonormal up to the gain sqrt(2)
    np.testing.assert_allclose((w @ w.T / 2.0).detach().numpy(), np.eye(w.shape[0]), atol=1e-4)
    assert all(float(m.bias.detach().abs().max()) == 0.0 for m in actor.modules() if isinstance(m, torch.nn.Linear))


def test_running_mean_std_matches_numpy():
    rng = np.random.default_rng(0)
    chunks = [rng.normal(3.0, 2.0, size=n) for n in (10, 50, 7)]
    rms = RunningMeanStd(epsilon=0.0)
    for c in chunks:
        rms.update(torch.as_tensor(c))
    allx = np.concatenate(chunks)
    assert rms.mean == pytest.approx(allx.mean())
    assert rms.std == pytest.approx(allx.std())


def test_gaussian_log_prob_and_entropy_are_torch_normal_bit_for_bit():
    torch.manual_seed(0)
    mean = torch.randn(7, 2, requires_grad=True)
    log_std = torch.tensor([-0.5, 0.3], requires_grad=True)
    x = torch.randn(7, 2)
    grads = []
    for fast in (False, True):
        std = log_std.expand_as(mean).exp()
        if fast:
            logp, ent = gaussian_log_prob(mean, std, x), gaussian_entropy(std)
        else:
            dist = torch.distributions.Normal(mean, std)
            logp, ent = dist.log_prob(x), dist.entropy()
        grads.append((logp.detach(), ent.detach(), *torch.autograd.grad((logp.sum(-1) * 0.7 - ent.sum(-1)).mean(), [mean, log_std])))
    for slow, fast in zip(*grads):
        assert torch.equal(slow, fast)


def test_one_always_present_entity_is_encoded_as_its_pooled_code():
    torch.manual_seed(0)
    enc = EntityEncoder(6, 8, mask_feature=None)
    x = torch.randn(5, 1, 6)
    assert torch.equal(enc(x), masked_mean(torch.tanh(enc.layer(x)), torch.ones(5, 1)))


def test_a_policy_step_runs_torch_on_one_thread_and_restores_the_count():
    from train.policy import ActorPolicy

    spec = ObsSpec.make(3, 1, 16)
    actor = Actor(spec, NetConfig())
    seen = []
    actor.register_forward_hook(lambda *_: seen.append(torch.get_num_threads()))
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        ActorPolicy(actor, "a").act(np.zeros((2, 3, spec.dim), dtype=np.float32), spec)
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_every_transition_is_used_once_per_epoch_when_the_minibatch_does_not_divide_the_rollout(monkeypatch):
    """n = 10 transitions, minibatch 4: two minibatches of 5 per epoch, not two of 4 with 2 left out.
    With gamma 0 and zero values each advantage is its transition's reward (1..10), so the advantages
    the loss sees name the transitions it was given."""
    import train.ppo as ppo
    from train.agent import ActorCritic
    from train.config import load_train_config
    from train.storage import Rollout

    cfg = load_train_config([], ["ppo.epochs=3", "ppo.batch_size=8", "ppo.minibatch_size=4", "ppo.norm_adv=false",
                                 "net.encoder_width=4", "net.hidden=[4]"])
    spec = ObsSpec.make(1, 1, 4)
    buf = Rollout(5, 2, 1, spec.dim)  # T=5, W=2, N=1: n = 10
    buf.rewards.copy_(torch.arange(1.0, 11.0).reshape(5, 2, 1))
    seen = []
    loss = ppo.clipped_policy_loss

    def spy(new_logp, old_logp, advantages, clip, weights=None):
        seen.append(sorted(advantages.tolist()))
        return loss(new_logp, old_logp, advantages, clip, weights)

    monkeypatch.setattr(ppo, "clipped_policy_loss", spy)
    model = ActorCritic(spec, 0, cfg)
    ppo.ppo_update(model, torch.optim.Adam(model.parameters(), lr=1e-3), buf, cfg.ppo, 0.0, torch.Generator().manual_seed(0))
    assert [len(s) for s in seen] == [5, 5] * 3  # n // minibatch = 2 steps per epoch, the remainder shared
    for epoch in range(3):
        assert sorted(seen[2 * epoch] + seen[2 * epoch + 1]) == [float(k) for k in range(1, 11)]


def test_a_kickstarted_update_moves_the_mean_toward_the_teachers_actions_and_logs_the_error():
    """ppo.teacher_coef adds weight x the squared distance of the actor's mean from the teacher's
    action (stored per transition by the collector): from the same start and rollout, the
    kickstarted update ends nearer the teacher than the plain one."""
    from train.config import load_train_config
    from train.ppo import ppo_update

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=16)
    buf.teacher_actions.copy_(buf.obs[..., :2])  # a teacher whose action is a function of what it sees
    error = {}
    for weight in (0.0, 5.0):
        cfg = load_train_config([], ["ppo.epochs=20", "ppo.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]"])
        model = _model_that_acted(buf, spec, cfg)
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        stats = ppo_update(model, opt, buf, cfg.ppo, 0.99, torch.Generator().manual_seed(3), teacher_weight=weight)
        with torch.no_grad():
            error[weight] = float(((model.actor(buf.obs, spec)[0] - buf.teacher_actions) ** 2).sum(-1).mean())
        assert ("teacher_mse" in stats) == (weight > 0)  # an update without a teacher logs none
    assert error[5.0] < 0.5 * error[0.0]


def test_a_masked_out_teacher_label_pulls_on_nothing():
    """buf.teacher_mask (ppo.teacher_from_step) says which labels count: with every label masked
    out the kickstarted update is the plain one to the bit; with half masked out, the mean
    moves toward the labels that count and not toward the others (which disagree with them)."""
    from train.config import load_train_config
    from train.ppo import ppo_update

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=16)
    buf.teacher_actions[:, 0] = buf.obs[:, 0, ..., :2]  # world 0's labels count
    buf.teacher_actions[:, 1] = -buf.obs[:, 1, ..., :2]  # world 1's contradict them and are masked out
    cfg = load_train_config([], ["ppo.epochs=20", "ppo.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]"])

    def update(weight: float, mask: torch.Tensor):
        buf.teacher_mask.copy_(mask)
        model = _model_that_acted(buf, spec, cfg)
        stats = ppo_update(model, torch.optim.Adam(model.parameters(), lr=3e-3), buf, cfg.ppo, 0.99,
                           torch.Generator().manual_seed(3), teacher_weight=weight)
        with torch.no_grad():
            error = ((model.actor(buf.obs, spec)[0] - buf.teacher_actions) ** 2).sum(-1).mean((0, 2))
        return model, stats, error

    plain, _, plain_error = update(0.0, torch.ones(16, 2))
    masked, stats, _ = update(5.0, torch.zeros(16, 2))
    for a, b in zip(plain.parameters(), masked.parameters()):
        assert torch.equal(a, b)
    assert stats["teacher_coverage"] == 0.0
    half = torch.zeros(16, 2)
    half[:, 0] = 1
    _, stats, error = update(5.0, half)
    assert stats["teacher_coverage"] == pytest.approx(0.5)
    assert error[0] < 0.5 * plain_error[0]  # pulled toward the labels that count
    assert error[1] > plain_error[1]  # and so away from the contradicting ones, never toward them


@pytest.mark.parametrize("coef,updates,update,expected", [
    (2.0, 0, 0, 2.0), (2.0, 0, 500, 2.0),  # no decay: constant
    (2.0, 10, 0, 2.0), (2.0, 10, 5, 1.0), (2.0, 10, 10, 0.0), (2.0, 10, 30, 0.0),  # linear to 0
    (0.0, 10, 0, 0.0),
])
def test_the_teachers_weight_falls_linearly_over_teacher_updates(coef, updates, update, expected):
    from train.config import PPOConfig
    from train.ppo import teacher_weight

    assert teacher_weight(PPOConfig(teacher_coef=coef, teacher_updates=updates), update) == pytest.approx(expected)


# ----------------------------------------------------------------------------- the update's wiring


def test_a_rollouts_advantages_are_the_plain_loops_with_its_own_terminations_and_truncations():
    """compute_gae is tested alone above; this is what the update feeds it from a Rollout."""
    from train.ppo import advantages_and_returns
    from train.storage import Rollout

    T, W, N = 9, 3, 2
    g = torch.Generator().manual_seed(5)
    buf = Rollout(T, W, N, 4)
    buf.rewards.normal_(generator=g)
    buf.values.normal_(generator=g)
    buf.last_value.normal_(generator=g)
    buf.terminated[2, 0] = buf.terminated[6, 1] = True
    buf.truncated[4, 0] = buf.truncated[3, 2] = buf.truncated[8, 1] = True
    buf.final_values[buf.truncated] = torch.randn(int(buf.truncated.sum()) * N, generator=g).view(-1, N)
    gamma, lam = 0.9, 0.8
    adv, ret, _ = advantages_and_returns(buf, gamma, lam)
    for w in range(W):
        for i in range(N):
            b = w * N + i
            values = buf.values[:, w, i].double().numpy()
            obs_next = np.append(values[1:], float(buf.last_value[w, i]))
            want_adv, want_ret = reference_gae(buf.rewards[:, w, i].double().numpy(), values, obs_next,
                                               buf.final_values[:, w, i].double().numpy(), buf.terminated[:, w].numpy(),
                                               buf.truncated[:, w].numpy(), gamma, lam)
            np.testing.assert_allclose(adv[:, b].numpy(), want_adv, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(ret[:, b].numpy(), want_ret, rtol=1e-5, atol=1e-5)


def _acted(buf, spec, overrides):
    """(model, cfg): a seeded model of one gradient step over all of `buf` per update, whose actor
    sampled buf's actions and whose critic gave its values, as the collector stores them."""
    from train.config import load_train_config

    cfg = load_train_config([], ["ppo.epochs=1", f"ppo.minibatch_size={buf.n_transitions}", "net.encoder_width=8",
                                 "net.hidden=[8]", *overrides])
    model = _model_that_acted(buf, spec, cfg)
    with torch.no_grad():
        buf.values.copy_(model.value(buf.obs, None))
    return model, cfg


def _update_once(model, buf, cfg, lagged=False):
    """(the model before, stats) of one ppo_update of `model` on `buf`."""
    import copy

    from train.ppo import ppo_update

    before = copy.deepcopy(model)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    return before, ppo_update(model, opt, buf, cfg.ppo, cfg.ppo.gamma, torch.Generator().manual_seed(3), lagged=lagged)


def _ppo_as_written_in_the_papers(model, buf, spec, p, gamma: float, lr: float, generator) -> None:
    """One PPO update of `model` on `buf`, the slow obvious way (Schulman et al. 2017 with GAE, as
    the "37 implementation details" spell it, and the reference study's value-loss scale): per
    stream, advantages walked back from the end (no bootstrap after a termination, the value of
    the final observation after a truncation); per epoch, the shuffled transitions in n //
    minibatch_size parts; per part, advantages normalised, the clipped surrogate, the entropy of
    torch's Normal, the value loss over the std of all returns, one clip of every gradient
    together, one Adam step (eps 1e-5)."""
    T, W, N = buf.T, buf.W, buf.N
    n = T * W * N
    values, rewards = buf.values.double(), buf.rewards.double()
    adv = torch.zeros(T, W, N, dtype=torch.float64)
    for w in range(W):
        for i in range(N):
            running = 0.0
            for t in reversed(range(T)):
                if buf.terminated[t, w]:
                    bootstrap = 0.0
                elif buf.truncated[t, w]:
                    bootstrap = float(buf.final_values[t, w, i])
                else:
                    bootstrap = float(values[t + 1, w, i]) if t + 1 < T else float(buf.last_value[w, i])
                delta = float(rewards[t, w, i]) + gamma * bootstrap - float(values[t, w, i])
                ended = bool(buf.terminated[t, w] or buf.truncated[t, w])
                running = delta if ended else delta + gamma * p.gae_lambda * running
                adv[t, w, i] = running
    returns = (adv + values).reshape(n).float()
    adv = adv.reshape(n).float()
    obs, actions, old_logp = buf.obs.reshape(n, -1), buf.actions.reshape(n, 2), buf.logp.reshape(n)
    value_scale = returns.std(unbiased=False)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr, eps=1e-5)
    for _ in range(p.epochs):
        for idx in torch.tensor_split(torch.randperm(n, generator=generator), n // p.minibatch_size):
            mean, log_std = model.actor(obs[idx], spec)
            policy = torch.distributions.Normal(mean, log_std.exp())
            ratio = torch.exp(policy.log_prob(actions[idx]).sum(-1) - old_logp[idx])
            a = (adv[idx] - adv[idx].mean()) / (adv[idx].std(unbiased=False) + 1e-8)
            surrogate = torch.min(ratio * a, torch.clamp(ratio, 1 - p.clip, 1 + p.clip) * a).mean()
            value_loss = ((model.critic(obs[idx], spec) - returns[idx]) ** 2).mean() / value_scale
            loss = -surrogate - p.ent_coef * policy.entropy().sum(-1).mean() + p.vf_coef * value_loss
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(list(model.parameters()), p.max_grad_norm)
            optimizer.step()


def test_one_whole_update_moves_every_weight_as_ppo_written_out_from_the_papers_does():
    """The pieces are tested alone above; this checks the whole update, wired together, against
    a loop written from the papers: a termination, a truncation with its final value, the
    bootstrap after the last step, two epochs whose minibatches share a remainder (36 = 3 x 12 at
    minibatch_size 10), the entropy bonus, and gradients large enough to be clipped."""
    import copy

    from train.config import load_train_config
    from train.ppo import ppo_update

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=9)
    cfg = load_train_config([], ["ppo.epochs=2", "ppo.minibatch_size=10", "ppo.ent_coef=0.01", "ppo.max_grad_norm=0.3",
                                 "net.encoder_width=8", "net.hidden=[8]"])
    model = _model_that_acted(buf, spec, cfg)
    buf.terminated[3, 0] = buf.truncated[6, 1] = True
    g = torch.Generator().manual_seed(4)
    with torch.no_grad():
        buf.values.copy_(model.value(buf.obs, None))
        buf.final_values[6, 1] = torch.randn(2, generator=g)
        buf.last_value.copy_(torch.randn(2, 2, generator=g))
    written_out, start = copy.deepcopy(model), copy.deepcopy(model.state_dict())
    stats = ppo_update(model, torch.optim.Adam(model.parameters(), lr=1e-2, eps=1e-5), buf, cfg.ppo, 0.9,
                       torch.Generator().manual_seed(3))
    _ppo_as_written_in_the_papers(written_out, buf, spec, cfg.ppo, 0.9, 1e-2, torch.Generator().manual_seed(3))
    assert stats["grad_norm"] > cfg.ppo.max_grad_norm  # the clip was at work
    for key, value in written_out.state_dict().items():
        assert not torch.equal(value, start[key]), f"{key} did not move: the test would not see a difference"
        torch.testing.assert_close(model.state_dict()[key], value, rtol=1e-5, atol=1e-6, msg=key)


def test_advantage_normalisation_makes_the_policy_step_blind_to_a_constant_added_to_every_reward():
    spec = ObsSpec.make(2, 1, 4)
    actors = []
    for shift in (0.0, 5.0):
        buf = _random_rollout(spec, T=8)
        model, cfg = _acted(buf, spec, ["ppo.gamma=0", "ppo.gae_lambda=0", "ppo.vf_coef=0"])
        buf.rewards += shift  # at gamma 0 every advantage moves by the same constant
        _update_once(model, buf, cfg)
        actors.append(model.actor.state_dict())
    for k in actors[0]:
        torch.testing.assert_close(actors[1][k], actors[0][k], rtol=1e-5, atol=1e-6)


def test_the_logged_value_loss_is_scaled_by_the_std_of_the_returns():
    from train.ppo import advantages_and_returns

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    buf.rewards *= 7.0
    model, cfg = _acted(buf, spec, [])
    before, stats = _update_once(model, buf, cfg)
    _, ret, _ = advantages_and_returns(buf, cfg.ppo.gamma, cfg.ppo.gae_lambda)
    with torch.no_grad():
        v = before.raw_value(buf.obs.reshape(buf.n_transitions, -1), None)
    want = float(((v - ret.reshape(-1)) ** 2).mean() / ret.std(unbiased=False))
    assert stats["value_loss"] == pytest.approx(want, rel=1e-4)


def test_the_entropy_bonus_widens_the_policy_where_advantages_say_nothing():
    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    model, cfg = _acted(buf, spec, ["ppo.gamma=0", "ppo.gae_lambda=0", "ppo.ent_coef=0.1", "ppo.norm_adv=false", "ppo.vf_coef=0"])
    buf.rewards.copy_(buf.values)  # at gamma 0 every advantage is reward - value: 0
    before, _ = _update_once(model, buf, cfg)
    assert bool((model.actor.log_std > before.actor.log_std).all())


def test_a_lagged_update_takes_its_ratios_against_the_model_as_it_is_not_the_policy_that_acted():
    """In the first gradient step of a lagged update every ratio is 1, however far the acting policy was."""
    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    model, cfg = _acted(buf, spec, [])
    buf.logp += 1.0  # the policy that acted found every sample e times likelier than the model does now
    _, stats = _update_once(model, buf, cfg, lagged=True)
    assert stats["clip_frac"] == 0.0 and abs(stats["approx_kl"]) < 1e-6
    assert stats["behaviour_weight"] == pytest.approx(math.exp(-1.0), rel=1e-4)  # each sample weighted by model / acting


def test_every_gradient_step_is_clipped_to_max_grad_norm(monkeypatch):
    from torch import nn

    calls = []
    real = nn.utils.clip_grad_norm_

    def recording(parameters, max_norm, *a, **k):
        parameters = list(parameters)
        calls.append((len(parameters), max_norm))
        return real(parameters, max_norm, *a, **k)

    monkeypatch.setattr(nn.utils, "clip_grad_norm_", recording)
    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    model, cfg = _acted(buf, spec, ["ppo.max_grad_norm=0.25"])
    _update_once(model, buf, cfg)
    assert calls == [(len(list(model.parameters())), 0.25)]  # actor and critic, one joint norm


def _gradients_of(model, actor_grad: float, critic_grad: float) -> None:
    """Every actor parameter's gradient set to actor_grad, every critic one's to critic_grad."""
    for p in model.actor.parameters():
        p.grad = torch.full_like(p, actor_grad)
    for p in model.critic.parameters():
        p.grad = torch.full_like(p, critic_grad)


def _norm(parameters) -> float:
    return float(torch.cat([p.grad.flatten() for p in parameters]).norm())


def test_separate_clipping_bounds_each_networks_gradient_by_its_own_norm_where_joint_shrinks_both():
    from train.ppo import clip_gradients

    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    for how in ("joint", "separate"):
        model, cfg = _acted(buf, spec, ["ppo.max_grad_norm=0.5", f"ppo.grad_clip={how}"])
        _gradients_of(model, 1e-3, 1.0)  # a small policy gradient beside a large value gradient
        actor, critic = _norm(model.actor.parameters()), _norm(model.critic.parameters())
        assert actor < 0.5 < critic
        norms = clip_gradients(model, cfg.ppo)
        assert float(norms[0]) == pytest.approx(math.hypot(actor, critic), rel=1e-5)  # the norm of both, before
        if how == "joint":
            shrink = 0.5 / math.hypot(actor, critic)
            assert len(norms) == 1
            assert _norm(model.actor.parameters()) == pytest.approx(actor * shrink, rel=1e-4)
            assert _norm(model.parameters()) == pytest.approx(0.5, rel=1e-4)
        else:
            assert [float(n) for n in norms[1:]] == pytest.approx([actor, critic], rel=1e-5)
            assert _norm(model.actor.parameters()) == pytest.approx(actor, rel=1e-6)  # under the bound: untouched
            assert _norm(model.critic.parameters()) == pytest.approx(0.5, rel=1e-4)


def test_a_separately_clipped_update_logs_both_networks_norms_and_a_joint_one_does_not():
    spec = ObsSpec.make(2, 1, 4)
    buf = _random_rollout(spec, T=8)
    buf.rewards *= 50.0
    stats = {}
    for how in ("joint", "separate"):
        model, cfg = _acted(buf, spec, [f"ppo.grad_clip={how}"])
        stats[how] = _update_once(model, buf, cfg)[1]
    assert "actor_grad_norm" not in stats["joint"] and "critic_grad_norm" not in stats["joint"]
    sep = stats["separate"]
    assert sep["grad_norm"] == pytest.approx(math.hypot(sep["actor_grad_norm"], sep["critic_grad_norm"]), rel=1e-5)
    assert sep["grad_norm"] == pytest.approx(stats["joint"]["grad_norm"], rel=1e-5)  # one step from one start
    assert sep["actor_grad_norm"] > 0 and sep["critic_grad_norm"] > 0


def test_an_unknown_grad_clip_is_refused_naming_the_key():
    from pursuit_mj.configio import ConfigError
    from train.config import load_train_config

    with pytest.raises(ConfigError, match="ppo.grad_clip"):
        load_train_config([], ["ppo.grad_clip=both"])


def test_every_net_kind_the_config_accepts_builds_its_own_trunk_and_an_unknown_kind_is_refused():
    """train/networks.py TRUNKS and the choices of net.kind (train/config.py NET_KINDS) are one
    list: a kind added to the config but not to the networks must not fall back to the flat
    MLP (until 2026-12 every kind but reference built FlatTrunk without a word)."""
    import dataclasses

    from train.config import NET_KINDS
    from train.networks import TRUNKS, FlatTrunk, PooledTrunk, make_trunk

    assert set(TRUNKS) == set(NET_KINDS)
    spec = ObsSpec.make(3, 1, 4)
    assert isinstance(make_trunk(spec, NetConfig(kind="reference", encoder_width=8, hidden=(8,))), PooledTrunk)
    assert isinstance(make_trunk(spec, NetConfig(kind="mlp", hidden=(8,))), FlatTrunk)
    unknown = dataclasses.replace(NetConfig(hidden=(8,)), kind="attention")
    with pytest.raises(ValueError, match=r"net.kind 'attention'.*reference, mlp"):
        make_trunk(spec, unknown)
    with pytest.raises(ValueError, match=r"net.kind 'attention'"):
        Actor(spec, unknown)


# ----------------------------------------------------------------------------- the learnable discount


def _meta_problem(dtype=torch.float32):
    """(actor, spec, obs, actions, rewards, values, next_values, terminated, done) of a small seeded
    rollout (T 12, B 4) with one termination, for Discount.meta_step."""
    spec = ObsSpec.make(2, 1, 4)
    torch.manual_seed(0)
    actor = Actor(spec, NetConfig(encoder_width=8, hidden=(8,))).to(dtype)
    g = torch.Generator().manual_seed(0)
    T, B = 12, 4
    obs = (torch.rand(T, B, spec.dim, generator=g) * 2 - 1).to(dtype)
    with torch.no_grad():
        mean, _ = actor(obs, spec)
    actions = mean + 0.5 * torch.randn(mean.shape, generator=g, dtype=dtype)
    rewards, values, next_values = (torch.randn(T, B, generator=g, dtype=dtype) for _ in range(3))
    terminated = torch.zeros(T, B, dtype=torch.bool)
    terminated[5, 1] = True
    return actor, spec, obs, actions, rewards, values, next_values, terminated, terminated.clone()


@pytest.mark.parametrize("outer", [0.9999, 0.0])
def test_a_learned_discount_stays_inside_the_range_it_may_start_in(outer):
    """gamma = sigmoid(logit) in float32 reaches 1.0 exactly once the logit passes about 17:
    a meta-gradient pushing it up for long enough left gamma at 1 (the sigmoid's gradient 0 there,
    so it never came back) and the logged meta-gradient NaN (0 / 0); pushed down, it went on
    toward 0, where one Adam step hardly moves it. It stays within discount.LEARNABLE_START."""
    from train.discount import LEARNABLE_START, Discount

    actor, spec, *rollout = _meta_problem()
    d = Discount(0.5, True, 3.0, outer)  # a large meta step: the bound is met within a few updates
    lo, hi = LEARNABLE_START
    seen = []
    for _ in range(30):
        meta_grad = d.meta_step(actor, spec, *rollout, 0.95, 1e-3, torch.arange(48))
        seen.append((d.value, meta_grad))
    assert all(0.0 < gamma < 1.0 and math.isfinite(meta_grad) for gamma, meta_grad in seen), seen[-3:]
    assert all(lo - 1e-7 <= gamma <= hi + 1e-7 for gamma, _ in seen), seen[-3:]
    assert d.value == pytest.approx(hi if outer > 0.5 else lo, abs=1e-6)  # pushed to the bound, not past it


def test_the_meta_gradient_is_the_derivative_in_gamma_of_the_outer_loss_after_one_inner_step():
    """Written out: theta' = theta - lr grad L_in(theta, gamma), L_out(theta') with advantages of
    gamma_outer; its central difference in gamma against meta_step's d L_out / d gamma (first
    order in lr, so within a few per cent at lr 1e-3), in float64."""
    import copy

    from train.discount import Discount

    actor, spec, obs, actions, rewards, values, next_values, terminated, done = _meta_problem(torch.float64)
    lam, lr, outer, flat_obs, flat_act = 0.9, 1e-3, 0.995, obs.reshape(-1, spec.dim), actions.reshape(-1, 2)

    def outer_loss_after_inner_step(gamma: float) -> float:
        moved = copy.deepcopy(actor)
        params = list(moved.parameters())
        adv_in = normalise(compute_gae(rewards, values, next_values, terminated, done, gamma, lam)[0].reshape(-1))
        logp = moved.distribution(flat_obs, spec).log_prob(flat_act).sum(-1)
        grads = torch.autograd.grad(-(logp * adv_in).mean(), params)
        with torch.no_grad():
            for p, g in zip(params, grads):
                p -= lr * g
            adv_out = normalise(compute_gae(rewards, values, next_values, terminated, done, outer, lam)[0].reshape(-1))
            logp = moved.distribution(flat_obs, spec).log_prob(flat_act).sum(-1)
            return float(-(logp * adv_out).mean())

    gamma, eps = 0.9, 1e-3
    want = (outer_loss_after_inner_step(gamma + eps) - outer_loss_after_inner_step(gamma - eps)) / (2 * eps)
    d = Discount(gamma, True, 1e-3, outer)
    got = d.meta_step(actor, spec, obs, actions, rewards, values, next_values, terminated, done, lam, lr,
                      torch.arange(obs.shape[0] * obs.shape[1]))
    assert got == pytest.approx(want, rel=0.03)
    assert (d.value > gamma) == (want < 0)  # the step goes down the outer loss


def test_mappo_targets_are_normalised_by_statistics_updated_with_this_rollouts_returns_first():
    """Written out: GAE in reward units (the critic's outputs denormalised by the statistics of the
    rollout's time), the running statistics merged with the rollout's returns (parallel Welford),
    then the value loss of the critic's raw outputs against (return - mean') / std'."""
    from train.agent import ActorCritic
    from train.config import load_train_config
    from train.ppo import advantages_and_returns, ppo_update
    from train.storage import Rollout

    spec, S, T, W, N = ObsSpec.make(2, 1, 4), 6, 8, 2, 2
    cfg = load_train_config([], ["algo=mappo", "ppo.epochs=1", "ppo.minibatch_size=32", "net.encoder_width=8",
                                 "net.hidden=[8]", "net.critic_hidden=[8]"])
    torch.manual_seed(1)
    model = ActorCritic(spec, S, cfg)
    model.value_norm.load_state_dict({"mean": 3.0, "var": 4.0, "count": 100.0})
    buf = Rollout(T, W, N, spec.dim, S)
    g = torch.Generator().manual_seed(0)
    buf.obs.uniform_(-1, 1, generator=g)
    buf.states.uniform_(-1, 1, generator=g)
    buf.rewards.normal_(generator=g).mul_(5.0)
    buf.terminated[3, 0] = buf.truncated[5, 1] = True
    states = buf.states.unsqueeze(2).expand(-1, -1, N, -1)
    with torch.no_grad():
        mean, log_std = model.actor(buf.obs, spec)
        buf.actions.copy_(mean + 0.3 * torch.randn(mean.shape, generator=g))
        buf.logp.copy_(gaussian_log_prob(mean, log_std.exp(), buf.actions).sum(-1))
        buf.values.copy_(model.value(buf.obs, states))
        raw = model.raw_value(buf.obs, states).double().reshape(-1).numpy()
    np.testing.assert_allclose(buf.values.double().reshape(-1).numpy(), raw * 2.0 + 3.0, rtol=1e-5)  # reward units
    buf.final_values.normal_(generator=g)
    buf.last_value.normal_(generator=g)
    _, ret, _ = advantages_and_returns(buf, cfg.ppo.gamma, cfg.ppo.gae_lambda)
    x = ret.reshape(-1).double().numpy()
    n0, m0, v0, n1, m1, v1 = 100.0, 3.0, 4.0, len(x), x.mean(), x.var()
    mean_after = m0 + (m1 - m0) * n1 / (n0 + n1)
    var_after = (v0 * n0 + v1 * n1 + (m1 - m0) ** 2 * n0 * n1 / (n0 + n1)) / (n0 + n1)
    stats = ppo_update(model, torch.optim.Adam(model.parameters(), lr=1e-3), buf,
                       cfg.ppo, cfg.ppo.gamma, torch.Generator().manual_seed(3))
    assert model.value_norm.mean == pytest.approx(mean_after) and model.value_norm.var == pytest.approx(var_after)
    want = float(((raw - (x - mean_after) / math.sqrt(var_after)) ** 2).mean())  # one step over the whole batch
    assert stats["value_loss"] == pytest.approx(want, rel=1e-5)


def _plain_ppo_update(model, optimizer, buf, cfg, generator):
    """PPO's minibatch loop written the plain way (torch's own clip and step on model.parameters()
    at every step): the arithmetic ppo_update must keep, whatever it does to run faster."""
    from torch import nn

    from train.ppo import advantages_and_returns

    adv, ret, _ = advantages_and_returns(buf, cfg.gamma, cfg.gae_lambda)
    n = buf.n_transitions
    obs, actions, old_logp = buf.obs.reshape(n, -1), buf.actions.reshape(n, 2), buf.logp.reshape(n)
    adv, ret = adv.reshape(n), ret.reshape(n)
    target_std = float(ret.std(unbiased=False))
    for _ in range(cfg.epochs):
        for idx in torch.tensor_split(torch.randperm(n, generator=generator), max(n // cfg.minibatch_size, 1)):
            mean, log_std = model.actor(obs[idx], model.spec)
            std = log_std.exp()
            new_logp = gaussian_log_prob(mean, std, actions[idx]).sum(-1)
            entropy = gaussian_entropy(std).sum(-1).mean()
            pg_loss, _ = clipped_policy_loss(new_logp, old_logp[idx], normalise(adv[idx]), cfg.clip)
            v_loss = scaled_value_loss(model.raw_value(obs[idx], None), ret[idx], target_std)
            loss = pg_loss - cfg.ent_coef * entropy + cfg.vf_coef * v_loss
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(model.parameters(), cfg.max_grad_norm)
            optimizer.step()


@pytest.mark.parametrize("how", ["joint", "separate"])
def test_kept_parameter_lists_clip_exactly_as_lists_made_at_every_step(how):
    """ppo_update lists the model's parameters once per update (train/ppo.py: ParameterLists)
    instead of walking the module tree at each of its minibatch steps: the norms and the clipped
    gradients are the same to the bit, and the lists follow the weights as the optimiser moves them."""
    import copy

    from train.ppo import ParameterLists, clip_gradients

    spec = ObsSpec.make(2, 1, 4)
    model, cfg = _acted(_random_rollout(spec, T=8), spec, ["ppo.max_grad_norm=0.5", f"ppo.grad_clip={how}"])
    kept = ParameterLists(model)
    _gradients_of(model, 1e-3, 1.0)
    torch.optim.SGD(model.parameters(), lr=0.1).step()  # the weights move in place after the lists were made
    other = copy.deepcopy(model)
    for m in (model, other):
        _gradients_of(m, 1e-3, 1.0)  # a small policy gradient beside a large value gradient: both ways clip
    for a, b in zip(clip_gradients(model, cfg.ppo, kept), clip_gradients(other, cfg.ppo)):
        assert torch.equal(a, b)
    for p, q in zip(model.parameters(), other.parameters()):
        assert torch.equal(p, q) and torch.equal(p.grad, q.grad)
    assert _norm(model.critic.parameters()) == pytest.approx(0.5, rel=1e-3)  # it did clip


def test_an_update_is_the_plain_ppo_loop_to_the_bit():
    """Whatever ppo_update does to run faster changes no number: two epochs of minibatch steps,
    clipped (max_grad_norm small enough to clip), end in the weights and Adam state of the plain
    loop, bit for bit."""
    import copy

    from train.ppo import ppo_update

    spec = ObsSpec.make(3, 1, 4)
    buf = _random_rollout(spec, T=12, W=2, N=3)
    model, cfg = _acted(buf, spec, ["ppo.epochs=2", "ppo.minibatch_size=24", "ppo.max_grad_norm=0.2"])
    plain, start = copy.deepcopy(model), copy.deepcopy(model)
    optimisers = [torch.optim.Adam(m.parameters(), lr=1e-3, eps=1e-5, fused=True) for m in (model, plain)]
    for _ in range(2):  # the second update starts from Adam moments the first left
        ppo_update(model, optimisers[0], buf, cfg.ppo, cfg.ppo.gamma, torch.Generator().manual_seed(3))
        _plain_ppo_update(plain, optimisers[1], buf, cfg.ppo, torch.Generator().manual_seed(3))
    for (key, a), b in zip(model.state_dict().items(), plain.state_dict().values()):
        assert torch.equal(a, b), key
    assert not torch.equal(model.actor.head.weight, start.actor.head.weight)  # it did learn
    moments = [optimisers[i].state_dict()["state"] for i in (0, 1)]
    for k in moments[0]:
        for name in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(moments[0][k][name], moments[1][k][name]), (k, name)


# ----------------------------------------------------------------------------- mutation audit


def test_running_std_of_nearly_constant_returns_is_their_own_and_an_empty_update_changes_nothing():
    rms = RunningMeanStd(epsilon=0.0)
    rms.update(torch.tensor([1.0, 1.02, 1.0, 1.02], dtype=torch.float64))  # std 0.01: kept, not floored
    assert rms.std == pytest.approx(0.01)
    state = rms.state_dict()
    rms.update(torch.empty(0))
    assert rms.state_dict() == state
    constant = RunningMeanStd(epsilon=0.0)
    constant.update(torch.full((8,), 2.0))  # no spread at all: the floor, var 1e-8
    assert constant.std == pytest.approx(1e-4)


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_a_fixed_discount_may_be_zero_or_one_and_a_learned_one_may_not_start_there(gamma):
    from train.discount import Discount

    assert Discount(gamma, False, 1e-3, 0.995).value == gamma  # ppo.gamma lies in [0, 1]
    with pytest.raises(ValueError, match=f"learnable discount: start gamma {gamma:g} lies outside"):
        Discount(gamma, True, 1e-3, 0.995)


def test_net_use_rays_false_leaves_the_range_readings_out_of_the_network():
    """net.use_rays false (the reference study's network) has no ray encoder: the actor's and
    critic's outputs do not move when every range reading does, and the fused layer takes one
    encoder width less than with rays."""
    spec = ObsSpec.make(3, 1, 8)
    cfg = NetConfig(encoder_width=8, hidden=(8,), use_rays=False)
    torch.manual_seed(0)
    actor, critic = Actor(spec, cfg), Critic(spec, cfg)
    assert "rays" not in actor.trunk.encoders and actor.trunk.fuse[0].in_features == 3 * 8  # self, teammates, evaders
    obs = torch.as_tensor(_obs(spec, np.random.default_rng(3), [1, 1], [1]))[None]
    other = obs.clone()
    rays = spec.group("rays")
    other[..., rays.start : rays.stop] = torch.linspace(0.1, 4.0, spec.n_rays)
    assert torch.equal(actor(obs, spec)[0], actor(other, spec)[0])
    assert torch.equal(critic(obs, spec), critic(other, spec))
    with_rays = Actor(spec, NetConfig(encoder_width=8, hidden=(8,)))
    assert "rays" in with_rays.trunk.encoders and with_rays.trunk.fuse[0].in_features == 4 * 8


def test_heads_start_at_their_orthogonal_gains_and_log_std_at_net_init_log_std():
    """Orthogonal init with gain g makes a head's rows orthonormal times g: the actor's mean head
    (gain 0.01: first actions are the exploration noise around 0) has W W^T = 1e-4 I, the value
    heads (gain 1) unit-length rows; the log std starts at net.init_log_std."""
    from train.networks import CentralCritic

    spec = ObsSpec.make(3, 1, 8)
    torch.manual_seed(0)
    cfg = NetConfig(encoder_width=16, hidden=(32,), critic_hidden=(24,), init_log_std=-1.3)
    actor = Actor(spec, cfg)
    w = actor.head.weight.detach().double()  # (2, 32)
    torch.testing.assert_close(w @ w.T, 1e-4 * torch.eye(2, dtype=torch.float64), atol=1e-9, rtol=0)
    assert actor.log_std.detach().tolist() == [pytest.approx(-1.3)] * 2
    for head in (Critic(spec, cfg).head, CentralCritic(spec, 10, cfg).head):
        assert float(head.weight.detach().double().norm()) == pytest.approx(1.0, abs=1e-6)


def test_the_actor_mean_is_the_tanh_of_its_head_and_stays_within_one():
    """The mean action is tanh(head(trunk)): however large the head's output, within [-1, 1]."""
    spec = ObsSpec.make(3, 1, 8)
    torch.manual_seed(0)
    actor = Actor(spec, NetConfig(encoder_width=8, hidden=(8,)))
    with torch.no_grad():
        actor.head.weight.mul_(1e4)  # pre-tanh outputs far beyond 1
    obs = torch.as_tensor(_obs(spec, np.random.default_rng(4), [1, 1], [1]))[None]
    with torch.no_grad():
        raw = actor.head(actor.trunk(obs, spec))
        mean, _ = actor(obs, spec)
    assert float(raw.abs().max()) > 2.0
    torch.testing.assert_close(mean, torch.tanh(raw), atol=3e-7, rtol=0)
    assert float(mean.abs().max()) <= 1.0


def test_the_same_seed_gives_the_same_weights_whatever_the_thread_count():
    """init_linear runs the orthogonal QR on one thread: a process left at two threads (or any
    count) builds bit-for-bit the weights of one at one thread; the caller's count is restored."""
    before = torch.get_num_threads()
    built = []
    try:
        for threads in (2, 1):
            torch.set_num_threads(threads)
            torch.manual_seed(0)
            built.append(Actor(ObsSpec.make(3, 1, 16), NetConfig()).state_dict())
            assert torch.get_num_threads() == threads
    finally:
        torch.set_num_threads(before)
    assert all(torch.equal(built[0][k], built[1][k]) for k in built[0])
