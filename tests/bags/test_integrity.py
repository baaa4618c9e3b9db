"""Bag integrity and loss-free recovery, each case a probe of issue #10 that used to lose data.

Damage is made by hand at byte offsets taken from the file's own chunk index, so each test knows
exactly which chunk is hit and how many messages it held (from the index, independently of the
scanner). Values are exact: a recovered message is byte-identical to the recorded one.
"""
from __future__ import annotations

import hashlib
import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from rosbags.highlevel import AnyReader

from magtune_core import bags as bag
from magtune_core.bags import recover as bag_recover
from magtune_core.bags import scan as bag_scan
from magtune_core.bags.decode import Decoder
from magtune_core.base.errors import ConfigError
from magtune_core.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]
N = 300  # steps written by _write: N /clock + N /imu messages


def _write(tmp_path: Path, name="run", n=N, chunk_size=2048, stamp_offset_ns=0, skip_clock=()) -> Path:
    d = Decoder()
    T = d.types()
    w = bag.BagWriter(tmp_path / name, chunk_size=chunk_size, custom_data={"sigma": 60, "ts": 1.0})
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for i in range(n):
        t_ns = (i + 10) * 1_000_000_000  # starts at 10 s: room for a negative offset
        if i not in skip_clock:
            w.write("/clock", d.encode(T["rosgraph_msgs/msg/Clock"](
                clock=T["builtin_interfaces/msg/Time"](sec=i + 10, nanosec=0)), "rosgraph_msgs/msg/Clock"), t_ns)
        v = T["geometry_msgs/msg/Vector3"]
        imu = T["sensor_msgs/msg/Imu"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=i + 10, nanosec=0),
                                            frame_id="body"),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9), angular_velocity=v(x=1e-3 * i, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=v(x=0.0, y=0.0, z=0.0),
            linear_acceleration_covariance=np.zeros(9))
        w.write("/imu", d.encode(imu, "sensor_msgs/msg/Imu"), t_ns + stamp_offset_ns)
    w.close()
    return tmp_path / name


def _chunks(f: Path):
    with open(f, "rb") as fh:
        s = make_reader(fh).get_summary()
    return sorted(s.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _messages_in(data: bytes, ci) -> int:
    body = data[ci.chunk_start_offset + 9: ci.chunk_start_offset + ci.chunk_length]
    return sum(isinstance(r, Message) for r in breakup_chunk(Chunk.read(ReadDataStream(io.BytesIO(body)))))


def _digest(p: Path) -> dict:
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(p.iterdir())}


def _all(p) -> list:
    return [(m.topic, m.log_time, m.data) for m in bag.iter_messages(p)]


def test_damaged_chunk_length_field_loses_nothing(tmp_path):
    """Why #1: one corrupted byte in a chunk's length field kept 5 % and overwrote the input.
    Through the chunk index (summary present) and by the chunk's inner lengths (summary cut
    off), every message is kept; the input directory is byte-identical afterwards."""
    p = _write(tmp_path)
    ref = _all(p)
    f = bag.resolve_mcap(p)
    data = bytearray(f.read_bytes())
    victim = _chunks(f)[3]
    data[victim.chunk_start_offset + 1 + 5] ^= 0x40   # high byte of the uint64 length
    f.write_bytes(bytes(data))
    before = _digest(p)
    rep = bag_recover.recover(p)
    assert _digest(p) == before                        # input untouched
    out = Path(rep["output"])
    assert out == tmp_path / "run_recovered"
    assert rep["messages_recovered"] == rep["messages_expected"] == 2 * N
    assert _all(out) == ref
    with AnyReader([out]) as r:                         # an independent reader agrees
        assert sum(1 for _ in r.messages()) == 2 * N
    # without the summary: sequential scan, the chunk delimited by its inner lengths
    f.write_bytes(bytes(data[: _chunks_end(data)]))
    res = bag_scan.scan(f)
    assert res.message_count == 2 * N and not res.chunks_bad


