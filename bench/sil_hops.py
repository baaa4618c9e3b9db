"""SIL hops: where one lockstep SIL step's time goes, per message and per hop, for the messages the SIL sends.

    python bench/sil_hops.py [--n 1500] [--sil] [--dds sil|localhost]

Per topic of one step (environment full, truth feedback: the simulator's sim/* truth, /tf, /clock, markers and
torques, the sensors' measurements, the controller's dipole command), with the preallocated message of the node:
  1. fill: the node's field assignments into the preallocated message (Python), us;
  2. serialize / deserialize: rclpy.serialization.serialize_message / deserialize_message, us;
  3. publish: Publisher.publish with 0 matched subscribers and with 1 subscriber in another process, us;
  4. round trip: one Vector3Stamped out, one answer back (LOCKSTEP_QOS), between two processes with the
     EventsExecutor and with the SingleThreadedExecutor on both sides, and with both nodes in one process on
     one executor (the "composed" alternative), us;
  5. a summary: the parts summed per step (critical path simulator -> sensors -> controller -> simulator, and all
     messages), next to the measured ms/step of a real run with ``--sil`` (run_sil, LQ sigma=60 gain, 0.3 orbit,
     environment full).
Every timing is the median over 5 blocks of n/5 calls, but pub1: the median of n single calls 0.2 ms apart (the subscriber
takes each message before the next), and round trips: one block of n after 100 warm-up trips.
The helper processes (a subscriber of every topic, the pong side) are this script (``--child``), started in their
own process group with a ROS_DOMAIN_ID reserved by DomainLock and the SIL's DDS scope (``--dds sil``: the
loopback Fast DDS profile of process.dds_env; ``localhost``: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST as the bag
tests), dying with this process and stopped in a ``finally``.
"""
import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import rclpy  # noqa: E402
from geometry_msgs.msg import Vector3Stamped, WrenchStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from rclpy.task import Future  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, MagneticField  # noqa: E402

from magtune_core.base import topics as tp  # noqa: E402
from magtune_core.ros.process import DomainLock, dds_env, die_with_parent  # noqa: E402
from magtune_ros.inputs import ns_to_stamp  # noqa: E402
from magtune_ros.qos import CLOCK_QOS, LOCKSTEP_QOS  # noqa: E402
from magtune_ros.simulator import Simulator  # noqa: E402

#: rclpy's TimeSource subscribes /clock best-effort, depth 1 (the SIL's use_sim_time nodes)
CLOCK_SUB_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
WARM_TRIPS = 100
#: s between two timed publishes to a subscriber: it takes each before the next (a burst would fill its queue)
PACE = 0.0002
EXECUTORS = {"events": EventsExecutor, "single": SingleThreadedExecutor}


@dataclass
class Row:
    """One topic of a SIL step: who publishes it, its preallocated message, the node's fill, its subscribers in the SIL."""
    node: str
    topic: str
    make: object        # () -> the preallocated message, constant fields set
    fill: object        # (msg, data, stamp) -> None: the node's per-step assignments
    sil_subs: int       # matched subscribers in a SIL run without recorder or estimator
    critical: bool      # on the lockstep chain simulator -> sensors -> controller -> simulator
    per_step: float = 1.0  # messages per step (sim/torquer_field: only with coupled torquers, 0 by default)


def _framed(cls, frame="body", child=None):
    m = cls()
    m.header.frame_id = frame
    if child:
        m.child_frame_id = child
    return m


def _imu(orientation: bool):
    m = _framed(Imu)
    m.angular_velocity_covariance = [1e-8, 0.0, 0.0, 0.0, 1e-8, 0.0, 0.0, 0.0, 1e-8]
    m.linear_acceleration_covariance[0] = -1.0
    if orientation:
        m.orientation_covariance = [1e-6, 0.0, 0.0, 0.0, 1e-6, 0.0, 0.0, 0.0, 1e-6]
    else:
        m.orientation_covariance[0] = -1.0
    return m


