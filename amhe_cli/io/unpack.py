"""Unpack decoded messages into time-stamped arrays: step 3 of :mod:`~amhe_cli.io.reader`.

The messages of each role become time-stamped arrays in MuJoCo conventions
(wxyz quaternions, joints in :data:`~amhe_cli.io.trajectory.GO1_JOINTS` order,
matched by name), dropping the few messages with non-finite values; PD gains
are taken from the commands, a gains topic or an MCAP metadata record.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.joints import match_joints
from amhe_cli.io.logfile import _one_line
from amhe_cli.io.quat import body_to_world, quat_make_continuous, ros_to_mj
from amhe_cli.io.smoothing import noise_sigma
from amhe_cli.io.roles import GAINS_ROLE, _LOWCMD_TYPES, _LOWSTATE_TYPES, _short_type

#: Name of the MCAP metadata record that carries the PD gains.
GAINS_RECORD = "joint_command_gains"
#: A log is rejected when more than this fraction of a role's messages is bad.
_MAX_BAD_FRACTION = 0.10


@dataclass
class _Series:
    """The messages of one role as arrays, in time order.

    ``t_ns``: (N,) int64 message times. ``fields``: name -> (N, k) float array,
    e.g. ``pos`` (N, 3), ``quat`` (N, 4) wxyz, ``linvel`` (N, 3) world frame,
    ``angvel`` (N, 3) body frame, ``q``/``dq`` (N, 12) canonical joint order,
    ``tau`` (N, 12) joint efforts [N·m] where every message carries them.
    """

    topic: str
    msgtype: str
    t_ns: np.ndarray
    fields: dict[str, np.ndarray]
    #: median (log time − header stamp) [ns]: the transport latency, None without header stamps
    latency_ns: float | None = None
    #: the header frames the poses are given in (``frame_id``, leading ``/`` dropped; none for joints)
    frames: tuple = ()
    _pose_noise: tuple | None = field(default=None, repr=False, compare=False)

    def period_ns(self) -> float:
        """Median spacing of the messages [ns]."""
        return float(np.median(np.diff(self.t_ns))) if len(self.t_ns) > 1 else float("inf")

    def pose_noise(self) -> tuple[float, float]:
        """White-noise σ of a pose stream: position [m] and orientation [rad], the larger axis of each
        (:func:`~amhe_cli.io.smoothing.noise_sigma`; the orientation as twice the quaternion's vector
        part). Computed once: the sensor report and the smoothing window both ask."""
        if self._pose_noise is None:
            f = self.fields
            self._pose_noise = (float(noise_sigma(f["pos"]).max()),
                                float(noise_sigma(2.0 * quat_make_continuous(f["quat"])[:, 1:]).max()))
        return self._pose_noise


def _attr(obj: Any, *names: str) -> Any:
    for name in names:
        if hasattr(obj, name):
            return getattr(obj, name)
    raise AttributeError(f"none of the fields {', '.join(names)}")


def _stamp_ns(msg: Any) -> int:
    """Header stamp [ns], 0 for a message without header."""
    header = getattr(msg, "header", None)
    if header is None:
        return 0
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _vec(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def _quat(q: Any) -> list[float]:
    return [q.x, q.y, q.z, q.w]


def _unpack_pose(msgtype: str, msg: Any) -> dict[str, list[float]]:
    """Pose (and twist if the type has one) of one message, ROS conventions."""
    if msgtype == "nav_msgs/Odometry":
        pose = msg.pose.pose
        return {
            "pose.pose.position": _vec(pose.position),
            "pose.pose.orientation": _quat(pose.orientation),
            "twist.twist.linear": _vec(msg.twist.twist.linear),
            "twist.twist.angular": _vec(msg.twist.twist.angular),
        }
    if msgtype == "geometry_msgs/PoseStamped":
        return {"pose.position": _vec(msg.pose.position), "pose.orientation": _quat(msg.pose.orientation)}
    if msgtype == "geometry_msgs/PoseWithCovarianceStamped":
        pose = msg.pose.pose
        return {"pose.pose.position": _vec(pose.position), "pose.pose.orientation": _quat(pose.orientation)}
    if msgtype == "geometry_msgs/TransformStamped":
        tf = msg.transform
        return {"transform.translation": _vec(tf.translation), "transform.rotation": _quat(tf.rotation)}
    raise AssertionError(msgtype)


def _motors(msg: Any, kind: str) -> list[Any]:
    """First 12 motor entries of a Unitree LowState/LowCmd (Go1 order = GO1_JOINTS)."""
    motors = _attr(msg, "motorState", "motor_state") if kind == "state" else _attr(msg, "motorCmd", "motor_cmd")
    return list(motors)[:12]


class _Unpacker:
    """Turns the decoded messages of one role into a :class:`_Series`.

    Collects per-field rows; rows that cannot be unpacked (wrong length, no
    names) become NaN so the non-finite filter counts and drops them.
    """

    def __init__(self, role: str, topic: str, msgtype: str, joint_names_map, warns: list[str],
                 fallback_names: list[str] | None = None):
        self.role, self.topic, self.msgtype = role, topic, _short_type(msgtype)
        self.full_type = msgtype
        self.joint_names_map = joint_names_map
        self.fallback_names = fallback_names
        self.warns = warns
        self.t: list[int] = []
        self.stamps: list[int] = []
        self.rows: dict[str, list] = {}
        self.names: list[str] | None = None
        self._index_cache: dict[tuple[str, ...], np.ndarray] = {}
        self._no_names = 0
        self.frames: set[str] = set()

    def _put(self, key: str, row) -> None:
        self.rows.setdefault(key, []).append(row)

    def _joint_index(self, names: tuple[str, ...], n_values: int) -> np.ndarray | None:
        if not names:
            if self.fallback_names is not None and n_values == len(self.fallback_names):
                self._no_names += 1
                names = tuple(self.fallback_names)
            else:
                return None
        idx = self._index_cache.get(names)
        if idx is None:
            idx = match_joints(list(names), self.joint_names_map, topic=self.topic)
            self._index_cache[names] = idx
            if self.names is None:
                self.names = list(names)
        return idx

    def add(self, log_ns: int, msg: Any) -> None:
        self.t.append(int(log_ns))
        self.stamps.append(_stamp_ns(msg))
        kind = self.msgtype
        nan12 = np.full(12, np.nan)
        if kind == "sensor_msgs/JointState":
            pos = np.asarray(msg.position, dtype=float)
            idx = self._joint_index(tuple(msg.name), len(pos))
            ok = idx is not None and len(pos) == (len(msg.name) or len(pos))
            self._put("position", pos[idx] if ok else nan12)
            if self.role == "joint_states":
                vel = np.asarray(msg.velocity, dtype=float)
                self._put("velocity", vel[idx] if ok and len(vel) == len(pos) else None)
                eff = np.asarray(msg.effort, dtype=float)
                self._put("effort", eff[idx] if ok and len(eff) == len(pos) else None)
        elif kind in _LOWSTATE_TYPES:
            motors = _motors(msg, "state")
            self._put("motorState.q", [m.q for m in motors] if len(motors) == 12 else nan12)
            self._put("motorState.dq", [m.dq for m in motors] if len(motors) == 12 else nan12)
            self._put("motorState.tauEst", [getattr(m, "tauEst", getattr(m, "tau_est", np.nan)) for m in motors]
                      if len(motors) == 12 else None)
        elif kind in _LOWCMD_TYPES:
            motors = _motors(msg, "cmd")
            ok = len(motors) == 12
            self._put("motorCmd.q", [m.q for m in motors] if ok else nan12)
            self._put("Kp", [_attr(m, "Kp", "kp") for m in motors] if ok else nan12)
            self._put("Kd", [_attr(m, "Kd", "kd") for m in motors] if ok else nan12)
        elif kind == "std_msgs/Float64MultiArray":
            self._put("data", np.asarray(msg.data, dtype=float))
        else:
            for key, row in _unpack_pose(kind, msg).items():
                self._put(key, row)
            self.frames.add(str(getattr(getattr(msg, "header", None), "frame_id", "")).lstrip("/"))

    def finish(self) -> _Series:
        """Validate, drop bad rows, sort by time and convert to MuJoCo conventions.

        Raises:
            AmheError: no usable messages, or more than 10 % bad messages.
        """
        if self._no_names:
            self.warns.append(
                f"{self._no_names} messages on '{self.topic}' carry no joint names; assumed the joint "
                f"order of the joint states"
            )
        if self.msgtype == "sensor_msgs/JointState" and self.names is None and self.t:
            raise AmheError(
                f"messages on '{self.topic}' carry no joint names: expected sensor_msgs/JointState.name "
                f"to list the Go1 joints"
            )
        n = len(self.t)
        if n == 0:
            raise AmheError(f"topic '{self.topic}' for role '{self.role}' has no messages")
        optional = {k: self.rows.pop(k, None) for k in ("velocity", "effort", "motorState.tauEst")}
        if "data" in self.rows:  # arrays of varying length: rows unlike the first are bad
            size = len(self.rows["data"][0])
            self.rows["data"] = [r if len(r) == size else np.full(size, np.nan) for r in self.rows["data"]]
        arrays = {k: np.asarray(v, dtype=float) for k, v in self.rows.items()}
        for key, rows in optional.items():  # kept only where every message has them
            if rows is not None and all(r is not None for r in rows):
                arrays[key] = np.asarray(rows, dtype=float)
        bad = np.zeros(n, dtype=bool)
        worst, worst_count = "", 0
        for key, arr in arrays.items():
            rows_bad = ~np.all(np.isfinite(arr.reshape(n, -1)), axis=1)
            if key.endswith(("orientation", "rotation")):
                rows_bad |= np.linalg.norm(np.nan_to_num(arr), axis=1) < 1e-6
            if rows_bad.sum() > worst_count:
                worst, worst_count = key, int(rows_bad.sum())
            bad |= rows_bad
        if bad.any():
            n_bad = int(bad.sum())
            if n_bad > _MAX_BAD_FRACTION * n:
                raise AmheError(
                    f"topic '{self.topic}' has non-finite or invalid values in field '{worst}' in {n_bad} of "
                    f"{n} messages: expected finite numbers (at most 10 % bad messages are dropped)"
                )
            self.warns.append(
                f"dropped {n_bad} of {n} messages on '{self.topic}' with non-finite or invalid "
                f"values (field '{worst}')"
            )
        keep = ~bad
        # Header stamps are the measurement times; a topic whose stamps are all
        # zero (not filled in) falls back to the log (receive) times.
        stamps = np.asarray(self.stamps, dtype=np.int64)
        log_t = np.asarray(self.t, dtype=np.int64)
        t = (stamps if stamps.any() else log_t)[keep]
        latency = float(np.median(log_t[keep] - stamps[keep])) if stamps.any() else None
        arrays = {k: v[keep] for k, v in arrays.items()}
        order = np.argsort(t, kind="stable")
        t = t[order]
        arrays = {k: v[order] for k, v in arrays.items()}
        # Duplicate stamps: keep the last message of each time.
        last = np.append(t[1:] != t[:-1], True)
        if not last.all():
            self.warns.append(f"{int((~last).sum())} messages on '{self.topic}' repeat a time stamp; kept the last")
            t = t[last]
            arrays = {k: v[last] for k, v in arrays.items()}
        return _Series(self.topic, self.full_type, t, self._convert(arrays), latency, tuple(sorted(self.frames - {""})))

    def _convert(self, a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Rename fields to role-independent names in MuJoCo conventions."""
        kind = self.msgtype
        if kind == "sensor_msgs/JointState":
            out = {"q": a["position"]}
            if "velocity" in a:
                out["dq"] = a["velocity"]
            if "effort" in a:
                out["tau"] = a["effort"]
            return out
        if kind in _LOWSTATE_TYPES:
            out = {"q": a["motorState.q"], "dq": a["motorState.dq"]}
            if "motorState.tauEst" in a:
                out["tau"] = a["motorState.tauEst"]
            return out
        if kind in _LOWCMD_TYPES:
            return {"q": a["motorCmd.q"], "kp": a["Kp"], "kd": a["Kd"]}
        if kind == "std_msgs/Float64MultiArray":
            return {"data": a["data"]} if "data" in a else {}
        pos_key, quat_key = [k for k in a if not k.startswith("twist")][:2]
        quat = ros_to_mj(a[quat_key])
        quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        out = {"pos": a[pos_key], "quat": quat_make_continuous(quat)}
        if "twist.twist.linear" in a:
            lin, ang = a["twist.twist.linear"], a["twist.twist.angular"]
            moving = np.ptp(a[pos_key], axis=0).max() > 1e-6 if len(lin) else False
            if not lin.any() and not ang.any() and moving:
                self.warns.append(
                    f"twist on '{self.topic}' is all zero while the pose moves; differentiated the pose instead"
                )
            else:
                # Odometry twist is in the child (body) frame; MuJoCo wants world linear velocity.
                out["linvel"] = body_to_world(quat, lin)
                out["angvel"] = ang
        return out


