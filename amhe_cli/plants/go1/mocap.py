"""Motion capture for the Go1 plant: trunk and box poses, checked before use.

The Go1's low-level state holds no base position or linear velocity
(docs/reference.md#go1-low-level-link), so the closed loop takes the trunk's and the box's poses from motion
capture (the public Go1 box-pushing setup streamed OptiTrack rigid bodies
``Go1_body`` and ``Box_body`` at 120 Hz). Two ways in, one interface:

* :class:`UdpPoseSource` listens for the project's own **pose stream**, one
  UTF-8 JSON object per UDP datagram (``docs/pose_stream.md``), which a ROS
  node, a script or the Go1 emulator (:class:`PoseSender`) feeds;
* :class:`MotionCaptureSource` reads a motion-capture system directly through
  ``motioncapture`` (libmotioncapture: OptiTrack, Vicon, Qualisys, VRPN, NOKOV
  and a mock), the optional ``mocap`` extra.

Both are :class:`PoseSource` objects: a reader thread keeps the latest
*accepted* :class:`PoseSample` per rigid body. Samples are never silently
used when they are wrong: undecodable or invalid data (non-finite numbers,
non-unit quaternions) is counted and reported, out-of-order stamps are dropped,
a position that jumps faster than ``max_speed`` is rejected and reported (and,
after :data:`REACQUIRE_AFTER` seconds of rejected samples consistent with each
other, accepted again as a re-acquisition), and :meth:`PoseSource.age` tells a
caller how stale the latest sample is. Reports are collected as one-line
messages, read with :meth:`PoseSource.take_warnings`.

Conventions: positions in metres in the world frame (REP-103: x forward, y
left, z up); quaternions inside ``amhe`` are MuJoCo order (w, x, y, z). The
pose stream carries ROS order (x, y, z, w) and is converted only through
:func:`amhe_cli.io.quat.ros_to_mj` / :func:`~amhe_cli.io.quat.mj_to_ros`.
"""

from __future__ import annotations

import json
import math
import select
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import mj_to_ros, quat_from_rotvec, quat_mul, ros_to_mj

#: Default UDP port of the pose stream (docs/pose_stream.md).
POSE_STREAM_PORT = 9870
#: Version number the pose stream's ``"v"`` field must carry.
POSE_STREAM_VERSION = 1
#: Position slack added to ``max_speed * Δstamp`` before a sample counts as a jump [m].
JUMP_SLACK = 0.02
#: Seconds (sender stamps) of mutually consistent rejected samples after which the new position is accepted.
REACQUIRE_AFTER = 0.5
#: A quaternion whose norm is within this of 1 is normalised; farther off, the sample is rejected.
QUAT_NORM_TOL = 0.01
#: At most this many pending warnings are kept; the rest are counted in one summary line.
MAX_WARNINGS = 100
#: Accepted samples kept per body for :meth:`PoseSource.since` (about 16 s at 120 Hz).
HISTORY = 2000
#: Backends of ``motioncapture`` that :func:`open_pose_source` accepts.
MOCAP_KINDS = ("optitrack", "vicon", "qualisys", "vrpn", "nokov", "mock")
#: Rate of the ``mock`` backend [Hz] (the public setup's OptiTrack rate).
MOCK_RATE_HZ = 120

_MOCAP_HINT = "install the mocap extra: pip install 'amhe[mocap]'"


class PoseStreamError(AmheError):
    """A pose-stream datagram (or one body entry of it) that cannot be used; the message says why."""


@dataclass(frozen=True)
class PoseSample:
    """One accepted pose of one rigid body.

    Attributes:
        name: rigid-body name, e.g. ``"Go1_body"``.
        pos: (3,) read-only position [m], world frame, REP-103 (x forward, y left, z up).
        quat: (4,) read-only unit quaternion (w, x, y, z), MuJoCo order, body to world.
        stamp: the sender's capture time [s] on the sender's own clock (for
            :class:`MotionCaptureSource`, ``time.monotonic()`` at arrival).
        received: ``time.monotonic()`` when the sample arrived [s].
        seq: how many samples of this body have been accepted, this one included (1, 2, ...).
    """

    name: str
    pos: np.ndarray
    quat: np.ndarray
    stamp: float
    received: float
    seq: int


