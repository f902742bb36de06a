"""The Go1 emulator (amhe_cli/plants/go1/emulator.py, `amhe emulate go1`): everything on 127.0.0.1, ephemeral ports."""

from __future__ import annotations

import csv
import re
import select
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from amhe_cli.control.closed_loop import make_plant
from amhe_cli.control.tasks import get_task
from amhe_cli.errors import AmheError
from amhe_cli.model.scene import STAND_JOINTS
from amhe_cli.plants.go1.emulator import (DAMPING_MODE_KD, FAULT_KINDS, Fault, Go1Emulator, motor_torques,
                                          parse_fault)
from amhe_cli.plants.go1.link import LowLevelLink
from amhe_cli.plants.go1.mocap import UdpPoseSource, decode_pose_datagram
from amhe_cli.plants.go1.protocol import (LOWSTATE_SIZE, MODE_DAMPING, MODE_SERVO, POS_STOP_F, VEL_STOP_F, LowCmd,
                                          LowState, ProtocolError)
from amhe_cli.cli.emulate import parse_pose_noise, parse_robot

LOOP = "127.0.0.1"
LIMIT = np.tile([23.7, 23.7, 35.55], 4)
Z12 = np.zeros(12)


def servo(q=STAND_JOINTS, kp=100.0, kd=4.0) -> LowCmd:
    return LowCmd(mode=np.full(12, MODE_SERVO), q=np.asarray(q, float), dq=Z12, tau=Z12,
                  kp=np.full(12, kp), kd=np.full(12, kd))


def damping() -> LowCmd:
    return LowCmd(mode=np.full(12, MODE_DAMPING), q=Z12, dq=Z12, tau=Z12, kp=Z12, kd=Z12)


def emulator(**kw) -> Go1Emulator:
    task = get_task("t1")
    return Go1Emulator(make_plant(task, 100.0, 4.0), list(task.events), host=LOOP, port=0, **kw)


@pytest.fixture
def started():
    """``started(**kw)`` -> (a started emulator, a LowLevelLink client to it); both closed after the test."""
    made = []

    def start(**kw):
        emu = emulator(**kw)
        emu.start()
        link = LowLevelLink(robot=emu.address, local_port=0, bind_host=LOOP)
        made.append((emu, link))
        return emu, link
    yield start
    for emu, link in made:
        link.close()
        emu.stop()


def drive(link: LowLevelLink, cmd: LowCmd | bytes, seconds: float) -> list[LowState]:
    """Send ``cmd`` every 2 ms for ``seconds`` and collect the states that come back."""
    states = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if isinstance(cmd, bytes):
            link._sock.sendto(cmd, link.robot)
        else:
            link.send(cmd)
        st = link.recv(0.002)
        if st is not None:
            states.append(st)
    return states


# --- pure parts -------------------------------------------------------------------

def test_motor_torques_follow_the_go1_motor_law():
    q = np.linspace(-1, 1, 12)
    dq = np.linspace(2, -2, 12)
    cmd = LowCmd(mode=np.full(12, MODE_SERVO), q=q + 0.1, dq=np.full(12, 0.5), tau=np.full(12, 1.0),
                 kp=np.full(12, 20.0), kd=np.full(12, 2.0))
    np.testing.assert_allclose(motor_torques(cmd, q, dq, LIMIT), 20 * 0.1 + 2 * (0.5 - dq) + 1.0, atol=1e-9)
    # clipped at the Go1 limits, calf 35.55, hip/thigh 23.7
    big = LowCmd(mode=np.full(12, MODE_SERVO), q=q + 5, dq=Z12, tau=Z12, kp=np.full(12, 100.0), kd=Z12)
    np.testing.assert_allclose(motor_torques(big, q, Z12, LIMIT), LIMIT)
    # PosStopF / VelStopF switch their term off (the SDK's InitCmdData slots)
    stop = LowCmd(mode=np.full(12, MODE_SERVO), q=np.full(12, POS_STOP_F), dq=np.full(12, VEL_STOP_F), tau=Z12,
                  kp=np.full(12, 10.0), kd=np.full(12, 3.0))
    np.testing.assert_allclose(motor_torques(stop, q, dq, LIMIT), -3.0 * dq, atol=1e-9)
    # damping mode (and no command yet) ignores the command's fields
    mixed = LowCmd(mode=[MODE_DAMPING] * 6 + [MODE_SERVO] * 6, q=q, dq=Z12, tau=np.full(12, 3.0),
                   kp=np.full(12, 50.0), kd=Z12)
    tau = motor_torques(mixed, q, dq, LIMIT)
    np.testing.assert_allclose(tau[:6], -DAMPING_MODE_KD * dq[:6])
    np.testing.assert_allclose(tau[6:], 3.0, atol=1e-9)
    np.testing.assert_allclose(motor_torques(None, q, dq, LIMIT), -DAMPING_MODE_KD * dq)
    # weaker motors than the model's deliver a share of the law, and of its limits
    np.testing.assert_allclose(motor_torques(cmd, q, dq, LIMIT, 0.8), 0.8 * (20 * 0.1 + 2 * (0.5 - dq) + 1.0),
                               atol=1e-9)
    np.testing.assert_allclose(motor_torques(big, q, Z12, LIMIT, 0.8), 0.8 * LIMIT)


