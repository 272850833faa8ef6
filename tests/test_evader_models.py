"""Evaders of one's own through the task key evader.model (pursuit_mj.evader_models), on every path."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from pursuit_cli import main
from pursuit_mj.config import ConfigError, default_config, load_task_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.evader import EscapeModel
from pursuit_mj.evader_models import FileEvaderModel

DOCS = Path(__file__).resolve().parent.parent / "docs"


def documented_evader() -> str:
    """The my_evader.py example of docs/env_api.md, as written there."""
    block = re.search(r"```python\n# my_evader.py\n(.*?)```", (DOCS / "env_api.md").read_text(), re.S)
    assert block, "docs/env_api.md lost its my_evader.py example"
    return block.group(1)


@pytest.fixture
def straight(tmp_path) -> str:
    path = tmp_path / "my_evader.py"
    path.write_text(documented_evader())
    return f"{path}:Straight"


def config_with(model: str, **changes):
    return default_config(fidelity="point", evader={"model": model}, **changes)


def test_the_default_is_the_built_in_escape_model():
    assert isinstance(PursuitEnv(default_config(fidelity="point")).evader_model, EscapeModel)


def test_the_documented_evader_flies_straight_away_from_the_nearest_pursuer(straight):
    config = config_with(straight)
    env = PursuitEnv(config, n_worlds=4, seed=1)
    assert isinstance(env.evader_model, FileEvaderModel)
    env.reset()
    for _ in range(15):
        env.step(np.zeros((4, 3, 2)))  # the pursuers hover: the evaders run from where they are
    s = env.snapshot(0)
    away = s.evader_pos[0, :2] - s.pursuer_pos[np.linalg.norm(s.pursuer_pos[:, :2] - s.evader_pos[0, :2], axis=1).argmin(), :2]
    cmd = s.commands[3]  # the evader's desired velocity, m/s
    assert np.linalg.norm(cmd) == pytest.approx(config.evader_speed, rel=1e-6)
    assert np.dot(cmd, away) / (np.linalg.norm(cmd) * np.linalg.norm(away)) == pytest.approx(1.0, abs=1e-6)


class _Models:
    """Source text of broken models: each a line number where the failure is."""

    raising_factory = "def Model(config, n_worlds, seed):\n    raise RuntimeError('no')\n"
    a_class = "class Model:\n    pass\n\ndef Maker(config, n_worlds, seed):\n    return Model\n"
    no_compute = "class Model:\n    def __init__(self, c, w, s): pass\n    def reset(self, ids, seeds): pass\n"
    base = ("import numpy as np\nclass Model:\n    def __init__(self, c, w, s): self.shape = (w, c.n_evaders, 2)\n"
            "    def reset(self, ids, seeds): pass\n")


@pytest.mark.parametrize("source, name, message", [
    (_Models.raising_factory, "Model", r"Model\(config, n_worlds, seed\) raised RuntimeError: no \(at {p}:2\)"),
    (_Models.a_class, "Maker", r"Maker\(config, n_worlds, seed\) returned the class Model, not an instance of it; it must return an evader model"),
    (_Models.no_compute, "Model", r"Model\(config, n_worlds, seed\) returned <.*>, which has no compute method"),
    (_Models.base, "Absent", r"{p} defines no class or function 'Absent' \(it defines: Model\)"),
])
def test_a_model_that_cannot_be_made_is_refused_when_the_env_is(tmp_path, source, name, message):
    path = tmp_path / "m.py"
    path.write_text(source)
    with pytest.raises(ValueError, match="^task evader.model " + re.escape(f"{path}:{name}") + ": " + message.format(p=re.escape(str(path)))):
        PursuitEnv(config_with(f"{path}:{name}"), n_worlds=2)


@pytest.mark.parametrize("body, message", [
    ("        return np.zeros(self.shape[:2])", r"compute returned shape \(2, 1\), expected \(2, 1, 2\)"),
    ("        return np.full(self.shape, np.nan)", r"compute returned nan at \(world, evader, axis\) \(0, 0, 0\)"),
    ("        return {}[0]", r"compute\(\.\.\.\) raised KeyError: 0 \(at {p}:6\)"),
    # a forgotten return: "an array of dtype object" named no value the model returned
    ("        np.zeros(self.shape)", r"compute returned None, not an array of real numbers"),
    ("        return {'vx': 0.0}", r"compute returned dict \{{'vx': 0.0\}}, not an array of real numbers"),
])
def test_what_compute_returns_is_checked_and_named(tmp_path, body, message):
    path = tmp_path / "m.py"
    path.write_text(_Models.base + "    def compute(self, *args):\n" + body + "\n")
    env = PursuitEnv(config_with(f"{path}:Model"), n_worlds=2)
    env.reset()
    with pytest.raises(ValueError, match=message.format(p=re.escape(str(path)))):
        env.step(np.zeros((2, 3, 2)))


def test_nan_for_a_caught_evader_is_ignored_as_its_command_is(tmp_path):
    """Only the active evaders' commands count (docs/env_api.md)."""
    path = tmp_path / "m.py"
    path.write_text(_Models.base + "    def compute(self, ep, ev, pp, pv, active, obstacles, dt):\n"
                    "        return np.where(active[..., None], np.zeros(active.shape + (2,)), np.nan)\n")
    env = PursuitEnv(config_with(f"{path}:Model", n_evaders=2), n_worlds=1, auto_reset=False)
    env.reset()
    env.captured[0, 1] = True  # as a capture leaves it
    env.step(np.zeros((1, 3, 2)))
    assert np.isfinite(env.physics.commands).all()


