"""``amhe probe``: a first belief from the sim probing manoeuvre, or what a log can tell."""

from __future__ import annotations

import json

import click

from amhe_cli import __version__
from amhe_cli.cli.common import (identify_options, log_options, make_settings, output_path, parse_smooth,
                                 parse_truth, print_summary, run_identify, save_outputs)
from amhe_cli.errors import AmheError
from amhe_cli.estimation.problem import load_problem, parse_box_size, parse_topics

@click.command("probe")
@click.argument("log", required=False, type=click.Path())
@click.option("--target", type=click.Choice(["sim"]), default=None,
              help="Run the probing manoeuvre on this target instead of reading LOG (sim: the MuJoCo plant).")
@click.option("--truth", "truth_pairs", multiple=True, metavar="NAME=VALUE",
              help="True parameter of the sim plant (repeatable), e.g. --truth box_mass=5 --truth box_friction=0.45.")
@click.option("--record", type=click.Path(), default=None,
              help="MCAP to record the sim probe into (default: probe_sim.mcap).")
@click.option("--record-only", is_flag=True, help="Record the sim probe and stop (no identification).")
@log_options
@identify_options
@click.option("--out", default=None, type=click.Path(), help="Belief YAML (sim target; default probe_sim.belief.yaml).")
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object and nothing else.")
@click.option("--plot", type=click.Path(), default=None, help="PNG of the identification (sim target).")
@click.option("--quiet", "-q", is_flag=True)
def probe_cmd(log, target, truth_pairs, record, record_only, topics, map_file, box_size, smooth, params, prior,
              n_clips, horizon, popsize, generations, prior_weight, seed, threads, out, force, as_json, plot, quiet):
    """Probe for a first belief (--target sim), or report what LOG can tell.

    \b
    amhe probe --target sim --out belief.yaml   scripted lunges against a box in the
                                                sim plant, recorded and identified
    amhe probe LOG                              topics, rates, gaps, and how well each
                                                parameter can be identified from LOG
    """
    from amhe_cli.io.reader import inspect_log
    from amhe_cli.control.probing import simulate_probe
    from amhe_cli.estimation.probe import assess
    from amhe_cli.io.truth import TRUTH_RECORD
    settings = make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed)
    free = settings.params
    if target is None:
        if log is None:
            raise AmheError("probe needs a LOG to assess, or --target sim to run the probing manoeuvre")
        smooth = parse_smooth(smooth)
        info = inspect_log(log, topics=parse_topics(topics, map_file) or None)
        problem = load_problem(log, topics=parse_topics(topics, map_file), params=free, prior=prior,
                               box_size=parse_box_size(box_size), smooth=smooth)
        curv = assess(problem.traj, problem.scene, problem.space, n_clips=n_clips, horizon=settings.horizon,
                      seed=seed, nthread=threads)
        sp = problem.space
        report = {"log": info.to_dict(), "parameters": {}, "labels": sp.labels,
                  "correlation": curv.corr.tolist(), "fisher": curv.fisher.tolist(), "cost_at_prior": curv.cost}
        prior_val, prior_sd = sp.physical(sp.mean0, sp.std0)
        _, post_sd = sp.physical(sp.mean0, curv.std)
        for i, label in enumerate(sp.labels):
            report["parameters"][label] = {"prior": float(prior_val[i]), "prior_std": float(prior_sd[i]),
                                           "std": float(post_sd[i]),
                                           "information_gain": float(prior_sd[i] / max(post_sd[i], 1e-12))}
        if as_json:
            click.echo(json.dumps(report, default=str))
            return
        click.echo(str(info))
        click.echo(f"\nidentifiability from {n_clips} clips, at the prior ({problem.prior_source}):")
        click.echo(f"{'parameter':<16} {'prior':>9} {'prior std':>10} {'std':>10} {'prior std/std':>13}")
        for label, rec in report["parameters"].items():
            click.echo(f"{label:<16} {rec['prior']:>9.4g} {rec['prior_std']:>10.3g} {rec['std']:>10.3g} "
                       f"{rec['information_gain']:>13.3g}")
        if "box_mass" in sp.labels and "box_friction" in sp.labels:
            i, j = sp.labels.index("box_mass"), sp.labels.index("box_friction")
            click.echo(f"mass-friction correlation {curv.corr[i, j]:+.2f}")
        return
    if log is not None:
        raise AmheError("give either LOG or --target sim, not both")
    truth = {"box_mass": 5.0, "box_friction": 0.45}
    truth.update(parse_truth(truth_pairs))
    record_path = output_path(record or "probe_sim.mcap", "probe_sim", "", force)
    out_path = None if record_only else output_path(out or "probe_sim.belief.yaml", "probe_sim", "", force)
    from amhe_cli.cli.plot import check_plot_path
    plot_path = check_plot_path(plot)
    from amhe_cli.io.writer import write_mcap
    traj = simulate_probe(truth, seed=seed)
    truth_all = traj.meta["truth"]
    write_mcap(record_path, traj, overwrite=force, metadata={
        TRUTH_RECORD: {k: json.dumps(v) for k, v in truth_all.items()},
        "amhe_probe": {"manoeuvre": "lunges 0.06, 0.09, 0.12 m", "seed": str(seed), "amhe_version": __version__},
    })
    if not as_json:
        click.echo(f"recorded the sim probe ({traj.duration:.1f} s) to {record_path}", err=True)
    if record_only:
        if as_json:
            click.echo(json.dumps({"log": str(record_path), "truth": truth_all, "duration_s": traj.duration}))
        return
    problem = load_problem(str(record_path), params=free, prior=prior, box_size=parse_box_size(box_size))
    result = run_identify(problem, settings, quiet or as_json, threads)
    save_outputs(problem, result, "probe --target sim", str(record_path), out_path, force, plot_path, threads,
                 truth=truth_all)
    if as_json:
        s = result.summary()
        s.update(belief=str(out_path), log=str(record_path), truth={k: truth_all[k] for k in problem.space.free})
        click.echo(json.dumps(s))
        return
    print_summary(result, truth=truth_all)
    click.echo(f"belief written to {out_path}")
