"""The batched environment: outcomes, auto-reset, determinism, bad input, both fidelities."""

import dataclasses
import re

import numpy as np
import pytest

from pursuit_mj.config import ConfigError, default_config, load_task_config
from pursuit_mj.env import PursuitEnv

FAST = dict(fidelity="point", random_obstacles=0)


def _place(env, world, xy):
    """Teleport one world's drones (pursuers then evaders, (D, 2) m) and refresh observations."""
    env.physics.reset([world], np.asarray(xy, float)[None])
    env._obs = env._observe()


def test_collision_ends_the_episode_as_a_failure():
    env = PursuitEnv(default_config(**FAST), n_worlds=2, seed=0)
    env.reset()
    _place(env, 0, [[0.5, 1.0], [1.5, 1.0], [2.5, 1.0], [1.8, 4.5]])
    actions = np.zeros((2, 3, 2))
    actions[0, 0] = [-1.0, 0.0]  # pursuer 0 of world 0 flies into the left border
    for _ in range(40):
        obs, reward, term, trunc, info = env.step(actions)
        if term[0]:
            break
    assert term[0] and not trunc[0]
    assert info["outcome"][0] == "collision"
    rec = [e for e in info["episodes"] if e.world == 0][0]
    assert rec.outcome == "collision" and rec.returns["collision"] == pytest.approx(default_config().collision_penalty)
    assert np.all(info["reward_terms"]["collision"][0] < 0)
    assert env.steps[0] == 0, "auto-reset started a new episode in world 0"


def test_timeout_truncates():
    env = PursuitEnv(default_config(max_steps=5, **FAST), n_worlds=1, seed=1)
    env.reset()
    _place(env, 0, [[0.5, 1.0], [1.5, 1.0], [2.5, 1.0], [1.8, 4.5]])
    for k in range(5):
        obs, reward, term, trunc, info = env.step(np.zeros((1, 3, 2)))
    assert trunc[0] and not term[0] and info["outcome"][0] == "timeout"
    assert info["episodes"][0].steps == 5


def test_capture_is_a_success_and_final_obs_precedes_the_reset():
    env = PursuitEnv(default_config(**FAST), n_worlds=1, seed=2)
    env.reset()
    _place(env, 0, [[1.8, 3.0], [0.8, 1.0], [2.8, 1.0], [1.8, 3.2]])
    obs, reward, term, trunc, info = env.step(np.zeros((1, 3, 2)))
    assert term[0] and info["outcome"][0] == "success"
    assert info["episodes"][0].time_to_capture == pytest.approx(0.1)
    assert np.all(info["reward_terms"]["capture"] == default_config().capture_reward)
    spec = env.obs_spec
    assert info["final_obs"][0, 0, spec.index("evaders", 0, "captured")] == 1
    assert obs[0, 0, spec.index("evaders", 0, "captured")] == 0, "the returned obs starts a new episode"


def test_a_capture_on_the_last_step_is_a_success_not_a_timeout():
    env = PursuitEnv(default_config(max_steps=1, **FAST), n_worlds=1, seed=2)
    env.reset()
    _place(env, 0, [[1.8, 3.0], [0.8, 1.0], [2.8, 1.0], [1.8, 3.2]])
    obs, reward, term, trunc, info = env.step(np.zeros((1, 3, 2)))
    assert term[0] and not trunc[0] and info["outcome"][0] == "success"


def test_events_are_judged_where_the_drones_are_after_the_step():
    """0.105 m from the wall, flying at it: the step takes it inside the 0.1 m clearance, and that step collides."""
    env = PursuitEnv(default_config(**FAST), n_worlds=1, seed=1)
    env.reset()
    _place(env, 0, [[0.105, 1.0], [1.5, 1.0], [2.5, 1.0], [1.8, 4.5]])
    actions = np.zeros((1, 3, 2))
    actions[0, 0] = [-1.0, 0.0]
    obs, reward, term, trunc, info = env.step(actions)
    assert term[0] and info["outcome"][0] == "collision"


def test_two_evaders_caught_in_one_step_pay_two_captures():
    config = default_config(n_evaders=2, **FAST)
    env = PursuitEnv(config, n_worlds=1, seed=2)
    env.reset()
    _place(env, 0, [[1.0, 3.0], [0.8, 1.0], [2.8, 1.0], [1.0, 3.2], [2.8, 1.2]])
    obs, reward, term, trunc, info = env.step(np.zeros((1, 3, 2)))
    assert info["outcome"][0] == "success"
    assert np.all(info["reward_terms"]["capture"] == 2 * config.capture_reward)


def test_frozen_worlds_without_auto_reset():
    env = PursuitEnv(default_config(max_steps=3, **FAST), n_worlds=2, seed=0, auto_reset=False)
    env.reset()
    for _ in range(5):
        obs, reward, term, trunc, info = env.step(np.zeros((2, 3, 2)))
    assert env.done.all() and (reward == 0).all() and not term.any() and not trunc.any()
    env.reset_worlds([1])
    assert env.done.tolist() == [True, False]


def test_an_ended_world_is_paid_plain_zeros_not_negative_zeros():
    """A frozen world's terms are 0.0 in every step after its end: masking a negative term (the
    collision penalty, the proximity penalty it ended with) by multiplying gave -0.0, printed as
    '-0.0' in per-term logs and recordings, where the task's terms are never -0.0 otherwise."""
    env = PursuitEnv(default_config(max_steps=50, **FAST), n_worlds=1, seed=0, auto_reset=False)
    env.reset()
    _place(env, 0, [[0.05, 1.0], [1.0, 1.0], [2.0, 1.0], [1.8, 4.5]])  # pursuer 0 inside the clearance of the wall x = 0
    _, _, term, _, info = env.step(np.zeros((1, 3, 2)))
    assert term[0] and info["outcome"][0] == "collision" and (info["reward_terms"]["collision"] < 0).all()
    _, reward, _, _, info = env.step(np.zeros((1, 3, 2)))
    for name, values in {**info["reward_terms"], "reward": reward}.items():
        assert (values == 0).all() and not np.signbit(values).any(), f"{name}: {values}"
    assert not any(np.signbit(v).any() for v in env.snapshot(0).reward_terms.values())


def test_an_ended_world_stands_still_until_its_reset():
    """Without auto_reset an ended episode's world is not simulated (eval and validation wait in
    them for the last episode): its drones stay where the episode ended, its clock stops."""
    env = PursuitEnv(default_config(max_steps=3, **FAST), n_worlds=2, seed=0, auto_reset=False)
    env.reset()
    env.step(np.ones((2, 3, 2)))
    env.reset_worlds([1])
    for _ in range(2):
        env.step(np.ones((2, 3, 2)))
    assert env.done.tolist() == [True, False]
    ended, clock = env.physics.positions()[0], env.physics.time[0]
    env.step(np.ones((2, 3, 2)))
    assert np.array_equal(env.physics.positions()[0], ended) and env.physics.time[0] == clock
    assert env.done.all()