# ---------------------------------------------------------------- the nodes' fills (simulator.py, attitude_sensors.py, controller.py)
def fill_truth(m, d, st):
    m.header.stamp = st
    y, o = d.y, m.pose.pose.orientation
    o.w, o.x, o.y, o.z = float(y[0]), float(y[1]), float(y[2]), float(y[3])
    a = m.twist.twist.angular
    a.x, a.y, a.z = (float(v) for v in d.w)


def fill_rate(m, d, st):
    m.header.stamp = st
    m.vector.x, m.vector.y, m.vector.z = float(d.y[4]), float(d.y[5]), float(d.y[6])


def fill_field(m, d, st):
    m.header.stamp = st
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = float(d.b[0]), float(d.b[1]), float(d.b[2])


def fill_torquer_field(m, d, st):
    m.header.stamp = st
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = (float(x) for x in d.b)


def fill_orbit(o, d, st):
    o.header.stamp = st
    p, w = o.pose.pose.position, o.twist.twist.linear
    p.x, p.y, p.z = float(d.r[0]), float(d.r[1]), float(d.r[2])
    w.x, w.y, w.z = float(d.v[0]), float(d.v[1]), float(d.v[2])


def fill_sim_sun(u, d, st):
    u.header.stamp = st
    u.vector.x, u.vector.y, u.vector.z = float(d.s[0]), float(d.s[1]), float(d.s[2])


def fill_tf(m, d, st):
    body, orb = m.transforms
    body.header.stamp = st
    body.transform.rotation = d.truth.pose.pose.orientation
    orb.header.stamp = st
    tr, rot = orb.transform.translation, orb.transform.rotation
    tr.x, tr.y, tr.z = float(d.r[0]), float(d.r[1]), float(d.r[2])
    rot.w, rot.x, rot.y, rot.z = float(d.q[0]), float(d.q[1]), float(d.q[2]), float(d.q[3])


def fill_clock(m, d, st):
    m.clock = st


def fill_markers(m, d, st):
    mk = m.markers
    for mark, vec, scale in ((mk[1], d.b, 0.05e6), (mk[2], d.m, 0.2)):
        tip = mark.points[1]
        tip.x, tip.y, tip.z = float(vec[0] * scale), float(vec[1] * scale), float(vec[2] * scale)
    for mark in mk:
        mark.header.stamp = st


def fill_torque(m, d, st):
    m.header.stamp = st
    m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z = float(d.t[0]), float(d.t[1]), float(d.t[2])


def fill_mag(m, d, st):
    m.header.stamp = st
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = (float(x) for x in d.b)


def fill_attitude(att, d, st):
    att.header.stamp = st
    att.angular_velocity = d.imu.angular_velocity
    a = att.orientation
    a.w, a.x, a.y, a.z = (float(x) for x in d.q)


def fill_imu(imu, d, st):
    imu.header.stamp = st
    r = imu.angular_velocity
    r.x, r.y, r.z = (float(x) for x in d.w)


def fill_position(pos, d, st):
    pos.header.stamp = st
    pp, pv = pos.pose.pose.position, pos.twist.twist.linear
    pp.x, pp.y, pp.z = (float(x) for x in d.r)
    pv.x, pv.y, pv.z = (float(x) for x in d.v)


def fill_sensor_sun(m, d, st):
    m.header.stamp = st
    m.vector.x, m.vector.y, m.vector.z = (float(x) for x in d.s)


def fill_dipole(msg, d, st):
    msg.header.stamp = ns_to_stamp(d.ns)  # the controller builds its stamp from the input's ns
    msg.vector.x, msg.vector.y, msg.vector.z = float(d.m[0]), float(d.m[1]), float(d.m[2])


