"""Assign roles to the topics of a log: step 2 of :mod:`~amhe_cli.io.reader`.

Roles (``joint_states``, ``base``, ``box``, ``joint_commands``, optional
``gains``) go to topics by message type, topic-name hints or the caller's
explicit choice.
"""

from __future__ import annotations

import itertools
import re

from amhe_cli.errors import AmheError

#: Roles a log must provide for identification, in the order they are checked.
REQUIRED_ROLES: tuple[str, ...] = ("joint_states", "base", "box", "joint_commands")
#: Optional role: PD gains of the joint position controller.
GAINS_ROLE = "gains"

_ROLE_WHAT = {
    "joint_states": "joint states",
    "base": "robot base pose",
    "box": "box pose",
    "joint_commands": "joint commands",
    "gains": "joint PD gains",
}

_POSE_TYPES = (
    "geometry_msgs/PoseStamped",
    "nav_msgs/Odometry",
    "geometry_msgs/PoseWithCovarianceStamped",
    "geometry_msgs/TransformStamped",
)
_LOWSTATE_TYPES = ("unitree_legged_msgs/LowState", "unitree_go/LowState")
_LOWCMD_TYPES = ("unitree_legged_msgs/LowCmd", "unitree_go/LowCmd")
#: Message types (``pkg/Type``, without ``/msg/``) accepted for each role.
ROLE_TYPES: dict[str, tuple[str, ...]] = {
    "joint_states": ("sensor_msgs/JointState", *_LOWSTATE_TYPES),
    "base": _POSE_TYPES,
    "box": _POSE_TYPES,
    "joint_commands": ("sensor_msgs/JointState", *_LOWCMD_TYPES),
    "gains": ("std_msgs/Float64MultiArray", *_LOWCMD_TYPES),
}

#: Topic-name hints: substrings that make a topic more (+1 each) or less (-1
#: each) likely to play a role when several topics share a message type.
_HINTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "joint_states": (
        ("state", "joint", "feedback", "measured"),
        ("command", "cmd", "target", "desired", "setpoint", "goal"),
    ),
    "joint_commands": (
        ("command", "cmd", "target", "desired", "setpoint", "goal"),
        ("state", "feedback", "measured"),
    ),
    "base": (
        ("odom", "base", "body", "trunk", "robot", "go1", "torso", "state_estimat"),
        ("box", "object", "payload", "crate", "cube"),
    ),
    "box": (
        ("box", "object", "payload", "crate", "cube", "mocap", "vicon", "optitrack"),
        ("odom", "base", "body", "trunk", "robot", "go1", "torso"),
    ),
    "gains": (("gain", "kp"), ()),
}
#: Small type preferences that break ties between otherwise equal topics.
_TYPE_PRIOR = {
    ("base", "nav_msgs/Odometry"): 0.5,
    ("box", "geometry_msgs/PoseStamped"): 0.25,
    ("box", "geometry_msgs/TransformStamped"): 0.25,
    ("joint_states", "unitree_legged_msgs/LowState"): 0.5,
    ("joint_states", "unitree_go/LowState"): 0.5,
}


