"""``amhe emulate go1``: a Go1 on 127.0.0.1 — the task's sim plant behind the Go1 low-level protocol.

The plant is built here (``plants/`` may not import ``control``) and handed,
with the task's events, to :class:`~amhe_cli.plants.go1.emulator.Go1Emulator`.
"""

from __future__ import annotations

import math
import sys

import click

from amhe_cli.cli.common import check_live, live_option, start_live, task_view_frames
from amhe_cli.errors import AmheError

#: Gains the plant's scene is built with. The emulator zeroes the plant's position
#: servos and applies the motor PD of each LowCmd itself, so these only fill the
#: scene config (``amhe run``'s defaults).
_SCENE_KP, _SCENE_KD = 100.0, 4.0


def parse_pose_noise(text: str) -> tuple[float, float]:
    """``POS[,ROT]`` -> (position std [m], rotation std [rad]).

    ROT is in radians, or in degrees with a ``deg`` suffix (``0.001,0.2deg``);
    a missing ROT is 0.

    Raises:
        AmheError: not one or two non-negative finite numbers.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if not 1 <= len(parts) <= 2:
        raise AmheError(f"--pose-noise {text!r}: expected POS[,ROT], e.g. 0.001,0.2deg (metres, radians or deg)")
    try:
        pos = float(parts[0])
        rot_text = parts[1] if len(parts) == 2 else "0"
        if rot_text.endswith("deg"):
            rot = math.radians(float(rot_text[:-3]))
        else:
            rot = float(rot_text[:-3] if rot_text.endswith("rad") else rot_text)
    except ValueError:
        raise AmheError(f"--pose-noise {text!r}: expected POS[,ROT], e.g. 0.001,0.2deg "
                        "(metres, radians or deg)") from None
    if not (math.isfinite(pos) and math.isfinite(rot) and pos >= 0 and rot >= 0):
        raise AmheError(f"--pose-noise {text!r}: noise must be finite and >= 0")
    return pos, rot


#: The emulated robot's own parameters ``--robot`` may set, where it differs from the model ``amhe run``
#: plans with (``model/params.py``). The joint gains are not among them: the emulator applies each LowCmd's
#: own, and ``--motor-strength`` scales what the motors deliver.
ROBOT_SIDE = ("trunk_payload", "robot_box_friction")
#: The box's parameters ``--box`` may set at the start (the task's events still change them later).
BOX_SIDE = ("box_mass", "box_friction")


def parse_robot(text: str | None) -> dict[str, float]:
    """``--robot NAME=VALUE[,NAME=VALUE]`` -> {name: value} for :data:`ROBOT_SIDE` parameters (:func:`parse_truth`)."""
    return parse_truth(text, ROBOT_SIDE, "--robot", "trunk_payload=1.5")


def parse_truth(text: str | None, names: tuple, option: str, example: str) -> dict[str, float]:
    """``NAME=VALUE[,NAME=VALUE]`` -> {name: value} for the parameters ``names``, within their bounds.

    Raises:
        AmheError: an unknown name, a value that is not a number or lies outside the parameter's bounds;
            the message names ``option`` and gives ``example``.
    """
    from amhe_cli.model.params import PARAMETERS
    out: dict[str, float] = {}
    for part in [p.strip() for p in (text or "").split(",") if p.strip()]:
        name, sep, value = part.partition("=")
        name = name.strip()
        if not sep or name not in names:
            raise AmheError(f"{option} {part!r}: expected NAME=VALUE with NAME one of {', '.join(names)}, "
                            f"e.g. {example}")
        try:
            v = float(value)
        except ValueError:
            raise AmheError(f"{option} {part!r}: {value!r} is not a number") from None
        lo, hi = PARAMETERS[name].lower[0], PARAMETERS[name].upper[0]
        if not (math.isfinite(v) and lo <= v <= hi):
            raise AmheError(f"{option} {part!r}: expected {name} in [{lo:g}, {hi:g}] {PARAMETERS[name].unit}")
        out[name] = v
    return out


def _say_event(t: float, event, monotonic: float) -> None:
    """One stdout line per fired task event, with the machine's monotonic clock (benchmarks align runs by it)."""
    click.echo(f"amhe emulate go1: event {event.param} -> {event.value:g} at t={t:.3f} s "
               f"(monotonic {monotonic:.6f})")
    sys.stdout.flush()


@click.group("emulate")
def emulate_cmd():
    """Emulate a robot on this machine, for testing the real-robot path without one."""


@emulate_cmd.command("go1")
@click.option("--task", default="t1", show_default=True, help="Task whose sim plant (box, truth, events) to run.")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on for LowCmd packets.")
@click.option("--port", default=8007, show_default=True, type=click.IntRange(0, 65535),
              help="UDP port to listen on (0: any free port; the first line says which).")
@click.option("--pose-to", default="127.0.0.1:9870", show_default=True, metavar="HOST[:PORT]|off",
              help="Where to stream the trunk and box poses (120 Hz), or 'off'.")
@click.option("--pose-latency", default=0.003, show_default=True, type=click.FloatRange(0, 1.0),
              help="Latency of the pose stream [s].")
@click.option("--pose-noise", default="0.001,0.2deg", show_default=True, metavar="POS[,ROT]",
              help="Pose noise std: position [m], rotation [rad, or deg with a 'deg' suffix].")
