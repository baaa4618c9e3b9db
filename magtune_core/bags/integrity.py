"""Integrity of a whole bag: every file of a split bag, and metadata.yaml against the files.

:func:`.scan.scan` checks one file. A bag directory is complete only if, besides each of its
files being complete, every file ``metadata.yaml`` lists is there and ``metadata.yaml``'s counts
(``message_count``, each topic's and each file's ``message_count``) agree with what the files
hold. :func:`bag_report` merges the per-file scan summaries into one report with these checks;
``bag info``, ``replay``, ``report`` and ``bag recover`` all read a bag's integrity from it.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from .layout import read_metadata

#: Keys summed over the files of a split bag.
_SUMMED = ("messages_recovered", "messages_in_damaged_chunks", "chunks_ok", "valid_bytes",
           "unreadable_tail_bytes", "skipped_bytes", "orphan_messages")


def bag_metadata(bag) -> dict | None:
    """``rosbag2_bagfile_information`` of a bag directory; None for a lone file or an unreadable
    metadata.yaml (what can be read of the files is then all there is to compare)."""
    p = Path(bag)
    if not p.is_dir():
        return None
    try:
        meta = read_metadata(p)
    except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError, UnicodeDecodeError):
        return None
    return meta if isinstance(meta, dict) else None


def _count(v) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def metadata_disagreements(meta: dict | None, per_topic: dict, per_file: dict) -> list[str]:
    """Where ``metadata.yaml`` (``meta``) and the files disagree, one line each.

    ``per_topic``: topic -> messages the files hold; ``per_file``: file name -> messages it
    holds (files that are there). A provisional metadata.yaml (no topics, 0 messages: the
    recorder never finished) is one line.

    Returns
    -------
    list of str
        empty when every count agrees (or there is no metadata.yaml).
    """
    if not meta:
        return []
    total = sum(per_topic.values())
    topics = meta.get("topics_with_message_count") or []
    declared = _count(meta.get("message_count"))
    if not topics and not declared:
        return [] if not total else [f"metadata.yaml is provisional (0 messages, no topics: the recorder did not "
                                     f"finish); the files hold {total} messages"]
    out = []
    if declared is not None and declared != total:
        out.append(f"metadata.yaml message_count is {declared}, the files hold {total} "
                   f"({'missing ' + str(declared - total) if declared > total else str(total - declared) + ' more'})")
    for t in topics:
        name = ((t or {}).get("topic_metadata") or {}).get("name")
        n = _count((t or {}).get("message_count"))
        if name is not None and n is not None and n != per_topic.get(name, 0):
            out.append(f"metadata.yaml: topic {name} message_count is {n}, the files hold {per_topic.get(name, 0)}")
    for f in meta.get("files") or []:
        name, n = (f or {}).get("path"), _count((f or {}).get("message_count"))
        if name in per_file and n is not None and n != per_file[name]:
            out.append(f"metadata.yaml: file {name} message_count is {n}, it holds {per_file[name]}")
    return out


def expected_count(rep: dict) -> int:
    """Messages a file should hold: its summary's statistics, else readable plus indexed lost."""
    exp = rep.get("messages_expected")
    return int(exp) if exp is not None else int(rep.get("messages_recovered", 0)) + int(rep.get("messages_in_damaged_chunks", 0))


