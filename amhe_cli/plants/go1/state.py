"""State estimation of the real Go1 and the box: the planner's full state from the IMU, joints and motion capture.

The low-level link gives joints and an IMU but no base position or linear
velocity (docs/reference.md#go1-low-level-link); motion capture gives poses at ~120 Hz, late by a few
ms. :class:`StateEstimator` combines them into MuJoCo ``qpos``/``qvel`` of the
scene:

* joints: ``q``, ``dq`` of the newest LowState (the SDK's motor order is
  :data:`~amhe_cli.io.trajectory.GO1_JOINTS`);
* trunk orientation: the IMU quaternion, turned about z by the yaw offset
  between the IMU's frame and the motion-capture world (the IMU's yaw zero is
  where it powered on), low-passed; body rates: the gyroscope;
* trunk position: the newest mocap pose, carried forward over its age by the
  velocity estimate;
* trunk linear velocity: a complementary filter — the IMU's specific force,
  rotated to the world and minus gravity, integrated every state (500 Hz), and
  pulled toward the mocap finite difference with time constant ``tau_base``
  (the accelerometer carries the fast changes, the mocap removes its drift
  and bias; differentiated 1 mm mocap noise at 120 Hz is ≈ 0.17 m/s raw);
* box pose: the newest mocap pose carried forward over its age; its velocities
  by finite differences of consecutive mocap samples, low-passed with
  ``tau_box`` (no IMU on a box).
"""

from __future__ import annotations

import mujoco
import numpy as np

from amhe_cli.io.quat import quat_relative_rotvec, quat_to_yaw
from amhe_cli.model.scene import Scene

GRAVITY = np.array([0.0, 0.0, -9.81])


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


class _Differentiator:
    """Low-passed finite-difference velocity of a pose stream (world linear, body angular)."""

    def __init__(self, tau: float):
        self.tau = tau
        self.last = None  # (stamp, pos, quat)
        self.linvel = np.zeros(3)
        self.angvel = np.zeros(3)

    def add(self, stamp: float, pos: np.ndarray, quat: np.ndarray) -> None:
        """Feed one sample (a sample no later than the last one is ignored by the low-pass)."""
        if self.last is not None:
            dt = stamp - self.last[0]
            if dt > 1e-4:
                raw = (pos - self.last[1]) / dt
                w = quat_relative_rotvec(self.last[2], quat) / dt
                a = dt / (self.tau + dt)
                self.linvel += a * (raw - self.linvel)
                self.angvel += a * (w - self.angvel)
        self.last = (stamp, np.asarray(pos, float), np.asarray(quat, float))


