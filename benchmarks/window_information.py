"""Can a few seconds of data tell mass from friction? ``identify`` on consecutive windows after a change.

Usage::

    python benchmarks/window_information.py LOG [LOG ...] [--window 3] [--seeds 4] [--jobs 16] [--out rows.jsonl]

The online MHE is judged from 3 s after each change of the world (docs/evaluation.md). This asks what
the *data* of such windows allow, whatever the estimator: for each LOG (a truth CSV beside it, as
``amhe run`` writes and ``benchmarks/mocap_degrade.py`` keeps), the windows of ``--window`` seconds
from its last change of mass or friction (the log's start if none) to its end, and for each window
and seed ``identify`` — the offline estimator, no real-time budget: 24 CMA-ES generations over
the window's most informative clips, the noise handling of ``amhe identify`` — with the box's mass
and friction free (``--t-range`` = the window). Each row: the estimate against the truth at the
window's middle, the stated σ, and how the box moved in the window (its mean speed and the RMS of its
speed's changes about that mean: a box pushed at a steady crawl shows the friction force m·μ·g, and
only its accelerations show m apart from μ). Rows go to ``--out`` as they finish; the table per
(log, window) gives the mass and μ errors over the seeds and how many held 10 % and 0.05.
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np


def windows(log: str, length: float) -> list[tuple[float, float]]:
    """Consecutive (t0, t1) windows [s] from the log's last change of the truth (+0.05 s) to its end."""
    import warnings

    from amhe_cli.io.reader import read_log
    from amhe_cli.estimation.replay import truth_series
    with warnings.catch_warnings():  # the reader's notes on a noisy log: identify's own read repeats them
        warnings.simplefilter("ignore")
        traj = read_log(log)
    truth = truth_series(log, traj)
    last = [float(c[-1]) for c in (truth.change_times(n) for n in ("box_mass", "box_friction")) if len(c)]
    change = max(last, default=0.0)
    start = change + 0.05 if change > 0 else float(traj.t[0])
    end = float(traj.t[-1])
    out = []
    while start + length <= end + 1e-9:
        out.append((round(start, 2), round(start + length, 2)))
        start += length
    return out


def one(job: tuple) -> dict:
    import warnings

    from amhe_cli.estimation.identify import IdentifySettings, identify
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import truth_series
    warnings.simplefilter("ignore")
    log, (t0, t1), seed = job
    pr = load_problem(log, params=("box_mass", "box_friction"))
    res = identify(pr.traj, pr.scene, pr.space, IdentifySettings(params=("box_mass", "box_friction"), seed=seed,
                                                                   t_range=(t0, t1)), nthread=1)
    s = res.summary()
    truth = truth_series(log, pr.traj)
    mid = np.array([(t0 + t1) / 2])
    keep = (pr.traj.t >= t0) & (pr.traj.t <= t1)
    speed = np.linalg.norm(pr.traj.box_linvel[keep, :2], axis=1)
    return {"log": log, "window": [t0, t1], "seed": seed,
            "mass": s["estimate"]["box_mass"], "mass_std": s["std"]["box_mass"],
            "mu": s["estimate"]["box_friction"], "mu_std": s["std"]["box_friction"],
            "true_mass": float(truth.at("box_mass", mid)[0]), "true_mu": float(truth.at("box_friction", mid)[0]),
            "speed": float(speed.mean()), "speed_rms_change": float(speed.std())}


def table(rows: list[dict]) -> None:
    print(f"{'log':<14} {'window [s]':>12} {'n':>2} {'box speed':>9} {'± [m/s]':>7} {'mass err %':>16} "
          f"{'mass σ %':>8} {'mu err':>14} {'held':>5}")
    for key in sorted({(r["log"], tuple(r["window"])) for r in rows}):
        rs = [r for r in rows if (r["log"], tuple(r["window"])) == key]
        me = np.array([100 * (r["mass"] / r["true_mass"] - 1) for r in rs])
        mue = np.array([r["mu"] - r["true_mu"] for r in rs])
        held = sum(abs(a) <= 10 and abs(b) <= 0.05 for a, b in zip(me, mue))
        print(f"{Path(key[0]).stem:<14} {key[1][0]:5.1f}–{key[1][1]:<5.1f} {len(rs):>2} {rs[0]['speed']:9.3f} "
              f"{rs[0]['speed_rms_change']:7.3f} {me.mean():+7.1f} (±{me.std():4.1f}) "
              f"{100 * np.median([r['mass_std'] / r['true_mass'] for r in rs]):8.1f} "
              f"{mue.mean():+7.3f} ({np.abs(mue).max():.3f}) {held:>2}/{len(rs)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="*")
    ap.add_argument("--window", type=float, default=3.0, help="window length [s]")
    ap.add_argument("--seeds", type=int, default=4)
    rows_main(ap, lambda a: [(log, w, seed) for log in a.logs for w in windows(log, a.window)
                             for seed in range(a.seeds)], one, table)


def rows_main(ap: argparse.ArgumentParser, make_jobs, fn, table_fn) -> None:
    """The rest of a row-writing benchmark's command line: ``--jobs``, ``--out`` and ``--table`` added to ``ap``;
    then either the table of an existing ``--out`` file, or ``fn(job)`` for every job of ``make_jobs(args)``
    (:func:`run_rows`) and their table."""
    ap.add_argument("--jobs", type=int, default=os.cpu_count())
    ap.add_argument("--out", default=None, help="JSON-lines file each row is appended to as it finishes")
    ap.add_argument("--table", default=None, help="only print the table of an existing --out file")
    a = ap.parse_args()
    if a.table:
        table_fn([json.loads(line) for line in open(a.table)])
        return
    table_fn(run_rows(fn, make_jobs(a), a.jobs, a.out))


def run_rows(fn, jobs: list, n_jobs: int, out: str | None) -> list[dict]:
    """``fn(job)`` for every job in ``n_jobs`` processes; each row printed as a JSON line and appended to ``out``
    as it finishes (a run cut off keeps what finished). Returns the rows in finishing order."""
    rows = []
    with ProcessPoolExecutor(n_jobs) as ex:
        for fut in as_completed([ex.submit(fn, job) for job in jobs]):
            r = fut.result()
            rows.append(r)
            print(json.dumps(r), flush=True)
            if out:
                with open(out, "a") as f:
                    f.write(json.dumps(r) + "\n")
    return rows


if __name__ == "__main__":
    main()
