"""Training regimes and configs: the shipped YAMLs, fine_tune from full_obs, MAPPO, learnable discount."""

import json
import os
from pathlib import Path

import pytest
import torch

from pursuit_mj.config import ConfigError, load_task_config
from train.checkpoint import load_checkpoint
from train.config import load_train_config
from train.trainer import Trainer

TINY = [
    "task.fidelity=point", "task.random_obstacles=0", "task.max_steps=40",
    "n_envs=2", "ppo.batch_size=96", "ppo.minibatch_size=48", "ppo.epochs=2",
    "run.validate_every=0", "run.validation_episodes=2", "run.progress=false",
]
QUIET = {"log": lambda s: None}


@pytest.mark.parametrize("name,gamma,clip,envs,speeds,obs", [
    ("classic", 0.99, 0.2, 6, (0.3, 0.6), "partial"),
    ("full_obs", 0.95, 0.15, 10, (0.2, 0.3), "full"),
    ("fine_tune", 0.95, 0.1, 20, (0.2, 0.3), "partial"),
    ("mappo", 0.99, 0.2, 6, (0.3, 0.6), "partial"),
])
def test_regime_files_carry_the_reference_hyperparameters(name, gamma, clip, envs, speeds, obs):
    cfg = load_train_config([f"configs/train/{name}.yaml"])
    assert (cfg.ppo.gamma, cfg.ppo.clip, cfg.n_envs) == (gamma, clip, envs)
    assert (cfg.task.pursuer_speed, cfg.task.evader_speed, cfg.task.observability) == (*speeds, obs)
    assert (cfg.ppo.lr, cfg.ppo.gae_lambda, cfg.ppo.epochs, cfg.ppo.batch_size, cfg.ppo.minibatch_size) == (3e-4, 0.95, 10, 1024, 256)
    assert cfg.algo == ("mappo" if name == "mappo" else "ppo")
    assert cfg.regime == name


@pytest.mark.parametrize("path", sorted(str(p) for p in Path("configs/train").glob("*.yaml")))
def test_every_shipped_config_trains_at_least_two_episodes_long_between_validations(path):
    """A validation plays its episodes to the last one (up to max_steps in all its worlds at once)
    and costs about as much as max_steps decision steps of training; more often than every 2 x
    max_steps steps per world it took 40-70 % of a run's time (docs/training.md)."""
    cfg = load_train_config([path])
    assert cfg.run.validate_every > 0
    assert cfg.rollout_steps() * cfg.run.validate_every >= 2 * cfg.task.max_steps


def test_validating_changes_nothing_that_is_trained(tmp_path):
    """Validation plays its own env with its own seeds: the trained weights do not depend on how often it runs."""
    weights = []
    for every in (0, 1):
        cfg = load_train_config([], TINY + [f"run.validate_every={every}", f"run.runs_dir={tmp_path}", f"name=v{every}",
                                            "total_steps=60"])
        Trainer(cfg, **QUIET).train()
        weights.append(load_checkpoint(cfg.run_dir / "last.pt")["actor"])
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])


def test_the_initial_weights_do_not_depend_on_the_torch_thread_count(tmp_path):
    """Orthogonal init goes through a QR decomposition whose rounding depends on the threads
    it runs on: a second run in one process (after an update on one thread) started from
    weights 1e-8 away from the first's and trained differently."""
    weights, before = [], torch.get_num_threads()
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            cfg = load_train_config([], TINY + [f"run.runs_dir={tmp_path}", f"name=t{threads}"])
            weights.append(Trainer(cfg, **QUIET).model.state_dict())
    finally:
        torch.set_num_threads(before)
    for key in weights[0]:
        assert torch.equal(weights[0][key], weights[1][key]), key


def test_overrides_flags_and_task_file():
    cfg = load_train_config(["classic"], ["ppo.lr=1e-4", "task.fidelity=point", "task_file=hard"], {"total_steps": 5000})
    assert cfg.ppo.lr == 1e-4 and cfg.task.fidelity == "point" and cfg.total_steps == 5000
    hard = load_task_config(["hard"])
    # --set task_file applies its preset over the train file's task keys (classic's evader at
    # 0.6 m/s trained a mix of the two tasks that `eval --task hard` did not play)
    assert cfg.task.evader_speed == hard.evader_speed == 0.9
    assert cfg.task.miss_probability == hard.miss_probability > 0
    assert cfg.task.pursuer_speed == 0.3 and cfg.task.fidelity == "point"  # what the preset leaves, and later --set keys
    later = load_train_config(["classic"], ["task.evader_speed=1.2", "task_file=hard"], {"task": {"perception_radius": 2.5}})
    assert later.task.evader_speed == 1.2 and later.task.perception_radius == 2.5  # --set task.* and flags beat the preset
    with pytest.raises(ValueError, match="ppo.lrr.*did you mean 'ppo.lr'"):
        load_train_config(["classic"], ["ppo.lrr=1"])
    with pytest.raises(ValueError, match="pursuer_speed.*out of range"):
        load_train_config(["classic"], ["task.pursuer_speed=-1"])
    with pytest.raises(ValueError, match="fine_tune needs init_from"):
        load_train_config(["fine_tune"], ["init_from=null"])
    with pytest.raises(ValueError, match="minibatch_size 512 exceeds ppo.batch_size 256"):
        load_train_config([], ["ppo.batch_size=256", "ppo.minibatch_size=512"]).check_complete()


