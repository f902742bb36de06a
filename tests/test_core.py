"""Tests of the core pipeline: scene, parameters, clips, cost, uncertainty, identify, plant.

One synthetic log is generated per module (0.2 s of CPU): the simulated Go1
stands behind a 5 kg box (box–floor μ 0.45) and lunges three times
(:func:`~amhe_cli.control.maneuver.lunge_schedule`), so the head bumps the box and it
slides free three times. Everything downstream is checked against that known
truth: the cost is lowest there, clips rolled out under the truth reproduce the
log, ``identify`` recovers it.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import mujoco
import numpy as np
import pytest

from amhe_cli.estimation.clips import ROLES, choose_informative, join_clips, make_clips, sample_clips
from amhe_cli.estimation.cost import DEFAULT_SIGMA, RolloutCost, StateWeights
from amhe_cli.errors import AmheError
from amhe_cli.estimation.identify import IdentifySettings, identify
from amhe_cli.control.maneuver import lunge_schedule
from amhe_cli.model.params import PARAMETERS, ParameterSpace, parse_names
from amhe_cli.plants.sim import SimPlant
from amhe_cli.model.scene import (
    STAND_JOINTS,
    FloorRegion,
    Scene,
    SceneConfig,
    set_pd_gains,
    uniform_box_inertia,
)
from amhe_cli.io.trajectory import GO1_JOINTS
from amhe_cli.estimation.uncertainty import clip_information, curvature
from amhe_cli.estimation.surrogate import bootstrap_minima, fit_valley, unresolved_variance

TRUTH = {"box_mass": 5.0, "box_friction": 0.45}
#: the standing robot's head front is at x ≈ 0.28 m; box half-size 0.19 m; 1 cm gap
BOX_XY = (0.28 + 0.19 + 0.01, 0.0)
G = 9.81


def _generate(disable_warmstart: bool = False):
    plant = SimPlant(SceneConfig(), truth=dict(TRUTH))
    if disable_warmstart:
        plant.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_WARMSTART
    q, _ = plant.scene.standing_state(box_xy=BOX_XY)
    plant.reset(q)
    for u in lunge_schedule():
        plant.step(u)
    return plant, plant.trajectory()


@pytest.fixture(scope="module")
def log():
    return _generate()


@pytest.fixture(scope="module")
def traj(log):
    return log[1]


@pytest.fixture(scope="module")
def scene():
    return Scene(SceneConfig())


@pytest.fixture(scope="module")
def space2(scene):
    return ParameterSpace(scene, free=("box_mass", "box_friction"))


@pytest.fixture(scope="module")
def clips(traj, scene):
    return sample_clips(traj, scene, 12, rng=np.random.default_rng(0))


@pytest.fixture(scope="module")
def cost(scene, space2, clips):
    with RolloutCost(scene, space2, clips, prior_weight=0.0) as c:
        yield c


def _truth_vec(space):
    return space.vector(TRUTH)


def _box_speed(traj):
    return np.linalg.norm(traj.box_linvel[:, :2], axis=1)


def _independent_masks(traj):
    """Deep copy of ``traj`` whose role masks are separate arrays (see the plant aliasing test)."""
    t = copy.deepcopy(traj)
    t.observed = {k: np.array(v, dtype=bool, copy=True) for k, v in t.observed.items()}
    return t


# --------------------------------------------------------------------------- the log itself
def test_generated_log_has_three_bumps(traj):
    """Sanity of the fixture every other test relies on: the box really is pushed, three times."""
    assert abs(traj.dt - 0.002) < 1e-12
    assert 6.5 < traj.duration < 7.5
    moving = _box_speed(traj) > 0.02
    onsets = np.flatnonzero(np.diff(moving.astype(int)) == 1)
    assert len(onsets) == 3
    assert traj.box_pos[-1, 0] - traj.box_pos[0, 0] > 0.05  # it ends further away
    assert _box_speed(traj).max() > 0.2


# --------------------------------------------------------------------------- scene
def test_scene_actuators_in_go1_order(scene):
    m = scene.model
    assert m.nu == 12
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.actuator_trnid[i, 0]) for i in range(m.nu)]
    assert names == list(GO1_JOINTS)
    # the scene's own qpos addresses point at those joints too
    for k, name in enumerate(GO1_JOINTS):
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert scene.joint_qpos[k] == m.jnt_qposadr[j]
        assert scene.joint_qvel[k] == m.jnt_dofadr[j]


def test_scene_robot_mass(scene):
    m = scene.model
    robot = [b for b in range(1, m.nbody) if b != scene.box_body]
    expected = 5.204 + 4 * (0.68 + 1.009 + 0.195862)  # docs/reference.md#go1
    assert m.body_mass[robot].sum() == pytest.approx(expected, abs=1e-6)
    assert m.body_mass[robot].sum() == pytest.approx(12.74, abs=0.01)
    assert m.body_mass[scene.box_body] == pytest.approx(SceneConfig().box_mass)


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_box_floor_friction_is_the_pair_value(mu):
    """A box launched at 1 m/s slides v²/(2 μ g): box–floor friction is exactly the pair's μ."""
    s = Scene(SceneConfig(regions=(FloorRegion(mu=mu),)))
    m = s.model
    d = mujoco.MjData(m)
    q, _ = s.standing_state(box_xy=(3.0, 0.0))  # robot far away
    d.qpos[:] = q
    d.ctrl[:] = STAND_JOINTS
    mujoco.mj_step(m, d, nstep=100)  # box settles onto the floor
    box_contacts = [i for i in range(d.ncon)
                    if s.box_body in (m.geom_bodyid[d.contact.geom1[i]], m.geom_bodyid[d.contact.geom2[i]])]
    assert box_contacts, "box does not touch the floor"
    for i in box_contacts:  # every box-floor contact carries the pair's coefficient, not a max()
        assert d.contact.friction[i][0] == pytest.approx(mu, abs=1e-12)
        assert d.contact.friction[i][1] == pytest.approx(mu, abs=1e-12)
    x0 = d.qpos[s.box_qpos[0]]
    d.qvel[s.box_qvel[0]] = 1.0
    mujoco.mj_step(m, d, nstep=int(round(1.0 / m.opt.timestep)))
    dist = d.qpos[s.box_qpos[0]] - x0
    assert abs(d.qvel[s.box_qvel[0]]) < 1e-3  # it has stopped
    assert dist == pytest.approx(1.0 / (2 * mu * G), rel=0.03)


