"""Belief features (pursuit_mj/belief.py, train belief: true): memory appended to observations."""

import copy
import re

import numpy as np
import pytest
import torch

from pursuit_mj.belief import AGE_CAP, Belief, BeliefEnv, BeliefPolicy, BeliefTeam, belief_spec
from pursuit_mj.config import TaskConfig
from pursuit_mj.env import PursuitEnv
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.obs_spec import ObsSpec
from train.config import NetConfig, load_train_config
from train.networks import PooledTrunk
from train.policy import load_policy
from train.rollout import hand_made_team, make_action_path
from train.trainer import Trainer

TASK = TaskConfig(fidelity="point")


def _obs(spec: ObsSpec, pos, evader=None) -> np.ndarray:
    """One world, every pursuer at `pos` at rest, open rays; evader (dx, dy, vx, vy) visible or None."""
    obs = np.zeros((1, spec.n_pursuers, spec.dim), np.float32)
    obs[..., spec.index("self", 0, "x")], obs[..., spec.index("self", 0, "y")] = pos
    g = spec.group("rays")
    obs[..., g.start : g.stop] = TASK.ray_range
    if evader is not None:
        for name, value in zip(("dx", "dy", "vx", "vy"), evader):
            obs[..., spec.index("evaders", 0, name)] = value
        obs[..., spec.index("evaders", 0, "visible")] = 1.0
    return obs


def _memory(features: np.ndarray, spec: ObsSpec) -> dict[str, float]:
    """Pursuer 0's memory of evader 0 as a dict of named features."""
    full = belief_spec(spec)
    vec = np.concatenate([np.zeros(spec.dim, np.float32), features[0, 0]])
    return {f: float(vec[full.index("memory", 0, f)]) for f in full.group("memory").features}


def test_the_belief_groups_follow_the_environment_groups():
    spec = ObsSpec.make(3, 2, 16)
    full = belief_spec(spec)
    assert full.has_belief and not spec.has_belief
    assert full.dim == spec.dim + 2 * 6 + 3
    assert [g.name for g in full.groups] == ["self", "teammates", "evaders", "rays", "memory", "goal"]
    assert full.groups[:4] == spec.groups  # the environment's part is unchanged, in front
    assert "belief" in spec.compatible(full.to_dict()) and "belief" in full.compatible(spec.to_dict())


def test_a_lost_evader_is_remembered_moved_along_its_velocity_then_forgotten_when_searched():
    spec = ObsSpec.make(3, 1, TASK.n_rays)
    belief = Belief.from_config(TASK)
    belief.reset(1)
    first = _memory(belief.features(_obs(spec, (1.0, 1.0), evader=(1.0, 0.0, 0.2, 0.0)), spec), spec)
    assert first == pytest.approx({"dx": 1.0, "dy": 0.0, "vx": 0.2, "vy": 0.0, "age": 0.0, "known": 1.0})
    for k in range(1, 4):  # out of sight: the estimate drifts with the last velocity, the age grows
        lost = _memory(belief.features(_obs(spec, (1.0, 1.0)), spec), spec)
        age = k * TASK.control_dt
        assert lost == pytest.approx({"dx": 1.0 + 0.2 * age, "dy": 0.0, "vx": 0.2, "vy": 0.0, "age": age, "known": 1.0})
    # the pursuer arrives where the evader should be and finds nothing: the memory is cleared
    gone = _memory(belief.features(_obs(spec, (2.06, 1.0)), spec), spec)
    assert gone == {"dx": 0.0, "dy": 0.0, "vx": 0.0, "vy": 0.0, "age": 0.0, "known": 0.0}


def test_the_age_reads_capped():
    spec = ObsSpec.make(3, 1, TASK.n_rays)
    belief = Belief.from_config(TASK)
    belief.reset(1)
    belief.features(_obs(spec, (1.0, 1.0), evader=(3.0, 0.0, 0.0, 0.0)), spec)
    for _ in range(int(AGE_CAP / TASK.control_dt) + 10):
        mem = _memory(belief.features(_obs(spec, (1.0, 1.0)), spec), spec)
    assert mem["known"] == 1.0 and mem["age"] == AGE_CAP


