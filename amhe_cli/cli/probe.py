"""``amhe probe``: a first belief from the sim probing manoeuvre, or what one or more logs can tell."""

from __future__ import annotations

import json
import textwrap
import warnings

import click

from amhe_cli import __version__
from amhe_cli.cli.common import (check_outputs, identify_options, log_options, make_settings, parse_smooth,
                                 parse_truth, print_summary, run_identify, save_outputs)
from amhe_cli.errors import AmheError
from amhe_cli.estimation.problem import load_problem, parse_box_size, parse_topics
from amhe_cli.model.params import PARAMETERS

#: Printed under each identifiability table: what its σ are, and are not.
BEST_CASE_NOTE = ("σ here is a best case: the cost's curvature (Fisher information) at the prior, with the prior "
                  "included; `amhe identify` reports σ about 10× wider, as it also counts the spread over clips "
                  "and the search's own spread.")


@click.command("probe")
@click.argument("logs", nargs=-1, type=click.Path(), metavar="[LOG]...")
@click.option("--target", type=click.Choice(["sim"]), default=None,
              help="Run the probing manoeuvre on this target instead of reading LOG (sim: the MuJoCo plant).")
@click.option("--truth", "truth_pairs", multiple=True, metavar="NAME=VALUE",
              help="True parameter of the sim plant (repeatable), e.g. --truth box_mass=5 --truth box_friction=0.45 "
                   "(default: 5 kg, μ 0.45).")
@click.option("--record", type=click.Path(), default=None,
              help="MCAP to record the sim probe into (default: probe_sim.mcap).")
@click.option("--record-only", is_flag=True, help="Record the sim probe and stop (no identification).")
@log_options
@identify_options
@click.option("--out", default=None, type=click.Path(), help="Belief YAML (sim target; default probe_sim.belief.yaml).")
@click.option("--force", is_flag=True, help="Overwrite existing output files (--record, --out, --plot).")
@click.option("--json", "as_json", is_flag=True,
              help="Print JSON and nothing else: one object (sim target, or one LOG), a list of objects for several LOGs.")
@click.option("--plot", type=click.Path(), default=None, help="PNG of the identification (sim target).")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
def probe_cmd(logs, target, truth_pairs, record, record_only, topics, map_file, box_size, smooth, params, prior,
              n_clips, candidates, horizon, popsize, generations, prior_weight, seed, threads, out, force, as_json, plot,
              quiet):
    """Probe for a first belief (--target sim), or report what each LOG can tell.

    \b
    amhe probe --target sim --out belief.yaml   scripted lunges against a box in the
                                                sim plant, recorded and identified
    amhe probe LOG [LOG]...                     per log: topics, rates, gaps, and how
                                                well each parameter can be identified
    """
    from amhe_cli.io.truth import TRUTH_RECORD
    settings = make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed, candidates=candidates)
    free = settings.params
    if target is None:
        if not logs:
            raise AmheError("probe needs a LOG to assess, or --target sim to run the probing manoeuvre")
        if plot or out or record or record_only:
            raise AmheError("--plot, --out, --record and --record-only are for --target sim; assessing a LOG "
                            "writes nothing")
        smooth = parse_smooth(smooth)
        chosen = parse_topics(topics, map_file)
        reports = []
        for k, log in enumerate(logs):
            rep, text = _assess_log(log, chosen, free, prior, box_size, smooth, n_clips, settings.horizon, seed,
                                    threads, as_json)
            reports.append(rep)
            if not as_json:
                click.echo(("\n" if k else "") + text)
        if as_json:
            click.echo(json.dumps(reports[0] if len(reports) == 1 else reports, default=str))
        return
    if logs:
        raise AmheError("give either LOG or --target sim, not both")
    from amhe_cli.cli.plot import check_png_name
    truth = {"box_mass": 5.0, "box_friction": 0.45}
    truth.update(parse_truth(truth_pairs))
    record_path, out_path, plot_path = check_outputs(
        force, ("--record", record or "probe_sim.mcap"),
        ("--out", None if record_only else (out or "probe_sim.belief.yaml")),
        ("--plot", None if record_only else check_png_name(plot)))
    from amhe_cli.control.probing import simulate_probe
    from amhe_cli.io.writer import write_mcap
    if not (quiet or as_json):
        click.echo("simulating the lunge probe in the sim plant (a few seconds)", err=True)
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
        if plot_path is not None:
            s["plot"] = str(plot_path)
        click.echo(json.dumps(s))
        return
    print_summary(result, truth=truth_all)
    click.echo(f"belief written to {out_path}" + (f"; plot to {plot_path}" if plot_path else ""))


