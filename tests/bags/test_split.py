"""Split bags (rosbag2's --max-bag-size / --max-bag-duration) written by BagWriter: every file is
a complete MCAP, metadata.yaml lists them with their own stats, and the readers (ours, rosbags,
mcap) see one bag."""
from __future__ import annotations

import contextlib
import struct

import pytest
import yaml
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


# --- integrity of every file of a split bag (issue 32) ------------------------------------------

def _split(tmp_path, name="run"):
    """A bag of 4 files x 100 /clock messages (5 s each), uncompressed, small chunks."""
    out = tmp_path / name
    with bags.BagWriter(out, compression="none", chunk_size=512, max_duration_ns=5 * 10**9) as w:
        w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        for k in range(N):
            w.write("/clock", _clock(k * DT), k * DT)
    return out


def _truncate(path, fraction=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    return path.read_bytes()


@contextlib.contextmanager
def _damaged_split_bag_on_full_disk(tmp_path):
    """A split bag with its second file half cut, copied onto a small tmpfs that is then filled:
    (mount point, bag, the bag's files' bytes before filling, the filler file to free the disk)."""
    import shutil

    from smallfs import fill, small_tmpfs

    src = _split(tmp_path)
    _truncate(src / "run_1.mcap")
    with small_tmpfs(tmp_path / "small", "96k") as mnt:
        bag = mnt / "run"
        shutil.copytree(src, bag)
        before = {p.name: p.read_bytes() for p in bag.iterdir()}
        yield mnt, bag, before, fill(mnt)


def _cli(capsys, *argv):
    from magtune_core.cli import main

    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_missing_listed_file_is_named_and_bag_not_complete(tmp_path, capsys):
    """Why: a file listed in metadata.yaml but missing was skipped and the bag called complete."""
    bag = _split(tmp_path)
    (bag / "run_2.mcap").unlink()
    inf = bags.info(bag)
    assert not inf["complete"] and inf["missing_files"] == ["run_2.mcap"] and inf["message_count"] == 300
    assert "metadata.yaml message_count is 400, the files hold 300 (missing 100)" in inf["metadata_disagreements"]
    report: dict = {}
    assert len(list(bags.iter_messages(bag, report=report))) == 300
    assert report["complete"] is False and report["missing_files"] == ["run_2.mcap"]
    assert report["messages_recovered"] == 300 and report["messages_expected"] == 400
    code, out, _ = _cli(capsys, "bag", "info", str(bag))
    assert code == 1 and "DAMAGED/UNFINISHED" in out  # not complete: exit 1 (issue 57)
    assert "warning: run_2.mcap: listed in metadata.yaml but missing" in out


def test_metadata_counts_that_disagree_are_reported(tmp_path, capsys):
    bag = _split(tmp_path)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["message_count"] = 450
    info["topics_with_message_count"][0]["message_count"] = 450
    info["files"][1]["message_count"] = 150
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    inf = bags.info(bag)
    assert not inf["complete"] and inf["missing_files"] == []
    assert inf["metadata_disagreements"] == [
        "metadata.yaml message_count is 450, the files hold 400 (missing 50)",
        "metadata.yaml: topic /clock message_count is 450, the files hold 400",
        "metadata.yaml: file run_1.mcap message_count is 150, it holds 100"]
    code, out, _ = _cli(capsys, "bag", "info", str(bag))
    assert "warning: metadata.yaml: file run_1.mcap message_count is 150, it holds 100" in out


def test_damaged_second_file_is_recovered_beside(tmp_path, capsys):
    """Why: recover handled only the first file and reported "N of N, complete"."""
    bag = _split(tmp_path)
    damaged = _truncate(bag / "run_1.mcap")
    inf = bags.info(bag)
    assert not inf["complete"] and [f["complete"] for f in inf["files"]] == [True, False, True, True]
    readable = inf["message_count"]
    assert 300 <= readable < 400
    code, _, err = _cli(capsys, "bag", "recover", str(bag))
    assert code == 0, err
    out = tmp_path / "run_recovered"
    assert sorted(p.name for p in out.glob("*.mcap")) == [f"run_recovered_{i}.mcap" for i in range(4)]
    assert f"recovered {readable} of {readable} messages (metadata.yaml: 400)" in err
    assert "run_1.mcap: " in err and "warning: metadata.yaml message_count is 400" in err
    assert (bag / "run_1.mcap").read_bytes() == damaged                  # input untouched
    after = bags.info(out)
    assert after["complete"] and after["message_count"] == readable
    assert [m.log_time for m in bags.iter_messages(out)][:100] == [k * DT for k in range(100)]


def test_in_place_keeps_damaged_later_file(tmp_path):
    """Why: --in-place dropped a damaged later file from the bag."""
    from magtune_core.bags import recover

    bag = _split(tmp_path)
    first = (bag / "run_0.mcap").read_bytes()
    damaged = _truncate(bag / "run_1.mcap")
    rep = recover.recover(bag, in_place=True)
    assert rep["recovered_files"] == [f"run_{i}.mcap" for i in range(4)]
    assert (bag / "run_1.mcap.damaged").read_bytes() == damaged and (bag / "run_0.mcap").read_bytes() == first
    assert (bag / "metadata.yaml.damaged").is_file()
    inf = bags.info(bag)
    assert inf["complete"] and inf["message_count"] == rep["messages_recovered"] and len(inf["files"]) == 4
    again = _truncate(bag / "run_1.mcap", 0.9)    # damaged again: the first kept original is not overwritten
    recover.recover(bag, in_place=True)
    assert (bag / "run_1.mcap.damaged").read_bytes() == damaged and (bag / "run_1.mcap.damaged.1").read_bytes() == again


def test_unreadable_later_file_does_not_stop_the_others(tmp_path):
    bag = _split(tmp_path)
    (bag / "run_3.mcap").write_bytes(b"")
    inf = bags.info(bag)
    assert not inf["complete"] and inf["message_count"] == 300
    assert "unreadable" in inf["integrity"]["files"][3]["problem"]
    assert sum(1 for _ in bags.iter_messages(bag)) == 300


def test_recover_on_full_disk_is_one_line_and_retry_works(tmp_path, capsys):
    """Why: a full disk during recovery was a traceback and left a 0-byte .tmp that blocked the retry."""
    with _damaged_split_bag_on_full_disk(tmp_path) as (mnt, bag, _, filler):
        code, _, err = _cli(capsys, "bag", "recover", str(bag))
        assert code == 1 and len(err.strip().splitlines()) == 1 and "No space left on device" in err, err
        assert sorted(p.name for p in mnt.iterdir()) == ["filler", "run"]     # no output dir, no .tmp
        assert not [p for p in bag.iterdir() if p.name.endswith(".tmp") or p.name.startswith(".")]
        filler.unlink()
        code, _, err = _cli(capsys, "bag", "recover", str(bag))
        assert code == 0, err
        assert bags.info(mnt / "run_recovered")["complete"]


def test_replay_validation_names_every_bad_file(tmp_path):
    """Replay plays what is readable, but names the missing and the damaged file before it starts."""
    from magtune_core.bags.playback import ReplayOptions, validate
    from magtune_core.bags.scan import check_file

    bag = _split(tmp_path)
    (bag / "run_0.mcap").write_bytes(b"")     # even the first file: check_file finds the next good one
    (bag / "run_3.mcap").unlink()
    assert check_file(bag) == bag / "run_1.mcap"
    sel = validate(bag, ReplayOptions())
    assert sel.bag_start_ns == 100 * DT and sel.bag_end_ns == 299 * DT
    assert "run_3.mcap: listed in metadata.yaml but missing (its messages are lost; the bag is not complete)" in sel.warnings
    assert any(w.startswith("run_0.mcap: unreadable (empty file") for w in sel.warnings), sel.warnings


def test_metadata_not_utf8_is_ignored_not_a_traceback(tmp_path, capsys):
    bag = _split(tmp_path)
    (bag / "metadata.yaml").write_bytes(b"\xff\xfe garbage")
    assert bags.info(bag)["message_count"] == N       # the files are found by name and read
    code, _, err = _cli(capsys, "bag", "recover", str(bag))
    assert code == 0 and "Traceback" not in err
    assert bags.info(tmp_path / "run_recovered")["complete"]


def test_recover_in_place_on_full_disk_changes_nothing(tmp_path, capsys):
    with _damaged_split_bag_on_full_disk(tmp_path) as (_, bag, before, filler):
        code, _, err = _cli(capsys, "bag", "recover", "--in-place", str(bag))
        assert code == 1 and len(err.strip().splitlines()) == 1, err
        assert {p.name: p.read_bytes() for p in bag.iterdir()} == before      # nothing replaced, nothing left
        filler.unlink()
        code, _, err = _cli(capsys, "bag", "recover", "--in-place", str(bag))
        assert code == 0, err
        assert bags.info(bag)["complete"] and (bag / "run_1.mcap.damaged").read_bytes() == before["run_1.mcap"]
