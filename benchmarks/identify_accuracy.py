"""Accuracy and wall time of ``identify`` across seeds and settings, against ground truth.

Usage::

    python benchmarks/identify_accuracy.py LOG TRUTH.yaml [--seeds 4] [--jobs 4] [--threads 2]
        [--setting name:clips,popsize,generations ...] [--params box_mass,box_friction]

TRUTH.yaml is either an amhe belief (``parameters.box_mass.value``,
``parameters.box_friction.value``) or a ground-truth YAML holding
``box: {mass_schedule: [{mass_kg: M}, ...]}`` and
``floor: {regions: [{mu_sliding_box_floor: MU}, ...]}`` (the first entry of each
is used). For logs amhe wrote, the truth is also in their ``amhe_truth``
metadata record (docs/log_schema.md#metadata-records). Each (setting, seed) runs in its own process with ``--threads``
rollout threads; the table gives mean ± std over seeds of the mass error [%],
the friction error, and the wall time. Last line: ``worst_mass_err_pct=… worst_mu_err=…``.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import yaml


def truth_of(path: str) -> tuple[float, float]:
    d = yaml.safe_load(open(path))
    if "parameters" in d:  # an amhe belief
        return float(d["parameters"]["box_mass"]["value"]), float(d["parameters"]["box_friction"]["value"])
    return float(d["box"]["mass_schedule"][0]["mass_kg"]), float(d["floor"]["regions"][0]["mu_sliding_box_floor"])


def one(job):
    log, params, clips, popsize, gens, seed, threads = job
    from amhe_cli.estimation.identify import IdentifySettings, identify
    from amhe_cli.model.params import parse_names
    from amhe_cli.estimation.problem import load_problem
    free = parse_names(params)
    pr = load_problem(log, params=free)
    t0 = time.perf_counter()
    res = identify(pr.traj, pr.scene, pr.space,
                   IdentifySettings(params=free, n_clips=clips, popsize=popsize, max_gen=gens, seed=seed),
                   nthread=threads)
    est = res.summary()
    return est["estimate"]["box_mass"], est["estimate"]["box_friction"], est["std"]["box_mass"], \
        time.perf_counter() - t0, len(res.history)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("truth")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--params", default=None)
    ap.add_argument("--setting", action="append", default=None,
                    help="name:clips,popsize,generations (repeatable); default: the CLI defaults")
    a = ap.parse_args()
    m_true, mu_true = truth_of(a.truth)
    settings = a.setting or ["default:32,16,50"]
    jobs, names = [], []
    for s in settings:
        name, _, nums = s.partition(":")
        c, p, g = (int(x) for x in nums.split(","))
        for seed in range(a.seeds):
            jobs.append((a.log, a.params, c, p, g, seed, a.threads))
            names.append(name)
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        out = list(ex.map(one, jobs))
    print(f"truth: mass {m_true} kg, mu {mu_true}")
    print(f"{'setting':<14} {'mass err %':>16} {'mu err':>16} {'reported std kg':>16} {'wall s':>12} {'gens':>6}")
    worst_m = worst_mu = 0.0
    for name in dict.fromkeys(names):
        rows = np.array([o for o, n in zip(out, names) if n == name])
        me = 100 * (rows[:, 0] - m_true) / m_true
        mue = rows[:, 1] - mu_true
        worst_m, worst_mu = max(worst_m, np.abs(me).max()), max(worst_mu, np.abs(mue).max())
        print(f"{name:<14} {me.mean():+7.2f} ± {me.std():5.2f} {mue.mean():+8.4f} ± {mue.std():.4f} "
              f"{rows[:, 2].mean():16.4f} {rows[:, 3].mean():6.1f} ± {rows[:, 3].std():4.1f} {rows[:, 4].mean():6.1f}")
        for r in rows:
            print(f"    mass {r[0]:.3f}  mu {r[1]:.4f}  {r[3]:.1f} s")
    print(f"worst_mass_err_pct={worst_m:.2f} worst_mu_err={worst_mu:.4f}")


if __name__ == "__main__":
    main()