def _vector(value, size: int, what: str) -> np.ndarray:
    """A finite float vector of ``size`` from a JSON list / array, or :class:`PoseStreamError`."""
    if isinstance(value, (str, bytes, dict)) or value is None:
        raise PoseStreamError(f"{what} must be a list of {size} numbers, got {type(value).__name__}")
    try:
        seq = list(value)
    except TypeError:
        raise PoseStreamError(f"{what} must be a list of {size} numbers, got {type(value).__name__}") from None
    if len(seq) != size or any(isinstance(v, bool) or not isinstance(v, (int, float, np.number)) for v in seq):
        raise PoseStreamError(f"{what} must be a list of {size} numbers, got {value!r:.80}")
    arr = np.asarray(seq, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise PoseStreamError(f"{what} has non-finite numbers: {arr.tolist()}")
    return arr


def _unit_quat(q_wxyz: np.ndarray, what: str) -> np.ndarray:
    """Normalise a near-unit (w, x, y, z) quaternion; :class:`PoseStreamError` if its norm is off by more than :data:`QUAT_NORM_TOL`."""
    norm = float(np.linalg.norm(q_wxyz))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise PoseStreamError(f"{what} is not a unit quaternion (norm {norm:.4g}, expected 1 ± {QUAT_NORM_TOL})")
    return q_wxyz / norm


def _pose_arrays(poses, name) -> tuple[np.ndarray, np.ndarray]:
    """(pos (3,), quat (4,)) float arrays of ``poses[name]``; AmheError naming the body when malformed."""
    if not isinstance(name, str) or not name:
        raise AmheError(f"rigid-body name must be a non-empty string, got {name!r}")
    pose = poses[name]
    try:
        pos, quat = pose
    except (TypeError, ValueError):
        raise AmheError(f"pose of {name} must be (pos (3,), quat (4,) w,x,y,z), got {pose!r:.80}") from None
    pos, quat = np.array(pos, dtype=float), np.array(quat, dtype=float)
    if pos.shape != (3,) or quat.shape != (4,):
        raise AmheError(f"pose of {name}: expected pos (3,) and quat (4,), got {pos.shape} and {quat.shape}")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
        raise AmheError(f"pose of {name} has non-finite values: pos {pos.tolist()}, quat {quat.tolist()}")
    return pos, quat


def _check_poses(poses) -> None:
    if not isinstance(poses, dict):
        raise AmheError(f"poses must be a dict name -> (pos (3,), quat (4,) w,x,y,z), got {type(poses).__name__}")


def encode_pose_datagram(poses: dict, stamp: float) -> bytes:
    """Pack poses into one pose-stream datagram (docs/pose_stream.md, version 1).

    Args:
        poses: rigid-body name -> ``(pos, quat)``: pos (3,) [m, world, REP-103],
            quat (4,) (w, x, y, z) MuJoCo order; written as ``quat_xyzw`` (ROS order).
        stamp: capture time [s] on the sender's clock, written as ``"t"``.

    Returns:
        Compact UTF-8 JSON, e.g. ``{"v":1,"t":12.5,"bodies":{"Go1_body":{"pos":[..],"quat_xyzw":[..]}}}``.

    Raises:
        AmheError: a non-string/empty name, a pos or quat of the wrong shape or
            with non-finite values, or a non-finite stamp.
    """
    if not isinstance(stamp, (int, float, np.number)) or isinstance(stamp, bool) or not math.isfinite(stamp):
        raise AmheError(f"pose stamp must be a finite number of seconds, got {stamp!r}")
    _check_poses(poses)
    bodies = {}
    for name in poses:
        pos, quat = _pose_arrays(poses, name)
        bodies[name] = {"pos": [float(v) for v in pos], "quat_xyzw": [float(v) for v in mj_to_ros(quat)]}
    obj = {"v": POSE_STREAM_VERSION, "t": float(stamp), "bodies": bodies}
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode("utf-8")


def decode_pose_datagram(data: bytes) -> tuple[float, dict]:
    """Unpack the envelope of one pose-stream datagram (docs/pose_stream.md, version 1).

    Body entries are returned as sent (checked one by one with
    :func:`decode_body_entry`), so that one bad body does not discard the others.

    Args:
        data: the datagram's payload.

    Returns:
        ``(stamp [s], {name: entry})`` with the raw JSON entry of each body.

    Raises:
        PoseStreamError: not UTF-8 JSON, not an object, ``"v"`` other than 1,
            ``"t"`` missing or not a finite number, ``"bodies"`` missing or not an object.
    """
    try:
        obj = json.loads(bytes(data).decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise PoseStreamError(f"datagram is not UTF-8 JSON ({type(exc).__name__}: {str(exc)[:60]})") from None
    if not isinstance(obj, dict):
        raise PoseStreamError(f"datagram must be a JSON object, got {type(obj).__name__}")
    version = obj.get("v")
    if isinstance(version, bool) or version != POSE_STREAM_VERSION:
        raise PoseStreamError(f"datagram has version {version!r}, expected \"v\": {POSE_STREAM_VERSION}")
    stamp = obj.get("t")
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float)) or not math.isfinite(stamp):
        raise PoseStreamError(f"datagram needs \"t\": a finite capture time in seconds, got {stamp!r}")
    bodies = obj.get("bodies")
    if not isinstance(bodies, dict):
        raise PoseStreamError(f"datagram needs \"bodies\": an object name -> pose, got {type(bodies).__name__}")
    return float(stamp), bodies


