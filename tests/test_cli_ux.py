"""A new user's first hour: outputs never overwritten, commands that explain themselves.

Fast: the CLI runs in-process, and every refusal is checked with a bad LOG or
settings that would take long, so a refusal that came after the work would
fail (or time out) the test.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import click
import numpy as np
import pytest
from helpers import amhe, one_line_error

from amhe_cli.estimation.problem import example_logs

FAST_ID = ["--clips", "4", "--popsize", "4", "--params", "box_mass,box_friction", "-q"]


@pytest.fixture(scope="module")
def example():
    return example_logs()[0]


# -- 1. one overwrite rule, checked before any work --------------------------------------------

def _existing(tmp_path, name, text="keep me\n"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("case", [
    # (subcommand args with {x} the existing file, {missing} a log that does not exist)
    ("identify", "{missing}", "--plot", "{x}"),
    ("identify", "{missing}", "--out", "{x}"),
    ("mhe-replay", "{missing}", "--plot", "{x}"),
    ("mhe-replay", "{missing}", "--out", "{x}"),
    ("mhe-replay", "{missing}", "--mcap", "{x}"),
    ("probe", "--target", "sim", "--record", "{x}"),
    ("probe", "--target", "sim", "--record", "{new}", "--plot", "{x}"),
    ("probe", "--target", "sim", "--record", "{new}", "--out", "{x}"),
    ("run", "--mode", "true", "--out", "{new}", "--plot", "{x}"),
    ("run", "--mode", "true", "--out", "{x}"),
    ("evaluate", "--modes", "true", "--out", "{x}"),
], ids=lambda c: " ".join(c))
def test_existing_output_is_refused_before_any_work(capsys, tmp_path, case):
    suffix = ".png" if "--plot" in case else ".mcap" if ("--record" in case or "--mcap" in case
                                                          or case[0] == "run") else ".out"
    x = _existing(tmp_path, "x" + suffix)
    new = tmp_path / "new.mcap"
    args = [a.format(x=x, missing=tmp_path / "missing.mcap", new=new) for a in case]
    t0 = time.perf_counter()
    line = one_line_error(amhe(capsys, *args), str(x), "already exists", "pass --force")
    assert time.perf_counter() - t0 < 5, "the refusal came after work"
    assert "missing.mcap" not in line  # the output check came before reading the log
    assert x.read_text() == "keep me\n" and not new.exists()


def test_run_refuses_its_truth_csv_and_probe_belief_before_probing(capsys, tmp_path):
    out = tmp_path / "r.mcap"
    csv = _existing(tmp_path, "r.truth.csv")
    one_line_error(amhe(capsys, "run", "--mode", "true", "--out", out), str(csv), "pass --force")
    csv.unlink()
    belief = _existing(tmp_path, "r.probe.belief.yaml")
    t0 = time.perf_counter()  # adaptive without --belief would probe for a minute first
    one_line_error(amhe(capsys, "run", "--out", out), str(belief), "pass --force")
    assert time.perf_counter() - t0 < 5
    assert not out.exists() and belief.read_text() == "keep me\n"


def test_a_robot_belief_is_refused_in_true_mode_and_when_missing(capsys, tmp_path):
    """``--robot-belief`` models a robot a belief describes: true mode plans with the plant's own, and a file
    that is not there is named; both before any work."""
    out = tmp_path / "r.mcap"
    one_line_error(amhe(capsys, "run", "--mode", "true", "--robot-belief", tmp_path / "robot.yaml", "--out", out),
                   "--robot-belief", "--mode true")
    missing = tmp_path / "missing.belief.yaml"
    one_line_error(amhe(capsys, "run", "--mode", "baseline", "--belief", missing, "--robot-belief", missing,
                        "--out", out), str(missing), "not found")
    assert not out.exists()


def test_two_outputs_cannot_share_a_file(capsys, tmp_path):
    one_line_error(amhe(capsys, "identify", tmp_path / "missing.mcap", "--out", tmp_path / "a.png",
                        "--plot", tmp_path / "a.png"), "--plot", "--out")


def test_check_outputs_rule():
    from amhe_cli.cli.common import check_outputs
    from amhe_cli.errors import AmheError
    with pytest.raises(AmheError, match="folder .* does not exist"):
        check_outputs(False, ("--out", "/no/such/folder/x.csv"))
    assert check_outputs(False, ("--plot", None), ("--out", "fresh-name.csv")) == [None, Path("fresh-name.csv")]


# -- 5. convergence, and --force replacing a plot ---------------------------------------------

def test_identify_stopped_by_generations_warns_and_says_not_converged(capsys, tmp_path, example):
    plot = _existing(tmp_path, "fit.png")
    # 8 clips: 4 of a clean log's short ones may hold no push, and a search inside the prior's σ has converged
    code, out, err = amhe(capsys, "identify", example, *FAST_ID, "--clips", "8", "--generations", "2", "--json",
                          "--out", tmp_path / "b.yaml", "--plot", plot, "--force")
    assert code == 0, err
    res = json.loads(out)
    assert res["converged"] is False and res["generations"] == 2 and "maxiter" in res["stop"]
    assert res["truth"] == {"box_mass": pytest.approx(2.5), "box_friction": pytest.approx(0.3)}
    warn = [ln for ln in err.splitlines() if ln.startswith("amhe: warning:")]
    assert len(warn) == 1 and "generation limit (2)" in warn[0] and "--generations" in warn[0]
    # it names the coordinates whose search is still wider than the data's σ (that spread is in σ)
    assert res["unsettled"] and all(v > 1 for v in res["unsettled"].values())
    assert "wider than the log's own σ" in warn[0] and "box_mass" in warn[0] and "in the stated σ" in warn[0]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # --force replaced it
    # the text says so too, and does not call the residual consistent with the noise
    code, out, err = amhe(capsys, "identify", example, *FAST_ID, "--clips", "8", "--generations", "2",
                          "--out", tmp_path / "b.yaml", "--force")
    assert code == 0, err
    assert "not converged" in out and "consistent with" not in out


def test_identify_chooses_clips_by_information_when_asked(capsys, tmp_path, example):
    """--candidates 3: as many clips as asked, said in the summary and kept in the belief's settings."""
    import yaml
    code, out, err = amhe(capsys, "identify", example, *FAST_ID, "--generations", "3", "--candidates", "3",
                          "--out", tmp_path / "b.yaml")
    assert code == 0, err
    assert "4 clips (the most informative of 3× as many)" in out
    belief = yaml.safe_load((tmp_path / "b.yaml").read_text())
    assert "candidates: 3" in yaml.safe_dump(belief)
    code, out, err = amhe(capsys, "identify", example, *FAST_ID, "--candidates", "0", "--out", tmp_path / "c.yaml")
    assert code == 2 and "'--candidates': 0 is not in the range" in err and "Traceback" not in err