def _unit(label: str) -> str:
    """The unit of a parameter label (``box_inertia_0`` -> ``kg*m^2``; ``1`` -> ``-``)."""
    name = label if label in PARAMETERS else label.rpartition("_")[0]
    unit = PARAMETERS[name].unit if name in PARAMETERS else ""
    return "-" if unit in ("", "1") else unit


def _assess_log(log, chosen, free, prior, box_size, smooth, n_clips, horizon, seed, threads,
                as_json) -> tuple[dict, str]:
    """What one log can tell: (the JSON report, the text block with its identifiability table).

    A warning of the log's reader (a truncated log) is shown once: in the text's
    log summary, or on stderr with ``--json``.
    """
    from amhe_cli.estimation.probe import assess
    from amhe_cli.io.reader import inspect_log
    info = inspect_log(log, topics=chosen or None)
    if as_json:  # the text's log summary lists them otherwise
        for text in info.warnings:
            click.echo(f"amhe: warning: {text}", err=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem = load_problem(log, topics=chosen, params=free, prior=prior, box_size=parse_box_size(box_size),
                               smooth=smooth)
    for w in caught:  # the log's own warnings are already in ``info``: the others pass on
        if str(w.message) not in info.warnings:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    from amhe_cli.estimation.identify import clip_plan
    n_clips, horizon, _ = clip_plan(problem.traj, n_clips, horizon)
    curv = assess(problem.traj, problem.scene, problem.space, n_clips=n_clips, horizon=horizon, seed=seed,
                  nthread=threads)
    sp = problem.space
    report = {"log": info.to_dict(), "parameters": {}, "labels": sp.labels, "correlation": curv.corr.tolist(),
              "fisher": curv.fisher.tolist(), "cost_at_prior": curv.cost, "note": BEST_CASE_NOTE}
    prior_val, prior_sd = sp.physical(sp.mean0, sp.std0)
    _, post_sd = sp.physical(sp.mean0, curv.std)
    for i, label in enumerate(sp.labels):
        report["parameters"][label] = {"unit": _unit(label), "prior": float(prior_val[i]),
                                       "prior_std": float(prior_sd[i]), "std": float(post_sd[i]),
                                       "information_gain": float(prior_sd[i] / max(post_sd[i], 1e-12))}
    head = ("parameter", "unit", "prior", "prior σ", "best-case σ", "σ shrinks by")
    rows = [(label, rec["unit"], f"{rec['prior']:.4g}", f"{rec['prior_std']:.3g}", f"{rec['std']:.3g}",
             f"{rec['information_gain']:.3g}×") for label, rec in report["parameters"].items()]
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(len(head))]
    lines = [str(info), "",
             f"identifiability from {n_clips} clips of {horizon[0]:g}–{horizon[1]:g} s, at the prior "
             f"({problem.prior_source}):",
             "  ".join(h.ljust(w) if i < 2 else h.rjust(w) for i, (h, w) in enumerate(zip(head, widths)))]
    lines += ["  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))
              for r in rows]
    if "box_mass" in sp.labels and "box_friction" in sp.labels:
        i, j = sp.labels.index("box_mass"), sp.labels.index("box_friction")
        lines.append(f"mass-friction correlation {curv.corr[i, j]:+.2f}")
    lines.append(textwrap.fill(BEST_CASE_NOTE, 100))
    return report, "\n".join(lines)
