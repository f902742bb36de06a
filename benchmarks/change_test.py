"""What each window's change test reads before and after a change of the box, through noisy motion capture.

Usage::

    python benchmarks/change_test.py LOG [LOG ...] [--clips 16] [--draws 1] [--jobs 2] [--out rows.jsonl]

The online MHE with ``attribute`` tests each informative window's data for a moved friction force
(:meth:`~amhe_cli.estimation.attribution.SplitTracker.test`): clips drawn from the window's second of data,
scored by the shared cost at the split held and at the friction force moved by ``exp(±CHANGE)`` along either
line (:meth:`~amhe_cli.estimation.attribution.SplitTracker.test_candidates`). This replays that test on every
window of each LOG (``<stem>.truth.csv`` beside it, as ``amhe run`` writes and ``mocap_degrade.py`` keeps),
the split held at the truth before the log's last change, ``W_x`` the windows' own for the log. A row per
(LOG, draw of clips): each window's best gain (a share of the held split's cost) and its direction (+1: more
force), then the largest gain before the change, the smallest from 1.5 s after it until the box next rests,
the first window after it past ``DETECT``, and the pairs of successive windows past ``DETECT`` the same way
before it (what would open a change where there was none). docs/evaluation.md, "A change test on each
window's data".
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

NAMES = ("box_mass", "box_friction")


def one(job: tuple) -> dict:
    """One (log, draw): the change test at every window of the log."""
    from amhe_cli.estimation.attribution import DETECT, SplitTracker, test_reading
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.mhe import MHESettings, decision_clips
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import truth_series
    warnings.simplefilter("ignore")
    log, draw, n_clips = job
    pr = load_problem(log, params=NAMES)
    traj, s = pr.traj, MHESettings()
    truth = truth_series(log, traj)
    changes = [float(c[-1]) for n in NAMES if len(c := truth.change_times(n))]
    if not changes:
        raise SystemExit(f"{log}: its truth has no change of box_mass or box_friction")
    t_c = max(changes)
    sl = pr.space.slices()
    held = np.array([float(truth.at(n, np.array([t_c - 0.2]))[0]) for n in NAMES])
    tracker = SplitTracker((sl["box_mass"].start, sl["box_friction"].start), pr.space.mean0, pr.space.std0,
                           pr.space.scale * s.sigma_init, s.sigma_floor, s.window, s.every)
    tracker.ref = tuple(held)
    P = tracker.test_candidates(pr.space.mean0)
    rng = np.random.default_rng(draw)
    weights = StateWeights.for_log(traj)
    windows, cost = [], None
    for t in np.arange(s.window, float(traj.t[-1]), s.every):
        stop = int(np.searchsorted(traj.t, t, side="right"))
        clips = decision_clips(traj, pr.scene, stop, t - s.window, n_clips, rng, s.min_speed)
        if clips is None:
            windows.append([round(float(t), 2), None, 0])  # the box at rest
            continue
        if cost is None:
            cost = RolloutCost(pr.scene, pr.space, clips, weights, nthread=1)
        else:
            cost.set_clips(clips, weights)
        reading = test_reading(cost.evaluate(P).data)
        windows.append([round(float(t), 2), None if reading is None else round(reading[0], 3),
                        0 if reading is None else reading[1]])
    if cost is not None:
        cost.close()
    before = [w for w in windows if w[0] <= t_c and w[1] is not None]
    after = [w for w in windows if w[0] >= t_c + 1.5]
    rest = next((i for i, w in enumerate(after) if w[1] is None), len(after))
    pairs = sum(1 for a, b in zip(before, before[1:])
                if a[1] >= DETECT and b[1] >= DETECT and a[2] == b[2] and b[0] - a[0] <= s.every + 1e-6)
    first = next((w[0] for w in windows if w[0] > t_c and w[1] is not None and w[1] >= DETECT), None)
    return {"log": log, "draw": draw, "change": round(t_c, 2), "windows": windows,
            "max_before": max((w[1] for w in before), default=None),
            "min_after": min((w[1] for w in after[:rest]), default=None),
            "first_after_s": None if first is None else round(first - t_c, 2),
            "pairs_before": pairs, "tested_before": len(before)}


def table(rows: list[dict]) -> None:
    from pathlib import Path
    print(f"{'log':<16} {'draw':>4} {'change':>7} {'max before':>11} {'min 1.5 s after':>16} {'first past':>11} "
          f"{'false pairs':>12}")
    for r in sorted(rows, key=lambda r: (r["log"], r["draw"])):
        fmt = lambda v, f: "–" if v is None else format(v, f)  # noqa: E731
        print(f"{Path(r['log']).stem:<16} {r['draw']:>4} {r['change']:7.2f} {fmt(r['max_before'], '+.2f'):>11} "
              f"{fmt(r['min_after'], '+.2f'):>16} {fmt(r['first_after_s'], '.2f'):>11} "
              f"{r['pairs_before']:>5} of {r['tested_before']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="*")
    ap.add_argument("--clips", type=int, default=None, help="clips per test (default: the estimator's TEST_CLIPS)")
    ap.add_argument("--draws", type=int, default=1, help="draws of clips per log")
    from amhe_cli.estimation.attribution import TEST_CLIPS
    from window_information import rows_main  # beside this script
    rows_main(ap, lambda a: [(log, d, a.clips or TEST_CLIPS) for log in a.logs for d in range(a.draws)], one, table)


if __name__ == "__main__":
    main()