def test_a_residual_that_flags_a_mismatched_model_says_what_to_free():
    """Past MISMATCH_RMS the warning names the robot-side parameters not yet free and the probe
    that tells which the log can separate; below it, or unconverged (not judged), nothing."""
    from amhe_cli.cli.common import MISMATCH_RMS, mismatch_warning
    box = SimpleNamespace(params=("box_mass", "box_inertia", "box_friction"))
    text = mismatch_warning(SimpleNamespace(converged=True, residual_rms=2 * MISMATCH_RMS, settings=box))
    names = "box_mass,box_inertia,box_friction,robot_box_friction,robot_kp,robot_kd,trunk_payload"
    assert f"--params {names}" in text and f"amhe probe LOG --params {names}" in text and "biased" in text
    assert mismatch_warning(SimpleNamespace(converged=True, residual_rms=0.5 * MISMATCH_RMS, settings=box)) is None
    assert mismatch_warning(SimpleNamespace(converged=False, residual_rms=2 * MISMATCH_RMS, settings=box)) is None
    every = SimpleNamespace(params=("box_mass", "robot_box_friction", "robot_kp", "robot_kd", "trunk_payload"))
    text = mismatch_warning(SimpleNamespace(converged=True, residual_rms=2 * MISMATCH_RMS, settings=every))
    assert "biased" in text and "--params" not in text  # nothing left to free: the flag alone


# -- 4. probe: several logs, units, the best-case note, a warning once, an empty file ---------

def test_probe_takes_two_logs(capsys):
    logs = example_logs()[:2]
    args = ["probe", *logs, "--params", "box_mass,box_friction", "--clips", "4"]
    code, out, err = amhe(capsys, *args, "--json")
    assert code == 0, err
    reps = json.loads(out)
    assert isinstance(reps, list) and [Path(r["log"]["path"]).name for r in reps] == [p.name for p in logs]
    assert reps[0]["parameters"]["box_mass"]["unit"] == "kg"
    code, out, err = amhe(capsys, *args)
    assert code == 0, err
    assert out.count("identifiability from 4 clips") == 2 and out.count("best case") == 2
    assert "best-case σ" in out and "unit" in out and " kg " in out


