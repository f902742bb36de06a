"""The ``cuda`` rollout backend: MuJoCo Warp, candidates × clips as the worlds of one batched model.

The cost module (paper eq. 1 / eq. 4, :mod:`~amhe_cli.estimation.cost`) asks a
backend to roll ``B`` candidates out over ``N_c`` clips. Here that is one
MuJoCo Warp model with ``B · N_c`` worlds (world ``b · N_c + k`` = candidate
``b`` on clip ``k``) stepped ``H_max`` times by launching one captured CUDA graph of a step:

* **Per-world fields.** Everything :meth:`ParameterSpace.write
  <amhe_cli.model.params.ParameterSpace.write>` changes is a batched model
  field (:data:`BATCHED_FIELDS`: body mass and inertia, the box–floor pair
  friction, robot geom friction, servo gains), and so is every constant
  ``mj_setConst`` derives from them (``body_invweight0``, ``dof_invweight0``,
  ``body_subtreemass``, ``actuator_acc0``). The written fields of all
  candidates come from :meth:`ParameterSpace.model_fields
  <amhe_cli.model.params.ParameterSpace.model_fields>` (the very values
  ``write`` sets on the CPU) and the derived ones from ``mj_setConst`` on a
  host copy per candidate (:func:`candidate_fields`), so both backends see the
  same derived constants; :func:`check_space` refuses a parameter space that
  writes any other field.
* **Buffers.** Contact and constraint buffers are sized from the scene: an
  upper bound (:func:`buffer_sizes`: every geom pair that can touch, at the
  most contacts its types make, and the rows each contact and each joint
  limit, friction loss and equality adds) caps twice what the clips need at
  the prior (:func:`measured_sizes`, :func:`choose_sizes`). MuJoCo Warp flags
  an overflow per world; a flagged batch is repeated with larger buffers, and
  at the bound (or with sizes given) it raises
  :class:`~amhe_cli.errors.AmheError` — never a silent wrong answer.
* **The box's zero friction.** The CPU scene gives the box geom friction 0 so
  MuJoCo's max rule lets the robot geoms' coefficient (or the feet's, by
  priority) set robot–box friction, while the box–floor friction is an explicit
  ``<pair>``. MuJoCo Warp warns that a friction below ``MJ_MINMU`` "may cause
  NaN"; :func:`friction_floor` raises it to ``MJ_MINMU`` only where the max
  rule provably never uses it (every partner at least as large, or of higher
  priority), so neither backend's answer changes (tested on the CPU).
* **Scored on the device.** :meth:`WarpRollout.score_candidates` adds each step's weighted squared state
  error to a per-world sum inside the captured step (the cost module's ``state_error`` and ``W_x``, written
  out as a Warp kernel over :func:`dof_layout`), so only the (B, N_c) sums come back, not every state.
* **Refusals.** :func:`check_scene` refuses, with one line, a scene the
  backend cannot simulate faithfully; what MuJoCo Warp's own ``put_model``
  refuses is passed on as one line too.

Kernels compile on first use (about 3 minutes for this scene) into Warp's
kernel cache (``~/.cache/warp``, or ``$WARP_CACHE_PATH``); later processes load
them in seconds. The first use says so on stderr, with the time it took.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import os
import sys
import threading
import time

import mujoco
import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.model.params import ParameterSpace
from amhe_cli.model.rollout import edit_each

#: MuJoCo's smallest friction coefficient (mjMINMU).
MJ_MINMU = 1e-5

#: The fields ``mj_setConst`` derives from those :meth:`ParameterSpace.write
#: <amhe_cli.model.params.ParameterSpace.write>` sets (:attr:`ParameterSpace.MODEL_FIELDS
#: <amhe_cli.model.params.ParameterSpace.MODEL_FIELDS>`).
DERIVED_FIELDS = ("body_subtreemass", "body_invweight0", "dof_invweight0", "tendon_invweight0", "actuator_acc0")

#: Model fields that are per world (batched) in the Warp model: those ParameterSpace.write
#: sets and those mj_setConst derives from them.
BATCHED_FIELDS = ParameterSpace.MODEL_FIELDS + DERIVED_FIELDS

#: Fields mj_setConst may rewrite that a MuJoCo Warp step never reads (kept out of the per-world copy).
HOST_ONLY_FIELDS = ("dof_M0", "body_gravcomp_invweight0")

#: Unbatched fields that MuJoCo Warp's model lays out as ``MjModel`` does (``(*, n)`` or ``(n,)``, vec2 ranges
#: as pairs), so an edit copies them into a slot's device model in place (:meth:`WarpRollout.edit_models`)
IN_PLACE_FIELDS = ("actuator_forcerange", "actuator_forcelimited", "actuator_ctrlrange", "actuator_ctrllimited",
                   "dof_damping", "dof_armature", "dof_frictionloss")

#: Overflow bits (mujoco_warp OverflowType) that mean lost contacts or constraints: NEFC, NJMAX_NNZ,
#: BROADPHASE, NARROWPHASE, CCD. The solver's iteration limit (also flagged) is not an overflow: MuJoCo
#: on the CPU stops there too.
OVERFLOW_BITS = {1: "constraint rows (njmax)", 2: "constraint Jacobian non-zeros (njmax_nnz)",
                 4: "broadphase contacts (nconmax)", 8: "narrowphase contacts (nconmax)", 16: "CCD contacts"}

#: Slots (world capacities) kept at once; the least recently used is dropped beyond this.
MAX_SLOTS = 8

#: Held by every phase of a backend that enqueues device work (allocation, uploads, graph capture and launch,
#: the read-back copies), never while it waits. Warp's current stream is one setting per device, not per
#: thread: two backends in one process (a run's GPU planner and its GPU MHE thread), each in its own stream
#: through ``ScopedStream``, switched it under each other, so one's kernels landed in the other's stream — in
#: the middle of its graph capture ("Warp CUDA error 900: operation not permitted when stream is capturing",
#: an emulated Go1 run stopped 9 s in; tests/test_gpu_backend.py) or past its wait.
ENQUEUE_LOCK = threading.RLock()

#: Whether this process has said that the kernels compile (or load) and how long it took: once, not once per
#: backend (a command that fits the payload and then identifies makes two).
_KERNELS_ANNOUNCED = {"done": False}

_G = mujoco.mjtGeom
#: Most contacts one geom pair can make, by geom types (sorted); others: 4 (8 with a box or mesh).
MAX_CONTACTS = {
    (_G.mjGEOM_PLANE, _G.mjGEOM_SPHERE): 1, (_G.mjGEOM_PLANE, _G.mjGEOM_CAPSULE): 2,
    (_G.mjGEOM_PLANE, _G.mjGEOM_ELLIPSOID): 1, (_G.mjGEOM_PLANE, _G.mjGEOM_CYLINDER): 4,
    (_G.mjGEOM_PLANE, _G.mjGEOM_BOX): 4, (_G.mjGEOM_SPHERE, _G.mjGEOM_SPHERE): 1,
    (_G.mjGEOM_SPHERE, _G.mjGEOM_CAPSULE): 1, (_G.mjGEOM_SPHERE, _G.mjGEOM_CYLINDER): 1,
    (_G.mjGEOM_SPHERE, _G.mjGEOM_BOX): 1, (_G.mjGEOM_CAPSULE, _G.mjGEOM_CAPSULE): 2,
    (_G.mjGEOM_CAPSULE, _G.mjGEOM_BOX): 2, (_G.mjGEOM_BOX, _G.mjGEOM_BOX): 8,
}


def warp_device() -> str:
    """The Warp device the ``cuda`` backend uses: ``cuda:0``, or ``$AMHE_WARP_DEVICE`` (``cpu`` runs the
    same kernels on Warp's CPU back end, slowly: a debugging aid on machines without a GPU)."""
    return os.environ.get("AMHE_WARP_DEVICE", "cuda:0")


def _quiet(wp) -> None:
    """Keep Warp's greeting and per-module load lines off stderr (amhe prints what matters)."""
    if hasattr(wp, "LOG_WARNING"):  # warp-lang >= 1.19
        wp.config.log_level = wp.LOG_WARNING
    else:
        wp.config.quiet = True


def _array_fields(model: mujoco.MjModel) -> list[str]:
    return [a for a in dir(model) if not a.startswith("_") and isinstance(getattr(model, a, None), np.ndarray)]


def _max_contacts(t1: int, t2: int) -> int:
    key = tuple(sorted((int(t1), int(t2))))
    if key in MAX_CONTACTS:
        return MAX_CONTACTS[key]
    big = {int(_G.mjGEOM_BOX), int(_G.mjGEOM_MESH), int(_G.mjGEOM_HFIELD), int(_G.mjGEOM_SDF)}
    return 8 if big & set(key) else 4


def collision_pairs(model: mujoco.MjModel) -> tuple[list[tuple[int, int]], list[int]]:
    """Geom pairs that can touch: dynamic pairs (contype/conaffinity, not welded together, not parent
    and child unless the filter is off, not excluded, not shadowed by an explicit pair) and the
    explicit ``<pair>`` ids.

    Returns:
        ([(g1, g2), ...] dynamic pairs with g1 < g2, [pair id, ...]).
    """
    m = model
    explicit = {tuple(sorted((int(m.pair_geom1[i]), int(m.pair_geom2[i])))) for i in range(m.npair)}
    excluded = {int(s) for s in m.exclude_signature}
    filter_parent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    weld = m.body_weldid
    pairs = []
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            if not ((m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1])):
                continue
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            w1, w2 = int(weld[b1]), int(weld[b2])
            if w1 == w2:
                continue
            if filter_parent and w1 and w2 and (w1 == weld[m.body_parentid[w2]] or w2 == weld[m.body_parentid[w1]]):
                continue
            if ((min(b1, b2) << 16) + max(b1, b2)) in excluded or (g1, g2) in explicit:
                continue
            pairs.append((g1, g2))
    return pairs, list(range(m.npair))


