"""The view: what the robot, the planner and the estimator think, as Foxglove messages.

One converter feeds two sinks that carry the same channels, schemas and bytes:
the live Foxglove WebSocket server (:mod:`amhe_cli.io.live`) and the MCAP a
``run`` or ``mhe-replay --mcap`` writes (:class:`ViewRecorder`). The messages
are Foxglove's standard schemas in their ROS 2 form (``foxglove_msgs/msg/…``,
schema encoding ``ros2msg``, message encoding ``cdr``), so Foxglove draws them
as it draws ``foxglove.SceneUpdate`` and friends, while the file stays a plain
ROS 2 MCAP that ``rosbags`` (and so ``amhe identify``) still reads: ``rosbags``
refuses any MCAP that holds a protobuf or JSON-schema channel.

=====================  =================================  ===========================================
topic                  type                               content
=====================  =================================  ===========================================
``/amhe/scene``        foxglove_msgs/msg/SceneUpdate      robot bodies from the MuJoCo model's own geoms
                                                          (box, sphere, capsule, cylinder; no meshes),
                                                          the box, the goal, floor regions with their μ
``/amhe/tf``           foxglove_msgs/msg/FrameTransforms  ``world`` -> each body frame
``/amhe/plan``         foxglove_msgs/msg/SceneUpdate      planner's mean plan: predicted trunk and box paths
``/amhe/planner``      std_msgs/msg/Float64MultiArray     ``rate_hz, compute_ms, lead_ms, forecast_tilt_deg``
                                                          (labelled; the last: the least, over the planner's
                                                          samples, of each one's largest trunk tilt over the
                                                          horizon [°], the fall reflex's forecast)
``/amhe/belief``       std_msgs/msg/Float64MultiArray     per parameter: value, σ, value ∓ σ, window, truth
``/amhe/safety``       std_msgs/msg/Float64MultiArray     Go1 safety state (``ok, hold, stand, damp, clamped``)
``/amhe/log``          foxglove_msgs/msg/Log              every warning, trip and watchdog, with its reason
=====================  =================================  ===========================================

Times are log times in ns; frames per REP-103 (``world`` z up); units SI.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from amhe_cli.io.quat import mj_to_ros, quat_rotate

__all__ = ["View", "ViewFrames", "ViewRecorder", "VIEW_TOPICS", "msgdef", "encoder", "Event", "belief_message"]

# -- the ROS 2 form of Foxglove's schemas ------------------------------------------------------------
#: Definitions of the ``foxglove_msgs`` types the view uses, field for field as Foxglove's schemas
#: (``foxglove.SceneUpdate`` … in the SDK); nested Foxglove geometry maps to geometry_msgs, times to
#: builtin_interfaces (as in the ``foxglove_msgs`` ROS 2 package). A test compares the field names
#: with the SDK's own schemas.
FOXGLOVE_MSGS = {
    "foxglove_msgs/msg/Color": "float64 r\nfloat64 g\nfloat64 b\nfloat64 a\n",
    "foxglove_msgs/msg/KeyValuePair": "string key\nstring value\n",
    "foxglove_msgs/msg/ArrowPrimitive": (
        "geometry_msgs/Pose pose\nfloat64 shaft_length\nfloat64 shaft_diameter\nfloat64 head_length\n"
        "float64 head_diameter\nfoxglove_msgs/Color color\n"),
    "foxglove_msgs/msg/CubePrimitive": "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfoxglove_msgs/Color color\n",
    "foxglove_msgs/msg/SpherePrimitive": "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfoxglove_msgs/Color color\n",
    "foxglove_msgs/msg/CylinderPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 size\nfloat64 bottom_scale\nfloat64 top_scale\n"
        "foxglove_msgs/Color color\n"),
    "foxglove_msgs/msg/LinePrimitive": (
        "uint8 LINE_STRIP=0\nuint8 LINE_LOOP=1\nuint8 LINE_LIST=2\n"
        "uint8 type\ngeometry_msgs/Pose pose\nfloat64 thickness\nbool scale_invariant\n"
        "geometry_msgs/Point[] points\nfoxglove_msgs/Color color\nfoxglove_msgs/Color[] colors\nuint32[] indices\n"),
    "foxglove_msgs/msg/TriangleListPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Point[] points\nfoxglove_msgs/Color color\n"
        "foxglove_msgs/Color[] colors\nuint32[] indices\n"),
    "foxglove_msgs/msg/TextPrimitive": (
        "geometry_msgs/Pose pose\nbool billboard\nfloat64 font_size\nbool scale_invariant\n"
        "foxglove_msgs/Color color\nstring text\n"),
    "foxglove_msgs/msg/ModelPrimitive": (
        "geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nfoxglove_msgs/Color color\nbool override_color\n"
        "string url\nstring media_type\nuint8[] data\n"),
    "foxglove_msgs/msg/SceneEntity": (
        "builtin_interfaces/Time timestamp\nstring frame_id\nstring id\nbuiltin_interfaces/Duration lifetime\n"
        "bool frame_locked\nfoxglove_msgs/KeyValuePair[] metadata\nfoxglove_msgs/ArrowPrimitive[] arrows\n"
        "foxglove_msgs/CubePrimitive[] cubes\nfoxglove_msgs/SpherePrimitive[] spheres\n"
        "foxglove_msgs/CylinderPrimitive[] cylinders\nfoxglove_msgs/LinePrimitive[] lines\n"
        "foxglove_msgs/TriangleListPrimitive[] triangles\nfoxglove_msgs/TextPrimitive[] texts\n"
        "foxglove_msgs/ModelPrimitive[] models\n"),
    "foxglove_msgs/msg/SceneEntityDeletion": (
        "uint8 MATCHING_ID=0\nuint8 ALL=1\nbuiltin_interfaces/Time timestamp\nuint8 type\nstring id\n"),
    "foxglove_msgs/msg/SceneUpdate": (
        "foxglove_msgs/SceneEntityDeletion[] deletions\nfoxglove_msgs/SceneEntity[] entities\n"),
    "foxglove_msgs/msg/FrameTransform": (
        "builtin_interfaces/Time timestamp\nstring parent_frame_id\nstring child_frame_id\n"
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"),
    "foxglove_msgs/msg/FrameTransforms": "foxglove_msgs/FrameTransform[] transforms\n",
    "foxglove_msgs/msg/Log": (
        "uint8 UNKNOWN=0\nuint8 DEBUG=1\nuint8 INFO=2\nuint8 WARNING=3\nuint8 ERROR=4\nuint8 FATAL=5\n"
        "builtin_interfaces/Time timestamp\nuint8 level\nstring message\nstring name\nstring file\nuint32 line\n"),
}

SCENE_UPDATE = "foxglove_msgs/msg/SceneUpdate"
FRAME_TRANSFORMS = "foxglove_msgs/msg/FrameTransforms"
LOG = "foxglove_msgs/msg/Log"
FLOAT_ARRAY = "std_msgs/msg/Float64MultiArray"

#: topic -> message type of every channel of the view.
VIEW_TOPICS = {
    "/amhe/scene": SCENE_UPDATE,
    "/amhe/tf": FRAME_TRANSFORMS,
    "/amhe/plan": SCENE_UPDATE,
    "/amhe/planner": FLOAT_ARRAY,
    "/amhe/belief": FLOAT_ARRAY,
    "/amhe/safety": FLOAT_ARRAY,
    "/amhe/log": LOG,
}
#: Foxglove Log levels.
LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}

_STORE = None
_STORE_LOCK = threading.Lock()
_MSGDEFS: dict[str, str] = {}
_ENCODERS: dict[str, Callable] = {}


def _store():
    """The ROS 2 Humble type store with the ``foxglove_msgs`` types above added (built once)."""
    global _STORE
    with _STORE_LOCK:
        if _STORE is None:
            from rosbags.typesys import Stores, get_types_from_msg, get_typestore
            store = get_typestore(Stores.ROS2_HUMBLE)
            types = {}
            for name, text in FOXGLOVE_MSGS.items():
                types.update(get_types_from_msg(text, name))
            store.register(types)
            _STORE = store
        return _STORE


def msgdef(msgtype: str) -> str:
    """The ``ros2msg`` schema text (the type and its dependencies, as MCAP's ros2 profile stores it).

    Args:
        msgtype: e.g. ``foxglove_msgs/msg/SceneUpdate`` or ``std_msgs/msg/Float64MultiArray``.

    Raises:
        KeyError: an unknown type.
    """
    if msgtype not in _MSGDEFS:
        text, _ = _store().generate_msgdef(msgtype, ros_version=2)
        _MSGDEFS[msgtype] = text
    return _MSGDEFS[msgtype]


def encoder(msgtype: str) -> Callable[[dict], bytes]:
    """A function message dict -> CDR bytes for ``msgtype`` (the same encoder the MCAP writer uses)."""
    if msgtype not in _ENCODERS:
        from mcap_ros2._dynamic import serialize_dynamic
        _ENCODERS[msgtype] = serialize_dynamic(msgtype, msgdef(msgtype))[msgtype]
    return _ENCODERS[msgtype]


# -- small message pieces ------------------------------------------------------------------------------
def _time(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}


def _vec(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _quat_wxyz(q) -> dict:
    """A MuJoCo (w, x, y, z) quaternion as a ROS (x, y, z, w) message (the one boundary conversion)."""
    x, y, z, w = mj_to_ros(np.asarray(q, dtype=float))
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


def _pose(pos, quat_wxyz=(1.0, 0.0, 0.0, 0.0)) -> dict:
    return {"position": _vec(pos), "orientation": _quat_wxyz(quat_wxyz)}


def _color(rgba) -> dict:
    return {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}


def _entity(ns: int, frame: str, ident: str, frame_locked: bool = True, **prims) -> dict:
    e = {"timestamp": _time(ns), "frame_id": frame, "id": ident, "lifetime": {"sec": 0, "nanosec": 0},
         "frame_locked": frame_locked, "metadata": []}
    for key in ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models"):
        e[key] = prims.get(key, [])
    return e


def _mu_color(mu: float) -> tuple:
    """Floor colour by box–floor μ: light (slippery, μ 0.2) to dark (grippy, μ 1.0)."""
    g = float(np.clip(0.85 - 0.6 * (mu - 0.2) / 0.8, 0.25, 0.85))
    return (g, g, min(1.0, g + 0.08), 1.0)


@dataclass
class Event:
    """One thing the view is told, as its hooks hand it over (cheap: arrays are the caller's copies).

    Attributes:
        kind: ``state`` (qpos), ``plan`` (trunk (H, 3), box (H, 3) paths [m], compute [s], lead [s]),
            ``belief`` (labels, values (K,)), ``safety`` (labels, values), ``log`` (level, text),
            ``goal`` ((x, y) [m]: the goal moved; no message of its own, the next scene shows it).
        t: log time [s].
        data: the kind's payload (see above).
        due: ``time.monotonic()`` before which a live server should not send it (paced playback).
    """

    kind: str
    t: float
    data: tuple
    due: float = 0.0


class ViewFrames:
    """Converts :class:`Event` s into the view's messages (see the module docstring).

    Args:
        model: the ``mujoco.MjModel`` whose bodies and geoms are drawn (the plant's or the log's scene);
            each body is a frame named after it; the world body's geoms (the floor) are not drawn.
        regions: (x_min, x_max, μ[, source]) per floor region [m] (None: unbounded), drawn as floor
            patches labelled with their box–floor μ and where it comes from (``truth``, ``model``).
        goal: (x, y) [m] of the box's goal, or None.
        t0: log time [s] added to every event's time (a log's start, 0 for a run).

    Not thread-safe: one thread converts (the live server's, or the recorder at the end).
    """

    def __init__(self, model, regions: Sequence[tuple] = (), goal: Sequence[float] | None = None, t0: float = 0.0):
        import mujoco
        self.mujoco = mujoco
        self.model = model
        self.data = mujoco.MjData(model)
        self.regions = list(regions)
        self.goal = None if goal is None else (float(goal[0]), float(goal[1]))
        self.t0 = float(t0)
        self.bodies = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in range(model.nbody)]

    def __getstate__(self) -> dict:
        """Pickled (for the live server's process) as its model and settings; the MjData is rebuilt."""
        return {"model": self.model, "regions": self.regions, "goal": self.goal, "t0": self.t0}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["model"], state["regions"], state["goal"], state["t0"])

    def ns(self, t: float) -> int:
        """Log time [ns] of event time ``t`` [s]."""
        return max(0, int(round((t + self.t0) * 1e9)))

    # -- the static scene -------------------------------------------------------------------------------
    def _geom_prims(self, g: int) -> dict:
        """Primitives of geom ``g`` in its body's frame (a capsule is a cylinder and two spheres)."""
        m = self.model
        gt = self.mujoco.mjtGeom
        typ, size = int(m.geom_type[g]), m.geom_size[g]
        pos, quat, rgba = m.geom_pos[g], m.geom_quat[g], m.geom_rgba[g]
        if typ == gt.mjGEOM_BOX:
            return {"cubes": [{"pose": _pose(pos, quat), "size": _vec(2 * size[:3]), "color": _color(rgba)}]}
        if typ == gt.mjGEOM_SPHERE:
            d = 2 * size[0]
            return {"spheres": [{"pose": _pose(pos, quat), "size": _vec((d, d, d)), "color": _color(rgba)}]}
        if typ in (gt.mjGEOM_CYLINDER, gt.mjGEOM_CAPSULE):
            r, half = size[0], size[1]
            out = {"cylinders": [{"pose": _pose(pos, quat), "size": _vec((2 * r, 2 * r, 2 * half)),
                                  "bottom_scale": 1.0, "top_scale": 1.0, "color": _color(rgba)}]}
            if typ == gt.mjGEOM_CAPSULE:
                ends = [pos + quat_rotate(quat, np.array([0.0, 0.0, s * half])) for s in (-1.0, 1.0)]
                out["spheres"] = [{"pose": _pose(e), "size": _vec((2 * r,) * 3), "color": _color(rgba)} for e in ends]
            return out
        return {}

    def scene(self, t: float) -> dict:
        """A SceneUpdate of everything that does not move by itself: each body's geoms (frame-locked to
        the body's frame), the floor regions with their μ, the goal."""
        m, ns = self.model, self.ns(t)
        by_body: dict[int, dict] = {}
        entities = []
        for k, (x0, x1, mu, *source) in enumerate(self.regions):
            lo = (-2.0 if x1 is None else min(-2.0, x1 - 4.0)) if x0 is None else x0
            hi = (max(lo, 0.0) + 6.0) if x1 is None else x1
            centre = ((lo + hi) / 2, 0.0, -0.001)
            entities.append(_entity(ns, "world", f"floor/{k}", cubes=[
                {"pose": _pose(centre), "size": _vec((hi - lo, 4.0, 0.002)), "color": _color(_mu_color(mu))}],
                texts=[{"pose": _pose((centre[0], -1.5, 0.01)), "billboard": True, "font_size": 14.0,
                        "scale_invariant": True, "color": _color((0.1, 0.1, 0.1, 1.0)),
                        "text": f"box–floor μ {mu:.2f}" + (f" ({source[0]})" if source else "")}]))
        for g in range(m.ngeom):
            if m.geom_bodyid[g] == 0:  # the floor and its contact regions: drawn above, with their μ
                continue
            if m.geom_rgba[g][3] <= 0:
                continue
            prims = self._geom_prims(g)
            slot = by_body.setdefault(int(m.geom_bodyid[g]), {})
            for key, vals in prims.items():
                slot.setdefault(key, []).extend(vals)
        for b, prims in sorted(by_body.items()):
            entities.append(_entity(ns, self.bodies[b], f"body/{self.bodies[b]}", **prims))
        if self.goal is not None:
            gx, gy = self.goal
            entities.append(_entity(ns, "world", "goal", cylinders=[
                {"pose": _pose((gx, gy, 0.005)), "size": _vec((0.4, 0.4, 0.01)), "bottom_scale": 1.0, "top_scale": 1.0,
                 "color": _color((0.1, 0.7, 0.2, 0.6))}],
                texts=[{"pose": _pose((gx, gy, 0.3)), "billboard": True, "font_size": 14.0, "scale_invariant": True,
                        "color": _color((0.1, 0.5, 0.1, 1.0)), "text": "goal"}]))
        return {"deletions": [], "entities": entities}

    # -- what moves -------------------------------------------------------------------------------------
    def transforms(self, t: float, qpos: np.ndarray) -> dict:
        """FrameTransforms ``world`` -> every body, from ``qpos`` (nq,) by forward kinematics."""
        d = self.data
        d.qpos[:] = qpos
        self.mujoco.mj_kinematics(self.model, d)
        ts = _time(self.ns(t))
        return {"transforms": [
            {"timestamp": ts, "parent_frame_id": "world", "child_frame_id": self.bodies[b],
             "translation": _vec(d.xpos[b]), "rotation": _quat_wxyz(d.xquat[b])}
            for b in range(1, self.model.nbody)]}

    def plan(self, t: float, trunk: np.ndarray, box: np.ndarray) -> dict:
        """SceneUpdate of the mean plan's predicted trunk (blue) and box (orange) paths, (H, 3) each [m]."""
        ns = self.ns(t)

        def line(points, rgba):
            return {"type": 0, "pose": _pose((0, 0, 0)), "thickness": 0.02, "scale_invariant": False,
                    "points": [_vec(p) for p in points], "color": _color(rgba), "colors": [], "indices": []}
        return {"deletions": [], "entities": [_entity(ns, "world", "plan", frame_locked=False, lines=[
            line(trunk, (0.1, 0.4, 0.9, 1.0)), line(box, (0.95, 0.5, 0.1, 1.0))])]}

    @staticmethod
    def array(labels: Sequence[str], values: Sequence[float]) -> dict:
        """A labelled Float64MultiArray (the project's convention: ``layout.dim[0].label`` = comma-joined labels)."""
        return {"layout": {"dim": [{"label": ",".join(labels), "size": len(labels), "stride": len(labels)}],
                           "data_offset": 0}, "data": [float(v) for v in values]}

    def log(self, t: float, level: str, text: str) -> dict:
        """A Foxglove Log message (``name`` amhe)."""
        return {"timestamp": _time(self.ns(t)), "level": LOG_LEVELS.get(level, 0), "message": str(text),
                "name": "amhe", "file": "", "line": 0}

    def convert(self, ev: Event) -> list[tuple[str, int, dict]]:
        """The messages of one event: [(topic, log time [ns], message dict)]."""
        ns = self.ns(ev.t)
        if ev.kind == "state":
            return [("/amhe/tf", ns, self.transforms(ev.t, ev.data[0]))]
        if ev.kind == "scene":
            return [("/amhe/scene", ns, self.scene(ev.t))]
        if ev.kind == "plan":
            trunk, box, compute, lead, rate, tilt = ev.data
            out = [("/amhe/planner", ns, self.array(["rate_hz", "compute_ms", "lead_ms", "forecast_tilt_deg"],
                                                    [rate, 1e3 * compute, 1e3 * lead, np.degrees(tilt)]))]
            if trunk is not None:
                out.append(("/amhe/plan", ns, self.plan(ev.t, trunk, box)))
            return out
        if ev.kind == "belief":
            return [("/amhe/belief", ns, self.array(*ev.data))]
        if ev.kind == "safety":
            return [("/amhe/safety", ns, self.array(*ev.data))]
        if ev.kind == "log":
            return [("/amhe/log", ns, self.log(ev.t, *ev.data))]
        if ev.kind == "goal":  # the goal moved (placed where the robot stands): the next scene shows it
            self.goal = (float(ev.data[0]), float(ev.data[1]))
            return []
        raise ValueError(f"unknown view event {ev.kind!r}")


#: What ``/amhe/belief`` says of each parameter, in order: the (fused) estimate, its σ, estimate ∓ σ
#: (the band a plot draws), the last window's own estimate, the truth (NaN where unknown).
BELIEF_FIELDS = ("", "_std", "_lo", "_hi", "_window", "_truth")
#: Parameters always first in ``/amhe/belief``, in this order, so one layout plots every command's belief
#: (mass at ``data[0]``…, friction at ``data[6]``…); other free parameters follow.
BELIEF_FIRST = ("box_mass", "box_friction")


def belief_order(labels: Sequence[str]) -> list[int]:
    """Indices into ``labels`` putting :data:`BELIEF_FIRST` first (those present), the rest after in order."""
    labels = list(labels)
    first = [labels.index(n) for n in BELIEF_FIRST if n in labels]
    return first + [i for i in range(len(labels)) if i not in first]


def belief_message(labels: Sequence[str], value, std, window=None, truth=None) -> tuple[list[str], list[float]]:
    """The ``/amhe/belief`` labels and values of parameters ``labels`` (K,), (see :data:`BELIEF_FIELDS`).

    Args:
        labels: (K,) parameter labels (``box_mass``, ``box_friction``, ``box_inertia_0`` …).
        value, std: (K,) estimate and σ in physical units (kg, -, kg·m²).
        window: (K,) the window's own estimate, or None (NaN).
        truth: (K,) the truth, or None (NaN; entries may be NaN).
    Returns:
        (6K labels, 6K values), :data:`BELIEF_FIRST` first.
    """
    value = np.asarray(value, dtype=float).ravel()
    nan = np.full(value.shape, np.nan)
    std = np.asarray(std, dtype=float).ravel()
    window = nan if window is None else np.asarray(window, dtype=float).ravel()
    truth = nan if truth is None else np.asarray(truth, dtype=float).ravel()
    cols = np.stack([value, std, value - std, value + std, window, truth], axis=1)
    order = belief_order(labels)
    return ([f"{labels[i]}{f}" for i in order for f in BELIEF_FIELDS], cols[order].ravel().tolist())


class View:
    """The hooks' one entry point: tell it what happens, it hands each sink an :class:`Event`.

    Every method costs the caller a small tuple and an array copy; sinks (a
    :class:`ViewRecorder`, a :class:`~amhe_cli.io.live.LiveServer`) take events
    through ``offer(event)``, which must never block. ``View()`` with no sinks
    does nothing, so hooks need no ``if``.

    Args:
        sinks: objects with ``offer(event: Event) -> None``.
        state_rate: most ``state`` events per second of event time handed on [Hz].
        plan_rate: most plan paths per second of event time handed on [Hz].
    """

    def __init__(self, sinks: Iterable[Any] = (), state_rate: float = 50.0, plan_rate: float = 25.0):
        self.sinks = [s for s in sinks if s is not None]
        self.min_dt = 1.0 / state_rate
        self.plan_dt = 1.0 / plan_rate
        self._last_state = -math.inf
        self._last_plan = -math.inf
        self._rate = _Rate()

    def __bool__(self) -> bool:
        return bool(self.sinks)

    def _emit(self, ev: Event) -> None:
        for s in self.sinks:
            s.offer(ev)

    def scene(self, t: float) -> None:
        """(Re)send the static scene (bodies, floor, goal)."""
        if self.sinks:
            self._emit(Event("scene", t, ()))

    def state(self, t: float, qpos: np.ndarray, due: float = 0.0, force: bool = False) -> None:
        """The robot and box where they are at ``t`` [s]: ``qpos`` (nq,) of the view's model."""
        if self.sinks and (force or t - self._last_state >= self.min_dt - 1e-9):
            self._last_state = t
            self._emit(Event("state", t, (np.array(qpos, dtype=float),), due))

    def plan(self, t: float, trunk: np.ndarray | None, box: np.ndarray | None, compute: float,
             lead: float = 0.0, forecast_tilt: float = 0.0) -> None:
        """A planner cycle at ``t`` [s]: its mean plan's predicted (H, 3) trunk and box paths [m] (None:
        not known), its compute time and lead [s], and its samples' least largest trunk tilt over the
        horizon [rad] (:attr:`~amhe_cli.control.planner.Plan.predicted_tilt`). The replanning rate is
        measured here over every call; the paths are handed on at most ``plan_rate`` times per second
        of event time."""
        if self.sinks:
            rate = self._rate.tick()
            if t - self._last_plan < self.plan_dt - 1e-9:
                trunk = box = None
            else:
                self._last_plan = t
            self._emit(Event("plan", t, (None if trunk is None else np.array(trunk, dtype=float),
                                         None if box is None else np.array(box, dtype=float), compute, lead, rate,
                                         float(forecast_tilt))))

    def belief(self, t: float, labels: Sequence[str], values: Sequence[float]) -> None:
        """The belief at ``t`` [s]: ``labels`` and ``values`` as :func:`belief_message` gives them."""
        if self.sinks:
            self._emit(Event("belief", t, (list(labels), list(values))))

    def safety(self, t: float, status: dict) -> None:
        """The safety layer's state at ``t`` [s]: name -> number (e.g. ``ok``, ``damp``, ``clamped``)."""
        if self.sinks:
            self._emit(Event("safety", t, (list(status), [float(v) for v in status.values()])))

    def log(self, t: float, text: str, level: str = "warning") -> None:
        """A message at ``t`` [s] (a warning, a trip or watchdog with its reason, a phase change)."""
        if self.sinks:
            self._emit(Event("log", t, (level, text)))


class _Rate:
    """Events per second over the last few intervals (wall clock)."""

    def __init__(self, n: int = 10):
        import collections
        import time
        self.clock = time.monotonic
        self.times = collections.deque(maxlen=n + 1)

    def tick(self) -> float:
        self.times.append(self.clock())
        if len(self.times) < 2:
            return float("nan")
        return (len(self.times) - 1) / max(self.times[-1] - self.times[0], 1e-9)


@dataclass
class ViewRecorder:
    """Keeps a view's events in memory and writes them into an MCAP at the end (same channels as live).

    Events are stored as handed over (no conversion on the control path); :meth:`write` converts
    them with a :class:`ViewFrames` and writes them through an :class:`~amhe_cli.io.writer.McapLog`.

    Attributes:
        events: the events received, in order.
    """

    events: list = field(default_factory=list)

    def offer(self, ev: Event) -> None:
        """Keep ``ev`` (never blocks)."""
        self.events.append(ev)

    def write(self, log, frames: ViewFrames) -> int:
        """Write every event's messages (and the static scene first) to ``log``; returns the message count."""
        n = 0
        t_first = min((ev.t for ev in self.events), default=0.0)
        for topic, ns, msg in frames.convert(Event("scene", t_first, ())):
            log.write_message(topic, VIEW_TOPICS[topic], ns, msg)
            n += 1
        for ev in sorted(self.events, key=lambda e: e.t):
            if ev.kind == "scene":
                continue
            for topic, ns, msg in frames.convert(ev):
                log.write_message(topic, VIEW_TOPICS[topic], ns, msg)
                n += 1
        return n
