"""Uncertainty of parameters from the shape of the cost (Fisher information).

With whitened residuals ``r(p) = sqrt(W_x) (x(p) - x^r)`` the data term is
``J = Σ_k ||r_k(p)||²``, twice a negative log-likelihood if the ``W_x`` σ's were
the real noise levels. Around a point ``p`` the residual Jacobian ``G = ∂r/∂p``
is taken by central differences through the shared cost module (one batch of
``2d + 1`` candidates), giving:

* the Gauss–Newton **Fisher information** ``F = Gᵀ G`` — positive semi-definite
  anywhere, so it also answers "how much could this log tell?" at the prior,
  before anything is fitted (``amhe probe LOG``);
* per-clip scores ``s_k = 2 G_kᵀ r_k`` and the **sandwich** covariance
  ``A⁻¹ S A⁻¹`` with ``A = 2F`` and ``S`` the scores' scatter — the spread of the
  optimum over resampled clips, robust to residuals correlated along a clip.

At an estimate, the belief takes the more conservative of the sandwich and the
least-squares covariance ``s² F⁻¹`` (``s²`` = residual variance per whitened
component, i.e. ``J`` relative to the ``W_x`` noise levels); both include the
prior, ``Σ = (F + W_p)⁻¹``. Neither includes a bias from model mismatch: the
residual rms reported beside it is the flag for that.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amhe_cli.estimation.cost import RolloutCost


@dataclass
class Curvature:
    """Local information about the parameters at ``point``.

    Attributes:
        point: (d,) where it was evaluated.
        fisher: (d, d) Gauss–Newton information ``Gᵀ G`` of the data.
        cov: (d, d) belief covariance (prior included).
        std: (d,) sqrt of its diagonal.
        corr: (d, d) correlation matrix.
        cost: ``J`` at ``point``.
        data: the state-matching part of ``J`` at ``point``.
        residual_scale: ``s²``, mean squared whitened residual per observed component.
        sources: name -> (d,) σ of each candidate covariance before the choice
            (``fisher``: ``(F + W_p)⁻¹``; at an estimate also ``least_squares`` and
            ``sandwich``; :func:`~amhe_cli.estimation.identify.identify` adds
            ``clip_bootstrap`` and ``search``), for reports and calibration.
    """

    point: np.ndarray
    fisher: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    corr: np.ndarray
    cost: float
    data: float
    residual_scale: float
    sources: dict = field(default_factory=dict)


def curvature(cost: RolloutCost, point: np.ndarray, rel_step: float = 0.01, at_estimate: bool = True) -> Curvature:
    """Fisher information and belief covariance of the free parameters at ``point`` (d,).

    Args:
        cost: the shared cost (its clips, weights and prior).
        point: (d,) parameters.
        rel_step: finite-difference step per coordinate as a fraction of
            ``max(|p_i|, prior σ_i)``.
        at_estimate: True at a fitted estimate (conservative of sandwich and
            ``s² F⁻¹``); False at a prior (``F⁻¹``: what the log could tell if the
            ``W_x`` σ's are the noise levels).
    """
    space = cost.space
    p = space.project(np.asarray(point, dtype=float))[0][0]
    d = p.size
    h = rel_step * np.maximum(np.abs(p), space.std0)
    pts = [p]
    for i in range(d):
        for sgn in (1.0, -1.0):
            q = p.copy()
            q[i] += sgn * h[i]
            pts.append(q)
    pts = space.project(np.array(pts))[0]
    res, diverged = cost.residuals(pts)
    steps = pts[1::2, np.arange(d)].diagonal() - pts[2::2, np.arange(d)].diagonal()
    steps = np.where(np.abs(steps) > 0, steps, 1.0)
    r0 = res[0]  # (N_c, H, 2nv)
    G = np.stack([(res[1 + 2 * i] - res[2 + 2 * i]) / steps[i] for i in range(d)], axis=-1)  # (N_c, H, 2nv, d)
    G[diverged.any(axis=0)] = 0.0
    Gk = G.reshape(G.shape[0], -1, d)
    rk = r0.reshape(r0.shape[0], -1)
    F = np.einsum("kni,knj->ij", Gk, Gk)
    prior_prec = np.diag(cost.prior_weight / cost.prior_std ** 2)
    # a parameter nothing informs keeps a belief no wider than its bounds
    prior_prec = prior_prec + np.diag(1.0 / (space.upper - space.lower) ** 2)
    n_obs = max(cost.observed_components, 1)
    j0 = float((rk ** 2).sum())
    s2 = j0 / max(n_obs - d, 1)
    cov = np.linalg.inv(F + prior_prec)
    sources = {"fisher": _cov_std_corr(cov)[1]}
    if at_estimate:
        cov_ls = np.linalg.inv(F / max(s2, 1e-300) + prior_prec) if s2 > 0 else cov * 0
        scores = 2.0 * np.einsum("kni,kn->ki", Gk, rk)  # (N_c, d)
        sc = scores - scores.mean(axis=0)
        nc = max(scores.shape[0], 2)
        S = sc.T @ sc * nc / (nc - 1)
        A_inv = np.linalg.inv(2.0 * F + 2.0 * prior_prec)
        cov_sw = A_inv @ S @ A_inv
        sources.update(least_squares=_cov_std_corr(cov_ls)[1], sandwich=_cov_std_corr(cov_sw)[1])
        cov = cov_ls if np.trace(cov_ls / np.outer(space.std0, space.std0)) >= \
            np.trace(cov_sw / np.outer(space.std0, space.std0)) else cov_sw
    total = j0 + cost.prior_weight * float((((p - cost.prior_mean) / cost.prior_std) ** 2).sum())
    return Curvature(p, F, *_cov_std_corr(cov), total, j0, s2, sources)


def sensing_friction_std(velocity_sigma: float, horizon: float, gravity: float = 9.81) -> float:
    """σ of box–floor friction [-] that a clip's noisy initial velocity leaves: ``2 σ_v / (g T)``.

    A clip of ``horizon`` T [s] starts from a recorded box velocity off by
    ``velocity_sigma`` σ_v [m/s] (the log's pose noise through its smoothing,
    :func:`~amhe_cli.io.smoothing.velocity_noise`); over T that moves the box
    by σ_v·T, as a friction off by Δμ does by ½·Δμ·g·T² — so one clip reads μ
    no closer than ``2 σ_v / (g T)`` (:func:`~amhe_cli.estimation.mhe.noise_clip`
    sizes the MHE's clips by it).
    The smoothing's error is common to overlapping clips and the same in every
    seed, so it does not average down over clips: neither the clip bootstrap
    nor the search spread sees it. *Measured* on ``noisy_b`` (σ_v 0.024 m/s,
    clips of 0.1–0.2 s: 0.032): μ read −0.020 … −0.046 off in all 16 runs on
    both backends, RMS (estimate − truth)/σ 1.37 (CPU) and 2.11 (GPU, 2σ held
    it in 3 of 8) without this term, 0.78 and 0.99 (8 of 8) with it.

    Raises:
        ValueError: a non-positive ``horizon``.
    """
    if not horizon > 0:
        raise ValueError(f"clip horizon {horizon} s: expected > 0")
    return 2.0 * max(float(velocity_sigma), 0.0) / (gravity * float(horizon))


def clip_information(cost: RolloutCost, point: np.ndarray, step: float = 0.25) -> np.ndarray:
    """(N_c, n_params) how much each clip of ``cost`` tells about each free parameter at ``point`` (d,).

    The diagonal of each clip's Gauss–Newton information ``G_kᵀ G_k``
    (module docstring), in prior-σ units and summed over a vector
    parameter's components (``box_inertia``): ``Σ ||r_k(p + h σ_i e_i) −
    r_k(p)||² / h²``, by forward differences of ``step`` prior σ (one batch of
    ``d + 1`` candidates through the shared cost; a step this wide reads a
    clip's response across the contact's roughness, not its local slope).
    Columns follow ``cost.space.slices()``; a diverged rollout counts nothing.
    """
    space = cost.space
    p = space.project(np.asarray(point, dtype=float))[0][0]
    d = p.size
    pts = np.repeat(p[None], d + 1, axis=0)
    pts[1:] += np.diag(step * space.std0)
    pts = space.project(pts)[0]
    h = np.abs(np.diagonal(pts[1:] - p)) / space.std0  # smaller where a bound cut the step
    h = np.where(h > 0, h, np.inf)  # a coordinate pinned at its bound tells nothing here
    res, diverged = cost.residuals(pts)
    info = ((res[1:] - res[0][None]) ** 2).sum(axis=(2, 3)) / (h[:, None] ** 2)  # (d, N_c)
    info[:, diverged.any(axis=0)] = 0.0
    return np.stack([info[sl].sum(axis=0) for sl in space.slices().values()], axis=1)


def _cov_std_corr(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(d, d) covariance symmetrised, its (d,) std and its (d, d) correlation (1 on the diagonal)."""
    cov = 0.5 * (cov + cov.T)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.outer(std, std) > 0, cov / np.outer(std, std), 0.0)
    np.fill_diagonal(corr, 1.0)
    return cov, std, np.clip(corr, -1, 1)


def with_covariance(curv: Curvature, cov: np.ndarray) -> Curvature:
    """``curv`` with its covariance (and std, correlation) replaced by ``cov`` (d, d)."""
    return Curvature(curv.point, curv.fisher, *_cov_std_corr(cov), curv.cost, curv.data, curv.residual_scale,
                     dict(curv.sources))


def coverage(estimate: np.ndarray, std: np.ndarray, truth: np.ndarray, k: float = 2.0) -> np.ndarray:
    """Whether each stated interval holds the truth: ``|estimate − truth| ≤ k σ``.

    The check of honest uncertainty over seeds and logs: with Gaussian errors
    and a right σ, k = 2 holds the truth in 95 % of runs.

    Args:
        estimate, std, truth: (N, d) or broadcastable arrays (runs × parameters).
        k: interval half-width in σ.
    Returns:
        (N, d) bool; its mean over runs is the coverage.

    Raises:
        ValueError: a negative or non-finite σ.
    """
    std = np.asarray(std, dtype=float)
    if np.any(~np.isfinite(std)) or np.any(std < 0):
        raise ValueError("coverage needs finite, non-negative standard deviations")
    return np.abs(np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)) <= k * std
