"""The setpoint logic of D virtual Crazyflies, vectorised: which command flies each drone now.

Modelled on the public Crazyflie firmware's commander:
- low-level setpoints (generic commander, legacy commander) take priority over the
  high-level commander (HLC) and disable its planner, until `notify_setpoint_stop`
  relaxes the priority;
- setpoint watchdog: 0.5 s after the last low-level setpoint the drone levels (its
  horizontal velocity is no longer controlled, the height is held) and the HLC may take
  over; 2 s after it the motors stop;
- HLC take-off, land and go-to are smooth (minimum-jerk) position trajectories from the
  current position; while the HLC governs and idles (at boot, after `stop`, after a
  finished landing) it holds the motors off;
- an emergency stop cuts the motors until the drone is restarted (here: never).

Packet handlers write one drone's registers (`set_*`, `hl_*`); `compute` turns all
registers into airframe commands in one vectorised pass per tick. Times in s (the
virtual clock), positions in m and velocities in m/s in each drone's world frame.
"""

from __future__ import annotations

import numpy as np

LEVEL_AFTER = 0.5  # s without low-level setpoints: level out, HLC may take over
STOP_AFTER = 2.0  # s: motors off unless the HLC flies
ESTOP_WATCHDOG = 1.0  # s: an armed emergency-stop watchdog fires if not refreshed

# low-level setpoint modes
NONE, STOP, VELOCITY, HOVER, POSITION, ATTITUDE = 0, 1, 2, 3, 4, 5
# priorities (as the firmware's): disabled, high-level (= lowest), CRTP
PRIO_DISABLED, PRIO_HIGH_LEVEL, PRIO_CRTP = 0, 1, 2
# HLC planner states: disabled by low-level control (silent), idle (motors off), flying, landing
HL_DISABLED, HL_IDLE, HL_FLYING, HL_LANDING = 0, 1, 2, 3
# what flew each drone in the last tick
SRC_OFF, SRC_HL, SRC_VELOCITY, SRC_HOVER, SRC_POSITION, SRC_LEVEL = 0, 1, 2, 3, 4, 5

POSITION_GAIN = 2.0  # 1/s: position error -> velocity, for position setpoints and HLC tracking
POSITION_MAX_SPEED = 1.0  # m/s


