"""The recorded trajectory every subcommand works on (docs/reference.md#architecture).

A :class:`Trajectory` holds a log's signals on **one uniform time grid**, already
converted to MuJoCo conventions:

* quaternions are (w, x, y, z);
* free-body linear velocities are in the **world** frame, angular velocities in
  the **body** frame (the layout of a MuJoCo free joint's ``qvel``);
* joints are in the canonical Go1 order :data:`GO1_JOINTS` whatever order or
  names the log used;
* ``ctrl[i]`` is the joint position target that is active during the step from
  ``t[i]`` to ``t[i+1]`` (zero-order hold of the last command at or before
  ``t[i]``), and the state at index ``i`` is the state *before* that step.

Nothing downstream reads raw messages: log readers build a Trajectory, the cost
module slices clips out of it, the recorder of ``amhe run`` appends to one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Canonical Go1 joint order (FR, FL, RR, RL) x (hip, thigh, calf), the order of
#: the actuators in the bundled model.
GO1_JOINTS: tuple[str, ...] = tuple(
    f"{leg}_{part}_joint" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf")
)

#: Names of the per-sample arrays and their trailing shapes.
SIGNALS: dict[str, tuple[int, ...]] = {
    "base_pos": (3,),
    "base_quat": (4,),
    "base_linvel": (3,),
    "base_angvel": (3,),
    "joint_pos": (12,),
    "joint_vel": (12,),
    "box_pos": (3,),
    "box_quat": (4,),
    "box_linvel": (3,),
    "box_angvel": (3,),
    "ctrl": (12,),
}


@dataclass
class Trajectory:
    """A log resampled onto a uniform grid, in SI units and MuJoCo conventions.

    Attributes:
        t: (T,) sample times [s] from the log's first message, uniform spacing ``dt``.
        dt: grid spacing [s]; the model timestep or a multiple of it.
        base_pos: (T, 3) robot base (trunk) position in the world frame [m].
        base_quat: (T, 4) base orientation, (w, x, y, z), unit norm.
        base_linvel: (T, 3) base linear velocity in the **world** frame [m/s].
        base_angvel: (T, 3) base angular velocity in the **body** frame [rad/s].
        joint_pos: (T, 12) joint positions [rad], order :data:`GO1_JOINTS`.
        joint_vel: (T, 12) joint velocities [rad/s].
        box_pos: (T, 3) box centre position in the world frame [m].
        box_quat: (T, 4) box orientation (w, x, y, z).
        box_linvel: (T, 3) box linear velocity, world frame [m/s].
        box_angvel: (T, 3) box angular velocity, body frame [rad/s].
        ctrl: (T, 12) joint position targets [rad] held during step ``i``.
        kp: (12,) position gains [N·m/rad] if the log carries them, else None.
        kd: (12,) velocity gains [N·m·s/rad] if the log carries them, else None.
        joint_effort: (T, 12) measured joint torques [N·m] (``JointState.effort``,
            a LowState's ``tauEst``) where the log carries them, else None.
        observed: role name -> (T,) bool, True where that role had a message
            within the resampling tolerance (False inside drop-outs/gaps).
            Roles: ``joint_states``, ``base``, ``box``, ``joint_commands``.
        measured_velocity: role name -> bool, True where the velocity of that
            role came from the log, False where it was differentiated.
        meta: free-form provenance: ``path``, ``sha256``, ``topics`` (role ->
            topic), ``format``, ``metadata`` (MCAP metadata records), ``warnings``.
    """

    t: np.ndarray
    dt: float
    base_pos: np.ndarray
    base_quat: np.ndarray
    base_linvel: np.ndarray
    base_angvel: np.ndarray
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    box_pos: np.ndarray
    box_quat: np.ndarray
    box_linvel: np.ndarray
    box_angvel: np.ndarray
    ctrl: np.ndarray
    kp: np.ndarray | None = None
    kd: np.ndarray | None = None
    joint_effort: np.ndarray | None = None
    observed: dict[str, np.ndarray] = field(default_factory=dict)
    measured_velocity: dict[str, bool] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        n = self.t.shape[0]
        for name, tail in SIGNALS.items():
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (n, *tail):
                raise ValueError(f"Trajectory.{name} has shape {arr.shape}, expected {(n, *tail)}")
            setattr(self, name, arr)
        for name in ("kp", "kd"):
            val = getattr(self, name)
            if val is not None:
                val = np.asarray(val, dtype=float).reshape(-1)
                if val.shape != (12,):
                    raise ValueError(f"Trajectory.{name} has shape {val.shape}, expected (12,)")
                setattr(self, name, val)
        if self.joint_effort is not None:
            self.joint_effort = np.asarray(self.joint_effort, dtype=float)
            if self.joint_effort.shape != (n, 12):
                raise ValueError(f"Trajectory.joint_effort has shape {self.joint_effort.shape}, expected {(n, 12)}")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Time spanned by the grid [s]."""
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0

    def valid(self) -> np.ndarray:
        """(T,) bool: samples where every role was observed (no gap)."""
        ok = np.ones(len(self), dtype=bool)
        for mask in self.observed.values():
            ok &= np.asarray(mask, dtype=bool)
        return ok

    def slice(self, start: int, stop: int) -> "Trajectory":
        """Samples ``start:stop`` as a new Trajectory sharing ``meta``."""
        kw = {name: getattr(self, name)[start:stop] for name in SIGNALS}
        return Trajectory(
            t=self.t[start:stop], dt=self.dt, kp=self.kp, kd=self.kd,
            joint_effort=None if self.joint_effort is None else self.joint_effort[start:stop],
            observed={k: v[start:stop] for k, v in self.observed.items()},
            measured_velocity=dict(self.measured_velocity), meta=self.meta, **kw,
        )
