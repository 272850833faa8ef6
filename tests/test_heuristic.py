"""The heuristic pursuer team: reactions to crafted observations, and that it beats a random team."""

from __future__ import annotations

import numpy as np
import pytest

from pursuit_mj.config import default_config
from pursuit_mj.evaluation import evaluate
from pursuit_mj.coverage import CoverageParams
from pursuit_mj.heuristic import HeuristicParams, HeuristicTeam
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policy import RandomPolicy

SPEC = ObsSpec.make(3, 1, 16)
RAY_RANGE = 2.0


def blank_obs(n_worlds: int = 1) -> np.ndarray:
    """Observations (W, 3, dim): pursuers far apart at (1, 1), (3, 1), (5, 1), nothing seen, open rays."""
    obs = np.zeros((n_worlds, 3, SPEC.dim), np.float32)
    for i in range(3):
        obs[:, i, SPEC.index("self", 0, "x")] = 1.0 + 2.0 * i
        obs[:, i, SPEC.index("self", 0, "y")] = 1.0
    rays = SPEC.group("rays")
    obs[..., rays.start : rays.stop] = RAY_RANGE
    return obs


def see_evader(obs: np.ndarray, rel: tuple[float, float], vel: tuple[float, float] = (0.0, 0.0), pursuer: int = 0, world: int = 0) -> None:
    for name, value in zip(("dx", "dy", "vx", "vy", "visible"), (*rel, *vel, 1.0)):
        obs[world, pursuer, SPEC.index("evaders", 0, name)] = value


def team() -> HeuristicTeam:
    return HeuristicTeam(pursuer_speed=0.3, ray_range=RAY_RANGE)


def act(t: HeuristicTeam, obs: np.ndarray) -> np.ndarray:
    a = t.act(obs, SPEC)
    assert a.shape == obs.shape[:2] + (2,)
    assert np.all(np.abs(a) <= 1.0 + 1e-9)
    return a


def cos(a: np.ndarray, b) -> float:
    b = np.asarray(b, float)
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_chases_a_visible_evader_at_full_speed():
    t = team()
    t.reset(1)
    obs = blank_obs()
    see_evader(obs, (1.5, 0.5))
    a = act(t, obs)[0, 0]
    assert cos(a, (1.5, 0.5)) > 0.99
    assert np.linalg.norm(a) == pytest.approx(1.0, abs=1e-6)


def test_leads_a_moving_evader():
    still, moving = team(), team()
    still.reset(1)
    moving.reset(1)
    obs = blank_obs()
    see_evader(obs, (1.5, 0.0))
    a_still = act(still, obs)[0, 0]
    see_evader(obs, (1.5, 0.0), vel=(0.0, 0.6))
    a_moving = act(moving, obs)[0, 0]
    assert abs(a_still[1]) < 1e-6
    assert a_moving[1] > 0.3  # aims ahead of the evader, toward where it is going


def test_repels_from_a_close_teammate():
    t = team()
    t.reset(1)
    obs = blank_obs()
    for name, value in zip(("dx", "dy", "visible"), (0.22, 0.0, 1.0)):
        obs[0, 0, SPEC.index("teammates", 0, name)] = value
    see_evader(obs, (0.0, 1.5))  # the target is straight up; the teammate is just to the right
    a = act(t, obs)[0, 0]
    assert a[0] < -0.05  # backs away from the teammate instead of only chasing


def test_turns_away_from_a_close_wall():
    t = team()
    t.reset(1)
    obs = blank_obs()
    rays = SPEC.group("rays")
    obs[0, 0, rays.start + 0] = 0.12  # ray 0 points along +x: a wall 0.12 m ahead
    see_evader(obs, (1.5, 0.0))  # the evader is behind that wall
    a = act(t, obs)[0, 0]
    assert a[0] < 0.0  # never closes in on the wall, even with the target beyond it
    assert np.linalg.norm(a) > 0.2  # but keeps moving (around it)


def test_searches_the_last_known_position_then_forgets_on_reset():
    t = team()
    t.reset(2)
    obs = blank_obs(2)
    for w in range(2):
        see_evader(obs, (1.0, 0.5), world=w)
    act(t, obs)
    gone = blank_obs(2)  # the evader disappears (out of sight); nobody has moved
    a = act(t, gone)
    for w in range(2):
        assert cos(a[w, 0], (1.0, 0.5)) > 0.98
    t.reset(2, np.array([1]))  # a new episode in world 1 only
    b = act(t, gone)
    assert cos(b[0, 0], (1.0, 0.5)) > 0.98  # world 0 remembers
    assert np.isinf(t._mem["age"][1]).all()  # world 1 forgot