class _Set:
    """A model set as env.evader_model (docs/env_api.md), answering `answer(evader_pos)`."""

    def __init__(self, answer):
        self.answer = answer

    def reset(self, world_ids, seeds):
        pass

    def compute(self, evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt):
        return self.answer(evader_pos)


def _fleeing_up_by_moving_itself(evader_pos):
    evader_pos[..., 1] += 1.0  # writes into the env's array the rewards are measured from
    return np.zeros(evader_pos.shape)


@pytest.mark.parametrize("answer, message", [
    # (1, 1, 2) was broadcast to every world, (W, M) and None failed in numpy's concatenate
    # naming nothing, NaN was "commands: non-finite value nan at index (0, 3, 0)"
    (lambda e: np.ones((1, 1, 2)), r"^env.evader_model _Set: compute returned shape \(1, 1, 2\), expected \(2, 1, 2\)"),
    (lambda e: np.zeros(e.shape[:2]), r"^env.evader_model _Set: compute returned shape \(2, 1\), expected \(2, 1, 2\)"),
    (lambda e: None, r"^env.evader_model _Set: compute returned None"),
    (lambda e: np.full(e.shape, np.nan), r"^env.evader_model _Set: compute returned nan at \(world, evader, axis\) \(0, 0, 0\)"),
    (_fleeing_up_by_moving_itself, r"^env.evader_model _Set: compute\(\.\.\.\) raised ValueError: output array is read-only \(at .*test_evader_models.py:\d+\)$"),
])
def test_a_model_set_on_the_env_is_checked_as_a_files_is(answer, message):
    env = PursuitEnv(default_config(fidelity="point"), n_worlds=2)
    env.evader_model = model = _Set(answer)
    assert env.evader_model is model
    env.reset()
    with pytest.raises(ValueError, match=message):
        env.step(np.zeros((2, 3, 2)))


def test_a_model_that_is_neither_janosov_nor_a_file_reference_is_refused_naming_the_key():
    with pytest.raises(ConfigError, match=r"--set evader.model=straight: key 'evader.model': 'straight' is neither janosov"):
        load_task_config([], ["evader.model=straight"])