def test_set_pd_gains_changes_actuator_force(scene):
    m = copy.copy(scene.model)
    d = mujoco.MjData(m)
    q, _ = scene.standing_state(box_xy=(3.0, 0.0))

    def force(kp, kd):
        set_pd_gains(m, kp, kd)
        d.qpos[:] = q
        d.qvel[:] = 0
        d.qvel[scene.joint_qvel] = 0.5
        d.ctrl[:] = STAND_JOINTS + 0.1
        mujoco.mj_forward(m, d)
        return d.actuator_force.copy()

    np.testing.assert_allclose(force(55.0, 3.0), 55.0 * 0.1 - 3.0 * 0.5, atol=1e-9)
    np.testing.assert_allclose(force(30.0, 2.0), 30.0 * 0.1 - 2.0 * 0.5, atol=1e-9)
    kp = np.linspace(20, 60, 12)
    kd = np.linspace(1, 4, 12)
    np.testing.assert_allclose(force(kp, kd), kp * 0.1 - kd * 0.5, atol=1e-9)
    # the template is untouched
    assert scene.model.actuator_gainprm[0, 0] == pytest.approx(55.0)
    # and SceneConfig gains reach the compiled model
    s2 = Scene(SceneConfig(kp=tuple([40.0] * 12), kd=tuple([2.5] * 12)))
    np.testing.assert_allclose(s2.model.actuator_gainprm[:, 0], 40.0)
    np.testing.assert_allclose(s2.model.actuator_biasprm[:, 1:3], [[-40.0, -2.5]] * 12)


# --------------------------------------------------------------------------- params
def _push_speed(scene, space, mass, force=50.0, duration=0.2):
    """Box x-speed after ``force`` [N] at its centre for ``duration`` [s], box friction 0.01."""
    m = copy.copy(scene.model)
    space.write(m, space.vector({"box_mass": mass, "box_friction": 0.01}))
    d = mujoco.MjData(m)
    q, _ = scene.standing_state(box_xy=(3.0, 0.0))
    d.qpos[:] = q
    d.ctrl[:] = STAND_JOINTS
    mujoco.mj_step(m, d, nstep=50)
    d.xfrc_applied[scene.box_body, 0] = force
    mujoco.mj_step(m, d, nstep=int(round(duration / m.opt.timestep)))
    return d.qvel[scene.box_qvel[0]]


def test_write_heavier_box_is_slower(scene, space2):
    v5 = _push_speed(scene, space2, 5.0)
    v10 = _push_speed(scene, space2, 10.0)
    assert v5 > 0.5
    assert v5 / v10 == pytest.approx(2.0, rel=0.05)
    # and it matches F/m - μ g within 5 %
    assert v5 == pytest.approx((50.0 / 5.0 - 0.01 * G) * 0.2, rel=0.05)


def test_write_calls_set_const(scene, space2):
    m = copy.copy(scene.model)
    before = m.body_invweight0[scene.box_body].copy()
    space2.write(m, space2.vector({"box_mass": 10.0}))
    assert m.body_mass[scene.box_body] == 10.0
    # a free body's translational inverse weight is 1/m: refreshed by mj_setConst
    assert m.body_invweight0[scene.box_body, 0] == pytest.approx(1.0 / 10.0, rel=1e-3)
    assert before[0] == pytest.approx(1.0 / SceneConfig().box_mass, rel=1e-3)
    # friction reaches every box-floor pair; the template is untouched
    space2.write(m, space2.vector({"box_friction": 0.77}))
    np.testing.assert_allclose(m.pair_friction[scene.region_pairs, :2], 0.77)
    assert scene.model.body_mass[scene.box_body] == pytest.approx(SceneConfig().box_mass)


def _triangle_ok(inertia, tol=1e-9):
    a, b, c = inertia.T
    return np.all(a <= b + c + tol) & np.all(b <= a + c + tol) & np.all(c <= a + b + tol)


def test_project_bounds_and_inertia_triangle(scene):
    space = ParameterSpace(scene)  # mass, inertia shape ratios (3), friction
    assert space.labels == ["box_mass", "box_inertia_0", "box_inertia_1", "box_inertia_2", "box_friction"]
    sl = space.slices()["box_inertia"]
    rng = np.random.default_rng(1)
    P = np.column_stack([
        rng.uniform(-5, 60, 200),
        np.exp(rng.uniform(np.log(1e-3), np.log(20), (200, 3))),
        rng.uniform(-1, 3, 200),
    ])
    P[0, sl] = [4.9, 0.2, 0.2]   # the worst violation inside the bounds
    P[1, sl] = [50.0, 0.0, 0.0]  # out of bounds and infeasible
    Q, moved = space.project(P)
    assert np.all(Q >= space.lower - 1e-12) and np.all(Q <= space.upper + 1e-12)
    moments = np.array([space.values(q)["box_inertia"] for q in Q])
    assert _triangle_ok(moments)
    raw = np.array([space.values(p)["box_inertia"] for p in P])
    infeasible = np.any(P < space.lower, axis=1) | np.any(P > space.upper, axis=1) | ~np.array(
        [_triangle_ok(m[None], tol=0.0) for m in raw])
    assert infeasible.sum() > 50
    assert np.all(moved[infeasible] > 0)
    # feasible candidates pass through unchanged with zero penalty
    feas = np.tile(space.mean0, (5, 1))
    feas[:, 0] = [0.5, 1, 5, 20, 39]
    for row in feas:
        row[sl] = space.vector({"box_mass": row[0], "box_inertia": uniform_box_inertia(row[0], (0.3, 0.5, 0.2))})[sl]
    Qf, mf = space.project(feas)
    np.testing.assert_allclose(Qf, feas, rtol=1e-12)
    np.testing.assert_array_equal(mf, 0.0)
    # the inertia coordinates are shape ratios: physical moments follow the mass
    np.testing.assert_allclose(space.values(feas[2])["box_inertia"], uniform_box_inertia(5.0, (0.3, 0.5, 0.2)))


