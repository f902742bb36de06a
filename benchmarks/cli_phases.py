"""Where the wall time of one ``amhe`` command goes, phase by phase, without a profiler's distortion.

    python benchmarks/cli_phases.py identify LOG --device cuda --out /tmp/b.yaml --force

runs the command in this process (as the ``amhe`` entry point does) with wall-clock timers
around its phases: the imports before the command starts, reading the log (every read, with
its decoding), the robot-side payload fit, creating the rollout backend (on ``cuda``: importing
Warp and MuJoCo Warp), the first rollout call (on ``cuda``: loading or compiling the kernels and
the first slot), the rest of the identification, and writing the outputs. cProfile inflates
Python-heavy phases (message decoding) 2–4×, so its figures misstate what a user waits for; these
do not. Prints one ``phase seconds`` line per phase and ``total``; ``$OUT/cli_phases.txt`` gets
the same lines when ``$OUT`` is set.
"""

from __future__ import annotations

import importlib
import os
import sys
import time

T0 = time.perf_counter()

from amhe_cli.cli import main  # noqa: E402  (the entry point's own import, timed)

PHASES: dict[str, float] = {"imports (entry point)": time.perf_counter() - T0}
_depth: dict[str, int] = {}


def _timed(name, fn):
    """``fn`` wrapped to add its wall time to ``PHASES[name]`` (outermost call of that phase only; phases
    nest: "identify" includes "make backend")."""
    def wrapper(*a, **k):
        if _depth.get(name):
            return fn(*a, **k)
        _depth[name] = 1
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            PHASES[name] = PHASES.get(name, 0.0) + time.perf_counter() - t
            _depth[name] = 0
    wrapper.__wrapped__ = fn
    return wrapper


def _wrap(module_name: str, attr: str, wrap) -> None:
    """Replace ``module.attr``, and every amhe module's reference to the same object, by ``wrap(it)``."""
    fn = getattr(importlib.import_module(module_name), attr)
    new = wrap(fn)
    for name, m in list(sys.modules.items()):
        if name.startswith("amhe_cli") and getattr(m, attr, None) is fn:
            setattr(m, attr, new)


def _patch(module_name: str, attr: str, phase: str) -> None:
    """``module.attr`` timed as ``phase`` wherever amhe calls it."""
    _wrap(module_name, attr, lambda fn: _timed(phase, fn))


def _patch_first_call(module_name: str, cls: str, attr: str, phase: str) -> None:
    """The first call of method ``cls.attr`` timed as ``phase``."""
    klass = getattr(importlib.import_module(module_name), cls)
    fn = getattr(klass, attr)
    timed = _timed(phase, fn)
    state = {"done": False}

    def method(self, *a, **k):
        if state["done"]:
            return fn(self, *a, **k)
        state["done"] = True
        return timed(self, *a, **k)
    setattr(klass, attr, method)


BACKENDS: list = []


def _keep_backends() -> None:
    """Keep every backend ``make_backend`` creates, to print the Warp backend's own phase timing."""
    def keeping(made):
        def keep(*a, **k):
            BACKENDS.append(made(*a, **k))
            return BACKENDS[-1]
        return keep
    _wrap("amhe_cli.model.device", "make_backend", keeping)


def main_phases(argv: list[str]) -> None:
    t = time.perf_counter()
    import amhe_cli.cli.common  # noqa: F401  (what `amhe identify` imports before it starts)
    import amhe_cli.cli.identify  # noqa: F401
    import amhe_cli.estimation.identify  # noqa: F401
    PHASES["imports (command)"] = time.perf_counter() - t
    _patch("amhe_cli.io.reader", "read_log", "read log (decode, resample, smooth)")
    _patch("amhe_cli.model.device", "set_default", "choose device (imports Warp on cuda)")
    _patch("amhe_cli.estimation.problem", "mocap_offset", "pose stream lag")
    _patch("amhe_cli.estimation.problem", "infer_scene_config", "scene geometry from the log")
    _patch("amhe_cli.estimation.problem", "_servo_from_efforts", "servo gains from efforts")
    _patch("amhe_cli.estimation.payload", "fit_payload", "payload fit")
    _patch("amhe_cli.model.device", "make_backend", "make backend (imports Warp on cuda)")
    _keep_backends()
    _patch("amhe_cli.estimation.identify", "identify", "identify (all of it)")
    _patch("amhe_cli.cli.common", "save_outputs", "write outputs")
    _patch_first_call("amhe_cli.model.rollout_warp", "WarpRollout", "rollout_candidates",
                      "first cuda rollout call (kernels, first slot)")
    t = time.perf_counter()
    try:
        main(argv)
    finally:
        PHASES["command (all of it)"] = time.perf_counter() - t
        PHASES["total (process start to end)"] = time.perf_counter() - T0
        lines = [f"{k:48s} {v:8.2f}" for k, v in PHASES.items()]
        for b in BACKENDS:
            if hasattr(b, "timing"):  # the Warp backend's phases, summed over its calls
                lines.append("  warp backend: " + ", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                                                           for k, v in b.timing.items()))
        text = "\n".join(lines)
        print(text, flush=True)
        if os.environ.get("OUT"):
            with open(os.path.join(os.environ["OUT"], "cli_phases.txt"), "a") as f:
                f.write(" ".join(argv) + "\n" + text + "\n\n")


if __name__ == "__main__":
    main_phases(sys.argv[1:])
