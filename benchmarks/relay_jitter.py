"""The relay's command period against the Go1 emulator, idle and with the planner busy on every core.

Starts ``amhe emulate go1 --task t1`` on 127.0.0.1 in a subprocess, opens a
:class:`~amhe_cli.plants.go1.plant.Go1Plant` on it (armed: the relay ramps to
the stand and then follows plans), and measures the relay's own command period
(``Relay.periods``) and what the emulator received (its ``--record`` CSV):

1. idle: the relay alone for ``--seconds``;
2. loaded: the task's planner replanning back to back from the measured state
   (rollouts on ``--threads`` threads, default all cores) and handing each plan
   to the relay, as ``amhe run`` does.

Prints median, p99 and max of the period [ms] for both, and the last line
``p99_loaded_ms=…``. Only 127.0.0.1 is used.

    python benchmarks/relay_jitter.py [--seconds 10] [--threads N]
"""

from __future__ import annotations

import argparse
import csv
import os
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stats(periods) -> str:
    p = 1e3 * np.asarray(periods)
    return f"median {np.median(p):.2f} ms, p99 {np.percentile(p, 99):.2f} ms, max {p.max():.2f} ms ({len(p)} periods)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()

    from amhe_cli.cli import child_command
    from amhe_cli.control.closed_loop import RunSettings, make_planner, task_scene_config
    from amhe_cli.control.tasks import get_task
    from amhe_cli.estimation.belief import Belief
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene
    from amhe_cli.plants.base import PlantFailure
    from amhe_cli.plants.go1.plant import Go1Plant, Go1Settings
    from amhe_cli.io.quat import quat_to_yaw

    task = get_task("t1")
    from amhe_cli.control.planner import REALTIME_PLANNER, PlannerSettings
    settings = RunSettings(mode="baseline", realtime=True, threads=args.threads,
                           planner=PlannerSettings.from_dict(REALTIME_PLANNER))
    port, pose_port = free_port(), free_port()
    rec = os.path.join(tempfile.mkdtemp(), "rx.csv")
    emu = subprocess.Popen([*child_command(), "emulate", "go1",
                            "--task", "t1", "--port", str(port), "--pose-to", f"127.0.0.1:{pose_port}",
                            "--record", rec, "--duration", str(2 * args.seconds + 15)],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        print(emu.stdout.readline().strip())
        scene = Scene(task_scene_config(task, 0.002, settings.kp, settings.kd))
        plant = Go1Plant(scene, Go1Settings(robot=("127.0.0.1", port), local_port=0,
                                            mocap=f"udp:127.0.0.1:{pose_port}", arm=True))
        m = plant.start()
        relay = plant.relay
        relay.periods.clear()
        time.sleep(args.seconds)
        idle = list(relay.periods)
        busy_idle = np.median(relay.busy) * 1e3
        sc = scene
        task = task.placed(m.qpos[sc.base_qpos[:2]], float(quat_to_yaw(m.qpos[sc.base_qpos[3:]])),
                           m.qpos[sc.box_qpos[:2]])
        belief = Belief.nominal(ParameterSpace(scene, free=("box_mass", "box_friction")))
        planner, _ = make_planner(task, settings, belief, {})
        relay.periods.clear()
        t_load = time.monotonic()
        n_plans = 0
        tripped = None
        while time.monotonic() - t_load < args.seconds:
            try:  # the load is what counts here: after a trip the relay keeps its 2 ms damping loop
                m = plant.measure()
            except PlantFailure as exc:
                tripped = tripped or str(exc)
            q = m.qpos
            cmd = task.command(q[sc.base_qpos[:2]], float(quat_to_yaw(q[sc.base_qpos[3:]])), q[sc.box_qpos[:2]],
                               0.19)
            plan = planner.plan(planner.scene.full_state(m.qpos[None], m.qvel[None])[0], m.t, cmd)
            try:
                plant.execute(plan.controls, settings.planner.dt, plan.compute_time)
            except PlantFailure as exc:
                tripped = tripped or str(exc)
            n_plans += 1
        loaded = list(relay.periods)
        planner.close()
        plant.close()
    finally:
        emu.terminate()
        emu.wait(5)
    with open(rec) as fh:
        rows = list(csv.reader(fh))[1:]
    t_rx = np.array([float(r[0]) for r in rows])
    print(f"relay period, idle:   {stats(idle)}; work per period {busy_idle:.3f} ms (median)")
    print(f"relay period, loaded: {stats(loaded)}; {n_plans / args.seconds:.1f} plans/s on "
          f"{settings.threads or os.cpu_count()} rollout threads")
    if tripped:
        print(f"(the robot tripped during the loaded phase: {tripped}; the relay kept its period, damping)")
    print(f"received by the emulator (its 2 ms tick clock), whole run: {stats(np.diff(t_rx))}")
    print(f"p99_loaded_ms={1e3 * np.percentile(loaded, 99):.2f}")


if __name__ == "__main__":
    main()