def test_parse_names():
    with pytest.raises(AmheError, match="nope"):
        parse_names("box_mass,nope")
    with pytest.raises(AmheError):
        parse_names("")
    assert parse_names("box_friction, box_mass") == ("box_mass", "box_friction")  # canonical order
    assert parse_names(None) == ("box_mass", "box_inertia", "box_friction")


def test_inertia_follows_mass_when_not_free(scene, space2):
    prior_inertia = space2.prior_values["box_inertia"]
    prior_mass = space2.prior_values["box_mass"][0]
    vals = space2.values(np.array([2 * prior_mass, 0.5]))
    np.testing.assert_allclose(vals["box_inertia"], 2 * prior_inertia)
    m = copy.copy(scene.model)
    space2.write(m, np.array([2 * prior_mass, 0.5]))
    np.testing.assert_allclose(m.body_inertia[scene.box_body], 2 * prior_inertia)
    # a free inertia is a shape ratio to the mass-scaled prior: ratio 1 follows the mass, 1.5 is 1.5x that
    space5 = ParameterSpace(scene)
    vec = space5.mean0.copy()
    vec[0] *= 2
    np.testing.assert_allclose(space5.values(vec)["box_inertia"], 2 * space5.prior_values["box_inertia"])
    vec[space5.slices()["box_inertia"]] = 1.5
    np.testing.assert_allclose(space5.values(vec)["box_inertia"], 3 * space5.prior_values["box_inertia"])


# --------------------------------------------------------------------------- clips
def test_make_clips_alignment(traj, scene):
    starts = np.array([10, 700, 1500])
    horizons = np.array([5, 60, 30])
    c = make_clips(traj, scene, starts, horizons)
    qpos_all, qvel_all = scene.qpos_qvel(traj)
    nq, nv = scene.model.nq, scene.model.nv
    for k, (s, h) in enumerate(zip(starts, horizons)):
        # initial state = the state before step s, at time t[s]
        assert c.initial_state[k, 0] == pytest.approx(traj.t[s])
        np.testing.assert_array_equal(c.initial_state[k, 1:1 + nq], qpos_all[s])
        np.testing.assert_array_equal(c.initial_state[k, 1 + nq:1 + nq + nv], qvel_all[s])
        # row 0 of the recorded states is the state after step s; controls row 0 drives step s
        np.testing.assert_array_equal(c.qpos[k, 0], qpos_all[s + 1])
        np.testing.assert_array_equal(c.qvel[k, 0], qvel_all[s + 1])
        np.testing.assert_array_equal(c.control[k, 0], traj.ctrl[s])
        np.testing.assert_array_equal(c.qpos[k, h - 1], qpos_all[s + h])
        np.testing.assert_array_equal(c.control[k, h - 1], traj.ctrl[s + h - 1])
        assert c.observed[k, :h].all() and not c.observed[k, h:].any()
    assert c.steps == horizons.sum()
    with pytest.raises(AmheError):
        make_clips(traj, scene, [len(traj) - 5], [10])


def test_join_clips_keeps_each_clip_and_says_where_each_part_went(traj, scene):
    a = make_clips(traj, scene, [700, 1500], [60, 30])
    b = make_clips(traj, scene, [10, 900, 1600], [5, 20, 40])
    both, (ia, ib) = join_clips(traj, scene, a, b)
    assert list(both.start) == [10, 700, 900, 1500, 1600] and list(ia) == [1, 3] and list(ib) == [0, 2, 4]
    for part, index in ((a, ia), (b, ib)):
        np.testing.assert_array_equal(both.start[index], part.start)
        np.testing.assert_array_equal(both.horizon[index], part.horizon)
        for k, i in enumerate(index):  # the same clip, padded to the longer batch's horizon
            h = part.horizon[k]
            np.testing.assert_array_equal(both.qpos[i, :h], part.qpos[k, :h])
            np.testing.assert_array_equal(both.control[i, :h], part.control[k, :h])
            np.testing.assert_array_equal(both.initial_state[i], part.initial_state[k])


def test_rollout_matches_mj_step_replay(cost, clips, scene, traj):
    """The cost's batched rollout equals a plain mj_step replay from the clip's initial state."""
    truth = _truth_vec(cost.space)
    qpos, qvel = cost.rollout(truth[None])
    m = copy.copy(scene.model)
    cost.space.write(m, truth)
    for k in range(len(clips)):
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, clips.initial_state[k], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        for t in range(clips.horizon[k]):
            d.ctrl[:] = clips.control[k, t]
            mujoco.mj_step(m, d)
            np.testing.assert_allclose(qpos[0, k, t], d.qpos, atol=1e-12, rtol=0)
            np.testing.assert_allclose(qvel[0, k, t], d.qvel, atol=1e-10, rtol=0)


