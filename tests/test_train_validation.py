"""Validation paired with the heuristic team on the same fixed episodes (train/validation.py)."""

import dataclasses

import pytest

from pursuit_mj.config import TaskConfig
from pursuit_mj.env import EpisodeRecord
from pursuit_mj.policies import make_policy
from pursuit_mj.evaluation import capture_steps
from train.validation import FixedSeedValidator, versus


def record(world: int, outcome: str, steps: int, seed: int | None = None) -> EpisodeRecord:
    return EpisodeRecord(world=world, episode=0, seed=100 + world if seed is None else seed, outcome=outcome, steps=steps,
                         time_to_capture=None, returns={}, captured=int(outcome == "success"), layout="0")


def test_versus_pairs_capture_steps_episode_by_episode():
    policy = [record(0, "success", 10), record(1, "timeout", 50), record(2, "collision", 35), record(3, "success", 30)]
    heuristic = [record(0, "success", 20), record(1, "success", 40), record(2, "success", 45), record(3, "success", 30)]
    assert capture_steps(policy, 50) == (10.0, 50.0, 50.0, 30.0)  # a crash at step 35 counts as never catching
    out = versus(policy, heuristic, max_steps=50)
    # differences -10, +10, +5, 0
    assert out["vs_heuristic_steps"] == pytest.approx(1.25)
    assert out["vs_heuristic_lo"] < 1.25 < out["vs_heuristic_hi"]
    assert out["heuristic_success"] == 1.0 and out["heuristic_mean_steps"] == pytest.approx(33.75)
    # success on the episodes one side alone won: the team caught 2 the policy lost, none the other way
    assert (out["vs_heuristic_only_policy"], out["vs_heuristic_only_heuristic"]) == (0, 2)
    assert out["vs_heuristic_success_p"] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="same episodes"):
        versus(policy, [dataclasses.replace(r, seed=r.seed + 1) for r in heuristic], max_steps=50)


def test_the_heuristic_team_against_itself_is_level_to_the_step():
    task = TaskConfig(fidelity="point", max_steps=60)
    validator = FixedSeedValidator(task, [0], n_episodes=4, seed=7)
    _, first = validator.run(make_policy("heuristic", task))
    _, again = validator.run(make_policy("heuristic", task))  # a fresh team, the same episodes
    out = versus(again, first, task.max_steps)
    assert out["vs_heuristic_steps"] == out["vs_heuristic_lo"] == out["vs_heuristic_hi"] == 0.0


def test_progress_bar_labels_its_throughput_and_shows_no_rates_before_an_episode_ends():
    import io

    from tqdm import tqdm

    from train.progress_bar import advance_bar as _advance

    row = {"world_steps": 342, "agent_steps_per_s": 900.0}
    out = io.StringIO()
    bar = tqdm(total=100.0, file=out)
    _advance(bar, row, [], {}, 0.5, note="validating")
    assert "steps=342" in out.getvalue() and "agent_sps=900" in out.getvalue()  # not a rate of `steps`
    assert "succ=-" in out.getvalue() and "ep_len=-" in out.getvalue() and "nan" not in out.getvalue()
    ended = [EpisodeRecord(0, 0, 0, "success", 40, 4.0, {}, 1, "open"), EpisodeRecord(1, 0, 0, "collision", 20, None, {}, 0, "open")]
    _advance(bar, row, ended, {}, 0.6, note="validating")
    assert "succ=50%" in out.getvalue() and "coll=50%" in out.getvalue() and "ep_len=30" in out.getvalue()
    bar.close()


@pytest.mark.parametrize("fidelity, shown", [("point", "point"), ("quadrotor", "quad")])
def test_progress_bar_names_the_fidelity_the_run_trains_in(fidelity, shown, capsys):
    """The bar named the run and its live figures but not its physics: two runs side by side, one
    in point fidelity and one in quadrotor, read alike. Its label now ends in the fidelity."""
    from train.config import load_train_config
    from train.progress_bar import advance_bar, progress_bar

    cfg = load_train_config([], [f"task.fidelity={fidelity}", "name=chase", "run.progress=true"])
    bar = progress_bar(cfg, 0.25)
    advance_bar(bar, {"world_steps": 10, "agent_steps_per_s": 90.0}, [], {}, 0.5)
    bar.close()
    drawn = capsys.readouterr().err
    assert f"chase ({shown}): " in drawn and "steps=10" in drawn, drawn


def test_a_validation_layout_that_cannot_be_loaded_is_refused_before_any_update_naming_its_key(tmp_path):
    from train.config import load_train_config
    from train.trainer import Trainer

    base = ["task.fidelity=point", "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "total_steps=64",
            "run.validate_every=0", "run.progress=false", f"run.runs_dir={tmp_path}"]
    # it was found only by the closing validation, after every update: the run crashed there, and
    # a resume (which cannot change run.validation_layouts) trained the last update again to crash again.
    # A built-in index out of range is refused as the config is read, naming the --set it came from
    with pytest.raises(ValueError, match=r"--set run\.validation_layouts=\[99\]: key 'run\.validation_layouts': 99 is not a built-in"):
        load_train_config([], base + ["run.validation_layouts=[99]"])
    # a file that does not load, as the run starts, before any update
    cfg = load_train_config([], base + [f"run.validation_layouts=[{tmp_path / 'missing.yaml'}]"])
    with pytest.raises(ValueError, match=r"run\.validation_layouts.*missing\.yaml"):
        Trainer(cfg, log=lambda s: None)
    assert not (cfg.run_dir / "metrics.jsonl").exists() and not (cfg.run_dir / "last.pt").exists()
