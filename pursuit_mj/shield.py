"""A safety shield for any pursuer policy: it caps the speed toward every hazard a pursuer knows of.

The shield works from a pursuer's own observation only (its position and velocity, the
range readings and the teammates and evaders it sees; see obs_spec.py), so it runs the
same in simulation and on real drones. Every decision step, per pursuer:

1. remember the end points of this step's range readings that hit something (world
   frame, the last `hit_memory` steps): a thin wall seen edge-on slips between the rays
   of one step, but not between those of many;
2. cap the velocity component toward each hazard to approach_rate * (gap - buffer), by
   projection (`safety_passes` passes, worst hazard first). Hazards: every remembered hit
   (gap = distance - obstacle clearance), every visible teammate (gap = distance -
   teammate clearance, half the rate each since both move; see below) and every captured evader
   (gap = distance - capture radius - obstacle clearance). Each gap is first shortened by
   what the current closing speed covers in `response_time` (a drone does not stop at
   once). A negative cap backs the pursuer off. Where the passes leave a cap exceeded (two
   caps meeting at a sharp angle, as a wall and a teammate on either side), the velocity
   nearest the desired one within every cap is solved for exactly; where no velocity keeps
   within them all (a teammate pressing the pursuer against a wall, or the evader it just
   caught beside a wall), the walls win.

Teammates are remembered: one that drops out of sight (behind the pursuer, with a narrow
field of view) stays a hazard for `mate_memory` s, at its last seen position moved along
its last seen velocity. Two pursuers that cannot see each other would otherwise close in
at full speed; on the `hard` preset (120 deg view) that was every collision of the
heuristic team.

With a narrow field of view a teammate may be flying toward a pursuer that it cannot see (the
pursuer is outside its view cone, which points along the teammate's observed velocity, or
beyond its perception radius); it will not give way. Then the pursuer takes the teammate's
own approach speed out of its half of the budget too, so the pair's closing speed stays
within the cap. And where perceived positions are noisy (task `position_noise`, std m),
a teammate's gap is shortened by `noise_margin` std more (range readings are exact, so
walls keep the plain buffer). On the `hard` preset in quadrotor fidelity these two cut the
heuristic team's collisions from 47 to 14 in 576 episodes (docs/evaluation.md).

A velocity that moves away from every hazard, or toward one slowly enough, passes
unchanged. `Shielded` puts the shield on top of any `Policy`. The heuristic team
(heuristic.py) uses the same `SafetyShield` as its last step.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from .configio import TaskValueError
from .obs_spec import ObsSpec, named_views
from .planar import EPS, clip_unit, limit_closing, norm, unit
from .policy import Policy, check_observations, check_world_count, check_world_ids, checked_actions
from .sensing import heading_min_speed

MIN_RAYS = 8  # range readings the shield (and the heuristic team) need to keep off walls: they see walls through nothing else
# (8 is a floor, not a promise: 45 deg apart they first see a 0.065 m cylinder at the collision distance; 16 is the default)


def check_rays(n_rays: int, who: str) -> None:
    """ValueError unless the task gives `who` enough range readings (MIN_RAYS)."""
    if n_rays < MIN_RAYS:
        raise TaskValueError("n_rays", n_rays, f"{who} sees walls only through range readings and needs at least "
                             f"{MIN_RAYS} (set n_rays >= {MIN_RAYS})")


def _is_number(value) -> bool:
    """Whether value is a real number (an int, float or numpy scalar; not a bool, a string or None)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


@dataclasses.dataclass(frozen=True)
class ShieldParams:
    """Tuning of the shield. Distances in m, times in s."""

    safety_buffer: float = 0.05  # keep this much beyond each clearance (m)
    approach_rate: float = 1.5  # max closing speed toward a hazard = rate * (gap - buffer) (1/s)
    response_time: float = 0.25  # the gap shrinks by this much of the current closing speed before a command acts (s)
    safety_passes: int = 4  # projection passes of the closing-speed limits (then an exact solve where they fall short)
    hit_memory: int = 12  # steps of ray hit points kept as hazards
    mate_memory: float = 3.0  # an unseen teammate stays a hazard this long, dead-reckoned (s; 0: off)
    noise_margin: float = 1.0  # a teammate's gap is shortened by this many std of the position noise (task position_noise)

    def __post_init__(self):
        for key in ("safety_buffer", "response_time", "mate_memory", "noise_margin"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"ShieldParams.{key}: expected a number >= 0, got {value!r}")
        if not (isinstance(self.approach_rate, (int, float)) and math.isfinite(self.approach_rate) and self.approach_rate > 0):
            raise ValueError(f"ShieldParams.approach_rate: expected a number > 0 (1/s), got {self.approach_rate!r}")
        for key in ("safety_passes", "hit_memory"):
            value = getattr(self, key)
            if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1):
                raise ValueError(f"ShieldParams.{key}: expected an integer >= 1, got {value!r}")


