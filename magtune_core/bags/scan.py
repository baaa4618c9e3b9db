"""Integrity scan of an MCAP file: every chunk CRC-checked, damaged records skipped, losses counted.

Every reader of the project goes through :func:`scan` (``bag info``, replay, report, recovery),
so a bag is never called complete unless each of its chunks decompresses and matches its CRC.

* A **cleanly closed file** (valid summary with a chunk index) is read through the chunk index:
  each chunk is read at its indexed offset and length, so damage to one record (even to a
  chunk's own length field) costs at most that chunk. Schemas and channels come from the
  summary, so a damaged first chunk does not orphan the later ones.
* A file **without summary** (recorder killed with SIGKILL, power loss, damaged footer) is
  walked record by record. A record whose length is implausible or runs past the end of the
  file, an unknown opcode or a bad magic makes the scan **resynchronise**: it looks for the next
  byte offset holding a structurally valid chunk whose payload decompresses and matches its
  CRC (a chunk whose own length field is damaged is found this way too, from its inner lengths).

Damaged chunks are listed with their offset, the reason, and, where the message index records
(or the summary's chunk index) say so, how many messages they held and their time range. An
empty file, or one in which nothing MCAP-like can be found, raises
:class:`~magtune_core.base.errors.ConfigError` (exit status 2 in every command).
"""
from __future__ import annotations

import collections
import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Message, MessageIndex, Schema
from mcap.stream_reader import breakup_chunk

from ..base.errors import ConfigError
from ..base.paramfile import check_path, open_regular, read_regular
from .layout import BagMessage, TopicInfo, listed_files, resolve_mcap

MAGIC = b"\x89MCAP0\r\n"
MAX_RECORD = 1 << 31  # larger length fields are treated as corruption
COMPRESSIONS = (b"", b"zstd", b"lz4")
_KNOWN_OPCODES = {int(o) for o in Opcode}


@dataclass
class BadChunk:
    """A chunk that could not be read: where, why, and what it held (None: unknown)."""

    offset: int
    reason: str
    messages: int | None = None
    start_ns: int | None = None
    end_ns: int | None = None

    def to_dict(self) -> dict:
        """Plain-dict form (JSON-able) for :meth:`ScanResult.summary`."""
        return {"offset": self.offset, "reason": self.reason, "messages": self.messages,
                "start_ns": self.start_ns, "end_ns": self.end_ns}