def test_a_train_file_that_a_later_flag_or_set_completes_is_accepted(tmp_path):
    """The train files' checks across keys were judged before the flags and --set applied: a file of
    one's own with regime fine_tune and no init_from was refused beside --init-from CKPT ('needs
    init_from'), and an evader.panic_distance that a --set calm_distance made consistent was refused."""
    own = tmp_path / "ft.yaml"
    own.write_text("name: ft\nregime: fine_tune\n")
    assert load_train_config([own], [], {"init_from": "ckpt.pt"}).init_from == "ckpt.pt"
    assert load_train_config([own], ["init_from=ckpt.pt"]).init_from == "ckpt.pt"
    panic = tmp_path / "panic.yaml"
    panic.write_text("name: p\ntask:\n  evader:\n    panic_distance: 3.5\n")
    assert load_train_config([panic], ["task.evader.calm_distance=5"]).task.evader.calm_distance == 5.0
    # nothing later repairs it: still refused, naming the file that left it so
    with pytest.raises(ConfigError, match=f"^{own}: regime fine_tune needs init_from"):
        load_train_config([own], ["ppo.lr=1e-4"], {"total_steps": 1000})
    with pytest.raises(ConfigError, match=r"^--set init_from=null: regime fine_tune needs init_from"):
        load_train_config(["fine_tune"], ["init_from=null"])


def test_a_task_file_applies_where_its_train_file_stands_in_the_order(tmp_path):
    """Files apply in order, each with its task_file under its own task: keys: a later file's
    task_file used to lose to an earlier file's task: keys."""
    slow = tmp_path / "slow.yaml"
    slow.write_text("name: x\ntask:\n  evader_speed: 0.5\n  pursuer_speed: 0.25\n")
    hard = tmp_path / "hard_run.yaml"
    hard.write_text("name: y\ntask_file: hard\n")
    tuned = tmp_path / "tuned.yaml"
    tuned.write_text("name: z\ntask_file: hard\ntask:\n  evader_speed: 0.7\n")
    cfg = load_train_config([slow, hard], [])
    assert (cfg.task.evader_speed, cfg.task.pursuer_speed, cfg.task.miss_probability) == (0.9, 0.25, 0.2)
    assert load_train_config([slow, tuned], []).task.evader_speed == 0.7  # a file's own task keys beat its task_file
    assert load_train_config([hard, slow], []).task.evader_speed == 0.5  # a later file beats an earlier task_file
    assert load_train_config([hard, slow], []).task.miss_probability == 0.2
    assert load_train_config([slow, hard], []).task_file == "hard"


def test_settings_this_combination_never_reads_are_named_when_the_run_starts(tmp_path):
    """residual.scale without a base, ppo.value_scaling under MAPPO, MAPPO's critic widths or
    DAgger settings under PPO were taken without a word: a user tuning them saw no effect."""
    assert load_train_config(["classic"], []).idle_settings() == []
    assert load_train_config(["residual"], ["residual.scale=0.5"]).idle_settings() == []
    idle = load_train_config(["classic"], ["residual.scale=0.5", "net.critic_hidden=[64]", "imitation.lr=1e-4"]).idle_settings()
    assert idle == ["residual.scale 0.5 does nothing without residual.base",
                    "net.critic_hidden [64] does nothing under algo ppo (it sizes MAPPO's critic)",
                    "imitation.lr does nothing under algo ppo (DAgger settings)"]
    assert load_train_config(["mappo"], ["ppo.value_scaling=false"]).idle_settings() == [
        "ppo.value_scaling does nothing under algo mappo (its centralised critic normalises values)"]
    lines: list[str] = []
    cfg = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "residual.scale=0.5"])
    Trainer(cfg, log=lines.append)
    assert "[train] note: residual.scale 0.5 does nothing without residual.base" in lines


def test_a_drone_mass_under_point_fidelity_is_named_as_idle():
    """The point model's lag and acceleration limit do not follow drone_mass (docs/DESIGN.md): a run
    with --set task.drone_mass=0.033 --fidelity point trained exactly as at 0.027 g, without a word."""
    assert load_train_config(["classic"], ["task.drone_mass=0.033"]).idle_settings() == []  # quadrotor flies it
    assert load_train_config(["classic"], ["task.fidelity=point"]).idle_settings() == []
    assert load_train_config(["classic"], ["task.fidelity=point", "task.drone_mass=0.033"]).idle_settings() == [
        "task.drone_mass 0.033 does nothing under task.fidelity point (the point model's response does not follow "
        "the mass; quadrotor fidelity flies it)"]