def test_a_task_file_finds_its_model_beside_itself(tmp_path, monkeypatch, straight):
    folder = tmp_path / "exp"
    folder.mkdir()
    shutil.copy(straight.split(":")[0], folder / "flee.py")
    (folder / "task.yaml").write_text("evader:\n  model: flee.py:Straight\n")
    monkeypatch.chdir(tmp_path)
    assert load_task_config(["exp/task.yaml"]).evader.model == "exp/flee.py:Straight"  # as layout files are found


def test_eval_plays_the_documented_evader_and_resumes_only_with_the_same_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the docs name the file from the current folder
    Path("my_evader.py").write_text(documented_evader())
    base = ["eval", "--policy", "heuristic", "--policy", "random", "--set", "evader.model=my_evader.py:Straight",
            "--layouts", "0", "--episodes", "2", "--worlds", "2", "--fidelity", "point", "-q", "--out", "t"]
    assert main(base) == 0, capsys.readouterr().err
    data = json.loads(Path("t.json").read_text())
    assert data["config"]["evader"]["model"] == "my_evader.py:Straight" and len(data["evader_model_sha256"]) == 64
    kept = {**data, "rows": data["rows"][:1]}  # as an eval stopped after its first row leaves it
    Path("t.interrupted.json").write_text(json.dumps(kept))
    Path("my_evader.py").write_text(documented_evader() + "\n# edited\n")
    assert main(base + ["--resume"]) == 2
    assert "--resume: evader_model_sha256 differs from the interrupted eval's" in capsys.readouterr().err
    Path("my_evader.py").write_text(documented_evader())
    assert main(base + ["--resume"]) == 0, capsys.readouterr().err
    assert main(["eval", "--policy", "heuristic", "--set", "evader.model=gone.py:Straight", "--fidelity", "point"]) == 2
    err = capsys.readouterr().err
    assert "evader.model gone.py:Straight: no file gone.py" in err and len(err.strip().splitlines()) == 1


def test_render_names_its_files_by_the_evader_models_bytes(tmp_path, straight, capsys):
    def rendered(model_args):
        out = tmp_path / f"r{len(list(tmp_path.glob('r*')))}"
        assert main(["render", "--policy", "heuristic", "--fidelity", "point", "--set", "max_steps=3", "--width", "64",
                     "--height", "48", "--format", "gif", "-s", str(out), *model_args]) == 0, capsys.readouterr().err
        return sorted(p.name for p in out.iterdir())

    built_in = rendered([])
    own = rendered(["--set", f"evader.model={straight}"])
    Path(straight.split(":")[0]).write_text(documented_evader() + "\n# edited\n")
    edited = rendered(["--set", f"evader.model={straight}"])
    assert len({tuple(built_in), tuple(own), tuple(edited)}) == 3


def test_training_flies_the_model_and_refuses_to_resume_with_another_file(tmp_path, straight, capsys):
    tiny = ["task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30", "n_envs=2",
            "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=1", "run.validate_every=0", "run.validation_episodes=2",
            f"run.runs_dir={tmp_path}", f"task.evader.model={straight}"]
    args = ["train", "--no-progress", "--name", "s", "--total-steps", "32"] + sum((["--set", s] for s in tiny), [])
    assert main(args) == 0, capsys.readouterr().err
    data = torch.load(tmp_path / "s" / "last.pt", weights_only=True)
    path = straight.split(":")[0]
    assert data["train_config"]["task"]["evader"]["model"] == straight and list(data["code_sha256"]) == [path]
    Path(path).write_text(documented_evader() + "\n# edited\n")
    assert main(["train", "--no-progress", "--resume", str(tmp_path / "s"), "--total-steps", "64"]) == 2
    assert f"{path} (task.evader.model) has changed since the run started" in capsys.readouterr().err


