"""PNG figures for results a person would rather look at than read.

matplotlib with the non-interactive Agg backend, so plots work on a headless
machine; every function writes one PNG and returns its path.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from amhe_cli.errors import AmheError  # noqa: E402


def _check_png(path) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise AmheError(f"--plot {path}: expected a file name ending in .png")
    if not path.parent.exists():
        raise AmheError(f"--plot {path}: folder {path.parent} does not exist")
    return path


def check_plot_path(path) -> Path | None:
    """Validate a ``--plot`` path before any long work starts (None passes)."""
    return None if path is None else _check_png(path)


def _estimate_band(ax, t: np.ndarray, v: np.ndarray, sd: np.ndarray, label: str) -> np.ndarray:
    """A piecewise-constant estimate ``v`` over ``t`` with its ±1σ band; returns ``v``."""
    ax.fill_between(t, v - sd, v + sd, step="post", alpha=0.25, color="tab:blue", label="±1σ")
    ax.step(t, v, where="post", color="tab:blue", label=label)
    return v


def plot_identify(path, result, cost_rollout, traj=None) -> Path:
    """Cost over generations and recorded vs predicted box motion of an identification.

    Args:
        path: PNG to write.
        result: :class:`~amhe_cli.estimation.identify.IdentifyResult`.
        cost_rollout: callable (B, d) -> (qpos (B, N_c, H, nq), qvel) over the
            result's clips, i.e. ``RolloutCost.rollout``; called once with the
            prior and the estimate.
        traj: the recorded trajectory, for the whole box path (optional).
    """
    path = _check_png(path)
    sp, clips = result.space, result.clips
    scene = sp.scene
    gens = [h["generation"] for h in result.history]
    fig = plt.figure(figsize=(13, 8), constrained_layout=True)
    grid = fig.add_gridspec(2, 3)
    ax = fig.add_subplot(grid[0, 0])
    ax.semilogy(gens, [h["best"] for h in result.history], label="best of generation")
    ax.semilogy(gens, [h["mean_cost"] for h in result.history], alpha=0.6, label="generation mean")
    ax.axhline(result.cost_prior, color="grey", ls=":", label="at prior")
    ax.set_xlabel("generation")
    ax.set_ylabel("J")
    ax.set_title("CMA-ES cost")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[1, 0])
    means = np.array([h["mean"] for h in result.history])
    for i, label in enumerate(sp.labels):
        scale = max(abs(result.estimate[i]), 1e-9)
        ax.plot(gens, means[:, i] / scale, label=label)
    ax.set_xlabel("generation")
    ax.set_ylabel("CMA mean / estimate")
    ax.set_title("parameter convergence")
    ax.legend(fontsize=7)

    qpos, _ = cost_rollout(np.vstack([sp.mean0, result.estimate]))
    bx = scene.box_qpos
    # the recorded box path with each clip's prediction under the estimate laid on it
    ax = fig.add_subplot(grid[0, 1:])
    if traj is not None:
        ax.plot(traj.box_pos[:, 0], traj.box_pos[:, 1], color="0.6", lw=1, label="recorded box path")
    for k in range(len(clips)):
        h = clips.horizon[k]
        ax.plot(clips.qpos[k, :h, bx[0]], clips.qpos[k, :h, bx[1]], color="k", lw=3,
                label="recorded, clips" if k == 0 else None)
        ax.plot(qpos[1, k, :h, bx[0]], qpos[1, k, :h, bx[1]], color="tab:blue", lw=1.2,
                label="predicted, estimate" if k == 0 else None)
    ax.set_xlabel("box x [m]")
    ax.set_ylabel("box y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("box path and the clips")
    ax.legend(fontsize=8)
    # planar prediction error of every clip over its horizon, at the prior and at the estimate
    ax = fig.add_subplot(grid[1, 1:])
    for k in range(len(clips)):
        h = clips.horizon[k]
        tt = (np.arange(h) + 1) * clips.dt
        for row, color, label in ((0, "tab:red", "prior"), (1, "tab:blue", "estimate")):
            err = np.linalg.norm(qpos[row, k, :h][:, bx[:2]] - clips.qpos[k, :h][:, bx[:2]], axis=1)
            ax.plot(tt, 1e3 * err, color=color, lw=1, alpha=0.7, label=label if k == 0 else None)
    ax.set_xlabel("time into clip [s]")
    ax.set_ylabel("box planar error [mm]")
    ax.set_title("prediction error per clip")
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_estimates(path, head: list[str], rows: np.ndarray, truth=None, skipped=None) -> Path:
    """Each estimated parameter over time with its ±1σ band and the truth where known.

    Args:
        path: PNG to write.
        head, rows: the estimates table (``t, name, name_std, …``) of
            :func:`~amhe_cli.estimation.replay.estimates_table`.
        truth: a :class:`~amhe_cli.estimation.replay.TruthSeries` or None.
        skipped: (n,) bool, updates whose window held no information (marked).
    """
    path = _check_png(path)
    names = [h for h in head[1:] if not h.endswith("_std")]
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.6 * len(names)), sharex=True, squeeze=False,
                             constrained_layout=True)
    t = rows[:, 0]
    for ax, name in zip(axes[:, 0], names):
        v = _estimate_band(ax, t, rows[:, head.index(name)], rows[:, head.index(name + "_std")], "estimate")
        if skipped is not None and np.any(skipped):
            ax.plot(t[skipped], v[skipped], "x", color="0.5", ms=4, label="kept (window at rest)")
        if truth is not None:
            base, _, idx = name.rpartition("_")
            key, col = (base, int(idx)) if idx.isdigit() and base in truth.values else (name, None)
            if key in truth.values:
                tv = truth.values[key] if col is None else truth.values[key][:, col]
                ax.step(truth.t, tv, where="post", color="k", lw=1.5, label="truth")
        ax.set_ylabel(name)
        ax.legend(fontsize=8, loc="best")
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle("moving horizon estimates")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(path, result, task) -> Path:
    """A closed-loop run: box path vs goal/path, speed tracking, estimates vs truth.

    Args:
        path: PNG to write.
        result: :class:`~amhe_cli.control.closed_loop.RunResult`.
        task: the :class:`~amhe_cli.control.tasks.Task` it ran.
    """
    path = _check_png(path)
    fig, ax = plt.subplots(1, 4, figsize=(17, 4))
    traj = result.traj
    ax[0].plot(traj.box_pos[:, 0], traj.box_pos[:, 1], label="box")
    ax[0].plot(traj.base_pos[:, 0], traj.base_pos[:, 1], lw=0.8, label="robot base")
    if task.circle is not None:
        cx, cy, r, arc = task.circle
        a0 = np.arctan2(task.box_start[1] - cy, task.box_start[0] - cx)
        a = a0 + np.linspace(0, arc, 100)
        ax[0].plot(cx + r * np.cos(a), cy + r * np.sin(a), "k:", label="path")
    ax[0].plot(*task.goal, "k*", ms=12, label="goal")
    ax[0].add_patch(plt.Circle(task.goal, task.success_radius, fill=False, ls="--", color="k"))
    ax[0].set_aspect("equal", adjustable="datalim")
    ax[0].set_xlabel("x [m]"), ax[0].set_ylabel("y [m]"), ax[0].legend(fontsize=7)
    ax[0].set_title(f"{task.name}: e_g {result.e_g:.3f} m, {'success' if result.success else 'failure'}")
    t_cyc = result.box_path[:, 0]
    ax[1].plot(t_cyc, result.speed[:, 0], lw=0.8, label="forward speed")
    ax[1].plot(t_cyc, result.speed[:, 1], "k--", label="commanded")
    ax[1].set_xlabel("t [s]"), ax[1].set_ylabel("m/s"), ax[1].legend(fontsize=7)
    ax[1].set_title(f"speed tracking, RMSE {result.rmse:.3f} m/s")
    est_t, est_v, est_s = result.estimates
    ts = traj.meta.get("truth_series", {})
    for k, (name, unit) in enumerate((("box_mass", "kg"), ("box_friction", "-"))):
        a = ax[2 + k]
        if name in result.labels:
            i = result.labels.index(name)  # held until the run's end
            _estimate_band(a, np.append(est_t, traj.t[-1]), np.append(est_v[:, i], est_v[-1, i]),
                           np.append(est_s[:, i], est_s[-1, i]), "planner's belief")
        if name in ts:
            a.plot(ts["t"], ts[name], "k--", label="truth")
        a.set_xlabel("t [s]"), a.set_ylabel(f"{name} [{unit}]"), a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
