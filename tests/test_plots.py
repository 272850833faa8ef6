"""Training curves and evaluation bar charts: what is read, what is drawn, what is refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from pursuit_cli import main
from pursuit_mj.env import EpisodeRecord
from pursuit_mj.plots import curve_keys, plot_eval, plot_training, read_eval_rows, read_training_log, x_key


def _log(path, n=12, scale=1.0, cut_last=False):
    lines = []
    for u in range(1, n + 1):
        lines.append(json.dumps({
            "update": u, "world_steps": 512 * u,
            "train": {"success": scale * u / n, "collision": 0.1, "mean_steps": 400 - 10 * u, "episodes": 4},
            "episode_returns": {"capture": u * 0.5, "progress": 1.0},
            "validation": {"success": u / (n + 2)} if u % 4 == 0 else {},
            "loss": {"policy": -0.01, "value": float("nan") if u == 3 else 0.5},
        }).replace("NaN", "null"))
    text = "\n".join(lines) + "\n"
    if cut_last:
        text += '{"update": 13, "world_st'
    path.write_text(text)
    return path


def _eval_json(path, policies=("heuristic", "classic"), layouts=("0", "1", "2", "3")):
    rows = []
    for i, p in enumerate(policies):
        for j, l in enumerate(layouts):
            s = 40 + 10 * i + 5 * j
            rows.append({"policy": p, "layout": l, "episodes": 150, "success_pct": s, "success_ci_lo": s - 8, "success_ci_hi": s + 8,
                         "collision_pct": 5, "collision_ci_lo": 2, "collision_ci_hi": 10, "timeout_pct": 100 - s - 5,
                         "timeout_ci_lo": 90 - s, "timeout_ci_hi": 100 - s, "mean_steps": 300.0, "mean_steps_ci_lo": 280.0,
                         "mean_steps_ci_hi": 320.0})
    path.write_text(json.dumps({"episodes": 150, "rows": rows}))
    return path


def _ink(path):
    """Fraction of pixels that are not background white."""
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    return (np.abs(img - 255).sum(-1) > 30).mean()


def test_training_log_is_flattened_and_a_cut_last_line_is_skipped(tmp_path):
    rows = read_training_log(_log(tmp_path / "m.jsonl", cut_last=True))
    assert len(rows) == 12
    assert rows[0]["train.success"] == pytest.approx(1 / 12) and rows[3]["validation.success"] == pytest.approx(4 / 14)
    assert "loss.value" not in rows[2] and rows[2]["loss.policy"] == -0.01


def test_a_run_started_again_in_its_folder_is_plotted_from_its_latest_rows(tmp_path):
    """Killed before its first checkpoint and started again: the log holds updates 1-5, then 1-3
    anew. The curve shows the new 1-3 and no x twice (it would run back over itself)."""
    old, new = _log(tmp_path / "old.jsonl", n=5), _log(tmp_path / "new.jsonl", n=3, scale=0.5)
    log = tmp_path / "m.jsonl"
    log.write_text(old.read_text() + new.read_text())
    rows = read_training_log(log)
    assert [r["update"] for r in rows] == [1, 2, 3]
    assert [r["train.success"] for r in rows] == pytest.approx([0.5 / 3, 1 / 3, 0.5])
    # a resume whose log kept updates 6-7 past its checkpoint at 5: 6 and 7 logged again replace them
    log.write_text(_log(tmp_path / "a.jsonl", n=7).read_text() + "\n".join(_log(tmp_path / "b.jsonl", n=8).read_text().splitlines()[5:]))
    assert [r["update"] for r in read_training_log(log)] == list(range(1, 9))


def test_malformed_line_is_named(tmp_path):
    p = tmp_path / "bad.jsonl"
    p.write_text('{"update": 1}\nnot json\n{"update": 2}\n')
    with pytest.raises(ValueError, match=r"bad.jsonl, line 2: not JSON"):
        read_training_log(p)
    with pytest.raises(ValueError, match="file not found"):
        read_training_log(tmp_path / "none.jsonl")


def test_an_evaluation_table_given_as_a_training_log_points_to_eval(tmp_path, capsys):
    """It said 'line 1: not JSON (Expecting property name ...)' of eval's indented JSON."""
    table = tmp_path / "s0.json"
    table.write_text(json.dumps(json.loads(_eval_json(tmp_path / "t.json").read_text()), indent=2))
    assert main(["plot", "--log", str(table), "--out", str(tmp_path / "plots")]) == 2
    assert f"training log {table}: an evaluation table (pursuit-mj eval --json), not a training log: plot it with " \
           f"--eval {table}" in capsys.readouterr().err


