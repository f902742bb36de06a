"""The fall-prevention reflex: its envelope trips, holds, releases, and in the closed loop stops the task."""

from __future__ import annotations

import numpy as np
import pytest

from amhe_cli.control.closed_loop import RunSettings, make_plant, run_task
from amhe_cli.control.evaluate import run_settings
from amhe_cli.control.planner import PlannerSettings
from amhe_cli.control.reflex import FallReflex, ReflexSettings, recovery_command, trunk_tilt
from amhe_cli.control.tasks import get_task
from amhe_cli.errors import AmheError
from amhe_cli.io.quat import quat_from_rotvec

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
UP = np.array([0.0, 0.0, 0.265])
STILL = np.zeros(3)


def tilted(rad: float, axis=(1.0, 0.0, 0.0)) -> np.ndarray:
    return quat_from_rotvec(np.asarray(axis) * rad)


def test_trunk_tilt_is_the_angle_from_vertical_whatever_the_yaw():
    assert trunk_tilt(LEVEL) == pytest.approx(0.0)
    assert trunk_tilt(tilted(0.3)) == pytest.approx(0.3)
    assert trunk_tilt(tilted(0.3, (0.0, 1.0, 0.0))) == pytest.approx(0.3)
    assert trunk_tilt(tilted(1.2, (0.0, 0.0, 1.0))) == pytest.approx(0.0, abs=1e-7)


def test_a_level_trunk_never_trips():
    r = FallReflex()
    for k in range(100):
        assert r.update(0.02 * k, UP, tilted(0.15), np.array([0.5, -0.5, 2.0])) is None
    assert not r.active and r.recoveries == 0


@pytest.mark.parametrize("pos, quat, angvel, why", [
    (UP, tilted(0.35), STILL, "trunk tilt 20°"),
    (UP, tilted(0.35, (0.0, 1.0, 0.0)), STILL, "trunk tilt 20°"),
    (np.array([0.0, 0.0, 0.17]), LEVEL, STILL, "trunk height 0.170 m"),
    (UP, LEVEL, np.array([0.0, 3.5, 0.0]), "roll/pitch rate 3.5"),
])
def test_leaving_the_envelope_starts_a_recovery_and_says_why(pos, quat, angvel, why):
    r = FallReflex()
    text = r.update(0.0, pos, quat, angvel)
    assert r.active and r.recoveries == 1
    assert why in text and "recovering the stand" in text


def test_a_recovery_ends_only_after_the_trunk_settles_inside_the_tighter_envelope():
    s = ReflexSettings(settle=0.4)
    r = FallReflex(s)
    r.update(0.0, UP, tilted(0.4), STILL)
    # between the two envelopes (0.2 rad: inside enter, outside exit) it stays in recovery
    for k in range(1, 50):
        assert r.update(0.02 * k, UP, tilted(0.2), STILL) is None and r.active
    # level again: ends after `settle`, not before; a wobble restarts the count
    assert r.update(1.00, UP, LEVEL, STILL) is None and r.active
    assert r.update(1.30, UP, LEVEL, STILL) is None and r.active
    assert r.update(1.32, UP, LEVEL, np.array([1.0, 0.0, 0.0])) is None and r.active
    assert r.update(1.50, UP, LEVEL, STILL) is None and r.active
    text = r.update(1.90, UP, LEVEL, STILL)
    assert not r.active and "resuming the task" in text
    assert r.recoveries == 1
    r.update(2.0, UP, tilted(0.5), STILL)
    assert r.active and r.recoveries == 2


def test_a_plan_whose_every_sample_tilts_the_trunk_starts_a_recovery_before_the_trunk_tilts():
    r = FallReflex()
    assert r.update(0.0, UP, LEVEL, STILL, predicted_tilt=None) is None  # no plan yet
    assert r.update(0.01, UP, LEVEL, STILL, predicted_tilt=0.34) is None and not r.active
    text = r.update(0.02, UP, LEVEL, STILL, predicted_tilt=0.40)
    assert r.active and r.recoveries == 1
    assert "every sampled plan tilts the trunk past 20° (23°)" in text and "recovering the stand" in text
    off = FallReflex(ReflexSettings(enter_predicted_tilt=0.0))
    assert off.update(0.0, UP, LEVEL, STILL, predicted_tilt=1.0) is None and not off.active
    for bad in (-0.1, 0.1):  # negative, or inside the exit envelope (it would never let a recovery end)
        with pytest.raises(AmheError, match="enter_predicted_tilt"):
            FallReflex(ReflexSettings(enter_predicted_tilt=bad))


