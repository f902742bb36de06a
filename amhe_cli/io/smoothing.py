"""Noise estimates and zero-phase smoothing of recorded poses.

A backward difference is the exact velocity of a clean MuJoCo log (semi-implicit
Euler, docs/reference.md#identification), but motion capture has noise: 1 mm at 500 Hz becomes
0.7 m/s of velocity noise, and every clip would start with the box flying. So a
pose stream is smoothed only where its noise shows:

* :func:`noise_sigma` — robust noise level from second differences (MAD, so the
  few large second differences of impacts do not count);
* :func:`window_for` — the shortest odd window whose local-quadratic fit brings
  the velocity noise under a target;
* :func:`savgol` — zero-phase local polynomial (Savitzky–Golay) smoothing and
  differentiation, a thin wrapper of ``scipy.signal.savgol_filter``
  (``mode="interp"``: the ends are fitted on one-sided windows).

The noise logic (:func:`noise_sigma`, :func:`window_for`) is the project's own;
SciPy does the filtering. Orientations are smoothed as sign-continuous (w, x, y, z)
components (:func:`~amhe_cli.io.quat.quat_make_continuous`) and renormalised by
the caller (:mod:`~amhe_cli.io.resample`).
"""

from __future__ import annotations

import numpy as np

#: Noise below this is what clean 2 ms simulations show (a simulated push log: base 4e-6 m, 2.5e-5 rad
#: of real gait motion): leave it. [m] for positions, [rad] for orientations.
CLEAN_SIGMA = 2e-5
CLEAN_SIGMA_ROT = 1e-4
#: Velocity noise the smoothing window aims for [m/s or rad/s].
TARGET_VEL_SIGMA = 0.03
"""0.03 m/s: ``identify`` starts its clips from these velocities, and their noise biases the m·μ split
(errors in variables), while a longer window lags at impacts. On 1 mm motion capture this is a 58 ms
window at 120 Hz and 30 ms at 500 Hz. *Measured* (``benchmarks/identify_accuracy.py``, 8 seeds per
log, one 64-core run), mass error mean ± std (worst) at targets 0.05 / 0.03 / 0.02 m/s:

- ``noisy_b`` (120 Hz): −0.9 ± 5.3 (+9.3) / +3.1 ± 6.5 (+14.3) / +3.3 ± 5.5 (+13.5) %;
- ``mismatch_b`` with 1 mm noise and 2 % drops added at 500 Hz: −26.8 ± 11.2 (−45.9, μ off by
  0.26) / −5.7 ± 4.2 (−15.0) / +8.8 ± 8.3 (+16.3) %;
- ``const_a`` with the same noise: +1.2 ± 8.8 (−13.3, μ 0.11) / +2.7 ± 5.2 (+10.8) / +4.4 ± 2.8 (+9.5) %;
- 2σ coverage over the three: 80.8 / 95.0 / 92.5 %.

0.05 suited 120 Hz but gave 22 ms windows at 500 Hz, where the bias took the mass a quarter low;
0.03 is the target that holds at both rates."""
MAX_WINDOW = 61


#: Median absolute deviation of a standard normal distribution (Φ⁻¹(3/4)): MAD / this estimates σ.
MAD_NORMAL = 0.6744897501960817


