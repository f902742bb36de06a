"""``amhe evaluate``: modes × seeds of a task, the paper's Table I layout and per-run rows."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from amhe_cli.cli.common import T5_WARNING, TASK_HELP, belief_text, check_outputs, load_belief, progress_bar
from amhe_cli.errors import AmheError
from amhe_cli.estimation.identify import IdentifySettings
from amhe_cli.io.rows import RowLog, read_rows


@click.command("evaluate")
@click.option("--task", "task_name", default="t4", show_default=True, help=TASK_HELP)
@click.option("--seeds", default=15, show_default=True, type=int,
              help="Runs per mode, with seeds 0..SEEDS-1 (the paper's Table I uses 15).")
@click.option("--modes", default="true,baseline,adaptive", show_default=True, metavar="MODE,…",
              help="Comma-separated modes to compare: true (the planner knows the truth), baseline (a fixed "
                   "starting belief), adaptive (the belief re-estimated online by the MHE).")
@click.option("--belief", default=None, type=click.Path(),
              help="Starting belief of baseline/adaptive (default: probe in the sim once, about a minute on "
                   "2 cores, with progress; the probe's belief is saved as <out stem>.probe.belief.yaml, and "
                   "--resume starts from it).")
@click.option("--config", default=None, type=click.Path(),
              help="Run config YAML, as for `amhe run --config` (planner, weights, mhe, mhe_params, kp, kd, "
                   "cycle, task).")
@click.option("--duration", default=None, type=float, help="Time limit per run [s] (default: the task's).")
@click.option("--workers", default=None, type=int, help="Worker processes, one run each (default: all CPUs).")
@click.option("--ray", "ray_address", default=None, is_flag=False, flag_value="local", metavar="[ADDRESS]",
              help="Run the grid as Ray tasks, one CPU each: --ray alone starts a local Ray instance (--workers "
                   "CPUs), --ray ADDRESS joins a running cluster (e.g. ray://head:10001; amhe must be installed "
                   "on its nodes). Needs pip install 'amhe[ray]'.")
@click.option("--out", default=None, type=click.Path(),
              help="CSV of per-run rows: task, mode, seed, success, e_g, J, t_exec, rmse, fell, recoveries, control_hz, "
                   "setting (default: evaluate_<task>.csv).")
@click.option("--force", is_flag=True,
              help="Overwrite an existing --out file (and --jsonl, and the probe's belief beside --out).")
@click.option("--resume", is_flag=True,
              help="Keep the rows an existing --out already has (a grid cut off) and run only the missing ones.")
@click.option("--jsonl", default=None, type=click.Path(),
              help="Also append each finished run as one JSON line (all its metrics) to this file.")
@click.option("--sweep", "sweeps", multiple=True, metavar="KEY=V1,V2,…",
              help="Ablation: rerun the grid for each value of a dotted run setting (mhe.samples=6,10,16, "
                   "mhe.window=0.5,1,2, planner.samples=…, kp=…); several --sweep flags vary one setting at a "
                   "time around the defaults (values that leave the settings at their defaults run once, their rows "
                   "shared). The table gets one block per value.")
@click.option("--plot", default=None, type=click.Path(),
              help="With --sweep: write the ablation figure (PNG): per swept setting, mean controller cost J "
                   "and success rate against its values, the default marked.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary table as one JSON object and nothing else.")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
def evaluate_cmd(task_name, seeds, modes, belief, config, duration, workers, ray_address, out, force, resume, jsonl,
                 sweeps, plot, as_json, quiet):
    """Run modes × seeds of a task in parallel and print the paper's Table I layout.

    Per mode: success rate S_R [%], and mean ± std over the seeds of the final
    goal error e_g [m], the task cost J per control cycle and the execution
    time t_exec [s] (until the box is at the goal, else the time limit).
    Each run's row is appended to the --out CSV (and --jsonl) the moment it
    finishes, so a grid cut off loses only the runs in flight; --resume then
    runs only what is missing. Without --resume or --force an existing --out
    is refused before any run.
    """
    from amhe_cli.cli.plot import check_png_name
    from amhe_cli.control.evaluate import (check_ray, default_setting, evaluate, load_config, parse_sweep, probe_belief,
                                           run_settings, summarise, sweep_variants)

    from amhe_cli.control.closed_loop import MODES
    mode_list = [m.strip() for m in modes.split(",") if m.strip()]
    bad = [m for m in mode_list if m not in MODES]
    if bad or not mode_list:
        raise AmheError(f"--modes {modes!r}: expected a comma-separated list from {', '.join(MODES)}")
    if seeds < 1:
        raise AmheError(f"--seeds {seeds}: expected at least 1")
    cfg = load_config(config)
    task, _ = run_settings(task_name, mode_list[0] if mode_list else "true", cfg, duration=duration)
    if workers is not None and workers < 1:
        raise AmheError(f"--workers {workers}: expected at least 1")
    if ray_address:
        check_ray(ray_address)
    variants = sweep_variants(task_name, cfg, list(sweeps)) if sweeps else None
    labels = [label for label, _ in variants] if variants else [""]
    if plot is not None and not sweeps:
        raise AmheError("--plot draws the ablation figure of a --sweep: give at least one --sweep")
    plot = check_png_name(plot)
    if resume and force:
        raise AmheError("--resume keeps the rows --out has and --force discards them: give one of them")
    out_path = Path(out or f"evaluate_{task.name}.csv")
    probing = belief is None and bool(set(mode_list) - {"true"})
    # the probe's belief is kept beside the rows, so that a resumed grid starts every run from the same one
    probe_path = out_path.with_name(out_path.stem + ".probe.belief.yaml") if probing else None
    kept: list[dict] = []
    if resume and out_path.exists():
        kept = [r for r in read_rows(out_path)
                if r["mode"] in mode_list and r["seed"] < seeds and r["setting"] in labels]
        other = {r["task"] for r in kept} - {task.name}
        if other:
            raise AmheError(f"--resume: {out_path} holds rows of task {', '.join(sorted(other))}, not {task.name}")
        (jsonl_path,) = check_outputs(True, ("--jsonl", jsonl)) if jsonl else (None,)
        (plot_path,) = check_outputs(True, ("--plot", plot))  # redrawn from the resumed rows
        if probe_path is not None and probe_path.exists():
            belief = str(probe_path)  # the cut-off grid's own starting belief
        else:
            (probe_path,) = check_outputs(True, ("--out", probe_path))
    else:
        out_path, jsonl_path, plot_path, probe_path = check_outputs(
            force, ("--out", out_path), ("--jsonl", jsonl), ("--plot", plot), ("--out", probe_path))
        for p in (out_path, jsonl_path):
            if p is not None and p.exists():
                p.unlink()  # --force: start the grid anew
    if task.name == "t5":
        click.echo(f"amhe: warning: {T5_WARNING}", err=True)
    start = load_belief(belief)
    talk = not (quiet or as_json)
    if start is not None and probing and talk:
        click.echo(f"--resume: starting belief from {probe_path}, the probe this grid's first runs started from "
                   f"({belief_text(start)})", err=True)
    if start is None and probing:
        if talk:
            click.echo("no --belief: probing in the sim once for the baseline/adaptive starting belief "
                       "(the lunge probe, then identify: about a minute on 2 cores)", err=True)
        pbar = progress_bar(IdentifySettings.max_gen, "probe+identify", quiet or as_json)
        try:
            start = probe_belief(task, seed=0, progress=lambda g, b: pbar.update(g - pbar.n))
        finally:
            pbar.close()
        start.save(probe_path, force=True)  # claimed above (check_outputs)
        if talk:
            click.echo(f"starting belief: {belief_text(start)}; saved to {probe_path} (--resume starts from it; "
                       f"`amhe run --belief {probe_path}` too)", err=True)
    done = {(r["setting"], r["mode"], r["seed"]) for r in kept}
    total = seeds * len(mode_list) * len(labels)
    if kept and talk:
        click.echo(f"--resume: {len(done)} of {total} runs already in {out_path}; running the other "
                   f"{total - len(done)}", err=True)
    rows = list(kept)
    bar = progress_bar(total, f"evaluate {task.name}", quiet or as_json, counter="{n_fmt}/{total_fmt} runs")
    bar.update(len(done))

    def finished(row: dict) -> None:
        log.write(row)
        rows.append(row)
        bar.update(1)
        bar.set_postfix_str("S_R " + " ".join(
            f"{m} {sum(r['success'] for r in rows if r['mode'] == m)}/{sum(r['mode'] == m for r in rows)}"
            for m in mode_list))
    try:
        with RowLog(out_path, jsonl_path) as log:
            evaluate(task.name, mode_list, seeds, start, cfg, workers, duration, progress=finished, done=done,
                     ray=ray_address, variants=variants)
    except KeyboardInterrupt:
        bar.close()
        click.echo(f"amhe: interrupted: {len(rows)} of {total} runs are in {out_path}; run the same command "
                   "with --resume to finish the grid", err=True)
        sys.exit(130)
    finally:
        bar.close()
    table = summarise(rows, mode_list, labels)
    if plot_path is not None:
        from amhe_cli.cli.plot import plot_ablation
        swept = [parse_sweep(t) for t in sweeps]
        plot_ablation(plot_path, table, swept, {k: default_setting(task.name, cfg, k) for k, _ in swept}, mode_list)
    if as_json:
        click.echo(json.dumps({"task": task.name, "seeds": seeds, "rows": table, "csv": str(out_path),
                               **({"plot": str(plot_path)} if plot_path else {}),
                               **({"probe_belief": str(probe_path)} if probe_path else {})}))
        return
    click.echo(f"{task.name}, {seeds} seed(s) per mode (mean ± std)")
    wide = max((len(label) for label in labels), default=0)
    head = f"{'setting':<{wide}}  " if sweeps else ""
    click.echo(f"{head}{'mode':>10}  {'S_R %':>6}  {'falls':>5}  {'e_g [m]':>15}  {'J':>15}  {'t_exec [s]':>15}")
    for r in table:
        lead = f"{r['setting']:<{wide}}  " if sweeps else ""
        click.echo(f"{lead}{r['mode']:>10}  {r['S_R']:6.1f}  {r['falls']:5d}  {r['e_g'][0]:7.3f} ± {r['e_g'][1]:5.3f}  "
                   f"{r['J'][0]:7.2f} ± {r['J'][1]:5.2f}  {r['t_exec'][0]:7.1f} ± {r['t_exec'][1]:5.1f}")
    click.echo(f"per-run rows: {out_path}" + (f"; ablation figure: {plot_path}" if plot_path else ""))
