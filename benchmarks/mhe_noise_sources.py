"""Which sensor's noise costs the MHE a mass switch? Replays with one signal made clean at a time.

Usage::

    python benchmarks/mocap_degrade.py mass_switch.mcap noisy_switch.mcap --seed 21
    python benchmarks/mhe_noise_sources.py noisy_switch.mcap mass_switch.mcap [--seeds 4] [--jobs 2]
        [--variants as-read,bridged,bridged+base,bridged+box,...] [--config key=value ...]

NOISY is a mass-switch log (4 -> 6 kg at 10 s, ``mass_switch.mcap`` or an ``amhe run --task t3 --mode
true`` recording) as motion capture records it (``mocap_degrade.py``); CLEAN is the same log without
the noise, with its ``.truth.csv`` beside it. Each variant replays the MHE (``mhe-replay``'s settings,
:data:`~amhe_cli.estimation.mhe.REPLAY_SETTINGS`, box mass and friction free) on NOISY as read
(``as-read``), except for what its ``+``-joined parts name:

* ``bridged``: the trunk and box poses counted as observed throughout, where the reader marks each
  dropped message as a gap (``_observed_interp``) and the MHE leaves out every clip across one;
* ``base``: the trunk's pose and twist taken from CLEAN (interpolated onto NOISY's grid);
* ``box``: the box's pose and velocities taken from CLEAN;
* ``box-velocity``: the box's horizontal velocity and yaw rate from the truth CSV;
* ``unpenetrated``: where a robot geom reads inside the box (a noisy pose: the clean log's robot
  stands ~1 mm off the box while it pushes), the box moved out along the separating direction;
* ``planar-box``: the box held on the floor: its height the log's median, roll and pitch 0, no
  vertical velocity, no roll or pitch rate (what a box sliding flat has).

Everything else (the reader's noise report, clip length, ``W_x``, the rest test) stays NOISY's, so a
variant isolates what that signal's noise does to the windows. Per variant, the means over seeds of:
the ``mhe_accuracy.py`` mass-switch targets met (mass within 10 % over 8–10 s and from 13 s, μ
within 0.1), the fused mass's RMS error from 8 s (leaving out 10–13 s, where the switch is followed),
the median window estimate (eq. 4, before fusion) over 8–10 s and from 14 s, and μ's RMS error from
8 s. Rows print as the runs finish.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

PARTS = ("as-read", "bridged", "base", "box", "box-velocity", "planar-box", "unpenetrated", "contact-smoothed")
VARIANTS = ("as-read", "bridged", "bridged+base", "bridged+box", "bridged+box-velocity", "bridged+planar-box",
            "box")
ROLE_FIELDS = {"base": ("base_pos", "base_quat", "base_linvel", "base_angvel"),
               "box": ("box_pos", "box_quat", "box_linvel", "box_angvel")}


def cleaned(traj, variant: str, clean_log: str, scene=None):
    """``traj`` with each ``+``-joined part of ``variant`` applied in place (module docstring)."""
    for part in variant.split("+"):
        _clean(traj, part, clean_log, scene)
    return traj


def unpenetrate(traj, scene) -> int:
    """Move the box out of every robot geom it reads inside of, sample by sample (up to 3 passes: a push
    out of one geom may leave another); returns how many moves were made."""
    moved = 0
    for _ in range(3):
        gaps, dirs = robot_box_gaps(traj, scene)
        inside = gaps < 0
        if not inside.any():
            break
        traj.box_pos[inside] += dirs[inside] * (-gaps[inside])[:, None]
        moved += int(inside.sum())
    return moved


def robot_box_gaps(traj, scene):
    """(T,) distance [m] from the nearest robot geom to the box (negative inside; inf beyond 2 cm) and
    (T, 3) the unit direction that moves the box away from it."""
    import mujoco
    m = scene.model
    d = mujoco.MjData(m)
    box = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "box")
    robot = [g for g in range(m.ngeom) if m.geom_bodyid[g] not in (0, m.geom_bodyid[box])
             and (m.geom_contype[g] & m.geom_conaffinity[box] or m.geom_conaffinity[g] & m.geom_contype[box])]
    fromto = np.zeros(6)
    gaps, dirs = np.full(len(traj), np.inf), np.zeros((len(traj), 3))
    for i, q in enumerate(scene.qpos_qvel(traj)[0]):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        dist, g = min((mujoco.mj_geomDistance(m, d, g, box, 0.02, fromto), g) for g in robot)
        if dist >= 0.02:
            continue
        mujoco.mj_geomDistance(m, d, g, box, 0.02, fromto)
        n = fromto[3:] - fromto[:3]  # robot point -> box point; inside, it points into the robot
        n = n / max(np.linalg.norm(n), 1e-12)
        gaps[i], dirs[i] = dist, (n if dist >= 0 else -n)
    return gaps, dirs


def contact_smooth(traj, scene, window: int = 75) -> None:
    """Where the robot is within 5 mm of the box, move the box along the separating direction so that the
    robot-box distance is its local linear fit over ``window`` samples rather than one noisy reading."""
    from scipy.signal import savgol_filter
    gaps, dirs = robot_box_gaps(traj, scene)
    near = gaps < 0.005
    g = np.where(np.isfinite(gaps), gaps, 0.02)
    fit = savgol_filter(g, window, 1)
    ok = near & (fit < 0.005)
    traj.box_pos[ok] += dirs[ok] * (fit[ok] - gaps[ok])[:, None]
    print(f"contact-smoothed: {ok.sum()} box poses moved, rms {1e3 * np.sqrt(np.mean((fit[ok] - gaps[ok]) ** 2)):.2f} mm",
          flush=True)


def _clean(traj, variant: str, clean_log: str, scene=None) -> None:
    from pathlib import Path

    from amhe_cli.io.quat import rotation_from_wxyz
    from amhe_cli.io.reader import read_log
    t = traj.t
    if variant == "contact-smoothed":
        contact_smooth(traj, scene)
    elif variant == "unpenetrated":
        print(f"unpenetrated: {unpenetrate(traj, scene)} box poses moved", flush=True)
    elif variant == "bridged":
        for role in ("base", "box"):
            traj.observed[role][:] = True
    elif variant in ROLE_FIELDS:
        clean = read_log(clean_log)
        for name in ROLE_FIELDS[variant]:
            src = getattr(clean, name)
            getattr(traj, name)[:] = np.stack([np.interp(t, clean.t, src[:, j]) for j in range(src.shape[1])], 1)
    elif variant == "box-velocity":
        d = np.genfromtxt(Path(clean_log).with_suffix(".truth.csv"), delimiter=",", names=True)
        traj.box_linvel[:, 0] = np.interp(t, d["t"], d["box_vx_world"])
        traj.box_linvel[:, 1] = np.interp(t, d["t"], d["box_vy_world"])
        rot = rotation_from_wxyz(traj.box_quat)
        yaw_rate = np.interp(t, d["t"], d["box_wz"])
        traj.box_angvel[:] = rot.inv().apply(np.stack([0 * t, 0 * t, yaw_rate], 1))  # body frame
    elif variant == "planar-box":
        rot = rotation_from_wxyz(traj.box_quat)
        yaw_rate = rot.apply(traj.box_angvel)[:, 2]  # world z
        yaw = rot.as_euler("ZYX")[:, 0]
        traj.box_pos[:, 2] = np.median(traj.box_pos[:, 2])
        traj.box_quat[:] = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)
        traj.box_linvel[:, 2] = 0.0
        traj.box_angvel[:] = np.stack([0 * t, 0 * t, yaw_rate], 1)  # flat: body z is world z


def run(job):
    noisy, clean, variant, settings, seed = job
    import warnings

    from amhe_cli.estimation.cost import StateWeights
    from amhe_cli.estimation.mhe import REPLAY_SETTINGS, MHESettings, MovingHorizonEstimator
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import estimates_table, replay
    warnings.simplefilter("ignore")  # the reader's noise report, once per run
    pr = load_problem(noisy, params=("box_mass", "box_friction"))
    if variant != "as-read":
        cleaned(pr.traj, variant, clean, pr.scene)
    with MovingHorizonEstimator(pr.scene, pr.space, MHESettings(**{**REPLAY_SETTINGS, **settings, "seed": seed}),
                                StateWeights.for_log(pr.traj), nthread=1) as m:
        res = replay(pr.traj, m)
    head, rows = estimates_table(pr.space, res)
    t, mass, mu = rows[:, 0], rows[:, head.index("box_mass")], rows[:, head.index("box_friction")]
    truth = np.where(t < 10, 4.0, 6.0)
    pre, post, late = (t >= 8) & (t <= 10), t >= 13, (t >= 8) & ((t < 10) | (t >= 13))
    met = (np.abs(mass[pre] - 4).max() <= 0.4 and np.abs(mass[post] - 6).max() <= 0.6
           and np.abs(mu[t >= 8] - 0.5).max() <= 0.1)
    w = np.array([[u.t, u.window_mean[0]] for u in res.updates if not u.skipped])
    return variant, seed, {
        "met": bool(met),
        "mass_rms": float(np.sqrt(np.mean(((mass[late] - truth[late]) / truth[late]) ** 2))),
        "window_pre": float(np.median(w[(w[:, 0] >= 8) & (w[:, 0] <= 10), 1])),
        "window_post": float(np.median(w[w[:, 0] >= 14, 1])),
        "mu_rms": float(np.sqrt(np.mean((mu[t >= 8] - 0.5) ** 2))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("noisy")
    ap.add_argument("clean")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--config", nargs="*", default=[], help="MHE settings key=value (python literals)")
    a = ap.parse_args()
    variants = a.variants.split(",")
    bad = {p for v in variants for p in v.split("+")} - set(PARTS)
    if bad:
        ap.error(f"unknown variant part {', '.join(sorted(bad))}: expected parts among {', '.join(PARTS)}")
    settings = {k: eval(v) for k, v in (kv.split("=", 1) for kv in a.config)}
    jobs = [(a.noisy, a.clean, v, settings, s) for v in variants for s in range(a.seeds)]
    got: dict[str, list] = {v: [] for v in variants}
    with ProcessPoolExecutor(a.jobs) as ex:
        for fut in as_completed([ex.submit(run, j) for j in jobs]):
            v, seed, r = fut.result()
            got[v].append(r)
            print(f"{v} seed {seed}: " + " ".join(f"{k} {x:.3f}" if isinstance(x, float) else f"{k} {x}"
                                                  for k, x in r.items()), flush=True)
    w = max(len(v) for v in variants + ["variant"])
    print(f"{'variant':<{w}} {'targets met':>11} {'fused mass rms':>14} {'window 8-10 s':>13} {'window 14 s-':>12} "
          f"{'mu rms':>7}")
    for v in variants:
        r = got[v]
        print(f"{v:<{w}} {sum(x['met'] for x in r):>5}/{len(r):<5} {100 * np.mean([x['mass_rms'] for x in r]):12.1f} % "
              f"{np.mean([x['window_pre'] for x in r]):10.2f} kg {np.mean([x['window_post'] for x in r]):9.2f} kg "
              f"{np.mean([x['mu_rms'] for x in r]):7.3f}")


if __name__ == "__main__":
    main()
