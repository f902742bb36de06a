"""The command line as a user meets it: errors, outputs, files, the bundled example."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from amhe_cli.io.writer import write_mcap
from amhe_cli.estimation.problem import example_logs
from amhe_cli.control.probing import simulate_probe

AMHE = [sys.executable, "-c", "from amhe_cli.cli import main; main()"]
# small but not degenerate: 8 clips x 12 generations misses by up to 10 % (benchmarks/identify_accuracy.py);
# 18 of a clean log's 0.07-0.13 s clips are the simulated time of 12 of 0.1-0.2 s
FAST = ["--clips", "18", "--popsize", "10", "--generations", "20", "--params", "box_mass,box_friction", "-q"]
#: CLI tests check plumbing; accuracy at 5 % is tests/test_core.py's and the benchmark's job
MASS_TOL = 0.10


def amhe(*args, cwd=None):
    """Run the CLI in a subprocess (exit code, stdout and stderr as a user sees them)."""
    return subprocess.run([*AMHE, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300)


def one_line_error(proc, *words):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.startswith("amhe: error:")]
    assert len(lines) == 1, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    """A short sim probe log with known truth (mass 4 kg, μ 0.4)."""
    traj = simulate_probe({"box_mass": 4.0, "box_friction": 0.4}, seed=3, lunges=(0.07, 0.1))
    path = tmp_path_factory.mktemp("logs") / "sim.mcap"
    write_mcap(path, traj, metadata={"amhe_truth": {"box_mass": "4.0", "box_friction": "0.4"}})
    return path


def test_example_logs_are_shipped():
    logs = example_logs()
    assert len(logs) >= 2 and all(p.stat().st_size < 2.5e6 for p in logs)


def test_missing_file(tmp_path):
    one_line_error(amhe("identify", tmp_path / "nope.mcap", "--out", tmp_path / "b.yaml"), "nope.mcap")


def test_not_a_log(tmp_path):
    bad = tmp_path / "notes.txt"
    bad.write_text("hello\n")
    one_line_error(amhe("identify", bad, "--out", tmp_path / "b.yaml"), "notes.txt", "expected")


def test_log_without_box_pose(tmp_path, sim_log):
    from amhe_cli.io.reader import read_log
    traj = read_log(sim_log)
    # write the same log, then name a non-existent topic for the box
    proc = amhe("identify", sim_log, "--topic", "box=/no/such/topic", "--out", tmp_path / "b.yaml")
    one_line_error(proc, "box")
    assert len(traj) > 100


def test_nan_in_log_is_an_error(tmp_path):
    traj = simulate_probe({"box_mass": 4.0}, seed=0, lunges=(0.05,))
    traj.box_pos[200:800] = np.nan  # far more than a few dropped messages
    path = tmp_path / "nan.mcap"
    write_mcap(path, traj)
    one_line_error(amhe("identify", path, "--out", tmp_path / "b.yaml"), "box")


def test_bad_options(tmp_path, sim_log):
    one_line_error(amhe("identify", sim_log, "--params", "box_mass,colour", "--out", tmp_path / "b.yaml"),
                   "colour", "box_mass")
    one_line_error(amhe("identify", sim_log, "--horizon", "0.3,0.1", "--out", tmp_path / "b.yaml"), "--horizon")
    one_line_error(amhe("identify", sim_log, "--plot", tmp_path / "x.jpg", "--out", tmp_path / "b.yaml"), ".png")
    one_line_error(amhe("probe", "--target", "sim", "--truth", "box_mass=-3", "--record", tmp_path / "r.mcap"),
                   "box_mass")


def test_identify_json_belief_and_overwrite(tmp_path, sim_log):
    out = tmp_path / "sim.belief.yaml"
    proc = amhe("identify", sim_log, *FAST, "--json", "--out", out, "--plot", tmp_path / "id.png")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)  # stdout holds exactly one JSON object
    assert abs(result["estimate"]["box_mass"] - 4.0) / 4.0 < MASS_TOL
    assert abs(result["estimate"]["box_friction"] - 0.4) < 0.03
    assert set(result["std"]) == {"box_mass", "box_friction"}
    assert (tmp_path / "id.png").stat().st_size > 10_000
    belief = yaml.safe_load(out.read_text())
    assert belief["parameters"]["box_mass"]["value"] == pytest.approx(result["estimate"]["box_mass"])
    assert belief["provenance"]["sha256"]
    # the clips that ran: --clips as given, the horizon by the clean log's plan (identify.clip_plan)
    assert belief["provenance"]["settings"]["n_clips"] == 18
    assert belief["provenance"]["settings"]["horizon"] == [0.07, 0.13]
    # an existing belief is never overwritten without --force
    before = out.read_text()
    one_line_error(amhe("identify", sim_log, *FAST, "--out", out), "--force")
    assert out.read_text() == before


def test_truncated_log_still_identifies(tmp_path, sim_log):
    data = sim_log.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    # half FAST's generations: 4.02 kg on this cut log (the warning and the yield are the test)
    proc = amhe("identify", cut, *FAST, "--generations", "10", "--json", "--out", tmp_path / "cut.belief.yaml")
    assert proc.returncode == 0, proc.stderr
    assert "amhe: warning:" in proc.stderr and "Traceback" not in proc.stderr
    result = json.loads(proc.stdout)
    assert abs(result["estimate"]["box_mass"] - 4.0) / 4.0 < MASS_TOL


def test_identify_defaults_to_bundled_example(tmp_path):
    # plumbing only (the example found, its truth printed, a belief written): the smallest search that runs
    proc = amhe("identify", "--clips", "6", "--popsize", "6", "--generations", "2", "--params",
                "box_mass,box_friction", "-q", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "bundled example" in proc.stderr
    assert "truth" in proc.stdout  # the example carries its ground truth
    assert list(tmp_path.glob("*.belief.yaml"))


def test_probe_reports_log_and_identifiability(sim_log):
    proc = amhe("probe", sim_log, "--params", "box_mass,box_friction", "--clips", "8", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    topics = {t["topic"] for t in rep["log"]["topics"]}
    assert {"/joint_states", "/odom", "/mocap/box/pose", "/joint_commands"} <= topics
    for name in ("box_mass", "box_friction"):
        p = rep["parameters"][name]
        assert 0 < p["std"] < p["prior_std"]  # the log informs both
    corr = np.array(rep["correlation"])
    assert corr.shape == (2, 2) and abs(corr[0, 1]) <= 1


def test_probe_sim_records_then_identifies(tmp_path):
    proc = amhe("probe", "--target", "sim", "--truth", "box_mass=3", "--truth", "box_friction=0.5",
                "--record", tmp_path / "p.mcap", "--out", tmp_path / "p.yaml", *FAST, "--json")
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    assert abs(result["estimate"]["box_mass"] - 3.0) / 3.0 < MASS_TOL
    assert abs(result["estimate"]["box_friction"] - 0.5) < 0.03
    assert Path(result["log"]).exists() and (tmp_path / "p.yaml").exists()


def test_topic_map_and_pairs(tmp_path):
    from amhe_cli.errors import AmheError
    from amhe_cli.estimation.problem import parse_box_size, parse_topics
    m = tmp_path / "map.yaml"
    m.write_text("topics:\n  box: /vicon/box\n  base: /vicon/go1\n")
    assert parse_topics(("box=/mocap/crate",), str(m)) == {"box": "/mocap/crate", "base": "/vicon/go1"}
    m.write_text("box: [not, a, topic]\n")
    with pytest.raises(AmheError, match="role: topic"):
        parse_topics((), str(m))
    with pytest.raises(AmheError, match="not found"):
        parse_topics((), str(tmp_path / "missing.yaml"))
    with pytest.raises(AmheError, match="ROLE=TOPIC"):
        parse_topics(("box",), None)
    assert parse_box_size("0.4") == (0.4, 0.4, 0.4) and parse_box_size("0.4,0.3,0.2") == (0.4, 0.3, 0.2)
    with pytest.raises(AmheError, match="--box-size"):
        parse_box_size("0.4,-1")


def test_map_file_selects_the_box_topic(tmp_path, sim_log):
    """A log whose box topic has an unusual name is read once the map names it."""
    from amhe_cli.io.reader import read_log
    m = tmp_path / "map.yaml"
    m.write_text("box: /mocap/box/pose\n")
    proc = amhe("probe", sim_log, "--map", m, "--params", "box_friction", "--clips", "4", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["log"]["roles"]["box"] == "/mocap/box/pose"
    assert len(read_log(sim_log, topics={"box": "/mocap/box/pose"})) > 100
