"""The gymnasium VectorEnv (pursuit_mj.vector_env): slots are the batched env's pursuers, both
autoreset modes, and gymnasium's own vector wrappers on it."""

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import ClipAction, NormalizeObservation, RecordEpisodeStatistics

from pursuit_mj.config import default_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.heuristic import HeuristicTeam
from pursuit_mj.vector_env import PursuitVectorEnv

W, N = 3, 3


def config(**changes):
    return default_config(**{"fidelity": "point", "max_steps": 12, **changes})


def actions(t: int, scale: float = 0.3) -> np.ndarray:
    """(W, N, 2) deterministic actions for step t, varied per slot and step (at scale 0.3 no pursuer
    reaches a wall or teammate within 30 steps of these episodes: every episode is a timeout)."""
    rng = np.random.default_rng(100 + t)
    return rng.uniform(-scale, scale, (W, N, 2))


def test_spaces_and_slot_count():
    env = PursuitVectorEnv(config(), n_worlds=W, seed=1)
    assert env.num_envs == W * N and env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.single_observation_space.shape == (env.batched.obs_dim,) and env.single_action_space.shape == (2,)
    assert env.observation_space.shape == (W * N, env.batched.obs_dim) and env.action_space.shape == (W * N, 2)
    obs, info = env.reset(seed=2)
    assert obs.dtype == np.float32 and obs in env.observation_space and info == {}
    obs, rew, term, trunc, info = env.step(env.action_space.sample())
    assert obs in env.observation_space and rew.dtype == np.float64 and rew.shape == term.shape == trunc.shape == (W * N,)
    assert set(info["reward_terms"]) >= {"capture", "progress", "_capture", "_progress"}


