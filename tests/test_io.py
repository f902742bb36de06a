"""Tests of amhe_cli.io: quaternion helpers, log reader, MCAP writer.

Synthetic logs are written with rosbags' own writers (rosbag2 sqlite3, ROS 1)
from a synthetic trajectory whose exact values are known, so the reader is
checked against an independent writer; the project writer is checked by round
trips. Tests on the shared recorded log are skipped when it is absent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import (
    body_to_world,
    mj_to_ros,
    quat_from_rotvec,
    quat_from_yaw,
    quat_make_continuous,
    quat_mul,
    quat_normalize,
    quat_relative_rotvec,
    quat_rotate,
    quat_to_rotvec,
    quat_to_yaw,
    ros_to_mj,
    rotation_from_wxyz,
    rotation_to_wxyz,
    world_to_body,
)
from amhe_cli.io.reader import (
    assign_roles,
    canonical_joint_name,
    inspect_log,
    match_joints,
    read_float_arrays,
    read_log,
)
from amhe_cli.io.writer import McapLog, write_mcap
from amhe_cli.io.trajectory import GO1_JOINTS, SIGNALS, Trajectory

# an optional simulated log outside the repository (shared/logs beside the checkout); tests needing it skip without it
CONST_A = Path(__file__).resolve().parents[2] / "shared" / "logs" / "const_a.mcap"
STAND = np.tile([0.0, 0.9, -1.8], 4)
ANYMAL = {"FR": "RF", "FL": "LF", "RR": "RH", "RL": "LH"}
ANYMAL_PART = {"hip": "HAA", "thigh": "HFE", "calf": "KFE"}


# --------------------------------------------------------------------------- #
# Synthetic data
# --------------------------------------------------------------------------- #


def make_traj(n: int = 501, dt: float = 0.002, cmd_every: int = 5) -> Trajectory:
    """A smooth synthetic trajectory whose velocities are consistent with its poses.

    The box moves at constant world velocity and constant yaw rate, so its
    backward-difference velocities are exact; the commands are a staircase
    that changes every ``cmd_every`` samples.
    """
    t = np.arange(n) * dt
    phase = np.arange(12) * 0.3
    joint_pos = STAND + 0.1 * np.sin(2 * np.pi * t[:, None] + phase)
    joint_vel = 0.2 * np.pi * np.cos(2 * np.pi * t[:, None] + phase)
    held = t[(np.arange(n) // cmd_every) * cmd_every]
    ctrl = STAND + 0.05 * np.sin(3.0 * held[:, None] + phase)
    base_yaw = 0.3 * t
    return Trajectory(
        t=t,
        dt=dt,
        base_pos=np.stack([0.1 * t, 0.05 * t, np.full(n, 0.27)], axis=1),
        base_quat=quat_from_yaw(base_yaw),
        base_linvel=np.tile([0.1, 0.05, 0.0], (n, 1)),
        base_angvel=np.tile([0.0, 0.0, 0.3], (n, 1)),
        joint_pos=joint_pos,
        joint_vel=joint_vel,
        box_pos=np.stack([1.0 + 0.2 * t, -0.1 * t, np.full(n, 0.18)], axis=1),
        box_quat=quat_from_yaw(0.5 * t),
        box_linvel=np.tile([0.2, -0.1, 0.0], (n, 1)),
        box_angvel=np.tile([0.0, 0.0, 0.5], (n, 1)),
        ctrl=ctrl,
        kp=np.full(12, 55.0),
        kd=np.full(12, 3.0),
    )


class BagWriter:
    """Writes typed messages to a rosbag2 (sqlite3) folder or a ROS 1 .bag with rosbags."""

    def __init__(self, path: Path, ros1: bool = False, extra_types: dict | None = None, storage: str = "sqlite3",
                 log_delay_ns: int = 0):
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = ros1
        self.ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if extra_types:
            self.ts.register(extra_types)
        if ros1:
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.log_delay_ns = log_delay_ns
        self._rng = np.random.default_rng(7)
        self.conns: dict[str, object] = {}

    def T(self, name: str):
        return self.ts.types[name]

    def header(self, ns: int, frame: str = "world"):
        stamp = self.T("builtin_interfaces/msg/Time")(sec=ns // 10**9, nanosec=ns % 10**9)
        kw = {"seq": 0} if self.ros1 else {}
        return self.T("std_msgs/msg/Header")(stamp=stamp, frame_id=frame, **kw)

    def write(self, topic: str, msgtype: str, ns: int, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        data = self.ts.serialize_ros1(msg, msgtype) if self.ros1 else self.ts.serialize_cdr(msg, msgtype)
        # Log (receive) time lags the header stamp by up to log_delay_ns.
        delay = int(self._rng.integers(0, self.log_delay_ns + 1))
        self.writer.write(self.conns[topic], ns + delay, data)

    def close(self) -> None:
        self.writer.close()

    # Standard messages -------------------------------------------------------
    def joint_state(self, ns, names, pos, vel=()):
        return self.T("sensor_msgs/msg/JointState")(
            header=self.header(ns, "base"), name=list(names), position=np.asarray(pos, float),
            velocity=np.asarray(vel, float), effort=np.zeros(0),
        )

    def pose(self, pos, q_wxyz):
        x, y, z, w = mj_to_ros(q_wxyz)
        return self.T("geometry_msgs/msg/Pose")(
            position=self.T("geometry_msgs/msg/Point")(x=pos[0], y=pos[1], z=pos[2]),
            orientation=self.T("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w),
        )

    def pose_stamped(self, ns, pos, q_wxyz):
        return self.T("geometry_msgs/msg/PoseStamped")(header=self.header(ns), pose=self.pose(pos, q_wxyz))

    def odometry(self, ns, pos, q_wxyz, lin_body, ang_body):
        V = self.T("geometry_msgs/msg/Vector3")
        return self.T("nav_msgs/msg/Odometry")(
            header=self.header(ns),
            child_frame_id="base",
            pose=self.T("geometry_msgs/msg/PoseWithCovariance")(pose=self.pose(pos, q_wxyz), covariance=np.zeros(36)),
            twist=self.T("geometry_msgs/msg/TwistWithCovariance")(
                twist=self.T("geometry_msgs/msg/Twist")(linear=V(*lin_body), angular=V(*ang_body)),
                covariance=np.zeros(36),
            ),
        )


def write_bag(
    path: Path,
    traj: Trajectory,
    *,
    names=GO1_JOINTS,
    order=None,
    topics=None,
    skip=(),
    box_drop=(),
    box_nan=(),
    cmd_every: int = 5,
    offset_ns: int = 0,
    dup_box: str | None = None,
    stamp_shift: dict | None = None,
    each=None,
    **bag_kw,
) -> Path:
    """Write ``traj`` as a rosbag2 sqlite3 folder with rosbags' writer.

    Args:
        names: joint names in canonical order (e.g. ANYmal-style aliases).
        order: permutation of the 12 joints in the messages (default identity).
        topics: role -> topic name overrides.
        skip: roles not to write at all.
        box_drop: sample indices whose box message is dropped.
        box_nan: sample indices whose box position is NaN.
        cmd_every: commands written every ``cmd_every`` samples (their change points).
        offset_ns: added to every time stamp.
        dup_box: name of a second topic carrying the box pose shifted by 1 m in x.
        stamp_shift: role -> ns added to its header stamps only (a stream stamped on another clock).
        each: called as ``each(bag, i, ns)`` after sample ``i``'s messages, to write more.
        bag_kw: passed to :class:`BagWriter` (``storage``, ``log_delay_ns``).
    """
    topics = {"joint_states": "/joint_states", "base": "/odom", "box": "/mocap/box/pose",
              "joint_commands": "/joint_commands", **(topics or {})}
    order = np.arange(12) if order is None else np.asarray(order)
    bag = BagWriter(path, **bag_kw)
    lin_body = world_to_body(traj.base_quat, traj.base_linvel)
    msg_names = [names[k] for k in order]
    shift = stamp_shift or {}
    for i in range(len(traj)):
        ns = int(round(traj.t[i] * 1e9)) + offset_ns
        if "joint_states" not in skip:
            bag.write(topics["joint_states"], "sensor_msgs/msg/JointState", ns,
                      bag.joint_state(ns, msg_names, traj.joint_pos[i, order], traj.joint_vel[i, order]))
        if "base" not in skip:
            bag.write(topics["base"], "nav_msgs/msg/Odometry", ns,
                      bag.odometry(ns + shift.get("base", 0), traj.base_pos[i], traj.base_quat[i], lin_body[i],
                                   traj.base_angvel[i]))
        if "box" not in skip and i not in box_drop:
            pos = np.full(3, np.nan) if i in box_nan else traj.box_pos[i]
            bag.write(topics["box"], "geometry_msgs/msg/PoseStamped", ns, bag.pose_stamped(ns, pos, traj.box_quat[i]))
        if dup_box:
            bag.write(dup_box, "geometry_msgs/msg/PoseStamped", ns,
                      bag.pose_stamped(ns, traj.box_pos[i] + [1.0, 0, 0], traj.box_quat[i]))
        if "joint_commands" not in skip and i % cmd_every == 0:
            bag.write(topics["joint_commands"], "sensor_msgs/msg/JointState", ns,
                      bag.joint_state(ns, msg_names, traj.ctrl[i, order]))
        if each is not None:
            each(bag, i, ns)
    bag.close()
    return path


def assert_close(a: Trajectory, b: Trajectory, pos_tol=1e-9, vel_tol=1e-6, signals=SIGNALS) -> None:
    assert len(a) == len(b)
    for name in signals:
        tol = vel_tol if ("vel" in name) else pos_tol
        if name == "ctrl":
            np.testing.assert_array_equal(a.ctrl, b.ctrl)
        else:
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=tol, rtol=0, err_msg=name)


# --------------------------------------------------------------------------- #
# Quaternions and frames
# --------------------------------------------------------------------------- #


def test_quat_order_conversion_is_a_reordering():
    q_ros = np.array([0.1, 0.2, 0.3, 0.9])  # x, y, z, w
    np.testing.assert_array_equal(ros_to_mj(q_ros), [0.9, 0.1, 0.2, 0.3])
    batch = np.random.default_rng(0).normal(size=(5, 7, 4))
    np.testing.assert_array_equal(mj_to_ros(ros_to_mj(batch)), batch)
    assert ros_to_mj(batch).shape == (5, 7, 4)


def test_quat_rotate_matches_mujoco_and_hand_case():
    import mujoco

    rng = np.random.default_rng(1)
    q = quat_normalize(rng.normal(size=(20, 4)))
    v = rng.normal(size=(20, 3))
    ref = np.empty_like(v)
    for k in range(20):
        mujoco.mju_rotVecQuat(ref[k], v[k], q[k])
    np.testing.assert_allclose(quat_rotate(q, v), ref, atol=1e-12)
    # 90 deg about z maps x to y.
    np.testing.assert_allclose(quat_rotate(quat_from_yaw(np.pi / 2), [1.0, 0.0, 0.0]), [0, 1, 0], atol=1e-15)


def test_body_to_world_velocity_yaw_90():
    q = quat_from_yaw(np.pi / 2)
    np.testing.assert_allclose(body_to_world(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(world_to_body(q, [0.0, 1.0, 0.0]), [1.0, 0.0, 0.0], atol=1e-15)
    # Batched: leading axes broadcast.
    qs = quat_from_yaw(np.array([0.0, np.pi / 2, np.pi]))
    np.testing.assert_allclose(body_to_world(qs, [1.0, 0.0, 0.0]), [[1, 0, 0], [0, 1, 0], [-1, 0, 0]], atol=1e-15)


def test_scipy_boundary_round_trips_exactly():
    """wxyz -> xyzw -> wxyz is a reordering, bit for bit; wxyz -> Rotation -> wxyz up to SciPy's renormalisation."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    q = quat_normalize(rng.normal(size=(3, 5, 4)))
    np.testing.assert_array_equal(ros_to_mj(mj_to_ros(q)), q)
    rot = rotation_from_wxyz(q)
    assert len(rot) == 15
    np.testing.assert_allclose(rot.as_quat(), mj_to_ros(q).reshape(-1, 4), rtol=0, atol=1e-15)  # SciPy: (x, y, z, w)
    back = rotation_to_wxyz(rot, q.shape[:-1])
    assert back.shape == q.shape
    np.testing.assert_allclose(back, q, rtol=0, atol=1e-15)  # SciPy renormalises: last-bit rounding only
    np.testing.assert_array_equal(back[..., 0] > 0, q[..., 0] > 0)  # signs are not canonicalised
    # a single quaternion is a stack of one; the identity is (1, 0, 0, 0) here and (0, 0, 0, 1) in SciPy
    np.testing.assert_array_equal(rotation_from_wxyz([1.0, 0, 0, 0]).as_quat(), [[0, 0, 0, 1.0]])
    np.testing.assert_array_equal(rotation_to_wxyz(Rotation.identity(), ()), [1.0, 0, 0, 0])


