"""``amhe run``: the closed loop, adaptive sampling MPC with the online MHE, on a plant (the sim or a Go1)."""

from __future__ import annotations

import json
import signal
import sys

from pathlib import Path

import click
import numpy as np

from amhe_cli.cli.common import (T5_WARNING, TASK_HELP, belief_text, check_live, check_outputs, live_option,
                                 load_belief, parse_xy, progress_bar, start_live, task_view_frames)
from amhe_cli.control.closed_loop import MODES
from amhe_cli.errors import AmheError
from amhe_cli.estimation.identify import IdentifySettings


@click.command("run")
@click.option("--task", "task_name", default="t1", show_default=True, help=TASK_HELP)
@click.option("--target", type=click.Choice(["sim", "go1"]), default="sim", show_default=True,
              help="Plant: the MuJoCo sim, or a Go1 over its low-level UDP link (a real robot or `amhe emulate go1`).")
@click.option("--mode", type=click.Choice(MODES), default="adaptive", show_default=True,
              help="Planner's parameters: the truth, a fixed belief, or the belief re-estimated online by the MHE.")
@click.option("--belief", default=None, type=click.Path(),
              help="Starting belief YAML (default: sim: probe in the sim first, about a minute on 2 cores, saved "
                   "as <out stem>.probe.belief.yaml for the next run's --belief; go1: the nominal prior).")
@click.option("--robot-belief", default=None, type=click.Path(),
              help="Belief YAML whose robot side (servo, trunk payload, motors' torque limits, robot–box "
                   "friction) the planner and the MHE model, the box's still from --belief: `amhe identify` of "
                   "one run of this robot, kept for every box it pushes (default: --belief's robot side).")
@click.option("--config", default=None, type=click.Path(),
              help="YAML: planner, weights, mhe, mhe_params, kp, kd, cycle, task, safety, reflex overrides.")
@click.option("--seed", default=0, show_default=True, type=int,
              help="Seed of the planner's sampling, the MHE and the sim probe.")
@click.option("--duration", default=None, type=float, help="Time limit [s] (default: the task's).")
@click.option("--realtime", is_flag=True, help="Run the sim plant on the wall clock (default: lock-step; go1 always is).")
@click.option("--robot", default="192.168.123.10:8007", show_default=True, metavar="HOST:PORT",
              help="go1: the robot's low-level UDP endpoint.")
@click.option("--local-port", default=8080, show_default=True, type=click.IntRange(0, 65535),
              help="go1: this machine's UDP port (the robot answers it).")
@click.option("--mocap", default="udp:9870", show_default=True, metavar="SPEC",
              help="go1: pose source: udp:PORT (the project's pose stream), optitrack:HOST, vicon:HOST, "
                   "qualisys:HOST, vrpn:HOST, nokov:HOST.")
@click.option("--base-body", default="Go1_body", show_default=True, help="go1: rigid-body name of the trunk.")
@click.option("--box-body", default="Box_body", show_default=True, help="go1: rigid-body name of the box.")
@click.option("--goal", default=None, metavar="X,Y",
              help="go1: goal of the box in the mocap world [m] (default: the task's, relative to the box and "
                   "the robot's heading at the start).")
@click.option("--arm/--dry-run", default=False, show_default=True,
              help="go1: --arm sends servo commands after the ramp to the stand; --dry-run (the default) sends "
                   "damping packets only and records what it would have sent.")
@click.option("--out", default=None, type=click.Path(), help="MCAP to record (default: run_<task>_<mode>_s<seed>.mcap).")
@click.option("--force", is_flag=True,
              help="Overwrite existing output files (--out, its .truth.csv, .probe.belief.yaml and .stalls.txt, --plot).")
@click.option("--plot", type=click.Path(), default=None, help="PNG: box path vs goal, speed tracking, estimates vs truth.")
@click.option("--json", "as_json", is_flag=True,
              help="Print only {success, e_g, J, t_exec, rmse, fell, recoveries[, reason][, failure][, probe_belief]} "
                   "as JSON; recoveries counts the fall-prevention reflex's stops, reason says why a run failed, "
                   "probe_belief where the probe's belief was saved.")
