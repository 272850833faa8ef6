"""The rollout stores exactly what the update recomputes: log-probabilities and values of its own data."""

import numpy as np
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


def _assert_labels_of_a_fresh_team(buf: Rollout, task, spec) -> None:
    """buf.teacher_actions are what a team with empty memory says when fed the rollout's
    observations and episode ends in order (the team keeps memory per world)."""
    from pursuit_mj.heuristic import HeuristicTeam
    from train.rollout import forget_ended

    replay = HeuristicTeam.from_config(task)
    replay.reset(buf.W)
    for t in range(buf.T):
        expected = replay.act(buf.obs[t].numpy(), spec)
        torch.testing.assert_close(buf.teacher_actions[t], torch.as_tensor(expected, dtype=torch.float32))
        forget_ended(replay, (buf.terminated[t] | buf.truncated[t]).numpy())


def test_a_teacher_labels_every_stored_observation_with_the_action_it_would_take_there():
    """With a teacher (ppo.teacher_coef), the collector stores the team's action for each stored
    observation; the team keeps memory, so a second team fed the same observations and episode
    ends must give the same labels. The worlds are still driven by the policy's samples."""
    from pursuit_mj.heuristic import HeuristicTeam

    torch.manual_seed(0)
    task = default_config(fidelity="point", random_obstacles=0, max_steps=6)
    env = PursuitEnv(task, n_worlds=2, seed=3, nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    buf = Rollout(8, 2, env.n_pursuers, env.obs_dim)
    Collector(env, model, torch.Generator().manual_seed(1), teacher=HeuristicTeam.from_config(task)).collect(buf)
    assert bool(buf.truncated.any())  # labels run across an episode end
    _assert_labels_of_a_fresh_team(buf, task, env.obs_spec)
    assert float(buf.teacher_actions.abs().max()) > 0.1
    assert not torch.allclose(buf.actions.clamp(-1, 1), buf.teacher_actions)  # the policy drove, not the teacher
    assert bool((buf.teacher_mask == 1).all())  # without ppo.teacher_from_step every label counts


def test_a_teacher_from_a_step_on_counts_only_where_the_episode_has_run_that_long():
    """ppo.teacher_from_step K: a label counts (teacher_mask 1) only for observations met after
    K or more decision steps of their episode; the count starts again when an episode ends."""
    from pursuit_mj.heuristic import HeuristicTeam

    task = default_config(fidelity="point", random_obstacles=0, max_steps=6)
    env = PursuitEnv(task, n_worlds=2, seed=3, nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    buf = Rollout(14, 2, env.n_pursuers, env.obs_dim)
    Collector(env, model, torch.Generator().manual_seed(1), teacher=HeuristicTeam.from_config(task),
              teacher_from_step=3).collect(buf)
    episode_step = np.zeros(2, np.int64)  # decision steps taken before each stored observation
    for t in range(buf.T):
        np.testing.assert_array_equal(buf.teacher_mask[t].numpy(), (episode_step >= 3).astype(np.float32))
        episode_step = np.where((buf.terminated[t] | buf.truncated[t]).numpy(), 0, episode_step + 1)
    assert 0 < float(buf.teacher_mask.mean()) < 1


class _CountingTeam:
    """A heuristic team that counts the decision steps it was asked to act at."""

    def __init__(self, task):
        from pursuit_mj.heuristic import HeuristicTeam

        self.team = HeuristicTeam.from_config(task)
        self.calls = 0

    def reset(self, n_worlds, world_ids=None):
        self.team.reset(n_worlds, world_ids)

    def act(self, obs, spec):
        self.calls += 1
        return self.team.act(obs, spec)


def test_a_teacher_not_teaching_labels_nothing_and_starts_afresh_when_it_teaches_again():
    """Collector.teaching False (the teacher's weight has reached 0): the team is not stepped at
    all and no label counts. Teaching again, it labels every step, its memory reset (it missed
    the steps between), so its labels equal a fresh team's on this rollout's observations."""

    task = default_config(fidelity="point", random_obstacles=0, max_steps=6)
    env = PursuitEnv(task, n_worlds=2, seed=3, nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    buf = Rollout(4, 2, env.n_pursuers, env.obs_dim)
    teacher = _CountingTeam(task)
    collector = Collector(env, model, torch.Generator().manual_seed(1), teacher=teacher)
    collector.teaching = False
    stats = collector.collect(buf)
    assert teacher.calls == 0 and stats.teacher_steps == 0
    assert float(buf.teacher_mask.abs().sum()) == 0
    collector.teaching = True
    stats = collector.collect(buf)
    assert teacher.calls == buf.T and stats.teacher_steps == buf.T
    assert bool((buf.teacher_mask == 1).all())
    _assert_labels_of_a_fresh_team(buf, task, env.obs_spec)


def test_a_truncated_episode_bootstraps_from_its_own_last_observation_not_the_next_episodes_first():
    torch.manual_seed(0)
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0, max_steps=6), n_worlds=2, seed=3, nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    final_obs = {}
    real_step = env.step

    def recording_step(actions):
        out = real_step(actions)
        if out[3].any():
            final_obs[len(final_obs)] = (out[3].copy(), out[4]["final_obs"].copy())
        return out

    env.step = recording_step
    buf = Rollout(8, 2, env.n_pursuers, env.obs_dim)
    Collector(env, model, torch.Generator().manual_seed(1)).collect(buf)
    (truncated, last_obs), = final_obs.values()  # both worlds time out at step 6
    t = int(torch.nonzero(buf.truncated.any(1))[0])
    with torch.no_grad():
        idx = np.flatnonzero(truncated)
        torch.testing.assert_close(buf.final_values[t, idx], model.world_value(torch.as_tensor(last_obs[idx]), None))
        assert not torch.allclose(buf.final_values[t, idx], model.world_value(buf.obs[t + 1, idx], None))  # the reset's


def test_a_mappo_truncation_bootstraps_from_the_ended_worlds_own_last_state_in_reward_units():
    """MAPPO's critic reads the global state beside each pursuer's observation: at a timeout both
    must be the ended episode's last ones (info["final_state"], info["final_obs"]), not those of
    the episode the auto-reset began, and the stored value is in reward units (the critic's
    output denormalised by the running statistics of the rollout's time). Two evaders, so the
    state carries a captured flag per evader."""
    from train.config import load_train_config

    torch.manual_seed(0)
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0, max_steps=6, n_evaders=2), n_worlds=2, seed=3,
                     nthread=1)
    model = ActorCritic(env.obs_spec, env.state_dim, load_train_config([], ["algo=mappo"]))
    model.value_norm.load_state_dict({"mean": 3.0, "var": 4.0, "count": 10.0})
    ends, before = [], []
    real_step = env.step

    def recording_step(actions):
        before.append(env.global_state())
        out = real_step(actions)
        ends.append((out[3].copy(), out[4]["final_obs"].copy(), out[4]["final_state"].copy()))
        return out

    env.step = recording_step
    buf = Rollout(8, 2, env.n_pursuers, env.obs_dim, env.state_dim)
    Collector(env, model, torch.Generator().manual_seed(1)).collect(buf)
    np.testing.assert_array_equal(buf.states.numpy(), np.stack(before))  # each observation's own state
    t = int(torch.nonzero(buf.truncated.any(1))[0])
    truncated, last_obs, last_state = ends[t]
    idx = np.flatnonzero(truncated)
    with torch.no_grad():
        state = torch.as_tensor(last_state[idx])
        raw = model.raw_value(torch.as_tensor(last_obs[idx]), state.unsqueeze(1).expand(-1, env.n_pursuers, -1))
        torch.testing.assert_close(buf.final_values[t, idx], raw * 2.0 + 3.0)
        reset = model.world_value(torch.as_tensor(last_obs[idx]), buf.states[t + 1, idx])
        assert not torch.allclose(buf.final_values[t, idx], reset)  # the new episode's state would give another value


