"""Named physical parameters ``p`` and how a value is written into an ``MjModel``.

A :class:`ParameterSpace` is the map between the flat vectors the optimisers see
(CMA-ES in ``identify``/``probe``, the diagonal Gaussian of the MHE) and the
physics: each free parameter has a unit, a prior mean, a prior standard deviation
(``W_p = diag(1/σ²)``, paper eq. 4), bounds, and a writer. Parameters that are
not free stay at their prior.

Coordinates: every parameter is its physical value in the flat vector, except
``box_inertia``, which is the **shape ratio** ``r`` (3,) of the principal
moments to the prior's moments scaled to the current mass,
``I = r ⊙ I_prior · m / m_prior`` (prior mean 1, prior σ 0.3). Inertia then
follows mass unless the data say otherwise; with raw moments, CMA-ES had to
learn the mass–inertia coupling and traded one against the other (measured on
the example logs: inertia +67 %, mass +6 %). Outputs are always moments.

Physical consistency: principal moments of inertia must satisfy the triangle
inequalities (``I_x ≤ I_y + I_z`` and permutations, i.e. non-negative second
moments of mass). :meth:`ParameterSpace.project` maps any candidate onto the
bounds and that set; the cost module charges the distance moved as a penalty, so
CMA-ES is steered back rather than fed a flat plateau.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.model.scene import Scene


@dataclass(frozen=True)
class Parameter:
    """One named physical parameter.

    Attributes:
        name: identifier used on the command line and in beliefs.
        unit: SI unit string.
        size: number of scalars (1, or 3 for principal moments).
        lower, upper: (size,) bounds.
        prior_std: (size,) default prior standard deviation (``W_p = 1/σ²``).
        doc: one-line meaning.
    """

    name: str
    unit: str
    size: int
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    prior_std: tuple[float, ...]
    doc: str


#: Every parameter amhe knows, in canonical order.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("box_mass", "kg", 1, (0.2,), (40.0,), (3.0,), "mass of the box"),
        Parameter("box_inertia", "kg*m^2", 3, (1e-4,) * 3, (3.0,) * 3, (0.1,) * 3,
                  "principal moments of inertia of the box about its centre (box axes)"),
        Parameter("box_friction", "1", 1, (0.01,), (2.0,), (0.5,),
                  "box-floor sliding friction coefficient (all floor regions)"),
        Parameter("robot_box_friction", "1", 1, (0.05,), (2.0,), (0.3,),
                  "robot-box sliding friction coefficient, feet excepted (nuisance; also sets the "
                  "robot body's friction against the floor, which only matters if it falls)"),
        Parameter("robot_kp", "N*m/rad", 1, (5.0,), (300.0,), (8.0,),
                  "joint position gain the robot's servos applied, mean over the 12 joints (nuisance; "
                  "the joints keep their ratios to the scene's gains)"),
        Parameter("robot_kd", "N*m*s/rad", 1, (0.1,), (20.0,), (1.0,),
                  "joint velocity gain the robot's servos applied, mean over the 12 joints (nuisance)"),
        Parameter("trunk_payload", "kg", 1, (-2.0,), (10.0,), (1.0,),
                  "mass carried on the trunk beyond the model's, a point mass at the trunk's centre of "
                  "mass (nuisance: a battery, a sensor)"),
    )
}

#: Parameters whose default prior σ is this fraction of their nominal value (gains differ by robot).
RELATIVE_STD = {"robot_kp": 0.15, "robot_kd": 0.3}

#: The robot-side nuisance parameters: freed next to the box's when the robot differs from its model.
ROBOT_PARAMETERS = ("robot_box_friction", "robot_kp", "robot_kd", "trunk_payload")

DEFAULT_FREE = ("box_mass", "box_inertia", "box_friction")

#: Bounds and prior σ of the inertia shape ratio ``r`` (see module docstring).
INERTIA_RATIO_BOUNDS = (0.2, 5.0)
INERTIA_RATIO_STD = 0.3


def parse_names(text: str | None) -> tuple[str, ...]:
    """Parse ``"box_mass,box_friction"`` into names; ``None`` gives the default set.

    Raises:
        AmheError: an unknown name (the message lists the known ones).
    """
    if text is None:
        return DEFAULT_FREE
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in PARAMETERS]
    if bad or not names:
        raise AmheError(f"unknown parameter {', '.join(bad) or repr(text)}: expected a comma-separated "
                        f"subset of {', '.join(PARAMETERS)}")
    return tuple(n for n in PARAMETERS if n in names)


class ParameterSpace:
    """The free parameters of one estimation problem and their prior.

    Args:
        scene: the scene whose model the values are written into.
        free: names of the free parameters (see :data:`PARAMETERS`).
        prior: name -> prior mean (scalar or (size,) array) overriding the
            scene's nominal values; may also hold fixed values of parameters
            that are not free.
        prior_std: name -> prior standard deviation overriding the defaults.

    Attributes:
        dim: number of free scalars ``d``.
        labels: (d,) flat labels, ``box_inertia_0`` etc. for vectors.
        mean0: (d,) prior mean ``p0``; ``std0``: (d,) prior std; ``lower``, ``upper``: (d,) bounds
            (all in the flat coordinates: inertia as shape ratios).
        scale: (d,) each coordinate's nominal prior std, whatever ``prior_std`` says: the
            step scale of samplers that must keep moving however confident the prior is.

    If ``box_inertia`` is not free it follows the mass: the prior moments are
    scaled by ``mass / prior mass`` (uniform density, same shape), which keeps a
    heavier box physically consistent.
    """

    def __init__(self, scene: Scene, free=DEFAULT_FREE, prior: dict | None = None,
                 prior_std: dict | None = None):
        self.scene = scene
        self.free = tuple(parse_names(",".join(free)) if not isinstance(free, str) else parse_names(free))
        m = scene.model
        # robot geoms other than feet (priority 0, not world, not box): their friction is the
        # robot-box coefficient under MuJoCo's max rule (the box geom's own friction is 0)
        body = m.geom_bodyid
        self._robot_geoms = np.flatnonzero((body != 0) & (body != scene.box_body) & (m.geom_priority == 0))
        self._trunk = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "trunk")
        # the model's own trunk without any payload (the scene's, as built): trunk_payload, where free, is
        # added to it; the payload the model carries now is its nominal value, so writing one is idempotent
        # (a plant that reads its nominal from the written model once added a payload at every write)
        self._trunk_mass = scene.trunk_mass
        self._kp0 = m.actuator_gainprm[:, 0].copy()  # the scene's (logged or fitted) gains
        self._kd0 = -m.actuator_biasprm[:, 2].copy()
        nominal = {
            "box_mass": np.array([m.body_mass[scene.box_body]]),
            "box_inertia": m.body_inertia[scene.box_body].copy(),
            "box_friction": np.array([m.pair_friction[scene.region_pairs[0], 0]]),
            "robot_box_friction": np.array([m.geom_friction[self._robot_geoms[0], 0]]),
            "robot_kp": np.array([self._kp0.mean()]),
            "robot_kd": np.array([self._kd0.mean()]),
            "trunk_payload": np.array([float(m.body_mass[self._trunk]) - scene.trunk_mass]),
        }
        self.prior_values: dict[str, np.ndarray] = {}
        prior = prior or {}
        for name, p in PARAMETERS.items():
            val = np.atleast_1d(np.asarray(prior.get(name, nominal[name]), dtype=float))
            if val.shape != (p.size,):
                raise AmheError(f"prior for {name} has {val.size} values, expected {p.size}")
            self.prior_values[name] = val
        if "box_inertia" not in prior and "box_mass" in prior:
            # a prior mass without a prior inertia: scale the nominal shape to it
            self.prior_values["box_inertia"] = nominal["box_inertia"] * (
                self.prior_values["box_mass"][0] / nominal["box_mass"][0])
        prior_std = prior_std or {}
        self.labels: list[str] = []
        mean0, std0, scale, lo, hi, self._slices = [], [], [], [], [], {}
        for name in self.free:
            p = PARAMETERS[name]
            s = len(mean0)
            self._slices[name] = slice(s, s + p.size)
            if name == "box_inertia":  # shape ratio coordinates
                mean0 += [1.0] * 3
                if name in prior_std:
                    std0 += list(np.broadcast_to(np.asarray(prior_std[name], dtype=float), (3,))
                                 / self.prior_values[name])
                else:
                    std0 += [INERTIA_RATIO_STD] * 3
                scale += [INERTIA_RATIO_STD] * 3
                lo += [INERTIA_RATIO_BOUNDS[0]] * 3
                hi += [INERTIA_RATIO_BOUNDS[1]] * 3
            else:
                mean0 += list(self.prior_values[name])
                default_std = p.prior_std if name not in RELATIVE_STD else \
                    tuple(RELATIVE_STD[name] * abs(v) for v in nominal[name])
                std0 += list(np.broadcast_to(np.asarray(prior_std.get(name, default_std), dtype=float), (p.size,)))
                scale += list(default_std)
                lo += list(p.lower)
                hi += list(p.upper)
            self.labels += [name] if p.size == 1 else [f"{name}_{i}" for i in range(p.size)]
        self.mean0 = np.array(mean0)
        self.std0 = np.array(std0)
        self.scale = np.array(scale)
        self.lower = np.array(lo)
        self.upper = np.array(hi)
        self.dim = len(self.labels)
        self._scratch: dict[int, mujoco.MjData] = {}
        if np.any(self.std0 <= 0):
            raise AmheError("prior standard deviations must be positive")
        self.mean0 = np.clip(self.mean0, self.lower, self.upper)

    # -- conversions --------------------------------------------------------
    def _inertia_base(self, mass: np.ndarray | float) -> np.ndarray:
        """(…, 3) prior moments scaled to ``mass`` (…,) [kg·m²]."""
        m = np.asarray(mass, dtype=float)[..., None]
        return self.prior_values["box_inertia"] * m / self.prior_values["box_mass"][0]

    def _moments(self, P: np.ndarray, mass: np.ndarray) -> np.ndarray:
        """(B, 3) box inertia moments [kg·m²] of (B, d) candidates with box masses (B,) [kg]: the free
        shape ratio (1 where the inertia is not free) times the prior's moments scaled to the mass."""
        ratio = P[:, self._slices["box_inertia"]] if "box_inertia" in self._slices else np.ones((len(P), 3))
        return ratio * self._inertia_base(mass)

    def values(self, vec: np.ndarray) -> dict[str, float | np.ndarray]:
        """All parameters (free from ``vec`` (d,), the rest at the prior) as name -> physical value."""
        vec = np.asarray(vec, dtype=float)
        out = {n: v.copy() for n, v in self.prior_values.items()}
        for name, sl in self._slices.items():
            out[name] = vec[sl].copy()
        out["box_inertia"] = self._moments(vec[None], out["box_mass"][:1])[0]
        return {n: (float(v[0]) if v.size == 1 else v) for n, v in out.items()}

    def physical(self, vec: np.ndarray, std: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """Flat (d,) values and stds in physical units (inertia ratios -> moments [kg·m²]).

        The inertia std is the ratio std times the mass-scaled prior moments
        (the mass's own uncertainty is not propagated into it).
        """
        vec = np.asarray(vec, dtype=float)
        val = vec.copy()
        sd = None if std is None else np.asarray(std, dtype=float).copy()
        if "box_inertia" in self._slices:
            sl = self._slices["box_inertia"]
            mass = self.values(vec)["box_mass"]
            base = self._inertia_base(mass)
            val[sl] = vec[sl] * base
            if sd is not None:
                sd[sl] = sd[sl] * base
        return val, sd

    def free_values(self, vec: np.ndarray) -> dict[str, float | list[float]]:
        """Free parameters of ``vec`` (d,) as name -> float or list (for YAML/JSON)."""
        vals = self.values(vec)
        return {n: (vals[n] if np.isscalar(vals[n]) else [float(x) for x in vals[n]]) for n in self.free}

    def vector(self, values: dict) -> np.ndarray:
        """(d,) vector of the free parameters from name -> physical value (missing: prior)."""
        vec = self.mean0.copy()
        for name, sl in self._slices.items():
            if name in values:
                vec[sl] = np.atleast_1d(np.asarray(values[name], dtype=float))
        if "box_inertia" in self._slices and "box_inertia" in values:
            mass = float(values.get("box_mass", self.prior_values["box_mass"][0]))
            vec[self._slices["box_inertia"]] /= self._inertia_base(mass)
        return vec

    def slices(self) -> dict[str, slice]:
        """name -> slice of the flat vector, for the free parameters."""
        return dict(self._slices)

    # -- feasibility --------------------------------------------------------
    def project(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest feasible candidates.

        Args:
            P: (B, d) candidates.
        Returns:
            (B, d) projected candidates and (B,) squared distance moved, measured
            in prior standard deviations.
        """
        P = np.atleast_2d(np.asarray(P, dtype=float))
        Q = np.clip(P, self.lower, self.upper)
        if "box_inertia" in self._slices:
            sl = self._slices["box_inertia"]
            mass = Q[:, self._slices["box_mass"]][:, 0] if "box_mass" in self._slices else \
                np.full(len(Q), self.prior_values["box_mass"][0])
            base = self._inertia_base(mass)
            inertia = Q[:, sl] * base
            for _ in range(3):  # raise the two smaller moments until I_max <= sum of the others
                order = np.argsort(inertia, axis=1)
                big = np.take_along_axis(inertia, order[:, 2:], axis=1)[:, 0]
                rest = np.take_along_axis(inertia, order[:, :2], axis=1).sum(axis=1)
                short = np.maximum(big - rest, 0.0)
                # split the deficit: lower the largest by a third, raise the others by a third each
                adj = np.zeros_like(inertia)
                np.put_along_axis(adj, order[:, 2:], -short[:, None] / 3, axis=1)
                np.put_along_axis(adj, order[:, :2], np.repeat(short[:, None] / 3, 2, axis=1), axis=1)
                inertia = inertia + adj
            Q[:, sl] = np.clip(inertia / base, self.lower[sl], self.upper[sl])
        moved = (((Q - P) / self.std0) ** 2).sum(axis=1)
        return Q, moved

    # -- writing into models ------------------------------------------------
    #: The ``MjModel`` fields :meth:`model_fields` returns (every field the parameters set directly;
    #: ``mj_setConst`` derives ``body_subtreemass``, ``body_invweight0``, ``dof_invweight0`` and
    #: ``actuator_acc0`` from them).
    MODEL_FIELDS = ("body_mass", "body_inertia", "pair_friction", "geom_friction", "actuator_gainprm",
                    "actuator_biasprm")

    def model_fields(self, P: np.ndarray) -> dict[str, np.ndarray]:
        """The model fields of ``B`` candidates at once, as :meth:`write` sets them (before ``mj_setConst``).

        Args:
            P: (B, d) candidates (flat coordinates of this space).
        Returns:
            field -> (B, *shape of the field) float64 arrays for every name in :data:`MODEL_FIELDS`:
            the scene model's field with the parameters' entries replaced — box mass and inertia
            [kg, kg·m²], box–floor pair friction (sliding, both tangential directions), robot geom
            friction (robot–box, under MuJoCo's max rule), and the servo gains and trunk mass only
            where ``robot_kp``, ``robot_kd``, ``trunk_payload`` are free (else the scene's own, so
            motors replaying torques stay motors). The derived constants are not included:
            :meth:`write_fields` gets them from ``mj_setConst``.
        """
        P = np.atleast_2d(np.asarray(P, dtype=float))
        B, m, b = len(P), self.scene.model, self.scene.box_body

        def value(name: str) -> np.ndarray:  # (B, size) physical values, the prior where not free
            if name in self._slices:
                return P[:, self._slices[name]]
            return np.broadcast_to(self.prior_values[name], (B, PARAMETERS[name].size))

        out = {f: np.repeat(np.asarray(getattr(m, f), dtype=float)[None], B, axis=0) for f in self.MODEL_FIELDS}
        mass = value("box_mass")[:, 0]
        out["body_mass"][:, b] = mass
        out["body_inertia"][:, b] = self._moments(P, mass)
        mu = value("box_friction")
        pairs = np.asarray(self.scene.region_pairs)
        out["pair_friction"][:, pairs, 0] = mu
        out["pair_friction"][:, pairs, 1] = mu
        out["geom_friction"][:, self._robot_geoms, 0] = value("robot_box_friction")
        # the robot's servo and trunk are touched only where they are free: the scene's own
        # actuators (position servos, or motors replaying torques) stay as they were built
        if "robot_kp" in self._slices:
            kp = self._kp0[None] * (value("robot_kp") / self._kp0.mean())
            out["actuator_gainprm"][:, :, 0] = kp
            out["actuator_biasprm"][:, :, 1] = -kp
        if "robot_kd" in self._slices:
            out["actuator_biasprm"][:, :, 2] = -self._kd0[None] * (value("robot_kd") / self._kd0.mean())
        if "trunk_payload" in self._slices:
            out["body_mass"][:, self._trunk] = self._trunk_mass + value("trunk_payload")[:, 0]
        return out

    def write(self, model: mujoco.MjModel, vec: np.ndarray) -> None:
        """Write all parameter values of ``vec`` (d,) into ``model`` in place (:meth:`model_fields`,
        :meth:`write_fields`)."""
        self.write_fields(model, self.model_fields(vec))

    def write_fields(self, model: mujoco.MjModel, fields: dict[str, np.ndarray], b: int = 0) -> None:
        """Row ``b`` of :meth:`model_fields`' ``fields`` into ``model`` in place, then ``mujoco.mj_setConst``.

        Without ``mj_setConst`` ``body_invweight0`` stays stale and the contact solver behaves as if
        the mass were the old one (docs/reference.md#mujoco).
        """
        for f, v in fields.items():
            getattr(model, f)[...] = v[b]
        data = self._scratch.get(id(model))
        if data is None:
            data = self._scratch[id(model)] = mujoco.MjData(model)
        mujoco.mj_setConst(model, data)
