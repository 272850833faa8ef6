"""Perception: range, field of view, line of sight, relayed detections, noise; the index map."""

import math

import numpy as np
import pytest

from pursuit_mj.config import default_config
from pursuit_mj.geometry import ObstacleSet
from pursuit_mj.layout import layout_from_dict
from pursuit_mj.observations import build_observations
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.randomness import WorldRandom, world_keys
from pursuit_mj.sensing import WorldView, perceive


def _layout(obstacles=()):
    return layout_from_dict(
        {
            "arena": {"width": 4.0, "height": 4.0},
            "obstacles": list(obstacles),
            "random_obstacles": {"count": 0},
            "spawn": {"pursuers": {"x": [0.2, 3.8], "y": [0.2, 0.6]}, "evaders": {"x": [0.2, 3.8], "y": [3.4, 3.8]}},
        },
        "test-layout",
    )


WALL = {"wall": {"from": [1.0, 2.0], "to": [3.0, 2.0], "thickness": 0.05}}


def _view(pursuers, evaders, obstacles, heading=None, captured=None):
    p = np.array(pursuers, float)[None]
    e = np.array(evaders, float)[None]
    N, M = p.shape[1], e.shape[1]
    return WorldView(
        pursuer_pos=p,
        pursuer_vel=np.zeros_like(p),
        pursuer_heading=np.full((1, N), math.pi / 2) if heading is None else np.array(heading, float)[None],
        evader_pos=e,
        evader_vel=np.zeros_like(e),
        captured=np.zeros((1, M), bool) if captured is None else np.array(captured)[None],
        obstacles=ObstacleSet.stack([obstacles]),
    )


def _perceive(view, **changes):
    return perceive(view, default_config(random_obstacles=0, **changes), np.random.default_rng(0))


def test_evader_behind_wall_is_masked_and_in_open_is_seen():
    obstacles = _layout([WALL]).obstacle_set()
    view = _view([[2.0, 1.5], [0.3, 2.4]], [[2.0, 2.6]], obstacles)
    per = _perceive(view, share_detections=False)
    assert not per.seen[0, 0, 0], "the wall between them must hide the evader"
    assert per.seen[0, 1, 0], "a clear line at 1.5 m within the 2 m radius must see it"


def test_out_of_range_is_masked():
    view = _view([[0.5, 0.5]], [[0.5, 2.6]], _layout().obstacle_set())
    assert not _perceive(view, perception_radius=2.0).seen[0, 0, 0]
    assert _perceive(view, perception_radius=2.2).seen[0, 0, 0]


def test_field_of_view_masks_entities_behind_the_pursuer():
    view = _view([[2.0, 2.0], [1.0, 2.0]], [[3.0, 2.0]], _layout().obstacle_set(), heading=[0.0, math.pi])
    per = _perceive(view, field_of_view=math.pi / 2, share_detections=False)
    assert per.seen[0, 0, 0], "target straight ahead"
    assert not per.seen[0, 1, 0], "target straight behind"
    assert per.teammate_visible[0, 1, 0] is np.False_ or not per.teammate_visible[0, 1, 0]
    assert not per.teammate_visible[0, 0, 1], "teammate behind pursuer 0"


@pytest.mark.parametrize("fov, seen_deg, unseen_deg", [(math.pi / 2, 40, 50), (1.2 * math.pi, 100, 115)])
def test_the_field_of_view_is_centred_on_the_heading_and_half_of_it_each_side(fov, seen_deg, unseen_deg):
    """A 90 deg view sees 40 deg off the heading and not 50; a 216 deg view (over pi, still masked) sees 100 and not 115."""
    offsets = [seen_deg, -seen_deg, unseen_deg, -unseen_deg]
    heading = 0.3
    evaders = [[2.0 + math.cos(heading + math.radians(a)), 2.0 + math.sin(heading + math.radians(a))] for a in offsets]
    view = _view([[2.0, 2.0]], evaders, _layout().obstacle_set(), heading=[heading])
    per = _perceive(view, field_of_view=fov, share_detections=False)
    assert per.seen[0, 0].tolist() == [True, True, False, False]


