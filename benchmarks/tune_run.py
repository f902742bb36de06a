"""Run one closed-loop task with cost-weight / planner overrides and print its metrics (a tuning aid).

    python benchmarks/tune_run.py t1 '{"weights": {"waypoint": 20}, "planner": {"samples": 40}}' [seed] [mode]
"""
import json
import sys
import time

from amhe_cli.closed_loop import RunSettings, run_task
from amhe_cli.planner import PlannerSettings
from amhe_cli.tasks import CostWeights, get_task

name = sys.argv[1]
over = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
seed = int(sys.argv[3]) if len(sys.argv) > 3 else 0
mode = sys.argv[4] if len(sys.argv) > 4 else "true"
task = get_task(name, weights=CostWeights.from_dict(over.get("weights", {})), **over.get("task", {}))
settings = RunSettings(mode=mode, seed=seed, planner=PlannerSettings.from_dict(over.get("planner", {})),
                       threads=over.get("threads"), cycle=over.get("cycle", 0.02),
                       **{k: over[k] for k in ("kp", "kd") if k in over})
t0 = time.time()
r = run_task(task, None, settings)
print(json.dumps({"over": over, "seed": seed, **r.metrics(), "fell": r.fell, "hz": r.control_hz,
                  "wall": time.time() - t0, "box_end": r.traj.box_pos[-1, :2].tolist(),
                  "sim_t": float(r.traj.t[-1])}))
