"""A Go1 on 127.0.0.1: the project's sim plant behind the Go1 low-level UDP protocol.

:class:`Go1Emulator` steps a :class:`~amhe_cli.plants.sim.SimPlant` in real time
at its 2 ms step and speaks the robot's side of the legged_sdk 3.8 low-level
link (docs/reference.md#go1-low-level-link): a UDP socket bound on ``(host, port)`` (the robot's is
192.168.123.10:8007) takes 614-byte ``LowCmd`` packets and answers the sender
of the last valid one with an 807-byte ``LowState`` every tick (500 Hz; the
real robot streams up to 1 kHz). There is no handshake, and until a valid
command arrives nothing is sent. Packets of the wrong length or with a bad CRC
are counted and never applied.

Each motor does what the Go1 motor's PD does with a command (mode 0x0A)::

    tau = clip(Kp (q* - q) + Kd (dq* - dq) + tau_ff, -limit, limit)

with the Go1 torque limits (23.7, 23.7, 35.55 N·m for hip, thigh, calf; read
from the model's actuator force ranges), the SDK's ``PosStopF``/``VelStopF``
sentinels switching the position/velocity term off, and any other mode
(0x00, "damping") ``tau = -DAMPING_MODE_KD dq``. Before the first valid command
every motor is in damping. The torques go into ``data.qfrc_applied`` at the
joints' dofs of the emulator's own copy of the plant's model, whose position
servos are zeroed (``actuator_gainprm[:, 0]``, ``actuator_biasprm[:, 1:3]``),
so ``data.ctrl`` has no effect. Measured: at Kp 100 / Kd 4 this explicit PD is
stable at the plant's 2 ms step with no substeps (standing, a 3 rad/s kick on
every joint dies out; the stand pose sags by 0.055 rad under gravity, as the
plant's own servo does). One tick costs ≈ 0.4 ms on a busy 2-core machine
(≈ 50 µs physics, ≈ 0.2 ms building and encoding the LowState).

The state carries the joints (q, dq, ddq, tau_est = the applied torque), the
IMU of the trunk's ``imu`` site (quaternion w, x, y, z; gyroscope = body-frame
angular velocity [rad/s]; accelerometer = body-frame specific force
``R^T (a - g)`` [m/s²], MuJoCo's accelerometer computation, so a standing robot
reads ≈ +9.81 on z; roll, pitch, yaw [rad]), the feet's contact normal forces
[N] and the tick [ms since start]. Trunk and box poses go at 120 Hz to a motion
capture stream (:class:`~amhe_cli.plants.go1.mocap.PoseSender`) as rigid bodies
``Go1_body`` and ``Box_body``. Task events fire on the plant as in the sim.

Faults (:class:`Fault`, times after the first valid command) break the link or
the pose stream on purpose, to test a client's watchdogs.
"""

from __future__ import annotations

import copy
import csv
import math
import select
import signal
import socket
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import mujoco
import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.model.scene import FEET, torque_limit
from amhe_cli.plants.go1.mocap import PoseSender
from amhe_cli.plants.go1.relay import raise_thread_priority
from amhe_cli.plants.go1.protocol import MODE_SERVO, POS_STOP_F, VEL_STOP_F, LowCmd, LowState, ProtocolError

