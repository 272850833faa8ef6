"""Capture geometry, collision rules and reward terms on hand-made positions."""

import dataclasses

import numpy as np
import pytest

from pursuit_mj.config import default_config
from pursuit_mj.geometry import ObstacleSet
from pursuit_mj.layout import layout_from_dict
from pursuit_mj.rewards import detect_events, reward_terms

LAYOUT = layout_from_dict(
    {
        "arena": {"width": 4.0, "height": 4.0},
        "obstacles": [{"box": {"center": [2.0, 2.0], "size": [0.4, 0.4]}}],
        "random_obstacles": {"count": 0},
        "spawn": {"pursuers": {"x": [0.2, 3.8], "y": [0.2, 0.6]}, "evaders": {"x": [0.2, 3.8], "y": [3.4, 3.8]}},
    },
    "test-layout",
)
OBST = ObstacleSet.stack([LAYOUT.obstacle_set()])
CFG = default_config(random_obstacles=0)


def _events(pursuers, evaders, captured=None, contacts=None):
    p = np.array(pursuers, float)[None]
    e = np.array(evaders, float)[None]
    cap = np.zeros((1, e.shape[1]), bool) if captured is None else np.array(captured)[None]
    con = np.zeros((1, p.shape[1]), bool) if contacts is None else np.array(contacts)[None]
    return detect_events(p, e, cap, con, OBST, CFG)


@pytest.mark.parametrize("gap,caught", [(-1e-6, True), (1e-6, False)])
def test_capture_at_the_radius_boundary(gap, caught):
    ev = _events([[1.0, 1.0]], [[1.0 + CFG.capture_radius + gap, 1.0]])
    assert bool(ev.new_captures[0, 0]) is caught


def test_no_capture_through_a_thin_wall():
    walled = layout_from_dict(
        {
            "arena": {"width": 4.0, "height": 4.0},
            "obstacles": [{"wall": {"from": [1.0, 2.0], "to": [3.0, 2.0], "thickness": 0.05}}],
            "random_obstacles": {"count": 0},
            "spawn": {"pursuers": {"x": [0.2, 3.8], "y": [0.2, 0.6]}, "evaders": {"x": [0.2, 3.8], "y": [3.4, 3.8]}},
        },
        "thin-wall",
    )
    obstacles = ObstacleSet.stack([walled.obstacle_set()])

    def caught(pursuers, evader):
        p, e = np.array(pursuers, float)[None], np.array([evader], float)[None]
        return bool(detect_events(p, e, np.zeros((1, 1), bool), np.zeros((1, len(pursuers)), bool), obstacles, CFG).new_captures[0, 0])

    assert not caught([[2.0, 1.85]], [2.0, 2.1]), "0.25 m apart, but the wall is between them"
    assert caught([[0.8, 1.85]], [0.8, 2.1]), "the same 0.25 m beside the wall's end"
    assert caught([[2.0, 1.85], [2.1, 2.3]], [2.0, 2.1]), "a teammate on the evader's side still catches it"


def test_already_captured_evader_is_not_caught_again():
    ev = _events([[1.0, 1.0]], [[1.1, 1.0]], captured=[True])
    assert not ev.new_captures.any()


@pytest.mark.parametrize("x,collided", [(1.8 - 0.09, True), (1.8 - 0.11, False)])
def test_obstacle_clearance(x, collided):
    ev = _events([[x, 2.0]], [[3.5, 3.5]])
    assert bool(ev.collided[0, 0]) is collided


def test_border_clearance_and_teammate_clearance_and_contacts():
    assert _events([[0.05, 1.0]], [[3.5, 3.5]]).collided[0, 0]
    ev = _events([[1.0, 1.0], [1.19, 1.0], [3.0, 1.0]], [[3.5, 3.5]])
    assert ev.collided[0].tolist() == [True, True, False]
    ev = _events([[1.0, 1.0], [3.0, 1.0]], [[3.5, 3.5]], contacts=[False, True])
    assert ev.collided[0].tolist() == [False, True]


def test_reward_terms_are_named_and_scaled():
    prev = np.array([[[1.0, 1.0], [3.0, 1.0]]])
    now = np.array([[[1.0, 1.3], [3.0, 1.0]]])
    ev_pos = np.array([[[1.0, 3.0]]])
    free = np.ones((1, 1), bool)
    events = detect_events(now, ev_pos, ~free, np.zeros((1, 2), bool), OBST, CFG)
    terms = reward_terms(CFG, events, prev, now, ev_pos, ev_pos, free)
    assert set(terms) == {"capture", "progress", "collision", "proximity", "spread"}
    # pursuer 0 closed 0.3 m on the evader: one unit of progress; pursuer 1 moved away? no: stayed
    assert terms["progress"][0, 0] == pytest.approx(CFG.progress_reward * 1.0)
    assert terms["progress"][0, 1] == pytest.approx(0.0)
    assert (terms["capture"] == 0).all() and (terms["collision"] == 0).all()
    for name, values in terms.items():  # a negative scale times nothing was -0.0, logged and shown as such
        assert not np.signbit(values[values == 0]).any(), name
    crash = detect_events(np.array([[[0.05, 1.0], [3.0, 1.0]]]), ev_pos, ~free, np.zeros((1, 2), bool), OBST, CFG)
    t2 = reward_terms(CFG, crash, prev, now, ev_pos, ev_pos, free)
    assert (t2["collision"] == CFG.collision_penalty).all(), "a collision fails the whole team"
    assert t2["proximity"][0, 0] < 0 and t2["proximity"][0, 1] == 0


