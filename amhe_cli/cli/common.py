"""What the subcommands share: log and identification options, output paths, progress, the results table.

Every user-facing problem raises :class:`~amhe_cli.errors.AmheError`; the
entry point (:func:`amhe_cli.cli.main`) prints it as one line.
"""

from __future__ import annotations

import sys
from datetime import datetime, timezone
from pathlib import Path

import click
import numpy as np

from amhe_cli import __version__
from amhe_cli.errors import AmheError
from amhe_cli.estimation.belief import Belief
from amhe_cli.estimation.identify import IdentifyResult, IdentifySettings, identify, settings_dict
from amhe_cli.estimation.problem import Problem
from amhe_cli.model.params import PARAMETERS, parse_names


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
    hr = parse_range(horizon, "--horizon")
    if hr[0] <= 0:
        raise AmheError(f"--horizon {horizon}: expected positive seconds")
    tr = parse_range(t_range, "--t-range") if t_range else None
    return IdentifySettings(params=parse_names(params), n_clips=n_clips, horizon=hr, popsize=popsize,
                            max_gen=generations, prior_weight=prior_weight, seed=seed, t_range=tr)


def output_path(out: str | None, log: str, suffix: str, force: bool) -> Path:
    """Where an output goes: ``out``, or ``<log stem><suffix>`` in the working directory.

    Raises:
        AmheError: the file exists and ``force`` is not set, or its folder does not exist.
    """
    name = Path(log.rstrip("/")).name
    stem = Path(name).stem if Path(name).suffix in (".mcap", ".bag", ".db3", ".yaml") else name
    path = Path(out) if out else Path.cwd() / (stem + suffix)
    if path.exists() and not force:
        raise AmheError(f"{path} already exists: pass --force to overwrite it, or choose another --out")
    if not path.parent.exists():
        raise AmheError(f"--out {path}: folder {path.parent} does not exist")
    return path


def progress_bar(total: float, desc: str, quiet: bool, counter: str = "{n_fmt}/{total_fmt} gen"):
    """A progress bar on stderr (off with --quiet/--json, and when stderr is not a terminal)."""
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=True if quiet else None, leave=False,
                bar_format="{desc}: " + counter + " |{bar}| {elapsed} {postfix}")


def fmt(v) -> str:
    """A number or a short vector in 4 significant digits."""
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
        row = [name, unit, fmt(s["prior"][name]), fmt(s["estimate"][name]), fmt(s["std"][name])]
        if truth is not None:
            row.append(fmt(truth[name]) if name in truth else "-")
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
    bar = progress_bar(settings.max_gen, "identify", quiet)
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
        from amhe_cli.estimation.cost import RolloutCost
        from amhe_cli.cli.plot import plot_identify
        with RolloutCost(problem.scene, problem.space, result.clips, nthread=threads) as cost:
            plot_identify(plot_path, result, cost.rollout, problem.traj)


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


def load_belief(path: str | None) -> Belief | None:
    """The belief YAML at ``path`` (None: no belief)."""
    return None if path is None else Belief.load(path)


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


def parse_range(text: str, flag: str) -> tuple[float, float]:
    """``"a,b"`` -> (a, b) with a <= b; AmheError naming ``flag`` otherwise."""
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise AmheError(f"{flag} {text!r}: expected two numbers MIN,MAX") from None
    if not a <= b:
        raise AmheError(f"{flag} {text!r}: expected MIN <= MAX")
    return a, b


def parse_xy(text: str, flag: str) -> tuple[float, float]:
    """``"x,y"`` -> (x, y) finite floats; AmheError naming ``flag`` otherwise."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise AmheError(f"{flag} {text!r}: expected two numbers X,Y") from None
    if not (np.isfinite(x) and np.isfinite(y)):
        raise AmheError(f"{flag} {text!r}: expected finite numbers")
    return x, y
