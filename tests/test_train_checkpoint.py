"""Checkpoints: resume keeps counters, interrupts and kill -9 lose at most one update, bad files are refused."""

import json
import shutil
from pathlib import Path

import pytest
import torch

from conftest import weights_go_nan_at_update
from pursuit_mj.obs_spec import ObsSpec
from train.checkpoint import load_checkpoint
from train.config import load_train_config
from train.policy import load_policy
import train.trainer as trainer_module
from train.trainer import Trainer

TINY = [
    "task.fidelity=point", "task.n_pursuers=2", "task.random_obstacles=0", "task.max_steps=40",
    "n_envs=2", "ppo.batch_size=64", "ppo.minibatch_size=32", "ppo.epochs=2",
    "run.validate_every=0", "run.validation_episodes=2", "run.progress=false",
]


def tiny_config(tmp_path, name="run", updates=2, extra=()):
    per_update = 16 * 2  # rollout of ceil(64 / (2 worlds * 2 pursuers)) = 16 steps in 2 worlds
    return load_train_config([], TINY + [f"run.runs_dir={tmp_path}", f"name={name}", f"total_steps={per_update * updates}", *extra])


def rows(run_dir):
    return [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]


def test_resume_continues_counters_weights_and_optimiser(tmp_path):
    cfg = tiny_config(tmp_path, updates=2)
    result = Trainer(cfg, log=lambda s: None).train()
    assert result["status"] == "done" and result["counters"]["update"] == 2
    saved = load_checkpoint(cfg.run_dir / "last.pt")
    resumed = Trainer.resume(cfg.run_dir, total_steps=32 * 4, log=lambda s: None)
    assert resumed.counters.update == 2 and resumed.counters.world_steps == 64
    for k, v in saved["actor"].items():
        assert torch.equal(resumed.model.actor.state_dict()[k], v)
    assert resumed.optimizer.state_dict()["state"][0]["step"] == saved["optimizer"]["state"][0]["step"]
    assert torch.equal(resumed.generator.get_state(), saved["rng"]["sampler"])
    out = resumed.train()
    assert out["counters"]["update"] == 4 and out["counters"]["world_steps"] == 128
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2, 3, 4]
    assert (cfg.run_dir / "best.pt").is_file()


@pytest.mark.parametrize("algo", ["ppo", "mappo"])
def test_a_resumed_run_learns_from_its_next_rollout_exactly_as_the_run_going_on_would(tmp_path, algo):
    """Everything an update reads besides its rollout comes back from last.pt: the weights, Adam's
    moments and step counts, the learning rate's place in its decay, the minibatch draws, MAPPO's
    value statistics, a learned discount and its optimiser. Given the same next rollout (the env
    restarts on resume, so it is handed to both), the run that goes on in its process and the one
    resumed from its folder end that update with the same weights, bit for bit."""
    import copy

    cfg = tiny_config(tmp_path, updates=4, extra=[f"algo={algo}", "ppo.learnable_gamma=true", "run.split_update=false",
                                                 "net.encoder_width=16", "net.hidden=[16]", "net.critic_hidden=[16]"])
    going_on = Trainer(cfg, log=lambda s: None)
    for _ in range(2):
        going_on._log_row(going_on.train_one_update(), None, {})  # logged, then last.pt
    going_on.close()  # frees the folder; its model, optimiser and collector stay usable
    resumed = Trainer.resume(cfg.run_dir, log=lambda s: None)
    sampler = going_on.generator.get_state()
    rollout = going_on._next_rollout()
    going_on.generator.set_state(sampler)  # as last.pt has it: the rollout's noise is not the update's
    rows = []
    for trainer in (going_on, resumed):
        trainer._next_rollout = lambda: copy.deepcopy(rollout)
        rows.append(trainer.train_one_update())
    resumed.close()
    assert rows[0]["lr"] == rows[1]["lr"] < cfg.ppo.lr and rows[0]["gamma"] == rows[1]["gamma"] != cfg.ppo.gamma
    for (key, a), b in zip(going_on.model.state_dict().items(), resumed.model.state_dict().values()):
        assert torch.equal(a, b), key
    if algo == "mappo":
        assert going_on.model.value_norm.state_dict() == resumed.model.value_norm.state_dict()
    moments = [[v for s in t.optimizer.state_dict()["state"].values() for v in s.values()] for t in (going_on, resumed)]
    assert all(torch.equal(a, b) for a, b in zip(*moments))


@pytest.mark.parametrize("overlap", [False, True])
def test_ctrl_c_saves_the_last_consistent_update(tmp_path, monkeypatch, overlap):
    """Ctrl-C in the 4th rollout (collected in turn) or the 4th update (a rollout worker
    collecting beside it): update 3 is kept, the worker stops, and the run resumes."""
    cfg = tiny_config(tmp_path, updates=10, extra=[f"run.overlap={str(overlap).lower()}"])
    trainer = Trainer(cfg, log=lambda s: None)
    calls = {"n": 0}

    def fourth_call_interrupts(real):
        def call(*args, **kwargs):
            calls["n"] += 1
            if calls["n"] == 4:
                raise KeyboardInterrupt
            return real(*args, **kwargs)
        return call

    if overlap:
        monkeypatch.setattr("train.trainer.ppo_update", fourth_call_interrupts(trainer_module.ppo_update))
    else:
        monkeypatch.setattr(trainer.collector, "collect", fourth_call_interrupts(trainer.collector.collect))
    out = trainer.train()
    assert out["status"] == "interrupted"
    assert trainer.worker is None
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 3
    monkeypatch.undo()
    resumed = Trainer.resume(cfg.run_dir, total_steps=32 * 5, log=lambda s: None)
    assert resumed.counters.update == 3
    assert resumed.train()["counters"]["update"] == 5
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2, 3, 4, 5]


class _RunsACommand:
    """Pickles as a call of os.system: what a malicious checkpoint would hold."""

    def __init__(self, command: str):
        self.command = command

    def __reduce__(self):
        import os

        return (os.system, (self.command,))


