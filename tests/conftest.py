"""Shared fixtures: layouts and physics set-ups used by several test files."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

if "MUJOCO_GL" not in os.environ:  # before mujoco is imported: the backend the renderer would pick (EGL, else OSMesa)
    from pursuit_mj.render.gl import RenderBackendError, choose_backend

    try:
        os.environ["MUJOCO_GL"] = choose_backend()
    except RenderBackendError:  # none works: the render tests say why
        os.environ["MUJOCO_GL"] = "egl"

from pursuit_mj.config import default_config  # noqa: E402
from pursuit_mj.layout import Layout, layout_from_dict  # noqa: E402
from pursuit_mj.physics import BatchedPhysics  # noqa: E402


def open_layout(width: float = 20.0, height: float = 20.0, obstacles: list | None = None, name: str = "open_test") -> Layout:
    """A large empty arena, so that test flights never meet a wall unless they mean to."""
    return layout_from_dict(
        {
            "name": name,
            "arena": {"width": width, "height": height},
            "obstacles": obstacles or [],
            "random_obstacles": {"count": 0},
            "spawn": {"pursuers": {"x": [0.5, width - 0.5], "y": [0.5, 1.5]}, "evaders": {"x": [0.5, width - 0.5], "y": [height - 1.5, height - 0.5]}},
        },
        f"<{name}>",
    )


#: start positions (4, 2) m of the default 3 pursuers + 1 evader, far from each other and from walls
SPREAD_XY = np.array([[5.0, 5.0], [15.0, 5.0], [5.0, 15.0], [15.0, 15.0]])


def make_physics(fidelity: str = "quadrotor", n_worlds: int = 1, layout: Layout | None = None, xy: np.ndarray | None = None, **changes) -> BatchedPhysics:
    """BatchedPhysics of the default task (with `changes`), drones at `xy` (default SPREAD_XY) in every world."""
    config = default_config(fidelity=fidelity, **changes)
    physics = BatchedPhysics(config, [layout or open_layout()] * n_worlds, nthread=1)
    start = SPREAD_XY if xy is None else np.asarray(xy, dtype=float)
    physics.reset(np.arange(n_worlds), np.broadcast_to(start, (n_worlds,) + start.shape).copy())
    return physics


@pytest.fixture(scope="session")
def big_open_layout() -> Layout:
    return open_layout()


def nearest_allowed_on_a_grid(want: np.ndarray, dirs: np.ndarray, caps: np.ndarray, step: float = 0.001) -> float:
    """Distance (m/s) from `want` to the nearest velocity on a 1 mm/s grid within every limit."""
    axis = np.arange(-0.4, 0.4 + step / 2, step)
    grid = np.stack(np.meshgrid(axis, axis), -1).reshape(-1, 2)
    ok = np.all(grid @ dirs.T <= caps, axis=1)
    return float(np.min(np.linalg.norm(grid[ok] - want, axis=1)))


@pytest.fixture
def make_unwritable():
    """make_unwritable(path): no file can be created in the folder `path` (or appended to the
    file `path`) until the test ends. Tried in turn: permission bits (enough unless root), then
    the immutable attribute (chattr +i, which binds root too, on file systems that have it);
    the test is skipped where neither holds."""
    import shutil
    import stat
    import subprocess

    undo = []

    def writable(path: Path) -> bool:
        try:
            if path.is_dir():
                (path / ".probe").touch()
                (path / ".probe").unlink()
            else:
                with open(path, "a"):
                    pass
            return True
        except OSError:
            return False

    def make(path):
        path = Path(path)
        mode = path.stat().st_mode
        path.chmod(mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
        undo.append(lambda: path.chmod(mode))
        if writable(path) and shutil.which("chattr"):
            if subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode == 0:
                undo.append(lambda: subprocess.run(["chattr", "-i", str(path)], capture_output=True))
        if writable(path):
            pytest.skip(f"cannot make {path} unwritable here (root without chattr +i)")

    yield make
    for step in reversed(undo):
        step()


def _pin_xdist_worker_to_one_core() -> None:
    """Under `pytest -n N` worker k runs on core k mod cores (scripts/test.sh starts up to two per
    core): torch's OpenMP threads spin while they wait, and two workers each spinning on every core
    slowed the training tests about threefold."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if not worker.startswith("gw") or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cores[int(worker[2:]) % len(cores)]})


_pin_xdist_worker_to_one_core()


_STOP_SIGNALS = [s for s in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGTSTP") if hasattr(signal, s)]


@pytest.fixture(autouse=True)
def _signal_handlers_given_back():
    """Every test leaves the stop signals' handlers as it found them: a handler left behind
    changes how the later tests of the same worker see Ctrl-C and kill (the CLI takes only
    signals still at their defaults), so they pass or fail by test order. Fails the test that
    left one, naming the signal."""
    before = {name: signal.getsignal(getattr(signal, name)) for name in _STOP_SIGNALS}
    yield
    after = {name: signal.getsignal(getattr(signal, name)) for name in _STOP_SIGNALS}
    changed = {name: (before[name], after[name]) for name in before if after[name] != before[name]}
    for name, (handler, _) in changed.items():
        signal.signal(getattr(signal, name), handler)  # the next test starts clean either way
    assert not changed, f"this test left signal handlers changed (before, after): {changed}"


def stop_signals_at_their_defaults() -> None:
    """preexec_fn for a CLI subprocess a test stops with a signal: SIGINT, SIGTERM and SIGHUP at
    their defaults, as a terminal starts a command. Under `nohup` or `&` the suite inherits
    SIGHUP or SIGINT ignored, and the CLI rightly leaves an ignored signal alone."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


@pytest.fixture
def ctrl_c_as_in_a_terminal():
    """SIGINT handled by Python's default_int_handler during the test, as at a terminal: a suite
    started in the background (`bash scripts/test.sh &`, nohup) inherits SIGINT ignored, and
    the CLI rightly leaves an ignored signal alone."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def train_killing_a_child_after_update_1(trainer, child) -> str:
    """Run trainer.train(), kill -9 the process `child(trainer)` names right after update 1,
    and return what the ValueError that stopped the run said (as the out-of-memory killer
    would take a trainer's child process)."""
    update = trainer.train_one_update

    def update_then_kill():
        row = update()
        if row["update"] == 1:
            process = child(trainer)
            os.kill(process.pid, signal.SIGKILL)
            process.join(5)
        return row

    trainer.train_one_update = update_then_kill
    with pytest.raises(ValueError) as caught:
        trainer.train()
    return str(caught.value)


def weights_go_nan_at_update(monkeypatch, update: int) -> None:
    """Make the trainer's PPO update leave the actor's log-std NaN at its `update`-th call (1-based):
    a training run that diverges there, as a too-large learning rate can make it."""
    import torch

    import train.trainer as trainer_module

    real, calls = trainer_module.ppo_update, []

    def nan_at_the_chosen_one(model, *args, **kwargs):
        losses = real(model, *args, **kwargs)
        calls.append(1)
        if len(calls) == update:
            with torch.no_grad():
                model.actor.log_std.fill_(float("nan"))
        return losses

    monkeypatch.setattr(trainer_module, "ppo_update", nan_at_the_chosen_one)
