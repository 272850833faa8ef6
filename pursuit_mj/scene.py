"""Scene generation: (layout, drone counts, fidelity, physics settings) -> MjModel, through MjSpec.

Names follow one pattern: drones are `{role}_{i}` (role: pursuer | evader) and their parts
`{role}_{i}/{part}` (body, root, x, y, motor_0..3, fx, fy, collision, contact); obstacles are
`obstacle_{k}`, border segments `border_{k}`, the floor `floor`. Geom groups: 0 floor,
1 obstacles and border, 2 drone visuals, 3 drone collision volumes.
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import mujoco
import numpy as np

from .geometry import border_walls
from .layout import Box, Cylinder, Layout, Wall
from .palette import BORDER_RGBA, FLOOR_RGB, OBSTACLE_RGBA, ROLE_RGBA
from .shipped import shipped_dir

MODEL_DIR = shipped_dir("models")
DRONE_FILE = MODEL_DIR / "crazyflie.xml"

OBSTACLE_HEIGHT = 1.2  # m, at least; and at least OBSTACLE_HEADROOM above the flight height
BORDER_HEIGHT = 0.6  # m, at least (low, so that the angled camera sees in); likewise
OBSTACLE_HEADROOM = 0.3  # m: walls reach this far above the flight height, so no drone flies over one
GROUP_OBSTACLE = 1


def drone_names(n_pursuers: int, n_evaders: int) -> list[str]:
    """Drone names in state order: pursuers first, then evaders."""
    return [f"pursuer_{i}" for i in range(n_pursuers)] + [f"evader_{i}" for i in range(n_evaders)]


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """What a scene is made of; `build_model` is a pure function of it."""

    layout: Layout
    n_pursuers: int
    n_evaders: int
    fidelity: str
    physics_dt: float = 0.002
    flight_height: float = 0.5
    obstacle_slots: int = 0  # pad obstacles + border to this many geoms, so worlds share sizes
    drone_mass: float | None = None  # kg, each drone's take-off mass; None: the model file's (drone_parameters)

    @staticmethod
    def for_task(config, layout: Layout, obstacle_slots: int = 0) -> "SceneSpec":
        """The scene of a task config (pursuit_mj.config.TaskConfig) in `layout`."""
        c = config
        return SceneSpec(layout, c.n_pursuers, c.n_evaders, c.fidelity, c.physics_dt, c.flight_height, obstacle_slots, c.drone_mass)


@lru_cache(maxsize=1)
def _drone_template_xml() -> str:
    return DRONE_FILE.read_text()


def drone_parameters(mass: float | None = None) -> dict[str, np.ndarray | float]:
    """Physical parameters of one drone read from models/crazyflie.xml (SI units).

    mass (kg), inertia (3,) kg m^2, motor_xy (4, 2) m in the body frame, yaw_ratio (4,) m
    (signed torque per newton of thrust), max_thrust (N), motor_tau (s), drag (3,) N s/m,
    point_time_constant (s), point_max_accel (m/s^2). A fresh copy on every call.

    `mass` (kg), if given, replaces the file's and scales the inertia with it (see
    `scaled_inertia`); everything else is the file's. The scene builder applies the same.
    """
    params = {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in _read_drone_parameters().items()}
    if mass is not None:
        params["inertia"] = scaled_inertia(params["inertia"], params["mass"], mass)
        params["mass"] = float(mass)
    return params


def scaled_inertia(inertia: np.ndarray, file_mass: float, mass: float) -> np.ndarray:
    """Principal inertia (3,) kg m^2 of a drone of `mass` kg whose model file gives `inertia` at
    `file_mass` kg: scaled by mass / file_mass, as if the added mass (deck, markers, a bigger
    battery) were spread like the airframe's own. Decks and batteries sit near the centre, so
    a real drone's inertia grows less than this; the scaled one errs on the sluggish side
    (more rotor thrust difference for the same turn). A ratio of exactly 1 leaves it as is."""
    if not mass > 0.0:
        raise ValueError(f"drone mass: {mass!r} kg is not positive")
    return inertia * (float(mass) / file_mass)


@lru_cache(maxsize=1)
def _read_drone_parameters() -> dict[str, np.ndarray | float]:
    m = mujoco.MjModel.from_xml_path(str(DRONE_FILE))
    body = m.body("body").id
    sites = [m.site(f"motor_{i}").id for i in range(4)]
    acts = [m.actuator(f"motor_{i}").id for i in range(4)]
    return {
        "mass": float(m.body_mass[body]),
        "inertia": m.body_inertia[body].copy(),
        "motor_xy": m.site_pos[sites, :2].copy(),
        "yaw_ratio": m.actuator_gear[acts, 5].copy(),
        "max_thrust": float(m.actuator_ctrlrange[acts[0], 1]),
        "motor_tau": float(m.actuator_dynprm[acts[0], 0]),
        "drag": m.numeric("drag").data.copy(),
        "point_time_constant": float(m.numeric("point_time_constant").data[0]),
        "point_max_accel": float(m.numeric("point_max_accel").data[0]),
    }


def _drone_spec(role: str, fidelity: str, mass: float | None = None) -> mujoco.MjSpec:
    """A new spec of one drone of `role` in `fidelity`, to attach to a scene; `mass` (kg), if
    given, replaces the file's, with the inertia scaled as drone_parameters(mass) gives it."""
    child = _drone_spec_template(role, fidelity).copy()  # a copy costs a twentieth of building one
    if mass is not None:
        params = drone_parameters(mass)
        body = child.body("body")
        body.mass = params["mass"]
        body.inertia = params["inertia"]
    return child


