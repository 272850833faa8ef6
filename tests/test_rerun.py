"""Rerun recordings read back with rerun's own reader: entities, timelines, values, episodes, atomicity."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from pursuit_cli import main
from pursuit_mj.config import default_config
from pursuit_mj.palette import OBSTACLE_RGBA, rgb255
from pursuit_mj.env import PursuitEnv
from pursuit_mj.policy import RandomPolicy
from pursuit_mj.recording import EnvRecorder, EpisodeBuffer, RerunEpisodeRecording, RerunScalarLogger, check_rrd_path
from pursuit_mj.recording.rrd_read import read_entities
from pursuit_mj.render.episodes import run_episodes


def _plain_run(config, episodes, seed, policy_seed):
    """The episodes of run_episodes, stepped by hand with no recorder: per episode, snapshots per state."""
    env = PursuitEnv(config, n_worlds=1, seed=seed, auto_reset=False)
    policy = RandomPolicy(policy_seed)
    obs = env.reset()
    policy.reset(1)
    out = []
    for k in range(episodes):
        if k:
            obs = env.reset_worlds([0])
            policy.reset(1, np.array([0]))
        snaps = [env.snapshot(0)]
        while not env.done[0]:
            obs, *_ = env.step(policy.act(obs, env.obs_spec))
            snaps.append(env.snapshot(0))
        out.append(snaps)
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two quadrotor episodes recorded through run_episodes, and the same episodes stepped plainly."""
    config = default_config(fidelity="quadrotor", max_steps=6, layout=2)
    path = tmp_path_factory.mktemp("rrd") / "two.rrd"
    with RerunEpisodeRecording(path, trail_length=4) as rec:
        records = run_episodes(config, RandomPolicy(1), 2, seed=9, recording=rec, title="random")
    return config, path, records, read_entities(path), _plain_run(config, 2, 9, 1)


def test_every_episode_has_its_entities_and_both_timelines(recorded):
    config, _, records, ent, _ = recorded
    for k in range(2):
        p = f"/episode_{k}"
        for name in ("pursuer_0", "pursuer_1", "pursuer_2", "evader_0"):
            assert ent[f"{p}/drones/{name}"].n_rows == records[k].steps + 1
            assert ent[f"{p}/drones/{name}/body"].static
            assert ent[f"{p}/trails/{name}"].n_rows == records[k].steps + 1
            assert ent[f"{p}/velocity/{name}/commanded"].n_rows == records[k].steps + 1
            assert ent[f"{p}/thrust/{name}"].n_rows == records[k].steps + 1
        for name in ("pursuer_0", "pursuer_1", "pursuer_2"):
            assert f"{p}/perception/{name}/range" in ent and f"{p}/detections/{name}" in ent and f"{p}/rays/{name}" in ent
        for term in ("capture", "progress", "collision", "proximity", "spread"):
            assert ent[f"{p}/reward/{term}"].n_rows == records[k].steps + 1
        assert "Boxes3D:half_sizes" in ent[f"{p}/arena/boxes"].static or "Cylinders3D:radii" in ent[f"{p}/arena/cylinders"].static
        rows = ent[f"{p}/drones/pursuer_0"].rows
        assert rows["step"] == list(range(records[k].steps + 1))
        np.testing.assert_allclose(rows["sim_time"], np.arange(records[k].steps + 1) * config.control_dt, atol=1e-9)


def test_logged_values_equal_the_simulated_ones(recorded):
    _, _, _, ent, plain = recorded
    for k, snaps in enumerate(plain):
        p = f"/episode_{k}"
        pos = np.array([r[0] for r in ent[f"{p}/drones/pursuer_1"].rows["Transform3D:translation"]])
        np.testing.assert_allclose(pos, [s.pursuer_pos[1] for s in snaps], atol=1e-6)
        q = np.array([r[0] for r in ent[f"{p}/drones/evader_0"].rows["Transform3D:quaternion"]])  # x y z w
        np.testing.assert_allclose(q[:, [3, 0, 1, 2]], [s.evader_quat[0] for s in snaps], atol=1e-6)
        assert np.abs(q[:, :3]).max() > 1e-4, "quadrotor attitude is missing from the recording"
        thrust = np.array(ent[f"{p}/thrust/pursuer_2"].rows["Scalars:scalars"])
        np.testing.assert_allclose(thrust, [s.thrust[2] for s in snaps], rtol=1e-9)
        cmd = np.array(ent[f"{p}/velocity/pursuer_0/commanded"].rows["Scalars:scalars"])
        np.testing.assert_allclose(cmd, [s.commands[0] for s in snaps], rtol=1e-9)
        prog = np.array(ent[f"{p}/reward/progress"].rows["Scalars:scalars"])
        np.testing.assert_allclose(prog, [s.reward_terms["progress"] for s in snaps], rtol=1e-6)
        strips = ent[f"{p}/detections/pursuer_0"].rows["LineStrips3D:strips"]
        assert [len(r) for r in strips] == [int((s.known[0] & ~s.captured).sum()) for s in snaps]


