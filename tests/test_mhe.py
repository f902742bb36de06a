"""The moving horizon estimator: its update rule, tracking a change, outputs and errors."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from amhe_cli.errors import AmheError
from amhe_cli.io.reader import read_float_arrays
from amhe_cli.io.writer import write_mcap
from amhe_cli.estimation.mhe import MHESettings, MovingHorizonEstimator
from amhe_cli.estimation.sampling import gaussian_step, log_rank_weights
from amhe_cli.model.params import ParameterSpace
from amhe_cli.control.probing import simulate_probe
from amhe_cli.estimation.replay import TruthSeries, estimates_table, replay
from amhe_cli.model.scene import Scene, SceneConfig

AMHE = [sys.executable, "-c", "from amhe_cli.cli import main; main()"]


# -- the update rule on a cheap synthetic cost -----------------------------------

def test_log_rank_weights():
    w = log_rank_weights(5)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(np.diff(w) < 0) and np.all(w > 0)


def test_gaussian_step_moves_toward_low_cost_and_alpha_scales_it():
    rng = np.random.default_rng(0)
    mean, std = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    target = np.array([2.0, -1.0])
    P = mean + std * rng.standard_normal((200, 2))
    J = ((P - target) ** 2).sum(axis=1)
    m1, s1 = gaussian_step(mean, std, P, J, alpha=1.0)
    mh, sh = gaussian_step(mean, std, P, J, alpha=0.5)
    assert np.linalg.norm(m1 - target) < np.linalg.norm(mean - target) - 1.0
    np.testing.assert_allclose(mh, 0.5 * m1)  # (1-α)·old + α·new with old = 0
    np.testing.assert_allclose(sh, 0.5 * std + 0.5 * s1)
    # σ is the elites' spread around the *old* mean: a distant optimum widens it along the way,
    # a bowl centred on the mean tightens it
    assert s1[0] > s1[1]
    Jc = (P ** 2).sum(axis=1)
    _, sc = gaussian_step(mean, std, P, Jc, alpha=1.0)
    assert np.all(sc < 0.8 * std)


def test_iterated_update_converges_and_floor_stops_it():
    rng = np.random.default_rng(1)
    mean, std = np.array([5.0]), np.array([2.0])
    for it in range(1, 100):
        P = mean + std * rng.standard_normal((12, 1))
        mean, std = gaussian_step(mean, std, P, (P[:, 0] - 1.5) ** 2, 0.8)
        if std[0] < 1e-3:
            break
    assert abs(mean[0] - 1.5) < 0.05 and it < 99


# -- the estimator on generated logs ---------------------------------------------

@pytest.fixture(scope="module")
def step_log():
    """A sim log whose box-floor friction steps from 0.3 to 0.6 when the box passes x = 0.55 m."""
    lunges = tuple(np.linspace(0.06, 0.2, 10))
    traj = simulate_probe({"box_mass": 2.0, "box_friction": 0.3}, lunges=lunges, friction_step=(0.55, 0.6),
                          schedule=dict(hold=0.2, retreat=0.4, rest=0.3))
    return traj


def test_pull_keeps_estimate_when_window_is_uninformative(step_log):
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.5, "box_friction": 0.4})
    with MovingHorizonEstimator(scene, space, MHESettings()) as mhe:
        u = mhe.update(step_log, 0.9)  # the robot is still standing: the box rests
    assert u.skipped and u.iterations == 0
    np.testing.assert_allclose(u.mean, [2.5, 0.4])


def test_wp_pull_limits_a_single_update(step_log):
    scene = Scene(SceneConfig())
    kw = dict(free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.6})
    moved = {}
    for name, pull in (("strong", 0.005), ("weak", 1.0)):
        space = ParameterSpace(scene, **kw)
        st = MHESettings(pull={"box_mass": 10.0, "box_friction": pull}, iters=4, samples=12)
        with MovingHorizonEstimator(scene, space, st) as mhe:
            t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 0.5
            moved[name] = abs(mhe.update(step_log, t_push).mean[1] - 0.6)
    # before the step the truth is 0.3: a weak pull lets one update move much further toward it
    assert moved["weak"] > 2 * moved["strong"]


def test_tracks_a_friction_step(step_log):
    scene = Scene(SceneConfig())
    # a confident (and wrong) starting belief: the sampling σ must not shrink with it
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior_std={"box_mass": 0.05, "box_friction": 0.01})
    mu = step_log.meta["truth_series"]["box_friction"]
    t_step = step_log.t[np.argmax(mu > 0.45)]
    with MovingHorizonEstimator(scene, space, MHESettings(pull={"box_mass": 2.0, "box_friction": 0.3})) as mhe:
        res = replay(step_log, mhe)
    head, rows = estimates_table(space, res)
    t, est = rows[:, 0], rows[:, head.index("box_friction")]
    informative = np.array([not u.skipped for u in res.updates])
    before = est[informative & (t <= t_step)]
    after = est[t >= t_step + 3.0]
    assert before.size and abs(before[-1] - 0.3) < 0.05  # settled on the old floor (from a 0.5 prior)
    assert abs(after[-1] - 0.6) < abs(after[-1] - 0.3)  # it moved to the new floor, not back
    assert np.median(after) > 0.45


def test_fusion_reports_but_does_not_steer_the_windows(step_log):
    """With ``fuse`` the windows chain exactly the estimates they chain without it; only the report differs."""
    scene = Scene(SceneConfig())
    out = {}
    for fuse in (False, True):
        space = ParameterSpace(scene, free=("box_mass", "box_friction"))
        with MovingHorizonEstimator(scene, space, MHESettings(fuse=fuse, seed=3)) as mhe:
            out[fuse] = replay(step_log, mhe).updates
    raw, fused = out[False], out[True]
    np.testing.assert_allclose([u.window_mean for u in fused], [u.mean for u in raw])
    np.testing.assert_allclose([u.window_mean for u in raw], [u.mean for u in raw])
    informative = [i for i, u in enumerate(fused) if not u.skipped]
    assert len(informative) >= 4
    assert any(np.abs(fused[i].mean - raw[i].mean).max() > 1e-6 for i in informative)


def test_attribution_reports_the_line_decisions_of_real_rollouts(step_log, monkeypatch):
    """With ``attribute`` the MHE reports the tracker's reference, moved by decisions scored on the log; with
    ``attribute_device`` the decisions roll out on a backend of their own (here a second CPU pool, as
    ``cuda`` sends them to the GPU beside the windows' CPU pool) and decide the same."""
    from amhe_cli.estimation import attribution
    from amhe_cli.estimation.cost import RolloutCost
    from amhe_cli.model.rollout import RolloutPool
    monkeypatch.setattr(attribution, "PERIOD", 1.0)  # a decision every informative second, to keep this short
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    mu = step_log.meta["truth_series"]["box_friction"]
    t_step = step_log.t[np.argmax(mu > 0.45)]
    t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0
    runs, batches = {}, {}
    real_evaluate = RolloutCost.evaluate

    def counted(self, P):  # the decisions' batches (each a dependent rollout: its latency on a GPU)
        batches[where] = batches.get(where, 0) + (self is not mhe._cost)
        return real_evaluate(self, P)

    monkeypatch.setattr(RolloutCost, "evaluate", counted)
    for where in (None, "cpu", "gpu"):
        if where == "gpu":  # a GPU backend's path (the refinements scored in the lines' batch), on the CPU pool
            monkeypatch.setattr(MovingHorizonEstimator, "_decide_on_gpu", property(lambda self: True))
        with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1,
                                                              attribute_device=where and "cpu")) as mhe:
            assert mhe.lookback == attribution.LOOKBACK
            assert (mhe._decide_pool is None) == (where is None)
            ups = [mhe.update(step_log, t) for t in np.arange(t_push, min(t_push + 3.0, t_step), 0.5)]
            if where is not None:  # the decisions' clips went to their own pool, the windows' to theirs
                assert isinstance(mhe._decide_pool, RolloutPool) and mhe._decide_cost.pool is mhe._decide_pool
                assert mhe._cost.pool is mhe.pool is not mhe._decide_pool
        runs[where] = mhe.tracker
        tr = mhe.tracker
        assert tr.decisions and all(d.reason == "period" for d in tr.decisions)
        informative = [u for u in ups if not u.skipped]
        np.testing.assert_allclose(informative[-1].mean, tr.ref)
        # on the first floor, from the truth as its prior: the scored lines keep it there
        assert abs(tr.ref[0] / 2.0 - 1) < 0.1 and abs(tr.ref[1] - 0.3) < 0.03
    assert [d.cost for d in runs["cpu"].decisions] == [d.cost for d in runs[None].decisions]
    # with the refinements in the lines' batch: the same decisions, on one dependent batch each, not two
    assert [(d.cost, d.mass, d.friction) for d in runs["gpu"].decisions] == \
        [(d.cost, d.mass, d.friction) for d in runs["cpu"].decisions]
    assert batches["cpu"] - batches["gpu"] >= len(runs["gpu"].decisions) > 0  # change tests: one batch either way
    with pytest.raises(AmheError, match="attribute_device 'gpu'"):
        MHESettings(attribute=True, attribute_device="gpu").check()



