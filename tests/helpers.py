"""Helpers the test modules share: the CLI run in-process and the one-line error check."""

from __future__ import annotations


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
