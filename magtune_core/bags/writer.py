"""Crash-safe rosbag2-compatible MCAP writer (no rclpy); layout in :mod:`magtune_core.bags`."""
from __future__ import annotations

import os
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from . import msgdefs
from .layout import (
    DEFAULT_CHUNK_SIZE,
    LIBRARY,
    TopicInfo,
    build_metadata,
    mcap_file_name,
    qos_dict,
    qos_yaml,
    write_metadata,
)


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


class BagWriter:
    """Write a rosbag2 MCAP bag directory.

    Usage::

        w = BagWriter("bags/run1"); w.add_topic("/imu", "sensor_msgs/msg/Imu")
        w.write("/imu", cdr_bytes, log_time_ns); w.close()

    Not thread-safe: call from one thread (the recorder's writer thread).
    """

    def __init__(self, bag_dir, *, chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd",
                 custom_data: dict | None = None, overwrite: bool = False, max_bytes: int = 0,
                 max_duration_ns: int = 0):
        self.dir = Path(bag_dir)
        if self.dir.exists() and any(self.dir.iterdir()):
            if not overwrite:
                raise FileExistsError(f"bag directory {self.dir} exists and is not empty")
            for f in self.dir.iterdir():
                f.unlink()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.custom_data = dict(custom_data or {})
        self._chunk_size = chunk_size
        self._comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                      "none": CompressionType.NONE, "": CompressionType.NONE}[compression]
        # splitting (rosbag2's --max-bag-size / --max-bag-duration): a new NAME_<i>.mcap when the
        # current file holds max_bytes (checked at chunk boundaries) or spans max_duration_ns of log time
        self.max_bytes, self.max_duration_ns = int(max_bytes), int(max_duration_ns)
        self.files: list[dict] = []      # per file: path, start_ns, end_ns, count
        self.topics: dict[str, TopicInfo] = {}
        self._defs: dict[str, str] = {}  # type -> full ros2msg definition (schema of every file)
        self._open_file(0)
        self.start_ns: int | None = None
        self.end_ns = 0
        self.closed = False
        # a provisional metadata.yaml so that the directory is a bag even before close()
        write_metadata(self.dir, build_metadata(self.dir, [], 0, 0, self.custom_data))

    def _open_file(self, index: int) -> None:
        """Start ``NAME_<index>.mcap`` with the schemas and channels of every topic so far."""
        self.path = self.dir / mcap_file_name(self.dir, index)
        self._sink = _UnbufferedSink(self.path)
        self._w = Writer(self._sink, chunk_size=self._chunk_size, compression=self._comp)
        self._w.start(profile="ros2", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.files.append({"path": self.path.name, "start_ns": 0, "end_ns": 0, "count": 0})
        for t in list(self.topics.values()):
            self._register(t.name, t.type, t.offered_qos_profiles)

    def _finish_file(self) -> None:
        doc = self.metadata()
        self._w.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(
            doc["rosbag2_bagfile_information"], sort_keys=False)})
        self._w.finish()
        self._sink.fsync()
        self._sink.close()

    def split(self) -> None:
        """Close the current file (complete, with summary) and continue in the next one."""
        self._finish_file()
        self._open_file(len(self.files))
        write_metadata(self.dir, self.metadata())

    def _register(self, name: str, msg_type: str, profiles: list) -> str:
        if msg_type not in self._schemas:
            self._schemas[msg_type] = self._w.register_schema(msg_type, "ros2msg", self._defs[msg_type].encode())
        thash = msgdefs.type_hash(msg_type)
        self._channels[name] = self._w.register_channel(
            topic=name, message_encoding="cdr", schema_id=self._schemas[msg_type],
            metadata={"offered_qos_profiles": qos_yaml(profiles), "topic_type_hash": thash})
        return thash

    def add_topic(self, name: str, msg_type: str, qos_profiles: list[dict] | None = None,
                  definition: str | None = None) -> None:
        """Register a topic (schema once per type, one channel per topic). Idempotent."""
        if name in self._channels:
            return
        msg_type = msgdefs.normalize_type(msg_type)
        if msg_type not in self._defs:
            self._defs[msg_type] = definition if definition is not None else msgdefs.full_definition(msg_type)
        profiles = list(qos_profiles) if qos_profiles is not None else [qos_dict()]
        thash = self._register(name, msg_type, profiles)
        self.topics[name] = TopicInfo(name, msg_type, profiles, thash)

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int = 0) -> None:
        """Append one serialized (CDR) message."""
        t = int(log_time_ns)
        f = self.files[-1]
        if f["count"] and ((self.max_bytes and self._sink.tell() >= self.max_bytes)
                           or (self.max_duration_ns and t - f["t0"] >= self.max_duration_ns)):
            self.split()
            f = self.files[-1]
        if not f["count"]:
            f["t0"] = t    # the file's duration counts from its first message (log times may be slightly out of order)
        f["start_ns"] = t if not f["count"] else min(f["start_ns"], t)
        f["end_ns"] = max(f["end_ns"], t)
        f["count"] += 1
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
        """The ``metadata.yaml`` document of what has been written so far (:func:`.layout.build_metadata`)."""
        files = [dict(f) for f in self.files] if len(self.files) > 1 else None
        return build_metadata(self.dir, list(self.topics.values()), self.start_ns or 0,
                              self.end_ns, self.custom_data, files)

    def close(self) -> Path:
        """Finish the MCAP (summary, statistics, indexes) and write ``metadata.yaml``."""
        if self.closed:
            return self.dir
        self._finish_file()
        write_metadata(self.dir, self.metadata())
        self.closed = True
        return self.dir

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