def _short_type(msgtype: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs/JointState``."""
    return msgtype.replace("/msg/", "/")


def _topics_present(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} [{ty}]" for t, ty in sorted(topics.items())) or "none"


def _hint_score(role: str, topic: str, msgtype: str) -> float:
    # Motion-capture drivers name their streams "rigid_body_N": not a robot body.
    name = re.sub(r"rigid_?body", "", topic.lower())
    pos, neg = _HINTS[role]
    score = sum(1.0 for h in pos if h in name) - sum(1.0 for h in neg if h in name)
    return score + _TYPE_PRIOR.get((role, _short_type(msgtype)), 0.0)


def _expected_types(role: str) -> str:
    types = list(ROLE_TYPES[role])
    return ", ".join(types[:-1]) + " or " + types[-1] if len(types) > 1 else types[0]


def assign_roles(
    topics: dict[str, str], explicit: dict[str, str] | None = None
) -> tuple[dict[str, str], dict[str, str]]:
    """Decide which topic plays which role.

    Explicit choices win. Otherwise a topic is a candidate for a role if its
    message type fits the role and its name does not point elsewhere (hints such
    as ``box``/``object``/``mocap`` for the box, ``odom``/``base``/``trunk`` for the
    base, ``cmd``/``command`` vs ``state`` for joints); each role gets a distinct
    topic and the assignment with the best total hint score wins. A role whose
    best topic is not unique is reported as ambiguous.

    Args:
        topics: topic -> message type (e.g. ``sensor_msgs/msg/JointState``).
        explicit: role -> topic chosen by the user (``--topic box=/vicon/box``).

    Returns:
        ``(roles, problems)``: role -> topic for every role that could be
        assigned, and role -> one-line explanation for every required role that
        could not (missing or ambiguous). ``gains`` is optional and only appears
        in ``roles``.

    Raises:
        AmheError: an explicit choice names an unknown role, a topic that is not
            in the log, or a topic whose type cannot play that role.
    """
    explicit = dict(explicit or {})
    roles: dict[str, str] = {}
    problems: dict[str, str] = {}
    present = _topics_present(topics)
    for role, topic in explicit.items():
        if role not in ROLE_TYPES:
            raise AmheError(
                f"unknown role '{role}' in topic choice: expected one of {', '.join(ROLE_TYPES)}"
            )
        if topic not in topics:
            raise AmheError(f"topic '{topic}' chosen for role '{role}' is not in the log; topics present: {present}")
        if _short_type(topics[topic]) not in ROLE_TYPES[role]:
            raise AmheError(
                f"topic '{topic}' chosen for role '{role}' has type {topics[topic]}; expected "
                f"{_expected_types(role)}"
            )
        roles[role] = topic

    taken = set(roles.values())
    for group in (("joint_states", "joint_commands"), ("base", "box")):
        free = [r for r in group if r not in roles]
        cands = {
            r: [
                (t, _hint_score(r, t, ty))
                for t, ty in sorted(topics.items())
                if t not in taken and _short_type(ty) in ROLE_TYPES[r] and _hint_score(r, t, ty) >= 0
            ]
            for r in free
        }
        best: list[tuple[tuple[int, float], tuple]] = []
        for combo in itertools.product(*[c + [(None, 0.0)] for c in cands.values()]):
            chosen = [t for t, _ in combo if t is not None]
            if len(chosen) != len(set(chosen)):
                continue
            key = (len(chosen), sum(s for _, s in combo))
            if not best or key > best[0][0]:
                best = [(key, combo)]
            elif key == best[0][0]:
                best.append((key, combo))
        for k, role in enumerate(free):
            options = sorted({combo[k][0] for _, combo in best} - {None}) if best else []
            if len(options) == 1 and all(combo[k][0] is not None for _, combo in best):
                roles[role] = options[0]
            elif len(options) > 1:
                listed = ", ".join(f"{t} [{topics[t]}]" for t in options)
                problems[role] = (
                    f"log has several candidates for role '{role}' ({_ROLE_WHAT[role]}): {listed}; "
                    f"choose one with --topic {role}=NAME"
                )
            else:
                problems[role] = (
                    f"log has no {_ROLE_WHAT[role]}: expected a {_expected_types(role)} topic for "
                    f"role '{role}' (use --topic {role}=NAME); topics present: {present}"
                )

    if GAINS_ROLE not in roles:
        if _short_type(topics.get(roles.get("joint_commands", ""), "")) in _LOWCMD_TYPES:
            roles[GAINS_ROLE] = roles["joint_commands"]
        else:
            cands = [
                t for t, ty in topics.items()
                if _short_type(ty) == "std_msgs/Float64MultiArray" and _hint_score(GAINS_ROLE, t, ty) > 0
            ]
            if len(cands) == 1:
                roles[GAINS_ROLE] = cands[0]
    return roles, problems
