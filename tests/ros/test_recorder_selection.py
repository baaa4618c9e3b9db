"""Recorder options of ``ros2 bag record`` kind over real DDS: --exclude, --regex, split by duration.

The fixture publisher (tests/support/bag_fixture_pub.py: N steps 0.1 s of sim time apart, six
topics) runs against the recorder; the split bag is read back by rosbags (independent reader,
follows metadata.yaml's file list) and by our reader, and ``bag info`` lists every file.
"""
from __future__ import annotations

import bag_fixture_pub as fx
import pytest
from bagproc import Procs, executable, ros_env
from rosbags.highlevel import AnyReader
from test_bag_ros import SPECS

from magtune_core import bags as baglib

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]
N = 300   # 30 s of sim time (t = 0.1 .. 30 s)


def test_exclude_regex_and_split_by_duration(tmp_path):
    # typed topics minus /imu (excluded), plus /blob found by --regex; split every 10 s of log time.
    # A subscriber process takes /imu (the fixture publisher waits for one on every topic).
    procs = Procs(ros_env(), tmp_path / "logs")
    out = tmp_path / "split"
    try:
        rec = procs.start("recorder", executable("recorder") + [
            "-o", str(out), "--topics", *SPECS, "--exclude", "^/imu$", "--regex", "^/bl.b$",
            "--max-bag-duration", "10"])
        procs.wait_for_line(rec, "magtune-recorder ready")
        procs.python("subscriber", "bag_fixture_sub.py", tmp_path / "sub.json", "--expect", 10**6, "--timeout", 90)
        pub = procs.python("publisher", "bag_fixture_pub.py", N, "--blob", 16)
        assert pub.wait(90) == 0, procs.output(pub)
        import time
        time.sleep(0.5)
        rec.send_signal(2)
        assert rec.wait(30) == 0, procs.output(rec)
    finally:
        procs.stop_all()
    want = {t: n for t, n in fx.counts(N).items() if t != "/imu"}
    want["/blob"] = N
    inf = baglib.info(out)
    assert {t: v["count"] for t, v in inf["topics"].items()} == want
    # log times 0.1 .. 30.0 s: files [0.1, 10.1), [10.1, 20.1), [20.1, 30.0] -> 3 files (rosbag2 naming)
    assert [f["path"].rsplit("/", 1)[-1] for f in inf["files"]] == [f"split_{i}.mcap" for i in range(3)]
    assert sum(f["message_count"] for f in inf["files"]) == sum(want.values())
    assert all(f["complete"] for f in inf["files"])
    # metadata.yaml's total, per-topic and per-file counts agree with the files: the bag is complete
    assert inf["complete"] and inf["missing_files"] == [] and inf["metadata_disagreements"] == []
    # each file holds 10 s from its first written message; messages are written in receive order,
    # so a late burst of one topic can carry earlier log times into the next file (seen: 2.4 s at
    # load 15): the files overlap a little, the first and last files still end/start at the run's ends
    assert inf["files"][0]["start_ns"] == 100_000_000 and inf["files"][-1]["end_ns"] == N * 100_000_000
    assert inf["storage_identifier"] == "mcap" and inf["ros_distro"] == "jazzy"
    meta = baglib.read_metadata(out)
    assert meta["relative_file_paths"] == [f"split_{i}.mcap" for i in range(3)]
    assert sum(f["message_count"] for f in meta["files"]) == meta["message_count"] == sum(want.values())
    with AnyReader([out]) as r:       # rosbags reads all files of the split bag
        got = {}
        for con, _, _ in r.messages():
            got[con.topic] = got.get(con.topic, 0) + 1
    assert got == want
    times = [m.log_time for m in baglib.iter_messages(out)]
    assert times == sorted(times) and len(times) == sum(want.values())


def test_bad_regex_exits_2(tmp_path):
    import subprocess

    from bagproc import executable, ros_env
    env = ros_env()
    p = subprocess.run(executable("recorder") + ["-o", str(tmp_path / "x"), "--exclude", "("], env=env,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "not a regular expression" in p.stderr
