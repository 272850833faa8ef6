"""Residual policy learning (pursuit_mj/residual.py, train residual.*): a learned correction on a base team."""

import numpy as np
import pytest
import torch

from pursuit_mj.config import TaskConfig
from pursuit_mj.env import PursuitEnv
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.residual import ResidualTeam, combine
from pursuit_mj.belief import Belief, BeliefPolicy, BeliefTeam, belief_spec
from pursuit_mj.shield import SafetyShield, shield_policy
from train.config import NetConfig, load_train_config
from train.networks import Actor
from train.rollout import make_action_path
from train.policy import ActorPolicy, load_policy, trained_team
from train.rollout import ActionPath
from train.trainer import Trainer


class ConstantPolicy:
    """Every pursuer asks for the same action (2,)."""

    def __init__(self, action, name="const"):
        self.action = np.asarray(action, dtype=np.float64)
        self.name = name

    def reset(self, n_worlds, world_ids=None):
        pass

    def act(self, obs, spec):
        return np.broadcast_to(self.action, obs.shape[:2] + (2,)).copy()


def test_combine_adds_the_scaled_correction_and_stays_in_the_unit_disc():
    base = np.array([[[0.2, 0.0], [1.0, 0.0], [0.0, 0.0]]])
    corr = np.array([[[0.0, 1.0], [0.0, 5.0], [-3.0, 0.0]]])  # correction is clipped per axis first
    out = combine(base, corr, 0.5)
    assert out[0, 0] == pytest.approx([0.2, 0.5])
    assert out[0, 1] == pytest.approx(np.array([1.0, 0.5]) / np.hypot(1.0, 0.5))  # direction kept, norm 1
    assert out[0, 2] == pytest.approx([-0.5, 0.0])
    assert np.all(np.linalg.norm(out, axis=-1) <= 1.0 + 1e-12)


def _episode_actions(policy, task, steps=30):
    env = PursuitEnv(task, n_worlds=3, seed=5)
    obs = env.reset()
    policy.reset(env.n_worlds)
    actions = []
    for _ in range(steps):
        a = policy.act(obs, env.obs_spec)
        actions.append(a)
        obs, *_ = env.step(a)
    return np.array(actions)


def test_a_zero_correction_drives_exactly_like_the_base_team():
    task = TaskConfig(fidelity="point")
    alone = _episode_actions(HeuristicTeam.from_config(task), task)
    team = ResidualTeam(HeuristicTeam.from_config(task), ConstantPolicy([0.0, 0.0]), scale=0.5)
    assert team.name == "const@heuristic"
    np.testing.assert_array_equal(_episode_actions(team, task), alone)


def test_a_belief_fed_correction_shares_its_memory_with_the_heuristic_base():
    task = TaskConfig(fidelity="point")
    actor = Actor(belief_spec(PursuitEnv(task, n_worlds=1).obs_spec), NetConfig(encoder_width=8, hidden=(8,)))
    residual = load_train_config([], ["residual.base=heuristic"]).residual
    team = trained_team(ActorPolicy(actor, "bel"), task, shield=True, residual=residual, belief=True)
    assert isinstance(team.policy.base, BeliefTeam) and team.policy.base.belief is team.policy.correction.belief
    separate = ResidualTeam(HeuristicTeam.from_config(task), BeliefPolicy(ActorPolicy(actor, "bel"), Belief.from_config(task)), residual.scale)
    np.testing.assert_array_equal(_episode_actions(team, task), _episode_actions(shield_policy(separate, task), task))


def test_a_correction_steers_the_team():
    task = TaskConfig(fidelity="point")
    base = _episode_actions(HeuristicTeam.from_config(task), task, steps=1)
    team = ResidualTeam(HeuristicTeam.from_config(task), ConstantPolicy([0.0, 1.0]), scale=0.5)
    pushed = _episode_actions(team, task, steps=1)
    np.testing.assert_allclose(pushed, combine(base, np.array([0.0, 1.0]), 0.5))
    assert (pushed[..., 1] > base[..., 1]).all()


