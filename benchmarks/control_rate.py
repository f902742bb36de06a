"""Planner update rate with the defaults against the raw ``mujoco.rollout`` bound, in one run.

Drives the default MPOPI planner on task T1 (true mode) in lock-step with the
sim plant for ``--cycles`` cycles and times each ``Planner.plan`` call. The bound
is what raw ``mujoco.rollout`` of the same steps allows: every batch the planner
rolled out (its initial states and sampled controls, refinement loops at
contact-mode switches included) is recorded and rolled out again through a bare
``mujoco.rollout.Rollout`` with the same models and thread count, and timed.
(A standing robot's rollouts are about twice as fast as a walking, pushing one's,
so a bound from a fixed state would flatter nobody.)

Prints the figures and, as its last line, ``ratio=<planner Hz ÷ rollout-bound Hz>``.

    python benchmarks/control_rate.py [--cycles 150] [--threads N]
"""

import argparse
import time

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from amhe_cli.closed_loop import RunSettings, make_planner, task_scene_config
from amhe_cli.plant import SimPlant
from amhe_cli.tasks import get_task


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    task = get_task("t1")
    s = RunSettings(mode="true", threads=args.threads)
    plant = SimPlant(task_scene_config(task, 0.002, s.kp, s.kd), truth=task.truth, control_period=s.planner.dt)
    q, v = plant.scene.standing_state(box_xy=task.box_start)
    plant.reset(q, v)
    planner, _ = make_planner(task, s, None, plant.truth_values)
    sc = plant.scene
    times, rollouts, batches = [], [], []
    steps = int(round(s.cycle / s.planner.dt))
    pool_rollout = planner.pool.rollout

    def recording(models, initial_state, control, nstep=None):
        batches.append((None, models, initial_state.copy(), control.copy()))
        return pool_rollout(models, initial_state, control, nstep)

    planner.pool.rollout = recording
    with planner:
        for _ in range(args.cycles):
            q, v = plant.data.qpos, plant.data.qvel
            w, x, y, z = q[sc.base_qpos[3:]]
            cmd = task.command(q[sc.base_qpos[:2]], float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))),
                               q[sc.box_qpos[:2]], 0.19)
            t0 = time.perf_counter()
            plan = planner.plan(planner.scene.full_state(q[None], v[None])[0], float(plant.data.time), cmd)
            times.append(time.perf_counter() - t0)
            rollouts.append(plan.rollouts)
            for row in plan.controls[:steps]:
                plant.step(row)
        nthread = planner.pool.nthread
        raw = mj_rollout.Rollout(nthread=nthread)
        datas = [mujoco.MjData(planner.scene.model) for _ in range(nthread)]
        t0 = time.perf_counter()
        for _, models, init, ctrl in batches:
            raw.rollout(models, datas, init, ctrl)
        raw_time = time.perf_counter() - t0
        raw.close()
    planner_hz = 1.0 / float(np.mean(times))
    per_cycle = len(batches) / len(times)  # batches per cycle
    bound_hz = len(times) / raw_time
    batch_hz = len(batches) / raw_time
    p = s.planner
    print(f"planner: {p.samples} samples x {p.horizon} steps, {p.knots} knots, L_MPOPI {p.refine_loops}; "
          f"threads {planner.pool.nthread}")
    print(f"planner cycles: {len(times)}, mean {np.mean(times) * 1e3:.1f} ms, median {np.median(times) * 1e3:.1f} ms, "
          f"{per_cycle:.2f} batches per cycle")
    print(f"planner rate: {planner_hz:.2f} Hz")
    print(f"raw mujoco.rollout of the same batches: {batch_hz:.2f} batches/s = "
          f"{batch_hz * p.samples * p.horizon:.0f} steps/s; bound: {bound_hz:.2f} Hz")
    print(f"ratio={planner_hz / bound_hz:.3f}")


if __name__ == "__main__":
    main()