def test_the_closed_loop_trips_on_the_planners_predicted_tilt():
    """A trunk leaning 0.2 rad (11°, inside the measured envelope) at the start: every sample of the first
    plan keeps it past a 0.18 rad predicted bound, so the next cycle recovers; with the bound off it
    walks on."""
    task = get_task("t1", duration=0.3)
    runs = []
    for bound in (0.18, 0.0):
        settings = RunSettings(mode="true", planner=PlannerSettings(samples=8, horizon=20), threads=1,
                               reflex=ReflexSettings(enter_predicted_tilt=bound))
        plant = make_plant(task, settings.kp, settings.kd, settings.planner.dt, cycle=settings.cycle)
        qpos = plant.data.qpos.copy()
        qpos[plant.scene.base_qpos[3:]] = tilted(0.2)
        qpos[plant.scene.base_qpos[2]] += 0.02
        plant.reset(qpos, np.zeros(plant.model.nv))
        runs.append(run_task(task, None, settings, plant=plant))
    tripped, walked = runs
    assert tripped.recoveries >= 1 and walked.recoveries == 0
    first = next(w for w in tripped.warnings if "fall prevention" in w)
    assert float(first.split("t=")[1].split(" s")[0]) < 0.05  # the cycle after the first plan
    assert "every sampled plan tilts the trunk past 10°" in first
    assert "trunk tilt" not in first  # the measured trunk never left the envelope
    assert np.degrees(trunk_tilt(tripped.traj.base_quat).max()) < 17


def test_a_disabled_reflex_never_trips():
    r = FallReflex(ReflexSettings(enabled=False))
    assert r.update(0.0, np.array([0.0, 0.0, 0.05]), tilted(1.0), np.full(3, 9.0)) is None
    assert not r.active


def test_an_envelope_whose_exit_is_looser_than_its_entry_is_refused():
    with pytest.raises(AmheError, match="exit_tilt < enter_tilt"):
        FallReflex(ReflexSettings(enter_tilt=0.2, exit_tilt=0.3))
    with pytest.raises(AmheError, match="unknown reflex setting"):
        ReflexSettings.from_dict({"tilt": 0.3})
    with pytest.raises(AmheError, match="reflex setting"):
        run_settings("t1", "true", {"reflex": {"enter_tilt": 0.1, "exit_tilt": 0.2}})


def test_recovery_command_stands_where_the_robot_is_and_holds_the_box():
    cmd = get_task("t1").command(np.array([0.0, 0.0]), 0.0, np.array([0.52, 0.0]), 0.19)
    rec = recovery_command({**cmd, "reach": {"foot": np.zeros(3)}}, np.array([0.1, -0.2]), 0.3)
    assert rec["phase"] == "recover" and rec["speed"] == 0.0 and rec["omega"] == 0.0 and rec["box_speed"] == 0.0
    np.testing.assert_array_equal(rec["waypoint"], [0.1, -0.2])
    assert rec["yaw"] == 0.3 and "reach" not in rec
    assert cmd["phase"] == "push" and cmd["speed"] > 0  # the task's own command is not changed


def test_a_shoved_robot_stops_pushing_recovers_the_stand_and_resumes():
    """A roll-rate kick of 4 rad/s at the start (a shove) trips the reflex: the loop stands the robot up
    (no walking: the trunk stays within 3 cm where the unshoved robot trots 8+ cm off in the same time),
    levels it, resumes the task, and it never falls."""
    task = get_task("t1", duration=1.2)
    settings = RunSettings(mode="true", planner=PlannerSettings(samples=8, horizon=20), threads=1)
    runs = []
    for kick in (4.0, 0.0):
        plant = make_plant(task, settings.kp, settings.kd, settings.planner.dt, cycle=settings.cycle)
        qvel = np.zeros(plant.model.nv)
        qvel[plant.scene.base_qvel[3:]] = [kick, 0.0, 0.0]
        plant.reset(plant.data.qpos.copy(), qvel)
        runs.append(run_task(task, None, settings, plant=plant))
    shoved, calm = runs
    assert shoved.recoveries == 1 and not shoved.fell and calm.recoveries == 0
    assert any("fall prevention" in w and "roll/pitch rate 4.0" in w for w in shoved.warnings)
    assert shoved.metrics()["recoveries"] == 1 and shoved.metrics()["fell"] is False
    (end,) = [float(m.split("t=")[1].split(" s")[0]) for m in shoved.messages if "resuming the task" in m]
    assert 0.4 <= end < 1.2
    during = shoved.traj.t <= end
    moved = np.linalg.norm(shoved.traj.base_pos[during, :2] - shoved.traj.base_pos[0, :2], axis=1).max()
    trotted = np.linalg.norm(calm.traj.base_pos[calm.traj.t <= end, :2] - calm.traj.base_pos[0, :2], axis=1).max()
    assert moved < 0.03 and trotted > 0.08
    assert np.degrees(trunk_tilt(shoved.traj.base_quat[during][-1])) < 5  # level again when it resumed


