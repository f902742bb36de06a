"""The ``amhe`` command line: identify, probe, mhe-replay, run, evaluate.

Every user-facing problem raises :class:`~amhe_cli.errors.AmheError`; :func:`main`
prints it as one line ``amhe: error: …`` on stderr and exits with status 2,
without a traceback. Warnings (a truncated log, a dropped message) print as
``amhe: warning: …``.
"""

from __future__ import annotations

import json
import sys
from csv import writer as csv_writer
import warnings
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from . import __version__
from .belief import Belief
from .closed_loop import MODES
from .errors import AmheError
from .identify import IdentifyResult, IdentifySettings, identify, settings_dict
from .params import PARAMETERS, parse_names
from .problem import Problem, example_logs, load_problem, parse_box_size, parse_topics

# -- shared options ------------------------------------------------------------

def log_options(f):
    """Options every log-reading subcommand shares (evo-style)."""
    f = click.option("--topic", "topics", multiple=True, metavar="ROLE=TOPIC",
                     help="Use TOPIC for ROLE (joint_states, base, box, joint_commands, gains). Repeatable.")(f)
    f = click.option("--map", "map_file", type=click.Path(), default=None,
                     help="YAML file of role: topic.")(f)
    f = click.option("--box-size", default=None, metavar="EDGE|X,Y,Z",
                     help="Box edge length(s) [m]; default 0.38 m cube.")(f)
    f = click.option("--smooth", default="auto", show_default=True, metavar="auto|0|N",
                     help="Pose smoothing: auto (only where noise shows), 0 (off) or an N-sample window.")(f)
    return f


def identify_options(f):
    """Options of the CMA-ES identification, shared by ``identify`` and ``probe``."""
    opts = [
        click.option("--params", default=None, metavar="NAMES",
                     help=f"Free parameters, comma-separated, from: {', '.join(PARAMETERS)}. "
                          "Default: box_mass,box_inertia,box_friction."),
        click.option("--prior", type=click.Path(), default=None,
                     help="Belief YAML to start from (its values and stds)."),
        click.option("--clips", "n_clips", default=32, show_default=True, type=click.IntRange(1, 10000),
                     help="Number of clips N_c."),
        click.option("--horizon", default="0.1,0.2", show_default=True, metavar="MIN,MAX",
                     help="Clip horizon range [s], drawn uniformly."),
        click.option("--popsize", default=12, show_default=True, type=click.IntRange(2, 10000),
                     help="CMA-ES candidates per generation (B)."),
        click.option("--generations", default=40, show_default=True, type=click.IntRange(1, 100000),
                     help="CMA-ES generation limit (it stops earlier once converged)."),
        click.option("--prior-weight", default=1.0, show_default=True, type=click.FloatRange(0),
                     help="Scale of the prior term W_p (0 disables it)."),
        click.option("--seed", default=0, show_default=True, type=int, help="Seed for clips, CMA-ES and the sim."),
        click.option("--threads", default=None, type=click.IntRange(1, 1024),
                     help="Rollout threads (default: all CPUs)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed,
                  t_range=None) -> IdentifySettings:
    """:class:`IdentifySettings` from the shared options (validated)."""
    hr = _parse_range(horizon, "--horizon")
    if hr[0] <= 0:
        raise AmheError(f"--horizon {horizon}: expected positive seconds")
    tr = _parse_range(t_range, "--t-range") if t_range else None
    return IdentifySettings(params=parse_names(params), n_clips=n_clips, horizon=hr, popsize=popsize,
                            max_gen=generations, prior_weight=prior_weight, seed=seed, t_range=tr)


def _out_path(out: str | None, log: str, suffix: str, force: bool) -> Path:
    name = Path(log.rstrip("/")).name
    stem = Path(name).stem if Path(name).suffix in (".mcap", ".bag", ".db3", ".yaml") else name
    path = Path(out) if out else Path.cwd() / (stem + suffix)
    if path.exists() and not force:
        raise AmheError(f"{path} already exists: pass --force to overwrite it, or choose another --out")
    if not path.parent.exists():
        raise AmheError(f"--out {path}: folder {path.parent} does not exist")
    return path


def _progress(total: float, desc: str, quiet: bool, counter: str = "{n_fmt}/{total_fmt} gen"):
    """A progress bar on stderr (off with --quiet/--json, and when stderr is not a terminal)."""
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=True if quiet else None, leave=False,
                bar_format="{desc}: " + counter + " |{bar}| {elapsed} {postfix}")


