"""The rollout backends behind the cost module: device choice, and the Warp backend's CPU-side code.

Everything above the ``gpu`` mark runs in CI without a GPU (field mapping,
buffer sizing, refusals, device choice). Tests marked ``gpu`` need
``amhe[gpu]`` and a CUDA device and are skipped otherwise (with ``amhe[gpu]`` and
``AMHE_WARP_DEVICE=cpu`` they run the same kernels on Warp's CPU device, slowly).
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
from helpers import amhe, one_line_error

from amhe_cli.control.maneuver import lunge_schedule
from amhe_cli.control.robot_side import RobotSide, write_robot
from amhe_cli.errors import AmheError
from amhe_cli.estimation.clips import sample_clips
from amhe_cli.estimation.cost import RolloutCost, state_error
from amhe_cli.io.quat import quat_relative_rotvec
from amhe_cli.model import device as dev
from amhe_cli.model import rollout_warp as rw
from amhe_cli.model.params import PARAMETERS, ParameterSpace
from amhe_cli.model.rollout import RolloutPool
from amhe_cli.model.scene import Scene, SceneConfig
from amhe_cli.plants.sim import SimPlant

TRUTH = {"box_mass": 5.0, "box_friction": 0.45}
BOX_XY = (0.48, 0.0)


@pytest.fixture(scope="module")
def traj():
    plant = SimPlant(SceneConfig(), truth=dict(TRUTH))
    q, _ = plant.scene.standing_state(box_xy=BOX_XY)
    plant.reset(q)
    for u in lunge_schedule():
        plant.step(u)
    return plant.trajectory()


@pytest.fixture(scope="module")
def scene():
    return Scene(SceneConfig())


@pytest.fixture(scope="module")
def clips(traj, scene):
    return sample_clips(traj, scene, 8, rng=np.random.default_rng(0))


# -- device choice -------------------------------------------------------------------------------

def test_choose_device_falls_back_and_refuses_with_the_reason():
    assert dev.choose_device("cpu", packages="x", device_name=None) == "cpu"
    assert dev.choose_device("auto", packages="warp not installed", device_name=None) == "cpu"
    assert dev.choose_device(None, packages=None, device_name=None) == "cpu"  # packages, no device
    assert dev.choose_device("auto", packages=None, device_name="NVIDIA H100") == "cuda"
    assert dev.choose_device("cuda", packages=None, device_name="NVIDIA H100") == "cuda"
    with pytest.raises(AmheError, match="not installed"):
        dev.choose_device("cuda", packages="mujoco_warp not installed (pip install 'amhe[gpu]')", device_name=None)
    with pytest.raises(AmheError, match="no CUDA device"):
        dev.choose_device("cuda", packages=None, device_name=None)
    with pytest.raises(AmheError, match="expected one of"):
        dev.choose_device("tpu")


def test_make_backend_cpu_is_the_pool_and_announces_only_a_choice(capsys, scene):
    dev._announced.discard("cpu")
    with dev.make_backend(scene.model, "cpu", nthread=1) as pool:
        assert isinstance(pool, RolloutPool)
    assert "rollouts on" not in capsys.readouterr().err
    if dev.choose_device("auto") == "cpu":
        with dev.make_backend(scene.model, "auto", nthread=1):
            pass
        with dev.make_backend(scene.model, "auto", nthread=1):
            pass
        err = capsys.readouterr().err
        assert err.count("amhe: rollouts on cpu (mujoco.rollout, 1 threads)") == 1, err


@pytest.mark.skipif(dev.gpu_packages() is None, reason="amhe[gpu] installed: --device cuda would run")
def test_cli_device_cuda_without_gpu_is_one_line(capsys):
    res = amhe(capsys, "identify", "--device", "cuda", "--generations", "1")
    one_line_error(res, "--device cuda", "amhe[gpu]")


@pytest.mark.skipif(dev.gpu_packages() is None, reason="amhe[gpu] installed")
def test_warp_backend_without_warp_is_one_line(scene):
    with pytest.raises(AmheError, match=r"not installed \(pip install 'amhe\[gpu\]'\)"):
        rw.WarpRollout(scene.model)


def test_mhe_device_config_key_is_checked(scene):
    from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator
    with pytest.raises(AmheError, match="mhe device 'gpu'"):
        MHESettings(device="gpu").check()
    space = ParameterSpace(scene, ("box_mass",))
    with MovingHorizonEstimator(scene, space, MHESettings(device="cpu"), nthread=1) as mhe:
        assert isinstance(mhe.pool, RolloutPool)


def test_run_config_takes_the_mhe_device_key():
    from amhe_cli.control.evaluate import run_settings
    _, settings = run_settings("t1", "adaptive", {"mhe": {"device": "cpu"}})
    assert settings.mhe.device == "cpu"
    with pytest.raises(AmheError, match="mhe device"):
        run_settings("t1", "adaptive", {"mhe": {"device": "gpu"}})


def test_cli_device_unknown_is_refused(capsys):
    code, _, err = amhe(capsys, "identify", "--device", "tpu")
    assert code == 2 and "tpu" in err and "Traceback" not in err


# -- field mapping -------------------------------------------------------------------------------

def test_every_field_a_parameter_writes_is_batched(scene):
    """All seven parameters free: each model field they (and mj_setConst) change is a per-world field."""
    space = ParameterSpace(scene, tuple(PARAMETERS))
    written = rw.written_fields(space)
    assert {"body_mass", "body_inertia", "pair_friction", "geom_friction", "actuator_gainprm",
            "actuator_biasprm", "body_invweight0", "dof_invweight0", "body_subtreemass"} <= written
    assert written <= set(rw.BATCHED_FIELDS) | set(rw.HOST_ONLY_FIELDS)
    rw.check_space(space)


def test_a_parameter_writing_an_unbatched_field_is_refused(scene):
    class Solref(ParameterSpace):
        def write(self, model, vec):
            super().write(model, vec)
            model.geom_solref[:, 0] = 0.05

    with pytest.raises(AmheError, match="geom_solref"):
        rw.check_space(Solref(scene, ("box_mass",)))


def test_candidate_fields_are_what_write_sets_for_every_candidate(scene):
    """The per-world fields: for each candidate, every batched field (all parameters free, servo gains and
    trunk payload included; mj_setConst's derived constants too) equals, to the bit, what the CPU
    backend's model holds after ``write``."""
    space = ParameterSpace(scene, tuple(PARAMETERS))
    rng = np.random.default_rng(5)
    P = space.project(space.mean0 + rng.normal(0, 0.5, (4, space.dim)) * space.std0)[0]
    models = [copy.copy(scene.model) for _ in P]
    fields = rw.candidate_fields(space, P, models)
    assert set(fields) == {f for f in rw.BATCHED_FIELDS if getattr(scene.model, f).size}
    b = scene.box_body
    assert len(set(fields["body_mass"][:, b])) == 4  # one value per candidate
    for k in range(len(P)):
        m = copy.copy(scene.model)
        space.write(m, P[k])
        for f, v in fields.items():
            np.testing.assert_array_equal(v[k], getattr(m, f), err_msg=f)
    # the raised zero friction (friction_floor) applies to every candidate
    low, _ = rw.friction_floor(scene.model)
    raised = rw.candidate_fields(space, P, models, low)
    assert np.all(raised["geom_friction"][:, low] >= rw.MJ_MINMU)


def test_model_fields_leave_the_scenes_own_actuators_where_gains_are_not_free(scene):
    space = ParameterSpace(scene, ("box_mass", "box_friction"))
    f = space.model_fields(np.array([[2.0, 0.3], [9.0, 0.7]]))
    np.testing.assert_array_equal(f["actuator_gainprm"][1], scene.model.actuator_gainprm)
    np.testing.assert_array_equal(f["actuator_biasprm"][0], scene.model.actuator_biasprm)
    assert f["body_mass"][:, scene.box_body].tolist() == [2.0, 9.0]
    assert f["pair_friction"][:, scene.region_pairs[0], :2].tolist() == [[0.3, 0.3], [0.7, 0.7]]


# -- buffer sizing -------------------------------------------------------------------------------

BALLS = """
<mujoco><option cone="{cone}"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1" condim="3"/>
    <body pos="0 0 .1"><freejoint/><geom type="sphere" size=".05" condim="3"/></body>
    <body pos="1 0 .1"><freejoint/><geom type="box" size=".05 .05 .05" condim="4"/></body>
  </worldbody>
</mujoco>"""


def test_buffer_sizes_count_pairs_contacts_and_rows():
    m = mujoco.MjModel.from_xml_string(BALLS.format(cone="elliptic"))
    # sphere-plane 1 contact, box-plane 4, sphere-box 1; rows = condim (elliptic): 3 + 4*4 + 4
    assert rw.buffer_sizes(m) == (6, 3 + 16 + 4)
    m = mujoco.MjModel.from_xml_string(BALLS.format(cone="pyramidal"))
    assert rw.buffer_sizes(m) == (6, 4 + 4 * 6 + 6)  # 2 (condim - 1) rows per contact


def test_buffer_sizes_bound_what_the_scene_uses(scene, clips):
    """Along real clips of a push (feet on the floor, head on the box) the CPU never needs more than the
    bound, and the chosen sizes hold twice the need but stay far below the bound."""
    bound = rw.buffer_sizes(scene.model)
    most = rw.measured_sizes(scene.model, clips.initial_state, clips.control, clips.horizon)
    assert most[0] >= 4 and most[1] > 24  # the clips do touch
    assert bound[0] >= most[0] and bound[1] >= most[1]
    chosen = rw.choose_sizes(bound, most)
    assert all(2 * m <= c < b for m, c, b in zip(most, chosen, bound)), (most, chosen, bound)
    assert all(c % 16 == 0 for c in chosen)
    assert rw.choose_sizes((20, 30), (15, 25)) == (20, 30)  # never above the bound


# -- the box's zero friction and refusals --------------------------------------------------------

def test_friction_floor_changes_no_cpu_answer(scene, clips):
    """Raising the box geom's zero friction to MJ_MINMU (what Warp is given) leaves CPU rollouts bit-identical."""
    low, why = rw.friction_floor(scene.model)
    box_geom = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_GEOM, "box")
    assert low == [box_geom] and why is None
    host = rw.warp_host_model(scene.model)
    assert host.geom_friction[box_geom].min() == rw.MJ_MINMU and scene.model.geom_friction[box_geom].max() == 0
    n = len(clips)
    with RolloutPool(scene.model, 1) as pool:
        h = int(clips.horizon.max())
        a = pool.rollout([scene.model] * n, clips.initial_state, clips.control, nstep=h)
        b = pool.rollout([host] * n, clips.initial_state, clips.control, nstep=h)
    np.testing.assert_array_equal(a, b)


