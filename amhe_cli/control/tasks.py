"""The loco-manipulation tasks T1–T5 (paper §V-A; docs/tasks.md) and their costs.

A :class:`Task` says where the box starts and must go, which gait the robot
uses, which events change the *plant* mid-run (T3's mass switch, T4's floor
friction), and how a planner scores a rollout:

* **box**: distance of the box to its target (T1/T3/T4/T5: the goal; T2: a
  point a little ahead on the circle);
* **waypoint**: distance of the base to the robot waypoint ``R_i`` — on the
  pushing side of the box, behind it along the push direction (T1–T4), or the
  robot's own stance position (T5). A robot that lost the box (walked past it,
  slid off its side) is sent back behind it first (:meth:`Task.command`'s
  approach phase), where the paper's cost alone would keep it walking on;
* **heading**: yaw misalignment with the push direction, bent back toward the
  push line when the robot is off it (walking tasks);
* **speed**: squared error of the forward base speed to the commanded speed
  (0.2 m/s, slowing to ``slow_floor`` of it over the last ``slow_radius`` to the goal; 0 for T5);
  **lateral**: squared error of the sideways base speed to the commanded one (the push's step back
  toward its line; 0 otherwise);
* **posture**: base height and tilt; **effort**: joint targets away from the
  gait reference; **fall**: a large cost once the base drops below
  ``fall_height``.

Weights live in :class:`CostWeights` (YAML-configurable through
``amhe run --config``). Defaults were chosen by running T1 in the sim plant
(``benchmarks/tune_run.py``, 2 seeds per variant): strong speed and lateral-speed
terms (40) were the variant that reached the goal with the least velocity
error (RMSE 0.04 m/s); heavier posture terms or lighter speed terms fell more often.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from amhe_cli.errors import AmheError, check_names
from amhe_cli.control.gait import GAITS, HIP_POS, LEGS, Gait
from amhe_cli.control.maneuver import HIP_OFFSET
from amhe_cli.io.quat import quat_to_yaw
from amhe_cli.model.scene import FOOT_RADIUS

#: Forward reach of the head plate from the trunk origin [m] (the pushing surface).
HEAD_REACH = 0.28
#: Largest yaw rate the task commands [rad/s]: the calibrated trot turns as asked up to 0.45
#: (benchmarks/gait_calibration.py) and twists out of its stride at 0.6.
MAX_YAW_RATE = 0.45
#: Push phase: the robot's origin lies between these distances [m] behind the box's rear face
#: (0: it walked past the face; 0.5 m more than the pushing pose: it fell far back).
PUSH_ZONE = (0.0, 0.5)
#: Push phase: largest offset of the robot's origin from the push line beyond the box's half width [m]
#: (0.25: the head plate still overlaps the box; pushing a corner is still pushing).
LINE_TOLERANCE = 0.25
#: Push phase: the zone's hysteresis [m]. Coming from the approach, the robot enters the push only this far
#: inside the zone's front, side and back edges; once pushing, it leaves at the edges themselves. Without it an
#: emulated T4 run (machine L, Adaptive seed 0) stood beside a turned box's rear corner, 0.36–0.46 m off the push
#: line, and lost and regained the box 10 times in 7 s across the zone's front edge: each push walked it forward
#: out of the zone, each approach back into it (docs/evaluation.md, "Losing the box").
PHASE_HYSTERESIS = 0.1
#: Push phase: heading bend back toward the push line per metre of offset [rad/m], and its limit [rad].
LINE_GAIN, MAX_LINE_BEND = 1.5, 0.35
#: Push phase: the robot steps sideways toward the push line at this speed per metre of offset [1/s], at most
#: :data:`MAX_SIDEWAYS` [m/s] (a gait with a sidestep: ``Gait.sideways_gain``). Steering alone did not hold the
#: line: the head's reaction yawed the trunk away, an off-centre push turned the box, and T3's planner that knew
#: the box lost it two or more times in 7 of 12 lock-step runs with a 25 ms plan, at the goal in 34.5 s (mean);
#: with this sidestep 1 of 12, 18.0 s (docs/evaluation.md, "A sidestep holds the push line").
SIDE_GAIN, MAX_SIDEWAYS = 1.0, 0.1
#: Approach phase: the pre-push point lies this much behind the pushing pose (and this much more
#: to the side when going around the box) [m].
APPROACH_MARGIN = 0.15
#: Approach phase: the trunk's centre keeps this far from the box's centre [m] (``weights.keep_out``): the box's
#: half diagonal (0.27 for the 0.38 m cube), the trunk's half width with its legs (0.15) and 0.1 m of margin.
KEEP_OUT = 0.52
#: Approach phase: heading error [rad] above which the robot turns on the spot.
TURN_IN_PLACE = 0.6
#: Approach phase: the trunk's origin turns on the spot only this far from the box [m] (from the box's
#: surface, in the floor plane): the Go1's feet stand 0.23 m from its origin and its thighs and knees sweep a
#: little more. Nearer, it first steps along its heading away from the box (:data:`CLEAR_SPEED`). Two emulated
#: falls (T3, machines of stops 50 and 51) turned on the spot 0.22–0.24 m from the box's face after losing it:
#: a leg met the box and the trunk rolled or pitched past 25° (docs/fall_prevention.md, "Turning beside the
#: box"). Turning on the spot keeps the trunk's origin where it is, so a turn begun this far stays this far.
TURN_CLEARANCE = 0.30
#: Approach phase: a step clear of the box (:data:`TURN_CLEARANCE`) goes on until the trunk's origin is this much
#: further out [m] before the robot turns. Without it the command flipped between stepping and turning as the
#: trot's sway and the poses' noise carried the measured clearance across 0.30 m: in an emulated T3 run (stop
#: 71, seed 7, a box turned 57° near the goal) the step clear began 32 times in 23 s, 8 of them within 0.2 s of
#: the last, at 0.297–0.303 m, and the robot worked round the box for 22 s before it fell.
CLEAR_HYSTERESIS = 0.05
#: Approach phase: speed [m/s] of the step away from a box nearer than :data:`TURN_CLEARANCE`, along the
#: heading (backward where the box is ahead).
CLEAR_SPEED = 0.15
#: Push phase: the box's footprint point nearest the trunk's origin this far off its heading [rad] (60°) is
#: beside the robot, not ahead of its head. More than :data:`TURN_IN_PLACE` off the push heading, such a
#: robot turns on the spot (stepping clear first, as in the approach) instead of walking while it turns:
#: an emulated T3 run (machine L) "pushed" 5 s with the box 62–85° off its heading, its turn blocked by the
#: box at its side, until a hind leg caught the box's corner and it pitched over. Stood-up T2 runs have the
#: box this far off in under 5 % of their push samples, where a rule on the heading alone took 40–61 %
#: and cost T2 its time (docs/fall_prevention.md, "Turning beside the box").
BESIDE = np.radians(60.0)
#: Nominal base height of the standing Go1 over its floor [m] (after sinkage).
BASE_HEIGHT = 0.265
#: One-leg push (T5): the free foot's centre this far below the trunk origin [m] (about 7 cm above the
#: floor). A low foot reaches further across under the abduction limit (the sweep's start), a higher one
#: further out before the calf's limit stretches the leg (its end; 0.384 m, not thigh + calf 0.426). 0.22 or
#: 0.18 throughout, or 0.22 -> 0.17 over the sweep, left the box 18-20 cm from its goal where 0.20 left it
#: 15 cm (4 seeds, 8 s, true mode).
REACH_DEPTH = 0.20
#: One-leg push: the foot meets the box's face at most this far in from the face's end nearest the robot [m].
REACH_INSET = 0.05
#: One-leg push: the longest hip-to-foot distance the reach asks of the leg [m]. Beyond the 0.384 m it
#: can stretch, so the contact sits nearer the face's centre and turns the box less; 0.38 and 0.42 left
#: the box 2 cm further from its goal (4 seeds, 8 s, true mode).
REACH_LEG = 0.40
#: One-leg push: the foot's reference presses this far into the face [m] (the PD servo's push), and
#: keeps this clearance from it before contact [m].
REACH_PRESS, REACH_CLEARANCE = 0.02, 0.03
#: One-leg push: the reach's phases end at these times [s]: to beside the box's face behind its near
#: end (clear of the box), then along the face to the contact point; the push follows.
REACH_TIMES = (0.6, 1.2)


@dataclass
class CostWeights:
    """Weights of the task cost terms (dimensionless multipliers of squared SI errors)."""

    box: float = 5.0
    #: waypoint 20 / heading 20 (were 5 / 2, where 5° of heading error cost less than 0.05 m/s of speed
    #: error): pushing a box off-centre yaws the robot away from it, and at the old weights the planner let
    #: it drift; T4 true mode, 15 seeds: 13/15 → 15/15, e_g 0.094 → 0.054 m
    waypoint: float = 20.0
    heading: float = 20.0
    speed: float = 40.0
    lateral: float = 40.0
    height: float = 200.0
    tilt: float = 50.0
    #: pushed at height h, a box tips once μ·h exceeds half its depth (T4's μ 0.8 floor: h > 0.24 m, below
    #: the head) and jams against the robot; with this term T4 true mode went from 6/8 to 8/8 seeds
    box_tilt: float = 300.0
    #: one-leg push (T5) only: the box's yaw away from its yaw at the cycle start. A push off the face's
    #: centre turns the box, and a box turned by 40° slid off the foot and stopped (T5 true, seed 0)
    box_yaw: float = 50.0
    #: one-leg push (T5) only, in place of ``waypoint``: the trunk's distance from its stance over the three
    #: planted feet. At the walking tasks' 20 the planner leaned the trunk 8 cm toward the box, out of the
    #: feet's triangle, and the pushing foot went down to bear weight and dragged on the floor
    stance: float = 200.0
    #: approach phase only: the trunk inside :data:`KEEP_OUT` of the box's centre, per m² of intrusion. The
    #: recorded falls happened walking around the box (docs/fall_prevention.md), but 500 did not lower them:
    #: T2 true, seeds 0-15, 30 s, 5 falls and S_R 11/16 with it, as without the reflex; so off by default
    keep_out: float = 0.0
    angvel: float = 0.5
    effort: float = 0.2
    fall: float = 1000.0
    terminal: float = 5.0  #: extra multiple of the box term at the horizon's end

    @classmethod
    def from_dict(cls, d: dict) -> "CostWeights":
        check_names(d, {f.name for f in fields(cls)}, "cost weight")
        return cls(**{k: float(v) for k, v in d.items()})


@dataclass(frozen=True)
class Event:
    """A change of the plant's true parameters: at time ``t`` [s] or once the box centre passes ``box_x`` [m]."""

    param: str
    value: float
    t: float | None = None
    box_x: float | None = None

    def due(self, t: float, box_x: float) -> bool:
        return (self.t is not None and t >= self.t) or (self.box_x is not None and box_x >= self.box_x)


