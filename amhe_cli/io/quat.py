"""Quaternion and velocity-frame helpers, vectorised over leading axes; SciPy does the rotation maths.

This module is the **one** boundary between the two quaternion orders
(docs/log_schema.md#frames-and-units): ROS messages and SciPy's
:class:`~scipy.spatial.transform.Rotation` use (x, y, z, w); MuJoCo and every
array inside ``amhe`` store (w, x, y, z). Components are reordered only by
:func:`ros_to_mj` / :func:`mj_to_ros`: readers call the first as they unpack a
message, writers the second as they pack one, and the pair
:func:`rotation_from_wxyz` / :func:`rotation_to_wxyz` (built on them) is the
only way a wxyz array enters or leaves SciPy. Nothing else reorders components.

Rotation maths (products, inverses, rotating vectors, rotation vectors, yaw
quaternions, rotation matrices) is done by ``scipy.spatial.transform.Rotation``;
orientation streams are interpolated with ``scipy.spatial.transform.Slerp``
(:mod:`~amhe_cli.io.resample`). Two functions keep a small closed-form numpy
path because SciPy measured several times slower at their hot call sites (see
their docstrings): :func:`quat_relative_rotvec` (the rollout cost's state error)
and :func:`quat_to_yaw` (the Go1 state estimator, the control loop and the MPC cost).
:func:`quat_normalize` and :func:`quat_make_continuous` are plain array
operations with no SciPy equivalent.

All functions take arrays of shape ``(..., 4)`` (quaternions, w first) and
``(..., 3)`` (vectors); leading axes broadcast against each other (they are
flattened to SciPy's ``(N, 4)`` batches and restored). Quaternions handed to
SciPy are normalised by it; a zero quaternion raises ``ValueError``. Rotations
are active: :func:`quat_rotate` maps a vector expressed in the body frame to the
same vector expressed in the world frame, for a body whose orientation in the
world is ``q``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: Below this rotation angle [rad] the small-angle series are used (numpy fast path).
_SMALL = 1e-8


def ros_to_mj(q_xyzw: np.ndarray) -> np.ndarray:
    """Reorder ROS / SciPy (x, y, z, w) quaternions to MuJoCo (w, x, y, z).

    Args:
        q_xyzw: (..., 4) quaternions in ROS order.

    Returns:
        (..., 4) float array, same quaternions in (w, x, y, z) order (not normalised).
    """
    q = np.asarray(q_xyzw, dtype=float)
    return q[..., [3, 0, 1, 2]]


def mj_to_ros(q_wxyz: np.ndarray) -> np.ndarray:
    """Reorder MuJoCo (w, x, y, z) quaternions to ROS / SciPy (x, y, z, w).

    Args:
        q_wxyz: (..., 4) quaternions in MuJoCo order.

    Returns:
        (..., 4) float array in (x, y, z, w) order.
    """
    q = np.asarray(q_wxyz, dtype=float)
    return q[..., [1, 2, 3, 0]]


def rotation_from_wxyz(q_wxyz: np.ndarray) -> Rotation:
    """SciPy rotations of (w, x, y, z) quaternions of any leading shape.

    Args:
        q_wxyz: (..., 4) quaternions (normalised by SciPy; zero norm raises ``ValueError``).

    Returns:
        A stack of ``prod(...)`` rotations (leading axes flattened, C order; a
        single ``(4,)`` quaternion gives a stack of one). :func:`rotation_to_wxyz`
        with ``lead_shape=q_wxyz.shape[:-1]`` undoes the flattening.
    """
    return Rotation.from_quat(mj_to_ros(q_wxyz).reshape(-1, 4))


def rotation_to_wxyz(rot: Rotation, lead_shape: tuple[int, ...] | None = None) -> np.ndarray:
    """(w, x, y, z) quaternions of SciPy rotations, the inverse of :func:`rotation_from_wxyz`.

    Args:
        rot: a single rotation or a stack of them.
        lead_shape: leading shape to restore, e.g. the ``q.shape[:-1]`` the
            rotations were made from; None keeps SciPy's shape.

    Returns:
        (*lead_shape, 4) unit quaternions (w, x, y, z), signs as SciPy holds them (not canonicalised).
    """
    q = ros_to_mj(rot.as_quat())
    return q if lead_shape is None else q.reshape(tuple(lead_shape) + (4,))


def _broadcast(a: np.ndarray, na: int, b: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Broadcast the leading axes of ``a`` (..., na) and ``b`` (..., nb).

    Returns:
        ``a`` as (N, na), ``b`` as (N, nb) (writeable: SciPy's Cython wants
        writeable buffers) and the broadcast leading shape, ``N = prod(shape)``.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    lead = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    a = np.require(np.broadcast_to(a, lead + (na,)).reshape(-1, na), requirements="W")
    b = np.require(np.broadcast_to(b, lead + (nb,)).reshape(-1, nb), requirements="W")
    return a, b, lead


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternions to unit norm (signs kept).

    Args:
        q: (..., 4) quaternions, any component order.

    Returns:
        (..., 4) unit quaternions.

    Raises:
        ValueError: if a quaternion has zero (or non-finite) norm.
    """
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm)) or np.any(norm < 1e-12):
        raise ValueError("cannot normalise a quaternion of zero or non-finite norm")
    return q / norm


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of (w, x, y, z) quaternions (SciPy ``Rotation`` composition).

    Args:
        a: (..., 4) quaternions.
        b: (..., 4) quaternions, broadcast against ``a``.

    Returns:
        (..., 4) unit products (the inputs are normalised); ``quat_mul(q_wb, q_bc)``
        composes frame rotations. Signs follow the Hamilton product, not canonicalised.

    Not for hot batches: SciPy's composition measured ~30–40x slower than a
    written-out product on (16, 32, 100, 4) and 3x on one sample (11 vs 35 µs);
    the rollout cost uses :func:`quat_relative_rotvec` instead.
    """
    a, b, lead = _broadcast(a, 4, b, 4)
    return rotation_to_wxyz(rotation_from_wxyz(a) * rotation_from_wxyz(b), lead)


def quat_rotate(q_wxyz: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors by quaternions: ``R(q) @ v`` (SciPy ``Rotation.apply``).

    Args:
        q_wxyz: (..., 4) quaternions (w, x, y, z), normalised by SciPy.
        v: (..., 3) vectors, broadcast against ``q_wxyz``.

    Returns:
        (..., 3) rotated vectors.
    """
    q, v, lead = _broadcast(q_wxyz, 4, v, 3)
    return rotation_from_wxyz(q).apply(v).reshape(lead + (3,))


