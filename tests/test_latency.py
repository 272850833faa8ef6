"""task.command_latency: a pursuer's velocity command takes effect that long after it is given
(the radio and motion-capture loop of real flights); the evaders' commands are not delayed."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_physics

from pursuit_mj.config import ConfigError, default_config

FIDELITIES = ("point", "quadrotor")
TICK = 0.01  # s: one controller tick at the default controller_hz (100 Hz)


def tick_velocities(physics, commands) -> np.ndarray:
    """(ticks, D, 2) m/s world: every drone's planar velocity after each controller tick of world 0,
    stepping `commands` (steps, D, 2) in turn."""
    seen = []
    physics.observers.append(lambda p: seen.append(p.velocities()[0, :, :2]))
    for c in commands:
        physics.step(c[None])
    return np.array(seen)


def held_command(physics, steps: int) -> np.ndarray:
    """(steps, D, 2): every drone told to fly at a different fixed velocity, the same at every step."""
    c = np.zeros((steps, physics.n_drones, 2))
    c[:, :, 0] = 0.2 * physics.max_speed / physics.max_speed.max()
    c[:, :, 1] = -0.1 * physics.max_speed / physics.max_speed.max()
    c[:, 1, 1] = 0.25
    return c


@pytest.mark.parametrize("fidelity", FIDELITIES)
@pytest.mark.parametrize("latency", [0.05, 0.15])
def test_a_held_command_moves_the_pursuers_exactly_the_latency_later(fidelity, latency):
    """From rest, a delayed pursuer's velocity at tick t is the undelayed one's at tick t - latency
    (shorter than one decision step, and one and a half); the evaders fly as without latency."""
    lag = round(latency / TICK)
    plain = make_physics(fidelity)
    delayed = make_physics(fidelity, command_latency=latency)
    commands = held_command(plain, 4)
    v_plain, v_delayed = tick_velocities(plain, commands), tick_velocities(delayed, commands)
    P = plain.config.n_pursuers
    tol = 0 if fidelity == "point" else 1e-3  # a hovering quadrotor is not perfectly at rest
    np.testing.assert_allclose(v_delayed[:lag, :P], 0.0, atol=tol)
    np.testing.assert_allclose(v_delayed[lag:, :P], v_plain[:-lag, :P], atol=tol)
    assert np.abs(v_delayed[-1, :P]).max() > 0.05  # they did get going
    assert np.array_equal(v_delayed[:, P:], v_plain[:, P:])


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_a_latency_of_two_decision_steps_plays_the_commands_two_steps_late(fidelity):
    rng = np.random.default_rng(3)
    plain = make_physics(fidelity)
    delayed = make_physics(fidelity, command_latency=0.2)
    P = plain.config.n_pursuers
    commands = rng.uniform(-0.3, 0.3, (8, plain.n_drones, 2))
    shifted = commands.copy()
    shifted[:, :P] = np.concatenate([np.zeros((2, P, 2)), commands[:-2, :P]])
    v_plain, v_delayed = tick_velocities(plain, shifted), tick_velocities(delayed, commands)
    if fidelity == "point":
        assert np.array_equal(v_delayed, v_plain)
    else:
        np.testing.assert_allclose(v_delayed, v_plain, atol=1e-9)


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_a_reset_drops_the_commands_still_on_their_way(fidelity):
    physics = make_physics(fidelity, n_worlds=2, command_latency=0.2)
    go = np.zeros((2, physics.n_drones, 2))
    go[:, :, 0] = 0.2
    physics.step(go)
    physics.step(go)
    physics.reset([0], physics.positions()[[0], :, :2])
    for _ in range(2):  # the last two steps whose commands are in force are the two gos
        physics.step(np.zeros_like(go))
    P = physics.config.n_pursuers
    speed = np.linalg.norm(physics.velocities()[:, :P, :2], axis=-1)
    assert speed[0].max() < 1e-3  # world 0 was reset: the go it was sent before never arrives
    assert speed[1].min() > 0.05  # world 1 was not: its pursuers fly the go, two steps late


def test_without_latency_nothing_changes():
    assert default_config().command_latency == 0.0
    plain, zero = make_physics("point"), make_physics("point", command_latency=0.0)
    commands = held_command(plain, 3)
    assert np.array_equal(tick_velocities(plain, commands), tick_velocities(zero, commands))


@pytest.mark.parametrize("value,message", [
    (0.015, r"command_latency': 0.015 s is not a whole number of controller ticks \(0.01 s at controller_hz 100\)"),
    (-0.1, r"command_latency"),
    (2.0, r"command_latency"),
])
def test_a_latency_that_is_no_whole_number_of_ticks_is_refused_naming_the_key(value, message):
    with pytest.raises(ConfigError, match=message):
        default_config(command_latency=value)


def test_the_tick_follows_controller_hz():
    assert default_config(controller_hz=250, command_latency=0.012).command_latency_ticks == 3
    with pytest.raises(ConfigError, match=r"controller_hz 250"):
        default_config(controller_hz=250, command_latency=0.01)


@pytest.mark.parametrize("controller_hz,control_dt,ticks", [
    (250, 0.2, 7), (250, 0.2, 50), (250, 0.2, 53), (500, 0.05, 24), (500, 0.05, 25), (500, 0.05, 61), (100, 0.05, 12),
])
def test_the_delay_is_whole_ticks_at_any_controller_rate_and_decision_interval(controller_hz, control_dt, ticks):
    """Point fidelity, stepped a decision at a time, flies exactly as a twin stepped a controller
    tick at a time under the pursuers' commands moved `ticks` ticks later (fewer than, a whole
    number of, and more than the ticks of a decision)."""
    rates = {"controller_hz": controller_hz}
    delayed = make_physics("point", control_dt=control_dt, command_latency=ticks / controller_hz, **rates)
    twin = make_physics("point", control_dt=1.0 / controller_hz, **rates)
    P, T = delayed.config.n_pursuers, round(control_dt * controller_hz)
    commands = np.random.default_rng(ticks).uniform(-0.3, 0.3, (4, delayed.n_drones, 2))
    per_tick = np.repeat(commands, T, axis=0)
    late = per_tick.copy()
    late[:, :P] = np.concatenate([np.zeros((ticks, P, 2)), per_tick[:, :P]])[:len(per_tick)]
    expected = []
    for c in late:
        twin.step(c[None])
        expected.append(twin.velocities()[0, :, :2])
    assert np.array_equal(tick_velocities(delayed, commands), np.array(expected))
