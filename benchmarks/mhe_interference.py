"""What the online MHE costs the planner beyond the core it takes: its thread's interpreter lock.

A lock-step T3 run (wall clock's planner, true mode) records every planner call's inputs; the
same calls are then replayed, timed one by one, with the planner pinned to one CPU and

* ``alone``: nothing else running;
* ``thread``: the MHE (``run``'s settings) updating back to back over the run's trajectory in a
  thread of the same process, pinned to another CPU — as ``run`` runs it;
* ``process``: the same updates in a separate process pinned to that other CPU.

The planner's own work is identical in all three (same states, same seeds), so the difference
between ``alone`` and ``process`` is what sharing the machine costs (memory, caches), and the
difference between ``process`` and ``thread`` is what sharing the interpreter costs. Prints one line
per condition: median, p90 and p99 of the plan time [ms], and the MHE updates done meanwhile; the
last line is ``ratio_thread_over_process=`` (median plan time).

    python benchmarks/mhe_interference.py [--task t3] [--seconds 14] [--repeats 2] [--cpus 0,1]

Needs at least two CPUs.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import threading
import time
from dataclasses import replace

import numpy as np

from amhe_cli.control.closed_loop import RUN_PARAMS, make_estimator, make_plant, make_planner, run_task
from amhe_cli.control.evaluate import run_settings
from amhe_cli.control.planner import Planner
from amhe_cli.estimation.mhe import MovingHorizonEstimator


def make_mhe(task_name: str) -> MovingHorizonEstimator:
    """``run``'s MHE on the wall clock (its settings from a config with a latency), from the truth."""
    task, s = run_settings(task_name, "adaptive", {"latency": 0.035})
    plant = make_plant(task, s.kp, s.kd)
    return make_estimator(task, s, plant.record_dt, {k: v for k, v in plant.truth_values.items() if k in RUN_PARAMS})


def mhe_loop(task_name: str, traj, cpu: int, stop, count) -> None:
    """Update back to back over the recorded trajectory's windows until ``stop`` is set."""
    os.sched_setaffinity(0, {cpu})
    mhe = make_mhe(task_name)
    t = mhe.settings.window + 0.1
    while not stop.is_set():
        mhe.update(traj, t)
        with count.get_lock():
            count.value += 1
        t = t + 0.5 if t + 0.5 < traj.t[-1] else mhe.settings.window + 0.1
    mhe.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="t3")
    ap.add_argument("--seconds", type=float, default=14.0, help="length of the recorded run [s]")
    ap.add_argument("--repeats", type=int, default=2, help="replays of the recorded calls per condition")
    ap.add_argument("--cpus", default="0,1", help="the planner's CPU and the MHE's")
    a = ap.parse_args()
    cpu_plan, cpu_mhe = (int(x) for x in a.cpus.split(","))
    task, s = run_settings(a.task, "true", {"latency": 0.035}, threads=1, duration=a.seconds)
    calls = []
    real_plan = Planner.plan

    def recording(self, state, t, cmd, gait=None):
        calls.append((state.copy(), t, dict(cmd), gait))
        return real_plan(self, state, t, cmd, gait)

    Planner.plan = recording
    try:
        r = run_task(task, None, s)
    finally:
        Planner.plan = real_plan
    traj = r.traj
    print(f"recorded {len(calls)} planner calls over {traj.t[-1]:.1f} s of {a.task}", flush=True)

    os.sched_setaffinity(0, {cpu_plan})
    truth = make_plant(task, s.kp, s.kd).truth_values
    medians = {}
    for cond in ("alone", "thread", "process", "alone"):
        planner, _ = make_planner(task, replace(s, seed=0), None, truth, nthread=1)
        count = mp.get_context("spawn").Value("i", 0)
        stop, worker = None, None
        if cond == "thread":
            stop = threading.Event()
            worker = threading.Thread(target=mhe_loop, args=(a.task, traj, cpu_mhe, stop, count), daemon=True)
        elif cond == "process":
            ctx = mp.get_context("spawn")
            stop = ctx.Event()
            worker = ctx.Process(target=mhe_loop, args=(a.task, traj, cpu_mhe, stop, count), daemon=True)
        if worker is not None:
            worker.start()
            while count.value < 1:  # its set-up (imports, scene) is not what is measured
                time.sleep(0.05)
        times = []
        for _ in range(a.repeats):
            for state, t, cmd, gait in calls:
                t0 = time.perf_counter()
                planner.plan(state, t, cmd, gait)
                times.append(time.perf_counter() - t0)
        updates = count.value
        if worker is not None:
            stop.set()
            worker.join()
        planner.close()
        ms = np.array(times) * 1e3
        medians[cond] = float(np.median(ms))
        print(f"{cond:8s} plan ms p50 {np.median(ms):6.1f}  p90 {np.percentile(ms, 90):6.1f}  "
              f"p99 {np.percentile(ms, 99):6.1f}  ({len(ms)} calls; MHE updates meanwhile: {updates})", flush=True)
    print(f"ratio_thread_over_process={medians['thread'] / medians['process']:.3f}")


if __name__ == "__main__":
    main()