def test_ppo_update_settings_under_dagger_are_named_as_idle_and_refuse_nothing():
    """DAgger's update reads imitation.lr, minibatch_size, max_grad_norm: --config imitate --set
    ppo.lr=1e-5 changed nothing without a word (imitation.lr under PPO was named), and
    ppo.minibatch_size, which it never reads, refused a smaller ppo.batch_size."""
    assert load_train_config(["imitate"], []).idle_settings() == []
    assert load_train_config(["imitate"], ["ppo.lr=1e-5", "ppo.epochs=3"]).idle_settings() == [
        "ppo.lr, ppo.epochs do nothing under algo dagger (PPO's update; DAgger's are imitation.lr, "
        "imitation.minibatch_size, imitation.max_grad_norm, imitation.grad_steps)"]
    load_train_config(["imitate"], ["ppo.batch_size=128"]).check_complete()  # ppo.minibatch_size 256 is not used
    with pytest.raises(ValueError, match="ppo.minibatch_size 256 exceeds ppo.batch_size 128"):
        load_train_config(["classic"], ["ppo.batch_size=128"]).check_complete()


def test_settings_idle_under_mlp_a_fixed_discount_or_dagger_are_named():
    """net.encoder_width and net.use_rays under net.kind mlp, the meta-gradient's settings without
    ppo.learnable_gamma and run.overlap under DAgger changed nothing without a word."""
    assert load_train_config(["classic"], ["net.kind=mlp", "net.encoder_width=64", "net.use_rays=false"]).idle_settings() == [
        "net.encoder_width, net.use_rays do nothing under net.kind mlp (the reference network's entity encoders)"]
    assert load_train_config(["classic"], ["ppo.gamma_meta_lr=0.01", "ppo.gamma_outer=0.9"]).idle_settings() == [
        "ppo.gamma_meta_lr, ppo.gamma_outer do nothing without ppo.learnable_gamma (they tune the learned discount)"]
    assert load_train_config(["classic"], ["ppo.learnable_gamma=true", "ppo.gamma_outer=0.9"]).idle_settings() == []
    assert load_train_config(["imitate"], ["run.overlap=true"]).idle_settings() == [
        "run.overlap does nothing under algo dagger (it always collects in turn: the teacher's labels feed the update)"]
    assert load_train_config(["classic"], ["run.overlap=true", "net.use_rays=false"]).idle_settings() == []
    assert load_train_config(["classic"], ["run.overlap=true", "run.split_update=false"]).idle_settings() == [
        "run.split_update false does nothing with run.overlap (its update runs in one process)"]
    assert load_train_config(["classic"], ["run.split_update=false"]).idle_settings() == []


def test_a_teacher_share_that_never_applies_is_named_as_idle():
    """With imitation.beta_updates 0 the teacher never drives, whatever imitation.beta_start says
    (and with beta_start 0 the length of its fall is moot): both changed nothing without a word."""
    assert load_train_config(["imitate"], ["imitation.beta_updates=0", "imitation.beta_start=0.5"]).idle_settings() == [
        "imitation.beta_start 0.5 does nothing with imitation.beta_updates 0 (the teacher never drives; it labels only)"]
    assert load_train_config(["imitate"], ["imitation.beta_start=0"]).idle_settings() == [
        "imitation.beta_updates 40 does nothing with imitation.beta_start 0 (the teacher never drives; it labels only)"]
    assert load_train_config(["imitate"], ["imitation.beta_start=0.5"]).idle_settings() == []


def test_update_threads_take_the_cores_the_collection_leaves_idle():
    run = load_train_config(["classic"]).run
    assert run.torch_threads == 0  # auto by default
    assert run.update_threads(overlapped=False, cores=8) == 8  # collection waits: every core
    assert run.update_threads(overlapped=True, cores=8) == 7  # one core collects meanwhile
    assert run.update_threads(overlapped=True, cores=1) == 1
    fixed = load_train_config(["classic"], ["run.torch_threads=3"]).run
    assert fixed.update_threads(overlapped=False, cores=8) == fixed.update_threads(overlapped=True, cores=8) == 3


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity on this OS")
def test_update_threads_count_only_the_cores_this_process_may_use():
    """Under `taskset -c 0` (or a container's CPU set) the update must not start a thread per machine core."""
    run = load_train_config(["classic"]).run
    allowed = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(allowed)})
        assert run.update_threads(overlapped=False) == 1
    finally:
        os.sched_setaffinity(0, allowed)


def test_fine_tune_starts_from_full_obs_weights_and_switches_observability(tmp_path):
    base = TINY + [f"run.runs_dir={tmp_path}", "total_steps=32"]
    full = load_train_config(["full_obs"], base + ["n_envs=2"])
    Trainer(full, **QUIET).train()
    source = load_checkpoint(full.run_dir / "best.pt")
    assert source["train_config"]["task"]["observability"] == "full"

    ft = load_train_config(["fine_tune"], base + [f"init_from={full.run_dir / 'best.pt'}"])
    trainer = Trainer(ft, **QUIET)
    assert trainer.env.config.observability == "partial"
    assert trainer.env.config.collision_penalty == ft.task.collision_penalty != full.task.collision_penalty
    for k, v in source["actor"].items():
        assert torch.equal(trainer.model.actor.state_dict()[k], v), k
    for k, v in source["critic"].items():
        assert torch.equal(trainer.model.critic.state_dict()[k], v), k
    assert trainer.counters.update == 0  # weights only: a new run with its own counters
    trainer.train()
    moved = load_checkpoint(ft.run_dir / "last.pt")["actor"]
    assert any(not torch.equal(moved[k], v) for k, v in source["actor"].items())


