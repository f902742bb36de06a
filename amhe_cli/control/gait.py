"""Gait references: joint-position targets and contact schedules over a gait cycle.

The planner (:mod:`~amhe_cli.control.planner`) samples joint targets *around* a gait
reference, so the reference only has to be a plausible periodic motion for a
commanded base velocity; balance and steering come from the sampling. A
:class:`Gait` generates it from foot trajectories in each hip's sagittal plane
through the leg inverse kinematics of :mod:`~amhe_cli.control.maneuver`:

* stance: the foot slides backward under the hip at the commanded speed,
  covering the step length ``L = v · duty · period``;
* swing: the foot returns forward on a cycloid and lifts by ``step_height``;
* stride model: PD servos lag and feet slip, so a kinematic reference walks
  only part of its speed (23 % at 0.2 m/s, kp 100 / kd 4) and turns less
  still; the trot's ``stride_gain``/``stride_deadband``/``turn_gain``, fitted
  by ``benchmarks/gait_calibration.py``, make the reference ask for what the
  plant then realises, so the planner's mean already walks at the command.

Three gaits cover the tasks (docs/tasks.md): ``trot`` (diagonal pairs, T1–T4),
``stand`` (all feet planted) and ``tripod`` (front-right foot free for a
one-leg push, T5). A free leg's reference is a raised, forward-reaching pose,
or — where the task gives a *reach* (:meth:`~amhe_cli.control.tasks.Task.command`)
— the pose whose foot follows the reach's path through the three-joint leg IK
(:func:`~amhe_cli.control.maneuver.leg_ik3`), which the planner refines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amhe_cli.control.maneuver import leg_fk3, leg_ik, leg_ik3
from amhe_cli.model.scene import STAND_JOINTS

#: Leg order of the joint vector (GO1_JOINTS): FR, FL, RR, RL.
LEGS = ("FR", "FL", "RR", "RL")
#: Lateral offset of each hip from the trunk's centre line [m] (+ = left).
HIP_Y = np.array([-0.127, 0.127, -0.127, 0.127])
#: Position of each leg's abduction joint in the trunk frame [m] (models/go1.xml).
HIP_POS = np.array([[0.1881, -0.04675, 0.0], [0.1881, 0.04675, 0.0], [-0.1881, -0.04675, 0.0], [-0.1881, 0.04675, 0.0]])
#: Hip-to-foot height of the gait's stance legs [m]: 1.5 cm above the standing pose's
#: 0.265, so that PD sag under the trunk's weight leaves the base near its standing height.
STAND_HEIGHT = 0.28
#: Leg speed [m/s] over which the stride deadband is switched on (tanh), so a standing command stays still.
STRIDE_SMOOTH = 0.03


@dataclass(frozen=True)
class Gait:
    """A periodic gait.

    Attributes:
        name: ``trot``, ``stand`` or ``tripod``.
        period: cycle time [s].
        duty: fraction of the cycle each foot is in stance.
        offsets: (4,) phase offset of each leg (FR, FL, RR, RL) in cycles.
        step_height: swing-foot lift of the reference [m] (PD servos realise about half).
        free_legs: legs not in the gait (tripod: the pushing leg), held at
            ``free_pose`` and left to the planner; they never count as stance.
        free_pose: (3,) hip/thigh/calf reference of a free leg [rad].
        stride_gain, stride_deadband: the stride model of the PD-servoed legs:
            a leg whose reference slides at ``u`` [m/s] moves the base at about
            ``stride_gain · (u − stride_deadband)`` (the servos lag and the feet
            slip), so the reference slides at ``u/gain + deadband`` (smoothly
            signed) to realise ``u``. 1 and 0: the kinematic reference.
        turn_gain: realised fraction of a yaw rate after the stride model (feet
            slip sideways when the trunk turns); the reference asks ``ω / turn_gain``.
        sideways_gain: realised fraction of a commanded sideways speed (the reference asks ``vy / sideways_gain``);
            0: the gait has no sidestep and ignores one. The trot's 0.57: the raw reference walked 57 % of ±0.1 m/s
            across (``benchmarks/gait_calibration.py --raw``, kp 100 / kd 4); so calibrated, ±0.1 m/s asked
            walks +0.087 / −0.079 m/s across at 0.2 m/s forward, turning 0.15 rad/s away (which the heading's
            feedback takes back).
        body_shift: (2,) trunk offset (x, y) over the planted feet of a standing
            gait [m]. The tripod's: the robot's centre of mass (0.2 cm from the
            trunk origin) lies on the line from FL to RR, the edge of the three
            stance feet's triangle, so the trunk moves back and left by (−4, +5)
            cm, 6 cm inside it; unshifted, the free foot bore weight and dragged.
    """

    name: str = "trot"
    period: float = 0.5
    duty: float = 0.5
    offsets: tuple = (0.0, 0.5, 0.5, 0.0)
    step_height: float = 0.08
    free_legs: tuple = ()
    free_pose: tuple = (0.0, 0.3, -1.6)
    stride_gain: float = 1.0
    stride_deadband: float = 0.0
    turn_gain: float = 1.0
    body_shift: tuple = (0.0, 0.0)
    sideways_gain: float = 0.0

    @property
    def walking(self) -> bool:
        return self.duty < 1.0

    def phase(self, t: np.ndarray | float) -> np.ndarray:
        """(..., 4) phase of each leg in [0, 1) at time(s) ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        return np.mod(t[..., None] / self.period + np.asarray(self.offsets), 1.0)

    def contact(self, t: np.ndarray | float) -> np.ndarray:
        """(..., 4) bool: which feet are in stance at ``t``."""
        c = self.phase(t) < self.duty if self.walking else np.ones(np.shape(t) + (4,), bool)
        for leg in self.free_legs:
            c[..., LEGS.index(leg)] = False
        return c

    def mode(self, t: float) -> int:
        """Index of the contact mode at ``t`` (a 4-bit stance pattern); a change is a mode switch."""
        c = self.contact(t)
        return int(np.dot(c.astype(int), [1, 2, 4, 8]))

    def reference(self, t: np.ndarray | float, v: float = 0.0, omega: float = 0.0, reach: dict | None = None,
                  sideways: float = 0.0) -> np.ndarray:
        """Joint-position reference at time(s) ``t``.

        Args:
            t: time(s) [s], scalar or (N,).
            v: commanded forward speed of the base [m/s].
            omega: commanded yaw rate [rad/s] (steers by unequal step lengths).
            reach: the free legs' foot path (a task command's ``reach``): ``foot`` (3,)
                the foot centre at time ``t0`` [s] in the trunk frame [m], moving at
                ``velocity`` (3,) [m/s]; None: the free legs hold ``free_pose``.
            sideways: commanded sideways speed of the base [m/s], + left: each stance foot slides across under
                its hip (its abduction turned by ``asin(y / h)``, h the hip-to-foot height) as it slides back
                for ``v``, its swing returns it (a gait whose ``sideways_gain`` is 0 has no sidestep).
        Returns:
            (..., 12) joint targets [rad] in GO1_JOINTS order.
        """
        t = np.asarray(t, dtype=float)
        out = np.broadcast_to(STAND_JOINTS, t.shape + (12,)).copy()
        if self.walking:
            ph = self.phase(t)
            stance = ph < self.duty
            s_st = ph / self.duty
            s_sw = (ph - self.duty) / (1.0 - self.duty)
            u = v - omega / self.turn_gain * HIP_Y  # (4,) speed each leg must realise
            u = u / self.stride_gain + self.stride_deadband * np.tanh(u / STRIDE_SMOOTH)
            length = u * self.duty * self.period  # (4,) step length per leg
            x = np.where(stance, length * (0.5 - s_st),
                         length * (-0.5 + s_sw - np.sin(2 * np.pi * s_sw) / (2 * np.pi)))
            lift = np.where(stance, 0.0, self.step_height * 0.5 * (1 - np.cos(2 * np.pi * s_sw)))
            leg = leg_ik(-x, STAND_HEIGHT - lift)  # (..., 4, 2)
            out[..., 1::3] = leg[..., 0]
            out[..., 2::3] = leg[..., 1]
            if sideways and self.sideways_gain > 0:
                width = sideways / self.sideways_gain * self.duty * self.period  # the step across [m]
                y = np.where(stance, width * (0.5 - s_st),
                             width * (-0.5 + s_sw - np.sin(2 * np.pi * s_sw) / (2 * np.pi)))
                out[..., 0::3] += np.arcsin(np.clip(y / (STAND_HEIGHT - lift), -0.5, 0.5))
        if not self.walking and any(self.body_shift):
            for i in range(4):  # planted feet where they stand, the trunk shifted over them
                foot = leg_fk3(STAND_JOINTS[3 * i:3 * i + 3], np.sign(HIP_POS[i, 1]))
                foot[:2] -= self.body_shift
                out[..., 3 * i:3 * i + 3] = leg_ik3(foot, np.sign(HIP_POS[i, 1]))
        for name in self.free_legs:
            i = LEGS.index(name)
            if reach is None:
                out[..., 3 * i:3 * i + 3] = self.free_pose
            else:
                foot = reach["foot"] + np.multiply.outer(t - reach["t0"], reach["velocity"])
                out[..., 3 * i:3 * i + 3] = leg_ik3(foot - HIP_POS[i], np.sign(HIP_POS[i, 1]))
        return out


#: The gaits by name.
GAITS = {
    # stride model fitted by benchmarks/gait_calibration.py --raw at kp 100 / kd 4: the raw reference
    # walked 0.58 · (v − 0.12) m/s, 23 % of a 0.2 m/s command
    # and turned 32 % of a commanded yaw rate once the stride model was in
    "trot": Gait(stride_gain=0.58, stride_deadband=0.12, turn_gain=0.32, sideways_gain=0.57),
    "stand": Gait(name="stand", duty=1.0),
    "tripod": Gait(name="tripod", duty=1.0, free_legs=("FR",), body_shift=(-0.04, 0.05)),
}
