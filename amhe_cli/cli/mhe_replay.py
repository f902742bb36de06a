"""``amhe mhe-replay``: the sliding-window estimator along a log, and its ablation sweeps."""

from __future__ import annotations

import json
from csv import writer as csv_writer
from dataclasses import asdict, replace

import click
import numpy as np

from amhe_cli.cli.common import (check_live, check_outputs, default_output, device_option, live_option, log_options,
                                 nominal_prior_text, parse_smooth, progress_bar, start_live)
from amhe_cli.errors import AmheError
from amhe_cli.estimation.cost import StateWeights
from amhe_cli.estimation.mhe import REPLAY_SETTINGS, MHESettings, replay_windows
from amhe_cli.estimation.problem import load_problem, parse_box_size, parse_topics
from amhe_cli.model.params import PARAMETERS, parse_names

#: What ``tracking error vs truth`` is (:func:`~amhe_cli.estimation.replay.tracking_error`), printed beside it.
TRACKING_ERROR_TEXT = ("tracking error = RMS of (estimate − truth) at each update, over the updates from the first "
                       "informative one on (the earlier ones, windows without box motion, hold the prior); "
                       "box_mass in % of the truth, box_friction absolute")
#: The unit of each tracking error.
TRACKING_ERROR_UNITS = {"box_mass": "% of truth", "box_friction": "absolute (friction coefficient)"}

@click.command("mhe-replay")
@click.argument("log", type=click.Path())
@log_options
@click.option("--params", default="box_mass,box_friction", show_default=True, metavar="NAMES",
              help=f"Free parameters, from: {', '.join(PARAMETERS)} (an unfree inertia follows the mass).")
@click.option("--prior", type=click.Path(), default=None,
              help="Belief YAML (from identify or probe) to start from. Default: " + nominal_prior_text() + ".")
@click.option("--window", default=1.0, show_default=True, type=float, help="Window H [s].")
@click.option("--every", default=0.5, show_default=True, type=float, help="Update period Δt_update [s].")
@click.option("--iters", default=3, show_default=True, type=int, help="Iterations L_MHE per update.")
@click.option("--samples", default=None, type=int,
              help=f"Candidates B per iteration (default {REPLAY_SETTINGS['samples']}; with the attribution "
                   f"{MHESettings.samples}, as `amhe run` keeps for its real-time budget).")
@click.option("--alpha", default=0.8, show_default=True, type=float, help="Learning rate α.")
@click.option("--clip", default=0.1, show_default=True, type=float,
              help="Clip length [s] the window is cut into (reset to recorded states); 0 = one piece.")
@click.option("--max-steps", default=None, type=int,
              help=f"Simulated steps per candidate per update (most informative clips first; default "
                   f"{REPLAY_SETTINGS['max_steps']}, with the attribution {MHESettings.max_steps}, as `amhe run`). "
                   "300 offline: on mass_switch.mcap, with 10 samples, 7 of 8 seeds met the tracking targets against "
                   "5 of 8 with the 150 that `amhe run` keeps to stay real-time on two cores; with 20, 8 of 8.")
@click.option("--fuse/--no-fuse", default=REPLAY_SETTINGS["fuse"], show_default=True,
              help="Report the window estimates fused per parameter (Kalman arrival cost with change detection; "
                   "the windows themselves are unchanged). The CSV adds each window's own estimate as <name>_window.")
@click.option("--attribute/--no-attribute", default=None,
              help="Report the box's mass and friction from line decisions over seconds of data that tell which "
                   "of the two changed, holding the other (docs/config.md: mhe attribute), instead of each "
                   "window's split, which motion-capture noise blurs. Needs --prior: the split starts from a belief. "
                   "Default: on where --prior is given, box_mass and box_friction are free and the log's poses are "
                   "noisy (smoothed motion capture): on 12 noisy T3 and T4 recordings, from their probe beliefs, it held "
                   "both bounds from 3 s after the change in 43 of 48 replays (T3's mocap_degrade ones 7 of 8 on two "
                   "seeds), the windows' own split in 0 of 8; on 8 fresh ones, T3 8 of 12 and T4 12 of 12; with each "
                   "window's data tested for a change, on 14 fresh ones, T3 11 of 16 (8 recordings, 2 seeds) and T4 10 of 10 "
                   "(docs/evaluation.md).")
@click.option("--realtime", is_flag=True,
              help="Replay on the live clock as `amhe run`'s estimator lives: an update due while the last one "
                   "still runs is deferred (dropped), and an estimate is usable only after its compute.")
