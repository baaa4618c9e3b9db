"""Magnetorquer controller node, managed (lifecycle), digital sample-and-hold; law by flight mode.

    POINTING, ACQUISITION: m = sat( S(b)^T K x / |b|^2 ), x = [dq; dw]  (paper eq. 17,
                           magtune_core.onboard.law.ProjectionController)
    DETUMBLE:              saturated B-dot (magtune_core.onboard.bdot.BdotController, gain rule of
                           Avanzini & Giulietti 2012 unless bdot_gain is set)
    SAFE:                  m = 0
With a duty cycle (``torquer_off_time``, TORQUER_FIELDS) the torquers drive the law's dipole / f,
f the on fraction, saturated per axis (``duty_compensation``; onboard.torquers.Torquers.drive).
The mode is parameter ``initial_mode`` (default POINTING: the paper's run) until the mode
manager publishes one on ``mode`` (magtune_interfaces/Mode); a change applies from the next
sample. Lifecycle (magtune_ros.lifecycle.ManagedNode): configure loads and validates every
parameter, activate creates the subscriptions and the command publisher.

Parameters: the gains file ``config/gains/sigma_*.yaml`` (``gain``: 18 doubles, row-major 3x6 K;
``sigma``; ``ts``; provenance entries are declared read-only) and ``config/spacecraft.yaml``
(orbit period -> nominal rate). Pass them with ``--ros-args --params-file FILE``.

Subscribes (LOCKSTEP_QOS):
  sensors/magnetic_field   sensor_msgs/MagneticField  [T], body axes
  sensors/attitude         sensor_msgs/Imu            orientation (body w.r.t. orbital), rate [rad/s];
                                                      orientation_covariance[0] = -1: no attitude yet
                                                      (zero dipole, counted no_attitude); ``magtune sil
                                                      --attitude estimator`` remaps it to estimate/attitude
  mode                     magtune_interfaces/Mode    flight mode (MODE_QOS: reliable, transient-local)
  /clock                   rosgraph_msgs/Clock        (use_sim_time; stamps are checked against it)
Publishes:
  controller/dipole_command  geometry_msgs/Vector3Stamped [A m^2], stamped with the input stamp;
                             one per input pair; recomputed every ``ts`` of sim time, held between.
  /diagnostics  counters: samples, commands, weak_field, saturated, rejected_nonfinite, rejected_implausible,
                rejected_quaternion, rejected_malformed, rejected_stamp, stale_inputs, stale_data, mode_changes, rejected_mode,
                no_attitude, no_field, late_field;
                state (lifecycle), mode
The two sensor inputs are taken serialized and only the fields used are read (magtune_ros.raw: building the
messages cost more than the law). Inputs are paired by identical stamps. Bad inputs are rejected with a logged reason and
counted; |b| < min_field gives a zero dipole (counted as weak_field); if no valid input for
more than 2 ts of sim time, the held dipole is zeroed (stale_data).

A sample without its magnetometer message (a dropout: the attitude of t_k came, no field of t_k)
is answered at once with the dipole the offline mode loop models (sim/modes_loop.py): the held
one until 2 ts after the last field, then zero (counted no_field), so the lockstep goes on and the
simulator counts no missed step. How the node knows at once that the field of t_k is missing:
attitude_sensors publishes a step's magnetometer sample before its attitude, from one DDS participant
to this one, and in the lockstep only the current step's few messages are in flight, so none is lost
and resent out of order: the field of t_k, when there is one, arrives and is taken (the executor
takes messages in arrival order, the field's subscription first) before the attitude of t_k. The
rule applies once a first pair came after activation (at start-up the two readers match the sensors
one by one, and transient-local history may bring the field after the attitude). A field message of
t_k that came but was rejected (non-finite, implausible, stale) leaves the sample unanswered, as
before: the simulator holds and counts the step. A field of t_k that arrives after its sample was
answered is dropped and counted (late_field): the order above did not hold.
"""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from magtune_interfaces.msg import Mode
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.base.errors import ConfigError
from magtune_core.base.text import printable
from magtune_core.base.topics import FRAME_BODY, TOPIC_ATTITUDE, TOPIC_DIPOLE, TOPIC_MAG, TOPIC_MODE
from magtune_core.design.gains import Gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.bdot import BdotController, FieldDerivativeFilter, FilterState, bdot_gain, geomagnetic_inclination
from magtune_core.onboard.law import ProjectionController, linear_state
from magtune_core.onboard.modes import ACQUISITION, DETUMBLE, MODES, POINTING
from magtune_core.onboard.params import BDOT_FIELDS, CONTROLLER_FIELDS, TORQUER_FIELDS
from magtune_core.onboard.torquers import Torquers

