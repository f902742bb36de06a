"""Uncertainty of an estimate from the cost's local shape (Fisher information).

The cost is a sum over clips, ``J(p) = Σ_k J_k(p) + ||p - p0||²_{W_p}``. Around a
point ``p̂`` we take, by central finite differences through the shared cost
module (one batch of ``1 + 2d + 2d(d-1)`` candidates):

* ``A = ∇² Σ_k J_k`` — the data curvature;
* ``g_k = ∇ J_k`` — each clip's gradient, and ``S`` their centred scatter.

The data's Fisher information is the sandwich form ``F = A S⁻¹ A`` (its inverse
``A⁻¹ S A⁻¹`` is the M-estimator covariance, robust to autocorrelated residuals
and model mismatch because it measures how much the clips *disagree*, not how
big the residuals are), and the belief is ``Σ = (F + W_p)⁻¹`` with
``W_p = diag(1/σ_prior²)``. A parameter the data cannot see keeps its prior σ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cost import RolloutCost


@dataclass
class Curvature:
    """Local information about the parameters at ``point``.

    Attributes:
        point: (d,) where it was evaluated.
        hessian: (d, d) data curvature ``A``.
        fisher: (d, d) data information ``F``.
        cov: (d, d) belief covariance ``(F + W_p)⁻¹``.
        std: (d,) sqrt of its diagonal.
        corr: (d, d) correlation matrix.
        cost: J at ``point``.
    """

    point: np.ndarray
    hessian: np.ndarray
    fisher: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    corr: np.ndarray
    cost: float


def curvature(cost: RolloutCost, point: np.ndarray, rel_step: float = 0.02) -> Curvature:
    """Fisher information and belief covariance of the parameters at ``point`` (d,).

    ``rel_step`` sets the finite-difference step per coordinate as a fraction of
    ``max(|p_i|, prior σ_i)`` — large enough to step over contact-solver noise.
    """
    space = cost.space
    p = np.asarray(point, dtype=float)
    d = p.size
    h = rel_step * np.maximum(np.abs(p), space.std0)
    # keep steps inside the bounds
    h = np.minimum(h, 0.49 * (space.upper - space.lower))
    pts = [p.copy()]
    for i in range(d):
        for s in (1, -1):
            q = p.copy()
            q[i] += s * h[i]
            pts.append(q)
    pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
    for i, j in pairs:
        for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            q = p.copy()
            q[i] += si * h[i]
            q[j] += sj * h[j]
            pts.append(q)
    pts = np.array(pts)
    pts, _ = space.project(pts)  # stay feasible; keeps the differences honest at bounds
    br = cost.evaluate(pts)
    Jk = np.where(br.diverged, np.nan, br.per_clip)  # (n_pts, N_c)
    Jk = np.nan_to_num(Jk, nan=np.nanmax(Jk) if np.isfinite(Jk).any() else 0.0)
    c0 = Jk[0]
    g = np.empty((Jk.shape[1], d))
    A = np.empty((d, d))
    total = Jk.sum(axis=1)
    for i in range(d):
        up, dn = Jk[1 + 2 * i], Jk[2 + 2 * i]
        hi = pts[1 + 2 * i, i] - pts[2 + 2 * i, i]
        g[:, i] = (up - dn) / hi
        A[i, i] = (total[1 + 2 * i] - 2 * total[0] + total[2 + 2 * i]) / (hi / 2) ** 2
    base = 1 + 2 * d
    for n, (i, j) in enumerate(pairs):
        pp, pm, mp, mm = total[base + 4 * n:base + 4 * n + 4]
        A[i, j] = A[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
    A = _psd(A)
    gc = g - g.mean(axis=0)
    nc = max(g.shape[0], 2)
    S = gc.T @ gc * nc / (nc - 1)
    scale = np.maximum(np.abs(np.diag(A)), 1e-12)
    S_reg = S + 1e-9 * np.diag(np.maximum(np.diag(S), scale * 1e-6))
    F = _psd(A @ np.linalg.pinv(S_reg) @ A)
    prior_prec = np.diag(cost.prior_weight / space.std0 ** 2) if cost.prior_weight > 0 else np.zeros((d, d))
    # a parameter nothing informs keeps a wide belief: its bounds span
    prior_prec = prior_prec + np.diag(1.0 / (space.upper - space.lower) ** 2)
    cov = np.linalg.inv(F + prior_prec)
    cov = 0.5 * (cov + cov.T)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(std, std) if np.all(std > 0) else np.eye(d)
    return Curvature(p, A, F, cov, std, np.clip(corr, -1, 1), float(c0.sum() + br.prior[0] + br.penalty[0]))


def _psd(M: np.ndarray) -> np.ndarray:
    """Symmetric positive semi-definite part of ``M`` (negative eigenvalues zeroed)."""
    M = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(M)
    return (V * np.maximum(w, 0.0)) @ V.T
