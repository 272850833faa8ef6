"""The task config: defaults of DESIGN.md section 1, YAML files, overrides, and every kind of bad value."""

from __future__ import annotations

import dataclasses
import math
import re

import pytest
import yaml

from pursuit_cli import main
from pursuit_mj.layout import builtin_layout_path, load_layout
from pursuit_mj.config import ConfigError, TaskConfig, default_config, dump_yaml, load_task_config


def test_defaults_reproduce_the_reference_study():
    c = TaskConfig()
    expected = {"n_pursuers": 3, "n_evaders": 1, "pursuer_speed": 0.3, "evader_speed": 0.6, "perception_radius": 2.0,
                "field_of_view": 2 * math.pi, "capture_radius": 0.3, "obstacle_clearance": 0.1, "teammate_clearance": 0.2,
                "control_dt": 0.1, "max_steps": 1000, "flight_height": 0.5, "layout": 0,
                "random_layout": False, "observability": "partial", "collision_penalty": -10.0, "spread_reward": 0.0,
                "fidelity": "quadrotor"}
    assert {k: getattr(c, k) for k in expected} == expected
    assert c.substeps == 50 and c.substeps_per_control == 5 and c.n_drones == 4
    c.validate()
    # obstacle_num 5: every built-in layout file asks for 5 random obstacles, which the config defers to
    assert c.random_obstacles is None
    assert [c.random_obstacle_count(load_layout(i)) for i in range(4)] == [5, 5, 5, 5]


def test_config_is_frozen_and_changes_make_new_configs():
    c = default_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.n_pursuers = 5  # type: ignore[misc]
    d = default_config(n_pursuers=5, fidelity="point")
    assert (c.n_pursuers, d.n_pursuers, d.fidelity) == (3, 5, "point")


def test_yaml_files_flags_and_overrides_apply_in_order(tmp_path):
    f1, f2 = tmp_path / "a.yaml", tmp_path / "b.yaml"
    f1.write_text(yaml.safe_dump({"n_pursuers": 4, "evader_speed": 0.5, "evader": {"panic_distance": 1.0}}))
    f2.write_text(yaml.safe_dump({"n_pursuers": 5}))
    c = load_task_config([f1, f2], ["evader_speed=0.7", "evader.calm_distance=2.5"], {"fidelity": "point", "n_pursuers": 6})
    assert (c.n_pursuers, c.evader_speed, c.fidelity) == (6, 0.7, "point")
    assert (c.evader.panic_distance, c.evader.calm_distance) == (1.0, 2.5)


def test_a_bad_value_in_an_earlier_file_names_that_file(tmp_path):
    typo, bad, fine = tmp_path / "typo.yaml", tmp_path / "bad.yaml", tmp_path / "fine.yaml"
    typo.write_text("n_pursuer: 2\n")
    bad.write_text("n_pursuers: 0\n")
    fine.write_text("n_evaders: 2\n")
    with pytest.raises(ConfigError, match=r"typo.yaml: unknown key 'n_pursuer' \(did you mean 'n_pursuers'\?\)"):
        load_task_config([typo, fine])
    with pytest.raises(ConfigError, match=r"bad.yaml: key 'n_pursuers': 0 is out of range"):
        load_task_config([bad, fine], ["max_steps=10"])


@pytest.mark.parametrize(
    "overrides, flags",
    [
        (["evader.panic_distance=3.5", "evader.calm_distance=5"], None),  # each alone breaks calm > panic
        (["capture_radius=0.15"], {"perception_radius": 0.2}),  # the flag alone is below capture_radius
        (["physics_dt=0.004", "controller_hz=250"], None),  # 100 Hz does not divide 250 Hz
    ],
)
def test_keys_that_must_agree_are_judged_on_the_whole_not_in_the_order_given(overrides, flags):
    c = load_task_config([], overrides, flags)
    for text in overrides:
        key, value = text.split("=")
        obj = c
        for part in key.split(".")[:-1]:
            obj = getattr(obj, part)
        assert getattr(obj, key.split(".")[-1]) == float(value)


def test_keys_that_disagree_name_the_source_after_which_they_stayed_so(tmp_path):
    with pytest.raises(ConfigError, match=r"^--set perception_radius=0.4: perception_radius 0.4 is below capture_radius 0.5"):
        load_task_config([], ["capture_radius=0.5", "perception_radius=0.4", "n_pursuers=2"])
    narrow = tmp_path / "narrow.yaml"
    narrow.write_text("perception_radius: 0.2\n")
    with pytest.raises(ConfigError, match=r"narrow.yaml: perception_radius 0.2 is below capture_radius 0.3"):
        load_task_config([narrow], ["n_pursuers=2"], {"fidelity": "point"})


