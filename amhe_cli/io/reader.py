"""Read a recorded log (MCAP, rosbag2, ROS 1 bag) into a :class:`Trajectory`.

The pipeline, one step per module:

1. **open** the log (:mod:`~amhe_cli.io.logfile`);
2. **assign roles** to its topics (:mod:`~amhe_cli.io.roles`);
3. **unpack** the messages of each role into time-stamped arrays
   (:mod:`~amhe_cli.io.unpack`, joint names matched by :mod:`~amhe_cli.io.joints`);
4. **resample** onto a uniform grid covering the overlap of the roles, from its first joint-state message
   (:mod:`~amhe_cli.io.resample`).

:func:`inspect_log` runs only steps 1 and 2 on message timestamps (no
decoding) to describe a log for ``amhe probe``.

"""

from __future__ import annotations

import gc
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.trajectory import GO1_JOINTS, Trajectory

# the steps' modules (see the module docstring)
from amhe_cli.io.joints import canonical_joint_name, match_joints
from amhe_cli.io.logfile import _one_line, _open_log, _sha256
from amhe_cli.io.sensors import stream_report
from amhe_cli.io.resample import _resample
from amhe_cli.io.roles import GAINS_ROLE, REQUIRED_ROLES, _short_type, _topics_present, assign_roles
from amhe_cli.io.unpack import _gains, _Series, _Unpacker

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


# --------------------------------------------------------------------------- #
# Public API
# --------------------------------------------------------------------------- #


@contextmanager
def _collector_paused():
    """Python's cyclic garbage collector off while a log's messages are decoded and unpacked.

    A 20 s log decodes into some 10⁵ small objects, none of them in a reference cycle, and each
    collection walks all that are still held: measured on ``const_a`` (32 k messages), the collector
    was 40 % of :func:`read_log` (1.15 s with it, 0.69 s without). Turned back on afterwards (if it
    was on); reference counting frees everything as usual meanwhile.
    """
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


def read_log(
    path: str | Path,
    *,
    topics: dict[str, str] | None = None,
    dt: float = 0.002,
    joint_names_map: dict[str, str] | None = None,
    smooth: int | str = "auto",
    time_offset: dict[str, float] | None = None,
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
            window that brings differentiated velocity noise to ~5 cm/s; an
            int N > 1 forces an N-sample window on every pose; 0 turns it off.
            Logged velocities are kept as logged; velocities differentiated
            from smoothed poses come from the fit's slope.
        time_offset: role -> seconds added to that role's message times
            before resampling (e.g. the mocap-to-joint-state offset that
            :func:`~amhe_cli.estimation.sensors.mocap_offset` measured).

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
        ``gains_source`` and ``sensors``: ``{"streams": role -> rate, drops,
        jitter, latency, noise}`` (:func:`~amhe_cli.io.sensors.stream_report`)
        and ``time_offset_s`` (role -> applied shift). Each warning is also issued with ``warnings.warn``.

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

    with _open_log(path) as log, _collector_paused():
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
    _one_clock(series, warns)
    frames = {r: series[r].frames for r in ("base", "box")}
    if all(frames.values()) and set(frames["base"]) != set(frames["box"]):
        warns.append(f"the base pose is given in frame {'/'.join(frames['base'])} and the box pose in "
                     f"{'/'.join(frames['box'])}: amhe takes both in one world frame, so robot-box contact is "
                     "only right where these frames coincide (e.g. both from the motion capture)")
    meta["sensors"] = {"streams": {r: stream_report(series[r]) for r in REQUIRED_ROLES}}
    if time_offset:
        for role, shift in time_offset.items():
            if role in series and shift:
                series[role].t_ns = series[role].t_ns + int(round(shift * 1e9))
        meta["sensors"]["time_offset_s"] = {r: float(v) for r, v in time_offset.items()}
    traj = _resample(series, dt, dt_ns, smooth, meta)
    kp, kd, source = _gains(series, meta, warns, joint_names_map)
    traj.kp, traj.kd = kp, kd
    meta["gains_source"] = source
    if source is None or not source.startswith("topic"):
        meta["topics"].pop(GAINS_ROLE, None)
    for text in warns:
        warnings.warn(text, stacklevel=2)
    return traj


#: Header stamps this far [s] from their messages' log times, where the streams disagree by as much,
#: are on another clock (a robot's boot time beside the recorder's wall clock).
FOREIGN_CLOCK_S = 1.0


def _one_clock(series: dict, warns: list[str]) -> None:
    """Put every role's times on one clock, in place.

    Header stamps are the measurement times, but a stream may stamp with its
    own clock (the robot's time since boot beside the motion capture's wall
    clock). Where the roles' latencies (median log time − stamp) differ by
    more than :data:`FOREIGN_CLOCK_S`, each stream whose latency exceeds it
    is moved onto the log's clock by its median latency (its spacing kept),
    with a warning.
    """
    lat = {r: s.latency_ns or 0.0 for r, s in series.items() if r in REQUIRED_ROLES}
    if max(lat.values()) - min(lat.values()) <= FOREIGN_CLOCK_S * 1e9:
        return
    for role, latency in lat.items():
        if abs(latency) > FOREIGN_CLOCK_S * 1e9:
            s = series[role]
            s.t_ns, s.latency_ns = s.t_ns + int(round(latency)), None  # now on log times: no latency of its own
            warns.append(f"the header stamps on '{s.topic}' are {latency * 1e-9:+.6g} s off their log times, on "
                         "another clock than the other streams: moved onto the log's clock by that offset")


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
