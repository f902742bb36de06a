"""Fall prevention: stop pushing and recover the stand before the safety layer has to damp.

A sampling planner with a 0.4 s horizon does not avoid a fall it sees coming
when none of its samples, drawn narrowly around the gait, leads elsewhere.
Read from recorded falls (``benchmarks/fall_forensics.py``, T2 in the
lock-step sim): the trunk pitched from 7° to 30° in 0.4 s while the robot ran at
0.5–0.8 m/s, three times its command, and its head struck the floor; the run's
fall test (base below 0.15 m) fired 2.5 s later. The safety layer of a real Go1
(:mod:`~amhe_cli.plants.go1.safety`) trips to damping at 40° — a robot that lies
down, not one that stays up.

:class:`FallReflex` watches the measured trunk every cycle. When it leaves a
safe envelope (tilt beyond :attr:`ReflexSettings.enter_tilt`, height over the
floor below :attr:`ReflexSettings.enter_height`, or a roll/pitch rate beyond
:attr:`ReflexSettings.enter_rate`), or when the planner forecasts that it will
(every plan it sampled last cycle tilts the trunk beyond
:attr:`ReflexSettings.enter_predicted_tilt` within its horizon: its model
foresees the fall where the task's narrow sampling finds no way out), the
closed loop replaces the task's command by :func:`recovery_command` — no
walking, no pushing, the trunk level at the stand's height where it stands —
and the planner tracks the ``stand`` gait with all four feet planted: searching wide
while the trunk tips, holding the stand's reference at the task's noise while it is steady
(:attr:`ReflexSettings.hold_tilt`). Once the
trunk has been back inside the tighter exit envelope for
:attr:`ReflexSettings.settle` seconds, the task resumes (its approach phase
first, if the robot lost the box meanwhile). A safety trip stays
the last line, not the controller.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from amhe_cli.errors import AmheError, check_names


@dataclass
class ReflexSettings:
    """The safe envelope of the trunk and the reflex's hysteresis (``reflex:`` in a run config).

    Attributes:
        enabled: False turns the reflex off (for comparison runs only).
        enter_tilt: trunk tilt [rad] (angle between its z axis and the world's) that starts a recovery.
            0.3 rad (17°): the walking robot's tilt stays under 0.2 rad; falls read
            from the sim went past 0.3 rad 0.2–0.3 s before they were beyond saving.
        enter_height: trunk height over the robot's floor [m] under which a recovery starts
            (the trot stands at 0.265; the task's fall test is 0.15).
        enter_rate: roll or pitch rate [rad/s] beyond which a recovery starts.
        enter_predicted_tilt: the planner's predicted tilt [rad] beyond which a recovery starts
            (0: off): when the last cycle's every sampled plan tilts the trunk past it within
            the horizon (:attr:`~amhe_cli.control.planner.Plan.predicted_tilt`), the fall is
            coming whatever the task's narrow sampling tries. 0.35 rad (20°): in a recorded
            nose-dive (T4 Baseline seed 1, lock-step) it fired 0.40 s before the measured
            tilt reached 17°, and never earlier in that run's 17 s (docs/fall_prevention.md).
        exit_tilt, exit_height, exit_rate: the envelope the trunk must be back inside ...
        settle: ... for this long [s] before the task resumes.
        hold_tilt: while recovering, the planner holds the stand with the task's narrow σ from the
            stand's reference (:func:`recovery_command`'s ``phase`` ``hold``) whenever the trunk is
            steady: tilted less than this [rad], roll and pitch rates under ``exit_rate``, height over
            ``exit_height``, and the last plan's forecast under ``enter_predicted_tilt``; otherwise it
            catches the trunk with ``recovery_noise`` (0: catches throughout). The wide σ finds the leg
            that saves a tipping trunk; on a steady one the wall clock's 16 samples of it walked the
            plan's mean off the stand, and two emulated Go1 runs fell standing, a pair of feet held in
            the air (T3 Adaptive seed 2: level at 25.0 s, on a diagonal pair from 25.3 s, over at 26.2 s;
            T4 Baseline seed 7: 3.3 s of recovery at 6–9° with a rear foot up, over at 43.1 s).
    """

    enabled: bool = True
    enter_tilt: float = 0.3
    enter_height: float = 0.19
    enter_rate: float = 3.0
    enter_predicted_tilt: float = 0.35
    exit_tilt: float = 0.12
    exit_height: float = 0.23
    exit_rate: float = 0.8
    settle: float = 0.4
    hold_tilt: float = 0.2

    def check(self) -> None:
        """Raise :class:`AmheError` for an envelope that cannot work (exit looser than enter)."""
        if not (0 < self.exit_tilt < self.enter_tilt and 0 < self.enter_height < self.exit_height
                and 0 < self.exit_rate < self.enter_rate and self.settle >= 0
                and (self.enter_predicted_tilt == 0 or self.enter_predicted_tilt > self.exit_tilt)
                and (self.hold_tilt == 0 or self.exit_tilt <= self.hold_tilt < self.enter_tilt)):
            raise AmheError(f"reflex settings {asdict(self)}: expected 0 < exit_tilt < enter_tilt, "
                            "0 < enter_height < exit_height, 0 < exit_rate < enter_rate, settle >= 0, "
                            "enter_predicted_tilt 0 (off) or above exit_tilt, hold_tilt 0 (off) or in "
                            "[exit_tilt, enter_tilt)")

    @classmethod
    def from_dict(cls, d: dict) -> "ReflexSettings":
        check_names(d, {f.name for f in fields(cls)}, "reflex setting")
        return cls(**{k: (bool(v) if k == "enabled" else float(v)) for k, v in d.items()})


def fallen(base_pos: np.ndarray, base_quat: np.ndarray, floor: float, fall_height: float,
           fall_tilt: float) -> np.ndarray:
    """(...) bool: the robot has fallen — its trunk under ``fall_height`` [m] over the floor at ``floor`` [m],
    or tilted beyond ``fall_tilt`` [rad] (past it no recorded run came back: the trunk rolls on over).

    Args:
        base_pos: (..., 3) trunk positions [m]; base_quat: (..., 4) (w, x, y, z).
    """
    base_pos = np.asarray(base_pos, dtype=float)
    return (base_pos[..., 2] - floor < fall_height) | (trunk_tilt(base_quat) > fall_tilt)


def trunk_tilt(quat: np.ndarray) -> np.ndarray:
    """(...) angle [rad] between the trunk's z axis and world z, for (..., 4) (w, x, y, z) quaternions."""
    q = np.asarray(quat, dtype=float)
    return np.arccos(np.clip(1.0 - 2.0 * (q[..., 1] ** 2 + q[..., 2] ** 2), -1.0, 1.0))


class FallReflex:
    """Hysteresis between pushing and recovering the stand, on the measured trunk.

    Args:
        settings: :class:`ReflexSettings`.
        floor: z of the robot's floor [m].

    Attributes:
        active: True while recovering.
        recoveries: recoveries started so far.
        holding: True while recovering with the trunk steady (:attr:`ReflexSettings.hold_tilt`):
            the planner holds the stand rather than catching the trunk.
    """

    def __init__(self, settings: ReflexSettings | None = None, floor: float = 0.0):
        self.settings = s = settings or ReflexSettings()
        s.check()
        self.floor = float(floor)
        self.active = False
        self.recoveries = 0
        self._inside_since: float | None = None
        self._steady = False

    @property
    def holding(self) -> bool:
        """True while recovering with the trunk steady at the last :meth:`update` (hold the stand, don't catch)."""
        return self.active and self._steady

    def update(self, t: float, base_pos: np.ndarray, base_quat: np.ndarray, base_angvel: np.ndarray,
               predicted_tilt: float | None = None) -> str | None:
        """Feed one measurement; returns a message when the reflex starts or ends a recovery, else None.

        Args:
            t: time [s].
            base_pos: (3,) trunk position [m]; base_quat: (4,) (w, x, y, z);
            base_angvel: (3,) body-frame angular velocity [rad/s].
            predicted_tilt: the last plan's :attr:`~amhe_cli.control.planner.Plan.predicted_tilt` [rad],
                or None (no plan yet).
        """
        s = self.settings
        if not s.enabled:
            return None
        tilt = float(trunk_tilt(base_quat))
        height = float(base_pos[2]) - self.floor
        rate = float(np.max(np.abs(base_angvel[:2])))
        self._steady = (s.hold_tilt > 0 and tilt < s.hold_tilt and rate < s.exit_rate and height > s.exit_height
                        and not (s.enter_predicted_tilt > 0 and predicted_tilt is not None
                                 and predicted_tilt > s.enter_predicted_tilt))
        if not self.active:
            why = []
            if tilt > s.enter_tilt:
                why.append(f"trunk tilt {np.degrees(tilt):.0f}° > {np.degrees(s.enter_tilt):.0f}°")
            if height < s.enter_height:
                why.append(f"trunk height {height:.3f} m < {s.enter_height:.2f} m")
            if rate > s.enter_rate:
                why.append(f"roll/pitch rate {rate:.1f} rad/s > {s.enter_rate:.1f}")
            if s.enter_predicted_tilt > 0 and predicted_tilt is not None and predicted_tilt > s.enter_predicted_tilt:
                why.append(f"every sampled plan tilts the trunk past {np.degrees(s.enter_predicted_tilt):.0f}° "
                           f"({np.degrees(predicted_tilt):.0f}°)")
            if why:
                self.active, self._inside_since = True, None
                self.recoveries += 1
                return f"fall prevention: {', '.join(why)}; stop pushing, recovering the stand"
            return None
        inside = tilt < s.exit_tilt and height > s.exit_height and rate < s.exit_rate
        if not inside:
            self._inside_since = None
            return None
        if self._inside_since is None:
            self._inside_since = t
        if t - self._inside_since >= s.settle - 1e-9:
            self.active = False
            return f"fall prevention: trunk level again (tilt {np.degrees(tilt):.0f}°); resuming the task"
        return None


def recovery_command(cmd: dict, base_xy: np.ndarray, base_yaw: float, hold: bool = False) -> dict:
    """The task command ``cmd`` turned into a recovery: stand where the robot is, heading as it is, box held.

    Args:
        hold: the trunk is steady (:attr:`FallReflex.holding`): ``phase`` ``"hold"``, which the
            planner samples with the task's σ from the stand's reference, not the recovery's σ.
    Returns:
        a copy of ``cmd`` with ``waypoint`` the trunk's position, ``yaw`` its
        heading, ``speed`` and ``omega`` 0, ``box_speed`` 0 (the box's reference
        stays where the box is), no ``reach``, and ``phase`` ``"recover"`` (or ``"hold"``).
    """
    out = {k: v for k, v in cmd.items() if k != "reach"}
    out.update(waypoint=np.asarray(base_xy, dtype=float).copy(), yaw=float(base_yaw), speed=0.0, omega=0.0,
               box_speed=0.0, phase="hold" if hold else "recover")
    return out

