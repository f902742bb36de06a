"""Record a clean log's poses again as a motion-capture system would: a lower rate, noise, drops.

Usage::

    python benchmarks/mocap_degrade.py LOG OUT.mcap [--rate 120] [--position-noise 0.001]
        [--orientation-noise-deg 0.2] [--twist-noise 0.01] [--drop 0.02] [--latency 0.0] [--seed 7] [--force]

Makes the "several at once" logs that ``identify_accuracy.py`` is run on: a log
of a robot unlike its model (``mismatch_b.mcap``) with its base and box poses
kept only at ``--rate`` Hz (the samples nearest ``k / rate`` s), white noise on
position [m] per axis and orientation [°] per axis (a small rotation vector
composed in the body frame), white noise [m/s] on the base twist, and a
fraction ``--drop`` of the remaining pose messages left out at random. ``--latency``
stamps every pose that much late, as a log that stamps motion capture when it arrives
does: the trunk's and the box's positions and the box's orientation at time t are those
of t − latency (the trunk's orientation and velocities, the IMU's on a Go1, stay). Joint
states, commands, gains and efforts stay as they were. ``<LOG stem>.truth.yaml`` and
``.truth.csv`` beside LOG (an ``amhe run`` recording has the CSV: a friction step's truth over
time) are copied beside OUT, so ``identify_accuracy.py`` and ``mhe_accuracy.py`` find them.
Prints what it kept.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import rotation_from_wxyz, rotation_to_wxyz
from amhe_cli.io.reader import read_log
from amhe_cli.io.writer import write_mcap


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("out")
    ap.add_argument("--rate", type=float, default=120.0, help="pose rate [Hz]")
    ap.add_argument("--position-noise", type=float, default=0.001, help="σ per axis [m]")
    ap.add_argument("--orientation-noise-deg", type=float, default=0.2, help="σ per axis [°]")
    ap.add_argument("--twist-noise", type=float, default=0.01, help="σ of the base's linear velocity [m/s]")
    ap.add_argument("--drop", type=float, default=0.02, help="fraction of pose messages left out")
    ap.add_argument("--latency", type=float, default=0.0, help="poses stamped this late [s]")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--force", action="store_true", help="replace OUT")
    a = ap.parse_args()
    if a.rate <= 0 or not 0 <= a.drop < 1 or min(a.position_noise, a.orientation_noise_deg, a.twist_noise,
                                                   a.latency) < 0:
        sys.exit("expected --rate > 0, 0 <= --drop < 1 and non-negative noise figures and --latency")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reader's notes on the clean log
        src = read_log(a.log)
    rng = np.random.default_rng(a.seed)
    n = len(src.t)
    keep = np.zeros(n, dtype=bool)
    keep[np.unique(np.minimum(np.round(np.arange(0.0, src.t[-1], 1.0 / a.rate) / src.dt).astype(int), n - 1))] = True

    def noisy(pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = pos + rng.normal(0.0, a.position_noise, pos.shape)
        turn = Rotation.from_rotvec(rng.normal(0.0, np.radians(a.orientation_noise_deg), (n, 3)))
        return pos, rotation_to_wxyz(rotation_from_wxyz(quat) * turn)

    lag = int(round(a.latency / src.dt))

    def late(x: np.ndarray) -> np.ndarray:  # the value of `lag` samples before (the first `lag`: not measured)
        return np.concatenate([np.repeat(x[:1], lag, axis=0), x[:n - lag]]) if lag else x

    box_pos, box_quat = noisy(late(src.box_pos), late(src.box_quat))
    base_pos, base_quat = noisy(late(src.base_pos), src.base_quat)
    observed = dict(src.observed)
    for role in ("box", "base"):
        observed[role] = observed[role] & keep & (rng.random(n) >= a.drop) & (np.arange(n) >= lag)
    out = replace(src, box_pos=box_pos, box_quat=box_quat, base_pos=base_pos, base_quat=base_quat,
                  base_linvel=src.base_linvel + rng.normal(0.0, a.twist_noise, src.base_linvel.shape),
                  observed=observed, meta={})
    try:
        path = write_mcap(a.out, out, overwrite=a.force)
    except AmheError as e:
        sys.exit(f"mocap_degrade: {e}")
    for suffix in (".truth.yaml", ".truth.csv"):
        truth = Path(a.log).with_name(Path(a.log).stem + suffix)
        if truth.is_file():
            shutil.copyfile(truth, path.with_name(path.stem + suffix))
    print(f"{path}: {int(observed['box'].sum())} box and {int(observed['base'].sum())} base poses of {n} samples "
          f"({a.rate:g} Hz, {a.position_noise * 1e3:g} mm / {a.orientation_noise_deg:g}°, {100 * a.drop:g} % dropped, "
          f"{a.latency * 1e3:g} ms late)")


if __name__ == "__main__":
    main()
