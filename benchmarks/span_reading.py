"""What one span of a log reads along one parameter's line, and how much of its error is the draw of clips.

Usage::

    python benchmarks/span_reading.py LOG --span T0,T1 --line box_mass --around 6 --hold box_friction=0.5
        [--clips 32,64] [--draws 6] [--smooth auto|0|N] [--legs N] [--seed 0]

A line decision of the run's MHE (:mod:`~amhe_cli.estimation.attribution`) reads a change from clips drawn over
the span after it, the other parameter held. This scores the same thing with the shared cost
(:class:`~amhe_cli.estimation.cost.RolloutCost`, ``W_x`` from the log's pose noise as ``identify`` takes it, no
prior term): ``--line`` over a fine grid, ``--around`` × exp(±0.35) in 71 points, ``--hold`` fixed, on clips drawn
as a decision draws them (``identify``'s horizons, where the box moves) from ``--span`` [s]. Per width of
``--clips``, ``--draws`` draws: each draw's reading, their median and spread (σ of the log, in %). With ``--legs
N``: N clips of one draw, read all together and split by the legs' contact with the box
(:func:`~amhe_cli.estimation.clips.leg_only_touch`, and any leg within ``LEG_GAP``), each with a bootstrap σ.
``--smooth`` is the reader's pose smoothing (``amhe identify --smooth``). docs/evaluation.md, "The leg gate in
the emulated loop": the draw of 32 clips scatters a 2 s span's mass reading by 1–5 %, the span's own data and the
smoothing by more.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

NAMES = ("box_mass", "box_friction")


def _minimum(grid: np.ndarray, J: np.ndarray) -> float:
    return float(grid[int(np.nanargmin(J))])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--span", required=True, help="T0,T1 [s] of the log the clips start in")
    ap.add_argument("--line", choices=NAMES, default="box_mass", help="the parameter read")
    ap.add_argument("--around", type=float, required=True, help="centre of its grid (e.g. the truth)")
    ap.add_argument("--hold", required=True, help="NAME=VALUE of the other parameter, held")
    ap.add_argument("--clips", default="32", help="clip counts to compare, comma-separated")
    ap.add_argument("--draws", type=int, default=6, help="draws per clip count (0: none, only --legs)")
    ap.add_argument("--smooth", default="auto", help="pose smoothing: auto, 0 or an N-sample window")
    ap.add_argument("--legs", type=int, default=0, help="N clips of one draw split by the legs' contact (0: off)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    from amhe_cli.estimation.clips import (GAP_STRIDE, LEG_GAP, _gap_index, _gaps, leg_only_touch, rest_travel,
                                           sample_clips)
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.identify import IdentifySettings, clip_plan
    from amhe_cli.estimation.mhe import MHESettings
    from amhe_cli.estimation.problem import load_problem
    t0, t1 = (float(x) for x in a.span.split(","))
    held_name, held_value = a.hold.split("=")
    if held_name not in NAMES or held_name == a.line:
        raise SystemExit(f"--hold names the other of {NAMES}, got {held_name!r}")
    smooth = int(a.smooth) if a.smooth.isdigit() else a.smooth
    pr = load_problem(a.log, params=NAMES, smooth=smooth)
    traj = pr.traj
    _, horizon, _ = clip_plan(traj)
    weights = StateWeights.for_log(traj, dict(IdentifySettings().sigma))
    grid = a.around * np.exp(np.linspace(-0.35, 0.35, 71))
    P = np.stack([pr.space.vector({a.line: float(v), held_name: float(held_value)}) for v in grid])
    min_speed = MHESettings().min_speed

    def draw(n: int, seed: int):
        return sample_clips(traj, pr.scene, n, horizon, np.random.default_rng(seed), (t0, t1), min_speed,
                            rest_travel(traj))

    name = a.log.rstrip("/").split("/")[-1]
    for n in (int(x) for x in a.clips.split(",") if a.draws > 0):
        vals = []
        for d in range(a.draws):
            with RolloutCost(pr.scene, pr.space, draw(n, a.seed + d), weights, prior_weight=0.0) as cost:
                vals.append(_minimum(grid, np.asarray(cost(P), dtype=float)))
        v = np.array(vals)
        print(f"{name} [{t0:g}, {t1:g}] s, {a.line} ({held_name} {held_value}), {n} clips: draws "
              f"{np.round(v, 3).tolist()}, median {np.median(v):.3f}, spread {100 * np.std(np.log(v)):.1f} %",
              flush=True)
    if a.legs:
        clips = draw(a.legs, a.seed)
        hi = int(clips.horizon.max())
        alone = leg_only_touch(traj, pr.scene, clips.start, hi)
        index = _gap_index(traj, np.asarray(clips.start), hi, GAP_STRIDE)
        leg = (_gaps(traj, pr.scene, index, "legs")[index] <= LEG_GAP).any(axis=1)
        with RolloutCost(pr.scene, pr.space, clips, weights, prior_weight=0.0) as cost:
            C = cost.evaluate(P).per_clip
        rng = np.random.default_rng(a.seed)
        for what, sel in (("all", np.ones(len(leg), bool)), ("a leg alone on the box", alone),
                          ("no leg alone", ~alone), ("any leg on the box", leg), ("no leg on the box", ~leg)):
            idx = np.flatnonzero(sel)
            if idx.size < 4:
                print(f"  {what}: {idx.size} clips, too few")
                continue
            boot = [_minimum(grid, C[:, rng.choice(idx, idx.size)].sum(axis=1)) for _ in range(50)]
            print(f"  {what}: {idx.size} clips, {_minimum(grid, C[:, idx].sum(axis=1)):.3f} "
                  f"(bootstrap σ {100 * np.std(np.log(boot)):.1f} %)", flush=True)


if __name__ == "__main__":
    main()
