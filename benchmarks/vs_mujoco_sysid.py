"""amhe ``identify`` (CMA-ES) against MuJoCo 4.0's own identifier (``mujoco.sysid``) on the same data.

Usage::

    python benchmarks/vs_mujoco_sysid.py [LOG ...] [--truth T.yaml|auto ...] [--params box_mass,box_friction]
        [--clips 32] [--seed 0] [--threads 2] [--sysid-eps EPS] [--sysid-max-iters N]

What it measures. For each log, both identifiers estimate the same free parameters (box mass and
box–floor friction by default; ``box_inertia`` may be added) from the same clips, and the table
compares their estimates with the ground truth:

* **amhe**: :func:`amhe_cli.estimation.identify.identify` with the CLI defaults (``--clips`` clips,
  ``--seed``): CMA-ES over the rollout-matching cost ``J`` (whitened tangent-space state errors
  + the prior term), σ from amhe's curvature/bootstrap belief.
* **mujoco.sysid**: ``sysid.optimize(..., optimizer="mujoco")``, i.e. ``mujoco.minimize.least_squares``:
  box-bounded Gauss–Newton/Levenberg–Marquardt with a forward finite-difference Jacobian
  (step ``eps·max(1, |x|)``, default eps = √machine-ε ≈ 1.5e-8), started at amhe's prior mean,
  within amhe's bounds. It gets **amhe's clips** (``result.clips`` of the amhe run: the same initial
  states, recorded controls and recorded targets), one ``ModelSequences`` entry per clip, and it
  minimises **the same residual**: a custom ``modify_residual`` returns amhe's
  ``sqrt(W_x)·state_error(x(p), x^r)`` (:mod:`amhe_cli.estimation.cost`: box planar position/yaw and
  velocities, robot states lightly weighted, box rocking left out; unobserved samples dropped), with
  the very ``W_x`` and prior weight the amhe run used (read off its ``RolloutCost``), and
  the prior rows ``(p − p0)/σ_prior`` are appended, so Σ r² equals amhe's ``J`` (data + prior). The
  script checks this: J from sysid's residual at amhe's prior mean must equal amhe's
  ``RolloutCost`` there (stderr line ``J check``).
  σ is mujoco.sysid's own: ``calculate_intervals(r*, J)`` → ``Σ = s²·(JᵀJ)⁻¹`` with
  ``s² = Σr²/(n − p)`` at the optimum (the FD Jacobian of the final point), reported here as
  σ = CI half-width / t₀.₉₇₅(n − p), i.e. √diag Σ (∞ where JᵀJ is numerically singular in that
  parameter's direction).

Parameters are written into the model the way amhe writes them (``ParameterSpace.write``): each
``sysid.Parameter`` has a modifier that sets ``body_mass`` (inertia follows mass: prior moments ×
m/m_prior, or × the free shape ratio when ``box_inertia`` is free) or ``pair_friction`` columns 0 and 1
of every box–floor pair; ``build_model`` copies the scene's compiled model, applies the modifiers
with ``sysid.apply_param_modifiers_spec`` and calls ``mj_setConst``. amhe's ``Scene`` keeps only its
compiled ``MjModel`` (PD gains are written after compiling), so ``ModelSequences`` gets a stand-in
"spec" whose ``compile()`` returns a copy of that model; nothing is recompiled. The script checks that
the modifiers give the same model as ``ParameterSpace.write`` (masses, inertias, frictions, servo
gains, ``body_invweight0``, ``dof_invweight0``).

What sysid's note means. ``insufficient reduction``: Levenberg–Marquardt raised its regulariser to
``mu_max`` (1e8) without finding a step that lowers J, so it stopped where it was, which need not be a
minimum of J (compare the J column). Measured on the 2.5 kg example and ``const_a`` at sysid's
stopping points: the forward-difference slopes of J are reproducible (equal to 3–4 digits for steps
of 1e-8 to 1e-6), so the Jacobian is not noisy; but J is only piecewise smooth: steps of 1e-5 (μ) to
1e-4 (kg) already cross jumps where the slope reads 100–1000× larger and often of the other sign
(contacts that open or close, the box rocking on its corners, in 32 clips at once). On ``const_a``
the LM step at ``mu_max`` (Δμ = 8.7e-6) raised J by 6 where the linear model promised a fall of 0.015; only at
mu = 1e9 (Δμ = 9e-7) did J fall as predicted, by 1.5e-3. The Gauss–Newton model holds on a piece
narrower than the steps LM may take; amhe's CMA-ES uses only the ranking of J and steps over the jumps.

How to read the table. One row per method and log: estimate ± σ and error for the mass (error in %
of the truth) and μ (absolute error), ``J`` = amhe's cost at that method's estimate (the same
objective for both: the lower J found the better minimum of it), wall time [s] of the
identification (amhe: clip sampling + CMA-ES + σ; sysid: setup + optimisation + σ; rollouts on
``--threads`` threads) and the number of simulated MuJoCo steps it took (all rollouts, σ included).
``note``: amhe's stop condition; sysid's termination status and iterations, ``bound`` if an
estimate sits on a box bound. The last line summarises over logs: mean |mass error|, mean |μ error|,
how many estimates lie within 2σ of the truth, and the total wall times. Wall times are of one run
on a shared machine: compare them only within one table.

Limits of the comparison: sysid keeps candidates only inside the box bounds; amhe also projects
inertia ratios onto the triangle inequalities and charges the distance (``--params ...,box_inertia``
lets sysid write physically inconsistent moments). sysid's ``s²`` is estimated from the residual at
its optimum, not taken from ``W_x``: on a log simulated by amhe's own model (the bundled examples)
the fit is nearly exact, ``s²`` ≪ 1 and σ shrinks accordingly. Where the truth equals the prior mean
(μ = 0.5 on ``const_a``) a method that does not move μ scores a perfect μ.

Ground truth: ``--truth`` per log (a ``*.truth.yaml`` with ``box.mass_schedule[0].mass_kg`` and
``floor.regions[0].mu_sliding_box_floor``, or an amhe belief), or ``auto``: ``<log>.truth.yaml``
beside the log, else the log's ``amhe_truth`` MCAP metadata record, else ``_m<M>_mu<MU>`` in the
file name. Default logs: the bundled 2.5 kg example, then ``/work/shared/logs/{const_a,noisy_b,
mismatch_b}.mcap`` (missing ones are skipped with a note). Progress goes to stderr; the table to
stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import re
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import yaml

SHARED = Path("/work/shared/logs")
DEFAULT_SHARED = ("const_a.mcap", "noisy_b.mcap", "mismatch_b.mcap")
SUPPORTED = ("box_mass", "box_inertia", "box_friction")


def log_progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# -- ground truth -------------------------------------------------------------------------------------

def truth_from_yaml(path: str) -> dict:
    """name -> value from a ground-truth YAML or an amhe belief (first mass / floor entries)."""
    d = yaml.safe_load(open(path))
    if "parameters" in d:  # an amhe belief
        p = d["parameters"]
        out = {"box_mass": float(p["box_mass"]["value"]), "box_friction": float(p["box_friction"]["value"])}
        if "box_inertia" in p:
            out["box_inertia"] = np.asarray(p["box_inertia"]["value"], dtype=float)
        return out
    first = d["box"]["mass_schedule"][0]
    out = {"box_mass": float(first["mass_kg"]),
           "box_friction": float(d["floor"]["regions"][0]["mu_sliding_box_floor"])}
    if first.get("inertia_diag_kgm2") is not None:
        out["box_inertia"] = np.asarray(first["inertia_diag_kgm2"], dtype=float)
    return out


def find_truth(log: str, spec: str, traj) -> tuple[dict | None, str]:
    """(truth, where it came from) for ``log``; ``spec`` is a path or ``auto``."""
    if spec != "auto":
        return truth_from_yaml(spec), spec
    beside = Path(log).with_suffix(".truth.yaml")
    if beside.is_file():
        return truth_from_yaml(str(beside)), str(beside)
    from amhe_cli.io.truth import metadata_truth
    rec = metadata_truth(traj)
    if rec and "box_mass" in rec and "box_friction" in rec:
        out = {"box_mass": float(rec["box_mass"]), "box_friction": float(rec["box_friction"])}
        if rec.get("box_inertia") is not None:
            out["box_inertia"] = np.asarray(rec["box_inertia"], dtype=float)
        return out, "amhe_truth metadata"
    m = re.search(r"_m(\d+(?:\.\d+)?)_mu(\d+(?:\.\d+)?)", Path(log).name)
    if m:
        return {"box_mass": float(m.group(1)), "box_friction": float(m.group(2))}, "file name"
    return None, "none"


# -- amhe ---------------------------------------------------------------------------------------------

@contextlib.contextmanager
def counting_amhe_rollouts():
    """Count the MuJoCo steps ``identify`` simulates (its RolloutCost, σ rollouts included)."""
    import amhe_cli.estimation.identify as ident
    counter = {"steps": 0}
    base = ident.RolloutCost

    class CountingCost(base):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            counter.setdefault("weights", self.weights)  # the W_x identify actually used
            counter.setdefault("prior_weight", self.prior_weight)

        def close(self):
            counter["steps"] += self.rollout_steps
            super().close()

    ident.RolloutCost = CountingCost
    try:
        yield counter
    finally:
        ident.RolloutCost = base


def run_amhe(problem, free, n_clips: int | None, seed: int, threads: int):
    from amhe_cli.estimation.identify import IdentifySettings, identify
    settings = IdentifySettings(params=free, n_clips=n_clips, seed=seed)

    def progress(gen, best):
        if gen % 10 == 0:
            log_progress(f"    amhe generation {gen}: best J {best:.1f}")

    with counting_amhe_rollouts() as counter:
        result = identify(problem.traj, problem.scene, problem.space, settings, progress=progress, nthread=threads)
    weights = counter.get("weights")
    if weights is None:  # identify built no RolloutCost we could see: rebuild its W_x the way it does
        from amhe_cli.estimation.cost import StateWeights
        weights = StateWeights.for_log(problem.traj.meta, dict(settings.sigma)) \
            if hasattr(StateWeights, "for_log") else StateWeights(dict(settings.sigma))
    return result, counter["steps"], weights, counter.get("prior_weight", settings.prior_weight)


# -- mujoco.sysid -------------------------------------------------------------------------------------

class CompiledSceneSpec:
    """Stand-in for the ``MjSpec`` that ``sysid.ModelSequences`` wants.

    amhe's Scene keeps only the compiled model (its PD gains are written into the compiled model),
    so ``compile()`` hands out a copy of that model; ``build_model`` below never compiles.
    """

    def __init__(self, model: mujoco.MjModel):
        self.model = model

    def compile(self) -> mujoco.MjModel:
        return copy.copy(self.model)


class Tee(io.TextIOBase):
    """Text sink writing to stderr and keeping a copy (mujoco.minimize's iteration log)."""

    def __init__(self):
        self.buf = io.StringIO()

    def write(self, s):
        sys.stderr.write(s)
        self.buf.write(s)
        return len(s)


def sysid_parameters(space, sysid):
    """A ``sysid.ParameterDict`` of the free parameters of ``space``: nominal = prior mean, amhe's bounds.

    Modifiers act on an ``MjModel`` (see ``build_model``), mirroring ``ParameterSpace.write``.
    """
    scene = space.scene
    b = scene.box_body
    pairs = scene.region_pairs
    m_prior = float(space.prior_values["box_mass"][0])
    inertia_prior = space.prior_values["box_inertia"].copy()

    def set_mass(model, p):
        model.body_mass[b] = p.value[0]
        model.body_inertia[b] = inertia_prior * p.value[0] / m_prior  # inertia follows mass

    def set_inertia_ratio(model, p):  # after the mass (ParameterDict keeps insertion order)
        model.body_inertia[b] = p.value * inertia_prior * model.body_mass[b] / m_prior

    def set_friction(model, p):
        model.pair_friction[pairs, 0] = p.value[0]
        model.pair_friction[pairs, 1] = p.value[0]

    writers = {"box_mass": set_mass, "box_inertia": set_inertia_ratio, "box_friction": set_friction}
    params = sysid.ParameterDict()
    for name, sl in space.slices().items():
        params.add(sysid.Parameter(name, nominal=space.mean0[sl], min_value=space.lower[sl],
                                   max_value=space.upper[sl], modifier=writers[name]))
    return params


class SysidAdapter:
    """Everything ``mujoco.sysid`` needs to minimise amhe's J on amhe's clips."""

    def __init__(self, scene, space, clips, weights, prior_weight: float, threads: int):
        from mujoco import sysid
        from amhe_cli.estimation.cost import state_error
        self.sysid, self.state_error = sysid, state_error
        self.scene, self.space, self.clips = scene, space, clips
        self.prior_weight = prior_weight
        self.threads = threads
        m = scene.model
        self.nq, self.nv = m.nq, m.nv
        # template: every parameter at its prior (what ParameterSpace.write gives for non-free ones)
        self.template = copy.copy(m)
        space.write(self.template, space.mean0)
        self.params = sysid_parameters(space, sysid)
        self.w, self.role = weights.vector(scene)
        self.steps = 0
        self.builds = 0
        self._cache: dict[bytes, mujoco.MjModel] = {}
        self.spec = CompiledSceneSpec(self.template)

    # build_model(params, spec) -> MjModel
    def build_model(self, params, _spec=None) -> mujoco.MjModel:
        key = params.as_vector().tobytes()
        model = self._cache.get(key)
        if model is None:
            model = copy.copy(self.template)
            self.sysid.apply_param_modifiers_spec(params, model)
            mujoco.mj_setConst(model, mujoco.MjData(model))
            if len(self._cache) > 32:
                self._cache.clear()
            self._cache[key] = model
            self.builds += 1
        return model

    def check_writer(self, vec: np.ndarray) -> float:
        """Largest difference between the modifiers' model and ``ParameterSpace.write``'s at ``vec``."""
        p = self.params.copy()
        p.update_from_vector(vec)
        a = self.build_model(p)
        b = copy.copy(self.scene.model)
        self.space.write(b, vec)
        fields = ("body_mass", "body_inertia", "pair_friction", "geom_friction", "actuator_gainprm",
                  "actuator_biasprm", "body_invweight0", "dof_invweight0")
        return max(float(np.max(np.abs(getattr(a, f) - getattr(b, f)))) for f in fields)

    def sequences(self):
        """One ``ModelSequences`` holding every clip as a measured sequence."""
        sysid, c, m = self.sysid, self.clips, self.template
        TS, Obs = sysid.TimeSeries, sysid.SignalType.CustomObs
        names, inits, controls, measured = [], [], [], []
        for k in range(len(c)):
            h = int(c.horizon[k])
            x0 = c.initial_state[k]
            times = x0[0] + c.dt * np.arange(h + 1)
            # sysid drops the last control row (it would produce a state with no measurement)
            ctrl = np.vstack([c.control[k, :h], c.control[k, h - 1:h]])
            qpos = np.vstack([x0[1:1 + self.nq], c.qpos[k, :h]])
            qvel = np.vstack([x0[1 + self.nq:1 + self.nq + self.nv], c.qvel[k, :h]])
            obs = np.vstack([np.ones((1, c.observed.shape[2])), c.observed[k, :h]]).astype(float)
            names.append(f"clip{k:02d}_start{int(c.start[k])}_h{h}")
            inits.append(x0.copy())
            controls.append(TS.from_control_names(times, ctrl, m))
            measured.append(TS.from_custom_map(times, np.hstack([qpos, qvel, obs]),
                                               [("qpos", self.nq, Obs), ("qvel", self.nv, Obs),
                                                ("observed", obs.shape[1], Obs)]))
        from absl import logging as absl_logging
        level = absl_logging.get_verbosity()
        absl_logging.set_verbosity(absl_logging.ERROR)  # "sensor data dimension" warning per clip: expected
        try:
            return sysid.ModelSequences("amhe_scene", self.spec, names, inits, controls, measured,
                                        allow_missing_sensors=True)
        finally:
            absl_logging.set_verbosity(level)

    # modify_residual(params, pred, measured, model, return_pred_all, state=...) -> (res, pred, measured)
    def modify_residual(self, params, pred_ts, meas_ts, model, return_pred_all, state=None, **_):
        nq, nv = self.nq, self.nv
        meas = meas_ts.data[1:]
        qpos_ref, qvel_ref, obs = meas[:, :nq], meas[:, nq:nq + nv], meas[:, nq + nv:] > 0.5
        qpos, qvel = state[:, 1:1 + nq], state[:, 1 + nq:1 + nq + nv]
        err = self.state_error(self.scene, qpos_ref, qvel_ref, qpos, qvel)
        wmask = self.w[None, :] * obs[:, self.role]
        res = (err * np.sqrt(wmask))[wmask > 0]
        times = meas_ts.times[1:]
        mapping = meas_ts.signal_mapping
        pred = self.sysid.TimeSeries(times, np.hstack([qpos, qvel, meas[:, nq + nv:]]), mapping)
        return res, pred, self.sysid.TimeSeries(times, meas, mapping)

    def custom_rollout(self, *, models, datas, control_signal, initial_states, rollout_signal_mapping,
                       rollout_state_mapping, ctrl_mapping, **_):
        self.steps += sum(len(cs.times) - 1 for cs in control_signal)
        return self.sysid.sysid_rollout(models=models, datas=datas, control_signal=control_signal,
                                        initial_states=initial_states,
                                        rollout_signal_mapping=rollout_signal_mapping,
                                        rollout_state_mapping=rollout_state_mapping, ctrl_mapping=ctrl_mapping)

    def residual_fn(self, ms):
        """sysid residual closure + amhe's prior rows: Σ r² = amhe's J (data + prior)."""
        base = self.sysid.build_residual_fn(
            models_sequences=[ms], build_model=self.build_model, modify_residual=self.modify_residual,
            custom_rollout=self.custom_rollout, n_threads=self.threads, resample_true=False)
        mean0, std0 = self.space.mean0, self.space.std0
        scale = np.sqrt(self.prior_weight)

        def fn(x, params, **kw):
            res, preds, recs = base(x, params, **kw)
            if self.prior_weight > 0:
                x = np.asarray(x, dtype=float)
                shape = (-1,) if x.ndim == 1 else (-1, 1)
                res = list(res) + [scale * (x - mean0.reshape(shape)) / std0.reshape(shape)]
            return res, preds, recs

        return fn


def run_sysid(problem, result, weights, prior_weight: float, threads: int, eps: float | None,
              max_iters: int | None):
    """mujoco.sysid on amhe's clips with amhe's ``W_x`` and prior; returns estimate, σ, status, timings."""
    import scipy.special
    from mujoco import sysid
    ad = SysidAdapter(problem.scene, problem.space, result.clips, weights, prior_weight, threads)
    writer_gap = ad.check_writer(problem.space.mean0 + 0.37 * problem.space.std0)
    t0 = time.perf_counter()
    ms = ad.sequences()
    fn = ad.residual_fn(ms)
    tee = Tee()
    kwargs = {"output": tee}
    if eps is not None:
        kwargs["eps"] = eps
    if max_iters is not None:
        kwargs["max_iters"] = max_iters
    opt_params, opt = sysid.optimize(ad.params.copy(), fn, optimizer="mujoco", verbose=False, **kwargs)
    x = opt_params.as_vector()
    residuals, _, _ = fn(x, opt_params)
    jac = opt.jac
    if jac is None or not np.all(np.isfinite(jac)):
        sigma = np.full(x.size, np.nan)
    else:
        _, half = sysid.calculate_intervals(residuals, jac)
        n = int(sum(r.size for r in residuals))
        sigma = np.asarray(half) / scipy.special.stdtrit(n - x.size, 0.975)
    wall = time.perf_counter() - t0
    log_text = tee.buf.getvalue()
    m = re.search(r"Terminated after (\d+) iterations: ([^y]*?)\s*y:", log_text)
    status = f"{m.group(2).rstrip('.')} after {m.group(1)} it" if m else "no termination line"
    n_res = re.search(r"Residual evals: (\d+)", log_text)
    # J at the start, from sysid's own residual, to check it is amhe's J
    j_sysid_p0 = float(sum(float(np.sum(r ** 2)) for r in fn(problem.space.mean0.copy(), ad.params.copy())[0]))
    lo, hi = problem.space.lower, problem.space.upper
    at_bound = bool(np.any(np.isclose(x, lo, rtol=0, atol=1e-6 * (hi - lo))
                           | np.isclose(x, hi, rtol=0, atol=1e-6 * (hi - lo))))
    return {"x": x, "sigma": sigma, "wall": wall, "steps": ad.steps, "status": status, "at_bound": at_bound,
            "residual_evals": int(n_res.group(1)) if n_res else None, "builds": ad.builds,
            "j_p0": j_sysid_p0, "writer_gap": writer_gap, "n_residuals": int(sum(r.size for r in residuals))}


# -- table --------------------------------------------------------------------------------------------

def fmt_pm(v: float, s: float, digits: int) -> str:
    if not np.isfinite(v):
        return "-"
    ss = "nan" if np.isnan(s) else ("inf" if np.isinf(s) else f"{s:.2g}")
    return f"{v:.{digits}f} ± {ss}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="*", metavar="LOG")
    ap.add_argument("--truth", nargs="+", default=None, metavar="T.yaml|auto",
                    help="ground truth per log (a truth YAML or belief, or 'auto'); default: auto for all")
    ap.add_argument("--params", default="box_mass,box_friction",
                    help=f"free parameters, a comma-separated subset of {', '.join(SUPPORTED)} "
                         "(box_mass and box_friction must be included)")
    ap.add_argument("--clips", type=int, default=None,
                    help="clips N_c (default: as amhe identify plans them for the log, identify.clip_plan)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sysid-eps", type=float, default=None,
                    help="finite-difference step of mujoco.minimize (default: its own, sqrt(machine eps))")
    ap.add_argument("--sysid-max-iters", type=int, default=None,
                    help="iteration limit of mujoco.sysid (default: its own, 200)")
    a = ap.parse_args()

    from amhe_cli.estimation.cost import RolloutCost
    from amhe_cli.estimation.problem import example_logs, load_problem
    from amhe_cli.model.params import parse_names

    free = parse_names(a.params)
    bad = [n for n in free if n not in SUPPORTED]
    if bad or "box_mass" not in free or "box_friction" not in free:
        ap.error(f"--params: expected box_mass,box_friction[,box_inertia], got {a.params!r}")
    logs = list(a.logs)
    if not logs:
        ex = [p for p in example_logs() if p.name == "probe_m2.5_mu0.30.mcap"]
        logs = [str(ex[0]) if ex else "examples/logs/probe_m2.5_mu0.30.mcap"] + [str(SHARED / n) for n in DEFAULT_SHARED]
    truths = a.truth or ["auto"] * len(logs)
    if len(truths) == 1 and len(logs) > 1:
        truths = truths * len(logs)
    if len(truths) != len(logs):
        ap.error(f"--truth: give one per log ({len(logs)}) or 'auto'")

    from mujoco import sysid as _sysid_module
    if not hasattr(_sysid_module, "ParameterDict"):  # the package is there, its extra's dependencies are not
        sys.exit("vs_mujoco_sysid: mujoco.sysid is not installed with its dependencies: expected "
                 "pip install '.[sysid]' (mujoco[sysid] >= 4.0)")
    rows, notes = [], []
    t_all = time.perf_counter()
    for log, tspec in zip(logs, truths):
        name = Path(log).stem
        if not Path(log).exists():
            notes.append(f"skipped {log}: not found")
            log_progress(f"[{name}] skipped: {log} not found")
            continue
        log_progress(f"[{name}] loading {log}")
        problem = load_problem(log, params=free)
        truth, where = find_truth(log, tspec, problem.traj)
        log_progress(f"[{name}] truth ({where}): {truth}")
        log_progress(f"[{name}] amhe identify: {a.clips or 'planned'} clips, seed {a.seed}, {a.threads} threads")
        result, amhe_steps, weights, prior_weight = run_amhe(problem, free, a.clips, a.seed, a.threads)
        s = result.summary()
        log_progress(f"[{name}]   amhe: {s['estimate']} ± {s['std']} in {s['wall_time_s']:.1f} s "
                     f"({s['generations']} generations, stop {s['stop']})")
        log_progress(f"[{name}] mujoco.sysid on amhe's {len(result.clips)} clips "
                     f"({result.clips.steps} steps per evaluation)")
        try:
            sy = run_sysid(problem, result, weights, prior_weight, a.threads, a.sysid_eps, a.sysid_max_iters)
            sy_err = None
        except Exception as e:  # report, do not hide
            sy, sy_err = None, f"{type(e).__name__}: {e}"
            log_progress(f"[{name}]   mujoco.sysid failed: {sy_err}")
        # J (amhe's cost) at both estimates, and at the prior mean to check the two residuals agree
        sp = problem.space
        cands = [sp.mean0, result.estimate] + ([sy["x"]] if sy else [])
        with RolloutCost(problem.scene, sp, result.clips, weights, prior_weight=prior_weight,
                         nthread=a.threads) as cost:
            J = cost(np.array(cands))
        if sy:
            gap = abs(sy["j_p0"] - J[0]) / max(J[0], 1e-300)
            log_progress(f"[{name}]   J check at the prior mean: sysid Σr² {sy['j_p0']:.6g} vs amhe J {J[0]:.6g} "
                         f"(rel. diff {gap:.1e}); writer check: max |Δ| {sy['writer_gap']:.1e}")
            if gap > 1e-6 or sy["writer_gap"] > 1e-9:
                notes.append(f"{name}: sysid residual/model differs from amhe's (J rel. diff {gap:.1e}, "
                             f"model Δ {sy['writer_gap']:.1e})")
            phys, phys_sd = sp.physical(sy["x"], sy["sigma"])  # inertia ratios -> moments
            est = {k: round(float(v), 5) for k, v in zip(sp.labels, phys)}
            sig = {k: float(f"{v:.3g}") for k, v in zip(sp.labels, phys_sd)}
            log_progress(f"[{name}]   sysid: {est} ± {sig} in {sy['wall']:.1f} s, {sy['status']}, "
                         f"{sy['residual_evals']} residual evals, {sy['n_residuals']} residual rows")

        def row(method, vec, std, wall, steps, j, note):
            val, sd = sp.physical(vec, std)
            sl = sp.slices()
            mass, smass = float(val[sl["box_mass"]][0]), float(sd[sl["box_mass"]][0])
            mu, smu = float(val[sl["box_friction"]][0]), float(sd[sl["box_friction"]][0])
            r = {"method": method, "log": name, "mass": mass, "smass": smass, "mu": mu, "smu": smu,
                 "wall": wall, "steps": steps, "J": j, "note": note, "truth": truth}
            if "box_inertia" in sl:
                r["inertia"] = val[sl["box_inertia"]]
            return r

        amhe_note = ("converged" if result.converged else "not converged") + \
            f", {len(result.history)} gen, stop {','.join(result.stop) or '-'}"
        rows.append(row("amhe (CMA-ES)", result.estimate, result.curvature.std, s["wall_time_s"], amhe_steps,
                        float(J[1]), amhe_note))
        if sy:
            note = sy["status"] + f", {sy['residual_evals']} evals" + (", bound" if sy["at_bound"] else "")
            rows.append(row("mujoco.sysid (GN+FD)", sy["x"], sy["sigma"], sy["wall"], sy["steps"], float(J[2]), note))
        else:
            rows.append({"method": "mujoco.sysid (GN+FD)", "log": name, "failed": sy_err, "truth": truth})

    # -- print ----------------------------------------------------------------------------------------
    inertia = "box_inertia" in free
    head = (f"{'method':<22} {'log':<22} {'mass kg (est ± σ)':>18} {'mass err %':>10} {'μ (est ± σ)':>16} "
            f"{'μ err':>8} " + (f"{'I err %':>8} " if inertia else "") +
            f"{'J at est':>10} {'wall s':>7} {'rollout steps':>13}  note")
    print(head)
    print("-" * len(head))
    stats = {}
    for r in rows:
        t = r["truth"]
        if "failed" in r:
            print(f"{r['method']:<22} {r['log']:<22} FAILED: {r['failed']}")
            continue
        merr = 100 * (r["mass"] - t["box_mass"]) / t["box_mass"] if t else np.nan
        muerr = r["mu"] - t["box_friction"] if t else np.nan
        ierr = "-"
        if inertia and t and t.get("box_inertia") is not None:
            ierr = f"{100 * np.max(np.abs(r['inertia'] - t['box_inertia']) / t['box_inertia']):8.1f}"
        print(f"{r['method']:<22} {r['log']:<22} {fmt_pm(r['mass'], r['smass'], 3):>18} {merr:>+10.2f} "
              f"{fmt_pm(r['mu'], r['smu'], 4):>16} {muerr:>+8.4f} " + (f"{ierr:>8} " if inertia else "") +
              f"{r['J']:>10.1f} {r['wall']:>7.1f} {r['steps']:>13d}  {r['note']}")
        st = stats.setdefault(r["method"].split()[0], {"m": [], "mu": [], "in2": 0, "n": 0, "wall": 0.0})
        st["wall"] += r["wall"]
        if t:
            st["m"].append(abs(merr))
            st["mu"].append(abs(muerr))
            st["n"] += 2
            st["in2"] += int(abs(r["mass"] - t["box_mass"]) <= 2 * r["smass"]) + \
                int(abs(r["mu"] - t["box_friction"]) <= 2 * r["smu"])
    for n in notes:
        print(f"note: {n}")
    parts = []
    for method, st in stats.items():
        mm = f"{np.mean(st['m']):.2f}" if st["m"] else "n/a"
        mmu = f"{np.mean(st['mu']):.4f}" if st["mu"] else "n/a"
        parts.append(f"{method}: mean|mass err|={mm}% mean|mu err|={mmu} within2sigma={st['in2']}/{st['n']} "
                     f"wall={st['wall']:.1f}s")
    fails = sum(1 for r in rows if "failed" in r)
    print(f"summary over {len({r['log'] for r in rows})} logs: " + "; ".join(parts) +
          (f"; sysid failed on {fails} log(s)" if fails else "") + f" (total {time.perf_counter() - t_all:.0f} s)")


if __name__ == "__main__":
    main()
