"""--policy FILE.py:NAME: a policy of one's own on the command line (pursuit_mj.policy_file)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from pursuit_cli import main
from pursuit_mj.config import default_config
from pursuit_mj.policies import make_policy

DOCS = Path(__file__).resolve().parent.parent / "docs"


def documented_team() -> str:
    """The my_team.py example of docs/env_api.md, as written there."""
    text = (DOCS / "env_api.md").read_text()
    block = re.search(r"```python\n# my_team.py\n(.*?)```", text, re.S)
    assert block, "docs/env_api.md lost its my_team.py example"
    return block.group(1)


def test_the_documented_team_sits_in_evals_table_paired_with_the_heuristic_team(tmp_path, capsys):
    team = tmp_path / "my_team.py"
    team.write_text(documented_team())
    out = tmp_path / "t"
    code = main(["eval", "--policy", f"{team}:Chase", "--policy", "heuristic", "--shield", "--versus", "heuristic", "--layouts", "0",
                 "--episodes", "4", "--worlds", "4", "--fidelity", "point", "-q", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads(out.with_suffix(".json").read_text())
    assert [r["policy"] for r in data["rows"]] == ["chase+shield", "heuristic"]
    assert data["policy_file_sha256"] and len(data["policy_file_sha256"][0]) == 64
    assert "chase" in json.dumps(data["paired"])
    assert data["rows"][0]["success_count"] > 0  # it acts: a pursuer flies at what it sees and catches it
    assert data["rows"][0]["collision_count"] == 0  # the shield keeps it off the walls (without it: 4 of 4)


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "mine.py"
    path.write_text(text)
    return path


GOOD = """
import numpy as np
class Still:
    name = "still"
    def __init__(self, config, seed):
        self.n = config.n_pursuers
    def reset(self, n_worlds, world_ids=None):
        pass
    def act(self, obs, spec):
        return np.zeros(obs.shape[:2] + (2,))
def helper():
    pass
"""


@pytest.mark.parametrize("text, ref_name, said", [
    ("x = (\n", "Still", r"running {path} raised SyntaxError: .* \(at {path}:1\)"),
    ("import numpy\nraise RuntimeError('no gpu here')\n", "Still", r"running {path} raised RuntimeError: no gpu here \(at {path}:2\)"),
    ("import sys\nsys.exit(3)\n", "Still", r"running {path} raised SystemExit: 3 \(at {path}:2\)"),
    (GOOD, "Missing", r"{path} defines no class or function 'Missing' \(it defines: Still, helper\)"),
    (GOOD + "\ndef broken(config, seed):\n    return 1 / 0\n", "broken",
     r"broken\(config, seed\) raised ZeroDivisionError: division by zero \(at {path}:15\)"),
    (GOOD + "\ndef text(config, seed):\n    return 'heuristic'\n", "text",
     r"text\(config, seed\) returned 'heuristic', which has no act or reset method; it must return a Policy: an object "
     r"with name, reset\(n_worlds, world_ids=None\) and act\(obs, spec\) \(docs/env_api.md\)"),
    (GOOD + "\ndef cls(config, seed):\n    return Still\n", "cls", r"cls\(config, seed\) returned the class Still, not an instance of it; it must return a Policy"),
    (GOOD + "\nclass Nameless(Still):\n    name = ''\n", "Nameless", r"has no `name` text"),
])
def test_a_policy_file_that_cannot_give_a_policy_is_refused_naming_the_file_and_line(tmp_path, text, ref_name, said):
    path = _write(tmp_path, text)
    ref = f"{path}:{ref_name}"
    with pytest.raises(ValueError) as caught:
        make_policy(ref, default_config(), 0)
    message = str(caught.value)
    assert message.startswith(f"make_policy name {ref}: ") and "\n" not in message, message
    assert re.search(said.format(path=re.escape(str(path))), message), message


def test_the_policy_file_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["eval", "--policy", str(tmp_path / "nowhere.py") + ":Team", "--layouts", "0", "--episodes", "1"]) == 2
    assert f"--policy {tmp_path / 'nowhere.py'}:Team: no file {tmp_path / 'nowhere.py'}" in capsys.readouterr().err
    assert main(["eval", "--policy", "mine.py", "--layouts", "0", "--episodes", "1"]) == 2
    assert "or FILE.py:NAME for one of your own" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["render", "--policy", "mine.py", "--no-video"])
    assert "argument --policy: expected one of heuristic, random or FILE.py:NAME, got 'mine.py'" in capsys.readouterr().err


FAILING = GOOD + """
class Failing(Still):
    name = "failing"
    def __init__(self, config, seed, when="act"):
        super().__init__(config, seed)
        self.when = when
    def reset(self, n_worlds, world_ids=None):
        if self.when == "reset" and world_ids is not None:
            raise KeyError("no such world")
    def act(self, obs, spec):
        if self.when == "act":
            return [][0]  # a slip in the user's code
        return np.zeros(obs.shape[:2] + (2,))
