"""Replay runner: the ``player`` node of magtune_ros as a subprocess (no rclpy here).

The player (``<prefix>/lib/magtune_ros/player``, where ``ros2 run`` looks) republishes a bag
at its recorded sim time with /clock; it runs with the caller's ROS environment (ROS_DOMAIN_ID
etc.), Ctrl-C/SIGTERM are forwarded to it and its exit status is returned. It prints a JSON
line with what it published and, for a damaged bag, what it could not read.
"""
from __future__ import annotations

import signal
import subprocess
from dataclasses import dataclass

from ..base import ament

PACKAGE = "magtune_ros"


@dataclass
class ReplayOptions:
    """What ``magtune replay`` passes on to the player node."""

    rate: float = 1.0
    topics: list | None = None
    start: float = 0.0
    loop: bool = False
    no_clock: bool = False
    wait_subscribers: float = 0.0


def player_command(bag, opts: ReplayOptions) -> list[str]:
    """The player's command line (raises :class:`~magtune_core.base.ament.AmentNotFound`)."""
    cmd = [str(ament.executable(PACKAGE, "player")), str(bag), "--rate", str(opts.rate)]
    if opts.topics:
        cmd += ["--topics", *opts.topics]
    if opts.start:
        cmd += ["--start", str(opts.start)]
    if opts.loop:
        cmd.append("--loop")
    if opts.no_clock:
        cmd.append("--no-clock")
    if opts.wait_subscribers:
        cmd += ["--wait-subscribers", str(opts.wait_subscribers)]
    return cmd


def run_player(bag, opts: ReplayOptions) -> int:
    """Run the player on ``bag`` until it ends; forward SIGINT/SIGTERM; return its exit status."""
    cmd = player_command(bag, opts)
    proc = subprocess.Popen(cmd, env=ament.child_env(ament.package_prefix(PACKAGE)), start_new_session=True)

    def forward(signum, frame):  # noqa: ARG001
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)

    old = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return proc.wait()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