def test_dumped_config_loads_back_identical(tmp_path):
    c = default_config(n_pursuers=2, layout="configs/layouts/1_walls.yaml", observability="full")
    path = tmp_path / "c.yaml"
    path.write_text(dump_yaml(c))
    assert load_task_config([path]) == c


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["n_persuers=2"], r"--set n_persuers=2: unknown key 'n_persuers' \(did you mean 'n_pursuers'\?\)"),
        (["evader.panic_dist=1"], r"unknown key 'evader.panic_dist' \(did you mean 'evader.panic_distance'\?\)"),
        (["n_pursuers=2.5"], r"key 'n_pursuers': expected an integer, got 2.5"),
        (["n_pursuers=true"], r"key 'n_pursuers': expected an integer, got True"),
        (["pursuer_speed=fast"], r"key 'pursuer_speed': expected a number, got 'fast'"),
        (["random_layout=3"], r"key 'random_layout': expected true or false, got 3"),
        (["pursuer_speed=-0.3"], r"key 'pursuer_speed': -0.3 is out of range \(must be > 0.0\)"),
        (["n_pursuers=0"], r"key 'n_pursuers': 0 is out of range \(must be >= 1\)"),
        (["n_pursuers=99"], r"key 'n_pursuers': 99 is out of range \(must be <= 16\)"),
        (["fidelity=rigid"], r"key 'fidelity': 'rigid' is not one of \['point', 'quadrotor'\]"),
        (["pursuer_speed=.inf"], r"key 'pursuer_speed': expected a finite number"),
        (["control_dt=0.015"], r"control_dt 0.015 is not a whole number of physics_dt 0.002"),
        (["control_dt=1e-9"], r"control_dt 1e-09 is shorter than physics_dt 0.002: a decision step would advance no physics"),
        (["controller_hz=300"], r"controller_hz 300.0 does not divide the physics rate 500 Hz"),
        (["controller_hz=50"], r"key 'controller_hz': 50.0 is out of range \(must be >= 100.0\)"),
        (["perception_radius=0.2"], r"perception_radius 0.2 is below capture_radius 0.3"),
        (["capture_radius=0.1"], r"capture_radius 0.1 m is not beyond 0.137 m, where two drones' collision volumes touch"),
        (["drone_mass=0"], r"key 'drone_mass': 0.0 is out of range \(must be >= 0.01\)"),
        (["drone_mass=-0.03"], r"key 'drone_mass': -0.03 is out of range \(must be >= 0.01\)"),
        (["drone_mass=1e-5"], r"key 'drone_mass': 1e-05 is out of range \(must be >= 0.01\)"),
        (["drone_mass=0.045"], r"key 'drone_mass': 0.045 kg is more than the rotors can fly: their 0.6 N at full thrust "
                               r"must lift at least 1.5 times the weight \(at most 0.04077 kg\)"),
        (["drone_mass=heavy"], r"key 'drone_mass': expected a number, got 'heavy'"),
        (["n_pursuers"], r"'n_pursuers' is not of the form key=value"),
        (["evader=3"], r"key 'evader': expected a mapping of EvaderConfig keys, got 3"),
        (["n_pursuers.x=1"], r"'n_pursuers' has no sub-keys"),
    ],
)
def test_bad_overrides_raise_naming_key_value_and_source(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_task_config([], overrides)


@pytest.mark.parametrize("text, dropped", [("random_obstacles=#3", "#3"), ("layout=my arena #2.yaml", "#2.yaml"),
                                           ("n_pursuers=2 # two", "# two")])
def test_an_override_whose_value_yaml_reads_as_a_comment_is_refused_not_cut(text, dropped):
    """YAML reads ' #' (or a leading '#') as the start of a comment: --set random_obstacles=#3 was taken
    as null (each layout's own count) and --set 'layout=my arena #2.yaml' looked for 'my arena',
    without a word that the rest was dropped."""
    from pursuit_mj.configio import parse_override

    with pytest.raises(ConfigError, match=rf"^--set {re.escape(text)}: the value of '\w+' holds a YAML comment "
                                          rf"\({re.escape(repr(dropped))} is dropped\); quote the value"):
        load_task_config([], [text])
    value = text.split("=", 1)[1]
    assert parse_override(f'name="{value}"', "x") == (["name"], value)  # quoted, the '#' is kept
    assert parse_override("name=a#2", "x") == (["name"], "a#2")  # no space before it: no comment


def test_the_heaviest_drone_mass_the_refusal_names_is_accepted():
    """The bound printed was rounded to 0.0408 kg, just above the real one (0.040775): a flyer who
    set drone_mass=0.0408 was refused with 'at most 0.0408 kg'. The bound named, in the refusal
    and in the key's help, is itself accepted (rounded down)."""
    import re

    from pursuit_mj.config import DRONE_MAX_MASS

    with pytest.raises(ConfigError) as refused:
        load_task_config([], ["drone_mass=0.0408"])
    named = [float(x) for x in re.findall(r"at most ([0-9.]+) kg", str(refused.value))]
    help_text = next(f.metadata["help"] for f in dataclasses.fields(TaskConfig) if f.name == "drone_mass")
    named += [float(x) for x in re.findall(r"at most ([0-9.]+) kg", help_text)]
    assert len(named) == 2
    for bound in named:
        assert DRONE_MAX_MASS - 1e-5 <= bound <= DRONE_MAX_MASS
        assert load_task_config([], [f"drone_mass={bound}"]).drone_mass == bound


def test_the_contact_distance_is_twice_the_drone_models_collision_radius():
    import mujoco

    from pursuit_mj.config import DRONE_CONTACT_DISTANCE

    model = mujoco.MjModel.from_xml_path("models/crazyflie.xml")
    assert DRONE_CONTACT_DISTANCE == pytest.approx(2 * model.geom("collision").size[0])


def test_drone_mass_defaults_to_the_drone_models_and_its_limit_to_the_models_thrust():
    """Default configs keep the model file's mass (every documented number stays); the limit
    is the models' full thrust over 1.5 times g, and a mass just under it is accepted."""
    from pursuit_mj.config import DRONE_MAX_MASS, DRONE_MAX_THRUST, MIN_THRUST_TO_WEIGHT
    from pursuit_mj.scene import drone_parameters

    params = drone_parameters()
    assert TaskConfig().drone_mass == params["mass"] == 0.027
    assert DRONE_MAX_THRUST == pytest.approx(4 * params["max_thrust"], rel=1e-12)
    assert DRONE_MAX_MASS == pytest.approx(4 * params["max_thrust"] / (9.81 * MIN_THRUST_TO_WEIGHT))
    assert load_task_config([], [f"drone_mass={DRONE_MAX_MASS}"]).drone_mass == DRONE_MAX_MASS
    assert load_task_config([], ["drone_mass=0.033"]).drone_mass == 0.033


def test_bad_yaml_files_name_the_file(tmp_path):
    bad_key = tmp_path / "typo.yaml"
    bad_key.write_text("evader_sped: 0.5\n")
    with pytest.raises(ConfigError, match=r"typo.yaml: unknown key 'evader_sped' \(did you mean 'evader_speed'\?\)"):
        load_task_config([bad_key])
    bad_type = tmp_path / "type.yaml"
    bad_type.write_text("max_steps: many\n")
    with pytest.raises(ConfigError, match=r"type.yaml: key 'max_steps': expected an integer, got 'many'"):
        load_task_config([bad_type])
    broken = tmp_path / "broken.yaml"
    broken.write_text("n_pursuers: [1,\n")
    with pytest.raises(ConfigError, match=r"broken.yaml: not valid YAML, line \d+, column \d+: "):
        load_task_config([broken])
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match=r"list.yaml: expected a mapping at the top level, got list"):
        load_task_config([listing])
    with pytest.raises(ConfigError, match=r"nope.yaml: no such file"):
        load_task_config([tmp_path / "nope.yaml"])
    with pytest.raises(ConfigError, match=r"hardd: no such file, nor a task preset of that name \(presets: easy, hard, reference\)"):
        load_task_config(["hardd"])


