"""The closed loop: spline and MPPI rules, gaits, tasks, planner modes, runs and the ``run`` command.

Closed-loop runs here are short (≤ 1.5 s of plant time) with a small planner
(8 samples × 20 steps), so the whole file takes seconds; they check behaviour
(events, modes, estimator failures, files written), not task success.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import amhe, one_line_error

from amhe_cli.estimation.belief import Belief
from amhe_cli.control.closed_loop import (MHE_DUTY, OWN_CORE_FROM, RUN_PARAMS, TASK_BOX_SIZE, EstimatorThread,
                                          RunSettings, core_split, describe_split, make_plant, make_planner, run_task)
from amhe_cli.errors import AmheError
from amhe_cli.control.evaluate import run_settings, summarise
from amhe_cli.control.gait import GAITS, HIP_POS, LEGS, STAND_HEIGHT
from amhe_cli.control.maneuver import ABDUCTION_RANGE, CALF, THIGH, leg_fk3, leg_ik3
from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator, Update
from amhe_cli.control.planner import PlannerSettings, spline_basis
from amhe_cli.estimation.sampling import mppi_weights
from amhe_cli.model.scene import FOOT_RADIUS, STAND_JOINTS
from amhe_cli.control.tasks import (BASE_HEIGHT, HEAD_REACH, REACH_LEG, REACH_PRESS, REACH_TIMES, CostWeights, Event,
                                    get_task)

#: small planner: enough to exercise every code path, cheap enough for a test
SMALL = {"samples": 8, "horizon": 20}
HALF_DEPTH = TASK_BOX_SIZE[0] / 2  # what run_task passes to Task.command


def small_settings(mode: str, **kw) -> RunSettings:
    return RunSettings(mode=mode, planner=PlannerSettings(**SMALL), threads=1, **kw)


def belief(mass: float = 5.0, friction: float = 0.3) -> Belief:
    return Belief(values={"box_mass": mass, "box_friction": friction},
                  std={"box_mass": 0.5, "box_friction": 0.05}, free=["box_mass", "box_friction"])


# -- spline_basis -----------------------------------------------------------------

KNOTS = np.array([0.0, 0.1, 0.25, 0.4])  # non-uniform on purpose


def test_spline_interpolates_knots_exactly():
    B = spline_basis(KNOTS, KNOTS)
    np.testing.assert_allclose(B, np.eye(len(KNOTS)), atol=1e-12)
    y = np.array([0.3, -1.0, 2.0, 0.5])
    np.testing.assert_allclose(spline_basis(KNOTS, KNOTS) @ y, y, atol=1e-12)


def test_spline_reproduces_constants_and_lines():
    q = np.linspace(0.0, 0.4, 57)
    B = spline_basis(KNOTS, q)
    assert B.shape == (57, 4)
    np.testing.assert_allclose(B.sum(axis=1), 1.0, atol=1e-12)
    # a natural cubic spline through collinear knots is that line
    np.testing.assert_allclose(B @ (2.0 - 3.0 * KNOTS), 2.0 - 3.0 * q, atol=1e-12)


def test_spline_is_smooth_at_interior_knots():
    """C¹ at an interior knot (piecewise-linear interpolation would not be)."""
    y = np.array([0.0, 1.0, -0.5, 0.2])
    h = 1e-6
    for k in KNOTS[1:-1]:
        left = (spline_basis(KNOTS, [k])[0] - spline_basis(KNOTS, [k - h])[0]) @ y / h
        right = (spline_basis(KNOTS, [k + h])[0] - spline_basis(KNOTS, [k])[0]) @ y / h
        assert abs(left - right) < 1e-3 * max(1.0, abs(left))


def test_spline_holds_end_values_outside_knots():
    y = np.array([0.3, -1.0, 2.0, 0.5])
    out = spline_basis(KNOTS, [-1.0, -0.01, 0.41, 7.0]) @ y
    np.testing.assert_allclose(out, [0.3, 0.3, 0.5, 0.5], atol=1e-12)


# -- mppi_weights ----------------------------------------------------------------

def test_mppi_weights_normalised_and_ordered():
    costs = np.array([3.0, 1.0, 2.0, 10.0, 1.5])
    w = mppi_weights(costs, 0.5)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(w > 0)
    assert np.argmax(w) == 1
    # lower cost, larger weight, everywhere
    order = np.argsort(costs)
    assert np.all(np.diff(w[order]) < 0)


def test_mppi_weights_temperature_sharpens():
    costs = np.array([0.0, 0.5, 1.0])
    assert mppi_weights(costs, 0.05)[0] > mppi_weights(costs, 1.0)[0]


def test_mppi_weights_ignore_non_finite_costs():
    w = mppi_weights(np.array([1.0, np.nan, 2.0, np.inf, -np.inf]), 0.2)
    assert w[1] == 0 and w[3] == 0 and w[4] == 0
    assert w.sum() == pytest.approx(1.0)
    assert w[0] > w[2] > 0


@pytest.mark.parametrize("temperature", [0.0, -0.1, float("nan")])
def test_mppi_weights_reject_non_positive_temperature(temperature):
    with pytest.raises(ValueError):
        mppi_weights(np.array([1.0, 2.0]), temperature)


# -- gaits -------------------------------------------------------------------------

#: times that never fall on a trot phase boundary (multiples of 0.25 s)
T = 0.007 + 0.031 * np.arange(60)


def foot_xz(ref: np.ndarray, leg: str) -> tuple[np.ndarray, np.ndarray]:
    """Foot position (forward, up) in the hip's sagittal plane from (…, 12) joint targets (planar FK)."""
    i = LEGS.index(leg)
    th, ca = ref[..., 3 * i + 1], ref[..., 3 * i + 2]
    x = -THIGH * np.sin(th) - CALF * np.sin(th + ca)
    z = -THIGH * np.cos(th) - CALF * np.cos(th + ca)
    return x, z


def test_trot_diagonal_pairs_alternate():
    trot = GAITS["trot"]
    c = trot.contact(T)
    assert c.shape == (len(T), 4)
    fr, fl, rr, rl = (c[:, LEGS.index(n)] for n in ("FR", "FL", "RR", "RL"))
    np.testing.assert_array_equal(fr, rl)
    np.testing.assert_array_equal(fl, rr)
    np.testing.assert_array_equal(fr, ~fl)
    assert np.all(c.sum(axis=1) == 2)
    # half a period later the other pair is down
    np.testing.assert_array_equal(trot.contact(T + trot.period / 2), ~c)
    # and it really does switch: two modes over the cycle
    assert len({trot.mode(t) for t in T}) == 2


def test_stand_has_all_feet_down_and_one_mode():
    stand = GAITS["stand"]
    assert stand.contact(T).all()
    assert {stand.mode(t) for t in T} == {15}
    for v in (0.0, 0.3):
        np.testing.assert_array_equal(stand.reference(T, v), np.broadcast_to(STAND_JOINTS, (len(T), 12)))


def test_tripod_front_right_never_in_stance():
    tri = GAITS["tripod"]
    c = tri.contact(T)
    assert not c[:, LEGS.index("FR")].any()
    assert c[:, [LEGS.index(n) for n in ("FL", "RR", "RL")]].all()
    ref = tri.reference(T)
    np.testing.assert_allclose(ref[:, 0:3], np.broadcast_to(tri.free_pose, (len(T), 3)))


def stance_feet(ref: np.ndarray) -> np.ndarray:
    """(4, 3) feet of a (12,) joint reference in the trunk frame [m]."""
    return np.array([HIP_POS[i] + leg_fk3(ref[3 * i:3 * i + 3], np.sign(HIP_POS[i, 1])) for i in range(4)])


def test_tripod_keeps_the_centre_of_mass_inside_its_three_feet():
    """Standing on FL, RR, RL, the robot's centre of mass (at the trunk origin within 3 mm) lies on the line from
    FL to RR unless the trunk moves over the feet: the tripod reference shifts it 6 cm inside, feet planted."""
    tri = GAITS["tripod"]
    stand = stance_feet(STAND_JOINTS)
    feet = stance_feet(tri.reference(0.0))
    # each planted foot is where it stands in the standing pose, seen from a trunk moved by body_shift
    np.testing.assert_allclose(feet[1:, :2], stand[1:, :2] - np.array(tri.body_shift), atol=1e-9)
    np.testing.assert_allclose(feet[1:, 2], stand[1:, 2], atol=1e-9)
    fl, rr, rl = feet[1, :2], feet[2, :2], feet[3, :2]
    edge = (rr - fl) / np.linalg.norm(rr - fl)

    def side(p):  # signed distance of p from the FL-RR edge
        return edge[0] * (p - fl)[1] - edge[1] * (p - fl)[0]
    assert np.sign(side(np.zeros(2))) == np.sign(side(rl)) and abs(side(np.zeros(2))) > 0.05


def test_leg_ik3_inverts_mujocos_leg_kinematics():
    import mujoco
    from amhe_cli.model.scene import Scene, SceneConfig
    scene = Scene(SceneConfig())
    m, d = scene.model, mujoco.MjData(scene.model)
    rng = np.random.default_rng(0)
    for leg, i in (("FR", 0), ("RL", 3)):
        for _ in range(5):
            q = rng.uniform([-0.8, -0.5, -2.6], [0.8, 1.5, -1.0])
            d.qpos[:] = 0.0
            d.qpos[scene.base_qpos[3:]] = [1, 0, 0, 0]
            d.qpos[scene.joint_qpos[3 * i:3 * i + 3]] = q
            mujoco.mj_kinematics(m, d)
            foot = d.geom(f"{leg}_foot").xpos - d.body(f"{leg}_hip").xpos
            side = np.sign(HIP_POS[i, 1])
            np.testing.assert_allclose(leg_fk3(q, side), foot, atol=1e-9)
            np.testing.assert_allclose(leg_ik3(foot, side), q, atol=1e-9)
    # out of reach: the nearest pose the limits allow, never NaN
    far = leg_ik3(np.array([0.0, 0.5, -0.1]), -1.0)
    assert np.isfinite(far).all() and far[0] == pytest.approx(ABDUCTION_RANGE)


def test_trot_reference_in_place_keeps_feet_under_hips():
    trot = GAITS["trot"]
    ref = trot.reference(T, v=0.0)
    assert ref.shape == (len(T), 12)
    np.testing.assert_array_equal(ref[:, 0::3], 0.0)  # hips (abduction) stay at 0
    stance = trot.contact(T)
    for k, leg in enumerate(LEGS):
        x, z = foot_xz(ref, leg)
        np.testing.assert_allclose(x, 0.0, atol=1e-9)
        np.testing.assert_allclose(z[stance[:, k]], -STAND_HEIGHT, atol=1e-9)
        swing = z[~stance[:, k]]
        assert np.all(swing > -STAND_HEIGHT + 1e-9)  # swing feet lift ...
        assert swing.max() == pytest.approx(-STAND_HEIGHT + trot.step_height, abs=0.01)  # ... by step_height


def test_trot_forward_speed_moves_stance_foot_backward():
    from dataclasses import replace
    trot = replace(GAITS["trot"], stride_gain=1.0, stride_deadband=0.0, turn_gain=1.0)  # kinematic
    v = 0.3
    step = v * trot.duty * trot.period
    # FR is in stance over [0, 0.25) s of each cycle
    ts = np.linspace(0.001, trot.duty * trot.period - 0.001, 30)
    assert trot.contact(ts)[:, LEGS.index("FR")].all()
    x, z = foot_xz(trot.reference(ts, v=v), "FR")
    assert np.all(np.diff(x) < 0)  # the foot slides backward under the hip
    assert x[0] - x[-1] == pytest.approx(step, abs=2e-3)
    assert x[0] == pytest.approx(step / 2, abs=2e-3)
    np.testing.assert_allclose(z, -STAND_HEIGHT, atol=1e-9)  # without lifting
    # mid-swing the foot is forward-moving and lifted by step_height
    xs, zs = foot_xz(trot.reference(np.array([0.37, 0.375, 0.38]), v=v), "FR")
    assert np.all(np.diff(xs) > 0)
    assert zs[1] == pytest.approx(-STAND_HEIGHT + trot.step_height, abs=1e-6)
    assert not np.allclose(trot.reference(T, v=v), trot.reference(T, v=0.0))