def test_a_robot_unlike_its_model_stands_lower_and_bad_robot_settings_are_refused():
    """``--robot trunk_payload=…`` and ``--motor-strength`` make the emulated Go1 heavier or weaker than the
    model amhe plans with: under the same stand command its trunk settles lower."""
    assert parse_robot("trunk_payload=1.5, robot_box_friction=0.8") == {"trunk_payload": 1.5,
                                                                        "robot_box_friction": 0.8}
    assert parse_robot(None) == {} and parse_robot("") == {}
    for bad in ("robot_kp=40", "trunk_payload", "trunk_payload=heavy", "trunk_payload=50", "box_mass=3"):
        with pytest.raises(AmheError, match="--robot"):
            parse_robot(bad)
    with pytest.raises(AmheError, match="motor strength"):
        emulator(motor_strength=0.0)

    def stand_height(payload=0.0, strength=1.0):
        task = get_task("t1")
        plant = make_plant(task, 100.0, 4.0)
        plant.set_param("trunk_payload", payload)
        emu = Go1Emulator(plant, [], host=LOOP, port=0, motor_strength=strength)
        try:
            emu._cmd = servo(kp=40.0, kd=2.0)
            for _ in range(750):  # 1.5 s
                emu._tick()
            return float(emu.data.qpos[plant.scene.base_qpos[2]])
        finally:
            emu.close()
    nominal = stand_height()
    assert stand_height(payload=3.0) < nominal - 0.003
    assert stand_height(strength=0.6) < nominal - 0.003


def test_parse_fault_and_pose_noise():
    assert parse_fault("link-loss@5") == Fault("link-loss", 5.0)
    assert [parse_fault(f"{k}@0.25").kind for k in FAULT_KINDS] == list(FAULT_KINDS)
    for bad in ("link-loss", "explode@1", "corrupt@-1", "corrupt@x", "mocap-drop@nan", "@3"):
        with pytest.raises(AmheError, match="--fault"):
            parse_fault(bad)
    assert parse_pose_noise("0.001,0.2deg") == pytest.approx((0.001, np.radians(0.2)))
    assert parse_pose_noise("0.002,0.01") == (0.002, 0.01)
    assert parse_pose_noise("0") == (0.0, 0.0)
    for bad in ("a,b", "-1,0", "1,2,3", "0.001,inf"):
        with pytest.raises(AmheError, match="--pose-noise"):
            parse_pose_noise(bad)


def test_record_refuses_to_overwrite(tmp_path):
    path = tmp_path / "rx.csv"
    path.write_text("keep me\n")
    with pytest.raises(AmheError, match="exists"):
        emulator(record=str(path))
    assert path.read_text() == "keep me\n"
    emulator(record=str(path), overwrite=True).close()
    assert path.read_text().startswith("t,valid,mode_0")


# --- the link -------------------------------------------------------------------------