def test_corrupted_and_foreign_checkpoints_are_refused(tmp_path):
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    good = cfg.run_dir / "last.pt"
    data = good.read_bytes()
    cut = tmp_path / "cut.pt"
    cut.write_bytes(data[: len(data) // 2])
    flipped = tmp_path / "flipped.pt"
    flipped.write_bytes(data[:100] + bytes(b ^ 0xFF for b in data[100:400]) + data[400:])
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint at all")
    for bad, why in ((cut, "not a torch zip archive"), (junk, "not a torch zip archive"), (flipped, "corrupted")):
        with pytest.raises(ValueError, match=f"checkpoint .*{bad.name}.*{why}") as err:
            load_checkpoint(bad)
        assert "\n" not in str(err.value) and "weights_only" not in str(err.value)  # our words, one line
    evil = tmp_path / "evil.pt"
    torch.save({"format": "pursuit-mj-checkpoint", "payload": ObsSpec.make(2, 1, 4)}, evil)  # a pickled object
    with pytest.raises(ValueError, match="refused: it holds Python objects") as err:
        load_checkpoint(evil)
    assert "weights_only" not in str(err.value)
    marker = tmp_path / "ran"
    torch.save({"format": "pursuit-mj-checkpoint", "x": _RunsACommand(f"touch {marker}")}, evil)  # code, not a class
    with pytest.raises(ValueError, match="refused: it holds Python objects"):
        load_checkpoint(evil)
    assert not marker.exists()
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(ValueError, match="not a pursuit-mj checkpoint"):
        load_checkpoint(other)
    with pytest.raises(ValueError, match="file not found"):
        load_checkpoint(tmp_path / "missing.pt")


def test_a_checkpoint_whose_zip_headers_are_damaged_is_refused_in_one_line_naming_it(tmp_path):
    """One damaged byte in the archive's directory (the version it needs, its encryption flag, its
    compression method, its disk count) made zipfile raise NotImplementedError, RuntimeError, a
    zlib error or BadZipFile out of is_zipfile, none of which load_checkpoint caught: --resume, and
    a resume whose best.pt alone was damaged, ended in a traceback."""
    import io
    import struct
    import zipfile

    from train.checkpoint import save_checkpoint

    good = save_checkpoint(tmp_path / "good.pt", {"x": torch.zeros(3)}).read_bytes()
    directory = zipfile.ZipFile(io.BytesIO(good)).start_dir  # the first entry's central directory record
    locator = good.rfind(b"PK\x06\x07")  # torch writes zip64: its end locator holds the disk count

    def damaged(offset: int, fmt: str, value: int) -> bytes:
        raw = bytearray(good)
        raw[offset:offset + struct.calcsize(fmt)] = struct.pack(fmt, value)
        return bytes(raw)

    for name, raw in (("version", damaged(directory + 6, "<H", 0x3F0)), ("encrypted", damaged(directory + 8, "<H", 1)),
                      ("method", damaged(directory + 10, "<H", 99)), ("deflated", damaged(directory + 10, "<H", 8)),
                      ("disks", damaged(locator + 16, "<I", 2))):
        path = tmp_path / f"{name}.pt"
        path.write_bytes(raw)
        with pytest.raises(ValueError, match="corrupted") as err:
            load_checkpoint(path)
        assert str(err.value).startswith(f"checkpoint {path}: ") and "\n" not in str(err.value)


def test_mismatched_observation_spec_is_refused_other_team_sizes_accepted(tmp_path):
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    path = cfg.run_dir / "best.pt"
    with pytest.raises(ValueError, match="observation spec does not match.*n_rays"):
        load_policy(path, ObsSpec.make(2, 1, 8))
    for n, m in ((2, 1), (5, 3)):
        spec = ObsSpec.make(n, m, 16)
        actions = load_policy(path, spec).act(torch.zeros(3, n, spec.dim).numpy(), spec)
        assert actions.shape == (3, n, 2) and abs(actions).max() <= 1.0
    with pytest.raises(ValueError, match="observation spec does not match"):
        Trainer(tiny_config(tmp_path, name="ft", extra=[f"init_from={path}", "task.n_rays=8"]), log=lambda s: None)


@pytest.mark.parametrize("team", [(3, 1), (1, 6)])  # 1 pursuer and 6 evaders fill as many slots as 8 and 1
def test_a_flat_network_is_refused_for_another_team_naming_both_teams(tmp_path, team):
    """net.kind mlp reads each teammate and evader slot by its place: for another team its weights
    did not fit (a torch size mismatch to decode) or, where the vector is as long, loaded and read
    evaders as teammates without a word."""
    from pursuit_mj.configio import to_dict
    from train.checkpoint import save_checkpoint
    from train.networks import Actor

    trained = ObsSpec.make(8, 1, 16)
    cfg = load_train_config([], ["net.kind=mlp", "net.hidden=[16]", "task.n_pursuers=8"])
    path = save_checkpoint(tmp_path / "flat.pt", {"train_config": to_dict(cfg), "obs_spec": trained.to_dict(),
                                                  "actor": Actor(trained, cfg.net).state_dict(), "counters": {}})
    said = (rf"net.kind mlp reads the team it was trained with, 8 pursuers and 1 evader, and this environment has "
            rf"{team[0]} pursuers? and {team[1]} evaders?: .*net.kind reference")
    with pytest.raises(ValueError, match=rf"checkpoint {path}: {said}"):
        load_policy(path, ObsSpec.make(*team, 16))
    assert load_policy(path, trained).act(torch.zeros(2, 8, trained.dim).numpy(), trained).shape == (2, 8, 2)
    with pytest.raises(ValueError, match=rf"init_from {path}: net.kind mlp reads the team it was trained with, 8 pursuers"):
        Trainer(tiny_config(tmp_path, name="ft", extra=[f"init_from={path}", "net.kind=mlp", "net.hidden=[16]"]), log=lambda s: None)


def test_existing_run_is_not_overwritten_without_resume(tmp_path):
    from pursuit_cli import main

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    argv = ["train", "--no-progress"] + sum((["--set", s] for s in TINY + [f"run.runs_dir={tmp_path}", "name=run"]), [])
    assert main(argv) == 2


def test_best_checkpoint_ties_go_to_fewer_capture_steps_not_to_earlier_crashes(tmp_path):
    trainer = Trainer(tiny_config(tmp_path, updates=1), log=lambda s: None)
    val = trainer.validate()
    max_steps = trainer.cfg.task.max_steps
    assert val["capture_steps"] >= val["mean_steps"] and val["capture_steps"] <= max_steps
    if val["success"] < 1.0:  # a failed episode counts as max_steps
        assert val["capture_steps"] > val["mean_steps"] or val["mean_steps"] == max_steps
    assert trainer._maybe_best({"success": 0.0, "mean_steps": 300.0, "capture_steps": 1000.0})
    assert not trainer._maybe_best({"success": 0.0, "mean_steps": 200.0, "capture_steps": 1000.0})  # crashed sooner
    assert trainer._maybe_best({"success": 0.0, "mean_steps": 500.0, "capture_steps": 900.0})  # failed later, or caught
    assert trainer._maybe_best({"success": 0.5, "mean_steps": 600.0, "capture_steps": 950.0})  # success first
    assert trainer.counters.best_steps == 950.0


def test_ctrl_c_during_a_validation_is_made_good_on_resume(tmp_path, monkeypatch):
    """The update whose validation was cut short is validated first thing after --resume, so its
    log row (and its chance to be best.pt) is not lost."""
    cfg = tiny_config(tmp_path, updates=4, extra=["run.validate_every=1"])
    trainer = Trainer(cfg, log=lambda s: None)
    real = Trainer.validate
    calls = {"n": 0}

    def second_validation_interrupts(self):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(self)

    monkeypatch.setattr(Trainer, "validate", second_validation_interrupts)
    assert trainer.train()["status"] == "interrupted"
    assert [r["update"] for r in rows(cfg.run_dir)] == [1]
    assert load_checkpoint(cfg.run_dir / "last.pt")["pending_row"]["update"] == 2
    monkeypatch.setattr(Trainer, "validate", real)
    out = Trainer.resume(cfg.run_dir, log=lambda s: None).train()
    assert out["status"] == "done" and out["counters"]["update"] == 4
    logged = rows(cfg.run_dir)
    assert [r["update"] for r in logged] == [1, 2, 3, 4]
    assert all("validation" in r for r in logged)
    assert load_checkpoint(cfg.run_dir / "last.pt")["pending_row"] == {}


def test_export_never_replaces_a_training_checkpoint_and_an_export_does_not_resume(tmp_path):
    from train.checkpoint import export_actor

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    last = cfg.run_dir / "last.pt"
    with pytest.raises(ValueError, match="OUT is the checkpoint itself"):
        export_actor(last, last)
    with pytest.raises(ValueError, match="OUT is a training checkpoint"):
        export_actor(last, cfg.run_dir / "best.pt")
    small = export_actor(last, tmp_path / "small.pt")
    small.replace(last)
    with pytest.raises(ValueError, match="last.pt is a policy-only export .* not a training checkpoint"):
        Trainer.resume(cfg.run_dir, log=lambda s: None)


def test_a_checkpoint_names_the_code_that_trained_it_and_an_export_keeps_that(tmp_path):
    """Eval tables said which code made them; a model did not, so a file in pretrained/ could not be
    traced to the commit or sources that trained it. A resume by other code adds its own entry."""
    from pursuit_mj.provenance import provenance
    from train.checkpoint import export_actor, save_checkpoint

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    now = provenance()
    data = load_checkpoint(cfg.run_dir / "last.pt")
    assert data["trained_by"] == [{"from_update": 0, **now}]
    assert load_checkpoint(export_actor(cfg.run_dir / "last.pt", tmp_path / "small.pt"))["trained_by"] == data["trained_by"]
    Trainer.resume(cfg.run_dir, total_steps=32 * 2, log=lambda s: None).train()  # the same code: no second entry
    data = load_checkpoint(cfg.run_dir / "last.pt")
    assert data["trained_by"] == [{"from_update": 0, **now}]
    older = {**now, "git_commit": "0" * 40, "source_sha256": "ab" * 32}
    save_checkpoint(cfg.run_dir / "last.pt", {**data, "trained_by": [{"from_update": 0, **older}]})
    Trainer.resume(cfg.run_dir, total_steps=32 * 3, log=lambda s: None).train()
    assert load_checkpoint(cfg.run_dir / "last.pt")["trained_by"] == [{"from_update": 0, **older}, {"from_update": 2, **now}]


def test_a_run_started_from_a_checkpoint_keeps_that_files_sha256(tmp_path):
    """init_from names a path only, and the file there moves on (best.pt of a run still training)
    or goes (/tmp): the weights a run started from could not be told. Its sha256 as the run began
    stays in every checkpoint of the run, across a resume, and in an export."""
    import hashlib

    from train.checkpoint import export_actor

    src = tiny_config(tmp_path, name="src", updates=1)
    Trainer(src, log=lambda s: None).train()
    start = src.run_dir / "best.pt"
    sha = hashlib.sha256(start.read_bytes()).hexdigest()
    ft = tiny_config(tmp_path, name="ft", updates=1, extra=[f"init_from={start}"])
    Trainer(ft, log=lambda s: None).train()
    assert load_checkpoint(ft.run_dir / "last.pt")["init_from_sha256"] == sha
    start.write_bytes(b"another run's best.pt now")
    Trainer.resume(ft.run_dir, total_steps=32 * 2, log=lambda s: None).train()
    assert load_checkpoint(ft.run_dir / "last.pt")["init_from_sha256"] == sha
    assert load_checkpoint(export_actor(ft.run_dir / "last.pt", tmp_path / "small.pt"))["init_from_sha256"] == sha
    assert "init_from_sha256" not in load_checkpoint(src.run_dir / "last.pt")


def test_non_finite_weights_and_damaged_bytes_are_refused(tmp_path):
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    data = load_checkpoint(cfg.run_dir / "last.pt")
    name = next(iter(data["actor"]))
    data["actor"][name][0] = float("nan")
    torch.save(data, tmp_path / "nan.pt")
    with pytest.raises(ValueError, match=f"non-finite weights \\(NaN or inf\\) in actor.{name}"):
        load_checkpoint(tmp_path / "nan.pt")
    raw = bytearray((cfg.run_dir / "last.pt").read_bytes())
    middle = len(raw) // 2
    raw[middle:middle + 8] = bytes(8) if raw[middle:middle + 8] != bytes(8) else b"\xff" * 8
    (tmp_path / "flipped.pt").write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="corrupted"):
        load_checkpoint(tmp_path / "flipped.pt")


def test_starting_from_another_kind_of_run_says_what_does_not_carry_over(tmp_path):
    residual = tiny_config(tmp_path, name="res", updates=1, extra=["residual.base=heuristic", "shield=true"])
    Trainer(residual, log=lambda s: None).train()
    lines = []
    plain = tiny_config(tmp_path, name="plain", updates=1, extra=[f"init_from={residual.run_dir / 'last.pt'}", "algo=mappo"])
    Trainer(plain, log=lines.append)
    said = " ".join(lines)
    assert "its critic (ppo) is not this run's (mappo): the critic starts fresh" in said
    assert "correction to base team 'heuristic', here it acts on base 'none'" in said
    assert "trained behind the shield, this run is without it" in said


def test_an_interrupted_closing_validation_is_made_good_once(tmp_path, monkeypatch):
    cfg = tiny_config(tmp_path, updates=2)  # validate_every 0: only the closing validation, of update 2
    real = Trainer.validate
    monkeypatch.setattr(Trainer, "validate", lambda self: (_ for _ in ()).throw(KeyboardInterrupt))
    assert Trainer(cfg, log=lambda s: None).train()["status"] == "interrupted"
    monkeypatch.setattr(Trainer, "validate", real)
    for _ in range(2):  # the second resume has nothing left to do
        assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["status"] == "done"
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2] and "validation" in rows(cfg.run_dir)[1]


