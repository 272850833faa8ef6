"""DAgger (train/imitation.py): the dataset, the teacher's share, and a student that really learns."""

import math

import numpy as np
import pytest
import torch

from train.config import ImitationConfig, load_train_config
from train.imitation import Demonstrations, teacher_share
from train.trainer import Trainer


def test_demonstrations_drop_the_oldest_pairs_when_full():
    demos = Demonstrations(capacity=5, obs_dim=1)
    demos.add(torch.arange(3.0)[:, None], torch.zeros(3, 2))
    demos.add(torch.arange(3.0, 7.0)[:, None], torch.ones(4, 2))
    assert demos.size == 5
    assert sorted(demos.obs[:, 0].tolist()) == [2.0, 3.0, 4.0, 5.0, 6.0]
    demos.add(torch.arange(10.0, 18.0)[:, None], torch.ones(8, 2))  # more than fits: keep the newest
    assert sorted(demos.obs[:, 0].tolist()) == [13.0, 14.0, 15.0, 16.0, 17.0]
    obs, act = demos.sample(50, torch.Generator().manual_seed(0))
    assert obs.shape == (50, 1) and act.shape == (50, 2) and obs.min() >= 13.0


def test_teacher_share_falls_linearly_to_zero_and_stays_there():
    cfg = ImitationConfig(beta_start=0.8, beta_updates=4)
    assert [teacher_share(cfg, u) for u in range(6)] == pytest.approx([0.8, 0.6, 0.4, 0.2, 0.0, 0.0])
    assert teacher_share(ImitationConfig(beta_updates=0), 0) == 0.0


def test_the_teacher_drives_each_world_at_a_share_beta_of_its_steps(tmp_path):
    """beta is a per-world, per-step chance, not a share of whole worlds (as the docs once said)."""
    cfg = load_train_config([], ["name=beta", "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "n_envs=4",
                                 "ppo.batch_size=400", "net.encoder_width=8", "net.hidden=[8]", "run.progress=false",
                                 "run.validation_episodes=1", f"run.runs_dir={tmp_path}"])
    trainer = Trainer(cfg, log=lambda s: None)
    trainer.collector.beta = 0.5
    buf = trainer.buffer
    trainer.collector.collect(buf)
    trainer.close()
    labels = trainer.demos.actions[: buf.n_transitions].reshape(buf.T, buf.W, buf.N, 2)
    by_teacher = (buf.actions == labels).all(-1).all(-1).float()  # (T, W): the world stepped with the labels
    assert 0.35 < float(by_teacher.mean()) < 0.65
    assert ((by_teacher.min(0).values == 0) & (by_teacher.max(0).values == 1)).all()  # every world: both drove


def test_learnable_discount_is_refused_with_dagger():
    with pytest.raises(ValueError, match="learnable_gamma"):
        load_train_config([], ["algo=dagger", "ppo.learnable_gamma=true"]).check_complete()


EASY_TEAM = [
    "name=imitate", "seed=0", "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "task.pursuer_speed=0.5",
    "task.evader_speed=0.25", "task.random_obstacles=0", "task.layout=0", "task.max_steps=300",
    "task.observability=partial", "n_envs=16", "total_steps=8192", "ppo.batch_size=1024",
    "imitation.beta_updates=4", "imitation.grad_steps=40", "imitation.minibatch_size=512",
    "net.encoder_width=64", "net.hidden=[64,64]", "net.init_log_std=-2.0",
    "run.validate_every=0", "run.validation_episodes=16", "run.progress=false",
]


@pytest.mark.slow
def test_student_learns_the_teams_pursuit_from_its_own_observations(tmp_path):
    cfg = load_train_config([], EASY_TEAM + [f"run.runs_dir={tmp_path}"])
    trainer = Trainer(cfg, log=lambda s: None)
    before = trainer.validate()
    assert before["success"] <= 0.25, before
    first = trainer.train_one_update()
    result = trainer.train()
    after = result["validation"]
    last = trainer.metrics.rows()[-1]
    assert after["success"] >= 0.8, after
    assert after["collision"] <= 0.1, after
    assert first["loss"]["teacher_share"] == 1.0
    assert last["loss"]["teacher_share"] == 0.0  # the student drove alone at the end
    assert last["loss"]["bc_loss"] < 0.5 * first["loss"]["bc_loss"]


