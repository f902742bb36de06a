"""``amhe evaluate``: modes × seeds of a task, the paper's Table I layout and per-run rows."""

from __future__ import annotations

import json
from csv import writer as csv_writer

import click

from amhe_cli.cli.common import load_belief, output_path, progress_bar
from amhe_cli.errors import AmheError

@click.command("evaluate")
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
    from amhe_cli.control.evaluate import evaluate, load_config, probe_belief, run_settings, summarise

    mode_list = [m.strip() for m in modes.split(",") if m.strip()]
    if seeds < 1:
        raise AmheError(f"--seeds {seeds}: expected at least 1")
    cfg = load_config(config)
    task, _ = run_settings(task_name, mode_list[0] if mode_list else "true", cfg, duration=duration)
    out_path = output_path(out or f"evaluate_{task.name}.csv", f"evaluate_{task.name}", ".csv", force)
    start = load_belief(belief)
    if start is None and set(mode_list) - {"true"}:
        if not (quiet or as_json):
            click.echo("no --belief: probing in the sim once for the baseline/adaptive starting belief", err=True)
        start = probe_belief(task, seed=0)
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
