"""Quadratic surrogates of the cost over the candidates an optimiser evaluated.

Contact-rich rollouts make ``J(p)`` rough at small scales: a box rocking on its
corners turns a 1 % change of mass into millimetre-level differences in when it
lands, so the cost is a broad valley with a noisy floor (and, when the model is
exactly the plant's, a narrow spike at the truth). A finite difference at 1 %
reads that noise. A quadratic fitted by least squares to the late CMA-ES
generations reads the valley at the scale CMA-ES explored:

* :func:`fit_valley` fits it (and sets the standardisation below). Its
  minimiser is *not* the identify estimate: over that cloud ``J`` is far from
  quadratic and least squares lets the far, costly samples place the minimum
  (2.354 kg on the bundled 2.5 kg example, seed 0, with ``J`` there 4× that at
  the CMA-ES mean, 2.540 kg); :mod:`~amhe_cli.estimation.identify` reports the
  CMA-ES mean instead;
* per-clip quadratics, resampled over clips (bootstrap), give the spread of
  the optimum across plausible clip sets — the uncertainty that seed-to-seed
  reruns show (:func:`bootstrap_minima`). Each resample moves only along the
  directions its clips resolve (curvature at least :data:`RESOLVED` of the
  stiffest); along the others it stays at the centre, and
  :func:`unresolved_variance` gives them the extent of the cloud instead.

All work happens in standardised coordinates ``u = (z - centre) / scale``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def parabola_vertex(x: np.ndarray, J: np.ndarray) -> tuple[float, float]:
    """(x, J) at the minimum of the parabola through three points of a 1-D scan, ``x`` (3,) ascending and their
    costs ``J`` (3,): the vertex kept between ``x[0]`` and ``x[2]``, or the middle point where the three are
    not convex. A 1-D scan's best point refined between its neighbours (payload, change attribution)."""
    a, b, c = np.polyfit(x, J, 2)
    if not a > 0:
        return float(x[1]), float(J[1])
    xm = float(np.clip(-b / (2 * a), x[0], x[2]))
    return xm, float(np.polyval([a, b, c], xm))


def features(U: np.ndarray) -> np.ndarray:
    """(n, d) points -> (n, 1 + d + d(d+1)/2) quadratic features [1, u_i, u_i u_j (i ≤ j)]."""
    n, d = U.shape
    iu, ju = np.triu_indices(d)
    return np.hstack([np.ones((n, 1)), U, U[:, iu] * U[:, ju]])


