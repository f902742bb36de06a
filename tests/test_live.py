"""The live view (``--live``) and the recordings' view channels, as a Foxglove viewer sees them.

Each test starts amhe as a user would (a subprocess on 127.0.0.1), connects with a WebSocket client
speaking the Foxglove protocol (``tests/foxglove_ws.py``) and checks what arrives: the channels, their
schemas, and values that must match the log.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("websockets")

from foxglove_ws import watch  # noqa: E402
from helpers import patient  # noqa: E402

AMHE = [sys.executable, "-c", "from amhe_cli.cli import main; main()"]
LOG = Path(__file__).resolve().parents[1] / "examples" / "logs" / "probe_m2.5_mu0.30.mcap"
SCENE, TF, LOG_T = "foxglove_msgs/msg/SceneUpdate", "foxglove_msgs/msg/FrameTransforms", "foxglove_msgs/msg/Log"
ARRAY = "std_msgs/msg/Float64MultiArray"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(args, tmp_path):
    """amhe ``args`` in a subprocess; waits for its ``live view on ws://…`` line and returns (proc, url)."""
    proc = subprocess.Popen(AMHE + [str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if "live view on ws://" in line:
            return proc, line.split("live view on ")[1].split()[0]
    proc.wait(5)
    raise AssertionError("no live address printed:\n" + "".join(lines) + proc.stdout.read())


def box_poses(path):
    """(log times [ns], (n, 3) positions) of the box in a log (/mocap/box/pose)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    ts, ps = [], []
    with open(path, "rb") as f:
        for _, _, msg, dec in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/mocap/box/pose"]):
            ts.append(msg.log_time)
            p = dec.pose.position
            ps.append((p.x, p.y, p.z))
    return np.array(ts), np.array(ps)


def belief_of(msg) -> dict:
    return dict(zip(msg.layout.dim[0].label.split(","), msg.data))


def test_mhe_replay_live_streams_scene_transforms_belief_and_log(tmp_path):
    port = free_port()
    proc, url = start(["mhe-replay", LOG, "--live", f"127.0.0.1:{port}", "--max-steps", 150, "--samples", 12,
                       "--out", tmp_path / "est.csv", "-q"], tmp_path)
    try:
        assert url == f"ws://127.0.0.1:{port}"
        done = lambda got: any(t == "/amhe/log" and "finished" in m.message for t, _, m in got)  # noqa: E731
        channels, got = watch(url, until=done, timeout=90)
    finally:
        proc.wait(60)
    assert proc.returncode == 0, proc.stderr.read()
    want = {"/amhe/scene": SCENE, "/amhe/tf": TF, "/amhe/belief": ARRAY, "/amhe/log": LOG_T, "/amhe/plan": SCENE}
    for topic, schema in want.items():
        assert channels[topic]["schemaName"] == schema
    by = {}
    for topic, ns, msg in got:
        by.setdefault(topic, []).append((ns, msg))
    # the scene: the robot's bodies from the model's geoms, the box, the floor with the log's true μ
    scene = by["/amhe/scene"][0][1]
    ents = {e.id: e for e in scene.entities}
    assert ents["body/box"].frame_id == "box" and ents["body/box"].frame_locked
    assert pytest.approx(ents["body/box"].cubes[0].size.x, abs=1e-6) == 0.38
    trunk = ents["body/trunk"]
    assert trunk.cubes and trunk.cylinders and trunk.spheres  # box, capsule (cylinder + caps), head
    assert len(ents["body/FR_calf"].spheres) >= 1  # the foot
    assert any("μ 0.30 (truth)" in t.text for e in scene.entities if e.id.startswith("floor/") for t in e.texts)
    # transforms: world -> box near the logged box pose at the same log time
    t_log, p_log = box_poses(LOG)
    errs = []
    for ns, msg in by["/amhe/tf"]:
        tf = {x.child_frame_id: x for x in msg.transforms}
        assert tf["box"].parent_frame_id == "world" and "trunk" in tf
        i = np.argmin(np.abs(t_log - ns))
        tr = tf["box"].translation
        errs.append(np.linalg.norm(np.array([tr.x, tr.y, tr.z]) - p_log[i]))
    assert len(errs) >= 20 and max(errs) < 0.02, (len(errs), max(errs))
    # belief: mass and friction with σ, near the truth by the end
    beliefs = [belief_of(m) for _, m in by["/amhe/belief"]]
    last = beliefs[-1]
    assert last["box_mass_truth"] == pytest.approx(2.5) and last["box_friction_truth"] == pytest.approx(0.30)
    assert abs(last["box_mass"] - 2.5) / 2.5 < 0.10, last
    assert abs(last["box_friction"] - 0.30) < 0.05, last
    assert 0 < last["box_mass_std"] < 1 and last["box_mass_lo"] < last["box_mass"] < last["box_mass_hi"]
    logs = [m for _, m in by["/amhe/log"]]
    assert logs[-1].level == 2 and logs[-1].name == "amhe" and "updates" in logs[-1].message


def test_live_bad_address_and_busy_port_are_one_line_errors(tmp_path):
    bad = subprocess.run(AMHE + ["mhe-replay", str(LOG), "--live", "localhost:99999"], capture_output=True, text=True,
                         cwd=tmp_path)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1].startswith("amhe: error: --live 'localhost:99999'")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        busy = subprocess.run(AMHE + ["mhe-replay", str(LOG), "--live", str(port), "--out", str(tmp_path / "e.csv")],
                              capture_output=True, text=True, cwd=tmp_path)
    assert busy.returncode == 2 and "Traceback" not in busy.stderr, busy.stderr
    err = [ln for ln in busy.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(err) == 1 and f"127.0.0.1:{port}" in err[0] and "cannot listen" in err[0]
    assert not (tmp_path / "e.csv").exists()


def test_the_server_runs_in_its_own_process_and_a_stuck_or_dead_one_never_blocks_the_loop():
    """The view's work is off the control process; a stuck server's process fills its buffer and a
    dead one refuses: either way offer drops the event and returns at once."""
    import os
    import signal
    import time

    from amhe_cli.io.live import LiveServer
    from amhe_cli.io.view import Event, ViewFrames
    from amhe_cli.model.scene import Scene
    scene = Scene()
    server = LiveServer(ViewFrames(scene.model), "127.0.0.1", 0).start()
    ev = Event("state", 0.0, (scene.model.qpos0.copy(),))
    n = 5000  # about 2.5 MB of frames: more than the buffer holds
    try:
        assert server._proc.pid != os.getpid() and server._proc.is_alive() and server.port > 0
        os.kill(server._proc.pid, signal.SIGSTOP)  # stuck
        t0 = time.perf_counter()
        for _ in range(n):
            server.offer(ev)
        assert time.perf_counter() - t0 < 1.0
        stuck = server._dropped_here
        assert 0 < stuck < n
        server._proc.kill()  # dead
        server._proc.join(5)
        t0 = time.perf_counter()
        for _ in range(n):
            server.offer(ev)
        assert time.perf_counter() - t0 < 1.0
        assert server._dropped_here >= stuck + n - 1
    finally:
        t0 = time.perf_counter()
        server.close()
        assert time.perf_counter() - t0 < 5.0
    before = server.dropped
    server.offer(ev)  # after close: dropped, no error
    assert server.dropped == before + 1


def test_close_delivers_the_last_messages_to_a_connected_viewer():
    """What was offered before close reaches a subscribed viewer, the last log line included: the
    server's stop drops what its connections still queue, so it lingers first. Without the linger this
    test failed in 3 of 3 runs."""
    import threading
    import time

    from amhe_cli.io.live import LiveServer
    from amhe_cli.io.view import Event, ViewFrames
    from amhe_cli.model.scene import Scene
    frames = ViewFrames(Scene().model)
    last = lambda got: any(t == "/amhe/log" and m.message == "the end" for t, _, m in got)  # noqa: E731
    for _ in range(4):
        server = LiveServer(frames, "127.0.0.1", 0).start()
        seen = {}
        viewer = threading.Thread(target=lambda: seen.update(got=watch(server.address, until=last, timeout=20)[1]))
        viewer.start()
        deadline = time.monotonic() + 10
        while not server._stats[0] and time.monotonic() < deadline:  # the viewer has subscribed: scene sent
            time.sleep(0.05)
        for i in range(200):
            server.offer(Event("log", 0.01 * i, ("warning", f"line {i}")))
        server.offer(Event("log", 3.0, ("info", "the end")))
        server.close()
        viewer.join(30)
        logs = [m.message for t, _, m in seen["got"] if t == "/amhe/log"]
        assert logs[-1] == "the end" and len(logs) == 201, (len(logs), logs[-3:])


def test_live_layout_prints_the_shipped_layout_built_from_the_sdk(tmp_path):
    import json
    from amhe_cli.io.live import build_layout
    out = subprocess.run(AMHE + ["live-layout"], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0
    layout = json.loads(out.stdout)
    assert out.stdout == build_layout()  # the shipped file is what the builder makes today
    text = json.dumps(layout)
    for topic in ("/amhe/scene", "/amhe/plan", "/amhe/belief.data[0]", "/amhe/belief.data[6]", "/amhe/planner",
                  "/amhe/safety", "/amhe/log"):
        assert topic in text


def _emulated_live_run(where):
    """One `amhe emulate go1 --live` + `amhe run --target go1 --live` pair in ``where``; the emulator
    freezes the motion capture 5 s after the first command. Returns (run channels, run messages,
    emulator view, recording path, run stderr, emulator stderr)."""
    import threading
    p_emu, p_run, pose = free_port(), free_port(), free_port()
    emu = subprocess.Popen(AMHE + ["emulate", "go1", "--task", "t1", "--port", "0", "--pose-to", f"127.0.0.1:{pose}",
                                   "--duration", "40", "--fault", "mocap-freeze@5", "--live", f"127.0.0.1:{p_emu}"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=where)
    first = emu.stdout.readline()
    assert "listening on udp://127.0.0.1:" in first, first + emu.stderr.read()
    port = int(first.split("udp://127.0.0.1:")[1].split(",")[0])
    emu_seen = {}
    t_emu = threading.Thread(target=lambda: emu_seen.update(zip(("channels", "got"), watch(
        f"ws://127.0.0.1:{p_emu}", until=lambda got: sum(t == "/amhe/tf" for t, _, _ in got) >= 20, timeout=60))))
    t_emu.start()
    out = where / "go1.mcap"
    run, url = start(["run", "--task", "t1", "--target", "go1", "--robot", f"127.0.0.1:{port}", "--local-port", "0",
                      "--mocap", f"udp:127.0.0.1:{pose}", "--mode", "baseline", "--threads", "1", "--arm",
                      "--duration", "8", "--out", out, "--live", f"127.0.0.1:{p_run}", "-q", *patient(where)], where)
    try:
        channels, got = watch(url, timeout=90)  # until the run ends and its server goes
    finally:
        run.wait(120)
        t_emu.join(60)
        emu.send_signal(2)
        emu.wait(10)
    return channels, got, emu_seen, out, run.stderr.read(), emu.stderr.read()


def test_run_on_the_emulator_streams_plan_rate_safety_and_trips_and_records_the_same_channels(tmp_path):
    """`amhe emulate go1 --live` and `amhe run --target go1 --live` at once: the emulator shows the true
    robot and box, the run its plan, replanning rate, belief, safety state and the motion-capture
    watchdog as a Log line; the run's recording carries the same channels, and identify reads it."""
    import re
    from mcap.reader import make_reader
    from amhe_cli.plants.go1.safety import SafetySettings
    # A busy machine (two amhe processes, two viewers, on 2 cores) can hold the emulator itself up past
    # the client's state watchdog before the freeze: the client then rightly damps on "no valid robot
    # state" and this run cannot show the freeze. Only a run whose emulator says it stalled is tried again.
    for attempt in range(3):
        where = tmp_path / f"try{attempt}"
        where.mkdir()
        channels, got, emu_seen, out, run_err, emu_said = _emulated_live_run(where)
        if "no valid robot state" not in run_err:
            break
        gap = re.search(r"longest state gap ([0-9.]+) ms", emu_said)
        assert gap and float(gap.group(1)) / 1e3 > SafetySettings().state_timeout, \
            f"the run lost the robot state with no stall of the emulator:\n{run_err}\n{emu_said}"
    else:
        pytest.fail(f"the emulator stalled past the state watchdog in all 3 runs:\n{emu_said}")
    by = {}
    for topic, ns, msg in got:
        by.setdefault(topic, []).append(msg)
    # the plan: a trunk path starting near the trunk, a box path near the box; a replanning rate
    assert len(by["/amhe/plan"]) >= 5 and len(by["/amhe/planner"]) >= 10
    lines = by["/amhe/plan"][-1].entities[0].lines
    assert len(lines) == 2 and len(lines[0].points) > 10
    assert 0.15 < lines[0].points[0].z < 0.4  # the trunk's height
    rates = [m.data[0] for m in by["/amhe/planner"] if np.isfinite(m.data[0])]
    assert rates and 1 < np.median(rates) < 200
    # the planner's forecast the fall reflex reads, in degrees: a standing, walking trunk stays well under 20°;
    # a cycle past 20° (once in ~8 CI runs on two loaded cores, 20.2° at 22 Hz) must have started the reflex
    planner = [dict(zip(m.layout.dim[0].label.split(","), m.data)) for m in by["/amhe/planner"]]
    tilts = np.array([p["forecast_tilt_deg"] for p in planner[1:]])
    assert np.all((tilts >= 0) & (tilts < 90)), (tilts.round(1).tolist(), run_err)
    assert 1 < np.median(tilts) < 10, (tilts.round(1).tolist(), run_err)  # degrees, not radians (5.5 on a clean run)
    assert not np.any(tilts > 20) or "fall prevention: " in run_err, (tilts.round(1).tolist(), run_err)
    # safety: servoing first, then the motion-capture watchdog holds the stand, said in the log with its reason
    states = [dict(zip(m.layout.dim[0].label.split(","), m.data)) for m in by["/amhe/safety"]]
    assert states[0]["ok"] == 1 and any(s["stand"] == 1 for s in states), (states[-1], run_err)
    assert any(m.level == 3 and "motion capture stale" in m.message for m in by["/amhe/log"])
    belief = dict(zip(by["/amhe/belief"][0].layout.dim[0].label.split(","), by["/amhe/belief"][0].data))
    assert belief["box_mass_std"] > 0 and np.isnan(belief["box_mass_truth"])  # a robot: no truth
    # the emulator's own view: the true robot and box
    assert emu_seen["channels"]["/amhe/tf"]["schemaName"] == TF
    tf = [m for t, _, m in emu_seen["got"] if t == "/amhe/tf"][-1]
    frames = {x.child_frame_id: x for x in tf.transforms}
    assert abs(frames["box"].translation.x - 0.52) < 0.3 and 0.15 < frames["trunk"].translation.z < 0.4
    # the recording: the same view channels as live, and identify still reads it
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    recorded = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    for topic in ("/amhe/scene", "/amhe/tf", "/amhe/plan", "/amhe/planner", "/amhe/belief", "/amhe/safety",
                  "/amhe/log"):
        assert recorded[topic] == channels[topic]["schemaName"], topic
    assert recorded["/odom"] == "nav_msgs/msg/Odometry"  # the project's channels stay
    ident = subprocess.run(AMHE + ["identify", str(out), "--generations", "2", "--clips", "4", "--candidates", "1",
                                   "--out", str(where / "b.yaml"), "--json"], capture_output=True, text=True)
    assert "Traceback" not in ident.stderr and "cannot read" not in ident.stderr, ident.stderr


def test_the_ros2_form_of_each_foxglove_schema_has_the_sdk_schemas_fields():
    """The view's foxglove_msgs definitions name the same fields, in the same order, as the SDK's own
    (protobuf) Foxglove schemas, so Foxglove reads them as the standard SceneUpdate, Log, …"""
    descriptor_pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    import foxglove.messages as fm
    from amhe_cli.io.view import FOXGLOVE_MSGS, encoder
    checked = 0
    for name, text in FOXGLOVE_MSGS.items():
        short = name.rsplit("/", 1)[1]
        fds = descriptor_pb2.FileDescriptorSet()
        fds.ParseFromString(getattr(fm, short).get_schema().data)
        proto = {m.name: [f.name for f in m.field] for f in fds.file for m in f.message_type}
        ours = [ln.split()[1] for ln in text.splitlines() if ln and "=" not in ln]
        assert ours == proto[short], (name, ours, proto[short])
        encoder(name)  # and each one compiles to a CDR encoder
        checked += 1
    assert checked == len(FOXGLOVE_MSGS) >= 15