def test_default_curves_and_x_axis(tmp_path):
    runs = {"a": read_training_log(_log(tmp_path / "a.jsonl"))}
    assert x_key(runs) == "world_steps"
    keys = curve_keys(runs)
    assert keys[:4] == ["train.success", "validation.success", "train.collision", "train.mean_steps"]
    assert "episode_returns.capture" in keys and "loss.policy" not in keys
    assert curve_keys(runs, ["policy"]) == ["loss.policy"]
    with pytest.raises(ValueError, match="--metric 'nope': no such key"):
        curve_keys(runs, ["nope"])
    with pytest.raises(ValueError, match="--x 'env_steps': not in every log"):
        x_key(runs, "env_steps")


def test_several_runs_on_one_chart(tmp_path):
    runs = {"a": read_training_log(_log(tmp_path / "a.jsonl")), "b": read_training_log(_log(tmp_path / "b.jsonl", scale=0.5))}
    one = plot_training({"a": runs["a"]}, tmp_path / "one", ["train.success"])
    two = plot_training(runs, tmp_path / "two", ["train.success"])
    assert one[0].name == two[0].name == "curve_train_success.png"
    assert _ink(two[0]) > _ink(one[0]), "the second run's line is missing"


def test_eval_bars_per_metric(tmp_path):
    rows = read_eval_rows(_eval_json(tmp_path / "t.json"))
    paths = plot_eval(rows, tmp_path / "plots")
    assert [p.name for p in paths] == ["eval_success.png", "eval_collision.png", "eval_timeout.png", "eval_mean_steps.png"]
    fewer = plot_eval([r for r in rows if r["policy"] == "heuristic"], tmp_path / "fewer")
    assert _ink(paths[0]) > _ink(fewer[0])


def test_eval_json_errors_are_named(tmp_path):
    p = tmp_path / "e.json"
    p.write_text(json.dumps({"rows": [{"layout": "0"}]}))
    with pytest.raises(ValueError, match="row 0 lacks 'policy' or 'layout'"):
        read_eval_rows(p)
    p.write_text("{")
    with pytest.raises(ValueError, match="e.json: not JSON"):
        read_eval_rows(p)
    for value, shown in (("abc", "'abc'"), (True, "True"), ([1], r"\[1\]")):
        p.write_text(json.dumps({"rows": [{"policy": "a", "layout": "0", "success_pct": 50}, {"policy": "b", "layout": "0", "mean_steps": value}]}))
        with pytest.raises(ValueError, match=rf"e.json: row 1 \(b on layout 0\): mean_steps is {shown}, expected a number or null"):
            read_eval_rows(p)
    # matplotlib's "'yerr' must not contain negative values" named no file, row or key
    p.write_text(json.dumps([{"policy": "x", "layout": 0, "success_pct": 50, "success_ci_lo": 60, "success_ci_hi": 40}]))
    with pytest.raises(ValueError, match=r"e.json: row 0 \(x on layout 0\): success_pct 50 is outside its interval "
                                         r"\[success_ci_lo 60, success_ci_hi 40\]"):
        read_eval_rows(p)
    p.write_text(json.dumps([{"policy": "x", "layout": 0, "collision_pct": 130}]))
    with pytest.raises(ValueError, match=r"row 0 \(x on layout 0\): collision_pct is 130, expected a percentage in 0-100"):
        read_eval_rows(p)
    p.write_text(json.dumps([{"policy": "a", "layout": "0", "episodes": "many", "success_pct": 50}]))
    with pytest.raises(ValueError, match="row 0 .*episodes is 'many'"):
        read_eval_rows(p)
    p.write_text(json.dumps([{"policy": "a", "layout": "0", "score": 3}]))  # some other table
    with pytest.raises(ValueError, match="e.json: no row has any of success_pct"):
        read_eval_rows(p)


def test_a_binary_file_given_as_a_log_or_results_is_named(tmp_path):
    p = tmp_path / "picture.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xcc")
    with pytest.raises(ValueError, match=r"training log .*picture.png: not a text file"):
        read_training_log(p)
    with pytest.raises(ValueError, match=r"evaluation results .*picture.png: not a text file"):
        read_eval_rows(p)