def test_a_run_trained_behind_the_shield_loads_behind_it(tmp_path):
    from pursuit_mj.config import TaskConfig
    from pursuit_mj.obs_spec import ObsSpec
    from train.policy import load_policy

    cfg = load_train_config([], [
        "name=shielded", "algo=dagger", "shield=true", "task.fidelity=point", "task.n_pursuers=2",
        "task.max_steps=20", "n_envs=2", "total_steps=40", "ppo.batch_size=40", "ppo.minibatch_size=20", "imitation.grad_steps=2",
        "imitation.minibatch_size=16", "net.encoder_width=8", "net.hidden=[8]", "run.validate_every=0",
        "run.validation_episodes=2", "run.progress=false", f"run.runs_dir={tmp_path}",
    ])
    trainer = Trainer(cfg, log=lambda s: None)
    assert trainer.collector.path.shield is not None
    trainer.train()
    spec = ObsSpec.make(2, 1, cfg.task.n_rays)
    policy = load_policy(tmp_path / "shielded" / "best.pt", spec, task=TaskConfig(n_pursuers=2, pursuer_speed=0.4))
    assert policy.name == "shielded+shield" and policy.has_shield
    assert policy.shield.speed == 0.4  # sized for the task it runs in, not the one it trained on
    assert load_policy(tmp_path / "shielded" / "best.pt", spec).shield.speed == cfg.task.pursuer_speed


def _fit_one_action(target, kind: str, start, lr: float):
    """The single action (2,) that minimises cloning_loss against every row of target (B, 2), by Adam."""
    import torch

    from train.imitation import cloning_loss

    a = torch.tensor(start, requires_grad=True)
    opt = torch.optim.Adam([a], lr=lr)
    for _ in range(1500):
        opt.zero_grad()
        cloning_loss(a.expand(len(target), 2), target, kind).backward()
        opt.step()
    return a.detach()


def test_heading_speed_cloning_keeps_the_teachers_speed_where_mse_averages_it_away():
    """Two demonstrations of one observation, at full speed left and full speed up: the mse
    optimum is their average (speed 0.71), the heading_speed optimum flies at speed 1."""
    import torch

    from train.imitation import cloning_loss

    target = torch.tensor([[-1.0, 0.0], [0.0, 1.0]])
    best = {kind: _fit_one_action(target, kind, [0.1, 0.1], lr=0.02) for kind in ("mse", "heading_speed")}
    torch.testing.assert_close(best["mse"], torch.tensor([-0.5, 0.5]), atol=1e-3, rtol=0)
    assert abs(float(best["heading_speed"].norm()) - 1.0) < 0.01
    torch.testing.assert_close(best["heading_speed"] / best["heading_speed"].norm(), torch.tensor([-0.7071, 0.7071]),
                               atol=1e-3, rtol=0)
    # a single demonstration is matched exactly by both, and a still teacher asks only for speed 0
    one = torch.tensor([[0.6, -0.8]])
    assert float(cloning_loss(one, one, "heading_speed")) < 1e-3 and float(cloning_loss(one, one, "mse")) == 0.0
    assert float(cloning_loss(torch.zeros(1, 2), torch.zeros(1, 2), "heading_speed")) == 0.0
    with pytest.raises(ValueError, match="imitation.loss: 'huber'"):
        cloning_loss(one, one, "huber")


def test_median_speed_cloning_copies_the_speed_the_teacher_flies_most():
    """Three demonstrations of one observation, all heading +x, at speeds 1, 1 and 0.2: the
    squared speed error is least at their mean (0.73), the absolute one at their median (1)."""
    import torch

    target = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.2, 0.0]])
    speed = {kind: float(_fit_one_action(target, kind, [0.5, 0.0], lr=0.01).norm())
             for kind in ("heading_speed", "heading_median_speed")}
    assert abs(speed["heading_speed"] - 2.2 / 3) < 0.01
    assert abs(speed["heading_median_speed"] - 1.0) < 0.02


