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
  statistics, else the recovered ones plus those listed by the damaged chunks' indexes), and
  what metadata.yaml says (``messages_expected_metadata``);
* a **split bag** is recovered file by file: every listed file that is there is rebuilt (a
  damaged later file too), a listed file that is missing is named in the report; ``in_place``
  replaces only the damaged files, each kept as ``<file>.damaged`` (``.damaged.1``, ... if
  that name is taken: nothing is ever overwritten);
* a write error (disk full, quota) removes what was written (no ``.tmp`` left behind, no
  half-made output directory), so a retry after freeing space works.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

from ..base.atomic import atomic_output, output_entries
from ..base.errors import ConfigError
from ..base.paramfile import check_path
from .integrity import bag_metadata, bag_report, expected_count, unreadable_report
from .layout import LIBRARY, STORAGE_ID, build_metadata, listed_files, mcap_file_name, read_metadata, write_metadata
from .scan import scan

SUFFIX = "_recovered"


def storage_of(bag_dir: Path) -> str | None:
    """``storage_identifier`` of a bag directory's metadata.yaml (None if absent/unreadable)."""
    try:
        return str(read_metadata(bag_dir).get("storage_identifier") or "") or None
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError):
        return None


def check_storage(bag) -> tuple[Path, list[Path], list[str]]:
    """(bag directory, its .mcap files, names listed in metadata.yaml but missing) of an MCAP
    bag; ConfigError for any other storage."""
    p = Path(bag)
    check_path(p)
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
        files, missing = listed_files(p)
    except FileNotFoundError as exc:
        raise ConfigError(p, None, f"{exc} (expected a rosbag2 MCAP bag)") from None
    return bag_dir, files, missing


def default_output(bag) -> Path:
    """``bags/NAME`` -> ``bags/NAME_recovered`` (``x.mcap`` -> ``x_recovered``)."""
    p = Path(bag)
    return p.parent / f"{p.name if p.is_dir() else p.stem}{SUFFIX}"


def _check_output(bag, out, bag_dir: Path, files: list[Path]) -> Path:
    out = Path(out) if out is not None else default_output(bag)
    if out.resolve() == bag_dir.resolve() or any(out.resolve() == f.resolve() for f in files):
        raise ConfigError(out, None, "the output must differ from the input (or use --in-place)")
    if out.exists() and (not out.is_dir() or output_entries(out)):  # a lock file does not count
        raise ConfigError(out, None, "output exists and is not an empty directory; choose another --output")
    return out


def _scan_all(files: list[Path]) -> list:
    """(file, ScanResult or None, scan summary) per file; a file of a split bag that cannot be
    read at all is kept in the list with its reason (a single file raises, as before)."""
    out = []
    for f in files:
        try:
            res = scan(f)
        except ConfigError as exc:
            if len(files) == 1:
                raise
            out.append((f, None, unreadable_report(f, exc)))
            continue
        out.append((f, res, res.summary()))
    return out


def recover(bag, out=None, *, in_place: bool = False, chunk_size: int = 1 << 20) -> dict:
    """Rebuild ``bag`` (directory or .mcap; every file of a split bag) from every intact chunk
    (see module doc).

    ``out``: new bag directory (default ``<bag>_recovered`` beside it; must not exist or be
    empty), one rebuilt file per readable input file. ``in_place``: replace each damaged file
    of the bag and metadata.yaml, keeping the originals as ``<file>.damaged``. A write error
    (disk full) removes the partial output and raises OSError; the input is untouched and a
    retry works.

    Returns
    -------
    dict
        The bag's integrity report (:func:`.integrity.bag_report`) plus ``output``,
        ``messages_expected`` (what the files say they held, plus the metadata counts of missing
        files), ``messages_expected_metadata`` (metadata.yaml's ``message_count``),
        ``recovered_files`` and ``original_kept``.
    """
    bag_dir, files, missing = check_storage(bag)
    if in_place and out is not None:
        raise ConfigError(bag, None, "give either an output directory or --in-place, not both")
    if not in_place:
        out = _check_output(bag, out, bag_dir, files)
    scanned = _scan_all(files)  # ConfigError for an empty / non-MCAP single file
    if sum(r.message_count for _, r, _ in scanned if r is not None) == 0:
        where = files[0] if len(files) == 1 else bag
        raise ConfigError(where, None, "no readable message in the file; nothing written (the bag was left untouched)")
    # what the input holds and what its metadata.yaml says, before anything is rewritten
    rep = bag_report(bag_dir if Path(bag).is_dir() else files[0], files, [d for _, _, d in scanned], missing)
    listed = {f.get("path"): f.get("message_count") for f in (bag_metadata(bag_dir) or {}).get("files") or []}
    custom = {}
    try:
        custom = read_metadata(bag_dir).get("custom_data") or {}
    except (OSError, KeyError, TypeError, AttributeError, yaml.YAMLError, UnicodeDecodeError):
        pass  # a missing or broken metadata.yaml is what we rebuild
    if in_place:
        stats, kept = _rebuild_in_place(bag_dir, scanned, chunk_size)
        target = bag_dir
    else:
        stats, kept, target = _rebuild_beside(out, scanned, chunk_size), str(bag_dir if Path(bag).is_dir() else files[0]), out
    topics = _topics([r for _, r, _ in scanned if r is not None])
    kept_files = [r for _, r, _ in scanned if r is not None and r.message_count] if not in_place else \
        [r for f, r, _ in scanned if r is not None and (target / f.name).is_file()]
    start = min((r.start_ns for r in kept_files if r.message_count), default=0)
    end = max((r.end_ns for r in kept_files if r.message_count), default=0)
    write_metadata(target, build_metadata(target, topics, start, end, custom, stats if len(stats) > 1 else
                                          [s["path"] for s in stats]))
    rep.update(output=str(target), original_kept=kept, recovered_files=[s["path"] for s in stats],
               messages_expected=sum(expected_count(d) for _, _, d in scanned) + sum(int(listed.get(m) or 0) for m in missing),
               messages_expected_metadata=rep.get("metadata_message_count"))
    return rep