def test_truth_rollout_reproduces_log_exactly_without_warmstart(scene):
    """Same model, same dt: with the solver's warm start off in plant and cost the match is exact.

    (The warm start ``qacc_warmstart`` is not part of ``mjSTATE_FULLPHYSICS`` and not in any
    log, so with it on the clip starts cold while the plant ran warm: see the next test.)
    """
    plant, traj = _generate(disable_warmstart=True)
    s = Scene(SceneConfig())
    s.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_WARMSTART
    space = ParameterSpace(s, free=("box_mass", "box_friction"))
    c = sample_clips(traj, s, 12, rng=np.random.default_rng(0))
    with RolloutCost(s, space, c, prior_weight=0.0) as cost:
        qpos, qvel = cost.rollout(_truth_vec(space)[None])
        assert np.abs(qpos[0] - c.qpos).max() < 1e-9
        assert np.abs(qvel[0] - c.qvel).max() < 1e-9
        assert cost.evaluate(_truth_vec(space)[None]).data[0] < 1e-12


def test_truth_rollout_reproduces_log(cost, clips):
    """With the default (warm-started) solver: positions within 1e-6, velocities within 1e-4.

    The remaining velocity error (≈1e-5 m/s on clips with active contacts) comes from the
    Newton solver's warm start: the plant's step s began from step s-1's ``qacc_warmstart``,
    the clip's from zero, and the solver stops at its tolerance at slightly different points.
    """
    qpos, qvel = cost.rollout(_truth_vec(cost.space)[None])
    assert np.abs(qpos[0] - clips.qpos).max() < 1e-6
    assert np.abs(qvel[0] - clips.qvel).max() < 1e-4
    assert cost.evaluate(_truth_vec(cost.space)[None]).data[0] < 1e-4


def test_sample_clips_deterministic_and_prefers_moving_box(traj, scene):
    a = sample_clips(traj, scene, 16, rng=np.random.default_rng(3))
    b = sample_clips(traj, scene, 16, rng=np.random.default_rng(3))
    c = sample_clips(traj, scene, 16, rng=np.random.default_rng(4))
    np.testing.assert_array_equal(a.start, b.start)
    np.testing.assert_array_equal(a.horizon, b.horizon)
    np.testing.assert_array_equal(a.control, b.control)
    assert not np.array_equal(a.start, c.start)
    assert np.all((a.horizon >= 50) & (a.horizon <= 100))  # 0.1-0.2 s at 2 ms
    assert len(np.unique(a.start)) == 16
    speed = _box_speed(traj)
    moving_share = (speed > 0.02).mean()
    assert moving_share < 0.2  # the box rests most of the log ...
    for cl in (a, c):
        moves = [speed[s:s + h + 1].max() > 0.02 for s, h in zip(cl.start, cl.horizon)]
        assert np.mean(moves) >= 0.75  # ... yet most clips see it move


def test_sample_clips_warn_where_the_box_rests(traj, scene):
    """Too few starts with the box moving: clips come from where it rests, and a warning says the
    estimate will stay near the prior; a log with enough motion draws without one."""
    speed = _box_speed(traj)
    rest_end = traj.t[int(np.flatnonzero(speed > 0.02)[0])] - 0.3  # up to just before the first push
    with pytest.warns(UserWarning, match=r"at only 0 clip starts.*stays near the prior"):
        c = sample_clips(traj, scene, 8, rng=np.random.default_rng(0), t_range=(0.0, rest_end))
    assert len(c) == 8 and all(speed[s:s + h + 1].max() <= 0.02 for s, h in zip(c.start, c.horizon))
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sample_clips(traj, scene, 8, rng=np.random.default_rng(0))


def test_sample_clips_avoid_gaps(traj, scene):
    t = _independent_masks(traj)
    moving = np.flatnonzero(_box_speed(t) > 0.02)
    i, j = int(moving[0]) + 20, int(moving[0]) + 140  # a box drop-out in the first push
    t.observed["box"][i:j] = False
    for seed in range(3):
        c = sample_clips(t, scene, 16, rng=np.random.default_rng(seed))
        for s, h in zip(c.start, c.horizon):
            assert s + h < i or s >= j, f"clip {s}..{s + h} covers the gap {i}..{j}"
    with pytest.raises(AmheError):  # nothing left long enough
        t2 = _independent_masks(traj)
        t2.observed["base"][::40] = False
        sample_clips(t2, scene, 4)


# --------------------------------------------------------------------------- cost
def test_truth_scores_lowest(cost):
    truth = _truth_vec(cost.space)
    P = np.array([truth, [4.0, 0.45], [6.0, 0.45], [5.0, 0.35], [5.0, 0.55]])
    J = cost(P)
    assert np.all(np.isfinite(J))
    assert np.all(J[0] < J[1:])
    assert J[0] < 1e-4 < 1.0 < J[1:].min()


def test_batch_equals_single_and_deterministic(scene, space2, clips, cost):
    P = np.array([[5.0, 0.45], [4.2, 0.5], [6.3, 0.38], [3.0, 0.7], [5.5, 0.42]])
    batch = cost.evaluate(P)
    single = np.array([cost.evaluate(p[None]).total[0] for p in P])
    np.testing.assert_allclose(batch.total, single, rtol=1e-12, atol=1e-15)
    again = cost.evaluate(P)
    np.testing.assert_array_equal(batch.total, again.total)
    np.testing.assert_array_equal(batch.per_clip, again.per_clip)
    np.testing.assert_array_equal(cost.evaluate(P[::-1]).total[::-1], batch.total)
    # independent of the thread count
    with RolloutCost(scene, space2, clips, prior_weight=0.0, nthread=1) as one:
        np.testing.assert_array_equal(one.evaluate(P).total, batch.total)
    np.testing.assert_allclose(batch.per_clip.sum(axis=1), batch.data)
    np.testing.assert_allclose(batch.total, batch.data + batch.prior + batch.penalty)