def test_a_ctrl_c_at_any_point_of_an_update_neither_loses_nor_repeats_a_metrics_row(tmp_path, monkeypatch):
    """Three moments the log used to get wrong: while an update's row is being built (the row
    was lost), and right after a resumed run logged its pending row, while last.pt was being
    rewritten (the row came twice)."""
    cfg = tiny_config(tmp_path, updates=4, extra=["run.validate_every=1"])
    built = {"rows": 0}
    real_returns = trainer_module._mean_returns

    def ctrl_c_while_building_row_2(episodes):
        built["rows"] += 1
        if built["rows"] == 2:
            raise KeyboardInterrupt
        return real_returns(episodes)

    monkeypatch.setattr(trainer_module, "_mean_returns", ctrl_c_while_building_row_2)
    assert Trainer(cfg, log=lambda s: None).train()["status"] == "interrupted"
    monkeypatch.setattr(trainer_module, "_mean_returns", real_returns)
    assert [r["update"] for r in rows(cfg.run_dir)] == [1]

    real_validate = Trainer.validate
    validations = {"n": 0}

    def ctrl_c_in_the_second_validation(self):
        validations["n"] += 1
        if validations["n"] == 2:
            raise KeyboardInterrupt
        return real_validate(self)

    monkeypatch.setattr(Trainer, "validate", ctrl_c_in_the_second_validation)
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["status"] == "interrupted"
    monkeypatch.setattr(Trainer, "validate", real_validate)
    pending = load_checkpoint(cfg.run_dir / "last.pt")["pending_row"]
    assert pending and "validation" not in pending

    real_save = trainer_module.save_checkpoint
    once = {"done": False}

    def ctrl_c_while_writing_last_pt(path, payload):
        if str(path).endswith("last.pt") and not once["done"]:
            once["done"] = True
            raise KeyboardInterrupt
        return real_save(path, payload)

    monkeypatch.setattr(trainer_module, "save_checkpoint", ctrl_c_while_writing_last_pt)
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["status"] == "interrupted"
    monkeypatch.setattr(trainer_module, "save_checkpoint", real_save)
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).train()["status"] == "done"
    logged = rows(cfg.run_dir)
    assert [r["update"] for r in logged] == [1, 2, 3, 4]
    assert all("validation" in r for r in logged)  # validate_every 1: the re-logged rows were validated too


def test_a_ctrl_c_as_a_resumed_run_starts_reading_its_log_is_an_interrupt_that_frees_the_folder(tmp_path, monkeypatch):
    """train() wrote config.yaml, cut the log of a run stopped before its first checkpoint and read
    the log's last validation (the whole file: seconds for a long run) before its try: a Ctrl-C
    there left train() as a bare KeyboardInterrupt, with no word of how to resume, and left the run
    folder locked and the rerun stream open for the rest of the process."""
    cfg = tiny_config(tmp_path, updates=3)
    assert Trainer(tiny_config(tmp_path, updates=1), log=lambda s: None).train()["status"] == "done"

    def ctrl_c(self):
        raise KeyboardInterrupt

    monkeypatch.setattr(Trainer, "_logged_validation", ctrl_c)
    said: list[str] = []
    trainer = Trainer.resume(cfg.run_dir, total_steps=cfg.total_steps, log=said.append)
    try:
        status = trainer.train()["status"]
    except KeyboardInterrupt:  # (caught here: pytest itself stops on one)
        status = "a KeyboardInterrupt out of train()"
    assert status == "interrupted"
    assert f"continue with: pursuit-mj train --resume {cfg.run_dir}" in "\n".join(said), said
    monkeypatch.undo()
    resumed = Trainer.resume(cfg.run_dir, total_steps=cfg.total_steps, log=lambda s: None)  # the folder is free
    assert resumed.train()["counters"]["update"] == 3
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2, 3]


def test_a_ctrl_c_while_best_pt_is_written_leaves_the_counters_naming_the_best_pt_on_disk(tmp_path, monkeypatch):
    cfg = tiny_config(tmp_path, updates=3, extra=["run.validate_every=1"])
    real_validate = Trainer.validate

    def better_every_update(self):
        out = real_validate(self)
        out["success"] = self.counters.update / 10
        return out

    real_save = trainer_module.save_checkpoint

    def ctrl_c_writing_best_of_update_2(path, payload):
        if str(path).endswith("best.pt") and payload["counters"]["update"] == 2:
            raise KeyboardInterrupt
        return real_save(path, payload)

    monkeypatch.setattr(Trainer, "validate", better_every_update)
    monkeypatch.setattr(trainer_module, "save_checkpoint", ctrl_c_writing_best_of_update_2)
    assert Trainer(cfg, log=lambda s: None).train()["status"] == "interrupted"
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["best_update"] == 1  # what best.pt holds
    monkeypatch.setattr(trainer_module, "save_checkpoint", real_save)
    result = Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None).train()
    assert result["counters"]["best_update"] == 2 and load_checkpoint(cfg.run_dir / "best.pt")["counters"]["update"] == 2


def test_a_resume_with_nothing_left_to_train_says_which_limit_ended_the_run(tmp_path):
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    said = []
    Trainer.resume(cfg.run_dir, log=said.append).train()
    assert any("reached total_steps 32" in s and "--total-steps" in s for s in said)
    timed = tiny_config(tmp_path, name="timed", updates=100, extra=["max_minutes=0.0001"])
    assert Trainer(timed, log=lambda s: None).train()["counters"]["update"] == 1  # the time ran out first
    said = []
    result = Trainer.resume(timed.run_dir, total_steps=32 * 200, log=said.append).train()
    assert result["counters"]["update"] == 1
    assert any("max_minutes 0.0001" in s and "--max-minutes" in s for s in said)


def test_a_run_that_crashed_before_its_first_checkpoint_starts_afresh_with_its_log(tmp_path, monkeypatch):
    """A crash (or kill -9) before the first last.pt leaves rows but nothing to resume: the new
    start must not append its rows after them (the log read 1, 2, 1, 2)."""
    cfg = tiny_config(tmp_path, updates=10, extra=["run.checkpoint_every=10"])
    trainer = Trainer(cfg, log=lambda s: None)
    real, calls = trainer.collector.collect, {"n": 0}

    def crash_in_the_third_rollout(buffer):
        calls["n"] += 1
        if calls["n"] == 3:
            raise MemoryError
        return real(buffer)

    monkeypatch.setattr(trainer.collector, "collect", crash_in_the_third_rollout)
    with pytest.raises(MemoryError):
        trainer.train()
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2] and not (cfg.run_dir / "last.pt").exists()
    said = []
    assert Trainer(tiny_config(tmp_path, updates=2), log=said.append).train()["status"] == "done"
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2]
    assert "dropping 2 rows" in said[0]
    (cfg.run_dir / "last.pt").unlink()
    (cfg.run_dir / "best.pt").unlink()  # (kept, that run's best.pt would have this one refused: test_train_cli)
    (cfg.run_dir / "metrics.jsonl").write_text('{"update": 1, "world_st')  # killed while writing its first row
    Trainer(tiny_config(tmp_path, updates=1), log=lambda s: None).train()
    assert [r["update"] for r in rows(cfg.run_dir)] == [1]


def test_a_checkpoint_whose_entries_do_not_fit_is_refused_in_one_line_naming_it(tmp_path):
    """Entries of the wrong kind, weights, optimiser state, counters or random state that do not
    fit: each was a traceback (or a resume with a broken optimiser); a counter missing from an
    older layout keeps its default."""
    from train.checkpoint import save_checkpoint

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    good = load_checkpoint(cfg.run_dir / "last.pt")
    body = {k: v for k, v in good.items() if k not in ("format", "version")}
    moments = {"step": torch.tensor(1.0), "exp_avg": torch.zeros(1), "exp_avg_sq": torch.zeros(1)}
    for changes, words in (
        ({"actor": [1, 2]}, "entry actor is a list, not a dict"),
        ({"obs_spec": {}}, "obs_spec lacks"),
        ({"critic": {k: torch.zeros(1) for k in good["critic"]}}, "cannot resume from its critic weights \\(size mismatch"),
        ({"train_config": {**good["train_config"], "algo": "mappo"}}, "cannot resume from its critic weights"),
        ({"optimizer": {**good["optimizer"], "state": {0: moments}}}, "optimiser state .*shapes"),
        ({"rng": {"torch": good["rng"]["torch"]}}, "random state"),
        ({"counters": {**good["counters"], "update": "two"}}, "counter update is 'two'"),
        ({"counters": {**good["counters"], "old_counter": 1}}, "unknown counters \\['old_counter'\\]"),
    ):
        save_checkpoint(cfg.run_dir / "last.pt", {**body, **changes})
        with pytest.raises(ValueError, match=words) as err:
            Trainer.resume(cfg.run_dir, total_steps=96, log=lambda s: None)
        assert str(cfg.run_dir / "last.pt") in str(err.value) and "\n" not in str(err.value)
    save_checkpoint(cfg.run_dir / "last.pt", {k: v for k, v in body.items() if k != "rng"})
    with pytest.raises(ValueError, match=r"lacks \['rng'\], which a resume needs"):
        Trainer.resume(cfg.run_dir, log=lambda s: None)
    save_checkpoint(cfg.run_dir / "last.pt", {**body, "counters": {"update": 1, "world_steps": 32}})
    assert Trainer.resume(cfg.run_dir, log=lambda s: None).counters.validation_seconds == 0.0


