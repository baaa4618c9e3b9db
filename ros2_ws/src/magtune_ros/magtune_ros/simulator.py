"""Attitude simulator node: nonlinear dynamics + environment, source of simulated time.

Physics: ``magtune_core.sim.dynamics.AttitudeDynamics`` (rigid body, pitch wheel, gravity gradient,
residual dipole, eq. 26 field; other field models and disturbance torques plug in through the
``field_plugin`` / ``field_file`` (a ``magtune fit-field`` output) / ``disturbance_plugins`` parameters) with ``environment: paper`` (default), or
``magtune_core.sim.fullenv.FullDynamics`` with ``environment: full`` (J2 orbit, IGRF degree
``igrf_degree``, gravity gradient with the actual radius, drag, SRP; switches ``env_*``; the
nominal orbit period is the ``orbit_period`` given, which ``magtune sil`` derives once for every
node from the actual orbit), integrated with the same RK4 steps as the offline
``magtune_core.sim.simulate.simulate`` (``substeps`` per step, re-chosen every step from the rate up to
``max_substeps``: ``magtune_core.sim.substeps.Substeps``); the commanded dipole is held over each step (ZOH).

Publishes (all stamped with simulated time t_k = k * ts):
  /clock                       rosgraph_msgs/Clock        (this node is the time source)
  sim/truth                    nav_msgs/Odometry          frame 'orbital', child 'body' (REP-105):
                               pose.orientation = q (body w.r.t. orbital axes; ROS x,y,z,w order),
                               twist.angular = rate of the body w.r.t. the orbital frame [rad/s] in
                               body axes, w - R(q)^T w_oi(t) (w_oi = [0, 0, -W0] on the circular orbit),
                               pose.position / twist.linear = 0 (attitude only)
  sim/inertial_rate            geometry_msgs/Vector3Stamped  inertial body rate w [rad/s], body axes
                               (the paper's w, what a gyro measures; the sensors' input)
  sim/magnetic_field           sensor_msgs/MagneticField  true field b = R(q)^T b_orb(t) [T], body axes
  sim/orbit                    nav_msgs/Odometry (environment 'full' only) frame 'eci', child 'eci':
                               pose.position = r [m], twist.linear = v [m/s] (ECI), orientation identity
  sim/sun                      geometry_msgs/Vector3Stamped (environment 'full' only) frame 'eci':
                               geocentric Sun position [m] (the environment's, env.sun)
  sim/torquer_field            sensor_msgs/MagneticField (only with a nonzero ``torquer_coupling``): the
                               torquers' field at the magnetometer at t_k [T], body axes, from the dipole
                               applied over the last period (onboard.torquers.Torquers.field)
  sim/magnetic_torque          geometry_msgs/WrenchStamped  m x b at t_k [N m], body axes
  sim/disturbance_torque       geometry_msgs/WrenchStamped  gravity gradient + residual dipole (+ drag, SRP) at t_k
  /diagnostics                 diagnostic_msgs/DiagnosticArray (steps, missed_steps, rejected, ...)
  /tf                          tf2_msgs/TFMessage (``publish_tf``): orbital -> body (rotation q, the
                               pose of sim/truth) and, with environment 'full', eci -> orbital
                               (translation r [m], rotation = orbital axes in ECI); Foxglove's 3D panel
  sim/markers                  visualization_msgs/MarkerArray (``publish_markers``), frame body: the
                               0.6 x 1.0 x 0.8 m box, arrows of the true field (MARKER_FIELD_SCALE m per uT)
                               and of the applied dipole (MARKER_DIPOLE_SCALE m per A m^2) of step k
  Stamps are ``time_origin_ns`` + k * ts: 0 by default (sim time from 0), the scenario epoch in
  ns since 1970 with ``magtune sil --epoch-time`` (tools then show real dates).
Subscribes:
  controller/dipole_command    geometry_msgs/Vector3Stamped [A m^2], body axes; saturated per axis.

Faults (parameter ``faults``, magtune_core.design.faults): the torquer faults act on the applied
dipole (``faults.actuate``: the truth side, recorded in the results); the duty cycle
(``torquer_off_time``, TORQUER_FIELDS) switches the torquers off for the end of every step
(``Torquers.substep_weights``); at a ``sensors_killed`` fault's
time the simulator logs ``fault sensors_killed at t=...`` and holds that step 1 s of wall time, so
the runner's SIGKILL of attitude_sensors lands at that sim time.

Lockstep (default): the state at t_k is published, then the simulator waits for the command
stamped t_k before integrating to t_k+1; after ``lockstep_timeout`` wall seconds it holds the
last command and counts a missed step. ``real_time_factor`` > 0 paces against the wall clock
(0 = as fast as possible). With ``lockstep: false`` the simulator free-runs at
``real_time_factor`` and applies the latest command. At the end it writes ``results_path``
(.npz, the arrays of ``magtune_core.sim.simulate.SimResult`` plus counters) and exits.
"""
from __future__ import annotations

