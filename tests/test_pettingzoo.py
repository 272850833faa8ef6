"""PettingZoo's own conformance tests on the ParallelEnv (and its AEC conversion), in both fidelities."""

import dataclasses

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test, state_test
from pettingzoo.utils.conversions import parallel_to_aec

from pursuit_mj.config import default_config
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.pz_env import PursuitParallelEnv


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_parallel_api(fidelity):
    env = PursuitParallelEnv(default_config(fidelity=fidelity, random_obstacles=2, max_steps=40))
    parallel_api_test(env, num_cycles=60)


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_parallel_seed(fidelity):
    parallel_seed_test(lambda: PursuitParallelEnv(default_config(fidelity=fidelity, random_obstacles=2, max_steps=30)), num_cycles=40)



@pytest.mark.filterwarnings("ignore:.*space value is .*infinity")  # the Boxes are unbounded on purpose
@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_the_aec_conversion_passes_the_aec_tests(fidelity):
    config = default_config(fidelity=fidelity, random_obstacles=2, max_steps=30, n_pursuers=2, n_evaders=2)
    api_test(parallel_to_aec(PursuitParallelEnv(config)), num_cycles=60)
    seed_test(lambda: parallel_to_aec(PursuitParallelEnv(config)), num_cycles=30)
    state_test(parallel_to_aec(PursuitParallelEnv(config)), PursuitParallelEnv(config), num_cycles=30)


def _drive(env, policy):
    """Plays one episode from reset(seed=0), checking every observation and state against the spaces;
    returns the last step's (terminations, truncations, infos) and the agents alive before it."""
    obs, _ = env.reset(seed=0)
    while True:
        for agent, o in obs.items():
            assert o.dtype == np.float32 and env.observation_space(agent).contains(o)
        assert env.state_space.contains(env.state())
        if not env.agents:
            return last, alive
        alive = list(env.agents)
        obs, _, terms, truncs, infos = env.step(policy(obs))
        last = terms, truncs, infos
        assert set(obs) == set(terms) == set(truncs) == set(infos) == set(alive)


@pytest.mark.parametrize("outcome, config, policy", [
    ("success", default_config(fidelity="point", n_pursuers=4, observability="full", random_obstacles=0), "heuristic"),
    ("collision", default_config(fidelity="quadrotor", n_pursuers=2, n_evaders=2), (1.0, 0.0)),
    ("timeout", default_config(fidelity="point", n_pursuers=1, n_evaders=3, max_steps=15), (0.0, 0.0)),
])
def test_every_ending_ends_every_agent_with_observations_in_their_space(outcome, config, policy):
    env = PursuitParallelEnv(config)
    if policy == "heuristic":
        team = HeuristicTeam.from_config(config)
        team.reset(1)
        act = lambda obs: dict(zip(env.agents, team.act(np.stack(list(obs.values()))[None], env.obs_spec)[0]))
    else:
        act = lambda obs: {a: np.array(policy) for a in env.agents}
    (terms, truncs, infos), alive = _drive(env, act)
    assert alive == env.possible_agents and env.agents == []
    assert all(terms[a] == (outcome != "timeout") and truncs[a] == (outcome == "timeout") for a in alive)
    assert {i["outcome"] for i in infos.values()} == {outcome}
    with pytest.raises(ValueError, match="finished episode"):
        env.step({a: np.zeros(2) for a in alive})
    env.close()
    env.close()  # closing twice is harmless

def test_action_dict_errors_name_the_agent():
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing agents \\['pursuer_2'\\]"):
        env.step({"pursuer_0": np.zeros(2), "pursuer_1": np.zeros(2)})
    with pytest.raises(ValueError, match="unknown agents \\['pursuer_9'\\]"):
        env.step({f"pursuer_{i}": np.zeros(2) for i in (0, 1, 2, 9)})
    with pytest.raises(ValueError, match="expected shape \\(2,\\)"):
        env.step({f"pursuer_{i}": np.zeros(3) for i in range(3)})
    with pytest.raises(ValueError, match="actions\\['pursuer_0'\\]: expected shape \\(2,\\), got a ragged list"):
        env.step({f"pursuer_{i}": [[0.1], 0.2] for i in range(3)})  # numpy's own message before


