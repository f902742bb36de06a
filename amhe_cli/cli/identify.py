"""``amhe identify``: box parameters from a log, SPI-style CMA-ES over short clips."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import click

from amhe_cli.cli.common import (check_outputs, default_output, identify_options, log_options, make_settings,
                                 parse_smooth, print_summary, run_identify, save_outputs, sensor_lines)
from amhe_cli.errors import AmheError
from amhe_cli.estimation.problem import example_logs, load_problem, parse_box_size, parse_topics

@click.command("identify")
@click.argument("log", required=False, type=click.Path())
@log_options
@identify_options
@click.option("--t-range", default=None, metavar="T0,T1", help="Use only this part of the log [s].")
@click.option("--replicates", default=1, show_default=True, type=click.IntRange(1, 256),
              help="Searches run side by side: the main one, and K-1 on bootstrap resamples of the clips "
                   "(K x the rollouts, in as many rollout calls); their spread is reported as "
                   "std_sources.replicates. Best with --device cuda, whose width they fill.")
@click.option("--out", default=None, type=click.Path(), help="Belief YAML to write (default: <log stem>.belief.yaml).")
@click.option("--force", is_flag=True, help="Overwrite existing output files (--out, --plot).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the results and nothing else.")
@click.option("--plot", type=click.Path(), default=None,
              help="Write a PNG: cost over generations, each parameter's path to its estimate ± σ, "
                   "recorded vs predicted box velocity and position error over the clips.")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
def identify_cmd(log, topics, map_file, box_size, smooth, params, prior, n_clips, candidates, horizon, popsize,
                 generations, prior_weight, t_range, replicates, seed, threads, out, force, as_json, plot, quiet):
    """Identify box mass, inertia and box-floor friction from LOG (SPI-style CMA-ES).

    With no LOG, runs on the bundled example log. Every output (--out, --plot)
    is refused if it exists, unless --force, before any work starts.
    """
    from amhe_cli.cli.plot import check_png_name
    if log is None:
        logs = example_logs()
        if not logs:
            raise AmheError("no LOG given and no bundled example found: expected 'amhe identify LOG'")
        log = str(logs[0])
        if not as_json:
            click.echo(f"no LOG given: using the bundled example {Path(log).name}", err=True)
    settings = make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed, t_range,
                             candidates=candidates, replicates=replicates)
    smooth = parse_smooth(smooth)
    out_path, plot_path = check_outputs(force, ("--out", default_output(out, log, ".belief.yaml")),
                                        ("--plot", check_png_name(plot)))
    problem = load_problem(log, topics=parse_topics(topics, map_file), params=settings.params if params else None,
                           prior=prior, box_size=parse_box_size(box_size), smooth=smooth, nthread=threads)
    settings = replace(settings, params=problem.space.free)
    from amhe_cli.io.truth import metadata_truth
    truth = metadata_truth(problem.traj)
    result = run_identify(problem, settings, quiet or as_json, threads)
    save_outputs(problem, result, "identify", log, out_path, force, plot_path, threads, truth=truth)
    if as_json:
        s = result.summary()
        if truth is not None:
            s["truth"] = {k: truth[k] for k in result.space.free if k in truth}
        s["sensors"] = problem.traj.meta.get("sensors", {})
        s["belief"] = str(out_path)
        if plot_path is not None:
            s["plot"] = str(plot_path)
        click.echo(json.dumps(s))
        return
    click.echo(f"log {log}: {len(problem.traj) * problem.traj.dt:.1f} s, box floor z={problem.scene.config.floor_height:+.3f} m, "
               f"robot floor z={problem.scene.config.robot_floor_height:+.3f} m")
    for line in sensor_lines(problem.traj.meta):
        click.echo(f"  {line}")
    print_summary(result, truth=truth)
    click.echo(f"belief written to {out_path}" + (f"; plot to {plot_path}" if plot_path else ""))
