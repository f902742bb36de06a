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

from .errors import AmheError  # noqa: E402


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


def plot_identify(path, result, cost_rollout) -> Path:
    """Cost over generations and recorded vs predicted box motion of an identification.

    Args:
        path: PNG to write.
        result: :class:`~amhe_cli.identify.IdentifyResult`.
        cost_rollout: callable (B, d) -> (qpos (B, N_c, H, nq), qvel) over the
            result's clips, i.e. ``RolloutCost.rollout``; called once with the
            prior and the estimate.
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
    t_rec = clips.start[:, None] + 1 + np.arange(clips.qpos.shape[1])[None, :]
    bx = scene.box_qpos
    for col, (axis, name) in enumerate(((0, "x"), (1, "y"))):
        ax = fig.add_subplot(grid[col, 1:])
        for k in range(len(clips)):
            h = clips.horizon[k]
            tt = t_rec[k, :h] * clips.dt
            ax.plot(tt, clips.qpos[k, :h, bx[axis]], color="k", lw=2.5, label="recorded" if k == 0 else None)
            ax.plot(tt, qpos[0, k, :h, bx[axis]], color="tab:red", lw=1, ls="--",
                    label="predicted, prior" if k == 0 else None)
            ax.plot(tt, qpos[1, k, :h, bx[axis]], color="tab:blue", lw=1.2,
                    label="predicted, estimate" if k == 0 else None)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"box {name} [m]")
        ax.set_title(f"box {name} over the {len(clips)} clips")
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
