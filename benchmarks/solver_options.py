"""What MuJoCo's solver options cost and change on the identification clips of a log.

The bundled model (``models/go1.xml``) spends most of a step in the constraint
solver. This script takes ``--clips`` clips of a log (the same draw as ``amhe
identify``), rolls every clip out with the model as shipped and with one option
changed at a time, and prints per option:

* the time ratio against the model as shipped, through the project's rollout
  pool (``amhe_cli.model.rollout.RolloutPool``, the cost module's) on
  ``--threads`` threads (the option and the shipped model alternate over
  ``--repeats`` timed passes; medians);
* the largest deviation of the box's and the trunk's positions at the clips'
  ends [mm] — 0 means the option only changes how the same answer is computed.

A one-thread pass with MuJoCo's timers splits a step of the shipped model into
its stages first (which is why the solver options are the ones worth trying).

Usage::

    python benchmarks/solver_options.py [LOG] [--clips 128] [--repeats 5] [--threads N]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from amhe_cli.estimation.clips import sample_clips  # noqa: E402
from amhe_cli.estimation.identify import clip_plan  # noqa: E402
from amhe_cli.estimation.problem import example_logs, load_problem  # noqa: E402
from amhe_cli.model.rollout import RolloutPool, default_threads  # noqa: E402

#: (label, option field, value) tried one at a time against the model as shipped.
VARIANTS = [
    ("jacobian dense", "jacobian", int(mujoco.mjtJacobian.mjJAC_DENSE)),
    ("jacobian auto", "jacobian", int(mujoco.mjtJacobian.mjJAC_AUTO)),
    ("tolerance 1e-6", "tolerance", 1e-6),
    ("ls_iterations 10", "ls_iterations", 10),
    ("solver CG", "solver", int(mujoco.mjtSolver.mjSOL_CG)),
    ("impratio 1", "impratio", 1.0),
]


def stage_times(model: mujoco.MjModel, clips) -> dict[str, float]:
    """Mean µs per step of each MuJoCo timer stage, stepping every clip once on one thread."""
    d = mujoco.MjData(model)
    for c in range(len(clips)):
        mujoco.mj_setState(model, d, clips.initial_state[c], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        for k in range(int(clips.horizon[c])):
            d.ctrl[:] = clips.control[c, k]
            mujoco.mj_step(model, d)
    out = {}
    for i, t in enumerate(d.timer):
        if t.number:
            out[mujoco.mjtTimer(i).name.removeprefix("mjTIMER_").lower()] = t.duration / t.number * 1e6
    return out


class ClipRollouts:
    """Every clip rolled out once through the project's rollout pool (:class:`~amhe_cli.model.rollout.RolloutPool`),
    one call per horizon group, as the cost module makes them."""

    def __init__(self, clips, model: mujoco.MjModel, nthread: int):
        self.clips = clips
        self.groups = [np.flatnonzero(clips.horizon == h) for h in np.unique(clips.horizon)]
        self.pool = RolloutPool(model, nthread=nthread)

    def run(self, model: mujoco.MjModel) -> tuple[float, np.ndarray]:
        """(wall time [s], (N_c, nstate) final states) of ``model`` (sizes as the pool's template)."""
        final = np.empty((len(self.clips), self.pool.nstate))
        t0 = time.perf_counter()
        for idx in self.groups:
            h = int(self.clips.horizon[idx[0]])
            state = self.pool.rollout([model] * idx.size, self.clips.initial_state[idx],
                                      self.clips.control[idx, :h], nstep=h)
            final[idx] = state[:, -1]
        return time.perf_counter() - t0, final

    def close(self) -> None:
        self.pool.close()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", nargs="?", default=None, help="log to cut clips from (default: the bundled example)")
    ap.add_argument("--clips", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    problem = load_problem(args.log or example_logs()[0])
    scene = problem.scene
    _, horizon, _ = clip_plan(problem.traj)  # the horizons identify draws for this log
    clips = sample_clips(problem.traj, scene, args.clips, horizon, rng=np.random.default_rng(args.seed))
    shipped = scene.model
    print(f"model as shipped: jacobian {mujoco.mjtJacobian(shipped.opt.jacobian).name}, "
          f"solver {mujoco.mjtSolver(shipped.opt.solver).name}, nv {shipped.nv}; "
          f"{len(clips)} clips, {clips.steps} steps")
    stages = stage_times(shipped, clips)
    print("one step, µs (one thread): " + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()
                                                     if k in ("step", "position", "velocity", "constraint",
                                                              "pos_collision", "actuation", "advance")))
    nthread = args.threads or default_threads()
    roll = ClipRollouts(clips, shipped, nthread)
    box, base = scene.box_qpos[:3], scene.base_qpos[:3]  # state row 0 is time; qpos follows
    try:
        roll.run(shipped)  # warm-up
        print(f"\n{'option':<18} {'time ratio':>10} {'box dev [mm]':>13} {'trunk dev [mm]':>15}  ({nthread} threads)")
        for label, name, value in VARIANTS:
            variant = copy.copy(shipped)
            setattr(variant.opt, name, value)
            t_ship, t_var = [], []
            for _ in range(args.repeats):
                w, ref = roll.run(shipped)
                t_ship.append(w)
                w, x = roll.run(variant)
                t_var.append(w)
            dev_box = np.abs(x[:, 1 + box] - ref[:, 1 + box]).max() * 1e3
            dev_base = np.abs(x[:, 1 + base] - ref[:, 1 + base]).max() * 1e3
            print(f"{label:<18} {statistics.median(t_var) / statistics.median(t_ship):>10.2f} "
                  f"{dev_box:>13.4f} {dev_base:>15.4f}")
    finally:
        roll.close()


if __name__ == "__main__":
    main()
