"""The one main of every magtune node: parameter files checked first, options parsed, the node
built and spun until done or SIGINT/SIGTERM/SIGHUP, finished; exit status 0/1/2.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import check_ros_params

from .lifecycle import ManagedNode
from .params import ParamError


def make_executor():
    """EventsExecutor (C++, lowest per-callback overhead) unless MAGTUNE_EXECUTOR=single."""
    if os.environ.get("MAGTUNE_EXECUTOR", "events") != "single":
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except Exception:  # pragma: no cover - older rclpy
            pass
    return SingleThreadedExecutor()


#: Signals that stop a node cleanly: Ctrl-C, ``kill``, closed terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def install_stop_handlers() -> threading.Event:
    """SIGINT/SIGTERM/SIGHUP set the returned event: the node's spin loop ends and it finishes
    cleanly (a recorder closes its bag, a simulator keeps what it wrote)."""
    stop = threading.Event()

    def handler(signum, frame):  # noqa: ARG001
        stop.set()

    for sig in STOP_SIGNALS:
        signal.signal(sig, handler)
    return stop


def spin_until_done(node: Node, executor, stop: threading.Event) -> int:
    """Spin until the node reports completion (``node.done``, its exit status) or a stop signal."""
    while rclpy.ok() and not stop.is_set() and not node.done.done():
        executor.spin_until_future_complete(node.done, timeout_sec=0.1)
    return int(node.done.result() or 0) if node.done.done() else 0


def _check_parameter_files(prog: str, argv: list[str]) -> bool:
    """Check each ``--params-file`` first: one clear line instead of rcl's parser message."""
    for i, a in enumerate(argv[:-1]):
        if a == "--params-file":
            try:
                check_ros_params(argv[i + 1])
            except ConfigError as exc:
                print(f"{prog}: {exc}", file=sys.stderr)
                return False
    return True


def run(node_cls, args=None) -> int:
    """Start a magtune node and return its exit status: the one main of every node.

    Parameter files are checked first; ``node_cls.parse_options(argv)`` (if the node has
    command-line options, as ``ros2 bag`` does) parses the arguments that are not ROS
    arguments; then rclpy starts, the node is built (``node_cls(options)`` or ``node_cls()``),
    added to ``node_cls.EXECUTOR()`` (default :func:`make_executor`) and spun by
    ``node.spin(executor, stop)`` if it has one, else until ``node.done``. SIGINT,
    SIGTERM and SIGHUP end the spin; ``node.finish()`` then runs and rclpy shuts down. A bad
    parameter or option (ParamError, ConfigError, or one of ``node_cls.START_ERRORS``) prints
    one line naming it and returns 2.
    """
    prog = node_cls.NODE_NAME
    argv = list(sys.argv if args is None else args)
    if not _check_parameter_files(prog, argv):
        return 2
    start_errors = (ParamError, ConfigError, *getattr(node_cls, "START_ERRORS", ()))
    parse_options = getattr(node_cls, "parse_options", None)
    try:
        options = parse_options(remove_ros_args(argv)[1:]) if parse_options else None
    except start_errors as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # malformed --params-file etc.
        print(f"{prog}: cannot start: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    stop = install_stop_handlers()
    node = executor = None
    code = 0
    try:
        node = node_cls(options) if parse_options else node_cls()
        executor = (getattr(node_cls, "EXECUTOR", None) or make_executor)()
        executor.add_node(node)
        if isinstance(node, ManagedNode) and not node.autostart():
            print(f"{prog}: {node.config_error}", file=sys.stderr)
            return 2
        code = _spin_profiled(prog, node, executor, stop)
    except start_errors as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    finally:
        _shutdown(prog, node, executor)
    return code


def _spin_profiled(prog: str, node: Node, executor, stop: threading.Event) -> int:
    """The node's spin; with MAGTUNE_PROFILE=DIR a cProfile of it is dumped to DIR/<prog>.prof."""
    prof = os.environ.get("MAGTUNE_PROFILE")
    profiler = None
    if prof:
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    try:
        spin = getattr(node, "spin", None)
        return int(spin(executor, stop) or 0) if spin else spin_until_done(node, executor, stop)
    finally:
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(os.path.join(prof, f"{prog}.prof"))


def _shutdown(prog: str, node, executor) -> None:
    if node is not None:
        try:
            node.finish()
        except Exception as exc:  # noqa: BLE001 - best effort at shutdown
            print(f"{prog}: error while finishing: {exc}", file=sys.stderr)
    if executor is not None:
        executor.shutdown()
    if node is not None:
        node.destroy_node()
    rclpy.try_shutdown()
