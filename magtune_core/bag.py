"""rosbag2-compatible MCAP bags: writer, reader and ``metadata.yaml`` (no rclpy).

Layout (what ``ros2 bag record -s mcap`` writes in Jazzy)::

    bags/NAME/
        metadata.yaml      rosbag2 metadata version 9, storage_identifier mcap
        NAME_0.mcap        profile ros2; schemas ros2msg (full .msg text); channels cdr

MCAP details (rosbag2_storage_mcap conventions):

* one Schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, data = the full
  definition text (:func:`magtune_core.msgdefs.full_definition`);
* one Channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (the YAML
  sequence of QoS maps rosbag2 serializes with its version-9 string enums) and
  ``topic_type_hash`` (RIHS01);
* Message ``log_time`` = receive time, ``publish_time`` = the recorder's send time (for our
  recorder both are the receive time on the node's clock, i.e. sim time with use_sim_time);
* chunked, zstd-compressed chunks, message indexes, summary with statistics, chunk indexes
  and a ``rosbag2`` Metadata record holding ``serialized_metadata`` (as rosbag2 does on close).

Crash safety: every chunk is written to the OS as soon as it is complete (the output stream is
unbuffered), and :meth:`BagWriter.flush` closes the open chunk on demand (the recorder calls it
periodically). After a SIGKILL the file holds every completed chunk but no summary; read it
with :func:`magtune_core.bag_recover.scan` (or any MCAP stream reader) and rewrite the summary
and ``metadata.yaml`` with :func:`magtune_core.bag_recover.recover`. What is lost: messages of
the chunk still open in memory (at most ``chunk_size`` bytes or ``flush`` period of data).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, NamedTuple

import yaml
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from . import msgdefs

METADATA_VERSION = 9
STORAGE_ID = "mcap"
ROS_DISTRO = "jazzy"
LIBRARY = "magtune-bag 0.1 (mcap-python writer, rosbag2_storage_mcap conventions)"
DEFAULT_CHUNK_SIZE = 256 * 1024
# rmw's "infinite" duration as rosbag2 stores it: RMW_DURATION_INFINITE = INT64_MAX ns
INFINITE = {"sec": 9223372036, "nsec": 854775807}


def qos_dict(*, reliability="reliable", durability="volatile", history="keep_last", depth=10,
             deadline=None, lifespan=None, liveliness="automatic", lease=None,
             avoid_ros_namespace_conventions=False) -> dict:
    """One offered QoS profile in rosbag2's metadata-version-9 form (string enums)."""
    return {
        "history": history, "depth": int(depth), "reliability": reliability,
        "durability": durability, "deadline": dict(deadline or INFINITE),
        "lifespan": dict(lifespan or INFINITE), "liveliness": liveliness,
        "liveliness_lease_duration": dict(lease or INFINITE),
        "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions),
    }


def qos_yaml(profiles: list[dict]) -> str:
    """Channel metadata ``offered_qos_profiles``: a YAML block sequence, as yaml-cpp dumps it."""
    if not profiles:
        return ""
    return yaml.safe_dump(list(profiles), sort_keys=False, default_flow_style=False).rstrip("\n")


class _UnbufferedSink:
    """Write-through file wrapper: each write reaches the OS at once (survives SIGKILL)."""

    def __init__(self, path: Path):
        self._f = open(path, "wb", buffering=0)
        self._pos = 0

    def write(self, data) -> int:
        view = memoryview(data)
        while view:
            n = self._f.write(view)
            view = view[n:]
        self._pos += len(data)
        return len(data)

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def fsync(self) -> None:
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


@dataclass
class TopicInfo:
    """A topic of a bag: rosbag2 ``topic_metadata`` plus its message count."""

    name: str
    type: str
    offered_qos_profiles: list = field(default_factory=list)
    type_description_hash: str = ""
    serialization_format: str = "cdr"
    message_count: int = 0

    def to_metadata(self) -> dict:
        return {
            "topic_metadata": {
                "name": self.name, "type": self.type,
                "serialization_format": self.serialization_format,
                "offered_qos_profiles": list(self.offered_qos_profiles),
                "type_description_hash": self.type_description_hash,
            },
            "message_count": int(self.message_count),
        }


def mcap_file_name(bag_dir: Path) -> str:
    return f"{Path(bag_dir).name}_0.mcap"