def test_same_seed_same_trajectory_and_different_seed_differs():
    def run(seed):
        env = PursuitEnv(default_config(fidelity="point", random_obstacles=3), n_worlds=3, seed=seed)
        obs = [env.reset()]
        rng = np.random.default_rng(0)
        for _ in range(30):
            obs.append(env.step(rng.uniform(-1, 1, (3, 3, 2)))[0])
        return np.stack(obs)

    a, b, c = run(5), run(5), run(6)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_quadrotor_fidelity_has_the_same_interface():
    env = PursuitEnv(default_config(fidelity="quadrotor", random_obstacles=2), n_worlds=2, seed=0)
    obs = env.reset()
    obs2, reward, term, trunc, info = env.step(np.full((2, 3, 2), 0.5))
    assert obs.shape == obs2.shape == (2, 3, env.obs_dim) and obs.dtype == np.float32
    assert reward.shape == (2, 3) and env.global_state().shape == (2, env.state_dim)
    snap = env.snapshot(1)
    assert snap.pursuer_quat.shape == (3, 4) and snap.thrust.shape == (4, 4) and snap.thrust.sum() > 0
    assert snap.rays.shape == (3, env.config.n_rays)


@pytest.mark.parametrize(
    "actions,match",
    [
        (np.zeros((2, 3)), "expected shape"),
        (np.zeros((1, 2, 2)), "expected shape"),
        (np.full((1, 3, 2), np.nan), "non-finite"),
        (np.full((1, 3, 2), np.inf), "non-finite"),
        (np.full((1, 3, 2), "0.5"), "dtype <U3"),
        (np.ones((1, 3, 2), bool), "dtype bool"),
        (np.full((1, 3, 2), 0.5 + 1j), "dtype complex128"),
        ([[[0.1, None]] * 3], "dtype object"),
        # numpy's own 'inhomogeneous shape after 2 dimensions' before
        ([[[0.1, 0.2], [0.1], [0.0, 0.0]]], r"actions: expected shape \(1, 3, 2\) \(worlds, pursuers, vx vy\), got a ragged list"),
    ],
)
def test_bad_actions_are_refused(actions, match):
    env = PursuitEnv(default_config(**FAST), n_worlds=1)
    env.reset()
    with pytest.raises(ValueError, match=match):
        env.step(actions)


def test_bad_task_settings_are_refused():
    with pytest.raises(ValueError, match="cannot reliably hold 16 pursuers"):
        PursuitEnv(default_config(n_pursuers=16, **FAST))
    with pytest.raises(ConfigError, match="perception_radius"):
        default_config(perception_radius=0.2)
    with pytest.raises(ConfigError, match="pursuer_speed"):
        default_config(pursuer_speed=0.0)
    with pytest.raises(ConfigError, match="evader_speed"):
        default_config(evader_speed=-1.0)
    with pytest.raises(ValueError, match="n_worlds"):
        PursuitEnv(default_config(**FAST), n_worlds=0)


@pytest.mark.parametrize("key,value", [("capture_reward", -10.0), ("capture_reward", 1e308), ("progress_reward", -1e308),
                                       ("spread_reward", 1e9), ("collision_penalty", -1e308), ("proximity_penalty", -1e7)])
def test_reward_scales_that_reward_evasion_or_overflow_the_float32_rewards_are_refused(key, value):
    with pytest.raises(ConfigError, match=key):
        default_config(**{key: value})


def test_reward_scales_at_their_bounds_give_finite_rewards():
    from pursuit_mj.config import REWARD_SCALE_LIMIT

    cfg = default_config(capture_reward=REWARD_SCALE_LIMIT, progress_reward=-REWARD_SCALE_LIMIT, collision_penalty=-REWARD_SCALE_LIMIT,
                         proximity_penalty=-REWARD_SCALE_LIMIT, spread_reward=REWARD_SCALE_LIMIT, **FAST)
    env = PursuitEnv(cfg, n_worlds=2, seed=0)
    env.reset()
    for _ in range(20):
        _, reward, *_ = env.step(np.ones((2, 3, 2)))
        assert np.isfinite(reward).all()


def test_random_layout_and_several_evaders_run():
    env = PursuitEnv(default_config(fidelity="point", random_layout=True, n_evaders=2, n_pursuers=4), n_worlds=4, seed=3)
    obs = env.reset()
    names = {l.name for l in env.world_layouts}
    assert len(names) >= 2, "random_layout draws different built-in layouts"
    for _ in range(5):
        obs, *_ = env.step(np.zeros((4, 4, 2)))
    assert obs.shape == (4, 4, env.obs_spec.dim)


def test_a_world_whose_physics_diverges_ends_as_a_collision_without_stopping_the_others():
    env = PursuitEnv(default_config(fidelity="quadrotor", random_obstacles=0), n_worlds=2, seed=0)
    env.reset()
    env.physics.qvel[0, :] = 1e12  # what a violent crash can do: MuJoCo resets such a world
    with pytest.warns(RuntimeWarning, match=r"physics diverged in worlds \[0\] .*a PursuitEnv ends their episodes as collisions"):
        obs, reward, term, trunc, info = env.step(np.zeros((2, 3, 2)))
    assert info["outcome"].tolist() == ["collision", ""]
    assert np.isfinite(obs).all() and np.isfinite(reward).all()
    obs, *_ = env.step(np.zeros((2, 3, 2)))
    assert np.isfinite(obs).all()


def test_a_diverged_world_pays_the_collision_and_nothing_its_reset_positions_suggest():
    """MuJoCo puts a diverged point world's drones all on one spot: that step used to pay a
    capture of every evader (+20 with two, more than the -10 of the crash) and count them caught."""
    import warnings

    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0, n_evaders=2), n_worlds=2, seed=0)
    env.reset()
    env.physics.qvel[0, :] = 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, reward, term, _, info = env.step(np.zeros((2, 3, 2)))
    assert info["outcome"].tolist() == ["collision", ""] and term.tolist() == [True, False]
    record = info["episodes"][0]
    assert record.captured == 0 and record.returns["capture"] == 0.0
    for name, value in info["reward_terms"].items():
        want = env.config.collision_penalty if name == "collision" else 0.0
        np.testing.assert_array_equal(value[0], want, err_msg=name)
    np.testing.assert_array_equal(reward[0], env.config.collision_penalty)


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_reset_worlds_with_a_seed_replays_an_episode_exactly(fidelity):
    """An episode is a function of its seed and actions: noise, misses, obstacles and the
    evader's zigzag included, whatever world it runs in and whatever the others do."""
    config = load_task_config(["hard"], flags={"fidelity": fidelity, "random_obstacles": 3})
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (25, 3, 2))

    def replay(env, world, prefix_steps):
        for _ in range(prefix_steps):  # other episodes first, so the world is not fresh
            env.step(rng.uniform(-1, 1, (env.n_worlds, 3, 2)))
        obs = [env.reset_worlds([world], [12345])[world]]
        for a in actions:
            batch = rng.uniform(-1, 1, (env.n_worlds, 3, 2))
            batch[world] = a
            obs.append(env.step(batch)[0][world])
        return np.stack(obs), env.snapshot(world).evader_pos

    a = PursuitEnv(config, n_worlds=3, seed=1)
    a.reset()
    b = PursuitEnv(config, n_worlds=1, seed=2, auto_reset=False)
    b.reset(seeds=[7])
    obs_a, ev_a = replay(a, 1, 4)
    obs_b, ev_b = replay(b, 0, 0)
    assert np.array_equal(obs_a, obs_b) and np.array_equal(ev_a, ev_b)
    assert not np.array_equal(obs_a[1:, :, :2], obs_a[:-1, :, :2])  # it moved


