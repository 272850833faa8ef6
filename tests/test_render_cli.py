"""`pursuit-mj render` end to end: outputs and their names, reference flags, models, and bad input refused early."""

from __future__ import annotations

import pytest

from conftest import stop_signals_at_their_defaults
from pursuit_cli import main
from pursuit_mj.render.video import ensure_ffmpeg

W, H = 160, 120


@pytest.fixture(scope="module", autouse=True)
def _ffmpeg():
    ensure_ffmpeg()


def _cli(tmp_path, *extra, policy="random"):
    who = ["--policy", policy] if policy else []
    return main(["render", *who, "--fidelity", "point", "--set", "max_steps=5", "--width", str(W), "--height", str(H), *extra])


def test_cli_writes_videos_finals_and_reference_flags_work(tmp_path, capsys):
    out = tmp_path / "renders"
    code = _cli(tmp_path, "-s", str(out), "--episodes", "2", "--final-frame", "--format", "gif",
                "-i", "2", "-rv", "0.4", "-ev", "0.5", "--r_perception", "1.5", "--obstacle_num", "2", "--delta_t", "0.1", "-sc")
    assert code == 0
    text = capsys.readouterr().out
    assert "perception_radius: 1.5" in text and "pursuer_speed: 0.4" in text and "random_obstacles: 2" in text
    names = sorted(p.name for p in out.iterdir())
    digest = names[0].split("_")[4]
    assert len(digest) == 6 and int(digest, 16) >= 0
    stem = f"random_layout2_point_seed0_{digest}"
    assert names == [f"{stem}_ep000.gif", f"{stem}_ep000_final.png", f"{stem}_ep001.gif", f"{stem}_ep001_final.png"]


def test_a_save_path_ending_in_a_slash_is_a_folder_even_with_a_dot_in_its_name(tmp_path):
    out = tmp_path / "renders.v0.2"
    assert _cli(tmp_path, "-s", f"{out}/", "--format", "gif") == 0
    assert [p.name[:26] + p.name[33:] for p in out.iterdir()] == ["random_layout0_point_seed0_ep000.gif"]


def test_files_of_episodes_on_random_layouts_are_not_named_after_a_layout(tmp_path, capsys):
    """With random_layout each episode draws a built-in layout: a layout flag beside it is refused (`-i 3`
    was accepted, named none of the layouts played and only changed which episodes played)."""
    out = tmp_path / "renders"
    assert _cli(tmp_path, "-s", str(out), "--set", "random_layout=true", "--format", "gif") == 0
    [name] = [p.name for p in out.iterdir()]
    assert name.startswith("random_layoutrandom_point_seed0_"), name
    assert _cli(tmp_path, "-s", str(out), "-i", "3", "--set", "random_layout=true", "--format", "gif") == 2
    assert "'random_layout' draws each episode's layout from the built-in 0-3, so layout 3 would be ignored" in \
        capsys.readouterr().err


def test_cli_single_file_and_no_video(tmp_path):
    assert _cli(tmp_path, "-s", str(tmp_path / "one.mp4")) == 0
    assert (tmp_path / "one.mp4").is_file()
    assert _cli(tmp_path, "-s", str(tmp_path / "Two.GIF"), "--episodes", "2") == 0  # the name as given, upper case too
    assert sorted(p.name for p in tmp_path.glob("Two*")) == ["Two_ep000.GIF", "Two_ep001.GIF"]
    assert _cli(tmp_path, "-s", str(tmp_path / "finals"), "--no-video", "--final-frame", "--episodes", "3") == 0
    assert len(list((tmp_path / "finals").glob("*_final.png"))) == 3
    assert not list((tmp_path / "finals").glob("*.mp4"))


def test_render_seed_plays_the_first_episodes_of_eval_with_that_seed(tmp_path, capsys):
    """render --seed S --episodes K played other episodes than eval --seed S, its files named seedS all the same."""
    from pursuit_mj.config import default_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy

    task = default_config(fidelity="point", max_steps=60, layout=2)
    [row] = evaluate(make_policy("heuristic", task), task, [2], episodes=2, seed=4, n_worlds=2)
    code = main(["render", "--policy", "heuristic", "--fidelity", "point", "--set", "max_steps=60", "-i", "2",
                 "--seed", "4", "--episodes", "2", "--no-video", "--final-frame", "--width", str(W), "--height", str(H),
                 "-s", str(tmp_path / "r")])
    assert code == 0
    lines = [l for l in capsys.readouterr().out.splitlines() if l.startswith("episode ")]
    for k, (line, (seed, outcome, steps, *_)) in enumerate(zip(lines, row.episode_log)):
        assert line.startswith(f"episode {k}: {outcome} after {steps} steps (seed {seed})"), (line, row.episode_log)


