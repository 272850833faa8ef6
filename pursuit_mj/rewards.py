"""Capture and collision rules, and the named reward terms (each scaled by config, logged alone).

Shapes: W worlds, N pursuers, M evaders; positions in the layout frame (m).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .config import TaskConfig
from .geometry import ObstacleSet, pairwise_line_of_sight, obstacle_distance

REWARD_TERMS = ("capture", "progress", "collision", "proximity", "spread")
PROGRESS_UNIT = 0.3  # m: progress is measured in units of 0.3 m, as in the reference study


@dataclasses.dataclass
class Events:
    """What happened in one step.

    new_captures (W, M) bool; collided (W, N) bool (the pursuer broke a clearance or touched
    something); obstacle_gap (W, N) m: centre distance to the nearest surface of `obstacles`
    (the layout's and the border; the env passes no caught evaders: touching one collides by
    contact, and no clearance is kept from it, its catcher being within capture_radius of it);
    nearest_mate (W, N) m: centre distance to the nearest teammate (inf if alone).
    """

    new_captures: np.ndarray
    collided: np.ndarray
    obstacle_gap: np.ndarray
    nearest_mate: np.ndarray


def pairwise_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(W, A, B) m between points a (W, A, 2) and b (W, B, 2)."""
    return np.linalg.norm(a[:, :, None, :] - b[:, None, :, :], axis=-1)


def detect_events(
    pursuer_pos: np.ndarray,
    evader_pos: np.ndarray,
    captured: np.ndarray,
    pursuer_contacts: np.ndarray,
    obstacles: ObstacleSet,
    config: TaskConfig,
) -> Events:
    """Captures (a pursuer within capture_radius of a free evader, with no wall between them)
    and collisions.

    A pursuer collides when its centre comes closer than obstacle_clearance to an obstacle
    or the border, closer than teammate_clearance to another pursuer, or MuJoCo reports a
    contact of its collision volume (pursuer_contacts (W, N) bool). Distances are those of
    the positions given (the end of a decision step); contacts cover the whole step.
    """
    N = pursuer_pos.shape[1]
    d_pe = pairwise_distance(pursuer_pos, evader_pos)
    within = (d_pe <= config.capture_radius) & ~captured[:, None, :]  # (W, N, M)
    if within.any():  # not through a thin wall: one ray per pair, only in steps that may capture
        within &= pairwise_line_of_sight(pursuer_pos, evader_pos, obstacles)
    new_captures = within.any(axis=1)
    gap = obstacle_distance(pursuer_pos, obstacles)
    if N > 1:
        d_pp = pairwise_distance(pursuer_pos, pursuer_pos) + np.where(np.eye(N, dtype=bool), np.inf, 0.0)
        nearest = d_pp.min(-1)
    else:
        nearest = np.full(pursuer_pos.shape[:2], np.inf)
    collided = (gap < config.obstacle_clearance) | (nearest < config.teammate_clearance) | pursuer_contacts
    return Events(new_captures, collided, gap, nearest)


def nearest_free_distance(pursuer_pos: np.ndarray, evader_pos: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(W, N) m: each pursuer's distance to its nearest free evader (0 where none is free)."""
    d = np.where(free[:, None, :], pairwise_distance(pursuer_pos, evader_pos), np.inf)
    d = d.min(-1)
    return np.where(np.isfinite(d), d, 0.0)


def reward_terms(
    config: TaskConfig,
    events: Events,
    prev_pursuer_pos: np.ndarray,
    pursuer_pos: np.ndarray,
    evader_pos: np.ndarray,
    prev_evader_pos: np.ndarray,
    free_before: np.ndarray,
) -> dict[str, np.ndarray]:
    """The named terms, each (W, N) float32, already scaled by config.

    capture: capture_reward per evader caught this step, to every pursuer (team reward).
    progress: progress_reward * (d_prev - d) / 0.3, d the distance to the nearest evader
      that was free at the start of the step.
    collision: collision_penalty to every pursuer of a world where one collided (a
      collision fails the whole team).
    proximity: proximity_penalty * how far inside the soft zone (proximity_distance beyond
      the clearances) a pursuer is, to walls and teammates, in [0, 1] each.
    spread: spread_reward * min(1, distance to the nearest teammate / 1 m).
    """
    W, N = pursuer_pos.shape[:2]
    caught = events.new_captures.sum(-1).astype(np.float32)  # (W,)
    capture = np.broadcast_to(config.capture_reward * caught[:, None], (W, N))
    d_prev = nearest_free_distance(prev_pursuer_pos, prev_evader_pos, free_before)
    d_now = nearest_free_distance(pursuer_pos, evader_pos, free_before)
    progress = config.progress_reward * (d_prev - d_now) / PROGRESS_UNIT
    failed = events.collided.any(-1)
    collision = np.broadcast_to(config.collision_penalty * failed[:, None], (W, N))
    pd = max(config.proximity_distance, 1e-9)
    wall_zone = np.clip(1.0 - (events.obstacle_gap - config.obstacle_clearance) / pd, 0.0, 1.0)
    mate_zone = np.clip(1.0 - (events.nearest_mate - config.teammate_clearance) / pd, 0.0, 1.0)
    proximity = config.proximity_penalty * (wall_zone + mate_zone)
    spread = config.spread_reward * np.minimum(1.0, np.where(np.isfinite(events.nearest_mate), events.nearest_mate, 1.0))
    terms = {"capture": capture, "progress": progress, "collision": collision, "proximity": proximity, "spread": spread}
    return {k: np.asarray(v, dtype=np.float32) + np.float32(0.0) for k, v in terms.items()}  # + 0: no -0.0 from a negative scale
