"""How fast does the gait reference actually walk the plant, open loop?

Usage::

    python benchmarks/gait_calibration.py [--kp 100 --kd 4] [--raw]

Plays the trot reference (no planner) in the 2 ms sim plant for a range of
commanded forward speeds, yaw rates and sideways speeds, measures the base's
mean forward, yaw and sideways speeds from 1 s to 5 s, and fits the stride model of
:class:`~amhe_cli.control.gait.Gait` — realised leg speed = gain · (commanded −
deadband) — to the raw kinematic reference (``--raw``: stride_gain 1,
deadband 0, turn_gain 1, sideways_gain 1). Without ``--raw`` it measures the calibrated
reference, whose achieved speeds should match the commands. The last line
gives the fit and the realised shares of the commanded yaw rate and sideways speed.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np


def walk(gait, v, omega, kp, kd, seconds=5.0, sideways=0.0):
    from amhe_cli.control.closed_loop import make_plant
    from amhe_cli.io.quat import quat_to_yaw
    from amhe_cli.control.tasks import get_task
    plant = make_plant(get_task("t1", box_start=(9.0, 9.0)), kp, kd)  # box far out of the way
    sc = plant.scene
    poses = []
    for k in range(int(seconds / 0.01)):
        plant.step(gait.reference(k * 0.01, v, omega, None, sideways))
        if k in (99, int(seconds / 0.01) - 1):
            qp = plant.data.qpos
            poses.append((qp[sc.base_qpos[0]], qp[sc.base_qpos[1]], float(quat_to_yaw(qp[sc.base_qpos[3:7]]))))
    (x0, y0, a0), (x1, y1, a1) = poses
    dt = seconds - 1.0
    heading = 0.5 * (a0 + a1)
    fwd = ((x1 - x0) * np.cos(heading) + (y1 - y0) * np.sin(heading)) / dt
    side = (-(x1 - x0) * np.sin(heading) + (y1 - y0) * np.cos(heading)) / dt
    return fwd, np.angle(np.exp(1j * (a1 - a0))) / dt, side


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kp", type=float, default=100.0)
    ap.add_argument("--kd", type=float, default=4.0)
    ap.add_argument("--raw", action="store_true", help="measure the uncalibrated kinematic reference")
    a = ap.parse_args()
    from amhe_cli.control.gait import GAITS
    gait = GAITS["trot"]
    if a.raw:
        gait = replace(gait, stride_gain=1.0, stride_deadband=0.0, turn_gain=1.0, sideways_gain=1.0)
    cmds, got, turns = [], [], []
    for v in (0.1, 0.2, 0.3):
        fwd, yaw, _ = walk(gait, v, 0.0, a.kp, a.kd)
        print(f"v {v:.2f} m/s -> {fwd:.3f} m/s (yaw {yaw:+.3f} rad/s)", flush=True)
        cmds.append(v), got.append(fwd)
    for om in (0.15, 0.3, 0.45):
        fwd, yaw, _ = walk(gait, 0.2, om, a.kp, a.kd)
        print(f"v 0.20, omega {om:.2f} rad/s -> {fwd:.3f} m/s, {yaw:+.3f} rad/s", flush=True)
        turns.append(yaw / om)
    sides = []
    for vy in (0.1, -0.1):
        fwd, yaw, side = walk(gait, 0.2, 0.0, a.kp, a.kd, sideways=vy)
        print(f"v 0.20, sideways {vy:+.2f} m/s -> {fwd:.3f} m/s, {side:+.3f} m/s across, {yaw:+.3f} rad/s", flush=True)
        sides.append(side / vy)
    c, g = np.array(cmds), np.array(got)
    gain, off = np.polyfit(c, g, 1)
    print(f"fit: achieved = {gain:.3f} · (commanded - {-off / gain:.3f}) m/s; "
          f"at 0.2 m/s {g[1] / 0.2 * 100:.0f} % of the command; yaw rate {np.mean(turns) * 100:.0f} % of the command; "
          f"sideways {np.mean(sides) * 100:.0f} % of the command")


if __name__ == "__main__":
    main()
