"""Beliefs: an estimate with its uncertainty and provenance, as YAML.

``identify`` and ``probe`` write one; ``mhe-replay`` and ``run`` start from one
(``--prior``/``--belief``). The file is plain YAML, readable by people::

    amhe_belief: 1
    parameters:
      box_mass: {value: 5.02, std: 0.07, unit: kg}
      box_inertia: {value: [0.12, 0.12, 0.12], std: [...], unit: kg*m^2}
    free: [box_mass, box_inertia, box_friction]
    correlation: {labels: [...], matrix: [[...]]}
    cost: {prior: ..., estimate: ...}
    scene: {...}          # geometry the estimate refers to
    provenance: {command: identify, log: ..., sha256: ..., settings: {...}}
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from amhe_cli.errors import AmheError
from amhe_cli.io.plain import to_plain
from amhe_cli.model.params import PARAMETERS

FORMAT_VERSION = 1


@dataclass
class Belief:
    """Mean, standard deviation and correlation of parameters, with provenance.

    Attributes:
        values: name -> float or (size,) list, every parameter the belief fixes.
        std: name -> float or list, for the estimated ones.
        free: names that were estimated (the rest are fixed values).
        labels: flat labels of the correlation matrix.
        correlation: (d, d) correlation of the free parameters' flat vector.
        cost: e.g. ``{"prior": J(p0), "estimate": J(p̂)}`` and residual per step.
        scene: scene configuration the values refer to (SceneConfig.to_dict()).
        provenance: command, log path and digest, settings, time.
    """

    values: dict
    std: dict = field(default_factory=dict)
    free: list = field(default_factory=list)
    labels: list = field(default_factory=list)
    correlation: list = field(default_factory=list)
    cost: dict = field(default_factory=dict)
    scene: dict = field(default_factory=dict)
    provenance: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        params = {}
        for name, val in self.values.items():
            entry = {"value": to_plain(val), "unit": PARAMETERS[name].unit if name in PARAMETERS else ""}
            if name in self.std:
                entry["std"] = to_plain(self.std[name])
            params[name] = entry
        return {
            "amhe_belief": FORMAT_VERSION,
            "parameters": params,
            "free": list(self.free),
            "correlation": {"labels": list(self.labels), "matrix": to_plain(self.correlation)},
            "cost": {k: to_plain(v) for k, v in self.cost.items()},
            "scene": to_plain(self.scene),
            "provenance": to_plain(self.provenance),
        }

    def save(self, path: str | os.PathLike, force: bool = False) -> Path:
        """Write YAML to ``path``.

        Raises:
            AmheError: the file exists and ``force`` is False.
        """
        path = Path(path)
        if path.exists() and not force:
            raise AmheError(f"{path} already exists: pass --force to overwrite it, or choose another --out")
        path.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False, width=120))
        return path

    @classmethod
    def nominal(cls, space, provenance: dict | None = None) -> "Belief":
        """The prior of ``space`` as a belief: its nominal values and default prior stds, nothing identified.

        What a run on a real robot starts from when no ``--belief`` is given
        (a sim probe knows nothing about a real box).
        """
        values = to_plain(space.values(space.mean0))
        from amhe_cli.model.params import PARAMETERS as P
        std = {n: (P[n].prior_std[0] if P[n].size == 1 else list(P[n].prior_std)) for n in space.free}
        return cls(values=values, std=to_plain(std), free=[], scene=space.scene.config.to_dict(),
                   provenance=dict(provenance or {"source": "nominal prior"}))

    @classmethod
    def from_identify(cls, result, space, scene_config, provenance: dict) -> "Belief":
        """The belief an identification leaves: estimate, std, correlation and cost of ``result``.

        Args:
            result: an :class:`~amhe_cli.estimation.identify.IdentifyResult` over ``space``
                (a :class:`~amhe_cli.model.params.ParameterSpace`).
            scene_config: the :class:`~amhe_cli.model.scene.SceneConfig` the values refer to.
            provenance: where the estimate came from (command, log, settings …).
        """
        s = result.summary()
        return cls(values=to_plain(space.values(result.estimate)), std=s["std"], free=list(space.free),
                   labels=s["labels"], correlation=s["correlation"], cost=s["cost"],
                   scene=scene_config.to_dict(), provenance=provenance)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Belief":
        """Read a belief YAML.

        Raises:
            AmheError: missing file, not YAML, or not an amhe belief.
        """
        path = Path(path)
        if not path.is_file():
            raise AmheError(f"belief file {path} not found: expected a YAML written by 'amhe identify' or 'amhe probe'")
        try:
            d = yaml.safe_load(path.read_text())
        except yaml.YAMLError as e:
            raise AmheError(f"{path} is not valid YAML ({str(e).splitlines()[0]})") from None
        if not isinstance(d, dict) or "parameters" not in d or not isinstance(d["parameters"], dict):
            raise AmheError(f"{path} is not an amhe belief: expected a 'parameters' mapping")
        values, std = {}, {}
        for name, entry in d["parameters"].items():
            if name not in PARAMETERS:
                raise AmheError(f"{path}: unknown parameter {name!r}: expected one of {', '.join(PARAMETERS)}")
            if not isinstance(entry, dict) or "value" not in entry:
                raise AmheError(f"{path}: parameter {name!r} needs a 'value'")
            values[name] = entry["value"]
            if "std" in entry:
                std[name] = entry["std"]
        corr = d.get("correlation") or {}
        return cls(values=values, std=std, free=list(d.get("free", [])), labels=list(corr.get("labels", [])),
                   correlation=corr.get("matrix", []), cost=d.get("cost", {}), scene=d.get("scene", {}),
                   provenance=d.get("provenance", {}))
