"""The ``amhe`` command line: identify, probe, mhe-replay, run, evaluate, emulate, live-layout.

One module per subcommand in this package; the options and helpers they share
live in :mod:`~amhe_cli.cli.common`. Every user-facing problem raises
:class:`~amhe_cli.errors.AmheError`; :func:`main` prints it as one line
``amhe: error: …`` on stderr and exits with status 2, without a traceback.
Warnings (a truncated log, a dropped message) print as ``amhe: warning: …``.
"""

from __future__ import annotations

import sys
import warnings

import click

from amhe_cli import __version__
from amhe_cli.cli.emulate import emulate_cmd
from amhe_cli.cli.evaluate import evaluate_cmd
from amhe_cli.cli.identify import identify_cmd
from amhe_cli.cli.live_layout import live_layout_cmd
from amhe_cli.cli.mhe_replay import mhe_replay_cmd
from amhe_cli.cli.probe import probe_cmd
from amhe_cli.cli.run import run_cmd
from amhe_cli.errors import AmheError


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="amhe")
def cli():
    """Sampling-based system identification and adaptive MPC for a Go1 pushing a box.

    Identify a box's mass, inertia and box-floor friction from a recorded log
    (MCAP, rosbag2, ROS 1 bag), re-estimate them over a sliding window, probe
    for a first belief, and push boxes with an adaptive sampling MPC.
    """



for _cmd in (identify_cmd, probe_cmd, mhe_replay_cmd, run_cmd, evaluate_cmd, emulate_cmd, live_layout_cmd):
    cli.add_command(_cmd)


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
