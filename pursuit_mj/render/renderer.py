"""Offscreen frames of a pursuit scene: drone poses in, an RGB image (H, W, 3) uint8 out.

`SceneRenderer` owns one GL context and builds its own MjModel from each layout it is given
(random obstacles give each episode its own layout), with the same scene generator as the
simulation. It poses the drones from arrays (so it renders live worlds and recorded ones
alike), runs only MuJoCo's kinematics on a private MjData (never the simulation's), lets a
caller add decoration geoms, and reads the pixels.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import mujoco
import numpy as np

from ..config import TaskConfig
from ..layout import Layout
from ..scene import DroneIds, SceneSpec, build_model, drone_names
from .camera import CameraSpec
from .caption import band_height, key_band_height
from .gl import RenderBackendError, choose_backend, create_context

QUALITIES = ("fast", "high")
OVERLAY_GEOMS = 3000  # decoration geoms available per frame on top of the model's own, unless told
TOP_MARGIN = 0.15  # m of floor shown around the arena in the top view
FLOOR_GRID = 0.5  # m: rendering grid of the floor plane
ANGLED_TILT = math.radians(38)  # angled view: camera axis from the vertical, steep enough to see over walls


@dataclasses.dataclass(frozen=True)
class RenderSettings:
    """Image size (pixels), camera text ('top', 'angled', 'follow:<drone>'), quality, colour key.

    quality 'fast': no multisampling or shadows (software GL renders several times faster);
    'high': 4x multisampling, shadows and reflections. key: frames get a colour key band at
    the bottom (the top and angled views are framed clear of it).
    """

    width: int = 640
    height: int = 480
    camera: str = "top"
    quality: str = "fast"
    key: bool = True

    def bands(self) -> tuple[float, float]:
        """(top, bottom): the shares of the frame height that the caption and the key cover."""
        bottom = key_band_height(self.height) if self.key else 0
        return band_height(self.height) / self.height, bottom / self.height

    def check(self, model: mujoco.MjModel, prefix: str = "--") -> None:
        """Raise ValueError naming the setting if the size or quality cannot be rendered; `prefix`
        names where it came from ('--': render's flags, --width; 'render_settings.': a field)."""
        for name, value, limit in (("width", self.width, model.vis.global_.offwidth), ("height", self.height, model.vis.global_.offheight)):
            if not isinstance(value, int) or not 16 <= value <= limit:
                raise ValueError(f"{prefix}{name} {value}: must be an integer in 16..{limit} pixels")
        caption, key = band_height(self.height), (key_band_height(self.height) if self.key else 0)
        if caption + key >= self.height:  # the cameras frame the arena between the bands: no room would be left
            bands = f"the caption band ({caption} px) and the colour key ({key} px)" if key else f"the caption band ({caption} px)"
            no_key = "--no-key" if prefix == "--" else f"{prefix}key False"
            raise ValueError(f"{prefix}height {self.height}: too small to hold {bands} and the scene between them; "
                             f"use {prefix}height {caption + key + 1} or more" + (f" (or {no_key})" if key else ""))
        if self.quality not in QUALITIES:
            raise ValueError(f"{prefix}quality {self.quality!r}: choose from {', '.join(QUALITIES)}")
        if not isinstance(self.key, bool):  # 'no' would draw the key
            raise ValueError(f"{prefix}key {self.key!r}: expected True or False")
        if not isinstance(self.camera, str):
            raise ValueError(f"{prefix}camera {self.camera!r}: expected text such as 'top', 'angled' or 'follow:p0'")


def check_settings(settings: RenderSettings, config: TaskConfig, layout: Layout, prefix: str = "--") -> None:
    """Refuse a bad size, quality or camera for the scenes of `config` (drones) and `layout`
    before any GL context is made; ValueError naming the setting with `prefix` (see check)."""
    model = build_model(SceneSpec.for_task(config, layout))
    settings.check(model, prefix)
    CameraSpec.parse(settings.camera, model, drone_names(config.n_pursuers, config.n_evaders), f"{prefix}camera")


DrawFn = Callable[[mujoco.MjvScene], None]
OverlayBudget = Callable[[Layout], int]  # decoration geoms a frame of this layout may add


@dataclasses.dataclass
class _Scene:
    """What drawing one layout's scene needs: its model, a private MjData for the drones' poses,
    the GL context made for the model, and the scene the frame is built in."""

    layout: Layout
    model: mujoco.MjModel
    data: mujoco.MjData
    context: mujoco.MjrContext
    scene: mujoco.MjvScene
    qpos_idx: np.ndarray  # (D, 2 or 7): each drone's qpos entries


class SceneRenderer:
    """Renders the drones of `config` (pursuers then evaders, its fidelity) in scenes of any layout.

    overlay_geoms: how many decoration geoms a `draw` callback may add per frame, for each
    layout bound (default OVERLAY_GEOMS whatever the layout). keep_scenes: how many scenes (model
    and GL context) stay made, the most recently bound ones, so that going back to one is free
    (one drawer of several worlds, each with its random obstacles); 1 frees each when another is bound.
    """

    def __init__(self, settings: RenderSettings, config: TaskConfig, layout: Layout, overlay_geoms: OverlayBudget | None = None,
                 keep_scenes: int = 1):
        if isinstance(keep_scenes, bool) or not isinstance(keep_scenes, int) or keep_scenes < 1:
            raise ValueError(f"keep_scenes: expected an integer >= 1, got {keep_scenes!r}")
        self.config = config
        self._keep = keep_scenes
        self._kept: dict[int, _Scene] = {}  # id(layout) -> its scene, least recently bound first
        self._overlay_geoms = overlay_geoms or (lambda _layout: OVERLAY_GEOMS)
        self.names = drone_names(config.n_pursuers, config.n_evaders)
        self.fidelity = config.fidelity
        model = self._build(layout)
        settings.check(model)
        self.settings = settings
        self.camera_spec = CameraSpec.parse(settings.camera, model, self.names)
        self._gl = create_context(settings.width, settings.height)
        self._rect = mujoco.MjrRect(0, 0, settings.width, settings.height)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._bound: _Scene | None = None
        self._pixels = np.empty((settings.height, settings.width, 3), np.uint8)
        self._bind_model(model, layout)

    # ------------------------------------------------------------------ model binding

    def _build(self, layout: Layout) -> mujoco.MjModel:
        return build_model(SceneSpec.for_task(self.config, layout))

    def bind(self, layout: Layout) -> None:
        """Draw the scene of `layout` from now on; free when it is the layout bound, or a kept one."""
        if self._bound is not None and layout is self._bound.layout:
            return
        kept = self._kept.pop(id(layout), None)
        if kept is not None and kept.layout is layout:
            self._kept[id(layout)] = kept  # the most recent now
            self._gl.make_current()
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, kept.context)
            self._bound = kept
            return
        self._bind_model(self._build(layout), layout)

    def _bind_model(self, m: mujoco.MjModel, layout: Layout) -> None:
        high = self.settings.quality == "high"
        m.vis.quality.offsamples = 4 if high else 0
        m.vis.quality.shadowsize = 2048 if high else 0
        # the scene's overhead light plus MuJoCo's headlight saturate top faces; soften both
        m.vis.headlight.ambient[:] = 0.3
        m.vis.headlight.diffuse[:] = 0.3
        m.vis.headlight.specular[:] = 0.0
        m.light_diffuse[:] = np.minimum(m.light_diffuse, 0.5)
        # a plane's third size is its rendering grid spacing; the scene's fine grid costs a
        # software renderer several ms per frame and adds nothing under a uniform light
        planes = m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
        m.geom_size[planes, 2] = np.maximum(m.geom_size[planes, 2], FLOOR_GRID)
        cameras = [m.camera(i).name for i in range(m.ncam)]
        if "top" in cameras:
            self._frame_top(m, layout)
        if "angled" in cameras:
            self._frame_angled(m, layout)
        self._gl.make_current()
        while self._kept and len(self._kept) >= self._keep:  # the least recently bound goes
            self._kept.pop(next(iter(self._kept))).context.free()
        self._bound = None
        try:
            context = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
        except mujoco.FatalError as exc:  # a context that was made but cannot draw (no GL 1.5 / framebuffer)
            raise RenderBackendError(f"the OpenGL context of backend {choose_backend()} cannot render MuJoCo scenes ({exc}); "
                                     f"set MUJOCO_GL to another of egl, osmesa") from None
        try:
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, context)
            scene = mujoco.MjvScene(m, maxgeom=m.ngeom + self._overlay_geoms(layout))
            scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = high
            scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = high
            ids = DroneIds.lookup(m, self.names, self.fidelity)
            width = 7 if self.fidelity == "quadrotor" else 2
            qpos_idx = ids.qpos_adr[:, None] + np.arange(width)  # (D, width)
            data = mujoco.MjData(m)
        except BaseException:
            context.free()  # not kept, so close() would not free it
            raise
        self._bound = _Scene(layout, m, data, context, scene, qpos_idx)
        self._kept[id(layout)] = self._bound

    def _frame_top(self, m: mujoco.MjModel, layout: Layout) -> None:
        """Make the 'top' camera an orthographic map of the arena, clear of the caption band."""
        W, H = self.settings.width, self.settings.height
        top, bottom = self.settings.bands()
        extent = max((layout.height + 2 * TOP_MARGIN) / (1.0 - top - bottom), (layout.width + 2 * TOP_MARGIN) * H / W)
        cam = m.camera("top").id
        m.cam_projection[cam] = mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC
        m.cam_fovy[cam] = extent  # the visible height (m) for an orthographic camera
        m.cam_pos[cam, :2] = (layout.width / 2, layout.height / 2 + (top - bottom) * extent / 2)  # centred between the bands

    def _frame_angled(self, m: mujoco.MjModel, layout: Layout) -> None:
        """Look at the arena centre from the south, tilted by ANGLED_TILT, far enough to see all of it."""
        W, H = self.settings.width, self.settings.height
        cam = m.camera("angled").id
        half_fov = math.radians(m.cam_fovy[cam]) / 2
        # the near (south) half is foreshortened least; fit the full depth and the width with margin
        need = max(layout.height * math.cos(ANGLED_TILT) + 1.2 * math.sin(ANGLED_TILT), layout.width * H / W)
        dist = 0.62 * need / math.tan(half_fov) / (1.0 - sum(self.settings.bands()))
        cx, cy = layout.width / 2, layout.height / 2
        m.cam_pos[cam] = (cx, cy - dist * math.sin(ANGLED_TILT), dist * math.cos(ANGLED_TILT))
        m.cam_quat[cam] = (math.cos(ANGLED_TILT / 2), math.sin(ANGLED_TILT / 2), 0.0, 0.0)

    @property
    def scene(self) -> mujoco.MjvScene:
        return self._bound.scene

    @property
    def model(self) -> mujoco.MjModel:
        """The bound layout's model (its cameras framed for these settings)."""
        return self._bound.model

    @property
    def data(self) -> mujoco.MjData:
        """The bound scene's private MjData, as the last pose() left it."""
        return self._bound.data

    # ------------------------------------------------------------------ frames

    def pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Place the drones: pos (D, 3) m world, quat (D, 4) w,x,y,z body->world (ignored in point fidelity)."""
        b = self._bound
        if self.fidelity == "quadrotor":
            b.data.qpos[b.qpos_idx] = np.concatenate([pos, quat], axis=-1)
        else:
            b.data.qpos[b.qpos_idx] = pos[:, :2]
        m, d = b.model, b.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_camlight(m, d)

    def render(self, pos: np.ndarray, quat: np.ndarray, draw: DrawFn | None = None) -> np.ndarray:
        """The frame (H, W, 3) uint8 for drones at pos (D, 3) m world / quat (D, 4) w,x,y,z body->world
        (as `pose`); `draw` adds decorations.

        The returned array is reused by the next call: copy it to keep it.
        """
        self.pose(pos, quat)
        b = self._bound
        self.camera_spec.apply(self._camera, b.model, pos)
        mujoco.mjv_updateScene(b.model, b.data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, b.scene)
        if draw is not None:
            draw(b.scene)
        self._gl.make_current()
        mujoco.mjr_render(self._rect, b.scene, b.context)
        mujoco.mjr_readPixels(self._pixels, None, self._rect, b.context)
        return self._pixels[::-1]

    def close(self) -> None:
        if self._kept:
            self._gl.make_current()
            for kept in self._kept.values():
                kept.context.free()
            self._kept.clear()
            self._bound = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> "SceneRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
