"""`pursuit-mj study` end to end on a tiny budget: every regime trains, everything is evaluated."""

import dataclasses
import json
import os

import pytest

from conftest import weights_go_nan_at_update
from pursuit_cli import main

TRAIN = ["task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30", "n_envs=2", "ppo.batch_size=64",
         "ppo.minibatch_size=32", "ppo.epochs=1", "imitation.grad_steps=2", "run.validate_every=0", "run.validation_episodes=2"]
# the tests of resuming and refusing: 3 updates an arm, so that the arms end by their steps long before their share
# of the budget (the end-to-end test keeps the arms timed by their shares, as a user's study is)
BY_STEPS = [*TRAIN, "total_steps=96"]


@pytest.fixture
def no_training_floor(monkeypatch):
    """Lets a study under a minute run: it would refuse budgets that leave an arm under 10 s."""
    from train import study

    monkeypatch.setattr(study, "MIN_ARM_TRAIN_S", 0.0)


def test_study_end_to_end_on_a_tiny_budget(tmp_path, capsys, no_training_floor, monkeypatch):
    from train import study
    from train.trainer import Trainer

    events = []
    real_evaluate, real_train = study.evaluate, Trainer.train

    def evaluate_logged(policy, config, layouts, *a, label=None, **k):
        events.append(f"eval {label}")
        return real_evaluate(policy, config, layouts, *a, label=label, **k)

    def train_logged(self, *a, **k):
        events.append(f"train {self.cfg.name}")
        return real_train(self, *a, **k)

    monkeypatch.setattr(study, "evaluate", evaluate_logged)
    monkeypatch.setattr(Trainer, "train", train_logged)
    out_dir = tmp_path / "study"
    code = main(["study", "--budget-minutes", "0.8", "--episodes", "2", "--worlds", "2", "--layouts", "0", "1",
                 "--out", str(out_dir), "--fidelity", "point", "--set", "max_steps=20"]
                + sum((["--train-set", s] for s in TRAIN), []))
    assert code == 0
    out = capsys.readouterr().out
    names = {"heuristic", "full_obs", "fine_tune", "classic", "mappo", "imitate", "imitate_ppo", "residual@heuristic+shield",
             "belief+shield", "belief_ppo+shield"}  # the arms trained behind the shield say so, as eval names them
    for name in names:
        assert name in out
    assert "min" in out  # the timings
    table = json.loads((out_dir / "table.json").read_text())
    assert {r["policy"] for r in table["rows"]} == names
    assert "paired with heuristic on the same episodes" in out  # every arm against the team, episode by episode
    assert {(p["policy"], p["layout"]) for p in table["paired"]} == {(n, l) for n in names - {"heuristic"} for l in ("0", "1", "all")}
    assert (out_dir / "plots" / "success.png").is_file() and (out_dir / "timings.json").is_file()
    ft = json.loads((out_dir / "runs" / "fine_tune" / "metrics.jsonl").read_text().splitlines()[0])
    assert ft["update"] == 1
    assert f"initialised from {out_dir / 'runs' / 'imitate' / 'best.pt'}" in out  # PPO continues the imitation
    # each arm is evaluated as soon as it has trained (on both layouts), so that what its evaluation takes
    # more or less than reserved moves the later arms' training time, not the study's end
    arms = [a.name for a in study.ARMS]
    labels = {"residual": "residual@heuristic+shield", "belief": "belief+shield", "belief_ppo": "belief_ppo+shield"}
    assert events == ["eval heuristic"] * 3 + sum(([f"train {a}"] + [f"eval {labels.get(a, a)}"] * 2 for a in arms), [])


def test_an_arm_gets_its_share_of_the_time_left_less_its_closing_validation():
    from train.study import VALIDATION_SHARE, arm_budget

    # 600 s left, a quarter of the shares still to come: 150 s; 24 validation episodes of 1 s, twice
    minutes, episodes = arm_budget(600.0, 0.1, 0.4, 24, 1.0, 1.0)
    assert episodes == int(VALIDATION_SHARE * 150 / 2) == 22  # 48 s would be over 30 % of 150 s
    assert minutes * 60 == pytest.approx(150 - 2 * 22)
    minutes, episodes = arm_budget(6000.0, 0.1, 0.4, 24, 1.0, 0.0)  # plenty: all 24, the policy alone
    assert episodes == 24 and minutes * 60 == pytest.approx(1500 - 24)
    minutes, episodes = arm_budget(-5.0, 0.1, 0.4, 24, 1.0, 1.0)  # over time already
    assert minutes == 0.0 and episodes == 4


def test_a_closing_validation_is_priced_at_the_time_limit_not_at_the_teams_episode_length():
    """A barely trained policy plays its validation to the time limit: 4 episodes of 959 mean steps took
    16 s where the team's length had priced them at 3.5 s, and the arms after it got no training."""
    from train.study import ArmValidation, ValidationSpeed, timeout_episode_seconds

    assert timeout_episode_seconds(0.5, 250.0, 1000) == pytest.approx(2.0)
    assert timeout_episode_seconds(0.5, 250.0, 100) == 0.5  # never below the team's own episode
    # 150 s for the arm; an episode at the limit costs 2 s, and the team plays it too at 0.5 s
    speed = ValidationSpeed(0.5, 250.0)
    minutes, episodes = ArmValidation(1000, 24, True, speed).budget(600.0, 0.1, 0.4)
    assert episodes == int(0.3 * 150 / 2.5) == 18 and minutes * 60 == pytest.approx(150 - 18 * 2.5)
    minutes, episodes = ArmValidation(1000, 24, False, speed).budget(600.0, 0.1, 0.4)
    assert episodes == 22 and minutes * 60 == pytest.approx(150 - 22 * 2.0)
    # a policy that acts at twice the team's cost (the belief arms build the team's memory every step)
    minutes, episodes = ArmValidation(1000, 24, False, speed, policy_cost=2.0).budget(600.0, 0.1, 0.4)
    assert episodes == int(0.3 * 150 / 4.0) == 11 and minutes * 60 == pytest.approx(150 - 11 * 4.0)


def test_validation_speed_is_probed_in_each_arms_own_training_task(tmp_path):
    """The closing validation plays the arm's training task (point fidelity by default) on its training
    layouts; it was priced from the team's evaluation (quadrotor fidelity, all four layouts), 3-7x too high."""
    from pursuit_mj.config import default_config
    from train.study import ARMS, StudyPlan, arm_validations

    plan = StudyPlan(budget_minutes=10.0, out=tmp_path, eval_task=default_config(),
                     train_overrides=("task.fidelity=point", "task.max_steps=40", "task.random_obstacles=0"))
    arms = [a for a in ARMS if a.name in ("full_obs", "classic", "belief")]
    validations = arm_validations(plan, arms)
    full, classic, belief = (validations[a.name] for a in arms)
    assert classic.speed is belief.speed  # one probe for arms that validate alike
    assert full.speed is not classic.speed  # full observability is another probe
    for v in validations.values():
        assert v.max_steps == 40 and 0 < v.speed.team_steps <= 40 and v.speed.team_episode_s > 0
    assert belief.policy_cost == 2.1 and classic.policy_cost == 1.1
    assert belief.budget(600.0, 0.1, 0.4)[0] < classic.budget(600.0, 0.1, 0.4)[0]


