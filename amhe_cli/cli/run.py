"""``amhe run``: the closed loop, adaptive sampling MPC with the online MHE, on a plant."""

from __future__ import annotations

import json

import click

from amhe_cli.cli.common import fmt, load_belief, output_path, progress_bar
from amhe_cli.control.closed_loop import MODES
from amhe_cli.errors import AmheError

@click.command("run")
@click.option("--task", "task_name", default="t1", show_default=True, help="Task t1..t5 (DESIGN.md §6).")
@click.option("--target", type=click.Choice(["sim", "go1"]), default="sim", show_default=True,
              help="Plant: the MuJoCo sim (a real Go1 is not supported by this version).")
@click.option("--mode", type=click.Choice(MODES), default="adaptive", show_default=True,
              help="Planner's parameters: the truth, a fixed belief, or the belief re-estimated online by the MHE.")
@click.option("--belief", default=None, type=click.Path(), help="Starting belief YAML (default: probe in sim first).")
@click.option("--config", default=None, type=click.Path(),
              help="YAML: planner, weights, mhe, mhe_params, kp, kd, cycle, task overrides.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--duration", default=None, type=float, help="Time limit [s] (default: the task's).")
@click.option("--realtime", is_flag=True, help="Run the plant on the wall clock (default: lock-step).")
@click.option("--out", default=None, type=click.Path(), help="MCAP to record (default: run_<task>_<mode>_s<seed>.mcap).")
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--plot", type=click.Path(), default=None, help="PNG: box path vs goal, speed tracking, estimates vs truth.")
@click.option("--json", "as_json", is_flag=True, help="Print only {success, e_g, J, t_exec, rmse} as JSON.")
@click.option("--threads", default=None, type=int, help="Planner rollout threads (default: all CPUs).")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def run_cmd(task_name, target, mode, belief, config, seed, duration, realtime, out, force, plot, as_json, threads, quiet):
    """Push a box with the adaptive sampling MPC (MPOPI + online MHE) in the sim plant."""
    from amhe_cli.control.closed_loop import run_task, save_run
    from amhe_cli.control.evaluate import load_config, probe_belief, run_settings
    from amhe_cli.cli.plot import check_plot_path, plot_run

    if target != "sim":
        raise AmheError("--target go1: driving a real Go1 is not supported by this version; use --target sim")
    task, settings = run_settings(task_name, mode, load_config(config), seed=seed, realtime=realtime,
                                  threads=threads, duration=duration)
    out_path = output_path(out or f"run_{task.name}_{mode}_s{seed}.mcap", f"run_{task.name}", ".mcap", force)
    plot_path = check_plot_path(plot)
    start = load_belief(belief)
    if start is None and mode != "true":
        if not (quiet or as_json):
            click.echo("no --belief: probing in the sim with the task's starting box first", err=True)
        bar = progress_bar(40, "probe+identify", quiet or as_json)
        try:
            start = probe_belief(task, seed=seed, threads=threads, progress=lambda g, b: bar.update(g - bar.n))
        finally:
            bar.close()
        if not (quiet or as_json):
            click.echo("starting belief: " + ", ".join(f"{k} {fmt(v)}" for k, v in start.values.items()
                                                      if k in ("box_mass", "box_friction")), err=True)
    bar = progress_bar(task.duration, f"{task.name} {mode}", quiet or as_json, counter="{n:.1f}/{total:.0f} s")
    try:
        result = run_task(task, start, settings, progress=lambda t: bar.update(t - bar.n))
    finally:
        bar.close()
    save_run(result, out_path, task, settings, overwrite=force)
    if plot_path is not None:
        plot_run(plot_path, result, task)
    for m in result.warnings:
        click.echo(f"amhe: warning: {m}", err=True)
    if as_json:
        click.echo(json.dumps(result.metrics()))
        return
    click.echo(f"{task.name} {mode} seed {seed}: {'success' if result.success else 'failure'}"
               f"{' (the robot fell)' if result.fell else ''}")
    click.echo(f"  e_g {result.e_g:.3f} m   J {result.J:.3f}   t_exec {result.t_exec:.1f} s   "
               f"speed RMSE {result.rmse:.3f} m/s   control {result.control_hz:.1f} Hz")
    click.echo(f"recorded {out_path}" + (f", plot {plot_path}" if plot_path else ""))