@dataclass
class ScanResult:
    """What the integrity scan of an MCAP file could read, and what it could not."""

    path: Path
    schemas: dict = field(default_factory=dict)      # id -> mcap Schema
    channels: dict = field(default_factory=dict)     # id -> mcap Channel
    messages: list = field(default_factory=list)     # BagMessage of the selected topics, file order
    counts: collections.Counter = field(default_factory=collections.Counter)  # topic -> readable msgs
    chunks_ok: int = 0
    chunks_bad: list = field(default_factory=list)   # BadChunk
    footer: bool = False
    indexed: bool = False                            # read through the summary's chunk index
    expected: int | None = None                      # message count the summary promises
    valid_bytes: int = 0                             # offset where readable data ends
    size: int = 0
    skipped_bytes: int = 0                           # bytes passed over while resynchronising
    orphans: int = 0                                 # messages of a channel whose record was lost
    problem: str = ""
    start_ns: int = 0
    end_ns: int = 0

    @property
    def message_count(self) -> int:
        """Messages read intact, all topics."""
        return sum(self.counts.values())

    @property
    def complete(self) -> bool:
        """True if the file was closed cleanly and nothing was lost (no bad chunk, problem or orphan)."""
        return self.footer and not self.chunks_bad and not self.problem and not self.orphans

    @property
    def lost_known(self) -> int:
        """Messages held by damaged chunks, as far as their indexes tell."""
        return sum(c.messages or 0 for c in self.chunks_bad)

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topics seen in the file (name -> :class:`TopicInfo` with the intact message counts)."""
        out: dict[str, TopicInfo] = {}
        for ch in self.channels.values():
            sc = self.schemas.get(ch.schema_id)
            try:
                qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "") or "[]") or []
            except yaml.YAMLError:
                qos = []
            out[ch.topic] = TopicInfo(ch.topic, sc.name if sc else "", qos,
                                      ch.metadata.get("topic_type_hash", ""), ch.message_encoding,
                                      self.counts.get(ch.topic, 0))
        return out

    def summary(self) -> dict:
        """Plain-dict report (JSON-able) of what was read and what was not."""
        return {
            "complete": self.complete,
            "messages_recovered": self.message_count,
            "messages_expected": self.expected,
            "messages_in_damaged_chunks": self.lost_known,
            "per_topic": dict(sorted(self.counts.items())),
            "chunks_ok": self.chunks_ok,
            "chunks_bad": [c.to_dict() for c in self.chunks_bad],
            "footer_found": self.footer,
            "read_through_index": self.indexed,
            "valid_bytes": self.valid_bytes,
            "unreadable_tail_bytes": max(0, self.size - self.valid_bytes) if not self.footer else 0,
            "skipped_bytes": self.skipped_bytes,
            "orphan_messages": self.orphans,
            "problem": self.problem,
        }


class _Scanner:
    def __init__(self, data: bytes, res: ScanResult, topics, visit):
        self.data, self.res, self.visit = data, res, visit
        self.wanted = set(topics) if topics is not None else None

    # ------------------------------------------------------------ messages
    def add(self, m: Message) -> None:
        res = self.res
        ch = res.channels.get(m.channel_id)
        if ch is None:
            res.orphans += 1
            return
        res.counts[ch.topic] += 1
        if res.message_count == 1 or m.log_time < res.start_ns:
            res.start_ns = m.log_time
        res.end_ns = max(res.end_ns, m.log_time)
        if self.wanted is not None and ch.topic not in self.wanted:
            return
        sc = res.schemas.get(ch.schema_id)
        bm = BagMessage(ch.topic, sc.name if sc else "", m.log_time, m.publish_time, bytes(m.data))
        if self.visit is not None:
            self.visit(bm)
        else:
            res.messages.append(bm)

    def take_chunk(self, chunk: Chunk, offset: int) -> bool:
        """Decompress + CRC-check one chunk; keep its records or list it as bad."""
        try:
            records = breakup_chunk(chunk, validate_crc=True)
        except Exception as exc:  # noqa: BLE001 - CRC mismatch, bad zstd frame, bad record
            self.res.chunks_bad.append(BadChunk(offset, f"{type(exc).__name__}: {exc}",
                                                start_ns=chunk.message_start_time,
                                                end_ns=chunk.message_end_time))
            return False
        pending = []
        for r in records:
            if isinstance(r, Schema):
                self.res.schemas.setdefault(r.id, r)
            elif isinstance(r, Channel):
                self.res.channels.setdefault(r.id, r)
            elif isinstance(r, Message):
                pending.append(r)
        for m in pending:
            self.add(m)
        self.res.chunks_ok += 1
        return True

    # ------------------------------------------------------------ chunk at an offset
    def chunk_at(self, pos: int) -> tuple[Chunk, int] | None:
        """The chunk record starting at ``pos`` read from its inner lengths (not its outer
        length field) and its end offset, if it is structurally valid; else None."""
        d = self.data
        p = pos + 9
        if pos >= len(d) or d[pos] != Opcode.CHUNK or p + 40 > len(d):
            return None
        start, end, usize, crc, clen = struct.unpack_from("<QQQII", d, p)
        if clen > 8 or start > end or usize > MAX_RECORD:
            return None
        comp = bytes(d[p + 32:p + 32 + clen])
        if comp not in COMPRESSIONS or p + 40 + clen > len(d):
            return None
        (rlen,) = struct.unpack_from("<Q", d, p + 32 + clen)
        rec_end = p + 40 + clen + rlen
        if rlen > MAX_RECORD or rec_end > len(d) or (comp == b"" and rlen != usize):
            return None
        chunk = Chunk(compression=comp.decode(), data=bytes(d[p + 40 + clen:rec_end]),
                      message_end_time=end, message_start_time=start, uncompressed_crc=crc,
                      uncompressed_size=usize)
        return chunk, rec_end

    def resync(self, pos: int) -> int | None:
        """Offset of the next chunk after ``pos`` that is structurally valid and passes its
        CRC (a false match in compressed bytes fails one of the two)."""
        d = self.data
        i = pos + 1
        while True:
            i = d.find(b"\x06", i)
            if i < 0:
                return None
            got = self.chunk_at(i)
            if got is not None:
                try:
                    breakup_chunk(got[0], validate_crc=True)
                    if got[0].uncompressed_crc != 0 or got[0].compression:
                        return i
                except Exception:  # noqa: BLE001 - not a chunk after all
                    pass
            i += 1


def _index_messages(data: bytes, offsets: dict) -> int | None:
    """Messages listed by the message index records at ``offsets`` (None if unreadable)."""
    n = 0
    try:
        for off in offsets.values():
            if data[off] != Opcode.MESSAGE_INDEX:
                return None
            (length,) = struct.unpack_from("<Q", data, off + 1)
            n += len(MessageIndex.read(ReadDataStream(io.BytesIO(data[off + 9:off + 9 + length]))).records)
    except Exception:  # noqa: BLE001 - a damaged index: count unknown
        return None
    return n


def _scan_indexed(sc: _Scanner) -> bool:
    """Read through the summary's chunk index; False if there is no usable summary."""
    data, res = sc.data, sc.res
    try:
        summary = make_reader(io.BytesIO(data)).get_summary()
    except Exception:  # noqa: BLE001 - no footer / damaged summary: sequential scan
        return False
    if summary is None or not summary.chunk_indexes:
        return False
    res.indexed = res.footer = True
    res.schemas.update(summary.schemas)
    res.channels.update(summary.channels)
    if summary.statistics is not None:
        res.expected = int(summary.statistics.message_count)
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        off, end = ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length
        try:
            if end > len(data) or data[off] != Opcode.CHUNK:
                raise ValueError("chunk index points outside the file or not at a chunk")
            chunk = Chunk.read(ReadDataStream(io.BytesIO(data[off + 9:end])))
        except Exception as exc:  # noqa: BLE001 - damaged chunk header
            res.chunks_bad.append(BadChunk(off, f"unreadable chunk record: {exc}",
                                           start_ns=ci.message_start_time, end_ns=ci.message_end_time))
            res.chunks_bad[-1].messages = _index_messages(data, ci.message_index_offsets)
            continue
        if not sc.take_chunk(chunk, off):
            res.chunks_bad[-1].messages = _index_messages(data, ci.message_index_offsets)
    res.valid_bytes = len(data)
    return True