def test_bad_keyword_to_default_config_names_the_nearest_key():
    with pytest.raises(ConfigError, match=r"default_config\(\): unknown key 'flight_hieght' \(did you mean 'flight_height'\?\)"):
        default_config(flight_hieght=1.0)
    with pytest.raises(ValueError):  # ConfigError is a ValueError, for callers that catch those
        default_config(layout=-1)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["config", "--set", "bogus=1"], "unknown key 'bogus'"),
        (["config", "--pursuers", "0"], "flag --pursuers 0: key 'n_pursuers': 0 is out of range"),
        (["config", "-ev", "0.5", "--pursuers", "0"], "flag --pursuers 0: key 'n_pursuers'"),
        (["config", "-i", "7"], "flag -i 7: key 'layout': 7 is not a built-in layout index (0-3)"),
        (["config", "--set", "layout=9"], "--set layout=9: key 'layout': 9 is not a built-in layout index"),
        (["config", "--set", "random_layout=true", "--set", "layout=configs/layouts/1_walls.yaml"],
         "key 'random_layout' draws each episode's layout from the built-in 0-3, so layout configs/layouts/1_walls.yaml would be ignored"),
        (["config", "-i", "no_such_layout.yaml"], "layout 'no_such_layout.yaml': no such file"),
        (["train", "--seed", "-1", "--total-steps", "10"], "flag --seed -1: key 'seed': -1 is out of range"),
        (["config", "--set", "evader_speed=-1"], "--set evader_speed=-1: key 'evader_speed': -1.0 is out of range"),
    ],
)
def test_cli_bad_config_exits_2_with_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.parametrize("command", [["eval"], ["render"], ["demo"], ["simulate"], ["layout", "new", "x.yaml"]])
def test_negative_seed_is_refused_naming_the_flag(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--seed", "-1"])
    assert exc.value.code == 2
    assert "argument --seed: expected an integer >= 0, got -1" in capsys.readouterr().err


def test_yaml_merge_keys_and_aliases_are_read_and_a_key_twice_still_refused(tmp_path):
    merged = tmp_path / "merged.yaml"
    merged.write_text("evader:\n  <<: {panic_distance: 1.2, calm_distance: 4}\n  calm_distance: 5\n")
    c = load_task_config([merged])
    assert (c.evader.panic_distance, c.evader.calm_distance) == (1.2, 5.0)  # a key beside << wins over the merged one
    twice = tmp_path / "twice.yaml"
    twice.write_text("evader:\n  <<: {panic_distance: 1.2}\n  calm_distance: 4\n  calm_distance: 5\n")
    with pytest.raises(ConfigError, match=r"twice.yaml: not valid YAML, line 4, column 3: key 'calm_distance' given twice"):
        load_task_config([twice])


def test_a_mapping_given_by_set_updates_the_section_like_a_file_does(tmp_path):
    ev = tmp_path / "ev.yaml"
    ev.write_text("evader: {panic_distance: 2, calm_distance: 5}\n")
    c = load_task_config([ev], ["evader={panic_distance: 1.2}"])
    assert (c.evader.panic_distance, c.evader.calm_distance) == (1.2, 5.0)  # calm_distance was reset to 3.0


def test_a_number_with_a_leading_zero_is_decimal_not_octal():
    # YAML 1.1 reads 010 as octal 8; YAML 1.2 and every user mean ten
    assert load_task_config([], ["n_pursuers=010", "max_steps=0100"]).n_pursuers == 10
    assert load_task_config([], ["max_steps=0100"]).max_steps == 100
    assert load_task_config([], ["max_steps=0x10"]).max_steps == 16


def test_a_number_with_a_colon_is_refused_not_read_in_base_60():
    # YAML 1.1 reads 1:30 as 90 and 1:30.5 as 90.5 (sexagesimal); YAML 1.2 reads strings
    with pytest.raises(ConfigError, match="key 'max_steps': expected an integer, got '1:30'"):
        load_task_config([], ["max_steps=1:30"])
    with pytest.raises(ConfigError, match="key 'evader_speed': expected a number, got '1:30.5'"):
        load_task_config([], ["evader_speed=1:30.5"])


def _experiment_folder(tmp_path):
    """exp/arena.yaml beside exp/task.yaml and exp/train.yaml, which name it by its bare file name."""
    exp = tmp_path / "exp"
    exp.mkdir()
    (exp / "arena.yaml").write_text(builtin_layout_path(2).read_text())
    (exp / "task.yaml").write_text("layout: arena.yaml\nfidelity: point\n")
    (exp / "train.yaml").write_text("name: exp\ntask:\n  layout: arena.yaml\nlayouts: [arena.yaml, 0]\n"
                                    "run:\n  validation_layouts: [arena.yaml]\n")
    (exp / "train_task_file.yaml").write_text("name: exp2\ntask_file: task.yaml\n")
    return exp


def test_a_layout_file_named_in_a_task_or_train_file_is_found_beside_that_file(tmp_path, monkeypatch, capsys):
    from train.config import load_train_config

    exp = _experiment_folder(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the run starts in another folder: "arena.yaml" is not there
    beside = str(exp / "arena.yaml")
    assert load_task_config([str(exp / "task.yaml")]).layout == beside
    cfg = load_train_config([str(exp / "train.yaml")])
    assert (cfg.task.layout, cfg.layouts, cfg.run.validation_layouts) == (beside, (beside, 0), (beside,))
    cfg.check_layouts()
    assert load_train_config([str(exp / "train_task_file.yaml")]).task.layout == beside
    assert main(["config", "--task", str(exp / "task.yaml")]) == 0
    assert f"layout: {beside}" in capsys.readouterr().out
    assert main(["simulate", "--task", str(exp / "task.yaml"), "--seconds", "0.2"]) == 0


def test_a_layout_file_in_the_current_folder_wins_over_one_beside_the_task_file(tmp_path, monkeypatch):
    exp = _experiment_folder(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "arena.yaml").write_text(builtin_layout_path(1).read_text())
    assert load_task_config([str(exp / "task.yaml")]).layout == "arena.yaml"  # as before: from the current folder


def test_a_layout_file_found_nowhere_is_refused_naming_the_file_and_key_that_named_it(tmp_path, monkeypatch, capsys):
    """It was refused only when the layout loaded, without the file that named it; and
    `train -sc` printed such a config and exited 0."""
    from train.config import load_train_config

    exp = tmp_path / "exp"
    exp.mkdir()
    task, train = exp / "task.yaml", exp / "train.yaml"
    task.write_text("layout: arena.yaml\n")
    monkeypatch.chdir(tmp_path)
    looked = rf"no such file in the current folder \({tmp_path}\) or beside {exp}"
    with pytest.raises(ConfigError, match=rf"{task}: key 'layout': layout 'arena.yaml': {looked}"):
        load_task_config([str(task)])
    for key, text in (("task.layout", "task: {layout: arena.yaml}"), ("layouts", "layouts: [0, arena.yaml]"),
                      ("run.validation_layouts", "run: {validation_layouts: [arena.yaml]}")):
        train.write_text(f"name: exp\n{text}\n")
        with pytest.raises(ConfigError, match=rf"{train}: key '{key}': layout 'arena.yaml': {looked}"):
            load_train_config([str(train)])
    train.write_text(f"name: exp\ntask_file: {task}\n")
    assert main(["train", "--config", str(train), "-sc"]) == 2
    assert f"{task}: key 'layout'" in capsys.readouterr().err
    assert main(["train", "--config", "classic", "--set", "run.validation_layouts=[0,nothere.yaml]", "-sc"]) == 2
    assert "run.validation_layouts [0, 'nothere.yaml']: layout 'nothere.yaml': no such file" in capsys.readouterr().err
    # a path given on the command line names only the current folder
    assert main(["layout", "check", "arena.yaml"]) == 2
    err = capsys.readouterr().err
    assert f"layout 'arena.yaml': no such file in the current folder ({tmp_path})," in err and "beside" not in err


@pytest.mark.parametrize("command", [["config"], ["eval", "--policy", "heuristic"], ["simulate"], ["render", "--policy", "random"]])
@pytest.mark.parametrize("given, named", [(["-i", "none.yaml"], "-i none.yaml"), (["--layout", "none.yaml"], "--layout none.yaml"),
                                          (["--set", "layout=none.yaml"], "--set layout=none.yaml"),
                                          (["--set", "layout='7'"], "--set layout='7'")])
def test_a_layout_given_on_the_command_line_that_cannot_be_loaded_names_its_flag(tmp_path, capsys, monkeypatch,
                                                                                   command, given, named):
    """-i none.yaml or --set layout=none.yaml was refused as "layout 'none.yaml': no such file ...",
    naming neither the flag nor the --set that gave it, as errors of other task values do."""
    monkeypatch.chdir(tmp_path)
    assert main(command + given) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pursuit-mj {command[0]}: error: {named}: layout ") and len(err.splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("given, message", [
    (["--set", "n_pursuers=16"], "cannot reliably hold 16 pursuers"),
    (["--set", "random_layout=true", "--set", "n_pursuers=16"], "cannot reliably hold 16 pursuers"),
    (["--set", "capture_radius=3.5", "--set", "perception_radius=4"], "within the capture_radius of 3.5 m"),
])
def test_config_refuses_a_task_its_layout_cannot_hold_as_every_run_does(capsys, given, message):
    """`pursuit-mj config --set n_pursuers=16` printed the config, which every run (eval, render,
    train, simulate) then refused: the layout's spawn region cannot hold that team."""
    assert main(["config", *given]) == 2
    out, err = capsys.readouterr()
    assert out == "" and message in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("argv, key", [(["--r_perception", "2000"], "perception_radius"),  # the reference study's mm
                                       (["--set", "ray_range=1500"], "ray_range"),
                                       (["--set", "evader.sense_radius=4000"], "evader.sense_radius")])