@dataclass
class Task:
    """One task: start, goal or path, gait, plant truth and events.

    Attributes:
        name: ``t1`` … ``t5``.
        box_start: (x, y) [m] of the box centre; the robot starts at the origin facing +x.
        goal: (x, y) [m] the box must reach (T2: the end of the circle arc).
        circle: T2's (centre x, centre y, radius [m], arc [rad]) or None.
        gait: gait name (:data:`~amhe_cli.control.gait.GAITS`).
        speed: commanded robot speed [m/s].
        box_speed: speed of the box's reference toward its target [m/s] (T5: the pushing leg's job).
        truth: plant parameters at the start (name -> value).
        events: plant events.
        duration: time limit [s].
        goal_tol: the run ends once the box is this close to the goal [m].
        success_radius: final goal error counted as success [m].
        slow_radius: the commanded speeds (robot and box) fall linearly over this last distance [m] ...
        slow_floor: ... to this fraction of ``speed`` / ``box_speed`` at ``goal_tol``, where the run ends.
            The push is force-limited: on T4's μ 0.8 floor a 4 kg box moved at 3–8 mm/s under a
            0.02–0.09 m/s command, so a slow-down to 0 made it creep its last 0.15 m for 30 s (T4
            baseline seed 1); three of the 15-seed T4 grid's four falls came 0.07–0.10 m from the goal
            during such waits (docs/fall_prevention.md#waiting-at-the-goal).
        push_side: T5's lateral push direction (+1 left, −1 right); 0 otherwise.
        robot_pose: where the robot starts, (x [m], y [m], yaw [rad]): the
            one-leg push keeps the trunk there (over its three planted feet).
        weights: :class:`CostWeights`.
        fall_height: base height over the robot's floor under which the robot counts as fallen [m].
        fall_tilt: trunk tilt beyond which it counts as fallen [rad] (35°: no recorded run tilted further
            and came back; the Go1 safety layer damps at 40°).
        heading_rate: the rate [rad/s] at which the planner's heading reference turns toward the
            commanded heading in the approach phase (:meth:`heading_reference`); 0: the commanded
            heading itself, fixed.

    Raises:
        AmheError: ``slow_floor`` outside [0, 1], ``heading_rate`` negative.
    """

    name: str
    box_start: tuple
    goal: tuple
    circle: tuple | None = None
    gait: str = "trot"
    speed: float = 0.2
    box_speed: float = 0.2
    truth: dict = field(default_factory=lambda: {"box_mass": 4.0, "box_friction": 0.5})
    events: tuple = ()
    duration: float = 40.0
    goal_tol: float = 0.05
    success_radius: float = 0.2
    slow_radius: float = 0.3
    slow_floor: float = 0.5
    push_side: int = 0
    robot_pose: tuple = (0.0, 0.0, 0.0)
    weights: CostWeights = field(default_factory=CostWeights)
    fall_height: float = 0.15
    fall_tilt: float = 0.6
    #: base height under which a rollout is penalised as falling [m]
    unsafe_height: float = 0.19
    heading_rate: float = 0.0

    def __post_init__(self):
        if not 0.0 <= self.slow_floor <= 1.0:
            raise AmheError(f"task slow_floor {self.slow_floor}: expected a fraction of the speed in [0, 1]")
        if isinstance(self.heading_rate, bool) or not isinstance(self.heading_rate, (int, float)) or self.heading_rate < 0:
            raise AmheError(f"task heading_rate {self.heading_rate}: expected a yaw rate >= 0 [rad/s] (0: a fixed heading)")

    @property
    def gait_spec(self) -> Gait:
        return GAITS[self.gait]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["events"] = [asdict(e) for e in self.events]
        return d

    def placed(self, robot_xy, robot_yaw: float, box_xy, goal=None) -> "Task":
        """The task moved into a world where the robot and the box already stand (a real lab).

        The task's own frame has the robot at the origin facing +x; here the
        box start maps onto the measured box ``box_xy`` and the frame turns by
        the robot's yaw, so the goal (and T2's circle) keep their place
        *relative to the box and the robot's heading*. ``goal`` (x, y) [m], if
        given, is the goal in the world instead. Plant events (a simulated
        mass switch or floor change) are dropped: the real world has its own.

        Args:
            robot_xy: (2,) measured trunk position [m] (where the one-leg push keeps it).
            robot_yaw: measured trunk yaw [rad].
            box_xy: (2,) measured box centre [m].
            goal: optional (2,) goal in the world [m].
        """
        c, s_ = np.cos(robot_yaw), np.sin(robot_yaw)
        rot = np.array([[c, -s_], [s_, c]])
        start = np.asarray(self.box_start, dtype=float)
        box = np.asarray(box_xy, dtype=float)[:2]

        def move(p):
            return tuple(float(x) for x in box + rot @ (np.asarray(p, dtype=float) - start))
        circle = None
        if self.circle is not None:
            cx, cy, r, arc = self.circle
            circle = (*move((cx, cy)), r, arc)
        new_goal = tuple(float(x) for x in goal) if goal is not None else move(self.goal)
        return replace(self, box_start=tuple(float(x) for x in box), goal=new_goal, circle=circle, events=(),
                       robot_pose=(*(float(x) for x in np.asarray(robot_xy, dtype=float)[:2]), float(robot_yaw)))

    # -- targets -------------------------------------------------------------
    def box_target(self, box_xy: np.ndarray) -> np.ndarray:
        """(2,) where the box should head now: the goal, or (T2) a point 0.3 m ahead on the circle."""
        if self.circle is None:
            return np.asarray(self.goal, dtype=float)
        cx, cy, r, arc = self.circle
        ang = np.arctan2(box_xy[1] - cy, box_xy[0] - cx)
        start = np.arctan2(self.box_start[1] - cy, self.box_start[0] - cx)
        sweep = np.mod(ang - start, 2 * np.pi) if arc > 0 else -np.mod(start - ang, 2 * np.pi)
        ahead = np.clip(sweep + np.sign(arc) * 0.3 / r, min(0, arc), max(0, arc)) + start
        return np.array([cx + r * np.cos(ahead), cy + r * np.sin(ahead)])

    def goal_error(self, box_xy: np.ndarray) -> float:
        """e_g [m]: distance of the box centre to the goal."""
        return float(np.linalg.norm(np.asarray(box_xy)[:2] - np.asarray(self.goal)))

    def command(self, base_xy: np.ndarray, base_yaw: float, box_xy: np.ndarray, half_depth: float,
                half_width: float | None = None, t: float = 0.0, box_yaw: float = 0.0,
                phase: str | None = None, clearing: bool = False) -> dict:
        """Per-cycle targets for the planner's cost and the gait.

        Walking tasks have two phases, chosen from where the robot stands in the
        push frame (``d`` from the box to its target):

        * **push**: the robot is behind the box (its origin between
          :data:`PUSH_ZONE` behind the box's rear extent along ``d``, its footprint
          turned by ``box_yaw``) and within ``half_width +`` :data:`LINE_TOLERANCE`
          of the push line; coming from the approach (``phase``) it must be
          :data:`PHASE_HYSTERESIS` inside those edges. The waypoint is the pushing
          pose on that line; the heading is ``d``, bent back toward the line by
          :data:`LINE_GAIN` per metre of offset, and a gait with a sidestep steps
          back across toward it (``sideways``, :data:`SIDE_GAIN` per metre of
          offset up to :data:`MAX_SIDEWAYS`: steering alone let an off-centre push
          turn the box away). Where
          the box is beside the robot rather than ahead of its head (its nearest
          point more than :data:`BESIDE` off the heading) and the heading is more
          than :data:`TURN_IN_PLACE` off, it turns on the spot instead (``beside``
          True; stepping clear first as below) with the box's reference held still.
        * **approach**: otherwise (it slid off the box, walked past it, or fell
          back). The robot walks to a pre-push point :data:`APPROACH_MARGIN`
          behind the pushing pose — around the box's side first if the box is in
          the way — turning on the spot while the heading error exceeds
          :data:`TURN_IN_PLACE`; the box's reference holds still. Nearer the box
          than :data:`TURN_CLEARANCE` it does not turn but steps along its heading
          away from the box first (``clearing``; the box's footprint taken as
          ``half_depth`` × ``half_width`` along its own axes, turned by ``box_yaw``).

        The one-leg push (``push_side``, T5) keeps the robot where it stands and
        gives the free leg a **reach** (:meth:`reach`): to beside the box's face,
        along it to the contact point, then sweeping with the face along the push.

        Args:
            base_xy, base_yaw: the robot's current planar pose [m], [rad].
            box_xy: the box centre [m].
            half_depth: half the box's extent along the push [m].
            half_width: half its extent across the push [m] (default: ``half_depth``).
            t: time since the task started [s] (the one-leg push's reach phases).
            box_yaw: the box's yaw [rad] (the push zone's front edge; the one-leg push: which face the foot meets).
            phase: the phase this returned last cycle (``"push"``, ``"approach"``), for the zone's
                hysteresis; None (a first cycle, or a stateless caller): the zone's own edges.
            clearing: whether this returned ``clearing`` last cycle: an approach's step clear of the box goes on
                to :data:`TURN_CLEARANCE` + :data:`CLEAR_HYSTERESIS` before the robot turns.
        Returns:
            dict with ``target`` (2,) box target, ``direction`` (2,) unit push
            direction, ``waypoint`` (2,) robot waypoint, ``yaw`` desired heading
            [rad], ``speed`` commanded speed [m/s], ``omega`` yaw-rate command
            for the gait [rad/s], ``sideways`` (push phase) the sideways speed
            toward the push line for the gait [m/s, + left], ``box`` (2,) the box now, ``box_speed`` [m/s]
            of its reference, ``phase`` ``"push"`` (with ``beside`` True while it turns to face the push) or ``"approach"``
            (``clearing`` True while it steps away from the box before turning), ``base`` (2,) the
            trunk now (where :meth:`waypoint_reference` starts), ``base_yaw`` its heading now [rad]
            (where :meth:`heading_reference` starts); the one-leg
            push adds ``reach`` (see :meth:`reach`) and ``box_yaw`` (the box's yaw now, [rad]).
        """
        half_width = half_depth if half_width is None else half_width
        base_xy, box_xy = np.asarray(base_xy, float), np.asarray(box_xy, float)
        target = self.box_target(box_xy)
        to_goal = self.goal_error(box_xy) if self.circle is None else np.inf
        slow = float(np.clip((to_goal - self.goal_tol) / self.slow_radius, 0.0, 1.0))
        slow = self.slow_floor + (1.0 - self.slow_floor) * slow
        box_speed = self.box_speed * slow
        out = {"target": target, "box": box_xy.copy(), "box_speed": box_speed, "phase": "push", "base": base_xy.copy(),
               "base_yaw": float(base_yaw)}
        if self.push_side:  # T5: robot stays; box goes sideways
            d = np.subtract(self.goal, self.box_start)
            d = d / max(float(np.linalg.norm(d)), 1e-9)  # along the push, fixed in the world
            x0, y0, yaw0 = self.robot_pose
            c, s_ = np.cos(yaw0), np.sin(yaw0)
            bx, by = self.gait_spec.body_shift  # the trunk's stance over the three planted feet
            stance = np.array([x0 + c * bx - s_ * by, y0 + s_ * bx + c * by])
            reach = self.reach(t, base_xy, base_yaw, box_xy, box_yaw, d, half_depth, half_width, box_speed)
            return {**out, "direction": d, "waypoint": stance, "yaw": float(yaw0), "speed": 0.0, "omega": 0.0,
                    "box_yaw": float(box_yaw), "reach": reach}
        delta = target - box_xy
        dist = float(np.linalg.norm(delta))
        d = delta / dist if dist > 1e-6 else np.array([np.cos(base_yaw), np.sin(base_yaw)])
        normal = np.array([-d[1], d[0]])  # left of the push direction
        rel = base_xy - box_xy
        along, lateral = float(rel @ d), float(rel @ normal)
        reach = half_depth + HEAD_REACH
        push_yaw = float(np.arctan2(d[1], d[0]))
        # the box's rear extent along the push, its footprint turned: a robot beside a turned box's corner
        # is not behind it
        rear = box_half_extent(d, box_yaw, half_depth, half_width)
        inset = PHASE_HYSTERESIS if phase == "approach" else 0.0
        behind = -(reach + PUSH_ZONE[1]) + inset <= along <= -(rear + PUSH_ZONE[0]) - inset
        if behind and abs(lateral) <= half_width + LINE_TOLERANCE - inset:
            yaw = push_yaw - float(np.clip(LINE_GAIN * lateral, -MAX_LINE_BEND, MAX_LINE_BEND))
            out = {**out, "direction": d, "waypoint": box_xy - d * reach, "yaw": yaw}
            near_point = box_nearest(base_xy, box_xy, box_yaw, half_depth, half_width) - base_xy
            bearing = _yaw_error(float(np.arctan2(near_point[1], near_point[0])), base_yaw)
            if abs(_yaw_error(yaw, base_yaw)) > TURN_IN_PLACE and abs(bearing) > BESIDE:
                # the box is beside the robot, not ahead of its head: turn to face the push first
                # (no step-clear hysteresis here: a longer step beside the box left the push zone, and the push and
                # the approach took turns, 5 times in 10 s in a lock-step T3 run)
                return self._turn_on_the_spot({**out, "box_speed": 0.0, "beside": True}, base_xy, base_yaw,
                                              box_xy, box_yaw, half_depth, half_width)
            side = float(np.clip(-SIDE_GAIN * lateral, -MAX_SIDEWAYS, MAX_SIDEWAYS)) \
                if self.gait_spec.sideways_gain > 0 else 0.0
            return {**out, "speed": self.speed * slow, "omega": _turn(yaw, base_yaw), "sideways": side}
        # approach: to the pre-push point, around the side the robot is on if the box is in the way
        waypoint = box_xy - d * (reach + APPROACH_MARGIN)
        if along > -(rear + PUSH_ZONE[0]):
            side = 1.0 if lateral >= 0 else -1.0
            waypoint = waypoint + normal * side * (half_width + HEAD_REACH + APPROACH_MARGIN)
        to_wp = waypoint - base_xy
        yaw = float(np.arctan2(to_wp[1], to_wp[0]))
        near = min(1.0, float(np.linalg.norm(to_wp)) / self.slow_radius)  # slowing down as at the goal
        out = {**out, "direction": d, "box_speed": 0.0, "phase": "approach", "waypoint": waypoint, "yaw": yaw}
        if abs(_yaw_error(yaw, base_yaw)) <= TURN_IN_PLACE:
            return {**out, "speed": self.speed * near, "omega": _turn(yaw, base_yaw)}
        return self._turn_on_the_spot(out, base_xy, base_yaw, box_xy, box_yaw, half_depth, half_width, clearing)

    @staticmethod
    def _turn_on_the_spot(out: dict, base_xy: np.ndarray, base_yaw: float, box_xy: np.ndarray, box_yaw: float,
                          half_x: float, half_y: float, clearing: bool = False) -> dict:
        """:meth:`command`'s targets for a turn on the spot toward ``out['yaw']`` [rad] (speed 0) — or, with
        the trunk's origin nearer the box's footprint than :data:`TURN_CLEARANCE` [m] (or, ``clearing`` already,
        than :data:`TURN_CLEARANCE` + :data:`CLEAR_HYSTERESIS`), a step along the heading away from the box first
        (``clearing`` True; backward where the box is ahead)."""
        if box_clearance(base_xy, box_xy, box_yaw, half_x, half_y) < TURN_CLEARANCE + clearing * CLEAR_HYSTERESIS:
            heading = np.array([np.cos(base_yaw), np.sin(base_yaw)])
            away = -1.0 if float((box_xy - base_xy) @ heading) > 0 else 1.0
            return {**out, "waypoint": base_xy + away * heading * TURN_CLEARANCE, "yaw": float(base_yaw),
                    "speed": away * CLEAR_SPEED, "omega": 0.0, "clearing": True}
        return {**out, "speed": 0.0, "omega": _turn(out["yaw"], base_yaw)}

    def reach(self, t: float, base_xy: np.ndarray, base_yaw: float, box_xy: np.ndarray, box_yaw: float,
              direction: np.ndarray, half_x: float, half_y: float, speed: float) -> dict:
        """The free foot's path for a one-leg push (T5), in the trunk frame.

        The foot pushes the box's face that looks most against ``direction`` (the
        box's yaw counts: a turned box is met on its turned face), with its centre
        :data:`REACH_DEPTH` below the trunk origin, at the point of the face
        nearest its centre that the leg still reaches (:data:`REACH_LEG`; at most
        :data:`REACH_INSET` in from the face's end nearest the robot): a push off
        the centre turns the box, and the leg reaches less far along the face the
        further it has swept. By phase (:data:`REACH_TIMES`): until the first
        time, beside the face but behind the box's near side (the leg clear of
        the box); until the second, moving along the face to
        :data:`REACH_CLEARANCE` off the contact point; then pressing
        :data:`REACH_PRESS` into the face and moving with it along ``direction``
        at the box's reference ``speed`` — the sweep the planner refines. The
        face follows the box's measured pose each cycle.

        Args:
            t: time since the task started [s].
            base_xy, base_yaw: trunk position [m] and yaw [rad].
            box_xy: box centre [m]; box_yaw: its yaw [rad]; direction: (2,) unit push direction (world).
            half_x, half_y: half the box's extent along its own x and y axes [m].
            speed: the box reference's speed [m/s].
        Returns:
            dict ``foot`` (3,) [m] the foot centre at ``t0`` [s] in the trunk frame,
            ``velocity`` (3,) [m/s] in the trunk frame, ``t0``, ``phase``
            (``"reach"`` or ``"push"``): :meth:`~amhe_cli.control.gait.Gait.reference`'s ``reach``.
        """
        d = np.asarray(direction, dtype=float)
        box_xy, base_xy = np.asarray(box_xy, dtype=float), np.asarray(base_xy, dtype=float)
        # the box's face normals (outward); the pushed face is the one most against the push
        normals = np.array([[np.cos(box_yaw + k * np.pi / 2), np.sin(box_yaw + k * np.pi / 2)] for k in range(4)])
        k = int(np.argmin(normals @ d))
        normal = normals[k]
        along = np.array([-normal[1], normal[0]])  # along the face, toward the robot's side of the box
        if along @ (base_xy - box_xy) < 0:
            along = -along
        half_n, half_a = (half_x, half_y) if k % 2 == 0 else (half_y, half_x)
        c, s_ = np.cos(base_yaw), np.sin(base_yaw)

        def turn(v, z):  # a world (..., 2) vector -> the trunk frame (..., 3), with height z
            v = np.asarray(v)
            x, y = c * v[..., 0] + s_ * v[..., 1], -s_ * v[..., 0] + c * v[..., 1]
            return np.stack([x, y, np.full_like(x, z)], axis=-1)

        def trunk(p):  # a world (..., 2) point -> the trunk frame (..., 3), at the reach depth
            return turn(np.asarray(p) - base_xy, -REACH_DEPTH)
        # the contact: from the face's centre toward its near end, the first point the leg reaches
        offsets = np.linspace(0.0, half_a - REACH_INSET, 25)
        points = box_xy + normal * half_n + along * offsets[:, None]
        rel = trunk(points - d * (FOOT_RADIUS - REACH_PRESS)) - HIP_POS[LEGS.index(self.gait_spec.free_legs[0])]
        ok = np.sum(rel ** 2, axis=-1) - HIP_OFFSET ** 2 <= REACH_LEG ** 2
        contact = points[int(np.argmax(ok))] if ok.any() else points[-1]
        pre = contact - d * (FOOT_RADIUS + REACH_CLEARANCE)
        behind = pre + along * (half_a + FOOT_RADIUS + REACH_CLEARANCE - np.linalg.norm(contact - points[0]))
        zero = np.zeros(3)
        if t < REACH_TIMES[0]:
            return {"foot": trunk(behind), "velocity": zero, "t0": float(t), "phase": "reach"}
        if t < REACH_TIMES[1]:
            span = REACH_TIMES[1] - REACH_TIMES[0]
            a, b = trunk(behind), trunk(pre)
            return {"foot": a + (b - a) * (t - REACH_TIMES[0]) / span, "velocity": (b - a) / span,
                    "t0": float(t), "phase": "reach"}
        foot = trunk(contact - d * (FOOT_RADIUS - REACH_PRESS))
        vel = turn(d, 0.0) * speed
        return {"foot": foot, "velocity": vel, "t0": float(t), "phase": "push"}

    # -- cost ------------------------------------------------------------------
    def stage_cost(self, base_pos: np.ndarray, base_quat: np.ndarray, base_vel: np.ndarray, base_angvel: np.ndarray,
                   box_pos: np.ndarray, ctrl: np.ndarray, ref: np.ndarray, cmd: dict, tau: np.ndarray | float = 0.0,
                   floor: float = 0.0, box_quat: np.ndarray | None = None) -> np.ndarray:
        """Running cost of states, vectorised over any leading axes.

        The box's reference moves from where the box was at the cycle start
        (``cmd['box']``) toward its target at the commanded speed, so the box
        term asks for steady progress, not a lunge.

        Args:
            base_pos: (..., 3) [m]; base_quat: (..., 4) (w, x, y, z);
            base_vel: (..., 3) world-frame linear velocity [m/s];
            base_angvel: (..., 3) body-frame angular velocity [rad/s];
            box_pos: (..., 3) [m]; ctrl, ref: (..., 12) joint targets and gait reference [rad];
            cmd: :meth:`command` output; tau: time into the horizon [s],
            broadcastable to the leading axes; floor: the robot's floor height [m];
            box_quat: (..., 4) the box's orientation, for the box-tilt term (None: no term).
        Returns:
            (...) cost per state.
        """
        w = self.weights
        yaw = quat_to_yaw(base_quat)
        c = self._box_term(box_pos, cmd, tau)
        c += (w.stance if self.push_side else w.waypoint) * np.sum(
            (base_pos[..., :2] - self.waypoint_reference(cmd, tau)) ** 2, axis=-1)
        heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
        c += w.heading * (1 - np.cos(yaw - self.heading_reference(cmd, tau)))
        c += w.speed * (np.sum(base_vel[..., :2] * heading, axis=-1) - cmd["speed"]) ** 2
        c += w.lateral * (base_vel[..., 1] * heading[..., 0] - base_vel[..., 0] * heading[..., 1]
                          - cmd.get("sideways", 0.0)) ** 2
        height = base_pos[..., 2] - floor
        c += w.height * (height - BASE_HEIGHT) ** 2 + w.tilt * _tilt(base_quat)
        c += w.angvel * np.sum(base_angvel[..., :2] ** 2, axis=-1)
        c += w.effort * np.sum((ctrl - ref) ** 2, axis=-1)
        c += w.fall * (height < self.unsafe_height)
        if w.keep_out and cmd.get("phase") == "approach":
            near = np.linalg.norm(base_pos[..., :2] - cmd["box"], axis=-1)
            c += w.keep_out * np.maximum(KEEP_OUT - near, 0.0) ** 2
        if box_quat is not None:
            c += w.box_tilt * _tilt(box_quat)
            if "box_yaw" in cmd:
                c += w.box_yaw * (1 - np.cos(quat_to_yaw(box_quat) - cmd["box_yaw"]))
        return c

    def waypoint_reference(self, cmd: dict, tau: np.ndarray | float) -> np.ndarray:
        """(..., 2) where the trunk should be ``tau`` [s] into the horizon: from where it stood at the cycle
        start (``cmd['base']``) toward the waypoint at the commanded speed, never past it.

        A fixed waypoint paid the planner for every centimetre it gained on a far
        waypoint: walking around the box, the trunk surged to 0.5 m/s against a
        0.2 m/s command, pitched nose-down over its front legs and fell (T2
        baseline, seed 0, 13.6–14.0 s, benchmarks/fall_forensics.py). The box's
        reference moves the same way (:meth:`box_reference`). With ``speed`` 0 (turning
        in place, recovering) the trunk is held where it stands. The one-leg
        push's stance, and a command without ``base`` (the executed cost ``J``),
        keep the fixed waypoint.
        """
        tau = np.asarray(tau, dtype=float)[..., None]
        goal = np.asarray(cmd["waypoint"], dtype=float)
        start = cmd.get("base")
        if self.push_side or start is None:
            return np.broadcast_to(goal, tau.shape[:-1] + (2,))
        delta = goal - start
        dist = float(np.linalg.norm(delta))
        if dist < 1e-9:
            return np.broadcast_to(goal, tau.shape[:-1] + (2,))
        return start + delta / dist * np.minimum(abs(cmd["speed"]) * tau, dist)

    def heading_reference(self, cmd: dict, tau: np.ndarray | float) -> np.ndarray | float:
        """(...) the heading [rad] the trunk should have ``tau`` [s] into the horizon: with a ``heading_rate``,
        in the approach phase, from its heading at the cycle start (``cmd['base_yaw']``) toward ``cmd['yaw']``
        at that rate, never past it; otherwise ``cmd['yaw']`` itself.

        The heading's counterpart of :meth:`waypoint_reference`. A fixed heading pays the planner for every
        degree it gains on a far one: turning round (the approach, T2's curve) it twisted the trunk at
        1.1–1.35 rad/s, three times :data:`MAX_YAW_RATE`, in 4 of the 19 recorded falls with a timeline.
        Measured (docs/fall_prevention.md, "The planner's heading as a moving reference"): at
        :data:`MAX_YAW_RATE` in every phase, fewer falls with plans 35 ms late but T2 slower, and at the
        paper's setting 2 falls in 7 T2 runs where the fixed heading had none; in the approach alone,
        T2's falls 7 -> 1 in 30 runs with plans 35 ms late, but at the paper's setting 1 fall in 19 T2 runs
        where the fixed heading had none, and slower. Off by default.
        The push (its steering back to the line), the one-leg push and a command without ``base`` (the
        executed cost ``J``) keep the fixed heading.
        """
        if self.heading_rate <= 0 or cmd.get("phase") != "approach" or cmd.get("base") is None:
            return cmd["yaw"]
        start = cmd["base_yaw"]
        err = _yaw_error(cmd["yaw"], start)
        return start + np.sign(err) * np.minimum(self.heading_rate * np.asarray(tau, dtype=float), abs(err))

    def _box_term(self, box_pos: np.ndarray, cmd: dict, tau: np.ndarray | float) -> np.ndarray:
        """(...) ``w_box`` × squared distance of the box to its reference, per (10 cm)²."""
        return self.weights.box * np.sum((box_pos[..., :2] - self.box_reference(cmd, tau)) ** 2, axis=-1) / 0.01

    def box_reference(self, cmd: dict, tau: np.ndarray | float) -> np.ndarray:
        """(..., 2) where the box should be ``tau`` [s] into the horizon: moving toward the target at the
        commanded box speed, never past it."""
        tau = np.asarray(tau, dtype=float)[..., None]
        start = cmd["box"]
        delta = cmd["target"] - start
        dist = float(np.linalg.norm(delta))
        if dist < 1e-9:
            return np.broadcast_to(start, tau.shape[:-1] + (2,))
        return start + delta / dist * np.minimum(cmd["box_speed"] * tau, dist)

    def terminal_cost(self, box_pos: np.ndarray, cmd: dict, tau: float) -> np.ndarray:
        """(...) extra cost of the box's position at the end of a horizon ``tau`` [s] long."""
        return self.weights.terminal * self._box_term(box_pos, cmd, tau)


