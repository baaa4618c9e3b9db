"""Timing checks of a recorded bag: /clock gaps and log time against the header stamp.

A lockstep SIL bag has one ``/clock`` sample per simulator step and every stamped message logged
at (or within one step after) its header stamp. A recorder starved of CPU may lose ``/clock``
samples (queue overflow) or map a message to the wrong sim time; both corrupt a replay (the
controller sees stale or rejected inputs), so ``magtune bag info`` checks them.

CDR layout used here (XCDR1, 4-byte encapsulation header): a message whose first field is a
``std_msgs/Header`` starts with ``int32 sec, uint32 nanosec`` at byte 4, as does
``rosgraph_msgs/Clock``.
"""
from __future__ import annotations

import struct

import numpy as np

CLOCK = "/clock"


def stamp_from_cdr(data: bytes) -> int | None:
    """The leading ``builtin_interfaces/Time`` of a CDR message (ns), None if too short."""
    if len(data) < 12:
        return None
    endian = "<" if data[1] == 1 else ">"
    sec, nsec = struct.unpack_from(endian + "iI", data, 4)
    return sec * 1_000_000_000 + nsec


def has_header(definition: str) -> bool:
    """True if a ros2msg definition's first field is a ``std_msgs/Header``."""
    for line in definition.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        return line.split()[0] in ("std_msgs/Header", "Header", "std_msgs/msg/Header")
    return False


class TimingCheck:
    """Accumulates per-message timing (feed :meth:`add`, then :meth:`report`)."""

    def __init__(self):
        self.clock: list[int] = []
        self.dev: dict[str, list[int]] = {}

    def add(self, topic: str, log_time: int, data: bytes) -> None:
        """Record one message: a /clock stamp, or the log time minus the header stamp of another topic."""
        if topic == CLOCK:
            s = stamp_from_cdr(data)
            if s is not None:
                self.clock.append(s)
        else:
            s = stamp_from_cdr(data)
            if s:  # an unset (zero) stamp says nothing
                self.dev.setdefault(topic, []).append(log_time - s)

    def report(self, ts: float | None, stamped: set[str]) -> dict:
        """Clock gaps and log-time deviations of the ``stamped`` topics (those whose type starts
        with a header, :func:`has_header`); ``ts`` (s) is the tolerance (the step).

        Returns
        -------
        dict
            ``step_s`` (tolerance used), ``clock`` (samples, nominal period, gaps, missing
            samples, largest gap), ``log_time_minus_stamp`` per topic (min/max s, count beyond
            the step, count earlier than the stamp) and ``warnings`` (one line each).
        """
        warnings: list[str] = []
        clock = {"samples": len(self.clock)}
        nominal = None
        if len(self.clock) > 2:
            c = np.sort(np.asarray(self.clock, dtype=np.int64))
            dt = np.diff(c)
            dt = dt[dt > 0]
            if len(dt):
                nominal = float(np.median(dt))
                big = dt > 1.5 * nominal
                missing = int(np.sum(np.rint(dt[big] / nominal) - 1))
                clock.update(period_s=nominal * 1e-9, gaps=int(big.sum()), missing_samples=missing,
                             largest_gap_s=float(dt.max()) * 1e-9)
                if big.any():
                    warnings.append(f"/clock: {int(big.sum())} gaps, about {missing} samples missing "
                                    f"(largest gap {dt.max() * 1e-9:.3f} s, period {nominal * 1e-9:.3f} s)")
        step = ts if ts else (nominal * 1e-9 if nominal else None)
        dev_out = {}
        for topic, d in sorted(self.dev.items()):
            if topic not in stamped:
                continue
            a = np.asarray(d, dtype=np.int64)
            row = {"min_s": float(a.min()) * 1e-9, "max_s": float(a.max()) * 1e-9,
                   "before_stamp": int(np.sum(a < 0))}
            if step:
                row["beyond_step"] = int(np.sum(np.abs(a) > step * 1e9 * (1 + 1e-9)))
                if row["beyond_step"] or row["before_stamp"]:
                    warnings.append(f"{topic}: {row['beyond_step']} messages with |log_time - stamp| > "
                                    f"{step:g} s, {row['before_stamp']} logged before their stamp "
                                    f"(range {row['min_s']:+.3f} .. {row['max_s']:+.3f} s)")
            dev_out[topic] = row
        return {"step_s": step, "clock": clock, "log_time_minus_stamp": dev_out, "warnings": warnings}