def test_a_distance_far_beyond_any_arena_is_refused_as_a_unit_slip(argv, key, capsys):
    """2000 (mm) was taken as 2000 m: partial observability quietly became an unlimited view."""
    assert main(["config"] + argv) == 2
    err = capsys.readouterr().err
    assert f"key '{key}'" in err and "out of range (must be <= 100.0)" in err, err


def test_a_bad_nested_key_is_named_by_its_dotted_path_and_its_suggestion_too(tmp_path):
    task = tmp_path / "t.yaml"
    task.write_text("evader:\n  panic_distance: -1\n")
    with pytest.raises(ConfigError, match=rf"{task}: key 'evader.panic_distance': -1.0 is out of range"):
        load_task_config([str(task)])
    task.write_text("evader:\n  panic_distnce: 1\n")
    with pytest.raises(ConfigError, match=rf"{task}: unknown key 'evader.panic_distnce' "
                                          r"\(did you mean 'evader.panic_distance'\?\)"):
        load_task_config([str(task)])
    with pytest.raises(ConfigError, match=r"--set evader.panic_distance=0: key 'evader.panic_distance': 0.0 is out"):
        load_task_config([], ["evader.panic_distance=0"])


def test_a_list_written_without_brackets_is_shown_with_them():
    from train.config import load_train_config

    with pytest.raises(ConfigError, match=r"--set layouts=0,1: key 'layouts': expected a list, got '0,1' \(write it as \[0,1\]\)"):
        load_train_config([], ["layouts=0,1"])