def test_calibrated_trot_strides_longer_and_stands_still_at_zero():
    from amhe_cli.control.gait import STRIDE_SMOOTH
    trot = GAITS["trot"]
    assert trot.stride_gain < 1 and trot.stride_deadband > 0  # the servos realise less than the kinematics
    ts = np.linspace(0.001, trot.duty * trot.period - 0.001, 30)
    v = 0.2
    x, _ = foot_xz(trot.reference(ts, v=v), "FR")
    u = v / trot.stride_gain + trot.stride_deadband * np.tanh(v / STRIDE_SMOOTH)
    assert x[0] - x[-1] == pytest.approx(u * trot.duty * trot.period, abs=2e-3)
    # a zero command is a trot in place: no stride at all
    x0, _ = foot_xz(trot.reference(ts, v=0.0), "FR")
    np.testing.assert_allclose(x0, 0.0, atol=1e-9)
    # a yaw-rate command lengthens the outer (right, for a left turn) legs' strides
    xr, _ = foot_xz(trot.reference(ts, v=v, omega=0.3), "FR")
    assert xr[0] - xr[-1] > x[0] - x[-1]


def test_the_trot_steps_sideways_as_asked_and_no_command_changes_nothing():
    """``Gait.reference``'s ``sideways``: each stance foot slides across under its hip (the abduction turned by
    asin(y / h)) by the step the calibrated trot asks; zero, or a gait without a sidestep, leaves the reference as
    it was; open loop in the sim plant the trot walks sideways about as asked, both ways."""
    trot = GAITS["trot"]
    assert 0 < trot.sideways_gain < 1  # the servos realise less than the kinematics
    ts = np.linspace(0.001, trot.duty * trot.period - 0.001, 30)  # FR's stance
    np.testing.assert_array_equal(trot.reference(ts, v=0.2, sideways=0.0), trot.reference(ts, v=0.2))
    for name in ("stand", "tripod"):
        np.testing.assert_array_equal(GAITS[name].reference(ts, sideways=0.1), GAITS[name].reference(ts))
    ref = trot.reference(ts, v=0.2, sideways=0.1)
    i = LEGS.index("FR")
    _, z = foot_xz(ref, "FR")
    across = -z * np.sin(ref[:, 3 * i])  # the foot's offset across from its hip, the abduction turned
    assert across[0] - across[-1] == pytest.approx(0.1 / trot.sideways_gain * trot.duty * trot.period, abs=2e-3)
    from amhe_cli.control.closed_loop import make_plant
    from amhe_cli.io.quat import quat_to_yaw
    for asked in (0.1, -0.1):
        plant = make_plant(get_task("t1", box_start=(9.0, 9.0)), 100.0, 4.0)  # the box out of the way
        sc = plant.scene
        for k in range(300):
            plant.step(trot.reference(k * 0.01, 0.2, 0.0, None, asked))
            if k == 99:
                start = plant.data.qpos[sc.base_qpos[:2]].copy(), float(quat_to_yaw(plant.data.qpos[sc.base_qpos[3:]]))
        moved = plant.data.qpos[sc.base_qpos[:2]] - start[0]
        heading = 0.5 * (start[1] + float(quat_to_yaw(plant.data.qpos[sc.base_qpos[3:]])))
        side = (-moved[0] * np.sin(heading) + moved[1] * np.cos(heading)) / 2.0
        assert 0.6 * abs(asked) < side * np.sign(asked) < 1.4 * abs(asked), side  # 0.087 / −0.079 measured


# -- tasks ---------------------------------------------------------------------------

def test_unknown_task():
    with pytest.raises(AmheError, match="t9.*t1"):
        get_task("t9")
    assert get_task("T1").name == "t1"
    assert get_task("t1", duration=2.0).duration == 2.0
    assert get_task("t1").duration == 40.0  # overrides do not leak into the table


def test_t1_waypoint_behind_box_on_line_to_goal():
    task = get_task("t1")
    cmd = task.command(np.zeros(2), 0.0, np.array(task.box_start), HALF_DEPTH)
    np.testing.assert_allclose(cmd["target"], task.goal)
    np.testing.assert_allclose(cmd["direction"], [1.0, 0.0])
    assert cmd["waypoint"][0] < task.box_start[0]
    assert cmd["waypoint"][0] == pytest.approx(task.box_start[0] - HALF_DEPTH - HEAD_REACH)
    assert cmd["waypoint"][1] == pytest.approx(0.0)
    assert cmd["speed"] == pytest.approx(task.speed) and task.speed == pytest.approx(0.2)
    assert cmd["phase"] == "push"
    # box off the axis, robot behind it on the goal-box line: the waypoint is on that line, beyond the box
    box = np.array([1.0, 0.4])
    goal = np.asarray(task.goal)
    d = (goal - box) / np.linalg.norm(goal - box)
    cmd = task.command(box - 0.5 * d, 0.0, box, HALF_DEPTH)
    assert cmd["phase"] == "push"
    a, b = box - goal, cmd["waypoint"] - goal
    assert abs(a[0] * b[1] - a[1] * b[0]) < 1e-9
    assert np.linalg.norm(b) == pytest.approx(np.linalg.norm(a) + HALF_DEPTH + HEAD_REACH)
    assert cmd["yaw"] == pytest.approx(np.arctan2(-0.4, 1.0))
    assert cmd["omega"] < 0  # turn right toward the push direction


def test_push_heading_bends_back_toward_the_push_line():
    task = get_task("t1")
    box = np.array(task.box_start)
    back = HALF_DEPTH + HEAD_REACH  # the pushing pose
    on_line = task.command(box - [back, 0.0], 0.0, box, HALF_DEPTH)
    left = task.command(box - [back, -0.1], 0.0, box, HALF_DEPTH)
    right = task.command(box - [back, 0.1], 0.0, box, HALF_DEPTH)
    assert on_line["phase"] == left["phase"] == right["phase"] == "push"
    assert on_line["yaw"] == pytest.approx(0.0)
    assert left["yaw"] < 0 < right["yaw"]  # steer back to the line (and step toward it: the next test)
    assert left["yaw"] == pytest.approx(-right["yaw"])
    np.testing.assert_allclose(left["waypoint"], on_line["waypoint"])  # the pushing pose stays on the line


def test_the_push_steps_sideways_back_to_the_push_line():
    """Off the push line the trot steps back across toward it (``SIDE_GAIN`` per metre, at most ``MAX_SIDEWAYS``);
    on it, in the approach, or with a gait that has no sidestep (T5's tripod), it asks none. The planner's lateral
    cost then asks that sideways speed, not zero."""
    from amhe_cli.control.tasks import MAX_SIDEWAYS, SIDE_GAIN
    task = get_task("t1")
    box = np.array(task.box_start)
    back = HALF_DEPTH + HEAD_REACH
    assert task.command(box - [back, 0.0], 0.0, box, HALF_DEPTH)["sideways"] == 0.0
    right = task.command(box - [back, 0.05], 0.0, box, HALF_DEPTH)  # 5 cm right of the line: step left
    assert right["phase"] == "push" and right["sideways"] == pytest.approx(SIDE_GAIN * 0.05)
    far_left = task.command(box - [back, -0.3], 0.0, box, HALF_DEPTH)
    assert far_left["phase"] == "push" and far_left["sideways"] == pytest.approx(-MAX_SIDEWAYS)
    assert task.command(box + [0.3, 0.8], 0.0, box, HALF_DEPTH).get("sideways", 0.0) == 0.0  # approach
    t5 = get_task("t5")
    assert t5.command(np.zeros(2), 0.0, np.array(t5.box_start), HALF_DEPTH, t=1.0).get("sideways", 0.0) == 0.0
    # the lateral cost: a trunk moving across at the asked speed costs less than one that does not
    quat, zero3, ref = np.array([1.0, 0, 0, 0]), np.zeros(3), np.array(STAND_JOINTS)
    pos = np.array([*(box - [back, 0.05]), BASE_HEIGHT])
    cost = [task.stage_cost(pos, quat, np.array([0.2, vy, 0.0]), zero3, np.array([*box, 0.19]), ref, ref, right)
            for vy in (0.0, right["sideways"])]
    assert cost[1] < cost[0]


def test_a_robot_past_the_box_walks_back_behind_it():
    task = get_task("t4")
    box = np.array([1.9, 0.0])
    # beside and ahead of the box, facing the goal: turn on the spot, around the box on the robot's side
    cmd = task.command(box + [0.3, 0.8], 0.0, box, HALF_DEPTH)
    assert cmd["phase"] == "approach"
    assert cmd["speed"] == 0.0 and abs(cmd["omega"]) > 0
    assert cmd["waypoint"][0] < box[0] - HALF_DEPTH - HEAD_REACH  # behind the pushing pose
    assert cmd["waypoint"][1] > box[1] + HALF_DEPTH  # on the robot's (left) side of the box
    assert cmd["box_speed"] == 0.0  # nobody pushes the box meanwhile
    # once facing its waypoint it walks there
    wp = cmd["waypoint"]
    base = box + [0.3, 0.8]
    facing = float(np.arctan2(*(wp - base)[::-1]))
    walk = task.command(base, facing, box, HALF_DEPTH)
    assert walk["speed"] > 0 and walk["yaw"] == pytest.approx(facing)
    # fallen far behind the box: walk up to it
    cmd = task.command(box - [1.5, 0.0], 0.0, box, HALF_DEPTH)
    assert cmd["phase"] == "approach" and cmd["speed"] > 0 and cmd["waypoint"][1] == pytest.approx(box[1])


def test_a_robot_too_near_the_box_to_turn_steps_clear_of_it_first():
    """Two emulated falls (T3, stops 50 and 51) turned on the spot 0.22–0.24 m from the box's face after losing
    it and met the box with a leg. Nearer than TURN_CLEARANCE the approach steps along the heading away
    from the box (backward where the box is ahead, forward where it is behind), without turning; clear of
    it, it turns on the spot as before."""
    from amhe_cli.control.tasks import CLEAR_SPEED, TURN_CLEARANCE, box_clearance
    task = get_task("t4")
    box = np.array([1.9, 0.0])
    # slid off the box's side, the box 0.40 m to the left and a little ahead (as in the falls)
    base = box + [-0.10, -0.40]
    assert box_clearance(base, box, 0.0, HALF_DEPTH, HALF_DEPTH) == pytest.approx(0.40 - HALF_DEPTH)
    cmd = task.command(base, 0.0, box, HALF_DEPTH)
    assert cmd["phase"] == "approach" and cmd.get("clearing")
    assert cmd["speed"] == -CLEAR_SPEED and cmd["omega"] == 0.0 and cmd["yaw"] == 0.0
    assert cmd["box_speed"] == 0.0
    ref = task.waypoint_reference(cmd, np.array([0.0, 1.0, 100.0]))  # its reference backs away at that speed
    np.testing.assert_allclose(ref[1], base - [CLEAR_SPEED, 0.0], atol=1e-12)
    np.testing.assert_allclose(ref[2], base - [TURN_CLEARANCE, 0.0], atol=1e-12)
    # the box beside and a little behind: forward
    fwd = task.command(box + [0.10, -0.40], 0.0, box, HALF_DEPTH)
    assert fwd.get("clearing") and fwd["speed"] == CLEAR_SPEED and fwd["omega"] == 0.0
    # a turned box counts by its own footprint: its corner nearer than its face would be
    assert box_clearance(box + [0.0, 0.45], box, np.pi / 4, HALF_DEPTH, HALF_DEPTH) == \
        pytest.approx(0.45 - HALF_DEPTH * np.sqrt(2))
    assert box_clearance(box, box, 0.3, HALF_DEPTH, HALF_DEPTH) == 0.0
    # clear of the box: turn on the spot, as before
    far = task.command(box + [-0.10, -0.40 - TURN_CLEARANCE], 0.0, box, HALF_DEPTH)
    assert far["phase"] == "approach" and not far.get("clearing")
    assert far["speed"] == 0.0 and abs(far["omega"]) > 0
    # facing its waypoint it walks on, near the box or not
    facing = float(np.arctan2(*(far["waypoint"] - base)[::-1]))
    walk = task.command(base, facing, box, HALF_DEPTH)
    assert not walk.get("clearing") and walk["speed"] > 0