def test_same_step_slots_are_the_batched_envs_pursuers_with_final_observations():
    vec = PursuitVectorEnv(config(), n_worlds=W, seed=4, autoreset_mode=AutoresetMode.SAME_STEP)
    ref = PursuitEnv(config(), n_worlds=W, seed=4)
    obs = vec.reset(seed=7)[0]
    np.testing.assert_array_equal(obs, ref.reset(seed=7).reshape(W * N, -1))
    ends = 0
    for t in range(30):  # two timeouts at max_steps 12 and the start of a third episode
        obs, rew, term, trunc, info = vec.step(actions(t).reshape(W * N, 2))
        r_obs, r_rew, r_term, r_trunc, r_info = ref.step(actions(t))
        np.testing.assert_array_equal(obs, r_obs.reshape(W * N, -1))  # slot w * N + n is pursuer n of world w
        np.testing.assert_array_equal(rew, r_rew.reshape(-1))
        np.testing.assert_array_equal(term, np.repeat(r_term, N))
        np.testing.assert_array_equal(trunc, np.repeat(r_trunc, N))
        for k, v in r_info["reward_terms"].items():
            np.testing.assert_array_equal(info["reward_terms"][k], v.reshape(-1))
        ended = np.repeat(r_term | r_trunc, N)
        if ended.any():
            ends += 1
            np.testing.assert_array_equal(info["_final_obs"], ended)
            for i in range(W * N):
                if ended[i]:
                    np.testing.assert_array_equal(info["final_obs"][i], r_info["final_obs"][i // N, i % N])
                    assert info["final_info"]["outcome"][i] == "timeout" and info["final_info"]["_outcome"][i]
                else:
                    assert info["final_obs"][i] is None
            assert not np.array_equal(obs[ended], info["final_obs"][ended][0][None])  # the new episode's first
        else:
            assert "final_obs" not in info
    assert ends == 2


def test_same_step_collisions_and_out_of_box_actions_match_the_batched_env():
    vec = PursuitVectorEnv(config(), n_worlds=W, seed=4, autoreset_mode=AutoresetMode.SAME_STEP)
    ref = PursuitEnv(config(), n_worlds=W, seed=4)
    vec.reset(seed=3), ref.reset(seed=3)
    collided = 0
    for t in range(30):
        a = actions(t, scale=1.2)  # some outside the Box: clipped as PursuitEnv clips them
        obs, rew, term, _, info = vec.step(a.reshape(W * N, 2))
        r_obs, r_rew, r_term, *_ = ref.step(a)
        np.testing.assert_array_equal(obs, r_obs.reshape(W * N, -1))
        np.testing.assert_array_equal(rew, r_rew.reshape(-1))
        np.testing.assert_array_equal(term, np.repeat(r_term, N))
        assert set(info["outcome"][term]) <= {"collision"}
        collided += int(term.sum())
    assert collided >= N  # a world's episode ended in a collision in these 30 steps


def test_next_step_mode_restarts_a_step_later_into_the_same_episodes():
    """NEXT_STEP returns the last observation at the end, then the next step restarts the world
    (reward 0, no flag, its actions ignored) into the episode SAME_STEP starts at once."""
    nxt = PursuitVectorEnv(config(), n_worlds=W, seed=4)
    same = PursuitVectorEnv(config(), n_worlds=W, seed=4, autoreset_mode="SameStep")
    nxt.reset(seed=7), same.reset(seed=7)
    for t in range(12):
        obs, rew, term, trunc, info = nxt.step(actions(t).reshape(W * N, 2))
        s_obs, s_rew, *_, s_info = same.step(actions(t).reshape(W * N, 2))
        np.testing.assert_array_equal(rew, s_rew)
    assert trunc.all() and "final_obs" not in info
    np.testing.assert_array_equal(obs, np.stack(list(s_info["final_obs"])))  # the ended episode's last
    assert (info["outcome"] == "timeout").all()
    obs, rew, term, trunc, info = nxt.step(np.full((W * N, 2), 7.0))  # ignored: the worlds restart
    np.testing.assert_array_equal(obs, s_obs)  # the new episodes' first observation
    assert not (rew.any() or term.any() or trunc.any()) and (info["outcome"] == "").all()
    for t in range(12, 20):  # and both then play the same episodes
        obs, rew, *_ = nxt.step(actions(t).reshape(W * N, 2))
        s_obs, s_rew, *_ = same.step(actions(t).reshape(W * N, 2))
        np.testing.assert_array_equal(obs, s_obs)
        np.testing.assert_array_equal(rew, s_rew)


def test_a_capture_terminates_every_slot_of_its_world_only():
    cfg = config(evader_speed=0.3, max_steps=400, n_pursuers=N)
    vec = PursuitVectorEnv(cfg, n_worlds=W, seed=0)
    team = HeuristicTeam.from_config(cfg)
    team.reset(W)
    obs, _ = vec.reset(seed=0)
    for _ in range(400):
        act = team.act(obs.reshape(W, N, -1), vec.obs_spec).reshape(W * N, 2)
        obs, rew, term, trunc, info = vec.step(act)
        if term.any():
            break
    assert term.any(), "the heuristic team caught no evader in 400 steps"
    worlds = term.reshape(W, N)
    assert (worlds.all(1) | ~worlds.any(1)).all()  # a world's slots end together
    assert set(info["outcome"][term]) == {"success"} and not trunc.any()
    assert (rew[term] >= cfg.capture_reward).all()


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_gymnasiums_episode_statistics_wrapper_counts_whole_episodes(mode):
    env = PursuitVectorEnv(config(), n_worlds=W, seed=4, autoreset_mode=mode)
    wrapped = RecordEpisodeStatistics(ClipAction(env))
    wrapped.reset(seed=3)
    returns, stats = np.zeros(W * N), None
    for t in range(12):
        _, rew, _, _, info = wrapped.step(actions(t).reshape(W * N, 2))
        returns += rew
        stats = info.get("episode", stats)
    assert stats is not None and info["_episode"].all()
    np.testing.assert_array_equal(stats["l"], np.full(W * N, 12))
    np.testing.assert_allclose(stats["r"], returns)


def test_gymnasiums_observation_wrappers_run_on_the_default_mode():
    env = NormalizeObservation(PursuitVectorEnv(config(), n_worlds=W, seed=4))
    obs, _ = env.reset(seed=1)
    for t in range(20):  # across an end and its restart
        obs, *_ = env.step(actions(t).reshape(W * N, 2))
    assert obs.shape == (W * N, env.single_observation_space.shape[0]) and np.isfinite(obs).all()


def test_reset_with_a_seed_replays_and_without_moves_on():
    env = PursuitVectorEnv(config(), n_worlds=W, seed=4)
    first = env.reset(seed=9)[0]
    np.testing.assert_array_equal(env.reset(seed=9)[0], first)
    assert not np.array_equal(env.reset()[0], first)


@pytest.mark.parametrize("call, message", [
    (lambda e: e.step(np.zeros((W * N, 3))), f"actions: expected shape ({W * N}, 2), one row per slot ({W} worlds x {N} pursuers), got ({W * N}, 3)"),
    (lambda e: e.step(np.full((W * N, 2), np.nan)), "nan"),
    (lambda e: e.step([[0.0, 0.0]] * (W * N - 1) + [[0.0]]), f"actions: expected shape ({W * N}, 2), got a ragged list"),
    (lambda e: e.step(np.ma.masked_array(np.zeros((W * N, 2)), mask=np.eye(W * N, 2))), "actions: a masked array"),
    (lambda e: e.reset(seed=[1] * (W * N)), "reset seed: expected an int or None"),
    (lambda e: e.reset(seed=True), "reset seed: expected an int or None"),
    (lambda e: e.reset(options={"layout": 2}), "reset options: PursuitVectorEnv takes none"),
])
def test_bad_input_is_refused_naming_it(call, message):
    env = PursuitVectorEnv(config(), n_worlds=W, seed=4)
    env.reset()
    with pytest.raises(ValueError) as err:
        call(env)
    assert message in str(err.value).lower() if message == "nan" else message in str(err.value)


def test_bad_construction_and_misuse_are_refused():
    with pytest.raises(ValueError, match="autoreset_mode: expected one of AutoresetMode.NEXT_STEP"):
        PursuitVectorEnv(config(), autoreset_mode=AutoresetMode.DISABLED)
    with pytest.raises(ValueError, match="n_worlds"):
        PursuitVectorEnv(config(), n_worlds=0)
    env = PursuitVectorEnv(config())
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros((N, 2)))
    env.reset()
    with pytest.warns(UserWarning, match="render_mode='rgb_array'"):
        assert env.render() is None
    with pytest.raises(ValueError, match="render_mode: 'human' is not supported"):
        PursuitVectorEnv(config(), render_mode="human")


def test_rgb_array_mode_draws_each_world_for_its_slots():
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(random_obstacles=0), n_worlds=2, seed=4, render_mode="rgb_array",
                           render_settings=RenderSettings(160, 120))
    with pytest.raises(RuntimeError, match="before reset"):
        env.render()
    env.reset(seed=0)
    first = env.render()
    assert len(first) == 2 * N and first[0].shape == (120, 160, 3) and first[0].dtype == np.uint8
    assert all(f is first[0] for f in first[:N]) and all(f is first[N] for f in first[N:])  # a world's slots share it
    assert not np.array_equal(first[0], first[N])  # two worlds, two episodes
    for _ in range(5):
        env.step(np.tile([1.0, 0.0], (2 * N, 1)))
    moved = env.render()
    assert np.abs(moved[0].astype(int) - first[0]).sum() > 0  # the drones flew east, trails behind them
    env.close()
    env.reset(seed=0)  # a new renderer after close, the same first picture
    assert np.array_equal(env.render()[0], first[0])
    env.close()
    assert env._frames is None  # the second close freed the second renderer too


