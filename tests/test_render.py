"""Offscreen rendering: real videos and images read back, overlays, cameras, atomic files, bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mediapy
import mujoco
import numpy as np
import pytest
from PIL import Image

from pursuit_mj.config import default_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.layout import load_layout
from pursuit_mj.policy import RandomPolicy
from pursuit_mj.render.caption import Caption, KeyEntry, band_height, draw_caption, draw_key, key_band_height
from pursuit_mj.render.episodes import EpisodeOutputs, FrameMaker, run_episodes
from pursuit_mj.render.overlays import OverlayStyle, key_entries
from pursuit_mj.render.renderer import RenderSettings, SceneRenderer
from pursuit_mj.render.video import ensure_ffmpeg, video_format

W, H = 160, 120
CFG = dict(fidelity="point", max_steps=8, layout=1)


def small(**changes):
    return RenderSettings(W, H, changes.pop("camera", "top"), changes.pop("quality", "fast"))


@pytest.fixture(scope="module", autouse=True)
def _ffmpeg():
    ensure_ffmpeg()


def _play(tmp_path, fmt, episodes=1, **cfg):
    config = default_config(**{**CFG, **cfg})
    videos = [tmp_path / f"ep{k}.{fmt}" for k in range(episodes)]
    finals = [tmp_path / f"ep{k}.png" for k in range(episodes)]
    records = run_episodes(config, RandomPolicy(3), episodes, seed=5, settings=small(), outputs=EpisodeOutputs(videos, finals, fps=10))
    return records, videos, finals


@pytest.mark.parametrize("fmt", ["mp4", "gif"])
def test_video_is_read_back_with_one_frame_per_state(tmp_path, fmt):
    (record,), (video,), _ = _play(tmp_path, fmt)
    frames = mediapy.read_video(video)
    assert frames.shape == (record.steps + 1, H, W, 3)  # the start state, then one frame per step
    first, last = frames[0].astype(int), frames[-1].astype(int)
    assert first.std() > 10, "the first frame is blank"
    assert np.abs(first - last).mean() > 0.5, "first and last frames are the same: nothing moved on screen"
    assert list(tmp_path.glob("*.part*")) == []


def test_final_frame_png_per_episode_shows_the_outcome(tmp_path):
    records, _, finals = _play(tmp_path, "mp4", episodes=2)
    assert [r.outcome for r in records] and all(r.outcome in ("success", "collision", "timeout") for r in records)
    for rec, path in zip(records, finals):
        img = np.asarray(Image.open(path).convert("RGB"))
        assert img.shape == (H, W, 3) and img.std() > 10
    # the PNG equals the video's last frame up to compression: same caption, same state
    last = mediapy.read_video(tmp_path / "ep1.mp4")[-1].astype(int)
    png = np.asarray(Image.open(finals[1]).convert("RGB")).astype(int)
    assert np.abs(last - png).mean() < 8


def test_rendering_does_not_change_the_episode(tmp_path):
    config = default_config(**CFG)
    plain = run_episodes(config, RandomPolicy(3), 2, seed=5)
    drawn = run_episodes(config, RandomPolicy(3), 2, seed=5, settings=small(),
                         outputs=EpisodeOutputs([tmp_path / "a.gif", tmp_path / "b.gif"], None))
    assert [(r.outcome, r.steps, r.returns) for r in plain] == [(r.outcome, r.steps, r.returns) for r in drawn]


def test_interrupted_render_leaves_no_file_under_the_final_name(tmp_path):
    class Interrupting(RandomPolicy):
        calls = 0

        def act(self, obs, spec):
            Interrupting.calls += 1
            if Interrupting.calls == 4:
                raise KeyboardInterrupt
            return super().act(obs, spec)

    target = tmp_path / "chase.mp4"
    with pytest.raises(KeyboardInterrupt):
        run_episodes(default_config(**CFG), Interrupting(0), 1, settings=small(), outputs=EpisodeOutputs([target], None))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("fmt", ["mp4", "gif"])
def test_an_interrupt_while_the_encoder_finishes_the_file_leaves_nothing(tmp_path, fmt):
    """Ctrl-C or SIGTERM while ffmpeg writes the last frames out (closing a long video takes a
    while): neither the file nor its temporary part stays, and the encoder is not left running."""
    from pursuit_mj.render.video import video_file

    target, frame = tmp_path / f"chase.{fmt}", np.zeros((H, W, 3), np.uint8)
    with pytest.raises(KeyboardInterrupt):
        with video_file(target, W, H, 10.0) as video:
            video.add(frame)
            writer = video._writer
            finish = writer.close

            def interrupted_close():
                writer.close = finish  # as a signal arriving during the wait for ffmpeg
                raise KeyboardInterrupt

            writer.close = interrupted_close
    assert list(tmp_path.iterdir()) == []
    assert writer._proc is None or writer._proc.poll() is not None


def test_a_video_that_cannot_replace_the_file_under_its_name_is_kept_beside_it_and_the_error_says_where(tmp_path, monkeypatch):
    """The finished video cannot replace the file under its name (a file of another user in a
    sticky-bit folder, an immutable one, a folder made there meanwhile): it was deleted with the
    error; now it is kept, whole, as NAME.new.SUFFIX (numbered when that is taken) and the
    one-line error says where."""
    import os

    from pursuit_mj import io_utils
    from pursuit_mj.io_utils import CannotWrite
    from pursuit_mj.render.video import video_file

    target, frame = tmp_path / "chase.gif", np.zeros((H, W, 3), np.uint8)
    replace = os.replace

    def refused(src, dst):
        if Path(dst) == target:
            raise PermissionError(1, "Operation not permitted", str(src), None, str(dst))
        replace(src, dst)

    monkeypatch.setattr(io_utils.os, "replace", refused)
    kept = tmp_path / "chase.new.gif"
    with pytest.raises(CannotWrite, match=f"^{target}: cannot replace it \\(Operation not permitted\\); "
                                          f"what was written is kept in {kept}$"):
        with video_file(target, W, H, 10.0) as video:
            video.add(frame)
            video.add(frame)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chase.new.gif"]
    assert mediapy.read_video(kept).shape[0] == 2
    with pytest.raises(CannotWrite, match=f"kept in {tmp_path / 'chase.new-2.gif'}$"):  # the first one is not replaced
        with video_file(target, W, H, 10.0) as video:
            video.add(frame)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chase.new-2.gif", "chase.new.gif"]
    assert mediapy.read_video(kept).shape[0] == 2


def test_a_folder_made_under_an_eval_tables_name_keeps_the_table_beside_it(tmp_path):
    """atomic_write_text (eval's CSV/JSON tables, metrics logs): the written text survives a
    final rename that fails because a folder took the name meanwhile."""
    from pursuit_mj.io_utils import atomic_write_text

    (tmp_path / "results.csv").mkdir()
    with pytest.raises(ValueError, match=f"results.csv: cannot replace it .*; what was written is kept in {tmp_path / 'results.new.csv'}$"):
        atomic_write_text(tmp_path / "results.csv", "a,b\n1,2\n")
    assert (tmp_path / "results.new.csv").read_text() == "a,b\n1,2\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv", "results.new.csv"]


@pytest.mark.parametrize("when", ["mid-stream", "at the end"])
def test_an_encoder_that_stops_early_is_an_error_naming_the_file_and_leaves_nothing(tmp_path, when):
    """A full disk or a killed ffmpeg: neither a silent exit 0 (a broken pipe) nor a traceback."""
    from pursuit_mj.io_utils import CannotWrite
    from pursuit_mj.render.video import video_file

    target, frame = tmp_path / "chase.mp4", np.zeros((H, W, 3), np.uint8)
    with pytest.raises(CannotWrite, match=f"{target}: cannot write it \\(the ffmpeg encoder stopped"):
        with video_file(target, W, H, 10.0) as video:
            video.add(frame)
            video._writer._proc.kill()  # as a full disk would end it
            video._writer._proc.wait()
            if when == "mid-stream":
                video.add(frame)
    assert list(tmp_path.iterdir()) == []


def test_a_final_frame_that_does_not_fit_on_the_disk_is_an_error_naming_it(tmp_path, monkeypatch):
    import errno

    from pursuit_mj.io_utils import CannotWrite
    from pursuit_mj.render.video import save_png

    def full_disk(self, fp, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", full_disk)
    target = tmp_path / "chase_final.png"
    with pytest.raises(CannotWrite, match=f"{target}: cannot write it \\(No space left on device\\)"):
        save_png(target, np.zeros((H, W, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_quadrotor_attitude_reaches_the_rendered_model():
    config = default_config(fidelity="quadrotor")
    layout = load_layout(0)
    with SceneRenderer(small(camera="follow:pursuer_0"), config, layout) as r:
        pos = np.array([[1.0, 1.0, 0.5], [2.0, 1.0, 0.5], [3.0, 1.0, 0.5], [1.8, 4.5, 0.5]])
        tilt = np.array([np.cos(0.2), np.sin(0.2), 0.0, 0.0])  # 0.4 rad roll
        level = np.tile([1.0, 0, 0, 0], (4, 1))
        tilted = level.copy()
        tilted[0] = tilt
        img_level = r.render(pos, level).copy()
        body = r.model.body("pursuer_0/body").id
        img_tilted = r.render(pos, tilted).copy()
        np.testing.assert_allclose(r.data.xquat[body], tilt, atol=1e-12)
        assert np.abs(img_level.astype(int) - img_tilted.astype(int)).sum(-1).astype(bool).sum() > 20, "the tilt is not visible"


@pytest.mark.parametrize("key", [True, False])
def test_top_camera_frames_the_whole_arena_between_caption_and_key(key):
    config = default_config(fidelity="point")
    layout = load_layout(0)
    with SceneRenderer(RenderSettings(320, 240, "top", key=key), config, layout) as r:
        m = r.model
        cam = m.camera("top").id
        assert m.cam_projection[cam] == mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC
        extent = m.cam_fovy[cam]
        top_edge = m.cam_pos[cam, 1] + extent / 2 - extent * band_height(240) / 240
        bottom_edge = m.cam_pos[cam, 1] - extent / 2 + (extent * key_band_height(240) / 240 if key else 0.0)
        assert bottom_edge < 0.0 and top_edge > layout.height
        assert extent * 320 / 240 > layout.width


@pytest.mark.parametrize("key", [True, False])
def test_a_frame_too_short_for_its_bands_is_refused_and_the_shortest_allowed_frames_the_arena(key):
    config, layout = default_config(fidelity="point"), load_layout(0)
    bands = band_height(48) + (key_band_height(48) if key else 0)  # 42 px, 27 px without the key
    with pytest.raises(ValueError, match=f"--height {bands}: too small to hold the caption band"):
        SceneRenderer(RenderSettings(64, bands, "top", key=key), config, layout)
    with SceneRenderer(RenderSettings(64, bands + 1, "top", key=key), config, layout) as r:
        m = r.model
        cam = m.camera("top").id
        extent = m.cam_fovy[cam]  # visible height (m): it was 1/0 or negative (an upside-down view) before
        assert extent > 0 and r.render(np.ones((4, 3)), np.tile([1.0, 0, 0, 0], (4, 1))).shape == (bands + 1, 64, 3)
        top_edge = m.cam_pos[cam, 1] + extent / 2 - extent * band_height(bands + 1) / (bands + 1)
        bottom_edge = m.cam_pos[cam, 1] - extent / 2 + (extent * key_band_height(bands + 1) / (bands + 1) if key else 0.0)
        assert bottom_edge < 0.0 and top_edge > layout.height


def test_caption_band_differs_with_outcome():
    frame = np.full((H, W, 3), 200, np.uint8)
    a = draw_caption(frame, Caption("t", 3, 10, 0.3, ""))
    b = draw_caption(frame, Caption("t", 3, 10, 0.3, "success"))
    band = band_height(H)
    assert (a[band:] == frame[band:]).all(), "the caption spills below its band"
    assert np.abs(a[:band].astype(int) - b[:band].astype(int)).sum() > 0


@pytest.mark.parametrize("width, height", [(320, 240), (640, 480), (160, 120)])
def test_a_long_title_and_status_stay_clear_of_the_outcome(width, height):
    """A checkpoint's name behind the shield on a named layout: the caption's lines are fitted to the
    room left of the widest outcome word, so COLLISION is never drawn over them."""
    from pursuit_mj.render.caption import OUTCOME_RGB

    frame = np.zeros((height, width, 3), np.uint8)
    band = band_height(height)
    title = "finetune_ppo+shield | layout warehouse_with_long_name | quadrotor | episode 123"
    for outcome in ("collision", "success", "timeout"):
        full = draw_caption(frame, Caption(title, 1000, 1000, 100.0, outcome))[:band].astype(int)
        bare = draw_caption(frame, Caption("", 0, 0, 0.0, outcome))[:band].astype(int)
        word = np.nonzero((np.abs(bare - OUTCOME_RGB[outcome]).sum(-1) < 60).any(0))[0]
        lines = np.nonzero((np.abs(full - bare).sum(-1) > 60).any(0))[0]
        assert len(word) and len(lines), "the outcome or the caption lines were not drawn"
        assert lines.max() < word.min(), f"{outcome}: the caption lines reach x={lines.max()}, the outcome starts at x={word.min()}"


def test_colour_key_stays_in_its_band_and_lists_what_the_task_shows():
    frame = np.full((H, W, 3), 200, np.uint8)
    keyed = draw_key(frame, [KeyEntry("pursuer", (40, 115, 240), "dot"), KeyEntry("random", (209, 138, 46), "square")])
    band = key_band_height(H)
    assert (keyed[:-band] == frame[:-band]).all(), "the key spills above its band"
    assert (keyed[-band:] != frame[-band:]).any()
    env = PursuitEnv(default_config(**CFG), seed=0, auto_reset=False)
    env.reset()
    snap = env.snapshot(0)
    labels = [e.label for e in key_entries(snap, OverlayStyle())]
    assert labels == ["pursuer", "evader", "sight", "seen", "relayed", "capture", "caught", "obstacle", "random"]
    full = PursuitEnv(default_config(**CFG, observability="full", random_obstacles=0), seed=0, auto_reset=False)
    full.reset()
    labels = [e.label for e in key_entries(full.snapshot(0), OverlayStyle())]
    assert labels == ["pursuer", "evader", "seen", "capture", "caught", "obstacle"]
    # the caught disc is keyed as it looks over the floor: drawn at its translucent grey without
    # the floor under it, it was (89, 89, 89) on a key band of about (85, 86, 87), invisible
    floor = np.array([226, 226, 222], float)
    band_rgb = floor * (85 / 255) + np.array([15, 18, 24]) * (170 / 255)
    (caught,) = [e for e in key_entries(full.snapshot(0), OverlayStyle()) if e.label == "caught"]
    assert np.abs(np.array(caught.rgb) - band_rgb).min() > 40, caught.rgb


def test_colour_key_lists_no_relayed_line_for_a_lone_pursuer():
    """With one pursuer nothing is ever relayed (known = seen), so the key must not list it."""
    env = PursuitEnv(default_config(**CFG, n_pursuers=1, share_detections=True), seed=0, auto_reset=False)
    env.reset()
    snap = env.snapshot(0)
    assert not (snap.known & ~snap.seen & ~snap.captured[None, :]).any()
    labels = [e.label for e in key_entries(snap, OverlayStyle())]
    assert "relayed" not in labels and "sight" in labels and "seen" in labels


def test_frames_carry_the_key_unless_it_is_turned_off():
    config = default_config(**CFG)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    snap = env.snapshot(0)
    frames = {}
    for key in (True, False):
        settings = RenderSettings(W, H, "follow:pursuer_0", key=key)  # the same view either way
        with FrameMaker(config, snap.layout, settings, "t", 5) as maker:
            frames[key] = maker.draw(snap, 0)
    band = key_band_height(H)
    assert (frames[True][:-band] == frames[False][:-band]).all()
    assert (frames[True][-band:] != frames[False][-band:]).any()


def test_overlays_add_scene_geoms_for_every_element():
    config = default_config(**CFG)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    snap = env.snapshot(0)
    with FrameMaker(config, snap.layout, small(), "t", 5) as maker:
        maker.push(snap)
        maker.draw(snap, 0)
        with_overlays = maker.renderer.scene.ngeom
        maker.renderer.render(*[np.concatenate(x) for x in ((snap.pursuer_pos, snap.evader_pos), (snap.pursuer_quat, snap.evader_quat))])
        plain = maker.renderer.scene.ngeom
    n, m = config.n_pursuers, config.n_evaders
    circles = n * maker.style.circle_segments + m * (maker.style.circle_segments // 2)
    assert with_overlays - plain >= circles + n + m  # rings, capture zones, one marker per drone


def test_largest_team_with_every_evader_relayed_across_the_arena_fits_the_scene(tmp_path):
    """16 pursuers and 8 evaders, every pair a dashed relay line corner to corner: the worst
    frame the overlays can draw must fit the scene the renderer sized for it."""
    big = tmp_path / "big.yaml"
    big.write_text("name: big\narena: {width: 8.0, height: 10.0}\nboundary: rectangle\nobstacles: []\n"
                   "spawn:\n  pursuers: {x: [0.2, 7.8], y: [0.2, 2.0]}\n  evaders: {x: [0.2, 7.8], y: [8.0, 9.8]}\n")
    config = default_config(**{**CFG, "layout": str(big), "n_pursuers": 16, "n_evaders": 8})
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    snap = env.snapshot(0)
    n, m = config.n_pursuers, config.n_evaders
    far = dataclasses.replace(
        snap,
        pursuer_pos=np.tile([0.0, 0.0, 0.5], (n, 1)),
        evader_pos=np.tile([snap.layout.width, snap.layout.height, 0.5], (m, 1)),
        seen=np.zeros((n, m), bool), known=np.ones((n, m), bool), captured=np.zeros(m, bool))
    with FrameMaker(config, snap.layout, small(), "t", 40) as maker:
        for _ in range(40):
            maker.push(far)
        frame = maker.draw(far, 0)
        assert maker.renderer.scene.ngeom <= maker.renderer.scene.maxgeom
        assert maker.renderer.scene.ngeom > 3000  # more than the old fixed allowance held
    assert frame.shape == (H, W, 3)


def test_video_format_by_extension():
    assert video_format("a/b.MP4") == "mp4" and video_format("x.gif") == "gif"
    with pytest.raises(ValueError, match="unknown video extension '.avi'"):
        video_format("x.avi")


def test_backend_is_chosen_by_trying_when_mujoco_gl_is_unset():
    import os
    import subprocess
    import sys

    code = ("from pursuit_mj.config import default_config\n"
            "from pursuit_mj.layout import load_layout\n"
            "from pursuit_mj.render import gl\n"
            "from pursuit_mj.render.renderer import RenderSettings, SceneRenderer\n"
            "r = SceneRenderer(RenderSettings(64, 48), default_config(fidelity='point'), load_layout(0))\n"
            "import numpy as np\n"
            "img = r.render(np.zeros((4, 3)) + 1.0, np.tile([1.0, 0, 0, 0], (4, 1)))\n"
            "print(gl.choose_backend(), img.shape, int(img.std() > 1))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    backend, *rest = out.stdout.split()
    assert backend in ("egl", "osmesa") and " ".join(rest) == "(48, 64, 3) 1"


def test_backend_errors_name_what_to_install(monkeypatch):
    from pursuit_mj.render import gl

    monkeypatch.setattr(gl, "_chosen", None)
    monkeypatch.setenv("MUJOCO_GL", "vulkan")
    with pytest.raises(gl.RenderBackendError, match="MUJOCO_GL='vulkan'.*egl, osmesa, glfw"):
        gl.choose_backend()
    text = gl._explain({"egl": "no device", "osmesa": "library not found"})
    assert "egl: no device" in text and "libegl1" in text and "libosmesa6" in text


def test_a_pyopengl_platform_set_alone_is_the_only_backend_tried_and_the_error_says_so(monkeypatch):
    from pursuit_mj.render import gl

    tried = []
    monkeypatch.setattr(gl, "_chosen", None)
    monkeypatch.setattr(gl, "_pinned_platform", lambda: None)
    monkeypatch.setattr(gl, "_probe", lambda backend: tried.append(backend) or "library not found")
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setenv("PYOPENGL_PLATFORM", "osmesa")  # egl would fail in-process under it, whatever a probe said
    with pytest.raises(gl.RenderBackendError, match="osmesa: library not found.*PYOPENGL_PLATFORM=osmesa asks for it"):
        gl.choose_backend()
    assert tried == ["osmesa"]


def test_a_long_trail_follows_the_path_and_starts_at_its_oldest_point():
    """A 300-step trail was drawn through 13 of its points: chords of up to 1.5 m cut the
    corners of the path, and its oldest 24 steps were left out."""
    from pursuit_mj.render.overlays import OverlayStyle, trail_points

    t = np.linspace(0.0, 6 * np.pi, 300)  # three laps of a 1 m circle, 6.3 cm a step
    trails = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], -1)[:, None, :]  # (T, 1 drone, 3)
    pts = trail_points(trails, OverlayStyle())
    np.testing.assert_array_equal(pts[0], trails[0])  # the oldest point
    np.testing.assert_array_equal(pts[-1], trails[-1])  # and the newest
    chords = np.linalg.norm(np.diff(pts[:, 0], axis=0), axis=-1)
    assert chords.max() < 0.07, chords.max()  # every step drawn
    long = np.concatenate([trails] * 10)  # 3000 steps: thinned evenly, 8 steps a segment at most
    chords = np.linalg.norm(np.diff(trail_points(long, OverlayStyle())[:, 0], axis=0), axis=-1)
    assert chords.max() < 8 * 0.0632 and len(chords) <= OverlayStyle().trail_segments


@pytest.mark.parametrize("change, said", [
    ({"policy": "random"}, "run_episodes policy: expected a Policy"),
    ({"recording": "x.rrd"}, "run_episodes recording: expected a RerunEpisodeRecording"),
    ({"episode_seeds": 5}, "episode seeds: expected a list of seeds, got 5; for one, give \\[5\\]"),
    ({"episodes": True}, "episodes \\(--episodes\\): expected an integer >= 1, got True"),
])
def test_run_episodes_refuses_arguments_of_the_wrong_kind_before_an_episode_plays(change, said):
    """They failed deep inside (the recording only after a whole episode had played), or True ran one episode."""
    from pursuit_mj.config import default_config
    from pursuit_mj.policy import RandomPolicy
    from pursuit_mj.render.episodes import run_episodes

    args = {"config": default_config(fidelity="point", max_steps=3), "policy": RandomPolicy(0), "episodes": 1, **change}
    with pytest.raises(ValueError, match=said):
        run_episodes(**args)


@pytest.mark.parametrize("field, value, said", [("key", "no", "key 'no': expected True or False"),
                                                ("camera", None, "camera None: expected text")])
def test_render_settings_of_the_wrong_kind_are_refused_naming_the_field(field, value, said):
    """key='no' drew the key (any text is true); camera=None failed inside the camera parser."""
    import dataclasses

    from pursuit_mj.config import default_config
    from pursuit_mj.layout import load_layout
    from pursuit_mj.render.renderer import RenderSettings, check_settings

    settings = dataclasses.replace(RenderSettings(), **{field: value})
    with pytest.raises(ValueError, match=f"render_settings.{said}"):
        check_settings(settings, default_config(), load_layout(0), prefix="render_settings.")


def test_a_renderer_keeping_scenes_draws_them_as_one_that_rebuilds_them_and_builds_each_once(monkeypatch):
    """keep_scenes > 1: going back to a scene bound before reuses its model and GL context (a new
    context costs 13 ms of software GL per scene), and its frames are the same, pixel for pixel."""
    import pursuit_mj.render.renderer as renderer_module

    config = default_config(fidelity="point")
    layouts = [load_layout(0), load_layout(1), load_layout(2)]
    pos = np.array([[0.5 + i, 0.5, 0.3] for i in range(config.n_pursuers + config.n_evaders)])
    quat = np.tile([1.0, 0, 0, 0], (len(pos), 1))
    settings = RenderSettings(96, 72)
    order = [0, 1, 2, 0, 1, 2, 1]
    with SceneRenderer(settings, config, layouts[0]) as plain:
        expected = []
        for i in order:
            plain.bind(layouts[i])
            expected.append(plain.render(pos, quat).copy())
    builds = []
    real_build = renderer_module.build_model
    monkeypatch.setattr(renderer_module, "build_model", lambda spec: (builds.append(spec), real_build(spec))[1])
    with SceneRenderer(settings, config, layouts[0], keep_scenes=3) as keeping:
        for i, frame in zip(order, expected):
            keeping.bind(layouts[i])
            assert np.array_equal(keeping.render(pos, quat), frame)
    assert len(builds) == 3  # one per layout (the constructor's included), none on a return


def test_glfw_without_a_display_is_one_line_naming_the_backend_and_the_missing_display(tmp_path):
    """With MUJOCO_GL=glfw and no display, the error said 'no offscreen OpenGL backend works here
    ...; install one, or set MUJOCO_GL' on a machine where EGL works and MUJOCO_GL is set."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    env["MUJOCO_GL"] = "glfw"
    out = subprocess.run([sys.executable, "-m", "pursuit_cli", "render", "--fidelity", "point", "--set", "max_steps=2",
                          "--width", "64", "--height", "64", "-s", str(tmp_path / "out") + "/"],
                         env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr  # no GLFW warnings printed before it
    # only the backend MUJOCO_GL asks for was tried: the others are not said not to work (egl did, here)
    assert lines[0].startswith("pursuit-mj render: error: environment variable MUJOCO_GL=glfw asks for an OpenGL "
                               "backend that does not work here (glfw: "), lines[0]
    assert "DISPLAY" in lines[0] and "unset MUJOCO_GL to let pursuit-mj try egl and osmesa" in lines[0]
    assert "no offscreen OpenGL backend works here" not in lines[0]


@pytest.mark.parametrize("steps", [1, 3])
def test_a_trail_of_n_decision_steps_spans_n_steps_of_the_path(steps):
    """--trail N is the last N decision steps (docs/rendering.md): N segments through N + 1
    states; a trail of 1 step drew nothing, as --trail 0 does."""
    config = default_config(**CFG)
    env = PursuitEnv(config, n_worlds=1, seed=2, auto_reset=False)
    obs = env.reset()
    policy = RandomPolicy(0)
    policy.reset(1)
    with FrameMaker(config, env.world_layouts[0], small(), "t", steps) as maker, \
            FrameMaker(config, env.world_layouts[0], small(), "t", 0) as bare:
        states = []
        for _ in range(steps + 3):
            snap = env.snapshot(0)
            states.append(np.concatenate([snap.pursuer_pos, snap.evader_pos]))
            maker.push(snap)
            bare.push(snap)
            obs, *_ = env.step(policy.act(obs, env.obs_spec))
        np.testing.assert_array_equal(maker.trail.array(), np.stack(states[-(steps + 1):]))
        assert np.any(maker.draw(snap, 0) != bare.draw(snap, 0))  # the trail is drawn


def _wall_layout():
    from pursuit_mj.layout import layout_from_dict

    return layout_from_dict({"name": "walled", "arena": {"width": 4.0, "height": 4.0},
                             "obstacles": [{"box": {"center": [2.0, 2.6], "size": [2.0, 0.2]}}],
                             "spawn": {"pursuers": {"x": [0.5, 3.5], "y": [0.5, 1.5]}, "evaders": {"x": [0.5, 3.5], "y": [3.0, 3.5]}}}, "test")


@pytest.mark.parametrize("fov_deg", [120.0, 360.0])
def test_the_sight_outline_stops_at_walls_as_the_pursuers_sight_does(fov_deg):
    """The drawn wedge (or ring) went through walls and out of the arena, showing a pursuer seeing
    what its line-of-sight check hides: it now ends where a ray from the pursuer meets a wall."""
    import math

    from pursuit_mj.geometry import cast_rays
    from pursuit_mj.render.overlays import sight_outline

    layout = _wall_layout()
    obstacles = layout.obstacle_set()
    p, radius, fov = np.array([2.0, 2.0, 0.5]), 1.5, math.radians(fov_deg)  # the box's lower face at y 2.5, 0.5 m ahead
    pts = sight_outline(p, math.pi / 2, radius, fov, obstacles, 64)
    if fov_deg < 360:
        assert np.allclose(pts[0], p) and np.allclose(pts[-1], p)  # a wedge: from the pursuer and back
        arc = pts[1:-1]
    else:
        assert np.allclose(pts[0], pts[-1])  # a closed ring
        arc = pts[:-1]
    rel = arc[:, :2] - p[:2]
    reach = np.linalg.norm(rel, axis=1)
    assert (reach <= radius + 1e-9).all() and np.allclose(arc[:, 2], p[2])
    over_box = (arc[:, 0] > 1.01) & (arc[:, 0] < 2.99)  # the box spans x 1-3
    assert over_box.sum() >= 10 and (arc[over_box, 1] <= 2.5 + 1e-9).all()  # nothing drawn beyond its near face
    angle = np.arctan2(rel[:, 1], rel[:, 0])
    near_up = np.abs(angle - math.pi / 2) < math.radians(20)
    assert near_up.sum() >= 2 and np.allclose(reach[near_up], 0.5 / np.sin(angle[near_up]))  # the face 0.5 m ahead
    # each point lies where the pursuer's own ray in its direction ends (or at the radius)
    dirs = rel / reach[:, None]
    hit = cast_rays(np.broadcast_to(p[:2], dirs.shape)[None], dirs[None], obstacles)[0]
    assert np.allclose(reach, np.minimum(hit, radius))
    if fov_deg == 360:
        assert np.isclose(reach, radius).any()  # sideways and behind, nothing in the way


def test_the_sight_outline_in_the_open_is_the_whole_wedge():
    import math

    from pursuit_mj.render.overlays import arc_points, sight_outline

    p = np.array([2.0, 1.0, 0.5])
    pts = sight_outline(p, 0.0, 0.5, math.radians(120), _wall_layout().obstacle_set(), 64)
    assert len(pts) - 3 == 21  # a third of the ring's segments
    np.testing.assert_allclose(pts[1:-1], arc_points(p, 0.5, -math.radians(60), math.radians(60), 21), atol=1e-12)


def _drawn_line_ends(scene, start: int) -> np.ndarray:
    """(G, 2, 3) m: the ends of the line geoms an overlay drew from geom `start` on."""
    ends = []
    for g in list(scene.geoms)[start:scene.ngeom]:
        a = np.array(g.pos)
        ends.append([a, a + np.array(g.mat).reshape(3, 3)[:, 2] * g.size[2]])
    return np.array(ends)


def test_the_drawn_sight_stops_at_a_caught_evader_as_the_pursuers_sight_does():
    """A caught evader blocks sight as the drone it is (sensing.CAUGHT_BODY_RADIUS): the drawn ring
    went through it, showing the pursuer seeing what its line of sight hides."""
    import math
    import types

    import mujoco

    from pursuit_mj.config import default_config
    from pursuit_mj.render.overlays import GeomWriter, OverlayStyle, draw_perception
    from pursuit_mj.sensing import CAUGHT_BODY_RADIUS

    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    scene = mujoco.MjvScene(model, maxgeom=1000)
    p = np.array([1.0, 1.0, 0.5])
    evader = np.array([[1.5, 1.0, 0.5]])  # 0.5 m ahead along +x, on a ray of the 128
    config = dataclasses.replace(default_config(), observability="partial", perception_radius=1.5, field_of_view=2 * math.pi)
    for captured, reach in ((False, 1.5), (True, 0.5 - CAUGHT_BODY_RADIUS)):
        snap = types.SimpleNamespace(config=config, layout=_wall_layout(), pursuer_pos=p[None], heading=np.zeros(1),
                                     evader_pos=evader, captured=np.array([captured]))
        start = scene.ngeom
        draw_perception(GeomWriter(scene), snap, OverlayStyle())
        ends = _drawn_line_ends(scene, start)
        ahead = ends[np.isclose(ends[:, 0, 1], p[1], atol=1e-9) & (ends[:, 0, 0] > p[0])][:, 0]  # the point on the +x ray
        assert len(ahead) == 1 and np.isclose(ahead[0, 0] - p[0], reach, atol=1e-6), (captured, ahead)


def test_an_ffmpeg_named_by_IMAGEIO_FFMPEG_EXE_that_is_not_there_is_one_clear_error(tmp_path, monkeypatch):
    """imageio-ffmpeg returns IMAGEIO_FFMPEG_EXE untested: a stale one (no ffmpeg on PATH) let the
    render run on to mediapy's traceback ("RuntimeError: Program ... is not found")."""
    import shutil

    from pursuit_mj.render import video

    missing = tmp_path / "no" / "ffmpeg"
    monkeypatch.setattr(shutil, "which", lambda name, *a, **k: None)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(missing))
    try:
        with pytest.raises(ValueError, match=f"IMAGEIO_FFMPEG_EXE={missing}: no such program"):
            video.ensure_ffmpeg()
        not_a_program = tmp_path / "ffmpeg.txt"
        not_a_program.write_text("")
        monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(not_a_program))
        with pytest.raises(ValueError, match=f"IMAGEIO_FFMPEG_EXE={not_a_program}: not an executable program"):
            video.ensure_ffmpeg()
    finally:
        monkeypatch.undo()
        ensure_ffmpeg()  # the module's other tests go on with the real one