@pytest.mark.parametrize("heading", [math.pi - 0.01, -math.pi + 0.01])
def test_a_pursuer_heading_near_pi_sees_across_the_seam_of_the_angle(heading):
    """Angles wrap at +-pi: a target 0.1 rad off the heading on the far side of the seam is in a 1 rad view."""
    target_angle = heading + (0.1 if heading > 0 else -0.1)  # just past +-pi
    view = _view([[2.0, 2.0]], [[2.0 + math.cos(target_angle), 2.0 + math.sin(target_angle)]], _layout().obstacle_set(),
                 heading=[heading])
    assert _perceive(view, field_of_view=1.0, share_detections=False).seen[0, 0, 0]


def test_a_hidden_teammate_leaves_every_feature_of_its_slot_zero():
    """The flat mlp network reads every slot: a hidden teammate's position must not leak into it."""
    view = _view([[2.0, 2.0], [1.0, 2.0]], [[3.0, 2.0]], _layout().obstacle_set(), heading=[0.0, math.pi])
    config = default_config(random_obstacles=0, field_of_view=math.pi / 2, share_detections=False, share_teammates=False)
    per = perceive(view, config, np.random.default_rng(0))
    assert not per.teammate_visible[0, 0, 1]  # pursuer 1 is behind pursuer 0
    obs = build_observations(view, per, ObsSpec.make(2, 1, config.n_rays))
    mates = ObsSpec.make(2, 1, config.n_rays).group("teammates").view(obs)
    assert (mates[0, 0] == 0).all()


def test_relayed_detection_is_known_to_all_and_flagged():
    obstacles = _layout([WALL]).obstacle_set()
    view = _view([[2.0, 1.5], [0.3, 2.4]], [[2.0, 2.6]], obstacles)
    spec = ObsSpec.make(2, 1, 16)
    per = _perceive(view, share_detections=True)
    assert per.known[0, 0, 0] and not per.seen[0, 0, 0]
    obs = build_observations(view, per, spec)
    assert obs[0, 0, spec.index("evaders", 0, "visible")] == 1
    assert obs[0, 0, spec.index("evaders", 0, "relayed")] == 1
    assert obs[0, 1, spec.index("evaders", 0, "relayed")] == 0
    off = _perceive(view, share_detections=False)
    obs_off = build_observations(view, off, spec)
    assert obs_off[0, 0, spec.index("evaders", 0, "visible")] == 0
    assert np.all(spec.group("evaders").view(obs_off)[0, 0, 0] == 0), "a hidden evader's values are all zero"


def test_shared_teammates_are_known_exactly_through_walls_and_out_of_view():
    obstacles = _layout([WALL]).obstacle_set()
    # pursuer 1 is behind the wall from pursuer 0, pursuer 2 behind it (heading +y) and 3.5 m away
    view = _view([[2.0, 2.5], [2.0, 1.5], [0.3, 0.3]], [[3.5, 3.5]], obstacles)
    alone = _perceive(view, field_of_view=1.0, position_noise=0.1)
    assert not alone.teammate_visible[0, 0, 1] and not alone.teammate_visible[0, 0, 2]
    shared = _perceive(view, field_of_view=1.0, position_noise=0.1, share_teammates=True)
    assert shared.teammate_visible[0] == pytest.approx(~np.eye(3, dtype=bool))
    assert np.array_equal(shared.teammate_pos_est[0, 0], view.pursuer_pos[0]), "broadcast positions carry no noise"
    assert np.array_equal(shared.evader_pos_est, alone.evader_pos_est), "evaders are perceived as without sharing"
    assert np.array_equal(shared.seen, alone.seen)


def test_full_observability_masks_nothing():
    obstacles = _layout([WALL]).obstacle_set()
    view = _view([[2.0, 1.5], [0.5, 0.3]], [[2.0, 3.8]], obstacles)
    per = _perceive(view, observability="full")
    assert per.known.all() and per.teammate_visible[0, 0, 1] and per.teammate_visible[0, 1, 0]