def test_scipy_based_helpers_known_values():
    """A 90° yaw through every SciPy-backed helper, and the numpy fast paths against SciPy."""
    h = np.sqrt(0.5)
    q = quat_from_yaw(np.pi / 2)
    np.testing.assert_allclose(q, [h, 0.0, 0.0, h], atol=1e-16)
    assert quat_to_yaw(q) == pytest.approx(np.pi / 2, abs=1e-15)
    np.testing.assert_allclose(quat_to_rotvec(q), [0.0, 0.0, np.pi / 2], atol=1e-15)
    np.testing.assert_allclose(quat_from_rotvec([0.0, 0.0, np.pi / 2]), q, atol=1e-16)
    np.testing.assert_allclose(quat_mul(q, q), [0.0, 0.0, 0.0, 1.0], atol=1e-15)  # 180° about z
    np.testing.assert_allclose(quat_relative_rotvec(quat_from_yaw(0.3), quat_from_yaw(0.3 + np.pi / 2)),
                               [0.0, 0.0, np.pi / 2], atol=1e-15)
    # fast paths agree with SciPy on random rotations of any leading shape
    rng = np.random.default_rng(5)
    a = quat_normalize(rng.normal(size=(4, 6, 4)))
    b = quat_normalize(rng.normal(size=(4, 6, 4)))
    ref = (rotation_from_wxyz(a).inv() * rotation_from_wxyz(b)).as_rotvec().reshape(4, 6, 3)
    np.testing.assert_allclose(quat_relative_rotvec(a, b), ref, atol=1e-12)
    np.testing.assert_allclose(quat_relative_rotvec(a, -b), ref, atol=1e-12)  # either sign, shorter rotation
    np.testing.assert_allclose(quat_relative_rotvec(a, a), 0.0, atol=1e-15)
    np.testing.assert_allclose(quat_to_yaw(a), rotation_from_wxyz(a).as_euler("ZYX")[:, 0].reshape(4, 6), atol=1e-12)