def test_a_run_folder_that_cannot_be_written_is_refused_before_training_naming_it(tmp_path):
    """It was a NotADirectoryError traceback from deep inside the trainer (or after an update's work)."""
    from train.checkpoint import save_checkpoint

    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ValueError, match=f"run folder \\(run.runs_dir {blocker}, name run\\): cannot create") as err:
        Trainer(tiny_config(blocker), log=lambda s: None)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=f"checkpoint {blocker / 'last.pt'}: cannot write it"):
        save_checkpoint(blocker / "last.pt", {})


def test_a_run_whose_last_pt_is_damaged_is_told_how_to_go_on_from_its_intact_best_pt(tmp_path, capsys):
    from pursuit_cli import main

    cfg = tiny_config(tmp_path, updates=2, extra=["run.validate_every=1"])
    Trainer(cfg, log=lambda s: None).train()
    kept = (cfg.run_dir / "last.pt").read_bytes()
    (cfg.run_dir / "last.pt").unlink()
    assert main(["train", "--resume", str(cfg.run_dir)]) == 2
    assert f"no last.pt in {cfg.run_dir}; its best.pt (update" in capsys.readouterr().err
    (cfg.run_dir / "last.pt").write_bytes(kept)
    last = cfg.run_dir / "last.pt"
    last.write_bytes(last.read_bytes()[:1000])
    with pytest.raises(ValueError, match=f"checkpoint {last}: .*cut short.*; its best.pt \\(update [12]\\) is intact: copy it over last.pt"):
        Trainer.resume(cfg.run_dir, log=lambda s: None)
    (cfg.run_dir / "best.pt").write_text("")
    with pytest.raises(ValueError, match="cut short\\)$"):  # no advice when best.pt is damaged too
        Trainer.resume(cfg.run_dir, log=lambda s: None)


def test_a_run_folder_given_for_a_checkpoint_file_is_named_as_a_folder(tmp_path, capsys):
    """--init-from, --export and demo --model said 'no such checkpoint' / 'file not found' of a folder."""
    from pursuit_cli import main

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    folder = f"a folder, not a checkpoint file; did you mean {cfg.run_dir / 'best.pt'}\\?"
    with pytest.raises(ValueError, match=f"checkpoint {cfg.run_dir}: {folder}"):
        load_checkpoint(cfg.run_dir)
    with pytest.raises(ValueError, match=folder):
        Trainer(tiny_config(tmp_path, name="ft", extra=[f"init_from={cfg.run_dir}"]), log=lambda s: None)
    assert main(["demo", "-m", str(cfg.run_dir)]) == 2
    assert f"--model {cfg.run_dir}: a folder" in capsys.readouterr().err


def test_a_second_trainer_on_a_folder_in_use_is_refused_and_the_folder_is_free_after_the_first_ends(tmp_path):
    """Two runs in one folder (the same --resume in two terminals) would interleave their
    metrics rows and overwrite each other's checkpoints."""
    cfg = tiny_config(tmp_path, updates=1)
    first = Trainer(cfg, log=lambda s: None)
    with pytest.raises(ValueError, match=rf"run folder {cfg.run_dir} is in use by another trainer \(pid \d+\)"):
        Trainer(cfg, log=lambda s: None)
    assert first.train()["status"] == "done"  # ending a run frees its folder
    again = Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None)
    assert again.train()["counters"]["update"] == 2
    # a run that cannot start frees the folder too
    (cfg.run_dir / "last.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError):
        Trainer(cfg, checkpoint={"counters": {"bogus": 1}}, log=lambda s: None)
    Trainer(tiny_config(tmp_path, updates=1), log=lambda s: None).close()


def test_a_checkpoint_written_before_a_setting_existed_resumes_saying_which_defaults_it_took(tmp_path):
    """A stored train_config missing a whole section (or a key) was filled with today's defaults without a word."""
    from train.checkpoint import save_checkpoint

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    good = load_checkpoint(cfg.run_dir / "last.pt")
    body = {k: v for k, v in good.items() if k not in ("format", "version")}
    old = {k: v for k, v in good["train_config"].items() if k != "imitation"}
    old["ppo"] = {k: v for k, v in old["ppo"].items() if k != "vf_coef"}
    save_checkpoint(cfg.run_dir / "last.pt", {**body, "train_config": old})
    said: list[str] = []
    resumed = Trainer.resume(cfg.run_dir, total_steps=96, log=said.append)
    assert resumed.cfg.imitation == cfg.imitation and resumed.cfg.ppo.vf_coef == cfg.ppo.vf_coef
    notes = [s for s in said if s.startswith("note:")]
    assert len(notes) == 1 and "resumes with today's defaults for them: ppo.vf_coef, imitation" in notes[0], said
    resumed.close()
    save_checkpoint(cfg.run_dir / "last.pt", body)  # a whole config: nothing to say
    said.clear()
    Trainer.resume(cfg.run_dir, total_steps=96, log=said.append).close()
    assert not [s for s in said if s.startswith("note:")]


def test_a_diverged_update_is_refused_before_a_checkpoint_holds_its_nan_weights(tmp_path, monkeypatch):
    """A run whose weights went NaN saved them over a good last.pt (which then could not be loaded)
    and stopped one rollout later on 'actions: non-finite value nan'."""
    weights_go_nan_at_update(monkeypatch, 2)
    cfg = tiny_config(tmp_path, updates=3)
    with pytest.raises(ValueError, match=r"training diverged at update 2: the weights actor.log_std are no longer finite "
                                         r"\(losses: .*\); .*last.pt keeps update 1, from which a new run can start "
                                         r"\(--init-from .*last.pt --set ppo.lr=...\). Try a lower ppo.lr"):
        Trainer(cfg, log=lambda s: None).train()
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 1
    assert [r["update"] for r in rows(cfg.run_dir)] == [1]


@pytest.mark.parametrize("blocked", ["folder", "folder mid-update", "log"])
def test_a_run_folder_that_cannot_be_written_stops_the_run_saying_what_is_kept_and_how_to_go_on(tmp_path, make_unwritable, blocked):
    """A full disk or a folder made read-only: the run's config (folder, at the start), its
    checkpoint (folder mid-update) or its metrics row (log) cannot be written. The run stops
    naming the file, the update last.pt keeps and the resume command."""
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    trainer = Trainer.resume(cfg.run_dir, total_steps=32 * 3, log=lambda s: None)
    if blocked == "folder mid-update":  # after config.yaml is written, during the next update
        update = trainer.train_one_update

        def update_then_block():
            row = update()
            make_unwritable(cfg.run_dir)
            return row

        trainer.train_one_update = update_then_block
    else:
        make_unwritable(cfg.run_dir if blocked == "folder" else cfg.run_dir / "metrics.jsonl")
    with pytest.raises(ValueError) as caught:
        trainer.train()
    said = str(caught.value)
    what = {"folder": f"{cfg.run_dir / 'config.yaml'}: cannot write it",
            "folder mid-update": f"checkpoint {cfg.run_dir / 'last.pt'}: cannot write it",
            "log": f"metrics log {cfg.run_dir / 'metrics.jsonl'}: cannot append to it"}[blocked]
    assert said.startswith(what), said
    assert said.endswith(f"; last.pt keeps update 1; once the folder has room and write access, continue with: "
                         f"pursuit-mj train --resume {cfg.run_dir}"), said
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 1


def test_a_resume_from_a_last_pt_older_than_best_pt_does_not_replace_it_with_a_worse_one(tmp_path, monkeypatch):
    """A crash (kill -9, a full disk) after best.pt of update 2 was written but before last.pt
    was: the resumed run starts from update 1, whose counters know an older best. best.pt
    holds a better policy than the redone update 2's; it must stay, and the counters name it."""
    cfg = tiny_config(tmp_path, updates=2, extra=["run.validate_every=1"])
    real_validate = Trainer.validate
    scripted = iter([0.1, 0.9, 0.5])  # update 1, update 2 (then the crash), update 2 again

    def scripted_success(self):
        out = real_validate(self)
        out["success"] = next(scripted)
        return out

    real_append = trainer_module.MetricsLog.append

    def crash_logging_update_2(self, row):
        if row["update"] == 2:
            raise MemoryError
        return real_append(self, row)

    monkeypatch.setattr(Trainer, "validate", scripted_success)
    monkeypatch.setattr(trainer_module.MetricsLog, "append", crash_logging_update_2)
    with pytest.raises(MemoryError):
        Trainer(cfg, log=lambda s: None).train()
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 1
    assert load_checkpoint(cfg.run_dir / "best.pt")["counters"]["best_success"] == 0.9
    monkeypatch.setattr(trainer_module.MetricsLog, "append", real_append)
    result = Trainer.resume(cfg.run_dir, log=lambda s: None).train()
    assert load_checkpoint(cfg.run_dir / "best.pt")["counters"]["best_success"] == 0.9
    assert result["counters"]["best_success"] == 0.9 and result["counters"]["best_update"] == 2
    assert [r["validation"]["best"] for r in rows(cfg.run_dir)] == [True, False]


@pytest.fixture
def file_size_limit():
    """`with file_size_limit(n):` no file of this process grows past n bytes inside the block (a
    full disk, as a write sees it: the write fails with an OSError; root is bound too). The limit
    is lifted as the block ends, before pytest reports the test: that report is a write too, and
    with the output going to a file (pytest ... > log) it failed and ended the whole session."""
    import contextlib
    import resource
    import signal

    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # else the write kills the process

    @contextlib.contextmanager
    def limited(n: int):
        resource.setrlimit(resource.RLIMIT_FSIZE, (n, hard))
        try:
            yield
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))

    yield limited
    resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    signal.signal(signal.SIGXFSZ, previous)