def test_float32_states_a_gpu_returns_are_scored_in_float32_to_the_float64_costs(cost, scene):
    """A GPU backend's states are float32: :func:`state_error` keeps them so (half the host memory a wide batch's
    cost walks), and the per-clip costs it sums come back float64 within 1e-4 of scoring the same states in
    float64. The CPU's float64 states are scored as before."""
    from amhe_cli.estimation.cost import state_error
    from amhe_cli.io.quat import quat_normalize, quat_relative_rotvec
    rng = np.random.default_rng(2)
    P = cost.space.project(cost.space.mean0 + 0.2 * cost.space.std0 * rng.standard_normal((4, cost.space.dim)))[0]
    qpos, qvel = cost.rollout(P)
    assert qpos.dtype == np.float64
    c = cost.clips
    e64 = state_error(scene, c.qpos[None], c.qvel[None], qpos, qvel)
    e32 = state_error(scene, c.qpos[None], c.qvel[None], qpos.astype(np.float32), qvel.astype(np.float32))
    assert e64.dtype == np.float64 and e32.dtype == np.float32
    np.testing.assert_allclose(e32, e64.astype(np.float32), atol=1e-5)
    J64 = cost.evaluate(P).per_clip
    J32 = cost.evaluate(P, states=(qpos.astype(np.float32), qvel.astype(np.float32))).per_clip
    assert J32.dtype == np.float64 and np.all(np.abs(J32 - J64) <= 1e-4 * np.abs(J64) + 1e-9)
    a, b = (quat_normalize(rng.normal(size=(5, 4))).astype(np.float32) for _ in range(2))
    r32 = quat_relative_rotvec(a, b, single=True)
    assert r32.dtype == np.float32 and quat_relative_rotvec(a, b).dtype == np.float64  # only where asked
    np.testing.assert_allclose(r32, quat_relative_rotvec(a.astype(float), b.astype(float)), atol=1e-5)


def test_states_already_rolled_out_are_scored_without_a_rollout(cost):
    """``evaluate(P, states=...)`` scores the rollouts given (a GPU launch's own, ``WarpRollout.last_states``) as it
    scores its own, and rolls nothing out."""
    P = np.array([[5.0, 0.45], [4.2, 0.5], [3.0, 0.7]])
    states = cost.rollout(P)
    before = cost.rollout_steps
    given = cost.evaluate(P, states=states)
    assert cost.rollout_steps == before
    np.testing.assert_array_equal(given.per_clip, cost.evaluate(P).per_clip)
    moved = (states[0].copy(), states[1])
    moved[0][0, :, 1:, 0] += 0.1  # the first candidate's trunk 10 cm off after its first step
    assert cost.evaluate(P, states=moved).per_clip[0].sum() > given.per_clip[0].sum()


def test_rollout_step_counter(cost, clips):
    before = cost.rollout_steps
    cost.evaluate(np.tile(_truth_vec(cost.space), (3, 1)))
    assert cost.rollout_steps - before == 3 * clips.steps


def test_extreme_candidates_never_nan(scene, clips):
    space = ParameterSpace(scene, free=("box_mass", "box_friction", "robot_box_friction"))
    lo, hi = space.lower, space.upper
    P = np.array([
        [lo[0], hi[1], hi[2]],
        [lo[0], lo[1], lo[2]],
        [hi[0], lo[1], hi[2]],
        [hi[0], hi[1], lo[2]],
        [1e-6, 0.45, 0.6],     # out of bounds: projected and charged
        [-1.0, -1.0, -1.0],
        [1e3, 1e3, 1e3],
    ])
    with RolloutCost(scene, space, clips) as c:
        br = c.evaluate(P)
    assert np.all(np.isfinite(br.total)) and np.all(np.isfinite(br.per_clip))
    assert np.all(br.penalty[:4] == 0) and np.all(br.penalty[4:] > 0)
    assert np.all(br.total[4:] > br.data[4:])


def test_sigma_inf_removes_a_group(scene, space2, clips):
    wrong = np.array([[6.0, 0.55]])
    with RolloutCost(scene, space2, clips, prior_weight=0.0) as c:
        full = c.evaluate(wrong).data[0]
    assert full > 1.0
    parts = {}
    for g in DEFAULT_SIGMA:
        only = {k: (DEFAULT_SIGMA[k] if k == g else np.inf) for k in DEFAULT_SIGMA}
        with RolloutCost(scene, space2, clips, StateWeights(only), prior_weight=0.0) as c:
            parts[g] = c.evaluate(wrong).data[0]
    # the data term is additive over groups; each σ=inf removes exactly that group's share
    assert sum(parts.values()) == pytest.approx(full, rel=1e-9)
    assert parts["box_pos"] > 0 and parts["box_linvel"] > 0
    with RolloutCost(scene, space2, clips, StateWeights({"box_pos": np.inf}), prior_weight=0.0) as c:
        assert c.evaluate(wrong).data[0] == pytest.approx(full - parts["box_pos"], rel=1e-9)
    nothing = {k: np.inf for k in DEFAULT_SIGMA}
    with RolloutCost(scene, space2, clips, StateWeights(nothing), prior_weight=0.0) as c:
        assert c.evaluate(wrong).data[0] == 0.0
    with pytest.raises(AmheError):
        StateWeights({"box_speed": 1.0})


def test_unobserved_role_weighs_zero(traj, scene, space2):
    t = _independent_masks(traj)
    moving = np.flatnonzero(_box_speed(t) > 0.05)
    s0 = int(moving[0])
    starts, horizons = np.array([s0, s0 + 200]), np.array([80, 80])
    wrong = np.array([[6.0, 0.55]])
    box_off = {k: np.inf for k in DEFAULT_SIGMA if k.startswith("box_")}

    def data(tr, weights=None):
        c = make_clips(tr, scene, starts, horizons)
        with RolloutCost(scene, space2, c, weights, prior_weight=0.0) as cost:
            return cost.evaluate(wrong).per_clip[0], c

    full, _ = data(t)
    no_box_weights, _ = data(t, StateWeights(box_off))
    # box unobserved over all of clip 0 (s0+1 .. s0+80 are its recorded states)
    t.observed["box"][s0 + 1:s0 + 81] = False
    gap, c = data(t)
    assert not c.observed[0, :80, ROLES.index("box")].any()
    assert c.observed[0, :80, ROLES.index("base")].all()
    assert gap[0] == pytest.approx(no_box_weights[0], rel=1e-9)
    assert gap[1] == pytest.approx(full[1], rel=1e-12)  # the other clip is untouched
    assert full[0] > gap[0] > 0