def test_an_episode_of_an_evaluation_table_replays_by_its_episode_seed(tmp_path, capsys):
    """eval's JSON lists each episode's seed; render --episode-seed plays that very episode
    (an episode depends on its seed alone), named after it."""
    from pursuit_mj.config import default_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy

    task = default_config(fidelity="point", max_steps=60, layout=2)
    [row] = evaluate(make_policy("heuristic", task), task, [2], episodes=3, seed=4, n_worlds=3)
    seeds, outcomes = [e[0] for e in row.episode_log], [(e[1], e[2]) for e in row.episode_log]
    out = tmp_path / "renders"
    code = main(["render", "--policy", "heuristic", "--fidelity", "point", "--set", "max_steps=60", "-i", "2",
                 "--width", str(W), "--height", str(H), "-s", str(out), "--format", "gif",
                 "--episode-seed", str(seeds[2]), "--episode-seed", str(seeds[0])])
    assert code == 0
    lines = [l for l in capsys.readouterr().out.splitlines() if l.startswith("episode ")]
    for line, k in zip(lines, (2, 0)):
        assert line.startswith(f"episode {0 if k == 2 else 1}: {outcomes[k][0]} after {outcomes[k][1]} steps (seed {seeds[k]})")
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 2 and all(n.startswith("heuristic_layout2_point_") for n in names)
    assert {n.rsplit("_", 1)[1] for n in names} == {f"episode{seeds[2]}.gif", f"episode{seeds[0]}.gif"}
    assert _cli(tmp_path, "-s", str(out), "--format", "gif", "--episode-seed", "7", "--episodes", "2") == 2
    assert "--episodes 2 and 1 --episode-seed: give one or the other" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _cli(tmp_path, "--episode-seed", "-3")
    assert "argument --episode-seed: expected an integer >= 0, got -3" in capsys.readouterr().err


@pytest.mark.parametrize("args, message", [
    (["-s", "out.avi"], "-s out.avi: unknown video extension '.avi' (use .mp4 or .gif, which --final-frame follows with _final.png; for a folder end the name with /: -s out.avi/)"),
    (["-s", "x.mp4", "--format", "gif"], "--format gif contradicts"),
    (["--camera", "side"], "--camera 'side': no such camera"),
    (["--camera", "follow:pursuer_7"], "no drone named 'pursuer_7'"),
    (["-m", "missing.pt"], "--model missing.pt: no such checkpoint file"),
    (["--width", "161"], "mp4 (h264) needs even frame sizes"),
    (["--width", "4000"], "--width 4000: must be an integer in 16..1920 pixels"),
    (["--width", "-5"], "--width -5: must be an integer in 16..1920 pixels"),  # the range before the parity
    (["--episodes", "0"], "--episodes: expected an integer in 1..1,000,000, got 0"),
    (["--height", "42"], "--height 42: too small to hold the caption band (27 px) and the colour key (15 px)"),
    (["--height", "20", "--no-key"], "--height 20: too small to hold the caption band (27 px) and the scene"),
    (["--rerun", "x.txt"], "expected a file name ending in .rrd"),
    (["--rerun", "rec/x.rrd", "--camera", "side"], "--camera 'side': no such camera"),
    (["-s", "out.rrd/", "--rerun", "out.rrd"], "-s out.rrd/ and --rerun out.rrd: the recording would be written where -s makes its folder"),
    (["-s", "out.rrd/sub/", "--final-frame", "--no-video", "--rerun", "out.rrd"], "the recording would be written where -s"),
    (["--rerun", "rec/x.rrd", "--width", "161"], "mp4 (h264) needs even frame sizes"),
    (["--no-video"], "leaves nothing to write"),
    (["-s", "out/x.gif", "--fps", "60"], "--fps: 60 frames per second is beyond what a GIF plays"),
    (["-s", "out/", "--format", "gif", "--set", "control_dt=0.01"], "--fps (default 1/control_dt = 100): 100 frames per second"),
    (["--fps", "1e-9"], "--fps: 1e-09 frames per second is outside what ffmpeg writes correctly (0.01..1e+06)"),
    (["--fps", "1e308"], "--fps: 1e+308 frames per second is outside what ffmpeg writes correctly (0.01..1e+06)"),
])
def test_cli_refuses_bad_input_before_any_work(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    if args[0] == "-m":
        args = ["-m", str(tmp_path / "missing.pt")]
        message = f"--model {tmp_path / 'missing.pt'}: no such checkpoint file"
    code = main(["render", "--fidelity", "point", "--set", "max_steps=5", *args])
    assert code == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # not even an empty output folder


def test_cli_refuses_an_unwritable_save_path(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert _cli(tmp_path, "-s", str(blocker / "sub")) == 2
    assert f"-s {blocker / 'sub'}: cannot create the folder" in capsys.readouterr().err


def test_an_episode_of_the_random_teams_table_replays_by_its_episode_seed_alone(tmp_path, capsys):
    """eval --seed 5 made the random team with seed 5 and render --episode-seed with --seed's
    default 0: the team drew other actions, so the table's episode did not replay (a collision
    after 24 steps in eval was one after 181 in render) and files named alike held other episodes."""
    import json

    table = tmp_path / "t.json"
    assert main(["eval", "--policy", "random", "--fidelity", "point", "--set", "max_steps=40", "--layouts", "0",
                 "--episodes", "1", "--seed", "5", "-q", "--json", str(table)]) == 0
    log = json.loads(table.read_text())["rows"][0]["per_episode"]
    episodes = list(zip(log["seed"], log["outcome"], log["steps"]))
    for extra in ([], ["--seed", "9"]):
        code = main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=40", "-i", "0", *extra,
                     "--no-video", "--final-frame", "--width", str(W), "--height", str(H), "-s", str(tmp_path / "r"),
                     *(a for seed, *_ in episodes for a in ("--episode-seed", str(seed)))])
        assert code == 0
        lines = [l for l in capsys.readouterr().out.splitlines() if l.startswith("episode ")]
        assert len(lines) == 1
        for k, (line, (seed, outcome, steps)) in enumerate(zip(lines, episodes)):
            assert line.startswith(f"episode {k}: {outcome} after {steps} steps (seed {seed})"), (extra, line, episodes)