def test_a_replay_by_episode_seed_names_the_seed_in_its_caption(tmp_path, monkeypatch):
    """A render of `--episode-seed S` is the episode of a table that seed names, but its frames said
    'episode 0' (its place in this render), which matches nothing in the table; they now say 'seed S'.
    Episodes the render draws itself keep their number."""
    import pursuit_mj.render.episodes as episodes

    texts = []

    class Recorded(Caption):
        def __init__(self, text, *rest):
            texts.append(text)
            super().__init__(text, *rest)

    monkeypatch.setattr(episodes, "Caption", Recorded)
    config = default_config(**CFG)
    run_episodes(config, RandomPolicy(3), 2, settings=small(), outputs=EpisodeOutputs(None, [tmp_path / "a.png", tmp_path / "b.png"]),
                 episode_seeds=[1234, 987654321])
    assert [t.rsplit(" | ", 1)[1] for t in texts] == ["seed 1234", "seed 987654321"], texts
    texts.clear()
    run_episodes(config, RandomPolicy(3), 2, seed=5, settings=small(), outputs=EpisodeOutputs(None, [tmp_path / "c.png", tmp_path / "d.png"]))
    assert [t.rsplit(" | ", 1)[1] for t in texts] == ["episode 0", "episode 1"], texts


def _thin_wall_frame(wall_thickness):
    """A 640 x 480 top view (no key) of a 3.6 x 5 m arena, with a wall at y = 2.52 m of this thickness (None: none)."""
    from pursuit_mj.layout import layout_from_dict

    walls = [] if wall_thickness is None else [{"wall": {"from": [0.3, 2.52], "to": [3.3, 2.52], "thickness": wall_thickness}}]
    layout = layout_from_dict({"name": "thin", "arena": {"width": 3.6, "height": 5.0}, "obstacles": walls,
                               "spawn": {"pursuers": {"x": [0.2, 3.4], "y": [0.2, 0.8]}, "evaders": {"x": [0.2, 3.4], "y": [4.2, 4.8]}}},
                              "thin.yaml")
    config = default_config(fidelity="point", random_obstacles=0, observability="full")
    env = PursuitEnv(config, seed=0, auto_reset=False, layouts=[layout])
    env.reset()
    snap = env.snapshot(0)
    with FrameMaker(config, snap.layout, RenderSettings(640, 480, "top", "fast", key=False), "t", 5) as maker:
        return maker.draw(snap, 0)