def test_zero_friction_that_decides_a_contact_is_refused():
    xml = BALLS.format(cone="elliptic").replace('type="sphere" size=".05" condim="3"',
                                                'type="sphere" size=".05" condim="3" friction="0 0 0"')
    m = mujoco.MjModel.from_xml_string(xml.replace('name="floor" type="plane"',
                                                   'name="floor" type="plane" friction="0 0 0"'))
    with pytest.raises(AmheError, match="below MuJoCo Warp's minimum") as e:
        rw.check_scene(m)
    assert "\n" not in str(e.value)


def test_noslip_and_unsupported_integrator_are_refused(scene):
    m = copy.copy(scene.model)
    m.opt.noslip_iterations = 3
    with pytest.raises(AmheError, match="noslip"):
        rw.check_scene(m)
    rw.check_scene(scene.model)  # the shipped scene is accepted


def test_dof_layout_reads_the_cost_modules_state_error(scene):
    """The device scorer's layout (:func:`rw.dof_layout`), read as its kernel reads it, gives the position part of
    ``state_error`` for the Go1 + box scene: free-joint translations and body-frame rotation vectors, joints."""
    rng = np.random.default_rng(3)
    m = scene.model
    qpos = np.tile(scene.model.qpos0, (2, 5, 1)) + rng.normal(0, 0.1, (2, 5, m.nq))
    for j in range(m.njnt):
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            a = m.jnt_qposadr[j] + 3
            qpos[..., a:a + 4] = rng.normal(size=(2, 5, 4))
            qpos[..., a:a + 4] /= np.linalg.norm(qpos[..., a:a + 4], axis=-1, keepdims=True)
    ref, q = qpos[0], qpos[1]
    qadr, rot = rw.dof_layout(m)
    want = state_error(scene, ref, np.zeros((5, m.nv)), q, np.zeros((5, m.nv)))[:, :m.nv]
    got = np.empty((5, m.nv))
    for j in range(m.nv):
        if rot[j] < 0:
            got[:, j] = q[:, qadr[j]] - ref[:, qadr[j]]
        else:
            got[:, j] = quat_relative_rotvec(ref[:, qadr[j]:qadr[j] + 4], q[:, qadr[j]:qadr[j] + 4])[:, rot[j]]
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert (rot >= 0).sum() == 6  # two free joints' orientations