def _rows(condim: int, elliptic: bool) -> int:
    return condim if (elliptic or condim == 1) else 2 * (condim - 1)


def buffer_sizes(model: mujoco.MjModel) -> tuple[int, int]:
    """Contact and constraint buffer sizes per world, from the scene: ``(nconmax, njmax)``.

    ``nconmax`` is the most contacts all pairs of :func:`collision_pairs` can make
    at once (:data:`MAX_CONTACTS` by geom types); ``njmax`` the rows they add
    (``condim`` per contact with elliptic cones, ``2 (condim − 1)`` pyramidal)
    plus one per limited joint or tendon, one per DOF or tendon with friction
    loss, and 3 / 6 / 1 per connect / weld / other equality. An upper bound, so
    a world never overflows in a scene that stays as built; an overflow still
    raises (:class:`WarpRollout`).
    """
    m = model
    elliptic = m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    pairs, explicit = collision_pairs(m)
    ncon = nrow = 0
    for g1, g2 in pairs:
        n = _max_contacts(m.geom_type[g1], m.geom_type[g2])
        ncon += n
        nrow += n * _rows(int(max(m.geom_condim[g1], m.geom_condim[g2])), elliptic)
    for p in explicit:
        n = _max_contacts(m.geom_type[m.pair_geom1[p]], m.geom_type[m.pair_geom2[p]])
        ncon += n
        nrow += n * _rows(int(m.pair_dim[p]), elliptic)
    nrow += int(np.count_nonzero(m.jnt_limited)) + int(np.count_nonzero(m.dof_frictionloss > 0))
    nrow += int(np.count_nonzero(m.tendon_limited)) + int(np.count_nonzero(m.tendon_frictionloss > 0))
    eq_rows = {int(mujoco.mjtEq.mjEQ_CONNECT): 3, int(mujoco.mjtEq.mjEQ_WELD): 6}
    nrow += sum(eq_rows.get(int(t), 1) for t in m.eq_type)
    return max(ncon, 1), max(nrow, 1)