def test_a_privileged_teacher_labels_the_students_states_from_its_own_fuller_view(tmp_path):
    from pursuit_mj.config import ConfigError

    cfg = load_train_config([], [
        "name=privileged", "algo=dagger", "belief=true", "task_file=hard", "task.fidelity=point",
        "task.max_steps=30", "n_envs=3", "total_steps=60", "ppo.batch_size=90", "ppo.minibatch_size=30",
        "imitation.grad_steps=2", "imitation.minibatch_size=16", "imitation.teacher_sees=full",
        "net.encoder_width=8", "net.hidden=[8]", "run.validate_every=0", "run.validation_episodes=2",
        "run.progress=false", f"run.runs_dir={tmp_path}",
    ])
    trainer = Trainer(cfg, log=lambda s: None)
    collector = trainer.collector
    raw = trainer.env.raw_spec
    seen = []  # (teacher's observation, student's observation) per step
    act = collector.teacher.act

    def recording_act(obs, spec):
        seen.append((obs.copy(), collector.obs_np.copy()))
        assert spec is raw, "the teacher reads plain observations, without the student's belief features"
        return act(obs, spec)

    collector.teacher.act = recording_act
    trainer.train_one_update()
    assert len(seen) == trainer.buffer.T
    teacher_known = np.stack([raw.group("evaders").view(t)[..., 4] for t, _ in seen])
    student_known = np.stack([raw.group("evaders").view(s[..., : raw.dim])[..., 4] for _, s in seen])
    assert teacher_known.min() == 1.0, "fully observed: the teacher always knows where the evader is"
    assert student_known.mean() < 0.5, "the student, with the hard preset's 120 deg view, mostly does not"
    # the student's own base observation is what the task shows; the teacher's is the same state seen fully
    np.testing.assert_array_equal(raw.group("self").view(seen[5][0]), raw.group("self").view(seen[5][1][..., : raw.dim]))
    with pytest.raises(ConfigError, match="teacher_sees"):
        load_train_config([], ["imitation.teacher_sees=psychic"])


def test_ppo_started_from_a_dagger_student_names_the_noise_it_keeps_over_net_init_log_std(tmp_path):
    """The checkpoint's log std replaced the run's net.init_log_std without a word."""
    small = ["task.fidelity=point", "task.n_pursuers=2", "n_envs=2", "net.encoder_width=8", "net.hidden=[8]",
             "run.validation_episodes=1", "run.progress=false", f"run.runs_dir={tmp_path}"]
    student = Trainer(load_train_config([], small + ["name=student", "algo=dagger", "net.init_log_std=-1.6"]), log=lambda s: None)
    student.save()
    student.close()
    start = [f"init_from={tmp_path / 'student' / 'last.pt'}"]
    lines = []
    ppo = Trainer(load_train_config([], small + ["name=ppo", "net.init_log_std=-0.5"] + start), log=lines.append)
    ppo.close()
    assert ppo.model.actor.log_std.tolist() == pytest.approx([-1.6, -1.6])
    note = next(line for line in lines if line.startswith("initialised from"))
    assert "its log std -1.6 replaces net.init_log_std -0.5" in note
    lines.clear()
    Trainer(load_train_config([], small + ["name=same", "net.init_log_std=-1.6"] + start), log=lines.append).close()
    assert "log std" not in next(line for line in lines if line.startswith("initialised from"))


def _held(demos):
    """The pairs a dataset holds, oldest first: obs (n, D), actions (n, 2)."""
    return demos.newest(demos.size)