@click.option("--threads", default=None, type=click.IntRange(1, 1024),
              help="Planner rollout threads (default: all CPUs; on the wall clock, less the adaptive MHE's "
                   "own core where it has one: mhe_cores in docs/config.md).")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
@live_option
def run_cmd(task_name, target, mode, belief, robot_belief, config, seed, duration, realtime, robot, local_port, mocap,
            base_body, box_body, goal, arm, out, force, plot, as_json, threads, quiet, live):
    """Push a box with the adaptive sampling MPC (MPOPI + online MHE) on the sim plant or a Go1.

    \b
    amhe run --task t4 --mode adaptive                       the sim plant, lock-step
    amhe run --task t1 --target go1 --robot 127.0.0.1:8007 --mocap udp:9870 --arm
                                                             a Go1 (or `amhe emulate go1`)
    A sim run without --belief first probes (the lunge probe and identify,
    about a minute on 2 cores) and saves that belief beside the recording.
    Every output is refused if it exists, unless --force, before any work.
    A Go1 run waits for the robot's state stream and both poses, ramps to the
    stand over 2 s, and only then plans; any failure (safety trip, lost link,
    stale state, Ctrl-C, an exception) ends in damping, the recording is kept
    and the exit status is non-zero. So does a fall, on either target.
    """
    from amhe_cli.cli.plot import plot_run
    from amhe_cli.control.closed_loop import run_robot_side, run_task, save_run
    from amhe_cli.control.evaluate import load_config, probe_belief, run_settings

    cfg = load_config(config)
    task, settings = run_settings(task_name, mode, cfg, seed=seed, realtime=realtime or target == "go1",
                                  threads=threads, duration=duration)
    from amhe_cli.cli.plot import check_png_name
    out_path = Path(out or f"run_{task.name}_{mode}_s{seed}.mcap")
    stem = out_path.name.split(".mcap")[0]
    probing = target == "sim" and belief is None and mode != "true"
    watched = settings.realtime and settings.stall_after is not None  # run_task's stall watch: its stacks' file
    out_path, truth_path, probe_path, stalls_path, plot_path = check_outputs(
        force, ("--out", out_path),
        ("--out", out_path.with_name(stem + ".truth.csv") if target == "sim" else None),  # save_run's truth CSV
        ("--out", out_path.with_name(stem + ".probe.belief.yaml") if probing else None),
        ("--out", out_path.with_name(stem + ".stalls.txt") if watched else None),
        ("--plot", check_png_name(plot)))
    if stalls_path is not None and stalls_path.exists():  # --force: this run's stacks only
        stalls_path.unlink()
    check_live(live)
    goal_xy = parse_xy(goal, "--goal") if goal is not None else None
    if target == "sim" and goal is not None:
        raise AmheError("--goal is for --target go1; the sim tasks have their own goals (use --config task: goal)")
    if robot_belief is not None and mode == "true":
        raise AmheError("--robot-belief is for --mode baseline or adaptive: --mode true plans with the plant's "
                        "own robot")
    start = load_belief(belief)
    robot_start = load_belief(robot_belief)
    talk = not (quiet or as_json)
    if task.name == "t5":
        click.echo(f"amhe: warning: {T5_WARNING}", err=True)
    if (why := prior_warning(target, mode, settings, start)) is not None:
        click.echo(f"amhe: warning: {why}", err=True)
    if target == "go1" and mode == "true":
        raise AmheError("--mode true needs the box's true parameters, which a real robot does not have: "
                        "use --mode adaptive or baseline")
    # the view: recorded into the MCAP always, streamed to Foxglove with --live; the server starts
    # before the plant or the probe (a busy port costs nothing) and stops whatever happens
    from amhe_cli.io.view import Event, View, ViewFrames, ViewRecorder
    frames = task_view_frames(task, settings.kp, settings.kd, floor=target == "sim")
    server = start_live(live, frames)
    recorder = ViewRecorder()
    try:
        plant = None
        if target == "go1":
            _load_estimator(task, settings, start, quiet or as_json)
            plant, task, start = _start_go1(task, settings, cfg, start, robot, local_port, mocap, base_body, box_body,
                                            goal_xy, arm, quiet or as_json)
            frames.goal = tuple(task.goal)  # placed where the robot and the box stand (the recording's scene)
            if server is not None:  # the live server's own copy of the frames
                server.offer(Event("goal", 0.0, frames.goal))
        elif probing:
            if talk:
                click.echo("no --belief: probing first, as `amhe probe --target sim` does with the task's box: the "
                           f"lunge probe, then identify (up to {IdentifySettings.max_gen} CMA-ES generations, under a "
                           f"minute on 2 cores); then the {task.name} run (up to {task.duration:g} s of sim time)",
                           err=True)
            bar = progress_bar(IdentifySettings.max_gen, "probe+identify", quiet or as_json)
            try:
                start = probe_belief(task, seed=seed, threads=threads, progress=lambda g, b: bar.update(g - bar.n))
            finally:
                bar.close()
            start.save(probe_path, force=force)
            if talk:
                click.echo(f"starting belief: {belief_text(start)}; saved to {probe_path} (next time: --belief "
                           f"{probe_path})", err=True)
        if talk and mode != "true":  # a robot unlike the model, as the belief has it
            side = run_robot_side(settings, robot_start or start, {})
            if side.source:
                click.echo(side.source, err=True)
        bar = progress_bar(task.duration, f"{task.name} {mode}", quiet or as_json, counter="{n:.1f}/{total:.0f} s")
        try:
            result = run_task(task, start, settings, progress=lambda t: bar.update(t - bar.n), plant=plant,
                              view=View([server, recorder]), robot=robot_start, stall_file=stalls_path)
        finally:
            bar.close()
        save_run(result, out_path, task, settings, overwrite=force,
                 extra_meta={"target": target, **({"robot": robot, "mocap": mocap, "armed": arm} if plant else {})},
                 more=lambda log: recorder.write(log, ViewFrames(frames.model, frames.regions, frames.goal)))
        if plant is not None and arm:  # the robot's own efforts against the model the run planned with
            note = _robot_check(result, settings, plant.scene)
            if note:
                result.warnings.append(note)
    finally:
        if server is not None:
            server.close()
    if plot_path is not None:
        plot_run(plot_path, result, task)
    for m in result.warnings:
        click.echo(f"amhe: warning: {m}", err=True)
    reason = failure_reason(result, task)
    if as_json:
        metrics = result.metrics()
        if reason is not None:
            metrics["reason"] = reason
        if probe_path is not None:
            metrics["probe_belief"] = str(probe_path)
        click.echo(json.dumps(metrics))
    else:
        click.echo(f"{task.name} {mode} seed {seed}: {'success' if result.success else 'failure'}"
                   + (f": {reason}" if reason else ""))
        click.echo(f"  e_g {result.e_g:.3f} m   J {result.J:.3f}   t_exec {result.t_exec:.1f} s   "
                   f"speed RMSE {result.rmse:.3f} m/s   control {result.control_hz:.1f} Hz")
        click.echo(f"recorded {out_path}" + (f", {truth_path.name}" if truth_path is not None and truth_path.exists()
                                             else "")
                   + (f", probe belief {probe_path}" if probe_path is not None else "")
                   + (f", stalls' stacks {stalls_path.name}" if stalls_path is not None and stalls_path.exists() else "")
                   + (f", plot {plot_path}" if plot_path else ""))
    if result.failure is not None:
        if result.failure.startswith("interrupted"):
            click.echo(f"amhe: {result.failure}; recorded {out_path}", err=True)
            sys.exit(130)
        raise AmheError(f"run stopped: {result.failure} (recorded {out_path})")
    if result.fell:  # a fall is a broken robot: a script that runs this must not read it as a run that ended
        raise AmheError(f"run stopped: {reason}" + ("; the robot was damped" if plant is not None else "")
                        + f" (recorded {out_path})")


