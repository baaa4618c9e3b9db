"""Reading bags: messages in time order, topics, summary (damaged files through :mod:`.scan`)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import yaml
from mcap.reader import make_reader

from .layout import BagMessage, TopicInfo, has_summary, read_metadata, resolve_mcap
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
    path = resolve_mcap(bag)
    wanted = set(topics) if topics is not None else None
    if wanted is not None and not wanted:
        return
    res = scan(path, topics=wanted)
    if report is not None:
        report.update(res.summary())
    msgs = [m for m in res.messages if start_ns is None or m.log_time >= start_ns]
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
    return scan(path).topics


def info(bag, ts: float | None = None) -> dict:
    """Summary of a bag for ``magtune bag info``: counts, times, topics, integrity, timing.

    ``ts`` (s): tolerance of the timing check (default: ``ts`` of metadata.yaml custom_data,
    else the /clock period).

    Returns
    -------
    dict
        path, complete, size, counts, times, chunks, topics, ``integrity`` (the scan summary:
        damaged chunks and the messages they held) and ``timing``
        (:meth:`magtune_core.bags.timing.TimingCheck.report`: /clock gaps, log time vs stamp).
    """
    path = resolve_mcap(bag)
    if ts is None:
        ts = _metadata_ts(bag)
    check = TimingCheck()
    res = scan(path, visit=lambda m: check.add(m.topic, m.log_time, m.data))
    count, start, end = res.message_count, res.start_ns, res.end_ns
    integ = res.summary()
    integ.pop("per_topic", None)
    return {"path": str(path), "complete": res.complete, "size_bytes": path.stat().st_size,
            "message_count": count, "start_ns": start, "end_ns": end,
            "duration_s": (end - start) / 1e9 if count else 0.0, "chunks": res.chunks_ok,
            "topics": {n: {"type": t.type, "count": t.message_count}
                       for n, t in sorted(res.topics.items())},
            "integrity": integ, "timing": check.report(ts, _stamped_topics(res))}


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
