"""The closed loop of the paper's Algorithm 1: plant, MPOPI planner and the MHE thread.

:func:`run_task` runs one task on a plant:

* the **plant** (:class:`~amhe_cli.plants.base.Plant`) is measured and commanded
  through one interface: the sim plant (:class:`~amhe_cli.plants.sim.SimPlant`,
  its own MuJoCo model with the true parameters and a 2 ms step; task events
  act on it only) or a Go1 (:class:`~amhe_cli.plants.go1.plant.Go1Plant`,
  always on the wall clock);
* the **planner** (:class:`~amhe_cli.control.planner.Planner`) has its own model at a
  10 ms step and sees the plant only through its measured state;
* the **estimator** (:class:`EstimatorThread`) runs the MHE of ``mhe-replay``
  in a thread of its own over the plant's recording and swaps each new estimate
  into the planner between cycles, never blocking it.

Modes differ only in the planner's parameters: ``true`` gets the plant's truth
(and every change of it), ``baseline`` a fixed belief, ``adaptive`` the same
belief and then the MHE's estimates.

On the wall clock a plan arrives ``compute time`` after the state it was
computed from, while the last plan runs on: the loop plans from the planner
model's prediction of the state at the expected arrival (an average of the
recent compute times), after those rows, and the plan starts there (its
``lead``).

Timing of the sim plant (a real robot never waits): by default it waits for the
planner (lock-step; reproducible for a seed — the MHE's update for the window ending at ``t`` is applied at
``t + every`` in plant time, the thread computing it meanwhile). With
``realtime`` the plant runs on for as long as each planner cycle took (with the
previous plan's later targets, as a real robot would), and an estimate is used
as soon as the thread has it; an update due while the last one still runs is
skipped and logged.

On the wall clock the objects made before the loop (every module, a GPU backend's kernels: half a million with
MuJoCo Warp) are frozen out of the garbage collector (:func:`gc.freeze`, not collected first) for the loop's length:
a full pass over them held the planner's whole process 0.24–0.32 s mid-run, in 4 of 64 GPU clients traced by
:class:`~amhe_cli.control.stall_watch.StallWatch` (docs/evaluation.md, stop 77).
"""

from __future__ import annotations

import csv
import gc
import json
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from amhe_cli.estimation.belief import Belief
from amhe_cli.io.plain import to_plain
from amhe_cli.errors import AmheError, check_names
from amhe_cli.io.quat import quat_to_yaw
from amhe_cli.io.writer import write_mcap
from amhe_cli.estimation.mhe import FILL_MAX, MHESettings, MovingHorizonEstimator, Update
from amhe_cli.estimation.mhe import rested as mhe_rested
from amhe_cli.model.params import ParameterSpace
from amhe_cli.plants.base import Plant, PlantFailure
from amhe_cli.plants.sim import SimPlant
from amhe_cli.io.truth import TRUTH_RECORD
from amhe_cli.control.gait import GAITS
from amhe_cli.io.view import belief_message
from amhe_cli.control.planner import Planner, PlannerSettings
from amhe_cli.control.stall_watch import AFTER as STALL_AFTER, PERIOD as STALL_PERIOD, StallWatch
from amhe_cli.control.reflex import FallReflex, ReflexSettings, fallen, recovery_command, trunk_tilt
from amhe_cli.control.robot_side import (READ_EVERY, READ_FROM, READ_SAMPLES, READ_WINDOW, RobotSide, follow,
                                         read_robot, robot_side, write_robot)
from amhe_cli.model.rollout import default_threads
from amhe_cli.model.scene import Scene, SceneConfig, torque_limit
from amhe_cli.control.tasks import Task
from amhe_cli.io.smoothing import preload as preload_smoothing
from amhe_cli.io.trajectory import Trajectory

MODES = ("true", "baseline", "adaptive")
#: Parameters a belief gives the planner.
RUN_PARAMS = ("box_mass", "box_inertia", "box_friction")
#: Parameters the online MHE frees by default (as ``mhe-replay``); the inertia follows the mass.
#: Pushing a box straight hardly excites its inertia, and three more free coordinates made
#: every update noisier in mass and friction.
MHE_PARAMS = ("box_mass", "box_friction")
#: The run's log line as each flag of :meth:`~amhe_cli.control.tasks.Task.command` comes on.
COMMAND_NOTES = {"beside": "the box is beside the robot, not ahead: turning to face the push first",
                 "clearing": "too near the box to turn on the spot, stepping clear of it first"}
#: Longest latency compensation on the wall clock [s]: a planner slower than this is
#: better off replanning from the measured state than from a long open-loop prediction.
MAX_LEAD = 0.15
#: Slowest replanning rate [Hz] trusted on the wall clock, and the planner cycles it is judged over at the start
#: (or the cycles of its first ``RATE_CHECK_SECONDS`` of plant time, at least 5, if the planner is slower still).
#: In the sim a lock-step loop replanning every 70 ms fell or missed in 2 of 3 runs where one replanning every
#: 20 ms reached the goal in 3 of 3; the emulated Go1 runs that stayed up replanned at 23-30 Hz.
MIN_REALTIME_HZ, RATE_CHECK_CYCLES, RATE_CHECK_SECONDS = 15.0, 20, 2.0
#: Largest share of wall time the MHE thread may be busy on a wall-clock plant where it shares the
#: planner's CPUs: an update due sooner after the last one than this allows waits for the next slot.
#: Updates that ran back to back took a core from the planner's rollouts (T1 on the Go1 emulator,
#: 2 cores: planner 74 ms a cycle with the MHE, 50 ms without).
MHE_DUTY = 0.5
#: CPUs from which the wall clock's MHE gets a core of its own by default (``RunSettings.mhe_cores``).
#: On the emulated Go1 with 4 CPUs per client (Adaptive, T1/T3/T4, :data:`~amhe_cli.estimation.mhe.REALTIME_MHE`)
#: the planner on the other 3 replanned at 17–34 Hz and the runs fell 5 times in 70; with the MHE on half a
#: shared core 8 times (with ``mhe-replay``'s heavier updates, 22–57 of them deferred a run even on a core of
#: their own). A second core of its own left the planner 2 and 20 Hz: 4 falls in 30 (docs/evaluation.md).
#: Below 4 CPUs a core is too dear to the planner: on a 2-CPU client with the MHE on one, it replanned at 9–15 Hz.
OWN_CORE_FROM = 4
#: Box edge lengths of the task scenes [m] (the public Go1 box-pushing box).
TASK_BOX_SIZE = (0.38, 0.38, 0.38)