def test_a_decision_that_seeks_its_change_rolls_the_search_and_its_lines_out_in_one_gpu_batch(step_log, monkeypatch):
    """On a GPU backend of their own (here a second CPU pool on the GPU path) a decision that seeks its change scores
    the search and its lines in one batch, every candidate on every clip: the lines' costs are those of their clips
    scored alone. Where the search places the change later than their first clip by more than SHIFT, those that
    start after it (less SHIFT) are kept where they are KEEP of them or more, else the lines are drawn again from the
    new place and scored in a second batch; where it places the change more than SHIFT before where they were drawn
    from, the search's own clips that start between join them (the data between), still one batch."""
    from amhe_cli.estimation import attribution, mhe as mhe_module
    from amhe_cli.estimation.cost import RolloutCost
    monkeypatch.setattr(MovingHorizonEstimator, "_decide_on_gpu", property(lambda self: True))
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    mu = step_log.meta["truth_series"]["box_friction"]
    t_step = float(step_log.t[np.argmax(mu > 0.45)])
    t = t_step + 2.5
    stop = int(np.searchsorted(step_log.t, t, side="right"))
    real_evaluate, real_known, real_join = RolloutCost.evaluate, mhe_module.known_costs, mhe_module.join_clips
    lines = 2 * attribution.FACTORS.size + 4 * (attribution.FACTORS.size - 1)
    # the change placed at the lines' first clip, 1.25 s before it (before where they were drawn from: the search's
    # clips between join them), and SHIFT after the start of their tenth percentile (most of them kept) and of their
    # thirtieth (too few kept): ``q`` about the share of the lines' clips that start before the place, less SHIFT
    for shift, q, kept in ((0.0, 0.0, "all"), (-5 * attribution.SHIFT, 0.0, "between"),
                           (attribution.SHIFT, 0.1, "some"), (attribution.SHIFT, 0.3, "none")):
        batches, known, parts = [], [], []
        with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, attribute_device="cpu", seed=2)) as mhe:
            mhe.update(step_log, t_step - 1.0)  # the windows' cost, whose W_x the decisions' takes
            monkeypatch.setattr(RolloutCost, "evaluate", lambda self, P: (
                batches.append((len(P), len(self.clips))) if self is mhe._decide_cost else None) or real_evaluate(self, P))
            monkeypatch.setattr(mhe_module, "known_costs", lambda Q, JQ, ev: known.append((Q, JQ)) or real_known(Q, JQ, ev))
            monkeypatch.setattr(mhe_module, "join_clips", lambda traj, sc, *p: parts.extend(p) or real_join(traj, sc, *p))
            # the search places the change at the first sought clip ``shift`` or more after the lines' q-quantile start
            at = lambda: int(np.flatnonzero(step_log.t[parts[0].start] >=  # noqa: E731
                                            np.quantile(step_log.t[parts[1].start], q) + shift)[0])
            monkeypatch.setattr(mhe_module, "locate", lambda C, held: at())
            tr = mhe.tracker
            for w in np.arange(t_step - 2.0, t + 0.01, 0.5):
                tr.advance(w)
            tr.open(t_step, 0.5)
            mhe._decide(step_log, stop, t, t_step, "provisional", mhe.mean.copy(), np.random.default_rng(0))
            sought, ahead = parts
            placed = tr.pending[0] if tr.pending is not None else tr.decisions[-1].since
            assert placed == pytest.approx(float(step_log.t[sought.start[at()]]))
            assert batches[0] == (lines + 1, len(sought) + len(ahead))  # the search and the lines, one batch
            Q, JQ = known[0]
            assert len(Q) == lines
            after = step_log.t[ahead.start] >= placed - attribution.SHIFT
            share = after.mean()
            if kept == "all":
                first = step_log.t[ahead.start].min()  # (the box rests after the step: they start 0.75 s after it)
                assert t_step - attribution.SHIFT <= placed <= first + attribution.SHIFT
                assert share == 1.0 and len(batches) == 1  # nothing more rolled out for the decision
                np.testing.assert_allclose(JQ, real_evaluate(mhe._decision_cost(ahead), Q).data, rtol=1e-9)
            elif kept == "some":  # those after the change, their costs from the one batch
                assert attribution.KEEP <= share < 1.0 and len(batches) == 1
                assert len(mhe._decide_cost.clips) == after.sum()
                np.testing.assert_allclose(JQ, real_evaluate(mhe._decision_cost(ahead.subset(after)), Q).data,
                                           rtol=1e-9)
            elif kept == "between":  # all of the lines' clips and the search's that start from the place to them
                first = step_log.t[ahead.start].min()
                assert placed < first - attribution.SHIFT and share == 1.0 and len(batches) == 1
                own_t = step_log.t[sought.start]
                between = (own_t >= placed - attribution.SHIFT) & (own_t < t_step)
                assert between.sum() >= 3 and (own_t < placed - attribution.SHIFT).any()  # not every sought clip
                used = mhe._decide_cost.clips
                np.testing.assert_array_equal(np.sort(used.start), np.sort(np.r_[sought.start[between], ahead.start]))
                np.testing.assert_allclose(JQ, real_evaluate(mhe._decision_cost(used), Q).data, rtol=1e-9)
            else:  # too few after it: drawn again after the new place, a batch of their own
                assert share < attribution.KEEP
                assert batches[1][0] == lines and len(batches) == 2
                again = mhe._decide_cost.clips
                assert again is not ahead and step_log.t[again.start].min() >= placed - 1e-9
                np.testing.assert_allclose(JQ, real_evaluate(mhe._decision_cost(again), Q).data, rtol=1e-9)
            assert tr.decisions and tr.decisions[-1].t == t
        monkeypatch.undo()
        monkeypatch.setattr(MovingHorizonEstimator, "_decide_on_gpu", property(lambda self: True))


