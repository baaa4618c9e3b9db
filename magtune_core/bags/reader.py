"""Reading bags: messages in time order, topics, summary (damaged files through :mod:`.scan`)."""
from __future__ import annotations

import heapq
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterator

import yaml
from mcap.reader import make_reader

from .layout import STORAGE_ID, BagMessage, TopicInfo, has_summary, read_metadata, resolve_mcap, resolve_mcaps
from .scan import scan


def iter_messages(bag, topics=None, start_ns: int | None = None, report: dict | None = None,
                  order: str = "log") -> Iterator[BagMessage]:
    """Messages of a bag in log-time order (``order="publish"``: by publish time, ties in
    log-time order; ``start_ns`` then applies to publish times).

    A cleanly closed file is read through its index. A truncated or corrupt file (no summary) is
    scanned sequentially; every complete, CRC-valid chunk is returned and ``report`` (if a dict)
    receives what was skipped (see :func:`magtune_core.bags.scan.scan`).
    """
    if order == "publish":
        msgs = sorted(iter_messages(bag, topics, None, report), key=lambda m: m.publish_time)
        yield from (m for m in msgs if start_ns is None or m.publish_time >= start_ns)
        return
    if order != "log":
        raise ValueError(f"order must be 'log' or 'publish', not {order!r}")
    files = resolve_mcaps(bag)
    if len(files) > 1:   # split bag: the files' streams merged by log time (stable: file order on ties)
        reports = [{} for _ in files]
        yield from heapq.merge(*(iter_messages(f, topics, start_ns, r) for f, r in zip(files, reports)),
                               key=lambda m: m.log_time)
        if report is not None:
            report.update({"complete": all(r.get("complete", True) for r in reports)})
            bad = [r for r in reports if not r.get("complete", True)]
            if bad:
                report.update({k: v for k, v in bad[0].items() if k != "complete"})
        return
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
    res = scan(path)
    if report is not None:
        report.update(res.summary())
    msgs = [m for m in res.messages if (wanted is None or m.topic in wanted)
            and (start_ns is None or m.log_time >= start_ns)]
    msgs.sort(key=lambda m: m.log_time)  # stable: file order within equal times
    yield from msgs


def topics_of(bag) -> dict[str, TopicInfo]:
    """Topics (name -> :class:`TopicInfo` with counts) from the MCAP itself."""
    files = resolve_mcaps(bag)
    if len(files) > 1:   # split bag: counts summed over the files
        out: dict[str, TopicInfo] = {}
        for f in files:
            for name, t in topics_of(f).items():
                if name in out:
                    out[name].message_count += t.message_count
                else:
                    out[name] = t
        return out
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
    return scan(path).topics


def info(bag) -> dict:
    """Summary of a bag for ``magtune bag info``: counts, times, topics, integrity, and as
    ``ros2 bag info``: start/end as UTC dates, storage id, ROS distro, every file of a split bag."""
    files = resolve_mcaps(bag)
    parts = [_file_info(f) for f in files]
    count = sum(p["message_count"] for p in parts)
    used = [p for p in parts if p["message_count"]]
    start = min((p["start_ns"] for p in used), default=0)
    end = max((p["end_ns"] for p in used), default=0)
    meta = {}
    if Path(bag).is_dir():
        try:
            meta = read_metadata(Path(bag))
        except (OSError, KeyError, TypeError, ValueError):
            meta = {}
    out = dict(parts[0]) if len(parts) == 1 else {
        "path": str(Path(bag)), "complete": all(p["complete"] for p in parts),
        "size_bytes": sum(p["size_bytes"] for p in parts), "message_count": count, "start_ns": start,
        "end_ns": end, "duration_s": (end - start) / 1e9 if count else 0.0,
        "chunks": sum(p["chunks"] for p in parts),
        "topics": {n: {"type": t.type, "count": t.message_count} for n, t in sorted(topics_of(bag).items())}}
    out.update({"storage_identifier": meta.get("storage_identifier", STORAGE_ID),
                "ros_distro": meta.get("ros_distro", ""),
                "start_utc": _utc(out["start_ns"]) if out["message_count"] else "",
                "end_utc": _utc(out["end_ns"]) if out["message_count"] else "",
                "files": [{"path": p["path"], "size_bytes": p["size_bytes"], "complete": p["complete"],
                           "message_count": p["message_count"], "start_ns": p["start_ns"], "end_ns": p["end_ns"]}
                          for p in parts]})
    return out


def _utc(ns: int) -> str:
    """ns since 1970 as an ISO 8601 UTC date (a sim-time bag starts at 1970-01-01)."""
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat(timespec="milliseconds")


def _file_info(bag) -> dict:
    """:func:`info` of one MCAP file."""
    path = resolve_mcap(bag)
    complete = has_summary(path)
    if complete:
        with open(path, "rb") as f:
            s = make_reader(f).get_summary()
        st = s.statistics
        start, end, count = st.message_start_time, st.message_end_time, st.message_count
        chunks = st.chunk_count
    else:
        res = scan(path)
        start, end, count = res.start_ns, res.end_ns, res.message_count
        chunks = res.chunks_ok
    return {"path": str(path), "complete": complete, "size_bytes": path.stat().st_size,
            "message_count": count, "start_ns": start, "end_ns": end,
            "duration_s": (end - start) / 1e9 if count else 0.0, "chunks": chunks,
            "topics": {n: {"type": t.type, "count": t.message_count}
                       for n, t in sorted(topics_of(path).items())}}
