"""Update rules of sampling distributions, shared by the estimator and the planner.

The MHE (paper Algorithm 1, MHE-Estimate) and MPOPI (Algorithm 1, MPOPI) are
the same pattern — a distribution, samples, their costs, an update — so both use
these rules: :func:`gaussian_step`, the log-rank-weighted elite update of a
diagonal Gaussian with learning rate α (paper §IV-C), and
:func:`mppi_weights`, the exponential weights of MPPI.
"""

from __future__ import annotations

import numpy as np


def log_rank_weights(k: int) -> np.ndarray:
    """(k,) weights of the k best samples, ∝ log(k + ½) − log(rank), summing to 1 (CMA-ES style)."""
    w = np.log(k + 0.5) - np.log(np.arange(1, k + 1))
    return w / w.sum()


def gaussian_step(mean: np.ndarray, std: np.ndarray, samples: np.ndarray, costs: np.ndarray,
                  alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's update of a diagonal Gaussian from scored samples.

    Args:
        mean, std: (d,) current distribution.
        samples: (B, d) candidates; costs: (B,) their costs.
        alpha: learning rate α.
    Returns:
        new (mean, std): ``(1-α)·old + α·(log-rank-weighted average of the best half)``,
        σ from the elites' weighted spread around the old mean.
    """
    k = max(1, len(costs) // 2)
    elite = samples[np.argsort(costs)[:k]]
    w = log_rank_weights(k)
    mean_new = w @ elite
    std_new = np.sqrt(w @ (elite - mean) ** 2)
    return (1 - alpha) * mean + alpha * mean_new, (1 - alpha) * std + alpha * std_new


def mppi_weights(costs: np.ndarray, temperature: float) -> np.ndarray:
    """(B,) MPPI weights ``∝ exp(-(J - min J) / (λ · spread))``, summing to 1.

    Costs are normalised by their spread (max − min) so that the temperature
    ``λ`` is unitless: λ = 0.1 puts ~e⁻¹⁰ on the worst sample, whatever the task
    cost's scale. Non-finite costs get weight 0.

    Raises:
        ValueError: ``temperature`` is not positive.
    """
    if not temperature > 0:
        raise ValueError(f"temperature {temperature}: expected > 0")
    costs = np.asarray(costs, dtype=float)
    ok = np.isfinite(costs)
    if not ok.any():
        return np.full(costs.shape, 1.0 / costs.size)
    c = np.where(ok, costs, np.nan)
    lo, hi = np.nanmin(c), np.nanmax(c)
    z = (c - lo) / max(hi - lo, 1e-12)
    w = np.where(ok, np.exp(-z / temperature), 0.0)
    return w / w.sum()
