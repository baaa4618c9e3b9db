"""``live_bridge`` node: stream ROS topics to Foxglove over WebSocket (``magtune sil --foxglove``).

Usage::

    live_bridge [--port 8765] [--host 127.0.0.1] [--topics /a:pkg/msg/Type ...] [--ros-args ...]

Subscribes raw (CDR bytes, nothing deserialized) to the project's topics
(:data:`magtune_core.base.topics.PROJECT_TOPICS`, or ``--topics``) with QoS compatible with
their publishers, and logs each message to a Foxglove WebSocket server
(:class:`magtune_core.bags.live.LiveServer`: one ``cdr`` channel with a ``ros2msg`` schema per
topic) at the sim time of the last ``/clock`` received (messages that arrive before the first
``/clock``, when DDS matched their topic first, have no sim time and are not streamed). Prints ``magtune-live ws://HOST:PORT``
once the server listens. SIGINT/SIGTERM stop it.

Why a node and not the simulator itself: it sees what is on the wire (a remapped or namespaced
run, a replayed bag, a real satellite's topics) and keeps WebSocket work off the lockstep loop.
"""
from __future__ import annotations

import argparse

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from magtune_core.bags.live import DEFAULT_PORT, LiveServer
from magtune_core.base.topics import PROJECT_TOPICS

from .bag_common import message_class
from .main import run
from .params import ParamError

CLOCK = "/clock"


def parse_args(argv):
    """The node's options (--port, --host, --topics) from the arguments that are not ROS arguments."""
    p = argparse.ArgumentParser(prog="live_bridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="WebSocket port (0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (0.0.0.0: every interface)")
    p.add_argument("--topics", nargs="*", default=None, help="/name:pkg/msg/Type (default: the project's topics)")
    return p.parse_args(argv)


class LiveBridge(Node):
    """Raw subscriptions to the project's topics, each logged to the Foxglove server at sim time."""

    NODE_NAME = "live_bridge"
    EXECUTOR = SingleThreadedExecutor
    parse_options = staticmethod(parse_args)

    def __init__(self, args):
        super().__init__(self.NODE_NAME)
        try:
            self.server = LiveServer(args.port, args.host, name="magtune sil")
        except (OSError, RuntimeError) as exc:   # port in use, ...
            raise ParamError("port", f"cannot start the WebSocket server on port {args.port}: {exc}") from None
        print(f"magtune-live ws://{args.host}:{self.server.port}", flush=True)
        specs = args.topics or [f"{n}:{t}" for n, (t, _) in PROJECT_TOPICS.items()]
        self.sim_ns = None  # no /clock yet
        self.subs = []
        for spec in specs:
            name, _, typ = spec.partition(":")
            if not typ and name in PROJECT_TOPICS:
                typ = PROJECT_TOPICS[name][0]
            if not typ:
                raise ParamError("topics", f"topic {name!r} needs a type (/name:pkg/msg/Type)")
            durable = PROJECT_TOPICS.get(name, ("", "volatile"))[1] == "transient_local"
            qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE)
            self.server.add_topic(name, typ)
            self.subs.append(self.create_subscription(message_class(typ), name, self._callback(name), qos, raw=True))

    def spin(self, executor, stop) -> int:
        """Stream until a stop signal."""
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
        return 0

    def finish(self) -> None:
        """Close the WebSocket server (called by ``main.run`` at shutdown)."""
        self.server.close()

    def _callback(self, name):
        server = self.server
        if name == CLOCK:
            def on_clock(data: bytes):
                import struct
                endian = "<" if data[1] == 1 else ">"
                sec, nsec = struct.unpack_from(endian + "iI", data, 4)
                self.sim_ns = sec * 1_000_000_000 + nsec
                server.log(name, data, self.sim_ns)
            return on_clock
        def on_message(data: bytes):
            if self.sim_ns is not None:
                server.log(name, data, self.sim_ns)
        return on_message


def main(argv=None):
    """Entry point of the live_bridge node (console script): run(LiveBridge)'s exit status."""
    return run(LiveBridge, argv)


if __name__ == "__main__":
    raise SystemExit(main())
