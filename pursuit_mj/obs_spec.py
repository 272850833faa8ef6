"""The index map of a pursuer's observation vector (DESIGN.md section 5).

A pursuer's observation is a flat float32 vector made of groups, in this order:

| group       | count  | width | features (SI units, layout frame)                                  |
|-------------|--------|-------|--------------------------------------------------------------------|
| `self`      | 1      | 4     | x, y (m), vx, vy (m/s)                                              |
| `teammates` | N - 1  | 5     | dx, dy (m, relative to self), dvx, dvy (m/s, relative), visible     |
| `evaders`   | M      | 7     | dx, dy (m, relative), vx, vy (m/s, absolute), visible, relayed, captured |
| `rays`      | 1      | K     | range (m) to the nearest wall/obstacle along K directions, ray i at |
|             |        |       | angle 2*pi*i/K from world +x, capped at ray_range                   |

With belief features (pursuit_mj.belief; `ObsSpec.make(..., belief=True)`), computed by the
policy from the pursuer's own observation history, two groups follow:

| group       | count  | width | features                                                            |
|-------------|--------|-------|---------------------------------------------------------------------|
| `memory`    | M      | 6     | dx, dy (m, estimated position relative to self), vx, vy (m/s, last  |
|             |        |       | known), age (s since known, capped), known                          |
| `goal`      | 1      | 3     | dx, dy (m, relative): the next waypoint of the coverage search,     |
|             |        |       | planned (1 when it lies on a path found around known walls)         |

Teammates come in ascending pursuer index, the observer left out (pursuer 1 of 4 sees 0, 2, 3);
evaders in their index order.
`visible` is 1 when the entity is known this step (seen directly, or for evaders relayed by
a teammate when share_detections is on); when 0 the entity's other values are zero.
`relayed` is 1 when an evader is known only through a teammate. `captured` is 1 for an
evader already caught (its other values then describe where it stopped, visible 1).
The same spec drives networks (per-entity encoders with masked pooling) and tests.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Group:
    """One block of the observation: `count` entities of `width` features from `start`."""

    name: str
    start: int
    count: int
    width: int
    mask_feature: int | None = None  # index within an entity of its 0/1 visibility flag
    features: tuple[str, ...] = ()

    @property
    def stop(self) -> int:
        return self.start + self.count * self.width

    def view(self, obs: np.ndarray) -> np.ndarray:
        """The group's slice of obs (..., dim) reshaped to (..., count, width)."""
        return obs[..., self.start : self.stop].reshape(obs.shape[:-1] + (self.count, self.width))


SELF_FEATURES = ("x", "y", "vx", "vy")
TEAMMATE_FEATURES = ("dx", "dy", "dvx", "dvy", "visible")
EVADER_FEATURES = ("dx", "dy", "vx", "vy", "visible", "relayed", "captured")
MEMORY_FEATURES = ("dx", "dy", "vx", "vy", "age", "known")
GOAL_FEATURES = ("dx", "dy", "planned")