def test_a_step_clear_of_the_box_goes_on_past_the_threshold_before_the_robot_turns():
    """An emulated T3 run (stop 71, seed 7) flipped between stepping clear and turning 32 times in 23 s as the
    trot's sway carried the measured clearance across TURN_CLEARANCE (0.297–0.303 m at the flips). An approach's
    step clear now goes on to TURN_CLEARANCE + CLEAR_HYSTERESIS; a robot not yet stepping starts only below
    TURN_CLEARANCE; a push's turn beside the box keeps the one threshold. The closed loop carries the flag."""
    from amhe_cli.control.closed_loop import measured_command
    from amhe_cli.control.tasks import CLEAR_HYSTERESIS, TURN_CLEARANCE, box_clearance
    task = get_task("t4")
    box = np.array([1.9, 0.0])
    between = box + [-0.10, -HALF_DEPTH - TURN_CLEARANCE - CLEAR_HYSTERESIS / 2]  # 0.325 m from the box's side
    assert TURN_CLEARANCE < box_clearance(between, box, 0.0, HALF_DEPTH, HALF_DEPTH) < TURN_CLEARANCE + CLEAR_HYSTERESIS
    turning = task.command(between, 0.0, box, HALF_DEPTH)
    assert not turning.get("clearing") and turning["speed"] == 0.0 and abs(turning["omega"]) > 0
    stepping = task.command(between, 0.0, box, HALF_DEPTH, clearing=True)
    assert stepping["clearing"] and stepping["speed"] != 0.0 and stepping["omega"] == 0.0
    beyond = box + [-0.10, -HALF_DEPTH - TURN_CLEARANCE - CLEAR_HYSTERESIS - 0.01]
    assert not task.command(beyond, 0.0, box, HALF_DEPTH, clearing=True).get("clearing")
    # not in the push: a longer step beside the box left the push zone (push and approach took turns)
    pushing = box - [HALF_DEPTH + TURN_CLEARANCE + CLEAR_HYSTERESIS / 2, 0.0]
    beside = task.command(pushing, np.radians(-75.0), box, HALF_DEPTH, phase="push", clearing=True)
    assert beside["phase"] == "push" and beside["beside"] and not beside.get("clearing")
    # through the loop's helper, from a measured state
    from amhe_cli.model.scene import Scene, SceneConfig
    sc = Scene(SceneConfig())
    q = sc.model.qpos0.copy()
    q[sc.base_qpos[:2]], q[sc.box_qpos[:2]] = between, box
    assert measured_command(task, sc, q, 1.0, phase="approach", clearing=True)[0]["clearing"]
    assert not measured_command(task, sc, q, 1.0, phase="approach")[0].get("clearing")


def test_a_push_with_the_box_beside_the_robot_turns_to_face_it_instead_of_walking():
    """An emulated T3 fall (machine L): in the push zone, 60–100° off the push heading, the box at the
    robot's side blocked its turn; it walked on beside the box for 5 s until a hind leg caught the box's
    corner. With the box's nearest point more than BESIDE off the heading, the push turns on the spot (or
    steps clear first); with the box ahead of the head the same heading error still pushes (T2's turns)."""
    from amhe_cli.control.tasks import BESIDE, CLEAR_SPEED, TURN_CLEARANCE, TURN_IN_PLACE, box_clearance, box_nearest
    task = get_task("t4")
    box = np.array([1.0, 0.0])  # pushed along +x (the goal at x = 2)
    base = box - [0.40, 0.0]  # on the push line, in the push zone
    heading = np.radians(-75.0)  # turned right: the box's nearest point lies 75° to its left
    near = box_nearest(base, box, 0.0, HALF_DEPTH, HALF_DEPTH)
    np.testing.assert_allclose(near, box - [HALF_DEPTH, 0.0])  # the rear face's centre
    cmd = task.command(base, heading, box, HALF_DEPTH)
    assert cmd["phase"] == "push" and cmd["beside"] and cmd["box_speed"] == 0.0
    assert box_clearance(base, box, 0.0, HALF_DEPTH, HALF_DEPTH) < TURN_CLEARANCE
    assert cmd["clearing"] and abs(cmd["speed"]) == CLEAR_SPEED and cmd["omega"] == 0.0
    # clear of the box: it turns on the spot toward the push, left
    far = task.command(box - [HALF_DEPTH + TURN_CLEARANCE + 0.01, 0.0], heading, box, HALF_DEPTH)
    assert far["phase"] == "push" and far["beside"] and not far.get("clearing")
    assert far["speed"] == 0.0 and far["omega"] > 0 and far["box_speed"] == 0.0
    # 45° off with the box ahead of the head plate (T2's box turning under it) still pushes
    ahead = task.command(base, np.radians(-45.0), box, HALF_DEPTH)
    assert abs(np.radians(-45.0) - ahead["yaw"]) > TURN_IN_PLACE
    assert np.radians(45.0) < BESIDE  # the rear face's centre, dead ahead of the base, 45° to the heading's left
    assert ahead["phase"] == "push" and not ahead.get("beside") and ahead["speed"] > 0
    # and within TURN_IN_PLACE of the push heading it pushes whatever the bearing
    assert not task.command(base, 0.0, box, HALF_DEPTH).get("beside")


def test_the_push_zone_takes_the_box_turn_and_enters_with_hysteresis():
    """An emulated T4 run (machine L) stood beside a box turned 50°, 0.16–0.22 m behind its centre and 0.4 m off
    the push line, and lost and regained the box 10 times in 7 s: the zone's front edge took the box unturned
    (0.19 m back), and nothing held a phase once taken."""
    from amhe_cli.control.tasks import LINE_TOLERANCE, PHASE_HYSTERESIS, PUSH_ZONE
    task = get_task("t4")
    box = np.array([1.0, 0.0])  # pushed along +x
    corner = box + [-0.20, -0.40]  # the episode's stance, facing the push
    assert task.command(corner, 0.0, box, HALF_DEPTH)["phase"] == "push"  # an unturned box: behind it
    turned = np.radians(50.0)  # the box reaches 0.19 (cos 50° + sin 50°) = 0.27 m back
    assert task.command(corner, 0.0, box, HALF_DEPTH, box_yaw=turned)["phase"] == "approach"
    behind = box + [-(0.19 * (np.cos(turned) + np.sin(turned)) + 0.01), -0.40]
    assert task.command(behind, 0.0, box, HALF_DEPTH, box_yaw=turned)["phase"] == "push"
    assert task.command(corner, 0.0, box, HALF_DEPTH, box_yaw=-turned)["phase"] == "approach"  # either way
    # hysteresis: just inside each edge the phase stays what it was; well inside, the approach ends
    edges = {"front": [-(HALF_DEPTH + PUSH_ZONE[0]) - PHASE_HYSTERESIS / 2, 0.0],
             "side": [-(HALF_DEPTH + HEAD_REACH), HALF_DEPTH + LINE_TOLERANCE - PHASE_HYSTERESIS / 2],
             "back": [-(HALF_DEPTH + HEAD_REACH + PUSH_ZONE[1]) + PHASE_HYSTERESIS / 2, 0.0]}
    for edge, rel in edges.items():
        base = box + rel
        for prev, expected in ((None, "push"), ("push", "push"), ("approach", "approach")):
            assert task.command(base, 0.0, box, HALF_DEPTH, phase=prev)["phase"] == expected, (edge, prev)
    inside = box - [HALF_DEPTH + HEAD_REACH, 0.0]
    assert task.command(inside, 0.0, box, HALF_DEPTH, phase="approach")["phase"] == "push"
    outside = box - [HALF_DEPTH - 0.01, HALF_DEPTH + HEAD_REACH]  # past the front edge: approach whatever came before
    assert task.command(outside, 0.0, box, HALF_DEPTH, phase="push")["phase"] == "approach"


def test_t1_speed_command_slows_to_its_floor_at_goal_and_a_bad_floor_is_refused():
    task = get_task("t1")
    goal = np.asarray(task.goal)

    def cmd(box):  # the robot in its pushing pose behind the box
        box = np.asarray(box, dtype=float)
        return task.command(box - [HALF_DEPTH + HEAD_REACH, 0.0], 0.0, box, HALF_DEPTH)

    far, mid, near = cmd(task.box_start), cmd(goal - [0.2, 0.0]), cmd(goal - [0.5 * task.goal_tol, 0.0])
    assert far["speed"] == pytest.approx(0.2) and far["box_speed"] == pytest.approx(0.2)
    assert task.slow_floor * 0.2 < mid["speed"] < far["speed"]
    # a force-limited push still gets a command at the goal (a μ 0.8 box crept 0.15 m for 30 s without)
    assert near["speed"] == pytest.approx(task.slow_floor * 0.2) and near["speed"] > 0
    assert near["box_speed"] == pytest.approx(task.slow_floor * 0.2)
    assert get_task("t1", slow_floor=0.0).command(
        goal - [HALF_DEPTH + HEAD_REACH, 0.0], 0.0, goal, HALF_DEPTH)["speed"] == 0.0
    with pytest.raises(AmheError, match="slow_floor"):
        get_task("t1", slow_floor=1.5)


def test_box_reference_never_passes_target():
    task = get_task("t1")
    box = np.array([1.8, 0.0])
    cmd = task.command(box - [HALF_DEPTH + HEAD_REACH, 0.0], 0.0, box, HALF_DEPTH)
    tau = np.linspace(0.0, 100.0, 2001)
    ref = task.box_reference(cmd, tau)
    assert ref.shape == (len(tau), 2)
    np.testing.assert_allclose(ref[0], box)
    assert np.all(ref[:, 0] <= task.goal[0] + 1e-12)
    assert np.all(np.diff(ref[:, 0]) >= 0)
    np.testing.assert_allclose(ref[-1], task.goal)
    # it moves at the commanded box speed before it gets there
    assert task.box_reference(cmd, 0.1)[0] - box[0] == pytest.approx(0.1 * cmd["box_speed"])


UPRIGHT = np.array([1.0, 0, 0, 0])


def still_cost(task, height=BASE_HEIGHT, box_quat=None):
    """Stage cost of the robot standing still at the origin at ``height``, the box resting at its start."""
    cmd = task.command(np.zeros(2), 0.0, np.array(task.box_start), HALF_DEPTH)
    zero = np.zeros(3)
    return float(task.stage_cost(np.array([0.0, 0.0, height]), UPRIGHT, zero, zero,
                                 np.array([*task.box_start, 0.19]), STAND_JOINTS, STAND_JOINTS, cmd,
                                 box_quat=box_quat))


def test_stage_cost_penalises_a_fallen_base():
    task = get_task("t1")
    cmd = task.command(np.zeros(2), 0.0, np.array(task.box_start), HALF_DEPTH)
    quat, box = UPRIGHT, np.array([*task.box_start, 0.19])
    nominal, fallen = still_cost(task), still_cost(task, 0.1)
    assert fallen > nominal + task.weights.fall
    # vectorised over leading axes
    c = task.stage_cost(np.array([[0, 0, BASE_HEIGHT], [0, 0, 0.1]]), np.tile(quat, (2, 1)), np.zeros((2, 3)),
                        np.zeros((2, 3)), np.tile(box, (2, 1)), np.tile(STAND_JOINTS, (2, 1)),
                        np.tile(STAND_JOINTS, (2, 1)), cmd)
    np.testing.assert_allclose(c, [nominal, fallen])


def test_approach_keeps_the_trunk_out_of_the_box_s_reach_and_pushing_does_not():
    """Walking around the box (approach phase) a trunk within KEEP_OUT of the box's centre costs more, the nearer
    the more; pushing, where the head must touch the box, it costs nothing extra."""
    from amhe_cli.control.tasks import KEEP_OUT
    task = get_task("t1")
    box = np.array([1.0, 0.0])
    past = task.command(np.array([1.0, 0.45]), 0.0, box, HALF_DEPTH)  # beside the box: approach
    push = task.command(np.array([0.45, 0.0]), 0.0, box, HALF_DEPTH)
    assert past["phase"] == "approach" and push["phase"] == "push"

    def cost(cmd, xy, keep_out):
        t = get_task("t1", weights=CostWeights(keep_out=keep_out))
        return float(t.stage_cost(np.array([*xy, BASE_HEIGHT]), UPRIGHT, np.zeros(3), np.zeros(3),
                                  np.array([*box, 0.19]), STAND_JOINTS, STAND_JOINTS, cmd))
    for xy, extra in (((1.0, 0.45), 500 * (KEEP_OUT - 0.45) ** 2), ((1.0, 0.35), 500 * (KEEP_OUT - 0.35) ** 2),
                      ((1.0, 0.60), 0.0)):
        assert cost(past, xy, 500.0) - cost(past, xy, 0.0) == pytest.approx(extra)
    assert cost(push, (0.45, 0.0), 500.0) == cost(push, (0.45, 0.0), 0.0)