def test_reset_worlds_takes_its_worlds_in_any_order():
    # [3, 1] was refused deep inside MuJoCo ('ids must be sorted and unique, got 3 before 1')
    config = default_config(**FAST)
    a, b = PursuitEnv(config, n_worlds=4, seed=0), PursuitEnv(config, n_worlds=4, seed=0)
    a.reset(), b.reset()
    obs_a = a.reset_worlds([3, 1], [11, 22])
    obs_b = b.reset_worlds([1, 3], [22, 11])
    np.testing.assert_array_equal(obs_a, obs_b)
    assert a._episode_seeds.tolist() == b._episode_seeds.tolist() == [a._episode_seeds[0], 22, a._episode_seeds[2], 11]


def test_bad_episode_seeds_are_refused():
    env = PursuitEnv(default_config(**FAST), n_worlds=2)
    env.reset()
    with pytest.raises(ValueError, match="reset_worlds seeds"):
        env.reset_worlds([0, 1], [1])
    with pytest.raises(ValueError, match="reset_worlds seeds"):
        env.reset_worlds([0], [-3])
    with pytest.raises(ValueError, match="reset seeds"):
        env.reset(seeds=[1.5, 2.0])
    for ids, shown in (([2], "[2]"), (5, "[5]"), (np.int64(7), "[7]"), (np.array([1, 1]), "[1, 1]")):  # a scalar was a TypeError
        with pytest.raises(ValueError, match=f"world_ids: expected distinct indices in 0..1, got {re.escape(shown)}$"):
            env.reset_worlds(ids)


def test_observe_as_gives_a_privileged_view_of_the_same_state_and_changes_nothing():
    import dataclasses

    from pursuit_mj.sensing import privileged_config

    hard = load_task_config(["hard"], flags=dict(FAST))
    env, twin = PursuitEnv(hard, n_worlds=8, seed=3), PursuitEnv(hard, n_worlds=8, seed=3)
    env.reset(), twin.reset()
    for w in range(8):  # the evader within sight range of every pursuer, behind the first (they face +y)
        xy = [[1.0 + 0.1 * w, 2.0], [2.0, 1.5], [0.5, 1.0], [1.0 + 0.1 * w, 1.2]]
        _place(env, w, xy), _place(twin, w, xy)
    obs = env._obs.copy()
    spec = env.obs_spec
    known = lambda o: spec.group("evaders").view(o)[..., 4] > 0.5  # noqa: E731  (W, N, M)
    own_known = priv_known = 0
    rng = np.random.default_rng(0)
    for _ in range(20):
        np.testing.assert_array_equal(env.observe_as(hard), obs)  # the task's own view: the same draws
        priv = env.observe_as(privileged_config(hard, "all_round"))
        assert np.all(known(priv) | ~known(obs)), "all-round sight sees all that the 120 deg view sees"
        own_known += int(known(obs).sum())
        priv_known += int(known(priv).sum())
        # exact positions: a known evader sits where the env put it (relative to the pursuer)
        ev, me = spec.group("evaders").view(priv), spec.group("self").view(priv)
        truth = env.physics.positions()[:, None, env.n_pursuers:, :2] - me[:, :, None, 0, 0:2]
        np.testing.assert_allclose(ev[..., 0:2][known(priv)], truth[known(priv)], atol=1e-5)
        actions = rng.uniform(-0.3, 0.3, (8, 3, 2))
        obs = env.step(actions)[0]
        np.testing.assert_array_equal(obs, twin.step(actions)[0])  # observe_as left the episode alone
    assert priv_known > own_known * 1.2, (own_known, priv_known)
    with pytest.raises(ValueError, match="evader_speed"):
        env.observe_as(dataclasses.replace(hard, evader_speed=0.5))


def test_observe_as_without_misses_keeps_the_tasks_position_noise():
    """observe_as draws from the env's noise streams: a view that only drops the missed detections
    sees the same noisy teammates (their noise used to shift to other numbers when no misses were drawn)."""
    import dataclasses

    hard = load_task_config(["hard"], flags=dict(FAST))
    env = PursuitEnv(hard, n_worlds=4, seed=1)
    obs = env.reset()
    mates = env.obs_spec.group("teammates")
    no_miss = env.observe_as(dataclasses.replace(hard, miss_probability=0.0))
    assert mates.view(obs)[..., 4].any()
    np.testing.assert_array_equal(mates.view(no_miss), mates.view(obs))


def test_reset_without_a_seed_never_replays_an_episode():
    env = PursuitEnv(default_config(fidelity="point"), n_worlds=2, seed=4)
    first = env.reset()
    layouts = [l.obstacles for l in env.world_layouts]
    second = env.reset()
    assert not np.array_equal(first, second)
    assert [l.obstacles for l in env.world_layouts] != layouts
    np.testing.assert_array_equal(env.reset(seed=4), first)  # a seed restarts its sequence


def test_random_obstacles_default_to_the_layout_files_count(tmp_path):
    layout = tmp_path / "two.yaml"
    layout.write_text("arena: {width: 3.6, height: 5.0}\nrandom_obstacles: {count: 2, kinds: [box], size: [0.15, 0.3]}\n"
                      "spawn: {pursuers: {x: [0.5, 3.1], y: [0.4, 1.2]}, evaders: {x: [0.5, 3.1], y: [3.8, 4.6]}}\n")
    env = PursuitEnv(default_config(fidelity="point", layout=str(layout)), n_worlds=2)
    env.reset()
    assert [len(l.obstacles) for l in env.world_layouts] == [2, 2]
    env = PursuitEnv(default_config(fidelity="point", layout=str(layout), random_obstacles=4))
    env.reset()
    assert len(env.world_layouts[0].obstacles) == 4  # a config value overrides every layout's count