def decode_body_entry(name: str, entry) -> tuple[np.ndarray, np.ndarray]:
    """Check one body entry of a pose-stream datagram and convert its quaternion.

    Args:
        name: the body's name (for messages).
        entry: ``{"pos": [x, y, z], "quat_xyzw": [x, y, z, w]}``.

    Returns:
        ``(pos (3,) [m], quat (4,) unit, (w, x, y, z))``; a near-unit quaternion
        (norm within :data:`QUAT_NORM_TOL` of 1) is normalised.

    Raises:
        PoseStreamError: not an object, a field missing, wrong lengths,
            non-finite numbers, or a quaternion far from unit norm.
    """
    if not isinstance(entry, dict):
        raise PoseStreamError(f"{name}: entry must be an object with \"pos\" and \"quat_xyzw\", got {type(entry).__name__}")
    for key in ("pos", "quat_xyzw"):
        if key not in entry:
            raise PoseStreamError(f"{name}: entry has no \"{key}\" field")
    pos = _vector(entry["pos"], 3, f"{name}: \"pos\"")
    quat = _unit_quat(ros_to_mj(_vector(entry["quat_xyzw"], 4, f"{name}: \"quat_xyzw\"")), f"{name}: \"quat_xyzw\"")
    return pos, quat


class _Track:
    """Per-body bookkeeping of :class:`PoseSource` (last accepted sample, current run of rejections)."""

    __slots__ = ("last_stamp", "acc_pos", "acc_stamp", "run_start", "run_pos", "run_stamp", "run_count", "run_jump")

    def __init__(self):
        self.last_stamp = -math.inf      # newest stamp seen (accepted or rejected as a jump)
        self.acc_pos = None              # (3,) position of the last accepted sample
        self.acc_stamp = -math.inf
        self.run_start = None            # stamp of the first rejected sample of the current run
        self.run_pos = None
        self.run_stamp = None
        self.run_count = 0
        self.run_jump = 0.0


def _new_stats() -> dict:
    return {"received": 0, "accepted": 0, "rejected_jumps": 0, "bad": 0, "out_of_order": 0, "reacquired": 0}


