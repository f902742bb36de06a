"""`amhe run --target go1` against `amhe emulate go1`: S_R, falls, e_g, replanning rate and MHE error, per task and mode.

Each run starts the emulator of the task on 127.0.0.1 (1 mm / 0.2° mocap noise,
3 ms latency: its defaults) and the client as a user would:

    amhe run --task T --target go1 --robot 127.0.0.1:PORT --mocap udp:PORT --mode MODE --arm --json --duration D

the client pinned with ``taskset`` to the run's own ``--cores-per-run`` CPUs (a many-core
machine standing in for several robot laptops), the emulator to ``--emulator-cores`` CPUs
of its own (default 1 where the machine has one to spare: the robot's computer, which a
laptop's client never shares; 0 puts it on the client's CPUs); ``--parallel`` pairs run at
once (default: as many as the CPUs hold), spread over ``--gpus`` GPUs where the clients' decisions run on one. The
same seeds run in every mode, so rows pair.
One JSON line per run as it finishes (also appended to ``--jsonl``; ``emulator`` holds the emulator's
overruns, its longest gap between two state packets sent and the states its socket refused, so a watchdog
trip on a gap the rig made is told from the client's own, and the longest gap between two commands it received
(the motors hold the last command meanwhile: a client that stalled); ``lost_box`` counts the client's push-to-approach
switches, ``holds`` the relay's soft holds of a stale plan, ``recoveries_why`` holds [t, reason] of each
fall-reflex recovery,
``robot_reads`` [t, servo share, limit share] of each read of the robot that the planner followed,
``mhe_deferred`` the MHE updates its core budget put off and ``mhe_update_s`` their median wall time [s],
``mhe_decision_s`` the median wall time [s] of its line decisions (``mhe: {attribute: true}``) and
``mhe_decision_batches`` where their GPU backend spent its time (batches, steps, fields, read-back [s]),
``mhe_attributed`` [t, decision, parameter, value] of each change the MHE attributed (``mhe: {attribute: true}``),
``mhe_failed`` its updates that raised, ``plan_interval_ms`` [median, 90th, 99th percentile, longest] of the
time between the planner's plans and ``plan_compute_ms`` [median, 90th, 99th] of their compute (``/amhe/planner``:
what the rest of the client, an estimator's work on its control loop, costs the planner's cycle), ``stalls`` [t, s]
of each stall of the client's process in its loop past 0.15 s (every thread's stack at each stall, the set-up's
too, in the recording's ``.stalls.txt``, gathered into ``--keep``'s ``stalls.txt``); each ``mhe`` segment after a
change holds ``within_after_s``, the seconds after the change from which every estimate held both bounds, None where
the last did not,
``swaps`` [s after the change, kg, μ] of each estimate the planner was given over its first ``SWAPS_AFTER`` s,
and ``attributed_s`` / ``to_planner_s``, the data after the change at its first attribution and the seconds from
there to the planner (:func:`attribution_latency`)), then one row per (task, mode):

* S_R [%] (the client's success: box within the task's radius, no fall, no trip),
  falls (the client's fall test or a safety layer's tilt trip), fall-prevention
  recoveries, other safety trips, e_g mean ± std [m], t_exec mean ± std [s] (to the
  goal, else the run's length), the planner's replanning rate (median over runs, Hz), the robot's longest
  wait for a command (``gap ms``, the worst run's);
* the online MHE's error after each change of the world (T3's mass switch, T4's
  friction step; the emulator prints when each fires and the client's recording
  holds its own start on the same monotonic clock): from 3 s after the change to
  the next one, the worst |mass error| [%] and |μ error| of the planner's
  estimates, and in how many runs they stayed within 10 % and 0.05 (``seg1``,
  ``seg2``…); ``seg0`` is the estimate in force when the first change came (or,
  without one, the last estimate). Baseline rows show
  the fixed belief's error against the changed world.

    python benchmarks/go1_emulated_runs.py --tasks t3,t4 --modes baseline,adaptive --seeds 8 --cores-per-run 4
                                           [--duration S] [--config run.yaml] [--pose-noise 0.001,0.2deg] [--pose-latency 0.02] [--threads 3]
                                           [--label TEXT]   # tags the rows: --table keeps labels apart
                                           [--keep DIR [--keep-max 4] [--keep-tail 10]]  # falls' recordings, and their last seconds
    python benchmarks/go1_emulated_runs.py --table rows.jsonl [more.jsonl ...]   # the table of runs kept earlier

A grid cut off keeps every finished run in ``--jsonl``; ``--table`` prints the table of
such files (several calls' rows together) without running anything.

Clients and emulators run the ``amhe_cli`` this script imported (:func:`amhe_cli.cli.child_command`), not the
working directory's, so ``PYTHONPATH=OTHER python benchmarks/go1_emulated_runs.py --label other`` runs OTHER's
code from any folder. (Before stop 67 a plain ``python -c`` ran the working directory's under every label.)
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from queue import Queue

import numpy as np
from amhe_cli.cli import child_command
from amhe_cli.control.tasks import get_task
from amhe_cli.io.reader import inspect_log, read_float_arrays
from mhe_accuracy import MASS_BOUND, MU_BOUND, held_from, within_bounds  # benchmarks/: the bounds

AMHE = child_command()
EVENT = re.compile(r"event (\w+) -> ([-+0-9.eE]+) at t=([0-9.]+) s \(monotonic ([0-9.]+)\)")
#: the box the emulator plays where ``--box`` set it (its first line's last part: ``, box box_mass 6, box_friction 0.6``)
EMULATOR_BOX = re.compile(r", box ((?:box_\w+ [-+0-9.eE]+(?:, )?)+)$")
EMULATOR_STATS = re.compile(r"overruns (\d+), longest state gap ([0-9.]+) ms")
EMULATOR_REFUSED = re.compile(r"states sent \d+ \(refused (\d+)\)")
EMULATOR_COMMANDS = re.compile(r"longest command gap ([0-9.]+) ms")
EMULATOR_POSES = re.compile(r"longest pose gap ([0-9.]+) ms")
DEFERRED = re.compile(r"(\d+) MHE updates deferred")
STEPS = re.compile(r"MHE step budget per candidate: median (\d+)")
UPDATE_TIME = re.compile(r"MHE updates took a median ([0-9.]+) s")
DECISION_TIME = re.compile(r"MHE line decisions took a median ([0-9.]+) s")
DECISION_BATCHES = re.compile(r"their backend: ([0-9]+) batches, steps ([0-9.]+) s, candidates' fields ([0-9.]+) s, "
                              r"read-back ([0-9.]+) s")
#: the tests and decisions that waited for a leg alone on the box (MovingHorizonEstimator.legs_held)
LEGS_HELD = re.compile(r"(\d+) test\(s\) or decision\(s\) held where the box moved only under a leg alone")
#: the fall reflex's start of a recovery, with what set it off (reflex.FallReflex.update)
RECOVERY = re.compile(r"t=([0-9.]+) s: fall prevention: ([^;]*); stop pushing")
#: the run's read of its robot mid-run (closed_loop.run_task, robot_read): the servo share and the motors' limit share
ROBOT_READ = re.compile(r"t=([0-9.]+) s: this robot is not the one the planner modelled: its own joint efforts read "
                        r"the servo at ([0-9.]+) × the commanded gains and the motors at ([0-9]+)%")
#: Each change the run's MHE attributed (``mhe: {attribute: true}``), from its run log: data time, decision, parameter, value.
ATTRIBUTED = re.compile(r"t=([0-9.]+) s: MHE attributes the change \((\w+), data from [0-9.]+ s\) to (\w+): ([0-9.]+)")
#: The MHE is judged from this long after a change [s] (the issue's "from 3 s after each change").
SETTLE = 3.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_records(path: str) -> dict:
    """A run's MCAP metadata records, name -> dict (``amhe_run``: its settings and figures;
    ``amhe_run_log``: its messages); {} if unreadable."""
    try:
        return {name: dict(rec) for name, rec in inspect_log(path).metadata.items()}
    except ImportError:  # this machine cannot read any recording back: every row would lack its figures
        raise
    except Exception:  # noqa: BLE001 - a run cut off before its recording closed
        return {}


#: Seconds after a change whose estimate swaps a row lists (``swaps``): when each reading reached the planner.
SWAPS_AFTER = 8.0


def emulator_box(first_line: str) -> dict[str, float]:
    """The box parameters the emulator's first line says ``--box`` set (name -> value; {} where none): the truth
    the run's estimates are judged against from the start, in place of the task's."""
    m = EMULATOR_BOX.search(first_line.rstrip())
    if m is None:
        return {}
    return {name: float(value) for name, value in (part.split(" ") for part in m.group(1).split(", "))}


def mhe_errors(recording: str, task, events: list[tuple], t0: float | None, box: dict | None = None) -> list[dict]:
    """Per segment of constant truth (the start, then after each fired event): the worst estimate error
    from ``SETTLE`` s into it to its end, on the client's clock. ``events``: (param, value, monotonic); ``box``:
    the emulator's own box at the start where it is not the task's (:func:`emulator_box`)."""
    try:
        t, est, labels = read_float_arrays(recording, "/amhe/estimate")
    except ImportError:
        raise
    except Exception as exc:  # noqa: BLE001 - no estimate recorded: say why in the run's row
        return [{"error": f"{type(exc).__name__}: {exc}"}]
    if not len(t):
        return []
    truth = {**task.truth, **(box or {})}
    segments, start = [], 0.0
    changes = sorted((mono - t0, p, v) for p, v, mono in events) if t0 is not None else []
    run_end = float(t[-1])
    for k in range(len(changes) + 1):
        end = changes[k][0] if k < len(changes) else np.inf
        segments.append((start, end, dict(truth)))
        if k < len(changes):
            start = changes[k][0]
            truth[changes[k][1]] = changes[k][2]
    mass_all, mu_all = est[:, labels.index("box_mass")], est[:, labels.index("box_friction")]

    def in_force(lo: float, hi: float) -> np.ndarray:  # the estimates in force over [lo, hi): the last swap
        # before it, and every later one
        return np.r_[np.where(t < lo)[0][-1:], np.where((t >= lo) & (t < hi))[0]].astype(int)

    out = []
    for i, (a, b, tr) in enumerate(segments):
        if i == 0:  # before any change: the estimate in force when the world changes (or at the end)
            idx = np.where(t < min(b, run_end + 1))[0][-1:]
            lo = a
        else:  # over [change + SETTLE, next change)
            lo = a + SETTLE
            if lo >= min(b, run_end):
                continue
            idx = in_force(lo, b)
        if not len(idx):
            continue
        mass, mu = mass_all[idx], mu_all[idx]
        row = {"from": round(lo, 2), "to": round(min(b, run_end), 2),
               "mass_err_pct": round(float(np.max(np.abs(100 * (mass / tr["box_mass"] - 1)))), 1),
               "mu_err": round(float(np.max(np.abs(mu - tr["box_friction"]))), 3)}
        if i > 0:  # when it got there: seconds after the change from which every estimate holds both bounds
            k = in_force(a, b)
            held = held_from(t[k], within_bounds(mass_all[k], mu_all[k], tr["box_mass"], tr["box_friction"]), a)
            row["within_after_s"] = None if held is None else round(held, 2)
            # what the planner was given when, over the first SWAPS_AFTER s: seconds after the change, kg, μ
            near = k[t[k] < a + SWAPS_AFTER]
            row["swaps"] = [[round(float(t[j] - a), 2), round(float(mass_all[j]), 2), round(float(mu_all[j]), 3)]
                            for j in near]
        out.append(row)
    return out


def plan_timing(recording: str) -> dict:
    """``plan_interval_ms`` and ``plan_compute_ms`` of a run's recording (the module doc), rounded to 0.1 ms; {}
    where it holds fewer than two plans (a run that ended at its start)."""
    t, v, labels = read_float_arrays(recording, "/amhe/planner")
    if len(t) < 2:
        return {}
    gaps = 1e3 * np.diff(np.asarray(t, dtype=float))
    compute = v[:, labels.index("compute_ms")]
    return {"plan_interval_ms": [round(float(x), 1) for x in (*np.percentile(gaps, [50, 90, 99]), gaps.max())],
            "plan_compute_ms": [round(float(x), 1) for x in np.percentile(compute, [50, 90, 99])]}


def attribution_latency(row: dict) -> None:
    """Add to each of ``row``'s MHE segments after a change where to look for lost time: ``attributed_s``, the
    seconds of data after the change at the first attribution (``mhe_attributed``: the time of the window whose
    decision made it), and ``to_planner_s``, from there to the first estimate the planner was given that carries
    it (``swaps``); both None where there was none within :data:`SWAPS_AFTER` s. A change's bounds from 3 s need
    their sum under 3 s. Where the run says when its MHE jobs ran (``mhe_jobs``), ``job_s`` splits the second:
    ``[started, ended]``, the seconds after its window's update began at which the job that made the first
    attribution started and ended (what lies after ``ended`` is the loop taking it up)."""
    segs = [g for g in row.get("mhe", []) if "swaps" in g]
    for g, ev in zip(segs, row.get("events", [])):
        g["attributed_s"] = g["to_planner_s"] = None
        g.pop("job_s", None)
        if ev.get("t") is None:
            continue
        first = next((a for a in row.get("mhe_attributed", []) if 0 <= a[0] - ev["t"] <= SWAPS_AFTER), None)
        if first is None:
            continue
        after = first[0] - ev["t"]
        col, tol = (1, 0.006) if first[2] == "box_mass" else (2, 0.0015)
        got = next((sw[0] for sw in g["swaps"] if sw[0] >= after - 0.05 and abs(sw[col] - first[3]) <= tol), None)
        g["attributed_s"] = round(after, 2)
        g["to_planner_s"] = None if got is None else round(got - after, 2)
        job = next((j for j in row.get("mhe_jobs", []) if abs(j[0] - first[0]) < 0.006 and j[4] == first[1]), None)
        if job is not None:
            g["job_s"] = [round(job[1], 2), round(job[2], 2)]


def worth_reading(rows: list[dict], limit: int) -> list[dict]:
    """At most ``limit`` of ``rows`` whose recordings a person will want to read afterwards: the runs that fell,
    then those that tripped, then those whose change held the bounds latest after it (never first, then past 3 s,
    latest first). On a lent host the recordings go with it: stop 70's one fall was not read so."""
    def late(r: dict) -> float:
        held = [g.get("within_after_s", -1.0) for g in r.get("mhe", []) if "swaps" in g]
        return max((np.inf if h is None else h for h in held), default=-1.0)
    ranked = sorted(rows, key=lambda r: (not r.get("fell"), not r.get("trip"), -late(r)))
    return [r for r in ranked if r.get("fell") or r.get("trip") or late(r) > 3.0][:limit]