def test_bad_scale_is_refused():
    with pytest.raises(ValueError, match="scale"):
        ResidualTeam(HeuristicTeam(), ConstantPolicy([0, 0]), scale=0.0)


def test_the_action_path_adds_the_base_team_then_shields():
    task = TaskConfig(fidelity="point")
    env = PursuitEnv(task, n_worlds=2, seed=1)
    env.reset()
    toward_wall = np.tile([-1.0, 0.0], (2, task.n_pursuers, 1))
    for _ in range(10):  # fly toward the -x border until the shield has work to do
        obs, *_ = env.step(toward_wall)
    heuristic = HeuristicTeam.from_config(task)
    heuristic.reset(2)
    correction = toward_wall.copy()
    summed = combine(heuristic.act(obs, env.obs_spec), correction, 1.0)
    reference_shield = SafetyShield.from_config(task)
    reference_shield.reset(2)
    want = reference_shield.shield_actions(summed, obs, env.obs_spec)
    assert np.abs(want - summed).max() > 0.1
    path = ActionPath(shield=SafetyShield.from_config(task), base=HeuristicTeam.from_config(task), scale=1.0)
    path.reset(2)
    got = path(torch.as_tensor(correction, dtype=torch.float32), torch.as_tensor(obs), env.obs_spec)
    np.testing.assert_allclose(got, want)
    unshielded = ActionPath(base=HeuristicTeam.from_config(task), scale=1.0)
    unshielded.reset(2)
    np.testing.assert_allclose(unshielded(torch.as_tensor(correction, dtype=torch.float32), torch.as_tensor(obs), env.obs_spec), summed)


@pytest.mark.parametrize("overrides, message", [
    (["algo=dagger", "residual.base=heuristic"], "residual.base"),
    (["residual.base=greedy"], "greedy"),
    (["residual.scale=0"], "residual.scale"),
])
def test_bad_residual_settings_are_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=message):
        load_train_config([], overrides).check_complete()


def test_a_residual_run_trains_validates_and_loads_as_its_team(tmp_path):
    from pursuit_mj.obs_spec import ObsSpec

    cfg = load_train_config([], [
        "name=res", "algo=ppo", "shield=true", "residual.base=heuristic", "residual.scale=0.5",
        "task.fidelity=point", "task.n_pursuers=2", "task.max_steps=30", "n_envs=2", "total_steps=80",
        "ppo.batch_size=80", "ppo.minibatch_size=40", "ppo.epochs=1", "net.encoder_width=8", "net.hidden=[8]",
        "run.validate_every=1", "run.validation_episodes=2", "run.progress=false", f"run.runs_dir={tmp_path}",
    ])
    trainer = Trainer(cfg, log=lambda s: None)
    path = make_action_path(cfg)  # what the rollout worker steps the env through
    assert isinstance(path.base, HeuristicTeam) and path.shield is not None
    result = trainer.train()
    assert result["status"] == "done" and result["validation"]["episodes"] == 2
    val = result["validation"]
    assert val["heuristic_mean_steps"] > 0 and val["vs_heuristic_lo"] <= val["vs_heuristic_steps"] <= val["vs_heuristic_hi"]
    spec = ObsSpec.make(2, 1, cfg.task.n_rays)
    policy = load_policy(tmp_path / "res" / "best.pt", spec, task=TaskConfig(n_pursuers=2, pursuer_speed=0.4))
    assert policy.name == "res@heuristic+shield" and policy.has_shield
    assert isinstance(policy.policy, ResidualTeam) and policy.policy.scale == 0.5
    assert policy.policy.base.speed == 0.4  # the base team is sized for the task it runs in


@pytest.mark.parametrize("scale", ["x", None, True, float("nan"), 0.0, -1.0])
def test_a_residual_team_refuses_a_scale_that_is_no_positive_number_by_name(scale):
    """scale='x' or None failed inside math.isfinite with a bare TypeError; True passed as 1.0."""
    task = TaskConfig(fidelity="point")
    with pytest.raises(ValueError, match="ResidualTeam: scale must be a positive number, got"):
        ResidualTeam(HeuristicTeam.from_config(task), ConstantPolicy([0.0, 0.0]), scale=scale)