def test_load_train_config_takes_one_file_or_override_as_a_string_like_load_task_config():
    """A string was read one character at a time: 'c: no such file', '--set p: not key=value'."""
    from train.config import load_train_config

    assert load_train_config("classic") == load_train_config(["classic"])
    assert load_train_config((), "ppo.lr=1e-4").ppo.lr == 1e-4
    with pytest.raises(ValueError, match="load_train_config files: expected a list, got None"):
        load_train_config(None)


def test_a_nested_config_object_is_checked_where_it_is_given():
    """An EvaderConfig made directly skipped every check, and PursuitEnv then named itself as the source."""
    from pursuit_mj.config import EvaderConfig

    with pytest.raises(ValueError, match="default_config\\(\\).*evader.*panic_distance"):
        default_config(evader=EvaderConfig(panic_distance=-5))
    with pytest.raises(ValueError, match="panic_distance"):
        load_task_config(flags={"evader": EvaderConfig(panic_distance=-5)})
    assert default_config(evader=EvaderConfig()).evader == EvaderConfig()


@pytest.mark.parametrize("args, said", [((None,), "load_task_config files: expected a list of paths or preset names, got None"),
                                        (([3],), "load_task_config files: expected a list of paths or preset names, got \\[3\\]"),
                                        (([], [None]), "load_task_config overrides: expected a list of KEY=VALUE texts, got \\[None\\]")])
def test_load_task_config_refuses_arguments_of_the_wrong_kind_in_one_line(args, said):
    with pytest.raises(ValueError, match=said):
        load_task_config(*args)


def test_a_layout_file_or_train_config_given_as_a_task_file_is_named_for_what_it_is(tmp_path, capsys):
    """A layout file as --task was refused as "unknown key 'name'", which did not say where it belongs."""
    from pursuit_mj.layout import builtin_layout_path

    layout = tmp_path / "my.yaml"
    layout.write_text(builtin_layout_path(1).read_text())
    assert main(["config", "--task", str(layout)]) == 2
    assert (f"{layout}: this is a layout file (it has arena, boundary, spawn), not a task file: give it with "
            f"-i/--layout FILE, or among --layouts for a table (eval, demo, study)") in capsys.readouterr().err
    # a study trains on layout 0 and plays --layouts: a single layout given to it was accepted and ignored
    for given in (["-i", str(layout)], ["--set", "layout=2"]):
        assert main(["study", "--budget-minutes", "1", "--out", str(tmp_path / "s"), *given]) == 2
        assert "the study trains every arm on layout 0 and evaluates on --layouts" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
    assert main(["eval", "--task", "configs/train/classic.yaml"]) == 2
    assert "this is a train config (it has ppo, regime, algo, n_envs, total_steps), not a task file: give it to " \
           "pursuit-mj train --config FILE" in capsys.readouterr().err
    assert main(["config", "--task", "hard"]) == 0  # a task file is read as before


def test_a_task_file_beside_the_train_file_is_still_found_when_set_task_file_layers_another_over_it(tmp_path, monkeypatch):
    """--set task_file=X applies X over the train file's own task_file, which still counts for the
    keys X leaves: it is read from beside the train file as without the --set (it was looked for
    in the current folder only, and refused)."""
    from train.config import load_train_config

    exp = tmp_path / "exp"
    exp.mkdir()
    (exp / "mytask.yaml").write_text("evader_speed: 0.5\nperception_radius: 1.8\n")
    (exp / "train.yaml").write_text("name: exp\ntask_file: mytask.yaml\n")
    monkeypatch.chdir(tmp_path)
    cfg = load_train_config([str(exp / "train.yaml")], ["task_file=easy"])
    assert (cfg.task.evader_speed, cfg.task.perception_radius) == (0.45, 1.8)  # easy's speed over the file's radius


