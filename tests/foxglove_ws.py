"""A Foxglove WebSocket viewer for the tests: connects as the Foxglove app does, subscribes to every
channel the server advertises and decodes what arrives (ros2msg schemas, CDR messages).

Protocol (Foxglove WebSocket, subprotocol ``foxglove.sdk.v1`` / ``foxglove.websocket.v1``): the server
sends ``serverInfo`` and ``advertise`` as JSON text; the client answers ``subscribe`` with one
subscription per channel; each message then arrives as binary: opcode 0x01, subscription id (u32 LE),
log time (u64 LE, ns), payload.
"""

from __future__ import annotations

import asyncio
import json
import struct
import time


def decoder_for(channel: dict):
    """A CDR decoder for an advertised channel (its ``schemaName`` and ros2msg ``schema`` text)."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    assert channel["encoding"] == "cdr" and channel.get("schemaEncoding") == "ros2msg", channel
    schema = Schema(id=1, name=channel["schemaName"], encoding="ros2msg", data=channel["schema"].encode())
    return DecoderFactory().decoder_for("cdr", schema)


async def _watch(url: str, until, timeout: float, connect_timeout: float) -> tuple[dict, list]:
    import websockets
    end = time.monotonic() + connect_timeout
    while True:
        try:
            ws = await websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                          max_size=None)
            break
        except OSError:
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.05)
    channels: dict[int, dict] = {}
    decoders: dict[int, object] = {}
    got: list = []
    stop = time.monotonic() + timeout
    async with ws:
        assert ws.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1"), ws.subprotocol
        while time.monotonic() < stop and not until(got):
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.2)
            except asyncio.TimeoutError:
                continue
            except Exception:  # the server went away: what arrived is the answer  # noqa: BLE001
                break
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    new = {c["id"]: c for c in op["channels"]}
                    channels.update(new)
                    for cid, c in new.items():
                        decoders[cid] = decoder_for(c)
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": cid, "channelId": cid} for cid in new]}))
                continue
            if frame[0] == 0x01:
                sub, log_time = struct.unpack_from("<IQ", frame, 1)
                got.append((channels[sub]["topic"], log_time, decoders[sub](frame[13:])))
    return {c["topic"]: c for c in channels.values()}, got


def watch(url: str, until=lambda got: False, timeout: float = 60.0, connect_timeout: float = 30.0):
    """Connect to ``url``, subscribe to everything, collect messages until ``until(got)`` is true, the
    server closes, or ``timeout`` [s] passes.

    Returns:
        (topic -> advertised channel dict, [(topic, log time [ns], decoded message)]).
    """
    return asyncio.run(_watch(url, until, timeout, connect_timeout))
