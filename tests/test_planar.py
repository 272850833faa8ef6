"""Planar maths: the closing-speed limiter keeps every cap where that is possible (the nearest such
velocity where the projections fall short), and says when it is not."""

from __future__ import annotations

import numpy as np

from conftest import nearest_allowed_on_a_grid
from pursuit_mj.planar import clip_norm, clip_unit, limit_closing, rotate, unit


def test_the_limiter_keeps_every_cap_wherever_that_is_possible():
    rng = np.random.default_rng(0)
    axis = np.linspace(-0.4, 0.4, 201)
    grid = np.stack(np.meshgrid(axis, axis), -1).reshape(-1, 2)  # velocities (G, 2) m/s
    solved = 0
    for _ in range(60):
        n_caps = rng.integers(1, 5)
        angles = rng.uniform(0, 2 * np.pi, n_caps)
        dirs = np.stack([np.cos(angles), np.sin(angles)], -1)  # (H, 2)
        caps = rng.uniform(-0.1, 0.2, n_caps)  # m/s
        want = rng.uniform(-0.3, 0.3, 2)
        out, met = limit_closing(want[None], dirs[None], caps[None])
        if np.all(grid @ dirs.T <= caps, axis=1).any():  # some velocity keeps them all
            assert met[0]
            assert np.all(dirs @ out[0] <= caps + 1e-7)
            solved += 1
    assert solved >= 30  # the test means something: most draws have an answer


def test_many_caps_at_once_are_kept_wherever_possible():
    # 10-30 caps (a shield sees ~200): the exact solve must not stall on caps it already has
    # (it once re-added the same cap each round and gave up on rows that had an answer)
    rng = np.random.default_rng(1)
    n_rows, n_caps = 300, 20
    angles = rng.uniform(0, 2 * np.pi, (n_rows, n_caps))
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)  # (P, H, 2)
    caps = rng.uniform(0.0, np.pi, (n_rows, n_caps)) * 0.05  # m/s, all >= 0: standing still is allowed
    want = rng.uniform(-0.3, 0.3, (n_rows, 2))
    out, met = limit_closing(want, dirs, caps, passes=0)
    assert met.all()
    assert np.all(np.einsum("phk,pk->ph", dirs, out) <= caps + 1e-7)
    out, met = limit_closing(np.array([[1.0, 1.0]]), np.array([[[1.0, 0.0], [0.0, 1.0]]]), np.zeros((1, 2)), passes=0)
    assert met[0]
    np.testing.assert_allclose(out[0], [0.0, 0.0], atol=1e-12)
    out, met = limit_closing(want[:2], np.zeros((2, 0, 2)), np.zeros((2, 0)))  # no hazards at all
    np.testing.assert_array_equal(out, want[:2])
    assert met.all()


def test_two_caps_at_a_sharp_angle_get_the_nearest_velocity_within_both():
    # a 30 deg wedge between "back off 0.04 m/s" and "at most 0.005 m/s": projections
    # alternate between the two and converge slowly; the exact answer is their crossing
    a, b = np.radians(194.0), np.radians(64.0)
    dirs = np.array([[np.cos(a), np.sin(a)], [np.cos(b), np.sin(b)]])
    caps = np.array([-0.04, 0.005])
    want = 0.3 * np.array([np.cos(np.radians(163.0)), np.sin(np.radians(163.0))])
    out, met = limit_closing(want[None], dirs[None], caps[None], passes=4)
    assert met[0]
    np.testing.assert_allclose(dirs @ out[0], caps, atol=1e-9)  # both bind
    assert np.linalg.norm(out[0] - want) <= nearest_allowed_on_a_grid(want, dirs, caps) + 1e-9


def test_conflicting_caps_are_reported_and_zero_directions_ignored():
    toward_and_away = np.array([[[1.0, 0.0], [-1.0, 0.0]]])  # (1, 2, 2)
    out, met = limit_closing(np.array([[0.3, 0.1]]), toward_and_away, np.array([[-0.1, -0.1]]))
    assert not met[0]  # both ways away at 0.1 m/s: impossible
    out, met = limit_closing(np.array([[0.3, 0.1]]), np.array([[[0.0, 0.0], [1.0, 0.0]]]), np.array([[-0.5, 0.1]]))
    assert met[0]
    np.testing.assert_allclose(out[0], [0.1, 0.1])  # the direction-less cap counted for nothing


