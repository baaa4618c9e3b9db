"""Bag library without ROS processes: MCAP/rosbag2 format, independent readers, recovery.

Values are exact: CDR carries float64 bit-for-bit, so decoded values equal what was encoded.
"""
from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader

from magtune_core import bags as bag
from magtune_core.bags import msgdefs
from magtune_core.bags import recover as bag_recover
from magtune_core.bags import scan as bag_scan
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.bags.layout import BagMessage

TYPES = ["sensor_msgs/msg/Imu", "sensor_msgs/msg/MagneticField", "nav_msgs/msg/Odometry",
         "geometry_msgs/msg/Vector3Stamped", "rosgraph_msgs/msg/Clock",
         "diagnostic_msgs/msg/DiagnosticArray"]


def _imu(d: Decoder, i: int) -> bytes:
    T = d.types()
    t = T["builtin_interfaces/msg/Time"](sec=i, nanosec=500)
    v = T["geometry_msgs/msg/Vector3"]
    m = T["sensor_msgs/msg/Imu"](
        header=T["std_msgs/msg/Header"](stamp=t, frame_id="body"),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.1 * i, w=1.0),
        orientation_covariance=np.zeros(9), angular_velocity=v(x=1e-3 * i, y=-2.0, z=0.5),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=v(x=0.0, y=0.0, z=0.0),
        linear_acceleration_covariance=np.zeros(9))
    return d.encode(m, "sensor_msgs/msg/Imu")


def _write(tmp_path: Path, n=300, chunk_size=2048, name="run") -> Path:
    d = Decoder()
    w = bag.BagWriter(tmp_path / name, chunk_size=chunk_size, custom_data={"sigma": 60})
    w.add_topic("/imu", "sensor_msgs/msg/Imu",
                [bag.qos_dict(reliability="reliable", depth=7)])
    w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    T = d.types()
    for i in range(n):
        t_ns = i * 1_000_000_000 + 500
        w.write("/clock", d.encode(T["rosgraph_msgs/msg/Clock"](
            clock=T["builtin_interfaces/msg/Time"](sec=i, nanosec=500)), "rosgraph_msgs/msg/Clock"), t_ns)
        w.write("/imu", _imu(d, i), t_ns)
    w.close()
    return tmp_path / name


@pytest.mark.parametrize("t", TYPES)
def test_definitions_and_hashes_match_rosbags(t):
    """Our ros2msg text parses to the same type as rosbags' built-in Jazzy store, and the
    RIHS01 hash from rosidl's .json equals rosbags' independent computation."""
    d = Decoder()
    assert msgdefs.type_hash(t) == d.store.hash_rihs01(t)
    text = msgdefs.full_definition(t)
    assert text.startswith(msgdefs.msg_text(t))
    fresh = Decoder()
    fresh.store = type(d.store)()  # empty store: must learn everything from our text
    fresh.learn(t, text)
    assert fresh.store.hash_rihs01(t) == d.store.hash_rihs01(t)