def test_world_capacity_reuses_slots_and_pads_at_most_a_quarter():
    assert rw.world_capacity(1) == 64
    assert rw.world_capacity(12 * 48) == 640
    assert rw.world_capacity(1024) == 1024
    assert rw.world_capacity(1025) == 1280
    for n in range(1, 70000, 37):
        cap = rw.world_capacity(n)
        assert cap >= n and cap % 16 == 0 and (n < 64 or cap <= 1.25 * n)


# -- on a GPU ------------------------------------------------------------------------------------

gpu = pytest.mark.skipif(dev.choose_device("auto") != "cuda", reason="needs amhe[gpu] and a CUDA device")


@pytest.mark.gpu
@gpu
def test_gpu_cost_agrees_with_cpu(scene, clips):
    """Same candidates, same clips: box position within 10 µm (median) and 100 µm (p95) of the CPU's over
    every rolled-out step, and > 80 % of candidate pairs ordered alike by the two costs."""
    space = ParameterSpace(scene, ("box_mass", "box_friction"))
    rng = np.random.default_rng(1)
    P = space.project(space.vector(TRUTH) + rng.normal(0, 1, (16, 2)) * [1.5, 0.1])[0]
    with RolloutCost(scene, space, clips, prior_weight=0.0, device="cpu", nthread=2) as cpu, \
            RolloutCost(scene, space, clips, prior_weight=0.0, device="cuda") as gpu_cost:
        qc, _ = cpu.rollout(P)
        qg, _ = gpu_cost.rollout(P)
        jc, jg = cpu(P), gpu_cost(P)
    box = scene.box_qpos[:2]
    err = np.linalg.norm(qc[..., box] - qg[..., box], axis=-1)  # (B, N_c, H) [m]
    # measured with Warp's CPU device on const_a (12 x 48): median 0.3 µm, p95 1.2 µm, rare contact flips ~2 mm
    assert np.median(err) < 1e-5 and np.percentile(err, 95) < 1e-4
    pairs = [(i, j) for i in range(len(P)) for j in range(i + 1, len(P))]
    same = np.mean([np.sign(jc[i] - jc[j]) == np.sign(jg[i] - jg[j]) for i, j in pairs])
    assert same > 0.8


