"""Fusing successive MHE window estimates: the arrival cost, with change detection.

Each MHE update (:mod:`~amhe_cli.estimation.mhe`) solves eq. (4) over a short
window. On a log whose poses carry measurement noise, one window's estimate
scatters around the truth by what that window's noise happened to be, and
windows that overlap share it (*measured* on ``noisy_b``, 8 seeds: at a given
update the seeds agree within ±0.03 on μ while successive windows move by
±0.06). Eq. (4)'s fixed ``W_p`` cannot average that away without slowing the
tracking of a real change. This module does what an arrival cost does in MHE
theory (Rao, Rawlings & Mayne, IEEE TAC 2003: the information of the data
that left the window, carried as a Gaussian prior), per coordinate, on the
window estimates ``y_k``:

* **random walk**: ``p_k = p_{k-1} + w``, ``w ~ N(0, q² Δt)`` with
  ``q = PROCESS_RATE · scale`` (1 % of each parameter's nominal scale per √s);
* **measurement noise** ``R`` of a window estimate, estimated from the log
  itself: the median absolute difference of the last ``NOISE_MEMORY``
  successive window estimates, ``R = (MAD / 0.6745 / √2)²``, floored at
  ``(σ_floor · scale)²`` (robust to a change, which spoils only a few
  differences);
* **warm-up**: until :data:`NOISE_MIN` windows have been seen ``R`` is a guess
  (the sampling σ), and a coordinate whose prior is no surer than that reports
  the window's estimate as it is (averaging a sampler still converging from a
  nominal prior only lags it); a confident prior (a belief from ``identify``)
  is fused as below from the first window on;
* **Kalman update** ``P⁻ = P + q² Δt``, ``K = P⁻ / (P⁻ + R)``,
  ``x = x + K (y − x)``, ``P = (1 − K) P⁻`` — the closed-form minimiser of
  ``(x − x⁻)²/P⁻ + (x − y)²/R``, i.e. eq. (4)'s prior term with ``W_p = 1/P⁻``
  where the data term is taken as quadratic around ``y``;
* **change detection** on the normalised innovation ``z = (y − x⁻)/√(P⁻ + R)``:
  an innovation beyond :data:`GATE` σ is held (not fused) until a window that
  shares no data with the first one (starting at or after its end) confirms it
  on the same side — then the filter restarts at that window's estimate with
  ``P = R``; an innovation inside the gate clears what was held. A two-sided
  CUSUM (Page, *Biometrika* 1954; ``k`` = :data:`CUSUM_K`, ``h`` =
  :data:`CUSUM_H`, the textbook pair) catches shifts too small for the gate
  and restarts the variance (``P = R``) the same way.

So a parameter that stays put is averaged over many windows (its reported σ
shrinks with ``√P``, scaled for windows that share data: :attr:`WindowFusion.std`),
an isolated outlier window is ignored, and a jump is followed one
non-overlapping window after it shows.

*Measured* (``benchmarks/mhe_accuracy.py --seeds 8``, one thread per run; the
``mhe-replay`` row is its defaults, 300 steps and 20 samples per update, fused):

==========================  ===========  ============  ==============  =================
setting                     mass switch  worst post    T4 step @3 s /  ``noisy_b`` μ
                            targets      switch error  from 3 s        within 0.05 (worst)
==========================  ===========  ============  ==============  =================
``mhe-replay`` (fused)      8/8          6.3 %         7/8, 6/8        8/8 (0.043)
the same, not fused         8/8          5.3 %         7/8, 4/8        0/8 (0.112)
library (10 samples, 150)   5/8          13.6 %        6/8, 3/8        0/8 (0.146)
library, fused              3/8          14.0 %        6/8, 4/8        5/8 (0.088)
==========================  ===========  ============  ==============  =================

With 10 samples the windows follow the mass switch more slowly and the
confirmation delay costs it, so only ``mhe-replay`` fuses by default. On a
mass switch recorded through noisy motion capture (``mass_switch.mcap`` given
``noisy_b``'s mocap by ``benchmarks/mocap_degrade.py --seed 21``) no setting
meets the targets; fused, the worst errors are 16.8 % before and 24.7 % after
the switch and μ 0.133, against 16.8 %, 27.6 % and 0.212 not fused.
"""

