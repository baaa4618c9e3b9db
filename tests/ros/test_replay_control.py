"""``magtune replay`` / the player node vs ``ros2 bag play``: validation, window, services, remap.

The bag is written by :class:`magtune_core.bags.BagWriter` (real MCAP) from CDR serialized by
rclpy: /sim/truth (nav_msgs/Odometry) and /tf (tf2_msgs/TFMessage), 40 samples 0.1 s apart.
The player runs as its own process over real DDS; a client process (tests/support/player_client.py)
calls its rosbag2_interfaces services.
"""
from __future__ import annotations

import json
import sys

import pytest
from bagproc import Procs, ros_env

from magtune_core.bags import BagWriter
from magtune_core.cli import main as magtune

N = 40
DT_NS = 100_000_000


def _bag(path, n=N):
    from geometry_msgs.msg import TransformStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from tf2_msgs.msg import TFMessage

    with BagWriter(path) as w:
        w.add_topic("/sim/truth", "nav_msgs/msg/Odometry")
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage")
        for k in range(n):
            t = k * DT_NS
            o = Odometry()
            o.header.stamp.sec, o.header.stamp.nanosec = divmod(t, 10**9)
            o.header.frame_id, o.child_frame_id = "orbital", "body"
            o.pose.pose.orientation.w = 1.0
            w.write("/sim/truth", serialize_message(o), t)
            tf = TransformStamped()
            tf.header = o.header
            tf.child_frame_id = "body"
            tf.transform.rotation.w = 1.0
            w.write("/tf", serialize_message(TFMessage(transforms=[tf])), t)
    return path


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    return _bag(tmp_path_factory.mktemp("replay") / "ten_hz")


@pytest.mark.parametrize("opts, words", [
    (["--rate", "-1"], "--rate"),
    (["--rate", "nan"], "--rate"),
    (["--start", "10"], "past the end"),
    (["--topics", "/nope"], "/nope not in"),
    (["--exclude", "("], "not a regular expression"),
    (["--exclude", "."], "no topic"),
    (["--start", "2", "--playback-until", "1"], "before the start point"),
    (["--playback-duration", "-3"], "--playback-duration"),
])
def test_bad_options_exit_2_before_starting(bag, capsys, opts, words):
    assert magtune(["replay", str(bag), *opts]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err


def _player(tmp, name, bag, *opts):
    procs = Procs(ros_env(), tmp / name)
    try:
        p = procs.start("player", [sys.executable, "-m", "magtune_core", "replay", str(bag), "--rate", "0",
                                   "--wait-subscribers", "0", *opts])
        assert p.wait(60) == 0, procs.output(p)
        return json.loads(procs.output(p).strip().splitlines()[-1])["published"]
    finally:
        procs.stop_all()


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_window_and_exclude(bag, tmp_path):
    # [1.0 s, 2.5 s] inclusive at 10 Hz: 16 samples; /tf excluded, /clock once per time
    got = _player(tmp_path, "window", bag, "--start", "1", "--playback-duration", "1.5", "--exclude", "^/tf$")
    assert got == {"/clock": 16, "/sim/truth": 16}
    got = _player(tmp_path, "until", bag, "--playback-until", "0.45", "--topics", "/tf")
    assert got == {"/clock": 5, "/tf": 5}   # 0.0 .. 0.4 s


@pytest.mark.ros
@pytest.mark.timeout(180)
def test_start_paused_services_and_remap(bag, tmp_path):
    """Done-when of issue 13: ``magtune replay BAG --start-paused`` is resumed through its service;
    remapping passes through ``--ros-args``; play_next, set_rate, get_rate, seek behave as rosbag2's."""
    procs = Procs(ros_env(), tmp_path / "logs")
    try:
        cli = procs.python("client", "player_client.py", "/remapped/truth", N)
        procs.wait_for_line(cli, "client ready")
        player = procs.start("player", [sys.executable, "-m", "magtune_core", "replay", str(bag), "--start-paused",
                                        "--topics", "/sim/truth", "--wait-subscribers", "30",
                                        "--ros-args", "-r", "/sim/truth:=/remapped/truth"])
        assert cli.wait(120) == 0, procs.output(cli)
        assert player.wait(30) == 0, procs.output(player)
        out = json.loads(procs.output(cli).strip().splitlines()[-1])
    finally:
        procs.stop_all()
    assert out["paused_at_start"] is True
    assert out["received_while_paused"] == 0
    assert out["play_next"] is True and out["received_after_play_next"] == 1
    assert out["set_rate_negative"] is False and out["set_rate_20"] is True and out["get_rate"] == 20.0
    assert out["seek_outside"] is False
    assert out["paused_after_resume"] is False
    assert out["stamps"] == [k * DT_NS for k in range(N)]      # every sample, in order, on the remapped name
    # 3.9 s of bag at rate 20 is 0.2 s; at rate 1 it would take >= 3.8 s (slack for a loaded machine)
    assert out["resume_to_end_s"] < 3.0