def test_the_waypoint_reference_moves_at_the_commanded_speed_so_a_lunge_costs_more():
    """Walking to a far waypoint, the trunk's reference moves from where it stood at the commanded speed:
    a trunk that surges ahead of it pays, where a fixed waypoint paid it for every centimetre gained."""
    task = get_task("t1")
    box = np.array([1.0, 0.0])
    heading = task.command(np.array([1.0, 0.6]), 0.0, box, HALF_DEPTH)["yaw"]
    cmd = task.command(np.array([1.0, 0.6]), heading, box, HALF_DEPTH)  # beside the box, facing the waypoint
    assert cmd["phase"] == "approach" and cmd["speed"] > 0
    start, goal = cmd["base"], cmd["waypoint"]
    dist = np.linalg.norm(goal - start)
    ref = task.waypoint_reference(cmd, np.array([0.0, 0.5, 100.0]))
    np.testing.assert_allclose(ref[0], start)
    np.testing.assert_allclose(np.linalg.norm(ref[1] - start), cmd["speed"] * 0.5)
    np.testing.assert_allclose(ref[2], goal)  # never past the waypoint
    assert np.linalg.norm(ref[1] - start) < dist

    def cost(xy, tau, c=cmd):
        return float(task.stage_cost(np.array([*xy, BASE_HEIGHT]), UPRIGHT, np.zeros(3), np.zeros(3),
                                     np.array([*box, 0.19]), STAND_JOINTS, STAND_JOINTS, c, tau))
    on_pace, surged = ref[1], start + (goal - start) / dist * min(2.5 * cmd["speed"] * 0.5, dist)
    assert cost(on_pace, 0.5) < cost(surged, 0.5)
    fixed = {**cmd, "base": None}  # the executed cost J: the waypoint itself, as before
    assert cost(surged, 0.5, fixed) < cost(on_pace, 0.5, fixed)
    # turning in place (speed 0) or recovering: held where it stands
    np.testing.assert_allclose(task.waypoint_reference({**cmd, "speed": 0.0}, 0.5), start)
    # the one-leg push keeps its stance point
    t5 = get_task("t5")
    c5 = t5.command(np.array(t5.robot_pose[:2]) + 0.05, t5.robot_pose[2], np.array(t5.box_start), HALF_DEPTH)
    np.testing.assert_allclose(t5.waypoint_reference(c5, 0.5), c5["waypoint"])


def test_a_heading_rate_turns_the_heading_reference_so_a_twist_costs_more():
    """With ``heading_rate``, turning round toward a far heading in the approach, the trunk's heading
    reference turns from where it faced at that rate: a trunk twisting faster pays, where a fixed heading
    (the default) paid it for every degree gained. The push keeps its fixed heading."""
    from amhe_cli.control.tasks import MAX_YAW_RATE
    task = get_task("t1", heading_rate=MAX_YAW_RATE)
    box = np.array([1.0, 0.0])
    cmd = task.command(np.array([1.6, 0.1]), 0.0, box, HALF_DEPTH)  # past the box, facing away from it
    assert cmd["phase"] == "approach" and abs(cmd["yaw"]) > 2.0
    err = float(np.angle(np.exp(1j * cmd["yaw"])))
    ref = task.heading_reference(cmd, np.array([0.0, 0.5, 100.0]))
    assert ref[0] == pytest.approx(0.0)
    assert ref[1] == pytest.approx(np.sign(err) * MAX_YAW_RATE * 0.5)
    assert np.angle(np.exp(1j * (ref[2] - cmd["yaw"]))) == pytest.approx(0.0, abs=1e-12)  # never past it

    def cost(yaw, tau, c=cmd):
        q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
        return float(task.stage_cost(np.array([1.6, 0.1, BASE_HEIGHT]), q, np.zeros(3), np.zeros(3),
                                     np.array([*box, 0.19]), STAND_JOINTS, STAND_JOINTS, c, tau))
    on_pace, twisted = ref[1], 3 * ref[1]
    assert cost(on_pace, 0.5) < cost(twisted, 0.5)
    fixed = {**cmd, "base": None}  # the executed cost J: the heading itself, as before
    assert cost(twisted, 0.5, fixed) < cost(on_pace, 0.5, fixed)
    assert get_task("t1").heading_reference(cmd, 0.5) == cmd["yaw"]  # the default: fixed
    assert run_settings("t1", "true", {"task": {"heading_rate": 0.45}})[0].heading_rate == 0.45  # a run config's
    for bad in (-0.1, "fast"):
        with pytest.raises(AmheError, match="heading_rate"):
            get_task("t1", heading_rate=bad)
    # the push steers back to its line at once; so does the one-leg push
    near = task.command(np.array([0.4, 0.05]), 0.3, box, HALF_DEPTH)
    assert near["phase"] == "push" and abs(near["yaw"] - 0.3) > 0.2
    assert task.heading_reference(near, 0.1) == near["yaw"]
    t5 = get_task("t5", heading_rate=MAX_YAW_RATE)
    c5 = t5.command(np.array(t5.robot_pose[:2]) + 0.05, t5.robot_pose[2] + 0.3, np.array(t5.box_start), HALF_DEPTH)
    assert t5.heading_reference(c5, 0.1) == c5["yaw"]


def test_stage_cost_penalises_a_tipped_box_not_its_yaw():
    from amhe_cli.io.quat import quat_from_rotvec
    task = get_task("t4")
    level = still_cost(task, box_quat=UPRIGHT)
    assert still_cost(task, box_quat=quat_from_rotvec(np.array([0.0, 0.0, 0.7]))) == pytest.approx(level)  # yawed
    tipped = still_cost(task, box_quat=quat_from_rotvec(np.array([0.0, np.radians(8.0), 0.0])))
    assert tipped - level == pytest.approx(task.weights.box_tilt * (1 - np.cos(np.radians(8.0))), rel=1e-9)


def test_one_leg_push_reaches_around_the_box_then_presses_its_face():
    """T5's reach: beside the face behind the box's near side first, then along the face, then pressing it
    (REACH_PRESS deep) and moving with the push; a turned box is met on its turned face."""
    task = get_task("t5")
    box = np.array(task.box_start)
    half = HALF_DEPTH
    fr = LEGS.index("FR")

    def world(cmd):  # the reach's foot target in the world (the robot at the origin, facing +x)
        return cmd["reach"]["foot"][:2]
    early = task.command(np.zeros(2), 0.0, box, half, t=0.1)
    assert early["reach"]["phase"] == "reach" and early["speed"] == 0.0
    foot = world(early)
    assert foot[0] < box[0] - half - FOOT_RADIUS  # behind the box's near side ...
    assert foot[1] > box[1] + half + FOOT_RADIUS  # ... and beside its left face: clear of the box
    push = task.command(np.zeros(2), 0.0, box, half, t=REACH_TIMES[1] + 0.1)
    r = push["reach"]
    assert r["phase"] == "push"
    foot = world(push)
    assert foot[1] == pytest.approx(box[1] + half + FOOT_RADIUS - REACH_PRESS)  # pressed into the left face
    assert box[0] - half < foot[0] < box[0] + half  # on the face
    np.testing.assert_allclose(r["velocity"], [0.0, -push["box_speed"], 0.0], atol=1e-12)  # along the push
    rel = r["foot"] - HIP_POS[fr]
    assert np.sum(rel ** 2) - 0.08 ** 2 <= REACH_LEG ** 2 + 1e-12  # a point the leg reaches
    # the gait turns it into the FR joints whose foot is there
    ref = GAITS["tripod"].reference(r["t0"], reach=r)
    np.testing.assert_allclose(HIP_POS[fr] + leg_fk3(ref[:3], -1.0), r["foot"], atol=1e-9)
    # a box turned by 0.3 rad: the target lies on the turned face (pressed into it along the push)
    turned = task.command(np.zeros(2), 0.0, box, half, t=REACH_TIMES[1] + 0.1, box_yaw=0.3)
    normal = np.array([-np.sin(0.3), np.cos(0.3)])
    assert (world(turned) - box) @ normal == pytest.approx(half + (FOOT_RADIUS - REACH_PRESS) * np.cos(0.3))


def test_a_placed_one_leg_push_keeps_the_robot_where_it_stands_and_reaches_the_same():
    """Placed in a lab (robot at (1, 2) facing +y), T5's stance, heading, push direction and the foot's reach in
    the trunk frame are the task's own, moved with the robot."""
    task = get_task("t5")
    yaw, robot = np.pi / 2, np.array([1.0, 2.0])
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    box = robot + rot @ np.array(task.box_start)
    placed = task.placed(robot, yaw, box)
    t = REACH_TIMES[1] + 0.1
    here = task.command(np.zeros(2), 0.0, np.array(task.box_start), HALF_DEPTH, t=t)
    there = placed.command(robot, yaw, box, HALF_DEPTH, t=t, box_yaw=yaw)
    np.testing.assert_allclose(there["waypoint"], robot + rot @ here["waypoint"], atol=1e-12)
    np.testing.assert_allclose(there["direction"], rot @ here["direction"], atol=1e-12)
    assert there["yaw"] == pytest.approx(yaw)
    np.testing.assert_allclose(there["reach"]["foot"], here["reach"]["foot"], atol=1e-12)
    np.testing.assert_allclose(there["reach"]["velocity"], here["reach"]["velocity"], atol=1e-12)


def test_one_leg_push_costs_a_turned_box():
    from amhe_cli.io.quat import quat_from_rotvec
    task = get_task("t5")
    level = still_cost(task, box_quat=UPRIGHT)
    turned = still_cost(task, box_quat=quat_from_rotvec(np.array([0.0, 0.0, 0.4])))
    assert turned - level == pytest.approx(task.weights.box_yaw * (1 - np.cos(0.4)), rel=1e-9)


# -- modes: only the planner's parameters differ ---------------------------------------

def test_modes_differ_only_in_planner_parameters():
    task = get_task("t1")
    truth = {"box_mass": 4.0, "box_friction": 0.5}
    p_true, s_true = make_planner(task, small_settings("true"), None, truth)
    p_base, s_base = make_planner(task, small_settings("baseline"), belief(6.0, 0.3), truth)
    try:
        mt, mb = p_true._models[0], p_base._models[0]
        box = p_true.scene.box_body
        pairs = p_true.scene.region_pairs
        assert mt.body_mass[box] == pytest.approx(4.0)
        assert mb.body_mass[box] == pytest.approx(6.0)
        np.testing.assert_allclose(mt.pair_friction[pairs, 0], 0.5)
        np.testing.assert_allclose(mb.pair_friction[pairs, 0], 0.3)
        # an inertia absent from the belief follows its mass
        np.testing.assert_allclose(mb.body_inertia[box], mt.body_inertia[box] * 6.0 / 4.0)
        # every model copy of a planner holds the same parameters
        for m in p_base._models:
            assert m.body_mass[box] == pytest.approx(6.0)
        robot = np.arange(mt.nbody) != box
        np.testing.assert_array_equal(mt.body_mass[robot], mb.body_mass[robot])
        np.testing.assert_array_equal(mt.actuator_gainprm, mb.actuator_gainprm)
        np.testing.assert_array_equal(mt.actuator_biasprm, mb.actuator_biasprm)
        np.testing.assert_array_equal(mt.geom_friction, mb.geom_friction)
        np.testing.assert_array_equal(mt.geom_size, mb.geom_size)
        assert mt.opt.timestep == mb.opt.timestep == pytest.approx(p_true.settings.dt)
        assert s_true.labels == s_base.labels
    finally:
        p_true.close()
        p_base.close()