#: Control and state period of the emulator [s]: the plant's step (500 Hz).
TICK = 0.002
#: Rate of the motion-capture pose stream [Hz] (the public Go1 box-pushing
#: setup streamed OptiTrack rigid bodies at 120 Hz).
POSE_RATE = 120.0
#: Joint damping of a motor in damping mode (0x00) or before any command
#: [N·m·s/rad]. Unitree does not document it; 5 is an assumed value, just above
#: the Kd of a holding servo (3–4), so a standing robot left in damping folds
#: down instead of dropping (measured here: trunk 0.29 → 0.15 m in 1 s, on its
#: belly at 0.07 m after 2 s; Kd 2 drops it to 0.10 m in 1 s), and a leg swung
#: by hand at 1 rad/s resists with 5 N·m.
DAMPING_MODE_KD = 5.0
#: Kinds of fault :func:`parse_fault` knows.
FAULT_KINDS = ("link-loss", "corrupt", "mocap-freeze", "mocap-drop", "motor-loss")
#: Reported for the motors' and the IMU's temperature [°C] (the sim has no heat).
TEMPERATURE = 35
#: The wire's int16 range, for the raw ddq and foot-force fields.
_I16 = 32767
#: Behind the wall clock by more than this many ticks, the loop stops catching
#: up (drops the backlog) instead of stepping in a burst.
MAX_CATCH_UP = 10

_NJ = 12


@dataclass(frozen=True)
class Fault:
    """A fault injected ``t`` seconds of emulator time after the first valid command.

    ``kind``: ``link-loss`` (no more state: the client no longer hears the
    robot, the robot still hears, records and applies the client, so the
    client's reaction — damping — shows in the record), ``corrupt`` (every LowState from then on has a bad
    CRC), ``mocap-freeze`` (the same poses with the same stamp are sent from
    then on), ``mocap-drop`` (poses stop), ``motor-loss`` (the motors deliver no torque from then on, whatever
    is commanded, as when their power is cut: the robot folds to the floor, a fall the client must report).
    """

    kind: str
    t: float


def parse_fault(text: str) -> Fault:
    """Parse ``KIND@T`` (e.g. ``link-loss@5``, ``corrupt@0.5``) into a :class:`Fault`.

    Raises:
        AmheError: unknown kind, or T not a finite number ≥ 0 [s].
    """
    kind, sep, t = str(text).strip().partition("@")
    if not sep or kind not in FAULT_KINDS:
        raise AmheError(f"--fault {text!r}: expected KIND@T with KIND one of {', '.join(FAULT_KINDS)} "
                        f"and T seconds after the first valid command, e.g. link-loss@5")
    try:
        tv = float(t)
    except ValueError:
        tv = float("nan")
    if not math.isfinite(tv) or tv < 0:
        raise AmheError(f"--fault {text!r}: T must be a number of seconds >= 0, got {t!r}")
    return Fault(kind, tv)


@dataclass
class EmulatorStats:
    """Counters of a running emulator (a snapshot from :attr:`Go1Emulator.stats`).

    Attributes:
        valid: LowCmd packets accepted (right length and CRC, finite values).
        bad: packets rejected (length, CRC, non-finite values); never applied.
        ignored: packets that arrived while a ``link-loss`` fault kept the state from going out.
        overruns: ticks whose work ended after their wall-clock deadline.
        sent: LowState packets sent.
        send_failed: LowState packets the socket refused (``sendto`` raised: a full send buffer on a loaded
            host, an unreachable client); the gap they leave counts in ``longest_gap``.
        poses: pose frames handed to the pose stream.
        ticks: plant steps taken (emulator time = ticks × 2 ms).
        longest_gap: the longest wall-clock time between two LowState packets
            sent back to back [s]; a gap past the client's ``state_timeout``
            that no ``link-loss`` fault caused means the emulator itself was
            held up (a busy or paused machine), and a client that damped
            then did right.
        longest_command_gap: the longest wall-clock time between two valid
            LowCmd packets [s], as the robot saw its client (from the first on):
            meanwhile its motors held the last command. A client whose process
            stalls shows here (stop 76: 0.23 s mid-stride in a fall).
        longest_pose_gap: the longest wall-clock time between two pose datagrams
            sent [s], from the client's first command on (no ``mocap-drop`` or
            ``mocap-freeze`` fault active): past the client's ``mocap_timeout``, the
            emulated world ran that much slower than the clock (a starved
            emulator still streams states within the state watchdog, its poses
            at 120 Hz of its own time) or stopped, and a client that then held
            the stand for stale motion capture did right.
    """

    valid: int = 0
    bad: int = 0
    ignored: int = 0
    overruns: int = 0
    sent: int = 0
    send_failed: int = 0
    poses: int = 0
    ticks: int = 0
    longest_gap: float = 0.0
    longest_command_gap: float = 0.0
    longest_pose_gap: float = 0.0