def _scan_sequential(sc: _Scanner) -> None:
    data, res = sc.data, sc.res
    pos = 8
    if data[:8] != MAGIC:
        res.problem = "bad magic (damaged or not an MCAP file)"
        nxt = sc.resync(-1)
        res.skipped_bytes += (nxt if nxt is not None else len(data))
        if nxt is None:
            return
        pos = nxt
    res.valid_bytes = pos
    last_bad: BadChunk | None = None   # message index records after a bad chunk count its loss
    while pos < len(data):
        why = ""
        opcode = data[pos]
        length = struct.unpack_from("<Q", data, pos + 1)[0] if pos + 9 <= len(data) else None
        if length is None:
            why = f"truncated record header at byte {pos}"
        elif opcode not in _KNOWN_OPCODES:
            why = f"unknown record opcode 0x{opcode:02x} at byte {pos} (corrupt)"
        elif length > MAX_RECORD:
            why = f"implausible record length {length} at byte {pos} (corrupt)"
        elif pos + 9 + length > len(data):
            why = (f"record (opcode 0x{opcode:02x}) at byte {pos} cut short: "
                   f"{len(data) - pos - 9} of {length} bytes present")
        got = sc.chunk_at(pos) if opcode == Opcode.CHUNK else None
        if got is not None:   # chunks are delimited by their inner lengths (a damaged outer
            if length != got[1] - pos - 9:           # length field costs nothing)
                res.problem = res.problem or f"chunk at byte {pos}: record length field damaged"
            last_bad = None if sc.take_chunk(got[0], pos) else res.chunks_bad[-1]
            pos = res.valid_bytes = got[1]
            continue
        if why:
            nxt = sc.resync(pos)
            if nxt is None:
                res.problem = res.problem or why
                break
            res.problem = res.problem or why.replace(" (corrupt)", "") + "; resynchronised"
            res.skipped_bytes += nxt - pos
            pos = nxt
            last_bad = None
            continue
        body_start, body_end = pos + 9, pos + 9 + length
        body = ReadDataStream(io.BytesIO(data[body_start:body_end]))
        try:
            if opcode == Opcode.SCHEMA:
                s = Schema.read(body)
                res.schemas.setdefault(s.id, s)
            elif opcode == Opcode.CHANNEL:
                c = Channel.read(body)
                res.channels.setdefault(c.id, c)
            elif opcode == Opcode.MESSAGE:
                sc.add(Message.read(body, length))
            elif opcode == Opcode.CHUNK:
                last_bad = None if sc.take_chunk(Chunk.read(body), pos) else res.chunks_bad[-1]
            elif opcode == Opcode.MESSAGE_INDEX and last_bad is not None:
                last_bad.messages = (last_bad.messages or 0) + len(MessageIndex.read(body).records)
            elif opcode == Opcode.FOOTER:
                Footer.read(body)
                res.footer = True
        except Exception as exc:  # noqa: BLE001 - a malformed record body: report, go on
            res.chunks_bad.append(BadChunk(pos, f"malformed record 0x{opcode:02x}: {exc}"))
            last_bad = res.chunks_bad[-1] if opcode == Opcode.CHUNK else None
        pos = body_end
        res.valid_bytes = pos
        if res.footer:
            break


