"""Sampling-based moving horizon estimation (paper §IV-A, §IV-C, Algorithm 1 MHE-Estimate).

Every ``Δt_update`` seconds the estimator takes the last ``H`` seconds of data
(the window), and solves eq. (4)::

    p̂_t = argmin_p  Σ_k || x^r_{k+1} - x_{k+1}(p) ||²_{W_x}  +  || p - p̂⁻ ||²_{W_p}

with the paper's update: a diagonal Gaussian ``N(μ, diag σ²)`` starts at the
previous estimate ``p̂⁻``; for ``L_MHE`` iterations ``B`` candidates are drawn and
scored by the shared cost module over the window, and mean and σ move toward the
log-rank-weighted average of the lowest-cost half with learning rate ``α``; the
loop stops early once every σ is below ``σ_floor``. ``W_p = diag(1/σ_pull²)``
pulls toward ``p̂⁻`` — this is what keeps a parameter steady while the window
holds nothing that informs it (a box at rest says nothing about its mass).

The window is rolled out either in one piece (``clip=None``, the paper's
formulation) or as consecutive clips reset to the recorded states (multiple
shooting, ``clip`` seconds each); of those clips only the ones where the box moves
are rolled out, up to ``max_steps`` simulated steps per candidate, so an update
has a bounded cost whatever the window length.

:class:`MovingHorizonEstimator` holds no thread of its own: ``mhe-replay`` calls
:meth:`~MovingHorizonEstimator.update` along a recorded log, ``run`` will call it
from the estimator thread with the live buffer.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections import deque
from dataclasses import asdict, dataclass, field

import numpy as np

from amhe_cli.estimation.attribution import (CLIPS as ATTRIBUTION_CLIPS, FACTORS, LOCATE_CLIPS, LOOKBACK, MOVING_MIN,
                                             NAMES as SPLIT_NAMES, SEEK_WORK, TEST_CLIPS, SplitTracker, kept_clips,
                                             locate)
from amhe_cli.estimation.clips import ClipsHeld, join_clips, legs_hold, rest_travel, sample_clips, window_clips
from amhe_cli.estimation.cost import RolloutCost, StateWeights
from amhe_cli.estimation.fusion import WindowFusion
from amhe_cli.estimation.identify import clip_plan
from amhe_cli.errors import AmheError
from amhe_cli.model.params import ParameterSpace
from amhe_cli.model.device import make_backend
from amhe_cli.model.rollout import RolloutPool
from amhe_cli.estimation.sampling import gaussian_step
from amhe_cli.estimation.uncertainty import sensing_friction_std
from amhe_cli.model.scene import STAND_JOINTS, Scene
from amhe_cli.io.smoothing import velocity_noise
from amhe_cli.io.trajectory import Trajectory

#: Default ``W_p`` pull standard deviations per parameter (physical units; inertia as shape ratio).
DEFAULT_PULL = {"box_mass": 0.5, "box_inertia": 0.1, "box_friction": 0.05, "robot_box_friction": 0.05,
                "robot_kp": 2.0, "robot_kd": 0.2, "trunk_payload": 0.2}


#: Friction resolution [-] a clip must reach against the noise of its recorded initial velocity, in
#: :data:`CLIP_SIGMAS` standard deviations (:func:`noise_clip`).
CLIP_MU, CLIP_SIGMAS = 0.05, 2.0


def noise_clip(traj: Trajectory) -> float:
    """Shortest clip [s] over which friction shows through the noise of the box's initial velocity (0 if clean).

    A clip starts from the recorded velocity, off by σ_v (the log's measured
    velocity noise, :func:`~amhe_cli.io.smoothing.velocity_noise`); over T
    seconds that moves the box by σ_v·T, while a friction off by Δμ moves it
    by ½·Δμ·g·T². Friction shows at :data:`CLIP_MU` once
    ``½ Δμ g T² ≥ CLIP_SIGMAS · σ_v T``, i.e. ``T = 2 · CLIP_SIGMAS · σ_v / (Δμ g)``:
    0.19 s on ``noisy_b`` (σ_v 0.024 m/s through its 58 ms smoothing window).
    *Measured* there (``benchmarks/mhe_accuracy.py --sliding``, 8 seeds, worst
    friction error from 3 s after the box first slid), with the 42 ms window
    of the earlier smoothing target (σ_v 0.039 m/s): fixed 0.1 s clips 0.23,
    0.2 s 0.15, 0.3 s 0.096, 0.4 s 0.19; this rule (then 0.31 s) 0.052–0.105
    per seed (median 0.068) at 150, 300 or 600 steps, the clean mass-switch
    log unchanged; longer windows did worse (worst 0.33 with a 2 s window and
    600 steps, 0.24 with 3 s and 900; 3 s lost the mass switch in every seed).
    With the 58 ms window (:data:`~amhe_cli.io.smoothing.TARGET_VEL_SIGMA`
    0.03, chosen for ``identify`` at other sampling rates): 0.064–0.146 per
    seed at 150 steps, 0.055–0.107 at 300.
    """
    sigma_v = velocity_noise(traj.meta, "box", traj.dt)
    # the clip over which friction's resolution (``sensing_friction_std``, ∝ 1/T) falls to CLIP_MU / CLIP_SIGMAS
    return CLIP_SIGMAS * sensing_friction_std(sigma_v, 1.0) / CLIP_MU


@dataclass
class MHESettings:
    """Hyper-parameters of the estimator (paper Algorithm 1), with units.

    Attributes:
        window: ``H`` [s], length of the estimation window.
        every: ``Δt_update`` [s] between updates.
        iters: ``L_MHE``, sampling iterations per update.
        samples: ``B``, candidates per iteration.
        alpha: ``α``, learning rate of the mean/σ update (1 = jump to the elite average).
        sigma_init: σ each update starts with, in units of each parameter's nominal
            scale (``ParameterSpace.scale``, e.g. 3 kg, μ 0.5) — not of a belief's std,
            which would freeze the tracker after a confident ``identify``.
        sigma_floor: ``σ_floor`` in the same units: stop iterating once every σ is below it.
        pull: name -> σ_pull of ``W_p = diag(1/σ_pull²)`` toward ``p̂⁻``.
        clip: clip length [s] for multiple shooting, or None for one piece.
            0.1 s by measurement (benchmarks/mhe_accuracy.py, 6 seeds on a
            mass-switch log, box 4 → 6 kg at 10 s): one piece met the targets in 0/6 runs at real-time
            factor 0.38, 0.1 s clips in 4/6 at 1.12 (one thread each) — an
            open-loop second drifts on contact details the clips reset.
            On a log with pose noise the clips are longer where its velocity
            noise asks (:func:`noise_clip`, at most ``window``).
        max_steps: simulated steps per candidate per update (the most excited clips are kept).
        min_speed: box speed [m/s] below which a clip is considered at rest (uninformative).
        fuse: fuse successive window estimates into the reported one
            (:class:`~amhe_cli.estimation.fusion.WindowFusion`: a Kalman arrival
            cost per parameter with change detection). The windows still chain
            their own estimates as ``p̂⁻`` (eq. 4 as the paper has it); only
            what the estimator reports (:attr:`MovingHorizonEstimator.mean`)
            is fused. Off by default (the lock-step closed loop of Table II is
            measured without it); ``mhe-replay`` and ``run`` on the wall clock
            turn it on (:data:`REPLAY_SETTINGS`, :data:`REALTIME_MHE`).
        fill: on the wall clock, the share of the update period (``every``, times the share of a core
            the estimator is given: :attr:`MovingHorizonEstimator.duty`) an update may take. The step
            budget then follows the measured speed update by update (:meth:`MovingHorizonEstimator.budget`),
            from ``max_steps`` up to :data:`FILL_MAX` times it: more of each window rolled out where the
            core has time to spare. None (default): ``max_steps`` fixed, as offline.
        attribute: report the box's mass and friction from line decisions over seconds of data, which tell
            which of the two changed (:mod:`~amhe_cli.estimation.attribution`), instead of each window's
            own split, which motion-capture noise blurs; the windows then detect changes. Needs both free
            and a prior that holds the split (a belief). Off by default.
        seed: sampling seed.
        device: rollout backend, ``cpu``, ``cuda`` or ``auto``
            (:func:`~amhe_cli.model.device.choose_device`); None (default): the
            process's (``--device``; ``cpu`` in library use). In ``run``/``evaluate``
            configs: ``mhe: {device: cuda}``.
        attribute_device: rollout backend of ``attribute``'s line decisions alone, as ``device``; None
            (default): the windows'. A decision is large batches (on the CPU the lines, 22 candidates × 32 clips,
            then 8 refinements, and before them 23 × 48 where it seeks its change, 3–6 s of a core; on a GPU one
            batch of 62 × 32, or 63 × 80 where it seeks: 0.2–0.3 s of an H200's steps, 0.4–0.8 s a decision in
            the emulated loop) where a window is many small ones
            (faster on the CPU), and each window's change test one of 5 candidates × 16 clips
            (:meth:`~amhe_cli.estimation.attribution.SplitTracker.test`): ``cuda`` here keeps the windows on the CPU
            and sends the decisions and tests to the GPU,
            where on the wall clock each runs on a thread of its own (:attr:`MovingHorizonEstimator.concurrent`).
    """

    window: float = 1.0
    every: float = 0.5
    iters: int = 3
    samples: int = 10
    alpha: float = 0.8
    sigma_init: float = 0.15
    sigma_floor: float = 0.01
    pull: dict = field(default_factory=lambda: dict(DEFAULT_PULL))
    clip: float | None = 0.1
    max_steps: int = 150
    min_speed: float = 0.02
    fuse: bool = False
    fill: float | None = None
    attribute: bool = False
    seed: int = 0
    device: str | None = None
    attribute_device: str | None = None

    def check(self) -> None:
        """Raise :class:`AmheError` for settings that cannot work."""
        if not self.window > 0 or not self.every > 0:
            raise AmheError(f"--window {self.window} and --every {self.every} must be positive seconds")
        if self.iters < 1 or self.samples < 2:
            raise AmheError(f"--iters {self.iters} must be >= 1 and --samples {self.samples} >= 2")
        if not 0 < self.alpha <= 1:
            raise AmheError(f"--alpha {self.alpha}: expected a learning rate in (0, 1]")
        for key in ("device", "attribute_device"):
            if getattr(self, key) not in (None, "auto", "cpu", "cuda"):
                raise AmheError(f"mhe {key} {getattr(self, key)!r}: expected auto, cpu or cuda")
        if self.fill is not None and not 0 < self.fill <= 1:
            raise AmheError(f"mhe fill {self.fill}: expected the share of the update period an update may take, "
                            "in (0, 1], or null for a fixed max_steps")
        if self.clip is not None and not 0 < self.clip <= self.window:
            raise AmheError(f"--clip {self.clip}: expected 0 < clip <= window ({self.window} s), or 0 for one piece")

    def to_dict(self) -> dict:
        return asdict(self)


#: What ``amhe mhe-replay`` changes from the library's defaults, offline where it need not keep up with a
#: robot: 300 steps and 20 samples per update follow the mass switch faster (benchmarks/mhe_accuracy.py,
#: docs/reference.md), and that speed is what lets the fused estimate (``fuse``) average noisy windows
#: without losing the switch (:mod:`~amhe_cli.estimation.fusion`).
REPLAY_SETTINGS = {"max_steps": 300, "samples": 20, "fuse": True}


def replay_windows(attribute: bool, given: dict) -> dict:
    """``samples`` and ``max_steps`` of ``mhe-replay``'s windows: each of ``given`` (name -> value) that is not
    None, else :data:`REPLAY_SETTINGS`'s, or with ``attribute`` the library's, as ``run`` has them. With the
    attribution the windows only detect changes, and ``mhe-replay``'s larger windows detected them worse: on
    the four T3 ``mocap_degrade`` recordings, seeds 0–1, both bounds held from 3 s after the switch in 5 of 8
    replays against 7 of 8 with the library's (docs/evaluation.md "Line decisions on a thread of their own")."""
    base = MHESettings() if attribute else MHESettings(**{k: REPLAY_SETTINGS[k] for k in ("samples", "max_steps")})
    return {k: (given.get(k) if given.get(k) is not None else getattr(base, k)) for k in ("samples", "max_steps")}


