"""Read a recorded log (MCAP, rosbag2, ROS 1 bag) into a :class:`Trajectory`.

The pipeline, one step per section below:

1. **open** the log with ``rosbags.highlevel.AnyReader`` (bare ``.mcap``,
   rosbag2 folders with sqlite3 or mcap storage, ROS 1 ``.bag``); a truncated
   MCAP (no footer/summary) falls back to the ``mcap`` stream reader and keeps
   whatever complete records precede the cut;
2. **assign roles** (``joint_states``, ``base``, ``box``, ``joint_commands``,
   optional ``gains``) to topics by message type, topic-name hints or the
   caller's explicit choice;
3. **unpack** the messages of each role into time-stamped arrays in MuJoCo
   conventions (wxyz quaternions, joints in :data:`GO1_JOINTS` order, matched by
   name), dropping the few messages with non-finite values;
4. **resample** onto a uniform grid covering the overlap of the roles: linear
   interpolation of positions, slerp of orientations, zero-order hold of the
   commands; velocities come from the log where it has them, else from a
   backward difference of the resampled poses.

:func:`inspect_log` runs only steps 1 and 2 on message timestamps (no
decoding) to describe a log for ``amhe probe``.
"""

from __future__ import annotations

import hashlib
import itertools
import re
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import AmheError
from ..trajectory import GO1_JOINTS, Trajectory
from .smoothing import CLEAN_SIGMA_ROT, noise_sigma, savgol, window_for
from .quat import (
    body_to_world,
    quat_conj,
    quat_make_continuous,
    quat_mul,
    quat_normalize,
    quat_slerp,
    quat_to_rotvec,
    ros_to_mj,
)

__all__ = [
    "REQUIRED_ROLES",
    "LogInfo",
    "TopicInfo",
    "assign_roles",
    "canonical_joint_name",
    "inspect_log",
    "match_joints",
    "read_float_arrays",
    "read_log",
]

#: Roles a log must provide for identification, in the order they are checked.
REQUIRED_ROLES: tuple[str, ...] = ("joint_states", "base", "box", "joint_commands")
#: Optional role: PD gains of the joint position controller.
GAINS_ROLE = "gains"
#: Name of the MCAP metadata record that carries the PD gains.
GAINS_RECORD = "joint_command_gains"

_ROLE_WHAT = {
    "joint_states": "joint states",
    "base": "robot base pose",
    "box": "box pose",
    "joint_commands": "joint commands",
    "gains": "joint PD gains",
}

_POSE_TYPES = (
    "geometry_msgs/PoseStamped",
    "nav_msgs/Odometry",
    "geometry_msgs/PoseWithCovarianceStamped",
    "geometry_msgs/TransformStamped",
)
_LOWSTATE_TYPES = ("unitree_legged_msgs/LowState", "unitree_go/LowState")
_LOWCMD_TYPES = ("unitree_legged_msgs/LowCmd", "unitree_go/LowCmd")
#: Message types (``pkg/Type``, without ``/msg/``) accepted for each role.
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "joint_states": ("sensor_msgs/JointState", *_LOWSTATE_TYPES),
    "base": _POSE_TYPES,
    "box": _POSE_TYPES,
    "joint_commands": ("sensor_msgs/JointState", *_LOWCMD_TYPES),
    "gains": ("std_msgs/Float64MultiArray", *_LOWCMD_TYPES),
}

#: Topic-name hints: substrings that make a topic more (+1 each) or less (-1
#: each) likely to play a role when several topics share a message type.
_HINTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "joint_states": (
        ("state", "joint", "feedback", "measured"),
        ("command", "cmd", "target", "desired", "setpoint", "goal"),
    ),
    "joint_commands": (
        ("command", "cmd", "target", "desired", "setpoint", "goal"),
        ("state", "feedback", "measured"),
    ),
    "base": (
        ("odom", "base", "body", "trunk", "robot", "go1", "torso", "state_estimat"),
        ("box", "object", "payload", "crate", "cube"),
    ),
    "box": (
        ("box", "object", "payload", "crate", "cube", "mocap", "vicon", "optitrack"),
        ("odom", "base", "body", "trunk", "robot", "go1", "torso"),
    ),
    "gains": (("gain", "kp"), ()),
}
#: Small type preferences that break ties between otherwise equal topics.
_TYPE_PRIOR = {
    ("base", "nav_msgs/Odometry"): 0.5,
    ("box", "geometry_msgs/PoseStamped"): 0.25,
    ("box", "geometry_msgs/TransformStamped"): 0.25,
    ("joint_states", "unitree_legged_msgs/LowState"): 0.5,
    ("joint_states", "unitree_go/LowState"): 0.5,
}

#: A log is rejected when more than this fraction of a role's messages is bad.
_MAX_BAD_FRACTION = 0.10
#: A grid time counts as observed if its bracketing messages are at most this
#: many median message periods apart (commands: if the last one is this old).
_GAP_FACTOR = 1.5


