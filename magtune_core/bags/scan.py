"""Sequential scan of an MCAP file without its index: what survives of a damaged or unfinished bag.

A recorder killed with SIGKILL leaves a file with the header, every completed chunk (each
followed by its message indexes) and no summary/footer; the last record may be cut short. A
corrupted file may hold chunks whose CRC or compression is broken. :func:`scan` walks the
records sequentially (no index needed), keeps schemas, channels and the messages of every
complete chunk whose CRC and decompression check out, and reports the rest: chunks rejected,
where the readable data ends and how many bytes follow it.
"""
from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Message, Schema
from mcap.stream_reader import breakup_chunk

from .layout import BagMessage, TopicInfo, resolve_mcap

MAGIC = b"\x89MCAP0\r\n"
MAX_RECORD = 1 << 31  # larger length fields are treated as corruption


@dataclass
class ScanResult:
    """What a sequential scan of an MCAP file could read."""

    path: Path
    schemas: dict = field(default_factory=dict)      # id -> mcap Schema
    channels: dict = field(default_factory=dict)     # id -> mcap Channel
    messages: list = field(default_factory=list)     # BagMessage, file order
    chunks_ok: int = 0
    chunks_bad: list = field(default_factory=list)   # (offset, reason)
    footer: bool = False
    valid_bytes: int = 0                             # offset where readable data ends
    size: int = 0
    problem: str = ""

    @property
    def message_count(self) -> int:
        return len(self.messages)

    @property
    def start_ns(self) -> int:
        return min((m.log_time for m in self.messages), default=0)

    @property
    def end_ns(self) -> int:
        return max((m.log_time for m in self.messages), default=0)

    @property
    def topics(self) -> dict[str, TopicInfo]:
        out: dict[str, TopicInfo] = {}
        for ch in self.channels.values():
            sc = self.schemas.get(ch.schema_id)
            qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "") or "[]") or []
            out[ch.topic] = TopicInfo(ch.topic, sc.name if sc else "", qos,
                                      ch.metadata.get("topic_type_hash", ""), ch.message_encoding)
        for m in self.messages:
            out[m.topic].message_count += 1
        return out

    def summary(self) -> dict:
        """Plain-dict report (JSON-able) of what was recovered and what was not."""
        return {
            "complete": self.footer and not self.chunks_bad and not self.problem,
            "messages_recovered": self.message_count,
            "per_topic": {n: t.message_count for n, t in sorted(self.topics.items())},
            "chunks_ok": self.chunks_ok,
            "chunks_bad": [{"offset": o, "reason": r} for o, r in self.chunks_bad],
            "footer_found": self.footer,
            "valid_bytes": self.valid_bytes,
            "unreadable_tail_bytes": max(0, self.size - self.valid_bytes) if not self.footer else 0,
            "problem": self.problem,
        }


def scan(path) -> ScanResult:
    """Sequentially read every record of an MCAP file that can be read (see module doc)."""
    path = resolve_mcap(path)
    data = Path(path).read_bytes()
    res = ScanResult(Path(path), size=len(data))
    if data[:8] != MAGIC:
        res.problem = "bad magic: not an MCAP file"
        return res
    pos = 8
    res.valid_bytes = pos
    while pos < len(data):
        if pos + 9 > len(data):
            res.problem = f"truncated record header at byte {pos}"
            break
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        body_start, body_end = pos + 9, pos + 9 + length
        if length > MAX_RECORD:
            res.problem = f"implausible record length {length} at byte {pos} (corrupt)"
            break
        if body_end > len(data):
            res.problem = (f"record (opcode 0x{opcode:02x}) at byte {pos} cut short: "
                           f"{len(data) - body_start} of {length} bytes present")
            break
        body = ReadDataStream(io.BytesIO(data[body_start:body_end]))
        try:
            if opcode == Opcode.SCHEMA:
                s = Schema.read(body)
                res.schemas[s.id] = s
            elif opcode == Opcode.CHANNEL:
                c = Channel.read(body)
                res.channels[c.id] = c
            elif opcode == Opcode.MESSAGE:
                _add_message(res, Message.read(body, length))
            elif opcode == Opcode.CHUNK:
                _read_chunk(res, Chunk.read(body), pos)
            elif opcode == Opcode.FOOTER:
                Footer.read(body)
                res.footer = True
        except Exception as exc:  # noqa: BLE001 - a malformed record body: report, go on
            res.chunks_bad.append((pos, f"malformed record 0x{opcode:02x}: {exc}"))
        pos = body_end
        res.valid_bytes = pos
        if res.footer:
            break
    return res


def _add_message(res: ScanResult, m: Message) -> None:
    ch = res.channels.get(m.channel_id)
    if ch is None:
        return
    sc = res.schemas.get(ch.schema_id)
    res.messages.append(BagMessage(ch.topic, sc.name if sc else "", m.log_time, m.publish_time,
                                   bytes(m.data)))


def _read_chunk(res: ScanResult, chunk: Chunk, offset: int) -> None:
    try:
        records = breakup_chunk(chunk, validate_crc=True)
    except Exception as exc:  # noqa: BLE001 - CRC mismatch, bad zstd frame, bad record
        res.chunks_bad.append((offset, f"{type(exc).__name__}: {exc}"))
        return
    pending = []
    for r in records:
        if isinstance(r, Schema):
            res.schemas[r.id] = r
        elif isinstance(r, Channel):
            res.channels[r.id] = r
        elif isinstance(r, Message):
            pending.append(r)
    for m in pending:
        _add_message(res, m)
    res.chunks_ok += 1