def body_to_world(q_wxyz: np.ndarray, v_body: np.ndarray) -> np.ndarray:
    """Express body-frame vectors (e.g. an Odometry twist) in the world frame.

    Args:
        q_wxyz: (..., 4) body orientation in the world, (w, x, y, z).
        v_body: (..., 3) vectors in body coordinates.

    Returns:
        (..., 3) the same vectors in world coordinates.
    """
    return quat_rotate(q_wxyz, v_body)


def world_to_body(q_wxyz: np.ndarray, v_world: np.ndarray) -> np.ndarray:
    """Express world-frame vectors in the body frame (inverse of :func:`body_to_world`).

    Args:
        q_wxyz: (..., 4) body orientation in the world, (w, x, y, z).
        v_world: (..., 3) vectors in world coordinates.

    Returns:
        (..., 3) the same vectors in body coordinates (``R(q)ᵀ @ v``).
    """
    q, v, lead = _broadcast(q_wxyz, 4, v_world, 3)
    return rotation_from_wxyz(q).apply(v, inverse=True).reshape(lead + (3,))


def quat_to_rotvec(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation vector (axis × angle [rad]) of quaternions, i.e. ``2 log(q)`` (SciPy ``as_rotvec``).

    The shorter of the two equivalent rotations is returned (angle in [0, π]).

    Args:
        q_wxyz: (..., 4) quaternions, normalised by SciPy.

    Returns:
        (..., 3) rotation vectors [rad].
    """
    q = np.asarray(q_wxyz, dtype=float)
    return rotation_from_wxyz(q).as_rotvec().reshape(q.shape[:-1] + (3,))


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors, the inverse of :func:`quat_to_rotvec` (SciPy ``from_rotvec``).

    Args:
        r: (..., 3) rotation vectors (axis × angle [rad]).

    Returns:
        (..., 4) unit quaternions (w, x, y, z), ``w = cos(|r| / 2)``.
    """
    r = np.asarray(r, dtype=float)
    return rotation_to_wxyz(Rotation.from_rotvec(r.reshape(-1, 3)), r.shape[:-1])


def quat_relative_rotvec(q_ref: np.ndarray, q: np.ndarray, single: bool = False) -> np.ndarray:
    """Rotation vector of ``q`` relative to ``q_ref`` in ``q_ref``'s body frame: ``2 log(q_ref* ⊗ q)``.

    The shorter rotation is returned (angle in [0, π]); equal to
    ``(rotation_from_wxyz(q_ref).inv() * rotation_from_wxyz(q)).as_rotvec()``
    for unit quaternions (agreement to 1e-12 is tested).

    Numpy fast path, kept on purpose: this is the rotation part of
    :func:`amhe_cli.estimation.cost.state_error` (every CMA-ES generation, on
    arrays of about (16, 32, 100, 4)), of the Go1 state estimator's box
    differentiator and of the log reader's backward angular velocity. Measured
    (SciPy 1.17.1, best of 5, strided (12|16, 32, 100, 4) slices of qpos as in
    the cost): this closed form 4.6–5.6 ms, SciPy ``from_quat`` / ``inv`` /
    ``*`` / ``as_rotvec`` 30–47 ms, i.e. SciPy 6.5–8.5x slower (its composition
    alone is ~30x slower than the written-out product); one (4,) sample 21 µs
    vs 32–42 µs (SciPy 1.5–1.8x slower).

    Args:
        q_ref: (..., 4) unit quaternions (w, x, y, z), e.g. the reference state.
        q: (..., 4) unit quaternions, broadcast against ``q_ref``.
        single: compute in float32 where both are float32 (a GPU backend's states in
            :func:`~amhe_cli.estimation.cost.state_error`); else, and by default, in float64.

    Returns:
        (..., 3) rotation vectors [rad]; divided by a time step they are body-frame angular velocities.
    """
    dtype = np.float32 if single and np.result_type(q_ref, q) == np.float32 else np.float64
    a = np.asarray(q_ref, dtype=dtype)
    b = np.asarray(q, dtype=dtype)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    # a* ⊗ b, written out
    w = aw * bw + ax * bx + ay * by + az * bz
    xyz = np.stack([aw * bx - ax * bw - ay * bz + az * by,
                    aw * by + ax * bz - ay * bw - az * bx,
                    aw * bz - ax * by + ay * bx - az * bw], axis=-1)
    sign = np.where(w < 0.0, dtype(-1.0), dtype(1.0))  # shorter rotation: w >= 0
    w = w * sign
    s = np.linalg.norm(xyz, axis=-1)
    small = s < _SMALL
    # 2 atan2(s, w) / s -> 2 / w as s -> 0 (w -> 1); avoids 0/0.
    scale = np.where(small, 2.0 / np.where(small, w, 1.0), 2.0 * np.arctan2(s, w) / np.where(small, 1.0, s))
    return xyz * (sign * scale.astype(dtype, copy=False))[..., None]


def quat_make_continuous(q_wxyz: np.ndarray) -> np.ndarray:
    """Flip signs along a sequence so consecutive quaternions share a hemisphere.

    ``q`` and ``-q`` are the same rotation; component-wise smoothing (or a
    hand-rolled interpolation) between them would go the long way round.

    Args:
        q_wxyz: (N, 4) quaternions in time order.

    Returns:
        (N, 4) the same rotations with ``dot(q[i-1], q[i]) >= 0``.
    """
    q = np.array(q_wxyz, dtype=float, copy=True)
    if q.shape[0] < 2:
        return q
    flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0.0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)])
    return q * sign[:, None]


