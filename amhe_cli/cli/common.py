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
from amhe_cli.model.params import INERTIA_RATIO_STD, PARAMETERS, ROBOT_PARAMETERS, parse_names
from amhe_cli.model.scene import SceneConfig


def nominal_prior_text() -> str:
    """The default prior in words, read from the code (the nominal box of
    :class:`~amhe_cli.model.scene.SceneConfig` and the parameters' prior σ), for ``--prior`` help."""
    cfg, p = SceneConfig(), PARAMETERS
    return (f"the nominal box: mass {cfg.box_mass:g} kg (σ {p['box_mass'].prior_std[0]:g} kg), "
            f"box-floor μ {cfg.regions[0].mu:g} (σ {p['box_friction'].prior_std[0]:g}), "
            f"inertia of a uniform box of that mass and --box-size (σ {INERTIA_RATIO_STD:.0%})")


#: ``--task`` help of ``run`` and ``evaluate``: the tasks in one line each, T5's state said plainly.
TASK_HELP = ("Task (box 4 kg, μ 0.5 unless said): t1 push it 1.5 m straight ahead (40 s); t2 along a "
             "quarter circle of radius 1 m (60 s); t3 2.5 m straight, its mass becomes 6 kg at t = 10 s (60 s); "
             "t4 2 m straight, μ 0.4 then 0.8 past x = 1.5 m (60 s); t5 0.5 m sideways with the front-right foot, "
             "standing on three legs (20 s; the foot's reach ends about 0.15 m short). Success: the box ends "
             "within 0.2 m of the goal and the robot never falls.")
#: Said before a t5 run or evaluation.
T5_WARNING = ("task t5: the front-right foot's sweep ends where the leg's reach does, about 0.15 m short of "
              "the 0.5 m push (docs/tasks.md, the one-leg push)")


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


def _device_callback(ctx, param, value):
    from amhe_cli.model.device import set_default
    set_default(value)
    return value


#: ``--device``, once for every subcommand whose cost module rolls out candidates (identify, probe,
#: mhe-replay): where the rollouts of the shared cost run (amhe_cli.model.device, docs/gpu.md).
device_option = click.option(
    "--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]),
    callback=_device_callback, expose_value=False,
    help="Where rollouts run: cpu (mujoco.rollout on --threads), cuda (MuJoCo Warp; needs amhe[gpu] and a "
         "CUDA device), auto: cuda where both are present. The choice is printed once to stderr.")


