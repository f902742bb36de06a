"""Match the joint names of a log to :data:`~amhe_cli.io.trajectory.GO1_JOINTS`.

Names used by other stacks (prefixes, lower case, ANYmal-style ``RF_HAA``)
are mapped through leg and part aliases; used by step 3 of
:mod:`~amhe_cli.io.reader` to put joints in Go1 order.
"""

from __future__ import annotations

import re

import numpy as np

from amhe_cli.errors import AmheError
from amhe_cli.io.trajectory import GO1_JOINTS

_LEG_ALIASES = {"fr": "FR", "rf": "FR", "fl": "FL", "lf": "FL", "rr": "RR", "rh": "RR", "rl": "RL", "lh": "RL"}
_PART_ALIASES = {
    "hip": "hip", "haa": "hip", "abad": "hip", "abduction": "hip",
    "thigh": "thigh", "hfe": "thigh", "upper": "thigh",
    "calf": "calf", "kfe": "calf", "knee": "calf", "shank": "calf", "lower": "calf",
}
#: Legs spelled out (``front_right_hip``): (fore/hind word, side word) -> leg.
_SPELLED_LEGS = {("front", "right"): "FR", ("front", "left"): "FL", ("rear", "right"): "RR", ("rear", "left"): "RL"}
_FORE_HIND = {"front": "front", "fore": "front", "rear": "rear", "hind": "rear", "back": "rear"}
#: unitree_legged_sdk's motor names ``FR_0``, ``FR_1``, ``FR_2``: hip, thigh, calf.
_SDK_PARTS = {"0": "hip", "1": "thigh", "2": "calf"}


def canonical_joint_name(name: str) -> str | None:
    """Go1 joint name (:data:`GO1_JOINTS`) for a joint name used by some stack.

    Case-insensitive; accepts ``FR_hip_joint``, ``FR_hip``, ``fr_hip_joint``,
    prefixes such as ``go1/FR_hip_joint``, ANYmal-style ``RF_HAA``/``LH_KFE``
    (LF=FL, RF=FR, LH=RL, RH=RR; HAA=hip, HFE=thigh, KFE=calf), legs spelled
    out (``front_right_hip``, ``hind_left_knee``) and unitree_legged_sdk's
    motor names ``FR_0``/``FR_1``/``FR_2`` (hip, thigh, calf).

    Returns:
        The canonical name, or None when the name is not recognised.
    """
    tokens = [t for t in re.split(r"[^a-z0-9]+", name.lower()) if t and t != "joint"]
    legs = {_LEG_ALIASES[t] for t in tokens if t in _LEG_ALIASES}
    if not legs:
        fore = {_FORE_HIND[t] for t in tokens if t in _FORE_HIND}
        side = {t for t in tokens if t in ("left", "right")}
        if len(fore) == 1 and len(side) == 1:
            legs = {_SPELLED_LEGS[(fore.pop(), side.pop())]}
    parts = {_PART_ALIASES[t] for t in tokens if t in _PART_ALIASES}
    if not parts and len(legs) == 1:
        parts = {_SDK_PARTS[t] for t in tokens if t in _SDK_PARTS}
    if len(legs) != 1 or len(parts) != 1:
        return None
    return f"{legs.pop()}_{parts.pop()}_joint"


def match_joints(names: list[str] | tuple[str, ...], joint_names_map: dict[str, str] | None = None,
                 *, topic: str = "") -> np.ndarray:
    """Indices that put a message's joints into :data:`GO1_JOINTS` order.

    Args:
        names: joint names of one message, any order (extra joints are ignored).
        joint_names_map: optional explicit map, log name -> Go1 joint name
            (canonical or any alias :func:`canonical_joint_name` accepts); it is
            applied before automatic matching.
        topic: topic name used in error messages.

    Returns:
        (12,) int array ``idx`` with ``values[idx]`` in canonical order.

    Raises:
        AmheError: a Go1 joint is missing, two log joints map to the same Go1
            joint, or ``joint_names_map`` names an unknown Go1 joint.
    """
    where = f" on '{topic}'" if topic else ""
    explicit = {}
    for log_name, target in (joint_names_map or {}).items():
        canon = target if target in GO1_JOINTS else canonical_joint_name(target)
        if canon is None:
            raise AmheError(
                f"joint map entry '{log_name}: {target}' names no Go1 joint: expected one of {', '.join(GO1_JOINTS)}"
            )
        explicit[log_name] = canon
    found: dict[str, int] = {}
    for i, name in enumerate(names):
        canon = explicit.get(name) or canonical_joint_name(name)
        if canon is None:
            continue
        if canon in found:
            raise AmheError(
                f"joints '{names[found[canon]]}' and '{name}'{where} both match Go1 joint {canon}; "
                f"give a joint map to choose"
            )
        found[canon] = i
    missing = [j for j in GO1_JOINTS if j not in found]
    if missing:
        raise AmheError(
            f"joint names{where} lack Go1 joints {', '.join(missing)}; names in the log: "
            f"{', '.join(names) or '(none)'} (give a joint map, log name -> Go1 name)"
        )
    return np.array([found[j] for j in GO1_JOINTS], dtype=int)
