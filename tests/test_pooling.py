"""Pooling evaluation tables (pursuit_mj.pooling, `pursuit-mj pool`): episodes are known by their
seeds, so tables of several seeds make one table, an episode met twice counts once, and policies
from different files pair on the episodes both played. Tables come from real point-fidelity
episodes of the heuristic team and the random policy."""

from __future__ import annotations

import dataclasses
import json

import pytest

from pursuit_mj.config import default_config
from pursuit_mj.evaluation import evaluate, write_json
from pursuit_mj.policies import make_policy
from pursuit_mj.pooling import POOLED_SEED, pool_tables, pooled_pairs

TASK = dataclasses.replace(default_config(), fidelity="point", max_steps=120)


def _table(tmp_path, name, seed, policies=("heuristic",), task=TASK, meta=None):
    rows = []
    for label in policies:
        rows += evaluate(make_policy(label, task, seed), task, [0], 3, seed, 3)
    return write_json(rows, tmp_path / f"{name}.json", task, meta or {"policies": list(policies), "models": [], "model_sha256": []})


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pool")
    return {"h0": _table(tmp, "h0", 0), "h1": _table(tmp, "h1", 1), "hr0": _table(tmp, "hr0", 0, ("heuristic", "random")),
            "tmp": tmp}


def test_tables_of_two_seeds_pool_into_one_row_and_a_repeated_episode_counts_once(tables):
    pooled = pool_tables([tables["h0"], tables["h1"], tables["hr0"]])
    team = [r for r in pooled.rows if r.policy == "heuristic"]
    assert len(team) == 1 and team[0].episodes == 6  # 3 of seed 0 (in two files) + 3 of seed 1
    assert team[0].seed == POOLED_SEED
    seeds = [e[0] for e in team[0].episode_log]
    assert seeds == sorted(seeds) and len(set(seeds)) == 6
    single = {json.dumps(r["per_episode"]["seed"]) for f in (tables["h0"], tables["h1"]) for r in json.loads(f.read_text())["rows"]}
    assert set(seeds) == {s for text in single for s in json.loads(text)}
    successes = sum(r["success_count"] for f in (tables["h0"], tables["h1"]) for r in json.loads(f.read_text())["rows"])
    assert team[0].success.count == successes


def test_pairs_are_made_on_the_episodes_both_played(tables):
    pooled = pool_tables([tables["h0"], tables["h1"], tables["hr0"]])
    pairs = pooled_pairs(pooled.rows, "heuristic", pooled.max_steps)
    assert [(p.policy, p.episodes) for p in pairs] == [("random", 3)]  # random played seed 0 only
    with pytest.raises(ValueError, match="--versus 'greedy'"):
        pooled_pairs(pooled.rows, "greedy", pooled.max_steps)


def test_pooled_pairs_over_two_layouts_end_with_the_line_over_all_episodes(tmp_path):
    rows = []
    for label in ("heuristic", "random"):
        rows += evaluate(make_policy(label, TASK, 0), TASK, [0, 1], 3, 0, 3)
    path = write_json(rows, tmp_path / "two.json", TASK, {"policies": ["heuristic", "random"], "models": [], "model_sha256": []})
    pooled = pool_tables([path])
    pairs = pooled_pairs(pooled.rows, "heuristic", pooled.max_steps)
    assert [(p.layout, p.episodes) for p in pairs] == [("0", 3), ("1", 3), ("all", 6)]
    assert pairs[-1].only_reference == pairs[0].only_reference + pairs[1].only_reference


def test_tables_of_different_tasks_are_refused_naming_the_setting(tables):
    other = _table(tables["tmp"], "fast", 0, task=dataclasses.replace(TASK, evader_speed=0.7))
    with pytest.raises(ValueError, match=r"fast\.json.*evader_speed.*0\.7"):
        pool_tables([tables["h0"], other])


def test_one_label_for_two_models_is_refused(tables):
    a = _table(tables["tmp"], "ma", 0, meta={"policies": ["heuristic"], "models": ["a.pt"], "model_sha256": ["aaaa"]})
    b = _table(tables["tmp"], "mb", 1, meta={"policies": ["heuristic"], "models": ["b.pt"], "model_sha256": ["bbbb"]})
    with pytest.raises(ValueError, match="'heuristic' is two different models"):
        pool_tables([a, b])


def test_an_episode_that_ended_differently_in_two_files_is_refused(tables):
    data = json.loads(tables["h0"].read_text())
    log = data["rows"][0]["per_episode"]
    log["steps"][0] = 1 if log["steps"][0] != 1 else 2
    edited = tables["tmp"] / "edited.json"
    edited.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="episode seed .* ended"):
        pool_tables([tables["h0"], edited])


@pytest.mark.parametrize("content, match", [
    ("not json", "not a JSON file"),
    ('{"rows": []}', "not an evaluation table"),
    ('{"rows": [{"policy": "heuristic", "layout": "0", "fidelity": "point"}], "config": {}}', "no per-episode records"),
    ('{"rows": [{"policy": "heuristic", "layout": "0", "fidelity": "point", "per_episode": {"seed": [1], '
     '"outcome": ["success"], "steps": ["ten"], "captured": [1]}}], "config": {"max_steps": 100}}', "holds 'ten'"),
    ('{"rows": [], "config": {"max_steps": "long"}}', "max_steps is 'long'"),
])
def test_files_that_are_not_tables_are_refused_by_name(tmp_path, content, match):
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    with pytest.raises(ValueError, match=f"bad.json.*{match}"):
        pool_tables([bad])


