"""The relay in a process of its own: a stalled planner's process keeps the robot's commands coming, and a
process that dies on either side ends in damping. The robot is a small one in a process of its own on 127.0.0.1:
it streams a standing LowState every 2 ms and notes when each command came and in which mode."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from amhe_cli.model.scene import STAND_JOINTS
from amhe_cli.plants.go1.link import LowLevelLink
from amhe_cli.plants.go1.protocol import MODE_DAMPING, MODE_SERVO
from amhe_cli.plants.go1.relay import Relay
from amhe_cli.plants.go1.relay_process import RelayProcess
from amhe_cli.plants.go1.safety import SafetyLayer, SafetySettings
from helpers import gil_hog

ROBOT = textwrap.dedent("""
    import json, select, socket, sys, time
    import numpy as np
    from amhe_cli.model.scene import STAND_JOINTS
    from amhe_cli.plants.go1.protocol import LowCmd, LowState
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    print(sock.getsockname()[1], flush=True)
    state = LowState.zeros()
    state.q[:] = STAND_JOINTS
    state.quaternion[:] = [1, 0, 0, 0]
    packet = state.encode()
    client, got, end = None, [], time.monotonic() + 30.0
    while time.monotonic() < end and not select.select([sys.stdin], [], [], 0)[0]:  # until stdin closes
        while True:
            try:
                data, client = sock.recvfrom(2048)
            except BlockingIOError:
                break
            got.append((time.monotonic(), int(LowCmd.decode(data).mode[0])))
        if client is not None:
            sock.sendto(packet, client)
        time.sleep(0.002)
    print(json.dumps(got), flush=True)