class EstimatorThread:
    """The MHE in a background thread: submit a window, collect the estimate later.

    Args:
        mhe: the estimator (its own rollout pool).

    An exception inside an update is caught: the last good estimate stays, and
    :attr:`errors` records it. The controller is never blocked unless it asks
    to :meth:`wait` (lock-step). Line decisions on a thread of their own
    (:attr:`MovingHorizonEstimator.concurrent`) reach the controller through
    :meth:`poll_decision`, as soon as they finish, not at the next window.
    """

    def __init__(self, mhe: MovingHorizonEstimator):
        self.mhe = mhe
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._result: Update | None = None
        self.errors: list[str] = []
        self.compute_time = 0.0  # wall time of the last finished update [s]
        self.finished_at = -np.inf  # time.monotonic() when it finished
        self._last: Update | None = None  # the last informative update handed out
        self._decided = 0  # the estimator's decisions on their own thread that the updates handed out carry

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def rested(self, duty: float) -> bool:
        """Idle long enough since the last update that starting one now keeps the thread's busy
        share of wall time at most ``duty`` (0 < duty <= 1)."""
        return not self.busy and mhe_rested(time.monotonic() - self.finished_at, self.compute_time, duty)

    def submit(self, traj: "Trajectory | Callable[[], Trajectory]", t: float) -> bool:
        """Start an update over ``traj`` up to ``t`` [s]; False (nothing started) while one still runs.

        ``traj`` may be a callable that gives the data: it is then called on the estimator's thread, not the
        caller's (a robot plant's :meth:`~amhe_cli.plants.base.Plant.trajectory` resamples and smooths the
        motion capture of the span the line decisions read, 50 ms for 8 s of a Go1 run on this project's 2-core
        machine, every update: on the control loop, a planning cycle lost twice a second). A failure there is
        an update's failure (:attr:`errors`)."""
        if self.busy:
            return False

        def work():
            t0 = time.monotonic()
            try:
                res = self.mhe.update(traj() if callable(traj) else traj, t)
            except Exception as exc:  # noqa: BLE001 - the controller must survive any estimator failure
                with self._lock:
                    self.errors.append(f"t={t:.2f} s: MHE update failed ({type(exc).__name__}: {exc}); "
                                       "keeping the last estimate")
                return
            finally:
                self.finished_at = time.monotonic()
                self.compute_time = self.finished_at - t0
            with self._lock:
                self._result = res

        self._thread = threading.Thread(target=work, name="amhe-mhe", daemon=True)
        self._thread.start()
        return True

    def take_errors(self) -> list[str]:
        """Errors recorded since the last call (the updates', then the line decisions' on their own thread)."""
        with self._lock:
            out, self.errors = self.errors, []
        return out + self.mhe.take_decision_errors()

    def poll(self, wait: bool = False) -> Update | None:
        """The finished update not yet collected (None if none), with the newest split a line decision
        published (:meth:`MovingHorizonEstimator.stamp`); ``wait`` blocks until the running one ends."""
        if wait and self._thread is not None:
            self._thread.join()
        with self._lock:
            res, self._result = self._result, None
        return None if res is None else self._hand_out(res)

    def poll_decision(self) -> Update | None:
        """The last informative update again, stamped with the split of a line decision that finished on its
        own thread since it was handed out; None where none did (or no update was informative yet)."""
        if self.mhe.decided == self._decided or self._last is None:
            return None
        return self._hand_out(self._last)

    def _hand_out(self, res: Update) -> Update:
        if res.skipped:  # the planner takes nothing from it: a decision finished meanwhile waits for poll_decision
            return res
        self._decided = self.mhe.decided
        mean, std = self.mhe.stamp(res.mean, res.std)
        self._last = replace(res, mean=mean, std=std)
        return self._last

    def close(self) -> None:
        if self._thread is not None:
            self._thread.join()
        self.mhe.close()


@dataclass
class RunSettings:
    """Settings of one closed-loop run.

    Attributes:
        mode: ``true``, ``baseline`` or ``adaptive``.
        realtime: run the plant on the wall clock (see module docstring).
        planner: :class:`~amhe_cli.control.planner.PlannerSettings`.
        mhe: :class:`~amhe_cli.estimation.mhe.MHESettings` of the estimator thread.
        cycle: plant time per planner cycle in lock-step [s] (multiple of the
            planner's dt); in realtime mode the planner's own compute time.
        seed: seeds the planner's and the estimator's sampling.
        threads: rollout threads of the planner (default: the CPUs left to it, :func:`core_split`).
        mhe_cores: cores the online MHE may keep busy on the wall clock (:func:`core_split`):
            below 1 it shares the planner's CPUs with one thread and defers updates to stay
            under that share of a core; 1 or more gives it that many threads of its own, taken
            from the planner's. None (default): one of its own on a machine of at least
            :data:`OWN_CORE_FROM` CPUs, else :data:`MHE_DUTY`. The lock-step sim ignores it.
        mhe_params: parameters the MHE frees (a subset of :data:`RUN_PARAMS`).
        reflex: the fall-prevention reflex's envelope (:class:`~amhe_cli.control.reflex.ReflexSettings`).
        kp, kd: joint PD gains of the position servos [N·m/rad], [N·m·s/rad],
            the same in plant and planner (they are the controller's command
            interface, not a plant secret). 100/4 by measurement: with the
            public 55/3 a trot reference barely lifts the feet (1.6 cm of 5)
            and does not move the base open-loop; T1 runs with 55/3 fell in
            3 of 4 tries, with 100/4 (and the default weights) in 1 of 2.
        latency: lock-step sim only: every plan takes this long [s] as if computed on the wall
            clock (the plant runs the last plan's rows meanwhile, the plan starts from the
            latency-compensated state, exactly as with ``realtime``), whatever this machine's
            speed; None (default): plain lock-step. A wall-clock loop's falls then reproduce on
            any machine, run after run (docs/fall_prevention.md#the-wall-clock).
        mhe_shadow: ``adaptive`` mode only: the online MHE runs, and its estimates are recorded
            and shown, but the planner keeps the starting belief — Baseline's control with the
            estimator's load and a watch on its estimate (check an estimator on a robot before
            trusting it; measure what running it costs the loop: docs/evaluation.md#on-the-emulated-go1).
        robot_read: read the robot's servo and motors from its own joint efforts every
            :data:`~amhe_cli.control.robot_side.READ_EVERY` s of the run (in a thread of its own on the
            wall clock) and, where they differ from what the planner models, plan for (and estimate
            with) the robot as read (:func:`~amhe_cli.control.robot_side.follow`); ``baseline`` and
            ``adaptive`` only. None (default): on the wall clock (a robot), off in the lock-step sim.
        stall_after: on the wall clock, a stall of the planner's process longer than this [s] is a warning of the
            run (a note where it held the set-up before the loop), with every thread's stack at the time written to
            :func:`run_task`'s ``stall_file``
            (:class:`~amhe_cli.control.stall_watch.StallWatch`); None: not watched. The lock-step sim ignores it.
    """

    mode: str = "adaptive"
    realtime: bool = False
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    mhe: MHESettings = field(default_factory=MHESettings)
    cycle: float = 0.02
    seed: int = 0
    threads: int | None = None
    mhe_cores: float | None = None
    kp: float = 100.0
    kd: float = 4.0
    mhe_params: tuple = MHE_PARAMS
    reflex: ReflexSettings = field(default_factory=ReflexSettings)
    latency: float | None = None
    mhe_shadow: bool = False
    robot_read: bool | None = None
    stall_after: float | None = STALL_AFTER

    def check(self) -> None:
        if self.mode not in MODES:
            raise AmheError(f"unknown mode {self.mode!r}: expected one of {', '.join(MODES)}")
        if self.mhe_shadow and self.mode != "adaptive":
            raise AmheError(f"mhe_shadow runs the online MHE beside a fixed belief: it needs mode adaptive, "
                            f"not {self.mode}")
        check_names(self.mhe_params, RUN_PARAMS, "MHE parameter")
        if not self.mhe_params:
            raise AmheError(f"mhe_params is empty: expected some of {', '.join(RUN_PARAMS)}")
        self.planner.check()
        self.mhe.check()
        self.reflex.check()
        if self.mhe_cores is not None and not (0 < self.mhe_cores <= 64 and
                                               (self.mhe_cores < 1 or float(self.mhe_cores).is_integer())):
            raise AmheError(f"mhe_cores {self.mhe_cores}: expected a share of one core in (0, 1) "
                            "or a whole number of cores")
        if self.robot_read and self.mode == "true":
            raise AmheError("robot_read follows a robot unlike its model, and mode true plans with the plant's "
                            "truth: use mode baseline or adaptive")
        if self.stall_after is not None and not STALL_PERIOD < self.stall_after <= 10:
            raise AmheError(f"stall_after {self.stall_after} s: expected a time in ({STALL_PERIOD:g}, 10] s, "
                            "or none to not watch the planner's process")
        if self.cycle < self.planner.dt - 1e-12:
            raise AmheError(f"cycle {self.cycle} s is shorter than the planner's dt {self.planner.dt} s")
        if self.latency is not None:
            if self.realtime:
                raise AmheError("latency emulates the wall clock in the lock-step sim: a run on the wall clock "
                                "(--realtime, --target go1) has its own")
            if not 0 < self.latency <= MAX_LEAD:
                raise AmheError(f"latency {self.latency} s: expected a planner compute time in (0, {MAX_LEAD}] s")


