"""Assemble per-pursuer observation vectors (index map in obs_spec.py) and the global state.

Used identically by the simulator and the real-flight bridge.
"""

from __future__ import annotations

import numpy as np

from .obs_spec import ObsSpec
from .sensing import Perception, WorldView


def build_observations(view: WorldView, perception: Perception, spec: ObsSpec) -> np.ndarray:
    """Observations (W, N, spec.dim) float32 from the true view and what each pursuer perceived.

    Hidden entities have every feature zero (visible flag 0).
    """
    W, N, _ = view.pursuer_pos.shape
    M = view.evader_pos.shape[1]
    obs = np.zeros((W, N, spec.dim), np.float32)
    p, v = view.pursuer_pos, view.pursuer_vel

    own = spec.group("self").view(obs)
    own[:, :, 0, 0:2] = p
    own[:, :, 0, 2:4] = v

    if N > 1:
        # teammate j of pursuer i, in order of index skipping i
        idx = np.array([[j for j in range(N) if j != i] for i in range(N)])  # (N, N-1)
        rows = np.arange(N)[:, None]
        vis = perception.teammate_visible[:, rows, idx]  # (W, N, N-1)
        rel_p = perception.teammate_pos_est[:, rows, idx] - p[:, :, None, :]
        rel_v = v[:, idx] - v[:, :, None, :]
        mates = spec.group("teammates").view(obs)
        mates[..., 0:2] = rel_p * vis[..., None]
        mates[..., 2:4] = rel_v * vis[..., None]
        mates[..., 4] = vis

    known = perception.known
    ev = spec.group("evaders").view(obs)
    rel = perception.evader_pos_est - p[:, :, None, :]
    ev[..., 0:2] = rel * known[..., None]
    ev[..., 2:4] = np.broadcast_to(view.evader_vel[:, None], (W, N, M, 2)) * (known & ~view.captured[:, None, :])[..., None]
    ev[..., 4] = known
    ev[..., 5] = known & ~perception.seen & ~view.captured[:, None, :]
    ev[..., 6] = view.captured[:, None, :]

    if spec.n_rays:
        spec.group("rays").view(obs)[:, :, 0, :] = perception.rays
    # resting drones report velocities of ~1e-40: denormal floats slow CPU matrix products
    # several-fold in any network that reads them, and mean nothing physically
    obs[np.abs(obs) < 1e-20] = 0.0
    return obs


def global_state_dim(n_pursuers: int, n_evaders: int) -> int:
    return 4 * n_pursuers + 5 * n_evaders + 1


def build_global_state(view: WorldView, time_fraction: np.ndarray) -> np.ndarray:
    """The centralised critic's input (W, 4N + 5M + 1) float32.

    Per pursuer x, y (m), vx, vy (m/s); per evader x, y, vx, vy, captured (0/1); then steps /
    max_steps (unitless). World (layout) frame; time_fraction (W,) is steps / max_steps.
    """
    W = view.pursuer_pos.shape[0]
    parts = [
        np.concatenate([view.pursuer_pos, view.pursuer_vel], -1).reshape(W, -1),
        np.concatenate([view.evader_pos, view.evader_vel, view.captured[..., None]], -1).reshape(W, -1),
        time_fraction[:, None],
    ]
    return np.concatenate(parts, -1).astype(np.float32)