def test_the_goal_is_the_heuristic_sweep_waypoint():
    from pursuit_mj.heuristic import HeuristicTeam

    env = PursuitEnv(TASK, n_worlds=2, seed=3, layouts=[1])
    obs = env.reset()
    belief, team = Belief.from_config(TASK), HeuristicTeam.from_config(TASK)
    belief.reset(2), team.reset(2)
    full = belief_spec(env.obs_spec)
    goal = full.group("goal")
    for _ in range(5):
        aug = belief.augment(obs, env.obs_spec)
        _, _, sweep, planned = team.observe(obs, env.obs_spec)
        team.tick()
        np.testing.assert_allclose(aug[..., goal.start : goal.start + 2], sweep, atol=1e-5)
        np.testing.assert_array_equal(aug[..., goal.start + 2], planned)
        obs, *_ = env.step(np.zeros((2, TASK.n_pursuers, 2)))


def test_the_env_wrapper_clears_the_memory_of_ended_episodes():
    task = TaskConfig(fidelity="point", max_steps=4)
    env = BeliefEnv(PursuitEnv(task, n_worlds=2, seed=2), Belief.from_config(task))
    raw_dim = env.raw_spec.dim
    obs = env.reset()
    assert obs.shape == (2, task.n_pursuers, env.obs_dim) and env.obs_spec.has_belief
    previous = obs
    for step in range(4):
        obs, _, terminated, truncated, info = env.step(np.zeros((2, task.n_pursuers, 2)))
        if step < 3:
            previous = obs
    assert truncated.all()
    np.testing.assert_array_equal(info["final_obs"][..., raw_dim:], previous[..., raw_dim:])  # one step old
    fresh = Belief.from_config(task)
    fresh.reset(2)
    np.testing.assert_allclose(obs[..., raw_dim:], fresh.features(obs[..., :raw_dim], env.raw_spec), atol=1e-6)
    # restarting some worlds between steps would age the others' memory: refused, not passed through
    with pytest.raises(RuntimeError, match="reset_worlds: not supported"):
        env.reset_worlds([0])


def test_the_team_acting_from_a_belief_acts_exactly_as_a_team_with_its_own_memory():
    task = TaskConfig(fidelity="point", max_steps=40)
    env = BeliefEnv(PursuitEnv(task, n_worlds=3, seed=4), Belief.from_config(task))
    shared = BeliefTeam(env.belief)
    own = HeuristicTeam.from_config(task)
    obs = env.reset()
    own.reset(3)
    ended_any = False
    for _ in range(60):  # through auto-resets of ended episodes
        actions = shared.act(obs, env.obs_spec)
        np.testing.assert_array_equal(actions, own.act(obs, env.obs_spec))
        obs, _, terminated, truncated, _ = env.step(actions)
        ended = terminated | truncated
        ended_any |= ended.any()
        shared.reset(3, np.flatnonzero(ended))  # a no-op: the BeliefEnv reset the memory already
        own.reset(3, np.flatnonzero(ended))
    assert ended_any


def test_the_team_acting_from_a_belief_refuses_observations_the_belief_did_not_take_in():
    task = TaskConfig(fidelity="point")
    env = BeliefEnv(PursuitEnv(task, n_worlds=2, seed=4), Belief.from_config(task))
    team = BeliefTeam(env.belief)
    with pytest.raises(RuntimeError, match="no observations yet"):
        team.act(np.zeros((2, task.n_pursuers, env.obs_dim), np.float32), env.obs_spec)
    obs = env.reset()
    team.act(obs[..., : env.raw_spec.dim], env.raw_spec)  # the raw part alone is the same step
    stale = obs.copy()
    stale[0, 0, 0] += 0.1
    with pytest.raises(RuntimeError, match="not the observations the belief took in last"):
        team.act(stale, env.obs_spec)