#: The MHE on the wall clock (``run --target go1``, ``run --realtime``, a config's ``latency``), under a
#: run config's ``mhe:`` keys: the library's steps and samples, fused. Sized so an update fits the
#: estimator's core budget and every window is seen: ``mhe-replay``'s settings (20 samples, 300 steps)
#: cost four times the work, so on the emulated Go1 (4 CPUs per client, the MHE on a core of its own)
#: 22–57 of a run's updates were deferred, and replayed offline with only every sixth update run they
#: held m·μ within 10 % in 2–4 of 16 runs against 10 with every one. Measured on the emulated Go1
#: (default motion capture noise and latency, Adaptive, 70 runs of T1, T3 and T4): with the MHE's own
#: core these settings fell 5 times (S_R 83 %), ``mhe-replay``'s on half a shared core 8 times (81 %) —
#: on T1 and T4 1 against 6, on T3 4 against 2; T4's μ after its step, worst error from 3 s on, median
#: 0.23 against 0.35, but its mass 33 % against 19 % (docs/evaluation.md). No margin on the falls; taken
#: for the estimator that runs on time. The lock-step sim keeps the library's, unfused (Table II).
REALTIME_MHE = {"fuse": True}

#: Largest step budget :attr:`MHESettings.fill` may reach, as a multiple of ``max_steps``.
FILL_MAX = 4.0
#: Weight of the latest update in the running estimate of the estimator's speed (``fill``).
SPEED_EMA = 0.3
#: Line decisions on their own thread whose longest run is what a change's next provisional decision is taken to
#: take (:attr:`SplitTracker.lead`; of those that sought their change, :attr:`SplitTracker.seek_lead`): one that
#: would still run when the final one is due is not made. Those that seek their change took 0.41–1.13 s on an H200,
#: periodic ones 0.23–0.55 s (docs/evaluation.md "The final decision on 1.5 s of data"): read from the periodic
#: ones, a provisional decision that sought its change ran 0.56 s against a lead of 0.47 s, and the final one waited.
LEAD_JOBS = 4


