"""Reading bags: messages in time order, topics, summary (damaged files through :mod:`.scan`)."""
from __future__ import annotations

from typing import Iterator

import yaml
from mcap.reader import make_reader

from .layout import BagMessage, TopicInfo, has_summary, resolve_mcap
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
        res = scan(path)
        start, end, count = res.start_ns, res.end_ns, res.message_count
        chunks = res.chunks_ok
    return {"path": str(path), "complete": complete, "size_bytes": path.stat().st_size,
            "message_count": count, "start_ns": start, "end_ns": end,
            "duration_s": (end - start) / 1e9 if count else 0.0, "chunks": chunks,
            "topics": {n: {"type": t.type, "count": t.message_count}
                       for n, t in sorted(topics_of(path).items())}}
