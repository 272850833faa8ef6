"""run.split_update: the critic learns in a child process while the actor learns in the trainer."""

import copy

import pytest
import torch

import train.trainer as trainer_module
from conftest import train_killing_a_child_after_update_1
from train.config import load_train_config
from train.critic_worker import CriticWorker
from train.ppo import ppo_update
from train.trainer import Trainer

TINY = [
    "task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=40",
    "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=24", "ppo.epochs=2", "net.encoder_width=16", "net.hidden=[16]",
    "run.validate_every=0", "run.validation_episodes=2", "run.progress=false",
]


def tiny(tmp_path, *extra):
    return load_train_config([], TINY + [f"run.runs_dir={tmp_path}", *extra])


@pytest.fixture
def two_cores(monkeypatch):
    """The split needs two usable cores; CI's machine has them, a pinned test run may not."""
    monkeypatch.setattr(trainer_module, "usable_cores", lambda: 2)


@pytest.mark.parametrize("algo", ["ppo", "mappo"])
def test_a_split_update_gives_the_weights_and_losses_of_the_update_in_one_process(tmp_path, algo):
    """Same rollout, same minibatches: the actor here and the critic in the child end where one
    process would, the shared gradient clipping included (max_grad_norm small enough to clip)."""
    cfg = tiny(tmp_path, f"algo={algo}", "run.split_update=false", "ppo.max_grad_norm=0.05")
    trainer = Trainer(cfg, log=lambda s: None)
    buf, _ = trainer._next_rollout()
    runs = []
    for split in (False, True):
        model, optimizer = copy.deepcopy(trainer.model), None
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-5, fused=True)
        generator = torch.Generator().manual_seed(3)
        worker = CriticWorker(model, cfg, buf.n_transitions, threads=1) if split else None
        try:
            stats = ppo_update(model, optimizer, buf, cfg.ppo, 0.99, generator, critic_worker=worker)
            stats2 = ppo_update(model, optimizer, buf, cfg.ppo, 0.99, generator, critic_worker=worker)  # Adam state carries on
        finally:
            if worker is not None:
                worker.close()
        runs.append((model.state_dict(), stats, stats2, optimizer.state_dict()))
    (alone, s1, s2, opt_alone), (split, t1, t2, opt_split) = runs
    start = trainer.model.state_dict()
    for key in alone:
        torch.testing.assert_close(split[key], alone[key], rtol=1e-5, atol=1e-6, msg=key)
    for key in ("actor.head.weight", "actor.log_std", "critic.head.weight", "critic.head.bias"):
        assert not torch.equal(alone[key], start[key]), f"{key} did not move: the test would not see a difference"
    for a, b in ((s1, t1), (s2, t2)):
        assert a.keys() == b.keys()
        for k in a:
            assert b[k] == pytest.approx(a[k], rel=1e-4, abs=1e-6), k
    assert s1["grad_norm"] > cfg.ppo.max_grad_norm  # the clipping joined both halves' gradients
    for pid, state in opt_alone["state"].items():
        torch.testing.assert_close(opt_split["state"][pid]["exp_avg_sq"], state["exp_avg_sq"], rtol=1e-4, atol=1e-9)


def test_a_split_dagger_update_gives_the_weights_of_the_update_in_one_process(tmp_path):
    from train.imitation import imitation_update

    cfg = tiny(tmp_path, "algo=dagger", "run.split_update=false", "imitation.max_grad_norm=0.05")
    trainer = Trainer(cfg, log=lambda s: None)
    buf, _ = trainer._next_rollout()
    runs = []
    for split in (False, True):
        model = copy.deepcopy(trainer.model)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-5, fused=True)
        worker = CriticWorker(model, cfg, buf.n_transitions, threads=1) if split else None
        try:
            stats = imitation_update(model, optimizer, trainer.demos, buf, cfg.imitation, cfg.ppo, 0.99,
                                     torch.Generator().manual_seed(5), critic_worker=worker)
        finally:
            if worker is not None:
                worker.close()
        runs.append((model.state_dict(), stats))
    (alone, s1), (split, t1) = runs
    for key in alone:
        torch.testing.assert_close(split[key], alone[key], rtol=1e-5, atol=1e-6, msg=key)
    assert not torch.equal(alone["critic.head.weight"], trainer.model.state_dict()["critic.head.weight"])
    assert s1.keys() == t1.keys() and all(t1[k] == pytest.approx(s1[k], rel=1e-4, abs=1e-6) for k in s1)
    assert s1["grad_norm"] > cfg.imitation.max_grad_norm


def test_the_trainer_splits_the_update_in_turn_on_two_cores_and_not_otherwise(tmp_path, monkeypatch):
    cases = ((2, [], True), (1, [], False), (2, ["run.split_update=false"], False), (2, ["run.overlap=true"], False),
             (2, ["algo=dagger"], True), (2, ["algo=mappo"], True))
    for i, (cores, extra, expected) in enumerate(cases):
        monkeypatch.setattr(trainer_module, "usable_cores", lambda: cores)
        trainer = Trainer(tiny(tmp_path, f"name=r{i}", *extra), log=lambda s: None)
        assert trainer.split_update is expected, (cores, extra)
        if expected:  # a core each: the actor's update here, the critic's in the child
            assert trainer.update_threads == 1
        trainer.close()


def test_a_split_run_learns_what_a_run_in_one_process_learns_and_leaves_no_process(tmp_path, two_cores):
    weights = []
    for split in ("true", "false"):
        trainer = Trainer(tiny(tmp_path, f"name=s{split}", "total_steps=96", f"run.split_update={split}"), log=lambda s: None)
        trainer.train()
        weights.append(trainer.model.state_dict())
        assert trainer.critic_worker is None
    for key in weights[0]:
        torch.testing.assert_close(weights[0][key], weights[1][key], rtol=1e-4, atol=1e-5, msg=key)


