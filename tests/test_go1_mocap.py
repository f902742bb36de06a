"""Motion capture for the Go1 plant (amhe_cli/plants/go1/mocap.py, docs/pose_stream.md).

Every socket here is on 127.0.0.1 with an ephemeral port; nothing is sent anywhere else.
"""

from __future__ import annotations

import json
import math
import socket
import sys
import time

import numpy as np
import pytest

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import quat_rotate, quat_to_rotvec
from amhe_cli.plants.go1 import mocap
from amhe_cli.plants.go1.mocap import (
    POSE_STREAM_PORT, MotionCaptureSource, PoseSender, PoseStreamError, UdpPoseSource,
    decode_body_entry, decode_pose_datagram, encode_pose_datagram, open_pose_source, parse_pose_spec,
)

BODIES = ("Go1_body", "Box_body")
LOOPBACK = "127.0.0.1"
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def _until(predicate, timeout=2.0):
    """Poll ``predicate`` until true; fail the test after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail("condition not met in time")
        time.sleep(0.002)


@pytest.fixture
def source():
    with UdpPoseSource(0, host=LOOPBACK, bodies=BODIES) as src:
        yield src


@pytest.fixture
def raw(source):
    """A plain UDP socket aimed at ``source`` for hand-written datagrams."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield lambda data: sock.sendto(data if isinstance(data, bytes) else json.dumps(data).encode(), source.address)
    sock.close()


def _received(src, name="Go1_body", n=1):
    _until(lambda: src.stats[name]["received"] >= n)


def test_default_port_constant():
    assert POSE_STREAM_PORT == 9870
    assert parse_pose_spec("udp:9870") == ("udp", "0.0.0.0", 9870)


def test_encode_is_byte_exact_with_ros_quaternion_order():
    q_wxyz = [0.5, 0.1, 0.2, 0.3]
    data = encode_pose_datagram({"Go1_body": ([1, 2, 0.27], q_wxyz)}, 12.5)
    assert data == (b'{"v":1,"t":12.5,"bodies":{"Go1_body":'
                    b'{"pos":[1.0,2.0,0.27],"quat_xyzw":[0.1,0.2,0.3,0.5]}}}')
    stamp, bodies = decode_pose_datagram(data)
    assert stamp == 12.5
    with pytest.raises(PoseStreamError, match="not a unit quaternion"):
        decode_body_entry("Go1_body", bodies["Go1_body"])  # norm 0.62: rejected, not normalised
    with pytest.raises(AmheError, match="non-finite"):
        encode_pose_datagram({"Go1_body": ([np.nan, 0, 0], IDENTITY)}, 0.0)
    with pytest.raises(AmheError, match=r"pos \(3,\)"):
        encode_pose_datagram({"Go1_body": ([0, 0], IDENTITY)}, 0.0)


def test_round_trip_sender_to_source(source):
    yaw = math.radians(30)
    q = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])  # w, x, y, z
    with PoseSender(source.address) as tx:
        tx.send({"Go1_body": ([0.1, -0.2, 0.27], q), "Box_body": ([0.6, 0.0, 0.1], IDENTITY)}, stamp=100.25)
        _received(source, "Box_body")
        tx.send({"Go1_body": ([0.1, -0.2, 0.27], q)}, stamp=100.26)
        _until(lambda: source.stats["Go1_body"]["accepted"] == 2)
    s = source.latest("Go1_body")
    np.testing.assert_allclose(s.pos, [0.1, -0.2, 0.27])
    np.testing.assert_allclose(s.quat, q)
    np.testing.assert_allclose(quat_rotate(s.quat, [1.0, 0.0, 0.0]), [math.cos(yaw), math.sin(yaw), 0.0], atol=1e-12)
    assert (s.name, s.stamp, s.seq) == ("Go1_body", 100.26, 2)
    assert source.latest("Box_body").seq == 1
    assert not s.pos.flags.writeable and not s.quat.flags.writeable
    assert source.take_warnings() == []