def test_renders_that_differ_in_anything_they_show_get_names_of_their_own(tmp_path, capsys):
    out = tmp_path / "renders"
    assert _cli(tmp_path, "-s", str(out), "--format", "gif") == 0
    first = sorted(p.name for p in out.iterdir())
    assert _cli(tmp_path, "-s", str(out), "--format", "gif") == 0  # the same render again replaces its own copy
    assert sorted(p.name for p in out.iterdir()) == first
    for extra in (["--set", "evader_speed=0.3"], ["--camera", "angled"], ["--trail", "5"]):
        assert _cli(tmp_path, "-s", str(out), "--format", "gif", *extra) == 0
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 4 and len({n.split("_")[4] for n in names}) == 4
    assert all(n.startswith("random_layout0_point_seed0_") and n.endswith("_ep000.gif") for n in names)


def test_a_policy_file_that_draws_from_its_seed_renders_an_episode_seed_under_names_of_each_seed(tmp_path, capsys):
    """With --episode-seed the file names leave --seed out, but a policy of one's own is made as
    NAME(config, seed) with it: one that draws from it played another episode under --seed 1 than
    under --seed 0 and wrote it over the first, under the very same name."""
    team = tmp_path / "noisy.py"
    team.write_text("import numpy as np\n\n\nclass Noisy:\n    name = 'noisy'\n\n"  # seed 0: into the wall below; 1: hover
                    "    def __init__(self, config, seed):\n        self.down = -1.0 if seed % 2 == 0 else 0.0\n\n"
                    "    def reset(self, n_worlds, world_ids=None):\n        pass\n\n"
                    "    def act(self, obs, spec):\n        return np.stack(np.broadcast_arrays(0.0 * obs[..., 0], self.down + 0.0 * obs[..., 0]), -1)\n")
    out = tmp_path / "renders"
    played = {}
    for seed in ("0", "1"):
        assert _cli(tmp_path, "-s", str(out), "--no-video", "--final-frame", "--set", "max_steps=60", "--seed", seed,
                    "--episode-seed", "123", policy=f"{team}:Noisy") == 0
        played[seed] = [l.split(" ->")[0] for l in capsys.readouterr().out.splitlines() if l.startswith("episode ")]
    assert played["0"] != played["1"]  # two episodes: each keeps a file of its own
    assert len(list(out.glob("noisy_layout0_point_*_episode123_final.png"))) == 2


