"""From a log and the user's options to an estimation problem: trajectory, scene, parameters.

Every subcommand that reads a log (``identify``, ``probe LOG``, ``mhe-replay``)
goes through :func:`load_problem`, so topic mapping, scene inference and priors
behave the same everywhere.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from amhe_cli.estimation.belief import Belief
from amhe_cli.estimation.gains import MAX_DELAY, applied_gains, applied_limit, delayed, fit_gains
from amhe_cli.estimation.payload import MIN_CLIPS as PAYLOAD_MIN_CLIPS, fit_payload
from amhe_cli.estimation.timing import APPLY_ABOVE, mocap_offset
from amhe_cli.errors import AmheError
from amhe_cli.io.reader import read_log
from amhe_cli.model.params import DEFAULT_FREE, ParameterSpace
from amhe_cli.model.scene import Scene, SceneConfig, infer_scene_config, torque_limit
from amhe_cli.io.trajectory import Trajectory


def example_logs() -> list[Path]:
    """The example logs shipped inside the package, sorted by name.

    Installed, they are the package data ``amhe_cli/examples``; in a source
    checkout, the repository's ``examples/logs``.
    """
    roots = [Path(str(resources.files("amhe_cli"))) / "examples",
             Path(__file__).resolve().parents[2] / "examples" / "logs"]
    for root in roots:
        if root.is_dir():
            found = sorted(p for p in root.iterdir() if p.suffix == ".mcap")
            if found:
                return found
    return []


def parse_topics(pairs: tuple[str, ...], map_file: str | None) -> dict[str, str]:
    """Role -> topic from ``--topic ROLE=NAME`` pairs and a ``--map FILE.yaml``.

    The YAML may be ``{role: topic}`` or ``{topics: {role: topic}}``.

    Raises:
        AmheError: malformed pair or map file.
    """
    topics: dict[str, str] = {}
    if map_file:
        path = Path(map_file)
        if not path.is_file():
            raise AmheError(f"topic map {map_file} not found: expected a YAML file of role: topic")
        try:
            data = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as e:
            raise AmheError(f"topic map {map_file} is not valid YAML ({str(e).splitlines()[0]})") from None
        data = data.get("topics", data) if isinstance(data, dict) else None
        if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
            raise AmheError(f"topic map {map_file}: expected a mapping of role: topic, e.g. 'box: /vicon/box'")
        topics.update({str(k): v for k, v in data.items()})
    for pair in pairs:
        role, sep, name = pair.partition("=")
        if not sep or not role or not name:
            raise AmheError(f"--topic {pair!r}: expected ROLE=TOPIC, e.g. --topic box=/vicon/box")
        topics[role.strip()] = name.strip()
    return topics


def parse_box_size(text: str | None) -> tuple[float, float, float] | None:
    """``"0.38"`` (cube) or ``"0.4,0.3,0.38"`` -> edge lengths [m]."""
    if text is None:
        return None
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 3) or any(v <= 0 for v in vals):
        raise AmheError(f"--box-size {text!r}: expected one edge length or x,y,z edge lengths in metres")
    return tuple(vals * 3) if len(vals) == 1 else tuple(vals)


@dataclass
class Problem:
    """A log ready for estimation.

    Attributes:
        traj: the resampled trajectory.
        scene: the model ``f`` with geometry matched to the log.
        space: free parameters and their prior.
        prior_source: where the prior came from ("nominal" or a belief path).
    """

    traj: Trajectory
    scene: Scene
    space: ParameterSpace
    prior_source: str

    @property
    def robot_differs(self) -> tuple[str, ...]:
        """Why the log's robot is not its model (fitted servo gains, a payload), empty if it is: what
        :func:`load_problem` recorded in ``traj.meta["sensors"]["robot_differs"]``, where identify's
        clip plan reads it."""
        return tuple(self.traj.meta.get("sensors", {}).get("robot_differs", ()))


#: Freed beside the box by default where the log's robot is not its model (fitted gains or a payload):
#: a robot that differs in servo or mass may differ in its shell too, and box clips do tell the robot-box
#: friction (mismatch_b, 8 seeds, payload modelled: box mass +6.2 ± 5.2 %, worst 12.3 — +3.5 ± 3.2 %,
#: worst 8.4, in a run whose payload read 0.497 kg — with it free; −9.3 ± 8.4 %, worst −19.0, with it at the
#: model's 0.6 where the truth was 0.8; its noisy twin's worst −25.4 % -> +11.9 %). Where the robot is its
#: model it stays fixed: freed on noisy_b it widened the spread (+2.1 ± 8.1 % against +3.0 ± 6.5 %).
#: (With the clean log's shorter clips, identify.clip_plan, mismatch_b reads +2.6 ± 2.9 %, worst 7.6, with it free.)
ROBOT_DIFFERS_FREE = ("robot_box_friction",)

#: A fitted payload is modelled where it lies this many σ from zero (else the log cannot tell it from
#: none: noisy_b, whose robot is its model, read −0.03 ± 0.03 kg) and is at least this many kg (const_a
#: read 1 g at 4σ: 0.01 % of the robot, nothing a push shows); it is reported as a warning, and counts
#: as a robot unlike its model, from this many kg.
PAYLOAD_SIGMAS, PAYLOAD_MIN_KG, PAYLOAD_WARN_KG = 3.0, 0.05, 0.1


def run_dated_poses(traj: Trajectory) -> float | None:
    """The lateness [s] by which an ``amhe run`` recording already dated its poses, where its run measured it
    (``amhe_run`` metadata ``mocap_latency``, source ``measured``; a recording older than the source key
    counts where the lateness is positive), else None.

    Such poses are not shifted again by :func:`~amhe_cli.estimation.timing.mocap_offset`: on recordings of
    the emulated Go1 (motion capture 3 ms late, measured 3.9–4.4 ms and dated back) the stance feet read a
    further +7 to +13 ms, and shifting by it put the box mass +9–11 % off where the run's dating gave
    −1.3 % and 0.0 % (docs/reference.md#identification).
    """
    run = (traj.meta.get("metadata") or {}).get("amhe_run") or {}
    try:
        late = float(run["mocap_latency"])
    except (KeyError, TypeError, ValueError):
        return None
    source = run.get("mocap_latency_source")
    return late if source == "measured" or (source is None and late > 0) else None


def _servo_from_efforts(traj: Trajectory, config: SceneConfig) -> SceneConfig:
    """The scene with the PD gains that acted, fitted from the log's joint efforts where it has them
    (:mod:`~amhe_cli.estimation.gains`), and ``traj``'s commands shifted in place by the delay the fit found;
    the fit goes into ``traj.meta["sensors"]["gains"]``."""
    fit = fit_gains(traj)
    if fit is None:
        return config
    if fit.at_edge:
        warnings.warn(f"the joint efforts fit the servo law best with the commands acting {MAX_DELAY * 1e3:.0f} ms "
                      "after their stamps, the longest searched: no delay or gains read from them; the commands "
                      "are taken as stamped and the logged gains kept", stacklevel=3)
    steps = int(round(fit.delay / traj.dt))
    if steps:  # the rollouts apply each command when it acted
        traj.ctrl = delayed(traj.ctrl, steps)
        if traj.observed.get("joint_commands") is not None:
            traj.observed["joint_commands"] = delayed(np.asarray(traj.observed["joint_commands"], dtype=bool), steps,
                                                      fill=False)
        warnings.warn(f"the joint commands act {fit.delay * 1e3:.0f} ms after their stamps (the joint efforts say "
                      "so): shifted them that much later", stacklevel=3)
    kp, kd, warns = applied_gains(traj, fit)
    limit, limit_warns = applied_limit(fit, torque_limit(Scene(config).model))
    for text in warns + limit_warns:
        warnings.warn(text, stacklevel=3)
    traj.meta.setdefault("sensors", {})["gains"] = {
        **fit.to_dict(), "logged_kp": None if traj.kp is None else traj.kp.tolist(),
        "logged_kd": None if traj.kd is None else traj.kd.tolist(), "used": "fitted" if warns else "logged",
        "torque_limit_applied": limit is not None}
    if limit is not None:
        config = replace(config, torque_limit=limit)
    if kp is None:
        return config
    return replace(config, kp=tuple(float(x) for x in kp), kd=tuple(float(x) for x in kd))


def _payload_from_rest(traj: Trajectory, config: SceneConfig, nthread: int | None) -> SceneConfig:
    """The scene with the trunk payload fitted where the box rests (:mod:`~amhe_cli.estimation.payload`)
    where the fit tells it from none; the fit goes into ``traj.meta["sensors"]["payload"]``, and a payload
    of :data:`PAYLOAD_WARN_KG` or more warns."""
    try:
        fit = fit_payload(traj, Scene(config), nthread=nthread)
    except AmheError:  # too short for one clip: what needs clips says so itself
        fit = None
    sensors = traj.meta.setdefault("sensors", {})
    if fit is None:
        sensors["payload"] = {"trunk_payload_kg": None, "note": f"fewer than {PAYLOAD_MIN_CLIPS} clips where the "
                              "box rests out of the robot's reach: the robot is taken as its model"}
        return config
    told = abs(fit.value) > max(PAYLOAD_SIGMAS * fit.std, PAYLOAD_MIN_KG)
    sensors["payload"] = {**fit.to_dict(), "applied": told}
    if not told:  # the log cannot tell it from none: the robot is taken as its model
        return config
    if abs(fit.value) >= PAYLOAD_WARN_KG:
        edge = " (at the end of the range tried: it may be more)" if fit.at_edge else ""
        warnings.warn(f"the robot moves as if it carried {fit.value:+.2f} ± {fit.std:.2f} kg on its trunk beyond "
                      f"its model{edge} (fitted on {fit.clips} clips where the box rests): modelled as a trunk "
                      "payload", stacklevel=3)
    return replace(config, trunk_payload=fit.value)


def load_problem(log: str, *, topics: dict[str, str] | None = None, params=None, prior: str | None = None,
                 box_size: tuple | None = None, base_config: SceneConfig | None = None,
                 smooth: int | str = "auto", payload: bool = True, nthread: int | None = None) -> Problem:
    """Read ``log`` and build the scene and parameter space for it.

    Args:
        log: path of an MCAP file, rosbag2 folder or ROS 1 bag.
        topics: explicit role -> topic choices.
        params: free parameter names. None: the box's (:data:`~amhe_cli.model.params.DEFAULT_FREE`), and
            ``robot_box_friction`` beside them where the log's robot is found not to be its model
            (:data:`ROBOT_DIFFERS_FREE`; a warning says so).
        prior: path of a belief YAML whose values and stds become the prior.
        box_size: box edge lengths [m] (None: the scene default, a 0.38 m cube).
        base_config: scene defaults to start from.
        smooth: pose smoothing, ``"auto"``, 0 or a window (see :func:`~amhe_cli.io.reader.read_log`).
        payload: fit the robot's trunk payload where the box rests
            (:mod:`~amhe_cli.estimation.payload`) and model it; False keeps the model's trunk.
        nthread: rollout threads of that fit.

    Raises:
        AmheError: unreadable log, missing roles, inconsistent geometry, bad belief.
    """
    base = base_config or SceneConfig()
    traj = read_log(log, topics=topics or None, dt=base.timestep, smooth=smooth)
    lag = mocap_offset(traj, Scene(base))
    dated = run_dated_poses(traj)
    if lag is not None and dated is not None and abs(lag.offset) > APPLY_ABOVE:
        warnings.warn(f"the recording's poses are dated by the {dated * 1e3:.1f} ms its run measured (IMU attitude "
                      f"against motion capture): not shifted by the stance feet's {lag.offset * 1e3:+.1f} ms",
                      stacklevel=2)
    elif lag is not None and abs(lag.offset) > APPLY_ABOVE:
        warnings.warn(f"the pose streams lag the joint states by {lag.offset * 1e3:+.1f} ms (stance feet slide "
                      f"otherwise): shifted them by {-lag.offset * 1e3:+.1f} ms", stacklevel=2)
        with warnings.catch_warnings():  # its warnings were issued by the first read
            warnings.simplefilter("ignore")
            traj = read_log(log, topics=topics or None, dt=base.timestep, smooth=smooth,
                            time_offset={"base": -lag.offset, "box": -lag.offset})
    if lag is not None:
        traj.meta["sensors"]["time_offset"] = {**lag.to_dict(),
                                               "applied": dated is None and abs(lag.offset) > APPLY_ABOVE,
                                               **({"dated_by_run_s": dated} if dated is not None else {})}
    if len(traj) < 10:
        raise AmheError(f"{log} holds only {len(traj)} samples on the {base.timestep * 1e3:g} ms grid: "
                        "expected at least a second of overlapping joint states, base, box and commands")
    values, stds, source = {}, {}, "nominal"
    if prior:
        belief = Belief.load(prior)
        values, stds, source = belief.values, belief.std, str(prior)
        if belief.scene.get("box_size") and box_size is None:
            box_size = tuple(belief.scene["box_size"])
    config = infer_scene_config(traj, replace(base, box_mass=float(values.get("box_mass", base.box_mass))),
                                box_size=box_size)
    config = _servo_from_efforts(traj, config)
    if payload:
        config = _payload_from_rest(traj, config, nthread)
    differs = tuple(why for why, found in (
        ("servo gains", traj.meta.get("sensors", {}).get("gains", {}).get("used") == "fitted"),
        ("motor torque limits", config.torque_limit is not None),
        ("payload", abs(config.trunk_payload) >= PAYLOAD_WARN_KG)) if found)
    traj.meta.setdefault("sensors", {})["robot_differs"] = list(differs)  # Problem.robot_differs, identify.clip_plan
    if params is None:
        params = DEFAULT_FREE
        if differs:
            params = DEFAULT_FREE + ROBOT_DIFFERS_FREE
            warnings.warn(f"the log's robot is not its model ({', '.join(differs)}): its "
                          f"{', '.join(ROBOT_DIFFERS_FREE)} is freed beside the box (--params to choose)", stacklevel=2)
    scene = Scene(config)
    space = ParameterSpace(scene, free=params, prior=values, prior_std={k: v for k, v in stds.items() if v})
    return Problem(traj, scene, space, source)
