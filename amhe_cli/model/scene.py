"""The Go1 + box + floor scene, built from the bundled Go1 MJCF with ``mujoco.MjSpec``.

The scene is the one dynamics model ``f(x, u; p)`` of the paper (eq. 3) that
identification, estimation, planning and the sim plant all instantiate. Its
geometry (box size, floor height, friction regions) comes from a
:class:`SceneConfig`, which :func:`infer_scene_config` derives from a log so that a
log recorded in another world frame or with another box still lines up.

Contact design (docs/reference.md#mujoco): the box touches the floor **only** through one
explicit ``<pair>`` per floor region, so "box–floor friction" is exactly the
pair's sliding coefficient; the robot's feet keep their own friction (priority 1)
and robot–box contacts use the robot geoms' 0.6. Cones are elliptic.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.quat import quat_face_tilt
from amhe_cli.io.trajectory import GO1_JOINTS, Trajectory

#: Standing joint pose per leg (hip, thigh, calf) [rad], docs/reference.md#go1.
STAND_JOINTS = np.tile([0.0, 0.9, -1.8], 4)
FOOT_RADIUS = 0.023
#: A box tilted less than this from lying on a face counts as level when finding its floor [deg].
LEVEL_TILT_DEG = 2.0
FEET = ("FR_foot", "FL_foot", "RR_foot", "RL_foot")


def model_path(name: str = "go1.xml") -> str:
    """Filesystem path of a bundled MJCF: ``amhe_cli/models`` installed, the repository's ``models/`` in a checkout."""
    installed = Path(str(resources.files("amhe_cli"))) / "models" / name
    return str(installed if installed.exists() else Path(__file__).resolve().parents[2] / "models" / name)


@dataclass(frozen=True)
class FloorRegion:
    """A floor area with its own box–floor sliding friction.

    ``x_min``/``x_max`` [m] bound the region along world x (None = unbounded).
    """

    mu: float
    x_min: float | None = None
    x_max: float | None = None


@dataclass(frozen=True)
class SceneConfig:
    """Geometry and nominal physics of a scene.

    Attributes:
        box_size: full edge lengths (x, y, z) of the box [m].
        box_mass: nominal box mass [kg].
        box_inertia: principal moments [kg·m²]; None = uniform-density box.
        floor_height: z of the floor surface under the box in the world frame [m].
        robot_floor_height: z of the floor under the robot's feet [m]; None =
            ``floor_height``. Differs when the log's robot is not our model
            (other leg lengths): each floor is placed where the log says its
            bodies rest, so no recorded state starts inside the floor.
        regions: floor regions; one unbounded region = a uniform floor.
        timestep: model timestep [s].
        kp, kd: (12,) joint PD gains [N·m/rad], [N·m·s/rad]; None = model's 55/3.
        trunk_payload: mass [kg] added to the trunk at its centre of mass (its
            inertia about the CoM unchanged): what a log's robot carries beyond
            the model (:mod:`~amhe_cli.estimation.payload`).
        torque_limit: (12,) the motors' torque limits [N·m] (the position servos' force range,
            symmetric); None = the model's 23.7 / 23.7 / 35.55 per leg. Lower where a log's joint
            efforts plateau below them (weaker motors, a low battery: :mod:`~amhe_cli.estimation.gains`).
    """

    box_size: tuple[float, float, float] = (0.38, 0.38, 0.38)
    box_mass: float = 3.7
    box_inertia: tuple[float, float, float] | None = None
    floor_height: float = 0.0
    robot_floor_height: float | None = None
    regions: tuple[FloorRegion, ...] = (FloorRegion(mu=0.5),)
    timestep: float = 0.002
    kp: tuple[float, ...] | None = None
    kd: tuple[float, ...] | None = None
    trunk_payload: float = 0.0
    torque_limit: tuple[float, ...] | None = None

    @property
    def robot_floor(self) -> float:
        """z of the floor under the robot's feet [m] (``robot_floor_height``, else ``floor_height``)."""
        return self.floor_height if self.robot_floor_height is None else self.robot_floor_height

    def inertia(self, mass: float | None = None) -> np.ndarray:
        """(3,) principal moments [kg·m²]: explicit, or a uniform box of ``mass``."""
        m = self.box_mass if mass is None else mass
        if self.box_inertia is not None and mass is None:
            return np.asarray(self.box_inertia, dtype=float)
        return uniform_box_inertia(m, self.box_size)

    def to_dict(self) -> dict:
        return {
            "box_size": [float(x) for x in self.box_size],
            "box_mass": self.box_mass,
            "box_inertia": None if self.box_inertia is None else [float(x) for x in self.box_inertia],
            "floor_height": float(self.floor_height),
            "robot_floor_height": None if self.robot_floor_height is None else float(self.robot_floor_height),
            "regions": [{"mu": r.mu, "x_min": r.x_min, "x_max": r.x_max} for r in self.regions],
            "timestep": self.timestep,
            "kp": None if self.kp is None else [float(x) for x in self.kp],
            "kd": None if self.kd is None else [float(x) for x in self.kd],
            "trunk_payload": float(self.trunk_payload),
            "torque_limit": None if self.torque_limit is None else [float(x) for x in self.torque_limit],
        }

    @classmethod
    def from_dict(cls, d: dict) -> "SceneConfig":
        d = dict(d)
        d["regions"] = tuple(FloorRegion(**r) for r in d.get("regions", [{"mu": 0.5}]))
        for k in ("box_size", "box_inertia", "kp", "kd", "torque_limit"):
            if d.get(k) is not None:
                d[k] = tuple(float(x) for x in d[k])
        return cls(**d)


