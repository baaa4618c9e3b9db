"""Helpers shared by the recorder and the player: message classes, QoS conversion."""
from __future__ import annotations

import importlib

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from magtune_core.bags.layout import qos_dict
from magtune_core.bags.msgdefs import split_type

# topics every ROS graph has; not recorded by --all unless asked for
HIDDEN_TOPICS = ("/rosout", "/parameter_events")


def message_class(type_name: str):
    """The rclpy message class of ``pkg/msg/Type``."""
    pkg, ns, typ = split_type(type_name)
    return getattr(importlib.import_module(f"{pkg}.{ns}"), typ)


def _duration(d: Duration) -> dict:
    ns = int(d.nanoseconds)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_profile_dict(q: QoSProfile) -> dict:
    """An rclpy QoS profile (e.g. a publisher's offered QoS) in rosbag2's version-9 form."""
    return qos_dict(
        history=HistoryPolicy(q.history).name.lower(), depth=q.depth,
        reliability=ReliabilityPolicy(q.reliability).name.lower(),
        durability=DurabilityPolicy(q.durability).name.lower(),
        deadline=_duration(q.deadline), lifespan=_duration(q.lifespan),
        liveliness=q.liveliness.name.lower(), lease=_duration(q.liveliness_lease_duration),
        avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions)


def adapt_request(offered: list[QoSProfile], depth: int) -> QoSProfile:
    """Subscription QoS compatible with every offer (rosbag2's adapt_request_to_offers).

    Reliable if all publishers offer reliable, else best effort; transient-local if all offer
    it, else volatile. History KEEP_LAST with a deep queue so bursts are not dropped.
    """
    rel = ReliabilityPolicy.RELIABLE
    dur = DurabilityPolicy.VOLATILE
    if offered:
        if not all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered):
            rel = ReliabilityPolicy.BEST_EFFORT
        if all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered):
            dur = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel, durability=dur)


def offer_from_recorded(profiles: list[dict], depth: int) -> QoSProfile:
    """Publisher QoS for replay from the recorded offers (rosbag2's adapt_offer_to_recorded)."""
    rel = ReliabilityPolicy.RELIABLE
    dur = DurabilityPolicy.VOLATILE
    if profiles:
        if any(str(p.get("reliability")) == "best_effort" for p in profiles):
            rel = ReliabilityPolicy.BEST_EFFORT
        if all(str(p.get("durability")) == "transient_local" for p in profiles):
            dur = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel, durability=dur)
