"""Reading bags: messages in time order, topics, summary (damaged files through :mod:`.scan`)."""
from __future__ import annotations

import heapq
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterator

import yaml
from mcap.reader import make_reader

from ..base.errors import ConfigError
from ..base.paramfile import open_regular
from .integrity import bag_metadata, bag_report, unreadable_report
from .layout import STORAGE_ID, BagMessage, TopicInfo, has_summary, listed_files, read_metadata, resolve_mcap, resolve_mcaps
from .scan import scan
from .timing import TimingCheck, has_header


def iter_messages(bag, topics=None, start_ns: int | None = None, report: dict | None = None,
                  order: str = "log") -> Iterator[BagMessage]:
    """Messages of a bag in log-time order (``order="publish"``: by publish time, ties in
    log-time order; ``start_ns`` then applies to publish times).

    Every chunk is CRC-checked (:func:`magtune_core.bags.scan.scan`, through the chunk index of
    a cleanly closed file, sequentially otherwise); the messages of every intact chunk are
    returned and ``report`` (if a dict) receives the integrity summary: ``complete`` and, for a
    damaged file, which chunks are damaged and how many messages they held. An empty or
    non-MCAP file raises :class:`~magtune_core.base.errors.ConfigError`.
    """
    if order == "publish":
        msgs = sorted(iter_messages(bag, topics, None, report), key=lambda m: m.publish_time)
        yield from (m for m in msgs if start_ns is None or m.publish_time >= start_ns)
        return
    if order != "log":
        raise ValueError(f"order must be 'log' or 'publish', not {order!r}")
    files, missing = listed_files(bag)
    if len(files) > 1 or missing or Path(bag).is_dir():
        # a bag directory (split or not): the files' streams merged by log time (stable: file
        # order on ties); the report checks every listed file and metadata.yaml's counts
        reports = [{} for _ in files]
        streams = [iter_messages(f, topics, start_ns, r) for f, r in zip(files, reports)] if len(files) == 1 else \
            [_tolerant(f, topics, start_ns, r) for f, r in zip(files, reports)]
        yield from heapq.merge(*streams, key=lambda m: m.log_time)
        if report is not None:
            report.update(bag_report(bag, files, reports, missing))
        return
    path = files[0]
    wanted = set(topics) if topics is not None else None
    if wanted is not None and not wanted:
        if report is not None:
            report.update(scan(path, topics=wanted).summary())
        return
    res = scan(path, topics=wanted)
    if report is not None:
        report.update(res.summary())
    msgs = [m for m in res.messages if start_ns is None or m.log_time >= start_ns]
    msgs.sort(key=lambda m: m.log_time)  # stable: file order within equal times
    yield from msgs


def ties_in_topic_order(messages, topics, order: str = "log") -> Iterator[BagMessage]:
    """``messages`` (time-ordered) with each run of equal times reordered by the rank of its topic in
    ``topics`` (stable otherwise). A recorder receives two topics of one sim instant in either order (separate
    DDS readers), so a bag cannot say which was published first; a replay that must give a node its field
    before its attitude sample, as the sensors node publishes them, names the topics in that order.

    Parameters
    ----------
    messages : iterable of BagMessage
        In ``order`` time (:func:`iter_messages`).
    topics : sequence of str
        The topics by rank (a topic not listed goes last).
    order : {"log", "publish"}
        Which time makes a tie.

    Returns
    -------
    iterator of BagMessage
    """
    rank = {t: i for i, t in enumerate(topics)}
    run, t_run = [], None
    for m in messages:
        t = m.log_time if order == "log" else m.publish_time
        if run and t != t_run:
            yield from sorted(run, key=lambda x: rank.get(x.topic, len(rank)))
            run = []
        run.append(m)
        t_run = t
    yield from sorted(run, key=lambda x: rank.get(x.topic, len(rank)))


def _tolerant(path, topics, start_ns, report: dict) -> Iterator[BagMessage]:
    """The messages of one file of a split bag; a file that cannot be read at all is reported
    (:func:`.integrity.unreadable_report`) and the other files are still read."""
    try:
        yield from iter_messages(path, topics, start_ns, report)
    except ConfigError as exc:
        report.clear()
        report.update(unreadable_report(path, exc))


def topics_of(bag) -> dict[str, TopicInfo]:
    """Topics (name -> :class:`TopicInfo` with counts) from the MCAP itself."""
    files = resolve_mcaps(bag)
    if len(files) > 1:   # split bag: counts summed over the files
        out: dict[str, TopicInfo] = {}
        for f in files:
            try:
                found = topics_of(f)
            except ConfigError:  # an unreadable file of a split bag: reported by the integrity check
                continue
            for name, t in found.items():
                if name in out:
                    out[name].message_count += t.message_count
                else:
                    out[name] = t
        return out
    path = resolve_mcap(bag)
    if has_summary(path):
        with open_regular(path) as f:
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