def prior_warning(target: str, mode: str, settings, start) -> str | None:
    """Why a robot run's MHE should not start from the nominal prior, or None: ``mhe: {attribute: true}`` holds
    the prior's split of the box's mass and friction until a change shows which moved, and a prior off the
    box reads as a change whose split the push may not tell (docs/evaluation.md "Each decision of a change
    locates it again": from the nominal prior, μ 0.1 above T4's first floor, 2 of 15 emulated runs gave that
    floor to the mass). ``start``: the --belief given, or None."""
    if target != "go1" or mode != "adaptive" or start is not None or not settings.mhe.attribute:
        return None
    return ("mhe attribute starts from the nominal prior's split of the box's mass and friction, and a box unlike "
            "it reads as a change the push may give to the wrong one: start from a belief (--belief: `amhe "
            "identify` of a recorded push of this box, such as a --mode baseline run's recording)")


def failure_reason(result, task) -> str | None:
    """Why a run did not succeed, in one line; None for a success.

    In order: the plant's own failure text (``RunResult.failure``: a safety
    trip, a lost link, Ctrl-C); "robot fell at t = 12.3 s" (the first recorded
    sample with the trunk below ``task.fall_height`` over the floor or tilted
    beyond ``task.fall_tilt``); "time limit (40 s)
    reached with the box 0.70 m from the goal (success: within 0.20 m)"; or,
    for a run that ended early without either, where the box was left.

    Args:
        result: :class:`~amhe_cli.control.closed_loop.RunResult`.
        task: the :class:`~amhe_cli.control.tasks.Task` it ran (its ``duration``,
            ``fall_height``, ``fall_tilt`` and ``success_radius``).
    """
    from amhe_cli.control.reflex import fallen
    from amhe_cli.model.scene import SceneConfig
    if result.success:
        return None
    if result.failure is not None:
        return result.failure
    traj = result.traj
    if result.fell:
        t_fall = result.t_exec
        if traj is not None and len(traj):
            floor = SceneConfig.from_dict(traj.meta["scene"]).robot_floor if "scene" in traj.meta else 0.0
            low = np.flatnonzero(fallen(traj.base_pos, traj.base_quat, floor, task.fall_height, task.fall_tilt))
            t_fall = float(traj.t[low[0]] if len(low) else traj.t[-1])
        return f"robot fell at t = {t_fall:.1f} s"
    where = f"the box {result.e_g:.2f} m from the goal (success: within {task.success_radius:.2f} m)"
    if result.t_exec >= task.duration - 0.1:
        return f"time limit ({task.duration:g} s) reached with {where}"
    return f"run ended at t = {result.t_exec:.1f} s with {where}"