def test_hand_written_ros_order_datagram(source, raw):
    # A ROS node's datagram: quaternion (x, y, z, w) for +90 deg about z.
    h = math.sqrt(0.5)
    raw({"v": 1, "t": 5.0, "bodies": {"Box_body": {"pos": [1, 2, 3], "quat_xyzw": [0, 0, h, h]}}})
    _received(source, "Box_body")
    s = source.latest("Box_body")
    np.testing.assert_allclose(s.quat, [h, 0, 0, h])
    np.testing.assert_allclose(quat_rotate(s.quat, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-12)


def test_latency_is_respected(source):
    with PoseSender(source.address, latency=0.08) as tx:
        t0 = time.monotonic()
        tx.send({"Go1_body": ([0, 0, 0.27], IDENTITY)}, stamp=1.0)
        assert tx.pending == 1 and tx.sent == 0
        time.sleep(0.03)
        tx.flush()
        time.sleep(0.01)
        assert source.latest("Go1_body") is None
        while source.latest("Go1_body") is None:
            tx.flush()
            time.sleep(0.002)
            assert time.monotonic() - t0 < 2.0
    assert source.latest("Go1_body").received >= t0 + 0.08


def test_stale_body_age_grows(source):
    with PoseSender(source.address) as tx:
        tx.send({"Go1_body": ([0, 0, 0.27], IDENTITY)}, stamp=1.0)
    _received(source)
    a0 = source.age("Go1_body")
    time.sleep(0.15)
    a1 = source.age("Go1_body")
    assert 0.14 <= a1 - a0 < 1.0
    s = source.latest("Go1_body")
    assert source.age("Go1_body", now=s.received + 1.0) == pytest.approx(1.0)
    assert source.age("Box_body") == math.inf
    with pytest.raises(AmheError, match="unknown rigid body 'Go1'"):
        source.age("Go1")
    with pytest.raises(AmheError, match="no pose of Box_body"):
        source.wait(timeout=0.05)


def _stream(tx, xs, t0=0.0, dt=0.01, name="Go1_body"):
    for k, x in enumerate(xs):
        tx.send({name: ([x, 0.0, 0.27], IDENTITY)}, stamp=round(t0 + k * dt, 6))


def test_jump_rejected_then_reacquired(source):
    with PoseSender(source.address) as tx:
        _stream(tx, [0.0] * 5)                        # stamps 0.00 .. 0.04 at x = 0
        # stamps 0.05 .. 0.30, 3 m away: 5 m/s x dt + 0.02 m allows 0.07 .. 1.32 m (3 m not before dt = 0.6 s)
        _stream(tx, [3.0] * 26, t0=0.05)
        _received(source, n=31)
        st = source.stats["Go1_body"]
        assert (st["accepted"], st["rejected_jumps"], st["reacquired"]) == (5, 26, 0)
        assert source.latest("Go1_body").pos[0] == 0.0 and source.latest("Go1_body").stamp == 0.04
        warns = source.take_warnings()
        assert len(warns) == 1 and "Go1_body: pose jump rejected: moved 3.000 m in 10.0 ms" in warns[0]
        _stream(tx, [3.0] * 30, t0=0.31)              # stamps 0.31 .. 0.60
        _received(source, n=61)
    st = source.stats["Go1_body"]
    assert st["reacquired"] == 1 and st["rejected_jumps"] == 50   # 0.05 .. 0.54 rejected, 0.55 re-acquires
    s = source.latest("Go1_body")
    assert s.pos[0] == 3.0 and s.stamp == 0.6 and s.seq == 5 + 1 + 5
    warns = source.take_warnings()
    assert len(warns) == 1 and warns[0].startswith("Go1_body: re-acquired at (3.000, 0.000, 0.270) m after 0.500 s of 50 consistent rejected samples")
    assert source.take_warnings() == []


def test_glitch_and_inconsistent_jumps_never_accepted(source):
    with PoseSender(source.address) as tx:
        _stream(tx, [0.0, 0.0, 2.0, 0.0, 0.0])        # one glitch at stamp 0.02
        _received(source, n=5)
        assert source.stats["Go1_body"]["rejected_jumps"] == 1
        assert source.latest("Go1_body").seq == 4
        assert len(source.take_warnings()) == 1
        # A tracker flipping between two wrong places 5 m off for 0.6 s: rejected throughout, never re-acquired.
        _stream(tx, [5.0, -5.0] * 30, t0=0.05)
        _received(source, n=65)
    st = source.stats["Go1_body"]
    assert st["rejected_jumps"] == 61 and st["reacquired"] == 0
    assert source.latest("Go1_body").pos[0] == 0.0


def test_out_of_order_and_duplicate_stamps_dropped(source):
    with PoseSender(source.address) as tx:
        for t, x in ((1.0, 0.0), (0.9, 0.01), (1.0, 0.02), (1.01, 0.03)):
            tx.send({"Go1_body": ([x, 0, 0.27], IDENTITY)}, stamp=t)
        _received(source, n=4)
    st = source.stats["Go1_body"]
    assert (st["accepted"], st["out_of_order"]) == (2, 2)
    assert source.latest("Go1_body").stamp == 1.01


def test_garbage_datagrams_and_bad_bodies_counted(source, raw):
    good = {"pos": [0, 0, 0.27], "quat_xyzw": [0, 0, 0, 1]}
    for junk in (b"\xff\xfe\x00", b"not json", b"[1, 2]", {"v": 2, "t": 1.0, "bodies": {}},
                 {"v": 1, "bodies": {}}, b'{"v":1,"t":NaN,"bodies":{}}', {"v": 1, "t": 1.0, "bodies": []}):
        raw(junk)
    for t, entry in enumerate(({"pos": [0, 0], "quat_xyzw": [0, 0, 0, 1]},
                               {"pos": [0, 0, 0.27]},
                               {"pos": [0, 0, 0.27], "quat_xyzw": [0, 0, 0, 2]},
                               "pose"), start=1):
        raw({"v": 1, "t": float(t), "bodies": {"Go1_body": entry}})
    raw(b'{"v":1,"t":5.0,"bodies":{"Go1_body":{"pos":[NaN,0,0],"quat_xyzw":[0,0,0,1]}}}')
    # Near-unit quaternion: normalised and accepted; an untracked body: ignored, reported once.
    raw({"v": 1, "t": 6.0, "bodies": {"Go1_body": {"pos": [0, 0, 0.27], "quat_xyzw": [0, 0, 0, 1.005]},
                                      "Go1": good}})
    raw({"v": 1, "t": 7.0, "bodies": {"Go1": good}})
    _until(lambda: source.stats["_bad"]["received"] == 14)
    st = source.stats
    assert st["_bad"]["bad"] == 7
    assert (st["Go1_body"]["bad"], st["Go1_body"]["accepted"]) == (5, 1)
    assert "Go1" not in st
    np.testing.assert_allclose(source.latest("Go1_body").quat, IDENTITY)
    warns = source.take_warnings()
    assert len(warns) == 7 + 5 + 1
    assert sum("not UTF-8 JSON" in w for w in warns) == 2
    assert any("version 2, expected" in w for w in warns)
    assert any('no "quat_xyzw" field' in w for w in warns)
    assert any("norm 2, expected 1" in w for w in warns)
    assert sum("rigid body 'Go1', not tracked" in w for w in warns) == 1


@pytest.mark.parametrize("spec", ["", "   ", "udp", "udp:", "udp:abc", "udp:70000", "udp:-1", "udp:::1:5",
                                  "tcp:9870", "optitrack", "optitrack:", "vicon:", "go1:1"])
def test_bad_specs(spec):
    with pytest.raises(AmheError) as err:
        open_pose_source(spec, BODIES)
    assert "\n" not in str(err.value) and spec.strip()[:4] in str(err.value)


def test_good_specs_parse_without_connecting():
    assert parse_pose_spec("udp:127.0.0.1:0") == ("udp", "127.0.0.1", 0)
    assert parse_pose_spec("OptiTrack:mocap-pc") == ("optitrack", "mocap-pc", None)
    assert parse_pose_spec("mock") == ("mock", "", None)
    with open_pose_source("udp:127.0.0.1:0", BODIES) as src:
        assert isinstance(src, UdpPoseSource) and src.address[0] == LOOPBACK and src.address[1] > 0
        with pytest.raises(AmheError, match=f"cannot listen for the pose stream on 127.0.0.1:{src.address[1]}"):
            UdpPoseSource(src.address[1], host=LOOPBACK)


def test_bad_arguments():
    with pytest.raises(AmheError, match="max_speed"):
        UdpPoseSource(0, host=LOOPBACK, max_speed=0.0)
    with pytest.raises(AmheError, match="port must be"):
        UdpPoseSource(70000, host=LOOPBACK)
    with pytest.raises(AmheError, match="target must be"):
        PoseSender((LOOPBACK, 0))
    with pytest.raises(AmheError, match="latency"):
        PoseSender((LOOPBACK, 9), latency=-0.1)
    with PoseSender((LOOPBACK, 9)) as tx:
        with pytest.raises(AmheError, match="pose of Go1_body"):
            tx.send({"Go1_body": [0, 0, 0]}, stamp=0.0)
        with pytest.raises(AmheError, match="stamp"):
            tx.send({"Go1_body": ([0, 0, 0], IDENTITY)}, stamp=float("inf"))


def test_close_stops_thread_and_forbids_restart():
    src = UdpPoseSource(0, host=LOOPBACK, bodies=BODIES)
    src.start()
    thread = src._thread
    src.close()
    assert not thread.is_alive()
    with pytest.raises(AmheError, match="closed"):
        src.start()


def test_a_datagram_the_reader_has_not_read_is_unread_until_it_is():
    # the plant's freshness verdict asks this before it calls a stream stale: a pose thread behind its socket
    src = UdpPoseSource(0, host=LOOPBACK, bodies=BODIES)
    try:
        assert not src.unread()
        with PoseSender(src.address) as tx:
            tx.send({"Go1_body": ([0, 0, 0.3], IDENTITY)}, stamp=1.0)
            _until(src.unread)  # arrived; the reader not started
            src.start()
            _received(src)
            _until(lambda: not src.unread())
    finally:
        src.close()
    assert not src.unread()  # closed: nothing to read


def test_sender_noise_has_the_requested_sigma():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)  # 300 datagrams in one burst
    rx.bind((LOOPBACK, 0))
    rx.settimeout(2.0)
    n = 300
    with PoseSender(rx.getsockname(), noise_pos=0.01, noise_rot=0.02, seed=3) as tx:
        for k in range(n):
            tx.send({"Go1_body": ([1.0, 2.0, 0.27], IDENTITY)}, stamp=float(k))
    pos, rot = [], []
    for _ in range(n):
        _, bodies = decode_pose_datagram(rx.recv(65535))
        p, q = decode_body_entry("Go1_body", bodies["Go1_body"])
        pos.append(p)
        rot.append(quat_to_rotvec(q))
    rx.close()
    err = np.array(pos) - [1.0, 2.0, 0.27]
    assert np.std(err, axis=0) == pytest.approx([0.01] * 3, rel=0.2)
    assert np.std(np.array(rot), axis=0) == pytest.approx([0.02] * 3, rel=0.2)


