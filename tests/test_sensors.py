"""Real sensor data: noise and timing measured from a log, the servo gains fitted from efforts,
robot-side nuisance parameters, and the coverage check of stated uncertainty.

Every check uses a log generated here with a known answer: a simulated Go1
whose servo applies other gains than its log states, a box whose pose stream
carries white noise of a known σ, pose streams shifted by a known time.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from amhe_cli.control.maneuver import lunge_schedule
from amhe_cli.control.robot_side import (READ_JOINTS, READ_STD, RobotSide, check_run, follow, read_robot,
                                         write_robot)
from amhe_cli.errors import AmheError
from amhe_cli.estimation.clips import (CLEAR_GAP, REST_FLOOR, ROBOT_REACH, TRUNK_PUSH, box_travel,
                                      leg_only_touch, robot_box_clear, sample_rest_clips)
from amhe_cli.estimation.gains import applied_gains, applied_limit, fit_gains
from amhe_cli.estimation.payload import fit_payload
from amhe_cli.estimation.identify import IdentifySettings, identify
from amhe_cli.estimation.problem import example_logs, load_problem, run_dated_poses
from amhe_cli.estimation.timing import mocap_offset
from amhe_cli.estimation.uncertainty import coverage
from amhe_cli.estimation.cost import StateWeights, DEFAULT_SIGMA
from amhe_cli.io.reader import read_log
from amhe_cli.io.sensors import stream_report
from amhe_cli.io.unpack import _Series
from amhe_cli.io.writer import write_mcap
from amhe_cli.model.params import DEFAULT_FREE, ParameterSpace
from amhe_cli.model.scene import FOOT_RADIUS, Scene, SceneConfig, set_pd_gains
from amhe_cli.plants.sim import SimPlant

BOX_XY = (0.28 + 0.19 + 0.01, 0.0)
TRUTH = {"box_mass": 5.0, "box_friction": 0.45}


#: The model's motor torque limits [N·m].
MODEL_LIMIT = np.tile([23.7, 23.7, 35.55], 4)


def _lunge_log(kp=55.0, kd=3.0, payload=0.0, box_xy=BOX_XY, torque_share=1.0):
    """A lunge probe (three head bumps) by a robot whose servo applies ``kp``/``kd``, whose trunk carries
    ``payload`` [kg] and whose motors give ``torque_share`` of the model's torque limits; its trajectory
    states the nominal 55/3, as a lab's command log would."""
    limit = None if torque_share == 1.0 else tuple(torque_share * MODEL_LIMIT)
    plant = SimPlant(SceneConfig(trunk_payload=payload, torque_limit=limit), truth=dict(TRUTH))
    set_pd_gains(plant.model, kp, kd)
    q, _ = plant.scene.standing_state(box_xy=box_xy)
    plant.reset(q)
    for u in lunge_schedule():
        plant.step(u)
    traj = plant.trajectory()
    traj.kp, traj.kd = np.full(12, 55.0), np.full(12, 3.0)
    return traj


@pytest.fixture(scope="module")
def stiff_log():
    return _lunge_log(kp=63.0, kd=2.4)


def test_gain_fit_recovers_the_applied_gains(stiff_log):
    fit = fit_gains(stiff_log)
    assert fit.ok.all()
    np.testing.assert_allclose(fit.kp, 63.0, rtol=1e-3)
    np.testing.assert_allclose(fit.kd, 2.4, rtol=1e-3)
    kp, kd, warns = applied_gains(stiff_log, fit)
    np.testing.assert_allclose(kp, 63.0, rtol=1e-3)
    np.testing.assert_allclose(kd, 2.4, rtol=1e-3)
    assert len(warns) == 1 and "disagree" in warns[0] and "55" in warns[0] and "63" in warns[0]


def test_commands_that_act_a_tick_after_their_stamps_are_found_and_shifted(tmp_path, stiff_log):
    """A recording whose commands are stamped one 2 ms tick before they acted (amhe run's, against a Go1):
    the fit finds the delay, reads the gains it would misread without it, and load_problem shifts the
    commands so that rollouts apply each when it acted."""
    early = replace(stiff_log, ctrl=np.concatenate([stiff_log.ctrl[1:], stiff_log.ctrl[-1:]]), meta={})
    assert fit_gains(stiff_log).delay == 0.0
    fit = fit_gains(early)
    assert fit.delay == pytest.approx(0.002)
    np.testing.assert_allclose(fit.kp, 63.0, rtol=0.01)
    path = write_mcap(tmp_path / "early.mcap", early)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem = load_problem(str(path), payload=False, nthread=2)
    assert any("act 2 ms after their stamps" in str(w.message) for w in caught)
    np.testing.assert_allclose(problem.traj.ctrl[5:-5], stiff_log.ctrl[5:-5])
    assert problem.traj.meta["sensors"]["gains"]["command_delay_s"] == pytest.approx(0.002)


def test_poses_shifted_between_joint_samples_leave_the_grid_on_the_joint_states(tmp_path, stiff_log):
    """A pose stream shifted 3.9 ms for its lateness (as ``load_problem`` does) once moved the grid between the 2 ms
    joint samples: each effort met the command before its own, and the gain fit read a 20 ms command delay with
    Kp 25–60 and negative Kd on a fresh lock-step recording whose servo applied its logged 100 / 4. The grid now
    starts at a joint-state message, so the servo law holds between samples of one clock."""
    path = write_mcap(tmp_path / "stiff.mcap", stiff_log)
    for shift in (0.0039, -0.0039, 0.0011):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            traj = read_log(str(path), time_offset={"base": shift, "box": shift})
        joint_t0 = float(stiff_log.t[0]) - min(0.0, shift)  # the joint states' first stamp on the log's time axis
        assert np.round((traj.t[0] - joint_t0) / traj.dt, 9) % 1 == 0  # on a joint-state stamp
        fit = fit_gains(traj)
        assert fit.delay == 0.0
        np.testing.assert_allclose(fit.kp, 63.0, rtol=1e-3)
        np.testing.assert_allclose(fit.kd, 2.4, rtol=1e-3)