def _robot_check(result, settings, scene) -> str | None:
    """:func:`~amhe_cli.control.robot_side.check_run` on an armed Go1 run's recording against the robot side
    its planner modelled (``result.side``), the motors' limits the plant's ``scene`` (the model's own): one line
    where the robot was not that one. The run is over and the robot damped: a check that fails says so, it never
    raises."""
    from amhe_cli.control.robot_side import check_run
    from amhe_cli.model.scene import torque_limit
    if result.side is None:  # the run stopped before it planned
        return None
    try:
        return check_run(result.traj, result.side, settings.kp, torque_limit(scene.model))
    except Exception as e:  # noqa: BLE001 - advice after the run, never a new failure
        return f"could not check the robot against the planner's model ({type(e).__name__}: {e})"


def _sigterm_as_interrupt(signum, frame):
    """SIGTERM (a process manager, ``kill``) ends a robot run like Ctrl-C: damping, the recording kept."""
    raise KeyboardInterrupt


def _load_estimator(task, settings, start, quiet: bool) -> None:
    """Before the robot is connected: what an ``adaptive`` run's MHE loads at its start, so that neither a missing
    device nor minutes of loading come while the robot stands, the run's clock running (docs/evaluation.md, stop 77).

    The smoothing's imports (``scipy.signal``: 0.2–0.6 s of a GPU client's set-up), and with the line decisions on
    a backend of their own (``mhe: {attribute: true, attribute_device: …}``) that backend, one batch rolled out on
    the task's nominal scene and closed: on ``cuda`` MuJoCo Warp's kernels compile into Warp's cache the first time
    on a machine (minutes) and load into this process, so the run's own warm after the robot stands up (each
    batch width's slot, on its own backend) takes seconds.

    Raises:
        AmheError: the decisions' device is missing ("the run config's mhe attribute_device cuda: …"), before any
            packet to the robot.
    """
    if settings.mode != "adaptive":
        return
    from amhe_cli.control.closed_loop import make_estimator
    from amhe_cli.io.smoothing import preload
    from amhe_cli.model.device import choose_device

    preload()
    if not (settings.mhe.attribute and settings.mhe.attribute_device is not None):
        return
    try:
        choose_device(settings.mhe.attribute_device)
    except AmheError as e:  # said as the run config's key, not as an option this command lacks
        raise AmheError(f"the run config's mhe attribute_device {settings.mhe.attribute_device}: "
                        f"{str(e).split(': ', 1)[-1]}") from None
    prior = {} if start is None else {k: v for k, v in start.values.items() if k in settings.mhe_params}
    mhe = make_estimator(task, settings, 0.002, prior)
    try:
        took = mhe.warm(slots=False)  # the widths' slots are the run's own backend's to set up
    finally:
        mhe.close()
    if not quiet:
        click.echo(f"go1: the MHE's line decisions loaded on {settings.mhe.attribute_device} in {took:.1f} s, "
                   "before the robot", err=True)


