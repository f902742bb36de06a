"""What a log says about its own sensors: rate, drops, stamp jitter, latency and noise per stream.

Measurement noise, latency and jitter are properties of the recording, not of
the box, and a lab's log rarely states them. They are measured here from the
messages themselves, before resampling:

* **rate** — the median message period;
* **drops** — the fraction of periods without a message;
* **jitter** — the robust spread (MAD) of the header stamps about the
  nearest multiple of the period on a line fitted through them;
* **latency** — the median of log (receive) time minus header stamp, where
  the messages carry stamps;
* **noise** — white-noise σ from second differences
  (:func:`~amhe_cli.io.smoothing.noise_sigma`): position [m] and orientation
  [rad] of a pose stream, joint angle [rad] of joint states.

The report lands in ``Trajectory.meta["sensors"]["streams"]`` and from there in
the summary and the belief's provenance; the estimator uses the noise for
``W_x`` (:meth:`~amhe_cli.estimation.cost.StateWeights.with_noise`).
"""

from __future__ import annotations

import numpy as np

from amhe_cli.io.smoothing import noise_sigma, robust_sigma
from amhe_cli.io.unpack import _Series


def stream_report(s: _Series) -> dict:
    """Rate [Hz], drop fraction, jitter [ms], latency [ms] and noise σ of one role's messages.

    Args:
        s: the role's unpacked messages (times = header stamps where present).
    Returns:
        plain dict: ``rate_hz``, ``messages``, ``dropped_fraction``,
        ``jitter_ms``, ``latency_ms`` (None without header stamps) and, for
        poses, ``position_noise_m``, ``orientation_noise_rad``; for joint states,
        ``joint_noise_rad``.
    """
    t = np.asarray(s.t_ns, dtype=float)
    n = len(t)
    out: dict = {"messages": int(n)}
    if n < 3:
        return out
    period = float(np.median(np.diff(t)))
    # message index on the clock: gaps rounded one at a time, so a period a little off does not accumulate
    k = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(np.diff(t) / period), 1.0))])
    expected = int(k[-1]) + 1
    fit = np.polyfit(k, t, 1)  # a clock with its own rate: residuals about the fitted line
    out.update({
        "rate_hz": round(1e9 / fit[0], 3),
        "dropped_fraction": round(max(0.0, 1.0 - n / expected), 4),
        "jitter_ms": round(float(robust_sigma(t - np.polyval(fit, k))) * 1e-6, 4),
        "latency_ms": None if s.latency_ns is None else round(s.latency_ns * 1e-6, 3),
    })
    f = s.fields
    if "pos" in f:
        sig_p, sig_r = s.pose_noise()
        out["position_noise_m"] = float(f"{sig_p:.3g}")
        out["orientation_noise_rad"] = float(f"{sig_r:.3g}")
    elif "dq" in f or "tau" in f:
        out["joint_noise_rad"] = float(f"{np.median(noise_sigma(f['q'])):.3g}")
    return out
