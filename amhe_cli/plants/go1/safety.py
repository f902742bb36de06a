"""The safety layer every Go1 command passes, and the limits it enforces.

Every number here is a named setting with its reason (:class:`SafetySettings`);
``amhe run --target go1`` can override them from a run config's ``safety:``
section, never silently. Two parts:

* :meth:`SafetyLayer.filter` shapes each outgoing command: joint targets
  clamped to the SDK's ``PositionLimit`` ranges, their rate of change capped,
  gains capped;
* :meth:`SafetyLayer.check` watches each incoming state and *trips* (the
  relay then commands damping and the run ends with a one-line reason) on
  roll/pitch beyond a limit, an estimated torque at its limit for too long, or
  mechanical power Σ|τ·dq| over a limit for several cycles — the idea of the
  SDK's ``PowerProtect(level)``, which trips at ≈ 100 W × level.

The watchdogs on time (state, plan, mocap) live in the relay
(:mod:`~amhe_cli.plants.go1.relay`), which owns the clock; their limits are here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from amhe_cli.errors import AmheError

#: The SDK's ``PositionLimit`` (legged_sdk 3.8) per joint kind [rad]: hip, thigh, calf.
#: Tighter than the URDF ranges; a target outside them is clamped, not refused.
SDK_JOINT_LOWER = np.tile([-1.047, -0.663, -2.721], 4)
SDK_JOINT_UPPER = np.tile([1.047, 2.966, -0.837], 4)
#: Go1 motor torque limits [N·m] per joint kind (hip, thigh, calf), docs/reference.md#go1.
TORQUE_LIMIT = np.tile([23.7, 23.7, 35.55], 4)


@dataclass
class SafetySettings:
    """Limits of the safety layer and the relay's watchdogs (all SI).

    Attributes:
        kp_max: cap on the position gain [N·m/rad]. Public Go1 low-level
            controllers use 20–100; the planner's model was fitted at 100.
        kd_max: cap on the velocity gain [N·m·s/rad]; public controllers 1–5.
        max_target_rate: cap on how fast a joint target may move [rad/s].
            Plans of the trot (interpolated as the relay does) move thigh and
            calf targets at ≤ 6 rad/s in 99 % of steps and ≈ 13 rad/s at peak
            (measured on T1); 30 leaves that alone and still spreads a jump of a
            whole plan (a planner glitch) of 1 rad over 33 ms instead of one 2 ms step.
        max_tilt: roll or pitch beyond this trips [rad] (0.7 ≈ 40°: a pushing
            Go1 stays within ±15°; beyond 40° it is falling).
        torque_fraction, torque_cycles: an estimated joint torque at or above
            this fraction of its motor limit for this many consecutive states
            trips (100 states = 0.2 s at 500 Hz: a stalled or blocked leg, not
            a footfall peak).
        power_limit, power_cycles: mechanical power Σ|τ·dq| over all motors
            above this [W] for this many consecutive states trips (PowerProtect
            level 7 ≈ 700 W; a trotting Go1 averages ≈ 100–250 W; 10 states = 20 ms).
        state_timeout: no valid robot state for this long → damping [s]. A
            trusted ROS bridge treats 20–50 ms without data as link loss; 40 ms
            leaves a command period and its jitter so the damping packet is on
            the wire within 50 ms of the last state.
        plan_periods: no fresh plan for this many planner periods → hold the
            pose with soft gains (the planner stalled; the robot must not
            replay a stale trajectory).
        mocap_timeout: a box or trunk pose older than this → stop pushing and
            hold the stand [s] (120 Hz mocap: 12 frames lost).
        ramp_time: the ramp from the measured pose to the stand [s] (slow
            enough that Kp·Δq stays small when the robot starts lying down).
        hold_kp, hold_kd: soft gains of the hold on a stale plan.
        damping_kd: velocity gain of the damping command [N·m·s/rad] (mode 0x00
            plus Kd: the motors resist motion and the robot sinks slowly).
        damping_burst: damping packets sent back to back before closing (a lost
            UDP datagram must not leave the last servo command active).
    """

    kp_max: float = 120.0
    kd_max: float = 8.0
    max_target_rate: float = 30.0
    max_tilt: float = 0.7
    torque_fraction: float = 1.0
    torque_cycles: int = 100
    power_limit: float = 700.0
    power_cycles: int = 10
    state_timeout: float = 0.04
    plan_periods: float = 3.0
    mocap_timeout: float = 0.1
    ramp_time: float = 2.0
    hold_kp: float = 30.0
    hold_kd: float = 2.0
    damping_kd: float = 4.0
    damping_burst: int = 20

    def check(self) -> None:
        """Raises AmheError for a setting that is not positive (or a gain cap above the wire's range)."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not np.isfinite(v) or v <= 0:
                raise AmheError(f"safety.{f.name} = {v}: expected a positive number")
        if self.kp_max > 2047 or self.kd_max > 4095:
            raise AmheError("safety gain caps exceed the LowCmd range (Kp ≤ 2047, Kd ≤ 4095)")

    @classmethod
    def from_dict(cls, d: dict | None) -> "SafetySettings":
        """From a run config's ``safety:`` mapping; AmheError on an unknown key."""
        from amhe_cli.errors import check_names
        d = dict(d or {})
        check_names(d, [f.name for f in fields(cls)], "safety setting")
        out = cls(**{k: type(getattr(cls, k))(v) for k, v in d.items()})
        out.check()
        return out

    def to_dict(self) -> dict:
        return asdict(self)


class SafetyTrip(AmheError):
    """A safety limit tripped: the robot is put into damping and the run ends."""


class SafetyLayer:
    """Shapes outgoing commands and watches incoming states (see module docstring).

    Args:
        settings: :class:`SafetySettings`.
    """

    def __init__(self, settings: SafetySettings | None = None):
        self.settings = settings or SafetySettings()
        self.settings.check()
        self._torque_count = np.zeros(12, dtype=int)
        self._power_count = 0
        self.clamped = 0

    def filter(self, q_target: np.ndarray, q_prev: np.ndarray | None, kp: np.ndarray, kd: np.ndarray,
               dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A command made safe to send.

        Args:
            q_target: (12,) wanted joint targets [rad] (GO1_JOINTS order).
            q_prev: (12,) the target sent last [rad], or None (no rate cap).
            kp, kd: (12,) or scalar wanted gains.
            dt: time since the last command [s].
        Returns:
            (q, kp, kd): (12,) targets clamped to :data:`SDK_JOINT_LOWER`/``UPPER``
            and moved at most ``max_target_rate·dt`` from ``q_prev``; gains clipped
            to [0, kp_max] and [0, kd_max]. NaN targets are replaced by ``q_prev``
            (or the clamp's midpoint) and counted in :attr:`clamped`.
        """
        s = self.settings
        q = np.array(q_target, dtype=float)
        bad = ~np.isfinite(q)
        if bad.any():
            fallback = q_prev if q_prev is not None else (SDK_JOINT_LOWER + SDK_JOINT_UPPER) / 2
            q[bad] = np.asarray(fallback)[bad]
        if q_prev is not None:
            step = s.max_target_rate * max(dt, 0.0)
            q = np.clip(q, q_prev - step, q_prev + step)
        clamped = np.clip(q, SDK_JOINT_LOWER, SDK_JOINT_UPPER)
        self.clamped += int(bad.sum() + (clamped != q).sum())
        kp = np.clip(np.nan_to_num(np.broadcast_to(np.asarray(kp, dtype=float), (12,))), 0.0, s.kp_max)
        kd = np.clip(np.nan_to_num(np.broadcast_to(np.asarray(kd, dtype=float), (12,))), 0.0, s.kd_max)
        return clamped, kp, kd

    def check(self, rpy: np.ndarray, tau_est: np.ndarray, dq: np.ndarray) -> None:
        """Check one robot state; raises :class:`SafetyTrip` with a one-line reason when a limit trips.

        Args:
            rpy: (3,) roll, pitch, yaw from the IMU [rad].
            tau_est: (12,) estimated joint torques [N·m].
            dq: (12,) joint velocities [rad/s].
        """
        s = self.settings
        roll, pitch = float(rpy[0]), float(rpy[1])
        if not (np.isfinite(roll) and np.isfinite(pitch)):
            raise SafetyTrip("IMU roll/pitch is not a number")
        if max(abs(roll), abs(pitch)) > s.max_tilt:
            raise SafetyTrip(f"tilt limit: roll {np.degrees(roll):+.0f}°, pitch {np.degrees(pitch):+.0f}° "
                             f"beyond ±{np.degrees(s.max_tilt):.0f}°")
        over = np.abs(tau_est) >= s.torque_fraction * TORQUE_LIMIT
        self._torque_count = np.where(over, self._torque_count + 1, 0)
        if (self._torque_count >= s.torque_cycles).any():
            j = int(np.argmax(self._torque_count))
            raise SafetyTrip(f"torque limit: joint {j} at {tau_est[j]:+.1f} N·m for {s.torque_cycles} states")
        power = float(np.sum(np.abs(np.asarray(tau_est) * np.asarray(dq))))
        self._power_count = self._power_count + 1 if power > s.power_limit else 0
        if self._power_count >= s.power_cycles:
            raise SafetyTrip(f"power limit: Σ|τ·dq| = {power:.0f} W above {s.power_limit:.0f} W "
                             f"for {s.power_cycles} states")