def test_recording_does_not_change_the_trajectory(recorded):
    _, _, records, _, plain = recorded
    assert [r.steps + 1 for r in records] == [len(s) for s in plain]
    assert [r.outcome for r in records] == [s[-1].outcome for s in plain]


def test_episodes_are_findable_by_property_and_outcome_entity(recorded):
    from rerun.chunk import RrdReader

    _, path, records, ent, _ = recorded
    assert len(RrdReader(path).blueprints()) == 1, "no viewer layout (one tab per episode) in the file"
    for k, rec in enumerate(records):
        props = ent[f"/__properties/episode_{k}"].static
        assert props["outcome"] == [rec.outcome] and props["steps"] == [rec.steps] and props["seed"] == [rec.seed]
        assert props["policy"] == ["random"]
        log = ent[f"/episode_{k}/outcome"]
        assert log.rows["TextLog:text"] == [[f"{rec.outcome} after {rec.steps} steps"]]
        assert log.rows["step"] == [rec.steps]


def test_a_recording_abandoned_before_any_episode_leaves_no_file(tmp_path):
    with pytest.raises(RuntimeError, match="boom"):
        with RerunEpisodeRecording(tmp_path / "x.rrd") as rec:
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == [] and rec.kept is None
    assert "x.rrd was not written" in rec.summary()


def test_an_interrupted_recording_keeps_its_finished_episodes_beside_the_whole_one(tmp_path):
    """Ctrl-C (or any error) after some episodes: they stay readable under x.interrupted.rrd,
    marked as such; x.rrd, which only ever holds a whole run, keeps what an earlier run wrote."""
    earlier = tmp_path / "x.rrd"
    earlier.write_bytes(b"an earlier, whole recording")
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    with pytest.raises(KeyboardInterrupt):
        with RerunEpisodeRecording(earlier) as rec:
            for _ in range(2):
                buf = EpisodeBuffer()
                buf.append(env.snapshot(0))
                rec.add_episode(buf)
            raise KeyboardInterrupt
    partial = tmp_path / "x.interrupted.rrd"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.interrupted.rrd", "x.rrd"]  # no .part file left
    assert earlier.read_bytes() == b"an earlier, whole recording"
    assert rec.kept == partial and "the 2 episodes finished before it are in" in rec.summary()
    ent = read_entities(partial)
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" in ent
    assert ent["/__properties/interrupted"].static["finished_episodes"] == [2]

    partial_bytes = partial.read_bytes()
    with pytest.raises(KeyboardInterrupt):  # interrupted again: the earlier interrupted episodes were replaced
        with RerunEpisodeRecording(earlier) as again:
            buf = EpisodeBuffer()
            buf.append(env.snapshot(0))
            again.add_episode(buf)
            raise KeyboardInterrupt
    second = tmp_path / "x.interrupted-2.rrd"
    assert again.kept == second and partial.read_bytes() == partial_bytes
    assert f"the 1 episode finished before it is in {second}" in again.summary() and f"{partial} beside it keeps an earlier interrupted run's" in again.summary()
    assert read_entities(second)["/__properties/interrupted"].static["finished_episodes"] == [1]

    def interrupted_run():
        with pytest.raises(KeyboardInterrupt):
            with RerunEpisodeRecording(earlier) as rec:
                buf = EpisodeBuffer()
                buf.append(env.snapshot(0))
                rec.add_episode(buf)
                raise KeyboardInterrupt
        return rec

    third = interrupted_run()  # every earlier one is named
    assert third.kept == tmp_path / "x.interrupted-3.rrd"
    assert f"; {partial}, {second} beside it keep earlier interrupted runs' episodes" in third.summary()
    partial.unlink()  # the numbers still follow the runs when the first is deleted
    assert interrupted_run().kept == tmp_path / "x.interrupted-4.rrd"

    with RerunEpisodeRecording(earlier) as whole:  # a later run that ends: the interrupted ones are pointed out, kept
        buf = EpisodeBuffer()
        buf.append(env.snapshot(0))
        whole.add_episode(buf)
    kept = ", ".join(str(tmp_path / f"x.interrupted-{k}.rrd") for k in (2, 3, 4))
    assert whole.summary().endswith(f"; {kept} beside it keep earlier interrupted runs' episodes"), whole.summary()


