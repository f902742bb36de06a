"""MPOPI: sampling-based whole-body MPC over joint-position targets (paper §III-A, §IV-B).

Each control cycle the planner

1. shifts last cycle's mean to the new time (warm start),
2. draws ``N`` sequences of joint-target *offsets* around the gait reference —
   ``K`` spline knots per joint, interpolated by a natural cubic spline over the
   horizon — and rolls them out under its own model ``f(p̂)`` through the shared
   rollout pool (:class:`~amhe_cli.model.rollout.RolloutPool`, or with ``device: cuda`` the
   MuJoCo Warp backend, :class:`~amhe_cli.model.rollout_warp.WarpRollout`),
3. scores them with the task cost (:meth:`~amhe_cli.control.tasks.Task.stage_cost`),
4. moves the mean by MPPI weighting; and **only when the gait's contact mode
   changes** it first refines mean and σ over ``L_MPOPI`` loops of the elite
   update shared with the MHE (:func:`~amhe_cli.estimation.sampling.gaussian_step`) — the
   paper's cheaper MPOPI, the last distribution warm-starting the cycles in
   between.

The planner owns its model copies: :meth:`Planner.set_params` writes a new
belief into them (the MHE thread's swap) and nothing else ever touches them; it
never sees the plant's model.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, fields

import numpy as np

from amhe_cli.errors import AmheError, check_names
from amhe_cli.control.gait import Gait
from amhe_cli.control.reflex import trunk_tilt
from amhe_cli.model.device import make_backend
from amhe_cli.model.params import ParameterSpace
from amhe_cli.model.rollout import RolloutPool
from amhe_cli.estimation.sampling import gaussian_step, mppi_weights
from amhe_cli.model.scene import Scene
from amhe_cli.control.tasks import Task


@dataclass
class PlannerSettings:
    """MPOPI hyper-parameters (defaults: the public Go1 box-pushing MPPI, docs/reference.md#planner-reference).

    Attributes:
        dt: planner model timestep [s] (coarser than the plant's).
        horizon: steps per rollout (40 × 10 ms = 0.4 s, most of a trot cycle).
        samples: ``N`` rollouts per batch (sample 0 is the mean itself).
        knots: spline knots per joint over the horizon.
        temperature: MPPI ``λ`` on spread-normalised costs (:func:`~amhe_cli.estimation.sampling.mppi_weights`).
        noise: σ of the knot offsets for (hip, thigh, calf) [rad].
        refine_loops: ``L_MPOPI`` elite-update loops at a contact-mode switch.
        refine_alpha: learning rate of those loops.
        sigma_floor: σ never falls below this fraction of ``noise``, to avoid
            collapse of the covariance during MPC.
        sigma_ceiling: nor rises above this multiple of it.
        device: rollout backend, ``cpu`` or ``cuda``.
    """

    dt: float = 0.01
    horizon: int = 40
    samples: int = 30
    knots: int = 4
    temperature: float = 0.12
    #: half the public MPPI's 0.06/0.1/0.1 rad: T2 true in the lock-step sim, seeds 0–7, 30 s, with the fall
    #: reflex, S_R 6/8 against 3/8 for 0.06/0.1/0.1 and 4/8 for 0.02/0.03/0.03, 2 falls each
    #: (benchmarks/fall_forensics.py); on the wall clock it kept the robot up in 12/14 runs against 7/14
    noise: tuple = (0.03, 0.05, 0.05)
    refine_loops: int = 3
    refine_alpha: float = 0.5
    sigma_floor: float = 0.3
    sigma_ceiling: float = 2.0
    #: knot σ [rad] while the fall reflex recovers the stand (a command whose ``phase`` is ``recover``),
    #: 4× ``noise``. The actions that save a tipping trunk (a hanging leg reaching 5–10 cm down to the
    #: floor, a leg stepping out) lie far from the stand's reference, beyond what ``noise`` samples:
    #: from the recorded states of a T2 fall (true mode, seed 1, 0.5–0.3 s before it) the default
    #: planner fell in 3 of 3 restarts, the same with 256 samples in 3 of 3, and with this σ in 0 of 3
    #: (benchmarks/fall_forensics.py --rescue).
    recovery_noise: tuple = (0.12, 0.2, 0.2)
    #: while recovering, every cycle refines over ``refine_loops`` elite loops, as at a contact switch:
    #: a wide distribution needs the loops to narrow onto the saving action (max tilt 22–24° against
    #: 24–27° with one loop, on the same restarts)
    recovery_refine: bool = True
    #: where the rollouts run: ``cpu`` (``mujoco.rollout`` on threads) or ``cuda`` (MuJoCo Warp, every
    #: sample a world of one batched model, float32; needs ``amhe[gpu]`` and a CUDA device):
    #: docs/gpu.md#the-planner-on-the-gpu
    device: str = "cpu"

    def check(self) -> None:
        """Raise :class:`AmheError` for settings that cannot work."""
        if self.horizon < 2 or self.samples < 2 or not 2 <= self.knots <= self.horizon:
            raise AmheError(f"planner horizon {self.horizon}, samples {self.samples}, knots {self.knots}: "
                            "expected horizon >= 2, samples >= 2, 2 <= knots <= horizon")
        if not self.dt > 0 or not self.temperature > 0:
            raise AmheError(f"planner dt {self.dt} and temperature {self.temperature} must be positive")
        for name in ("noise", "recovery_noise"):
            v = getattr(self, name)
            if len(v) != 3 or not all(x > 0 for x in v):
                raise AmheError(f"planner {name} {list(v)}: expected three positive σ's [rad] (hip, thigh, calf)")
        if self.device not in ("cpu", "cuda"):
            raise AmheError(f"planner device {self.device!r}: expected cpu or cuda")

    @classmethod
    def from_dict(cls, d: dict) -> "PlannerSettings":
        check_names(d, {f.name for f in fields(cls)}, "planner setting")
        d = dict(d)
        for k in ("noise", "recovery_noise"):
            if k in d:
                d[k] = tuple(float(x) for x in d[k])
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


#: Planner settings on the wall clock (``run --realtime``, every real robot), applied under a run
#: config's ``planner:`` keys. There a plan's compute time is open-loop time for the robot: with the
#: lock-step defaults (30 samples, 3 refine loops at contact switches) T1 replanned at 6 Hz on a
#: 2-core machine and the robot fell at 3.5 s; 16 samples and one loop replanned at 23 Hz. Smaller
#: knot noise (0.03/0.05/0.05 rad instead of 0.06/0.1/0.1) then kept the robot up in 12 of 14 runs
#: against the Go1 emulator (T1 adaptive, 20 s, 2 cores each) where the lock-step noise kept it up
#: in 7 of 14 (benchmarks/go1_emulated_runs.py); that noise is now the lock-step default too.
#: Halving it again on the wall clock (0.015/0.025/0.025 rad) cut the falls of plans 35 ms late
#: (``latency: 0.035``, T4 true + baseline, seeds 0–15) from 9 to 1 in 32 runs, S_R 66 → 84 %,
#: mean e_g 0.22 → 0.11 m, where a higher MPPI temperature (0.5, 1.0) cut them to 3 and 2 but
#: left the box short (S_R 56 %), 48 samples did not help (5 falls in 17) and a wider hip σ made
#: it worse (14 and 18 falls); halving only the first knot's σ left 9, only the hip's 10, only
#: the thigh's and calf's 6: the sampling noise the mean carries over the horizon, which a late
#: plan cannot correct, is what tips the trot. It pushes slower (its successes took 42 s against
#: 24 s); over T1–T4 at 35 ms it fell in 7 of 80 runs against 17, as often as before on T1 and T2
#: (1 and 2 in 16), with a lower S_R there.
#: On the emulated Go1 (T1/T4, Adaptive and Baseline, seeds 0–3, 4 CPUs per client) 15 of 16
#: runs reached the goal with 1 fall, against 11 and 5 at 0.03/0.05/0.05
#: (docs/fall_prevention.md#the-wall-clock).
REALTIME_PLANNER = {"samples": 16, "refine_loops": 1, "noise": (0.015, 0.025, 0.025)}


def spline_basis(knot_t: np.ndarray, query_t: np.ndarray) -> np.ndarray:
    """(Q, K) matrix mapping K knot values to a natural cubic spline at Q query times.

    Queries outside the knots hold the end value. ``knot_t`` must be increasing.
    """
    knot_t = np.asarray(knot_t, dtype=float)
    K = len(knot_t)
    h = np.diff(knot_t)
    # second derivatives M (natural: M_0 = M_{K-1} = 0) solve A M_inner = R y
    A = np.zeros((K, K))
    R = np.zeros((K, K))
    A[0, 0] = A[-1, -1] = 1.0
    for i in range(1, K - 1):
        A[i, i - 1], A[i, i], A[i, i + 1] = h[i - 1], 2 * (h[i - 1] + h[i]), h[i]
        R[i, i - 1], R[i, i], R[i, i + 1] = 6 / h[i - 1], -6 / h[i - 1] - 6 / h[i], 6 / h[i]
    M = np.linalg.solve(A, R)  # (K, K): second derivatives per unit knot
    q = np.clip(np.asarray(query_t, dtype=float), knot_t[0], knot_t[-1])
    j = np.clip(np.searchsorted(knot_t, q, side="right") - 1, 0, K - 2)
    a = (knot_t[j + 1] - q) / h[j]
    b = 1 - a
    eye = np.eye(K)
    out = a[:, None] * eye[j] + b[:, None] * eye[j + 1]
    out += ((a ** 3 - a) * h[j] ** 2 / 6)[:, None] * M[j] + ((b ** 3 - b) * h[j] ** 2 / 6)[:, None] * M[j + 1]
    return out


@dataclass
class Plan:
    """One planner cycle's result.

    Attributes:
        controls: (horizon, 12) joint targets [rad] of the mean sequence; row 0 is applied first.
        cost: task cost of the mean's rollout.
        refined: True if this cycle ran the ``L_MPOPI`` refinement (mode switch).
        rollouts: rollouts simulated this cycle (× horizon steps each).
        compute_time: wall time [s].
        predicted_tilt: the planner model's forecast [rad]: over this cycle's last batch of samples,
            the least of each one's largest trunk tilt over the horizon, so no sampled plan keeps
            the trunk more level than this (the fall reflex's trigger
            :attr:`~amhe_cli.control.reflex.ReflexSettings.enter_predicted_tilt`).
    """

    controls: np.ndarray
    cost: float
    refined: bool
    rollouts: int
    compute_time: float
    predicted_tilt: float = 0.0


class Planner:
    """MPOPI over a task, a gait and the planner's own model ``f(p̂)``.

    Args:
        scene: the planner's scene (its timestep should equal ``settings.dt``).
        space: the parameters a belief sets (written by :meth:`set_params`).
        task: the task whose cost is minimised.
        settings: :class:`PlannerSettings`.
        nthread: rollout threads (default: all CPUs; one where ``settings.device`` is ``cuda``).
        seed: sampling seed.
    """

    def __init__(self, scene: Scene, space: ParameterSpace, task: Task, settings: PlannerSettings | None = None,
                 nthread: int | None = None, seed: int = 0):
        self.settings = s = settings or PlannerSettings()
        s.check()
        if abs(scene.model.opt.timestep - s.dt) > 1e-9:
            raise AmheError(f"planner scene timestep {scene.model.opt.timestep} differs from planner dt {s.dt}")
        self.scene, self.space, self.task = scene, space, task
        self.gait: Gait = task.gait_spec
        # the GPU, where asked, rolls the samples out; the CPU pool (one thread then) keeps the short
        # latency-compensation rollout of predict(), a few steps that a GPU launch would only slow
        self.gpu = make_backend(scene.model, "cuda") if s.device == "cuda" else None
        self.pool = RolloutPool(scene.model, 1 if self.gpu else nthread)
        self._models = self.pool.models(1 if self.gpu else s.samples)
        self.set_params(space.mean0)
        self.rng = np.random.default_rng(seed)
        self.knot_t = np.linspace(0.0, (s.horizon - 1) * s.dt, s.knots)
        self.basis = spline_basis(self.knot_t, np.arange(s.horizon) * s.dt)  # (T, K)
        #: (K, 12) knot σ of the task's gait and of a recovery (``cmd["phase"] == "recover"``) [rad]
        self.sigma_task = np.broadcast_to(np.tile(np.asarray(s.noise, dtype=float), 4), (s.knots, 12)).copy()
        self.sigma_recover = np.broadcast_to(np.tile(np.asarray(s.recovery_noise, dtype=float), 4),
                                             (s.knots, 12)).copy()
        self._recovering = False
        self.mean = np.zeros((s.knots, 12))
        self.sigma = self.sigma0.copy()
        lo, hi = scene.model.actuator_ctrlrange.T
        self.ctrl_lo, self.ctrl_hi = lo.copy(), hi.copy()
        self._t_last: float | None = None
        self._mode: tuple | None = None
        #: (trunk (H, 3), box (H, 3)) [m]: the mean's predicted paths from the last cycle's state (live view)
        self.mean_path: tuple[np.ndarray, np.ndarray] | None = None
        self._predicted_tilt = 0.0  # [rad] the last scored batch's (:attr:`Plan.predicted_tilt`)
        m = scene.model
        self._qpos = slice(1, 1 + m.nq)
        self._qvel = slice(1 + m.nq, 1 + m.nq + m.nv)

    @property
    def sigma0(self) -> np.ndarray:
        """(K, 12) the knot σ this cycle samples around [rad]: the recovery's while recovering, else the task's."""
        return self.sigma_recover if self._recovering else self.sigma_task

    def where(self) -> str:
        """Where the samples roll out, for messages: ``the GPU`` or ``N thread(s)``."""
        return "the GPU" if self.gpu is not None else f"{self.pool.nthread} thread(s)"

    def close(self) -> None:
        self.pool.close()
        if self.gpu is not None:
            self.gpu.close()

    def __enter__(self) -> "Planner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def edit_models(self, edit) -> None:
        """Apply ``edit(model)`` (in place; it sets values) to every model the planner rolls out, from the next
        plan on, on the CPU and on the GPU alike: what is not a belief parameter, such as a robot's servo and
        motors read mid-run (:mod:`~amhe_cli.control.robot_side`)."""
        self.pool.edit_models(edit, base=self.space.scene.model)
        if self.gpu is not None:
            self.gpu.edit_models(edit, base=self.space.scene.model)

    def set_params(self, values: np.ndarray) -> None:
        """Write a parameter vector (flat coordinates of ``space``) into every planner model copy."""
        self._belief = np.array(values, dtype=float)  # the GPU backend writes it into its worlds
        fields = self.space.model_fields(self._belief)  # once, for every copy
        for m in self._models:
            self.space.write_fields(m, fields)

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """The planner model's state after holding each row of ``controls`` (n, 12) for one ``dt`` from ``state``.

        Latency compensation on the wall clock: the plan computed now starts
        where the robot will be when it arrives, after the previous plan's rows
        that run meanwhile. Returns ``state`` itself for n = 0.
        """
        controls = np.asarray(controls, dtype=float).reshape(-1, 12)
        if len(controls) == 0:
            return state
        return self.pool.rollout(self._models[:1], state[None], controls[None])[0, -1]

    def _shift(self, t: float) -> None:
        if self._t_last is not None and t > self._t_last:
            self.mean = spline_basis(self.knot_t, self.knot_t + (t - self._t_last)) @ self.mean
        self._t_last = t

    def _controls(self, knots: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """(N, T, 12) clipped joint targets of (N, K, 12) knot offsets around the (T, 12) reference."""
        u = ref[None] + np.einsum("tk,nkj->ntj", self.basis, knots)
        return np.clip(u, self.ctrl_lo, self.ctrl_hi)

    def _score(self, state: np.ndarray, knots: np.ndarray, ref: np.ndarray, cmd: dict) -> np.ndarray:
        u = self._controls(knots, ref)
        n = len(knots)
        init = np.broadcast_to(state, (n, state.size))
        if self.gpu is not None:  # one candidate (the belief), n clips: the samples
            qpos, qvel, _ = self.gpu.rollout_candidates(self.space, self._belief[None], init, u,
                                                        np.full(n, self.settings.horizon))
            qpos, qvel = qpos[0].astype(float), qvel[0].astype(float)
        else:
            states = self.pool.rollout(self._models[:n], init, u)
            qpos = states[..., self._qpos]
            qvel = states[..., self._qvel]
        sc = self.scene
        box = qpos[..., sc.box_qpos[:3]]
        # sample 0 is the current mean: its predicted trunk and box paths, (H, 3) [m], for the live view
        self.mean_path = (qpos[0][:, sc.base_qpos[:3]], box[0])
        self._predicted_tilt = float(np.min(trunk_tilt(qpos[..., sc.base_qpos[3:]]).max(axis=1)))
        tau = (np.arange(self.settings.horizon) + 1) * self.settings.dt
        J = self.task.stage_cost(qpos[..., sc.base_qpos[:3]], qpos[..., sc.base_qpos[3:]],
                                 qvel[..., sc.base_qvel[:3]], qvel[..., sc.base_qvel[3:]], box, u, ref[None], cmd,
                                 tau, sc.config.robot_floor, qpos[..., sc.box_qpos[3:]]).mean(axis=1)
        J += self.task.terminal_cost(box[:, -1], cmd, tau[-1])
        return np.where(np.isfinite(J), J, np.inf)

    def plan(self, state: np.ndarray, t: float, cmd: dict, gait: Gait | None = None) -> Plan:
        """One MPOPI cycle from the measured full-physics ``state`` (nstate,) at time ``t`` [s].

        Args:
            state: the plant's state in the planner scene's mjSTATE_FULLPHYSICS layout.
            t: time [s] (the gait phase clock).
            cmd: the task's :meth:`~amhe_cli.control.tasks.Task.command` for this cycle. A
                ``phase`` of ``recover`` (:func:`~amhe_cli.control.reflex.recovery_command`)
                samples with ``recovery_noise`` from a mean reset to the reference, refining every
                cycle if ``recovery_refine``; the first cycle after it (a ``hold`` of the stand, or the
                task) starts the task's σ afresh from the reference.
            gait: the gait to track this cycle (default: the task's); the fall
                reflex (:mod:`~amhe_cli.control.reflex`) asks for ``stand``. A change
                of gait changes the contact mode, so the cycle refines.
        Returns:
            a :class:`Plan`; apply ``controls[0]`` (and further rows if the next
            cycle comes late).
        """
        t0 = time.perf_counter()
        s = self.settings
        self._shift(t)
        gait = gait or self.gait
        ref = gait.reference(t + np.arange(s.horizon) * s.dt, cmd["speed"], cmd["omega"], cmd.get("reach"),
                             cmd.get("sideways", 0.0))
        recovering = cmd.get("phase") == "recover"
        if recovering != self._recovering:  # a recovery starts or ends: the last distribution is not a guide
            self._recovering = recovering
            self.mean = np.zeros_like(self.mean)
            self.sigma = self.sigma0.copy()
        mode = (gait.name, gait.mode(t))
        refine = mode != self._mode or (recovering and s.recovery_refine)
        self._mode = mode
        loops = s.refine_loops if refine else 1
        floor, ceil = self.sigma0 * s.sigma_floor, self.sigma0 * s.sigma_ceiling
        rollouts = 0
        for loop in range(loops):
            eps = self.rng.standard_normal((s.samples,) + self.mean.shape)
            eps[0] = 0.0  # the current mean competes too
            knots = self.mean[None] + self.sigma[None] * eps
            J = self._score(state, knots, ref, cmd)
            rollouts += s.samples
            if refine:  # MPOPI loop: elite update of mean and σ; the last loop's mean comes from MPPI below
                m, sd = gaussian_step(self.mean.ravel(), self.sigma.ravel(), knots.reshape(s.samples, -1), J,
                                      s.refine_alpha)
                self.sigma = np.clip(sd.reshape(self.sigma.shape), floor, ceil)
                if loop < loops - 1:
                    self.mean = m.reshape(self.mean.shape)
        w = mppi_weights(J, s.temperature)
        self.mean = np.einsum("n,nkj->kj", w, knots)
        controls = self._controls(self.mean[None], ref)[0]
        return Plan(controls, float(J[0]), refine, rollouts, time.perf_counter() - t0, self._predicted_tilt)