# --------------------------------------------------------------------------- uncertainty
def test_curvature_at_truth(cost):
    truth = _truth_vec(cost.space)
    cur = curvature(cost, truth)
    assert np.all(np.isfinite(cur.std)) and np.all(cur.std > 0)
    # the log informs both far beyond the prior (σ 3 kg, 0.5)
    assert cur.std[0] < 0.1 * cost.space.std0[0]
    assert cur.std[1] < 0.1 * cost.space.std0[1]
    assert cur.std[0] < 0.25  # kg
    assert cur.std[1] < 0.03
    assert np.all(np.abs(cur.corr) <= 1)
    np.testing.assert_allclose(np.diag(cur.corr), 1.0)
    assert cur.cost < 1e-3


def test_uninformed_parameter_keeps_prior_std(traj, scene):
    """Clips from the first second (box resting, robot standing clear of it) say nothing about friction."""
    space = ParameterSpace(scene, free=("box_mass", "box_friction", "robot_box_friction"))
    rest = make_clips(traj, scene, np.arange(50, 450, 40), np.full(10, 75))
    assert np.abs(rest.qvel[..., scene.box_qvel[:3]]).max() < 1e-2
    with RolloutCost(scene, space, rest) as c:
        cur = curvature(c, space.vector({**TRUTH, "robot_box_friction": 0.6}))
    assert np.all(np.isfinite(cur.std))
    for name in ("box_friction", "robot_box_friction"):
        i = space.labels.index(name)
        assert cur.std[i] == pytest.approx(space.std0[i], rel=0.05)


def test_clip_information_sees_the_bumps_not_the_rest(traj, scene, space2):
    """A clip of the resting box tells nothing of its mass or friction; a clip over a bump tells both."""
    speed = _box_speed(traj)
    bump = int(np.flatnonzero(speed > 0.05)[0]) - 20  # just before the first push starts the box
    rest_and_bump = make_clips(traj, scene, [50, 200, bump, bump + 60], [75, 75, 75, 75])
    with RolloutCost(scene, space2, rest_and_bump) as c:
        info = clip_information(c, space2.mean0)
    assert info.shape == (4, 2) and np.all(info >= 0)
    assert info[:2].max() < 1e-6 * info[2:].min(), info  # columns: mass, friction (prior-σ units)
    assert np.all(info[2:] > 1.0), info


def test_choose_informative_keeps_the_clips_a_rare_parameter_needs():
    """Five of 100 candidate clips inform the mass (the bumps), all of them the friction (the slides):
    20 clips chosen by information hold the five bumps, where 20 drawn by box motion would hold one."""
    rng = np.random.default_rng(0)
    info = np.zeros((100, 2))
    bumps = np.array([7, 31, 55, 62, 90])
    info[bumps, 0] = rng.uniform(1.0, 3.0, 5)
    info[:, 1] = rng.uniform(0.5, 1.5, 100)
    held = []
    for seed in range(50):
        idx = choose_informative(info, 20, np.random.default_rng(seed))
        assert idx.size == 20 and np.all(np.diff(idx) > 0)  # sorted, no clip twice
        held.append(np.isin(bumps, idx).sum())
    assert np.mean(held) >= 4.5, held  # a uniform draw holds 1 of the 5 on average
    np.testing.assert_array_equal(choose_informative(info[:10], 20, rng), np.arange(10))  # fewer: all of them
    np.testing.assert_array_equal(choose_informative(info, 20, np.random.default_rng(3)),
                                  choose_informative(info, 20, np.random.default_rng(3)))


# --------------------------------------------------------------------------- identify
@pytest.mark.parametrize("candidates", [1, 3])
def test_identify_recovers_truth(traj, candidates):
    """By box motion (1) and by information among 3 × 12 candidate clips (3), the truth is recovered."""
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"))
    settings = IdentifySettings(params=("box_mass", "box_friction"), n_clips=12, max_gen=25, popsize=10,
                                candidates=candidates)
    res = identify(traj, scene, space, settings)
    assert len(res.clips) == 12
    mass, mu = res.estimate
    with RolloutCost(scene, space, res.clips, prior_weight=settings.prior_weight) as c:
        j_truth = float(c(_truth_vec(space)[None])[0])
    why = (f"estimate {res.estimate} after {len(res.history)} generations: J(estimate) = {res.cost_estimate:.4g}, "
           f"J(truth) = {j_truth:.4g} on the same clips")
    assert mass == pytest.approx(5.0, rel=0.05), why
    assert mu == pytest.approx(0.45, abs=0.03), why
    # the estimate is CMA-ES's mean averaged over its last generations (not a quadratic's minimum over them),
    # and its σ covers the truth: within 3σ, since an honest 2σ misses one run in 20 (this short run, 12 clips and
    # 25 generations, stops in a trough beside the truth's at 2.4σ; over seeds and logs the σ is checked in
    # benchmarks/identify_accuracy.py)
    late = np.mean([h["mean"] for h in res.history[-settings.average_last:]], axis=0)
    np.testing.assert_allclose(res.estimate, space.project(late)[0][0], rtol=1e-12)
    assert np.all(np.abs(res.estimate - _truth_vec(space)) <= 3 * res.curvature.std), \
        f"{why}; σ {res.curvature.std}"
    assert res.cost_estimate < res.cost_prior
    assert res.residual_rms < 1.0  # the model explains the log
    assert np.all(np.isfinite(res.curvature.std)) and np.all(res.curvature.std > 0)
    summ = res.summary()
    assert set(summ["estimate"]) == {"box_mass", "box_friction"}
    # the candidate σ's are reported beside the chosen one, which is never narrower than the data's or the search's
    src = summ["std_sources"]
    assert {"fisher", "least_squares", "sandwich", "search"} <= set(src)
    for name in ("box_mass", "box_friction"):
        assert summ["std"][name] >= max(src[k][name] for k in ("least_squares", "sandwich", "search")) * (1 - 1e-9)
    assert summ["generations"] == len(res.history) <= 25