def _fmt(v) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    return f"{v:.4g}"


def belief_from_result(result: IdentifyResult, problem: Problem, command: str, log: str) -> Belief:
    """A :class:`Belief` holding an identification result and its provenance."""
    return Belief.from_identify(
        result, problem.space, problem.scene.config,
        {
            "command": command, "amhe_version": __version__, "log": str(log),
            "sha256": problem.traj.meta.get("sha256"), "topics": problem.traj.meta.get("topics"),
            "prior": problem.prior_source, "settings": settings_dict(result.settings),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "wall_time_s": round(result.wall_time, 2), "evaluations": result.evaluations,
            "clips": len(result.clips), "generations": len(result.history),
        },
    )


def print_summary(result: IdentifyResult, truth: dict | None = None) -> None:
    """A small plain-text results table on stdout (prior, estimate, std, truth if known)."""
    s = result.summary()
    rows = []
    for name in result.space.free:
        unit = PARAMETERS[name].unit
        row = [name, unit, _fmt(s["prior"][name]), _fmt(s["estimate"][name]), _fmt(s["std"][name])]
        if truth is not None:
            row.append(_fmt(truth[name]) if name in truth else "-")
        rows.append(row)
    head = ["parameter", "unit", "prior", "estimate", "std"] + (["truth"] if truth is not None else [])
    widths = [max(len(str(r[i])) for r in rows + [head]) for i in range(len(head))]
    line = "  ".join(h.ljust(w) for h, w in zip(head, widths))
    click.echo(line)
    click.echo("-" * len(line))
    for r in rows:
        click.echo("  ".join(str(c).ljust(w) for c, w in zip(r, widths)))
    c = s["cost"]
    click.echo(f"\ncost J: prior {c['prior']:.4g} -> estimate {c['estimate']:.4g}; residual rms per step "
               f"{c['residual_rms']:.3g} ({'consistent with' if c['residual_rms'] < 3 else 'LARGER than'} the "
               f"W_x noise levels{'' if c['residual_rms'] < 3 else ': the model may not match the log'})")
    corr = np.array(s["correlation"])
    labels = s["labels"]
    if "box_mass" in labels and "box_friction" in labels:
        click.echo(f"mass-friction correlation {corr[labels.index('box_mass'), labels.index('box_friction')]:+.2f}")
    click.echo(f"{s['clips']} clips, {s['generations']} generations, {s['evaluations']} candidates, "
               f"{s['wall_time_s']:.1f} s")


def run_identify(problem: Problem, settings: IdentifySettings, quiet: bool, threads: int | None) -> IdentifyResult:
    """:func:`identify` with a progress bar on stderr."""
    bar = _progress(settings.max_gen, "identify", quiet)
    try:
        def tick(gen, best):
            bar.update(gen - bar.n)
            bar.set_postfix_str(f"J={best:.4g}")
        return identify(problem.traj, problem.scene, problem.space, settings, progress=tick, nthread=threads)
    finally:
        bar.close()


def save_outputs(problem: Problem, result: IdentifyResult, command: str, log: str, out_path: Path, force: bool,
                 plot_path: Path | None, threads: int | None, truth: dict | None = None) -> None:
    """Write the belief YAML (and the --plot PNG) of an identification."""
    belief = belief_from_result(result, problem, command, log)
    if truth is not None:
        belief.provenance["truth"] = truth
    belief.save(out_path, force=force)
    if plot_path is not None:
        from .cost import RolloutCost
        from .plot import plot_identify
        with RolloutCost(problem.scene, problem.space, result.clips, nthread=threads) as cost:
            plot_identify(plot_path, result, cost.rollout, problem.traj)