_SIM = SimpleNamespace(environment="full")  # Simulator._make_tf / _make_markers read only this
ROWS = [
    Row("simulator", tp.TOPIC_TRUTH, lambda: _framed(Odometry, "orbital", "body"), fill_truth, 1, True),
    Row("simulator", tp.TOPIC_INERTIAL_RATE, lambda: _framed(Vector3Stamped), fill_rate, 1, True),
    Row("simulator", tp.TOPIC_TRUE_FIELD, lambda: _framed(MagneticField), fill_field, 1, True),
    Row("simulator", tp.TOPIC_ORBIT, lambda: _framed(Odometry, "eci", "eci"), fill_orbit, 1, False),
    Row("simulator", tp.TOPIC_TRUE_SUN, lambda: _framed(Vector3Stamped, "eci"), fill_sim_sun, 1, False),
    Row("simulator", tp.TOPIC_TF, lambda: Simulator._make_tf(_SIM), fill_tf, 0, False),
    Row("simulator", tp.TOPIC_CLOCK, Clock, fill_clock, 2, False),
    # published after the next state since the sensors and the controller wait for that (off without a bag or a live view)
    Row("simulator", tp.TOPIC_MARKERS, lambda: Simulator._make_markers(_SIM), fill_markers, 0, False),
    Row("simulator", tp.TOPIC_MAG_TORQUE, lambda: _framed(WrenchStamped), fill_torque, 0, False),
    Row("simulator", tp.TOPIC_DIST_TORQUE, lambda: _framed(WrenchStamped), fill_torque, 0, False),
    Row("simulator", tp.TOPIC_TORQUER_FIELD, lambda: _framed(MagneticField), fill_torquer_field, 1, False, 0.0),
    Row("sensors", tp.TOPIC_MAG, lambda: _framed(MagneticField), fill_mag, 1, True),
    Row("sensors", tp.TOPIC_ATTITUDE, lambda: _imu(True), fill_attitude, 1, True),
    Row("sensors", tp.TOPIC_IMU, lambda: _imu(False), fill_imu, 0, False),
    Row("sensors", tp.TOPIC_POSITION, lambda: _framed(Odometry, "eci", "eci"), fill_position, 0, False),
    Row("sensors", tp.TOPIC_SUN, lambda: _framed(Vector3Stamped), fill_sensor_sun, 0, False),
    Row("controller", tp.TOPIC_DIPOLE, lambda: _framed(Vector3Stamped), fill_dipole, 1, True),
]


def step_data():
    """The numbers a step fills in (numpy arrays as in the nodes; values do not matter for the cost)."""
    rng = np.random.default_rng(0)
    d = SimpleNamespace(y=rng.normal(size=7), w=rng.normal(size=3), b=rng.normal(size=3) * 3e-5, r=rng.normal(size=3) * 7e6,
                        v=rng.normal(size=3) * 7e3, s=rng.normal(size=3), q=rng.normal(size=4), m=rng.normal(size=3),
                        t=rng.normal(size=3) * 1e-7, ns=1_234_000_000_000, truth=Odometry(), imu=Imu())
    return d, ns_to_stamp(d.ns)


def topic(prefix: str, row: Row) -> str:
    """The benchmark's own name of a row's topic (``prefix`` + the SIL name without its leading slash)."""
    return prefix + row.topic.lstrip("/")


def qos_pub(row: Row):
    return CLOCK_QOS if row.topic == tp.TOPIC_CLOCK else LOCKSTEP_QOS


def qos_sub(row: Row):
    return CLOCK_SUB_QOS if row.topic == tp.TOPIC_CLOCK else LOCKSTEP_QOS


