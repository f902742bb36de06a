"""Where a line decision places its change (:func:`~amhe_cli.estimation.attribution.locate`), against the truth.

Usage::

    python benchmarks/locate_placement.py LOG [LOG ...] --held M,MU [--lag 0.85] [--back 2.5] [--ahead 1.0]
        [--draws 6] [--tol 0,5,10] [--moved]

A decision that seeks its change (``SplitTracker.search_from``) draws :data:`LOCATE_CLIPS` clips from the data
before and after it, scores both lines and the split held on each, and places the change at the clip from which
the lines gain most on the held split (a likelihood-ratio change point, the best candidate each). This replays
that on each LOG (``<stem>.truth.csv`` beside it, its last change of the box's mass or friction at ``t_c``):
clips from ``[t_c − back, t_c + ahead]`` (a provisional decision's span), the held split ``--held`` (the belief
the run started from), the lines centred on ``--lag`` × the friction force after the change (the windows' product
follows a change over seconds). One line per LOG: each draw's placement minus ``t_c`` [s], per rule: ``tol`` 0 is
``locate`` as the MHE runs it; ``tol`` p takes the latest clip whose gain is within p % of the largest (a later
placement where the clips before the change barely tell); with ``--moved``, also ``locate`` over only the
candidates that move the friction force by :data:`CHANGE` or more. Placed early, a decision scores the old box's data
with the new one's (docs/evaluation.md, "The leg gate in the emulated loop").
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

NAMES = ("box_mass", "box_friction")


def placements(log: str, held: tuple[float, float], lag: float, back: float, ahead: float, draws: int,
               tols: list[float], moved: bool = False) -> dict:
    """{rule: [placement − t_c per draw]} of one LOG (module doc): a ``tol`` per rule, and ``"moved"``."""
    from amhe_cli.estimation.attribution import CHANGE, FACTORS, LOCATE_CLIPS, change_gains, locate
    from amhe_cli.estimation.clips import rest_travel, sample_clips
    from amhe_cli.estimation.cost import RolloutCost, StateWeights
    from amhe_cli.estimation.identify import IdentifySettings, clip_plan
    from amhe_cli.estimation.mhe import MHESettings
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import truth_series
    pr = load_problem(log, params=NAMES)
    traj = pr.traj
    truth = truth_series(log, traj)
    changes = [float(c[-1]) for n in NAMES if truth is not None and len(c := truth.change_times(n))]
    if not changes:
        raise SystemExit(f"{log}: no truth with a change of box_mass or box_friction beside it")
    t_c = max(changes)
    after = {n: float(truth.at(n, np.array([t_c + 0.2]))[0]) for n in NAMES}
    m0, mu0 = held
    f = after["box_mass"] * after["box_friction"] * lag
    n = FACTORS.size
    splits = np.zeros((2 * n + 1, 2))  # the mass line, the friction line (as SplitTracker.candidates), the held split
    splits[:n] = np.c_[f / mu0 * FACTORS, np.full(n, mu0)]
    splits[n:2 * n] = np.c_[np.full(n, m0), f / m0 * FACTORS]
    splits[-1] = held
    im, iu = pr.space.labels.index("box_mass"), pr.space.labels.index("box_friction")
    P = np.repeat(pr.space.mean0[None], len(splits), axis=0)
    P[:, im], P[:, iu] = splits[:, 0], splits[:, 1]
    _, horizon, _ = clip_plan(traj)
    weights = StateWeights.for_log(traj, dict(IdentifySettings().sigma))
    out = {tol: [] for tol in tols} | ({"moved": []} if moved else {})
    far = np.abs(np.log(splits[:-1].prod(axis=1) / (m0 * mu0))) >= CHANGE  # candidates that move the force
    for d in range(draws):
        clips = sample_clips(traj, pr.scene, LOCATE_CLIPS, horizon, np.random.default_rng(100 + d),
                             (t_c - back, t_c + ahead), MHESettings().min_speed, rest_travel(traj))
        with RolloutCost(pr.scene, pr.space, clips, weights, prior_weight=0.0) as cost:
            C = cost.evaluate(P).per_clip
        gain = change_gains(C[:-1], C[-1])
        for tol in tols:
            j = locate(C[:-1], C[-1]) if tol == 0 else \
                int(np.flatnonzero(gain >= gain.max() - tol / 100 * abs(gain.max()))[-1])
            out[tol].append(float(traj.t[clips.start[j]]) - t_c)
        if moved:
            out["moved"].append(float(traj.t[clips.start[locate(C[:-1][far], C[-1])]]) - t_c)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--held", required=True, help="M,MU: the split held before the change (kg, 1)")
    ap.add_argument("--lag", type=float, default=0.85, help="the lines' centre as a share of the force after it")
    ap.add_argument("--back", type=float, default=2.5, help="seconds of data before the change searched")
    ap.add_argument("--ahead", type=float, default=1.0, help="seconds of data after it")
    ap.add_argument("--draws", type=int, default=6)
    ap.add_argument("--tol", default="0,5,10", help="rules, comma-separated: 0 is locate, p the latest within p %%")
    ap.add_argument("--moved", action="store_true", help="also locate over the candidates that move the force")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    held = tuple(float(x) for x in a.held.split(","))
    tols = [float(x) for x in a.tol.split(",")]
    early, late = {}, {}

    def name(rule) -> str:
        return rule if isinstance(rule, str) else f"tol {rule:g}"

    for log in a.logs:
        out = placements(log, held, a.lag, a.back, a.ahead, a.draws, tols, a.moved)
        print(log.rstrip("/").split("/")[-1] + ": " + " | ".join(
            f"{name(rule)}: " + " ".join(f"{e:+.2f}" for e in v) + f" (median {np.median(v):+.2f})"
            for rule, v in out.items()), flush=True)
        for rule, v in out.items():
            early[rule] = early.get(rule, 0) + sum(e < -0.3 for e in v)
            late[rule] = late.get(rule, 0) + sum(e > 0.3 for e in v)
    print("placed more than 0.3 s early / late, of " + str(a.draws * len(a.logs)) + " draws: " +
          ", ".join(f"{name(rule)}: {early[rule]} / {late[rule]}" for rule in early))


if __name__ == "__main__":
    main()