def test_leading_dimensions_are_kept_and_safe_velocities_pass_unchanged():
    v = np.zeros((2, 3, 2))
    v[..., 0] = -0.2  # away from the one hazard, to the +x side
    u = np.zeros((2, 3, 1, 2))
    u[..., 0] = 1.0
    out, met = limit_closing(v, u, np.full((2, 3, 1), 0.05))
    assert out.shape == (2, 3, 2) and met.shape == (2, 3) and met.all()
    np.testing.assert_array_equal(out, v)


def test_each_velocity_is_limited_the_same_whatever_else_is_in_the_batch():
    # Row 0 needs the exact solve and finds an allowed velocity at once; row 1 needs more
    # rounds. Row 1's extra rounds used to add caps to row 0 too and change its answer (by
    # 0.11 m/s here): a pursuer's shielded velocity depended on the other pursuers and worlds
    # of the batch, so an eval episode ended differently with --worlds 1 and --worlds 6.
    want = np.array([[-0.8263233461744847, 0.663199334447105], [-1.1243859199611483, 0.870374762016278]])
    angles = np.array([[3.7364461058234286, 2.4684807639480315, 3.131694912732728, 4.574094657609654, 1.9585079332658477, 1.8198648524529117],
                       [1.637072629554822, 0.2879924901307654, 3.215134311118233, 3.5462048874407417, 2.11857226956252, 1.5000758991364387]])
    caps = np.array([[0.06307876192940914, -0.02672806889503249, -0.04137756517567492, 0.5324180078838434, -0.06201894782563397, -0.04242630102742562],
                     [0.28082191752993607, -0.1631978993867944, -0.22908051941506558, -0.12316222292401402, -0.17301454281889295, 0.15814323336603037]])
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    together, met = limit_closing(want, dirs, caps, passes=1)
    for row in range(2):
        alone, met_alone = limit_closing(want[row : row + 1], dirs[row : row + 1], caps[row : row + 1], passes=1)
        assert met_alone[0] == met[row]
        np.testing.assert_array_equal(alone[0], together[row])
    assert met[0] and np.all(dirs[0] @ together[0] <= caps[0] + 1e-7)


def test_small_vector_helpers():
    np.testing.assert_allclose(unit(np.array([[3.0, 4.0], [0.0, 0.0]])), [[0.6, 0.8], [0.0, 0.0]])
    np.testing.assert_allclose(rotate(np.array([1.0, 0.0]), np.pi / 2), [0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(clip_norm(np.array([[0.6, 0.8], [0.3, 0.0]]), 0.5), [[0.3, 0.4], [0.3, 0.0]])
    once = clip_unit(np.array([[3.0, 4.0], [0.2, -0.9]]))
    np.testing.assert_array_equal(clip_unit(once), once)  # clipping twice changes nothing, bit for bit


def test_a_vector_without_length_takes_the_fallback_direction_and_perp_turns_left():
    from pursuit_mj.planar import perp

    fallback = np.array([[0.0, 1.0], [1.0, 0.0]])
    np.testing.assert_array_equal(unit(np.array([[0.0, 0.0], [3.0, 4.0]]), fallback), [[0.0, 1.0], [0.6, 0.8]])
    np.testing.assert_array_equal(perp(np.array([[1.0, 0.0], [0.0, 2.0]])), [[0.0, 1.0], [-2.0, 0.0]])  # +90 deg


def test_of_several_allowed_candidates_the_nearest_is_taken():
    # three caps that the four projections leave exceeded: the exact solve finds more than one
    # allowed candidate; the first of them in its list lay 2.335 m/s from v, the nearest 2.250
    v = np.array([[2.11, 0.52]])
    angles = np.radians([-8.17, -160.85, 56.55])
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    caps = np.array([0.045, 0.171, -0.228])
    out, met = limit_closing(v, dirs[None], caps[None])
    assert met.all() and np.all(dirs @ out[0] <= caps + 1e-9)
    assert np.linalg.norm(out[0] - v[0]) <= nearest_allowed_on_a_grid(v[0], dirs, caps) + 1e-3