class SafetyShield:
    """Filters desired velocities (W, N, 2) m/s, world frame, against the hazards each pursuer observes.

    pursuer_speed (m/s) converts actions (fractions of it) to velocities in `Shielded`;
    capture_radius (m) sizes captured evaders as hazards; obstacle/teammate clearance (m)
    are the collision distances of the task; ray_range (m) is the cap of range readings (a
    reading below it hit something); control_dt (s) is the decision interval (one `filter`
    call each); field_of_view (rad), perception_radius (m) and position_noise (std, m) are
    how teammates perceive each other, for the who-gives-way and noise-margin rules, unless
    share_teammates (task key: positions broadcast, every teammate known exactly). Keeps a
    memory of hits and teammates per world: call `reset` at episode starts, as for any policy.
    """

    def __init__(
        self,
        pursuer_speed: float = 0.3,
        capture_radius: float = 0.3,
        obstacle_clearance: float = 0.1,
        teammate_clearance: float = 0.2,
        ray_range: float = 2.0,
        params: ShieldParams | None = None,
        control_dt: float = 0.1,
        field_of_view: float = 2 * math.pi,
        perception_radius: float = math.inf,
        position_noise: float = 0.0,
        share_teammates: bool = False,
    ):
        for key, value, positive in (("pursuer_speed", pursuer_speed, True), ("ray_range", ray_range, True),
                                     ("control_dt", control_dt, True),
                                     ("capture_radius", capture_radius, False), ("obstacle_clearance", obstacle_clearance, False),
                                     ("teammate_clearance", teammate_clearance, False)):
            if not (_is_number(value) and math.isfinite(value) and (value > 0 if positive else value >= 0)):
                raise ValueError(f"SafetyShield: {key} must be a {'positive' if positive else 'non-negative'} number, got {value!r}")
        for key, value in (("field_of_view", field_of_view), ("perception_radius", perception_radius),
                           ("position_noise", position_noise)):
            if not _is_number(value):
                raise ValueError(f"SafetyShield: {key} must be a number, got {value!r}")
        if not (0 < field_of_view <= 2 * math.pi and perception_radius > 0):
            raise ValueError(f"SafetyShield: field_of_view must be in (0, 2 pi] rad and perception_radius > 0 m, "
                             f"got {field_of_view!r} and {perception_radius!r}")
        if not (math.isfinite(position_noise) and position_noise >= 0):
            raise ValueError(f"SafetyShield: position_noise must be a non-negative number (m), got {position_noise!r}")
        if share_teammates:  # teammates broadcast their own positions: each knows of every other, exactly
            field_of_view, perception_radius, position_noise = 2 * math.pi, math.inf, 0.0
        self.position_noise = float(position_noise)
        self.field_of_view = float(field_of_view)
        self.perception_radius = float(perception_radius)
        self.speed = float(pursuer_speed)
        self.capture_radius = float(capture_radius)
        self.obstacle_clearance = float(obstacle_clearance)
        self.teammate_clearance = float(teammate_clearance)
        self.ray_range = float(ray_range)
        self.dt = float(control_dt)
        self.p = params or ShieldParams()
        self._n_worlds: int | None = None
        self._hits: np.ndarray | None = None  # (W, N, hit_memory * K, 2) m world: recent ray end points
        self._hit_ok: np.ndarray | None = None  # (W, N, hit_memory * K) bool: which of them are on something
        self._slot = 0  # ring-buffer position of the next step's hits
        # last seen teammates, per observer: position (W, N, N-1, 2) m world, velocity
        # (W, N, N-1, 2) m/s world, age (W, N, N-1) s since seen (inf: not remembered)
        self._mates: dict[str, np.ndarray] | None = None

    @classmethod
    def from_config(cls, config, params: ShieldParams | None = None) -> "SafetyShield":
        """A shield for a TaskConfig's speed, clearances, ray range and teammates' sight
        (in full observability every teammate knows every other, exactly: none is taken as blind,
        and no gap is shortened for position_noise, which full observability does not apply); its
        response_time grows by the task's command_latency, during which a drone flies on."""
        check_rays(config.n_rays, "the safety shield")
        full = config.observability == "full"
        params = params or ShieldParams()
        if config.command_latency:  # a command acts that much later: the drone flies on meanwhile
            params = dataclasses.replace(params, response_time=params.response_time + config.command_latency)
        return cls(config.pursuer_speed, config.capture_radius, config.obstacle_clearance,
                   config.teammate_clearance, config.ray_range, params, config.control_dt,
                   2 * math.pi if full else config.field_of_view, math.inf if full else config.perception_radius,
                   0.0 if full else config.position_noise, config.share_teammates)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        """Forget the hits and teammates seen in the listed worlds (all, and resize, when world_ids is None);
        ValueError for ids that are not worlds 0..n_worlds-1."""
        world_ids = check_world_ids(world_ids, n_worlds, "SafetyShield")
        if world_ids is None or self._n_worlds != n_worlds:
            self._n_worlds = int(n_worlds)
            self._hits = self._hit_ok = self._mates = None
            return
        if self._hit_ok is not None:
            self._hit_ok[world_ids] = False
        if self._mates is not None:
            self._mates["age"][world_ids] = np.inf

    def apply(self, v: np.ndarray, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Filtered velocities (W, N, 2) m/s from desired ones v (W, N, 2) m/s and observations (W, N, spec.dim)."""
        return self.filter(v, named_views(check_observations(obs, spec, "SafetyShield"), spec))

    def shield_actions(self, actions: np.ndarray, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Policy actions (W, N, 2) (fraction of pursuer_speed) -> shielded actions in the unit disc.

        The actions are first clipped as the environment would (each axis to [-1, 1], then to
        unit norm), so the shield sees the velocity that would be flown.
        """
        a = clip_unit(np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0))
        return clip_unit(self.apply(a * self.speed, obs, spec) / self.speed)

    def filter(self, v: np.ndarray, o: dict[str, np.ndarray]) -> np.ndarray:
        """Filtered velocities (W, N, 2) m/s from desired ones v (W, N, 2) m/s and the named
        observation arrays o (obs_spec.named_views); remembers this step's ray hits."""
        v = np.asarray(v, dtype=np.float64)
        W, N = o["pos"].shape[:2]
        if v.shape != (W, N, 2):
            raise ValueError(f"SafetyShield: expected velocities of shape {(W, N, 2)} (worlds, pursuers, vx vy), got {v.shape}")
        if not np.isfinite(v).all():
            raise ValueError("SafetyShield: desired velocities contain NaN or inf")
        if self._n_worlds is None:
            self._n_worlds = W
        check_world_count(W, self._n_worlds, "SafetyShield")
        self._remember_hits(o)
        return self._limit_closing(v, self._with_remembered_mates(o))

    def _with_remembered_mates(self, o: dict) -> dict:
        """o with teammates out of sight for at most mate_memory s put back where they should be now."""
        rel, vis = o["mate_rel"], o["mate_vis"]
        if rel.shape[2] == 0 or self.p.mate_memory <= 0:
            return o
        pos, vel = o["pos"][:, :, None], o["vel"][:, :, None]
        m = self._mates
        if m is None or m["age"].shape != vis.shape:
            m = self._mates = {"pos": np.zeros(rel.shape), "vel": np.zeros(rel.shape), "age": np.full(vis.shape, np.inf)}
        m["pos"] = np.where(vis[..., None], pos + rel, m["pos"])
        m["vel"] = np.where(vis[..., None], vel + o["mate_dvel"], m["vel"])
        m["age"] = np.where(vis, 0.0, m["age"] + self.dt)
        recalled = ~vis & (m["age"] <= self.p.mate_memory)
        if not recalled.any():
            return o
        est = m["pos"] + m["vel"] * np.where(recalled, m["age"], 0.0)[..., None]
        return dict(o, mate_rel=np.where(recalled[..., None], est - pos, rel),
                    mate_dvel=np.where(recalled[..., None], m["vel"] - vel, o["mate_dvel"]), mate_vis=vis | recalled)

    def _remember_hits(self, o: dict) -> None:
        """Store this step's ray end points (world frame) in the ring buffer of the last hit_memory steps."""
        W, N, K = o["rays"].shape
        size = self.p.hit_memory * K
        if self._hits is None or self._hits.shape != (W, N, size, 2):
            self._hits = np.zeros((W, N, size, 2))
            self._hit_ok = np.zeros((W, N, size), bool)
            self._slot = 0
        if K == 0:
            return
        slot = self._slot % self.p.hit_memory
        self._slot = slot + 1
        sl = slice(slot * K, (slot + 1) * K)
        self._hits[:, :, sl] = o["pos"][:, :, None] + o["rays"][..., None] * o["ray_dirs"]
        self._hit_ok[:, :, sl] = o["rays"] < self.ray_range - 1e-6

    def _hit_dirs(self, ray_dirs: np.ndarray) -> np.ndarray:
        """(hit_memory * K, 2) unit vectors: the direction of the ray each stored hit was found
        along (slot s, ray k is entry s * K + k). The direction of a hit at the pursuer's own
        position (a ray reading 0 m: it touches the wall) is that ray's."""
        return np.tile(ray_dirs, (self.p.hit_memory, 1))

    def _mate_sees_me(self, u: np.ndarray, d: np.ndarray, mate_vel: np.ndarray) -> np.ndarray:
        """(W, N, N-1) bool: whether each teammate (unit direction u from this pursuer, distance d
        m, velocity mate_vel m/s) has this pursuer in its view: within its perception radius and,
        with a field of view under 360 deg, inside the cone around its direction of flight (a
        teammate too slow to have a direction counts as not seeing). Walls are not checked: they
        block both ways, and a pursuer that sees a teammate is in that teammate's line of sight."""
        near = d <= self.perception_radius
        if self.field_of_view >= 2 * math.pi - 1e-9:
            return near
        speed = norm(mate_vel)
        cos_to_me = -np.einsum("wnmk,wnmk->wnm", u, mate_vel) / np.maximum(speed, EPS)
        return near & (speed > heading_min_speed(self.speed)) & (cos_to_me >= math.cos(self.field_of_view / 2))

    def _limit_closing(self, v: np.ndarray, o: dict) -> np.ndarray:
        """Cap the speed toward each hazard (module docstring) by projection; v (W, N, 2) m/s."""
        p = self.p
        lag = p.response_time
        dirs, limits = [], []
        if o["rays"].shape[-1]:
            rel = self._hits - o["pos"][:, :, None]
            d = np.sqrt(rel[..., 0] ** 2 + rel[..., 1] ** 2)
            u = np.where((d > EPS)[..., None], rel / np.maximum(d, EPS)[..., None], self._hit_dirs(o["ray_dirs"]))
            closing = np.maximum(np.einsum("wnhk,wnk->wnh", u, o["vel"]), 0.0)
            gap = d - self.obstacle_clearance - p.safety_buffer - lag * closing
            dirs.append(u)
            limits.append(np.where(self._hit_ok, p.approach_rate * gap, np.inf))
        if o["mate_rel"].shape[2]:
            d = norm(o["mate_rel"])
            u = unit(o["mate_rel"])
            closing = np.maximum(-np.einsum("wnmk,wnmk->wnm", u, o["mate_dvel"]), 0.0)
            margin = p.safety_buffer + p.noise_margin * self.position_noise
            gap = np.where(o["mate_vis"], d - self.teammate_clearance - margin - lag * closing, np.inf)
            mate_vel = o["vel"][:, :, None] + o["mate_dvel"]  # (W, N, N-1, 2) m/s
            # a teammate that cannot see this pursuer does not give way: its approach comes off the cap
            blind = ~self._mate_sees_me(u, d, mate_vel)
            approach = np.minimum(np.einsum("wnmk,wnmk->wnm", u, mate_vel), 0.0)
            dirs.append(u)
            limits.append(0.5 * p.approach_rate * gap + np.where(blind, approach, 0.0))
        d = norm(o["ev_rel"])
        u = unit(o["ev_rel"])
        closing = np.maximum(np.einsum("wnmk,wnk->wnm", u, o["vel"]), 0.0)
        gap = d - self.capture_radius - self.obstacle_clearance - p.safety_buffer - lag * closing
        dirs.append(u)
        limits.append(np.where(o["ev_cap"] & o["ev_vis"], p.approach_rate * gap, np.inf))
        u = np.concatenate(dirs, axis=2)  # (W, N, H, 2)
        cap = np.concatenate(limits, axis=2)  # (W, N, H) m/s, may be negative (back off)
        out, met = limit_closing(v, u, cap, p.safety_passes)
        if met.all():
            return out
        # No velocity keeps within every cap: they conflict (a teammate presses the pursuer
        # against a wall). Then the static hazards (remembered hits, captured evaders) get the
        # last word: a wall does not move, and a teammate's own shield makes it give way. Where
        # those still conflict (a pursuer beside the evader it caught, whose 0.45 m hazard
        # reaches far beyond its body, next to a wall), the walls alone: else the caught
        # evader's cap, projected last, sent the pursuer into the wall at full speed.
        n_hits = self._hits.shape[2] if o["rays"].shape[-1] else 0
        caught = np.zeros(cap.shape[-1], bool)
        caught[n_hits + o["mate_rel"].shape[2] :] = True
        walls = np.zeros(cap.shape[-1], bool)
        walls[:n_hits] = True
        w, n = np.nonzero(~met)
        out[w, n], met[w, n] = limit_closing(out[w, n], u[w, n][:, walls | caught], cap[w, n][:, walls | caught], p.safety_passes)
        w, n = np.nonzero(~met & np.isfinite(cap[..., caught]).any(-1))
        out[w, n], _ = limit_closing(out[w, n], u[w, n][:, walls], cap[w, n][:, walls], p.safety_passes)
        return out


