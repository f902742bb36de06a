"""The time offset between the motion-capture and the joint-state streams, measured from the log.

Motion capture and joint encoders run on different clocks; a log whose pose
stamps are receive times, or a mocap PC whose clock is off, shifts the trunk and
box poses against the joints and the commands. The legs tell the offset: a
foot in stance stands still in the world, and its world position is the trunk
pose (motion capture) composed with the leg's forward kinematics (joint
angles). With the poses shifted by the wrong ``τ``, stance feet appear to slide
by about ``τ`` times the trunk's acceleration. So

    τ̂ = argmin_τ  mean_t  min_feet | d/dt ( x_base(t+τ) + R_base(t+τ) p_foot(q(t)) ) |²

over the samples where the robot walks (trunk speed above 5 cm/s), on the
resampling grid, refined below one grid step by a parabola through the three
best shifts. The same shift applies to every pose stream of the mocap (base and
box share its clock). Forward kinematics: ``mujoco.mj_kinematics`` of the
scene's Go1 with the trunk at the origin.

Measured on the two bundled example logs with their pose streams shifted by a
known lag: +4…+20 ms came back within 1.4 ms; −4…−20 ms (poses stamped early)
came back 0.5–6.5 ms short (−20 ms read −13.5 and −15.3 ms): the correction is
then partial, never of the wrong sign. Unshifted logs read 0.0–0.5 ms.

Not on every log: on ``amhe run``'s recordings of the emulated Go1, whose trunk
orientation is the IMU's and whose poses the run had dated by the lateness it
measured, it read a further +7 to +13 ms (the trunk's position alone +6 to
+10 ms, its orientation alone −8 to −10 ms), and the box mass fitted after that
shift was +9–11 % off against −1.3 % and 0.0 % without it. ``load_problem``
keeps such a recording's dating
(:func:`~amhe_cli.estimation.problem.run_dated_poses`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amhe_cli.io.quat import quat_rotate
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.model.scene import Scene

#: Shifts searched [s] (± this).
MAX_OFFSET = 0.05
#: An offset is applied only when it exceeds this [s] (below it, the grid step and noise dominate).
APPLY_ABOVE = 0.003
#: Trunk speed above which the robot counts as walking [m/s].
WALKING = 0.05


@dataclass
class OffsetFit:
    """Result of :func:`mocap_offset`.

    Attributes:
        offset: τ̂ [s], how late the pose streams are stamped against the
            joint states: the pose stamped ``t + τ̂`` describes the moment
            ``t``, so ``−τ̂`` is the correction to add to their times.
        shifts: (K,) shifts tried [s]; ``cost``: (K,) mean squared stance-foot speed [m²/s²].
        samples: walking samples used.
    """

    offset: float
    shifts: np.ndarray
    cost: np.ndarray
    samples: int

    def to_dict(self) -> dict:
        """Plain summary for the belief's provenance."""
        i = int(np.argmin(self.cost))
        return {"pose_stamp_lag_s": round(self.offset, 5), "samples": self.samples,
                "stance_foot_speed_mps": round(float(np.sqrt(self.cost[i])), 5)}


def foot_positions_in_base(scene: Scene, joint_pos: np.ndarray) -> np.ndarray:
    """(T, 4, 3) foot centres in the trunk frame [m] for (T, 12) joint angles (forward kinematics)."""
    qpos = np.tile(scene.model.qpos0, (len(joint_pos), 1))
    qpos[:, scene.base_qpos] = [0, 0, 0, 1, 0, 0, 0]  # the trunk at the origin, unturned
    qpos[:, scene.joint_qpos] = joint_pos
    return scene.foot_centres(qpos)


def mocap_offset(traj: Trajectory, scene: Scene, max_offset: float = MAX_OFFSET) -> OffsetFit | None:
    """Estimate the pose streams' time offset against the joint states (module docstring).

    Args:
        traj: trajectory on a uniform grid, poses possibly smoothed.
        scene: any scene with the Go1 (only its kinematics are used).
        max_offset: search range ± [s].
    Returns:
        the :class:`OffsetFit`, or None when the robot hardly walks in the log
        (fewer than 100 walking samples) or the best shift lies on the search
        boundary (no minimum inside it).
    """
    dt = traj.dt
    speed = np.linalg.norm(traj.base_linvel[:, :2], axis=1)
    ok = traj.valid() & (speed > WALKING)
    if ok.sum() < 100:
        return None
    feet = foot_positions_in_base(scene, traj.joint_pos)  # (T, 4, 3)
    K = int(round(max_offset / dt))
    shifts = np.arange(-K, K + 1)
    n = len(traj)
    cost = np.full(len(shifts), np.inf)
    used = 0
    for j, k in enumerate(shifts):
        # pose at t + k dt with the joints at t, for t where both exist
        lo, hi = max(0, -k), min(n, n - k)
        pos = traj.base_pos[lo + k:hi + k]
        quat = traj.base_quat[lo + k:hi + k]
        world = pos[:, None, :] + quat_rotate(np.repeat(quat[:, None, :], 4, axis=1), feet[lo:hi])
        vel = np.linalg.norm(np.diff(world, axis=0), axis=2) / dt  # (T'-1, 4)
        stance = vel.min(axis=1)
        mask = ok[lo + 1:hi] & ok[lo:hi - 1]
        if mask.sum() < 100:
            continue
        cost[j] = float(np.mean(stance[mask] ** 2))
        used = max(used, int(mask.sum()))
    i = int(np.argmin(cost))
    if not np.isfinite(cost[i]) or i in (0, len(shifts) - 1):
        return None
    c0, c1, c2 = cost[i - 1:i + 2]
    denom = c0 - 2 * c1 + c2
    frac = 0.5 * (c0 - c2) / denom if denom > 0 else 0.0
    return OffsetFit(offset=float((shifts[i] + np.clip(frac, -0.5, 0.5)) * dt), shifts=shifts * dt,
                     cost=cost, samples=used)