def test_a_folder_where_the_interrupted_recording_would_go_is_refused_up_front(tmp_path, capsys):
    (tmp_path / "x.interrupted.rrd").mkdir()
    assert main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=3", "--no-video",
                 "--rerun", str(tmp_path / "x.rrd")]) == 2
    captured = capsys.readouterr()
    assert f"--rerun {tmp_path / 'x.rrd'}: {tmp_path / 'x.interrupted.rrd'} is a folder" in captured.err
    assert "episode 0" not in captured.out and sorted(p.name for p in tmp_path.iterdir()) == ["x.interrupted.rrd"]
    # refused before the videos' folder was made (an empty folder was left behind)
    assert main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=3", "-s",
                 f"{tmp_path / 'videos'}/", "--rerun", str(tmp_path / "x.rrd")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.interrupted.rrd"]


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # what a killed writer leaves; rerun reads it by a scan
def test_the_episodes_of_a_recording_killed_with_kill_9_stay_readable_and_the_next_run_names_them(tmp_path, capsys):
    """kill -9 left the finished episodes only in a hidden temporary file, which the next
    recording of the same name then deleted: they are now written under a visible name,
    flushed as each episode ends, and kept."""
    import subprocess
    import sys

    path = tmp_path / "x.rrd"
    code = ("import os, signal, sys\n"
            "from pursuit_mj.config import default_config\n"
            "from pursuit_mj.env import PursuitEnv\n"
            "from pursuit_mj.recording import EpisodeBuffer, RerunEpisodeRecording\n"
            "env = PursuitEnv(default_config(fidelity='point', max_steps=3), seed=0, auto_reset=False)\n"
            "env.reset()\n"
            "rec = RerunEpisodeRecording(sys.argv[1])\n"
            "for _ in range(2):\n"
            "    buf = EpisodeBuffer()\n"
            "    buf.append(env.snapshot(0))\n"
            "    rec.add_episode(buf)\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -9, proc.stderr[-2000:]
    (left,) = tmp_path.iterdir()
    assert re.fullmatch(r"x\.unfinished-\d+-[0-9a-f]{6}\.rrd", left.name), left.name
    ent = read_entities(left)
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" in ent
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    with RerunEpisodeRecording(path) as again:
        buf = EpisodeBuffer()
        buf.append(env.snapshot(0))
        again.add_episode(buf)
    assert f"{left} beside it holds what a recording killed before it finished had written" in again.summary()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([left.name, "x.rrd"])
    # eval says so too (it printed a "wrote" line of its own, render the recording's summary)
    capsys.readouterr()
    assert main(["eval", "--policy", "random", "--fidelity", "point", "--set", "max_steps=3", "--layouts", "0",
                 "--episodes", "1", "-q", "--rerun", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {path} (1 episode; open with: rerun {path})" in out and f"{left} beside it holds what" in out, out


@pytest.mark.parametrize("limit", [0, 20000])
def test_a_recording_that_does_not_fit_on_the_disk_is_an_error_naming_it(tmp_path, limit):
    """A full disk, played by a file size limit on a child process (no room at the start, or none
    for the first episode): a one-line error, no traceback, no file."""
    import subprocess
    import sys

    path = tmp_path / "r.rrd"
    code = ("import resource, signal, sys\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"  # a write past the limit then fails with EFBIG, as on a full disk
            f"resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.RLIM_INFINITY))\n"
            "from pursuit_cli import main\n"
            "sys.exit(main(['render', '--policy', 'random', '--fidelity', 'point', '--set', 'max_steps=30', '--episodes', '2',"
            " '--no-video', '--rerun', sys.argv[1]]))\n")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.returncode == 2 and f"pursuit-mj render: error: --rerun {path}: cannot write it" in proc.stderr
    assert "(rerun:" in proc.stderr  # its error, or that its flush timed out
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_recording_whose_closing_write_fails_says_its_episodes_are_lost(tmp_path):
    """The disk fills between the last episode and the stop: nothing is kept, and the summary says
    so instead of naming a file that does not exist."""
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()

    def full_disk(**kwargs):
        raise RuntimeError("Failed to write: No space left on device (os error 28)")

    with pytest.raises(KeyboardInterrupt):
        with RerunEpisodeRecording(tmp_path / "r.rrd") as rec:
            buf = EpisodeBuffer()
            buf.append(env.snapshot(0))
            rec.add_episode(buf)
            rec.stream.flush = full_disk
            raise KeyboardInterrupt
    assert rec.kept is None and list(tmp_path.iterdir()) == []
    assert rec.summary().startswith("the 1 episode recorded could not be written (Failed to write: No space left")
    assert f"neither {tmp_path / 'r.rrd'} nor {tmp_path / 'r.interrupted.rrd'} holds them" in rec.summary()


def test_a_recording_that_cannot_replace_the_file_under_its_name_keeps_its_episodes_beside_it(tmp_path):
    """A folder made under the name during the run: the finished file was deleted with every
    episode, and the error did not name --rerun; now the episodes stay, readable, in x.new.rrd,
    and the error and the summary say so."""
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    path, kept = tmp_path / "x.rrd", tmp_path / "x.new.rrd"
    with pytest.raises(ValueError) as raised:
        with RerunEpisodeRecording(path) as rec:
            for _ in range(2):
                buf = EpisodeBuffer()
                buf.append(env.snapshot(0))
                rec.add_episode(buf)
            path.mkdir()
    assert str(raised.value) == f"--rerun {path}: cannot replace it (Is a directory); what was written is kept in {kept}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.new.rrd", "x.rrd"] and rec.kept == kept
    ent = read_entities(kept)
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" in ent
    assert rec.summary().startswith(f"--rerun {path}: cannot replace it") and f"(2 episodes; open with: rerun {kept})" in rec.summary()


def refuse_renames_onto(path, monkeypatch) -> None:
    """Plays an immutable file at `path`: every rename of a finished file onto it is refused."""
    import os

    from pursuit_mj import io_utils

    replace = os.replace

    def refused(src, dst):
        if str(dst) == str(path):
            raise PermissionError(1, "Operation not permitted", str(src), None, str(dst))
        replace(src, dst)

    monkeypatch.setattr(io_utils.os, "replace", refused)


def test_render_names_the_rerun_flag_and_where_the_episodes_are_when_the_recording_cannot_replace_its_file(tmp_path, capsys, monkeypatch):
    """An immutable file under the name (played by a refused rename): exit 2, one line naming
    --rerun and the kept file, which holds the episodes."""
    path, kept = tmp_path / "x.rrd", tmp_path / "x.new.rrd"
    refuse_renames_onto(path, monkeypatch)
    assert main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=3", "--episodes", "2",
                 "--no-video", "--rerun", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"error: --rerun {path}: cannot replace it (Operation not permitted); what was written is kept in {kept}" in err, err
    assert "Traceback" not in err and sorted(p.name for p in tmp_path.iterdir()) == ["x.new.rrd"]
    ent = read_entities(kept)
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" in ent


def test_rrd_path_is_checked(tmp_path):
    with pytest.raises(ValueError, match="--rerun .*x.rr: expected a file name ending in .rrd"):
        check_rrd_path(tmp_path / "x.rr")
    blocker = tmp_path / "f"
    blocker.write_text("")
    with pytest.raises(ValueError, match="f exists and is not a folder"):
        check_rrd_path(blocker / "a.rrd")


def test_scalar_logger_streams_nested_metrics(tmp_path):
    path = tmp_path / "train.rrd"
    with RerunScalarLogger(path, run_name="tiny") as log:
        log.log(100, {"train": {"success": 0.25, "mean_steps": 300}, "lr": 3e-4, "skip": "text", "nan": math.nan})
        log.log(200, {"train": {"success": 0.5, "mean_steps": 250}, "lr": 2e-4})
        with pytest.raises(ValueError, match="step must be an integer in 0..2\\^63-1, got -1"):
            log.log(-1, {"lr": 1.0})
        with pytest.raises(ValueError, match="step must be an integer in 0..2\\^63-1"):
            log.log(2 ** 70, {"lr": 1.0})  # was an OverflowError from inside rerun
        with pytest.raises(ValueError, match="metrics must be a mapping of names to numbers, got None"):
            log.log(300, None)
        log.log(np.int64(300), {"lr": 1e-4})  # a numpy count, as a loop over np.arange gives it
    ent = read_entities(path)
    succ = ent["/train/train/success"].rows
    assert succ["env_steps"] == [100, 200] and succ["Scalars:scalars"] == [[0.25], [0.5]]
    assert ent["/train/lr"].rows["Scalars:scalars"] == [[3e-4], [2e-4], [1e-4]]
    assert "/train/skip" not in ent and "/train/nan" not in ent


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # what a killed writer leaves; rerun reads it by a scan
def test_scalar_rows_survive_a_kill_9_right_after_they_are_logged(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "train.rrd"
    code = ("import os, signal, sys; from pursuit_mj.recording import RerunScalarLogger\n"
            "log = RerunScalarLogger(sys.argv[1])\n"
            "for k in range(50): log.log(k, {'loss': float(k)})\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -9, proc.stderr[-2000:]
    assert read_entities(path)["/train/loss"].rows["env_steps"] == list(range(50))


def test_render_command_records_rerun_without_video(tmp_path, capsys):
    path = tmp_path / "r.rrd"
    code = main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=4", "--episodes", "3",
                 "--no-video", "--rerun", str(path), "-s", str(tmp_path / "unused")])
    assert code == 0 and "3 episodes" in capsys.readouterr().out
    assert {f"/__properties/episode_{k}" for k in range(3)} <= set(read_entities(path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd"]


@pytest.mark.parametrize("bad, message", [(["-m", "missing.pt"], "no such checkpoint file"), (["--versus", "nobody"], "not a policy of this table")])
def test_eval_refusing_its_policies_leaves_no_folder_for_its_recording(tmp_path, capsys, monkeypatch, bad, message):
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--fidelity", "point", "--set", "max_steps=4", "--rerun", "rec/e.rrd", *bad]) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_env_recorder_follows_a_multi_world_evaluation_loop(tmp_path):
    """The loop of pursuit_mj.evaluation.run_episodes (parallel worlds, restarts) with a recorder attached."""
    config = default_config(fidelity="point", max_steps=5, random_obstacles=0)

    def loop(recorder_path=None, max_episodes=None):
        env = PursuitEnv(config, n_worlds=3, seed=4, auto_reset=False)
        policy = RandomPolicy(2)
        rec = None
        obs = env.reset()
        if recorder_path:
            rec = EnvRecorder(RerunEpisodeRecording(recorder_path), env, {"policy": "random"}, max_episodes)
            rec.started(range(3))
        done, started, finals = [], 3, []
        while len(done) < 5:
            obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
            if rec:
                rec.stepped(info)
            for r in info["episodes"]:
                done.append(r)
                finals.append(env.snapshot(r.world).evader_pos.copy())
            restart = [r.world for r in info["episodes"]][: max(5 - started, 0)]
            if restart:
                obs = env.reset_worlds(restart)
                started += len(restart)
                if rec:
                    rec.started(restart)
        if rec:
            rec.recording.close()
        return done, finals

    plain, finals = loop()
    recorded, _ = loop(tmp_path / "eval.rrd", max_episodes=4)
    assert [(r.world, r.episode, r.steps, r.outcome) for r in plain] == [(r.world, r.episode, r.steps, r.outcome) for r in recorded]
    ent = read_entities(tmp_path / "eval.rrd")
    props = [ent[f"/__properties/episode_{k}"].static for k in range(4)]
    assert "/__properties/episode_4" not in ent, "max_episodes was not respected"
    assert sorted(p["started"][0] for p in props) == [0, 1, 2, 3]  # the order they began in
    assert all(p["started"] == [p["world"][0]] for p in props if p["episode"][0] == 0)  # worlds 0-2 began first
    for k, p in enumerate(props):
        i = next(i for i, r in enumerate(plain) if r.world == p["world"][0] and r.episode == p["episode"][0])
        assert p["steps"] == [plain[i].steps]
        last = ent[f"/episode_{k}/drones/evader_0"].rows["Transform3D:translation"][-1][0]
        np.testing.assert_allclose(last, finals[i][0], atol=1e-6)
    with RerunEpisodeRecording(tmp_path / "x.rrd") as rec:
        with pytest.raises(ValueError, match="auto_reset=False"):
            EnvRecorder(rec, PursuitEnv(config, seed=0))


def test_obstacles_are_coloured_by_origin_as_in_the_frames(recorded):
    config, _, records, ent, plain = recorded
    layout = plain[0][0].layout
    packed = list(ent["/episode_0/arena/boxes"].static.get("Boxes3D:colors", []))
    packed += list(ent["/episode_0/arena/cylinders"].static.get("Cylinders3D:colors", []))
    rgb = [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in packed]  # rerun packs 0xRRGGBBAA
    assert len(rgb) == len(layout.obstacles) and layout.n_random > 0
    assert rgb.count(rgb255(OBSTACLE_RGBA["random"])) == layout.n_random
    assert rgb.count(rgb255(OBSTACLE_RGBA["fixed"])) == len(layout.obstacles) - layout.n_random


def test_env_recorder_and_recording_refuse_arguments_of_the_wrong_kind(tmp_path):
    env = PursuitEnv(default_config(fidelity="point", max_steps=3), seed=0, auto_reset=False)
    with pytest.raises(ValueError, match="trail length: expected an integer >= 1 step, got 2.5"):
        RerunEpisodeRecording(tmp_path / "x.rrd", trail_length=2.5)
    with RerunEpisodeRecording(tmp_path / "x.rrd") as rec:
        for kwargs, said in (({"max_episodes": "3"}, "max_episodes: expected an integer >= 1 or None, got '3'"),
                             ({"label": "x"}, "EnvRecorder label: expected a mapping"),
                             ({"env": object()}, "EnvRecorder env: expected a PursuitEnv, got object")):
            with pytest.raises(ValueError, match=said):
                EnvRecorder(rec, kwargs.pop("env", env), **kwargs)
        with pytest.raises(ValueError, match="EnvRecorder recording: expected a RerunEpisodeRecording, got 'x.rrd'"):
            EnvRecorder("x.rrd", env)


def test_two_recordings_of_one_name_in_one_process_do_not_share_a_file(tmp_path):
    """Both streamed into NAME.unfinished-PID.rrd: the first closed onto a corrupt x.rrd, the second failed."""
    env = PursuitEnv(default_config(fidelity="point", max_steps=3), seed=0, auto_reset=False)
    env.reset()
    a, b = RerunEpisodeRecording(tmp_path / "x.rrd"), RerunEpisodeRecording(tmp_path / "x.rrd")
    for rec, n in ((a, 2), (b, 1)):
        for _ in range(n):
            buf = EpisodeBuffer()
            buf.append(env.snapshot(0))
            rec.add_episode(buf)
    a.close()
    assert {"/episode_0/outcome", "/episode_1/outcome"} <= set(read_entities(tmp_path / "x.rrd"))
    b.close()
    ent = read_entities(tmp_path / "x.rrd")
    assert "/episode_0/outcome" in ent and "/episode_1/outcome" not in ent  # b's whole recording, the later one
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.rrd"]


def test_an_unfinished_recording_left_under_this_processs_pid_is_kept_and_named(tmp_path):
    """A killed run whose pid comes round again (in a container, every start): its file was
    taken as this process's own, truncated and renamed over x.rrd."""
    import os

    left = tmp_path / f"x.unfinished-{os.getpid()}-abc123.rrd"
    left.write_bytes(b"the killed run's episodes")
    env = PursuitEnv(default_config(fidelity="point", max_steps=3), seed=0, auto_reset=False)
    env.reset()
    with RerunEpisodeRecording(tmp_path / "x.rrd") as rec:
        buf = EpisodeBuffer()
        buf.append(env.snapshot(0))
        rec.add_episode(buf)
    assert left.read_bytes() == b"the killed run's episodes"
    assert f"{left} beside it holds what a recording killed before it finished had written" in rec.summary()


def test_a_scalar_log_is_not_refused_for_a_folder_where_episode_recordings_keep_interrupted_runs(tmp_path):
    """The interrupted-name check moved into check_rrd_path refused train --rerun's metrics.rrd too,
    which never writes an interrupted file."""
    (tmp_path / "metrics.interrupted.rrd").mkdir()
    RerunScalarLogger(tmp_path / "metrics.rrd").close()
    with pytest.raises(ValueError, match="metrics.interrupted.rrd is a folder"):
        RerunEpisodeRecording(tmp_path / "metrics.rrd")


def test_render_trail_of_n_steps_records_trails_of_n_steps(tmp_path):
    """render --trail N: the recording's trails, like the frames', span the last N decision steps (N + 1 points)."""
    path = tmp_path / "t.rrd"
    assert main(["render", "--policy", "random", "--fidelity", "point", "--set", "max_steps=5", "--trail", "2",
                 "--no-video", "--rerun", str(path)]) == 0
    rows = read_entities(path)["/episode_0/trails/pursuer_0"].rows
    assert [len(strips[0]) for strips in rows["LineStrips3D:strips"]] == [1, 2, 3, 3, 3, 3]


def test_the_summary_of_an_interrupted_recording_of_one_episode_says_it_in_the_singular(tmp_path):
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    with pytest.raises(KeyboardInterrupt):
        with RerunEpisodeRecording(tmp_path / "x.rrd") as rec:
            buf = EpisodeBuffer()
            buf.append(env.snapshot(0))
            rec.add_episode(buf)
            raise KeyboardInterrupt
    assert rec.summary().startswith(f"interrupted: the 1 episode finished before it is in {tmp_path / 'x.interrupted.rrd'} ")


def test_eval_prints_and_writes_its_table_when_its_recording_cannot_replace_its_file(tmp_path, capsys, monkeypatch):
    """The table was lost (neither printed nor written) when only the recording failed at the end;
    now the table comes first, then the one-line error naming --rerun (exit 2)."""
    path, table = tmp_path / "x.rrd", tmp_path / "t.csv"
    refuse_renames_onto(path, monkeypatch)
    assert main(["eval", "--policy", "random", "--fidelity", "point", "--set", "max_steps=3", "--episodes", "2",
                 "--layouts", "0", "--worlds", "2", "--csv", str(table), "--rerun", str(path)]) == 2
    out, err = capsys.readouterr()
    assert "random" in out and f"wrote {table}" in out, out
    assert table.read_text().count("\n") == 2  # the header and the one row
    assert f"error: --rerun {path}: cannot replace it (Operation not permitted)" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv", "x.new.rrd"]


def test_docs_name_every_key_of_an_episode_s_recording_property(recorded):
    """docs/rendering.md listed 'outcome, steps, seed, layout, policy, returns': the property also
    carries world, episode (the world's own episode count, so episode_2 could read episode 1),
    fidelity, captured and time_to_capture_s, which a reader of the file met unexplained."""
    from pathlib import Path

    _, _, _, ent, _ = recorded
    text = (Path(__file__).resolve().parents[1] / "docs" / "rendering.md").read_text()
    start = text.index("described by the recording property `episode_k`")
    paragraph = text[start:text.index("\n\n", start)]
    named = set(re.findall(r"`([a-z_<>]+)`", paragraph))
    keys = {re.sub(r"^return_.*", "return_<term>", k) for k in ent["/__properties/episode_0"].static}
    keys |= {"started", "time_to_capture_s"}  # eval's recordings; successes only
    assert keys - named == set(), f"docs/rendering.md does not name {sorted(keys - named)}"


@pytest.mark.parametrize("writer", ["scalars", "episodes"])
def test_a_recording_whose_file_stops_growing_is_an_error_not_a_hang(tmp_path, writer):
    """A full disk while a recording streams (played by a file size limit on a child process):
    rerun 0.41's flush without a timeout, and its disconnect, could wait forever once its file
    writer had died (train --rerun on a full disk hung for good, deaf to Ctrl-C and SIGTERM).
    Each flush is bounded (lowered here to 2 s), a failed stream is never disconnected, and the
    failure is the one-line error naming the file (CannotWrite, a ValueError)."""
    import subprocess
    import sys

    path = tmp_path / "m.rrd"
    code = ("import os, resource, signal, sys\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (100000, resource.RLIM_INFINITY))\n"
            "from pursuit_mj.config import default_config\n"
            "from pursuit_mj.env import PursuitEnv\n"
            "from pursuit_mj.recording import EpisodeBuffer, RerunEpisodeRecording, RerunScalarLogger, unfinished\n"
            "unfinished.FLUSH_TIMEOUT_S = 2.0\n"
            "env = PursuitEnv(default_config(fidelity='point', max_steps=3), seed=0, auto_reset=False)\n"
            "env.reset()\n"
            "rec = RerunScalarLogger(sys.argv[1]) if sys.argv[2] == 'scalars' else RerunEpisodeRecording(sys.argv[1])\n"
            "try:\n"
            "    for i in range(5000):\n"
            "        if sys.argv[2] == 'scalars':\n"
            "            rec.log(i, {f'k{j}': float(i * j) for j in range(60)})\n"
            "        else:\n"
            "            buf = EpisodeBuffer()\n"
            "            buf.append(env.snapshot(0))\n"
            "            rec.add_episode(buf)\n"
            "except ValueError as exc:\n"
            "    print('refused:', exc, flush=True)\n"
            "    rec.close(ok=False) if sys.argv[2] == 'episodes' else rec.close()\n"
            "    assert unfinished.any_failed()\n"
            "    os._exit(3)\n")  # rerun's own shutdown would wait on the dead writer: pursuit_cli.main ends so
    proc = subprocess.run([sys.executable, "-c", code, str(path), writer], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 3, (proc.returncode, proc.stdout[-1000:], proc.stderr[-2000:])
    assert f"{path}: cannot write it" in proc.stdout and "(rerun:" in proc.stdout, proc.stdout  # its error, or the flush timed out


def test_a_command_whose_recording_fails_ends_with_its_error(tmp_path):
    """`pursuit-mj render --rerun` on a full disk (a file size limit): the process ends, exit status
    2, with the error naming the file; rerun's shutdown at exit could wait on the dead writer forever."""
    import os
    import resource
    import signal
    import subprocess
    import sys

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (100000, resource.RLIM_INFINITY))

    path = tmp_path / "r.rrd"
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    proc = subprocess.run([sys.executable, "-m", "pursuit_cli", "render", "--policy", "random", "--fidelity", "point",
                           "--set", "max_steps=20", "--episodes", "40", "--no-video", "--rerun", str(path)],
                          capture_output=True, text=True, timeout=60, preexec_fn=limited, env=env)
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert f"pursuit-mj render: error: --rerun {path}: cannot write it" in proc.stderr and "(rerun:" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_recording_whose_first_episode_cannot_be_written_is_not_called_interrupted(tmp_path):
    """A full disk at the first episode's write: render printed 'interrupted before any episode
    finished: r.rrd was not written' above its error, though nothing was interrupted and the
    episode had finished (its video was written)."""
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    path = tmp_path / "r.rrd"

    def full_disk(**kwargs):
        raise RuntimeError("Failed to write: No space left on device (os error 28)")

    with pytest.raises(ValueError, match="cannot write it"):
        with RerunEpisodeRecording(path) as rec:
            rec.stream.flush = full_disk
            buf = EpisodeBuffer()
            buf.append(env.snapshot(0))
            rec.add_episode(buf)
    assert "interrupted" not in rec.summary()
    assert rec.summary() == f"no episode was recorded: {path} could not be written (Failed to write: No space left on device (os error 28))"
    assert list(tmp_path.iterdir()) == []


def _slow_flush(stream, tmp, grows: bool):
    """rerun's flush of `stream` as a slow disk makes it: each call waits its timeout out and
    reports it as rerun does ('Flush timed out'), the file under way growing by a byte meanwhile
    (`grows`) or not, until the fourth call, which flushes for real."""
    real = stream.flush
    calls = []

    def flush(timeout_sec):
        calls.append(timeout_sec)
        if len(calls) >= 4 and grows:
            return real(timeout_sec=timeout_sec)
        import time

        time.sleep(timeout_sec)
        if grows:
            with open(tmp, "ab") as f:
                f.write(b"\0")  # what the writer got out meanwhile
        raise RuntimeError("Flush timed out - not all log messages were sent")

    stream.flush = flush
    return calls


@pytest.mark.parametrize("grows", [True, False])
def test_a_slow_flush_that_still_writes_is_waited_for_and_a_stalled_one_is_called_timed_out(tmp_path, monkeypatch, grows):
    """The bound on a flush (unfinished.FLUSH_TIMEOUT_S, lowered here to 0.3 s) took a slow disk
    for a failed one: an episode whose flush outlasted it was lost as 'cannot write it'. A flush
    now fails only once nothing reached its file for that long, and says it stalled."""
    from pursuit_mj.recording import unfinished

    monkeypatch.setattr(unfinished, "FLUSH_TIMEOUT_S", 0.3)
    monkeypatch.setattr(unfinished, "FLUSH_POLL_S", 0.15, raising=False)
    monkeypatch.setattr(unfinished, "FAILED_STREAMS", [])
    config = default_config(fidelity="point", max_steps=3)
    env = PursuitEnv(config, seed=0, auto_reset=False)
    env.reset()
    path = tmp_path / "r.rrd"
    rec = RerunEpisodeRecording(path)
    calls = _slow_flush(rec.stream, rec._tmp, grows)
    buf = EpisodeBuffer()
    buf.append(env.snapshot(0))
    if grows:  # 4 waits of 0.15 s, 0.6 s in all: twice the bound, the file growing all along
        rec.add_episode(buf)
        assert len(calls) == 4
        del rec.stream.flush  # the rest as a quick disk
        assert rec.close() == path and rec.n_episodes == 1
        assert not unfinished.any_failed()
        return
    with pytest.raises(ValueError) as err:
        rec.add_episode(buf)
    assert str(err.value).startswith(f"--rerun {path}: cannot write it: the flush timed out, nothing reached it for 0.3 s "
                                     f"(rerun: Flush timed out")
    assert 2 <= len(calls) <= 20 and unfinished.any_failed()  # (rerun's own batcher may still write at first)
    rec.close(ok=False)
    assert list(tmp_path.iterdir()) == []


def test_a_python_caller_whose_recording_failed_exits_promptly_with_the_error(tmp_path):
    """A Python script (no CLI, which ends by os._exit) recording on a full disk (a file size
    limit) got the error, and then its process hung at exit now and then (about 1 run in 3 here):
    rerun's shutdown at exit, or the failed stream's __del__ as the interpreter ended, waited on
    the dead file writer forever. Several recordings fail here, so that at least one (almost
    surely) fails in the way that hung."""
    import subprocess
    import sys

    code = ("import resource, signal, sys\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (100000, resource.RLIM_INFINITY))\n"
            "from pursuit_mj.recording import RerunScalarLogger, unfinished\n"
            "unfinished.FLUSH_TIMEOUT_S = 1.0\n"
            "for k in range(5):\n"
            "    rec = RerunScalarLogger(f'{sys.argv[1]}/m{k}.rrd')\n"
            "    try:\n"
            "        for i in range(5000):\n"
            "            rec.log(i, {f'k{j}': float(i * j) for j in range(60)})\n"
            "    except ValueError as exc:\n"
            "        print('refused:', exc, flush=True)\n"
            "    rec.close()\n"
            "assert unfinished.any_failed()\n")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, (proc.stdout[-1000:], proc.stderr[-2000:])
    assert proc.stdout.count("refused:") == 5 and "cannot write it" in proc.stdout