def box_nearest(point_xy: np.ndarray, box_xy: np.ndarray, box_yaw: float, half_x: float,
                half_y: float) -> np.ndarray:
    """(2,) the point of a box's footprint nearest ``point_xy`` (2,) [m], in the floor plane: the footprint is
    the rectangle of half extents ``half_x``, ``half_y`` [m] along the box's own axes, centred at ``box_xy``
    (2,) and turned by ``box_yaw`` [rad]; ``point_xy`` itself where it lies inside."""
    c, s_ = np.cos(box_yaw), np.sin(box_yaw)
    dx, dy = np.subtract(point_xy, box_xy)
    lx = np.clip(c * dx + s_ * dy, -half_x, half_x)
    ly = np.clip(-s_ * dx + c * dy, -half_y, half_y)
    return np.asarray(box_xy, float) + [c * lx - s_ * ly, s_ * lx + c * ly]


def box_half_extent(direction: np.ndarray, box_yaw: float, half_x: float, half_y: float) -> float:
    """Half the extent [m] of a box's footprint (half extents ``half_x``, ``half_y`` [m] along its own axes,
    turned by ``box_yaw`` [rad]) along the unit ``direction`` (2,): ``half_x |cos θ| + half_y |sin θ|`` with θ
    the angle between them (a square box turned 45° reaches √2 times its half depth)."""
    c, s_ = np.cos(box_yaw), np.sin(box_yaw)
    along_x = direction[0] * c + direction[1] * s_  # the direction in the box's own axes
    along_y = direction[1] * c - direction[0] * s_
    return float(half_x * abs(along_x) + half_y * abs(along_y))


