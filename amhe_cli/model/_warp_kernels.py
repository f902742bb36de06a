"""Warp kernels of the ``cuda`` rollout backend (imported only where ``warp`` is installed)."""

import warp as wp


@wp.kernel
def set_ctrl(t: int, ctrl_in: wp.array3d(dtype=float), ctrl: wp.array2d(dtype=float)):
    """ctrl[w, :] = ctrl_in[w, t, :]: the recorded control of step ``t``, (nworld, H, nu) -> (nworld, nu)."""
    w, i = wp.tid()
    ctrl[w, i] = ctrl_in[w, t, i]


@wp.kernel
def record(t: int, qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float),
           qpos_out: wp.array3d(dtype=float), qvel_out: wp.array3d(dtype=float)):
    """Row ``t`` of the (nworld, H, nq) / (nworld, H, nv) outputs: the state after step ``t``."""
    w, i = wp.tid()
    if i < qpos.shape[1]:
        qpos_out[w, t, i] = qpos[w, i]
    if i < qvel.shape[1]:
        qvel_out[w, t, i] = qvel[w, i]
