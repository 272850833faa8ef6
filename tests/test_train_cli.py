"""The train, study, demo and bench-train commands end to end on tiny settings."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pursuit_cli import main

TINY = ["task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30",
        "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=1",
        "run.validate_every=0", "run.validation_episodes=2"]


def sets(items):
    return sum((["--set", s] for s in items), [])


@pytest.mark.parametrize("command", ["train", "study", "demo"])
def test_help(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert command in capsys.readouterr().out


def test_train_then_resume_from_the_command_line(tmp_path, capsys):
    base = ["train", "--no-progress", "--name", "cli", "--total-steps", "32"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(base) == 0
    out = capsys.readouterr().out
    assert "2 updates" not in out and "done: 1 update," in out and "best validation success" in out
    assert "the heuristic team" in out and "capture steps per episode" in out  # validation paired with it
    assert main(["train", "--no-progress", "--resume", str(tmp_path / "cli"), "--total-steps", "64"]) == 0
    rows = [json.loads(x) for x in (tmp_path / "cli" / "metrics.jsonl").read_text().splitlines()]
    assert [r["update"] for r in rows] == [1, 2]
    # validate_every 0: only the closing validation, and the summary keeps its time apart
    counters = torch.load(tmp_path / "cli" / "last.pt", weights_only=True)["counters"]
    spent = sum(r["validation"]["seconds"] for r in rows if "validation" in r)
    assert [r["update"] for r in rows if "validation" in r] == [1, 2]  # each run's last update
    assert counters["validation_seconds"] == pytest.approx(spent) and counters["seconds"] > spent
    out = capsys.readouterr().out
    assert "s training, " in out and "of it in this session" in out  # the resumed run says what this session spent
    capsys.readouterr()
    assert main(["train", "--resume", str(tmp_path / "cli"), "--set", "ppo.lr=1e-3"]) == 2
    assert "stored config" in capsys.readouterr().err
    assert main(base + ["--resume", "--set", "ppo.lr=1e-3"]) == 2  # config differs from the stored run
    captured = capsys.readouterr()
    assert "differs from the stored run's: ppo.lr 0.001 (asked) vs 0.0003 (stored)" in captured.err
    assert "resumed" not in captured.out  # refused before anything is restored
    assert main(base + ["--resume", "--total-steps", "96"]) == 0
    assert json.loads((tmp_path / "cli" / "metrics.jsonl").read_text().splitlines()[-1])["update"] == 3


def test_train_show_config_and_bad_input(tmp_path, capsys):
    assert main(["train", "--config", "classic", "--set", "ppo.lr=1e-4", "--fidelity", "point", "-sc"]) == 0
    out = capsys.readouterr().out
    assert "lr: 0.0001" in out and "fidelity: point" in out
    assert main(["train", "--config", "classic", "--set", "ppo.clip=7"]) == 2
    assert "--set ppo.clip=7: key 'ppo.clip': 7.0 is out of range" in capsys.readouterr().err
    assert main(["train", "--config", "no_such_regime"]) == 2
    assert main(["train", "--resume", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert "no such run folder" in err and "Traceback" not in err
    # one --layout would be ignored by --random-layout; several are the pool it draws from
    assert main(["train", "--config", "classic", "--layout", "2", "--random-layout", "-sc"]) == 2
    err = capsys.readouterr().err
    assert "--layout 2 with --random-layout" in err and "would be ignored" in err and len(err.splitlines()) == 1
    assert main(["train", "--config", "classic", "--layout", "0", "--layout", "2", "--random-layout", "-sc"]) == 0
    assert "random_layout: true" in capsys.readouterr().out
    # a layout that cannot be loaded is named with its flag (it was "layout 7: ..." from deep in the env)
    for given in (["--layout", "0", "--layout", "7"], ["--layout", "nosuch.yaml"]):
        assert main(["train", "--config", "classic", "--set", f"run.runs_dir={tmp_path}", *given]) == 2
        err = capsys.readouterr().err
        assert f"--layout {given[-1]}: layout" in err and len(err.splitlines()) == 1, err
    assert not any(tmp_path.glob("classic*"))  # refused before the run folder was made


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    root = tmp_path_factory.mktemp("model")
    assert main(["train", "--no-progress", "--name", "m", "--total-steps", "32"] + sets(TINY + [f"run.runs_dir={root}"])) == 0
    return root / "m" / "best.pt"


def test_demo_of_a_model_of_one_s_own_does_not_call_the_shipped_recipe_its_model_s(tiny_model, capsys):
    """The closing next steps said 'train --config belief ... (how the demo's model was made)' under a
    table of a model the user had just trained with another config."""
    assert main(["demo", "--model", str(tiny_model), "--episodes", "1", "--worlds", "1", "--layouts", "0", "--no-shield",
                 "--no-heuristic", "--fidelity", "point", "--set", "max_steps=5"]) == 0
    steps = capsys.readouterr().out.split("Next steps:", 1)[1]
    assert "demo's model" not in steps
    made = [line for line in steps.splitlines() if "was made" in line]
    assert made and all("pretrained/pursuers.pt" in line for line in made), made


def test_demo_prints_the_table_and_how_to_train(tiny_model, capsys, monkeypatch):
    from pursuit_cli import demo

    code = main(["demo", "--model", str(tiny_model), "--episodes", "2", "--worlds", "2", "--layouts", "0", "1",
                 "--fidelity", "point", "--set", "max_steps=20"])
    assert code == 0
    captured = capsys.readouterr()
    out = captured.out
    assert f"model: m = {tiny_model}\n" in captured.err  # which file the table's rows are
    assert "heuristic" in out and "m " in out and "m+shield " in out and "pursuit-mj train" in out
    assert "paired with heuristic on the same episodes" in out
    assert "use --episodes 150 for the reference study's sample size" in out
    assert main(["demo", "--model", str(tiny_model.parent / "missing.pt")]) == 2
    code = main(["demo", "--model", str(tiny_model), "--episodes", "1", "--worlds", "1", "--layouts", "0", "--no-shield",
                 "--no-heuristic", "--fidelity", "point", "--set", "max_steps=5"])
    out = capsys.readouterr().out
    assert code == 0 and "+shield" not in out
    assert "use --episodes" in out  # 1 of the reference study's 150
    monkeypatch.setattr(demo, "REFERENCE_EPISODES", 1)  # played at the reference size: no such advice
    assert main(["demo", "--model", str(tiny_model), "--episodes", "1", "--worlds", "1", "--layouts", "0", "--no-heuristic",
                 "--fidelity", "point", "--set", "max_steps=5"]) == 0
    assert "use --episodes" not in capsys.readouterr().out
    # with no --model it shows the shipped policy and says so
    code = main(["demo", "--episodes", "1", "--worlds", "1", "--layouts", "0", "--no-heuristic", "--fidelity", "point",
                 "--set", "max_steps=5"])
    assert code == 0 and "pursuers.pt (the small policy shipped with the repository" in capsys.readouterr().err


@pytest.mark.parametrize("args, message", [
    (["--layouts", "0", "7"], "--layouts: layout 7: no built-in layout"),
    (["--layouts", "0", "0"], "--layouts: 0 is given twice"),
    (["--layouts", "0", "00"], "--layouts: 00 is given twice (as 0 and 00)"),
    (["--worlds", "0"], "--worlds: expected an integer >= 1"),
])
def test_demo_refuses_bad_layouts_and_worlds_before_any_episode(tiny_model, capsys, args, message):
    assert main(["demo", "--model", str(tiny_model), "--fidelity", "point", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "[demo]" not in err and len(err.strip().splitlines()) == 1


def test_eval_command_loads_a_checkpoint_with_other_team_sizes(tiny_model, capsys):
    code = main(["eval", "--model", str(tiny_model), "--episodes", "2", "--worlds", "2", "--pursuers", "4",
                 "--evaders", "2", "--fidelity", "point", "--set", "max_steps=20", "-q"])
    assert code == 0
    assert "m " in capsys.readouterr().out


def test_bench_train_prints_rollout_and_update_rates(capsys):
    code = main(["bench", "train", "--fidelity", "point", "--updates", "1", "--n-envs", "2"] + sets(TINY[1:-2]))
    assert code == 0
    out = capsys.readouterr().out
    assert "rollout ag-steps/s" in out and "s per update" in out and "bare env ag-steps/s" in out
    assert "aims point, in turn: update faster than its rollout" in out
    assert "aims point, overlapped: update faster than its rollout" in out  # both collection modes by default
    assert "measured point, in turn: 1 update after one warm-up" in out  # it said '1 updates'


def test_bench_train_measures_a_dagger_config_in_turn_once(capsys):
    """DAgger always collects in turn: --collection both printed two 'in turn' rows of one configuration."""
    code = main(["bench", "train", "--config", "imitate", "--fidelity", "point", "--updates", "1", "--n-envs", "2"]
                + sets(TINY[1:-2]))
    assert code == 0
    out = capsys.readouterr().out
    assert "note: config imitate trains by DAgger, which always collects in turn: measured in turn only" in out
    assert out.count("aims point, in turn:") == 1 and "aims point, overlapped" not in out


def test_export_writes_a_small_policy_only_checkpoint(tiny_model, tmp_path, capsys):
    from pursuit_mj.obs_spec import ObsSpec
    from train.checkpoint import load_checkpoint
    from train.policy import load_policy

    out = tmp_path / "small.pt"
    assert main(["train", "--export", str(tiny_model), str(out)]) == 0
    data = load_checkpoint(out)
    assert "optimizer" not in data and "critic" not in data
    assert out.stat().st_size < tiny_model.stat().st_size / 2
    spec = ObsSpec.make(3, 1, 16)
    full, small = load_policy(tiny_model, spec), load_policy(out, spec)
    obs = torch.randn(2, 3, spec.dim).numpy()
    assert (full.act(obs, spec) == small.act(obs, spec)).all()


def test_export_to_a_name_ending_in_a_slash_is_refused_not_written_as_a_file_of_that_name(tiny_model, tmp_path, capsys):
    """--export best.pt exports/ (a folder not made yet) wrote the policy to a file called 'exports'."""
    out = f"{tmp_path}/exports/"
    assert main(["train", "--export", str(tiny_model), out]) == 2
    assert f"--export OUT path {out}: ends in '/', which names a folder" in capsys.readouterr().err
    assert not (tmp_path / "exports").exists()


@pytest.mark.parametrize("extra", [["--resume", "runs/classic"], ["--config", "classic"], ["--total-steps", "2e6"],
                                   ["--set", "ppo.lr=1e-4"], ["-sc"], ["--name", "x"], ["--random-layout"]])
def test_export_with_training_flags_is_refused_naming_them(tiny_model, tmp_path, capsys, extra):
    out = tmp_path / "small.pt"
    assert main(["train", "--export", str(tiny_model), str(out)] + extra) == 2
    err = capsys.readouterr().err
    assert f"--export writes a policy-only copy and exits; {extra[0]} would be ignored" in err, err
    assert not out.exists()


def test_train_streams_its_scalars_to_rerun(tmp_path, capsys):
    from pursuit_mj.recording.rrd_read import read_entities

    args = ["train", "--no-progress", "--rerun", "--name", "rr", "--total-steps", "64"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(args) == 0
    rows = [json.loads(x) for x in (tmp_path / "rr" / "metrics.jsonl").read_text().splitlines()]
    ent = read_entities(tmp_path / "rr" / "metrics.rrd")
    steps = ent["/train/agent_steps"].rows
    assert steps["world_steps"] == [r["world_steps"] for r in rows]  # the timeline was named env_steps
    assert steps["Scalars:scalars"] == [[float(r["agent_steps"])] for r in rows]
    # a resumed run's file starts afresh and holds the earlier curves too
    assert main(["train", "--no-progress", "--resume", str(tmp_path / "rr"), "--total-steps", "128", "--rerun"]) == 0
    rows = [json.loads(x) for x in (tmp_path / "rr" / "metrics.jsonl").read_text().splitlines()]
    steps = read_entities(tmp_path / "rr" / "metrics.rrd")["/train/agent_steps"].rows
    assert len(rows) >= 2 and steps["world_steps"] == [r["world_steps"] for r in rows]


def test_a_model_used_in_another_task_than_it_learned_says_so(tiny_model, capsys):
    assert main(["eval", "--model", str(tiny_model), "--layouts", "0", "--episodes", "1", "--fidelity", "point",
                 "--pursuers", "2", "--set", "max_steps=10", "-q", "--observability", "full", "-ev", "0.5",
                 "--set", "drone_mass=0.033", "--set", "command_latency=0.1"]) == 0
    err = capsys.readouterr().err
    assert ("was trained with observability partial (this task: full), evader_speed 0.6 (this task: 0.5), "
            "drone_mass 0.027 (this task: 0.033), command_latency 0.0 (this task: 0.1)") in err


def test_a_flight_is_not_told_of_the_latency_a_model_learned_with(tiny_model, capsys):
    """A flight has no command_latency (its delay is the real loop's), so the note would compare
    the model's with a 0 that means nothing there; in simulation it is told."""
    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec

    task = default_config(n_pursuers=2, fidelity="point", command_latency=0.1)
    spec = ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays)
    load_model(tiny_model, spec, task)
    assert "command_latency 0.0 (this task: 0.1)" in capsys.readouterr().err
    load_model(tiny_model, spec, task, flight=True)
    assert "command_latency" not in capsys.readouterr().err


