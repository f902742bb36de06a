"""Scripted probing manoeuvres: joint targets that excite the box without a planner.

The probing step of the paper (§V: Adaptive-MHE "first initializes its belief via
an offline probing estimation step") needs interaction data before any belief
exists. A *lunge* does it with all four feet planted: the trunk is shifted
forward by leg inverse kinematics so the robot's front bumps the box (the bump
shows the mass), then retreats while the box slides free (the slide shows μ).
Several lunges of rising reach follow the box as it moves away.
"""

from __future__ import annotations

import numpy as np

from amhe_cli.model.scene import STAND_JOINTS

THIGH = 0.213  #: thigh length [m]
CALF = 0.213   #: calf length [m]


def leg_ik(dx: np.ndarray | float, height: float = 0.2648) -> np.ndarray:
    """Sagittal-plane IK of one Go1 leg: thigh and calf angles [rad].

    Args:
        dx: forward shift of the hip over a planted foot [m] (scalar or (N,)).
        height: hip height above the foot centre [m].
    Returns:
        (..., 2) (thigh, calf) angles placing the foot ``dx`` behind the hip.
    """
    dx = np.asarray(dx, dtype=float)
    d = np.sqrt(dx ** 2 + height ** 2)
    alpha = np.arccos(np.clip(d / (THIGH + CALF), -1.0, 1.0))
    phi = np.arctan2(dx, height)
    return np.stack([phi + alpha, -2.0 * alpha], axis=-1)


#: Lateral offset of the thigh from the abduction axis, in the abducted leg's frame [m] (+ left legs).
HIP_OFFSET = 0.08
#: Abduction (hip) joint range of the Go1 [rad].
ABDUCTION_RANGE = 0.863


def leg_ik3(foot: np.ndarray, side: float) -> np.ndarray:
    """Three-joint IK of one Go1 leg: (abduction, thigh, calf) angles [rad] placing its foot.

    The abduction joint turns the leg's sagittal plane about the hip's x axis;
    in that plane the thigh sits ``side ×`` :data:`HIP_OFFSET` to the side and
    :func:`leg_ik` places the foot. A point out of reach gets the nearest pose
    the joint limits and leg length allow (the abduction clipped to
    ±:data:`ABDUCTION_RANGE`, the leg stretched).

    Args:
        foot: (..., 3) foot centre relative to the abduction joint, trunk frame (x forward, y left, z up) [m].
        side: +1 left leg, −1 right leg.
    Returns:
        (..., 3) joint angles [rad].
    """
    foot = np.asarray(foot, dtype=float)
    fx, fy, fz = np.moveaxis(foot, -1, 0)
    off = side * HIP_OFFSET
    h = np.sqrt(np.maximum(fy ** 2 + fz ** 2 - off ** 2, 1e-6))  # depth below the hip in the leg's plane
    # (fy, fz) is (off, −h) turned by the abduction angle a about x
    a = np.arctan2(fz, fy) - np.arctan2(-h, off)
    a = np.clip(np.angle(np.exp(1j * a)), -ABDUCTION_RANGE, ABDUCTION_RANGE)
    sagittal = leg_ik(-fx, h)
    return np.concatenate([a[..., None], sagittal], axis=-1)


def leg_fk3(joints: np.ndarray, side: float) -> np.ndarray:
    """(..., 3) foot centre relative to the abduction joint [m] of (..., 3) leg joint angles (:func:`leg_ik3`'s
    inverse; ``side`` +1 left, −1 right)."""
    a, t1, t2 = np.moveaxis(np.asarray(joints, dtype=float), -1, 0)
    x = -THIGH * np.sin(t1) - CALF * np.sin(t1 + t2)
    z = -THIGH * np.cos(t1) - CALF * np.cos(t1 + t2)
    y0 = side * HIP_OFFSET
    return np.stack([x, y0 * np.cos(a) - z * np.sin(a), y0 * np.sin(a) + z * np.cos(a)], axis=-1)


def body_shift_targets(dx: np.ndarray | float, height: float = 0.2648) -> np.ndarray:
    """(…, 12) joint targets that shift the trunk forward by ``dx`` [m] over planted feet."""
    leg = leg_ik(dx, height)
    out = np.broadcast_to(STAND_JOINTS, np.shape(dx) + (12,)).copy()
    for i in range(4):
        out[..., 3 * i + 1] = leg[..., 0]
        out[..., 3 * i + 2] = leg[..., 1]
    return out


def lunge_schedule(control_period: float = 0.01, settle: float = 1.0, lunges=(0.06, 0.09, 0.12),
                   strike: float = 0.25, hold: float = 0.3, retreat: float = 0.6, rest: float = 0.8) -> np.ndarray:
    """Joint-target sequence of a lunge probe, one row per control period.

    Args:
        control_period: seconds per row.
        settle: standing time first [s].
        lunges: forward reach of each lunge [m].
        strike, hold, retreat, rest: durations of each lunge's phases [s]
            (fast strike, hold in contact, slow retreat, stand still).
    Returns:
        (N, 12) joint position targets [rad].
    """
    def ramp(a, b, T):
        n = max(1, int(round(T / control_period)))
        s = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, n))
        return a + (b - a) * s

    dx = [np.zeros(int(round(settle / control_period)))]
    for reach in lunges:
        dx += [ramp(0.0, reach, strike), np.full(int(round(hold / control_period)), reach),
               ramp(reach, 0.0, retreat), np.zeros(int(round(rest / control_period)))]
    return body_shift_targets(np.concatenate(dx))