def measured_sizes(model: mujoco.MjModel, initial_state: np.ndarray, control: np.ndarray,
                   horizon: np.ndarray, most: int = 16) -> tuple[int, int]:
    """Most contacts and constraint rows one world needs along the clips, at the model's own parameters.

    Steps up to ``most`` clips, spread over the set, on the CPU (``mj_step``)
    from their recorded starts with their recorded controls. All 48 clips of an
    ``identify`` took 1.0–1.2 s of its 4.9 s on the H100 machine; the sizes are
    twice this need (:func:`choose_sizes`) and a clip that needs more is caught
    by the overflow flags and grows the buffers, so a sample is enough.

    Args:
        initial_state: (N_c, nstate) mjSTATE_FULLPHYSICS; control: (N_c, H_max, nu); horizon: (N_c,).
    Returns:
        (most ``ncon``, most ``nefc``) over every step of the clips stepped.
    """
    d = mujoco.MjData(model)
    ncon = nefc = 0
    for k in np.unique(np.linspace(0, len(horizon) - 1, min(most, len(horizon))).round().astype(int)):
        mujoco.mj_setState(model, d, initial_state[k], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        for t in range(int(horizon[k])):
            d.ctrl[:] = control[k, t]
            mujoco.mj_step(model, d)
            ncon, nefc = max(ncon, d.ncon), max(nefc, d.nefc)
    return ncon, nefc


def choose_sizes(bound: tuple[int, int], measured: tuple[int, int]) -> tuple[int, int]:
    """Buffer sizes ``(nconmax, njmax)``: twice what the clips need at the prior (at least 16 more),
    rounded up to 16, never above the scene's :func:`buffer_sizes` bound.

    Why not the bound itself: MuJoCo Warp launches many solver kernels over
    ``nworld × njmax`` threads, so a bound 10× the need (876 rows against ~60
    for the Go1 and box) costs time every step. Candidates far from the prior
    may need more: an overflow then grows the buffers toward the bound and the
    call is repeated (:class:`WarpRollout`), never answered from a truncated step.
    """
    def size(b, m):
        return int(min(b, 16 * np.ceil(max(2 * m, m + 16) / 16)))
    return size(bound[0], measured[0]), size(bound[1], measured[1])


def friction_floor(model: mujoco.MjModel) -> tuple[list[int], str | None]:
    """Geoms whose friction below ``MJ_MINMU`` can be raised to it without changing any contact.

    Under MuJoCo's rule a dynamic contact takes the higher-priority geom's
    friction, or with equal priorities the element-wise max; explicit pairs
    carry their own. So raising geom ``g``'s components to ``MJ_MINMU`` changes
    nothing when every partner that can touch it has higher priority, or the
    same priority and every component ≥ ``MJ_MINMU``.

    Returns:
        (geom ids to raise, None), or ([], a one-line reason) when a partner
        would take the raised value (then the backend refuses the scene).
    """
    m = model
    low = [g for g in range(m.ngeom) if np.any(m.geom_friction[g] < MJ_MINMU)]
    if not low:
        return [], None
    pairs, _ = collision_pairs(m)
    for g in low:
        for g1, g2 in pairs:
            if g not in (g1, g2):
                continue
            other = g2 if g == g1 else g1
            if m.geom_priority[other] > m.geom_priority[g]:
                continue
            if m.geom_priority[other] < m.geom_priority[g] or np.any(m.geom_friction[other] < MJ_MINMU):
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
                oname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, other) or f"#{other}"
                return [], (f"geom {name}'s friction {m.geom_friction[g].tolist()} is below MuJoCo Warp's "
                            f"minimum {MJ_MINMU} and decides its contacts with {oname}")
    return low, None


def check_scene(model: mujoco.MjModel) -> None:
    """Refuse a scene the Warp backend cannot simulate faithfully.

    Raises:
        AmheError: one line naming what (noslip, flexes, plugins, an
            integrator MuJoCo Warp lacks, a zero friction the max rule uses).
    """
    m = model
    why = []
    if m.opt.noslip_iterations > 0:
        why.append(f"noslip iterations ({m.opt.noslip_iterations})")
    if m.nflex:
        why.append(f"{m.nflex} flexes")
    if m.nplugin:
        why.append(f"{m.nplugin} plugins")
    if m.na:
        why.append(f"actuator activations (na={m.na}: clip starts carry qpos and qvel only)")
    if m.opt.integrator not in (mujoco.mjtIntegrator.mjINT_EULER, mujoco.mjtIntegrator.mjINT_RK4,
                                mujoco.mjtIntegrator.mjINT_IMPLICITFAST, mujoco.mjtIntegrator.mjINT_IMPLICIT):
        why.append(f"integrator {mujoco.mjtIntegrator(m.opt.integrator).name}")
    _, reason = friction_floor(m)
    if reason:
        why.append(reason)
    if why:
        raise AmheError("--device cuda cannot simulate this scene faithfully: " + "; ".join(why)
                        + " (use --device cpu)")