def _topics(results) -> list:
    """The topics of every scanned file, counts summed (first file's QoS and type)."""
    out: dict = {}
    for r in results:
        for name, t in r.topics.items():
            if name in out:
                out[name].message_count += t.message_count
            else:
                out[name] = t
    return list(out.values())


def _stat(name: str, res) -> dict:
    return {"path": name, "start_ns": res.start_ns, "end_ns": res.end_ns, "count": res.message_count}


def _rebuild_beside(out: Path, scanned: list, chunk_size: int) -> list:
    """One rebuilt file per input file with readable messages into the new bag ``out``; on any
    error the files written so far and ``out`` itself (if it was created here) are removed."""
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    stats: list = []
    try:
        for _, res, _ in scanned:
            if res is None or not res.message_count:
                continue
            name = mcap_file_name(out, len(stats))
            _write(res, out / name, chunk_size)
            stats.append(_stat(name, res))
    except BaseException:
        for s in stats:
            (out / s["path"]).unlink(missing_ok=True)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    return stats


def _keep_name(path: Path) -> Path:
    """``<file>.damaged`` beside ``path``, or ``.damaged.1``, ... if that exists (never overwritten)."""
    cand, i = path.with_name(path.name + ".damaged"), 0
    while cand.exists() or cand.is_symlink():
        i += 1
        cand = path.with_name(f"{path.name}.damaged.{i}")
    return cand


def _rebuild_in_place(bag_dir: Path, scanned: list, chunk_size: int) -> tuple[list, str]:
    """Replace every damaged file of the bag by its rebuilt version, the original kept under
    :func:`_keep_name` (a hard link made before the atomic rename, so the original is never
    absent); a file with nothing readable is renamed to its ``.damaged`` name and left out of
    metadata.yaml. Complete files are not touched. Returns (file stats, kept originals)."""
    stats, kept = [], []
    meta = bag_dir / "metadata.yaml"
    for src, res, _ in scanned:
        if res is not None and res.complete:
            stats.append(_stat(src.name, res))
            continue
        keep = _keep_name(src)
        if res is None or not res.message_count:
            os.rename(src, keep)
            kept.append(str(keep))
            continue
        tmp = src.with_name(f".{src.name}.rebuilt")
        _write(res, tmp, chunk_size)  # atomic: nothing left on failure
        try:
            try:
                os.link(src, keep)
            except OSError:
                shutil.copy2(src, keep)
            os.replace(tmp, src)
        finally:
            tmp.unlink(missing_ok=True)
        kept.append(str(keep))
        stats.append(_stat(src.name, res))
    if meta.exists() and kept:
        shutil.copy2(meta, _keep_name(meta))
    return stats, ", ".join(kept) or "(no file needed rebuilding)"


def _write(res, path: Path, chunk_size: int) -> None:
    """The messages of ``res`` as a new, cleanly closed MCAP at ``path`` (atomically)."""
    with atomic_output(path, "wb") as f:
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