def test_a_wall_thinner_than_a_pixel_is_still_drawn():
    """A 5 mm wall is 0.4 px wide at 640 x 480: it fell between pixel centres and vanished from the
    frame (at y = 2.52 m; at 2.5 m it showed), while the pursuers turned at it. Walls and boxes
    narrower than 1/120 of the arena's longer side get a line along them, drawn in pixels."""
    plain = _thin_wall_frame(None).astype(int)
    for thickness in (0.005, 0.01):
        differ = np.abs(_thin_wall_frame(thickness).astype(int) - plain).sum(-1) > 60
        assert differ.sum() > 200, (thickness, differ.sum())  # the 3 m wall spans about 230 px
    from pursuit_mj.render.overlays import thin_obstacle_segments

    assert all(thin_obstacle_segments(load_layout(k)) == [] for k in range(4))  # the built-in walls draw as before


def _big_arena_frame(style):
    """A 640 x 480 top view (no key) of a 50 x 50 m arena with its team, drawn with overlay `style`."""
    from pursuit_mj.layout import layout_from_dict
    from pursuit_mj.render.overlays import OverlayStyle

    layout = layout_from_dict({"name": "big", "arena": {"width": 50.0, "height": 50.0}, "obstacles": [],
                               "spawn": {"pursuers": {"x": [5, 20], "y": [5, 20]}, "evaders": {"x": [30, 45], "y": [30, 45]}}},
                              "big.yaml")
    config = default_config(fidelity="point", random_obstacles=0, observability="full")
    env = PursuitEnv(config, seed=0, auto_reset=False, layouts=[layout])
    env.reset()
    with FrameMaker(config, layout, RenderSettings(640, 480, "top", "fast", key=False), "t", 5, style=OverlayStyle(**style)) as maker:
        return maker.draw(env.snapshot(0), 0)


