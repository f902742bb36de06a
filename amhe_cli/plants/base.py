"""The one plant interface the closed loop drives (docs/reference.md#architecture, "Plant").

The planner and the MHE never know which plant they drive: the closed loop
(:func:`~amhe_cli.control.closed_loop.run_task`) only

1. :meth:`Plant.measure`\\ s the state (robot and box, time-stamped),
2. hands the plan's joint targets to :meth:`Plant.execute`,
3. reads :meth:`Plant.trajectory` (the recording) for the MHE and the log,
4. and :meth:`Plant.close`\\ s it, with a reason when something failed.

Implementations: :class:`~amhe_cli.plants.sim.SimPlant` (MuJoCo; lock-step or
on the wall clock) and :class:`~amhe_cli.plants.go1.plant.Go1Plant` (a real
Go1, or the emulator, over the low-level UDP link; always on the wall clock).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.trajectory import Trajectory
from amhe_cli.model.scene import Scene


class PlantFailure(AmheError):
    """The plant cannot go on (a safety trip, a lost link): the run ends, the robot damped."""


@dataclass
class Measurement:
    """The plant's measured state at one instant.

    Attributes:
        t: plant time [s] since the run's start (sim time, or wall time for a real robot).
        qpos: (nq,) positions in the plant scene's layout (robot base, joints, box).
        qvel: (nv,) velocities (free joints: world linear, body angular).
        ages: source -> age of its newest sample at ``t`` [s] (``joints``,
            ``base``, ``box``); all 0 for the sim.
        box_fresh: the box pose is fresh enough to push against.
    """

    t: float
    qpos: np.ndarray
    qvel: np.ndarray
    ages: dict = field(default_factory=dict)
    box_fresh: bool = True


class Plant(ABC):
    """What the closed loop drives.

    Attributes:
        scene: the scene whose ``qpos``/``qvel`` layout :meth:`measure` fills.
        record_dt: grid of :meth:`trajectory` [s].
        realtime: True when the plant runs on the wall clock (a real robot,
            always); False for a lock-step simulation that waits for the planner.
        truth_values: the true parameters now (name -> value), or None where
            nobody knows them (a real robot).
        armed: the plan's targets reach the motors. False for a robot's dry
            run (damping only: it lies down, so a "fall" ends nothing).
        concurrent_trajectory: :meth:`trajectory` may be called from another thread while the plant runs
            (it copies what it reads under a lock of its own): on the wall clock the online MHE then builds
            its data on its own thread, off the control loop. False (default) for a plant the loop steps.
    """

    scene: Scene
    record_dt: float
    realtime: bool
    truth_values: dict | None
    armed: bool = True
    concurrent_trajectory: bool = False

    @abstractmethod
    def measure(self) -> Measurement:
        """The state now. Raises :class:`PlantFailure` when the plant has failed."""

    @abstractmethod
    def execute(self, controls: np.ndarray, dt: float, compute_time: float, lead: float = 0.0) -> list:
        """Carry out a plan measured at the last :meth:`measure`.

        Args:
            controls: (H, 12) joint position targets [rad]; row k is meant for
                ``lead + k·dt`` after the measurement.
            dt: row spacing [s].
            compute_time: how long the planner took [s] (a wall-clock plant
                has already run on for that long).
            lead: how far after the measurement the plan starts [s] (the
                closed loop's latency compensation on the wall clock; 0 in lock-step).
        Returns:
            the task events that fired meanwhile (the sim's; a real plant has none).
        """

    @abstractmethod
    def trajectory(self, last: float | None = None) -> Trajectory:
        """The recording so far (or its ``last`` seconds) on the ``record_dt`` grid."""

    def joint_record(self, last: float) -> Trajectory:
        """The joints' last ``last`` seconds (states, targets, efforts) on the ``record_dt`` grid, as cheaply as
        the plant can give them: what a read of the robot's servo needs, mid-run, beside the planner
        (:func:`~amhe_cli.control.robot_side.read_robot`). Other streams may be left unprocessed (default:
        :meth:`trajectory`)."""
        return self.trajectory(last)

    def recording(self) -> Trajectory:
        """The whole recording as it should be logged (default: :meth:`trajectory`)."""
        return self.trajectory()

    def close(self, reason: str | None = None) -> None:
        """End the plant's run; ``reason`` says what failed (a real robot is damped either way)."""

    def take_messages(self) -> list[str]:
        """What the plant has to tell the user since the last call (watchdogs, stale sensors); none by default."""
        return []

    def extras(self) -> dict:
        """Raw streams to record beside the trajectory (e.g. ``imu``, ``foot_forces``); none by default."""
        return {}