def test_sweeps_when_nothing_is_known():
    t = team()
    t.reset(1)
    a = act(t, blank_obs())[0]
    assert np.all(np.linalg.norm(a, axis=-1) > 0.9)  # nobody waits for the evader to show up


def test_worlds_do_not_influence_each_other():
    rng = np.random.default_rng(3)
    obs = blank_obs(3)
    for w in range(3):
        see_evader(obs, tuple(rng.uniform(-1.5, 1.5, 2)), tuple(rng.uniform(-0.6, 0.6, 2)), pursuer=int(rng.integers(3)), world=w)
    batch = team()
    batch.reset(3)
    together = act(batch, obs)
    for w in range(3):
        alone = team()
        alone.reset(1)
        np.testing.assert_allclose(act(alone, obs[w : w + 1])[0], together[w], atol=1e-9)


def test_refuses_bad_observations():
    t = team()
    t.reset(1)
    with pytest.raises(ValueError, match="expected observations"):
        t.act(np.zeros((1, 3, SPEC.dim - 1)), SPEC)
    bad = blank_obs()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        t.act(bad, SPEC)
    with pytest.raises(ValueError, match="reset"):
        t.act(blank_obs(2), SPEC)


def test_beats_a_random_team_on_layout_0():
    config = default_config(fidelity="point", layout=0, max_steps=300)
    kwargs = dict(layouts=[0], episodes=12, seed=11, n_worlds=12)
    heuristic = evaluate(HeuristicTeam.from_config(config), config, **kwargs)[0]
    random = evaluate(RandomPolicy(seed=11), config, **kwargs)[0]
    assert heuristic.episodes == random.episodes == 12
    assert heuristic.success.p >= random.success.p + 0.5
    assert heuristic.success.lo > random.success.hi  # the 95 % intervals do not even overlap
    assert heuristic.collision.count <= 1


def test_a_narrow_view_team_keeps_off_its_teammates_when_they_share_positions():
    # a 57 deg camera: pursuers cross each other's paths out of each other's sight
    config = default_config(fidelity="point", layout=0, max_steps=250, field_of_view=1.0)
    kwargs = dict(layouts=[0], episodes=8, seed=3, n_worlds=8)
    blind = evaluate(HeuristicTeam.from_config(config), config, **kwargs)[0]
    shared_config = default_config(fidelity="point", layout=0, max_steps=250, field_of_view=1.0, share_teammates=True)
    shared = evaluate(HeuristicTeam.from_config(shared_config), shared_config, **kwargs)[0]
    assert blind.collision.count >= 1, "the unshared team collides here (2 of 8 when written): else the test shows nothing"
    assert shared.collision.count == 0


def test_a_team_made_from_a_task_config_by_mistake_says_to_use_from_config():
    from pursuit_mj.config import default_config
    from pursuit_mj.heuristic import HeuristicTeam

    with pytest.raises(TypeError, match=r"got TaskConfig; for a task config use HeuristicTeam.from_config\(config\)"):
        HeuristicTeam(default_config())


def test_the_random_policy_refuses_bad_observations_as_the_others_do():
    """RandomPolicy.act drew actions for observations of any shape, NaN included."""
    policy = RandomPolicy(0)
    with pytest.raises(ValueError, match=r"policy random: expected observations \(worlds, 3, %d\)" % SPEC.dim):
        policy.act(np.zeros((1, 3, SPEC.dim - 1)), SPEC)
    bad = blank_obs()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="policy random: observations contain NaN"):
        policy.act(bad, SPEC)
    assert policy.act(blank_obs(2), SPEC).shape == (2, 3, 2)


