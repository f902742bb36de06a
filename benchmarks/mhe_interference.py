"""What the online MHE and the planner cost each other beyond the core each takes.

A lock-step T3 run (wall clock's planner, true mode) records every planner call's inputs; the
same calls are then replayed, timed one by one, with the planner pinned to one CPU and

* ``alone``: nothing else running;
* ``thread``: the MHE (``run``'s settings) updating back to back over the run's trajectory in a
  thread of the same process, pinned to another CPU — as ``run`` runs it;
* ``process``: the same updates in a separate process pinned to that other CPU;
* ``mhe only``: those updates in that process with no planner running, as long as ``process`` ran.

The planner's own work is identical in all three (same states, same seeds), so the difference
between ``alone`` and ``process`` is what sharing the machine costs (memory, caches), and the
difference between ``process`` and ``thread`` is what sharing the interpreter costs. Prints one line
per condition: median, p90 and p99 of the plan time [ms], the MHE updates done meanwhile and the mean
wall time of those that rolled out a window [ms]; the last lines are ``ratio_thread_over_process=``
(median plan time) and ``mhe_update_ratio_beside_planner=`` (the MHE's update time in ``process`` over
``mhe only``: what a planner on the next CPU costs the estimator).

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


def mhe_loop(task_name: str, traj, cpu: int, stop, count, busy) -> None:
    """Update back to back over the recorded trajectory's windows until ``stop`` is set; ``busy`` adds up
    the wall time [s] of the updates that rolled a window out, ``count`` counts every update (the first one
    marks the set-up done)."""
    os.sched_setaffinity(0, {cpu})
    mhe = make_mhe(task_name)
    t = mhe.settings.window + 0.1
    while not stop.is_set():
        res = mhe.update(traj, t)
        with count.get_lock():
            count.value += 1
        if not res.skipped:
            with busy.get_lock():
                busy[0] += res.compute_time
                busy[1] += 1
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
    medians, update_ms, process_wall = {}, {}, 0.0
    for cond in ("alone", "thread", "process", "mhe only", "alone"):
        ctx = mp.get_context("spawn")
        count, busy = ctx.Value("i", 0), ctx.Array("d", 2)
        stop, worker = None, None
        if cond == "thread":
            stop = threading.Event()
            worker = threading.Thread(target=mhe_loop, args=(a.task, traj, cpu_mhe, stop, count, busy), daemon=True)
        elif cond in ("process", "mhe only"):
            stop = ctx.Event()
            worker = ctx.Process(target=mhe_loop, args=(a.task, traj, cpu_mhe, stop, count, busy), daemon=True)
        if worker is not None:
            worker.start()
            while count.value < 1:  # its set-up (imports, scene) is not what is measured
                time.sleep(0.05)
            with busy.get_lock():
                busy[0] = busy[1] = 0.0
        times = []
        t_start = time.perf_counter()
        if cond == "mhe only":
            time.sleep(process_wall)
        else:
            planner, _ = make_planner(task, replace(s, seed=0), None, truth, nthread=1)
            for _ in range(a.repeats):
                for state, t, cmd, gait in calls:
                    t0 = time.perf_counter()
                    planner.plan(state, t, cmd, gait)
                    times.append(time.perf_counter() - t0)
            planner.close()
        if cond == "process":
            process_wall = time.perf_counter() - t_start
        updates = count.value
        if worker is not None:
            stop.set()
            worker.join()
        mean_update = 1e3 * busy[0] / busy[1] if busy[1] else float("nan")
        update_ms[cond] = mean_update
        line = f"{cond:8s} "
        if times:
            ms = np.array(times) * 1e3
            medians[cond] = float(np.median(ms))
            line += (f"plan ms p50 {np.median(ms):6.1f}  p90 {np.percentile(ms, 90):6.1f}  "
                     f"p99 {np.percentile(ms, 99):6.1f}  ({len(ms)} calls; ")
        else:
            line += f"no planner for {process_wall:.1f} s ("
        print(line + f"MHE updates meanwhile: {updates}, {int(busy[1])} rolled out, {mean_update:.0f} ms each)",
              flush=True)
    print(f"ratio_thread_over_process={medians['thread'] / medians['process']:.3f}")
    print(f"mhe_update_ratio_beside_planner={update_ms['process'] / update_ms['mhe only']:.3f}")


if __name__ == "__main__":
    main()
