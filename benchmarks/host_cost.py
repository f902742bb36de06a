"""The host's share of a GPU batch: the shared cost scored from states already rolled out.

A MuJoCo Warp batch returns every world's states as float32; ``RolloutCost.evaluate`` then scores them on the
CPU (``state_error``, the whitening, the per-clip sums). In the emulated loop a line decision's batch of 2048
worlds (62 candidates × 32 clips) took 0.46 s, 0.165 s of it the steps (docs/evaluation.md, stop 70): most of
the rest is this scoring, beside a planner on the same CPUs.

In one run on one machine, alternating (a, b, a, b, …) so a noisy machine hurts both alike, medians reported:

(a) the states in float64, as the CPU backend returns them and as every state was scored before float32
    scoring (``state_error`` upcast float32 states to float64);
(b) the same states in float32, as the GPU backend returns them, scored in float32.

The states are one candidate's real rollout over the clips (CPU), repeated over the batch, so no GPU is needed.
The last line printed is ``ratio=<time (a) / time (b)>``.

Usage::

    python benchmarks/host_cost.py LOG [--prior BELIEF] [--candidates 62] [--clips 32] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", help="a recording to draw the clips from (a noisy one: identify's 0.1-0.2 s clips)")
    ap.add_argument("--prior", default=None, help="belief YAML for the parameter space (default: nominal)")
    ap.add_argument("--candidates", type=int, default=62, help="candidates per batch (a GPU line decision's: 62)")
    ap.add_argument("--clips", type=int, default=32, help="clips per batch (a line decision's: 32)")
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    from amhe_cli.estimation.clips import sample_clips
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.identify import clip_plan
    from amhe_cli.estimation.problem import load_problem
    pr = load_problem(a.log, params=("box_mass", "box_friction"), prior=a.prior)
    _, horizon, _ = clip_plan(pr.traj)
    clips = sample_clips(pr.traj, pr.scene, a.clips, horizon, np.random.default_rng(0))
    cost = RolloutCost(pr.scene, pr.space, clips, StateWeights.for_log(pr.traj), nthread=1)
    P = np.repeat(pr.space.mean0[None], a.candidates, axis=0)
    q, v = cost.rollout(P[:1])
    states = {"float64": (np.repeat(q, a.candidates, 0), np.repeat(v, a.candidates, 0))}
    states["float32"] = tuple(x.astype(np.float32) for x in states["float64"])
    print(f"batch: {a.candidates} candidates x {len(clips.horizon)} clips x {q.shape[2]} steps "
          f"({a.candidates * len(clips.horizon)} worlds)", flush=True)
    times: dict[str, list[float]] = {k: [] for k in states}
    per_clip = {}
    for _ in range(a.repeats):
        for kind, s in states.items():
            cost.rollout = lambda Q, s=s: s
            t0 = time.perf_counter()
            per_clip[kind] = cost.evaluate(P).per_clip
            times[kind].append(time.perf_counter() - t0)
    cost.close()
    for kind, ts in times.items():
        print(f"{kind}: median {statistics.median(ts):.3f} s ({min(ts):.3f}-{max(ts):.3f}) per evaluate", flush=True)
    rel = np.max(np.abs(per_clip["float32"] - per_clip["float64"]) / np.abs(per_clip["float64"]))
    print(f"per-clip costs, float32 against float64: {rel:.1e} relative at most")
    print(f"ratio={statistics.median(times['float64']) / statistics.median(times['float32']):.2f}")


if __name__ == "__main__":
    main()