def test_the_training_a_budget_needs_leaves_every_arm_the_floor_and_a_little_less_does_not():
    from train.study import ARMS, MIN_ARM_TRAIN_S, ArmValidation, ValidationSpeed, planned_training_seconds, training_seconds_needed

    validations = {a.name: ArmValidation(1000, 24, a.name in ("belief", "belief_ppo"), ValidationSpeed(0.5, 250.0)) for a in ARMS}
    need = training_seconds_needed(ARMS, validations)
    planned = planned_training_seconds(need, ARMS, validations)
    assert min(planned.values()) >= MIN_ARM_TRAIN_S
    assert min(planned_training_seconds(need / 1.02, ARMS, validations).values()) < MIN_ARM_TRAIN_S
    # the arm of the smallest share is the one short: residual (0.08), with 4 validation episodes of 2 s
    assert min(planned, key=planned.get) in ("imitate", "residual")
    assert need > (MIN_ARM_TRAIN_S + 4 * 2.0) / 0.08 * 0.99


def test_a_study_budget_that_leaves_an_arm_under_the_floor_is_refused_with_one_that_would_do(tmp_path, capsys):
    """It ran: the arms after the first were left 0 s of training, and the study ran 26-40 % over."""
    out_dir = tmp_path / "study"
    code = main(["study", "--budget-minutes", "0.8", "--episodes", "2", "--worlds", "2", "--layouts", "0",
                 "--out", str(out_dir), "--fidelity", "point", "--set", "max_steps=20"]
                + sum((["--train-set", s] for s in BY_STEPS), []))
    assert code == 2
    err = capsys.readouterr().err
    assert "--budget-minutes 0.8: too small on this machine; the " in err and "arm would be left" in err
    assert "its time limit of 30 steps" in err and "raise the budget to about " in err
    needed = float(err.split("raise the budget to about ")[1].split(" min")[0])
    assert 0.8 < needed < 10
    # the refused study left no record: a --resume of it is told there is none, not that it "was trained
    # with other settings" (nothing was trained), and a fresh study there starts as in an empty folder
    assert not (out_dir / "study.json").exists()
    assert main(["study", "--budget-minutes", "0.8", "--resume", "--out", str(out_dir)]) == 2
    err = capsys.readouterr().err
    assert "study to continue" in err and "other settings" not in err, err  # nor even a folder: it made none
    assert not out_dir.exists()  # nothing trained


def test_the_evaluation_is_reserved_by_each_arms_cost_and_short_ones_keep_a_floor():
    from pathlib import Path

    from pursuit_mj.config import default_config
    from train.study import ARM_START_S, ARMS, ARMS_EVAL_COST, BATCH_FLOOR, MIN_TRAIN_FRACTION, StudyPlan, eval_seconds, fit_episodes

    assert ARMS_EVAL_COST > len(ARMS)  # the belief arms build the team's memory every step: about twice the team
    plan = StudyPlan(budget_minutes=10.0, out=Path("x"), eval_task=default_config(), episodes=150)
    # a probe of 8 episodes per layout took 3.2 s: 0.4 s an episode beyond it
    episodes, train_minutes = fit_episodes(plan, 3.2, 8, 0.0)
    rounds = 1 + ARMS_EVAL_COST
    assert rounds * eval_seconds(3.2, 8, episodes) <= 600 * (1 - MIN_TRAIN_FRACTION) < rounds * eval_seconds(3.2, 8, episodes + 1)
    assert train_minutes == pytest.approx((600 - rounds * eval_seconds(3.2, 8, episodes) - ARM_START_S * len(ARMS)) / 60)
    assert eval_seconds(3.2, 8, 16) == pytest.approx(6.4) and eval_seconds(3.2, 8, 8) == 3.2
    assert eval_seconds(3.2, 8, 0) == pytest.approx(3.2 * BATCH_FLOOR)  # fewer episodes than a batch save less
    assert eval_seconds(3.2, 8, 2) >= 3.2 * 2 / 8
    # a budget where even one episode per layout leaves nothing to train
    small = StudyPlan(budget_minutes=3.0, out=Path("x"), eval_task=default_config(), episodes=150)
    episodes, train_minutes = fit_episodes(small, 13.4, 8, 13.4)
    assert episodes == 1 and train_minutes < 0


def test_a_train_override_one_arm_refuses_is_found_before_anything_runs(tmp_path, capsys):
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", "ppo.learnable_gamma=true"]) == 2
    err = capsys.readouterr().err
    assert "--train-set ppo.learnable_gamma=true: the imitate and belief arms refuse it (imitate config): " in err, err
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", "foo=1"]) == 2
    err = capsys.readouterr().err
    assert "--train-set foo=1: every arm refuses it: unknown key 'foo'" in err and "--set foo" not in err.replace("--train-set foo", "")
    assert not out.exists()  # no arm trained, no evaluation run, not even the folder made
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--layouts", "0", "9"]) == 2
    assert "layout 9" in capsys.readouterr().err and not out.exists()
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--layouts", "1", "01"]) == 2
    assert "--layouts: 01 is given twice" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("override, key", [("run.validation_layouts=[9]", "run.validation_layouts"),
                                           ("layouts=[0,no_such.yaml]", "layouts"),
                                           ("task.layout=no_such.yaml", "task.layout")])
def test_a_train_override_naming_a_layout_that_cannot_be_loaded_is_found_before_anything_runs(tmp_path, capsys, override, key):
    # found at the first arm's start, after the heuristic team's evaluation had been kept in study.json,
    # which then refused a fresh study in that folder and a resume without the bad --train-set alike
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", override]) == 2
    err = capsys.readouterr().err
    assert "--train-set" in err and (f"{key} " in err or f"--train-set {key}=" in err), err
    assert "no_such.yaml" in err or "9 is not a built-in layout index" in err, err
    assert not out.exists()


def test_the_largest_seed_is_a_study_seed_like_any_other(tmp_path, capsys):
    """--seed 2**63 - 1 passed the flag's check, then the team's speed probe, played with the next seed,
    stopped the study with 'evaluate seed: ... got 9223372036854775808', a number the user never gave."""
    out_dir = tmp_path / "study"
    assert main(["study", "--budget-minutes", "0.02", "--seed", str(2**63 - 1), "--episodes", "2", "--worlds", "2",
                 "--layouts", "0", "--out", str(out_dir), "--fidelity", "point", "--set", "max_steps=20"]
                + sum((["--train-set", s] for s in BY_STEPS), [])) == 2
    err = capsys.readouterr().err
    assert "--budget-minutes 0.02: too small on this machine" in err and "seed" not in err, err  # refused as any seed is


def test_an_evaluation_task_that_draws_its_layout_per_episode_is_refused_before_anything_runs(tmp_path, capsys):
    """--set random_layout=true was taken and ignored: every column of the table was its one layout, as
    eval and demo, which refuse it, would not have played it either."""
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--set", "random_layout=true"]) == 2
    err = capsys.readouterr().err
    assert "error: --set random_layout=true: the task draws a layout per episode" in err, err
    assert "--layouts 0 1 2 3" in err and not out.exists()


@pytest.mark.parametrize("flags, said", [
    (["--set", "n_rays=8"], "error: --set n_rays=8: the evaluation task gives 8 range readings (n_rays) and every arm trains with 16"),
    (["--train-set", "task.n_rays=8"],
     "error: --train-set task.n_rays=8: the evaluation task gives 16 range readings (n_rays) and every arm trains with 8")])
def test_an_evaluation_task_with_other_rays_than_the_arms_train_with_is_refused_before_anything_runs(tmp_path, capsys, flags, said):
    """A trained policy reads the range readings it learned with: the study evaluated the team, trained
    the full_obs arm, then stopped at its evaluation ('observation spec does not match ... (n_rays)').
    The refusal named neither the flag that gave the count nor that every arm trains with the other
    ('the full_obs arm trains with 8')."""
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), *flags]) == 2
    err = capsys.readouterr().err
    assert said in err, err
    assert "--set n_rays=N and --train-set task.n_rays=N" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("override", ["name=mine", "run.runs_dir=elsewhere", "max_minutes=1", "init_from=x.pt"])
