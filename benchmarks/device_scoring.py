"""A GPU batch scored on the device against the same batch scored on the host, on one machine in one run.

``RolloutCost.evaluate`` on the ``cuda`` backend used to copy every world's states back (float32, (worlds, H,
nq + nv)) and score them on the CPU (``state_error``, the whitening, the per-clip sums): for a line decision's
2048 worlds about 0.3 s of its 0.46 s in the emulated loop (docs/evaluation.md, stop 70). The backend now
scores each step inside its captured step graph (``WarpRollout.score_candidates``) and returns (B, N_c) sums.

For each batch width, alternating (host, device, host, device, …) so a noisy machine hurts both alike, medians
reported, each line written to stdout and to ``$OUT/device_scoring.txt`` (or ``--out``) as it is known:

* ``host``: ``evaluate`` with ``score_on_device = False`` (the code before: states back, scored here);
* ``device``: ``evaluate`` as it is now;
* the backend's own step time for one call (launch to sync) and, for reference, ``mujoco.rollout`` of the same
  batch on the CPU pool (``--cpu-threads``);
* how far the device's per-clip sums lie from the host's scoring of the very states of the same launch (read
  back from the slot; relative, at most), and whether the two flag the same rollouts as diverged. Two launches
  on a GPU can differ (its atomics order contacts otherwise: a rare contact flip moves a chaotic clip's cost by
  tens of per cent), so the host's own call is not the reference; its median difference is printed beside.

The last line is ``ratio=<host / device>`` at the widest batch.

Usage::

    python benchmarks/device_scoring.py [LOG] [--candidates 2,8,22,62,128] [--clips 32] [--horizon 0.1,0.2]
        [--repeats 7] [--cpu-threads 16]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from pathlib import Path

import numpy as np


def same_launch(gpu, cost, P):
    """``cost.evaluate(P)`` scored on the host from the states of ``gpu``'s last launch (the same rollouts)."""
    c = cost.clips
    return cost.evaluate(P, states=gpu.last_states(len(P), c.horizon, c.control.shape[1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", default=None, help="recording to draw clips from (default: the bundled "
                                                         "example log)")
    ap.add_argument("--candidates", default="2,8,22,62,128", help="candidates per batch, comma-separated (a line "
                                                                  "decision's: 62; a test's: 5)")
    ap.add_argument("--clips", type=int, default=32, help="clips per batch (a line decision's: 32)")
    ap.add_argument("--horizon", default="0.1,0.2", help="clip lengths MIN,MAX [s] (a noisy log's: 0.1,0.2)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--cpu-threads", type=int, default=os.cpu_count())
    ap.add_argument("--out", default=os.environ.get("OUT", "."), help="folder of device_scoring.txt")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    from amhe_cli.estimation.clips import sample_clips
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.problem import example_logs, load_problem
    from amhe_cli.model.rollout import RolloutPool
    from amhe_cli.model.rollout_warp import WarpRollout

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    sink = open(out / "device_scoring.txt", "w")

    def say(line: str) -> None:
        print(line, flush=True)
        sink.write(line + "\n")
        sink.flush()

    a.log = a.log or str(example_logs()[-1])
    pr = load_problem(a.log, params=("box_mass", "box_friction"))
    lo, hi = (float(x) for x in a.horizon.split(","))
    clips = sample_clips(pr.traj, pr.scene, a.clips, (lo, hi), np.random.default_rng(0))
    weights = StateWeights.for_log(pr.traj)
    rng = np.random.default_rng(1)
    widths = [int(x) for x in a.candidates.split(",")]
    P_all = pr.space.project(pr.space.mean0 + rng.normal(0, 0.5, (max(widths), pr.space.dim)) * pr.space.std0)[0]
    say(f"log {a.log}: {len(clips.horizon)} clips of {clips.control.shape[1]} steps at most; "
        f"widths {widths} candidates; {a.repeats} repeats, alternating")
    ratio = None
    with WarpRollout(pr.scene.model) as gpu, RolloutPool(pr.scene.model, a.cpu_threads) as pool, \
            RolloutCost(pr.scene, pr.space, clips, weights, prior_weight=0.0, pool=gpu) as cost, \
            RolloutCost(pr.scene, pr.space, clips, weights, prior_weight=0.0, pool=pool) as cpu_cost:
        t0 = time.perf_counter()
        cost.evaluate(P_all[:1])
        say(f"first call (kernels, slot, graph): {time.perf_counter() - t0:.1f} s")
        for B in widths:
            P = P_all[:B]
            for flag in (False, True):  # each width's slot and graph set up before timing
                cost.score_on_device = flag
                cost.evaluate(P)
            times: dict[str, list[float]] = {"host": [], "device": [], "steps": []}
            got = {}
            for _ in range(a.repeats):
                for kind, flag in (("host", False), ("device", True)):
                    cost.score_on_device = flag
                    steps0 = gpu.timing["steps"]
                    t0 = time.perf_counter()
                    got[kind] = cost.evaluate(P)
                    times[kind].append(time.perf_counter() - t0)
                    if flag:
                        times["steps"].append(gpu.timing["steps"] - steps0)
            t0 = time.perf_counter()
            cpu_cost.evaluate(P)
            t_cpu = time.perf_counter() - t0
            h, d = got["host"], got["device"]
            same = same_launch(gpu, cost, P)  # the last device call's own states, scored on the host
            ok = ~same.diverged
            rel = float(np.max(np.abs(d.per_clip[ok] - same.per_clip[ok]) / np.abs(same.per_clip[ok])))
            ok2 = ~h.diverged & ~d.diverged
            rel2 = float(np.median(np.abs(d.per_clip[ok2] - h.per_clip[ok2]) / np.abs(h.per_clip[ok2])))
            med = {k: statistics.median(v) for k, v in times.items()}
            ratio = med["host"] / med["device"]
            say(f"{B} x {len(clips.horizon)} = {B * len(clips.horizon)} worlds: host-scored {med['host']:.3f} s, "
                f"device-scored {med['device']:.3f} s (steps {med['steps']:.3f} s), ratio {ratio:.2f}; "
                f"mujoco.rollout + host scoring on {a.cpu_threads} CPU threads {t_cpu:.3f} s; per-clip sums "
                f"within {rel:.1e} relative of the same launch's states scored on the host, diverged alike: "
                f"{bool(np.array_equal(same.diverged, d.diverged))} (against the host's own launch: median "
                f"{rel2:.1e})")
    say(f"ratio={ratio:.2f}")
    sink.close()


if __name__ == "__main__":
    main()
