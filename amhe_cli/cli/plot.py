"""PNG figures for results a person would rather look at than read.

matplotlib with the non-interactive Agg backend, so plots work on a headless
machine; every function writes one PNG and returns its path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from amhe_cli.errors import AmheError


def _pyplot():
    """``matplotlib.pyplot`` on the Agg backend, imported when a figure is drawn (half a second that
    the commands which check a ``--plot`` name but draw nothing need not pay)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _check_png(path) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise AmheError(f"--plot {path}: expected a file name ending in .png")
    if not path.parent.exists():
        raise AmheError(f"--plot {path}: folder {path.parent} does not exist")
    return path


def check_png_name(path) -> Path | None:
    """A ``--plot`` name checked for its ``.png`` ending only (None passes); its folder and
    whether it exists are :func:`~amhe_cli.cli.common.check_outputs`' job (called by each command:
    this module does not import ``common``, which imports it for ``--plot``).

    Raises:
        AmheError: the name does not end in .png.
    """
    if path is None:
        return None
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise AmheError(f"--plot {path}: expected a file name ending in .png")
    return path


def _estimate_band(ax, t: np.ndarray, v: np.ndarray, sd: np.ndarray, label: str) -> np.ndarray:
    """A piecewise-constant estimate ``v`` over ``t`` with its ±1σ band; returns ``v``."""
    ax.fill_between(t, v - sd, v + sd, step="post", alpha=0.25, color="tab:blue", label="±1σ")
    ax.step(t, v, where="post", color="tab:blue", label=label)
    return v


#: Plain names and units of the parameters on plots.
_PRETTY = {"box_mass": ("box mass", "kg"), "box_friction": ("box–floor μ", "-"),
           "box_inertia": ("box inertia", "kg·m²"), "robot_box_friction": ("robot–box μ", "-"),
           "robot_kp": ("robot Kp", "N·m/rad"), "robot_kd": ("robot Kd", "N·m·s/rad"),
           "trunk_payload": ("trunk payload", "kg")}


def _pretty(name: str) -> tuple[str, str]:
    """(plain name, unit) of a parameter name or label (``box_inertia_2`` -> ``box inertia (z)``)."""
    if name in _PRETTY:
        return _PRETTY[name]
    base, _, idx = name.rpartition("_")
    if base in _PRETTY and idx.isdigit():
        return f"{_PRETTY[base][0]} ({'xyz'[int(idx)]})", _PRETTY[base][1]
    return name, ""


def _fmt_pm(v: float, sd: float) -> str:
    """``v ± sd`` with the digits ``sd`` supports (2 significant digits of σ)."""
    if not np.isfinite(sd) or sd <= 0:
        return f"{v:.4g}"
    digits = max(0, 1 - int(np.floor(np.log10(sd))))
    return f"{v:.{digits}f} ± {sd:.{digits}f}"


