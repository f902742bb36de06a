"""Run configuration, the probing belief, and the evaluation grid (paper §V, Table I).

* :func:`run_settings` builds :class:`~amhe_cli.control.closed_loop.RunSettings` and the
  task from a YAML config (``planner:``, ``weights:``, ``mhe:``, ``kp``, ``kd``,
  ``cycle``, ``task:`` overrides such as ``duration``);
* :func:`probe_belief` is what ``run`` does without ``--belief``: the lunge probe
  in the sim plant with the task's starting truth, then ``identify``;
* :func:`evaluate` runs tasks × modes × seeds in worker processes (or as Ray
  tasks, on this machine or a cluster) and
  :func:`summarise` gives the mean ± std table of S_R, e_g, J, t_exec.
"""

from __future__ import annotations

import copy
import json
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import yaml

from amhe_cli.estimation.belief import Belief
from amhe_cli.io.plain import to_plain
from amhe_cli.control.closed_loop import MODES, RUN_PARAMS, RunSettings, run_task, task_scene_config
from amhe_cli.errors import AmheError, check_names
from amhe_cli.estimation.identify import IdentifySettings, identify
from amhe_cli.estimation.mhe import REALTIME_MHE, MHESettings
from amhe_cli.model.params import ParameterSpace
from amhe_cli.control.planner import REALTIME_PLANNER, PlannerSettings
from amhe_cli.control.probing import simulate_probe
from amhe_cli.control.reflex import ReflexSettings
from amhe_cli.model.scene import Scene, infer_scene_config
from amhe_cli.control.tasks import CostWeights, Task, get_task

CONFIG_KEYS = {"planner", "weights", "mhe", "mhe_params", "kp", "kd", "cycle", "latency", "mhe_cores", "task",
               "safety", "reflex", "mhe_shadow", "mocap_latency", "robot_read", "relay_process", "stall_after"}


