"""Reward terms of one's own (pursuit_mj.custom_rewards): paid, logged and checked like the task's."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from pursuit_cli import main

from pursuit_mj.config import default_config
from pursuit_mj.custom_rewards import load_reward_file, load_reward_files
from pursuit_mj.env import PursuitEnv
from pursuit_mj.policies import make_policy
from pursuit_mj.pz_env import PursuitParallelEnv
from pursuit_mj.rewards import REWARD_TERMS

W, N = 3, 3


def point_config(**changes):
    return dataclasses.replace(default_config(), fidelity="point", **changes)


def flee_actions(steps: int, seed: int = 0) -> np.ndarray:
    """(steps, W, N, 2) fixed random actions: both envs of a comparison fly the same."""
    return np.random.default_rng(seed).uniform(-1, 1, (steps, W, N, 2))


def test_a_term_is_paid_beside_the_tasks_terms_and_changes_nothing_else():
    plain = PursuitEnv(point_config(), n_worlds=W, seed=3)
    paid = PursuitEnv(point_config(), n_worlds=W, seed=3, extra_rewards={"bonus": lambda step: np.full((W, N), 0.25)})
    assert np.array_equal(plain.reset(), paid.reset())
    episodes = []
    for a in flee_actions(40):
        o1, r1, te1, tr1, i1 = plain.step(a)
        o2, r2, te2, tr2, i2 = paid.step(a)
        assert np.array_equal(o1, o2) and np.array_equal(te1, te2) and np.array_equal(tr1, tr2)
        for k in REWARD_TERMS:
            assert np.array_equal(i1["reward_terms"][k], i2["reward_terms"][k])
        assert list(i2["reward_terms"]) == [*REWARD_TERMS, "bonus"]
        assert i2["reward_terms"]["bonus"].dtype == np.float32
        np.testing.assert_allclose(r2, r1 + 0.25, atol=1e-6)
        episodes += i2["episodes"]
    snap = paid.snapshot(0)
    assert snap.reward_terms["bonus"].tolist() == [0.25] * N
    assert paid.returns["bonus"][0] == pytest.approx(0.25 * paid.steps[0])
    assert episodes, "no episode ended in 40 steps of random flight"  # collisions end them
    assert all(e.returns["bonus"] == pytest.approx(0.25 * e.steps) for e in episodes)


def test_ended_worlds_are_paid_nothing_whatever_the_term_returns():
    env = PursuitEnv(point_config(), n_worlds=W, seed=3, auto_reset=False, extra_rewards={"bonus": lambda step: np.ones((W, N))})
    env.reset()
    ended_once = False
    for a in flee_actions(60, seed=1):
        was_done = env.done.copy()
        _, reward, *_, info = env.step(a)
        assert (info["reward_terms"]["bonus"][was_done] == 0).all()
        assert (info["reward_terms"]["bonus"][~was_done] == 1).all()
        ended_once |= was_done.any()
    assert ended_once


@pytest.mark.parametrize("unpaid", [np.nan, np.inf, 1e39])
def test_what_a_term_returns_for_an_ended_world_is_not_checked_as_it_is_not_paid(unpaid):
    """A frozen world's values are replaced by 0 (docs/env_api.md: "whatever the callable
    returns"), so a term's NaN there (a heading of a drone at rest, a distance to the nearest
    free evader once none is free) must not stop the run."""
    ended = np.zeros(W, bool)  # the worlds whose episode ended before the step the term pays for
    term = lambda step: np.where(ended[:, None], unpaid, 1.0) * np.ones((W, N))  # noqa: E731
    env = PursuitEnv(point_config(), n_worlds=W, seed=3, auto_reset=False, extra_rewards={"heading": term})
    env.reset()
    for a in flee_actions(60, seed=1):
        ended[:] = env.done
        with np.errstate(all="raise"):  # no warning of a cast overflow either: the value is not used
            *_, info = env.step(a)
        assert (info["reward_terms"]["heading"][ended] == 0).all()
        assert (info["reward_terms"]["heading"][~ended] == 1).all()
    assert ended.any()


def test_the_step_view_holds_what_the_env_knew_before_and_after_the_step():
    seen = []

    def record(step):
        seen.append(step)
        return np.zeros((W, N))

    config = point_config()
    env = PursuitEnv(config, n_worlds=W, seed=5, auto_reset=False, extra_rewards={"watch": record})
    team = make_policy("heuristic", config)  # it finds the evader, so `known` changes
    obs = env.reset()
    team.reset(W)
    for _ in range(150):
        before = [env.snapshot(w) for w in range(W)]
        a = team.act(obs, env.obs_spec)
        obs, *_ = env.step(a)
        after = [env.snapshot(w) for w in range(W)]
        step = seen[-1]
        for w in range(W):
            if before[w].outcome:  # ended before this step: nothing moved
                continue
            assert np.array_equal(step.known_before[w], before[w].known)
            assert np.array_equal(step.known[w], after[w].known) and np.array_equal(step.seen[w], after[w].seen)
            assert np.array_equal(step.pursuer_pos_before[w], before[w].pursuer_pos[:, :2])
            assert np.array_equal(step.pursuer_pos[w], after[w].pursuer_pos[:, :2])
            assert np.array_equal(step.evader_pos[w], after[w].evader_pos[:, :2])
            assert step.steps[w] == after[w].step
            assert step.outcome[w] == after[w].outcome
        np.testing.assert_array_equal(step.actions, np.clip(a, -1, 1))
    known = [bool(s.known.any()) for s in seen]
    assert any(known) and not all(known), "`known` never changed: the checks above saw little"


def test_a_term_cannot_change_the_step_it_reads():
    def meddle(step):
        step.pursuer_pos[:] = 0.0
        return np.zeros((W, N))

    env = PursuitEnv(point_config(), n_worlds=W, extra_rewards={"meddle": meddle})
    env.reset()
    with pytest.raises(ValueError, match=r"reward term 'meddle' raised ValueError: .*read-only"):
        env.step(np.zeros((W, N, 2)))


@pytest.mark.parametrize("term, message", [
    (lambda step: np.zeros(W), r"reward term 'bad' returned shape \(3,\), expected \(3, 3\) \(worlds, pursuers\)"),
    (lambda step: np.full((W, N), np.nan), r"reward term 'bad' returned nan at \(world, pursuer\) \(0, 0\)"),
    (lambda step: np.full((W, N), "x"), r"reward term 'bad' returned an array of dtype <U1, not real numbers"),
    (lambda step: np.full((W, N), 1e39), r"reward term 'bad' returned 1e\+39 at \(world, pursuer\) \(0, 0\), "
                                         r"beyond float32 \(the reward's type\)$"),
    (lambda step: 1 / 0, r"reward term 'bad' raised ZeroDivisionError: division by zero"),
    (lambda step: np.ma.masked_array(np.ones((W, N)), mask=np.eye(W, N, dtype=bool)),
     r"reward term 'bad' returned: a masked array with 3 masked entries; give every value"),
])
def test_what_a_term_returns_is_checked_and_named(term, message):
    env = PursuitEnv(point_config(), n_worlds=W, extra_rewards={"bad": term})
    env.reset()
    with pytest.raises(ValueError, match=r"PursuitEnv extra_rewards: " + message), np.errstate(over="raise"):
        env.step(np.zeros((W, N, 2)))


def test_a_term_computed_in_torch_is_paid_its_values():
    """A term may compute with torch, as a policy may act with it: a tensor that carries a gradient or
    is of half precision was refused as 'not an array', though the env takes such actions."""
    terms = {"grad": lambda step: torch.full((W, N), 0.5, requires_grad=True) * 1.0,
             "half": lambda step: torch.full((W, N), 0.25, dtype=torch.bfloat16)}
    env = PursuitEnv(point_config(), n_worlds=W, extra_rewards=terms)
    env.reset()
    *_, info = env.step(np.zeros((W, N, 2)))
    assert (info["reward_terms"]["grad"] == 0.5).all() and (info["reward_terms"]["half"] == 0.25).all()


@pytest.mark.parametrize("extra, message", [
    ({"capture": lambda s: 0}, r"'capture' is one of the task's own reward terms"),
    ({"2fast": lambda s: 0}, r"'2fast' is not a usable term name"),
    ({"bonus": 1.0}, r"the term 'bonus' is 1.0, not a callable taking a StepView"),
    ([lambda s: 0], r"expected a mapping of term name -> callable\(StepView\), got list"),
])
def test_terms_are_checked_when_the_env_is_made(extra, message):
    with pytest.raises(ValueError, match=r"PursuitEnv extra_rewards: " + message):
        PursuitEnv(point_config(), n_worlds=1, extra_rewards=extra)


def test_the_pettingzoo_env_pays_the_term_to_each_agent():
    env = PursuitParallelEnv(point_config(), seed=0, extra_rewards={"bonus": lambda step: np.full((1, N), 0.5)})
    env.reset(seed=0)
    _, rewards, _, _, infos = env.step({agent: np.zeros(2) for agent in env.agents})
    assert all(info["reward_terms"]["bonus"] == 0.5 for info in infos.values())
    plain = PursuitParallelEnv(point_config(), seed=0)
    plain.reset(seed=0)
    _, plain_rewards, *_ = plain.step({agent: np.zeros(2) for agent in plain.agents})
    assert all(rewards[a] == pytest.approx(plain_rewards[a] + 0.5) for a in rewards)


def test_a_term_from_a_file_is_named_by_its_reference_in_errors(tmp_path):
    path = tmp_path / "terms.py"
    path.write_text("import numpy as np\n\ndef good(step):\n    return np.zeros(step.pursuer_pos.shape[:2])\n\n"
                    "def broken(step):\n    return step.nothing\n")
    name, term = load_reward_file(f"{path}:good")
    assert name == "good"
    env = PursuitEnv(point_config(), n_worlds=W, extra_rewards=load_reward_files([f"{path}:good", f"{path}:broken"]))
    env.reset()
    with pytest.raises(ValueError, match=rf"^--reward {path}:broken: reward term 'broken' raised AttributeError: .*nothing.* "
                                         rf"\(at {path}:7\)$"):
        env.step(np.zeros((W, N, 2)))


@pytest.mark.parametrize("ref, message", [
    ("{p}:absent", r"--reward {p}:absent: {p} defines no function 'absent' \(it defines: capture, good\)"),
    ("{p}:capture", r"--reward {p}:capture: 'capture' is one of the task's own reward terms"),
    ("{p}", r"--reward '{p}': expected FILE.py:NAME"),
    ("{d}/none.py:good", r"--reward {d}/none.py:good: no file {d}/none.py"),
])
def test_a_reward_file_that_cannot_give_a_term_is_refused_in_one_line(tmp_path, ref, message):
    path = tmp_path / "terms.py"
    path.write_text("def good(step):\n    return 0\n\ncapture = good\n")
    ref, message = ref.format(p=path, d=tmp_path), message.format(p=path, d=tmp_path)
    with pytest.raises(ValueError, match=message):
        load_reward_file(ref)


def test_two_terms_of_one_name_are_refused(tmp_path):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "t.py").write_text("def sight(step):\n    return 0\n")
    refs = [f"{tmp_path}/a/t.py:sight", f"{tmp_path}/b/t.py:sight"]
    with pytest.raises(ValueError, match=r"a term 'sight' is already given"):
        load_reward_files(refs)


# ---------------------------------------------------------------- in training: pursuit-mj train --reward

DOCS = Path(__file__).resolve().parent.parent / "docs"
TINY = ["task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30",
        "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=1",
        "run.validate_every=0", "run.validation_episodes=2"]


def documented_sight() -> str:
    """The sight.py example of docs/training.md, as written there."""
    block = re.search(r"```python\n# sight.py\n(.*?)```", (DOCS / "training.md").read_text(), re.S)
    assert block, "docs/training.md lost its sight.py example"
    return block.group(1)


def sets(items):
    return sum((["--set", s] for s in items), [])


def rows_of(run_dir: Path) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]


def test_the_documented_term_trains_is_logged_and_guards_its_resume(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # the docs give the file relative to the current folder
    Path("sight.py").write_text(documented_sight())
    args = (["train", "--no-progress", "--name", "sighted", "--total-steps", "64", "--reward", "sight.py:sight"]
            + sets(TINY + ["task.observability=full"]))  # the evader known from the start: the term pays at once
    assert main(args) == 0, capsys.readouterr().err
    run = tmp_path / "runs" / "sighted"
    rows = rows_of(run)
    paid = [r["reward_terms_per_step"]["sight"] for r in rows]
    assert all(v < 0 for v in paid)  # known throughout: 0.99 x 1 - 1 per step, and -1 where a collision ends one
    assert all("sight" in r["reward_terms_per_step"] for r in rows)
    data = torch.load(run / "last.pt", weights_only=True)
    assert data["train_config"]["rewards"] == [f"{tmp_path / 'sight.py'}:sight"]  # absolute: resumable from anywhere
    assert list(data["code_sha256"]) == [str(tmp_path / "sight.py")]

    monkeypatch.chdir(run.parent.parent.parent)  # a resume from another folder loads the stored path
    Path(tmp_path / "sight.py").write_text(documented_sight().replace("WEIGHT = 1.0", "WEIGHT = 2.0"))
    assert main(["train", "--no-progress", "--resume", str(run), "--total-steps", "128"]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'sight.py'} (rewards) has changed since the run started" in err
    Path(tmp_path / "sight.py").write_text(documented_sight())
    assert main(["train", "--no-progress", "--resume", str(run), "--total-steps", "128"]) == 0
    assert [r["update"] for r in rows_of(run)] == [1, 2, 3, 4]


def test_a_term_is_paid_in_the_overlapped_rollout_worker_too(tmp_path, capsys):
    (tmp_path / "bonus.py").write_text("import numpy as np\n\ndef bonus(step):\n    return np.full(step.pursuer_pos.shape[:2], 0.5)\n")
    args = ["train", "--no-progress", "--name", "o", "--total-steps", "128", "--reward", f"{tmp_path}/bonus.py:bonus"]
    assert main(args + sets(TINY + [f"run.runs_dir={tmp_path}", "run.overlap=true"])) == 0, capsys.readouterr().err
    rows = rows_of(tmp_path / "o")
    assert len(rows) == 4 and all(r["reward_terms_per_step"]["bonus"] == pytest.approx(0.5) for r in rows)


def test_a_train_file_names_its_terms_beside_itself(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "exp"
    folder.mkdir()
    (folder / "terms.py").write_text("import numpy as np\n\ndef calm(step):\n    return -0.1 * np.abs(step.actions).sum(-1)\n")
    (folder / "run.yaml").write_text("name: calm\nrewards: [terms.py:calm]\n")
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--config", "exp/run.yaml", "--no-progress", "--total-steps", "32"] + sets(TINY)) == 0, capsys.readouterr().err
    rows = rows_of(tmp_path / "runs" / "calm")
    assert rows[0]["reward_terms_per_step"]["calm"] < 0


@pytest.mark.parametrize("args, message", [
    (["--reward", "{d}/none.py:sight"], "--reward {d}/none.py:sight: no file {d}/none.py"),
    (["--reward", "sight"], "--reward 'sight': expected FILE.py:NAME"),
    (["--reward", "{d}/t.py:nothing"], "--reward {d}/t.py:nothing: {d}/t.py defines no function 'nothing' (it defines: sight)"),
    (["--set", "rewards=[sight]"], "key 'rewards': 'sight' is not FILE.py:NAME"),
])
def test_a_bad_reward_is_refused_in_one_line_before_training(tmp_path, capsys, args, message):
    (tmp_path / "t.py").write_text("def sight(step):\n    return 0\n")
    args = [a.format(d=tmp_path) for a in args]
    code = main(["train", "--no-progress", "--total-steps", "32"] + args + sets(TINY + [f"run.runs_dir={tmp_path}/runs"]))
    err = capsys.readouterr().err
    assert code == 2 and message.format(d=tmp_path) in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "runs").exists()


def test_a_reward_flag_beside_resume_run_dir_is_refused_not_ignored(tmp_path, capsys):
    """--resume RUN_DIR continues with the stored config: a --reward beside it (another term, or
    one the run never had) was silently dropped, the run going on without it."""
    (tmp_path / "bonus.py").write_text("import numpy as np\n\ndef bonus(step):\n    return np.full(step.pursuer_pos.shape[:2], 0.5)\n")
    args = ["train", "--no-progress", "--name", "r", "--total-steps", "32"]
    assert main(args + sets(TINY + [f"run.runs_dir={tmp_path}"])) == 0, capsys.readouterr().err
    capsys.readouterr()
    code = main(["train", "--no-progress", "--resume", str(tmp_path / "r"), "--total-steps", "64",
                 "--reward", f"{tmp_path}/bonus.py:bonus"])
    err = capsys.readouterr().err
    assert code == 2 and "--reward cannot change it" in err, err
    assert [r["update"] for r in rows_of(tmp_path / "r")] == [1]


def test_the_documented_shaping_keeps_its_potential_at_a_timeout():
    """A timeout truncates an episode (training bootstraps from the value of info["final_obs"]),
    so potential-based shaping pays GAMMA x the potential there as at any step; only a
    termination (success, collision) takes it to 0. The example took it to 0 at a timeout too:
    -WEIGHT for having the evader in sight when time ran out, the best policy changed."""
    namespace: dict = {}
    exec(documented_sight(), namespace)
    gamma, weight = namespace["GAMMA"], namespace["WEIGHT"]
    config = point_config(observability="full", random_obstacles=0, max_steps=12)
    env = PursuitEnv(config, n_worlds=W, seed=0, auto_reset=False, extra_rewards={"sight": namespace["sight"]})
    env.reset()
    for _ in range(config.max_steps):
        *_, info = env.step(np.zeros((W, N, 2)))  # hovering: no capture, no collision, the evader in sight
    assert info["outcome"].tolist() == ["timeout"] * W
    np.testing.assert_allclose(info["reward_terms"]["sight"], gamma * weight - weight, atol=1e-6)
    assert env.returns["sight"] == pytest.approx(np.full(W, config.max_steps * (gamma * weight - weight)), abs=1e-5)


def test_a_term_that_fails_in_the_overlapped_rollout_worker_is_one_line_too(tmp_path, capsys):
    """run.overlap=true steps the env in a child process: a failing term came back as the child's
    traceback (exit 1) where the same run without overlap says one line naming the term's line."""
    (tmp_path / "late.py").write_text("import numpy as np\n\ndef late(step):\n    if (step.steps > 3).any():\n"
                                      "        return step.nothing\n    return np.zeros(step.pursuer_pos.shape[:2])\n")
    args = ["train", "--no-progress", "--name", "o", "--total-steps", "64", "--reward", f"{tmp_path}/late.py:late"]
    for overlap in ("false", "true"):
        code = main(args + sets(TINY + [f"run.runs_dir={tmp_path}/{overlap}", f"run.overlap={overlap}"]))
        err = capsys.readouterr().err
        assert code == 2, err
        assert err.strip().splitlines() == [f"pursuit-mj train: error: rewards {tmp_path}/late.py:late: reward term 'late' "
                                            f"raised AttributeError: 'StepView' object has no attribute 'nothing' "
                                            f"(at {tmp_path}/late.py:5)"], err