def keep_tail(src: str, dst: str, seconds: float) -> int:
    """Write to ``dst`` the last ``seconds`` [s] of the MCAP recording ``src`` (by log time, its end read from the
    summary or, for a recording cut short, from its messages): every channel's last message before then (the scene,
    the gains and the belief are published once, at the start), the messages from there on, every metadata record
    (the run's log). Returns the messages written. A fall's whole recording can be over what a
    lent host sends back (15 MB): stop 75's one fall, kept on the host, was not read so; its last seconds are
    what tells it.

    Raises:
        OSError: ``src`` unreadable or ``dst`` not writable; mcap's errors for a file that is not an MCAP."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    from amhe_cli.io.writer import chunk_compression
    with open(src, "rb") as fh:
        reader = make_reader(fh)
        header = reader.get_header()
        summary = reader.get_summary()
        if summary is not None and summary.statistics is not None and summary.statistics.message_count:
            end = summary.statistics.message_end_time
        else:
            end = max((m.log_time for _, _, m in reader.iter_messages()), default=0)
        since = end - int(round(seconds * 1e9))
        with open(dst, "wb") as out:
            writer = Writer(out, compression=chunk_compression())  # as the run's own recording is written
            writer.start(profile=header.profile, library=header.library)
            schemas, channels, before, n = {}, {}, {}, 0

            def write(schema, channel, message) -> None:
                if channel.id not in channels:
                    sid = 0
                    if schema is not None:
                        if schema.id not in schemas:
                            schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                        sid = schemas[schema.id]
                    channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, sid,
                                                                   dict(channel.metadata))
                writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                                   message.sequence)

            for schema, channel, message in reader.iter_messages(log_time_order=True):
                if message.log_time < since:
                    before[channel.id] = (schema, channel, message)
                    continue
                for held in sorted(before.values(), key=lambda m: m[2].log_time):
                    write(*held)
                    n += 1
                before = {}
                write(schema, channel, message)
                n += 1
            for record in reader.iter_metadata():
                writer.add_metadata(record.name, dict(record.metadata))
            writer.finish()
    return n


def recording_name(task_name: str, mode: str, seed: int, label: str | None) -> str:
    """File name of one run's recording in ``--out-dir``: ``go1_TASK_MODE_sSEED[_LABEL].mcap``, the label's
    characters outside ``[A-Za-z0-9.-]`` as ``_``. Without the label, two grids run side by side into one folder
    with the same task and seed (two codes compared run for run) wrote one file at once: 6 of 48 runs lost their
    recording or read the other's half-written one (stop 68)."""
    tag = "" if not label else "_" + re.sub(r"[^A-Za-z0-9.-]", "_", label)
    return f"go1_{task_name}_{mode}_s{seed}{tag}.mcap"