def load_config(path: str | os.PathLike | None) -> dict:
    """A run config YAML as a dict ({} for None).

    Raises:
        AmheError: unreadable file, not a mapping, or unknown top-level keys.
    """
    if path is None:
        return {}
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except OSError as e:
        raise AmheError(f"--config {path}: {e.strerror}") from None
    except yaml.YAMLError as e:
        raise AmheError(f"--config {path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise AmheError(f"--config {path}: expected a mapping of {', '.join(sorted(CONFIG_KEYS))}")
    check_names(data, CONFIG_KEYS, f"key in --config {path}:")
    return data


def _number(config: dict, key: str) -> float:
    """The config's ``key`` as a float, or an :class:`AmheError` naming the key and what was expected."""
    try:
        return float(config[key])
    except (TypeError, ValueError):
        raise AmheError(f"config key {key}: {config[key]!r} is not a number") from None


def _flag(config: dict, key: str) -> bool:
    """The config's ``key`` as a YAML boolean, or an :class:`AmheError` naming the key."""
    if not isinstance(config[key], bool):
        raise AmheError(f"config key {key}: {config[key]!r} is not true or false")
    return config[key]


def _names(value) -> tuple:
    """``"a,b"`` or ``[a, b]`` -> ``("a", "b")``."""
    items = value.split(",") if isinstance(value, str) else list(value or [])
    return tuple(str(x).strip() for x in items if str(x).strip())


def run_settings(task_name: str, mode: str, config: dict | None = None, seed: int = 0, realtime: bool = False,
                 threads: int | None = None, duration: float | None = None) -> tuple[Task, RunSettings]:
    """The task and settings of one run from a config dict (see :func:`load_config`).

    On the wall clock (``realtime``), or a lock-step run that emulates it (the config's
    ``latency``), the planner starts from :data:`~amhe_cli.control.planner.REALTIME_PLANNER`
    and the MHE from :data:`~amhe_cli.estimation.mhe.REALTIME_MHE`, under the config's
    ``planner:`` and ``mhe:`` keys.

    Raises:
        AmheError: unknown task, mode, setting or weight name.
    """
    config = config or {}
    overrides = dict(config.get("task") or {})
    if duration is not None:
        overrides["duration"] = duration
    known = set(Task.__dataclass_fields__) - {"name", "weights", "events"}
    check_names(overrides, known, "task setting")
    if "duration" in overrides and not float(overrides["duration"]) > 0:
        raise AmheError(f"--duration {overrides['duration']}: expected a positive number of seconds")
    task = get_task(task_name, weights=CostWeights.from_dict(config.get("weights") or {}), **overrides)
    mhe = config.get("mhe") or {}
    check_names(mhe, MHESettings.__dataclass_fields__, "mhe setting")
    # the wall clock's planner and MHE where a run has one, or emulates one (``latency``)
    wall = realtime or config.get("latency") is not None
    planner = {**(REALTIME_PLANNER if wall else {}), **(config.get("planner") or {})}
    mhe = {**(REALTIME_MHE if wall else {}), **mhe}
    settings = RunSettings(mode=mode, realtime=realtime, planner=PlannerSettings.from_dict(planner),
                           mhe=MHESettings(**mhe), seed=seed, threads=threads,
                           reflex=ReflexSettings.from_dict(config.get("reflex") or {}),
                           **{k: _number(config, k) for k in ("kp", "kd", "cycle", "latency", "mhe_cores")
                              if config.get(k) is not None},
                           **({"mhe_params": _names(config["mhe_params"])} if "mhe_params" in config else {}),
                           **({k: _flag(config, k) for k in ("mhe_shadow", "robot_read") if k in config}),
                           **({"stall_after": None if config["stall_after"] is None else _number(config, "stall_after")}
                              if "stall_after" in config else {}))
    settings.check()
    return task, settings


def probe_belief(task: Task, seed: int = 0, threads: int | None = None, progress=None) -> Belief:
    """Probe in the sim plant with the task's starting truth and identify: the Adaptive-MHE starting belief.

    The probe is the lunge manoeuvre of ``amhe probe --target sim`` with the
    task's box; the identification uses the defaults of ``amhe identify``.
    """
    cfg = task_scene_config(task, 0.002)
    traj = simulate_probe(task.truth, config=replace(cfg, kp=None, kd=None), seed=seed)
    scene_cfg = infer_scene_config(traj, box_size=cfg.box_size)
    scene = Scene(scene_cfg)
    space = ParameterSpace(scene, free=RUN_PARAMS)
    res = identify(traj, scene, space, IdentifySettings(seed=seed), progress=progress, nthread=threads)
    return Belief.from_identify(res, space, scene_cfg, {"command": "run (probe in sim, then identify)", "seed": seed,
                                                         "truth": to_plain(dict(task.truth))})


def _one(args) -> dict:
    task_name, mode, seed, config, belief_dict, duration, setting = args
    task, settings = run_settings(task_name, mode, config, seed=seed, threads=1, duration=duration)
    belief = Belief(**belief_dict) if belief_dict else None
    r = run_task(task, belief, settings)
    return {"task": task_name, "mode": mode, "seed": seed, **r.metrics(), "control_hz": r.control_hz,
            "setting": setting}


def parse_sweep(text: str) -> tuple[str, list]:
    """``"mhe.samples=6,10,16"`` -> ``("mhe.samples", [6, 10, 16])`` (values read as YAML scalars).

    Raises:
        AmheError: not ``KEY=V1,V2,…``.
    """
    key, sep, vals = text.partition("=")
    values = [yaml.safe_load(v) for v in vals.split(",") if v.strip()]
    if not sep or not key.strip() or not values:
        raise AmheError(f"--sweep {text!r}: expected a dotted run setting and its values, e.g. mhe.samples=6,10,16")
    return key.strip(), values


def with_setting(config: dict, key: str, value) -> dict:
    """A copy of the run config ``config`` with the dotted setting ``key`` (``mhe.samples``, ``kp``) set."""
    out = copy.deepcopy(config or {})
    *path, leaf = key.split(".")
    node = out
    for part in path:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise AmheError(f"--sweep {key}: {part} is not a group of settings")
    node[leaf] = value
    return out


def default_setting(task_name: str, config: dict | None, key: str):
    """The value the dotted setting ``key`` has in the run ``config`` leaves (for marking the default).

    ``task.*`` and ``weights.*`` are read from the task, ``mhe.*`` and
    ``planner.*`` from the run settings' groups, others (``kp``, ``cycle``) from
    the run settings themselves.
    """
    task, settings = run_settings(task_name, "adaptive", config)
    head, _, leaf = key.partition(".")
    owner = {"task": task, "weights": task.weights, "mhe": settings.mhe, "planner": settings.planner}.get(head)
    return getattr(settings, head) if owner is None and not leaf else getattr(owner, leaf)


def sweep_variants(task_name: str, config: dict | None, sweeps: list[str]) -> list[tuple[str, dict]]:
    """(label, config) per swept value, one setting at a time around ``config`` (the paper's ablation).

    Raises:
        AmheError: a malformed ``--sweep`` or a setting the run config does not know.
    """
    out = []
    for text in sweeps:
        key, values = parse_sweep(text)
        for v in values:
            cfg = with_setting(config, key, v)
            run_settings(task_name, "adaptive", cfg)  # unknown names fail here, before any run
            out.append((f"{key}={v}", cfg))
    return out


def evaluate(task_name: str, modes, seeds: int, belief: Belief | None, config: dict | None = None,
             workers: int | None = None, duration: float | None = None, progress=None,
             done: set | None = None, ray: str | None = None,
             variants: list[tuple[str, dict]] | None = None) -> list[dict]:
    """Run every mode × seed of a task in worker processes (one rollout thread each), or as Ray tasks.

    Args:
        done: (setting, mode, seed) triples to skip (rows a cut-off grid already has).
        variants: (label, config) pairs to run the grid for (:func:`sweep_variants`);
            None: ``config`` alone, label "".
        progress: called with each row the moment its run finishes (in finishing
            order) — where a caller writes it to disk.
        ray: None: a local process pool of ``workers``. ``"local"``: a Ray
            instance started here (``workers`` CPUs); otherwise the address of
            a running Ray cluster (``ray://head:10001`` or ``head:6379``), whose
            nodes need the same amhe installed. One CPU per run either way, so
            the rows are the same (``control_hz`` aside, a wall-clock figure).
    Returns:
        one dict per run made, in finishing order: task, mode, seed, success,
        e_g, J, t_exec, rmse, fell, control_hz (and ``failure`` where the plant failed).
    Raises:
        AmheError: unknown mode, modes needing a belief without one, Ray asked for but not installed.
        KeyboardInterrupt: passed on after the runs not yet started are cancelled
            (those in flight are lost; every finished one went to ``progress``).
    """
    check_names(modes, MODES, "mode")
    if belief is None and set(modes) - {"true"}:
        raise AmheError("baseline and adaptive modes need a belief")
    variants = variants or [("", config)]
    done = done or set()
    # variants whose settings coincide (each swept setting's default value) run once, their row
    # copied under every label: a 4-setting ablation around the defaults saves 3 grids of runs.
    # Building the key validates each config before any worker starts.
    labels = {}  # effective settings -> labels sharing them
    for label, cfg in variants:
        labels.setdefault(_settings_key(task_name, cfg, duration), []).append((label, cfg))
    jobs, shared = [], {}
    for group in labels.values():
        label, cfg = group[0]
        for s in range(seeds):
            for m in modes:
                todo = [lb for lb, _ in group if (lb, m, s) not in done]
                if todo:
                    jobs.append((task_name, m, s, cfg, belief.__dict__ if belief else None, duration, todo[0]))
                    shared[(todo[0], m, s)] = todo
    rows = []
    finished = _ray_runs(jobs, ray, workers) if ray else _pool_runs(jobs, workers)
    for row in finished:
        for label in shared[(row["setting"], row["mode"], row["seed"])]:
            copy_ = {**row, "setting": label}
            rows.append(copy_)
            if progress is not None:
                progress(copy_)
    return rows


def _settings_key(task_name: str, config: dict | None, duration: float | None) -> str:
    """A canonical text of the task and run settings a config gives (ints as floats: ``window: 1`` is 1.0)."""
    task, settings = run_settings(task_name, "adaptive", config, duration=duration)

    def norm(x):
        if isinstance(x, dict):
            return {str(k): norm(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [norm(v) for v in x]
        if isinstance(x, (int, float, np.number)) and not isinstance(x, bool):
            return float(x)
        return x
    return json.dumps(norm(to_plain({"task": task.to_dict(), "settings": asdict(settings)})), sort_keys=True, default=str)


def _pool_runs(jobs: list, workers: int | None):
    """Rows of ``jobs`` from local worker processes, as each run finishes."""
    pool = ProcessPoolExecutor(max_workers=workers or os.cpu_count())
    try:
        futures = [pool.submit(_one, job) for job in jobs]
        for fut in as_completed(futures):
            yield fut.result()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def check_ray(address: str) -> None:
    """Fail before any run where ``--ray ADDRESS`` cannot work: Ray not installed, or nothing answers there.

    Raises:
        AmheError: one line saying which.
    """
    import importlib.util
    if address != "local":
        _check_reachable(address)
    if importlib.util.find_spec("ray") is None:
        raise AmheError("--ray needs Ray: pip install 'amhe[ray]'")


def _ray_runs(jobs: list, address: str, workers: int | None):
    """Rows of ``jobs`` run as Ray tasks of one CPU each, as each finishes (``ray.wait``)."""
    check_ray(address)
    import ray
    started = not ray.is_initialized()
    if started:
        if address == "local":  # a private instance, gone with this command (Ray binds the host's address)
            kw = {"num_cpus": workers or os.cpu_count()}
        else:
            kw = {"address": address}
        try:
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kw)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise AmheError(f"--ray {address}: cannot reach a Ray cluster there ({str(e).splitlines()[0]})") from None
    remote = ray.remote(num_cpus=1, max_retries=0)(_one)
    pending = [remote.remote(job) for job in jobs]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail fast, in one line, where nothing answers at a Ray address (Ray itself retries for minutes).

    Raises:
        AmheError: the address is not ``[ray://]host:port`` or nothing accepts a connection there.
    """
    import socket
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep or not host or not port.isdigit():
        raise AmheError(f"--ray {address}: expected a Ray cluster address HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as e:
        raise AmheError(f"--ray {address}: no Ray cluster answers there ({e.strerror or e}); start one with "
                        "`ray start --head` or give --ray alone for a local instance") from None


def summarise(rows: list[dict], modes, settings=("",)) -> list[dict]:
    """Per setting and mode: n, S_R [%], falls, recoveries, and mean ± std of e_g, J, t_exec, rmse (the
    paper's Table I, with the falls counted).

    ``settings``: the sweep labels in order (``("",)`` outside a sweep); each table row carries its ``setting``.
    """
    out = []
    for label in settings:
        for m in modes:
            sel = [r for r in rows if r["mode"] == m and r.get("setting", "") == label]
            if sel:
                out.append({"setting": label, **_stats(sel, m)})
    return out


def _stats(sel: list[dict], m: str) -> dict:
    """n, S_R [%], falls, fall-prevention recoveries and (mean, std) of e_g, J, t_exec, rmse over the rows
    ``sel`` of mode ``m``."""
    row = {"mode": m, "n": len(sel), "S_R": 100.0 * float(np.mean([r["success"] for r in sel])),
           "falls": int(sum(bool(r.get("fell")) for r in sel)),
           "recoveries": int(sum(int(r.get("recoveries", 0)) for r in sel))}
    for k in ("e_g", "J", "t_exec", "rmse"):
        v = np.array([r[k] for r in sel], dtype=float)
        row[k] = (float(v.mean()), float(v.std()))
    return row