def test_a_mappo_run_started_from_a_mappo_checkpoint_keeps_its_critics_value_scale(tmp_path):
    base = TINY + [f"run.runs_dir={tmp_path}", "total_steps=96"]
    source_cfg = load_train_config(["mappo"], base + ["name=src"])
    Trainer(source_cfg, **QUIET).train()
    source = load_checkpoint(source_cfg.run_dir / "last.pt")
    assert source["value_norm"]["count"] > 1  # the source learnt its returns' statistics
    child = Trainer(load_train_config(["mappo"], base + ["name=child", f"init_from={source_cfg.run_dir / 'last.pt'}"]), **QUIET)
    for k, v in source["value_norm"].items():
        assert torch.equal(torch.as_tensor(child.model.value_norm.state_dict()[k]), torch.as_tensor(v)), k


def test_an_anchor_needs_a_start_and_is_idle_under_dagger():
    with pytest.raises(ConfigError, match=r"ppo.anchor_coef 0.5 needs init_from"):
        load_train_config(["classic"], ["ppo.anchor_coef=0.5"]).check_complete()
    assert load_train_config(["imitate"], ["ppo.anchor_coef=0.5"]).idle_settings() == [
        "ppo.anchor_coef does nothing under algo dagger (PPO's update; DAgger's are imitation.lr, "
        "imitation.minibatch_size, imitation.max_grad_norm, imitation.grad_steps)"]
    with pytest.raises(ConfigError, match=r"ppo.anchor_coef.*-1"):
        load_train_config(["classic"], ["ppo.anchor_coef=-1"])


def test_an_anchored_run_keeps_its_start_as_anchor_through_a_resume(tmp_path):
    """The anchor is the init_from actor, frozen; the checkpoint carries it, so a resume keeps
    it even when the file it started from is gone, and the log shows the KL to it."""
    base = TINY + [f"run.runs_dir={tmp_path}"]
    src = load_train_config(["classic"], base + ["name=src", "total_steps=32"])
    Trainer(src, **QUIET).train()
    start = tmp_path / "start.pt"
    (src.run_dir / "last.pt").rename(start)
    cfg = load_train_config(["classic"], base + ["name=anchored", "total_steps=64", f"init_from={start}",
                                                 "ppo.anchor_coef=1.0", "ppo.lr=3e-3"])
    trainer = Trainer(cfg, **QUIET)
    trainer.train_one_update()
    trainer.save()
    trainer.close()
    start_actor = load_checkpoint(start)["actor"]
    saved = load_checkpoint(cfg.run_dir / "last.pt")
    for k, v in start_actor.items():
        assert torch.equal(saved["anchor_actor"][k], v), k
    assert any(not torch.equal(saved["actor"][k], v) for k, v in start_actor.items())
    start.unlink()
    resumed = Trainer.resume(cfg.run_dir, **QUIET)
    for k, v in start_actor.items():
        assert torch.equal(resumed.anchor.state_dict()[k], v), k
    assert all(not p.requires_grad for p in resumed.anchor.parameters())
    resumed.train()
    rows = [json.loads(line) for line in (cfg.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert all(row["loss"]["anchor_kl"] >= 0.0 for row in rows) and rows[-1]["loss"]["anchor_kl"] > 0.0


def test_an_anchored_checkpoint_without_its_anchor_is_refused_on_resume(tmp_path):
    base = TINY + [f"run.runs_dir={tmp_path}"]
    src = load_train_config(["classic"], base + ["name=src", "total_steps=32"])
    Trainer(src, **QUIET).train()
    cfg = load_train_config(["classic"], base + ["name=anchored", "total_steps=64",
                                                 f"init_from={src.run_dir / 'last.pt'}", "ppo.anchor_coef=1.0"])
    trainer = Trainer(cfg, **QUIET)
    trainer.train_one_update()
    data = trainer.checkpoint_payload()
    trainer.close()
    del data["anchor_actor"]
    from train.checkpoint import save_checkpoint
    save_checkpoint(cfg.run_dir / "last.pt", data)
    with pytest.raises(ValueError, match=r"cannot resume from its anchor actor"):
        Trainer.resume(cfg.run_dir, **QUIET)


def test_fine_tune_without_its_full_obs_checkpoint_says_how_to_get_one(tmp_path):
    ft = load_train_config(["fine_tune"], TINY + [f"run.runs_dir={tmp_path}", f"init_from={tmp_path / 'nope.pt'}"])
    with pytest.raises(ValueError, match=r"init_from .*nope.pt: no such checkpoint .*--init-from.*"
                                         r"fine_tune starts from a full_obs run"):
        Trainer(ft, **QUIET)


def test_fine_tune_from_a_partially_observed_run_is_refused_and_custom_takes_it(tmp_path):
    """fine_tune means continuing a full_obs run under partial observability; from a classic run it
    was accepted with only a line in the log saying which observability the weights had."""
    base = TINY + [f"run.runs_dir={tmp_path}", "total_steps=32"]
    classic = load_train_config(["classic"], base + ["name=src"])
    Trainer(classic, **QUIET).train()
    start = f"init_from={classic.run_dir / 'best.pt'}"
    with pytest.raises(ValueError, match=r"src.best.pt: fine_tune starts from a full_obs run, and this checkpoint was "
                                         r"trained with observability partial; .*--set regime=custom"):
        Trainer(load_train_config(["fine_tune"], base + [start]), **QUIET)
    custom = Trainer(load_train_config(["fine_tune"], base + [start, "regime=custom", "name=custom"]), **QUIET)
    assert custom.counters.update == 0


def test_mappo_trains_with_a_centralised_normalised_critic(tmp_path):
    cfg = load_train_config(["mappo"], TINY + [f"run.runs_dir={tmp_path}", "total_steps=96"])
    trainer = Trainer(cfg, **QUIET)
    first_input = trainer.model.critic.body[0].in_features
    assert first_input == trainer.env.state_dim + trainer.env.obs_dim
    trainer.train()
    assert trainer.model.value_norm.count > 100
    data = load_checkpoint(cfg.run_dir / "last.pt")
    assert data["value_norm"]["count"] == pytest.approx(trainer.model.value_norm.count)
    rows = [json.loads(x) for x in (cfg.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert all(torch.isfinite(torch.tensor(r["loss"]["value_loss"])) for r in rows)


def test_learnable_discount_moves_and_is_logged(tmp_path):
    cfg = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "total_steps=160",
                                                 "ppo.learnable_gamma=true", "ppo.gamma_meta_lr=0.05"])
    Trainer(cfg, **QUIET).train()
    rows = [json.loads(x) for x in (cfg.run_dir / "metrics.jsonl").read_text().splitlines()]
    gammas = [r["gamma"] for r in rows]
    assert len(rows) == 5 and gammas[0] != gammas[-1]
    assert all(0.0 < g < 1.0 for g in gammas) and all("gamma_meta_grad" in r for r in rows)
    # a fixed discount stays put
    fixed = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "name=fixed", "total_steps=64"])
    Trainer(fixed, **QUIET).train()
    assert {json.loads(x)["gamma"] for x in (fixed.run_dir / "metrics.jsonl").read_text().splitlines()} == {0.99}