def unpack(coef: np.ndarray, d: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Feature coefficients (m,) -> (c, g (d,), H (d, d)) with y ≈ c + g·u + ½ uᵀ H u."""
    c, g = coef[0], coef[1:1 + d]
    iu, ju = np.triu_indices(d)
    H = np.zeros((d, d))
    H[iu, ju] = coef[1 + d:]
    H = H + H.T  # off-diagonals: coef = H_ij; diagonal: coef = ½ H_ii, doubled here
    return float(c), g, H


def _psd(H: np.ndarray, floor: float) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    return (V * np.maximum(w, floor)) @ V.T


#: A direction of a resample's summed per-clip quadratic counts as resolved by the clips where its curvature is
#: at least this fraction of the stiffest direction's (:func:`bootstrap_minima`).
RESOLVED = 1e-2


def _minimise(g: np.ndarray, H: np.ndarray, bound: float) -> np.ndarray:
    """Minimiser of ``g·u + ½ uᵀ H u`` with ``H``'s eigenvalues floored positive, clipped to ``|u_i| ≤ bound``.

    :func:`fit_valley`'s minimiser: along a flat or concave direction the
    floored step is huge and the clip holds it at the edge of the fitted cloud.
    """
    scale = max(float(np.abs(np.diag(H)).max()), 1e-12)
    u = -np.linalg.solve(_psd(H, 1e-6 * scale), g)
    return np.clip(u, -bound, bound)


@dataclass
class Valley:
    """The fitted valley.

    Attributes:
        centre, scale: (d,) standardisation of the fit (z = centre + scale · u).
        z_min: (d,) minimiser in optimiser coordinates.
        hessian_u: (d, d) curvature in u.
        r2: fraction of the cost's variance over the samples the fit explains.
        convex: whether the fitted Hessian was positive definite.
    """

    centre: np.ndarray
    scale: np.ndarray
    z_min: np.ndarray
    hessian_u: np.ndarray
    r2: float
    convex: bool


def fit_valley(Z: np.ndarray, J: np.ndarray, centre: np.ndarray, bound: float = 3.0) -> Valley | None:
    """Fit ``J ≈ quadratic(z)`` over samples ``Z`` (n, d) with costs ``J`` (n,).

    Args:
        Z: (n, d) evaluated points in optimiser coordinates.
        J: (n,) their costs.
        centre: (d,) standardisation centre (the CMA-ES mean).
        bound: limit of the minimiser, in sample standard deviations.

    Returns None when there are too few samples for a quadratic (n < 2m,
    ``m = 1 + d + d(d+1)/2`` features).
    The minimiser is limited to ``bound`` sample standard deviations from
    ``centre`` (a quadratic is not trusted beyond the cloud it was fitted on).
    """
    n, d = Z.shape
    m = 1 + d + d * (d + 1) // 2
    if n < 2 * m:
        return None
    scale = np.maximum(Z.std(axis=0), 1e-9)
    U = (Z - centre) / scale
    X = features(U)
    coef, *_ = np.linalg.lstsq(X, J, rcond=None)
    pred = X @ coef
    r2 = 1.0 - float(((J - pred) ** 2).sum() / max(((J - J.mean()) ** 2).sum(), 1e-300))
    _, g, H = unpack(coef, d)
    convex = bool(np.linalg.eigvalsh(0.5 * (H + H.T)).min() > 0)
    u = _minimise(g, H, bound)
    return Valley(centre, scale, centre + scale * u, H, r2, convex)


def _principal(H: np.ndarray, resolved: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues (d,), eigenvectors (d, d) of the symmetrised ``H``, and (d,) bool: resolved, i.e. an
    eigenvalue above ``resolved`` × the largest (flat and concave directions are not)."""
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    return w, V, w > resolved * max(float(w.max()), 1e-300)


def _resolved_step(g: np.ndarray, H: np.ndarray, bound: float, resolved: float) -> np.ndarray:
    """Minimiser of ``g·u + ½ uᵀ H u`` within the directions ``H`` resolves, clipped to ``|u_i| ≤ bound``.

    The Newton step restricted to the eigenvectors of ``H`` whose eigenvalue is at
    least ``resolved`` × the largest; along the others (flat, or concave where a
    fit over a rough floor bends the wrong way) the step is zero.
    """
    w, V, keep = _principal(H, resolved)
    u = -(V[:, keep] / w[keep]) @ (V[:, keep].T @ g)
    return np.clip(u, -bound, bound)


def unresolved_variance(valley: Valley, prior_weight: float, bound: float = 3.0,
                        resolved: float = RESOLVED) -> np.ndarray:
    """(d,) variance, in optimiser coordinates, of what the clips leave unresolved: ``bound`` sample σ along it.

    The principal directions of the summed fit's curvature (prior included)
    whose eigenvalue is below ``resolved`` × the largest are the ones
    :func:`bootstrap_minima` holds at the centre. Along such a direction the
    data place the optimum nowhere in particular within the cloud CMA-ES
    explored, and CMA-ES's own spread there is no measure of it (its step size
    shrinks with the resolved directions), so each coordinate gets
    ``(bound · scale_i)²`` times its share of those directions,
    ``Σ_j V_ij²`` over the unresolved eigenvectors ``V_j`` (0 for a coordinate
    the clips resolve, 1 for one they do not touch). Before, every resample's
    floored step along such a direction was held at the bound and, through
    the eigenvectors' tilt, took the resolved coordinates there too.
    """
    _, V, keep = _principal(valley.hessian_u + prior_weight * 2.0 * np.diag(valley.scale ** 2), resolved)
    share = (V[:, ~keep] ** 2).sum(axis=1)
    return share * (bound * valley.scale) ** 2


def bootstrap_minima(Z: np.ndarray, per_clip: np.ndarray, valley: Valley, prior_weight: float,
                     n_boot: int = 200, rng: np.random.Generator | None = None, bound: float = 3.0,
                     resolved: float = RESOLVED) -> np.ndarray:
    """Minimisers of the summed per-clip quadratics over clip sets resampled with replacement.

    Each resample's minimiser is its Newton step from ``valley.centre`` along
    the directions its curvature resolves (eigenvalue ≥ ``resolved`` × the
    largest, :func:`_resolved_step`), held within ``bound`` sample standard
    deviations; along an unresolved direction it stays at the centre, so the
    spread says what the clip sets tell and nothing about a direction they do
    not (:func:`unresolved_variance` is that part). The version before, flooring every eigenvalue positive,
    took a huge step along a flat direction, which the bound held at the edge
    of the cloud, and through the eigenvectors' tilt it dragged the resolved
    coordinates there too: measured over 8 seeds on five logs (2 cores,
    ``benchmarks/identify_accuracy.py``), the mass's spread was the bound
    times the cloud's in every log (σ proportional to ``bound``), 3–10× the
    seed-to-seed error on the clean logs; this one's RMS of (estimate −
    truth)/σ, computed afterwards from the same runs' samples, was 0.72–1.50
    on the three logs without a bias all clips share, near what the bootstrap
    of the whole estimator (``--replicates``) read on a GPU (0.57–1.08).

    Args:
        Z: (n, d) evaluated points (optimiser coordinates: prior mean at 0, prior σ = 1).
        per_clip: (n, K) each clip's cost at each point.
        valley: the fit whose standardisation to reuse.
        prior_weight: the prior term is ``prior_weight · |z|²``, added exactly.
        n_boot: resamples.
        bound: the most a minimiser moves from the centre, in sample σ.
        resolved: curvature fraction of the stiffest direction below which a direction is left alone.
    Returns:
        (n_boot, d) minimisers in optimiser coordinates.
    """
    rng = rng or np.random.default_rng(0)
    n, d = Z.shape
    U = (Z - valley.centre) / valley.scale
    coefs, *_ = np.linalg.lstsq(features(U), per_clip, rcond=None)  # (m, K)
    K = per_clip.shape[1]
    # prior |z|² with z = c + s u: gradient 2 s c, Hessian 2 diag(s²)
    g_prior = prior_weight * 2.0 * valley.scale * valley.centre
    H_prior = prior_weight * 2.0 * np.diag(valley.scale ** 2)
    out = np.empty((n_boot, d))
    for b in range(n_boot):
        counts = np.bincount(rng.integers(0, K, size=K), minlength=K)
        _, g, H = unpack(coefs @ counts, d)
        out[b] = valley.centre + valley.scale * _resolved_step(g + g_prior, H + H_prior, bound, resolved)
    return out
