"""Poses recorded on ``/tf``: each child frame of a ``tf2_msgs/TFMessage`` topic as a topic of its own.

Motion-capture bridges and robot state publishers often record poses only as
transforms on ``/tf`` (``tf2_msgs/msg/TFMessage``, ROS 1 ``tf/tfMessage``),
many frames to one topic. :func:`split_tf` gives each child frame its own
virtual topic, ``<topic>#<child_frame_id>`` (e.g. ``/tf#box``,
``/tf#base_link``), of type ``geometry_msgs/msg/TransformStamped``, so the
roles are assigned, named (``--topic box=/tf#box``) and read like any other
pose topic: the transform's translation and rotation are the pose, in its
parent frame (chains of frames are not composed, as for every other pose
type). ``/tf_static`` is left out: a static frame is not a moving body.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Iterator

#: Message types of transform topics (ROS 2 and ROS 1 names, with and without ``/msg/``).
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage", "tf/msg/tfMessage", "tf/tfMessage")
#: Separator between a transform topic and a child frame in a virtual topic's name.
SEP = "#"
TRANSFORM_TYPE = "geometry_msgs/msg/TransformStamped"


def split_tf(log):
    """``log`` (an opened log, :func:`~amhe_cli.io.logfile._open_log`) with its transform topics split by frame.

    Each non-static transform topic is read once (decoded) and replaced in
    ``topics``, ``counts`` and ``iterate`` by one virtual topic per child frame,
    ``<topic>#<frame>`` (leading ``/`` of frame names dropped), whose messages
    are that frame's ``TransformStamped`` entries with their log times. A log
    without transform topics is returned as it is.

    Returns:
        an opened log of the same kind; a warning is added for a frame that
        has more than one parent frame.
    """
    tf_topics = {t for t, ty in log.topics.items() if ty in TF_TYPES and not t.rstrip("/").endswith("tf_static")}
    if not tf_topics:
        return log
    frames: dict[str, list[tuple[int, Any]]] = {}
    parents: dict[str, set[str]] = {}
    for topic, log_ns, msg in log.iterate(tf_topics, True):
        for transform in msg.transforms:
            name = f"{topic}{SEP}{transform.child_frame_id.lstrip('/')}"
            frames.setdefault(name, []).append((log_ns, transform))
            parents.setdefault(name, set()).add(transform.header.frame_id.lstrip("/"))
    warnings = list(log.warnings)
    for name, found in sorted(parents.items()):
        if len(found) > 1:
            warnings.append(f"frame '{name}' has several parent frames ({', '.join(sorted(found))}): each pose is "
                            "read in its own message's parent frame")
    topics = {t: ty for t, ty in log.topics.items() if t not in tf_topics}
    counts = {t: n for t, n in log.counts.items() if t not in tf_topics}
    for name, entries in frames.items():
        topics[name] = TRANSFORM_TYPE
        counts[name] = len(entries)
    inner = log.iterate

    def iterate(wanted, decode: bool) -> Iterator[tuple[str, int, Any]]:
        wanted = set(wanted)
        yield from inner(wanted - frames.keys(), decode)
        for name in sorted(wanted & frames.keys()):
            for log_ns, transform in frames[name]:
                yield name, log_ns, transform if decode else None

    return replace(log, topics=topics, counts=counts, warnings=warnings, iterate=iterate)
