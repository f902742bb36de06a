"""What building the online MHE's data costs on a live Go1: ``Go1Plant.trajectory(last=…)`` over a recording
of a given length, as a run's estimator thread builds it before each update (twice a second).

The plant's recording is filled here, as a run fills it (no robot, no network): joint ticks at 500 Hz and
motion capture of the trunk and the box at 120 Hz with 1 mm of noise, for each ``--history`` length [s]; each
build is timed ``--repeat`` times. Prints one line per (history, last): the median and fastest build [ms]. A
build that reads the whole history grows with the run's length (before stop 85 the ticks' times were converted
whole under the plant's lock: 600 s of history 27.1 ms for the last 8 s and 12.0 ms for the last 1 s, against
19.4 and 6.3 ms reading only the span, on this project's 2-core machine).

    python benchmarks/mhe_data_build.py [--history 12,60,600] [--last 8,1] [--repeat 15]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def filled_plant(history: float, seed: int = 3):
    """A Go1 plant (no link) whose recording holds ``history`` seconds of ticks and motion capture."""
    from amhe_cli.model.scene import Scene, SceneConfig
    from amhe_cli.plants.go1.plant import Go1Plant, Go1Settings
    scene = Scene(SceneConfig())
    plant = Go1Plant(scene, Go1Settings(), link=object(), poses=object())
    rng = np.random.default_rng(seed)
    box0 = scene.model.qpos0[scene.box_qpos].copy()
    for t in np.arange(0.0, history, 1 / 120):
        plant._raw["box"].append((t, box0[:3] + [0.2 * (t % 5), 0, 0] + rng.normal(0, 0.001, 3), box0[3:],
                                  len(plant._raw["box"])))
        plant._raw["base"].append((t, np.array([0.0, 0.0, 0.27]) + rng.normal(0, 0.001, 3), np.array([1.0, 0, 0, 0]),
                                   len(plant._raw["base"])))
    rec = plant._rec
    for t in np.arange(0.0, history, 0.002):
        rec["t"].append(t)
        rec["qpos"].append(scene.model.qpos0 + rng.normal(0, 1e-3, scene.model.nq))
        rec["qvel"].append(rng.normal(0, 1, scene.model.nv))
        rec["ctrl"].append(rng.normal(0, 1, 12))
        rec["servo"].append(True)
        rec["tau"].append(rng.normal(0, 1, 12))
    return plant


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--history", default="12,60,600", help="recording lengths [s], comma-separated")
    ap.add_argument("--last", default="8,1", help="spans built [s], comma-separated (8: with attribution)")
    ap.add_argument("--repeat", type=int, default=15)
    a = ap.parse_args()
    for history in (float(h) for h in a.history.split(",")):
        plant = filled_plant(history)
        for last in (float(x) for x in a.last.split(",")):
            took = []
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                plant.trajectory(last=last)
                took.append(time.perf_counter() - t0)
            print(f"history {history:6.0f} s, last {last:g} s: build median {np.median(took) * 1e3:.1f} ms "
                  f"(fastest {min(took) * 1e3:.1f})", flush=True)


if __name__ == "__main__":
    main()
