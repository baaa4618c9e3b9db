"""Replay runner: the ``player`` node of magtune_ros as a subprocess (no rclpy here).

The player (``<prefix>/lib/magtune_ros/player``, where ``ros2 run`` looks) republishes a bag
at its recorded sim time with /clock; it runs with the caller's ROS environment (ROS_DOMAIN_ID
etc.), Ctrl-C/SIGTERM/SIGHUP are forwarded to it (as SIGINT: it stops cleanly) and its exit
status is returned; it gets SIGTERM from the kernel if this process dies (``PR_SET_PDEATHSIG``). It prints a JSON
line with what it published and, for a damaged bag, what it could not read.
"""
from __future__ import annotations

import signal
import subprocess
from dataclasses import dataclass

from ..base import ament
from .sil import STOP_SIGNALS, die_with_parent

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
    proc = subprocess.Popen(cmd, env=ament.child_env(ament.package_prefix(PACKAGE)), start_new_session=True,
                            preexec_fn=die_with_parent())

    def forward(signum, frame):  # noqa: ARG001
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)

    old = {s: signal.signal(s, forward) for s in STOP_SIGNALS}
    try:
        while True:
            try:
                return proc.wait()
            except KeyboardInterrupt:  # pragma: no cover - only if a handler raised
                forward(signal.SIGINT, None)
    finally:
        if proc.poll() is None:
            try:
                proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for s, h in old.items():
            signal.signal(s, h)