def quat_to_yaw(q_wxyz: np.ndarray) -> np.ndarray:
    """Heading (rotation about world z, ZYX convention) of unit quaternions [rad].

    Equal to ``rotation_from_wxyz(q).as_euler("ZYX")[:, 0]`` away from ±90°
    pitch; at ±90° pitch this closed form stays defined (no gimbal-lock warning).

    Numpy fast path, kept on purpose: called on one sample per mocap pose by
    the Go1 state estimator and per control step by the closed loop, and on
    whole rollout batches by the MPC task cost. Measured (SciPy 1.17.1, best of
    5): one (4,) sample 4 µs vs SciPy ``as_euler("ZYX")`` 11–19 µs (2.7–4.5x
    slower); a (16, 32, 100, 4) batch 0.23 ms vs 6.8–7.8 ms (30x slower).

    Args:
        q_wxyz: (..., 4) unit quaternions.

    Returns:
        (...) yaw angles in (-π, π].
    """
    q = np.asarray(q_wxyz, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw: np.ndarray) -> np.ndarray:
    """Quaternions of pure rotations about z by ``yaw`` [rad], (...) -> (..., 4) (SciPy ``from_euler``).

    ``w = cos(yaw / 2)``, ``z = sin(yaw / 2)`` (no sign canonicalisation, so a
    yaw sequence gives a continuous quaternion sequence).
    """
    yaw = np.asarray(yaw, dtype=float)
    return rotation_to_wxyz(Rotation.from_euler("z", yaw.reshape(-1, 1)), yaw.shape)


def quat_face_tilt(q_wxyz: np.ndarray) -> np.ndarray:
    """Tilt of a box from lying on any face [rad]: angle between world z and the nearest body axis.

    A box at rest on one of its six faces has tilt 0 whatever its yaw; one
    leaning on an edge has the lean angle.

    Args:
        q_wxyz: (..., 4) quaternions (body to world), normalised by SciPy.

    Returns:
        (...) angles in [0, arccos(1/√3)].
    """
    q = np.asarray(q_wxyz, dtype=float)
    # world-z components of the body axes: the third row of the rotation matrix
    row = rotation_from_wxyz(q).as_matrix()[:, 2, :].reshape(q.shape[:-1] + (3,))
    return np.arccos(np.clip(np.abs(row).max(axis=-1), 0.0, 1.0))
