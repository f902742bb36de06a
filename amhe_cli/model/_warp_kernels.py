"""Warp kernels of the ``cuda`` rollout backend (imported only where ``warp`` is installed).

Worlds are laid out candidate-major: world ``w`` is candidate ``w // nclip`` on clip
``w % nclip``; worlds past ``ncand · nclip`` (padding up to the allocated width)
repeat candidate 0.
"""

import warp as wp


@wp.kernel
def expand(ncand: int, nclip: wp.array(dtype=int), src: wp.array2d(dtype=float), dst: wp.array2d(dtype=float)):
    """Per-candidate field rows (ncand, k) -> per-world rows (nworld, k)."""
    w, i = wp.tid()
    b = w // nclip[0]
    if b >= ncand:
        b = 0
    dst[w, i] = src[b, i]


@wp.kernel
def reset_worlds(nclip: wp.array(dtype=int), nq: int, nv: int, init: wp.array2d(dtype=float),
                 time: wp.array(dtype=float), qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float),
                 qacc_warmstart: wp.array2d(dtype=float), overflow: wp.array(dtype=int), step: wp.array(dtype=int)):
    """Each world to its clip's recorded start: init rows are (time, qpos (nq), qvel (nv)); warm start and
    overflow flags cleared; the step counter to 0."""
    w = wp.tid()
    if w == 0:
        step[0] = 0
    k = w % nclip[0]
    time[w] = init[k, 0]
    for i in range(nq):
        qpos[w, i] = init[k, 1 + i]
    for i in range(nv):
        qvel[w, i] = init[k, 1 + nq + i]
        qacc_warmstart[w, i] = 0.0
    overflow[w] = 0


@wp.kernel
def set_ctrl(step: wp.array(dtype=int), nclip: wp.array(dtype=int), ctrl_in: wp.array3d(dtype=float),
             ctrl: wp.array2d(dtype=float)):
    """ctrl[w, :] = ctrl_in[w's clip, t, :] with t = step[0]: the recorded control of step t,
    (N_c, H, nu) -> (nworld, nu)."""
    w, i = wp.tid()
    ctrl[w, i] = ctrl_in[w % nclip[0], step[0], i]


@wp.kernel
def record(step: wp.array(dtype=int), qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float),
           qpos_out: wp.array3d(dtype=float), qvel_out: wp.array3d(dtype=float)):
    """Row t = step[0] of the (nworld, H, nq) / (nworld, H, nv) outputs: the state after step t."""
    w, i = wp.tid()
    t = step[0]
    if i < qpos.shape[1]:
        qpos_out[w, t, i] = qpos[w, i]
    if i < qvel.shape[1]:
        qvel_out[w, t, i] = qvel[w, i]


@wp.kernel
def advance(step: wp.array(dtype=int)):
    """The step counter to the next step (one thread, last in the captured step)."""
    step[0] = step[0] + 1