@pytest.mark.parametrize("beyond,share", [(0.0, 1.0), (0.5, 0.5), (1.0, 0.0), (1.1, 0.0)])
def test_proximity_zone_lies_beyond_the_clearance(beyond, share):
    # the soft zone is proximity_distance wide, starting at obstacle_clearance (centre to
    # surface), not proximity_distance from the wall as the key's help once said
    x = 1.8 - CFG.obstacle_clearance - beyond * CFG.proximity_distance  # the box's left face is at x = 1.8
    p = np.array([[[x, 2.0]]])
    ev_pos = np.array([[[3.5, 3.5]]])
    free = np.ones((1, 1), bool)
    events = detect_events(p, ev_pos, ~free, np.zeros((1, 1), bool), OBST, CFG)
    terms = reward_terms(CFG, events, p, p, ev_pos, ev_pos, free)
    assert terms["proximity"][0, 0] == pytest.approx(share * CFG.proximity_penalty, abs=1e-6)



# ----------------------------------------------------------------------------- mutation audit

FAR_EVADER = np.array([[[3.5, 3.5]]])  # one free evader in the top right corner, far from everything


def _standing_terms(pos, cfg=CFG):
    """reward_terms of one step in which pursuers (N, 2) stand at pos and FAR_EVADER stands too."""
    p = np.array(pos, float)[None]
    free = np.ones((1, 1), bool)
    events = detect_events(p, FAR_EVADER, ~free, np.zeros((1, len(pos)), bool), OBST, cfg)
    return reward_terms(cfg, events, p, p, FAR_EVADER, FAR_EVADER, free)


def test_two_evaders_caught_in_one_step_pay_the_capture_reward_twice():
    p = np.array([[[1.0, 1.0], [3.0, 1.0]]])
    e = np.array([[[1.1, 1.0], [3.1, 1.0]]])
    free = np.ones((1, 2), bool)
    events = detect_events(p, e, ~free, np.zeros((1, 2), bool), OBST, CFG)
    assert events.new_captures.all()
    terms = reward_terms(CFG, events, p, p, e, e, free)
    np.testing.assert_allclose(terms["capture"], 2 * CFG.capture_reward)


def test_progress_is_measured_to_where_the_evader_was_then_and_is_now():
    # the pursuer stands still while the evader flees 0.3 m: one unit of progress lost
    p = np.array([[[1.0, 1.0]]])
    e_prev, e_now = np.array([[[1.0, 2.0]]]), np.array([[[1.0, 2.3]]])
    free = np.ones((1, 1), bool)
    events = detect_events(p, e_now, ~free, np.zeros((1, 1), bool), OBST, CFG)
    terms = reward_terms(CFG, events, p, p, e_now, e_prev, free)
    assert terms["progress"][0, 0] == pytest.approx(-CFG.progress_reward)


def test_proximity_to_a_teammate_lies_beyond_the_teammate_clearance_and_adds_to_the_wall_s():
    half = CFG.teammate_clearance + 0.5 * CFG.proximity_distance  # half way into the teammates' soft zone
    terms = _standing_terms([[1.0, 1.0], [1.0 + half, 1.0]])
    np.testing.assert_allclose(terms["proximity"], 0.5 * CFG.proximity_penalty, rtol=1e-5)
    x = 1.8 - CFG.obstacle_clearance  # pursuer 0 also at the box's clearance (its left face is at x = 1.8)
    terms = _standing_terms([[x, 2.0], [x, 2.0 + half]])
    assert terms["proximity"][0, 0] == pytest.approx(1.5 * CFG.proximity_penalty, rel=1e-5)  # both shares count


@pytest.mark.parametrize("pos,share", [([[1.0, 1.0], [1.5, 1.0]], 0.5), ([[1.0, 1.0], [3.0, 1.0]], 1.0), ([[1.0, 1.0]], 1.0)])
def test_spread_grows_with_the_nearest_teammate_s_distance_up_to_one_metre(pos, share):
    terms = _standing_terms(pos, dataclasses.replace(CFG, spread_reward=0.2))
    np.testing.assert_allclose(terms["spread"], 0.2 * share, rtol=1e-6)  # a lone pursuer: as far apart as counts