def on_reset(config, seed):
    return Failing(config, seed, "reset")
"""


@pytest.mark.parametrize("ref_name, said", [
    ("Failing", r"act\(obs, spec\) raised IndexError: list index out of range \(at {path}:24\)"),
    ("on_reset", r"reset\(n_worlds, world_ids\) raised KeyError: 'no such world' \(at {path}:21\)"),
])
def test_an_error_raised_in_a_policy_files_act_or_reset_is_one_line_naming_the_file_and_line(tmp_path, capsys, ref_name, said):
    path = _write(tmp_path, FAILING)
    ref = f"{path}:{ref_name}"
    assert main(["eval", "--policy", ref, "--layouts", "0", "--episodes", "2", "--worlds", "1", "--fidelity", "point",
                 "--set", "max_steps=3"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pursuit-mj eval: error: --policy {ref}: ") and "\n" not in err, err
    assert re.search(said.format(path=re.escape(str(path))), err), err


def test_a_policy_from_a_file_keeps_its_own_attributes(tmp_path):
    path = _write(tmp_path, GOOD + "Still.has_shield = True\nStill.speed = 0.25\n")
    policy = make_policy(f"{path}:Still", default_config(), 0)
    assert policy.name == "still" and policy.has_shield is True and policy.speed == 0.25 and policy.n == 3


SCRIBBLER = GOOD + """
class East(Still):
    name = "east"
    def act(self, obs, spec):
        return np.tile([1.0, 0.0], obs.shape[:2] + (1,))
class Scribbler(East):
    name = "scribbler"
    def act(self, obs, spec):
        obs[...] = 0.0  # normalised in place, say: the caller's array
        return super().act(obs, spec)
