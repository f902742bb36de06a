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

A run that was planned for one robot and recorded another says so at its end (:func:`check_run`): its own
joint efforts against its commands give the servo and where the motors plateau, as ``identify`` reads them.
``amhe run --robot-belief`` takes the robot side from one belief and the box from another (``--belief``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from amhe_cli.estimation.belief import Belief
from amhe_cli.estimation.gains import applied_limit, fit_gains, spread

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


def check_run(traj, side: RobotSide, kp: float, model_limit) -> str | None:
    """One line where a run's own recording shows a robot unlike the one its planner modelled, else None.

    The recording's joint efforts against its commands (:func:`~amhe_cli.estimation.gains.fit_gains`: the
    servo law ``τ = Kp (q* − q) − Kd q̇ + b`` with the commands' delay, and where the efforts plateau short of
    it) give the share of the commanded Kp the servo delivered and the share of the model's torque limits the
    motors reached (:func:`~amhe_cli.estimation.gains.applied_limit`). Either more than :data:`CHECK_SHARE`
    from the planner's (``side``) is reported, with what reads the robot and gives it to the next run. Motors
    weaker than the planner's only: efforts that never plateau cannot show a stronger one. The payload needs
    rollouts (``identify`` fits it) and is not checked here.

    Args:
        traj: the run's :class:`~amhe_cli.io.trajectory.Trajectory` (``joint_effort`` (T, 12) [N·m],
            ``ctrl`` (T, 12) the commanded joint targets [rad]).
        side: the :class:`RobotSide` the planner and the MHE modelled.
        kp: the run's commanded Kp [N·m/rad] (every joint).
        model_limit: (12,) the model's motor torque limits [N·m].
    Returns:
        the line, or None (no efforts, too few samples, or the robot as modelled).
    """
    fit = fit_gains(traj)
    if fit is None or not fit.ok.any():
        return None
    model_limit = np.asarray(model_limit, dtype=float)
    found = []
    read, planned = float(np.median(fit.kp[fit.ok])) / kp, float(np.mean(side.kp)) / kp
    if abs(read - planned) > CHECK_SHARE * planned:
        found.append(f"its servo gave {read:.2f} × the commanded Kp where the planner modelled {planned:.2f}")
    limit, _ = applied_limit(fit, model_limit)
    read_l = 1.0 if limit is None else float(np.median(np.asarray(limit) / model_limit))
    planned_l = 1.0 if side.torque_limit is None else float(np.median(np.asarray(side.torque_limit) / model_limit))
    if read_l < (1 - CHECK_SHARE) * planned_l:
        found.append(f"its motors plateaued at {read_l:.0%} of the model's torque limits where the planner "
                     f"modelled {planned_l:.0%}")
    if not found:
        return None
    return (f"this robot is not the one the planner modelled ({'; '.join(found)}): `amhe identify` of this recording "
            "reads its servo, motors and payload, and `--belief` with that belief gives them to the next run's "
            "planner and MHE (docs/real_robot.md)")