def test_bootstrap_replicates_leave_the_main_search_unchanged_and_report_their_spread(traj, scene, space2):
    """replicates=4: three searches on resampled clips run beside the main one, which is bit-identical to a
    run without them; their spread is reported as the ``replicates`` σ and each replicate is its own search."""
    base = IdentifySettings(params=("box_mass", "box_friction"), n_clips=8, max_gen=5, popsize=6, candidates=1,
                            seed=2)
    alone = identify(traj, scene, space2, base)
    both = identify(traj, scene, space2, replace(base, replicates=4))
    np.testing.assert_array_equal(both.estimate, alone.estimate)
    np.testing.assert_array_equal(both.curvature.std, alone.curvature.std)
    assert [h["mean"] for h in both.history] == [h["mean"] for h in alone.history]
    assert alone.replicates.size == 0 and "replicates" not in alone.summary()["std_sources"]
    assert both.replicates.shape == (3, 2) and len(np.unique(both.replicates[:, 0])) == 3
    assert both.evaluations == 4 * alone.evaluations
    np.testing.assert_allclose(both.curvature.sources["replicates"], both.replicates.std(axis=0, ddof=1))
    summ = both.summary()
    assert [r["box_mass"] for r in summ["replicates"]] == list(both.replicates[:, 0])
    assert summ["std_sources"]["replicates"]["box_mass"] > 0


def test_fit_valley_recovers_a_quadratic_minimum():
    rng = np.random.default_rng(0)
    Z = rng.normal(size=(60, 2))
    zmin = np.array([0.3, -0.2])
    H = np.array([[2.0, 0.6], [0.6, 1.0]])
    J = 0.5 * np.einsum("ni,ij,nj->n", Z - zmin, H, Z - zmin) + 7.0
    v = fit_valley(Z, J, Z.mean(axis=0))
    assert v.convex and v.r2 == pytest.approx(1.0)
    np.testing.assert_allclose(v.z_min, zmin, atol=1e-9)
    assert fit_valley(Z[:11], J[:11], np.zeros(2)) is None  # fewer than 2 x 6 samples


def test_bootstrap_spread_is_the_clip_sets_own_along_what_they_resolve_and_none_along_what_they_do_not():
    """Clip k pulls z0 toward 0.02 k (convex) and bends z1 the wrong way (a saddle, as a fit over a rough floor can):
    the bootstrap's z0 spread is that of the clips' own minima resampled, and z1, which no clip resolves, stays at
    the centre (unresolved_variance gives it the cloud's extent), where flooring the saddle threw it to the edge."""
    rng = np.random.default_rng(1)
    Z = rng.normal(scale=0.1, size=(80, 2))
    K = np.stack([(Z[:, 0] - 0.02 * k) ** 2 - 0.5 * Z[:, 1] ** 2 + 1e-3 * rng.normal(size=80) for k in range(8)], 1)
    v = fit_valley(Z, K.sum(axis=1), np.zeros(2))
    assert not v.convex
    minima = bootstrap_minima(Z, K, v, prior_weight=0.0, n_boot=2000, rng=np.random.default_rng(0))
    assert minima.shape == (2000, 2) and np.all(np.isfinite(minima))
    # the mean of 8 clip minima 0.02 k resampled with replacement: spread std(0.02 k) / sqrt(8)
    assert minima[:, 0].std() == pytest.approx(np.std(0.02 * np.arange(8)) / np.sqrt(8), rel=0.1)
    assert minima[:, 0].mean() == pytest.approx(0.07, abs=0.005)
    assert minima[:, 1].std() < 0.02 * v.scale[1]
    # made convex (the saddle term's sign flipped), z1 is resolved: its minimum 0 for every clip set
    Kc = K + Z[:, 1:2] ** 2
    vc = fit_valley(Z, Kc.sum(axis=1), np.zeros(2))
    assert vc.convex
    mc = bootstrap_minima(Z, Kc, vc, prior_weight=0.0, rng=np.random.default_rng(0))
    assert mc[:, 1].std() < 0.05 * vc.scale[1] and abs(mc[:, 1].mean()) < 0.01
    # a bound holds every minimiser within that many sample σ of the centre
    tight = bootstrap_minima(Z, K, v, prior_weight=0.0, rng=np.random.default_rng(0), bound=0.2)
    assert np.all(np.abs(tight - v.centre) <= 0.2 * v.scale + 1e-12)


def test_unresolved_variance_gives_a_direction_no_clip_curves_the_clouds_extent_and_a_resolved_one_none():
    rng = np.random.default_rng(2)
    Z = rng.normal(scale=[0.1, 0.2], size=(80, 2))
    J = 50.0 * Z[:, 0] ** 2 + 1e-4 * rng.normal(size=80)  # z0 curved, z1 flat
    v = fit_valley(Z, J, np.zeros(2))
    var = unresolved_variance(v, prior_weight=0.0, bound=3.0)
    assert var[1] == pytest.approx((3.0 * v.scale[1]) ** 2, rel=1e-3)
    assert var[0] < 1e-6 * (3.0 * v.scale[0]) ** 2
    # curved along both (z1 a tenth as stiff: above the 1 % line), nothing is left unresolved
    v2 = fit_valley(Z, J + 5.0 * Z[:, 1] ** 2, np.zeros(2))
    assert np.all(unresolved_variance(v2, prior_weight=0.0) == 0.0)