def test_configs_made_without_the_loader_are_checked_by_the_env():
    import dataclasses

    from pursuit_mj.config import TaskConfig

    with pytest.raises(ConfigError, match="PursuitEnv config: key 'pursuer_speed': -1.0 is out of range"):
        PursuitEnv(TaskConfig(pursuer_speed=-1.0, fidelity="point"))
    with pytest.raises(ConfigError, match="key 'fidelity': 'pointy' is not one of"):
        PursuitEnv(TaskConfig(fidelity="pointy"))
    with pytest.raises(ConfigError, match="key 'max_steps': 0"):
        PursuitEnv(dataclasses.replace(default_config(**FAST), max_steps=0))
    with pytest.raises(ConfigError, match="unknown key 'evader.x'"):
        PursuitEnv(TaskConfig(evader={"x": 1}, fidelity="point"))
    with pytest.raises(ConfigError, match="expected a TaskConfig .* got dict"):
        PursuitEnv({"fidelity": "point"})
    for seed in (-1, 1.7, "abc", None, True):
        with pytest.raises(ValueError, match="PursuitEnv seed: expected a non-negative integer"):
            PursuitEnv(default_config(**FAST), seed=seed)
    with pytest.raises(ValueError, match="reset seed: expected a non-negative integer"):
        PursuitEnv(default_config(**FAST)).reset(seed=-5)
    with pytest.raises(ValueError, match="auto_reset: expected True or False"):
        PursuitEnv(default_config(**FAST), auto_reset="no")
    with pytest.raises(ValueError, match="layouts: expected a list"):
        PursuitEnv(default_config(**FAST), layouts=2)
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=np.int64(0)), n_worlds=np.int64(2), seed=np.int64(3))
    assert env.n_worlds == 2 and env.reset().shape[0] == 2
    assert load_task_config("hard") == load_task_config(["hard"])


def test_layout_objects_made_without_the_loader_are_checked_by_the_env():
    """As configs are: a Layout made directly or with dataclasses.replace skips the loader's checks."""
    import dataclasses

    from pursuit_mj.layout import Box, LayoutError, RandomObstacles, load_layout

    base = load_layout(0)
    outside = dataclasses.replace(base, obstacles=(Box((10.0, 10.0), (1.0, 1.0)),))  # was simulated and drawn
    with pytest.raises(LayoutError, match=r"0_open.yaml: obstacles\[0\] \(box centre \[10.0, 10.0\] .*\) lies \(partly\) outside"):
        PursuitEnv(default_config(**FAST), layouts=[outside])
    many = dataclasses.replace(base, random_obstacles=RandomObstacles(count=10**7))  # hung building ten million geoms
    with pytest.raises(LayoutError, match="random_obstacles.count: 10000000 is more than 64"):
        PursuitEnv(default_config(fidelity="point"), layouts=[many])
    placed = base.with_random_obstacles(np.random.default_rng(0))  # a checked layout's own placement passes
    assert PursuitEnv(default_config(**FAST), layouts=[placed]).world_layouts[0] is placed


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_a_caught_evader_stops_at_once_while_the_chase_goes_on(fidelity):
    from pursuit_mj.heuristic import HeuristicTeam

    config = default_config(fidelity=fidelity, n_evaders=2)
    env = PursuitEnv(config, n_worlds=4, seed=0, auto_reset=False)
    team = HeuristicTeam.from_config(config)
    obs = env.reset()
    team.reset(env.n_worlds)
    N = config.n_pursuers
    for _ in range(config.max_steps):
        before = env.captured.copy()
        obs, *_ = env.step(team.act(obs, env.obs_spec))
        new = env.captured & ~before & ~env.done[:, None]
        if new.any():
            break
    else:
        pytest.fail("no world caught one of its two evaders and went on")
    w, j = map(int, np.argwhere(new)[0])
    assert np.all(env.physics.velocities()[w, N + j] == 0.0)
    where = env.physics.positions()[w, N + j, :2].copy()
    for _ in range(10):  # a quadrotor caught while tilted used to drift off at 0.15 m/s
        obs, *_ = env.step(team.act(obs, env.obs_spec))
        assert np.linalg.norm(env.physics.positions()[w, N + j, :2] - where) < 0.02


def test_the_pursuer_that_catches_one_evader_still_sees_its_teammates_and_the_other_evader():
    """A caught evader used to block sight as its capture disc, which holds its catcher: every
    ray of that pursuer read 0 and it saw no one until it flew out of the disc."""
    cfg = default_config(fidelity="point", random_obstacles=0, n_evaders=2)
    env = PursuitEnv(cfg, n_worlds=1, seed=0)
    env.reset()
    xy = [[1.8, 3.0], [0.8, 2.5], [2.8, 2.5], [1.8, 3.2], [1.0, 3.5]]  # p0 0.2 m from evader 0, evader 1 free
    env.physics.reset([0], np.asarray(xy, float)[None])
    env._obs = env._observe()
    obs, _, terminated, _, _ = env.step(np.zeros((1, 3, 2)))
    assert env.captured[0].tolist() == [True, False] and not terminated[0]
    spec = env.obs_spec
    rays = spec.group("rays").view(obs)[0, 0, 0]
    assert rays.min() > 0.1  # the caught drone is a body of 0.0685 m, not a 0.3 m disc around its catcher
    assert spec.group("teammates").view(obs)[0, 0, :, spec.group("teammates").mask_feature].tolist() == [1.0, 1.0]
    assert env._perception.seen[0, 0, 1]  # the free evader, 1 m away in the open


def test_a_caught_evader_reads_in_the_range_readings_as_the_drone_body_a_pursuer_would_hit():
    """A caught evader is an obstacle of the drone's own collision radius (models/crazyflie.xml,
    0.0685 m: arms and propellers), where a pursuer touching it collides; it read as a 0.05 m body,
    1.85 cm more free room than there is."""
    from pursuit_mj.config import DRONE_CONTACT_DISTANCE

    cfg = default_config(fidelity="point", random_obstacles=0, n_evaders=2)
    env = PursuitEnv(cfg, n_worlds=1, seed=0)
    env.reset()
    _place(env, 0, [[1.0, 2.0], [2.5, 1.0], [3.0, 1.0], [1.0, 2.5], [3.0, 4.0]])  # evader 0 0.5 m above pursuer 0
    env.captured[0, 0] = True
    env._obs = env._observe()
    up = cfg.n_rays // 4  # ray i points at 2 pi i / K from +x
    assert env.snapshot(0).rays[0, up] == pytest.approx(0.5 - DRONE_CONTACT_DISTANCE / 2, abs=1e-9)