@pytest.mark.gpu
@gpu
def test_device_scores_are_the_host_scores_of_the_same_rollouts(scene, clips, tmp_path, monkeypatch):
    """``evaluate`` scored on the device (``score_candidates``) gives the per-clip sums and diverged flags the host
    gives from the very states of that launch (float32, read back from the slot), with unobserved roles weighed
    zero; a clip that starts from a non-finite state, or 5 km away, diverges in both. (Two launches on a GPU can
    differ: its atomics order contacts otherwise, so the states compared are one launch's.)"""
    import dataclasses
    space = ParameterSpace(scene, ("box_mass", "box_friction"))
    P = space.project(space.vector(TRUTH) + np.random.default_rng(4).normal(0, 1, (5, 2)) * [1.5, 0.1])[0]
    observed = clips.observed.copy()
    observed[1, 10:30, 2] = False  # a gap in the box's poses
    init = clips.initial_state.copy()
    init[3, 1 + scene.box_qpos[0]] = np.nan  # a clip that cannot be rolled out
    init[5, 1 + scene.box_qpos[0]] = 5e3  # nor can one beyond the 1 km bound
    monkeypatch.chdir(tmp_path)  # MuJoCo's warning about the NaN goes to MUJOCO_LOG.TXT in the working directory
    odd = dataclasses.replace(clips, observed=observed, initial_state=init)
    hmax = odd.control.shape[1]
    with rw.WarpRollout(scene.model) as w, RolloutCost(scene, space, odd, prior_weight=0.0, pool=w) as cost:
        dev_ = cost.evaluate(P)
        qpos, qvel = w.last_states(len(P), odd.horizon, hmax)
        host = cost.evaluate(P, states=(qpos, qvel))
    assert qpos.dtype == np.float32
    assert np.array_equal(dev_.diverged, host.diverged) and host.diverged[:, [3, 5]].all() and host.diverged.sum() == 10
    ok = ~host.diverged
    # atol: a clip of a box at rest sums float32 rounding alone (~1e-9), which a GPU's fused multiply-adds round
    # otherwise
    np.testing.assert_allclose(dev_.per_clip[ok], host.per_clip[ok], rtol=1e-5, atol=1e-7)
    assert np.unique(host.per_clip[ok].round(6)).size > 10  # the candidates and clips differ


