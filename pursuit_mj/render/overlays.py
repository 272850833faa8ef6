"""Decorations drawn into the MuJoCo scene to explain a chase: what each pursuer perceives and does.

Per frame, from a `Snapshot` (pursuit_mj.env) and the recent trail of every drone:
perception circles (or field-of-view wedges), cut short where walls and obstacles block the
pursuer's line of sight, a solid line from a pursuer to each evader it
sees and a dashed one to each it knows only by relay, short fading trails, the capture
radius around every evader (filled once captured), a role-coloured disc under each drone
that tilts with its body, and a line along every wall or box too thin for the frame to show.
Lines are MuJoCo line geoms (width in pixels), so they stay crisp at any camera distance.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from ..geometry import ObstacleSet, cast_rays
from ..palette import OBSTACLE_RGBA, ROLE_RGBA, over_floor, rgb255
from ..sensing import CAUGHT_BODY_RADIUS
from .caption import KeyEntry

_EYE = np.eye(3).ravel()
_LINE = mujoco.mjtGeom.mjGEOM_LINE


@dataclasses.dataclass(frozen=True)
class OverlayStyle:
    """Colours (RGBA 0-1), line widths (pixels) and sizes (m) of the decorations."""

    perception_rgba: tuple = (0.15, 0.45, 0.95, 0.45)
    seen_rgba: tuple = (1.0, 0.75, 0.05, 0.95)
    relayed_rgba: tuple = (1.0, 0.75, 0.05, 0.6)
    capture_rgba: tuple = (0.95, 0.25, 0.15, 0.8)
    captured_fill_rgba: tuple = (0.35, 0.35, 0.35, 0.55)
    line_width: float = 2.0
    ring_width: float = 1.5
    trail_width: float = 2.5
    marker_radius: float = 0.1  # m: role disc under each drone, bigger than the 9 cm frame
    marker_alpha: float = 0.6
    circle_segments: int = 64  # a 2 m circle is then within 2.5 mm of round (24 showed facets at 1280 x 720)
    sight_segments: int = 128  # rays of a full ring of sight cut at walls (64 left 11 cm between rays 2 m out)
    trail_segments: int = 400  # a trail is drawn through at most this many + 1 of its points (every step up to 400)
    dash_length: float = 0.1  # m
    thin_obstacle_width: float = 2.0  # px: the line along a wall or box too thin to show by itself


def _rgba(c) -> np.ndarray:
    return np.asarray(c, dtype=np.float32)


class GeomWriter:
    """Appends decoration geoms to an MjvScene after mjv_updateScene has filled it."""

    def __init__(self, scene: mujoco.MjvScene):
        self.scene = scene
        self._geoms = scene.geoms

    def _next(self) -> mujoco.MjvGeom:
        i = self.scene.ngeom
        if i >= self.scene.maxgeom:
            raise RuntimeError(f"render overlays need more than {self.scene.maxgeom} scene geoms")
        self.scene.ngeom = i + 1
        return self._geoms[i]

    def line(self, a: np.ndarray, b: np.ndarray, rgba: np.ndarray, width: float) -> None:
        """A line from a (3,) to b (3,) m world, width in pixels."""
        g = self._next()
        mujoco.mjv_initGeom(g, _LINE, np.zeros(3), np.zeros(3), _EYE, rgba)
        mujoco.mjv_connector(g, _LINE, width, a, b)
        g.castshadow = 0

    def polyline(self, pts: np.ndarray, rgba: np.ndarray, width: float, fade: bool = False) -> None:
        """Connected lines through pts (P, 3) m; with fade, alpha rises from 0 to rgba's along the path."""
        n = len(pts) - 1
        for k in range(n):
            c = rgba
            if fade:
                c = rgba.copy()
                c[3] *= (k + 1) / n
            self.line(pts[k], pts[k + 1], c, width)

    def dashed(self, a: np.ndarray, b: np.ndarray, rgba: np.ndarray, width: float, dash: float) -> None:
        """A dashed line a -> b (3,) m: dashes and gaps of `dash` m each."""
        length = float(np.linalg.norm(b - a))
        n = max(1, int(length / dash))
        for k in range(0, n, 2):
            self.line(a + (b - a) * (k / n), a + (b - a) * (min(k + 1, n) / n), rgba, width)

    def disc(self, center: np.ndarray, radius: float, rgba: np.ndarray, mat: np.ndarray = _EYE, thickness: float = 0.002) -> None:
        """A flat disc (thin cylinder) of `radius` m at center (3,), oriented by mat (9,) row-major."""
        g = self._next()
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_CYLINDER, np.array([radius, thickness, 0.0]), np.asarray(center, float), np.asarray(mat, float), rgba)
        g.castshadow = 0


