"""Open a recorded log (MCAP, rosbag2, ROS 1 bag): step 1 of :mod:`~amhe_cli.io.reader`.

The log is opened with ``rosbags.highlevel.AnyReader`` (bare ``.mcap``,
rosbag2 folders with sqlite3 or mcap storage, ROS 1 ``.bag``); a truncated
MCAP (no footer/summary) falls back to the ``mcap`` stream reader and keeps
whatever complete records precede the cut. Transform topics (``/tf``) come
out split into one pose topic per frame (:mod:`~amhe_cli.io.tf`). MCAP
metadata records are read alongside, and :func:`_sha256` fingerprints the log
for the trajectory's meta.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from amhe_cli.errors import AmheError
from amhe_cli.io.tf import split_tf

_NOT_A_LOG = "expected an MCAP file, a rosbag2 folder or a ROS 1 .bag"


@dataclass
class _OpenLog:
    """An opened log: its topics, metadata and a message iterator.

    ``iterate(topics, decode)`` yields ``(topic, log_time_ns, message)`` where
    ``message`` is the decoded message object (attribute access by field name)
    or, with ``decode=False``, None.
    """

    path: Path
    format: str
    topics: dict[str, str]
    counts: dict[str, int]
    metadata: dict[str, dict[str, str]]
    warnings: list[str]
    iterate: Callable[[Any, bool], Iterator[tuple[str, int, Any]]]


def _detect_format(path: Path) -> str:
    """Classify ``path`` as 'mcap', 'rosbag2', 'db3' or 'ros1'; AmheError otherwise."""
    if not path.exists():
        raise AmheError(f"log '{path}' does not exist: {_NOT_A_LOG}")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag2"
        raise AmheError(
            f"cannot read '{path}' as a log: the folder has no metadata.yaml, so it is not a "
            f"rosbag2 folder; {_NOT_A_LOG}"
        )
    if path.stat().st_size == 0:
        raise AmheError(f"log '{path}' is empty (0 bytes): {_NOT_A_LOG}")
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"#ROSBAG V2.0"):
        if path.suffix != ".bag":
            raise AmheError(f"cannot read ROS 1 bag '{path}': its name must end in .bag")
        return "ros1"
    if head.startswith(b"SQLite format 3") and path.suffix == ".db3":
        return "db3"
    raise AmheError(f"cannot read '{path}' as a log: {_NOT_A_LOG}")


def _mcap_metadata(files: list[Path]) -> dict[str, dict[str, str]]:
    """MCAP metadata records of complete MCAP files, name -> {key: value}."""
    from mcap.reader import make_reader

    out: dict[str, dict[str, str]] = {}
    for file in files:
        with file.open("rb") as f:
            for record in make_reader(f).iter_metadata():
                out[record.name] = dict(record.metadata)
    return out


@contextmanager
def _open_log(path: str | Path) -> Iterator[_OpenLog]:
    """Open a log of any supported format (see module docstring).

    Raises:
        AmheError: missing path, not a log, unreadable or undecodable log.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if path.name == "metadata.yaml" and path.is_file():
        path = path.parent
    fmt = _detect_format(path)
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as err:  # rosbags raises several unrelated types here
        if fmt == "mcap":
            yield split_tf(_open_mcap_stream(path, reason=_one_line(err).rstrip(".")))
            return
        raise AmheError(f"cannot read '{path}' as a {_FORMAT_NAMES[fmt]}: {_one_line(err)}") from None
    try:
        warns: list[str] = []
        metadata: dict[str, dict[str, str]] = {}
        mcap_files = [path] if fmt == "mcap" else sorted(path.glob("*.mcap")) if fmt == "rosbag2" else []
        if mcap_files:
            try:
                metadata = _mcap_metadata(mcap_files)
            except Exception as err:  # metadata is optional: keep the messages
                warns.append(f"could not read the MCAP metadata records of '{path}': {_one_line(err)}")
        if fmt == "rosbag2":
            storage = "mcap" if mcap_files else "sqlite3"
            fmt = f"rosbag2/{storage}"
        elif fmt == "db3":
            fmt = "rosbag2/sqlite3"
        topics: dict[str, str] = {}
        counts: dict[str, int] = {}
        for conn in reader.connections:
            topics.setdefault(conn.topic, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount

        def iterate(wanted, decode: bool) -> Iterator[tuple[str, int, Any]]:
            conns = [c for c in reader.connections if c.topic in wanted]
            if not conns:
                return
            for conn, timestamp, raw in reader.messages(connections=conns):
                if not decode:
                    yield conn.topic, timestamp, None
                    continue
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as err:
                    raise AmheError(
                        f"cannot decode a {conn.msgtype} message on '{conn.topic}' in '{path}': "
                        f"{_one_line(err)}"
                    ) from None
                yield conn.topic, timestamp, msg

        yield split_tf(_OpenLog(path, fmt, topics, counts, metadata, warns, iterate))
    finally:
        reader.close()


_FORMAT_NAMES = {
    "mcap": "MCAP file",
    "rosbag2": "rosbag2 folder",
    "db3": "rosbag2 sqlite3 file",
    "ros1": "ROS 1 bag",
}


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text or type(err).__name__


def _open_mcap_stream(path: Path, reason: str) -> _OpenLog:
    """Read an MCAP file record by record, keeping everything before a cut.

    Used when the indexed reader fails, typically because the file was cut
    mid-way (a recorder that crashed): there is no footer or summary, but the
    complete chunks before the cut are still valid.

    Raises:
        AmheError: the file does not even hold a readable header and channel.
    """
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap_ros2.decoder import DecoderFactory

    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: dict[str, dict[str, str]] = {}
    messages: dict[int, list[tuple[int, bytes]]] = {}
    broke: str | None = None
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Message):
                    messages.setdefault(record.channel_id, []).append((record.log_time, record.data))
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
        except Exception as err:  # EndOfFile, a torn record, a bad chunk...
            broke = _one_line(err)
    n_msgs = sum(len(v) for v in messages.values())
    if not channels:
        raise AmheError(f"cannot read '{path}' as an MCAP file: {reason}; no channel could be recovered")
    warns: list[str] = []
    if broke is not None:
        times = [t for v in messages.values() for t, _ in v]
        span = (max(times) - min(times)) * 1e-9 if times else 0.0
        warns.append(
            f"'{path.name}' is truncated or damaged ({reason}); read the {n_msgs} complete "
            f"messages before the cut, spanning {span:.3f} s; the rest of the log is lost"
        )
    topics = {c.topic: schemas[c.schema_id].name if c.schema_id in schemas else "" for c in channels.values()}
    counts = {c.topic: 0 for c in channels.values()}
    for cid, lst in messages.items():
        if cid in channels:
            counts[channels[cid].topic] += len(lst)
    factory = DecoderFactory()

    def iterate(wanted, decode: bool) -> Iterator[tuple[str, int, Any]]:
        for cid, lst in messages.items():
            chan = channels.get(cid)
            if chan is None or chan.topic not in wanted:
                continue
            decoder = None
            if decode:
                try:
                    decoder = factory.decoder_for(chan.message_encoding, schemas.get(chan.schema_id))
                except Exception as err:
                    decoder, why = None, _one_line(err)
                else:
                    why = f"message encoding {chan.message_encoding!r} is not ROS 2 CDR"
                if decoder is None:
                    raise AmheError(f"cannot decode messages on '{chan.topic}' in '{path}': {why}")
            for log_time, data in lst:
                yield chan.topic, log_time, (decoder(data) if decoder else None)

    return _OpenLog(path, "mcap", topics, counts, metadata, warns, iterate)


def _sha256(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (relative name and content, sorted by name)."""
    digest = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for file in files:
        if path.is_dir():
            digest.update(str(file.relative_to(path)).encode() + b"\0")
        with file.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()
