"""`amhe run --target go1` against `amhe emulate go1`, repeated: how often the box gets there and the robot stays up.

Each run starts the emulator of the task on 127.0.0.1 (1 mm / 0.2° mocap
noise, 3 ms latency: its defaults) and the client as a user would:

    amhe run --task T --target go1 --robot 127.0.0.1:PORT --mocap udp:PORT --mode MODE --arm --json --duration D

and reads the client's JSON and exit code. ``--parallel N`` runs N pairs at
once, each pinned with ``taskset`` to its own ``--cores`` CPUs (a many-core
machine standing in for N two-core laptops); the default runs one at a time.
Prints one line per run and a summary: runs with the box within 1.0 m of the
goal (the task's start is 1.48 m away for T1), falls, safety trips, median e_g;
in adaptive mode on a task whose box does not change (T1, T2, T5), also the
online MHE's last estimate against the emulator's truth (median and 90th
percentile of the mass error [%] and the friction error).

    python benchmarks/go1_emulated_runs.py [--runs 5] [--task t1] [--mode adaptive] [--duration 20] [--parallel 1]
                                           [--config run.yaml] [--pose-noise 0.001,0.2deg]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from amhe_cli.control.tasks import get_task
from amhe_cli.io.reader import read_float_arrays

AMHE = [sys.executable, "-c", "from amhe_cli.cli import main; main()"]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_run(k: int, args, cores: list[int] | None, out_dir: str) -> dict:
    pin = ["taskset", "-c", ",".join(map(str, cores))] if cores else []
    pose = free_port()
    recording = os.path.join(out_dir, f"go1_{k}.mcap")
    emu = subprocess.Popen(pin + AMHE + ["emulate", "go1", "--task", args.task, "--port", "0", "--pose-to",
                                         f"127.0.0.1:{pose}", "--duration", str(args.duration + 20), "--seed", str(k),
                                         "--pose-noise", args.pose_noise],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        port = int(emu.stdout.readline().split("udp://127.0.0.1:")[1].split(",")[0])
        t0 = time.monotonic()
        proc = subprocess.run(pin + AMHE + ["run", "--task", args.task, "--target", "go1", "--robot",
                                            f"127.0.0.1:{port}", "--local-port", "0", "--mocap", f"udp:127.0.0.1:{pose}",
                                            "--mode", args.mode, "--arm", "--json", "--duration", str(args.duration),
                                            "--seed", str(k), "--out", recording, "--force",
                                            *(["--config", args.config] if args.config else [])],
                              capture_output=True, text=True, timeout=args.duration + 120)
        wall = time.monotonic() - t0
    finally:
        emu.terminate()
        emu.wait(10)
    try:
        res = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        res = {"failure": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no output"}
    res.update(run=k, rc=proc.returncode, wall_s=round(wall, 1))
    task = get_task(args.task)
    if args.mode == "adaptive" and not task.events and os.path.exists(recording):
        try:
            _, est, labels = read_float_arrays(recording, "/amhe/estimate")
        except Exception:  # noqa: BLE001 - a run cut off before its first estimate
            est = None
        if est is not None and len(est):
            mass, mu = est[-1, labels.index("box_mass")], est[-1, labels.index("box_friction")]
            res.update(mass_err_pct=round(100 * (mass / task.truth["box_mass"] - 1), 1),
                       mu_err=round(float(mu - task.truth["box_friction"]), 3))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--task", default="t1")
    ap.add_argument("--mode", default="adaptive")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--parallel", type=int, default=1)
    ap.add_argument("--cores", type=int, default=2, help="CPUs per pair when --parallel > 1")
    ap.add_argument("--out-dir", default=".")
    ap.add_argument("--config", default=None, help="run config YAML passed to amhe run")
    ap.add_argument("--pose-noise", default="0.001,0.2deg", help="the emulator's pose noise (0,0: clean)")
    args = ap.parse_args()
    ncpu = os.cpu_count() or 1
    cores = [None] * args.runs if args.parallel <= 1 else \
        [[(k % args.parallel) * args.cores + c for c in range(args.cores)] for k in range(args.runs)]
    if args.parallel > 1 and args.parallel * args.cores > ncpu:
        sys.exit(f"--parallel {args.parallel} x --cores {args.cores} needs {args.parallel * args.cores} CPUs, "
                 f"this machine has {ncpu}")
    with ThreadPoolExecutor(max(1, args.parallel)) as pool:
        results = []
        for res in pool.map(lambda k: one_run(k, args, cores[k], args.out_dir), range(args.runs)):
            results.append(res)
            print(json.dumps(res), flush=True)
    e_g = np.array([r.get("e_g", np.nan) for r in results], dtype=float)
    fell = [r for r in results if "tilt" in str(r.get("failure", "")) or r.get("fell")]
    within = int(np.sum(e_g <= 1.0))
    print(f"{args.task} {args.mode}, {args.runs} runs of {args.duration:g} s: box within 1.0 m of the goal in {within}, "
          f"without a fall or trip in {sum(r['rc'] == 0 for r in results)}, safety trips {len(fell)}; "
          f"e_g median {np.nanmedian(e_g):.3f} m")
    mass = np.abs([r["mass_err_pct"] for r in results if "mass_err_pct" in r])
    mu = np.abs([r["mu_err"] for r in results if "mu_err" in r])
    if len(mass):
        print(f"online MHE, last estimate of {len(mass)} runs: |mass error| median {np.median(mass):.1f} %, "
              f"90th percentile {np.percentile(mass, 90):.1f} %; |friction error| median {np.median(mu):.3f}, "
              f"90th percentile {np.percentile(mu, 90):.3f}")


if __name__ == "__main__":
    main()