# -- the command group ---------------------------------------------------------

@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="amhe")
def cli():
    """Sampling-based system identification and adaptive MPC for a Go1 pushing a box.

    Identify a box's mass, inertia and box-floor friction from a recorded log
    (MCAP, rosbag2, ROS 1 bag), re-estimate them over a sliding window, probe
    for a first belief, and push boxes with an adaptive sampling MPC.
    """


@cli.command("identify")
@click.argument("log", required=False, type=click.Path())
@log_options
@identify_options
@click.option("--t-range", default=None, metavar="T0,T1", help="Use only this part of the log [s].")
@click.option("--out", default=None, type=click.Path(), help="Belief YAML to write (default: <log stem>.belief.yaml).")
@click.option("--force", is_flag=True, help="Overwrite an existing --out file.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the results and nothing else.")
@click.option("--plot", type=click.Path(), default=None, help="Write a PNG: cost over generations, recorded vs predicted box.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def identify_cmd(log, topics, map_file, box_size, smooth, params, prior, n_clips, horizon, popsize, generations,
                 prior_weight, t_range, seed, threads, out, force, as_json, plot, quiet):
    """Identify box mass, inertia and box-floor friction from LOG (SPI-style CMA-ES).

    With no LOG, runs on the bundled example log.
    """
    from .plot import check_plot_path
    if log is None:
        logs = example_logs()
        if not logs:
            raise AmheError("no LOG given and no bundled example found: expected 'amhe identify LOG'")
        log = str(logs[0])
        if not as_json:
            click.echo(f"no LOG given: using the bundled example {Path(log).name}", err=True)
    settings = make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed, t_range)
    smooth = parse_smooth(smooth)
    out_path = _out_path(out, log, ".belief.yaml", force)
    plot_path = check_plot_path(plot)
    problem = load_problem(log, topics=parse_topics(topics, map_file), params=settings.params, prior=prior,
                           box_size=parse_box_size(box_size), smooth=smooth)
    result = run_identify(problem, settings, quiet or as_json, threads)
    save_outputs(problem, result, "identify", log, out_path, force, plot_path, threads)
    if as_json:
        s = result.summary()
        s["belief"] = str(out_path)
        if plot_path is not None:
            s["plot"] = str(plot_path)
        click.echo(json.dumps(s))
        return
    click.echo(f"log {log}: {len(problem.traj) * problem.traj.dt:.1f} s, box floor z={problem.scene.config.floor_height:+.3f} m, "
               f"robot floor z={problem.scene.config.robot_floor_height:+.3f} m")
    from .probe import metadata_truth
    print_summary(result, truth=metadata_truth(problem.traj))
    click.echo(f"belief written to {out_path}" + (f"; plot to {plot_path}" if plot_path else ""))


def parse_truth(pairs: tuple[str, ...]) -> dict:
    """``("box_mass=5", "box_inertia=0.1,0.1,0.12")`` -> {name: value}.

    Raises:
        AmheError: unknown name or a value that is not numbers.
    """
    truth = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        name = name.strip()
        if not sep or name not in PARAMETERS:
            raise AmheError(f"--truth {pair!r}: expected NAME=VALUE with NAME one of {', '.join(PARAMETERS)}")
        try:
            vals = [float(x) for x in text.split(",")]
        except ValueError:
            raise AmheError(f"--truth {pair!r}: expected numbers after '='") from None
        if len(vals) != PARAMETERS[name].size or not all(np.isfinite(vals)):
            raise AmheError(f"--truth {pair!r}: {name} takes {PARAMETERS[name].size} finite value(s)")
        lo, hi = PARAMETERS[name].lower, PARAMETERS[name].upper
        if any(v < a or v > b for v, a, b in zip(vals, lo, hi)):
            raise AmheError(f"--truth {pair!r}: outside the bounds {lo}..{hi} of {name}")
        truth[name] = vals[0] if len(vals) == 1 else vals
    return truth