def pair_slots(cpus: list[int], parallel: int, cores_per_run: int, emulator_cores: int,
               gpus: int = 0) -> list[tuple[list[int], list[int], int | None]]:
    """Where each of ``parallel`` emulator + client pairs runs: ``(the client's CPUs, the emulator's own, the
    client's GPU)``, CPUs taken in order from ``cpus``, pair k on GPU k mod ``gpus`` (None where ``gpus`` is 0)."""
    per = cores_per_run + emulator_cores
    return [(cpus[k * per:k * per + cores_per_run], cpus[k * per + cores_per_run:(k + 1) * per],
             k % gpus if gpus > 0 else None) for k in range(parallel)]


def one_run(task_name: str, mode: str, seed: int, args, cores: tuple[list[int], list[int], int | None]) -> dict:
    """One emulator + client pair; ``cores``: the client's CPUs, the emulator's own (empty: the client's) and the
    GPU the client's CUDA work goes to (``CUDA_VISIBLE_DEVICES``; None: as this process's)."""
    client, robot, gpu = cores
    env = None if gpu is None else {**os.environ, "CUDA_VISIBLE_DEVICES": str(gpu)}
    pin = ["taskset", "-c", ",".join(map(str, client))]
    pin_emu = ["taskset", "-c", ",".join(map(str, robot or client))]
    pose = free_port()
    duration = args.duration or get_task(task_name).duration  # the task's own limit unless given
    recording = os.path.join(args.out_dir, recording_name(task_name, mode, seed, args.label))
    emu = subprocess.Popen(pin_emu + AMHE + ["emulate", "go1", "--task", task_name, "--port", "0", "--pose-to",
                                         f"127.0.0.1:{pose}", "--duration", str(duration + 30), "--seed",
                                         str(seed), "--pose-noise", args.pose_noise,
                                         *(["--pose-latency", str(args.pose_latency)]
                                           if args.pose_latency is not None else []),
                                         *shlex.split(args.emulator_args)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: Queue = Queue()
    reader = threading.Thread(target=lambda: [lines.put(x) for x in emu.stdout], daemon=True)
    reader.start()
    proc = None
    try:
        first = lines.get(timeout=60)
        while "listening on udp://" not in first:  # a warning on stderr before it
            first = lines.get(timeout=60)
        port = int(first.split("udp://127.0.0.1:")[1].split(",")[0])
        box = emulator_box(first)
        t0 = time.monotonic()
        proc = subprocess.run(pin + AMHE + ["run", "--task", task_name, "--target", "go1", "--robot",
                                            f"127.0.0.1:{port}", "--local-port", "0", "--mocap", f"udp:127.0.0.1:{pose}",
                                            "--mode", mode, "--arm", "--json", "--duration", str(duration),
                                            "--seed", str(seed), "--out", recording, "--force",
                                            *(["--config", args.config] if args.config else []),
                                            *(["--threads", str(args.threads)] if args.threads else []),
                                            *shlex.split(args.run_args.replace("{task}", task_name))],
                              capture_output=True, text=True, timeout=duration + 180, env=env)
        wall = time.monotonic() - t0
    finally:
        emu.terminate()
        emu.wait(10)
        reader.join(5)
    events, emulator = [], {}
    while not lines.empty():
        line = lines.get()
        m = EVENT.search(line)
        if m:
            events.append((m.group(1), float(m.group(2)), float(m.group(4))))
        m = EMULATOR_STATS.search(line)
        if m:  # the emulator's own timing: a state gap past the client's watchdog is the rig's, not the client's
            emulator = {"overruns": int(m.group(1)), "longest_state_gap_ms": float(m.group(2))}
            refused = EMULATOR_REFUSED.search(line)
            if refused:
                emulator["refused_sends"] = int(refused.group(1))
            commands = EMULATOR_COMMANDS.search(line)
            if commands:  # what the robot saw of its client: the motors hold the last command meanwhile
                emulator["longest_command_gap_ms"] = float(commands.group(1))
            poses = EMULATOR_POSES.search(line)
            if poses:  # its world run slow or stopped: a client's stale motion capture then is the rig's
                emulator["longest_pose_gap_ms"] = float(poses.group(1))
    try:
        res = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError, AttributeError):
        res = {"failure": proc.stderr.strip().splitlines()[-1] if proc and proc.stderr.strip() else "no output"}
    text = f"{res.get('failure', '')} {res.get('reason', '')}"
    res.update(task=task_name, mode=mode, seed=seed, rc=proc.returncode if proc else None, wall_s=round(wall, 1),
               **({"threads": args.threads} if args.threads else {}),
               **({"gpu": gpu} if gpu is not None else {}),
               **({"label": args.label} if args.label else {}),
               **({"emulator_args": args.emulator_args} if args.emulator_args else {}),
               **({"run_args": args.run_args} if args.run_args else {}),
               emulator=emulator,
               fell=bool(res.get("fell")) or "tilt" in text or "fell" in text,
               trip="safety" in text or "no valid robot state" in text or "torque" in text or "power" in text)
    # the client's own account (its run log): push-to-approach switches (a trunk at a bound of the push zone
    # flips them) and the MHE updates its core budget put off on the wall clock
    records = run_records(recording)  # read once
    log = " ".join(records.get("amhe_run_log", {}).values())
    res["lost_box"] = log.count("lost the box")
    res["holds"] = log.count("-> hold: ")  # the relay's soft holds of a stale plan
    # when each recovery started and why (a tilt, a height, a rate, or every sampled plan tilting):
    # the rows then tell which part of the loop pushed the trunk out of its envelope
    res["recoveries_why"] = [[float(t), why] for t, why in RECOVERY.findall(log)]
    # each time the run read its robot unlike the planner's model and followed it: [t, servo share, limit share]
    res["robot_reads"] = [[float(t), float(sv), float(lim) / 100] for t, sv, lim in ROBOT_READ.findall(log)]
    res["mhe_attributed"] = [[float(t), why, p, float(v)] for t, why, p, v in ATTRIBUTED.findall(log)]
    res["mhe_failed"] = log.count("MHE update failed")
    m = DEFERRED.search(log)
    res["mhe_deferred"] = int(m.group(1)) if m else 0
    m = STEPS.search(log)
    if m:  # mhe fill: the step budget the estimator's core afforded
        res["mhe_steps"] = int(m.group(1))
    m = UPDATE_TIME.search(log)
    if m:  # the wall time of its updates on the core it had: why fill's budget grew or did not
        res["mhe_update_s"] = float(m.group(1))
    m = DECISION_TIME.search(log)
    if m:  # with the attribution: its share of the time from a change's data to the planner
        res["mhe_decision_s"] = float(m.group(1))
    m = DECISION_BATCHES.search(log)
    if m:  # and where their GPU backend spent it, summed over the run
        res["mhe_decision_batches"] = dict(zip(("batches", "steps_s", "fields_s", "readback_s"),
                                               (int(m.group(1)), *map(float, m.group(2, 3, 4)))))
    if "mhe_decision_s" in res:  # and the spans that waited for a leg alone on the box
        m = LEGS_HELD.search(log)
        res["mhe_legs_held"] = int(m.group(1)) if m else 0
    meta = records.get("amhe_run", {})
    if "control_hz" in meta:
        res["control_hz"] = round(float(meta["control_hz"]), 1)
    try:
        res.update(plan_timing(recording))
    except ImportError:
        raise
    except Exception as exc:  # noqa: BLE001 - no plans recorded: the row says why
        res["plan_timing_error"] = f"{type(exc).__name__}: {exc}"
    t0_run = float(meta["monotonic_t0"]) if "monotonic_t0" in meta else None
    if box:  # the truth it started from, where not the task's
        res["box"] = box
    res["events"] = [{"param": p, "value": v, "t": round(mono - t0_run, 2) if t0_run else None}
                     for p, v, mono in events]
    try:
        res["mhe"] = mhe_errors(recording, get_task(task_name), events, t0_run, box)
    except ImportError:
        raise
    except Exception as exc:  # noqa: BLE001 - a benchmark row says what went wrong rather than ending the grid
        res["mhe"] = [{"error": f"{type(exc).__name__}: {exc}"}]
    attribution_latency(res)
    return res


def table(rows: list[dict], tasks, modes) -> None:
    """One row per (task, mode, ``--label``): S_R, falls, recoveries, trips, e_g, t_exec (to the goal, else the run's
    length), replanning rate, the worst run's longest command gap at the robot, the longest stall of a client's
    process [s] (``amhe run``'s stall watch; ``-``: none past its 0.15 s, or rows from before it), the medians of a run's
    lost-box switches and deferred MHE updates (``-`` in rows from before they were counted), MHE after
    each change."""
    print(f"{'task':4} {'mode':9} {'runs':>4} {'S_R %':>6} {'falls':>5} {'recov':>5} {'trips':>5} "
          f"{'e_g mean ± std [m]':>19} {'t_exec [s]':>12} {'Hz':>5} {'gap ms':>6} {'stall':>5} {'lost':>4} {'defer':>5}  MHE from 3 s after each change: "
          "worst |mass err| / |μ err|, runs within 10 % / 0.05")

    def median(sel, key):
        got = [r[key] for r in sel if r.get(key) is not None]
        return f"{np.median(got):g}" if got else "-"

    labels = list(dict.fromkeys(r.get("label", "") for r in rows))
    for t, m, label in ((t, m, label) for t in tasks for m in modes for label in labels):
        sel = [r for r in rows if r["task"] == t and r["mode"] == m and r.get("label", "") == label]
        if sel:
            e_g = np.array([r.get("e_g", np.nan) for r in sel], dtype=float)
            t_exec = np.array([r.get("t_exec", np.nan) for r in sel], dtype=float)
            hz = [r["control_hz"] for r in sel if "control_hz" in r]
            gaps = [r["emulator"]["longest_command_gap_ms"] for r in sel
                    if "longest_command_gap_ms" in r.get("emulator", {})]
            stalls = [d for r in sel for _, d in r.get("stalls", [])]
            segs = []
            ok = [[g for g in r["mhe"] if "error" not in g] for r in sel]
            nseg = max((len(g) for g in ok), default=0)
            for k in range(nseg):
                got = [g[k] for g in ok if len(g) > k]
                mass = np.array([g["mass_err_pct"] for g in got])
                mu = np.array([g["mu_err"] for g in got])
                settled = [g.get("within_after_s") for g in got if "within_after_s" in g]
                mid = np.median([x if x is not None else np.inf for x in settled]) if settled else np.inf
                late = (f", within both after {f'{mid:.1f} s' if np.isfinite(mid) else 'never'}"
                        f" (median; never in {sum(x is None for x in settled)})") if settled else ""
                lag = [(g["attributed_s"], g["to_planner_s"]) for g in got if g.get("to_planner_s") is not None]
                if lag:  # where those seconds went: the data to its first attribution, then on to the planner
                    late += (f", attributed on {np.median([a for a, _ in lag]):.2f} s of data, at the planner "
                             f"{np.median([b for _, b in lag]):.2f} s later (median of {len(lag)})")
                jobs = [g["job_s"] for g in got if g.get("job_s")]
                if jobs:  # and of those: when its job started and ended after its window's update began
                    late += (f", its job from +{np.median([a for a, _ in jobs]):.2f} s to "
                             f"+{np.median([b for _, b in jobs]):.2f} s")
                segs.append(f"seg{k}: {mass.max():.1f} % / {mu.max():.3f}, {int(np.sum(mass <= 100 * MASS_BOUND))}"
                            f"/{len(got)} / {int(np.sum(mu <= MU_BOUND))}/{len(got)}{late}")
            print(f"{t:4} {m:9} {len(sel):4d} {100 * np.mean([bool(r.get('success')) for r in sel]):6.1f} "
                  f"{sum(r['fell'] for r in sel):5d} {sum(int(r.get('recoveries', 0)) for r in sel):5d} "
                  f"{sum(r['trip'] and not r['fell'] for r in sel):5d} "
                  f"{np.nanmean(e_g):8.3f} ± {np.nanstd(e_g):6.3f} {np.nanmean(t_exec):5.1f} ± {np.nanstd(t_exec):4.1f} "
                  f"{np.median(hz) if hz else float('nan'):5.1f} {f'{max(gaps):.0f}' if gaps else '-':>6} "
                  f"{f'{max(stalls):.2f}' if stalls else '-':>5} "
                  f"{median(sel, 'lost_box'):>4} {median(sel, 'mhe_deferred'):>5}  " + "; ".join(segs)
                  + (f"  [{label}]" if label else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="t1")
    ap.add_argument("--modes", default="adaptive")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=None,
                    help="time limit per run [s] (default: the task's own, as amhe run's: T1 40 s, T2-T4 60 s, T5 20 s)")
    ap.add_argument("--cores-per-run", type=int, default=2, help="CPUs each client is pinned to")
    ap.add_argument("--emulator-cores", type=int, default=None,
                    help="CPUs of each emulator's own, the robot's computer (0: it shares the client's; "
                         "default 1 where the machine has a CPU to spare, else 0)")
    ap.add_argument("--parallel", type=int, default=None,
                    help="pairs at once (default: CPUs // (--cores-per-run + --emulator-cores))")
    ap.add_argument("--out-dir", default=".",
                    help="folder of the runs' recordings, go1_TASK_MODE_sSEED[_LABEL].mcap (grids side by side "
                         "into one folder need labels of their own)")
    ap.add_argument("--jsonl", default=None, help="append each run's JSON line here as it finishes")
    ap.add_argument("--gpus", type=int, default=0,
                    help="spread the clients over this many GPUs, pair k on GPU k mod N (CUDA_VISIBLE_DEVICES), "
                         "for decisions on a GPU (mhe: {attribute_device: cuda}); 0 (default): as this process's")
    ap.add_argument("--config", default=None, help="run config YAML passed to amhe run")
    ap.add_argument("--threads", type=int, default=None,
                    help="the client's planner threads, passed to amhe run (default: its own split of the "
                         "client's CPUs, which gives the adaptive MHE one of 4): e.g. a baseline on 3 of 4 "
                         "plans at adaptive's rate")
    ap.add_argument("--pose-noise", default="0.001,0.2deg", help="the emulator's pose noise (0,0: clean)")
    ap.add_argument("--pose-latency", type=float, default=None,
                    help="how late the emulator's poses arrive [s] (default: the emulator's own, 3 ms)")
    ap.add_argument("--emulator-args", default="",
                    help="more arguments for amhe emulate go1, given with '=': a robot unlike its model, "
                         "--emulator-args='--robot trunk_payload=1.5 --motor-strength 0.85' (kept in each row)")
    ap.add_argument("--run-args", default="",
                    help="more arguments for amhe run, given with '=': --run-args='--belief robot.belief.yaml' "
                         "(kept in each row); {task} stands for the run's task: --run-args='--belief {task}.belief.yaml'")
    ap.add_argument("--label", default=None,
                    help="tag every row of this grid (e.g. the config or machine it ran with): --table keeps "
                         "rows with different labels apart")
    ap.add_argument("--keep", default=None, metavar="DIR",
                    help="copy the recordings worth reading (falls, trips, changes held after 3 s; at most "
                         "--keep-max) here at the end, e.g. a folder that comes back from a lent host")
    ap.add_argument("--keep-max", type=int, default=4)
    ap.add_argument("--keep-tail", type=float, default=10.0, metavar="S",
                    help="beside each kept recording, its last S seconds as NAME.tail.mcap (a few MB, under what a "
                         "lent host sends back; the whole one may not be); 0: none")
    ap.add_argument("--table", nargs="+", default=None, metavar="JSONL",
                    help="print the table of the runs in these --jsonl files and exit")
    args = ap.parse_args()
    if args.table:
        rows = [json.loads(line) for path in args.table for line in open(path) if line.strip()]
        table(rows, list(dict.fromkeys(r["task"] for r in rows)), list(dict.fromkeys(r["mode"] for r in rows)))
        return
    ncpu = len(os.sched_getaffinity(0))
    if args.emulator_cores is None:
        args.emulator_cores = 1 if ncpu > args.cores_per_run else 0
    per = args.cores_per_run + args.emulator_cores
    parallel = args.parallel or max(1, ncpu // per)
    if parallel * per > ncpu:
        sys.exit(f"--parallel {parallel} x (--cores-per-run {args.cores_per_run} + --emulator-cores "
                 f"{args.emulator_cores}) needs {parallel * per} CPUs, this machine has {ncpu}")
    os.makedirs(args.out_dir, exist_ok=True)  # every run's recording goes here: a missing folder failed each run
    slots: Queue = Queue()
    for slot in pair_slots(sorted(os.sched_getaffinity(0)), parallel, args.cores_per_run, args.emulator_cores,
                           args.gpus):
        slots.put(slot)
    tasks, modes = args.tasks.split(","), args.modes.split(",")
    jobs = [(t, m, s) for s in range(args.first_seed, args.first_seed + args.seeds) for t in tasks for m in modes]

    def job(t, m, s):
        cores = slots.get()
        try:
            return one_run(t, m, s, args, cores)
        finally:
            slots.put(cores)

    rows = []
    out = open(args.jsonl, "a") if args.jsonl else None
    with ThreadPoolExecutor(parallel) as pool:
        futures = [pool.submit(job, *j) for j in jobs]
        for fut in as_completed(futures):
            try:
                row = fut.result()
            except ImportError as exc:
                # every row would lack its replanning rate and MHE errors (a lent host without backports.zstd
                # ran 50 runs so): stop at the first, not at the end of the grid
                for f in futures:
                    f.cancel()
                sys.exit(f"cannot read a run's recording back on this machine ({type(exc).__name__}: {exc}); "
                         "install amhe with its dependencies (pip install .) and run the grid again")
            rows.append(row)
            line = json.dumps(row)
            print(line, flush=True)
            if out:
                out.write(line + "\n")
                out.flush()
    table(rows, tasks, modes)
    if args.keep:
        os.makedirs(args.keep, exist_ok=True)
        for r in worth_reading(rows, args.keep_max):
            src = os.path.join(args.out_dir, recording_name(r["task"], r["mode"], r["seed"], args.label))
            if os.path.exists(src):
                shutil.copy(src, args.keep)
                print(f"kept {os.path.basename(src)} in {args.keep}", flush=True)
                if args.keep_tail > 0:
                    tail = os.path.join(args.keep, os.path.basename(src)[:-len(".mcap")] + ".tail.mcap")
                    try:
                        n = keep_tail(src, tail, args.keep_tail)
                        print(f"kept its last {args.keep_tail:g} s ({n} messages) as {os.path.basename(tail)}", flush=True)
                    except Exception as exc:  # noqa: BLE001 - the whole recording is kept either way
                        print(f"could not cut the last {args.keep_tail:g} s of {src}: {exc}", flush=True)
        # every run's stalls of the client's process, with each thread's stack then (amhe run's STEM.stalls.txt)
        stacks = {(r["task"], r["mode"], r["seed"]): os.path.join(args.out_dir, recording_name(
            r["task"], r["mode"], r["seed"], args.label))[:-len(".mcap")] + ".stalls.txt" for r in rows}
        traced = [(r, stacks[r["task"], r["mode"], r["seed"]]) for r in rows
                  if os.path.exists(stacks[r["task"], r["mode"], r["seed"]])]
        if traced:
            with open(os.path.join(args.keep, "stalls.txt"), "a") as f:
                for r, src in traced:
                    f.write(f"==== {os.path.basename(src)}: the loop's stalls [t, s] {r.get('stalls', [])}\n")
                    f.write(open(src).read())
            print(f"kept the stacks of {len(traced)} runs' stalls in {os.path.join(args.keep, 'stalls.txt')}",
                  flush=True)


if __name__ == "__main__":
    main()