def bag_report(bag, files: list[Path], reports: list[dict], missing: list[str]) -> dict:
    """One integrity report for ``bag`` from the scan summaries (``reports``) of its ``files``
    and the names of the listed files that are ``missing``.

    A single file with nothing missing keeps its scan summary's keys; a split bag sums the
    counts, lists each file's summary under ``files`` (with its ``path``) and prefixes each
    ``problem`` with the file name. Both get ``missing_files``, ``metadata_disagreements``,
    ``metadata_message_count`` and ``complete`` (False if any file is damaged or missing or a
    count disagrees).

    Returns
    -------
    dict
        the merged report (JSON-able).
    """
    meta = bag_metadata(bag)
    per_topic: dict = {}
    for r in reports:
        for k, v in (r.get("per_topic") or {}).items():
            per_topic[k] = per_topic.get(k, 0) + v
    per_file = {Path(f).name: int(r.get("messages_recovered", 0)) for f, r in zip(files, reports)}
    disagree = metadata_disagreements(meta, per_topic, per_file)
    if len(reports) == 1 and not missing:
        rep = dict(reports[0])
    else:
        rep = {k: sum(int(r.get(k) or 0) for r in reports) for k in _SUMMED}
        listed = {(f or {}).get("path"): _count((f or {}).get("message_count")) for f in (meta or {}).get("files") or []}
        rep["messages_expected"] = sum(expected_count(r) for r in reports) + sum(listed.get(m) or 0 for m in missing)
        rep["per_topic"] = dict(sorted(per_topic.items()))
        rep["chunks_bad"] = [dict(c, file=Path(f).name) for f, r in zip(files, reports) for c in r.get("chunks_bad") or []]
        rep["footer_found"] = all(r.get("footer_found", True) for r in reports)
        problems = [f"{Path(f).name}: {r['problem']}" for f, r in zip(files, reports) if r.get("problem")]
        rep["problem"] = "; ".join(problems)
        rep["files"] = [dict(r, path=str(f)) for f, r in zip(files, reports)]
        rep["complete"] = all(r.get("complete", True) for r in reports)
    rep["missing_files"] = list(missing)
    rep["metadata_disagreements"] = disagree
    rep["metadata_message_count"] = _count((meta or {}).get("message_count"))
    rep["complete"] = bool(rep.get("complete", True)) and not missing and not disagree
    return rep


def unreadable_report(path, exc: Exception) -> dict:
    """The scan summary of a file of a split bag that cannot be read at all (empty, no MCAP
    record): nothing recovered, the reason as its ``problem``; the other files are still read."""
    reason = getattr(exc, "expected", None) or str(exc)
    return {"complete": False, "messages_recovered": 0, "messages_expected": None, "messages_in_damaged_chunks": 0,
            "per_topic": {}, "chunks_ok": 0, "chunks_bad": [], "footer_found": False, "read_through_index": False,
            "valid_bytes": 0, "unreadable_tail_bytes": Path(path).stat().st_size if Path(path).exists() else 0,
            "skipped_bytes": 0, "orphan_messages": 0, "problem": f"unreadable ({reason})"}


def problem_lines(rep: dict) -> list[str]:
    """The bag-level problems of a :func:`bag_report`: missing files and count disagreements."""
    out = [f"{m}: listed in metadata.yaml but missing (its messages are lost; the bag is not complete)"
           for m in rep.get("missing_files") or []]
    return out + list(rep.get("metadata_disagreements") or [])


def integrity_lines(integ: dict) -> list[str]:
    """One line per integrity problem of a bag's integrity report (:func:`bag_report`):
    each file of a split bag (its lines prefixed with its name), then missing files and
    metadata.yaml's counts that disagree with the files."""
    if "files" in integ:
        lines = [f"{Path(part['path']).name}: {line}" for part in integ["files"] for line in _file_lines(part)]
    else:
        lines = _file_lines(integ)
    return lines + problem_lines(integ)


def _file_lines(integ: dict) -> list[str]:
    """One line per integrity problem of one file's scan summary."""
    out = []
    for c in integ.get("chunks_bad") or []:
        held = "unknown number of" if c.get("messages") is None else str(c["messages"])
        span = (f", log time {c['start_ns'] * 1e-9:.3f}..{c['end_ns'] * 1e-9:.3f} s"
                if c.get("start_ns") is not None else "")
        out.append(f"damaged chunk at byte {c['offset']} ({held} messages{span}): {c['reason']}")
    if integ.get("problem"):
        out.append(integ["problem"])
    if integ.get("unreadable_tail_bytes"):
        out.append(f"{integ['unreadable_tail_bytes']} bytes at the end are unreadable (no summary)")
    if integ.get("orphan_messages"):
        out.append(f"{integ['orphan_messages']} messages belong to a channel whose definition was lost")
    return out