def test_full_observability_ignores_position_noise_and_misses():
    """docs/DESIGN.md section 5: with observability full, miss_probability and position_noise have
    no effect (noise used to be added to every position, the evaders' and the teammates')."""
    view = _view([[2.0, 1.5], [0.5, 0.3]], [[2.0, 3.8]], _layout([WALL]).obstacle_set())
    per = _perceive(view, observability="full", position_noise=0.2, miss_probability=1.0)
    assert per.known.all() and per.seen.all()
    np.testing.assert_array_equal(per.evader_pos_est[0], np.broadcast_to(view.evader_pos[0], (2, 1, 2)))
    np.testing.assert_array_equal(per.teammate_pos_est[0], np.broadcast_to(view.pursuer_pos[0], (2, 2, 2)))


def test_observation_index_map_matches_the_vector():
    view = _view([[1.0, 1.0], [2.0, 1.5], [3.0, 1.0]], [[1.5, 2.0]], _layout().obstacle_set())
    view.pursuer_vel[0, 0] = [0.1, -0.2]
    view.evader_vel[0, 0] = [0.5, 0.3]
    spec = ObsSpec.make(3, 1, 8)
    obs = build_observations(view, _perceive(view, n_rays=8), spec)
    assert obs.shape == (1, 3, spec.dim) and spec.dim == 4 + 2 * 5 + 7 + 8
    o = obs[0, 0]
    assert (o[spec.index("self", 0, "x")], o[spec.index("self", 0, "y")]) == (1.0, 1.0)
    assert o[spec.index("self", 0, "vy")] == pytest.approx(-0.2)
    assert o[spec.index("teammates", 0, "dx")] == pytest.approx(1.0)  # pursuer 1 seen from 0
    assert o[spec.index("teammates", 1, "dx")] == pytest.approx(2.0)  # pursuer 2
    assert o[spec.index("teammates", 0, "dvx")] == pytest.approx(-0.1)
    assert o[spec.index("evaders", 0, "dx")] == pytest.approx(0.5)
    assert o[spec.index("evaders", 0, "dy")] == pytest.approx(1.0)
    assert o[spec.index("evaders", 0, "vx")] == pytest.approx(0.5)
    # ray 0 points along +x from (1, 1): the border at x = 4 is 3 m away, capped at ray_range 2
    assert o[spec.index("rays", 0, "range_0")] == pytest.approx(2.0)
    # ray 4 of 8 points along -x: the border at x = 0 is 1 m away
    assert o[spec.index("rays", 0, "range_4")] == pytest.approx(1.0)


def test_noise_and_missed_detections_are_seeded():
    view = _view([[1.0, 1.0]], [[1.5, 2.0]], _layout().obstacle_set())
    a = perceive(view, default_config(position_noise=0.05), np.random.default_rng(3))
    b = perceive(view, default_config(position_noise=0.05), np.random.default_rng(3))
    assert np.array_equal(a.evader_pos_est, b.evader_pos_est)
    assert not np.allclose(a.evader_pos_est[0, 0, 0], [1.5, 2.0])
    assert np.abs(a.evader_pos_est[0, 0, 0] - [1.5, 2.0]).max() < 0.3
    missed = perceive(view, default_config(miss_probability=1.0), np.random.default_rng(0))
    assert not missed.seen.any()


def test_world_random_draws_depend_on_their_own_world_only():
    keys, ticks = world_keys(np.array([5, 6, 7])), np.array([0, 3, 9])
    three = WorldRandom(keys, ticks)
    a, b = three.random((3, 2, 4)), three.normal(0.0, 0.05, (3, 2, 4, 2))
    one = WorldRandom(keys[1:2], ticks[1:2])
    assert np.array_equal(one.random((1, 2, 4))[0], a[1]) and np.array_equal(one.normal(0.0, 0.05, (1, 2, 4, 2))[0], b[1])
    assert not np.array_equal(a[0], a[1])  # other seeds, other numbers
    assert not np.array_equal(WorldRandom(keys, ticks + 1).random((3, 2, 4)), a)  # next step, new numbers
    u = WorldRandom(world_keys(np.arange(200)), np.zeros(200, int)).random((200, 50))
    z = WorldRandom(world_keys(np.arange(200)), np.zeros(200, int)).normal(0.0, 1.0, (200, 50))
    assert 0.0 <= u.min() and u.max() < 1.0 and abs(u.mean() - 0.5) < 0.01
    assert abs(z.mean()) < 0.02 and abs(z.std() - 1.0) < 0.02
    with pytest.raises(ValueError, match="number of worlds"):
        three.random((2, 4))