def test_each_window_s_data_is_tested_and_two_tests_open_the_friction_step_for_its_decision(step_log, monkeypatch):
    """The change test (:meth:`SplitTracker.test`) on real rollouts, the windows' own change detection off: from
    the truth before the friction step, no test opens a change; after it, two successive windows' tests read
    the force moved up and open the change before them, and its first decision gives it to the friction."""
    from amhe_cli.estimation import attribution, fusion, mhe as mhe_module
    monkeypatch.setattr(attribution, "PERIOD", 1e9)  # no periodic decision: only a change makes one
    # a clean log: fewer do (its lunges are brief: with 16 clips the search placed the step in the rest before it)
    for name, n in (("TEST_CLIPS", 8), ("ATTRIBUTION_CLIPS", 24), ("LOCATE_CLIPS", 32)):
        monkeypatch.setattr(mhe_module, name, n)
    monkeypatch.setattr(fusion, "GATE", np.inf)  # nor the windows' product
    monkeypatch.setattr(fusion, "CUSUM_H", np.inf)
    opened = []
    real = attribution.SplitTracker.test
    monkeypatch.setattr(attribution.SplitTracker, "test", lambda self, t, J, located=None: (
        opened.append(t) or True) if real(self, t, J, located) else False)
    located = []  # the change is placed once, by the test that opens it, and its first decision does not seek it
    monkeypatch.setattr(mhe_module, "locate", lambda C, held: located.append(C.shape[0]) or attribution.locate(C, held))
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    mu = step_log.meta["truth_series"]["box_friction"]
    t_step = float(step_log.t[np.argmax(mu > 0.45)])
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1)) as mhe:
        tr = mhe.tracker
        for t in np.arange(t_step - 1.0, t_step + 3.0, 0.5):
            mhe.update(step_log, t)
            if tr.decisions:
                break
    # the box rests from the step to 0.7 s after it: two windows with its data, then the change, located before;
    # decided at the window that makes FINAL seconds of data after it
    assert opened and t_step < opened[0] <= t_step + 2.5 and tr.product.restarts == 0
    d = tr.decisions[0]
    assert opened[0] <= d.t <= opened[0] + 0.5 and t_step - 0.5 < d.since < opened[0] - 0.5
    assert located == [2 * attribution.FACTORS.size]  # sought by the lines, as a decision seeks it, not the test's 4
    assert d.reason in ("provisional", "change") and d.changed == "box_friction" and d.mass == 2.0
    assert abs(d.friction - 0.6) < 0.1


