"""The relay in a process of its own, so nothing the planner's process does can stop the robot's commands.

:class:`~amhe_cli.plants.go1.relay.Relay` is a thread; a thread shares the
interpreter lock with the planner, the MHE, the GPU decisions, the pose
receiver and the recorder. Whatever holds that lock holds the commands too:
in an emulated T3 run (stop 76, seed 31, a lent H200) the client stopped for
0.23–0.31 s at 45.0 s (no IMU sample recorded, no pose, no plan, the MHE's test
0.29 s instead of 0.02), the robot kept the last command's joint targets at
kp 100 mid-stride, pitched 10° → 29° on two legs and fell; every emulated GPU
run of stops 73–76 shows such stalls of 60–250 ms in its first seconds (the
GPU backend loading). :class:`RelayProcess` runs the same :class:`Relay`, its
watchdogs and its safety layer in a child process (``spawn``) that owns the
link's socket: a stall of the planner's process leaves it interpolating the
last plan, then its stale-plan watchdog soft-holds the pose, as it would for a
slow planner; the child damps the robot and ends when the planner's process
dies.

What crosses between the processes (``multiprocessing`` queues, neither side
ever blocks on the other): plans, the motion capture's freshness, damp and
stop go to the child; every tick ``(t, state, q_sent, mode, run servo, the dry
run's target, work time)`` and the relay's messages come back to a thread here
that calls ``on_tick`` in order: late after a stall, never lost, each with the
child's own ``time.monotonic()`` (a clock both processes share), the state as
the fields this process reads (:class:`StateSample`). The phase, the
trip's reason and the ready/streaming/failed flags are shared memory, so they
are current even while this process lags.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from amhe_cli.plants.go1.relay import HISTORY, PHASES, SWITCH_INTERVAL, Relay, damping_burst
from amhe_cli.plants.go1.safety import SafetyLayer, SafetySettings

#: How long the child may take to start (a spawned interpreter imports numpy and MuJoCo) [s].
START_TIMEOUT = 30.0
#: How often the child looks for orders and checks that the planner's process lives [s].
CHECK_EVERY = 0.02
#: How long :meth:`RelayProcess.damp` waits for the child to confirm it damps [s].
DAMP_WAIT = 0.5
#: Bytes kept for the trip's reason in shared memory.
REASON_BYTES = 512


class StateSample:
    """What the planner's process reads of a :class:`~amhe_cli.plants.go1.protocol.LowState` (the attributes of
    :data:`FIELDS`, float64 arrays of those sizes), sent across as one array's bytes.

    Raises:
        ValueError (from :meth:`unpack`): bytes not of the :data:`FIELDS`' total size."""

    FIELDS = (("quaternion", 4), ("gyroscope", 3), ("accelerometer", 3), ("rpy", 3), ("q", 12), ("dq", 12),
              ("tau_est", 12), ("foot_force", 4))
    __slots__ = tuple(name for name, _ in FIELDS)

    @classmethod
    def pack(cls, state) -> bytes:
        """The fields of ``state`` (a LowState) as bytes."""
        return np.concatenate([np.asarray(getattr(state, name), dtype=float) for name, _ in cls.FIELDS]).tobytes()

    @classmethod
    def unpack(cls, data: bytes) -> "StateSample":
        """A sample from :meth:`pack`'s bytes (read-only arrays over them)."""
        values = np.frombuffer(data, dtype=float)
        if values.size != sum(n for _, n in cls.FIELDS):
            raise ValueError(f"a state sample holds {sum(n for _, n in cls.FIELDS)} numbers, got {values.size}")
        out, k = cls.__new__(cls), 0
        for name, n in cls.FIELDS:
            setattr(out, name, values[k:k + n])
            k += n
        return out


class _SharedFailed:
    """The child's ``Relay.failed``: the reason and the phase go to shared memory before the flag is raised, so the
    planner's process never sees a failure without its reason, nor a phase from before it."""

    def __init__(self, event, reason, phase, relay: Relay):
        self._event, self._reason, self._phase, self._relay = event, reason, phase, relay

    def set(self) -> None:
        text = (self._relay.reason or "the relay stopped").encode()[:REASON_BYTES - 1]
        self._reason.value = text
        self._phase.value = PHASES.index("damp")
        self._event.set()

    def is_set(self) -> bool:
        return self._event.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._event.wait(timeout)


