"""run.overlap: rollouts collected in a child process while the parent learns."""

import copy
import json

import pytest
import torch

import train.trainer as trainer_module
from conftest import train_killing_a_child_after_update_1
from train.config import load_train_config
from train.networks import gaussian_log_prob
from train.rollout_worker import RolloutWorker
from train.trainer import Trainer

TINY = [
    "task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=40",
    "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=2", "net.encoder_width=16", "net.hidden=[16]",
    "run.validate_every=0", "run.validation_episodes=2", "run.progress=false", "run.overlap=true",
]


def tiny(tmp_path, *extra):
    return load_train_config([], TINY + [f"run.runs_dir={tmp_path}", *extra])


def test_each_update_learns_from_the_rollout_of_the_weights_one_update_older(tmp_path, monkeypatch):
    """Update k (k >= 2) sees a rollout sampled with the weights after update k - 2: the
    weights the model had when update k - 1 began."""
    seen = []
    real = trainer_module.ppo_update

    def spy(model, optimizer, buf, *args, **kwargs):
        seen.append((copy.deepcopy(model.actor.state_dict()), buf.obs.clone(), buf.actions.clone(), buf.logp.clone()))
        return real(model, optimizer, buf, *args, **kwargs)

    monkeypatch.setattr(trainer_module, "ppo_update", spy)
    trainer = Trainer(tiny(tmp_path, "total_steps=128"), log=lambda s: None)
    assert trainer.overlap
    trainer.train()
    assert len(seen) == 4 and trainer.worker is None
    actor = copy.deepcopy(trainer.model.actor)
    for k in range(1, 4):
        behaviour = seen[k - 1][0] if k >= 2 else seen[0][0]  # updates 1 and 2 both learn from the initial weights
        actor.load_state_dict(behaviour)
        _, obs, actions, logp = seen[k]
        with torch.no_grad():
            mean, log_std = actor(obs, trainer.spec)
            expected = gaussian_log_prob(mean, log_std.exp(), actions).sum(-1)
        torch.testing.assert_close(logp, expected, rtol=1e-5, atol=1e-5)
        if k >= 2:  # and not with the weights the update itself starts from
            actor.load_state_dict(seen[k][0])
            with torch.no_grad():
                mean, log_std = actor(obs, trainer.spec)
            assert not torch.allclose(gaussian_log_prob(mean, log_std.exp(), actions).sum(-1), logp, atol=1e-5)


def test_an_overlapped_run_is_reproducible_and_logs_its_timing(tmp_path):
    runs = []
    for name in ("a", "b"):
        trainer = Trainer(tiny(tmp_path, f"name={name}", "total_steps=96"), log=lambda s: None)
        trainer.train()
        runs.append(trainer.model.actor.state_dict())
    for k in runs[0]:
        assert torch.equal(runs[0][k], runs[1][k]), k
    last = json.loads((tmp_path / "b" / "metrics.jsonl").read_text().splitlines()[-1])
    assert {"rollout_s", "wait_s", "update_s", "wall_s"} <= last.keys()
    assert last["rollout_s"] > 0 and last["wall_s"] >= last["update_s"]


def test_the_worker_stops_labelling_once_the_teachers_weight_has_reached_0(tmp_path):
    """With ppo.teacher_updates 1 only the first rollout feeds an update that uses the labels;
    the worker knows which update each rollout feeds, also in a resumed run."""
    cfg = tiny(tmp_path, "ppo.teacher_coef=1", "ppo.teacher_updates=1")
    T = cfg.rollout_steps()
    for start, expected in ((0, [T, 0, 0]), (1, [0, 0])):
        trainer = Trainer(cfg, log=lambda s: None)
        buf = trainer.buffer
        worker = RolloutWorker(cfg, start, buf.T, buf.W, buf.N, buf.obs.shape[-1], 0)
        try:
            assert [worker.result(trainer.model)[1].teacher_steps for _ in expected] == expected
        finally:
            worker.close()
            trainer.close()


def test_overlap_off_and_dagger_collect_in_turn(tmp_path):
    assert not Trainer(tiny(tmp_path, "run.overlap=false"), log=lambda s: None).overlap
    dagger = Trainer(tiny(tmp_path, "algo=dagger", "name=d"), log=lambda s: None)
    assert not dagger.overlap and dagger.collector is not None