@pytest.mark.parametrize("make, message", [
    (lambda: CoverageParams(cell=0.0), r"CoverageParams.cell: expected a number > 0 \(m\), got 0.0"),
    (lambda: CoverageParams(stale_time=float("nan")), "CoverageParams.stale_time"),
    (lambda: CoverageParams(relax_passes=1.5), "CoverageParams.relax_passes: expected an integer >= 0"),
    (lambda: HeuristicParams(lead_gain=float("nan")), "HeuristicParams.lead_gain: expected a number >= 0, got nan"),
    (lambda: HeuristicParams(memory_time=-1.0), "HeuristicParams.memory_time"),
    (lambda: HeuristicParams(encircle_fade=0.0), "HeuristicParams.encircle_fade: expected a number > 0"),
    (lambda: HeuristicParams(coverage={"cell": 0.2}), "HeuristicParams.coverage: expected CoverageParams"),
])
def test_bad_tuning_is_refused_by_name(make, message):
    """A cell of 0 m was a ZeroDivisionError at the first step; a NaN gain went on to act."""
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize("spec, message", [
    (ObsSpec.make(3, 0, 16), r"HeuristicTeam: the observations hold no evaders \(spec n_evaders 0\)"),
    (ObsSpec.make(3, 1, 4), r"HeuristicTeam: the observations hold 4 range readings \(spec n_rays\); .* at least 8"),
])
def test_refuses_a_spec_it_cannot_act_on(spec, message):
    """No evaders was 'attempt to get argmin of an empty sequence'; too few rays went on
    flying blind to walls (from_config refuses such a task, a spec handed to act() was taken)."""
    t = team()
    t.reset(1)
    obs = np.zeros((1, 3, spec.dim))
    with pytest.raises(ValueError, match=message):
        t.act(obs, spec)


@pytest.mark.parametrize("n_worlds", [0, -1, 2.5, "2", True])
@pytest.mark.parametrize("make", [team, lambda: RandomPolicy(0)])
def test_reset_refuses_a_world_count_that_is_no_positive_integer(make, n_worlds):
    """reset(2.5) went on as 2 worlds, reset(0) was taken until the first act()."""
    with pytest.raises(ValueError, match=rf"reset n_worlds: expected an integer >= 1, got {n_worlds!r}"):
        make().reset(n_worlds)


@pytest.mark.parametrize("name", ["heuristic", "random"])
@pytest.mark.parametrize("config, seed, message", [
    (None, 0, "make_policy: config: expected a TaskConfig, got NoneType"),
    ({"n_rays": 16}, 0, "make_policy: config: expected a TaskConfig, got dict"),
    (default_config(), "a", "make_policy: seed: expected an integer, got 'a'"),
    (default_config(), 1.5, "make_policy: seed: expected an integer, got 1.5"),
])
def test_make_policy_refuses_a_config_or_seed_of_the_wrong_kind(name, config, seed, message):
    """None was "'NoneType' object has no attribute 'n_rays'"; seed 'a' numpy's "invalid literal for int()"."""
    from pursuit_mj.policies import make_policy

    with pytest.raises(ValueError, match=message):
        make_policy(name, config, seed)


@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_the_tie_breaking_side_lets_the_lower_index_of_each_pair_yield(n):
    """tie_side[i, k] is +1 where teammate slot k of pursuer i holds a lower-indexed pursuer
    (slots list the others in index order, skipping i), -1 where it holds a higher one."""
    from pursuit_mj.heuristic import _parse

    spec = ObsSpec.make(n, 1, 8)
    tie = _parse(np.zeros((1, n, spec.dim), np.float32), spec)["tie_side"]
    assert tie.shape == (n, n - 1)
    for i in range(n):
        others = [j for j in range(n) if j != i]
        assert tie[i].tolist() == [1.0 if j < i else -1.0 for j in others]


# A 50 x 50 m arena (the largest a layout may have): the coverage map grows over many cells.
BIG_ARENA = """name: big
arena: {width: 50.0, height: 50.0}
boundary: rectangle
obstacles:
  - wall: {from: [0.0, 4.0], to: [6.0, 4.0], thickness: 0.1}
random_obstacles: {count: 12, kinds: [box, cylinder], size: [0.2, 1.0]}
spawn:
  pursuers: {x: [1.0, 6.0], y: [1.0, 3.0]}
  evaders: {x: [30.0, 48.0], y: [30.0, 48.0]}
"""