def test_a_capture_in_the_step_of_a_collision_fails_without_a_capture_time():
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0), n_worlds=1, seed=0)
    env.reset()
    env.physics.reset([0], np.array([[[1.8, 3.0], [0.8, 1.0], [0.9, 1.0], [1.8, 3.2]]]))  # p1 and p2 0.1 m apart
    env._obs = env._observe()
    _, _, _, _, info = env.step(np.zeros((1, 3, 2)))
    record = info["episodes"][0]
    assert record.outcome == "collision" and record.captured == 1
    assert record.time_to_capture is None or np.isnan(record.time_to_capture)


def test_reset_worlds_before_reset_is_refused():
    env = PursuitEnv(default_config(fidelity="point"), n_worlds=2, seed=0)
    with pytest.raises(RuntimeError, match="call reset"):
        env.reset_worlds([0])


def test_reading_the_state_before_reset_is_refused_and_works_after():
    """snapshot, global_state and observe_as before any episode would report the drones' build
    placement (a row in a corner) as if it were one."""
    env = PursuitEnv(default_config(fidelity="point"), n_worlds=1, seed=0)
    for read in (lambda: env.snapshot(0), env.global_state, lambda: env.observe_as(env.config)):
        with pytest.raises(RuntimeError, match="call reset"):
            read()
    obs = env.reset()
    assert env.snapshot(0).seen.shape == (3, 1)
    assert env.global_state().shape == (1, env.state_dim)
    np.testing.assert_array_equal(env.observe_as(env.config), obs)


@pytest.mark.parametrize("key, value", [("obstacle_clearance", 0.25), ("teammate_clearance", 0.45)])
def test_clearances_the_spawn_spacing_breaks_are_refused_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=f"'{key}'.*collision before any action"):
        default_config(**{key: value})


@pytest.mark.parametrize("speed", [0.3, 0.04])
def test_the_field_of_view_turns_with_the_direction_of_flight_at_any_pursuer_speed(speed):
    """A fixed 0.05 m/s floor on the speed that sets a pursuer's heading kept pursuers of max
    speed 0.05 m/s or less facing +y (their start) wherever they flew."""
    cfg = default_config(fidelity="point", random_obstacles=0, pursuer_speed=speed, field_of_view=1.0)
    env = PursuitEnv(cfg, n_worlds=1, seed=0)
    env.reset()
    actions = np.zeros((1, 3, 2))
    actions[..., 0] = -1.0
    for _ in range(15):
        env.step(actions)
    assert np.cos(env.heading[0]) == pytest.approx(-1.0), "flying along -x, the pursuers look along -x"


@pytest.mark.parametrize("changes", [{"random_obstacles": 3}, {"random_layout": True}, {}])
def test_the_obstacles_sensed_and_collided_with_are_each_worlds_current_ones_after_resets(changes):
    """Each world's obstacle arrays are rebuilt only when its episode brings new obstacles (a
    speed-up of resets); after any sequence of resets they must still be the worlds' own."""
    from pursuit_mj.geometry import ObstacleSet

    env = PursuitEnv(default_config(fidelity="point", max_steps=4, **changes), n_worlds=4, seed=3)
    env.reset()
    for ids in ([1], [0, 3], [2], [1]):
        env.reset_worlds(np.array(ids), np.array([7 * i + len(ids) for i in ids]))
    for _ in range(9):  # and through auto-reset at the 4-step timeouts
        env.step(np.zeros((4, env.n_pursuers, 2)))
    want = ObstacleSet.stack([layout.obstacle_set() for layout in env.world_layouts])
    got = env._obstacles
    for field in ("boxes", "box_valid", "cylinders", "cylinder_valid", "border", "border_valid"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)


@pytest.mark.parametrize("kind", ["grad", "bfloat16", "masked"])
def test_actions_as_torch_tensors_are_taken_and_masked_arrays_refused(kind):
    """A tensor that requires grad, or of bfloat16, failed inside torch's numpy(); a masked
    array's hidden values were flown as if given."""
    import torch

    env = PursuitEnv(default_config(fidelity="point", max_steps=5), n_worlds=2, seed=0)
    env.reset()
    if kind == "masked":
        with pytest.raises(ValueError, match="actions: a masked array with 12 masked entries"):
            env.step(np.ma.masked_array(np.zeros((2, 3, 2)), mask=True))
        return
    actions = torch.full((2, 3, 2), 0.5, requires_grad=True) if kind == "grad" else torch.full((2, 3, 2), 0.5, dtype=torch.bfloat16)
    twin = PursuitEnv(default_config(fidelity="point", max_steps=5), n_worlds=2, seed=0)
    twin.reset()
    np.testing.assert_array_equal(env.step(actions)[0], twin.step(np.full((2, 3, 2), 0.5))[0])


@pytest.mark.parametrize("nthread", [-1, 2 ** 40, True, 1.5])
def test_a_thread_count_out_of_range_is_refused_naming_it(nthread):
    """2**40 reached MuJoCo's batch constructor, which refused it with a pybind signature dump."""
    with pytest.raises(ValueError, match=re.escape(f"nthread: expected an integer in 0..1024 (0: MuJoCo's choice), got {nthread!r}")):
        PursuitEnv(default_config(fidelity="point"), nthread=nthread)


def test_a_layout_object_with_a_field_of_the_wrong_kind_is_a_layout_error_naming_its_source():
    import dataclasses

    from pursuit_mj.layout import LayoutError, load_layout

    broken = dataclasses.replace(load_layout(0), obstacles=({"a": 1},))
    with pytest.raises(LayoutError, match="0_open.yaml: not a well-formed Layout"):
        PursuitEnv(default_config(fidelity="point"), layouts=[broken])


class _FleeEast:
    """An evader model of one's own (docs/env_api.md): every free evader asks for 5 m/s east."""

    def __init__(self):
        self.resets = []

    def reset(self, world_ids, seeds):
        self.resets.append((np.asarray(world_ids).tolist(), np.asarray(seeds).tolist()))

    def compute(self, evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt):
        assert evader_pos.shape == evader_vel.shape == active.shape + (2,) and pursuer_pos.shape[-1] == 2 and dt > 0
        return np.tile([5.0, 0.0], active.shape + (1,))


def test_an_evader_model_of_ones_own_drives_the_evaders_capped_at_evader_speed():
    from pursuit_mj.config import default_config
    from pursuit_mj.env import PursuitEnv

    env = PursuitEnv(default_config(fidelity="point"), n_worlds=2, seed=3)
    env.evader_model = model = _FleeEast()
    env.reset(seeds=[11, 12])
    assert model.resets == [([0, 1], [11, 12])]
    N, start = env.n_pursuers, env.physics.positions()[:, env.n_pursuers:, :2].copy()
    speeds = []
    for _ in range(10):
        env.step(np.zeros((2, N, 2)))
        speeds.append(np.linalg.norm(env.physics.velocities()[:, N:, :2], axis=-1))  # (W, M) m/s
    moved = env.physics.positions()[:, N:, :2] - start  # (W, M, 2) m
    assert np.all(moved[..., 0] > 0.3) and np.all(np.abs(moved[..., 1]) < 0.05), moved  # east, as the model asked
    assert max(np.max(s) for s in speeds) <= env.config.evader_speed * 1.01, speeds  # capped, not 5 m/s


