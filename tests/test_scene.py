"""Scene generation: every built-in layout compiles, names follow one pattern, obstacles are real geometry."""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np
import pytest

from pursuit_mj.layout import N_BUILTIN, Box, Cylinder, Wall, load_layout
from pursuit_mj.palette import OBSTACLE_RGBA
from pursuit_mj.scene import DroneIds, SceneSpec, build_model, drone_names, drone_parameters

FIDELITIES = ("point", "quadrotor")
DRONE = r"(pursuer|evader)_\d+"


@pytest.fixture(scope="module")
def built_in_instances():
    """Each built-in layout with its random obstacles of seed 11 placed."""
    return [load_layout(i).with_random_obstacles(np.random.default_rng(11)) for i in range(N_BUILTIN)]


def names_of(model: mujoco.MjModel, kind: str, count: int) -> list[str | None]:
    obj = getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}")
    return [mujoco.mj_id2name(model, obj, i) for i in range(count)]


@pytest.mark.parametrize("fidelity", FIDELITIES)
@pytest.mark.parametrize("index", range(N_BUILTIN))
def test_every_built_in_layout_compiles_and_steps(built_in_instances, index, fidelity):
    layout = built_in_instances[index]
    assert len(layout.obstacles) > len(load_layout(index).obstacles)  # random obstacles were added
    model = build_model(SceneSpec(layout, 3, 1, fidelity))
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, 10)
    assert np.isfinite(data.qpos).all()
    ids = DroneIds.lookup(model, drone_names(3, 1), fidelity)
    assert len(set(ids.body.tolist())) == 4


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_every_element_is_named_from_one_pattern(built_in_instances, fidelity):
    layout = built_in_instances[3]
    model = build_model(SceneSpec(layout, 2, 2, fidelity, obstacle_slots=40))
    bodies = names_of(model, "body", model.nbody)
    assert bodies[0] == "world" and all(re.fullmatch(rf"{DRONE}/body", n) for n in bodies[1:])
    for kind, count in (("joint", model.njnt), ("site", model.nsite), ("actuator", model.nu), ("sensor", model.nsensor)):
        names = names_of(model, kind, count)
        assert count > 0 and all(n and re.fullmatch(rf"{DRONE}/\w+", n) for n in names), (kind, names)
    geoms = names_of(model, "geom", model.ngeom)
    assert all(n for n in geoms), "an unnamed geom"
    n_obst, n_border = len(layout.obstacles), len(layout.border())
    assert sorted(n for n in geoms if n.startswith("obstacle_")) == sorted(f"obstacle_{k}" for k in range(n_obst))
    assert sorted(n for n in geoms if n.startswith("border_")) == sorted(f"border_{k}" for k in range(n_border))
    other = [n for n in geoms if not re.fullmatch(rf"(obstacle|border|unused)_\d+|floor|{DRONE}/\w+", n)]
    assert other == []
    assert names_of(model, "camera", model.ncam) == ["top", "angled"]
    # the parts a user looks up, for every drone
    parts = ["body/body", "collision/geom", "contact/sensor"]
    parts += [f"motor_{k}/actuator" for k in range(4)] + ["root/joint"] if fidelity == "quadrotor" else ["x/joint", "y/joint", "fx/actuator", "fy/actuator"]
    for drone in drone_names(2, 2):
        for part in parts:
            name, kind = part.split("/")
            assert getattr(model, kind)(f"{drone}/{name}").id >= 0


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_obstacles_and_border_are_collision_geometry_where_the_layout_says(built_in_instances, fidelity):
    layout = built_in_instances[3]
    model = build_model(SceneSpec(layout, 3, 1, fidelity))
    for k, o in enumerate(layout.obstacles):
        g = model.geom(f"obstacle_{k}")
        assert g.contype[0] and g.conaffinity[0]
        np.testing.assert_allclose(g.pos[:2], (o.as_box() if isinstance(o, Wall) else o).center, atol=1e-9)
        if isinstance(o, Cylinder):
            assert g.type[0] == mujoco.mjtGeom.mjGEOM_CYLINDER and g.size[0] == pytest.approx(o.radius)
        else:
            box = o.as_box() if isinstance(o, Wall) else o
            assert isinstance(box, Box) and g.type[0] == mujoco.mjtGeom.mjGEOM_BOX
            np.testing.assert_allclose(g.size[:2], np.array(box.size) / 2)
            yaw = 2 * math.atan2(g.quat[3], g.quat[0])
            assert math.cos(yaw - box.yaw) == pytest.approx(1.0)
        assert g.pos[2] - g.size[1 if isinstance(o, Cylinder) else 2] <= 0.0  # from the floor up
    for k in range(len(layout.border())):
        g = model.geom(f"border_{k}")
        assert g.contype[0] and g.conaffinity[0] and g.pos[2] + g.size[2] > 0.5 + 0.05  # above flight height