def test_the_render_digest_follows_the_checkpoint_bytes_and_the_layout_file_content(tmp_path):
    from pursuit_cli.render_cmd import render_digest
    from pursuit_mj.config import TaskConfig
    from pursuit_mj.layout import LAYOUT_DIR

    layout = tmp_path / "arena.yaml"
    layout.write_text((LAYOUT_DIR / "1_walls.yaml").read_text())
    config = TaskConfig(layout=str(layout))
    model = tmp_path / "best.pt"
    model.write_bytes(b"weights of update 10")
    before = render_digest(config, "classic", model, {"camera": "top"})
    assert render_digest(config, "classic", model, {"camera": "top"}) == before
    model.write_bytes(b"weights of update 20")  # trained on: the same file name, another policy
    after_training = render_digest(config, "classic", model, {"camera": "top"})
    layout.write_text(layout.read_text().replace("\n", "\n\n", 1))  # the same layout, written differently
    assert render_digest(config, "classic", model, {"camera": "top"}) == after_training
    layout.write_text((LAYOUT_DIR / "2_bars.yaml").read_text())  # another layout under the same name
    assert len({before, after_training, render_digest(config, "classic", model, {"camera": "top"})}) == 3


@pytest.mark.parametrize("suffix, extra", [(".mp4", []), ("_final.png", ["--final-frame", "--no-video"])])
def test_a_folder_where_an_output_file_goes_is_refused_before_any_episode(tmp_path, capsys, suffix, extra):
    out = tmp_path / "renders"
    assert _cli(tmp_path, "-s", str(out), *extra) == 0  # learns the name of episode 0
    (written,) = out.iterdir()
    written.unlink()
    name = written.name.replace(f"_ep000{suffix}", f"_ep001{suffix}")
    (out / name).mkdir()
    capsys.readouterr()
    assert _cli(tmp_path, "-s", str(out), "--episodes", "2", *extra) == 2
    err = capsys.readouterr()
    assert f"-s {out}: {out / name} is a folder, expected a file name there" in err.err and "episode 0" not in err.out
    assert [p.name for p in out.iterdir()] == [name]


def test_cli_checkpoints_another_observation_spec_refused_matching_one_used(tmp_path, capsys):
    from train.config import load_train_config
    from train.trainer import Trainer

    mc = tmp_path / "model.yaml"
    mc.write_text(f"name: sixteen_rays\nn_envs: 1\nrun: {{runs_dir: {tmp_path}, progress: false}}\ntask: {{fidelity: point, max_steps: 3, layout: 3}}\n")
    assert main(["render", "-mc", str(mc), "-s", str(tmp_path / "m.mp4")]) == 2
    assert f"no checkpoint at {tmp_path / 'sixteen_rays' / 'best.pt'}" in capsys.readouterr().err
    good = Trainer(load_train_config([str(mc)]), log=lambda s: None).save("best.pt")
    # the same model against a task whose observation has 8 range readings instead of 16
    assert _cli(tmp_path, "-m", str(good), "--set", "n_rays=8", "-s", str(tmp_path / "o.mp4"), policy=None) == 2
    assert "observation spec does not match" in capsys.readouterr().err
    assert not (tmp_path / "o.mp4").exists()
    assert _cli(tmp_path, "-m", str(good), "-s", str(tmp_path / "g.mp4"), policy=None) == 0
    assert (tmp_path / "g.mp4").is_file()
    # -mc: its task is the base (layout 3, 3 steps) and its run's best.pt the model
    assert main(["render", "-mc", str(mc), "-s", str(tmp_path / "m.mp4"), "--width", str(W), "--height", str(H), "-sc"]) == 0
    out = capsys.readouterr().out
    assert "layout: 3" in out and "max_steps: 3" in out and (tmp_path / "m.mp4").is_file()


def test_a_model_configs_task_takes_task_files_and_flags_as_the_other_commands_do(tmp_path, capsys):
    """With -mc, each --task file's checks across keys were judged before the --set after it (a file that
    a later --set completes, as every other command takes it, was refused), and -i with a digit that is
    not ASCII ('²') ended in Python's "invalid literal for int() with base 10"."""
    mc = tmp_path / "model.yaml"
    mc.write_text(f"name: none_here\nrun: {{runs_dir: {tmp_path}}}\ntask: {{fidelity: point, max_steps: 3}}\n")
    panic = tmp_path / "panic.yaml"
    panic.write_text("evader:\n  panic_distance: 3.5\n")
    args = ["render", "-mc", str(mc), "-s", str(tmp_path / "m.mp4"), "--task", str(panic)]
    assert main(args + ["--set", "evader.calm_distance=5", "-sc"]) == 2
    captured = capsys.readouterr()  # the config is taken and shown; the model is what is missing
    assert "calm_distance: 5.0" in captured.out and "no checkpoint at" in captured.err, captured.err
    assert main(args) == 2  # nothing repairs it: the file is named
    assert f"{panic}: key 'evader': evader.calm_distance 3.0 must exceed" in capsys.readouterr().err
    assert main(["render", "-mc", str(mc), "-i", "\u00b2"]) == 2
    err = capsys.readouterr().err
    assert "layout '\u00b2'" in err and "invalid literal" not in err, err