def test_an_eval_csv_a_training_log_and_a_folder_are_refused_saying_what_to_pool_instead(tables, tmp_path):
    """eval --out writes PREFIX.csv beside PREFIX.json, and a run folder holds metrics.jsonl: a user
    who hands pool one of those is told what it is and which file pool reads, not a JSON parse error."""
    from pursuit_mj.evaluation import write_csv

    rows = evaluate(make_policy("heuristic", TASK, 0), TASK, [0], 1, 0, 1)
    csv = write_csv(rows, tmp_path / "t.csv")
    with pytest.raises(ValueError, match=r"t\.csv: an evaluation CSV.*per-episode.*t\.json"):
        pool_tables([csv])
    log = tmp_path / "metrics.jsonl"
    two_updates = '{"update": 1, "world_steps": 342}\n{"update": 2, "world_steps": 684}\n'
    for text in (two_updates, two_updates.splitlines()[0] + "\n"):  # a run's first update is one JSON object
        log.write_text(text)
        with pytest.raises(ValueError, match=r"metrics\.jsonl: a training log .*not an evaluation table.*plot --log"):
            pool_tables([log])
    with pytest.raises(ValueError, match=r"a folder, not an evaluation table"):
        pool_tables([tmp_path])


def test_the_command_prints_the_pooled_table_and_writes_it(tables, tmp_path, capsys):
    from pursuit_cli import main

    assert main(["pool", str(tables["h0"]), str(tables["hr0"]), str(tables["h1"]), "--out", str(tmp_path / "all")]) == 0
    out = capsys.readouterr().out
    assert "heuristic" in out and "paired with heuristic" in out
    written = json.loads((tmp_path / "all.json").read_text())
    assert {r["policy"]: r["episodes"] for r in written["rows"]} == {"heuristic": 6, "random": 3}
    assert written["pooled_from"] == [str(tables[k]) for k in ("h0", "hr0", "h1")]
    assert written["paired"][0]["episodes"] == 3


def test_tables_of_two_arenas_under_one_layout_name_are_refused(tmp_path, monkeypatch, capsys):
    """Rows were keyed by the layout's name alone: two evals of arena.yaml, edited in between, were
    merged into one row, and two policies on different arenas were paired as if on the same episodes."""
    from pursuit_cli import main
    from pursuit_mj.layout import builtin_layout_path

    monkeypatch.chdir(tmp_path)
    arena = tmp_path / "arena.yaml"
    for name, builtin, seed in (("open", 0, "0"), ("walls", 1, "1")):
        arena.write_text(builtin_layout_path(builtin).read_text())
        assert main(["eval", "--fidelity", "point", "--episodes", "2", "--set", "max_steps=40", "--layouts", "arena.yaml",
                     "--seed", seed, "-q", "--out", name]) == 0
    capsys.readouterr()
    with pytest.raises(ValueError, match=r"layout arena.yaml: walls.json played another arena under it than open.json"):
        pool_tables(["open.json", "walls.json"])
    (tmp_path / "open2.json").write_text((tmp_path / "open.json").read_text())
    assert main(["pool", "open.json", "open2.json"]) == 0  # one arena: pooled


def test_a_pooled_table_pools_again_with_its_models_and_arenas_known(tables, tmp_path, capsys):
    """The pooled JSON dropped the models' hashes, so pooling it again with a table of another model
    under the same label was taken."""
    from pursuit_cli import main

    a = _table(tables["tmp"], "pa", 0, meta={"policies": ["heuristic"], "models": ["a.pt"], "model_sha256": ["aaaa"],
                                                "layout_sha256": {"0": "1111"}})
    b = _table(tables["tmp"], "pb", 1, meta={"policies": ["heuristic"], "models": ["b.pt"], "model_sha256": ["bbbb"]})
    c = _table(tables["tmp"], "pc", 1, meta={"policies": ["heuristic"], "models": ["a.pt"], "model_sha256": ["aaaa"],
                                                "layout_sha256": {"0": "2222"}})
    assert main(["pool", str(a), "--out", str(tmp_path / "pooled")]) == 0
    assert "pooled 1 table, " in capsys.readouterr().out  # not '1 tables'
    written = json.loads((tmp_path / "pooled.json").read_text())
    assert written["model_sha256_of"] == {"heuristic": "aaaa"} and written["layout_sha256"] == {"0": "1111"}
    with pytest.raises(ValueError, match="'heuristic' is two different models"):
        pool_tables([tmp_path / "pooled.json", b])
    with pytest.raises(ValueError, match="layout 0: .*pc.json played another arena"):
        pool_tables([tmp_path / "pooled.json", c])


def test_a_layout_is_known_as_the_eval_that_played_it_knew_it_from_any_folder(tmp_path, monkeypatch, capsys):
    """`0` and the built-in's file path play the same episodes; pooled from another folder, the path's
    row stood apart from the `0` row and was not paired."""
    from pursuit_cli import main

    repo = __import__("pathlib").Path(__file__).resolve().parents[1]
    monkeypatch.chdir(repo)
    common = ["eval", "--fidelity", "point", "--episodes", "3", "--set", "max_steps=40", "-q"]
    assert main([*common, "--policy", "heuristic", "--layouts", "0", "--out", str(tmp_path / "team")]) == 0
    assert main([*common, "--policy", "random", "--layouts", "configs/layouts/0_open.yaml", "--out", str(tmp_path / "rand")]) == 0
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    pooled = pool_tables(["team.json", "rand.json"])
    assert sorted((r.policy, r.layout) for r in pooled.rows) == [("heuristic", "0"), ("random", "configs/layouts/0_open.yaml")]
    pairs = pooled_pairs(pooled.rows, "heuristic", pooled.max_steps, pooled.meta["layout_identity"])
    assert [(p.policy, p.layout, p.episodes) for p in pairs] == [("random", "configs/layouts/0_open.yaml", 3)]
    assert main(["pool", "team.json", "rand.json"]) == 0
    paired = capsys.readouterr().out.split("paired with")[1].splitlines()
    assert any(line.split()[:3] == ["random", "heuristic", "configs/layouts/0_open.yaml"] for line in paired), paired