def test_silent_until_a_valid_command_then_holds_a_commanded_pose(started):
    emu, link = started()
    assert link.recv(0.15) is None                       # no handshake: nothing before a command
    assert emu.stats.sent == 0 and emu.stats.ticks > 40  # ... though the plant runs
    ran_ms = emu.time * 1000.0                           # plant time before the first command
    target = STAND_JOINTS + np.tile([0.0, -0.15, 0.25], 4)   # a higher stance than the start
    states = drive(link, servo(target), 1.2)
    assert len(states) > 150
    st = states[-1]
    # kp 100 holds the pose to within its gravity sag (0.055 rad at the stand pose)
    assert np.abs(st.q - target).max() < 0.08
    assert np.abs(st.dq).max() < 0.05
    assert (st.motor_mode == MODE_SERVO).all()
    # tau_est is the PD torque actually applied, to the wire's 1/256 N·m
    np.testing.assert_allclose(st.tau_est, np.clip(100 * (target - st.q) - 4 * st.dq, -LIMIT, LIMIT), atol=0.05)
    # a standing robot: IMU level, accelerometer +g on z, feet carry the weight (12.7 kg)
    np.testing.assert_allclose(st.quaternion, [1, 0, 0, 0], atol=0.01)
    assert np.abs(st.rpy[:2]).max() < 0.02 and np.abs(st.gyroscope).max() < 0.05
    np.testing.assert_allclose(st.accelerometer, [0, 0, 9.81], atol=0.15)
    assert (st.foot_force > 15).all() and abs(st.foot_force.sum() - 12.7 * 9.81) < 15
    ticks = np.array([s.tick for s in states])
    # ms of plant time since start, not since the first command (the plant's clock, not the
    # wall's: under load it runs behind the wall, so the bound is what it had run before)
    assert (np.diff(ticks) > 0).all() and ticks[0] >= ran_ms > 80


def test_damping_torque_opposes_joint_velocity(started):
    emu, link = started()
    states = drive(link, damping(), 0.6)   # the robot folds down: joints move, motors brake
    moving = [(s.tau_est, s.dq) for s in states if np.abs(s.dq).max() > 0.2]
    assert len(moving) > 20
    tau, dq = map(np.array, zip(*moving))
    m = np.abs(dq) > 0.2
    assert (tau[m] * dq[m] < 0).all()
    # tau_est is the torque of the step that ended at this state (dq changes during it): the ratio is -Kd_damp
    assert np.median(tau[m] / dq[m]) == pytest.approx(-DAMPING_MODE_KD, rel=0.05)
    assert (states[-1].motor_mode == MODE_DAMPING).all()


def test_bad_packets_are_counted_not_applied_and_link_loss_stops_the_state(started):
    emu, link = started(faults=[Fault("link-loss", 0.2)])
    far = servo(STAND_JOINTS + 0.6).encode()
    bad_crc = far[:-4] + bytes(b ^ 0x5A for b in far[-4:])
    for pkt in (bad_crc, far[:-1], far + b"\0"):
        link._sock.sendto(pkt, link.robot)
    time.sleep(0.1)
    assert emu.stats.bad == 3 and emu.stats.valid == 0
    assert link.recv(0.05) is None                # a bad packet is no command: no client, no state
    states = drive(link, servo(), 0.5)            # valid: the stream starts, then the link dies at 0.2 s
    assert len(states) > 50
    span = states[-1].tick - states[0].tick
    assert 150 <= span <= 230, span
    assert drive(link, servo(), 0.15) == [] and emu.stats.ignored > 30
    # the bad packets were never applied: the joints still hold the stand pose, not stand + 0.6
    assert np.abs(states[-1].q - STAND_JOINTS).max() < 0.08


def test_longest_gap_is_the_emulators_own_stall_not_a_link_loss_fault():
    emu = emulator(faults=["link-loss@0.01"])
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind((LOOP, 0))
    try:
        wall = iter([0.0, 0.002, 0.004, 0.067, 0.069, 0.071, 0.5, 0.6])
        emu._clock = lambda: next(wall)
        emu._packet(servo().encode(), client.getsockname())  # a client: states go out
        for _ in range(5):
            emu._tick()                   # sent at 0, 2, 4 ms, held up 63 ms, then 69 ms
        assert emu.stats.sent == 5 and emu.stats.longest_gap == pytest.approx(0.063)
        for _ in range(4):
            emu._tick()                   # link-loss from 10 ms: the silence it makes is no gap
        assert emu.stats.sent == 5 and emu.stats.longest_gap == pytest.approx(0.063)
    finally:
        client.close()
        emu.close()


