"""Why the closed loop falls: lock-step sim runs, and for every fall the trunk's last seconds.

Runs tasks × modes × seeds of ``amhe run --target sim`` (one rollout thread each, in
worker processes) and prints one JSON line per run as it finishes: the run's metrics,
whether it fell, the fall-prevention reflex's recoveries, and for a fall a timeline of
its last ``--before`` seconds every 0.1 s — trunk height over the floor, roll and
pitch [deg], yaw rate [rad/s], forward speed [m/s], the box's position in the trunk
frame [m] and the feet on the floor — so the cause can be read, not guessed. The last
lines are a table: runs, falls, recoveries, S_R per (task, mode).

    python benchmarks/fall_forensics.py --tasks t2,t3 --modes true,adaptive --seeds 8 --jobs 16 [--out runs.jsonl]

``--rescue 0.5,0.4,0.3`` also asks, for every fall, *could the recovery have saved it*: from the
recorded plant state that many seconds before the fall it restarts the stand recovery (the reflex's
command, the planner as the run config sets it, the true parameters, 2 s) and reports whether
the robot fell again and its largest tilt (``rescue`` in the run's line). Comparing run configs
on the same falls separates a search that cannot find the saving action from a state already
beyond saving.

``--rescue-log REC --tasks T --rescue 1.27,0.76 --seeds 4`` asks the same of a fall recorded elsewhere (an
emulated Go1's or a real robot's ``amhe run`` recording, which ends at its fall): from its recorded states
that many seconds before its end, ``--seeds`` planner seeds each, no run of its own. A recovery that stays
up here fell to what the wall clock adds (late plans, a state estimated from noisy motion capture).

``--replay-log REC --tasks T --replay-from 4,3 --duration 6 --seeds 4`` runs the task's *own* loop (the
planner as the run config sets it, the reflex, true parameters, any event of the recorded run already
fired) from a recorded run's states that many seconds before its end, in lock-step: does the controller
fall from there without the wall clock? (A config's ``latency`` makes every plan that late, as ``amhe run``
does with it.) Comparing versions (``PYTHONPATH`` at another checkout) on the
same recorded states tries a change against the situation that broke a robot.

``--commands-log REC --tasks T [--cycle 0.025]`` recomputes the task's command at a recorded run's states every
cycle, its phase and step-clear flag carried from cycle to cycle as the loop carries them, and counts how often a
step clear of the box and a turn to face the push began, with the flag carried and without (the code before
:data:`~amhe_cli.control.tasks.CLEAR_HYSTERESIS`): how much of a run's to and fro the command's own thresholds made.

Modes other than ``true`` start from the task's probe belief (as ``amhe evaluate``); ``--beliefs DIR``
keeps the probed beliefs there, so a grid split over several calls (``--first-seed``) probes once.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path

import numpy as np

from amhe_cli.control.closed_loop import has_fallen, make_plant, make_planner, measured_command, run_task
from amhe_cli.control.evaluate import load_config, probe_belief, run_settings
from amhe_cli.control.gait import GAITS
from amhe_cli.control.reflex import recovery_command, trunk_tilt
from amhe_cli.errors import AmheError
from amhe_cli.estimation.belief import Belief
from amhe_cli.io.quat import quat_to_yaw, rotation_from_wxyz, world_to_body
from amhe_cli.io.reader import read_log
from amhe_cli.model.scene import Scene, SceneConfig


def timeline(result, before: float) -> list[dict]:
    """The trunk's last ``before`` seconds of a run's recording, every 0.1 s."""
    tr = result.traj
    cfg = tr.meta["scene"]
    scene = Scene(SceneConfig.from_dict(cfg))
    floor = scene.config.robot_floor
    qpos = scene.qpos_qvel(tr)[0]
    keep = np.where(tr.t >= tr.t[-1] - before)[0][::50]
    feet = scene.foot_bottoms(qpos[keep]) - floor < 0.01
    q = tr.base_quat[keep]
    _, pitch, roll = np.degrees(rotation_from_wxyz(q).as_euler("ZYX")).T
    rel = world_to_body(q, tr.box_pos[keep] - tr.base_pos[keep])
    yaw = quat_to_yaw(q)
    fwd = tr.base_linvel[keep, 0] * np.cos(yaw) + tr.base_linvel[keep, 1] * np.sin(yaw)
    return [{"t": round(float(tr.t[i]), 2), "h": round(float(tr.base_pos[i, 2] - floor), 3),
             "roll": round(float(roll[j]), 1), "pitch": round(float(pitch[j]), 1),
             "wz": round(float(tr.base_angvel[i, 2]), 2), "v": round(float(fwd[j]), 2),
             "box": [round(float(v), 2) for v in rel[j]], "feet": "".join("x" if f else "." for f in feet[j])}
            for j, i in enumerate(keep)]


def plant_at(task, settings, traj, i: int, latency: bool = False):
    """The task's sim plant set to ``traj``'s state at sample ``i`` (lock-step; with ``latency`` the one
    ``settings.latency`` runs on, as :func:`run_task` makes it); (plant, that qpos (nq,))."""
    plant = make_plant(task, settings.kp, settings.kd, settings.planner.dt, realtime=latency, cycle=settings.cycle)
    qpos, qvel = plant.scene.qpos_qvel(traj.slice(i, i + 1))
    plant.reset(qpos[0], qvel[0])
    return plant, qpos[0]


def rescue(task_name: str, config: dict, traj, t0: float, duration: float = 2.0, seed: int = 0) -> dict:
    """Restart the stand recovery from the recorded state at ``t0`` [s]; did the robot stay up?

    The planner is the run config's (true parameters), commanded as the fall reflex does
    (:func:`~amhe_cli.control.reflex.recovery_command`, the ``stand`` gait) for ``duration``
    seconds of lock-step sim from a fresh distribution.
    """
    task, s = run_settings(task_name, "true", config, seed=seed, threads=1)
    i = int(np.argmin(np.abs(traj.t - t0)))
    plant, qpos = plant_at(task, s, traj, i)
    sc = plant.scene
    planner, _ = make_planner(task, s, None, task.truth)
    tilt, fell = float(trunk_tilt(qpos[sc.base_qpos[3:]])), False
    with planner:
        m = plant.measure()
        while m.t < duration and not fell:
            cmd, yaw = measured_command(task, sc, m.qpos, t0 + m.t)
            cmd = recovery_command(cmd, m.qpos[sc.base_qpos[:2]], yaw)
            plan = planner.plan(planner.scene.full_state(m.qpos[None], m.qvel[None])[0], t0 + m.t, cmd, GAITS["stand"])
            plant.execute(plan.controls, s.planner.dt, 0.0)
            m = plant.measure()
            tilt = max(tilt, float(trunk_tilt(m.qpos[sc.base_qpos[3:]])))
            fell = has_fallen(task, sc, m.qpos)
    return {"before": round(float(traj.t[-1] - traj.t[i]), 2), "seed": seed, "fell": fell,
            "max_tilt_deg": round(float(np.degrees(tilt)), 1)}


def replay(task_name: str, config: dict, traj, t0: float, duration: float, seed: int = 0) -> dict:
    """Run the task's own loop (true mode: the planner as ``config`` sets it, the reflex) from the recorded
    state at ``t0`` [s] for ``duration`` seconds of lock-step sim; the run's metrics and largest tilt.

    The plant holds the task's truth with every event already due at ``t0`` applied (``traj``'s box
    position for an event at a box position), and no later event.
    """
    task, s = run_settings(task_name, "true", config, seed=seed, threads=1, duration=duration)
    i = int(np.argmin(np.abs(traj.t - t0)))
    due = {e.param: e.value for e in task.events if e.due(float(traj.t[i]), float(traj.box_pos[i, 0]))}
    task = replace(task, truth={**task.truth, **due}, events=())
    r = run_task(task, None, s, plant=plant_at(task, s, traj, i, latency=s.latency is not None)[0])
    tilt = float(np.degrees(np.max(trunk_tilt(r.traj.base_quat))))
    return {"from": round(float(traj.t[-1] - traj.t[i]), 2), "seed": seed, **r.metrics(),
            "max_tilt_deg": round(tilt, 1), "warnings": r.warnings[:8]}


def from_log(a, path: str, before: list[float], start) -> list[dict]:
    """``start(traj, t0, seed)`` from a recorded run's states ``before`` [s] before its end, for each of
    ``--seeds`` planner seeds; one JSON line each as it finishes, and the rows."""
    try:
        traj = read_log(path)
    except AmheError as exc:
        sys.exit(f"fall_forensics: {exc}")
    rows = []
    for b in before:
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            rows.append(start(traj, float(traj.t[-1]) - b, seed))
            print(json.dumps(rows[-1], default=float), flush=True)
    return rows


def one(args) -> dict:
    task_name, mode, seed, config, belief, before, duration, rescue_at = args
    task, settings = run_settings(task_name, mode, config, seed=seed, threads=1, duration=duration)
    r = run_task(task, Belief(**belief) if belief else None, settings)
    row = {"task": task_name, "mode": mode, "seed": seed, **r.metrics(), "control_hz": round(r.control_hz, 2),
           "warnings": [w for w in r.warnings if "lost the box" not in w][:6]}
    if r.fell or r.failure:
        row["timeline"] = timeline(r, before)
    if r.fell and rescue_at:
        row["rescue"] = [rescue(task_name, config, r.traj, float(r.traj.t[-1]) - b) for b in rescue_at]
    return row


def probe_task(task_name: str, config: dict, threads: int) -> Belief:
    """The task's probe belief, as ``amhe evaluate`` starts Baseline and Adaptive from."""
    task, _ = run_settings(task_name, "adaptive", config)
    return probe_belief(task, seed=0, threads=threads)


