"""A Foxglove WebSocket client written from the protocol's specification
(``foxglove.websocket.v1``, github.com/foxglove/ws-protocol docs/spec.md) on the
plain ``websockets`` library: no code shared with the server under test."""

from __future__ import annotations

import asyncio
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import websockets
from websockets.typing import Subprotocol

SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
"""The spec's subprotocol, and the name foxglove-sdk servers (0.30) select for the same messages."""


@dataclass
class Session:
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    """channel id -> its advertisement (topic, encoding, schemaName, schema, schemaEncoding)."""
    messages: list[tuple[str, int, Any]] = field(default_factory=list)
    """(topic, timestamp ns, decoded JSON payload), in arrival order."""
    times: list[int] = field(default_factory=list)
    statuses: list[dict[str, Any]] = field(default_factory=list)


async def watch(url: str, topics: set[str] | None, seconds: float, *, connect_timeout_s: float = 60.0, until_topic_count: int | None = None) -> Session:
    """Connect (retrying until the server is up), subscribe to ``topics`` (every advertised one
    when None) as soon as their advertisement is read (no wait, no retry), and collect for ``seconds`` of wall time or until the connection closes."""
    deadline = time.monotonic() + connect_timeout_s
    while True:
        try:
            ws = await websockets.connect(url, subprotocols=[Subprotocol(p) for p in SUBPROTOCOLS], max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    assert ws.subprotocol in SUBPROTOCOLS
    s = Session()
    subscriptions: dict[int, str] = {}
    end = time.monotonic() + seconds
    async with ws:
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic()))
            except (TimeoutError, websockets.ConnectionClosed):
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                op = msg["op"]
                if op == "serverInfo":
                    s.server_info = msg
                elif op == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        s.channels[ch["id"]] = ch
                        if topics is None or ch["topic"] in topics:
                            new.append(ch)
                    if new:
                        first = max(subscriptions, default=-1) + 1
                        subs = [{"id": first + i, "channelId": ch["id"]} for i, ch in enumerate(new)]
                        for sub, ch in zip(subs, new):
                            subscriptions[sub["id"]] = ch["topic"]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif op == "status":
                    s.statuses.append(msg)
            else:
                opcode = frame[0]
                if opcode == 0x01:
                    sub_id, ts = struct.unpack_from("<IQ", frame, 1)
                    s.messages.append((subscriptions[sub_id], ts, json.loads(frame[13:])))
                elif opcode == 0x02:
                    s.times.append(struct.unpack_from("<Q", frame, 1)[0])
            if until_topic_count is not None and len({m[0] for m in s.messages}) >= until_topic_count:
                break
    return s