@dataclasses.dataclass(frozen=True)
class ObsSpec:
    """The layout of one pursuer's observation; `dim` is the vector length."""

    n_pursuers: int
    n_evaders: int
    n_rays: int
    groups: tuple[Group, ...]

    @staticmethod
    def make(n_pursuers: int, n_evaders: int, n_rays: int, belief: bool = False) -> "ObsSpec":
        """The environment's spec; with `belief`, the memory and goal groups appended."""
        groups = []
        start = 0
        layout = [
            ("self", 1, SELF_FEATURES, None),
            ("teammates", n_pursuers - 1, TEAMMATE_FEATURES, 4),
            ("evaders", n_evaders, EVADER_FEATURES, 4),
            ("rays", 1, tuple(f"range_{i}" for i in range(n_rays)), None),
        ]
        if belief:
            layout += [("memory", n_evaders, MEMORY_FEATURES, 5), ("goal", 1, GOAL_FEATURES, None)]
        for name, count, feats, mask in layout:
            g = Group(name, start, count, len(feats), mask, feats)
            groups.append(g)
            start = g.stop
        return ObsSpec(n_pursuers, n_evaders, n_rays, tuple(groups))

    @property
    def dim(self) -> int:
        return self.groups[-1].stop

    @property
    def has_belief(self) -> bool:
        """Whether the belief groups (memory, goal) are part of the vector."""
        return any(g.name == "memory" for g in self.groups)

    def group(self, name: str) -> Group:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(f"observation has no group '{name}' (groups: {[g.name for g in self.groups]})")

    def index(self, group: str, entity: int, feature: str) -> int:
        """Flat index of one feature, e.g. spec.index('evaders', 0, 'visible'); KeyError for an
        unknown group, IndexError for an entity it lacks, ValueError for a feature it lacks."""
        g = self.group(group)
        if not 0 <= entity < g.count:
            raise IndexError(f"group '{group}' has {g.count} entities, asked for {entity}")
        if feature not in g.features:
            raise ValueError(f"group '{group}' has no feature {feature!r} (features: {_feature_list(g.features)})")
        return g.start + entity * g.width + g.features.index(feature)

    def to_dict(self) -> dict:
        """A plain description, stored in checkpoints to refuse mismatched environments."""
        return {
            "n_pursuers": self.n_pursuers,
            "n_evaders": self.n_evaders,
            "n_rays": self.n_rays,
            "groups": [[g.name, g.width, list(g.features)] for g in self.groups],
        }

    def compatible(self, other: dict) -> str | None:
        """None if a stored spec (to_dict) has the same per-entity features and rays; else why not.

        Entity counts may differ: pooled encoders handle any number of teammates/evaders.
        """
        mine = self.to_dict()
        theirs_belief = any(g[0] == "memory" for g in other.get("groups", []))
        if theirs_belief != self.has_belief:
            side = ("the model", "the environment") if theirs_belief else ("the environment", "the model")
            return f"{side[0]} has belief features (memory, goal) and {side[1]} does not (train config key belief)"
        if other.get("n_rays") != self.n_rays:
            return f"the model expects {other.get('n_rays')} range readings, the environment gives {self.n_rays} (n_rays)"
        if [g[:3] for g in other.get("groups", [])] != [g[:3] for g in mine["groups"]] and \
           [(g[0], g[2]) for g in other.get("groups", [])] != [(g[0], g[2]) for g in mine["groups"]]:
            return f"observation features differ: model {other.get('groups')} vs environment {mine['groups']}"
        return None


def _feature_list(features: tuple[str, ...]) -> str:
    """A group's feature names for a message: all of them, or the first and last range readings."""
    if len(features) > 3 and all(f.startswith("range_") for f in features):
        return f"{features[0]} .. {features[-1]}"
    return ", ".join(features) or "none"


def named_views(obs: np.ndarray, spec: ObsSpec) -> dict[str, np.ndarray]:
    """Named arrays of observations obs (W, N, spec.dim), layout frame, SI units.

    pos, vel (W, N, 2) m, m/s: own state; mate_rel, mate_dvel (W, N, N-1, 2) m, m/s and
    mate_vis (W, N, N-1) bool; ev_rel (W, N, M, 2) m, ev_vel (W, N, M, 2) m/s, ev_vis and
    ev_cap (W, N, M) bool; rays (W, N, K) m; ray_dirs (K, 2) unit vectors of the rays.
    """
    W, N = obs.shape[:2]
    own = spec.group("self").view(obs)[:, :, 0]
    mates = spec.group("teammates").view(obs)
    ev = spec.group("evaders").view(obs)
    rays = spec.group("rays").view(obs)[:, :, 0] if spec.n_rays else np.zeros((W, N, 0))
    angles = 2 * np.pi * np.arange(spec.n_rays) / max(spec.n_rays, 1)
    return {
        "pos": own[..., 0:2],
        "vel": own[..., 2:4],
        "mate_rel": mates[..., 0:2],
        "mate_dvel": mates[..., 2:4],
        "mate_vis": mates[..., 4] > 0.5,
        "ev_rel": ev[..., 0:2],
        "ev_vel": ev[..., 2:4],
        "ev_vis": ev[..., 4] > 0.5,
        "ev_cap": ev[..., 6] > 0.5,
        "rays": rays,
        "ray_dirs": np.stack([np.cos(angles), np.sin(angles)], -1),
    }