def robust_sigma(x: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Standard deviation of ``x`` along ``axis`` from its median absolute deviation (outliers kept out).

    ``median(|x − median(x)|) / Φ⁻¹(3/4)``: σ for normally distributed ``x``; what
    ``scipy.stats.median_abs_deviation(x, axis, scale="normal")`` returns, without importing
    ``scipy.stats`` (a quarter of a second on every log read).
    """
    x = np.asarray(x, dtype=float)
    med = np.median(x, axis=axis, keepdims=True)
    return np.median(np.abs(x - med), axis=axis) / MAD_NORMAL


def noise_sigma(x: np.ndarray) -> np.ndarray:
    """(T, k) samples -> (k,) robust white-noise standard deviation per column.

    For white noise σ, the second difference has std √6 σ; a smooth motion
    sampled finely adds almost nothing. Median absolute deviation keeps impacts out.
    """
    x = np.asarray(x, dtype=float)
    if len(x) < 5:
        return np.zeros(x.shape[1])
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    return robust_sigma(d2, axis=0) / np.sqrt(6.0)


def window_for(sigma: float, dt: float, target: float = TARGET_VEL_SIGMA, clean: float = CLEAN_SIGMA) -> int:
    """Odd window (samples) whose linear-fit slope has noise ≤ ``target`` for noise ``sigma``.

    Slope variance of a least-squares line over w samples: 12 σ² / (dt² w (w² - 1)).
    Returns 1 (no smoothing) at or below ``clean``; at most :data:`MAX_WINDOW`.
    """
    if sigma <= clean:
        return 1
    w = 3
    while w < MAX_WINDOW and 12 * sigma ** 2 / (dt ** 2 * w * (w * w - 1)) > target ** 2:
        w += 2
    return w


def preload() -> None:
    """Import now what :func:`savgol` imports at its first call (``scipy.signal``, 0.7 s on 2 cores).

    A command that never smooths never pays for it; a control loop on the wall clock calls this before
    its clock starts. Without it the online MHE's first noisy window imported it mid-run: against
    ``amhe emulate go1`` (T1 adaptive, 2 cores) the planner stopped for 1.0 s at t = 1 s, the relay
    soft-held the walking robot and its trunk tilted past the fall reflex's 17° in 3 of 3 runs.
    """
    import scipy.signal  # noqa: F401


def savgol(x: np.ndarray, window: int, dt: float, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Zero-phase local-polynomial (Savitzky–Golay) smoothing of (T, k) samples along time.

    ``scipy.signal.savgol_filter`` with ``deriv=0`` and ``deriv=1, delta=dt``,
    ``mode="interp"``: interior samples take the value and slope of a
    least-squares polynomial of degree ``order`` over the centred window, the
    first and last ``window // 2`` samples those of the fit over the first /
    last window.

    Args:
        x: (T, k) samples at a uniform step (also (T,)).
        window: window length [samples]; an even one is raised to the next odd.
            1 (or a series shorter than the window) means no smoothing: ``x`` is
            returned with its ``np.gradient`` derivative.
        dt: sample step [s].
        order: polynomial degree, < window.

    Returns:
        (T, k) smoothed values and (T, k) their time derivative [per second].
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    window = int(window) | 1
    if window <= 1 or n < window:
        return x.copy(), np.gradient(x, dt, axis=0) if n > 1 else np.zeros_like(x)
    from scipy.signal import savgol_filter  # imported where a noisy log needs it (half a second)

    val = savgol_filter(x, window, order, deriv=0, axis=0, mode="interp")
    der = savgol_filter(x, window, order, deriv=1, delta=dt, axis=0, mode="interp")
    return val, der



def _window_samples(meta: dict, role: str, dt: float, noise: str, window: str) -> tuple[float, float, float]:
    """(σ, the stream's own sample period h [s], its samples n within the smoothing window) of one pose
    component (``position_noise_m``/``position_window`` or the orientation's) of ``role``, from what
    ``read_log`` measured (``meta["sensors"]``, ``meta["smoothing"]``); the window counts samples of the
    trajectory's step ``dt`` [s], the stream's measured ``rate_hz`` gives h (``dt`` if unknown)."""
    stream = meta.get("sensors", {}).get("streams", {}).get(role, {})
    smoothed = meta.get("smoothing", {}).get(role) or {}
    sigma = float(smoothed.get(noise, stream.get(noise, 0.0)) or 0.0)
    rate = float(stream.get("rate_hz", 0.0) or 0.0)
    step = 1.0 / rate if rate > 0 else dt
    return sigma, step, int(smoothed.get(window, 1)) * dt / step


def pose_noise(meta: dict, role: str, dt: float) -> tuple[float, float]:
    """(position [m], orientation [rad]) noise of a free body's (``"box"``, ``"base"``) poses as read.

    The stream's measured noise (``meta["sensors"]``) through the smoothing
    window it got (``meta["smoothing"]``; the window counts samples of the
    trajectory's step ``dt`` [s], but only the stream's own samples, at its
    measured ``rate_hz``, carry independent noise): the centre value of a
    quadratic least-squares fit over n independent samples has variance
    ``σ² · 3 (3n² − 7) / (4 n (n² − 4))`` (0.49 σ² for n = 5: 120 Hz motion
    capture smoothed over 42 ms). (0, 0) where the log holds no noise figure
    (a simulated or live trajectory).
    """
    out = []
    for noise, window in (("position_noise_m", "position_window"), ("orientation_noise_rad", "orientation_window")):
        sigma, _, n = _window_samples(meta, role, dt, noise, window)
        factor = 3 * (3 * n * n - 7) / (4 * n * (n * n - 4)) if n >= 5 else 1.0
        out.append(sigma * np.sqrt(min(factor, 1.0)))
    return out[0], out[1]


def velocity_noise(meta: dict, role: str, dt: float) -> float:
    """Noise [m/s] of a free body's linear velocity as read, per axis (0 where the log holds no noise figure).

    The velocity is the slope of the smoothing fit (:func:`savgol`), so its
    noise is a least-squares slope's over the stream's own samples within the
    window (as :func:`pose_noise` counts them): ``sqrt(12 σ² / (h² n (n² − 1)))``
    for n samples h apart; without smoothing the backward difference's
    ``√2 σ / h``. On ``noisy_b`` (1 mm at 120 Hz) smoothed over 42 ms: 0.039
    m/s, where the box at rest read 0.033 m/s per axis (58 ms, the default
    now: 0.024 m/s).
    """
    sigma, step, n = _window_samples(meta, role, dt, "position_noise_m", "position_window")
    if sigma <= CLEAN_SIGMA:
        return 0.0
    if n < 2:
        return float(np.sqrt(2.0) * sigma / step)
    return float(np.sqrt(12.0 * sigma ** 2 / (step ** 2 * n * (n * n - 1))))