def rested(idle: float, compute_time: float, duty: float) -> bool:
    """Whether the online estimator, idle for ``idle`` [s] since an update that took ``compute_time`` [s],
    may start the next one and keep its busy share of wall time at most ``duty`` (0 < duty <= 1).

    The wall clock's rule beside a planner (``run``: ``RunSettings.mhe_cores``), replayed offline by
    :func:`~amhe_cli.estimation.replay.replay` (``mhe-replay --realtime --duty``): an update due before
    it holds is deferred — dropped, not queued — and the next due one is tried.
    """
    return idle >= compute_time * (1.0 / duty - 1.0)


def held_by_legs(traj: Trajectory, scene: Scene, stop: int, since: float, min_speed: float) -> bool:
    """Whether a change test or line decision over ``since`` [s] to sample ``stop`` waits: a leg alone touched the
    box (:func:`~amhe_cli.estimation.clips.leg_only_touch`) in some of the clips from the span's moving starts
    (over the clips' longest horizon the box faster than ``min_speed`` [m/s], beyond the log's pose noise), and
    the others come to less than :data:`~amhe_cli.estimation.attribution.MOVING_MIN` seconds' worth, or the leg's
    outnumber them more than :data:`~amhe_cli.estimation.clips.LEGS_OUTNUMBER` to one
    (:func:`~amhe_cli.estimation.clips.legs_hold`). False where no start moves.

    Where enough of the span is a push, it does not wait, a leg's clips and all: a front foot strikes the box
    beside the pushing trunk at every stride of some pushes, and those clips carry the switch. *Measured* on an
    H200 (emulated T3 and T4, docs/evaluation.md "A leg on the box is not a push"): two T4 runs read mass changes
    of −35 % and +34 % that were not there from spans that wait here; with the clips of a leg alone left out of
    every decision instead (up to two thirds of a window's at T3's switch), both bounds held from 3 s in 11 of 16
    T3 runs (16 of 16 before), and drawn only where the box moved, in 4 of 8."""
    return _draw_or_hold(traj, scene, stop, since, 0, None, min_speed)[1]


def decision_clips(traj: Trajectory, scene: Scene, stop: int, since: float, n: int, rng: np.random.Generator,
                   min_speed: float):
    """``n`` clips of a line decision or change test (:mod:`~amhe_cli.estimation.attribution`), drawn with ``rng``
    as ``identify`` draws them (its horizons) from ``since`` [s] to sample ``stop``, starting where the box moves
    faster than ``min_speed`` [m/s]; None where not a clip's worth is in yet, or where the span waits for a leg
    alone on the box (:func:`held_by_legs`; the next update tries again)."""
    return _draw_or_hold(traj, scene, stop, since, n, rng, min_speed)[0]


def _draw_or_hold(traj: Trajectory, scene: Scene, stop: int, since: float, n: int, rng: np.random.Generator | None,
                  min_speed: float):
    """(:func:`decision_clips`, :func:`held_by_legs`) of one reading of the span's moving starts; with ``rng`` None
    only whether it is held (nothing drawn)."""
    _, horizon, _ = clip_plan(traj)
    need = MOVING_MIN / traj.dt
    held = False

    def hold(moving: np.ndarray, hi: int) -> bool:
        nonlocal held
        held = legs_hold(traj, scene, moving, hi, need)
        return held or rng is None  # without rng only whether it is held: nothing drawn

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a short span holds fewer moving starts than n: it still tells
            return sample_clips(traj, scene, n, horizon, rng, (since, float(traj.t[stop - 1])), min_speed,
                                rest_travel(traj), hold=hold), False
    except ClipsHeld:
        return None, held
    except AmheError:  # not a clip's worth in yet
        return None, False


def known_costs(Q: np.ndarray, JQ: np.ndarray, evaluate):
    """A scorer ``(B, d) candidates -> (B,) costs`` that takes each candidate's cost from ``JQ`` (the costs of the
    (M, d) candidates ``Q``, already scored on the same clips) where it is one of them, to 1e-9 relative, and
    scores the others with ``evaluate`` in one batch."""
    Q, JQ = np.asarray(Q, dtype=float), np.asarray(JQ, dtype=float)

    def score(R: np.ndarray) -> np.ndarray:
        R = np.atleast_2d(np.asarray(R, dtype=float))
        same = np.all(np.isclose(R[:, None], Q[None], rtol=1e-9, atol=0.0), axis=2)
        hit = same.any(axis=1)
        out = np.where(hit, JQ[np.argmax(same, axis=1)], np.nan)
        if not hit.all():
            out[~hit] = evaluate(R[~hit])
        return out

    return score


@dataclass
class Update:
    """One MHE update.

    Attributes:
        t: time [s] of the window's end (data up to here).
        mean: (d,) estimate ``p̂_t`` (flat coordinates of the space): the fused one
            with ``MHESettings.fuse``, else the window's.
        std: (d,) its σ: the fused σ, else that of the sampling distribution at the end.
        cost: lowest cost J (eq. 4) among the last iteration's candidates over the window (NaN if
            skipped); the updated mean itself is not rolled out again.
        iterations: iterations run (0 if skipped).
        compute_time: wall time of the update [s].
        skipped: True if the window held no informative data (estimate kept).
        window_mean: (d,) the window's own estimate (eq. 4); equals ``mean`` without fusion.
        steps: the step budget per candidate this update had (``max_steps``, or ``fill``'s).
    """

    t: float
    mean: np.ndarray
    std: np.ndarray
    cost: float
    iterations: int
    compute_time: float
    skipped: bool
    window_mean: np.ndarray | None = None
    steps: int | None = None