def uniform_box_inertia(mass: float, size) -> np.ndarray:
    """(3,) principal moments of a uniform box of ``mass`` [kg] and edges ``size`` [m]."""
    a, b, c = np.asarray(size, dtype=float)
    return mass / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


class Scene:
    """A compiled Go1 + box scene and the index bookkeeping around it.

    Attributes:
        config: the :class:`SceneConfig` it was built from.
        model: the compiled ``mujoco.MjModel`` (treat as a template: copy it
            before writing parameters).
        box_body: body id of the box.
        trunk_mass: the model's trunk mass [kg] without :attr:`SceneConfig.trunk_payload`.
        region_pairs: (n_regions,) ids of the box–floor ``<pair>`` per region.
        joint_qpos, joint_qvel: (12,) qpos/qvel addresses of the Go1 joints in
            :data:`GO1_JOINTS` order.
        base_qpos, box_qpos: (7,) qpos addresses of the free joints.
        base_qvel, box_qvel: (6,) qvel addresses of the free joints.
    """

    def __init__(self, config: SceneConfig | None = None):
        self.config = config or SceneConfig()
        self.model = _build(self.config)
        m = self.model
        self.box_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "box")
        # the model's own trunk [kg], without the config's payload: what a written trunk_payload adds to
        self.trunk_mass = float(m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "trunk")]) - \
            self.config.trunk_payload
        self._feet_kin = None  # (MjData, foot geom ids) for foot_centres, made on first use
        self._gap_kin = None  # (MjData, box geom, part -> geoms) for robot_box_gap, made on first use
        self.region_pairs = np.array(
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_PAIR, f"box_floor_{i}") for i in range(len(self.config.regions))]
        )
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in GO1_JOINTS]
        self.joint_qpos = np.array([m.jnt_qposadr[j] for j in jids])
        self.joint_qvel = np.array([m.jnt_dofadr[j] for j in jids])
        base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "floating_base")
        box = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "box")
        self.base_qpos = np.arange(m.jnt_qposadr[base], m.jnt_qposadr[base] + 7)
        self.box_qpos = np.arange(m.jnt_qposadr[box], m.jnt_qposadr[box] + 7)
        self.base_qvel = np.arange(m.jnt_dofadr[base], m.jnt_dofadr[base] + 6)
        self.box_qvel = np.arange(m.jnt_dofadr[box], m.jnt_dofadr[box] + 6)
        act_joint = [m.actuator_trnid[i, 0] for i in range(m.nu)]
        if act_joint != jids:
            raise RuntimeError("bundled model's actuators are not in GO1_JOINTS order")
        self.nstate = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self._state_template = np.empty(self.nstate)  # the default state, for full_state()
        mujoco.mj_getState(m, mujoco.MjData(m), self._state_template, mujoco.mjtState.mjSTATE_FULLPHYSICS)

    # -- state layout -------------------------------------------------------
    def qpos_qvel(self, traj: Trajectory, index=None) -> tuple[np.ndarray, np.ndarray]:
        """Scene-layout states of a trajectory, or of its samples ``index`` (an index array).

        Returns:
            qpos: (T, nq); qvel: (T, nv) in this model's layout (T = len(index) where given).
        """
        pick = (lambda a: a) if index is None else (lambda a: a[index])
        n = len(traj) if index is None else len(index)
        qpos = np.zeros((n, self.model.nq))
        qvel = np.zeros((n, self.model.nv))
        qpos[:, self.base_qpos[:3]] = pick(traj.base_pos)
        qpos[:, self.base_qpos[3:]] = pick(traj.base_quat)
        qpos[:, self.joint_qpos] = pick(traj.joint_pos)
        qpos[:, self.box_qpos[:3]] = pick(traj.box_pos)
        qpos[:, self.box_qpos[3:]] = pick(traj.box_quat)
        qvel[:, self.base_qvel[:3]] = pick(traj.base_linvel)
        qvel[:, self.base_qvel[3:]] = pick(traj.base_angvel)
        qvel[:, self.joint_qvel] = pick(traj.joint_vel)
        qvel[:, self.box_qvel[:3]] = pick(traj.box_linvel)
        qvel[:, self.box_qvel[3:]] = pick(traj.box_angvel)
        return qpos, qvel

    def full_state(self, qpos: np.ndarray, qvel: np.ndarray, time: np.ndarray | float = 0.0) -> np.ndarray:
        """Pack (N, nq) qpos and (N, nv) qvel into (N, nstate) mjSTATE_FULLPHYSICS vectors.

        Everything else in the state (act, mocap, userdata) is the model default.
        """
        qpos = np.atleast_2d(qpos)
        qvel = np.atleast_2d(qvel)
        m = self.model
        out = np.tile(self._state_template, (qpos.shape[0], 1))
        out[:, 0] = time
        out[:, 1:1 + m.nq] = qpos
        out[:, 1 + m.nq:1 + m.nq + m.nv] = qvel
        return out

    def standing_state(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0,
                       box_xy=(0.6, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """(nq,), (nv,) of the robot standing at (x, y, yaw) and the box resting at ``box_xy``."""
        m = self.model
        qpos = m.qpos0.copy()
        qpos[self.joint_qpos] = STAND_JOINTS
        qpos[self.base_qpos[:3]] = [x, y, self.config.robot_floor + 0.288]
        qpos[self.base_qpos[3:]] = [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
        qpos[self.box_qpos[:3]] = [box_xy[0], box_xy[1], self.config.floor_height + self.config.box_size[2] / 2]
        qpos[self.box_qpos[3:]] = [1, 0, 0, 0]
        return qpos, np.zeros(m.nv)

    def foot_centres(self, qpos: np.ndarray) -> np.ndarray:
        """(N, 4, 3) world positions of the foot-sphere centres [m] (:data:`FEET` order) for (N, nq) states."""
        m = self.model
        if self._feet_kin is None:  # asked once per state of a recording (fall forensics): one MjData, kept
            self._feet_kin = (mujoco.MjData(m), [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f) for f in FEET])
        d, gids = self._feet_kin
        qpos = np.atleast_2d(qpos)
        out = np.empty((len(qpos), 4, 3))
        for i, q in enumerate(qpos):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            out[i] = d.geom_xpos[gids]
        return out

    def robot_box_gap(self, qpos: np.ndarray, distmax: float = 0.5, part: str = "robot") -> np.ndarray:
        """(N,) smallest distance [m] between the robot's geoms that can touch the box and the box, for (N, nq)
        states (negative: penetrating; ``distmax`` where farther), over ``part``'s geoms: ``"robot"`` (all),
        ``"trunk"`` (the trunk body's own) or ``"legs"`` (all the others). ``mujoco.mj_geomDistance`` after
        ``mj_kinematics``, over the robot's collision geoms whose contype/conaffinity meet the box's: about
        70 µs a state on one core.

        Raises:
            ValueError: an unknown ``part``.
        """
        m = self.model
        if self._gap_kin is None:
            box = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "box")
            trunk = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "trunk")
            robot = [g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] == m.body_rootid[trunk]
                     and (m.geom_contype[g] & m.geom_conaffinity[box] or m.geom_conaffinity[g] & m.geom_contype[box])]
            parts = {"robot": robot, "trunk": [g for g in robot if m.geom_bodyid[g] == trunk],
                     "legs": [g for g in robot if m.geom_bodyid[g] != trunk]}
            self._gap_kin = (mujoco.MjData(m), box, parts)
        d, box, parts = self._gap_kin
        if part not in parts:
            raise ValueError(f"part {part!r}: expected one of {sorted(parts)}")
        geoms = parts[part]
        qpos = np.atleast_2d(qpos)
        out = np.empty(len(qpos))
        for i, q in enumerate(qpos):
            d.qpos[:] = q
            mujoco.mj_kinematics(m, d)
            out[i] = min(mujoco.mj_geomDistance(m, d, g, box, distmax, None) for g in geoms)
        return out

    def foot_bottoms(self, qpos: np.ndarray) -> np.ndarray:
        """(N, 4) z of the lowest point of each foot sphere [m] for (N, nq) states."""
        return self.foot_centres(qpos)[..., 2] - FOOT_RADIUS