@pytest.mark.parametrize("text, replacing, leaving", [
    ("task:\n  layout: gone.yaml\n", "task={layout: 2}", "task={fidelity: point}"),
    ("task:\n  evader: {model: gone.py:Straight}\n", "task.evader={model: janosov}", "task.evader={zigzag_rate: 2.0}"),
    ("task:\n  evader: {model: gone.py:Straight}\n", "task={evader: {model: janosov}}", "task={evader: {zigzag_rate: 2.0}}"),
    ("run:\n  validation_layouts: [gone.yaml]\n", "run={validation_layouts: [1]}", "run={progress: false}"),
])
def test_a_gone_file_replaced_by_a_set_of_its_section_is_not_looked_up(tmp_path, monkeypatch, text, replacing, leaving):
    """--set SECTION={KEY: VALUE} replaces KEY as --set SECTION.KEY=VALUE does (a mapping updates
    its section): the file KEY named in the train file is not looked up; a --set of the section
    that leaves KEY keeps it looked up and refused."""
    from train.config import load_train_config

    monkeypatch.chdir(tmp_path)
    (tmp_path / "run.yaml").write_text(f"name: exp\n{text}")
    cfg = load_train_config(["run.yaml"], [replacing])
    assert "gone" not in str((cfg.task.layout, cfg.task.evader.model, cfg.run.validation_layouts))
    with pytest.raises(ConfigError, match="run.yaml: key '.*': .*gone"):
        load_train_config(["run.yaml"], [leaving])


def test_a_text_key_given_a_word_yaml_reads_as_a_boolean_says_how_to_keep_the_word(tmp_path):
    """`train --set name=no` said 'expected a string, got False', naming a value the user never typed."""
    from train.config import load_train_config

    with pytest.raises(ConfigError) as caught:
        load_train_config([], ["name=no"])
    said = str(caught.value)
    assert "expected a string, got False" in said and "YAML reads" in said and "quote" in said, said
    with pytest.raises(ConfigError) as caught:
        load_train_config([], ["name=3"])
    assert "YAML reads" not in str(caught.value)  # a number is what was typed
    assert load_train_config([], ['name="no"']).name == "no"


@pytest.mark.parametrize("text", ["name=run #2", "name=#3", "name=no", "run.runs_dir=off"])
def test_the_quoting_an_override_refusal_advises_works_when_typed_in_a_shell(text):
    """The refusals of a value YAML cuts at a '#' or reads as a boolean advised name="run #2" and
    'quote the word': typed so after --set, the shell takes the quotes away and the same value
    is refused again. The advice is now a whole --set argument in the shell's quotes."""
    import shlex

    from train.config import load_train_config

    with pytest.raises(ConfigError) as caught:
        load_train_config([], [text])
    said = str(caught.value)
    advised = said.rsplit(": ", 1)[-1].rstrip(")")
    words = shlex.split(advised)  # what a POSIX shell hands the command
    assert words[0] == "--set" and len(words) == 2, said
    key, value = text.split("=", 1)
    cfg = load_train_config([], [words[1]])
    got = cfg.name if key == "name" else cfg.run.runs_dir
    assert got == value, said



EVAL_ONE = ["eval", "--policy", "heuristic", "--episodes", "1"]


@pytest.mark.parametrize("argv, named", [
    (["config", "--set", "n_pursuers=16"], "--set n_pursuers=16: the spawn region of "),
    ([*EVAL_ONE, "--set", "n_pursuers=16"], "--set n_pursuers=16: the spawn region of "),
    ([*EVAL_ONE, "--pursuers", "16"], "--pursuers 16: the spawn region of "),
    (["config", "--set", "n_pursuers=2", "--set", "n_pursuers=16"], "--set n_pursuers=16: the spawn region of "),
])
def test_a_team_the_layout_cannot_hold_names_the_flag_that_gave_it(capsys, argv, named):
    """The refusal read 'n_pursuers=16: the spawn region ...' whichever flag had set the team size."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pursuit-mj {argv[0]}: error: {named}") and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("given, shown_as", [("max_steps=1e30", "1e+30"), ("random_obstacles=1e300", "1e+300")])
def test_a_huge_whole_number_out_of_range_is_shown_short(capsys, given, shown_as):
    """A count typed as 1e300 is read as a whole number; the refusal printed all its 301 digits."""
    assert main(["config", "--set", given]) == 2
    err = capsys.readouterr().err
    assert f"{shown_as} is out of range (must be <= " in err and len(err) < 200, err


def test_a_refused_task_value_is_not_blamed_on_a_source_that_gave_another_value():
    """The CLI names the flag or task file that gave a refused task value (TaskValueError): it
    blamed whichever of them named the key, whatever value it gave. A study whose arms train
    with --train-set task.n_pursuers=16 was refused with 'task file reference: n_pursuers 16:
    ...', though that preset holds n_pursuers 3; with no source of that value the message is
    the refusal's own."""
    import argparse

    from pursuit_cli import _with_source
    from pursuit_mj.layout_check import SpawnCapacityError

    exc = SpawnCapacityError("n_pursuers", 16, "the spawn region cannot hold them")
    study_args = argparse.Namespace(command="study", overrides=[], n_pursuers=None, task_files=["reference"],
                                    train_overrides=[])  # 16 came from elsewhere (the arms' own configs, say)
    assert _with_source(exc, study_args) == "n_pursuers=16: the spawn region cannot hold them"
    for overrides, n_pursuers, task_files in ((["n_pursuers=4"], None, []), ([], 4, []), (["n_pursuers=16", "n_pursuers=4"], None, [])):
        args = argparse.Namespace(command="eval", overrides=overrides, n_pursuers=n_pursuers, task_files=task_files)
        assert _with_source(exc, args) == "n_pursuers=16: the spawn region cannot hold them", (overrides, n_pursuers)
    # the source of that very value is still named
    args = argparse.Namespace(command="eval", overrides=["n_pursuers=16"], n_pursuers=None, task_files=["reference"])
    assert _with_source(exc, args) == "--set n_pursuers=16: the spawn region cannot hold them"
    args = argparse.Namespace(command="eval", overrides=[], n_pursuers=16, task_files=["reference"])
    assert _with_source(exc, args) == "--pursuers 16: the spawn region cannot hold them"


