"""Throughput of the shared rollout-matching cost against raw ``mujoco.rollout`` on the same work.

In one run on one machine:

(a) ``RolloutCost.evaluate(P)`` for a (batch, d) ``P``: simulated steps per second,
    counted by the cost's own ``rollout_steps`` (batch x clips.steps per call);
(b) the same rollouts straight through a persistent ``mujoco.rollout.Rollout``
    pool: the same clips grouped by horizon, the same ``B`` model copies (with the
    same parameters written in beforehand, untimed), the same thread count, chunk
    size, initial states and controls, inputs and output buffers prepared
    outside the timed region — nothing else.

(a) and (b) alternate over the repeats (a, b, a, b, ...) so a noisy shared machine
hurts both alike; the medians are reported. A separate instrumented pass splits
the cost's time into parameter writes (including ``mj_setConst``), time inside
MuJoCo's rollout, and the rest (input tiling, state unpacking, residuals).

The last line printed is ``ratio=<cost steps/s / raw steps/s>``.

Usage::

    python benchmarks/cost_throughput.py [LOG] [--clips 32] [--batch 16] [--repeats 5] [--threads N]
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
from mujoco import rollout as mj_rollout

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from amhe_cli.estimation.clips import sample_clips  # noqa: E402
from amhe_cli.estimation.cost import RolloutCost, state_error  # noqa: E402
from amhe_cli.model.params import ParameterSpace, parse_names  # noqa: E402
from amhe_cli.model.rollout import default_threads  # noqa: E402
from amhe_cli.model.scene import Scene, SceneConfig, infer_scene_config  # noqa: E402


def synthetic_log():
    """The lunge log of tests/test_core.py: 5 kg box, μ 0.45, three bumps; returns (traj, SceneConfig)."""
    from amhe_cli.control.maneuver import lunge_schedule
    from amhe_cli.plants.sim import SimPlant

    config = SceneConfig()
    plant = SimPlant(config, truth={"box_mass": 5.0, "box_friction": 0.45})
    q, _ = plant.scene.standing_state(box_xy=(0.28 + 0.19 + 0.01, 0.0))
    plant.reset(q)
    for u in lunge_schedule():
        plant.step(u)
    return plant.trajectory(), config


class RawRollout:
    """The cost's rollouts with nothing around them: prepared inputs, one pool call per horizon group."""

    def __init__(self, cost: RolloutCost, P: np.ndarray, nthread: int):
        scene, clips = cost.scene, cost.clips
        B = P.shape[0]
        self.models = [copy.copy(scene.model) for _ in range(B)]
        Q, _ = cost.space.project(P)
        for b in range(B):  # same parameters as the cost will write; not timed
            cost.space.write(self.models[b], Q[b])
        self.datas = [mujoco.MjData(scene.model) for _ in range(nthread)]
        self.pool = mj_rollout.Rollout(nthread=nthread)
        nstate = mujoco.mj_stateSize(scene.model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self.calls = []
        self.steps = 0
        for h in np.unique(clips.horizon):
            idx = np.flatnonzero(clips.horizon == h)
            h = int(h)
            models = [self.models[b] for b in range(B) for _ in idx]
            init = np.ascontiguousarray(np.tile(clips.initial_state[idx], (B, 1)))
            ctrl = np.ascontiguousarray(np.tile(clips.control[idx, :h], (B, 1, 1)))
            state = np.empty((len(models), h, nstate))
            chunk = max(1, len(models) // (nthread * 4))  # what amhe_cli.model.rollout.RolloutPool uses
            self.calls.append((models, init, ctrl, h, state, chunk))
            self.steps += len(models) * h

    def __call__(self) -> None:
        for models, init, ctrl, h, state, chunk in self.calls:
            self.pool.rollout(models, self.datas, init, ctrl, nstep=h, state=state, chunk_size=chunk)

    def close(self) -> None:
        self.pool.close()


def breakdown(cost: RolloutCost, P: np.ndarray, repeats: int) -> dict[str, float]:
    """Median seconds per evaluation spent in writes, in MuJoCo, and elsewhere (instrumented pass)."""
    space, pool = cost.space, cost.pool
    orig_write, orig_inner = space.write, pool._pool.rollout
    acc = {"write": 0.0, "mujoco": 0.0}

    def timed_write(model, vec):
        t = time.perf_counter()
        orig_write(model, vec)
        acc["write"] += time.perf_counter() - t

    class TimedPool:  # stands in for the mujoco pool inside RolloutPool.rollout
        def rollout(self, *a, **kw):
            t = time.perf_counter()
            orig_inner(*a, **kw)
            acc["mujoco"] += time.perf_counter() - t

    space.write = timed_write
    real_pool = pool._pool
    pool._pool = TimedPool()
    rows = []
    try:
        for _ in range(repeats):
            acc["write"] = acc["mujoco"] = 0.0
            t = time.perf_counter()
            cost.evaluate(P)
            total = time.perf_counter() - t
            rows.append((total, acc["write"], acc["mujoco"]))
    finally:
        del space.write
        pool._pool = real_pool
    total, write, inner = (statistics.median(r[i] for r in rows) for i in range(3))
    # pieces of "write": mj_setConst with its MjData allocation, timed on a spare model copy
    m = copy.copy(cost.scene.model)
    sc_times = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(P.shape[0]):
            mujoco.mj_setConst(m, mujoco.MjData(m))
        sc_times.append(time.perf_counter() - t)
    set_const = statistics.median(sc_times)
    # residuals alone: state error + weighting on the rolled-out states
    Q, _ = space.project(P)
    qpos, qvel = cost.rollout(Q)
    c = cost.clips
    res_times = []
    for _ in range(repeats):
        t = time.perf_counter()
        err = state_error(cost.scene, c.qpos[None], c.qvel[None], qpos, qvel)
        ((err * np.sqrt(cost._wmask)[None]) ** 2).sum(axis=(2, 3))  # as RolloutCost.residuals/evaluate
        res_times.append(time.perf_counter() - t)
    residual = statistics.median(res_times)
    return {"total": total, "write": write, "set_const": set_const, "mujoco": inner,
            "residual": residual, "other": total - write - inner}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", nargs="?", help="log to cut clips from (default: a synthetic lunge log)")
    ap.add_argument("--clips", type=int, default=32, help="clips N_c (default 32)")
    ap.add_argument("--batch", type=int, default=16, help="candidates per evaluation B (default 16)")
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats of each (default 5)")
    ap.add_argument("--threads", type=int, default=None, help="rollout threads (default: all CPUs)")
    ap.add_argument("--params", default=None, help="free parameters (default: box_mass,box_inertia,box_friction)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    nthread = args.threads or default_threads()

    t0 = time.perf_counter()
    if args.log:
        from amhe_cli.io.reader import read_log
        traj = read_log(args.log)
        config = infer_scene_config(traj)
        source = args.log
    else:
        traj, config = synthetic_log()
        source = "synthetic lunge log (5 kg, mu 0.45)"
    scene = Scene(config)
    space = ParameterSpace(scene, free=parse_names(args.params))
    rng = np.random.default_rng(args.seed)
    clips = sample_clips(traj, scene, args.clips, rng=rng)
    # candidates near the prior, as in a CMA-ES generation
    P = space.project(space.mean0 + 0.1 * space.std0 * rng.standard_normal((args.batch, space.dim)))[0]
    setup = time.perf_counter() - t0

    cost = RolloutCost(scene, space, clips, nthread=nthread)
    raw = RawRollout(cost, P, nthread)
    steps_per_eval = args.batch * clips.steps
    assert raw.steps == steps_per_eval

    # warm-up (pool threads, page faults, model copies), untimed
    cost.evaluate(P)
    raw()

    t_cost, t_raw, c_cost, c_raw = [], [], [], []
    for _ in range(args.repeats):
        before = cost.rollout_steps
        c, t = time.process_time(), time.perf_counter()
        cost.evaluate(P)
        t_cost.append(time.perf_counter() - t)
        c_cost.append(time.process_time() - c)
        if cost.rollout_steps - before != steps_per_eval:
            raise RuntimeError(f"cost simulated {cost.rollout_steps - before} steps, expected {steps_per_eval}")
        c, t = time.process_time(), time.perf_counter()
        raw()
        t_raw.append(time.perf_counter() - t)
        c_raw.append(time.process_time() - c)
    parts = breakdown(cost, P, args.repeats)
    cost.close()
    raw.close()

    mc, mr = statistics.median(t_cost), statistics.median(t_raw)
    sps_cost, sps_raw = steps_per_eval / mc, steps_per_eval / mr
    hs = np.unique(clips.horizon)
    print(f"log: {source}, {traj.duration:.2f} s; setup {setup:.2f} s")
    print(f"clips: {len(clips)} (horizons {hs.min()}-{hs.max()} steps, {hs.size} horizon groups), "
          f"batch B={args.batch}, d={space.dim} ({','.join(space.free)}), threads={nthread}, "
          f"repeats={args.repeats}, mujoco {mujoco.__version__}")
    print(f"steps per candidate: {clips.steps}; per evaluation: {steps_per_eval}")
    print()
    cc, cr = statistics.median(c_cost), statistics.median(c_raw)
    print("wall-clock medians (min/max over repeats); CPU = process CPU time of all threads:")
    print(f"{'':24s}{'steps/s':>12s}{'ms/eval':>10s}{'min ms':>9s}{'max ms':>9s}{'CPU ms':>9s}{'steps/CPU-s':>13s}")
    for name, m_, ts, c_ in (("(a) RolloutCost.evaluate", mc, t_cost, cc), ("(b) raw mujoco.rollout", mr, t_raw, cr)):
        print(f"{name:24s}{steps_per_eval / m_:12,.0f}{1e3 * m_:10.1f}{1e3 * min(ts):9.1f}{1e3 * max(ts):9.1f}"
              f"{1e3 * c_:9.1f}{steps_per_eval / c_:13,.0f}")
    print(f"ratio of best repeats: {min(t_raw) / min(t_cost):.3f}; ratio of CPU time: {cr / cc:.3f}")
    print()
    tot = parts["total"]
    print(f"where the cost's time goes (instrumented pass, median {1e3 * tot:.1f} ms/eval):")
    print(f"  inside mujoco.rollout        {1e3 * parts['mujoco']:8.1f} ms  {100 * parts['mujoco'] / tot:5.1f} %")
    print(f"  parameter writes             {1e3 * parts['write']:8.1f} ms  {100 * parts['write'] / tot:5.1f} %"
          f"   (of which mj_setConst + MjData alloc ~{1e3 * parts['set_const']:.1f} ms)")
    print(f"  rest (tiling, unpacking, residuals) {1e3 * parts['other']:5.1f} ms  {100 * parts['other'] / tot:5.1f} %"
          f"   (residuals alone ~{1e3 * parts['residual']:.1f} ms)")
    print(f"  outside MuJoCo               {1e3 * (tot - parts['mujoco']):8.1f} ms  "
          f"{100 * (tot - parts['mujoco']) / tot:5.1f} %")
    print(f"ratio={sps_cost / sps_raw:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