def test_the_learned_discount_is_held_while_the_critic_warms_up(tmp_path):
    """With ppo.critic_warmup the discount took its meta-step while the actor was held: it was
    judged by a policy step never taken, on the advantages of a critic still learning."""
    cfg = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "total_steps=160", "ppo.critic_warmup=3",
                                                 "ppo.learnable_gamma=true", "ppo.gamma_meta_lr=0.05"])
    Trainer(cfg, **QUIET).train()
    rows = [json.loads(x) for x in (cfg.run_dir / "metrics.jsonl").read_text().splitlines()]
    held = [r for r in rows if r["loss"]["critic_only"]]
    assert len(held) == 3 and len({r["gamma"] for r in held}) == 1 and held[0]["gamma"] == pytest.approx(0.99, abs=1e-6)
    assert {r["gamma_meta_grad"] for r in held} == {0.0}
    assert rows[-1]["gamma"] != held[0]["gamma"] and rows[-1]["gamma_meta_grad"] != 0.0


def test_a_run_started_from_a_learned_discount_says_it_starts_its_own(tmp_path):
    """init_from takes weights, not the discount the source learned: that went without a word."""
    learned = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "name=src", "ppo.learnable_gamma=true"])
    src = Trainer(learned, **QUIET)
    with torch.no_grad():
        src.discount.logit.fill_(5.0)  # gamma 0.9933
    src.save()
    src.close()
    lines = []
    start = [f"run.runs_dir={tmp_path}", f"init_from={tmp_path / 'src' / 'last.pt'}"]
    Trainer(load_train_config(["classic"], TINY + start + ["name=dst"]), log=lines.append).close()
    note = next(line for line in lines if line.startswith("initialised from"))
    assert "its learned discount 0.9933 is not carried over: gamma starts at ppo.gamma 0.99" in note


@pytest.mark.parametrize("gamma", ["1", "0", "0.99999"])
def test_a_learned_discount_that_cannot_start_at_ppo_gamma_is_refused_by_name(gamma):
    """It started silently at 0.9999 (or 0.0001) instead, where the sigmoid barely moves."""
    cfg = load_train_config(["classic"], [f"ppo.gamma={gamma}", "ppo.learnable_gamma=true"])
    with pytest.raises(ConfigError, match=rf"ppo.gamma {gamma} .*ppo.learnable_gamma"):
        cfg.check_complete()
    load_train_config(["classic"], [f"ppo.gamma={gamma}"]).check_complete()  # a fixed discount may be 0 or 1
    load_train_config(["classic"], ["ppo.gamma=0.9999", "ppo.learnable_gamma=true"]).check_complete()


