"""The evaders' escape model: fleeing, panic, zigzag, walls, gaps, capture, vectorisation, bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pursuit_mj.config import DRONE_CONTACT_DISTANCE, ConfigError, default_config, load_task_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.evader import EscapeModel, panic_level, surrounded
from pursuit_mj.geometry import ObstacleSet, inside_boundary, obstacle_distance
from pursuit_mj.layout import load_layout
from pursuit_mj.physics import BatchedPhysics
from pursuit_mj.policies import make_policy

DT = 0.1


def arena_obstacles(n_worlds: int, layout: int = 0, border: bool = True) -> ObstacleSet:
    """The fixed obstacles of a built-in layout (no random ones), stacked over worlds."""
    return ObstacleSet.stack([ObstacleSet.from_layout(load_layout(layout), include_border=border)] * n_worlds)


def chase(pursuer_pos: np.ndarray, evader_pos: np.ndarray, speed: float) -> np.ndarray:
    """Naive pursuit: every pursuer (W, N, 2) flies straight at evader 0 (W, M, 2) at `speed`."""
    to_evader = evader_pos[:, :1, :] - pursuer_pos
    return speed * to_evader / np.maximum(np.linalg.norm(to_evader, axis=-1, keepdims=True), 1e-9)


def fly(model: EscapeModel, evader: np.ndarray, pursuers: np.ndarray, obstacles: ObstacleSet, steps: int, chasing: bool = True):
    """Kinematic rollout: evaders follow the model, pursuers chase naively (or hover).

    Returns evader positions (steps + 1, W, M, 2), pursuer positions (steps + 1, W, N, 2) and
    evader commands (steps, W, M, 2).
    """
    speed = model.config.pursuer_speed
    e, p = np.array(evader, float), np.array(pursuers, float)
    ve, vp = np.zeros_like(e), np.zeros_like(p)
    es, ps, cmds = [e.copy()], [p.copy()], []
    active = np.ones(e.shape[:2], bool)
    for _ in range(steps):
        vp = chase(p, e, speed) if chasing else np.zeros_like(p)
        ve = model.compute(e, ve, p, vp, active, obstacles, DT)
        e, p = e + ve * DT, p + vp * DT
        es.append(e.copy())
        ps.append(p.copy())
        cmds.append(ve.copy())
    return np.array(es), np.array(ps), np.array(cmds)


def heading_of(v: np.ndarray) -> np.ndarray:
    return np.arctan2(v[..., 1], v[..., 0])


# ----------------------------------------------------------------------------- fleeing


def test_distance_to_a_lone_chaser_grows_in_open_space():
    config = default_config(n_pursuers=1)
    W = 4
    model = EscapeModel(config, W, seed=3)
    angles = np.array([0.0, 1.3, 2.9, 4.4])
    evader = np.zeros((W, 1, 2))
    chaser = 1.0 * np.stack([np.cos(angles), np.sin(angles)], -1)[:, None, :]  # 1 m away, all around
    es, ps, _ = fly(model, evader, chaser, arena_obstacles(W, border=False), steps=50)
    d = np.linalg.norm(es[:, :, 0] - ps[:, :, 0], axis=-1)  # (steps + 1, W)
    panicked = d[:-1] < config.evader.panic_distance
    assert np.all(np.diff(d, axis=0)[panicked] > 0.02), "distance must grow every step while in panic"
    assert np.all(d[-1] > 2.3), d[-1]


# chaser, evader (m) in the open 3.6 x 5 m arena: below, diagonal, far diagonal, above, beside
CHASE_STARTS = [((1.8, 1.6), (1.8, 2.4)), ((1.0, 1.0), (2.5, 3.0)), ((2.5, 1.0), (1.0, 4.0)), ((1.8, 4.0), (1.8, 2.5)), ((0.8, 2.5), (1.6, 2.5))]


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_a_lone_naive_chaser_never_catches_it_through_physics(fidelity):
    config = default_config(n_pursuers=1, fidelity=fidelity)
    physics = BatchedPhysics(config, [load_layout(0)] * len(CHASE_STARTS), nthread=1)  # no random obstacles
    physics.reset(np.arange(len(CHASE_STARTS)), np.array(CHASE_STARTS, dtype=float))
    model = EscapeModel(config, len(CHASE_STARTS), seed=0)
    obstacles = arena_obstacles(len(CHASE_STARTS))
    free = np.ones((len(CHASE_STARTS), 1), bool)
    d = []
    for _ in range(300):
        pos, vel = physics.positions()[..., :2], physics.velocities()[..., :2]
        d.append(np.linalg.norm(pos[:, 1] - pos[:, 0], axis=-1))
        cmd_e = model.compute(pos[:, 1:], vel[:, 1:], pos[:, :1], vel[:, :1], free, obstacles, DT)
        physics.step(np.concatenate([chase(pos[:, :1], pos[:, 1:], config.pursuer_speed), cmd_e], axis=1))
    d = np.array(d)  # (steps, starts) m
    assert d[15, 0] > d[0, 0] + 0.25, "it flees: the gap to a chaser right below opens within 1.5 s"
    assert d.min() > config.capture_radius, f"a naive chaser caught it within 30 s: closest {d.min(0).round(2)} m per start"


@pytest.mark.parametrize("layout_index", [1, 3])
@pytest.mark.parametrize("speed", [0.6, 0.9])
def test_it_never_flies_into_walls_or_obstacles(layout_index, speed):
    config = default_config(fidelity="point", evader_speed=speed)
    rng = np.random.default_rng(layout_index)
    base = load_layout(layout_index)
    layouts = [base.with_random_obstacles(rng, 5) for _ in range(3)]
    W, N = len(layouts), config.n_pursuers
    physics = BatchedPhysics(config, layouts, nthread=1)
    start = np.zeros((W, N + 1, 2))
    start[:, :N] = [[0.4, 0.4], [1.8, 0.3], [3.2, 0.4]]
    start[:, N] = [[0.5, 4.6], [1.8, 4.5], [3.1, 4.6]]
    physics.reset(np.arange(W), start)
    model = EscapeModel(config, W, seed=7)
    obstacles = ObstacleSet.stack([l.obstacle_set() for l in layouts])
    running = np.ones(W, bool)  # until captured (then everything stops, as in an episode)
    closest = np.full(W, np.inf)
    for _ in range(300):
        pos, vel = physics.positions()[..., :2], physics.velocities()[..., :2]
        cmd_e = model.compute(pos[:, N:], vel[:, N:], pos[:, :N], vel[:, :N], running[:, None], obstacles, DT)
        cmd_p = chase(pos[:, :N], pos[:, N:], config.pursuer_speed) * running[:, None, None]
        contacts = physics.step(np.concatenate([cmd_p, cmd_e], axis=1))
        after = physics.positions()[:, N, :2]
        assert not np.any(contacts[:, N] & running), "the evader touched something"
        closest = np.where(running, np.minimum(closest, obstacle_distance(after[:, None], obstacles)[:, 0]), closest)
        inside = np.array([inside_boundary(l, after[w]) for w, l in enumerate(layouts)])
        assert np.all(inside | ~running), "the evader left the arena"
        caught = np.linalg.norm(physics.positions()[:, :N, :2] - after[:, None], axis=-1).min(-1) < config.capture_radius
        running &= ~caught
    assert np.all(closest > 0.08), closest


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
@pytest.mark.parametrize("speed", [2.0, 3.0])
def test_a_fast_evader_chased_by_the_heuristic_team_keeps_off_walls(fidelity, speed):
    # the fixed margins kept evaders up to 0.9 m/s off walls (closest 0.070 m centre to wall,
    # evader.py step 7), but a faster one could not shed its speed within them: here every
    # run of both speeds touched a wall within 60 steps (0.01-0.065 m centre to wall: its
    # collision volume pressed in); step 7 brakes it
    config = default_config(fidelity=fidelity, evader_speed=speed, layout=0)
    W, N = 4, config.n_pursuers
    env = PursuitEnv(config, n_worlds=W, seed=0, auto_reset=False, nthread=1)
    team = make_policy("heuristic", config)
    closest = np.full(W, np.inf)

    def watch(physics):  # every controller tick, not only at decisions
        d = obstacle_distance(physics.positions()[:, N:, :2], env._obstacles)[:, 0]
        closest[:] = np.where(env.done | env.captured[:, 0], closest, np.minimum(closest, d))

    env.physics.observers.append(watch)
    obs = env.reset()
    team.reset(W)
    for _ in range(100):
        running = ~env.done & ~env.captured[:, 0]
        obs, *_ = env.step(team.act(obs, env.obs_spec))
        assert not (env.physics.contacts[:, N] & running).any(), "the evader touched something"
    body = DRONE_CONTACT_DISTANCE / 2
    assert np.all(closest > body + 0.03), f"closest approach to a wall per world {closest.round(3)} m (body radius {body} m)"


# ----------------------------------------------------------------------------- panic and zigzag


def test_panic_falls_monotonically_with_chaser_distance():
    c = default_config().evader
    d = np.linspace(0.0, 6.0, 121)
    p = panic_level(d, c.panic_distance, c.calm_distance)
    assert np.all(np.diff(p) <= 0)
    assert np.all(p[d <= c.panic_distance] == 1.0) and np.all(p[d >= c.calm_distance] == 0.0)
    assert 0.0 < p[np.searchsorted(d, 0.5 * (c.panic_distance + c.calm_distance))] < 1.0
    # the model's own panic, one chaser at each distance (one world each)
    config = default_config(n_pursuers=1)
    W = len(d)
    model = EscapeModel(config, W, seed=0)
    chaser = np.stack([d, np.zeros(W)], -1)[:, None, :]
    still = np.zeros((W, 1, 2))
    model.compute(still, still, chaser, np.zeros_like(chaser), np.ones((W, 1), bool), arena_obstacles(W, border=False), DT)
    assert np.all(np.diff(model.panic[:, 0]) <= 0)
    np.testing.assert_allclose(model.panic[:, 0], p)


def test_calm_zigzag_turns_and_is_seeded():
    config = default_config(n_pursuers=1)
    far = np.array([[[50.0, 50.0]]])  # beyond sense_radius: calm
    paths = []
    for seed in (5, 5, 6):
        model = EscapeModel(config, 1, seed=0)
        model.reset(np.array([0]), np.array([seed]))
        es, _, cmds = fly(model, np.zeros((1, 1, 2)), far, arena_obstacles(1, border=False), steps=200, chasing=False)
        paths.append(es[:, 0, 0])
        turns = np.abs(np.angle(np.exp(1j * np.diff(heading_of(cmds[:, 0, 0])))))
        assert np.sum(turns > 0.15) >= 8, "a calm evader changes heading every few seconds"
        np.testing.assert_allclose(np.linalg.norm(cmds, axis=-1), config.evader_speed)
    np.testing.assert_array_equal(paths[0], paths[1])
    assert np.abs(paths[0] - paths[2]).max() > 0.5, "another seed, another path"


# ----------------------------------------------------------------------------- walls and gaps


def test_it_follows_a_wall_away_from_the_chaser():
    config = default_config(n_pursuers=1)
    model = EscapeModel(config, 1, seed=0)
    # near the bottom wall; the chaser above and to the right drives it into the wall
    e, p = np.array([[[1.5, 0.35]]]), np.array([[[1.9, 1.2]]])
    following, cmds, ys = [], [], []
    for _ in range(15):
        v = model.compute(e, np.zeros_like(e), p, np.zeros_like(p), np.ones((1, 1), bool), arena_obstacles(1), DT)
        following.append(model.following[0, 0])
        cmds.append(v[0, 0])
        e = e + v * DT
        ys.append(e[0, 0, 1])
    v = np.array(cmds)[3:]
    assert all(following), "fleeing would drive it into the wall, so it follows the wall"
    assert np.all(v[:, 0] < -0.4), "along the wall, away from the chaser (to the left)"
    assert np.all(np.abs(v[:, 1]) < 0.35), "mostly along the wall, neither into it nor off it"
    assert min(ys) > 0.2, "it keeps off the wall"


@pytest.mark.parametrize("seed", range(4))
def test_unchased_close_to_a_wall_it_moves_off_it(seed):
    """The wall push points away from the wall: 0.15 m from it, with no chaser in sight, five
    steps take it past 0.3 m (pushed the wrong way it stayed at 0.21-0.22 m in three of these seeds)."""
    model = EscapeModel(default_config(n_pursuers=1), 1, seed=seed)
    e, p = np.array([[[1.5, 0.15]]]), np.array([[[3.3, 4.7]]])  # the chaser far beyond its sensing
    for _ in range(5):
        v = model.compute(e, np.zeros_like(e), p, np.zeros_like(p), np.ones((1, 1), bool), arena_obstacles(1), DT)
        e = e + v * DT
    assert e[0, 0, 1] > 0.3


def test_the_flee_vector_weights_each_chasers_direction_by_one_over_its_distance_squared():
    from pursuit_mj.evader import flee_vector

    away = np.array([[[[1.0, 0.0], [0.0, 2.0], [5.0, 5.0]]]])  # evader minus chaser, (W, M, N, 2)
    sensed = np.array([[[True, True, False]]])
    np.testing.assert_allclose(flee_vector(away, sensed), [[[1.0, 0.25]]])  # (1, 0) / 1 + (0, 1) / 4; the third unsensed


def test_it_flees_from_where_a_moving_chaser_will_be():
    """A chaser 0.8 m below, flying right at 0.3 m/s: it flees from 0.3 x lead_time further right, so a little left."""
    config = default_config(n_pursuers=1)
    model = EscapeModel(config, 1, seed=0)
    e, p, pv = np.array([[[1.8, 2.5]]]), np.array([[[1.8, 1.7]]]), np.array([[[0.3, 0.0]]])
    v = model.compute(e, np.zeros_like(e), p, pv, np.ones((1, 1), bool), arena_obstacles(1), DT)[0, 0]
    ahead = 0.3 * model.cfg.lead_time
    np.testing.assert_allclose(v, config.evader_speed * np.array([-ahead, 0.8]) / np.hypot(ahead, 0.8), rtol=1e-6)


def test_it_slips_through_a_gap_it_can_reach_first():
    config = default_config()
    model = EscapeModel(config, 1, seed=0)
    # cornered against the bottom wall; two chasers close in from both sides, a third far up
    evader = np.array([[[1.8, 0.45]]])
    chasers = np.array([[[0.6, 1.3], [3.0, 1.3], [1.8, 4.5]]])
    es, ps, cmds = fly(model, evader, chasers, arena_obstacles(1), steps=25)
    first = cmds[0, 0, 0] / config.evader_speed
    to_gap = np.array([0.0, 1.0])  # the pair's midpoint (1.8, 1.3) is straight up
    assert first @ to_gap > 0.95
    passed = es[:, 0, 0, 1] > ps[:, 0, 0, 1] + 0.3  # beyond the line of the two side chasers
    assert passed.any(), "it gets through"
    d = np.linalg.norm(es[:, 0, 0][:, None] - ps[:, 0], axis=-1).min()
    assert d > config.capture_radius + 0.1, "and is never within reach while doing it"


def test_no_gap_escape_when_the_chasers_are_too_close():
    config = default_config()
    model = EscapeModel(config, 1, seed=0)
    evader = np.array([[[1.8, 0.45]]])
    chasers = np.array([[[1.45, 0.85], [2.15, 0.85], [1.8, 4.5]]])  # midpoint 0.4 m away, 0.35 m from each
    vel = model.compute(evader, np.zeros_like(evader), chasers, np.zeros_like(chasers), np.ones((1, 1), bool), arena_obstacles(1), DT)
    assert not model.gap[0, 0]
    assert (vel[0, 0] / config.evader_speed) @ np.array([0.0, 1.0]) < 0.9, "it does not dash for the closed gap"
    # the same pair twice as far apart leaves a gap it takes
    wide = chasers.copy()
    wide[0, :2, 0] = [1.8 - 1.2, 1.8 + 1.2]
    model.reset(np.array([0]))
    model.compute(evader, np.zeros_like(evader), wide, np.zeros_like(wide), np.ones((1, 1), bool), arena_obstacles(1), DT)
    assert model.gap[0, 0]


def test_it_keeps_to_its_gap_when_the_other_chaser_becomes_the_nearer():
    # cornered against the bottom wall; chaser 0 hovers, chaser 1 closes in from the right, so
    # halfway through the gap chaser 1 becomes the nearer of the two (once the committed gap was
    # recognised only with its nearer chaser first: the evader dropped it there, out of the
    # corner, and turned back toward the wall before it was across)
    config = default_config(n_pursuers=2)
    model = EscapeModel(config, 1, seed=0)
    e, p = np.array([[[1.8, 0.45]]]), np.array([[[0.9, 1.3], [3.0, 1.3]]])
    vp = np.array([[[0.0, 0.0], [-0.2, 0.0]]])
    ve, on, across, nearer = np.zeros_like(e), [], [], []
    for _ in range(20):
        ve = model.compute(e, ve, p, vp, np.ones((1, 1), bool), arena_obstacles(1), DT)
        edge, rel = p[0, 1] - p[0, 0], e[0, 0] - p[0, 0]
        across.append(edge[0] * rel[1] - edge[1] * rel[0] > 0)
        nearer.append(np.argmin(np.linalg.norm(e[0, 0] - p[0], axis=-1)))
        on.append(model.gap[0, 0])
        assert across[-1] or (model.gap[0, 0] and ve[0, 0, 1] > 0.5), "until across it keeps to the gap, upward"
        e, p = e + ve * DT, p + vp * DT
    assert nearer[0] == 0 and 1 in nearer[: across.index(True)], "the other chaser became the nearer on the way"
    assert e[0, 0, 1] > p[0, :, 1].max() + 0.3, "it got through"


def test_surrounded_in_the_open_it_takes_the_widest_safe_gap():
    config = default_config()
    model = EscapeModel(config, 1, seed=0)
    ang = np.radians([90.0, 200.0, 340.0])  # the widest gap is between 200 and 340 degrees (below)
    chasers = (1.2 * np.stack([np.cos(ang), np.sin(ang)], -1))[None]
    still = np.zeros((1, 1, 2))
    vel = model.compute(still, still, chasers, np.zeros_like(chasers), np.ones((1, 1), bool), arena_obstacles(1, border=False), DT)
    assert model.gap[0, 0]
    assert (vel[0, 0] / config.evader_speed) @ np.array([0.0, -1.0]) > 0.95


# ----------------------------------------------------------------------------- interface


def test_output_speed_and_captured_evaders():
    config = default_config(n_evaders=3)
    rng = np.random.default_rng(2)
    W = 16
    base = load_layout(3)
    obstacles = ObstacleSet.stack([base.with_random_obstacles(rng, 5).obstacle_set() for _ in range(W)])
    model = EscapeModel(config, W, seed=1)
    active = rng.random((W, 3)) < 0.7
    for _ in range(5):
        e = np.stack([rng.uniform(0.3, 3.3, (W, 3)), rng.uniform(0.3, 4.7, (W, 3))], -1)
        p = np.stack([rng.uniform(0.3, 3.3, (W, 3)), rng.uniform(0.3, 4.7, (W, 3))], -1)
        v = model.compute(e, 0.3 * rng.normal(size=e.shape), p, rng.normal(size=p.shape), active, obstacles, DT)
        speed = np.linalg.norm(v, axis=-1)
        d = np.linalg.norm(e[:, :, None] - e[:, None], axis=-1)
        d = np.where(active[:, None, :] & ~np.eye(3, dtype=bool), d, np.inf).min(-1)
        alone = active & (d > 2.0)  # no other free evader near enough to slow it (step 8)
        assert alone.sum() >= 3
        np.testing.assert_allclose(speed[alone], config.evader_speed, rtol=1e-9)
        assert np.all(speed[active] <= config.evader_speed * (1 + 1e-9))
        assert np.all(v[~active] == 0.0)


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_evaders_never_fly_into_each_other(fidelity):
    # hovering pursuers: three evaders zigzag about the same arena (before step 8 they touched
    # in 5 of 8 worlds in quadrotor fidelity and tumbled to the floor)
    config = default_config(fidelity=fidelity, n_evaders=3, layout=0)
    env = PursuitEnv(config, n_worlds=6, seed=1, auto_reset=False)
    env.reset()
    N = config.n_pursuers
    for _ in range(150):
        env.step(np.zeros((6, N, 2)))
        assert not env.physics.contacts[:, N:].any()
        gaps = np.linalg.norm(env.physics.positions()[:, N:, None, :2] - env.physics.positions()[:, None, N:, :2], axis=-1)
        assert np.all(gaps + np.eye(3) > DRONE_CONTACT_DISTANCE)


def test_keeping_apart_never_commands_more_than_evader_speed():
    # two evaders 0.25 m apart closing at 1.7 m/s, 1 m below the top wall: the upper one must
    # back off upward, but must not turn further toward the wall than it flew, and the two caps'
    # lines cross almost in parallel; the crossing (79 m/s sideways) was returned as the command
    config = default_config(n_evaders=2)
    model = EscapeModel(config, 1, seed=499)
    e = np.array([[[2.185, 3.719], [2.186, 3.971]]])
    ev = np.array([[[0.378, 0.794], [0.701, -0.912]]])
    p = np.array([[[1.264, 3.691], [1.083, 2.569], [0.866, 2.69]]])
    v = model.compute(e, ev, p, np.zeros_like(p), np.ones((1, 2), bool), arena_obstacles(1), DT)
    assert np.all(np.linalg.norm(v, axis=-1) <= config.evader_speed * (1 + 1e-9)), np.linalg.norm(v, axis=-1)
    closing = -(v[0, 1] - v[0, 0]) @ (e[0, 1] - e[0, 0]) / np.linalg.norm(e[0, 1] - e[0, 0])
    assert closing <= 1e-9, f"the pair still closes in at {closing} m/s"


def test_evaders_meeting_head_on_turn_aside():
    # two evaders following the top wall toward each other, each pushed on by a chaser: the
    # look-ahead did not see the other evader, so both kept choosing the way into it and step 8
    # held them face to face, nearly still (about 0.01-0.04 m/s for 4-9 decisions here; in the
    # env with a heuristic team, up to 5.8 s)
    config = default_config(n_evaders=2)
    model = EscapeModel(config, 1, seed=0)
    e, v = np.array([[[1.0, 4.6], [1.25, 4.6]]]), np.array([[[0.1, 0.0], [-0.1, 0.0]]])
    p = np.array([[[0.6, 4.3], [1.65, 4.3], [1.12, 3.0]]])
    speeds = []
    for _ in range(10):
        v = model.compute(e, v, p, np.zeros_like(p), np.ones((1, 2), bool), arena_obstacles(1), DT)
        e = e + v * DT
        speeds.append(np.linalg.norm(v, axis=-1)[0])
    assert np.min(speeds) > 0.5 * config.evader_speed


def test_evaders_push_each_other_apart():
    config = default_config(n_evaders=2)
    lonely = dataclasses.replace(config, evader=dataclasses.replace(config.evader, evader_gain=0.0))
    e = np.array([[[1.7, 2.5], [1.9, 2.5]]])
    far = np.array([[[50.0, 50.0], [51.0, 50.0], [52.0, 50.0]]])
    apart = []
    for c in (config, lonely):
        model = EscapeModel(c, 1, seed=4)
        v = model.compute(e, np.zeros_like(e), far, np.zeros_like(far), np.ones((1, 2), bool), arena_obstacles(1), DT)
        apart.append(v[0, 1, 0] - v[0, 0, 0])  # rate at which their x separation grows
    assert apart[0] > apart[1] + 0.02


def test_worlds_together_equal_worlds_apart():
    config = default_config(n_evaders=2)
    rng = np.random.default_rng(11)
    W = 5
    layouts = [load_layout(i % 4).with_random_obstacles(rng, 4) for i in range(W)]
    sets = [l.obstacle_set() for l in layouts]
    e0 = np.stack([rng.uniform(0.5, 3.1, (W, 2)), rng.uniform(3.8, 4.6, (W, 2))], -1)
    p0 = np.stack([rng.uniform(0.5, 3.1, (W, 3)), rng.uniform(0.4, 2.0, (W, 3))], -1)
    seeds = rng.integers(0, 2**31, W)
    together = EscapeModel(config, W, seed=0)
    together.reset(np.arange(W), seeds)
    es, _, cmds = fly(together, e0, p0, ObstacleSet.stack(sets, n_boxes=12, n_cylinders=12), steps=40)
    for w in range(W):
        alone = EscapeModel(config, 1, seed=99)
        alone.reset(np.array([0]), seeds[w : w + 1])
        es_w, _, cmds_w = fly(alone, e0[w : w + 1], p0[w : w + 1], ObstacleSet.stack([sets[w]]), steps=40)
        np.testing.assert_allclose(cmds_w[:, 0], cmds[:, w], atol=1e-9)
        np.testing.assert_allclose(es_w[:, 0], es[:, w], atol=1e-9)


def test_reset_restarts_an_episode_exactly():
    config = default_config()
    model = EscapeModel(config, 2, seed=0)
    model.reset(np.arange(2), np.array([8, 9]))
    e0, p0 = np.array([[[1.0, 4.0]], [[2.5, 4.2]]]), np.array([[[0.5, 1.0], [1.5, 1.0], [2.5, 1.0]]] * 2)
    _, _, first = fly(model, e0, p0, arena_obstacles(2, layout=3), steps=20)
    model.reset(np.array([1]), np.array([9]))  # only world 1 starts again
    model.reset(np.array([0]), np.array([8]))
    _, _, again = fly(model, e0, p0, arena_obstacles(2, layout=3), steps=20)
    np.testing.assert_array_equal(first, again)


def test_bad_input_is_refused_by_name():
    config = default_config()
    model = EscapeModel(config, 2, seed=0)
    e, p = np.zeros((2, 1, 2)), np.ones((2, 3, 2))
    ok = dict(evader_pos=e, evader_vel=e, pursuer_pos=p, pursuer_vel=p, active=np.ones((2, 1), bool), obstacles=arena_obstacles(2), dt=DT)
    for key, value, word in [
        ("evader_pos", np.zeros((2, 2, 2)), "evader_pos"),
        ("pursuer_vel", np.full((2, 3, 2), np.nan), "pursuer_vel"),
        ("active", np.ones((2, 1)), "active"),
        ("obstacles", arena_obstacles(3), "obstacles"),
        ("dt", 0.0, "dt"),
        ("dt", True, "dt"),  # ran as a 1 s decision interval (the seed refuses bools already)
    ]:
        with pytest.raises(ValueError, match=word):
            model.compute(**{**ok, key: value})
    with pytest.raises(ValueError, match="world_ids"):
        model.reset(np.array([2]))
    with pytest.raises(ValueError, match="seeds"):
        model.reset(np.array([0, 1]), np.array([1]))
    with pytest.raises(ValueError, match="n_worlds"):
        EscapeModel(config, 0, seed=0)
    for seed in (1.5, "7", -1, True):  # 1.5 ran as seed 1, "7" failed in int(), -1 only at reset(seeds)
        with pytest.raises(ValueError, match="EscapeModel seed"):
            EscapeModel(config, 1, seed=seed)


def test_evader_settings_are_validated():
    with pytest.raises(ConfigError, match="calm_distance"):
        default_config(evader={"panic_distance": 2.0, "calm_distance": 1.5})
    with pytest.raises(ConfigError, match="zigzag_angle"):
        load_task_config(overrides=["evader.zigzag_angle=4"])
    assert load_task_config(overrides=["evader.sense_radius=2.5"]).evader.sense_radius == 2.5


def test_a_config_made_without_the_loader_is_checked():
    # dataclasses.replace skips the loader's checks: calm_distance below panic_distance made
    # panic 1 far from the chasers and 0 next to them, and an evader dict failed deep inside
    config = default_config()
    inverted = dataclasses.replace(config, evader=dataclasses.replace(config.evader, calm_distance=1.0))
    with pytest.raises(ConfigError, match="EscapeModel config.*calm_distance"):
        EscapeModel(inverted, 1, seed=0)
    with pytest.raises(ConfigError, match="EscapeModel config: key 'evader'"):
        EscapeModel(dataclasses.replace(config, evader={"calm_distance": 1.0}), 1, seed=0)


# ----------------------------------------------------------------------------- mutation audit


@pytest.mark.parametrize("room_at,room,speed", [(0, 1.0, 0.97161), (3, 0.1, 1.05832)])
def test_a_fast_evader_brakes_to_the_speed_its_room_allows_along_each_direction(room_at, room, speed):
    """Step 7 written out: flying +x at 2 m/s, the only obstacle `room` m away along RING
    direction `room_at` (0: straight ahead; 3: 67.5 deg off). Ahead: left = 1 - 0.1 - 0.3 * 2 =
    0.3 m, cap = sqrt(0.405**2 + 2 * 1.3 * 0.3) = 0.9716 m/s; 67.5 deg off, closing at
    2 cos(67.5 deg): no room left, so the cap is the floor 0.9**2 / 2 = 0.405 m/s along that
    direction, 0.405 / cos(67.5 deg) = 1.058 m/s along +x."""
    from pursuit_mj.evader import RING, RING_ANGLES

    model = EscapeModel(default_config(evader_speed=2.0), 1, seed=0)
    final = np.array([[[1.0, 0.0]]])
    survey = np.stack([np.cos(RING_ANGLES), np.sin(RING_ANGLES)], -1)[None, None]  # (1, 1, RING, 2), 0 = +x
    rooms = np.full((1, 1, RING), 1e6)
    rooms[0, 0, room_at] = room
    got = model._braking_speed(final, np.array([[[2.0, 0.0]]]), survey, rooms)
    assert float(np.squeeze(got)) == pytest.approx(speed, abs=1e-5)


@pytest.mark.parametrize("velocity", [(0.0, -0.4), (0.3, 0.3), (-0.5, 0.0)])
def test_an_evader_new_to_an_episode_flies_on_along_its_velocity(velocity):
    # calm (chasers far beyond sense_radius), no zigzag, no walls: the first command keeps the
    # direction the evader was already flying (step 1 of `_start_headings`), not a random one
    config = default_config(n_pursuers=1, evader={"zigzag_rate": 0.0})
    model = EscapeModel(config, 1, seed=0)
    v = model.compute(np.zeros((1, 1, 2)), np.array([[velocity]]), np.array([[[50.0, 50.0]]]), np.zeros((1, 1, 2)),
                      np.ones((1, 1), bool), arena_obstacles(1, border=False), DT)
    np.testing.assert_allclose(v[0, 0], config.evader_speed * np.array(velocity) / np.linalg.norm(velocity), atol=1e-9)


def test_a_calm_evader_takes_no_gap_however_cornered():
    # the scene of test_it_slips_through_a_gap_it_can_reach_first, but with the chasers (1.5 m
    # away) beyond calm_distance: no panic, so no gap escape (step 3), though the flee
    # direction has no room and the gap would be open
    chasers = np.array([[[0.6, 1.3], [3.0, 1.3], [1.8, 4.5]]])
    evader = np.array([[[1.8, 0.45]]])
    gaps = []
    for calm in (3.0, 1.0):
        model = EscapeModel(default_config(evader={"panic_distance": 0.5, "calm_distance": calm}), 1, seed=0)
        model.compute(evader, np.zeros((1, 1, 2)), chasers, np.zeros((1, 3, 2)), np.ones((1, 1), bool), arena_obstacles(1), DT)
        gaps.append(bool(model.gap[0, 0]))
    assert gaps == [True, False]  # panicked (calm_distance 3 m): through the gap; calm: not


def test_two_evaders_closing_in_share_the_closing_speed_budget():
    # step 8: each of two evaders 1 m apart, standing, flying at the other, may close at half
    # of APART_RATE * (gap - APART_BUFFER), the gap between their collision volumes
    from pursuit_mj.evader import APART_BUFFER, APART_RATE

    model = EscapeModel(default_config(n_evaders=2), 1, seed=0)
    e = np.array([[[1.0, 1.0], [2.0, 1.0]]])
    v = np.array([[[0.6, 0.0], [-0.6, 0.0]]])
    out = model._keep_apart(e, np.zeros_like(e), v, np.ones((1, 2), bool), np.zeros_like(e))
    cap = 0.5 * APART_RATE * (1.0 - DRONE_CONTACT_DISTANCE - APART_BUFFER)
    np.testing.assert_allclose(out[0], [[cap, 0.0], [-cap, 0.0]], atol=1e-9)


@pytest.mark.parametrize("push,side", [(0.3, -1.0), (0.98, 1.0)])
def test_a_wall_follower_keeps_its_side_unless_the_chasers_push_back_hard(push, side):
    # following the bottom wall with it on the right (side -1: along +x), wanting into it: a
    # chaser push the other way (toward -x, the tangent (-1, 0) that keeps the wall on the left)
    # of `push` (panic 1) turns it round only beyond FOLLOW_SWITCH (0.5); a weaker one leaves
    # the side it chose
    model = EscapeModel(default_config(n_pursuers=1), 1, seed=0)
    model.following[:] = True
    model.follow_side[:] = -1.0
    model.panic[:] = 1.0
    model.heading[:] = [1.0, 0.0]
    flee = np.array([[[-push, -np.sqrt(1 - push**2)]]])  # tangent here is (-1, 0): push along it is `push`
    model._follow_walls(np.array([[[1.8, 0.4]]]), np.array([[[0.0, -1.0]]]), np.array([[0.35]]), flee,
                        arena_obstacles(1), np.ones((1, 1), bool))
    assert model.following[0, 0] and model.follow_side[0, 0] == side


@pytest.mark.parametrize("wall,speed", [(True, 0.3), (False, 0.6)])
def test_an_evader_pressed_by_another_is_not_turned_into_a_wall_nor_made_faster(wall, speed):
    # A flies +x 0.2 m below B, closer than their buffer: keeping apart alone would back A off
    # downward (cap -0.028 m/s toward B), toward the bottom wall (at 0.3 m/s), or above
    # evader_speed (at 0.6 m/s). It may do neither (step 8): A flies on level, and only stops
    # closing in
    model = EscapeModel(default_config(n_evaders=2), 1, seed=0)
    e = np.array([[[1.0, 0.2], [1.0, 0.4]]])
    v = np.array([[[speed, 0.0], [0.0, 0.0]]])
    normal = np.array([[[0.0, 1.0], [0.0, 1.0]]]) if wall else np.zeros((1, 2, 2))  # away from the wall
    out = model._keep_apart(e, np.zeros_like(e), v, np.ones((1, 2), bool), normal)
    np.testing.assert_allclose(out[0, 0], [speed, 0.0], atol=1e-12)
    if wall:  # without the wall the same evader backs off
        free = model._keep_apart(e, np.zeros_like(e), v, np.ones((1, 2), bool), np.zeros((1, 2, 2)))
        assert free[0, 0, 1] < -0.02


def test_another_evader_limits_the_room_toward_it_only():
    # B 0.5 m east of A: A's room ends DRONE_CONTACT_DISTANCE + APART_BUFFER short of B going
    # east, and is open going west, away from B
    from pursuit_mj.evader import APART_BUFFER
    from pursuit_mj.geometry import FAR

    model = EscapeModel(default_config(n_evaders=2), 1, seed=0)
    e = np.array([[[1.0, 1.0], [1.5, 1.0]]])
    dirs = np.array([[[[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]]]])
    room = model._evader_room(e, np.ones((1, 2), bool), dirs)
    np.testing.assert_allclose(room[0, 0], [0.5 - DRONE_CONTACT_DISTANCE - APART_BUFFER, FAR, FAR])
    np.testing.assert_allclose(room[0, 1], [FAR, 0.5 - DRONE_CONTACT_DISTANCE - APART_BUFFER, FAR])


def test_a_panicked_evader_will_not_fly_into_a_chaser_s_reach_for_alignment():
    # panicked, wanting +x, with a chaser 2 m ahead on +x: along +x it would come within the
    # chaser's reach (capture radius included) at the end of the horizon; +y keeps clear. The
    # margin it would lose counts DANGER times (step 6), so +y wins over the better alignment
    config = default_config(n_pursuers=1)
    assert config.pursuer_speed / config.evader_speed == 0.5 and config.capture_radius == 0.3  # the numbers below
    model = EscapeModel(config, 1, seed=0)
    model.panic[:] = 1.0
    want = np.array([[[1.0, 0.0]]])
    model.heading[:] = want
    candidates = np.array([[[[1.0, 0.0], [0.0, 1.0]]]])
    # along +x: 2 - 1.5 - 0.5 * 1.5 - 0.3 = -0.55 m, times DANGER; along +y: clear by over 1 m
    best = model._choose(np.zeros((1, 1, 2)), np.array([[[2.0, 0.0]]]), np.ones((1, 1, 1), bool), want, candidates,
                         np.full((1, 1, 2), 10.0))
    assert best[0, 0] == 1


def test_a_cornered_evader_keeps_to_the_gap_it_chose_over_one_a_little_safer():
    # three open gaps; it is committed to the one between chasers 0 and 2 (side +1). The gap
    # between 0 and 1 keeps about 0.76 m more out of reach, less than the 1 m a chosen gap is
    # worth (step 3): it stays with its gap rather than switch between steps
    model = EscapeModel(default_config(), 1, seed=0)
    e = np.zeros((1, 1, 2))
    pp = np.array([[[3.0, 0.0], [-3.0, 0.0], [0.0, 3.0]]])
    toward = pp[:, None] - e[:, :, None]
    dist = np.linalg.norm(toward, axis=-1)
    dirs = np.array([[0.0, -1.0], [np.sqrt(0.5), -np.sqrt(0.5)], [-np.sqrt(0.5), -np.sqrt(0.5)]])[None, None]
    ci, cj = np.array([[[0, 0, 1]]]), np.array([[[1, 2, 2]]])
    model.panic[:] = 1.0
    model.gap_pair[:] = [0, 2]
    model.gap_side[:] = 1.0
    on, through = model._gap_escape(dist, np.ones((1, 1, 3), bool), dirs, np.ones((1, 1, 3)), np.ones((1, 1, 3)), ci, cj,
                                    np.full((1, 1, 3), 10.0), np.array([[0.1]]), toward, pp, e, np.ones((1, 1), bool))
    assert on[0, 0] and model.gap_pair[0, 0].tolist() == [0, 2]
    np.testing.assert_allclose(through[0, 0], dirs[0, 0, 1])


@pytest.mark.parametrize("free,taken", [(0.3, False), (0.5, True)])
def test_a_short_gap_path_needs_the_look_ahead_s_room_beyond_it(free, taken):
    # a path of 0.2 m through the gap, free for `free` m: the look-ahead needs clearance +
    # evader_speed * lookahead_time = 0.45 m free, however short the path (step 3)
    model = EscapeModel(default_config(), 1, seed=0)
    assert model._need == pytest.approx(0.45)
    e = np.zeros((1, 1, 2))
    pp = np.array([[[3.0, 0.0], [-3.0, 0.0], [0.0, 3.0]]])
    toward = pp[:, None] - e[:, :, None]
    dirs = np.tile([0.0, -1.0], (1, 1, 3, 1))
    model.panic[:] = 1.0
    on, _ = model._gap_escape(np.linalg.norm(toward, axis=-1), np.ones((1, 1, 3), bool), dirs, np.full((1, 1, 3), 0.2),
                              np.ones((1, 1, 3)), np.array([[[0, 0, 1]]]), np.array([[[1, 2, 2]]]), np.full((1, 1, 3), free),
                              np.array([[0.1]]), toward, pp, e, np.ones((1, 1), bool))
    assert bool(on[0, 0]) is taken


def test_a_zigzag_turn_is_between_half_and_all_of_zigzag_angle_either_side():
    config = default_config()
    model = EscapeModel(config, 64, seed=3)
    model.heading[:] = [1.0, 0.0]
    model._turn_wander(1e3)  # a turn is all but certain within 1000 s
    turn = np.arctan2(model.wander[..., 1], model.wander[..., 0]).ravel()
    a = config.evader.zigzag_angle
    assert np.all((np.abs(turn) >= 0.5 * a - 1e-9) & (np.abs(turn) <= a + 1e-9))
    assert (turn > 0).any() and (turn < 0).any() and np.ptp(np.abs(turn)) > 0.25 * a  # both sides, amplitudes spread


def test_surrounded_answers_each_evader_alone():
    """A batch mixing evaders with 0-4 counted chasers, some surrounded, gives each evader the
    answer it gets alone (surrounded only sorts bearings where 3 or more count)."""
    ang = np.radians([[0.0, 120.0, 240.0, 60.0], [0.0, 30.0, 60.0, 90.0], [0.0, 120.0, 240.0, 60.0], [0.0, 170.0, 130.0, 250.0]])
    toward = np.stack([np.cos(ang), np.sin(ang)], -1)[None]  # (1, 4, 4, 2)
    mask = np.array([[[True, True, True, False], [True, True, True, True], [True, True, False, False], [True, False, True, True]]])
    expected = [True, False, False, True]  # 3 around; all on one side; only 2 count; 3 around (4th not counted)
    assert surrounded(toward, mask).tolist() == [expected]
    for m in range(4):
        assert surrounded(toward[:, m : m + 1], mask[:, m : m + 1]).tolist() == [[expected[m]]]
    assert not surrounded(toward, np.zeros_like(mask)).any()


def test_obstacle_normal_is_distance_and_normals_normal_to_the_bit():
    """The follow-walls probe measures only the four offsets its normal needs: the same numbers
    as distance_and_normal's normal (boxes at any yaw, cylinders, border, padded worlds)."""
    from pursuit_mj.evader import distance_and_normal, obstacle_normal
    from pursuit_mj.geometry import ObstacleSet

    rng = np.random.default_rng(4)
    sets = []
    for w in range(5):
        nb, nc = rng.integers(0, 4), rng.integers(0, 3)
        boxes = np.column_stack([rng.uniform(1, 9, (nb, 2)), rng.uniform(0.1, 1, (nb, 2)), rng.uniform(-3, 3, nb)])
        cyl = np.column_stack([rng.uniform(1, 9, (nc, 2)), rng.uniform(0.1, 0.6, nc)])
        border = np.array([[0, 0, 10, 0], [10, 0, 10, 8], [10, 8, 0, 8], [0, 8, 0, 0]], float)
        sets.append(ObstacleSet(boxes, np.ones(nb, bool), cyl, np.ones(nc, bool), border, np.ones(4, bool)))
    obstacles = ObstacleSet.stack(sets)
    points = rng.uniform(-0.5, 10.5, (5, 40, 2))
    _, normal = distance_and_normal(points, obstacles)
    assert obstacle_normal(points, obstacles).tobytes() == normal.tobytes()