def test_a_delay_at_the_end_of_the_search_is_not_taken(tmp_path, stiff_log):
    """Commands stamped 30 ms before they acted, beyond the 20 ms searched: the fit's best delay is the longest
    searched, which says only that the search missed; no joint's gains or plateau is trusted, the commands are
    taken as stamped and the logged gains kept, with a warning (the safe reading of a servo it cannot fit)."""
    k = 15  # 30 ms of 2 ms steps
    early = replace(stiff_log, ctrl=np.concatenate([stiff_log.ctrl[k:], np.repeat(stiff_log.ctrl[-1:], k, axis=0)]),
                    meta={})
    fit = fit_gains(early)
    assert fit.at_edge and fit.delay == 0.0 and not fit.ok.any() and not np.isfinite(fit.limit).any()
    assert not fit_gains(stiff_log).at_edge
    kp, kd, warns = applied_gains(early, fit)
    assert warns == [] and np.allclose(kp, 55.0) and np.allclose(kd, 3.0)
    path = write_mcap(tmp_path / "early30.mcap", early)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem = load_problem(str(path), payload=False, nthread=2)
    assert any("the longest searched" in str(w.message) for w in caught)
    np.testing.assert_allclose(problem.traj.ctrl[5:-5], early.ctrl[5:-5])  # not shifted
    assert problem.traj.meta["sensors"]["gains"]["delay_at_search_edge"] is True
    np.testing.assert_allclose(problem.scene.config.kp, 55.0)


def test_gain_fit_agrees_silently_and_needs_efforts():
    traj = _lunge_log()
    kp, kd, warns = applied_gains(traj, fit_gains(traj))
    assert warns == [] and np.allclose(kp, 55.0) and np.allclose(kd, 3.0)
    traj.joint_effort = None
    assert fit_gains(traj) is None