def test_longest_pose_gap_is_the_emulated_world_running_slow_from_the_first_command():
    """A starved emulator still streams states within the client's watchdog while its poses, at 120 Hz of its own
    time, fall silent past the client's ``mocap_timeout``: ``longest_pose_gap`` says so (from the first command)."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind((LOOP, 0))
    emu = emulator(pose_to=rx.getsockname())
    clock = [0.0]
    emu._clock = lambda: clock[0]
    try:
        for _ in range(40):              # no client yet: the world slow (25 ms a tick), no gap counted
            clock[0] += 0.025
            emu._tick()
        assert emu.stats.poses >= 9 and emu.stats.longest_pose_gap == 0.0
        emu._packet(servo().encode(), rx.getsockname())
        for _ in range(20):              # on time: a pose every 4-5 ticks of 2 ms
            clock[0] += 0.002
            emu._tick()
        assert emu.stats.longest_pose_gap == pytest.approx(0.010)
        for _ in range(20):              # 25 ms a tick: states 25 ms apart, poses 100-125 ms
            clock[0] += 0.025
            emu._tick()
        assert emu.stats.longest_gap == pytest.approx(0.025)
        assert emu.stats.longest_pose_gap == pytest.approx(0.125)
    finally:
        rx.close()
        emu.close()


class RefusingSocket:
    """The emulator's socket, whose sends raise while told to (a full send buffer on a loaded host)."""

    def __init__(self, sock):
        self.sock, self.refuse = sock, False

    def sendto(self, buf, addr):
        if self.refuse:
            raise BlockingIOError(11, "Resource temporarily unavailable")
        return self.sock.sendto(buf, addr)

    def __getattr__(self, name):
        return getattr(self.sock, name)


def test_a_state_the_socket_refused_is_not_counted_sent_and_its_silence_is_a_gap():
    emu = emulator()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind((LOOP, 0))
    real = emu.sock
    try:
        wall = iter([0.0, 0.002, 0.104, 0.106, 0.108])  # read at each state sent
        emu._clock = lambda: next(wall)
        emu._packet(servo().encode(), client.getsockname())
        emu.sock = RefusingSocket(real)
        for _ in range(2):
            emu._tick()                   # sent at 0 and 2 ms
        emu.sock.refuse = True
        for _ in range(50):
            emu._tick()                   # refused: nothing reaches the client
        emu.sock.refuse = False
        emu._tick()                       # sent again at 104 ms: the client heard nothing for 102 ms
        assert emu.stats.sent == 3 and emu.stats.send_failed == 50
        assert emu.stats.longest_gap == pytest.approx(0.102)
        for _ in range(2):
            emu._tick()
        assert emu.stats.sent == 5
    finally:
        emu.sock = real
        client.close()
        emu.close()


def test_corrupt_fault_sends_states_the_sdk_rejects(started):
    emu, link = started(faults=["corrupt@0.15"])
    sock = link._sock
    cmd = servo().encode()
    good = bad = 0
    end = time.monotonic() + 0.45
    while time.monotonic() < end:
        sock.sendto(cmd, link.robot)
        if select.select([sock], [], [], 0.002)[0]:
            buf, _ = sock.recvfrom(2048)
            assert len(buf) == LOWSTATE_SIZE
            try:
                LowState.decode(buf)
                assert bad == 0           # once corrupt, never good again
                good += 1
            except ProtocolError as e:
                assert "CRC" in str(e)
                bad += 1
    assert good > 30 and bad > 50
    assert emu.stats.valid > 100          # commands are still taken while states are corrupt


# --- poses ------------------------------------------------------------------------------

def test_poses_arrive_with_the_body_names():
    src = UdpPoseSource(0, host=LOOP, bodies=("Trunk", "Crate"))
    src.start()
    emu = emulator(pose_to=src.address, base_body="Trunk", box_body="Crate", pose_latency=0.003)
    emu.start()
    try:
        time.sleep(0.35)
        trunk, box = src.latest("Trunk"), src.latest("Crate")
        assert trunk is not None and box is not None
        assert 30 <= trunk.seq <= 50 and emu.stats.poses >= trunk.seq   # 120 Hz, before any command
        task = get_task("t1")
        np.testing.assert_allclose(box.pos[:2], task.box_start, atol=0.01)
        np.testing.assert_allclose(trunk.pos[:2], [0, 0], atol=0.05)   # no command: damping, sagging
        assert 0.15 < trunk.pos[2] < 0.3
        assert abs(trunk.quat[3]) < 0.01                               # still facing +x
    finally:
        emu.stop()
        src.close()


