"""Replaying a log through the moving horizon estimator, with honest timing.

:func:`replay` steps a :class:`~amhe_cli.estimation.mhe.MovingHorizonEstimator` along a
recorded trajectory. Two clocks:

* as fast as possible (default): an update at every ``Δt_update`` of log time,
  each estimate stamped with the end of its window;
* ``realtime=True``: as ``run``'s estimator thread lives beside a robot. Log time
  runs at wall-clock pace; an update due while the last one still runs, or before
  the thread has rested enough to stay within ``duty`` of a core
  (:func:`~amhe_cli.estimation.mhe.rested`), is deferred — dropped, as ``run``
  drops it, not queued — and the next due one is tried. An update that runs sees
  the data up to its due time and its estimate becomes usable ``compute_time``
  later. Deferred updates are counted, each update's lag (usable time − data time)
  is kept. The replay does not sleep: the schedule follows from the measured
  compute times, which is what a live thread on an otherwise idle core would see.

Either way the real-time factor is the log's duration ÷ the compute that every due
update would take (≥ 1: the estimator keeps up with every window).

Ground truth, where the log has it, comes from :func:`truth_series`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.estimation.mhe import MovingHorizonEstimator, Update, rested
from amhe_cli.model.params import ParameterSpace
from amhe_cli.io.trajectory import Trajectory


@dataclass
class ReplayResult:
    """What a replay produced.

    Attributes:
        updates: every update, in order.
        usable_at: (n,) log time [s] at which each estimate became usable.
        deferred: updates that were due and not run (realtime only: the estimator was busy or resting).
        compute_time: total estimator compute of the updates run [s].
        duration: log time replayed [s].
        realtime: which clock was used.
    """

    updates: list[Update]
    usable_at: np.ndarray
    deferred: int
    compute_time: float
    duration: float
    realtime: bool

    @property
    def realtime_factor(self) -> float:
        """Log duration ÷ the compute every due update would take at the mean measured (≥ 1: the
        estimator keeps up with every window)."""
        due = len(self.updates) + self.deferred
        return self.duration * len(self.updates) / max(due * self.compute_time, 1e-9)

    @property
    def lags(self) -> np.ndarray:
        """(n,) usable time − data time [s] per update."""
        return self.usable_at - np.array([u.t for u in self.updates])


def attribute_by_default(problem, prior) -> bool:
    """Whether ``mhe-replay`` attributes (``MHESettings.attribute``) unless told: a belief to start from
    (``prior``, a path or None), the box's mass and friction both free in ``problem``
    (:class:`~amhe_cli.estimation.problem.Problem`), and the box's poses smoothed for their measured noise
    (motion capture). On a clean log the windows split the two well, and a decision costs seconds of a core.
    Measured on 12 noisy T3 and T4 recordings with their probe beliefs: both bounds from 3 s after the change
    in 43 of 48 replays (T3's ``mocap_degrade`` ones 7 of 8 on two seeds), the windows' own split in 0 of 8
    (docs/evaluation.md)."""
    names = problem.space.slices()
    return (prior is not None and "box_mass" in names and "box_friction" in names
            and bool(problem.traj.meta.get("smoothing", {}).get("box")))


def replay(traj: Trajectory, mhe: MovingHorizonEstimator, realtime: bool = False, duty: float = 1.0,
           progress: Callable[[float], None] | None = None,
           on_update: Callable[[Update], None] | None = None) -> ReplayResult:
    """Run ``mhe`` along ``traj`` (see the module docstring for the two clocks).

    Args:
        realtime: replay on the live clock, deferring what ``run`` would defer.
        duty: with ``realtime``, the largest share of wall time the estimator may be busy (0 < duty <= 1):
            1 on a core of its own, ``run``'s ``MHE_DUTY`` where it shares the planner's CPUs.
        progress: called with the log time reached after each update.
        on_update: called with each :class:`~amhe_cli.estimation.mhe.Update` as it is made (the live view's hook).
    Raises:
        AmheError: ``duty`` outside (0, 1].
    """
    if not 0 < duty <= 1:
        raise AmheError(f"duty {duty}: expected the estimator's share of a core in (0, 1]")
    s = mhe.settings
    if realtime:
        mhe.duty = duty  # what MHESettings.fill sizes an update to, as run's core split does
        mhe.warm()  # the decisions' own backend loads before the clock starts, as run's does
    t_end = float(traj.t[-1])
    due = float(traj.t[0]) + s.window
    free_at, last = -np.inf, 0.0  # live clock: when the last update finished, what it took [s]
    updates, usable, deferred, total = [], [], 0, 0.0
    while due <= t_end + 1e-9:
        if realtime and not (due >= free_at and rested(due - free_at, last, duty)):
            deferred += 1
            due += s.every
            continue
        u = mhe.update(traj, due)
        total += u.compute_time
        updates.append(u)
        if on_update is not None:
            on_update(u)
        usable.append(due + u.compute_time if realtime else u.t)
        free_at, last = due + u.compute_time, u.compute_time
        if progress:
            progress(due)
        due += s.every
    return ReplayResult(updates, np.array(usable), deferred, total, t_end - float(traj.t[0]), realtime)


# -- ground truth -------------------------------------------------------------------

#: Columns of a ``<log>.truth.csv`` per parameter (docs/log_schema.md#ground-truth).
TRUTH_COLUMNS = {
    "box_mass": ("box_mass_kg",),
    "box_inertia": ("box_Ixx", "box_Iyy", "box_Izz"),
    "box_friction": ("mu_floor_at_box_center", "mu_area_weighted"),
}


@dataclass
class TruthSeries:
    """Ground truth over time: name -> (T,) or (T, k) values on ``t``."""

    t: np.ndarray
    values: dict = field(default_factory=dict)

    def at(self, name: str, t: np.ndarray) -> np.ndarray | None:
        """Truth of ``name`` at times ``t`` (previous sample), or None if unknown."""
        if name not in self.values:
            return None
        idx = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        return self.values[name][idx]

    def change_times(self, name: str) -> np.ndarray:
        """(n,) times [s] of the samples where ``name`` takes a new value (empty if it never changes or is unknown)."""
        v = self.values.get(name)
        if v is None:
            return np.zeros(0)
        changed = np.diff(np.asarray(v, dtype=float).reshape(len(self.t), -1), axis=0).any(axis=1)
        return self.t[np.flatnonzero(changed) + 1]


def truth_series(log: str, traj: Trajectory, csv_path: str | None = None) -> TruthSeries | None:
    """Ground truth for a log: ``csv_path``, else ``<log stem>.truth.csv`` beside it, else the
    constant ``amhe_truth`` metadata of logs amhe simulated; None if there is none."""
    path = Path(csv_path) if csv_path else None
    if path is None:
        p = Path(log.rstrip("/"))
        guess = p.with_name(p.name.split(".mcap")[0].split(".bag")[0] + ".truth.csv")
        path = guess if guess.is_file() else None
    if path is not None:
        with path.open() as f:
            rows = list(csv.DictReader(f))
        if rows and "t" in rows[0]:
            t = np.array([float(r["t"]) for r in rows])
            vals = {}
            for name, cols in TRUTH_COLUMNS.items():
                present = [c for c in cols if c in rows[0]]
                if name == "box_inertia" and len(present) == 3:
                    vals[name] = np.array([[float(r[c]) for c in present] for r in rows])
                elif name != "box_inertia" and present:
                    vals[name] = np.array([float(r[present[0]]) for r in rows])
            return TruthSeries(t, vals)
    from amhe_cli.io.truth import metadata_truth
    rec = metadata_truth(traj)
    if rec:
        vals = {k: np.array([v] * 2, dtype=float) for k, v in rec.items()}
        return TruthSeries(np.array([traj.t[0], traj.t[-1]]), vals)
    return None


def estimates_table(space: ParameterSpace, result: ReplayResult, windows: bool = False) -> tuple[list[str], np.ndarray]:
    """CSV columns ``t, <name>, <name>_std, …`` (vectors as ``<name>_0`` …) and (n, columns) rows,
    in physical units, one row per update, stamped with the time the estimate became usable.

    With ``windows`` (for a fused estimator, ``MHESettings.fuse``) the table ends with one
    ``<name>_window`` column per value: each window's own estimate (eq. 4), which the fused one combines.
    """
    head = ["t"]
    labels_all = []
    for name, sl in space.slices().items():
        k = sl.stop - sl.start
        labels = [name] if k == 1 else [f"{name}_{i}" for i in range(k)]
        labels_all += labels
        head += [x for lab in labels for x in (lab, f"{lab}_std")]
    if windows:
        head += [f"{lab}_window" for lab in labels_all]
    rows = []
    for u, t in zip(result.updates, result.usable_at):
        val, sd = space.physical(u.mean, u.std)
        row = [t]
        for sl in space.slices().values():
            for i in range(sl.start, sl.stop):
                row += [val[i], sd[i]]
        if windows:
            own = u.window_mean if u.window_mean is not None else u.mean
            row += list(space.physical(own)[0])
        rows.append(row)
    return head, np.array(rows).reshape(len(rows), len(head))


def tracking_error(space: ParameterSpace, result: ReplayResult, truth: TruthSeries) -> dict[str, float]:
    """RMS error against truth per scalar parameter over informative updates (mass: relative [%])."""
    head, rows = estimates_table(space, result)
    informative = np.array([not u.skipped for u in result.updates])
    seen = np.cumsum(informative) > 0  # from the first informative update on
    out = {}
    for name in ("box_mass", "box_friction"):
        if name in head and name in truth.values and seen.any():
            est = rows[seen, head.index(name)]
            tru = truth.at(name, rows[seen, 0])
            err = (est - tru) / tru * 100 if name == "box_mass" else est - tru
            out[name] = float(np.sqrt(np.mean(err ** 2)))
    return out
