"""The evaluation table: confidence intervals, determinism, every episode counted, the eval CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pursuit_cli import main
from pursuit_mj.config import default_config, load_task_config
from pursuit_mj.env import EpisodeRecord
from pursuit_mj.evaluation import FIELDS, evaluate, format_table, read_csv, run_episodes, summarise, write_csv, write_json
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.layout import builtin_layout_path, load_layout
from pursuit_mj.recording.rrd_read import read_entities
from pursuit_mj.stats import mean_interval, t_quantile_975, wilson_interval


@pytest.mark.parametrize(
    "count, n, lo, hi",
    [
        # by hand: centre = (p + z^2/2n) / (1 + z^2/n), half = z / (1 + z^2/n) * sqrt(p(1-p)/n + z^2/4n^2)
        (8, 10, 0.49016, 0.94332),
        (0, 10, 0.0, 0.27753),
        (10, 10, 0.72247, 1.0),
        (75, 150, 0.42099, 0.57901),
        (1, 1, 0.20654, 1.0),
    ],
)
def test_wilson_interval_matches_hand_computed_values(count, n, lo, hi):
    got = wilson_interval(count, n)
    assert got == pytest.approx((lo, hi), abs=5e-5)


def test_wilson_interval_holds_the_rate_exactly_at_0_and_100_percent():
    for n in range(1, 200):
        assert wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
        for count in (0, n // 2, n):
            lo, hi = wilson_interval(count, n)
            assert lo <= count / n <= hi


def test_wilson_interval_refuses_impossible_counts():
    with pytest.raises(ValueError, match="count=11"):
        wilson_interval(11, 10)
    assert wilson_interval(0, 0) == (0.0, 1.0)


def test_t_interval_of_a_mean():
    # published 97.5 % quantiles of Student's t
    for dof, q in ((1, 12.7062), (4, 2.7764), (10, 2.2281), (30, 2.0423), (100, 1.9840)):
        assert t_quantile_975(dof) == pytest.approx(q, abs=2e-4)
    m = mean_interval([1.0, 2.0, 3.0, 4.0, 5.0])  # sd sqrt(2.5), se sqrt(0.5), t(4) 2.7764
    half = 2.7764 * math.sqrt(0.5)
    assert (m.n, m.mean) == (5, 3.0)
    assert (m.lo, m.hi) == pytest.approx((3.0 - half, 3.0 + half), abs=1e-3)
    assert mean_interval([]).mean is None
    assert mean_interval([7.0]).mean == 7.0 and mean_interval([7.0]).lo is None  # one sample: no interval
    skewed = mean_interval([50.0, 60.0, 1000.0], bounds=(0.0, 1000.0))  # t interval -1000..1740 unbounded
    assert (skewed.lo, skewed.hi) == (0.0, 1000.0) and skewed.mean == pytest.approx(370.0)


def test_difficulty_presets_by_bare_name():
    assert load_task_config(["reference"]) == default_config()
    easy, hard = load_task_config(["easy"]), load_task_config(["hard"])
    assert easy == default_config(evader_speed=0.45)
    assert (hard.evader_speed, hard.perception_radius) == (0.9, 1.5)
    assert hard.position_noise > 0 and 0 < hard.miss_probability < 0.5
    assert hard.field_of_view == pytest.approx(math.radians(120))  # a camera's view, not all round
    assert load_task_config(["hard"], flags={"fidelity": "point"}).fidelity == "point"


def record(outcome: str, steps: int) -> EpisodeRecord:
    return EpisodeRecord(0, 0, 0, outcome, steps, None, {}, 0, "open")


def test_summarise_counts_outcomes_and_steps():
    rows = [record("success", 100), record("success", 200), record("collision", 30), record("timeout", 1000)]
    row = summarise("p", "0", "point", 5, rows)
    assert (row.success.count, row.collision.count, row.timeout.count, row.episodes) == (2, 1, 1, 4)
    assert row.success.p == 0.5
    assert row.steps.mean == pytest.approx(332.5)
    assert row.steps_success.mean == pytest.approx(150.0)
    flat = row.flat()
    assert tuple(flat) == FIELDS
    assert flat["success_pct"] == 50.0 and flat["collision_count"] == 1


def test_csv_and_json_read_back_equal_what_was_written(tmp_path):
    """Names a CSV must quote or could mistake for numbers, no success (no steps-if-success mean),
    one episode (no interval), an all-success row (a 100 % rate)."""
    rows = [summarise('net, "v2"', "my layouts/a b.yaml", "point", 7, [record("success", 12), record("timeout", 40)], 40),
            summarise("007", "0", "point", 7, [record("collision", 3)], 40),
            summarise("heuristic", "1", "quadrotor", 2**62, [record("success", 31)] * 3 + [record("success", 17)], 40)]
    assert rows[1].steps_success.mean is None and rows[1].steps.lo is None
    written = [r.flat() for r in rows]
    assert read_csv(write_csv(rows, tmp_path / "t.csv")) == written
    back = json.loads(write_json(rows, tmp_path / "t.json").read_text())["rows"]
    assert [{k: v for k, v in r.items() if k != "per_episode"} for r in back] == written


def test_a_foreign_or_cut_csv_is_named(tmp_path):
    p = tmp_path / "t.csv"
    write_csv([summarise("a", "0", "point", 1, [record("success", 5)], 40)], p)
    text = p.read_text()
    p.write_text(text[: len(text) - 20])  # cut mid-line
    with pytest.raises(ValueError, match=r"t.csv, line 2: \d+ values under 23 columns \(a file cut short\?\)"):
        read_csv(p)
    p.write_text(text.replace(",point,1,", ",point,one,"))
    with pytest.raises(ValueError, match=r"t.csv, line 2: episodes is 'one', expected an integer"):
        read_csv(p)
    p.write_text("name,score\nx,1\n")
    with pytest.raises(ValueError, match="t.csv: line 1 is not a header with policy and layout"):
        read_csv(p)


def quick_config(**changes):
    return default_config(fidelity="point", max_steps=25, **changes)


def test_same_seed_same_table_and_every_episode_counted():
    config = quick_config()

    def run(seed, layouts):
        records = []
        rows = evaluate(HeuristicTeam.from_config(config), config, layouts, episodes=5, seed=seed, n_worlds=2, on_episode=records.append)
        return rows, sorted((r.layout, r.seed, r.outcome, r.steps, tuple(r.returns.values())) for r in records)

    (rows_a, rec_a), (rows_b, rec_b) = run(3, [0, 1]), run(3, [0, 1])
    assert rows_a == rows_b and rec_a == rec_b  # same seed: same table, down to each episode's returns
    assert [r.layout for r in rows_a] == ["0", "1"]
    for r in rows_a:
        assert r.episodes == 5
        assert r.success.count + r.collision.count + r.timeout.count == 5
    assert len({rec[1] for rec in rec_a}) == 10  # every episode has its own seed
    _, rec_c = run(4, [0])
    assert not {rec[1] for rec in rec_c} & {rec[1] for rec in rec_a}  # another seed, other episodes


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_same_table_whatever_the_number_of_worlds(fidelity):
    # the hard preset: perception noise and missed detections on, plus random obstacles
    config = load_task_config(["hard"], flags={"fidelity": fidelity}, overrides=["max_steps=40"])
    assert config.position_noise > 0 and config.miss_probability > 0 and config.random_obstacle_count(load_layout(config.layout)) > 0

    def run(worlds):
        records = run_episodes(HeuristicTeam.from_config(config), config, 5, seed=11, n_worlds=worlds)
        return [(r.seed, r.outcome, r.steps, r.time_to_capture, r.returns) for r in records]

    one, three = run(1), run(3)
    assert one == three
    assert len({r[0] for r in one}) == 5 and len({str(r[4]) for r in one}) == 5  # distinct episodes
    rows = [evaluate(HeuristicTeam.from_config(config), config, [0], episodes=4, seed=3, n_worlds=w) for w in (2, 3)]
    assert format_table(rows[0]) == format_table(rows[1]) and rows[0] == rows[1]


def test_random_and_trained_policies_play_the_same_episodes_whatever_the_number_of_worlds():
    import numpy as np

    from pursuit_mj.belief import belief_spec
    from pursuit_mj.policy import RandomPolicy
    from train.checkpoint import load_checkpoint
    from train.policy import ROWS_PER_FORWARD, ActorPolicy, actor_from_checkpoint, spec_from_dict

    config = default_config(fidelity="point", max_steps=30)

    def run(policy, worlds):
        return [(r.seed, r.outcome, r.steps, r.returns) for r in run_episodes(policy, config, 5, seed=2, n_worlds=worlds)]

    assert run(RandomPolicy(4), 1) == run(RandomPolicy(4), 3)
    # a trained actor gives each pursuer the same action whatever else shares its forward pass
    # (float32 products of another shape differ in the last bits, and a chase amplifies that)
    data = load_checkpoint("pretrained/pursuers.pt")
    spec = belief_spec(spec_from_dict(data["obs_spec"]))
    policy = ActorPolicy(actor_from_checkpoint(data, spec, "pretrained"), "pretrained")
    obs = np.random.default_rng(0).normal(size=(ROWS_PER_FORWARD + 5, 3, spec.dim)).astype(np.float32)
    whole = policy.act(obs, spec)
    for w in (1, 2, 7):
        np.testing.assert_array_equal(policy.act(obs[:w], spec), whole[:w])
    np.testing.assert_array_equal(policy.act(obs[9:], spec), whole[9:])


def _episodes(config, layout, seed=3):
    (row,) = evaluate(HeuristicTeam.from_config(config), config, [layout], episodes=3, seed=seed, n_worlds=3)
    return row


def test_a_built_in_layout_named_by_its_file_plays_the_episodes_of_its_index(tmp_path, monkeypatch):
    import os
    import zlib

    import numpy as np

    from pursuit_mj.comparison import pair
    from pursuit_mj.evaluation import layout_seed

    config = quick_config()
    by_index = _episodes(config, 0)
    # the index seeds as it always did (documented numbers measured with indexes stay)
    assert layout_seed(3, "0") == int(np.random.SeedSequence([3, zlib.crc32(b"0")]).generate_state(1)[0])
    assert by_index.seed == 3 and by_index.episode_log[0][0] != 0
    builtin = builtin_layout_path(0)
    monkeypatch.chdir(builtin.parent.parent.parent)  # the repository: configs/layouts/0_*.yaml
    relative = os.path.relpath(builtin)
    link = tmp_path / "mine.yaml"
    link.symlink_to(builtin)
    for ref in (relative, f"./{relative}", str(builtin), str(link)):
        row = _episodes(config, ref)
        assert row.layout == ref  # shown as given
        assert row.episode_log == by_index.episode_log, ref  # the same seeds, outcomes and steps
        assert pair(row, by_index, config.max_steps).steps.mean == 0.0  # paired with the index's row
    assert _episodes(config, 1).episode_log != by_index.episode_log


def test_a_layout_file_plays_the_same_episodes_however_its_path_is_spelled(tmp_path, monkeypatch):
    import zlib

    import numpy as np

    from pursuit_mj.evaluation import layout_seed

    config = quick_config()
    (tmp_path / "sub").mkdir()
    (tmp_path / "x.yaml").write_text(builtin_layout_path(1).read_text())  # a copy: a layout of its own
    monkeypatch.chdir(tmp_path)
    plain = _episodes(config, "x.yaml")
    for ref in ("./x.yaml", "sub/../x.yaml", ".//x.yaml"):
        row = _episodes(config, ref)
        assert row.layout == ref and row.episode_log == plain.episode_log, ref
    # a path in its normal form seeds as it always did; a copy of a built-in is not that built-in
    assert layout_seed(3, "x.yaml") == int(np.random.SeedSequence([3, zlib.crc32(b"x.yaml")]).generate_state(1)[0])
    assert layout_seed(3, "x.yaml") != layout_seed(3, "1")


def test_evaluate_refuses_bad_layouts_and_counts_before_running():
    config = quick_config()
    team = HeuristicTeam.from_config(config)
    with pytest.raises(ValueError, match="layout 7"):
        evaluate(team, config, [0, 7], episodes=2)
    with pytest.raises(ValueError, match="episodes"):
        evaluate(team, config, [0], episodes=0)


def test_eval_cli_writes_csv_json_and_plots(tmp_path, capsys):
    layout_file = "configs/layouts/1_walls.yaml"
    code = main(["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", layout_file, "--episodes", "3",
                 "--worlds", "3", "--fidelity", "point", "--set", "max_steps=20", "--seed", "2", "--out", str(tmp_path / "table"),
                 "--plots", str(tmp_path / "plots"), "--rerun", str(tmp_path / "eval.rrd"), "--rerun-episodes", "1", "-q"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "success % [95% CI]" in printed and "random" in printed
    rows = read_csv(tmp_path / "table.csv")
    assert [(r["policy"], r["layout"]) for r in rows] == [("heuristic", "0"), ("heuristic", layout_file), ("random", "0"), ("random", layout_file)]
    data = json.loads((tmp_path / "table.json").read_text())
    assert data["config"]["fidelity"] == "point" and data["config"]["max_steps"] == 20
    assert [{k: v for k, v in r.items() if k != "per_episode"} for r in data["rows"]] == rows  # the same table
    assert "paired with heuristic on the same episodes" in printed  # heuristic and others: paired by default
    assert [(p["policy"], p["versus"], p["layout"]) for p in data["paired"]] == [
        ("random", "heuristic", "0"), ("random", "heuristic", layout_file), ("random", "heuristic", "all")]  # and over both layouts
    assert data["paired"][-1]["episodes"] == 6 and {"mcnemar_p", "success_verdict"} <= data["paired"][-1].keys()
    for r in data["rows"]:
        assert r["episodes"] == 3
        assert r["success_count"] + r["collision_count"] + r["timeout_count"] == 3
        per = r["per_episode"]  # every episode, to pair or pool later
        assert per["outcome"].count("success") == r["success_count"] and len(per["steps"]) == 3
    by_layout = {}
    for r in data["rows"]:
        by_layout.setdefault(r["layout"], []).append(r["per_episode"]["seed"])
    assert all(a == b for a, b in by_layout.values())  # the same episodes for both policies
    code_meta = data["code"]
    assert len(code_meta["drone_model_sha256"]) == 64 and "git_commit" in code_meta and "version" in code_meta
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == ["collision.png", "mean_steps.png", "steps_success.png",
                                                                      "success.png", "timeout.png"]
    assert (tmp_path / "plots" / "success.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    recorded = {e for e in read_entities(tmp_path / "eval.rrd") if e.startswith("/__properties/episode_")}
    assert len(recorded) == 4  # one episode per policy and layout


def test_eval_cli_runs_a_trained_model_beside_the_heuristic(tmp_path, capsys):
    import torch

    from pursuit_mj.configio import to_dict
    from pursuit_mj.obs_spec import ObsSpec
    from train.checkpoint import save_checkpoint
    from train.config import load_train_config
    from train.networks import Actor

    torch.manual_seed(0)
    cfg = load_train_config([], ["name=untrained"])
    spec = ObsSpec.make(3, 1, 16)
    save_checkpoint(tmp_path / "m.pt", {"train_config": to_dict(cfg), "obs_spec": spec.to_dict(),
                                         "actor": Actor(spec, cfg.net).state_dict(), "counters": {"update": 0}})
    code = main(["eval", "--policy", "heuristic", "-m", str(tmp_path / "m.pt"), "--layouts", "0", "--episodes", "2",
                 "--worlds", "2", "--fidelity", "point", "--set", "max_steps=10", "--json", str(tmp_path / "t.json"), "-q"])
    assert code == 0
    rows = json.loads((tmp_path / "t.json").read_text())["rows"]
    assert [r["policy"] for r in rows] == ["heuristic", "untrained"]
    assert rows[1]["episodes"] == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["--layouts", "9"], "layout 9"),
        (["--layouts", "no/such/layout.yaml"], "no/such/layout.yaml"),
        (["--policy", "greedy"], "unknown policy"),
        (["--model", "missing/model.pt"], "--model missing/model.pt: no such checkpoint file"),
        (["--episodes", "0"], "--episodes"),
        (["--set", "evader_speed=-1"], "evader_speed"),
        (["--policy", "heuristic", "--policy", "random", "--versus", "greedy"], "--versus 'greedy': not a policy of this table"),
        (["--layouts", "0", "1", "0"], "--layouts: 0 is given twice"),
        (["--layouts", "0", str(builtin_layout_path(0))], "0_open.yaml is given twice (as 0 and"),
        (["--plots", "/dev/null/plots"], "--plots /dev/null/plots: cannot create the folder"),
        (["--csv", "same.txt", "--json", "same.txt"], "both name same.txt"),
        (["--json", "run.rrd", "--rerun", "run.rrd"], "--json and --rerun: both name run.rrd"),
    ],
)
def test_eval_cli_bad_input_exits_2_with_a_clear_message(args, message, capsys, tmp_path):
    code = main(["eval", "--fidelity", "point", "--episodes", "1", "--out", str(tmp_path / "t"), "-q"] + args)
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("pursuit-mj eval: error:") and message in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize("prefix", ["tables/", "tables/."])
def test_eval_out_naming_a_folder_is_refused_not_written_as_hidden_files(prefix, tmp_path, capsys):
    """--out tables/ wrote tables/.csv and tables/.json, files ls does not show."""
    out = f"{tmp_path}/{prefix}"
    assert main(["eval", "--fidelity", "point", "--episodes", "1", "-q", "--out", out]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: names a folder, not a file name prefix" in err and f"give e.g. --out {tmp_path}/tables/table" in err
    assert not (tmp_path / "tables").exists()


@pytest.mark.parametrize("flag", ["--json", "--csv"])
def test_eval_json_or_csv_naming_a_folder_is_refused_not_written_as_a_file_of_that_name(flag, tmp_path, capsys):
    """--json tables/ (a folder that does not exist yet) wrote the table to a file called 'tables'."""
    out = f"{tmp_path}/tables/"
    assert main(["eval", "--fidelity", "point", "--episodes", "1", "--set", "max_steps=5", "-q", flag, out]) == 2
    err = capsys.readouterr().err
    assert f"{flag} path {out}: ends in '/', which names a folder" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "tables").exists()


@pytest.mark.parametrize("command", ["eval", "pool"])
def test_an_out_prefix_ending_in_a_table_extension_is_refused(command, tmp_path, capsys):
    """--out o.json wrote o.json.csv and o.json.json."""
    out = f"{tmp_path}/o.json"
    args = ["--fidelity", "point", "--episodes", "1", "-q"] if command == "eval" else [str(tmp_path / "t.json")]
    assert main([command, *args, "--out", out]) == 2
    assert f"--out {out}: a file name prefix, to which .csv and .json are added" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag, value, message", [
    ("--out", "", "--out '': an empty path"),
    ("--csv", "", "--csv '': an empty path"),
    ("--json", " ", "--json ' ': an empty path"),
    ("--plots", "", "--plots '': an empty path"),
    ("--rerun", "", "--rerun '': an empty path"),
])
def test_eval_refuses_an_empty_output_path_it_would_ignore(flag, value, message, capsys, tmp_path):
    """--out '' (or another empty output path) ran the table and wrote nothing, without a word."""
    assert main(["eval", "--fidelity", "point", "--episodes", "1", "--set", "max_steps=5", "-q", flag, value]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_eval_keeps_its_finished_cells_beside_the_table_it_was_asked_for(tmp_path, monkeypatch, capsys):
    """SIGTERM (or Ctrl-C) while the third policy-layout cell runs: the two finished cells are
    printed and written to t.interrupted.json / .csv; a whole t.json from before stays whole."""
    import os
    import signal

    import pursuit_mj.evaluation as evaluation

    whole = tmp_path / "t.json"
    whole.write_text('{"rows": "an earlier, whole table"}\n')
    real, cells = evaluation.evaluate, []

    def evaluate_then_stopped(*a, **k):
        cells.append(k["label"])
        if len(cells) == 3:
            os.kill(os.getpid(), signal.SIGTERM)  # arrives inside this cell, before its row exists
        return real(*a, **k)

    monkeypatch.setattr(evaluation, "evaluate", evaluate_then_stopped)
    code = main(["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", "1", "--episodes", "2",
                 "--worlds", "2", "--fidelity", "point", "--set", "max_steps=20", "--out", str(tmp_path / "t"), "-q"])
    assert code == 143  # 128 + SIGTERM
    err = capsys.readouterr().err
    assert "[eval] interrupted; the 2 finished policy-layout cells, every row in point fidelity, task reference with --set max_steps=20:" in err and err.endswith("pursuit-mj eval: interrupted by SIGTERM\n")
    kept = json.loads((tmp_path / "t.interrupted.json").read_text())
    assert kept["interrupted"] is True and [(r["policy"], r["layout"]) for r in kept["rows"]] == [("heuristic", "0"), ("heuristic", "1")]
    assert all(len(r["per_episode"]["seed"]) == 2 for r in kept["rows"])
    assert len(read_csv(tmp_path / "t.interrupted.csv")) == 2
    assert whole.read_text() == '{"rows": "an earlier, whole table"}\n' and not (tmp_path / "t.csv").exists()


def test_an_eval_whose_table_goes_to_dev_stdout_as_a_pipe_runs_to_its_end(tmp_path, monkeypatch, capsys):
    """'eval --csv /dev/stdout | ...' (a pipe, which --csv may be) played its first cell, then kept
    that cell beside the table, as /dev/stdout.interrupted, a name in /dev that no device holds:
    refused, the eval stopped after its first cell. A pipe or device holds no earlier table to keep
    whole and no file for --resume: such an eval keeps nothing beside it. Here a named pipe
    'stdout' in a stand-in for /dev stands for the real one, which is never touched."""
    import os
    import threading

    from pursuit_mj import io_utils

    dev = tmp_path / "dev"
    dev.mkdir()
    os.mkfifo(dev / "stdout")
    monkeypatch.setattr(io_utils, "DEVICES_FOLDER", str(dev))
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append((dev / "stdout").read_text()), daemon=True)
    reader.start()
    code = main(["eval", "--policy", "heuristic", "--layouts", "0", "1", "--episodes", "1", "--worlds", "1",
                 "--fidelity", "point", "--set", "max_steps=20", "--csv", str(dev / "stdout"), "-q"])
    reader.join(5)
    assert code == 0, capsys.readouterr().err
    assert [line.split(",")[:2] for line in got[0].splitlines()] == [["policy", "layout"], ["heuristic", "0"], ["heuristic", "1"]]
    assert [p.name for p in dev.iterdir()] == ["stdout"]


def test_resume_to_a_pipe_says_that_nothing_is_kept_beside_one(tmp_path, capsys):
    """'--json PIPE --resume' looked for PIPE.interrupted, which no eval to a pipe keeps."""
    import os

    os.mkfifo(tmp_path / "view.json")
    assert main(["eval", "--policy", "heuristic", "--layouts", "0", "--episodes", "1", "--fidelity", "point",
                 "--json", str(tmp_path / "view.json"), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "--resume: " in err and "view.json is a pipe or device, beside which an eval keeps no finished rows" in err, err


def test_resume_counts_the_rows_it_takes_back_in_words_that_fit_one(tmp_path, monkeypatch, capsys):
    """A resume of an eval stopped after its first row said '[eval] resuming: 1 finished rows from ...'."""
    import os
    import signal

    import pursuit_mj.evaluation as evaluation

    cmd = ["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", "--episodes", "1", "--worlds", "1",
           "--fidelity", "point", "--set", "max_steps=5", "--out", str(tmp_path / "t")]
    real, cells = evaluation.evaluate, []

    def stop_at_second(*a, **k):
        cells.append(k["label"])
        if len(cells) == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return real(*a, **k)

    monkeypatch.setattr(evaluation, "evaluate", stop_at_second)
    assert main(cmd) == 143
    monkeypatch.setattr(evaluation, "evaluate", real)
    capsys.readouterr()
    assert main(cmd + ["--resume"]) == 0
    err = capsys.readouterr().err
    assert f"[eval] resuming: 1 finished row from {tmp_path / 't.interrupted.json'}" in err
    assert "[eval] random layout 0: 1 episode in " in err  # the row's progress line likewise


def test_resume_runs_only_the_rows_an_interrupted_eval_did_not_finish_and_gives_the_whole_table(tmp_path, monkeypatch, capsys):
    import os
    import signal

    import pursuit_mj.evaluation as evaluation

    cmd = ["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", "1", "--episodes", "3", "--worlds", "2",
           "--fidelity", "point", "--set", "max_steps=25", "-q"]
    assert main(cmd + ["--out", str(tmp_path / "whole")]) == 0  # the table uninterrupted, to compare with
    real, cells = evaluation.evaluate, []

    def evaluate_counted(*a, **k):
        cells.append(k["label"])
        if len(cells) == 3 and os.environ.get("STOP_AT_THIRD") == "1":
            os.kill(os.getpid(), signal.SIGTERM)
        return real(*a, **k)

    monkeypatch.setattr(evaluation, "evaluate", evaluate_counted)
    monkeypatch.setenv("STOP_AT_THIRD", "1")
    assert main(cmd + ["--out", str(tmp_path / "t")]) == 143  # stopped by SIGTERM
    assert (tmp_path / "t.interrupted.json").is_file()
    # the same command with another task setting, or other episodes, is refused
    assert main(cmd + ["--out", str(tmp_path / "t"), "--resume", "--set", "evader_speed=0.5"]) == 2
    assert "--resume: the task config differs from the interrupted eval's at evader_speed (0.6 in" in capsys.readouterr().err
    assert main(cmd + ["--out", str(tmp_path / "t"), "--resume", "--episodes", "4"]) == 2
    err = capsys.readouterr().err
    assert "--resume: episodes differs from the interrupted eval's (3 in" in err
    # how to start over: without --resume alone the kept rows refuse it too
    assert (f"run it again without --resume after deleting {tmp_path / 't.interrupted.json'} and "
            f"{tmp_path / 't.interrupted.csv'}, or with another --out") in err, err
    monkeypatch.setenv("STOP_AT_THIRD", "0")
    cells.clear()
    assert main(cmd + ["--out", str(tmp_path / "t"), "--resume", "--worlds", "3"]) == 0  # worlds do not change a table
    assert cells == ["random", "random"]  # the two heuristic rows were finished
    whole, resumed = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("whole", "t"))
    assert resumed["rows"] == whole["rows"] and resumed["paired"] == whole["paired"]
    assert (tmp_path / "t.csv").read_text() == (tmp_path / "whole.csv").read_text()
    assert not (tmp_path / "t.interrupted.json").exists() and not (tmp_path / "t.interrupted.csv").exists()
    assert main(cmd + ["--out", str(tmp_path / "t"), "--resume"]) == 2
    assert f"--resume: no interrupted eval at {tmp_path / 't.interrupted.json'}" in capsys.readouterr().err


@pytest.mark.parametrize("field, value", [("outcome", "escaped"), ("seed", 12345), ("steps", 0), ("captured", 3)])
def test_resume_refuses_kept_rows_whose_episodes_this_eval_would_not_play(tmp_path, capsys, field, value):
    """The kept rows are rebuilt from their episodes: a damaged or edited episode list (an unknown
    outcome, another seed, steps or evaders caught out of range) must not enter the table."""
    cmd = ["eval", "--policy", "heuristic", "--layouts", "0", "1", "--episodes", "2", "--worlds", "2", "--fidelity", "point",
           "--set", "max_steps=20", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 0
    data = json.loads((tmp_path / "t.json").read_text())
    data["rows"][1]["per_episode"][field][0] = value
    (tmp_path / "t.interrupted.json").write_text(json.dumps(data))
    assert main(cmd + ["--resume"]) == 2
    assert f"--resume: {tmp_path / 't.interrupted.json'}, row 2: its episodes (per_episode) are not those this eval would play" \
        in capsys.readouterr().err


def test_resume_refuses_rows_kept_for_a_layout_file_edited_since(tmp_path, capsys):
    """A kept row was tied to its layout by the file's path alone: after the file was edited,
    --resume put the old arena's rows into the table."""
    arena = tmp_path / "arena.yaml"
    arena.write_text(builtin_layout_path(1).read_text())
    cmd = ["eval", "--policy", "heuristic", "--layouts", "0", str(arena), "--episodes", "1", "--worlds", "1",
           "--fidelity", "point", "--set", "max_steps=20", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 0
    (tmp_path / "t.interrupted.json").write_text((tmp_path / "t.json").read_text())  # as if stopped at the end
    arena.write_text(builtin_layout_path(2).read_text())
    assert main(cmd + ["--resume"]) == 2
    err = capsys.readouterr().err
    assert f"--resume: the layout file {arena} changed since the interrupted eval" in err


def test_resume_keys_kept_rows_to_the_source_not_the_git_commit(tmp_path, monkeypatch, capsys):
    """Kept rows were matched on the git commit: a docs-only commit threw them away, and an
    uncommitted edit of the code that plays the episodes was not noticed at all."""
    import pursuit_mj.provenance as provenance

    cmd = ["eval", "--policy", "heuristic", "--layouts", "0", "--episodes", "1", "--worlds", "1", "--fidelity", "point",
           "--set", "max_steps=20", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 0
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["code"]["source_sha256"] == provenance.source_sha256()
    data["code"]["git_commit"] = "0" * 40  # another commit, the same source
    (tmp_path / "t.interrupted.json").write_text(json.dumps(data))
    assert main(cmd + ["--resume"]) == 0
    (tmp_path / "t.interrupted.json").write_text((tmp_path / "t.json").read_text())
    monkeypatch.setattr(provenance, "source_sha256", lambda: "f" * 64)  # as after an edit of the code
    assert main(cmd + ["--resume"]) == 2
    assert "--resume: the code changed since the interrupted eval (source_sha256" in capsys.readouterr().err


def test_the_source_hash_follows_every_source_file_but_not_compiled_caches(tmp_path):
    from pursuit_mj.provenance import source_digest

    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "model.xml").write_text("<mujoco/>")
    first = source_digest({"pkg": pkg})
    (pkg / "__pycache__").mkdir()
    (pkg / "__pycache__" / "a.cpython-311.pyc").write_bytes(b"cache")
    assert source_digest({"pkg": pkg}) == first
    (pkg / "sub" / "model.xml").write_text("<mujoco />")
    assert source_digest({"pkg": pkg}) != first
    (pkg / "sub" / "model.xml").write_text("<mujoco/>")
    assert source_digest({"pkg": pkg}) == first
    (pkg / "b.py").write_text("")  # a new, empty module is a change too
    assert source_digest({"pkg": pkg}) != first
    assert source_digest({"other": pkg}) != source_digest({"pkg": pkg})


def test_an_eval_stopped_before_any_cell_finished_says_nothing_is_kept(tmp_path, monkeypatch, capsys):
    """It said only 'interrupted'; its --resume then answered 'an eval stopped by Ctrl-C or SIGTERM
    leaves one', as if the eval had not been stopped that way."""

    import pursuit_mj.evaluation as evaluation

    def stopped(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluation, "evaluate", stopped)
    cmd = ["eval", "--fidelity", "point", "--episodes", "1", "-q", "--out", str(tmp_path / "t")]
    assert main(cmd) == 130
    assert "[eval] interrupted before any policy-layout cell finished: nothing is kept for --resume" in capsys.readouterr().err
    assert main(cmd + ["--resume"]) == 2
    assert "(an eval stopped after its first policy-layout cell leaves one)" in capsys.readouterr().err


def test_eval_versus_a_policy_with_no_other_to_pair_is_refused(capsys, tmp_path):
    """--versus heuristic on a table of the heuristic team alone was taken, printed a blank line
    and wrote "paired": [] without a word: the comparison asked for was never made."""
    code = main(["eval", "--policy", "heuristic", "--versus", "heuristic", "--fidelity", "point", "--episodes", "1",
                 "--set", "max_steps=5", "--json", str(tmp_path / "t.json"), "-q"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--versus 'heuristic': this table has no other policy to pair with it" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "t.json").exists()


@pytest.mark.parametrize("args, message", [
    (["eval", "--layouts", "0", "--layout", "2"], "--layout 2 beside --layouts 0: the table's layouts are --layouts"),
    (["eval", "--layouts", "0", "--set", "layout=2"], "--set layout=2 beside --layouts 0: the table's layouts are --layouts"),
    (["eval", "--set", "random_layout=true"], "random_layout: the task draws a layout per episode"),
    (["demo", "--layouts", "0", "-i", "2"], "--layout 2 beside --layouts 0: the table's layouts are --layouts"),
    (["demo", "--set", "random_layout=true"], "random_layout: the task draws a layout per episode"),
])
def test_a_layout_choice_the_table_would_not_play_is_refused(args, message, capsys):
    """eval --layouts 0 --layout 2 played layout 0 only, and random_layout (which evaluate switches
    off) played the task's one layout under its label, both without a word."""
    assert main(args + ["--fidelity", "point", "--episodes", "1", "--set", "max_steps=5"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


def test_demo_plays_the_layout_named_by_layout(capsys):
    """demo --layout 2 played layouts 0, 1, 2 and 3: the flag was taken and ignored."""
    code = main(["demo", "--layout", "2", "--no-heuristic", "--no-shield", "--episodes", "1", "--worlds", "1",
                 "--fidelity", "point", "--set", "max_steps=5"])
    assert code == 0
    table = capsys.readouterr().out.split("\n\n")[0].splitlines()
    assert table[0] == "evaluated 1 policy on 1 layout, every row in point fidelity, task reference with --set max_steps=5"
    assert [line.split()[1] for line in table[2:]] == ["2"]


@pytest.mark.parametrize("seconds, said", [(0.0, "under 1 s"), (0.49, "under 1 s"), (0.99, "under 1 s"), (1.0, "1 s"), (83.4, "83 s")])
def test_demo_says_a_run_under_a_second_took_under_1_s_not_0_s(seconds, said):
    """demo's closing line said '(0 s; brackets are ...)' for a run under half a second."""
    from pursuit_cli.demo import took

    assert took(seconds) == said


@pytest.mark.parametrize("command", [["eval"], ["demo"]])
def test_a_seed_too_large_for_episode_seeds_is_refused_naming_the_flag(command, capsys, tmp_path):
    """--seed 2**63 was taken by the parser, made the output folders, then failed as 'evaluate seed'."""
    out = ["--out", str(tmp_path / "new" / "t")] if command == ["eval"] else []
    with pytest.raises(SystemExit) as exc:
        main([*command, "--seed", str(2**63), "--fidelity", "point", "--episodes", "1", *out])
    assert exc.value.code == 2
    assert f"argument --seed: expected an integer below 2**63, got {2**63}" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_demo_tells_a_model_named_heuristic_from_the_heuristic_team_and_pairs_both_its_rows(tmp_path, capsys):
    """A model trained as run 'heuristic' gave demo two rows called heuristic: the bare model was
    paired with nothing (with --no-shield there was no paired table at all)."""
    import torch

    from pursuit_mj.configio import to_dict
    from pursuit_mj.obs_spec import ObsSpec
    from train.checkpoint import save_checkpoint
    from train.config import load_train_config
    from train.networks import Actor

    torch.manual_seed(0)
    cfg = load_train_config([], ["name=heuristic"])
    spec = ObsSpec.make(3, 1, 16)
    save_checkpoint(tmp_path / "m.pt", {"train_config": to_dict(cfg), "obs_spec": spec.to_dict(),
                                         "actor": Actor(spec, cfg.net).state_dict(), "counters": {"update": 0}})
    code = main(["demo", "-m", str(tmp_path / "m.pt"), "--layouts", "0", "--episodes", "2", "--worlds", "2",
                 "--fidelity", "point", "--set", "max_steps=10"])
    assert code == 0
    table, paired = capsys.readouterr().out.split("\n\n")[:2]
    assert [line.split()[0] for line in table.splitlines()[2:]] == ["heuristic#2", "heuristic#2+shield", "heuristic"]
    assert [line.split()[:2] for line in paired.splitlines()[2:]] == [["heuristic#2", "heuristic"],
                                                                      ["heuristic#2+shield", "heuristic"]]


def test_a_rare_outcome_in_a_large_table_does_not_print_as_zero_or_all():
    from pursuit_mj.evaluation import percent_text

    assert percent_text(1 / 2500) == "0.04"  # one collision in 2500 episodes: not "0.0"
    assert percent_text(2499 / 2500) == "99.96"  # and the successes beside it not "100.0"
    assert percent_text(1 / 3_000_000) == "0.00003"
    assert percent_text(0.0) == "0.0" and percent_text(1.0) == "100.0" and percent_text(0.125) == "12.5"
    records = [EpisodeRecord(0, k, 0, "collision" if k == 0 else "success", 100, None, {}, 0, "0") for k in range(2500)]
    table = format_table([summarise("p", "0", "point", 0, records, 1000)])
    line = table.splitlines()[-1]
    assert " 99.96 [" in line and " 0.04 [" in line


def test_a_rare_outcome_in_a_huge_table_is_not_zero_or_all_in_its_csv_and_json_either():
    """Row.flat rounded percentages to 3 decimals: one collision in 300,000 episodes was 0.0 % in the CSV
    and JSON (the table said 0.0003), the successes beside it 100.0, and none in 100,000 had the
    interval [0.0, 0.0], a certainty the Wilson interval (hi 0.0038 %) does not claim."""
    from pursuit_mj.evaluation import Row
    from pursuit_mj.stats import Mean, percent_text, rate

    steps = Mean(2, 1.0, 1.0, 1.0)
    for count, n in ((1, 300_000), (0, 100_000)):
        flat = Row("p", "0", "point", n, rate(n - count, n), rate(count, n), rate(0, n), steps, steps, 0).flat()
        assert 0 < flat["collision_ci_hi"] and flat["success_ci_lo"] < 100
        if count:
            assert 0 < flat["collision_pct"] < flat["collision_ci_hi"] and flat["success_pct"] < 100
            assert 0 < flat["collision_ci_lo"] and flat["success_ci_hi"] < 100
        assert flat["collision_pct"] == float(percent_text(count / n))  # what the table prints: 0.0003, 0.0
        assert flat["collision_ci_hi"] == pytest.approx(100 * rate(count, n).hi, rel=0.15)
    flat = Row("p", "0", "point", 16, rate(1, 16), rate(15, 16), rate(0, 16), steps, steps, 0).flat()
    assert (flat["success_pct"], flat["success_ci_lo"], flat["collision_ci_hi"]) == (6.25, 1.112, 98.888)  # as before


def test_an_eval_killed_with_kill_9_keeps_its_finished_cells_for_resume(tmp_path):
    """kill -9 (or the out-of-memory killer) leaves no moment to write the finished cells: they
    were lost, and only Ctrl-C or SIGTERM kept them. Each finished cell is now kept as it ends."""
    import subprocess
    import sys
    from pathlib import Path

    cmd = ["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", "1", "--episodes", "2",
           "--worlds", "2", "--fidelity", "point", "--set", "max_steps=20", "--out", str(tmp_path / "t"), "-q"]
    killed_at_third_cell = (
        "import os, signal, sys\n"
        "import pursuit_mj.evaluation as evaluation\n"
        "from pursuit_cli import main\n"
        "real, cells = evaluation.evaluate, []\n"
        "def evaluate(*a, **k):\n"
        "    cells.append(k['label'])\n"
        "    if len(cells) == 3:\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return real(*a, **k)\n"
        "evaluation.evaluate = evaluate\n"
        "main(sys.argv[1:])\n")
    proc = subprocess.run([sys.executable, "-c", killed_at_third_cell, *cmd], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == -9, proc.stderr[-2000:]
    kept = json.loads((tmp_path / "t.interrupted.json").read_text())
    assert [(r["policy"], r["layout"]) for r in kept["rows"]] == [("heuristic", "0"), ("heuristic", "1")]
    assert len(read_csv(tmp_path / "t.interrupted.csv")) == 2
    assert main(cmd + ["--resume"]) == 0
    assert [(r["policy"], r["layout"]) for r in json.loads((tmp_path / "t.json").read_text())["rows"]] == [
        ("heuristic", "0"), ("heuristic", "1"), ("random", "0"), ("random", "1")]
    assert not (tmp_path / "t.interrupted.json").exists() and not (tmp_path / "t.interrupted.csv").exists()


def test_an_eval_to_a_prefix_holding_an_interrupted_evals_rows_is_refused_unless_it_resumes(tmp_path, capsys):
    """Another eval to the same prefix overwrote them as its cells finished and removed them at its
    end: the interrupted eval's --resume then found nothing."""
    kept = tmp_path / "t.interrupted.json"
    kept.write_text('{"rows": []}')
    cmd = ["eval", "--policy", "random", "--layouts", "0", "--episodes", "1", "--fidelity", "point",
           "--set", "max_steps=5", "--out", str(tmp_path / "t"), "-q"]
    assert main(cmd) == 2
    assert (f"{kept}: the finished rows of an interrupted eval are kept there; give --resume to go on from them, or "
            f"delete {kept} to start over") in capsys.readouterr().err
    assert kept.read_text() == '{"rows": []}'
    kept.unlink()
    assert main(cmd) == 0 and sorted(p.name for p in tmp_path.iterdir() if "interrupted" in p.name) == []


@pytest.mark.parametrize("layouts, said", [
    ("configs/layouts/1_walls.yaml", "layouts: expected a list of layouts"),
    ("12", "layouts: expected a list of layouts"),  # ran layouts 1 and 2
    (0, "layouts: expected a list of layouts"),
])
def test_evaluate_refuses_one_layout_not_in_a_list_instead_of_reading_it_character_by_character(layouts, said):
    from pursuit_mj.policy import RandomPolicy

    with pytest.raises(ValueError, match=said) as err:
        evaluate(RandomPolicy(), default_config(fidelity="point"), layouts=layouts, episodes=1)
    assert f"[{layouts!r}]" in str(err.value)


@pytest.mark.parametrize("policy, config, said", [
    ("heuristic", "ok", "evaluate policy: expected a Policy (with act and reset), got 'heuristic'"),
    ("random", None, "evaluate config: expected a TaskConfig (pursuit_mj.config.default_config"),
])
def test_evaluate_refuses_a_policy_or_config_of_the_wrong_kind_before_any_episode(policy, config, said):
    from pursuit_mj.policy import RandomPolicy

    policy = RandomPolicy() if policy == "random" else policy
    config = default_config(fidelity="point", max_steps=3) if config == "ok" else config
    with pytest.raises(ValueError, match=said.replace("(", "\\(").replace(")", "\\)")):
        evaluate(policy, config, layouts=[0], episodes=1)


def test_evaluate_asks_for_a_label_up_front_when_the_policy_has_no_name():
    class Nameless:
        def reset(self, n_worlds, world_ids=None):
            pass

        def act(self, obs, spec):
            return np.zeros(obs.shape[:-1] + (2,))

    with pytest.raises(ValueError, match="evaluate label: the policy has no name; give label="):
        evaluate(Nameless(), default_config(fidelity="point", max_steps=3), layouts=[0], episodes=1)
    (row,) = evaluate(Nameless(), default_config(fidelity="point", max_steps=3), layouts=[0], episodes=1, label="mine")
    assert row.policy == "mine"


def test_two_models_of_one_run_name_are_told_apart_by_their_files(tmp_path, capsys):
    """best.pt and last.pt of one run were labelled NAME and NAME#2, and nothing said which was which."""
    import torch

    from pursuit_mj.configio import to_dict
    from pursuit_mj.obs_spec import ObsSpec
    from train.checkpoint import save_checkpoint
    from train.config import load_train_config
    from train.networks import Actor

    torch.manual_seed(0)
    cfg = load_train_config([], ["name=fo"])
    spec = ObsSpec.make(3, 1, 16)
    for name in ("best.pt", "last.pt"):
        save_checkpoint(tmp_path / name, {"train_config": to_dict(cfg), "obs_spec": spec.to_dict(),
                                          "actor": Actor(spec, cfg.net).state_dict(), "counters": {"update": 0}})
    best, last = str(tmp_path / "best.pt"), str(tmp_path / "last.pt")
    code = main(["eval", "-m", best, "-m", last, "--layouts", "0", "--episodes", "1", "--fidelity", "point",
                 "--set", "max_steps=5", "-q", "--json", str(tmp_path / "t.json")])
    assert code == 0
    out = capsys.readouterr().out
    assert f"models: fo = {best}; fo#2 = {last}" in out, out
    assert json.loads((tmp_path / "t.json").read_text())["model_of"] == {"fo": best, "fo#2": last}
    code = main(["eval", "-m", best, "--policy", "random", "--layouts", "0", "--episodes", "1", "--fidelity", "point",
                 "--set", "max_steps=5", "-q"])
    assert code == 0 and "models:" not in capsys.readouterr().out  # a label that names its run alone says enough


class _ActsAs:
    """A policy of one's own whose act() answers in one way (`how`): wrongly (transposed, nan,
    text, masked) or as the env takes it (grad, bfloat16: torch tensors)."""

    name = "mine"

    def __init__(self, how: str):
        self.how = how

    def reset(self, n_worlds, world_ids=None):
        pass

    def act(self, obs, spec):
        import torch

        a = np.full(obs.shape[:-1] + (2,), 0.5)
        if self.how == "nan":
            a[-1, 1, 0] = np.nan
        if self.how == "masked":
            a = np.ma.masked_array(a, mask=np.zeros(a.shape, bool))
            a[0, 0, 0] = np.ma.masked
        makers = {"transposed": lambda: a.transpose(1, 0, 2), "text": lambda: a.astype(str),
                  "grad": lambda: torch.tensor(a, requires_grad=True), "bfloat16": lambda: torch.tensor(a, dtype=torch.bfloat16)}
        return makers.get(self.how, lambda: a)()


@pytest.mark.parametrize("how, said", [
    ("transposed", r"policy mine: act\(\) gave actions of shape \(3, 2, 2\), expected \(2, 3, 2\) \(worlds, pursuers, vx vy\)"),
    ("nan", r"policy mine: act\(\) gave nan for world 1, pursuer 1, vx"),
    ("text", r"policy mine: act\(\) gave actions of dtype <U32, expected real numbers"),
])
def test_a_policy_that_acts_wrongly_is_named_in_evaluate_and_render(how, said):
    """A policy of one's own that returned the wrong shape or a NaN was reported by the env as
    'actions: expected shape ...', naming neither the policy nor that its act() was at fault."""
    from pursuit_mj.render.episodes import run_episodes as render_episodes

    config = default_config(fidelity="point", max_steps=3)
    with pytest.raises(ValueError, match=said):
        evaluate(_ActsAs(how), config, layouts=[0], episodes=2, n_worlds=2)
    with pytest.raises(ValueError, match=said.replace(r"\(2, 3, 2\)", r"\(1, 3, 2\)").replace(r"\(3, 2, 2\)", r"\(3, 1, 2\)").replace("world 1", "world 0")):
        render_episodes(config, _ActsAs(how), 1)


@pytest.mark.parametrize("how", ["grad", "bfloat16"])
def test_evaluate_and_render_take_the_torch_tensors_the_env_takes(how):
    """checked_actions read act()'s answer with np.asarray: a tensor with grad (RuntimeError) or of
    bfloat16 (TypeError) ended evaluate and render in a traceback, where env.step takes both."""
    from pursuit_mj.render.episodes import run_episodes as render_episodes

    config = default_config(fidelity="point", max_steps=3)
    (row,) = evaluate(_ActsAs(how), config, layouts=[0], episodes=2, n_worlds=2)
    assert row.steps.mean == 3
    render_episodes(config, _ActsAs(how), 1)


def test_a_masked_array_from_act_is_refused_naming_the_policy():
    """np.asarray dropped the mask: the hidden values were flown as if act() had given them (the
    env refuses a masked array, as it did before evaluate checked the actions itself)."""
    config = default_config(fidelity="point", max_steps=3)
    with pytest.raises(ValueError, match=r"policy mine: act\(\) gave actions: a masked array with 1 masked entries"):
        evaluate(_ActsAs("masked"), config, layouts=[0], episodes=2, n_worlds=2)


def test_the_source_hash_reads_linked_asset_folders_as_an_installed_wheel_does(tmp_path):
    """In a git checkout pursuit_mj/assets/configs is a link to configs/ (a wheel holds a copy):
    the hash skipped linked folders, so an edited built-in layout kept the hash, and a kept eval
    row of the old layout was taken by --resume. Linked and copied folders now hash alike; the
    shipped policies are left out (each model file is hashed where it is used)."""
    import shutil

    from pursuit_mj.provenance import source_digest

    top = tmp_path / "repo"
    (top / "configs" / "layouts").mkdir(parents=True)
    (top / "configs" / "layouts" / "0.yaml").write_text("arena: {width: 4}\n")
    (top / "pretrained").mkdir()
    (top / "pretrained" / "p.pt").write_bytes(b"weights")
    linked = top / "linked"
    (linked / "assets").mkdir(parents=True)
    (linked / "a.py").write_text("x = 1\n")
    for name in ("configs", "pretrained"):
        (linked / "assets" / name).symlink_to(top / name, target_is_directory=True)
    copied = top / "copied"
    shutil.copytree(linked, copied, symlinks=False)
    first = source_digest({"pkg": linked})
    assert source_digest({"pkg": copied}) == first
    (top / "configs" / "layouts" / "0.yaml").write_text("arena: {width: 5}\n")
    assert source_digest({"pkg": linked}) != first
    (top / "configs" / "layouts" / "0.yaml").write_text("arena: {width: 4}\n")
    (top / "pretrained" / "p.pt").write_bytes(b"other weights")
    assert source_digest({"pkg": linked}) == first


@pytest.mark.parametrize("ending", ["/.", "/..", "/./"])
def test_eval_json_ending_in_a_dot_folder_is_refused_not_written_as_a_file_of_the_folders_name(ending, tmp_path, capsys):
    """--json tables/. names the folder as much as tables/ does, but Path('tables/.') is 'tables':
    the table went to a file called 'tables' after the trailing slash was refused."""
    out = f"{tmp_path}/new/tables{ending}"
    assert main(["eval", "--fidelity", "point", "--episodes", "1", "--set", "max_steps=5", "-q", "--json", out]) == 2
    err = capsys.readouterr().err
    assert f"--json path {out}: " in err and "names a folder" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("flags, said", [
    (["--csv", "n1/a.csv", "--json", "n2/"], "names a folder"),
    (["--csv", "n1/a.csv", "--json", "n1/a.csv"], "both name n1/a.csv"),
    (["--out", "n1/x/t", "--plots", "mine.txt"], "exists and is not a folder"),
    (["--out", "n1/x/t", "--resume"], "no interrupted eval"),
    (["--out", "n1/x/t", "--rerun", "mine.txt/r.rrd"], "exists and is not a folder"),
    (["--out", "n1/x/t", "--plots", "n1/plots", "--rerun", "n1/r/e.rrd", "--policy", "{failing}"], "raised IndexError"),
])
def test_an_eval_refused_or_failed_before_it_kept_anything_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch, flags, said):
    """One output's folder was made (check_writable of --csv, of --out's PREFIX.csv) before another
    output or --resume was refused, and a table whose first cell failed left the folders of --out,
    --plots and --rerun: empty folders the user never had (n1/, n1/x/)."""
    from pathlib import Path

    from test_policy_file import FAILING

    monkeypatch.chdir(tmp_path)
    Path("mine.txt").write_text("mine")
    Path("pol.py").write_text(FAILING)
    flags = [f.format(failing="pol.py:Failing") for f in flags]
    assert main(["eval", "--fidelity", "point", "--layouts", "0", "--episodes", "1", "--worlds", "1", "--set", "max_steps=3",
                 "-q", *flags]) == 2
    assert said in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "__pycache__") == ["mine.txt", "pol.py"]


POLICY_FILE = """from pursuit_mj.heuristic import HeuristicTeam
class Team:
    name = "mine"
    def __init__(self, config, seed):
        self.team = HeuristicTeam.from_config(config)
    def reset(self, n_worlds, world_ids=None):
        self.team.reset(n_worlds, world_ids)
    def act(self, obs, spec):
        return self.team.act(obs, spec)
class Still:
    def __init__(self, config, n_worlds, seed):
        self.n = n_worlds
    def reset(self, world_ids, seeds):
        pass
    def compute(self, evader_pos, *rest):
        return 0 * evader_pos
"""


@pytest.mark.parametrize("inputs, flag, out, said", [
    (["--model", "m.pt"], "--json", "m.pt", "--model m.pt"),
    (["--policy", "team.py:Team"], "--csv", "team.py", "--policy team.py:Team"),
    (["--layouts", "0", "arena.yaml"], "--csv", "./arena.yaml", "--layouts arena.yaml"),
    (["--task", "task.yaml"], "--json", "task.yaml", "--task task.yaml"),
    (["--set", "evader.model=team.py:Still"], "--json", "team.py", "evader.model team.py:Still"),
    (["--model", "m.pt"], "--rerun", "m.pt.rrd", None),  # not an input: no refusal from this check
])
def test_eval_refuses_an_output_that_is_one_of_its_input_files(inputs, flag, out, said, tmp_path, monkeypatch, capsys):
    """`eval --model m.pt --json m.pt` played the table and then wrote it over the checkpoint (and
    --csv over a policy file, a layout file, a task file): the user's input was gone."""
    import os
    import shutil

    from pursuit_mj.shipped import shipped_dir

    monkeypatch.chdir(tmp_path)
    shutil.copy(shipped_dir("pretrained") / "belppo_point.pt", "m.pt")
    (tmp_path / "team.py").write_text(POLICY_FILE)
    (tmp_path / "arena.yaml").write_text(builtin_layout_path(1).read_text())
    (tmp_path / "task.yaml").write_text("fidelity: point\n")
    os.link(tmp_path / "m.pt", tmp_path / "hard.pt")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    code = main(["eval", "--fidelity", "point", "--episodes", "1", "--worlds", "1", "--set", "max_steps=5", "-q",
                 *inputs, flag, out])
    err = capsys.readouterr().err
    if said is None:
        assert code == 0, err
        return
    assert code == 2, err
    assert f"{flag} {out}: the same file as {said}" in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


@pytest.mark.parametrize("flag, name", [("--json", "notes.json"), ("--csv", "data.csv"), ("--out", "notes")])
def test_eval_refuses_to_write_its_table_over_a_file_that_is_no_table(flag, name, tmp_path, monkeypatch, capsys):
    """eval --json notes.json (or --csv data.csv, --out notes) replaced a file of the user's that was
    no evaluation table, without a word; an earlier table under the name is replaced as before."""
    monkeypatch.chdir(tmp_path)
    for file in ("notes.json", "data.csv"):
        (tmp_path / file).write_text('{"mine": [1, 2, 3]}\n' if file.endswith(".json") else "x,y\n1,2\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    args = ["eval", "--fidelity", "point", "--episodes", "1", "--worlds", "1", "--set", "max_steps=3", "-q"]
    assert main([*args, flag, name]) == 2
    err = capsys.readouterr().err
    shown = name if flag != "--out" else "notes.json"
    assert f"{shown}: exists and is not an evaluation table" in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert main([*args, "--out", "table"]) == 0 and main([*args, "--out", "table", "--seed", "1"]) == 0  # a table: replaced
    assert json.loads((tmp_path / "table.json").read_text())["seed"] == 1


def _cli_with_little_memory(args: list[str], cwd, memory_bytes: int = 2 << 30):
    """`python -m pursuit_cli ARGS` run in `cwd` with its address space capped (RLIMIT_AS), so
    that reading a multi-GB file whole fails (MemoryError) instead of filling the machine."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    cap = f"import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_AS, ({memory_bytes}, {memory_bytes})); " \
          f"sys.argv = ['pursuit-mj', *sys.argv[1:]]; runpy.run_module('pursuit_cli', run_name='__main__')"
    env = {**os.environ, "PYTHONPATH": root, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", cap, *args], cwd=cwd, capture_output=True, text=True, timeout=120, env=env)


@pytest.mark.parametrize("kind", ["no table", "table"])
def test_eval_tells_a_multi_gb_output_file_without_reading_it_whole(kind, tmp_path):
    """eval --json big.json read the whole of an existing big.json to tell whether it was a table:
    a 6 GB file given by mistake was loaded into memory (MemoryError under a memory cap). Now
    its head says what it is: refused as no table, or replaced as an earlier (huge) table."""
    args = ["eval", "--fidelity", "point", "--episodes", "1", "--worlds", "1", "--set", "max_steps=3", "-q"]
    assert main([*args, "--json", str(tmp_path / "small.json")]) == 0
    big = tmp_path / "big.json"
    big.write_bytes(b"x" if kind == "no table" else (tmp_path / "small.json").read_bytes()[:-12])  # a table cut in its rows
    with open(big, "r+b") as f:
        f.truncate(6 << 30)  # sparse: no disk used
    proc = _cli_with_little_memory([*args, "--json", "big.json"], tmp_path)
    if kind == "no table":
        assert proc.returncode == 2, proc.stderr
        assert "--json path big.json: exists and is not an evaluation table" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and big.stat().st_size == 6 << 30, proc.stderr
    else:
        assert proc.returncode == 0, proc.stderr
        assert json.loads(big.read_text())["rows"]


@pytest.mark.parametrize("model, out", [
    ("soft.pt", "m.pt"),  # the file the input's link reaches: replacing it loses the checkpoint
    ("./m.pt", "sub/../m.pt"),  # the same name written two ways
])
def test_eval_refuses_an_output_named_as_the_file_an_input_reaches(model, out, tmp_path, monkeypatch, capsys):
    """The output's own name is what a table replaces (io_utils.atomic_path renames onto it): the
    checkpoint's file, however the two are spelt, is refused."""
    import os
    import shutil

    from pursuit_mj.shipped import shipped_dir

    monkeypatch.chdir(tmp_path)
    shutil.copy(shipped_dir("pretrained") / "belppo_point.pt", "m.pt")
    os.symlink("m.pt", "soft.pt")
    os.mkdir("sub")
    checkpoint = (tmp_path / "m.pt").read_bytes()
    code = main(["eval", "--fidelity", "point", "--episodes", "1", "--worlds", "1", "--set", "max_steps=5", "-q",
                 "--model", model, "--json", out])
    err = capsys.readouterr().err
    assert code == 2 and f"--json {out}: the same file as --model {model}" in err, err
    assert (tmp_path / "m.pt").read_bytes() == checkpoint


@pytest.mark.parametrize("given", ["mine.py", "mine.py:Team"])
def test_demo_of_a_python_policy_file_says_how_to_show_it_with_a_command_that_takes_it(given, tmp_path, monkeypatch, capsys):
    """`demo --model mine.py` advised '--policy mine.py:NAME', a flag demo does not have (and
    `demo --model mine.py:Team` said 'no such file'): eval shows a policy of one's own."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.py").write_text("class Team:\n    pass\n")
    assert main(["demo", "--model", given]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--model {given}: a Python file, not a checkpoint" in err, err
    assert "pursuit-mj eval --policy mine.py:" in err and "--policy heuristic" in err, err


def test_t_quantile_matches_the_published_table_to_its_documented_precision():
    # published 0.975 quantiles of Student's t (6 decimals); the module keeps 4 decimals up to
    # 9 degrees of freedom and promises an error below 1e-4 from its expansion beyond
    published = {1: 12.706205, 2: 4.302653, 3: 3.182446, 4: 2.776445, 5: 2.570582, 6: 2.446912,
                 7: 2.364624, 8: 2.306004, 9: 2.262157, 10: 2.228139, 11: 2.200985, 12: 2.178813,
                 13: 2.160369, 15: 2.131450, 20: 2.085963, 25: 2.059539, 40: 2.021075, 120: 1.979930}
    for dof, q in published.items():
        assert t_quantile_975(dof) == pytest.approx(q, abs=1e-4), dof


def test_percent_value_keeps_any_rate_short_of_0_or_100_percent_off_them():
    from pursuit_mj.evaluation import percent_value

    assert percent_value(1 / 300_000) == 0.0003  # 0.000333... %: 3 decimals would say 0.0
    assert percent_value(1 / 3_000_000) == 0.00003
    assert percent_value(1 / 30_000_000) == 0.000003
    assert percent_value(1 - 1 / 30_000_000) == 99.999997
    assert (percent_value(0.0), percent_value(1.0), percent_value(0.0625)) == (0.0, 100.0, 6.25)


def test_an_index_spelled_with_a_leading_zero_is_that_layout_and_plays_its_episodes():
    from pursuit_mj.evaluation import layout_identity, layout_seed

    assert layout_identity("01") == layout_identity(" 1 ") == layout_identity(1) == "1"
    assert layout_seed(7, "01") == layout_seed(7, 1)


def test_episode_seeds_are_pinned_so_that_published_tables_replay():
    """Episode k of a row has seed SeedSequence([row seed, k]); a change (say from k + 1) would
    change every table ever published, the shipped policies' included."""
    from pursuit_mj.evaluation import episode_seeds, layout_seed

    assert episode_seeds(0, 3).tolist() == [2968811710, 3964924996, 3141116543]
    assert layout_seed(0, 0) == layout_seed(0, "0") == 3223363731


def test_summarise_cuts_the_steps_intervals_to_0_and_max_steps():
    records = [EpisodeRecord(0, k, 0, "success", steps, None, {}, 1, "0") for k, steps in enumerate((10, 10, 1000))]
    row = summarise("p", "0", "point", 0, records, 1000)
    # mean 340, sd 571.58, t(2) 4.3027: 340 -+ 1419.9 unbounded
    assert row.steps.mean == pytest.approx(340.0)
    assert (row.steps.lo, row.steps.hi) == (0.0, 1000.0)
    assert (row.steps_success.lo, row.steps_success.hi) == (0.0, 1000.0)


def test_run_episodes_returns_episode_order_not_the_order_they_finished_in():
    """Pairing takes episode k of one row against episode k of another: the records must be in
    episode order whatever order the worlds finished them in."""
    from pursuit_mj.evaluation import episode_seeds
    from pursuit_mj.policy import RandomPolicy

    finished = []
    records = run_episodes(RandomPolicy(0), default_config(fidelity="point", max_steps=60), 6, 1, 3, on_episode=finished.append)
    assert [r.seed for r in records] == episode_seeds(1, 6).tolist()
    assert [r.seed for r in finished] != [r.seed for r in records]  # episode 1 ended first: the order was restored


def test_evaluate_plays_the_named_layout_even_when_the_task_draws_random_layouts():
    config = default_config(fidelity="point", max_steps=5, random_layout=True)
    heard = []
    rows = evaluate(HeuristicTeam.from_config(config), config, [2], episodes=4, seed=0, n_worlds=2, on_episode=heard.append)
    assert rows[0].layout == "2" and {r.layout for r in heard} == {load_layout(2).name}


def test_the_fidelity_column_appears_only_for_rows_of_several_fidelities():
    records = [EpisodeRecord(0, 0, 0, "success", 10, None, {}, 1, "0")]
    point = summarise("p", "0", "point", 0, records, 100)
    assert "fidelity" not in format_table([point]).splitlines()[0]
    quad = summarise("p", "0", "quadrotor", 0, records, 100)
    assert "fidelity" in format_table([point, quad]).splitlines()[0]


def test_a_kept_record_is_taken_back_only_as_the_episodes_this_eval_plays():
    import copy

    from pursuit_mj.evaluation import episode_seeds, layout_seed, row_from_record, row_record

    config = default_config(fidelity="point", max_steps=100)
    seeds = episode_seeds(layout_seed(4, "0"), 3).tolist()
    records = [EpisodeRecord(0, k, s, "success", 50, None, {}, 1, "0") for k, s in enumerate(seeds)]
    good = row_record(summarise("p", "0", "point", 4, records, config.max_steps))
    assert row_from_record(good, config, 4, 3) == summarise("p", "0", "point", 4, records, config.max_steps)

    def edited(edit):
        record = copy.deepcopy(good)
        edit(record)
        return row_from_record(record, config, 4, 3)

    assert edited(lambda r: r.__setitem__("fidelity", "quadrotor")) is None
    assert edited(lambda r: r["per_episode"]["steps"].__setitem__(0, config.max_steps)) is not None
    assert edited(lambda r: r["per_episode"]["steps"].__setitem__(0, config.max_steps + 1)) is None
    assert edited(lambda r: r["per_episode"]["captured"].__setitem__(0, config.n_evaders + 1)) is None
    assert edited(lambda r: r["per_episode"]["outcome"].pop()) is None  # not zipped down to 2 episodes


def test_csv_counts_read_back_as_integers():
    from pursuit_mj.evaluation import _cell

    assert type(_cell("episodes", "6", "here")) is int and type(_cell("success_count", "3", "here")) is int
    assert type(_cell("success_pct", "50", "here")) is float


def _row_of_successes(successes: int, episodes: int, layout: str = "0"):
    """A Row of `episodes` made-up episodes, the first `successes` of them caught at step 100."""
    from types import SimpleNamespace

    from pursuit_mj.evaluation import summarise

    records = [SimpleNamespace(seed=k, outcome="success" if k < successes else "timeout", steps=100 if k < successes else 600,
                               captured=1 if k < successes else 0) for k in range(episodes)]
    return summarise("heuristic", layout, "point", 0, records, 600)


@pytest.mark.parametrize("command, said", [("eval", "success 99.96 %"), ("demo", "success 99.96 %")])
def test_the_progress_line_of_a_row_says_its_success_as_the_table_does(command, said, capsys, monkeypatch):
    """eval's progress line printed 2499 of 2500 caught as 'success 100.0 %' (demo's as '100 %'),
    beside a table that says 99.96: a rate that is not 1 must not print as 100 (nor one that is
    not 0 as 0)."""
    import dataclasses

    import pursuit_mj.evaluation as evaluation
    from pursuit_cli import main

    monkeypatch.setattr(evaluation, "evaluate", lambda policy, config, layouts, *a, label=None, **k:
                        [dataclasses.replace(_row_of_successes(2499, 2500, str(layouts[0])), policy=label)])
    flags = ["--policy", "heuristic", "--layouts", "0"] if command == "eval" else ["--no-heuristic", "--layouts", "0"]
    assert main([command, *flags, "--episodes", "2500", "--fidelity", "point"]) == 0
    err = capsys.readouterr().err
    assert said in err, err
    assert "100.0 %" not in err and "success 100 %" not in err


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_eval_paired_table_names_the_fidelity_it_compares(fidelity, capsys):
    """eval's paired table (heuristic and another policy) has no fidelity column, and its heading
    said nothing of the fidelity either ('paired with heuristic on the same episodes (capture
    steps: ...'); pool's heading names a single fidelity, and eval's now says it the same way."""
    assert main(["eval", "--policy", "heuristic", "--policy", "random", "--layouts", "0", "--episodes", "1", "--worlds", "1",
                 "--fidelity", fidelity, "--set", "max_steps=3", "-q"]) == 0
    printed = capsys.readouterr().out
    assert f"\npaired with heuristic on the same episodes, in {fidelity} fidelity (capture steps: " in printed, printed


def _save_tiny_checkpoint(path, overrides: list[str]) -> None:
    """An untrained checkpoint of a train config with `overrides` (3 pursuers, 1 evader, 16 rays)."""
    import torch

    from pursuit_mj.configio import to_dict
    from pursuit_mj.obs_spec import ObsSpec
    from train.checkpoint import save_checkpoint
    from train.config import load_train_config
    from train.networks import Actor

    torch.manual_seed(0)
    cfg = load_train_config([], overrides)
    spec = ObsSpec.make(3, 1, 16)
    save_checkpoint(path, {"train_config": to_dict(cfg), "obs_spec": spec.to_dict(),
                           "actor": Actor(spec, cfg.net).state_dict(), "counters": {"update": 0}})


def test_eval_json_records_the_layouts_each_model_trained_on(tmp_path, capsys):
    """The checkpoint names the layouts a model trained on, and eval printed a note when the table
    played none of them, but its JSON kept nothing of them: a reader of the table could not tell a
    model judged on its own arena from one judged on arenas it never met. `trained_layouts` holds
    them per model label (as the rows name layouts); the older keys are as before, and `plot
    --eval` and `eval --resume` read the file as before."""
    _save_tiny_checkpoint(tmp_path / "a.pt", ["name=fo", "task.layout=2"])
    _save_tiny_checkpoint(tmp_path / "b.pt", ["name=rl", "task.random_layout=true"])
    a, b, out = str(tmp_path / "a.pt"), str(tmp_path / "b.pt"), tmp_path / "t"
    flags = ["eval", "--policy", "heuristic", "-m", a, "-m", b, "--shield", "--layouts", "0", "1", "--episodes", "1",
             "--worlds", "1", "--fidelity", "point", "--set", "max_steps=3", "-q", "--out", str(out)]
    assert main(flags) == 0
    assert "note: --model " + a + " was trained on layout 2, which this run does not play (layouts 0, 1)" in capsys.readouterr().err
    data = json.loads((tmp_path / "t.json").read_text())
    assert data["trained_layouts"] == {"fo+shield": ["2"], "rl+shield": ["0", "1", "2", "3"]}
    assert data["model_of"] == {"fo+shield": a, "rl+shield": b} and data["policies"] == ["heuristic", "fo+shield", "rl+shield"]
    assert main(["plot", "--eval", str(tmp_path / "t.json"), "-o", str(tmp_path / "plots")]) == 0
    assert (tmp_path / "plots" / "eval_success.png").is_file()
    # an interrupted table's JSON holds the key too, and --resume takes its rows back
    (tmp_path / "t.json").rename(tmp_path / "t.interrupted.json")
    (tmp_path / "t.csv").unlink()
    capsys.readouterr()
    assert main(flags[:-2] + ["--out", str(out), "--resume"]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["trained_layouts"] == data["trained_layouts"]


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
@pytest.mark.parametrize("command", [["eval", "--policy", "heuristic"], ["demo", "--no-heuristic", "--no-shield"]])
def test_the_main_table_names_the_fidelity_its_rows_were_played_in(command, fidelity, capsys):
    """eval's (and demo's) main table has no fidelity column when its rows are of one fidelity, as
    they always are, and nothing above it said which: success %, collision % and mean steps with no
    word of the physics that made them, while the paired table below names it in its heading
    (comparison.one_fidelity). The main table now has a heading that says it the same way."""
    assert main([*command, "--layouts", "0", "1", "--episodes", "1", "--worlds", "1", "--fidelity", fidelity,
                 "--set", "max_steps=3", *(["-q"] if command[0] == "eval" else [])]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = next(k for k, line in enumerate(lines) if line.startswith("policy "))
    assert lines[head - 1] == f"evaluated 1 policy on 2 layouts, every row in {fidelity} fidelity, task reference with --set max_steps=3", lines


def test_an_interrupted_eval_names_the_fidelity_of_the_cells_it_shows(tmp_path, capsys):
    """The finished cells an interrupted eval prints on stderr are the main table's rows: their
    heading names the fidelity as the whole table's does."""
    from pursuit_cli.eval_resume import keep_finished

    from pursuit_mj.policies import make_policy

    config = default_config(fidelity="point", max_steps=3)
    rows = evaluate(make_policy("heuristic", config), config, layouts=[0], episodes=1, n_worlds=1)
    keep_finished(rows, None, None, config, {})
    assert "[eval] interrupted; the 1 finished policy-layout cell, every row in point fidelity:\npolicy " in capsys.readouterr().err


@pytest.mark.parametrize("task, named", [
    ([], "task reference with --set max_steps=3"),
    (["--task", "hard"], "task hard with --set max_steps=3"),
    (["--task", "easy", "--task", "FILE", "--pursuers", "2"], "task easy + FILE with --pursuers 2, --set max_steps=3"),
])
@pytest.mark.parametrize("command", [["eval", "--policy", "heuristic", "-q"], ["demo", "--no-heuristic", "--no-shield"]])
def test_the_main_table_names_the_task_its_rows_were_played_in(command, task, named, tmp_path, capsys):
    """The heading above eval's (and demo's) main table named the fidelity but not the task: a table
    of --task hard read as one of the reference task. It now names the task files and presets as
    given (the defaults are the reference preset's values) and the task flags and --set overrides
    given, leaving out --fidelity and --layout, which the heading and the table already name."""
    assert load_task_config([]) == load_task_config(["reference"])  # no --task is the reference task
    file = tmp_path / "mine.yaml"
    file.write_text("evader_speed: 0.5\n")
    task = [str(file) if t == "FILE" else t for t in task]
    assert main([*command, *task, "--layouts", "0", "--episodes", "1", "--worlds", "1", "--fidelity", "point",
                 "--set", "max_steps=3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = next(k for k, line in enumerate(lines) if line.startswith("policy "))
    assert lines[head - 1] == f"evaluated 1 policy on 1 layout, every row in point fidelity, {named.replace('FILE', str(file))}"


def test_an_interrupted_eval_names_the_task_of_the_cells_it_shows(monkeypatch, capsys):
    """The finished cells an interrupted eval prints named the fidelity but not the task, which the
    whole table's heading names (common.task_named): the cells of --task hard read as the reference
    task's. They are now named alike."""
    import os
    import signal

    import pursuit_mj.evaluation as evaluation

    real, cells = evaluation.evaluate, []

    def evaluate_then_stopped(*a, **k):
        cells.append(k["label"])
        if len(cells) == 2:
            os.kill(os.getpid(), signal.SIGTERM)  # arrives inside the second cell, before its row exists
        return real(*a, **k)

    monkeypatch.setattr(evaluation, "evaluate", evaluate_then_stopped)
    assert main(["eval", "--policy", "heuristic", "--policy", "random", "--task", "hard", "--layouts", "0", "--episodes", "1",
                 "--worlds", "1", "--fidelity", "point", "--set", "max_steps=5", "-q"]) == 143
    err = capsys.readouterr().err
    assert ("[eval] interrupted; the 1 finished policy-layout cell, every row in point fidelity, task hard with "
            "--set max_steps=5:\npolicy ") in err, err