def test_missing_motioncapture_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "motioncapture", None)  # import fails as if not installed
    with pytest.raises(AmheError, match=r"install the mocap extra: pip install 'amhe\[mocap\]'"):
        open_pose_source("mock", BODIES)


def test_motioncapture_mock_backend():
    # libmotioncapture's mock: static rigid bodies at its frame rate, no network at all.
    pytest.importorskip("motioncapture")
    h = math.sqrt(0.5)
    with MotionCaptureSource("mock", f"Go1_body(1,2,3,{h},0,0,{h});Stray(0,0,0,1,0,0,0)",
                             bodies=("Go1_body",)) as src:
        first = src.wait(timeout=2.0)["Go1_body"]
        _until(lambda: src.latest("Go1_body").seq >= first.seq + 2)
        warns = src.take_warnings()
    s = src.latest("Go1_body")
    np.testing.assert_allclose(s.pos, [1, 2, 3], atol=1e-6)
    np.testing.assert_allclose(s.quat, [h, 0, 0, h], atol=1e-6)       # (w, x, y, z), read by component name
    np.testing.assert_allclose(quat_rotate(s.quat, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-6)
    assert s.stamp == s.received and s.stamp > first.stamp
    assert warns == ["mock motion capture carries rigid body 'Stray', not tracked (expected Go1_body): ignored"]
    with pytest.raises(AmheError, match="unknown motion capture kind"):
        MotionCaptureSource("phasespace", "host")
    assert mocap.MOCAP_KINDS[-1] == "mock"


# -- how late motion capture arrives (amhe_cli/plants/go1/latency.py) -----------------------------------------

def _trotting_attitude(t: np.ndarray, yaw_zero: float = 0.0, tilt: float = 0.0) -> np.ndarray:
    """(N, 4) w, x, y, z of a trunk rocking as a trot rocks it (1.35 Hz and harmonics, about a degree), turning
    at 0.3 rad/s; ``yaw_zero`` and ``tilt`` (a marker set's roll) are what a second sensor may add."""
    from scipy.spatial.transform import Rotation
    roll = np.radians(1.0) * np.sin(2 * np.pi * 1.35 * t) + np.radians(0.4) * np.sin(2 * np.pi * 2.7 * t + 1) + tilt
    pitch = np.radians(0.8) * np.sin(2 * np.pi * 2.7 * t + 0.3) + np.radians(0.3) * np.sin(2 * np.pi * 5.4 * t)
    xyzw = Rotation.from_euler("ZYX", np.stack([0.3 * t + yaw_zero, pitch, roll], axis=-1)).as_quat()
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)