def arc_points(center: np.ndarray, radius: float, start: float, stop: float, segments: int) -> np.ndarray:
    """(segments + 1, 3) points, m world, on a horizontal arc of `radius` m about center (3,) m
    from angle start to stop (rad, from world +x) at center's height."""
    a = np.linspace(start, stop, segments + 1)
    pts = np.empty((segments + 1, 3))
    pts[:, 0] = center[0] + radius * np.cos(a)
    pts[:, 1] = center[1] + radius * np.sin(a)
    pts[:, 2] = center[2]
    return pts


def sight_outline(center: np.ndarray, heading: float, radius: float, fov: float, obstacles: ObstacleSet, ring_segments: int) -> np.ndarray:
    """The outline (P, 3) m world, at center's height, of what a pursuer at center (3,) can see:
    its wedge of `fov` rad around `heading` (rad), or its ring for a full view, of `radius` m,
    each arc point (ring_segments + 1 round a full ring, the wedge's share of them, at least 5)
    pulled in to where the ray toward it meets an obstacle or the border (the line of sight the
    task checks). A wedge starts and ends at center; a ring is closed (its last point is its first)."""
    full = fov >= 2 * math.pi - 1e-9
    segments = ring_segments if full else max(4, int(ring_segments * fov / (2 * math.pi)))
    start, stop = (0.0, 2 * math.pi) if full else (heading - fov / 2, heading + fov / 2)
    arc = arc_points(center, radius, start, stop, segments)
    rel = arc[:, :2] - center[:2]
    dirs = rel / radius
    reach = np.minimum(cast_rays(np.broadcast_to(center[:2], dirs.shape), dirs, obstacles), radius)
    arc[:, :2] = center[:2] + dirs * reach[:, None]
    return arc if full else np.concatenate([center[None], arc, center[None]])


def draw_perception(w: GeomWriter, snap, style: OverlayStyle) -> None:
    """Perception ring (full field of view) or wedge per pursuer, cut at walls and caught evaders;
    nothing in full observability.

    Outlines only: with the default 2 m radius the circles cover most of the arena, and
    filled ones would wash it out."""
    cfg = snap.config
    if cfg.observability == "full":
        return
    r, fov = cfg.perception_radius, cfg.field_of_view
    ring = _rgba(style.perception_rgba)
    obstacles = snap.layout.obstacle_set()
    if snap.captured.any():  # a caught evader blocks sight as the drone it is, as in the task's perception
        obstacles = obstacles.with_extra_cylinders(np.asarray(snap.evader_pos)[:, :2], CAUGHT_BODY_RADIUS, snap.captured)
    for i, p in enumerate(snap.pursuer_pos):
        w.polyline(sight_outline(p, float(snap.heading[i]), r, fov, obstacles, style.sight_segments), ring, style.ring_width)


def draw_detections(w: GeomWriter, snap, style: OverlayStyle) -> None:
    """Solid line pursuer -> evader for a direct sighting, dashed for a relayed one."""
    seen, known, captured = snap.seen, snap.known, snap.captured
    relayed = known & ~seen & ~captured[None, :]
    c_seen, c_rel = _rgba(style.seen_rgba), _rgba(style.relayed_rgba)
    for i, j in zip(*np.nonzero(seen)):
        w.line(snap.pursuer_pos[i], snap.evader_pos[j], c_seen, style.line_width)
    for i, j in zip(*np.nonzero(relayed)):
        w.dashed(snap.pursuer_pos[i], snap.evader_pos[j], c_rel, style.line_width, style.dash_length)