def _child(link, settings: SafetySettings, kp: float, kd: float, dry_run: bool, planner_period: float,
           inbox, outbox, flags: dict, parent: int) -> None:
    """The relay process: a :class:`Relay` on ``link`` until told to stop, damped if the planner's process dies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the planner's to handle: it damps through us

    def terminate(*_) -> None:  # a SIGTERM of its own: damp (below) and end
        raise SystemExit(0)
    signal.signal(signal.SIGTERM, terminate)

    def tick(now, state, q_sent, mode) -> None:
        flags["phase"].value = PHASES.index(relay.phase)
        flags["bad_packets"].value = getattr(link, "bad_packets", 0)
        flags["clamped"].value = relay.clamped
        would = relay.would_send[-1][1] if relay.dry_run and relay.would_send else None
        # arrays as their bytes: a pickled LowState or ndarray costs tens of microseconds on each side, and
        # decoding the state's datagram again on the planner's side 74 µs
        outbox.put(("tick", now, None if state is None else StateSample.pack(state),
                    None if q_sent is None else np.asarray(q_sent, float).tobytes(), int(mode),
                    relay.run_servo, None if would is None else np.asarray(would, float).tobytes(),
                    relay.busy[-1] if relay.busy else 0.0))

    relay = Relay(link, SafetyLayer(settings), kp, kd, dry_run=dry_run, planner_period=planner_period, on_tick=tick)
    relay.streaming, relay.ready = flags["streaming"], flags["ready"]
    relay.failed = _SharedFailed(flags["failed"], flags["reason"], flags["phase"], relay)
    outbox.put(("started", os.getpid()))  # first in the queue, before any tick
    relay.start()
    why = None
    try:
        while True:
            try:
                order = inbox.get(timeout=CHECK_EVERY)
            except queue.Empty:
                order = None
            if os.getppid() != parent:
                why = "the planner's process ended without stopping the relay"
                relay.damp(why)
                break
            if order is not None:
                kind = order[0]
                if kind == "plan":
                    relay.set_plan(*order[1:])
                elif kind == "mocap":
                    relay.set_mocap_ok(order[1])
                elif kind == "damp":
                    relay.damp(order[1])
                elif kind == "stop":
                    break
            for text in relay.take_messages():
                outbox.put(("message", text))
    finally:
        relay.stop()  # a burst of damping packets, then the thread ends
        flags["phase"].value = PHASES.index("damp")
        for text in relay.take_messages():
            outbox.put(("message", text))
        outbox.put(("stopped", relay.scheduling, why))
        link.close()
        # the queue's last items go out at exit; a reader that is gone must not keep this process (and the
        # robot's port) alive: a second at most
        guard = threading.Timer(1.0, os._exit, (0,))
        guard.daemon = True
        guard.start()


class RelayProcess:
    """:class:`~amhe_cli.plants.go1.relay.Relay` in a child process, with the thread relay's interface.

    Args:
        link: an open :class:`~amhe_cli.plants.go1.link.LowLevelLink`; its socket goes to the child, which alone
            reads and writes it (this process keeps a copy to damp the robot if the child dies).
        settings: the safety layer's :class:`~amhe_cli.plants.go1.safety.SafetySettings`.
        kp, kd, dry_run, planner_period: as :class:`Relay`.
        on_tick: called here, from a thread of its own, for every tick of the child, in order, with
            ``(t, state or None, q_sent or None, mode)`` as :class:`Relay` calls it (``t`` the child's
            ``time.monotonic()``, ``state`` a :class:`StateSample`).
    Attributes:
        phase, reason, run_servo, state (a :class:`StateSample`), state_time, would_send, periods, busy,
        scheduling, messages,
        streaming, ready, failed, bad_packets, clamped: as :class:`Relay`'s (``phase``, ``reason``,
        ``bad_packets``, ``clamped``, ``streaming``, ``ready`` and ``failed`` live in shared memory; the others as
        the ticks arrive here).
        pid: the child's process id once started.
    Raises:
        PlantFailure (from :meth:`start`): the child did not start within :data:`START_TIMEOUT`.
    """

    def __init__(self, link, settings: SafetySettings, kp: float, kd: float, dry_run: bool = False,
                 planner_period: float = 0.25, on_tick: Callable | None = None):
        self.link = link
        self.safety_settings = settings
        self.kp, self.kd, self.dry_run, self.planner_period = float(kp), float(kd), dry_run, planner_period
        self.on_tick = on_tick
        ctx = mp.get_context("spawn")  # never fork a process that holds thread pools and maybe a GPU context
        self._ctx = ctx
        self.streaming, self.ready, self.failed = ctx.Event(), ctx.Event(), ctx.Event()
        self._reason = ctx.Array("c", REASON_BYTES, lock=False)
        self._phase = ctx.Value("i", PHASES.index("wait"), lock=False)
        self._bad_packets = ctx.Value("q", 0, lock=False)
        self._clamped = ctx.Value("q", 0, lock=False)
        self._inbox, self._outbox = ctx.Queue(), ctx.Queue()
        self.run_servo = False
        self.state = None
        self.state_time = -np.inf
        self.would_send: deque = deque(maxlen=HISTORY)
        self.periods: deque[float] = deque(maxlen=HISTORY)
        self.busy: deque[float] = deque(maxlen=HISTORY)
        self.messages: list[str] = []
        self.scheduling = ""
        self.pid: int | None = None
        self._proc = None
        self._receiver: threading.Thread | None = None
        self._lock = threading.Lock()
        self._mocap_ok = True
        self._last_t = None
        self._stopped = threading.Event()
        self._switch = sys.getswitchinterval()
        self._ended = False  # stop() ran

    # -- shared state -------------------------------------------------------------
    @property
    def phase(self) -> str:
        """The child relay's phase now (shared memory)."""
        return PHASES[self._phase.value]

    @property
    def reason(self) -> str | None:
        """Why the child relay damped (None until it did)."""
        text = self._reason.value.decode(errors="replace")
        return text or None

    @property
    def clamped(self) -> int:
        """Targets the child's safety layer clamped so far."""
        return int(self._clamped.value)

    @property
    def bad_packets(self) -> int:
        """Invalid packets the child's link dropped so far."""
        return int(self._bad_packets.value)

    # -- the caller's side ----------------------------------------------------------
    def start(self) -> None:
        """Spawn the child relay (phase ``wait``: damping packets until the robot answers) and the thread here
        that takes its ticks; returns once the child runs.

        Raises:
            PlantFailure: the child did not start within :data:`START_TIMEOUT` s.
        """
        from amhe_cli.plants.base import PlantFailure
        flags = {"streaming": self.streaming, "ready": self.ready, "failed": self.failed, "reason": self._reason,
                 "phase": self._phase, "bad_packets": self._bad_packets, "clamped": self._clamped}
        self._proc = self._ctx.Process(
            target=_child, name="amhe-relay", daemon=True,
            args=(self.link, self.safety_settings, self.kp, self.kd, self.dry_run, self.planner_period,
                  self._inbox, self._outbox, flags, os.getpid()))
        self._proc.start()
        try:
            first = self._outbox.get(timeout=START_TIMEOUT)
        except queue.Empty:
            first = None
        if first is None:
            code = self._proc.exitcode
            self._proc.kill()
            raise PlantFailure(f"the relay process did not start within {START_TIMEOUT:g} s" +
                               (f" (it ended with exit code {code})" if code is not None else ""))
        self.pid = first[1]
        # this process's threads that take the ticks and the poses wait for the interpreter lock no longer than
        # the relay's thread did here (the planner's Python holds it for the default 5 ms otherwise)
        sys.setswitchinterval(SWITCH_INTERVAL)
        self._receiver = threading.Thread(target=self._receive, name="amhe-relay-ticks", daemon=True)
        self._receiver.start()

    def wait_ready(self, timeout: float) -> bool:
        """Block until the ramp to the stand is done (``dry``: until the state streams); False on timeout or trip."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.failed.is_set() or not self.alive():
                return False
            if self.ready.wait(0.01):
                return True
        return False

    def alive(self) -> bool:
        """Whether the child relay runs."""
        return self._proc is not None and self._proc.is_alive()

    def set_plan(self, controls: np.ndarray, dt: float, t0: float) -> None:
        """Hand over a plan (as :meth:`Relay.set_plan`; ``t0`` on ``time.monotonic()``, which the child shares)."""
        self._inbox.put(("plan", np.asarray(controls, dtype=float), float(dt), float(t0)))

    def set_mocap_ok(self, ok: bool) -> None:
        """Whether the motion capture is fresh enough to push; sent to the child when it changes."""
        ok = bool(ok)
        if ok != self._mocap_ok:
            self._mocap_ok = ok
            self._inbox.put(("mocap", ok))

    def take_messages(self) -> list[str]:
        """The child relay's phase changes and watchdog events since the last call."""
        with self._lock:
            out, self.messages = self.messages, []
        return out

    def damp(self, reason: str) -> None:
        """Damp now (an error elsewhere, Ctrl-C); the first reason given is kept. Returns once the child
        confirms it sends damping packets only, or, if it does not within :data:`DAMP_WAIT`, after this
        process sent a burst of damping packets itself."""
        if self.alive():
            self._inbox.put(("damp", str(reason)))
            if self.failed.wait(DAMP_WAIT):
                return
        self._damp_here(reason)

    def stop(self) -> None:
        """End the child relay: a burst of damping packets, then it exits. Safe to call twice."""
        if self._proc is None or self._ended:
            return
        self._ended = True
        if self._proc.is_alive():
            self._inbox.put(("stop",))
            self._proc.join(timeout=2.0)
        if self._proc.is_alive() or self._proc.exitcode != 0:
            self._proc.kill()
            self._proc.join(timeout=1.0)
            self._damp_here("the relay process did not stop cleanly")
        if self._receiver is not None:
            self._stopped.wait(1.0)
        self._stopped.set()
        sys.setswitchinterval(self._switch)
        self._inbox.cancel_join_thread()  # a child that is gone reads nothing: never wait on it at exit
        self._inbox.close()

    # -- here -----------------------------------------------------------------------
    def _damp_here(self, reason: str) -> None:
        """The last resort where the child cannot: damping packets from this process's copy of the socket."""
        if not self._reason.value:
            self._reason.value = str(reason).encode()[:REASON_BYTES - 1]
        self._phase.value = PHASES.index("damp")
        damping_burst(self.link, self.safety_settings)
        self.failed.set()

    def _receive(self) -> None:
        """The ticks and messages from the child, in order; ``on_tick`` for each tick."""
        while True:
            try:
                item = self._outbox.get(timeout=0.5)
            except queue.Empty:
                if self._proc is not None and not self._proc.is_alive():
                    break
                continue
            except (EOFError, OSError):
                break
            kind = item[0]
            if kind == "tick":
                _, now, packed, q_sent, mode, run_servo, would, busy = item
                state = None if packed is None else StateSample.unpack(packed)
                q_sent = None if q_sent is None else np.frombuffer(q_sent)
                would = None if would is None else np.frombuffer(would)
                if self._last_t is not None:
                    self.periods.append(now - self._last_t)
                self._last_t = now
                self.busy.append(busy)
                self.run_servo = run_servo
                if state is not None:
                    self.state, self.state_time = state, now
                if would is not None:
                    self.would_send.append((now, would))
                if self.on_tick is not None:
                    try:
                        self.on_tick(now, state, q_sent, mode)
                    except Exception as exc:  # noqa: BLE001 - as the thread relay: a recorder failure damps
                        self.damp(f"recorder failed: {type(exc).__name__}: {exc}")
            elif kind == "message":
                with self._lock:
                    self.messages.append(item[1])
            elif kind == "stopped":
                self.scheduling = item[1]
                if item[2]:
                    with self._lock:
                        self.messages.append(item[2])
                break
        if not self.failed.is_set() and self._proc is not None and not self._proc.is_alive() \
                and self._proc.exitcode not in (0, None):
            self._damp_here(f"the relay process ended (exit code {self._proc.exitcode})")
        self._stopped.set()