@pytest.mark.gpu
@gpu
def test_gpu_overflow_is_raised_or_grown(scene, clips, capsys):
    space = ParameterSpace(scene, ("box_mass",))
    with rw.WarpRollout(scene.model, nconmax=1, njmax=8) as w:  # sizes given: raise
        with pytest.raises(AmheError, match="ran out of buffer space"):
            w.rollout_candidates(space, space.mean0[None], clips.initial_state, clips.control, clips.horizon)
    with rw.WarpRollout(scene.model) as w, RolloutPool(scene.model, 1) as pool:  # chosen sizes: grow, repeat
        w.rollout_candidates(space, space.mean0[None], clips.initial_state, clips.control, clips.horizon)
        w.nconmax, w.njmax = 2, 16
        w.close()
        qg, _, _ = w.rollout_candidates(space, space.mean0[None], clips.initial_state, clips.control, clips.horizon)
        qc, _, _ = pool.rollout_candidates(space, space.mean0[None], clips.initial_state, clips.control,
                                           clips.horizon)
        assert w.njmax > 16 and "growing" in capsys.readouterr().err
        assert np.median(np.abs(qg - qc)[..., scene.box_qpos[:2]]) < 1e-5
        w.bound = w.nconmax, w.njmax = (2, 16)  # at the bound: the overflowed worlds read as diverged
        w.close()
        with RolloutCost(scene, space, clips, pool=w) as cost:
            br = cost.evaluate(space.mean0[None])
        assert br.diverged.any() and "count as diverged" in capsys.readouterr().err


@pytest.mark.gpu
@gpu
def test_two_backends_in_two_threads_roll_out_as_each_does_alone(scene, clips):
    """A run's GPU planner and its GPU MHE thread: one backend keeps capturing steps for new widths while the
    other keeps launching its own; every batch of either comes back as it does alone, and nothing raises.
    (Warp's current stream is per device, not per thread: before :data:`~amhe_cli.model.rollout_warp.ENQUEUE_LOCK`
    an emulated Go1 run with both on one GPU stopped 9 s in with "operation not permitted when stream is
    capturing".)"""
    import threading
    space = ParameterSpace(scene, ("box_mass", "box_friction"))
    widths = (3, 9, 17, 33, 65)  # candidates: 24 .. 520 worlds, a new slot (and capture) each
    P = space.project(space.vector(TRUTH) + np.random.default_rng(2).normal(0, 1, (max(widths), 2)) * [1.5, 0.1])[0]
    args = (clips.initial_state, clips.control, clips.horizon)
    with rw.WarpRollout(scene.model) as a, rw.WarpRollout(scene.model) as b:
        alone_a = [a.rollout_candidates(space, P[:w], *args)[0] for w in widths]
        alone_b = b.rollout_candidates(space, P[:4], *args)[0]
        a.close()  # every width captured anew beside b
        errors, got_b, stop = [], [], threading.Event()

        def keep_launching():
            try:
                while not stop.is_set():
                    got_b.append(b.rollout_candidates(space, P[:4], *args)[0])
            except Exception as exc:  # noqa: BLE001 - asserted below
                errors.append(exc)

        t = threading.Thread(target=keep_launching)
        t.start()
        try:
            got_a = [a.rollout_candidates(space, P[:w], *args)[0] for w in widths]
        finally:
            stop.set()
            t.join()
    assert not errors, errors
    assert len(got_b) >= 2
    box = scene.box_qpos[:2]
    for x, y in [*zip(got_a, alone_a), *((x, alone_b) for x in got_b)]:
        err = np.abs(x[..., box] - y[..., box])  # the device's atomics may order contacts otherwise: a rare flip
        assert np.median(err) < 1e-6 and np.percentile(err, 99) < 1e-3


@pytest.mark.gpu
@gpu
def test_the_kernel_message_is_said_once_per_process(scene, clips, capsys):
    """A command that makes two backends (the payload fit's, then identify's) says once that kernels
    compile or load, and how long it took."""
    space = ParameterSpace(scene, ("box_mass",))
    for _ in range(2):
        with rw.WarpRollout(scene.model) as w:
            w.rollout_candidates(space, space.mean0[None], clips.initial_state, clips.control, clips.horizon)
            assert w.compile_time is not None
    err = capsys.readouterr().err
    assert err.count("kernels ready in") <= 1  # none if an earlier test in this process said it
    assert rw._KERNELS_ANNOUNCED["done"]


# -- the planner's samples on the GPU ------------------------------------------------------------