def test_obstacles_are_coloured_by_origin(built_in_instances):
    base = load_layout(3)
    layout = built_in_instances[3]
    assert layout.n_random == base.random_obstacles.count == len(layout.obstacles) - len(base.obstacles)
    model = build_model(SceneSpec(layout, 3, 1, "point"))
    for k in range(len(layout.obstacles)):
        origin = "fixed" if k < len(base.obstacles) else "random"
        np.testing.assert_allclose(model.geom(f"obstacle_{k}").rgba, OBSTACLE_RGBA[origin], atol=1e-6)


def test_padded_scenes_share_sizes_across_layouts(built_in_instances):
    models = [build_model(SceneSpec(l, 3, 1, "quadrotor", obstacle_slots=40)) for l in built_in_instances]
    for m in models[1:]:
        assert (m.ngeom, m.nq, m.nv, m.nu, m.na, m.nsensordata, m.nbvh) == (
            models[0].ngeom, models[0].nq, models[0].nv, models[0].nu, models[0].na, models[0].nsensordata, models[0].nbvh)
    with pytest.raises(ValueError, match="exceed 5 slots"):
        build_model(SceneSpec(built_in_instances[3], 3, 1, "quadrotor", obstacle_slots=5))


def test_scene_building_is_a_pure_function(built_in_instances):
    spec = SceneSpec(built_in_instances[2], 3, 1, "quadrotor")
    a, b = build_model(spec), build_model(spec)
    for field in ("geom_pos", "geom_size", "geom_quat", "body_mass", "actuator_gear", "name_geomadr"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_drone_parameters_match_the_cited_crazyflie_numbers():
    p = drone_parameters()
    assert 0.027 <= p["mass"] <= 0.029
    np.testing.assert_allclose(p["inertia"], [1.66e-5, 1.66e-5, 2.93e-5], rtol=0.01)
    np.testing.assert_allclose(np.linalg.norm(p["motor_xy"], axis=1), 0.046, rtol=0.01)
    np.testing.assert_allclose(np.abs(p["yaw_ratio"]), 0.006)
    assert sorted(np.sign(p["yaw_ratio"]).tolist()) == [-1, -1, 1, 1]
    assert 0.12 <= p["max_thrust"] <= 0.15 and 4 * p["max_thrust"] > 1.5 * p["mass"] * 9.81
    assert 0.01 <= p["motor_tau"] <= 0.1
    assert (p["drag"] > 0).all() and p["drag"][0] == p["drag"][1]


def test_point_and_quadrotor_bodies_share_mass_and_collision_volume():
    layout = load_layout(0)
    quad, point = (build_model(SceneSpec(layout, 1, 1, f)) for f in ("quadrotor", "point"))
    for name in ("pursuer_0", "evader_0"):
        assert quad.body(f"{name}/body").mass[0] == point.body(f"{name}/body").mass[0]
        np.testing.assert_array_equal(quad.geom(f"{name}/collision").size, point.geom(f"{name}/collision").size)


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_drone_mass_sets_every_drones_body_mass_and_scales_its_inertia(fidelity):
    """Both fidelities, every drone; the inertia scaled by the mass ratio, as drone_parameters
    gives it to the controller."""
    base = drone_parameters()
    model = build_model(SceneSpec(load_layout(0), 3, 1, fidelity, drone_mass=0.033))
    for name in drone_names(3, 1):
        body = model.body(f"{name}/body")
        assert body.mass[0] == 0.033
        np.testing.assert_allclose(body.inertia, base["inertia"] * 0.033 / 0.027, rtol=1e-12)
    np.testing.assert_allclose(drone_parameters(0.033)["inertia"], base["inertia"] * 0.033 / 0.027, rtol=1e-12)
    assert drone_parameters(0.033)["mass"] == 0.033


def test_scenes_of_different_drone_masses_are_built_apart():
    """The drone spec template is cached per role and fidelity: a mass set on one scene's copy
    must not reach the template or the next scene, whichever order they are built in."""
    layout = load_layout(0)
    specs = [SceneSpec(layout, 1, 1, "quadrotor", drone_mass=m) for m in (0.035, None, 0.030, 0.027)]
    assert len(set(specs)) == len(specs)  # distinct keys wherever a SceneSpec is cached or compared
    masses = [build_model(s).body("pursuer_0/body").mass[0] for s in specs]
    assert masses == [0.035, 0.027, 0.030, 0.027]


def test_a_non_positive_drone_mass_is_refused_by_the_scene():
    with pytest.raises(ValueError, match=r"drone mass: 0.0 kg is not positive"):
        drone_parameters(0.0)
    with pytest.raises(ValueError, match=r"drone mass: -0.03 kg is not positive"):
        build_model(SceneSpec(load_layout(0), 1, 1, "quadrotor", drone_mass=-0.03))


def test_the_default_drone_mass_builds_the_model_files_drone_exactly():
    """drone_mass at its default (the file's 0.027 kg) gives the same model, bit for bit, as
    leaving the model file's mass alone, so no episode of a default task changes."""
    from pursuit_mj.config import default_config

    layout = load_layout(1)
    configured = build_model(SceneSpec.for_task(default_config(), layout))
    untouched = build_model(SceneSpec(layout, 3, 1, "quadrotor"))
    for field in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "dof_invweight0", "body_invweight0"):
        assert np.array_equal(getattr(configured, field), getattr(untouched, field)), field
    assert drone_parameters(0.027).keys() == drone_parameters().keys()
    for key, value in drone_parameters(0.027).items():
        assert np.array_equal(value, drone_parameters()[key]), key