def _play_and_hash(config, n_worlds: int, steps: int, reset_at: int, params: HeuristicParams | None = None) -> str:
    """sha256 of the team's actions every step and of its coverage map (free, blocked, seen, dist,
    goal, waited) every 5th step, over `steps` steps of `n_worlds` worlds; world 1 is reset at
    step `reset_at` (its episode restarts, the team forgets it); ended episodes restart."""
    import hashlib

    from pursuit_mj.env import PursuitEnv

    env = PursuitEnv(config, n_worlds=n_worlds, seed=3)
    t = HeuristicTeam.from_config(config, params)
    t.reset(n_worlds)
    obs = env.reset()
    h = hashlib.sha256()
    for k in range(steps):
        a = t.act(obs, env.obs_spec)
        h.update(np.ascontiguousarray(a).tobytes())
        if k % 5 == 0:
            m = t._mem["map"]
            for arr in (m.free, m.blocked, m.seen, m.dist, m.goal, m.waited):
                h.update(repr(arr.shape).encode() + np.ascontiguousarray(arr).tobytes())
        obs, _, term, trunc, _ = env.step(a)
        ids = np.flatnonzero(term | trunc)
        if k == reset_at:
            ids = np.union1d(ids, [1])
        if ids.size:
            obs = env.reset_worlds(ids)
            t.reset(n_worlds, ids)
    return h.hexdigest()