def test_the_documented_loop_runs_as_written(capsys):
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "docs" / "env_api.md").read_text()
    block = re.search(r"```python\n# gym_loop.py\n(.*?)```", text, re.S)
    assert block, "docs/env_api.md lost its gym_loop.py example"
    exec(compile(block.group(1), "docs/env_api.md: gym_loop.py", "exec"), {})
    lines = capsys.readouterr().out.splitlines()
    assert lines and all(re.fullmatch(r"episodes ended: \d+, mean return -?\d+\.\d\d, \d+ steps", line) for line in lines), lines


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_a_restarted_worlds_trails_start_again(mode):
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(max_steps=4), n_worlds=2, seed=4, render_mode="rgb_array",
                           render_settings=RenderSettings(64, 48), autoreset_mode=mode)
    env.reset(seed=0)
    lengths = []
    for t in range(6):
        env.step(actions(t)[:2].reshape(2 * N, 2))
        lengths.append([trail.array().shape[0] for trail in env._frames.trails])
    # 4 steps, then the restart: at once (SAME_STEP) or one step later (NEXT_STEP), with a fresh trail
    expected = [2, 3, 4, 1, 2, 3] if mode == "SameStep" else [2, 3, 4, 5, 1, 2]
    assert lengths == [[n, n] for n in expected]
    env.close()


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_per_world_seeds_given_to_the_batched_env_are_the_episodes_played(mode):
    """The docs send per-world episode seeds to env.batched.reset(seeds=...): the vector env steps
    those episodes, before its own first reset as after an episode end (NEXT_STEP restarted the
    worlds that had ended a second time, into their default sequence's next episode, and refused
    a step before env.reset())."""
    cfg = config(max_steps=3)
    vec = PursuitVectorEnv(cfg, n_worlds=2, seed=0, autoreset_mode=mode)
    ref = PursuitEnv(cfg, n_worlds=2, seed=0)
    for first in (True, False):
        if not first:
            vec.reset(seed=0)
            for _ in range(3):  # every world's episode ends (a timeout)
                *_, trunc, _ = vec.step(np.zeros((2 * N, 2)))
            assert trunc.all()
        obs = vec.batched.reset(seeds=[11, 12])
        np.testing.assert_array_equal(obs, ref.reset(seeds=[11, 12]))
        np.testing.assert_array_equal(vec.step(np.zeros((2 * N, 2)))[0], ref.step(np.zeros((2, N, 2)))[0].reshape(2 * N, -1))


