"""The rosbag2 (Jazzy, metadata version 9) MCAP bag layout: metadata.yaml, QoS, topic records.

Shared by the writer, the reader and recovery; see :mod:`magtune_core.bags` for the format.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import yaml
from mcap.reader import make_reader

from ..base.atomic import atomic_write
from ..base.errors import ConfigError
from ..base.paramfile import USER_FILE_LIMIT, check_path, is_regular_file, open_regular, too_large

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
        """This topic's entry of ``metadata.yaml``'s ``topics_with_message_count`` (rosbag2 version 9)."""
        return {
            "topic_metadata": {
                "name": self.name, "type": self.type,
                "serialization_format": self.serialization_format,
                "offered_qos_profiles": list(self.offered_qos_profiles),
                "type_description_hash": self.type_description_hash,
            },
            "message_count": int(self.message_count),
        }


def mcap_file_name(bag_dir: Path, index: int = 0) -> str:
    """``NAME_<index>.mcap``: rosbag2's name of the index-th file of a (split) bag."""
    return f"{Path(bag_dir).name}_{int(index)}.mcap"


def build_metadata(bag_dir: Path, topics: list[TopicInfo], start_ns: int, end_ns: int,
                   custom_data: dict | None = None, files: list[str] | None = None) -> dict:
    """The ``rosbag2_bagfile_information`` document (version 9)."""
    count = sum(t.message_count for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    files = files or [mcap_file_name(bag_dir)]
    if files and isinstance(files[0], dict):   # split bag: per-file {path, start_ns, end_ns, count}
        return _with_files(bag_dir, topics, start_ns, end_ns, custom_data, files)
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


def _with_files(bag_dir, topics, start_ns, end_ns, custom_data, stats: list[dict]) -> dict:
    """Metadata of a split bag: one ``files`` entry per file with its own start, duration, count."""
    doc = build_metadata(bag_dir, topics, start_ns, end_ns, custom_data, [f["path"] for f in stats])
    info = doc["rosbag2_bagfile_information"]
    info["files"] = [{"path": f["path"], "starting_time": {"nanoseconds_since_epoch": int(f["start_ns"] if f["count"] else 0)},
                      "duration": {"nanoseconds": int(max(0, f["end_ns"] - f["start_ns"]) if f["count"] else 0)},
                      "message_count": int(f["count"])} for f in stats]
    return doc


def write_metadata(bag_dir: Path, doc: dict) -> Path:
    """Atomically write ``metadata.yaml``."""
    return atomic_write(Path(bag_dir) / "metadata.yaml", yaml.safe_dump(doc, sort_keys=False, default_flow_style=False))


def read_metadata(bag_dir: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of a bag directory.

    ``metadata.yaml`` must be a regular file of at most 1 MiB (``USER_FILE_LIMIT``; a FIFO or a
    device is never read, a huge file never parsed): ConfigError otherwise. A missing or
    unreadable file raises OSError, a malformed one yaml.YAMLError (callers treat both as no
    usable metadata).
    """
    path = Path(bag_dir) / "metadata.yaml"
    with open_regular(path) as fh:
        data = fh.read(USER_FILE_LIMIT + 1)
    if len(data) > USER_FILE_LIMIT:
        raise too_large(path, len(data))
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:  # every caller treats it as a malformed metadata.yaml
        raise yaml.YAMLError(f"metadata.yaml is not UTF-8 text (byte offset {exc.start})") from None
    doc = yaml.safe_load(text)
    return doc["rosbag2_bagfile_information"]


class BagMessage(NamedTuple):
    """One recorded message: topic, type, receive (log) time, publish time, CDR bytes."""

    topic: str
    type: str
    log_time: int
    publish_time: int
    data: bytes


def listed_files(bag) -> tuple[list[Path], list[str]]:
    """The ``.mcap`` files of a bag in order, and the names ``metadata.yaml`` lists that are not
    there (a split bag has several files: ``relative_file_paths``; without a usable list, every
    ``NAME_<i>.mcap`` by index). A file path gives itself and nothing missing.

    Every file returned is a regular file (or a symbolic link to one): a bag file, a listed file
    or ``metadata.yaml`` that is a FIFO, a device or a socket (or a link to one) raises
    :class:`~magtune_core.base.errors.ConfigError` naming it, before anything is opened (a FIFO
    would block every reader, ``/dev/zero`` never ends).

    Returns
    -------
    tuple
        (present files, missing file names); FileNotFoundError when no file is there at all.
    """
    p = Path(bag)
    check_path(p)  # a symbolic link loop: one line, as for every other file argument
    if p.exists() and not p.is_dir():
        is_regular_file(p)  # ConfigError for a FIFO, a device, a link to one
        return [p], []
    listed: list[str] = []
    if is_regular_file(p / "metadata.yaml"):
        try:
            listed = [str(f) for f in (read_metadata(p).get("relative_file_paths") or [])]
        except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError, UnicodeDecodeError):
            listed = []
    if listed:
        there = {f for f in listed if _listed_file(p, f)}
        present = [p / f for f in listed if f in there]
        missing = [f for f in listed if f not in there]
        if present:
            return present, missing
    cands = [f for f in p.glob("*.mcap") if is_regular_file(f)]  # a dangling link is not there
    if not cands:
        raise FileNotFoundError(f"no .mcap file in {p}" + (f" (metadata.yaml lists {', '.join(listed)})" if listed else ""))

    def index(f: Path):
        tail = f.stem.rpartition("_")[2]
        return (0, int(tail), f.name) if tail.isdigit() else (1, 0, f.name)
    return sorted(cands, key=index), listed


def _listed_file(bag_dir: Path, name: str) -> bool:
    """Whether the file ``metadata.yaml`` lists as ``name`` is there (a regular file); ConfigError
    for anything else there (a FIFO, a device, a directory, a link to one)."""
    try:
        return is_regular_file(bag_dir / name)
    except ConfigError:
        raise
    except ValueError:  # a name holding a NUL byte: nothing can be there
        return False


def resolve_mcaps(bag) -> list[Path]:
    """Every ``.mcap`` file of a bag that is there, in order (:func:`listed_files`)."""
    return listed_files(bag)[0]


def resolve_mcap(bag) -> Path:
    """The first ``.mcap`` file of a bag directory (or the file itself)."""
    return resolve_mcaps(bag)[0]


def has_summary(mcap_path: Path) -> bool:
    """True if the file ends with a valid footer + magic (i.e. was closed cleanly)."""
    try:
        with open_regular(mcap_path) as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # noqa: BLE001 - any parse failure means: not a complete file
        return False