def test_training_on_a_list_of_layouts_gives_each_world_its_layout(tmp_path):
    cfg = load_train_config([], TINY + [f"run.runs_dir={tmp_path}", "total_steps=32", "n_envs=4", "layouts=[0, 2]"])
    trainer = Trainer(cfg, **QUIET)
    names = [l.name for l in trainer.env.world_layouts]
    assert names[0] == names[2] != names[1] == names[3]


def test_unknown_preset_names_the_presets():
    with pytest.raises(ConfigError, match=r"clasic: no such file, nor a train preset of that name \(presets: .*classic, .*mappo"):
        load_train_config(["clasic"])
    with pytest.raises(ConfigError, match=r"--set task_file=hardd: task_file hardd: no such file, nor a task preset .*easy, hard, reference"):
        load_train_config([], ["task_file=hardd"])


def test_preset_name_wins_over_a_folder_of_the_same_name(tmp_path, monkeypatch):
    (tmp_path / "classic").mkdir()
    monkeypatch.chdir(tmp_path)
    assert load_train_config(["classic"]).regime == "classic"


@pytest.mark.parametrize("split", ["true", "false"])
def test_a_critic_warmup_holds_the_actor_while_a_fresh_critic_learns(tmp_path, split, monkeypatch):
    """From a policy-only export the critic starts fresh, and its first advantages are noise:
    ppo.critic_warmup updates train the critic alone, then both learn."""
    from train.checkpoint import export_actor

    import train.trainer as trainer_module

    if split == "true":
        monkeypatch.setattr(trainer_module, "usable_cores", lambda: 2)  # the split needs two cores
    base = TINY + [f"run.runs_dir={tmp_path}", "ppo.lr=3e-3", f"run.split_update={split}"]
    src = load_train_config(["classic"], base + ["name=src", "total_steps=32"])
    Trainer(src, **QUIET).train()
    start = export_actor(src.run_dir / "last.pt", tmp_path / "policy.pt")
    cfg = load_train_config(["classic"], base + ["name=warm", "total_steps=10000", f"init_from={start}", "ppo.critic_warmup=2"])
    said = []
    trainer = Trainer(cfg, log=said.append)
    assert any("policy-only export: the critic starts fresh (2 update(s) train it alone, ppo.critic_warmup)" in s for s in said)
    actor0 = {k: v.clone() for k, v in trainer.model.actor.state_dict().items()}
    critic0 = {k: v.clone() for k, v in trainer.model.critic.state_dict().items()}
    rows = [trainer.train_one_update() for _ in range(2)]
    assert (trainer.critic_worker is not None) == (split == "true")
    for k, v in actor0.items():
        assert torch.equal(trainer.model.actor.state_dict()[k], v), k  # held, log std included
    assert any(not torch.equal(trainer.model.critic.state_dict()[k], v) for k, v in critic0.items())
    assert all(row["loss"]["critic_only"] == 1.0 for row in rows)
    row = trainer.train_one_update()  # the third update: the actor learns again
    assert row["loss"]["critic_only"] == 0.0
    assert any(not torch.equal(trainer.model.actor.state_dict()[k], v) for k, v in actor0.items())
    trainer.close()
    with pytest.raises(ConfigError, match=r"ppo.critic_warmup.*-1"):
        load_train_config(["classic"], ["ppo.critic_warmup=-1"])
    assert load_train_config(["imitate"], ["ppo.critic_warmup=3"]).idle_settings()[0].startswith("ppo.critic_warmup does nothing")


@pytest.mark.parametrize("overlap", ["false", "true"])
def test_a_kickstarted_run_logs_the_teachers_error_and_weight(tmp_path, overlap):
    """ppo.teacher_coef: the heuristic team labels the rollout (in this process, or in the
    rollout worker's with run.overlap), the update pulls toward it with a weight that falls
    over ppo.teacher_updates, and the metrics log both; with ppo.teacher_from_step only the
    labels of steps that far into an episode count, and the log says what share that was."""
    cfg = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "name=kick", "total_steps=192",
                                                 "ppo.teacher_coef=2", "ppo.teacher_updates=2", f"run.overlap={overlap}",
                                                 "ppo.teacher_from_step=5"])
    Trainer(cfg, **QUIET).train()
    rows = [json.loads(line) for line in (cfg.run_dir / "metrics.jsonl").read_text().splitlines()]
    updates = [r for r in rows if "loss" in r]
    assert [r["loss"]["teacher_weight"] for r in updates[:3]] == [2.0, 1.0, 0.0]
    assert updates[0]["loss"]["teacher_mse"] > 0
    assert 0.5 < updates[0]["loss"]["teacher_coverage"] < 1  # 16 steps a rollout, the first 5 of an episode not taught
    assert "teacher_mse" not in updates[2]["loss"]  # weight 0: no teacher term


def test_a_run_in_turn_stops_labelling_once_the_teachers_weight_has_reached_0(tmp_path):
    """The team labels (one step of it per decision step) only the rollouts of updates whose
    teacher weight is above 0."""
    cfg = load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "name=kick1", "total_steps=96",
                                                 "ppo.teacher_coef=2", "ppo.teacher_updates=1", "run.overlap=false"])
    trainer = Trainer(cfg, **QUIET)
    teacher, calls = trainer.collector.teacher, []
    real = teacher.act
    teacher.act = lambda obs, spec: calls.append(1) or real(obs, spec)
    trainer.train()
    assert trainer.counters.update == 3
    assert len(calls) == cfg.rollout_steps()  # the first update's rollout only