def _parse_floats(text: str) -> np.ndarray:
    return np.array([float(x) for x in re.split(r"[,\s\[\]]+", text.strip()) if x], dtype=float)


def _gains(series: dict[str, _Series], meta: dict, warns: list[str], joint_names_map: dict | None):
    """PD gains ``(kp (12,), kd (12,), source)`` from LowCmd, a gains topic or the
    metadata record, in that order of preference; ``(None, None, None)`` if none.

    A 24-value gains array is taken to follow the joint order of the command
    messages; the metadata record's optional ``joint_order`` key names its order.
    """
    cmd = series["joint_commands"]
    if "kp" in cmd.fields and np.any(cmd.fields["kp"]):
        kp, kd = cmd.fields["kp"], cmd.fields["kd"]
        if np.ptp(kp, axis=0).max() > 0 or np.ptp(kd, axis=0).max() > 0:
            warns.append(f"gains on '{cmd.topic}' change during the log; using the first")
        return kp[0].copy(), kd[0].copy(), f"topic {cmd.topic}"
    gs = series.get(GAINS_ROLE)
    if gs is not None and "kp" in gs.fields:
        return gs.fields["kp"][0].copy(), gs.fields["kd"][0].copy(), f"topic {gs.topic}"
    if gs is not None and "data" in gs.fields and gs.fields["data"].shape[1:] == (24,):
        data = gs.fields["data"]
        if np.ptp(data, axis=0).max() > 0:
            warns.append(f"gains on '{gs.topic}' change during the log; using the first")
        order = meta["joint_names"].get("joint_commands")
        idx = match_joints(order, joint_names_map) if order and len(order) == 12 else np.arange(12)
        return data[0, :12][idx], data[0, 12:][idx], f"topic {gs.topic}"
    if gs is not None:
        warns.append(f"ignored gains topic '{gs.topic}': expected 24 values (12 kp, then 12 kd)")
    record = meta["metadata"].get(GAINS_RECORD)
    if record and "kp" in record and "kd" in record:
        try:
            kp, kd = _parse_floats(record["kp"]), _parse_floats(record["kd"])
            kp = np.broadcast_to(kp, (12,)).copy() if kp.size == 1 else kp
            kd = np.broadcast_to(kd, (12,)).copy() if kd.size == 1 else kd
            if kp.shape != (12,) or kd.shape != (12,):
                raise ValueError("expected 1 or 12 values")
            if record.get("joint_order"):
                idx = match_joints([s.strip() for s in record["joint_order"].split(",")], joint_names_map)
                kp, kd = kp[idx], kd[idx]
            return kp, kd, f"metadata {GAINS_RECORD}"
        except (ValueError, AmheError) as err:
            warns.append(f"ignored metadata record '{GAINS_RECORD}': {_one_line(err)}")
    return None, None, None