class PoseSource:
    """Latest accepted pose per rigid body, filled by a reader thread (abstract).

    Subclasses open their input in ``__init__`` (so that errors show at once)
    and implement :meth:`_run` (the reader loop, which returns when
    ``self._stop`` is set) and :meth:`_close_input`. They hand each decoded
    sample to :meth:`_ingest`, which applies the checks below.

    Checks, per body, on the sender's stamps:

    * out of order: a stamp not newer than the newest seen is dropped
      (``stats[name]["out_of_order"]``);
    * jump: a position farther than ``max_speed * Δstamp + JUMP_SLACK`` [m]
      from the last accepted one is rejected (``"rejected_jumps"``) and
      reported; once rejected samples consistent with each other (same bound,
      sample to sample) have spanned :data:`REACQUIRE_AFTER` seconds, the new
      position is accepted as a re-acquisition (``"reacquired"``) and reported;
    * bad: a body entry with missing fields, non-finite numbers or a
      non-unit quaternion (``"bad"``); an undecodable datagram is counted
      under the key ``"_bad"`` (``stats["_bad"]["bad"]``).

    Args:
        bodies: rigid-body names to keep; ``None`` keeps every body seen.
            Other names are ignored (reported once each).
        max_speed: fastest believable speed of a body [m/s], > 0.

    Raises:
        AmheError: ``max_speed`` not a positive finite number, or ``bodies``
            not a tuple of non-empty strings.
    """

    def __init__(self, bodies: tuple[str, ...] | None = None, max_speed: float = 5.0):
        if isinstance(max_speed, bool) or not isinstance(max_speed, (int, float)) \
                or not math.isfinite(max_speed) or max_speed <= 0:
            raise AmheError(f"max_speed must be a positive number of m/s, got {max_speed!r}")
        if bodies is not None:
            if isinstance(bodies, str) or not all(isinstance(b, str) and b for b in bodies):
                raise AmheError(f"bodies must be a tuple of rigid-body names, got {bodies!r}")
            bodies = tuple(bodies)
        self.bodies = bodies
        self.max_speed = float(max_speed)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._latest: dict[str, PoseSample] = {}
        self._history: dict[str, deque[PoseSample]] = {}
        self._tracks: dict[str, _Track] = {}
        self._stats: dict[str, dict] = {"_bad": _new_stats()}
        for name in bodies or ():
            self._stats[name] = _new_stats()
        self._warnings: list[str] = []
        self._dropped_warnings = 0
        self._unknown: set[str] = set()
        self._closed = False

    # --- public interface ---------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (a second call does nothing).

        Raises:
            AmheError: the source was closed.
        """
        if self._closed:
            raise AmheError(f"{type(self).__name__} is closed: open a new one")
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"amhe-{type(self).__name__}", daemon=True)
            self._thread.start()

    def latest(self, name: str) -> PoseSample | None:
        """The latest accepted sample of rigid body ``name``, or ``None`` if none has been accepted.

        Raises:
            AmheError: ``name`` is not one of the ``bodies`` this source was opened for.
        """
        self._check_name(name)
        with self._lock:
            return self._latest.get(name)

    def since(self, name: str, seq: int) -> list[PoseSample]:
        """The accepted samples of rigid body ``name`` after the one numbered ``seq`` (its ``seq``; 0: from the
        first), oldest first: the last :data:`HISTORY` of them at most. A reader that lags behind the stream (the
        relay's ticks taken late after a stall of its process) takes every pose it missed, at its arrival.

        Raises:
            AmheError: ``name`` is not one of the ``bodies`` this source was opened for.
        """
        self._check_name(name)
        with self._lock:
            kept = self._history.get(name)
            if not kept or kept[-1].seq <= seq:
                return []
            out = []
            for sample in reversed(kept):
                if sample.seq <= seq:
                    break
                out.append(sample)
        return out[::-1]

    def age(self, name: str, now: float | None = None) -> float:
        """Seconds since the latest accepted sample of ``name`` arrived (its ``received``).

        Args:
            name: rigid-body name.
            now: ``time.monotonic()`` reading to measure against [s]; default: now.

        Returns:
            Age [s]; ``inf`` if no sample has been accepted.

        Raises:
            AmheError: ``name`` is not one of the ``bodies`` this source was opened for.
        """
        sample = self.latest(name)
        if sample is None:
            return math.inf
        return (time.monotonic() if now is None else float(now)) - sample.received

    def unread(self) -> bool:
        """True where poses have arrived that the reader thread has not yet read: this process, not the stream,
        is behind (after a stall, the GIL elsewhere). A source that cannot tell (a library's blocking read)
        says False; the caller then judges the stream by :meth:`latest` alone."""
        return False

    def wait(self, names: tuple[str, ...] | None = None, timeout: float = 2.0) -> dict[str, PoseSample]:
        """Block until every body in ``names`` (default: ``bodies``) has an accepted sample.

        Returns:
            name -> latest :class:`PoseSample`.

        Raises:
            AmheError: ``timeout`` [s] passed first; the message names the
                missing bodies and what was received.
        """
        names = tuple(names if names is not None else (self.bodies or ()))
        deadline = time.monotonic() + timeout
        while True:
            got = {n: self.latest(n) for n in names}
            missing = [n for n, s in got.items() if s is None]
            if not missing:
                return got
            if time.monotonic() >= deadline:
                stats = self.stats
                seen = sorted(k for k, v in stats.items() if k != "_bad" and v["received"])
                raise AmheError(f"no pose of {', '.join(missing)} from {self.describe()} within {timeout:g} s "
                                f"(bodies received: {', '.join(seen) or 'none'}; "
                                f"undecodable datagrams: {stats['_bad']['bad']})")
            time.sleep(0.005)

    @property
    def stats(self) -> dict:
        """Snapshot of the counters: name -> {received, accepted, rejected_jumps, bad, out_of_order, reacquired}.

        ``received`` counts every entry of that body that arrived; ``"_bad"``
        holds the same keys for datagrams that could not be decoded at all
        (``stats["_bad"]["bad"]``; ``stats["_bad"]["received"]`` counts every datagram).
        """
        with self._lock:
            return {k: dict(v) for k, v in self._stats.items()}

    def take_warnings(self) -> list[str]:
        """One-line messages about rejected jumps, re-acquisitions and bad data since the last call."""
        with self._lock:
            out = self._warnings
            if self._dropped_warnings:
                out.append(f"{self._dropped_warnings} further pose warnings dropped (more than {MAX_WARNINGS} pending)")
            self._warnings = []
            self._dropped_warnings = 0
        return out

    def describe(self) -> str:
        """Where the poses come from, for messages."""
        return type(self).__name__

    def close(self) -> None:
        """Stop the reader thread and release the input (safe to call twice)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self._close_input()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    # --- for subclasses -----------------------------------------------------------

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _close_input(self) -> None:
        pass

    def _check_name(self, name: str) -> None:
        if self.bodies is not None and name not in self.bodies:
            raise AmheError(f"unknown rigid body {name!r}: this pose source tracks {', '.join(self.bodies)}")

    def _warn(self, message: str) -> None:
        """Queue a warning (caller holds the lock)."""
        if len(self._warnings) < MAX_WARNINGS:
            self._warnings.append(message)
        else:
            self._dropped_warnings += 1

    def _count_bad_datagram(self, reason: str) -> None:
        with self._lock:
            self._stats["_bad"]["bad"] += 1
            self._warn(f"bad pose datagram from {self.describe()}: {reason}")

    def _wanted(self, name: str) -> bool:
        """Whether ``name`` is tracked; reports an unexpected name once (caller holds the lock)."""
        if self.bodies is None or name in self.bodies:
            if name not in self._stats:
                self._stats[name] = _new_stats()
            return True
        if name not in self._unknown and len(self._unknown) < 50:
            self._unknown.add(name)
            self._warn(f"{self.describe()} carries rigid body {name!r}, not tracked "
                       f"(expected {', '.join(self.bodies)}): ignored")
        return False

    def _ingest_entry(self, name: str, entry, stamp: float, received: float) -> None:
        """Decode one pose-stream body entry and pass it to :meth:`_ingest` (bad entries counted)."""
        with self._lock:
            if not self._wanted(name):
                return
        try:
            pos, quat = decode_body_entry(name, entry)
        except PoseStreamError as exc:
            with self._lock:
                self._stats[name]["received"] += 1
                self._stats[name]["bad"] += 1
                self._warn(f"bad pose of {exc}")
            return
        self._ingest(name, pos, quat, stamp, received)

    def _ingest(self, name: str, pos: np.ndarray, quat_wxyz: np.ndarray, stamp: float, received: float) -> None:
        """Apply the out-of-order and jump checks to one decoded sample and keep it if accepted.

        Args:
            name: rigid-body name.
            pos: (3,) finite position [m].
            quat_wxyz: (4,) finite quaternion (w, x, y, z); normalised here if near unit.
            stamp: sender capture time [s].
            received: ``time.monotonic()`` at arrival [s].
        """
        with self._lock:
            if not self._wanted(name):
                return
            st = self._stats[name]
            st["received"] += 1
            pos = np.array(pos, dtype=float)
            quat = np.array(quat_wxyz, dtype=float)
            if pos.shape != (3,) or quat.shape != (4,) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
                st["bad"] += 1
                self._warn(f"bad pose of {name}: non-finite or misshapen pos {pos.tolist()} / quat {quat.tolist()}")
                return
            try:
                quat = _unit_quat(quat, f"{name}: quaternion")
            except PoseStreamError as exc:
                st["bad"] += 1
                self._warn(f"bad pose of {exc}")
                return
            tr = self._tracks.setdefault(name, _Track())
            if not stamp > tr.last_stamp:
                st["out_of_order"] += 1
                return
            tr.last_stamp = stamp
            reacquired = False
            if tr.acc_pos is not None:
                dist = float(np.linalg.norm(pos - tr.acc_pos))
                dt = stamp - tr.acc_stamp
                limit = self.max_speed * dt + JUMP_SLACK
                if dist > limit:
                    consistent = tr.run_start is not None and float(np.linalg.norm(pos - tr.run_pos)) \
                        <= self.max_speed * (stamp - tr.run_stamp) + JUMP_SLACK
                    if not consistent:
                        if tr.run_start is not None and tr.run_count > 1:
                            self._warn(f"{name}: {tr.run_count} samples rejected over "
                                       f"{tr.run_stamp - tr.run_start:.3f} s ended by another jump")
                        tr.run_start, tr.run_count = stamp, 0
                        self._warn(f"{name}: pose jump rejected: moved {dist:.3f} m in {dt * 1e3:.1f} ms since the "
                                   f"last accepted sample (limit {limit:.3f} m = {self.max_speed:g} m/s x dt "
                                   f"+ {JUMP_SLACK} m)")
                    tr.run_pos, tr.run_stamp = pos, stamp
                    tr.run_count += 1
                    tr.run_jump = float(np.linalg.norm(pos - tr.acc_pos))
                    if stamp - tr.run_start < REACQUIRE_AFTER - 1e-9:
                        st["rejected_jumps"] += 1
                        return
                    reacquired = True
                    st["reacquired"] += 1
                    self._warn(f"{name}: re-acquired at ({pos[0]:.3f}, {pos[1]:.3f}, {pos[2]:.3f}) m after "
                               f"{stamp - tr.run_start:.3f} s of {tr.run_count - 1} consistent rejected samples "
                               f"({tr.run_jump:.3f} m from the last accepted pose): new position accepted")
            if tr.run_start is not None and not reacquired and tr.run_count > 1:
                self._warn(f"{name}: {tr.run_count} samples rejected over {tr.run_stamp - tr.run_start:.3f} s, "
                           f"then one within the speed bound accepted ({dist:.3f} m from the last accepted pose)")
            tr.run_start, tr.run_pos, tr.run_stamp, tr.run_count = None, None, None, 0
            tr.acc_pos, tr.acc_stamp = pos, stamp
            st["accepted"] += 1
            pos.setflags(write=False)
            quat.setflags(write=False)
            sample = PoseSample(name=name, pos=pos, quat=quat, stamp=float(stamp), received=float(received),
                                seq=st["accepted"])
            self._latest[name] = sample
            self._history.setdefault(name, deque(maxlen=HISTORY)).append(sample)


class UdpPoseSource(PoseSource):
    """Listens for the project's pose stream: one JSON datagram per capture (docs/pose_stream.md).

    The socket is bound at construction; :meth:`start` starts the reader thread.

    Args:
        port: UDP port to listen on (0: an ephemeral port, see :attr:`address`);
            the stream's default is :data:`POSE_STREAM_PORT`.
        host: local address to bind (``"0.0.0.0"``: every interface; ``"127.0.0.1"``: loopback only).
        bodies: rigid-body names to keep (``None``: all).
        max_speed: fastest believable body speed [m/s] for jump detection.

    Raises:
        AmheError: a bad port, or the address cannot be bound (in use, not local).
    """

    def __init__(self, port: int, host: str = "0.0.0.0", bodies: tuple[str, ...] | None = None,
                 max_speed: float = 5.0):
        super().__init__(bodies, max_speed)
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise AmheError(f"pose stream port must be an integer 0..65535, got {port!r}")
        if not isinstance(host, str) or not host:
            raise AmheError(f"pose stream host must be a local address such as 0.0.0.0, got {host!r}")
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, port))
        except (OSError, OverflowError) as exc:
            self._sock.close()
            self._closed = True
            raise AmheError(f"cannot listen for the pose stream on {host}:{port}: {exc}") from None
        self._sock.settimeout(0.05)
        self._address = self._sock.getsockname()[:2]

    @property
    def address(self) -> tuple[str, int]:
        """``(host, port)`` actually bound (the real port when 0 was asked for)."""
        return self._address

    def describe(self) -> str:
        return f"pose stream udp:{self._address[0]}:{self._address[1]}"

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, _ = self._sock.recvfrom(65535)
            except socket.timeout:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                time.sleep(0.01)
                continue
            self.handle_datagram(data, time.monotonic())

    def unread(self) -> bool:
        """True where a datagram waits at the socket, unread (``select`` with no wait; False once closed)."""
        try:
            return bool(select.select([self._sock], [], [], 0)[0])
        except (OSError, ValueError):  # closed meanwhile
            return False

    def handle_datagram(self, data: bytes, received: float) -> None:
        """Decode one datagram and ingest its bodies (the reader thread's step; public for replay tools).

        Args:
            data: the datagram's payload.
            received: ``time.monotonic()`` at arrival [s].
        """
        with self._lock:
            self._stats["_bad"]["received"] += 1
        try:
            stamp, bodies = decode_pose_datagram(data)
        except PoseStreamError as exc:
            self._count_bad_datagram(str(exc))
            return
        for name, entry in bodies.items():
            self._ingest_entry(name, entry, stamp, received)

    def _close_input(self) -> None:
        self._sock.close()