def test_a_teacher_is_refused_under_a_residual_and_idle_under_dagger():
    with pytest.raises(ConfigError, match=r"ppo.teacher_coef 1 .*residual.base 'heuristic'"):
        load_train_config(["residual"], ["ppo.teacher_coef=1"]).check_complete()
    assert load_train_config(["imitate"], ["ppo.teacher_coef=1"]).idle_settings()[0].startswith("ppo.teacher_coef does nothing")
    with pytest.raises(ConfigError, match=r"ppo.teacher_coef.*-1"):
        load_train_config(["classic"], ["ppo.teacher_coef=-1"])
    assert load_train_config(["classic"], ["ppo.teacher_updates=5"]).idle_settings() == [
        "ppo.teacher_updates 5 does nothing without ppo.teacher_coef (it schedules the teacher's weight)"]
    assert load_train_config(["classic"], ["ppo.teacher_from_step=100"]).idle_settings() == [
        "ppo.teacher_from_step 100 does nothing without ppo.teacher_coef (it says where the teacher's labels count)"]
    assert load_train_config(["classic"], ["ppo.teacher_coef=1", "ppo.teacher_from_step=1000"]).idle_settings() == [
        "ppo.teacher_coef 1 does nothing with ppo.teacher_from_step 1000 and task.max_steps 1000 (no episode runs "
        "that long, so no label counts)"]


def test_the_learning_set_up_of_docs_design_md_section_6_is_the_train_defaults_and_regime_files():
    """Pins DESIGN.md section 6 to the code: the hyperparameters "for all" are PPOConfig's
    defaults and every shipped regime file's, the network's widths NetConfig's, and each regime
    line (gamma, clip, envs, speeds) its file's; the defaults themselves are classic's."""
    import re

    from train.config import NetConfig, PPOConfig, TrainConfig

    text = (Path(__file__).resolve().parents[1] / "docs" / "DESIGN.md").read_text()
    section = " ".join(text.split("\n## 6. ", 1)[1].split("\n## ", 1)[0].split())
    common = re.search(r"lr ([\d.e-]+), lambda ([\d.]+), (\d+) epochs, batch (\d+), minibatch (\d+) for all", section)
    lr, lam, epochs, batch, minibatch = float(common[1]), float(common[2]), int(common[3]), int(common[4]), int(common[5])
    ppo = PPOConfig()
    assert (ppo.lr, ppo.gae_lambda, ppo.epochs, ppo.batch_size, ppo.minibatch_size) == (lr, lam, epochs, batch, minibatch)
    assert ppo.max_grad_norm == float(re.search(r"grad-norm clip ([\d.]+)", section)[1])
    assert ppo.lr_decay and ppo.value_scaling and ppo.grad_clip == "joint"
    width = int(re.search(r"self: \d+ -> (\d+)\)", section)[1])
    fused = [int(w) for w in re.search(r"concatenated \(([\d -> ]+)\)", section)[1].split(" -> ")]
    net = NetConfig()
    assert net.kind == "reference" and net.encoder_width == width and fused == [3 * width, *net.hidden]
    # what ours builds instead, as the "(Ours: ...)" note under the section's hyperparameters says
    from pursuit_mj.config import default_config
    from pursuit_mj.env import PursuitEnv
    from train.networks import Actor

    ours = re.search(r"self (\d+) \(.*?a teammate (\d+) \(.*?an evader (\d+) \(.*?concatenates ([\d -> ]+) \(", section)
    assert ours, "docs/DESIGN.md section 6 lost its note on the network ours builds"
    trunk = Actor(PursuitEnv(default_config(fidelity="point")).obs_spec, net).trunk
    inputs = {name: enc.layer.in_features for name, enc in trunk.encoders.items()}
    assert [inputs["self"], inputs["teammates"], inputs["evaders"]] == [int(ours[i]) for i in (1, 2, 3)]
    assert set(inputs) == {"self", "teammates", "evaders", "rays"} and net.use_rays
    layers = [m for m in trunk.fuse if isinstance(m, torch.nn.Linear)]
    assert [layers[0].in_features, *(m.out_features for m in layers)] == [int(w) for w in ours[4].split(" -> ")]
    regimes = re.findall(r"- (\w+)(?: \(from (\w+) weights\))?: gamma ([\d.]+), clip ([\d.]+), (\d+) envs, speeds ([\d.]+)/([\d.]+)",
                         section)
    assert [r[0] for r in regimes] == ["classic", "full_obs", "fine_tune"]
    for name, start, gamma, clip, envs, pursuer, evader in regimes:
        cfg = load_train_config([f"configs/train/{name}.yaml"])
        assert cfg.regime == name and (cfg.ppo.lr, cfg.ppo.gae_lambda, cfg.ppo.epochs) == (lr, lam, epochs), name
        assert (cfg.ppo.batch_size, cfg.ppo.minibatch_size) == (batch, minibatch), name
        assert (cfg.ppo.gamma, cfg.ppo.clip, cfg.n_envs) == (float(gamma), float(clip), int(envs)), name
        assert (cfg.task.pursuer_speed, cfg.task.evader_speed) == (float(pursuer), float(evader)), name
        assert (start and start in (cfg.init_from or "")) or (not start and cfg.init_from is None), name
    classic = regimes[0]
    defaults = TrainConfig()
    assert (defaults.ppo.gamma, defaults.ppo.clip, defaults.n_envs) == (float(classic[2]), float(classic[3]), int(classic[4]))