def test_slerp_midpoint_and_hemisphere():
    from amhe_cli.io.resample import _slerp

    q0 = quat_from_yaw(0.0)
    q1 = quat_from_yaw(np.pi / 2)
    t_msg = np.array([0, 10_000_000], dtype=np.int64)  # ns
    mid = _slerp(t_msg, np.stack([q0, q1]), np.array([5_000_000]))[0]
    np.testing.assert_allclose(mid, quat_from_yaw(np.pi / 4), atol=1e-15)
    # -q1 is the same rotation: slerp still takes the short way, keeping q0's sign.
    np.testing.assert_allclose(_slerp(t_msg, np.stack([q0, -q1]), np.array([5_000_000]))[0], mid, atol=1e-15)
    # Many grid times over a sequence of messages, at epoch-sized stamps.
    t0 = 1_700_000_000_000_000_000
    yaw_msg = np.array([0.0, 0.4, 1.0, 1.2])
    t_msg = t0 + np.array([0, 10, 20, 40], dtype=np.int64) * 1_000_000
    grid = t0 + np.arange(0, 41, 5, dtype=np.int64) * 1_000_000
    yaws = quat_to_yaw(_slerp(t_msg, quat_from_yaw(yaw_msg), grid))
    np.testing.assert_allclose(yaws, np.interp(grid - t0, t_msg - t0, yaw_msg), atol=1e-14)


def test_rotvec_roundtrip_and_continuity():
    rng = np.random.default_rng(2)
    r = rng.normal(size=(50, 3))
    r *= (np.pi * 0.99 / np.linalg.norm(r, axis=1).max())
    np.testing.assert_allclose(quat_to_rotvec(quat_from_rotvec(r)), r, atol=1e-12)
    tiny = np.array([1e-12, -2e-12, 3e-12])
    np.testing.assert_allclose(quat_to_rotvec(quat_from_rotvec(tiny)), tiny, rtol=1e-9)
    seq = quat_from_yaw(np.linspace(0, 1, 6))
    seq[[1, 3, 4]] *= -1
    cont = quat_make_continuous(seq)
    assert np.all(np.einsum("ij,ij->i", cont[1:], cont[:-1]) > 0)
    np.testing.assert_allclose(np.abs(cont), np.abs(seq))
    assert quat_mul(quat_from_yaw(0.2), quat_from_yaw(0.3)) == pytest.approx(quat_from_yaw(0.5))


# --------------------------------------------------------------------------- #
# Joint names and roles
# --------------------------------------------------------------------------- #


def test_canonical_joint_names_and_aliases():
    assert canonical_joint_name("FR_hip_joint") == "FR_hip_joint"
    assert canonical_joint_name("FL_hip") == "FL_hip_joint"
    assert canonical_joint_name("fl_hip_joint") == "FL_hip_joint"
    assert canonical_joint_name("LF_HAA") == "FL_hip_joint"
    assert canonical_joint_name("RF_HFE") == "FR_thigh_joint"
    assert canonical_joint_name("LH_KFE") == "RL_calf_joint"
    assert canonical_joint_name("RH_KFE") == "RR_calf_joint"
    assert canonical_joint_name("go1/RL_thigh_joint") == "RL_thigh_joint"
    assert canonical_joint_name("arm_joint_1") is None
    # legs spelled out, and unitree_legged_sdk's motor names FR_0/1/2 (hip, thigh, calf)
    assert canonical_joint_name("front_right_hip_joint") == "FR_hip_joint"
    assert canonical_joint_name("hind_left_knee") == "RL_calf_joint"
    assert [canonical_joint_name(f"RR_{k}") for k in range(3)] == ["RR_hip_joint", "RR_thigh_joint", "RR_calf_joint"]
    assert canonical_joint_name("go1/FL_1") == "FL_thigh_joint"
    assert canonical_joint_name("front_hip") is None and canonical_joint_name("imu_0") is None


def test_match_joints_errors_and_explicit_map():
    names = list(GO1_JOINTS[::-1])
    idx = match_joints(names)
    assert [names[k] for k in idx] == list(GO1_JOINTS)
    with pytest.raises(AmheError, match="RL_calf_joint"):
        match_joints(list(GO1_JOINTS[:11]), topic="/joint_states")
    odd = [f"j{k}" for k in range(12)]
    idx = match_joints(odd, dict(zip(odd, GO1_JOINTS)))
    np.testing.assert_array_equal(idx, np.arange(12))
    with pytest.raises(AmheError, match="names no Go1 joint"):
        match_joints(odd, {"j0": "elbow"})