def per_call_us(fn, n: int, blocks: int = 5, pace: float = 0.0) -> float:
    """Median over ``blocks`` blocks of n/blocks calls of ``fn()``, us per call; ``pace`` > 0: the median of n calls each
    timed alone with ``pace`` s of sleep between (a subscriber takes each message before the next, as in a lockstep step;
    the median, as one preempted call weighs a lot on a loaded machine)."""
    if pace:
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
            time.sleep(pace)
        return 1e6 * statistics.median(times)
    m = max(1, n // blocks)
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(m):
            fn()
        times.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(times) / m


# ---------------------------------------------------------------- helper processes (--child)
class Children:
    """Helper processes of this script: own process group, die with the parent, DomainLock fd inherited; ``stop_all`` in a finally."""

    def __init__(self, env: dict, log_dir: Path, lock: DomainLock):
        self.env, self.log_dir, self.lock, self.procs = env, log_dir, lock, []

    def start(self, role: str, executor: str, prefix: str) -> subprocess.Popen:
        log = self.log_dir / f"{role}_{executor}_{len(self.procs)}.log"
        with open(log, "wb") as fh:
            p = subprocess.Popen([sys.executable, __file__, "--child", role, "--executor", executor, "--prefix", prefix],
                                 env=self.env, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 start_new_session=True, pass_fds=(self.lock.fh.fileno(),), preexec_fn=die_with_parent())
        p.log = log
        self.procs.append(p)
        end = time.monotonic() + 60.0  # a Python+rclpy start: 1-2 s idle, 20 s on a loaded 2-core box
        while b"ready" not in log.read_bytes():
            if p.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"helper {role} did not start:\n{log.read_text(errors='replace')}")
            time.sleep(0.05)
        return p

    @staticmethod
    def stop(p: subprocess.Popen) -> str:
        """SIGINT to its group, SIGKILL after 5 s; its log."""
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGINT)
                p.wait(timeout=5.0)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                p.wait()
        return p.log.read_text(errors="replace")

    def stop_all(self) -> None:
        for p in self.procs:
            self.stop(p)


def make_pong(node: Node, prefix: str) -> None:
    """The answering side: every ping refilled into a preallocated Vector3Stamped and published back (as the controller)."""
    out = _framed(Vector3Stamped)
    pub = node.create_publisher(Vector3Stamped, prefix + "pong", LOCKSTEP_QOS)

    def on_ping(msg):
        out.header.stamp = msg.header.stamp
        out.vector.x, out.vector.y, out.vector.z = msg.vector.x, msg.vector.y, msg.vector.z
        pub.publish(out)
    node.create_subscription(Vector3Stamped, prefix + "ping", on_ping, LOCKSTEP_QOS)


def child(a) -> None:
    """``--child sub``: subscribes to every row's topic and counts; ``--child pong``: the pong side; until SIGINT/SIGTERM."""
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = Node(f"hops_{a.child}")
    got = [0]

    def count(_msg):
        got[0] += 1
    if a.child == "sub":
        for row in ROWS:
            node.create_subscription(type(row.make()), topic(a.prefix, row), count, qos_sub(row))
    else:
        make_pong(node, a.prefix)
    ex = EXECUTORS[a.executor]()
    ex.add_node(node)
    print("ready", flush=True)
    never = Future()
    while not stop.is_set():
        ex.spin_until_future_complete(never, timeout_sec=0.1)
    print(f"received {got[0]}", flush=True)
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()


# ---------------------------------------------------------------- measurements
def wait_matched(entities, timeout: float = 60.0, settle: float = 0.5) -> None:
    """Until every publisher has a subscriber and every subscription a publisher (then ``settle`` s more)."""
    end = time.monotonic() + timeout
    while not all((e.get_subscription_count() if hasattr(e, "get_subscription_count") else e.get_publisher_count()) >= 1
                  for e in entities):
        if time.monotonic() > end:
            raise RuntimeError("helper process not matched within 60 s")
        time.sleep(0.02)
    time.sleep(settle)