def _random_obstacles(rng, worlds):
    from pursuit_mj.geometry import ObstacleSet

    sets = []
    for _ in range(worlds):
        nb, nc = rng.integers(0, 4), rng.integers(0, 3)
        boxes = np.column_stack([rng.uniform(1, 9, (nb, 2)), rng.uniform(0.1, 1, (nb, 2)), rng.uniform(-3, 3, nb)])
        cyl = np.column_stack([rng.uniform(1, 9, (nc, 2)), rng.uniform(0.1, 0.6, nc)])
        border = np.array([[0, 0, 10, 0], [10, 0, 10, 8], [10, 8, 0, 8], [0, 8, 0, 0]], float)
        sets.append(ObstacleSet(boxes, np.ones(nb, bool), cyl, np.ones(nc, bool), border, np.ones(4, bool)))
    return ObstacleSet.stack(sets)


def test_corridors_free_rows_are_the_free_lengths_of_those_evaders_to_the_bit():
    from pursuit_mj.evader import Corridors

    rng = np.random.default_rng(5)
    W, M, Q = 6, 3, 5
    obstacles = _random_obstacles(rng, W)
    corridors = Corridors(obstacles, rng.uniform(0.5, 9.5, (W, M, 2)), rng.uniform(0.0, 0.1, (W, M)))
    a = rng.uniform(0, 2 * np.pi, (W, M, Q))
    dirs = np.stack([np.cos(a), np.sin(a)], -1)
    whole = corridors.free(dirs)
    rows = np.array([16, 2, 7])  # flat w * M + m, in any order
    assert corridors.free_rows(dirs.reshape(W * M, Q, 2)[rows], rows).tobytes() == whole.reshape(W * M, Q)[rows].tobytes()
    assert corridors.free_rows(dirs.reshape(W * M, Q, 2), None).tobytes() == whole.reshape(W * M, Q).tobytes()


