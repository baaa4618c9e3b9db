"""A minimal Foxglove WebSocket client for the live-view tests (subprotocol ``foxglove.sdk.v1``,
the foxglove-sdk server's name for the ``foxglove.websocket.v1`` protocol).

It speaks the protocol from the wire up with the ``websockets`` library (independent of the
foxglove-sdk server under test): reads ``serverInfo`` and ``advertise``, subscribes to chosen
topics, and returns the binary ``messageData`` frames (opcode 1: u32 subscription id, u64 log
time, payload) with each channel's schema, so the test can decode the CDR with rosbags.
"""
from __future__ import annotations

import json
import struct
import time


def collect(url: str, topics: list[str], per_topic: int, timeout: float = 60.0) -> dict:
    """{topic: {"schema_name", "schema", "encoding", "messages": [(log_time_ns, payload), ...]}}
    with ``per_topic`` messages of each topic (fewer if ``timeout`` runs out); also ``_server``
    (the serverInfo) and ``_time`` (the last time broadcast, opcode 2)."""
    from websockets.sync.client import connect

    out: dict = {"_server": None, "_time": None}
    end = time.monotonic() + timeout
    with connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"], open_timeout=timeout) as ws:
        subs: dict[int, str] = {}
        next_id = 1
        while time.monotonic() < end:
            try:
                frame = ws.recv(timeout=max(0.1, end - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    out["_server"] = msg
                elif msg["op"] == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        if ch["topic"] in topics and ch["topic"] not in out:
                            out[ch["topic"]] = {"schema_name": ch["schemaName"], "schema": ch["schema"],
                                                "encoding": ch["encoding"],
                                                "schema_encoding": ch.get("schemaEncoding"), "messages": []}
                            subs[next_id] = ch["topic"]
                            new.append({"id": next_id, "channelId": ch["id"]})
                            next_id += 1
                    if new:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                continue
            op = frame[0]
            if op == 1:
                sid, t = struct.unpack_from("<IQ", frame, 1)
                topic = subs.get(sid)
                if topic is not None and len(out[topic]["messages"]) < per_topic:
                    out[topic]["messages"].append((t, bytes(frame[13:])))
            elif op == 2:
                out["_time"] = struct.unpack_from("<Q", frame, 1)[0]
            if all(t in out and len(out[t]["messages"]) >= per_topic for t in topics):
                break
    return out