def measure_messages(node: Node, children: Children, n: int) -> tuple[list[dict], str]:
    """Fill, serialize, deserialize, publish with 0 and with 1 remote subscriber, per row; and the subscriber's log."""
    d, st = step_data()
    out = []
    for row in ROWS:
        msg = row.make()
        row.fill(msg, d, st)
        raw = serialize_message(msg)
        cls = type(msg)
        pub0 = node.create_publisher(cls, topic("hops0/", row), qos_pub(row))
        out.append(dict(row=row, type=cls.__name__, bytes=len(raw), msg=msg,
                        fill=per_call_us(lambda r=row, m=msg: r.fill(m, d, st), n),
                        ser=per_call_us(lambda m=msg: serialize_message(m), n),
                        deser=per_call_us(lambda b=raw, c=cls: deserialize_message(b, c), n),
                        pub0=per_call_us(lambda p=pub0, m=msg: p.publish(m), n)))
    pubs = [node.create_publisher(type(r["msg"]), topic("hops1/", r["row"]), qos_pub(r["row"])) for r in out]
    sub = children.start("sub", "events", "hops1/")
    wait_matched(pubs)
    for r, pub in zip(out, pubs):
        r["pub1"] = per_call_us(lambda p=pub, m=r["msg"]: p.publish(m), n, pace=PACE)
    time.sleep(0.5)  # let the subscriber drain before it reports
    return out, Children.stop(sub)


class Pinger:
    """The timing side of the ping-pong: sends ping k, waits for pong k (stamp.sec), sends ping k+1."""

    def __init__(self, node: Node, prefix: str, n: int):
        self.pub = node.create_publisher(Vector3Stamped, prefix + "ping", LOCKSTEP_QOS)
        self.sub = node.create_subscription(Vector3Stamped, prefix + "pong", self.on_pong, LOCKSTEP_QOS)
        self.msg, self.k, self.n, self.done, self.t0 = _framed(Vector3Stamped), 0, n, Future(), 0.0

    def send(self):
        self.msg.header.stamp.sec = self.k
        self.msg.vector.x = float(self.k)
        self.pub.publish(self.msg)

    def on_pong(self, msg):
        if msg.header.stamp.sec != self.k:
            return  # a duplicate from transient-local history: not ours
        self.k += 1
        if self.k == WARM_TRIPS:
            self.t0 = time.perf_counter()
        if self.k == WARM_TRIPS + self.n:
            self.done.set_result(1e6 * (time.perf_counter() - self.t0) / self.n)
            return
        self.send()


def round_trip(children: Children, executor: str, composed: bool, n: int, tag: str) -> float:
    """us per round trip: the pong side in a helper process (``composed`` False) or in this process on the same executor."""
    prefix = f"rt_{tag}/"
    node = Node(f"hops_ping_{tag}")
    pinger = Pinger(node, prefix, n)
    pong = helper = None
    ex = EXECUTORS[executor]()
    try:
        if composed:
            pong = Node(f"hops_pong_{tag}")
            make_pong(pong, prefix)
            ex.add_node(pong)
        else:
            helper = children.start("pong", executor, prefix)
        wait_matched([pinger.pub, pinger.sub])
        ex.add_node(node)
        pinger.send()
        ex.spin_until_future_complete(pinger.done, timeout_sec=60.0 + 0.01 * n)
        if not pinger.done.done():
            raise RuntimeError(f"round trip {tag}: only {pinger.k} trips within the timeout")
        return pinger.done.result()
    finally:
        ex.shutdown()
        for nd in (node, pong):
            if nd is not None:
                nd.destroy_node()
        if helper is not None:
            Children.stop(helper)


# ---------------------------------------------------------------- report
def print_messages(res: list[dict], sub_log: str, n: int) -> None:
    """The per-topic table and the subscriber's receive count."""
    print("fill: the node's assignments into its preallocated message (Python, float() of numpy values), median of 5 blocks")
    print("ser / deser: rclpy.serialization.serialize_message / deserialize_message of the filled message")
    print("pub0 / pub1: Publisher.publish (LOCKSTEP_QOS; /clock CLOCK_QOS) with 0 / 1 matched subscriber in another process "
          f"(EventsExecutor, /clock best-effort as rclpy's TimeSource); pub1: median of single calls {1e3 * PACE:.1f} ms apart")
    print(f"{'node':10s} {'topic':26s} {'type':15s} {'/step':>5s} {'subs':>4s} {'bytes':>5s} "
          f"{'fill':>6s} {'ser':>6s} {'deser':>6s} {'pub0':>6s} {'pub1':>6s}  [us]")
    for r in res:
        row = r["row"]
        flag = ("*" if row.critical else " ")
        print(f"{row.node:10s} {row.topic + flag:26s} {r['type']:15s} {row.per_step:5.0f} {row.sil_subs:4d} {r['bytes']:5d} "
              f"{r['fill']:6.1f} {r['ser']:6.1f} {r['deser']:6.1f} {r['pub0']:6.1f} {r['pub1']:6.1f}")
    print("* on the lockstep critical path; subs: matched subscribers in the SIL (truth feedback, no recorder; /clock: 2, "
          "measured with 1); sim/torquer_field only with coupled torquers (0 per step by default)")
    last = sub_log.strip().splitlines()[-1] if sub_log.strip() else "(no log)"
    print(f"subscriber process: {last} of {len(ROWS) * n} published")