import json
import time

import numpy as np
from geometry_msgs.msg import Point, TransformStamped, Vector3Stamped, WrenchStamped
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import MagneticField
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from magtune_core.base.errors import ConfigError
from magtune_core.base.rotations import cross, matrix_to_quat
from magtune_core.base.topics import (
    FRAME_BODY,
    FRAME_ECI,
    FRAME_ORBITAL,
    TOPIC_DIPOLE,
    TOPIC_DIST_TORQUE,
    TOPIC_INERTIAL_RATE,
    TOPIC_MAG_TORQUE,
    TOPIC_MARKERS,
    TOPIC_ORBIT,
    TOPIC_TF,
    TOPIC_TORQUER_FIELD,
    TOPIC_TRUE_FIELD,
    TOPIC_TRUE_SUN,
    TOPIC_TRUTH,
)
from magtune_core.design import faults as fl
from magtune_core.design.fitfield import field_for_spacecraft
from magtune_core.design.node_params import FAULTS, SIMULATOR_FIELDS, check_simulator
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.law import linear_state, saturate
from magtune_core.onboard.params import TORQUER_FIELDS
from magtune_core.onboard.torquers import Torquers
from magtune_core.sim.fullenv import FullEnvironmentOptions, make_dynamics
from magtune_core.sim.simulate import DIVERGED_EXIT, STARTUP_EXIT, SimResult, divergence, initial_state
from magtune_core.sim.substeps import Substeps

from .diagnostics import Diagnostics
from .inputs import finite, ns_to_stamp, sec_to_ns, stamp_to_ns
from .main import run
from .params import ParamError, check, check_ts, from_schema, param_error, parse_fields
from .qos import CLOCK_QOS, LOCKSTEP_QOS

#: Arrow lengths of sim/markers: field 0.05 m per uT (|b| 20-50 uT -> 1-2.5 m), dipole 0.2 m per A m^2
MARKER_FIELD_SCALE = 0.05e6
MARKER_DIPOLE_SCALE = 0.2
BOX_DIMS = (0.6, 1.0, 0.8)  # magtune_core.env.geometry.BoxGeometry default [m]


def load_plugin(spec: str):
    """Import ``module:attribute`` (e.g. an environment model of magtune_core)."""
    import importlib

    mod, _, attr = spec.partition(":")
    if not mod or not attr:
        raise ValueError("expected 'module:function'")
    return getattr(importlib.import_module(mod), attr)