def test_drones_in_a_large_arena_are_marked_big_enough_to_see():
    """In a 50 m arena the 0.1 m role disc is about 1 px across at 640 x 480: the drones showed only
    through their trails and sight rings. The disc grows to 1/100 of the arena's longer side there
    (0.5 m), and keeps its 0.1 m in the built-in arenas."""
    from pursuit_mj.render.overlays import marker_radius

    plain = _big_arena_frame({"marker_alpha": 0.0}).astype(int)
    marked = np.abs(_big_arena_frame({}).astype(int) - plain).sum(-1) > 30
    assert marked.sum() >= 4 * 30, marked.sum()  # 3 pursuers and an evader, each a disc of several px
    from pursuit_mj.render.overlays import OverlayStyle

    assert all(marker_radius(load_layout(k), OverlayStyle()) == 0.1 for k in range(4))


def test_a_write_that_fails_while_a_stop_is_held_is_reported_and_leaves_the_episode_whole(tmp_path, monkeypatch):
    """An episode's outputs go into place under io_utils.stops_held. A SIGTERM held there while the
    final PNG could not be written (its folder is a file) was then delivered over the failure: the
    caller got 'interrupted' and no word of the PNG, and the video, already renamed into place,
    had no entry in the rerun recording. Now the other outputs still go into place, the held stop
    is delivered (its KeyboardInterrupt) with the write failure as its cause, and that failure
    names the file that failed and what is in place."""
    import os
    import signal

    from pursuit_mj.io_utils import CannotWrite
    from pursuit_mj.recording import RerunEpisodeRecording
    from pursuit_mj.recording.rrd_read import read_entities
    from pursuit_mj.render import episodes

    (tmp_path / "blocker").write_text("a file where the image's folder should be\n")
    video, final, rrd = tmp_path / "ep0.mp4", tmp_path / "blocker" / "ep0.png", tmp_path / "ev.rrd"
    save = episodes.save_png

    def killed_while_saving(path, frame):
        os.kill(os.getpid(), signal.SIGTERM)  # lands inside the block: held until it ends
        return save(path, frame)

    def as_the_cli_stops(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(episodes, "save_png", killed_while_saving)
    previous = signal.signal(signal.SIGTERM, as_the_cli_stops)
    try:
        with pytest.raises(KeyboardInterrupt) as stopped:
            with RerunEpisodeRecording(rrd) as recording:
                run_episodes(default_config(**CFG), RandomPolicy(3), 1, seed=5, settings=small(),
                             outputs=EpisodeOutputs([video], [final]), recording=recording)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert stopped.value.args == ("SIGTERM",)
    failure = stopped.value.__cause__
    assert isinstance(failure, CannotWrite), repr(failure)
    assert str(failure).startswith(f"{final}: cannot write it") and f"{video} is in place" in str(failure), str(failure)
    assert "entry in the rerun recording" in str(failure)
    assert video.is_file() and not final.exists() and len(mediapy.read_video(video)) > 1
    assert recording.n_episodes == 1 and "/episode_0/outcome" in read_entities(recording.kept)