def motor_torques(cmd: LowCmd | None, q: np.ndarray, dq: np.ndarray, limit: np.ndarray,
                  strength: float = 1.0) -> np.ndarray:
    """Torques (12,) [N·m] the Go1 motors apply for a command, per motor (docs/reference.md#go1-low-level-link).

    Mode 0x0A (servo): ``Kp (q* - q) + Kd (dq* - dq) + tau_ff``, where a q* at
    ``PosStopF`` drops the position term and a dq* at ``VelStopF`` uses dq* = 0.
    Any other mode, or no command (``cmd`` None): ``-DAMPING_MODE_KD dq``. Then
    times ``strength`` and clipped to ±``strength · limit``.

    Args:
        cmd: the command in force, or None before the first valid one.
        q, dq: (12,) joint positions [rad] and velocities [rad/s].
        limit: (12,) torque limits [N·m].
        strength: the share of the law's torque the motors deliver (1: as commanded; 0.85: a robot
            whose motors are weaker than its model's, ``amhe emulate go1 --motor-strength``; 0: no torque,
            the ``motor-loss`` fault).
    """
    q = np.asarray(q, dtype=float)
    dq = np.asarray(dq, dtype=float)
    if cmd is None:
        tau = -DAMPING_MODE_KD * dq
    else:
        mode = np.asarray(cmd.mode)[:_NJ]
        qt = np.asarray(cmd.q, dtype=float)[:_NJ]
        dqt = np.asarray(cmd.dq, dtype=float)[:_NJ]
        kp = np.asarray(cmd.kp, dtype=float)[:_NJ]
        kd = np.asarray(cmd.kd, dtype=float)[:_NJ]
        pos = np.where(np.abs(qt) >= POS_STOP_F, 0.0, kp * (qt - q))
        vel = kd * (np.where(np.abs(dqt) >= VEL_STOP_F, 0.0, dqt) - dq)
        servo = pos + vel + np.asarray(cmd.tau, dtype=float)[:_NJ]
        tau = np.where(mode == MODE_SERVO, servo, -DAMPING_MODE_KD * dq)
    return np.clip(strength * tau, -strength * limit, strength * limit)


