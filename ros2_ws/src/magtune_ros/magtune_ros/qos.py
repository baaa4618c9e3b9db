"""QoS profiles of the magtune topics: lockstep data, /clock, the mode, /diagnostics.
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Lockstep data topics (truth, field, sensors, dipole command, torques): reliable, and
#: transient-local so a subscriber matched after the first publication (DDS discovery is
#: asynchronous between the three processes) still receives it; depth 1000 (about 17 minutes of
#: sim time at Ts = 1 s, a few seconds of wall time at full SIL speed) so a recorder starved of
#: CPU on a loaded machine catches up instead of losing bursts (seen with depth 100 at load 5).
LOCKSTEP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /clock: reliable publisher (compatible with rclpy's best-effort TimeSource subscriber);
#: depth 1000 as the lockstep topics, for a reliable recorder that falls behind (with 100, a
#: recorder starved at load 4.7 lost up to 265 /clock samples of a 5-orbit run; issue #10).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
#: mode: reliable and transient-local with depth 10, so a late subscriber (controller activated
#: after the manager published, a recorder) gets the current mode and the last transitions.
MODE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /diagnostics: the usual diagnostic_aggregator QoS.
DIAG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
