"""Input checks of the nodes' callbacks: stamps, finiteness, matching topics by stamp, the stamp gate.

A node never trusts a message: each callback checks it here and counts what it rejects (Diagnostics).
"""
from __future__ import annotations

import math
import time

from builtin_interfaces.msg import Time
from rclpy.node import Node


def ns_to_stamp(ns: int) -> Time:
    """builtin_interfaces/Time of a time in integer ns: how the nodes stamp their messages."""
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def stamp_to_ns(stamp) -> int:
    """Integer ns of a header stamp: stamps are compared and paired exactly, as integers."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def sec_to_ns(t: float) -> int:
    """Seconds to integer ns (rounded): sample periods and stamps on an exact grid, without float drift."""
    return int(round(t * 1e9))


def finite(*values) -> bool:
    """True if every value is finite: the callbacks' check before a sample is used."""
    return all(math.isfinite(v) for v in values)


def now_wall() -> float:
    """Monotonic wall time [s] (perf_counter): waits measured in wall time, independent of the sim clock."""
    return time.perf_counter()

# ---------------------------------------------------------------- input checks
class PairSync:
    """Matches ``n`` input topics (default 2) by identical header stamps.

    Each slot keeps its last ``depth`` messages by stamp, so a set completes even when another
    topic already delivered the next step (free-running at a high real-time factor, or a
    loaded machine); a completed stamp drops itself and everything older in every slot.
    """

    def __init__(self, n: int = 2, depth: int = 16):
        self.slots: list[dict] = [{} for _ in range(n)]  # stamp ns -> msg, insertion (= stamp) order
        self.depth = depth

    def add(self, slot: int, ns: int, msg):
        """Store ``msg``; return (msg0, msg1, ...) when every slot holds stamp ``ns``, else None."""
        mine = self.slots[slot]
        mine[ns] = msg
        if len(mine) > self.depth:
            del mine[next(iter(mine))]
        return self.take(ns) if all(ns in x for x in self.slots) else None

    def take(self, ns: int, missing: int | None = None):
        """Return stamp ``ns``'s set (None in slot ``missing``) if every other slot holds it, else None; a returned
        set drops itself and everything older in every slot."""
        if not all(ns in x for i, x in enumerate(self.slots) if i != missing):
            return None
        out = tuple(x.get(ns) for x in self.slots)
        for x in self.slots:
            for k in [k for k in x if k <= ns]:
                del x[k]
        return out


class CommandLag:
    """Pairs each sample with the command stamped one period before it (the dipole applied until the sample),
    whichever of the two arrives first: the command reaches this node in one hop, the next sample through the
    simulator and the sensors, yet a loaded executor may take the sample first (measured: 4-11 of 1400 samples).
    Samples leave in stamp order; one whose command has not come after ``depth`` newer samples leaves without
    it (None)."""

    def __init__(self, lag_ns: int, depth: int = 4):
        self.lag_ns, self.depth = lag_ns, depth
        self.commands: dict = {}  # stamp -> command, the newest 16
        self.samples: list = []  # (stamp, inputs) waiting for their command, in stamp order
        self.first: int | None = None  # stamp of the first command (samples before it have none to miss)

    def command(self, ns: int, cmd) -> list:
        """Store the command of stamp ``ns``; the samples now ready, as (stamp, inputs, command) in order."""
        self.commands[ns] = cmd
        self.first = ns if self.first is None else self.first
        while len(self.commands) > 16:
            del self.commands[next(iter(self.commands))]
        return self._ready()

    def sample(self, ns: int, inputs) -> list:
        """Queue sample ``ns``; the samples now ready, as (stamp, inputs, command or None) in order."""
        self.samples.append((ns, inputs))
        return self._ready()

    def missed(self, ns: int) -> bool:
        """True if sample ``ns`` should have had a command (one came at or before its period's start)."""
        return self.first is not None and ns - self.lag_ns >= self.first

    def _ready(self) -> list:
        out = []
        while self.samples:
            ns, inputs = self.samples[0]
            cmd = self.commands.get(ns - self.lag_ns)
            if cmd is None and len(self.samples) <= self.depth:
                break
            out.append((ns, inputs, cmd))
            self.samples.pop(0)
        return out


class StampGate:
    """Rejects inputs whose stamps are not newer than the last accepted one, older than
    ``max_age`` relative to the node's (simulated) clock, or more than ``max_age`` ahead of it
    (``max_age_ns`` None: the stamps' order only, no clock read).

    A sim clock still at 0 has not received /clock yet (rclpy's use_sim_time starts there): only
    the order is checked then. The lockstep data readers can match the simulator before the
    best-effort /clock reader does; a controller at 0 s was seen rejecting the sample of t = 3 s
    as "in the future", so that step went unanswered and the seeded run differed from its twin.
    """

    def __init__(self, node: Node, max_age_ns: int | None, n: int = 2):
        self.node = node
        self.max_age_ns = None if max_age_ns is None else int(max_age_ns)
        self.last_ns = [-1] * n

    def check(self, slot: int, ns: int):
        """Return None if acceptable, else (counter, reason)."""
        if ns <= self.last_ns[slot]:
            kind = "duplicate" if ns == self.last_ns[slot] else "from the past"
            return "rejected_stamp", f"stamp {ns * 1e-9:.3f} s {kind} (last accepted {self.last_ns[slot] * 1e-9:.3f} s)"
        now = 0 if self.max_age_ns is None else self.node.get_clock().now().nanoseconds
        if now:  # 0: no age limit, or no /clock yet
            if now - ns > self.max_age_ns:
                return "stale_inputs", f"stamp {ns * 1e-9:.3f} s older than {self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)"
            if ns - now > self.max_age_ns:
                return "rejected_stamp", (f"stamp {ns * 1e-9:.3f} s in the future by more than "
                                          f"{self.max_age_ns * 1e-9:g} s (now {now * 1e-9:.3f} s)")
        self.last_ns[slot] = ns
        return None