def box_clearance(point_xy: np.ndarray, box_xy: np.ndarray, box_yaw: float, half_x: float,
                  half_y: float) -> float:
    """Distance [m] in the floor plane from ``point_xy`` (2,) to a box's footprint (:func:`box_nearest`);
    0 inside it."""
    return float(np.linalg.norm(np.subtract(point_xy, box_nearest(point_xy, box_xy, box_yaw, half_x, half_y))))


def _yaw_error(yaw: float, base_yaw: float) -> float:
    """``yaw − base_yaw`` wrapped to (−π, π] [rad]."""
    return float(np.angle(np.exp(1j * (yaw - base_yaw))))


def _turn(yaw: float, base_yaw: float) -> float:
    """Yaw-rate command [rad/s] toward heading ``yaw``: proportional, clipped to :data:`MAX_YAW_RATE`."""
    return float(np.clip(1.5 * _yaw_error(yaw, base_yaw), -MAX_YAW_RATE, MAX_YAW_RATE))


def _tilt(quat: np.ndarray) -> np.ndarray:
    """(...) ``1 − cos`` of the angle between a body's z axis and world z, for (..., 4) (w, x, y, z) quaternions."""
    _, x, y, _ = np.moveaxis(quat, -1, 0)
    return 2 * (x * x + y * y)