def _perceived_worlds(monkeypatch):
    """Record how many worlds each call of perception covers (the real perceive runs)."""
    import pursuit_mj.env as env_module

    calls = []

    def counting(view, config, rng):
        calls.append(view.pursuer_pos.shape[0])
        return env_module.perceive.__wrapped__(view, config, rng)

    counting.__wrapped__ = env_module.perceive
    monkeypatch.setattr(env_module, "perceive", counting)
    return calls


def test_restarting_some_worlds_perceives_only_those_again(monkeypatch):
    # with many worlds some episode ends in nearly every step: perceiving every world twice then
    # (once at the end of the step, once after the restart) doubled perception's cost
    env = PursuitEnv(default_config(max_steps=3, n_evaders=2, **FAST), n_worlds=16, seed=2)
    env.reset()
    env.steps[:] = [2] + [0] * 15  # only world 0 reaches max_steps in the next step
    env.captured[3, 0] = True  # a caught evader elsewhere: its body is an obstacle in every world's set
    calls = _perceived_worlds(monkeypatch)
    obs, *_, info = env.step(np.zeros((16, 3, 2)))
    assert [e.world for e in info["episodes"]] == [0]
    assert calls == [16, 1]
    calls.clear()
    obs = env.reset_worlds([2, 5])
    assert calls == [2]
    monkeypatch.undo()
    fresh = env._observe()  # every world perceived anew: the same numbers, bit for bit
    np.testing.assert_array_equal(obs, fresh)
    np.testing.assert_array_equal(env._obs, fresh)


def test_new_random_obstacles_restack_only_the_restarted_worlds(monkeypatch):
    # each restart with new random obstacles stacked every world's obstacles anew, a Python loop
    # over all W worlds in nearly every step of a many-world run
    from pursuit_mj.geometry import ObstacleSet, obstacle_distance

    env = PursuitEnv(default_config(fidelity="point", random_obstacles=4, max_steps=3), n_worlds=12, seed=4)
    env.reset()
    stacked = []
    real_stack = ObstacleSet.stack
    monkeypatch.setattr(ObstacleSet, "stack", staticmethod(lambda sets, *a, **k: stacked.append(len(sets)) or real_stack(sets, *a, **k)))
    env.steps[:] = [2, 0, 0, 2] + [0] * 8  # worlds 0 and 3 reach max_steps in the next step
    env.step(np.zeros((12, 3, 2)))
    assert stacked and max(stacked) == 2
    monkeypatch.undo()
    fresh = ObstacleSet.stack(env._world_obstacles)
    pts = env.physics.positions()[:, :, :2]
    np.testing.assert_array_equal(obstacle_distance(pts, env._obstacles), obstacle_distance(pts, fresh))


def test_reset_worlds_of_no_world_restarts_nothing():
    # reset_worlds([]) (a loop's np.flatnonzero(done) when nothing ended) stopped with numpy's
    # 'cannot reshape array of size 0' once a restart perceived only the restarted worlds
    env = PursuitEnv(default_config(fidelity="point", random_obstacles=2, n_evaders=2), n_worlds=3, seed=2)
    obs = env.reset()
    episodes, steps = env.episode.copy(), env.steps.copy()
    again = env.reset_worlds(np.array([], dtype=np.int64), [])
    np.testing.assert_array_equal(again, obs)
    np.testing.assert_array_equal(env.reset_worlds([]), obs)
    assert env.episode.tolist() == episodes.tolist() and env.steps.tolist() == steps.tolist()
    with pytest.raises(ValueError, match="reset_worlds seeds"):
        env.reset_worlds([], [5])


def _documented_signature(call: str):
    """The parameters (name, default or None) of a call that docs/env_api.md writes in signature
    form, `NAME(a: T, b: T = 1, ...)`, in order."""
    import ast
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "env_api.md").read_text()
    found = re.search(re.escape(call) + r"\(((?:[^()]|\([^()]*\))*)\)", text)
    assert found, f"docs/env_api.md no longer shows {call}(...)"
    args = ast.parse(f"def f({' '.join(found[1].split())}): pass").body[0].args
    defaults = [None] * (len(args.args) - len(args.defaults)) + list(args.defaults)
    return [(a.arg, None if d is None else ast.unparse(d)) for a, d in zip(args.args, defaults)]


@pytest.mark.parametrize("call", ["PursuitEnv", "PursuitParallelEnv", "PursuitVectorEnv", "env.reset", "env.reset_worlds"])
def test_the_signatures_docs_env_api_md_shows_are_the_codes(call):
    """Parameter names, order and defaults as documented, so that a call written from the docs,
    by keyword too, works (reset_worlds was documented as taking `ids`; its parameter is world_ids)."""
    import inspect

    from gymnasium.vector import AutoresetMode

    from pursuit_mj.pz_env import PursuitParallelEnv
    from pursuit_mj.vector_env import PursuitVectorEnv

    code = {"PursuitEnv": PursuitEnv.__init__, "PursuitParallelEnv": PursuitParallelEnv.__init__,
            "PursuitVectorEnv": PursuitVectorEnv.__init__, "env.reset": PursuitEnv.reset,
            "env.reset_worlds": PursuitEnv.reset_worlds}[call]
    params = [p for p in inspect.signature(code).parameters.values() if p.name != "self"]
    documented = _documented_signature(call)
    assert [name for name, _ in documented] == [p.name for p in params], call
    for (name, default), p in zip(documented, params):
        expected = None if p.default is inspect.Parameter.empty else p.default
        shown = None if default is None else eval(default, {"AutoresetMode": AutoresetMode})
        assert (default is None and p.default is inspect.Parameter.empty) or shown == expected, (call, name)


def test_an_ended_world_keeps_its_step_count_and_the_state_says_the_time_fraction():
    env = PursuitEnv(default_config(max_steps=3, **FAST), n_worlds=2, seed=0, auto_reset=False)
    env.reset()
    env.step(np.zeros((2, 3, 2)))
    assert env.global_state()[:, -1] == pytest.approx([1 / 3, 1 / 3])  # steps / max_steps
    for _ in range(4):
        env.step(np.zeros((2, 3, 2)))
    assert env.steps.tolist() == [3, 3]  # frozen at the timeout, not counting on
    assert env.global_state()[:, -1] == pytest.approx([1.0, 1.0])