def test_the_full_disk_tests_run_with_their_output_going_to_a_file(tmp_path):
    """Their limit on file sizes held until the test ended, so pytest's own report of the test,
    written to a file (pytest -q ... > log), hit it: 'OSError: [Errno 27] File too large' and an
    INTERNALERROR ended the session."""
    import subprocess
    import sys

    log = tmp_path / "pytest.log"
    with open(log, "w") as out:
        rc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", __file__, "-k",
                             "cuts_the_metrics_log_in_place or new_run_on_a_full_disk"],
                            stdout=out, stderr=subprocess.STDOUT, cwd=Path(__file__).parent.parent).returncode
    said = log.read_text()
    assert rc == 0 and "File too large" not in said and said.startswith(".."), said[-2000:]


def test_a_checkpoint_that_does_not_fit_on_the_disk_stops_the_run_naming_it_and_keeps_the_one_before(tmp_path, file_size_limit):
    """torch reports a failed write (a full disk) as a bare RuntimeError: the run must still say
    which file could not be written and what last.pt keeps, not end in torch's traceback."""
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    trainer = Trainer.resume(cfg.run_dir, total_steps=32 * 3, log=lambda s: None)
    with file_size_limit((cfg.run_dir / "last.pt").stat().st_size // 2), pytest.raises(ValueError) as caught:
        trainer.train()  # the log and config.yaml still fit
    said = str(caught.value)
    assert said.startswith(f"checkpoint {cfg.run_dir / 'last.pt'}: cannot write it ("), said
    assert said.endswith(f"; last.pt keeps update 1; once the folder has room and write access, continue with: "
                         f"pursuit-mj train --resume {cfg.run_dir}"), said
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 1
    assert not [p.name for p in cfg.run_dir.iterdir() if ".part" in p.name]


def test_a_save_cut_short_by_kill_9_leaves_no_temporary_file_behind_once_the_run_goes_on(tmp_path):
    """kill -9 during a save leaves its temporary file (as large as a checkpoint) beside last.pt;
    the next trainer in the folder removes it, and nothing else."""
    import subprocess
    import sys

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    cut_short = ("import os, sys; from pursuit_mj.io_utils import atomic_path\n"
                 "with atomic_path(sys.argv[1]) as tmp:\n    tmp.write_bytes(b'half a checkpoint'); os._exit(9)")
    subprocess.run([sys.executable, "-c", cut_short, str(cfg.run_dir / "last.pt")], check=False,
                   cwd=Path(__file__).resolve().parents[1])
    (left,) = [p for p in cfg.run_dir.iterdir() if ".part" in p.name]
    (cfg.run_dir / "notes.part.txt").write_text("the user's")
    said = []
    Trainer.resume(cfg.run_dir, total_steps=32 * 2, log=said.append).train()
    assert not left.exists() and (cfg.run_dir / "notes.part.txt").is_file()
    assert any(left.name in line for line in said), said
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 2


def test_a_checkpoint_whose_spec_config_or_pending_row_is_of_the_wrong_kind_is_refused_in_one_line_naming_it(tmp_path):
    """A file that passes its checksums but whose obs_spec, train_config sections, pending row or
    counters are of the wrong kind (damaged, hand-edited, written by other code) ended resume and
    load_policy in a TypeError traceback (or a message naming no file)."""
    from train.checkpoint import save_checkpoint

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    path = cfg.run_dir / "last.pt"
    good = load_checkpoint(path)
    body = {k: v for k, v in good.items() if k not in ("format", "version")}
    for changes, words, resume_only in (
        ({"obs_spec": {**good["obs_spec"], "groups": 5}}, "obs_spec entry groups is not a list", False),
        ({"obs_spec": {**good["obs_spec"], "groups": [1, 2]}}, "obs_spec entry groups is not a list", False),
        ({"obs_spec": {**good["obs_spec"], "n_rays": "8"}}, "obs_spec entry n_rays is '8', not a whole number", False),
        ({"train_config": {**good["train_config"], "task": 3}}, "train_config entry task is a int, not a dict", False),
        ({"pending_row": [1, 2]}, "entry pending_row is a list, not a dict", False),
        ({"counters": {**good["counters"], "update": -5}}, "counter update is -5, expected at least 0", True),
    ):
        save_checkpoint(path, {**body, **changes})
        loads = [lambda: Trainer.resume(cfg.run_dir, total_steps=96, log=lambda s: None)]
        if not resume_only:
            loads.append(lambda: load_policy(path, ObsSpec.make(2, 1, 16)))
        for load in loads:
            with pytest.raises(ValueError, match=words) as err:
                load()
            assert str(err.value).startswith(f"checkpoint {path}: ") and "\n" not in str(err.value)


def test_a_run_refused_at_the_start_leaves_no_folder_it_made(tmp_path):
    """A missing --init-from checkpoint left runs/<name>/ holding only .lock, which a later
    `--resume` then took for a run ("no last.pt in ...")."""
    missing = tmp_path / "nope" / "best.pt"
    cfg = tiny_config(tmp_path, name="refused", extra=[f"init_from={missing}"])
    with pytest.raises(ValueError, match="no such checkpoint"):
        Trainer(cfg, log=lambda s: None)
    assert not cfg.run_dir.exists()
    # a folder the user made (or an earlier run) is left where it was, with what it held
    cfg.run_dir.mkdir()
    (cfg.run_dir / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="no such checkpoint"):
        Trainer(cfg, log=lambda s: None)
    assert sorted(p.name for p in cfg.run_dir.iterdir()) == ["notes.txt"]  # and no .lock of the refused run in it
    # nor the folders made on the way to it: run.runs_dir=a/b of a run refused left a/b
    deep = load_train_config([], TINY + [f"run.runs_dir={tmp_path / 'a' / 'b'}", "name=x", f"init_from={missing}"])
    with pytest.raises(ValueError, match="no such checkpoint"):
        Trainer(deep, log=lambda s: None)
    assert not (tmp_path / "a").exists()


def test_a_run_on_a_layout_file_resumes_from_any_folder_and_not_on_a_changed_file(tmp_path, monkeypatch):
    """The stored config kept the path as typed: a relative one failed to load when the run was
    resumed from another folder; and a layout file edited in between was trained on silently."""
    from pursuit_mj.layout import builtin_layout_path

    start, elsewhere = tmp_path / "start", tmp_path / "elsewhere"
    start.mkdir(), elsewhere.mkdir()
    (start / "arena.yaml").write_text(builtin_layout_path(1).read_text())
    monkeypatch.chdir(start)
    cfg = tiny_config(tmp_path, updates=1, extra=["task.layout=arena.yaml", "layouts=[arena.yaml, 0]"])
    Trainer(cfg, log=lambda s: None).train()
    stored = load_checkpoint(cfg.run_dir / "last.pt")["train_config"]
    assert (stored["task"]["layout"], stored["layouts"]) == (str(start / "arena.yaml"), [str(start / "arena.yaml"), 0])
    monkeypatch.chdir(elsewhere)
    assert Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None).train()["counters"]["update"] == 2
    (start / "arena.yaml").write_text(builtin_layout_path(2).read_text())
    with pytest.raises(ValueError, match=rf"--resume {cfg.run_dir}: layout file {start / 'arena.yaml'} \(task.layout\) "
                                         r"has changed since the run started"):
        Trainer.resume(cfg.run_dir, total_steps=96, log=lambda s: None)


def test_a_resume_says_which_rows_its_metrics_log_has_lost(tmp_path):
    """A deleted (or cut) metrics.jsonl went unnoticed: the log went on from the next update."""
    cfg = tiny_config(tmp_path, updates=2)
    Trainer(cfg, log=lambda s: None).train()
    (cfg.run_dir / "metrics.jsonl").unlink()
    said = []
    Trainer.resume(cfg.run_dir, total_steps=32 * 3, log=said.append).train()
    assert any("metrics.jsonl lacks the rows of updates 1-2" in line for line in said), said
    assert [r["update"] for r in rows(cfg.run_dir)] == [3]


def test_a_last_pt_older_than_the_log_is_refused_rather_than_cutting_the_log(tmp_path):
    """A last.pt copied in from another run (or an old copy put back) made the resume cut the
    metrics log back to that checkpoint's update: the rows of every later update were lost."""
    old = tiny_config(tmp_path, name="other", updates=1)
    Trainer(old, log=lambda s: None).train()
    cfg = tiny_config(tmp_path, updates=4)
    Trainer(cfg, log=lambda s: None).train()
    log_before = (cfg.run_dir / "metrics.jsonl").read_text()
    (cfg.run_dir / "last.pt").write_bytes((old.run_dir / "last.pt").read_bytes())
    with pytest.raises(ValueError, match=r"last.pt is at update 1, but metrics.jsonl holds the rows of updates 2-4: "
                                         r"it is not this run's latest checkpoint"):
        Trainer.resume(cfg.run_dir, total_steps=32 * 6, log=lambda s: None)
    assert (cfg.run_dir / "metrics.jsonl").read_text() == log_before
    (cfg.run_dir / "metrics.jsonl").rename(cfg.run_dir / "metrics.old.jsonl")  # the way out it names
    assert Trainer.resume(cfg.run_dir, total_steps=32 * 2, log=lambda s: None).train()["counters"]["update"] == 2


def test_a_run_stopped_before_its_first_checkpoint_says_there_is_nothing_to_resume(tmp_path, monkeypatch):
    """It said 'state of update -1 is in .../last.pt; continue with --resume', and there was no last.pt."""
    def stopped(*args, **kwargs):  # Ctrl-C in the first update's gradient steps, its state half changed
        raise KeyboardInterrupt

    monkeypatch.setattr(trainer_module, "ppo_update", stopped)
    lines: list[str] = []
    cfg = tiny_config(tmp_path)
    result = Trainer(cfg, log=lines.append).train()
    assert result["status"] == "interrupted" and not (cfg.run_dir / "last.pt").exists()
    said = "\n".join(lines)
    assert "interrupted before the first checkpoint: nothing to resume" in said and "--resume" not in said