@pytest.mark.parametrize("bad, message", [
    (None, "got None$"),  # was "got ()": the shape numpy gives None, which the user never wrote
    (0.5, "got 0.5$"),  # one number where two belong
    ("ab", "got 'ab'$"),
    (np.zeros(3), r"got shape \(3,\): array\(\[0\., 0\., 0\.\]\)$"),
    (np.zeros(400), r"got shape \(400,\): array\(\[0\., 0\., .*\.\.\.$"),  # one line, cut short
])
def test_an_action_of_another_shape_is_shown_as_given(bad, message):
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"^actions\['pursuer_1'\]: expected shape \(2,\) \(vx, vy\), " + message) as caught:
        env.step({a: (bad if a == "pursuer_1" else np.zeros(2)) for a in env.agents})
    assert "\n" not in str(caught.value) and len(str(caught.value)) < 200


@pytest.mark.parametrize("bad, message", [
    (np.array([True, False]), "expected real numbers \\(vx, vy\\), got an array of dtype bool"),  # was full speed
    (np.array([0.5 + 1j, 0.0]), "got an array of dtype complex128"),  # was 0.5, the 1j dropped
    (["0.5", "0"], "got an array of dtype <U3"),  # was parsed as numbers
    (np.array([0.1, np.nan]), "non-finite value in \\[0.1, nan\\]"),
])
def test_actions_the_batched_env_refuses_are_refused_naming_the_agent(bad, message):
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"actions\\['pursuer_1'\\]: .*{message}"):
        env.step({a: (bad if a == "pursuer_1" else np.zeros(2)) for a in env.agents})
    with pytest.raises(ValueError, match="expected real numbers|non-finite"):  # the contract it follows
        env.batched.step(np.tile(np.asarray(bad), (1, 3, 1)))
    assert env.batched.steps[0] == 0 and env.agents == env.possible_agents  # nothing was stepped
    env.step({a: np.array([1, 0], np.int64) for a in env.agents})  # integers are numbers
    assert env.batched.steps[0] == 1


def test_reset_without_a_seed_moves_on_to_the_next_episode():
    env = PursuitParallelEnv(default_config(fidelity="point", max_steps=5))

    def start():
        obs, _ = env.reset()
        return obs["pursuer_0"].copy(), env.batched.snapshot().layout.obstacles

    first, second = start(), start()
    assert not np.array_equal(first[0], second[0]) or first[1] != second[1]
    env.reset(seed=0)
    replay = env.batched.snapshot().layout.obstacles
    assert replay == first[1]  # a seed restarts the sequence: episode 0 again


def test_agent_names_and_call_order_are_checked():
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    with pytest.raises(ValueError, match="before reset"):
        env.step({f"pursuer_{i}": np.zeros(2) for i in range(3)})
    with pytest.raises(RuntimeError, match="^state\\(\\) called before reset\\(\\)"):  # not the batched env's global_state()
        env.state()
    with pytest.raises(ValueError, match="no agent 'evader_0'"):
        env.observation_space("evader_0")


def test_render_mode_none_draws_nothing_and_unknown_modes_are_refused_by_name():
    config = default_config(fidelity="point", random_obstacles=0)
    env = PursuitParallelEnv(config, render_mode=None)  # what generic tooling passes
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode='rgb_array'"):
        assert env.render() is None
    with pytest.raises(ValueError, match="render_mode: 'human' is not supported"):
        PursuitParallelEnv(config, render_mode="human")


def test_rgb_array_mode_renders_each_step_as_the_render_command_draws_it():
    from pursuit_mj.render.renderer import RenderSettings

    config = default_config(fidelity="point", random_obstacles=0)
    env = PursuitParallelEnv(config, render_mode="rgb_array", render_settings=RenderSettings(240, 180))
    assert env.metadata["render_fps"] == pytest.approx(1.0 / config.control_dt)
    with pytest.raises(RuntimeError, match="before reset"):
        env.render()
    obs, _ = env.reset(seed=0)
    first = env.render()
    assert first.shape == (180, 240, 3) and first.dtype == np.uint8 and first.std() > 0
    for _ in range(5):
        env.step({a: np.array([1.0, 0.0]) for a in env.agents})
    moved = env.render()
    assert moved.shape == first.shape and np.abs(moved.astype(int) - first).sum() > 0  # the drones flew east
    env.close()
    env.close()  # harmless twice
    with pytest.raises(RuntimeError, match=r"render\(\) called after close\(\): call reset\(\) to draw again"):
        env.render()  # it said "called before reset()" of an env that had been reset
    env.reset(seed=0)  # episode 0 again: the same picture, caption and all (it said "episode 1", counting resets)
    assert np.array_equal(env.render(), first)
    env.close()