def test_a_missing_model_leaves_no_output_folder_behind(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["render", "-mc", "classic", "-s", "finals/", "--fidelity", "point"]) == 2
    assert "no checkpoint at" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def _cli_process(args, env_changes=None, **popen):
    import os
    import subprocess
    import sys

    env = {**os.environ, **(env_changes or {})}
    code = "import sys; from pursuit_cli import main; sys.exit(main(sys.argv[1:]))"
    popen.setdefault("preexec_fn", stop_signals_at_their_defaults)  # the signal tests work under nohup too
    return subprocess.Popen([sys.executable, "-c", code, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **popen)


@pytest.mark.parametrize("value", ["foo", "osmesa-typo"])
def test_a_mujoco_gl_value_mujoco_rejects_is_one_line_naming_it_even_for_help(value):
    proc = _cli_process(["--help"], {"MUJOCO_GL": value})
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and out == ""
    assert err.startswith(f"pursuit-mj: error: environment variable MUJOCO_GL={value!r}") and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("env, names", [({"MUJOCO_GL": "egl", "PYOPENGL_PLATFORM": "osmesa"}, "MUJOCO_GL=egl and PYOPENGL_PLATFORM=osmesa"),
                                        ({"MUJOCO_GL": "", "PYOPENGL_PLATFORM": "glx"}, "PYOPENGL_PLATFORM='glx'")])
def test_a_pyopengl_platform_at_odds_with_offscreen_rendering_is_named_not_blamed_on_the_install(tmp_path, env, names):
    """A Docker image's PYOPENGL_PLATFORM left over under another MUJOCO_GL: PyOpenGL must use the backend
    rendered with, so the error names the variable to change, not a library to install that is there."""
    proc = _cli_process(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=2",
                         "--width", str(W), "--height", str(H), "-s", str(tmp_path / "a.gif")], env)
    out, err = proc.communicate(timeout=180)
    assert proc.returncode == 2 and not (tmp_path / "a.gif").exists()
    assert names in err and "PYOPENGL_PLATFORM" in err.split(names, 1)[1] and "install" not in err, err
    assert len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])
def test_a_render_killed_by_sigterm_or_sighup_leaves_no_partial_video(tmp_path, sig):
    import signal
    import time

    out = tmp_path / "renders"
    # drones at 2 cm/s neither collide nor catch: the episode outlasts the test
    proc = _cli_process(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=100000",
                         "--set", "pursuer_speed=0.02", "--set", "evader_speed=0.02",
                         "--width", str(W), "--height", str(H), "-s", str(out / "long.mp4")])
    deadline = time.monotonic() + 90
    while not (out.is_dir() and any(out.iterdir())) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    time.sleep(0.3)  # a few frames into the video
    proc.send_signal(getattr(signal, sig))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + getattr(signal, sig), err[-2000:]
    assert f"interrupted by {sig}" in err
    assert not out.exists()  # nor the folder it made for the video, left empty


def test_a_recording_interrupted_by_sigterm_keeps_its_finished_episodes(tmp_path):
    import signal

    from pursuit_mj.recording.rrd_read import read_entities

    rrd = tmp_path / "ev.rrd"
    # 20-step episodes, one after another, far more than the test waits for
    proc = _cli_process(["render", "--policy", "random", "--fidelity", "point", "--episodes", "5000", "--no-video",
                         "--set", "max_steps=20", "--set", "pursuer_speed=0.02", "--set", "evader_speed=0.02",
                         "--rerun", str(rrd)])
    line = ""
    while not line.startswith("episode 1:") and proc.poll() is None:  # two episodes are in the recording
        line = proc.stdout.readline()
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err[-2000:]  # 128 + SIGTERM
    partial = tmp_path / "ev.interrupted.rrd"
    assert f"finished before it are in {partial}" in err and f"{rrd} was not written" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ev.interrupted.rrd"]
    ent = read_entities(partial)
    n = ent["/__properties/interrupted"].static["finished_episodes"][0]
    assert n >= 2 and f"/episode_{n - 1}/outcome" in ent


@pytest.mark.parametrize("extra", [[], ["--no-video"]])
def test_an_empty_rerun_path_is_refused_naming_the_flag_not_ignored(tmp_path, capsys, monkeypatch, extra):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        _cli(tmp_path, "-s", "out/", "--rerun", "", *extra)
    assert exit_.value.code == 2
    assert "argument --rerun: an empty path ('')" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no video played and written without the recording asked for


