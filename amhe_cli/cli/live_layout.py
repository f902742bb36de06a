"""``amhe live-layout``: print the Foxglove layout of the live view (``amhe live-layout > amhe.json``)."""

from __future__ import annotations

import click


@click.command("live-layout")
def live_layout_cmd():
    """Print the Foxglove layout for --live and for recordings (JSON, on stdout).

    \b
    amhe live-layout > amhe.json     then in Foxglove: Layouts -> Import from file
    It shows the 3D scene (robot, box, goal, floor μ, the planner's plan), the
    belief over time (estimate ± σ, window, truth), the replanning rate, the
    safety state and the log, for `run`, `emulate go1` and `mhe-replay`.
    Nothing is written but stdout; the SDK is not needed.
    """
    from amhe_cli.io.live import layout_text
    click.echo(layout_text(), nl=False)
