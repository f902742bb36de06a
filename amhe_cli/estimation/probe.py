"""Probing: judge what a log can tell about each parameter.

The paper's Adaptive-MHE "first initializes its belief via an offline probing
estimation step" (§V). Making the probing data is a manoeuvre on a plant
(:func:`~amhe_cli.control.maneuver.simulate_probe`); here is the estimation
half: :func:`assess` says, for any log, how well each parameter can be
identified from it: the cost's Fisher information around the prior (through the
shared cost module), the standard deviations it implies and the correlations.
"""

from __future__ import annotations

import numpy as np

from amhe_cli.estimation.clips import sample_clips
from amhe_cli.estimation.cost import RolloutCost
from amhe_cli.estimation.identify import clip_plan
from amhe_cli.model.params import ParameterSpace
from amhe_cli.model.scene import Scene
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.estimation.uncertainty import Curvature, curvature


def assess(traj: Trajectory, scene: Scene, space: ParameterSpace, n_clips: int | None = None,
           horizon=None, seed: int = 0, nthread: int | None = None) -> Curvature:
    """Identifiability of ``space``'s free parameters from ``traj``, at the prior mean.

    Returns the :class:`~amhe_cli.estimation.uncertainty.Curvature` of the shared cost
    over ``n_clips`` clips of ``horizon`` = (min, max) [s] (None: as ``identify``
    would draw them, :func:`~amhe_cli.estimation.identify.clip_plan`): Fisher
    information, implied standard deviations (prior included) and correlations.
    """
    n_clips, horizon, _ = clip_plan(traj, n_clips, horizon)
    clips = sample_clips(traj, scene, n_clips, horizon, rng=np.random.default_rng(seed))
    with RolloutCost(scene, space, clips, nthread=nthread) as cost:
        return curvature(cost, space.mean0, at_estimate=False)