def test_an_evader_model_file_that_draws_from_its_seed_renders_an_episode_seed_under_names_of_each_seed(tmp_path, capsys):
    """An evader model of one's own is made as NAME(config, n_worlds, seed) with the env's seed,
    render's --seed: one that draws from it plays another episode under another --seed, and with
    --episode-seed (names without --seed) the second render replaced the first under one name,
    as a policy file's did until its digest took --seed in."""
    model = tmp_path / "parity.py"  # seed 0: the evader flies left; 1: right
    model.write_text("import numpy as np\n\n\nclass Parity:\n"
                     "    def __init__(self, config, n_worlds, seed):\n        self.v = config.evader_speed * (1.0 if seed % 2 else -1.0)\n\n"
                     "    def reset(self, world_ids, seeds):\n        pass\n\n"
                     "    def compute(self, ep, ev, pp, pv, active, obstacles, dt):\n"
                     "        out = np.zeros_like(ep)\n        out[..., 0] = self.v\n        return out\n")
    out = tmp_path / "renders"
    for seed in ("0", "1"):
        assert _cli(tmp_path, "-s", str(out), "--no-video", "--final-frame", "--set", "max_steps=20", "--seed", seed,
                    "--set", f"evader.model={model}:Parity", "--episode-seed", "5", policy="heuristic") == 0
    capsys.readouterr()
    assert len(list(out.glob("heuristic_layout0_point_*_episode5_final.png"))) == 2
    for seed in ("0", "1"):  # without an evader model of one's own --seed decides nothing there: one name
        assert _cli(tmp_path, "-s", str(out / "plain"), "--no-video", "--final-frame", "--seed", seed, "--episode-seed", "5",
                    policy="heuristic") == 0
    assert len(list((out / "plain").glob("*_episode5_final.png"))) == 1


@pytest.mark.parametrize("extra, said", [
    (["--policy", "heuristic", "--rerun", "n1/x/r.rrd", "-s", "mine.txt/"], "exists and is not a folder"),
    (["--policy", "pol.py:Failing", "-s", "n1/x/", "--rerun", "n1/r/e.rrd"], "raised IndexError"),
    (["--policy", "pol.py:Failing", "-s", "n1/x/", "--no-video", "--final-frame"], "raised IndexError"),
])
def test_a_render_refused_or_failed_before_it_wrote_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch, extra, said):
    """--rerun's folder was made (its check) before -s was refused, and a policy that failed in its
    first episode left the folders of -s and --rerun behind, empty."""
    from test_policy_file import FAILING

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("mine")
    (tmp_path / "pol.py").write_text(FAILING)
    assert _cli(tmp_path, *extra, policy=None) == 2
    assert said in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "__pycache__") == ["mine.txt", "pol.py"]


def test_a_recording_to_a_named_pipe_goes_into_the_pipe_and_leaves_it_a_pipe(tmp_path, capsys, monkeypatch):
    """render --rerun ep.rrd, with ep.rrd a named pipe (to a viewer reading it, say), renamed the
    finished recording over the pipe: a regular file took its place, and its reader got nothing.
    The recording is now written into the pipe, as every other output of the project is; with no
    reader, one line names the pipe and where the recording is kept instead."""
    import os
    import stat
    import threading

    from pursuit_mj import io_utils

    pipe = tmp_path / "ep.rrd"
    os.mkfifo(pipe)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_bytes()), daemon=True)
    reader.start()
    argv = ["render", "--policy", "heuristic", "--fidelity", "point", "--set", "max_steps=5", "--no-video",
            "-s", str(tmp_path / "out"), "--rerun", str(pipe)]
    assert main(argv) == 0, capsys.readouterr().err
    reader.join(10)
    assert stat.S_ISFIFO(os.stat(pipe).st_mode), "the pipe was replaced by a file"
    assert got and got[0][:4] == b"RRF2" and len(got[0]) > 1000  # a whole recording, rerun's file header first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep.rrd"]  # no unfinished file left beside it

    monkeypatch.setattr(io_utils, "PIPE_READER_WAIT_S", 0.2)
    assert main(argv) == 2
    err = capsys.readouterr().err
    kept = tmp_path / "ep.new.rrd"
    assert f"--rerun {pipe}: a named pipe that no program opened for reading" in err and f"kept in {kept}" in err, err
    assert len(err.strip().splitlines()) == 1 and kept.read_bytes()[:4] == b"RRF2"
    assert stat.S_ISFIFO(os.stat(pipe).st_mode) and sorted(p.name for p in tmp_path.iterdir()) == ["ep.new.rrd", "ep.rrd"]