def test_actions_beyond_full_speed_fly_as_full_speed():
    def flown(scale):
        env = PursuitEnv(default_config(**FAST), n_worlds=1, seed=3)
        env.reset()
        actions = np.zeros((1, 3, 2))
        actions[0, :] = scale
        for _ in range(3):
            env.step(actions)
        return env.physics.positions()[0, :3, :2]

    # each component is clipped to -1..1 (docs/env_api.md): (5, 1) flies as (1, 1), at 45 degrees,
    # not as (5, 1) cut to full speed along its own direction
    np.testing.assert_array_equal(flown([5.0, 1.0]), flown([1.0, 1.0]))
    np.testing.assert_array_equal(flown([-5.0, 0.0]), flown([-1.0, 0.0]))


def test_a_record_counts_every_evader_caught():
    config = default_config(n_evaders=2, **FAST)
    env = PursuitEnv(config, n_worlds=1, seed=2)
    env.reset()
    _place(env, 0, [[1.0, 3.0], [0.8, 1.0], [2.8, 1.0], [1.0, 3.2], [2.8, 1.2]])
    *_, info = env.step(np.zeros((1, 3, 2)))
    assert info["episodes"][0].outcome == "success" and info["episodes"][0].captured == 2


def test_restarted_worlds_take_the_next_episode_of_their_default_sequence():
    from pursuit_mj.env import episode_seed

    env = PursuitEnv(default_config(max_steps=2, **FAST), n_worlds=2, seed=7)
    env.reset()
    assert env._episode_seeds.tolist() == [episode_seed(7, 0, 0), episode_seed(7, 1, 0)]
    env.reset_worlds([1])
    assert env._episode_seeds.tolist() == [episode_seed(7, 0, 0), episode_seed(7, 1, 1)]
    env.step(np.zeros((2, 3, 2)))
    *_, info = env.step(np.zeros((2, 3, 2)))  # world 0 times out and auto-resets
    assert info["episodes"][0].world == 0 and info["episodes"][0].seed == episode_seed(7, 0, 0)
    assert env._episode_seeds[0] == episode_seed(7, 0, 1)


def test_with_random_layouts_an_episode_s_layout_follows_from_its_seed_not_its_world():
    env = PursuitEnv(default_config(random_layout=True, **FAST), n_worlds=2, seed=0)
    names = set()
    for s in range(6):
        env.reset(seeds=[s, s])
        assert env.world_layouts[0].name == env.world_layouts[1].name, s
        names.add(env.world_layouts[0].name)
    assert len(names) > 1  # and the seeds draw more than one layout



def test_a_diverged_quadrotor_world_ends_as_a_collision_alone():
    """A quadrotor world whose physics went bad ends as a collision, as a point world does, and
    only that world: MuJoCo resets it to the model's rest positions, which no drone flew to."""
    import warnings

    env = PursuitEnv(default_config(fidelity="quadrotor", random_obstacles=0), n_worlds=2, seed=0)
    env.reset()
    env.physics.qvel[0, :] = 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, reward, term, _, info = env.step(np.zeros((2, 3, 2)))
    assert env.physics.diverged.tolist() == [True, False]
    assert info["outcome"].tolist() == ["collision", ""] and term.tolist() == [True, False]
    np.testing.assert_array_equal(reward[0], env.config.collision_penalty)


def test_an_ended_world_catches_nothing_and_stops_no_evader_while_the_others_go_on():
    """Without auto_reset an ended world is frozen: a pursuer found within capture radius of a free
    evader there (placed by hand; a diverged world's drones all lie on one spot) is no capture,
    and the evader is not halted. Its captured flags, evader velocities, observation, returns,
    steps and outcome stay as the episode ended while the other world runs on."""
    env = PursuitEnv(default_config(max_steps=3, **FAST), n_worlds=2, seed=0, auto_reset=False)
    env.reset()
    env.step(np.ones((2, 3, 2)))
    env.reset_worlds([1])
    for _ in range(2):
        obs, *_ = env.step(np.ones((2, 3, 2)))
    assert env.done.tolist() == [True, False] and env.outcome[0] == "timeout"
    N = env.n_pursuers
    evader_xy = env.physics.positions()[0, N, :2]
    assert np.linalg.norm(env.physics.velocities()[0, N]) > 0.1  # fleeing when its episode ended
    env.physics.qpos[0, env.physics._qpos_idx[0]] = evader_xy + [0.15, 0.0]  # pursuer 0 within capture radius
    env._obs = obs = env._observe()
    ended = dict(vel=env.physics.velocities()[0].copy(), obs=obs[0].copy(), steps=env.steps[0],
                 returns={k: v[0] for k, v in env.returns.items()}, outcome=env.outcome[0])
    for _ in range(2):
        obs, reward, term, trunc, info = env.step(np.zeros((2, 3, 2)))
        assert not env.captured[0].any() and all(e.world == 1 for e in info["episodes"]) and not term[0] and not trunc[0]
        np.testing.assert_array_equal(env.physics.velocities()[0], ended["vel"])
        np.testing.assert_array_equal(obs[0], ended["obs"])
        assert env.steps[0] == ended["steps"] and env.outcome[0] == ended["outcome"]
        assert {k: v[0] for k, v in env.returns.items()} == ended["returns"] and (reward[0] == 0).all()
    assert env.steps[1] == 3 and env.done[1]  # the other world ran on to its own timeout
    assert not env.snapshot(0).captured.any()


def test_a_diverged_world_without_auto_reset_counts_no_capture_in_the_steps_after_its_end():
    """MuJoCo puts a diverged point world's drones all on one spot, every evader within capture
    radius of every pursuer; waiting for its reset (no auto_reset), that world must not count them
    caught in the steps after its end."""
    import warnings

    env = PursuitEnv(default_config(fidelity="point", random_obstacles=0, n_evaders=2), n_worlds=2, seed=0, auto_reset=False)
    env.reset()
    env.physics.qvel[0, :] = 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env.step(np.zeros((2, 3, 2)))
        assert env.outcome.tolist() == ["collision", ""]
        for _ in range(2):
            env.step(np.zeros((2, 3, 2)))
    assert not env.captured[0].any() and not env.snapshot(0).captured.any() and env.steps.tolist() == [1, 3]


def test_worlds_restarted_in_any_order_perceive_their_own_noise_and_misses():
    """reset_worlds perceives only the restarted worlds again; with position noise and misses each
    must draw from its own episode's streams, as a fresh env reset to that seed does, while the
    other worlds' rows stay as they were; so does what a snapshot says each pursuer perceived."""
    config = default_config(fidelity="point", random_obstacles=2, position_noise=0.1, miss_probability=0.3, n_evaders=2)
    a = PursuitEnv(config, n_worlds=4, seed=0)
    a.reset()
    for _ in range(2):
        before, *_ = a.step(np.zeros((4, 3, 2)))
    obs = a.reset_worlds([3, 1], [11, 22])
    b = PursuitEnv(config, n_worlds=2, seed=5)
    fresh = b.reset(seeds=[22, 11])
    np.testing.assert_array_equal(obs[[1, 3]], fresh)
    np.testing.assert_array_equal(obs[[0, 2]], before[[0, 2]])
    for w, v in ((1, 0), (3, 1)):
        ours, theirs = a.snapshot(w), b.snapshot(v)
        for name in ("rays", "seen", "known"):
            np.testing.assert_array_equal(getattr(ours, name), getattr(theirs, name), err_msg=f"world {w} {name}")
    quiet = PursuitEnv(dataclasses.replace(config, position_noise=0.0), n_worlds=2, seed=5).reset(seeds=[22, 11])
    assert not np.array_equal(fresh, quiet)  # the noise is in the numbers compared


