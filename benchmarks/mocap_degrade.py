"""Record a clean log's poses again as a motion-capture system would: a lower rate, noise, drops.

Usage::

    python benchmarks/mocap_degrade.py LOG OUT.mcap [--rate 120] [--position-noise 0.001]
        [--orientation-noise-deg 0.2] [--twist-noise 0.01] [--drop 0.02] [--seed 7] [--force]

Makes the "several at once" logs that ``identify_accuracy.py`` is run on: a log
of a robot unlike its model (``mismatch_b.mcap``) with its base and box poses
kept only at ``--rate`` Hz (the samples nearest ``k / rate`` s), white noise on
position [m] per axis and orientation [°] per axis (a small rotation vector
composed in the body frame), white noise [m/s] on the base twist, and a
fraction ``--drop`` of the remaining pose messages left out at random. Joint
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
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--force", action="store_true", help="replace OUT")
    a = ap.parse_args()
    if a.rate <= 0 or not 0 <= a.drop < 1 or min(a.position_noise, a.orientation_noise_deg, a.twist_noise) < 0:
        sys.exit("expected --rate > 0, 0 <= --drop < 1 and non-negative noise figures")
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

    box_pos, box_quat = noisy(src.box_pos, src.box_quat)
    base_pos, base_quat = noisy(src.base_pos, src.base_quat)
    observed = dict(src.observed)
    for role in ("box", "base"):
        observed[role] = observed[role] & keep & (rng.random(n) >= a.drop)
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
          f"({a.rate:g} Hz, {a.position_noise * 1e3:g} mm / {a.orientation_noise_deg:g}°, {100 * a.drop:g} % dropped)")


if __name__ == "__main__":
    main()