def test_efforts_that_plateau_below_the_models_limit_give_the_motors_limit(tmp_path):
    """Motors at half the model's torque: the thighs' efforts plateau at 11.85 N·m through the lunges, the
    fit reads it there and models every joint at that share (one motor type); the model's own motors,
    and efforts that never plateau, leave the limits alone. The scene carries it as its force range."""
    weak = _lunge_log(box_xy=(1.5, 0.0), torque_share=0.5)
    fit = fit_gains(weak)
    seen = np.isfinite(fit.limit)
    assert seen[[1, 4]].all() and not seen[[0, 2, 3, 5]].any()  # the front thighs; hips and knees never reach it
    np.testing.assert_allclose(fit.limit[seen], 11.85, rtol=0.01)
    limit, warns = applied_limit(fit, MODEL_LIMIT)
    np.testing.assert_allclose(limit, 0.5 * MODEL_LIMIT, rtol=0.01)
    assert len(warns) == 1 and "50%" in warns[0] and "FR_thigh_joint" in warns[0]
    assert applied_limit(fit_gains(_lunge_log(box_xy=(1.5, 0.0))), MODEL_LIMIT) == (None, [])
    # a motor-current torque estimate scatters (0.3 N·m here): the plateau still reads, a robot that is its
    # model still reads none
    rng = np.random.default_rng(0)
    for share, found in ((0.5, True), (1.0, False)):
        noisy = _lunge_log(box_xy=(1.5, 0.0), torque_share=share)
        noisy.joint_effort = noisy.joint_effort + rng.normal(0.0, 0.3, noisy.joint_effort.shape)
        got, _ = applied_limit(fit_gains(noisy), MODEL_LIMIT)
        assert (got is not None) == found
        if found:
            np.testing.assert_allclose(got, 0.5 * MODEL_LIMIT, rtol=0.02)
    assert applied_limit(None, MODEL_LIMIT) == (None, [])
    # the scene: its force range, through a belief's dict and back
    config = SceneConfig(torque_limit=limit)
    assert SceneConfig.from_dict(config.to_dict()) == config
    np.testing.assert_allclose(Scene(config).model.actuator_forcerange[:, 1], limit)
    with pytest.raises(AmheError, match="torque limits"):
        Scene(SceneConfig(torque_limit=(0.0,) * 12))
    # a log of it: load_problem models the limit and says so
    path = write_mcap(tmp_path / "weak.mcap", replace(weak, meta={}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem = load_problem(str(path), nthread=2, payload=False)
    assert any("plateau at 50%" in str(w.message) for w in caught)
    np.testing.assert_allclose(problem.scene.config.torque_limit, 0.5 * MODEL_LIMIT, rtol=0.01)
    assert "motor torque limits" in problem.robot_differs


def test_a_kd_fit_a_few_percent_low_is_velocity_noise_not_another_servo():
    """Noise on the measured joint velocity biases a least-squares Kd low (a live Go1 recording read 3.8 where
    4 acted): within 10 % the logged Kd stands without a warning; Kp keeps its 3 %."""
    from dataclasses import replace
    traj = _lunge_log()
    fit = fit_gains(traj)
    tight = np.full(12, 1e-4)  # standard errors far below either gap
    for kd_fit, warned in ((0.95 * 3.0, False), (2.5, True)):
        kp, kd, warns = applied_gains(traj, replace(fit, kd=np.full(12, kd_fit), kd_std=tight))
        assert bool(warns) is warned and np.allclose(kd, kd_fit if warned else 3.0)
    kp, kd, warns = applied_gains(traj, replace(fit, kp=np.full(12, 0.95 * 55.0), kp_std=tight))
    assert len(warns) == 1 and "Kp" in warns[0] and np.allclose(kp, 0.95 * 55.0)


def test_a_run_recorded_on_a_robot_unlike_its_plan_says_so():
    """check_run: a robot whose servo gives 0.85 of the commanded Kp and whose motors plateau at half the
    model's limits is told against a plan for the nominal robot, and not against a plan for itself; the
    nominal robot against the nominal plan, and a log without efforts, say nothing."""
    nominal = RobotSide((55.0,) * 12, (3.0,) * 12)
    weak = _lunge_log(kp=0.85 * 55.0, kd=0.85 * 3.0, box_xy=(1.5, 0.0), torque_share=0.5)
    line = check_run(weak, nominal, 55.0, MODEL_LIMIT)
    assert line is not None and "0.85 × the commanded Kp where the planner modelled 1.00" in line
    assert "plateaued at 50% of the model's torque limits where the planner modelled 100%" in line
    assert "amhe identify" in line and "--belief" in line
    as_read = RobotSide((0.85 * 55.0,) * 12, (0.85 * 3.0,) * 12, torque_limit=tuple(0.5 * MODEL_LIMIT))
    assert check_run(weak, as_read, 55.0, MODEL_LIMIT) is None
    model = _lunge_log(box_xy=(1.5, 0.0))
    assert check_run(model, nominal, 55.0, MODEL_LIMIT) is None
    # a plan for a weaker robot than the one recorded: its servo is told, its motors cannot be (no plateau)
    line = check_run(model, as_read, 55.0, MODEL_LIMIT)
    assert "1.00 × the commanded Kp where the planner modelled 0.85" in line and "plateaued" not in line
    model.joint_effort = None
    assert check_run(model, nominal, 55.0, MODEL_LIMIT) is None


def test_a_read_whose_joints_disagree_on_the_servo_says_nothing():
    """read_robot: one servo law drives every motor, so a fit whose well-posed joints disagree on its share
    (interquartile range over READ_SPREAD) is no read of the robot; joints that agree, at 0.85, are one."""
    kp = np.where(np.arange(12) % 2 == 0, 55.0, 0.85 * 55.0)  # half the joints' servo at 0.85
    split = _lunge_log(kp=kp, kd=3.0, box_xy=(1.5, 0.0))
    fit = fit_gains(split)
    good = fit.ok & (fit.kp_std < READ_STD * np.abs(fit.kp))
    assert good.sum() >= READ_JOINTS and np.ptp(fit.kp[good] / 55.0) > 0.1  # well posed, each joint right
    assert read_robot(split, 55.0, MODEL_LIMIT) is None
    assert read_robot(split, 55.0, MODEL_LIMIT, max_samples=400) is None
    weak = _lunge_log(kp=0.85 * 55.0, kd=0.85 * 3.0, box_xy=(1.5, 0.0))
    assert read_robot(weak, 55.0, MODEL_LIMIT, max_samples=400).servo == pytest.approx(0.85, rel=0.01)


def test_a_read_of_the_robot_mid_run_gives_the_planner_that_robot():
    """read_robot + follow (``robot_read``): a servo at 0.85 of the commanded gains and motors plateauing at half
    the model's limits are read (thinned to a few hundred samples as a run's read is, as the whole log reads
    them) and become the side a run follows; a side already as read, and the nominal robot against the nominal
    side, are followed by nothing; write_robot puts the side into a model."""
    nominal = RobotSide((55.0,) * 12, (3.0,) * 12)
    weak = _lunge_log(kp=0.85 * 55.0, kd=0.85 * 3.0, box_xy=(1.5, 0.0), torque_share=0.5)
    whole, thinned = read_robot(weak, 55.0, MODEL_LIMIT), read_robot(weak, 55.0, MODEL_LIMIT, max_samples=400)
    for read in (whole, thinned):
        assert read.servo == pytest.approx(0.85, rel=0.01) and read.limit_share == pytest.approx(0.5, rel=0.02)
    side = follow(nominal, thinned, 55.0, 3.0, MODEL_LIMIT)
    np.testing.assert_allclose(side.kp, 0.85 * 55.0, rtol=0.01)
    np.testing.assert_allclose(side.kd, 0.85 * 3.0, rtol=0.01)
    np.testing.assert_allclose(side.torque_limit, 0.5 * MODEL_LIMIT, rtol=0.02)
    assert "servo at 0.85 × the commanded gains and the motors at 50%" in side.source
    assert follow(side, whole, 55.0, 3.0, MODEL_LIMIT) is None
    # payload and shell stay the side's own: a read has no rollouts to tell them
    assert follow(replace(nominal, trunk_payload=1.5), whole, 55.0, 3.0, MODEL_LIMIT).trunk_payload == 1.5
    model = _lunge_log(box_xy=(1.5, 0.0))
    read = read_robot(model, 55.0, MODEL_LIMIT, max_samples=400)
    assert read.servo == pytest.approx(1.0, abs=0.01) and read.limit_share == 1.0
    assert follow(nominal, read, 55.0, 3.0, MODEL_LIMIT) is None
    # the servo alone differs (no plateau): the limits stay the model's
    only_servo = follow(nominal, replace(read, servo=0.8), 55.0, 3.0, MODEL_LIMIT)
    assert only_servo.torque_limit is None and only_servo.kp == pytest.approx((44.0,) * 12)
    assert follow(nominal, replace(read, servo=0.2), 55.0, 3.0, MODEL_LIMIT) is None  # no Go1's servo
    # efforts flat at half the limits on some joints while another delivered 90 % of its own: no motor limit
    fit = fit_gains(weak)
    assert applied_limit(fit, MODEL_LIMIT)[0] is not None and fit.peak.max() <= 0.5 * MODEL_LIMIT.max() + 1e-6
    busy = replace(fit, peak=np.where(np.arange(12) == 2, 0.9 * MODEL_LIMIT, fit.peak))
    limit, warns = applied_limit(busy, MODEL_LIMIT)
    assert limit is None and "FR_calf_joint delivered 90% of its own" in warns[0]
    # too few well-posed joints say nothing
    model.joint_effort = None
    assert read_robot(model, 55.0, MODEL_LIMIT) is None
    scene = Scene(SceneConfig())
    write_robot(scene.model, side)
    np.testing.assert_allclose(scene.model.actuator_gainprm[:, 0], side.kp)
    np.testing.assert_allclose(-scene.model.actuator_biasprm[:, 2], side.kd)
    np.testing.assert_allclose(scene.model.actuator_forcerange[:, 1], side.torque_limit)


def test_fitted_gains_reach_the_scene_through_a_written_log(stiff_log, tmp_path):
    path = write_mcap(tmp_path / "stiff.mcap", stiff_log)
    with pytest.warns(UserWarning, match="disagree"):
        problem = load_problem(str(path))
    np.testing.assert_allclose(problem.scene.model.actuator_gainprm[:, 0], 63.0, rtol=1e-3)
    np.testing.assert_allclose(-problem.scene.model.actuator_biasprm[:, 2], 2.4, rtol=1e-3)
    assert problem.traj.meta["sensors"]["gains"]["used"] == "fitted"


def test_stream_report_measures_rate_drops_jitter_latency_and_noise():
    rng = np.random.default_rng(3)
    period = 1e9 / 120
    k = np.arange(2400)
    k = k[rng.random(k.size) > 0.03]  # 3 % dropped
    stamps = (k * period + rng.uniform(-1e6, 1e6, k.size)).astype(np.int64)  # ±1 ms jitter
    t = stamps * 1e-9
    pos = np.column_stack([0.3 * np.sin(t), 0.2 * t, 0.19 + 0 * t]) + rng.normal(0, 0.0015, (k.size, 3))
    quat = np.tile([1.0, 0, 0, 0], (k.size, 1))
    s = _Series("/box", "geometry_msgs/msg/PoseStamped", stamps, {"pos": pos, "quat": quat}, latency_ns=4e6)
    r = stream_report(s)
    assert r["rate_hz"] == pytest.approx(120.0, rel=1e-3)
    assert r["dropped_fraction"] == pytest.approx(0.03, abs=0.01)
    assert 0.4 < r["jitter_ms"] < 1.0  # uniform ±1 ms: σ 0.58 ms (robust MAD scale 0.74)
    assert r["latency_ms"] == pytest.approx(4.0)
    assert r["position_noise_m"] == pytest.approx(0.0015, rel=0.15)
    assert r["orientation_noise_rad"] < 1e-9


def test_noise_is_measured_through_a_log_and_widens_W_x(tmp_path):
    traj = _lunge_log()
    rng = np.random.default_rng(0)
    noisy = replace(traj, box_pos=traj.box_pos + rng.normal(0, 0.003, traj.box_pos.shape), meta={})
    path = write_mcap(tmp_path / "noisy.mcap", noisy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the smoothing notice
        read = read_log(path)
    box = read.meta["sensors"]["streams"]["box"]
    assert box["position_noise_m"] == pytest.approx(0.003, rel=0.15)
    assert read.meta["sensors"]["streams"]["base"]["position_noise_m"] < 1e-4
    w = StateWeights.for_log(read)
    assert w.sigma["box_pos"] == pytest.approx(np.hypot(DEFAULT_SIGMA["box_pos"], box["position_noise_m"]))
    assert w.sigma["box_linvel"] == np.inf  # differentiated from smoothed poses: left to the positions
    assert w.sigma["base_pos"] == pytest.approx(DEFAULT_SIGMA["base_pos"], rel=1e-3)
    assert StateWeights.for_log(read, {"box_pos": 0.01}).sigma["box_pos"] == 0.01  # --sigma wins


@pytest.mark.parametrize("shift", [0.0, 0.012, -0.005])
def test_pose_stream_lag_is_found_from_the_stance_feet(shift):
    log = example_logs()[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_log(log, time_offset={"base": shift, "box": shift})
    fit = mocap_offset(traj, Scene())
    assert fit is not None and fit.samples > 500
    assert fit.offset == pytest.approx(shift, abs=0.0025)


def test_a_run_recording_dated_by_its_measured_latency_is_not_shifted_again(tmp_path):
    """``amhe run`` dates a recording's poses by the lateness it measured (IMU against motion capture);
    ``load_problem`` keeps that dating and says what the stance feet read instead. A lateness the user gave,
    or none measured, leaves the stance-feet estimate to apply, as for any log."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        late = read_log(example_logs()[0], time_offset={"base": 0.012, "box": 0.012})
    for source, applied in (("measured", False), ("given", True)):
        meta = {"amhe_run": {"mode": "baseline", "mocap_latency": "0.003", "mocap_latency_source": source}}
        path = write_mcap(tmp_path / f"{source}.mcap", replace(late, meta={}), metadata=meta)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            problem = load_problem(str(path), payload=False, nthread=2)
        said = " ".join(str(w.message) for w in caught)
        got = problem.traj.meta["sensors"]["time_offset"]
        assert got["pose_stamp_lag_s"] == pytest.approx(0.012, abs=0.0025) and got["applied"] is applied
        assert ("dated by the 3.0 ms its run measured" in said and "not shifted" in said) is not applied
        assert ("shifted them by" in said) is applied
    # a recording from before the source was kept: a positive lateness was measured (auto is the default)
    older = replace(late, meta={"metadata": {"amhe_run": {"mocap_latency": "0.004"}}})
    assert run_dated_poses(older) == 0.004
    assert run_dated_poses(replace(late, meta={"metadata": {"amhe_run": {"mocap_latency": "0.000000"}}})) is None
    unmeasured = {"amhe_run": {"mocap_latency": "0.000000", "mocap_latency_source": "unmeasured"}}
    assert run_dated_poses(replace(late, meta={"metadata": unmeasured})) is None
    assert run_dated_poses(replace(late, meta={})) is None


def test_a_free_robot_side_parameter_is_recovered():
    """The robot's servo is stiffer than its log says; freeing ``robot_kp`` finds it, with the box."""
    stiff_log = _lunge_log(kp=63.0)
    scene = Scene(SceneConfig())  # the logged 55/3
    free = ("box_mass", "box_friction", "robot_kp")
    space = ParameterSpace(scene, free=free)
    assert space.mean0[2] == pytest.approx(55.0) and space.std0[2] == pytest.approx(0.15 * 55.0)
    res = identify(stiff_log, scene, space, IdentifySettings(params=free, n_clips=12, max_gen=30, popsize=10),
                   nthread=2)
    mass, mu, kp = res.estimate
    assert kp == pytest.approx(63.0, rel=0.05), res.estimate
    assert mass == pytest.approx(5.0, rel=0.05) and mu == pytest.approx(0.45, abs=0.03)


def test_nuisance_parameters_write_the_model():
    scene = Scene(SceneConfig(kp=tuple([50.0] * 6 + [60.0] * 6)))
    space = ParameterSpace(scene, free=("robot_kp", "robot_kd", "trunk_payload"))
    m = scene.model
    trunk = m.body("trunk").id
    before = float(m.body_mass[trunk])
    space.write(m, np.array([66.0, 4.5, 0.5]))
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], [60.0] * 6 + [72.0] * 6)  # ratios kept, mean 66
    np.testing.assert_allclose(-m.actuator_biasprm[:, 1], m.actuator_gainprm[:, 0])
    np.testing.assert_allclose(-m.actuator_biasprm[:, 2], 4.5)
    assert m.body_mass[trunk] == pytest.approx(before + 0.5)
    space.write(m, space.mean0)
    assert m.body_mass[trunk] == pytest.approx(before)
    # where they are not free, the servo and the trunk stay as the scene built them (e.g. torque motors)
    box_only = ParameterSpace(scene, free=("box_mass",))
    m.actuator_gainprm[:, 0], m.actuator_biasprm[:, :3] = 1.0, 0.0
    box_only.write(m, box_only.mean0)
    assert np.all(m.actuator_gainprm[:, 0] == 1.0) and np.all(m.actuator_biasprm[:, :3] == 0.0)


#: The box out of the lunging robot's reach (its head plate ends 0.28 m ahead of the trunk, the box's
#: half diagonal is 0.27 m): every clip is one of the box at rest.
FAR_BOX = (1.5, 0.0)


@pytest.fixture(scope="module")
def heavy_robot_log():
    return _lunge_log(payload=0.6, box_xy=FAR_BOX)


def test_payload_is_fitted_where_the_box_rests(heavy_robot_log):
    """A robot 0.6 kg heavier than its model: its own lunges, the box far away, tell the payload."""
    fit = fit_payload(heavy_robot_log, Scene(SceneConfig()), nthread=2)
    assert fit is not None and fit.clips == 32 and not fit.at_edge
    assert fit.value == pytest.approx(0.6, abs=0.03), fit
    assert 0 < fit.std < 0.05
    # the robot that is its model reads no payload
    light = fit_payload(_lunge_log(box_xy=FAR_BOX), Scene(SceneConfig()), nthread=2)
    assert abs(light.value) < 0.03, light
    # a scene that already carries a payload is searched around it, and finds the same robot
    again = fit_payload(heavy_robot_log, Scene(SceneConfig(trunk_payload=0.6)), nthread=2)
    assert again.value == pytest.approx(fit.value, abs=0.01)


def test_rest_clips_keep_the_box_still_and_out_of_the_robots_reach(heavy_robot_log):
    scene = Scene(SceneConfig())
    clips = sample_rest_clips(heavy_robot_log, scene, 16, rng=np.random.default_rng(0))
    assert clips is not None and len(clips) == 16
    ends = clips.start + clips.horizon
    assert np.all(box_travel(heavy_robot_log, clips.start, clips.horizon) <= REST_FLOOR)
    assert np.all(robot_box_clear(heavy_robot_log, scene, clips.start, int(clips.horizon.max())))
    assert np.all(ends < len(heavy_robot_log))
    # the lunge log with the box at the head plate: no clip through a bump (the head on the box) or from
    # the start (1.4 cm apart); once the bumps have pushed the box off, the robot stands 6-17 cm from it
    near = _lunge_log()
    starts = np.arange(0, len(near) - 100, 50)
    clear = robot_box_clear(near, scene, starts, 100)
    qpos = scene.qpos_qvel(near)[0]
    touching = np.array([scene.robot_box_gap(qpos[s:s + 101:5]).min() < 0.01 for s in starts])
    assert not clear[0] and touching.any() and not clear[touching].any()
    assert clear[-1] and scene.robot_box_gap(qpos[-1:])[0] > 0.1
    drawn = sample_rest_clips(near, scene, 16, rng=np.random.default_rng(0))
    assert drawn is not None and (scene.robot_box_gap(qpos[drawn.start]) > CLEAR_GAP).all()


def test_a_box_moved_by_a_leg_alone_gives_the_line_decisions_no_clip():
    """The lunge log's head bumps push the box (its feet on the floor): no clip of them counts as a leg alone
    on the box. The same robot with the box carried along its front-right foot, 5 mm inside it, and moving
    0.1 m/s: every clip counts, and a change test or line decision over it draws none (None: the next update
    tries again); the box 5 cm off the foot, as fast: clips are drawn. (Two emulated T4 runs read mass changes
    that were not there from such spans: a front foot struck the box or stood against it.) A span with enough
    of a push keeps the leg's clips in the draw; one with less than MOVING_MIN of it waits."""
    from amhe_cli.estimation.attribution import MOVING_MIN
    from amhe_cli.estimation.identify import clip_plan
    from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator, decision_clips, held_by_legs
    scene = Scene(SceneConfig())
    lunge = _lunge_log()
    qpos = scene.qpos_qvel(lunge)[0]
    starts = np.arange(0, len(lunge) - 100, 25)
    assert scene.robot_box_gap(qpos[::5], part="trunk").min() < 0.005  # the head does reach the box
    assert not leg_only_touch(lunge, scene, starts, 100).any()

    def beside(offset: float):
        foot = scene.foot_centres(qpos)[:, 0]  # FR
        pos = lunge.box_pos.copy()
        pos[:, 0] = foot[:, 0]
        pos[:, 1] = foot[:, 1] - FOOT_RADIUS + offset - 0.19  # the box's left face `offset` past the foot's edge
        vel = np.zeros_like(lunge.box_linvel)
        vel[:, 0] = 0.1
        return replace(lunge, box_pos=pos, box_quat=np.tile([1.0, 0, 0, 0], (len(lunge), 1)), box_linvel=vel,
                       box_angvel=np.zeros_like(lunge.box_angvel))

    kicked, clear = beside(0.005), beside(-0.05)
    q = scene.qpos_qvel(kicked)[0][::50]
    assert scene.robot_box_gap(q, part="legs").max() < 0 and scene.robot_box_gap(q, part="trunk").min() > TRUNK_PUSH
    assert leg_only_touch(kicked, scene, starts, 100).all()
    assert not leg_only_touch(clear, scene, starts, 100).any()
    stop = len(lunge) - 1
    rng = np.random.default_rng(0)
    assert held_by_legs(kicked, scene, stop, 0.0, 0.02) and not held_by_legs(clear, scene, stop, 0.0, 0.02)
    assert decision_clips(kicked, scene, stop, 0.0, 16, rng, 0.02) is None
    drawn = decision_clips(clear, scene, stop, 0.0, 16, rng, 0.02)
    assert drawn is not None and len(drawn) == 16
    # the run's estimator counts the waits and says so at the end of a run
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 5.0, "box_friction": 0.45})
    with MovingHorizonEstimator(scene, space, MHESettings()) as mhe:
        assert mhe._decision_clips(kicked, stop, 0.0, 16, rng) is None and mhe.legs_held == 1
        assert mhe._decision_clips(clear, stop, 0.0, 16, rng) is not None and mhe.legs_held == 1
        mhe.decision_times.append(0.4)
        assert "1 test(s) or decision(s) held where the box moved only under a leg alone" in mhe.describe_decisions()
    # the foot on the box for the first half of the span, off it for the second: the leg's clips stay in the
    # draw beside the push's
    half = len(lunge) // 2
    mixed = replace(clear, box_pos=np.concatenate([kicked.box_pos[:half], clear.box_pos[half:]]))
    drawn = decision_clips(mixed, scene, stop, 0.0, 64, rng, 0.02)
    assert drawn is not None and (drawn.start < half - 200).sum() > 8 and (drawn.start > half).sum() > 8
    # the foot on the box for four fifths of the span: a push's worth of clean clips after it, but the leg's
    # outnumber them more than two to one (an emulated T3 run's late span, the robot stepping round the box: 87 %
    # of its moving clip starts a leg's alone, 0.16 s clean; it read a change that was not there): it waits
    most = len(lunge) * 4 // 5
    kicks = replace(clear, box_pos=np.concatenate([kicked.box_pos[:most], clear.box_pos[most:]]))
    assert (len(lunge) - most) * lunge.dt > 2 * MOVING_MIN
    assert held_by_legs(kicks, scene, stop, 0.0, 0.02) and decision_clips(kicks, scene, stop, 0.0, 16, rng, 0.02) is None
    # a span where the foot is on the box until the box comes off it: with less than MOVING_MIN's worth of
    # clip starts after, it waits; with more, it draws
    hi = int(round(clip_plan(clear)[1][1] / lunge.dt))  # the longest clip
    need = int(round(MOVING_MIN / lunge.dt))
    for clean, tells in ((need // 2, False), (2 * need, True)):
        off = stop - 1 - hi - clean  # clips from here on, `clean` of them, end by stop with the box off the foot
        later = replace(clear, box_pos=np.concatenate([kicked.box_pos[:off], clear.box_pos[off:]]))
        drawn = decision_clips(later, scene, stop, float(lunge.t[off - need]), 16, rng, 0.02)
        assert (drawn is not None) == tells
    with pytest.raises(ValueError, match="part"):
        scene.robot_box_gap(q, part="arm")


def test_a_robot_near_the_box_but_not_touching_it_tells_its_payload():
    """The box 0.15 m ahead of the head plate, inside the robot's reach radius until the last, deepest
    lunge pushes it off: the clips of the robot's lunges clear of it are kept by the geometry (the radius
    alone kept only those after the push) and the payload is fitted as with the box far away."""
    log = _lunge_log(payload=0.6, box_xy=(0.28 + 0.19 + 0.15, 0.0))
    scene = Scene(SceneConfig())
    reach = np.linalg.norm(log.base_pos[:, :2] - log.box_pos[:, :2], axis=1)
    inside = reach < ROBOT_REACH + 0.5 * np.hypot(0.38, 0.38)
    assert inside[:int(5.0 / log.dt)].all()  # the first two lunges, within the radius
    assert (scene.robot_box_gap(scene.qpos_qvel(log)[0][::50]) < CLEAR_GAP).any()  # and touched
    fit = fit_payload(log, scene, nthread=2)
    assert fit is not None and fit.clips == 32
    assert fit.value == pytest.approx(0.6, abs=0.03), fit
    assert (sample_rest_clips(log, scene, 32).start < int(5.0 / log.dt)).sum() > 8  # most from those lunges


def test_a_robot_unlike_its_model_gets_its_payload_and_robot_box_friction(tmp_path, heavy_robot_log):
    """load_problem models the payload it finds, says so, and frees the robot-box friction by default;
    a robot that is its model keeps the box's parameters only."""
    path = write_mcap(tmp_path / "heavy.mcap", replace(heavy_robot_log, meta={}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        problem = load_problem(str(path), nthread=2)
    text = " ".join(str(w.message) for w in caught)
    assert "payload" in text and "robot_box_friction is freed" in text
    assert problem.scene.config.trunk_payload == pytest.approx(0.6, abs=0.03)
    assert problem.space.free == DEFAULT_FREE + ("robot_box_friction",)
    assert problem.robot_differs == ("payload",)
    assert problem.traj.meta["sensors"]["payload"]["applied"] is True
    assert problem.traj.meta["sensors"]["robot_differs"] == ["payload"]  # a clean log: identify draws by motion
    # asked for explicitly, the free set is the caller's
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert load_problem(str(path), params=("box_mass",), nthread=2).space.free == ("box_mass",)
    plain = write_mcap(tmp_path / "plain.mcap", replace(_lunge_log(box_xy=FAR_BOX), meta={}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        nominal = load_problem(str(plain), nthread=2)
    assert nominal.space.free == DEFAULT_FREE and nominal.robot_differs == ()
    assert nominal.traj.meta["sensors"]["robot_differs"] == []
    assert abs(nominal.scene.config.trunk_payload) < 0.03


def test_a_scene_payload_is_trunk_mass_and_the_free_parameter_replaces_it():
    plain, heavy = Scene(SceneConfig()), Scene(SceneConfig(trunk_payload=0.5))
    trunk = plain.model.body("trunk").id
    assert heavy.model.body_mass[trunk] == pytest.approx(plain.model.body_mass[trunk] + 0.5)
    np.testing.assert_allclose(heavy.model.body_inertia[trunk], plain.model.body_inertia[trunk])
    assert SceneConfig.from_dict(heavy.config.to_dict()).trunk_payload == 0.5
    space = ParameterSpace(heavy, free=("trunk_payload",))
    assert space.mean0[0] == pytest.approx(0.5)  # the prior is the scene's payload
    m = heavy.model
    space.write(m, np.array([0.8]))
    assert m.body_mass[trunk] == pytest.approx(plain.model.body_mass[trunk] + 0.8)
    with pytest.raises(AmheError, match="trunk payload"):
        Scene(SceneConfig(trunk_payload=-10.0))


def test_coverage_counts_intervals_that_hold_the_truth():
    est = np.array([[1.0, 0.5], [1.35, 0.45], [0.55, 0.515]])
    std = np.array([[0.1, 0.01], [0.1, 0.03], [0.3, 0.01]])
    got = coverage(est, std, np.array([1.1, 0.5]))
    np.testing.assert_array_equal(got, [[True, True], [False, True], [True, True]])
    assert got[:, 0].mean() == pytest.approx(2 / 3)
    with pytest.raises(ValueError):
        coverage(est, -std, np.array([1.1, 0.5]))


def _with_box_noise(tmp_path, sigma: float, seed: int):
    """The lunge log, and it read back from MCAP with white noise ``sigma`` [m] on the box's positions
    and without: (trajectory, noisy read, clean read)."""
    traj = _lunge_log()
    rng = np.random.default_rng(seed)
    noisy = replace(traj, box_pos=traj.box_pos + rng.normal(0, sigma, traj.box_pos.shape), meta={})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the smoothing notice
        read = read_log(write_mcap(tmp_path / "noisy.mcap", noisy))
        clean = read_log(write_mcap(tmp_path / "clean.mcap", replace(traj, meta={})))
    return traj, read, clean


def test_mhe_skips_a_box_at_rest_that_only_noise_moves(tmp_path):
    """With 1 mm of pose noise a resting box reads a speed, so its clips pass the MHE's speed test;
    the travel test (the noise's own scale, from the log) drops them and keeps the bumps."""
    from amhe_cli.estimation.clips import box_travel, rest_travel, window_clips
    from amhe_cli.estimation.mhe import MHESettings
    traj, read, clean = _with_box_noise(tmp_path, 0.001, seed=1)
    assert rest_travel(clean) == 0.0
    travel = rest_travel(read)
    assert 0.001 < travel < 0.01
    scene = Scene(SceneConfig())
    s = MHESettings()
    speed = np.linalg.norm(traj.box_linvel[:, :2], axis=1)
    first = int(np.argmax(speed > 0.05))  # the first bump
    assert first > 250
    rest = (0, first - 50)  # the box at rest, only noise on its pose
    clip = int(round(s.clip / read.dt))
    assert window_clips(read, scene, *rest, clip, s.max_steps, s.min_speed) is not None  # noise passes
    assert window_clips(read, scene, *rest, clip, s.max_steps, s.min_speed, travel) is None
    bump = (first - 50, first + 200)
    kept = window_clips(read, scene, *bump, clip, s.max_steps, s.min_speed, travel)
    assert kept is not None and np.all(box_travel(read, kept.start, kept.horizon) > travel)


def test_velocity_noise_matches_a_resting_box_and_lengthens_the_mhe_clips(tmp_path):
    """The velocity noise predicted from the log's measured pose noise and smoothing window is what a
    resting box's read velocity shows; the MHE's clips grow with it so friction shows through it."""
    from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator, noise_clip
    from amhe_cli.io.smoothing import velocity_noise
    traj, read, clean = _with_box_noise(tmp_path, 0.001, seed=2)
    speed = np.linalg.norm(traj.box_linvel[:, :2], axis=1)
    rest = slice(50, int(np.argmax(speed > 0.05)) - 50)  # the box at rest before the first bump
    seen = read.box_linvel[rest, :2].std()
    predicted = velocity_noise(read.meta, "box", read.dt)
    assert predicted == pytest.approx(seen, rel=0.15)
    assert velocity_noise(clean.meta, "box", clean.dt) == 0.0 and noise_clip(clean) == 0.0
    assert noise_clip(read) == pytest.approx(4 * predicted / (0.05 * 9.81))
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"))
    with MovingHorizonEstimator(scene, space, MHESettings(window=1.0, max_steps=10_000), nthread=1) as m:
        stop = int(np.argmax(speed > 0.05)) + 200
        long_clips = m.window_clips(read, stop)
        short_clips = m.window_clips(clean, stop)
    want = int(round(min(max(0.1, noise_clip(read)), 1.0) / read.dt))
    assert long_clips.horizon.max() == want > short_clips.horizon.max() == int(round(0.1 / read.dt))


def test_the_mhe_spends_the_rest_of_its_step_budget_on_the_next_clip_cut_to_it(tmp_path):
    """A noise-sized clip that does not divide the step budget leaves a remainder; where it is at least half
    a clip the next most excited clip is rolled out cut to it (a 95-step clip in 150 steps was one clip,
    55 steps unspent), where less it is left; a clean log's 0.1 s clips divide the library's 150."""
    from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator, noise_clip
    traj, read, clean = _with_box_noise(tmp_path, 0.001, seed=2)
    c = int(round(noise_clip(read) / read.dt))
    assert c > 60  # longer than the 0.1 s (50-step) clip of a clean log
    speed = np.linalg.norm(traj.box_linvel[:, :2], axis=1)
    stop = int(np.argmax(speed > 0.05)) + 200
    scene = Scene(SceneConfig())

    def horizons(log, **kw):
        space = ParameterSpace(scene, free=("box_mass", "box_friction"))
        with MovingHorizonEstimator(scene, space, MHESettings(window=1.0, **kw), nthread=1) as m:
            return sorted(m.window_clips(log, stop).horizon.tolist())

    budget = c + (2 * c) // 3
    assert horizons(read, max_steps=budget) == [budget - c, c]  # the whole budget
    assert horizons(read, max_steps=c + c // 3) == [c]  # a third of a clip: left unspent
    assert horizons(clean, max_steps=150) == [50, 50, 50]


def test_identify_plans_its_clips_by_the_logs_noise_and_robot(tmp_path):
    """identify.clip_plan: 48 clips of 0.07–0.13 s where the box's velocity holds no measurement noise (a
    push's chaos grows with the horizon), 32 of 0.1–0.2 s where it does (a longer clip outweighs its noisy
    start), the same simulated time either way; chosen by information, but by box motion on a clean log
    whose robot the reading found unlike its model; what a user gives wins."""
    from amhe_cli.estimation.identify import CLEAN_LOG_CLIPS, INFORMATION_CANDIDATES, NOISY_LOG_CLIPS, clip_plan
    _, read, clean = _with_box_noise(tmp_path, 0.001, seed=2)
    assert clip_plan(clean) == (*CLEAN_LOG_CLIPS, INFORMATION_CANDIDATES) == (48, (0.07, 0.13), 4)
    assert clip_plan(read) == (*NOISY_LOG_CLIPS, INFORMATION_CANDIDATES) == (32, (0.1, 0.2), 4)
    # clips × mean horizon: the same simulated time per candidate, so the same wall time
    simulated = [n * np.mean(h) for n, h in (CLEAN_LOG_CLIPS, NOISY_LOG_CLIPS)]
    assert simulated[0] == pytest.approx(simulated[1])
    assert clip_plan(read, 12, (0.2, 0.3), 1) == (12, (0.2, 0.3), 1)
    assert clip_plan(clean, None, (0.2, 0.3)) == (48, (0.2, 0.3), 4)
    assert clip_plan(read, 20) == (20, (0.1, 0.2), 4)
    clean.meta.setdefault("sensors", {})["robot_differs"] = ["payload"]
    assert clip_plan(clean) == (48, (0.07, 0.13), 1)  # by motion: information at a wrong model
    assert clip_plan(clean, candidates=3)[2] == 3
    read.meta["sensors"]["robot_differs"] = ["payload"]
    assert clip_plan(read) == (32, (0.1, 0.2), 4)  # noisy: the draw by motion's noise costs more


def test_a_live_go1_window_reaches_the_mhe_as_the_reader_makes_a_log():
    """The online MHE's window of a Go1 run: the box's velocity from its mocap samples (smoothed as a log's
    are), not the estimator's lagging low-pass; the noise measured and in W_x, as mhe-replay would see it."""
    from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator
    from amhe_cli.plants.go1.plant import Go1Plant, Go1Settings
    scene = Scene(SceneConfig())
    plant = Go1Plant(scene, Go1Settings(), link=object(), poses=object())  # no network: the recording is filled here
    rng = np.random.default_rng(3)
    box0 = scene.model.qpos0[scene.box_qpos].copy()
    box_pos = lambda t: box0[:3] + [0.2 * t, 0.0, 0.0]  # noqa: E731 - sliding at 0.2 m/s along x
    for t in np.arange(0.0, 1.5, 1 / 120):  # 120 Hz motion capture with 1 mm of noise
        plant._raw["box"].append((t, box_pos(t) + rng.normal(0, 0.001, 3), box0[3:], len(plant._raw["box"])))
        plant._raw["base"].append((t, np.array([0.0, 0.0, 0.27]) + rng.normal(0, 0.001, 3), np.array([1.0, 0, 0, 0]),
                                   len(plant._raw["base"])))
    for t in np.arange(0.0, 1.5, 0.002):  # 500 Hz ticks; the estimator's box velocity still zero (a lag)
        qpos = scene.model.qpos0.copy()
        qpos[scene.box_qpos[:3]] = box_pos(t)
        plant._rec["t"].append(t)
        plant._rec["qpos"].append(qpos)
        plant._rec["qvel"].append(np.zeros(scene.model.nv))
        plant._rec["ctrl"].append(np.zeros(12))
        plant._rec["servo"].append(True)  # the servo at the run's gains (not a soft hold)
        plant._rec["tau"].append(np.zeros(12))
    traj = plant.trajectory(last=1.0)
    assert 0.95 <= traj.t[-1] - traj.t[0] <= 1.01
    mid = slice(len(traj) // 4, 3 * len(traj) // 4)
    np.testing.assert_allclose(traj.box_linvel[mid, 0].mean(), 0.2, atol=0.01)
    assert traj.box_linvel[mid, 0].std() < 0.05  # smoothed: a backward difference of 1 mm noise at 120 Hz is 0.2 m/s
    assert traj.meta["smoothing"]["box"]["position_window"] > 1
    assert traj.meta["sensors"]["streams"]["box"]["position_noise_m"] == pytest.approx(0.001, rel=0.3)
    w = StateWeights.for_log(traj)
    assert w.sigma["box_linvel"] == np.inf and w.sigma["box_pos"] > DEFAULT_SIGMA["box_pos"]
    assert w.sigma["base_linvel"] == DEFAULT_SIGMA["base_linvel"]  # the trunk's are the estimator's, kept
    # the recording a log keeps is not smoothed: the box pose only where a sample arrived
    rec = plant.recording()
    assert rec.observed["box"].sum() == len(plant._raw["box"]) and "smoothing" not in rec.meta
    # an MHE given no W_x takes each window's from its sensor report
    space = ParameterSpace(scene, free=("box_mass", "box_friction"))
    with MovingHorizonEstimator(scene, space, MHESettings(iters=1, samples=3), nthread=1) as mhe:
        assert not mhe.update(traj, float(traj.t[-1])).skipped
        assert mhe._cost.weights.sigma == w.sigma


def test_identify_adds_the_friction_a_noisy_clip_start_cannot_tell_and_a_clean_log_gets_none(tmp_path):
    """A noisy log's clips start from a smoothed velocity off by σ_v: μ's σ holds 2 σ_v / (g T) for the clips'
    mean horizon T (no resample or search spread sees that error); a clean log's σ has no such term."""
    from amhe_cli.estimation.identify import IdentifySettings, identify
    from amhe_cli.estimation.uncertainty import sensing_friction_std
    from amhe_cli.io.smoothing import velocity_noise
    assert sensing_friction_std(0.024, 0.15) == pytest.approx(2 * 0.024 / (9.81 * 0.15))
    assert sensing_friction_std(0.0, 0.15) == 0.0
    with pytest.raises(ValueError, match="horizon"):
        sensing_friction_std(0.02, 0.0)
    _, read, clean = _with_box_noise(tmp_path, 0.001, seed=2)
    scene = Scene(SceneConfig())
    settings = IdentifySettings(params=("box_mass", "box_friction"), n_clips=8, max_gen=4, popsize=6, candidates=1)
    for traj, noisy in ((read, True), (clean, False)):
        space = ParameterSpace(scene, free=("box_mass", "box_friction"))
        res = identify(traj, scene, space, settings, nthread=1)
        src = res.curvature.sources
        if noisy:
            want = sensing_friction_std(velocity_noise(traj.meta, "box", traj.dt),
                                        float(np.mean(res.clips.horizon)) * traj.dt)
            assert want > 0.01
            assert src["sensing"][1] == pytest.approx(want) and src["sensing"][0] == 0.0
            assert res.curvature.std[1] >= want
        else:
            assert "sensing" not in src
