"""Offline identification, SPI-style (paper §III-B): CMA-ES over rollout-matching clips.

``N_c`` clips with horizons drawn uniformly from a range are cut from the log
where the box moves (:func:`~amhe_cli.estimation.clips.sample_clips`) — or, with
``candidates`` > 1, the ``N_c`` of ``candidates × N_c`` such clips that inform the
free parameters most (:func:`~amhe_cli.estimation.uncertainty.clip_information`
at the prior, :func:`~amhe_cli.estimation.clips.choose_informative`); CMA-ES
(the ``cma`` package, ask/tell) minimises the shared cost ``J`` (eq. 1) over the
free parameters.

**The estimate is CMA-ES's final mean** — the rank-weighted recombination of
the best candidates, which uses only the order of the costs and so is robust to
the rough floor that rocking contacts give ``J``. Before, the estimate
was the minimum of a quadratic fitted by least squares to the late half of the
generations; on the bundled 2.5 kg example (seed 0) that read 2.354 kg (−5.8 %)
where the CMA-ES mean stood at 2.540 kg, and ``J`` at the quadratic's minimum
was 120 against 30 at the mean: ``J`` is not quadratic over the cloud CMA-ES
leaves behind (a narrow trough at the truth in broad walls, samples of
generations 20–40 spanning where the mean still moved), and least squares lets
the far, costly samples set the minimum. Measured over 4 seeds on 5 logs
(``nthread=1``), mean |mass error| with the quadratic → with the mean: 2.5 kg
example 1.9 % → 0.9 % (worst −5.8 % → +1.6 %), 5 kg example 1.5 % → 0.7 %,
``const_a`` 0.9 % → 0.5 %; friction within 0.006 on all three either way. A
last-quarter fit, cost-rank-weighted fits and a local kernel fit were mostly
not convex (falling back to the mean) and no better where they were; the best
single sample was as accurate but reads one draw of the rough floor.

The belief's covariance is the larger of the local Fisher information / sandwich
(:mod:`~amhe_cli.estimation.uncertainty`) and a bootstrap over clips of
per-clip quadratics fitted to the late generations
(:func:`~amhe_cli.estimation.surrogate.bootstrap_minima`: the spread of the
optimum over plausible clip sets, which is what differs between seeds, along
the directions the clips resolve), **plus** CMA-ES's own search spread when it
stopped (where in its spread the search stopped is an error of its own, and it
covers the directions the clips leave unresolved). Before, each bootstrap
resample floored its curvature positive and was held within 3 sample σ of the
mean, and the search spread was a floor, not a term: along a flat direction the
floored step ran to the bound and dragged the mass with it, so the mass's σ was
3× the cloud CMA-ES left in every log, 4–10× the error on the clean ones (RMS
of (estimate − truth)/σ over 8 seeds: ``const_a`` 0.10, ``mismatch_b`` 0.23,
the 5 kg example 0.14; docs/benchmarks.md has the table with this one's).
On a log with pose noise, friction's σ also holds what a clip's smoothed
initial velocity cannot tell (:func:`~amhe_cli.estimation.uncertainty.sensing_friction_std`,
``std_sources.sensing``). What no σ from the log sees is a bias every clip
shares (a model unlike the log's robot): the residual rms reported beside it
is the flag for that. The candidates are reported beside it (``std_sources``
in ``--json``).

CMA-ES searches in prior-σ units, ``z = (p - p0) / σ_prior``, so a kilogram and a
friction coefficient are steps of comparable meaning.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from amhe_cli.estimation.clips import Clips, choose_informative, rest_travel, sample_clips
from amhe_cli.estimation.cost import RolloutCost, StateWeights
from amhe_cli.model.params import DEFAULT_FREE, ParameterSpace
from amhe_cli.model.scene import Scene
from amhe_cli.io.smoothing import velocity_noise
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.estimation.surrogate import bootstrap_minima, fit_valley, unresolved_variance
from amhe_cli.estimation.uncertainty import (Curvature, clip_information, curvature, sensing_friction_std,
                                             with_covariance)


@dataclass
class IdentifySettings:
    """Settings of one identification run (stored in the belief's provenance).

    Attributes:
        params: free parameter names.
        n_clips: number of clips ``N_c``; None: :func:`clip_plan` chooses by the log's noise.
        horizon: (min, max) clip horizon [s], drawn uniformly; None: :func:`clip_plan`.
        popsize: CMA-ES population (candidates per generation, ``B``).
        max_gen: generation limit. 30, with the estimate averaged over the last 6
            means: against 40 generations and the final mean, the same accuracy
            over 8 seeds × 5 logs (mass error ±5 % on the noisy and mismatched
            logs either way) and a truer σ (2σ coverage 92 % against 84 %) in
            0.70 of the time (one thread each on 16 cores; on 2 cores, ``amhe
            identify`` on a 20 s log: 32.8 s against 42.2 s, median of 3).
            Then 24 against 30, on the same 8 seeds × 5 logs: no log worse
            beyond its seed-to-seed spread (noisy log: worst mass 9.3 % against
            11.6 %, μ 0.040 against 0.050; mismatched robot: median 4.9 %
            against 6.2 %), 2σ coverage 95.5 % against 94.5 %, in 0.85 of the
            time (2 cores, ``amhe identify`` on a 20 s log: 31.9 s against
            37.5 s, medians of 3 in one session; 27.7 s against 32.7 s on a
            quieter day). Of the 27.7 s, 24 s were rollouts at raw
            ``mujoco.rollout`` speed, 2.5 s reading the log and 1.3 s imports;
            the model's sparse constraint Jacobian then cut the whole to 23.9 s
            against 30.9 s (same session, same estimate). Stopping once CMA-ES's
            search spread is inside the data's σ (after 8–16 generations) did
            not hold: const_a ± 2.2 % against ± 0.9 %, the 2.5 kg example's
            worst 17 % against 4 % (8 seeds × 6 logs).
            What did not hold: popsize 10
            (worst mass 18.5 %, coverage 87 %), and the first 8 generations on
            every other clip (0.67 of the time; noisy log worst 12.6 %, μ
            0.053). (The seed-to-seed spread is mostly which clips were drawn,
            not CMA-ES's path: on one fixed clip set the mass moved ± 0.9–1.9 %
            over CMA-ES seeds, ± 5–6 % with the clips drawn anew; see ``candidates``.)
        candidates: > 1 chooses the clips by their information about the free
            parameters at the prior (:func:`~amhe_cli.estimation.clips.choose_informative`)
            among this many times ``n_clips`` drawn by box motion; 1 keeps the
            draw by box motion alone; None: :func:`clip_plan` chooses (1 on a
            clean log whose robot is found unlike its model, 4 otherwise). The
            pre-pass costs ``d + 1`` rollouts of every candidate clip and the
            chosen clips are richer in contacts: 1.06× the wall time on
            ``const_a`` (2 cores), 1.1–1.2× on 16.
        sigma0: initial CMA-ES step in prior-σ units.
        tolx: stop when every coordinate's CMA-ES step is below this, in
            prior-σ units (3e-3: 9 g of mass, 0.0015 of friction at the
            default prior σ's — below what the logs resolve).
        prior_weight: scales ``W_p`` (0: no prior term).
        seed: seeds clip selection and CMA-ES.
        t_range: (t0, t1) [s] part of the log to use, or None for all of it.
        sigma: state-error σ per group overriding the defaults (``W_x``).
        average_last: the estimate is the mean of CMA-ES's means over this many
            last generations (0 or 1: the final mean): on a rough cost the mean
            jitters by about its search spread from one generation to the next.
        replicates: ``K`` searches run in lock-step (:func:`_searches`): the
            main one, whose mean is the estimate, and ``K − 1`` on bootstrap
            resamples of the clips from their own CMA-ES seeds, whose spread is
            the ``replicates`` σ (the bootstrap of the whole estimator). 1: the
            main search alone. ``K``× the rollouts, in the same number of
            rollout calls.
    """

    params: tuple = DEFAULT_FREE
    n_clips: int | None = None
    horizon: tuple | None = None
    popsize: int = 12
    max_gen: int = 24
    candidates: int | None = None
    sigma0: float = 0.3
    tolx: float = 3e-3
    prior_weight: float = 1.0
    seed: int = 0
    t_range: tuple | None = None
    sigma: dict = field(default_factory=dict)
    average_last: int = 6
    replicates: int = 1


@dataclass
class IdentifyResult:
    """What :func:`identify` found.

    Attributes:
        space: the parameter space (labels, prior).
        estimate: (d,) the estimate ``p̂``.
        curvature: belief covariance etc. at ``p̂``.
        cost_prior, cost_estimate: ``J`` at the prior mean and at ``p̂``.
        residual_rms: sqrt(data term / simulated steps) at ``p̂``: ≈ 1 means the
            model explains the log to within the ``W_x`` σ's; ≫ 1 flags a
            model mismatch.
        history: per generation: best cost, mean cost, step size, mean (d,).
        clips: the clips used.
        wall_time: seconds.
        evaluations: candidate evaluations.
        converged: CMA-ES stopped on one of its own convergence criteria
            (``tolx``, ``tolfun``, a flat fitness, ...), or its search spread
            per coordinate had shrunk below the estimate's σ from the data
            (``stop["search_within_sigma"]``: more generations would move it by
            less than its uncertainty); False when the generation limit
            ``max_gen`` stopped a search still wider than that, so the estimate
            may still be moving, its σ includes the search's spread and
            ``residual_rms`` says nothing about model fit.
        stop: the CMA-ES termination conditions that fired, name -> value
            (e.g. ``{"maxiter": 40}`` or ``{"tolx": 0.003}``).
        replicates: (K − 1, d) the bootstrap replicates' estimates
            (``settings.replicates``); (0, d) without.
        unsettled: where the generation limit stopped the search, each coordinate (its label) whose
            search spread was still wider than its σ from the data -> that ratio (> 1); empty when converged.
    """

    space: ParameterSpace
    estimate: np.ndarray
    curvature: Curvature
    cost_prior: float
    cost_estimate: float
    residual_rms: float
    history: list
    clips: Clips
    settings: IdentifySettings
    wall_time: float
    evaluations: int
    converged: bool = True
    stop: dict = field(default_factory=dict)
    replicates: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    unsettled: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """JSON-ready ``{"estimate", "std", "prior", ...}`` (vectors as lists)."""
        sp = self.space
        std = self._physical_std(self.curvature.std)
        return {
            "estimate": sp.free_values(self.estimate),
            "std": std,
            "prior": sp.free_values(sp.mean0),
            "labels": list(sp.labels),
            "correlation": self.curvature.corr.tolist(),
            "cost": {"prior": self.cost_prior, "estimate": self.cost_estimate,
                     "residual_rms": self.residual_rms},
            "clips": len(self.clips),
            "generations": len(self.history),
            "evaluations": self.evaluations,
            "wall_time_s": self.wall_time,
            "converged": bool(self.converged),
            "stop": {k: (float(v) if isinstance(v, (int, float, np.number)) else str(v)) for k, v in self.stop.items()},
            "std_sources": {src: self._physical_std(v) for src, v in self.curvature.sources.items()},
            "replicates": [sp.free_values(r) for r in self.replicates],
            "unsettled": {k: float(v) for k, v in self.unsettled.items()},
        }

    def _physical_std(self, std: np.ndarray) -> dict:
        """name -> σ in physical units of a (d,) σ in the space's flat coordinates."""
        _, phys = self.space.physical(self.estimate, std)
        return {name: float(phys[sl][0]) if phys[sl].size == 1 else [float(x) for x in phys[sl]]
                for name, sl in self.space.slices().items()}


#: Clips (count, horizon range [s]) where the box's velocity as read holds measurement noise (the clip's
#: initial state is off by it, and a longer clip lets the position errors outweigh it).
NOISY_LOG_CLIPS = (32, (0.1, 0.2))
#: Clips where it holds none (a clean or simulated log): shorter, and as many more as keep the simulated
#: time per candidate the same (48 × 0.1 s against 32 × 0.15 s on average).
CLEAN_LOG_CLIPS = (48, (0.07, 0.13))
#: Candidates per clip for the information choice (all logs but a clean one of a robot unlike its model).
INFORMATION_CANDIDATES = 4


def clip_plan(traj: Trajectory, n_clips: int | None = None, horizon: tuple | None = None,
              candidates: int | None = None) -> tuple[int, tuple, int]:
    """How many clips, how long and how chosen for ``traj``: ``(N_c, (min, max) [s], candidates)``.

    A value given wins; None is chosen here from what the log's reading found
    (``traj.meta["sensors"]``).

    **Length.** The horizon trades two errors. Each clip starts from the
    recorded state, so an error σ_v in the box's initial velocity moves its
    rolled-out position by σ_v·t; the longer the clip, the more its position
    errors outweigh that start. But a push is chaotic in the parameters (a
    foot meets the box one step sooner or later, the gait's stance shifts),
    and that roughness of the cost grows with the horizon. So a log whose box
    velocity holds measurement noise (:func:`~amhe_cli.io.smoothing.velocity_noise`
    > 0: pose noise read through the smoother) gets :data:`NOISY_LOG_CLIPS`,
    32 clips of 0.1–0.2 s, and one without gets :data:`CLEAN_LOG_CLIPS`, 48 of
    0.07–0.13 s (the same simulated time per candidate, so the same wall time).

    **Choice.** The clips are chosen by their information about the free
    parameters (:data:`INFORMATION_CANDIDATES` times as many drawn by box
    motion, :func:`~amhe_cli.estimation.clips.choose_informative`): a handful
    of clips carries most of the information, and a draw by motion differs
    from seed to seed in which it holds. One case keeps the draw by motion: a
    clean log whose reading found the robot unlike its model
    (``sensors["robot_differs"]``: gains fitted from its efforts, or a
    payload; :func:`~amhe_cli.estimation.problem.load_problem`). There the
    information read at a wrong model points at the bumps, where the mismatch
    acts; on a noisy log the draw by motion's clips of noise cost more than that.

    *Measured* (8 seeds per log, one thread each, mass error mean ± std
    (worst)):

    - clean logs, 48 × 0.07–0.13 s against 32 × 0.1–0.2 s (by motion):
      ``mismatch_b`` (a robot unlike its model) +2.6 ± 2.9 % (7.6) against
      +6.2 ± 5.2 % (12.3), μ within 0.008 against 0.036; ``const_a``
      +0.6 ± 1.1 % (2.3) against +0.8 ± 0.9 %; the bundled examples
      +2.5 ± 1.0 % (4.5) and +0.7 ± 1.0 % (2.5) against +2.0 ± 1.5 % (4.2)
      and +1.1 ± 0.9 % (2.9). On the noisy logs the short clips lose:
      ``noisy_b`` +4.2 ± 9.4 % (14.4) against +3.1 ± 6.5 % (14.3), the noisy
      mismatched log +6.0 ± 13.2 % (23.4) against +6.0 ± 5.6 % (11.9); 64
      clips of 0.05–0.1 s: ``mismatch_b`` +4.0 ± 3.2 % (8.7), ``noisy_b``
      worst 16.9 %; 27 of 0.12–0.24 s: ``noisy_b`` −16.0 ± 40.0 %.
    - by information against by motion: ``noisy_b`` +4.0 ± 3.5 % (8.4, μ
      0.040) against +3.1 ± 6.5 % (14.3); ``const_a`` with ``noisy_b``'s
      motion capture (``benchmarks/mocap_degrade.py``) +4.7 ± 3.1 % (8.0)
      against +4.2 ± 7.2 % (12.8); clean ``const_a`` −0.3 ± 0.4 % (0.7) and
      the examples +2.0 ± 1.3 % (4.0), +0.8 ± 1.0 % (2.4), as good as by
      motion; ``mismatch_b`` +6.0 ± 4.1 % (14.7) against +2.6 ± 2.9 % (7.6);
      ``mismatch_b`` with three draws of ``noisy_b``'s motion capture
      +10.5 ± 9.0 % (31.5), +0.4 ± 8.3 % (−15.6), +2.9 ± 10.4 % (16.7)
      against +6.0 ± 5.6 % (11.9), −4.5 ± 16.1 % (−29.7), +6.6 ± 13.7 %
      (30.6): rms 11.2 % against 13.9 %. A mixture (weights ¾ information, ¼
      uniform) read the first +3.3 ± 8.7 % (14.1).

    Per-clip cost along the line from an estimate to the truth on
    ``mismatch_b`` (25 points) varied most, up to 5× its range in total
    variation, on the push clips (box at 0.3–0.7 m/s, robot at the box).
    """
    noisy = velocity_noise(traj.meta, "box", traj.dt) > 0
    plan_n, plan_h = NOISY_LOG_CLIPS if noisy else CLEAN_LOG_CLIPS
    plan_c = 1 if traj.meta.get("sensors", {}).get("robot_differs") and not noisy else INFORMATION_CANDIDATES
    return ((plan_n if n_clips is None else int(n_clips)), (plan_h if horizon is None else tuple(horizon)),
            (plan_c if candidates is None else int(candidates)))


def identify(traj: Trajectory, scene: Scene, space: ParameterSpace, settings: IdentifySettings,
             progress: Callable[[int, float], None] | None = None, nthread: int | None = None) -> IdentifyResult:
    """Identify the free parameters of ``space`` from ``traj``.

    Args:
        traj: recorded trajectory on the model's timestep.
        scene: model ``f`` (geometry matched to the log).
        space: free parameters and prior.
        settings: see :class:`IdentifySettings`.
        progress: called after each generation with (generation, best cost).
        nthread: rollout threads.

    Raises:
        AmheError: the log has no usable clip.
    """
    t0 = time.perf_counter()
    n_clips, horizon, candidates = clip_plan(traj, settings.n_clips, settings.horizon, settings.candidates)
    # the belief's provenance says what ran
    settings = replace(settings, n_clips=n_clips, horizon=horizon, candidates=candidates)
    rng = np.random.default_rng(settings.seed)
    by_information = settings.candidates > 1
    # candidates for an information choice leave out a box that only pose noise moves: its noisy start
    # reads as friction information (a random draw keeps them: measured, dropping them there moved noisy_b's
    # mass from +3.0 ± 6.5 % to +8.9 ± 4.7 %)
    clips = sample_clips(traj, scene, settings.n_clips, settings.horizon, rng=rng, t_range=settings.t_range,
                         min_travel=rest_travel(traj) if by_information else 0.0, candidates=settings.candidates)
    weights = StateWeights.for_log(traj, dict(settings.sigma))
    with RolloutCost(scene, space, clips, weights, prior_weight=settings.prior_weight, nthread=nthread) as cost:
        if by_information and len(clips) > settings.n_clips:  # keep the clips that inform most
            clips = clips.subset(choose_informative(clip_information(cost, space.mean0), settings.n_clips, rng))
            cost.set_clips(clips)
        p0, s0 = space.mean0, space.std0
        import cma  # here, not at import: it loads matplotlib.pyplot and scipy.stats (1–2 s)
        cost_prior = float(cost(p0[None])[0])
        main, reps = _searches(cma, cost, space, settings, cost_prior, progress)
        es, history, stop, converged = main.es, main.history, main.stop, main.converged
        evals = sum(r.evals for r in [main, *reps])
        samples_z, samples_j, samples_clip, samples_gen = main.samples
        # The estimate is CMA-ES's own (rank-weighted) mean: robust to the cost's rough floor, where a
        # least-squares quadratic over the late generations was pulled by far, costly samples (module doc).
        z_mean = main.mean_z(space, settings.average_last)
        estimate = space.project(p0 + z_mean * s0)[0][0]
        rep_estimates = np.array([space.project(p0 + r.mean_z(space, settings.average_last) * s0)[0][0]
                                  for r in reps]).reshape(-1, space.dim)
        curv = curvature(cost, estimate)  # its centre rollout also gives J at the estimate
        j_est, data = curv.cost, curv.data
        # spread over clip sets: per-clip quadratics over the late generations, resampled over clips
        boot = _clip_set_cov(samples_z, samples_j, samples_clip, samples_gen, z_mean, settings)
        search_std = np.asarray(es.result.stds, dtype=float) * s0
        curv.sources["search"] = search_std
        if len(rep_estimates) >= 2:
            curv.sources["replicates"] = rep_estimates.std(axis=0, ddof=1)
        if boot is not None:
            boot_cov = boot * np.outer(s0, s0)
            curv.sources["clip_bootstrap"] = np.sqrt(np.maximum(np.diag(boot_cov), 0.0))
            if np.trace(boot) > np.trace(curv.cov / np.outer(s0, s0)):
                curv = with_covariance(curv, boot_cov)
        # a search stopped before converging has not narrowed further than its own spread
        if not converged and np.all(search_std <= curv.std):
            # the search's spread is inside what the data can tell (the rough floor of the cost keeps
            # tolx from firing): more generations would move the estimate by less than its σ
            converged = True
            stop["search_within_sigma"] = True
        ratio = search_std / np.maximum(curv.std, 1e-300)
        unsettled = {} if converged else {space.labels[i]: float(ratio[i]) for i in np.flatnonzero(ratio > 1)}
        # where CMA-ES stopped inside its own spread (which draw of the rough floor ended the search) is an error
        # of its own, beside the clip sets': a term, not a floor (docs/benchmarks.md, "Does the stated σ ...")
        curv = with_covariance(curv, curv.cov + np.diag(search_std ** 2))
        # a noisy log's clips start from a smoothed velocity whose error no resample or search sees
        sense = np.zeros(space.dim)
        sense[space.slices().get("box_friction", slice(0, 0))] = sensing_friction_std(
            velocity_noise(traj.meta, "box", traj.dt), float(np.mean(clips.horizon)) * traj.dt)
        if np.any(sense > 0):
            curv.sources["sensing"] = sense
            curv = with_covariance(curv, curv.cov + np.diag(sense ** 2))
    return IdentifyResult(
        space=space, estimate=estimate, curvature=curv, cost_prior=cost_prior, cost_estimate=j_est,
        residual_rms=float(np.sqrt(data / max(clips.steps, 1))), history=history, clips=clips,
        settings=settings, wall_time=time.perf_counter() - t0, evaluations=evals,
        converged=converged, stop=stop, replicates=rep_estimates, unsettled=unsettled,
    )


@dataclass
class _Search:
    """One CMA-ES search of :func:`_searches`: its strategy, clip weights and trace."""

    es: object
    weights: np.ndarray | None  # (N_c,) clip multiplicities; None: every clip once (J as the cost module sums it)
    history: list = field(default_factory=list)
    samples: tuple = field(default_factory=lambda: ([], [], [], []))  # z, J, per-clip J, generation of each
    best: float = np.inf
    evals: int = 0
    stop: dict = field(default_factory=dict)
    converged: bool = False
    rng_state: tuple = field(default_factory=np.random.get_state)  # see _searches

    def mean_z(self, space: ParameterSpace, average_last: int) -> np.ndarray:
        """(d,) CMA-ES's mean in its coordinates, averaged over the last ``average_last`` generations."""
        if average_last > 1 and self.history:
            return np.mean([(np.asarray(h["mean"]) - space.mean0) / space.std0
                            for h in self.history[-average_last:]], axis=0)
        return np.asarray(self.es.mean, dtype=float)


def _searches(cma, cost: RolloutCost, space: ParameterSpace, settings: IdentifySettings, cost_prior: float,
              progress: Callable[[int, float], None] | None) -> tuple[_Search, list[_Search]]:
    """Run the main search and ``settings.replicates − 1`` bootstrap replicates in lock-step.

    Every generation, the candidates of all searches still running go to the
    cost module as one batch (one rollout call: on a GPU the replicates fill
    worlds that would otherwise idle). The main search minimises ``J`` over the
    chosen clips; replicate ``k`` minimises the same ``J`` with each clip
    counted as often as a resample of the clips with replacement drew it, from
    its own CMA-ES seed — the nonparametric bootstrap of the whole estimator
    (Efron & Tibshirani 1993, ch. 6), rough floor and CMA-ES's path included.

    Args:
        cma: the ``cma`` module.
        cost_prior: ``J`` at the prior mean (the best cost before any generation, for ``progress``).
    Returns:
        the main search and the replicates (``settings.replicates − 1``, ≥ 0).
    """
    p0, s0 = space.mean0, space.std0
    opts = {
        "popsize": settings.popsize, "verbose": -9,
        "bounds": [list((space.lower - p0) / s0), list((space.upper - p0) / s0)],
        "maxiter": settings.max_gen, "tolfun": 1e-12, "tolx": settings.tolx, "tolflatfitness": 5,
    }
    n_clips = len(cost.clips)
    searches = [_Search(cma.CMAEvolutionStrategy(np.zeros(space.dim), settings.sigma0,
                                                 dict(opts, seed=settings.seed + 1)), None, best=cost_prior)]
    # the replicates' resamples come from their own generator: the main search is the same with or without them
    boot = np.random.default_rng([settings.seed, 1])
    for k in range(1, max(settings.replicates, 1)):
        w = np.bincount(boot.integers(0, n_clips, size=n_clips), minlength=n_clips).astype(float)
        searches.append(_Search(cma.CMAEvolutionStrategy(np.zeros(space.dim), settings.sigma0,
                                                         dict(opts, seed=settings.seed + 1 + 7919 * k)), w))
    # ``cma`` draws from numpy's global generator (seeded by its ``seed`` option when a strategy is made):
    # each search keeps its own generator state, swapped in around its calls, so that the searches do not
    # draw from one stream and the main search samples the same with or without replicates
    outer = np.random.get_state()
    while True:
        active = [s for s in searches if not s.es.stop()]
        if not active:
            break
        Zs = [np.array(_own_rng(s, s.es.ask)) for s in active]
        br = cost.evaluate(p0 + np.concatenate(Zs) * s0)
        i = 0
        for s, Z in zip(active, Zs):
            rows = slice(i, i + len(Z))
            i += len(Z)
            J = br.total[rows] if s.weights is None else (
                br.per_clip[rows] @ s.weights + br.prior[rows] + br.penalty[rows])
            s.evals += len(Z)
            _own_rng(s, s.es.tell, list(Z), list(J))
            s.best = min(s.best, float(J.min()))
            s.history.append({"generation": len(s.history) + 1, "best": float(J.min()), "mean_cost": float(J.mean()),
                              "sigma": float(s.es.sigma), "mean": (p0 + np.asarray(s.es.mean) * s0).tolist()})
            if s.weights is None:  # the main search's samples feed the clip bootstrap
                ok = ~br.diverged[rows].any(axis=1) & (br.penalty[rows] == 0)
                sz, sj, sc, sg = s.samples
                sz.append(Z[ok])
                sj.append(J[ok])
                sc.append(br.per_clip[rows][ok])
                sg += [len(s.history) - 1] * int(ok.sum())
                if progress:
                    progress(len(s.history), s.best)
    np.random.set_state(outer)
    for s in searches:
        s.stop = {str(k): v for k, v in dict(s.es.stop()).items()}
        # converged: some criterion other than the generation limit fired (or, in identify, the search
        # narrowed within the data's own uncertainty)
        s.converged = any(k != "maxiter" for k in s.stop) or not s.stop
    return searches[0], searches[1:]


def _own_rng(search: _Search, fn: Callable, *args):
    """``fn(*args)`` with numpy's global generator in ``search``'s own state (kept for its next call)."""
    np.random.set_state(search.rng_state)
    try:
        return fn(*args)
    finally:
        search.rng_state = np.random.get_state()


def _clip_set_cov(samples_z: list, samples_j: list, samples_clip: list, samples_gen: list, z_mean: np.ndarray,
                  settings: IdentifySettings) -> np.ndarray | None:
    """(d, d) covariance, in CMA-ES coordinates, of the optimum over resampled clip sets.

    Per-clip quadratics fitted to the samples of the late half of the
    generations (:func:`~amhe_cli.estimation.surrogate.fit_valley`),
    bootstrapped over clips (:func:`~amhe_cli.estimation.surrogate.bootstrap_minima`)
    along the directions they resolve, plus the cloud's extent along the ones
    they do not (:func:`~amhe_cli.estimation.surrogate.unresolved_variance`);
    no rollouts. None with too few samples for a quadratic.
    """
    gens = np.asarray(samples_gen)
    if gens.size == 0:
        return None
    late = gens >= (gens.max() + 1) // 2
    Zs = np.concatenate(samples_z)[late]
    Js = np.concatenate(samples_j)[late]
    Ks = np.concatenate(samples_clip)[late]
    valley = fit_valley(Zs, Js, z_mean)
    if valley is None:
        return None
    minima = bootstrap_minima(Zs, Ks, valley, settings.prior_weight, rng=np.random.default_rng(settings.seed))
    d = z_mean.size
    return np.cov(minima.T).reshape(d, d) + np.diag(unresolved_variance(valley, settings.prior_weight))


def settings_dict(settings: IdentifySettings) -> dict:
    """Settings as plain YAML/JSON types."""
    d = asdict(settings)
    d["params"] = list(d["params"])
    if d["horizon"] is not None:
        d["horizon"] = list(d["horizon"])
    if d["t_range"] is not None:
        d["t_range"] = list(d["t_range"])
    return d