@pytest.mark.parametrize("case, expected", [
    ("layout0-3p", "466fdb4034eecb9aed9f9d595a7a8da79becb41b6e7e62e13b262ed5b76c1ab8"),
    ("hard-layout3-2p", "cbb43396df4a2a65c12c9262891dba2ecaa6448008179d5d230fb1f440633458"),
    ("big-3p", "f61ecaa8926666ed616ec676073d48bc4ad0caa3d3f63fcf54fbc9f7217425ac"),
    ("big-1p", "d00a3e4836988ea6ddef04b6c6dbcbc377d51e9ea33c414ed133ee4b93709f4e"),
    ("big-2p-impatient", "8f484d130f73a5ab9630a23ab56ff665f1bff774bd7482c72e46110a5e41e7d2"),
])
def test_the_coverage_map_and_the_actions_stay_the_same_to_the_bit(case, expected, tmp_path):
    """Pins the team's play (actions and coverage map, hashed) on small and large arenas, one to
    three pursuers, several worlds: a faster coverage map must give the same bits."""
    if case == "layout0-3p":
        config, worlds, steps = default_config(fidelity="point", layout=0), 4, 160
    elif case == "hard-layout3-2p":
        from pursuit_mj.config import load_task_config

        config, worlds, steps = load_task_config(["hard"], ["fidelity=point", "layout=3", "n_pursuers=2"]), 3, 160
    else:
        path = tmp_path / "big.yaml"
        path.write_text(BIG_ARENA)
        n = {"big-3p": 3, "big-1p": 1, "big-2p-impatient": 2}[case]
        config, worlds, steps = default_config(fidelity="point", layout=str(path), n_pursuers=n), 3, 250
    # one pass a step and little patience: goals are given up (their surroundings marked seen)
    params = HeuristicParams(coverage=CoverageParams(relax_passes=1, patience=0.5)) if "impatient" in case else None
    assert _play_and_hash(config, worlds, steps, reset_at=steps // 2, params=params) == expected


def _dense_goal(m, pos, mate_pos, mate_vis, now):
    """The sweep goal (W, N, 2) as scored over every cell of the grid (the rule of
    CoverageMap.choose_goal, written densely): the reference for the map's boxed scoring."""
    p, c = m.p, m.p.cell
    dx = (np.arange(m.GX) + 0.5) * c
    dy = (np.arange(m.GY) + 0.5) * c

    def dist2(xy):
        return (dx - xy[..., 0, None])[..., :, None] ** 2 + (dy - xy[..., 1, None])[..., None, :] ** 2

    stale = np.clip((now[:, None, None, None] - m.seen) / p.stale_time, 0.0, 1.0)
    score = stale - np.sqrt(dist2(pos)) / p.distance_scale
    score -= p.mate_penalty * ((dist2(mate_pos) < (2 * p.mate_radius) ** 2) & mate_vis[..., None, None]).any(2)
    has = m.goal[..., 0] >= 0
    w, n = np.arange(m.W)[:, None], np.arange(m.N)[None, :]
    score[w, n, np.maximum(m.goal[..., 0], 0), np.maximum(m.goal[..., 1], 0)] += p.keep_bonus * has
    best = np.argmax(np.where(m.free & ~m.blocked, score, -np.inf).reshape(m.W, m.N, -1), -1)
    return np.stack([best // m.GY, best % m.GY], -1)


def _dense_relax(m):
    """The path lengths (W, N, GX, GY) after relaxing every cell of the grid `relax_passes` times
    (the rule of CoverageMap._relax, written densely): the reference for the map's front."""
    pad = np.pad(m.blocked, ((0, 0), (0, 0), (1, 1), (1, 1)))
    near = np.zeros_like(m.blocked)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            near |= pad[:, :, 1 + di : 1 + di + m.GX, 1 + dj : 1 + dj + m.GY]
    cost = (1.0 + m.p.wall_cost * near).astype(np.float32)
    d = m.dist.copy()
    for _ in range(m.p.relax_passes):
        pad = np.pad(d, ((0, 0), (0, 0), (1, 1), (1, 1)), constant_values=np.inf)
        best = d
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            best = np.minimum(best, pad[:, :, 1 + di : 1 + di + m.GX, 1 + dj : 1 + dj + m.GY] + cost)
        d = np.where(m.free & ~m.blocked, best, d)
    return d


def test_the_coverage_map_scores_and_relaxes_few_cells_yet_as_if_it_did_every_one():
    """The map scores goals inside the box of free cells, marks teammates' surroundings from a
    window around them and relaxes only the wavefront's front; under random readings, jumps onto
    blocked cells (which clears them), goal changes, world resets and growth of the grid, goals
    and path lengths are those of the whole-grid rules, to the bit."""
    from pursuit_mj.coverage import CoverageMap

    rng = np.random.default_rng(0)
    W, N, K = 3, 2, 16
    m = CoverageMap(W, N, CoverageParams(relax_passes=2, patience=0.3))
    angles = 2 * np.pi * np.arange(K) / K
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    pos = rng.uniform(0.5, 2.0, (W, N, 2))
    jumps = 0
    for step in range(120):
        now = np.full(W, 0.1 * step)
        free_and_blocked = np.argwhere(m.free & m.blocked)
        if step % 3 == 2 and len(free_and_blocked):  # onto a cell once found free, later blocked: it is cleared
            w, n, i, j = free_and_blocked[rng.integers(len(free_and_blocked))]
            pos[w, n] = (np.array([i, j]) + 0.5) * m.p.cell
            jumps += 1
        else:
            pos = np.clip(pos + rng.normal(0, 0.15 + step / 300, pos.shape), 0.0, 8.0)
        rays = np.where(rng.random((W, N, K)) < 0.9, RAY_RANGE, rng.uniform(0.05, RAY_RANGE, (W, N, K)))
        mate_pos = pos[:, ::-1][:, :, None] + rng.normal(0, 0.05, (W, N, 1, 2))
        mate_vis = rng.random((W, N, 1)) < 0.7
        m.update(pos, rays, dirs, RAY_RANGE, mate_pos, mate_vis, now, 1.2)
        expected_goal = _dense_goal(m, pos, mate_pos, mate_vis, now)
        m.choose_goal(pos, mate_pos, mate_vis, now, 0.1)
        assert np.array_equal(m.goal, expected_goal), step
        expected_dist = _dense_relax(m)
        m.waypoint(pos, now)
        assert np.array_equal(m.dist, expected_dist), step
        if step % 50 == 25:
            m.reset(np.array([1]))
    assert m.GX > 30 and m.GY > 30 and jumps >= 20


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast:RuntimeWarning")  # NaN readings, on purpose
def test_the_coverage_map_keeps_the_wall_cost_of_cells_it_grows_beside_a_blocked_edge_cell():
    """A reading that is not a number keeps the grid from growing that step, so hits beyond the
    grid are clipped onto its last row and column; when the grid grows later, the cells beyond
    them lie beside blocked cells and cost as much to cross as the whole-grid rule says."""
    from pursuit_mj.coverage import CoverageMap

    rng = np.random.default_rng(1)
    K = 16
    m = CoverageMap(1, 1, CoverageParams(relax_passes=2))
    angles = 2 * np.pi * np.arange(K) / K
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    none = np.zeros((1, 1, 0, 2)), np.zeros((1, 1, 0), bool)
    pos = np.array([[[1.3, 1.3]]])
    rays = np.full((1, 1, K), 1.0)  # walls all round at 1 m: beyond the 1.6 m grid to the east and north
    rays[0, 0, 5] = np.nan
    m.update(pos, rays, dirs, 3.0, *none, np.zeros(1), 1.2)
    assert m.GX == 8 and m.blocked[0, 0, 7].any() and m.blocked[0, 0, :, 7].any()  # clipped onto the edges
    for step in range(1, 40):
        pos = np.clip(pos + rng.normal(0, 0.2, pos.shape), 0.0, 3.0)
        now = np.full(1, 0.1 * step)
        rays = np.where(rng.random((1, 1, K)) < 0.5, 3.0, rng.uniform(0.3, 3.0, (1, 1, K)))
        m.update(pos, rays, dirs, 3.0, *none, now, 1.2)
        m.choose_goal(pos, *none, now, 0.1)
        expected_dist = _dense_relax(m)
        m.waypoint(pos, now)
        assert np.array_equal(m.dist, expected_dist), step


def test_a_coverage_map_that_never_relaxes_keeps_no_growing_wavefront():
    """relax_passes=0 (valid: path lengths never spread from the goal) reads no front, so none is kept: the
    cells each step puts on it do not pile up step after step (memory and time would grow
    with the episode's length)."""
    from pursuit_mj.coverage import CoverageMap

    rng = np.random.default_rng(0)
    W, N, K = 2, 2, 16
    m = CoverageMap(W, N, CoverageParams(relax_passes=0))
    angles = 2 * np.pi * np.arange(K) / K
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    none = np.zeros((W, N, 0, 2)), np.zeros((W, N, 0), bool)
    pos = rng.uniform(1.0, 3.0, (W, N, 2))
    for step in range(60):
        now = np.full(W, 0.1 * step)
        pos = np.clip(pos + rng.normal(0, 0.2, pos.shape), 0.0, 8.0)
        rays = np.where(rng.random((W, N, K)) < 0.7, RAY_RANGE, rng.uniform(0.2, RAY_RANGE, (W, N, K)))
        m.update(pos, rays, dirs, RAY_RANGE, *none, now, 1.2)
        m.choose_goal(pos, *none, now, 0.1)
        m.waypoint(pos, now)
    assert m._front.size == 0


def test_under_full_observability_the_team_acts_alike_whatever_the_perception_settings():
    """With observability full every entity is known exactly, so the perception keys change no
    observation (sensing.perceive). They must not change the team either: its shield was built with
    the task's position_noise (shortening teammates' gaps by noise the observations do not have),
    and its coverage search with perception_radius, so `eval --observability full --task hard`
    played other episodes than `eval --observability full` on identical observations."""
    from pursuit_mj.env import PursuitEnv

    plain = default_config(fidelity="point", observability="full", max_steps=300)
    noisy = default_config(fidelity="point", observability="full", max_steps=300, position_noise=0.3,
                           field_of_view=1.5, perception_radius=0.8, miss_probability=0.5)
    envs = [PursuitEnv(c, n_worlds=4, seed=0, auto_reset=False) for c in (plain, noisy)]
    teams = [HeuristicTeam.from_config(c) for c in (plain, noisy)]
    obs = [env.reset() for env in envs]
    np.testing.assert_array_equal(obs[0], obs[1])
    for t in teams:
        t.reset(4)
    spec = envs[0].obs_spec
    for _ in range(300):
        actions = [t.act(o, spec) for t, o in zip(teams, obs)]
        np.testing.assert_array_equal(actions[0], actions[1])
        obs = [env.step(a)[0] for env, a in zip(envs, actions)]
        np.testing.assert_array_equal(obs[0], obs[1])


def test_make_policy_from_python_names_its_argument_and_the_cli_its_flag(capsys):
    """make_policy's errors named `--policy` by default, a flag a Python caller never typed: an
    unknown name from Python said "--policy 'heuristc'". From Python they name the argument;
    eval still names its flag."""
    from pursuit_cli import main
    from pursuit_mj.policies import make_policy

    with pytest.raises(ValueError, match=r"^make_policy name 'heuristc': unknown policy \(valid: heuristic, random"):
        make_policy("heuristc", default_config())
    assert main(["eval", "--policy", "heuristc", "--layouts", "0", "--episodes", "1"]) == 2
    assert "error: --policy 'heuristc': unknown policy" in capsys.readouterr().err
