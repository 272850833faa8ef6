"""BatchedPhysics: determinism, resets of some worlds, contacts per drone, state shapes, bad input."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import SPREAD_XY, make_physics, open_layout

from pursuit_mj.config import ConfigError, default_config
from pursuit_mj.physics import BatchedPhysics

FIDELITIES = ("point", "quadrotor")


def random_commands(physics, steps: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (steps, physics.n_worlds, physics.n_drones, 2)) * physics.max_speed[:, None]


def full_state(physics) -> np.ndarray:
    """Every state row (W, nstate) of the batch: qpos, qvel, act, ctrl, applied forces ..."""
    return physics.batch.state.copy()


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_same_seed_and_commands_give_bit_identical_trajectories(fidelity):
    cmds = None
    runs = []
    for _ in range(2):
        physics = make_physics(fidelity, n_worlds=3)
        cmds = random_commands(physics, 15, seed=4) if cmds is None else cmds
        trajectory = []
        for c in cmds:
            physics.step(c)
            trajectory.append(full_state(physics))
        runs.append(np.array(trajectory))
    assert np.array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0][0], runs[0][-1])  # it did move


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_resetting_some_worlds_leaves_the_others_untouched(fidelity):
    reference, physics = make_physics(fidelity, n_worlds=3), make_physics(fidelity, n_worlds=3)
    cmds = random_commands(physics, 12, seed=5)
    for c in cmds[:6]:
        reference.step(c)
        physics.step(c)
    new_xy = SPREAD_XY[None] + 0.5
    physics.reset([1], new_xy)
    np.testing.assert_array_equal(physics.positions()[1, :, :2], new_xy[0])
    np.testing.assert_array_equal(physics.velocities()[1], 0.0)
    assert physics.time[1] == 0.0 and physics.time[0] > 0
    for c in cmds[6:]:  # worlds 0 and 2 carry on exactly as if nothing happened (controller memory included)
        reference.step(c)
        physics.step(c)
    untouched = full_state(physics)[[0, 2]]
    assert np.array_equal(untouched, full_state(reference)[[0, 2]])


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_stepping_some_worlds_leaves_the_others_as_they_were_and_the_stepped_as_if_alone(fidelity):
    def drones(p):  # positions, velocities, attitudes of world 1 (the inputs written to it may change)
        return np.concatenate([p.positions()[1], p.velocities()[1], p.quaternions()[1]], -1)

    reference, physics = make_physics(fidelity, n_worlds=3), make_physics(fidelity, n_worlds=3)
    cmds = random_commands(physics, 10, seed=6)
    for c in cmds[:4]:
        reference.step(c)
        physics.step(c)
    paused, clock = drones(physics), physics.time[1]
    for c in cmds[4:]:
        reference.step(c)
        physics.step(c, worlds=np.array([True, False, True]))
    assert np.array_equal(drones(physics), paused) and physics.time[1] == clock
    assert np.array_equal(full_state(physics)[[0, 2]], full_state(reference)[[0, 2]])
    assert (physics.time[[0, 2]] == reference.time[[0, 2]]).all() and not physics.diverged.any()
    physics.step(cmds[0], worlds=np.zeros(3, bool))  # none: nothing moves
    assert np.array_equal(drones(physics), paused) and not physics.contacts.any()
    with pytest.raises(ValueError, match=r"worlds: expected a \(3,\) bool mask"):
        physics.step(cmds[0], worlds=np.array([True, False]))


@pytest.mark.parametrize("fidelity", FIDELITIES)
@pytest.mark.parametrize("latency", [0.0, 0.15], ids=["no-latency", "latency-0.15s"])
def test_a_paused_world_keeps_its_commands_and_controller_memory_and_resumes_as_never_paused(fidelity, latency):
    """A world left out of `worlds` keeps everything, not only its drones: its last commands
    (which snapshots show), the pursuers' commands still on their way (command_latency) and
    its quadrotor controller's altitude integrator; stepped again without a reset it flies on
    exactly as a world that was never paused, whatever the others did meanwhile."""
    def drones(p):
        return np.concatenate([p.positions()[1], p.velocities()[1], p.quaternions()[1]], -1)

    reference = make_physics(fidelity, n_worlds=2, command_latency=latency)
    physics = make_physics(fidelity, n_worlds=2, command_latency=latency)
    cmds = random_commands(physics, 12, seed=8)
    for c in cmds[:5]:
        reference.step(c)
        physics.step(c)
    last = physics.commands[1].copy()
    for c in cmds[5:8]:  # world 1 waits while world 0 runs on other commands
        physics.step(-c, worlds=np.array([True, False]))
    assert np.array_equal(physics.commands[1], last), "a paused world's last commands were overwritten"
    for c in cmds[5:]:
        reference.step(c)
        physics.step(c)
    assert np.array_equal(drones(physics), drones(reference))
    assert physics.time[1] == reference.time[1]


@pytest.mark.parametrize("fidelity,flight_height", [("point", 0.5), ("quadrotor", 0.5), ("point", 2.0), ("quadrotor", 1.0)])
def test_contact_with_a_wall_is_reported_for_that_drone_only(fidelity, flight_height):
    xy = SPREAD_XY.copy()
    xy[0] = [0.4, 5.0]  # 0.4 m from the left border
    physics = make_physics(fidelity, xy=xy, flight_height=flight_height)  # the border rises with the flight height
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0] = [-0.3, 0.0]
    touched = np.zeros(4, bool)
    for _ in range(15):
        touched |= physics.step(cmd)[0]
    assert touched.tolist() == [True, False, False, False]
    assert physics.positions()[0, 0, 0] > 0.0  # stopped by the wall, not through it


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_contact_between_two_drones_is_reported_for_both(fidelity):
    xy = SPREAD_XY.copy()
    xy[0], xy[3] = [9.6, 10.0], [10.4, 10.0]  # pursuer_0 and the evader face each other 0.8 m apart
    physics = make_physics(fidelity, xy=xy)
    cmd = np.zeros((1, 4, 2))
    cmd[0, 0], cmd[0, 3] = [0.3, 0.0], [-0.3, 0.0]
    touched = np.zeros(4, bool)
    for _ in range(15):
        touched |= physics.step(cmd)[0]
    assert touched.tolist() == [True, False, False, True]


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_each_world_collides_with_its_own_obstacles(fidelity):
    pillar = open_layout(obstacles=[{"cylinder": {"center": [5.0, 5.6], "radius": 0.3}}], name="pillar")
    config = default_config(fidelity=fidelity)
    physics = BatchedPhysics(config, [pillar, open_layout()], nthread=1)
    physics.reset([0, 1], np.stack([SPREAD_XY, SPREAD_XY]))
    cmd = np.zeros((2, 4, 2))
    cmd[:, 0] = [0.0, 0.3]  # pursuer_0 flies toward the pillar, which only world 0 has
    touched = np.zeros((2, 4), bool)
    for _ in range(15):
        touched |= physics.step(cmd)
    assert touched[0].tolist() == [True, False, False, False]
    assert not touched[1].any()


def test_set_layouts_with_more_obstacles_rebuilds_and_keeps_state():
    physics = make_physics("quadrotor", n_worlds=2)
    for c in random_commands(physics, 3, seed=6):
        physics.step(c)
    before = full_state(physics)
    many = [{"cylinder": {"center": [1.0 + 0.8 * k, 18.0], "radius": 0.2}} for k in range(20)]
    physics.set_layouts([1], [open_layout(obstacles=many, name="many")])
    assert physics.model(1).ngeom == physics.model(0).ngeom
    assert np.array_equal(full_state(physics), before)
    physics.reset([1], SPREAD_XY[None])
    physics.step(np.zeros((2, 4, 2)))
    assert sum(physics.model(1).geom(f"obstacle_{k}").id >= 0 for k in range(20)) == 20


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_drone_ids_still_name_the_drones_after_a_rebuild(fidelity):
    """A rebuild for more obstacles adds padding geoms before the drones, so geom ids move:
    physics.ids must be looked up again on the new models."""
    physics = make_physics(fidelity, n_worlds=2)
    many = [{"cylinder": {"center": [1.0 + 0.8 * k, 18.0], "radius": 0.2}} for k in range(20)]
    physics.set_layouts([1], [open_layout(obstacles=many, name="many")])
    for w in range(2):
        model = physics.model(w)
        assert [model.geom(g).name for g in physics.ids.collision_geom] == [f"{n}/collision" for n in physics.names]
        assert [model.body(b).name for b in physics.ids.body] == [f"{n}/body" for n in physics.names]


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_state_arrays_have_documented_shapes(fidelity):
    physics = make_physics(fidelity, n_worlds=2)
    physics.step(np.zeros((2, 4, 2)))
    s = physics.state()
    assert s.pos.shape == s.vel.shape == s.angvel.shape == (2, 4, 3)
    assert s.quat.shape == s.thrust.shape == (2, 4, 4)
    np.testing.assert_allclose(np.linalg.norm(s.quat, axis=-1), 1.0)
    np.testing.assert_allclose(s.pos[..., :2], np.broadcast_to(SPREAD_XY, (2, 4, 2)), atol=0.01)
    if fidelity == "quadrotor":  # hovering: four rotors together carry the weight
        np.testing.assert_allclose(s.thrust.sum(-1), physics.params["mass"] * 9.81, rtol=0.02)
    s.pos[:] = 0  # a copy: the simulation is unaffected
    assert physics.positions()[0, 0, 0] == pytest.approx(SPREAD_XY[0, 0], abs=0.01)


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_commands_are_clipped_to_each_drones_max_speed(fidelity):
    physics = make_physics(fidelity)
    cmd = np.full((1, 4, 2), 3.0)
    physics.step(cmd)
    np.testing.assert_allclose(np.linalg.norm(physics.commands[0], axis=-1), physics.max_speed)
    np.testing.assert_allclose(physics.commands[0, :, 0], physics.commands[0, :, 1])  # direction kept


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_observers_run_after_every_physics_chunk(fidelity):
    physics = make_physics(fidelity)
    calls = []
    physics.observers.append(lambda p: calls.append(p.positions()[0, 0, 0]))
    physics.step(np.zeros((1, 4, 2)))
    c = physics.config
    assert len(calls) == c.substeps // c.substeps_per_control  # every controller tick, in both fidelities


@pytest.mark.parametrize(
    "commands, message",
    [
        (np.zeros((1, 3, 2)), r"expected shape \(1, 4, 2\).*got \(1, 3, 2\)"),
        (np.zeros((4, 2)), r"expected shape \(1, 4, 2\).*got \(4, 2\)"),
        (np.array([[[0, 0]] * 3 + [[np.nan, 0]]]), r"non-finite value nan at index \(0, 3, 0\)"),
        (np.array([[[0, 0], [0, np.inf], [0, 0], [0, 0]]]), r"non-finite value inf at index \(0, 1, 1\)"),
        ("fast", r"commands: expected a numeric array"),
        # no velocities, though numpy would turn them into some: True is 1 m/s, "0.1" is 0.1 m/s,
        # and 1+1j lost its imaginary part with only a warning
        (np.ones((1, 4, 2), bool), r"commands: expected a numeric array .* got an array of dtype bool"),
        (np.full((1, 4, 2), "0.1"), r"commands: expected a numeric array .* got an array of dtype <U3"),
        (np.full((1, 4, 2), 1 + 1j), r"commands: expected a numeric array .* got an array of dtype complex128"),
        ([[[0, 0], [0, 0], [0, 0], [0]]], r"commands: expected a numeric array"),  # ragged
    ],
)
def test_bad_commands_raise_value_error_naming_the_problem(commands, message):
    physics = make_physics("point")
    with pytest.raises(ValueError, match=message):
        physics.step(commands)


def test_bad_reset_and_layout_arguments_raise_value_error():
    physics = make_physics("point", n_worlds=2)
    with pytest.raises(ValueError, match=r"reset positions: expected shape \(1, 4, 2\)"):
        physics.reset([0], np.zeros((1, 3, 2)))
    with pytest.raises(ValueError, match=r"world index out of range 0..1 in \[2\]"):
        physics.reset([2], np.zeros((1, 4, 2)))
    with pytest.raises(ValueError, match=r"repeated world index"):
        physics.reset([0, 0], np.zeros((2, 4, 2)))
    with pytest.raises(ValueError, match=r"non-finite"):
        physics.reset([0], np.full((1, 4, 2), np.nan))
    with pytest.raises(ValueError, match=r"2 world ids but 1 layouts"):
        physics.set_layouts([0, 1], [open_layout()])
    with pytest.raises(ValueError, match=r"layouts is empty"):
        BatchedPhysics(default_config(), [])


@pytest.mark.parametrize("change,message", [
    ({"command_latency": 0.004}, r"key 'command_latency': 0.004 s is not a whole number of controller ticks"),
    ({"controller_hz": 150.0}, r"controller_hz 150.0 does not divide the physics rate"),
    ({"physics_dt": 0.003}, r"control_dt 0.1 is not a whole number of physics_dt 0.003"),
    ({"pursuer_speed": -0.3}, r"key 'pursuer_speed': -0.3 is out of range"),
    ({"drone_mass": 0.1}, r"key 'drone_mass': 0.1 kg is more than the rotors can fly"),
], ids=["latency-between-ticks", "controller-rate", "physics-dt", "negative-speed", "too-heavy"])
def test_a_config_that_skipped_the_loaders_checks_is_refused_naming_the_key(change, message):
    """A TaskConfig changed with dataclasses.replace skips the loader's checks; BatchedPhysics
    checks it as PursuitEnv does, instead of rounding a latency of 0.4 ticks to none, running
    the controller at 167 Hz for 150, reversing every command of a negative speed or flying a
    drone its rotors cannot lift."""
    config = dataclasses.replace(default_config(), **change)
    with pytest.raises(ConfigError, match=r"BatchedPhysics config: " + message):
        BatchedPhysics(config, [open_layout()], nthread=1)


def test_a_diverged_world_is_reported_by_index():
    physics = make_physics("quadrotor", n_worlds=2)
    physics.qpos[1, 0] = np.nan  # MuJoCo resets a simulation that goes non-finite
    with pytest.raises(FloatingPointError, match=r"worlds \[1\] \(MuJoCo warnings: BADQPOS"):
        physics.step(np.zeros((2, 4, 2)))
    physics.reset([1], SPREAD_XY[None])  # a reset heals it
    physics.step(np.zeros((2, 4, 2)))


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_halting_drones_of_several_worlds_at_once_is_halting_each_world_in_turn(fidelity):
    together, in_turn = make_physics(fidelity, n_worlds=3), make_physics(fidelity, n_worlds=3)
    for c in random_commands(together, 3, seed=11):
        together.step(c)
        in_turn.step(c)
    worlds, drones = np.array([2, 0, 2, 1]), np.array([1, 3, 0, 3])
    together.halt(worlds, drones)
    for w in (0, 1, 2):
        in_turn.halt(worlds[worlds == w], drones[worlds == w])
    assert np.array_equal(full_state(together), full_state(in_turn))
    assert (together.velocities()[worlds, drones] == 0).all()


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_halt_stops_only_the_named_drones_and_refuses_bad_indices(fidelity):
    physics = make_physics(fidelity, n_worlds=2)
    for c in random_commands(physics, 3, seed=7):
        physics.step(c)
    before = full_state(physics)
    for worlds, drones, message in [([-1], [0], "index out of range"), ([0], [-4], "index out of range"),  # wrapped silently
                                    ([0], [4], "index out of range"), ([0, 1], [1], "equal length"), ([0.0], [1], "integer")]:
        with pytest.raises(ValueError, match=message):
            physics.halt(np.array(worlds), np.array(drones))
        assert np.array_equal(full_state(physics), before)  # nothing changed before the refusal
    physics.halt(np.array([1, 1]), np.array([0, 3]))
    v = physics.velocities()
    assert (v[1, [0, 3]] == 0).all() and (v[1, [1, 2]] != 0).any() and (v[0] != 0).any()
    assert np.array_equal(full_state(physics)[0], before[0])
    np.testing.assert_allclose(physics.quaternions()[1, [0, 3], 1:3], 0.0, atol=1e-12)  # levelled, yaw kept


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_a_diverged_world_is_told_as_a_python_warning_with_mujocos_words_and_no_log_file(fidelity, tmp_path, monkeypatch, capfd):
    """MuJoCo's own handler printed its warning and appended it to MUJOCO_LOG.TXT in whatever
    folder the user ran from; the step now says it once, as a RuntimeWarning naming the worlds."""
    import mujoco

    monkeypatch.chdir(tmp_path)
    physics = make_physics(fidelity, n_worlds=3)
    physics.qvel[1, :] = 1e12
    with pytest.warns(RuntimeWarning, match=r"physics diverged in worlds \[1\] \(MuJoCo warnings: BADQVEL; MuJoCo: Nan, Inf or huge value in QVEL") as caught:
        physics.step(np.zeros((3, 4, 2)), strict=False)
    assert len(caught) == 1
    assert physics.diverged.tolist() == [False, True, False]
    assert list(tmp_path.iterdir()) == []
    out, err = capfd.readouterr()
    assert "Nan" not in out + err  # pytest.warns took the warning; MuJoCo printed nothing
    assert mujoco.get_mju_user_warning() is None  # MuJoCo's own handling outside the step, as before
    physics.reset([1], SPREAD_XY[None])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        physics.step(np.zeros((3, 4, 2)), strict=False)  # healed: nothing to tell


def test_a_strict_step_names_mujocos_words_in_its_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    physics = make_physics("point", n_worlds=2)
    physics.qvel[0, :] = 1e12
    with pytest.raises(FloatingPointError, match=r"worlds \[0\] \(MuJoCo warnings: BADQVEL; MuJoCo: Nan, Inf or huge value in QVEL"):
        physics.step(np.zeros((2, 4, 2)))
    assert list(tmp_path.iterdir()) == []


def test_a_warning_handler_of_ones_own_keeps_getting_mujocos_warnings(tmp_path, monkeypatch):
    import mujoco

    monkeypatch.chdir(tmp_path)
    got: list[str] = []
    mujoco.set_mju_user_warning(got.append)
    try:
        physics = make_physics("point", n_worlds=2)
        physics.qvel[0, :] = 1e12
        with pytest.warns(RuntimeWarning, match=r"physics diverged in worlds \[0\]"):
            physics.step(np.zeros((2, 4, 2)), strict=False)
        assert len(got) == 1 and got[0].startswith("Nan, Inf or huge value in QVEL")
        assert mujoco.get_mju_user_warning() is not None
    finally:
        mujoco.set_mju_user_warning(None)


def test_no_python_runs_in_mujocos_callbacks_and_the_log_settings_come_back(tmp_path, monkeypatch):
    """A warning handler in Python ran inside MuJoCo's C++ callback, where an exception (Ctrl-C
    arriving then) ends the process: the step turns MuJoCo's log off instead, reads the warnings
    from its counters, and puts the settings back after, also when steps overlap (one inside
    another's observer, as threads would)."""
    import mujoco

    monkeypatch.chdir(tmp_path)
    outer, inner = make_physics("point", n_worlds=2), make_physics("point", n_worlds=2)
    inside = []

    def step_the_other(_physics):
        if not inside:
            inside.append((mujoco.get_mju_user_warning(), mujoco.MjLogConfig.get().logto_file))
            inner.qvel[1, :] = 1e12
            with pytest.warns(RuntimeWarning, match=r"worlds \[1\] \(MuJoCo warnings: BADQVEL; MuJoCo: Nan, Inf or huge value in QVEL"):
                inner.step(np.zeros((2, 4, 2)), strict=False)
            inside.append(mujoco.MjLogConfig.get().logto_file)  # the outer step is still open

    outer.observers.append(step_the_other)
    outer.step(np.zeros((2, 4, 2)))
    assert inside == [(None, False), False]
    config = mujoco.MjLogConfig.get()
    assert (config.logto_console, config.logto_file) == (True, True)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("physics_dt", [0.002, 0.01])
@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_a_drone_at_the_fastest_accepted_speed_stops_at_a_1_mm_wall_and_never_passes_it(fidelity, physics_dt):
    """At the highest speed a task accepts (3 m/s) a drone moves at most 3 cm per physics step
    (physics_dt up to 0.01 s), under half its collision radius (0.0685 m): MuJoCo's contact
    catches it before its centre nears even a 1 mm wall, and pushes it back to the near side."""
    thickness, wall_x = 0.001, 10.0
    layout = open_layout(obstacles=[{"wall": {"from": [wall_x, 8.0], "to": [wall_x, 12.0], "thickness": thickness}}])
    xy = SPREAD_XY.copy()
    xy[3] = [8.5, 10.0]  # the evader, 1.5 m before the wall
    physics = make_physics(fidelity, layout=layout, xy=xy, evader_speed=3.0, physics_dt=physics_dt)
    face = wall_x - thickness / 2 - 0.0685  # the evader's centre where its cylinder touches the wall
    xs = []
    physics.observers.append(lambda p: xs.append(p.positions()[0, 3, 0]))
    cmd = np.zeros((1, 4, 2))
    cmd[0, 3] = [3.0, 0.0]
    touched = np.zeros(4, bool)
    for _ in range(25):
        touched |= physics.step(cmd)[0]
    assert touched.tolist() == [False, False, False, True]
    assert max(xs) < face + 0.03, f"{max(xs) - face:.4f} m into the wall"
    assert physics.positions()[0, 3, 0] == pytest.approx(face, abs=0.005)  # pressed against it, on the near side