def test_demonstration_files_give_back_the_newest_pairs_and_keep_about_one_dataset(tmp_path):
    """Saved before each checkpoint, the files refill a dataset as the checkpoint had it (also after
    the ring wrapped); files of a later update (a crash cut its checkpoint) are not taken, and files
    holding only dropped pairs are removed."""
    from train.demonstration_files import DemonstrationFiles

    files = DemonstrationFiles(tmp_path)
    demos = Demonstrations(capacity=7, obs_dim=1)
    for update in range(1, 5):  # 3 pairs per update: 12 in all, the ring wraps
        first = 3 * (update - 1)
        demos.add(torch.arange(first, first + 3.0)[:, None], torch.full((3, 2), float(update)))
        files.save(demos, update)
        files.prune(demos)  # after the checkpoint
    assert len(list(files.folder.iterdir())) == 3  # the file of update 1 held only dropped pairs
    at_4 = _held(demos)
    demos.add(torch.arange(100.0, 103.0)[:, None], torch.zeros(3, 2))
    files.save(demos, 5)  # its checkpoint never written: a resume from update 4 must not take it
    again = Demonstrations(capacity=7, obs_dim=1)
    assert files.restore(again, 4, total=12) == 7
    assert again.size == 7 and again.total == 12
    for a, b in zip(_held(again), at_4):
        assert torch.equal(a, b)
    assert [float(x) for x in _held(again)[0][:, 0]] == [5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0]
    assert not any(p.name.startswith("u0000005") for p in files.folder.iterdir())
    again.add(torch.tensor([[12.0]]), torch.zeros(1, 2))  # goes on dropping the oldest first
    assert [float(x) for x in _held(again)[0][:, 0]] == [6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]
    # a damaged file costs its pairs and the older ones, not the resume
    newest = max(files.folder.iterdir())
    newest.write_bytes(b"not a tensor file")
    assert files.restore(Demonstrations(capacity=7, obs_dim=1), 4, total=12) == 0


def test_a_resumed_dagger_run_keeps_the_demonstrations_its_last_checkpoint_had(tmp_path):
    """The dataset was not kept: a resumed DAgger run started it empty and learned from the few
    pairs of its next rollouts alone, losing far more than one update."""
    sets = ["name=keep", "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "n_envs=2", "ppo.batch_size=64",
            "task.max_steps=20", "run.validation_episodes=1",
            "total_steps=96", "imitation.grad_steps=2", "imitation.minibatch_size=16", "net.encoder_width=8",
            "net.hidden=[8]", "run.progress=false", "run.validate_every=0", "run.split_update=false",
            f"run.runs_dir={tmp_path}"]
    first = Trainer(load_train_config([], sets), log=lambda s: None)
    first.train()
    assert first.counters.update == 3 and first.demos.total == 3 * 64
    expected = _held(first.demos)
    resumed = Trainer.resume(tmp_path / "keep", total_steps=160, log=lambda s: None)
    try:
        assert resumed.demos.total == first.demos.total
        for a, b in zip(_held(resumed.demos), expected):
            assert torch.equal(a, b)
    finally:
        resumed.close()


def test_unsaved_gives_only_the_pairs_added_since_the_last_save_with_their_index():
    """The demonstration files hold each pair once: after mark_saved, unsaved gives the pairs
    added since (index in total of the first), not the whole dataset again; pairs added and
    dropped again before a save are not given."""
    demos = Demonstrations(capacity=5, obs_dim=1)
    demos.add(torch.arange(4.0)[:, None], torch.zeros(4, 2))
    first, obs, _ = demos.unsaved()
    assert first == 0 and obs[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0]
    demos.mark_saved()
    demos.add(torch.arange(4.0, 7.0)[:, None], torch.ones(3, 2))
    first, obs, actions = demos.unsaved()
    assert first == 4 and obs[:, 0].tolist() == [4.0, 5.0, 6.0] and actions.tolist() == [[1.0, 1.0]] * 3
    demos.mark_saved()
    demos.add(torch.arange(7.0, 15.0)[:, None], torch.ones(8, 2))  # 8 new pairs, 5 held
    first, obs, _ = demos.unsaved()
    assert first == 10 and obs[:, 0].tolist() == [10.0, 11.0, 12.0, 13.0, 14.0]
    demos.mark_saved()
    assert demos.unsaved()[1].shape == (0, 1)