class Simulator(Node):
    """The simulator node (plain, the time source): integrates the dynamics, publishes /clock and the sim/* truth, takes
    controller/dipole_command (lockstep by default); writes ``results_path`` and ends when the run is done."""
    NODE_NAME = "simulator"

    def __init__(self):
        super().__init__(self.NODE_NAME)
        self.done = Future()
        v = self.load_parameters()
        self.build_plant(v)
        self.make_interfaces()

    def load_parameters(self) -> dict:
        """The spacecraft file's schema and SIMULATOR_FIELDS, declared from the schemas and
        validated once; the orbit period is the one given (``magtune sil`` derives it)."""
        self.p = from_schema(self, SpacecraftParams)
        v = parse_fields(self, SIMULATOR_FIELDS)
        check(check_simulator, v, self)
        check_ts(v["ts"], self.p)
        self.ts, self.substeps, self.m_max = v["ts"], v["substeps"], v["dipole_limit"]
        self.lockstep, self.timeout, self.startup_timeout = v["lockstep"], v["lockstep_timeout"], v["startup_timeout"]
        self.rtf, self.results_path, self.pub_torques = v["real_time_factor"], v["results_path"], v["publish_torques"]
        self.wait_peers, self.pub_tf_on, self.pub_markers_on = v["wait_for_peers"], v["publish_tf"], v["publish_markers"]
        self.time_origin_ns, self.min_subs = v["time_origin_ns"], v["min_truth_subscribers"]
        self.environment = v["environment"]
        self.n = v["steps"] if v["steps"] > 0 else int(round(v["orbits"] * self.p.orbit_period / self.ts))
        try:
            self.faults = fl.from_list(parse_fields(self, (FAULTS,))["faults"], "faults")
        except ConfigError as exc:
            raise param_error(exc) from None
        self.fault_state, self.kill_t = fl.FaultState(), fl.kill_time(self.faults)
        self.torquers = Torquers.from_values(parse_fields(self, TORQUER_FIELDS))
        try:
            self.torquers.check(self.ts, "parameters")
        except ConfigError as exc:
            raise param_error(exc) from None
        # the sub-steps re-chosen every step from the rate, the duty cycle's switch-off on the grid
        self.rule = Substeps.ladder(self.ts, self.substeps, max(self.substeps, v["max_substeps"]), self.torquers)
        self.substeps, self.weights = self.rule.most, self.rule.weights(self.torquers)
        return v

    def build_plant(self, v: dict) -> None:
        """The dynamics of ``environment`` (with the field and disturbance plug-ins), the initial
        state and the buffers of the recorded run (the layout of SimResult)."""
        p = self.p
        opts = FullEnvironmentOptions(gravity_gradient=v["env_gravity_gradient"], drag=v["env_drag"], srp=v["env_srp"],
                                      field=v["env_field"], igrf_degree=v["igrf_degree"])
        field = self._field(v["field_plugin"], v["field_file"])
        dist = []
        for spec in v["disturbance_plugins"]:
            try:
                dist.append(load_plugin(spec)(p))
            except Exception as exc:  # noqa: BLE001 - any failure is a parameter error
                raise ParamError("disturbance_plugins", f"cannot load {spec!r}: {exc}") from None
        self.dyn = make_dynamics(self.environment, p, ts=self.ts, substeps=self.substeps,
                                 residual_dipole=v["residual_dipole"], field=field, disturbances=dist, options=opts)
        self.y = initial_state(p, v["initial_rate_error"], v["initial_quaternion"])
        self.k = 0
        self.t_ns = [self.time_origin_ns + sec_to_ns(k * self.ts) for k in range(self.n + 1)]
        self.m_cmd = np.zeros(3)
        self.m_last = np.zeros(3)  # the dipole applied over the last step: its field at the magnetometer
        self.last_cmd_ns = -1
        self.awaiting = False
        self.progress_every = max(1, self.n // 10)
        self.t_progress = time.perf_counter()
        self.started = False
        self.clock_held = 0   # timer ticks /clock was held at time_origin_ns with the peers listening
        self.finished = False
        self.Y = np.zeros((self.n + 1, 7))
        self.X = np.zeros((self.n + 1, 6))
        self.M = np.zeros((self.n + 1, 3))
        self.B = np.zeros((self.n + 1, 3))
        self.field_name = (v["field_file"] or p.field_model) if self.environment == "paper" else opts.field

    def _field(self, field_plugin: str, field_file: str):
        """b_orb(t) of a field plug-in or a field file; None: the spacecraft's field_model."""
        if field_plugin:
            try:
                return load_plugin(field_plugin)(self.p)
            except Exception as exc:  # noqa: BLE001 - any failure is a parameter error
                raise ParamError("field_plugin", f"cannot load {field_plugin!r}: {exc}") from None
        if field_file:
            try:
                return field_for_spacecraft(field_file, self.p)
            except ConfigError as exc:
                raise ParamError("field_file", str(exc)) from None
        return None

    def make_interfaces(self) -> None:
        """Diagnostics, publishers, the command subscription, preallocated messages and the timer."""
        self.diag = Diagnostics(self, ["steps", "missed_steps", "rejected_commands", "late_commands",
                                         "saturated_commands"])
        self.pub_clock = self.create_publisher(ClockMsg, "/clock", CLOCK_QOS)
        self.pub_truth = self.create_publisher(Odometry, TOPIC_TRUTH, LOCKSTEP_QOS)
        self.pub_rate = self.create_publisher(Vector3Stamped, TOPIC_INERTIAL_RATE, LOCKSTEP_QOS)
        self.pub_field = self.create_publisher(MagneticField, TOPIC_TRUE_FIELD, LOCKSTEP_QOS)
        self.pub_tmag = self.create_publisher(WrenchStamped, TOPIC_MAG_TORQUE, LOCKSTEP_QOS)
        full = self.environment == "full"  # orbit and Sun exist only there (the paper's model has neither)
        self.pub_orbit = self.create_publisher(Odometry, TOPIC_ORBIT, LOCKSTEP_QOS) if full else None
        self.pub_sun = self.create_publisher(Vector3Stamped, TOPIC_TRUE_SUN, LOCKSTEP_QOS) if full else None
        self.pub_tdist = self.create_publisher(WrenchStamped, TOPIC_DIST_TORQUE, LOCKSTEP_QOS)
        self.pub_tqf = (self.create_publisher(MagneticField, TOPIC_TORQUER_FIELD, LOCKSTEP_QOS)
                        if self.torquers.coupled else None)
        self.sub_cmd = self.create_subscription(Vector3Stamped, TOPIC_DIPOLE, self.on_command, LOCKSTEP_QOS)
        self.pub_tf = self.create_publisher(TFMessage, TOPIC_TF, LOCKSTEP_QOS) if self.pub_tf_on else None
        self.pub_markers = (self.create_publisher(MarkerArray, TOPIC_MARKERS, LOCKSTEP_QOS)
                            if self.pub_markers_on else None)
        self.msg_tf = self._make_tf()
        self.msg_markers = self._make_markers()
        # preallocated messages (fields overwritten every step)
        self.msg_clock = ClockMsg()
        self.msg_truth = Odometry()
        self.msg_truth.header.frame_id = FRAME_ORBITAL
        self.msg_truth.child_frame_id = FRAME_BODY
        self.msg_orbit, self.msg_sun = Odometry(), Vector3Stamped()
        self.msg_orbit.header.frame_id = self.msg_orbit.child_frame_id = self.msg_sun.header.frame_id = FRAME_ECI
        self.msg_rate, self.msg_field, self.msg_tqf = Vector3Stamped(), MagneticField(), MagneticField()
        self.msg_tmag, self.msg_tdist = WrenchStamped(), WrenchStamped()
        for msg in (self.msg_rate, self.msg_field, self.msg_tqf, self.msg_tmag, self.msg_tdist):
            msg.header.frame_id = FRAME_BODY
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.wall0 = time.perf_counter()
        self.pace0 = self.wall0  # reference of the real-time-factor pacing (re-anchored after a stall)
        self.t_publish = self.wall0
        self.watchdog = self.create_timer(0.05 if self.lockstep else self.ts / max(self.rtf, 1e-9),
                                          self.on_timer, clock=steady)
        self.get_logger().info(
            f"{self.n} steps of {self.ts} s ({self.n * self.ts / self.p.orbit_period:.3f} orbits), "
            f"lockstep={self.lockstep}, real_time_factor={self.rtf or 'max'}, environment={self.environment}, "
            f"field={self.field_name}, T={self.p.orbit_period:.3f} s")

    # ---------------------------------------------------------------- stepping
    def peers_ready(self) -> bool:
        """True once the lockstep peers are matched (truth, rate and field have subscribers, the command a publisher) or
        ``wait_for_peers`` is off."""
        return (not self.wait_peers) or not self.peers_missing()

    def peers_missing(self) -> list[str]:
        """What the start still waits for, one phrase per topic (the startup error names it)."""
        need = [(self.pub_truth, self.pub_truth.get_subscription_count(), self.min_subs, "subscribers"),
                (self.pub_field, self.pub_field.get_subscription_count(), 1, "subscriber"),
                (self.pub_rate, self.pub_rate.get_subscription_count(), 1, "subscriber"),
                (self.sub_cmd, self.sub_cmd.get_publisher_count(), 1, "publisher (the controller)")]
        return [f"{e.topic_name}: {n} of {want} {what}" for e, n, want, what in need if n < want]

    def on_timer(self):
        """Steady-time timer: starts the run once the peers are ready (exit 3 after startup_timeout); free-running, steps; in lockstep,
        counts a missed step and advances on the held command when the command is late."""
        now = time.perf_counter()
        if self.finished:
            return
        if not self.started:
            if self.time_origin_ns:
                # epoch-stamped run: hold every node's clock at the origin while waiting, so the first
                # samples (stamped 2026-...) are not "in the future" of a clock still at 0
                self.msg_clock.clock = ns_to_stamp(self.t_ns[0])
                self.pub_clock.publish(self.msg_clock)
                # start once the sensors and the controller take /clock and had 0.5 s to follow it
                takers = {i.node_name for i in self.get_subscriptions_info_by_topic(self.pub_clock.topic_name)}
                if {"attitude_sensors", "controller"} <= takers or not self.wait_peers:
                    self.clock_held += 1
                if self.clock_held < 10:
                    return
            if self.peers_ready():
                self.started = True
                self.wall0 = self.t_progress = self.pace0 = time.perf_counter()
                self.publish_state()
            elif now - self.wall0 > self.startup_timeout:
                self.get_logger().error("no subscriber/controller matched within startup_timeout; giving up (waiting for "
                                        + "; ".join(self.peers_missing()) + ")")
                self.finish_run(code=STARTUP_EXIT)
            return
        if not self.lockstep:  # free-running: latest command, after a first answer to step 0
            if self.k == 0:
                if self.last_cmd_ns < 0 and now - self.t_publish < self.startup_timeout:
                    return
                self.wall0 = now
            self.advance()
            return
        limit = self.startup_timeout if self.k == 0 else self.timeout
        if self.awaiting and now - self.t_publish > limit:
            self.diag.count("missed_steps", f"no command for t={self.k * self.ts:.3f} s within {limit} s; "
                                            f"holding {self.m_cmd.tolist()}")
            self.advance()

    def publish_state(self):
        """Publish /clock, truth and true field at t_k, then wait for the command (lockstep)."""
        k, y = self.k, self.y
        if self.kill_t is not None and k * self.ts >= self.kill_t:
            self.get_logger().warning(f"fault sensors_killed at t={k * self.ts:.3f} s: step held 1 s for the runner")
            self.kill_t = None
            time.sleep(1.0)  # the runner polls this log every 0.05 s and kills attitude_sensors meanwhile
        stamp = ns_to_stamp(self.t_ns[k])
        b = self.dyn.body_field(k * self.ts, y[:4])
        self.Y[k], self.B[k] = y, b
        self.X[k] = linear_state(y[:4], y[4:], self.dyn.orbit_rate)
        m = self.msg_truth
        m.header.stamp = stamp
        o = m.pose.pose.orientation
        o.w, o.x, o.y, o.z = float(y[0]), float(y[1]), float(y[2]), float(y[3])
        a = m.twist.twist.angular
        a.x, a.y, a.z = (float(v) for v in self.dyn.relative_rate(k * self.ts, y[:4], y[4:]))
        r = self.msg_rate
        r.header.stamp = stamp
        r.vector.x, r.vector.y, r.vector.z = float(y[4]), float(y[5]), float(y[6])
        f = self.msg_field
        f.header.stamp = stamp
        f.magnetic_field.x, f.magnetic_field.y, f.magnetic_field.z = float(b[0]), float(b[1]), float(b[2])
        self.awaiting = True
        self.t_publish = time.perf_counter()
        self.pub_truth.publish(m)
        self.pub_rate.publish(r)
        self.pub_field.publish(f)
        if self.pub_tqf is not None:
            g = self.msg_tqf
            g.header.stamp = stamp
            g.magnetic_field.x, g.magnetic_field.y, g.magnetic_field.z = (float(x) for x in self.torquers.field(self.m_last))
            self.pub_tqf.publish(g)
        if self.pub_orbit is not None:
            self.publish_orbit(k, stamp)
        # /clock right after the step's data: the nodes' clock callbacks then run off the
        # lockstep critical path (their inputs are accepted up to 2 Ts from their clock)
        self.msg_clock.clock = stamp
        self.pub_clock.publish(self.msg_clock)
        if self.pub_tf is not None:  # for viewers only: after what the chain waits for
            self.publish_tf(k, stamp, o)

    def on_command(self, msg: Vector3Stamped):
        """controller/dipole_command: rejects and counts non-finite, out-of-order, future and (lockstep) late commands; saturates and
        holds it; in lockstep, advances."""
        v = msg.vector
        if not finite(v.x, v.y, v.z):
            self.diag.count("rejected_commands", "non-finite dipole command")
            return
        ns = stamp_to_ns(msg.header.stamp)
        if not self.started or self.finished:
            return
        cur = self.t_ns[self.k]
        if ns < self.last_cmd_ns:
            self.diag.count("rejected_commands", f"command stamp {ns * 1e-9:.3f} s older than the last applied")
            return
        if ns < cur and self.lockstep:
            self.diag.count("late_commands", f"command for t={ns * 1e-9:.3f} s arrived at step t={cur * 1e-9:.3f} s")
            return
        if ns > cur:
            self.diag.count("rejected_commands", f"command stamped in the future ({ns * 1e-9:.3f} s > "
                                                 f"{cur * 1e-9:.3f} s)")
            return
        m = np.array([v.x, v.y, v.z])
        ms = saturate(m, self.m_max)
        if np.any(ms != m):
            self.diag.count("saturated_commands")
        self.m_cmd = ms
        self.last_cmd_ns = ns
        if self.lockstep and self.awaiting:
            self.advance()

    def advance(self):
        """Apply the held command over [t_k, t_k+1] and publish the next state (or finish)."""
        k = self.k
        self.awaiting = False
        m = self.m_cmd
        if self.faults:  # a dead or stuck torquer: the dipole the body gets
            m, self.fault_state = fl.actuate(self.faults, k * self.ts, m, self.fault_state)
            m = saturate(m, self.m_max)
        self.M[k] = m
        self.diag.count("steps")
        if k and k % self.progress_every == 0:
            now = time.perf_counter()
            self.get_logger().info(f"step {k}/{self.n}: {1e3 * (now - self.t_progress) / self.progress_every:.3f} "
                                   "ms/step over the last interval")
            self.t_progress = now
        if k >= self.n:
            if self.pub_torques:
                self.publish_torques(k, m)
            if self.pub_markers is not None:
                self.publish_markers(k, m)
            self.finish_run()
            return
        S = self.rule.at(self.y)
        self.y = self.dyn.step(k * self.ts, self.y, self.ts, m, S, self.weights[S])
        self.m_last = m
        self.k = k + 1
        why = divergence(self.y)
        if why:  # stop at once: stepping a NaN state would "succeed" with garbage
            self.get_logger().error(f"simulation diverged at step {self.k} (t={self.k * self.ts:.3f} s): {why}")
            self.finish_run(DIVERGED_EXIT)
            return
        if self.rtf > 0 and self.lockstep:
            lag = self.pace0 + self.k * self.ts / self.rtf - time.perf_counter()
            if lag > 0:
                time.sleep(lag)
            elif lag < -self.ts / self.rtf:
                # more than a step behind (a slow first command: DDS's reliable retransmission can
                # take seconds): re-anchor the pace instead of bursting steps to catch up, which
                # outran a 1 s recorder flush by 60 steps at rtf 20 (tests/ros/test_faults.py)
                self.pace0 -= lag
        self.publish_state()
        # the torques and markers of the step just applied, off the lockstep critical path (bench/sil_hops.py:
        # a MarkerArray costs 0.16-0.24 ms to publish, more than the three messages the sensors wait for)
        if self.pub_torques:
            self.publish_torques(k, m)
        if self.pub_markers is not None:
            self.publish_markers(k, m)

    # ---------------------------------------------------------------- visualization
    def _make_tf(self) -> TFMessage:
        body = TransformStamped()
        body.header.frame_id, body.child_frame_id = FRAME_ORBITAL, FRAME_BODY
        tfs = [body]
        if self.environment == "full":
            orb = TransformStamped()
            orb.header.frame_id, orb.child_frame_id = FRAME_ECI, FRAME_ORBITAL
            tfs.append(orb)
        return TFMessage(transforms=tfs)

    def publish_orbit(self, k, stamp):
        """sim/orbit (r, v in ECI) and sim/sun (geocentric Sun position, ECI) at t_k: the truth the
        sun sensor and the position fix of attitude_sensors measure."""
        r, v = self.dyn.env.orbit.state(k * self.ts)
        s = self.dyn.env.sun_eci(k * self.ts)
        o, u = self.msg_orbit, self.msg_sun
        o.header.stamp = u.header.stamp = stamp
        p, w = o.pose.pose.position, o.twist.twist.linear
        p.x, p.y, p.z = float(r[0]), float(r[1]), float(r[2])
        w.x, w.y, w.z = float(v[0]), float(v[1]), float(v[2])
        u.vector.x, u.vector.y, u.vector.z = float(s[0]), float(s[1]), float(s[2])
        self.pub_orbit.publish(o)
        self.pub_sun.publish(u)

    def publish_tf(self, k, stamp, o):
        """orbital -> body: the rotation of sim/truth (a body vector's orbital coordinates,
        v_orb = R(q) v_body, as tf's parent <- child convention); eci -> orbital: the orbit's
        position r [m] and R_eci_to_orbital^T (orbital axes expressed in ECI)."""
        tfs = self.msg_tf.transforms
        body = tfs[0]
        body.header.stamp = stamp
        body.transform.rotation = o
        if len(tfs) > 1:
            from magtune_core.env.orbit import eci_to_orbital
            r, v = self.dyn.env.orbit.state(k * self.ts)
            qo = matrix_to_quat(eci_to_orbital(r, v).T)
            orb = tfs[1]
            orb.header.stamp = stamp
            tr, rot = orb.transform.translation, orb.transform.rotation
            tr.x, tr.y, tr.z = float(r[0]), float(r[1]), float(r[2])
            rot.w, rot.x, rot.y, rot.z = float(qo[0]), float(qo[1]), float(qo[2]), float(qo[3])
        self.pub_tf.publish(self.msg_tf)

    def _make_markers(self) -> MarkerArray:
        def marker(mid, mtype, rgba, ns):
            mk = Marker()
            mk.header.frame_id = FRAME_BODY
            mk.ns, mk.id, mk.type, mk.action = ns, mid, mtype, Marker.ADD
            mk.pose.orientation.w = 1.0
            mk.color.r, mk.color.g, mk.color.b, mk.color.a = rgba
            mk.frame_locked = True
            return mk
        box = marker(0, Marker.CUBE, (0.7, 0.7, 0.7, 0.6), "body")
        box.scale.x, box.scale.y, box.scale.z = BOX_DIMS
        arrows = []
        for mid, rgba, ns in ((1, (0.2, 0.4, 1.0, 1.0), "magnetic_field"), (2, (1.0, 0.3, 0.1, 1.0), "dipole")):
            a = marker(mid, Marker.ARROW, rgba, ns)
            a.scale.x, a.scale.y, a.scale.z = 0.04, 0.08, 0.12  # shaft, head diameter, head length [m]
            a.points = [Point(), Point()]
            arrows.append(a)
        return MarkerArray(markers=[box, *arrows])

    def publish_markers(self, k, m):
        """Body box, true field b(t_k) and the dipole applied over [t_k, t_k+1], in body axes."""
        stamp = ns_to_stamp(self.t_ns[k])
        b = self.B[k]
        mk = self.msg_markers.markers
        for mark, vec, scale in ((mk[1], b, MARKER_FIELD_SCALE), (mk[2], m, MARKER_DIPOLE_SCALE)):
            tip = mark.points[1]
            tip.x, tip.y, tip.z = float(vec[0] * scale), float(vec[1] * scale), float(vec[2] * scale)
        for mark in mk:
            mark.header.stamp = stamp
        self.pub_markers.publish(self.msg_markers)

    def publish_torques(self, k, m):
        """Publish sim/magnetic_torque (m x b) and sim/disturbance_torque of step k, body axes (``publish_torques``)."""
        y, b = self.Y[k], self.B[k]
        stamp = ns_to_stamp(self.t_ns[k])
        tm = cross(m, b)
        td = self.dyn.disturbance_torque(k * self.ts, y[:4], y[4:], b)
        for msg, T, pub in ((self.msg_tmag, tm, self.pub_tmag), (self.msg_tdist, td, self.pub_tdist)):
            msg.header.stamp = stamp
            msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = float(T[0]), float(T[1]), float(T[2])
            pub.publish(msg)

    # ---------------------------------------------------------------- end of run
    def finish_run(self, code: int = 0):
        """End the run (once): last diagnostics, wait for a recorder's acks, write ``results_path`` (status 0 only), log the summary and
        complete ``done`` with ``code``."""
        if self.finished:
            return
        self.finished = True
        wall = time.perf_counter() - self.wall0
        steps = self.k + 1 if code == 0 else self.k
        sim_t = self.k * self.ts
        self.diag.extra.update(wall_time=f"{wall:.3f}", real_time_factor=f"{sim_t / max(wall, 1e-9):.1f}")
        self.diag.publish()
        if self.min_subs >= 2:  # a recorder listens: let it acknowledge the last samples first
            from rclpy.duration import Duration
            deadline = time.monotonic() + 5.0
            for pub in (self.pub_truth, self.pub_rate, self.pub_field, self.pub_tmag, self.pub_tdist, self.pub_clock):
                left = deadline - time.monotonic()
                if left <= 0 or not pub.wait_for_all_acked(Duration(seconds=left)):
                    self.get_logger().warning(f"{pub.topic_name}: not every sample acknowledged before exit")
                    break
        if self.results_path and code == 0:
            res = SimResult(np.array(self.t_ns[:steps]) * 1e-9, self.Y[:steps, :4], self.Y[:steps, 4:],
                            self.X[:steps], self.M[:steps], self.B[:steps], self.p.orbit_period)
            res.t = np.arange(steps) * self.ts  # exactly the offline grid
            res.to_npz(self.results_path, wall_time=wall, counters=json.dumps(self.diag.counts),
                       ts=self.ts, substeps=self.substeps)
        self.get_logger().info(f"done: {self.k} steps, sim {sim_t:.0f} s in {wall:.2f} s wall "
                               f"(RTF {sim_t / max(wall, 1e-9):.0f}), counters {self.diag.counts}")
        self.done.set_result(code)

    def finish(self):
        """Called by main.run at shutdown (e.g. Ctrl-C): nothing to flush unless finished."""


def main(args=None):
    """Entry point of the simulator node (console script): run(Simulator)'s exit status."""
    return run(Simulator, args)


if __name__ == "__main__":
    raise SystemExit(main())