def test_a_line_decision_on_its_own_thread_holds_no_window_up_and_reaches_the_loop_when_it_finishes(
        step_log, monkeypatch):
    """``concurrent`` (``run`` on the wall clock, decisions on a backend of their own): the windows go on while a
    decision runs, reporting the split published before it; the tracker is the decision's alone, the windows
    queued and fused once it is in; the loop's :class:`EstimatorThread` hands the new split out as soon as the
    decision finishes (``poll_decision``), not at the next window; a decision that fails is reported and the
    split kept; a model edit meanwhile reaches the decisions' backend only after it."""
    import threading
    from amhe_cli.control.closed_loop import EstimatorThread
    from amhe_cli.estimation import attribution, mhe as mhe_module
    monkeypatch.setattr(attribution, "PERIOD", 1.0)
    for name, n in (("TEST_CLIPS", 8), ("ATTRIBUTION_CLIPS", 12), ("LOCATE_CLIPS", 16)):  # decisions of a CPU
        monkeypatch.setattr(mhe_module, name, n)  # backend: seconds each at full size, and the log is 12 s long
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0
    times = iter(np.arange(t_push, step_log.t[-1], 0.25))
    mhe = MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1, attribute_device="cpu"))
    mhe.concurrent = True
    assert mhe.warm() > 0  # as run does: the decisions' backend has its model copies before the loop
    copies = {id(m) for m in mhe._decide_pool._models}
    gate, started, fail = threading.Event(), threading.Event(), []
    real = MovingHorizonEstimator._decide

    def held(self, *job):  # a decision that waits for the test's word, as a slow backend would
        started.set()
        assert gate.wait(60)
        if fail:
            raise RuntimeError(fail[0])
        return real(self, *job)

    monkeypatch.setattr(MovingHorizonEstimator, "_decide", held)
    est = EstimatorThread(mhe)
    tr = mhe.tracker

    def window():
        assert est.submit(step_log, next(times))
        return est.poll(wait=True)

    first = window()
    while not started.is_set():
        first = window()
    assert mhe.deciding and mhe.decided == 0 and not tr.decisions
    before = (first.mean[tr.im], first.mean[tr.iu])
    last_fused = tr.last
    during = [window() for _ in range(3)]  # the windows go on, each as fast as without a decision
    # queued: the windows that ended during it (the one whose update started it too, where it started there)
    queued, ended = [q[0] for q in mhe._queued], [u.t for u in during if not u.skipped]
    assert mhe.deciding and queued[len(queued) - len(ended):] == ended and queued[:-len(ended)] in ([], [first.t])
    assert tr.last == last_fused and not tr.decisions  # the tracker untouched meanwhile
    for u in during:
        assert (u.mean[tr.im], u.mean[tr.iu]) == before and u.compute_time < 5.0
    assert est.poll_decision() is None  # nothing new to hand out yet
    edits = []
    mhe.edit_models(lambda mdl: edits.append(id(mdl)))
    assert copies and not copies & set(edits) and len(edits) > 1  # the windows' models now, not the decision's
    gate.set()
    mhe._decider.join(60)
    assert mhe.decided == 1 and len(tr.decisions) == 1 and tr.decisions[0].t == first.t
    # the windows that ended meanwhile were fused as it ended, on its thread, not at the next window's update
    assert not mhe.deciding and not mhe._queued and tr.last == during[-1].t
    assert [j[0] for j in mhe.jobs][:1] == [first.t] and mhe.jobs[0][4] == tr.decisions[0].reason
    assert all(0 <= j[1] <= j[2] for j in mhe.jobs)  # started, ended: seconds after its window's update began
    # its measured run (held here) is what the next provisional decision is taken to take: none is made that
    # would still run when its change's final one is due
    assert tr.lead == pytest.approx(max(e - s for _, s, e, _, w in mhe.jobs if w != "test")) and tr.lead > 0
    # one that seeks its change scores LOCATE_CLIPS clips more: before any such ran, taken to take that much more
    assert tr.seek_lead == pytest.approx(tr.lead * attribution.SEEK_WORK) and attribution.SEEK_WORK > 2
    assert len(mhe.decision_times) == 1 and mhe.decision_times[0] > 0
    said = mhe.describe_decisions()  # the run's log line (the CPU backend keeps no timing of its own)
    assert said.startswith("MHE line decisions took a median ") and said.endswith("1 decisions, each on a thread "
                                                                                    "of its own")
    handed = est.poll_decision()  # the decision's split, at once, on the last window's other parameters
    assert handed is not None and (handed.mean[tr.im], handed.mean[tr.iu]) == tr.ref
    assert handed.t == during[-1].t and est.poll_decision() is None
    after = window()  # the queued windows fused, in order, then this one; the edit reaches the decisions' models
    if mhe.deciding:  # this window's change test, started with its update, may outlast it (on a CPU backend)
        mhe._decider.join(60)
    assert tr.last == after.t or [q[0] for q in mhe._queued] == [after.t]
    assert tr.last >= during[-1].t and copies <= set(edits)
    # a decision that fails: reported by the loop's thread, the split kept, the windows unharmed
    fail.append("backend lost")
    gate.clear()
    started.clear()
    while not started.is_set():
        window()
    kept = tr.ref
    gate.set()
    mhe._decider.join(60)
    errors = est.take_errors()  # the windows queued meanwhile chain the decision still due: it fails again
    assert errors and all("MHE line decision failed (RuntimeError: backend lost)" in e for e in errors)
    assert mhe.jobs[-1][4] == "failed"
    assert tr.ref == kept and est.poll_decision() is not None and window() is not None
    est.close()