@pytest.mark.parametrize("path", sorted(str(p) for p in Path("configs/train").glob("*.yaml")))
def test_the_validation_cadence_a_config_file_states_in_its_comments_is_the_one_it_sets(path):
    """Each shipped config says in a comment how often it validates ('every 40 updates (2280 steps
    per world)', 'every 2048 steps per world'); those numbers follow from run.validate_every,
    ppo.batch_size, n_envs and the team size, and change silently when one of them does."""
    import re

    text = " ".join(Path(path).read_text().split())
    cfg = load_train_config([path])
    per_world = cfg.rollout_steps() * cfg.run.validate_every
    updates = re.search(r"every (\d+) updates \((\d+) steps per world\)", text)
    steps = re.search(r"every (\d+) steps per world", text)
    assert updates or steps, f"{path} does not say how often it validates"
    if updates:
        assert (int(updates[1]), int(updates[2])) == (cfg.run.validate_every, per_world), path
    if steps:
        assert int(steps[1]) == per_world, path


def test_perception_keys_under_full_observability_are_named_as_idle():
    """`train --config full_obs --set task_file=hard` trained on exact observations, the preset's noise,
    misses, radius and view unread, without a word."""
    assert load_train_config(["full_obs"], []).idle_settings() == []
    assert load_train_config(["full_obs"], ["task.position_noise=0.1", "task.share_teammates=true"]).idle_settings() == [
        "task.share_teammates True, task.position_noise 0.1 do nothing under task.observability full (every evader "
        "and teammate is known exactly)"]


def test_a_run_started_from_a_checkpoint_of_another_task_names_the_keys_that_differ(tmp_path):
    """init_from said only how the observability differed ('trained with observability partial, now
    partial'): a checkpoint trained at another fidelity, evader speed, field of view or reward scale
    continued without a word of it. One note now lists the task keys that differ, checkpoint ->
    this run, as eval --model's note compares them (pursuit_cli.common.load_model)."""
    src = Trainer(load_train_config(["classic"], TINY + [f"run.runs_dir={tmp_path}", "name=src"]), **QUIET)
    src.save()
    src.close()
    start = [f"run.runs_dir={tmp_path}", f"init_from={tmp_path / 'src' / 'last.pt'}"]
    changed = ["task.fidelity=quadrotor", "task.evader_speed=0.9", "task.field_of_view=2.0943951",
               "task.capture_reward=5", "task.max_steps=60"]
    notes = {}
    for name, extra in (("same", []), ("other", changed)):
        lines = []
        Trainer(load_train_config(["classic"], TINY + start + [f"name={name}"] + extra), log=lines.append).close()
        notes[name] = next(line for line in lines if line.startswith("initialised from"))
    assert "task" not in notes["same"].split("now partial)")[1]
    assert ("note: its task differs from this run's (checkpoint -> this run): evader_speed 0.6 -> 0.9, field_of_view "
            "360 deg -> 120 deg, fidelity point -> quadrotor, max_steps 40 -> 60, capture_reward 10.0 -> 5.0") in notes["other"]


def test_net_settings_idle_under_a_network_of_ones_own_are_named_from_its_shape_keys(monkeypatch):
    """The note on idle net.* settings knew only net.kind mlp: a network added as docs/training.md
    says, whose SHAPE_KEYS leave out encoder_width, took --set net.encoder_width=64 without a word.
    The keys its trunk's weights do not depend on are named for any kind; a trunk without
    SHAPE_KEYS uses them all."""
    import dataclasses

    import train.networks as networks

    class NoEncoders(torch.nn.Module):
        SHAPE_KEYS = ("hidden", "use_rays")  # kind left out: no weight depends on it

    class Unsaid(torch.nn.Module):
        pass

    monkeypatch.setitem(networks.TRUNKS, "no_encoders", NoEncoders)
    monkeypatch.setitem(networks.TRUNKS, "unsaid", Unsaid)
    cfg = load_train_config(["classic"], ["net.encoder_width=64", "net.use_rays=false"])
    own = dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, kind="no_encoders"))
    assert own.idle_settings() == ["net.encoder_width does nothing under net.kind no_encoders (its trunk's weights "
                                   "do not depend on it: SHAPE_KEYS in train/networks.py)"]
    assert dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, kind="unsaid")).idle_settings() == []
    assert dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, kind="mlp")).idle_settings() == [
        "net.encoder_width, net.use_rays do nothing under net.kind mlp (the reference network's entity encoders)"]