@pytest.mark.parametrize("ref", ["{d}/none.py:sight", "{d}/t.py:nothing"])
def test_a_study_train_set_reward_that_cannot_be_loaded_is_found_before_anything_runs(tmp_path, capsys, ref):
    """Found at the first arm's start, after the heuristic team's evaluation was kept in study.json
    (which then refuses a fresh study in that folder), as bad layouts were."""
    (tmp_path / "t.py").write_text("def sight(step):\n    return 0\n")
    out = tmp_path / "study"
    ref = ref.format(d=tmp_path)
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", f"rewards=[{ref}]"]) == 2
    err = capsys.readouterr().err
    assert f"--train-set rewards=[{ref}]: every arm refuses it" in err and f"rewards {ref}: " in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_show_config_refuses_a_reward_that_training_would_refuse(tmp_path, capsys, monkeypatch):
    """-sc refuses what training would (its contract): a rewards key naming no file was shown as fine."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "run.yaml").write_text("rewards: [none.py:sight]\n")
    for args in (["--set", "rewards=[none.py:sight]"], ["--config", "run.yaml"]):
        assert main(["train", "-sc", *args]) == 2
        err = capsys.readouterr().err
        assert "rewards" in err and "none.py" in err and len(err.strip().splitlines()) == 1, err


def test_a_train_file_naming_a_reward_file_found_nowhere_is_named_with_its_key(tmp_path, monkeypatch, capsys):
    """As a layout file a train file names: the message named neither the YAML file nor that FILE
    is looked for beside it too ("train config: rewards ...: give FILE relative to the current folder")."""
    (tmp_path / "exp").mkdir()
    (tmp_path / "exp" / "run.yaml").write_text("name: calm\nrewards: [terms.py:calm]\n")
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--config", "exp/run.yaml", "--no-progress", "--total-steps", "32"] + sets(TINY)) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"pursuit-mj train: error: exp/run.yaml: key 'rewards': file 'terms.py' (of terms.py:calm): "
                           f"no such file in the current folder ({tmp_path}) or beside exp"), err
    assert not (tmp_path / "runs").exists()


def test_a_diverged_world_pays_no_term_of_ones_own_as_documented():
    """Its positions are MuJoCo's reset, not the drones': a term is set to 0 there as the task's
    measured terms are, while the task's collision penalty is paid (the StepView docstring says so)."""
    import warnings

    from pursuit_mj import custom_rewards

    env = PursuitEnv(point_config(random_obstacles=0), n_worlds=2, seed=0, extra_rewards={"one": lambda s: np.ones((2, N))})
    env.reset()
    env.physics.qvel[0, :] = 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        *_, info = env.step(np.zeros((2, N, 2)))
    assert info["outcome"].tolist() == ["collision", ""]
    assert info["reward_terms"]["one"].tolist() == [[0.0] * N, [1.0] * N]
    assert "diverged" in custom_rewards.StepView.__doc__


