"""``amhe evaluate``: modes × seeds of a task, the paper's Table I layout and per-run rows."""

from __future__ import annotations

import json
from csv import writer as csv_writer

import click

from amhe_cli.cli.common import T5_WARNING, TASK_HELP, check_outputs, load_belief, progress_bar
from amhe_cli.errors import AmheError

@click.command("evaluate")
@click.option("--task", "task_name", default="t4", show_default=True, help=TASK_HELP)
@click.option("--seeds", default=15, show_default=True, type=int,
              help="Runs per mode, with seeds 0..SEEDS-1 (the paper's Table I uses 15).")
@click.option("--modes", default="true,baseline,adaptive", show_default=True, metavar="MODE,…",
              help="Comma-separated modes to compare: true (the planner knows the truth), baseline (a fixed "
                   "starting belief), adaptive (the belief re-estimated online by the MHE).")
@click.option("--belief", default=None, type=click.Path(),
              help="Starting belief of baseline/adaptive (default: probe in the sim once, about a minute on "
                   "2 cores, with progress).")
@click.option("--config", default=None, type=click.Path(),
              help="Run config YAML, as for `amhe run --config` (planner, weights, mhe, mhe_params, kp, kd, "
                   "cycle, task).")
@click.option("--duration", default=None, type=float, help="Time limit per run [s] (default: the task's).")
@click.option("--workers", default=None, type=int, help="Worker processes, one run each (default: all CPUs).")
@click.option("--out", default=None, type=click.Path(),
              help="CSV of per-run rows: task, mode, seed, success, e_g, J, t_exec, rmse, fell, control_hz "
                   "(default: evaluate_<task>.csv).")
@click.option("--force", is_flag=True, help="Overwrite an existing --out file.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary table as one JSON object and nothing else.")
@click.option("--quiet", "-q", is_flag=True, help="No progress on stderr (no bar, no progress lines).")
def evaluate_cmd(task_name, seeds, modes, belief, config, duration, workers, out, force, as_json, quiet):
    """Run modes × seeds of a task in parallel and print the paper's Table I layout.

    Per mode: success rate S_R [%], and mean ± std over the seeds of the final
    goal error e_g [m], the task cost J per control cycle and the execution
    time t_exec [s] (until the box is at the goal, else the time limit).
    The --out CSV is refused if it exists, unless --force, before any run.
    """
    from amhe_cli.control.evaluate import evaluate, load_config, probe_belief, run_settings, summarise

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
    (out_path,) = check_outputs(force, ("--out", out or f"evaluate_{task.name}.csv"))
    if task.name == "t5":
        click.echo(f"amhe: warning: {T5_WARNING}", err=True)
    start = load_belief(belief)
    if start is None and set(mode_list) - {"true"}:
        if not (quiet or as_json):
            click.echo("no --belief: probing in the sim once for the baseline/adaptive starting belief "
                       "(the lunge probe, then identify: about a minute on 2 cores)", err=True)
        pbar = progress_bar(40, "probe+identify", quiet or as_json)
        try:
            start = probe_belief(task, seed=0, progress=lambda g, b: pbar.update(g - pbar.n))
        finally:
            pbar.close()
    bar = progress_bar(seeds * len(mode_list), f"evaluate {task.name}", quiet or as_json, counter="{n_fmt}/{total_fmt} runs")
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
