"""The planner's samples on the GPU (``planner: {device: cuda}``) against the CPU, on one machine in one run.

For each planner width (``--samples``, one refinement loop as on the wall clock):

1. **agreement**: from the task's standing start, the same knot offsets scored by both backends
   (``mujoco.rollout`` in float64, MuJoCo Warp in float32): the rank correlation of the costs and
   their largest relative difference, and whether both pick the same best sample.
2. **cycle**: a lock-step run of the task (true mode, ``--cycles`` planner cycles) on each device;
   the median ``Planner.plan`` time [ms] (rollouts, costs and the MPPI update), which on the wall
   clock is the plan's delay. On the CPU the planner has every core (``--threads``).
3. **bound**: raw ``mujoco.rollout`` of the same width (samples × horizon steps from the standing
   start, one model copy per sample) on the same cores: the rate the CPU planner cannot beat.

Each result is one JSON line, flushed to stdout and to ``$OUT/gpu_planner.jsonl`` (or ``--out``) as
soon as it is known, so a call cut off keeps what finished. The last lines are
``ratio_cycle_<N>=`` (CPU planner cycle ÷ GPU planner cycle) per width.

    python benchmarks/gpu_planner.py [--task t4] [--samples 16,64,256,1024] [--cycles 60] [--cpu-max 256]

Needs ``amhe[gpu]`` and a CUDA device (``--device-name cpu`` runs Warp's slow CPU back end instead,
to check the plumbing on a machine without a GPU).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from amhe_cli.control.closed_loop import make_planner, make_plant, measured_command, run_task
from amhe_cli.control.evaluate import run_settings
from amhe_cli.control.planner import REALTIME_PLANNER
from amhe_cli.model.rollout import default_threads


def emit(out, **row) -> None:
    line = json.dumps(row)
    print(line, flush=True)
    with open(out, "a") as f:
        f.write(line + "\n")


def settings_for(task_name: str, samples: int, device: str, threads: int | None):
    """The wall clock's planner (REALTIME_PLANNER) at this width and device, lock-step, true mode."""
    cfg = {"planner": dict(REALTIME_PLANNER, samples=samples, device=device)}
    cfg["planner"]["noise"] = list(cfg["planner"]["noise"])
    return run_settings(task_name, "true", cfg, seed=0, threads=threads)


def start_state(task, s):
    """The planner, its scene's standing start as a full-physics state, the first command and reference."""
    plant = make_plant(task, s.kp, s.kd)
    planner, _ = make_planner(task, s, None, plant.truth_values, nthread=s.threads)
    sc = planner.scene
    qpos, qvel = sc.standing_state(box_xy=task.box_start)
    m = sc.model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d)
    state = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    cmd, _ = measured_command(task, sc, qpos, 0.0)
    p = planner.settings
    ref = planner.gait.reference(np.arange(p.horizon) * p.dt, cmd["speed"], cmd["omega"], cmd.get("reach"))
    return planner, state, cmd, ref


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="t4")
    ap.add_argument("--samples", default="16,64,256,1024")
    ap.add_argument("--cycles", type=int, default=60)
    ap.add_argument("--cpu-max", type=int, default=256, help="widest batch the CPU planner is timed at")
    ap.add_argument("--threads", type=int, default=None, help="CPU planner threads (default: all CPUs)")
    ap.add_argument("--device-name", default=None, help="Warp device (default cuda:0; cpu: Warp's CPU back end)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    out = Path(a.out or Path(os.environ.get("OUT", ".")) / "gpu_planner.jsonl")
    out.parent.mkdir(parents=True, exist_ok=True)
    threads = a.threads or default_threads()
    widths = [int(x) for x in a.samples.split(",")]
    cycle_ms = {}
    for n in widths:
        # 1. agreement: the same knots through both backends
        task, s_cpu = settings_for(a.task, n, "cpu", threads)
        cpu_planner, state, cmd, ref = start_state(task, s_cpu)
        rng = np.random.default_rng(n)
        knots = cpu_planner.sigma[None] * rng.standard_normal((n,) + cpu_planner.mean.shape)
        knots[0] = 0.0
        J_cpu = cpu_planner._score(state, knots, ref, cmd)
        _, s_gpu = settings_for(a.task, n, "cuda" if a.device_name is None else "cpu", threads)
        if a.device_name is not None:  # Warp's CPU back end: swap the backend in by hand
            from amhe_cli.model.rollout_warp import WarpRollout
            gpu_planner, *_ = start_state(task, s_cpu)
            gpu_planner.gpu = WarpRollout(gpu_planner.scene.model, device=a.device_name)
        else:
            gpu_planner, *_ = start_state(task, s_gpu)
        t0 = time.perf_counter()
        J_gpu = gpu_planner._score(state, knots, ref, cmd)
        first = time.perf_counter() - t0
        rank = np.corrcoef(np.argsort(np.argsort(J_cpu)), np.argsort(np.argsort(J_gpu)))[0, 1]
        emit(out, what="agreement", samples=n, rank_corr=round(float(rank), 4),
             max_rel_diff=float(np.max(np.abs(J_gpu - J_cpu) / np.maximum(np.abs(J_cpu), 1e-9))),
             same_best=bool(np.argmin(J_cpu) == np.argmin(J_gpu)), first_call_s=round(first, 2))
        cpu_planner.close()
        gpu_planner.close()
        if a.device_name is not None:
            continue
        # 2. cycle: a lock-step run's planner cycles on each device
        for dev, s in (("cpu", s_cpu), ("cuda", s_gpu)):
            if dev == "cpu" and n > a.cpu_max:
                continue
            t = replace(task, duration=a.cycles * s.cycle)
            t0 = time.perf_counter()
            r = run_task(t, None, s)
            times = np.asarray(r.plan_times[1:])
            cycle_ms[(dev, n)] = float(np.median(times)) * 1e3
            emit(out, what="cycle", device=dev, samples=n, threads=threads if dev == "cpu" else None,
                 cycles=len(times), median_ms=round(cycle_ms[(dev, n)], 2),
                 p90_ms=round(float(np.percentile(times, 90)) * 1e3, 2), wall_s=round(time.perf_counter() - t0, 1),
                 fell=bool(r.fell))
        # 3. bound: raw mujoco.rollout of the same width from the standing start
        m = cpu_planner.scene.model
        models = [m] * n
        raw = mj_rollout.Rollout(nthread=threads)
        datas = [mujoco.MjData(m) for _ in range(threads)]
        u = cpu_planner._controls(knots, ref)
        init = np.repeat(state[None], n, axis=0)
        reps = []
        for _ in range(5):
            t0 = time.perf_counter()
            raw.rollout(models, datas, init, u)
            reps.append(time.perf_counter() - t0)
        raw.close()
        emit(out, what="bound", samples=n, threads=threads, raw_rollout_ms=round(float(np.median(reps)) * 1e3, 2))
    for n in widths:
        if ("cpu", n) in cycle_ms and ("cuda", n) in cycle_ms:
            print(f"ratio_cycle_{n}={cycle_ms[('cpu', n)] / cycle_ms[('cuda', n)]:.3f}", flush=True)


if __name__ == "__main__":
    main()