def _chunks_end(data: bytearray) -> int:
    # end of the data section: the DATA_END record (opcode 0x0f) precedes the summary
    i = len(data) - 1
    pos = data.rfind(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")
    assert 0 < pos < i
    return pos


def test_damaged_magic_is_recovered_not_emptied(tmp_path):
    """Why #1: a damaged magic replaced the bag with an empty one and rewrote metadata.yaml to
    0 messages (exit 0). Now: resynchronised, everything recovered beside the input."""
    p = _write(tmp_path)
    ref = _all(p)
    f = bag.resolve_mcap(p)
    data = bytearray(f.read_bytes())
    data[1:5] = b"XXXX"
    f.write_bytes(bytes(data))
    before = _digest(p)
    rep = bag_recover.recover(p)
    assert _digest(p) == before
    assert rep["messages_recovered"] == 2 * N and "bad magic" in rep["problem"]
    assert _all(rep["output"]) == ref


def test_sqlite3_bag_is_refused_untouched(tmp_path):
    """Why #1: a rosbag2 sqlite3 bag was deleted and replaced by an empty MCAP."""
    p = tmp_path / "old"
    p.mkdir()
    (p / "old_0.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    (p / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n"
                                     "  relative_file_paths: [old_0.db3]\n")
    before = _digest(p)
    with pytest.raises(ConfigError, match="storage 'sqlite3' is not supported"):
        bag_recover.recover(p)
    assert cli_main(["bag", "recover", str(p)]) == 2
    assert _digest(p) == before and not (tmp_path / "old_recovered").exists()


def test_in_place_keeps_the_damaged_original(tmp_path):
    p = _write(tmp_path)
    f = bag.resolve_mcap(p)
    orig = f.read_bytes()
    f.write_bytes(orig[: len(orig) * 6 // 10])          # SIGKILL-like truncation
    cut = f.read_bytes()
    rep = bag_recover.recover(p, in_place=True)
    assert (p / (f.name + ".damaged")).read_bytes() == cut
    assert bag.has_summary(f) and bag.read_metadata(p)["message_count"] == rep["messages_recovered"]
    assert bag.read_metadata(p)["custom_data"]["sigma"] == "60"
    other = _write(tmp_path, "other", n=5)
    before = _digest(other)
    with pytest.raises(ConfigError, match="not an empty directory"):  # never overwrite an output
        bag_recover.recover(p, other)
    assert _digest(other) == before


def test_flipped_bytes_inside_a_chunk_are_reported_everywhere(tmp_path, capsys):
    """Why #2: flipped bytes inside a chunk of a closed bag went unnoticed ("complete", inf in
    the report). Now the CRC check names the chunk and the messages it held, in info and in
    the report every reader fills; the intact chunks are still read."""
    p = _write(tmp_path)
    f = bag.resolve_mcap(p)
    data = bytearray(f.read_bytes())
    victim = _chunks(f)[2]
    held = _messages_in(bytes(data), victim)
    mid = victim.chunk_start_offset + victim.chunk_length - 20
    data[mid:mid + 4] = bytes(b ^ 0xFF for b in data[mid:mid + 4])
    f.write_bytes(bytes(data))
    inf = bag.info(p)
    assert inf["complete"] is False and inf["message_count"] == 2 * N - held
    bad = inf["integrity"]["chunks_bad"]
    assert [(c["offset"], c["messages"]) for c in bad] == [(victim.chunk_start_offset, held)]
    assert inf["integrity"]["messages_expected"] == 2 * N
    report: dict = {}
    assert len(list(bag.iter_messages(p, report=report))) == 2 * N - held
    assert report["complete"] is False and report["chunks_bad"][0]["messages"] == held
    assert cli_main(["bag", "info", str(p)]) == 1  # exit 0 on a bag it calls DAMAGED misled scripts (issue 57)
    out = capsys.readouterr().out
    assert "DAMAGED" in out and f"damaged chunk at byte {victim.chunk_start_offset} ({held} messages" in out
    rep = bag_recover.recover(p)
    assert rep["messages_recovered"] == 2 * N - held and rep["messages_expected"] == 2 * N


@pytest.mark.parametrize("content", [b"", b"hello, this is not a bag\n" * 10])
def test_empty_or_non_mcap_file_is_an_error(tmp_path, content, capsys):
    """Why #6: an empty or non-MCAP file replayed as complete. Now: one line, exit 2."""
    p = tmp_path / "x"
    p.mkdir()
    (p / "x_0.mcap").write_bytes(content)
    with pytest.raises(ConfigError):
        list(bag.iter_messages(p))
    with pytest.raises(ConfigError):
        bag_scan.check_file(p)
    for cmd in (["bag", "info", str(p)], ["bag", "recover", str(p)], ["replay", str(p)]):
        assert cli_main(cmd) == 2, cmd
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "x_recovered").exists()


def test_directory_without_mcap_replay_and_report(tmp_path, capsys):
    """Why #5: a directory without .mcap in replay, a malformed metadata.yaml in report."""
    empty = tmp_path / "nobag"
    empty.mkdir()
    assert cli_main(["replay", str(empty)]) == 2
    assert "no .mcap file" in capsys.readouterr().err
    p = _write(tmp_path)
    (p / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    code = cli_main(["report", str(p), "--out", str(tmp_path / "rep")])
    err = capsys.readouterr().err
    assert "Traceback" not in err and code in (0, 1, 2)


def test_timing_warnings_clock_gaps_and_log_time(tmp_path):
    """Why #3: bags with /clock samples missing and log_time far from the header stamp were
    called complete. info now counts the gaps and the messages beyond one step (ts = 1 s)."""
    good = bag.info(_write(tmp_path, "good"))
    assert good["timing"]["warnings"] == [] and good["timing"]["clock"]["gaps"] == 0
    p = _write(tmp_path, "late", stamp_offset_ns=-1_500_000_000, skip_clock=range(100, 110))
    t = bag.info(p)["timing"]
    assert t["step_s"] == 1.0
    assert t["clock"]["gaps"] == 1 and t["clock"]["missing_samples"] == 10
    dev = t["log_time_minus_stamp"]["/imu"]
    assert dev["before_stamp"] == N and dev["beyond_step"] == N and dev["min_s"] == pytest.approx(-1.5)
    assert len(t["warnings"]) == 2


def test_bag_info_into_closed_pipe_has_no_traceback(tmp_path):
    """Why #5: ``bag info | head`` ended in a BrokenPipe traceback."""
    p = _write(tmp_path, n=20)
    r = subprocess.run(f"{sys.executable} -m magtune_core bag info --json {p} | head -c 10",
                       shell=True, capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr
