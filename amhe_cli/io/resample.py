"""Resample unpacked series onto one uniform grid: step 4 of :mod:`~amhe_cli.io.reader`.

The grid covers the overlap of the roles, from its first joint-state message, so that on a log whose joint
states come every ``dt`` the joint positions, velocities and efforts are taken as measured and the commands
held against them as stamped: the servo law that :mod:`~amhe_cli.estimation.gains` fits and the rollouts
replay holds between samples of one clock. (Started at the latest stream's first message, a pose stream
shifted 3.9 ms for its lateness by ``load_problem`` moved a lock-step recording's grid between its 2 ms joint
samples: each effort then met the command before its own, the command-delay fit went to the end of its range,
20 ms, with Kp 25–60 and negative Kd on six joints, and the MHE read the box's friction force 28 % low
throughout; docs/reference.md#identification.) Then: linear interpolation of positions,
slerp of orientations (``scipy.spatial.transform.Slerp`` over each pose stream's
messages), zero-order hold of the commands; velocities come from the log where
it has them, else from a backward difference of the resampled poses. Base and
box poses may be smoothed first (:mod:`~amhe_cli.io.smoothing`, SciPy's
Savitzky–Golay filter).

Quaternions here are MuJoCo (w, x, y, z) arrays; they enter and leave SciPy only
through :func:`~amhe_cli.io.quat.rotation_from_wxyz` /
:func:`~amhe_cli.io.quat.rotation_to_wxyz`, the module :mod:`~amhe_cli.io.quat`
being the one wxyz/xyzw boundary.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Slerp

from amhe_cli.errors import AmheError
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.io.quat import (quat_make_continuous, quat_normalize, quat_relative_rotvec, rotation_from_wxyz,
                              rotation_to_wxyz)
from amhe_cli.io.roles import REQUIRED_ROLES
from amhe_cli.io.smoothing import CLEAN_SIGMA_ROT, savgol, window_for
from amhe_cli.io.unpack import _Series

#: A grid time counts as observed if its bracketing messages are at most this
#: many median message periods apart (commands: if the last one is this old)...
_GAP_FACTOR = 1.5
#: ... or at most this long apart [s], whatever the rate: a few dropped frames of a fast stream are
#: filled by interpolation, whose error over a gap g is at most a g² / 8 for an acceleration a (10 ms:
#: 0.06 mm for a box sliding to rest at 5 m/s², 2.5 mrad at a swing leg's 200 rad/s²). It fills up to
#: four dropped frames at 500 Hz, where the rule in periods alone left 189 of 9,900 0.2 s clip starts
#: without a gap on a log with 2 % of its pose frames dropped (0.98¹⁰⁰ of them, 13 %) and
#: ``identify`` read a 3.5 kg box as 0.2 kg. A dropped 120 Hz frame (16.7 ms) stays a gap: filling
#: it (20 ms) was measured worse on ``noisy_b`` (mass +8.0 ± 4.2 % against +4.0 ± 3.5 %, 8 seeds).
FILL_GAP_S = 0.010


def _bracket(t_msg: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left neighbour index (N_grid,) in [0, N-2] and fraction (N_grid,) in [0, 1]."""
    i = np.clip(np.searchsorted(t_msg, grid, side="right") - 1, 0, len(t_msg) - 2)
    u = (grid - t_msg[i]).astype(float) / (t_msg[i + 1] - t_msg[i]).astype(float)
    return i, u


def _lerp(x: np.ndarray, i: np.ndarray, u: np.ndarray) -> np.ndarray:
    return x[i] + u[:, None] * (x[i + 1] - x[i])


def _slerp(t_msg: np.ndarray, q_msg: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Orientations of a pose stream at grid times, by SciPy ``Slerp`` over all its messages.

    Between two messages the rotation follows the shorter arc at constant rate,
    whatever the quaternions' signs; the result keeps the sign of the earlier
    message's quaternion (``q[i] ⊗ exp(u log(q[i]* ⊗ q[i+1]))``), so a
    sign-continuous stream stays sign-continuous.

    Args:
        t_msg: (N,) strictly increasing message times [ns], N >= 2.
        q_msg: (N, 4) message orientations (w, x, y, z).
        grid: (N_grid,) grid times [ns]; ones outside the messages' span take the end orientation.

    Returns:
        (N_grid, 4) unit quaternions (w, x, y, z).
    """
    # times relative to the first message: absolute ns do not fit a float's 53 bits
    t = (t_msg - t_msg[0]).astype(float)
    g = np.clip((grid - t_msg[0]).astype(float), t[0], t[-1])
    return rotation_to_wxyz(Slerp(t, rotation_from_wxyz(q_msg))(g), g.shape)


def _observed_interp(t_msg: np.ndarray, grid: np.ndarray, period: float) -> np.ndarray:
    """True where the grid time is a message time or lies between two close messages: at most
    ``_GAP_FACTOR`` × ``period`` or :data:`FILL_GAP_S` apart (times and period [ns])."""
    i = np.clip(np.searchsorted(t_msg, grid, side="right") - 1, 0, len(t_msg) - 1)
    nxt = np.minimum(i + 1, len(t_msg) - 1)
    at_msg = t_msg[i] == grid
    return at_msg | ((t_msg[nxt] - t_msg[i]) <= max(_GAP_FACTOR * period, FILL_GAP_S * 1e9))


def _backward_diff(x: np.ndarray, dt: float) -> np.ndarray:
    """(T, k) -> (T, k): v[i] = (x[i] - x[i-1]) / dt, v[0] = v[1]."""
    v = np.empty_like(x)
    v[1:] = (x[1:] - x[:-1]) / dt
    v[0] = v[1] if len(x) > 1 else 0.0
    return v


def _backward_angvel(q: np.ndarray, dt: float) -> np.ndarray:
    """(T, 4) wxyz -> (T, 3) body angular velocity [rad/s], omega[i] = 2 log(q[i-1]^-1 q[i]) / dt."""
    w = np.empty((len(q), 3))
    w[1:] = quat_relative_rotvec(q[:-1], q[1:]) / dt
    w[0] = w[1] if len(q) > 1 else 0.0
    return w


def _pose_windows(s: "_Series", dt: float, smooth: int | str) -> tuple[int, int, float, float]:
    """Grid windows (position, orientation) and noise levels [m, rad] of one pose stream."""
    if smooth != "auto":
        w = int(smooth) if smooth and smooth > 1 else 1
        return w, w, 0.0, 0.0
    period = max(s.period_ns() * 1e-9, dt)
    sig_p, sig_r = s.pose_noise()
    # windows are chosen on the raw message rate, then expressed in grid samples
    wp = window_for(sig_p, period)
    wr = window_for(sig_r, period, target=0.2, clean=CLEAN_SIGMA_ROT)
    to_grid = period / dt
    return (int(round(wp * to_grid)) | 1 if wp > 1 else 1, int(round(wr * to_grid)) | 1 if wr > 1 else 1,
            sig_p, sig_r)


def resample_pose(s: "_Series", grid: np.ndarray, dt: float, smooth: int | str, meta: dict,
                  role: str) -> dict[str, np.ndarray]:
    """One pose stream on the grid, smoothed where its noise shows, with its velocities.

    Args:
        s: the stream's messages: ``fields["pos"]`` (N, 3) [m], ``fields["quat"]`` (N, 4) (w, x, y, z),
            and where logged ``linvel`` (N, 3) [m/s] world frame and ``angvel`` (N, 3) [rad/s] body frame;
            ``t_ns`` (N,) message times.
        grid: (T,) int64 grid times [ns]; dt: its spacing [s].
        smooth: ``"auto"``, 0 or a window in samples (:func:`~amhe_cli.io.reader.read_log`).
        meta: the trajectory's meta: a smoothing applied is noted in ``meta["smoothing"][role]``
            and, as a line for the user, in ``meta["warnings"]``.
        role: ``"base"`` or ``"box"``.
    Returns:
        ``pos`` (T, 3), ``quat`` (T, 4), ``linvel`` (T, 3), ``angvel`` (T, 3): the logged velocities where
        the stream has them, else the slope of the Savitzky–Golay fit (or a backward difference).
    """
    i, u = _bracket(s.t_ns, grid)
    pos = _lerp(s.fields["pos"], i, u)
    quat = _slerp(s.t_ns, s.fields["quat"], grid)
    wp, wr, sig_p, sig_r = _pose_windows(s, dt, smooth)
    linvel = _backward_diff(pos, dt)
    if wp > 1:
        pos, linvel = savgol(pos, wp, dt)
    if wr > 1:
        quat = quat_normalize(savgol(quat_make_continuous(quat), wr, dt)[0])
    angvel = _backward_angvel(quat, dt)
    if "linvel" in s.fields:
        linvel = _lerp(s.fields["linvel"], i, u)
        angvel = _lerp(s.fields["angvel"], i, u)
    if wp > 1 or wr > 1:
        meta.setdefault("smoothing", {})[role] = {"position_window": wp, "orientation_window": wr,
                                                 "position_noise_m": sig_p, "orientation_noise_rad": sig_r}
        what = "smoothed (--smooth)" if smooth != "auto" else \
            f"pose noise ~{sig_p * 1e3:.2g} mm / {sig_r * 1e3:.2g} mrad: smoothed"
        msg = f"{role} {what} over {wp * dt * 1e3:.0f} ms (position) / {wr * dt * 1e3:.0f} ms (orientation)"
        meta.setdefault("warnings", []).append(msg)  # issued with the others at the end of read_log
    return {"pos": pos, "quat": quat, "linvel": linvel, "angvel": angvel}


def _resample(series: dict[str, _Series], dt: float, dt_ns: int, smooth: int | str, meta: dict) -> Trajectory:
    """Put the required roles on one grid (see :func:`read_log`)."""
    cmd = series["joint_commands"]
    cmd_period = cmd.period_ns()
    start = max(int(series[r].t_ns[0]) for r in REQUIRED_ROLES)
    js = series["joint_states"]
    # the grid on the robot's own samples from there (module doc)
    first = int(np.searchsorted(js.t_ns, start, side="left"))
    if first < len(js.t_ns):
        start = int(js.t_ns[first])
    # A held command stays valid for one period after its last message.
    ends = [int(series[r].t_ns[-1]) for r in REQUIRED_ROLES if r != "joint_commands"]
    end = min(*ends, int(cmd.t_ns[-1] + cmd_period))
    t0 = min(int(series[r].t_ns[0]) for r in REQUIRED_ROLES)
    meta["t0_ns"] = t0
    if end - start < dt_ns:
        spans = "; ".join(
            f"{r} {(series[r].t_ns[0] - t0) * 1e-9:.3f}-{(series[r].t_ns[-1] - t0) * 1e-9:.3f} s"
            for r in REQUIRED_ROLES
        )
        raise AmheError(f"the log's roles overlap for less than one step dt={dt} s: {spans}")
    n = (end - start) // dt_ns + 1
    grid = start + dt_ns * np.arange(n, dtype=np.int64)
    out: dict[str, np.ndarray] = {}
    observed: dict[str, np.ndarray] = {}
    measured: dict[str, bool] = {}

    # Joint states.
    i, u = _bracket(js.t_ns, grid)
    out["joint_pos"] = _lerp(js.fields["q"], i, u)
    measured["joint_states"] = "dq" in js.fields
    out["joint_vel"] = _lerp(js.fields["dq"], i, u) if "dq" in js.fields else _backward_diff(out["joint_pos"], dt)
    observed["joint_states"] = _observed_interp(js.t_ns, grid, js.period_ns())
    # efforts that are all zero are a field left unfilled, not a measurement
    if "tau" in js.fields and np.abs(js.fields["tau"]).max() > 1e-9:
        out["joint_effort"] = _lerp(js.fields["tau"], i, u)

    # Free bodies.
    for role in ("base", "box"):
        s = series[role]
        out.update({f"{role}_{k}": v for k, v in resample_pose(s, grid, dt, smooth, meta, role).items()})
        measured[role] = "linvel" in s.fields
        observed[role] = _observed_interp(s.t_ns, grid, s.period_ns())

    # Commands: zero-order hold of the last command at or before each grid time.
    j = np.searchsorted(cmd.t_ns, grid, side="right") - 1
    out["ctrl"] = cmd.fields["q"][j]
    observed["joint_commands"] = (grid - cmd.t_ns[j]) <= _GAP_FACTOR * cmd_period
    measured["joint_commands"] = True

    t = (grid - t0).astype(float) * 1e-9
    return Trajectory(t=t, dt=dt, observed=observed, measured_velocity=measured, meta=meta, **out)