def test_a_pooled_table_of_two_fidelities_shows_them_and_plots_them_apart(tables, tmp_path, capsys):
    """Its rows of one policy and layout printed alike but for their counts, and --plots failed
    ('policy heuristic on layout 0 is given twice') after writing the CSV and JSON."""
    from pursuit_cli import main

    quad = dataclasses.replace(TASK, fidelity="quadrotor", max_steps=120)
    q = _table(tables["tmp"], "quad", 0, ("heuristic", "random"), task=quad)
    assert main(["pool", str(tables["hr0"]), str(q), "--out", str(tmp_path / "both"), "--plots", str(tmp_path / "plots")]) == 0
    out = capsys.readouterr().out
    table, paired = out.split("paired with")
    assert "fidelity" in table.splitlines()[1] and any("point" in x for x in table.splitlines()) and "quadrotor" in table
    assert "fidelity" in paired.splitlines()[1] and "quadrotor" in paired
    assert {p["fidelity"] for p in json.loads((tmp_path / "both.json").read_text())["paired"]} == {"point", "quadrotor"}
    assert (tmp_path / "plots" / "success.png").is_file()


def test_a_row_of_no_episodes_is_refused(tmp_path):
    """It printed a success rate of 0.0 % for no episodes at all."""
    bad = tmp_path / "empty.json"
    bad.write_text('{"rows": [{"policy": "heuristic", "layout": "0", "fidelity": "point", "per_episode": {"seed": [], '
                   '"outcome": [], "steps": [], "captured": []}}], "config": {"max_steps": 100}}')
    with pytest.raises(ValueError, match="empty.json: row heuristic on layout 0 holds no episodes"):
        pool_tables([bad])


def test_one_layout_label_that_named_two_layouts_is_refused(tables):
    """x.yaml was the built-in layout 0 (a link to it) in one eval's folder and another file in the
    other's: the two rows printed alike, and a pool of the pool merged them into one."""
    base = {"policies": ["heuristic"], "models": [], "model_sha256": []}
    a = _table(tables["tmp"], "ia", 0, meta={**base, "layout_identity": {"0": "0"}})
    b = _table(tables["tmp"], "ib", 1, meta={**base, "layout_identity": {"0": "elsewhere/0"}})
    with pytest.raises(ValueError, match=r"layout 0: names another layout in .*ib.json than in .*ia.json"):
        pool_tables([a, b])


def test_a_pool_of_several_code_versions_keeps_them_all_when_pooled_again(tables, tmp_path, capsys):
    from pursuit_cli import main

    base = {"policies": ["heuristic"], "models": [], "model_sha256": []}
    a = _table(tables["tmp"], "ca", 0, meta={**base, "code": {"git_commit": "aaaaaaaaaaaa"}})
    b = _table(tables["tmp"], "cb", 1, meta={**base, "code": {"git_commit": "bbbbbbbbbbbb"}})
    assert main(["pool", str(a), str(b), "--out", str(tmp_path / "ab")]) == 0
    capsys.readouterr()
    assert main(["pool", str(tmp_path / "ab.json")]) == 0
    out = capsys.readouterr().out
    assert "several code versions" in out and "aaaaaaaaaa in" in out and "bbbbbbbbbb in" in out, out


def test_a_table_written_before_a_task_key_existed_pools_with_one_at_its_default(tables, tmp_path):
    """A table from before command_latency (or drone_mass) was played at today's default, which
    steps as before: it was refused as another task ('command_latency (0.0 there, None in ...)')."""
    from pursuit_cli.plot_cmd import _check_one_task

    data = json.loads(tables["h0"].read_text())
    del data["config"]["command_latency"], data["config"]["drone_mass"], data["config"]["evader"]["smoothing"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    pooled = pool_tables([old, tables["h1"]])
    assert [r.episodes for r in pooled.rows] == [6]
    pool_tables([tables["h1"], old])
    _check_one_task([str(old), str(tables["h1"])])
    delayed = tmp_path / "delayed.json"
    data["config"]["command_latency"] = 0.05
    delayed.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"delayed\.json.*command_latency \(0\.05 there, 0\.0 in"):
        pool_tables([tables["h1"], delayed])


@pytest.mark.parametrize("field, value, said", [
    ("steps", TASK.max_steps + 880, f"steps {TASK.max_steps + 880}, outside 1..{TASK.max_steps}"),
    ("steps", 0, f"steps 0, outside 1..{TASK.max_steps}"),
    ("captured", 5, f"captured 5, outside 0..{TASK.n_evaders}"),
    ("fidelity", None, "fidelity None, not one of point, quadrotor"),
])
def test_an_episode_no_eval_of_the_task_can_play_is_refused(tables, field, value, said):
    """A success after 1000 steps under max_steps 120 was pooled (a capture time past the limit, and
    paired as such), and a row of fidelity null made a row of fidelity 'None' beside the point one."""
    data = json.loads(tables["hr0"].read_text())
    row = data["rows"][0]
    if field == "fidelity":
        row["fidelity"] = value
    else:
        row["per_episode"][field][0] = value
    edited = tables["tmp"] / f"edited_{field}.json"
    edited.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=f"edited_{field}.json: row heuristic on layout 0: .*{said}"):
        pool_tables([tables["hr0"], edited] if field == "fidelity" else [edited])