""")


class Robot:
    """The little robot above (at most 30 s); :meth:`commands` ends it and gives [(t, mode)] of what it got."""

    def __init__(self):
        self.proc = subprocess.Popen([sys.executable, "-c", ROBOT], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True)
        self.port = int(self.proc.stdout.readline())

    def commands(self) -> list[tuple[float, int]]:
        out = self.proc.communicate(input="", timeout=40)[0]
        return [tuple(c) for c in json.loads(out.strip().splitlines()[-1])]


def settings():
    return SafetySettings(ramp_time=0.1)


@contextlib.contextmanager
def standing(robot: Robot, kind: str = "process"):
    """A relay (``"process"`` or ``"thread"``) on ``robot``, ramped to the stand and following a 10 s plan of it;
    stopped and its link closed after."""
    link = LowLevelLink(("127.0.0.1", robot.port), 0)
    if kind == "process":
        relay = RelayProcess(link, settings(), 100, 4, planner_period=5.0)
    else:
        relay = Relay(link, SafetyLayer(settings()), 100, 4, planner_period=5.0)
    relay.start()
    try:
        assert relay.wait_ready(10.0), (relay.alive(), relay.take_messages())  # why not, where it was not
        relay.set_plan(np.tile(STAND_JOINTS, (1000, 1)), 0.01, time.monotonic())
        time.sleep(0.2)
        yield relay
    finally:
        relay.stop()
        link.close()


def longest_gap(commands, since: float, until: float) -> float:
    t = np.array([c[0] for c in commands if since <= c[0] <= until])
    return float(np.diff(t).max())


@pytest.mark.parametrize("kind", ["process", "thread"])
def test_a_stall_of_the_planners_process_leaves_the_robot_s_commands_coming_only_from_a_relay_process(kind):
    robot = Robot()
    with standing(robot, kind) as relay:
        t0 = time.monotonic()
        gil_hog(0.4)
        t1 = time.monotonic()
        time.sleep(0.2)
        assert relay.phase == "run"
    commands = robot.commands()
    assert t1 - t0 > 0.3  # the stall came
    gap = longest_gap(commands, t0 - 0.05, t1 + 0.1)
    if kind == "process":  # the commands came on: the motors never held one for more than a few periods
        assert gap < 0.05, f"the robot waited {gap * 1e3:.0f} ms for a command"
    else:  # the same stall, the relay a thread of the stalled process: the robot held one command for it
        assert gap > 0.25


def test_the_relay_process_damps_the_robot_when_the_planners_process_dies():
    robot = Robot()
    planner = textwrap.dedent(f"""
        import os, signal, time
        import numpy as np
        from amhe_cli.model.scene import STAND_JOINTS
        from amhe_cli.plants.go1.link import LowLevelLink
        from amhe_cli.plants.go1.relay_process import RelayProcess
        from amhe_cli.plants.go1.safety import SafetySettings
        if __name__ == "__main__":
            link = LowLevelLink(("127.0.0.1", {robot.port}), 0)
            relay = RelayProcess(link, SafetySettings(ramp_time=0.1), 100, 4, planner_period=5.0)
            relay.start()
            assert relay.wait_ready(10.0), (relay.alive(), relay.take_messages())
            relay.set_plan(np.tile(STAND_JOINTS, (1000, 1)), 0.01, time.monotonic())
            time.sleep(0.3)
            print(time.monotonic(), flush=True)
            os.kill(os.getpid(), signal.SIGKILL)  # no stop, no close: gone
    """)
    proc = subprocess.run([sys.executable, "-c", planner], capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    died = float(proc.stdout.strip().splitlines()[-1])
    commands = robot.commands()
    modes_before = [m for t, m in commands if t < died]
    after = [(t, m) for t, m in commands if t >= died]
    assert modes_before[-1] == MODE_SERVO  # it stood at the plan's targets
    assert after and after[-1][1] == MODE_DAMPING  # and ended damped
    damped_at = next(t for t, m in after if m == MODE_DAMPING)
    assert damped_at - died < 0.2
    assert all(m == MODE_DAMPING for t, m in after if t > damped_at)
    assert after[-1][0] - died < 1.0  # then the relay process ended: no command after


def test_a_relay_process_that_dies_is_damped_from_the_planners_side():
    robot = Robot()
    with standing(robot) as relay:
        killed = time.monotonic()
        os.kill(relay.pid, signal.SIGKILL)
        assert relay.failed.wait(2.0)
        assert "relay process ended" in relay.reason and "-9" in relay.reason
        assert relay.phase == "damp"
    after = [m for t, m in robot.commands() if t > killed + 0.01]  # (what the child sent as it was killed)
    assert after and all(m == MODE_DAMPING for m in after)  # the burst this process sent on its own socket


def test_damp_from_the_planners_side_returns_once_the_relay_process_damps_and_keeps_the_first_reason():
    robot = Robot()
    with standing(robot) as relay:
        asked = time.monotonic()
        relay.damp("interrupted (Ctrl-C)")
        assert relay.failed.is_set() and relay.phase == "damp"
        relay.damp("a second reason")
        assert relay.reason == "interrupted (Ctrl-C)"
        returned = time.monotonic()
        time.sleep(0.1)
    commands = robot.commands()  # (noted as the robot reads them, a period or two after they were sent)
    assert all(m == MODE_DAMPING for t, m in commands if t > returned + 0.02)
    assert any(m == MODE_SERVO for t, m in commands if t < asked)


def test_the_run_config_s_relay_process_takes_true_or_false_only():
    from amhe_cli.errors import AmheError
    from amhe_cli.plants.go1.plant import relay_process_setting
    assert relay_process_setting(True) is True and relay_process_setting(False) is False
    with pytest.raises(AmheError, match="relay_process: expected true or false, got 'yes'"):
        relay_process_setting("yes")


def test_a_state_crosses_to_the_planners_process_as_the_fields_it_reads():
    from amhe_cli.plants.go1.protocol import LowState
    from amhe_cli.plants.go1.relay_process import StateSample
    rng = np.random.default_rng(0)
    state = LowState.zeros()
    for name, n in StateSample.FIELDS:
        getattr(state, name)[:] = rng.normal(size=n)
    got = StateSample.unpack(StateSample.pack(LowState.decode(state.encode())))
    wire = LowState.decode(state.encode())  # what the relay's process holds after the wire
    for name, _ in StateSample.FIELDS:
        assert np.array_equal(getattr(got, name), np.asarray(getattr(wire, name), dtype=float)), name
    with pytest.raises(ValueError, match="holds 53 numbers, got 52"):
        StateSample.unpack(np.zeros(52).tobytes())


def test_a_tick_taken_late_leaves_the_motion_capture_verdict_until_one_on_time_or_a_second_passed():
    """After a stall of the planner's process its pose thread has not yet read the poses that queued meanwhile:
    the ticks it catches up on (taken more than LATE_TICK after their time) do not judge the motion capture
    stale, and no tick does while poses wait unread at the socket; a tick on time with none waiting does, and so
    does a late one once a second passed without a verdict."""
    from amhe_cli.control.closed_loop import task_scene_config
    from amhe_cli.control.tasks import get_task
    from amhe_cli.model.scene import Scene
    from amhe_cli.plants.go1.mocap import PoseSample
    from amhe_cli.plants.go1.plant import JUDGE_WITHIN, LATE_TICK, Go1Plant, Go1Settings

    class Poses:  # the last pose arrived 0.3 s ago: the motion capture's stream, or this process, stopped
        def latest(self, name):
            t = time.monotonic() - 0.3
            return PoseSample(name, np.zeros(3), np.array([1.0, 0, 0, 0]), t, t, 1)

        def since(self, name, seq):
            return []

        def unread(self):
            return False

    class Relay:
        dry_run, run_servo, would_send = True, False, []

        def __init__(self):
            self.verdicts = []

        def set_mocap_ok(self, ok):
            self.verdicts.append(ok)

    plant = Go1Plant(Scene(task_scene_config(get_task("t1"), 0.002, 100.0, 4.0)), Go1Settings(mocap_latency=0.0),
                     link=object(), poses=Poses())
    plant.relay = relay = Relay()
    plant._on_tick(time.monotonic() - 0.01, None, None, 0)  # on time: judged stale
    assert relay.verdicts == [False]
    plant._fresh = True  # as if fresh when the stall began
    plant._judged = time.monotonic()
    plant._on_tick(time.monotonic() - 5 * LATE_TICK, None, None, 0)  # caught up late: no verdict
    assert relay.verdicts == [False] and plant._fresh
    plant._judged -= JUDGE_WITHIN + 0.01
    plant._on_tick(time.monotonic() - 5 * LATE_TICK, None, None, 0)  # late, but a second without a verdict
    assert relay.verdicts == [False, False]
    # poses wait unread at the socket: this process behind, not the stream -- no stale verdict on a tick on time,
    # nor on any a second after the last verdict (CI saw such a verdict 0.11 s into a run, "fresh again" at once)
    plant.poses.unread = lambda: True
    plant._fresh, plant._judged = True, time.monotonic()
    plant._on_tick(time.monotonic() - 0.001, None, None, 0)
    assert relay.verdicts == [False, False] and plant._fresh
    plant._judged -= JUDGE_WITHIN + 0.01
    for late in (0.001, 5 * LATE_TICK):
        plant._on_tick(time.monotonic() - late, None, None, 0)
    assert relay.verdicts == [False, False] and plant._fresh
    plant.poses.unread = lambda: False  # read, and none since: the stream stopped
    plant._tick_before = time.monotonic() - 0.003  # the relay's tick before, 2 ms before this one
    plant._on_tick(time.monotonic() - 0.001, None, None, 0)
    assert relay.verdicts == [False, False, False] and "newest poses 0.30 s (trunk) and 0.30 s (box) old" in plant._stale_why
    assert "after the relay's tick before" not in plant._stale_why  # its ticks came on time
    # the relay's own ticks paused 0.25 s before this verdict: the machine stalled, and the verdict says so (CI saw
    # a stale verdict 0.08 s into a run, with no state silence and no pose unread)
    plant._fresh, plant._judged = True, time.monotonic()
    plant._on_tick(time.monotonic() - 0.25, None, None, 0)  # late: no verdict, but the relay's tick before
    plant._on_tick(time.monotonic() - 0.001, None, None, 0)
    assert relay.verdicts[-1] is False
    assert re.search(r", 2[45][0-9] ms after the relay's tick before$", plant._stale_why), plant._stale_why


def test_the_targets_the_relay_process_clamps_are_counted_on_the_planners_side():
    """The live view's ``clamped`` (``Go1Plant.safety_status``) counts the child's safety layer, not a copy here."""
    from amhe_cli.plants.go1.safety import SDK_JOINT_UPPER
    robot = Robot()
    with standing(robot) as relay:
        assert relay.clamped == 0
        relay.set_plan(np.tile(SDK_JOINT_UPPER + 0.5, (1000, 1)), 0.01, time.monotonic())
        time.sleep(0.1)
        assert relay.clamped > 0
    robot.commands()
