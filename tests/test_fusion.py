"""Fusing successive MHE window estimates: averaging, outliers, changes, bad input."""

from __future__ import annotations

import numpy as np
import pytest

import amhe_cli.estimation.fusion as fusion_module
from amhe_cli.estimation.fusion import GATE, WindowFusion

SCALE = np.array([3.0, 0.5])  # box mass [kg], friction [-]


def fusion(mean0=(4.0, 0.5), std0=(3.0, 0.5), noise0=(0.45, 0.075), window=1.0):
    return WindowFusion(np.array(mean0), np.array(std0), np.array(noise0), SCALE, floor=0.01, window=window)


def feed(f, truth, sigma, n, rng, t0=0.0, every=0.5):
    out = []
    for k in range(n):
        out.append(f.update(t0 + k * every, truth(t0 + k * every) + sigma * rng.standard_normal(2)))
    return np.array(out)


def test_a_constant_parameter_is_averaged_over_windows():
    rng = np.random.default_rng(0)
    truth, sigma = np.array([4.2, 0.55]), np.array([0.3, 0.04])
    f = fusion(window=0.5)  # windows 0.5 s long every 0.5 s: independent
    est = feed(f, lambda t: truth, sigma, 40, rng)
    late = est[20:] - truth
    # the windows scatter by sigma; the fused estimate by a fraction of it, and its sigma says so
    assert np.all(np.sqrt((late ** 2).mean(axis=0)) < 0.5 * sigma)
    assert np.all(f.std < 0.5 * sigma) and np.all(f.std > 0.05 * sigma)
    assert f.restarts <= 1


def test_the_stated_sigma_holds_the_truth_when_successive_windows_share_data():
    """Windows of 1 s every 0.5 s share half their data: their errors are correlated (MA(1))."""
    rng = np.random.default_rng(4)
    truth, sigma = np.array([4.2, 0.55]), np.array([0.3, 0.04])
    f = fusion()
    e = rng.standard_normal((401, 2))
    covered, covered_p = [], []
    for k in range(1, 401):
        x = f.update(0.5 * k, truth + sigma * (e[k] + e[k - 1]) / np.sqrt(2.0))
        if k > 20:
            covered.append(np.abs(x - truth) <= 2 * f.std)
            covered_p.append(np.abs(x - truth) <= 2 * np.sqrt(f.P))
    assert np.mean(covered) >= 0.85  # nominally 95 %
    assert np.mean(covered) > np.mean(covered_p) + 0.05  # √P alone, as if independent, is too narrow
    assert np.all(f.overlap() >= 2.0)  # two windows per window length


def test_a_nominal_prior_gives_way_to_the_first_windows_a_confident_one_does_not():
    y = np.array([2.5, 0.3])
    vague = fusion(mean0=(3.7, 0.5))
    np.testing.assert_allclose(vague.update(1.0, y), y)  # the nominal prior knows less than one window
    sure = fusion(mean0=(2.6, 0.32), std0=(0.02, 0.002))
    first = sure.update(1.0, y)
    assert np.all(np.abs(first - [2.6, 0.32]) < 0.01 * np.abs(y - [2.6, 0.32]) + 1e-12)


def test_an_isolated_outlier_window_is_held_not_fused():
    rng = np.random.default_rng(1)
    truth, sigma = np.array([4.0, 0.5]), np.array([0.05, 0.005])
    f = fusion()
    feed(f, lambda t: truth, sigma, 20, rng)
    before = f.mean
    after_outlier = f.update(10.0, truth + np.array([2.0, 0.2]))  # 40 σ off, once
    np.testing.assert_allclose(after_outlier, before)
    f.update(10.5, truth)  # the next window disagrees with it: the outlier is dropped
    assert np.all(np.abs(f.mean - truth) < 3 * sigma)
    assert f.restarts == 0


def test_a_step_is_followed_once_a_window_sharing_no_data_confirms_it():
    rng = np.random.default_rng(2)
    sigma = np.array([0.05, 0.005])
    f = fusion()
    feed(f, lambda t: np.array([4.0, 0.5]), sigma, 20, rng)  # t = 0 ... 9.5
    new = np.array([6.0, 0.5])
    held = f.update(10.0, new)  # the first window past the switch is held
    assert abs(held[0] - 4.0) < 0.2
    f.update(10.5, new + sigma * rng.standard_normal(2))  # overlaps the held window: still held
    assert abs(f.mean[0] - 4.0) < 0.2
    f.update(11.0, new + sigma * rng.standard_normal(2))  # starts where the held one ended: confirmed
    assert abs(f.mean[0] - 6.0) < 3 * sigma[0] and abs(f.mean[1] - 0.5) < 3 * sigma[1]
    assert f.restarts == 1


def test_a_small_sustained_shift_is_followed(monkeypatch):
    """Inside the gate a shift is followed by the random walk; without one (rate 0) the CUSUM restarts it."""
    for rate in (None, 0.0):
        if rate is not None:
            monkeypatch.setattr(fusion_module, "PROCESS_RATE", rate)
        rng = np.random.default_rng(3)
        sigma = np.array([0.1, 0.01])
        f = fusion()
        feed(f, lambda t: np.array([4.0, 0.5]), sigma, 20, rng)
        shift = np.array([0.0, 2.0 * sigma[1]])  # inside the gate
        assert np.all(shift / sigma < GATE)
        est = feed(f, lambda t: np.array([4.0, 0.5]) + shift, sigma, 16, rng, t0=10.0)
        assert abs(est[-1, 1] - 0.52) < 0.4 * shift[1]
        if rate == 0.0:
            assert f.restarts >= 1


@pytest.mark.parametrize("kw, words", [
    (dict(mean0=np.zeros(2), std0=np.ones(3), noise0=np.ones(2), scale=np.ones(2), floor=0.01, window=1.0),
     "must be (d,) alike"),
    (dict(mean0=np.zeros(2), std0=np.array([1.0, 0.0]), noise0=np.ones(2), scale=np.ones(2), floor=0.01,
          window=1.0), "positive"),
    (dict(mean0=np.zeros(2), std0=np.ones(2), noise0=np.ones(2), scale=np.ones(2), floor=0.01, window=0.0),
     "positive"),
])
def test_bad_shapes_and_values_raise(kw, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        WindowFusion(**kw)