STILL = """
import numpy as np
class Still:
    name = "still"
    def __init__(self, config, seed):
        pass
    def reset(self, n_worlds, world_ids=None):
        pass
    def act(self, obs, spec):
        return {speed} * np.ones(obs.shape[:2] + (2,))
"""


def test_one_label_for_two_policy_files_is_refused_and_a_pool_keeps_the_file_s_hash(tmp_path, capsys):
    """A policy of one's own edited between the tables of two seeds was pooled into one row, as if one
    policy had played them all (a label naming two checkpoints was refused, one naming two files not)."""
    from pursuit_cli import main

    team = tmp_path / "mine.py"
    cmd = ["eval", "--policy", f"{team}:Still", "--policy", "heuristic", "--layouts", "0", "--episodes", "2", "--worlds", "2",
           "--fidelity", "point", "--set", "max_steps=5", "-q"]
    team.write_text(STILL.format(speed=0.0))
    assert main(cmd + ["--seed", "0", "--out", str(tmp_path / "s0")]) == 0
    assert main(cmd + ["--seed", "1", "--out", str(tmp_path / "s1")]) == 0
    team.write_text(STILL.format(speed=0.5))
    assert main(cmd + ["--seed", "2", "--out", str(tmp_path / "s2")]) == 0
    capsys.readouterr()
    assert main(["pool", str(tmp_path / "s0.json"), str(tmp_path / "s1.json"), "--out", str(tmp_path / "p01")]) == 0
    for files in ([tmp_path / "s0.json", tmp_path / "s2.json"], [tmp_path / "p01.json", tmp_path / "s2.json"]):
        capsys.readouterr()
        assert main(["pool", *map(str, files)]) == 2
        err = capsys.readouterr().err
        assert "policy 'still' is two different policy files: sha256 " in err and f"in {files[1]}" in err, err


def test_the_files_of_a_pool_of_two_fidelities_plot_as_its_plots_do(tables, tmp_path, capsys):
    """`pool --plots` drew 'heuristic (point)' beside 'heuristic (quadrotor)', but `plot --eval` refused the
    JSON and CSV that pool wrote: 'rows 0 and 2 both hold policy heuristic on layout 0'."""
    from pursuit_cli import main
    from pursuit_mj.plots import plot_eval, read_eval_rows

    quad = dataclasses.replace(TASK, fidelity="quadrotor", max_steps=120)
    q = _table(tables["tmp"], "quad2", 0, ("heuristic",), task=quad)
    assert main(["pool", str(tables["h0"]), str(q), "--out", str(tmp_path / "both")]) == 0
    for suffix in (".json", ".csv"):
        capsys.readouterr()
        assert main(["plot", "--eval", str(tmp_path / f"both{suffix}"), "-o", str(tmp_path / suffix[1:])]) == 0, \
            capsys.readouterr().err
        assert (tmp_path / suffix[1:] / "eval_success.png").is_file()
    drawn = []
    import matplotlib.axes

    real = matplotlib.axes.Axes.bar
    def spy(self, x, height, *args, label=None, **kw):
        drawn.append(label)
        return real(self, x, height, *args, label=label, **kw)
    import unittest.mock
    with unittest.mock.patch.object(matplotlib.axes.Axes, "bar", spy):
        plot_eval(read_eval_rows(tmp_path / "both.json"), tmp_path / "spy")
    assert {"heuristic (point)", "heuristic (quadrotor)"} <= set(drawn)
    with pytest.raises(ValueError, match="rows 0 and 1 both hold policy heuristic on layout 0 .point."):
        twice = json.loads((tmp_path / "both.json").read_text())
        twice["rows"][1] = twice["rows"][0]
        (tmp_path / "twice.json").write_text(json.dumps(twice))
        read_eval_rows(tmp_path / "twice.json")


def test_one_label_for_a_checkpoint_in_one_table_and_a_hand_made_team_in_another_is_refused(tables, tmp_path):
    """A model whose run was named 'heuristic', evaluated alone at seed 1, was pooled into the heuristic
    team's row of a seed-0 table (its episodes were other seeds, so none ended differently)."""
    net = _table(tables["tmp"], "net1", 1, meta={"policies": ["heuristic"], "models": ["runs/heuristic/best.pt"],
                                                 "model_sha256": ["cd" * 32]})
    with pytest.raises(ValueError, match=r"policy 'heuristic' is a checkpoint \(sha256 cdcdcdcdcdcd\) in .*net1.json but "
                                          r"not a checkpoint in .*hr0.json"):
        pool_tables([tables["hr0"], net])
    with pytest.raises(ValueError, match=r"policy 'heuristic' is not a checkpoint in .*hr0.json but a checkpoint"):
        pool_tables([net, tables["hr0"]])
    team = dict(json.loads(tables["h1"].read_text()), policy_file_sha256_of={"heuristic": "ef" * 32})
    (tmp_path / "file1.json").write_text(json.dumps(team))
    hand = dict(json.loads(tables["hr0"].read_text()), policy_file_sha256_of={})
    (tmp_path / "hand0.json").write_text(json.dumps(hand))
    with pytest.raises(ValueError, match=r"policy 'heuristic' is a policy file \(sha256 efefefefefef\) in .*file1.json but "
                                          r"a hand-made team in .*hand0.json"):
        pool_tables([tmp_path / "hand0.json", tmp_path / "file1.json"])
    assert pool_tables([tables["hr0"], tmp_path / "file1.json"]).rows  # hr0 predates the key: it may have been that file
    assert pool_tables([tables["hr0"], tables["h1"]]).rows