@click.option("--duty", default=None, type=click.FloatRange(0, 1, min_open=True),
              help="With --realtime: the share of a core the estimator may keep busy, deferring updates to stay "
                   "under it, as `amhe run` does where the MHE shares the planner's CPUs (0.5 there; "
                   "default 1: a core of its own).")
@click.option("--fill", default=None, type=click.FloatRange(0, 1, min_open=True),
              help="With --realtime: size each update's steps to this share of the update period (times "
                   "--duty) from the measured speed, from --max-steps up to 4x it, as `amhe run` does with "
                   "mhe: {fill} (docs/config.md). Default: --max-steps fixed.")
@click.option("--truth", "truth_csv", type=click.Path(), default=None,
              help="Ground-truth CSV (default: <log stem>.truth.csv beside the log, if any).")
@click.option("--sweep", default=None, metavar="NAME=V1,V2,…",
              help="Ablation: rerun for each value of one setting (window, every, iters, samples, alpha, clip, max_steps).")
@click.option("--seeds", default=1, show_default=True, type=click.IntRange(1, 1000), help="Seeds per sweep value.")
@click.option("--seed", default=0, show_default=True, type=int,
              help="Seed of the estimator's candidate sampling (a sweep's k-th seed is SEED+k).")
@click.option("--threads", default=None, type=click.IntRange(1, 1024),
              help="Rollout threads (default: all CPUs).")
@device_option
@click.option("--out", default=None, type=click.Path(), help="Estimates CSV (default: <log stem>.mhe.csv).")
@click.option("--mcap", "mcap_out", default=None, type=click.Path(),
              help="Also write the estimates to this MCAP on /amhe/estimate (Float64MultiArray), with the "
                   "live view's channels (docs/log_schema.md#the-view).")
@live_option
@click.option("--force", is_flag=True, help="Overwrite existing output files.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object and nothing else.")
@click.option("--plot", type=click.Path(), default=None,
              help="PNG: each parameter [its unit] over log time [s], ±1σ, truth.")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