def test_a_non_finite_or_non_real_action_is_named_by_its_slot():
    """The index is the slot's in the (num_envs, 2) array given (it was the batched env's
    (world, pursuer, component), an index the caller's array does not have)."""
    env = PursuitVectorEnv(config(), n_worlds=2, seed=4)
    env.reset()
    a = np.zeros((2 * N, 2))
    a[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"^actions: non-finite value nan at slot 4 \(world 1, pursuer 1\), component 1$"):
        env.step(a)
    for bad, kind in ((np.ones((2 * N, 2), bool), "bool"), (None, "object")):
        with pytest.raises(ValueError, match=rf"^actions: expected real numbers, one row \(vx, vy\) per slot, got an array of dtype {kind}"):
            env.step(bad)


def test_render_after_close_says_so():
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(random_obstacles=0), n_worlds=1, seed=4, render_mode="rgb_array",
                           render_settings=RenderSettings(64, 48))
    env.reset()
    env.close()
    with pytest.raises(RuntimeError, match=r"render\(\) called after close\(\): call reset\(\) to draw again"):
        env.render()


def test_a_step_after_close_makes_no_renderer_that_close_cannot_free():
    """close() marks the env closed and a second close() does nothing (gymnasium's VectorEnv.close):
    a step after close() made a new OpenGL renderer that no close() freed any more."""
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(random_obstacles=0), n_worlds=1, seed=4, render_mode="rgb_array",
                           render_settings=RenderSettings(64, 48))
    env.reset()
    env.close()
    with pytest.raises(RuntimeError, match=r"step\(\) called after close\(\): call reset\(\) first"):
        env.step(np.zeros((N, 2)))  # close() freed the simulation too (PursuitEnv.close)
    env.close()
    assert env._frames is None
    with pytest.raises(RuntimeError, match=r"render\(\) called after close\(\): call reset\(\) to draw again"):
        env.render()
    env.reset()  # a reset draws again, and the next close() frees that renderer
    assert env.render()[0].shape == (48, 64, 3)
    env.close()
    assert env._frames is None


def test_a_reward_term_named_like_an_info_mask_is_refused():
    """gymnasium's vector infos keep '_KEY' for the mask of KEY: a term '_capture' replaced the mask
    of 'capture' (or was replaced by it), and DictInfoToList drops every '_' key."""
    with pytest.raises(ValueError, match="PursuitVectorEnv extra_rewards: '_capture' starts with '_'"):
        PursuitVectorEnv(config(), extra_rewards={"_capture": lambda step: np.zeros(step.steps.shape + (N,))})


def test_gymnasium_make_vec_makes_it_by_its_id():
    import gymnasium

    from pursuit_mj.vector_env import ENV_ID

    env = gymnasium.make_vec(f"pursuit_mj.vector_env:{ENV_ID}", num_envs=2 * N, config=config(), seed=4)
    assert isinstance(env, PursuitVectorEnv) and env.num_envs == 2 * N and env.n_worlds == 2 and env.spec.id == ENV_ID
    same = PursuitVectorEnv(config(), n_worlds=2, seed=4)
    np.testing.assert_array_equal(env.reset(seed=1)[0], same.reset(seed=1)[0])
    with pytest.raises(ValueError, match=rf"num_envs: expected a positive multiple of n_pursuers \({N}: one slot per pursuer"):
        gymnasium.make_vec(ENV_ID, num_envs=N + 1, config=config())
    with pytest.raises(ValueError, match=r"max_episode_steps: the task's own max_steps is the time limit"):
        gymnasium.make_vec(ENV_ID, num_envs=N, max_episode_steps=50)
    with pytest.raises(ValueError, match="give num_envs"):
        gymnasium.make_vec(ENV_ID, num_envs=N, n_worlds=1)
    with pytest.raises(ValueError, match=r"is a vector env .* gymnasium.make_vec"):
        gymnasium.make(ENV_ID)