def test_a_provisional_decision_that_would_seek_its_change_is_taken_to_take_what_such_decisions_took(monkeypatch):
    """The lead the tracker holds its provisional decisions to (``SplitTracker.due``): the longest of the last
    LEAD_JOBS decisions' runs on their own thread (``lead``), and for one that would seek its change the longest of
    the last LEAD_JOBS that sought theirs (``seek_lead``), before any did ``lead`` × SEEK_WORK: read from the
    periodic decisions alone, a provisional decision that sought its change ran 0.56 s against a lead of 0.47 s
    on an H200, and the change's final decision waited for it."""
    import time
    from types import SimpleNamespace
    from amhe_cli.estimation import attribution, mhe as mhe_module
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    mhe = MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1, attribute_device="cpu"))
    tr = mhe.tracker

    def job(self, traj, stop, t, base, rng, test):  # a decision of ``t``'s kind that takes ``t`` / 50 s
        reason, sought = kinds[t]
        time.sleep(t / 50)
        self._sought = sought
        self.decision_times.append(t / 50)
        self.tracker.decisions.append(SimpleNamespace(reason=reason))

    monkeypatch.setattr(MovingHorizonEstimator, "_test_and_decide", job)
    kinds = {8.0: ("period", False), 4.0: ("period", False), 6.0: ("provisional", True), 3.0: ("change", True),
             2.0: ("period", False), 1.0: ("period", False), 1.5: ("period", False), 2.5: ("period", False)}
    expected = []
    for t in kinds:
        mhe._run_job(None, 0, t, None, None, False)
        expected.append((tr.lead, tr.seek_lead))
    assert [j[4] for j in mhe.jobs] == [reason for reason, _ in kinds.values()]
    lead, seek = np.array(expected).T
    assert mhe_module.LEAD_JOBS == 4 and attribution.SEEK_WORK > 2
    # none sought yet: SEEK_WORK times the lead; then what those that sought took, whatever ran between
    assert seek[:2] == pytest.approx(attribution.SEEK_WORK * np.array([0.16, 0.16]), abs=0.04)
    assert seek[2:] == pytest.approx([0.12, 0.12, 0.12, 0.12, 0.12, 0.12], abs=0.015)
    # the lead: the longest of the last four, the periodic 0.16 s out of them at the fifth
    assert lead == pytest.approx([0.16, 0.16, 0.16, 0.16, 0.12, 0.12, 0.06, 0.05], abs=0.015)


def test_a_window_s_decision_and_change_test_start_with_its_update_beside_the_window_s_solve(step_log, monkeypatch):
    """``concurrent``: a window's data count as soon as its update starts, and the decision they make due, or else
    the window's change test, starts then on the decisions' thread, not after the window's solve (which neither
    needs), so the solve's time is not between the data and the planner: held there, the window solves meanwhile
    and waits in the queue, fused once the thread is done."""
    import threading
    from amhe_cli.estimation import attribution
    monkeypatch.setattr(attribution, "PERIOD", 1.0)  # the first window's second of data makes a decision due
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0
    gate, calls = threading.Event(), []
    real = MovingHorizonEstimator._test_and_decide

    def held(self, traj, stop, t, base, rng, test=True):
        # the windows' cost (its W_x, which the decisions' cost takes) is set before: at the first window the
        # thread once ran ahead of it (AttributeError, the test lost)
        calls.append((float(t), self.tracker.due(), self.window_mean.copy(), self._cost is not None))
        assert gate.wait(60)
        return real(self, traj, stop, t, base, rng, test)

    monkeypatch.setattr(MovingHorizonEstimator, "_test_and_decide", held)
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1,
                                                          attribute_device="cpu")) as mhe:
        assert not mhe.early  # by default only for decisions on a GPU: on the CPU they would take the cores
        mhe.concurrent = mhe.early = True
        tr = mhe.tracker
        for k, t in enumerate((t_push, t_push + 0.5)):
            gate.clear()
            before = mhe.window_mean.copy()
            u = mhe.update(step_log, t)
            assert not u.skipped and len(calls) == k + 1 and calls[k][0] == u.t and tr.last == u.t
            np.testing.assert_array_equal(calls[k][2], before)  # started before the window's solve
            assert calls[k][3]
            assert mhe.deciding and [q[0] for q in mhe._queued] == [u.t]  # solved meanwhile, waiting
            gate.set()
            mhe._decider.join(60)
            if k == 0:  # the first: the periodic decision its data made due, on data to the window's end
                assert calls[0][1] == (t_push - 1.0, "period") and len(tr.decisions) == 1
                assert tr.decisions[0].t == u.t
            else:  # the next: its change test (no decision due), the window before fused first
                assert calls[1][1] is None and len(tr.decisions) == 1 and calls[0][0] in tr.product.times


def test_a_decision_the_windows_make_due_during_another_starts_as_that_one_ends(step_log, monkeypatch):
    """``concurrent``: windows that end while a decision runs are fused on its thread as it ends, and the decision
    they make due starts there at once, on the last of them, not at the next window's update (up to 0.5 s later
    on the wall clock)."""
    import threading
    from amhe_cli.estimation import attribution
    monkeypatch.setattr(attribution, "PERIOD", 0.5)  # each window's new half second makes a decision due
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0
    gate = threading.Event()
    real = MovingHorizonEstimator._decide

    def held(self, *job):
        assert gate.wait(60)
        return real(self, *job)

    monkeypatch.setattr(MovingHorizonEstimator, "_decide", held)
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1,
                                                          attribute_device="cpu")) as mhe:
        mhe.concurrent = mhe.early = True
        tr = mhe.tracker
        ts = [t_push, t_push + 0.5, t_push + 1.0]
        updates = [mhe.update(step_log, t) for t in ts]  # the first's decision held; the others end meanwhile
        assert not any(u.skipped for u in updates) and mhe.deciding and not tr.decisions
        assert [q[0] for q in mhe._queued] == ts
        gate.set()
        mhe._decider.join(120)
        # no window since: the first's decision, then the one the queued windows made due, on the last of them
        assert not mhe.deciding and [d.t for d in tr.decisions] == [ts[0], ts[2]]
        assert [j[0] for j in mhe.jobs] == [ts[0], ts[2]] and tr.last == ts[2]
        first, chained = mhe.jobs
        began = mhe._began  # time.monotonic() at each window's update start: the jobs' times are after it
        assert 0 <= began[ts[2]] + chained[1] - (began[ts[0]] + first[2]) < 0.1  # started as the first ended
        # taking the queued windows in fails: reported, and the thread is never left marked busy (the windows
        # would queue for ever, no decision made again)
        gate.clear()
        u = mhe.update(step_log, ts[2] + 0.5)
        assert mhe.deciding
        mhe.update(step_log, ts[2] + 1.0)  # queued
        monkeypatch.setattr(tr, "fuse", lambda *a: (_ for _ in ()).throw(RuntimeError("fusion broke")))
        gate.set()
        mhe._decider.join(120)
        errors = mhe.take_decision_errors()
        assert not mhe.deciding and not mhe._queued and len(errors) == 1 and "fusion broke" in errors[0]
        assert not u.skipped


