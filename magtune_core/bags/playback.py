"""Playback options of a bag and their check against it (``magtune replay``, the player node).

:func:`validate` checks every option against the bag before any process starts (the CLI and
the player node use it): a bad value raises :class:`~magtune_core.base.errors.ConfigError`
naming the option and the fix (exit 2). The services mirror ``ros2 bag play``'s.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..base.errors import ConfigError
from ..base.paramfile import check_path
from .integrity import integrity_lines
from .reader import info, topics_of

#: default wait for subscribers [wall s] before the first message
DEFAULT_WAIT_SUBSCRIBERS = 5.0
#: the control services of the player (rosbag2_interfaces/srv/<Type>), as ``ros2 bag play`` names them
SERVICES = {"pause": "Pause", "resume": "Resume", "toggle_paused": "TogglePaused", "is_paused": "IsPaused",
            "get_rate": "GetRate", "set_rate": "SetRate", "play_next": "PlayNext", "seek": "Seek"}


@dataclass
class ReplayOptions:
    """What ``magtune replay`` passes on to the player node."""

    rate: float = 1.0
    topics: list | None = None
    exclude: str | None = None
    start: float = 0.0
    playback_duration: float = 0.0
    playback_until: float | None = None
    loop: bool = False
    no_clock: bool = False
    start_paused: bool = False
    wait_subscribers: float = DEFAULT_WAIT_SUBSCRIBERS
    progress: str = "auto"
    foxglove: int | None = None
    ros_args: list = field(default_factory=list)


@dataclass
class Selection:
    """The validated playback window and topic set of one bag."""

    topics: list
    start_ns: int        # first log time to play
    end_ns: int          # last log time to play (inclusive)
    bag_start_ns: int
    bag_end_ns: int
    warnings: list = field(default_factory=list)   # integrity problems of the bag (damaged/missing files, counts)


#: Largest time option [s]: bag times are int64 nanoseconds (9.22e9 s, about 292 years).
MAX_SECONDS = 9.2e9
#: Largest --rate (a day of bag in a tenth of a second).
MAX_RATE = 1e6
#: Largest --wait-subscribers [s].
MAX_WAIT = 3600.0


def _in_range(option: str, value: float, lo: float, hi: float, what: str) -> None:
    """ConfigError naming ``option`` unless ``lo <= value <= hi`` (NaN and infinities refused)."""
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(option, None, f"{value:g}: out of range {lo:g} .. {hi:g} ({what})")


def check_numbers(opts: ReplayOptions) -> None:
    """Every number of ``opts`` within its range before it is used (a time beyond the int64
    nanoseconds of a bag, ``--start 1e300``, was a traceback).

    Raises
    ------
    ConfigError
        one line naming the option, the value and the range.
    """
    ns = "bag times are int64 nanoseconds"
    _in_range("--rate", opts.rate, 0.0, MAX_RATE, "a speed factor; 0: as fast as acknowledged")
    _in_range("--start", opts.start, 0.0, MAX_SECONDS, f"seconds from the beginning of the bag; {ns}")
    _in_range("--playback-duration", opts.playback_duration, 0.0, MAX_SECONDS, f"bag seconds, 0: to the end; {ns}")
    if opts.playback_until is not None:
        _in_range("--playback-until", opts.playback_until, -MAX_SECONDS, MAX_SECONDS, f"a log time in seconds; {ns}")
    _in_range("--wait-subscribers", opts.wait_subscribers, 0.0, MAX_WAIT, "wall seconds")


def validate(bag, opts: ReplayOptions) -> Selection:
    """Check ``opts`` against ``bag``; return the playback window and topics.

    Raises
    ------
    ConfigError
        one line naming the bad option, the value and the fix.
    """
    p = Path(bag)
    check_path(p)
    if not p.exists():
        raise ConfigError(bag, None, "no such bag (expected a bag directory or an .mcap file)")
    check_numbers(opts)
    if opts.progress not in ("auto", "on", "off"):
        raise ConfigError("--progress", None, f"{opts.progress}: expected auto, on or off")
    if opts.foxglove is not None and not 0 <= opts.foxglove <= 65535:
        raise ConfigError("--foxglove", None, f"{opts.foxglove}: expected a TCP port 0..65535 (0: any free port)")
    try:
        excl = re.compile(opts.exclude) if opts.exclude else None
    except re.error as exc:
        raise ConfigError("--exclude", None, f"{opts.exclude!r} is not a regular expression ({exc})") from None
    try:
        inf = info(p)
        names = sorted(topics_of(p))
    except (OSError, ValueError) as exc:
        raise ConfigError(bag, None, f"cannot read the bag ({exc})") from None
    if opts.topics:
        missing = [t for t in opts.topics if t not in names]
        if missing:
            raise ConfigError("--topics", None, f"{', '.join(missing)} not in {bag} (its topics: {', '.join(names)})")
        names = [t for t in names if t in opts.topics]
    if excl is not None:
        names = [t for t in names if not excl.search(t)]
    if not names:
        raise ConfigError("--topics/--exclude", None, f"no topic of {bag} left to play")
    b0, b1 = int(inf["start_ns"]), int(inf["end_ns"])
    if inf["message_count"] == 0:
        raise ConfigError(bag, None, "the bag holds no message")
    start_ns = b0 + int(round(opts.start * 1e9))
    if start_ns > b1:
        raise ConfigError("--start", None, f"{opts.start:g} s is past the end of the bag ({(b1 - b0) * 1e-9:.3f} s long)")
    end_ns = b1
    if opts.playback_duration > 0:
        end_ns = min(end_ns, start_ns + int(round(opts.playback_duration * 1e9)))
    if opts.playback_until is not None:
        until = int(round(opts.playback_until * 1e9))
        if not math.isfinite(opts.playback_until) or until < start_ns:
            raise ConfigError("--playback-until", None, f"{opts.playback_until:g} is before the start point "
                              f"{start_ns * 1e-9:.3f} s (the bag spans {b0 * 1e-9:.3f} .. {b1 * 1e-9:.3f} s, log time)")
        end_ns = min(end_ns, until)
    warnings = [] if inf["complete"] else (integrity_lines(inf["integrity"]) or ["the bag is not complete"])
    return Selection(names, start_ns, end_ns, b0, b1, warnings)