HAND_LAYOUT = """
name: by_hand
arena: {width: 3.0, height: 4.0}
boundary: rectangle
obstacles:
  - box: {center: [1.0, 2.0], size: [0.6, 0.2], yaw: 0.5235987755982988}   # 30 deg counter-clockwise
  - cylinder: {center: [2.2, 1.5], radius: 0.15}
  - wall: {from: [0.0, 3.0], to: [1.2, 3.0], thickness: 0.04}
  - wall: {from: [2.0, 2.6], to: [2.6, 3.2]}                                # default thickness 0.05
random_obstacles: {count: 0}
spawn:
  pursuers: {x: [0.2, 2.8], y: [0.2, 0.8]}
  evaders: {x: [0.2, 2.8], y: [3.3, 3.8]}
"""


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_the_compiled_geoms_are_the_yaml_obstacles_and_border_worked_out_by_hand(tmp_path, fidelity):
    """Names, types, world positions, half sizes, heights and rotation sense of every obstacle
    and border geom, against numbers worked out from the YAML text above (not from Layout)."""
    path = tmp_path / "by_hand.yaml"
    path.write_text(HAND_LAYOUT)
    model = build_model(SceneSpec(load_layout(path), 3, 1, fidelity))  # flight height 0.5 m: obstacles 1.2 m, border 0.8 m tall
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    c30, s30, r2 = math.cos(math.pi / 6), math.sin(math.pi / 6), math.sqrt(0.5)
    # name: (type, centre x y z, half sizes, world direction of the geom's local x axis)
    expected = {
        "obstacle_0": ("BOX", (1.0, 2.0, 0.6), (0.3, 0.1, 0.6), (c30, s30)),
        "obstacle_1": ("CYLINDER", (2.2, 1.5, 0.6), (0.15, 0.6), None),
        "obstacle_2": ("BOX", (0.6, 3.0, 0.6), (0.6, 0.02, 0.6), (1.0, 0.0)),
        "obstacle_3": ("BOX", (2.3, 2.9, 0.6), (0.6 * math.sqrt(2) / 2, 0.025, 0.6), (r2, r2)),
        # border walls 5 cm thick just outside each side, counter-clockwise from the bottom,
        # lengthened 5 cm past each (convex) corner
        "border_0": ("BOX", (1.5, -0.025, 0.4), (1.55, 0.025, 0.4), (1.0, 0.0)),
        "border_1": ("BOX", (3.025, 2.0, 0.4), (2.05, 0.025, 0.4), (0.0, 1.0)),
        "border_2": ("BOX", (1.5, 4.025, 0.4), (1.55, 0.025, 0.4), (-1.0, 0.0)),
        "border_3": ("BOX", (-0.025, 2.0, 0.4), (2.05, 0.025, 0.4), (0.0, -1.0)),
    }
    assert sorted(n for n in names_of(model, "geom", model.ngeom) if n.startswith(("obstacle_", "border_"))) == sorted(expected)
    for name, (kind, pos, half, x_axis) in expected.items():
        g = model.geom(name)
        assert g.type[0] == getattr(mujoco.mjtGeom, f"mjGEOM_{kind}"), name
        np.testing.assert_allclose(data.geom(name).xpos, pos, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(g.size[:len(half)], half, atol=1e-9, err_msg=name)
        if x_axis is not None:
            xmat = data.geom(name).xmat.reshape(3, 3)
            np.testing.assert_allclose(xmat[:, 0], (*x_axis, 0.0), atol=1e-9, err_msg=name)
            np.testing.assert_allclose(xmat[:, 2], (0.0, 0.0, 1.0), atol=1e-9, err_msg=name)
    # the rotated box's corner at local (+0.3, +0.1), where the YAML's 30 deg turn puts it
    xmat = data.geom("obstacle_0").xmat.reshape(3, 3)
    corner = data.geom("obstacle_0").xpos + xmat @ np.array([0.3, 0.1, 0.6])
    np.testing.assert_allclose(corner, (1.0 + 0.3 * c30 - 0.1 * s30, 2.0 + 0.3 * s30 + 0.1 * c30, 1.2), atol=1e-9)
    # the walls' ends lie where the YAML puts them
    for name, (a, b) in (("obstacle_2", ((0.0, 3.0), (1.2, 3.0))), ("obstacle_3", ((2.0, 2.6), (2.6, 3.2)))):
        x_axis, half = data.geom(name).xmat.reshape(3, 3)[:2, 0], model.geom(name).size[0]
        np.testing.assert_allclose(sorted([tuple(data.geom(name).xpos[:2] - half * x_axis), tuple(data.geom(name).xpos[:2] + half * x_axis)]),
                                   sorted([a, b]), atol=1e-9, err_msg=name)


def test_a_layout_made_with_a_clockwise_polygon_gets_its_border_walls_outside_the_flyable_region():
    """The loader stores a polygon counter-clockwise, but a Layout made directly (which PursuitEnv
    takes, checked as its file would be) kept its clockwise points: the scene built every border
    wall on the inside of its edge, 5 cm into the flyable region."""
    import dataclasses

    from pursuit_mj.geometry import inside_boundary
    from pursuit_mj.layout import Boundary

    ccw = load_layout(2)
    cw = dataclasses.replace(ccw, boundary=Boundary("polygon", points=ccw.boundary.points[::-1]))
    model, reference = build_model(SceneSpec(cw, 3, 1, "point")), build_model(SceneSpec(ccw, 3, 1, "point"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    walls = np.array([data.geom(f"border_{k}").xpos[:2] for k in range(len(cw.border()))])
    assert not inside_boundary(cw, walls).any()
    assert sorted(map(tuple, np.round(walls, 9))) == sorted(
        tuple(np.round(reference.geom(f"border_{k}").pos[:2], 9)) for k in range(len(ccw.border())))
