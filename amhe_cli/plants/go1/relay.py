"""The relay: one command to the Go1 every 2 ms, through the safety layer, with its watchdogs.

The planner replans every ~0.1–0.3 s; the robot's motor loop wants a command
every 2 ms (public Go1 low-level controllers run at 500 Hz). The relay fills
the gap: a thread that, every ``period``, reads the newest robot state,
interpolates the latest plan's joint targets at the current time, passes them
through :class:`~amhe_cli.plants.go1.safety.SafetyLayer` and sends them.

Phases (:attr:`Relay.phase`)::

    wait ──state──► ramp ──2 s──► ready ──plan──► run ◄──► hold (stale plan: soft hold of the pose)
      │                                            ◄──► stand (stale mocap: hold the stand, stop pushing)
      └──state──► dry (--dry-run: damping packets only; the would-be targets are logged)
    any ──trip / no state for state_timeout / damp()──► damp (mode 0x00, terminal)

*wait* sends damping packets: there is no handshake, the robot answers the
client's first packet. *ramp* moves from the measured pose to the stand over
``ramp_time`` with a smoothstep. Every failure ends in *damp*: a tripped limit,
a silent link, or :meth:`Relay.damp` from outside (an exception in the planner
or the MHE, Ctrl-C); :meth:`Relay.stop` sends a burst of damping packets
before it returns, so a lost datagram cannot leave a servo command active.

The relay is a thread here; :class:`~amhe_cli.plants.go1.plant.Go1Plant` runs it
in a process of its own (:mod:`~amhe_cli.plants.go1.relay_process`). A thread
shares the interpreter lock: the planner's rollouts run in MuJoCo's C thread
pool without it, and with the interpreter's switch interval cut to 0.5 ms the
relay thread gets it within a fraction of its period — measured against the
emulator on a 2-core machine with the planner busy on both cores
(``benchmarks/relay_jitter.py``): period median 2.00 ms, p99 2.9 ms, max
9.6 ms. But anything that holds the lock longer holds the commands: emulated
GPU clients stalled for 60–310 ms (the GPU backend loading at the start, once
0.3 s at 45 s: the robot kept one command's joint targets mid-stride and fell),
which a process of its own does not see. The thread also asks for real-time
scheduling (:func:`raise_thread_priority`) where the OS allows it, and the heap
built before the relay started is frozen out of the garbage collector's full
passes while it runs (:meth:`Relay.start`): a full pass stops every thread of
its process (48–54 ms mid-run in a T3 client before).
"""

from __future__ import annotations

import gc
import sys
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from amhe_cli.model.scene import STAND_JOINTS
from amhe_cli.plants.go1.protocol import MODE_DAMPING, MODE_SERVO, LowCmd, LowState
from amhe_cli.plants.go1.safety import SafetyLayer, SafetyTrip

#: Command period [s] (500 Hz, as public Go1 low-level controllers).
PERIOD = 0.002
#: The interpreter's switch interval while a relay runs [s]: the default 5 ms
#: would let a busy planner thread hold the GIL for over two command periods.
SWITCH_INTERVAL = 0.0005

PHASES = ("wait", "ramp", "ready", "run", "hold", "stand", "dry", "damp")
#: Periods, work times and dry-run targets kept for statistics: the last minute at 500 Hz.
HISTORY = 30000
#: Real-time priority (SCHED_FIFO) asked for the relay thread where the OS allows it.
RT_PRIORITY = 20


def raise_thread_priority(priority: int = RT_PRIORITY) -> str:
    """Give the calling thread real-time scheduling (SCHED_FIFO), else a lower nice value, where allowed.

    A 2 ms loop must not wait behind the planner's rollout threads for a core.
    Linux applies ``sched_setscheduler(0, …)`` to the calling thread only. A
    user without the right (no root, no ``rtprio`` limit) keeps the default
    scheduler; the returned text says which one the thread got.
    """
    import os
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"SCHED_FIFO {priority}"
    except (AttributeError, OSError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), -10)
        return "nice -10"
    except (AttributeError, OSError):
        return "default scheduler (no right to raise the priority)"


def damping_burst(link, settings) -> None:
    """Send ``settings.damping_burst`` damping packets (``settings.damping_kd``) 0.5 ms apart on ``link``, so that a
    lost datagram cannot leave a servo command active; a link that fails to send ends the burst (it cannot damp)."""
    cmd = LowCmd.damping(kd=settings.damping_kd)
    for _ in range(settings.damping_burst):
        try:
            link.send(cmd)
        except Exception:  # noqa: BLE001 - a dead link cannot be damped; nothing else to do
            break
        time.sleep(0.0005)