@dataclass
class RunResult:
    """Outcome of one run (paper §V metrics).

    Attributes:
        success: the box ended within ``task.success_radius`` of the goal and the robot never fell.
        e_g: final goal error [m].
        J: mean task running cost of the executed trajectory, per control cycle.
        t_exec: time until the box reached ``task.goal_tol`` of the goal, else the run's length [s].
        rmse: RMS error of the base's forward speed to the commanded speed [m/s].
        fell: the trunk dropped below ``task.fall_height`` over the floor or tilted beyond ``task.fall_tilt``.
        recoveries: times the fall-prevention reflex stopped the task to recover the stand.
        control_hz: planner cycles per wall-clock second (plant stepping included).
        plan_times: (cycles,) wall time of each planner cycle [s].
        traj: the plant's recording (2 ms grid), truth series in ``meta``.
        estimates: (t [s], (n, d) physical values, (n, d) std) of the planner's
            parameters each time they changed (t = plant time of the swap); with
            ``mhe_shadow``, the MHE's estimates, which the planner did not take.
        labels: (d,) labels of the estimate columns.
        messages: the run's log (plant events, phase changes and all of ``warnings``).
        warnings: the messages a user should see: a fall, a lost box, estimator failures.
        failure: why the plant stopped early (a safety trip, a lost link), else None.
        extras: the plant's raw streams (:meth:`~amhe_cli.plants.base.Plant.extras`), recorded beside the trajectory.
        side: the robot side the planner and the MHE modelled at the run's end
            (:class:`~amhe_cli.control.robot_side.RobotSide`; one read mid-run, ``robot_read``, replaces the first).
        decision_jobs: on the wall clock with ``mhe: {attribute: true}``, each change test or line decision the MHE
            ran on its own thread (:attr:`MovingHorizonEstimator.jobs
            <amhe_cli.estimation.mhe.MovingHorizonEstimator.jobs>`): ``(t, started, ended, batches, what)``, the
            window's end [s], when the job started and ended [s after that window's update began, which is
            about ``t`` on the plant's clock], its GPU batches (None off a GPU) and ``test``, ``failed`` or the
            decision's reason; empty otherwise.
        stalls: on the wall clock, each stall of the planner's process in the loop longer than ``stall_after``
            (:class:`~amhe_cli.control.stall_watch.StallWatch`): ``(t, length)``, its start on the plant's clock [s]
            and its length [s].
    """

    success: bool
    e_g: float
    J: float
    t_exec: float
    rmse: float
    fell: bool
    control_hz: float
    traj: Trajectory
    estimates: tuple
    labels: list
    messages: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    box_path: np.ndarray | None = None
    speed: np.ndarray | None = None
    plan_times: np.ndarray | None = None
    failure: str | None = None
    extras: dict = field(default_factory=dict)
    recoveries: int = 0
    side: RobotSide | None = None
    decision_jobs: list = field(default_factory=list)
    stalls: list = field(default_factory=list)

    def metrics(self) -> dict:
        """The JSON object ``amhe run --json`` prints (``failure`` only when the plant failed; ``mhe_jobs``, the
        :attr:`decision_jobs`, and ``stalls``, :attr:`stalls`, only where there were any)."""
        out = {"success": bool(self.success), "e_g": self.e_g, "J": self.J, "t_exec": self.t_exec,
               "rmse": self.rmse, "fell": bool(self.fell), "recoveries": int(self.recoveries)}
        if self.failure is not None:
            out["failure"] = self.failure
        if self.decision_jobs:
            out["mhe_jobs"] = [[round(t, 3), round(a, 3), round(b, 3), n, what]
                               for t, a, b, n, what in self.decision_jobs]
        if self.stalls:
            out["stalls"] = [[round(t, 3), round(d, 3)] for t, d in self.stalls]
        return out


def task_scene_config(task: Task, dt: float, kp: float | tuple = 55.0, kd: float | tuple = 3.0,
                      trunk_payload: float = 0.0, torque_limit: tuple | None = None) -> SceneConfig:
    """Scene of a task at timestep ``dt``: uniform floor, the task's box (nominal mass from its truth), PD gains
    (one for every joint, or (12,)), a trunk payload [kg] and (12,) motor torque limits [N·m] (None: the
    model's) — a robot unlike the model: :mod:`robot_side`."""
    kp, kd = (tuple(float(x) for x in np.broadcast_to(np.asarray(g, dtype=float), (12,))) for g in (kp, kd))
    return SceneConfig(box_size=TASK_BOX_SIZE, box_mass=float(task.truth.get("box_mass", 3.7)), timestep=dt,
                       kp=kp, kd=kd, trunk_payload=float(trunk_payload), torque_limit=torque_limit)