def test_a_model_used_at_another_decision_interval_or_sight_than_it_learned_says_so(tiny_model, capsys):
    """The decision interval, the rays' reach, detection sharing and position noise change what a
    pursuer's observation means and how long an action lasts: a model used at other values (render's
    --delta-t, say) was told nothing, as it is of other speeds."""
    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec

    task = default_config(n_pursuers=2, fidelity="point", control_dt=0.2, ray_range=1.5, share_detections=False,
                          position_noise=0.05)
    load_model(tiny_model, ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays), task)
    assert ("control_dt 0.1 (this task: 0.2), ray_range 2.0 (this task: 1.5), share_detections True (this task: False), "
            "position_noise 0.0 (this task: 0.05)") in capsys.readouterr().err


def test_a_model_used_with_another_field_of_view_says_it_in_degrees(tiny_model, capsys):
    """The note printed the angles as stored: 'field_of_view 6.283185307179586 (this task: 2.0943951)'."""
    import math

    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec

    task = default_config(n_pursuers=2, fidelity="point", field_of_view=math.radians(120))
    load_model(tiny_model, ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays), task)
    assert "field_of_view 360 deg (this task: 120 deg)" in capsys.readouterr().err


def test_a_model_used_with_other_missed_detections_or_shared_teammates_says_so(tiny_model, capsys):
    """miss_probability (the hard preset's 20 % missed detections) and share_teammates (every teammate
    known exactly) change what a pursuer's observation holds, as the other perception keys do, but a
    model trained without them was evaluated under the hard preset with a note that left them out."""
    from pursuit_cli.common import TRAINED_TASK_KEYS, load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec
    from pursuit_mj.sensing import PERCEPTION_KEYS

    task = default_config(n_pursuers=2, fidelity="point", miss_probability=0.2, share_teammates=True)
    load_model(tiny_model, ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays), task)
    err = capsys.readouterr().err
    assert "share_teammates False (this task: True)" in err and "miss_probability 0.0 (this task: 0.2)" in err, err
    assert set(PERCEPTION_KEYS) <= set(TRAINED_TASK_KEYS)  # what the pursuers perceive, every key of it