class Shielded:
    """A `Policy` that passes any policy's actions through a `SafetyShield`.

    act = clip_unit(shield(a * speed) / speed), where a is the wrapped policy's action
    clipped as the environment would (each axis to [-1, 1], then to unit norm). Results with
    it are labelled: name = "<policy name>+shield".
    """

    has_shield = True  # eval/render/fly do not wrap it again

    def __init__(self, policy: Policy, shield: SafetyShield):
        self.policy = policy
        self.shield = shield
        self._inner = str(getattr(policy, "name", type(policy).__name__))
        self.name = f"{self._inner}+shield"
        self._n_worlds: int | None = None  # as reset() was last called (None: not yet)

    def reset(self, n_worlds: int, world_ids: np.ndarray | None = None) -> None:
        world_ids = check_world_ids(world_ids, n_worlds, f"policy {self.name}")
        self._n_worlds = int(n_worlds)
        self.policy.reset(n_worlds, world_ids)
        self.shield.reset(n_worlds, world_ids)

    def act(self, obs: np.ndarray, spec: ObsSpec) -> np.ndarray:
        """Actions (W, N, 2) within the unit disc: desired world-frame velocity / pursuer_speed."""
        check_observations(obs, spec, f"policy {self.name}")
        check_world_count(np.shape(obs)[0], self._n_worlds, f"policy {self.name}")
        raw = self.policy.act(np.array(obs), spec)  # a copy: what it writes into it must not move the walls below
        # read as the env and evaluate read a policy's actions (a torch tensor by its values; bools,
        # text, complex numbers, masked entries, another shape, NaN and inf refused naming the policy)
        W, N = np.shape(obs)[:2]
        a = checked_actions(raw, W, N, f"policy {self._inner}")
        return self.shield.shield_actions(a, obs, spec)


def shield_policy(policy: Policy, config, params: ShieldParams | None = None) -> Policy:
    """`policy` behind a shield for TaskConfig `config`; unchanged if it has one built in (`has_shield`)."""
    if getattr(policy, "has_shield", False):
        return policy
    return Shielded(policy, SafetyShield.from_config(config, params))