def test_a_belief_of_a_robot_unlike_its_model_gives_the_planner_and_the_mhe_that_robot():
    """An emulated Go1 with 1.5 kg on its trunk, head-plate friction 0.8 and motors at 85 % fell in 2 of 64
    runs planned with the nominal robot, 1 of 64 with a belief identify read from a recording of it (its servo
    from the joint efforts, its motors' limits where the efforts plateau, its payload). The belief's robot side
    (torque limits included) reaches both models; a belief that cannot say
    what share of the commanded gains acts leaves the servo as commanded."""
    from amhe_cli.control.closed_loop import make_estimator, run_robot_side
    from amhe_cli.control.robot_side import robot_side
    task = get_task("t3")
    s = small_settings("baseline")
    b = Belief(values={"box_mass": 4.0, "box_friction": 0.5, "trunk_payload": 1.5, "robot_box_friction": 0.8},
               std={"box_mass": 0.5, "box_friction": 0.05}, free=["box_mass", "box_friction"],
               scene={"kp": [0.85 * s.kp] * 12, "kd": [0.85 * s.kd] * 12,
                      "torque_limit": [20.1, 20.1, 30.2] * 4},
               provenance={"sensors": {"gains": {"logged_kp": [s.kp] * 12, "logged_kd": [s.kd] * 12}}})
    side = run_robot_side(s, b, {})
    assert "servo 0.85 × Kp, 0.85 × Kd" in side.source and "+1.50 kg" in side.source
    assert "torque limits 20.1–30.2 N·m" in side.source
    nominal, _ = make_planner(task, s, belief(4.0, 0.5), {})
    planner, _ = make_planner(task, s, b, {}, side=side)
    mhe = make_estimator(task, replace(s, mode="adaptive"), 0.002, {"box_mass": 4.0, "box_friction": 0.5,
                                                                     "robot_box_friction": 0.8}, side=side)
    try:
        for m in (planner._models[0], mhe.scene.model):
            trunk = m.body("trunk").id
            assert m.body_mass[trunk] == pytest.approx(nominal._models[0].body_mass[trunk] + 1.5)
            np.testing.assert_allclose(m.actuator_gainprm[:, 0], 0.85 * s.kp)
            np.testing.assert_allclose(-m.actuator_biasprm[:, 2], 0.85 * s.kd)
            np.testing.assert_allclose(m.actuator_forcerange[:, 1], [20.1, 20.1, 30.2] * 4)
        np.testing.assert_allclose(nominal._models[0].actuator_forcerange[:, 1], [23.7, 23.7, 35.55] * 4)
        pm, nm = planner._models[0], nominal._models[0]
        changed = nm.geom_friction[:, 0] != pm.geom_friction[:, 0]
        assert changed.any() and np.all(pm.geom_friction[changed, 0] == pytest.approx(0.8))
    finally:
        nominal.close(), planner.close(), mhe.close()
    # the log's commanded gains unknown: the share is unknown, the servo stays as commanded
    blind = replace(b, provenance={"sensors": {"gains": {"logged_kp": None, "logged_kd": None}}})
    side = robot_side(s.kp, s.kd, belief=blind)
    assert side.kp == (s.kp,) * 12 and side.trunk_payload == 1.5 and "unknown" in side.source
    # another controller's gains (55 acting where 100 was never commanded) are not this servo's
    odd = replace(b, scene={"kp": [20.0] * 12, "kd": [0.85 * s.kd] * 12})
    assert robot_side(s.kp, s.kd, belief=odd).kp == (s.kp,) * 12
    # a nominal belief and the nominal truth leave the robot as the model has it
    for side in (robot_side(s.kp, s.kd, belief=belief(4.0, 0.5)),
                 robot_side(s.kp, s.kd, truth=make_plant(task, s.kp, s.kd).truth_values)):
        assert side.kp == (s.kp,) * 12 and side.kd == (s.kd,) * 12 and side.trunk_payload == 0.0 and not side.source


def test_a_robot_belief_gives_its_robot_and_the_box_belief_its_box():
    """``run_task(..., robot=B)`` (``amhe run --robot-belief``): the planner models B's robot (here a servo
    at 0.85 × the commanded gains and 1.5 kg on the trunk) and plans with the box of the run's own belief,
    not B's; the run's log says which robot it planned for."""
    s = small_settings("baseline")
    robot = Belief(values={"box_mass": 9.0, "box_friction": 0.9, "trunk_payload": 1.5},
                   std={"box_mass": 0.5, "box_friction": 0.05}, free=["box_mass", "box_friction"],
                   scene={"kp": [0.85 * s.kp] * 12, "kd": [0.85 * s.kd] * 12},
                   provenance={"sensors": {"gains": {"logged_kp": [s.kp] * 12, "logged_kd": [s.kd] * 12}}})
    r = run_task(get_task("t1", duration=0.1), belief(5.0, 0.3), s, robot=robot)
    assert any("servo 0.85 × Kp" in m and "+1.50 kg" in m for m in r.messages), r.messages
    est_v = r.estimates[1]
    assert est_v[0, r.labels.index("box_mass")] == pytest.approx(5.0)
    assert est_v[0, r.labels.index("box_friction")] == pytest.approx(0.3)
    plain = run_task(get_task("t1", duration=0.1), belief(5.0, 0.3), s)
    assert not any("planner's robot" in m for m in plain.messages)


def test_baseline_planner_needs_a_belief():
    with pytest.raises(AmheError, match="belief"):
        make_planner(get_task("t1"), small_settings("baseline"), None, {"box_mass": 4.0})
    with pytest.raises(AmheError, match="belief"):
        run_task(get_task("t1", duration=0.1), None, small_settings("adaptive"))


# -- closed-loop runs ------------------------------------------------------------------

T3_EARLY = dict(duration=0.5, events=(Event("box_mass", 6.0, t=0.1),))


def test_t3_event_changes_plant_not_baseline_planner():
    task = get_task("t3", **T3_EARLY)
    r = run_task(task, belief(5.0, 0.3), small_settings("baseline"))
    ts = r.traj.meta["truth_series"]
    assert ts["box_mass"][0] == 4.0 and ts["box_mass"][-1] == 6.0
    t_switch = ts["t"][np.argmax(ts["box_mass"] == 6.0)]
    assert t_switch == pytest.approx(0.1, abs=0.011)
    assert r.traj.meta["truth"]["box_mass"] == 4.0  # truth at the start
    col = r.labels.index("box_mass")
    est_t, est_v, _ = r.estimates
    np.testing.assert_array_equal(est_v[:, col], 5.0)
    assert len(est_t) == 1  # the planner's parameters never changed
    assert any("plant event box_mass -> 6.0" in m for m in r.messages)
    assert r.traj.t[-1] == pytest.approx(0.5, abs=0.003)


def test_t3_event_reaches_true_mode_planner():
    task = get_task("t3", **T3_EARLY)
    r = run_task(task, None, small_settings("true"))
    col = r.labels.index("box_mass")
    est_t, est_v, est_s = r.estimates
    assert est_v[0, col] == pytest.approx(4.0)
    assert 6.0 in est_v[:, col]
    assert np.all(est_t[est_v[:, col] == 6.0] >= 0.1 - 1e-9)
    np.testing.assert_array_equal(est_s, 0.0)  # the truth has no uncertainty
    # inertia follows the new mass in the planner too
    i0 = r.labels.index("box_inertia_0")
    assert est_v[-1, i0] == pytest.approx(est_v[0, i0] * 6.0 / 4.0)


@pytest.fixture(scope="module")
def t1_true_runs():
    task, settings = run_settings("t1", "true", {"planner": SMALL}, seed=0, threads=1, duration=1.5)
    return task, run_task(task, None, settings), run_task(task, None, settings)


def test_t5_one_leg_push_moves_the_box_sideways_on_three_legs():
    """T5 with the default planner: within 2.5 s the front-right foot has swept the box 15+ cm toward its goal
    (without its reach the box moved 2-3 cm in 20 s), the robot standing where it was."""
    task, settings = run_settings("t5", "true", None, seed=0, threads=2, duration=2.5)  # both CPUs: the same run
    r = run_task(task, None, settings)
    box, base = r.traj.box_pos, r.traj.base_pos
    assert box[0, 1] - box[-1, 1] >= 0.15  # sideways, to the right
    assert task.goal_error(box[-1, :2]) <= task.goal_error(box[0, :2]) - 0.15
    assert not r.fell and np.linalg.norm(base[-1, :2] - base[0, :2]) < 0.1


def test_a_recording_that_cannot_be_written_where_asked_is_kept_elsewhere_and_said(t1_true_runs, tmp_path,
                                                                                  monkeypatch):
    """A disk that fills during a robot run must not cost the run's recording: save_run writes it to a
    fresh temporary folder instead and its one-line error names where; if that fails too, it says so."""
    import amhe_cli.control.closed_loop as cl
    from amhe_cli.io.reader import read_log

    task, r, _ = t1_true_runs
    real, wanted = cl.write_mcap, tmp_path / "run.mcap"
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # the spare copy stays inside the test's folder

    def full_disk(path, *a, **kw):
        if path == wanted:
            raise OSError(28, "No space left on device")
        return real(path, *a, **kw)

    monkeypatch.setattr(cl, "write_mcap", full_disk)
    with pytest.raises(AmheError, match=r"No space left on device\): the run's recording is in (\S+) instead") as e:
        cl.save_run(r, wanted, task, small_settings("true"))
    spare = Path(str(e.value).rsplit(" is in ", 1)[1].split(" instead")[0])
    assert spare.name == "run.mcap" and spare.parent.parent == tmp_path / "tmp"
    np.testing.assert_array_equal(read_log(spare).box_pos[:, 0], r.traj.box_pos[:, 0])
    assert spare.with_name("run.truth.csv").is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["tmp"]  # no half-written file where the user asked

    monkeypatch.setattr(cl, "write_mcap", lambda *a, **kw: (_ for _ in ()).throw(OSError(28, "No space left on device")))
    with pytest.raises(AmheError, match="nor a copy in .*: the run's recording is lost"):
        cl.save_run(r, wanted, task, small_settings("true"))


def test_t1_closed_loop_makes_progress(t1_true_runs):
    task, r, _ = t1_true_runs
    box, base = r.traj.box_pos, r.traj.base_pos
    assert box[0, 0] == pytest.approx(0.52)
    assert box[-1, 0] - box[0, 0] >= 0.02 or base[-1, 0] - base[0, 0] >= 0.05
    assert not r.fell
    assert base[:, 2].min() > task.fall_height
    assert r.traj.t[-1] == pytest.approx(1.5, abs=0.003)
    assert r.traj.dt == pytest.approx(0.002)
    assert np.isfinite([r.e_g, r.J, r.t_exec, r.rmse]).all()
    assert r.e_g == pytest.approx(task.goal_error(box[-1, :2]))
    assert set(r.metrics()) == {"success", "e_g", "J", "t_exec", "rmse", "fell", "recoveries"}
    assert r.control_hz > 0


def test_t1_lock_step_is_reproducible(t1_true_runs):
    _, a, b = t1_true_runs
    np.testing.assert_array_equal(a.traj.box_pos, b.traj.box_pos)
    np.testing.assert_array_equal(a.traj.ctrl, b.traj.ctrl)


def test_the_wall_clocks_planner_and_mhe_differ_from_lock_steps_and_a_config_still_overrides_them():
    """On the wall clock, or a lock-step run that emulates it (``latency``), the planner samples fewer,
    narrower knots (REALTIME_PLANNER) and the MHE fuses its windows (REALTIME_MHE), with the library's
    steps and samples so an update fits its core; the lock-step run keeps the defaults; a config's keys win."""
    _, lock = run_settings("t4", "adaptive", {})
    assert (lock.planner.samples, lock.planner.refine_loops) == (30, 3)
    assert lock.planner.noise == pytest.approx((0.03, 0.05, 0.05))
    assert (lock.mhe.max_steps, lock.mhe.samples, lock.mhe.fuse) == (150, 10, False)
    for config, realtime in (({}, True), ({"latency": 0.035}, False)):
        _, wall = run_settings("t4", "adaptive", config, realtime=realtime)
        assert (wall.planner.samples, wall.planner.refine_loops) == (16, 1)
        assert wall.planner.noise == pytest.approx((0.015, 0.025, 0.025))
        assert wall.planner.recovery_noise == lock.planner.recovery_noise  # the recovery's search is not narrowed
        assert (wall.mhe.max_steps, wall.mhe.samples, wall.mhe.fuse) == (150, 10, True)
    _, mine = run_settings("t4", "adaptive", {"latency": 0.035, "planner": {"noise": [0.03, 0.05, 0.05]},
                                              "mhe": {"fuse": False, "max_steps": 300}})
    assert mine.planner.noise == pytest.approx((0.03, 0.05, 0.05)) and mine.planner.samples == 16
    assert not mine.mhe.fuse and mine.mhe.max_steps == 300