#: The tasks by name (docs/tasks.md). The robot starts at the origin facing +x; the box just ahead of its head.
TASKS = {
    "t1": Task("t1", box_start=(0.52, 0.0), goal=(2.0, 0.0)),
    "t2": Task("t2", box_start=(0.52, 0.0), goal=(0.52 + 1.0, 1.0), circle=(0.52, 1.0, 1.0, np.pi / 2),
               duration=60.0),
    "t3": Task("t3", box_start=(0.52, 0.0), goal=(3.0, 0.0), events=(Event("box_mass", 6.0, t=10.0),),
               duration=60.0),
    "t4": Task("t4", box_start=(0.52, 0.0), goal=(2.5, 0.0), truth={"box_mass": 4.0, "box_friction": 0.4},
               events=(Event("box_friction", 0.8, box_x=1.5),), duration=60.0),
    # T5: the box ahead and to the right, its left face where the front-right foot's sweep begins
    # (its centre 0.2 m below the trunk reaches y = +0.06 m at the abduction limit)
    "t5": Task("t5", box_start=(0.49, -0.18), goal=(0.49, -0.68), gait="tripod", speed=0.0, push_side=-1,
               duration=20.0, slow_floor=0.1),  # the leg's box reference as measured in Table II
}


def get_task(name: str, **overrides) -> Task:
    """The task ``name`` (case-insensitive) with fields replaced by ``overrides``.

    Raises:
        AmheError: unknown task name.
    """
    key = name.lower()
    if key not in TASKS:
        raise AmheError(f"unknown task {name!r}: expected one of {', '.join(TASKS)}")
    return replace(TASKS[key], **overrides)
