"""What each pursuer perceives: range, field of view, line of sight, relayed detections, noise.

Pure functions over arrays (no MuJoCo): the simulator and the real-flight bridge call the
same code. Shapes: W worlds, N pursuers, M evaders, K rays; positions in the layout frame (m).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .config import DRONE_CONTACT_DISTANCE, TaskConfig
from .geometry import ObstacleSet, cast_fan, line_of_sight
from .randomness import WorldRandom


@dataclasses.dataclass
class WorldView:
    """The true state that perception works from (one entry per world).

    pursuer_pos (W, N, 2) m; pursuer_vel (W, N, 2) m/s; pursuer_heading (W, N) rad (the
    direction the pursuer faces, for the field of view); evader_pos (W, M, 2) m;
    evader_vel (W, M, 2) m/s; captured (W, M) bool; obstacles: ObstacleSet with (W, ...)
    arrays, border included (captured evaders may be added as cylinders).
    """

    pursuer_pos: np.ndarray
    pursuer_vel: np.ndarray
    pursuer_heading: np.ndarray
    evader_pos: np.ndarray
    evader_vel: np.ndarray
    captured: np.ndarray
    obstacles: ObstacleSet


@dataclasses.dataclass
class Perception:
    """Who knows what, per pursuer.

    seen (W, N, M) bool: evader detected directly this step; known (W, N, M): seen directly
    or relayed by a teammate (share_detections) or captured; teammate_visible (W, N, N) bool
    (diagonal False; every teammate with share_teammates); evader_pos_est (W, N, M, 2) m and
    teammate_pos_est (W, N, N, 2) m: the positions as perceived (with noise when
    position_noise > 0, except teammates' own broadcast positions and caught evaders, known
    where they stopped); rays (W, N, K) m.
    """

    seen: np.ndarray
    known: np.ndarray
    teammate_visible: np.ndarray
    evader_pos_est: np.ndarray
    teammate_pos_est: np.ndarray
    rays: np.ndarray


#: the TaskConfig keys that shape what a pursuer perceives (and nothing else of the task)
PERCEPTION_KEYS = ("observability", "perception_radius", "field_of_view", "share_detections",
                   "share_teammates", "position_noise", "miss_probability")

#: privileged views a teacher can be given in training (train/imitation.py): name -> changes
PRIVILEGED_VIEWS = {
    "all_round": {"field_of_view": 2 * np.pi, "position_noise": 0.0, "miss_probability": 0.0},
    "full": {"observability": "full", "position_noise": 0.0, "miss_probability": 0.0},
}


def privileged_config(config: TaskConfig, view: str) -> TaskConfig:
    """config with the perception of a privileged `view` ('same' returns config itself).

    all_round: the same radius and line of sight, but a 360 deg view, exact positions and no
    missed detections; full: every entity known, exactly (full observability).
    """
    if view == "same":
        return config
    if view not in PRIVILEGED_VIEWS:
        raise ValueError(f"privileged view {view!r}: not one of same, {', '.join(PRIVILEGED_VIEWS)}")
    return dataclasses.replace(config, **PRIVILEGED_VIEWS[view])


#: a pursuer faces +y (into the arena) at the start of an episode
INITIAL_HEADING = np.pi / 2
HEADING_MIN_SPEED = 0.05  # m/s: below this a pursuer keeps its previous heading (see heading_min_speed)
# m: a caught evader blocks sight and range readings as the drone it is: its collision volume,
# arms and propellers, half of DRONE_CONTACT_DISTANCE (0.0685 m; a pursuer that comes closer
# touches it and collides), not its capture disc, which holds the pursuer that caught it:
# from inside, every ray and line of sight would be blocked at once
CAUGHT_BODY_RADIUS = DRONE_CONTACT_DISTANCE / 2


def heading_min_speed(pursuer_speed: float) -> float:
    """The speed (m/s) above which a pursuer of max speed `pursuer_speed` (m/s) faces where it flies.

    HEADING_MIN_SPEED, or half the max speed for pursuers slower than 0.1 m/s: with a fixed
    floor, pursuers whose max speed is 0.05 m/s or less would face their start heading forever.
    """
    return min(HEADING_MIN_SPEED, 0.5 * pursuer_speed)


def update_heading(heading: np.ndarray, velocity: np.ndarray, min_speed: float) -> np.ndarray:
    """The direction each pursuer faces (..., N) rad: along its velocity (..., N, 2) m/s when
    faster than min_speed (m/s, `heading_min_speed` of the task), else the previous heading."""
    speed = np.hypot(velocity[..., 0], velocity[..., 1])
    return np.where(speed > min_speed, np.arctan2(velocity[..., 1], velocity[..., 0]), heading)


@functools.lru_cache(maxsize=None)
def ray_directions(n_rays: int) -> np.ndarray:
    """Unit directions (K, 2): ray i at angle 2*pi*i/K from world +x (shared, read only)."""
    a = 2 * np.pi * np.arange(n_rays) / max(n_rays, 1)
    out = np.stack([np.cos(a), np.sin(a)], -1)
    out.flags.writeable = False
    return out


def _visible(observer: np.ndarray, heading: np.ndarray, target: np.ndarray, config: TaskConfig, obstacles: ObstacleSet) -> np.ndarray:
    """(W, N, T) bool: each observer's own targets (W, N, T, 2) within perception_radius of the
    observer (W, N, 2), inside its field of view (heading (W, N) rad) and in its line of sight
    (one ray cast for all)."""
    delta = target - observer[:, :, None, :]  # (W, N, T, 2)
    dist = np.hypot(delta[..., 0], delta[..., 1])
    ok = dist <= config.perception_radius
    if config.field_of_view < 2 * np.pi - 1e-9:
        ang = np.arctan2(delta[..., 1], delta[..., 0]) - heading[:, :, None]
        ang = (ang + np.pi) % (2 * np.pi) - np.pi
        ok &= np.abs(ang) <= config.field_of_view / 2
    W, N, T = ok.shape
    a = np.broadcast_to(observer[:, :, None, :], target.shape).reshape(W, N * T, 2)
    return ok & line_of_sight(a, target.reshape(W, N * T, 2), obstacles).reshape(W, N, T)


@functools.lru_cache(maxsize=None)
def _others(N: int) -> np.ndarray:
    """(N, N-1) indices: pursuer i's teammates, in order of index skipping i (shared, read only)."""
    out = np.array([[j for j in range(N) if j != i] for i in range(N)], dtype=np.int64).reshape(N, max(N - 1, 0))
    out.flags.writeable = False
    return out