@cli.command("probe")
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
    from .io.reader import inspect_log
    from .probe import TRUTH_RECORD, assess, simulate_probe
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
    record_path = _out_path(record or "probe_sim.mcap", "probe_sim", "", force)
    out_path = None if record_only else _out_path(out or "probe_sim.belief.yaml", "probe_sim", "", force)
    from .plot import check_plot_path
    plot_path = check_plot_path(plot)
    from .io.writer import write_mcap
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


@cli.command("mhe-replay")
@click.argument("log", type=click.Path())
@log_options
@click.option("--params", default="box_mass,box_friction", show_default=True, metavar="NAMES",
              help=f"Free parameters, from: {', '.join(PARAMETERS)} (an unfree inertia follows the mass).")
@click.option("--prior", type=click.Path(), default=None, help="Belief YAML (from identify or probe) to start from.")
@click.option("--window", default=1.0, show_default=True, type=float, help="Window H [s].")
@click.option("--every", default=0.5, show_default=True, type=float, help="Update period Δt_update [s].")
@click.option("--iters", default=3, show_default=True, type=int, help="Iterations L_MHE per update.")
@click.option("--samples", default=10, show_default=True, type=int, help="Candidates B per iteration.")
@click.option("--alpha", default=0.8, show_default=True, type=float, help="Learning rate α.")
@click.option("--clip", default=0.1, show_default=True, type=float,
              help="Clip length [s] the window is cut into (reset to recorded states); 0 = one piece.")
@click.option("--max-steps", default=150, show_default=True, type=int,
              help="Simulated steps per candidate per update (most informative clips first).")
@click.option("--realtime", is_flag=True, help="Replay on the live clock: estimates usable only after their compute.")
@click.option("--truth", "truth_csv", type=click.Path(), default=None,
              help="Ground-truth CSV (default: <log stem>.truth.csv beside the log, if any).")
@click.option("--sweep", default=None, metavar="NAME=V1,V2,…",
              help="Ablation: rerun for each value of one setting (window, every, iters, samples, alpha, clip, max_steps).")