def mhe_replay_cmd(log, topics, map_file, box_size, smooth, params, prior, window, every, iters, samples, alpha,
                   clip, max_steps, fuse, attribute, realtime, duty, fill, truth_csv, sweep, seeds, seed, threads, out,
                   mcap_out, live, force, as_json, plot, quiet):
    """Track box parameters over LOG with the sliding-window estimator (paper §IV-A, eq. 4).

    Outputs (--out CSV, --mcap, --plot) are refused if they exist, unless
    --force, before any work starts. With a ground truth (a truth CSV beside
    the log, or --truth) it prints the tracking error: the RMS of estimate −
    truth over the updates from the first informative one on; box_mass in %
    of the truth, box_friction absolute.
    """
    from amhe_cli.estimation.mhe import MovingHorizonEstimator
    from amhe_cli.cli.plot import check_png_name, plot_estimates
    from amhe_cli.estimation.replay import attribute_by_default, estimates_table, replay, tracking_error, truth_series
    given = {"samples": samples, "max_steps": max_steps}  # None: the default of the mode (attribution or not)
    settings = MHESettings(window=window, every=every, iters=iters, alpha=alpha, clip=clip if clip > 0 else None,
                           fuse=fuse, fill=fill, seed=seed, attribute=bool(attribute),
                           **replay_windows(bool(attribute), given))
    settings.check()
    free = parse_names(params)
    smooth = parse_smooth(smooth)
    if attribute and prior is None:
        raise AmheError("--attribute holds the mass/friction split of a belief until a change shows which moved: "
                        "give --prior BELIEF.yaml (from identify or probe)")
    if duty is not None and not realtime:
        raise AmheError(f"--duty {duty:g} shares the live clock's core: it needs --realtime")
    if fill is not None and not realtime:
        raise AmheError(f"--fill {fill:g} sizes updates to the live clock's period: it needs --realtime")
    if sweep is not None:
        if out or mcap_out or plot or live:
            raise AmheError("--sweep prints a table and writes no file: drop --out, --mcap, --plot and --live")
        out_path = mcap_path = plot_path = None
    else:
        out_path, mcap_path, plot_path = check_outputs(
            force, ("--out", default_output(out, log, ".mhe.csv")), ("--mcap", mcap_out), ("--plot", check_png_name(plot)))
    check_live(live)
    problem = load_problem(log, topics=parse_topics(topics, map_file), params=free, prior=prior,
                           box_size=parse_box_size(box_size), smooth=smooth)
    if attribute is None and attribute_by_default(problem, prior):
        attribute = True
        settings = replace(settings, attribute=True, **replay_windows(True, given))
        if not (quiet or as_json):
            click.echo("a belief and noisy poses: the mass and friction are attributed by line decisions, with the "
                       f"run's windows ({settings.samples} samples, {settings.max_steps} steps; --no-attribute for each "
                       "window's own split)", err=True)
    attribute = bool(attribute)
    if settings.window > problem.traj.duration:
        raise AmheError(f"--window {settings.window} s is longer than the log ({problem.traj.duration:.2f} s)")
    truth = truth_series(log, problem.traj, truth_csv)
    if truth_csv and truth is None:
        raise AmheError(f"--truth {truth_csv}: expected a CSV with a 't' column and truth columns")

    view, server, recorder, frames = None, None, None, None
    if sweep is None and (live or mcap_path is not None):
        from amhe_cli.io.view import View, ViewFrames, ViewRecorder
        # the floor is labelled with the log's true μ where its truth gives one μ for the whole log on a
        # uniform floor, else with the model's
        regions = [(r.x_min, r.x_max, r.mu, "model") for r in problem.scene.config.regions]
        mu_true = truth.values.get("box_friction") if truth is not None else None
        if mu_true is not None and len(regions) == 1 and np.ptp(mu_true) == 0:
            regions = [(None, None, float(mu_true[0]), "truth")]
        frames = ViewFrames(problem.scene.model, regions, t0=problem.traj.meta.get("t0_ns", 0) * 1e-9)
        server = start_live(live, frames)
        recorder = ViewRecorder() if mcap_path is not None else None
        view = View([server, recorder])

    decisions = []

    def run_one(st: MHESettings):
        bar = progress_bar(round(problem.traj.duration, 2), "mhe-replay", quiet or as_json,
                        counter="{n:.1f}/{total:.1f} s of log")
        with MovingHorizonEstimator(problem.scene, problem.space, st, StateWeights.for_log(problem.traj),
                                    nthread=threads) as mhe:
            hook = None if view is None else _view_hook(view, problem, truth)
            res = replay(problem.traj, mhe, realtime=realtime, duty=duty or 1.0,
                         progress=lambda t: bar.update(t - bar.n), on_update=hook)
            decisions[:] = mhe.tracker.decisions if mhe.tracker is not None else []
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
        click.echo(f"sweep of {name} over {seeds} seed(s), mean ± std over the seeds; "
                   + (TRACKING_ERROR_TEXT if truth else "no truth for this log: no tracking error")
                   + "; compute time per update [s]")
        click.echo(f"{name:>10}  {'mass err [%]':>16}  {'friction err [-]':>18}  {'update [s]':>14}")
        for r in rows:
            m = r.get("box_mass")
            f = r.get("box_friction")
            click.echo(f"{r['value']:>10g}  {(f'{m[0]:6.2f} ± {m[1]:5.2f}' if m else '-'):>16}  "
                       f"{(f'{f[0]:.4f} ± {f[1]:.4f}' if f else '-'):>18}  "
                       f"{r['update_s'][0]:6.3f} ± {r['update_s'][1]:5.3f}")
        return

    try:
        res = run_one(settings)
        if view is not None:
            view.log(float(problem.traj.t[-1]), f"mhe-replay finished: {len(res.updates)} updates over "
                     f"{res.duration:.1f} s of log, compute {res.compute_time:.1f} s", level="info")
    finally:
        if server is not None:
            server.close()
    head, table = estimates_table(problem.space, res, windows=fuse)
    with open(out_path, "w", newline="") as fh:
        w = csv_writer(fh)
        w.writerow(head)
        w.writerows(table.tolist())
    if mcap_path is not None:
        from amhe_cli.io.writer import McapLog
        t0 = problem.traj.meta.get("t0_ns", 0) * 1e-9
        with McapLog(mcap_path, overwrite=force) as mlog:
            labels = head[1:]
            mlog.write_array("/amhe/estimate", table[:, 0] + t0, table[:, 1:], labels)
            mlog.write_metadata("amhe_mhe", {k: json.dumps(v) for k, v in settings.to_dict().items()})
            recorder.write(mlog, frames)
    skipped = np.array([u.skipped for u in res.updates])
    if plot_path is not None:
        plot_estimates(plot_path, head, table, truth, skipped, decisions)
    errors = tracking_error(problem.space, res, truth) if truth else {}
    lags = res.lags
    summary = {
        "updates": len(res.updates), "informative_updates": int((~skipped).sum()),
        "final": {h: float(table[-1, i]) for i, h in enumerate(head) if i > 0} if len(table) else {},
        "realtime": res.realtime, "realtime_factor": res.realtime_factor, "deferred": res.deferred,
        "lag_s": {"mean": float(lags.mean()) if len(lags) else 0.0, "max": float(lags.max()) if len(lags) else 0.0},
        "tracking_error": errors, "csv": str(out_path),
    }
    steps = [u.steps for u in res.updates if not u.skipped and u.steps is not None]
    if fill is not None and steps:
        summary["step_budget"] = {"median": int(np.median(steps)), "min": min(steps), "max": max(steps)}
    if errors:
        summary["tracking_error_units"] = {k: TRACKING_ERROR_UNITS[k] for k in errors}
        summary["tracking_error_definition"] = TRACKING_ERROR_TEXT
    if attribute:
        summary["decisions"] = [asdict(d) for d in decisions]
    if mcap_path is not None:
        summary["mcap"] = str(mcap_path)
    if plot_path is not None:
        summary["plot"] = str(plot_path)
    if as_json:
        click.echo(json.dumps(summary))
        return
    click.echo(f"{len(res.updates)} updates ({summary['informative_updates']} informative) over "
               f"{res.duration:.1f} s of log; compute {res.compute_time:.1f} s")
    final = summary["final"]
    for h, v in final.items():
        if not h.endswith(("_std", "_window")):
            own = f" (last window's own: {final[h + '_window']:.4g})" if h + "_window" in final else ""
            click.echo(f"  final {h} = {v:.4g} ± {final[h + '_std']:.2g}{own}")
    for d in decisions:
        if d.changed is not None:
            click.echo("  " + d.describe())
    if attribute:
        n_changes = sum(d.changed is not None for d in decisions)
        click.echo(f"  {len(decisions)} line decisions, {n_changes} of them a change")
    if errors:
        n_seen = int((np.cumsum(~skipped) > 0).sum())
        click.echo(f"tracking error vs truth over {n_seen} updates: " + ", ".join(
            f"{k} {v:.2f} %" if k == "box_mass" else f"{k} {v:.4f}" for k, v in errors.items()))
        click.echo(f"  ({TRACKING_ERROR_TEXT})")
    if realtime:
        why = "the last one still running" + (f", or resting under --duty {duty:g}" if duty else "")
        click.echo(f"realtime factor {res.realtime_factor:.2f}; {res.deferred} of {res.deferred + len(res.updates)} "
                   f"due update(s) deferred ({why}); lag mean {lags.mean():.3f} s, max {lags.max():.3f} s")
        if "step_budget" in summary:
            b = summary["step_budget"]
            click.echo(f"step budget per candidate (--fill {fill:g}): median {b['median']}, {b['min']}–{b['max']}")
    click.echo(f"estimates written to {out_path}" + (f", {mcap_path}" if mcap_path else "")
               + (f"; plot to {plot_path}" if plot_path else ""))