def _rpy(quat: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (3,) [rad] (Z-Y-X, the Go1 IMU's convention) of a (w, x, y, z) quaternion."""
    w, x, y, z = quat
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


class Go1Emulator:
    """The sim plant behind the Go1 low-level UDP protocol, stepped on the wall clock.

    The socket is bound at construction, so :attr:`address` is known before
    :meth:`start` (``port=0`` takes an ephemeral port).

    Args:
        plant: a ready :class:`~amhe_cli.plants.sim.SimPlant` (2 ms step, reset to
            its start state); the emulator steps ``plant.data`` with its own
            copy of ``plant.model`` whose servos are zeroed.
        events: the task's pending events (a list; fired ones are removed), fired
            with ``plant.fire_due`` every tick. A timed event (T3's mass switch at 10 s)
            counts in the *task's* time, as in the sim: from ``task_delay`` after the
            first command that servos a motor (a client's ramp to the stand, then its task),
            not from the emulator's start, which a client may join many seconds later.
        host, port: where to listen for LowCmd packets.
        pose_to: ``(host, port)`` of the pose stream, or None for no poses.
        faults: :class:`Fault` objects (or ``KIND@T`` strings).
        record: CSV path of one row per received packet (``t``, ``valid``,
            ``mode_i``, ``q_i``, ``kp_i``, ``kd_i``), or None.
        base_body, box_body: rigid-body names on the pose stream.
        pose_latency: pose stream latency [s].
        pose_noise: (position [m], rotation [rad]) noise std of the pose stream.
        seed: seed of the pose noise.
        overwrite: allow ``record`` to replace an existing file.
        on_event: called as ``on_event(t, event, monotonic)`` from the emulator's loop when a task
            event fires: its emulated time [s], the event, and ``time.monotonic()`` then (the clock a
            client on this machine can align its own recording to).
        task_delay: seconds from the first servo command to the task's time 0 (the client's
            ramp to the stand: :class:`~amhe_cli.plants.go1.safety.SafetySettings` ``ramp_time``).
        view: an :class:`~amhe_cli.io.view.View` told the true state every tick (it keeps what its rate
            allows, never blocks) and each fault and task event as it fires; None: no view.
        motor_strength: the share of the motor law's torque the motors deliver, limits included
            (:func:`motor_torques`); 1: the model's motors.

    Raises:
        AmheError: a plant whose step is not 2 ms, a motor strength outside (0, 2], a bad fault, an existing
            ``record`` file without ``overwrite``, a port that cannot be bound.
    """

    def __init__(self, plant, events, host: str = "127.0.0.1", port: int = 0, pose_to=None, faults=(),
                 record=None, base_body: str = "Go1_body", box_body: str = "Box_body",
                 pose_latency: float = 0.0, pose_noise=(0.0, 0.0), seed: int = 0, overwrite: bool = False,
                 view=None, on_event=None, task_delay: float = 2.0, motor_strength: float = 1.0):
        dt = plant.model.opt.timestep
        if not 0 < motor_strength <= 2:
            raise AmheError(f"motor strength {motor_strength}: expected the share of the commanded torque the "
                            "motors deliver, in (0, 2]")
        self.motor_strength = float(motor_strength)
        if abs(dt - TICK) > 1e-9:
            raise AmheError(f"emulator plant steps at {dt * 1e3:g} ms: expected {TICK * 1e3:g} ms")
        self.plant = plant
        self.view = view
        self.events = events if events is not None else []
        self.on_event = on_event
        self.task_delay = float(task_delay)
        self._task_start: float | None = None  # emulated time of the task's time 0
        self.faults = tuple(f if isinstance(f, Fault) else parse_fault(f) for f in faults)
        self.base_body, self.box_body = str(base_body), str(box_body)
        s = plant.scene
        self._jq, self._jv = s.joint_qpos, s.joint_qvel
        self._bq, self._bv, self._xq = s.base_qpos, s.base_qvel, s.box_qpos
        self.limit = torque_limit(plant.model)
        self.model = self._torque_model()
        m = self.model
        self._imu = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "imu")
        self._feet = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f) for f in FEET])
        self.data = plant.data
        self._lock = threading.Lock()
        self._closed = False
        self.scheduling = ""
        self._poses = None
        self._csv_file = None
        self._csv = None

        try:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind((host, int(port)))
        except (OSError, OverflowError, TypeError, ValueError) as e:
            self.sock.close()
            raise AmheError(f"cannot listen on udp://{host}:{port}: {e}") from None
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()[:2]

        self.pose_to = tuple(pose_to) if isinstance(pose_to, (tuple, list)) else pose_to
        if self.pose_to is not None:
            try:
                self._poses = PoseSender(target=self.pose_to, latency=float(pose_latency),
                                         noise_pos=float(pose_noise[0]), noise_rot=float(pose_noise[1]),
                                         seed=int(seed))
            except AmheError:
                self.close()
                raise
        if record is not None:
            path = Path(record)
            try:
                self._csv_file = open(path, "w" if overwrite else "x", newline="")
            except FileExistsError:
                self.close()
                raise AmheError(f"{path} exists: pass --force to overwrite it") from None
            except OSError as e:
                self.close()
                raise AmheError(f"cannot write {path}: {e.strerror or e}") from None
            self._csv = csv.writer(self._csv_file)
            self._csv.writerow(["t", "valid"] + [f"{k}_{i}" for k in ("mode", "q", "kp", "kd") for i in range(_NJ)])
            self._csv_file.flush()

        self._stats = EmulatorStats()
        self._cmd: LowCmd | None = None
        self._client = None
        self._t_first = None
        self._active: set[str] = set()
        self._frozen = None
        self._tau = np.zeros(_NJ)
        self._acc = np.zeros(6)
        self._next_pose = 0.0
        self._last_sent: float | None = None
        self._last_pose_sent: float | None = None  # when a pose datagram last went out [s, monotonic]
        self._poses_counted = 0
        self._last_cmd_wall: float | None = None
        self._stop = threading.Event()
        self._thread = None
        self._running = False

    # -- public ------------------------------------------------------------
    @property
    def stats(self) -> EmulatorStats:
        """A snapshot of the counters (:class:`EmulatorStats`)."""
        return EmulatorStats(**asdict(self._stats))

    @property
    def time(self) -> float:
        """Emulator time since start [s] (ticks × 2 ms)."""
        return self._stats.ticks * TICK

    def start(self, duration: float | None = None) -> None:
        """Run the loop in a daemon thread for ``duration`` s of emulator time (None: until :meth:`stop`).

        Raises:
            AmheError: already started, or closed.
        """
        if self._thread is not None or self._closed:
            raise AmheError("emulator already started or closed: make a new one")
        self._thread = threading.Thread(target=self._loop, args=(duration,), name="go1-emulator", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the loop (thread or :meth:`run`), then close the socket, CSV and pose stream."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        deadline = time.monotonic() + 5.0
        while self._running and time.monotonic() < deadline:  # run() in another thread
            time.sleep(0.002)
        self.close()

    def run(self, duration: float | None = None) -> EmulatorStats:
        """Run the loop in this thread for ``duration`` s of emulator time (None: until
        :meth:`stop`, SIGINT or SIGTERM), then close everything; returns the final stats."""
        if self._thread is not None or self._closed:
            raise AmheError("emulator already started or closed: make a new one")
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, lambda *_: self._stop.set())
        try:
            self._loop(duration)
        finally:
            for sig, h in handlers.items():
                signal.signal(sig, h)
            self.close()
        return self.stats

    def close(self) -> None:
        """Close the socket, the CSV and the pose stream (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self.sock.close()
        except (AttributeError, OSError):
            pass
        if self._csv_file is not None:
            self._csv_file.close()
        if self._poses is not None:
            self._poses.close()

    # -- loop --------------------------------------------------------------
    def _loop(self, duration: float | None) -> None:
        self._running = True
        # a robot has its own computer; on a shared one the emulator's physics must not starve
        self.scheduling = raise_thread_priority()
        n_end = None if duration is None else int(round(duration / TICK))
        t0 = time.monotonic()
        k = 0
        try:
            while not self._stop.is_set() and (n_end is None or k < n_end):
                self._tick()
                k += 1
                deadline = t0 + k * TICK
                now = time.monotonic()
                if now > deadline:
                    self._stats.overruns += 1
                    if now - deadline > MAX_CATCH_UP * TICK:
                        t0 += now - deadline  # stop catching up: the emulator falls behind the clock
                        deadline = now
                self._receive(deadline)
        finally:
            self._running = False

    def _receive(self, deadline: float) -> None:
        """Take every packet that arrives until ``deadline`` (monotonic s); the last valid one rules."""
        sock = self.sock
        while True:
            while True:
                try:
                    buf, addr = sock.recvfrom(2048)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:  # e.g. ICMP port unreachable from a client that left
                    continue
                self._packet(buf, addr)
            wait = deadline - time.monotonic()
            if wait <= 0 or self._stop.is_set():
                return
            try:
                select.select([sock], [], [], wait)
            except (InterruptedError, ValueError, OSError):
                return

    def _packet(self, buf: bytes, addr) -> None:
        t = self.time
        if "link-loss" in self._active:
            self._stats.ignored += 1  # still heard, recorded and applied: only the state direction is lost
        try:
            cmd = LowCmd.decode(buf)
            fields = [np.asarray(getattr(cmd, f), dtype=float)[:_NJ] for f in ("q", "dq", "tau", "kp", "kd")]
            if not all(np.all(np.isfinite(v)) for v in fields):
                raise ProtocolError("non-finite value in a motor command")
        except ProtocolError:
            self._stats.bad += 1
            self._record(t, None)
            return
        self._stats.valid += 1
        wall = time.monotonic()
        if self._last_cmd_wall is not None:
            self._stats.longest_command_gap = max(self._stats.longest_command_gap, wall - self._last_cmd_wall)
        self._last_cmd_wall = wall
        self._cmd = cmd
        self._client = addr
        if self._t_first is None:
            self._t_first = t
        self._record(t, cmd)

    def _record(self, t: float, cmd: LowCmd | None) -> None:
        if self._csv is None:
            return
        if cmd is None:
            row = [f"{t:.3f}", 0] + [0] * (4 * _NJ)
        else:
            row = [f"{t:.3f}", 1] + [int(v) for v in np.asarray(cmd.mode)[:_NJ]]
            for f in ("q", "kp", "kd"):
                row += [f"{v:.6g}" for v in np.asarray(getattr(cmd, f), dtype=float)[:_NJ]]
        self._csv.writerow(row)
        self._csv_file.flush()

    def _tick(self) -> None:
        """One 2 ms step: faults, events, motor torques, physics, state out, poses out."""
        m, d = self.model, self.data
        self._update_faults()
        if self._task_start is None and self._cmd is not None and \
                np.any((np.asarray(self._cmd.mode)[:_NJ] == MODE_SERVO) & (np.asarray(self._cmd.kp)[:_NJ] > 0)):
            self._task_start = float(d.time) + self.task_delay
        task_t = -np.inf if self._task_start is None else float(d.time) - self._task_start
        fired = self.plant.fire_due(self.events, t=task_t)
        if fired:
            self.model = m = self._torque_model()
            if self.on_event is not None:
                for ev in fired:
                    self.on_event(float(d.time), ev, time.monotonic())
            if self.view is not None:
                self.view.log(self.time, f"emulator: {len(fired)} task event(s) fired "
                              f"(truth now {self.plant.truth_values})", "info")
        q, dq = d.qpos[self._jq], d.qvel[self._jv]
        strength = 0.0 if "motor-loss" in self._active else self.motor_strength  # a power cut: no torque at all
        self._tau = motor_torques(self._cmd, q, dq, self.limit, strength)
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self._jv] = self._tau
        mujoco.mj_step(m, d)
        # the MuJoCo accelerometer at the IMU site, from the step's own forward pass
        mujoco.mj_rnePostConstraint(m, d)
        mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_SITE, self._imu, self._acc, 1)
        self._stats.ticks += 1
        if self._client is not None and "link-loss" not in self._active:
            buf = self._state().encode()
            if "corrupt" in self._active:
                buf = buf[:-4] + bytes(b ^ 0xFF for b in buf[-4:])
            try:
                self.sock.sendto(buf, self._client)
            except OSError:
                self._stats.send_failed += 1  # not sent: the client hears a silence, and the gap runs on
            else:
                self._stats.sent += 1
                now = self._clock()
                if self._last_sent is not None:
                    self._stats.longest_gap = max(self._stats.longest_gap, now - self._last_sent)
                self._last_sent = now
        else:
            self._last_sent = None  # a silence the emulator meant (no client yet, link-loss) is no gap
        self._send_poses()
        if self.view is not None:
            self.view.state(self.time, d.qpos)

    def _update_faults(self) -> None:
        if self._t_first is None:
            return
        for f in self.faults:
            if f.kind not in self._active and self.time >= self._t_first + f.t:
                self._active.add(f.kind)
                if self.view is not None:
                    self.view.log(self.time, f"emulator: fault {f.kind} injected at {f.t:g} s after the first "
                                  "command", "warning")

    def _state(self) -> LowState:
        """The LowState of the current plant state (see the module docstring)."""
        d = self.data
        quat = np.array(d.qpos[self._bq[3:]], dtype=float)
        quat /= np.linalg.norm(quat)
        mode = np.zeros(_NJ, dtype=np.uint8) if self._cmd is None else self._cmd.mode
        feet = np.clip(self._foot_forces(), -_I16, _I16)
        return LowState(
            quaternion=quat,
            gyroscope=d.qvel[self._bv[3:]],  # a free joint's angular velocity is in its body frame
            accelerometer=self._acc[3:], rpy=_rpy(quat), imu_temperature=TEMPERATURE,
            motor_mode=mode, q=d.qpos[self._jq], dq=d.qvel[self._jv],
            ddq=np.clip(d.qacc[self._jv], -_I16, _I16),  # the wire's raw int16, here rad/s²
            tau_est=self._tau, motor_temperature=np.full(_NJ, TEMPERATURE),
            foot_force=feet, foot_force_est=feet, tick=int(round(self.time * 1000.0)) & 0xFFFFFFFF)

    def _foot_forces(self) -> np.ndarray:
        """(4,) normal contact force on each foot sphere [N] (FR, FL, RR, RL), floor and box contacts summed."""
        m, d = self.model, self.data
        out = np.zeros(4)
        if d.ncon == 0:
            return out
        geoms = d.contact.geom[:d.ncon]
        f6 = np.zeros(6)
        for i, foot in enumerate(self._feet):
            for c in np.flatnonzero((geoms[:, 0] == foot) | (geoms[:, 1] == foot)):
                if d.contact.efc_address[c] >= 0:
                    mujoco.mj_contactForce(m, d, int(c), f6)
                    out[i] += f6[0]
        return out

    def _send_poses(self) -> None:
        if self._poses is None:
            return
        t = self.time
        if "mocap-drop" not in self._active and t + 1e-9 >= self._next_pose:
            self._next_pose += 1.0 / POSE_RATE
            if "mocap-freeze" in self._active:
                if self._frozen is None:  # a frozen tracker repeats itself exactly: no fresh noise either
                    self._frozen = self._pose_frame()
                    self._poses.noise_pos = self._poses.noise_rot = 0.0
                frame = self._frozen
            else:
                frame = self._pose_frame()
            self._poses.send(*frame)
            self._stats.poses += 1
        now = self._clock()
        self._poses.flush(now)
        if self._poses.sent > self._poses_counted and self._t_first is not None:  # one went out, a client there
            if self._last_pose_sent is not None and not self._active & {"mocap-drop", "mocap-freeze"}:
                self._stats.longest_pose_gap = max(self._stats.longest_pose_gap, now - self._last_pose_sent)
            self._last_pose_sent = now
        self._poses_counted = self._poses.sent

    def _pose_frame(self):
        d = self.data
        poses = {self.base_body: (np.array(d.qpos[self._bq[:3]]), np.array(d.qpos[self._bq[3:]])),
                 self.box_body: (np.array(d.qpos[self._xq[:3]]), np.array(d.qpos[self._xq[3:]]))}
        return poses, self._clock()

    # -- helpers -----------------------------------------------------------
    def _clock(self) -> float:
        return time.monotonic()

    def _torque_model(self) -> mujoco.MjModel:
        """A copy of the plant's model (true parameters as now) with its position servos zeroed."""
        m = copy.copy(self.plant.model)
        m.actuator_gainprm[:, 0] = 0.0
        m.actuator_biasprm[:, 1:3] = 0.0
        return m

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        self.close()