def test_plot_command(tmp_path, capsys):
    a, b = _log(tmp_path / "a.jsonl"), _log(tmp_path / "b.jsonl", scale=0.7)
    ev = _eval_json(tmp_path / "t.json")
    out = tmp_path / "out"
    assert main(["plot", "--log", f"first={a}", "--log", str(b), "--eval", str(ev), "-o", str(out)]) == 0
    written = {p.name for p in out.iterdir()}
    assert {"curve_train_success.png", "curve_train_collision.png", "curve_train_mean_steps.png", "eval_success.png"} <= written
    assert main(["plot", "-o", str(out)]) == 2
    assert "nothing to plot" in capsys.readouterr().err


def test_a_layout_s_bars_are_centred_on_it_and_a_pair_given_twice_is_refused(tmp_path):
    import matplotlib.pyplot as plt

    rows = read_eval_rows(_eval_json(tmp_path / "t.json", policies=("a", "b", "c", "d"), layouts=("0",)))
    rows += read_eval_rows(_eval_json(tmp_path / "u.json", policies=("a", "b"), layouts=("1",)))
    drawn = []
    real_bar = plt.Axes.bar

    def spy(self, x, height, width, **kw):
        drawn.append((round(float(x), 6), kw.get("label")))
        return real_bar(self, x, height, width, **kw)

    plt.Axes.bar = spy
    try:
        plot_eval(rows, tmp_path / "plots")
    finally:
        plt.Axes.bar = real_bar
    first_chart = drawn[:6]
    at = {x for x, _ in first_chart}
    assert sum(x > 0.5 for x in at) == 2 and np.mean([x for x in at if x > 0.5]) == pytest.approx(1.0)  # centred
    assert np.mean([x for x in at if x < 0.5]) == pytest.approx(0.0)
    assert [lab for _, lab in first_chart].count("a") == 1  # one legend entry per policy
    with pytest.raises(ValueError, match="policy a on layout 0 is given twice"):
        plot_eval(rows + rows[:1], tmp_path / "again")