def test_a_window_whose_update_starts_during_a_decision_has_its_own_started_as_that_one_ends(step_log, monkeypatch):
    """``concurrent`` and ``early``: a window whose update starts while a decision runs has its data counted, and
    the decision they make due started, on the decisions' thread as that one ends, beside the window's solve, not
    after it (there a final decision waited for a provisional one and then for the solve, 0.3–0.4 s); once solved
    the window is fused in order and neither tested nor decided again."""
    import threading
    import time as _time
    from amhe_cli.estimation import attribution, mhe as mhe_module
    monkeypatch.setattr(attribution, "PERIOD", 0.5)  # each window's new half second makes a decision due
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    t_push = step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0
    ts = [float(t_push), float(t_push) + 0.5]
    first, solve, solving = threading.Event(), threading.Event(), threading.Event()
    calls, holding = [], {"solve": False}
    real_decide, real_step = MovingHorizonEstimator._decide, mhe_module.gaussian_step

    def decide(self, traj, stop, t, *a, **k):
        calls.append(float(t))
        if len(calls) == 1:
            assert first.wait(60)
        return real_decide(self, traj, stop, t, *a, **k)

    def step(*a):  # the second window's solve, held until the test lets it go
        if holding["solve"]:
            solving.set()
            assert solve.wait(60)
        return real_step(*a)

    def until(ok, timeout=60.0):
        end = _time.monotonic() + timeout
        while not ok() and _time.monotonic() < end:
            _time.sleep(0.01)
        return ok()

    monkeypatch.setattr(MovingHorizonEstimator, "_decide", decide)
    monkeypatch.setattr(mhe_module, "gaussian_step", step)
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1,
                                                          attribute_device="cpu")) as mhe:
        mhe.concurrent = mhe.early = True
        tr = mhe.tracker
        assert not mhe.update(step_log, ts[0]).skipped and mhe.deciding and calls == [ts[0]]
        holding["solve"] = True
        out = []
        second = threading.Thread(target=lambda: out.append(mhe.update(step_log, ts[1])), daemon=True)
        second.start()
        assert solving.wait(60)  # its update started (its data in) while the first decision runs
        first.set()
        # the first window fused, then the decision the second's data make due, while its solve is held
        assert until(lambda: len(calls) == 2, 10.0) and calls[1] == ts[1] and second.is_alive()
        holding["solve"] = False
        solve.set()
        second.join(60)
        assert out and not out[0].skipped
        assert until(lambda: not mhe.deciding)
        mhe._decider.join(60)
        assert [d.t for d in tr.decisions] == ts and [j[0] for j in mhe.jobs] == ts  # nothing again after its solve
        assert tr.last == ts[1] and ts[1] in tr.product.times
        assert mhe._early is None and not mhe._queued and mhe._started_early is None


def test_a_window_started_early_is_taken_in_by_its_solve_or_by_the_decisions_thread_never_both(step_log, monkeypatch):
    """The hand-over of a window whose update starts during a decision: claimed by the decisions' thread first, its
    solved window is queued as tested; solved first, it is queued untested and the thread tests it once, from the
    queue. A window tested twice would count as two tests in a row, which open a change."""
    from amhe_cli.estimation import attribution
    monkeypatch.setattr(attribution, "PERIOD", 1e9)  # no periodic decision: only change tests are due
    scene = Scene(SceneConfig())
    space = ParameterSpace(scene, free=("box_mass", "box_friction"), prior={"box_mass": 2.0, "box_friction": 0.3},
                           prior_std={"box_mass": 0.1, "box_friction": 0.015})
    t0 = float(step_log.t[np.argmax(np.linalg.norm(step_log.box_linvel[:, :2], axis=1) > 0.05)] + 1.0)
    with MovingHorizonEstimator(scene, space, MHESettings(attribute=True, fuse=True, seed=1,
                                                          attribute_device="cpu")) as mhe:
        mhe.concurrent = mhe.early = True
        mhe.update(step_log, t0)
        mhe._decider.join(60)
        mu = mhe.window_mean.copy()
        for k, claimed_first in enumerate((True, False)):
            t = t0 + 0.5 * (k + 1)
            stop = int(np.searchsorted(step_log.t, t, side="right"))
            mhe._busy = True  # a decision runs on the thread
            assert not mhe._test_early(step_log, stop, t) and mhe._early[2] == t
            if claimed_first:  # the decision ends before the window's solve: the thread starts its test
                job = mhe._next_job()
                assert job[2] == t and job[5] is True and mhe._early is None and mhe._started_early == t
                mhe._attribute(step_log, stop, t, mu)  # solved: queued, already tested
                assert mhe._queued[-1][0] == t and mhe._queued[-1][4] is True and mhe._started_early is None
                assert mhe._next_job() is None and not mhe.deciding  # fused; nothing more for it
            else:  # the solve is in first: queued untested, and the thread's claim of it lapses
                mhe._attribute(step_log, stop, t, mu)
                assert mhe._early is None and mhe._queued[-1][0] == t and mhe._queued[-1][4] is False
                job = mhe._next_job()
                assert job[2] == t and job[5] is True  # its one test, from the queue
                mhe._busy = False
            assert mhe.tracker.last == t


# -- outputs and errors through the CLI ------------------------------------------