class StateEstimator:
    """Full scene state of the robot and the box from LowState and motion capture (module docstring).

    Args:
        scene: the scene whose ``qpos``/``qvel`` layout to fill.
        tau_base: time constant pulling the IMU-integrated trunk velocity toward the mocap's [s].
        tau_box: time constant of the box's velocity low-pass [s].
        tau_yaw: time constant of the IMU-to-world yaw alignment [s].

    Measured against the emulator's truth (T1 pushing, 1 mm / 0.2° mocap noise,
    3 ms latency): with 0.04 s for both the trunk's velocity erred by 0.03–0.09
    m/s rms; with these the errors were 0.015–0.04 m/s (benchmarks/go1_emulated_runs.py repeats such runs).
    """

    def __init__(self, scene: Scene, tau_base: float = 0.15, tau_box: float = 0.08, tau_yaw: float = 0.5):
        self.scene = scene
        self.tau_yaw = tau_yaw
        self.qpos = scene.model.qpos0.copy()
        self.qvel = np.zeros(scene.model.nv)
        self._imu_quat = np.array([1.0, 0, 0, 0])
        self._gyro = np.zeros(3)
        self._yaw_offset: float | None = None
        self._imu_t: float | None = None
        self._base_v = np.zeros(3)
        self.tau_base = tau_base
        self._box = _Differentiator(tau_box)
        self._base_pose = None  # (received, pos, quat, seq) of the newest trunk sample, and its stamp:
        self._base_stamp = 0.0
        self._box_pose = None

    @property
    def base_quat(self) -> np.ndarray:
        """(4,) trunk orientation (w, x, y, z) in the motion-capture world."""
        off = 0.0 if self._yaw_offset is None else self._yaw_offset
        out = np.empty(4)
        mujoco.mju_mulQuat(out, np.array([np.cos(off / 2), 0.0, 0.0, np.sin(off / 2)]), self._imu_quat)
        return out

    def update_state(self, t: float, low) -> None:
        """Feed a LowState received at ``t`` (``time.monotonic()`` [s]): joints, IMU, velocity prediction.

        Runs every 2 ms in the relay thread, so single-sample rotations use
        MuJoCo's ``mju_*`` functions (≈ 1 µs) rather than the batched
        :mod:`amhe_cli.io.quat` (tens of µs per call on one sample).
        """
        s = self.scene
        self.qpos[s.joint_qpos] = low.q
        self.qvel[s.joint_qvel] = low.dq
        q = np.array(low.quaternion, dtype=float)
        mujoco.mju_normalize4(q)
        self._imu_quat = q
        self._gyro = np.array(low.gyroscope, dtype=float)
        if self._imu_t is not None:
            dt = min(max(t - self._imu_t, 0.0), 0.02)
            acc_world = np.empty(3)
            mujoco.mju_rotVecQuat(acc_world, np.array(low.accelerometer, dtype=float), self.base_quat)
            self._base_v = self._base_v + (acc_world + GRAVITY) * dt
        self._imu_t = t

    def update_poses(self, base, box) -> None:
        """Feed the newest :class:`~amhe_cli.plants.go1.mocap.PoseSample` of the trunk and the box (None: none yet)."""
        if base is not None and (self._base_pose is None or base.seq != self._base_pose[3]):
            if self._base_pose is not None and base.stamp - self._base_stamp > 1e-4:
                dt = base.stamp - self._base_stamp
                raw = (np.asarray(base.pos, float) - self._base_pose[1]) / dt
                self._base_v = self._base_v + dt / (self.tau_base + dt) * (raw - self._base_v)
            yaw_err = _wrap(float(quat_to_yaw(base.quat)) - float(quat_to_yaw(self._imu_quat)))
            if self._yaw_offset is None:
                self._yaw_offset = yaw_err
            else:
                dt = max(base.stamp - self._base_stamp, 0.0)
                gain = dt / (self.tau_yaw + dt)
                self._yaw_offset = _wrap(self._yaw_offset + gain * _wrap(yaw_err - self._yaw_offset))
            self._base_pose = (base.received, np.asarray(base.pos, float), np.asarray(base.quat, float), base.seq)
            self._base_stamp = base.stamp
        if box is not None and (self._box_pose is None or box.seq != self._box_pose[3]):
            self._box.add(box.stamp, box.pos, box.quat)
            self._box_pose = (box.received, np.asarray(box.pos, float), np.asarray(box.quat, float), box.seq)

    def estimate(self, now: float) -> tuple[np.ndarray, np.ndarray]:
        """(nq,), (nv,) of the scene at ``now`` (``time.monotonic()`` [s]); poses carried forward over their age."""
        s = self.scene
        qpos, qvel = self.qpos.copy(), self.qvel.copy()
        qpos[s.base_qpos[3:]] = self.base_quat
        qvel[s.base_qvel[3:]] = self._gyro
        qvel[s.base_qvel[:3]] = self._base_v
        if self._base_pose is not None:
            age = min(max(now - self._base_pose[0], 0.0), 0.1)
            qpos[s.base_qpos[:3]] = self._base_pose[1] + self._base_v * age
        if self._box_pose is not None:
            age = min(max(now - self._box_pose[0], 0.0), 0.1)
            qpos[s.box_qpos[:3]] = self._box_pose[1] + self._box.linvel * age
            qpos[s.box_qpos[3:]] = self._box_pose[2]
            qvel[s.box_qvel[:3]] = self._box.linvel
            qvel[s.box_qvel[3:]] = self._box.angvel
        return qpos, qvel
