"""A real training process killed with kill -9, Ctrl-C (SIGINT) or SIGTERM loses at most one update."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import stop_signals_at_their_defaults
from train.checkpoint import load_checkpoint
from train.trainer import Trainer

REPO = Path(__file__).resolve().parent.parent
TINY = [
    "task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=40",
    "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=2",
    "run.validate_every=0", "run.validation_episodes=2", "run.progress=false",
]


def children(pid: int) -> list[int]:
    """Live processes whose parent is `pid` (Linux /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(entry.name))
            except (OSError, IndexError, ValueError):
                pass
    return out


def alive(pid: int) -> bool:
    """True while `pid` exists and is not a zombie."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def rows(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("sig, overlap", [(signal.SIGKILL, False), (signal.SIGKILL, True), (signal.SIGINT, False),
                                          (signal.SIGINT, True), (signal.SIGTERM, False)])
def test_kill_9_ctrl_c_or_sigterm_loses_at_most_one_update(tmp_path, sig, overlap):
    """Also with a rollout worker (run.overlap) or the critic's process (run.split_update, in
    turn), neither of which may outlive its trainer; SIGTERM
    (kill, a batch scheduler's stop) is handled as Ctrl-C."""
    args = [sys.executable, "-c", "import sys; from pursuit_cli import main; sys.exit(main())", "train", "--no-progress", "--total-steps", "100000"]
    for s in TINY + [f"run.runs_dir={tmp_path}", "name=killed", f"run.overlap={str(overlap).lower()}"]:
        args += ["--set", s]
    env = dict(os.environ, MUJOCO_GL="egl")
    # the machine's cores, not this xdist worker's one (conftest pins it): in turn on 2+ cores the
    # critic learns in a child process, which must not outlive its trainer either
    cores = os.sched_getaffinity(os.getppid())
    # a shell that starts the suite in the background makes it ignore SIGINT (nohup: SIGHUP), and
    # children inherit that: give the trainer the defaults, as a terminal's Ctrl-C would find them
    proc = subprocess.Popen(args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=lambda: (stop_signals_at_their_defaults(), os.sched_setaffinity(0, cores)))
    log = tmp_path / "killed" / "metrics.jsonl"
    deadline = time.time() + 120  # the loop ends at the third row; the margin is for a machine under load
    while time.time() < deadline and proc.poll() is None and (not log.exists() or len(log.read_text().splitlines()) < 3):
        time.sleep(0.05)
    assert log.exists(), (proc.stderr.read().decode() if proc.poll() is not None
                          else "no update logged in 120 s: the kill would test nothing")
    workers = children(proc.pid)  # the rollout worker, or in turn on 2+ cores the critic's (run.split_update)
    assert bool(workers) == (overlap or len(cores) >= 2), workers
    os.kill(proc.pid, sig)
    code = proc.wait(timeout=90)
    deadline = time.time() + 15
    while time.time() < deadline and any(alive(pid) for pid in workers):
        time.sleep(0.05)
    assert not any(alive(pid) for pid in workers), "the child process outlived its trainer"
    out, err = proc.stdout.read().decode(), proc.stderr.read().decode()
    assert log.exists(), err
    if sig in (signal.SIGINT, signal.SIGTERM):
        assert code == 128 + sig and "interrupted" in out and "--resume" in out and "Traceback" not in err, err
    logged = len(log.read_text().splitlines())
    saved = load_checkpoint(tmp_path / "killed" / "last.pt")["counters"]["update"]
    assert logged - 1 <= saved <= logged + 1
    resumed = Trainer.resume(tmp_path / "killed", total_steps=32 * (saved + 1), log=lambda s: None)
    assert resumed.counters.update == saved
    assert resumed.train()["counters"]["update"] == saved + 1
    assert [r["update"] for r in rows(tmp_path / "killed")] == list(range(1, saved + 2))


def test_a_sigterm_that_mujoco_reports_as_a_type_error_still_saves_and_says_how_to_resume(tmp_path, monkeypatch, capsys):
    """mujoco's bindings report a signal that lands while they convert an argument as their own
    TypeError; training used to end on that traceback, without its last update saved or the
    resume command printed."""
    import mujoco

    from pursuit_cli import main
    from pursuit_mj.env import PursuitEnv

    class SigtermWhileConverted:  # the signal arrives while the binding reads this sequence
        def __len__(self):
            return 2

        def __getitem__(self, i):
            if i == 0:
                os.kill(os.getpid(), signal.SIGTERM)
            if i >= 2:
                raise IndexError(i)
            return 1.0

    steps = {"n": 0}
    step = PursuitEnv.step

    def step_then_stopped(self, actions):
        steps["n"] += 1
        if steps["n"] == 30:  # in the second update's rollout (16 steps of 2 worlds x 2 pursuers each)
            mujoco.MjSpec().add_material().texrepeat = SigtermWhileConverted()
        return step(self, actions)

    monkeypatch.setattr(PursuitEnv, "step", step_then_stopped)
    sets = [a for kv in TINY + [f"run.runs_dir={tmp_path}", "name=typed"] for a in ("--set", kv)]
    assert main(["train", "--config", "classic", *sets, "--total-steps", "100000"]) == 143  # 128 + SIGTERM
    out = capsys.readouterr()
    assert f"interrupted: state of update 1 is in {tmp_path / 'typed' / 'last.pt'}" in out.out + out.err
    assert f"pursuit-mj train --resume {tmp_path / 'typed'}" in out.out + out.err
    assert load_checkpoint(tmp_path / "typed" / "last.pt")["counters"]["update"] == 1
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handlers given back


_TRAIN_STOPPED_IN_GENERATED_CODE = """
import sys
from train.config import load_train_config
from train.trainer import Trainer

cfg = load_train_config([], overrides=sys.argv[2:] + [f"run.runs_dir={sys.argv[1]}", "name=stopped"])
trainer = Trainer(cfg)
trainer.train_one_update = lambda: exec("raise KeyboardInterrupt")  # a Ctrl-C inside code made by exec
print(trainer.train()["status"])
"""


def test_a_script_whose_training_was_interrupted_ends_normally_not_by_sigint(tmp_path):
    """Trainer.train handles a Ctrl-C (it returns 'interrupted'); one that left code run by exec()
    still ended the script by SIGINT once it finished (CPython keeps such an interrupt marked
    unhandled), so the script's caller saw -2 instead of 0."""
    out = subprocess.run([sys.executable, "-c", _TRAIN_STOPPED_IN_GENERATED_CODE, str(tmp_path), *TINY], cwd=REPO,
                         capture_output=True, text=True, timeout=120, env=dict(os.environ, MUJOCO_GL="egl"),
                         preexec_fn=stop_signals_at_their_defaults)
    assert (out.returncode, out.stdout.splitlines()[-1:]) == (0, ["interrupted"]), out.stderr[-2000:]
