"""From the drones' layout-frame states to what the policy and the escape model see, with the simulator's code.

`FlightObserver` keeps the little state the simulator keeps between steps (each pursuer's
heading for the field of view, captured evaders) and calls the very functions
`PursuitEnv` calls: `sensing.perceive`, `observations.build_observations`, and the capture
rule of `rewards.detect_events`. One world (W = 1); N pursuers, M evaders; positions in m
and velocities in m/s, layout frame.
"""

from __future__ import annotations

import numpy as np

from ..config import TaskConfig
from ..evader_models import make_evader_model
from ..geometry import ObstacleSet
from ..layout import Layout
from ..obs_spec import ObsSpec
from ..observations import build_observations
from ..rewards import detect_events
from ..sensing import CAUGHT_BODY_RADIUS, INITIAL_HEADING, Perception, WorldView, heading_min_speed, perceive, update_heading


class FlightObserver:
    """Observations of one real (or virtual) world, step by step (module docstring)."""

    def __init__(self, config: TaskConfig, layout: Layout, seed: int = 0):
        self.config = config
        self.spec = ObsSpec.make(config.n_pursuers, config.n_evaders, config.n_rays)
        self.obstacles = ObstacleSet.stack([layout.obstacle_set()])
        self.heading = np.full((1, config.n_pursuers), INITIAL_HEADING)  # as the simulator starts
        self.captured = np.zeros((1, config.n_evaders), bool)
        self.rng = np.random.default_rng(seed)
        self.view: WorldView | None = None
        self.perception: Perception | None = None

    def obstacles_now(self, evader_pos: np.ndarray, radius: float = CAUGHT_BODY_RADIUS) -> ObstacleSet:
        """Virtual obstacles plus captured evaders as cylinders of `radius` (m), (1, ...) arrays:
        as the simulator has them, the drone's body for perception, the capture disc for the
        free evaders' escape."""
        if not self.captured.any():
            return self.obstacles
        return self.obstacles.with_extra_cylinders(evader_pos[None], radius, self.captured)

    def update_captures(self, pursuer_pos: np.ndarray, evader_pos: np.ndarray) -> np.ndarray:
        """Apply the simulator's capture rule; returns the evaders (M,) bool captured just now."""
        N = pursuer_pos.shape[0]
        events = detect_events(pursuer_pos[None], evader_pos[None], self.captured, np.zeros((1, N), bool), self.obstacles, self.config)
        new = events.new_captures[0]
        self.captured |= new[None]
        return new

    def observe(self, pursuer_pos: np.ndarray, pursuer_vel: np.ndarray, evader_pos: np.ndarray, evader_vel: np.ndarray) -> np.ndarray:
        """Observations (1, N, spec.dim) float32 from pursuer_pos/vel (N, 2) and evader_pos/vel (M, 2),
        m and m/s in the layout frame."""
        self.heading = update_heading(self.heading, pursuer_vel[None], heading_min_speed(self.config.pursuer_speed))
        self.view = WorldView(pursuer_pos[None], pursuer_vel[None], self.heading, evader_pos[None], evader_vel[None], self.captured.copy(), self.obstacles_now(evader_pos))
        self.perception = perceive(self.view, self.config, self.rng)
        return build_observations(self.view, self.perception, self.spec)


class EvaderPilot:
    """The task's evader model (evader.model) flying evader drones: desired velocities (M, 2) m/s, layout frame."""

    def __init__(self, config: TaskConfig, seed: int = 0):
        self.model = make_evader_model(config, 1, seed)
        self.model.reset(np.array([0]), np.array([seed]))
        self.dt = config.control_dt
        self.capture_radius = config.capture_radius

    def command(self, observer: FlightObserver, evader_pos: np.ndarray, evader_vel: np.ndarray,
                pursuer_pos: np.ndarray, pursuer_vel: np.ndarray) -> np.ndarray:
        """Desired velocities (M, 2) m/s of the evaders, layout frame (0 for caught ones), from
        evader_pos / evader_vel (M, 2) and pursuer_pos / pursuer_vel (N, 2), m and m/s in the
        layout frame (the lab's estimates already mapped by the alignment)."""
        active = ~observer.captured
        v = self.model.compute(evader_pos[None], evader_vel[None], pursuer_pos[None], pursuer_vel[None], active, observer.obstacles_now(evader_pos, self.capture_radius), self.dt)
        return np.where(active[..., None], v, 0.0)[0]