def _start_go1(task, settings, cfg, start, robot, local_port, mocap, base_body, box_body, goal_xy, arm, quiet):
    """Open the Go1 plant, wait for state and poses, ramp to the stand; place the task where robot and box are.

    Returns:
        (plant, placed task, starting belief).
    """
    from amhe_cli.control.closed_loop import RUN_PARAMS, describe_split, task_scene_config
    from amhe_cli.estimation.belief import Belief
    from amhe_cli.io.quat import quat_to_yaw
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene
    from amhe_cli.plants.go1.latency import parse_mocap_latency
    from amhe_cli.plants.go1.link import parse_address
    from amhe_cli.plants.go1.plant import Go1Plant, Go1Settings, relay_process_setting
    from amhe_cli.plants.go1.safety import SafetySettings

    scene = Scene(task_scene_config(task, 0.002, settings.kp, settings.kd))
    if start is None:
        start = Belief.nominal(ParameterSpace(scene, free=RUN_PARAMS), {"source": "nominal prior (no --belief)"})
        if not quiet:
            click.echo(f"no --belief: starting from the nominal prior ({belief_text(start)})", err=True)
    split = describe_split(settings, clocked=True)  # a split that leaves the planner nothing stops before the link
    go1 = Go1Settings(robot=parse_address(robot, 8007), local_port=local_port, mocap=mocap, base_body=base_body,
                      box_body=box_body, arm=arm, kp=settings.kp, kd=settings.kd,
                      safety=SafetySettings.from_dict(cfg.get("safety")),
                      mocap_latency=parse_mocap_latency(cfg.get("mocap_latency", "auto")),
                      relay_process=relay_process_setting(cfg.get("relay_process", True)))
    signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    plant = Go1Plant(scene, go1)
    if not quiet:
        click.echo(f"go1: {split}", err=True)
        click.echo(f"go1: waiting for {robot} and poses from {mocap} ({base_body}, {box_body}); "
                   f"{'ARMED' if arm else 'dry run: damping packets only'}", err=True)
    m = plant.start()
    sc = scene
    placed = task.placed(m.qpos[sc.base_qpos[:2]], float(quat_to_yaw(m.qpos[sc.base_qpos[3:]])),
                         m.qpos[sc.box_qpos[:2]], goal=goal_xy)
    if not quiet:
        click.echo(f"go1: standing; box at ({placed.box_start[0]:.2f}, {placed.box_start[1]:.2f}) m, goal "
                   f"({placed.goal[0]:.2f}, {placed.goal[1]:.2f}) m, {placed.goal_error(placed.box_start):.2f} m away",
                   err=True)
    return plant, placed, start