from __future__ import annotations

import numpy as np

#: Normalised innovation [σ] beyond which a window is held as a possible change.
GATE = 3.0
#: CUSUM reference value and decision threshold, in σ of the normalised innovation.
CUSUM_K, CUSUM_H = 0.5, 4.0
#: Random-walk rate of each parameter, in its nominal scale per √s.
PROCESS_RATE = 0.01
#: Window estimates whose successive differences give the measurement noise ``R``.
NOISE_MEMORY = 16
#: Window estimates needed before ``R`` is read from them (before: the initial σ).
NOISE_MIN = 4


class WindowFusion:
    """Per-coordinate Kalman fusion of successive window estimates with change detection (module doc).

    Args:
        mean0: (d,) initial estimate (the prior ``p̂_0``).
        std0: (d,) its σ (the prior's: a confident belief from ``identify`` is
            held until the windows disagree with it, the nominal prior is not).
        noise0: (d,) σ of one window estimate assumed until :data:`NOISE_MIN`
            window estimates have been seen.
        scale: (d,) nominal scale of each coordinate (``ParameterSpace.scale``).
        floor: σ floor of ``R`` in units of ``scale``.
        window: ``H`` [s]: windows ending less than ``H`` apart share data.

    Attributes:
        mean: (d,) fused estimate.
        std: (d,) its σ, ``√P`` scaled for windows that share data (:meth:`overlap`).
        restarts: number of confirmed changes and CUSUM restarts so far.

    Raises:
        ValueError: shapes that disagree, or a non-positive ``std0``/``noise0``/``scale``/``window``.
    """

    def __init__(self, mean0: np.ndarray, std0: np.ndarray, noise0: np.ndarray, scale: np.ndarray, floor: float,
                 window: float):
        mean0, std0, noise0, scale = (np.asarray(a, dtype=float).copy() for a in (mean0, std0, noise0, scale))
        if not (mean0.shape == std0.shape == noise0.shape == scale.shape) or mean0.ndim != 1:
            raise ValueError(f"mean0 {mean0.shape}, std0 {std0.shape}, noise0 {noise0.shape} and scale "
                             f"{scale.shape} must be (d,) alike")
        if np.any(std0 <= 0) or np.any(noise0 <= 0) or np.any(scale <= 0) or not window > 0:
            raise ValueError("std0, noise0, scale and window must be positive")
        self.x, self.P = mean0, std0 ** 2
        self.r0, self.scale, self.window = noise0 ** 2, scale, float(window)
        self.r_floor = (floor * scale) ** 2
        self.history: list[np.ndarray] = []
        self.times: list[float] = []
        d = mean0.size
        self.cusum_hi, self.cusum_lo = np.zeros(d), np.zeros(d)
        self.held: list[list[tuple[float, float]]] = [[] for _ in range(d)]
        self.restarts = 0

    @property
    def mean(self) -> np.ndarray:
        """(d,) fused estimate (a copy)."""
        return self.x.copy()

    @property
    def std(self) -> np.ndarray:
        """(d,) σ of the fused estimate: ``√(P · overlap)``, the windows' scatter averaged.

        ``P`` treats the windows as independent, but successive windows share
        data: their differences understate one window's noise, and an average
        of ``n`` of them holds fewer than ``n`` windows' worth. So the variance
        is scaled by ``H / Δt`` (windows per window length, from the times of
        the fused windows) and by the ratio of ``R`` read from windows ``H``
        apart (sharing no data) to ``R`` read from successive ones, where it
        exceeds 1 (*measured* on replays of 8 seeds: 2σ held the truth in 57 %
        of ``noisy_b``'s mass estimates and 42 % of ``mass_switch``'s after the
        switch with ``√P``, in 83 % and 93 % so scaled; μ 99–100 %). A bias that
        all windows share is in neither.
        """
        return np.sqrt(self.P * self.overlap())

    def overlap(self) -> np.ndarray:
        """(d,) factor ≥ 1 on ``P`` for windows that share data (:attr:`std`)."""
        n = len(self.times)
        if n < NOISE_MIN:
            return np.ones_like(self.P)
        t = np.array(self.times[-NOISE_MEMORY - 1:])
        H = np.array(self.history[-NOISE_MEMORY - 1:])
        per_window = max(self.window / max(float(np.median(np.diff(t))), 1e-9), 1.0)
        # each window against the latest one that ended at least H before it
        j = np.searchsorted(t, t - self.window + 1e-9, side="right") - 1
        ok = j >= 0
        if ok.sum() < NOISE_MIN - 1:
            return np.full_like(self.P, per_window)
        return per_window * np.maximum(self._variance(H[ok] - H[j[ok]]) / self.noise(), 1.0)

    def noise(self) -> np.ndarray:
        """(d,) variance ``R`` of one window estimate, from the recent window estimates (module doc)."""
        if len(self.history) < NOISE_MIN:
            return self.r0.copy()
        return self._variance(np.diff(np.array(self.history[-NOISE_MEMORY:]), axis=0))

    def _variance(self, diffs: np.ndarray) -> np.ndarray:
        """(d,) variance of one estimate from (n, d) differences of two: ``(MAD / 0.6745 / √2)²``, floored."""
        mad = np.median(np.abs(diffs), axis=0)
        return np.maximum((mad / 0.6745 / np.sqrt(2.0)) ** 2, self.r_floor)

    def restart(self, i: int, value: float, variance: float | None = None, keep_held: bool = False) -> None:
        """Restart coordinate ``i`` at ``value`` with ``variance`` (None: one window's, :meth:`noise`), forgetting
        the CUSUM sums and what was held: what a confirmed change does, and what an estimator that places the
        value by other means (:mod:`~amhe_cli.estimation.attribution`) asks for. With ``keep_held`` the windows
        held beyond the gate stay, for a later one sharing no data with them to confirm."""
        self.x[i] = value
        self.P[i] = self.noise()[i] if variance is None else variance
        if not keep_held:
            self.held[i] = []
        self.cusum_hi[i] = self.cusum_lo[i] = 0.0

    def update(self, t: float, y: np.ndarray) -> np.ndarray:
        """Fuse the estimate ``y`` (d,) of the window ending at ``t`` [s]; returns the fused (d,) estimate."""
        y = np.asarray(y, dtype=float)
        dt = max(t - self.times[-1], 0.0) if self.times else 0.0
        self.history.append(y.copy())
        self.times.append(float(t))
        R = self.noise()
        Pm = self.P + (PROCESS_RATE * self.scale) ** 2 * dt
        # until the windows' noise can be read, a prior no surer than one window gives way to the window
        warm = (len(self.history) < NOISE_MIN) & (Pm >= R)
        for i in range(y.size):
            if warm[i]:
                self.x[i], self.P[i] = y[i], R[i]
                continue
            nu = y[i] - self.x[i]
            z = nu / np.sqrt(Pm[i] + R[i])
            if abs(z) > GATE:
                held = [(tt, v) for tt, v in self.held[i] if np.sign(v - self.x[i]) == np.sign(nu)]
                if held and t - self.window >= held[0][0] - 1e-9:  # confirmed by a window sharing no data
                    self.restart(i, y[i], R[i])
                    self.restarts += 1
                else:
                    self.held[i] = held + [(t, y[i])]
                    self.P[i] = Pm[i]
                continue
            self.held[i] = []
            self.cusum_hi[i] = max(0.0, self.cusum_hi[i] + z - CUSUM_K)
            self.cusum_lo[i] = max(0.0, self.cusum_lo[i] - z - CUSUM_K)
            if self.cusum_hi[i] > CUSUM_H or self.cusum_lo[i] > CUSUM_H:
                Pm[i] = R[i]
                self.cusum_hi[i] = self.cusum_lo[i] = 0.0
                self.restarts += 1
            K = Pm[i] / (Pm[i] + R[i])
            self.x[i] += K * nu
            self.P[i] = (1.0 - K) * Pm[i]
        return self.mean