@pytest.mark.parametrize("n_panicking", [0, 1, 5, 8])
def test_each_evader_flies_as_it_would_alone_whether_few_or_most_others_panic(n_panicking):
    # the chaser-safety score and the gap escape are worked out only for the evaders that panic
    # (or keep to a gap) while few do, for all at once when most do: either way each evader's
    # command, gap and state are what the same model gives it in a world of its own
    rng = np.random.default_rng(n_panicking)
    W, N = 8, 3
    config = default_config()
    obstacles = _random_obstacles(rng, W)
    e = rng.uniform(2, 8, (W, 1, 2))
    far = rng.uniform(0, 10, (W, N, 2)) * [1, 0.2] + [0, 7.5]  # chasers on the far side, mostly beyond calm_distance
    near = e + rng.uniform(-1.2, 1.2, (W, N, 2))  # within panic_distance
    pp = np.where((np.arange(W) < n_panicking)[:, None, None], near, far)
    pv = rng.uniform(-0.5, 0.5, (W, N, 2))
    batch = EscapeModel(config, W, seed=1)
    alone = [EscapeModel(config, 1, seed=1) for _ in range(W)]
    seeds = np.arange(W) + 10
    batch.reset(np.arange(W), seeds)
    for w in range(W):
        alone[w].reset(np.arange(1), seeds[w : w + 1])
    active = np.ones((W, 1), bool)
    for _ in range(4):
        got = batch.compute(e, np.zeros((W, 1, 2)), pp, pv, active, obstacles, 0.1)
        for w in range(W):
            one = alone[w].compute(e[w : w + 1], np.zeros((1, 1, 2)), pp[w : w + 1], pv[w : w + 1], active[w : w + 1],
                                   obstacles.take(np.array([w])), 0.1)
            assert one.tobytes() == got[w : w + 1].tobytes()
            for k in ("panic", "gap", "gap_pair", "gap_side", "heading", "following"):
                assert getattr(alone[w], k).tobytes() == getattr(batch, k)[w : w + 1].tobytes(), k
        e = e + got * 0.1
    assert (batch.panic > 0).sum() >= n_panicking


def test_corridors_grow_box_edges_out_and_border_segments_in_by_the_radius():
    # evaders 1 m right of a 1 m box's face and 1 m off its corner, radius 0.2 m: a ray meets the
    # box's face grown by it, the border moved in by it, and the corner's circle of that radius
    from pursuit_mj.evader import Corridors

    box = ObstacleSet(np.array([[2.0, 2.0, 0.5, 0.5, 0.0]]), np.ones(1, bool), np.zeros((0, 3)), np.zeros(0, bool),
                      np.array([[0, 0, 10, 0], [10, 0, 10, 8], [10, 8, 0, 8], [0, 8, 0, 0]], float), np.ones(4, bool))
    c = Corridors(ObstacleSet.stack([box]), np.array([[[3.5, 2.0], [3.5, 3.5]]]), np.array([[0.2, 0.2]]))
    h = np.sqrt(0.5)
    dirs = np.array([[[[-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]], [[-h, -h], [0.0, 1.0], [1.0, 0.0]]]])
    np.testing.assert_allclose(c.free(dirs)[0], [[0.8, 1.8, 6.3], [np.sqrt(2.0) - 0.2, 4.3, 6.3]], atol=1e-5)