def make_plant(task: Task, kp: float, kd: float, control_period: float = 0.01, realtime: bool = False,
               cycle: float = 0.02) -> SimPlant:
    """The task's sim plant (2 ms, true parameters and events, PD gains ``kp``/``kd``), the robot standing
    at the origin and the box at its start; each target is held ``control_period`` [s]; lock-step runs
    ``cycle`` [s] of each plan, ``realtime`` runs on the wall clock (see :class:`~amhe_cli.plants.sim.SimPlant`)."""
    plant = SimPlant(task_scene_config(task, 0.002, kp, kd), truth=task.truth, record_dt=0.002,
                     control_period=control_period, events=task.events, realtime=realtime, cycle=cycle)
    plant.reset(*plant.scene.standing_state(box_xy=task.box_start))
    return plant


def make_estimator(task: Task, settings: "RunSettings", record_dt: float, prior: dict, prior_std: dict | None = None,
                   nthread: int = 1, duty: float = 1.0, side: RobotSide | None = None) -> MovingHorizonEstimator:
    """The online MHE of an ``adaptive`` run (paper §IV-A): the task's scene on the plant's recording grid
    ``record_dt`` [s], ``settings.mhe_params`` free around ``prior`` (name -> value; ``prior_std`` name ->
    σ, None: the nominal σ), ``settings.mhe`` seeded with the run's seed, ``nthread`` rollout threads and
    ``duty``, the share of a core :func:`core_split` gives it (what ``MHESettings.fill`` sizes updates to);
    the robot's servo, payload and torque limits ``side`` (:func:`~amhe_cli.control.robot_side.robot_side`;
    None: nominal).
    """
    side = side or robot_side(settings.kp, settings.kd)
    scene = Scene(task_scene_config(task, record_dt, side.kp, side.kd, side.trunk_payload, side.torque_limit))
    space = ParameterSpace(scene, free=settings.mhe_params, prior=prior, prior_std=prior_std)
    mhe = MovingHorizonEstimator(scene, space, replace(settings.mhe, seed=settings.seed), nthread=nthread)
    mhe.duty = duty
    return mhe


def _belief_std(belief: Belief | None) -> dict | None:
    return None if belief is None else {k: v for k, v in belief.std.items() if v and k in RUN_PARAMS}


def _to_planner(update: Update, mspace: ParameterSpace, space: ParameterSpace) -> tuple[np.ndarray, np.ndarray]:
    """An MHE update in the planner's coordinates: (d,) values and stds (0 where the MHE holds it fixed)."""
    values = space.vector(mspace.values(update.mean))
    std = np.zeros(space.dim)
    for name, sl in mspace.slices().items():
        std[space.slices()[name]] = update.std[sl]
    return values, std


def core_split(settings: "RunSettings", clocked: bool, cpus: int | None = None) -> tuple[int | None, int, float]:
    """How a run's CPUs are shared between the planner and the online MHE (``RunSettings.mhe_cores``).

    Args:
        clocked: the run is on the wall clock (a robot, ``--realtime``); in lock-step the MHE's time
            is not the planner's, and it keeps one thread.
        cpus: the CPUs this process may use (default: its affinity).
    Returns:
        (planner rollout threads, None for all CPUs; MHE rollout threads; MHE duty: the largest share
        of wall time the estimator thread may be busy, 1 where it has cores of its own).
    Raises:
        AmheError: ``mhe_cores`` would leave the planner no CPU.
    """
    s = settings
    if not clocked or s.mode != "adaptive":
        return s.threads, 1, 1.0
    cpus = cpus or default_threads()
    cores = s.mhe_cores if s.mhe_cores is not None else 1 if cpus >= OWN_CORE_FROM else MHE_DUTY
    if cores < 1:
        return s.threads, 1, cores
    own = int(cores)
    if s.threads is None and cpus <= own:
        raise AmheError(f"mhe_cores {own} leaves the planner none of the {cpus} CPU(s) this process may use: "
                        f"expected fewer than {cpus}, or a share of one core below 1")
    return (s.threads or cpus - own), own, 1.0


def describe_split(settings: "RunSettings", clocked: bool, cpus: int | None = None) -> str:
    """One line on :func:`core_split`'s answer, as the run's log and ``run --target go1`` state it.

    Raises:
        AmheError: as :func:`core_split`.
    """
    cpus = cpus or default_threads()
    planner_threads, mhe_threads, duty = core_split(settings, clocked, cpus)
    text = ("the planner rolls out on the GPU (planner device cuda)" if settings.planner.device == "cuda"
            else f"the planner rolls out on {planner_threads or cpus} thread(s)")
    if settings.mode != "adaptive":
        return text
    return text + ", the MHE on " + (f"{mhe_threads} core(s) of its own" if duty >= 1 else
                                     f"one thread sharing them, busy at most {duty:.0%} of a core") + " (mhe_cores)"


def make_planner(task: Task, settings: "RunSettings", belief: Belief | None, truth: dict,
                 nthread: int | None = None, side: RobotSide | None = None) -> tuple[Planner, ParameterSpace]:
    """The planner of a run and its parameter space.

    The planner's scene is the task's nominal scene at the planner's timestep;
    only its parameters depend on the mode: the plant's ``truth`` for ``true``,
    the belief's values otherwise, the robot's own side (servo, trunk payload,
    robot–box friction, torque limits) included (``side``; None: :func:`run_robot_side`). Nothing
    of the plant's model is passed.

    Raises:
        AmheError: a mode other than ``true`` without a belief.
    """
    s = settings
    if s.mode != "true" and belief is None:
        raise AmheError(f"mode {s.mode} needs a starting belief (--belief, or let run probe first)")
    side = side or run_robot_side(s, belief, truth)
    pscene = Scene(task_scene_config(task, s.planner.dt, side.kp, side.kd, side.trunk_payload, side.torque_limit))
    prior = {k: v for k, v in (truth if s.mode == "true" else belief.values).items() if k in RUN_PARAMS}
    if side.robot_box_friction is not None:
        prior["robot_box_friction"] = side.robot_box_friction
    space = ParameterSpace(pscene, free=RUN_PARAMS, prior=prior,
                           prior_std=None if s.mode == "true" else _belief_std(belief))
    return Planner(pscene, space, task, s.planner, nthread=nthread or s.threads, seed=s.seed), space


def run_robot_side(settings: "RunSettings", belief: Belief | None, truth: dict) -> RobotSide:
    """The robot side of a run's planner and MHE (:func:`~amhe_cli.control.robot_side.robot_side`): from the
    plant's ``truth`` in ``true`` mode, else from the belief."""
    if settings.mode == "true":
        return robot_side(settings.kp, settings.kd, truth=truth)
    return robot_side(settings.kp, settings.kd, belief=belief)


def measured_command(task: Task, scene: Scene, qpos: np.ndarray, t: float,
                     phase: str | None = None, clearing: bool = False) -> tuple[dict, float]:
    """The task's command (:meth:`~amhe_cli.control.tasks.Task.command`) from a measured plant state.

    Args:
        qpos: (nq,) the plant's generalized positions (``scene``'s layout); t: task time [s].
        phase: the command's phase last cycle (the push zone's hysteresis), None on the first.
        clearing: whether last cycle's command stepped clear of the box (the step's hysteresis).
    Returns:
        (command dict, the trunk's yaw [rad]).
    """
    yaw = float(quat_to_yaw(qpos[scene.base_qpos[3:]]))
    cmd = task.command(qpos[scene.base_qpos[:2]], yaw, qpos[scene.box_qpos[:2]], TASK_BOX_SIZE[0] / 2, t=t,
                       box_yaw=float(quat_to_yaw(qpos[scene.box_qpos[3:]])), phase=phase, clearing=clearing)
    return cmd, yaw