def resting_offsets(scene: "Scene") -> tuple[float, float]:
    """How deep our model's bodies rest in the floor [m] (negative = below the surface).

    Simulates 1.5 s of the Go1 standing (PD targets at the stand pose) with the
    box resting far from it and returns (mean foot-sphere bottom, box bottom)
    relative to their floors. Soft contacts let a standing Go1 sink ~2 cm and
    the box ~0.1 mm; a log recorded in the same physics shows the same depths,
    so floors inferred from it must add them back.
    """
    m = scene.model
    d = mujoco.MjData(m)
    qpos, _ = scene.standing_state(box_xy=(5.0, 0.0))
    d.qpos[:] = qpos
    d.ctrl[:] = STAND_JOINTS
    mujoco.mj_step(m, d, nstep=int(1.5 / m.opt.timestep))
    cfg = scene.config
    feet = float(np.mean(scene.foot_bottoms(d.qpos[None])[0]) - cfg.robot_floor)
    box = float(d.qpos[scene.box_qpos[2]] - cfg.box_size[2] / 2 - cfg.floor_height)
    return feet, box


#: The bundled model's joint PD gains (models/go1.xml) [N·m/rad], [N·m·s/rad].
DEFAULT_KP = 55.0
DEFAULT_KD = 3.0


def servo_torque(model: mujoco.MjModel, ctrl: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Joint torques (…, nu) [N·m] the position servos apply for targets ``ctrl`` at joint state ``q``, ``dq``.

    ``clip(kp (ctrl − q) − kd dq, forcerange)`` — what MuJoCo's position actuator
    computes during the step that starts at that state; all arrays (…, nu) in
    actuator order.
    """
    kp = model.actuator_gainprm[:, 0]
    tau = kp * np.asarray(ctrl) + model.actuator_biasprm[:, 1] * np.asarray(q) + model.actuator_biasprm[:, 2] * np.asarray(dq)
    lo, hi = model.actuator_forcerange[:, 0], model.actuator_forcerange[:, 1]
    limited = model.actuator_forcelimited.astype(bool)
    return np.where(limited, np.clip(tau, lo, hi), tau)


def set_pd_gains(model: mujoco.MjModel, kp, kd) -> None:
    """Write joint PD gains into the position actuators of ``model`` (in place).

    ``kp`` [N·m/rad] and ``kd`` [N·m·s/rad] are scalars or (nu,) arrays; a
    MuJoCo position servo computes ``kp (ctrl - q) - kd dq``.
    """
    kp = np.broadcast_to(np.asarray(kp, dtype=float), (model.nu,))
    kd = np.broadcast_to(np.asarray(kd, dtype=float), (model.nu,))
    model.actuator_gainprm[:, 0] = kp
    model.actuator_biasprm[:, 1] = -kp
    model.actuator_biasprm[:, 2] = -kd


def torque_limit(model: mujoco.MjModel) -> np.ndarray:
    """(nu,) the motors' torque limits [N·m] of ``model``'s position servos (the upper end of each force range), a copy."""
    return model.actuator_forcerange[:, 1].copy()


def set_torque_limit(model: mujoco.MjModel, limit) -> None:
    """Write the motors' torque limits [N·m] (scalar or (nu,), positive) into the position servos' force range
    of ``model`` (in place).

    Raises:
        AmheError: a limit that is not positive.
    """
    limit = np.broadcast_to(np.asarray(limit, dtype=float), (model.nu,))
    if not np.all(limit > 0):
        raise AmheError(f"torque limits {list(limit)}: expected positive N·m for every joint")
    model.actuator_forcerange[:] = np.column_stack([-limit, limit])
    model.actuator_forcelimited[:] = 1


def _build(cfg: SceneConfig) -> mujoco.MjModel:
    if len(cfg.regions) == 0:
        raise AmheError("scene needs at least one floor region")
    if any(s <= 0 for s in cfg.box_size) or cfg.box_mass <= 0:
        raise AmheError(f"box size {cfg.box_size} and mass {cfg.box_mass} must be positive")
    spec = mujoco.MjSpec.from_file(model_path("go1.xml"))
    spec.option.timestep = cfg.timestep
    world = spec.worldbody
    # The robot's floor: an infinite plane at floor_height, colliding with the robot only.
    world.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05],
                   pos=[0, 0, cfg.robot_floor],
                   contype=1, conaffinity=2, friction=[1.0, 0.005, 0.0001],
                   rgba=[0.8, 0.8, 0.8, 1])
    # Box-floor regions: geoms that collide with nothing dynamically; contacts come from pairs only.
    for i, r in enumerate(cfg.regions):
        name = f"floor_region_{i}"
        if r.x_min is None and r.x_max is None:
            world.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05],
                           pos=[0, 0, cfg.floor_height], contype=0, conaffinity=0, group=3)
        else:
            lo = -50.0 if r.x_min is None else r.x_min
            hi = 50.0 if r.x_max is None else r.x_max
            world.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=[(hi - lo) / 2, 50.0, 0.05],
                           pos=[(hi + lo) / 2, 0, cfg.floor_height - 0.05], contype=0, conaffinity=0, group=3)
    half = [s / 2 for s in cfg.box_size]
    box = world.add_body(name="box", pos=[0.6, 0, cfg.floor_height + half[2]])
    box.add_freejoint(name="box")
    box.mass = cfg.box_mass
    box.inertia = list(cfg.inertia())
    box.ipos = [0.0, 0.0, 0.0]
    box.iquat = [1.0, 0.0, 0.0, 0.0]
    box.explicitinertial = True
# friction 0, priority 0: robot-box contacts take the robot geom's friction (max rule, 0.6) and
    # foot-box contacts the foot's (priority 1: μ 0.8, soft solimp), as in the public Go1 world;
    # giving the box its own priority made foot-box contacts stiff and moved the mass by +10 %
    box.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=half, contype=4, conaffinity=2,
                 condim=3, friction=[0, 0, 0], rgba=[0.8, 0.5, 0.2, 1])
    for i, r in enumerate(cfg.regions):
        spec.add_pair(name=f"box_floor_{i}", geomname1="box", geomname2=f"floor_region_{i}",
                      condim=3, friction=[r.mu, r.mu, 0.005, 0.0001, 0.0001])
    if cfg.trunk_payload:
        trunk = spec.body("trunk")
        if not trunk.mass + cfg.trunk_payload > 0:
            raise AmheError(f"trunk payload {cfg.trunk_payload:+.3f} kg leaves the trunk without mass")
        trunk.mass = trunk.mass + cfg.trunk_payload
    model = spec.compile()
    if cfg.kp is not None or cfg.kd is not None:
        set_pd_gains(model, cfg.kp if cfg.kp is not None else DEFAULT_KP, cfg.kd if cfg.kd is not None else DEFAULT_KD)
    if cfg.torque_limit is not None:
        set_torque_limit(model, cfg.torque_limit)
    return model


def infer_scene_config(traj: Trajectory, base: SceneConfig | None = None,
                       box_size: tuple[float, float, float] | None = None) -> SceneConfig:
    """A :class:`SceneConfig` whose geometry matches a recorded log.

    * robot floor: median over the log of the lowest foot-sphere bottom, by
      forward kinematics of the recorded base pose and joint angles through
      *our* Go1 model (so a log robot with other leg lengths still stands on it);
    * box floor: the box's median resting z (at rest and lying on a face, within
      :data:`LEVEL_TILT_DEG`) minus half its height, with the box
      size from ``box_size`` (x, y, z edges [m]) or else ``base.box_size``;
      when no size was given and that floor misses the robot's by more than
      1 cm, the default size is wrong for this log: the box is taken as a cube
      whose height puts it on the robot's floor (with a warning);
    * PD gains: the log's ``kp``/``kd`` where it carries them;
    * timestep: the trajectory's grid spacing.

    Raises:
        AmheError: the box would rest below the robot's floor by more than its
            own height (frames or size inconsistent).
    """
    cfg = base or SceneConfig()
    size = tuple(float(s) for s in (box_size or cfg.box_size))
    scene = Scene(replace(cfg, box_size=size, regions=(FloorRegion(mu=0.5),), robot_floor_height=None,
                          floor_height=0.0))
    qpos, _ = scene.qpos_qvel(traj)
    idx = np.linspace(0, len(traj) - 1, min(len(traj), 400)).astype(int)
    # soft foot contacts (solimp 0.015/1/0.031) let a standing Go1 sink ~2 cm into the floor:
    # the recorded feet sit that deep too, so subtract our model's own resting sinkage
    fk_floor = float(np.median(scene.foot_bottoms(qpos[idx]).min(axis=1)))
    feet_depth, box_depth = resting_offsets(scene)
    robot_floor = fk_floor - feet_depth
    speed = np.linalg.norm(traj.box_linvel[:, :2], axis=1)
    rest = speed <= max(0.01, np.percentile(speed, 30))
    # a box leaning on the robot (pushed high on a rough floor) rests higher: keep samples on a face
    level = quat_face_tilt(traj.box_quat) < np.radians(LEVEL_TILT_DEG)
    if np.count_nonzero(rest & level) >= 10:
        rest &= level
    elif np.count_nonzero(level) >= 10:
        rest = level
    rest_z = float(np.median(traj.box_pos[rest, 2]))
    box_floor = rest_z - size[2] / 2 - box_depth
    if box_size is None and abs(box_floor - robot_floor) > 0.01:
        edge = 2.0 * (rest_z - robot_floor - box_depth)
        if edge > 0.02:
            warnings.warn(f"the box rests {rest_z - robot_floor:.3f} m above the robot's floor, which does not fit the "
                          f"default {size[2]:.2f} m box: taking a {edge:.3f} m cube (give --box-size if it is not a cube)",
                          stacklevel=2)
            size = (edge,) * 3
            box_floor = robot_floor
    if abs(box_floor - robot_floor) > size[2] / 2:
        raise AmheError(f"box rests {box_floor - robot_floor:+.3f} m from the robot's floor: expected a box of height "
                        f"{size[2]:.3f} m on the floor the robot stands on (check --box-size and the log's frames)")
    if abs(box_floor - robot_floor) < 0.01:
        robot_floor = box_floor  # one physical floor; the gap is within the sinkage estimate
    return replace(
        cfg, box_size=size, floor_height=box_floor, robot_floor_height=robot_floor, timestep=float(traj.dt),
        kp=None if traj.kp is None else tuple(traj.kp), kd=None if traj.kd is None else tuple(traj.kd),
    )