def test_a_train_override_of_a_key_the_study_sets_per_arm_is_refused_before_anything_runs(tmp_path, capsys, override):
    """--train-set name=x put every arm in runs/x: the second arm stopped the study after the first had
    trained ('already holds a run; choose another --out'); max_minutes was overwritten without a word."""
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", override]) == 2
    err = capsys.readouterr().err
    assert f"--train-set {override}: the study sets {override.split('=')[0]} for each arm" in err, err
    assert not out.exists()


def test_a_key_the_study_sets_per_arm_is_refused_inside_a_section_given_as_a_mapping_too(tmp_path, capsys, monkeypatch):
    """--train-set run.runs_dir=x was refused, but --train-set "run={runs_dir: x}" slipped past the check
    and put every arm's run folder in x, outside --out (and the study failed after its first arm,
    finding no best.pt under --out)."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", "run={runs_dir: elsewhere}"]) == 2
    err = capsys.readouterr().err
    assert "--train-set run={runs_dir: elsewhere}: the study sets run.runs_dir for each arm" in err, err
    assert not out.exists() and not (tmp_path / "elsewhere").exists()


def test_an_interrupted_study_resumes_keeping_its_finished_arms_and_evaluations(tmp_path, capsys, monkeypatch, no_training_floor):
    from train import study
    from train.trainer import Trainer

    out_dir = tmp_path / "study"
    args = ["--episodes", "2", "--worlds", "2", "--layouts", "0", "--out", str(out_dir), "--fidelity", "point",
            "--set", "max_steps=20"] + sum((["--train-set", s] for s in BY_STEPS), [])
    real_update = Trainer.train_one_update

    def ctrl_c_in_classic(self):
        if self.cfg.name == "classic" and self.counters.update >= 1:
            raise KeyboardInterrupt
        return real_update(self)

    monkeypatch.setattr(Trainer, "train_one_update", ctrl_c_in_classic)
    real_arm_budget = study.arm_budget

    def at_least_six_seconds(*a, **k):  # on a loaded machine the first arms' overruns left classic no update
        minutes, episodes = real_arm_budget(*a, **k)
        return max(minutes, 0.1), episodes

    monkeypatch.setattr(study, "arm_budget", at_least_six_seconds)
    assert main(["study", "--budget-minutes", "0.8", *args]) == 130
    err = capsys.readouterr().err
    assert "pursuit-mj study --resume" in err and "pursuit-mj train --resume" not in err
    first = json.loads((out_dir / "study.json").read_text())
    assert set(first["arms"]) == {"full_obs", "fine_tune"}
    # each arm is evaluated as soon as it has trained: the finished arms' cells are kept already
    assert set(first["evaluation"]["cells"]) == {"heuristic", "full_obs", "fine_tune"}
    assert main(["study", "--budget-minutes", "0.8", *args]) == 2  # not over the runs without --resume
    assert "continue them with --resume" in capsys.readouterr().err
    kept = (out_dir / "runs" / "full_obs" / "metrics.jsonl").read_text()
    classic_rows = len((out_dir / "runs" / "classic" / "metrics.jsonl").read_text().splitlines())

    # as if stopped after fine_tune ended but before study.json recorded it: it is not trained again
    state = json.loads((out_dir / "study.json").read_text())
    del state["arms"]["fine_tune"]
    (out_dir / "study.json").write_text(json.dumps(state))
    fine_tune_log = (out_dir / "runs" / "fine_tune" / "metrics.jsonl").read_text()

    monkeypatch.setattr(Trainer, "train_one_update", real_update)
    played = []
    real_evaluate = study.evaluate

    def evaluate_until_mappo(policy, config, layouts, *a, label=None, **k):
        played.append(label)
        if label == "mappo" and stop_at_mappo:
            raise KeyboardInterrupt  # Ctrl-C during mappo's evaluation, right after it trained
        return real_evaluate(policy, config, layouts, *a, label=label, **k)

    monkeypatch.setattr(study, "evaluate", evaluate_until_mappo)
    stop_at_mappo = True
    assert main(["study", "--budget-minutes", "0.6", "--resume", *args]) == 130
    out = capsys.readouterr().out
    assert "full_obs: trained in an earlier session, kept" in out and "resuming classic" in out
    assert "fine_tune: finished in an earlier session (stopped before the study recorded it), kept" in out
    assert "heuristic: 1 of 1 layout evaluated in an earlier session, kept" in out  # evaluated before classic stopped
    assert "full_obs: 1 of 1 layout evaluated in an earlier session, kept" in out
    assert "fine_tune: 1 of 1 layout evaluated in an earlier session, kept" in out  # as it ended, before the record
    assert played == ["classic", "mappo"]
    assert (out_dir / "runs" / "fine_tune" / "metrics.jsonl").read_text() == fine_tune_log
    assert (out_dir / "runs" / "full_obs" / "metrics.jsonl").read_text() == kept
    updates = [json.loads(x)["update"] for x in (out_dir / "runs" / "classic" / "metrics.jsonl").read_text().splitlines()]
    assert updates[:classic_rows] == list(range(1, classic_rows + 1)) and len(updates) > classic_rows  # continued
    assert not (out_dir / "table.json").exists()
    cells = json.loads((out_dir / "study.json").read_text())["evaluation"]["cells"]
    assert set(cells) == {"heuristic", "full_obs", "fine_tune", "classic"}

    # resumed again: the arms after mappo train, and only the cells not played yet are played
    played.clear()
    stop_at_mappo = False
    assert main(["study", "--budget-minutes", "0.8", "--resume", *args]) == 0
    out = capsys.readouterr().out
    assert played == ["mappo", "imitate", "imitate_ppo", "residual@heuristic+shield", "belief+shield", "belief_ppo+shield"]
    assert "classic: 1 of 1 layout evaluated in an earlier session, kept" in out
    table = json.loads((out_dir / "table.json").read_text())
    assert len({r["policy"] for r in table["rows"]}) == 10  # the heuristic team and all nine arms
    by_policy = {r["policy"]: r for r in table["rows"]}
    for key in ("heuristic", "full_obs", "fine_tune", "classic"):
        assert by_policy[key] == cells[key]["0"]["row"]  # the kept rows, episodes and all
    timings = json.loads((out_dir / "timings.json").read_text())
    assert "classic (eval, earlier session)" in timings and "classic (eval)" not in timings and "mappo (eval)" in timings
    # the arms' training on their runs' own clock in every session; the total of all three sessions beside this one's
    assert timings["classic (train, earlier session)"] == json.loads((out_dir / "study.json").read_text())["arms"]["classic"]["train_seconds"]
    assert timings["total, all sessions"] > timings["total"] + timings["classic (train, earlier session)"]
    assert json.loads((out_dir / "study.json").read_text())["seconds"] == pytest.approx(timings["total, all sessions"], abs=0.2)
    # the table says what it took: every session's budget (not the refused one's), and the time of all of them
    assert table["budget_minutes"] == 0.8 and table["session_budgets_minutes"] == [0.8, 0.6, 0.8]
    assert table["seconds_all_sessions"] == pytest.approx(timings["total, all sessions"], abs=0.2)

    # another episode count asked for: nothing kept counts
    played.clear()
    assert main(["study", "--budget-minutes", "0.1", "--resume", *args[:1], "3", *args[2:]]) == 0
    assert "every policy is evaluated again" in capsys.readouterr().out
    assert len(played) == 10 + 1  # the speed probe, the team, nine arms
    assert main(["study", "--budget-minutes", "0.6", "--resume", *args, "--train-set", "n_envs=3"]) == 2
    assert "--train-set n_envs=3 (was n_envs=2). Give the same --train-fidelity and --train-set" in capsys.readouterr().err


def test_a_resumed_study_whose_kept_arm_lost_its_best_pt_is_refused_before_anything_runs(tmp_path, capsys):
    """It was found only when an arm started from it, or at the evaluation after every other arm had trained."""
    out_dir = tmp_path / "study"
    (out_dir / "runs" / "full_obs").mkdir(parents=True)
    (out_dir / "runs" / "full_obs" / "best.pt").write_bytes(b"")
    state = {"train_overrides": ["task.fidelity=point"], "arms": {"full_obs": {"train_seconds": 1.0}}}
    (out_dir / "study.json").write_text(json.dumps(state))
    assert main(["study", "--budget-minutes", "1", "--resume", "--out", str(out_dir)]) == 2
    err = capsys.readouterr().err
    assert f"the full_obs arm is kept as finished in {out_dir / 'study.json'}, but checkpoint " in err
    assert "best.pt: not a pursuit-mj checkpoint" in err and "delete its entry" in err
    assert not (out_dir / "runs" / "fine_tune").exists()


def test_the_timings_compare_the_total_with_the_budget():
    from train.study import format_timings

    over = format_timings({"heuristic (eval)": 1.2, "total": 138.0}, 1.5).splitlines()
    assert over[0] == "  heuristic (eval)       1 s" and over[1].endswith("2.3 min (budget 1.5 min, 0.8 min over)")  # it read 0.0 min
    assert format_timings({"total": 80.0}, 1.5).endswith("80 s (budget 1.5 min)")
    resumed = format_timings({"total": 80.0, "total, all sessions": 200.0}, 1.5).splitlines()
    assert resumed[0].endswith("80 s (budget 1.5 min)") and resumed[1].endswith("3.3 min")  # the budget is this session's


def test_kept_evaluation_cells_are_taken_back_only_when_they_are_what_this_study_would_play(tmp_path, monkeypatch):
    import dataclasses

    from pursuit_mj.config import load_task_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy
    from train.study import StudyPlan
    from train.study_evaluation import KeptEvaluation

    task = load_task_config([], ["fidelity=point", "max_steps=20"])
    plan = StudyPlan(budget_minutes=1.0, out=tmp_path, eval_task=task, layouts=(0,), episodes=2, worlds=2, resume=True)
    state: dict = {}
    kept = KeptEvaluation(plan, state, lambda: None)
    assert kept.episodes is None and not kept.covers("heuristic")
    kept.start(2)
    (row,) = evaluate(make_policy("heuristic", task), task, [0], 2, plan.seed, 2, label="heuristic")
    kept.keep("heuristic", row, 1.5)
    written = json.loads(json.dumps(state))  # as study.json holds it

    again = KeptEvaluation(plan, json.loads(json.dumps(written)), lambda: None)
    back = again.row("heuristic", "heuristic", 0)
    assert back.flat() == row.flat() and back.episode_log == row.episode_log and again.seconds("heuristic") == 1.5
    assert again.row("heuristic", "belief+shield", 0) is None and again.row("heuristic", "heuristic", 1) is None

    damaged = json.loads(json.dumps(written))
    damaged["evaluation"]["cells"]["heuristic"]["0"]["row"]["per_episode"]["steps"][0] = 21  # past max_steps
    assert KeptEvaluation(plan, damaged, lambda: None).row("heuristic", "heuristic", 0) is None

    for changed in (dataclasses.replace(plan, seed=1), dataclasses.replace(plan, episodes=3),
                    dataclasses.replace(plan, eval_task=dataclasses.replace(task, max_steps=21))):
        logs: list[str] = []
        other = KeptEvaluation(changed, json.loads(json.dumps(written)), lambda: None, logs.append)
        assert other.episodes is None and "every policy is evaluated again" in logs[0]
    assert KeptEvaluation(dataclasses.replace(plan, resume=False), json.loads(json.dumps(written)), lambda: None).episodes is None
    # the cells belong to the source that played them, not to a git commit (a docs-only one keeps them)
    import train.study_evaluation as study_evaluation

    real = study_evaluation.provenance
    monkeypatch.setattr(study_evaluation, "provenance", lambda: {**real(), "git_commit": "0" * 40})
    assert KeptEvaluation(plan, json.loads(json.dumps(written)), lambda: None).episodes == 2
    monkeypatch.setattr(study_evaluation, "provenance", lambda: {**real(), "source_sha256": "f" * 64})
    assert KeptEvaluation(plan, json.loads(json.dumps(written)), lambda: None, lambda line: None).episodes is None
    monkeypatch.setattr(study_evaluation, "provenance", real)

    # a trained arm's cells belong to the best.pt they were played from
    best = tmp_path / "best.pt"
    best.write_bytes(b"weights 1")
    kept.use_checkpoint("classic", best)
    kept.keep("classic", dataclasses.replace(row, policy="classic"), 2.0)
    assert kept.covers("classic", best) and kept.row("classic", "classic", 0) is not None
    kept.use_checkpoint("classic", best)  # the same file: kept
    assert kept.row("classic", "classic", 0) is not None
    best.write_bytes(b"weights 2")  # trained again
    assert not kept.covers("classic", best)
    kept.use_checkpoint("classic", best)
    assert kept.row("classic", "classic", 0) is None and kept.seconds("classic") == 0


@pytest.mark.parametrize("damage", ["no_row", "seconds_text", "seconds_negative", "row_not_a_dict", "cells_a_list",
                                    "evaluation_a_list", "episodes_zero"])
def test_a_damaged_kept_evaluation_is_played_again_not_a_crash(tmp_path, damage):
    from types import SimpleNamespace

    from pursuit_mj.config import load_task_config
    from pursuit_mj.evaluation import Row, episode_seeds, layout_seed, summarise
    from train.study import StudyPlan
    from train.study_evaluation import KeptEvaluation

    task = load_task_config([], ["fidelity=point", "max_steps=20"])
    plan = StudyPlan(budget_minutes=1.0, out=tmp_path, eval_task=task, layouts=(0,), episodes=2, worlds=2, resume=True)
    state: dict = {}
    kept = KeptEvaluation(plan, state, lambda: None)
    kept.start(2)
    seeds = episode_seeds(layout_seed(plan.seed, "0"), 2)
    records = [SimpleNamespace(seed=int(s), outcome="timeout", steps=20, captured=0) for s in seeds]
    kept.keep("heuristic", summarise("heuristic", "0", "point", plan.seed, records, 20), 1.0)
    data = json.loads(json.dumps(state))
    ev, cell = data["evaluation"], data["evaluation"]["cells"]["heuristic"]["0"]
    if damage == "no_row":
        del cell["row"]
    elif damage == "seconds_text":
        cell["seconds"] = "1 s"
    elif damage == "seconds_negative":
        cell["seconds"] = -1.0
    elif damage == "row_not_a_dict":
        cell["row"] = 5
    elif damage == "cells_a_list":
        ev["cells"]["heuristic"] = []
    elif damage == "evaluation_a_list":
        data["evaluation"] = []
    elif damage == "episodes_zero":
        ev["episodes"] = 0
    again = KeptEvaluation(plan, data, lambda: None, lambda line: None)
    assert again.row("heuristic", "heuristic", 0) is None and not again.covers("heuristic")
    assert again.seconds("heuristic") == 0
    assert isinstance(KeptEvaluation(plan, json.loads(json.dumps(state)), lambda: None).row("heuristic", "heuristic", 0), Row)


def test_a_fresh_study_over_an_interrupted_ones_kept_evaluation_is_refused(tmp_path, capsys):
    """A study stopped during the team's evaluation (no run yet) lost its evaluated cells to a
    `study` without --resume in the same folder: study.json was written anew before anything ran."""
    out_dir = tmp_path / "study"
    out_dir.mkdir()
    state = {"train_overrides": ["task.fidelity=point"], "arms": {},
             "evaluation": {"identity": {}, "episodes": 2, "checkpoints": {},
                            "cells": {"heuristic": {"0": {"row": {"policy": "heuristic"}, "seconds": 60.0}}}}}
    (out_dir / "study.json").write_text(json.dumps(state))
    assert main(["study", "--budget-minutes", "1", "--out", str(out_dir)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out_dir}: its study.json keeps 1 evaluated policy-layout cell" in err and "--resume" in err
    assert json.loads((out_dir / "study.json").read_text()) == state  # untouched


def _resumed_classic_study_refusal(tmp_path, monkeypatch, budget_minutes: float) -> str:
    """The refusal of a resumed study of the classic arm alone, whose team evaluation (kept) took
    1 s, with `budget_minutes` for what is left."""
    from pursuit_mj.config import load_task_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy
    from train import study
    from train.study_evaluation import KeptEvaluation

    monkeypatch.setattr(study, "ARMS", (study.Arm("classic", "classic", 1.0),))
    task = load_task_config([], ["fidelity=point", "max_steps=20"])
    plan = study.StudyPlan(budget_minutes=budget_minutes, out=tmp_path, eval_task=task, layouts=(0,), episodes=2, worlds=2,
                           train_overrides=("task.fidelity=point",), resume=True)
    state = {"train_overrides": list(plan.train_overrides), "arms": {}}
    kept = KeptEvaluation(plan, state, lambda: None)
    kept.start(2)
    (row,) = evaluate(make_policy("heuristic", task), task, [0], 2, plan.seed, 2, label="heuristic")
    kept.keep("heuristic", row, 1.0)
    (tmp_path / study.STATE_FILE).write_text(json.dumps(state))
    with pytest.raises(ValueError) as err:
        study.run_study(plan, log=lambda line: None)
    return str(err.value)


def test_a_resumed_study_too_short_to_train_says_how_much_budget_would_do(tmp_path, monkeypatch):
    """It said 'raise the budget to about 0 min' (minutes rounded to whole ones) for one run left."""
    from train import study

    monkeypatch.setattr(study, "MIN_ARM_TRAIN_S", 0.0)  # the budget that gives training any time at all
    # 3 s of budget less 1 s for the team's evaluation and 1 s for the arm's, 3 s to start, and the
    # probe of the arm's validation speed (1-2 s)
    said = _resumed_classic_study_refusal(tmp_path, monkeypatch, 0.05)
    assert "starting 1 run leave 0 s for training (raise the budget to about 0." in said, said
    needed = said.split("raise the budget to about ")[1].split(" min")[0]
    assert len(needed) == 3 and 0.05 < float(needed) < 0.5  # tenths of a minute, not "about 0 min"


def test_a_resumed_study_that_would_leave_an_arm_under_the_floor_says_how_much_budget_would_do(tmp_path, monkeypatch):
    # 12 s of budget, 1 s for the team and 1 s for the arm's evaluation, 3 s to start, 1-2 s to probe the
    # validation's speed; its episodes of up to 1000 steps (classic's own task) are priced at that limit
    said = _resumed_classic_study_refusal(tmp_path, monkeypatch, 0.2)
    left = float(said.split("the classic arm would be left ")[1].split(" s of training")[0])
    assert left < 10 and "time limit of 1000 steps" in said
    needed = float(said.split("raise the budget to about ")[1].split(" min")[0])
    assert 0.2 + (10 - left) / 60 < needed < 10


def test_kept_cells_of_a_layout_file_edited_since_are_played_again(tmp_path):
    """Cells were keyed by the layout file's path alone: a resumed study took back the rows of
    the arena as it was before the file was edited."""
    from pursuit_mj.config import load_task_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.layout import builtin_layout_path
    from pursuit_mj.policies import make_policy
    from train.study import StudyPlan
    from train.study_evaluation import KeptEvaluation

    arena = tmp_path / "arena.yaml"
    arena.write_text(builtin_layout_path(1).read_text())
    task = load_task_config([], ["fidelity=point", "max_steps=20"])
    plan = StudyPlan(budget_minutes=1.0, out=tmp_path, eval_task=task, layouts=(str(arena),), episodes=1, worlds=1,
                     resume=True)
    state: dict = {}
    kept = KeptEvaluation(plan, state, lambda: None)
    kept.start(1)
    (row,) = evaluate(make_policy("heuristic", task), task, [str(arena)], 1, plan.seed, 1, label="heuristic")
    kept.keep("heuristic", row, 1.0)
    assert KeptEvaluation(plan, json.loads(json.dumps(state)), lambda: None).row("heuristic", "heuristic", str(arena))
    arena.write_text(builtin_layout_path(2).read_text())  # another arena under the same name
    logs: list[str] = []
    again = KeptEvaluation(plan, json.loads(json.dumps(state)), lambda: None, logs.append)
    assert again.episodes is None and again.row("heuristic", "heuristic", str(arena)) is None
    assert "every policy is evaluated again" in logs[0]


def test_a_resume_may_change_how_training_is_shown_but_not_what_is_trained(tmp_path):
    """`train --resume` lets the progress bar and rerun streaming change; `study --resume` refused
    a different --train-set run.progress=... as a study trained with other settings."""
    from pursuit_mj.config import default_config
    from train.study import StudyPlan, _load_state

    out_dir = tmp_path / "study"
    out_dir.mkdir()
    state = {"train_overrides": ["task.fidelity=point", "run.progress=false", "ppo.lr=0.0001"], "arms": {}}
    (out_dir / "study.json").write_text(json.dumps(state))
    plan = StudyPlan(1.0, out_dir, default_config(), train_overrides=("task.fidelity=point", "ppo.lr=0.0001", "run.rerun=true"),
                     resume=True)
    assert _load_state(plan)["arms"] == {}
    other = dataclasses.replace(plan, train_overrides=("task.fidelity=point", "ppo.lr=0.0002"))
    with pytest.raises(ValueError, match=r"trained with other settings: --train-set ppo.lr=0.0002 \(was ppo.lr=0.0001\)\. "
                                         r"Give the same"):
        _load_state(other)


def test_a_resume_compares_the_settings_not_the_order_or_spelling_of_the_train_overrides(tmp_path):
    """The resume compared the two lists of texts: the same values in another order were refused,
    and the refusal printed both whole lists, leaving the user to find what differed."""
    from pursuit_mj.config import default_config
    from train.study import StudyPlan, _load_state

    out_dir = tmp_path / "study"
    out_dir.mkdir()
    stored = ["task.fidelity=point", "n_envs=16", "ppo.lr=0.0001", "shield=true"]
    (out_dir / "study.json").write_text(json.dumps({"train_overrides": stored, "arms": {}}))
    plan = StudyPlan(1.0, out_dir, default_config(), resume=True,
                     train_overrides=("task.fidelity=point", "shield=true", "ppo.lr=1e-4", "n_envs=8", "n_envs=16.0"))
    assert _load_state(plan)["arms"] == {}  # another order, another spelling, a key given twice: the same settings
    other = dataclasses.replace(plan, train_overrides=("task.fidelity=quadrotor", "n_envs=3", "ppo.lr=0.0001", "batch=2"))
    with pytest.raises(ValueError) as refused:
        _load_state(other)
    said = str(refused.value)
    assert ("other settings: --train-fidelity quadrotor (was point); --train-set batch=2 is new; --train-set n_envs=3 "
            "(was n_envs=16); --train-set shield=true is missing. Give the same") in said, said
    assert "ppo.lr" not in said  # what is the same is not listed
    # decided by the configs they give the arms: a section and its key in another order are a change,
    # a key given twice that ends at the same value, or a default given explicitly, is none
    (out_dir / "study.json").write_text(json.dumps({"train_overrides": ["task.fidelity=point", "ppo={lr: 0.001}",
                                                                        "ppo.lr=0.0005"], "arms": {}}))
    assert _load_state(dataclasses.replace(plan, train_overrides=("task.fidelity=point", "ppo.lr=0.0005")))  # the same lr
    swapped = dataclasses.replace(plan, train_overrides=("task.fidelity=point", "ppo.lr=0.0005", "ppo={lr: 0.001}"))
    with pytest.raises(ValueError, match=r"other settings: ppo.lr is 0.001 now, 0.0005 then \(the full_obs arm's config\)"):
        _load_state(swapped)
    (out_dir / "study.json").write_text(json.dumps({"train_overrides": ["task.fidelity=point"], "arms": {}}))
    assert _load_state(dataclasses.replace(plan, train_overrides=("task.fidelity=point", "seed=0", "ppo.max_grad_norm=0.5")))
    (out_dir / "study.json").write_text(json.dumps({"train_overrides": ["n_envs"], "arms": {}}))
    with pytest.raises(ValueError, match=r"study.json, \"train_overrides\" 'n_envs': 'n_envs' is not of the form key=value"):
        _load_state(plan)
    (out_dir / "study.json").write_text(json.dumps({"train_overrides": [3], "arms": {}}))
    with pytest.raises(ValueError, match="is not a study record .*not all KEY=VALUE strings"):
        _load_state(plan)


def test_a_study_stopped_by_sigterm_while_an_arm_trains_exits_143_saying_so(tmp_path, capsys, monkeypatch, no_training_floor):
    """The arm's run stopped on the signal and the study raised a bare interrupt: exit 130, "interrupted"."""
    import os
    import signal

    from train.trainer import Trainer

    real_update = Trainer.train_one_update
    calls = []

    def sigterm_in_the_second_update(self):
        # counted over the arms: on a busy machine the first arm's share may end after one update
        calls.append(self.cfg.name)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return real_update(self)

    monkeypatch.setattr(Trainer, "train_one_update", sigterm_in_the_second_update)
    args = ["--episodes", "2", "--worlds", "2", "--layouts", "0", "--out", str(tmp_path / "study"), "--fidelity", "point",
            "--set", "max_steps=20"] + sum((["--train-set", s] for s in BY_STEPS), [])
    assert main(["study", "--budget-minutes", "0.8", *args]) == 143
    assert "pursuit-mj study: interrupted by SIGTERM" in capsys.readouterr().err