def test_a_csv_is_sent_to_the_json_beside_it_only_where_there_is_one(tmp_path):
    # the refusal of a CSV named 't.json, written beside it' whether or not there was one (eval
    # --csv writes a CSV alone), and called a CSV that does not exist at all 'an evaluation CSV'
    from pursuit_mj.evaluation import write_csv, write_json

    rows = evaluate(make_policy("heuristic", TASK, 0), TASK, [0], 1, 0, 1)
    alone = write_csv(rows, tmp_path / "alone.csv")
    with pytest.raises(ValueError, match=r"alone\.csv: an evaluation CSV.*per-episode") as refused:
        pool_tables([alone])
    assert "written beside it" not in str(refused.value) and "no alone.json beside" in str(refused.value)
    write_csv(rows, tmp_path / "pair.csv"), write_json(rows, tmp_path / "pair.json", TASK)
    with pytest.raises(ValueError, match=r"pair\.csv: an evaluation CSV.*pool the JSON written beside it \(.*pair\.json\)"):
        pool_tables([tmp_path / "pair.csv"])
    with pytest.raises(ValueError, match=r"missing\.csv: cannot read it \(No such file"):
        pool_tables([tmp_path / "missing.csv"])


def test_pool_refuses_one_table_given_twice_as_plot_does(tables, tmp_path, capsys, monkeypatch):
    """'pool t.json t.json' said 'pooled 2 tables' of one table (its episodes, the same seeds, were
    counted once), where plot refuses the same file given twice."""
    from pursuit_cli import main

    monkeypatch.chdir(tables["h0"].parent)
    name = tables["h0"].name
    assert main(["pool", name, f"./{name}"]) == 2
    assert f"pool: error: ./{name}: the same file as {name}, given twice" in capsys.readouterr().err


@pytest.mark.parametrize("flags", [["--out", "n1/x/p", "--plots", "mine.txt"], ["--out", "n1/x/p", "--plots", "n1/plots"]])
def test_a_pool_refused_or_stopped_before_it_wrote_leaves_no_folder_it_made(tables, tmp_path, capsys, monkeypatch, flags):
    """--out's folder was made (its check) before --plots was refused: 'pool t.json --out n1/x/p
    --plots FILE' left the empty n1/x/; so did a pool stopped (Ctrl-C) before it wrote a file."""
    from pursuit_cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("mine")
    if "mine.txt" not in flags:  # stopped as it starts writing
        import pursuit_mj.evaluation

        def stop(*args, **kwargs):
            raise KeyboardInterrupt

        monkeypatch.setattr(pursuit_mj.evaluation, "write_csv", stop)
    assert main(["pool", str(tables["h0"]), *flags]) in (2, 130)
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


def test_pool_refuses_an_out_prefix_that_writes_over_a_table_it_pools(tables, tmp_path, capsys):
    """`pool s0.json s1.json --out s0` wrote the pooled table over s0.json: the seed-0 table was gone."""
    import shutil

    from pursuit_cli import main

    s0, s1 = tmp_path / "s0.json", tmp_path / "s1.json"
    shutil.copy(tables["h0"], s0)
    shutil.copy(tables["h1"], s1)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert main(["pool", str(s0), str(s1), "--out", str(tmp_path / "s0")]) == 2
    err = capsys.readouterr().err
    assert f"--out {tmp_path}/s0 (it writes {s0}): the same file as {s0}" in err and len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_pool_refuses_to_write_its_table_over_a_file_that_is_no_table(tables, tmp_path, capsys):
    """pool ... --out notes replaced notes.json, a file of the user's that was no table."""
    from pursuit_cli import main

    notes = tmp_path / "notes.json"
    notes.write_text('{"mine": 1}\n')
    assert main(["pool", str(tables["h0"]), str(tables["h1"]), "--out", str(tmp_path / "notes")]) == 2
    err = capsys.readouterr().err
    assert f"--out {tmp_path}/notes path {notes}: exists and is not an evaluation table" in err, err
    assert notes.read_text() == '{"mine": 1}\n' and not (tmp_path / "notes.csv").exists()


@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_pool_out_over_a_link_to_a_table_it_pools_replaces_the_link_and_keeps_the_table(link, tables, tmp_path, capsys):
    """pool s0.json s1.json --out latest, latest.json a link to s1.json (kept pointing at the newest
    table), was refused as 'the same file as s1.json, which writing there would destroy': the
    pooled table is written beside latest.json and renamed onto it, which replaces the link and
    leaves s1.json whole."""
    import os
    import shutil

    from pursuit_cli import main

    s0, s1, latest = tmp_path / "s0.json", tmp_path / "s1.json", tmp_path / "latest.json"
    shutil.copy(tables["h0"], s0)
    shutil.copy(tables["h1"], s1)
    (os.symlink if link == "symbolic" else os.link)(s1, latest)
    kept = s1.read_bytes()
    assert main(["pool", str(s0), str(s1), "--out", str(tmp_path / "latest")]) == 0, capsys.readouterr().err
    assert s1.read_bytes() == kept and not latest.is_symlink()
    assert json.loads(latest.read_text())["pooled_from"] == [str(s0), str(s1)]