def test_trails_start_again_for_episodes_started_on_the_batched_env():
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(), n_worlds=2, seed=4, render_mode="rgb_array", render_settings=RenderSettings(64, 48))
    env.reset(seed=0)
    for t in range(3):
        env.step(actions(t)[:2].reshape(2 * N, 2))
    assert [trail.array().shape[0] for trail in env._frames.trails] == [4, 4]
    env.batched.reset(seeds=[11, 12])  # per-world seeds, as the docs say
    env.step(actions(0)[:2].reshape(2 * N, 2))
    assert [trail.array().shape[0] for trail in env._frames.trails] == [1, 1]  # the new episodes' first step only
    env.close()


@pytest.mark.parametrize("mode", ["NextStep", "SameStep"])
def test_an_ending_step_gives_its_episode_records_and_same_step_the_final_state(mode):
    """The docs sent users to env.batched for episode records, which it keeps nowhere (PursuitEnv
    gives them only in its step's info, which the vector env dropped), and SAME_STEP dropped the
    final global state that a centralised critic bootstraps a timeout from (the world has restarted
    by the time the step returns). Both now come in the ending step's infos, gymnasium-style."""
    cfg = config(max_steps=3)
    vec = PursuitVectorEnv(cfg, n_worlds=2, seed=0, autoreset_mode=mode)
    ref = PursuitEnv(cfg, n_worlds=2, seed=0)
    vec.reset(seed=5)
    ref.reset(seed=5)
    for t in range(3):
        *_, info = vec.step(np.zeros((2 * N, 2)))
        r_info = ref.step(np.zeros((2, N, 2)))[-1]
    assert info["_episode_record"].all() and len(r_info["episodes"]) == 2
    for i in range(2 * N):
        assert info["episode_record"][i] == r_info["episodes"][i // N]
    if mode == "SameStep":
        assert info["_final_state"].all()
        for i in range(2 * N):
            np.testing.assert_array_equal(info["final_state"][i], r_info["final_state"][i // N])
    else:
        assert "final_state" not in info  # the frozen world's env.batched.global_state() is it
        np.testing.assert_array_equal(vec.batched.global_state(), r_info["final_state"])
    info = vec.step(np.zeros((2 * N, 2)))[-1]
    assert "episode_record" not in info and "final_state" not in info


def test_every_info_mask_is_an_array_of_its_own():
    """gymnasium's wrappers may edit a mask in place (its _add_info does): one must not change another."""
    env = PursuitVectorEnv(config(max_steps=2), n_worlds=W, seed=4, autoreset_mode="SameStep")
    env.reset(seed=0)
    env.step(actions(0).reshape(W * N, 2))
    *_, info = env.step(actions(1).reshape(W * N, 2))  # every world times out: every key and mask present

    def masks(d):
        for k, v in d.items():
            if k.startswith("_"):
                yield v
            elif isinstance(v, dict):
                yield from masks(v)

    found = list(masks(info))
    assert len(found) > 10 and len({id(m) for m in found}) == len(found)
    assert info["final_info"]["outcome"] is not info["outcome"]


@pytest.mark.parametrize("steps_before", [0, 1])
def test_a_trail_starts_again_when_batched_reset_returns_to_episode_0_early(steps_before):
    """env.batched.reset(seed=...) puts the episode index back to 0; within episode 0's first step
    the (episode, steps) seen at the last push came back the same one step later, so the old
    episode's points stayed at the head of the new trail."""
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(), n_worlds=1, seed=4, render_mode="rgb_array", render_settings=RenderSettings(64, 48))
    env.reset(seed=0)
    for t in range(steps_before):
        env.step(actions(t)[:1].reshape(N, 2))
    env.batched.reset(seed=7)
    env.step(actions(0)[:1].reshape(N, 2))
    assert env._frames.trails[0].array().shape[0] == 1  # the new episode's first step only
    env.close()


def test_the_registered_spec_serialises_and_survives_a_reload():
    """The spec held its entry points as functions: EnvSpec.to_json refused it ("does not support
    serialising callables"), and after importlib.reload of the module pickling it (or an env's
    spec) failed, the functions no longer being the module's. Strings, as gymnasium's own envs give."""
    import subprocess
    import sys

    import gymnasium
    from gymnasium.envs.registration import EnvSpec

    from pursuit_mj.vector_env import ENV_ID

    spec = EnvSpec.from_json(gymnasium.spec(ENV_ID).to_json())
    env = gymnasium.make_vec(spec, num_envs=N, config=config())
    assert env.num_envs == N and env.spec.id == ENV_ID
    script = ("import importlib, pickle, gymnasium, pursuit_mj.vector_env as m; importlib.reload(m); "
              "pickle.loads(pickle.dumps(gymnasium.spec(m.ENV_ID))); "
              "env = gymnasium.make_vec(m.ENV_ID, num_envs=3); pickle.loads(pickle.dumps(env.spec)); "
              "assert isinstance(env, m.PursuitVectorEnv)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.parametrize("worlds, kept", [(3, 3), (8, 8), (9, 1)])
def test_the_renderer_keeps_every_worlds_scene_up_to_eight_worlds(worlds, kept):
    """Drawn in turn, 9 worlds in 8 kept scenes would evict each one just before it is needed:
    then only the bound one is kept, as before keeping existed."""
    from pursuit_mj.render.renderer import RenderSettings

    env = PursuitVectorEnv(config(), n_worlds=worlds, seed=4, render_mode="rgb_array", render_settings=RenderSettings(64, 48))
    env.reset(seed=0)
    assert env._frames.maker.renderer._keep == kept
    env.close()


def test_make_vec_takes_the_task_as_keys_or_a_preset_so_its_spec_is_json():
    """A TaskConfig in make_vec's kwargs made env.spec.to_json() fail (not JSON); task keys as a
    mapping, or a task file or preset name, serialise and make the same env again."""
    import dataclasses

    import gymnasium
    from gymnasium.envs.registration import EnvSpec

    from pursuit_mj.config import ConfigError, load_task_config
    from pursuit_mj.vector_env import ENV_ID

    keys = {"n_pursuers": 2, "evader_speed": 0.3, "evader": {"panic_distance": 1.0}}
    env = gymnasium.make_vec(ENV_ID, num_envs=4, config=keys)
    expected = default_config(n_pursuers=2, evader_speed=0.3)
    assert env.config == dataclasses.replace(expected, evader=dataclasses.replace(expected.evader, panic_distance=1.0))
    again = gymnasium.make_vec(EnvSpec.from_json(env.spec.to_json()), num_envs=4)
    assert again.config == env.config and again.n_worlds == 2
    hard = gymnasium.make_vec(ENV_ID, num_envs=3, config="hard")
    assert hard.config == load_task_config(["hard"])
    assert EnvSpec.from_json(hard.spec.to_json()).kwargs["config"] == "hard"
    with pytest.raises(ConfigError, match=r"pursuit_mj/Pursuit-v0 config.*evader_sped"):
        gymnasium.make_vec(ENV_ID, num_envs=3, config={"evader_sped": 0.3})
    with pytest.raises(ConfigError, match=r"pursuit_mj/Pursuit-v0 config: nope: no such file.*reference"):
        gymnasium.make_vec(ENV_ID, num_envs=3, config="nope")
    with pytest.raises(ConfigError, match=r"PursuitVectorEnv config: expected a TaskConfig, task keys or a task file"):
        PursuitVectorEnv(config=3)


def test_close_frees_the_batched_envs_simulation_and_a_reset_plays_on():
    """close() freed the renderer only: the MuJoCo batch (its worker threads) lived on until the env
    was garbage-collected, though gymnasium's close() is where an env lets go of what it holds. It
    now closes PursuitEnv too; a step after it says so; reset() plays on as if never closed."""
    envs = [PursuitVectorEnv(config(random_obstacles=0), n_worlds=2, seed=4) for _ in range(2)]
    for env in envs:
        env.reset(seed=1)
    envs[1].close()
    assert envs[1].batched.closed
    with pytest.raises(RuntimeError, match=r"step\(\) called after close\(\): call reset\(\) first"):
        envs[1].step(np.zeros((2 * N, 2)))
    first = [env.reset()[0] for env in envs]
    np.testing.assert_array_equal(*first)
    stepped = [env.step(np.full((2 * N, 2), 0.5))[:2] for env in envs]
    for a, b in zip(*stepped):
        np.testing.assert_array_equal(a, b)