def test_a_flight_file_names_its_evader_model_and_a_bad_one_is_refused_before_any_drone(tmp_path, straight, capsys):
    from tests.test_flight_virtual import quick_spec

    flight = tmp_path / "quick.yaml"
    flight.write_text(yaml.safe_dump(quick_spec(task={"evader_speed": 0.3, "evader": {"model": "missing.py:Straight"}})))
    assert main(["fly", "--flight", str(flight), "--policy", "heuristic", "--virtual", "--max-time", "1.0"]) == 2
    err = capsys.readouterr().err
    assert f"{flight}: key 'task.evader.model': file 'missing.py' (of missing.py:Straight): no such file" in err
    shutil.copy(straight.split(":")[0], tmp_path / "missing.py")  # now beside the flight file
    events = tmp_path / "f.jsonl"
    assert main(["fly", "--flight", str(flight), "--policy", "heuristic", "--virtual", "--max-time", "1.0",
                 "--events", str(events)]) == 0, capsys.readouterr().err
    steps = [json.loads(line) for line in events.read_text().splitlines() if '"kind": "step"' in line]
    pos, wanted = np.array(steps[-1]["pos"]), np.array(steps[-1]["wanted"])
    away = pos[-1][:2] - pos[np.linalg.norm(pos[:-1, :2] - pos[-1, :2], axis=1).argmin()][:2]
    assert np.dot(wanted[-1], away) > 0.99 * np.linalg.norm(wanted[-1]) * np.linalg.norm(away)  # straight away


def test_a_model_that_fails_in_the_overlapped_rollout_worker_is_one_line_as_without_it(tmp_path, capsys):
    """run.overlap=true steps the env in a child process; a model's error comes back as its one line."""
    path = tmp_path / "m.py"
    path.write_text(_Models.base + "    def compute(self, *args):\n        return {}[0]\n")
    tiny = ["task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30", "n_envs=2",
            "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=1", "run.validate_every=0", "run.validation_episodes=2",
            f"task.evader.model={path}:Model"]
    for overlap in ("false", "true"):
        sets = tiny + [f"run.runs_dir={tmp_path}/{overlap}", f"run.overlap={overlap}"]
        code = main(["train", "--no-progress", "--name", "o", "--total-steps", "64"] + sum((["--set", s] for s in sets), []))
        err = capsys.readouterr().err
        assert code == 2 and err.strip().splitlines() == [
            f"pursuit-mj train: error: task evader.model {path}:Model: compute(...) raised KeyError: 0 (at {path}:6)"], err


def test_a_model_cannot_change_what_the_env_measures_rewards_and_captures_from(tmp_path):
    """The arrays compute gets are the env's own (its positions before the step, which the reward
    terms read, and its obstacles): a model that writes into them is refused naming its line, as a
    reward term's StepView is read-only, never left to change the rewards silently."""
    path = tmp_path / "m.py"
    path.write_text(_Models.base + "    def compute(self, ep, ev, pp, pv, active, obstacles, dt):\n"
                    "        ep -= pp.mean(axis=1, keepdims=True)\n        return np.zeros(self.shape)\n")
    env = PursuitEnv(config_with(f"{path}:Model"), n_worlds=2)
    env.reset()
    with pytest.raises(ValueError, match=r"compute\(\.\.\.\) raised ValueError: .*read-only.* \(at " + re.escape(f"{path}:6)")):
        env.step(np.zeros((2, 3, 2)))
    path.write_text(_Models.base + "    def compute(self, ep, ev, pp, pv, active, obstacles, dt):\n"
                    "        obstacles.border[...] = 0\n        return np.zeros(self.shape)\n")
    env = PursuitEnv(config_with(f"{path}:Model"), n_worlds=2)
    env.reset()
    with pytest.raises(ValueError, match=r"read-only"):
        env.step(np.zeros((2, 3, 2)))