class Relay:
    """The 2 ms command thread between the planner and the robot link.

    Args:
        link: a :class:`~amhe_cli.plants.go1.link.LowLevelLink` (or anything
            with ``send(LowCmd)`` and ``recv() -> LowState | None``).
        safety: the :class:`SafetyLayer` every command passes.
        kp, kd: servo gains of the plan and the stand [N·m/rad], [N·m·s/rad].
        dry_run: send damping packets only; keep what would have been sent in :attr:`would_send`.
        planner_period: expected planner cycle [s]; with ``safety.plan_periods``
            it sets the stale-plan watchdog (the larger of this and the
            observed plan interval counts).
        on_tick: called from the relay thread every period with
            ``(t, state or None, q_sent (12,), mode)``: ``t`` is ``time.monotonic()``,
            ``mode`` the motor mode sent (:attr:`run_servo` says whether at the run's gains). Keep it short.
        period: command period [s].
    Attributes:
        phase: current phase (:data:`PHASES`).
        run_servo: the last command was the servo at the run's gains ``kp``/``kd`` — not the stale plan's
            soft hold nor damping: its efforts are samples of the servo law a recording states.
        reason: why the relay entered ``damp`` (None until then).
        periods: measured command periods [s] (for jitter statistics; the last :data:`HISTORY`).
        busy: time each period's work took [s] (receive, check, interpolate, send, record).
        scheduling: what :func:`raise_thread_priority` got for the relay thread.
        messages: phase changes and watchdog events, time-stamped (:meth:`take_messages`).
        streaming: set once the first valid state arrived; ready: set once the ramp is done.
    """

    def __init__(self, link, safety: SafetyLayer, kp: float, kd: float, dry_run: bool = False,
                 planner_period: float = 0.25, on_tick: Callable | None = None, period: float = PERIOD):
        self.link = link
        self.safety = safety
        self.kp, self.kd = float(kp), float(kd)
        self.dry_run = dry_run
        self.planner_period = planner_period
        self.on_tick = on_tick
        self.period = period
        self.phase = "wait"
        self.run_servo = False
        self.reason: str | None = None
        self.periods: deque[float] = deque(maxlen=HISTORY)
        self.busy: deque[float] = deque(maxlen=HISTORY)
        self.messages: list[str] = []
        self.scheduling = ""
        self.would_send: deque[tuple[float, np.ndarray]] = deque(maxlen=HISTORY)
        self.state: LowState | None = None
        self.state_time = -np.inf
        self._bad_at_state = 0  # the link's invalid-packet count at the last valid state
        self._streaming = False
        self.streaming = threading.Event()
        self.ready = threading.Event()
        self.failed = threading.Event()
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()  # a command's choice and send, against an outside damp()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plan: tuple[np.ndarray, float, float] | None = None  # (controls (H, 12), dt, t0)
        self._plan_received = -np.inf
        self._plan_interval = planner_period
        self._mocap_ok = True
        self._q_prev: np.ndarray | None = None
        self._ramp_from: np.ndarray | None = None
        self._ramp_start = 0.0
        self._hold_q: np.ndarray | None = None
        self._t0 = 0.0
        self._switch = sys.getswitchinterval()

    @property
    def clamped(self) -> int:
        """Targets the safety layer clamped so far."""
        return int(self.safety.clamped)

    @property
    def bad_packets(self) -> int:
        """Invalid packets the link dropped so far (0 for a link that does not count them)."""
        return int(getattr(self.link, "bad_packets", 0))

    # -- the caller's side ----------------------------------------------------
    def start(self) -> None:
        """Start the relay thread (phase ``wait``: damping packets until the robot answers).

        Everything the process holds so far (modules, models, the planner) is
        moved out of the cyclic garbage collector's reach (``gc.freeze``) until
        :meth:`stop`: a full collection stops every thread, the relay's too, for
        as long as it walks the heap — 70 ms in a T1 run against the emulator
        before (its last full collection; a command gap past the 20–50 ms a
        robot's bridge takes for a lost link).
        """
        self._t0 = time.monotonic()
        sys.setswitchinterval(SWITCH_INTERVAL)
        gc.freeze()
        self._thread = threading.Thread(target=self._loop, name="amhe-relay", daemon=True)
        self._thread.start()

    def wait_ready(self, timeout: float) -> bool:
        """Block until the ramp to the stand is done (``dry``: until the state streams); False on timeout or trip."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.failed.is_set():
                return False
            if self.ready.wait(0.01):
                return True
        return False

    def set_plan(self, controls: np.ndarray, dt: float, t0: float) -> None:
        """Hand over a plan: row k of ``controls`` (H, 12) [rad] is the target at ``t0 + k·dt`` (``time.monotonic()``)."""
        now = time.monotonic()
        with self._lock:
            if np.isfinite(self._plan_received):
                self._plan_interval = 0.8 * self._plan_interval + 0.2 * (now - self._plan_received)
            self._plan = (np.array(controls, dtype=float), float(dt), float(t0))
            self._plan_received = now

    def set_mocap_ok(self, ok: bool) -> None:
        """Whether the motion capture is fresh enough to push (False: hold the stand)."""
        self._mocap_ok = bool(ok)

    def take_messages(self) -> list[str]:
        """Phase changes and watchdog events since the last call."""
        with self._lock:
            out, self.messages = self.messages, []
        return out

    def damp(self, reason: str) -> None:
        """Enter damping now (an error elsewhere, Ctrl-C); the first reason given is kept.

        Once this returns, the relay sends damping packets only: it waits for a command being chosen
        and sent to go out, and the relay thread's own phase changes cannot leave ``damp``.
        """
        with self._send_lock:
            self._trip(reason)

    def stop(self) -> None:
        """End the relay: damping packets (a burst), then the thread stops. Safe to call twice."""
        if self.phase != "damp":
            self._set_phase("damp")
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        damping_burst(self.link, self.safety.settings)
        sys.setswitchinterval(self._switch)
        gc.unfreeze()

    # -- the relay thread -------------------------------------------------------
    def _set_phase(self, phase: str, note: str = "") -> None:
        """Change phase; entering or leaving a fallback (hold, stand, damp) is logged in :attr:`messages`.
        ``damp`` is final: a phase change the relay thread chose before an outside :meth:`damp` does not undo it."""
        if phase != self.phase and self.phase != "damp":
            if phase in ("hold", "stand", "damp") or self.phase in ("hold", "stand"):
                self.messages.append(f"relay {self.phase} -> {phase}" + (f": {note}" if note else ""))
            self.phase = phase

    def _silence(self, now: float) -> str:
        """Why no valid state came since the last one, for the trip: packets that came and were rejected (the
        link's count and last reason: a robot or a rig sending what it should not), or none at all (link lost)."""
        bad = getattr(self.link, "bad_packets", 0) - self._bad_at_state
        why = (f"{bad} invalid packet{'s' * (bad != 1)} meanwhile, the last: {getattr(self.link, 'last_error', '')}"
               if bad > 0 else "link lost")
        return f"no valid robot state for {1e3 * (now - self.state_time):.0f} ms ({why})"

    def _trip(self, reason: str) -> None:
        with self._lock:
            if self.reason is None:
                self.reason = reason
            self._set_phase("damp", reason)
        self.failed.set()

    def _target(self, now: float, state: LowState | None) -> tuple[np.ndarray, float, float, int]:
        """(q (12,), kp, kd, mode) wanted now, before the safety layer."""
        s = self.safety.settings
        stand = STAND_JOINTS
        if self.phase == "ramp":
            u = min(1.0, (now - self._ramp_start) / s.ramp_time)
            w = u * u * (3 - 2 * u)
            if u >= 1.0:
                self._set_phase("ready")
                self.ready.set()
            return (1 - w) * self._ramp_from + w * stand, self.kp, self.kd, MODE_SERVO
        with self._lock:
            plan, received, interval = self._plan, self._plan_received, self._plan_interval
        stale = now - received > s.plan_periods * max(self.planner_period, interval)
        if self.phase in ("ready", "run", "hold", "stand"):
            if not self._mocap_ok:
                self._set_phase("stand", "motion capture stale: holding the stand")
                return stand, self.kp, self.kd, MODE_SERVO
            if plan is None:
                if self.phase == "stand":
                    self._set_phase("ready", "motion capture back")
                return stand, self.kp, self.kd, MODE_SERVO
            if stale:
                if self.phase != "hold":
                    self._set_phase("hold", f"no plan for {now - received:.2f} s: soft hold")
                    self._hold_q = state.q.copy() if state is not None else self._q_prev
                return self._hold_q, s.hold_kp, s.hold_kd, MODE_SERVO
            if self.phase != "run":
                self._set_phase("run")
            return _plan_at(plan, now), self.kp, self.kd, MODE_SERVO
        return stand, 0.0, s.damping_kd, MODE_DAMPING

    def _loop(self) -> None:
        self.scheduling = raise_thread_priority()
        s = self.safety.settings
        damping = LowCmd.damping(kd=s.damping_kd)
        next_t = time.monotonic()
        last_t = None
        while not self._stop.is_set():
            now = time.monotonic()
            if last_t is not None:
                self.periods.append(now - last_t)
            last_t = now
            asked = time.monotonic()
            try:
                state = self.link.recv()
            except Exception as exc:  # noqa: BLE001 - a broken socket is a lost link
                state = None
                self._trip(f"robot link failed: {exc}")
            # a state is stamped when received, not at the top of the period: a stall before the receive (the
            # garbage collector stopping every thread for 50 ms) delivers the states that queued meanwhile, and
            # stamping them with the stale time made the next empty receive look like 50 ms of silence. A silence
            # runs to when the socket was asked and found empty, not to after it: a stall between the two (an
            # emulated T3 run, its client loading its GPU backend at start: "no valid robot state for 59 ms" while
            # the robot streamed) delivers its states to the next receive
            received = time.monotonic()
            if state is not None:
                self.state, self.state_time = state, received
                self._bad_at_state = getattr(self.link, "bad_packets", 0)
                if not self._streaming:  # once: a shared (process) flag costs a lock each time
                    self._streaming = True
                    self.streaming.set()
                if self.phase == "wait":
                    if self.dry_run:
                        self._set_phase("dry", "state streaming; dry run: damping packets only")
                        self.ready.set()
                    else:
                        self._ramp_from, self._ramp_start = state.q.copy(), now
                        self._q_prev = state.q.copy()
                        self._set_phase("ramp", "state streaming: ramping to the stand")
                if self.phase not in ("damp", "wait"):
                    try:
                        self.safety.check(state.rpy, state.tau_est, state.dq)
                    except SafetyTrip as trip:
                        self._trip(str(trip))
            elif self.phase not in ("wait", "damp") and asked - self.state_time > s.state_timeout:
                self._trip(self._silence(asked))
            with self._send_lock:  # damp() from another thread waits for this command, then wins
                if self.phase in ("wait", "damp"):
                    cmd, q_sent, mode = damping, None, MODE_DAMPING
                else:
                    q, kp, kd, mode = self._target_dry(now) if self.phase == "dry" else self._target(now, state)
                    q, kp, kd = self.safety.filter(q, self._q_prev, kp, kd, self.period)
                    if self.dry_run:
                        self.would_send.append((now, q.copy()))
                        cmd, q_sent, mode = damping, None, MODE_DAMPING
                    else:
                        self._q_prev = q
                        cmd = LowCmd(mode=np.full(12, mode, dtype=np.uint8), q=q, dq=np.zeros(12), tau=np.zeros(12),
                                     kp=kp if mode == MODE_SERVO else np.zeros(12), kd=kd)
                        q_sent = q
                try:
                    self.link.send(cmd)
                except Exception as exc:  # noqa: BLE001
                    self._trip(f"robot link failed: {exc}")
            self.run_servo = q_sent is not None and mode == MODE_SERVO and self.phase != "hold"
            if self.on_tick is not None:
                try:
                    self.on_tick(now, state, q_sent, mode)
                except Exception as exc:  # noqa: BLE001 - a recorder failure must not stop the commands
                    self._trip(f"recorder failed: {type(exc).__name__}: {exc}")
            self.busy.append(time.monotonic() - now)
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -self.period:
                next_t = time.monotonic()  # fell behind: do not burst to catch up

    def _target_dry(self, now: float):
        """In a dry run the would-be command follows the plan (or the stand) as if armed."""
        with self._lock:
            plan = self._plan
        q = STAND_JOINTS if plan is None else _plan_at(plan, now)
        return q, self.kp, self.kd, MODE_SERVO


def _plan_at(plan: tuple[np.ndarray, float, float], now: float) -> np.ndarray:
    """(12,) targets of ``plan = (controls (H, 12), dt, t0)`` at ``now``: linear between rows, the ends held."""
    controls, dt, t0 = plan
    if len(controls) == 1:
        return controls[0]
    u = float(np.clip((now - t0) / dt, 0, len(controls) - 1))
    k = min(int(u), len(controls) - 2)
    return controls[k] + (u - k) * (controls[k + 1] - controls[k])