class MotionCaptureSource(PoseSource):
    """Reads rigid bodies straight from a motion-capture system through ``motioncapture``.

    ``motioncapture`` (libmotioncapture, the optional ``mocap`` extra) connects
    at construction; the reader thread calls ``waitForNextFrame()`` and takes
    every rigid body of the frame: ``position`` (3,) [m] and ``rotation`` read
    by component name (``.w, .x, .y, .z``) into (w, x, y, z). The library's
    Python API gives no capture time, so ``stamp`` is ``time.monotonic()`` at
    arrival. Configure the system to stream **z up** in metres: no axis
    conversion is made here.

    Args:
        kind: one of :data:`MOCAP_KINDS` (``"optitrack"``, ``"vicon"``, ...,
            ``"mock"``).
        host: the system's server address (``{"hostname": host}``). For
            ``"mock"`` (no network), libmotioncapture's static rigid bodies
            ``"NAME(x,y,z,qw,qx,qy,qz);..."``; empty: each of ``bodies`` at the
            origin, unrotated.
        bodies: rigid-body names to keep (``None``: all).
        max_speed: fastest believable body speed [m/s] for jump detection.
        options: further libmotioncapture settings (string -> string), e.g.
            ``{"port": "22223"}`` for Qualisys; the mock's ``frequency`` defaults
            to :data:`MOCK_RATE_HZ`.

    Raises:
        AmheError: an unknown kind, ``motioncapture`` not installed
            ("install the mocap extra ..."), or the connection failing.
    """

    def __init__(self, kind: str, host: str, bodies: tuple[str, ...] | None = None, max_speed: float = 5.0,
                 options: dict[str, str] | None = None):
        super().__init__(bodies, max_speed)
        if kind not in MOCAP_KINDS:
            self._closed = True
            raise AmheError(f"unknown motion capture kind {kind!r}: expected one of {', '.join(MOCAP_KINDS)}")
        if not isinstance(host, str) or (kind != "mock" and not host):
            self._closed = True
            raise AmheError(f"{kind} motion capture needs a host (the server's address), got {host!r}")
        mc_module = _import_motioncapture()
        self.kind, self.host = kind, host
        cfg = {"hostname": host}
        if kind == "mock":
            cfg = {"frequency": str(MOCK_RATE_HZ),
                   "rigid_bodies": host or ";".join(f"{b}(0,0,0,1,0,0,0)" for b in bodies or ())}
        cfg.update({str(k): str(v) for k, v in (options or {}).items()})
        try:
            self._mc = mc_module.connect(kind, cfg)
        except Exception as exc:  # the library raises RuntimeError (and others) from C++
            self._closed = True
            raise AmheError(f"cannot connect to {kind} motion capture at {host or 'mock'}: {exc}") from None

    def describe(self) -> str:
        return f"{self.kind} motion capture" + (f" at {self.host}" if self.kind != "mock" else "")

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._mc.waitForNextFrame()
                received = time.monotonic()
                bodies = self._mc.rigidBodies
            except Exception as exc:
                if self._stop.is_set():
                    return
                self._count_bad_datagram(f"{type(exc).__name__}: {exc}")
                time.sleep(0.1)
                continue
            if self._stop.is_set():
                return
            for name, rb in bodies.items():
                rot = rb.rotation
                # Explicit, by component name: (w, x, y, z) is MuJoCo order already.
                quat = np.array([rot.w, rot.x, rot.y, rot.z], dtype=float)
                self._ingest(str(name), np.asarray(rb.position, dtype=float), quat, received, received)