def _pose_stamps(seconds, **kw):
    """(arrival, stamp, Go1_body pos) of the raw pose datagrams while a client commands the emulator."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind((LOOP, 0))
    rx.setblocking(False)
    emu = emulator(pose_to=rx.getsockname(), **kw)
    emu.start()
    link = LowLevelLink(robot=emu.address, local_port=0, bind_host=LOOP)
    stamps, bodies = [], set()
    try:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            link.send(servo())
            link.recv(0.002)
            while True:
                try:
                    data, _ = rx.recvfrom(65535)
                except BlockingIOError:
                    break
                t, b = decode_pose_datagram(data)
                stamps.append((time.monotonic(), t, b["Go1_body"]["pos"]))
                bodies |= set(b)
    finally:
        link.close()
        emu.stop()
        rx.close()
    return stamps, bodies


def test_mocap_freeze_repeats_the_stamp_and_mocap_drop_stops_poses():
    stamps, bodies = _pose_stamps(0.5, faults=["mocap-freeze@0.2"], pose_noise=(0.001, 0.003))
    assert bodies == {"Go1_body", "Box_body"}
    t = np.array([s[1] for s in stamps])
    assert len(t) > 45
    frozen = np.flatnonzero(np.diff(t) == 0)
    assert len(frozen) > 10
    k = frozen[0]
    assert (np.diff(t[:k + 1]) > 0).all() and (t[k:] == t[k]).all()    # fresh, then one stamp forever
    pos = np.array([s[2] for s in stamps])
    assert (pos[k + 1:] == pos[k + 1]).all()                            # ... and one pose, noise frozen too
    assert (np.diff(pos[:k], axis=0) != 0).all()                       # (fresh noise before the freeze)
    stamps, _ = _pose_stamps(0.45, faults=["mocap-drop@0.1"])
    arrival = np.array([s[0] for s in stamps])
    assert len(arrival) > 10                                 # poses before the first command and until the fault
    assert arrival[-1] < arrival[0] + 0.32                   # nothing in the last ~0.15 s


def test_task_events_fire_on_the_emulated_plant():
    from amhe_cli.control.tasks import Event
    task = get_task("t1")
    plant = make_plant(task, 100.0, 4.0)
    events = [Event("box_mass", 6.5, t=0.1)]
    emu = Go1Emulator(plant, events, host=LOOP, port=0, task_delay=0.0)
    box = plant.scene.box_body
    before = float(emu.model.body_mass[box])
    emu._cmd = servo()  # a client servoing the motors: the task's clock runs
    emu.start()
    time.sleep(0.3)
    emu.stop()
    assert events == [] and before != 6.5
    assert emu.model.body_mass[box] == pytest.approx(6.5)       # the emulator's own model has it
    assert (emu.model.actuator_gainprm[:, 0] == 0).all()        # ... and still no position servos


def test_a_timed_event_counts_from_the_clients_task_start_and_is_announced():
    """T3's mass switch at 10 s is 10 s into the client's task (its first servo command, then its ramp), not
    10 s after the emulator started, which a client may join late; each firing calls on_event."""
    from amhe_cli.control.tasks import Event
    plant = make_plant(get_task("t1"), 100.0, 4.0)
    events, heard = [Event("box_mass", 6.5, t=0.02)], []
    emu = Go1Emulator(plant, events, host=LOOP, port=0, task_delay=0.01,
                      on_event=lambda t, ev, mono: heard.append((t, ev, mono)))
    try:
        for _ in range(20):  # 40 ms with no command, then damping: no task yet
            emu._tick()
        emu._cmd = damping()
        for _ in range(10):
            emu._tick()
        assert events and not heard
        emu._cmd = servo()
        start = float(emu.data.time)
        while events and emu.data.time < start + 1.0:
            emu._tick()
        (t, ev, mono), = heard
        assert ev.param == "box_mass" and t == pytest.approx(start + 0.01 + 0.02, abs=0.0021)
        assert abs(mono - time.monotonic()) < 5.0
    finally:
        emu.close()


# --- record ------------------------------------------------------------------------------

def test_record_has_a_row_per_packet(tmp_path):
    path = tmp_path / "rx.csv"
    emu = emulator(record=str(path))
    emu.start()
    link = LowLevelLink(robot=emu.address, local_port=0, bind_host=LOOP)
    target = STAND_JOINTS + 0.01
    try:
        cmd = servo(target, kp=60.0, kd=3.0)
        for i in range(20):
            link.send(cmd)
            if i % 5 == 4:
                link._sock.sendto(b"\xfe\xef" + bytes(100), link.robot)
            time.sleep(0.003)
        time.sleep(0.05)
        with open(path) as f:                  # readable while the emulator runs
            assert len(list(csv.reader(f))) == 25
    finally:
        link.close()
        emu.stop()
    with open(path) as f:
        rows = list(csv.reader(f))
    header = ["t", "valid"] + [f"{k}_{i}" for k in ("mode", "q", "kp", "kd") for i in range(12)]
    assert rows[0] == header
    body = np.array(rows[1:], dtype=float)
    assert body.shape == (24, 50)
    valid = body[:, 1] == 1
    assert valid.sum() == 20 == emu.stats.valid and (~valid).sum() == 4 == emu.stats.bad
    np.testing.assert_allclose(body[valid, 2:14], MODE_SERVO)
    np.testing.assert_allclose(body[valid, 14:26], np.tile(target, (20, 1)), atol=1e-6)
    np.testing.assert_allclose(body[valid, 26:38], 60.0)
    np.testing.assert_allclose(body[valid, 38:50], 3.0)
    assert (body[~valid, 2:] == 0).all()
    assert (np.diff(body[:, 0]) >= 0).all() and body[-1, 0] < 1.0


# --- the command line ---------------------------------------------------------------------

def test_cli_prints_the_bound_port_and_ends_cleanly(tmp_path):
    prog = "from amhe_cli.cli import main; main()"
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind((LOOP, 0))
    rx.settimeout(3.0)
    rec = tmp_path / "rx.csv"
    args = [sys.executable, "-c", prog, "emulate", "go1", "--task", "t1", "--port", "0",
            "--pose-to", f"{LOOP}:{rx.getsockname()[1]}", "--record", str(rec)]
    try:
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = proc.stdout.readline()
        m = re.fullmatch(r"amhe emulate go1: listening on udp://127\.0\.0\.1:(\d+), poses to "
                         rf"udp://127\.0\.0\.1:{rx.getsockname()[1]} \(Go1_body, Box_body\), task t1\n", line)
        assert m, line
        port = int(m.group(1))
        assert port != 0
        t, bodies = decode_pose_datagram(rx.recvfrom(65535)[0])
        assert set(bodies) == {"Go1_body", "Box_body"}
        link = LowLevelLink(robot=(LOOP, port), local_port=0, bind_host=LOOP)
        states = drive(link, servo(), 0.3)
        link.close()
        assert len(states) > 30
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        rx.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert out == ""
    assert re.search(r"packets valid \d+ bad 0 .*overruns \d+", err), err
    rows = rec.read_text().splitlines()
    assert rows[0].startswith("t,valid,mode_0") and len(rows) > 30


def test_cli_duration_and_bad_fault():
    from click.testing import CliRunner
    from amhe_cli.cli.emulate import emulate_cmd
    r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--pose-to", "off", "--duration", "0.2"])
    assert r.exit_code == 0, r.output
    assert re.match(r"amhe emulate go1: listening on udp://127\.0\.0\.1:[1-9]\d*, poses off, task t1", r.output)
    r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--fault", "melt@3"])
    assert isinstance(r.exception, AmheError) and "--fault 'melt@3'" in str(r.exception)
    r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--pose-to", "off", "--duration", "0.2",
                                         "--robot", "trunk_payload=1.5", "--motor-strength", "0.85"])
    assert r.exit_code == 0, r.output
    assert "robot unlike its model: trunk_payload 1.5, motor strength 0.85" in r.output
    r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--robot", "robot_kp=40"])
    assert isinstance(r.exception, AmheError) and "--robot 'robot_kp=40'" in str(r.exception)
    # a box unlike the task's: its truth from the start, said in the first line; a robot-side name is refused
    r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--pose-to", "off", "--duration", "0.2",
                                         "--box", "box_mass=5.5,box_friction=0.35"])
    assert r.exit_code == 0, r.output
    assert "box box_mass 5.5, box_friction 0.35" in r.output.splitlines()[0]
    for bad in ("trunk_payload=1", "box_mass=200", "box_friction=sticky"):
        r = CliRunner().invoke(emulate_cmd, ["go1", "--port", "0", "--box", bad])
        assert isinstance(r.exception, AmheError) and f"--box {bad!r}" in str(r.exception)