@pytest.mark.parametrize("draw", [lambda r: r.normal(0.0, 1.0), lambda r: r.random(None), lambda r: r.random(3.0),
                                  lambda r: r.random((3, -2)), lambda r: r.normal(0.0, 1.0, (3, 2.5))])
def test_world_random_refuses_a_size_that_is_no_shape_naming_it(draw):
    """A size left out (numpy's one number), a float or a negative extent failed inside with
    "'NoneType' object is not iterable" or gave an empty array as if asked for none."""
    three = WorldRandom(world_keys(np.array([5, 6, 7])), np.array([0, 3, 9]))
    with pytest.raises(ValueError, match=r"WorldRandom: size .* expected a shape \(3, ...\) of non-negative integers"):
        draw(three)


def test_a_stored_spec_whose_features_are_renamed_or_reordered_is_not_compatible():
    """Checkpoints store their spec: the same groups and widths with other features must be refused."""
    spec = ObsSpec.make(3, 1, 16)
    assert spec.compatible(spec.to_dict()) is None
    assert spec.compatible(ObsSpec.make(5, 2, 16).to_dict()) is None  # other team sizes: pooled encoders take them
    for change in (lambda f: f[:1] + ["speed"] + f[2:], lambda f: [f[1], f[0]] + f[2:]):
        stored = spec.to_dict()
        group = next(g for g in stored["groups"] if g[0] == "evaders")
        group[2] = change(list(group[2]))
        assert "observation features differ" in spec.compatible(stored)


def test_an_unknown_feature_name_is_refused_naming_it_and_the_group_s_features():
    """spec.index('evaders', 0, 'visble') said only 'tuple.index(x): x not in tuple'."""
    spec = ObsSpec.make(3, 1, 8)
    with pytest.raises(ValueError, match=r"'evaders'.*'visble'.*dx, dy, vx, vy, visible, relayed, captured"):
        spec.index("evaders", 0, "visble")
    with pytest.raises(ValueError, match=r"'rays'.*'range_8'.*range_0 .. range_7"):
        spec.index("rays", 0, "range_8")


def test_a_caught_evader_is_known_where_it_stopped_without_fresh_noise():
    """A caught evader stands still and its capture was reported, so every pursuer knows its true
    position. Fresh position noise each step made a standing drone jitter by position_noise (and
    the shield's cap toward it had no margin for that); a free evader keeps its noise."""
    view = _view([[1.0, 1.0], [3.0, 1.0]], [[1.5, 2.0], [2.5, 2.0]], _layout().obstacle_set(), captured=[True, False])
    config = default_config(random_obstacles=0, position_noise=0.1, n_evaders=2)
    a = perceive(view, config, np.random.default_rng(0))
    b = perceive(view, config, np.random.default_rng(1))
    for per in (a, b):
        np.testing.assert_array_equal(per.evader_pos_est[0, :, 0], [[1.5, 2.0], [1.5, 2.0]])
        assert per.known[0, :, 0].all()
    assert not np.allclose(a.evader_pos_est[0, :, 1], b.evader_pos_est[0, :, 1])  # the free one: noisy


@pytest.mark.parametrize("share_teammates, rays", [(False, 3 * (1 + 2)), (True, 3 * 1)])
def test_lines_of_sight_are_cast_only_for_the_pairs_that_need_one(monkeypatch, share_teammates, rays):
    # a ray from every pursuer to itself (N of them), and with share_teammates to every teammate,
    # whose broadcast makes it known anyway, was cast too: N (M + N) rays where N (M + N - 1) or N M do
    import pursuit_mj.geometry as geometry

    obstacles = _layout([WALL]).obstacle_set()
    view = _view([[2.0, 1.5], [0.3, 2.4], [3.5, 1.0]], [[2.0, 2.6]], obstacles)
    want = _perceive(view, share_teammates=share_teammates)
    cast = []
    real_cast = geometry.cast_rays
    monkeypatch.setattr(geometry, "cast_rays", lambda origins, dirs, obs: cast.append(origins.shape[1]) or real_cast(origins, dirs, obs))
    got = _perceive(view, share_teammates=share_teammates)
    assert cast == [rays]
    for field in ("seen", "known", "teammate_visible", "evader_pos_est", "teammate_pos_est", "rays"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=field)
    assert not got.teammate_visible[0].diagonal().any()
    # without sharing only pursuers 0 and 2 see each other: the wall hides 1 from 0, and 1 and 2 are 3.4 m apart
    assert got.teammate_visible[0].sum() == (6 if share_teammates else 2)