from .inputs import PairSync, StampGate, finite, ns_to_stamp, sec_to_ns, stamp_to_ns
from .lifecycle import ManagedNode
from .main import run
from .params import check_ts, declare_overrides, from_schema, param_error, parse_fields
from .qos import LOCKSTEP_QOS, MODE_QOS
from .raw import raw_imu, raw_magnetic_field

#: Largest plausible magnetometer reading per axis [T]: the geomagnetic field is below 7e-5 T,
#: the spacecraft schema bounds constant_field the same way; a larger (finite) value is rejected
#: and counted (rejected_implausible), never fed to the projection.
MAX_FIELD = 1e-3


class Controller(ManagedNode):
    """The controller node, managed (lifecycle): sensors/magnetic_field + sensors/attitude (paired by stamp) and mode in,
    controller/dipole_command out; configure loads the gains and builds the laws, activate creates the topics."""
    NODE_NAME = "controller"

    def __init__(self):
        super().__init__(self.NODE_NAME, ["samples", "commands", "weak_field", "saturated", "rejected_nonfinite",
                                          "rejected_implausible", "rejected_quaternion", "rejected_malformed",
                                          "rejected_stamp", "stale_inputs", "stale_data", "mode_changes", "rejected_mode", "no_attitude",
                                          "no_field", "late_field"])
        self.m = np.zeros(3)
        self.last_input_ns = None
        self.answered_ns = None  # stamp of the last sample answered with a command (a pair or no_field)
        self.create_timer(0.1, self.check_stale, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ---------------------------------------------------------------- lifecycle
    def configure(self):
        """Load and validate the gains, the node's options and the spacecraft file; build both laws."""
        # the gains-file schema (as `magtune analyze`), the node's options and the spacecraft file's:
        # each parameter declared from its schema and validated once
        gains = from_schema(self, Gains)
        K, self.sigma, self.ts = gains.K, gains.sigma, gains.ts
        v = parse_fields(self, CONTROLLER_FIELDS)
        b = parse_fields(self, BDOT_FIELDS)
        tq = Torquers.from_values(parse_fields(self, TORQUER_FIELDS))
        p = from_schema(self, SpacecraftParams)
        check_ts(self.ts, p)  # Nyquist of the nutation, also for a controller started alone
        declare_overrides(self)
        try:
            tq.check(self.ts, "parameters")
        except ConfigError as exc:
            raise param_error(exc) from None
        self.torquers, self.w0 = tq, p.orbit_rate
        lim = tq.law_limit(v["dipole_limit"], self.ts)  # the duty cycle's compensation (onboard.torquers)
        self.law = ProjectionController(K, lim, v["min_field"])
        k = b["bdot_gain"] or bdot_gain(p.orbit_rate, geomagnetic_inclination(math.radians(p.inclination_deg)),
                                        p.inertia)
        self.bdot_law = BdotController(k, lim, min_field=v["min_field"])
        self.filter = FieldDerivativeFilter(self.ts, b["bdot_cutoff"])
        self.mode = v["initial_mode"]
        self.ts_ns = sec_to_ns(self.ts)
        self.msg = Vector3Stamped()
        self.msg.header.frame_id = FRAME_BODY
        self.get_logger().info(f"K loaded (sigma={self.sigma:g}, ts={self.ts:g} s, |K|={np.linalg.norm(K):.4g}); "
                               f"B-dot k={k:.4g} N m s; mode {self.mode}")

    def activate(self):
        """Fresh input state, then the command publisher and the subscriptions (sensors, mode)."""
        self.gate = StampGate(self, 2 * self.ts_ns)
        self.sync = PairSync()
        self.fstate = FilterState()
        self.next_sample_ns = None
        self.last_input_ns = None
        self.answered_ns = None  # no_field answers only after a first pair (the module docstring)
        self.field_seen_ns = -1  # newest stamp of any magnetometer message taken, valid or not
        self.m = np.zeros(3)
        self.pub = self.data_publisher(Vector3Stamped, TOPIC_DIPOLE, LOCKSTEP_QOS)
        self.data_subscription(Mode, TOPIC_MODE, self.on_mode, MODE_QOS)
        self.data_subscription(MagneticField, TOPIC_MAG, self.on_mag, LOCKSTEP_QOS, raw=True)
        self.data_subscription(Imu, TOPIC_ATTITUDE, self.on_attitude, LOCKSTEP_QOS, raw=True)

    # ---------------------------------------------------------------- inputs
    def on_mode(self, msg: Mode):
        """The mode manager's mode: the law of the next sample (unknown ids rejected and counted)."""
        if msg.mode >= len(MODES):
            return self.diag.count("rejected_mode", f"unknown mode id {msg.mode}")
        mode = MODES[msg.mode]
        if mode != self.mode:
            self.diag.count("mode_changes")
            self.get_logger().info(f"mode {self.mode} -> {mode} (decided at t={stamp_to_ns(msg.header.stamp) * 1e-9:.1f}"
                                   f" s: {printable(msg.reason)})")  # a peer's string: one bounded line
            self.mode = mode
        self.diag.extra["mode"] = mode

    def on_mag(self, data: bytes):
        """sensors/magnetic_field (raw): rejects and counts a malformed message or a non-finite or implausible (> MAX_FIELD) field;
        else stamp-gated and paired."""
        f = raw_magnetic_field(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/magnetic_field message")
        ns, b = f
        self.field_seen_ns = max(self.field_seen_ns, ns)
        if not finite(*b):
            return self.diag.count("rejected_nonfinite", "non-finite magnetic field")
        if max(abs(b[0]), abs(b[1]), abs(b[2])) > MAX_FIELD:  # e.g. 1e308 T: finite, not physical
            return self.diag.count("rejected_implausible", f"|b| component above {MAX_FIELD:g} T")
        self._input(0, ns, b)

    def on_attitude(self, data: bytes):
        """sensors/attitude (raw): rejects and counts a malformed message, a non-finite attitude/rate or a quaternion norm off 1 by
        > 1e-3; else stamp-gated and paired (orientation_covariance[0] = -1: no attitude yet, REP-145)."""
        f = raw_imu(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/attitude message")
        ns, q, w, known = f
        if not finite(*q, *w):
            return self.diag.count("rejected_nonfinite", "non-finite attitude/rate")
        if abs(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) - 1.0) > 1e-3:
            return self.diag.count("rejected_quaternion", "attitude quaternion norm differs from 1 by > 1e-3")
        self._input(1, ns, (q, w, known))

    def _input(self, slot, ns, value):
        if self.diag.extra.get("state") != "active":
            # a message the executor hands over after a peer's deactivate destroyed the topics: dropped (its command
            # would go to the destroyed publisher, which raises and ended the node)
            return
        bad = self.gate.check(slot, ns)
        if bad:
            return self.diag.count(*bad)
        if slot == 0 and self.answered_ns is not None and ns <= self.answered_ns:
            return self.diag.count("late_field", f"field of t={ns * 1e-9:.3f} s came after its sample was answered "
                                                 "without it: dropped")
        pair = self.sync.add(slot, ns, value)
        if pair:
            self.command(ns, *pair)
        elif slot == 1 and self.answered_ns is not None and self.field_seen_ns < ns:
            self.no_field(ns)

    def no_field(self, ns):
        """The attitude of t = ``ns`` came without its magnetometer sample (module docstring): hold the dipole until
        2 ts after the last field, then zero it, as the offline loop (``modes_loop._Stack.step``); publish it stamped ``ns``."""
        self.diag.count("no_field", f"no magnetometer sample of t={ns * 1e-9:.3f} s: dipole held 2 ts, then zero")
        if self.last_input_ns is None or ns - self.last_input_ns > 2 * self.ts_ns:
            self.m = np.zeros(3)
        self.answered_ns = ns
        self.publish(ns)

    def command(self, ns, b, att):
        """A stamp-paired sample (the field ``b`` and ``att`` = (q, rate, attitude known)): recompute the dipole with the mode's
        law when a sample period ``ts`` is due (else hold it), then publish it stamped ``ns``."""
        self.last_input_ns = self.answered_ns = ns
        if self.next_sample_ns is None or ns >= self.next_sample_ns:
            q, w, known = att
            bv = np.array(b)
            self.fstate, bdot = self.filter.step(self.fstate, bv)  # every sample: warm when DETUMBLE starts
            if self.mode in (ACQUISITION, POINTING) and not known:
                self.m = np.zeros(3)  # no attitude yet (the estimator before its coarse fix): torquers off
                self.diag.count("no_attitude")
            elif self.mode in (ACQUISITION, POINTING):
                x = linear_state(q, w, self.w0)
                out = self.law(x, bv)
                self.m = self.torquers.drive(out.m, self.ts)
                if out.weak_field:
                    self.diag.count("weak_field", f"|b| below min_field at t={ns * 1e-9:.3f} s: zero dipole")
                if out.saturated:
                    self.diag.count("saturated")
            elif self.mode == DETUMBLE:
                self.m = self.torquers.drive(self.bdot_law.dipole(bv, bdot), self.ts)
            else:  # SAFE: torquers off
                self.m = np.zeros(3)
            self.diag.count("samples")
            # next sample one period later on the grid of the first sample (ZOH at Ts)
            self.next_sample_ns = ns + self.ts_ns if self.next_sample_ns is None else \
                self.next_sample_ns + self.ts_ns * max(1, (ns - self.next_sample_ns) // self.ts_ns + 1)
        self.publish(ns)

    def publish(self, ns):
        """Publish the held dipole on controller/dipole_command stamped ``ns`` (counted: commands)."""
        msg = self.msg
        msg.header.stamp = ns_to_stamp(ns)
        msg.vector.x, msg.vector.y, msg.vector.z = float(self.m[0]), float(self.m[1]), float(self.m[2])
        self.diag.count("commands")
        self.pub.publish(msg)

    def check_stale(self):
        """Steady-time timer (10 Hz): while active, zero a nonzero held dipole and publish it when no valid input came for 2 ts of
        sim time (stale_data); not while the attitude still comes (no_field answers each sample at its own stamp)."""
        if self.last_input_ns is None or not np.any(self.m) or self.diag.extra.get("state") != "active":
            return
        now = self.get_clock().now().nanoseconds
        if self.answered_ns is not None and now - self.answered_ns <= self.ts_ns:
            return
        if now - self.last_input_ns > 2 * self.ts_ns:
            self.m = np.zeros(3)
            self.diag.count("stale_data", f"no valid input since t={self.last_input_ns * 1e-9:.3f} s "
                                          f"(now {now * 1e-9:.3f} s): dipole zeroed")
            self.publish(now)


def main(args=None):
    """Entry point of the controller node (console script): run(Controller)'s exit status."""
    return run(Controller, args)


if __name__ == "__main__":
    raise SystemExit(main())