def _feed(est, t_imu, q_imu, t_mocap, q_mocap):
    """Both streams into ``est`` in arrival order, updating as a planner would; returns ``est``."""
    events = sorted([(t, 0, i) for i, t in enumerate(t_imu)] + [(t, 1, i) for i, t in enumerate(t_mocap)])
    for t, which, i in events:
        if which:
            est.add_mocap(t, q_mocap[i])
        else:
            est.add_imu(t, q_imu[i])
        est.update(t)
    return est


@pytest.mark.parametrize("late", [0.003, 0.017, 0.045])
def test_mocap_latency_is_read_against_the_imu_through_noise_a_yaw_zero_and_tilted_markers(late):
    from amhe_cli.plants.go1.latency import MocapLatency
    rng = np.random.default_rng(3)
    t_imu, t_cap = np.arange(0, 10, 0.002), np.arange(0, 10, 1 / 120)
    q_cap = _trotting_attitude(t_cap, yaw_zero=1.0, tilt=np.radians(2))  # captured at t_cap, arrives `late` later
    noise = rng.normal(0, np.radians(0.2), (len(t_cap), 3))  # the emulator's default: 0.2° per axis
    from scipy.spatial.transform import Rotation
    noisy = Rotation.from_quat(np.roll(q_cap, -1, axis=1)) * Rotation.from_rotvec(noise)
    q_cap = np.roll(noisy.as_quat(), 1, axis=1)
    est = _feed(MocapLatency(), t_imu, _trotting_attitude(t_imu), t_cap + late, q_cap)
    assert len(est.estimates) >= 5
    assert est.latency == pytest.approx(late, abs=0.001)


