"""The robot the planner's and the MHE's model stand for: its servo, trunk payload and shell friction.

A run plans with the task's scene. Its box comes from the belief (or the truth); this module gives it the
robot's own side from the same source, so that a robot unlike the model (markers and a head plate on its
trunk, motors that deliver less than commanded) is planned for as it is:

* **servo**: the share of the commanded PD gains the robot's servo delivers. A belief from ``identify``
  holds the gains that acted (``scene.kp``/``kd``, fitted from the log's joint efforts where they disagree
  with the logged ones, :mod:`~amhe_cli.estimation.gains`), scaled by ``robot_kp``/``robot_kd`` where those
  were free, and the gains its log commanded (``provenance.sensors.gains.logged_kp``/``logged_kd``). Their
  ratio, joint by joint, times the run's own ``kp``/``kd``, is the model's servo. A log whose commanded
  gains are unknown says nothing about the share: the model keeps the run's gains.
* **trunk payload** [kg] and **robot–box friction** [-]: the belief's values (``identify`` fits the payload
  where the box rests, or frees it).
* **motor torque limits** [N·m]: the belief scene's ``torque_limit``, where ``identify`` read the log's joint
  efforts plateauing below the model's (:func:`~amhe_cli.estimation.gains.applied_limit`).

In ``true`` mode they come from the plant's truth (the sim's robot is its model unless a config's
``task: {truth: …}`` says otherwise). *Measured* (docs/evaluation.md, "A robot unlike its model"): an
emulated Go1 with 1.5 kg on its trunk, robot–box friction 0.8 and motors at 85 % (T1–T4, both modes, seeds
0–7) fell in 2 of 64 runs planned with the nominal robot and 1 of 64 with a belief ``identify`` read from a
recording of it; the online MHE, whose model is the planner's, held T1's box within 10 % in 0 of 8 runs
without that belief and 6 of 8 with it.

A run on the wall clock reads its robot while it runs (``RunSettings.robot_read``): every :data:`READ_EVERY`
seconds its own joint efforts against its commands give the servo and where the motors plateau
(:func:`read_robot`, as ``identify`` reads them), and where either is unlike what the planner models the
planner and the MHE take the robot as read (:func:`follow`, :func:`write_robot`); *measured* on the
emulated robot above: 0 falls in 66 runs reading it, 4 in 36 without (docs/evaluation.md, "The run reads
its robot"). What is still unlike at the end is said then (:func:`check_run`). ``amhe run --robot-belief``
takes the robot side from one belief and the box from another (``--belief``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from amhe_cli.estimation.belief import Belief
from amhe_cli.estimation.gains import applied_limit, fit_gains, spread
from amhe_cli.model.scene import set_pd_gains, set_torque_limit

#: Shares of the commanded gains outside this range are taken as a belief that does not describe this
#: servo (another controller's log, a fit gone wrong): the model keeps the run's gains and says so.
SERVO_SHARE = (0.3, 2.0)
#: A servo share, or a share of the model's torque limits, this far (fraction) from the planner's is a robot
#: unlike the one it modelled (:func:`check_run`): the fit reads an emulated Go1's Kp within 2 %.
CHECK_SHARE = 0.05


@dataclass(frozen=True)
class RobotSide:
    """The robot's own side of the planner's and the MHE's scene.

    Attributes:
        kp, kd: (12,) the PD gains [N·m/rad], [N·m·s/rad] the model's servo applies for the run's commanded ones.
        trunk_payload: mass on the trunk beyond the model's [kg].
        robot_box_friction: robot–box friction [-], or None for the scene's nominal.
        torque_limit: (12,) the motors' torque limits [N·m], or None for the model's.
        source: where it came from, one line for the run's log (empty: the nominal robot).
    """

    kp: tuple
    kd: tuple
    trunk_payload: float = 0.0
    robot_box_friction: float | None = None
    torque_limit: tuple | None = None
    source: str = ""


def robot_side(kp: float, kd: float, belief: Belief | None = None, truth: dict | None = None) -> RobotSide:
    """The robot side of a run's model for commanded gains ``kp``, ``kd`` (module doc).

    Args:
        kp, kd: the run's commanded PD gains (every joint).
        belief: the starting belief (``baseline``/``adaptive``), or None.
        truth: the plant's true parameters (``true`` mode), or None; taken over ``belief``.
    Returns:
        :class:`RobotSide`; the nominal robot (the run's gains, no payload) where neither says otherwise.
    """
    nominal = RobotSide((float(kp),) * 12, (float(kd),) * 12)
    if truth:
        share_kp = float(np.mean(truth.get("robot_kp", kp))) / kp
        share_kd = float(np.mean(truth.get("robot_kd", kd))) / kd
        out = RobotSide((kp * share_kp,) * 12, (kd * share_kd,) * 12, float(np.mean(truth.get("trunk_payload", 0.0))),
                        _scalar(truth.get("robot_box_friction")))
        differs = abs(share_kp - 1) > 1e-9 or abs(share_kd - 1) > 1e-9 or out.trunk_payload != 0.0
        return replace(out, source=_describe(out, share_kp, share_kd, "the truth") if differs else "")
    if belief is None:
        return nominal
    shares, note = _servo_shares(belief)
    payload = float(_scalar(belief.values.get("trunk_payload")) or 0.0)
    limit = belief.scene.get("torque_limit")
    if limit is not None:
        limit = tuple(float(x) for x in np.broadcast_to(np.asarray(limit, float), (12,)))
    out = RobotSide(tuple(float(x) for x in kp * shares[0]), tuple(float(x) for x in kd * shares[1]), payload,
                    _scalar(belief.values.get("robot_box_friction")), limit)
    differs = bool(np.any(np.abs(shares - 1) > 1e-6)) or payload != 0.0 or limit is not None
    text = _describe(out, float(np.mean(shares[0])), float(np.mean(shares[1])), "the belief") if differs else ""
    return replace(out, source="; ".join(t for t in (text, note) if t))


def _servo_shares(belief: Belief) -> tuple[np.ndarray, str]:
    """(2, 12) shares of the commanded Kp and Kd the belief's servo delivers, and a note where it gives none."""
    ones = np.ones((2, 12))
    scene_kp, scene_kd = belief.scene.get("kp"), belief.scene.get("kd")
    if scene_kp is None or scene_kd is None:
        return ones, ""
    acted = np.array([np.broadcast_to(np.asarray(scene_kp, float), (12,)),
                      np.broadcast_to(np.asarray(scene_kd, float), (12,))])
    for i, name in enumerate(("robot_kp", "robot_kd")):  # a free mean gain scales the joints' own
        if name in belief.free and belief.values.get(name) is not None:
            acted[i] = acted[i] * float(_scalar(belief.values[name])) / float(np.mean(acted[i]))
    gains = belief.provenance.get("sensors", {}).get("gains") or {}
    if gains:  # fitted from efforts: against what the log commanded
        logged = gains.get("logged_kp"), gains.get("logged_kd")
        if logged[0] is None or logged[1] is None:
            return ones, "the belief's log carried no commanded gains: its servo's share of them is unknown"
        commanded = np.array([np.broadcast_to(np.asarray(v, float), (12,)) for v in logged])
    else:  # the scene's gains are the ones its log commanded
        commanded = np.array([np.broadcast_to(np.asarray(v, float), (12,)) for v in (scene_kp, scene_kd)])
    with np.errstate(divide="ignore", invalid="ignore"):
        shares = acted / commanded
    if not np.all(np.isfinite(shares)) or np.any(shares < SERVO_SHARE[0]) or np.any(shares > SERVO_SHARE[1]):
        return ones, (f"the belief's servo delivers {np.nanmin(shares):.2f}–{np.nanmax(shares):.2f} of its "
                      f"commanded gains, outside {SERVO_SHARE[0]}–{SERVO_SHARE[1]}: modelled as commanded")
    return shares, ""


def _describe(side: RobotSide, share_kp: float, share_kd: float, where: str) -> str:
    return (f"the planner's robot from {where}: servo {share_kp:.2f} × Kp, {share_kd:.2f} × Kd of those commanded, "
            f"trunk payload {side.trunk_payload:+.2f} kg"
            + (f", robot–box friction {side.robot_box_friction:.2f}" if side.robot_box_friction is not None else "")
            + (f", motors' torque limits {spread(side.torque_limit)} N·m" if side.torque_limit is not None else ""))


def _scalar(v) -> float | None:
    if v is None:
        return None
    return float(np.mean(np.asarray(v, dtype=float)))


@dataclass(frozen=True)
class RobotRead:
    """What a recording's own joint efforts say of the robot's servo and motors (:func:`read_robot`).

    Attributes:
        servo: the share of the commanded Kp the servo delivered (median over the joints whose fit is well
            posed, :data:`READ_STD`).
        limit_share: the share of the model's torque limits where the efforts plateaued, 1.0 where they did
            not (:func:`~amhe_cli.estimation.gains.applied_limit`).
    """

    servo: float
    limit_share: float


#: A run on the wall clock reads its robot (:func:`read_robot`) from READ_FROM [s] on, every READ_EVERY [s],
#: over the recording's last READ_WINDOW [s] (``RunSettings.robot_read``): walking, not standing, shows the
#: servo, and windows that overlap hold the plateaus of a push.
READ_FROM, READ_EVERY, READ_WINDOW = 5.0, 5.0, 10.0
#: Samples a read mid-run fits the servo law on (:func:`~amhe_cli.estimation.gains.fit_gains`'s ``max_samples``):
#: a 10 s window thinned to these reads the emulated Go1's servo as the whole recording does, in a fraction of
#: the time, on a thread that shares the planner's cores.
READ_SAMPLES = 1500
#: A joint's fitted Kp counts towards the servo share only where its standard error is under this fraction of
#: it, and a read needs :data:`READ_JOINTS` such joints: a few seconds of standing, with joint errors of a
#: hundredth of a radian, give Kp to tens of percent and say nothing.
READ_STD, READ_JOINTS = 0.02, 4
#: A read's well-posed joints must agree on the servo share (interquartile range at most READ_SPREAD): one
#: servo law drives all twelve motors, so joints that disagree say the fit is off, not the robot. *Measured*
#: on emulated recordings read every second from 5 s on (as a run reads, thinned): the model's servo
#: 0.99–1.01, a servo at 0.85 0.854–0.861, the joints' interquartile range 0.002–0.03 in both. The
#: window an emulated T3 run read its servo (1.00) as 1.06 from, on a client loaded with the MHE's GPU
#: decisions, read again from its recording: 0.99, its joints 0.88–1.04, interquartile range 0.055 (0.085
#: on every sample, 0.97). Such first reads of the model's servo (0.86–0.95 or 1.05–1.06, in 10 of 75
#: emulated runs with GPU decisions) were followed by the planner and the MHE until the next read said
#: 1.00, and one gave T4's first floor to the box's mass.
READ_SPREAD = 0.04


def read_robot(traj, kp: float, model_limit, max_samples: int | None = None) -> RobotRead | None:
    """The servo share and the motors' limit share a recording's joint efforts show (module doc).

    Args:
        traj: a :class:`~amhe_cli.io.trajectory.Trajectory` with ``joint_effort`` (T, 12) [N·m] and ``ctrl``
            (T, 12) the commanded joint targets [rad].
        kp: the commanded Kp [N·m/rad] (every joint).
        model_limit: (12,) the model's motor torque limits [N·m].
        max_samples: fit on about this many samples (None: all; :data:`READ_SAMPLES` mid-run).
    Returns:
        :class:`RobotRead`, or None where the recording has no efforts, too few well-posed joints
        (:data:`READ_JOINTS`), or joints that disagree on the servo share (:data:`READ_SPREAD`).
    """
    fit = fit_gains(traj, max_samples)
    if fit is None:
        return None
    good = fit.ok & (fit.kp_std < READ_STD * np.abs(fit.kp))
    if good.sum() < READ_JOINTS:
        return None
    q1, q3 = np.percentile(fit.kp[good], [25, 75]) / kp
    if q3 - q1 > READ_SPREAD:
        return None
    model_limit = np.asarray(model_limit, dtype=float)
    limit, _ = applied_limit(fit, model_limit)
    share = 1.0 if limit is None else float(np.median(np.asarray(limit) / model_limit))
    return RobotRead(float(np.median(fit.kp[good])) / kp, share)


def _planned(side: RobotSide, kp: float, model_limit: np.ndarray) -> tuple[float, float]:
    """The servo share and the limit share ``side`` models."""
    limit = 1.0 if side.torque_limit is None else float(np.median(np.asarray(side.torque_limit) / model_limit))
    return float(np.mean(side.kp)) / kp, limit


def unlike(read: RobotRead, side: RobotSide, kp: float, model_limit) -> tuple[bool, bool]:
    """Whether ``read`` shows a servo, and motors, unlike ``side``'s by more than :data:`CHECK_SHARE`.

    Motors weaker than modelled only: efforts that never plateau cannot show a stronger one.
    """
    servo, limit = _planned(side, kp, np.asarray(model_limit, dtype=float))
    return abs(read.servo - servo) > CHECK_SHARE * servo, read.limit_share < (1 - CHECK_SHARE) * limit


def follow(side: RobotSide, read: RobotRead, kp: float, kd: float, model_limit) -> RobotSide | None:
    """The robot side a run's planner and MHE take on from a read of the robot mid-run, or None (as modelled).

    Where the servo differs (:func:`unlike`), both gains become the read share of the commanded ones: a motor
    that delivers less gives that share of the whole law ``Kp (q* − q) − Kd q̇`` (the least-squares Kd is
    biased low by the joint velocity's noise, :data:`~amhe_cli.estimation.gains.DISAGREE`, so it is not read
    on its own). Where the motors plateau lower, every limit becomes that share of the model's. The payload
    and the shell's friction stay ``side``'s (they need rollouts: ``identify``). A servo share outside
    :data:`SERVO_SHARE` is no Go1's and is not followed.

    Args:
        side: what the planner models now.
        read: :func:`read_robot` of the run so far.
        kp, kd: the run's commanded gains (every joint).
        model_limit: (12,) the model's motor torque limits [N·m].
    """
    model_limit = np.asarray(model_limit, dtype=float)
    if not SERVO_SHARE[0] <= read.servo <= SERVO_SHARE[1]:  # no Go1's servo: a fit gone wrong is not followed
        return None
    servo, motors = unlike(read, side, kp, model_limit)
    if not (servo or motors):
        return None
    out = side
    if servo:
        out = replace(out, kp=(kp * read.servo,) * 12, kd=(kd * read.servo,) * 12)
    if motors:
        out = replace(out, torque_limit=tuple(float(x) for x in read.limit_share * model_limit))
    now, limit = _planned(out, kp, model_limit)
    return replace(out, source=f"its own joint efforts read the servo at {now:.2f} × the commanded gains and the "
                               f"motors at {limit:.0%} of the model's torque limits")


def write_robot(model, side: RobotSide) -> None:
    """Write ``side``'s servo gains and torque limits into ``model`` (in place; limits only where it has some)."""
    set_pd_gains(model, side.kp, side.kd)
    if side.torque_limit is not None:
        set_torque_limit(model, side.torque_limit)


def check_run(traj, side: RobotSide, kp: float, model_limit) -> str | None:
    """One line where a run's own recording shows a robot unlike the one its planner modelled, else None.

    The recording's joint efforts against its commands (:func:`read_robot`, by
    :func:`~amhe_cli.estimation.gains.fit_gains`: the servo law ``τ = Kp (q* − q) − Kd q̇ + b`` with the
    commands' delay, and where the efforts plateau short of it) give the share of the commanded Kp the servo
    delivered and the share of the model's torque limits the motors reached
    (:func:`~amhe_cli.estimation.gains.applied_limit`). Either more than :data:`CHECK_SHARE` from the
    planner's (``side``, :func:`unlike`) is reported, with what reads the robot and gives it to the next run.
    The payload needs rollouts (``identify`` fits it) and is not checked here.

    Args:
        traj: the run's :class:`~amhe_cli.io.trajectory.Trajectory` (``joint_effort`` (T, 12) [N·m],
            ``ctrl`` (T, 12) the commanded joint targets [rad]).
        side: the :class:`RobotSide` the planner and the MHE modelled (at the run's end).
        kp: the run's commanded Kp [N·m/rad] (every joint).
        model_limit: (12,) the model's motor torque limits [N·m].
    Returns:
        the line, or None (no efforts, too few samples, or the robot as modelled).
    """
    model_limit = np.asarray(model_limit, dtype=float)
    read = read_robot(traj, kp, model_limit)
    if read is None:
        return None
    servo, motors = unlike(read, side, kp, model_limit)
    planned, planned_l = _planned(side, kp, model_limit)
    found = []
    if servo:
        found.append(f"its servo gave {read.servo:.2f} × the commanded Kp where the planner modelled {planned:.2f}")
    if motors:
        found.append(f"its motors plateaued at {read.limit_share:.0%} of the model's torque limits where the planner "
                     f"modelled {planned_l:.0%}")
    if not found:
        return None
    return (f"this robot is not the one the planner modelled ({'; '.join(found)}): `amhe identify` of this recording "
            "reads its servo, motors and payload, and `--belief` with that belief gives them to the next run's "
            "planner and MHE (docs/real_robot.md)")