def test_sampling_draws_only_pairs_the_dataset_holds_before_it_is_full():
    """Before the ring is full, minibatches come from the pairs added, never from the empty slots
    (zero observations labelled with zero actions)."""
    demos = Demonstrations(capacity=100, obs_dim=1)
    demos.add(torch.tensor([[1.0], [2.0], [3.0]]), torch.ones(3, 2))
    obs, actions = demos.sample(300, torch.Generator().manual_seed(0))
    assert set(obs[:, 0].tolist()) == {1.0, 2.0, 3.0} and bool((actions == 1.0).all())


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_a_teacher_share_of_one_drives_every_step_and_of_zero_none(tmp_path, beta):
    """beta is the teacher's chance to drive a world's step: 1 at the start of DAgger (the teacher
    drives everything), 0 once beta_updates have passed (the student alone, exploring with its
    Gaussian noise)."""
    cfg = load_train_config([], ["name=beta", "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "n_envs=2",
                                 "ppo.batch_size=64", "net.encoder_width=8", "net.hidden=[8]", "run.progress=false",
                                 "run.validation_episodes=1", f"run.runs_dir={tmp_path}"])
    trainer = Trainer(cfg, log=lambda s: None)
    trainer.collector.beta = beta
    buf = trainer.buffer
    trainer.collector.collect(buf)
    trainer.close()
    labels = trainer.demos.actions[: buf.n_transitions].reshape(buf.T, buf.W, buf.N, 2)
    by_teacher = (buf.actions == labels).all(-1).all(-1).float()  # (T, W)
    assert by_teacher.tolist() == [[beta] * buf.W] * buf.T
    if beta == 0.0:  # the student explores: its actions are samples around its mean, std exp(log_std)
        with torch.no_grad():
            mean, log_std = trainer.model.actor(buf.obs, trainer.model.spec)
        inside = buf.actions.abs() < 1.0  # not clamped
        spread = float((buf.actions - mean)[inside].std()) / float(log_std.detach().exp().mean())
        assert int(inside.sum()) > 50 and 0.7 < spread < 1.3, spread


def test_cloning_losses_on_hand_computed_numbers():
    """mse is the squared distance of the two actions averaged over the batch (not over its
    coordinates too); heading_speed adds the squared speed error to the squared heading error,
    heading_median_speed the absolute one."""
    from train.imitation import cloning_loss

    student = torch.tensor([[0.0, 0.0], [0.3, 0.4]])
    teacher = torch.tensor([[0.6, 0.8], [0.3, 0.4]])
    assert float(cloning_loss(student, teacher, "mse")) == pytest.approx((1.0 + 0.0) / 2)
    # student (0, 0): heading 0, teacher heading (0.6, 0.8): heading error 1; speed error 1
    # student (0.3, 0.4) = teacher: heading (0.3, 0.4) / sqrt(0.25 + 0.05^2) vs (0.6, 0.8), speed error 0
    h = (0.5 / math.sqrt(0.25 + 0.0025) - 1.0) ** 2
    assert float(cloning_loss(student, teacher, "heading_speed")) == pytest.approx((1.0 + h) / 2 + (1.0 + 0.0) / 2)
    slow = torch.tensor([[0.0, 0.2], [0.3, 0.4]])  # speed error 0.8, heading (0, 0.2) / sqrt(0.04 + 0.0025)
    hs = (0.6 ** 2 + (0.2 / math.sqrt(0.0425) - 0.8) ** 2)
    assert float(cloning_loss(slow, teacher, "heading_median_speed")) == pytest.approx((hs + h) / 2 + 0.8 / 2)
    assert float(cloning_loss(slow, teacher, "heading_speed")) == pytest.approx((hs + h) / 2 + 0.64 / 2)
    # a still teacher (below 0.05) has no heading to learn: only the speed counts
    assert float(cloning_loss(torch.tensor([[0.3, 0.4]]), torch.tensor([[0.01, 0.0]]), "heading_speed")) == pytest.approx(0.49 ** 2)