@click.option("--seeds", default=1, show_default=True, type=click.IntRange(1, 1000), help="Seeds per sweep value.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--threads", default=None, type=click.IntRange(1, 1024))
@click.option("--out", default=None, type=click.Path(), help="Estimates CSV (default: <log stem>.mhe.csv).")
@click.option("--mcap", "mcap_out", default=None, type=click.Path(),
              help="Also write the estimates to this MCAP on /amhe/estimate (Float64MultiArray).")
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object and nothing else.")
@click.option("--plot", type=click.Path(), default=None, help="PNG: each parameter over time, ±1σ, truth.")
@click.option("--quiet", "-q", is_flag=True)
def mhe_replay_cmd(log, topics, map_file, box_size, smooth, params, prior, window, every, iters, samples, alpha,
                   clip, max_steps, realtime, truth_csv, sweep, seeds, seed, threads, out, mcap_out, force, as_json,
                   plot, quiet):
    """Track box parameters over LOG with the sliding-window estimator (paper §IV-A, eq. 4)."""
    from .mhe import MHESettings, MovingHorizonEstimator
    from .plot import check_plot_path, plot_estimates
    from .replay import estimates_table, replay, tracking_error, truth_series
    settings = MHESettings(window=window, every=every, iters=iters, samples=samples, alpha=alpha,
                           clip=clip if clip > 0 else None, max_steps=max_steps, seed=seed)
    settings.check()
    free = parse_names(params)
    smooth = parse_smooth(smooth)
    plot_path = check_plot_path(plot)
    if sweep is None:
        out_path = _out_path(out, log, ".mhe.csv", force)
        mcap_path = _out_path(mcap_out, log, ".mhe.mcap", force) if mcap_out else None
    problem = load_problem(log, topics=parse_topics(topics, map_file), params=free, prior=prior,
                           box_size=parse_box_size(box_size), smooth=smooth)
    if settings.window > problem.traj.duration:
        raise AmheError(f"--window {settings.window} s is longer than the log ({problem.traj.duration:.2f} s)")
    truth = truth_series(log, problem.traj, truth_csv)
    if truth_csv and truth is None:
        raise AmheError(f"--truth {truth_csv}: expected a CSV with a 't' column and truth columns")

    def run_one(st: MHESettings):
        bar = _progress(round(problem.traj.duration, 2), "mhe-replay", quiet or as_json,
                        counter="{n:.1f}/{total:.1f} s of log")
        with MovingHorizonEstimator(problem.scene, problem.space, st, nthread=threads) as mhe:
            res = replay(problem.traj, mhe, realtime=realtime, progress=lambda t: bar.update(t - bar.n))
        bar.close()
        return res

    if sweep is not None:
        name, sep, vals = sweep.partition("=")
        if not sep or name not in ("window", "every", "iters", "samples", "alpha", "clip", "max_steps"):
            raise AmheError(f"--sweep {sweep!r}: expected NAME=V1,V2,… with NAME one of window, every, iters, "
                            "samples, alpha, clip, max_steps")
        try:
            values = [float(v) for v in vals.split(",")]
        except ValueError:
            raise AmheError(f"--sweep {sweep!r}: expected numbers after '='") from None
        rows = []
        for v in values:
            errs, times = [], []
            for k in range(seeds):
                st = MHESettings(**{**settings.to_dict(), name: (int(v) if name in ("iters", "samples", "max_steps")
                                                               else (v if not (name == "clip" and v == 0) else None)),
                                    "seed": seed + k})
                st.check()
                res = run_one(st)
                errs.append(tracking_error(problem.space, res, truth) if truth else {})
                times.append(res.compute_time / max(len(res.updates), 1))
            row = {"value": v, "update_s": (float(np.mean(times)), float(np.std(times)))}
            for key in ("box_mass", "box_friction"):
                e = [x[key] for x in errs if key in x]
                if e:
                    row[key] = (float(np.mean(e)), float(np.std(e)))
            rows.append(row)
        if as_json:
            click.echo(json.dumps({"sweep": name, "seeds": seeds, "rows": rows}))
            return
        click.echo(f"sweep of {name} over {seeds} seed(s); tracking error vs truth "
                   f"({'box_mass RMS %, box_friction RMS' if truth else 'no truth in this log'}), compute per update")
        click.echo(f"{name:>10}  {'mass err %':>16}  {'friction err':>18}  {'update s':>14}")
        for r in rows:
            m = r.get("box_mass")
            f = r.get("box_friction")
            click.echo(f"{r['value']:>10g}  {(f'{m[0]:6.2f} ± {m[1]:5.2f}' if m else '-'):>16}  "
                       f"{(f'{f[0]:.4f} ± {f[1]:.4f}' if f else '-'):>18}  "
                       f"{r['update_s'][0]:6.3f} ± {r['update_s'][1]:5.3f}")
        return

    res = run_one(settings)
    head, table = estimates_table(problem.space, res)
    with open(out_path, "w", newline="") as fh:
        w = csv_writer(fh)
        w.writerow(head)
        w.writerows(table.tolist())
    if mcap_path is not None:
        from .io.writer import McapLog
        t0 = problem.traj.meta.get("t0_ns", 0) * 1e-9
        with McapLog(mcap_path, overwrite=force) as mlog:
            labels = head[1:]
            mlog.write_array("/amhe/estimate", table[:, 0] + t0, table[:, 1:], labels)
            mlog.write_metadata("amhe_mhe", {k: json.dumps(v) for k, v in settings.to_dict().items()})
    skipped = np.array([u.skipped for u in res.updates])
    if plot_path is not None:
        plot_estimates(plot_path, head, table, truth, skipped)
    errors = tracking_error(problem.space, res, truth) if truth else {}
    lags = res.lags
    summary = {
        "updates": len(res.updates), "informative_updates": int((~skipped).sum()),
        "final": {h: float(table[-1, i]) for i, h in enumerate(head) if i > 0} if len(table) else {},
        "realtime": res.realtime, "realtime_factor": res.realtime_factor, "behind": res.behind,
        "lag_s": {"mean": float(lags.mean()) if len(lags) else 0.0, "max": float(lags.max()) if len(lags) else 0.0},
        "tracking_error": errors, "csv": str(out_path),
    }
    if mcap_path is not None:
        summary["mcap"] = str(mcap_path)
    if plot_path is not None:
        summary["plot"] = str(plot_path)
    if as_json:
        click.echo(json.dumps(summary))
        return
    click.echo(f"{len(res.updates)} updates ({summary['informative_updates']} informative) over "
               f"{res.duration:.1f} s of log; compute {res.compute_time:.1f} s")
    for h, v in summary["final"].items():
        if not h.endswith("_std"):
            click.echo(f"  final {h} = {v:.4g} ± {summary['final'][h + '_std']:.2g}")
    if errors:
        click.echo("tracking error vs truth: " + ", ".join(
            f"{k} {v:.2f} %" if k == "box_mass" else f"{k} {v:.4f}" for k, v in errors.items()))
    if realtime:
        click.echo(f"realtime factor {res.realtime_factor:.2f}; {res.behind} update(s) fell behind; "
                   f"lag mean {lags.mean():.3f} s, max {lags.max():.3f} s")
    click.echo(f"estimates written to {out_path}" + (f", {mcap_path}" if mcap_path else "")
               + (f"; plot to {plot_path}" if plot_path else ""))


