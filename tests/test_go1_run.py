"""`amhe run --target go1` end to end against `amhe emulate go1`, all on 127.0.0.1.

Each test starts the emulator and the client as the user would (two
processes), injects a fault and reads what the emulator received (its
``--record`` CSV) to check what the client did and when.
"""

from __future__ import annotations

import csv
import json
import re
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from amhe_cli.io.reader import read_float_arrays, read_log
from amhe_cli.model.scene import STAND_JOINTS
from amhe_cli.plants.go1.safety import SafetySettings
from helpers import patient

AMHE = [sys.executable, "-c", "from amhe_cli.cli import main; main()"]
SERVO, DAMPING = 0x0A, 0x00


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Emulator:
    """`amhe emulate go1` in a subprocess; ``.port`` from its first line, ``.rows()`` from its record."""

    def __init__(self, tmp_path, *args, duration=30):
        self.pose_port = free_port()
        self.record = tmp_path / "rx.csv"
        self.summary = ""
        self.proc = subprocess.Popen(
            AMHE + ["emulate", "go1", "--task", "t1", "--port", "0", "--pose-to", f"127.0.0.1:{self.pose_port}",
                    "--record", str(self.record), "--duration", str(duration), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = self.proc.stdout.readline()
        assert "listening on udp://127.0.0.1:" in first, first + self.proc.stderr.read()
        self.port = int(first.split("udp://127.0.0.1:")[1].split(",")[0])

    def client_args(self):
        return ["--robot", f"127.0.0.1:{self.port}", "--local-port", "0", "--mocap", f"udp:127.0.0.1:{self.pose_port}"]

    def stop(self):
        self.proc.send_signal(signal.SIGINT)
        self.proc.wait(10)
        self.summary = self.proc.stderr.read()

    def longest_gap(self) -> float:
        """The emulator's longest wall-clock gap between two states sent [s], from its closing line."""
        m = re.search(r"longest state gap ([0-9.]+) ms", self.summary)
        assert m, self.summary
        return float(m.group(1)) / 1e3

    def longest_pose_gap(self) -> float:
        """The emulator's longest wall-clock gap between two pose datagrams sent [s], from its closing line."""
        m = re.search(r"longest pose gap ([0-9.]+) ms", self.summary)
        assert m, self.summary
        return float(m.group(1)) / 1e3

    def rows(self):
        with open(self.record) as fh:
            rows = list(csv.DictReader(fh))
        t = np.array([float(r["t"]) for r in rows])
        valid = np.array([int(r["valid"]) for r in rows], dtype=bool)
        mode = np.array([[int(r[f"mode_{j}"]) for j in range(12)] for r in rows])
        q = np.array([[float(r[f"q_{j}"]) for j in range(12)] for r in rows])
        kp = np.array([[float(r[f"kp_{j}"]) for j in range(12)] for r in rows])
        kd = np.array([[float(r[f"kd_{j}"]) for j in range(12)] for r in rows])
        return t, valid, mode, q, kp, kd


@pytest.fixture
def emulator(tmp_path, request):
    made = []

    def make(*args, duration=30, where=None):
        emu = Emulator(where or tmp_path, *args, duration=duration)
        made.append(emu)
        return emu
    yield make
    for emu in made:
        if emu.proc.poll() is None:
            emu.stop()


def wait_for_servo(emu, seconds: float, client: subprocess.Popen, timeout: float = 90.0) -> bool:
    """Block until the emulator has heard servo commands for ``seconds`` (its record, read as it grows):
    True; False if the ``client`` process ended first.

    A fixed sleep assumed the client's start-up: on CI's loaded two cores a run
    interrupted 5 s after it started had recorded 0.67 s.
    """
    end = time.monotonic() + timeout
    header, tail, first = None, "", None
    with open(emu.record) as fh:  # only the rows written since the last look: the test must not load the cores
        while time.monotonic() < end:
            lines = (tail + fh.read()).split("\n")
            tail = lines.pop()  # a row half written waits for its end
            for line in filter(None, (ln.strip() for ln in lines)):
                cells = line.split(",")
                if header is None:
                    header = cells
                    i_valid, i_mode = header.index("valid"), header.index("mode_0")
                    continue
                if int(cells[i_valid]) and all(int(c) == SERVO for c in cells[i_mode:i_mode + 12]):
                    first = float(cells[0]) if first is None else first
                    if float(cells[0]) - first >= seconds:
                        return True
            if client.poll() is not None:
                return False
            time.sleep(0.2)
    client.kill()
    _, err = client.communicate(timeout=30)
    raise AssertionError(f"the emulator heard no {seconds} s of servo commands within {timeout} s; "
                         f"the client said:\n{err[-3000:]}")


def stall_retries(emulator, tmp_path, *args, tries: int = 3):
    """Fresh emulators started with ``args``, each with its own folder: yields (emulator, folder) up to
    ``tries`` times, until the test breaks out; fails the test when every try was spent.

    A busy machine can hold the emulator itself up past the client's 40 ms state watchdog: the client
    then rightly damps early and that run cannot show what the test checks. The test tries again only
    a run :func:`assert_stalled` finds so ended.
    """
    for attempt in range(tries):
        where = tmp_path / f"try{attempt}"
        where.mkdir()
        emu = emulator(*args, where=where)
        yield emu, where
    pytest.fail(f"the emulator stalled past the watchdog in all {tries} runs:\n{emu.summary}")


def assert_stalled(emu, why: str, said: str) -> None:
    """The run was spoiled by the emulator's own stall: its longest state gap passed the client's watchdog."""
    assert emu.longest_gap() > SafetySettings().state_timeout, \
        f"{why} with no stall of the state stream; the client said:\n{said}"


def run_unless_stalled(emulator, tmp_path, emulator_args=(), client_args=(), patient_client=False):
    """The client (``client_args``; with ``patient_client``, :func:`helpers.patient`'s watchdogs) against a fresh
    emulator (``emulator_args``), run again (:func:`stall_retries`) only where the emulator's own stall tripped
    the client's state watchdog. Returns (the stopped emulator, the client's process, its recording)."""
    for emu, where in stall_retries(emulator, tmp_path, *emulator_args):
        proc, out = run_client(emu, where, *client_args, *(patient(where) if patient_client else ()))
        emu.stop()
        if "no valid robot state" not in proc.stderr:
            return emu, proc, out
        assert_stalled(emu, "the run stopped", proc.stderr)


def run_client(emu, tmp_path, *args, timeout=90):
    out = tmp_path / "go1.mcap"
    proc = subprocess.run(AMHE + ["run", "--task", "t1", "--target", "go1", *emu.client_args(), "--mode", "baseline",
                                  "--threads", "1", "--out", str(out), "--json", *args],
                          capture_output=True, text=True, timeout=timeout)
    return proc, out


def damped(mode, kp, kd):
    """(N,) rows where every motor is in damping: mode 0x00, or Kp 0 with Kd > 0."""
    return (mode == DAMPING).all(axis=1) | ((kp == 0).all(axis=1) & (kd > 0).all(axis=1))


def first_valid_time(t, valid):
    return t[np.argmax(valid)]


#: Damping must reach the robot within 50 ms of its last state, plus two 2 ms emulator ticks; the record's
#: times are whole ticks, so 1 µs absorbs their floating-point difference (CI once read 5.072 − 5.018 s,
#: exactly 54 ms, as 0.05400000000000027).
DAMP_WITHIN = 0.05 + 0.004 + 1e-6


@pytest.mark.parametrize("fault", ["link-loss", "corrupt"])
def test_lost_or_corrupt_state_ends_in_damping_within_50_ms(emulator, tmp_path, fault):
    # only a run that the emulator's own stall spoiled is tried again (stall_retries): one that ended it
    # before the fault, or one where the damping reached it late and it had stalled (a corrupt state
    # stream still counts its gaps; a client that damps late with no such stall fails below)
    for emu, where in stall_retries(emulator, tmp_path, "--fault", f"{fault}@4.5"):
        proc, out = run_client(emu, where, "--arm", "--duration", "20")
        emu.stop()
        t, valid, mode, q, kp, kd = emu.rows()
        t_loss = first_valid_time(t, valid) + 4.5
        servo = valid & (mode == SERVO).all(axis=1)
        early = valid & (t < t_loss) & (t > t[np.argmax(servo)]) & damped(mode, kp, kd)
        after = (t >= t_loss) & valid & damped(mode, kp, kd)
        late = after.any() and t[after][0] - t_loss > DAMP_WITHIN
        if not early.any() and not (late and emu.longest_gap() > SafetySettings().state_timeout):
            break
        if early.any():
            assert_stalled(emu, f"damped {t_loss - t[early][0]:.3f} s before the fault", proc.stderr)
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(errors) == 1 and "no valid robot state" in errors[0] and "Traceback" not in proc.stderr
    assert json.loads(proc.stdout)["failure"].startswith("no valid robot state")
    # and it says which: a silent robot, or packets that came and failed the link's checks
    assert ("(link lost)" if fault == "link-loss" else "invalid packets meanwhile, the last: LowState packet CRC "
            "mismatch") in errors[0], errors[0]
    before = (t < t_loss) & valid
    assert (mode[before] == SERVO).all(axis=1).sum() > 500  # it was standing and walking on servo commands
    assert after.any(), f"no damping command after the fault; the client said:\n{proc.stderr}"
    # within 50 ms of the last state (+ two emulator ticks)
    # a failure says how long the client itself saw no state when it tripped (a CI run once damped 62 ms after
    # the fault by the emulator's rows, the emulator 156 ticks overrun, and did not say)
    said = re.search(r"no valid robot state for (\d+) ms", errors[0])
    assert t[after][0] - t_loss <= DAMP_WITHIN, (f"damped {t[after][0] - t_loss:.3f} s after the fault; the client "
                                                 f"tripped {said.group(1) if said else '?'} ms after its last state"
                                                 f"\n{emu.summary}")
    assert damped(mode, kp, kd)[valid & (t > t[after][0])].all()  # and damping from then on
    traj = read_log(str(out))  # the recording is closed and readable
    assert traj.duration > 1.0


def test_a_fall_ends_in_damping_and_a_non_zero_exit(emulator, tmp_path):
    """The motors' power cut 3.5 s after the first command (``motor-loss``): the robot folds to the floor. The
    client reports the fall as its failure, with a non-zero exit (a run that broke the robot once ended with
    status 0 and only ``"fell": true`` in its JSON), damps it, and keeps the recording."""
    emu, proc, out = run_unless_stalled(emulator, tmp_path, ("--fault", "motor-loss@3.5"),
                                        ("--arm", "--duration", "12"), patient_client=True)
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(errors) == 1 and "robot fell at t = " in errors[0] and "damped" in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr
    metrics = json.loads(proc.stdout)
    assert metrics["fell"] is True and metrics["success"] is False and metrics["reason"].startswith("robot fell")
    t, valid, mode, q, kp, kd = emu.rows()
    t_cut = first_valid_time(t, valid) + 3.5
    assert (valid & (t < t_cut) & (mode == SERVO).all(axis=1)).sum() > 500  # it stood and walked before
    after = valid & (t > t_cut) & damped(mode, kp, kd)
    assert after.any() and damped(mode, kp, kd)[valid & (t > t[after][0])].all()  # damping, and only that
    assert t[valid][-1] - t_cut < 4.0  # seen and ended within seconds, not at the run's 12 s
    assert read_log(str(out)).duration > 1.0  # the recording (from the stand, after the ramp) closed and readable


def test_a_frozen_mocap_stops_the_push_and_holds_the_stand(emulator, tmp_path):
    # Only a run that the emulator's own stall ended before the freeze is tried again (run_unless_stalled).
    emu, proc, out = run_unless_stalled(emulator, tmp_path, ("--fault", "mocap-freeze@4.5"),
                                        ("--arm", "--duration", "5", "-q"), patient_client=True)
    assert "motion capture stale: holding the stand" in proc.stderr
    t, valid, mode, q, kp, kd = emu.rows()
    t_freeze = first_valid_time(t, valid) + 4.5
    # the stand from 0.2 s after the freeze: the 100 ms mocap timeout, a pose period, the emulator's catch-up
    # (at most 20 ms) and the relay's scheduling on a loaded 2-core machine (the suite's CI once saw the
    # first 4 ms past 0.15 s still carry the push, on a day the machine ran the suite 1.7x slower) -- plus
    # the emulator's own longest stall, which holds up its clock and the client's view alike (CI once saw the
    # push 0.202 s after the freeze in a run whose emulator stalled 52 ms)
    held = valid & (t > t_freeze + 0.2 + emu.longest_gap()) & (mode == SERVO).all(axis=1)
    assert held.sum() > 50
    off = np.abs(q[held] - STAND_JOINTS).max(axis=1)
    worst = int(np.argmax(off))  # where and when, for a failure on a loaded machine (CI saw 0.050 rad once)
    assert off[worst] < 0.02, (f"{off[worst]:.3f} rad off the stand {t[held][worst] - t_freeze:.3f} s after the "
                               f"freeze ({int((off >= 0.02).sum())} of {off.size} held commands); {emu.summary}")
    assert read_log(str(out)).duration > 1.0


def test_ctrl_c_damps_and_keeps_the_recording(emulator, tmp_path):
    # As above: a busy machine can stall the emulator past the client's state watchdog, and the client then
    # rightly damps and ends before it can be interrupted. Only such a run, told by the emulator's own
    # longest state gap, is tried again.
    for emu, where in stall_retries(emulator, tmp_path):
        out = where / "go1.mcap"
        proc = subprocess.Popen(AMHE + ["run", "--task", "t1", "--target", "go1", *emu.client_args(), "--mode",
                                        "baseline", "--threads", "1", "--out", str(out), "--arm", "--duration", "20",
                                        "-q", *patient(where)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if wait_for_servo(emu, 4.0, proc):  # past the start-up and the 2 s ramp: the planner has run for 2 s
            break
        _, err = proc.communicate(timeout=30)
        emu.stop()
        assert "no valid robot state" in err, f"the run ended before it could be interrupted:\n{err}"
        assert_stalled(emu, "the run ended before it could be interrupted", err)
    t_int = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    emu.stop()
    t, valid, mode, q, kp, kd = emu.rows()
    assert (mode[valid] == SERVO).all(axis=1).any()
    assert damped(mode, kp, kd)[valid][-20:].all()  # the damping burst is the last thing the robot heard
    assert time.monotonic() - t_int < 30
    rec = read_log(str(out))
    assert rec.duration > 1.0
    # the robot's tauEst is kept as the joint efforts, as a log of these streams holds them
    assert rec.joint_effort is not None and np.abs(rec.joint_effort).max() > 1.0


def test_dry_run_sends_damping_only_and_records_the_plan(emulator, tmp_path):
    emu = emulator()
    # not a watchdog test: a busy CI host once stalled the emulator 47 ms, past the 40 ms default (link lost)
    proc, out = run_client(emu, tmp_path, "--dry-run", "--duration", "2", *patient(tmp_path))
    emu.stop()
    assert proc.returncode == 0, proc.stderr
    t, valid, mode, q, kp, kd = emu.rows()
    assert valid.sum() > 500 and damped(mode, kp, kd)[valid].all()
    traj = read_log(str(out))
    assert traj.duration > 1.5
    # what it would have sent: the planner's targets (inside the SDK limits, replanned), not the damping zeros
    from amhe_cli.plants.go1.safety import SDK_JOINT_LOWER, SDK_JOINT_UPPER
    assert ((traj.ctrl >= SDK_JOINT_LOWER - 1e-6) & (traj.ctrl <= SDK_JOINT_UPPER + 1e-6)).all()
    assert (traj.ctrl[:, 2::3] < -0.8).all() and np.ptp(traj.ctrl, axis=0).max() > 0.01


def test_the_online_mhe_never_holds_up_the_planner(emulator, tmp_path):
    # The MHE's first window of noisy motion capture (the emulator's default: 1 mm, 0.2°) once imported
    # scipy.signal in the control loop, 1 s into the run: on 2 cores the planner stopped for 1.0 s and the
    # relay soft-held the walking robot (3 of 3 T1 runs then tipped past the fall reflex's 17°).
    # Only a run that the emulator's own stall ended (its state stream past the watchdog) is tried again.
    emu, proc, out = run_unless_stalled(emulator, tmp_path, (), ("--mode", "adaptive", "--dry-run", "--duration", "3"))
    assert proc.returncode == 0, proc.stderr
    assert "soft hold" not in proc.stderr, proc.stderr
    # nor is the start-up wait for the first poses reported as a stale motion capture once the run runs (that
    # bug said so at t = 0.1-0.8 s of every run). An early report stands where the stream did fall silent for
    # most of the poses' age: the emulated world ran slow (the emulator's longest pose gap: starved, it still
    # streams states within the watchdog), or the relay's own ticks paused as long (the machine stalled, the
    # emulator with it). One more is known and not yet explained (docs/evaluation.md, stop 81): CI saw, in two
    # runs of three, one verdict at t = 0.08-0.09 s, "newest poses 0.11 s … old", with the emulator's poses never
    # more than 10.2 ms apart, no relay pause, none unread, and "fresh again" on the next tick; one such
    # single-tick verdict is let pass (the stand held for a tick, the safe side), a second or a longer one is not
    lines = proc.stderr.splitlines()
    again = [float(g.group(1)) for g in (re.search(r"t=([0-9.]+) s: motion capture fresh again", ln) for ln in lines)
             if g]
    single = 0
    for line in lines:
        said = re.search(r"t=([0-9.]+) s: motion capture stale", line)
        if said and float(said.group(1)) < 1.0:
            m = re.search(r"newest poses ([0-9.]+) s \(trunk\) and ([0-9.]+) s \(box\) old", line)
            assert m, proc.stderr
            paused = re.search(r", ([0-9]+) ms after the relay's tick before", line)
            silent = max(emu.longest_pose_gap(), float(paused.group(1)) / 1e3 if paused else 0.0)
            if silent >= 0.5 * min(map(float, m.group(1, 2))):
                continue
            single += 1
            assert single == 1 and any(0 <= t - float(said.group(1)) <= 0.02 for t in again), \
                f"{proc.stderr}\n{emu.summary}"
    t, _, _ = read_float_arrays(str(out), "/amhe/planner")  # one message per planner cycle
    assert t[-1] > 2.5  # past the MHE's first windows (due from t = 1 s)
    gaps = np.diff(t)
    assert gaps.max() < 0.5, f"the planner paused {gaps.max():.2f} s at t = {t[np.argmax(gaps)]:.2f} s"


def test_no_robot_is_a_one_line_error(tmp_path):
    proc = subprocess.run(AMHE + ["run", "--target", "go1", "--robot", f"127.0.0.1:{free_port()}", "--local-port", "0",
                                  "--mocap", f"udp:127.0.0.1:{free_port()}", "--out", str(tmp_path / "x.mcap")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(errors) == 1 and "no valid LowState from 127.0.0.1" in errors[0]
    assert not (tmp_path / "x.mcap").exists()


def test_late_motion_capture_is_measured_against_the_imu_and_said(emulator, tmp_path):
    """The emulator's poses 25 ms late: the client reads that lateness from the trunk's attitude (IMU against
    motion capture) while it walks, says it in the run's log and keeps it with the recording (as measured),
    whose poses (as the MHE's window) it dates that much earlier. The emulated robot's motors give 85 % of
    the commanded torque: the run reads that from its own joint efforts while it walks (``robot_read``, from
    t = 5 s), says it once, and plans for that robot from then on (the end-of-run check, against the robot
    as read, then adds at most the servo the whole recording reads, where the read mid-run was off)."""
    emu, proc, out = run_unless_stalled(emulator, tmp_path, ("--pose-latency", "0.025", "--motor-strength", "0.85"),
                                        ("--arm", "--duration", "8"), patient_client=True)
    assert proc.returncode == 0, proc.stderr
    said = [float(m.group(1)) for m in re.finditer(r"motion capture arrives ([0-9.]+) ms late", proc.stderr)]
    assert said, proc.stderr
    # 25 ms is the emulator's floor: on loaded cores its pose thread runs late too (CI once read 31.2 ms, with
    # "motion capture stale" lines), and the relay's 2 ms tick can date the IMU a little late
    assert 21.0 <= said[-1] <= 45.0, proc.stderr
    told = [ln for ln in proc.stderr.splitlines() if "not the one the planner modelled" in ln]
    # the read mid-run, thinned on a thread beside the planner: on a loaded machine a first read scatters by a few
    # hundredths (robot_side.READ_SPREAD's measurements; CI once read 0.89 here), so it need only name the weaker
    # servo; the end-of-run check, over the whole recording, may add motors that plateaued after it, and names
    # the servo again only where the read missed it, then at what the motors give
    assert re.search(r"t=[5-7]\.[0-9]+ s: .*read the servo at 0\.(8[3-9]|90) ×", told[0]), proc.stderr
    assert "the planner models it so from now on" in told[0], proc.stderr  # Baseline: no MHE to tell
    assert len(told) <= 2, proc.stderr
    again = [ln for ln in told[1:] if "its servo gave" in ln]
    assert all(re.search(r"its servo gave 0\.8[3-7] ×", ln) for ln in again), proc.stderr
    from mcap.reader import make_reader
    with open(out, "rb") as fh:
        run_meta = next(m.metadata for m in make_reader(fh).iter_metadata() if m.name == "amhe_run")
    assert 0.021 <= float(run_meta["mocap_latency"]) <= 0.045 and run_meta["mocap_latency_source"] == "measured"
    # so identify keeps that dating rather than shifting the poses again by what the stance feet read
    from amhe_cli.estimation.problem import run_dated_poses
    assert run_dated_poses(read_log(str(out))) == pytest.approx(float(run_meta["mocap_latency"]))


def test_a_bad_mocap_latency_is_a_one_line_error_before_any_link(tmp_path):
    cfg = tmp_path / "late.yaml"
    cfg.write_text("mocap_latency: 12 ms\n")
    proc = subprocess.run(AMHE + ["run", "--target", "go1", "--robot", f"127.0.0.1:{free_port()}", "--local-port", "0",
                                  "--mocap", f"udp:127.0.0.1:{free_port()}", "--config", str(cfg),
                                  "--out", str(tmp_path / "x.mcap")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(errors) == 1 and "mocap_latency '12 ms'" in errors[0] and "auto" in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.mcap").exists()


def test_decisions_on_a_missing_gpu_are_a_one_line_error_before_the_robot_gets_a_packet(tmp_path):
    """``mhe: {attribute: true, attribute_device: cuda}`` where no CUDA device (or no GPU package) is: refused before
    the link opens — not after the robot has stood up, as when the MHE was made inside the run."""
    from amhe_cli.model.device import cuda_device
    if cuda_device() is not None:
        pytest.skip("this machine has a CUDA device: the decisions would load")
    cfg = tmp_path / "gpu.yaml"
    cfg.write_text("mhe: {attribute: true, attribute_device: cuda}\n")
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.bind(("127.0.0.1", 0))
    robot.settimeout(0.5)
    try:
        proc = subprocess.run(AMHE + ["run", "--target", "go1", "--robot", f"127.0.0.1:{robot.getsockname()[1]}",
                                      "--local-port", "0", "--mocap", f"udp:127.0.0.1:{free_port()}", "--mode",
                                      "adaptive", "--config", str(cfg), "--out", str(tmp_path / "x.mcap")],
                              capture_output=True, text=True, timeout=120)
        with pytest.raises(socket.timeout):
            robot.recvfrom(2048)  # nothing was ever sent to the robot
    finally:
        robot.close()
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("amhe: error:")]
    assert len(errors) == 1 and "mhe attribute_device cuda" in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.mcap").exists()