def test_a_lateness_is_reported_only_once_its_spans_agree(monkeypatch):
    """The first span of a run (the slow ramp to the stand) timed the emulator's 3 ms as 31.1 and 80.0 ms; the
    median of the first two or three dated the MHE's poses 20–40 ms wrong. Now the median of the last five is
    taken once three of them agree within 3 ms, and kept until they agree again."""
    from amhe_cli.plants.go1.latency import MocapLatency
    est = MocapLatency()
    reads = iter([0.0311, 0.0056, 0.0050, 0.0050, 0.0052, 0.030, 0.031, 0.032, 0.0305])
    monkeypatch.setattr(est, "measure", lambda imu, moc: next(reads))
    got = [est.update(float(k)) for k in range(9)]
    assert got[:3] == [None, None, None]  # one good read beside the bad one is not yet agreement
    assert got[3] == pytest.approx(0.0053) and got[4] == pytest.approx(0.0052)
    assert got[5] == got[6] == pytest.approx(0.0052)  # new reads elsewhere: the agreed lateness stands ...
    # ... until three of the last five agree on the new one: a real change is taken
    assert got[7] == pytest.approx(0.030) and got[8] == pytest.approx(0.0305)


def test_a_lateness_beyond_the_range_is_not_read_as_its_end():
    """Poses 0.12 s late against a 0.08 s range: the best lag sits at the range's end, no minimum inside
    it, so no estimate (where the old code read 80 ms)."""
    from amhe_cli.plants.go1.latency import MocapLatency
    t_imu, t_cap = np.arange(0, 8, 0.002), np.arange(0, 8, 1 / 120)
    est = _feed(MocapLatency(), t_imu, _trotting_attitude(t_imu), t_cap + 0.12, _trotting_attitude(t_cap))
    assert est.latency is None and est.estimates == []
    near = _feed(MocapLatency(), t_imu, _trotting_attitude(t_imu), t_cap + 0.07, _trotting_attitude(t_cap))
    assert near.latency == pytest.approx(0.07, abs=0.001)  # inside the range it is read


def test_a_still_trunk_gives_no_latency_and_bad_settings_are_refused():
    from amhe_cli.plants.go1.latency import MocapLatency, parse_mocap_latency
    t = np.arange(0, 8, 0.002)
    still = np.tile(IDENTITY, (len(t), 1))
    est = _feed(MocapLatency(), t, still, t[::4] + 0.01, still[::4])
    assert est.latency is None and est.estimates == []  # nothing moved: no timing to read
    with pytest.raises(ValueError):
        MocapLatency(span=0.05, max_lag=0.08)
    assert parse_mocap_latency("auto") is None and parse_mocap_latency(None) is None
    assert parse_mocap_latency(0.012) == 0.012
    for bad in (-0.01, 0.9, "12 ms", True):
        with pytest.raises(AmheError, match="mocap_latency"):
            parse_mocap_latency(bad)