def plot_identify(path, result, cost_rollout, traj=None, truth: dict | None = None) -> Path:
    """What a user needs to judge an identification, on one PNG.

    Panels: the CMA-ES cost over generations; each parameter in physical units
    (the CMA-ES mean per generation, the prior, the final estimate ± σ band and
    the truth where known); the recorded box speed over the clips laid end to
    end against the predictions at the prior and at the estimate; the box's
    planar position error over each clip's horizon. The final numbers are in
    the figure's title lines.

    Args:
        path: PNG to write.
        result: :class:`~amhe_cli.estimation.identify.IdentifyResult`.
        cost_rollout: callable (B, d) -> (qpos (B, N_c, H, nq), qvel (B, N_c, H, nv))
            over the result's clips, i.e. ``RolloutCost.rollout``; called once with
            the prior and the estimate.
        traj: the recorded trajectory (optional; its time axis places the clips).
        truth: name -> true value (scalar or (3,) for the inertia), when known.

    Returns:
        The PNG's path.

    Raises:
        AmheError: ``path`` does not end in .png or its folder does not exist.
    """
    plt = _pyplot()
    path = _check_png(path)
    sp, clips = result.space, result.clips
    scene = sp.scene
    truth = truth or {}
    gens = np.array([h["generation"] for h in result.history])
    est_phys, est_sd = sp.physical(result.estimate, result.curvature.std)
    prior_phys, prior_sd = sp.physical(sp.mean0, sp.std0)
    means = np.array([sp.physical(np.asarray(h["mean"]))[0] for h in result.history])
    groups = list(sp.slices().items())  # name -> slice of the flat vector

    from matplotlib.lines import Line2D
    from matplotlib.ticker import MaxNLocator

    n_par_rows = (len(groups) + 2) // 3
    fig = plt.figure(figsize=(15, 3.7 * (2 + n_par_rows)), constrained_layout=True)
    grid = fig.add_gridspec(2 + n_par_rows, 3, height_ratios=[1.0] + [1] * n_par_rows + [1.15])
    # -- the CMA-ES cost
    ax = fig.add_subplot(grid[0, 0])
    ax.semilogy(gens, [h["best"] for h in result.history], label="best of generation")
    ax.semilogy(gens, [h["mean_cost"] for h in result.history], alpha=0.6, label="generation mean")
    ax.axhline(result.cost_prior, color="grey", ls=":", label="at the prior")
    ax.axhline(result.cost_estimate, color="tab:blue", ls="--", lw=1, label="at the estimate")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("CMA-ES generation")
    ax.set_ylabel("cost J (log scale)")
    ax.set_title("CMA-ES cost: " + ("converged" if result.converged else
                                    f"NOT converged (stopped at --generations {result.settings.max_gen})"))
    ax.legend(fontsize=8)
    # -- the final numbers, and the key to the parameter panels
    ax = fig.add_subplot(grid[0, 1:])
    ax.axis("off")
    lines = ["final estimate ± 1σ", ""]
    for name, sl in groups:
        label, unit = _pretty(name)
        unit = "" if unit == "-" else unit
        for i in range(sl.start, sl.stop):
            sub = _pretty(sp.labels[i])[0] if sl.stop - sl.start > 1 else label
            tv = truth.get(name)
            tv = None if tv is None else np.atleast_1d(np.asarray(tv, dtype=float))[i - sl.start]
            lines.append(f"{sub:<17} {_fmt_pm(est_phys[i], est_sd[i]):>17} {unit:<6}  prior {prior_phys[i]:<8.4g}"
                         + (f"  truth {tv:.4g}" if tv is not None else ""))
    lines += ["", f"residual rms per step {result.residual_rms:.3g}"
              + ("" if result.converged else " (not judged: CMA-ES had not converged)"),
              f"{len(clips)} clips, {len(result.history)} generations, {result.evaluations} candidates, "
              f"{result.wall_time:.1f} s"]
    ax.text(0.0, 1.0, "\n".join(lines), family="monospace", fontsize=10, va="top", ha="left",
            transform=ax.transAxes)
    key = [Line2D([], [], color="0.3", lw=1.2, label="CMA-ES mean per generation"),
           Line2D([], [], color="0.3", lw=2.5, label="final estimate (band: ±1σ)"),
           Line2D([], [], color="0.3", lw=1.2, ls=":", label="prior"),
           Line2D([], [], color="k", lw=1.2, ls="--", label="truth")]
    ax.legend(handles=key if truth else key[:3], loc="lower right", fontsize=9, title="parameter panels")
    # -- each parameter in physical units
    colors = ["tab:blue", "tab:orange", "tab:green"]
    for k, (name, sl) in enumerate(groups):
        ax = fig.add_subplot(grid[1 + k // 3, k % 3])
        label, unit = _pretty(name)
        tv = truth.get(name)
        tv = None if tv is None else np.atleast_1d(np.asarray(tv, dtype=float))
        multi = sl.stop - sl.start > 1
        for j, i in enumerate(range(sl.start, sl.stop)):
            c = colors[j % 3]
            ax.plot(gens, means[:, i], color=c, lw=1.2)
            ax.axhspan(est_phys[i] - est_sd[i], est_phys[i] + est_sd[i], color=c, alpha=0.15)
            ax.axhline(est_phys[i], color=c, lw=2.5, label="xyz"[j] if multi else None)
            ax.axhline(prior_phys[i], color=c, ls=":", lw=1.2)
            if tv is not None and not (j and np.isclose(tv[j], tv[0])):
                ax.axhline(tv[j], color="k", ls="--", lw=1.2)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("CMA-ES generation")
        ax.set_ylabel(f"{label} [{unit}]")
        ax.set_title(label if multi else f"{label}: {_fmt_pm(est_phys[sl.start], est_sd[sl.start])}"
                     + ("" if unit == "-" else f" {unit}") + (f" (truth {tv[0]:.4g})" if tv is not None else ""))
        if multi:
            ax.legend(fontsize=8, ncol=3, loc="best", title="axis", title_fontsize=8)

    qpos, qvel = cost_rollout(np.vstack([sp.mean0, result.estimate]))
    bx, bv = scene.box_qpos, scene.box_qvel
    order = np.argsort(clips.start)
    # -- recorded vs predicted box speed over the clips, laid end to end in log order
    ax = fig.add_subplot(grid[-1, 0:2])
    t0, gap = 0.0, 0.03
    for n, k in enumerate(order):
        h = clips.horizon[k]
        tt = t0 + (np.arange(h) + 1) * clips.dt
        ax.plot(tt, np.linalg.norm(clips.qvel[k, :h][:, bv[:2]], axis=1), color="k", lw=2.2,
                label="recorded" if n == 0 else None)
        ax.plot(tt, np.linalg.norm(qvel[0, k, :h][:, bv[:2]], axis=1), color="tab:red", lw=1, ls="--",
                label="predicted at the prior" if n == 0 else None)
        ax.plot(tt, np.linalg.norm(qvel[1, k, :h][:, bv[:2]], axis=1), color="tab:blue", lw=1.3,
                label="predicted at the estimate" if n == 0 else None)
        t0 = tt[-1] + gap
    ax.set_xlabel("clips laid end to end, in log order [s]")
    ax.set_ylabel("box planar speed [m/s]")
    ax.set_title("box speed over the clips: recorded vs predicted")
    ax.legend(fontsize=8)
    # -- planar prediction error of every clip over its horizon, at the prior and at the estimate
    ax = fig.add_subplot(grid[-1, 2])
    for k in range(len(clips)):
        h = clips.horizon[k]
        tt = (np.arange(h) + 1) * clips.dt
        for row, color, label in ((0, "tab:red", "at the prior"), (1, "tab:blue", "at the estimate")):
            err = np.linalg.norm(qpos[row, k, :h][:, bx[:2]] - clips.qpos[k, :h][:, bx[:2]], axis=1)
            ax.plot(tt, 1e3 * err, color=color, lw=1, alpha=0.6, label=label if k == 0 else None)
    ax.set_xlabel("time into the clip [s]")
    ax.set_ylabel("box planar position error [mm]")
    ax.set_title("prediction error of each clip")
    ax.legend(fontsize=8)
    fig.suptitle("amhe identify" + (f": {Path(traj.meta['path']).name}" if traj is not None and traj.meta.get("path")
                                    else ""), fontsize=12)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_estimates(path, head: list[str], rows: np.ndarray, truth=None, skipped=None, decisions=()) -> Path:
    """Each estimated parameter over time with its ±1σ band and the truth where known.

    Args:
        path: PNG to write.
        head, rows: the estimates table (``t, name, name_std, …``, optionally ``name_window``) of
            :func:`~amhe_cli.estimation.replay.estimates_table`; window estimates, where
            present, are drawn as dots behind the fused estimate.
        truth: a :class:`~amhe_cli.estimation.replay.TruthSeries` or None.
        skipped: (n,) bool, updates whose window held no information (marked).
        decisions: the change attribution's :class:`~amhe_cli.estimation.attribution.Decision` list
            (``mhe-replay --attribute``): each attribution is marked on its parameter's axis, a line at the
            time it was made and a band over the data it read.
    """
    plt = _pyplot()
    path = _check_png(path)
    names = [h for h in head[1:] if not h.endswith(("_std", "_window"))]
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.6 * len(names)), sharex=True, squeeze=False,
                             constrained_layout=True)
    t = rows[:, 0]
    for ax, name in zip(axes[:, 0], names):
        fused = name + "_window" in head
        if fused:
            own = np.ones(len(t), bool) if skipped is None else ~np.asarray(skipped, bool)
            ax.plot(t[own], rows[own, head.index(name + "_window")], ".", color="tab:orange", ms=5,
                    label="window estimate (eq. 4)")
        v = _estimate_band(ax, t, rows[:, head.index(name)], rows[:, head.index(name + "_std")],
                           "fused estimate" if fused else "estimate")
        if skipped is not None and np.any(skipped):
            ax.plot(t[skipped], v[skipped], "x", color="0.5", ms=4, label="kept (window at rest)")
        for k, d in enumerate(d for d in decisions if d.changed == name):
            ax.axvspan(d.since, d.t, color="tab:green", alpha=0.12, lw=0,
                       label=None if k else "data an attribution read")
            ax.axvline(d.t, color="tab:green", ls="--", lw=1.5, label=None if k else "change attributed here")
        if truth is not None:
            base, _, idx = name.rpartition("_")
            key, col = (base, int(idx)) if idx.isdigit() and base in truth.values else (name, None)
            if key in truth.values:
                tv = truth.values[key] if col is None else truth.values[key][:, col]
                ax.step(truth.t, tv, where="post", color="k", lw=1.5, label="truth")
        label, unit = _pretty(name)
        ax.set_ylabel(f"{label} [{unit}]" if unit else label)
        ax.legend(fontsize=8, loc="best")
    axes[-1, 0].set_xlabel("time from the log's start [s]")
    fig.suptitle("moving horizon estimates (each held from its update on; ±1σ band)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(path, result, task) -> Path:
    """A closed-loop run: box path vs goal/path, speed tracking, estimates vs truth (2 × 2, readable fonts).

    Args:
        path: PNG to write.
        result: :class:`~amhe_cli.control.closed_loop.RunResult`.
        task: the :class:`~amhe_cli.control.tasks.Task` it ran.

    Returns:
        The PNG's path.

    Raises:
        AmheError: ``path`` does not end in .png or its folder does not exist.
    """
    plt = _pyplot()
    path = _check_png(path)
    with plt.rc_context({"font.size": 11, "axes.titlesize": 12, "axes.labelsize": 11, "legend.fontsize": 9.5,
                         "xtick.labelsize": 10, "ytick.labelsize": 10}):
        fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), constrained_layout=True)
        ax = axes.ravel()
        traj = result.traj
        ax[0].plot(traj.box_pos[:, 0], traj.box_pos[:, 1], lw=2, label="box")
        ax[0].plot(traj.base_pos[:, 0], traj.base_pos[:, 1], lw=1, label="robot base")
        if task.circle is not None:
            cx, cy, r, arc = task.circle
            a0 = np.arctan2(task.box_start[1] - cy, task.box_start[0] - cx)
            a = a0 + np.linspace(0, arc, 100)
            ax[0].plot(cx + r * np.cos(a), cy + r * np.sin(a), "k:", label="path")
        ax[0].plot(*task.goal, "k*", ms=14, label="goal")
        ax[0].add_patch(plt.Circle(task.goal, task.success_radius, fill=False, ls="--", color="k",
                                   label=f"success radius {task.success_radius:g} m"))
        ax[0].set_aspect("equal", adjustable="datalim")
        ax[0].set_xlabel("x [m]"), ax[0].set_ylabel("y [m]"), ax[0].legend(loc="best")
        ax[0].set_title(f"{task.name}: {'success' if result.success else 'failure'}, final goal error "
                        f"{result.e_g:.3f} m")
        t_cyc = result.box_path[:, 0] if result.box_path is not None and len(result.box_path) else np.zeros(0)
        if len(t_cyc):
            ax[1].plot(t_cyc, result.speed[:, 0], lw=1, label="robot forward speed")
            ax[1].plot(t_cyc, result.speed[:, 1], "k--", label="commanded")
        ax[1].set_xlabel("t [s]"), ax[1].set_ylabel("speed [m/s]"), ax[1].legend(loc="best")
        ax[1].set_title(f"speed tracking, RMSE {result.rmse:.3f} m/s")
        est_t, est_v, est_s = result.estimates
        ts = traj.meta.get("truth_series", {})
        for k, (name, unit) in enumerate((("box_mass", "kg"), ("box_friction", "-"))):
            a = ax[2 + k]
            if name in result.labels and len(est_t):
                i = result.labels.index(name)  # held until the run's end
                _estimate_band(a, np.append(est_t, traj.t[-1]), np.append(est_v[:, i], est_v[-1, i]),
                               np.append(est_s[:, i], est_s[-1, i]), "planner's belief")
            if name in ts:
                a.plot(ts["t"], ts[name], "k--", label="truth")
            label = _pretty(name)[0]
            a.set_xlabel("t [s]"), a.set_ylabel(f"{label} [{unit}]"), a.legend(loc="best")
            a.set_title(f"{label}: planner's belief vs truth")
        fig.savefig(path, dpi=100)
        plt.close(fig)
    return path