def has_fallen(task: Task, scene: Scene, qpos: np.ndarray) -> bool:
    """Whether the measured plant state (qpos (nq,)) counts as a fall by the task's ``fall_height`` [m] and
    ``fall_tilt`` [rad] (:func:`~amhe_cli.control.reflex.fallen`)."""
    return bool(fallen(qpos[scene.base_qpos[:3]], qpos[scene.base_qpos[3:]], scene.config.robot_floor,
                       task.fall_height, task.fall_tilt))


def run_task(task: Task, belief: Belief | None, settings: RunSettings | None = None,
             progress: Callable[[float], None] | None = None, plant: Plant | None = None,
             view=None, robot: Belief | None = None, stall_file: str | Path | None = None) -> RunResult:
    """Run ``task`` on a plant with the planner in ``settings.mode`` (paper Algorithm 1).

    Args:
        task: the task (start, goal, truth, events).
        belief: starting belief of ``baseline``/``adaptive`` (ignored by ``true``).
        settings: :class:`RunSettings`.
        progress: called with the plant time [s] after every cycle.
        plant: the :class:`~amhe_cli.plants.base.Plant` to drive (default: the
            task's sim plant, lock-step unless ``settings.realtime``; with ``settings.latency``
            only a sim plant made with ``realtime``, as :func:`make_plant` makes it). It is
            closed at the end, with the reason when the run failed.
        view: an :class:`~amhe_cli.io.view.View` told, each cycle, the measured state, the plan
            (mean paths, compute time, lead), the safety state of a plant that has one
            (``plant.safety_status()``), each change of the planner's belief, and every message;
            it never blocks (None: no view).
        robot: a belief whose robot side (:mod:`~amhe_cli.control.robot_side`: servo, payload, torque
            limits, robot–box friction) the planner and the MHE model instead of ``belief``'s, whose box
            they keep (None: ``belief``'s own; ``true`` mode takes the plant's truth either way).
        stall_file: on the wall clock, where every thread's stack goes at each stall of this process longer than
            ``settings.stall_after`` (appended; removed at the end if no stall came; None: stalls are warned of,
            not traced).
    Returns:
        :class:`RunResult`; ``failure`` says why a run ended early — a plant
        failure (a safety trip, a lost link), Ctrl-C, or an exception in the
        loop: the plant was closed with that reason (a robot damped) and the
        recording up to then is kept.
    Raises:
        AmheError: bad settings, a belief missing for a mode that needs one,
            ``true`` mode on a plant whose truth nobody knows, or a ``stall_file`` that cannot be opened (the plant
            is closed first).
    """
    s = settings or RunSettings()
    s.check()
    pdt = s.planner.dt
    if plant is None:
        plant = make_plant(task, s.kp, s.kd, pdt, realtime=s.realtime or s.latency is not None, cycle=s.cycle)
    elif s.latency is not None and not (isinstance(plant, SimPlant) and plant.realtime):
        plant.close("latency needs the sim plant")
        raise AmheError("latency emulates the wall clock in the sim: a robot has its own (drop the latency setting)")
    # the wall clock itself (a robot, --realtime), not the lock-step sim that emulates one with a fixed latency
    clocked = plant.realtime and s.latency is None
    floor = plant.scene.config.robot_floor
    reflex = FallReflex(s.reflex, floor=floor)
    safety_status = getattr(plant, "safety_status", None)  # a robot's safety layer, for the view
    messages: list[str] = []
    warnings: list[str] = []
    if view is None:
        from amhe_cli.io.view import View
        view = View()
    clock = [0.0]  # plant time of the current cycle [s], for the view's log

    def warn(text: str) -> None:
        messages.append(text), warnings.append(text)
        view.log(clock[0], text, "warning")

    def note(text: str) -> None:
        messages.append(text)
        view.log(clock[0], text, "info")

    failure = None
    mhe_deferred = 0
    n_decided = 0  # the MHE's line decisions already noted (MHESettings.attribute)
    mhe_steps: list[int] = []  # each informative update's step budget (MHESettings.fill)
    mhe_compute: list[float] = []  # each informative update's wall time [s]
    read_times: list[float] = []  # each read of the robot's servo and motors: wall time [s]
    estimator, planner, reader, watch = None, None, None, None
    unfreeze = False  # the objects made before the loop are out of the garbage collector's passes (module doc)
    stalls: list[tuple[float, float]] = []  # (start on the plant's clock, length) [s]: RunResult.stalls
    taken = [0.0]  # the plant time of the last take_stalls
    looping = [None]  # time.monotonic() at the loop's start: a stall before it held the set-up, not the loop

    def take_stalls(now: float) -> None:
        # the watch's stalls, dated on the plant's clock: back from now by the wall time since (a robot's clock is
        # the wall's), not before the last cycle that saw none (the realtime sim's clock runs only while it plans)
        for start, length in watch.take() if watch is not None else []:
            t0 = max(now - (time.monotonic() - start), taken[0])
            where = f"; every thread's stack then: {watch.path.name}" if watch.path is not None else ""
            if looping[0] is None or start < looping[0]:  # imports, a GPU backend's set-up: the robot stands
                note(f"t={t0:.2f} s: the set-up held the planner's process {length:.2f} s{where}")
                continue
            stalls.append((t0, length))
            warn(f"t={t0:.2f} s: the planner's process stalled {length:.2f} s (no plan, pose or estimate "
                 f"meanwhile{where})")
        taken[0] = now

    plan_times, wall0 = [], time.perf_counter()
    fell, t_reach = False, None
    costs, speeds, cmd_speeds, box_path = [], [], [], []
    try:
        if clocked and s.stall_after is not None:
            try:
                watch = StallWatch(s.stall_after, stall_file).start()
            except OSError as e:
                raise AmheError(f"stall file {stall_file}: {e.strerror}") from None
        if s.mode == "true" and plant.truth_values is None:
            raise AmheError("mode true needs the plant's true parameters, and this plant has none "
                            "(a real robot): use --mode baseline or adaptive")
        planner_threads, mhe_threads, mhe_duty = core_split(s, clocked)
        side = run_robot_side(s, robot or belief, plant.truth_values or {})
        if side.source:
            note(side.source)
        planner, space = make_planner(task, s, belief, plant.truth_values or {}, nthread=planner_threads, side=side)
        if s.mode == "adaptive":
            estimator = EstimatorThread(make_estimator(task, s, plant.record_dt, space.values(space.mean0),
                                                       _belief_std(belief), mhe_threads, mhe_duty, side))
            if clocked:  # the robot walks on while an import runs: what the MHE's windows need loads now
                preload_smoothing()
                note(describe_split(s, clocked))
                loaded = estimator.mhe.warm()  # and its line decisions' backend, not at the first decision
                if loaded:
                    # on the clock a decision (seconds on a CPU, a few GPU batches) must not hold the windows up
                    estimator.mhe.concurrent = True
                    note(f"the MHE's line decisions roll out on {s.mhe.attribute_device} (loaded in {loaded:.1f} s), "
                         "on a thread of their own beside the windows")
        read_on = s.mode != "true" and (clocked if s.robot_read is None else s.robot_read)
        if read_on:
            model_limit = torque_limit(plant.scene.model)  # the model's own, whatever the planner models
            # on the wall clock a read (the joints' last seconds and a least-squares fit: 0.1 s on an idle core,
            # up to 0.8 s beside a loaded planner on 2 cores) runs in a thread; in lock-step at its time, so a
            # run repeats
            reader = ThreadPoolExecutor(1, thread_name_prefix="amhe-robot-read") if clocked else None
    except BaseException as exc:
        plant.close(f"{type(exc).__name__}: {exc}")
        if planner is not None:
            planner.close()
        if watch is not None:
            watch.close()
        raise
    try:
        pscene = planner.scene
        v0, sd0 = space.physical(space.mean0, space.std0)
        est_t, est_v, est_s = [0.0], [v0], [np.zeros_like(sd0) if s.mode == "true" else sd0]

        def show_belief(t: float, v: np.ndarray, sd: np.ndarray, window: np.ndarray | None = None) -> None:
            truth = None
            if plant.truth_values is not None:
                truth = space.physical(space.vector({k: x for k, x in plant.truth_values.items() if k in RUN_PARAMS}))[0]
            view.belief(t, *belief_message(space.labels, v, sd, window, truth))

        def swap(values: np.ndarray, std: np.ndarray, t: float, window: np.ndarray | None = None) -> None:
            if not s.mhe_shadow:  # in shadow the estimate is only recorded and shown
                planner.set_params(values)
            v, sd = space.physical(values, std)
            est_t.append(t), est_v.append(v), est_s.append(sd)
            if view:
                show_belief(t, v, sd, window)

        if view:
            view.scene(0.0)
            view.log(0.0, f"{task.name} {s.mode}{' (MHE in shadow: the planner keeps its starting belief)' if s.mhe_shadow else ''}"
                     ": run started", "info")
            show_belief(0.0, est_v[0], est_s[0])

        sc = plant.scene
        stand = GAITS["stand"]
        rate_checked = False
        next_update = s.mhe.window
        pending = False
        phase = task_phase = None  # the command's phase as said, and the task's own (before any recovery)
        task_clearing = False  # whether the task's own command stepped clear of the box last cycle
        flags = dict.fromkeys(COMMAND_NOTES, False)  # Task.command's flags as of the last cycle
        compute_ema = None  # EMA of the planner's compute time [s]: the wall-clock plan's lead
        prev_rows, prev_start = None, 0.0  # the last plan and the plant time its row 0 was due
        forecast = None  # the last plan's predicted tilt [rad] (the reflex's forecast trigger)
        next_read, reading, mhe_side = READ_FROM, None, None  # the robot read's next time, its job, the MHE's due side
        read_failed = False  # a read that fails is said once

        def read_now():  # never raises: a read that fails leaves the robot as modelled
            t0 = time.perf_counter()
            try:
                return read_robot(plant.joint_record(READ_WINDOW), s.kp, model_limit, READ_SAMPLES), None
            except Exception as exc:  # noqa: BLE001
                return None, f"reading the robot from its joint efforts failed ({type(exc).__name__}: {exc})"
            finally:
                read_times.append(time.perf_counter() - t0)

        def take_read(answer, t: float) -> None:
            nonlocal side, mhe_side, read_failed
            read, error = answer
            if error is not None and not read_failed:
                read_failed = True
                warn(f"t={t:.2f} s: {error}; the planner keeps its robot")
            new = None if read is None else follow(side, read, s.kp, s.kd, model_limit)
            if new is None:
                return
            side = mhe_side = new
            planner.edit_models(lambda mdl: write_robot(mdl, new))
            who = "the planner and the MHE model" if estimator is not None else "the planner models"
            warn(f"t={t:.2f} s: this robot is not the one the planner modelled: {new.source}; {who} it so from now on")

        # added to what a relay thread froze at its start (Relay.start: it unfreezes all at its stop); given back
        # here only where nothing was frozen before (a relay in a process of its own freezes that process's heap)
        frozen = clocked and gc.isenabled()
        unfreeze = frozen and gc.get_freeze_count() == 0
        if frozen:  # (module doc) no pass over these objects from now on; freezing them takes microseconds, where a
            # full pass first (0.04 s on amhe's CPU path, 0.2 s with MuJoCo Warp) held the process as its loop began:
            # CI saw a relay tick judge the motion capture stale 0.15 s in, its poses not yet read
            gc.freeze()
            note(f"{gc.get_freeze_count()} objects made before the loop left out of the garbage collector's passes")
        m = plant.measure()
        looping[0] = time.monotonic()
        while m.t < task.duration - 1e-9:
            t, q, v = m.t, m.qpos, m.qvel
            clock[0] = t
            view.state(t, q)
            if safety_status is not None and view:
                view.safety(t, safety_status())
            box_xy = q[sc.box_qpos[:2]]
            cmd, yaw = measured_command(task, sc, q, t, phase=task_phase, clearing=task_clearing)
            task_phase, task_clearing = cmd["phase"], bool(cmd.get("clearing", False))
            text = reflex.update(t, q[sc.base_qpos[:3]], q[sc.base_qpos[3:]], v[sc.base_qvel[3:]], forecast)
            if text is not None:
                (warn if reflex.active else note)(f"t={t:.2f} s: {text}")
            if reflex.active:
                cmd = recovery_command(cmd, q[sc.base_qpos[:2]], yaw, hold=reflex.holding)
            if cmd["phase"] != phase:
                if phase == "push" and cmd["phase"] == "approach":
                    warn(f"t={t:.2f} s: lost the box, walking back behind it")
                elif phase is not None and cmd["phase"] == "push":
                    note(f"t={t:.2f} s: behind the box again, pushing")
                phase = cmd["phase"]
            for flag, text in COMMAND_NOTES.items():  # said as each flag comes on
                if cmd.get(flag, False) and not flags[flag]:
                    note(f"t={t:.2f} s: {text}")
                flags[flag] = cmd.get(flag, False)
            gait = stand if reflex.active else planner.gait
            state = pscene.full_state(q[None], v[None])[0]
            lead = 0.0
            if plant.realtime and compute_ema is not None:
                # latency compensation: plan from where the robot will be when the plan arrives,
                # after the last plan's rows that run meanwhile
                n = int(np.ceil(compute_ema / pdt))
                lead = n * pdt
                idx = np.round((t + pdt * np.arange(n) - prev_start) / pdt).astype(int)
                state = planner.predict(state, prev_rows[np.clip(idx, 0, len(prev_rows) - 1)])
            plan = planner.plan(state, t + lead, cmd, gait)
            forecast = plan.predicted_tilt
            compute = plan.compute_time if s.latency is None else s.latency  # what the plant waits for
            if len(plan_times):  # the first plan warms caches up: not a latency to expect
                compute_ema = min(compute if compute_ema is None else 0.7 * compute_ema + 0.3 * compute, MAX_LEAD)
            plan_times.append(plan.compute_time)
            if clocked and not rate_checked and (len(plan_times) > RATE_CHECK_CYCLES or
                                                 (t >= RATE_CHECK_SECONDS and len(plan_times) > 5)):
                rate_checked = True
                hz = 1.0 / max(float(np.median(plan_times[1:])), 1e-9)
                if hz < MIN_REALTIME_HZ:
                    warn(f"t={t:.2f} s: the planner replans at {hz:.1f} Hz on {planner.where()}, "
                         f"under the {MIN_REALTIME_HZ:g} Hz it needs on a robot: give it more cores, or fewer "
                         "planner samples (--config planner.samples)"
                         + (", or the MHE's own core back (mhe_cores: 0.5)" if estimator and mhe_duty >= 1 else ""))
            if view:
                trunk_path, box_path_pred = planner.mean_path or (None, None)
                view.plan(t, trunk_path, box_path_pred, plan.compute_time, lead, plan.predicted_tilt)
            # executed-trajectory metrics at the cycle start
            speeds.append(float(v[sc.base_qvel[:2]] @ [np.cos(yaw), np.sin(yaw)]))
            cmd_speeds.append(cmd["speed"])
            box_path.append([t, *box_xy])
            ref0 = gait.reference(t, cmd["speed"], cmd["omega"], cmd.get("reach"), cmd.get("sideways", 0.0))
            # the executed cost J measures the trunk against the waypoint itself (base None), as before the
            # planner's moving reference (Task.waypoint_reference): its figures stay comparable
            costs.append(float(task.stage_cost(q[sc.base_qpos[:3]], q[sc.base_qpos[3:]], v[sc.base_qvel[:3]],
                                               v[sc.base_qvel[3:]], q[sc.box_qpos[:3]], plan.controls[0], ref0,
                                               {**cmd, "base": None}, box_quat=q[sc.box_qpos[3:]])))
            fired = plant.execute(plan.controls, pdt, compute, lead)
            prev_rows, prev_start = plan.controls, t + lead
            for t_ev, ev in fired:
                note(f"t={t_ev:.2f} s: plant event {ev.param} -> {ev.value}")
                if s.mode == "true":
                    swap(space.vector(plant.truth_values), np.zeros(space.dim), t_ev)
            m = plant.measure()
            now = clock[0] = m.t
            if plant.armed and has_fallen(task, sc, m.qpos):
                fell = True
                warn(f"t={now:.2f} s: the robot fell (base at {m.qpos[sc.base_qpos[2]] - floor:.3f} m over the "
                     f"floor, tilted {np.degrees(trunk_tilt(m.qpos[sc.base_qpos[3:]])):.0f}°)")
                break
            if task.goal_error(m.qpos[sc.box_qpos[:2]]) <= task.goal_tol:
                t_reach = now
                break
            if estimator is not None:
                res = estimator.poll(wait=not clocked and pending and now >= next_update - 1e-9)
                fresh = res is not None  # a window's update, else perhaps a line decision's newer split
                if fresh:
                    pending = False
                else:
                    res = estimator.poll_decision()
                if res is not None and not res.skipped:
                    if fresh:
                        mhe_steps.append(res.steps)
                        mhe_compute.append(res.compute_time)
                    window = None
                    if view and res.window_mean is not None:
                        own = replace(res, mean=res.window_mean)
                        window = space.physical(_to_planner(own, estimator.mhe.space, space)[0])[0]
                    swap(*_to_planner(res, estimator.mhe.space, space), now, window)
                    tracker = estimator.mhe.tracker
                    for d in tracker.decisions[n_decided:] if tracker is not None else []:
                        if d.changed is not None:
                            note(d.describe())
                    n_decided = len(tracker.decisions) if tracker is not None else 0
                for text in estimator.take_errors():
                    warn(text)
                if mhe_side is not None and not estimator.busy:
                    estimator.mhe.edit_models(lambda mdl: write_robot(mdl, mhe_side))
                    mhe_side = None
                if now >= next_update - 1e-9:
                    # the wall clock defers an update while the last one runs or the thread rests (the planner's
                    # core share comes first); the lock-step loop waited for it above: submit never finds it busy
                    if clocked and not estimator.rested(mhe_duty):
                        mhe_deferred += 1
                    else:
                        data = partial(plant.trajectory, last=estimator.mhe.lookback + 0.01)
                        # a plant safe beside its run is read on the estimator's thread, off this loop
                        if estimator.submit(data if clocked and plant.concurrent_trajectory else data(), now):
                            pending = True
                    next_update += s.mhe.every
            if read_on:
                if reading is not None and reading.done():
                    take_read(reading.result(), now)
                    reading = None
                if now >= next_read - 1e-9 and reading is None:
                    if reader is None:
                        take_read(read_now(), now)
                    else:
                        reading = reader.submit(read_now)
                    next_read = now + READ_EVERY
            for text in plant.take_messages():
                warn(f"t={now:.2f} s: {text}")
            take_stalls(now)
            if progress is not None:
                progress(now)
    except PlantFailure as exc:
        failure = str(exc)
    except KeyboardInterrupt:
        failure = "interrupted (Ctrl-C)"
    except Exception as exc:  # noqa: BLE001 - a crash anywhere ends the run with the plant damped, the recording kept
        failure = f"{type(exc).__name__} in the closed loop: {exc}"
    finally:
        wall = time.perf_counter() - wall0
        plant.close(failure)
        planner.close()
        if estimator is not None:
            estimator.close()
        if reader is not None:
            reader.shutdown(wait=True)
        if unfreeze:
            gc.unfreeze()
        if watch is not None:
            watch.close()
            take_stalls(clock[0] + (time.perf_counter() - wall0 - wall))
    if estimator is not None and mhe_deferred:
        messages.append(f"{mhe_deferred} MHE updates deferred to keep the estimator within "
                        + (f"{mhe_duty:.0%} of a core" if mhe_duty < 1 else f"its {mhe_threads} core(s)")
                        + " on the wall clock")
    if clocked and mhe_compute:  # what the estimator's core gave it: read beside the deferrals and fill's budget
        messages.append(f"MHE updates took a median {np.median(mhe_compute):.3f} s ({min(mhe_compute):.3f}–"
                        f"{max(mhe_compute):.3f}) of the {s.mhe.every:g} s between them, {len(mhe_compute)} updates")
    decided = estimator.mhe.describe_decisions() if clocked and estimator is not None else None
    if decided:  # beside the updates: how late a decision's split reaches the planner after its data
        messages.append(decided)
    if read_times:
        messages.append(f"the robot was read from its joint efforts {len(read_times)} times, a median "
                        f"{np.median(read_times):.3f} s each ({max(read_times):.3f} at most)")
    if mhe_steps and s.mhe.fill is not None:
        messages.append(f"MHE step budget per candidate: median {int(np.median(mhe_steps))}, {min(mhe_steps)}–"
                        f"{max(mhe_steps)} over {len(mhe_steps)} updates (mhe fill {s.mhe.fill:g}: from max_steps "
                        f"{s.mhe.max_steps} up to {int(FILL_MAX * s.mhe.max_steps)})")
    if failure is not None:
        warn(f"run stopped: {failure}")
    traj = plant.recording()
    view.log(clock[0], f"{task.name} {s.mode}: run ended at t = {clock[0]:.2f} s", "info")
    if view and safety_status is not None:
        view.safety(clock[0], safety_status())  # the state it ended in: damped, as every Go1 run ends
    box_final = traj.box_pos[-1, :2] if len(traj) else np.asarray(task.box_start, dtype=float)
    e_g = task.goal_error(box_final)
    speeds, cmd_speeds = np.array(speeds), np.array(cmd_speeds)
    return RunResult(
        success=bool(e_g <= task.success_radius and not fell and failure is None), e_g=e_g,
        J=float(np.mean(costs)) if costs else float("nan"),
        t_exec=float(t_reach if t_reach is not None else (traj.t[-1] if len(traj) else 0.0)),
        rmse=float(np.sqrt(np.mean((speeds - cmd_speeds) ** 2))) if len(speeds) else float("nan"), fell=fell,
        control_hz=len(plan_times) / wall if wall > 0 else float("nan"), traj=traj,
        estimates=(np.array(est_t), np.array(est_v), np.array(est_s)), labels=list(space.labels),
        messages=messages, warnings=warnings, box_path=np.array(box_path), speed=np.stack([speeds, cmd_speeds], axis=1),
        plan_times=np.array(plan_times), failure=failure, extras=plant.extras(),
        recoveries=reflex.recoveries, side=side,
        decision_jobs=[tuple(j) for j in estimator.mhe.jobs] if clocked and estimator is not None else [],
        stalls=stalls,
    )