def spied_planner(monkeypatch, refine_loops: int):
    """A T1 planner (200 samples, task σ 0.01/0.02/0.02, recovery σ 0.1/0.2/0.2 rad), its start state and
    task command, and two lists each scoring batch appends to: the σ it sampled at (hip, thigh, calf of leg
    FR) and the largest |offset| of the mean it sampled around."""
    from amhe_cli.control.closed_loop import make_planner
    from amhe_cli.control.planner import Planner

    drawn, means = [], []
    score = Planner._score

    def spy(self, state, knots, ref, cmd):
        drawn.append(np.std(knots[1:] - self.mean[None], axis=0).mean(axis=0)[:3])
        means.append(np.abs(self.mean).max())
        return score(self, state, knots, ref, cmd)

    monkeypatch.setattr(Planner, "_score", spy)
    task = get_task("t1")
    settings = RunSettings(mode="true", threads=1, planner=PlannerSettings(
        samples=200, horizon=6, knots=2, refine_loops=refine_loops, noise=(0.01, 0.02, 0.02),
        recovery_noise=(0.1, 0.2, 0.2)))
    planner, _ = make_planner(task, settings, None, task.truth)
    plant = make_plant(task, settings.kp, settings.kd)
    state = planner.scene.full_state(plant.data.qpos[None], plant.data.qvel[None])[0]
    cmd = task.command(np.zeros(2), 0.0, np.array(task.box_start), 0.19)
    return planner, state, cmd, drawn, means


