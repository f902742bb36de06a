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

import yaml

from amhe_cli.estimation.belief import Belief
from amhe_cli.estimation.gains import applied_gains, fit_gains
from amhe_cli.estimation.timing import APPLY_ABOVE, mocap_offset
from amhe_cli.errors import AmheError
from amhe_cli.io.reader import read_log
from amhe_cli.model.params import DEFAULT_FREE, ParameterSpace
from amhe_cli.model.scene import Scene, SceneConfig, infer_scene_config
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


def _servo_from_efforts(traj: Trajectory, config: SceneConfig) -> SceneConfig:
    """The scene with the PD gains that acted, fitted from the log's joint efforts where it has them
    (:mod:`~amhe_cli.estimation.gains`); the fit goes into ``traj.meta["sensors"]["gains"]``."""
    fit = fit_gains(traj)
    if fit is None:
        return config
    kp, kd, warns = applied_gains(traj, fit)
    for text in warns:
        warnings.warn(text, stacklevel=3)
    traj.meta.setdefault("sensors", {})["gains"] = {
        **fit.to_dict(), "logged_kp": None if traj.kp is None else traj.kp.tolist(),
        "logged_kd": None if traj.kd is None else traj.kd.tolist(), "used": "fitted" if warns else "logged"}
    if kp is None:
        return config
    return replace(config, kp=tuple(float(x) for x in kp), kd=tuple(float(x) for x in kd))


def load_problem(log: str, *, topics: dict[str, str] | None = None, params=None, prior: str | None = None,
                 box_size: tuple | None = None, base_config: SceneConfig | None = None,
                 smooth: int | str = "auto") -> Problem:
    """Read ``log`` and build the scene and parameter space for it.

    Args:
        log: path of an MCAP file, rosbag2 folder or ROS 1 bag.
        topics: explicit role -> topic choices.
        params: free parameter names (None: the default set).
        prior: path of a belief YAML whose values and stds become the prior.
        box_size: box edge lengths [m] (None: the scene default, a 0.38 m cube).
        base_config: scene defaults to start from.
        smooth: pose smoothing, ``"auto"``, 0 or a window (see :func:`~amhe_cli.io.reader.read_log`).

    Raises:
        AmheError: unreadable log, missing roles, inconsistent geometry, bad belief.
    """
    base = base_config or SceneConfig()
    traj = read_log(log, topics=topics or None, dt=base.timestep, smooth=smooth)
    lag = mocap_offset(traj, Scene(base))
    if lag is not None and abs(lag.offset) > APPLY_ABOVE:
        warnings.warn(f"the pose streams lag the joint states by {lag.offset * 1e3:+.1f} ms (stance feet slide "
                      f"otherwise): shifted them by {-lag.offset * 1e3:+.1f} ms", stacklevel=2)
        with warnings.catch_warnings():  # its warnings were issued by the first read
            warnings.simplefilter("ignore")
            traj = read_log(log, topics=topics or None, dt=base.timestep, smooth=smooth,
                            time_offset={"base": -lag.offset, "box": -lag.offset})
    if lag is not None:
        traj.meta["sensors"]["time_offset"] = {**lag.to_dict(), "applied": abs(lag.offset) > APPLY_ABOVE}
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
    scene = Scene(config)
    space = ParameterSpace(scene, free=params if params is not None else DEFAULT_FREE,
                           prior=values, prior_std={k: v for k, v in stds.items() if v})
    return Problem(traj, scene, space, source)