def step_costs(res: list[dict], critical: bool) -> dict:
    """us per step by part: each node's fills + publishes (pub1 where the SIL has subscribers), the receivers' deserializations."""
    parts = {"simulator": 0.0, "sensors": 0.0, "controller": 0.0, "deserialize": 0.0}
    for r in res:
        row = r["row"]
        if critical and not row.critical:
            continue
        pub = r["pub1"] if row.sil_subs else r["pub0"]
        parts[row.node] += row.per_step * (r["fill"] + pub)
        parts["deserialize"] += row.per_step * r["deser"] * (min(row.sil_subs, 1) if critical else row.sil_subs)
    return parts


def print_summary(res: list[dict], rts: dict, sil_ms: float | None) -> None:
    """Per SIL step: the parts (critical path and all messages), 3 hops of wire + wake-up, their sum; the alternatives; the run."""
    dip = next(r for r in res if r["row"].topic == tp.TOPIC_DIPOLE)
    wake = rts["2 proc events"] / 2 - (dip["fill"] + dip["pub1"] + dip["deser"])  # a round trip's side minus its message work
    print(f"hop wire + wake-up = round trip / 2 - (fill + pub1 + deser of a Vector3Stamped) = {wake:.0f} us (2 processes, events)")
    crit, every = step_costs(res, True), step_costs(res, False)
    print(f"{'per SIL step [ms]':56s} {'critical path':>13s} {'all messages':>13s}")
    for part in crit:
        n_c = sum(r["row"].per_step for r in res if r["row"].node == part and r["row"].critical)
        n_a = sum(r["row"].per_step for r in res if r["row"].node == part)
        # the SIL's sensors, estimator, controller and mode manager read raw bytes (magtune_ros.raw): the rclpy message
        # they would otherwise build is this row
        what = f"{part}: fill + publish ({n_c:.0f} / {n_a:.0f} msgs)" if part != "deserialize" else "receivers: deserialize (not paid: raw)"
        print(f"{what:56s} {crit[part] / 1e3:13.3f} {every[part] / 1e3:13.3f}")
    print(f"{'3 hops wire + wake-up (2 processes, EventsExecutor)':56s} {3 * wake / 1e3:13.3f} {3 * wake / 1e3:13.3f}")
    s_c, s_a = (sum(v for k, v in d.items() if k != "deserialize") + 3 * wake for d in (crit, every))
    print(f"{'sum of parts (deserialize not counted)':56s} {s_c / 1e3:13.3f} {s_a / 1e3:13.3f}")
    for name, other in (("composed, events", "composed events"), ("SingleThreadedExecutor", "2 proc single")):
        d = 1.5 * (rts[other] - rts["2 proc events"]) / 1e3  # 3 hops = 1.5 round trips
        print(f"{'  ' + name + ' instead (1.5 x RT diff)':56s} {d:+13.3f} {d:+13.3f}")
    if sil_ms is not None:
        print(f"{'measured SIL (run_sil, environment full, 0.3 orbit)':56s} {sil_ms:13.3f}")
        print(f"{'remainder (physics, sensor models, law, dispatch)':56s} {sil_ms - s_c / 1e3:13.3f} {sil_ms - s_a / 1e3:13.3f}")


