"""Accuracy, honesty of the stated σ (2σ coverage) and wall time of ``identify``, against ground truth.

Usage::

    python benchmarks/identify_accuracy.py LOG [LOG ...] [--seeds 8] [--first-seed 0] [--jobs 4] [--threads 1]
        [--params box_mass,box_inertia,box_friction] [--out rows.jsonl] [--identify-arg --clips=24 ...] [--device cuda]

The truth of each LOG is read from ``<LOG stem>.truth.yaml`` beside it
(``box.mass_schedule[0]`` mass and inertia, ``floor.regions[0]`` friction), from
an amhe belief given as ``LOG=TRUTH.yaml``, or from the ``amhe_truth`` metadata
record that logs amhe simulates carry. Each (log, seed) runs ``amhe identify``'s
code path (``load_problem`` + ``identify`` with the CLI defaults) in its own
process with ``--threads`` rollout threads; each finished run is appended to
``--out`` (JSON lines) at once, so a cut-off benchmark keeps its rows.

Per log, the table gives the mass error [%] (mean ± std, median, worst), the
worst friction error, the **2σ coverage** — the fraction of (run, parameter)
values whose stated interval ``estimate ± 2σ`` holds the truth, for mass,
friction and the three moments of inertia
(:func:`~amhe_cli.estimation.uncertainty.coverage`) —, the RMS of
(estimate − truth)/σ for mass and friction (``z``: 1 for an honest σ), the
median stated mass σ [% of the truth] and the median wall time. The last lines give the coverage and the worst errors over all logs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np
import yaml


def truth_of(log: str, given: str | None) -> dict:
    """name -> true value (box_mass, box_friction, box_inertia when known)."""
    path = Path(given) if given else Path(log).with_name(Path(log).stem + ".truth.yaml")
    if path.is_file():
        d = yaml.safe_load(path.read_text())
        if "parameters" in d:  # an amhe belief
            return {k: d["parameters"][k]["value"] for k in ("box_mass", "box_friction", "box_inertia")
                    if k in d["parameters"]}
        sched = d["box"]["mass_schedule"][0]
        out = {"box_mass": float(sched["mass_kg"]),
               "box_friction": float(d["floor"]["regions"][0]["mu_sliding_box_floor"])}
        if "inertia_diag_kgm2" in sched:
            out["box_inertia"] = [float(x) for x in sched["inertia_diag_kgm2"]]
        return out
    import warnings
    from amhe_cli.io.reader import read_log
    from amhe_cli.io.truth import metadata_truth
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = metadata_truth(read_log(log))
    if not truth:
        sys.exit(f"no truth for {log}: expected {path.name} beside it, LOG=TRUTH.yaml or an amhe_truth record")
    return {k: truth[k] for k in ("box_mass", "box_friction", "box_inertia") if k in truth}


def one(job: dict) -> dict:
    import warnings
    from dataclasses import replace

    from amhe_cli.estimation.identify import IdentifySettings, identify
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.model import device as dev
    from amhe_cli.model.params import parse_names
    warnings.simplefilter("ignore")
    dev.set_default(job.get("device", "cpu"))
    names = {"clips": "n_clips", "generations": "max_gen", "popsize": "popsize", "horizon": "horizon"}
    over = {names.get(k, k): (tuple(float(x) for x in str(v).split(",")) if k == "horizon" else v)
            for k, v in job["identify"].items()}
    settings = IdentifySettings(params=parse_names(job["params"]), seed=job["seed"], sigma=job.get("sigma", {}),
                                **over)
    t0 = time.perf_counter()
    # as `amhe identify` does: without --params the reading decides (a robot unlike its model frees its
    # robot-side parameters beside the box)
    pr = load_problem(job["log"], params=settings.params if job["params"] else None, smooth=job.get("smooth", "auto"))
    settings = replace(settings, params=pr.space.free)
    res = identify(pr.traj, pr.scene, pr.space, settings, nthread=job["threads"])
    s = res.summary()
    return {"log": job["log"], "seed": job["seed"], "tag": job.get("tag", ""), "estimate": s["estimate"], "std": s["std"],
            "truth": job["truth"], "wall_s": time.perf_counter() - t0, "generations": s["generations"],
            "residual_rms": s["cost"]["residual_rms"], "converged": s["converged"], "std_sources": s["std_sources"],
            "replicates": s["replicates"],
            # what the reading made of the log's robot: its payload fit, the gains (limits) and why it differs
            "robot": {k: pr.traj.meta.get("sensors", {}).get(k) for k in ("payload", "robot_differs")}
            | {"torque_limit": pr.scene.config.torque_limit,
               "kp_mean": None if pr.scene.config.kp is None else float(np.mean(pr.scene.config.kp))}}


def rms_z(err: np.ndarray, std: np.ndarray) -> float:
    """RMS of (estimate − truth)/σ over runs: 1 for an honest σ (the issue asks 0.5–1.5)."""
    return float(np.sqrt(np.mean((np.asarray(err) / np.asarray(std)) ** 2)))


def table(rows: list[dict]) -> None:
    from amhe_cli.estimation.uncertainty import coverage
    print(f"{'log':<24} {'n':>2} {'mass err % mean±std':>20} {'median':>7} {'worst':>7} {'mu err worst':>12} "
          f"{'cov mass':>8} {'cov mu':>7} {'cov I':>6} {'z mass':>6} {'z mu':>5} {'sd mass %':>9} {'wall s':>7}")
    hits, worst_m, worst_mu = [], 0.0, 0.0
    for log in dict.fromkeys(r["log"] for r in rows):
        rs = [r for r in rows if r["log"] == log]
        t = rs[0]["truth"]
        m = np.array([r["estimate"]["box_mass"] for r in rs])
        me = 100 * (m - t["box_mass"]) / t["box_mass"]
        mue = np.array([r["estimate"]["box_friction"] - t["box_friction"] for r in rs])
        cov = {}
        for name in ("box_mass", "box_friction", "box_inertia"):
            if name in t and name in rs[0]["estimate"]:
                c = coverage([np.atleast_1d(r["estimate"][name]) for r in rs],
                             [np.atleast_1d(r["std"][name]) for r in rs], np.atleast_1d(t[name]))
                cov[name] = c
                hits.append(c.ravel())
        worst_m, worst_mu = max(worst_m, np.abs(me).max()), max(worst_mu, np.abs(mue).max())
        f = lambda k: f"{100 * cov[k].mean():.0f} %" if k in cov else "-"  # noqa: E731
        sd_m = np.array([r["std"]["box_mass"] for r in rs])
        sd_mu = np.array([r["std"]["box_friction"] for r in rs])
        print(f"{Path(log).name:<24} {len(rs):>2} {me.mean():+9.2f} ± {me.std():5.2f}   {np.median(np.abs(me)):6.2f} "
              f"{me[np.argmax(np.abs(me))]:+7.2f} {mue[np.argmax(np.abs(mue))]:+12.4f} {f('box_mass'):>8} "
              f"{f('box_friction'):>7} {f('box_inertia'):>6} {rms_z(m - t['box_mass'], sd_m):6.2f} "
              f"{rms_z(mue, sd_mu):5.2f} {100 * np.median(sd_m) / t['box_mass']:9.1f} "
              f"{np.median([r['wall_s'] for r in rs]):7.1f}")
    allhits = np.concatenate(hits) if hits else np.zeros(0)
    print(f"2-sigma coverage over all runs and parameters: {100 * allhits.mean():.1f} % of {allhits.size} values")
    print(f"worst_mass_err_pct={worst_m:.2f} worst_mu_err={worst_mu:.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", help="LOG or LOG=TRUTH.yaml")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds run: FIRST_SEED .. FIRST_SEED + SEEDS - 1")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--params", default=None)
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda", "auto"), help="where rollouts run (as --device)")
    ap.add_argument("--out", default=None, help="JSON-lines file the rows are appended to as they finish")
    ap.add_argument("--identify-arg", action="append", default=[], metavar="KEY=VALUE",
                    help="identify setting other than the CLI default: clips, popsize, generations, "
                         "horizon (MIN,MAX) or any IdentifySettings field (e.g. average_last=6)")
    ap.add_argument("--sigma", action="append", default=[], metavar="GROUP=SIGMA",
                    help="W_x σ of a state group (as identify's W_x overrides), e.g. box_linvel=inf")
    ap.add_argument("--smooth", default="auto", help="pose smoothing: auto, 0 or a window in samples")
    ap.add_argument("--tag", default="", help="label stored with each row (e.g. the setting compared)")
    ap.add_argument("--table", default=None, help="only print the table of an existing --out file")
    a = ap.parse_args()
    if a.table:
        table([json.loads(line) for line in open(a.table) if line.strip()])
        return
    ident = {}
    for kv in a.identify_arg:
        k, _, v = kv.lstrip("-").partition("=")
        ident[k] = v if k == "horizon" else (int(v) if v.lstrip("-").isdigit() else float(v))
    jobs = []
    for spec in a.logs:
        log, _, given = spec.partition("=")
        truth = truth_of(log, given or None)
        sigma = {k: float(v) for k, _, v in (x.partition("=") for x in a.sigma)}
        smooth = a.smooth if a.smooth == "auto" else int(a.smooth)
        jobs += [{"log": log, "seed": s, "tag": a.tag, "sigma": sigma, "smooth": smooth, "threads": a.threads,
                  "device": a.device, "params": a.params, "identify": ident, "truth": truth}
                 for s in range(a.first_seed, a.first_seed + a.seeds)]
    rows = []
    out = open(a.out, "a") if a.out else None
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        futures = [ex.submit(one, j) for j in jobs]
        for fut in as_completed(futures):
            r = fut.result()
            rows.append(r)
            if out:
                out.write(json.dumps(r) + "\n")
                out.flush()
            print(f"[{len(rows)}/{len(jobs)}] {Path(r['log']).name} seed {r['seed']}: mass {r['estimate']['box_mass']:.3f} "
                  f"± {r['std']['box_mass']:.3f}, mu {r['estimate']['box_friction']:.4f} ± {r['std']['box_friction']:.4f}, "
                  f"{r['wall_s']:.1f} s", file=sys.stderr, flush=True)
    rows.sort(key=lambda r: (a.logs.index(next(s for s in a.logs if s.partition('=')[0] == r["log"])), r["seed"]))
    table(rows)


if __name__ == "__main__":
    main()
