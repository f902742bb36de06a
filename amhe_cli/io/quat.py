"""Quaternion and velocity-frame helpers, vectorised over leading axes.

This is the **one** place where quaternion order is converted (docs/log_schema.md#frames-and-units):
ROS messages store (x, y, z, w), MuJoCo and every array inside ``amhe`` store
(w, x, y, z). Readers call :func:`ros_to_mj` as they unpack a message, writers
call :func:`mj_to_ros` as they pack one; nothing else reorders components.

All functions take arrays of shape ``(..., 4)`` (quaternions, w first) and
``(..., 3)`` (vectors); leading axes broadcast against each other. Rotations
are active: :func:`quat_rotate` maps a vector expressed in the body frame to the
same vector expressed in the world frame, for a body whose orientation in the
world is ``q``.
"""

from __future__ import annotations

import numpy as np

#: Below this rotation angle [rad] the small-angle series are used.
_SMALL = 1e-8


def ros_to_mj(q_xyzw: np.ndarray) -> np.ndarray:
    """Reorder ROS (x, y, z, w) quaternions to MuJoCo (w, x, y, z).

    Args:
        q_xyzw: (..., 4) quaternions in ROS order.

    Returns:
        (..., 4) float array, same quaternions in (w, x, y, z) order (not normalised).
    """
    q = np.asarray(q_xyzw, dtype=float)
    return q[..., [3, 0, 1, 2]]


def mj_to_ros(q_wxyz: np.ndarray) -> np.ndarray:
    """Reorder MuJoCo (w, x, y, z) quaternions to ROS (x, y, z, w).

    Args:
        q_wxyz: (..., 4) quaternions in MuJoCo order.

    Returns:
        (..., 4) float array in (x, y, z, w) order.
    """
    q = np.asarray(q_wxyz, dtype=float)
    return q[..., [1, 2, 3, 0]]


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternions to unit norm.

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


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), (..., 4) -> (..., 4), (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of (w, x, y, z) quaternions.

    Args:
        a: (..., 4) quaternions.
        b: (..., 4) quaternions, broadcast against ``a``.

    Returns:
        (..., 4) products; ``quat_mul(q_wb, q_bc)`` composes frame rotations.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_rotate(q_wxyz: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors by unit quaternions: ``R(q) @ v``.

    Args:
        q_wxyz: (..., 4) unit quaternions (w, x, y, z).
        v: (..., 3) vectors, broadcast against ``q_wxyz``.

    Returns:
        (..., 3) rotated vectors.
    """
    q = np.asarray(q_wxyz, dtype=float)
    v = np.asarray(v, dtype=float)
    w = q[..., :1]
    u = q[..., 1:]
    # v' = v + 2 w (u x v) + 2 u x (u x v), the expanded form of q v q*.
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


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
        (..., 3) the same vectors in body coordinates.
    """
    return quat_rotate(quat_conj(q_wxyz), v_world)


def quat_to_rotvec(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation vector (axis × angle [rad]) of unit quaternions, i.e. ``2 log(q)``.

    The shorter of the two equivalent rotations is returned (angle in [0, π]).

    Args:
        q_wxyz: (..., 4) unit quaternions.

    Returns:
        (..., 3) rotation vectors [rad].
    """
    q = np.asarray(q_wxyz, dtype=float)
    q = np.where(q[..., :1] < 0.0, -q, q)
    w = q[..., 0]
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < _SMALL
    # angle / s -> 2 / w as s -> 0 (w -> 1); avoids 0/0.
    scale = np.where(small, 2.0 / np.where(small, w, 1.0), angle / np.where(small, 1.0, s))
    return xyz * scale[..., None]


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation vectors, the inverse of :func:`quat_to_rotvec`.

    Args:
        r: (..., 3) rotation vectors (axis × angle [rad]).

    Returns:
        (..., 4) unit quaternions (w, x, y, z).
    """
    r = np.asarray(r, dtype=float)
    angle = np.linalg.norm(r, axis=-1)
    small = angle < _SMALL
    half_sinc = np.where(small, 0.5 - angle**2 / 48.0, np.sin(0.5 * angle) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(0.5 * angle)[..., None], r * half_sinc[..., None]], axis=-1)


def quat_make_continuous(q_wxyz: np.ndarray) -> np.ndarray:
    """Flip signs along a sequence so consecutive quaternions share a hemisphere.

    ``q`` and ``-q`` are the same rotation; interpolating between them would go
    the long way round, so a sequence is made sign-continuous before slerp.

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


def quat_slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc.

    Computed as ``q0 ⊗ exp(u · log(q0* ⊗ q1))``, which stays accurate for the
    tiny rotations between consecutive samples of a log.

    Args:
        q0: (..., 4) unit quaternions at ``u = 0``.
        q1: (..., 4) unit quaternions at ``u = 1``.
        u: (...) interpolation fractions, usually in [0, 1].

    Returns:
        (..., 4) unit quaternions (w, x, y, z).
    """
    u = np.asarray(u, dtype=float)
    rel = quat_to_rotvec(quat_mul(quat_conj(q0), q1))
    return quat_mul(q0, quat_from_rotvec(rel * u[..., None]))


def quat_to_yaw(q_wxyz: np.ndarray) -> np.ndarray:
    """Heading (rotation about world z, ZYX convention) of quaternions [rad].

    Args:
        q_wxyz: (..., 4) unit quaternions.

    Returns:
        (...) yaw angles in (-π, π].
    """
    q = np.asarray(q_wxyz, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw: np.ndarray) -> np.ndarray:
    """Quaternions of pure rotations about z by ``yaw`` [rad], (...) -> (..., 4)."""
    yaw = np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(yaw)
    return np.stack([np.cos(0.5 * yaw), zeros, zeros, np.sin(0.5 * yaw)], axis=-1)


def quat_face_tilt(q_wxyz: np.ndarray) -> np.ndarray:
    """Tilt of a box from lying on any face [rad]: angle between world z and the nearest body axis.

    A box at rest on one of its six faces has tilt 0 whatever its yaw; one
    leaning on an edge has the lean angle.

    Args:
        q_wxyz: (..., 4) unit quaternions (body to world).

    Returns:
        (...) angles in [0, arccos(1/√3)].
    """
    q = np.asarray(q_wxyz, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # world-z components of the body axes: the third row of the rotation matrix
    row = np.stack([2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)], axis=-1)
    return np.arccos(np.clip(np.abs(row).max(axis=-1), 0.0, 1.0))