@pytest.mark.parametrize("damage", ["missing", "cut short"])
def test_a_resume_whose_best_pt_is_lost_says_so_and_writes_a_new_one_at_its_next_validation(tmp_path, damage):
    """The counters kept naming a best.pt that was gone or damaged, and it stayed so until a later
    validation beat the lost record (perhaps never): the run ended with no usable best.pt."""
    cfg = tiny_config(tmp_path, updates=2, extra=["run.validate_every=1"])
    Trainer(cfg, log=lambda s: None).train()
    best = cfg.run_dir / "best.pt"
    if damage == "missing":
        best.unlink()
    else:
        best.write_bytes(best.read_bytes()[:1000])
    said: list[str] = []
    trainer = Trainer.resume(cfg.run_dir, total_steps=32 * 3, log=said.append)
    assert trainer.counters.best_update == -1 and trainer.counters.best_success == -1
    note = [line for line in said if "best.pt" in line]
    assert note and f"{best}" in note[0] and "the next validation writes a new one" in note[0], said
    trainer.train()
    assert load_checkpoint(best)["counters"]["best_update"] == 3


def test_a_damaged_last_pt_replaced_by_the_runs_own_best_pt_resumes_from_it_as_the_hint_says(tmp_path, monkeypatch):
    """The hint for a damaged last.pt ('copy best.pt over it') led to a refusal: the metrics log
    held the rows of the updates after best.pt's, which looked like a last.pt from another run."""
    cfg = tiny_config(tmp_path, updates=4, extra=["run.validate_every=1"])
    real_validate = Trainer.validate

    def best_at_update_2(self):
        out = real_validate(self)
        out["success"] = 0.9 if self.counters.update == 2 else 0.1
        return out

    monkeypatch.setattr(Trainer, "validate", best_at_update_2)
    Trainer(cfg, log=lambda s: None).train()
    last, best = cfg.run_dir / "last.pt", cfg.run_dir / "best.pt"
    last.write_bytes(last.read_bytes()[:1000])
    with pytest.raises(ValueError, match="copy it over last.pt"):
        Trainer.resume(cfg.run_dir, log=lambda s: None)
    last.write_bytes(best.read_bytes())
    said: list[str] = []
    result = Trainer.resume(cfg.run_dir, log=said.append).train()
    assert result["counters"]["update"] == 4
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2, 3, 4]
    assert any("last.pt is this run's best.pt (update 2)" in line and "updates 2-4" in line for line in said), said
    assert load_checkpoint(best)["counters"]["best_update"] == 2


def test_a_checkpoint_with_a_huge_update_count_resumes_without_exhausting_memory(tmp_path):
    """The lost-rows check built the set of every update number up to the checkpoint's count: a
    damaged or hand-edited count of 3e8 took gigabytes and ended in a MemoryError."""
    from train.checkpoint import save_checkpoint

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    data = load_checkpoint(cfg.run_dir / "last.pt")
    data["counters"]["update"] = 10 ** 12
    save_checkpoint(cfg.run_dir / "last.pt", {k: v for k, v in data.items() if k not in ("format", "version")})
    said: list[str] = []
    trainer = Trainer.resume(cfg.run_dir, log=said.append)
    assert trainer.counters.update == 10 ** 12
    assert any(f"lacks the rows of updates 2-{10 ** 12} ({10 ** 12 - 1} of them)" in line
               or f"lacks the rows of updates 2-{10 ** 12}" in line for line in said), said


def test_missing_updates_names_the_gaps_without_listing_every_number():
    from train.metrics_log import missing_updates

    assert missing_updates({1, 2, 3}, 3) is None
    assert missing_updates(set(), 0) is None
    assert missing_updates({2, 3}, 3) == (1, 1, 1)
    assert missing_updates({1, 3}, 5) == (2, 5, 3)
    assert missing_updates({1, 5, 9}, 10 ** 15) == (2, 10 ** 15, 10 ** 15 - 3)
    assert missing_updates({7, 8}, 3) == (1, 3, 3)  # rows past the count are not the count's


def test_a_resume_cuts_the_metrics_log_in_place_without_room_for_a_second_copy(tmp_path, file_size_limit):
    """The resume rewrote the whole log into a temporary file even when nothing was dropped: on a
    full disk a resume failed for want of room for a second copy of metrics.jsonl."""
    from train.metrics_log import MetricsLog

    log = MetricsLog(tmp_path / "metrics.jsonl")
    for u in (1, 2, 3):
        log.append({"update": u, "loss": 0.5})
    with open(log.path, "a") as f:
        f.write('{"update": 4, "lo')  # a row cut short by a kill
    with file_size_limit(0):  # no file can grow: a copy of the log cannot be written
        log.truncate_after(3)
        assert log.path.read_text().splitlines()[-1] == '{"update": 3, "loss": 0.5}' and log.path.read_text().endswith("\n")
        log.truncate_after(2)
        assert [r["update"] for r in log.rows()] == [1, 2]
        log.truncate_after(5)
        assert [r["update"] for r in log.rows()] == [1, 2]
    assert not [p.name for p in tmp_path.iterdir() if ".part" in p.name]


def test_a_new_run_on_a_full_disk_is_refused_in_one_line_and_leaves_no_folder(tmp_path, file_size_limit):
    """The folder's lock file could not be written: an OSError traceback from lock_run_folder."""
    cfg = tiny_config(tmp_path, updates=1)
    with file_size_limit(0), pytest.raises(ValueError) as caught:
        Trainer(cfg, log=lambda s: None)
    said = str(caught.value)
    assert said.startswith(f"run folder {cfg.run_dir}: cannot write its lock file") and "\n" not in said, said
    assert not cfg.run_dir.exists()


def test_a_run_refused_because_another_trainer_holds_its_folder_leaves_that_folder_alone(tmp_path, monkeypatch):
    """The folder did not exist when this run looked, and another trainer made and locked it just
    after: the refusal removed the other trainer's folder while it ran."""
    cfg = tiny_config(tmp_path, updates=1)
    real_lock = trainer_module.lock_run_folder
    held = {}

    def another_trainer_first(run_dir):
        held["lock"] = real_lock(run_dir)  # the other trainer, between this one's look and its lock
        (run_dir / "config.yaml").write_text("the other run's")
        return real_lock(run_dir)

    monkeypatch.setattr(trainer_module, "lock_run_folder", another_trainer_first)
    with pytest.raises(ValueError, match="is in use by another trainer"):
        Trainer(cfg, log=lambda s: None)
    assert (cfg.run_dir / "config.yaml").read_text() == "the other run's"
    held["lock"].close()


def test_cutting_the_metrics_log_keeps_what_its_reader_reads(tmp_path):
    """In place, a whole last row without its newline was dropped, a file of bare-CR lines was cut
    to nothing, and a row numbered 7.0 after the cut was kept (and then logged twice)."""
    from train.metrics_log import MetricsLog

    log = MetricsLog(tmp_path / "m.jsonl")
    log.path.write_bytes(b'{"update": 1}\n{"update": 2}\n{"update": 3}')
    log.truncate_after(3)
    assert [r["update"] for r in log.rows()] == [1, 2, 3] and log.path.read_bytes().endswith(b"\n")
    log.append({"update": 4})
    assert [r["update"] for r in log.rows()] == [1, 2, 3, 4]
    log.path.write_bytes(b'{"update": 1}\r{"update": 2}\r')
    log.truncate_after(2)
    assert [r["update"] for r in log.rows()] == [1, 2]
    log.path.write_bytes(b'{"update": 1}\n{"update": 7.0}\n')
    log.truncate_after(1)
    assert [r["update"] for r in log.rows()] == [1]


def test_a_run_stored_with_an_idle_layout_index_beside_random_layout_resumes():
    """Versions before 2026-12-06 accepted task.layout=2 with random_layout and stored it; the check
    that now refuses that as input refused such a run's checkpoint, and nobody can edit one."""
    from pursuit_mj.configio import to_dict
    from train.config import train_config_from_dict

    stored = to_dict(load_train_config([], ["task.random_layout=true"]))
    stored["task"]["layout"] = 2  # as the old code wrote it
    cfg = train_config_from_dict(json.loads(json.dumps(stored)), "checkpoint x.pt: train_config")
    assert cfg.task.random_layout and cfg.task.layout == 0
    with pytest.raises(ValueError, match="layout 2 would be ignored"):  # as input it stays refused
        load_train_config([], ["task.random_layout=true", "task.layout=2"])


def test_init_from_a_checkpoint_of_another_network_names_both_networks(tmp_path):
    """A run started from a checkpoint of another net.kind or widths is refused naming the
    stored network and this run's, and which keys to set, not with torch's list of keys."""
    src = tiny_config(tmp_path, name="flat", updates=1, extra=["net.kind=mlp", "net.hidden=[16]"])
    Trainer(src, log=lambda s: None).train()
    path = src.run_dir / "best.pt"
    with pytest.raises(ValueError, match=r"init_from .*best.pt: its actor is net.kind mlp, net.hidden \[16\]; "
                                         r"this run builds net.kind reference, net.hidden \[128, 128\]"):
        Trainer(tiny_config(tmp_path, name="ft", extra=[f"init_from={path}"]), log=lambda s: None)
    same = Trainer(tiny_config(tmp_path, name="ft2", extra=[f"init_from={path}", "net.kind=mlp", "net.hidden=[16]"]),
                   log=lambda s: None)
    assert torch.equal(same.model.actor.head.weight, load_checkpoint(path)["actor"]["head.weight"])