# --------------------------------------------------------------------------- plant
def test_plant_set_param():
    plant = SimPlant(SceneConfig(), truth=dict(TRUTH))
    b = plant.scene.box_body
    assert plant.model.body_mass[b] == pytest.approx(5.0)
    assert plant.model.pair_friction[plant.scene.region_pairs, 0] == pytest.approx(0.45)
    plant.set_param("box_mass", 6.0)
    assert plant.model.body_mass[b] == pytest.approx(6.0)
    np.testing.assert_allclose(plant.model.body_inertia[b], uniform_box_inertia(6.0, SceneConfig().box_size))
    assert plant.model.body_invweight0[b, 0] == pytest.approx(1 / 6.0, rel=1e-3)
    assert plant.truth_values["box_mass"] == pytest.approx(6.0)
    assert plant.model.pair_friction[plant.scene.region_pairs, 0] == pytest.approx(0.45)  # others kept


def test_plant_writes_a_payload_once_whatever_else_changes():
    """Each set_param rewrites the whole truth: a trunk payload must not be added again at every write
    (an emulated robot with a payload and a second robot-side change, or a task event, once carried it
    twice, three times after T3's switch)."""
    plant = SimPlant(SceneConfig(), truth=dict(TRUTH))
    trunk = mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_BODY, "trunk")
    bare = float(plant.model.body_mass[trunk])
    assert plant.scene.trunk_mass == pytest.approx(bare)
    plant.set_param("trunk_payload", 1.5)
    plant.set_param("robot_box_friction", 0.8)
    plant.set_param("box_mass", 6.0)
    assert plant.model.body_mass[trunk] == pytest.approx(bare + 1.5)
    assert plant.truth_values["trunk_payload"] == pytest.approx(1.5)
    # a scene built with a payload reads it as its nominal, and a space on it writes it back unchanged
    scene = Scene(SceneConfig(trunk_payload=0.7))
    space = ParameterSpace(scene, free=("trunk_payload",))
    assert space.prior_values["trunk_payload"][0] == pytest.approx(0.7)
    space.write(scene.model, space.mean0)
    assert scene.model.body_mass[trunk] == pytest.approx(bare + 0.7)


def test_plant_trajectory_records_gains_and_masks(traj):
    np.testing.assert_allclose(traj.kp, 55.0)
    np.testing.assert_allclose(traj.kd, 3.0)
    assert set(traj.observed) == {"joint_states", "base", "box", "joint_commands"}
    for mask in traj.observed.values():
        assert mask.shape == (len(traj),) and mask.dtype == bool and mask.all()
    assert traj.meta["truth"]["box_mass"] == pytest.approx(5.0)
    assert set(PARAMETERS) <= set(traj.meta["truth"])
    np.testing.assert_allclose(np.diff(traj.t), traj.dt, atol=1e-9)
    # ctrl is the command held during the step: the first lunge target follows the stand pose
    np.testing.assert_allclose(traj.ctrl[0], lunge_schedule()[0])


def test_plant_observed_masks_are_independent(traj):
    masks = list(traj.observed.values())
    assert not any(np.shares_memory(a, b) for i, a in enumerate(masks) for b in masks[i + 1:])


def test_scene_infers_another_box_height_from_the_robots_floor():
    """A log of a 0.30 m box read without --box-size: the default 0.38 m would float it 4 cm."""
    from amhe_cli.control.probing import simulate_probe
    from amhe_cli.model.scene import infer_scene_config
    traj = simulate_probe({"box_mass": 3.0}, config=SceneConfig(box_size=(0.3, 0.3, 0.3)), lunges=(0.05,))
    with pytest.warns(UserWarning, match="cube"):
        cfg = infer_scene_config(traj)
    assert cfg.box_size[2] == pytest.approx(0.30, abs=0.003)
    assert abs(cfg.floor_height) < 0.002 and cfg.robot_floor_height == cfg.floor_height
    # an explicit size is taken as given
    cfg = infer_scene_config(traj, box_size=(0.3, 0.3, 0.3))
    assert cfg.box_size == (0.3, 0.3, 0.3) and abs(cfg.floor_height) < 0.001


def test_scene_floor_ignores_a_box_leaning_on_the_robot():
    """A box tipped 8° onto the robot rests 3 cm higher: without the tilt check it read as a 0.435 m cube."""
    import warnings as _w

    from amhe_cli.io.quat import quat_face_tilt, quat_from_rotvec
    from amhe_cli.control.probing import simulate_probe
    from amhe_cli.model.scene import infer_scene_config
    traj = simulate_probe({"box_mass": 3.0}, lunges=(0.05,))
    lean = np.arange(len(traj)) >= len(traj) // 3
    angle = np.radians(8.0)
    traj.box_quat[lean] = quat_from_rotvec(np.array([0.0, angle, 0.0]))
    traj.box_pos[lean, 2] = 0.19 * (np.cos(angle) + np.sin(angle))
    traj.box_linvel[lean] = 0.0
    assert np.degrees(quat_face_tilt(traj.box_quat[lean][0])) == pytest.approx(8.0)
    # a box lying on another face, at any yaw, is level
    assert quat_face_tilt(quat_from_rotvec(np.array([np.pi / 2, 0.0, 0.0]))) == pytest.approx(0.0, abs=1e-9)
    with _w.catch_warnings():
        _w.simplefilter("error")
        cfg = infer_scene_config(traj)
    assert cfg.box_size == (0.38, 0.38, 0.38) and abs(cfg.floor_height) < 0.002
