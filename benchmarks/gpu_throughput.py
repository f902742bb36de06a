"""MuJoCo Warp (``--device cuda``) against ``mujoco.rollout`` on all CPU cores, on one machine in one run.

Measures, each written as one flushed line to stdout and to ``$OUT/gpu_throughput.txt``
(or ``--out``) as soon as it is known:

1. **compile**: the Warp backend's first call (kernel compile or cache load, graph capture).
2. **agreement**: the same candidates on the same clips through both backends
   (:class:`~amhe_cli.model.rollout.RolloutPool` and
   :class:`~amhe_cli.model.rollout_warp.WarpRollout`): the box's planar
   position difference at each clip's end (median, 95th percentile, max
   [mm]), the whole state's at the end (max over components), and the share of
   candidate pairs of a CMA-ES-like generation that the two costs order alike —
   for a first generation (σ 0.3 prior-σ about the prior) and a late one (σ 0.03 about the truth).
3. **throughput**: useful simulated steps per second (candidates × Σ clip
   horizons / wall time of ``rollout_candidates``, parameter writes and
   transfers included) for several batch sizes (worlds = candidates × clips), and
   the GPU graph alone (launch to sync); then the call's phases (``phases``: slot and graph
   set-up, parameter fields on the host, their upload, the steps, the read-back, per call).
4. **identify**: ``identify`` on the log on cpu, on cuda with the CPU's
   settings, and on cuda with wider settings (``--wide POP,CLIPS``): wall
   time and the error against the log's truth (``--profile``: where the cuda run's time went).
5. with ``--cli``, ``amhe identify LOG --device cpu|cuda`` as a user runs it, each a fresh process
   (imports, reading the log, loading the kernels from the cache included; cuda twice).
6. with ``--mhe LOG``, ``amhe mhe-replay LOG --realtime`` on cpu (default samples) and on cuda
   (``--mhe-cuda``: 200 samples × 3 iterations, 300 × 2): real-time factor and tracking error against
   the log's truth.

The last lines are the ratios ``ratio_steps_best=`` (best Warp useful steps/s over best CPU
useful steps/s) and ``ratio_identify=`` (CPU identify wall / GPU identify wall).

Usage::

    python benchmarks/gpu_throughput.py LOG [--clips 48] [--batches 256,1024,4096,16384] [--repeats 3] [--profile] [--cli] [--mhe LOG]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from amhe_cli.cli import child_command

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from amhe_cli.estimation.clips import sample_clips  # noqa: E402
from amhe_cli.estimation.cost import RolloutCost  # noqa: E402
from amhe_cli.estimation.identify import CLEAN_LOG_CLIPS, IdentifySettings, identify  # noqa: E402
from amhe_cli.estimation.problem import load_problem  # noqa: E402
from identify_accuracy import truth_of  # noqa: E402  (benchmarks/: <LOG stem>.truth.yaml or metadata)
from amhe_cli.model import device as dev  # noqa: E402
from amhe_cli.model.rollout import RolloutPool, default_threads  # noqa: E402
from amhe_cli.model.rollout_warp import WarpRollout  # noqa: E402

_sink = None


def emit(line: str) -> None:
    """One measurement: stdout and the results file, flushed."""
    print(line, flush=True)
    if _sink is not None:
        _sink.write(line + "\n")
        _sink.flush()


#: the CLI as a user runs it, in a fresh process
AMHE = child_command()


def phases(timing: dict) -> str:
    """WarpRollout.timing as per-call seconds of each phase."""
    n = max(1, timing["calls"])
    return " ".join(f"{k}={v / n:.4f}" for k, v in timing.items() if k not in ("calls", "slots", "graphs")) + \
        f" slots={timing['slots']} graphs={timing['graphs']} calls={timing['calls']}"


def pair_agreement(a: np.ndarray, b: np.ndarray) -> float:
    """Share of pairs (i < j) that ``a`` and ``b`` order alike (ties count as alike only if tied in both)."""
    i, j = np.triu_indices(len(a), 1)
    return float(np.mean(np.sign(a[i] - a[j]) == np.sign(b[i] - b[j])))


def main(argv=None) -> None:
    global _sink
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--clips", type=int, default=CLEAN_LOG_CLIPS[0])
    ap.add_argument("--batches", default="256,1024,4096,16384", help="worlds (candidates x clips) per call")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--wide", default="48,96", help="identify on cuda with this POPSIZE,CLIPS too")
    ap.add_argument("--skip", default="", help="comma-separated sections to skip: agreement,throughput,identify")
    ap.add_argument("--out", default=os.environ.get("OUT", "."), help="folder of gpu_throughput.txt")
    ap.add_argument("--profile", action="store_true", help="profile identify on cuda (cProfile, top 30)")
    ap.add_argument("--cli", action="store_true", help="also time `amhe identify LOG --device cpu|cuda` as a "
                    "user runs it (a fresh process each: imports, log reading, kernel loading from the cache)")
    ap.add_argument("--mhe", metavar="LOG", help="also run `amhe mhe-replay LOG --realtime` on cpu with the default "
                    "samples and on cuda with --mhe-samples: real-time factor and tracking error")
    ap.add_argument("--mhe-cuda", default="200x3,300x2", help="cuda settings SAMPLESxITERS to try, comma-separated "
                    "(the CPU default is 20x3: 60 samples an update)")
    ap.add_argument("--warp-device", default=None, help="Warp device (default cuda:0, or $AMHE_WARP_DEVICE; "
                    "cpu: debug the script without a GPU)")
    a = ap.parse_args(argv)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    _sink = open(Path(a.out) / "gpu_throughput.txt", "a")
    skip = set(filter(None, a.skip.split(",")))

    t0 = time.perf_counter()
    problem = load_problem(a.log)
    scene, space, traj = problem.scene, problem.space, problem.traj
    truth = truth_of(a.log, None)
    clips = sample_clips(traj, scene, a.clips, CLEAN_LOG_CLIPS[1], rng=np.random.default_rng(0))
    nthread = default_threads()
    emit(f"setup log={Path(a.log).name} clips={len(clips)} steps_per_candidate={clips.steps} "
         f"hmax={clips.control.shape[1]} cpu_threads={nthread} load_s={time.perf_counter() - t0:.1f}")
    p0 = space.mean0
    tvec = space.vector({k: v for k, v in truth.items() if k in space.free}) if truth else p0
    rng = np.random.default_rng(1)

    warp = WarpRollout(scene.model, device=a.warp_device)
    pool = RolloutPool(scene.model, nthread)
    emit(f"device {warp.describe()}")
    c = clips
    t = time.perf_counter()
    warp.rollout_candidates(space, p0[None], c.initial_state, c.control, c.horizon)
    emit(f"compile_s={time.perf_counter() - t:.1f} (first call: kernels {warp.compile_time:.1f} s, then graph) "
         f"nconmax={warp.nconmax} njmax={warp.njmax} bound={warp.bound}")

    if "agreement" not in skip:
        h = c.horizon - 1
        box = scene.box_qpos[:2]
        for label, centre, sd in (("first_gen", p0, 0.3), ("late_gen", tvec, 0.03)):
            P = space.project(centre + rng.normal(0, sd, (12, space.dim)) * space.std0)[0]
            qc, vc, _ = pool.rollout_candidates(space, P, c.initial_state, c.control, c.horizon)
            qg, vg, _ = warp.rollout_candidates(space, P, c.initial_state, c.control, c.horizon)
            k = np.arange(len(c))
            end_c, end_g = qc[:, k, h], qg[:, k, h]  # (B, N_c, nq) at each clip's end
            dbox = np.linalg.norm(end_c[..., box] - end_g[..., box], axis=-1) * 1e3
            dstate = np.abs(end_c - end_g).max()
            with RolloutCost(scene, space, c, pool=pool, prior_weight=0.0) as cc, \
                    RolloutCost(scene, space, c, pool=warp, prior_weight=0.0) as cg:
                jc, jg = cc(P), cg(P)
            rel = np.abs(jg - jc) / np.maximum(np.abs(jc), 1e-12)
            emit(f"agreement {label}: box_end_mm median={np.median(dbox):.4f} p95={np.percentile(dbox, 95):.4f} "
                 f"max={dbox.max():.4f} state_end_max={dstate:.2e} J_rel_median={np.median(rel):.3g} "
                 f"J_rel_max={rel.max():.3g} ranking_pairs_same={pair_agreement(jc, jg):.3f}")

    best_g = best_c = 0.0
    if "throughput" not in skip:
        for worlds in (int(x) for x in a.batches.split(",")):
            B = max(1, worlds // len(c))
            P = space.project(p0 + rng.normal(0, 0.3, (B, space.dim)) * space.std0)[0]
            useful = B * clips.steps
            warp.rollout_candidates(space, P, c.initial_state, c.control, c.horizon)  # capture at this size
            tg = []
            warp.timing.update({k: 0 for k in warp.timing})
            for _ in range(a.repeats):
                t = time.perf_counter()
                warp.rollout_candidates(space, P, c.initial_state, c.control, c.horizon)
                tg.append(time.perf_counter() - t)
            emit(f"phases worlds={B * len(c)} per call [s]: " + phases(warp.timing))
            slot = warp._slot(B * len(c))
            tl = []
            for _ in range(a.repeats):
                t = time.perf_counter()
                warp._launch(slot, int(c.control.shape[1]))
                warp.wp.synchronize()
                tl.append(time.perf_counter() - t)
            tc = []
            for _ in range(max(1, a.repeats if worlds <= 4096 else 1)):
                t = time.perf_counter()
                pool.rollout_candidates(space, P, c.initial_state, c.control, c.horizon)
                tc.append(time.perf_counter() - t)
            g, l, cp = statistics.median(tg), statistics.median(tl), statistics.median(tc)
            best_g, best_c = max(best_g, useful / g), max(best_c, useful / cp)
            emit(f"throughput worlds={B * len(c)} candidates={B} warp_steps_per_s={useful / g:.0f} "
                 f"warp_graph_only_steps_per_s={B * len(c) * c.control.shape[1] / l:.0f} "
                 f"cpu_steps_per_s={useful / cp:.0f} ratio={cp / g:.2f} warp_call_s={g:.3f} cpu_call_s={cp:.3f}")
    pool.close()
    warp.close()

    ratio_identify = None
    if "identify" not in skip:
        walls = {}
        pop, ncl = (int(x) for x in a.wide.split(","))
        for label, device, settings in (("cpu", "cpu", IdentifySettings()), ("cuda", "cuda", IdentifySettings()),
                                        (f"cuda_pop{pop}_clips{ncl}", "cuda",
                                         IdentifySettings(popsize=pop, n_clips=ncl))):
            dev.set_default(device)
            prof = cProfile.Profile() if a.profile and device == "cuda" else None
            t = time.perf_counter()
            if prof:
                prof.enable()
            res = identify(traj, scene, space, settings)
            wall = time.perf_counter() - t
            if prof:
                prof.disable()
                text = io.StringIO()
                pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(30)
                emit(f"profile identify {label}:\n" + text.getvalue())
            walls[label] = wall
            est = space.values(res.estimate)
            errs = []
            if "box_mass" in truth:
                errs.append(f"mass_err_pct={100 * (est['box_mass'] - truth['box_mass']) / truth['box_mass']:+.2f}")
            if "box_friction" in truth:
                errs.append(f"mu_err={est['box_friction'] - truth['box_friction']:+.4f}")
            emit(f"identify {label}: wall_s={wall:.2f} evaluations={res.evaluations} generations={len(res.history)} "
                 + " ".join(errs))
        ratio_identify = walls["cpu"] / walls["cuda"]
    if a.cli:
        for device in ("cpu", "cuda", "cuda"):
            t = time.perf_counter()
            out = subprocess.run(AMHE + ["identify", a.log, "--device", device, "--json", "--force",
                                         "--out", str(Path(a.out) / f"cli_{device}.belief.yaml")],
                                 capture_output=True, text=True)
            wall = time.perf_counter() - t
            try:
                est = json.loads(out.stdout)["estimate"]
                what = " ".join(f"{k}={v:.4f}" for k, v in est.items() if isinstance(v, float))
            except (ValueError, KeyError, TypeError):
                what = out.stderr.strip()[-300:]
            emit(f"cli identify --device {device}: wall_s={wall:.2f} rc={out.returncode} {what}")
    if a.mhe:
        variants = [("cpu", [])] + [("cuda", ["--samples", v.split("x")[0], "--iters", v.split("x")[1]])
                                    for v in a.mhe_cuda.split(",")]
        for device, extra in variants:
            csv = Path(a.out) / f"mhe_{device}{'_'.join([''] + extra[1::2])}.csv"
            t = time.perf_counter()
            out = subprocess.run(AMHE + ["mhe-replay", a.mhe, "--realtime", "--device", device, "--json", "--force",
                                         "--out", str(csv), *extra], capture_output=True, text=True)
            wall = time.perf_counter() - t
            try:
                r = json.loads(out.stdout.strip().splitlines()[-1])
                emit(f"mhe-replay --device {device} {' '.join(extra)}: wall_s={wall:.1f} "
                     f"realtime_factor={r['realtime_factor']:.2f} behind={r['behind']} "
                     f"tracking_error={json.dumps(r.get('tracking_error'))}")
            except (IndexError, ValueError, KeyError):
                emit(f"mhe-replay --device {device}: rc={out.returncode} {out.stderr.strip()[-300:]}")
    if best_c:
        emit(f"ratio_steps_best={best_g / best_c:.2f}")
    if ratio_identify is not None:
        emit(f"ratio_identify={ratio_identify:.2f}")


if __name__ == "__main__":
    main()
