"""The simulated plant: the project's own MuJoCo world with chosen true parameters.

:class:`SimPlant` steps a scene whose parameters are the *truth* (never shown to
an estimator) under joint position targets held for a control period, and
records what a real robot's logs would hold as a :class:`Trajectory`. ``probe
--target sim`` drives it with a scripted manoeuvre (:meth:`SimPlant.step`);
``run --target sim`` with the planner, through the :class:`~amhe_cli.plants.base.Plant`
interface (:meth:`SimPlant.measure`, :meth:`SimPlant.execute`). The plant may use a
finer timestep than the recorded grid.

Timing is the sim plant's own business: in lock-step (the default) it waits
for the planner and runs ``cycle`` seconds of each plan; on the wall clock
(``realtime``) it runs on, for as long as each planner cycle took, with the
previous plan's later targets, as a real robot would.
"""

from __future__ import annotations

import mujoco
import numpy as np

from amhe_cli.io.plain import to_plain
from amhe_cli.model.params import ParameterSpace, PARAMETERS
from amhe_cli.model.scene import Scene, SceneConfig, servo_torque
from amhe_cli.plants.base import Measurement, Plant
from amhe_cli.io.trajectory import Trajectory


class SimPlant(Plant):
    """A MuJoCo plant with true parameters and a recorder.

    Args:
        config: scene geometry; ``timestep`` is the plant's step.
        truth: name -> true value for any of :data:`~amhe_cli.model.params.PARAMETERS`.
        record_dt: grid of the recorded trajectory [s] (a multiple of the plant step).
        control_period: how long each position target is held [s].
        events: task events (:class:`~amhe_cli.control.tasks.Event`) that
            :meth:`execute` fires on the plant when they are due.
        realtime: run on for each planner cycle's compute time (else lock-step).
        cycle: plant time per plan in lock-step [s].

    Attributes:
        scene, model, data: the plant's own scene, model (with the truth written) and state.
    """

    def __init__(self, config: SceneConfig | None = None, truth: dict | None = None,
                 record_dt: float = 0.002, control_period: float = 0.01, events=(), realtime: bool = False,
                 cycle: float = 0.02):
        self.config = config or SceneConfig()
        self.events = list(events)
        self.realtime = realtime
        self.cycle = cycle
        self._prev_plan: np.ndarray | None = None
        self._prev_used = 0
        self.scene = Scene(self.config)
        self.model = self.scene.model
        self.truth = dict(truth or {})
        self._apply_truth()
        self._truth_at_reset = dict(self.truth_values)
        self.data = mujoco.MjData(self.model)
        self.substeps = max(1, int(round(record_dt / self.model.opt.timestep)))
        self.record_dt = self.substeps * self.model.opt.timestep
        self.control_steps = max(1, int(round(control_period / self.record_dt)))
        self._log: dict[str, list] = {k: [] for k in ("t", "qpos", "qvel", "ctrl", "mass", "friction")}

    def reset(self, qpos: np.ndarray, qvel: np.ndarray | None = None) -> None:
        """Set the state and clear the recording."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = 0 if qvel is None else qvel
        mujoco.mj_forward(self.model, self.data)
        self._log = {k: [] for k in self._log}
        self._truth_at_reset = dict(self.truth_values)

    def step(self, target: np.ndarray) -> None:
        """Hold joint targets (12,) [rad] for one control period, recording each grid sample."""
        self.data.ctrl[:] = target
        for _ in range(self.control_steps):
            self._log["t"].append(self.data.time)
            self._log["qpos"].append(self.data.qpos.copy())
            self._log["qvel"].append(self.data.qvel.copy())
            self._log["ctrl"].append(self.data.ctrl.copy())
            self._log["mass"].append(self.truth_values["box_mass"])
            self._log["friction"].append(self.truth_values["box_friction"])
            mujoco.mj_step(self.model, self.data, nstep=self.substeps)

    def measure(self) -> Measurement:
        """The plant's exact state (no noise, no delay) at its current time."""
        return Measurement(t=float(self.data.time), qpos=self.data.qpos.copy(), qvel=self.data.qvel.copy())

    def execute(self, controls: np.ndarray, dt: float, compute_time: float, lead: float = 0.0) -> list:
        """Run a plan: in lock-step its first ``cycle`` seconds; on the wall clock, the previous
        plan's next rows for ``compute_time`` and then this plan's row for that moment.

        Args:
            controls: (H, 12) joint targets [rad], row k for ``lead + k·dt`` after the last
                measurement; each row is held for the plant's control period (= ``dt``).
            dt: row spacing [s].
            compute_time: the planner's wall time for this plan [s].
            lead: start of the plan after the measurement [s] (wall clock only).
        Returns:
            [(t [s], event)] of the task events fired meanwhile.
        """
        controls = np.asarray(controls)
        last = len(controls) - 1
        if self.realtime:
            lag = int(np.ceil(compute_time / dt))
            skip = int(round(lead / dt))  # rows of this plan before its row 0 is due
            prev = self._prev_plan
            rows = [prev[min(self._prev_used + i, len(prev) - 1)] for i in range(lag)] if prev is not None \
                else [controls[0]] * lag
            first = max(lag - skip, 0)
            rows += [controls[min(first, last)]]
            self._prev_used = first + 1
        else:
            rows = controls[:max(1, int(round(self.cycle / dt)))]
        self._prev_plan = controls
        fired = []
        for row in rows:
            self.step(row)
            fired += [(float(self.data.time), ev) for ev in self.fire_due(self.events)]
        return fired

    def fire_due(self, events: list, t: float | None = None) -> list:
        """Apply the task events of ``events`` that are due now (time or box x) to the plant.

        Args:
            events: pending :class:`~amhe_cli.control.tasks.Event` objects; the fired ones are removed.
            t: the task's time [s] the events' times count in (default: the plant's own time).
        Returns:
            the fired events, in order.
        """
        t = float(self.data.time) if t is None else float(t)
        box_x = float(self.data.qpos[self.scene.box_qpos[0]])
        fired = [ev for ev in events if ev.due(t, box_x)]
        for ev in fired:
            self.set_param(ev.param, ev.value)
            events.remove(ev)
        return fired

    def set_param(self, name: str, value) -> None:
        """Change a true parameter mid-run (a task event: mass switch, friction change)."""
        self.truth[name] = value
        self._apply_truth()

    def _apply_truth(self) -> None:
        """Write ``self.truth`` (the rest nominal) into the plant's model; refresh ``truth_values``."""
        space = ParameterSpace(self.scene, free=tuple(PARAMETERS), prior=self.truth)
        self.truth_values = space.values(space.mean0)
        space.write(self.model, space.mean0)

    def trajectory(self, last: float | None = None) -> Trajectory:
        """Everything recorded since :meth:`reset` (or its ``last`` seconds), as a :class:`Trajectory` on ``record_dt``.

        ``meta['truth']`` holds the true parameters at the reset, and
        ``meta['truth_series']`` ``{"t", "box_mass", "box_friction"}`` (T,) arrays
        of the truth at every sample, task events included.
        """
        s = self.scene
        k = 0 if last is None else max(0, len(self._log["t"]) - int(round(last / self.record_dt)))
        log = {key: v[k:] for key, v in self._log.items()}
        qpos = np.array(log["qpos"])
        qvel = np.array(log["qvel"])
        t = np.array(log["t"])
        n = len(t)
        return Trajectory(
            t=t, dt=self.record_dt,
            base_pos=qpos[:, s.base_qpos[:3]], base_quat=qpos[:, s.base_qpos[3:]],
            base_linvel=qvel[:, s.base_qvel[:3]], base_angvel=qvel[:, s.base_qvel[3:]],
            joint_pos=qpos[:, s.joint_qpos], joint_vel=qvel[:, s.joint_qvel],
            box_pos=qpos[:, s.box_qpos[:3]], box_quat=qpos[:, s.box_qpos[3:]],
            box_linvel=qvel[:, s.box_qvel[:3]], box_angvel=qvel[:, s.box_qvel[3:]],
            # the servo torque of each recorded step, as a real JointState.effort reports it (the sim's gains
            # do not change during a run)
            ctrl=np.array(log["ctrl"]),
            joint_effort=servo_torque(self.model, np.array(log["ctrl"]), qpos[:, s.joint_qpos], qvel[:, s.joint_qvel]),
            kp=self.model.actuator_gainprm[:, 0].copy(), kd=-self.model.actuator_biasprm[:, 2].copy(),
            observed={r: np.ones(n, dtype=bool) for r in ("joint_states", "base", "box", "joint_commands")},
            measured_velocity={"base": True, "joint_states": True, "box": True},
            meta={"source": "sim", "truth": to_plain(self._truth_at_reset),
                  "truth_series": {"t": t, "box_mass": np.array(log["mass"]),
                                   "box_friction": np.array(log["friction"])},
                  "scene": self.config.to_dict()},
        )