def test_a_failing_worker_raises_its_traceback_in_the_parent(tmp_path):
    cfg = tiny(tmp_path)
    trainer = Trainer(cfg, log=lambda s: None)
    buf = trainer.buffer
    worker = RolloutWorker(cfg, 0, buf.T, buf.W, buf.N, buf.obs.shape[-1] + 1, 0)  # buffers one column too wide
    try:
        with pytest.raises(RuntimeError, match="(?s)rollout worker .* failed:.*Traceback.*expanded size"):
            worker.result(trainer.model)
    finally:
        worker.close()
    assert not worker.process.is_alive()


def test_a_worker_killed_mid_run_stops_the_run_in_one_line_saying_what_last_pt_keeps(tmp_path):
    """The out-of-memory killer (or kill -9) takes the worker after update 1: the run stops naming
    how it ended, the update last.pt keeps and the resume command (it said 'exited (code -9)
    before its first rollout; its error is printed above', in a traceback), and it resumes."""
    cfg = tiny(tmp_path, "total_steps=96")
    trainer = Trainer(cfg, log=lambda s: None)
    said = train_killing_a_child_after_update_1(trainer, lambda t: t.worker.process)
    assert said.startswith(f"rollout worker rollout-{cfg.name} was killed by SIGKILL (the system's out-of-memory killer, "
                           f"or kill -9) without finishing its rollout; "), said
    assert said.endswith(f"; last.pt keeps update 1; continue with: pursuit-mj train --resume {cfg.run_dir}"), said
    assert trainer.worker is None
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["counters"]["update"] == 3


def test_a_training_script_without_a_main_guard_trains_once(tmp_path):
    """The worker is spawned without re-running the parent's script (which would train again)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = tmp_path / "train_here.py"
    script.write_text(
        "from train.config import load_train_config\n"
        "from train.trainer import Trainer\n"
        f"cfg = load_train_config([], {TINY + [f'run.runs_dir={tmp_path}', 'name=script', 'total_steps=64']!r})\n"
        "print('training', flush=True)\n"
        "print(Trainer(cfg, log=print).train()['status'])\n"
    )
    repo = Path(__file__).resolve().parent.parent
    done = subprocess.run([sys.executable, str(script)], cwd=repo, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(repo)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["training", "done"]
    assert len((tmp_path / "script" / "metrics.jsonl").read_text().splitlines()) == 2


def test_a_worker_that_cannot_start_stops_the_run_in_one_line_naming_run_overlap(tmp_path):
    """Its rollout buffers go into shared memory, which a full /dev/shm (a container's 64 MB
    default) or the open-file limit refuses: torch's RuntimeError ended the run in a traceback
    naming neither run.overlap nor what the run folder keeps."""
    import os
    import resource

    cfg = tiny(tmp_path, "total_steps=96")
    trainer = Trainer(cfg, log=lambda s: None)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    # room for config.yaml's write, not for the worker's buffers (one shared-memory file per tensor)
    resource.setrlimit(resource.RLIMIT_NOFILE, (len(os.listdir("/proc/self/fd")) + 6, hard))
    try:
        with pytest.raises(ValueError) as caught:
            trainer.train()
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    said = str(caught.value)
    assert said.startswith(f"run.overlap: the rollout worker rollout-{cfg.name} could not start ("), said
    assert "Too many open files" in said and "--set run.overlap=false" in said and "\n" not in said, said
    assert said.endswith("no checkpoint was written yet: start the run again once the worker can start"), said
    assert trainer.worker is None and not (cfg.run_dir / "last.pt").exists()


def test_a_worker_that_fails_before_reading_its_first_request_raises_its_error_not_a_silent_exit(tmp_path):
    """A child that fails while it builds its networks sends its traceback and exits with code 0,
    without reading the request the parent is sending. Weights larger than the pipe holds (the
    default widths) left the parent's send broken, and the run stopped with 'rollout worker ...
    exited (code 0) between two rollouts', the child's error lost. Here the child cannot build a
    net.kind that only the parent knows (one registered in train/networks.py TRUNKS from a script)."""
    import dataclasses

    cfg = load_train_config([], TINY[:8] + TINY[10:] + [f"run.runs_dir={tmp_path}", "net.hidden=[512, 512]"])
    trainer = Trainer(cfg, log=lambda s: None)
    buf = trainer.buffer
    only_here = dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, kind="only_in_the_parent"))
    worker = RolloutWorker(only_here, 0, buf.T, buf.W, buf.N, buf.obs.shape[-1], 0)
    try:
        with pytest.raises(RuntimeError, match="(?s)rollout worker .* failed:.*net.kind 'only_in_the_parent'"):
            worker.result(trainer.model)
    finally:
        worker.close()
        trainer.close()
    assert not worker.process.is_alive()