def save_run(result: RunResult, path, task: Task, settings: RunSettings, overwrite: bool = False,
             extra_meta: dict | None = None, more: Callable | None = None):
    """Write a run as an MCAP in the project schema, plus ``<stem>.truth.csv`` beside it.

    The MCAP holds the plant's recording (so ``identify`` and ``mhe-replay``
    read it back), the planner's parameters on ``/amhe/estimate``, the truth at
    the start (``amhe_truth`` metadata), the run settings and metrics
    (``amhe_run``) and what went wrong along the way (``amhe_run_log``). The CSV
    holds the truth over time in the columns of docs/log_schema.md#ground-truth (``t``,
    ``box_mass_kg``, ``mu_floor_at_box_center``) where the truth is known (not on a
    real robot). The plant's raw streams (``result.extras``: topic -> (t, values,
    labels), e.g. the Go1's IMU and foot forces) are written as labelled arrays; ``more`` (called
    with the open :class:`~amhe_cli.io.writer.McapLog`) adds other channels, e.g. the live view's.

    Returns:
        (mcap path, csv path or None).
    Raises:
        AmheError: a file exists and ``overwrite`` is False; or writing failed (a full disk, a folder
            gone during the run, …): then the recording is written to a fresh folder under the
            system's temporary directory and the message names it (or says that failed too).
    """
    path = Path(path)
    truth = result.traj.meta.get("truth")
    csv_path = path.with_name(path.name.split(".mcap")[0] + ".truth.csv") if truth is not None else None
    if csv_path is not None and csv_path.exists() and not overwrite:
        raise AmheError(f"{csv_path} exists: pass --force to overwrite it")
    est_t, est_v, est_s = result.estimates
    labels = [x for lab in result.labels for x in (lab, f"{lab}_std")]
    values = np.stack([est_v, est_s], axis=-1)  # (n, d, 2): value, std per label
    meta = {
        "amhe_run": {"task": json.dumps(to_plain(task.to_dict())), "mode": settings.mode, "seed": str(settings.seed),
                     "realtime": str(settings.realtime), "planner": json.dumps(settings.planner.to_dict()),
                     "mhe": json.dumps(to_plain(settings.mhe.to_dict())), "kp": str(settings.kp), "kd": str(settings.kd),
                     "metrics": json.dumps(to_plain(result.metrics())), "control_hz": str(result.control_hz),
                     **({"mhe_shadow": "true"} if settings.mhe_shadow else {}),  # the estimates were not used
                     **{k: str(v) for k, v in (extra_meta or {}).items()}},
        "amhe_run_log": {f"{i:04d}": m for i, m in enumerate(result.messages)},
    }
    if result.traj.meta.get("monotonic_t0") is not None:  # a robot's run: its t = 0 on the machine's clock
        meta["amhe_run"]["monotonic_t0"] = f"{result.traj.meta['monotonic_t0']:.6f}"
    if result.traj.meta.get("mocap_latency") is not None:  # and how late its motion capture came, as taken
        meta["amhe_run"]["mocap_latency"] = f"{result.traj.meta['mocap_latency']:.6f}"
        meta["amhe_run"]["mocap_latency_source"] = str(result.traj.meta.get("mocap_latency_source", "given"))
    if truth is not None:
        meta[TRUTH_RECORD] = {k: json.dumps(to_plain(v)) for k, v in truth.items()}
    extra = [("/amhe/estimate", est_t, values.reshape(len(est_t), -1), labels)]
    extra += [(topic, t, vals, labs) for topic, (t, vals, labs) in result.extras.items()]

    def write(path: Path, csv_path: Path | None, overwrite: bool) -> None:
        write_mcap(path, result.traj, metadata=meta, overwrite=overwrite, extra=extra, more=more)
        if csv_path is None:
            return
        ts = result.traj.meta["truth_series"]
        with csv_path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["t", "box_mass_kg", "mu_floor_at_box_center"])
            step = max(1, int(round(0.01 / result.traj.dt)))
            for i in range(0, len(ts["t"]), step):
                w.writerow([f"{ts['t'][i]:.4f}", f"{ts['box_mass'][i]:.6g}", f"{ts['box_friction'][i]:.6g}"])

    try:
        write(path, csv_path, overwrite)
    except AmheError:
        raise
    except Exception as exc:  # noqa: BLE001 - a disk full or a folder gone must not take the run with it
        def why(e: Exception) -> str:
            return getattr(e, "strerror", None) or f"{type(e).__name__}: {e}"

        spare = Path(tempfile.mkdtemp(prefix="amhe-run-")) / path.name
        try:
            write(spare, spare.with_name(csv_path.name) if csv_path else None, False)
        except Exception as exc2:  # noqa: BLE001
            raise AmheError(f"could not write {path} ({why(exc)}), nor a copy in {spare.parent} "
                            f"({why(exc2)}): the run's recording is lost") from exc
        raise AmheError(f"could not write {path} ({why(exc)}): the run's recording is in {spare} instead") from exc
    return path, csv_path