def test_the_mhe_shares_a_core_or_takes_its_own_its_duty_limit_defers_updates_and_it_builds_its_data_off_the_loop():
    """``mhe_cores`` below 1 keeps the planner on every CPU and holds the estimator thread to that share
    of one core; whole cores go to the MHE and off the planner; one that leaves the planner nothing is
    refused; the lock-step sim and modes without an MHE ignore it. Data given as a callable (a robot plant's
    recording) are built on the estimator's thread, not the control loop's."""
    wall = dict(mode="adaptive")
    assert core_split(RunSettings(**wall), clocked=True, cpus=OWN_CORE_FROM - 1) == (None, 1, MHE_DUTY)
    assert core_split(RunSettings(**wall), clocked=True, cpus=OWN_CORE_FROM) == (OWN_CORE_FROM - 1, 1, 1.0)
    assert core_split(RunSettings(**wall, mhe_cores=0.25), clocked=True, cpus=4) == (None, 1, 0.25)
    assert core_split(RunSettings(**wall, mhe_cores=1), clocked=True, cpus=4) == (3, 1, 1.0)
    assert core_split(RunSettings(**wall, mhe_cores=2, threads=5), clocked=True, cpus=4) == (5, 2, 1.0)
    assert core_split(RunSettings(**wall, mhe_cores=2), clocked=False, cpus=4) == (None, 1, 1.0)
    assert core_split(RunSettings(mode="baseline", mhe_cores=2), clocked=True, cpus=4) == (None, 1, 1.0)
    with pytest.raises(AmheError, match="leaves the planner none of the 2 CPU"):
        core_split(RunSettings(**wall, mhe_cores=2), clocked=True, cpus=2)
    for bad in (0, 1.5, -1):
        with pytest.raises(AmheError, match="mhe_cores"):
            RunSettings(**wall, mhe_cores=bad).check()
    assert run_settings("t4", "adaptive", {"mhe_cores": 2})[1].mhe_cores == 2
    own = run_task(get_task("t1", duration=0.6), belief(),
                   RunSettings(mode="adaptive", realtime=True, planner=PlannerSettings(**SMALL), mhe_cores=1,
                               threads=1))
    assert "the planner rolls out on 1 thread(s), the MHE on 1 core(s) of its own (mhe_cores)" in own.messages
    assert describe_split(RunSettings(mode="baseline"), clocked=True, cpus=4) == "the planner rolls out on 4 thread(s)"
    assert describe_split(RunSettings(**wall), clocked=True, cpus=2).endswith("busy at most 50% of a core (mhe_cores)")

    class Slow:  # an estimator whose update takes 0.2 s of wall time
        decided = 0  # line decisions on a thread of their own: none

        def update(self, traj, t):
            time.sleep(0.2)
            return Update(t, np.zeros(1), np.ones(1), float("nan"), 0, 0.2, True)

        def take_decision_errors(self):
            return []

        def close(self):
            pass

    thread = EstimatorThread(Slow())
    assert thread.rested(0.5) and thread.submit(None, 1.0)
    assert not thread.rested(1.0) and not thread.submit(None, 1.5)  # one update at a time
    assert thread.poll(wait=True).t == 1.0 and thread.poll_decision() is None
    assert thread.rested(1.0) and not thread.rested(0.5)  # at half a core it idles as long as it worked
    time.sleep(0.25)
    assert thread.rested(0.5)
    # data given as a callable (a robot plant's recording, resampled: 50 ms for 8 s of a Go1 run here) are built on
    # the estimator's thread, not the control loop's; a failure there is the update's, reported, the loop unharmed
    import threading
    built, t0 = [], time.monotonic()

    def data():
        time.sleep(0.3)
        built.append(threading.current_thread().name)
        return None

    assert thread.submit(data, 2.0) and time.monotonic() - t0 < 0.15 and not built
    assert thread.poll(wait=True).t == 2.0 and built == ["amhe-mhe"]

    def lost():
        raise RuntimeError("recording gone")

    assert thread.submit(lost, 2.5) and thread.poll(wait=True) is None
    assert [e for e in thread.take_errors() if "MHE update failed (RuntimeError: recording gone)" in e]
    thread.close()


def test_a_robot_run_whose_mhe_cores_leave_the_planner_nothing_stops_before_the_link(capsys, tmp_path):
    from amhe_cli.model.rollout import default_threads
    cpus = default_threads()  # what this process may use: an MHE of as many cores leaves the planner none
    if cpus > 64:
        pytest.skip("mhe_cores stops at 64")
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"mhe_cores: {cpus}\n")
    proc = amhe(capsys, "run", "--task", "t1", "--target", "go1", "--robot", "127.0.0.1:9", "--mode", "adaptive",
                "--config", str(bad), "--out", str(tmp_path / "r.mcap"))
    one_line_error(proc, f"mhe_cores {cpus} leaves the planner none of the {cpus} CPU(s)")
    assert not (tmp_path / "r.mcap").exists()


def test_an_emulated_latency_runs_the_wall_clocks_loop_the_same_on_every_run_and_is_refused_off_the_sim():
    task = get_task("t1", duration=0.4)
    runs = [run_task(task, None, small_settings("true", latency=0.04)) for _ in range(2)]
    # the plant ran the last plan's rows while each plan was "computed": four 10 ms rows a cycle + the new row
    assert len(runs[0].plan_times) == pytest.approx(0.4 / 0.05, abs=1)
    np.testing.assert_array_equal(runs[0].traj.base_pos, runs[1].traj.base_pos)  # not the machine's speed
    plain = run_task(task, None, small_settings("true"))  # lock-step: 20 ms a cycle, no lag
    assert len(plain.plan_times) == pytest.approx(0.4 / 0.02, abs=1)
    for bad, why in ((dict(latency=0.5), "compute time"), (dict(latency=0.03, realtime=True), "wall clock")):
        with pytest.raises(AmheError, match=why):
            small_settings("true", **bad).check()
    plant, closed = make_plant(task, 100.0, 4.0), []
    plant.close = closed.append  # a plant handed in (a robot's) is closed with the reason, never driven
    with pytest.raises(AmheError, match="robot has its own"):
        run_task(task, None, small_settings("true", latency=0.04), plant=plant)
    assert closed == ["latency needs the sim plant"]
    # the sim plant it makes itself, handed in (fall_forensics --replay-log sets its state first): the same run
    s = small_settings("true", latency=0.04)
    own = run_task(task, None, s, plant=make_plant(task, s.kp, s.kd, s.planner.dt, realtime=True, cycle=s.cycle))
    np.testing.assert_array_equal(own.traj.base_pos, runs[0].traj.base_pos)


def test_mhe_update_reaches_the_planner_with_inertia_following_mass():
    from amhe_cli.control.closed_loop import _to_planner, task_scene_config
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene

    task = get_task("t4")
    planner, space = make_planner(task, small_settings("baseline"), belief(5.0, 0.3), {})
    try:
        mspace = ParameterSpace(Scene(task_scene_config(task, 0.002, 100.0, 4.0)), free=("box_mass", "box_friction"),
                                prior=space.values(space.mean0))
        up = Update(1.0, np.array([6.0, 0.7]), np.array([0.2, 0.05]), 0.0, 3, 0.01, False)
        values, std = _to_planner(up, mspace, space)
    finally:
        planner.close()
    got = space.values(values)
    assert got["box_mass"] == pytest.approx(6.0) and got["box_friction"] == pytest.approx(0.7)
    np.testing.assert_allclose(got["box_inertia"], space.values(space.mean0)["box_inertia"] * 6.0 / 5.0)
    sl = space.slices()
    assert std[sl["box_mass"]][0] == 0.2 and std[sl["box_friction"]][0] == 0.05
    np.testing.assert_array_equal(std[sl["box_inertia"]], 0.0)  # held by the MHE, not estimated


def test_estimator_failure_never_stops_the_controller(monkeypatch):
    def broken(self, *args, **kwargs):
        raise RuntimeError("injected estimator fault")

    monkeypatch.setattr(MovingHorizonEstimator, "update", broken)
    task = get_task("t1", duration=1.5)
    r = run_task(task, belief(5.0, 0.3), small_settings("adaptive", mhe=MHESettings(window=0.5, every=0.25)))
    assert r.traj.t[-1] == pytest.approx(1.5, abs=0.003)
    failures = [m for m in r.messages if "MHE update failed" in m]
    assert failures and all("injected estimator fault" in m for m in failures)
    assert len(failures) >= 3  # updates at 0.5, 0.75, 1.0, 1.25 s all failed, and were all tried
    est_t, est_v, _ = r.estimates
    assert len(est_t) == 1  # the starting belief stays
    assert est_v[0, r.labels.index("box_mass")] == pytest.approx(5.0)


@pytest.mark.parametrize("shadow", [False, True])
def test_a_shadow_mhe_estimates_but_the_planner_keeps_its_starting_belief(monkeypatch, tmp_path, shadow):
    from mcap.reader import make_reader
    from amhe_cli.control import closed_loop as cl
    from amhe_cli.control.planner import Planner
    written = []
    real = Planner.set_params
    monkeypatch.setattr(Planner, "set_params", lambda self, v: (written.append(np.array(v)), real(self, v))[1])
    task = get_task("t1", duration=1.5)
    settings = small_settings("adaptive", mhe=MHESettings(window=0.5, every=0.25), mhe_shadow=shadow)
    r = run_task(task, belief(5.0, 0.3), settings)
    est_t, est_v, _ = r.estimates
    assert len(est_t) >= 3  # the MHE updated in both
    if shadow:
        assert len(written) == 1  # the starting belief, written when the planner was made, and nothing after
    else:
        assert len(written) == len(est_t)
    cl.save_run(r, tmp_path / "run.mcap", task, settings)
    with open(tmp_path / "run.mcap", "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["amhe_run"].get("mhe_shadow") == ("true" if shadow else None)  # a reader knows what was used


@pytest.mark.parametrize("realtime", [False, True])
def test_mhe_fill_sizes_updates_to_the_core_share_the_run_gives_it(monkeypatch, realtime):
    """``mhe: {fill}`` in a run: the estimator is told the duty of ``core_split`` (on the wall clock with
    one CPU: half a shared core; lock-step: 1), and the run's log states the step budgets it used."""
    from amhe_cli.estimation.mhe import MovingHorizonEstimator
    monkeypatch.setattr("amhe_cli.control.closed_loop.default_threads", lambda: 1)
    duties = []
    real = MovingHorizonEstimator.budget
    monkeypatch.setattr(MovingHorizonEstimator, "budget",
                        lambda self, *a: (duties.append(self.duty), real(self, *a))[1])
    task = get_task("t1", duration=3.0)  # the box moves within it, on a loaded machine's wall clock too
    settings = small_settings("adaptive", mhe=MHESettings(window=0.5, every=0.25, max_steps=40, fill=0.5),
                              realtime=realtime)
    r = run_task(task, belief(5.0, 0.3), settings)
    assert duties and set(duties) == {0.5 if realtime else 1.0}
    line = [m for m in r.messages if m.startswith("MHE step budget per candidate")]
    assert len(line) == 1 and "mhe fill 0.5: from max_steps 40 up to 160" in line[0]
    took = [m for m in r.messages if m.startswith("MHE updates took a median")]  # on the wall clock only
    assert len(took) == (1 if realtime else 0)
    if realtime:
        assert float(took[0].split()[5]) > 0 and "of the 0.25 s between them" in took[0]


def test_the_line_decisions_backend_loads_before_the_wall_clock_loop_not_at_the_first_decision(monkeypatch):
    """``mhe: {attribute_device}`` on the wall clock: the decisions' own backend rolls out once before the
    first cycle (on ``cuda`` that loads MuJoCo Warp's kernels, which at the first decision held the estimator
    for 5.9 s mid-run), and the run's log says so; lock-step, and a run without such a backend, do not."""
    from amhe_cli.estimation import attribution
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene, SceneConfig
    calls = []
    real = MovingHorizonEstimator.warm
    monkeypatch.setattr(MovingHorizonEstimator, "warm", lambda self, *a: (calls.append(self), real(self, *a))[1])
    task = get_task("t1", duration=0.3)
    said = {}
    for realtime, device in ((True, "cpu"), (False, "cpu"), (True, None)):
        mhe = MHESettings(window=0.5, every=0.25, max_steps=40, attribute=True, attribute_device=device)
        r = run_task(task, belief(5.0, 0.3), small_settings("adaptive", mhe=mhe, realtime=realtime))
        said[realtime, device] = [m for m in r.messages if m.startswith("the MHE's line decisions roll out on")]
    assert len(calls) == 2  # the wall clock's runs, before any update
    assert len(said[True, "cpu"]) == 1 and "on cpu (loaded in " in said[True, "cpu"][0]
    assert said[False, "cpu"] == [] and said[True, None] == []
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 4.0, "box_friction": 0.5})
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, attribute_device="cpu")) as m:
        rolled = []
        monkeypatch.setattr(m._decide_pool, "rollout_candidates",
                            lambda *a: rolled.append(a) or type(m._decide_pool).rollout_candidates(m._decide_pool, *a))
        assert real(m) > 0 and len(rolled) == 1  # one candidate, one clip, on the decisions' pool alone
        steps = int(round(0.2 / scene.model.opt.timestep))  # a clip's longest
        assert rolled[0][1].shape == (1, 2) and rolled[0][3].shape == (1, steps, scene.model.nu)
    # a GPU backend keeps a slot per width: each width the tests and decisions roll out is set up before the
    # loop too (the first test that seeks a change came at the change itself, and set its slot up then)
    monkeypatch.setattr(MovingHorizonEstimator, "_decide_on_gpu", property(lambda self: True))
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, attribute_device="cpu")) as m:
        rolled = []
        monkeypatch.setattr(m._decide_pool, "rollout_candidates", lambda *a: rolled.append(a))
        m.warm()
        widths = [(a[1].shape[0], a[2].shape[0]) for a in rolled]
        assert widths == [(1, 1)] + m.decision_batches() and len(widths) == 6
        assert (2 * attribution.FACTORS.size + 4 * (attribution.FACTORS.size - 1), attribution.CLIPS) in widths