def identify_options(f):
    """Options of the CMA-ES identification, shared by ``identify`` and ``probe``."""
    opts = [
        click.option("--params", default=None, metavar="NAMES",
                     help=f"Free parameters, comma-separated, from: {', '.join(PARAMETERS)}. "
                          "Default: box_mass,box_inertia,box_friction; identify adds robot_box_friction where "
                          "the log's robot is not its model (gains fitted from its efforts, or a trunk payload "
                          "fitted where the box rests)."),
        click.option("--prior", type=click.Path(), default=None,
                     help="Belief YAML to start from (its values and stds). Default: " + nominal_prior_text() + "."),
        click.option("--clips", "n_clips", default=None, type=click.IntRange(1, 10000),
                     help="Number of clips N_c. Default: 48 on a log whose box velocity holds no measurement "
                          "noise, 32 where it does (with --horizon's default, the same simulated time)."),
        click.option("--candidates", default=None, type=click.IntRange(1, 64),
                     help="Above 1: draw this many times N_c clips where the box moves and keep the N_c that "
                          "inform the free parameters most; 1: the draw by box motion alone. Default: 1 on a "
                          "clean log whose robot is found unlike its model (information read at a wrong model "
                          "points at the bumps, where the mismatch acts), 4 otherwise."),
        click.option("--horizon", default=None, metavar="MIN,MAX",
                     help="Clip horizon range [s], drawn uniformly. Default: 0.07,0.13 on a log whose box "
                          "velocity holds no measurement noise (a push is chaotic in the parameters, more so "
                          "the longer the clip), 0.1,0.2 where it does (a longer clip outweighs its noisy "
                          "initial velocity)."),
        click.option("--popsize", default=12, show_default=True, type=click.IntRange(2, 10000),
                     help="CMA-ES candidates per generation (B)."),
        click.option("--generations", default=IdentifySettings.max_gen, show_default=True, type=click.IntRange(1, 100000),
                     help="CMA-ES generation limit (it stops earlier once converged; stopping here first "
                          "gives a warning and \"converged\": false in --json)."),
        click.option("--prior-weight", default=1.0, show_default=True, type=click.FloatRange(0),
                     help="Scale of the prior term W_p (0 disables it)."),
        click.option("--seed", default=0, show_default=True, type=int, help="Seed for clips, CMA-ES and the sim."),
        click.option("--threads", default=None, type=click.IntRange(1, 1024),
                     help="Rollout threads (default: all CPUs)."),
        device_option,
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def make_settings(params, n_clips, horizon, popsize, generations, prior_weight, seed,
                  t_range=None, candidates: int | None = None, replicates: int = 1) -> IdentifySettings:
    """:class:`IdentifySettings` from the shared options (validated)."""
    hr = parse_range(horizon, "--horizon") if horizon is not None else None
    if hr is not None and hr[0] <= 0:
        raise AmheError(f"--horizon {horizon}: expected positive seconds")
    tr = parse_range(t_range, "--t-range") if t_range else None
    return IdentifySettings(params=parse_names(params), n_clips=n_clips, horizon=hr, popsize=popsize,
                            max_gen=generations, prior_weight=prior_weight, seed=seed, t_range=tr,
                            candidates=candidates, replicates=replicates)


def check_outputs(force: bool, *outputs: tuple[str, str | Path | None]) -> list[Path | None]:
    """The one overwrite rule of every subcommand: claim each file a command will write, before any work.

    Call it with every output (belief YAML, CSV, MCAP, PNG, truth CSV, estimates
    MCAP) right after parsing the options, so a refusal costs the user nothing.

    Args:
        force: ``--force`` was given: existing files may be replaced.
        outputs: ``(option, path)`` pairs naming where each output goes and the
            option that chose it (e.g. ``("--plot", "fit.png")``), used in the
            error; a ``None`` path (an output not asked for) is skipped.

    Returns:
        The paths as :class:`~pathlib.Path`, in order (``None`` kept).

    Raises:
        AmheError: a file exists and ``force`` is not set ("… already exists:
            pass --force to overwrite it, or choose another --plot"), a path is
            a folder, its folder does not exist, or two outputs share one path.
    """
    paths: list[Path | None] = []
    seen: dict[Path, str] = {}
    for flag, out in outputs:
        if out is None:
            paths.append(None)
            continue
        path = Path(out)
        if path.is_dir():
            raise AmheError(f"{flag} {path}: is a folder, expected a file name")
        if path.exists() and not force:
            raise AmheError(f"{path} already exists: pass --force to overwrite it, or choose another {flag}")
        if not path.parent.exists():
            raise AmheError(f"{flag} {path}: folder {path.parent} does not exist")
        key = path.resolve()
        if key in seen:
            raise AmheError(f"{flag} {path}: the same file as {seen[key]}; expected a different name")
        seen[key] = flag
        paths.append(path)
    return paths


def default_output(out: str | None, log: str, suffix: str) -> Path:
    """``out``, or ``<log stem><suffix>`` in the working directory (no checks: see :func:`check_outputs`)."""
    if out:
        return Path(out)
    name = Path(str(log).rstrip("/")).name
    stem = Path(name).stem if Path(name).suffix in (".mcap", ".bag", ".db3", ".yaml") else name
    return Path.cwd() / (stem + suffix)


def output_path(out: str | None, log: str, suffix: str, force: bool, flag: str = "--out") -> Path:
    """Where an output goes: ``out``, or ``<log stem><suffix>`` in the working directory, checked.

    Raises:
        AmheError: as :func:`check_outputs` (exists without ``force``, no such folder).
    """
    return check_outputs(force, (flag, default_output(out, log, suffix)))[0]


class LineProgress:
    """Progress as plain lines on a stream that is not a terminal (a log file, a CI job, a pipe).

    The subset of ``tqdm``'s interface the subcommands use (``n``, ``update``,
    ``set_postfix_str``, ``close``): a line ``desc: 12/40 gen, 15 s elapsed, J=…``
    at most every ``interval`` seconds, and a last one on :meth:`close` once any
    was printed.
    """

    def __init__(self, total: float, desc: str, unit: str = "", fmt_n: str = "{:g}",
                 interval: float = 5.0, file=None):
        import time
        self._clock = time.monotonic
        self.total, self.desc, self.unit, self.fmt_n, self.interval = total, desc, unit, fmt_n, interval
        self.file = file if file is not None else sys.stderr
        self.n = 0.0
        self.postfix = ""
        self.start = self._last = self._clock()
        self.printed = 0

    def _line(self) -> str:
        done = f"{self.fmt_n.format(self.n)}/{self.fmt_n.format(self.total)}{self.unit}"
        return (f"{self.desc}: {done}, {self._clock() - self.start:.0f} s elapsed"
                + (f", {self.postfix}" if self.postfix else ""))

    def update(self, k: float = 1) -> None:
        """Advance by ``k``; print a line when ``interval`` seconds passed since the last."""
        self.n += k
        now = self._clock()
        if now - self._last >= self.interval:
            self._last = now
            self.printed += 1
            print(self._line(), file=self.file, flush=True)

    def set_postfix_str(self, text: str) -> None:
        """Text appended to each line (e.g. ``J=1.23``)."""
        self.postfix = text

    def close(self) -> None:
        """Print the final count, if any line was printed before."""
        if self.printed:
            print(self._line() + " (done)", file=self.file, flush=True)
            self.printed = 0


def progress_bar(total: float, desc: str, quiet: bool, counter: str = "{n_fmt}/{total_fmt} gen",
                 interval: float = 5.0):
    """Progress on stderr: a tqdm bar on a terminal, a plain line every ``interval`` s otherwise.

    Args:
        total: the count or seconds at completion.
        desc: what is running (``identify``, ``t1 adaptive``).
        quiet: show nothing (``--quiet``, ``--json``).
        counter: tqdm's counter format; its unit word (``gen``, ``runs``,
            ``s of log``) is reused in the plain lines.
        interval: seconds between plain lines (not a terminal).

    Returns:
        An object with ``n``, ``update(k)``, ``set_postfix_str(text)`` and ``close()``.
    """
    from tqdm import tqdm
    if quiet:
        return tqdm(total=total, disable=True)
    if not (hasattr(sys.stderr, "isatty") and sys.stderr.isatty()):
        unit = counter.rsplit("}", 1)[-1]
        fmt_n = "{:.1f}" if ":.1f" in counter or ":.0f" in counter else "{:g}"
        return LineProgress(total, desc, unit=unit, fmt_n=fmt_n, interval=interval)
    return tqdm(total=total, desc=desc, file=sys.stderr, leave=False,
                bar_format="{desc}: " + counter + " |{bar}| {elapsed} {postfix}")


def fmt(v) -> str:
    """A number or a short vector in 4 significant digits."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    return f"{v:.4g}"


def belief_text(belief: Belief) -> str:
    """The box a belief holds, for the console: ``box_mass 4.05, box_friction 0.3959``."""
    return ", ".join(f"{k} {fmt(v)}" for k, v in belief.values.items() if k in ("box_mass", "box_friction"))


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
            "sensors": problem.traj.meta.get("sensors", {}),
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
    rms = c["residual_rms"]
    if not result.converged:
        verdict = "not judged: CMA-ES had not converged"
    elif rms < MISMATCH_RMS:
        verdict = "consistent with the W_x noise levels"
    else:
        verdict = "LARGER than the W_x noise levels: the model may not match the log"
    click.echo(f"\ncost J: prior {c['prior']:.4g} -> estimate {c['estimate']:.4g}; residual rms per step "
               f"{rms:.3g} ({verdict})")
    corr = np.array(s["correlation"])
    labels = s["labels"]
    if "box_mass" in labels and "box_friction" in labels:
        click.echo(f"mass-friction correlation {corr[labels.index('box_mass'), labels.index('box_friction')]:+.2f}")
    chosen = (f" (the most informative of {result.settings.candidates}× as many)"
              if result.settings.candidates > 1 else "")
    click.echo(f"{s['clips']} clips{chosen}, {s['generations']} generations"
               f"{'' if result.converged else ' (stopped by --generations, not converged)'}, "
               f"{s['evaluations']} candidates, {s['wall_time_s']:.1f} s")
    if s["replicates"]:
        rep = s["std_sources"]["replicates"]
        spread = ", ".join(f"{n} ± {fmt(rep[n])}" for n in ("box_mass", "box_friction") if n in rep)
        click.echo(f"{len(s['replicates'])} bootstrap replicate searches (clips resampled): spread {spread} "
                   f"(std_sources.replicates in --json)")


def sensor_lines(meta: dict) -> list[str]:
    """What the reader measured about the log's sensors (``meta["sensors"]``), one line per stream and finding."""
    sens = meta.get("sensors", {})
    lines = []
    for role, st in sens.get("streams", {}).items():
        if "rate_hz" not in st:
            continue
        parts = [f"{st['rate_hz']:.4g} Hz", f"{100 * st['dropped_fraction']:.1f} % dropped",
                 f"jitter {st['jitter_ms']:.2g} ms"]
        if st.get("latency_ms") is not None:
            parts.append(f"latency {st['latency_ms']:.2g} ms")
        if "position_noise_m" in st:
            parts.append(f"noise {st['position_noise_m'] * 1e3:.2g} mm / {st['orientation_noise_rad'] * 1e3:.2g} mrad")
        elif "joint_noise_rad" in st:
            parts.append(f"noise {st['joint_noise_rad'] * 1e3:.2g} mrad")
        lines.append(f"{role}: " + ", ".join(parts))
    off = sens.get("time_offset")
    if off:
        lines.append(f"pose streams lag the joint states by {off['pose_stamp_lag_s'] * 1e3:+.1f} ms"
                     + (" (corrected)" if off["applied"] else " (within 3 ms: left)"))
    gains = sens.get("gains")
    if gains:
        kp, kd = np.asarray(gains["kp"]), np.asarray(gains["kd"])
        lines.append(f"servo gains fitted from the efforts: Kp {kp.min():.3g}–{kp.max():.3g}, Kd {kd.min():.3g}–{kd.max():.3g}"
                     f" ({'used instead of the logged ones' if gains['used'] == 'fitted' else 'agree with the log'})")
    payload = sens.get("payload")
    if payload:
        if payload.get("trunk_payload_kg") is None:
            lines.append(f"trunk payload: {payload['note']}")
        else:
            lines.append(f"trunk payload fitted on {payload['clips']} clips where the box rests: "
                         f"{payload['trunk_payload_kg']:+.3f} ± {payload['std_kg']:.3f} kg "
                         f"({'modelled' if payload['applied'] else 'not told from none: the robot is its model'})")
    return lines


def not_converged_warning(result: IdentifyResult) -> str | None:
    """The warning for an identification the generation limit stopped before CMA-ES converged, else None."""
    if result.converged:
        return None
    where = ""
    if result.unsettled:
        lo, hi = min(result.unsettled.values()), max(result.unsettled.values())
        span = f"{lo:.1f}×" if hi - lo < 0.05 else f"{lo:.1f}–{hi:.1f}×"
        labels = result.space.labels
        names = [n for n, sl in result.space.slices().items()
                 if any(labels[i] in result.unsettled for i in range(sl.start, sl.stop))]
        where = f", its search along {', '.join(names)} still {span} wider than the log's own σ"
    return (f"CMA-ES stopped at the generation limit ({result.settings.max_gen}){where}: that spread is in the "
            "stated σ and the residual is not judged; more --generations narrow it (docs/benchmarks.md: a "
            "narrower σ misses a log's bias more often)")


#: Residual rms per step (in ``W_x`` σ's) from which an identification's model is taken not to match its log.
MISMATCH_RMS = 3.0


def mismatch_warning(result: IdentifyResult) -> str | None:
    """What to do when the converged residual says the model does not match the log, else None.

    The residual rms ≫ 1 flag (docs/reference.md: ≈ 1e-7 cost with a matching model,
    1e-6 … 1e-4 with a mismatched one) turned into the step a user can take: free
    the robot-side parameters not yet free, and ask ``probe`` which the log tells apart.
    """
    if not result.converged or result.residual_rms < MISMATCH_RMS:
        return None
    free = list(result.settings.params)
    more = [p for p in ROBOT_PARAMETERS if p not in free]
    text = (f"the residual ({result.residual_rms:.3g} per step, in W_x noise levels) says the model does not "
            "match the log, so the estimate may be biased")
    if more:
        names = ",".join(free + more)
        text += (f": if the robot differs from its model (shell, payload, servo), free its side with --params "
                 f"{names}; 'amhe probe LOG --params {names}' shows which of them this log can tell apart")
    return text


def run_identify(problem: Problem, settings: IdentifySettings, quiet: bool, threads: int | None,
                 desc: str = "identify") -> IdentifyResult:
    """:func:`identify` with progress on stderr, and a warning line (stderr, also with --json)
    when ``--generations`` stopped it before CMA-ES converged or its residual flags a model that
    does not match the log (:func:`mismatch_warning`)."""
    bar = progress_bar(settings.max_gen, desc, quiet)
    try:
        def tick(gen, best):
            bar.update(gen - bar.n)
            bar.set_postfix_str(f"J={best:.4g}")
        result = identify(problem.traj, problem.scene, problem.space, settings, progress=tick, nthread=threads)
    finally:
        bar.close()
    for text in (not_converged_warning(result), mismatch_warning(result)):
        if text:
            click.echo(f"amhe: warning: {text}", err=True)
    return result


def save_outputs(problem: Problem, result: IdentifyResult, command: str, log: str, out_path: Path, force: bool,
                 plot_path: Path | None, threads: int | None, truth: dict | None = None) -> None:
    """Write the belief YAML (and the --plot PNG) of an identification.

    ``truth`` (name -> value, when known) goes into the belief's provenance and onto the plot.
    Both paths were claimed by :func:`check_outputs` before the work started.
    """
    belief = belief_from_result(result, problem, command, log)
    if truth is not None:
        belief.provenance["truth"] = truth
    belief.save(out_path, force=force)
    if plot_path is not None:
        from amhe_cli.estimation.cost import RolloutCost
        from amhe_cli.cli.plot import plot_identify
        with RolloutCost(problem.scene, problem.space, result.clips, nthread=threads) as cost:
            plot_identify(plot_path, result, cost.rollout, problem.traj, truth=truth)


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


def _two_numbers(text: str, flag: str, names: str) -> tuple[float, float]:
    """``"a,b"`` -> (a, b) finite floats; AmheError naming ``flag`` and the expected ``names`` otherwise."""
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise AmheError(f"{flag} {text!r}: expected two numbers {names}") from None
    if not (np.isfinite(a) and np.isfinite(b)):
        raise AmheError(f"{flag} {text!r}: expected finite numbers")
    return a, b


def parse_range(text: str, flag: str) -> tuple[float, float]:
    """``"a,b"`` -> (a, b) with a <= b; AmheError naming ``flag`` otherwise."""
    a, b = _two_numbers(text, flag, "MIN,MAX")
    if not a <= b:
        raise AmheError(f"{flag} {text!r}: expected MIN <= MAX")
    return a, b


def parse_xy(text: str, flag: str) -> tuple[float, float]:
    """``"x,y"`` -> (x, y) finite floats; AmheError naming ``flag`` otherwise."""
    return _two_numbers(text, flag, "X,Y")


def live_option(f):
    """``--live [HOST:]PORT``: stream the view to Foxglove (``amhe[live]``); a bare ``--live`` is port 8765."""
    return click.option("--live", default=None, is_flag=False, flag_value="8765", metavar="[HOST:]PORT",
                        help="Stream what the robot, planner and estimator think to Foxglove over WebSocket "
                             "(Foxglove: Open connection, ws://HOST:PORT; load `amhe live-layout`). "
                             "Loopback unless a HOST is given; needs pip install 'amhe[live]'.")(f)


def check_live(address: str | None) -> None:
    """Validate ``--live`` before any work: the address parses and the SDK is installed.

    Raises:
        AmheError: a bad ``[HOST:]PORT`` or no ``foxglove-sdk``.
    """
    if address is not None:
        from amhe_cli.io.live import parse_live_address, require_sdk
        parse_live_address(address)
        require_sdk()


def start_live(address: str | None, frames, quiet: bool = False):
    """The live server of ``--live`` (None without it), listening, its address said on stderr.

    Args:
        address: the ``--live`` value (``[HOST:]PORT``) or None.
        frames: the :class:`~amhe_cli.io.view.ViewFrames` it converts with.
        quiet: do not print the address.

    Raises:
        AmheError: a bad address, the SDK missing, or the port busy (one line, before any work).
    """
    if address is None:
        return None
    from amhe_cli.io.live import LiveServer, parse_live_address
    host, port = parse_live_address(address)
    server = LiveServer(frames, host, port).start()
    if not quiet:
        click.echo(f"amhe: live view on {server.address} (Foxglove: Open connection -> Foxglove WebSocket; "
                   "layout: amhe live-layout > amhe.json)", err=True)
    return server


def task_view_frames(task, kp: float, kd: float, floor: bool = True):
    """The :class:`~amhe_cli.io.view.ViewFrames` of a task's plant: its bodies (the task's scene at 2 ms
    with PD gains ``kp``, ``kd``, as ``make_plant`` and the Go1 plant build it), the goal, and with
    ``floor`` the floor with the task's true box–floor μ (a region per friction event tied to the box's
    x, as T4's); a real floor's μ is unknown, so a Go1 run passes ``floor=False``."""
    from amhe_cli.control.closed_loop import task_scene_config
    from amhe_cli.io.view import ViewFrames
    from amhe_cli.model.scene import Scene
    scene = Scene(task_scene_config(task, 0.002, kp, kd))
    if not floor:
        return ViewFrames(scene.model, (), goal=task.goal)
    regions, mu = [], float(task.truth.get("box_friction", scene.config.regions[0].mu))
    x0 = None
    for ev in sorted((e for e in task.events if e.param == "box_friction" and e.box_x is not None),
                     key=lambda e: e.box_x):
        regions.append((x0, ev.box_x, mu, "truth"))
        x0, mu = ev.box_x, float(ev.value)
    regions.append((x0, None, mu, "truth"))
    return ViewFrames(scene.model, regions, goal=task.goal)