def test_assign_roles_uses_types_and_name_hints():
    topics = {
        "/robot/pose": "geometry_msgs/msg/PoseStamped",
        "/vicon/box": "geometry_msgs/msg/PoseStamped",
        "/low_cmd": "sensor_msgs/msg/JointState",
        "/joint_states": "sensor_msgs/msg/JointState",
        "/gains": "std_msgs/msg/Float64MultiArray",
    }
    roles, problems = assign_roles(topics)
    assert problems == {}
    assert roles == {"base": "/robot/pose", "box": "/vicon/box", "joint_commands": "/low_cmd",
                     "joint_states": "/joint_states", "gains": "/gains"}
    # Two anonymous pose topics: ambiguous, until the user chooses.
    topics2 = {"/a": "geometry_msgs/msg/PoseStamped", "/b": "geometry_msgs/msg/PoseStamped",
               "/odom": "nav_msgs/msg/Odometry"}
    roles, problems = assign_roles(topics2)
    assert roles["base"] == "/odom" and "box" in problems and "/a" in problems["box"] and "/b" in problems["box"]
    roles, problems = assign_roles(topics2, {"box": "/b"})
    assert roles["box"] == "/b" and "box" not in problems
    with pytest.raises(AmheError, match="not in the log"):
        assign_roles(topics2, {"box": "/nope"})
    with pytest.raises(AmheError, match="expected"):
        assign_roles(topics, {"box": "/joint_states"})


# --------------------------------------------------------------------------- #
# Reading synthetic logs
# --------------------------------------------------------------------------- #


def test_rosbag2_reads_back_the_trajectory(tmp_path):
    traj = make_traj()
    bag = write_bag(tmp_path / "bag", traj, offset_ns=1_700_000_000 * 10**9)
    got = read_log(bag)
    assert got.meta["format"] == "rosbag2/sqlite3"
    assert got.meta["t0_ns"] == 1_700_000_000 * 10**9
    np.testing.assert_allclose(got.t, traj.t, atol=1e-12)
    assert_close(traj, got)
    assert got.measured_velocity == {"joint_states": True, "base": True, "box": False, "joint_commands": True}
    assert all(m.all() for m in got.observed.values())
    assert got.meta["topics"]["box"] == "/mocap/box/pose"
    assert len(got.meta["sha256"]) == 64


def test_reading_a_log_leaves_the_garbage_collector_as_it_found_it(tmp_path):
    """read_log pauses the cyclic collector while it decodes (40 % of its time on a 20 s log) and
    restores it: on again if it was on, still off if the caller had turned it off — also when the
    read fails."""
    import gc

    bag = write_bag(tmp_path / "bag", make_traj())
    assert gc.isenabled()
    read_log(bag)
    assert gc.isenabled()
    with pytest.raises(AmheError):
        read_log(bag, topics={"box": "/nope"})
    assert gc.isenabled()
    gc.disable()
    try:
        read_log(bag)
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_robust_sigma_is_scipys_normal_scaled_mad():
    """smoothing.robust_sigma (numpy, no scipy.stats import) returns what scipy.stats returns, to the bit."""
    from scipy.stats import median_abs_deviation

    from amhe_cli.io.smoothing import robust_sigma

    x = np.random.default_rng(3).standard_t(3, size=(501, 4))
    np.testing.assert_array_equal(robust_sigma(x, axis=0), median_abs_deviation(x, axis=0, scale="normal"))
    assert robust_sigma(x[:, 1]) == median_abs_deviation(x[:, 1], scale="normal")
    np.testing.assert_allclose(robust_sigma(np.random.default_rng(4).normal(0, 2.0, 20000)), 2.0, rtol=0.03)


def test_header_stamps_win_over_log_times(tmp_path):
    # Messages reach the recorder up to 3 ms late; the header stamps are exact.
    traj = make_traj(n=101)
    got = read_log(write_bag(tmp_path / "bag", traj, log_delay_ns=3_000_000))
    assert_close(traj, got)


def test_rosbag2_mcap_storage(tmp_path):
    traj = make_traj(n=101)
    got = read_log(write_bag(tmp_path / "bag", traj, storage="mcap"))
    assert got.meta["format"] == "rosbag2/mcap"
    assert_close(traj, got)
    assert got.kp is None and got.kd is None and got.meta["gains_source"] is None


def test_joint_matching_by_name_shuffled_anymal(tmp_path):
    traj = make_traj(n=101)
    canonical = read_log(write_bag(tmp_path / "canon", traj))
    anymal = [f"{ANYMAL[j[:2]]}_{ANYMAL_PART[j.split('_')[1]]}" for j in GO1_JOINTS]
    order = np.random.default_rng(3).permutation(12)
    shuffled = read_log(write_bag(tmp_path / "anymal", traj, names=anymal, order=order))
    np.testing.assert_array_equal(shuffled.joint_pos, canonical.joint_pos)
    np.testing.assert_array_equal(shuffled.joint_vel, canonical.joint_vel)
    np.testing.assert_array_equal(shuffled.ctrl, canonical.ctrl)
    np.testing.assert_allclose(shuffled.joint_pos, traj.joint_pos, atol=1e-12)


def test_missing_joint_names_error(tmp_path):
    traj = make_traj(n=21)
    names = list(GO1_JOINTS)
    names[4] = "FL_elbow_joint"
    with pytest.raises(AmheError, match="FL_thigh_joint"):
        read_log(write_bag(tmp_path / "bag", traj, names=names))


def test_resampling_interpolates_positions_and_slerps(tmp_path):
    # Box messages every 10 ms (cmd-like rate) read on a 5 ms grid: odd samples are midpoints.
    traj = make_traj(n=41, dt=0.005)
    traj.box_quat = quat_from_yaw(4.0 * traj.t)
    bag = write_bag(tmp_path / "bag", traj, box_drop=set(range(1, 41, 2)), cmd_every=2)
    got = read_log(bag, dt=0.005)
    np.testing.assert_allclose(got.box_pos, traj.box_pos, atol=1e-12)
    np.testing.assert_allclose(quat_to_yaw(got.box_quat), 4.0 * traj.t, atol=1e-12)
    # Box period is 10 ms: a 10 ms bracket is within 1.5 periods, so all observed.
    assert got.observed["box"].all()


