"""Rebuild a damaged or unfinished bag from what :func:`.scan.scan` reads, without losing anything.

Rules (each one a lesson from a probe that lost data):

* the input is **never modified**: the recovered bag is a new bag directory beside it
  (``bags/NAME`` -> ``bags/NAME_recovered``), or, only with ``in_place=True``, the rebuilt MCAP
  and ``metadata.yaml`` replace the originals while the damaged file is kept as
  ``NAME_0.mcap.damaged`` (never deleted);
* a cleanly closed file is read through its summary's chunk index (a damaged record costs at
  most its own chunk), a file without summary sequentially with resynchronisation past damaged
  records; every message of every chunk whose CRC is good is kept;
* only MCAP storage is handled: a bag whose ``metadata.yaml`` names another
  ``storage_identifier`` (e.g. ``sqlite3``) is refused with one line, before anything is written;
* nothing readable (empty file, no MCAP record found) is an error, never an empty "recovered" bag;
* the report says how many messages were recovered and how many were expected (summary
  statistics, else the recovered ones plus those listed by the damaged chunks' indexes).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from ..base.errors import ConfigError
from .layout import LIBRARY, STORAGE_ID, build_metadata, mcap_file_name, read_metadata, resolve_mcap, write_metadata
from .scan import scan

SUFFIX = "_recovered"


def storage_of(bag_dir: Path) -> str | None:
    """``storage_identifier`` of a bag directory's metadata.yaml (None if absent/unreadable)."""
    try:
        return str(read_metadata(bag_dir).get("storage_identifier") or "") or None
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        return None


def check_storage(bag) -> tuple[Path, Path]:
    """(bag directory, its .mcap file) of an MCAP bag; ConfigError for any other storage."""
    p = Path(bag)
    if not p.exists():
        raise ConfigError(p, None, "no such bag (expected a bag directory or an .mcap file)")
    bag_dir = p if p.is_dir() else p.parent
    sid = storage_of(bag_dir) if p.is_dir() else None
    if sid is not None and sid != STORAGE_ID:
        raise ConfigError(p, None, f"storage '{sid}' is not supported: only MCAP bags can be recovered "
                                   f"(convert with 'ros2 bag convert'; the bag was left untouched)")
    if p.is_dir() and not any(p.glob("*.mcap")) and any(p.glob("*.db3")):
        raise ConfigError(p, None, "sqlite3 (.db3) bag: only MCAP bags can be recovered (the bag was left untouched)")
    try:
        return bag_dir, resolve_mcap(p)
    except FileNotFoundError as exc:
        raise ConfigError(p, None, f"{exc} (expected a rosbag2 MCAP bag)") from None


def default_output(bag) -> Path:
    """``bags/NAME`` -> ``bags/NAME_recovered`` (``x.mcap`` -> ``x_recovered``)."""
    p = Path(bag)
    return p.parent / f"{p.name if p.is_dir() else p.stem}{SUFFIX}"


def recover(bag, out=None, *, in_place: bool = False, chunk_size: int = 1 << 20) -> dict:
    """Rebuild ``bag`` (directory or .mcap) from every intact chunk (see module doc).

    ``out``: new bag directory (default ``<bag>_recovered`` beside it; must not exist or be
    empty). ``in_place``: replace the bag's MCAP and metadata.yaml, keeping the damaged file as
    ``<file>.damaged``.

    Returns
    -------
    dict
        The scan report (:meth:`~magtune_core.bags.scan.ScanResult.summary`) plus ``output``,
        ``messages_expected`` and ``original_kept`` (where the untouched input is).
    """
    bag_dir, src = check_storage(bag)
    if in_place and out is not None:
        raise ConfigError(bag, None, "give either an output directory or --in-place, not both")
    if not in_place:
        out = Path(out) if out is not None else default_output(bag)
        if out.resolve() == bag_dir.resolve() or out.resolve() == src.resolve():
            raise ConfigError(out, None, "the output must differ from the input (or use --in-place)")
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ConfigError(out, None, "output exists and is not an empty directory; choose another --output")
    res = scan(src)  # ConfigError for an empty / non-MCAP file
    if res.message_count == 0:
        raise ConfigError(src, None, "no readable message in the file; nothing written (the bag was left untouched)")
    custom = {}
    try:
        custom = read_metadata(bag_dir).get("custom_data") or {}
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        pass  # a missing or broken metadata.yaml is what we rebuild
    target = bag_dir if in_place else out
    target.mkdir(parents=True, exist_ok=True)
    dst = target / mcap_file_name(target)
    tmp = target / (dst.name + ".tmp")
    _write(res, tmp, chunk_size)
    kept = str(src)
    if in_place:
        kept = str(src.with_name(src.name + ".damaged"))
        os.replace(src, kept)
        meta = bag_dir / "metadata.yaml"
        if meta.exists():
            shutil.copy2(meta, bag_dir / "metadata.yaml.damaged")
    os.replace(tmp, dst)
    topics = list(res.topics.values())
    write_metadata(target, build_metadata(target, topics, res.start_ns, res.end_ns, custom))
    rep = res.summary()
    expected = res.expected if res.expected is not None else res.message_count + res.lost_known
    rep.update(output=str(target), messages_expected=expected, original_kept=kept)
    return rep


def _write(res, path: Path, chunk_size: int) -> None:
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library=LIBRARY + " (recovered)")
        schema_ids = {sid: w.register_schema(s.name, s.encoding, s.data)
                      for sid, s in sorted(res.schemas.items())}
        chan_ids = {}
        for cid, c in sorted(res.channels.items()):
            chan_ids[c.topic] = w.register_channel(c.topic, c.message_encoding,
                                                   schema_ids.get(c.schema_id, 0), dict(c.metadata))
        for m in sorted(res.messages, key=lambda m: m.log_time):
            w.add_message(chan_ids[m.topic], log_time=m.log_time, data=m.data,
                          publish_time=m.publish_time)
        w.finish()
        f.flush()
        os.fsync(f.fileno())