def scan(path, topics=None, visit=None) -> ScanResult:
    """Read every readable message of an MCAP file, CRC-checking each chunk (see module doc).

    ``topics``: keep only these topics' messages (all are counted); ``visit``: called with each
    kept :class:`BagMessage` in file order instead of storing it in ``messages``.

    Returns
    -------
    ScanResult
        Messages (or counts), schemas, channels, damaged chunks and what they held.
    """
    path = resolve_mcap(path)
    data = read_regular(path, limit=None)  # a FIFO or a device: ConfigError, never read
    if not data:
        raise ConfigError(path, None, "empty file (0 bytes): not an MCAP bag")
    res = ScanResult(Path(path), size=len(data))
    sc = _Scanner(data, res, topics, visit)
    if data[:8] != MAGIC or not _scan_indexed(sc):
        _scan_sequential(sc)
    if not (res.chunks_ok or res.channels or res.schemas or res.footer):
        raise ConfigError(path, None, f"not an MCAP file ({res.problem or 'no readable record'})")
    return res


def check_file(bag) -> Path:
    """The first .mcap file of ``bag`` that can be a bag (exists, non-empty, MCAP magic or at
    least MCAP-like after a damaged magic); ConfigError naming the problem otherwise. For a split
    bag, a damaged, empty or missing later file is not an error here (the integrity report names
    it); only a bag none of whose files can be read is. Cheap: commands call it before starting
    any process."""
    p = Path(bag)
    check_path(p)
    if not p.exists():
        raise ConfigError(p, None, "no such bag (expected a bag directory bags/NAME or an .mcap file)")
    try:
        files, _ = listed_files(p)
    except FileNotFoundError:
        raise ConfigError(p, None, "no .mcap file in this directory (expected a rosbag2 MCAP bag)") from None
    first_error = None
    for path in files:
        try:
            return _check_one(path)
        except ConfigError as exc:
            first_error = first_error or exc
    raise first_error


def _check_one(path: Path) -> Path:
    """``path`` if it is a non-empty, MCAP-like file; ConfigError otherwise."""
    try:
        with open_regular(path) as f:  # a FIFO or a device: ConfigError, never read
            head = f.read(8)
    except OSError as exc:
        raise ConfigError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if not head:
        raise ConfigError(path, None, "empty file (0 bytes): not an MCAP bag")
    if head != MAGIC:
        scan(path)  # raises ConfigError unless MCAP records can be found past the damage
    return path