def warp_host_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` with :func:`friction_floor`'s geoms raised to ``MJ_MINMU`` (what Warp is given)."""
    check_scene(model)
    low, _ = friction_floor(model)
    out = copy.copy(model)
    out.geom_friction[low] = np.maximum(out.geom_friction[low], MJ_MINMU)
    return out


def written_fields(space) -> set[str]:
    """Array fields of ``MjModel`` that ``space.write`` (with ``mj_setConst``) changes.

    Writes a candidate at 3/4 of the way to every upper bound into a copy of the
    scene's model and compares every array field with the template.
    """
    template = space.scene.model
    m = copy.copy(template)
    vec = space.mean0 + 0.75 * (space.upper - space.mean0)
    space.write(m, space.project(vec[None])[0][0])
    return {f for f in _array_fields(template)
            if getattr(template, f).shape == getattr(m, f).shape and not np.array_equal(getattr(template, f), getattr(m, f))}


def check_space(space) -> None:
    """Refuse a parameter space that writes a model field the Warp backend does not batch per world.

    Raises:
        AmheError: the field names.
    """
    extra = written_fields(space) - set(BATCHED_FIELDS) - set(HOST_ONLY_FIELDS)
    if extra:
        raise AmheError(f"--device cuda: parameters {', '.join(space.free)} write {', '.join(sorted(extra))}, "
                        "which the Warp backend does not set per world (use --device cpu)")


def candidate_fields(space, P: np.ndarray, models: list[mujoco.MjModel],
                     raise_friction: list[int] | None = None) -> dict[str, np.ndarray]:
    """Per-candidate values of :data:`BATCHED_FIELDS`, computed as the CPU backend computes them.

    The written fields of all candidates at once (:meth:`ParameterSpace.model_fields
    <amhe_cli.model.params.ParameterSpace.model_fields>`, what ``space.write`` sets), then per
    candidate those fields into a scratch model with ``mj_setConst`` (``space.write_fields``) and
    its :data:`DERIVED_FIELDS` read back: the same values to the bit as writing each candidate and
    copying every field, at half the cost (0.04 against 0.08 ms a candidate here; 200 candidates a
    call in a GPU MHE).

    Args:
        space: the parameter space.
        P: (B, d) feasible candidates.
        models: at least B scratch copies of the scene's model (overwritten).
        raise_friction: geoms whose friction is raised to ``MJ_MINMU`` (:func:`friction_floor`).
    Returns:
        field -> (B, *field shape) float64 array; empty fields (e.g. no tendons) left out.
    """
    P = np.atleast_2d(P)
    res = space.model_fields(P)
    derived = {f: np.empty((len(P),) + getattr(space.scene.model, f).shape)
               for f in DERIVED_FIELDS if getattr(space.scene.model, f).size}
    for b in range(len(P)):
        space.write_fields(models[b], res, b)
        for f, v in derived.items():
            v[b] = getattr(models[b], f)
    res.update(derived)
    if raise_friction:
        res["geom_friction"][:, raise_friction] = np.maximum(res["geom_friction"][:, raise_friction], MJ_MINMU)
    return res


def dof_layout(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """How each dof's position error is read from ``qpos``: the tangent layout of
    :func:`~amhe_cli.estimation.cost.state_error` for any scene.

    Returns:
        (nv,) qpos address and (nv,) rotation component per dof: -1 for a coordinate (a hinge or slide
        angle, a free joint's translation), the address its error is ``qpos[a] - qpos_ref[a]`` of; 0, 1, 2
        for a component of the rotation vector ``2 log(q_ref* ⊗ q)`` of the quaternion (w, x, y, z) at that
        address (a free or ball joint's orientation).
    """
    qadr = np.zeros(model.nv, dtype=np.int32)
    rot = np.full(model.nv, -1, dtype=np.int32)
    J = mujoco.mjtJoint
    for j in range(model.njnt):
        q, v, kind = int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j]), model.jnt_type[j]
        if kind == J.mjJNT_FREE:
            qadr[v:v + 3] = q + np.arange(3)
            qadr[v + 3:v + 6] = q + 3
            rot[v + 3:v + 6] = np.arange(3)
        elif kind == J.mjJNT_BALL:
            qadr[v:v + 3] = q
            rot[v:v + 3] = np.arange(3)
        else:
            qadr[v] = q
    return qadr, rot


def _digest(*arrays: np.ndarray) -> bytes:
    """A key for a set of arrays (shapes, dtypes and bytes): what a slot last uploaded, to skip the same again."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.shape, a.dtype.str)).encode())
        h.update(a.tobytes())
    return h.digest()


def _hold_past_horizon(qpos: np.ndarray, qvel: np.ndarray, horizon: np.ndarray) -> None:
    """Rows of (B, N_c, H, ·) states past each clip's horizon replaced by its last state, in place (as on the CPU)."""
    for k, h in enumerate(np.asarray(horizon, dtype=int)):
        qpos[:, k, h:] = qpos[:, k, h - 1:h]
        qvel[:, k, h:] = qvel[:, k, h - 1:h]


def world_capacity(nworld: int) -> int:
    """Worlds to allocate for ``nworld``: at least 64, rounded up to a quarter of the power of two below
    it (576 -> 640, 1200 -> 1280, 16368 -> 16384), so a batch that shrinks or grows a little reuses its
    slot (model, data and captured step) while a slot never steps much more than it needs: every world
    of a slot is stepped, and rounding to the next power of two stepped up to twice the worlds."""
    n = max(int(nworld), 64)
    quarter = max(16, (1 << (n.bit_length() - 1)) // 4)
    return -(-n // quarter) * quarter


class _Slot:
    """The device state of one world capacity: model and data for ``cap`` worlds, the per-world field views,
    the clip inputs and state outputs (with page-locked host twins), and the step captured on them."""

    def __init__(self, cap: int):
        self.cap = cap
        self.graph = None
        self.hcap = self.ncap = 0
        self.clipkey = None
        self.refkey = None
        self.fieldkey = None


class WarpRollout:
    """Batched rollouts on a CUDA device through MuJoCo Warp (the ``cuda`` rollout backend).

    Args:
        model: the scene's template ``MjModel`` (never modified).
        nconmax, njmax: per-world contact and constraint buffer sizes
            (default: :func:`choose_sizes` from the first call's clips, grown on
            overflow up to :func:`buffer_sizes`; given: fixed, and an overflow raises).
        device: Warp device (default :func:`warp_device`:
            ``cuda:0``); ``"cpu"`` (Warp's LLVM back end, no CUDA graph, slow)
            exists to debug the backend on a machine without a GPU.

    Raises:
        AmheError: ``amhe[gpu]`` not installed, no CUDA device, or a scene the
            backend refuses (:func:`check_scene`, or MuJoCo Warp's own checks).

    Offers the same ``rollout_candidates`` / ``close`` as
    :class:`~amhe_cli.model.rollout.RolloutPool`. Physics runs in float32 on
    the device; states come back as float32.
    """

    def __init__(self, model: mujoco.MjModel, nconmax: int | None = None, njmax: int | None = None,
                 device: str | None = None):
        try:
            import warp as wp
            _quiet(wp)  # before mujoco_warp's import initialises Warp: amhe says what matters
            import mujoco_warp as mjw
        except ImportError as e:
            raise AmheError(f"--device cuda: {e.name} not installed (pip install 'amhe[gpu]')") from None
        wp.init()
        device = device or warp_device()
        if device.startswith("cuda") and wp.get_cuda_device_count() < 1:
            raise AmheError("--device cuda: no CUDA device found")
        self.wp, self.mjw = wp, mjw
        self.template = model
        self.host = warp_host_model(model)
        self._raise, _ = friction_floor(model)
        self.bound = buffer_sizes(model)
        self._fixed = nconmax is not None or njmax is not None  # sizes given: an overflow raises
        # 0: chosen from the first call's clips (choose_sizes); one of them given: the other at the bound
        self.nconmax = int(nconmax or (self.bound[0] if self._fixed else 0))
        self.njmax = int(njmax or (self.bound[1] if self._fixed else 0))
        self.device = wp.get_device(device)
        #: a CUDA stream of its own: two backends in one process (the run's planner and its MHE thread)
        #: then run their steps side by side instead of queueing on the device's default stream
        self.stream = wp.Stream(self.device) if self.device.is_cuda else None
        self._models: list[mujoco.MjModel] = []
        self._spaces_checked: set[int] = set()
        self._slots: dict[int, _Slot] = {}
        self.compile_time: float | None = None
        #: host wall seconds per phase of rollout_candidates, summed over calls (benchmarks/gpu_throughput.py)
        self.timing = {"setup": 0.0, "fields": 0.0, "upload": 0.0, "steps": 0.0, "readback": 0.0, "calls": 0,
                       "slots": 0, "graphs": 0}
        self.nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self._dof = dof_layout(model)

    def describe(self) -> str:
        """One line for the device announcement."""
        return f"MuJoCo Warp {getattr(self.mjw, '__version__', '?')} on {self.device.name}"

    def __enter__(self) -> "WarpRollout":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Drop the device buffers and graphs (a later call allocates them again)."""
        with ENQUEUE_LOCK:
            self._slots.clear()

    @contextlib.contextmanager
    def _scope(self):
        """Enqueue work in this backend's stream (on CUDA) or on its device, holding :data:`ENQUEUE_LOCK`."""
        with ENQUEUE_LOCK, (self.wp.ScopedStream(self.stream) if self.stream is not None
                            else self.wp.ScopedDevice(self.device)):
            yield

    def _sync(self) -> None:
        """Wait for this backend's own work (its stream; the whole device off CUDA)."""
        if self.stream is not None:
            self.wp.synchronize_stream(self.stream)
        else:
            self.wp.synchronize_device(self.device)

    def models(self, n: int) -> list[mujoco.MjModel]:
        """``n`` host model copies to write candidates into (created once, reused)."""
        while len(self._models) < n:
            self._models.append(copy.copy(self.template))
        return self._models[:n]

    def edit_models(self, edit, base: mujoco.MjModel | None = None) -> None:
        """Apply ``edit(model)`` (in place) to the template, the host copies and ``base``, and carry what it
        changed into every slot's worlds from the next call on: what is not a parameter the candidates write,
        such as a robot's servo and motors read mid-run (:mod:`~amhe_cli.control.robot_side`), as
        :meth:`RolloutPool.edit_models <amhe_cli.model.rollout.RolloutPool.edit_models>` does on the CPU.

        A batched field (:data:`BATCHED_FIELDS`: the servo gains among them) is rewritten from ``base`` (the
        space's scene model, which :meth:`ParameterSpace.model_fields
        <amhe_cli.model.params.ParameterSpace.model_fields>` copies) at the next call, the slots' field cache
        dropped; a changed field of :data:`IN_PLACE_FIELDS` (the motors' ``actuator_forcerange``) is copied
        into each slot's device model in place, so its captured step stays valid. Any other changed field drops
        every slot (the next call builds them again from the edited model: seconds, not minutes). ``edit`` sets
        values (applying it twice is applying it once): a model the caller's CPU pool shares is edited by both.
        """
        edit_each(edit, base, self.template, *self._models)
        new = warp_host_model(self.template)
        changed = [f for f in _array_fields(new) if f not in BATCHED_FIELDS
                   and not np.array_equal(getattr(new, f), getattr(self.host, f))]
        self.host = new
        for s in list(self._slots.values()):
            s.fieldkey = None  # the batched fields come again from the edited base at the next call
            if not all(self._copy_field(s, f) for f in changed):
                self.close()
                break

    def _copy_field(self, s: _Slot, field: str) -> bool:
        """Host ``field`` into slot ``s``'s device model in place (every world); False where it cannot be."""
        wp = self.wp
        arr = getattr(s.m, field, None)
        if field not in IN_PLACE_FIELDS or not isinstance(arr, wp.array):
            return False
        shape = tuple(arr.shape) + tuple(getattr(arr.dtype, "_shape_", ()))  # a vec2 field: (..., 2) floats
        value = np.asarray(getattr(self.host, field))
        if value.size != int(np.prod(shape)):  # an unbatched field: one world's worth, (1, n) or (n,)
            return False
        value = value.reshape(shape)
        with self._scope():
            src = wp.array(np.ascontiguousarray(value), dtype=arr.dtype, device=self.device)
            wp.copy(arr, src)
        return True

    # -- device set-up ---------------------------------------------------------
    def _slot(self, nworld: int) -> _Slot:
        """The slot for ``world_capacity(nworld)`` worlds, allocated on first need.

        Each capacity keeps its own model, data and captured step, so a narrow call (a
        CMA-ES generation) never steps the worlds a wider one (the clip choice) needed:
        the graph steps every world of its slot.
        """
        cap = world_capacity(nworld)
        slot = self._slots.pop(cap, None) or self._allocate(cap)
        self._slots[cap] = slot  # most recently used last
        while len(self._slots) > MAX_SLOTS:  # an MHE's windows vary in width: keep the device memory bounded
            self._slots.pop(next(iter(self._slots)))
        return slot

    def _allocate(self, cap: int) -> _Slot:
        """Model, data and per-world field views for ``cap`` worlds."""
        wp, mjw = self.wp, self.mjw
        t0 = time.perf_counter()
        s = _Slot(cap)
        batch = {f: cap for f in BATCHED_FIELDS if getattr(self.host, f).size}
        try:
            with self._scope():
                s.m = mjw.put_model(self.host, batch_sizes=batch)
                s.m.opt.warn_overflow = 0  # overflows are read from d.overflow and handled, not printed
                s.d = mjw.put_data(self.host, mujoco.MjData(self.host), nworld=cap, nconmax=self.nconmax,
                                   njmax=self.njmax)
                # each batched field seen as (cap, k) floats, for the candidate -> world expansion
                s.flat = {}
                for f in batch:
                    arr = getattr(s.m, f)
                    if not arr.is_contiguous or arr.shape[0] != cap:
                        raise NotImplementedError(f"model field {f} is not a contiguous per-world array")
                    k = arr.size * wp.types.type_size_in_bytes(arr.dtype) // 4 // cap
                    s.flat[f] = wp.array(ptr=arr.ptr, dtype=float, shape=(cap, k), device=self.device)
                s.nclip = wp.zeros(1, dtype=int)
                s.step = wp.zeros(1, dtype=int)
                s.dof_qadr = wp.array(self._dof[0], dtype=int)
                s.dof_rot = wp.array(self._dof[1], dtype=int)
                s.acc = wp.zeros(cap, dtype=wp.float64)
                s.bad = wp.zeros(cap, dtype=int)
            # page-locked host twins of the overflow flags and the scores (read back in this backend's stream)
            pinned = self.device.is_cuda
            s.flags_host = wp.empty(cap, dtype=s.d.overflow.dtype, device="cpu", pinned=pinned)
            s.acc_host = wp.empty(cap, dtype=wp.float64, device="cpu", pinned=pinned)
            s.bad_host = wp.empty(cap, dtype=int, device="cpu", pinned=pinned)
        except (NotImplementedError, ValueError) as e:
            raise AmheError(f"--device cuda cannot simulate this scene: {str(e).splitlines()[0]} "
                            "(use --device cpu)") from None
        self.timing["setup"] += time.perf_counter() - t0
        self.timing["slots"] += 1
        return s

    def _buffers(self, s: _Slot, nclip: int, hmax: int) -> None:
        """Clip inputs (N_c, ...) and state outputs (worlds, H, ...) at least this large (drops the graph if grown)."""
        if hmax <= s.hcap and nclip <= s.ncap:
            return
        wp, m = self.wp, self.host
        s.hcap, s.ncap = max(hmax, s.hcap), max(nclip, s.ncap)
        with self._scope():
            s.init_in = wp.zeros((s.ncap, 1 + m.nq + m.nv), dtype=float)
            s.ctrl_in = wp.zeros((s.ncap, s.hcap, m.nu), dtype=float)
            s.qpos_out = wp.zeros((s.cap, s.hcap, m.nq), dtype=float)
            s.qvel_out = wp.zeros((s.cap, s.hcap, m.nv), dtype=float)
            # what score_candidates scores against: the clips' recorded states, sqrt(W_x) and horizons (a
            # horizon of 0 scores nothing: a call for states alone leaves the sums unread)
            s.ref_qpos = wp.zeros((s.ncap, s.hcap, m.nq), dtype=float)
            s.ref_qvel = wp.zeros((s.ncap, s.hcap, m.nv), dtype=float)
            s.sqrt_w = wp.zeros((s.ncap, s.hcap, 2 * m.nv), dtype=float)
            s.horizon = wp.zeros(s.ncap, dtype=int)
        # page-locked host twins, so the read-back is one DMA at full bus speed (a pageable copy is staged)
        pinned = self.device.is_cuda
        s.qpos_host = wp.empty(s.qpos_out.shape, dtype=float, device="cpu", pinned=pinned)
        s.qvel_host = wp.empty(s.qvel_out.shape, dtype=float, device="cpu", pinned=pinned)
        s.graph = None  # it writes the old buffers
        s.clipkey = s.refkey = None

    def _upload_clips(self, s: _Slot, initial_state: np.ndarray, control: np.ndarray) -> None:
        """Recorded starts and controls to the device, once per clip set (a changed set is uploaded anew)."""
        key = _digest(initial_state, control)
        if key == s.clipkey:
            return
        m, n, hmax = self.host, len(initial_state), control.shape[1]
        init = np.zeros((s.ncap, 1 + m.nq + m.nv), dtype=np.float32)
        init[:n] = initial_state[:, :1 + m.nq + m.nv]
        ctrl = np.zeros((s.ncap, s.hcap, m.nu), dtype=np.float32)
        ctrl[:n, :hmax] = control
        ctrl[:n, hmax:] = control[:, -1:]
        s.init_in.assign(init)
        s.ctrl_in.assign(ctrl)
        s.nclip.assign(np.array([n], dtype=np.int32))
        s.clipkey = key

    def _upload_refs(self, s: _Slot, horizon: np.ndarray, ref_qpos: np.ndarray, ref_qvel: np.ndarray,
                     sqrt_w: np.ndarray) -> None:
        """What the clips are scored against to the device, once per set (as :meth:`_upload_clips`)."""
        key = _digest(horizon, ref_qpos, ref_qvel, sqrt_w)
        if key == s.refkey:
            return
        n, hmax = ref_qpos.shape[:2]

        def padded(a, width):
            out = np.zeros((s.ncap, s.hcap, width), dtype=np.float32)
            out[:n, :hmax] = a
            return out
        hor = np.zeros(s.ncap, dtype=np.int32)
        hor[:n] = np.minimum(horizon, hmax)
        s.ref_qpos.assign(padded(ref_qpos, ref_qpos.shape[-1]))
        s.ref_qvel.assign(padded(ref_qvel, ref_qvel.shape[-1]))
        s.sqrt_w.assign(padded(sqrt_w, sqrt_w.shape[-1]))
        s.horizon.assign(hor)
        s.refkey = key

    def _graph(self, s: _Slot):
        """One step of slot ``s`` (set the step's control, step, record and score, advance the counter), captured
        as a CUDA graph on first need; a call launches it ``H_max`` times.

        One step, not the whole loop: capturing records every kernel launch of
        every step from Python (about 27 ms a step here), so a 65-step loop
        cost 1.3–1.9 s to capture for each new width and horizon — most of a
        short ``identify``'s time (measured: 5.3 s of 9.8 s). Launching a
        captured step costs ~0.2 ms of host time (profiled in a GPU ``mhe-replay``), queued while
        the previous steps run (1.3–1.6 ms each).
        """
        wp = self.wp
        if s.graph is None:
            first = self.compile_time is None
            say = first and not _KERNELS_ANNOUNCED["done"]
            if say:
                print("amhe: compiling MuJoCo Warp kernels, or loading them from Warp's kernel cache "
                      "(~/.cache/warp, or $WARP_CACHE_PATH): minutes the first time, seconds after…",
                      file=sys.stderr, flush=True)
            t0 = time.perf_counter()
            with self._scope():
                if first:  # load every module outside the capture
                    self._reset_worlds(s)
                    self._step(s)
                    self._sync()
                if self.device.is_cuda:
                    with wp.ScopedCapture() as cap:
                        self._step(s)
                    s.graph = cap.graph
                else:
                    s.graph = "eager"  # no graphs off CUDA: _launch steps eagerly
            if first:
                self.compile_time = time.perf_counter() - t0
                if say:
                    print(f"amhe: MuJoCo Warp kernels ready in {self.compile_time:.1f} s", file=sys.stderr,
                          flush=True)
                    _KERNELS_ANNOUNCED["done"] = True
            else:
                self.timing["setup"] += time.perf_counter() - t0
            self.timing["graphs"] += 1
        return s.graph

    def _reset_worlds(self, s: _Slot) -> None:
        """Every world to its clip's start, the step counter to 0."""
        from amhe_cli.model import _warp_kernels as K
        m, d = self.host, s.d
        self.wp.launch(K.reset_worlds, dim=s.cap, inputs=[s.nclip, m.nq, m.nv, s.init_in],
                       outputs=[d.time, d.qpos, d.qvel, d.qacc_warmstart, d.overflow, s.step])
        self.wp.launch(K.clear_scores, dim=s.cap, inputs=[], outputs=[s.acc, s.bad])

    def _step(self, s: _Slot) -> None:
        """One step of every world: the step's control, ``mjw.step``, the state recorded and scored, the counter
        advanced."""
        wp, m, d = self.wp, self.host, s.d
        from amhe_cli.model import _warp_kernels as K
        wp.launch(K.set_ctrl, dim=(s.cap, m.nu), inputs=[s.step, s.nclip, s.ctrl_in], outputs=[d.ctrl])
        self.mjw.step(s.m, d)
        wp.launch(K.record, dim=(s.cap, max(m.nq, m.nv)), inputs=[s.step, d.qpos, d.qvel],
                  outputs=[s.qpos_out, s.qvel_out])
        wp.launch(K.score, dim=s.cap, inputs=[s.step, s.nclip, s.horizon, d.qpos, d.qvel, s.ref_qpos, s.ref_qvel,
                                              s.sqrt_w, s.dof_qadr, s.dof_rot], outputs=[s.acc, s.bad])
        wp.launch(K.advance, dim=1, inputs=[s.step])

    def _launch(self, s: _Slot, hmax: int) -> None:
        """Reset every world, then ``hmax`` steps (the captured step graph launched ``hmax`` times)."""
        graph = self._graph(s)
        with self._scope():
            self._reset_worlds(s)
            for _ in range(hmax):
                if self.device.is_cuda:
                    self.wp.capture_launch(graph)
                else:
                    self._step(s)

    def _readback(self, s: _Slot, nworld: int, hmax: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """qpos (nworld, hmax, nq), qvel (nworld, hmax, nv) and the overflow flags (nworld,) of the last launch,
        as new host arrays.

        Only the first ``nworld`` worlds' rows are copied (into the pinned twins, enqueued in this backend's
        stream; the wait holds no lock), then out of them into arrays the caller owns: the twins are reused
        by the next call.
        """
        wp, m = self.wp, self.host
        rows = nworld * s.hcap
        with self._scope():
            wp.copy(s.qpos_host, s.qpos_out, count=rows * m.nq)
            wp.copy(s.qvel_host, s.qvel_out, count=rows * m.nv)
            wp.copy(s.flags_host, s.d.overflow, count=nworld)
        self._sync()
        return (np.array(s.qpos_host.numpy()[:nworld, :hmax]), np.array(s.qvel_host.numpy()[:nworld, :hmax]),
                np.array(s.flags_host.numpy()[:nworld]))

    def _readback_scores(self, s: _Slot, nworld: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The error sums (nworld,), diverged flags (nworld,) and overflow flags (nworld,) of the last launch,
        as new host arrays (as :meth:`_readback`)."""
        wp = self.wp
        with self._scope():
            wp.copy(s.acc_host, s.acc, count=nworld)
            wp.copy(s.bad_host, s.bad, count=nworld)
            wp.copy(s.flags_host, s.d.overflow, count=nworld)
        self._sync()
        return (np.array(s.acc_host.numpy()[:nworld]), np.array(s.bad_host.numpy()[:nworld]),
                np.array(s.flags_host.numpy()[:nworld]))

    def _set_fields(self, s: _Slot, fields: dict[str, np.ndarray], ncand: int) -> None:
        """Per-candidate (B, ...) fields to every world (world w: candidate w // N_c; padding: candidate 0)."""
        wp = self.wp
        from amhe_cli.model import _warp_kernels as K
        with self._scope():
            for f, v in fields.items():
                dst = s.flat[f]
                src = wp.array(np.ascontiguousarray(v.reshape(ncand, -1), dtype=np.float32), dtype=float)
                wp.launch(K.expand, dim=dst.shape, inputs=[ncand, s.nclip, src], outputs=[dst])

    # -- the backend interface -------------------------------------------------
    def rollout_candidates(self, space, P: np.ndarray, initial_state: np.ndarray, control: np.ndarray,
                           horizon: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Roll every candidate out over every clip (same contract as
        :meth:`RolloutPool.rollout_candidates <amhe_cli.model.rollout.RolloutPool.rollout_candidates>`;
        states come back as float32).

        All clips run ``H_max`` steps, the captured step launched ``H_max`` times (width is cheap on a
        GPU, depth is not); rows past a clip's horizon are then replaced by its
        last state, as on the CPU. The clips' recorded starts and controls are
        uploaded once per clip set; a call uploads only the candidates'
        per-world fields, and those only where they differ from the slot's
        last call's (a planner's belief, cycle after cycle, is written once).

        Raises:
            AmheError: with buffer sizes given, a contact or constraint buffer
                overflowed in some world (the count and which buffer); or
                ``space`` writes a field this backend does not batch
                (:func:`check_space`). Chosen sizes grow on overflow instead, and
                worlds that overflow the scene's bound come back as NaN (the
                cost module's "diverged") with a warning.
        """
        return self._rollout_candidates(space, P, initial_state, control, horizon)

    def score_candidates(self, space, P: np.ndarray, initial_state: np.ndarray, control: np.ndarray,
                         horizon: np.ndarray, ref_qpos: np.ndarray, ref_qvel: np.ndarray,
                         sqrt_w: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """Roll every candidate out over every clip and score it on the device: the data term of paper eq. (1)
        per candidate and clip, without the states coming back.

        Args:
            space, P, initial_state, control, horizon: as :meth:`rollout_candidates`.
            ref_qpos: (N_c, H_max, nq) and ref_qvel: (N_c, H_max, nv) the clips' recorded states after each step.
            sqrt_w: (N_c, H_max, 2 nv) ``sqrt(W_x)`` per tangent component (zero where unobserved), the layout
                of :func:`~amhe_cli.estimation.cost.state_error` (:func:`dof_layout`).
        Returns:
            (B, N_c) float64 sums ``Σ_t ||x^r_{t+1} - x_{t+1}(p)||²_{W_x}`` over each clip's horizon, computed in
            float32 per step (as the host scores a GPU's float32 states), (B, N_c) bool diverged (a state
            non-finite or beyond 1 km, or its world's buffers overflowed at the scene's bound; its sum is
            meaningless), and the steps simulated.

        Raises:
            AmheError: as :meth:`rollout_candidates`.
        """
        m = self.host
        n, hmax = len(horizon), int(control.shape[1])
        if ref_qpos.shape != (n, hmax, m.nq) or ref_qvel.shape != (n, hmax, m.nv) or sqrt_w.shape != (n, hmax,
                                                                                                       2 * m.nv):
            raise ValueError(f"score_candidates: references {ref_qpos.shape}, {ref_qvel.shape}, {sqrt_w.shape}; "
                             f"expected ({n}, {hmax}, {m.nq}), ({n}, {hmax}, {m.nv}), ({n}, {hmax}, {2 * m.nv})")
        return self._rollout_candidates(space, P, initial_state, control, horizon,
                                        (np.asarray(horizon), ref_qpos, ref_qvel, sqrt_w))

    def _rollout_candidates(self, space, P, initial_state, control, horizon, refs=None):
        """:meth:`rollout_candidates` (``refs`` None) or :meth:`score_candidates` (``refs`` its references)."""
        P = np.atleast_2d(P)
        if id(space) not in self._spaces_checked:
            check_space(space)
            self._spaces_checked.add(id(space))
        B, n = P.shape[0], len(horizon)
        nworld, hmax = B * n, int(control.shape[1])
        if not self.njmax:
            self.nconmax, self.njmax = choose_sizes(self.bound, measured_sizes(self.template, initial_state,
                                                                               control, horizon))
        with self._scope():  # the slot, its clip buffers and inputs, its captured step
            s = self._slot(nworld)
            self._buffers(s, n, hmax)
            self._upload_clips(s, initial_state, control)
            if refs is not None:
                self._upload_refs(s, *refs)
            self._graph(s)
        m, tm = self.host, self.timing
        t0 = time.perf_counter()
        # the same candidates of the same space on the same clip count as this slot's last call (the
        # planner's belief, cycle after cycle) are already in its worlds; the key holds the space itself,
        # so a later space cannot pass for it by reusing its id
        fkey = (P.shape, P.tobytes(), n)
        same = s.fieldkey is not None and s.fieldkey[0] is space and s.fieldkey[1] == fkey
        fields = None if same else candidate_fields(space, P, self.models(B), self._raise)
        t1 = time.perf_counter()
        with self._scope():  # enqueued under the lock; the wait below holds none
            if fields is not None:
                self._set_fields(s, fields, B)
                s.fieldkey = (space, fkey)
            t2 = time.perf_counter()
            self._launch(s, hmax)
        self._sync()
        t3 = time.perf_counter()
        if refs is None:
            qpos, qvel, flags = self._readback(s, nworld, hmax)
            qpos, qvel = qpos.reshape(B, n, hmax, m.nq), qvel.reshape(B, n, hmax, m.nv)
        else:
            acc, diverged, flags = self._readback_scores(s, nworld)
            acc, diverged = acc.reshape(B, n), diverged.reshape(B, n) != 0
        tm["fields"] += t1 - t0
        tm["upload"] += t2 - t1
        tm["steps"] += t3 - t2
        tm["readback"] += time.perf_counter() - t3
        tm["calls"] += 1
        bad = {name: int(np.count_nonzero(flags & bit)) for bit, name in OVERFLOW_BITS.items()}
        bad = {k: v for k, v in bad.items() if v}
        if bad:
            what = ", ".join(f"{k} in {v} of {nworld} worlds" for k, v in bad.items())
            if self._fixed:
                raise AmheError(f"--device cuda: MuJoCo Warp ran out of buffer space: {what} "
                                f"(nconmax {self.nconmax}, njmax {self.njmax}); use --device cpu")
            if (self.nconmax, self.njmax) == tuple(self.bound):
                # more than the scene's bound: only a rollout gone wild gets here; its states become NaN,
                # which the cost module charges as diverged, and the user is told
                lost = ((flags & sum(OVERFLOW_BITS)) != 0).reshape(B, n)
                if refs is None:
                    qpos[lost] = np.nan
                    qvel[lost] = np.nan
                else:
                    diverged |= lost
                print(f"amhe: warning: MuJoCo Warp buffers overflowed at the scene's bound ({what}): those "
                      "rollouts count as diverged", file=sys.stderr, flush=True)
                bad = {}
        if bad:
            self.nconmax, self.njmax = (min(self.bound[0], 2 * self.nconmax), min(self.bound[1], 2 * self.njmax))
            print(f"amhe: MuJoCo Warp buffers overflowed ({what}): growing to nconmax {self.nconmax}, "
                  f"njmax {self.njmax} and repeating the batch", file=sys.stderr, flush=True)
            self.close()  # every slot again, with the grown buffer sizes
            return self._rollout_candidates(space, P, initial_state, control, horizon, refs)
        if refs is not None:
            return acc, diverged, nworld * hmax
        _hold_past_horizon(qpos, qvel, horizon)
        return qpos, qvel, nworld * hmax

    def last_states(self, ncand: int, horizon: np.ndarray, hmax: int) -> tuple[np.ndarray, np.ndarray]:
        """The states of the last launch for ``ncand`` candidates × ``len(horizon)`` clips of ``hmax`` steps,
        (B, N_c, H, nq) and (B, N_c, H, nv), as :meth:`rollout_candidates` returns them: after a
        :meth:`score_candidates` call, the very rollouts it scored (a second launch can differ: the GPU's
        atomics order contacts otherwise)."""
        n = len(horizon)
        qpos, qvel, _ = self._readback(self._slots[world_capacity(ncand * n)], ncand * n, hmax)
        qpos, qvel = qpos.reshape(ncand, n, hmax, -1), qvel.reshape(ncand, n, hmax, -1)
        _hold_past_horizon(qpos, qvel, horizon)
        return qpos, qvel