def test_obstacle_gap_measures_the_layout_alone_as_the_tasks_clearance_rule_does():
    """A caught evader stays where it was caught, but StepView.obstacle_gap leaves it out, as the task's
    clearance rule and proximity term do (its docstring says so): its catcher, within capture_radius
    of it, creeps up to it with the gap to the walls unchanged and no proximity paid, and collides
    only when its body touches the caught one."""
    seen = []

    def spy(step):
        seen.append((step.obstacle_gap[0, 0], np.linalg.norm(step.pursuer_pos[0, 0] - step.evader_pos[0, 0]),
                     bool(step.captured[0, 0])))
        return np.zeros(step.obstacle_gap.shape)

    env = PursuitEnv(point_config(n_evaders=2, layout=0, random_obstacles=0), seed=0, extra_rewards={"spy": spy})
    env.reset()
    env.physics.reset([0], np.array([[[1.8, 2.0], [0.6, 0.6], [3.0, 0.6], [1.8, 2.2], [1.8, 4.5]]]))
    env._obs = env._observe()
    actions = np.zeros((1, 3, 2))
    actions[0, 0] = [0.0, 0.25]  # pursuer 0 catches evader 0, then creeps on toward it
    for _ in range(40):
        _, _, terminated, _, info = env.step(actions)
        if terminated[0]:
            break
        assert info["reward_terms"]["proximity"][0, 0] == 0.0
    assert info["outcome"][0] == "collision" and all(caught for _, _, caught in seen)
    assert [gap for gap, _, _ in seen] == pytest.approx([1.8] * len(seen))  # the left border, 1.8 m away
    assert seen[-2][1] < 0.2 and 0.13 < seen[-1][1] < 0.14  # inside its capture disc; contact at the bodies' touch