def test_a_study_stopped_before_it_kept_anything_says_to_start_again_not_to_resume(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the study checked its arms' configs said 'continue with pursuit-mj study --resume',
    which was then refused: 'holds no study to continue (no study.json)'."""
    from train import study

    def ctrl_c(plan):
        raise KeyboardInterrupt

    monkeypatch.setattr(study, "check_train_overrides", ctrl_c)
    out = tmp_path / "study"
    assert main(["study", "--budget-minutes", "30", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "--resume" not in err and f"[study] interrupted before it kept anything in {out}: run the same command" in err, err
    assert not (out / "study.json").exists()


def test_a_study_that_lost_its_record_says_how_to_go_on_instead_of_sending_the_user_round(tmp_path, capsys):
    """Without study.json, --resume said 'no study to continue' and a fresh start said 'continue
    them with --resume': each message sent the user to the other."""
    out = tmp_path / "study"
    (out / "runs" / "classic").mkdir(parents=True)
    (out / "runs" / "classic" / "last.pt").write_bytes(b"a run")
    assert main(["study", "--budget-minutes", "5", "--out", str(out), "--resume", "--fidelity", "point",
                 "--layouts", "0", "--episodes", "2"]) == 2
    err = capsys.readouterr().err
    assert f"holds no study to continue (no study.json); its trained runs in {out / 'runs'} cannot be resumed" in err
    assert "run the study again without --resume" in err


def test_a_second_study_in_a_folder_another_study_holds_is_refused_at_once(tmp_path, capsys):
    """It was refused only when it reached the arm whose run folder the first study held, with advice
    for `train` ("train under another name"), after spending its time on the arms before."""
    from train.study import STUDY_LOCK
    from train.folder_lock import lock_folder

    out_dir = tmp_path / "study"
    held = lock_folder(out_dir, STUDY_LOCK, "study folder", "study", "give another --out")  # as a running study holds it
    try:
        for resume in ([], ["--resume"]):
            assert main(["study", "--budget-minutes", "5", "--out", str(out_dir), *resume]) == 2
            err = capsys.readouterr().err
            assert f"study folder {out_dir} is in use by another study (pid {os.getpid()})" in err, err
            assert "give another --out" in err and "Traceback" not in err
        assert sorted(p.name for p in out_dir.iterdir()) == [STUDY_LOCK]  # nothing written beside the lock
    finally:
        held.close()





def _study_stopped_in_its_first_arm(tmp_path, monkeypatch) -> tuple:
    """A tiny study stopped by Ctrl-C in its first arm's first update, after the team's evaluation
    was recorded: (its folder, the arguments that resume it)."""
    from train.trainer import Trainer

    out_dir = tmp_path / "study"
    args = ["--episodes", "2", "--worlds", "2", "--layouts", "0", "--out", str(out_dir), "--fidelity", "point",
            "--set", "max_steps=20", "--train-set", "n_envs=2"]

    def ctrl_c(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(Trainer, "train_one_update", ctrl_c)
    assert main(["study", "--budget-minutes", "30", *args]) == 130
    return out_dir, args


def test_a_resume_refused_after_it_dropped_the_kept_evaluation_in_memory_keeps_it_on_disk(tmp_path, capsys, monkeypatch):
    """A resume with another --seed drops the kept cells (they are not what it would play) and was
    then refused for its budget; on the way out it wrote the emptied record over the kept cells."""
    out_dir, args = _study_stopped_in_its_first_arm(tmp_path, monkeypatch)
    kept = json.loads((out_dir / "study.json").read_text())["evaluation"]["cells"]
    seconds = json.loads((out_dir / "study.json").read_text())["seconds"]
    assert kept["heuristic"] and seconds > 0
    capsys.readouterr()
    assert main(["study", "--budget-minutes", "0.02", "--resume", *args, "--seed", "5"]) == 2
    assert "every policy is evaluated again" in capsys.readouterr().out
    record = json.loads((out_dir / "study.json").read_text())
    # nor does the refused session count in the study's time: it trained and evaluated nothing
    assert record["evaluation"]["cells"] == kept and record["seconds"] == seconds


def test_a_resumed_session_that_trained_then_failed_counts_its_time(tmp_path, capsys, monkeypatch):
    """Only a session refused before it trained or played anything adds no time; one whose arm
    trained and then stopped on an error (training diverged, say: a ValueError) before any record
    of this session added nothing either, leaving its training out of the study's time."""
    import time

    from train.trainer import Trainer

    out_dir, args = _study_stopped_in_its_first_arm(tmp_path, monkeypatch)
    seconds = json.loads((out_dir / "study.json").read_text())["seconds"]

    def diverge(self):
        time.sleep(1.0)  # an update's worth of training
        raise ValueError("training diverged at update 1")

    monkeypatch.setattr(Trainer, "train_one_update", diverge)
    capsys.readouterr()
    assert main(["study", "--budget-minutes", "30", "--resume", *args]) == 2
    assert "training diverged" in capsys.readouterr().err
    assert json.loads((out_dir / "study.json").read_text())["seconds"] >= seconds + 1.0


def test_a_fresh_study_refused_before_it_did_anything_leaves_no_folder_it_made(tmp_path, monkeypatch):
    """A study refused before it trained or recorded anything (a budget too small: 'study
    --budget-minutes 0.01 --out new') removed its study.json but left the folder it had made,
    holding only its lock file. A folder that was there already, or that holds anything else, stays."""
    import train.study as study
    from pursuit_mj.config import default_config

    def refuse(plan, log, stop_requested):
        raise ValueError("--budget-minutes 0.01: too small on this machine")

    monkeypatch.setattr(study, "_run_study", refuse)
    for out in (tmp_path / "new", tmp_path / "deeper" / "new"):
        with pytest.raises(ValueError, match="too small"):
            study.run_study(study.StudyPlan(0.01, out, default_config(fidelity="point")), log=lambda s: None)
        assert not out.exists(), list(out.iterdir())
    assert not (tmp_path / "deeper").exists()  # 'a/b' of '--out a/b/new' was left: made for the study, and empty
    kept = tmp_path / "mine"
    kept.mkdir()
    for resume, held in ((False, []), (True, []), (True, ["notes.txt"])):  # nor a lock file left in a folder that
        for name in held:                                                   # was there ('--resume --out mine')
            (kept / name).write_text("mine")
        with pytest.raises(ValueError):
            study.run_study(study.StudyPlan(0.01, kept, default_config(fidelity="point"), resume=resume), log=lambda s: None)
        assert kept.is_dir() and sorted(p.name for p in kept.iterdir()) == held

    def refuse_after_making_runs(plan, log, stop_requested):
        (plan.out / "runs").mkdir()
        raise ValueError("refused later")

    monkeypatch.setattr(study, "_run_study", refuse_after_making_runs)
    with pytest.raises(ValueError, match="refused later"):
        study.run_study(study.StudyPlan(0.01, tmp_path / "other", default_config(fidelity="point")), log=lambda s: None)
    assert (tmp_path / "other" / "runs").is_dir()


def test_a_train_set_word_read_as_a_boolean_is_advised_with_train_set(tmp_path, capsys):
    """8e0fdf8 advises a word YAML reads as a boolean in the shell's quotes with the flag that gave
    it, --train-set for a study's; but the study renames only '--set TEXT' to '--train-set TEXT' in
    an arm's refusal, so the advice read --set 'task.evader.model="no"', a flag whose keys are the
    evaluation task's (where task.evader.model is unknown)."""
    import shlex

    assert main(["study", "--budget-minutes", "30", "--out", str(tmp_path / "s"), "--train-set", "task.evader.model=no", "-sc"]) == 2
    err = capsys.readouterr().err
    advice = err.rsplit("inside the shell's own quotes: ", 1)[1].rstrip(")\n")
    assert shlex.split(advice) == ["--train-set", 'task.evader.model="no"'], err


@pytest.mark.parametrize("train_set, said", [
    # the value that a config check (not the key's own parse) refuses was named only as the train config's key
    (["n_envs=4", "task.layout=nope.yaml"], "--train-set task.layout=nope.yaml: every arm refuses it: task.layout nope.yaml: "
                                            "layout 'nope.yaml': no such file"),
    (["n_envs=-1"], "--train-set n_envs=-1: every arm refuses it: key 'n_envs': -1 is out of range"),
    # arms that differ: all of those that refuse are named, not only the first
    (["ppo.anchor_coef=0.5"], "--train-set ppo.anchor_coef=0.5: the full_obs, classic, mappo and residual arms refuse it "
                              "(full_obs config): ppo.anchor_coef 0.5 needs a start to anchor to"),
    (["algo=dagger"], "--train-set algo=dagger: the residual arm refuses it (residual config): residual.base 'heuristic' "
                      "works with algo ppo or mappo, not dagger"),
    # arms that refuse different values: each value with its own arms (residual was named as refusing the first)
    (["ppo.minibatch_size=2048", "ppo.teacher_coef=0.5"],
     "--train-set ppo.minibatch_size=2048: the full_obs, fine_tune, classic and mappo arms refuse it (full_obs config): "
     "ppo.minibatch_size 2048 exceeds ppo.batch_size 1024; --train-set ppo.teacher_coef=0.5: the residual arm refuses it "
     "(residual config): ppo.teacher_coef 0.5 cannot work with residual.base"),
])
def test_a_train_set_value_an_arm_refuses_is_named_with_the_arms_that_refuse_it(tmp_path, capsys, train_set, said):
    """'--train-set n_envs=4 --train-set task.layout=nope.yaml' was refused as '--train-set: the
    full_obs arm (full_obs config) refuses it: train config: task.layout nope.yaml: ...': which of
    the --train-set values was not said, nor that every arm refuses it (only the first arm that
    does was named, as if the others took it)."""
    argv = ["study", "--budget-minutes", "30", "--out", str(tmp_path / "s")] + sum((["--train-set", s] for s in train_set), [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and said in err, err
    assert not (tmp_path / "s").exists()


def test_docs_training_md_names_the_studys_arms_with_their_configs_and_its_output_files():
    """The study's table has a row `imitate_ppo`, trained from configs/train/finetune_ppo.yaml, and
    writes table.txt, table.csv and plots/ beside table.json; the docs named neither the arms nor
    those files, so a reader of the table could not tell which config a row came from."""
    import re
    from pathlib import Path

    from train import study

    root = Path(__file__).resolve().parents[1]
    prose = " ".join((root / "docs" / "training.md").read_text().split())
    said = re.search(r"Its arms, in training order: (.*?)\. It writes", prose)
    assert said, "docs/training.md does not list the study's arms"
    arms = re.finditer(r"`(\w+)`(?: \((?:`configs/train/(\w+)\.yaml`)?(?:, )?(?:from `(\w+)`)?\))?(?:, |$)", said[1])
    documented = [(arm[1], arm[2] or arm[1], arm[3]) for arm in arms]
    assert documented == [(a.name, a.config, a.start_from) for a in study.ARMS]
    files = re.search(r"It writes into `--out`[^:]*: (.*?)\. `pursuit-mj study --budget-minutes", prose)
    assert files, "docs/training.md does not list the study's output files"
    named = [n for n in re.findall(r"`([^`]+)`", files[1]) if "." in n or n.endswith("/")]  # files and folders
    source = (root / "train" / "study.py").read_text()
    for name in named:
        assert f'"{name.split("/")[0]}"' in source, name  # a string the study writes it by
    assert {"table.txt", "table.csv", "table.json", "plots/", "timings.json", "study.json", "runs/<arm>/"} <= set(named)


def test_a_train_set_that_needs_a_start_is_refused_with_advice_a_study_can_follow(tmp_path, capsys):
    """'study --train-set ppo.anchor_coef=0.5' was refused with 'set --init-from', which a study
    refuses (it sets init_from for each arm), and named the imitate_ppo and belief_ppo arms, which
    the study starts from their start arm's best.pt, among those that refuse it."""
    out = tmp_path / "s"
    assert main(["study", "--budget-minutes", "30", "--out", str(out), "--train-set", "ppo.anchor_coef=0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "--train-set ppo.anchor_coef=0.5: the full_obs, classic, mappo and residual arms refuse it" in err, err
    assert "set --init-from" not in err and "only fine_tune, imitate_ppo and belief_ppo" in err, err
    assert f"pursuit-mj train --config fine_tune --init-from {out / 'runs' / 'full_obs' / 'best.pt'} --set ppo.anchor_coef=0.5" in err, err
    assert not out.exists()


def test_an_arm_that_diverges_is_told_with_advice_a_study_can_follow(tmp_path, capsys, monkeypatch):
    """An arm whose training diverged stopped the study saying 'a new run can start (--init-from
    RUN/last.pt --set ppo.lr=...)': flags of train, which study refuses (--set there is the
    evaluation task's, init_from is set for each arm)."""
    weights_go_nan_at_update(monkeypatch, 2)
    out = tmp_path / "study"
    argv = ["study", "--budget-minutes", "30", "--episodes", "2", "--worlds", "2", "--layouts", "0", "--out", str(out),
            "--fidelity", "point", "--set", "max_steps=20"] + sum((["--train-set", s] for s in (
                "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "run.validation_episodes=2")), [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "training diverged at update 2" in err and "--init-from" not in err and "--set ppo.lr" not in err, err
    assert f"{out / 'runs' / 'full_obs' / 'last.pt'} keeps update 1" in err, err
    assert "--train-set ppo.lr=... with another --out" in err, err


def test_a_resumed_arm_whose_reward_file_changed_is_told_with_advice_a_study_can_follow(tmp_path, capsys, monkeypatch):
    """A study resumed after a reward file of its --train-set changed was refused with 'start a new
    run from this one with --init-from RUN/last.pt', a train flag that a study refuses."""
    from train.trainer import Trainer

    reward = tmp_path / "bonus.py"
    reward.write_text("import numpy as np\n\ndef bonus(step):\n    return np.full(step.pursuer_pos.shape[:2], 0.5)\n")
    out = tmp_path / "study"
    argv = ["study", "--budget-minutes", "30", "--episodes", "2", "--worlds", "2", "--layouts", "0", "--out", str(out),
            "--fidelity", "point", "--set", "max_steps=20"] + sum((["--train-set", s] for s in (
                "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "run.validation_episodes=2",
                f"rewards=[{reward}:bonus]")), [])
    real = Trainer.train_one_update

    def ctrl_c_in_the_second(self):
        if self.counters.update >= 1:
            raise KeyboardInterrupt
        return real(self)

    monkeypatch.setattr(Trainer, "train_one_update", ctrl_c_in_the_second)
    assert main(argv) == 130
    assert (out / "runs" / "full_obs" / "last.pt").is_file()
    reward.write_text(reward.read_text().replace("0.5", "0.7"))
    capsys.readouterr()
    assert main(argv + ["--resume"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "has changed since the run started" in err and "--init-from" not in err, err
    assert f"delete the arm's run folder {out / 'runs' / 'full_obs'}" in err, err


def test_an_arm_folder_holding_an_earlier_run_without_last_pt_is_told_with_advice_a_study_can_follow(tmp_path, capsys, monkeypatch):
    """An arm's run folder whose metrics.jsonl reaches past the first checkpoint but whose last.pt
    is gone was refused with 'train under another --name' and '--resume': a study has no --name
    (--out chooses the folder) and goes on with 'pursuit-mj study --resume'."""
    out_dir, args = _study_stopped_in_its_first_arm(tmp_path, monkeypatch)
    run = out_dir / "runs" / "full_obs"
    (run / "last.pt").unlink()  # lost
    with open(run / "metrics.jsonl", "a") as f:
        f.write(json.dumps({"update": 10 ** 6}) + "\n")
    capsys.readouterr()
    assert main(["study", "--budget-minutes", "30", "--resume", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"run folder {run} holds an earlier run (metrics.jsonl rows up to update 1000000" in err, err
    assert "--name" not in err and "then --resume" not in err, err
    assert "then pursuit-mj study --resume" in err and f"delete the arm's run folder {run} to train the arm afresh" in err, err


def test_the_study_table_names_each_arms_checkpoint_so_that_pool_refuses_two_studies_of_other_arms(tmp_path):
    """A study's table.json recorded no checkpoint, code or layout file: `pursuit-mj pool` over two
    studies (two seeds) made one row of two different full_obs networks without a word. It now
    records them as eval does, and pool refuses a label that names two checkpoints."""
    from types import SimpleNamespace

    from pursuit_mj.config import default_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy
    from pursuit_mj.pooling import pool_tables
    from train import study

    task = dataclasses.replace(default_config(), fidelity="point", max_steps=60)
    tables = []
    for seed, sha in ((0, "a" * 64), (1, "b" * 64)):
        rows = evaluate(make_policy("heuristic", task), task, [0], 2, seed, 2)
        rows += evaluate(make_policy("heuristic", task), task, [0], 2, seed, 2, label="full_obs")
        out = tmp_path / f"study{seed}"
        out.mkdir()
        state = {"evaluation": {"checkpoints": {"full_obs": sha}, "cells": {
            "heuristic": {"0": {"row": {"policy": "heuristic"}, "seconds": 1.0}},
            "full_obs": {"0": {"row": {"policy": "full_obs"}, "seconds": 1.0}}}}}
        plan = SimpleNamespace(out=out, eval_task=task, layouts=(0,), seed=seed, budget_minutes=1.0, eval_task_name="")
        study._write(plan, rows, {"total": 1.0}, 2, state)
        tables.append(out / "table.json")
    meta = json.loads(tables[0].read_text())
    assert meta["model_sha256_of"] == {"full_obs": "a" * 64} and meta["layout_identity"] == {"0": "0"}
    assert "source_sha256" in meta["code"]
    with pytest.raises(ValueError, match="policy 'full_obs' is two different models"):
        pool_tables(tables)
    assert len(pool_tables([tables[0]]).rows) == 2  # one study's table pools as ever


def test_the_study_table_names_the_fidelity_its_rows_were_played_in(tmp_path):
    """table.txt (which `pursuit-mj study` prints at its end) held the main table with no word of
    the fidelity it was evaluated in, though the arms train in --train-fidelity and are judged in
    the task's: the paired table below it named it, the main table did not. It has a heading now,
    as eval's has."""
    from types import SimpleNamespace

    from pursuit_mj.config import default_config
    from pursuit_mj.evaluation import evaluate
    from pursuit_mj.policies import make_policy
    from train import study

    task = dataclasses.replace(default_config(), fidelity="point", max_steps=5)
    rows = evaluate(make_policy("heuristic", task), task, [0], 1, 0, 1)
    rows += evaluate(make_policy("random", task), task, [0], 1, 0, 1, label="full_obs")
    plan = study.StudyPlan(budget_minutes=1.0, out=tmp_path, eval_task=task, layouts=(0,), seed=0,
                           eval_task_name="task hard with --set max_steps=5")
    study._write(plan, rows, {"total": 1.0}, 1, {})
    text = (tmp_path / "table.txt").read_text()
    assert text.startswith("evaluated 2 policies on 1 layout, every row in point fidelity, task hard with --set "
                           "max_steps=5\npolicy "), text
    # and table.json records the name, as eval's JSON does, for `pursuit-mj pool`'s heading
    assert json.loads((tmp_path / "table.json").read_text())["task_name"] == "task hard with --set max_steps=5"


def test_the_study_names_its_evaluation_task_in_the_table_heading(tmp_path, monkeypatch):
    """table.txt's heading named the fidelity but not the task the arms were judged in (the study's
    --task, reference by default, and its --set): the study command now gives its plan the name
    common.task_named makes of its task flags. The plan is taken where run_study would run it."""
    from pursuit_cli import main
    from train import study

    plans = []

    def keep(plan, **kwargs):
        plans.append(plan)
        raise ValueError("stop here")

    monkeypatch.setattr(study, "run_study", keep)
    for task, named in (([], "task reference with --set max_steps=5"), (["--task", "hard"], "task hard with --set max_steps=5")):
        assert main(["study", "--budget-minutes", "1", "--out", str(tmp_path / "s"), *task, "--set", "max_steps=5"]) == 2
        assert plans.pop().eval_task_name == named
