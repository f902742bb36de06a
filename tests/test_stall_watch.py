"""The planner's process stalls: noticed, dated, and traced to the thread that held it (control/stall_watch.py);
the garbage collector's full passes kept out of the wall-clock loop (control/closed_loop.py)."""

from __future__ import annotations

import gc
import threading
import time

import pytest

from amhe_cli.control.closed_loop import RunSettings, run_task
from amhe_cli.control.evaluate import run_settings
from amhe_cli.control.planner import PlannerSettings
from amhe_cli.control.reflex import ReflexSettings
from amhe_cli.control.stall_watch import StallWatch
from amhe_cli.control.tasks import get_task
from amhe_cli.errors import AmheError
from helpers import gil_hog


def hog_in_thread(seconds: float, delay: float = 0.1) -> threading.Thread:
    def hold():
        time.sleep(delay)
        gil_hog(seconds)

    th = threading.Thread(target=hold, name="hog")
    th.start()
    return th


def test_a_hold_of_the_interpreter_lock_is_one_stall_traced_to_the_thread_that_held_it(tmp_path):
    path = tmp_path / "stalls.txt"
    with StallWatch(after=0.15, file=path) as watch:
        hog_in_thread(0.4).join()
        time.sleep(0.1)
        new = watch.take()
        assert watch.take() == []  # handed out once
    assert new and new == watch.stalls  # (a busy machine may add a short one of its own)
    start, length = max(new, key=lambda s: s[1])
    assert 0.3 < length < 5.0
    text = path.read_text()
    assert text.startswith("Timeout")  # the stacks were written during the stall, not after it
    assert "in gil_hog" in text and "in hold" in text  # the holder's own frames
    assert text.count("-- the stall above:") == text.count("Timeout") == len(new)


def test_a_process_that_never_stalls_leaves_no_stall_and_no_file(tmp_path):
    path = tmp_path / "stalls.txt"
    with StallWatch(after=0.5, file=path) as watch:
        for _ in range(20):  # the lock is taken and given back all the time, never held
            sum(range(10_000))
            time.sleep(0.01)
    assert watch.stalls == [] and watch.take() == []
    assert not path.exists()


def test_bad_stall_settings_are_refused():
    with pytest.raises(ValueError, match="period"):
        StallWatch(after=0.01, period=0.02)
    with pytest.raises(AmheError, match="stall_after"):
        RunSettings(stall_after=0.01).check()
    assert run_settings("t1", "baseline", {"stall_after": 0.3})[1].stall_after == 0.3
    assert run_settings("t1", "baseline", {"stall_after": None})[1].stall_after is None
    with pytest.raises(AmheError, match="stall_after"):
        run_settings("t1", "baseline", {"stall_after": "soon"})


def test_a_run_on_the_wall_clock_warns_of_its_process_stalling_and_keeps_the_stacks(tmp_path):
    path = tmp_path / "run.stalls.txt"
    started = []

    def progress(t):
        if t > 0.3 and not started:
            started.append(hog_in_thread(0.4, delay=0.0))

    settings = RunSettings(mode="true", realtime=True, planner=PlannerSettings(samples=4, horizon=10, refine_loops=1),
                           threads=1, reflex=ReflexSettings(enabled=False))
    r = run_task(get_task("t1", duration=1.5), None, settings, progress=progress, stall_file=path)
    started[0].join()
    assert len(r.stalls) >= 1
    t0, length = max(r.stalls, key=lambda s: s[1])
    assert length > 0.3 and 0.0 <= t0 < 1.5  # dated on the plant's clock
    (w,) = [w for w in r.warnings if "the planner's process stalled" in w and f"{length:.2f} s" in w]
    assert "run.stalls.txt" in w
    assert "in gil_hog" in path.read_text()
    assert r.metrics()["stalls"][-1][1] == pytest.approx(r.stalls[-1][1], abs=1e-3)
    quiet = run_task(get_task("t1", duration=0.3), None, RunSettings(mode="true", planner=settings.planner, threads=1),
                     stall_file=tmp_path / "lockstep.txt")
    assert quiet.stalls == [] and "stalls" not in quiet.metrics()  # the lock-step sim is not watched
    assert not (tmp_path / "lockstep.txt").exists()


def test_the_wall_clock_loop_leaves_the_objects_made_before_it_out_of_the_collectors_passes():
    heap = [[i] for i in range(1_000_000)]  # a GPU backend's modules and kernels: half a million objects
    t = time.perf_counter()
    gc.collect()
    before = time.perf_counter() - t
    during = []

    def progress(t):
        if t > 0.2 and not during:
            a = time.perf_counter()
            gc.collect()  # a full pass, as the collector starts one when enough objects have piled up
            during.append(time.perf_counter() - a)

    settings = RunSettings(mode="true", realtime=True, planner=PlannerSettings(samples=4, horizon=10, refine_loops=1),
                           threads=1, reflex=ReflexSettings(enabled=False))
    r = run_task(get_task("t1", duration=0.8), None, settings, progress=progress)
    assert during and during[0] < before / 5, (during, before)
    assert any("left out of the garbage collector's passes" in m for m in r.messages)
    assert gc.get_freeze_count() == 0  # given back after the run
    t = time.perf_counter()
    gc.collect()
    assert time.perf_counter() - t > 2 * during[0]
    del heap