def test_an_out_prefix_that_names_a_pipe_or_device_is_refused_in_one_line(tables, tmp_path, capsys):
    """`pool A.json B.json --out /dev/null` wrote /dev/null.csv and /dev/null.json: --out is a prefix,
    and a user who names a device or a pipe means to write to it, not beside it. Refused now, as is a
    prefix in /dev (where /dev/stdout names a file, say); a regular file of that name takes PREFIX.csv
    and PREFIX.json beside it, as before."""
    import os

    from pursuit_cli import main
    from pursuit_cli.common import check_out_prefix

    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    assert main(["pool", str(tables["h0"]), str(tables["h1"]), "--out", str(pipe)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--out {pipe}: a named pipe, not a file name prefix" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]
    for prefix, said in (("/dev/null", "--out /dev/null: a device, not a file name prefix"),
                         ("/dev/no-such-device", "--out /dev/no-such-device: a prefix in /dev, the folder of devices")):
        with pytest.raises(ValueError, match=said):  # the check alone: nothing is written in /dev by a test
            check_out_prefix(prefix)
    check_out_prefix(str(tmp_path / "notes"))  # no file there: as before
    (tmp_path / "notes").write_text("mine")
    check_out_prefix(str(tmp_path / "notes"))  # a file of that name is left as it is, beside notes.csv


def test_a_table_written_to_a_named_pipe_needs_a_reader_and_is_read_whole_by_one(tables, tmp_path, capsys, monkeypatch):
    """`pool A.json B.json --out t` where t.csv is a named pipe that no program reads waited forever
    (open() of a pipe blocks until a reader comes). Refused after io_utils.PIPE_READER_WAIT_S now,
    naming it; a reader gets the whole file (the check for one must not end its data)."""
    import os
    import signal
    import threading

    from pursuit_cli import main
    import pursuit_mj.io_utils as io_utils
    from pursuit_mj.io_utils import atomic_write_text

    monkeypatch.setattr(io_utils, "PIPE_READER_WAIT_S", 0.3)

    def ring(signum, frame):
        raise TimeoutError("still waiting")

    pipe = tmp_path / "t.csv"
    os.mkfifo(pipe)
    before = signal.signal(signal.SIGALRM, ring)
    signal.alarm(20)
    try:
        assert main(["pool", str(tables["h0"]), str(tables["h1"]), "--out", str(tmp_path / "t")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"{pipe}: a named pipe that no program opened for reading within 0.3 s" in err, err
        got: list[str] = []
        reader = threading.Thread(target=lambda: got.append(pipe.read_text()))
        reader.start()
        monkeypatch.setattr(io_utils, "PIPE_READER_WAIT_S", 10.0)  # the reader's open() may come a little later
        atomic_write_text(pipe, "a,b\n1,2\n")
        reader.join(10)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, before)
    assert got == ["a,b\n1,2\n"] and pipe.exists()


def _edited(tables, name, edit, source="hr0"):
    """A copy of a module table with `edit(data)` applied, written under `name`.json."""
    data = json.loads(tables[source].read_text())
    edit(data)
    path = tables["tmp"] / f"{name}.json"
    path.write_text(json.dumps(data))
    return path


def test_episodes_at_the_task_s_limits_pool_and_one_step_or_evader_past_them_is_refused(tables):
    def set_first(field, value):
        return lambda data: data["rows"][0]["per_episode"][field].__setitem__(0, value)

    at_limit = pool_tables([_edited(tables, "at_steps", set_first("steps", TASK.max_steps))])
    assert TASK.max_steps in [e[2] for e in at_limit.rows[0].episode_log]
    caught_all = pool_tables([_edited(tables, "at_caught", set_first("captured", TASK.n_evaders))])
    assert TASK.n_evaders in [e[3] for e in caught_all.rows[0].episode_log]
    with pytest.raises(ValueError, match=f"steps {TASK.max_steps + 1}, outside 1..{TASK.max_steps}"):
        pool_tables([_edited(tables, "past_steps", set_first("steps", TASK.max_steps + 1))])
    with pytest.raises(ValueError, match=f"captured {TASK.n_evaders + 1}, outside 0..{TASK.n_evaders}"):
        pool_tables([_edited(tables, "past_caught", set_first("captured", TASK.n_evaders + 1))])
    with pytest.raises(ValueError, match="its config's max_steps is 0, not a whole number >= 1"):
        pool_tables([_edited(tables, "no_steps", lambda data: data["config"].__setitem__("max_steps", 0))])


def test_tables_whose_evaders_are_two_model_files_are_refused(tables):
    a = _edited(tables, "evader_a", lambda data: data.__setitem__("evader_model_sha256", "a" * 64), "h0")
    b = _edited(tables, "evader_b", lambda data: data.__setitem__("evader_model_sha256", "b" * 64), "h1")
    with pytest.raises(ValueError, match=r"evader_b\.json: its evaders are another model than .*evader_a\.json"):
        pool_tables([a, b])
    assert pool_tables([a, tables["h1"]]).rows[0].episodes == 6  # a table from before the key: not compared
    assert pool_tables([tables["h1"], a]).rows[0].episodes == 6
    assert pool_tables([a, a]).meta["evader_model_sha256"] == "a" * 64


def test_the_models_of_a_table_are_its_last_policies(tables):
    """eval lists its models last among its policies: with policies [heuristic, random] and one
    model, the model is 'random' (the checkpoint's label), not 'heuristic'."""
    def one_model(data):
        data["policies"], data["models"], data["model_sha256"] = ["heuristic", "random"], ["r.pt"], ["c" * 64]

    pooled = pool_tables([_edited(tables, "one_model", one_model)])
    assert pooled.meta["model_sha256_of"] == {"random": "c" * 64}


def test_a_pool_says_which_policy_files_it_knows_only_when_every_table_recorded_them(tables):
    knows = _edited(tables, "knows_files", lambda data: data.__setitem__("policy_file_sha256_of", {}), "h0")
    assert pool_tables([knows, knows]).meta["policy_file_sha256_of"] == {}
    assert "policy_file_sha256_of" not in pool_tables([knows, tables["h1"]]).meta
    assert "policy_file_sha256_of" not in pool_tables([tables["h1"], knows]).meta


def test_a_policy_that_shares_no_episode_with_the_reference_is_named_as_not_paired(tables, capsys):
    """A model evaluated on --seed 1 and the team on --seed 0 hold no episode in common: the paired
    table was printed as a bare header, with no word that the model was left out or why."""
    from pursuit_cli import main

    random_seed_0 = _table(tables["tmp"], "r0", 0, ("random",))
    assert main(["pool", str(tables["h1"]), str(random_seed_0)]) == 0
    out = capsys.readouterr().out
    paired = out.split("paired with heuristic", 1)[1]
    assert "not paired with heuristic: random on layout 0 (no episode both played" in paired, out
    # one that shares episodes is paired and not named so
    assert main(["pool", str(tables["h1"]), str(tables["hr0"])]) == 0
    assert "not paired" not in capsys.readouterr().out
    # a layout the reference did not play at all is named for that
    from pursuit_mj.pooling import not_paired, not_paired_text

    pooled = pool_tables([tables["h1"], random_seed_0])
    rows = pooled.rows + [dataclasses.replace(r, layout="1") for r in pooled.rows if r.policy == "random"]
    alone = not_paired(rows, "heuristic", pooled.max_steps)
    assert [(r.policy, r.layout) for r in alone] == [("random", "0"), ("random", "1")]
    text = not_paired_text(alone, "heuristic", rows)
    assert "random on layout 0 (no episode both played" in text and "random on layout 1 (heuristic has no row there)" in text


def test_tables_of_one_commit_but_different_source_are_noted_and_stay_noted_when_pooled_again(tables, tmp_path, capsys):
    """A table made from uncommitted edits (git_dirty, another source_sha256) at the same commit as
    another was pooled with it without a note: only git commits were compared, so two versions of
    the heuristic team became one row unremarked."""
    from pursuit_cli import main

    base = {"policies": ["heuristic"], "models": [], "model_sha256": []}
    clean = {"git_commit": "cccccccccccc", "git_dirty": False, "source_sha256": "1111111111aa"}
    edited = {"git_commit": "cccccccccccc", "git_dirty": True, "source_sha256": "2222222222bb"}
    a = _table(tables["tmp"], "sa", 0, meta={**base, "code": clean})
    b = _table(tables["tmp"], "sb", 1, meta={**base, "code": edited})
    assert any("1111111111" in n and "2222222222" in n for n in pool_tables([a, b]).notes)
    assert main(["pool", str(a), str(b), "--out", str(tmp_path / "ab")]) == 0
    out = capsys.readouterr().out
    assert "different source code" in out and "1111111111 in" in out and "2222222222 in" in out, out
    assert main(["pool", str(tmp_path / "ab.json")]) == 0  # the pooled table says so too
    assert "different source code" in capsys.readouterr().out
    same = _table(tables["tmp"], "sc", 1, meta={**base, "code": clean})
    assert pool_tables([a, same]).notes == []  # one commit, one source: nothing to note


def test_a_table_that_records_no_checkpoints_is_noted_when_pooled_with_others(tables, tmp_path):
    """A table that records no checkpoint hashes (written by a script, or a study's table.json
    before it recorded its arms) cannot have its labels checked: pooled beside others, a label in
    it was taken for the same policy without a word."""
    rows = evaluate(make_policy("heuristic", TASK, 1), TASK, [0], 3, 1, 3)
    bare = write_json(rows, tmp_path / "bare.json", TASK)  # no meta at all
    notes = pool_tables([tables["h0"], bare]).notes
    assert any(str(bare) in n and "no checkpoint" in n for n in notes), notes
    assert not any(str(tables["h0"]) in n for n in notes), notes
    assert pool_tables([bare]).notes == []  # alone, it is compared with nothing


def test_tables_of_one_fidelity_say_which_in_their_headings(tables, tmp_path, capsys):
    """With one fidelity the pooled and paired tables have no fidelity column (as with two they do),
    and nothing else in pool's output said whether their episodes were flown in point or quadrotor
    physics: the table alone left the reader guessing. Their headings now name it."""
    from pursuit_cli import main

    assert main(["pool", str(tables["hr0"]), str(tables["h1"])]) == 0
    out = capsys.readouterr().out
    table, paired = out.split("paired with")
    assert "fidelity" not in table.splitlines()[1]  # no column: the heading says it
    assert "pooled 2 tables, every row in point fidelity" in table
    assert paired.splitlines()[0].startswith(" heuristic on the episodes both played, in point fidelity (")
    # its success columns were not explained, as eval's heading explains them
    assert paired.splitlines()[0].endswith("negative = sooner; success: judged on the episodes only one of the two won):")
    quad = dataclasses.replace(TASK, fidelity="quadrotor", max_steps=120)
    q = _table(tmp_path, "quad", 0, ("heuristic", "random"), task=quad)
    assert main(["pool", str(tables["hr0"]), str(q)]) == 0
    out = capsys.readouterr().out  # two fidelities: a column in each table, nothing in the headings
    assert "pooled 2 tables\n" in out and "paired with heuristic on the episodes both played (" in out


def test_a_pool_keeps_the_layouts_each_model_trained_on_and_refuses_two_lists_for_one_label(tables, tmp_path, capsys):
    """eval's "trained_layouts" ({model label: layouts}) reaches the pooled JSON, which pools
    again with it; two tables that say one label trained on different layouts are refused."""
    def trained(layouts):
        def edit(data):
            data["policies"], data["models"], data["model_sha256"] = ["heuristic", "random"], ["r.pt"], ["c" * 64]
            data["trained_layouts"] = {"random": layouts}
        return edit

    a = _edited(tables, "trained_a", trained(["0", "1"]))
    b = _edited(tables, "trained_b", trained(["0", "1"]))
    from pursuit_cli import main

    assert pool_tables([a, b, tables["h0"]]).meta["trained_layouts"] == {"random": ["0", "1"]}
    assert "trained_layouts" not in pool_tables([tables["h0"], tables["h1"]]).meta
    assert main(["pool", str(a), str(b), "--out", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    assert pool_tables([tmp_path / "p.json", a]).meta["trained_layouts"] == {"random": ["0", "1"]}
    other = _edited(tables, "trained_c", trained(["2"]))
    with pytest.raises(ValueError, match=r"'random' trained on layouts \['0', '1'\] in .*trained_a.json but \['2'\] in .*trained_c.json"):
        pool_tables([a, other])
    bad = _edited(tables, "trained_bad", lambda data: data.__setitem__("trained_layouts", {"random": "0"}))
    with pytest.raises(ValueError, match=r"trained_bad.json: trained_layouts is .* not a map of model labels to lists"):
        pool_tables([bad])


def _named(tables, name, source, task_name, **config):
    """A copy of the fixture table `source` whose JSON names its task `task_name` (None: no name, as
    a table from before eval recorded it) and has the config keys `config` changed."""
    data = json.loads(tables[source].read_text())
    if task_name is not None:
        data["task_name"] = task_name
    data["config"].update(config)
    path = tables["tmp"] / f"{name}.json"
    path.write_text(json.dumps(data))
    return path


def test_eval_records_the_task_its_heading_names_and_pool_names_it_too(tmp_path, capsys):
    """pool's heading named the fidelity of the pooled rows but not the task, and eval's JSON did not
    record how its heading named it: a pool of --task hard tables read as one of the reference task.
    eval now writes the name ("task_name"), and pool names it above the table and keeps it in its own
    JSON, so that a pool pooled again names it too."""
    from pursuit_cli import main

    common = ["eval", "--task", "hard", "--fidelity", "point", "--episodes", "1", "--worlds", "1", "--set", "max_steps=5", "-q"]
    for seed in ("0", "1"):
        assert main([*common, "--seed", seed, "--out", str(tmp_path / f"s{seed}")]) == 0
    assert json.loads((tmp_path / "s0.json").read_text())["task_name"] == "task hard with --set max_steps=5"
    capsys.readouterr()
    assert main(["pool", str(tmp_path / "s0.json"), str(tmp_path / "s1.json"), "--out", str(tmp_path / "pooled")]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "pooled 2 tables, every row in point fidelity, task hard with --set max_steps=5", out
    assert json.loads((tmp_path / "pooled.json").read_text())["task_name"] == "task hard with --set max_steps=5"
    assert main(["pool", str(tmp_path / "pooled.json")]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "pooled 1 table, every row in point fidelity, task hard with --set max_steps=5"


def test_a_table_that_names_no_task_pools_under_the_name_the_others_give(tables):
    """A table written before eval recorded its task's name still pools; the task is the one the
    others name (their configs are equal), and with no name anywhere there is none to give."""
    old = _named(tables, "old_unnamed", "h1", None)
    named = _named(tables, "named_hard", "h0", "task hard")
    assert pool_tables([old, named]).task_name == "task hard" and pool_tables([named, old]).task_name == "task hard"
    assert pool_tables([old, tables["h0"]]).task_name == ""


def test_tables_naming_one_task_config_differently_pool_with_a_note_naming_each(tables):
    """Two names for equal configs (--task hard, and the reference with hard's values as flags) are one
    task: pooled, under the first table's name, with a note naming each name and its file."""
    a = _named(tables, "as_hard", "h0", "task hard")
    b = _named(tables, "as_flags", "h1", "task reference with --set evader_speed=0.6")
    pooled = pool_tables([a, b])
    assert pooled.task_name == "task hard"
    assert (f"note: the tables name their task differently, its config the same in all: task hard in {a}, "
            f"task reference with --set evader_speed=0.6 in {b}") in pooled.notes, pooled.notes


def test_tables_of_two_tasks_are_refused_naming_both_files_and_how_each_names_its_task(tables):
    """Tables of two tasks were refused, naming both files and the first key that differs; where the
    tables record their tasks' names, the refusal says them too."""
    a = _named(tables, "task_ref", "h0", "task reference with --set max_steps=120")
    b = _named(tables, "task_fast", "h1", "task reference with --evader-speed 0.9, --set max_steps=120", evader_speed=0.9)
    with pytest.raises(ValueError, match=(rf"^{b}: its task differs from {a}'s at evader_speed \(0\.9 there, 0\.6 in {a}; "
                                          rf"'task reference with --evader-speed 0\.9, --set max_steps=120' there, "
                                          rf"'task reference with --set max_steps=120' in {a}\); pool only tables of one task$")):
        pool_tables([a, b])
    with pytest.raises(ValueError, match=rf"^{b}: its task differs from {tables['h0']}'s at evader_speed \(0\.9 there, 0\.6 in "
                                         rf"{tables['h0']}\); pool only tables of one task$"):
        pool_tables([tables["h0"], b])  # the first names none: the key alone, as before