def test_zoh_ctrl_timing(tmp_path):
    # Commands at 0, 0.01, 0.02, ... (every 5 grid steps of 2 ms).
    traj = make_traj(n=31)
    got = read_log(write_bag(tmp_path / "bag", traj))
    c0, c1 = traj.ctrl[0], traj.ctrl[5]
    assert not np.array_equal(c0, c1)
    np.testing.assert_array_equal(got.ctrl[:5], np.tile(c0, (5, 1)))  # before t = 0.01: old target
    np.testing.assert_array_equal(got.ctrl[5], c1)  # from grid index 5 (t = 0.01) on: new target
    assert got.t[5] == pytest.approx(0.01)


def test_backward_difference_of_constant_velocity_box_is_exact(tmp_path):
    traj = make_traj(n=101)
    bag = write_bag(tmp_path / "bag", traj)
    for smooth in (0, "auto", 5):
        got = read_log(bag, smooth=smooth)
        assert got.measured_velocity["box"] is False
        np.testing.assert_allclose(got.box_linvel, traj.box_linvel, atol=1e-9)  # a quadratic fit keeps a line exact
        # quaternion components are not polynomials in time: a forced window is near, not exact
        np.testing.assert_allclose(got.box_angvel, traj.box_angvel, atol=1e-9 if smooth != 5 else 1e-6)
    assert "smoothing" not in read_log(bag).meta  # clean poses are left alone by default


def test_savgol_returns_a_noisy_polynomials_derivative():
    """SciPy Savitzky–Golay via smoothing.savgol: exact on polynomials of its order, ends included; the
    project's window choice brings a noisy cubic's derivative noise near its 0.02/s target."""
    from amhe_cli.io.smoothing import TARGET_VEL_SIGMA, noise_sigma, savgol, window_for

    P = np.polynomial.polynomial
    dt = 0.002
    t = np.arange(501) * dt
    c = [1.0, 2.0, -3.0, 0.5]  # cubic: not exact for a quadratic fit
    x = np.stack([P.polyval(t, c), -2.0 * P.polyval(t, c)], axis=1)
    dx = np.stack([P.polyval(t, P.polyder(c)), -2.0 * P.polyval(t, P.polyder(c))], axis=1)
    # clean: an order-3 fit is exact everywhere (one-sided fits at the ends); order 2 is exact on a quadratic
    val, der = savgol(x, 21, dt, order=3)
    np.testing.assert_allclose(val, x, atol=1e-9)
    np.testing.assert_allclose(der, dx, atol=1e-7)
    quad = P.polyval(t, c[:3])[:, None]
    val, der = savgol(quad, 20, dt)  # an even window is raised to 21
    np.testing.assert_allclose(val, quad, atol=1e-9)
    np.testing.assert_allclose(der[:, 0], P.polyval(t, P.polyder(c[:3])), atol=1e-7)
    # noisy: 0.2 mm white noise
    y = x + np.random.default_rng(0).normal(0.0, 2e-4, x.shape)
    sigma = noise_sigma(y)
    np.testing.assert_allclose(sigma, 2e-4, rtol=0.2)
    w = window_for(float(sigma.max()), dt)
    assert 5 <= w <= 11
    val, der = savgol(y, w, dt)
    inner = slice(w, -w)
    raw = np.diff(y, axis=0) / dt - dx[1:]
    assert np.sqrt((raw ** 2).mean()) > 0.08  # what a backward difference gives
    rms = np.sqrt(((der - dx)[inner] ** 2).mean(axis=0))
    assert np.all(rms < 1.5 * TARGET_VEL_SIGMA), rms
    assert np.abs(der - dx).max() < 0.2  # ends included
    assert np.sqrt(((val - x) ** 2).mean()) < 2e-4  # smoothing reduces the noise
    # no smoothing: a window of 1 returns the samples and their np.gradient
    val, der = savgol(y, 1, dt)
    np.testing.assert_array_equal(val, y)
    np.testing.assert_array_equal(der, np.gradient(y, dt, axis=0))


def test_noisy_mocap_is_smoothed(tmp_path):
    """1 mm box noise at 500 Hz: raw backward differences are ~0.7 m/s off; auto smoothing fixes that."""
    traj = make_traj(n=400)
    clean = read_log(write_bag(tmp_path / "clean", traj))
    rng = np.random.default_rng(0)
    traj.box_pos = traj.box_pos + rng.normal(0, 1e-3, traj.box_pos.shape)
    bag = write_bag(tmp_path / "noisy", traj)
    with pytest.warns(UserWarning, match="box pose noise"):
        got = read_log(bag)
    raw = read_log(bag, smooth=0)
    err = lambda t: np.sqrt(((t.box_linvel - clean.box_linvel)[20:-20] ** 2).mean())  # noqa: E731
    assert err(raw) > 0.3
    assert err(got) < 0.05
    assert got.meta["smoothing"]["box"]["position_noise_m"] == pytest.approx(1e-3, rel=0.2)


def test_odometry_twist_is_body_frame(tmp_path):
    # Base yawed 90 deg moving along world +y: the logged body twist is +x.
    traj = make_traj(n=21)
    traj.base_quat = np.tile(quat_from_yaw(np.pi / 2), (len(traj), 1))
    traj.base_linvel = np.tile([0.0, 1.0, 0.0], (len(traj), 1))
    lin_body = world_to_body(traj.base_quat[0], traj.base_linvel[0])
    np.testing.assert_allclose(lin_body, [1.0, 0.0, 0.0], atol=1e-15)  # what write_bag logs
    got = read_log(write_bag(tmp_path / "bag", traj))
    np.testing.assert_allclose(got.base_linvel, np.tile([0.0, 1.0, 0.0], (len(traj), 1)), atol=1e-14)


def test_gap_in_box_messages_is_not_observed(tmp_path):
    traj = make_traj(n=201)
    drop = set(range(50, 60)) | {100, 101, 102}  # 22 ms without box pose; 3 frames (8 ms) dropped
    got = read_log(write_bag(tmp_path / "bag", traj, box_drop=drop))
    obs = got.observed["box"]
    assert not obs[50:60].any()
    assert obs[:50].all() and obs[60:].all()  # a few dropped frames of a fast stream are filled (FILL_GAP_S)
    assert got.observed["joint_states"].all()
    assert not got.valid()[55] and got.valid()[10]
    # Positions across the gap are interpolated (the box moves linearly).
    np.testing.assert_allclose(got.box_pos, traj.box_pos, atol=1e-12)


