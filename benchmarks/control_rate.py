"""Planner update rate with the defaults against the raw ``mujoco.rollout`` bound, in one run.

Runs task T1 in true mode, lock-step, with the default planner for about
``--cycles`` cycles (``amhe_cli.control.closed_loop.run_task``) and takes each cycle's
``Planner.plan`` time. The bound is what raw ``mujoco.rollout`` of the same
steps allows: every batch the planner rolled out (its initial states and
sampled controls, refinement loops at contact-mode switches included) is
recorded and rolled out again through a bare ``mujoco.rollout.Rollout`` with
the same models and thread count, and timed. (A standing robot's rollouts are
about twice as fast as a walking, pushing one's, so a bound from a fixed state
would flatter the planner's overhead away.)

Prints the figures and, as its last line, ``ratio=<planner Hz ÷ rollout-bound Hz>``.

    python benchmarks/control_rate.py [--cycles 150] [--threads N]
"""

import argparse
import time

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from amhe_cli.control.closed_loop import RunSettings, run_task
from amhe_cli.model.rollout import RolloutPool, default_threads
from amhe_cli.control.tasks import get_task


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    s = RunSettings(mode="true", threads=args.threads)
    task = get_task("t1", duration=args.cycles * s.cycle)
    batches = []
    pool_rollout = RolloutPool.rollout

    def recording(pool, models, initial_state, control, nstep=None):
        batches.append((list(models), initial_state.copy(), control.copy()))
        return pool_rollout(pool, models, initial_state, control, nstep)

    RolloutPool.rollout = recording
    try:
        result = run_task(task, None, s)
    finally:
        RolloutPool.rollout = pool_rollout
    nthread = args.threads or default_threads()
    raw = mj_rollout.Rollout(nthread=nthread)
    datas = [mujoco.MjData(batches[0][0][0]) for _ in range(nthread)]
    t0 = time.perf_counter()
    for models, init, ctrl in batches:
        raw.rollout(models, datas, init, ctrl)
    raw_time = time.perf_counter() - t0
    raw.close()
    times = result.plan_times
    planner_hz = 1.0 / float(np.mean(times))
    bound_hz = len(times) / raw_time
    batch_hz = len(batches) / raw_time
    p = s.planner
    print(f"planner: {p.samples} samples x {p.horizon} steps, {p.knots} knots, L_MPOPI {p.refine_loops}; "
          f"threads {nthread}")
    print(f"planner cycles: {len(times)}, mean {np.mean(times) * 1e3:.1f} ms, median {np.median(times) * 1e3:.1f} ms, "
          f"{len(batches) / len(times):.2f} batches per cycle")
    print(f"planner rate: {planner_hz:.2f} Hz")
    print(f"raw mujoco.rollout of the same batches: {batch_hz:.2f} batches/s = "
          f"{batch_hz * p.samples * p.horizon:.0f} steps/s; bound: {bound_hz:.2f} Hz")
    print(f"ratio={planner_hz / bound_hz:.3f}")


if __name__ == "__main__":
    main()