def _import_motioncapture():
    """Import ``motioncapture`` or raise :class:`AmheError` with the install hint."""
    try:
        import motioncapture
    except ImportError:
        raise AmheError(f"the motioncapture module is missing: {_MOCAP_HINT}") from None
    return motioncapture


class PoseSender:
    """Sends the pose stream (docs/pose_stream.md) to one UDP address: the Go1 emulator's and users' side.

    Datagrams wait in a queue until ``latency`` has passed; :meth:`send` and
    :meth:`flush` send those that are due, so delivery happens at the caller's
    next call after the latency. Send errors (nobody listening) are counted in
    :attr:`errors`, not raised: a mocap feed must not stop for a missing reader.

    Args:
        target: ``(host, port)`` of the :class:`UdpPoseSource`.
        latency: delay from :meth:`send` to delivery [s], >= 0.
        noise_pos: Gaussian σ added to each position component [m], >= 0.
        noise_rot: Gaussian σ of each component of a rotation vector applied
            to the orientation [rad], >= 0.
        seed: seed of the noise generator (numpy ``default_rng``).

    Raises:
        AmheError: a malformed target or a negative/non-finite setting.
    """

    def __init__(self, target: tuple[str, int], latency: float = 0.0, noise_pos: float = 0.0,
                 noise_rot: float = 0.0, seed: int = 0):
        try:
            host, port = target
        except (TypeError, ValueError):
            raise AmheError(f"pose sender target must be (host, port), got {target!r}") from None
        if not isinstance(host, str) or not host or isinstance(port, bool) or not isinstance(port, int) \
                or not 1 <= port <= 65535:
            raise AmheError(f"pose sender target must be (host, port 1..65535), got {target!r}")
        for what, value in (("latency", latency), ("noise_pos", noise_pos), ("noise_rot", noise_rot)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise AmheError(f"pose sender {what} must be a finite number >= 0, got {value!r}")
        self.target = (host, port)
        self.latency = float(latency)
        self.noise_pos = float(noise_pos)
        self.noise_rot = float(noise_rot)
        self._rng = np.random.default_rng(seed)
        self._queue: deque[tuple[float, bytes]] = deque()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0
        self.errors = 0
        self.last_error: str | None = None

    def send(self, poses: dict[str, tuple[np.ndarray, np.ndarray]], stamp: float) -> None:
        """Queue one datagram of poses captured at ``stamp`` and send what is due.

        Args:
            poses: name -> ``(pos (3,) [m], quat (4,) (w, x, y, z))``; noise is
                added here (the quaternion is renormalised).
            stamp: capture time [s] on the sender's clock (the datagram's ``"t"``).

        Raises:
            AmheError: malformed poses or stamp (see :func:`encode_pose_datagram`), or a closed sender.
        """
        if self._sock.fileno() < 0:
            raise AmheError("PoseSender is closed")
        _check_poses(poses)
        noisy = {}
        for name in poses:
            pos, quat = _pose_arrays(poses, name)
            if self.noise_pos > 0:
                pos = pos + self._rng.normal(0.0, self.noise_pos, 3)
            if self.noise_rot > 0:
                quat = quat_mul(quat, quat_from_rotvec(self._rng.normal(0.0, self.noise_rot, 3)))
                quat = quat / np.linalg.norm(quat)
            noisy[name] = (pos, quat)
        data = encode_pose_datagram(noisy, stamp)
        self._queue.append((time.monotonic() + self.latency, data))
        self.flush()

    def flush(self, now: float | None = None) -> None:
        """Send every queued datagram whose delivery time has come.

        Args:
            now: ``time.monotonic()`` reading [s]; default: now.
        """
        now = time.monotonic() if now is None else float(now)
        while self._queue and self._queue[0][0] <= now:
            _, data = self._queue.popleft()
            try:
                self._sock.sendto(data, self.target)
                self.sent += 1
            except OSError as exc:
                self.errors += 1
                self.last_error = str(exc)

    @property
    def pending(self) -> int:
        """Datagrams queued but not yet due."""
        return len(self._queue)

    def close(self) -> None:
        """Close the socket; queued datagrams are discarded."""
        self._queue.clear()
        self._sock.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def parse_pose_spec(spec: str) -> tuple[str, str, int | None]:
    """Parse a pose-source spec without opening anything.

    Args:
        spec: ``"udp:PORT"``, ``"udp:HOST:PORT"``, ``"KIND:HOST"`` with KIND in
            ``optitrack, vicon, qualisys, vrpn, nokov``, ``"mock"`` or
            ``"mock:NAME(x,y,z,qw,qx,qy,qz);..."``.

    Returns:
        ``(kind, host, port)``: kind ``"udp"`` (host defaults to ``"0.0.0.0"``)
        or a :data:`MOCAP_KINDS` entry (port ``None``).

    Raises:
        AmheError: a one-line message naming the bad spec and the accepted forms.
    """
    forms = f"udp:PORT, udp:HOST:PORT, {', '.join(k + ':HOST' for k in MOCAP_KINDS if k != 'mock')} or mock"
    if not isinstance(spec, str) or not spec.strip():
        raise AmheError(f"empty pose source: expected {forms}")
    spec = spec.strip()
    kind, _, rest = spec.partition(":")
    kind = kind.lower()
    if kind == "udp":
        host, sep, port_text = rest.rpartition(":")
        host = host if sep else "0.0.0.0"
        try:
            port = int(port_text)
        except ValueError:
            port = -1
        if not 0 <= port <= 65535 or not host or ":" in host:
            raise AmheError(f"bad pose source {spec!r}: expected udp:PORT or udp:HOST:PORT "
                            f"with PORT 0..65535 (the stream's default is {POSE_STREAM_PORT})")
        return "udp", host, port
    if kind == "mock":
        return "mock", rest, None
    if kind in MOCAP_KINDS:
        if not rest:
            raise AmheError(f"bad pose source {spec!r}: {kind} needs the server's address, {kind}:HOST")
        return kind, rest, None
    raise AmheError(f"unknown pose source {spec!r}: expected {forms}")


def open_pose_source(spec: str, bodies: tuple[str, ...], max_speed: float = 5.0) -> PoseSource:
    """Open and start the pose source a spec names (see :func:`parse_pose_spec`).

    ``"udp:9870"`` / ``"udp:HOST:9870"`` give a :class:`UdpPoseSource`; the
    ``motioncapture`` kinds give a :class:`MotionCaptureSource`. The returned
    source is already started (``start()`` again does nothing); close it, or
    use it in a ``with`` block.

    Args:
        spec: the source, e.g. ``"udp:9870"`` or ``"optitrack:HOST"``.
        bodies: rigid-body names to track, e.g. ``("Go1_body", "Box_body")``.
        max_speed: fastest believable body speed [m/s].

    Raises:
        AmheError: a bad spec, a port that cannot be bound, ``motioncapture``
            missing ("install the mocap extra: pip install 'amhe[mocap]'"), or
            a failed connection.
    """
    kind, host, port = parse_pose_spec(spec)
    if kind == "udp":
        source: PoseSource = UdpPoseSource(port, host=host, bodies=bodies, max_speed=max_speed)
    else:
        source = MotionCaptureSource(kind, host, bodies=bodies, max_speed=max_speed)
    source.start()
    return source
