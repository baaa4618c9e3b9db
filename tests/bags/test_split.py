"""Split bags (rosbag2's --max-bag-size / --max-bag-duration) written by BagWriter: every file is
a complete MCAP, metadata.yaml lists them with their own stats, and the readers (ours, rosbags,
mcap) see one bag."""
from __future__ import annotations

import struct

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from magtune_core import bags

N = 400
DT = 50_000_000   # 0.05 s


def _clock(t: int) -> bytes:
    """CDR of rosgraph_msgs/Clock (little endian header, int32 sec, uint32 nanosec)."""
    return b"\x00\x01\x00\x00" + struct.pack("<iI", t // 10**9, t % 10**9)


@pytest.mark.parametrize("kw, files", [
    ({"max_duration_ns": 5 * 10**9}, 4),            # 20 s of log time in 5 s files
    ({"max_bytes": 3000, "chunk_size": 1024}, None),  # size checked at chunk boundaries
])
def test_split_files_are_complete_and_read_as_one_bag(tmp_path, kw, files):
    out = tmp_path / "run"
    with bags.BagWriter(out, compression="none", **kw) as w:
        w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        for k in range(N):
            w.write("/clock", _clock(k * DT), k * DT)
    paths = bags.resolve_mcaps(out)
    assert [p.name for p in paths] == [f"run_{i}.mcap" for i in range(len(paths))]
    assert len(paths) == files if files else len(paths) > 2
    for p in paths:
        with open(p, "rb") as f:
            assert make_reader(f).get_summary() is not None       # each file closed with its summary
    meta = bags.read_metadata(out)
    assert meta["relative_file_paths"] == [p.name for p in paths]
    assert sum(f["message_count"] for f in meta["files"]) == meta["message_count"] == N
    assert meta["files"][0]["starting_time"]["nanoseconds_since_epoch"] == 0
    if files:
        assert [f["message_count"] for f in meta["files"]] == [100] * 4
    assert [m.log_time for m in bags.iter_messages(out)] == [k * DT for k in range(N)]
    assert bags.topics_of(out)["/clock"].message_count == N
    inf = bags.info(out)
    assert inf["message_count"] == N and len(inf["files"]) == len(paths) and inf["complete"]
    assert inf["end_utc"] == "1970-01-01T00:00:19.950+00:00"
    with AnyReader([out]) as r:
        assert sum(1 for _ in r.messages()) == N