def test_rosbag2_layout_and_mcap_records(tmp_path):
    p = _write(tmp_path)
    assert sorted(f.name for f in p.iterdir()) == ["metadata.yaml", "run_0.mcap"]
    meta = yaml.safe_load((p / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["message_count"] == 600 and meta["relative_file_paths"] == ["run_0.mcap"]
    assert meta["duration"]["nanoseconds"] == 299_000_000_000
    assert meta["starting_time"]["nanoseconds_since_epoch"] == 500
    assert meta["custom_data"] == {"sigma": "60"}
    tm = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert tm["/imu"]["message_count"] == 300
    assert tm["/imu"]["topic_metadata"]["offered_qos_profiles"][0]["depth"] == 7
    assert tm["/imu"]["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
    with open(p / "run_0.mcap", "rb") as f:
        r = make_reader(f)
        assert r.get_header().profile == "ros2"
        s = r.get_summary()
        assert s.statistics.message_count == 600 and s.statistics.chunk_count > 5
        assert {c.compression for c in s.chunk_indexes} == {"zstd"}
        sch = {x.name: x for x in s.schemas.values()}
        assert sch["sensor_msgs/msg/Imu"].encoding == "ros2msg"
        assert b"\n" + b"=" * 80 + b"\nMSG: std_msgs/Header\n" in sch["sensor_msgs/msg/Imu"].data
        ch = {c.topic: c for c in s.channels.values()}
        assert ch["/imu"].message_encoding == "cdr"
        qos = yaml.safe_load(ch["/imu"].metadata["offered_qos_profiles"])
        assert qos[0]["reliability"] == "reliable" and qos[0]["deadline"]["sec"] == 9223372036
        assert [m.name for m in r.iter_metadata()] == ["rosbag2"]


def test_independent_readers_decode_values(tmp_path):
    p = _write(tmp_path)
    with AnyReader([p]) as r:  # rosbags: metadata.yaml + its own MCAP parser + typestore
        assert {c.topic: (c.msgtype, c.msgcount) for c in r.connections} == {
            "/imu": ("sensor_msgs/msg/Imu", 300), "/clock": ("rosgraph_msgs/msg/Clock", 300)}
        imu = [(ts, r.deserialize(raw, c.msgtype)) for c, ts, raw in r.messages()
               if c.topic == "/imu"]
    assert [ts for ts, _ in imu] == [i * 10**9 + 500 for i in range(300)]
    assert [m.angular_velocity.x for _, m in imu] == [1e-3 * i for i in range(300)]
    assert all(stamp_ns(m) == ts for ts, m in imu)
    with Rosbag2Reader(p) as r2:
        assert r2.message_count == 600 and r2.duration == 299_000_000_001
    # and through our own reader (mcap index path)
    ours = [m for m in bag.iter_messages(p, topics=["/imu"])]
    assert len(ours) == 300 and ours[5].log_time == 5 * 10**9 + 500


def test_truncated_file_recovery(tmp_path):
    """Cut the file mid-way (what SIGKILL leaves): complete chunks are recovered, the partial
    record is reported, and recover() rewrites a bag both readers accept."""
    p = _write(tmp_path)
    f = p / "run_0.mcap"
    data = f.read_bytes()
    f.write_bytes(data[: len(data) * 6 // 10])
    assert not bag.has_summary(f)
    res = bag_scan.scan(f)
    rep = res.summary()
    assert not rep["complete"] and rep["unreadable_tail_bytes"] > 0 and "cut short" in rep["problem"]
    n = rep["per_topic"]["/imu"]
    assert 100 < n < 300
    d = Decoder()
    imu = [m for m in res.messages if m.topic == "/imu"]
    # a contiguous prefix of the recording, values intact
    assert [d.decode(m.data, m.type).angular_velocity.x for m in imu] == [1e-3 * i for i in range(n)]
    out = bag_recover.recover(p)
    assert out["messages_recovered"] == rep["messages_recovered"]
    q = Path(out["output"])  # beside the input, which is left as it was
    assert q == tmp_path / "run_recovered" and not bag.has_summary(f) and bag.has_summary(bag.resolve_mcap(q))
    with AnyReader([q]) as r:
        assert {c.topic: c.msgcount for c in r.connections}["/imu"] == n
        assert sum(1 for _ in r.messages()) == rep["messages_recovered"]
    assert bag.read_metadata(q)["custom_data"] == {"sigma": "60"}


def test_corrupt_chunk_is_skipped_and_reported(tmp_path):
    p = _write(tmp_path)
    f = p / "run_0.mcap"
    with open(f, "rb") as fh:
        s = make_reader(fh).get_summary()
    chunks = sorted(s.chunk_indexes, key=lambda c: c.chunk_start_offset)
    victim = chunks[2]
    data = bytearray(f.read_bytes())
    body = data[victim.chunk_start_offset + 9: victim.chunk_start_offset + victim.chunk_length]
    in_victim = sum(isinstance(r, Message) for r in breakup_chunk(
        Chunk.read(ReadDataStream(io.BytesIO(bytes(body))))))
    mid = victim.chunk_start_offset + victim.chunk_length - 20  # inside compressed payload
    data[mid:mid + 8] = b"\xff" * 8
    data = data[: chunks[-1].chunk_start_offset + chunks[-1].chunk_length]  # also drop summary
    f.write_bytes(bytes(data))
    report: dict = {}
    msgs = list(bag.iter_messages(p, report=report))
    assert report["complete"] is False and len(report["chunks_bad"]) == 1
    assert report["chunks_bad"][0]["offset"] == victim.chunk_start_offset
    assert in_victim > 0 and len(msgs) == 600 - in_victim
    assert [m.log_time for m in msgs] == sorted(m.log_time for m in msgs)


def test_copy_of_bag_directory_is_self_contained(tmp_path):
    p = _write(tmp_path)
    q = tmp_path / "copy"
    shutil.copytree(p, q)
    # resolve_mcap follows metadata.yaml's relative_file_paths (run_0.mcap) in the copy
    assert bag.info(q)["message_count"] == 600


def test_topic_filter_and_publish_order(tmp_path):
    p = _write(tmp_path, n=20)
    assert list(bag.iter_messages(p, topics=[])) == []          # empty filter: nothing
    assert {m.topic for m in bag.iter_messages(p, topics=["/clock"])} == {"/clock"}
    d = Decoder()
    w = bag.BagWriter(tmp_path / "late", chunk_size=1024)
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    # a late-delivered sample: received (log) at 5 s, published at 1 s
    w.write("/imu", _imu(d, 5), 5_000_000_000, 5_000_000_000)
    w.write("/imu", _imu(d, 1), 5_000_000_000, 1_000_000_000)
    w.close()
    assert [m.publish_time for m in bag.iter_messages(tmp_path / "late", order="publish")] == \
        [1_000_000_000, 5_000_000_000]
    with pytest.raises(ValueError):
        list(bag.iter_messages(tmp_path / "late", order="stamp"))


def test_core_bag_modules_do_not_import_rclpy():
    import subprocess
    import sys
    code = ("import sys; import magtune_core.bags, magtune_core.bags.recover, magtune_core.bags.msgdefs, "
            "magtune_core.bags.decode, magtune_core.studies.report, magtune_core.ros.replay, "
            "magtune_core.base.topics, magtune_core.cli; assert 'rclpy' not in sys.modules, 'rclpy imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_ties_in_topic_order_reorders_only_equal_times():
    """A field and an attitude sample of one sim instant, recorded attitude first (separate DDS readers), come
    out field first when the topics are named in that order; different times and unlisted topics keep their
    place within their time (stable), and publish-time ties work the same."""
    def msg(topic, t):
        return BagMessage(topic, "", t, 10 * t, topic.encode())

    msgs = [msg("/att", 1), msg("/mag", 1), msg("/other", 1), msg("/att", 2), msg("/mag", 3), msg("/att", 3)]
    out = [(m.topic, m.log_time) for m in bag.ties_in_topic_order(iter(msgs), ["/mag", "/att"])]
    assert out == [("/mag", 1), ("/att", 1), ("/other", 1), ("/att", 2), ("/mag", 3), ("/att", 3)]
    assert [(m.topic, m.log_time) for m in bag.ties_in_topic_order(msgs, ["/att", "/mag"], "publish")] == \
        [("/att", 1), ("/mag", 1), ("/other", 1), ("/att", 2), ("/att", 3), ("/mag", 3)]
    assert list(bag.ties_in_topic_order([], ["/mag"])) == [] and list(bag.ties_in_topic_order(msgs, ())) == msgs