def perceive(view: WorldView, config: TaskConfig, rng: np.random.Generator | WorldRandom) -> Perception:
    """Apply perception radius, field of view, line of sight, missed detections, sharing and noise.

    With share_teammates every teammate is known at its true position (its own broadcast),
    whatever the radius, view, walls and position_noise; evaders are perceived as without it.

    In `full` observability every entity is known exactly (no masking, misses or noise). `rng`
    draws the misses and the noise (arrays with worlds first, in a fixed order whatever the
    miss probability): the simulator passes a `WorldRandom` so that each world's draws depend
    on its own episode and step only.
    """
    W, N, _ = view.pursuer_pos.shape
    M = view.evader_pos.shape[1]
    K = config.n_rays
    p = view.pursuer_pos
    partial = config.observability == "partial"
    # K range rays per pursuer (fixed directions: a fan), then (partial observability) what
    # each pursuer sees of every evader and every teammate
    rays = np.minimum(cast_fan(p, ray_directions(K), view.obstacles), config.ray_range)
    if partial:
        # each pursuer's lines of sight to every evader and (unless they broadcast, which makes
        # them known anyway) to every teammate but itself: N (M + N - 1) rays, or N M
        evaders = np.broadcast_to(view.evader_pos[:, None], (W, N, M, 2))
        others = _others(N) if not config.share_teammates else np.zeros((N, 0), np.int64)
        targets = np.concatenate([evaders, p[:, others]], axis=2)  # (W, N, M + T, 2)
        visible = _visible(p, view.pursuer_heading, targets, config, view.obstacles)
        seen = visible[..., :M]
        mates = np.zeros((W, N, N), bool)
        mates[:, np.arange(N)[:, None], others] = visible[..., M:]
        # drawn at any miss_probability, so that the noise below keeps its numbers (observe_as);
        # at 0 every draw is >= 0 and none is missed: a WorldRandom only counts the draw then
        if config.miss_probability > 0 or not isinstance(rng, WorldRandom):
            seen &= rng.random((W, N, M)) >= config.miss_probability
        else:
            rng.skip((W, N, M))
    else:
        seen = np.ones((W, N, M), bool)
        mates = np.ones((W, N, N), bool)
    seen &= ~view.captured[:, None, :]
    known = seen.copy()
    if config.share_detections or not partial:
        known |= seen.any(axis=1, keepdims=True)
    known |= view.captured[:, None, :]
    if config.share_teammates:  # each pursuer knows its own position and broadcasts it
        mates = np.ones((W, N, N), bool)
    mates &= ~np.eye(N, dtype=bool)[None]

    evader_est = np.broadcast_to(view.evader_pos[:, None], (W, N, M, 2)).copy()
    mate_est = np.broadcast_to(p[:, None], (W, N, N, 2)).copy()
    if config.position_noise > 0 and partial:
        # one independent draw per (observer, target), relayed detections included (not the
        # noise of the teammate that saw it): simple, and identical in both fidelities
        evader_est += rng.normal(0.0, config.position_noise, evader_est.shape)
        # a caught evader stands where its capture was reported: known exactly, no fresh jitter
        evader_est = np.where(view.captured[:, None, :, None], view.evader_pos[:, None], evader_est)
        mate_noise = rng.normal(0.0, config.position_noise, mate_est.shape)  # drawn either way: the same evader noise
        if not config.share_teammates:
            mate_est += mate_noise
    return Perception(seen, known, mates, evader_est, mate_est, rays)