def _short_type(msgtype: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs/JointState``."""
    return msgtype.replace("/msg/", "/")


# --------------------------------------------------------------------------- #
# 1. Opening a log
# --------------------------------------------------------------------------- #

_NOT_A_LOG = "expected an MCAP file, a rosbag2 folder or a ROS 1 .bag"


@dataclass
class _OpenLog:
    """An opened log: its topics, metadata and a message iterator.

    ``iterate(topics, decode)`` yields ``(topic, log_time_ns, message)`` where
    ``message`` is the decoded message object (attribute access by field name)
    or, with ``decode=False``, None.
    """

    path: Path
    format: str
    topics: dict[str, str]
    counts: dict[str, int]
    metadata: dict[str, dict[str, str]]
    warnings: list[str]
    iterate: Callable[[Any, bool], Iterator[tuple[str, int, Any]]]


def _detect_format(path: Path) -> str:
    """Classify ``path`` as 'mcap', 'rosbag2', 'db3' or 'ros1'; AmheError otherwise."""
    if not path.exists():
        raise AmheError(f"log '{path}' does not exist: {_NOT_A_LOG}")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag2"
        raise AmheError(
            f"cannot read '{path}' as a log: the folder has no metadata.yaml, so it is not a "
            f"rosbag2 folder; {_NOT_A_LOG}"
        )
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"#ROSBAG V2.0"):
        if path.suffix != ".bag":
            raise AmheError(f"cannot read ROS 1 bag '{path}': its name must end in .bag")
        return "ros1"
    if head.startswith(b"SQLite format 3") and path.suffix == ".db3":
        return "db3"
    raise AmheError(f"cannot read '{path}' as a log: {_NOT_A_LOG}")


def _mcap_metadata(files: list[Path]) -> dict[str, dict[str, str]]:
    """MCAP metadata records of complete MCAP files, name -> {key: value}."""
    from mcap.reader import make_reader

    out: dict[str, dict[str, str]] = {}
    for file in files:
        with file.open("rb") as f:
            for record in make_reader(f).iter_metadata():
                out[record.name] = dict(record.metadata)
    return out


@contextmanager
def _open_log(path: str | Path) -> Iterator[_OpenLog]:
    """Open a log of any supported format (see module docstring).

    Raises:
        AmheError: missing path, not a log, unreadable or undecodable log.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if path.name == "metadata.yaml" and path.is_file():
        path = path.parent
    fmt = _detect_format(path)
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # rosbags raises several unrelated types here
        if fmt == "mcap":
            yield _open_mcap_stream(path, reason=_one_line(err).rstrip("."))
            return
        raise AmheError(f"cannot read '{path}' as a {_FORMAT_NAMES[fmt]}: {_one_line(err)}") from None
    try:
        warns: list[str] = []
        metadata: dict[str, dict[str, str]] = {}
        mcap_files = [path] if fmt == "mcap" else sorted(path.glob("*.mcap")) if fmt == "rosbag2" else []
        if mcap_files:
            try:
                metadata = _mcap_metadata(mcap_files)
            except Exception as err:  # metadata is optional: keep the messages
                warns.append(f"could not read the MCAP metadata records of '{path}': {_one_line(err)}")
        if fmt == "rosbag2":
            storage = "mcap" if mcap_files else "sqlite3"
            fmt = f"rosbag2/{storage}"
        elif fmt == "db3":
            fmt = "rosbag2/sqlite3"
        topics: dict[str, str] = {}
        counts: dict[str, int] = {}
        for conn in reader.connections:
            topics.setdefault(conn.topic, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount

        def iterate(wanted, decode: bool) -> Iterator[tuple[str, int, Any]]:
            conns = [c for c in reader.connections if c.topic in wanted]
            if not conns:
                return
            for conn, timestamp, raw in reader.messages(connections=conns):
                if not decode:
                    yield conn.topic, timestamp, None
                    continue
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as err:
                    raise AmheError(
                        f"cannot decode a {conn.msgtype} message on '{conn.topic}' in '{path}': "
                        f"{_one_line(err)}"
                    ) from None
                yield conn.topic, timestamp, msg

        yield _OpenLog(path, fmt, topics, counts, metadata, warns, iterate)
    finally:
        reader.close()


_FORMAT_NAMES = {
    "mcap": "MCAP file",
    "rosbag2": "rosbag2 folder",
    "db3": "rosbag2 sqlite3 file",
    "ros1": "ROS 1 bag",
}


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text or type(err).__name__


def _open_mcap_stream(path: Path, reason: str) -> _OpenLog:
    """Read an MCAP file record by record, keeping everything before a cut.

    Used when the indexed reader fails, typically because the file was cut
    mid-way (a recorder that crashed): there is no footer or summary, but the
    complete chunks before the cut are still valid.

    Raises:
        AmheError: the file does not even hold a readable header and channel.
    """
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: dict[str, dict[str, str]] = {}
    messages: dict[int, list[tuple[int, bytes]]] = {}
    broke: str | None = None
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Message):
                    messages.setdefault(record.channel_id, []).append((record.log_time, record.data))
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
        except Exception as err:  # EndOfFile, a torn record, a bad chunk...
            broke = _one_line(err)
    n_msgs = sum(len(v) for v in messages.values())
    if not channels:
        raise AmheError(f"cannot read '{path}' as an MCAP file: {reason}; no channel could be recovered")
    warns: list[str] = []
    if broke is not None:
        times = [t for v in messages.values() for t, _ in v]
        span = (max(times) - min(times)) * 1e-9 if times else 0.0
        warns.append(
            f"'{path.name}' is truncated or damaged ({reason}); read the {n_msgs} complete "
            f"messages before the cut, spanning {span:.3f} s; the rest of the log is lost"
        )
    topics = {c.topic: schemas[c.schema_id].name if c.schema_id in schemas else "" for c in channels.values()}
    counts = {c.topic: 0 for c in channels.values()}
    for cid, lst in messages.items():
        if cid in channels:
            counts[channels[cid].topic] += len(lst)
    factory = DecoderFactory()

    def iterate(wanted, decode: bool) -> Iterator[tuple[str, int, Any]]:
        for cid, lst in messages.items():
            chan = channels.get(cid)
            if chan is None or chan.topic not in wanted:
                continue
            decoder = None
            if decode:
                try:
                    decoder = factory.decoder_for(chan.message_encoding, schemas.get(chan.schema_id))
                except Exception as err:
                    decoder, why = None, _one_line(err)
                else:
                    why = f"message encoding {chan.message_encoding!r} is not ROS 2 CDR"
                if decoder is None:
                    raise AmheError(f"cannot decode messages on '{chan.topic}' in '{path}': {why}")
            for log_time, data in lst:
                yield chan.topic, log_time, (decoder(data) if decoder else None)

    return _OpenLog(path, "mcap", topics, counts, metadata, warns, iterate)


def _sha256(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (relative name and content, sorted by name)."""
    digest = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode() + b"\0")
        with file.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


# --------------------------------------------------------------------------- #
# 2. Roles
# --------------------------------------------------------------------------- #


def _topics_present(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} [{ty}]" for t, ty in sorted(topics.items())) or "none"


def _hint_score(role: str, topic: str, msgtype: str) -> float:
    # Motion-capture drivers name their streams "rigid_body_N": not a robot body.
    name = re.sub(r"rigid_?body", "", topic.lower())
    pos, neg = _HINTS[role]
    score = sum(1.0 for h in pos if h in name) - sum(1.0 for h in neg if h in name)
    return score + _TYPE_PRIOR.get((role, _short_type(msgtype)), 0.0)


def _expected_types(role: str) -> str:
    types = list(ROLE_TYPES[role])
    return ", ".join(types[:-1]) + " or " + types[-1] if len(types) > 1 else types[0]


def assign_roles(
    topics: dict[str, str], explicit: dict[str, str] | None = None
) -> tuple[dict[str, str], dict[str, str]]:
    """Decide which topic plays which role.

    Explicit choices win. Otherwise a topic is a candidate for a role if its
    message type fits the role and its name does not point elsewhere (hints such
    as ``box``/``object``/``mocap`` for the box, ``odom``/``base``/``trunk`` for the
    base, ``cmd``/``command`` vs ``state`` for joints); each role gets a distinct
    topic and the assignment with the best total hint score wins. A role whose
    best topic is not unique is reported as ambiguous.

    Args:
        topics: topic -> message type (e.g. ``sensor_msgs/msg/JointState``).
        explicit: role -> topic chosen by the user (``--topic box=/vicon/box``).

    Returns:
        ``(roles, problems)``: role -> topic for every role that could be
        assigned, and role -> one-line explanation for every required role that
        could not (missing or ambiguous). ``gains`` is optional and only appears
        in ``roles``.

    Raises:
        AmheError: an explicit choice names an unknown role, a topic that is not
            in the log, or a topic whose type cannot play that role.
    """
    explicit = dict(explicit or {})
    roles: dict[str, str] = {}
    problems: dict[str, str] = {}
    present = _topics_present(topics)
    for role, topic in explicit.items():
        if role not in ROLE_TYPES:
            raise AmheError(
                f"unknown role '{role}' in topic choice: expected one of {', '.join(ROLE_TYPES)}"
            )
        if topic not in topics:
            raise AmheError(f"topic '{topic}' chosen for role '{role}' is not in the log; topics present: {present}")
        if _short_type(topics[topic]) not in ROLE_TYPES[role]:
            raise AmheError(
                f"topic '{topic}' chosen for role '{role}' has type {topics[topic]}; expected "
                f"{_expected_types(role)}"
            )
        roles[role] = topic

    taken = set(roles.values())
    for group in (("joint_states", "joint_commands"), ("base", "box")):
        free = [r for r in group if r not in roles]
        cands = {
            r: [
                (t, _hint_score(r, t, ty))
                for t, ty in sorted(topics.items())
                if t not in taken and _short_type(ty) in ROLE_TYPES[r] and _hint_score(r, t, ty) >= 0
            ]
            for r in free
        }
        best: list[tuple[tuple[int, float], tuple]] = []
        for combo in itertools.product(*[c + [(None, 0.0)] for c in cands.values()]):
            chosen = [t for t, _ in combo if t is not None]
            if len(chosen) != len(set(chosen)):
                continue
            key = (len(chosen), sum(s for _, s in combo))
            if not best or key > best[0][0]:
                best = [(key, combo)]
            elif key == best[0][0]:
                best.append((key, combo))
        for k, role in enumerate(free):
            options = sorted({combo[k][0] for _, combo in best} - {None}) if best else []
            if len(options) == 1 and all(combo[k][0] is not None for _, combo in best):
                roles[role] = options[0]
            elif len(options) > 1:
                listed = ", ".join(f"{t} [{topics[t]}]" for t in options)
                problems[role] = (
                    f"log has several candidates for role '{role}' ({_ROLE_WHAT[role]}): {listed}; "
                    f"choose one with --topic {role}=NAME"
                )
            else:
                problems[role] = (
                    f"log has no {_ROLE_WHAT[role]}: expected a {_expected_types(role)} topic for "
                    f"role '{role}' (use --topic {role}=NAME); topics present: {present}"
                )

    if GAINS_ROLE not in roles:
        if _short_type(topics.get(roles.get("joint_commands", ""), "")) in _LOWCMD_TYPES:
            roles[GAINS_ROLE] = roles["joint_commands"]
        else:
            cands = [
                t for t, ty in topics.items()
                if _short_type(ty) == "std_msgs/Float64MultiArray" and _hint_score(GAINS_ROLE, t, ty) > 0
            ]
            if len(cands) == 1:
                roles[GAINS_ROLE] = cands[0]
    return roles, problems


# --------------------------------------------------------------------------- #
# 3. Joint names
# --------------------------------------------------------------------------- #

_LEG_ALIASES = {"fr": "FR", "rf": "FR", "fl": "FL", "lf": "FL", "rr": "RR", "rh": "RR", "rl": "RL", "lh": "RL"}
_PART_ALIASES = {
    "hip": "hip", "haa": "hip", "abad": "hip", "abduction": "hip",
    "thigh": "thigh", "hfe": "thigh", "upper": "thigh",
    "calf": "calf", "kfe": "calf", "knee": "calf", "shank": "calf", "lower": "calf",
}


def canonical_joint_name(name: str) -> str | None:
    """Go1 joint name (:data:`GO1_JOINTS`) for a joint name used by some stack.

    Case-insensitive; accepts ``FR_hip_joint``, ``FR_hip``, ``fr_hip_joint``,
    prefixes such as ``go1/FR_hip_joint`` and ANYmal-style ``RF_HAA``/``LH_KFE``
    (LF=FL, RF=FR, LH=RL, RH=RR; HAA=hip, HFE=thigh, KFE=calf).

    Returns:
        The canonical name, or None when the name is not recognised.
    """
    tokens = [t for t in re.split(r"[^a-z0-9]+", name.lower()) if t and t != "joint"]
    legs = {_LEG_ALIASES[t] for t in tokens if t in _LEG_ALIASES}
    parts = {_PART_ALIASES[t] for t in tokens if t in _PART_ALIASES}
    if len(legs) != 1 or len(parts) != 1:
        return None
    return f"{legs.pop()}_{parts.pop()}_joint"


def match_joints(names: list[str] | tuple[str, ...], joint_names_map: dict[str, str] | None = None,
                 *, topic: str = "") -> np.ndarray:
    """Indices that put a message's joints into :data:`GO1_JOINTS` order.

    Args:
        names: joint names of one message, any order (extra joints are ignored).
        joint_names_map: optional explicit map, log name -> Go1 joint name
            (canonical or any alias :func:`canonical_joint_name` accepts); it is
            applied before automatic matching.
        topic: topic name used in error messages.

    Returns:
        (12,) int array ``idx`` with ``values[idx]`` in canonical order.

    Raises:
        AmheError: a Go1 joint is missing, two log joints map to the same Go1
            joint, or ``joint_names_map`` names an unknown Go1 joint.
    """
    where = f" on '{topic}'" if topic else ""
    explicit = {}
    for log_name, target in (joint_names_map or {}).items():
        canon = target if target in GO1_JOINTS else canonical_joint_name(target)
        if canon is None:
            raise AmheError(
                f"joint map entry '{log_name}: {target}' names no Go1 joint: expected one of {', '.join(GO1_JOINTS)}"
            )
        explicit[log_name] = canon
    found: dict[str, int] = {}
    for i, name in enumerate(names):
        canon = explicit.get(name) or canonical_joint_name(name)
        if canon is None:
            continue
        if canon in found:
            raise AmheError(
                f"joints '{names[found[canon]]}' and '{name}'{where} both match Go1 joint {canon}; "
                f"give a joint map to choose"
            )
        found[canon] = i
    missing = [j for j in GO1_JOINTS if j not in found]
    if missing:
        raise AmheError(
            f"joint names{where} lack Go1 joints {', '.join(missing)}; names in the log: "
            f"{', '.join(names) or '(none)'} (give a joint map, log name -> Go1 name)"
        )
    return np.array([found[j] for j in GO1_JOINTS], dtype=int)


# --------------------------------------------------------------------------- #
# 4. Unpacking messages
# --------------------------------------------------------------------------- #


@dataclass
class _Series:
    """The messages of one role as arrays, in time order.

    ``t_ns``: (N,) int64 message times. ``fields``: name -> (N, k) float array,
    e.g. ``pos`` (N, 3), ``quat`` (N, 4) wxyz, ``linvel`` (N, 3) world frame,
    ``angvel`` (N, 3) body frame, ``q``/``dq`` (N, 12) canonical joint order.
    """

    topic: str
    msgtype: str
    t_ns: np.ndarray
    fields: dict[str, np.ndarray]

    def period_ns(self) -> float:
        """Median spacing of the messages [ns]."""
        return float(np.median(np.diff(self.t_ns))) if len(self.t_ns) > 1 else float("inf")


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
        elif kind in _LOWSTATE_TYPES:
            motors = _motors(msg, "state")
            self._put("motorState.q", [m.q for m in motors] if len(motors) == 12 else nan12)
            self._put("motorState.dq", [m.dq for m in motors] if len(motors) == 12 else nan12)
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
        vel = self.rows.pop("velocity", None)
        if "data" in self.rows:  # arrays of varying length: rows unlike the first are bad
            size = len(self.rows["data"][0])
            self.rows["data"] = [r if len(r) == size else np.full(size, np.nan) for r in self.rows["data"]]
        arrays = {k: np.asarray(v, dtype=float) for k, v in self.rows.items()}
        if vel is not None and all(v is not None for v in vel):
            arrays["velocity"] = np.asarray(vel, dtype=float)
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
        t = (stamps if stamps.any() else np.asarray(self.t, dtype=np.int64))[keep]
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
        return _Series(self.topic, self.full_type, t, self._convert(arrays))

    def _convert(self, a: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Rename fields to role-independent names in MuJoCo conventions."""
        kind = self.msgtype
        if kind == "sensor_msgs/JointState":
            out = {"q": a["position"]}
            if "velocity" in a:
                out["dq"] = a["velocity"]
            return out
        if kind in _LOWSTATE_TYPES:
            return {"q": a["motorState.q"], "dq": a["motorState.dq"]}
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


# --------------------------------------------------------------------------- #
# 5. Resampling
# --------------------------------------------------------------------------- #


def _bracket(t_msg: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left neighbour index (N_grid,) in [0, N-2] and fraction (N_grid,) in [0, 1]."""
    i = np.clip(np.searchsorted(t_msg, grid, side="right") - 1, 0, len(t_msg) - 2)
    u = (grid - t_msg[i]).astype(float) / (t_msg[i + 1] - t_msg[i]).astype(float)
    return i, u


def _lerp(x: np.ndarray, i: np.ndarray, u: np.ndarray) -> np.ndarray:
    return x[i] + u[:, None] * (x[i + 1] - x[i])


def _observed_interp(t_msg: np.ndarray, grid: np.ndarray, period: float) -> np.ndarray:
    """True where the grid time is a message time or lies between two close messages."""
    i = np.clip(np.searchsorted(t_msg, grid, side="right") - 1, 0, len(t_msg) - 1)
    nxt = np.minimum(i + 1, len(t_msg) - 1)
    at_msg = t_msg[i] == grid
    return at_msg | ((t_msg[nxt] - t_msg[i]) <= _GAP_FACTOR * period)


def _backward_diff(x: np.ndarray, dt: float) -> np.ndarray:
    """(T, k) -> (T, k): v[i] = (x[i] - x[i-1]) / dt, v[0] = v[1]."""
    v = np.empty_like(x)
    v[1:] = (x[1:] - x[:-1]) / dt
    v[0] = v[1] if len(x) > 1 else 0.0
    return v


def _backward_angvel(q: np.ndarray, dt: float) -> np.ndarray:
    """(T, 4) wxyz -> (T, 3) body angular velocity, omega[i] = 2 log(q[i-1]^-1 q[i]) / dt."""
    w = np.empty((len(q), 3))
    w[1:] = quat_to_rotvec(quat_mul(quat_conj(q[:-1]), q[1:])) / dt
    w[0] = w[1] if len(q) > 1 else 0.0
    return w


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #


def read_log(
    path: str | Path,
    *,
    topics: dict[str, str] | None = None,
    dt: float = 0.002,
    joint_names_map: dict[str, str] | None = None,
    smooth: int | str = "auto",
) -> Trajectory:
    """Read a log and resample it onto a uniform grid in MuJoCo conventions.

    Args:
        path: an MCAP file, a rosbag2 folder (sqlite3 or mcap storage, or its
            ``metadata.yaml``) or a ROS 1 ``.bag``.
        topics: role -> topic overriding automatic detection; roles
            ``joint_states``, ``base``, ``box``, ``joint_commands``, ``gains``.
        dt: grid spacing [s], e.g. the model timestep 0.002.
        joint_names_map: log joint name -> Go1 joint name, for names that
            automatic matching does not recognise.
        smooth: smoothing of base and box poses: ``"auto"`` (default) fits a
            zero-phase local quadratic (Savitzky–Golay) to a pose stream only
            where its noise shows (:mod:`~amhe_cli.io.smoothing`), with the
            window that brings differentiated velocity noise to ~2 cm/s; an
            int N > 1 forces an N-sample window on every pose; 0 turns it off.
            Logged velocities are kept as logged; velocities differentiated
            from smoothed poses come from the fit's slope.

    Time: a topic's header stamps are used when any of them is nonzero,
    otherwise its log (receive) times; the grid starts where the last required
    role starts and ends where the first one ends (a command holds for one
    median command period after its last message).

    Returns:
        A :class:`Trajectory` on ``t = t_start + k * dt`` (seconds from the
        first message of any required role). ``meta``
        holds ``path``, ``sha256``, ``format``, ``topics`` (role -> topic),
        ``metadata`` (MCAP metadata records), ``warnings``, ``t0_ns`` (absolute
        time of ``t = 0``), ``joint_names`` (role -> names as logged) and
        ``gains_source``. Each warning is also issued with ``warnings.warn``.

    Raises:
        AmheError: missing path, not a log, a required role missing or
            ambiguous, joints missing, too many non-finite values, roles that do
            not overlap in time, or invalid ``dt``/``smooth``.
    """
    if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
        raise AmheError(f"dt must be a positive number of seconds, got {dt!r}")
    dt_ns = int(round(dt * 1e9))
    if dt_ns < 1:
        raise AmheError(f"dt must be at least 1 ns, got {dt!r}")
    if smooth != "auto" and (not isinstance(smooth, (int, np.integer)) or smooth < 0):
        raise AmheError(f"smooth must be 'auto' or a non-negative number of samples, got {smooth!r}")

    with _open_log(path) as log:
        roles, problems = assign_roles(log.topics, topics)
        for role in REQUIRED_ROLES:
            if role in problems:
                raise AmheError(problems[role])
        warns = list(log.warnings)
        wanted = {t: r for r, t in roles.items()}
        raw: dict[str, list[tuple[int, Any]]] = {t: [] for t in wanted}
        for topic, log_ns, msg in log.iterate(set(wanted), True):
            raw[topic].append((log_ns, msg))
        series: dict[str, _Series] = {}
        names: dict[str, list[str]] = {}
        for role in (*REQUIRED_ROLES, GAINS_ROLE):
            if role not in roles:
                continue
            topic = roles[role]
            if role == GAINS_ROLE and topic == roles["joint_commands"]:
                continue  # LowCmd: gains come with the commands
            fallback = names.get("joint_states") if role == "joint_commands" else None
            unpacker = _Unpacker(role, topic, log.topics[topic], joint_names_map, warns, fallback)
            try:
                for log_ns, msg in raw[topic]:
                    unpacker.add(log_ns, msg)
            except (AttributeError, TypeError) as err:
                raise AmheError(
                    f"cannot unpack {log.topics[topic]} messages on '{topic}' for role '{role}': "
                    f"{_one_line(err)}"
                ) from None
            try:
                series[role] = unpacker.finish()
            except AmheError:
                if role == GAINS_ROLE:
                    warns.append(f"ignored gains topic '{topic}': it has no usable messages")
                    continue
                raise
            if unpacker.names is not None:
                names[role] = unpacker.names
            elif role == "joint_states":
                names[role] = list(GO1_JOINTS)  # Unitree LowState: motors in Go1 order
        del raw
        meta = {
            "path": str(log.path),
            "sha256": _sha256(log.path),
            "format": log.format,
            "topics": {r: t for r, t in roles.items() if r in series or r == GAINS_ROLE},
            "metadata": log.metadata,
            "warnings": warns,
            "joint_names": names,
        }

    for role in REQUIRED_ROLES:
        if len(series[role].t_ns) < 2:
            raise AmheError(
                f"topic '{series[role].topic}' for role '{role}' has {len(series[role].t_ns)} usable "
                f"message(s): expected at least 2"
            )
    traj = _resample(series, dt, dt_ns, smooth, meta)
    kp, kd, source = _gains(series, meta, warns, joint_names_map)
    traj.kp, traj.kd = kp, kd
    meta["gains_source"] = source
    if source is None or not source.startswith("topic"):
        meta["topics"].pop(GAINS_ROLE, None)
    for text in warns:
        warnings.warn(text, stacklevel=2)
    return traj


def _pose_windows(s: "_Series", dt: float, smooth: int | str) -> tuple[int, int, float, float]:
    """Grid windows (position, orientation) and noise levels [m, rad] of one pose stream."""
    if smooth != "auto":
        w = int(smooth) if smooth and smooth > 1 else 1
        return w, w, 0.0, 0.0
    period = max(s.period_ns() * 1e-9, dt)
    sig_p = float(noise_sigma(s.fields["pos"]).max())
    sig_r = float(noise_sigma(2.0 * quat_make_continuous(s.fields["quat"])[:, 1:]).max())
    # windows are chosen on the raw message rate, then expressed in grid samples
    wp = window_for(sig_p, period)
    wr = window_for(sig_r, period, target=0.2, clean=CLEAN_SIGMA_ROT)
    to_grid = period / dt
    return (int(round(wp * to_grid)) | 1 if wp > 1 else 1, int(round(wr * to_grid)) | 1 if wr > 1 else 1,
            sig_p, sig_r)


def _resample(series: dict[str, _Series], dt: float, dt_ns: int, smooth: int | str, meta: dict) -> Trajectory:
    """Put the required roles on one grid (see :func:`read_log`)."""
    cmd = series["joint_commands"]
    cmd_period = cmd.period_ns()
    start = max(int(series[r].t_ns[0]) for r in REQUIRED_ROLES)
    # A held command stays valid for one period after its last message.
    ends = [int(series[r].t_ns[-1]) for r in REQUIRED_ROLES if r != "joint_commands"]
    end = min(*ends, int(cmd.t_ns[-1] + cmd_period))
    t0 = min(int(series[r].t_ns[0]) for r in REQUIRED_ROLES)
    meta["t0_ns"] = t0
    if end - start < dt_ns:
        spans = "; ".join(
            f"{r} {(series[r].t_ns[0] - t0) * 1e-9:.3f}-{(series[r].t_ns[-1] - t0) * 1e-9:.3f} s"
            for r in REQUIRED_ROLES
        )
        raise AmheError(f"the log's roles overlap for less than one step dt={dt} s: {spans}")
    n = (end - start) // dt_ns + 1
    grid = start + dt_ns * np.arange(n, dtype=np.int64)
    out: dict[str, np.ndarray] = {}
    observed: dict[str, np.ndarray] = {}
    measured: dict[str, bool] = {}

    # Joint states.
    js = series["joint_states"]
    i, u = _bracket(js.t_ns, grid)
    out["joint_pos"] = _lerp(js.fields["q"], i, u)
    measured["joint_states"] = "dq" in js.fields
    out["joint_vel"] = _lerp(js.fields["dq"], i, u) if "dq" in js.fields else _backward_diff(out["joint_pos"], dt)
    observed["joint_states"] = _observed_interp(js.t_ns, grid, js.period_ns())

    # Free bodies.
    for role in ("base", "box"):
        s = series[role]
        i, u = _bracket(s.t_ns, grid)
        pos = _lerp(s.fields["pos"], i, u)
        quat = quat_slerp(s.fields["quat"][i], s.fields["quat"][i + 1], u)
        measured[role] = "linvel" in s.fields
        wp, wr, sig_p, sig_r = _pose_windows(s, dt, smooth)
        linvel = _backward_diff(pos, dt)
        if wp > 1:
            pos, linvel = savgol(pos, wp, dt)
        if wr > 1:
            quat = quat_normalize(savgol(quat_make_continuous(quat), wr, dt)[0])
        angvel = _backward_angvel(quat, dt)
        if measured[role]:
            linvel = _lerp(s.fields["linvel"], i, u)
            angvel = _lerp(s.fields["angvel"], i, u)
        if wp > 1 or wr > 1:
            meta.setdefault("smoothing", {})[role] = {"position_window": wp, "orientation_window": wr,
                                                     "position_noise_m": sig_p, "orientation_noise_rad": sig_r}
            what = "smoothed (--smooth)" if smooth != "auto" else \
                f"pose noise ~{sig_p * 1e3:.2g} mm / {sig_r * 1e3:.2g} mrad: smoothed"
            msg = f"{role} {what} over {wp * dt * 1e3:.0f} ms (position) / {wr * dt * 1e3:.0f} ms (orientation)"
            meta["warnings"].append(msg)  # issued with the others at the end of read_log
        out.update({f"{role}_pos": pos, f"{role}_quat": quat, f"{role}_linvel": linvel, f"{role}_angvel": angvel})
        observed[role] = _observed_interp(s.t_ns, grid, s.period_ns())

    # Commands: zero-order hold of the last command at or before each grid time.
    j = np.searchsorted(cmd.t_ns, grid, side="right") - 1
    out["ctrl"] = cmd.fields["q"][j]
    observed["joint_commands"] = (grid - cmd.t_ns[j]) <= _GAP_FACTOR * cmd_period
    measured["joint_commands"] = True

    t = (grid - t0).astype(float) * 1e-9
    return Trajectory(t=t, dt=dt, observed=observed, measured_velocity=measured, meta=meta, **out)


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


# --------------------------------------------------------------------------- #
# Inspection
# --------------------------------------------------------------------------- #


@dataclass
class TopicInfo:
    """What one topic of a log holds (times are log times, not header stamps)."""

    topic: str
    msgtype: str
    count: int
    rate_hz: float
    first_s: float
    last_s: float
    max_gap_s: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class LogInfo:
    """Summary of a log for ``amhe probe``.

    Attributes:
        path: the log read.
        format: ``mcap``, ``rosbag2/sqlite3``, ``rosbag2/mcap`` or ``ros1``.
        duration_s: last minus first message time [s].
        start_ns: log time of the first message [ns].
        message_count: messages in the log.
        topics: one :class:`TopicInfo` per topic, sorted by name.
        metadata: MCAP metadata records, name -> {key: value}.
        roles: role -> topic as :func:`read_log` would assign them.
        problems: role -> one-line reason, for required roles that cannot be assigned.
        warnings: e.g. truncation.
    """

    path: str
    format: str
    duration_s: float
    start_ns: int
    message_count: int
    topics: list[TopicInfo] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    roles: dict[str, str] = field(default_factory=dict)
    problems: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        """Plain dict (YAML/JSON friendly)."""
        d = dict(self.__dict__)
        d["topics"] = [t.to_dict() for t in self.topics]
        return d

    def __str__(self) -> str:
        role_of = {t: r for r, t in self.roles.items()}
        lines = [
            f"{self.path}: {self.format}, {self.message_count} messages, {self.duration_s:.3f} s",
            f"{'topic':<28} {'type':<36} {'count':>7} {'rate Hz':>8} {'max gap s':>9}  role",
        ]
        for t in self.topics:
            lines.append(
                f"{t.topic:<28} {t.msgtype:<36} {t.count:>7} {t.rate_hz:>8.1f} {t.max_gap_s:>9.4f}  "
                f"{role_of.get(t.topic, '')}"
            )
        for name, rec in self.metadata.items():
            lines.append(f"metadata {name}: " + ", ".join(f"{k}={v}" for k, v in rec.items()))
        lines += [f"problem: {p}" for p in self.problems.values()]
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def inspect_log(path: str | Path, *, topics: dict[str, str] | None = None) -> LogInfo:
    """Describe a log without decoding its messages.

    Args:
        path: as for :func:`read_log`.
        topics: explicit role choices, as for :func:`read_log`.

    Returns:
        A :class:`LogInfo`: per topic its type, message count, rate [Hz] (count
        - 1 over its time span), first/last time [s] from the log start and
        largest gap between consecutive messages [s]; the log's format,
        duration [s], MCAP metadata records, and the role assignment
        :func:`read_log` would use (with problems for missing/ambiguous roles).

    Raises:
        AmheError: missing path, not a log, or invalid explicit topic choices.
    """
    with _open_log(path) as log:
        times: dict[str, list[int]] = {t: [] for t in log.topics}
        for topic, log_ns, _ in log.iterate(set(log.topics), False):
            times[topic].append(log_ns)
        roles, problems = assign_roles(log.topics, topics)
        info_path, fmt, metadata, warns = str(log.path), log.format, log.metadata, list(log.warnings)
        type_of = dict(log.topics)
    arrays = {t: np.sort(np.asarray(v, dtype=np.int64)) for t, v in times.items()}
    nonempty = [a for a in arrays.values() if len(a)]
    start = int(min(a[0] for a in nonempty)) if nonempty else 0
    end = int(max(a[-1] for a in nonempty)) if nonempty else 0
    infos = []
    for topic in sorted(arrays):
        a = arrays[topic]
        span = (a[-1] - a[0]) * 1e-9 if len(a) > 1 else 0.0
        infos.append(
            TopicInfo(
                topic=topic,
                msgtype=type_of[topic],
                count=int(len(a)),
                rate_hz=float((len(a) - 1) / span) if span > 0 else 0.0,
                first_s=float((a[0] - start) * 1e-9) if len(a) else float("nan"),
                last_s=float((a[-1] - start) * 1e-9) if len(a) else float("nan"),
                max_gap_s=float(np.diff(a).max() * 1e-9) if len(a) > 1 else 0.0,
            )
        )
    return LogInfo(
        path=info_path, format=fmt, duration_s=(end - start) * 1e-9, start_ns=start,
        message_count=int(sum(len(a) for a in arrays.values())), topics=infos, metadata=metadata,
        roles=roles, problems=problems, warnings=warns,
    )


def read_float_arrays(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read a labelled ``std_msgs/Float64MultiArray`` topic (e.g. ``/amhe/estimate``).

    Args:
        path: a log, as for :func:`read_log`.
        topic: the topic to read.

    Returns:
        ``(t, values, labels)``: (N,) log times [s] (as stored, not re-zeroed),
        (N, K) values, and the K labels from ``layout.dim[0].label``
        (comma-separated; empty list when unlabelled).

    Raises:
        AmheError: the topic is missing, not a Float64MultiArray, or its
            messages do not all have the same length.
    """
    with _open_log(path) as log:
        if topic not in log.topics:
            raise AmheError(f"log has no topic '{topic}'; topics present: {_topics_present(log.topics)}")
        if _short_type(log.topics[topic]) != "std_msgs/Float64MultiArray":
            raise AmheError(f"topic '{topic}' has type {log.topics[topic]}: expected std_msgs/msg/Float64MultiArray")
        t, rows, labels = [], [], []
        for _, log_ns, msg in log.iterate({topic}, True):
            t.append(log_ns)
            rows.append(np.asarray(msg.data, dtype=float))
            if not labels and msg.layout.dim:
                labels = [s for s in msg.layout.dim[0].label.split(",") if s]
    if len({len(r) for r in rows}) > 1:
        raise AmheError(f"messages on '{topic}' differ in length: expected one fixed-size array")
    order = np.argsort(np.asarray(t, dtype=np.int64), kind="stable")
    values = np.asarray(rows, dtype=float).reshape(len(rows), -1)[order]
    return np.asarray(t, dtype=np.int64)[order] * 1e-9, values, labels