# -- run / evaluate --------------------------------------------------------------

def _load_belief(path: str | None) -> Belief | None:
    return None if path is None else Belief.load(path)


@cli.command("run")
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
    from .closed_loop import run_task, save_run
    from .evaluate import load_config, probe_belief, run_settings
    from .plot import check_plot_path, plot_run

    if target != "sim":
        raise AmheError("--target go1: driving a real Go1 is not supported by this version; use --target sim")
    task, settings = run_settings(task_name, mode, load_config(config), seed=seed, realtime=realtime,
                                  threads=threads, duration=duration)
    out_path = _out_path(out or f"run_{task.name}_{mode}_s{seed}.mcap", f"run_{task.name}", ".mcap", force)
    plot_path = check_plot_path(plot)
    start = _load_belief(belief)
    if start is None and mode != "true":
        if not (quiet or as_json):
            click.echo("no --belief: probing in the sim with the task's starting box first", err=True)
        bar = _progress(40, "probe+identify", quiet or as_json)
        try:
            start = probe_belief(task, seed=seed, threads=threads, progress=lambda g, b: bar.update(g - bar.n))
        finally:
            bar.close()
        if not (quiet or as_json):
            click.echo("starting belief: " + ", ".join(f"{k} {_fmt(v)}" for k, v in start.values.items()
                                                      if k in ("box_mass", "box_friction")), err=True)
    bar = _progress(task.duration, f"{task.name} {mode}", quiet or as_json, counter="{n:.1f}/{total:.0f} s")
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


