"""The rollout stores exactly what the update recomputes: log-probabilities and values of its own data."""

import torch

from pursuit_mj.config import default_config
from pursuit_mj.env import PursuitEnv
from train.agent import ActorCritic
from train.config import TrainConfig
from train.networks import gaussian_log_prob
from train.rollout import Collector
from train.storage import Rollout


def test_stored_log_probs_and_values_match_the_networks_on_the_stored_data():
    torch.manual_seed(0)
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0, max_steps=6), n_worlds=2, seed=3, nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    buf = Rollout(8, 2, env.n_pursuers, env.obs_dim)
    stats = Collector(env, model, torch.Generator().manual_seed(1)).collect(buf)
    assert bool(buf.truncated.any()) and stats.episodes  # episodes of 6 steps end inside 8
    with torch.no_grad():
        mean, log_std = model.actor(buf.obs, env.obs_spec)
        torch.testing.assert_close(buf.logp, gaussian_log_prob(mean, log_std.exp(), buf.actions).sum(-1), rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(buf.values, model.value(buf.obs, None), rtol=1e-5, atol=1e-5)
        assert bool((buf.final_values[~buf.truncated] == 0).all()) and bool((buf.final_values[buf.truncated] != 0).all())
    assert not buf.last_value.is_inference()  # the update may use it with autograd on
