"""`pursuit-mj bench render`: how fast episodes become video, and what a rerun recording costs.

Three timed phases over the same 1000 decision steps of the heuristic team (episodes are
restarted until the step count is reached, as in a long render):
1. simulation: the environment and policy alone;
2. video: every state drawn (scene, overlays, caption) and encoded to mp4 at 640x480;
3. rerun: each state's snapshot plus sending the episodes to an .rrd file.
Targets (issue 5): video >= 20 frames per second; rerun < 20 % of the simulation time.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from pursuit_mj.config import TaskConfig, default_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.policies import make_policy
from ..common import seed_arg
from . import against_aim

HELP = "video frames per second of a render (default 1000 steps at 640x480: --steps, --width, --height), and the cost of a rerun recording"
TARGET_FPS = 20.0
TARGET_RERUN_FRACTION = 0.20


@dataclasses.dataclass
class RenderBenchResult:
    """Times in s; frames = states drawn (every step plus each episode's start); rates per second."""

    fidelity: str
    steps: int
    frames: int
    episodes: int
    width: int
    height: int
    sim_s: float
    snapshot_s: float
    render_s: float
    encode_s: float
    rerun_send_s: float
    layout: str = "0"  # of the default task, which the benchmark plays

    @property
    def video_fps(self) -> float:
        return self.frames / (self.render_s + self.encode_s)

    @property
    def rerun_s(self) -> float:
        return self.snapshot_s + self.rerun_send_s

    @property
    def rerun_fraction(self) -> float:
        return self.rerun_s / self.sim_s

    def lines(self) -> list[str]:
        ok = lambda good: "met" if good else "NOT met"  # noqa: E731
        return [
            f"render bench, {self.fidelity} fidelity, layout {self.layout} of the default task: {self.steps} decision steps in {self.episodes} episode{'' if self.episodes == 1 else 's'} of the heuristic team, "
            f"{self.frames} frames at {self.width}x{self.height}",
            f"  simulation (env + policy)         {self.sim_s:7.2f} s   {self.steps / self.sim_s:7.1f} steps/s",
            f"  video: draw {self.render_s:6.2f} s + encode {self.encode_s:5.2f} s   {against_aim(self.video_fps, TARGET_FPS, 1):>7} frames/s   target >= {TARGET_FPS:.0f}: {ok(self.video_fps >= TARGET_FPS)}",
            f"  end to end (simulate, draw, encode): {self.frames / (self.sim_s + self.render_s + self.encode_s):5.1f} frames/s",
            f"  rerun: snapshots {self.snapshot_s:5.2f} s + send {self.rerun_send_s:5.2f} s = {self.rerun_s:5.2f} s   "
            f"{against_aim(100 * self.rerun_fraction, 100 * TARGET_RERUN_FRACTION, 1):>5} % of simulation   target < {100 * TARGET_RERUN_FRACTION:.0f} %: {ok(self.rerun_fraction < TARGET_RERUN_FRACTION)}",
        ]


MAX_STEPS = 100_000  # decision steps to play at most (some 3 hours of rendering)


def _simulate(config: TaskConfig, steps: int, seed: int):
    """Play `steps` decision steps, restarting finished episodes.

    Returns (env, [(snapshots, EpisodeRecord or None if unfinished)], simulation seconds,
    snapshot seconds); the snapshot time is the per-step cost a recorder adds.
    """
    env = PursuitEnv(config, n_worlds=1, seed=seed, auto_reset=False)
    policy = make_policy("heuristic", config, seed)
    snap_t = 0.0

    def snapshot():
        nonlocal snap_t
        t0 = time.perf_counter()
        s = env.snapshot(0)
        snap_t += time.perf_counter() - t0
        return s

    start = time.perf_counter()
    obs = env.reset()
    policy.reset(1)
    episodes = [([snapshot()], None)]
    for _ in range(steps):
        if env.done[0]:
            obs = env.reset_worlds([0])
            policy.reset(1, np.array([0]))
            episodes.append(([snapshot()], None))
        obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
        episodes[-1][0].append(snapshot())
        if info["episodes"]:
            episodes[-1] = (episodes[-1][0], info["episodes"][0])
    sim = time.perf_counter() - start - snap_t
    return env, episodes, sim, snap_t


def _render(config: TaskConfig, episodes, folder: Path, width: int, height: int) -> tuple[float, float]:
    """Draw every snapshot into one mp4; returns (draw seconds, encode seconds)."""
    from pursuit_mj.render.episodes import FrameMaker
    from pursuit_mj.render.renderer import RenderSettings
    from pursuit_mj.render.video import video_file

    draw = enc = 0.0
    with FrameMaker(config, episodes[0][0][0].layout, RenderSettings(width, height, "top"), "heuristic", 30) as maker:
        with video_file(folder / "bench.mp4", width, height, 10.0) as video:
            for k, (snaps, _) in enumerate(episodes):
                maker.start_episode()
                for s in snaps:
                    t0 = time.perf_counter()
                    maker.push(s)
                    frame = maker.draw(s, k)
                    t1 = time.perf_counter()
                    video.add(frame)
                    enc += time.perf_counter() - t1
                    draw += t1 - t0
            t2 = time.perf_counter()  # leaving the block waits for ffmpeg to finish the file
        enc += time.perf_counter() - t2
    return draw, enc


def _record(episodes, folder: Path) -> float:
    from pursuit_mj.recording import EpisodeBuffer, RerunEpisodeRecording

    t = time.perf_counter()
    with RerunEpisodeRecording(folder / "bench.rrd") as rec:
        for snaps, record in episodes:
            buf = EpisodeBuffer({"policy": "heuristic"})
            for s in snaps:
                buf.append(s)
            rec.add_episode(buf, record)
    return time.perf_counter() - t


def bench_render(fidelity: str = "quadrotor", steps: int = 1000, width: int = 640, height: int = 480, seed: int = 0) -> RenderBenchResult:
    config = default_config(fidelity=fidelity)
    _, episodes, sim, snap_t = _simulate(config, steps, seed)
    with tempfile.TemporaryDirectory(prefix="pursuit_render_bench_") as tmp:
        draw, enc = _render(config, episodes, Path(tmp), width, height)
        send = _record(episodes, Path(tmp))
    frames = sum(len(snaps) for snaps, _ in episodes)
    return RenderBenchResult(fidelity, steps, frames, len(episodes), width, height, sim, snap_t, draw, enc, send,
                             str(config.layout))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fidelity", choices=("quadrotor", "point", "both"), default="both", help="physics fidelity (default both)")
    p.add_argument("--steps", type=int, default=1000, help="decision steps to play and render (default 1000)")
    p.add_argument("--width", type=int, default=640, help="frame width in pixels (default 640)")
    p.add_argument("--height", type=int, default=480, help="frame height in pixels (default 480)")
    p.add_argument("--seed", type=seed_arg, default=0, help="environment seed (default 0)")


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.steps <= MAX_STEPS:
        raise ValueError(f"--steps: must be in 1..{MAX_STEPS}, got {args.steps}")
    from pursuit_mj.layout import load_layout
    from pursuit_mj.render.renderer import RenderSettings, check_settings
    from pursuit_mj.render.video import check_frame_size, ensure_ffmpeg

    config = default_config()
    check_settings(RenderSettings(args.width, args.height, "top"), config, load_layout(config.layout))  # sizes first
    check_frame_size("mp4", args.width, args.height)
    ensure_ffmpeg()
    for fidelity in (("quadrotor", "point") if args.fidelity == "both" else (args.fidelity,)):
        result = bench_render(fidelity, args.steps, args.width, args.height, args.seed)
        print("\n".join(result.lines()), flush=True)
    return 0