@pytest.mark.parametrize("actions", [np.zeros((3, 2)), [np.zeros(2)] * 3, None])
def test_actions_that_are_not_a_dict_are_refused_clearly(actions):
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=f"actions: expected a dict .* got {type(actions).__name__}"):
        env.step(actions)
    assert env.batched.steps[0] == 0


@pytest.mark.parametrize("config", [{}, {"n_pursuers": 4}, "hard"])
def test_a_config_that_is_not_a_task_config_is_refused_by_name(config):
    """{} passed as 'no config' and trained the default task; a filled dict crashed in an attribute lookup."""
    from pursuit_mj.config import ConfigError

    with pytest.raises(ConfigError, match=f"PursuitParallelEnv config: expected a TaskConfig .* got {type(config).__name__}"):
        PursuitParallelEnv(config)


@pytest.mark.parametrize("settings", [(320, 240), "big", {"width": 320}])
def test_render_settings_that_are_not_render_settings_are_refused_by_name_when_made(settings):
    """A (width, height) tuple passed, then failed at the first reset with "'tuple' object has no attribute 'check'"."""
    with pytest.raises(ValueError, match=f"render_settings: expected a pursuit_mj.render.renderer.RenderSettings .*got {type(settings).__name__}"):
        PursuitParallelEnv(default_config(fidelity="point"), render_mode="rgb_array", render_settings=settings)


def test_a_bad_seed_is_refused_naming_the_env_the_user_made():
    with pytest.raises(ValueError, match=r"^PursuitParallelEnv seed: expected a non-negative integer below 2\*\*63, got -1"):
        PursuitParallelEnv(seed=-1)


@pytest.mark.parametrize("changes, message", [
    ({"width": 5}, r"render_settings.width 5: must be an integer in 16\.\.\d+ pixels"),
    ({"height": 20}, r"render_settings.height 20: too small to hold"),
    ({"quality": "ultra"}, r"render_settings.quality 'ultra': choose from fast, high"),
    ({"camera": "side"}, r"render_settings.camera 'side': no such camera"),
    ({"camera": "follow:evader_9"}, r"render_settings.camera 'follow:evader_9': no drone named 'evader_9'"),
])
def test_bad_render_settings_values_are_refused_by_their_field_when_made(changes, message):
    """They were accepted, then refused at the first reset() naming render's CLI flags (--width 5, --camera),
    which a PettingZoo user never passed."""
    from pursuit_mj.render.renderer import RenderSettings

    settings = dataclasses.replace(RenderSettings(), **changes)
    with pytest.raises(ValueError, match=f"^{message}"):
        PursuitParallelEnv(default_config(fidelity="point"), render_mode="rgb_array", render_settings=settings)


def test_render_settings_without_a_render_mode_are_refused_rather_than_ignored():
    from pursuit_mj.render.renderer import RenderSettings

    with pytest.raises(ValueError, match=r"render_settings: given without render_mode='rgb_array'"):
        PursuitParallelEnv(render_settings=RenderSettings())


def test_the_space_dicts_of_the_parallel_api_are_there():
    """PettingZoo's ParallelEnv declares observation_spaces and action_spaces; tools that read
    them (wrappers, SuperSuit) failed with an AttributeError."""
    env = PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0))
    assert set(env.observation_spaces) == set(env.action_spaces) == set(env.possible_agents)
    for agent in env.possible_agents:
        assert env.observation_spaces[agent] == env.observation_space(agent)
        assert env.action_spaces[agent] == env.action_space(agent)


def test_close_frees_the_simulation_a_step_after_it_says_so_and_a_reset_plays_on():
    """close() freed the renderer only, leaving the MuJoCo batch to the garbage collector; it now
    closes the one-world PursuitEnv too. A step after close() says so (in the words of a step
    before reset()); reset() plays on as if never closed."""
    envs = [PursuitParallelEnv(default_config(fidelity="point", random_obstacles=0), seed=2) for _ in range(2)]
    for env in envs:
        env.reset(seed=0)
    envs[1].close()
    envs[1].close()  # harmless twice
    assert envs[1].batched.closed
    with pytest.raises(ValueError, match=r"step\(\) called after close\(\): call reset\(\) first"):
        envs[1].step({a: np.zeros(2) for a in envs[1].possible_agents})
    first = [env.reset()[0] for env in envs]
    for a in envs[0].possible_agents:
        np.testing.assert_array_equal(first[0][a], first[1][a])
    stepped = [env.step({a: np.array([0.5, 0.5]) for a in env.agents})[1] for env in envs]
    assert stepped[0] == stepped[1]
