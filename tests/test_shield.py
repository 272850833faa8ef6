"""The safety shield: it keeps any policy off walls, leaves safe actions alone, and is labelled."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pursuit_cli import main
from conftest import nearest_allowed_on_a_grid
from pursuit_mj.config import default_config
from pursuit_mj.env import PursuitEnv
from pursuit_mj.evaluation import run_episodes
from pursuit_mj.geometry import ObstacleSet, obstacle_distance
from pursuit_mj.heuristic import HeuristicParams, HeuristicTeam
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policy import RandomPolicy
from pursuit_mj.shield import SafetyShield, Shielded, ShieldParams, shield_policy

SPEC = ObsSpec.make(3, 1, 16)
SPEED = 0.3
WALL_CAP = ShieldParams.approach_rate * (0.2 - 0.1 - ShieldParams.safety_buffer)  # m/s toward a wall 0.2 m away, standing


class Straight:
    """Every pursuer flies one fixed direction at full speed, whatever it sees."""

    name = "straight"

    def __init__(self, direction):
        self.direction = np.asarray(direction, float) / np.linalg.norm(direction)

    def reset(self, n_worlds, world_ids=None) -> None:
        pass

    def act(self, obs, spec):
        return np.broadcast_to(self.direction, obs.shape[:2] + (2,)).copy()


def blank_obs(n_worlds: int = 1) -> np.ndarray:
    """Observations (W, 3, dim): pursuers 2 m apart on y = 2.5, standing, nothing seen, open rays."""
    obs = np.zeros((n_worlds, 3, SPEC.dim))
    for i in range(3):
        obs[:, i, SPEC.index("self", 0, "x")] = 1.0 + 2.0 * i
        obs[:, i, SPEC.index("self", 0, "y")] = 2.5
    rays = SPEC.group("rays")
    obs[..., rays.start : rays.stop] = 2.0
    return obs


def wall_east(obs: np.ndarray, distance: float, world: int = 0, pursuer: int = 0) -> None:
    """A wall `distance` m to the +x side of one pursuer: the rays within +-60 degrees of +x see it."""
    for k in range(16):
        angle = 2 * np.pi * k / 16
        if np.cos(angle) > 0.5:
            obs[world, pursuer, SPEC.index("rays", 0, f"range_{k}")] = distance / np.cos(angle)


def test_random_team_collides_far_less_with_the_shield():
    cfg = dataclasses.replace(default_config(), fidelity="point", layout=0, max_steps=300)
    rates = {}
    for policy in (RandomPolicy(0), shield_policy(RandomPolicy(0), cfg)):
        records = run_episodes(policy, cfg, 16, seed=0, n_worlds=16)
        rates[policy.name] = np.mean([r.outcome == "collision" for r in records])
    assert rates["random"] >= 0.25  # the test means something: random flight does crash
    assert rates["random+shield"] <= min(0.5 * rates["random"], 0.25), rates


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
@pytest.mark.parametrize("direction, latency", [((0.0, -1.0), 0.0), ((1.0, 0.0), 0.0), ((1.0, 1.0), 0.0), ((1.0, 0.0), 0.3)])
def test_flying_straight_at_a_wall_stops_short_of_it(fidelity, direction, latency):
    cfg = dataclasses.replace(default_config(), fidelity=fidelity, layout=0, max_steps=100, command_latency=latency)
    env = PursuitEnv(cfg, n_worlds=3, seed=0, auto_reset=False)
    obs = env.reset(seeds=[11, 12, 13])
    policy = shield_policy(Straight(direction), cfg)
    policy.reset(3)
    obstacles = ObstacleSet.stack([layout.obstacle_set() for layout in env.world_layouts])
    closest = np.inf
    for _ in range(100):
        obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
        assert all(r.outcome != "collision" for r in info["episodes"])
        gaps = obstacle_distance(env.physics.positions()[:, : cfg.n_pursuers, :2], obstacles)  # (W, N) m
        closest = min(closest, float(gaps.min()))
        if env.done.all():
            break
    assert closest > cfg.obstacle_clearance
    assert closest < cfg.obstacle_clearance + 0.15 + latency / 6  # it went up to the wall, not stopped far away


def test_an_action_away_from_every_hazard_is_unchanged():
    obs = blank_obs()
    wall_east(obs, 0.2)
    mate = SPEC.index("teammates", 0, "dx")  # pursuer 0's first teammate, 0.3 m to its +y side
    obs[0, 0, mate : mate + 5] = [0.0, 0.3, 0.0, 0.0, 1.0]
    desired = np.zeros((1, 3, 2))
    desired[0, 0] = [-0.2, -0.2]  # away from the wall and from the teammate
    desired[0, 1] = [0.0, 0.3]
    shield = SafetyShield(SPEED)
    shield.reset(1)
    np.testing.assert_array_equal(shield.apply(desired, obs, SPEC), desired)
    toward = desired.copy()
    toward[0, 0] = [SPEED, 0.0]  # straight at the wall 0.2 m away
    np.testing.assert_allclose(shield.apply(toward, obs, SPEC)[0, 0], [WALL_CAP, 0.0], atol=1e-12)


def test_shielded_policy_keeps_safe_actions_and_labels_itself():
    obs = blank_obs()
    wall_east(obs, 0.2)
    policy = Shielded(Straight((-1.0, 0.0)), SafetyShield(SPEED))
    policy.reset(1)
    assert policy.name == "straight+shield"
    np.testing.assert_allclose(policy.act(obs, SPEC), np.tile([-1.0, 0.0], (1, 3, 1)))
    out = Shielded(RandomPolicy(0), SafetyShield(SPEED)).act(obs, SPEC)
    assert np.all(np.linalg.norm(out, axis=-1) <= 1.0 + 1e-12)


class Normalising(Straight):
    """Straight, after scaling its observations in place (the caller's array)."""

    name = "normalising"

    def act(self, obs, spec):
        obs *= 0.5
        return super().act(obs, spec)


def test_a_policy_that_writes_into_its_observations_does_not_change_what_its_shield_reads():
    """Shielded handed its policy the very array the shield then read: a policy normalising in
    place moved the walls the shield kept it from (here, from 0.2 m to 0.1 m away)."""
    obs = blank_obs()
    wall_east(obs, 0.2)
    seen = obs.copy()
    clean = Shielded(Straight((1.0, 0.0)), SafetyShield(SPEED))
    scaling = Shielded(Normalising((1.0, 0.0)), SafetyShield(SPEED))
    for policy in (clean, scaling):
        policy.reset(1)
    np.testing.assert_array_equal(scaling.act(obs, SPEC), clean.act(seen.copy(), SPEC))
    np.testing.assert_array_equal(obs, seen)


def test_reset_forgets_the_hits_of_the_listed_worlds_only():
    shield = SafetyShield(SPEED)
    shield.reset(2)
    near = blank_obs(2)
    wall_east(near, 0.2, world=0)
    wall_east(near, 0.2, world=1)
    fast_east = np.tile([SPEED, 0.0], (2, 3, 1))
    shield.apply(fast_east, near, SPEC)  # both worlds see the wall
    clear = blank_obs(2)  # the wall slips between the rays: only the memory knows it
    capped = shield.apply(fast_east, clear, SPEC)
    np.testing.assert_allclose(capped[:, 0, 0], WALL_CAP)
    shield.reset(2, np.array([0]))
    after = shield.apply(fast_east, clear, SPEC)
    assert after[0, 0, 0] == pytest.approx(SPEED)  # world 0 forgot the wall
    assert after[1, 0, 0] == pytest.approx(WALL_CAP)  # world 1 still remembers it


def _mate_east(obs: np.ndarray, distance: float | None) -> None:
    """Pursuer 0's first teammate standing `distance` m to its +x side (None: not seen)."""
    at = SPEC.index("teammates", 0, "dx")
    obs[0, 0, at : at + 5] = [0.0, 0.0, 0.0, 0.0, 0.0] if distance is None else [distance, 0.0, 0.0, 0.0, 1.0]


def test_a_teammate_out_of_sight_stays_a_hazard_for_mate_memory_seconds():
    shield = SafetyShield(SPEED, params=ShieldParams(mate_memory=0.5), control_dt=0.1)
    shield.reset(2)
    fast_east = np.tile([SPEED, 0.0], (2, 3, 1))
    seen = blank_obs(2)
    _mate_east(seen, 0.3)
    capped = shield.apply(fast_east, seen, SPEC)[0, 0, 0]
    mate_cap = 0.5 * ShieldParams.approach_rate * (0.3 - 0.2 - ShieldParams.safety_buffer)
    assert capped == pytest.approx(mate_cap)
    hidden = blank_obs(2)  # it is behind the pursuer now: not in the observation
    _mate_east(hidden, None)
    shield.reset(2, np.array([1]))  # another world's reset does not touch world 0's memory
    for _ in range(5):  # 0.1 .. 0.5 s out of sight: still there (it stood still)
        assert shield.apply(fast_east, hidden, SPEC)[0, 0, 0] == pytest.approx(mate_cap)
    assert shield.apply(fast_east, hidden, SPEC)[0, 0, 0] == pytest.approx(SPEED)  # 0.6 s: forgotten
    shield.apply(fast_east, seen, SPEC)
    shield.reset(2, np.array([0]))
    assert shield.apply(fast_east, hidden, SPEC)[0, 0, 0] == pytest.approx(SPEED)  # a new episode remembers nothing


def test_a_remembered_teammate_moves_along_its_last_velocity():
    shield = SafetyShield(SPEED, params=ShieldParams(mate_memory=3.0), control_dt=0.1)
    shield.reset(1)
    obs = blank_obs()
    at = SPEC.index("teammates", 0, "dx")
    obs[0, 0, at : at + 5] = [0.5, 0.0, -0.3, 0.0, 1.0]  # 0.5 m east, coming west at 0.3 m/s

    def cap(distance):  # the shield's limit toward a teammate closing at 0.3 m/s (module docstring)
        gap = distance - 0.2 - ShieldParams.safety_buffer - ShieldParams.response_time * 0.3
        return 0.5 * ShieldParams.approach_rate * gap

    east = np.tile([SPEED, 0.0], (1, 3, 1))
    assert shield.apply(east, obs, SPEC)[0, 0, 0] == pytest.approx(cap(0.5))
    hidden = blank_obs()
    for _ in range(2):  # after 0.2 s out of sight it should be 0.44 m away
        out = shield.apply(east, hidden, SPEC)[0, 0, 0]
    assert out == pytest.approx(cap(0.44))


def test_a_teammate_that_cannot_see_the_pursuer_leaves_it_all_the_giving_way():
    narrow = dict(field_of_view=2 * np.pi / 3, perception_radius=1.5)  # the hard preset's view

    def shielded_east(mate_velocity, **view):
        """Pursuer 0 (standing) wants +x at full speed; a teammate 0.5 m east flies mate_velocity."""
        shield = SafetyShield(SPEED, **view)
        shield.reset(1)
        obs = blank_obs()
        at = SPEC.index("teammates", 0, "dx")
        obs[0, 0, at : at + 5] = [0.5, 0.0, *mate_velocity, 1.0]
        return shield.apply(np.tile([SPEED, 0.0], (1, 3, 1)), obs, SPEC)[0, 0, 0]

    def shared_cap(closing):  # half the closing budget: the teammate gives way too
        return 0.5 * ShieldParams.approach_rate * (0.5 - 0.2 - ShieldParams.safety_buffer - ShieldParams.response_time * closing)

    head_on = (-0.3, 0.0)  # flying straight at the pursuer: it is in the teammate's view cone
    assert shielded_east(head_on, **narrow) == pytest.approx(shared_cap(0.3))
    sideways = (-0.1, 0.28)  # mostly north: the pursuer, due west of it, is 70 deg off its heading
    assert shielded_east(sideways, **narrow) == pytest.approx(shared_cap(0.1) - 0.1)  # its 0.1 m/s approach comes off
    assert shielded_east(sideways) == pytest.approx(shared_cap(0.1))  # all-round sight: it sees and gives way
    assert shielded_east((0.0, 0.0), **narrow) == pytest.approx(shared_cap(0.0))  # standing: nothing to take off
    assert shielded_east((0.2, 0.1), **narrow) == pytest.approx(shared_cap(0.0))  # moving away: no credit either
    # teammates that broadcast their positions know of each other: everyone gives way
    assert shielded_east(sideways, **narrow, share_teammates=True) == pytest.approx(shared_cap(0.1))
    with pytest.raises(ValueError, match="field_of_view"):
        SafetyShield(SPEED, field_of_view=0.0)


def test_in_full_observability_no_teammate_is_taken_as_blind():
    # With a 120 deg view but full observability every teammate knows every other (sensing
    # masks nothing), so each gives way: the shield must not take a teammate's approach off
    # the cap as if it could not see the pursuer (it did, from the task's field of view).
    obs = blank_obs()
    at = SPEC.index("teammates", 0, "dx")
    obs[0, 0, at : at + 5] = [0.5, 0.0, -0.1, 0.28, 1.0]  # 0.5 m east, flying mostly north: the pursuer is 70 deg off its heading
    want = np.tile([SPEED, 0.0], (1, 3, 1))
    hard = dict(n_rays=16, field_of_view=2 * np.pi / 3, perception_radius=1.5)

    def east(config, team=False):
        shield = HeuristicTeam.from_config(config).shield if team else SafetyShield.from_config(config)
        shield.reset(1)
        return shield.apply(want, obs, SPEC)[0, 0, 0]

    partial, full = default_config(**hard), default_config(**hard, observability="full")
    seen = east(default_config(**hard, share_teammates=True))  # teammates known to each other: both give way
    assert east(partial) == pytest.approx(seen - 0.1)  # a narrow view: its 0.1 m/s approach comes off
    assert east(full) == pytest.approx(seen)
    assert east(full, team=True) == pytest.approx(seen)  # the heuristic team's own shield too
    assert east(partial, team=True) == pytest.approx(seen - 0.1)


def test_noisy_teammate_positions_widen_the_teammate_margin_only():
    def capped(position_noise, hazard):
        shield = SafetyShield(SPEED, position_noise=position_noise)
        shield.reset(1)
        obs = blank_obs()
        if hazard == "mate":
            _mate_east(obs, 0.5)
        else:
            wall_east(obs, 0.25)
        return shield.apply(np.tile([SPEED, 0.0], (1, 3, 1)), obs, SPEC)[0, 0, 0]

    rate, buffer = ShieldParams.approach_rate, ShieldParams.safety_buffer
    assert capped(0.0, "mate") == pytest.approx(0.5 * rate * (0.5 - 0.2 - buffer))
    assert capped(0.1, "mate") == pytest.approx(0.5 * rate * (0.5 - 0.2 - buffer - ShieldParams.noise_margin * 0.1))
    assert capped(0.1, "wall") == pytest.approx(capped(0.0, "wall"))  # range readings are not noisy
    shield = SafetyShield(SPEED, position_noise=0.1, share_teammates=True)  # broadcast positions are exact
    assert shield.position_noise == 0.0
    with pytest.raises(ValueError, match="position_noise"):
        SafetyShield(SPEED, position_noise=-0.1)


def test_mate_memory_zero_forgets_at_once():
    shield = SafetyShield(SPEED, params=ShieldParams(mate_memory=0.0))
    shield.reset(1)
    seen, hidden = blank_obs(), blank_obs()
    _mate_east(seen, 0.3)
    fast_east = np.tile([SPEED, 0.0], (1, 3, 1))
    assert shield.apply(fast_east, seen, SPEC)[0, 0, 0] < SPEED
    assert shield.apply(fast_east, hidden, SPEC)[0, 0, 0] == pytest.approx(SPEED)


def wall_toward(obs: np.ndarray, distance: float, angle: float, pursuer: int = 0) -> None:
    """A straight wall `distance` m from one pursuer (world 0) on the side at `angle` rad: the
    rays within +-60 degrees of that direction see it."""
    for k in range(16):
        off = np.cos(2 * np.pi * k / 16 - angle)
        if off > 0.5:
            obs[0, pursuer, SPEC.index("rays", 0, f"range_{k}")] = distance / off


def limits_of(obs: np.ndarray, pursuer: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Directions (H, 2) and caps (H,) m/s the shield should hold for a standing pursuer of
    world 0 (module docstring): one per ray hit and one per visible teammate."""
    dirs, caps = [], []
    rate, buffer = ShieldParams.approach_rate, ShieldParams.safety_buffer
    for k in range(16):
        r = obs[0, pursuer, SPEC.index("rays", 0, f"range_{k}")]
        if r < 2.0 - 1e-6:
            dirs.append([np.cos(2 * np.pi * k / 16), np.sin(2 * np.pi * k / 16)])
            caps.append(rate * (r - 0.1 - buffer))
    for j in range(2):
        at = SPEC.index("teammates", j, "dx")
        dx, dy, _, _, seen = obs[0, pursuer, at : at + 5]
        if seen:
            d = np.hypot(dx, dy)
            dirs.append([dx / d, dy / d])
            caps.append(0.5 * rate * (d - 0.2 - buffer))
    return np.array(dirs), np.array(caps)


def test_limits_meeting_at_a_sharp_angle_all_hold():
    # a pursuer 0.2 m from a teammate (west-south-west, too close: back off) with a wall
    # 0.155 m away to the north-north-east, wanting to fly between them: the two limits
    # meet at about 30 deg, where projecting onto one limit at a time converged too slowly
    # (four passes left 0.05 m/s toward the teammate; seen with a team pushing into a wall)
    rng = np.random.default_rng(3)
    cases = [(0.2, np.radians(194), 0.155, np.radians(63), np.radians(163))]
    for _ in range(6):
        cases.append((rng.uniform(0.2, 0.35), rng.uniform(0, 2 * np.pi), rng.uniform(0.13, 0.3),
                      rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)))
    for mate_d, mate_angle, wall_d, wall_angle, heading in cases:
        shield = SafetyShield(SPEED)
        shield.reset(1)
        obs = blank_obs()
        wall_toward(obs, wall_d, wall_angle)
        at = SPEC.index("teammates", 0, "dx")
        obs[0, 0, at : at + 5] = [mate_d * np.cos(mate_angle), mate_d * np.sin(mate_angle), 0.0, 0.0, 1.0]
        want = SPEED * np.array([np.cos(heading), np.sin(heading)])
        out = shield.apply(np.tile(want, (1, 3, 1)), obs, SPEC)[0, 0]
        dirs, caps = limits_of(obs)
        assert np.all(dirs @ out <= caps + 1e-9), (dirs @ out - caps).max()
        if mate_d == 0.2:  # where the passes fell short, the answer moves the action least
            assert np.linalg.norm(out - want) <= nearest_allowed_on_a_grid(want, dirs, caps) + 1e-9


def test_a_teammate_pressing_a_pursuer_against_a_wall_does_not_push_it_into_the_wall():
    # both too close (wall 0.12 m east, teammate 0.2 m west): no velocity keeps off both,
    # and the wall wins; the teammate's own shield makes it give way
    shield = SafetyShield(SPEED)
    shield.reset(1)
    obs = blank_obs()
    wall_east(obs, 0.12)
    _mate_east(obs, -0.2)
    out = shield.apply(np.tile([-SPEED, 0.0], (1, 3, 1)), obs, SPEC)[0, 0]
    assert out[0] <= ShieldParams.approach_rate * (0.12 - 0.1 - ShieldParams.safety_buffer) + 1e-9


@pytest.mark.parametrize("fidelity", ["point", "quadrotor"])
def test_a_pursuer_beside_the_evader_it_caught_still_stops_short_of_a_wall(fidelity):
    # pursuer 0 catches evader 0 at once, 0.2 m east of it and 0.3 m from the west wall, then
    # flies west: the caught evader (a hazard up to 0.45 m away) and the wall conflict near the
    # wall, and the caught evader's cap, projected last, sent the pursuer into the wall
    cfg = default_config(fidelity=fidelity, random_obstacles=0, n_evaders=2, layout=0, max_steps=40)
    env = PursuitEnv(cfg, n_worlds=1, seed=0, auto_reset=False)
    env.reset(seeds=[0])
    env.physics.reset([0], np.array([[[0.3, 2.5], [2.0, 1.0], [3.0, 1.0], [0.5, 2.5], [3.0, 4.5]]]))
    obs = env._obs = env._observe()
    policy = shield_policy(Straight((-1.0, 0.0)), cfg)
    policy.reset(1)
    closest = np.inf
    for _ in range(40):
        obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
        assert env.captured[0, 0], "the test means something: the evader beside the pursuer is caught"
        assert all(r.outcome != "collision" for r in info["episodes"])
        closest = min(closest, float(env.physics.positions()[0, 0, 0]))  # m from the west wall
    assert closest > cfg.obstacle_clearance


@pytest.mark.parametrize("direction", [(-1.0, 0.3), (-1.0, -0.3)])
def test_a_team_pushing_into_one_wall_keeps_off_it_and_off_each_other(direction):
    # every pursuer flies into the west wall at a slant: they pile up along it, each
    # squeezed between the wall and a teammate (a wall collision in 8 episodes before)
    cfg = dataclasses.replace(default_config(), fidelity="point", layout=0, max_steps=200)
    env = PursuitEnv(cfg, n_worlds=8, seed=0, auto_reset=False)
    obs = env.reset(seeds=list(range(8)))
    policy = shield_policy(Straight(direction), cfg)
    policy.reset(8)
    obstacles = ObstacleSet.stack([layout.obstacle_set() for layout in env.world_layouts])
    wall_gap = mate_gap = np.inf
    for _ in range(200):
        flying = ~env.done
        obs, _, _, _, info = env.step(policy.act(obs, env.obs_spec))
        assert all(r.outcome != "collision" for r in info["episodes"])
        xy = env.physics.positions()[:, : cfg.n_pursuers, :2]  # (W, N, 2) m
        apart = np.linalg.norm(xy[:, :, None] - xy[:, None], axis=-1) + 9 * np.eye(cfg.n_pursuers)
        wall_gap = min(wall_gap, obstacle_distance(xy, obstacles)[flying].min(initial=np.inf))
        mate_gap = min(mate_gap, apart[flying].min(initial=np.inf))
        if env.done.all():
            break
    assert wall_gap > cfg.obstacle_clearance + 0.03
    assert mate_gap > cfg.teammate_clearance + 0.02


def test_heuristic_uses_a_shield_built_from_its_params():
    params = HeuristicParams(safety_buffer=0.08, hit_memory=5, mate_memory=1.5)
    team = HeuristicTeam(params=params, control_dt=0.2)
    assert team.shield.p == ShieldParams(0.08, ShieldParams.approach_rate, ShieldParams.response_time, ShieldParams.safety_passes, 5, 1.5)
    assert team.shield.dt == 0.2
    assert HeuristicParams().shield == ShieldParams()
    assert shield_policy(team, default_config()) is team  # the shield is built in: not wrapped twice


@pytest.mark.parametrize(
    "kwargs, message",
    [({"hit_memory": 0}, "hit_memory"), ({"approach_rate": -1.0}, "approach_rate"), ({"safety_buffer": float("nan")}, "safety_buffer"),
     ({"mate_memory": -1.0}, "mate_memory")],
)
def test_bad_params_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ShieldParams(**kwargs)


def test_bad_velocities_and_worlds_are_refused():
    shield = SafetyShield(SPEED)
    shield.reset(1)
    with pytest.raises(ValueError, match="velocities of shape"):
        shield.apply(np.zeros((1, 2, 2)), blank_obs(), SPEC)
    with pytest.raises(ValueError, match="2 worlds"):
        shield.apply(np.zeros((2, 3, 2)), blank_obs(2), SPEC)


def test_eval_cli_shield_labels_the_wrapped_policies_only(tmp_path):
    code = main(["eval", "--policy", "random", "--policy", "heuristic", "--shield", "--layouts", "0", "--episodes", "2",
                 "--worlds", "2", "--fidelity", "point", "--set", "max_steps=10", "--json", str(tmp_path / "t.json"), "-q"])
    assert code == 0
    data = json.loads((tmp_path / "t.json").read_text())
    assert [r["policy"] for r in data["rows"]] == ["random+shield", "heuristic"]


def test_the_team_and_the_shield_refuse_a_task_without_enough_range_readings():
    from pursuit_mj.config import ConfigError, default_config
    from pursuit_mj.heuristic import HeuristicTeam
    from train.config import load_train_config

    blind = default_config(n_rays=4)
    with pytest.raises(ValueError, match="task n_rays 4: the heuristic team sees walls only through range readings"):
        HeuristicTeam.from_config(blind)
    with pytest.raises(ValueError, match="task n_rays 4: the safety shield"):
        SafetyShield.from_config(blind)
    with pytest.raises(ConfigError, match="task.n_rays 0: .* shield, residual.base, run.validation_vs_heuristic"):
        load_train_config(["residual"], ["task.n_rays=0"]).check_complete()
    load_train_config(["classic"], ["task.n_rays=0", "run.validation_vs_heuristic=false"]).check_complete()  # a network alone may


def test_under_command_latency_the_shield_brakes_sooner():
    """A command acts task.command_latency later, so the drone flies on meanwhile: the shield
    judges each gap that much further ahead (its response_time grows by the latency)."""
    cfg = default_config()
    obs = blank_obs()
    wall_east(obs, 0.35)
    obs[0, 0, SPEC.index("self", 0, "vx")] = SPEED  # already flying at the wall
    toward = np.zeros((1, 3, 2))
    toward[0, 0] = [SPEED, 0.0]
    caps = []
    for latency in (0.0, 0.3):
        shield = SafetyShield.from_config(dataclasses.replace(cfg, command_latency=latency))
        shield.reset(1)
        caps.append(shield.apply(toward, obs, SPEC)[0, 0, 0])
    assert caps[1] < caps[0] < SPEED  # the gap is judged 0.3 s further ahead: it brakes sooner


def test_a_pursuer_touching_a_wall_is_not_let_into_it():
    """Rays into a wall the pursuer touches read 0 m: their hit points are the pursuer's own
    position, which gives no direction, so the wall's direction is the ray's (it was dropped)."""
    obs = blank_obs()
    wall_east(obs, 0.0)
    toward = np.zeros((1, 3, 2))
    toward[0, 0] = [SPEED, 0.0]
    shield = SafetyShield(SPEED)
    shield.reset(1)
    out = shield.apply(toward, obs, SPEC)
    assert np.isfinite(out).all()
    assert out[0, 0, 0] < 0.0  # backs off the wall it touches (the cap toward it is negative)
    np.testing.assert_array_equal(out[0, 1:], toward[0, 1:])  # the others see nothing


@pytest.mark.parametrize("world_ids", [[5], [-1], [0.5]])
def test_reset_refuses_world_ids_that_are_not_worlds(world_ids):
    shield = SafetyShield(SPEED)
    shield.reset(2)
    with pytest.raises(ValueError, match="SafetyShield: world ids"):
        shield.reset(2, world_ids)  # before any step (nothing remembered yet) too
    shield.apply(np.zeros((2, 3, 2)), blank_obs(2), SPEC)
    with pytest.raises(ValueError, match="SafetyShield: world ids"):
        shield.reset(2, world_ids)



@pytest.mark.parametrize("key", ["pursuer_speed", "capture_radius", "control_dt", "field_of_view", "perception_radius", "position_noise"])
@pytest.mark.parametrize("value", ["0.3", None, True])
def test_a_setting_that_is_no_number_is_refused_by_name(key, value):
    with pytest.raises(ValueError, match=f"SafetyShield: {key} must be a .*number.*got {value!r}"):
        SafetyShield(**{key: value})


@pytest.mark.parametrize("actions", [[["a", "b"]] * 3, [[[0.0, 0.0], [0.0]]]])
def test_shielded_names_the_policy_whose_actions_are_no_numbers(actions):
    class Odd(Straight):
        name = "odd"

        def act(self, obs, spec):
            return actions

    policy = Shielded(Odd((1.0, 0.0)), SafetyShield(SPEED))
    policy.reset(1)
    with pytest.raises(ValueError, match=r"policy odd: act\(\) gave (actions of dtype <U1|a ragged list)"):
        policy.act(blank_obs(), SPEC)


# ----------------------------------------------------------------------------- mutation audit

def _east_of(shield: SafetyShield, obs: np.ndarray, speed: float = SPEED) -> float:
    """Pursuer 0's shielded x velocity (m/s) when every pursuer wants +x at `speed`."""
    shield.reset(1)
    return shield.apply(np.tile([speed, 0.0], (1, 3, 1)), obs, SPEC)[0, 0, 0]


def test_a_range_reading_at_the_full_ray_range_is_no_hit():
    # a reading capped at ray_range saw nothing: taking it for a wall 2 m away capped a fast
    # pursuer at approach_rate * (2 - clearance - buffer) = 2.78 m/s in open space
    fast = 3.0
    assert _east_of(SafetyShield(fast), blank_obs(), fast) == pytest.approx(fast)
    obs = blank_obs()
    wall_east(obs, 1.9)  # just inside the range: a wall
    assert _east_of(SafetyShield(fast), obs, fast) == pytest.approx(ShieldParams.approach_rate * (1.9 - 0.1 - ShieldParams.safety_buffer))


def test_a_teammate_beyond_its_perception_radius_or_too_slow_to_have_a_heading_does_not_see_the_pursuer():
    """Both count as blind (SafetyShield._mate_sees_me): its approach comes off the pursuer's cap."""

    def shared_cap(closing):
        return 0.5 * ShieldParams.approach_rate * (0.5 - 0.2 - ShieldParams.safety_buffer - ShieldParams.response_time * closing)

    def east(mate_velocity, **view):
        obs = blank_obs()
        at = SPEC.index("teammates", 0, "dx")
        obs[0, 0, at : at + 5] = [0.5, 0.0, *mate_velocity, 1.0]  # 0.5 m east
        return _east_of(SafetyShield(SPEED, **view), obs)

    head_on = (-0.3, 0.0)
    assert east(head_on, perception_radius=1.5) == pytest.approx(shared_cap(0.3))  # all-round, near: it sees
    assert east(head_on, perception_radius=0.45) == pytest.approx(shared_cap(0.3) - 0.3)  # beyond its radius
    creeping = (-0.02, 0.0)  # straight at the pursuer, but below heading_min_speed (0.05 m/s): no view cone
    narrow = dict(field_of_view=2 * np.pi / 3, perception_radius=1.5)
    assert east(creeping, **narrow) == pytest.approx(shared_cap(0.02) - 0.02)
    assert east(creeping) == pytest.approx(shared_cap(0.02))  # all-round sight needs no heading


def _evader_east(obs: np.ndarray, distance: float, captured: bool) -> None:
    """Pursuer 0 sees evader 0 `distance` m to its +x side, standing, caught or free."""
    at = SPEC.index("evaders", 0, "dx")
    obs[0, 0, at : at + 7] = [distance, 0.0, 0.0, 0.0, 1.0, 0.0, float(captured)]


def test_a_caught_evader_is_a_hazard_of_capture_radius_and_a_free_one_is_none():
    obs = blank_obs()
    _evader_east(obs, 0.6, captured=True)
    rate, buffer = ShieldParams.approach_rate, ShieldParams.safety_buffer
    assert _east_of(SafetyShield(SPEED), obs) == pytest.approx(rate * (0.6 - 0.3 - 0.1 - buffer))
    free = blank_obs()
    _evader_east(free, 0.35, captured=False)  # the shield must not keep a pursuer from catching it
    assert _east_of(SafetyShield(SPEED), free) == pytest.approx(SPEED)


def test_a_teammate_pressing_a_pursuer_against_the_evader_it_caught_does_not_push_it_into_the_evader():
    # caught evader 0.4 m east (cap -0.075 m/s: back off), teammate 0.22 m west (also back
    # off): no velocity keeps both, and the caught evader, which does not move, wins
    obs = blank_obs()
    _evader_east(obs, 0.4, captured=True)
    _mate_east(obs, -0.22)
    evader_cap = ShieldParams.approach_rate * (0.4 - 0.3 - 0.1 - ShieldParams.safety_buffer)
    assert _east_of(SafetyShield(SPEED), obs) <= evader_cap + 1e-9


class Fixed(Straight):
    """Every pursuer gives one fixed action, as given (not normalised)."""

    name = "fixed"

    def __init__(self, action):
        self.direction = np.asarray(action, float)


def test_shielded_actions_are_clipped_as_the_environment_clips_them_and_stay_in_the_unit_disc():
    # the env clips each axis to [-1, 1] and then the norm: (2, 0.5) flies as (1, 0.5) / |(1, 0.5)|
    policy = Shielded(Fixed((2.0, 0.5)), SafetyShield(SPEED))
    policy.reset(1)
    np.testing.assert_allclose(policy.act(blank_obs(), SPEC)[0, 0], np.array([1.0, 0.5]) / np.hypot(1.0, 0.5))
    # flying north with something 0.1 m due east (one ray's hit): the shield backs it off west
    # as well, (-0.075, 0.3) m/s, and the action that comes out is cut back to the unit disc
    obs = blank_obs()
    obs[0, 0, SPEC.index("rays", 0, "range_0")] = 0.1
    north = Shielded(Fixed((0.0, 1.0)), SafetyShield(SPEED))
    north.reset(1)
    out = north.act(obs, SPEC)[0, 0]
    assert out[0] < 0 and np.linalg.norm(out) == pytest.approx(1.0)


def test_flying_away_from_a_wall_earns_no_extra_allowance_toward_it():
    # the gap is shortened by the closing speed only: a velocity away from the wall does not lengthen it
    obs = blank_obs()
    wall_east(obs, 0.2)
    obs[0, 0, SPEC.index("self", 0, "vx")] = -SPEED
    assert _east_of(SafetyShield(SPEED), obs) == pytest.approx(WALL_CAP)


class _Giving(Straight):
    """Gives `make(shape)` as its actions, whatever it sees (shape (W, N, 2))."""

    name = "giving"

    def __init__(self, make):
        self.make = make

    def act(self, obs, spec):
        return self.make(obs.shape[:2] + (2,))


def test_shielded_reads_a_torch_tensor_with_grad_or_in_bfloat16_as_the_env_reads_actions():
    # a torch policy that acts without torch.no_grad: `eval --policy net.py:Net` ran, and with
    # --shield it stopped in a traceback (numpy cannot read a tensor that requires grad), while
    # bfloat16 (no numpy type) was refused as "no array of numbers"
    torch = pytest.importorskip("torch")
    want = Shielded(Fixed((0.5, -0.25)), SafetyShield(SPEED))
    want.reset(1)
    expected = want.act(blank_obs(), SPEC)
    for make in (lambda s: torch.full(s, 0.5, requires_grad=True) * torch.tensor([1.0, -0.5]),
                 lambda s: torch.tensor([0.5, -0.25], dtype=torch.bfloat16).expand(s)):
        policy = Shielded(_Giving(make), SafetyShield(SPEED))
        policy.reset(1)
        np.testing.assert_array_equal(policy.act(blank_obs(), SPEC), expected)


@pytest.mark.parametrize("what, make", [
    ("dtype bool", lambda s: np.ones(s, bool)),  # True would fly at full speed
    ("dtype <U3", lambda s: np.full(s, "0.5")),  # text read as its number
    ("dtype complex128", lambda s: np.full(s, 0.5 + 1j)),  # the imaginary part dropped with a warning
    ("masked entries", lambda s: np.ma.masked_array(np.zeros(s), mask=True)),  # hidden values flown
])
def test_shielded_refuses_actions_that_the_env_and_evaluate_refuse_naming_the_policy(what, make):
    # behind the shield these were flown silently; without it evaluate refuses them (policy.checked_actions)
    policy = Shielded(_Giving(make), SafetyShield(SPEED))
    policy.reset(1)
    with pytest.raises(ValueError, match=f"policy giving: act\\(\\) gave .*{what}"):
        policy.act(blank_obs(), SPEC)


def test_a_shield_for_a_full_observability_task_takes_no_position_noise():
    """Full observability applies no position_noise (sensing.perceive): the shield put on a model
    (`--shield`) must not shorten teammates' gaps for noise the observations do not have."""
    import math

    full = default_config(fidelity="point", observability="full", position_noise=0.3, field_of_view=1.5)
    shield = SafetyShield.from_config(full)
    assert (shield.position_noise, shield.field_of_view, shield.perception_radius) == (0.0, 2 * math.pi, math.inf)
    partial = SafetyShield.from_config(default_config(fidelity="point", position_noise=0.3))
    assert partial.position_noise == 0.3