@lru_cache(maxsize=None)
def _drone_spec_template(role: str, fidelity: str) -> mujoco.MjSpec:
    child = mujoco.MjSpec.from_string(_drone_template_xml())
    child.material("role").rgba = ROLE_RGBA[role]
    if fidelity == "point":
        body = child.body("body")
        child.delete(child.joint("root"))
        for act in list(child.actuators):
            child.delete(act)
        for axis, name in ((0, "x"), (1, "y")):
            body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0 if axis == 0 else 0.0, 1.0 if axis == 1 else 0.0, 0.0])
            # a plain force (N) along the joint: physics.py sets it every controller tick, so
            # that the acceleration limit holds in every direction, not per axis
            child.add_actuator(name=f"f{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    return child


def wall_heights(flight_height: float) -> tuple[float, float]:
    """(obstacle, border) heights (m) of a scene whose drones hold `flight_height` (m)."""
    return max(OBSTACLE_HEIGHT, flight_height + OBSTACLE_HEADROOM), max(BORDER_HEIGHT, flight_height + OBSTACLE_HEADROOM)


def _add_box(world, name: str, center, half_xy, yaw: float, rgba, height: float) -> None:
    world.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[center[0], center[1], height / 2],
        size=[half_xy[0], half_xy[1], height / 2],
        quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
        rgba=rgba,
        group=GROUP_OBSTACLE,
    )


def _add_obstacles(spec: mujoco.MjSpec, layout: Layout, flight_height: float) -> None:
    """Obstacles coloured by origin (the layout's own, or placed at random), then the border."""
    world = spec.worldbody
    height, border_height = wall_heights(flight_height)
    first_random = len(layout.obstacles) - layout.n_random
    for k, o in enumerate(layout.obstacles):
        rgba = OBSTACLE_RGBA["random" if k >= first_random else "fixed"]
        if isinstance(o, Wall):
            o = o.as_box()
        if isinstance(o, Box):
            _add_box(world, f"obstacle_{k}", o.center, (o.size[0] / 2, o.size[1] / 2), o.yaw, rgba, height)
        elif isinstance(o, Cylinder):
            world.add_geom(
                name=f"obstacle_{k}",
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                pos=[o.center[0], o.center[1], height / 2],
                size=[o.radius, height / 2, 0],
                rgba=rgba,
                group=GROUP_OBSTACLE,
            )
    # The border: one thin box per boundary segment, just outside the flyable region.
    for k, (cx, cy, hx, hy, yaw) in enumerate(border_walls(layout.border())):
        _add_box(world, f"border_{k}", (cx, cy), (hx, hy), yaw, BORDER_RGBA, border_height)


