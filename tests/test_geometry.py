"""2D geometry: signed distances, ray casts and line of sight against brute force, MuJoCo and hand numbers."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pursuit_mj.geometry import (
    BORDER_THICKNESS,
    FAR,
    ObstacleSet,
    border_distance,
    box_sdf,
    cast_fan,
    cast_rays,
    cylinder_sdf,
    inside_boundary,
    line_of_sight,
    obstacle_distance,
)
from pursuit_mj.layout import BORDER_TOLERANCE, LayoutError, layout_from_dict, load_layout
from pursuit_mj.scene import SceneSpec, build_model

SPAWN = {"pursuers": {"x": [0.2, 3.4], "y": [0.2, 0.8]}, "evaders": {"x": [0.2, 3.4], "y": [4.2, 4.8]}}


def layout_with(obstacles, boundary="rectangle", spawn=SPAWN):
    return layout_from_dict({"arena": {"width": 3.6, "height": 5.0}, "boundary": boundary, "obstacles": obstacles, "spawn": spawn}, "<test>")


def central_spawn(y_low: float, y_high: float) -> dict:
    """Small spawn regions near the middle, inside round borders."""
    return {"pursuers": {"x": [1.5, 2.1], "y": [y_low, y_low + 0.3]}, "evaders": {"x": [1.5, 2.1], "y": [y_high - 0.3, y_high]}}


def brute_box_sdf(points, cx, cy, hx, hy, yaw, n=4000):
    """Distance to a densely sampled box outline, negative inside (for reference)."""
    t = np.linspace(0, 1, n, endpoint=False)
    local = np.concatenate([np.stack([-hx + 2 * hx * t, np.full(n, -hy)], 1), np.stack([np.full(n, hx), -hy + 2 * hy * t], 1),
                            np.stack([hx - 2 * hx * t, np.full(n, hy)], 1), np.stack([np.full(n, -hx), hy - 2 * hy * t], 1)])
    c, s = math.cos(yaw), math.sin(yaw)
    outline = local @ np.array([[c, s], [-s, c]]) + [cx, cy]
    d = np.linalg.norm(points[:, None] - outline[None], axis=-1).min(1)
    rel = (points - [cx, cy]) @ np.array([[c, -s], [s, c]])
    inside = (np.abs(rel[:, 0]) < hx) & (np.abs(rel[:, 1]) < hy)
    return np.where(inside, -d, d)


def test_box_sdf_matches_brute_force_for_rotated_boxes():
    rng = np.random.default_rng(0)
    boxes = np.array([[1.0, 2.0, 0.5, 0.2, 0.0], [2.5, 1.0, 0.3, 0.6, 0.7], [1.5, 3.5, 0.1, 0.9, -2.0]])
    pts = rng.uniform([0, 0], [3.6, 5.0], (300, 2))
    ours = box_sdf(pts, boxes)
    for k, b in enumerate(boxes):
        np.testing.assert_allclose(ours[:, k], brute_box_sdf(pts, *b), atol=2e-3)


def test_cylinder_sdf_and_obstacle_distance_by_hand():
    cyl = np.array([[1.0, 1.0, 0.5]])
    pts = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.3]])
    np.testing.assert_allclose(cylinder_sdf(pts, cyl)[:, 0], [-0.5, 0.5, -0.2])
    layout = layout_with([{"cylinder": {"center": [1.0, 2.5], "radius": 0.5}}, {"box": {"center": [2.6, 2.5], "size": [0.4, 1.0]}}])
    obst = ObstacleSet.from_layout(layout)
    p = np.array([[1.8, 2.5], [0.1, 2.5], [2.6, 2.5]])
    np.testing.assert_allclose(obstacle_distance(p, obst), [0.3, 0.1, -0.2])  # (0.1, 2.5) is nearest the border
    np.testing.assert_allclose(obstacle_distance(p, obst, with_border=False), [0.3, 0.4, -0.2])


def test_stacked_sets_with_padding_give_the_same_distances_and_rays():
    a = layout_with([{"cylinder": {"center": [1.0, 2.5], "radius": 0.3}}])
    b = layout_with([{"box": {"center": [2.0, 2.0], "size": [0.4, 0.4]}}, {"wall": {"from": [0.5, 4.0], "to": [3.0, 4.0]}}],
                    boundary={"circle": {"center": [1.8, 2.5], "radius": 1.8}}, spawn=central_spawn(1.0, 3.6))
    stacked = ObstacleSet.stack([a.obstacle_set(), b.obstacle_set()])
    assert stacked.boxes.shape[:2] == (2, 2) and stacked.cylinders.shape[:2] == (2, 1)
    rng = np.random.default_rng(1)
    pts = rng.uniform([0.5, 1.0], [3.0, 4.0], (2, 50, 2))
    dirs = rng.normal(size=(2, 50, 2))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    batched_d = obstacle_distance(pts, stacked)
    batched_r = cast_rays(pts, dirs, stacked)
    for w, layout in enumerate((a, b)):
        np.testing.assert_allclose(batched_d[w], obstacle_distance(pts[w], layout.obstacle_set()))
        np.testing.assert_allclose(batched_r[w], cast_rays(pts[w], dirs[w], layout.obstacle_set()))


def test_replacing_some_worlds_rows_matches_a_fresh_stack():
    a = layout_with([{"cylinder": {"center": [1.0, 2.5], "radius": 0.3}}])
    b = layout_with([{"box": {"center": [2.0, 2.0], "size": [0.4, 0.4]}}, {"wall": {"from": [0.5, 4.0], "to": [3.0, 4.0]}}],
                    boundary={"circle": {"center": [1.8, 2.5], "radius": 1.8}}, spawn=central_spawn(1.0, 3.6))
    c = layout_with([{"cylinder": {"center": [1.0, 2.5], "radius": 0.3}}, {"cylinder": {"center": [2.5, 3.5], "radius": 0.2}}])
    sets = {k: l.obstacle_set() for k, l in zip("abc", (a, b, c))}
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.5, 1.0], [3.0, 4.0], (3, 20, 2))
    dirs = rng.normal(size=(3, 20, 2))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    fan_dirs = dirs[0, :8]
    for before, rows, after in (("aab", {1: "b"}, "abb"), ("bab", {0: "a", 2: "a"}, "aaa"), ("aaa", {2: "c", 0: "b"}, "bac")):
        old = ObstacleSet.stack([sets[k] for k in before])
        ids = np.array(list(rows))
        replaced = old.with_rows(ids, [sets[rows[w]] for w in ids])
        fresh = ObstacleSet.stack([sets[k] for k in after])
        assert old.boxes[0].tolist() == ObstacleSet.stack([sets[k] for k in before]).boxes[0].tolist()  # old untouched
        for field in ("boxes", "box_valid", "cylinders", "cylinder_valid", "border", "border_valid"):
            np.testing.assert_array_equal(getattr(replaced, field), getattr(fresh, field), err_msg=field)
        for query in (lambda o: obstacle_distance(pts, o), lambda o: cast_rays(pts, dirs, o), lambda o: cast_fan(pts, fan_dirs, o)):
            np.testing.assert_array_equal(query(replaced), query(fresh))


def test_fan_of_rays_matches_single_rays_and_distances_match_per_kind():
    a = layout_with([{"cylinder": {"center": [1.0, 2.5], "radius": 0.3}}, {"box": {"center": [2.5, 1.5], "size": [0.6, 0.2], "yaw": 0.7}}])
    b = layout_with([{"box": {"center": [2.0, 2.0], "size": [0.4, 0.4]}}, {"wall": {"from": [0.5, 4.0], "to": [3.0, 4.0]}}],
                    boundary={"circle": {"center": [1.8, 2.5], "radius": 1.8}}, spawn=central_spawn(1.0, 3.6))
    stacked = ObstacleSet.stack([a.obstacle_set(), b.obstacle_set()])
    rng = np.random.default_rng(2)
    pts = rng.uniform([0.5, 1.0], [3.0, 4.0], (2, 7, 2))
    pts[0, 0] = [1.0, 2.6]  # inside the cylinder: every ray reads 0
    angles = rng.uniform(0, 2 * math.pi, 9)
    fan_dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    fan = cast_fan(pts, fan_dirs, stacked)  # (2, 7, 9)
    single = cast_rays(np.repeat(pts, 9, axis=1), np.broadcast_to(fan_dirs, (2, 7, 9, 2)).reshape(2, 63, 2), stacked)
    np.testing.assert_allclose(fan, single.reshape(2, 7, 9), atol=1e-9)
    assert (fan[0, 0] == 0).all() and cast_fan(pts, np.zeros((0, 2)), stacked).shape == (2, 7, 0)
    for w, layout in enumerate((a, b)):  # the fused distance equals the minimum over each kind
        o = layout.obstacle_set()
        parts = [box_sdf(pts[w], o.boxes), cylinder_sdf(pts[w], o.cylinders), border_distance(pts[w], o.border)[:, None]]
        np.testing.assert_allclose(obstacle_distance(pts, stacked)[w], np.concatenate(parts, -1).min(-1), atol=1e-12)


def test_rays_by_hand():
    layout = layout_with([{"box": {"center": [1.8, 3.0], "size": [1.0, 0.2]}}, {"cylinder": {"center": [3.0, 1.0], "radius": 0.2}}])
    obst = layout.obstacle_set()
    origin = np.array([[1.8, 1.0]] * 4)
    dirs = np.array([[0, 1.0], [0, -1.0], [1.0, 0], [-1.0, 0]])
    np.testing.assert_allclose(cast_rays(origin, dirs, obst), [1.9, 1.0, 1.0, 1.8])  # box face, floor wall, cylinder, left wall
    empty = ObstacleSet.from_layout(layout, include_border=False)
    up = cast_rays(np.array([[0.2, 0.5]]), np.array([[0.0, 1.0]]), empty)
    assert up[0] == FAR  # nothing above (0.2, 0.5) without the border


def test_line_of_sight_blocked_by_walls_and_obstacles():
    layout = layout_with([{"wall": {"from": [0.0, 2.5], "to": [2.0, 2.5], "thickness": 0.05}}])
    obst = layout.obstacle_set()
    a = np.array([[1.0, 1.0], [3.0, 1.0], [1.0, 1.0]])
    b = np.array([[1.0, 4.0], [3.0, 4.0], [1.5, 2.0]])
    assert line_of_sight(a, b, obst).tolist() == [False, True, True]


def test_inside_boundary_for_each_border_shape():
    circle = layout_with([], boundary={"circle": {"center": [1.8, 2.5], "radius": 1.0}}, spawn=central_spawn(1.8, 3.2))
    poly = load_layout(2)  # octagon with cut corners
    pts = np.array([[1.8, 2.5], [1.8, 3.6], [0.05, 0.05], [3.5, 2.5]])
    assert inside_boundary(circle, pts).tolist() == [True, False, False, False]
    assert inside_boundary(poly, pts).tolist() == [True, True, False, True]
    assert border_distance(np.array([[1.8, 2.5]]), circle.border())[0] == pytest.approx(1.0, abs=0.005)


@pytest.mark.parametrize("index", [2, 3])
def test_ray_casts_agree_with_mujoco_on_the_generated_scene(index):
    """The 2D geometry the task senses with is the geometry MuJoCo collides with."""
    layout = load_layout(index).with_random_obstacles(np.random.default_rng(5))
    model = build_model(SceneSpec(layout, 1, 1, "point"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    origin = np.array([1.8, 0.5])
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    ours = cast_rays(np.broadcast_to(origin, dirs.shape), dirs, layout.obstacle_set())
    group = np.zeros(6, np.uint8)
    group[1] = 1  # obstacles and border only
    geomid = np.zeros(1, np.int32)
    for k, d in enumerate(dirs):
        dist = mujoco.mj_ray(model, data, np.array([*origin, 0.5]), np.array([*d, 0.0]), group, 1, -1, geomid)
        assert dist == pytest.approx(ours[k], abs=1e-6), f"ray {k} ({mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geomid[0])})"


def test_ray_casts_agree_with_mujoco_around_the_reflex_corners_of_a_concave_border():
    """The border walls of a concave polygon do not reach into the flyable region at its reflex
    corners (they did by BORDER_THICKNESS, so MuJoCo hit walls the 2D geometry never saw)."""
    notch = {"polygon": [[0, 0], [3.6, 0], [3.6, 5], [2.6, 5], [2.6, 3.0], [1.0, 3.0], [1.0, 5], [0, 5]]}
    spawn = {"pursuers": {"x": [1.2, 2.4], "y": [0.4, 0.8]}, "evaders": {"x": [0.2, 0.8], "y": [4.2, 4.6]}}
    layout = layout_with([], boundary=notch, spawn=spawn)
    model = build_model(SceneSpec(layout, 1, 1, "point"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False) + 0.01
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    ring = 0.08 * np.stack([np.cos(angles + 0.1), np.sin(angles + 0.1)], -1)  # 8 cm around each reflex corner; no ray aims at it
    origins = np.concatenate([ring + [1.0, 3.0], ring + [2.6, 3.0]])
    origins = origins[inside_boundary(layout, origins)]
    group = np.zeros(6, np.uint8)
    group[1] = 1
    geomid = np.zeros(1, np.int32)
    for p in origins:
        ours = cast_rays(np.broadcast_to(p, dirs.shape), dirs, layout.obstacle_set())
        for k, d in enumerate(dirs):
            dist = mujoco.mj_ray(model, data, np.array([*p, 0.5]), np.array([*d, 0.0]), group, 1, -1, geomid)
            assert dist == pytest.approx(ours[k], abs=1e-6), (p, d, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geomid[0]))


@pytest.mark.parametrize("gap", [0.02, 0.045, 0.05, 0.1])
def test_a_slit_in_the_border_is_refused_or_mujoco_agrees_with_the_rays_across_it(gap):
    """A slit narrower than the border walls are thick put the wall outside each side into the
    flyable region on the other (MuJoCo hit it up to 5 cm before the 2D geometry's border)."""
    slit = {"polygon": [[0, 0], [3.6, 0], [3.6, 5], [0, 5], [0, 2.5 + gap], [2.6, 2.5 + gap], [2.6, 2.5], [0, 2.5]]}
    try:
        layout = layout_with([], boundary=slit)
    except LayoutError as exc:
        assert gap < BORDER_THICKNESS and "comes back within 0.05 m" in str(exc)
        return
    model = build_model(SceneSpec(layout, 1, 1, "point"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False) + 0.01
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    group = np.zeros(6, np.uint8)
    group[1] = 1
    geomid = np.zeros(1, np.int32)
    for p in np.array([[1.3, 2.3], [1.3, 2.7 + gap], [3.1, 2.5]]):
        ours = cast_rays(np.broadcast_to(p, dirs.shape), dirs, layout.obstacle_set())
        for k, d in enumerate(dirs):
            dist = mujoco.mj_ray(model, data, np.array([*p, 0.5]), np.array([*d, 0.0]), group, 1, -1, geomid)
            assert dist == pytest.approx(ours[k], abs=1e-6), (p, d, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geomid[0]))


def test_a_finely_sampled_wavy_border_is_accepted_and_mujoco_agrees_within_the_tolerance():
    """Walls lengthened past the convex corners of a curve sampled every few mm graze the next
    edges by a fraction of a millimetre: accepted, not taken for a slit."""
    a = np.linspace(0, 2 * np.pi, 1000, endpoint=False)
    r = 1.5 + 0.25 * np.sin(7 * a)
    wavy = {"polygon": np.stack([1.8 + r * np.cos(a), 2.5 + r * np.sin(a)], -1).round(6).tolist()}
    layout = layout_with([], boundary=wavy, spawn=central_spawn(1.3, 3.7))
    model = build_model(SceneSpec(layout, 1, 1, "point"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(0)
    group = np.zeros(6, np.uint8)
    group[1] = 1
    geomid = np.zeros(1, np.int32)
    origins = rng.uniform([0.4, 1.1], [3.2, 3.9], (40, 2))
    for p in origins[inside_boundary(layout, origins)]:
        d = rng.normal(size=(8, 2))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        ours = cast_rays(np.broadcast_to(p, d.shape), d, layout.obstacle_set())
        for k in range(len(d)):
            dist = mujoco.mj_ray(model, data, np.array([*p, 0.5]), np.array([*d[k], 0.0]), group, 1, -1, geomid)
            assert dist == pytest.approx(ours[k], abs=5 * BORDER_TOLERANCE)


def test_rays_through_a_box_corner_hit_the_corner():
    """A ray entering a box exactly through a corner stops there (rounding put it just past the
    end of both edges that meet there, and it read the box's far side instead)."""
    rng = np.random.default_rng(0)
    for k in range(60):
        box = np.array([[1.8, 2.5, *rng.uniform(0.05, 0.4, 2), rng.uniform(-3, 3)]])
        obst = ObstacleSet(box, np.ones(1, bool), np.zeros((0, 3)), np.zeros(0, bool), np.zeros((0, 4)), np.zeros(0, bool))
        corners = np.repeat(obst.segments()[0][:, :2], 10, axis=0)  # (40, 2)
        origins = rng.uniform([0.3, 0.3], [3.3, 4.7], corners.shape)
        dist = np.linalg.norm(corners - origins, axis=-1)
        dirs = (corners - origins) / dist[:, None]
        enters = box_sdf(origins + dirs * (dist + 1e-3)[:, None], box)[:, 0] < 0  # not only grazing the corner
        np.testing.assert_allclose(cast_rays(origins, dirs, obst)[enters], dist[enters], atol=1e-9, err_msg=f"box {k}")
        fan = np.array([cast_fan(o[None], d[None], obst)[0, 0] for o, d in zip(origins[enters], dirs[enters])])
        np.testing.assert_allclose(fan, dist[enters], atol=1e-9, err_msg=f"box {k}")


def test_a_fan_ray_along_the_line_of_a_box_edge_reads_what_a_single_ray_reads():
    """The range readings' fan (16 rays, ray 4 along +y with cos(pi/2) = 6e-17, not 0) from a
    point level with a box's edge: it read 0 (a wall touching the pursuer) or missed the box, which
    pursuers spawned on a 0.05 m grid met on layout 2 in the first observation of an episode."""
    layout = layout_with([{"wall": {"from": [1.0, 2.0], "to": [3.0, 2.0], "thickness": 0.05}}])
    obst = ObstacleSet.stack([layout.obstacle_set()])
    angles = 2 * np.pi * np.arange(16) / 16
    dirs = np.stack([np.cos(angles), np.sin(angles)], -1)
    origins = np.array([[[3.0, 0.5], [1.0, 3.5], [3.5, 2.025], [0.5, 1.975], [3.0 - 4e-16, 0.65], [1.0 + 4e-16, 3.2]]])
    fan = cast_fan(origins, dirs, obst)  # (1, 6, 16)
    single = cast_rays(np.repeat(origins, 16, axis=1), np.broadcast_to(dirs, (1, 6, 16, 2)).reshape(1, 96, 2), obst)
    np.testing.assert_allclose(fan, single.reshape(1, 6, 16), atol=1e-9)
    assert fan[0, 0, 4] == pytest.approx(1.475) and fan[0, 2, 8] == pytest.approx(0.5)  # up to the wall's end; along its top face to it


def test_distances_past_a_border_segment_s_end_are_to_its_end_point():
    """Outside the arena's corner (0, 0) the nearest border point is the corner itself: a segment's
    foot point is clipped to the segment, not taken on the line beyond its end."""
    layout = layout_with([])
    obstacles = ObstacleSet.from_layout(layout)
    points = np.array([[-1.0, -1.0], [-0.5, 2.5], [4.6, 6.0]])
    want = [math.sqrt(2.0), 0.5, math.sqrt(2.0)]
    np.testing.assert_allclose(obstacle_distance(points, obstacles), want, atol=1e-12)
    np.testing.assert_allclose(border_distance(points, obstacles.border), want, atol=1e-12)
    # a segment marked invalid (stack's padding) is not there
    valid = np.zeros(len(obstacles.border), bool)
    assert (border_distance(points, obstacles.border, valid) == FAR).all()


def test_a_target_on_a_surface_is_in_sight():
    """The ray to a target on the border ends where it hits the border: in sight, not blocked by it."""
    obstacles = ObstacleSet.from_layout(layout_with([]))
    a = np.array([[1.0, 2.5], [1.0, 2.5]])
    b = np.array([[0.0, 2.5], [1.0, 0.0]])  # on the left wall, on the bottom wall
    assert line_of_sight(a, b, obstacles).tolist() == [True, True]