class MovingHorizonEstimator:
    """Re-estimates the free parameters of ``space`` over a sliding window.

    Args:
        scene: the model ``f``.
        space: free parameters; its prior mean is the starting estimate ``p̂_0``.
        settings: :class:`MHESettings`.
        weights: ``W_x``; None (default): each update's from the window's own
            sensor report (:meth:`~amhe_cli.estimation.cost.StateWeights.for_log`:
            the default weights on a clean trajectory; the measured noise added,
            and velocities differentiated from smoothed poses left out, on a
            motion-capture one such as a live Go1's).
        pool: rollout pool to share (e.g. with a planner); else one is created.
        nthread: threads of a pool created here.

    Attributes:
        mean: (d,) current estimate ``p̂`` (fused with ``settings.fuse``).
        std: (d,) its σ after the last update.
        window_mean: (d,) the last window's own estimate, the ``p̂⁻`` of the next window.
        fusion: the :class:`~amhe_cli.estimation.fusion.WindowFusion`, or None.
        tracker: the :class:`~amhe_cli.estimation.attribution.SplitTracker` (``settings.attribute``), or None;
            its ``decisions`` list the line decisions so far.
        duty: share of a core the estimator is given (1: a core of its own; ``run`` sets it from
            ``mhe_cores``): with ``settings.fill`` an update aims at ``fill · every · duty`` seconds.
        steps: step budget per candidate of the next update (:meth:`budget`).
        concurrent: with ``settings.attribute`` and a backend of the decisions' own (``attribute_device``), make
            each line decision on a thread of its own (``run`` sets it on the wall clock):
            the windows go on at their cadence meanwhile, and those that end during a decision are fused once
            it is in. Off (default): a decision is made inside the update that found it due, as offline.
        early: with :attr:`concurrent`, start a window's change test, or the decision its data make due, when its
            update starts, beside the window's solve (:meth:`_test_early`); else after the solve. Default: where
            the decisions roll out on a GPU, whose thread mostly waits on it. With the decisions on the CPU they
            would take the cores the window and the planner use: an emulated T4 run on this 2-core machine with
            ``attribute_device: cpu`` fell in 2 of 3 runs so, against 0 of 2 (and one 40° tilt trip) after the
            solve (docs/evaluation.md "A decision started with its window").
        decided: line decisions finished on their own thread so far (:attr:`concurrent`): a reader that saw
            fewer may :meth:`stamp` its last update with the newer split.
        decision_errors: failures of decisions on their own thread, one line each, not yet taken
            (:meth:`take_decision_errors`).
        decision_times: wall time [s] of each line decision made so far (:meth:`describe_decisions`).
        legs_held: change tests and line decisions that waited for a leg alone on the box (:func:`held_by_legs`).
        jobs: each test or decision run on its own thread (:attr:`concurrent`), as ``(t, started, ended,
            batches, what)``: the window's end [s]; when it started and ended, in seconds after that window's
            update began; the batches of the decisions' backend (None where it keeps no count); ``test``,
            ``failed`` or the reason of the decision it made. Where the time from a change's data to the
            planner goes.
    """

    def __init__(self, scene: Scene, space: ParameterSpace, settings: MHESettings | None = None,
                 weights: StateWeights | None = None, pool: RolloutPool | None = None, nthread: int | None = None):
        self.settings = settings or MHESettings()
        self.settings.check()
        unknown = set(self.settings.pull) - set(DEFAULT_PULL)
        if unknown:
            raise AmheError(f"unknown parameter {', '.join(sorted(unknown))} in the W_p pull")
        self.scene, self.space = scene, space
        self.weights = weights
        self._own_pool = pool is None
        self.pool = pool or make_backend(scene.model, self.settings.device, nthread)
        self._cost: RolloutCost | None = None
        # the line decisions' own backend (``attribute_device``), else they roll out on the windows' pool
        self._decide_pool = (make_backend(scene.model, self.settings.attribute_device, nthread)
                             if self.settings.attribute and self.settings.attribute_device is not None else None)
        self._decide_cost: RolloutCost | None = None
        self.rng = np.random.default_rng(self.settings.seed)
        # a decision on its own thread draws its clips from its own stream (a Generator is not thread-safe);
        # made inside the update, from the windows' stream, as offline replays always have
        self._decide_rng = np.random.default_rng([self.settings.seed, 1])
        self.concurrent = False
        self.early = self._decide_on_gpu
        self._decider: threading.Thread | None = None
        self._busy = False  # a test or decision runs on its own thread (set and cleared under _lock)
        # windows (t, mean, traj, stop, tested) that ended while one ran: fused, in order, as it ends
        self._queued: list[tuple[float, np.ndarray, Trajectory, int, bool]] = []
        # the window (traj, stop, t) whose update started while one ran (:meth:`_test_early`): its test or the
        # decision its data make due starts as that one ends, beside its solve; and the time of the window so
        # started, until its solve is in (one at most: the next window's update starts after this one's ends)
        self._early: tuple[Trajectory, int, float] | None = None
        self._started_early: float | None = None
        self._began: dict[float, float] = {}  # time.monotonic() at which the update of each recent window began
        self.jobs: list[tuple[float, float, float, int | None, str]] = []
        # the last LEAD_JOBS decisions' runs [s] on their own thread, and of those that sought their change
        self._runs: deque[float] = deque(maxlen=LEAD_JOBS)
        self._seeking_runs: deque[float] = deque(maxlen=LEAD_JOBS)
        self._sought = False  # the decision of the job running now sought its change (:meth:`_decide`)
        self._decide_edits: list = []  # model edits made during a decision, for the decisions' backend after it
        self._lock = threading.Lock()
        self._reported: tuple[tuple[float, float], tuple[float, float]] | None = None  # (mass, μ), their σ
        self.decided = 0
        self.decision_errors: list[str] = []
        self.decision_times: list[float] = []
        self.legs_held = 0
        self.mean = space.mean0.copy()
        self.std = space.scale * self.settings.sigma_init
        self.window_mean = self.mean.copy()
        self.fusion = (WindowFusion(self.mean, space.std0, self.std, space.scale, self.settings.sigma_floor,
                                    self.settings.window) if self.settings.fuse else None)
        self.tracker = None
        if self.settings.attribute:
            sl = space.slices()
            missing = [n for n in SPLIT_NAMES if n not in sl]
            if missing:
                raise AmheError(f"mhe attribute needs {' and '.join(SPLIT_NAMES)} free; {', '.join(missing)} is not")
            self.tracker = SplitTracker((sl["box_mass"].start, sl["box_friction"].start), self.mean, space.std0,
                                        self.std, self.settings.sigma_floor, self.settings.window,
                                        self.settings.every)
        pull = np.empty(space.dim)
        for name, sl in space.slices().items():
            pull[sl] = self.settings.pull.get(name, DEFAULT_PULL[name])
        self.pull_std = pull
        self.duty = 1.0
        self.steps = self.settings.max_steps
        self._step_time: float | None = None  # running estimate [s] of one step of one candidate

    def budget(self, compute_time: float, simulated: int) -> int:
        """Step budget per candidate for the next update, from the last one (``settings.fill``).

        An update that simulated ``simulated`` steps (per candidate, over all its iterations) in
        ``compute_time`` [s] updates the running time per step (weight :data:`SPEED_EMA`); the budget is
        then the steps that ``iters`` iterations can take in ``fill · every · duty`` seconds, clipped to
        ``[max_steps, FILL_MAX · max_steps]``. The time per step is charged with everything else the
        update did, so the budget errs short. Without ``fill`` it stays ``max_steps``.
        """
        s = self.settings
        if s.fill is None or simulated <= 0 or not compute_time > 0:
            return self.steps
        per_step = compute_time / simulated
        self._step_time = per_step if self._step_time is None else (
            (1 - SPEED_EMA) * self._step_time + SPEED_EMA * per_step)
        steps = s.fill * s.every * self.duty / (s.iters * self._step_time)
        self.steps = int(np.clip(steps, s.max_steps, FILL_MAX * s.max_steps))
        return self.steps

    @property
    def lookback(self) -> float:
        """Seconds of data before ``t`` an :meth:`update` reads: the window, or with ``settings.attribute``
        the span its line decisions score (:data:`~amhe_cli.estimation.attribution.LOOKBACK`)."""
        return max(self.settings.window, LOOKBACK if self.tracker is not None else 0.0)

    def decision_batches(self) -> list[tuple[int, int]]:
        """``(candidates, clips)`` of each kind of batch the tests and decisions roll out at full size on a GPU
        backend of their own (:meth:`warm` sets each up): a change test, a test that also seeks its change, a
        change's location, the lines with the points between them (:meth:`SplitTracker.between`), and both at
        once (:meth:`_decide`)."""
        lines = 2 * FACTORS.size
        refined = lines + 4 * (FACTORS.size - 1)
        return [(5, TEST_CLIPS), (5 + lines, TEST_CLIPS + LOCATE_CLIPS), (lines + 1, LOCATE_CLIPS),
                (refined, ATTRIBUTION_CLIPS), (refined + 1, LOCATE_CLIPS + ATTRIBUTION_CLIPS)]

    def warm(self, steps: int | None = None, slots: bool = True) -> float:
        """Load the line decisions' own backend now (``attribute_device``), not at the first decision.

        On ``cuda`` the first rollout loads MuJoCo Warp's kernels (seconds from Warp's cache, minutes the first
        time). Left to a run's first decision, that load held the estimator thread mid-run: on an emulated T3
        (H200) the first decision took 5.9 s, 4.8 s of it the kernels, and no window ran for 6.5 s, across the
        mass switch, which the windows then never told apart from noise. Each width a GPU backend keeps a slot
        for (its device model and data, and the captured step) is then set up too (:meth:`decision_batches`),
        so the first change test that seeks a change, usually at the change itself, does not set one up on the
        way to the planner. Each is rolled out ``steps`` steps (default: a clip's longest, 0.2 s) from the robot
        standing beside the box at the current mean, its results dropped. With ``slots`` off only the first batch
        runs: the kernels load, no width is set up (a backend that is closed after, as ``run --target go1`` warms
        one before it knows the robot's scene).

        Returns:
            wall time it took [s]; 0.0 without a backend of the decisions' own (they roll out on the
            windows' pool, already loaded).
        """
        if self._decide_pool is None:
            return 0.0
        t0 = time.perf_counter()
        scene = self.scene
        steps = steps or int(round(0.2 / scene.model.opt.timestep))
        x0 = scene.full_state(*scene.standing_state())
        P = self.space.project(self.mean[None])[0]
        batches = [(1, 1)] + (self.decision_batches() if self._decide_on_gpu and slots else [])  # a CPU pool: none
        for n_cand, n_clip in batches:
            self._decide_pool.rollout_candidates(self.space, np.repeat(P, n_cand, axis=0), np.repeat(x0, n_clip, 0),
                                                 np.tile(STAND_JOINTS, (n_clip, steps, 1)), np.full(n_clip, steps))
        return time.perf_counter() - t0

    def edit_models(self, edit) -> None:
        """Apply ``edit(model)`` (in place; it sets values) to the models the next updates roll out, on either
        backend: what is not an estimated parameter, such as a robot's servo read mid-run
        (:mod:`~amhe_cli.control.robot_side`). Call it between updates; during a decision on its own thread
        (:attr:`concurrent`) the decisions' backend's model copies are edited once it (and any it chains) ends."""
        self.pool.edit_models(edit, base=self.space.scene.model)
        if self._decide_pool is not None:
            with self._lock:  # no decision starts meanwhile
                if self._busy:
                    self._decide_edits.append(edit)
                else:
                    self._decide_pool.edit_models(edit, base=self.space.scene.model)

    def close(self) -> None:
        if self._decider is not None:
            self._decider.join()  # a decision in flight ends before its backend does
        if self._own_pool:
            self.pool.close()
        if self._decide_pool is not None:
            self._decide_pool.close()

    def __enter__(self) -> "MovingHorizonEstimator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def window_clips(self, traj: Trajectory, stop: int):
        """Clips of the window ending at sample ``stop`` (exclusive), or None if it is uninformative."""
        s = self.settings
        start = max(0, stop - int(round(s.window / traj.dt)))
        clip = None if s.clip is None else min(max(s.clip, noise_clip(traj)), s.window)
        clip_steps = None if clip is None else int(round(clip / traj.dt))
        return window_clips(traj, self.scene, start, stop, clip_steps, self.steps, s.min_speed,
                            rest_travel(traj))

    @property
    def deciding(self) -> bool:
        """Whether a change test or line decision runs on its own thread (:attr:`concurrent`), or the windows
        that ended during one are being taken in there."""
        return self._busy

    @property
    def _decide_on_gpu(self) -> bool:
        """Whether the decisions have a backend of their own on a GPU (``attribute_device``), where a batch costs
        its latency more than its rollouts."""
        return self._decide_pool is not None and not isinstance(self._decide_pool, RolloutPool)

    @property
    def _aside(self) -> bool:
        """Whether tests and decisions run on a thread of their own (:attr:`concurrent`, with a backend of their
        own: the windows' pool serves one thread)."""
        return self.concurrent and self._decide_pool is not None

    def _catch_up(self, queued=()) -> None:
        """Between decisions: the model edits made during the last one go to its backend, and the windows
        ``queued`` that ended meanwhile are fused, in order."""
        with self._lock:
            edits, self._decide_edits = self._decide_edits, []
        for edit in edits:
            self._decide_pool.edit_models(edit, base=self.space.scene.model)
        for q in queued:
            self.tracker.fuse(q[0], q[1])

    def _start_decider(self, traj: Trajectory, stop: int, t: float, test: bool) -> None:
        """:meth:`_test_and_decide` at the window ending at sample ``stop`` (``t`` [s]) on a thread of its own."""
        with self._lock:
            self._busy = True
        self._decider = threading.Thread(target=self._decide_aside, name="amhe-mhe-decide", daemon=True,
                                         args=((traj, stop, t, self.mean.copy(), self._decide_rng, test),))
        self._decider.start()

    def _next_job(self) -> tuple | None:
        """On the decisions' thread, as a test or decision ends: the windows that ended meanwhile fused, in order,
        and the decision they made due, or else the last one's change test (where its update did not start one),
        returned as the next job to run there now, not at the next window's update; else, where a window's update
        started meanwhile and its solve is not in (:meth:`_test_early`), its data counted and its test or the
        decision they make due, as :meth:`_test_early` would have started it. None (the thread then ends) where
        nothing is due and no window waits. Left to the next window, a decision due during another waited up to
        an update period (0.5 s) more; left to its window's solve, a final decision due during a provisional one
        waited for the solve too (0.3–0.4 s in an emulated T4 run on an H200, whose change reached the planner
        3.04 s after the step)."""
        tr = self.tracker
        while True:
            with self._lock:
                queued, self._queued = self._queued, []
                early = self._early
                if early is not None and queued and early[2] <= queued[-1][0]:
                    self._early = early = None  # its solve is in: it is taken in with its window
                if not queued and early is None:
                    self._busy = False
                    return None
            if queued:
                self._catch_up(queued)
                self._publish()
                t, _, traj, stop, tested = queued[-1]
                if tr.due() is not None or (not tested and tr.testing(t)):
                    return traj, stop, t, self.mean.copy(), self._decide_rng, not tested
            if early is not None:
                self._catch_up()
                with self._lock:  # claimed here or taken in by its window's solve (:meth:`_attribute`), not both:
                    if self._early is not early:  # a window tested twice counts as two tests in a row
                        continue  # solved meanwhile: queued, taken in as the others
                    self._early = None
                    traj, stop, t = early
                    tr.advance(t)
                    run = tr.due() is not None or tr.testing(t)
                    if run:
                        self._started_early = float(t)
                if run:
                    self._publish()
                    return traj, stop, t, self.mean.copy(), self._decide_rng, True

    def _test_early(self, traj: Trajectory, stop: int, t: float) -> bool:
        """At the start of the update of the informative window ending at sample ``stop`` (``t`` [s]), with
        decisions on a thread of their own (:attr:`concurrent`): its data counted in (:meth:`SplitTracker.advance`),
        its change test and any decision due start there now, beside the window's own solve, which needs neither
        (the test holds the reference's split, a decision the split held before its change). Started after the
        solve, as before, a decision's split reached the planner 1.5 s after its data (median, emulated T4 on an
        H200; 0.9 s with the test started here), the solve's 0.2–0.3 s among it. Returns whether it started
        (the window is then not tested again after its solve)."""
        with self._lock:
            if self._busy:  # the thread starts it as its job ends (:meth:`_next_job`), if the solve is not in
                self._early = (traj, stop, float(t))
                return False
        self._catch_up()
        self._publish()  # what this window reports while a decision runs
        tr = self.tracker
        tr.advance(t)  # its data are in: a decision they make due starts now too
        if tr.due() is None and not tr.testing(t):
            return False
        self._start_decider(traj, stop, t, True)
        return True

    def _attribute(self, traj: Trajectory, stop: int, t: float, mu: np.ndarray, tested: bool = False) -> None:
        """Feed the window (d,) ending at ``t`` [s] to the tracker (``settings.attribute``); then a change test
        of its data where no decision is due (:meth:`SplitTracker.test`), and the decision due (after it): here,
        or on a thread of its own (:attr:`concurrent`; ``tested``: :meth:`_test_early` already started its test
        there). While one runs there, the tracker is its alone: the window waits in a queue, fused in order once
        the decision is in."""
        tr = self.tracker
        with self._lock:
            if self._started_early == float(t):  # its test or decision started on the thread as another ended
                self._started_early = None
                tested = True
            if self._early is not None and self._early[2] == float(t):
                self._early = None  # solved: taken in with its window, from the queue or here
            if self._busy:
                self._queued.append((float(t), mu.copy(), traj, stop, tested))
                return
        self._catch_up()
        tr.fuse(t, mu)
        if not self._aside:
            self._test_and_decide(traj, stop, t, self.mean.copy(), self.rng)
        self._publish()
        if self._aside and (tr.due() is not None or (not tested and tr.testing(t))):
            self._start_decider(traj, stop, t, not tested)

    def _test_and_decide(self, traj: Trajectory, stop: int, t: float, base: np.ndarray,
                         rng: np.random.Generator, test: bool = True) -> None:
        """At the window ending at sample ``stop`` (time ``t`` [s]): with ``test``, a change test of its data where
        no decision is due and a change may open, then the decision due, if any (``base`` (d,) holds the other
        parameters; clips drawn with ``rng``).

        Where the last test passed (:meth:`SplitTracker.test_search_from`), this one also scores the lines
        (:meth:`SplitTracker.candidates`) on :data:`LOCATE_CLIPS` clips of the data from there, as a decision seeks
        its change (:func:`locate`), and a change it opens is placed so: its first decision follows without seeking
        it. On a GPU backend that is in the test's own batch, one dependent rollout batch fewer between the data
        and the planner; on the CPU, a batch of its own (the same costs, no rollout spent on a pairing not read). (Placed by the test's own
        candidates, ±0.2 in log, on the window's clips and those before it, a T3 mass switch sat 0.37–0.6 s early in
        5 of 6 draws on two noisy recordings, against 1 of 6 by the lines on the clips a decision draws; in the
        emulated loop its readings came 10–15 % low, docs/evaluation.md "A decision started with its window".)"""
        tr = self.tracker
        seek = True
        if test and tr.due() is None and tr.testing(t):
            clips = self._decision_clips(traj, stop, t - self.settings.window, TEST_CLIPS, rng)
            back = tr.test_search_from()
            span = None if clips is None or back is None else self._decision_clips(traj, stop, back, LOCATE_CLIPS, rng)
            T = tr.test_candidates(base)  # T[0]: the split held
            if clips is not None and span is None:
                tr.test(t, self._decision_cost(clips).evaluate(T).data)
            elif clips is not None and self._decide_on_gpu:
                # one batch, every candidate on every clip: on a GPU its latency, not its rollouts, is the cost
                both, (own, sought) = join_clips(traj, self.scene, clips, span)
                C = self._decision_cost(both).evaluate(np.vstack([T, tr.candidates(base)])).per_clip
                located = float(traj.t[both.start[sought[locate(C[len(T):, sought], C[0, sought])]]])
                seek = not tr.test(t, C[:len(T), own].sum(axis=1), located)
            elif clips is not None:  # on the CPU, each set of candidates on its own clips: no rollout wasted
                J = self._decision_cost(clips).evaluate(T).data
                C = self._decision_cost(span).evaluate(np.vstack([tr.candidates(base), T[:1]])).per_clip
                seek = not tr.test(t, J, float(traj.t[span.start[locate(C[:-1], C[-1])]]))
        due = tr.due()
        if due is not None:
            self._decide(traj, stop, t, *due, base, rng, seek)

    def _decide_aside(self, job: tuple) -> None:
        """The decisions' thread: ``job`` (:meth:`_run_job`), then each that the windows ended meanwhile make
        due (:meth:`_next_job`), until none is."""
        try:
            while job is not None:
                self._run_job(*job)
                job = self._next_job()
        except Exception as exc:  # noqa: BLE001 - taking the windows in failed: never leave the thread marked busy
            with self._lock:
                self.decision_errors.append(f"MHE line decisions: taking in the windows failed ({type(exc).__name__}: "
                                            f"{exc}); the next window's update goes on without them")
                self._queued.clear()
                self._busy = False

    def _run_job(self, traj: Trajectory, stop: int, t: float, base: np.ndarray, rng: np.random.Generator,
                 test: bool) -> None:
        """:meth:`_test_and_decide` on the decisions' thread: a failure is recorded (:attr:`decision_errors`), the
        reference kept; either way the split it leaves is published (:attr:`decided`, counted where a decision
        was made or failed, not for a test alone), and when it ran goes to :attr:`jobs`."""
        made, recorded = len(self.decision_times), len(self.tracker.decisions)
        t0, n0 = time.monotonic(), self._batches()
        self._sought = False
        failed = False
        try:
            self._test_and_decide(traj, stop, t, base, rng, test)
        except Exception as exc:  # noqa: BLE001 - the windows and the planner go on with the reference as it was
            failed = True
            with self._lock:
                self.decision_errors.append(f"t={t:.2f} s: MHE line decision failed ({type(exc).__name__}: "
                                            f"{exc}); keeping the reported mass and friction")
        finally:
            self._publish(decided=failed or len(self.decision_times) > made)
            began = self._began.get(float(t), t0)
            n1 = self._batches()
            what = ("failed" if failed else self.tracker.decisions[-1].reason
                    if len(self.tracker.decisions) > recorded else "test")
            ended = time.monotonic()
            self.jobs.append((float(t), t0 - began, ended - began, None if n0 is None or n1 is None else n1 - n0, what))
            if what in ("provisional", "change", "period"):
                # what the next provisional decision may take: none is made that would hold the final one up
                self._runs.append(ended - t0)
                if self._sought:
                    self._seeking_runs.append(ended - t0)
                tr = self.tracker
                tr.lead = max(self._runs)
                tr.seek_lead = max(self._seeking_runs) if self._seeking_runs else tr.lead * SEEK_WORK

    def _batches(self) -> int | None:
        """Batches the decisions' own backend ran so far (MuJoCo Warp's timing), None where it keeps no count."""
        tm = getattr(self._decide_pool, "timing", None)
        return None if not tm else int(tm.get("calls", 0))

    def _publish(self, decided: bool = False) -> None:
        """Make the tracker's split (and its σ) what :meth:`stamp` writes; ``decided``: one more decision in."""
        tr = self.tracker
        with self._lock:
            self._reported = (tr.ref, tr.std())
            self.decided += int(decided)

    def stamp(self, mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``mean``, ``std`` (d,) with the box's mass and friction (and their σ, floored) the tracker last
        published (``settings.attribute``), as copies; as given without it."""
        if self.tracker is None or self._reported is None:
            return mean, std
        mean, std = np.array(mean, dtype=float), np.array(std, dtype=float)
        im, iu = self.tracker.im, self.tracker.iu
        with self._lock:
            (mean[im], mean[iu]), (std[im], std[iu]) = self._reported
        floor = self.space.scale * self.settings.sigma_floor
        std[[im, iu]] = np.maximum(std[[im, iu]], floor[[im, iu]])
        return mean, std

    def take_decision_errors(self) -> list[str]:
        """:attr:`decision_errors` since the last call."""
        with self._lock:
            out, self.decision_errors = self.decision_errors, []
        return out

    def _decide(self, traj: Trajectory, stop: int, t: float, since: float, reason: str, base: np.ndarray,
                rng: np.random.Generator, seek: bool = True) -> None:
        """The line decision due at the update ending at sample ``stop`` (time ``t`` [s]) for ``reason``, over
        the data from ``since`` [s] (:meth:`SplitTracker.due`), over clips drawn as ``identify`` draws them
        with ``rng`` (:mod:`~amhe_cli.estimation.attribution`); ``base`` (d,) holds the other parameters. With
        ``seek`` off it does not seek its change first (a test just placed it). Its wall time goes to
        :attr:`decision_times`.

        On a GPU backend of their own a decision that seeks its change scores the search (the lines and the split
        held, :data:`LOCATE_CLIPS` clips from :meth:`SplitTracker.search_from`) and its lines (with the points
        between them, :data:`ATTRIBUTION_CLIPS` clips drawn from where the change sat) in one batch, every
        candidate on every clip. It keeps the costs of the lines' clips that start after the place the search gives
        the change, less :data:`~amhe_cli.estimation.attribution.SHIFT` (its jitter between decisions), and where
        that place is earlier than where they were drawn from, of the search's own clips that start between, where
        these are :data:`~amhe_cli.estimation.attribution.KEEP` of the lines' number or more
        (:func:`~amhe_cli.estimation.attribution.kept_clips`); else the lines are scored again on clips drawn from
        the new place, a second batch (before stop 80 also where it placed the change later than their first clip
        by more than ``SHIFT``; before stop 85 wherever it placed it earlier). With two
        dependent batches, each its latency, a final decision waited for a provisional one still running in three
        of 32 emulated T3 runs and reached the planner past 3 s after the switch. *Measured* (docs/evaluation.md
        "One batch a decision"): in 32 emulated T3 runs on an H200 the final decision's job took 0.49 s at the
        median (0.77 s at the worst) against 0.53 s (0.90 s) with two batches; offline, with this path on a CPU
        pool, both held the bounds in the same 6 of 8 noisy T3 replays."""
        t0 = time.perf_counter()
        tr = self.tracker
        try:
            start = tr.search_from(reason) if seek else None
            self._sought = start is not None
            known = None  # (Q, the costs of Q on ``clips``) where the seeking batch scored the lines already
            if start is not None:
                # the change sought in the data from before it showed (:func:`locate`), then decided on clips
                # drawn afresh after it (the clips that placed it favour a change, whichever there was), the
                # search's own only for data those were not drawn from (a change found earlier than it sat)
                sought = self._decision_clips(traj, stop, start, LOCATE_CLIPS, rng)
                ahead = (self._decision_clips(traj, stop, since, ATTRIBUTION_CLIPS, rng)
                         if sought is not None and self._decide_on_gpu else None)
                if ahead is not None:  # one batch: the search and the lines on clips drawn where the change sits
                    P = tr.candidates(base)
                    Q = np.vstack([P, tr.between(P)])
                    both, (own, after) = join_clips(traj, self.scene, sought, ahead)
                    C = self._decision_cost(both).evaluate(np.vstack([Q, tr.held(base)])).per_clip
                    reason = tr.relocate(float(traj.t[sought.start[locate(C[:len(P), own], C[-1, own])]]))
                    # the lines' clips that start after the change (within the search's jitter), and where it sits
                    # earlier than where they were drawn from, the search's own that start between: where enough do
                    index = kept_clips(traj.t[sought.start], traj.t[ahead.start], own, after, tr.pending[0], since)
                    if index is not None:
                        clips, known = both.subset(index), (Q, C[:-1, index].sum(axis=1))
                elif sought is not None:
                    C = self._decision_cost(sought).evaluate(np.vstack([tr.candidates(base), tr.held(base)])).per_clip
                    reason = tr.relocate(float(traj.t[sought.start[locate(C[:-1], C[-1])]]))
                since = tr.pending[0] if sought is not None else since
            if known is None:
                clips = self._decision_clips(traj, stop, since, ATTRIBUTION_CLIPS, rng)
            if clips is not None:
                cost = self._decision_cost(clips)  # (after a seeking batch: its clips replaced by the lines')
                lines = lambda R: cost.evaluate(R).data  # noqa: E731
                # a change's lines once more, re-centred, where a line's minimum is at its end (a periodic
                # decision's end stays: its data may straddle a change the windows have not confirmed)
                for retry in ((True, False) if reason != "period" else (False,)):
                    P = tr.candidates(base)
                    if known is not None:  # scored in the seeking batch (re-centred lines: a batch of their own)
                        score, known = known_costs(*known, lines), None
                        J = score(P)
                    elif self._decide_on_gpu:  # the refinements' points in the lines' batch: one batch fewer
                        Q = np.vstack([P, tr.between(P)])
                        score = known_costs(Q, lines(Q), lines)
                        J = score(P)
                    else:  # on the CPU no rollout is spent on a point not read
                        J, score = lines(P), lines
                    if tr.decide(t, reason, P, J, retry, score=score) is not None:
                        break
        finally:
            self.decision_times.append(time.perf_counter() - t0)

    def describe_decisions(self) -> str | None:
        """One line on the line decisions so far (:attr:`decision_times`; where they ran, and with a GPU backend
        of their own, where it spent its time), or None where none was made."""
        took = self.decision_times
        if not took:
            return None
        text = (f"MHE line decisions took a median {np.median(took):.3f} s ({min(took):.3f}–{max(took):.3f}), "
                f"{len(took)} decisions, each " + ("on a thread of its own" if self.concurrent else "inside its update"))
        tm = getattr(self._decide_pool, "timing", None)  # MuJoCo Warp's own timing
        if tm and tm.get("calls"):
            text += (f"; their backend: {tm['calls']} batches, steps {tm['steps']:.2f} s, candidates' fields "
                     f"{tm['fields'] + tm['upload']:.2f} s, read-back {tm['readback']:.2f} s in all")
        if self.legs_held:
            text += f"; {self.legs_held} test(s) or decision(s) held where the box moved only under a leg alone"
        return text

    def _decision_clips(self, traj: Trajectory, stop: int, since: float, n: int, rng: np.random.Generator):
        """:func:`decision_clips` of this estimator's scene and ``min_speed``; a span that waits for a leg alone on
        the box (:func:`held_by_legs`) is counted in :attr:`legs_held`."""
        clips, held = _draw_or_hold(traj, self.scene, stop, since, n, rng, self.settings.min_speed)
        self.legs_held += held
        return clips

    def _decision_cost(self, clips) -> RolloutCost:
        """The cost a line decision scores ``clips`` with: the windows' own, or with ``attribute_device`` one
        on the decisions' backend (the windows' ``W_x``)."""
        if self._decide_pool is None:
            self._cost.set_clips(clips)
            return self._cost
        if self._decide_cost is None:
            self._decide_cost = RolloutCost(self.scene, self.space, clips, self._cost.weights, pool=self._decide_pool)
        else:
            self._decide_cost.set_clips(clips, self._cost.weights)
        return self._decide_cost

    def update(self, traj: Trajectory, t: float) -> Update:
        """Re-estimate from the window of ``traj`` that ends at time ``t`` [s] (eq. 4, Algorithm 1).

        ``traj`` may be a growing buffer; only samples up to ``t`` are used.
        """
        t0 = time.perf_counter()
        self._began = {k: v for k, v in self._began.items() if k > t - LOOKBACK}
        self._began[float(t)] = time.monotonic()
        s = self.settings
        stop = int(np.searchsorted(traj.t, t, side="right"))
        steps = self.steps
        clips = self.window_clips(traj, stop)
        if clips is None:
            return Update(t, self.mean.copy(), self.std.copy(), float("nan"), 0, time.perf_counter() - t0, True,
                          self.window_mean.copy(), steps)
        weights = self.weights or StateWeights.for_log(traj)
        if self._cost is None:
            self._cost = RolloutCost(self.scene, self.space, clips, weights, pool=self.pool)
        else:
            self._cost.set_clips(clips, weights)
        # after the windows' cost is set: the decisions' takes its W_x
        tested = self.tracker is not None and self._aside and self.early and self._test_early(traj, stop, t)
        prev = self.window_mean.copy()
        self._cost.set_prior(prev, self.pull_std)
        mu = prev.copy()
        sigma = self.space.scale * s.sigma_init
        floor = self.space.scale * s.sigma_floor
        it = 0
        for it in range(1, s.iters + 1):
            P = mu + sigma * self.rng.standard_normal((s.samples, mu.size))
            P[0] = mu  # the current mean competes too
            P = self.space.project(P)[0]
            J = self._cost(P)
            mu, sigma = gaussian_step(mu, sigma, P, J, s.alpha)
            mu = self.space.project(mu)[0][0]
            if np.all(sigma <= floor):
                break
        self.window_mean = mu.copy()
        self.mean, self.std = mu, np.maximum(sigma, floor)
        # the new mean is not rolled out again just to report its cost: that call was one more
        # dependent rollout batch per update, a quarter of an update on a GPU (latency-bound)
        j = float(np.min(J))
        if self.fusion is not None:
            self.mean, self.std = self.fusion.update(t, mu), self.fusion.std
        if self.tracker is not None:
            self._attribute(traj, stop, t, mu, tested)
            self.mean, self.std = self.stamp(self.mean, self.std)
            self.std = np.maximum(self.std, floor)
        elapsed = time.perf_counter() - t0
        self.budget(elapsed, it * int(np.sum(clips.horizon)))
        return Update(t, self.mean.copy(), self.std.copy(), j, it, elapsed, False, mu.copy(), steps)