def test_few_nan_messages_are_dropped_with_warning(tmp_path):
    traj = make_traj(n=201)
    bag = write_bag(tmp_path / "bag", traj, box_nan={30, 31, 120})
    with pytest.warns(UserWarning, match="dropped 3 of 201 messages on '/mocap/box/pose'"):
        got = read_log(bag)
    assert any("dropped 3" in w for w in got.meta["warnings"])
    assert np.all(np.isfinite(got.box_pos))
    # two frames (6 ms at 500 Hz) are filled by interpolation, as dropped frames are (FILL_GAP_S)
    assert got.observed["box"][30] and got.observed["box"][29]
    np.testing.assert_allclose(got.box_pos, traj.box_pos, atol=1e-12)


def test_many_nan_messages_raise(tmp_path):
    traj = make_traj(n=101)
    bag = write_bag(tmp_path / "bag", traj, box_nan=set(range(0, 100, 3)))
    with pytest.raises(AmheError, match=r"'/mocap/box/pose'.*'pose.position'"):
        read_log(bag)


def test_missing_role_error_names_role_and_topics(tmp_path):
    bag = write_bag(tmp_path / "bag", make_traj(n=11), skip=("box",))
    with pytest.raises(AmheError) as err:
        read_log(bag)
    text = str(err.value)
    assert "'box'" in text and "--topic box=NAME" in text
    assert "/joint_states [sensor_msgs/msg/JointState]" in text and "/odom [nav_msgs/msg/Odometry]" in text
    assert "\n" not in text


def test_missing_commands_raise(tmp_path):
    bag = write_bag(tmp_path / "bag", make_traj(n=11), skip=("joint_commands",))
    with pytest.raises(AmheError, match="role 'joint_commands'"):
        read_log(bag)


def test_explicit_topics_override_detection(tmp_path):
    traj = make_traj(n=51)
    topics = {"box": "/tracker/rigid_body_7", "base": "/tracker/rigid_body_3"}
    bag = write_bag(tmp_path / "bag", traj, topics=topics, dup_box="/tracker/rigid_body_9")
    # Base is the only Odometry; two PoseStamped with uninformative names: box is ambiguous...
    with pytest.raises(AmheError, match=r"several candidates for role 'box'.*rigid_body_7.*rigid_body_9"):
        read_log(bag)
    info = inspect_log(bag)
    assert info.roles["base"] == "/tracker/rigid_body_3" and "box" in info.problems
    # ...until the user says which one it is.
    got = read_log(bag, topics={"box": "/tracker/rigid_body_9"})
    np.testing.assert_allclose(got.box_pos, traj.box_pos + [1.0, 0, 0], atol=1e-12)
    assert got.meta["topics"] == {**topics, "box": "/tracker/rigid_body_9", "joint_states": "/joint_states",
                                  "joint_commands": "/joint_commands"}


def test_not_a_log_missing_file_and_plain_folder(tmp_path):
    text = tmp_path / "x.txt"
    text.write_text("hello\n")
    with pytest.raises(AmheError, match=r"cannot read .*x.txt.* as a log: expected an MCAP file"):
        read_log(text)
    with pytest.raises(AmheError, match="does not exist"):
        read_log(tmp_path / "missing.mcap")
    (tmp_path / "folder").mkdir()
    with pytest.raises(AmheError, match="not a rosbag2 folder"):
        read_log(tmp_path / "folder")
    with pytest.raises(AmheError, match="dt must be"):
        read_log(text, dt=0.0)


def test_inspect_log_reports_topics_rates_gaps(tmp_path):
    traj = make_traj(n=201)
    bag = write_bag(tmp_path / "bag", traj, box_drop=set(range(50, 60)))
    info = inspect_log(bag)
    by = {t.topic: t for t in info.topics}
    assert by["/joint_states"].count == 201 and by["/joint_states"].rate_hz == pytest.approx(500.0)
    assert by["/joint_commands"].rate_hz == pytest.approx(100.0)
    assert by["/mocap/box/pose"].count == 191
    assert by["/mocap/box/pose"].max_gap_s == pytest.approx(0.022)
    assert info.duration_s == pytest.approx(0.4)
    assert info.roles["box"] == "/mocap/box/pose" and info.problems == {}
    assert "/mocap/box/pose" in str(info)


# Minimal Unitree message definitions (only the fields the reader uses, plus a few).
_UNITREE_MSGS = {
    "unitree_legged_msgs/msg/MotorState": "float32 q\nfloat32 dq\nfloat32 tauEst\n",
    "unitree_legged_msgs/msg/MotorCmd": "uint8 mode\nfloat32 q\nfloat32 dq\nfloat32 tau\nfloat32 Kp\nfloat32 Kd\n",
    "unitree_legged_msgs/msg/LowState": "uint8 levelFlag\nMotorState[20] motorState\n",
    "unitree_legged_msgs/msg/LowCmd": "uint8 levelFlag\nMotorCmd[20] motorCmd\n",
}