def rescue_log(a, config: dict, task_name: str, before: list[float]) -> None:
    """``--rescue-log``: restart the recovery from a recorded fall's states, one JSON line per restart.

    The restarted plant holds the task's starting truth (an event of the recorded run, such as T3's mass
    switch, has not fired in it): a recovery that does not touch the box does not see the difference.
    """
    tries = from_log(a, a.rescue_log, before, lambda traj, t0, seed: rescue(task_name, config, traj, t0, seed=seed))
    print(f"rescues: {sum(not x['fell'] for x in tries)} of {len(tries)} restarts stayed up")


def replay_log(a, config: dict, task_name: str, before: list[float]) -> None:
    """``--replay-log``: the task's own loop from a recorded run's states, one JSON line per start and seed."""
    rows = from_log(a, a.replay_log, before,
                    lambda traj, t0, seed: replay(task_name, config, traj, t0, a.duration or 5.0, seed=seed))
    print(f"replays: {sum(r['fell'] for r in rows)} falls in {len(rows)}, largest tilt "
          f"{max(r['max_tilt_deg'] for r in rows):.1f}°")


def commands_log(a, config: dict, task_name: str) -> None:
    """``--commands-log``: how often the command's step clear and turn to face began along a recorded run (and how
    often within 0.2 s of the last), with the step-clear flag carried (as the loop does) and without; one JSON line."""
    from amhe_cli.control.closed_loop import measured_command
    task, _ = run_settings(task_name, "true", config)
    try:
        traj = read_log(a.commands_log)
    except AmheError as exc:
        sys.exit(f"fall_forensics: {exc}")
    sc = Scene(SceneConfig())
    qpos, _ = sc.qpos_qvel(traj)
    cycles = np.arange(traj.t[0], traj.t[-1], a.cycle)
    idx = np.searchsorted(traj.t, cycles).clip(0, len(traj.t) - 1)
    row = {"log": a.commands_log, "cycle_s": a.cycle, "cycles": len(idx)}
    for name, carry in (("carried", True), ("not_carried", False)):
        phase, clearing, onsets = None, False, {"clearing": [], "beside": []}
        was = dict.fromkeys(onsets, False)
        for t, i in zip(cycles, idx):
            cmd, _ = measured_command(task, sc, qpos[i], float(t), phase=phase, clearing=clearing and carry)
            phase, clearing = cmd["phase"], bool(cmd.get("clearing", False))
            for flag in onsets:
                if cmd.get(flag, False) and not was[flag]:
                    onsets[flag].append(round(float(t), 2))
                was[flag] = bool(cmd.get(flag, False))
        row[name] = {flag: {"onsets": len(v), "within_0.2_s": int(np.sum(np.diff(v) < 0.2)) if len(v) > 1 else 0,
                            "first": v[:1], "last": v[-1:]} for flag, v in onsets.items()}
    print(json.dumps(row), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="t2")
    ap.add_argument("--modes", default="true,adaptive")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=os.cpu_count())
    ap.add_argument("--config", default=None, help="run config YAML (as amhe run --config)")
    ap.add_argument("--duration", type=float, default=None, help="time limit per run [s] (default: the task's)")
    ap.add_argument("--before", type=float, default=2.0, help="seconds of timeline before a fall")
    ap.add_argument("--out", default=None, help="append each run's JSON line here too")
    ap.add_argument("--beliefs", default=None, metavar="DIR",
                    help="starting beliefs as DIR/<task>.belief.yaml: read where there, else probed (one process a "
                         "task, in parallel) and saved there for the next call")
    ap.add_argument("--rescue", default="",
                    help="seconds before each fall to restart the recovery from, e.g. 0.5,0.4,0.3")
    ap.add_argument("--rescue-log", default=None, metavar="REC",
                    help="restart the recovery from this recorded fall's states instead (--rescue: seconds before "
                         "its end; --seeds: planner seeds; the task from --tasks)")
    ap.add_argument("--replay-log", default=None, metavar="REC",
                    help="run the task's own loop from this recorded run's states instead (--replay-from: seconds "
                         "before its end; --duration: seconds, default 5; --seeds: planner seeds; the task from --tasks)")
    ap.add_argument("--replay-from", default="3", help="seconds before the recording's end to replay from, e.g. 4,3")
    ap.add_argument("--commands-log", default=None, metavar="REC",
                    help="count the command's step-clear and turn onsets along this recorded run instead (--tasks: "
                         "its task; --cycle: the control cycle [s])")
    ap.add_argument("--cycle", type=float, default=0.025, help="control cycle for --commands-log [s]")
    a = ap.parse_args()
    config = load_config(a.config)
    tasks, modes = a.tasks.split(","), a.modes.split(",")
    rescue_at = [float(x) for x in a.rescue.split(",") if x]  # seconds before a fall (or a recording's end)
    if a.rescue_log:
        rescue_log(a, config, tasks[0], rescue_at or [0.5])
        return
    if a.replay_log:
        replay_log(a, config, tasks[0], [float(x) for x in a.replay_from.split(",") if x])
        return
    if a.commands_log:
        commands_log(a, config, tasks[0])
        return
    beliefs = {}
    if set(modes) - {"true"}:
        saved = {t: Path(a.beliefs) / f"{t}.belief.yaml" for t in tasks} if a.beliefs else {}
        beliefs = {t: Belief.load(p).__dict__ for t, p in saved.items() if p.exists()}
        todo = [t for t in tasks if t not in beliefs]
        probed = {}
        if todo:
            threads = max(1, min(4, a.jobs // len(todo)))
            with ProcessPoolExecutor(max_workers=len(todo)) as pool:
                probed = dict(zip(todo, pool.map(probe_task, todo, [config] * len(todo), [threads] * len(todo))))
        for t, b in probed.items():
            beliefs[t] = b.__dict__
            if t in saved:
                saved[t].parent.mkdir(parents=True, exist_ok=True)
                b.save(saved[t])
    jobs = [(t, m, s, config, beliefs.get(t) if m != "true" else None, a.before, a.duration, rescue_at)
            for s in range(a.first_seed, a.first_seed + a.seeds) for t in tasks for m in modes]
    rows = []
    out = open(a.out, "a") if a.out else None
    with ProcessPoolExecutor(max_workers=a.jobs) as pool:
        for fut in as_completed([pool.submit(one, j) for j in jobs]):
            row = fut.result()
            rows.append(row)
            line = json.dumps(row, default=float)
            print(line, flush=True)
            if out:
                out.write(line + "\n")
                out.flush()
    print(f"{'task':5} {'mode':9} {'runs':>4} {'falls':>5} {'recov':>5} {'S_R %':>6} {'e_g med':>7}")
    for t in tasks:
        for m in modes:
            sel = [r for r in rows if r["task"] == t and r["mode"] == m]
            if sel:
                print(f"{t:5} {m:9} {len(sel):4d} {sum(r['fell'] for r in sel):5d} "
                      f"{sum(r['recoveries'] for r in sel):5d} {100 * np.mean([r['success'] for r in sel]):6.1f} "
                      f"{np.median([r['e_g'] for r in sel]):7.3f}")
    tries = [x for r in rows for x in r.get("rescue", [])]
    if tries:
        print(f"rescues: {sum(not x['fell'] for x in tries)} of {len(tries)} restarts stayed up")
    print(f"falls={sum(r['fell'] for r in rows)} runs={len(rows)}", file=sys.stdout)


if __name__ == "__main__":
    main()
