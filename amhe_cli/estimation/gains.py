"""The joint PD gains that acted, fitted from the log's joint efforts.

A command log states the gains it *sent* (``/joint_commands/gains``, a LowCmd's
``Kp``/``Kd``); the servo that acted may differ — motor gains drift, a firmware
scales them, a lab logs the nominal figures. Where the log also records the
applied joint torques (``JointState.effort``, a LowState's ``tauEst``), the
servo law

    τ_j = Kp_j (q*_j − q_j) − Kd_j q̇_j + b_j          (per joint j)

is linear in (Kp_j, Kd_j, b_j), so ordinary least squares over the samples that
are not at the torque limit recovers them (``numpy.linalg.lstsq``; ``b_j``
absorbs an effort-sensor offset and is not used in the model). On a log whose
robot applied Kp 60 / Kd 2.5 while it logged 55 / 3, ``identify`` with the logged
gains put the box mass 26 % low; with the fitted ones, within 1 %.

Where the law asks for more than the motor gives, the effort plateaus at the
motor's limit. A joint whose efforts sit on one level (:data:`PLATEAU_SPREAD`)
in at least :data:`MIN_SATURATED` samples where the fitted law asks for more
(:data:`SHORT_FRACTION`, :data:`SHORT_NM`) has its limit read there
(:attr:`GainFit.limit`). A Go1's twelve motors are one motor (the knee's 1.5 ×
gearing aside), so :func:`applied_limit` scales every joint's limit by the share
the saturated ones show, unless a joint delivered more than that share of its own
limit (:attr:`GainFit.peak`: then the flat efforts were something else; on the
emulated Go1 as its model, 10 s windows of T4 read 18–62 % in 6 of 20 runs
without this rule, none with it): a robot whose motors gave 85 % (``amhe emulate go1
--motor-strength 0.85``) plateaued at 20.14 N·m on its thighs, against the
model's 23.7, and the payload fitted beside the model's limits read 2.44 kg for
its 1.5 (the heavier trunk stood in for the weaker motors), 1.49 kg with them
modelled (docs/reference.md#identification).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from amhe_cli.io.trajectory import GO1_JOINTS, Trajectory
from amhe_cli.model.scene import DEFAULT_KD, DEFAULT_KP

#: Samples within this fraction of a joint's largest |effort| count as saturated (torque limit).
SATURATION = 0.98
#: Fewest usable samples per joint for a fit.
MIN_SAMPLES = 200
#: The fitted gains replace the logged ones when they differ by more than this fraction (and 4 σ), per gain.
#: Kd's is wider: noise on the measured joint velocity (its regressor) biases a least-squares Kd low — on
#: the live recording of an emulated Go1 run the fit read Kd 3.8 where 4 acted, and 3 % warned falsely.
#: A servo that differs by what matters to the box (Kd 2.5 against a logged 3, −17 %) still shows.
DISAGREE = {"Kp": 0.03, "Kd": 0.10}
#: A sample is short of the law where ``|law| > (1 + SHORT_FRACTION) |τ| + SHORT_NM`` and ``|τ|`` is over half
#: the joint's peak; a plateau needs ``MIN_SATURATED`` of them whose ``|τ|`` spread (interquartile range)
#: is under ``PLATEAU_SPREAD`` of their median plus the interquartile range of the effort's own noise
#: (1.35 × the fit's residual RMS: a motor-current estimate of the torque scatters).
SHORT_FRACTION, SHORT_NM, MIN_SATURATED, PLATEAU_SPREAD = 0.1, 0.5, 20, 0.03
#: The motors' limit is modelled below the model's where the share the plateaus show is under this.
LIMIT_SHARE = 0.97
#: Longest command delay [s] :func:`fit_gains` searches, on about this many samples of the log.
MAX_DELAY, DELAY_SAMPLES = 0.02, 4000


@dataclass
class GainFit:
    """Per-joint servo gains fitted from efforts.

    Attributes:
        kp: (12,) fitted position gains [N·m/rad], order :data:`GO1_JOINTS`.
        kd: (12,) fitted velocity gains [N·m·s/rad].
        kp_std, kd_std: (12,) their standard errors from the fit's residual.
        offset: (12,) effort offsets ``b_j`` [N·m].
        residual_rms: (12,) RMS effort residual per joint [N·m].
        samples: (12,) samples used per joint.
        ok: (12,) bool, joints whose fit is well posed (enough samples, both
            regressors excited).
        limit: (12,) the torque [N·m] the joint's efforts plateaued at where the law asked for more,
            NaN where they did not (the module docstring).
        delay: how long after its stamp a command acted on the servo [s] (:func:`fit_gains`).
        peak: (12,) the largest |effort| each joint delivered [N·m] (None: not read).
        at_edge: the servo law fitted best at the longest delay searched (:data:`MAX_DELAY`): the delay lies
            beyond the search or the efforts follow no such law, so no joint is ``ok``, no plateau is read and
            ``delay`` is 0 (:func:`fit_gains`).
    """

    kp: np.ndarray
    kd: np.ndarray
    kp_std: np.ndarray
    kd_std: np.ndarray
    offset: np.ndarray
    residual_rms: np.ndarray
    samples: np.ndarray
    ok: np.ndarray
    limit: np.ndarray | None = None
    delay: float = 0.0
    peak: np.ndarray | None = None
    at_edge: bool = False

    def to_dict(self) -> dict:
        """Plain-type summary for beliefs and ``--json``."""
        return {"kp": self.kp.round(3).tolist(), "kd": self.kd.round(4).tolist(),
                "kp_std": self.kp_std.round(4).tolist(), "kd_std": self.kd_std.round(5).tolist(),
                "effort_residual_rms_nm": self.residual_rms.round(4).tolist(),
                "samples": self.samples.tolist(), "ok": self.ok.tolist(),
                "torque_limit_nm": None if self.limit is None else
                [None if not np.isfinite(x) else round(float(x), 3) for x in self.limit],
                "command_delay_s": round(float(self.delay), 4), "delay_at_search_edge": bool(self.at_edge)}


def fit_gains(traj: Trajectory, max_samples: int | None = None) -> GainFit | None:
    """Least-squares fit of ``τ = Kp (q* − q) − Kd q̇ + b`` per joint (module docstring), with the command delay.

    Uses samples where joint states and commands were observed and the effort
    is below :data:`SATURATION` of the joint's largest recorded effort. The
    commands may act on the servo after their stamps (a Go1 applies a LowCmd at
    its next 2 ms tick): the fit is made with ``q*`` delayed by each whole grid
    step up to :data:`MAX_DELAY` and the delay whose mean residual over the
    well-posed joints is least is kept (:attr:`GainFit.delay`), unless it is the
    longest searched (:attr:`GainFit.at_edge`: no joint is then trusted). *Measured*: the
    shared logs read 0; ``amhe run``'s recordings of the emulated Go1 2 ms,
    where Kp read 95 on the thighs of a servo of 100 without the delay and
    100 ± 1 with it, the effort residual halved.

    Args:
        traj: a trajectory with ``joint_effort`` (T, 12).
        max_samples: fit the gains on about this many samples, evenly thinned (None: all; the delay is chosen
            on at most :data:`DELAY_SAMPLES`); the plateaus are read on every sample either way. A read mid-run
            (:func:`~amhe_cli.control.robot_side.read_robot`) thins, beside the planner.
    Returns:
        the :class:`GainFit`, or None when the log has no efforts.
    """
    if traj.joint_effort is None:
        return None
    cap = DELAY_SAMPLES if max_samples is None else min(DELAY_SAMPLES, max_samples)
    every = max(1, len(traj) // cap)  # the delay is chosen on a thinned log, the gains fitted on all (or max_samples)
    scores = []
    for k in range(int(round(MAX_DELAY / traj.dt)) + 1):
        fit = _fit_delayed(traj, k, every, plateaus=False)
        scores.append(float(np.mean(fit.residual_rms[fit.ok])) if fit.ok.any() else np.inf)
    best = int(np.argmin(scores))
    fit = _fit_delayed(traj, best, 1 if max_samples is None else max(1, len(traj) // max_samples))
    if best and best == len(scores) - 1:
        # at the end of the search: not a delay found. Taken, a grid between the joint samples once read a 20 ms
        # delay with Kp 25–60 and negative Kd on a servo that applied its logged 100 / 4 (io/resample.py)
        fit = replace(fit, ok=np.zeros_like(fit.ok), limit=np.full_like(fit.kp, np.nan), delay=0.0, at_edge=True)
    return fit


def delayed(a: np.ndarray, k: int, fill=None) -> np.ndarray:
    """``a`` (T, ...) delayed by ``k`` grid steps: row t holds row t − k; the first ``k`` rows hold row 0
    (``fill`` None) or ``fill``."""
    if not k:
        return a
    head = np.repeat(a[:1], k, axis=0) if fill is None else np.full((k,) + a.shape[1:], fill, dtype=a.dtype)
    return np.concatenate([head, a[:-k]])


def _fit_delayed(traj: Trajectory, k: int, every: int = 1, plateaus: bool = True) -> GainFit:
    """:func:`fit_gains` with the commands acting ``k`` grid steps after their stamps, on every ``every``-th
    sample (the plateaus, where asked, on all)."""
    n_t = len(traj)
    seen = np.ones(n_t, dtype=bool)  # every sample observed: the plateaus are read on these
    for role in ("joint_states", "joint_commands"):
        seen &= np.asarray(traj.observed.get(role, np.ones(n_t, dtype=bool)), dtype=bool)
    ctrl = delayed(traj.ctrl, k)  # the command acting at t is the one stamped at t - k, observed there
    if k:
        seen &= delayed(np.asarray(traj.observed.get("joint_commands", np.ones(n_t, dtype=bool)), dtype=bool), k,
                        fill=False)
    mask = np.zeros(n_t, dtype=bool)  # the samples the gains are fitted on
    mask[::every] = True
    mask &= seen
    tau = traj.joint_effort
    err = ctrl - traj.joint_pos
    vel = traj.joint_vel
    n = len(GO1_JOINTS)
    out = {name: np.zeros(n) for name in ("kp", "kd", "kp_std", "kd_std", "offset", "rms")}
    samples = np.zeros(n, dtype=int)
    ok = np.zeros(n, dtype=bool)
    plateau = np.full(n, np.nan)
    for j in range(n):
        limit = np.abs(tau[mask, j]).max() if mask.any() else 0.0
        use = mask & (np.abs(tau[:, j]) < SATURATION * limit) & np.isfinite(tau[:, j])
        samples[j] = int(use.sum())
        if samples[j] < MIN_SAMPLES:
            continue
        A = np.column_stack([err[use, j], -vel[use, j], np.ones(samples[j])])
        coef, _, rank, _ = np.linalg.lstsq(A, tau[use, j], rcond=None)
        if rank < 3:
            continue
        res = tau[use, j] - A @ coef
        s2 = float(res @ res) / max(samples[j] - 3, 1)
        cov = s2 * np.linalg.inv(A.T @ A)
        out["kp"][j], out["kd"][j], out["offset"][j] = coef
        out["kp_std"][j], out["kd_std"][j] = np.sqrt(np.diag(cov)[:2])
        out["rms"][j] = np.sqrt(s2)
        ok[j] = coef[0] > 0 and coef[1] >= 0
        if ok[j] and plateaus:
            plateau[j] = _plateau(tau[:, j], coef[0] * err[:, j] - coef[1] * vel[:, j] + coef[2], seen,
                                  out["rms"][j])
    # what each motor delivered, against which a plateau is judged (applied_limit): the final fit's only
    peak = np.nanmax(np.abs(tau[seen]), axis=0) if plateaus and seen.any() else None
    return GainFit(out["kp"], out["kd"], out["kp_std"], out["kd_std"], out["offset"], out["rms"], samples, ok,
                   plateau, k * traj.dt, peak)


def _plateau(tau: np.ndarray, law: np.ndarray, mask: np.ndarray, noise: float) -> float:
    """|τ| [N·m] where one joint's efforts sit short of its fitted ``law`` on one level (within its ``noise``
    [N·m RMS]), else NaN."""
    mag = np.abs(tau)
    with np.errstate(invalid="ignore"):
        short = mask & np.isfinite(mag) & (np.abs(law) > (1 + SHORT_FRACTION) * mag + SHORT_NM)
        short &= mag > 0.5 * np.nanmax(np.where(mask, mag, np.nan))
    if short.sum() < MIN_SATURATED:
        return float("nan")
    q1, med, q3 = np.percentile(mag[short], [25, 50, 75])
    return float(med) if q3 - q1 < PLATEAU_SPREAD * med + 1.35 * noise else float("nan")


def applied_limit(fit: GainFit | None, model_limit: np.ndarray) -> tuple[tuple[float, ...] | None, list[str]]:
    """The motors' torque limits to model, and a warning, where the log's efforts plateau below the model's.

    Args:
        fit: :func:`fit_gains`'s answer (None: no efforts).
        model_limit: (12,) the model's limits [N·m].
    Returns:
        (12,) limits [N·m] — every joint's model limit times the median share the plateaued joints show
        (one motor type: the module docstring) — or None where no joint plateaued, the share is at
        least :data:`LIMIT_SHARE`, or a joint delivered more than that share of its own limit (by
        :data:`SHORT_FRACTION`: then the flat efforts were no motor's limit); and one-line warnings.
    """
    if fit is None or fit.limit is None or not np.isfinite(fit.limit).any():
        return None, []
    seen = np.isfinite(fit.limit)
    share = float(np.median(fit.limit[seen] / model_limit[seen]))
    if share >= LIMIT_SHARE:
        return None, []
    names = ", ".join(GO1_JOINTS[j] for j in np.flatnonzero(seen))
    if fit.peak is not None:
        delivered = fit.peak / model_limit
        if delivered.max() > (1 + SHORT_FRACTION) * share:
            j = int(np.argmax(delivered))
            return None, [f"the joint efforts sat flat at {share:.0%} of the model's torque limits on {names}, but "
                          f"{GO1_JOINTS[j]} delivered {delivered[j]:.0%} of its own: not read as the motors' limit"]
    return tuple(float(x) for x in share * model_limit), [
        f"the joint efforts plateau at {share:.0%} of the model's torque limits ({spread(fit.limit[seen])} N·m on "
        f"{names}): modelling every motor's limit at that share (weaker motors or a low battery)"]


def applied_gains(traj: Trajectory, fit: GainFit | None) -> tuple[np.ndarray | None, np.ndarray | None, list[str]]:
    """The gains to model the servo with, and warnings where the log's gains disagree with its efforts.

    A joint's fitted gain replaces the logged one where the fit is well posed
    and differs by more than that gain's :data:`DISAGREE` fraction and 4
    standard errors; a log without gains takes the fitted ones wherever they
    are well posed.

    Returns:
        kp (12,) or None, kd (12,) or None (None: neither logged nor fitted),
        and one-line warnings.
    """
    kp = None if traj.kp is None else traj.kp.copy()
    kd = None if traj.kd is None else traj.kd.copy()
    if fit is None or not fit.ok.any():
        return kp, kd, []
    warns = []
    if kp is None or kd is None:
        kp = np.where(fit.ok, fit.kp, DEFAULT_KP) if kp is None else kp
        kd = np.where(fit.ok, fit.kd, DEFAULT_KD) if kd is None else kd
        warns.append(f"the log carries no gains: using the gains fitted from its joint efforts, "
                     f"Kp {spread(fit.kp[fit.ok])} N·m/rad, Kd {spread(fit.kd[fit.ok])} N·m·s/rad")
        return kp, kd, warns
    changed = []
    for name, logged, fitted, std in (("Kp", kp, fit.kp, fit.kp_std), ("Kd", kd, fit.kd, fit.kd_std)):
        off = fit.ok & (np.abs(fitted - logged) > np.maximum(DISAGREE[name] * np.abs(logged), 4 * std))
        if off.any():
            changed.append(f"{name} {spread(logged[off])} logged, {spread(fitted[off])} fitted "
                           f"({int(off.sum())} joints)")
            logged[off] = fitted[off]
    if changed:
        warns.append("the logged joint gains disagree with the joint efforts: " + "; ".join(changed)
                     + ". Using the fitted gains (the robot's servo is not the one its log states)")
    return kp, kd, warns


def spread(x) -> str:
    """``lo–hi`` of values to 3 significant figures, or one figure where they agree within 1 %."""
    lo, hi = float(np.min(x)), float(np.max(x))
    return f"{lo:.3g}" if abs(hi - lo) <= 0.01 * max(abs(hi), 1e-9) else f"{lo:.3g}–{hi:.3g}"