def _write_tf_bag(path: Path, traj: Trajectory, ros1: bool, base_parent: str = "world") -> Path:
    """``traj`` with its base and box poses only on ``/tf`` (with a leg frame beside them, as a
    robot_state_publisher records) and a sensor frame on ``/tf_static``; joints as usual."""
    from rosbags.typesys import get_types_from_msg
    TF = "tf2_msgs/msg/TFMessage"
    extra = get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF) if ros1 else None

    def transforms(bag, i, ns):
        T = bag.T

        def transform(parent, child, pos, q_wxyz):
            x, y, z, w = mj_to_ros(q_wxyz)
            pose = T("geometry_msgs/msg/Transform")(translation=T("geometry_msgs/msg/Vector3")(*pos),
                                                    rotation=T("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w))
            return T("geometry_msgs/msg/TransformStamped")(header=bag.header(ns, parent), child_frame_id=child,
                                                           transform=pose)
        if i == 0:
            imu = transform("base_link", "imu", [0, 0, 0.05], [1, 0, 0, 0])
            bag.write("/tf_static", TF, ns, T(TF)(transforms=[imu]))
        bag.write("/tf", TF, ns, T(TF)(transforms=[
            transform(base_parent, "base_link", traj.base_pos[i], traj.base_quat[i]),
            transform("base_link", "FR_thigh", [0.19, -0.13, 0.0], [1, 0, 0, 0]),
            transform("world", "/box", traj.box_pos[i], traj.box_quat[i]),
        ]))
    # ROS 1's type store here has no tf2_msgs
    return write_bag(path, traj, skip=("base", "box"), each=transforms, ros1=ros1, extra_types=extra)


@pytest.mark.parametrize("ros1", [False, True])
def test_poses_on_tf_are_read_per_frame(tmp_path, ros1):
    """Base and box recorded only as transforms on /tf: each child frame reads as a pose topic of its
    own (``/tf#base_link``, ``/tf#box``), assigned by its name, with the poses as written; the
    static frame and the leg frame play no role."""
    traj = make_traj()
    path = _write_tf_bag(tmp_path / ("tf.bag" if ros1 else "tf"), traj, ros1)
    got = read_log(path)
    assert got.meta["topics"]["base"] == "/tf#base_link" and got.meta["topics"]["box"] == "/tf#box"
    assert_close(traj, got, signals=("joint_pos", "base_pos", "base_quat", "box_pos", "box_quat", "ctrl"))
    info = inspect_log(path)
    assert {t.topic for t in info.topics} >= {"/tf#base_link", "/tf#box", "/tf#FR_thigh", "/tf_static"}
    assert "/tf" not in {t.topic for t in info.topics}
    assert not [w for w in got.meta["warnings"] if "frame" in w]
    with pytest.warns(UserWarning, match="frame base_link"):  # its parent is base_link, the box's is world
        explicit = read_log(path, topics={"base": "/tf#FR_thigh"})  # a frame named by hand wins
    np.testing.assert_allclose(explicit.base_pos[:, 0], 0.19)


def test_a_stream_stamped_on_another_clock_is_moved_onto_the_logs(tmp_path):
    """Odometry stamped with the robot's time since boot (here 1000 s behind the recorder's clock) beside
    motion capture and joints stamped on the recorder's: read on one clock, as if stamped there."""
    traj = make_traj()
    path = write_bag(tmp_path / "clocks", traj, offset_ns=2 * 10**12, stamp_shift={"base": -10**12})
    with pytest.warns(UserWarning, match=r"stamps on '/odom' are \+1000 s off"):
        got = read_log(path)
    assert_close(traj, got)


def test_base_and_box_in_different_frames_warn(tmp_path):
    """A base pose from the robot's odometry frame beside a box pose from the motion capture's world:
    amhe takes both in one frame, and says so."""
    path = _write_tf_bag(tmp_path / "odom", make_traj(), False, base_parent="/odom")
    with pytest.warns(UserWarning, match=r"base pose is given in frame odom and the box pose in world"):
        read_log(path)


def test_ros1_bag_with_unitree_lowstate_lowcmd(tmp_path):
    from rosbags.typesys import get_types_from_msg

    types = {}
    for name, text in _UNITREE_MSGS.items():
        types.update(get_types_from_msg(text, name))
    traj = make_traj(n=51)
    path = tmp_path / "go1.bag"
    bag = BagWriter(path, ros1=True, extra_types=types)
    MS, MC = bag.T("unitree_legged_msgs/msg/MotorState"), bag.T("unitree_legged_msgs/msg/MotorCmd")
    lin_body = world_to_body(traj.base_quat, traj.base_linvel)
    for i in range(len(traj)):
        ns = int(round(traj.t[i] * 1e9)) + 10**18
        state = [MS(q=traj.joint_pos[i, k], dq=traj.joint_vel[i, k], tauEst=0.0) for k in range(12)]
        state += [MS(q=0.0, dq=0.0, tauEst=0.0)] * 8
        bag.write("/low_state", "unitree_legged_msgs/msg/LowState", ns,
                  bag.T("unitree_legged_msgs/msg/LowState")(levelFlag=255, motorState=state))
        bag.write("/odom", "nav_msgs/msg/Odometry", ns,
                  bag.odometry(ns, traj.base_pos[i], traj.base_quat[i], lin_body[i], traj.base_angvel[i]))
        bag.write("/box_pose", "geometry_msgs/msg/PoseStamped", ns,
                  bag.pose_stamped(ns, traj.box_pos[i], traj.box_quat[i]))
        if i % 5 == 0:
            cmd = [MC(mode=10, q=traj.ctrl[i, k], dq=0.0, tau=0.0, Kp=20.0 + k, Kd=0.5) for k in range(12)]
            cmd += [MC(mode=0, q=0.0, dq=0.0, tau=0.0, Kp=0.0, Kd=0.0)] * 8
            bag.write("/low_cmd", "unitree_legged_msgs/msg/LowCmd", ns,
                      bag.T("unitree_legged_msgs/msg/LowCmd")(levelFlag=255, motorCmd=cmd))
    bag.close()
    got = read_log(path)
    assert got.meta["format"] == "ros1"
    assert got.meta["topics"]["joint_states"] == "/low_state" and got.meta["topics"]["joint_commands"] == "/low_cmd"
    # float32 fields in the Unitree messages.
    np.testing.assert_allclose(got.joint_pos, traj.joint_pos, atol=1e-6)
    np.testing.assert_allclose(got.ctrl, traj.ctrl, atol=1e-6)
    np.testing.assert_allclose(got.box_pos, traj.box_pos, atol=1e-12)
    np.testing.assert_array_equal(got.kp, 20.0 + np.arange(12))
    np.testing.assert_array_equal(got.kd, np.full(12, 0.5))
    assert got.measured_velocity["joint_states"]


# --------------------------------------------------------------------------- #
# Writer round trips
# --------------------------------------------------------------------------- #


def test_write_mcap_round_trip(tmp_path):
    traj = make_traj()
    path = write_mcap(tmp_path / "rt.mcap", traj, metadata={"ground_truth": {"box_mass": 4.0}},
                      extra=[("/amhe/estimate", traj.t[::100], np.ones((6, 2)), ["mass", "mu"])])
    got = read_log(path)
    np.testing.assert_allclose(got.t, traj.t, atol=1e-12)
    assert_close(traj, got)
    np.testing.assert_array_equal(got.kp, traj.kp)
    np.testing.assert_array_equal(got.kd, traj.kd)
    assert got.meta["metadata"]["ground_truth"] == {"box_mass": "4.0"}
    assert got.meta["metadata"]["joint_command_gains"]["joint_order"].split(",") == list(GO1_JOINTS)
    assert got.meta["warnings"] == []
    t, values, labels = read_float_arrays(path, "/amhe/estimate")
    assert labels == ["mass", "mu"] and values.shape == (6, 2)
    np.testing.assert_allclose(t, traj.t[::100], atol=1e-12)


@pytest.mark.parametrize("missing", [("zstandard",), ("zstandard", "lz4")])
def test_a_python_without_the_zstd_codec_still_writes_a_readable_recording(tmp_path, monkeypatch, missing):
    """A run's recording must not be lost to a missing codec: mcap imports zstandard and lz4 only
    if installed, and its writer's zstd default then failed when the run ended (seen with a wheel
    set carried without dependencies)."""
    import mcap.writer as mw
    from mcap.reader import make_reader

    for codec in missing:
        monkeypatch.setattr(mw, codec, None)
    traj = make_traj()
    path = write_mcap(tmp_path / "no_zstd.mcap", traj)
    assert_close(traj, read_log(path))
    with open(path, "rb") as f:
        chunks = {c.compression for c in make_reader(f).get_summary().chunk_indexes}
    assert chunks == ({"lz4"} if len(missing) == 1 else {""})
    assert not list(tmp_path.glob("*.part"))


def test_written_mcap_is_standard_for_anyreader(tmp_path):
    from rosbags.highlevel import AnyReader

    traj = make_traj(n=101)
    path = write_mcap(tmp_path / "rt.mcap", traj)
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        odom = next(c for c in reader.connections if c.topic == "/odom")
        _, ns, raw = next(reader.messages(connections=[odom]))
        msg = reader.deserialize(raw, odom.msgtype)
    assert types == {"/joint_states": "sensor_msgs/msg/JointState", "/odom": "nav_msgs/msg/Odometry",
                     "/mocap/box/pose": "geometry_msgs/msg/PoseStamped",
                     "/joint_commands": "sensor_msgs/msg/JointState",
                     "/joint_commands/gains": "std_msgs/msg/Float64MultiArray"}
    assert counts["/joint_states"] == 101 and counts["/joint_commands"] == 21
    # Twist stored in the body frame, stamp = log time.
    q = traj.base_quat[0]
    expected = world_to_body(q, traj.base_linvel[0])
    assert [msg.twist.twist.linear.x, msg.twist.twist.linear.y] == pytest.approx(expected[:2], abs=1e-15)
    assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == ns == 0
    assert msg.child_frame_id == "base"


def test_round_trip_keeps_gaps_and_refuses_overwrite(tmp_path):
    traj = make_traj(n=201)
    bag_traj = read_log(write_bag(tmp_path / "bag", traj, box_drop=set(range(50, 60))))
    path = tmp_path / "gap.mcap"
    write_mcap(path, bag_traj)
    got = read_log(path)
    np.testing.assert_array_equal(got.observed["box"], bag_traj.observed["box"])
    assert_close(bag_traj, got)
    with pytest.raises(AmheError, match="exists"):
        write_mcap(path, bag_traj)
    write_mcap(path, bag_traj, overwrite=True)


def test_gains_from_metadata_record(tmp_path):
    traj = make_traj(n=51)
    path = tmp_path / "meta.mcap"
    with McapLog(path) as log:
        log.write_trajectory(traj, gains=False)
        order = list(GO1_JOINTS[::-1])
        log.write_metadata("joint_command_gains", {"kp": "55", "kd": np.arange(12.0)[::-1], "joint_order": order})
    got = read_log(path)
    assert got.meta["gains_source"] == "metadata joint_command_gains"
    np.testing.assert_array_equal(got.kp, np.full(12, 55.0))
    np.testing.assert_array_equal(got.kd, np.arange(12.0))  # reordered by joint name
    assert "gains" not in got.meta["topics"]


def test_mcap_log_streams_and_cleans_up_on_error(tmp_path):
    path = tmp_path / "est.mcap"
    with McapLog(path) as log:
        log.write_array("/amhe/estimate", 0.5, [4.0, 0.4], ["mass", "mu"])
        log.write_array("/amhe/estimate", [1.0, 1.5], [[4.1, 0.41], [4.2, 0.42]], ["mass", "mu"])
        log.write_metadata("settings", {"alpha": 0.3, "H": 50, "name": "run"})
        with pytest.raises(ValueError):
            log.write_array("/amhe/estimate", 2.0, [1.0], ["mass", "mu"])
    t, values, labels = read_float_arrays(path, "/amhe/estimate")
    np.testing.assert_allclose(t, [0.5, 1.0, 1.5])
    np.testing.assert_allclose(values[:, 0], [4.0, 4.1, 4.2])
    assert inspect_log(path).metadata["settings"] == {"alpha": "0.3", "H": "50", "name": "run"}
    failed = tmp_path / "failed.mcap"
    with pytest.raises(RuntimeError):
        with McapLog(failed) as log:
            log.write_array("/x", 0.0, [1.0], ["a"])
            raise RuntimeError("boom")
    assert not failed.exists() and not (tmp_path / "failed.mcap.part").exists()


# --------------------------------------------------------------------------- #
# The shared recorded log
# --------------------------------------------------------------------------- #

needs_const_a = pytest.mark.skipif(not CONST_A.exists(), reason="shared log const_a.mcap absent")


@needs_const_a
def test_const_a_initial_box_and_gains():
    traj = read_log(CONST_A)
    np.testing.assert_allclose(traj.box_pos[0], [1.0, 0.0, 0.18], atol=1e-9)
    np.testing.assert_allclose(traj.box_quat[0], [1.0, 0.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_array_equal(traj.kp, np.full(12, 55.0))
    np.testing.assert_array_equal(traj.kd, np.full(12, 3.0))
    assert len(traj) == 10001 and traj.duration == pytest.approx(20.0)
    assert traj.valid().all()
    # 100 Hz commands held over 5 steps of 2 ms.
    changes = np.flatnonzero(np.any(traj.ctrl[1:] != traj.ctrl[:-1], axis=1)) + 1
    assert set(changes % 5) == {0}
    assert traj.meta["metadata"]["joint_command_gains"]["kp"] == "55.0"


@needs_const_a
def test_truncated_mcap_yields_data_and_warning(tmp_path):
    cut = tmp_path / "cut.mcap"
    data = CONST_A.read_bytes()
    cut.write_bytes(data[: int(0.4 * len(data))])
    with pytest.warns(UserWarning, match="truncated"):
        traj = read_log(cut)
    assert any("truncated" in w for w in traj.meta["warnings"])
    assert 2.0 < traj.duration < 12.0
    np.testing.assert_allclose(traj.box_pos[0], [1.0, 0.0, 0.18], atol=1e-9)
    full_head = read_log(CONST_A).slice(0, len(traj))
    np.testing.assert_allclose(traj.joint_pos, full_head.joint_pos, atol=1e-12)
    info = inspect_log(cut)
    assert info.warnings and info.roles["box"] == "/mocap/box/pose"