def test_init_from_compares_only_the_net_keys_the_networks_weights_depend_on(tmp_path):
    """net.kind mlp has no entity encoders: a run of another encoder_width or use_rays builds the
    same weights, and --init-from refused it ('its actor is net.encoder_width 128; this run builds
    net.encoder_width 64'), though the weights load."""
    src = tiny_config(tmp_path, name="flat", updates=1, extra=["net.kind=mlp", "net.hidden=[16]"])
    Trainer(src, log=lambda s: None).train()
    path = src.run_dir / "best.pt"
    same = Trainer(tiny_config(tmp_path, name="ft", extra=[f"init_from={path}", "net.kind=mlp", "net.hidden=[16]",
                                                           "net.encoder_width=64", "net.use_rays=false"]), log=lambda s: None)
    assert torch.equal(same.model.actor.head.weight, load_checkpoint(path)["actor"]["head.weight"])
    with pytest.raises(ValueError, match=r"its actor is net.hidden \[16\]; this run builds net.hidden \[8\]"):
        Trainer(tiny_config(tmp_path, name="ft2", extra=[f"init_from={path}", "net.kind=mlp", "net.hidden=[8]"]), log=lambda s: None)


def test_the_checkpoint_docstring_names_every_entry_a_training_checkpoint_holds(tmp_path):
    """train/checkpoint.py's docstring is the file's contract: it named an rng entry of 'numpy
    state as JSON text' that no checkpoint held, and left out entries every one holds."""
    import re

    import train.checkpoint as checkpoint_module

    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    data = load_checkpoint(cfg.run_dir / "last.pt")
    listed = {}
    for line in checkpoint_module.__doc__.splitlines():
        m = re.match(r"    (\w+(?:, \w+)*)\s{2,}(.*)", line)
        if m:
            listed.update({key: m.group(2) for key in m.group(1).split(", ")})
    assert set(data) <= set(listed), sorted(set(data) - set(listed))
    assert set(data["rng"]) == {"sampler", "torch"}
    assert all(k in listed["rng"] for k in data["rng"]) and "numpy" not in listed["rng"], listed["rng"]


def test_a_log_line_that_is_json_but_not_a_row_is_skipped_like_a_line_cut_short(tmp_path):
    """A line of metrics.jsonl that parses as JSON but is no object ([1], 7, null: garbled or
    hand-edited) was returned by MetricsLog.rows(), and every reader calls row.get: --resume
    ended in "AttributeError: 'list' object has no attribute 'get'", and so did cutting a log
    whose later row sat inside the file."""
    from train.metrics_log import MetricsLog

    log = MetricsLog(tmp_path / "m.jsonl")
    log.path.write_bytes(b'{"update": 1}\n[1]\n7\nnull\n{"update": 5}\n{"update": 2}\n')
    assert [r["update"] for r in log.rows()] == [1, 5, 2]
    log.truncate_after(2)  # row 5 inside the file: the log is rewritten from its rows
    assert [r["update"] for r in log.rows()] == [1, 2]


def test_a_log_row_whose_update_is_no_number_is_skipped_like_a_garbled_line(tmp_path):
    """{"update": null} (a hand edit) was returned as a row, and readers compare its update with a number."""
    from train.metrics_log import MetricsLog

    log = MetricsLog(tmp_path / "m.jsonl")
    log.path.write_bytes(b'{"update": 1}\n{"update": null}\n{"update": "2"}\n{"update": true}\n{"update": 3}\n')
    assert [r["update"] for r in log.rows()] == [1, 3]


@pytest.mark.parametrize("line", ["[1]", '{"update": null}'])
def test_a_resume_goes_on_past_a_stray_line_at_the_logs_end(tmp_path, line):
    """Such a line ended --resume in an AttributeError ([1]) or a TypeError (null) from deep in
    Trainer._restore; now the resume drops it as it drops a line cut short."""
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    with open(cfg.run_dir / "metrics.jsonl", "a") as f:
        f.write(line + "\n")
    assert Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None).train()["counters"]["update"] == 2
    assert [r["update"] for r in rows(cfg.run_dir)] == [1, 2]


def test_a_second_ctrl_c_during_the_interrupts_save_still_says_how_to_go_on(tmp_path, monkeypatch):
    """Ctrl-C, then Ctrl-C again while the interrupted run saved its last update: the second one
    escaped train() and nothing said what last.pt kept or how to resume. Now it cuts the save
    (last.pt stays the one before, whole) and the run says so."""
    cfg = tiny_config(tmp_path, updates=10, extra=["run.checkpoint_every=2"])
    lines = []
    trainer = Trainer(cfg, log=lines.append)
    calls = {"collect": 0}
    real_collect = trainer.collector.collect

    def collect(*args, **kwargs):
        calls["collect"] += 1
        if calls["collect"] == 4:  # update 3 is done, last.pt holds update 2
            monkeypatch.setattr(trainer, "save", second_ctrl_c)
            raise KeyboardInterrupt
        return real_collect(*args, **kwargs)

    def second_ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(trainer.collector, "collect", collect)
    assert trainer.train()["status"] == "interrupted"
    said = "\n".join(lines)
    assert f"interrupted: state of update 2 is in {cfg.run_dir / 'last.pt'}; continue with: pursuit-mj train --resume" in said, said
    assert load_checkpoint(cfg.run_dir / "last.pt")["counters"]["update"] == 2
    monkeypatch.undo()
    assert Trainer.resume(cfg.run_dir, total_steps=32 * 4, log=lambda s: None).train()["counters"]["update"] == 4


def test_best_pt_holds_its_updates_validation_so_a_copy_over_last_pt_resumes_without_validating_again(tmp_path):
    """best.pt was written before its update's row held the validation that made it best, so a resume
    from it (best_instead advises copying it over a damaged last.pt) validated that update again and
    logged it with best false."""
    cfg = tiny_config(tmp_path, updates=1)  # validate_every 0: the closing validation of update 1 makes it best
    Trainer(cfg, log=lambda s: None).train()
    best = load_checkpoint(cfg.run_dir / "best.pt")
    assert best["pending_row"]["validation"]["best"] is True
    shutil.copyfile(cfg.run_dir / "best.pt", cfg.run_dir / "last.pt")
    (cfg.run_dir / "metrics.jsonl").write_text("")  # as if the row never reached the log
    resumed = Trainer.resume(cfg.run_dir, log=lambda s: None)
    validated = []
    resumed.validate = lambda: validated.append(1) or {}
    resumed.train()
    assert validated == [] and [r["validation"]["best"] for r in rows(cfg.run_dir)] == [True]


def test_a_resume_reads_last_pt_only_once_it_holds_the_folder(tmp_path, monkeypatch):
    """Trainer.resume read last.pt before it took the folder's lock: a trainer of the same folder
    that saved and ended in between left the resume one checkpoint behind (and it then
    overwrote the newer last.pt)."""
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    real_load = trainer_module.load_checkpoint
    seen = {}

    def load_and_try_the_lock(path):
        try:
            trainer_module.lock_run_folder(cfg.run_dir).close()
            seen[Path(path).name] = "free"  # another trainer could still write last.pt after this read
        except ValueError:
            seen[Path(path).name] = "held"
        return real_load(path)

    monkeypatch.setattr(trainer_module, "load_checkpoint", load_and_try_the_lock)
    resumed = Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None)
    assert seen["last.pt"] == "held"
    with pytest.raises(ValueError, match="is in use by another trainer"):
        Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None)  # refused, the folder left to the first
    assert resumed.train()["counters"]["update"] == 2
    monkeypatch.setattr(trainer_module, "load_checkpoint", real_load)
    (cfg.run_dir / "last.pt").write_bytes(b"damaged")
    with pytest.raises(ValueError):
        Trainer.resume(cfg.run_dir, log=lambda s: None)
    # a refused resume frees the folder:
    trainer_module.lock_run_folder(cfg.run_dir).close()
    with pytest.raises(ValueError):
        Trainer.resume(tmp_path / "no_such_run", log=lambda s: None)
    assert not (tmp_path / "no_such_run").exists()  # and makes no folder of a mistyped name


def test_a_mappo_resume_from_a_checkpoint_without_value_statistics_says_they_start_afresh(tmp_path):
    """A MAPPO last.pt with no value statistics (an older or hand-edited file) resumed silently
    with fresh ones: its critic's outputs then meant other returns than it learned."""
    from train.checkpoint import save_checkpoint

    cfg = tiny_config(tmp_path, updates=1, extra=["algo=mappo"])
    Trainer(cfg, log=lambda s: None).train()
    data = load_checkpoint(cfg.run_dir / "last.pt")
    assert data["value_norm"]
    said = []
    Trainer.resume(cfg.run_dir, log=said.append).close()
    assert not [line for line in said if "value statistics" in line]
    data.pop("value_norm")
    save_checkpoint(cfg.run_dir / "last.pt", {k: v for k, v in data.items() if k not in ("format", "version")})
    Trainer.resume(cfg.run_dir, log=said.append).close()
    assert [line for line in said if "holds no value statistics" in line and "starts afresh" in line], said


def test_a_resume_of_a_folder_without_last_pt_leaves_no_lock_file_in_it(tmp_path):
    # since resume took the folder's lock before reading last.pt, Trainer.resume of a folder that
    # holds no run (a wrong folder given from Python) left a '.lock' file of its own in it
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "a.txt").write_text("mine")
    with pytest.raises(ValueError, match="last.pt"):
        Trainer.resume(folder, log=lambda s: None)
    assert sorted(p.name for p in folder.iterdir()) == ["a.txt"]


