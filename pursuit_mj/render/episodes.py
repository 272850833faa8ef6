"""Run episodes of a policy in one world and hand every state to the recorders that want it.

Recorders only read (`env.snapshot`): the video renderer, the final-frame PNG and the rerun
recording never touch the environment, so an episode is the same with or without them.
Episode k is the k-th episode of world 0 of `PursuitEnv(config, seed=seed)`, whichever
recorders run.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from ..config import TaskConfig
from ..env import EpisodeRecord, PursuitEnv, Snapshot, check_seeds
from ..layout import Layout
from ..policy import Policy, check_policy, checked_actions
from .caption import Caption, draw_caption, draw_key
from .overlays import OverlayStyle, TrailBuffer, draw_all, key_entries, overlay_geom_budget
from .renderer import RenderSettings, SceneRenderer
from ..io_utils import CannotWrite, stops_held
from .video import VideoFile, save_png, video_file

if TYPE_CHECKING:  # rerun is imported only when a recording is made
    from ..recording.rerun_episodes import RerunEpisodeRecording


@dataclasses.dataclass(frozen=True)
class EpisodeOutputs:
    """Where episode k goes: video_paths[k] (.mp4/.gif) and final_paths[k] (.png); None = not wanted."""

    video_paths: Sequence[Path] | None = None
    final_paths: Sequence[Path] | None = None
    fps: float = 10.0
    trail_length: int = 30


def drone_pose(snap: Snapshot) -> tuple[np.ndarray, np.ndarray]:
    """(pos (D, 3) m, quat (D, 4) wxyz) of all drones in scene order (pursuers first)."""
    return np.concatenate([snap.pursuer_pos, snap.evader_pos]), np.concatenate([snap.pursuer_quat, snap.evader_quat])


class FrameMaker:
    """Snapshot -> captioned frame (H, W, 3) uint8, keeping each drone's trail of the last
    `trail_length` decision steps.

    Works from snapshots alone (their layout picks the scene), so it draws live episodes and
    recorded ones the same way.
    """

    def __init__(self, config: TaskConfig, layout: Layout, settings: RenderSettings, title: str, trail_length: int,
                 style: OverlayStyle | None = None, keep_scenes: int = 1):
        self.title = title
        self.style = style or OverlayStyle()
        self.trail_steps = trail_length
        self.trail = self.new_trail()
        self.renderer = SceneRenderer(settings, config, layout, lambda lay: overlay_geom_budget(config, lay, self.style),
                                      keep_scenes=keep_scenes)

    def new_trail(self) -> TrailBuffer:
        """A buffer for a trail of `trail_length` decision steps: that many segments through one
        state more (a trail of 1 step is a line from the last state to this one)."""
        return TrailBuffer(self.trail_steps + 1)

    def start_episode(self) -> None:
        """Forget the trails of the previous episode."""
        self.trail.clear()

    def push(self, snap: Snapshot, trail: TrailBuffer | None = None) -> None:
        """Add this state to the trails (every step, drawn or not); `trail`: to that buffer instead
        of the maker's own (one maker drawing several worlds, each with its trails)."""
        (self.trail if trail is None else trail).push(drone_pose(snap)[0])

    def draw(self, snap: Snapshot, episode: int | str, trail: TrailBuffer | None = None) -> np.ndarray:
        """The captioned frame of `snap` with the trails pushed so far (to `trail` when given; the
        returned array is new). `episode`: its number, or a text that names it ('seed 1234'),
        which the caption shows after 'episode ' or as it is."""
        self.renderer.bind(snap.layout)
        pos, quat = drone_pose(snap)
        trails = (self.trail if trail is None else trail).array()
        img = self.renderer.render(pos, quat, lambda scene: draw_all(scene, snap, trails, self.style))
        which = episode if isinstance(episode, str) else f"episode {episode}"
        cap = Caption(f"{self.title} | layout {snap.layout.name} | {snap.config.fidelity} | {which}",
                      snap.step, snap.config.max_steps, snap.time, snap.outcome)
        img = draw_caption(img, cap)
        return draw_key(img, key_entries(snap, self.style)) if self.renderer.settings.key else img

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self) -> "FrameMaker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def run_episodes(
    config: TaskConfig,
    policy: Policy,
    episodes: int,
    seed: int = 0,
    settings: RenderSettings | None = None,
    outputs: EpisodeOutputs | None = None,
    recording: RerunEpisodeRecording | None = None,
    title: str | None = None,
    on_episode: Callable[[int, EpisodeRecord, list[Path]], None] | None = None,
    episode_seeds: Sequence[int] | None = None,
) -> list[EpisodeRecord]:
    """Play `episodes` episodes in one world, writing videos / final PNGs / rerun as asked.

    episode_seeds: play the episodes of these seeds (one each, `episodes` must be their number)
    instead of those the env draws from `seed`; an episode depends on its seed alone, so this
    replays an episode of an evaluation table (evaluation.Row.episode_log holds the seeds).

    Frames are rendered only when a video or final image of that episode is wanted (for
    final images only the last state is rendered). `on_episode(k, record, written_paths)` is
    called after each episode.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes (--episodes): expected an integer >= 1, got {episodes!r}")
    episodes = int(episodes)
    check_policy(policy, "run_episodes policy")
    if recording is not None and not callable(getattr(recording, "add_episode", None)):
        raise ValueError(f"run_episodes recording: expected a RerunEpisodeRecording (pursuit_mj.recording), got {recording!r}")
    outputs = outputs or EpisodeOutputs()
    for name, paths in (("video", outputs.video_paths), ("final-frame", outputs.final_paths)):
        if paths is not None and len(paths) != episodes:
            raise ValueError(f"{name} paths: {len(paths)} given for {episodes} episodes")
    wants_frames = outputs.video_paths is not None or outputs.final_paths is not None
    if episode_seeds is not None:
        if not hasattr(episode_seeds, "__len__") or isinstance(episode_seeds, (str, bytes)):
            raise ValueError(f"episode seeds: expected a list of seeds, got {episode_seeds!r}; for one, give [{episode_seeds!r}]")
        episode_seeds = check_seeds(episode_seeds, len(episode_seeds), "episode seeds")
        if len(episode_seeds) != episodes:
            raise ValueError(f"episode seeds: {len(episode_seeds)} given for {episodes} episodes")
    env = PursuitEnv(config, n_worlds=1, seed=seed, auto_reset=False)
    obs = env.reset(seeds=episode_seeds[:1]) if episode_seeds is not None else env.reset()
    policy.reset(1)
    label = title or getattr(policy, "name", "policy")
    maker = FrameMaker(config, env.world_layouts[0], settings or RenderSettings(), label, outputs.trail_length) if wants_frames else None
    records = []
    try:
        for k in range(episodes):
            if k:
                obs = env.reset_worlds([0], episode_seeds[k : k + 1] if episode_seeds is not None else None)
                policy.reset(1, np.array([0]))
            if maker is not None:
                maker.start_episode()
            shown = f"seed {episode_seeds[k]}" if episode_seeds is not None else k  # a replay: what names it in a table
            record, written = _one_episode(env, policy, obs, k, shown, maker, outputs, recording, label)
            records.append(record)
            if on_episode is not None:
                on_episode(k, record, written)
    finally:
        if maker is not None:
            maker.close()
    return records


def _one_episode(env: PursuitEnv, policy: Policy, obs: np.ndarray, k: int, shown: int | str, maker: FrameMaker | None,
                 outputs: EpisodeOutputs, recording: RerunEpisodeRecording | None, label: str) -> tuple[EpisodeRecord, list[Path]]:
    video_path = outputs.video_paths[k] if outputs.video_paths is not None else None
    final_path = outputs.final_paths[k] if outputs.final_paths is not None else None
    buffer = None
    if recording is not None:
        from ..recording.rerun_episodes import EpisodeBuffer

        buffer = EpisodeBuffer({"policy": label})
    written: list[Path] = []

    def observe(video) -> Snapshot:
        snap = env.snapshot(0)
        if buffer is not None:
            buffer.append(snap)
        if maker is not None:
            maker.push(snap)
            if video is not None:
                video.add(maker.draw(snap, shown))
        return snap

    def play(video) -> tuple[EpisodeRecord, Snapshot]:
        nonlocal obs
        snap = observe(video)
        info = None
        while not env.done[0]:
            actions = checked_actions(policy.act(obs, env.obs_spec), 1, env.n_pursuers, f"policy {getattr(policy, 'name', label)}")
            obs, _, _, _, info = env.step(actions)
            snap = observe(video)
        return info["episodes"][0], snap

    if video_path is not None:
        settings = maker.renderer.settings
        with video_file(video_path, settings.width, settings.height, outputs.fps) as video:
            record, last = play(video)
            video.finish()  # complete, not yet renamed: Ctrl-C or SIGTERM until here leaves nothing of the episode
            final = maker.draw(last, shown) if final_path is not None else None
            with stops_held():  # the episode's outputs go into place together; a stop meanwhile waits for them
                written += _put_in_place(video, final_path, final, recording, buffer, record)
    else:
        record, last = play(None)
        final = maker.draw(last, shown) if final_path is not None else None
        with stops_held():
            written += _put_in_place(None, final_path, final, recording, buffer, record)
    return record, written


def _put_in_place(video: VideoFile | None, final_path: Path | None, final: np.ndarray | None,
                  recording: RerunEpisodeRecording | None, buffer, record: EpisodeRecord) -> list[Path]:
    """Put a played episode's outputs in place: its video renamed onto its name, its final frame
    written, the episode added to the rerun recording; returns the files written. Called under
    io_utils.stops_held, so that a stop never leaves a video in place whose episode the recording lacks.
    One that cannot be written (CannotWrite) does not keep the others out: they go into place, and
    then the first failure is raised (a CannotWrite) saying which of them are in place."""
    written: list[Path] = []
    failures: list[CannotWrite] = []

    def attempt(put: Callable[[], object]) -> bool:
        try:
            put()
            return True
        except CannotWrite as exc:
            failures.append(exc)
            return False

    if video is not None:
        attempt(lambda: written.append(video.close(ok=True)))
    if final_path is not None:
        attempt(lambda: written.append(save_png(final_path, final)))
    recorded = recording is not None and attempt(lambda: recording.add_episode(buffer, record))
    if failures:
        raise CannotWrite(str(failures[0]) + _what_is_in_place(written, recorded, failures[1:])) from None
    return written


def _what_is_in_place(written: list[Path], recorded: bool, others: list[CannotWrite]) -> str:
    """'; ep0.mp4 is in place, with the episode's entry in the rerun recording' and the like: what
    the outputs of `_put_in_place` that did not fail left, told after its first failure (`others`:
    the failures after it)."""
    files = " and ".join(str(p) for p in written)
    verb = "is" if len(written) == 1 else "are"
    if files and recorded:
        said = f"{files} {verb} in place, with the episode's entry in the rerun recording"
    elif files:
        said = f"{files} {verb} in place"
    elif recorded:
        said = "the episode's entry in the rerun recording is added"
    else:
        said = "none of the episode's outputs is in place"
    return f"; {said}" + "".join(f"; also {exc}" for exc in others)