def test_training_shares_the_belief_memory_with_a_heuristic_teacher_or_base_team(tmp_path):
    trainer = Trainer(_tiny(tmp_path, "name=shared", "belief=true"), log=lambda s: None)
    assert isinstance(trainer.collector.teacher, BeliefTeam) and trainer.collector.teacher.belief is trainer.env.belief
    privileged = Trainer(_tiny(tmp_path, "name=priv", "belief=true", "imitation.teacher_sees=all_round"), log=lambda s: None)
    assert isinstance(privileged.collector.teacher, HeuristicTeam)  # it sees differently: its own memory
    plain = load_train_config([], ["task.fidelity=point", "residual.base=heuristic", "shield=true"])
    assert isinstance(hand_made_team("heuristic", plain), HeuristicTeam)
    env = BeliefEnv(PursuitEnv(plain.task, n_worlds=2, seed=0), Belief.from_config(plain.task))
    assert isinstance(make_action_path(plain, env).base, BeliefTeam)
    assert isinstance(make_action_path(plain).base, HeuristicTeam)


def test_hidden_memories_do_not_reach_the_network():
    spec = belief_spec(ObsSpec.make(3, 2, 8))
    trunk = PooledTrunk(spec, NetConfig(encoder_width=8, hidden=(8,)))
    obs = torch.randn(5, spec.dim)
    mem = spec.group("memory")
    obs[:, mem.start + 5] = 1.0  # evader 0 known
    obs[:, mem.start + mem.width + 5] = 0.0  # evader 1 not known
    other = obs.clone()
    other[:, mem.start + mem.width : mem.start + 2 * mem.width - 1] = torch.randn(5, mem.width - 1)
    torch.testing.assert_close(trunk(obs, spec), trunk(other, spec))
    other[:, mem.start] += 1.0
    assert not torch.allclose(trunk(obs, spec), trunk(other, spec))


def _tiny(tmp_path, *extra):
    return load_train_config([], [
        "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "task.max_steps=30", "n_envs=2",
        "total_steps=60", "ppo.batch_size=60", "ppo.minibatch_size=30", "imitation.grad_steps=2",
        "imitation.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]", "run.validate_every=1",
        "run.validation_episodes=2", "run.progress=false", f"run.runs_dir={tmp_path}", *extra,
    ])


def test_a_belief_run_trains_and_loads_as_a_policy_of_the_environment_observations(tmp_path):
    trainer = Trainer(_tiny(tmp_path, "name=bel", "belief=true"), log=lambda s: None)
    assert trainer.spec.has_belief and trainer.buffer.obs.shape[-1] == trainer.spec.dim
    assert trainer.train()["status"] == "done"
    env = PursuitEnv(TaskConfig(fidelity="point", n_pursuers=4, n_evaders=2), n_worlds=2, seed=0)
    policy = load_policy(tmp_path / "bel" / "best.pt", env.obs_spec, task=env.config)
    assert isinstance(policy, BeliefPolicy) and policy.name == "bel"
    obs = env.reset()
    policy.reset(2)
    for _ in range(3):
        actions = policy.act(obs, env.obs_spec)
        assert actions.shape == (2, 4, 2) and np.abs(actions).max() <= 1.0
        obs, *_ = env.step(actions)
    with pytest.raises(ValueError, match="belief"):
        Trainer(_tiny(tmp_path, "name=plain", f"init_from={tmp_path / 'bel' / 'best.pt'}"), log=lambda s: None)


def test_bad_observations_are_refused_with_what_was_wrong():
    spec = ObsSpec.make(3, 1, TASK.n_rays)
    belief = Belief.from_config(TASK)
    belief.reset(1)
    aug = belief.augment(_obs(spec, (1.0, 1.0)), spec)
    with pytest.raises(ValueError, match="already carry belief"):
        belief.features(aug, belief_spec(spec))
    with pytest.raises(ValueError, match=r"expected observations \(worlds, 3, %d\)" % spec.dim):
        belief.features(aug, spec)


def test_the_env_wrapper_can_be_copied_and_passes_unknown_names_to_the_env():
    env = BeliefEnv(PursuitEnv(TASK, n_worlds=1, seed=0), Belief.from_config(TASK))
    twin = copy.copy(env)  # was a RecursionError: __getattr__ looked for self.env before it was set
    assert twin.env is env.env and twin.obs_dim == env.obs_dim and twin.n_worlds == 1
    with pytest.raises(AttributeError, match="no_such_thing"):
        env.no_such_thing