"""


def test_a_policy_that_writes_into_its_observations_changes_nothing_its_shield_reads(tmp_path):
    """The shield (eval/render/fly --shield) reads the observations after the policy acted on
    them: a policy that wrote into them (an in-place normalisation) had its shield judge walls and
    teammates from what it wrote, not from what the pursuers saw."""
    from pursuit_mj.env import PursuitEnv
    from pursuit_mj.shield import shield_policy

    path = _write(tmp_path, SCRIBBLER)
    config = default_config(fidelity="point")
    env = PursuitEnv(config, n_worlds=2, seed=1)
    obs = env.reset()
    seen = obs.copy()
    acted = []
    for name in ("East", "Scribbler"):
        team = shield_policy(make_policy(f"{path}:{name}", config), config)
        team.reset(2)
        acted.append(team.act(obs, env.obs_spec))
    assert np.array_equal(obs, seen)
    np.testing.assert_array_equal(acted[1], acted[0])


def test_a_policy_file_given_as_a_model_is_pointed_to_policy(tmp_path, capsys):
    """--model takes checkpoints: a policy file given there was refused as 'no such checkpoint file'
    or 'not a torch zip archive', without a word of --policy."""
    path = _write(tmp_path, GOOD)
    for model in (f"{path}:Still", str(path)):
        assert main(["eval", "--model", model, "--layouts", "0", "--episodes", "1"]) == 2
        err = capsys.readouterr().err
        assert f"--model {model}: " in err and f"a policy of your own goes through --policy {path}:NAME" in err, err


def test_eval_resume_plays_again_only_the_rows_of_a_policy_file_edited_since(tmp_path, capsys, monkeypatch):
    """A policy file fixed after it failed mid-table: --resume refused the whole table, so the rows of
    every other policy had to be played again too. Now only the edited file's rows are, and it says so."""
    import pursuit_mj.evaluation as evaluation

    path = _write(tmp_path, GOOD)
    cmd = ["eval", "--policy", "heuristic", "--policy", f"{path}:Still", "--layouts", "0", "--episodes", "1", "--worlds",
           "1", "--fidelity", "point", "--set", "max_steps=5", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 0
    first = json.loads((tmp_path / "t.json").read_text())
    (tmp_path / "t.interrupted.json").write_text(json.dumps(first))  # as if stopped at the end
    assert main(cmd + ["--resume"]) == 0  # unchanged: the kept rows are taken
    assert "played again" not in capsys.readouterr().err
    (tmp_path / "t.interrupted.json").write_text(json.dumps(first))
    path.write_text(GOOD.replace("np.zeros", "0.5 * np.ones"))
    real, cells = evaluation.evaluate, []
    monkeypatch.setattr(evaluation, "evaluate", lambda *a, **k: cells.append(k["label"]) or real(*a, **k))
    assert main(cmd + ["--resume"]) == 0
    err = capsys.readouterr().err
    assert "--resume: the policy file of still changed since the interrupted eval: its rows are played again" in err, err
    assert cells == ["still"]  # the heuristic team's row was taken from the kept file
    assert json.loads((tmp_path / "t.json").read_text())["policy_file_sha256"] != first["policy_file_sha256"]


def test_an_interrupted_eval_kept_before_policy_files_resumes(tmp_path, capsys):
    """Rows kept by an eval from before the key existed have no policy_file_sha256: none is []."""
    cmd = ["eval", "--policy", "heuristic", "--layouts", "0", "--episodes", "1", "--worlds", "1", "--fidelity", "point",
           "--set", "max_steps=5", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 0
    data = json.loads((tmp_path / "t.json").read_text())
    del data["policy_file_sha256"]
    (tmp_path / "t.interrupted.json").write_text(json.dumps(data))
    assert main(cmd + ["--resume"]) == 0, capsys.readouterr().err


def test_render_names_its_files_by_the_policys_name_and_the_files_content(tmp_path):
    path = _write(tmp_path, GOOD.replace('name = "still"', 'name = "my still/team"'))
    cmd = ["render", "--policy", f"{path}:Still", "--no-video", "--final-frame", "-s", str(tmp_path / "r"), "--fidelity", "point",
           "--set", "max_steps=3"]
    assert main(cmd) == 0
    first = sorted(p.name for p in (tmp_path / "r").iterdir())
    assert first and all(n.startswith("my_still_team_layout0_point_") for n in first), first
    path.write_text(path.read_text().replace("np.zeros", "0.5 * np.ones"))
    assert main(cmd) == 0
    second = sorted(p.name for p in (tmp_path / "r").iterdir())
    assert len(second) == 2 * len(first), second  # other code, other pictures: the first render is kept


TWO_SPEEDS = """
import numpy as np
class Go:
    name = "go"
    def __init__(self, speed):
        self.speed = speed
    def reset(self, n_worlds, world_ids=None):
        pass
    def act(self, obs, spec):
        a = np.zeros(obs.shape[:2] + (2,))
        a[..., 0] = self.speed
        return a
def fast(config, seed):
    return Go(1.0)
def slow(config, seed):
    return Go(0.1)
"""


def test_eval_resume_refuses_the_rows_of_another_factory_of_the_same_file(tmp_path, capsys):
    """fast and slow of one file both give a policy named 'go': the label and the file's sha256
    are the same, so a resume with slow took the rows fast had played."""
    path = _write(tmp_path, TWO_SPEEDS)
    cmd = ["eval", "--layouts", "0", "--episodes", "1", "--worlds", "1", "--fidelity", "point",
           "--set", "max_steps=5", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd + ["--policy", f"{path}:fast"]) == 0
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["policy_file_names"] == ["fast"]
    (tmp_path / "t.interrupted.json").write_text(json.dumps(data))
    assert main(cmd + ["--policy", f"{path}:slow", "--resume"]) == 2
    assert "--resume: policy_file_names differs from the interrupted eval's" in capsys.readouterr().err
    assert main(cmd + ["--policy", f"{path}:fast", "--resume"]) == 0, capsys.readouterr().err


def test_render_keeps_apart_the_files_of_two_factories_of_the_same_file(tmp_path):
    """fast and slow both give a policy named 'go' from one file: the render of slow wrote over
    the render of fast (same name, same file bytes, same digest)."""
    path = _write(tmp_path, TWO_SPEEDS)
    cmd = ["--no-video", "--final-frame", "-s", str(tmp_path / "r"), "--fidelity", "point", "--set", "max_steps=3"]
    assert main(["render", "--policy", f"{path}:fast"] + cmd) == 0
    assert main(["render", "--policy", f"{path}:slow"] + cmd) == 0
    names = sorted(p.name for p in (tmp_path / "r").iterdir())
    assert len(names) == 2 and all(n.startswith("go_layout0_point_") for n in names), names


@pytest.mark.parametrize("name, start", [("x" * 300, "x" * 57 + "-"), ("..", "_._layout0_point_"), (".hidden", "_hidden_layout0_point_")])
def test_render_names_its_files_for_a_long_or_dotted_policy_name(tmp_path, name, start):
    """A 300-character name ended render in OSError 'File name too long'; a name with a leading
    dot made hidden files."""
    path = _write(tmp_path, GOOD.replace('name = "still"', f"name = {name!r}"))
    cmd = ["render", "--policy", f"{path}:Still", "--no-video", "--final-frame", "-s", str(tmp_path / "r"), "--fidelity", "point",
           "--set", "max_steps=3"]
    assert main(cmd) == 0
    (written,) = [p.name for p in (tmp_path / "r").iterdir()]
    assert written.startswith(start) and len(written.encode()) < 255, written


@pytest.mark.parametrize("name", ["heuristic", "random", "heuristic+shield", "random#2"])
def test_a_policy_named_as_a_built_in_teams_rows_are_is_refused(tmp_path, capsys, name):
    """--policy mine.py:Still --policy heuristic with Still.name 'heuristic' labelled the file's
    policy 'heuristic' and the built-in team 'heuristic#2', and eval paired the team against the
    file's policy under the heading 'paired with heuristic'."""
    path = _write(tmp_path, GOOD.replace('name = "still"', f"name = {name!r}"))
    code = main(["eval", "--policy", f"{path}:Still", "--policy", "heuristic", "--layouts", "0", "--episodes", "1",
                 "--fidelity", "point", "--set", "max_steps=5", "-q", "--json", str(tmp_path / "t.json")])
    assert code == 2 and not (tmp_path / "t.json").exists()
    err = capsys.readouterr().err
    assert f"--policy {path}:Still: the policy it gives is named {name!r}, as a built-in team's rows are labelled" in err, err
    for ok in ("heuristics", "my heuristic", "random+shields"):
        path.write_text(GOOD.replace('name = "still"', f"name = {ok!r}"))
        assert make_policy(f"{path}:Still", default_config(), 0).name == ok


def test_an_eval_whose_policy_file_fails_mid_table_says_where_the_finished_rows_are(tmp_path, capsys):
    """The heuristic team's row was kept in t.interrupted.json, but the one-line error said nothing of
    it: the user could not know that --resume, once the file is fixed, plays only the rest."""
    path = _write(tmp_path, FAILING)
    cmd = ["eval", "--policy", "heuristic", "--policy", f"{path}:Failing", "--layouts", "0", "--episodes", "1", "--worlds",
           "1", "--fidelity", "point", "--set", "max_steps=3", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 2
    err = capsys.readouterr().err.strip()
    kept = tmp_path / "t.interrupted.json"
    assert "\n" not in err and err.endswith(f"; 1 finished row is kept in {kept}: run the same command with --resume "
                                            f"once the cause is mended, to play only the rest"), err
    path.write_text(FAILING.replace("return [][0]", "return np.zeros(obs.shape[:2] + (2,))"))
    assert main(cmd + ["--resume"]) == 0


def test_a_folder_named_like_the_file_and_a_name_that_is_no_callable_are_told_as_such(tmp_path, monkeypatch):
    """--policy team.py:T with a folder team.py said 'no file team.py (give FILE.py:NAME, FILE
    relative to the current folder ...)' about a path that is there; and a NAME bound to a number
    was 'defines no class or function (it defines: none)', as if the name were missing."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "team.py").mkdir()
    with pytest.raises(ValueError, match=r"^--policy team\.py:T: team\.py is a folder, not a Python file$"):
        make_policy("team.py:T", default_config(), 0, "--policy")  # as the CLI calls it
    (tmp_path / "other.py").write_text("T = 5\n")
    with pytest.raises(ValueError, match=r"^--policy other\.py:T: other\.py binds T to an int, not a class or function$"):
        make_policy("other.py:T", default_config(), 0, "--policy")


WRONG_ANSWERS = GOOD + """
class Flat(Still):
    name = "flat"
    def act(self, obs, spec):
        return np.zeros((obs.shape[0] * obs.shape[1], 2))  # one row per pursuer of the batch, flattened
class Undefined(Still):
    name = "undefined"
    def act(self, obs, spec):
        return np.full(obs.shape[:2] + (2,), np.nan)  # a value its computation left undefined
"""


@pytest.mark.parametrize("command", ["eval", "render"])
@pytest.mark.parametrize("shield", [False, True])
@pytest.mark.parametrize("ref_name, said", [
    ("Flat", r"act\(\) gave actions of shape \((3|6), 2\), expected \((1|2), 3, 2\)"),
    ("Undefined", r"act\(\) gave nan for world 0, pursuer 0, vx"),
])
def test_a_policy_file_answering_another_shape_or_nan_is_refused_naming_the_file(tmp_path, capsys, command, shield, ref_name, said):
    # eval said "policy flat: act() gave actions of shape ..." without the file the policy came from
    # (and behind --shield "Shielded: policy flat gave ..."), where an exception it raises names it
    path = _write(tmp_path, WRONG_ANSWERS)
    ref = f"{path}:{ref_name}"
    args = ["--policy", ref, "--fidelity", "point", "--set", "max_steps=3"] + (["--shield"] if shield else [])
    if command == "eval":
        args += ["--layouts", "0", "--episodes", "2", "--worlds", "2"]
    else:
        args += ["-i", "0", "--no-video", "--final-frame", "-s", str(tmp_path / "renders")]
    assert main([command, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pursuit-mj {command}: error: --policy {ref}: ") and "\n" not in err, err
    assert re.search(said, err), err
