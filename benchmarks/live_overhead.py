"""What ``--live`` costs the control loop: the relay's command period and the planner's rate, with and
without the live server and a viewer connected, against the Go1 emulator.

Each trial starts ``amhe emulate go1 --task t1`` on 127.0.0.1, opens the Go1 plant on it (armed: the
relay ramps to the stand, then follows plans) and runs T1 in baseline mode through
``run_task`` for ``--duration`` s, as ``amhe run --target go1 --arm`` does, with its view:

* ``off``: the view records into memory only (what every ``amhe run`` does for its MCAP);
* ``live``: the same, plus the live server (:class:`amhe_cli.io.live.LiveServer`) and a viewer in a
  separate process (this script with ``--viewer``) subscribed to every channel, as the Foxglove app
  would be, decoding nothing.

Trials alternate off/live ``--trials`` times each (the emulator and a fresh plant per trial).
Per trial: the relay's command period p99 [ms] (``Relay.periods``, the whole run), the planner's
rate [Hz] (cycles per wall-clock second) and, live, the CPU time of the server's process (converting,
encoding, sending; off the control process since the server moved to a process of its own) per
second of run; per condition the medians; last line
``relay_p99_ratio=… planner_rate_ratio=…`` (live ÷ off). Only 127.0.0.1 is used.

``--pin`` (Linux) puts this process (relay, planner, live server) on the first half of the cores and
the emulator and the viewer on the other half, as a robot and a viewer's machine would be: what is
left is the view's own cost to the loop, not the robot's or the viewer's process waking on the
loop's cores. ``--out`` appends each trial as a JSON line as it finishes.

    python benchmarks/live_overhead.py [--trials 3] [--duration 10] [--threads N] [--pin] [--out rows.jsonl]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import time

import numpy as np

from amhe_cli.cli import child_command

AMHE = child_command()


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def viewer(url: str, seconds: float) -> None:
    """A Foxglove WebSocket client subscribed to every channel; prints how many messages and bytes came."""
    import websockets

    async def go():
        n = size = 0
        end = time.monotonic() + seconds
        while True:
            try:
                ws = await websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                              max_size=None)
                break
            except OSError:
                if time.monotonic() > end:
                    return
                await asyncio.sleep(0.05)
        async with ws:
            while time.monotonic() < end:
                try:
                    frame = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                except Exception:  # noqa: BLE001 - the server closed: done
                    break
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op.get("op") == "advertise":
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": c["id"], "channelId": c["id"]} for c in op["channels"]]}))
                else:
                    n, size = n + 1, size + len(frame)
        print(f"viewer: {n} messages, {size / 1e6:.1f} MB")

    asyncio.run(go())


def _pin_to_halves():
    """Pin this process to the first half of its cores; return a ``preexec_fn`` pinning a child to the rest."""
    cores = sorted(os.sched_getaffinity(0))
    half = max(1, len(cores) // 2)
    mine, rest = set(cores[:half]), set(cores[half:]) or set(cores)
    os.sched_setaffinity(0, mine)
    return lambda: os.sched_setaffinity(0, rest)


def trial(live: bool, args) -> dict:
    from amhe_cli.cli.common import task_view_frames
    from amhe_cli.control.closed_loop import RUN_PARAMS, run_task, task_scene_config
    from amhe_cli.control.evaluate import run_settings
    from amhe_cli.estimation.belief import Belief
    from amhe_cli.io.live import LiveServer
    from amhe_cli.io.quat import quat_to_yaw
    from amhe_cli.io.view import View, ViewRecorder
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene
    from amhe_cli.plants.go1.plant import Go1Plant, Go1Settings

    task, settings = run_settings("t1", "baseline", {}, realtime=True, threads=args.threads, duration=args.duration)
    pose = free_port()
    others = _pin_to_halves() if args.pin else None
    emu = subprocess.Popen(AMHE + ["emulate", "go1", "--task", "t1", "--port", "0", "--pose-to", f"127.0.0.1:{pose}",
                                   "--duration", str(args.duration + 30)],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, preexec_fn=others)
    server = client = None
    try:
        port = int(emu.stdout.readline().split("udp://127.0.0.1:")[1].split(",")[0])
        scene = Scene(task_scene_config(task, 0.002, settings.kp, settings.kd))
        plant = Go1Plant(scene, Go1Settings(robot=("127.0.0.1", port), local_port=0, mocap=f"udp:127.0.0.1:{pose}",
                                            arm=True, kp=settings.kp, kd=settings.kd))
        frames = task_view_frames(task, settings.kp, settings.kd, floor=False)
        if live:
            server = LiveServer(frames, "127.0.0.1", free_port(socket.SOCK_STREAM)).start()
            client = subprocess.Popen([sys.executable, __file__, "--viewer", server.address,
                                       str(args.duration + 30)], stdout=subprocess.PIPE, text=True,
                                      preexec_fn=others)
            time.sleep(1.0)  # the viewer connects and subscribes before the run starts
        m = plant.start()
        sc = scene
        task = task.placed(m.qpos[sc.base_qpos[:2]], float(quat_to_yaw(m.qpos[sc.base_qpos[3:]])),
                           m.qpos[sc.box_qpos[:2]])
        plant.relay.periods.clear()
        belief = Belief.nominal(ParameterSpace(scene, free=RUN_PARAMS))
        res = run_task(task, belief, settings, plant=plant, view=View([server, ViewRecorder()]))
        periods = np.asarray(plant.relay.periods)
    finally:
        if server is not None:
            server.close()
        emu.terminate()
        emu.wait(10)
    seen = ""
    if client is not None:
        seen = client.communicate(timeout=60)[0].strip()
    wall = np.sum(res.plan_times)
    return {"live": live, "p99_ms": 1e3 * float(np.percentile(periods, 99)),
            "median_ms": 1e3 * float(np.median(periods)), "planner_hz": float(res.control_hz),
            "compute_ms": 1e3 * float(np.median(res.plan_times)), "cycles": len(res.plan_times),
            "sent": server.sent if server else 0, "dropped": server.dropped if server else 0, "viewer": seen,
            "live_cpu_ms_per_s": 1e3 * server.cpu_s / max(res.traj.duration if len(res.traj) else 1.0, 1e-9)
            if server else 0.0,
            "failure": res.failure, "busy_s": float(wall)}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--viewer":
        viewer(sys.argv[2], float(sys.argv[3]))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--pin", action="store_true", help="loop on the first half of the cores, emulator and viewer "
                                                         "on the other (Linux)")
    ap.add_argument("--out", default=None, help="JSON-lines file each trial is appended to as it finishes")
    args = ap.parse_args()
    out = open(args.out, "a") if args.out else None
    rows = []
    for k in range(args.trials):
        for live in (False, True):
            r = trial(live, args)
            rows.append(r)
            if out:
                out.write(json.dumps({"trial": k, "pin": args.pin, **r}) + "\n")
                out.flush()
            print(f"trial {k} {'live' if live else 'off '}: relay period median {r['median_ms']:.2f} ms, "
                  f"p99 {r['p99_ms']:.2f} ms; planner {r['planner_hz']:.1f} Hz ({r['cycles']} cycles, compute "
                  f"{r['compute_ms']:.0f} ms median)" + (f"; sent {r['sent']}, dropped {r['dropped']}, live process CPU "
                                                        f"{r['live_cpu_ms_per_s']:.1f} ms/s; {r['viewer']}"
                                                       if live else "")
                  + (f"; run stopped: {r['failure']}" if r["failure"] else ""), flush=True)
    med = {live: {key: float(np.median([r[key] for r in rows if r["live"] == live]))
                  for key in ("p99_ms", "planner_hz")} for live in (False, True)}
    print(f"median over {args.trials} trials on {os.cpu_count()} cores: relay p99 {med[False]['p99_ms']:.2f} ms off, "
          f"{med[True]['p99_ms']:.2f} ms live; planner {med[False]['planner_hz']:.1f} Hz off, "
          f"{med[True]['planner_hz']:.1f} Hz live")
    print(f"relay_p99_ratio={med[True]['p99_ms'] / med[False]['p99_ms']:.3f} "
          f"planner_rate_ratio={med[True]['planner_hz'] / med[False]['planner_hz']:.3f}")


if __name__ == "__main__":
    main()