def test_a_mappo_run_started_from_a_mappo_checkpoint_without_value_statistics_says_they_start_afresh(tmp_path):
    """The resume of such a file says so (03a13e9); init_from loaded its critic and went on with
    fresh statistics without a word, so the critic's outputs meant other returns than it learned."""
    from train.checkpoint import save_checkpoint

    src = tiny_config(tmp_path, name="src", updates=1, extra=["algo=mappo"])
    Trainer(src, log=lambda s: None).train()
    data = load_checkpoint(src.run_dir / "last.pt")
    said = []
    Trainer(tiny_config(tmp_path, name="a", updates=1, extra=["algo=mappo", f"init_from={src.run_dir / 'last.pt'}"]),
            log=said.append).close()
    assert not [line for line in said if "value statistics" in line], said
    data.pop("value_norm")
    bare = tmp_path / "bare.pt"
    save_checkpoint(bare, {k: v for k, v in data.items() if k not in ("format", "version")})
    Trainer(tiny_config(tmp_path, name="b", updates=1, extra=["algo=mappo", f"init_from={bare}"]), log=said.append).close()
    assert [line for line in said if "holds no value statistics" in line and "starts afresh" in line], said


def test_a_lock_taken_on_a_lock_file_removed_meanwhile_is_taken_again_on_the_file_there(tmp_path, monkeypatch):
    """A run or study that cannot start removes the lock file it made, then lets the lock go. Another
    one that had opened that file just before, and locked it just after, held a lock on a file no
    longer there: a third then made a new lock file, locked it too, and both ran in one folder. The
    lock must be held on the file the folder names."""
    import fcntl
    import os
    from train.folder_lock import lock_folder

    lock_file = tmp_path / ".lock"
    real_flock = fcntl.flock
    calls = []

    def flock_after_removal(handle, op):  # the first holder removed the file between our open and our lock
        if not calls:
            lock_file.unlink()
        calls.append(op)
        return real_flock(handle, op)

    monkeypatch.setattr(fcntl, "flock", flock_after_removal)
    handle = lock_folder(tmp_path, ".lock", "run folder", "trainer", "train under another name")
    try:
        assert lock_file.is_file()
        assert os.fstat(handle.fileno()).st_ino == os.stat(lock_file).st_ino
    finally:
        handle.close()


def test_a_run_refused_in_a_folder_named_through_dot_dot_keeps_the_folder_it_names(tmp_path):
    """run.runs_dir=new/../keep names keep/, there with an earlier run in keep/x: the run could not
    find new/../keep/x before it made new/, took the run folder for one it made, and removed it,
    with the earlier run, when it refused to start there."""
    (tmp_path / "keep" / "x").mkdir(parents=True)
    (tmp_path / "keep" / "x" / "notes.txt").write_text("mine")
    missing = tmp_path / "nope" / "best.pt"
    cfg = load_train_config([], TINY + [f"run.runs_dir={tmp_path / 'new' / '..' / 'keep'}", "name=x", f"init_from={missing}"])
    with pytest.raises(ValueError, match="no such checkpoint"):
        Trainer(cfg, log=lambda s: None)
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["keep", "keep/x", "keep/x/notes.txt"]


def test_a_refused_resume_of_a_folder_without_a_lock_file_leaves_none_in_it(tmp_path, monkeypatch):
    """A run folder copied without its '.lock' (from another machine), whose resume is refused (last.pt
    damaged, or the run refused as it starts), was left holding a '.lock' the refused resume made."""
    cfg = tiny_config(tmp_path, updates=1)
    Trainer(cfg, log=lambda s: None).train()
    (cfg.run_dir / ".lock").unlink()
    kept = sorted(p.name for p in cfg.run_dir.iterdir())

    def refuse(self, checkpoint):
        raise ValueError("refused as it starts")

    with monkeypatch.context() as patched:
        patched.setattr(Trainer, "_build", refuse)
        with pytest.raises(ValueError, match="refused as it starts"):
            Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None)
    assert sorted(p.name for p in cfg.run_dir.iterdir()) == kept
    last = cfg.run_dir / "last.pt"
    good = last.read_bytes()
    last.write_bytes(b"damaged")
    with pytest.raises(ValueError):
        Trainer.resume(cfg.run_dir, log=lambda s: None)
    assert sorted(p.name for p in cfg.run_dir.iterdir()) == kept
    last.write_bytes(good)
    (cfg.run_dir / ".lock").write_text("")  # one that was there stays, as a refused resume found it
    with pytest.raises(ValueError):
        with monkeypatch.context() as patched:
            patched.setattr(Trainer, "_build", refuse)
            Trainer.resume(cfg.run_dir, total_steps=64, log=lambda s: None)
    assert (cfg.run_dir / ".lock").is_file()


def test_a_checkpoint_of_another_format_version_or_lacking_entries_is_refused_in_one_line_naming_it(tmp_path):
    """A file of another format version, one without the entries every checkpoint holds, one
    whose obs_spec lacks the team and ray counts, or whose provenance entries are of the wrong
    kind, or whose critic holds non-finite or non-tensor values is refused by name: never read as
    if it were this version, never a traceback."""
    spec = ObsSpec.make(2, 1, 4).to_dict()
    whole = {"format": "pursuit-mj-checkpoint", "version": 1, "train_config": {}, "obs_spec": spec,
             "actor": {"w": torch.zeros(2)}, "counters": {}}
    path = tmp_path / "x.pt"
    torch.save(whole, path)
    assert load_checkpoint(path)["obs_spec"] == spec
    for changes, words in (
        ({"version": 2}, "format version 2, this code reads 1"),
        ({"version": 0}, "format version 0, this code reads 1"),
        ({"obs_spec": None, "counters": None}, "missing entries ['obs_spec', 'counters']"),
        ({"obs_spec": {k: v for k, v in spec.items() if k not in ("n_rays", "groups")}}, "its obs_spec lacks ['n_rays', 'groups']"),
        ({"trained_by": "abc"}, "entry trained_by is not a list of dicts (damaged, or not written by pursuit-mj)"),
        ({"trained_by": [1]}, "entry trained_by is not a list of dicts (damaged, or not written by pursuit-mj)"),
        ({"init_from_sha256": 5}, "entry init_from_sha256 is not text (damaged, or not written by pursuit-mj)"),
        ({"critic": {"w": torch.tensor([0.0, float("inf")])}}, "non-finite weights (NaN or inf) in critic.w"),
        ({"critic": {"w": 3}}, "entry critic holds values other than tensors (damaged, or not written by pursuit-mj)"),
        ({"obs_spec": {**spec, "n_pursuers": -1}}, "obs_spec entry n_pursuers is -1, not a whole number (damaged, or not written by pursuit-mj)"),
        ({"obs_spec": {**spec, "groups": [g[:2] for g in spec["groups"]]}},
         "obs_spec entry groups is not a list of [name, width, features] (damaged, or not written by pursuit-mj)"),
    ):
        data = {k: v for k, v in {**whole, **changes}.items() if v is not None}
        torch.save(data, path)
        with pytest.raises(ValueError) as err:
            load_checkpoint(path)
        assert str(err.value) == f"checkpoint {path}: {words}"


def test_an_export_of_an_export_names_the_training_checkpoint_it_came_from(tmp_path):
    """exported_from names the checkpoint that was trained, also after exporting an export."""
    from train.checkpoint import export_actor, save_checkpoint

    trained = save_checkpoint(tmp_path / "last.pt", {
        "train_config": {}, "obs_spec": ObsSpec.make(2, 1, 4).to_dict(), "actor": {"w": torch.zeros(2)},
        "counters": {"update": 3}, "critic": {}, "optimizer": {}, "rng": {}})
    first = export_actor(trained, tmp_path / "small.pt")
    second = export_actor(first, tmp_path / "smaller.pt")
    assert load_checkpoint(first)["exported_from"] == str(trained)
    assert load_checkpoint(second)["exported_from"] == str(trained)
    assert load_checkpoint(second)["counters"] == {"update": 3} and "critic" not in load_checkpoint(second)


def test_init_from_compares_net_kind_even_where_a_trunks_shape_keys_leave_it_out(monkeypatch):
    """docs/training.md has a trunk's SHAPE_KEYS name 'the net.* keys its weights depend on'; a
    network added with SHAPE_KEYS = ('encoder_width', 'hidden', 'use_rays') - kind left out, as
    no weight depends on it - let --init-from from it into a reference run through the
    comparison, and the run was refused with torch's list of missing keys, not naming both
    networks (two kinds with the same weight names would have loaded into the other network)."""
    import train.networks as networks
    from train.config import NetConfig
    from train.run_checks import check_same_network

    monkeypatch.setattr(networks.FlatTrunk, "SHAPE_KEYS", ("hidden",))  # as a trunk of one's own might say
    data = {"train_config": {"net": {"kind": "mlp"}}}
    with pytest.raises(ValueError, match=r"^init_from x.pt: its actor is net.kind mlp; this run builds net.kind "
                                         r"reference \(to start from it, give the run the same network: --set net.kind=mlp\)$"):
        check_same_network(data, NetConfig(), "x.pt")
    check_same_network(data, NetConfig(kind="mlp", encoder_width=8), "x.pt")  # the keys it leaves out stay free


def test_an_export_of_a_checkpoint_of_an_unknown_network_kind_is_refused(tmp_path, capsys):
    """'train --export gru.pt out.pt' of a checkpoint whose net.kind this code does not have wrote
    out.pt without a word, and 'eval --model out.pt' then refused it; the export is refused as the
    loader refuses the checkpoint, naming the kind and the known ones, and writes nothing."""
    from pursuit_cli import main
    from train.checkpoint import save_checkpoint

    src = save_checkpoint(tmp_path / "gru.pt", {
        "train_config": {"net": {"kind": "gru"}}, "obs_spec": ObsSpec.make(2, 1, 4).to_dict(), "actor": {"w": torch.zeros(2)},
        "counters": {"update": 3}, "critic": {}, "optimizer": {}, "rng": {}})
    assert main(["train", "--export", str(src), str(tmp_path / "out" / "small.pt")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"pursuit-mj train: error: --export {src} {tmp_path / 'out' / 'small.pt'}: net.kind 'gru': no such network "
                   f"in train/networks.py TRUNKS (known: reference, mlp); no policy could be loaded from the export"), err
    assert not (tmp_path / "out").exists()