#: Pose frames per second of log time the live view plays back between two updates.
_PLAYBACK_RATE = 30.0


def _view_hook(view, problem, truth):
    """The replay's ``on_update`` hook feeding ``view``: the log's robot and box poses since the last
    update, paced over this update's compute time (so they play at the replay's speed), then the
    belief (fused estimate ± σ, the window's own, the truth where known) and a line per skipped window."""
    import time

    from amhe_cli.io.view import belief_message
    traj, space = problem.traj, problem.space
    qpos, _ = problem.scene.qpos_qvel(traj)
    labels = list(space.labels)
    names = [next(n for n, sl in space.slices().items() if sl.start <= i < sl.stop) for i in range(space.dim)]
    last = {"i": 0}
    view.scene(float(traj.t[0]))

    def hook(u):
        i1 = int(np.searchsorted(traj.t, u.t, side="right"))
        idx = np.arange(last["i"], i1)
        if len(idx):
            step = max(1, int(round(1.0 / (_PLAYBACK_RATE * traj.dt))))
            idx = idx[::step]
            now, span = time.monotonic(), min(max(u.compute_time, 0.0), 5.0)
            for k, i in enumerate(idx):
                view.state(float(traj.t[i]), qpos[i], due=now + span * k / len(idx), force=True)
        last["i"] = i1
        val, sd = space.physical(u.mean, u.std)
        own = space.physical(u.window_mean)[0] if u.window_mean is not None else None
        tru = None
        if truth is not None:
            tru = np.full(space.dim, np.nan)
            for j, name in enumerate(names):
                v = truth.at(name, np.array([u.t]))
                if v is not None:
                    v = np.ravel(v[0])
                    tru[j] = v[j - space.slices()[name].start] if len(v) > 1 else v[0]
        view.belief(u.t, *belief_message(labels, val, sd, own, tru))
        if u.skipped:
            view.log(u.t, f"t={u.t:.2f} s: no box motion in the window, estimate kept", level="info")
    return hook