@cli.command("evaluate")
@click.option("--task", "task_name", default="t4", show_default=True)
@click.option("--seeds", default=15, show_default=True, type=int)
@click.option("--modes", default="true,baseline,adaptive", show_default=True)
@click.option("--belief", default=None, type=click.Path(), help="Starting belief of baseline/adaptive (default: probe in sim once).")
@click.option("--config", default=None, type=click.Path(), help="Run config YAML (as for run).")
@click.option("--duration", default=None, type=float, help="Time limit per run [s].")
@click.option("--workers", default=None, type=int, help="Worker processes (default: all CPUs).")
@click.option("--out", default=None, type=click.Path(), help="CSV of per-run rows (default: evaluate_<task>.csv).")
@click.option("--force", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the summary table as JSON.")
@click.option("--quiet", "-q", is_flag=True)
def evaluate_cmd(task_name, seeds, modes, belief, config, duration, workers, out, force, as_json, quiet):
    """Run modes × seeds of a task in parallel and print the paper's Table I layout."""
    from .evaluate import evaluate, load_config, probe_belief, run_settings, summarise

    mode_list = [m.strip() for m in modes.split(",") if m.strip()]
    if seeds < 1:
        raise AmheError(f"--seeds {seeds}: expected at least 1")
    cfg = load_config(config)
    task, _ = run_settings(task_name, mode_list[0] if mode_list else "true", cfg, duration=duration)
    out_path = _out_path(out or f"evaluate_{task.name}.csv", f"evaluate_{task.name}", ".csv", force)
    start = _load_belief(belief)
    if start is None and set(mode_list) - {"true"}:
        if not (quiet or as_json):
            click.echo("no --belief: probing in the sim once for the baseline/adaptive starting belief", err=True)
        start = probe_belief(task, seed=0)
    bar = _progress(seeds * len(mode_list), f"evaluate {task.name}", quiet or as_json, counter="{n_fmt}/{total_fmt} runs")
    try:
        rows = evaluate(task.name, mode_list, seeds, start, cfg, workers, duration, progress=lambda r: bar.update(1))
    finally:
        bar.close()
    keys = ["task", "mode", "seed", "success", "e_g", "J", "t_exec", "rmse", "fell", "control_hz"]
    with open(out_path, "w", newline="") as fh:
        w = csv_writer(fh)
        w.writerow(keys)
        w.writerows([[r[k] for k in keys] for r in rows])
    table = summarise(rows, mode_list)
    if as_json:
        click.echo(json.dumps({"task": task.name, "seeds": seeds, "rows": table, "csv": str(out_path)}))
        return
    click.echo(f"{task.name}, {seeds} seed(s) per mode (mean ± std)")
    click.echo(f"{'mode':>10}  {'S_R %':>6}  {'e_g [m]':>15}  {'J':>15}  {'t_exec [s]':>15}")
    for r in table:
        click.echo(f"{r['mode']:>10}  {r['S_R']:6.1f}  {r['e_g'][0]:7.3f} ± {r['e_g'][1]:5.3f}  "
                   f"{r['J'][0]:7.2f} ± {r['J'][1]:5.2f}  {r['t_exec'][0]:7.1f} ± {r['t_exec'][1]:5.1f}")
    click.echo(f"per-run rows: {out_path}")


def parse_smooth(text: str) -> int | str:
    """``--smooth`` value: ``"auto"`` or a non-negative sample count."""
    if text == "auto":
        return text
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise AmheError(f"--smooth {text!r}: expected 'auto', 0 (off) or a window in samples")
    return n


def _parse_range(text: str, flag: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise AmheError(f"{flag} {text!r}: expected two numbers MIN,MAX") from None
    if not a <= b:
        raise AmheError(f"{flag} {text!r}: expected MIN <= MAX")
    return a, b


def main(argv=None) -> None:
    """Console entry point: runs :func:`cli`, turning AmheError into one line and exit 2."""
    def show_warning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"amhe: warning: {message}", err=True)
    warnings.showwarning = show_warning
    try:
        cli.main(args=argv, prog_name="amhe", standalone_mode=False)
    except AmheError as e:
        click.echo(f"amhe: error: {e}", err=True)
        sys.exit(2)
    except click.exceptions.Abort:
        click.echo("amhe: aborted", err=True)
        sys.exit(130)
    except click.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        click.echo("amhe: interrupted", err=True)
        sys.exit(130)
    except OSError as e:
        click.echo(f"amhe: error: {e.strerror or e}: {getattr(e, 'filename', '') or ''}".rstrip(": "), err=True)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
