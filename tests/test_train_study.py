"""`pursuit-mj study` end to end on a tiny budget: every regime trains, everything is evaluated."""

import json

from pursuit_mj.cli import main

TRAIN = ["task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=30", "n_envs=2", "ppo.batch_size=64",
         "ppo.minibatch_size=32", "ppo.epochs=1", "imitation.grad_steps=2", "run.validate_every=0", "run.validation_episodes=2"]


def test_study_end_to_end_on_a_tiny_budget(tmp_path, capsys):
    out_dir = tmp_path / "study"
    code = main(["study", "--budget-minutes", "0.5", "--episodes", "2", "--worlds", "2", "--layouts", "0", "1",
                 "--out", str(out_dir), "--fidelity", "point", "--set", "max_steps=20"]
                + sum((["--train-set", s] for s in TRAIN), []))
    assert code == 0
    out = capsys.readouterr().out
    names = {"heuristic", "full_obs", "fine_tune", "classic", "mappo", "imitate", "imitate_ppo", "residual", "belief",
             "belief_ppo"}
    for name in names:
        assert name in out
    assert "min" in out  # the timings
    table = json.loads((out_dir / "table.json").read_text())
    assert {r["policy"] for r in table["rows"]} == names
    assert "paired with heuristic on the same episodes" in out  # every arm against the team, episode by episode
    assert {(p["policy"], p["layout"]) for p in table["paired"]} == {(n, l) for n in names - {"heuristic"} for l in ("0", "1")}
    assert (out_dir / "plots" / "success.png").is_file() and (out_dir / "timings.json").is_file()
    ft = json.loads((out_dir / "runs" / "fine_tune" / "metrics.jsonl").read_text().splitlines()[0])
    assert ft["update"] == 1
    assert f"initialised from {out_dir / 'runs' / 'imitate' / 'best.pt'}" in out  # PPO continues the imitation