def test_plot_command_takes_a_run_folder_and_names_a_folder_it_cannot_use(tmp_path, capsys):
    run = tmp_path / "runs" / "classic"
    run.mkdir(parents=True)
    _log(run / "metrics.jsonl")
    assert main(["plot", "--log", str(run), "--metric", "train.success", "-o", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "curve_train_success.png").is_file()
    from pursuit_cli.plot_cmd import _label_and_path

    assert _label_and_path(str(run) + "/") == ("classic", run)
    for flag, message in (("--log", "a folder without metrics.jsonl"), ("--eval", "a folder, expected the JSON or CSV file")):
        assert main(["plot", flag, str(tmp_path / "runs"), "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert f"{tmp_path / 'runs'}: {message}" in err and len(err.strip().splitlines()) == 1


def test_plot_command_draws_the_csv_of_an_eval_as_its_json(tmp_path, capsys):
    from pursuit_mj.env import EpisodeRecord
    from pursuit_mj.evaluation import summarise, write_csv, write_json

    def row(policy, layout, outcomes):
        return summarise(policy, layout, "point", 0, [EpisodeRecord(0, 0, 0, o, s, None, {}, 0, layout) for o, s in outcomes], 40)

    rows = [row("heuristic", "0", [("success", 12), ("timeout", 40)]), row("random", "0", [("collision", 3)])]  # no success
    write_csv(rows, tmp_path / "t.csv")
    write_json(rows, tmp_path / "t.json")
    assert read_eval_rows(tmp_path / "t.csv") == [{k: v for k, v in r.items() if k != "per_episode"} for r in read_eval_rows(tmp_path / "t.json")]
    assert main(["plot", "--eval", str(tmp_path / "t.csv"), "-o", str(tmp_path / "out")]) == 0
    assert {p.name for p in (tmp_path / "out").iterdir()} >= {"eval_success.png", "eval_steps_success.png"}
    (tmp_path / "cut.csv").write_text((tmp_path / "t.csv").read_text()[:-30])
    assert main(["plot", "--eval", str(tmp_path / "cut.csv"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "cut.csv, line 3:" in err and "cut short" in err and len(err.strip().splitlines()) == 1


def test_a_mean_of_one_episode_has_no_whisker(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from pursuit_mj.env import EpisodeRecord
    from pursuit_mj.evaluation import plot_rows, summarise

    one = summarise("a", "0", "point", 0, [EpisodeRecord(0, 0, 0, "success", 12, None, {}, 0, "0")], 40)
    same = summarise("b", "0", "point", 0, [EpisodeRecord(0, k, 0, "success", 12, None, {}, 0, "0") for k in range(3)], 40)
    assert one.steps.lo is None and same.steps.lo == same.steps.hi == 12  # no interval / an interval of width 0
    whiskers = []
    real_bar = plt.Axes.bar
    monkeypatch.setattr(plt.Axes, "bar", lambda self, *a, **kw: whiskers.append(kw.get("yerr")) or real_bar(self, *a, **kw))
    plot_rows([one, same], tmp_path)
    success, _, _, steps, steps_success = [whiskers[i:i + 2] for i in range(0, 10, 2)]
    assert success[0] is not None and steps[0] is None and steps_success[0] is None
    assert steps[1] == [[0.0], [0.0]]


def test_one_bar_group_per_layout_however_the_tables_named_it(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from pursuit_mj.layout import builtin_layout_path

    zero = builtin_layout_path(0)
    a = read_eval_rows(_eval_json(tmp_path / "a.json", policies=("heuristic",), layouts=("0", "my/maze.yaml")))
    b = read_eval_rows(_eval_json(tmp_path / "b.json", policies=("classic",), layouts=(str(zero), "my/./maze.yaml")))
    ticks = []
    real = plt.Axes.set_xticks
    monkeypatch.setattr(plt.Axes, "set_xticks", lambda self, at, labels, **kw: ticks.append(list(labels)) or real(self, at, labels, **kw))
    plot_eval(a + b, tmp_path / "plots")
    assert ticks[0] == ["layout 0", "maze"]
    with pytest.raises(ValueError, match="policy heuristic on layout 0 is given twice"):
        plot_eval(a + [dict(a[0], layout=str(zero))], tmp_path / "again")
    from pursuit_mj.plots import layout_key

    assert layout_key("00") == layout_key(0) == layout_key(f"{zero.parent}/../layouts/{zero.name}") == "0"
    (tmp_path / "0_open.yaml").write_text(zero.read_text())  # a copy elsewhere is another file
    assert layout_key(tmp_path / "0_open.yaml") == str(tmp_path / "0_open.yaml")


def test_a_table_without_success_replaces_the_steps_of_successes_chart_of_an_earlier_one(tmp_path):
    from pursuit_mj.env import EpisodeRecord
    from pursuit_mj.evaluation import plot_rows, summarise

    def row(policy, outcome):
        return summarise(policy, "0", "point", 0, [EpisodeRecord(0, k, 0, outcome, 20 + k, None, {}, 0, "0") for k in range(4)], 40)

    first = plot_rows([row("a", "success"), row("b", "success")], tmp_path)
    before = (tmp_path / "steps_success.png").read_bytes()
    again = plot_rows([row("a", "timeout"), row("b", "success")], tmp_path)  # a: no success, no steps to show
    assert [p.name for p in again] == [p.name for p in first]
    assert (tmp_path / "steps_success.png").read_bytes() != before
    none = plot_rows([row("a", "timeout"), row("b", "collision")], tmp_path)  # no success at all
    assert [p.name for p in none] == [p.name for p in first]
    assert _ink(tmp_path / "steps_success.png") < _ink(first[-1].with_name("mean_steps.png"))


def test_a_chart_of_one_layout_holds_its_whole_title(tmp_path, monkeypatch):
    import pursuit_mj.plots as plots

    rows = read_eval_rows(_eval_json(tmp_path / "t.json", layouts=("0",)))
    rows = [dict(r, fidelity=f, episodes=n, mean_steps_success=250.0) for r, f, n in zip(rows, ("point", "quadrotor"), (10, 150))]
    spans = []
    real_save = plots._save

    def save(fig, path):
        box = fig.axes[0].title.get_window_extent(fig.canvas.get_renderer())
        spans.append((path.name, box.x0 >= 0 and box.x1 <= fig.bbox.width))
        return real_save(fig, path)

    monkeypatch.setattr(plots, "_save", save)
    plot_eval(rows, tmp_path / "plots")
    assert spans and all(inside for _, inside in spans), spans


def test_a_refused_plot_command_writes_no_chart(tmp_path, capsys):
    log, ev = _log(tmp_path / "a.jsonl"), _eval_json(tmp_path / "t.json")
    data = json.loads(ev.read_text())
    (tmp_path / "dup.json").write_text(json.dumps(dict(data, rows=data["rows"] + data["rows"][:1])))
    out = tmp_path / "out"
    for extra, message in ((["--eval", str(tmp_path / "dup.json")], "dup.json: rows 0 and 8 both hold policy heuristic on layout 0"),
                           (["--eval", str(ev), "--eval", str(ev)], "the same file as --eval"),
                           (["--eval", str(ev), "--metric", "nope"], "--metric 'nope': no such key")):
        assert main(["plot", "--log", str(log)] + extra + ["-o", str(out)]) == 2
        assert message in capsys.readouterr().err
        assert not out.exists() or not list(out.iterdir()), extra


def test_plot_command_tells_apart_a_policy_that_two_files_hold(tmp_path, capsys):
    one, two = _eval_json(tmp_path / "one.json"), _eval_json(tmp_path / "two.json", policies=("heuristic", "mappo"))
    assert main(["plot", "--eval", str(one), "--eval", str(two), "-o", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "eval_success.png").is_file()
    from pursuit_cli.plot_cmd import _combined_rows

    names = {r["policy"] for r in _combined_rows([(str(one), read_eval_rows(one)), (str(two), read_eval_rows(two))])}
    assert names == {"heuristic (one)", "heuristic (two)", "classic", "mappo"}


def test_plot_command_tells_apart_a_policy_that_two_files_of_one_name_hold(tmp_path, capsys):
    """a/eval.json and b/eval.json (two runs' tables) both labelled their heuristic 'heuristic (eval)'
    and the command refused them as one bar given twice; so did a table's CSV beside its JSON."""
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    one, two = _eval_json(tmp_path / "a" / "eval.json"), _eval_json(tmp_path / "b" / "eval.json", policies=("heuristic", "mappo"))
    assert main(["plot", "--eval", str(one), "--eval", str(two), "-o", str(tmp_path / "out")]) == 0, capsys.readouterr().err
    from pursuit_cli.plot_cmd import _combined_rows

    names = {r["policy"] for r in _combined_rows([(str(one), read_eval_rows(one)), (str(two), read_eval_rows(two))])}
    assert names == {f"heuristic ({one})", f"heuristic ({two})", "classic", "mappo"}
    again = tmp_path / "a" / ".." / "a" / "eval.json"  # one file twice, by two names
    assert main(["plot", "--eval", str(one), "--eval", str(again), "-o", str(tmp_path / "out")]) == 2
    # named as the one file it is, not as a policy to rename (the message said 'rename one (e.g. eval --model ...)')
    assert f"--eval {again}: the same file as --eval {one}, given twice" in capsys.readouterr().err


def test_plot_command_refuses_one_training_log_given_twice(tmp_path, capsys):
    """--log runs/c1 --log runs/c1/metrics.jsonl drew the run twice, as 'c1' and 'c1 (runs/c1/metrics.jsonl)'."""
    run = tmp_path / "c1"
    run.mkdir()
    _log(run / "metrics.jsonl")
    out = tmp_path / "out"
    assert main(["plot", "--log", str(run), "--log", f"again={run / 'metrics.jsonl'}", "-o", str(out)]) == 2
    assert f"--log again={run / 'metrics.jsonl'}: the same file as --log {run}, given twice" in capsys.readouterr().err
    assert not out.exists()


def test_a_reward_term_named_like_an_outcome_is_not_drawn_as_a_rate():
    from pursuit_mj.plots import _curve_label, is_rate

    assert is_rate("train.collision") and is_rate("validation.success")
    assert not is_rate("episode_returns.collision") and not is_rate("reward_terms_per_step.collision")
    assert _curve_label("episode_returns.collision") == "collision term (return per episode)"
    assert _curve_label("train.collision") == "train: collision rate (fraction)"


def test_a_chart_that_does_not_fit_on_the_disk_is_an_error_naming_it(tmp_path, capsys, monkeypatch):
    import errno

    from matplotlib.figure import Figure

    def full_disk(self, fname, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", full_disk)
    out = tmp_path / "plots"
    assert main(["plot", "--log", str(_log(tmp_path / "m.jsonl")), "-o", str(out)]) == 2
    assert f"{out / 'curve_train_success.png'}: cannot write it (No space left on device)" in capsys.readouterr().err
    assert not out.exists()  # no half-written chart, nor the folder made for them, left empty


def test_two_layout_files_of_one_name_are_told_apart_on_the_axis(tmp_path, monkeypatch):
    """v1/arena.yaml and v2/arena.yaml were both labelled 'arena': two bar groups under one name."""
    import matplotlib.pyplot as plt

    rows = read_eval_rows(_eval_json(tmp_path / "a.json", policies=("heuristic",), layouts=("0", "v1/arena.yaml", "v2/arena.yaml")))
    ticks = []
    real = plt.Axes.set_xticks
    monkeypatch.setattr(plt.Axes, "set_xticks", lambda self, at, labels, **kw: ticks.append(list(labels)) or real(self, at, labels, **kw))
    plot_eval(rows, tmp_path / "plots")
    assert ticks[0] == ["layout 0", "v1/arena.yaml", "v2/arena.yaml"]


def test_plot_command_refuses_tables_of_different_tasks_on_one_chart(tmp_path, capsys):
    """The heuristic team's rates of the reference task and of the hard one stood side by side
    as 'heuristic (one)' and 'heuristic (two)', nothing naming the tasks."""
    one, two = _eval_json(tmp_path / "one.json"), _eval_json(tmp_path / "two.json", policies=("heuristic", "mappo"))
    for path, speed in ((one, 0.6), (two, 0.9)):
        data = json.loads(path.read_text())
        data["config"] = {"evader_speed": speed, "n_pursuers": 3, "layout": 0}
        path.write_text(json.dumps(data))
    assert main(["plot", "--eval", str(one), "--eval", str(two), "-o", str(tmp_path / "out")]) == 2
    assert (f"--eval {two}: its task differs from {one}'s at evader_speed (0.9 there, 0.6 in {one}); one chart "
            "compares policies on one task") in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_training_log_given_as_an_evaluation_table_points_to_log(tmp_path, capsys):
    """It said 'not JSON (Extra data, line 2)'."""
    log = _log(tmp_path / "metrics.jsonl")
    assert main(["plot", "--eval", str(log), "-o", str(tmp_path / "out")]) == 2
    assert f"evaluation results {log}: a training log (one JSON object a line), not an evaluation table: plot it " \
           f"with --log {log}" in capsys.readouterr().err


def test_bar_labels_say_what_the_table_says():
    """Labels rounded half to even: 62.5 % read '62' and 87.5 % '88' while the table said 62.5 and 87.5."""
    from pursuit_mj.plots import bar_label

    assert [bar_label(v, percent=True) for v in (62.5, 87.5, 100.0, 0.0, 97.44)] == ["62.5", "87.5", "100", "0", "97.4"]
    assert [bar_label(v, percent=False) for v in (180.5, 181.5, 42.0)] == ["181", "182", "42"]


@pytest.mark.parametrize("count, n", [(1, 16), (5, 16), (3, 48), (9, 16), (1, 2500), (2499, 2500), (0, 7), (7, 7), (1, 3)])
def test_a_rate_s_bar_label_is_the_table_s_text(count, n):
    """The label read '6.3' for one success in 16 episodes (6.25 %) where the table printed 6.2, '0' for
    one collision in 2500 episodes where it printed 0.04, and '100' for 2499 successes in 2500 where it
    printed 99.96. The chart reads the rounded value of the CSV/JSON row (Row.flat), as `plot --eval` does."""
    from pursuit_mj.evaluation import format_table, summarise
    from pursuit_mj.plots import bar_label

    records = [EpisodeRecord(0, k, 0, "success" if k < count else "timeout", 100, None, {}, 0, "0") for k in range(n)]
    row = summarise("p", "0", "point", 0, records, 100)
    table = format_table([row]).splitlines()[1].split()[3]  # the success % column
    label = bar_label(row.flat()["success_pct"], percent=True)
    assert float(label) == float(table), (label, table)
    assert label == table.removesuffix(".0")


def test_a_plot_stopped_before_its_first_chart_leaves_no_out_folder_it_made(tmp_path, monkeypatch):
    """--out is made once the inputs are read; a plot stopped (Ctrl-C) or failed before it wrote a
    chart left 'new/plots/' behind, empty."""
    import pursuit_mj.plots

    ev = _eval_json(tmp_path / "t.json")

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pursuit_mj.plots, "plot_eval", stop)
    assert main(["plot", "--eval", str(ev), "-o", str(tmp_path / "new" / "plots")]) == 130
    assert not (tmp_path / "new").exists()


def test_a_chart_of_one_episode_per_bar_says_episode(tmp_path, monkeypatch):
    """`eval --episodes 1 --plots` titled every chart '1 episodes per bar'."""
    import pursuit_mj.plots as plots

    rows = read_eval_rows(_eval_json(tmp_path / "t.json", layouts=("0",)))
    titles = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: titles.append(fig.axes[0].get_title()) or real_save(fig, path))
    plot_eval([dict(r, episodes=1) for r in rows], tmp_path / "one")
    assert titles and all("\n1 episode per bar" in t for t in titles), titles
    titles.clear()
    plot_eval([dict(r, episodes=n) for r, n in zip(rows, (1, 3))], tmp_path / "mixed")
    assert titles and all("\n1-3 episodes per bar" in t for t in titles), titles


def test_a_metric_that_a_run_has_no_numbers_of_is_named(tmp_path, capsys):
    """`plot --log a --log b --metric validation.success`, b without validations, drew a's line
    alone and said nothing of b; and `--metric train.success_steps`, a key of every row but null
    in each (no success yet), was refused as 'no such key in the logs'."""
    a = _log(tmp_path / "a.jsonl")
    rows = [json.loads(line) for line in a.read_text().splitlines()]
    b = tmp_path / "b.jsonl"
    b.write_text("".join(json.dumps({**r, "validation": {}, "train": {**r["train"], "success_steps": None}}) + "\n" for r in rows))
    out = tmp_path / "out"
    assert main(["plot", "--log", str(a), "--log", str(b), "--metric", "validation.success", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: --metric validation.success: no numbers under it in run b, so curve_validation_success.png has no line for it" in err
    assert "in run a" not in err
    assert main(["plot", "--log", str(b), "--metric", "train.success_steps", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--metric 'train.success_steps': null in every row of the logs (nothing to draw)" in err


def test_the_json_and_csv_of_one_eval_are_one_table_given_twice(tmp_path, capsys):
    """`plot --eval results/t.json --eval results/t.csv` (or `--eval results/t.*`, the pair `eval --out
    results/t` writes) drew every policy twice, bars 'heuristic (t.json)' and 'heuristic (t.csv)'."""
    from pursuit_mj.env import EpisodeRecord
    from pursuit_mj.evaluation import summarise, write_csv, write_json

    rows = [summarise("heuristic", "0", "point", 0, [EpisodeRecord(0, 0, 0, "success", 12, None, {}, 0, "0")], 40)]
    write_csv(rows, tmp_path / "t.csv")
    write_json(rows, tmp_path / "t.json")
    out = tmp_path / "out"
    assert main(["plot", "--eval", str(tmp_path / "t.json"), "--eval", str(tmp_path / "t.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--eval {tmp_path / 't.csv'}: the same table as --eval {tmp_path / 't.json'} (the CSV and JSON of one eval), given twice" in err
    assert not out.exists()
    other = [summarise("heuristic", "0", "point", 0, [EpisodeRecord(0, 0, 0, "timeout", 40, None, {}, 0, "0")], 40)]
    write_csv(other, tmp_path / "t.csv")  # another eval written to the same prefix since: two tables
    assert main(["plot", "--eval", str(tmp_path / "t.json"), "--eval", str(tmp_path / "t.csv"), "-o", str(out)]) == 0


def test_a_legend_of_long_labels_fits_in_the_chart_with_its_axes(tmp_path, monkeypatch, recwarn):
    """Two tables of one stem are labelled by their paths: with long ones (absolute paths), the
    legend ran off the right edge (no label readable), the y label off the left, and matplotlib
    warned 'Tight layout not applied' on stderr."""
    import pursuit_mj.plots as plots

    long = "some/very/long/folder/name/for/the/results/of/the/first/experiment/eval.json"
    rows = [dict(r, policy=f"heuristic ({name})") for r, name in
            zip(read_eval_rows(_eval_json(tmp_path / "t.json", policies=("a", "b"), layouts=("0",))), (long, "b/eval.json"))]
    boxes = []
    real_save = plots._save

    def save(fig, path):
        renderer = fig.canvas.get_renderer()
        ax = fig.axes[0]
        boxes.append((path.name, fig.bbox.width, ax.get_legend().get_window_extent(renderer),
                      ax.yaxis.label.get_window_extent(renderer), ax.get_window_extent(renderer)))
        return real_save(fig, path)

    monkeypatch.setattr(plots, "_save", save)
    plot_eval(rows, tmp_path / "plots")
    assert boxes
    for name, width, legend, ylabel, axes in boxes:
        assert 0 <= legend.x0 and legend.x1 <= width, (name, legend, width)
        assert ylabel.x0 >= 0, (name, ylabel)
        assert axes.width > 100, (name, axes)  # the bars keep room
    assert not [w for w in recwarn if "Tight layout not applied" in str(w.message)]


def test_layouts_on_the_axis_are_in_layout_order_whatever_the_order_of_the_rows(tmp_path, monkeypatch):
    """'plot --eval late.json --eval early.json' (layouts 2, 3 then 0, 1), or a table of '--layouts 3 0',
    put the layouts on x in the order the rows first named them: layout 2 left of layout 0. They
    are in layout order, built-in layouts 0-3 first, then layout files by name; every bar stays
    over its layout in its policy's legend colour."""
    import matplotlib.pyplot as plt

    from pursuit_mj import plots

    late = read_eval_rows(_eval_json(tmp_path / "late.json", policies=("p",), layouts=("2", "zz/b_maze.yaml", "0")))
    early = read_eval_rows(_eval_json(tmp_path / "early.json", policies=("q",), layouts=("yy/a_arena.yaml", "1", "0")))
    early = [dict(r, **{k: r[k] + 1 for k in ("success_pct", "success_ci_lo", "success_ci_hi")}) for r in early]  # apart from late's
    order = ["layout 0", "layout 1", "layout 2", "a_arena", "b_maze"]
    ticks, bars, legends = [], [], []
    real_ticks, real_bar, real_save = plt.Axes.set_xticks, plt.Axes.bar, plots._save
    monkeypatch.setattr(plt.Axes, "set_xticks", lambda self, at, labels, **kw: ticks.append(list(labels)) or real_ticks(self, at, labels, **kw))
    monkeypatch.setattr(plt.Axes, "bar", lambda self, x, h, *a, **kw: bars.append((x, h, kw["color"])) or real_bar(self, x, h, *a, **kw))

    def save(fig, path):
        legend = fig.axes[0].get_legend()
        legends.append({t.get_text(): h.get_facecolor() for t, h in zip(legend.get_texts(), legend.legend_handles)})
        return real_save(fig, path)

    monkeypatch.setattr(plots, "_save", save)
    plot_eval(late + early, tmp_path / "plots")
    assert ticks[0] == order
    drawn = bars[:len(late) + len(early)]  # the success chart's bars
    for r in late + early:  # success_pct tells each row apart
        [(x, _, colour)] = [b for b in drawn if b[1] == float(r["success_pct"]) and round(b[0]) == order.index(plots._layout_names(
            [plots.layout_key(r["layout"])])[0])]
        assert tuple(colour) == tuple(legends[0][r["policy"]]), r


def test_training_curves_name_the_fidelity_their_runs_trained_in(tmp_path, monkeypatch):
    """`plot --log` titled each curve by its key alone ('validation.success'): a success rate with
    no word of the physics it was measured in, though every run folder's config.yaml names it (and
    eval's charts name theirs). Runs of one fidelity now say it under the title, as eval's charts
    do; runs of several have it beside their names in the legend; a log with no run config beside
    it is drawn as before."""
    import pursuit_mj.plots as plots

    charts = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: charts.append(
        (fig.axes[0].get_title(), [t.get_text() for t in fig.axes[0].get_legend().get_texts()])) or real_save(fig, path))
    for name, fidelity in (("a", "point"), ("b", "point"), ("q", "quadrotor")):
        (tmp_path / name).mkdir()
        _log(tmp_path / name / "metrics.jsonl")
        (tmp_path / name / "config.yaml").write_text(f"name: {name}\ntask:\n  fidelity: {fidelity}\n")
    _log(tmp_path / "loose.jsonl")
    metric = ["--metric", "validation.success"]
    assert main(["plot", "--log", str(tmp_path / "a"), "--log", str(tmp_path / "b" / "metrics.jsonl"), *metric,
                 "-o", str(tmp_path / "p1")]) == 0
    assert charts == [("validation.success\npoint fidelity", ["a", "b"])], charts
    charts.clear()
    assert main(["plot", "--log", str(tmp_path / "a"), "--log", str(tmp_path / "q"), *metric, "-o", str(tmp_path / "p2")]) == 0
    assert charts == [("validation.success", ["a (point)", "q (quadrotor)"])], charts
    charts.clear()
    assert main(["plot", "--log", str(tmp_path / "loose.jsonl"), *metric, "-o", str(tmp_path / "p3")]) == 0
    assert charts == [("validation.success", ["loose"])], charts
