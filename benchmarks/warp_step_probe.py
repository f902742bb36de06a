"""Where a MuJoCo Warp step's time goes at ``identify``'s width and a wide MHE's: the Newton solver's
iterations per world, and the step time and answer with ``opt.iterations`` capped.

    python benchmarks/warp_step_probe.py LOG [--clips 48] [--widths 12,200]

Needs ``amhe[gpu]`` and a CUDA device. For each width (candidates × the clips), rolls the candidates
out once with the scene's solver settings, reads the iterations the last step took per world, then
caps ``opt.iterations`` at 100, 30, 15, 8, 4 and 1 (the captured step re-captured each time) and
prints the call's time per step and how far the box's end position moved from the uncapped answer
[mm]. Lines also go to ``$OUT/warp_step_probe.txt`` when ``$OUT`` is set.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from amhe_cli.estimation.clips import sample_clips
from amhe_cli.estimation.identify import CLEAN_LOG_CLIPS
from amhe_cli.estimation.problem import load_problem
from amhe_cli.model.rollout_warp import WarpRollout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--clips", type=int, default=48)
    ap.add_argument("--widths", default="12,200", help="candidates per call, comma-separated")
    a = ap.parse_args()
    sink = open(os.path.join(os.environ["OUT"], "warp_step_probe.txt"), "a") if os.environ.get("OUT") else None

    def emit(line: str) -> None:
        print(line, flush=True)
        if sink:
            sink.write(line + "\n")
            sink.flush()

    pr = load_problem(a.log)
    sc, sp = pr.scene, pr.space
    c = sample_clips(pr.traj, sc, a.clips, CLEAN_LOG_CLIPS[1], rng=np.random.default_rng(0))
    hmax, k, end = c.control.shape[1], np.arange(len(c)), c.horizon - 1
    rng = np.random.default_rng(1)
    with WarpRollout(sc.model) as w:
        for B in (int(x) for x in a.widths.split(",")):
            P = sp.project(sp.mean0 + rng.normal(0, 0.3, (B, sp.dim)) * sp.std0)[0]
            ref = w.rollout_candidates(sp, P, c.initial_state, c.control, c.horizon)[0]
            slot = w._slot(B * len(c))
            nit = slot.d.solver_niter.numpy()[:B * len(c)]
            emit(f"candidates={B} worlds={B * len(c)} steps={hmax}: solver iterations at the last step "
                 f"mean {nit.mean():.1f} p95 {np.percentile(nit, 95):.0f} max {nit.max()}")
            for iters in (100, 30, 15, 8, 4, 1):
                slot.m.opt.iterations = iters
                slot.graph = None  # re-captured with the cap
                w.rollout_candidates(sp, P, c.initial_state, c.control, c.horizon)
                times = []
                for _ in range(3):
                    t = time.perf_counter()
                    q = w.rollout_candidates(sp, P, c.initial_state, c.control, c.horizon)[0]
                    times.append(time.perf_counter() - t)
                box = sc.box_qpos[:2]
                d = np.linalg.norm(q[:, k, end][..., box] - ref[:, k, end][..., box], axis=-1) * 1e3
                emit(f"  iterations<={iters}: {np.median(times) / hmax * 1e3:.3f} ms a step; box end moved "
                     f"median {np.median(d):.4f} p95 {np.percentile(d, 95):.4f} max {d.max():.3f} mm")
            slot.m.opt.iterations = sc.model.opt.iterations
            slot.graph = None


if __name__ == "__main__":
    main()