def test_pool_refuses_tables_whose_evaders_were_other_files_of_one_name(tmp_path, monkeypatch, capsys):
    """An eval names the model by its reference and its file's sha256: tables of one name but other
    bytes (edited between two seeds, or another folder's file) played other evaders."""
    monkeypatch.chdir(tmp_path)
    Path("my_evader.py").write_text(documented_evader())
    base = ["eval", "--policy", "heuristic", "--set", "evader.model=my_evader.py:Straight", "--layouts", "0",
            "--episodes", "2", "--worlds", "2", "--fidelity", "point", "-q"]
    assert main(base + ["--out", "a"]) == 0, capsys.readouterr().err
    assert main(base + ["--out", "b", "--seed", "1"]) == 0, capsys.readouterr().err
    assert main(["pool", "a.json", "b.json", "--out", "ab"]) == 0, capsys.readouterr().err
    sha = json.loads(Path("a.json").read_text())["evader_model_sha256"]
    assert json.loads(Path("ab.json").read_text())["evader_model_sha256"] == sha  # a pooled table is pooled again alike
    Path("my_evader.py").write_text(documented_evader().replace("self.speed * flee", "0.5 * self.speed * flee"))
    assert main(base + ["--out", "c", "--seed", "2"]) == 0, capsys.readouterr().err
    for first in ("a.json", "ab.json"):
        assert main(["pool", first, "c.json"]) == 2
        err = capsys.readouterr().err
        assert f"c.json: its evaders are another model than {first}'s (evader.model my_evader.py:Straight, its file's " \
               f"sha256 " in err and "pool only tables of one task" in err, err


def test_a_resumed_study_plays_its_evaluation_again_when_the_evader_file_changed(tmp_path, straight):
    """study --resume keeps evaluated cells only for the same task: an evader file edited since
    flies other evaders, though the task names it alike."""
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy
    from train.study import StudyPlan
    from train.study_evaluation import KeptEvaluation

    task = config_with(straight, max_steps=20)
    plan = StudyPlan(budget_minutes=1.0, out=tmp_path, eval_task=task, layouts=(0,), episodes=2, worlds=2, resume=True)
    state: dict = {}
    kept = KeptEvaluation(plan, state, lambda: None)
    kept.start(2)
    (row,) = evaluate(make_policy("heuristic", task), task, [0], 2, plan.seed, 2, label="heuristic")
    kept.keep("heuristic", row, 1.0)
    written = json.dumps(state)
    assert KeptEvaluation(plan, json.loads(written), lambda: None).episodes == 2
    Path(straight.split(":")[0]).write_text(documented_evader() + "\n# edited\n")
    logs: list[str] = []
    assert KeptEvaluation(plan, json.loads(written), lambda: None, logs.append).episodes is None
    assert "every policy is evaluated again" in logs[0]


def test_a_model_trained_against_an_evader_of_ones_own_plays_without_its_file_and_says_so(tmp_path, monkeypatch, capsys):
    """eval --model of a run trained against evader.model FILE.py:NAME needs no FILE (the default
    evaders fly unless told otherwise), and the note on what the model was trained with names it."""
    monkeypatch.chdir(tmp_path)
    Path("my_evader.py").write_text(documented_evader())
    tiny = ["task.fidelity=point", "task.random_obstacles=0", "task.max_steps=30", "n_envs=2",
            "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=1", "run.validate_every=0", "run.validation_episodes=2",
            "run.runs_dir=runs", "task.evader.model=my_evader.py:Straight"]
    assert main(["train", "--no-progress", "--name", "s", "--total-steps", "32"] + sum((["--set", s] for s in tiny), [])) == 0
    capsys.readouterr()
    play = ["eval", "--model", "runs/s/last.pt", "--layouts", "0", "--episodes", "2", "--worlds", "2", "--fidelity", "point", "-q"]
    assert main(play + ["--set", "evader.model=my_evader.py:Straight"]) == 0
    assert "evader.model" not in capsys.readouterr().err  # the same file, named from here
    Path("my_evader.py").unlink()
    assert main(play) == 0
    err = capsys.readouterr().err
    assert f"was trained with evader.model {tmp_path / 'my_evader.py'}:Straight (this task: janosov)" in err, err


