"""The ``amhe`` command line: identify, probe (and, later, mhe-replay, run).

Every user-facing problem raises :class:`~amhe_cli.errors.AmheError`; :func:`main`
prints it as one line ``amhe: error: …`` on stderr and exits with status 2,
without a traceback. Warnings (a truncated log, a dropped message) print as
``amhe: warning: …``.
"""

from __future__ import annotations

import json
import sys
import warnings
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from . import __version__
from .belief import Belief
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
    f = click.option("--smooth", default=0, show_default=True, type=click.IntRange(0, 200),
                     help="Moving-average samples for velocities differentiated from poses (noisy mocap).")(f)
    return f


def _out_path(out: str | None, log: str, suffix: str, force: bool) -> Path:
    path = Path(out) if out else Path.cwd() / (Path(log).name.split(".")[0] + suffix)
    if path.exists() and not force:
        raise AmheError(f"{path} already exists: pass --force to overwrite it, or choose another --out")
    if not path.parent.exists():
        raise AmheError(f"--out {path}: folder {path.parent} does not exist")
    return path


def _progress(total: int, desc: str, quiet: bool):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="gen", file=sys.stderr, disable=True if quiet else None, leave=False,
                bar_format="{desc}: {n_fmt}/{total_fmt} gen |{bar}| {elapsed} {postfix}")


def _fmt(v) -> str:
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    return f"{v:.4g}"


def belief_from_result(result: IdentifyResult, problem: Problem, command: str, log: str) -> Belief:
    """A :class:`Belief` holding an identification result and its provenance."""
    s = result.summary()
    values = problem.space.values(result.estimate)
    values = {n: (v if np.isscalar(v) else [float(x) for x in v]) for n, v in values.items()}
    return Belief(
        values=values, std=s["std"], free=list(problem.space.free), labels=s["labels"],
        correlation=s["correlation"], cost=s["cost"], scene=problem.scene.config.to_dict(),
        provenance={
            "command": command, "amhe_version": __version__, "log": str(log),
            "sha256": problem.traj.meta.get("sha256"), "topics": problem.traj.meta.get("topics"),
            "prior": problem.prior_source, "settings": settings_dict(result.settings),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "wall_time_s": round(result.wall_time, 2), "evaluations": result.evaluations,
            "clips": len(result.clips), "generations": len(result.history),
        },
    )


def print_summary(result: IdentifyResult, truth: dict | None = None) -> None:
    """A small results table on stdout (rich if available, else plain)."""
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
@click.option("--params", default=None, metavar="NAMES",
              help=f"Free parameters, comma-separated, from: {', '.join(PARAMETERS)}. "
                   "Default: box_mass,box_inertia,box_friction.")
@click.option("--prior", type=click.Path(), default=None, help="Belief YAML to start from (its values and stds).")
@click.option("--clips", "n_clips", default=32, show_default=True, type=click.IntRange(1, 10000),
              help="Number of clips N_c.")
@click.option("--horizon", default="0.1,0.2", show_default=True, metavar="MIN,MAX",
              help="Clip horizon range [s], drawn uniformly.")
@click.option("--popsize", default=16, show_default=True, type=click.IntRange(2, 10000),
              help="CMA-ES candidates per generation (B).")
@click.option("--generations", default=50, show_default=True, type=click.IntRange(1, 100000),
              help="CMA-ES generation limit.")
@click.option("--prior-weight", default=1.0, show_default=True, type=click.FloatRange(0),
              help="Scale of the prior term W_p (0 disables it).")
@click.option("--t-range", default=None, metavar="T0,T1", help="Use only this part of the log [s].")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed for clip selection and CMA-ES.")
@click.option("--threads", default=None, type=click.IntRange(1, 1024), help="Rollout threads (default: all CPUs).")
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
    from .plot import check_plot_path, plot_identify
    if log is None:
        logs = example_logs()
        if not logs:
            raise AmheError("no LOG given and no bundled example found: expected 'amhe identify LOG'")
        log = str(logs[0])
        if not as_json:
            click.echo(f"no LOG given: using the bundled example {Path(log).name}", err=True)
    free = parse_names(params)
    hr = _parse_range(horizon, "--horizon")
    if hr[0] <= 0:
        raise AmheError(f"--horizon {horizon}: expected positive seconds")
    tr = _parse_range(t_range, "--t-range") if t_range else None
    out_path = _out_path(out, log, ".belief.yaml", force)
    plot_path = check_plot_path(plot)
    problem = load_problem(log, topics=parse_topics(topics, map_file), params=free, prior=prior,
                           box_size=parse_box_size(box_size), smooth=smooth)
    settings = IdentifySettings(params=free, n_clips=n_clips, horizon=hr, popsize=popsize, max_gen=generations,
                                prior_weight=prior_weight, seed=seed, t_range=tr)
    result = run_identify(problem, settings, quiet or as_json, threads)
    belief = belief_from_result(result, problem, "identify", log)
    belief.save(out_path, force=force)
    if plot_path is not None:
        from .clips import Clips  # noqa: F401  (documented type of result.clips)
        from .cost import RolloutCost
        with RolloutCost(problem.scene, problem.space, result.clips, nthread=threads) as cost:
            plot_identify(plot_path, result, cost.rollout)
    if as_json:
        s = result.summary()
        s["belief"] = str(out_path)
        if plot_path is not None:
            s["plot"] = str(plot_path)
        click.echo(json.dumps(s))
        return
    click.echo(f"log {log}: {len(problem.traj) * problem.traj.dt:.1f} s, box floor z={problem.scene.config.floor_height:+.3f} m, "
               f"robot floor z={problem.scene.config.robot_floor_height:+.3f} m")
    print_summary(result)
    click.echo(f"belief written to {out_path}" + (f"; plot to {plot_path}" if plot_path else ""))


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
