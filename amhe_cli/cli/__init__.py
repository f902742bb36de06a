"""The ``amhe`` command line: identify, probe, mhe-replay, run, evaluate, emulate, live-layout.

One module per subcommand in this package; the options and helpers they share
live in :mod:`~amhe_cli.cli.common`. Every user-facing problem raises
:class:`~amhe_cli.errors.AmheError`; :func:`main` prints it as one line
``amhe: error: …`` on stderr and exits with status 2, without a traceback.
Warnings (a truncated log, a dropped message) print as ``amhe: warning: …``.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from pathlib import Path

import click

from amhe_cli import __version__
from amhe_cli.errors import AmheError

#: Subcommand -> (module, command object's name, the line ``amhe --help`` lists). A subcommand's
#: module is imported only when it runs (or its own ``--help`` is asked for): their imports (mujoco,
#: scipy, cma with matplotlib) take seconds that ``amhe --help`` and ``amhe live-layout`` need not
#: pay. A test checks each line is the command's own first docstring line.
COMMANDS = {
    "identify": ("amhe_cli.cli.identify", "identify_cmd",
                 "Identify box mass, inertia and box-floor friction from LOG (SPI-style CMA-ES)."),
    "probe": ("amhe_cli.cli.probe", "probe_cmd",
              "Probe for a first belief (--target sim), or report what each LOG can tell."),
    "mhe-replay": ("amhe_cli.cli.mhe_replay", "mhe_replay_cmd",
                   "Track box parameters over LOG with the sliding-window estimator (paper §IV-A, eq."),
    "run": ("amhe_cli.cli.run", "run_cmd",
            "Push a box with the adaptive sampling MPC (MPOPI + online MHE) on the sim plant or a Go1."),
    "evaluate": ("amhe_cli.cli.evaluate", "evaluate_cmd",
                 "Run modes × seeds of a task in parallel and print the paper's Table I layout."),
    "emulate": ("amhe_cli.cli.emulate", "emulate_cmd",
                "Emulate a robot on this machine, for testing the real-robot path without one."),
    "live-layout": ("amhe_cli.cli.live_layout", "live_layout_cmd",
                    "Print the Foxglove layout for --live and for recordings (JSON, on stdout)."),
}


class LazyGroup(click.Group):
    """A click group whose subcommands (:data:`COMMANDS`) are imported when first asked for."""

    def list_commands(self, ctx) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def get_command(self, ctx, name: str):
        """The subcommand ``name`` (importing its module the first time), or None."""
        if name in COMMANDS and name not in self.commands:
            module, attr, _ = COMMANDS[name]
            self.add_command(getattr(importlib.import_module(module), attr), name)
        return super().get_command(ctx, name)

    def format_commands(self, ctx, formatter) -> None:
        """The ``Commands:`` list from :data:`COMMANDS`' lines, importing nothing."""
        names = self.list_commands(ctx)
        if not names:
            return
        limit = formatter.width - 6 - max(len(n) for n in names)
        rows = []
        for name in names:
            if name in COMMANDS and name not in self.commands:
                rows.append((name, click.utils.make_default_short_help(COMMANDS[name][2], limit)))
            else:
                rows.append((name, self.commands[name].get_short_help_str(limit)))
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="amhe")
def cli():
    """Sampling-based system identification and adaptive MPC for a Go1 pushing a box.

    Identify a box's mass, inertia and box-floor friction from a recorded log
    (MCAP, rosbag2, ROS 1 bag), re-estimate them over a sliding window, probe
    for a first belief, and push boxes with an adaptive sampling MPC.
    """



def child_command() -> list[str]:
    """The argv prefix that runs this very ``amhe`` in a child process: ``sys.executable -c …`` with the folder
    holding the ``amhe_cli`` this process imported first on the child's ``sys.path``.

    ``python -c`` puts the working directory first, so from a checkout a child would import the checkout's
    ``amhe_cli`` even where this process runs another (a variant's tree on ``PYTHONPATH``, as a benchmark
    compares two codes). *Found* in stop 67: ``benchmarks/go1_emulated_runs.py``'s clients and emulators, run
    from the repository's root, ran the working tree's code under every variant's label."""
    root = str(Path(__file__).resolve().parents[2])
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {root!r}); from amhe_cli.cli import main; main()"]


def main(argv=None) -> None:
    """Console entry point: runs :func:`cli`, turning AmheError into one line and exit 2."""
    def show_warning(message, category, filename, lineno, file=None, line=None):
        click.echo(f"amhe: warning: {message}", err=True)
    warnings.showwarning = show_warning
    try:
        cli.main(args=argv, prog_name="amhe", standalone_mode=False)
    except AmheError as e:
        click.echo(f"amhe: error: {e}", err=True)
        sys.exit(2)
    except click.exceptions.Abort:
        click.echo("amhe: aborted", err=True)
        sys.exit(130)
    except click.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        click.echo("amhe: interrupted", err=True)
        sys.exit(130)
    except OSError as e:
        click.echo(f"amhe: error: {e.strerror or e}: {getattr(e, 'filename', '') or ''}".rstrip(": "), err=True)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