# ----------------------------------------------------------------------------- mutation audit


def test_a_teammate_s_view_is_its_own_one_sees_the_back_of_the_other():
    # pursuers 0 and 1 both face +x, 1 m apart on one line: 0 sees 1 ahead, 1 has 0 behind it
    view = _view([[1.0, 2.0], [2.0, 2.0], [3.0, 3.5]], [[3.5, 0.5]], _layout().obstacle_set(), heading=[0.0, 0.0, math.pi / 2])
    per = _perceive(view, field_of_view=math.pi / 2)
    assert per.teammate_visible[0, 0, 1] and not per.teammate_visible[0, 1, 0]
    assert not per.teammate_visible[0, 0, 2] and not per.teammate_visible[0, 2, 0]  # 2 faces north: neither sees the other


def test_a_caught_evader_in_plain_view_is_known_but_not_a_fresh_sighting():
    view = _view([[1.0, 1.0]], [[1.0, 1.5], [1.5, 1.0]], _layout().obstacle_set(), captured=[True, False])
    per = _perceive(view, n_evaders=2)
    assert per.known[0, 0].tolist() == [True, True]
    assert per.seen[0, 0].tolist() == [False, True]  # what the render draws as a sighting and custom rewards read


def test_a_slow_pursuer_faces_where_it_flies():
    from pursuit_mj.sensing import heading_min_speed, update_heading

    assert heading_min_speed(0.3) == 0.05
    slow = 0.04  # m/s, its top speed: flying at it must turn its heading, or it faces its start heading for good
    turned = update_heading(np.array([0.0]), np.array([[0.0, slow]]), heading_min_speed(slow))
    assert turned[0] == pytest.approx(math.pi / 2)


def test_the_group_tables_of_obs_spec_docstring_are_the_specs_groups():
    """The documented index map (pursuit_mj/obs_spec.py's tables, which docs/env_api.md and the
    policy contract point to) lists each group's name, count, width and features in order as
    ObsSpec lays them out, belief groups included: a feature added or moved in the code alone fails."""
    import re

    import pursuit_mj.obs_spec as obs_spec_module

    rows, current = [], None
    for line in obs_spec_module.__doc__.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if not cells or (cells[0] and set(cells[0]) <= {"-"}) or cells[0] == "group":
            continue
        if cells[0]:
            current = [cells[0].strip("`"), cells[1], cells[2], cells[3]]
            rows.append(current)
        else:
            current[3] += " " + cells[3]
    n, m, k = 4, 2, 16
    spec = obs_spec_module.ObsSpec.make(n, m, k, belief=True)
    assert [r[0] for r in rows] == [g.name for g in spec.groups]
    counts = {"1": 1, "N - 1": n - 1, "M": m}
    for (name, count, width, features), group in zip(rows, spec.groups):
        assert counts[count] == group.count, name
        assert (k if width == "K" else int(width)) == group.width, name
        if name == "rays":
            assert group.features == tuple(f"range_{i}" for i in range(k))
            continue
        bare = re.sub(r":[^,]*", "", re.sub(r"\([^)]*\)", "", features))  # units (...) and remarks (: ...) left out
        assert [w.strip() for w in bare.split(",")] == list(group.features), (name, bare)


def test_an_entity_a_group_lacks_is_an_index_error_not_a_slot_of_the_next_group():
    """spec.index counts entities from 0 to count - 1: evader 1 of one evader, or teammate -1,
    would be a slot of another group."""
    spec = ObsSpec.make(3, 1, 8)
    assert spec.index("evaders", 0, "dx") == 4 + 2 * 5  # after self (4) and two teammates (5 each)
    assert spec.index("teammates", 1, "visible") == 4 + 5 + 4
    for group, entity, count in (("evaders", 1, 1), ("teammates", 2, 2), ("teammates", -1, 2), ("self", 1, 1)):
        with pytest.raises(IndexError, match=rf"group '{group}' has {count} entities, asked for {entity}"):
            spec.index(group, entity, "dx" if group != "self" else "x")


