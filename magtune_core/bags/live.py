"""Live view in Foxglove: the ``foxglove-sdk`` WebSocket server fed with raw CDR (no rclpy here).

Foxglove (desktop or browser) connects to ``ws://HOST:PORT`` ("Open connection" -> "Foxglove
WebSocket") and decodes every channel itself: each ROS topic becomes a channel with message
encoding ``cdr`` and a ``ros2msg`` schema holding the full definition text (the same schema
records the bags carry, :func:`magtune_core.bags.msgdefs.full_definition`), so nothing is
converted and every standard panel (3D with /tf and markers, Plot, Raw Messages) works as on a
bag. The server also advertises the ``time`` capability and broadcasts the log time of the
messages, so Foxglove's clock follows sim time (or the scenario epoch with ``--epoch-time``).

Users: the player node (``magtune replay --foxglove``: logs what it publishes, at the bag's log
times) and the ``live_bridge`` node (``magtune sil --foxglove``: subscribes raw to the project's
topics over DDS and logs them at the sim time of the last /clock).
"""
from __future__ import annotations

#: Foxglove's default port (the app proposes ws://localhost:8765)
DEFAULT_PORT = 8765


class LiveServer:
    """A Foxglove WebSocket server with one ``cdr`` channel per topic.

    ``port=0`` binds any free port (:attr:`port` tells which). ``host`` defaults to localhost:
    the stream is for this machine; pass ``0.0.0.0`` to expose it.
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "magtune"):
        import foxglove

        self._fg = foxglove
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name=name, host=host, port=int(port), context=self.context,
                                            capabilities=[foxglove.Capability.Time])
        self.channels: dict = {}
        self.last_time = None

    @property
    def port(self) -> int:
        """The TCP port the server listens on (the one bound when 0 was asked)."""
        return int(self.server.port)

    def add_topic(self, topic: str, msg_type: str, definition: str | None = None) -> None:
        """Advertise ``topic`` with the ros2msg schema of ``msg_type`` (full definition text)."""
        if topic in self.channels:
            return
        if definition is None:
            from ..bags.msgdefs import full_definition

            definition = full_definition(msg_type)
        schema = self._fg.Schema(name=msg_type, encoding="ros2msg", data=definition.encode())
        self.channels[topic] = self._fg.Channel(topic, schema=schema, message_encoding="cdr", context=self.context)

    def log(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Send one CDR message (to the clients subscribed to ``topic``); advance the clients' clock."""
        ch = self.channels.get(topic)
        if ch is None:
            return
        t = int(log_time_ns)
        if self.last_time is None or t > self.last_time:
            self.server.broadcast_time(t)
            self.last_time = t
        ch.log(bytes(data), log_time=t)

    def close(self) -> None:
        """Close every channel and stop the server."""
        for ch in self.channels.values():
            ch.close()
        self.channels.clear()
        self.server.stop()