@pytest.fixture(scope="module")
def step_mcap(step_log, tmp_path_factory):
    path = tmp_path_factory.mktemp("mhe") / "step.mcap"
    write_mcap(path, step_log)
    ts = step_log.meta["truth_series"]
    with open(path.with_name("step.truth.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "box_mass_kg", "mu_floor_at_box_center"])
        w.writerows(zip(ts["t"][::5], ts["box_mass"][::5], ts["box_friction"][::5]))
    return path


def test_mhe_replay_attributes_by_default_given_a_belief_and_noisy_poses(step_log, step_mcap, tmp_path):
    """``mhe-replay`` attributes the mass and friction unless told (``--attribute/--no-attribute``) where a belief
    is given, both are free and the box's poses were smoothed for their noise (motion capture), with the run's
    windows; not on a clean log, without a belief, or with one of the two fixed."""
    from dataclasses import replace as dc_replace
    from amhe_cli.estimation.belief import Belief
    from amhe_cli.estimation.mhe import REPLAY_SETTINGS, replay_windows
    from amhe_cli.estimation.problem import load_problem
    from amhe_cli.estimation.replay import attribute_by_default
    rng = np.random.default_rng(0)
    k = int(np.searchsorted(step_log.t, 6.0))  # the first pushes: decisions due, and short
    cut = step_log.slice(0, k)
    noisy = dc_replace(cut, box_pos=cut.box_pos + rng.normal(0, 0.001, cut.box_pos.shape),
                       base_pos=cut.base_pos + rng.normal(0, 0.001, cut.base_pos.shape))
    noisy_mcap = write_mcap(tmp_path / "noisy.mcap", noisy)
    prior = Belief({"box_mass": 2.0, "box_friction": 0.3}, {"box_mass": 0.1, "box_friction": 0.015},
                   free=["box_mass", "box_friction"]).save(tmp_path / "b.belief.yaml")
    load = lambda log, params=("box_mass", "box_friction"): load_problem(str(log), params=params, prior=str(prior))  # noqa: E731
    noisy_problem = load(noisy_mcap)  # each load fits the log's robot (rollouts): once per log and space
    assert attribute_by_default(noisy_problem, prior)
    assert not attribute_by_default(load(step_mcap), prior)  # a clean log: the windows split it well
    assert not attribute_by_default(noisy_problem, None)  # no belief to hold the split
    assert not attribute_by_default(load(noisy_mcap, ("box_mass",)), prior)
    assert replay_windows(False, {"samples": None, "max_steps": None}) == {
        "samples": REPLAY_SETTINGS["samples"], "max_steps": REPLAY_SETTINGS["max_steps"]}
    assert replay_windows(True, {"samples": None, "max_steps": 99}) == {"samples": MHESettings.samples,
                                                                         "max_steps": 99}
    said = {}
    for extra in ([], ["--no-attribute"]):
        proc = subprocess.run([*AMHE, "mhe-replay", str(noisy_mcap), "--prior", str(prior), "--every", "2.0",
                               "--out", str(tmp_path / f"e{len(extra)}.csv"), *extra], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
        said[bool(extra)] = proc
    assert "attributed by line decisions, with the run's windows (10 samples, 150 steps" in said[False].stderr
    assert "line decisions" in said[False].stdout  # its summary counts them
    assert "attributed by line decisions" not in said[True].stderr and "line decisions" not in said[True].stdout


def test_cli_csv_and_mcap_round_trip(step_mcap, tmp_path):
    out, mcap, png = tmp_path / "est.csv", tmp_path / "est.mcap", tmp_path / "est.png"
    proc = subprocess.run([*AMHE, "mhe-replay", str(step_mcap), "--out", str(out), "--mcap", str(mcap),
                           "--plot", str(png), "--realtime", "--json", "-q"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["realtime"] and summary["realtime_factor"] > 0 and "box_friction" in summary["tracking_error"]
    with open(out) as f:
        rows = list(csv.reader(f))
    # fused by default: each window's own estimate follows the fused ones
    assert rows[0] == ["t", "box_mass", "box_mass_std", "box_friction", "box_friction_std",
                       "box_mass_window", "box_friction_window"]
    table = np.array(rows[1:], dtype=float)
    assert len(table) == summary["updates"] and np.all(np.diff(table[:, 0]) > 0)
    t, values, labels = read_float_arrays(mcap, "/amhe/estimate")
    assert labels == rows[0][1:]
    np.testing.assert_allclose(values, table[:, 1:])
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("args, words", [
    (["--window", "100"], ["--window", "longer than the log"]),
    (["--params", "box_mass,volume"], ["volume"]),
    (["--alpha", "1.5"], ["--alpha"]),
    (["--sweep", "colour=1,2"], ["--sweep"]),
    (["--fill", "0.5"], ["--fill 0.5", "needs --realtime"]),
    (["--attribute"], ["--attribute", "--prior"]),
])
def test_cli_errors(step_mcap, tmp_path, args, words):
    proc = subprocess.run([*AMHE, "mhe-replay", str(step_mcap), "--out", str(tmp_path / "x.csv"), *args],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("amhe: error:") and all(w in line for w in words)


def test_cli_fill_reports_the_step_budgets_it_used(step_mcap, tmp_path):
    proc = subprocess.run([*AMHE, "mhe-replay", str(step_mcap), "--out", str(tmp_path / "x.csv"), "--realtime",
                           "--fill", "0.5", "--every", "2", "--max-steps", "30", "--samples", "4", "--iters", "2",
                           "--threads", "1", "--json"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    budget = json.loads(proc.stdout)["step_budget"]
    assert budget["min"] == 30 and 30 < budget["max"] <= 120  # the first update at max_steps, then grown


def test_a_live_clock_replay_defers_what_run_would_and_counts_it():
    """``replay(realtime=True)`` keeps ``run``'s schedule: an update due while the last one runs, or before
    the thread has rested for ``duty``, is dropped, not queued; the real-time factor is that of every due
    update. A stub estimator takes 1.2 s an update, due every 0.5 s over 10 s of log."""
    from types import SimpleNamespace

    from amhe_cli.estimation.mhe import Update

    class Slow:
        settings = MHESettings(window=1.0, every=0.5)
        warmed = 0

        def warm(self):  # the live clock loads a decisions' backend before it starts
            self.warmed += 1
            return 0.0

        def update(self, traj, t):
            return Update(t=t, mean=np.zeros(1), std=np.ones(1), cost=0.0, iterations=1, compute_time=1.2,
                          skipped=False)

    traj = SimpleNamespace(t=np.arange(0.0, 10.0 + 1e-9, 0.002))
    fast = replay(traj, Slow())
    assert len(fast.updates) == 19 and fast.deferred == 0  # 1.0, 1.5, …, 10.0
    for duty, every_nth in ((1.0, 3), (0.5, 5)):  # busy 1.2 s: the next start 1.5 s on; resting too: 2.5 s
        live = replay(traj, slow := Slow(), realtime=True, duty=duty)
        assert slow.warmed == 1
        assert [u.t for u in live.updates] == pytest.approx(np.arange(1.0, 10.0 + 1e-9, 0.5 * every_nth))
        assert live.deferred == 19 - len(live.updates)
        np.testing.assert_allclose(live.lags, 1.2)
        assert live.realtime_factor == pytest.approx(fast.realtime_factor) == pytest.approx(10.0 / (19 * 1.2))
    with pytest.raises(AmheError, match="duty 0"):
        replay(traj, Slow(), realtime=True, duty=0.0)


def test_settings_check():
    with pytest.raises(AmheError, match="--clip"):
        MHESettings(window=0.5, clip=1.0).check()
    for fill in (0.0, 1.5):
        with pytest.raises(AmheError, match="mhe fill"):
            MHESettings(fill=fill).check()


def test_fill_sizes_the_step_budget_to_the_time_the_core_gives_an_update():
    """``fill``: steps per candidate = fill · every · duty / (iters · time per step), kept within
    [max_steps, FILL_MAX · max_steps]; without it the budget stays max_steps whatever the speed."""
    from amhe_cli.estimation.mhe import FILL_MAX, SPEED_EMA

    scene = Scene(SceneConfig())

    def estimator(**kw):
        return MovingHorizonEstimator(scene, ParameterSpace(scene, free=("box_mass", "box_friction")),
                                      MHESettings(every=0.5, iters=3, max_steps=150, **kw))

    with estimator() as m:
        assert m.budget(0.01, 450) == 150  # no fill: a fast core changes nothing
    with estimator(fill=0.8) as m:
        assert m.budget(0.3, 450) == pytest.approx(200, abs=1)  # 0.4 s / (3 · 0.3 s / 450)
        # the next update ran slower: the time per step moves by SPEED_EMA toward it
        per_step = (1 - SPEED_EMA) * 0.3 / 450 + SPEED_EMA * 0.6 / 450
        assert m.budget(0.6, 450) == pytest.approx(0.4 / (3 * per_step), abs=1) and m.steps < 199
    with estimator(fill=0.8) as m:
        assert m.budget(0.01, 450) == FILL_MAX * 150  # a core with time to spare: up to the cap
    with estimator(fill=0.8) as m:
        assert m.budget(1.0, 450) == 150  # a slow core: never below max_steps (deferral handles the rest)
    for compute, steps in ((0.3, 150), (0.1, 300)):  # half a shared core: half the time (100 -> floor; 300)
        with estimator(fill=0.8) as m:
            m.duty = 0.5
            assert m.budget(compute, 450) == pytest.approx(steps, abs=1)


def test_fill_rolls_out_more_of_each_window_on_a_live_clock_replay(step_log):
    """On a replay at run's clock an update with ``fill`` has more steps than max_steps where the period
    leaves the core idle (every 2 s here), and no update is deferred for it."""
    scene = Scene(SceneConfig())
    budgets = {}
    for fill in (None, 0.5):
        space = ParameterSpace(scene, free=("box_mass", "box_friction"))
        st = MHESettings(every=2.0, iters=2, samples=4, max_steps=30, fill=fill)
        with MovingHorizonEstimator(scene, space, st, nthread=1) as m:
            res = replay(step_log, m, realtime=True)
        assert res.deferred == 0
        budgets[fill] = [u.steps for u in res.updates if not u.skipped]
    assert len(budgets[None]) >= 3 and set(budgets[None]) == {30}
    assert budgets[0.5][0] == 30 and max(budgets[0.5][1:]) > 30 and max(budgets[0.5]) <= 120


def test_truth_change_times_name_where_a_parameter_takes_a_new_value():
    ts = TruthSeries(np.array([0.0, 0.5, 1.0, 1.5]), {"box_friction": np.array([0.4, 0.4, 0.8, 0.8]),
                                                     "box_inertia": np.array([[1, 1, 1], [1, 2, 1], [1, 2, 1],
                                                                              [1, 2, 1]], dtype=float)})
    np.testing.assert_array_equal(ts.change_times("box_friction"), [1.0])
    np.testing.assert_array_equal(ts.change_times("box_inertia"), [0.5])  # any component
    assert ts.change_times("box_mass").size == 0  # unknown: no change


def test_known_costs_are_taken_and_only_the_others_scored():
    from amhe_cli.estimation.mhe import known_costs
    Q = np.array([[1.0, 2.0], [3.0, 4.0]])
    asked = []

    def evaluate(R):
        asked.append(R.copy())
        return R.sum(axis=1) * 10
    score = known_costs(Q, np.array([5.0, 7.0]), evaluate)
    np.testing.assert_array_equal(score(np.array([[3.0, 4.0], [1.0, 1.0], [1.0, 2.0 * (1 + 1e-12)]])), [7.0, 20.0, 5.0])
    assert len(asked) == 1 and asked[0].tolist() == [[1.0, 1.0]]
    score(Q)
    assert len(asked) == 1