def test_a_hidden_moving_teammate_leaves_every_feature_of_its_slot_zero():
    """Its relative velocity too, not only its position: both drones flying, the teammate behind."""
    view = _view([[2.0, 2.0], [1.0, 2.0]], [[3.0, 2.0]], _layout().obstacle_set(), heading=[0.0, 0.0])
    view.pursuer_vel[0] = [[0.3, 0.1], [-0.4, 0.2]]
    config = default_config(random_obstacles=0, field_of_view=math.pi / 2, share_detections=False, share_teammates=False)
    per = perceive(view, config, np.random.default_rng(0))
    assert not per.teammate_visible[0, 0, 1] and per.teammate_visible[0, 1, 0]  # 1 sees 0 ahead of it
    spec = ObsSpec.make(2, 1, config.n_rays)
    mates = spec.group("teammates").view(build_observations(view, per, spec))
    assert (mates[0, 0] == 0).all()
    np.testing.assert_allclose(mates[0, 1, 0], [1.0, 0.0, 0.7, -0.1, 1.0], atol=1e-6)  # the seen one: every feature


def test_a_caught_evader_reads_where_it_stopped_with_no_velocity_and_is_no_relayed_detection():
    """The evaders group of a caught evader: position (relative), velocity 0 even while its drone
    still drifts (a quadrotor settling, a real drone after its capture), visible 1, relayed 0,
    captured 1; a free evader beside it keeps its velocity."""
    view = _view([[1.0, 1.0], [3.0, 1.0]], [[1.0, 1.5], [3.0, 1.5]], _layout().obstacle_set(), captured=[True, False])
    view.evader_vel[0] = [[0.05, -0.02], [0.4, 0.1]]
    per = _perceive(view, n_evaders=2, share_detections=True)
    assert per.known[0].all() and per.seen[0].tolist() == [[False, False], [False, True]]  # pursuer 0 sees neither afresh
    spec = ObsSpec.make(2, 2, default_config().n_rays)
    ev = spec.group("evaders").view(build_observations(view, per, spec))
    np.testing.assert_allclose(ev[0, 0, 0], [0.0, 0.5, 0.0, 0.0, 1.0, 0.0, 1.0], atol=1e-6)  # caught, its own catcher
    np.testing.assert_allclose(ev[0, 1, 0], [-2.0, 0.5, 0.0, 0.0, 1.0, 0.0, 1.0], atol=1e-6)  # caught, far off
    np.testing.assert_allclose(ev[0, 0, 1], [2.0, 0.5, 0.4, 0.1, 1.0, 1.0, 0.0], atol=1e-6)  # free, relayed by pursuer 1


def test_a_skipped_draw_leaves_the_next_draws_as_a_made_one_does():
    # perception only counts the missed-detection draw at miss_probability 0 (none can be missed):
    # the position noise drawn after it must be the same numbers
    keys, ticks = world_keys(np.array([5, 6, 7])), np.array([0, 3, 9])
    made, skipped = WorldRandom(keys, ticks), WorldRandom(keys, ticks)
    made.random((3, 2, 1))
    skipped.skip((3, 2, 1))
    assert made.normal(0.0, 0.1, (3, 2, 1, 2)).tobytes() == skipped.normal(0.0, 0.1, (3, 2, 1, 2)).tobytes()
    with pytest.raises(ValueError, match="must start with the number of worlds 3"):
        skipped.skip((2, 2))


def test_hash_uniforms_are_hash_uniform_of_each_stream_to_the_bit():
    from pursuit_mj.randomness import hash_uniform, hash_uniforms

    keys, ticks = world_keys(np.array([5, 6, 7, 2**40])), np.array([0, 3, 9, 2**33])
    both = hash_uniforms(keys, ticks, (2, 3), (0, 5))
    assert both.shape == (2, 4, 2, 3)
    for i, stream in enumerate((0, 5)):
        assert both[i].tobytes() == hash_uniform(keys, ticks, (2, 3), stream).tobytes()
    with pytest.raises(ValueError, match="expected 0..7, got 8"):
        hash_uniforms(keys, ticks, 1, (0, 8))
