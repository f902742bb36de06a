"""Can the moving horizon estimator keep up with the robot? Replays a log on the live clock.

Usage::

    python benchmarks/mhe_realtime.py [LOG]

LOG: any push log, e.g. one recorded by ``amhe run --task t3 --mode true`` (the
box's mass switches 4 -> 6 kg at 10 s; docs/tasks.md). Without LOG it replays
the bundled example log (a short probe: few informative updates).

Runs ``amhe mhe-replay LOG --realtime`` with the default settings (all rollout
threads of this machine), prints the updates deferred because the last one still
ran (as ``amhe run`` defers them) and the lag, and as its last line
``realtime_factor=<log duration ÷ the compute every due update would take>``;
≥ 1 means the estimator keeps up with every window.
"""

from __future__ import annotations

import sys

from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator
from amhe_cli.estimation.problem import example_logs, load_problem
from amhe_cli.estimation.replay import replay


def main() -> None:
    log = sys.argv[1] if len(sys.argv) > 1 else str(example_logs()[0])
    problem = load_problem(log, params=("box_mass", "box_friction"))
    settings = MHESettings()
    with MovingHorizonEstimator(problem.scene, problem.space, settings) as mhe:
        res = replay(problem.traj, mhe, realtime=True)
    busy = [u.compute_time for u in res.updates if not u.skipped]
    print(f"log {log}: {res.duration:.1f} s, {len(res.updates)} updates run, due every {settings.every} s "
          f"({len(busy)} informative), window {settings.window} s")
    print(f"compute per informative update: mean {sum(busy) / max(len(busy), 1):.3f} s, max {max(busy, default=0):.3f} s")
    print(f"deferred: {res.deferred} of {res.deferred + len(res.updates)}; "
          f"lag mean {res.lags.mean():.3f} s, max {res.lags.max():.3f} s")
    print(f"realtime_factor={res.realtime_factor:.2f}")


if __name__ == "__main__":
    main()
