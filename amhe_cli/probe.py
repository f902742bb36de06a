"""Probing: make informative data for a first belief, and judge what a log can tell.

The paper's Adaptive-MHE "first initializes its belief via an offline probing
estimation step" (§V). Here that is two things:

* :func:`simulate_probe` — a scripted probing manoeuvre (lunges, see
  :mod:`~amhe_cli.maneuver`) in the project's own sim plant with chosen true
  parameters, recorded as a :class:`Trajectory` (``amhe probe --target sim``
  writes it as an MCAP in the project schema and identifies from it);
* :func:`assess` — for any log, how well each parameter can be identified from
  it: the cost's Fisher information around the prior (through the shared cost
  module), the standard deviations it implies and the correlations.
"""

from __future__ import annotations

import json

import numpy as np

from .clips import sample_clips
from .cost import RolloutCost
from .params import ParameterSpace
from .plant import SimPlant
from .scene import Scene, SceneConfig
from .maneuver import lunge_schedule
from .tasks import Event
from .trajectory import Trajectory
from .uncertainty import Curvature, curvature

#: Metadata record holding the ground truth of logs amhe simulates.
TRUTH_RECORD = "amhe_truth"


def metadata_truth(traj: Trajectory) -> dict | None:
    """Ground truth a log amhe simulated carries (record :data:`TRUTH_RECORD`): name -> value, else None."""
    rec = traj.meta.get("metadata", {}).get(TRUTH_RECORD)
    if not rec:
        return None
    out = {}
    for k, v in rec.items():
        try:
            out[k] = json.loads(v) if isinstance(v, str) else v
        except json.JSONDecodeError:
            continue
    return out

#: Gap between the standing robot's head and the box's back face [m].
HEAD_GAP = 0.01
#: x of the head's front face of a Go1 standing at the origin [m] (head_top capsule).
HEAD_FRONT_X = 0.276


def simulate_probe(truth: dict, config: SceneConfig | None = None, seed: int = 0,
                   lunges=(0.06, 0.09, 0.12), friction_step: tuple[float, float] | None = None,
                   schedule: dict | None = None) -> Trajectory:
    """Run the lunge probe in a sim plant with ``truth`` and return the recording.

    Args:
        truth: name -> true value (see :data:`~amhe_cli.params.PARAMETERS`).
        config: scene geometry (default :class:`SceneConfig`).
        seed: varies the box's lateral offset (±3 cm) and yaw (±0.1 rad) so
            that example logs differ.
        lunges: reach of each lunge [m].
        schedule: phase durations passed to :func:`~amhe_cli.maneuver.lunge_schedule`
            (``strike``, ``hold``, ``retreat``, ``rest`` [s]).
        friction_step: (x_b [m], μ after) — the box–floor friction of the plant
            switches to μ after once the box centre passes x = x_b (task T4's
            event, DESIGN.md §6).
    Returns:
        the recorded :class:`Trajectory` on the plant's 2 ms grid, with the
        plant's ``meta['truth']`` and ``meta['truth_series']`` (see
        :meth:`~amhe_cli.plant.SimPlant.trajectory`).
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


def assess(traj: Trajectory, scene: Scene, space: ParameterSpace, n_clips: int = 32,
           horizon=(0.1, 0.2), seed: int = 0, nthread: int | None = None) -> Curvature:
    """Identifiability of ``space``'s free parameters from ``traj``, at the prior mean.

    Returns the :class:`~amhe_cli.uncertainty.Curvature` of the shared cost
    over ``n_clips`` clips: Fisher information, implied standard deviations
    (prior included) and correlations.
    """
    clips = sample_clips(traj, scene, n_clips, horizon, rng=np.random.default_rng(seed))
    with RolloutCost(scene, space, clips, nthread=nthread) as cost:
        return curvature(cost, space.mean0, at_estimate=False)