def test_a_recovery_samples_wide_refines_every_cycle_and_the_task_gets_its_own_noise_back(monkeypatch):
    """While the reflex recovers (command phase ``recover``) the planner samples knot offsets at
    ``recovery_noise`` around a fresh mean and refines each cycle (``refine_loops`` batches); the
    first task cycle after it samples at ``noise`` again."""
    from amhe_cli.control.gait import GAITS

    planner, state, cmd, drawn, _ = spied_planner(monkeypatch, refine_loops=2)
    rec = recovery_command(cmd, np.zeros(2), 0.0)
    with planner:
        plans = [planner.plan(state, t, c, GAITS["stand"] if c is rec else None)
                 for t, c in ((0.0, cmd), (0.02, rec), (0.04, rec), (0.06, cmd))]
    assert [p.rollouts for p in plans[1:3]] == [400, 400]  # two refine loops each recovering cycle
    first_recovery, task_again = drawn[plans[0].rollouts // 200], drawn[-1]
    np.testing.assert_allclose(first_recovery, [0.1, 0.2, 0.2], rtol=0.25)
    assert np.all(task_again < 0.06)
    with pytest.raises(AmheError, match="recovery_noise"):
        PlannerSettings(recovery_noise=(0.1, 0.2)).check()


def test_a_steady_trunk_in_recovery_holds_the_stand_with_the_tasks_noise_from_the_reference(monkeypatch):
    """While recovering, a steady trunk (under ``hold_tilt``, slow, high, no forecast fall) turns the command's
    phase to ``hold``: the planner drops the recovery's wide σ and its drifted mean and samples the stand's
    reference at the task's ``noise``; a trunk tipping again (tilted, rolling, or every plan tilting) is
    caught with the wide σ again. ``hold_tilt`` 0 catches throughout."""
    from amhe_cli.control.gait import GAITS

    r = FallReflex()
    r.update(0.0, UP, tilted(0.4), STILL)
    assert r.active and not r.holding  # the first cycle catches
    r.update(0.1, UP, tilted(0.15), STILL, predicted_tilt=0.1)
    assert r.holding  # 9°, still, outside the exit envelope: held, not caught
    for pos, quat, angvel, forecast in ((UP, tilted(0.25), STILL, 0.1),  # tilted past hold_tilt
                                        (UP, LEVEL, np.array([1.0, 0.0, 0.0]), 0.1),  # rolling
                                        (np.array([0.0, 0.0, 0.2]), LEVEL, STILL, 0.1),  # low
                                        (UP, LEVEL, STILL, 0.4)):  # every plan tilts past 20°
        r.update(0.2, pos, quat, angvel, predicted_tilt=forecast)
        assert r.active and not r.holding
    off = FallReflex(ReflexSettings(hold_tilt=0.0))
    off.update(0.0, UP, tilted(0.4), STILL)
    off.update(0.1, UP, LEVEL, STILL)
    assert off.active and not off.holding
    with pytest.raises(AmheError, match="hold_tilt"):
        ReflexSettings(hold_tilt=0.05).check()  # under exit_tilt: a settling trunk would be caught

    planner, state, cmd, drawn, means = spied_planner(monkeypatch, refine_loops=1)
    rec, hold = recovery_command(cmd, np.zeros(2), 0.0), recovery_command(cmd, np.zeros(2), 0.0, hold=True)
    assert hold["phase"] == "hold" and rec["phase"] == "recover"
    with planner:
        for t, c in ((0.0, rec), (0.02, rec), (0.04, hold), (0.06, hold), (0.08, rec)):
            planner.plan(state, t, c, GAITS["stand"])
    np.testing.assert_allclose(drawn[1], [0.1, 0.2, 0.2], rtol=0.25)  # catching: wide
    assert means[1] > 0.01 and means[2] == 0.0  # the hold starts from the stand's reference ...
    assert np.all(drawn[2] < 0.03) and np.all(drawn[3] < 0.03)  # ... at the task's noise
    np.testing.assert_allclose(drawn[4], [0.1, 0.2, 0.2], rtol=0.25)  # tipping again: wide again


def test_a_planner_too_slow_for_the_wall_clock_is_said_at_the_start(monkeypatch):
    """On the wall clock a plan's compute time is open-loop time: a planner under 15 Hz gets a warning after its
    first cycles, naming its rate and what to do; a fast one gets none."""
    import time

    from amhe_cli.control.closed_loop import MIN_REALTIME_HZ
    from amhe_cli.control.planner import Planner

    score = Planner._score

    def slow(self, *a, **kw):  # rollouts that take 90 ms, inside the planner's own timing
        time.sleep(0.09)
        return score(self, *a, **kw)

    task = get_task("t1", duration=3.2)
    settings = RunSettings(mode="true", realtime=True, planner=PlannerSettings(samples=4, horizon=10, refine_loops=1),
                           threads=1,
                           reflex=ReflexSettings(enabled=False))
    fast = run_task(task, None, settings)
    monkeypatch.setattr(Planner, "_score", slow)
    slowed = run_task(task, None, settings)
    assert len(slowed.plan_times) > 5
    (w,) = [w for w in slowed.warnings if "replans at" in w]
    assert f"under the {MIN_REALTIME_HZ:g} Hz" in w and "more cores" in w
    assert float(w.split("replans at ")[1].split(" Hz")[0]) < 11.2
    assert not [w for w in fast.warnings if "replans at" in w]


def test_a_robot_has_fallen_when_low_over_its_floor_or_tilted_past_35_degrees():
    from amhe_cli.control.reflex import fallen
    pos = np.array([[0.0, 0.0, 0.30], [0.0, 0.0, 0.30], [0.0, 0.0, 0.46], [0.0, 0.0, 0.30]])
    quat = np.array([LEVEL, tilted(0.65), LEVEL, tilted(0.55, (0.0, 1.0, 0.0))])
    np.testing.assert_array_equal(fallen(pos, quat, floor=0.0, fall_height=0.15, fall_tilt=0.6),
                                  [False, True, False, False])
    # the floor of a motion-capture world need not be z = 0: 0.0 m over a floor at 0.3 is down, 0.16 m up
    np.testing.assert_array_equal(fallen(pos, quat, floor=0.3, fall_height=0.15, fall_tilt=0.6),
                                  [True, True, False, True])


def test_the_reason_of_a_fall_names_the_first_fallen_sample():
    from amhe_cli.cli.run import failure_reason
    task, settings = run_settings("t1", "true", {"planner": {"samples": 4, "horizon": 10}}, threads=1, duration=0.3)
    r = run_task(task, None, settings)
    r.fell, r.success = True, False
    assert r.traj.t[100] == pytest.approx(0.2)
    r.traj.base_quat[100:] = tilted(0.7)  # from t = 0.2 s the trunk lies on its side
    assert failure_reason(r, task) == "robot fell at t = 0.2 s"