def min_jerk(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shape (s in [0, 1]) -> (fraction of the way, its derivative d/ds)."""
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2), 30 * s**2 * (1 - s) ** 2


class Commander:
    """Setpoint registers and rules for n drones (see module docstring)."""

    def __init__(self, n: int):
        self.n = n
        self.mode = np.zeros(n, np.int64)
        self.values = np.zeros((n, 4))  # meaning depends on mode (see set_low_level)
        self.sp_time = np.full(n, -np.inf)
        self.priority = np.full(n, PRIO_DISABLED)
        self.relax_at = np.full(n, np.inf)
        self.hl_state = np.full(n, HL_IDLE)  # at boot the planner idles: motors off
        self.hl_p0 = np.zeros((n, 3))
        self.hl_p1 = np.zeros((n, 3))
        self.hl_t0 = np.zeros(n)
        self.hl_duration = np.ones(n)
        self.hl_enabled = np.ones(n, bool)
        self.armed = np.ones(n, bool)  # Crazyflie 2.x arms itself
        self.locked = np.zeros(n, bool)
        self.estop_deadline = np.full(n, np.inf)
        self.source = np.full(n, SRC_OFF)
        self.z_ref = np.zeros(n)
        self.hl_finished = np.zeros(n, bool)

    # ------------------------------------------------------------------ writers (one drone)

    def set_low_level(self, i: int, t: float, mode: int, values=(0.0, 0.0, 0.0, 0.0)) -> None:
        """A low-level setpoint. values: VELOCITY (vx, vy, vz, yaw rate deg/s), HOVER (vx, vy
        body frame, yaw rate, z), POSITION (x, y, z, yaw deg); STOP and ATTITUDE ignore them."""
        self.mode[i] = mode
        self.values[i] = values
        self.sp_time[i] = t
        self.priority[i] = PRIO_CRTP
        self.relax_at[i] = np.inf
        self.hl_state[i] = HL_DISABLED

    def notify_setpoint_stop(self, i: int, t: float, remain_s: float) -> None:
        self.relax_at[i] = t + remain_s

    # High-level commander plans of drone i from time t (s): pos (3,) m where it is now and
    # target (3,) m, both in the drone's own lab frame; height (m); duration (s).

    def hl_takeoff(self, i: int, t: float, pos: np.ndarray, height: float, duration: float) -> None:
        self._hl_plan(i, t, pos, np.array([pos[0], pos[1], height]), duration, HL_FLYING)

    def hl_land(self, i: int, t: float, pos: np.ndarray, height: float, duration: float) -> None:
        self._hl_plan(i, t, pos, np.array([pos[0], pos[1], height]), duration, HL_LANDING)

    def hl_go_to(self, i: int, t: float, pos: np.ndarray, target: np.ndarray, duration: float, relative: bool) -> None:
        self._hl_plan(i, t, pos, pos + target if relative else np.asarray(target, np.float64), duration, HL_FLYING)

    def _hl_plan(self, i: int, t: float, pos: np.ndarray, target: np.ndarray, duration: float, state: int) -> None:
        if not self.hl_enabled[i] or self.locked[i]:
            return
        self.hl_p0[i] = pos
        self.hl_p1[i] = target
        self.hl_t0[i] = t
        self.hl_duration[i] = max(float(duration), 1e-3)
        self.hl_state[i] = state

    def hl_stop(self, i: int) -> None:
        """HLC stop: the planner idles; when it governs, that stops the motors."""
        self.hl_state[i] = HL_IDLE

    def emergency_stop(self, i: int) -> None:
        self.locked[i] = True

    def arm(self, i: int, armed: bool) -> None:
        self.armed[i] = bool(armed) and not self.locked[i]

    def emergency_watchdog(self, i: int, t: float) -> None:
        self.estop_deadline[i] = t + ESTOP_WATCHDOG

    # ------------------------------------------------------------------ all drones, per tick

    def compute(self, t: float, pos: np.ndarray, vel: np.ndarray, yaw: np.ndarray, dt: float):
        """Airframe commands: v_xy (n, 2) m/s, z_ref (n,) m, vz_ff (n,) m/s, motors (n,) bool.

        pos (n, 3) m, vel (n, 3) m/s, yaw (n,) rad: the drones' state in their world frame.
        """
        self.locked |= t > self.estop_deadline
        relax = t >= self.relax_at
        self.priority = np.where(relax & (self.priority > PRIO_HIGH_LEVEL), PRIO_HIGH_LEVEL, self.priority)
        self.relax_at = np.where(relax, np.inf, self.relax_at)
        age = t - self.sp_time
        watchdog = (self.priority == PRIO_CRTP) & (age > LEVEL_AFTER)
        self.priority = np.where(watchdog, PRIO_DISABLED, self.priority)

        hl_governs = (self.hl_state != HL_DISABLED) & (self.priority <= PRIO_HIGH_LEVEL)
        s = (t - self.hl_t0) / self.hl_duration
        frac, dfrac = min_jerk(s)
        hl_pos = self.hl_p0 + (self.hl_p1 - self.hl_p0) * frac[:, None]
        hl_vel = (self.hl_p1 - self.hl_p0) * (dfrac / self.hl_duration)[:, None]
        landed = hl_governs & (self.hl_state == HL_LANDING) & (s >= 1.0)
        self.hl_state = np.where(landed, HL_IDLE, self.hl_state)
        hl_flies = hl_governs & np.isin(self.hl_state, (HL_FLYING, HL_LANDING))

        fresh = age <= LEVEL_AFTER
        flying_mode = np.isin(self.mode, (VELOCITY, HOVER, POSITION, ATTITUDE))
        low = ~hl_governs & fresh & flying_mode
        level = ~hl_governs & ~low & flying_mode & (age <= STOP_AFTER)
        source = np.select(
            [hl_flies, hl_governs, low & (self.mode == VELOCITY), low & (self.mode == HOVER), low & (self.mode == POSITION), low | level],
            [SRC_HL, SRC_OFF, SRC_VELOCITY, SRC_HOVER, SRC_POSITION, SRC_LEVEL],
            SRC_OFF,
        )
        source = np.where(self.locked | ~self.armed, SRC_OFF, source)

        vv = self.values
        v_xy = np.zeros((self.n, 2))
        vz_ff = np.zeros(self.n)
        z_ref = np.where(self.source == SRC_OFF, pos[:, 2], self.z_ref)  # from rest: start where it is
        # velocity mode integrates its vertical speed into the height reference
        entering = (source == SRC_VELOCITY) & (self.source != SRC_VELOCITY)
        z_ref = np.where(entering, pos[:, 2], z_ref)
        is_vel = source == SRC_VELOCITY
        z_ref = np.where(is_vel, z_ref + vv[:, 2] * dt, z_ref)
        vz_ff = np.where(is_vel, vv[:, 2], vz_ff)
        v_xy = np.where(is_vel[:, None], vv[:, :2], v_xy)
        c, s_ = np.cos(yaw), np.sin(yaw)
        body = np.stack([c * vv[:, 0] - s_ * vv[:, 1], s_ * vv[:, 0] + c * vv[:, 1]], -1)
        v_xy = np.where((source == SRC_HOVER)[:, None], body, v_xy)
        z_ref = np.where(source == SRC_HOVER, vv[:, 3], z_ref)
        z_ref = np.where(source == SRC_POSITION, vv[:, 2], z_ref)
        v_pos = _clip_norm(POSITION_GAIN * (vv[:, :2] - pos[:, :2]), POSITION_MAX_SPEED)
        v_xy = np.where((source == SRC_POSITION)[:, None], v_pos, v_xy)
        is_hl = source == SRC_HL
        v_hl = hl_vel[:, :2] + POSITION_GAIN * (hl_pos[:, :2] - pos[:, :2])
        v_xy = np.where(is_hl[:, None], v_hl, v_xy)
        z_ref = np.where(is_hl, hl_pos[:, 2], z_ref)
        vz_ff = np.where(is_hl, hl_vel[:, 2], vz_ff)
        v_xy = np.where((source == SRC_LEVEL)[:, None], vel[:, :2], v_xy)
        self.source = source
        self.z_ref = np.maximum(z_ref, 0.0)
        self.hl_finished = (self.hl_state == HL_FLYING) & (s >= 1.0)
        return v_xy, self.z_ref.copy(), vz_ff, source != SRC_OFF


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v * np.minimum(1.0, limit / np.maximum(n, 1e-12))