def test_the_critic_process_starts_with_the_first_rollout_and_ends_with_the_run(tmp_path, two_cores):
    trainer = Trainer(tiny(tmp_path, "total_steps=96"), log=lambda s: None)
    assert trainer.critic_worker is None  # nothing started before training does
    trainer.train_one_update()
    worker = trainer.critic_worker
    assert worker is not None and worker.process.is_alive()
    trainer.close()
    assert trainer.critic_worker is None and not worker.process.is_alive()


def test_a_killed_critic_process_stops_the_run_in_one_line_saying_what_last_pt_keeps(tmp_path, two_cores):
    cfg = tiny(tmp_path, "total_steps=96")
    trainer = Trainer(cfg, log=lambda s: None)
    said = train_killing_a_child_after_update_1(trainer, lambda t: t.critic_worker.process)
    assert said.startswith(f"critic process critic-{cfg.name} was killed by SIGKILL (the system's out-of-memory killer, "
                           "or kill -9) during an update; "), said
    assert said.endswith(f"; last.pt keeps update 1; continue with: pursuit-mj train --resume {cfg.run_dir}"), said
    assert trainer.critic_worker is None
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["counters"]["update"] == 3


def test_a_failing_critic_process_raises_its_traceback_in_the_parent(tmp_path):
    cfg = tiny(tmp_path, "run.split_update=false")
    trainer = Trainer(cfg, log=lambda s: None)
    buf, _ = trainer._next_rollout()
    wide = tiny(tmp_path, "name=wide", "net.encoder_width=8")
    worker = CriticWorker(trainer.model, wide, buf.n_transitions, threads=1)  # the child builds a critic of other shapes
    try:
        with pytest.raises(RuntimeError, match="(?s)critic process critic-wide failed:.*Traceback.*shapes"):
            ppo_update(trainer.model, trainer.optimizer, buf, cfg.ppo, 0.99, torch.Generator(), critic_worker=worker)
    finally:
        worker.close()
    assert not worker.process.is_alive()


def test_a_critic_process_that_cannot_start_leaves_the_update_in_one_process_with_a_note(tmp_path, two_cores, monkeypatch):
    """No room in /dev/shm (a container's 64 MB default, filled by something else) must not stop
    training: the run says why and learns as it did before the split existed."""
    def no_shared_memory(*args, **kwargs):
        raise RuntimeError("unable to open shared memory object </torch_1_2> in read-write mode: No space left on device (28)")

    monkeypatch.setattr(trainer_module, "CriticWorker", no_shared_memory)
    said = []
    trainer = Trainer(tiny(tmp_path, "total_steps=64"), log=said.append)
    assert trainer.train()["status"] == "done"
    assert not trainer.split_update and trainer.update_threads == 2
    notes = [s for s in said if "critic process could not start" in s]
    assert len(notes) == 1 and "No space left on device" in notes[0] and "--set run.split_update=false" in notes[0], said


def test_a_child_ignores_ctrl_c_from_its_first_instant_while_it_still_imports_torch(capfd):
    """Ctrl-C reaches the whole process group. In the first seconds of a run a child was still
    importing torch, before it could ignore the signal, and printed a KeyboardInterrupt
    traceback over the parent's tidy 'interrupted' message."""
    import os
    import signal
    import time

    from train.child_process import spawn
    from train.critic_worker import _wait_for_close

    process, conn = spawn(_wait_for_close, (), "ctrl-c probe")
    end = time.monotonic() + 3.0  # covers the child's start and its import of torch
    while time.monotonic() < end and process.is_alive():
        os.kill(process.pid, signal.SIGINT)
        time.sleep(0.02)
    assert process.is_alive()
    conn.send(("stop",))
    process.join(10)
    assert process.exitcode == 0
    assert "KeyboardInterrupt" not in capfd.readouterr().err


class _ScriptTrunk(torch.nn.Module):
    """A trunk a script adds to train/networks.py TRUNKS (not the module's own): obs -> 4 features."""

    def __init__(self, spec, cfg):
        super().__init__()
        self.layer = torch.nn.Linear(spec.dim, 4)
        self.out_dim = 4

    def forward(self, obs, spec):
        return torch.tanh(self.layer(obs))


@pytest.mark.parametrize("child", ["run.split_update=true", "run.overlap=true"])
def test_a_net_kind_registered_from_a_script_is_refused_before_a_child_process_would_need_it(tmp_path, two_cores,
                                                                                            monkeypatch, child):
    """docs/training.md says to register a network in train/networks.py, not from a script, because
    the critic process and the rollout worker are spawned and build the networks afresh. A script
    that did so trained its first rollout, then stopped in the child's traceback ('no such network
    ... known: reference, mlp', the kind the script had just registered), or with run.overlap in
    'rollout worker ... exited (code 0) between two rollouts'. It is refused at once, in one line
    naming the kind, the setting that spawns and the way out; in one process the kind trains."""
    import dataclasses

    import train.networks as networks

    monkeypatch.setitem(networks.TRUNKS, "script_made", _ScriptTrunk)
    cfg = tiny(tmp_path, child, "total_steps=64")
    cfg = dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, kind="script_made"))
    key = child.split("=")[0]
    with pytest.raises(ValueError) as caught:
        Trainer(cfg, log=lambda s: None)
    said = str(caught.value)
    assert "net.kind 'script_made'" in said and key in said and "train/networks.py" in said and "\n" not in said, said
    assert "--set run.split_update=false" in said, said
    assert not cfg.run_dir.exists()
    alone = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, split_update=False, overlap=False))
    assert Trainer(alone, log=lambda s: None).train()["status"] == "done"