def _planner_and_start(device: str):
    """A T4 wall-clock planner (true mode) on ``device``, its standing start, command and reference."""
    from amhe_cli.control.closed_loop import make_planner, make_plant, measured_command
    from amhe_cli.control.evaluate import run_settings
    task, s = run_settings("t4", "true", {"planner": {"device": device, "samples": 12}}, threads=1)
    plant = make_plant(task, s.kp, s.kd)
    planner, _ = make_planner(task, s, None, plant.truth_values, nthread=1)
    sc = planner.scene
    qpos, qvel = sc.standing_state(box_xy=task.box_start)
    d = mujoco.MjData(sc.model)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(sc.model, d)
    state = np.empty(mujoco.mj_stateSize(sc.model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(sc.model, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    cmd, _ = measured_command(task, sc, qpos, 0.0)
    p = planner.settings
    ref = planner.gait.reference(np.arange(p.horizon) * p.dt, cmd["speed"], cmd["omega"], cmd.get("reach"))
    return planner, state, cmd, ref


def test_planner_device_key_is_checked():
    from amhe_cli.control.evaluate import run_settings
    from amhe_cli.control.planner import PlannerSettings
    with pytest.raises(AmheError, match="planner device 'gpu': expected cpu or cuda"):
        PlannerSettings(device="gpu").check()
    _, s = run_settings("t4", "adaptive", {"planner": {"device": "cuda"}}, realtime=True)
    assert s.planner.device == "cuda" and s.planner.samples == 16  # the wall clock's planner, on the GPU
    from amhe_cli.control.closed_loop import describe_split
    assert describe_split(s, True, 4).startswith("the planner rolls out on the GPU (planner device cuda)")


@pytest.mark.skipif(dev.gpu_packages() is None, reason="amhe[gpu] installed")
def test_planner_on_cuda_without_warp_is_one_line():
    with pytest.raises(AmheError, match=r"--device cuda: .*not installed \(pip install 'amhe\[gpu\]'\)"):
        _planner_and_start("cuda")


@pytest.mark.gpu
@gpu
def test_gpu_planner_scores_as_the_cpu_planner_and_follows_the_belief_and_the_robot_read():
    """The same knots from the same state cost the same on both backends (float32 against float64), and a
    new belief (set_params) or a robot read mid-run (edit_models) reaches the GPU's worlds: its costs change
    as the CPU's do."""
    cpu, state, cmd, ref = _planner_and_start("cpu")
    gpu_planner, *_ = _planner_and_start("cuda")
    assert gpu_planner.gpu is not None and gpu_planner.where() == "the GPU"
    knots = cpu.sigma[None] * np.random.default_rng(3).standard_normal((12,) + cpu.mean.shape)
    costs = []
    for belief in (cpu.space.mean0, cpu.space.vector({"box_mass": 12.0, "box_friction": 0.9})):
        cpu.set_params(belief)
        gpu_planner.set_params(belief)
        jc = cpu._score(state, knots, ref, cmd)
        jg = gpu_planner._score(state, knots, ref, cmd)
        # measured on an H100 and on Warp's CPU device: within 6e-5 relative, the same order
        assert np.max(np.abs(jg - jc) / np.abs(jc)) < 1e-3
        assert np.argmin(jg) == np.argmin(jc)
        costs.append(jg)
    assert np.max(np.abs(costs[1] - costs[0])) > 1e-3  # the heavier, stickier box's pushes cost otherwise
    # a robot read mid-run (write_robot) reaches both backends alike: motors at a quarter of the model's limits
    # (copied into the device model in place), then the servo at 0.6 of the gains too (per-world fields)
    m, slots = cpu.scene.model, gpu_planner.gpu.timing["slots"]
    kp, kd, limit = m.actuator_gainprm[:, 0].copy(), -m.actuator_biasprm[:, 2].copy(), m.actuator_forcerange[:, 1]
    for side in (RobotSide(tuple(kp), tuple(kd), torque_limit=tuple(0.25 * limit)),
                 RobotSide(tuple(0.6 * kp), tuple(0.6 * kd), torque_limit=tuple(0.25 * limit))):
        for p in (cpu, gpu_planner):
            p.edit_models(lambda mdl: write_robot(mdl, side))
        jc = cpu._score(state, knots, ref, cmd)
        jg = gpu_planner._score(state, knots, ref, cmd)
        assert np.max(np.abs(jg - jc) / np.abs(jc)) < 1e-3
        assert np.max(np.abs(jg - costs[-1]) / np.abs(costs[-1])) > 1e-3  # the edit changed what the GPU rolls out
        costs.append(jg)
    assert gpu_planner.gpu.timing["slots"] == slots  # edited in place: no device model was built again
    cpu.close()
    gpu_planner.close()