@pytest.mark.parametrize("drawn", [False, True])
def test_a_model_config_that_trained_on_several_layouts_is_not_rendered_on_one_it_never_met(tmp_path, capsys, drawn):
    """`train --layout A --layout B [--random-layout]` stores the layouts under `layouts`, its task's
    layout staying 0: `render -mc` of that run played layout 0, or with random_layout drew the
    built-in layouts, never A or B, without a word. It is refused, naming the run's layouts and how to
    choose one; a layout given on the command line is rendered."""
    mc = tmp_path / "model.yaml"
    mc.write_text(f"name: two\nlayouts: [1, 2]\nrun: {{runs_dir: {tmp_path}}}\n"
                  f"task: {{fidelity: point, max_steps: 3, random_layout: {str(drawn).lower()}}}\n")
    assert main(["render", "-mc", str(mc), "--policy", "heuristic", "--no-video", "--final-frame",
                 "-s", str(tmp_path / "f/")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"-mc {mc}: the run trained on layouts 1, 2" in err, err
    assert ("--set random_layout=false" in err) == drawn and "-i LAYOUT" in err
    assert not (tmp_path / "f").exists()
    chosen = ["-i", "2"] + (["--set", "random_layout=false"] if drawn else [])
    assert main(["render", "-mc", str(mc), "--policy", "heuristic", "--no-video", "--final-frame",
                 "-s", str(tmp_path / "f/"), "--width", str(W), "--height", str(H)] + chosen) == 0
    assert "layout2" in capsys.readouterr().out


def test_an_episode_seed_given_twice_is_refused_before_anything_is_played(tmp_path, capsys):
    """`--episode-seed 1234 --episode-seed 1234` played the episode twice and wrote its file twice,
    the second replacing the first under the one name (_episode1234): a slip in a list of seeds."""
    out = tmp_path / "renders"
    assert _cli(tmp_path, "-s", str(out), "--episode-seed", "7", "--episode-seed", "9", "--episode-seed", "7") == 2
    assert "--episode-seed 7: given twice (each seed plays one episode, named _episode7)" in capsys.readouterr().err
    assert not out.exists()


def test_the_help_of_fps_says_a_gif_of_a_fine_control_dt_needs_fps(capsys):
    """'(default: real time, 1/control_dt; a GIF at most 50)' read as a default capped at 50 for a
    GIF; with --delta-t 0.01 the default 100 is refused (test above), so the help says so."""
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "a GIF plays at most 50, so with gif a control_dt below 0.02 s needs --fps" in text


@pytest.mark.parametrize("flag, value, hint", [
    ("--r_velocity", "300", "--r_velocity 300.0: key 'pursuer_speed': 300.0 is out of range (must be <= 3.0); m/s here, where the reference study's run_sim.py took mm/s (300 mm/s is 0.3 m/s)"),
    ("-ev", "900", "-ev 900.0: key 'evader_speed': 900.0 is out of range"),
    ("--r_perception", "1500", "m here, where the reference study's run_sim.py took mm (1500 mm is 1.5 m)"),
])
def test_a_speed_or_radius_in_the_reference_studys_millimetres_is_refused_naming_the_flag_typed_and_the_unit(
        tmp_path, capsys, flag, value, hint):
    """The reference study's run_sim.py took speeds and radius in mm; `-rv 300` was refused as
    '--pursuer-speed 300.0 ... must be <= 3.0', naming a flag the user had not typed and no unit."""
    assert _cli(tmp_path, "-s", str(tmp_path / "x.gif"), flag, value) == 2
    assert hint in capsys.readouterr().err
    assert not (tmp_path / "x.gif").exists()


def test_a_speed_just_above_its_range_is_refused_without_a_millimetre_hint(tmp_path, capsys):
    assert _cli(tmp_path, "-s", str(tmp_path / "x.gif"), "--evader-speed", "5") == 2
    err = capsys.readouterr().err
    assert "--evader-speed 5.0: key 'evader_speed': 5.0 is out of range (must be <= 3.0)" in err and "mm" not in err


def test_a_layout_flag_that_names_no_file_is_refused_under_the_spelling_typed(tmp_path, capsys):
    assert _cli(tmp_path, "-s", str(tmp_path / "x.gif"), "--env_idx", "nothere.yaml") == 2
    assert "--env_idx nothere.yaml: " in capsys.readouterr().err


def test_render_names_the_policy_layout_and_fidelity_of_the_episodes_it_reports(tmp_path, capsys):
    """'episode 0: timeout after 5 steps (seed ...)' was all render printed with --rerun alone (no
    video or image whose file name carries them): outcomes and steps of which policy, where, in
    which physics, it did not say. A line above the episodes names them."""
    code = main(["render", "--policy", "heuristic", "--fidelity", "point", "--set", "max_steps=5", "-i", "2",
                 "--no-video", "--rerun", str(tmp_path / "r.rrd")])
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "render: heuristic on layout 2, point fidelity, task reference with --set max_steps=5" and lines[1].startswith("episode 0: "), lines


@pytest.mark.parametrize("final", [False, True])
def test_a_sigterm_just_after_a_video_is_renamed_into_place_still_records_its_episode(tmp_path, capsys, monkeypatch, final):
    """The video of an episode and its entry in --rerun are put in place as one step: a stop
    arriving between the two (here: right after the video's rename) takes effect once the episode
    is in the recording too, so a complete video is never missing from the recording."""
    import signal

    from pursuit_mj.recording.rrd_read import read_entities
    from pursuit_mj.render import video as video_mod

    close = video_mod.VideoFile.close

    def close_then_sigterm(self, ok=True):
        path = close(self, ok)
        if ok:
            assert callable(signal.getsignal(signal.SIGTERM)), "the CLI must handle SIGTERM here"
            signal.raise_signal(signal.SIGTERM)  # handled at once, between this rename and what follows
        return path

    monkeypatch.setattr(video_mod.VideoFile, "close", close_then_sigterm)
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as a terminal starts a command: the CLI takes it
    try:
        out, rrd = tmp_path / "ep.mp4", tmp_path / "ep.rrd"
        code = _cli(tmp_path, "-s", str(out), "--rerun", str(rrd), "--episodes", "3", *(["--final-frame"] if final else []))
    finally:
        signal.signal(signal.SIGTERM, previous)
    err = capsys.readouterr().err
    assert code == 143, err
    assert "interrupted by SIGTERM" in err
    videos = sorted(p.name for p in tmp_path.glob("ep_*.mp4"))
    assert videos == ["ep_ep000.mp4"]  # the episode whose video was renamed, and no other
    if final:
        assert (tmp_path / "ep_ep000_final.png").is_file()
    ent = read_entities(tmp_path / "ep.interrupted.rrd")
    assert ent["/__properties/interrupted"].static["finished_episodes"][0] == 1
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" not in ent


def test_a_final_image_that_cannot_be_written_while_a_kill_is_held_is_told_before_interrupted(tmp_path, capsys, monkeypatch):
    """A SIGTERM that lands while an episode's outputs go into place waits for them (stops_held).
    When the final PNG then could not be written, render said 'interrupted by SIGTERM' alone: the
    failed file went unmentioned and its episode's video stood with no entry in the recording. Now
    the failure is told first (naming the PNG and what is in place), then the stop, whose exit code
    (143) the command still ends with."""
    import os
    import signal

    from pursuit_mj.recording.rrd_read import read_entities
    from pursuit_mj.render import episodes

    save = episodes.save_png

    def killed_while_saving(path, frame):
        os.kill(os.getpid(), signal.SIGTERM)  # lands inside the block: held until it ends
        path.mkdir()  # and the image cannot take its name: a folder is there now
        return save(path, frame)

    monkeypatch.setattr(episodes, "save_png", killed_while_saving)
    out, rrd = tmp_path / "renders", tmp_path / "ev.rrd"
    assert _cli(tmp_path, "-s", str(out), "--final-frame", "--format", "gif", "--rerun", str(rrd)) == 143
    err = capsys.readouterr().err
    (png,) = out.glob("*_final.png")  # the folder in its place (the image is kept beside it, as the error says)
    (gif,) = out.glob("*.gif")
    lines = err.splitlines()
    assert lines[-2].startswith(f"pursuit-mj render: error: {png}: cannot") and f"{gif} is in place, with the episode's entry" in lines[-2], err
    assert lines[-1] == "pursuit-mj render: interrupted by SIGTERM", err
    assert "/episode_0/outcome" in read_entities(tmp_path / "ev.interrupted.rrd")


@pytest.mark.parametrize("task, named", [
    ([], "task reference with --set max_steps=5"),
    (["--task", "hard"], "task hard with --set max_steps=5"),
    (["-mc", "classic", "--policy", "heuristic", "-ec", "hard", "--pursuers", "2"],
     "task of -mc classic + hard with --pursuers 2, --set max_steps=5"),
])
def test_render_names_the_task_of_the_episodes_it_reports(task, named, tmp_path, capsys):
    """render's first line named the policy, layout and fidelity but not the task, which eval's
    heading names (common.task_named): episodes of --task hard read as the reference task's. It
    now names it as eval does; with -mc the run's task is what the task files and flags change, so
    the name starts from it."""
    policy = [] if "--policy" in task else ["--policy", "heuristic"]
    assert main(["render", *policy, *task, "--fidelity", "point", "--set", "max_steps=5", "-i", "2", "--no-video",
                 "--rerun", str(tmp_path / "r.rrd")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"render: heuristic on layout 2, point fidelity, {named}", lines