def build_metadata(bag_dir: Path, topics: list[TopicInfo], start_ns: int, end_ns: int,
                   custom_data: dict | None = None, files: list[str] | None = None) -> dict:
    """The ``rosbag2_bagfile_information`` document (version 9)."""
    count = sum(t.message_count for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    files = files or [mcap_file_name(bag_dir)]
    return {"rosbag2_bagfile_information": {
        "version": METADATA_VERSION,
        "storage_identifier": STORAGE_ID,
        "duration": {"nanoseconds": int(duration)},
        "starting_time": {"nanoseconds_since_epoch": int(start)},
        "message_count": int(count),
        "topics_with_message_count": [t.to_metadata() for t in topics],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": list(files),
        "files": [{"path": f, "starting_time": {"nanoseconds_since_epoch": int(start)},
                   "duration": {"nanoseconds": int(duration)}, "message_count": int(count)}
                  for f in files],
        "custom_data": {str(k): str(v) for k, v in (custom_data or {}).items()},
        "ros_distro": ROS_DISTRO,
    }}


def write_metadata(bag_dir: Path, doc: dict) -> Path:
    """Atomically write ``metadata.yaml``."""
    path = Path(bag_dir) / "metadata.yaml"
    tmp = path.with_suffix(".yaml.tmp")
    tmp.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=False))
    os.replace(tmp, path)
    return path