def test_simulate_says_that_an_evader_model_plays_no_part_in_its_scripted_flight(tmp_path, monkeypatch, capsys):
    """simulate flies every drone, the evaders too, on its scripted pattern: an evader model given
    there is said to play no part, not silently left unflown."""
    monkeypatch.chdir(tmp_path)
    Path("my_evader.py").write_text(documented_evader())
    assert main(["simulate", "--seconds", "0.1", "--layout", "0", "--fidelity", "point",
                 "--set", "evader.model=my_evader.py:Straight"]) == 0
    err = capsys.readouterr().err
    assert "note: evader.model my_evader.py:Straight plays no part in simulate" in err, err
    assert main(["simulate", "--seconds", "0.1", "--layout", "0", "--fidelity", "point"]) == 0
    assert "evader.model" not in capsys.readouterr().err


@pytest.mark.parametrize("command", [
    ["render", "-mc", "classic", "--policy", "heuristic", "--no-video", "--final-frame"],  # the -mc run's task as the base
    ["render", "--policy", "heuristic", "--no-video", "--final-frame", "-sc"],
    ["eval", "--policy", "heuristic", "-sc"],
])
def test_a_missing_evader_file_is_one_line_before_anything_is_printed_or_written(tmp_path, monkeypatch, capsys, command):
    monkeypatch.chdir(tmp_path)
    assert main(command + ["--fidelity", "point", "--set", "evader.model=missing.py:Straight", "-s" if command[0] == "render"
                           else "--out", "out"]) == 2
    out, err = capsys.readouterr()
    assert err.strip().splitlines() == [f"pursuit-mj {command[0]}: error: evader.model missing.py:Straight: no file "
                                        "missing.py (give FILE.py:NAME, FILE relative to the current folder or absolute)"], err
    assert out == "" and not list(tmp_path.iterdir())  # -sc prints no config that is then refused


def test_a_run_whose_evader_file_is_gone_renders_and_trains_with_the_model_replaced(tmp_path, monkeypatch, capsys):
    """A run config naming an evader file that is no longer there still serves as -mc (render) and
    --config (train -sc) when --set gives another model: the replaced reference is not looked up.
    Without the replacement it is refused, naming the file and key, as before."""
    monkeypatch.chdir(tmp_path)
    Path("run.yaml").write_text("regime: classic\ntask:\n  evader: {model: gone.py:Straight}\n")
    render = ["render", "-mc", "run.yaml", "--policy", "heuristic", "--no-video", "--final-frame", "--fidelity", "point",
              "-s", "out"]
    assert main(render) == 2
    assert "run.yaml: key 'task.evader.model': file 'gone.py'" in capsys.readouterr().err
    assert main(render + ["--set", "evader.model=janosov"]) == 0, capsys.readouterr().err
    assert list((tmp_path / "out").glob("*.png"))
    # a --set of the section replaces the key as well (a mapping updates its section)
    assert main(render[:-2] + ["-s", "out3", "--set", "evader={model: janosov}"]) == 0, capsys.readouterr().err
    capsys.readouterr()
    assert main(["train", "--config", "run.yaml", "-sc", "--set", "task.evader.model=janosov"]) == 0, capsys.readouterr().err
    assert "model: janosov" in capsys.readouterr().out
    Path("run.yaml").write_text("regime: classic\ntask:\n  layout: gone.yaml\n")  # a layout file gone: -i replaces it
    assert main(render[:-2] + ["-s", "out2"]) == 2
    assert "gone.yaml" in capsys.readouterr().err
    assert main(render[:-2] + ["-s", "out2", "-i", "1"]) == 0, capsys.readouterr().err
    Path("task.yaml").write_text("layout: 1\n")  # as does a task file that sets the layout
    assert main(render[:-2] + ["-s", "out4", "-ec", "task.yaml"]) == 0, capsys.readouterr().err
    assert main(["train", "--config", "run.yaml", "-sc", "--set", "task.layout=2"]) == 0, capsys.readouterr().err