def test_a_rollout_stores_to_the_bit_what_a_plain_loop_of_actor_and_env_gives():
    """The collector's arithmetic, pinned for work on its speed: a plain loop (the actor's sample
    per step, the env stepped with it clipped, the critic once over the stored observations) on
    a second env of the same seed gives every tensor of the rollout bit for bit."""
    task = default_config(fidelity="point", random_obstacles=0, max_steps=6)
    envs = [PursuitEnv(task, n_worlds=2, seed=3, nthread=1) for _ in range(2)]
    spec = envs[0].obs_spec
    torch.manual_seed(0)
    model = ActorCritic(spec, envs[0].state_dim, TrainConfig())
    buf = Rollout(8, 2, envs[0].n_pursuers, envs[0].obs_dim)
    Collector(envs[0], model, torch.Generator().manual_seed(1)).collect(buf)
    assert bool(buf.truncated.any())  # episodes of 6 steps end inside 8: final values are met
    noise = torch.Generator().manual_seed(1)
    obs = torch.as_tensor(envs[1].reset())
    with torch.inference_mode():
        for t in range(buf.T):
            mean, log_std = model.actor(obs, spec)
            std = log_std.exp()
            action = mean + std * torch.randn(mean.shape, generator=noise)
            assert torch.equal(buf.obs[t], obs) and torch.equal(buf.actions[t], action)
            assert torch.equal(buf.logp[t], gaussian_log_prob(mean, std, action).sum(-1))
            next_obs, reward, terminated, truncated, info = envs[1].step(action.clamp(-1.0, 1.0).numpy())
            assert torch.equal(buf.rewards[t], torch.as_tensor(reward))
            assert np.array_equal(buf.terminated[t].numpy(), terminated) and np.array_equal(buf.truncated[t].numpy(), truncated)
            final = torch.zeros(buf.W, buf.N)
            if truncated.any():
                idx = np.flatnonzero(truncated)
                final[torch.as_tensor(idx)] = model.world_value(torch.as_tensor(info["final_obs"][idx]), None)
            assert torch.equal(buf.final_values[t], final)
            obs = torch.as_tensor(next_obs)
        assert torch.equal(buf.last_value, model.world_value(obs, None))
        assert torch.equal(buf.values, model.world_value(buf.obs.flatten(0, 1), None).view(buf.T, buf.W, -1))
