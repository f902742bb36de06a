"""The probing manoeuvre run in a sim plant: data for a first belief (paper §V).

Adaptive-MHE "first initializes its belief via an offline probing estimation
step". :func:`simulate_probe` plays the lunges of :mod:`~amhe_cli.control.maneuver`
against a box in the project's own sim plant with chosen true parameters and
returns the recording (``amhe probe --target sim`` writes it as an MCAP and
identifies from it; ``amhe run`` without ``--belief`` does the same).
"""

from __future__ import annotations

import numpy as np

from amhe_cli.control.maneuver import lunge_schedule
from amhe_cli.control.tasks import Event
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.model.scene import SceneConfig
from amhe_cli.plants.sim import SimPlant

#: Gap between the standing robot's head and the box's back face [m].
HEAD_GAP = 0.01
#: x of the head's front face of a Go1 standing at the origin [m] (head_top capsule).
HEAD_FRONT_X = 0.276


def simulate_probe(truth: dict, config: SceneConfig | None = None, seed: int = 0,
                   lunges=(0.06, 0.09, 0.12), friction_step: tuple[float, float] | None = None,
                   schedule: dict | None = None) -> Trajectory:
    """Run the lunge probe in a sim plant with ``truth`` and return the recording.

    Args:
        truth: name -> true value (see :data:`~amhe_cli.model.params.PARAMETERS`).
        config: scene geometry (default :class:`SceneConfig`).
        seed: varies the box's lateral offset (±3 cm) and yaw (±0.1 rad) so
            that example logs differ.
        lunges: reach of each lunge [m].
        schedule: phase durations passed to :func:`~amhe_cli.control.maneuver.lunge_schedule`
            (``strike``, ``hold``, ``retreat``, ``rest`` [s]).
        friction_step: (x_b [m], μ after) — the box–floor friction of the plant
            switches to μ after once the box centre passes x = x_b (task T4's
            event, docs/tasks.md).
    Returns:
        the recorded :class:`Trajectory` on the plant's 2 ms grid, with the
        plant's ``meta['truth']`` and ``meta['truth_series']`` (see
        :meth:`~amhe_cli.plants.sim.SimPlant.trajectory`).
    """
    cfg = config or SceneConfig()
    rng = np.random.default_rng(seed)
    plant = SimPlant(cfg, truth=truth)
    qpos, qvel = plant.scene.standing_state()
    yaw = rng.uniform(-0.1, 0.1)
    qpos[plant.scene.box_qpos[:3]] = [HEAD_FRONT_X + HEAD_GAP + cfg.box_size[0] / 2, rng.uniform(-0.03, 0.03),
                                      cfg.floor_height + cfg.box_size[2] / 2]
    qpos[plant.scene.box_qpos[3:]] = [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
    plant.reset(qpos, qvel)
    events = [] if friction_step is None else [Event("box_friction", friction_step[1], box_x=friction_step[0])]
    for target in lunge_schedule(plant.control_steps * plant.record_dt, lunges=lunges, **(schedule or {})):
        plant.fire_due(events)
        plant.step(target)
    return plant.trajectory()
