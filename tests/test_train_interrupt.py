"""A real training process killed with kill -9, Ctrl-C (SIGINT) or SIGTERM loses at most one update."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

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
    """Also with a rollout worker (run.overlap), which must not outlive its trainer; SIGTERM
    (kill, a batch scheduler's stop) is handled as Ctrl-C."""
    args = [sys.executable, "-c", "import sys; from pursuit_cli import main; sys.exit(main())", "train", "--no-progress", "--total-steps", "100000"]
    for s in TINY + [f"run.runs_dir={tmp_path}", "name=killed", f"run.overlap={str(overlap).lower()}"]:
        args += ["--set", s]
    env = dict(os.environ, MUJOCO_GL="egl")
    # a shell that starts the suite in the background makes it ignore SIGINT, and children inherit
    # that: give the trainer the default disposition, as a terminal's Ctrl-C would find it
    proc = subprocess.Popen(args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    log = tmp_path / "killed" / "metrics.jsonl"
    deadline = time.time() + 25
    while time.time() < deadline and proc.poll() is None and (not log.exists() or len(log.read_text().splitlines()) < 3):
        time.sleep(0.05)
    workers = children(proc.pid)  # the rollout worker
    assert bool(workers) == overlap, workers
    os.kill(proc.pid, sig)
    code = proc.wait(timeout=30)
    deadline = time.time() + 15
    while time.time() < deadline and any(alive(pid) for pid in workers):
        time.sleep(0.05)
    assert not any(alive(pid) for pid in workers), "the rollout worker outlived its trainer"
    out, err = proc.stdout.read().decode(), proc.stderr.read().decode()
    assert log.exists(), err
    if sig in (signal.SIGINT, signal.SIGTERM):
        assert code == 130 and "interrupted" in out and "--resume" in out and "Traceback" not in err, err
    logged = len(log.read_text().splitlines())
    saved = load_checkpoint(tmp_path / "killed" / "last.pt")["counters"]["update"]
    assert logged - 1 <= saved <= logged + 1
    resumed = Trainer.resume(tmp_path / "killed", total_steps=32 * (saved + 1), log=lambda s: None)
    assert resumed.counters.update == saved
    assert resumed.train()["counters"]["update"] == saved + 1
    assert [r["update"] for r in rows(tmp_path / "killed")] == list(range(1, saved + 2))
