"""The shared rollout-matching cost ``J(p)`` — paper eq. (1) and eq. (4).

For a batch ``P`` of ``B`` candidate parameter vectors and ``N_c`` clips::

    J(p) = Σ_k Σ_{t=0}^{H_k-1} || x^r_{t+1,k} - x_{t+1,k}(p) ||²_{W_x}  +  || p - p0 ||²_{W_p}

where ``x_{t+1,k}(p)`` is the state rolled out under ``f(·; p)`` from clip
``k``'s recorded initial state with its recorded controls. This is the **one**
module every subcommand evaluates (``identify``, ``probe``, ``mhe-replay``,
``run``); none has its own rollout loop.

State error lives in the tangent space (length ``2 nv``): free-body positions
and rotation vectors of orientation error, joint angles, then all velocities.
``W_x`` is diagonal, built from per-group standard deviations
(``w = 1/σ²``, :class:`StateWeights`); components of a role that was not
observed at a step (log gap) weigh zero there.

Rollouts that diverge (non-finite or absurd states) get a large finite cost
(:data:`DIVERGED`) so optimisers rank them last; nothing returns NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amhe_cli.estimation.clips import ROLES, Clips
from amhe_cli.errors import AmheError
from amhe_cli.io.quat import quat_relative_rotvec
from amhe_cli.model.params import ParameterSpace
from amhe_cli.model.device import make_backend
from amhe_cli.model.rollout import RolloutPool
from amhe_cli.model.scene import Scene

#: Cost given to a candidate whose rollout diverged on a clip.
DIVERGED = 1e12
#: Weight of the feasibility penalty (per squared prior-σ moved by projection).
PENALTY = 1e3

#: Default state-error standard deviations per group, in SI units.
DEFAULT_SIGMA: dict[str, float] = {
    "base_pos": 0.02, "base_rot": 0.05, "joint_pos": 0.1,
    "box_pos": 0.002, "box_height": float("inf"), "box_yaw": 0.02, "box_tilt": float("inf"),
    "base_linvel": 0.5, "base_angvel": 1.0, "joint_vel": 5.0,
    "box_linvel": 0.05, "box_vz": float("inf"), "box_yawrate": 0.2, "box_tiltrate": float("inf"),
}
"""Why the box's rocking (height, tilt and their rates) is left out by default: a box
rocking on its corners is chaotic in the parameters, and a heavier box rocks less,
so matching the rocking pulls the estimate heavier. Measured on the 5 kg example
log: mass +6 % with the rocking in ``W_x``, +0.2 % without it."""


@dataclass
class StateWeights:
    """Diagonal ``W_x`` by state group: ``w = 1/σ²``, σ in the group's SI unit.

    Box groups split the planar motion that mass and friction govern
    (``box_pos`` x,y; ``box_yaw``; ``box_linvel`` vx,vy; ``box_yawrate``) from
    the rocking on its corners (``box_height``, ``box_tilt``, ``box_vz``,
    ``box_tiltrate``). A σ of ``inf`` leaves that group out of the cost.
    """

    sigma: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_SIGMA))

    def __post_init__(self) -> None:
        unknown = set(self.sigma) - set(DEFAULT_SIGMA)
        if unknown:
            raise AmheError(f"unknown state group {sorted(unknown)} in W_x: expected {sorted(DEFAULT_SIGMA)}")
        self.sigma = {**DEFAULT_SIGMA, **{k: float(v) for k, v in self.sigma.items()}}
        bad = [k for k, v in self.sigma.items() if not v > 0]
        if bad:
            raise AmheError(f"W_x σ of {', '.join(bad)} must be positive (inf leaves a group out)")

    @classmethod
    def for_log(cls, traj, overrides: dict | None = None) -> "StateWeights":
        """``W_x`` for a log whose sensors were measured (:mod:`~amhe_cli.io.sensors`).

        Each group's σ is the model-error default and the measured noise added
        in quadrature, ``σ² = σ_default² + σ_noise²``: pose noise for positions
        and orientations, encoder noise for joint angles. A velocity that was
        differentiated from a *smoothed* pose (a motion-capture stream without
        twist) leaves the cost (σ = inf): it holds nothing the positions do not,
        only the smoother's lag at impacts and stops, where it is off by up to
        half the window times the deceleration. Measured on ``noisy_b`` (8 seeds):
        with those velocities in ``W_x`` and a 78 ms window the mass read
        +5.2 ± 5.4 % and μ up to 0.052 low; without them, and with the 42 ms
        window of :data:`~amhe_cli.io.smoothing.TARGET_VEL_SIGMA` = 0.05 m/s
        (the target then; 0.03 now, see there), −0.9 ± 5.7 % and μ within 0.05.
        On a clean simulated log every term is ≪ the default and ``W_x`` is the
        default. ``overrides`` (group -> σ, e.g. ``--sigma``) win.

        Args:
            traj: the :class:`~amhe_cli.io.trajectory.Trajectory` (uses
                ``meta["sensors"]["streams"]``, ``meta["smoothing"]`` and
                ``measured_velocity``).
        """
        meta = traj.meta
        streams = meta.get("sensors", {}).get("streams", {})
        smoothed = meta.get("smoothing", {})
        sigma: dict[str, float] = {}
        for role in ("base", "box"):
            st = streams.get(role, {})
            pos_g, rot_g = f"{role}_pos", ("base_rot" if role == "base" else "box_yaw")
            for group, key in ((pos_g, "position_noise_m"), (rot_g, "orientation_noise_rad")):
                if st.get(key):
                    sigma[group] = float(np.hypot(DEFAULT_SIGMA[group], st[key]))
            if role in smoothed and not traj.measured_velocity.get(role, False):
                for group in ((f"{role}_linvel", "base_angvel") if role == "base" else ("box_linvel", "box_yawrate")):
                    sigma[group] = float("inf")
        joint = streams.get("joint_states", {}).get("joint_noise_rad")
        if joint:
            sigma["joint_pos"] = float(np.hypot(DEFAULT_SIGMA["joint_pos"], joint))
        return cls({**sigma, **(overrides or {})})

    def vector(self, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
        """(2 nv,) weights and (2 nv,) role index (into :data:`ROLES`) per tangent component."""
        nv = scene.model.nv
        w = np.zeros(2 * nv)
        role = np.zeros(2 * nv, dtype=int)
        b = scene.box_qvel
        base, joints, box = (ROLES.index(r) for r in ("base", "joint_states", "box"))
        groups = {  # group: (tangent indices, role, velocity group)
            "base_pos": (scene.base_qvel[:3], base, "base_linvel"),
            "base_rot": (scene.base_qvel[3:], base, "base_angvel"),
            "joint_pos": (scene.joint_qvel, joints, "joint_vel"),
            "box_pos": (b[:2], box, "box_linvel"), "box_height": (b[2:3], box, "box_vz"),
            "box_tilt": (b[3:5], box, "box_tiltrate"), "box_yaw": (b[5:6], box, "box_yawrate"),
        }
        for name, (idx, r, vel) in groups.items():
            w[idx] = 1.0 / self.sigma[name] ** 2
            role[idx] = r
            w[nv + idx] = 1.0 / self.sigma[vel] ** 2
            role[nv + idx] = r
        return w, role


def _span(idx: np.ndarray):
    """``idx`` as a slice where it is a contiguous run (basic indexing: a view, no gather), else itself."""
    idx = np.asarray(idx)
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


def state_error(scene: Scene, qpos_ref: np.ndarray, qvel_ref: np.ndarray, qpos: np.ndarray,
                qvel: np.ndarray) -> np.ndarray:
    """Tangent-space state error ``x - x^r``.

    Args:
        qpos_ref, qpos: (..., nq); qvel_ref, qvel: (..., nv).
    Returns:
        (..., 2 nv): position part in qvel layout (free joints: world-frame
        translation, body-frame rotation vector), then velocity difference;
        float32 where ``qpos`` and ``qvel`` are (a GPU backend's states), else float64.

    Contiguous address runs are sliced rather than gathered (the Go1 + box
    scene's are): with the in-place whitening in :meth:`RolloutCost.residuals`,
    :meth:`RolloutCost.evaluate` on (48, 96, 65, ·) rollouts took 0.155 s
    instead of 0.319 s (2 cores), host time that wide GPU batches pay every call.
    In float32 on a GPU's float32 states, a line decision's batch ((62, 32, 97, ·))
    took 0.12 s instead of 0.17 s (this 2-core machine, loaded), its per-clip costs within
    2e-5 of the float64 sums on the same states: rounding far below the states' own float32 rounding.
    """
    nv = scene.model.nv
    dtype = np.float32 if qpos.dtype == np.float32 and qvel.dtype == np.float32 else np.float64
    qpos_ref, qvel_ref = np.asarray(qpos_ref, dtype=dtype), np.asarray(qvel_ref, dtype=dtype)
    err = np.empty(np.broadcast_shapes(qpos.shape[:-1], qpos_ref.shape[:-1]) + (2 * nv,), dtype=dtype)
    np.subtract(qvel, qvel_ref, out=err[..., nv:])
    for qadr, vadr in ((scene.base_qpos, scene.base_qvel), (scene.box_qpos, scene.box_qvel)):
        qa, qb, va, vb = _span(qadr[:3]), _span(qadr[3:]), _span(vadr[:3]), _span(vadr[3:])
        np.subtract(qpos[..., qa], qpos_ref[..., qa], out=err[..., va])
        err[..., vb] = quat_relative_rotvec(qpos_ref[..., qb], qpos[..., qb], single=True)
    jq, jv = _span(scene.joint_qpos), _span(scene.joint_qvel)
    err[..., jv] = qpos[..., jq] - qpos_ref[..., jq]
    return err


@dataclass
class CostBreakdown:
    """Result of one batched evaluation.

    Attributes:
        total: (B,) ``J`` = data + prior + penalty.
        data: (B,) state-matching term summed over clips.
        prior: (B,) ``||p - p0||²_{W_p}``.
        penalty: (B,) infeasibility penalty (bounds, inertia inequalities).
        per_clip: (B, N_c) state-matching term per clip.
        diverged: (B, N_c) bool, rollouts that blew up.
    """

    total: np.ndarray
    data: np.ndarray
    prior: np.ndarray
    penalty: np.ndarray
    per_clip: np.ndarray
    diverged: np.ndarray


class RolloutCost:
    """``J(P)`` for batches of candidates over a fixed set of clips (eq. 1 / eq. 4).

    Args:
        scene: the model ``f``.
        space: free parameters, prior mean ``p0`` and prior std (``W_p``).
        clips: the recorded clips (change them with :meth:`set_clips`, e.g.
            when an MHE window slides).
        weights: ``W_x`` (default :class:`StateWeights`).
        prior_weight: multiplies ``W_p`` (0 disables the prior term).
        pool: a rollout backend to share (a :class:`RolloutPool`, or a
            :class:`~amhe_cli.model.rollout_warp.WarpRollout`); by default one
            is created by :func:`~amhe_cli.model.device.make_backend`.
        nthread: threads for a CPU pool created here.
        device: ``cpu``, ``cuda`` or ``auto`` for a backend created here
            (:func:`~amhe_cli.model.device.choose_device`); None: the
            process's (``--device``, :func:`~amhe_cli.model.device.set_default`). The cost is the
            same function on either: the candidates × clips are rolled out by
            whichever backend, and everything after that is this module's.

    Deterministic: MuJoCo rollouts are, so the same ``P`` gives the same ``J``.

    On a backend that scores on its device (``score_candidates``, the ``cuda`` one), :meth:`evaluate` sends the
    clips' recorded states and ``sqrt(W_x)`` there and gets back only the (B, N_c) sums: the same function,
    its states never copied to the host (``score_on_device`` False scores them here instead, for comparison).
    """

    #: Score on the backend's device where it offers ``score_candidates`` (:meth:`evaluate`).
    score_on_device = True

    def __init__(self, scene: Scene, space: ParameterSpace, clips: Clips, weights: StateWeights | None = None,
                 prior_weight: float = 1.0, pool: RolloutPool | None = None, nthread: int | None = None,
                 device: str | None = None):
        self.scene = scene
        self.space = space
        self.weights = weights or StateWeights()
        self.prior_weight = float(prior_weight)
        self.prior_mean = space.mean0.copy()
        self.prior_std = space.std0.copy()
        self._own_pool = pool is None
        self.pool = pool or make_backend(scene.model, device, nthread)
        self._w, self._role = self.weights.vector(scene)
        self.rollout_steps = 0  # total simulated steps, for throughput figures
        self.set_clips(clips)

    def __enter__(self) -> "RolloutCost":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._own_pool:
            self.pool.close()

    def set_clips(self, clips: Clips, weights: StateWeights | None = None) -> None:
        """Replace the clips, and ``W_x`` if given."""
        if weights is not None:
            self.weights = weights
            self._w, self._role = weights.vector(self.scene)
        self.clips = clips
        # (N_c, H_max, 2nv) weights with unobserved roles zeroed
        self._wmask = self._w[None, None, :] * clips.observed[:, :, self._role]
        self._sqrt_wmask = np.sqrt(self._wmask)
        self._sqrt_wmask32 = self._sqrt_wmask.astype(np.float32)  # for float32 (GPU) states: no upcast per element

    @property
    def observed_components(self) -> int:
        """Number of weighted state components over all clips and steps (residual count)."""
        return int(np.count_nonzero(self._wmask))

    def set_prior(self, mean: np.ndarray, std: np.ndarray | None = None) -> None:
        """Move the prior ``p0`` (and optionally its σ), e.g. to the previous MHE estimate ``p̂⁻``."""
        self.prior_mean = np.asarray(mean, dtype=float).copy()
        if std is not None:
            std = np.asarray(std, dtype=float).copy()
            if std.shape != self.prior_mean.shape or np.any(std <= 0):
                raise ValueError(f"prior std must be {self.prior_mean.shape} positive values")
            self.prior_std = std

    def __call__(self, P: np.ndarray) -> np.ndarray:
        """(B,) total cost of (B, d) candidates."""
        return self.evaluate(P).total

    def rollout(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Roll every candidate out over every clip.

        Args:
            P: (B, d) candidates (already feasible).
        Returns:
            qpos (B, N_c, H_max, nq) and qvel (B, N_c, H_max, nv); rows past a
            clip's horizon repeat its last rolled-out state.
        """
        c = self.clips
        qpos, qvel, steps = self.pool.rollout_candidates(self.space, np.atleast_2d(P), c.initial_state, c.control,
                                                         c.horizon)
        self.rollout_steps += steps
        return qpos, qvel

    def residuals(self, Q: np.ndarray, states: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Whitened state errors ``sqrt(W_x) (x(p) - x^r)`` of feasible candidates.

        Args:
            Q: (B, d) feasible candidates (see :meth:`ParameterSpace.project`).
            states: their rollouts' (qpos, qvel) as :meth:`rollout` returns them, where already made (None: rolled
                out here).
        Returns:
            (B, N_c, H_max, 2 nv) residuals (zero where unobserved or past a
            clip's horizon) and (B, N_c) bool, True where the rollout diverged
            (non-finite, or a coordinate beyond 1 km).
        """
        qpos, qvel = self.rollout(Q) if states is None else states
        c = self.clips
        res = state_error(self.scene, c.qpos[None], c.qvel[None], qpos, qvel)
        res *= (self._sqrt_wmask32 if res.dtype == np.float32 else self._sqrt_wmask)[None]
        # a non-finite residual makes its clip's sum non-finite: one reduction instead of an isfinite pass
        diverged = ~np.isfinite(np.einsum("bnhk->bn", res)) | (np.abs(qpos).max(axis=(2, 3)) > 1e3)
        if diverged.any():
            res[diverged] = 0.0
        return res, diverged

    def evaluate(self, P: np.ndarray, states: tuple[np.ndarray, np.ndarray] | None = None) -> CostBreakdown:
        """Evaluate ``J`` on a batch.

        Args:
            P: (B, d) candidate parameter vectors (any values: infeasible ones
                are projected and charged :data:`PENALTY` per squared prior-σ).
            states: the (qpos, qvel) of these candidates' rollouts over the clips, where already made (as
                :meth:`rollout` returns them, e.g. a GPU launch's own, ``WarpRollout.last_states``): scored on
                the host, nothing rolled out. None: rolled out now, and scored where :attr:`score_on_device`
                says.
        Returns:
            :class:`CostBreakdown` with (B,) totals and (B, N_c) per-clip terms.
        """
        P = np.atleast_2d(np.asarray(P, dtype=float))
        if P.shape[1] != self.space.dim:
            raise ValueError(f"candidates have {P.shape[1]} columns, expected {self.space.dim} ({self.space.labels})")
        Q, moved = self.space.project(P)
        score = getattr(self.pool, "score_candidates", None) if self.score_on_device and states is None else None
        if score is None:
            res, diverged = self.residuals(Q, states)
            sums = np.einsum("bnhk,bnhk->bn", res, res).astype(float)
        else:
            c = self.clips
            sums, diverged, steps = score(self.space, Q, c.initial_state, c.control, c.horizon, c.qpos, c.qvel,
                                          self._sqrt_wmask32)
            self.rollout_steps += steps
        per_clip = np.where(diverged, DIVERGED, sums)
        data = per_clip.sum(axis=1)
        prior = self.prior_weight * (((Q - self.prior_mean) / self.prior_std) ** 2).sum(axis=1)
        penalty = PENALTY * moved
        return CostBreakdown(data + prior + penalty, data, prior, penalty, per_clip, diverged)