def info(bag, ts: float | None = None) -> dict:
    """Summary of a bag for ``magtune bag info``: counts, times, topics, integrity, timing, and as
    ``ros2 bag info``: start/end as UTC dates, storage id, ROS distro, every file of a split bag.

    ``ts`` (s): tolerance of the timing check (default: ``ts`` of metadata.yaml custom_data,
    else the /clock period).

    Returns
    -------
    dict
        path, complete, size, counts, times, chunks, topics, ``integrity`` (the scan summary:
        damaged chunks and the messages they held; per file for a split bag) and ``timing``
        (:meth:`magtune_core.bags.timing.TimingCheck.report`: /clock gaps, log time vs stamp, over
        all files), ``start_utc``/``end_utc``, ``storage_identifier``, ``ros_distro``, ``files``.
    """
    files, missing = listed_files(bag)
    if ts is None:
        ts = _metadata_ts(bag)
    check = TimingCheck()
    parts, stamped = [], set()
    for f in files:
        try:
            res = scan(f, visit=lambda m: check.add(m.topic, m.log_time, m.data))
        except ConfigError as exc:
            if len(files) == 1:
                raise
            parts.append({"path": str(f), "complete": False, "size_bytes": f.stat().st_size, "message_count": 0,
                          "start_ns": 0, "end_ns": 0, "chunks": 0, "integrity": unreadable_report(f, exc), "topics": {}})
            continue
        stamped.update(_stamped_topics(res))
        parts.append({"path": str(f), "complete": res.complete, "size_bytes": f.stat().st_size,
                      "message_count": res.message_count, "start_ns": res.start_ns, "end_ns": res.end_ns,
                      "chunks": res.chunks_ok, "integrity": res.summary(), "topics": res.topics})
    integ = bag_report(bag, files, [p["integrity"] for p in parts], missing)
    for d in [integ] + integ.get("files", []) + [p["integrity"] for p in parts]:
        d.pop("per_topic", None)
    used = [p for p in parts if p["message_count"]]
    count = sum(p["message_count"] for p in parts)
    start = min((p["start_ns"] for p in used), default=0)
    end = max((p["end_ns"] for p in used), default=0)
    topics: dict = {}
    for p in parts:
        for n, t in p["topics"].items():
            e = topics.setdefault(n, {"type": t.type, "count": 0})
            e["count"] += t.message_count
    meta = bag_metadata(bag) or {}
    single = len(parts) == 1 and not missing
    return {"path": parts[0]["path"] if single else str(Path(bag)), "complete": integ["complete"],
            "size_bytes": sum(p["size_bytes"] for p in parts), "message_count": count, "start_ns": start,
            "end_ns": end, "duration_s": (end - start) / 1e9 if count else 0.0,
            "chunks": sum(p["chunks"] for p in parts), "topics": dict(sorted(topics.items())),
            "integrity": integ, "missing_files": integ["missing_files"],
            "metadata_disagreements": integ["metadata_disagreements"],
            "timing": check.report(ts, stamped),
            "storage_identifier": meta.get("storage_identifier", STORAGE_ID),
            "ros_distro": meta.get("ros_distro", ""),
            "start_utc": _utc(start) if count else "", "end_utc": _utc(end) if count else "",
            "files": [{"path": p["path"], "size_bytes": p["size_bytes"], "complete": p["complete"],
                       "message_count": p["message_count"], "start_ns": p["start_ns"], "end_ns": p["end_ns"]}
                      for p in parts]}


def _utc(ns: int) -> str:
    """ns since 1970 as an ISO 8601 UTC date (a sim-time bag starts at 1970-01-01)."""
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat(timespec="milliseconds")


def _metadata_ts(bag) -> float | None:
    p = Path(bag)
    try:
        v = float((read_metadata(p if p.is_dir() else p.parent).get("custom_data") or {}).get("ts"))
    except (OSError, KeyError, TypeError, ValueError, AttributeError, yaml.YAMLError):
        return None
    return v if v > 0 and v == v and v != float("inf") else None


def _stamped_topics(res) -> set[str]:
    """Topics whose type starts with a std_msgs/Header (from the schema text)."""
    out = set()
    for ch in res.channels.values():
        sc = res.schemas.get(ch.schema_id)
        if sc is not None and has_header(bytes(sc.data).decode(errors="replace")):
            out.add(ch.topic)
    return out