def draw_capture_zones(w: GeomWriter, snap, style: OverlayStyle) -> None:
    """The capture radius around each evader: a ring while free, a grey disc once captured."""
    r = snap.config.capture_radius
    ring, fill = _rgba(style.capture_rgba), _rgba(style.captured_fill_rgba)
    for j, p in enumerate(snap.evader_pos):
        w.polyline(arc_points(p, r, 0.0, 2 * math.pi, style.circle_segments // 2), ring, style.ring_width)  # 0.3 m: 32 do
        if snap.captured[j]:
            w.disc(p - [0, 0, 0.01], r, fill)


#: a drone's role disc is at least this share of the arena's longer side across (radius), so a
#: drone stays visible in a large arena: 50 m wide, 0.5 m (about 9 px across at 640 x 480) where the 0.1 m disc
#: was about 1 px; the built-in arenas (5 m at most) keep style.marker_radius
MARKER_SHARE = 1 / 100


def marker_radius(layout, style: OverlayStyle) -> float:
    """The role disc's radius (m) in `layout`'s arena: style.marker_radius, or more in a large arena."""
    return max(style.marker_radius, MARKER_SHARE * max(layout.width, layout.height))


def draw_markers(w: GeomWriter, snap, style: OverlayStyle) -> None:
    """A translucent role-coloured disc under every drone, tilted with its body (`marker_radius`)."""
    radius = marker_radius(snap.layout, style)
    for role, pos, quat in (("pursuer", snap.pursuer_pos, snap.pursuer_quat), ("evader", snap.evader_pos, snap.evader_quat)):
        c = _rgba(ROLE_RGBA[role])
        c[3] = style.marker_alpha
        mat = np.empty(9)
        for p, q in zip(pos, quat):
            mujoco.mju_quat2Mat(mat, np.asarray(q, float))
            w.disc(p, radius, c, mat, thickness=0.001)


def trail_points(trails: np.ndarray, style: OverlayStyle) -> np.ndarray:
    """The points (P, D, 3) m world a trail is drawn through: all of trails (T, D, 3) up to
    style.trail_segments segments, evenly thinned beyond (each geom is a draw call), the
    oldest and the newest point always among them."""
    segments = len(trails) - 1
    if segments <= style.trail_segments:
        return trails
    keep = np.unique(np.round(np.linspace(0, segments, style.trail_segments + 1)).astype(np.int64))
    return trails[keep]


def draw_trails(w: GeomWriter, trails: np.ndarray, n_pursuers: int, style: OverlayStyle) -> None:
    """Fading trail per drone; trails (T, D, 3) m world, oldest first, drones in scene order."""
    if len(trails) < 2:
        return
    pts = trail_points(trails, style)
    for d in range(trails.shape[1]):
        c = _rgba(ROLE_RGBA["pursuer" if d < n_pursuers else "evader"])
        w.polyline(pts[:, d], c, style.trail_width, fade=True)


#: walls and boxes narrower than this share of the arena's longer side get a line along them (a
#: 3.6 x 5 m arena: under 4.2 cm, about 3 px at 640 x 480; the built-in walls, 5-6 cm, do not)
THIN_OBSTACLE_SHARE = 1 / 120


def thin_obstacle_segments(layout) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """(start (2,), end (2,) m, random?) of the long axis of each wall or box of `layout` narrower
    than THIN_OBSTACLE_SHARE of its arena's longer side: drawn by MuJoCo alone, one under a pixel
    wide falls between pixel centres and vanishes from the frame, depending on where it lies."""
    from ..layout import Box, Wall

    limit = THIN_OBSTACLE_SHARE * max(layout.width, layout.height)
    first_random = len(layout.obstacles) - layout.n_random
    out = []
    for k, o in enumerate(layout.obstacles):
        box = o.as_box() if isinstance(o, Wall) else o
        if not isinstance(box, Box) or min(box.size) >= limit:
            continue
        along = 0 if box.size[0] >= box.size[1] else 1  # the long side's axis in the box's frame
        yaw = box.yaw + along * math.pi / 2
        half = box.size[along] / 2 * np.array([math.cos(yaw), math.sin(yaw)])
        out.append((np.asarray(box.center) - half, np.asarray(box.center) + half, k >= first_random))
    return out


def draw_thin_obstacles(w: GeomWriter, snap, style: OverlayStyle) -> None:
    """A line (style.thin_obstacle_width px) along the top of every thin wall or box
    (`thin_obstacle_segments`), in its obstacle colour, so that it shows at any scale."""
    from ..scene import wall_heights

    top = wall_heights(snap.config.flight_height)[0]
    for a, b, random in thin_obstacle_segments(snap.layout):
        c = _rgba(OBSTACLE_RGBA["random" if random else "fixed"])
        w.line(np.array([a[0], a[1], top]), np.array([b[0], b[1], top]), c, style.thin_obstacle_width)


def overlay_geom_budget(config, layout, style: OverlayStyle) -> int:
    """An upper bound on the geoms `draw_all` adds for `config`'s team in `layout`'s arena.

    The dashed relay lines are the only part that grows with distance, so the arena's
    diagonal (plus a metre for a drone that has left it) bounds them."""
    n_p, n_e = config.n_pursuers, config.n_evaders
    perception = n_p * (max(style.sight_segments, 4) + 2)  # a wedge's arc plus its two sides
    capture = n_e * (style.circle_segments // 2 + 1)  # the ring plus the captured fill
    trails = (n_p + n_e) * (style.trail_segments + 1)
    longest = math.hypot(layout.width, layout.height) + 1.0
    per_pair = int(longest / style.dash_length) // 2 + 1  # a sighting is one line, a relay at most this many dashes
    markers = n_p + n_e
    thin = len(layout.obstacles)  # at most a line per obstacle
    return perception + capture + trails + n_p * n_e * per_pair + markers + thin


def draw_all(scene: mujoco.MjvScene, snap, trails: np.ndarray, style: OverlayStyle) -> None:
    """Every decoration of one frame (see module docstring)."""
    w = GeomWriter(scene)
    draw_thin_obstacles(w, snap, style)
    draw_perception(w, snap, style)
    draw_capture_zones(w, snap, style)
    draw_trails(w, trails, len(snap.pursuer_pos), style)
    draw_detections(w, snap, style)
    draw_markers(w, snap, style)


def key_entries(snap, style: OverlayStyle) -> list[KeyEntry]:
    """The colour key of a frame of `snap`: what the marks drawn for its task mean.

    Only what the task can show is listed: no sight ring or relayed line in full
    observability (every pursuer sees every evader), no relayed line without shared
    detections or a teammate to relay them, no random obstacle where the layout has none.
    """
    cfg = snap.config
    entries = [KeyEntry("pursuer", rgb255(ROLE_RGBA["pursuer"]), "dot"), KeyEntry("evader", rgb255(ROLE_RGBA["evader"]), "dot")]
    partial = cfg.observability != "full"
    if partial:
        entries.append(KeyEntry("sight", rgb255(style.perception_rgba), "ring"))
    entries.append(KeyEntry("seen", rgb255(style.seen_rgba), "line"))
    if partial and cfg.share_detections and cfg.n_pursuers > 1:  # a lone pursuer has no one to relay to it
        entries.append(KeyEntry("relayed", rgb255(style.relayed_rgba), "dash"))
    entries.append(KeyEntry("capture", rgb255(style.capture_rgba), "ring"))
    entries.append(KeyEntry("caught", rgb255(over_floor(style.captured_fill_rgba)), "dot"))  # the filled capture disc, as seen
    layout = snap.layout
    if len(layout.obstacles) > layout.n_random:
        entries.append(KeyEntry("obstacle", rgb255(OBSTACLE_RGBA["fixed"]), "square"))
    if layout.n_random:
        entries.append(KeyEntry("random", rgb255(OBSTACLE_RGBA["random"]), "square"))
    return entries


class TrailBuffer:
    """The last `length` positions of every drone: (T, D, 3) m world, oldest first."""

    def __init__(self, length: int):
        if length < 0:
            raise ValueError(f"trail length: {length} must be >= 0 steps")
        self.length = length
        self._pts: list[np.ndarray] = []

    def clear(self) -> None:
        self._pts.clear()

    def push(self, pos: np.ndarray) -> None:
        """Add one sample, pos (D, 3) m world."""
        if self.length == 0:
            return
        self._pts.append(np.array(pos, dtype=float))
        if len(self._pts) > self.length:
            self._pts.pop(0)

    def array(self) -> np.ndarray:
        """The samples (T, D, 3) m world, oldest first ((0, 0, 3) before the first push)."""
        if not self._pts:
            return np.zeros((0, 0, 3))
        return np.stack(self._pts)