@click.option("--base-body", default="Go1_body", show_default=True, help="Rigid-body name of the trunk's pose.")
@click.option("--box-body", default="Box_body", show_default=True, help="Rigid-body name of the box's pose.")
@click.option("--fault", "faults", multiple=True, metavar="KIND@T",
              help="Inject a fault T s after the first valid command: link-loss, corrupt, mocap-freeze, "
                   "mocap-drop, motor-loss (no torque: the robot folds). Repeatable.")
@click.option("--record", type=click.Path(dir_okay=False), default=None,
              help="CSV of every received packet (t, valid, mode_i, q_i, kp_i, kd_i).")
@click.option("--force", is_flag=True, help="Overwrite an existing --record file.")
@click.option("--duration", type=click.FloatRange(0, min_open=True), default=None,
              help="Stop after this many seconds of emulator time (default: until SIGINT/SIGTERM).")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the pose noise.")
@click.option("--robot", "robot", default=None, metavar="NAME=VALUE[,...]",
              help="The emulated robot unlike the model amhe plans with: trunk_payload [kg] (a point mass at the "
                   "trunk's centre of mass), robot_box_friction [-].")
@click.option("--box", "box", default=None, metavar="NAME=VALUE[,...]",
              help="The box unlike the task's (and the run's nominal belief) from the start: box_mass [kg], "
                   "box_friction [-] (box–floor); the task's events still change them (T3's switch, T4's step).")
@click.option("--motor-strength", default=1.0, show_default=True, type=click.FloatRange(0, 2, min_open=True),
              help="Share of the commanded torque the motors deliver, torque limits included (0.85: weaker "
                   "motors than the model's).")
@click.option("--quiet", "-q", is_flag=True, help="No summary line on stderr at the end.")
@live_option
def go1_cmd(task, host, port, pose_to, pose_latency, pose_noise, base_body, box_body, faults, record, force,
            duration, seed, robot, box, motor_strength, quiet, live):
    """A Go1 EDU on the low-level UDP link (legged_sdk 3.8), played by the sim plant.

    \b
    Listens for 614-byte LowCmd packets on udp://HOST:PORT and answers the
    sender of the last valid one with an 807-byte LowState every 2 ms; streams
    the trunk and box poses to --pose-to (and, with --live, the true robot and
    box to Foxglove). The first line on stdout says where it listens and sends;
    a summary goes to stderr at the end.
    """
    from amhe_cli.control.closed_loop import make_plant
    from amhe_cli.control.tasks import get_task
    from amhe_cli.plants.go1.emulator import Go1Emulator, parse_fault
    from amhe_cli.plants.go1.link import parse_address
    from amhe_cli.plants.go1.mocap import POSE_STREAM_PORT

    fault_list = [parse_fault(f) for f in faults]
    noise = parse_pose_noise(pose_noise)
    robot_truth = parse_robot(robot)
    box_truth = parse_truth(box, BOX_SIDE, "--box", "box_mass=5.5")
    target = None if pose_to.strip().lower() == "off" else parse_address(pose_to, POSE_STREAM_PORT)
    check_live(live)
    t = get_task(task)
    plant = make_plant(t, _SCENE_KP, _SCENE_KD)
    for name, value in {**box_truth, **robot_truth}.items():  # the world's own truth, never shown to the client
        plant.set_param(name, value)
    server = view = None
    if live is not None:  # the emulated robot's true state, as the plant's own view
        from amhe_cli.io.view import View
        server = start_live(live, task_view_frames(t, _SCENE_KP, _SCENE_KD))
        view = View([server])
    try:
        emu = Go1Emulator(plant, list(t.events), host=host, port=port, pose_to=target, faults=fault_list,
                          record=record, base_body=base_body, box_body=box_body, pose_latency=pose_latency,
                          pose_noise=noise, seed=seed, overwrite=force, view=view, on_event=_say_event,
                          motor_strength=motor_strength)
    except BaseException:
        if server is not None:
            server.close()
        raise
    bh, bp = emu.address
    poses = (f"poses to udp://{target[0]}:{target[1]} ({base_body}, {box_body})" if target is not None
             else "poses off")
    extra = f", faults {' '.join(f'{f.kind}@{f.t:g}' for f in fault_list)}" if fault_list else ""
    unlike = [f"{k} {v:g}" for k, v in robot_truth.items()] + (
        [f"motor strength {motor_strength:g}"] if motor_strength != 1.0 else [])
    extra += f", robot unlike its model: {', '.join(unlike)}" if unlike else ""
    extra += f", box {', '.join(f'{k} {v:g}' for k, v in box_truth.items())}" if box_truth else ""
    click.echo(f"amhe emulate go1: listening on udp://{bh}:{bp}, {poses}, task {t.name}{extra}")
    sys.stdout.flush()
    try:
        st = emu.run(duration)
    finally:
        if server is not None:
            server.close()
    if not quiet:
        click.echo(f"amhe emulate go1: {st.ticks * 0.002:.2f} s emulated, packets valid {st.valid} bad {st.bad} "
                   f"ignored {st.ignored}, states sent {st.sent} (refused {st.send_failed}), poses {st.poses}, "
                   f"overruns {st.overruns}, "
                   f"longest state gap {st.longest_gap * 1e3:.1f} ms ({emu.scheduling}), "
                   f"longest command gap {st.longest_command_gap * 1e3:.1f} ms, "
                   f"longest pose gap {st.longest_pose_gap * 1e3:.1f} ms",
                   err=True)