def read_metadata(bag_dir: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of a bag directory."""
    doc = yaml.safe_load((Path(bag_dir) / "metadata.yaml").read_text())
    return doc["rosbag2_bagfile_information"]


class BagWriter:
    """Write a rosbag2 MCAP bag directory.

    Usage::

        w = BagWriter("bags/run1"); w.add_topic("/imu", "sensor_msgs/msg/Imu")
        w.write("/imu", cdr_bytes, log_time_ns); w.close()

    Not thread-safe: call from one thread (the recorder's writer thread).
    """

    def __init__(self, bag_dir, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 custom_data: dict | None = None, overwrite: bool = False):
        self.dir = Path(bag_dir)
        if self.dir.exists() and any(self.dir.iterdir()):
            if not overwrite:
                raise FileExistsError(f"bag directory {self.dir} exists and is not empty")
            for f in self.dir.iterdir():
                f.unlink()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.path = self.dir / mcap_file_name(self.dir)
        self.custom_data = dict(custom_data or {})
        self._sink = _UnbufferedSink(self.path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE, "": CompressionType.NONE}[compression]
        self._w = Writer(self._sink, chunk_size=chunk_size, compression=comp)
        self._w.start(profile="ros2", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.topics: dict[str, TopicInfo] = {}
        self.start_ns: int | None = None
        self.end_ns = 0
        self.closed = False
        # a provisional metadata.yaml so that the directory is a bag even before close()
        write_metadata(self.dir, build_metadata(self.dir, [], 0, 0, self.custom_data))

    def add_topic(self, name: str, msg_type: str, qos_profiles: list[dict] | None = None,
                  definition: str | None = None) -> None:
        """Register a topic (schema once per type, one channel per topic). Idempotent."""
        if name in self._channels:
            return
        msg_type = msgdefs.normalize_type(msg_type)
        if msg_type not in self._schemas:
            text = definition if definition is not None else msgdefs.full_definition(msg_type)
            self._schemas[msg_type] = self._w.register_schema(msg_type, "ros2msg", text.encode())
        profiles = list(qos_profiles) if qos_profiles is not None else [qos_dict()]
        thash = msgdefs.type_hash(msg_type)
        self._channels[name] = self._w.register_channel(
            topic=name, message_encoding="cdr", schema_id=self._schemas[msg_type],
            metadata={"offered_qos_profiles": qos_yaml(profiles), "topic_type_hash": thash})
        self.topics[name] = TopicInfo(name, msg_type, profiles, thash)

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int = 0) -> None:
        """Append one serialized (CDR) message."""
        t = int(log_time_ns)
        self._w.add_message(self._channels[topic], log_time=t, data=data,
                            publish_time=t if publish_time_ns is None else int(publish_time_ns),
                            sequence=sequence)
        self.topics[topic].message_count += 1
        self.start_ns = t if self.start_ns is None else min(self.start_ns, t)
        self.end_ns = max(self.end_ns, t)

    def flush(self) -> None:
        """Close the open chunk and push it to the OS (readable after a crash from now on)."""
        self._w.flush()

    def metadata(self) -> dict:
        return build_metadata(self.dir, list(self.topics.values()), self.start_ns or 0,
                              self.end_ns, self.custom_data)

    def close(self) -> Path:
        """Finish the MCAP (summary, statistics, indexes) and write ``metadata.yaml``."""
        if self.closed:
            return self.dir
        doc = self.metadata()
        self._w.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(
            doc["rosbag2_bagfile_information"], sort_keys=False)})
        self._w.finish()
        self._sink.fsync()
        self._sink.close()
        write_metadata(self.dir, doc)
        self.closed = True
        return self.dir

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BagMessage(NamedTuple):
    """One recorded message: topic, type, receive (log) time, publish time, CDR bytes."""

    topic: str
    type: str
    log_time: int
    publish_time: int
    data: bytes


def resolve_mcap(bag) -> Path:
    """The ``.mcap`` file of a bag directory (or the file itself)."""
    p = Path(bag)
    if p.is_file():
        return p
    meta = p / "metadata.yaml"
    if meta.is_file():
        try:
            files = read_metadata(p).get("relative_file_paths") or []
            if files and (p / files[0]).is_file():
                return p / files[0]
        except (yaml.YAMLError, KeyError, TypeError):
            pass
    cands = sorted(p.glob("*.mcap"))
    if not cands:
        raise FileNotFoundError(f"no .mcap file in {p}")
    return cands[0]


def has_summary(mcap_path: Path) -> bool:
    """True if the file ends with a valid footer + magic (i.e. was closed cleanly)."""
    try:
        with open(mcap_path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # noqa: BLE001 - any parse failure means: not a complete file
        return False


def iter_messages(bag, topics=None, start_ns: int | None = None, report: dict | None = None,
                  order: str = "log") -> Iterator[BagMessage]:
    """Messages of a bag in log-time order (``order="publish"``: by publish time, ties in
    log-time order; ``start_ns`` then applies to publish times).

    A cleanly closed file is read through its index. A truncated or corrupt file (no summary) is
    scanned sequentially; every complete, CRC-valid chunk is returned and ``report`` (if a dict)
    receives what was skipped (see :func:`magtune_core.bag_recover.scan`).
    """
    if order == "publish":
        msgs = sorted(iter_messages(bag, topics, None, report), key=lambda m: m.publish_time)
        yield from (m for m in msgs if start_ns is None or m.publish_time >= start_ns)
        return
    if order != "log":
        raise ValueError(f"order must be 'log' or 'publish', not {order!r}")
    path = resolve_mcap(bag)
    wanted = set(topics) if topics is not None else None
    if wanted is not None and not wanted:
        return
    if has_summary(path):
        with open(path, "rb") as f:
            for schema, channel, msg in make_reader(f).iter_messages(
                    topics=list(wanted) if wanted else None, start_time=start_ns,
                    log_time_order=True):
                yield BagMessage(channel.topic, schema.name if schema else "", msg.log_time,
                                 msg.publish_time, msg.data)
        if report is not None:
            report.update({"complete": True})
        return
    from .bag_recover import scan  # local import: recovery is the rare path
    res = scan(path)
    if report is not None:
        report.update(res.summary())
    msgs = [m for m in res.messages if (wanted is None or m.topic in wanted)
            and (start_ns is None or m.log_time >= start_ns)]
    msgs.sort(key=lambda m: m.log_time)  # stable: file order within equal times
    yield from msgs


def topics_of(bag) -> dict[str, TopicInfo]:
    """Topics (name -> :class:`TopicInfo` with counts) from the MCAP itself."""
    path = resolve_mcap(bag)
    if has_summary(path):
        with open(path, "rb") as f:
            s = make_reader(f).get_summary()
        out = {}
        for cid, ch in s.channels.items():
            sc = s.schemas.get(ch.schema_id)
            qos = yaml.safe_load(ch.metadata.get("offered_qos_profiles", "") or "[]") or []
            out[ch.topic] = TopicInfo(ch.topic, sc.name if sc else "", qos,
                                      ch.metadata.get("topic_type_hash", ""), ch.message_encoding,
                                      s.statistics.channel_message_counts.get(cid, 0)
                                      if s.statistics else 0)
        return out
    from .bag_recover import scan
    return scan(path).topics


def info(bag) -> dict:
    """Summary of a bag for ``magtune bag info``: counts, times, topics, integrity."""
    path = resolve_mcap(bag)
    complete = has_summary(path)
    if complete:
        with open(path, "rb") as f:
            s = make_reader(f).get_summary()
        st = s.statistics
        start, end, count = st.message_start_time, st.message_end_time, st.message_count
        chunks = st.chunk_count
    else:
        from .bag_recover import scan
        res = scan(path)
        start, end, count = res.start_ns, res.end_ns, res.message_count
        chunks = res.chunks_ok
    return {"path": str(path), "complete": complete, "size_bytes": path.stat().st_size,
            "message_count": count, "start_ns": start, "end_ns": end,
            "duration_s": (end - start) / 1e9 if count else 0.0, "chunks": chunks,
            "topics": {n: {"type": t.type, "count": t.message_count}
                       for n, t in sorted(topics_of(path).items())}}