def test_an_empty_train_config_file_is_refused(tmp_path, capsys):
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing yet\n")
    assert main(["train", "--config", str(empty), "-sc"]) == 2
    assert "empty.yaml: the file is empty" in capsys.readouterr().err


@pytest.mark.parametrize("flag, value, words", [("--total-steps", "inf", "whole number of steps"),
                                                ("--total-steps", "1e400", "whole number of steps"),
                                                ("--max-minutes", "-1", "minutes >= 0")])
def test_a_step_count_or_time_limit_out_of_range_is_refused_naming_the_flag(flag, value, words, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--config", "classic", flag, value, "-sc"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and words in err and "Traceback" not in err


def test_flags_that_would_be_ignored_or_end_in_a_traceback_are_refused_naming_them(tmp_path, capsys):
    base = ["train", "--no-progress", "--name", "r", "--total-steps", "32"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(base) == 0
    run_dir = tmp_path / "r"
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "a_file").write_text("x")
    for argv, words in (
        (["train", "--resume", str(run_dir), "-sc"], "does not resume"),
        (["train", "--resume", str(run_dir / "best.pt")], "resumes from its last.pt, not best.pt"),
        (["train", "--export", str(run_dir / "best.pt"), str(tmp_path / "a_folder")], "is a folder"),
        (["study", "--budget-minutes", "1", "--out", str(tmp_path / "a_file")], "not a folder"),
    ):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err, err
    assert [json.loads(x)["update"] for x in (run_dir / "metrics.jsonl").read_text().splitlines()] == [1]  # nothing resumed


def test_bench_train_cpu_ratio_sets_as_many_bare_env_rollouts_as_training_ones(monkeypatch):
    """Overlapped, the rollout after the warm-up is collected during the warm-up update, before
    any CPU reading; the bare env must be charged the rollouts the training CPU holds, no more.
    Here a rollout 'costs' 1 CPU second in the worker and a bare-env rollout 1 too: ratio 1."""
    import types

    import pursuit_cli.benchmarks.train as bench
    from train.rollout_worker import RolloutWorker

    started = [0]
    start = RolloutWorker.start

    def counting_start(self, model):
        started[0] += 1
        start(self, model)

    monkeypatch.setattr(RolloutWorker, "start", counting_start)
    monkeypatch.setattr(bench, "_child_cpu_s", lambda pid: float(started[0]) if pid is not None else 0.0)
    monkeypatch.setattr(bench, "_bare_env_block", lambda env, steps, rng: (0.01, 1.0))
    monkeypatch.setattr(bench, "time", types.SimpleNamespace(perf_counter=bench.time.perf_counter, process_time=lambda: 0.0))
    for overlap in ("true", "false"):
        r = bench.measure("classic", "point", 2, 3, TINY[1:-2] + [f"run.overlap={overlap}"])
        assert r.env_cpu_s == 3.0  # one bare block per measured update
        if overlap == "true":
            assert r.train_cpu_s == 3.0 and r.env_over_training_cpu == 1.0


def test_bench_train_counts_the_critic_process_cpu_in_training(monkeypatch):
    """In turn on two cores the critic learns in a child process (run.split_update): its CPU
    time over the measured updates (here 5 s before them, 8 s after) belongs to training."""
    import types

    import pursuit_cli.benchmarks.train as bench
    import train.trainer as trainer_module

    readings = iter([5.0, 8.0])
    monkeypatch.setattr(trainer_module, "usable_cores", lambda: 2)
    monkeypatch.setattr(bench, "_child_cpu_s", lambda pid: next(readings) if pid is not None else 0.0)
    monkeypatch.setattr(bench, "_bare_env_block", lambda env, steps, rng: (0.01, 1.0))
    monkeypatch.setattr(bench, "time", types.SimpleNamespace(perf_counter=bench.time.perf_counter, process_time=lambda: 0.0))
    r = bench.measure("classic", "point", 2, 3, TINY[1:-2] + ["run.overlap=false"])
    assert r.split and r.threads == "1 + 1 (split)"
    assert r.train_cpu_s == 3.0 and r.env_cpu_s == 3.0


def test_a_printed_config_with_a_number_like_name_loads_back(tmp_path, capsys):
    # the loader reads 1e6 as a number (YAML 1.2), so the dump must quote the string '1e6'
    assert main(["train", "--name", "1e6", "-sc"]) == 0
    saved = tmp_path / "saved.yaml"
    saved.write_text(capsys.readouterr().out)
    assert main(["train", "--config", str(saved), "-sc"]) == 0
    assert capsys.readouterr().out == saved.read_text()


def test_a_bad_value_in_an_earlier_train_config_names_that_file(tmp_path, capsys):
    bad, fine = tmp_path / "bad.yaml", tmp_path / "fine.yaml"
    bad.write_text("name: a\nppo: {lr: -1}\n")
    fine.write_text("name: b\n")
    assert main(["train", "--config", str(bad), "--config", str(fine), "-sc"]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: key 'ppo.lr': -1.0 is out of range" in err and "fine.yaml" not in err, err
    typo = tmp_path / "typo.yaml"
    typo.write_text("task: {evader_sped: 0.5}\n")
    assert main(["train", "--config", str(typo), "--config", str(fine), "-sc"]) == 2
    assert f"{typo}: unknown key 'task.evader_sped' (did you mean 'task.evader_speed'?)" in capsys.readouterr().err


def test_a_bad_value_in_a_task_file_names_the_task_file(tmp_path, capsys):
    task, train = tmp_path / "task.yaml", tmp_path / "train.yaml"
    task.write_text("evader_speed: -1\n")
    train.write_text(f"name: x\ntask_file: {task}\n")
    assert main(["train", "--config", str(train), "-sc"]) == 2
    assert f"task_file {task}: key 'evader_speed': -1.0 is out of range" in capsys.readouterr().err


def test_a_resume_with_the_run_length_given_by_set_trains_to_it(tmp_path, capsys):
    base = ["train", "--no-progress", "--name", "s"] + sets(TINY + [f"run.runs_dir={tmp_path}", "total_steps=32"])
    assert main(base) == 0
    # --set total_steps=64 is the --total-steps 64 of a resume (it was dropped: 'nothing to train')
    assert main(base + ["--resume", "--set", "total_steps=64"]) == 0
    out = capsys.readouterr().out
    assert "nothing to train" not in out and "done: 2 updates" in out
    assert [json.loads(x)["update"] for x in (tmp_path / "s" / "metrics.jsonl").read_text().splitlines()] == [1, 2]
    # and --set max_minutes: stored with the run, as --max-minutes is
    assert main(base + ["--resume", "--set", "total_steps=96", "--set", "max_minutes=5"]) == 0
    assert torch.load(tmp_path / "s" / "last.pt", weights_only=True)["train_config"]["max_minutes"] == 5.0


def test_a_resume_with_nothing_to_train_leaves_config_yaml_as_last_pt_has_it(tmp_path, capsys):
    """config.yaml took the --total-steps of a resume that trained nothing, so it no longer told the
    run's own length (last.pt, untouched, still held it)."""
    base = ["train", "--no-progress", "--name", "s"] + sets(TINY + [f"run.runs_dir={tmp_path}", "total_steps=64"])
    assert main(base) == 0
    config_yaml = (tmp_path / "s" / "config.yaml").read_text()
    assert main(["train", "--no-progress", "--resume", str(tmp_path / "s"), "--total-steps", "32"]) == 0
    assert "nothing to train: the run has reached total_steps 32" in capsys.readouterr().out
    assert (tmp_path / "s" / "config.yaml").read_text() == config_yaml
    assert torch.load(tmp_path / "s" / "last.pt", weights_only=True)["train_config"]["total_steps"] == 64


def test_the_command_that_started_a_run_on_a_relative_layout_file_resumes_it(tmp_path, capsys, monkeypatch):
    """The stored config holds the file's absolute path; the same command gives it relative."""
    from pursuit_mj.layout import builtin_layout_path

    monkeypatch.chdir(tmp_path)
    (tmp_path / "arena.yaml").write_text(builtin_layout_path(1).read_text())
    base = ["train", "--no-progress", "--name", "rel", "--layout", "arena.yaml"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(base + ["--total-steps", "32"]) == 0
    assert main(base + ["--resume", "--total-steps", "64"]) == 0, capsys.readouterr().err
    assert "done: 2 updates" in capsys.readouterr().out


def test_the_stored_config_of_a_run_on_a_relative_task_file_loads_from_any_folder(tmp_path, capsys, monkeypatch):
    """config.yaml kept task_file as typed, relative to the folder the run started in (its layout and
    code files are stored absolute): 'train --config RUN/config.yaml -sc', which a refused --resume -sc
    advises, failed from any other folder with 'task_file slow.yaml: no such file'."""
    start, other = tmp_path / "start", tmp_path / "other"
    start.mkdir(), other.mkdir()
    (start / "slow.yaml").write_text("evader_speed: 0.4\n")
    (start / "mine.yaml").write_text("name: rel\ntask_file: slow.yaml\n")
    monkeypatch.chdir(start)
    base = ["train", "--no-progress", "--config", "mine.yaml"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(base + ["--total-steps", "32"]) == 0
    stored = tmp_path / "rel" / "config.yaml"
    monkeypatch.chdir(other)
    capsys.readouterr()
    assert main(["train", "--config", str(stored), "-sc"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert f"task_file: {start / 'slow.yaml'}" in out and "evader_speed: 0.4" in out
    monkeypatch.chdir(start)  # the command that started it still resumes it
    assert main(base + ["--resume", "--total-steps", "64"]) == 0, capsys.readouterr().err
    assert "done: 2 updates" in capsys.readouterr().out


def test_a_resume_of_a_run_that_stored_its_task_file_relative_is_not_refused(tmp_path, monkeypatch):
    """Runs made before config.yaml held task_file absolute keep it relative; the command that started
    one, whose config now holds it absolute, must still resume it (its keys are compared as task.*)."""
    from pursuit_cli.train_cmd import _check_same
    from train.config import load_train_config

    (tmp_path / "slow.yaml").write_text("evader_speed: 0.4\n")
    monkeypatch.chdir(tmp_path)
    asked = load_train_config(["classic"], ["task_file=slow.yaml"])
    assert asked.with_absolute_files().task_file == str(tmp_path / "slow.yaml")
    _check_same(asked.with_absolute_files(), asked)
    with pytest.raises(ValueError, match="task.evader_speed"):
        _check_same(asked.with_absolute_files(), load_train_config(["classic"], ["task_file=easy"]))


@pytest.mark.parametrize("given, message", [
    ("layouts=[0,7]", "--set layouts=[0,7]: key 'layouts': 7 is not a built-in layout index (0-3)"),
    ("run.validation_layouts=[9]",
     "--set run.validation_layouts=[9]: key 'run.validation_layouts': 9 is not a built-in layout index (0-3)"),
    ("layouts=[nosuch.yaml]", "layouts ['nosuch.yaml']: layout 'nosuch.yaml': no such file"),
    ("task.layout=nosuch.yaml", "task.layout nosuch.yaml: layout 'nosuch.yaml': no such file"),
])
def test_a_layout_key_that_cannot_be_loaded_is_refused_naming_the_key(tmp_path, capsys, given, message):
    """--set layouts=[7] ended in 'layout 7: no built-in layout ...' from deep in the env, naming neither
    the key nor the --set, and left an empty run folder behind; -sc printed it as a valid config."""
    args = ["train", "--config", "classic", "--name", "bad", "--set", f"run.runs_dir={tmp_path}", "--set", given]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "bad").exists()  # refused before the run folder was made


@pytest.mark.parametrize("given, message", [
    (["--set", "evader_speed=0.5"], "--set evader_speed=0.5: unknown key 'evader_speed' (did you mean 'task.evader_speed'?)"),
    (["--set", "hidden=[64]"], "unknown key 'hidden' (did you mean 'net.hidden'?)"),
    (["--set", "lr=1e-4"], "unknown key 'lr' (did you mean 'ppo.lr' or 'imitation.lr'?)"),
    (["--set", "panic_distance=1"], "unknown key 'panic_distance' (did you mean 'task.evader.panic_distance'?)"),
    (["--set", "task.panic_distance=1"], "unknown key 'task.panic_distance' (did you mean 'task.evader.panic_distance'?)"),
    (["--set", "ppo.lrr=1"], "unknown key 'ppo.lrr' (did you mean 'ppo.lr'?)"),  # a typo: the close key, as before
])
def test_a_key_given_outside_its_section_is_pointed_to_it(capsys, given, message):
    """--set evader_speed=0.5 was answered 'did you mean seed?', --set hidden=[64] 'did you mean shield?':
    a key that lives in a section is now named with its section."""
    assert main(["train", "--config", "classic", *given, "-sc"]) == 2
    assert message in capsys.readouterr().err


def test_a_train_file_with_a_task_key_at_the_top_is_pointed_to_task(tmp_path, capsys):
    path = tmp_path / "mine.yaml"
    path.write_text("regime: classic\nevader_speed: 0.5\n")
    assert main(["train", "--config", str(path), "-sc"]) == 2
    assert f"{path}: unknown key 'evader_speed' (did you mean 'task.evader_speed'?)" in capsys.readouterr().err


def test_a_whole_count_written_as_a_float_is_taken_as_an_integer(capsys):
    """--set total_steps=2e4 was refused while --total-steps 2e4 was taken; a config now takes a
    whole number written with an exponent or a decimal point as the integer it is."""
    assert main(["train", "--config", "classic", "--set", "total_steps=2e4", "-sc"]) == 0
    assert "total_steps: 20000\n" in capsys.readouterr().out
    assert main(["train", "--config", "classic", "--set", "ppo.epochs=2.5", "-sc"]) == 2
    assert "key 'ppo.epochs': expected an integer, got 2.5\n" in capsys.readouterr().err


def test_resume_of_a_file_says_it_is_a_file(tmp_path, capsys):
    """--resume runs/x/metrics.jsonl said 'no such run folder' of a file that exists."""
    log = tmp_path / "metrics.jsonl"
    log.write_text("{}\n")
    assert main(["train", "--resume", str(log)]) == 2
    err = capsys.readouterr().err
    assert f"--resume {log}: a file, not a run folder; give its folder ({tmp_path})" in err, err


def test_an_empty_runs_dir_is_refused_rather_than_training_into_the_current_folder(capsys):
    assert main(["train", "--config", "classic", "--set", "run.runs_dir=", "-sc"]) == 2
    assert "key 'run.runs_dir': empty" in capsys.readouterr().err


def test_show_config_refuses_what_training_would_refuse(capsys):
    """-sc printed a config that spans keys training then refused (learnable discount under DAgger)."""
    assert main(["train", "--config", "imitate", "--set", "ppo.learnable_gamma=true", "-sc"]) == 2
    err = capsys.readouterr().err
    assert "ppo.learnable_gamma works with algo ppo or mappo, not dagger" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("given, message", [
    ("net.hidden=[100000000]", "key 'net.hidden': [100000000] is not a list of widths 1-4096"),
    ("net.critic_hidden=[64, 100000000]", "key 'net.critic_hidden': [64, 100000000] is not a list of widths 1-4096"),
    ("ppo.batch_size=1000000000", "key 'ppo.batch_size': 1000000000 is out of range (must be <= 1048576)"),
    ("imitation.dataset_size=1000000000", "key 'imitation.dataset_size': 1000000000 is out of range (must be <= 5000000)"),
    ("task.max_steps=100000000", "key 'task.max_steps': 100000000 is out of range (must be <= 100000)"),
])
def test_a_size_beyond_any_machine_is_refused_naming_its_key(given, message, capsys):
    """These had no upper bound: a slip of a few zeros failed deep in torch's allocator, or hung."""
    assert main(["train", "--config", "classic", "--set", given, "-sc"]) == 2
    assert message in capsys.readouterr().err


def test_a_bare_resume_says_it_looked_for_the_default_run_name(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--resume"]) == 2
    err = capsys.readouterr().err
    assert "no checkpoint runs/run/last.pt" in err and "continues the run named 'run', the default" in err
    assert "--resume runs/NAME" in err


def test_a_bad_flag_among_several_is_named_alone(capsys):
    """'flags --name z1 --n-envs 0 --seed 2 --fidelity point: key 'n_envs'...' named every flag typed."""
    assert main(["train", "--config", "classic", "--name", "z1", "--n-envs", "0", "--fidelity", "point", "--seed", "2", "-sc"]) == 2
    err = capsys.readouterr().err
    assert "error: flag --n-envs 0: key 'n_envs': 0 is out of range" in err, err
    assert main(["train", "--config", "classic", "--name", "z1", "--seed", "-3", "--fidelity", "point", "-sc"]) == 2
    assert "error: flag --seed -3: key 'seed'" in capsys.readouterr().err


def test_a_run_started_without_a_progress_bar_can_resume_with_one(tmp_path, monkeypatch):
    """--no-progress stuck: a resume could only keep the bar off (--set run.progress=true is refused there)."""
    from test_train_checkpoint import tiny_config
    from train.trainer import Trainer

    cfg = tiny_config(tmp_path, updates=1)  # run.progress=false
    Trainer(cfg, log=lambda s: None).train()
    seen = {}
    real = Trainer.resume

    def spy(*a, **k):
        trainer = real(*a, **k)
        seen["progress"] = trainer.cfg.run.progress
        return trainer

    monkeypatch.setattr(Trainer, "resume", spy)
    assert main(["train", "--resume", str(cfg.run_dir), "--progress", "--total-steps", "64"]) == 0
    assert seen["progress"] is True
    with pytest.raises(SystemExit) as stop:  # argparse: the two flags exclude each other
        main(["train", "--resume", str(cfg.run_dir), "--progress", "--no-progress"])
    assert stop.value.code == 2


def test_run_folder_mistakes_from_the_run_folder_audit(tmp_path, monkeypatch, capsys):
    """--resume . stored an empty run name (no later resume worked); --seed 0 beside --resume or
    --export was ignored where --seed 5 was refused; --export wrote over the run's metrics log."""
    import json

    from train.checkpoint import load_checkpoint

    base = ["train", "--config", "classic", "--no-progress", "--set", f"run.runs_dir={tmp_path}", "--name", "r"]
    assert main(base + [*sum((["--set", s] for s in TINY), []), "--set", "total_steps=32"]) == 0
    run = tmp_path / "r"
    monkeypatch.chdir(run)
    assert main(["train", "--resume", ".", "--total-steps", "64"]) == 0
    assert load_checkpoint(run / "last.pt")["train_config"]["name"] == "r"
    assert main(["train", "--resume", str(run), "--total-steps", "96"]) == 0
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--seed", "0"]) == 2
    assert "--seed cannot change it" in capsys.readouterr().err
    assert main(["train", "--export", str(run / "last.pt"), "x.pt", "--n-envs", "0"]) == 2
    assert "--n-envs would be ignored" in capsys.readouterr().err
    log = (run / "metrics.jsonl").read_text()
    assert main(["train", "--export", str(run / "last.pt"), str(run / "metrics.jsonl")]) == 2
    assert "OUT exists and is not a policy export" in capsys.readouterr().err
    assert (run / "metrics.jsonl").read_text() == log and [json.loads(x)["update"] for x in log.splitlines()] == [1, 2, 3]


def test_a_new_run_is_refused_in_a_folder_whose_earlier_run_lost_only_its_last_pt(tmp_path, capsys):
    """It said 'dropping 3 rows of a run stopped before its first checkpoint', cut the log and
    replaced best.pt."""
    cmd = ["train", "--config", "classic", "--no-progress", "--set", f"run.runs_dir={tmp_path}", "--name", "b",
           *sum((["--set", s] for s in TINY), []), "--set", "run.validate_every=1"]
    assert main(cmd + ["--set", "total_steps=96"]) == 0
    run = tmp_path / "b"
    (run / "last.pt").unlink()
    best, log = (run / "best.pt").read_bytes(), (run / "metrics.jsonl").read_text()
    capsys.readouterr()
    assert main(cmd + ["--set", "total_steps=32"]) == 2
    err = capsys.readouterr().err
    assert f"run folder {run} holds an earlier run (metrics.jsonl rows up to update 3" in err and "--name" in err
    assert (run / "best.pt").read_bytes() == best and (run / "metrics.jsonl").read_text() == log


def test_small_run_folder_refusals_leave_nothing_and_name_their_flag(tmp_path, capsys):
    """An export of a missing checkpoint made OUT's folder; bare --resume with -sc printed a new
    config; a folder given to --init-from was not named as --init-from's."""
    assert main(["train", "--export", str(tmp_path / "nope.pt"), str(tmp_path / "new" / "x.pt")]) == 2
    assert "nope.pt" in capsys.readouterr().err and not (tmp_path / "new").exists()
    assert main(["train", "--resume", "-sc", "--set", f"run.runs_dir={tmp_path}"]) == 2
    assert "--resume: -sc/--show-config does not resume" in capsys.readouterr().err
    (tmp_path / "folder").mkdir()
    assert main(["train", "--config", "classic", *sets(TINY), "--set", f"run.runs_dir={tmp_path}", "--name", "i",
                 "--init-from", str(tmp_path / "folder")]) == 2
    assert "init_from (--init-from): checkpoint" in capsys.readouterr().err


def test_bench_train_steps_the_bare_env_with_the_runs_reward_terms(tmp_path, monkeypatch):
    """A reward term of the run is part of the task: the bare env pays it too, so its cost is not
    counted as training's."""
    import types

    import pursuit_cli.benchmarks.train as bench

    (tmp_path / "terms.py").write_text("import numpy as np\n\ndef still(step):\n    return np.zeros(step.pursuer_pos.shape[:2])\n")
    seen = []
    monkeypatch.setattr(bench, "_bare_env_block", lambda env, steps, rng: (seen.append(tuple(env.reward_names)), (0.01, 1.0))[1])
    monkeypatch.setattr(bench, "time", types.SimpleNamespace(perf_counter=bench.time.perf_counter, process_time=lambda: 0.0))
    bench.measure("classic", "point", 2, 1, TINY[1:-2] + ["run.overlap=false", f"rewards=[{tmp_path / 'terms.py'}:still]"])
    assert seen and all(names[-1] == "still" for names in seen), seen


def test_a_set_value_that_is_not_yaml_says_why(capsys):
    """'value of 'task' is not valid YAML' hid the reason (a key given twice, an unclosed list)."""
    assert main(["train", "--set", "task={fidelity: point, fidelity: quadrotor}", "-sc"]) == 2
    err = capsys.readouterr().err
    assert "--set task={fidelity: point, fidelity: quadrotor}: value of 'task' is not valid YAML" in err, err
    assert "key 'fidelity' given twice" in err and len(err.strip().splitlines()) == 1, err



def test_an_empty_config_name_is_refused_as_empty(capsys):
    """--config '' said ': a folder, not a train file' (the empty path is the current folder)."""
    assert main(["train", "--config", "", "-sc"]) == 2
    err = capsys.readouterr().err
    assert "error: '': empty; give a train file or preset (presets: belief, " in err, err


def test_resume_with_show_config_points_to_a_command_that_shows_it(tmp_path, capsys):
    """It said '(or: pursuit-mj config ...)', which refuses a train config."""
    assert main(["train", "--resume", str(tmp_path), "-sc"]) == 2
    err = capsys.readouterr().err
    assert "pursuit-mj config" not in err, err
    assert f"pursuit-mj train --config {tmp_path / 'config.yaml'} -sc" in err, err


def test_resume_of_the_runs_folder_names_the_runs_in_it(tmp_path, capsys):
    """--resume runs said 'no last.pt in runs' of the folder holding the runs."""
    for name in ("b", "a"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "last.pt").write_bytes(b"")
    (tmp_path / "other").mkdir()
    assert main(["train", "--resume", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"--resume {tmp_path}: no last.pt in {tmp_path}; it holds the runs a, b: give one, e.g. --resume {tmp_path / 'a'}" in err, err


@pytest.mark.parametrize("given, hint", [("net.hidden=(64,64)", "[64,64]"), ("net.hidden=(64, 64)", "[64, 64]"),
                                         ("net.hidden=64,64", "[64,64]")])
def test_a_list_written_in_parentheses_is_shown_how_to_write_it(given, hint, capsys):
    """'(64,64)' was answered '(write it as [(64,64)])', which is refused too."""
    assert main(["train", "--set", given, "-sc"]) == 2
    err = capsys.readouterr().err
    assert f"key 'net.hidden': expected a list, got '{given.split('=')[1]}' (write it as {hint})\n" in err, err


@pytest.mark.parametrize("given", ["ppo..lr=1", ".ppo=1", "ppo.=1"])
def test_a_key_with_an_empty_part_is_refused_as_such(given, capsys):
    """'ppo..lr' was answered "unknown key 'ppo.'", '.ppo' "unknown key ''" and a list of every key."""
    assert main(["train", "--set", given, "-sc"]) == 2
    err = capsys.readouterr().err
    key = given.split("=")[0]
    assert f"--set {given}: '{key}' has an empty part (the keys of nested sections are joined by single dots)\n" in err, err


def test_train_help_places_the_run_folder_under_run_runs_dir(capsys):
    """--name and --rerun said 'runs/', which run.runs_dir changes."""
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "--name NAME run name: its folder is <run.runs_dir>/<name> (runs/<name> by default)" in out, out
    assert "stream the logged scalars to <run.runs_dir>/<name>/metrics.rrd" in out, out


def test_train_refuses_an_abbreviated_flag_instead_of_guessing_it(capsys):
    """argparse took --see 4 for --seed 4 (and --tot for --total-steps): scripts that pass train flags
    on, as scripts/train_recipe.sh does, could not tell a seed among them; flags are now given whole."""
    with pytest.raises(SystemExit) as stopped:
        main(["train", "--config", "classic", "--see", "4"])
    assert stopped.value.code == 2 and "unrecognized arguments: --see 4" in capsys.readouterr().err


def test_a_trained_policy_given_nan_observations_names_them_not_its_actions(tiny_model):
    """ActorPolicy.act checked only the observations' width: NaN in them came back as NaN actions,
    which the caller then blamed on the policy ('act() gave nan')."""
    from train.checkpoint import load_checkpoint
    from train.policy import ActorPolicy, load_policy, spec_from_dict

    policy = load_policy(tiny_model)
    spec = spec_from_dict(load_checkpoint(tiny_model)["obs_spec"])
    assert isinstance(policy, ActorPolicy)
    obs = np.zeros((1, spec.n_pursuers, spec.dim), np.float32)
    assert np.isfinite(policy.act(obs, spec)).all()
    obs[0, 1, 3] = np.nan
    with pytest.raises(ValueError, match=f"policy {policy.name}: observations contain NaN or inf"):
        policy.act(obs, spec)


def test_the_stored_config_of_a_run_from_a_relative_init_from_loads_from_any_folder(tmp_path, capsys, monkeypatch):
    """config.yaml kept init_from as typed, relative to the folder the run started in: 'train
    --config RUN/config.yaml' from another folder failed with 'init_from ...: no such checkpoint'.
    The command that started the run, and that of a run stored before the change, still resume it."""
    start, other = tmp_path / "start", tmp_path / "other"
    start.mkdir(), other.mkdir()
    monkeypatch.chdir(start)
    first = ["train", "--no-progress", "--name", "a"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(first + ["--total-steps", "32"]) == 0
    (start / "a.pt").write_bytes((tmp_path / "a" / "last.pt").read_bytes())
    base = ["train", "--no-progress", "--name", "b", "--init-from", "a.pt"] + sets(TINY + [f"run.runs_dir={tmp_path}"])
    assert main(base + ["--total-steps", "32"]) == 0
    stored = tmp_path / "b" / "config.yaml"
    assert f"init_from: {start / 'a.pt'}" in stored.read_text()
    monkeypatch.chdir(other)
    capsys.readouterr()
    assert main(["train", "--no-progress", "--config", str(stored), "--name", "c", "--total-steps", "32"]) == 0, \
        capsys.readouterr().err
    monkeypatch.chdir(start)  # the command that started it resumes it, also where config.yaml holds it relative
    assert main(base + ["--resume", "--total-steps", "64"]) == 0, capsys.readouterr().err
    stored.write_text(stored.read_text().replace(str(start / "a.pt"), "a.pt"))
    assert main(base + ["--resume", "--total-steps", "96"]) == 0, capsys.readouterr().err
    assert "done: 3 updates" in capsys.readouterr().out


@pytest.mark.parametrize("given, named", [
    (["--set", "task.layout=nope.yaml"], "--set task.layout=nope.yaml: task.layout nope.yaml: layout 'nope.yaml'"),
    (["--set", "task={layout: nope.yaml}"], "--set task={layout: nope.yaml}: task.layout nope.yaml"),
    (["--set", "layouts=[0, nope.yaml]"], "--set layouts=[0, nope.yaml]: layouts [0, 'nope.yaml']"),
    (["--set", "run.validation_layouts=[nope.yaml]", "-sc"], "--set run.validation_layouts=[nope.yaml]: run.validation_layouts"),
])
def test_a_missing_layout_file_given_by_set_names_the_flag(tmp_path, capsys, monkeypatch, given, named):
    """A layout file --set names that does not exist was blamed on the 'train config', not the flag."""
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--no-progress", *sets(TINY), *given]) == 2
    assert f"pursuit-mj train: error: {named}" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()



def test_an_export_of_a_file_that_is_no_checkpoint_leaves_no_folder_it_made(tmp_path, capsys):
    """--export notes.txt new/x/p.pt made new/x/ (the check that OUT can be written) and then found
    notes.txt to be no checkpoint, leaving the empty new/x/ behind."""
    notes = tmp_path / "notes.txt"
    notes.write_text("not a checkpoint")
    assert main(["train", "--export", str(notes), str(tmp_path / "new" / "x" / "p.pt")]) == 2
    assert "not a pursuit-mj checkpoint" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_a_run_that_fails_in_its_first_update_leaves_no_folder_it_made(tmp_path, monkeypatch, capsys):
    """A run that failed inside its first update (training diverged at update 1, say) left
    runs/NAME holding config.yaml and its .lock, and the runs folder it had made: nothing to
    resume or read. A folder that was there keeps what it held, without the files the run made."""
    import train.trainer as trainer_module

    def fails(*args, **kwargs):
        raise ValueError("training diverged at update 1 (as if)")

    monkeypatch.setattr(trainer_module, "ppo_update", fails)
    runs = tmp_path / "new" / "runs"
    base = ["train", "--no-progress", "--name", "x", "--total-steps", "32"] + sets(TINY)
    assert main(base + ["--set", f"run.runs_dir={runs}"]) == 2
    assert "diverged" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    mine = tmp_path / "mine" / "x"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("mine")
    assert main(base + ["--set", f"run.runs_dir={tmp_path / 'mine'}"]) == 2
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_a_check_across_two_train_keys_names_the_command_line_values_that_gave_them(tmp_path, capsys):
    """Errors of one key name the --set that gave it; those of two keys said 'train config: ...'
    even when a --set (or a flag) gave one of them, training or with -sc alike."""
    runs = tmp_path / "runs"
    cases = [
        (["--set", "ppo.minibatch_size=2000"], "--set ppo.minibatch_size=2000: ppo.minibatch_size 2000 exceeds ppo.batch_size 1024"),
        (["--set", "ppo.batch_size=8"], "--set ppo.batch_size=8: ppo.minibatch_size 256 exceeds ppo.batch_size 8"),
        (["--set", "ppo.batch_size=8", "--set", "ppo.minibatch_size=9"],
         "--set ppo.minibatch_size=9, --set ppo.batch_size=8: ppo.minibatch_size 9 exceeds ppo.batch_size 8"),
        (["--set", "ppo.anchor_coef=0.5"], "--set ppo.anchor_coef=0.5: ppo.anchor_coef 0.5 needs init_from"),
        (["--config", "imitate", "--learnable-gamma"], "--learnable-gamma: ppo.learnable_gamma works with algo ppo or mappo"),
    ]
    for given, said in cases:
        for sc in ([], ["-sc"]):
            assert main(["train", "--no-progress", "--name", "x", "--set", f"run.runs_dir={runs}", *given, *sc]) == 2
            err = capsys.readouterr().err
            assert f"error: {said}" in err, (given, sc, err)
    assert not runs.exists()
    assert main(["train", "-sc", "--config", "imitate", "--set", "ppo.learnable_gamma=true"]) == 2
    assert "error: --set ppo.learnable_gamma=true: ppo.learnable_gamma works" in capsys.readouterr().err


def test_the_closing_summary_says_validation_rates_as_the_eval_table_does(tmp_path, capsys, monkeypatch):
    """train's closing lines printed a validation success of 2499 of 2500 as '100.0%' (run.validation_episodes
    reaches 10000), and a McNemar p of 0.04998 as '0.05' beside the 0.05 a verdict needs."""
    from train.trainer import Trainer

    def finished(self, *a, **k):
        c = {"update": 1, "world_steps": 32, "agent_steps": 64, "episodes": 2, "seconds": 1.0, "validation_seconds": 0.5,
             "best_success": 2499 / 2500, "best_update": 1}
        val = {"episodes": 2500, "success": 2499 / 2500, "mean_steps": 100.0, "heuristic_success": 1 / 2500,
               "heuristic_mean_steps": 120.0, "vs_heuristic_steps": -20.0, "vs_heuristic_lo": -25.0, "vs_heuristic_hi": -15.0,
               "vs_heuristic_only_policy": 9, "vs_heuristic_only_heuristic": 1, "vs_heuristic_success_p": 0.049983}
        return {"status": "done", "counters": c, "validation": val, "run_dir": str(self.run_dir)}

    monkeypatch.setattr(Trainer, "train", finished)
    assert main(["train", "--no-progress", "--name", "sum", "--total-steps", "32"] + sets(TINY + [f"run.runs_dir={tmp_path}"])) == 0
    out = capsys.readouterr().out
    assert "best validation success 99.96 %" in out and "success 99.96 %, 100.0 mean steps" in out, out
    assert "the heuristic team 0.04 %" in out and "McNemar p 0.04998" in out, out


@pytest.mark.parametrize("given, message", [
    (["--set", "layouts=[0,1,2,3]", "--set", "n_envs=2"],
     "--set layouts=[0,1,2,3], --set n_envs=2: 4 layouts for n_envs 2"),
    (["--set", "run.validation_layouts=[0,1,2]", "--set", "run.validation_episodes=2"],
     "--set run.validation_layouts=[0,1,2], --set run.validation_episodes=2: 3 validation layouts for run.validation_episodes 2"),
    (["--set", "layouts=[0,1,2]", "--set", "run.validation_episodes=2"],
     "--set layouts=[0,1,2], --set run.validation_episodes=2: 3 validation layouts for run.validation_episodes 2"),
])
def test_more_layouts_than_worlds_to_play_them_is_refused_naming_the_keys(capsys, given, message):
    """World w plays layouts[w % len]: n_envs 2 over four layouts trained on two of them, and two
    validation episodes over three layouts validated on two, without a word."""
    assert main(["train", "--config", "classic", *given, "-sc"]) == 2  # refused as the run's config is checked
    err = capsys.readouterr().err
    assert message in err and len(err.splitlines()) == 1, err
    # drawn per episode (task.random_layout), every layout plays in any number of worlds
    assert main(["train", "--config", "classic", *given, "--set", "task.random_layout=true", "-sc"]) == 0


def test_a_flight_is_not_told_of_the_fidelity_a_model_learned_in(tiny_model, capsys):
    """A flight's physics is the real world's (flight.plan.SIMULATION_ONLY_KEYS: its task takes no
    fidelity), so `fly --model` of a point-trained model said 'fidelity point (this task: quadrotor)',
    comparing with a default that means nothing there; in simulation it is told."""
    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec

    task = default_config(n_pursuers=2, fidelity="quadrotor")
    spec = ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays)
    load_model(tiny_model, spec, task)
    assert "fidelity point (this task: quadrotor)" in capsys.readouterr().err
    load_model(tiny_model, spec, task, flight=True)
    assert "fidelity" not in capsys.readouterr().err
    from pursuit_cli.common import SIMULATION_ONLY_TRAINED_KEYS, TRAINED_TASK_KEYS
    from pursuit_mj.flight.plan import SIMULATION_ONLY_KEYS

    assert set(SIMULATION_ONLY_KEYS) & set(TRAINED_TASK_KEYS) == set(SIMULATION_ONLY_TRAINED_KEYS)


def test_a_model_trained_before_a_task_key_existed_is_compared_at_that_keys_default(capsys):
    """The shipped checkpoints predate command_latency, so their stored task has no such key, and
    `eval --model pretrained/belppo_kick.pt --set command_latency=0.1` (what docs/flight.md asks for
    before a flight) said nothing of the latency, where a model trained since says 'command_latency 0.0
    (this task: 0.1)'. A key the checkpoint lacks is what the code then did: its default (as
    load_policy rebuilds such a task)."""
    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec
    from pursuit_mj.shipped import shipped_dir

    task = default_config(command_latency=0.1)
    spec = ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays)
    policy = load_model(shipped_dir("pretrained") / "belppo_kick.pt", spec, task)
    assert "command_latency" not in policy.trained_task  # the case: a checkpoint older than the key
    assert "command_latency 0.0 (this task: 0.1)" in capsys.readouterr().err
    load_model(shipped_dir("pretrained") / "belppo_kick.pt", spec, default_config())
    assert capsys.readouterr().err == ""  # its own task: nothing to say


def test_a_model_used_against_an_otherwise_tuned_escape_model_says_so(tiny_model, capsys):
    """The escape model's keys (how far the evader senses chasers, when it panics) shape what a
    policy learned to chase as much as the evader's speed does, but a model evaluated against
    `--set evader.sense_radius=2` was told nothing; a model of one's own, which those keys do not
    tune, is compared by its name only."""
    import dataclasses

    from pursuit_cli.common import load_model
    from pursuit_mj.config import default_config
    from pursuit_mj.obs_spec import ObsSpec

    task = default_config(n_pursuers=2, fidelity="point")
    task = dataclasses.replace(task, evader=dataclasses.replace(task.evader, sense_radius=2.0, gap_escape=False))
    load_model(tiny_model, ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays), task)
    err = capsys.readouterr().err
    assert "evader.sense_radius 4.0 (this task: 2.0), evader.gap_escape True (this task: False)" in err, err
    mine = dataclasses.replace(task, evader=dataclasses.replace(task.evader, model="mine.py:Straight"))
    load_model(tiny_model, ObsSpec.make(task.n_pursuers, task.n_evaders, task.n_rays), mine)
    err = capsys.readouterr().err
    assert "evader.model janosov (this task: mine.py:Straight)" in err and "sense_radius" not in err, err


def test_a_model_played_on_no_layout_it_trained_on_says_which_it_trained_on(tmp_path, monkeypatch, capsys):
    """A run trained on a layout file of one's own, then `eval --model` (or `render -m`) without a
    layout, played the task's layout 0 without a word: the checkpoint names the file it trained on,
    so a note says so; a table that plays that file (by any spelling of its path) says nothing."""
    monkeypatch.chdir(tmp_path)
    Path("arena.yaml").write_text("arena: {width: 3.0, height: 4.0}\nspawn:\n  pursuers: {x: [0.3, 2.7], y: [0.3, 0.8]}\n"
                                  "  evaders: {x: [0.3, 2.7], y: [3.2, 3.7]}\n")
    assert main(["train", "--no-progress", "--name", "a", "--total-steps", "32", "--layout", "arena.yaml"]
                + sets(TINY + ["run.runs_dir=runs"])) == 0
    capsys.readouterr()
    play = ["eval", "--model", "runs/a/last.pt", "--episodes", "1", "--worlds", "1", "--fidelity", "point", "--pursuers", "2",
            "--set", "max_steps=5", "-q"]
    assert main(play) == 0
    note = f"note: --model runs/a/last.pt was trained on layout {tmp_path / 'arena.yaml'}, which this run does not play (layout 0)"
    assert note in capsys.readouterr().err
    for named in (["--layouts", "arena.yaml", "1"], ["--layouts", str(tmp_path / "arena.yaml")], ["-i", "./arena.yaml"]):
        assert main(play + named) == 0
        assert "was trained on layout" not in capsys.readouterr().err, named
    assert main(["render", "-m", "runs/a/last.pt", "--no-video", "--final-frame", "-s", "r/", "--fidelity", "point",
                 "--pursuers", "2", "--set", "max_steps=5"]) == 0
    assert note in capsys.readouterr().err  # render -m is --model too


def test_the_last_validation_line_names_the_fidelity_and_layouts_it_was_played_on(tmp_path, capsys):
    """`pursuit-mj train` ended with 'last validation (2 fixed episodes): success 0.0 %, 30.0 mean
    steps; the heuristic team ...': rates and steps with no word of the fidelity or layouts that
    made them (a run validated on run.validation_layouts other than those it trained on said the
    same). The line names them, as eval's tables now do."""
    assert main(["train", "--no-progress", "--name", "v", "--total-steps", "64", "--set", "run.validate_every=1",
                 "--set", "run.validation_layouts=[1, 2]"] + sets(TINY + [f"run.runs_dir={tmp_path}"])) == 0
    assert "\nlast validation (2 fixed episodes, point fidelity, layouts 1, 2): success " in capsys.readouterr().out
    assert main(["train", "--no-progress", "--name", "w", "--total-steps", "64", "--set", "run.validate_every=1"]
                + sets(TINY + [f"run.runs_dir={tmp_path}"])) == 0
    assert "\nlast validation (2 fixed episodes, point fidelity, layout 0): success " in capsys.readouterr().out


def test_bench_train_names_the_settings_it_was_given(capsys):
    """bench train's header named the config but not a --set, which changes the figures (the team,
    the obstacles, the batch): a run with '--set task.random_obstacles=0' printed the header of the
    config's own task. It now lists them, as bench env and physics do."""
    code = main(["bench", "train", "--fidelity", "point", "--updates", "1", "--n-envs", "2", "--collection", "in-turn"]
                + sets(TINY[1:-2]))
    assert code == 0
    given = " ".join(f"--set {s}" for s in TINY[1:-2])
    assert f"train benchmark, config classic ({given}): PPO" in capsys.readouterr().out
