"""Replay runner: the ``player`` node of magtune_ros as a subprocess (no rclpy here).

The player (``<prefix>/lib/magtune_ros/player``, where ``ros2 run`` looks) republishes a bag
at its recorded sim time with /clock; it runs with the caller's ROS environment (ROS_DOMAIN_ID
etc.), Ctrl-C/SIGTERM/SIGHUP are forwarded to it (as SIGINT: it stops cleanly) and its exit
status is returned; it gets SIGTERM from the kernel if this process dies (``PR_SET_PDEATHSIG``). It prints a JSON
line with what it published and, for a damaged bag, what it could not read.

What ``ros2 bag play`` offers and the player mirrors (``magtune replay`` passes it on):

* ``--ros-args ...`` goes to the node unchanged (remapping ``-r /a:=/b``, ``-r __node:=NAME``,
  ``-r __ns:=/sat1``, parameters);
* ``--start-paused``; control services on the node (``/magtune_player/<name>``, the types of
  rosbag2_interfaces, built in ros2_ws from the same definitions): ``pause``, ``resume``,
  ``toggle_paused``, ``is_paused``, ``get_rate``, ``set_rate``, ``play_next``, ``seek``;
* ``--playback-duration S`` (bag seconds from the start point), ``--playback-until T`` (bag time
  in seconds, as the bag's log times: sim seconds, or seconds since 1970 for ``--epoch-time``
  bags), ``--exclude REGEX`` (topics to leave out), ``--topics`` (only these);
* subscribers: by default the player waits up to ``wait_subscribers`` (5 s) until each
  selected topic has a subscriber, so nodes started just before miss nothing;
* a progress line on stderr when it is a terminal (``--progress on`` forces it).

:func:`magtune_core.bags.playback.validate` checks every option against the bag before any process starts (the CLI and
the player node use it): a bad value raises :class:`~magtune_core.base.errors.ConfigError`
naming the option and the fix (exit 2).
"""
from __future__ import annotations

import signal
import subprocess

from ..bags.playback import ReplayOptions, validate
from ..base import ament
from .process import STOP_SIGNALS, dds_env, die_with_parent

PACKAGE = "magtune_ros"


def player_command(bag, opts: ReplayOptions) -> list[str]:
    """The player's command line (raises :class:`~magtune_core.base.ament.AmentNotFound`)."""
    cmd = [str(ament.executable(PACKAGE, "player")), str(bag), "--rate", repr(float(opts.rate))]
    if opts.topics:
        cmd += ["--topics", *opts.topics]
    if opts.exclude:
        cmd += ["--exclude", opts.exclude]
    if opts.start:
        cmd += ["--start", repr(float(opts.start))]
    if opts.playback_duration:
        cmd += ["--playback-duration", repr(float(opts.playback_duration))]
    if opts.playback_until is not None:
        cmd += ["--playback-until", repr(float(opts.playback_until))]
    if opts.loop:
        cmd.append("--loop")
    if opts.no_clock:
        cmd.append("--no-clock")
    if opts.start_paused:
        cmd.append("--start-paused")
    cmd += ["--wait-subscribers", repr(float(opts.wait_subscribers)), "--progress", opts.progress]
    if opts.foxglove is not None:
        cmd += ["--foxglove", str(opts.foxglove)]
    if opts.ros_args:
        cmd += ["--ros-args", *opts.ros_args]
    return cmd


def run_player(bag, opts: ReplayOptions, warn=None, dds_interfaces: str = "loopback") -> int:
    """Validate, run the player on ``bag`` until it ends; forward SIGINT/SIGTERM; return its exit status.

    ``warn``: called with each integrity problem of the bag (a damaged or missing file of a
    split bag, metadata.yaml counts that disagree) before the player starts. ``dds_interfaces``:
    loopback (default: DDS on 127.0.0.1 only) or all (:func:`.process.dds_env`)."""
    sel = validate(bag, opts)
    for line in sel.warnings if warn is not None else ():
        warn(line)
    cmd = player_command(bag, opts)
    env = dds_env(ament.child_env(ament.package_prefix(PACKAGE)), dds_interfaces)
    proc = subprocess.Popen(cmd, env=env, start_new_session=True,
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
