"""Run one closed-loop task with config overrides and print its metrics as JSON (a tuning aid).

The overrides are a run config (as ``amhe run --config``) given inline, plus
``threads``::

    python benchmarks/tune_run.py t1 '{"weights": {"waypoint": 20}, "planner": {"samples": 40}, "threads": 1}' [seed] [mode]

Modes other than ``true`` probe for their starting belief first.
"""
import json
import sys
import time

from amhe_cli.control.closed_loop import run_task
from amhe_cli.control.evaluate import probe_belief, run_settings

name = sys.argv[1]
over = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
seed = int(sys.argv[3]) if len(sys.argv) > 3 else 0
mode = sys.argv[4] if len(sys.argv) > 4 else "true"
threads = over.pop("threads", None)
task, settings = run_settings(name, mode, over, seed=seed, threads=threads)
belief = None if mode == "true" else probe_belief(task, seed=seed, threads=threads)
t0 = time.time()
r = run_task(task, belief, settings)
print(json.dumps({"over": over, "seed": seed, **r.metrics(), "fell": r.fell, "hz": r.control_hz,
                  "wall": time.time() - t0, "box_end": r.traj.box_pos[-1, :2].tolist(),
                  "sim_t": float(r.traj.t[-1])}))
