"""Which parameter changed? One change of the box told from the other through noisy motion capture.

Usage::

    python benchmarks/change_attribution.py LOG [LOG ...] [--delay 0.5] [--window 3] [--clips N] [--draws 4]
        [--horizon LO,HI] [--jobs 2] [--out rows.jsonl]

Through 1 mm motion capture the online MHE tracks the friction force m·μ after a change but not its split
(docs/evaluation.md, "The issue's grids on one version"). Where one parameter changes at a time (a box
swapped: its mass; a floor that changes: its friction), the question an estimator has to answer is
smaller than "which (m, μ)": it is "which one moved". This scores the two one-parameter answers with the
shared cost (:class:`~amhe_cli.estimation.cost.RolloutCost`, ``W_x`` from the log's own pose noise as
``identify`` takes it, no prior term) on the same clips, drawn as ``identify`` draws them from the window
[change + ``--delay``, change + ``--delay`` + ``--window``] s:

* ``H_mass``: the friction held at its value before the change, the mass over a grid (1–12 kg);
* ``H_mu``: the mass held at its value before the change, the friction over a grid (0.1–1.5).

Held values are the truth before the change: the best an estimator that had converged before it could
hold. For each LOG (with ``<stem>.truth.csv`` beside it, as ``amhe run`` writes and
``benchmarks/mocap_degrade.py`` keeps) and each draw of clips, a row: both hypotheses' best cost and
value, the one with the lower cost, whether that is the parameter that changed, and how far apart the two
costs are against their spread over the draws. Rows go to ``--out`` as they finish; the table per log
says in how many draws the changed parameter won.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

NAMES = ("box_mass", "box_friction")
GRID = {"box_mass": np.linspace(1.0, 12.0, 45), "box_friction": np.linspace(0.1, 1.5, 57)}


def one(job: tuple) -> dict:
    """One (log, draw): both hypotheses scored on one draw of clips from the window after the log's last change."""
    from amhe_cli.estimation.clips import sample_clips
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.identify import IdentifySettings, clip_plan
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import truth_series
    warnings.simplefilter("ignore")
    log, draw, delay, window, n_clips, span = job
    pr = load_problem(log, params=NAMES)
    truth = truth_series(log, pr.traj)
    changes = [(float(c[-1]), n) for n in NAMES if len(c := truth.change_times(n))]
    if not changes:
        raise SystemExit(f"{log}: its truth has no change of box_mass or box_friction")
    t_c, changed = max(changes)
    before = {n: float(truth.at(n, np.array([t_c - 0.2]))[0]) for n in NAMES}
    after = {n: float(truth.at(n, np.array([t_c + 0.2]))[0]) for n in NAMES}
    t0 = t_c + delay
    t1 = min(t0 + window, float(pr.traj.t[-1]))
    n, horizon, _ = clip_plan(pr.traj, n_clips, span)  # identify's clip length for this log's noise, or as given
    clips = sample_clips(pr.traj, pr.scene, n, horizon, rng=np.random.default_rng(draw), t_range=(t0, t1))
    weights = StateWeights.for_log(pr.traj, dict(IdentifySettings().sigma))
    out = {"log": log, "draw": draw, "window": [round(t0, 2), round(t1, 2)], "horizon": list(horizon),
           "clips": len(clips.horizon), "changed": changed,
           "before": before, "after": after}
    with RolloutCost(pr.scene, pr.space, clips, weights, prior_weight=0.0, nthread=1) as cost:
        for hyp, free in (("H_mass", "box_mass"), ("H_mu", "box_friction")):
            grid = GRID[free]
            P = np.stack([pr.space.vector({**before, free: float(v)}) for v in grid])
            J = np.asarray(cost(P), dtype=float)
            k = int(np.nanargmin(J))
            out[hyp] = {"cost": float(J[k]), "value": float(grid[k]), "at_edge": k in (0, len(grid) - 1)}
        out["truth_after_cost"] = float(cost(pr.space.vector(after)[None])[0])
    won = "box_mass" if out["H_mass"]["cost"] < out["H_mu"]["cost"] else "box_friction"
    out["won"] = won
    out["right"] = won == changed
    out["margin"] = (out["H_mass"]["cost"] - out["H_mu"]["cost"]) / max(out["H_mass"]["cost"], out["H_mu"]["cost"])
    return out


def table(rows: list[dict]) -> None:
    print(f"{'log':<16} {'changed':<12} {'window [s]':>12} {'right':>6} {'H_mass kg':>10} {'H_mu':>6} "
          f"{'cost gap %':>18}")
    for log in sorted({r["log"] for r in rows}):
        rs = [r for r in rows if r["log"] == log]
        gap = np.array([100 * r["margin"] for r in rs])  # > 0: friction explains the window better
        print(f"{Path(log).stem:<16} {rs[0]['changed']:<12} {rs[0]['window'][0]:5.1f}–{rs[0]['window'][1]:<5.1f} "
              f"{sum(r['right'] for r in rs):>2}/{len(rs):<3} {np.median([r['H_mass']['value'] for r in rs]):10.2f} "
              f"{np.median([r['H_mu']['value'] for r in rs]):6.2f} {gap.mean():+8.2f} (±{gap.std():5.2f})")
    n = len(rows)
    print(f"the changed parameter won in {sum(r['right'] for r in rows)} of {n} draws")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="*")
    ap.add_argument("--delay", type=float, default=0.5, help="window start after the change [s]")
    ap.add_argument("--window", type=float, default=3.0, help="window length [s]")
    ap.add_argument("--clips", type=int, default=None, help="clips per draw (default: identify's for the log)")
    ap.add_argument("--draws", type=int, default=4, help="draws of clips per log")
    ap.add_argument("--horizon", default=None, metavar="LO,HI",
                    help="clip lengths [s] (default: identify's for the log's noise, 0.1-0.2 s on a noisy one)")
    from window_information import rows_main  # beside this script

    def jobs(a):
        span = None if a.horizon is None else tuple(float(x) for x in a.horizon.split(","))
        return [(log, d, a.delay, a.window, a.clips, span) for log in a.logs for d in range(a.draws)]
    rows_main(ap, jobs, one, table)

if __name__ == "__main__":
    main()