def plot_ablation(path, table: list[dict], sweeps: list[tuple[str, list]], defaults: dict, modes) -> Path:
    """The paper's ablation figure: one panel per swept setting, mean controller cost J (± its standard
    error over the seeds, left axis) and success rate S_R (right axis) against its values, per mode; the
    default value marked. (A std bar would reach below zero: J is skewed by the odd failed seed.)

    Args:
        table: :func:`~amhe_cli.control.evaluate.summarise` rows (with ``setting`` labels ``key=value``).
        sweeps: (key, values) in the order swept.
        defaults: key -> the value the run config leaves it at.
    """
    plt = _pyplot()
    path = Path(path)
    fig, axes = plt.subplots(1, len(sweeps), figsize=(4.6 * len(sweeps), 3.8), squeeze=False)
    twins = []
    for ax, (key, values) in zip(axes[0], sweeps):
        x = np.arange(len(values))
        right = ax.twinx()
        twins.append(right)
        for i, m in enumerate(modes):
            rows = [next((r for r in table if r["setting"] == f"{key}={v}" and r["mode"] == m), None) for v in values]
            if not any(rows):
                continue
            J = np.array([r["J"][0] if r else np.nan for r in rows])
            Jse = np.array([r["J"][1] / np.sqrt(max(r["n"], 1)) if r else np.nan for r in rows])
            sr = np.array([r["S_R"] if r else np.nan for r in rows])
            colour = f"C{i}"
            ax.errorbar(x, J, yerr=Jse, color=colour, marker="o", capsize=3, label=f"{m}: J")
            right.plot(x, sr, color=colour, marker="s", linestyle="--", label=f"{m}: S_R")
        if defaults.get(key) in values:
            ax.axvline(values.index(defaults[key]), color="0.5", linestyle=":", label="default")
        ax.set_xticks(x, [str(v) for v in values])
        ax.set_xlim(-0.5, len(values) - 0.5)
        ax.set_xlabel(f"{key} (default {defaults.get(key)})")
        ax.set_ylabel("controller cost J per cycle (mean ± s.e.)")
        right.set_ylabel("success rate S_R [%]")
        right.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
    h1, l1 = axes[0][0].get_legend_handles_labels()
    h2, l2 = twins[0].get_legend_handles_labels()
    fig.legend(h1 + h2, l1 + l2, fontsize=8, loc="lower center", ncol=len(h1 + h2), frameon=False)
    fig.suptitle("ablation: one setting varied at a time around the defaults")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