@pytest.mark.parametrize("digits, shown", [("1" + "0" * 400, "1e+400"), ("-" + "12345678" * 50, "-1.23457e+399")])
def test_a_whole_number_too_large_for_a_float_is_refused_in_one_line(capsys, digits, shown):
    """number_text showed an out-of-range whole number of more than 15 digits through float(),
    which fails past 1.8e308: '--set max_steps=1000...0' (401 digits) ended in an OverflowError
    traceback instead of the refusal."""
    from pursuit_mj.configio import number_text

    assert number_text(int(digits)) == shown
    assert number_text(10**30) == "1e+30" and number_text(123) == "123"
    assert main(["config", "--set", f"max_steps={digits}"]) == 2
    err = capsys.readouterr().err
    assert f"key 'max_steps': {shown} is out of range" in err and len(err.splitlines()) == 1, err


def test_a_team_the_layout_cannot_hold_names_the_train_flag_that_gave_it(capsys, tmp_path):
    """b6bf1f9 named the flag of a team size too large for the layout for the task's flags (--set
    n_pursuers=16, --pursuers 16) but not for a train key: 'train --set task.n_pursuers=16' read
    'n_pursuers=16: the spawn region ...', and a study's --train-set likewise."""
    import argparse

    from pursuit_cli import _with_source
    from pursuit_mj.layout_check import SpawnCapacityError

    argv = ["train", "--set", "task.n_pursuers=16", "--set", f"run.runs_dir={tmp_path}", "--total-steps", "10"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pursuit-mj train: error: --set task.n_pursuers=16: the spawn region of "), err
    exc = SpawnCapacityError("n_pursuers", 16, "the spawn region cannot hold them")
    study = argparse.Namespace(command="study", overrides=[], n_pursuers=None, task_files=["reference"],
                               train_overrides=["task.n_pursuers=16"])
    assert _with_source(exc, study) == "--train-set task.n_pursuers=16: the spawn region cannot hold them"
    study.train_overrides = ["task.n_pursuers=16", "task.n_pursuers=4"]  # the last one wins: 16 came from elsewhere
    assert _with_source(exc, study) == "n_pursuers=16: the spawn region cannot hold them"


@pytest.mark.parametrize("text", ["", "# evader_speed: 0.45\n", "\n\n"])
def test_an_empty_task_file_is_refused_as_an_empty_train_config_and_layout_are(text, tmp_path, capsys):
    """A task file cut to nothing (or with every line commented out) ran the default task without
    a word, while an empty train config and an empty layout file are refused."""
    from pursuit_cli import main

    task = tmp_path / "task.yaml"
    task.write_text(text)
    with pytest.raises(ConfigError, match=r"task\.yaml: the file is empty .*leave the file out"):
        load_task_config([task])
    assert main(["config", "--task", str(task)]) == 2
    err = capsys.readouterr().err
    assert f"{task}: the file is empty" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("argv, given, what, not_what", [
    (["train", "-sc", "--config", "{layout}"], "layout", "a layout file (it has arena, boundary, spawn)", "a train config"),
    (["train", "-sc", "--config", "{flight}"], "flight", "a flight file (it has drones, positioning", "a train config"),
    (["train", "-sc", "--config", "{task}"], "task", "a task file (it has evader_speed)", "a train config"),
    (["config", "--task", "{flight}"], "flight", "a flight file (it has drones, positioning", "a task file"),
    (["layout", "check", "{flight}"], "flight", "a flight file (it has drones, positioning", "a layout file"),
    (["layout", "check", "{task}"], "task", "a task file (it has evader_speed)", "a layout file"),
    (["fly", "check", "--flight", "{layout}"], "layout", "a layout file (it has arena, boundary, spawn)", "a flight file"),
    (["fly", "check", "--flight", "{task}"], "task", "a task file (it has evader_speed)", "a flight file"),
])
def test_a_file_of_another_kind_is_named_for_what_it_is_wherever_it_is_given(argv, given, what, not_what, tmp_path, capsys):
    """train --config LAYOUT.yaml said "unknown key 'arena' (did you mean 'run'?)", and train
    --config FLIGHT.yaml "unknown key 'layout' (did you mean 'task.layout'?)": advice that leads
    nowhere. Only a task file given a layout or train config said what the file was."""
    from pursuit_mj.layout import builtin_layout_path
    from pursuit_mj.shipped import shipped_dir

    files = {"layout": tmp_path / "arena.yaml", "flight": tmp_path / "lab.yaml", "task": tmp_path / "fast.yaml"}
    files["layout"].write_text(builtin_layout_path(1).read_text())
    files["flight"].write_text((shipped_dir("configs") / "flight" / "example.yaml").read_text())
    files["task"].write_text("evader_speed: 0.45\n")
    argv = [a.format(**files) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{files[given]}: this is {what}" in err and f"not {not_what}: " in err and "did you mean" not in err, err
    assert len(err.strip().splitlines()) == 1, err


def _design_section(number: int) -> str:
    """The text of section `number` of docs/DESIGN.md (the design contract the docs quote)."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "DESIGN.md").read_text()
    return text.split(f"\n## {number}. ", 1)[1].split("\n## ", 1)[0]


def _documented_default(text: str):
    """A default as DESIGN.md's table writes it ('2*pi', 'false', '0 (off)', 'null: ...') as a value."""
    word = text.split(":")[0].split(" (")[0].strip()
    if word == "null":
        return None
    if word in ("true", "false"):
        return word == "true"
    if word == "2*pi":
        return 2 * math.pi
    try:
        return int(word)
    except ValueError:
        try:
            return float(word)
        except ValueError:
            return word


def test_the_default_table_of_docs_design_md_is_the_configs_defaults_with_their_units():
    """Pins DESIGN.md section 1 to the code: each row's key, default and unit (m, m/s, s, rad)
    against TaskConfig's default and the unit its --help gives, rather than a copy of the table."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in _design_section(1).splitlines() if line.startswith("| `")]
    assert len(rows) == 19
    fields = {f.name: f for f in dataclasses.fields(TaskConfig)}
    for name_cell, default_cell, _ in rows:
        key = re.match(r"`(\w+)`", name_cell).group(1)
        assert key in fields, f"DESIGN.md section 1 names {key!r}, which TaskConfig lacks"
        assert getattr(TaskConfig(), key) == _documented_default(default_cell), key
        unit = re.search(r"\((?:max, )?([a-z/]+)\)", name_cell)
        if unit:
            assert f"({unit.group(1)})" in fields[key].metadata["help"], (key, unit.group(1))


def test_the_preset_table_of_docs_evaluation_md_is_what_each_preset_file_sets():
    """Pins the "Difficulty presets" table (evader speed, perception radius, field of view, noise,
    misses) to the task each configs/task preset resolves to, and lists every preset."""
    from pathlib import Path

    from pursuit_mj.config import preset_names

    text = (Path(__file__).resolve().parents[1] / "docs" / "evaluation.md").read_text()
    table = text.split("## Difficulty presets", 1)[1].split("\n\n", 1)[0]
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in table.splitlines() if line.startswith("| `")]
    assert sorted(r[0].strip("`") for r in rows) == preset_names("task")

    def number(cell: str) -> float:
        return 0.0 if cell == "0" else float(cell.split()[0])

    for name, speed, radius, view, noise, misses in rows:
        c = load_task_config([name.strip("`")])
        assert c.evader_speed == number(speed) and speed.endswith(" m/s"), name
        assert c.perception_radius == number(radius) and radius.endswith(" m"), name
        assert math.degrees(c.field_of_view) == pytest.approx(number(view), abs=1e-6) and view.endswith(" deg"), name
        assert c.position_noise == number(noise), name
        assert c.miss_probability == number(misses) / 100, name


def test_task_settings_a_combination_never_reads_are_named_one_line_each():
    """Full observability knows every entity exactly (sensing.perceive), and the point model's response
    does not follow drone_mass: `eval --observability full --set miss_probability=0.5` and `eval
    --fidelity point --set drone_mass=0.035` ran as without those keys, without a word."""
    assert default_config().idle_settings() == []
    assert default_config(observability="full").idle_settings() == []
    assert default_config(position_noise=0.1, miss_probability=0.2).idle_settings() == []  # partial reads them
    full = default_config(observability="full", position_noise=0.1, miss_probability=0.2, field_of_view=2.0)
    assert full.idle_settings() == [
        "field_of_view 114.6 deg, position_noise 0.1, miss_probability 0.2 do nothing under observability full (every "
        "evader and teammate is known exactly)"]
    assert default_config(fidelity="point", drone_mass=0.033).idle_settings() == [
        "drone_mass 0.033 does nothing under fidelity point (the point model's response does not follow the mass; "
        "quadrotor fidelity flies it)"]


def test_eval_notes_the_task_settings_its_combination_never_reads(capsys):
    """The note is one stderr line per idle setting, before the table; a run without one prints none."""
    args = ["eval", "--policy", "random", "--layouts", "0", "--episodes", "1", "--worlds", "1", "--fidelity", "point",
            "--set", "max_steps=2", "-q"]
    assert main(args + ["--observability", "full", "--task", "hard"]) == 0
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "note: perception_radius 1.5, field_of_view 120 deg, position_noise 0.1, miss_probability 0.2 do nothing under "
        "observability full (every evader and teammate is known exactly)"]
    assert main(args) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("given, source", [
    (["--set", "capture_radius=3.5", "--set", "perception_radius=4"], "--set capture_radius=3.5: "),
    (["--set", "perception_radius=4", "--task", "BIGCATCH"], "task file BIGCATCH: capture_radius 3.5: "),
])
def test_spawn_regions_within_a_capture_radius_given_are_refused_naming_where_it_was_given(tmp_path, capsys, given, source):
    """'--set capture_radius=3.5' was refused as '.../0_open.yaml: the spawn regions are 3.4 m apart,
    within the capture_radius of 3.5 m ...', naming the layout file and not where the radius came from."""
    task = tmp_path / "big_catch.yaml"
    task.write_text("capture_radius: 3.5\n")
    given = [str(task) if g == "BIGCATCH" else g for g in given]
    assert main(["eval", "--policy", "heuristic", "--episodes", "1", *given]) == 2
    err = capsys.readouterr().err
    source = source.replace("BIGCATCH", str(task))
    assert err.startswith(f"pursuit-mj eval: error: {source}") and "0_open.yaml" in err and len(err.splitlines()) == 1, err
