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


@wp.func
def _rotvec(a: wp.array2d(dtype=float), ra: wp.array3d(dtype=float), w: int, k: int, t: int, adr: int, c: int):
    """Component ``c`` of ``2 log(q_ref* ⊗ q)`` (the shorter rotation), ``q`` = a[w, adr:adr+4] and ``q_ref`` =
    ra[k, t, adr:adr+4], both (w, x, y, z): :func:`amhe_cli.io.quat.quat_relative_rotvec`, written out."""
    aw = ra[k, t, adr]
    ax = ra[k, t, adr + 1]
    ay = ra[k, t, adr + 2]
    az = ra[k, t, adr + 3]
    bw = a[w, adr]
    bx = a[w, adr + 1]
    by = a[w, adr + 2]
    bz = a[w, adr + 3]
    qw = aw * bw + ax * bx + ay * by + az * bz
    x = aw * bx - ax * bw - ay * bz + az * by
    y = aw * by + ax * bz - ay * bw - az * bx
    z = aw * bz - ax * by + ay * bx - az * bw
    sign = float(1.0)
    if qw < 0.0:
        sign = -1.0
        qw = -qw
    s = wp.sqrt(x * x + y * y + z * z)
    scale = float(0.0)
    if s < 1.0e-8:
        scale = 2.0 / qw
    else:
        scale = 2.0 * wp.atan2(s, qw) / s
    v = x
    if c == 1:
        v = y
    elif c == 2:
        v = z
    return v * sign * scale


@wp.kernel
def score(step: wp.array(dtype=int), nclip: wp.array(dtype=int), horizon: wp.array(dtype=int),
          qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float), ref_qpos: wp.array3d(dtype=float),
          ref_qvel: wp.array3d(dtype=float), sqrt_w: wp.array3d(dtype=float), dof_qadr: wp.array(dtype=int),
          dof_rot: wp.array(dtype=int), acc: wp.array(dtype=wp.float64), bad: wp.array(dtype=int)):
    """The weighted squared state error of step t = step[0] added to each world's sum, while t is inside its
    clip's horizon (the cost module's ``state_error`` and ``W_x`` on the device, paper eq. (1)).

    Tangent component j < nv is dof j's position error: ``qpos[dof_qadr[j]]`` minus the reference's where
    ``dof_rot[j]`` is -1, else component ``dof_rot[j]`` of the rotation vector of the quaternion at
    ``dof_qadr[j]``; component nv + j is dof j's velocity error. ``sqrt_w`` (N_c, H, 2 nv) is ``sqrt(W_x)``
    masked by what was observed. A world whose state is non-finite or beyond 1 km is flagged in ``bad``.
    """
    w = wp.tid()
    k = w % nclip[0]
    t = step[0]
    if t >= horizon[k]:
        return
    nv = qvel.shape[1]
    for i in range(qpos.shape[1]):
        q = qpos[w, i]
        if not wp.isfinite(q) or wp.abs(q) > 1.0e3:
            bad[w] = 1
            return
    total = float(0.0)
    for j in range(nv):
        v = qvel[w, j]
        if not wp.isfinite(v):
            bad[w] = 1
            return
        r = int(dof_rot[j])
        e = float(0.0)
        if r < 0:
            e = qpos[w, dof_qadr[j]] - ref_qpos[k, t, dof_qadr[j]]
        else:
            e = _rotvec(qpos, ref_qpos, w, k, t, dof_qadr[j], r)
        e = e * sqrt_w[k, t, j]
        f = (v - ref_qvel[k, t, j]) * sqrt_w[k, t, nv + j]
        total += e * e + f * f
    acc[w] = acc[w] + wp.float64(total)


@wp.kernel
def clear_scores(acc: wp.array(dtype=wp.float64), bad: wp.array(dtype=int)):
    """Each world's error sum and flag to zero, before its clip is rolled out and scored."""
    w = wp.tid()
    acc[w] = wp.float64(0.0)
    bad[w] = 0
