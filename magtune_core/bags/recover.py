"""Rewrite a damaged or unfinished bag as a clean one from what :func:`.scan.scan` reads.

:func:`recover` rewrites the bag directory: a complete MCAP (summary, statistics, indexes) and a
``metadata.yaml`` with the recovered counts.
"""
from __future__ import annotations

import os
from pathlib import Path

from mcap.writer import CompressionType, Writer

from .layout import LIBRARY, build_metadata, mcap_file_name, read_metadata, resolve_mcap, write_metadata
from .scan import scan


def recover(bag_dir, *, keep_original: bool = False, chunk_size: int = 1 << 20) -> dict:
    """Rewrite a damaged bag from what :func:`scan` reads; returns the scan report.

    The MCAP is rewritten in log-time order with a full summary; ``metadata.yaml`` is rebuilt
    from the recovered messages (``custom_data`` of an existing metadata.yaml is kept). With
    ``keep_original`` the damaged file is kept as ``<name>.damaged``.
    """
    bag_dir = Path(bag_dir)
    src = resolve_mcap(bag_dir)
    res = scan(src)
    custom = {}
    try:
        custom = read_metadata(bag_dir).get("custom_data") or {}
    except Exception:  # noqa: BLE001 - missing/broken metadata.yaml is what we repair
        pass
    dst = bag_dir / mcap_file_name(bag_dir)
    tmp = dst.with_suffix(".mcap.tmp")
    with open(tmp, "wb") as f:
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
    if keep_original and src == dst:
        os.replace(src, src.with_name(src.name + ".damaged"))
    os.replace(tmp, dst)
    if src != dst and src.exists() and not keep_original:
        src.unlink()
    topics = list(res.topics.values())
    write_metadata(bag_dir, build_metadata(bag_dir, topics, res.start_ns, res.end_ns, custom))
    return res.summary()