def test_mhe_shadow_needs_the_adaptive_mode():
    with pytest.raises(AmheError, match="mhe_shadow .* needs mode adaptive, not baseline"):
        run_settings("t1", "baseline", {"mhe_shadow": True})
    with pytest.raises(AmheError, match="config key mhe_shadow: 'yes' is not true or false"):
        run_settings("t1", "adaptive", {"mhe_shadow": "yes"})
    assert run_settings("t1", "adaptive", {"mhe_shadow": True})[1].mhe_shadow


def test_an_exception_in_the_loop_closes_the_plant_with_its_reason_and_keeps_the_recording(monkeypatch):
    from amhe_cli.control.closed_loop import make_plant
    from amhe_cli.control.planner import Planner

    task = get_task("t1", duration=2.0)
    settings = small_settings("true")
    plant = make_plant(task, settings.kp, settings.kd, settings.planner.dt)
    closed = []
    monkeypatch.setattr(plant, "close", lambda reason=None: closed.append(reason))
    calls = {"n": 0}
    real_plan = Planner.plan

    def flaky(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:
            raise ValueError("injected planner fault")
        return real_plan(self, *args, **kwargs)

    monkeypatch.setattr(Planner, "plan", flaky)
    r = run_task(task, None, settings, plant=plant)
    assert closed == ["ValueError in the closed loop: injected planner fault"]  # a robot plant damps on this
    assert r.failure == closed[0] and not r.success
    assert any("run stopped" in w for w in r.warnings)
    assert len(r.traj) > 0 and r.traj.t[-1] == pytest.approx(4 * settings.cycle, abs=0.003)  # 4 cycles kept


# -- the run command -----------------------------------------------------------------

def test_run_unknown_task(capsys, tmp_path):
    one_line_error(amhe(capsys, "run", "--task", "t9", "--out", tmp_path / "r.mcap"), "t9")
    assert not (tmp_path / "r.mcap").exists()


def test_run_go1_refuses_true_mode_before_touching_the_network(capsys, tmp_path):
    # a real box's truth is unknown; the check comes before any socket is opened
    one_line_error(amhe(capsys, "run", "--target", "go1", "--mode", "true", "--robot", "127.0.0.1:9",
                        "--out", tmp_path / "r.mcap"), "true")
    assert not (tmp_path / "r.mcap").exists()


def test_run_bad_config(capsys, tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("plannr: {samples: 8}\n")
    one_line_error(amhe(capsys, "run", "--mode", "true", "--config", cfg, "--out", tmp_path / "r.mcap"), "plannr")
    cfg.write_text("planner: {sample: 8}\n")
    one_line_error(amhe(capsys, "run", "--mode", "true", "--config", cfg, "--out", tmp_path / "r.mcap"), "sample")
    cfg.write_text("mhe_params: box_mass,box_colour\n")
    one_line_error(amhe(capsys, "run", "--mode", "true", "--config", cfg, "--out", tmp_path / "r.mcap"), "box_colour")
    cfg.write_text("planner: {samples: 8, horizon: 20}\n")
    one_line_error(amhe(capsys, "run", "--mode", "true", "--config", cfg, "--duration", "0",
                        "--out", tmp_path / "r.mcap"), "--duration")
    for text, named in (("latency: fast\n", "latency"), ("kp: high\n", "kp"), ("latency: 0.5\n", "latency 0.5")):
        cfg.write_text(text)
        one_line_error(amhe(capsys, "run", "--mode", "true", "--config", cfg, "--out", tmp_path / "r.mcap"), named)
    assert not (tmp_path / "r.mcap").exists()


def test_run_json_records_and_refuses_to_overwrite(capsys, tmp_path):
    from amhe_cli.io.reader import read_log

    cfg = tmp_path / "c.yaml"
    cfg.write_text("planner: {samples: 8, horizon: 20}\n")
    mcap, csv = tmp_path / "r.mcap", tmp_path / "r.truth.csv"
    args = ["run", "--task", "t1", "--mode", "true", "--duration", "0.4", "--json", "--out", mcap,
            "--config", cfg, "--threads", "1"]
    code, out, err = amhe(capsys, *args)
    assert code == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1, out
    metrics = json.loads(lines[0])
    assert set(metrics) == {"success", "e_g", "J", "t_exec", "rmse", "fell", "recoveries", "reason"}  # 0.4 s: no goal
    assert isinstance(metrics["success"], bool) and not metrics["success"]
    assert metrics["reason"].startswith("time limit (0.4 s) reached with the box")
    assert metrics["t_exec"] == pytest.approx(0.4, abs=0.01)
    assert mcap.is_file() and csv.is_file()

    rows = csv.read_text().splitlines()
    assert rows[0] == "t,box_mass_kg,mu_floor_at_box_center"
    assert [float(x) for x in rows[1].split(",")] == pytest.approx([0.0, 4.0, 0.5])

    traj = read_log(str(mcap))
    assert traj.dt == pytest.approx(0.002)
    assert traj.t[-1] - traj.t[0] == pytest.approx(0.4, abs=0.02)
    assert abs(len(traj) - 200) <= 5
    assert traj.box_pos[0, 0] == pytest.approx(0.52, abs=1e-3)

    before = mcap.read_bytes()
    one_line_error(amhe(capsys, *args), "exists", "--force")
    assert mcap.read_bytes() == before


# -- evaluate's table ----------------------------------------------------------------

def test_summarise_gives_success_rate_and_mean_std_per_mode():
    def row(mode, success, e_g, J, t_exec, rmse):
        return {"task": "t1", "mode": mode, "seed": 0, "success": success, "e_g": e_g, "J": J, "t_exec": t_exec,
                "rmse": rmse, "fell": not success, "recoveries": 1, "control_hz": 50.0}

    rows = [row("true", True, 0.1, 1.0, 10.0, 0.05), row("true", False, 0.5, 3.0, 20.0, 0.15),
            row("true", True, 0.3, 2.0, 12.0, 0.10), row("true", True, 0.2, 2.0, 14.0, 0.10),
            row("baseline", False, 1.0, 5.0, 40.0, 0.2)]
    table = summarise(rows, ["baseline", "adaptive", "true"])
    assert [r["mode"] for r in table] == ["baseline", "true"]  # asked-for order; modes without rows left out
    base, true = table
    assert base["n"] == 1 and base["S_R"] == 0.0
    assert base["e_g"] == (pytest.approx(1.0), pytest.approx(0.0))
    assert true["n"] == 4 and true["S_R"] == pytest.approx(75.0)
    assert true["falls"] == 1 and true["recoveries"] == 4 and base["falls"] == 1
    for key, vals in (("e_g", [0.1, 0.5, 0.3, 0.2]), ("J", [1.0, 3.0, 2.0, 2.0]), ("t_exec", [10.0, 20.0, 12.0, 14.0]),
                      ("rmse", [0.05, 0.15, 0.1, 0.1])):
        assert true[key] == (pytest.approx(np.mean(vals)), pytest.approx(np.std(vals))), key
    json.dumps(table)  # plain floats: the --json table


def test_evaluate_keeps_rows_as_they_finish_and_resume_runs_only_the_missing(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    from amhe_cli.io.rows import read_rows
    out, jsonl = tmp_path / "grid.csv", tmp_path / "grid.jsonl"
    cmd = [sys.executable, "-c", "from amhe_cli.cli import main; main()", "evaluate", "--task", "t1",
           "--modes", "true", "--seeds", "3", "--duration", "0.3", "--workers", "1", "--out", str(out), "-q"]
    proc = subprocess.Popen(cmd + ["--jsonl", str(jsonl)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not out.exists() or len(read_rows(out)) < 1):
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)  # cut the grid off after its first run
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "--resume" in err, err
    first = read_rows(out)
    assert 1 <= len(first) < 3
    assert len(jsonl.read_text().splitlines()) == len(first)
    refused = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "already exists" in refused.stderr  # nothing lost without --resume
    done = subprocess.run(cmd + ["--resume", "--json"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = read_rows(out)
    assert sorted(r["seed"] for r in rows) == [0, 1, 2]
    assert rows[:len(first)] == first  # finished rows kept as they were, not run again
    assert json.loads(done.stdout)["rows"][0]["n"] == 3


def test_evaluate_keeps_its_probe_belief_beside_the_rows_and_a_resumed_grid_starts_from_it(tmp_path, capsys,
                                                                                          monkeypatch):
    """The probe's belief goes to <out stem>.probe.belief.yaml; --resume loads it instead of probing again
    (after a code change a new probe could differ, and one grid's rows would start from two beliefs); a
    new grid without --force refuses to replace it. The probe and the runs are stand-ins here: the test is
    the command's bookkeeping (the real grid is test_evaluate_keeps_rows_as_they_finish_...)."""
    import amhe_cli.control.evaluate as ev
    from amhe_cli.io.rows import read_rows
    from amhe_cli.model.params import ParameterSpace
    from amhe_cli.model.scene import Scene
    probed, started = [], []

    def probe(task, seed=0, threads=None, progress=None):
        probed.append(task.name)
        b = Belief.nominal(ParameterSpace(Scene(), free=RUN_PARAMS), {"source": "test probe"})
        return Belief(**{**b.__dict__, "values": {**b.values, "box_mass": 4.321 + len(probed)}})

    def grid(task_name, modes, seeds, belief, config, workers, duration, progress=None, done=(), **kw):
        started.append(belief.values["box_mass"])
        for s in range(seeds):
            for m in modes:
                if ("", m, s) not in done:
                    progress({"task": task_name, "mode": m, "seed": s, "success": True, "e_g": 0.05, "J": 1.0,
                              "t_exec": 9.0, "rmse": 0.05, "fell": False, "recoveries": 0, "control_hz": 9.0,
                              "setting": ""})
                    if len(started) == 1 and s == 1:
                        raise KeyboardInterrupt  # the first grid cut off after two runs
        return []
    monkeypatch.setattr(ev, "probe_belief", probe)
    monkeypatch.setattr(ev, "evaluate", grid)
    out = tmp_path / "grid.csv"
    args = ["evaluate", "--task", "t1", "--modes", "baseline", "--seeds", "4", "--out", out]
    code, _, err = amhe(capsys, *args)
    assert code == 130 and len(read_rows(out)) == 2, err
    saved = tmp_path / "grid.probe.belief.yaml"
    assert Belief.load(saved).values["box_mass"] == pytest.approx(5.321) and "saved to" in err
    code, out_json, err = amhe(capsys, *args, "--resume", "--json")
    assert code == 0, err
    assert probed == ["t1"] and started == [pytest.approx(5.321)] * 2  # not probed again: the same belief
    assert sorted(r["seed"] for r in read_rows(out)) == [0, 1, 2, 3]
    assert json.loads(out_json)["probe_belief"] == str(saved)
    before = saved.read_bytes()
    out.unlink()  # a new grid under the same name must not replace the belief without --force
    one_line_error(amhe(capsys, *args), "grid.probe.belief.yaml", "--force")
    assert saved.read_bytes() == before and probed == ["t1"]
    code, _, err = amhe(capsys, *args, "--force", "-q")
    assert code == 0 and probed == ["t1", "t1"], err
    assert Belief.load(saved).values["box_mass"] == pytest.approx(6.321)


def _loopback_only(cmd: list) -> list:
    """``cmd`` run in a network namespace of its own holding only the loopback interface, so that nothing
    it starts can reach any other network. A real Ray instance will not bind 127.0.0.1 where the host has
    another address (it swaps 127.0.0.1 for it); with loopback alone it binds 127.0.0.1. Skips the test
    where this machine cannot make a namespace (not root, no ``unshare``/``ip``)."""
    import shutil
    import subprocess
    if not (shutil.which("unshare") and shutil.which("ip")):
        pytest.skip("needs unshare and ip (util-linux, iproute2) for a loopback-only network namespace")
    wrapped = ["unshare", "--net", "sh", "-c", 'ip link set lo up && exec "$@"', "sh"] + cmd
    probe = subprocess.run(wrapped[:-len(cmd)] + ["true"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot make a network namespace here: {probe.stderr.strip()}")
    return wrapped


#: The grid both --ray tests compare with the local process pool: two seeds of a short T1 run.
RAY_GRID = {"task": "t1", "modes": ["true"], "seeds": 2, "duration": 0.3}


def _without_rate(rows) -> list[dict]:
    """``rows`` by seed, control_hz (a wall-clock rate, the one field runs may not share) left out."""
    return [{k: v for k, v in r.items() if k != "control_hz"} for r in sorted(rows, key=lambda r: r["seed"])]


@pytest.fixture(scope="module")
def pool_rows():
    """:data:`RAY_GRID`'s rows from the local process pool (two workers), by seed, control_hz (a wall-clock
    rate) left out: what both --ray tests must give."""
    from amhe_cli.control.evaluate import evaluate
    g = RAY_GRID
    rows = evaluate(g["task"], g["modes"], g["seeds"], None, workers=2, duration=g["duration"])
    return _without_rate(rows)


def test_evaluate_on_a_local_ray_instance_gives_the_local_pools_rows(tmp_path, pool_rows):
    """`amhe evaluate ... --ray` on a real local Ray instance (two tasks of one CPU each), in a loopback-only
    network namespace: the same rows as the local process pool for the same seeds, control_hz aside."""
    import os
    import subprocess
    import sys

    from amhe_cli.io.rows import read_rows
    g = RAY_GRID
    grid = [sys.executable, "-c", "from amhe_cli.cli import main; main()", "evaluate", "--task", g["task"],
            "--seeds", str(g["seeds"]), "--modes", ",".join(g["modes"]), "--duration", str(g["duration"]),
            "--workers", "2", "-q", "--ray", "--out", str(tmp_path / "ray.csv")]
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    on_ray = subprocess.run(_loopback_only(grid), env=env, capture_output=True, text=True, timeout=400)
    assert on_ray.returncode == 0, on_ray.stderr[-2000:]
    rows = sorted(read_rows(tmp_path / "ray.csv"), key=lambda r: r["seed"])
    assert [r["seed"] for r in rows] == [0, 1]
    assert _without_rate(rows) == pool_rows


class _InProcessRay:
    """Just enough of Ray's task API, in this process, for what the real instance cannot show cheaply:
    the options each task is given, rows handed over in finishing order, one init and one shutdown."""

    def __init__(self):
        import importlib.machinery
        self.__spec__ = importlib.machinery.ModuleSpec("ray", None)
        self.inits, self.shutdowns, self._up = [], 0, False

    def is_initialized(self):
        return self._up

    def init(self, **kw):
        self.inits.append(kw)
        self._up = True

    def shutdown(self):
        self.shutdowns += 1
        self._up = False

    def remote(self, **opts):
        assert opts == {"num_cpus": 1, "max_retries": 0}  # one CPU per run, a failed run is not re-run

        class Fn:
            def __init__(self, fn):
                self.fn = fn

            def remote(self, job):
                return lambda: self.fn(job)  # a "task": run when its result is fetched
        return Fn

    def wait(self, refs, num_returns=1):
        return refs[-num_returns:], refs[:-num_returns]  # finishing order differs from submission order

    def get(self, ref):
        return ref()

    def cancel(self, ref, force=False):
        pass


def test_evaluate_as_ray_tasks_gives_the_local_pools_rows(monkeypatch, pool_rows):
    """`--ray` runs each (mode, seed) as a task of one CPU and hands rows over as they finish: the same rows
    as the process pool (control_hz aside, a wall-clock rate). Ray is stood in for in-process (see above);
    the test before this one runs a real local instance."""
    import sys

    from amhe_cli.control.evaluate import evaluate
    fake = _InProcessRay()
    g = RAY_GRID
    monkeypatch.setitem(sys.modules, "ray", fake)
    seen = []
    rows = evaluate(g["task"], g["modes"], g["seeds"], None, workers=2, duration=g["duration"], ray="local",
                    progress=seen.append)
    assert [r["seed"] for r in rows] == [1, 0] and seen == rows  # as they finish
    assert fake.inits == [{"include_dashboard": False, "log_to_driver": False, "configure_logging": False,
                           "num_cpus": 2}] and fake.shutdowns == 1
    assert _without_rate(rows) == pool_rows


def test_evaluate_refuses_a_ray_address_where_nothing_answers(tmp_path, capsys):
    out = tmp_path / "grid.csv"
    for address, words in (("127.0.0.1:1", ("127.0.0.1:1", "no Ray cluster answers")),
                           ("no-port", ("no-port", "HOST:PORT"))):
        res = amhe(capsys, "evaluate", "--task", "t4", "--seeds", "1", "--modes", "true", "--ray", address,
                   "--out", str(out))
        one_line_error(res, *words)
        assert not out.exists()  # refused before any output


def test_evaluate_says_how_to_get_ray_when_it_is_missing(tmp_path, capsys, monkeypatch):
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    out = tmp_path / "grid.csv"
    res = amhe(capsys, "evaluate", "--task", "t4", "--seeds", "1", "--modes", "true", "--ray", "--out", str(out))
    one_line_error(res, "--ray", "pip install 'amhe[ray]'")
    assert not out.exists()


def test_sweep_settings_are_dotted_run_config_keys():
    from amhe_cli.control.evaluate import default_setting, parse_sweep, sweep_variants, with_setting
    from amhe_cli.errors import AmheError
    assert parse_sweep("mhe.samples=6,10,16") == ("mhe.samples", [6, 10, 16])
    assert parse_sweep("mhe.alpha=0.5,1") == ("mhe.alpha", [0.5, 1])
    base = {"mhe": {"window": 2.0}}
    assert with_setting(base, "mhe.samples", 6) == {"mhe": {"window": 2.0, "samples": 6}}
    assert base == {"mhe": {"window": 2.0}}  # the config itself is left alone
    labels = [label for label, _ in sweep_variants("t4", base, ["mhe.samples=6,16", "kp=90"])]
    assert labels == ["mhe.samples=6", "mhe.samples=16", "kp=90"]
    assert default_setting("t4", base, "mhe.window") == 2.0 and default_setting("t4", None, "mhe.samples") == 10
    for bad in ("mhe.sampels=6", "mhe.samples", "=3"):
        with pytest.raises(AmheError):
            sweep_variants("t4", None, [bad])


def test_evaluate_sweep_writes_rows_per_value_and_the_ablation_figure(tmp_path, capsys):
    from amhe_cli.io.rows import read_rows
    out, png = tmp_path / "sweep.csv", tmp_path / "ablation.png"
    code, stdout, err = amhe(capsys, "evaluate", "--task", "t1", "--modes", "true", "--seeds", "1", "--duration", "0.4",
                             "--workers", "2", "--sweep", "planner.samples=8,30", "--sweep", "planner.knots=4,5",
                             "--out", out, "--plot", png, "-q")
    assert code == 0, err
    rows = read_rows(out)
    assert sorted(r["setting"] for r in rows) == ["planner.knots=4", "planner.knots=5", "planner.samples=30",
                                                   "planner.samples=8"]
    assert "planner.samples=8" in stdout and "planner.knots=5" in stdout
    # both defaults (30 samples, 4 knots) are one run, its row written under each label
    by = {r["setting"]: r for r in rows}
    assert {**by["planner.knots=4"], "setting": ""} == {**by["planner.samples=30"], "setting": ""}
    assert by["planner.knots=4"]["control_hz"] == by["planner.samples=30"]["control_hz"]  # a copy: wall-clock too
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    one_line_error(amhe(capsys, "evaluate", "--task", "t1", "--plot", tmp_path / "x.png", "--out", tmp_path / "y.csv"),
                   "--plot", "--sweep")
    one_line_error(amhe(capsys, "evaluate", "--task", "t1", "--sweep", "mhe.nope=1", "--out", tmp_path / "z.csv"),
                   "nope")


def test_rows_of_an_older_csv_read_but_are_not_appended_to(tmp_path):
    from amhe_cli.errors import AmheError
    from amhe_cli.io.rows import ROW_KEYS, RowLog, read_rows
    legacy = [k for k in ROW_KEYS if k != "recoveries"]
    before_sweeps = tmp_path / "old.csv"  # no setting, no recoveries column
    before_sweeps.write_text(",".join(legacy[:-1]) + "\nt4,true,0,True,0.05,1.0,30.0,0.1,False,9.5\n")
    before_reflex = tmp_path / "older.csv"  # a setting, no recoveries column
    before_reflex.write_text(",".join(legacy) + "\nt4,true,0,True,0.05,1.0,30.0,0.1,True,9.5,\n")
    for old, fell in ((before_sweeps, False), (before_reflex, True)):
        (row,) = read_rows(old)
        assert row["setting"] == "" and row["success"] is True and row["seed"] == 0
        assert row["fell"] is fell and row["recoveries"] == 0 and row["control_hz"] == 9.5
        with pytest.raises(AmheError, match="--force"):
            RowLog(old)


def test_a_ctrl_c_between_the_csv_and_the_json_line_acts_after_both(tmp_path, monkeypatch):
    """A Ctrl-C landing once a row's CSV line is on disk still lets its JSON line follow, then interrupts."""
    import os
    import signal

    from amhe_cli.io.rows import ROW_KEYS, RowLog, read_rows
    log = RowLog(tmp_path / "grid.csv", tmp_path / "grid.jsonl")
    flush = RowLog._flush
    sent = []

    def flush_then_ctrl_c(fh):
        flush(fh)
        if not sent:  # right after the CSV line
            sent.append(fh.name)
            os.kill(os.getpid(), signal.SIGINT)
    monkeypatch.setattr(log, "_flush", flush_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        log.write({**{k: 0 for k in ROW_KEYS}, "task": "t1", "mode": "true"})
    log.close()
    assert sent == [str(tmp_path / "grid.csv")]
    assert len(read_rows(tmp_path / "grid.csv")) == len((tmp_path / "grid.jsonl").read_text().splitlines()) == 1
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is back


def test_a_run_reads_its_robot_from_its_joint_efforts_and_plans_for_it(monkeypatch):
    """``robot_read``: a sim robot whose servo gives 85 of the commanded Kp 100 is read from the run's own joint
    efforts (here from t = 1 s) and said once; the planner's and the MHE's models take that servo from then on
    (every model write_robot edits holds 0.85 × the gains), and the run ends with that side. The nominal robot
    is read as its model and nothing changes; mode true (the plant's truth) refuses the setting."""
    from amhe_cli.control import closed_loop
    monkeypatch.setattr(closed_loop, "READ_FROM", 1.0)
    edited = []
    original = closed_loop.write_robot
    monkeypatch.setattr(closed_loop, "write_robot", lambda model, side: (edited.append(model), original(model, side)))
    task = replace(get_task("t1", duration=1.6), truth={**get_task("t1").truth, "robot_kp": 85.0})
    s = small_settings("adaptive", robot_read=True, mhe=MHESettings(window=0.5, every=0.25, iters=1, samples=4))
    result = run_task(task, belief(4.0, 0.5), s)
    told = [m for m in result.warnings if "not the one the planner modelled" in m]
    assert len(told) == 1 and "read the servo at 0.85 × the commanded gains" in told[0], result.messages
    assert "the planner and the MHE model it so from now on" in told[0]
    assert result.side.kp == pytest.approx((85.0,) * 12, rel=0.01) and result.side.torque_limit is None
    assert len(edited) > s.planner.samples  # the planner's sample models and the MHE's
    for model in edited:
        np.testing.assert_allclose(model.actuator_gainprm[:, 0], 85.0, rtol=0.01)
        np.testing.assert_allclose(-model.actuator_biasprm[:, 2], 0.85 * s.kd, rtol=0.01)
    assert any("read from its joint efforts 1 times" in m for m in result.messages)
    edited.clear()
    result = run_task(get_task("t1", duration=1.6), belief(4.0, 0.5), replace(s, mode="baseline"))
    assert not edited and result.side.kp == (s.kp,) * 12 and not any("not the one" in m for m in result.messages)
    with pytest.raises(AmheError, match="robot_read"):
        run_task(task, None, replace(s, mode="true"))


def test_a_robot_run_whose_mhe_attributes_from_the_nominal_prior_is_told_to_start_from_a_belief():
    from amhe_cli.cli.run import prior_warning
    _, attribute = run_settings("t4", "adaptive", {"mhe": {"attribute": True}}, realtime=True)
    _, windows = run_settings("t4", "adaptive", {}, realtime=True)
    assert "start from a belief (--belief" in prior_warning("go1", "adaptive", attribute, None)
    assert prior_warning("go1", "adaptive", attribute, start=object()) is None  # a belief given
    assert prior_warning("sim", "adaptive", attribute, None) is None  # a sim run probes first
    assert prior_warning("go1", "baseline", attribute, None) is None  # no MHE
    assert prior_warning("go1", "adaptive", windows, None) is None  # the windows' own split, no held one