def build_spec(scene: SceneSpec) -> mujoco.MjSpec:
    """The scene as an MjSpec (not compiled), for callers that want to edit it further."""
    layout = scene.layout
    spec = mujoco.MjSpec()
    spec.modelname = f"pursuit_{layout.name}_{scene.fidelity}"
    spec.option.timestep = scene.physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.visual.global_.offwidth = 1920
    spec.visual.global_.offheight = 1080
    spec.stat.center = [layout.width / 2, layout.height / 2, 0.5]
    spec.stat.extent = max(layout.width, layout.height)
    tex = spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=list(FLOOR_RGB[0]), rgb2=list(FLOOR_RGB[1]), width=512, height=512)
    mat = spec.add_material(name="floor")
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
    mat.texrepeat = [layout.width / 0.5, layout.height / 0.5]
    w = spec.worldbody
    w.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, pos=[layout.width / 2, layout.height / 2, 0], size=[layout.width / 2 + 0.5, layout.height / 2 + 0.5, 0.05], material="floor", group=0)
    w.add_light(name="sun", pos=[layout.width / 2, layout.height / 2, 6.0], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    cx, cy = layout.width / 2, layout.height / 2
    fovy = 45.0
    top_z = 0.55 * max(layout.height, layout.width * 3 / 4) / math.tan(math.radians(fovy / 2)) + 0.2
    w.add_camera(name="top", pos=[cx, cy, top_z], quat=[1, 0, 0, 0], fovy=fovy)
    tilt = math.radians(50)
    w.add_camera(name="angled", pos=[cx, cy - 0.9 * top_z * math.sin(tilt) - 0.6, 0.9 * top_z * math.cos(tilt) + 0.6], quat=[math.cos(tilt / 2), math.sin(tilt / 2), 0, 0], fovy=fovy)
    _add_obstacles(spec, layout, scene.flight_height)
    used = len(layout.obstacles) + len(layout.border())
    if scene.obstacle_slots and used > scene.obstacle_slots:
        raise ValueError(f"layout {layout.source}: {used} obstacle and border geoms exceed {scene.obstacle_slots} slots")
    # Padding: collidable (so the static BVH has the same size in every world) but far
    # below the floor, where nothing can reach it; static-static pairs are never tested.
    for k in range(max(0, scene.obstacle_slots - used)):
        w.add_geom(name=f"unused_{k}", type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=[-10.0 - k, -10.0, -10.0], size=[0.01, 0, 0], group=5)
    names = drone_names(scene.n_pursuers, scene.n_evaders)
    for i, name in enumerate(names):
        role = name.split("_")[0]
        # default positions on a row (reset places drones at their spawn points)
        frame = w.add_frame(pos=[0.3 + 0.3 * i, 0.3, scene.flight_height if scene.fidelity == "point" else 0.0])
        if scene.fidelity == "point":
            frame.pos = [0.0, 0.0, scene.flight_height]
        spec.attach(_drone_spec(role, scene.fidelity, scene.drone_mass), prefix=f"{name}/", frame=frame)
        sensor = spec.add_sensor(name=f"{name}/contact", type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_GEOM, objname=f"{name}/collision")
        sensor.intprm[0] = 1  # data: "found" (number of contacts)
        sensor.intprm[2] = 1  # num: one slot
    return spec


def build_model(scene: SceneSpec) -> mujoco.MjModel:
    """Compile the scene; raises ValueError naming the layout if MuJoCo refuses it."""
    spec = build_spec(scene)
    try:
        return spec.compile()
    except Exception as exc:  # mujoco raises its own error types from the compiler
        raise ValueError(f"layout {scene.layout.source}: MuJoCo could not compile the scene: {exc}") from exc


@dataclasses.dataclass(frozen=True)
class DroneIds:
    """Indices into the model's arrays, looked up once; each array has shape (n_drones, ...)."""

    names: tuple[str, ...]
    body: np.ndarray  # (D,) body ids
    qpos_adr: np.ndarray  # (D,) first qpos index of each drone's joint(s)
    qvel_adr: np.ndarray  # (D,) first qvel index
    ctrl_adr: np.ndarray  # (D,) first actuator index (4 motors, or the forces fx fy)
    contact_adr: np.ndarray  # (D,) sensordata index of each contact sensor
    collision_geom: np.ndarray  # (D,) geom id of each collision volume

    @staticmethod
    def lookup(model: mujoco.MjModel, names: list[str], fidelity: str) -> "DroneIds":
        first_joint = "root" if fidelity == "quadrotor" else "x"
        first_act = "motor_0" if fidelity == "quadrotor" else "fx"
        joints = [model.joint(f"{n}/{first_joint}") for n in names]
        return DroneIds(
            names=tuple(names),
            body=np.array([model.body(f"{n}/body").id for n in names]),
            qpos_adr=np.array([model.jnt_qposadr[j.id] for j in joints]),
            qvel_adr=np.array([model.jnt_dofadr[j.id] for j in joints]),
            ctrl_adr=np.array([model.actuator(f"{n}/{first_act}").id for n in names]),
            contact_adr=np.array([model.sensor_adr[model.sensor(f"{n}/contact").id] for n in names]),
            collision_geom=np.array([model.geom(f"{n}/collision").id for n in names]),
        )
