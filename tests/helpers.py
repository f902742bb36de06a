"""Helpers the test modules share: the CLI run in-process, the one-line error check, a patient run config, a
hold of the interpreter lock."""

from __future__ import annotations

import time


def amhe(capsys, *args):
    """Run the CLI in-process: (exit code, stdout, stderr)."""
    from amhe_cli.cli import main
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(result, *words) -> str:
    """Assert a run failed with exit 2 and exactly one ``amhe: error:`` line holding ``words``; return that line."""
    code, _, err = result
    assert code == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("amhe: error:")]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def patient(tmp_path) -> list[str]:
    """``--config`` args for a run whose test is not the state watchdog: a 0.5 s ``state_timeout``, so a
    busy machine that holds the emulator up past the 40 ms default (CI saw 70 ms gaps, the emulator at
    SCHED_FIFO) does not end the run before it can show what the test checks. The watchdog itself is
    tested at its default (``test_lost_or_corrupt_state_ends_in_damping_within_50_ms``)."""
    cfg = tmp_path / "patient.yaml"
    cfg.write_text("safety:\n  state_timeout: 0.5\n")
    return ["--config", str(cfg)]


def gil_hog(seconds: float) -> None:
    """Hold the interpreter lock for about ``seconds`` (or more on a busy machine): one C call that never lets
    it go."""
    t = time.perf_counter()
    sum(range(1_000_000))
    per = (time.perf_counter() - t) / 1_000_000
    sum(range(int(1.5 * seconds / per)))