def test_a_dagger_rollout_bootstraps_a_timeout_from_the_ended_episodes_last_observation():
    """At a timeout the critic's target goes on from the value of the ended episode's last
    observation (info["final_obs"]), as in PPO's collector: not 0 (a timeout is no terminal
    state), and not the value of the observation the auto-reset began."""
    from pursuit_mj.config import default_config
    from pursuit_mj.env import PursuitEnv
    from pursuit_mj.heuristic import HeuristicTeam
    from train.agent import ActorCritic
    from train.config import TrainConfig
    from train.imitation import DaggerCollector
    from train.storage import Rollout

    task = default_config(fidelity="point", random_obstacles=0, max_steps=6)
    env = PursuitEnv(task, n_worlds=2, seed=3, nthread=1)
    torch.manual_seed(0)
    model = ActorCritic(env.obs_spec, env.state_dim, TrainConfig())
    ends = []
    real_step = env.step

    def recording_step(actions):
        out = real_step(actions)
        ends.append((out[3].copy(), out[4]["final_obs"].copy()))
        return out

    env.step = recording_step
    buf = Rollout(8, 2, env.n_pursuers, env.obs_dim)
    collector = DaggerCollector(env, model, HeuristicTeam.from_config(task), Demonstrations(1000, env.obs_dim),
                                torch.Generator().manual_seed(1))
    collector.beta = 0.5
    collector.collect(buf)
    t = int(torch.nonzero(buf.truncated.any(1))[0])
    truncated, last_obs = ends[t]
    idx = np.flatnonzero(truncated)
    with torch.no_grad():
        expected = model.value(torch.as_tensor(last_obs[idx]), None)
        reset = model.value(buf.obs[t + 1, idx], None)
    torch.testing.assert_close(buf.final_values[t, idx], expected)
    assert not torch.allclose(buf.final_values[t, idx], reset) and bool((expected != 0).all())
    assert bool((buf.final_values[~buf.truncated] == 0).all())
    with torch.no_grad():  # the rollout's last step goes on from the value of the observation it ends at
        last = model.value(collector.obs, None)
    assert torch.equal(buf.last_value, last) and bool((last != 0).all())


def test_the_dagger_update_clips_its_gradient_at_imitation_max_grad_norm(tmp_path):
    """DAgger's update clips at imitation.max_grad_norm (here 0.05), not at PPO's ppo.max_grad_norm;
    the logged grad_norm is the norm before clipping."""
    from train.imitation import imitation_update

    cfg = load_train_config([], ["name=clip", "algo=dagger", "task.fidelity=point", "task.n_pursuers=2", "n_envs=2",
                                 "ppo.batch_size=64", "net.encoder_width=8", "net.hidden=[8]", "run.progress=false",
                                 "run.split_update=false", "imitation.max_grad_norm=0.05", "imitation.grad_steps=3",
                                 "imitation.minibatch_size=16", "run.validation_episodes=1", f"run.runs_dir={tmp_path}"])
    trainer = Trainer(cfg, log=lambda s: None)
    try:
        buf, _ = trainer._next_rollout()
        model = trainer.model
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        norms = []
        real_step = optimizer.step

        def step(*args, **kwargs):
            norms.append(float(torch.stack([p.grad.norm() for p in model.parameters() if p.grad is not None]).norm()))
            return real_step(*args, **kwargs)

        optimizer.step = step
        stats = imitation_update(model, optimizer, trainer.demos, buf, cfg.imitation, cfg.ppo, 0.99,
                                 torch.Generator().manual_seed(5))
    finally:
        trainer.close()
    assert cfg.ppo.max_grad_norm > 0.05 and stats["grad_norm"] > 0.05
    assert len(norms) == 3 and max(norms) <= 0.05 * (1 + 1e-5)
