"""Go1 low-level protocol (legged_sdk 3.8) codec, CRC and UDP link; byte compatibility with the official wheel.

Everything here talks to 127.0.0.1 only; the robot's default address is checked by reading the constant.
"""

import errno
import inspect
import socket
import struct
import time

import numpy as np
import pytest

from amhe_cli.errors import AmheError
from amhe_cli.plants.go1 import protocol as P
from amhe_cli.plants.go1.link import LinkError, LowLevelLink, parse_address
from amhe_cli.plants.go1.protocol import (LOWCMD_SIZE, LOWSTATE_SIZE, MODE_DAMPING, MODE_SERVO, LowCmd, LowState,
                                          ProtocolError, crc32_core)

LOOPBACK = "127.0.0.1"


# --- an independent reference of the SDK's CRC: its bit loop, word by word, MSB first ---

def crc_bitwise(buf: bytes) -> int:
    crc = 0xFFFFFFFF
    for (word,) in struct.iter_unpack("<I", buf[:4 * (len(buf) // 4 - 1)]):
        for bit in range(31, -1, -1):
            top = crc >> 31
            crc = (crc << 1) & 0xFFFFFFFF
            if top ^ ((word >> bit) & 1):
                crc ^= 0x04C11DB7
    return crc


def distinctive_cmd() -> LowCmd:
    """Values that are not multiples of the wire steps, of both signs, both modes."""
    j = np.arange(12)
    return LowCmd(mode=np.where(j % 3 == 2, MODE_DAMPING, MODE_SERVO).astype(np.uint8),
                  q=0.1 * j - 0.37, dq=-0.5 + 0.113 * j, tau=-3.3 + 0.7137 * j,
                  kp=20.3 + 1.71 * j, kd=0.55 + 0.307 * j)


def distinctive_state(seed=0) -> LowState:
    rng = np.random.default_rng(seed)
    quat = rng.normal(size=4)
    return LowState(quaternion=quat / np.linalg.norm(quat), gyroscope=rng.normal(size=3),
                    accelerometer=rng.normal(size=3) + [0, 0, 9.81], rpy=rng.normal(size=3),
                    imu_temperature=-7, motor_mode=np.arange(12) % 2 * MODE_SERVO,
                    q=rng.uniform(-2, 2, 12), dq=rng.normal(size=12), ddq=rng.integers(-3000, 3000, 12),
                    tau_est=rng.uniform(-30, 30, 12), motor_temperature=rng.integers(20, 80, 12),
                    foot_force=rng.integers(-50, 900, 4), foot_force_est=rng.integers(-50, 900, 4),
                    tick=3_000_000_123, battery_soc=87, wireless_remote=bytes(range(40)))


# --- CRC ---

@pytest.mark.parametrize("size", [LOWCMD_SIZE, LOWSTATE_SIZE, 8, 13, 4])
def test_crc_matches_bitwise_reference(size):
    rng = np.random.default_rng(size)
    for _ in range(3):
        buf = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
        assert crc32_core(buf) == crc_bitwise(buf)
    assert crc32_core(bytes(size)) == crc_bitwise(bytes(size))


def test_crc_ignores_the_crc_slot_and_uncovered_tail():
    buf = bytearray(np.random.default_rng(1).integers(0, 256, LOWSTATE_SIZE, dtype=np.uint8).tobytes())
    before = crc32_core(bytes(buf))
    buf[800:807] = b"\x00" * 7            # words 0..199 cover bytes 0..799 only
    assert crc32_core(bytes(buf)) == before
    buf[799] ^= 0x01
    assert crc32_core(bytes(buf)) != before


def test_crc_too_short():
    with pytest.raises(ProtocolError, match="too short"):
        crc32_core(b"\xfe\xef\x00")


def test_init_cmd_data_golden_packet():
    """The wheel's InitCmdData packet, captured from unitree-legged-sdk 3.8.20231105: CRC 0x347ff0e2."""
    slot = bytes.fromhex("0ab9d2ff4e00007a46") + bytes(18)          # servo, PosStopF, VelStopF, zeros
    golden = bytes.fromhex("feefff00") + bytes(18) + slot * 20 + bytes(48) + bytes.fromhex("e2f07f34")
    assert len(golden) == LOWCMD_SIZE
    cmd = LowCmd(mode=np.full(12, MODE_SERVO), q=np.full(12, P.POS_STOP_F), dq=np.full(12, P.VEL_STOP_F),
                 tau=np.zeros(12), kp=np.zeros(12), kd=np.zeros(12))
    assert cmd.encode() == golden
    assert crc_bitwise(golden) == 0x347FF0E2


# --- LowCmd ---

def test_lowcmd_layout_and_quantisation():
    cmd = distinctive_cmd()
    buf = cmd.encode()
    assert len(buf) == LOWCMD_SIZE and buf[:4] == b"\xfe\xef\xff\x00"
    for j in range(12):
        mode, q, dq, tau, kp, kd = struct.unpack_from("<BffhHH", buf, 22 + 27 * j)
        assert mode == cmd.mode[j]
        assert q == np.float32(cmd.q[j]) and dq == np.float32(cmd.dq[j])
        # C casts: float32, scaled, truncated toward zero (int() truncates the same way)
        assert tau == int(float(np.float32(cmd.tau[j])) * 256)
        assert kp == int(float(np.float32(cmd.kp[j])) * 32) and kd == int(float(np.float32(cmd.kd[j])) * 16)
    assert struct.unpack_from("<h", buf, 22 + 9)[0] == -844           # -3.3 N·m -> -844.8 -> -844
    assert int.from_bytes(buf[-4:], "little") == crc_bitwise(buf)


def test_lowcmd_round_trip_within_quantisation():
    rng = np.random.default_rng(3)
    cmd = LowCmd(mode=rng.choice([MODE_SERVO, MODE_DAMPING], 12), q=rng.uniform(-3, 3, 12),
                 dq=rng.normal(size=12), tau=rng.uniform(-127, 127, 12), kp=rng.uniform(0, 2000, 12),
                 kd=rng.uniform(0, 4000, 12), level=0xFF)
    back = LowCmd.decode(cmd.encode())
    np.testing.assert_array_equal(back.mode, cmd.mode)
    np.testing.assert_array_equal(back.q, cmd.q.astype(np.float32))
    np.testing.assert_array_equal(back.dq, cmd.dq.astype(np.float32))
    for name, step in (("tau", 1 / 256), ("kp", 1 / 32), ("kd", 1 / 16)):
        err = getattr(back, name) - getattr(cmd, name)
        assert np.all(np.abs(err) < step + 1e-5), name
    assert back.level == 0xFF
    assert back.encode() == cmd.encode()                                  # quantised values are exact


def test_lowcmd_damping():
    cmd = LowCmd.damping(kd=2.5)
    buf = cmd.encode()
    for j in range(12):
        assert struct.unpack_from("<BffhHH", buf, 22 + 27 * j) == (MODE_DAMPING, 0.0, 0.0, 0, 0, 40)
    assert LowCmd.damping().kd[0] == P.DAMPING_KD


@pytest.mark.parametrize("change, match", [
    (dict(tau=np.full(12, 200.0)), r"tau\[0\] = 200 N·m is out of the wire's range \[-128, 128\)"),
    (dict(tau=np.full(12, -128.01)), r"tau\[0\]"),
    (dict(kp=np.r_[np.zeros(11), -1.0]), r"kp\[11\] = -1 is negative"),
    (dict(kp=np.full(12, 2048.0)), r"kp\[0\]"),
    (dict(kd=np.full(12, 4096.0)), r"kd\[0\]"),
    (dict(q=np.r_[0.0, np.nan, np.zeros(10)]), r"q\[1\] = nan"),
    (dict(dq=np.full(12, 1e39)), r"dq\[0\]"),
    (dict(mode=np.full(12, 7)), r"mode\[0\] = 0x07"),
    (dict(level=300), r"level"),
])
def test_lowcmd_encode_rejects_what_the_wire_cannot_carry(change, match):
    fields = dict(mode=np.full(12, MODE_SERVO), q=np.zeros(12), dq=np.zeros(12), tau=np.zeros(12),
                  kp=np.zeros(12), kd=np.zeros(12))
    fields.update(change)
    with pytest.raises(ProtocolError, match=match):
        LowCmd(**fields).encode()


def test_lowcmd_rejects_wrong_shapes():
    with pytest.raises(AmheError, match=r"LowCmd.q has shape \(11,\), expected \(12,\)"):
        LowCmd(mode=np.zeros(12), q=np.zeros(11), dq=np.zeros(12), tau=np.zeros(12), kp=np.zeros(12),
               kd=np.zeros(12))
    with pytest.raises(AmheError, match="mode must hold whole numbers"):
        LowCmd(mode=np.full(12, 0.5), q=np.zeros(12), dq=np.zeros(12), tau=np.zeros(12), kp=np.zeros(12),
               kd=np.zeros(12))


# --- LowState ---

def test_lowstate_layout():
    st = distinctive_state()
    buf = st.encode()
    assert len(buf) == LOWSTATE_SIZE and buf[:3] == b"\xfe\xef\xff"
    np.testing.assert_array_equal(struct.unpack_from("<4f", buf, 22), st.quaternion.astype(np.float32))
    assert struct.unpack_from("<b", buf, 74)[0] == -7
    for j in range(12):
        mode, q, dq, ddq, tau = struct.unpack_from("<Bffhh", buf, 75 + 32 * j)
        assert (mode, q, ddq) == (st.motor_mode[j], np.float32(st.q[j]), st.ddq[j])
        assert tau == int(float(np.float32(st.tau_est[j])) * 256)
        assert struct.unpack_from("<b", buf, 75 + 32 * j + 23)[0] == st.motor_temperature[j]
    assert buf[718] == 87                                                      # BMS SOC
    assert struct.unpack_from("<4h4hI", buf, 739) == (*st.foot_force.astype(int), *st.foot_force_est.astype(int),
                                                       3_000_000_123)
    assert buf[759:799] == bytes(range(40))
    assert int.from_bytes(buf[-4:], "little") == crc_bitwise(buf)


def test_lowstate_round_trip():
    st = distinctive_state(5)
    back = LowState.decode(st.encode())
    for name in ("quaternion", "gyroscope", "accelerometer", "rpy", "q", "dq"):
        np.testing.assert_array_equal(getattr(back, name), getattr(st, name).astype(np.float32), err_msg=name)
    for name in ("motor_mode", "ddq", "motor_temperature", "foot_force", "foot_force_est"):
        np.testing.assert_array_equal(getattr(back, name), getattr(st, name), err_msg=name)
    assert np.all(np.abs(back.tau_est - st.tau_est) < 1 / 256)
    assert (back.imu_temperature, back.tick, back.level, back.battery_soc, back.wireless_remote) == \
        (-7, 3_000_000_123, 0xFF, 87, bytes(range(40)))
    assert back.encode() == st.encode()


def test_lowstate_zeros():
    st = LowState.decode(LowState.zeros().encode())
    assert st.quaternion.tolist() == [1, 0, 0, 0] and st.tick == 0 and not st.q.any()


@pytest.mark.parametrize("field, value, match", [
    ("tick", -1, r"LowState.tick = -1 is out of the wire's range \[0, 4294967295\]"), ("tick", 2**32, "tick"),
    ("imu_temperature", 130, "imu_temperature"),
    ("tau_est", np.full(12, 130.0), r"tau_est\[0\] = 130 N·m"), ("foot_force", np.full(4, 40000), "foot_force"),
    ("gyroscope", np.array([0, np.inf, 0]), r"gyroscope\[1\] = inf"),
])
def test_lowstate_encode_rejects_what_the_wire_cannot_carry(field, value, match):
    st = LowState.zeros()
    setattr(st, field, value)
    with pytest.raises(ProtocolError, match=match):
        st.encode()


# --- decoding faults ---

@pytest.mark.parametrize("cls, size", [(LowCmd, LOWCMD_SIZE), (LowState, LOWSTATE_SIZE)])
def test_decode_faults(cls, size):
    good = (distinctive_cmd() if cls is LowCmd else distinctive_state()).encode()
    cls.decode(good)
    name = cls.__name__
    with pytest.raises(ProtocolError, match=f"{name} packet is {size - 1} bytes, expected {size}"):
        cls.decode(good[:-1])
    with pytest.raises(ProtocolError, match=f"{name} packet is {size + 1} bytes"):
        cls.decode(good + b"\x00")
    with pytest.raises(ProtocolError, match="header is fe ee, expected fe ef"):
        cls.decode(b"\xfe\xee" + good[2:])
    corrupt = bytearray(good)
    corrupt[100] ^= 0x10
    with pytest.raises(ProtocolError, match="CRC is 0x[0-9a-f]{8}, computed 0x[0-9a-f]{8}"):
        cls.decode(bytes(corrupt))
    with pytest.raises(ProtocolError, match="must be bytes"):
        cls.decode("not bytes")


# --- byte compatibility with the official wheel (both directions), loopback only ---

def _wheel_and_peer():
    """A wheel client ri.UDP(low level, free local port, 127.0.0.1, peer port) and the peer socket it talks to."""
    ri = pytest.importorskip("unitree_legged_sdk.robot_interface")
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind((LOOPBACK, 0))
    peer.settimeout(2.0)
    udp = ri.UDP(0xFF, 0, LOOPBACK, peer.getsockname()[1])
    return ri, udp, peer


def test_wheel_lowcmd_bytes_equal_encode():
    ri, udp, peer = _wheel_and_peer()
    with peer:
        ours = distinctive_cmd()
        cmd = ri.LowCmd()
        udp.InitCmdData(cmd)                                  # the official recipe: init, then set 12 motors
        for j in range(12):
            m = cmd.motorCmd[j]
            m.mode, m.q, m.dq = int(ours.mode[j]), float(ours.q[j]), float(ours.dq[j])
            m.tau, m.Kp, m.Kd = float(ours.tau[j]), float(ours.kp[j]), float(ours.kd[j])
        udp.SetSend(cmd)
        udp.Send()
        data, _ = peer.recvfrom(2048)
        assert len(data) == LOWCMD_SIZE
        assert data == ours.encode()
        assert LowCmd.decode(data).encode() == data


def _wheel_recv(udp, ri, deadline_s=2.0):
    """Poll the wheel's Recv until it reports something other than 'nothing' (-1)."""
    end = time.monotonic() + deadline_s
    while True:
        code = udp.Recv()
        if code != -1 or time.monotonic() > end:
            state = ri.LowState()
            udp.GetRecv(state)
            return code, state
        time.sleep(0.001)


def test_wheel_accepts_encoded_lowstate_and_rejects_bad_crc():
    ri, udp, peer = _wheel_and_peer()
    with peer:
        udp.SetSend(ri.LowCmd())
        udp.Send()                                            # learn the wheel's ephemeral port
        _, wheel_addr = peer.recvfrom(2048)
        ours = distinctive_state(7)
        peer.sendto(ours.encode(), wheel_addr)
        code, st = _wheel_recv(udp, ri)
        assert code == 0
        f32 = np.float32
        np.testing.assert_array_equal(np.array(st.imu.quaternion, f32), ours.quaternion.astype(f32))
        np.testing.assert_array_equal(np.array(st.imu.gyroscope, f32), ours.gyroscope.astype(f32))
        np.testing.assert_array_equal(np.array(st.imu.accelerometer, f32), ours.accelerometer.astype(f32))
        assert st.imu.temperature == ours.imu_temperature
        decoded = LowState.decode(ours.encode())
        for j in range(12):
            ms = st.motorState[j]
            assert (ms.mode, f32(ms.q), f32(ms.dq)) == (ours.motor_mode[j], f32(ours.q[j]), f32(ours.dq[j]))
            assert ms.tauEst == decoded.tau_est[j] and ms.ddq == ours.ddq[j]
            assert ms.temperature == ours.motor_temperature[j]
        assert list(st.footForce) == ours.foot_force.astype(int).tolist()
        assert list(st.footForceEst) == ours.foot_force_est.astype(int).tolist()
        assert st.tick == ours.tick and st.bms.SOC == 87 and list(st.wirelessRemote) == list(range(40))

        newer = distinctive_state(8)
        bad = bytearray(newer.encode())
        bad[300] ^= 0x01
        peer.sendto(bytes(bad), wheel_addr)
        code, st2 = _wheel_recv(udp, ri)
        assert code == -3                                     # the wheel's "bad CRC / length"
        assert st2.tick == ours.tick and st2.motorState[0].q == st.motorState[0].q


# --- the link ---

@pytest.fixture
def robot_and_link():
    robot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    robot.bind((LOOPBACK, 0))
    robot.settimeout(2.0)
    link = LowLevelLink(robot=robot.getsockname(), local_port=0, bind_host=LOOPBACK)
    yield robot, link
    link.close()
    robot.close()


def _state(tick):
    st = LowState.zeros()
    st.tick = tick
    return st.encode()


def test_link_round_trip(robot_and_link):
    robot, link = robot_and_link
    cmd = distinctive_cmd()
    link.send(cmd)
    data, client = robot.recvfrom(2048)
    assert data == cmd.encode() and client == link.local_address
    corrupt = bytearray(_state(2))
    corrupt[400] ^= 0xFF
    for packet in (_state(1), bytes(corrupt), _state(3), _state(4)[:-1], b"\xfe\xee" + _state(5)[2:]):
        robot.sendto(packet, client)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:   # right packet, wrong sender
        stranger.bind((LOOPBACK, 0))
        stranger.sendto(_state(9), client)
    st = link.recv(timeout=1.0)
    assert st is not None and st.tick == 3                # newest VALID one
    assert link.received == 2 and link.bad_packets == 4
    assert "expected the robot" in link.last_error
    assert link.recv() is None                            # drained
    robot.sendto(_state(6), client)
    robot.sendto(bytes(corrupt), client)                  # a newest packet that is bad does not hide a valid one
    assert link.recv(timeout=1.0).tick == 6
    assert link.bad_packets == 5 and "CRC" in link.last_error


def test_link_recv_waits_for_timeout(robot_and_link):
    _, link = robot_and_link
    t0 = time.monotonic()
    assert link.recv(timeout=0.05) is None
    assert time.monotonic() - t0 >= 0.05
    with pytest.raises(AmheError, match="timeout"):
        link.recv(timeout=-1)


def test_link_send_error_is_an_amhe_error(robot_and_link, monkeypatch):
    _, link = robot_and_link

    def unreachable(self, *args):
        raise OSError(errno.ENETUNREACH, "Network is unreachable")
    monkeypatch.setattr(socket.socket, "sendto", unreachable)
    with pytest.raises(LinkError, match="cannot send to robot 127.0.0.1:[0-9]+: Network is unreachable"):
        link.send(LowCmd.damping())
    monkeypatch.undo()
    link.close()
    with pytest.raises(LinkError, match="closed"):
        link.send(LowCmd.damping())


def test_link_bind_in_use_and_context_manager():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind((LOOPBACK, 0))
        with pytest.raises(LinkError, match=f"cannot bind local UDP port {taken.getsockname()[1]}"):
            LowLevelLink(robot=(LOOPBACK, 9), local_port=taken.getsockname()[1], bind_host=LOOPBACK)
    with LowLevelLink(robot=(LOOPBACK, 9), local_port=0, bind_host=LOOPBACK) as link:
        assert link.local_address[0] == LOOPBACK
    assert link.closed
    with pytest.raises(LinkError, match="port 70000"):
        LowLevelLink(robot=(LOOPBACK, 70000), local_port=0, bind_host=LOOPBACK)


def test_defaults_are_the_robot_address():
    assert P.ROBOT_ADDRESS == ("192.168.123.10", 8007) and P.LOCAL_PORT == 8080 and P.LEVEL_LOW == 0xFF
    defaults = inspect.signature(LowLevelLink).parameters
    assert defaults["robot"].default == P.ROBOT_ADDRESS and defaults["local_port"].default == 8080


@pytest.mark.parametrize("text, expected", [
    ("127.0.0.1:8007", ("127.0.0.1", 8007)), ("robot.local", ("robot.local", 8007)),
    (" 10.0.0.2:9000 ", ("10.0.0.2", 9000)),
])
def test_parse_address(text, expected):
    assert parse_address(text, 8007) == expected


@pytest.mark.parametrize("text, match", [
    ("", "no valid host"), (":8007", "no valid host"), ("host:port", "port 'port'"),
    ("host:0", "port 0"), ("host:65536", "port 65536"), ("::1", "IPv6"), ("a b:1", "no valid host"),
])
def test_parse_address_rejects(text, match):
    with pytest.raises(AmheError, match=match):
        parse_address(text, 8007)