def run_sil_ms(tmp: Path) -> float:
    """ms/step of a real lockstep run (LQ sigma=60 gain as bench/sil_rtf.py, 0.3 orbit, environment full)."""
    from magtune_core.design.gains import save_gains
    from magtune_core.design.lq import lq_gains
    from magtune_core.design.model import AttitudeLTP
    from magtune_core.design.params import SpacecraftParams
    from magtune_core.ros import sil
    gains = tmp / "sigma_60.yaml"
    save_gains(gains, lq_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, 1.0))
    run = sil.run_sil(gains, orbits=0.3, ts=1.0, log_dir=tmp / "sil", environment="full")
    ms = 1e3 * run.wall_time / len(run.result.t)
    print(f"SIL run: {len(run.result.t)} steps, RTF {run.real_time_factor:.0f}x, {ms:.3f} ms/step, "
          f"missed steps {run.counters.get('missed_steps')}")
    return ms


def environment(dds: str, lock: DomainLock) -> dict:
    """This process's and the helpers' environment: the reserved domain, the DDS scope of ``dds``."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(lock.domain_id), PYTHONUNBUFFERED="1")
    env.pop("ROS_STATIC_PEERS", None)
    if dds == "sil":
        dds_env(env, "loopback")
    else:
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env


def measure(a, tmp: Path) -> tuple[list[dict], dict]:
    """Everything over DDS, in a reserved domain; the helpers stopped and the domain released whatever happens."""
    lock = DomainLock()
    env = environment(a.dds, lock)
    os.environ.update(env)  # before rclpy.init: the domain and the Fast DDS profile of this process too
    children = Children(env, tmp, lock)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    try:
        print(f"ROS_DOMAIN_ID {lock.domain_id}, DDS {a.dds}, n {a.n}")
        node = Node("hops_bench")
        res, sub_log = measure_messages(node, children, a.n)
        node.destroy_node()
        print_messages(res, sub_log, a.n)
        print(f"round trip: ping k out, pong k back (Vector3Stamped, LOCKSTEP_QOS, each side refills and publishes), "
              f"{a.n} trips after {WARM_TRIPS} warm-up, wall / n")
        rts = {}
        for name, executor, composed in (("2 proc events", "events", False), ("2 proc single", "single", False),
                                         ("composed events", "events", True), ("composed single", "single", True)):
            rts[name] = round_trip(children, executor, composed, a.n, name.replace(" ", "_"))
            print(f"  {name:16s} {rts[name]:8.1f} us/round trip"
                  + ("  (both nodes in one process, one executor)" if composed else "  (two processes)"))
        return res, rts
    finally:
        children.stop_all()
        rclpy.try_shutdown()
        lock.release()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1500, help="calls per measurement and round trips per variant")
    ap.add_argument("--sil", action="store_true", help="also a real run (0.3 orbit, environment full): its ms/step")
    ap.add_argument("--dds", choices=("sil", "localhost"), default="sil",
                    help="sil: the SIL's loopback Fast DDS profile (process.dds_env); localhost: ROS_AUTOMATIC_DISCOVERY_RANGE only")
    ap.add_argument("--child", choices=("sub", "pong"), help=argparse.SUPPRESS)
    ap.add_argument("--executor", choices=tuple(EXECUTORS), default="events", help=argparse.SUPPRESS)
    ap.add_argument("--prefix", default="", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        return child(a)
    tmp = Path(tempfile.mkdtemp(prefix="magtune_hops_"))
    print(f"load before: {_load()}")
    t0 = time.perf_counter()
    res, rts = measure(a, tmp)
    sil_ms = run_sil_ms(tmp) if a.sil else None
    print_summary(res, rts, sil_ms)
    print(f"load after: {_load()}; {time.perf_counter() - t0:.0f} s")


def _load() -> str:
    """The 1-, 5- and 15-minute load averages."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


if __name__ == "__main__":
    main()