def test_a_belief_policy_takes_observations_as_a_list_and_names_itself_for_bad_ones():
    """A list failed deep inside the belief ('list' object has no attribute 'shape')."""
    from pursuit_mj.config import default_config
    from train.policy import load_policy

    env = PursuitEnv(default_config(fidelity="point", max_steps=5), n_worlds=1, seed=0)
    obs = env.reset()
    policy = load_policy("pretrained/pursuers.pt", env.obs_spec)
    twin = load_policy("pretrained/pursuers.pt", env.obs_spec)
    policy.reset(1)
    twin.reset(1)
    np.testing.assert_array_equal(policy.act(obs.tolist(), env.obs_spec), twin.act(obs, env.obs_spec))
    with pytest.raises(ValueError, match=re.escape(f"policy {policy.name}: expected observations")):
        policy.act(obs[:, :, :3], env.obs_spec)


# ----------------------------------------------------------------------------- mutation audit


def test_the_goal_follows_a_team_whose_clock_runs_while_the_pursuers_search():
    """The belief advances its memory's clock every step: the coverage search ranks cells by how
    long ago they were seen. A frozen clock (every cell seen 'now' for good) gave a different
    waypoint once the team had looked round (step 97 here)."""
    env = PursuitEnv(TASK, n_worlds=2, seed=3, layouts=[1], auto_reset=False)
    obs = env.reset()
    belief, team, actor = Belief.from_config(TASK), HeuristicTeam.from_config(TASK), HeuristicTeam.from_config(TASK)
    for m in (belief, team, actor):
        m.reset(2)
    goal = belief_spec(env.obs_spec).group("goal")
    for _ in range(110):
        aug = belief.augment(obs, env.obs_spec)
        _, _, sweep, _ = team.observe(obs, env.obs_spec)
        team.tick()
        np.testing.assert_allclose(aug[..., goal.start : goal.start + 2], sweep, atol=1e-5)
        obs, *_ = env.step(actor.act(obs, env.obs_spec))


def test_a_belief_policy_says_whether_the_policy_behind_it_has_a_shield():
    from pursuit_mj.policy import RandomPolicy
    from pursuit_mj.shield import shield_policy

    shielded = BeliefPolicy(BeliefTeam(Belief.from_config(TASK)), Belief.from_config(TASK))
    assert shielded.has_shield and shield_policy(shielded, TASK) is shielded  # not wrapped in a second shield
    plain = BeliefPolicy(RandomPolicy(0), Belief.from_config(TASK))
    assert not plain.has_shield and shield_policy(plain, TASK) is not plain


def test_the_env_wrapper_s_final_observation_is_the_ended_episode_s_and_reset_forgets():
    task = TaskConfig(fidelity="point", max_steps=4)
    env = BeliefEnv(PursuitEnv(task, n_worlds=2, seed=2), Belief.from_config(task))
    plain = PursuitEnv(task, n_worlds=2, seed=2)
    raw_dim = env.raw_spec.dim
    env.reset(), plain.reset()
    rng = np.random.default_rng(0)
    for _ in range(4):
        actions = rng.uniform(-1, 1, (2, task.n_pursuers, 2))
        obs, _, _, truncated, info = env.step(actions)
        _, _, _, _, plain_info = plain.step(actions)
    assert truncated.all()
    np.testing.assert_array_equal(info["final_obs"][..., :raw_dim], plain_info["final_obs"])  # not the next episode's first
    assert not np.array_equal(info["final_obs"][..., :raw_dim], obs[..., :raw_dim])
    # a reset mid-episode starts the belief afresh too
    for _ in range(2):
        env.step(rng.uniform(-1, 1, (2, task.n_pursuers, 2)))
    obs = env.reset()
    fresh = Belief.from_config(task)
    fresh.reset(2)
    np.testing.assert_allclose(obs[..., raw_dim:], fresh.features(obs[..., :raw_dim], env.raw_spec), atol=1e-6)