def test_probe_truncated_log_warns_once(capsys, tmp_path, example):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(example.read_bytes()[: int(example.stat().st_size * 0.7)])
    code, out, err = amhe(capsys, "probe", cut, "--params", "box_mass", "--clips", "2")
    assert code == 0, err
    assert (out + err).count("is truncated or damaged") == 1
    code, out, err = amhe(capsys, "probe", cut, "--params", "box_mass", "--clips", "2", "--json")
    assert code == 0, err
    assert err.count("is truncated or damaged") == 1 and json.loads(out)["log"]["warnings"]


@pytest.mark.parametrize("cmd", ["identify", "probe", "mhe-replay"])
def test_empty_file_is_called_empty(capsys, tmp_path, cmd):
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    extra = ["--out", tmp_path / "o.yaml"] if cmd != "probe" else []
    one_line_error(amhe(capsys, cmd, empty, *extra), "empty.mcap", "is empty (0 bytes)")


# -- 2. run: the failure reason, progress off a terminal --------------------------------------

def test_run_failure_reason_in_json_and_printout(capsys, tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("planner: {samples: 8, horizon: 20}\n")
    args = ["run", "--task", "t1", "--mode", "true", "--duration", "0.3", "--config", cfg, "--threads", "1",
            "--force"]
    code, out, err = amhe(capsys, *args, "--json", "--out", tmp_path / "a.mcap")
    assert code == 0, err
    m = json.loads(out)
    assert m["success"] is False
    assert m["reason"].startswith("time limit (0.3 s) reached with the box ")
    assert f"{m['e_g']:.2f} m from the goal" in m["reason"]
    code, out, err = amhe(capsys, *args, "--out", tmp_path / "b.mcap")
    assert code == 0, err
    assert "failure: time limit (0.3 s) reached with the box" in out


def test_failure_reason_order():
    from amhe_cli.cli.run import failure_reason
    from amhe_cli.control.tasks import get_task
    task = get_task("t1")
    t = np.arange(0, 5, 0.002)
    z = np.where(t < 3.21, 0.3, 0.1)
    level = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    traj = type("T", (), {"t": t, "base_pos": np.stack([t, 0 * t, z], axis=1), "base_quat": level, "meta": {},
                          "__len__": lambda s: len(t)})()
    r = SimpleNamespace(success=False, failure=None, fell=True, t_exec=5.0, e_g=0.9, traj=traj)
    assert failure_reason(r, task) == "robot fell at t = 3.2 s"
    r.failure = "robot state stale for 40 ms: damping"
    assert failure_reason(r, task) == r.failure
    r = SimpleNamespace(success=False, failure=None, fell=False, t_exec=12.0, e_g=0.7, traj=traj)
    assert failure_reason(r, task) == "run ended at t = 12.0 s with the box 0.70 m from the goal (success: within 0.20 m)"
    r.t_exec = task.duration
    assert failure_reason(r, task).startswith(f"time limit ({task.duration:g} s) reached with the box 0.70 m")
    r.success = True
    assert failure_reason(r, task) is None


def test_progress_prints_lines_when_not_a_terminal(capsys):
    from amhe_cli.cli.common import LineProgress, progress_bar
    buf = io.StringIO()
    bar = LineProgress(40, "probe+identify", unit=" gen", interval=0.0, file=buf)
    bar.update(3)
    bar.set_postfix_str("J=1.5")
    bar.update(2)
    bar.close()
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("probe+identify: 3/40 gen, ") and lines[1].endswith("J=1.5")
    assert lines[-1].startswith("probe+identify: 5/40 gen") and lines[-1].endswith("(done)")
    quiet = LineProgress(40, "x", interval=3600.0, file=buf)  # nothing before its interval, nothing at close
    before = buf.getvalue()
    quiet.update(40), quiet.close()
    assert buf.getvalue() == before
    # under pytest stderr is not a terminal: lines, not a bar; --quiet: nothing
    assert isinstance(progress_bar(10, "run", False), LineProgress)
    silent = progress_bar(10, "run", True)
    silent.update(10), silent.close()
    assert capsys.readouterr().err == ""


# -- 3. and 6. help that points somewhere -----------------------------------------------------

def _commands():
    from amhe_cli.cli import cli
    return {name: cli.get_command(None, name) for name in ("identify", "probe", "mhe-replay", "run", "evaluate")}


def test_amhe_help_lists_each_commands_own_line_without_importing_them():
    """``amhe --help`` imports no subcommand (mujoco, cma); the lines it lists are the commands' own."""
    code = ("import sys; from amhe_cli.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('mujoco', 'cma', 'scipy', 'amhe_cli.cli.identify') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout
    assert "identify     Identify box mass" in out.stdout and "live-layout  Print the Foxglove" in out.stdout
    from amhe_cli.cli import COMMANDS, cli
    for name, (_, _, line) in COMMANDS.items():
        assert cli.get_command(None, name).get_short_help_str(limit=200) == line, name


def test_replaying_a_clean_log_imports_neither_plotting_nor_signal_processing(tmp_path):
    """``amhe mhe-replay`` on a clean log without --plot leaves matplotlib, scipy.signal and scipy.stats
    unimported (about a second of a short command): they load where a figure is drawn or a noisy
    pose stream smoothed. (``identify`` imports ``cma``, which loads matplotlib and scipy.stats itself.)"""
    from amhe_cli.estimation.problem import example_logs

    log = example_logs()[0]  # a clean simulated log
    code = ("import sys; from amhe_cli.cli import main\n"
            f"main(['mhe-replay', {str(log)!r}, '--samples', '4', '--iters', '1', '--max-steps', '50', "
            f"'--out', {str(tmp_path / 'e.csv')!r}, '--json', '--device', 'cpu'])\n"
            "print(sorted(m for m in ('matplotlib', 'scipy.signal', 'scipy.stats') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout


@pytest.mark.parametrize("name", ["identify", "probe", "mhe-replay", "run", "evaluate"])
def test_every_option_has_help_and_no_outside_document(name):
    cmd = _commands()[name]
    for p in cmd.params:
        if isinstance(p, click.Option):
            assert p.help and p.help.strip(), f"{name} {p.opts} has no help"
    ctx = click.Context(cmd, info_name=name)
    text = cmd.get_help(ctx)
    assert "DESIGN" not in text and "§6" not in text and "issue" not in text
    if any("--prior" in p.opts for p in cmd.params):
        assert "Default: the nominal box: mass 3.7 kg" in text and "μ 0.5" in text


def test_task_help_says_where_t5_falls_short(capsys):
    for name in ("run", "evaluate"):
        opt = next(p for p in _commands()[name].params if "--task" in p.opts)
        assert "t5" in opt.help and "the foot's reach ends about 0.15 m short" in opt.help


def test_mhe_replay_defines_its_tracking_error(capsys, tmp_path, example):
    code, out, err = amhe(capsys, "mhe-replay", example, "--samples", "4", "--iters", "1", "--every", "1.0",
                          "--threads", "1", "-q", "--out", tmp_path / "m.csv", "--plot", tmp_path / "m.png")
    assert code == 0, err
    line = next(ln for ln in out.splitlines() if ln.startswith("tracking error vs truth"))
    assert "box_mass" in line and "%" in line
    assert "RMS of (estimate − truth)" in out and "box_mass in % of the truth, box_friction absolute" in out
    code, out, err = amhe(capsys, "mhe-replay", example, "--samples", "4", "--iters", "1", "--every", "1.0",
                          "--threads", "1", "-q", "--json", "--out", tmp_path / "n.csv")
    assert code == 0, err
    s = json.loads(out)
    assert s["tracking_error_units"]["box_mass"] == "% of truth" and "tracking_error_definition" in s


def test_a_child_command_runs_this_amhe_not_the_one_in_its_working_directory(tmp_path):
    """``child_command()`` (what the benchmarks start clients and emulators with) imports the ``amhe_cli`` this
    process runs; a plain ``python -c`` from a folder holding another ``amhe_cli`` imports that one."""
    from amhe_cli import __version__
    from amhe_cli.cli import child_command
    (tmp_path / "amhe_cli").mkdir()
    (tmp_path / "amhe_cli" / "__init__.py").write_text("raise SystemExit('the other amhe_cli')\n")
    ours = subprocess.run([*child_command(), "--version"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert ours.returncode == 0 and __version__ in ours.stdout, ours.stderr
    plain = subprocess.run([sys.executable, "-c", "from amhe_cli.cli import main; main()", "--version"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=60)
    assert plain.returncode != 0 and "the other amhe_cli" in plain.stderr


@pytest.fixture
def emulated_grid(monkeypatch):
    """``benchmarks/go1_emulated_runs.py`` as a module."""
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "go1_emulated_runs.py"
    monkeypatch.syspath_prepend(str(path.parent))  # it imports the scripts beside it
    spec = importlib.util.spec_from_file_location("go1_emulated_runs", path)
    grid = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(grid)
    return grid


def test_the_emulated_grid_says_how_much_data_a_change_took_and_how_long_its_split_took_to_the_planner(emulated_grid):
    """A row's segment after a change: the first attribution's data after the change, and from there to the first
    estimate the planner was given that carries its value (not an earlier swap, nor one of another value)."""
    row = {"events": [{"param": "box_mass", "value": 6.0, "t": 10.0}],
           "mhe_attributed": [[9.0, "period", "box_friction", 0.51], [11.52, "provisional", "box_mass", 5.94],
                              [12.5, "change", "box_mass", 5.82]],
           "mhe": [{"from": 0.0, "to": 10.0}, {"from": 13.0, "to": 30.0, "within_after_s": 2.9,
                                               "swaps": [[0.5, 4.02, 0.497], [1.6, 4.02, 0.497], [2.8, 5.94, 0.497],
                                                         [3.4, 5.82, 0.497]]}]}
    emulated_grid.attribution_latency(row)
    assert row["mhe"][1]["attributed_s"] == 1.52 and row["mhe"][1]["to_planner_s"] == 1.28
    assert "attributed_s" not in row["mhe"][0] and "job_s" not in row["mhe"][1]
    # the run's MHE jobs (amhe run --json's mhe_jobs): the one that made the first attribution, not its window's test
    row["mhe_jobs"] = [[11.02, 0.01, 0.2, 1, "test"], [11.518, 0.7, 1.1, 3, "provisional"],
                       [12.5, 0.0, 0.6, 2, "change"]]
    emulated_grid.attribution_latency(row)
    assert row["mhe"][1]["job_s"] == [0.7, 1.1]
    row["mhe"][1]["swaps"] = row["mhe"][1]["swaps"][:2]  # never reached the planner in the rows kept
    emulated_grid.attribution_latency(row)
    assert row["mhe"][1]["attributed_s"] == 1.52 and row["mhe"][1]["to_planner_s"] is None


def test_the_emulated_grid_states_the_planner_s_cycle_from_the_run_s_recording(emulated_grid, tmp_path):
    """A row's ``plan_interval_ms`` (the time between plans, where an estimator's work on the control loop shows
    as cycles lost) and ``plan_compute_ms``, read from the recording's ``/amhe/planner``; none where it holds fewer
    than two plans."""
    from test_io import make_traj  # a short synthetic log to carry the topic
    from amhe_cli.io.writer import write_mcap
    traj = make_traj()
    t = np.r_[0.03 * np.arange(34), 1.06, 1.11]  # 34 plans 30 ms apart, then one 70 ms late, one more 50 ms on
    compute = np.r_[np.full(34, 20.0), 65.0, 25.0]
    plans = np.column_stack([1e3 / np.r_[30.0, np.diff(t) * 1e3], compute, np.zeros(36), np.zeros(36)])
    path = write_mcap(tmp_path / "run.mcap", traj, extra=[("/amhe/planner", t, plans,
                                                            ["rate_hz", "compute_ms", "lead_ms", "forecast_tilt_deg"])])
    got = emulated_grid.plan_timing(str(path))
    assert got["plan_interval_ms"][0] == pytest.approx(30.0) and got["plan_interval_ms"][3] == pytest.approx(70.0)
    assert got["plan_compute_ms"][0] == pytest.approx(20.0) and 20.0 < got["plan_compute_ms"][2] <= 65.0
    short = write_mcap(tmp_path / "short.mcap", traj, extra=[("/amhe/planner", t[:1], plans[:1],
                                                              ["rate_hz", "compute_ms", "lead_ms", "forecast_tilt_deg"])])
    assert emulated_grid.plan_timing(str(short)) == {}


def test_the_emulated_grid_judges_the_estimates_against_the_box_the_emulator_says_it_plays(emulated_grid):
    """``--emulator-args='--box …'``: the emulator's first line names its box, and the rows' errors are measured
    against it, not the task's (a robot-box friction named before it is not the box's)."""
    import subprocess
    proc = subprocess.run([*emulated_grid.AMHE, "emulate", "go1", "--task", "t4", "--port", "0", "--pose-to", "off",
                           "--duration", "0.1", "-q", "--box", "box_mass=6.5,box_friction=0.3",
                           "--robot", "robot_box_friction=0.8"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]
    assert emulated_grid.emulator_box(first) == {"box_mass": 6.5, "box_friction": 0.3}, first
    assert emulated_grid.emulator_box(first.split(", box ")[0]) == {}  # the task's own box


def test_the_emulated_grid_keeps_the_recordings_worth_reading_falls_first(emulated_grid):
    """``--keep``: a fall, then a trip, then the changes held latest after 3 s (never first); none held in time."""
    def row(seed, fell=False, trip=False, held=2.0):
        return {"seed": seed, "fell": fell, "trip": trip, "mhe": [{"from": 0.0}, {"swaps": [], "within_after_s": held}]}
    rows = [row(0), row(1, held=3.4), row(2, held=None), row(3, trip=True), row(4, fell=True, held=2.5),
            row(5, held=2.99), {"seed": 6, "fell": False, "trip": False, "mhe": []}]
    assert [r["seed"] for r in emulated_grid.worth_reading(rows, 10)] == [4, 3, 2, 1]
    assert [r["seed"] for r in emulated_grid.worth_reading(rows, 2)] == [4, 3]


def test_the_emulated_grid_keeps_a_kept_recording_s_last_seconds_readable_on_their_own(emulated_grid, tmp_path):
    """``--keep-tail``: the last seconds of a recording too large to come back from a lent host, with each channel's
    last message before them (a scene published once at the start) and the run's log; the rest left out."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    src, dst = tmp_path / "run.mcap", tmp_path / "run.tail.mcap"
    with open(src, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        scene, state = (w.register_channel(t, "cdr", sid) for t in ("/amhe/scene", "/joint_states"))
        w.add_message(scene, 0, b"scene", 0, 0)
        for k in range(201):  # 0 to 20 s, every 0.1 s
            w.add_message(state, k * 100_000_000, bytes([k]), k * 100_000_000, k)
        w.add_metadata("amhe_run_log", {"0": "t=19.50 s: fall prevention: trunk tilt 18° > 17°"})
        w.finish()
    assert emulated_grid.keep_tail(str(src), str(dst), 5.0) == 2 + 51
    reader = make_reader(open(dst, "rb"))
    got = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(log_time_order=True)]
    assert got[0] == ("/amhe/scene", 0, b"scene")
    assert [t for topic, t, _ in got[1:]] == [k * 100_000_000 for k in range(149, 201)]  # the state before, then 15-20 s
    assert got[-1][2] == bytes([200])
    assert [dict(m.metadata) for m in reader.iter_metadata()] == [{"0": "t=19.50 s: fall prevention: trunk tilt 18° > 17°"}]


def test_the_emulated_grid_names_each_label_s_recordings_apart(emulated_grid):
    """``benchmarks/go1_emulated_runs.py``: two grids side by side into one ``--out-dir`` (two codes, run for run)
    write one file per run each, not one file at once."""
    grid = emulated_grid
    names = {grid.recording_name("t3", "adaptive", 2, label) for label in (None, "new", "old", "a/b c")}
    assert names == {"go1_t3_adaptive_s2.mcap", "go1_t3_adaptive_s2_new.mcap", "go1_t3_adaptive_s2_old.mcap",
                     "go1_t3_adaptive_s2_a_b_c.mcap"}


def test_the_emulated_grid_gives_each_pair_cpus_of_its_own_and_spreads_the_clients_over_the_gpus(emulated_grid):
    """``--cores-per-run 6 --emulator-cores 1 --gpus 2`` on 32 CPUs: four pairs, none sharing a CPU, two clients on
    each GPU (how stop 77 ran T3 and T4 side by side on a lent 2 × H200 by hand); without ``--gpus``, no GPU set."""
    slots = emulated_grid.pair_slots(list(range(32)), 4, 6, 1, gpus=2)
    assert slots[0] == (list(range(6)), [6], 0) and slots[1] == (list(range(7, 13)), [13], 1)
    used = [c for client, emu, _ in slots for c in client + emu]
    assert len(used) == len(set(used)) == 28
    assert [g for _, _, g in slots] == [0, 1, 0, 1]
    assert [g for _, _, g in emulated_grid.pair_slots(list(range(8)), 2, 2, 1)] == [None, None]
    assert emulated_grid.pair_slots([4, 5], 1, 2, 0)[0] == ([4, 5], [], None)  # the emulator on the client's CPUs