class _RecordsActive:
    """An evader model of one's own that flies its active evaders east and leaves the others NaN,
    which docs/env_api.md allows (their commands are ignored); it keeps every `active` it is given."""

    def __init__(self):
        self.active = []

    def reset(self, world_ids, seeds):
        pass

    def compute(self, evader_pos, evader_vel, pursuer_pos, pursuer_vel, active, obstacles, dt):
        self.active.append(active.copy())
        return np.where(active[..., None], [0.3, 0.0], np.nan)


def test_an_evader_model_is_told_the_evaders_of_an_ended_world_are_not_active():
    """Without auto_reset, an ended world's evaders are not active (docs/env_api.md: the free
    evaders of running worlds); the model may leave their commands NaN while the others fly on."""
    env = PursuitEnv(default_config(max_steps=3, **FAST), n_worlds=2, seed=0, auto_reset=False)
    env.evader_model = model = _RecordsActive()
    env.reset()
    env.step(np.zeros((2, 3, 2)))
    env.reset_worlds([1])
    for _ in range(3):  # world 0 times out in the second, world 1 in the third
        env.step(np.zeros((2, 3, 2)))
    assert env.steps.tolist() == [3, 3] and env.done.all()
    assert model.active[-1].tolist() == [[False], [True]]  # the third step: world 0 had ended


def test_a_divergence_warning_turned_into_an_error_comes_after_the_step_is_whole():
    """With warnings as errors (python -W error, a test suite's filter) the divergence's RuntimeWarning
    was raised from inside the physics step: the worlds had moved but the env had counted no step,
    ended no world and paid nothing, and the next step reported the same world again. It is now
    told once the step is done, so the env is as a step without the filter leaves it."""
    import warnings

    envs = []
    for as_error in (True, False):
        env = PursuitEnv(default_config(fidelity="quadrotor", random_obstacles=0), n_worlds=2, seed=0)
        env.reset()
        env.physics.qvel[0, :] = 1e12
        with warnings.catch_warnings():
            warnings.simplefilter("error" if as_error else "ignore")
            if as_error:
                with pytest.raises(RuntimeWarning, match=r"physics diverged in worlds \[0\]"):
                    env.step(np.zeros((2, 3, 2)))
            else:
                env.step(np.zeros((2, 3, 2)))
        envs.append(env)
    raised, plain = envs
    assert raised.steps.tolist() == plain.steps.tolist() and raised.episode.tolist() == plain.episode.tolist()
    np.testing.assert_array_equal(raised.physics.positions(), plain.physics.positions())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # told once: the world was ended and reset
        for env in envs:
            env.step(np.zeros((2, 3, 2)))
    np.testing.assert_array_equal(raised.physics.positions(), plain.physics.positions())


def test_a_pool_of_more_layouts_than_worlds_is_refused_naming_those_that_would_never_run():
    # world w runs layouts[w % len]: 2 worlds over [0, 1, 2, 3] trained and validated on 0 and 1 alone, silently
    with pytest.raises(ValueError, match=r"layouts: 4 layouts for 2 worlds .* layouts\[2\], layouts\[3\] would never run"):
        PursuitEnv(default_config(**FAST), n_worlds=2, layouts=[0, 1, 2, 3])
    assert [l.name for l in PursuitEnv(default_config(**FAST), n_worlds=4, layouts=[0, 1, 2, 3]).world_layouts] == \
        ["open", "walls", "bars", "cluttered"]
    # with random_layout every episode draws from the whole pool, whatever the number of worlds
    PursuitEnv(default_config(random_layout=True, **FAST), n_worlds=1, layouts=[0, 1, 2, 3])


def _threads() -> int:
    """OS threads of this process now (Linux)."""
    import os

    return len(os.listdir(f"/proc/{os.getpid()}/task"))


def test_close_frees_the_mujoco_batch_and_a_step_after_it_says_so():
    """PursuitEnv had no close(): env.close() (a gymnasium habit, contextlib.closing, a wrapper that
    forwards close) was an AttributeError, and the batch's worker threads lived until the env was
    garbage-collected. close() frees them, may be called again, and what needs the simulation
    until the next reset() says that close() came first."""
    before = _threads()
    env = PursuitEnv(default_config(**FAST), n_worlds=4, seed=0, nthread=3)
    assert _threads() == before + 2  # the batch's workers beside the caller's thread
    env.reset()
    env.step(np.zeros((4, 3, 2)))
    env.close()
    assert _threads() == before and env.closed
    env.close()  # harmless twice
    for call in (lambda: env.step(np.zeros((4, 3, 2))), lambda: env.reset_worlds([0]), env.global_state,
                 lambda: env.snapshot(0), lambda: env.observe_as(env.config), lambda: env.physics.positions()):
        with pytest.raises(RuntimeError, match=r"called after close\(\): call reset\(\) to start again"):
            call()
    with PursuitEnv(default_config(**FAST), n_worlds=2, seed=0, nthread=2) as other:
        other.reset()
    assert other.closed and _threads() == before


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_a_reset_after_close_plays_on_as_if_never_closed(fidelity):
    """reset() after close() makes a new batch: its episodes are those of an env never closed
    (reset() the next ones, never a replay; reset(seed=s) episode 0 of s), bit for bit."""
    cfg = default_config(fidelity=fidelity, command_latency=0.1, max_steps=20)
    actions = np.random.default_rng(0).uniform(-1, 1, (25, 2, 3, 2))
    runs = []
    for closed in (False, True):
        env = PursuitEnv(cfg, n_worlds=2, seed=3)
        env.reset()
        env.step(actions[0])
        if closed:
            env.close()
        trace = [env.reset()]
        for a in actions[1:]:
            trace.extend(env.step(a)[:2])
        if closed:
            env.close()
        trace.append(env.reset(seed=5))
        trace.append(env.step(actions[0])[0])
        runs.append((trace, env.episode.tolist()))
    (kept, kept_episodes), (reopened, reopened_episodes) = runs
    assert kept_episodes == reopened_episodes
    for a, b in zip(kept, reopened):
        np.testing.assert_array_equal(a, b)
