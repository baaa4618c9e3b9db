"""Fault-injection relay node for the reliability tests: sensors -> (faults) -> controller.

    fault_relay.py [--drop P] [--nan-every N --nan-burst B] [--seed S] --ros-args ...

Subscribes ``sensors/magnetic_field_raw`` and ``sensors/attitude_raw`` (the sensors node remapped
there) and republishes on ``sensors/magnetic_field`` / ``sensors/attitude`` with the project's
lockstep QoS, after:

* ``--drop P``: each message dropped with probability P (one draw of
  ``default_rng([seed, topic, step])`` per message: reproducible whatever the arrival order);
* ``--nan-every N --nan-burst B``: the attitude samples whose step index k (stamp / ts) satisfies
  ``k % N < B`` (k > 0) get NaN in orientation.x: bursts of B consecutive bad samples every N steps.

On SIGINT/SIGTERM it prints one JSON line: the stamps it dropped and those it poisoned, per
topic, so a test can compare them with the counters the controller and simulator publish.
"""
from __future__ import annotations

import argparse
import json
import math
import signal
import sys

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import Imu, MagneticField

from magtune_ros.qos import LOCKSTEP_QOS


def main(argv=None):
    argv = sys.argv if argv is None else argv
    ap = argparse.ArgumentParser()
    ap.add_argument("--drop", type=float, default=0.0)
    ap.add_argument("--nan-every", type=int, default=0)
    ap.add_argument("--nan-burst", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ts", type=float, default=1.0)
    a = ap.parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("fault_relay")
    log = {"dropped": {"mag": [], "att": []}, "poisoned": [], "relayed": {"mag": 0, "att": 0}}
    stop = {"flag": False}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["flag"] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    pubs = {"mag": node.create_publisher(MagneticField, "sensors/magnetic_field", LOCKSTEP_QOS),
            "att": node.create_publisher(Imu, "sensors/attitude", LOCKSTEP_QOS)}

    def relay(kind):
        def cb(msg):
            ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            # one draw per (seed, topic, step): the same messages are dropped whatever the
            # order in which the two topics arrive
            k_draw = round(ns * 1e-9 / a.ts)
            if a.drop > 0 and np.random.default_rng([a.seed, kind == "att", k_draw]).random() < a.drop:
                log["dropped"][kind].append(ns)
                return
            k = round(ns * 1e-9 / a.ts)
            if kind == "att" and a.nan_every and k > 0 and k % a.nan_every < a.nan_burst:
                msg.orientation.x = math.nan
                log["poisoned"].append(ns)
            log["relayed"][kind] += 1
            pubs[kind].publish(msg)
        return cb

    node.create_subscription(MagneticField, "sensors/magnetic_field_raw", relay("mag"), LOCKSTEP_QOS)
    node.create_subscription(Imu, "sensors/attitude_raw", relay("att"), LOCKSTEP_QOS)
    print("fault_relay ready", flush=True)
    try:
        while not stop["flag"] and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        print(json.dumps(log), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
