"""mode_manager node: lifecycle bring-up of the flight nodes, the mode logic, health monitoring.

Bring-up (lifecycle_msgs services ``<node>/change_state``, in ``managed_nodes`` order, default
attitude_sensors then controller): configure every node, then activate them in order, each transition
waited for on the node's progress, not a fixed wall time (magtune_core.onboard.bringup: a lost or late
reply is found by ``get_state``; a node that answers is waited for up to ``bringup_limit``, one that gives
no sign of life for ``transition_timeout`` is named as not answering). A failed configure leaves that node
*unconfigured*: the manager prints ``mode_manager: <node>: <reason>`` (the node's one line, read from its
ERROR status on /diagnostics) and exits 2; a silent or too slow node gets its own line, and exit 2. On shutdown
(SIGINT/SIGTERM) it deactivates them in reverse order, then shuts them down (their processes end).
The manager itself is a plain node: it manages, as Nav2's lifecycle_manager does.

Mode logic (magtune_core.onboard.modes.ModeLogic, parameters MODE_FIELDS): stepped at each sensor
sample t_k (sensors/magnetic_field and sensors/attitude paired by stamp) with the measured
quantities only: |w_gyro| (the gyro sample, which sensors/attitude carries as sensors/imu does),
the filtered |db/dt| of sensors/magnetic_field (onboard.bdot.FieldDerivativeFilter, bdot_cutoff),
|b_k - b_(k-1)| of sensors/magnetic_field (a sample repeated for frozen_time: a frozen magnetometer
-> SAFE) and the pointing error of the attitude estimate. With the estimator (``magtune sil --modes
--attitude estimator``) sensors/attitude is remapped to estimate/attitude and the estimator is a managed
node; an estimate with orientation_covariance[0] = -1 (REP-145: not known, i.e. not valid) has no
pointing error and sets the logic's ``attitude_known`` false. The manager is outside the lockstep and
shares the cores with it, so it takes the two streams serialized (raw) and reads the few fields it
needs (raw.raw_imu, raw.raw_magnetic_field) instead of building the messages.

Time: the manager's sim time is the newest stamp of its samples (it keeps no /clock: use_sim_time
is forced false); transitions, commanded modes and /diagnostics are stamped with it.

Health, two clocks:
  liveness   steady wall-clock time: every managed node publishes its /diagnostics status (its
             heartbeat) at 1 Hz of steady time; none for ``heartbeat_timeout`` s -> SAFE, the
             node named in the reason and on /diagnostics (ERROR). Wall time, because in lockstep
             a dead node stalls the simulator and so /clock: a sim-time timeout would never expire.
             The ages count what the manager watched: after a gap between two checks above
             SELF_STALL (the manager itself stopped or starved; counter self_stalls) it first listens
             for heartbeat_timeout, taking in what the stall held back (a reliable stream's gap is
             repaired within a DDS writer's heartbeat period, seconds), and every age counts from the
             end of that: a manager that did not run never blames a node for the silence it could
             not watch.
  lifecycle  each managed node's ``<node>/transition_event`` (lifecycle_msgs/TransitionEvent): while
             monitoring, a node that leaves *active* (a peer's deactivate or shutdown; the manager
             changes states only at bring-up and bring-down) is lost as a silent one is: SAFE, the
             reason ``controller left active (deactivated by a peer)`` on mode and /diagnostics
             (ERROR, counter left_active); its heartbeat goes on in every state, so only the event
             tells. Active again: back, as a heartbeat that comes back.
  faults     each managed node's unit fault statuses (``magtune/<node>/fdir`` on /diagnostics, the unit in
             hardware_id: the estimator's sun sensor watch, ...): a new WARN/ERROR, or the unit's OK after one,
             republishes the mode unchanged with the status' message (which names the unit) as its reason,
             stamped at the detection: the mode topic names the unit (a notice, not a transition).
  staleness  sim time, from the stamps only: at every sensor message, a stream whose last stamp
             lags the newest of the other by more than ``stale_timeout`` -> the logic steps with
             ``stale`` at the newest stamp -> SAFE, once the lagging stream stayed silent for
             STALE_CONFIRM steady seconds (stamps, not a clock: the manager is outside the
             lockstep and may process samples well after /clock moved on, so "now minus last
             sample" fired spuriously at full speed; a stop of every stream is the liveness
             check's, or the simulator's missed steps'); it recovers by itself after
             ``safe_recovery_time`` of fresh data (while a heartbeat is missing, SAFE holds).
             Sim time, because "data older than 3 s" is a statement about the simulated world.

Publishes:
  mode           magtune_interfaces/Mode (MODE_QOS: reliable, transient-local): the mode, the
                 previous one and the reason of the last transition, stamped with its sim time
  /diagnostics   counters: samples, transitions, requests, rejected_nonfinite, rejected_malformed,
                 rejected_stamp, stale, heartbeat_lost, left_active, self_stalls; mode; lost (the nodes lost);
                 ERROR naming each node whose heartbeat is missing or which left active, and why
Service:
  set_mode       magtune_interfaces/SetMode: a commanded mode (reason recorded); a commanded SAFE
                 is sticky: it holds until another mode is commanded (docs/decisions.md)
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from functools import partial

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import State, Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from magtune_interfaces.msg import Mode
from magtune_interfaces.srv import SetMode
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import Imu, MagneticField

from magtune_core.base.errors import ConfigError
from magtune_core.base.text import printable
from magtune_core.base.topics import SERVICE_SET_MODE, TOPIC_ATTITUDE, TOPIC_DIAGNOSTICS, TOPIC_MAG, TOPIC_MODE
from magtune_core.onboard.bdot import FieldDerivativeFilter, FilterState
from magtune_core.onboard.bringup import ASK, DONE, FAILED, SEND, SILENT, SLOW, TransitionWait
from magtune_core.onboard.modes import MODES, SAFE, Measurements, ModeLogic, ModeParams, ModeState
from magtune_core.onboard.params import BDOT_FIELDS, MANAGER_FIELDS, MODE_FIELDS

from .diagnostics import Diagnostics
from .inputs import PairSync, StampGate, finite, ns_to_stamp, sec_to_ns, stamp_to_ns
from .main import run
from .params import declare_fields, declare_overrides, param_error, parse_fields
from .qos import DIAG_QOS, LOCKSTEP_QOS, MODE_QOS
from .raw import raw_imu, raw_magnetic_field

#: The sensor streams of the mode logic, by slot.
STREAMS = ("sensors/magnetic_field", "sensors/attitude")
#: Steady seconds a lagging stream must stay silent before the lag counts as stale: a manager behind the
#: world may drain one subscription in a burst before the other (a one-off SAFE in CI at 3 s of lag), while
#: a dropped stream stays silent; the stale step keeps the stamp where the lag was seen.
STALE_CONFIRM = 0.5
#: Name suffix of a managed node's fault statuses (diagnostics.Diagnostics.unit_fault: ``magtune/<node>/fdir``).
FDIR_SUFFIX = "/fdir"
#: A transition not done after this long [steady s] is logged once as slow (the bring-up goes on waiting while the
#: node answers, up to bringup_limit).
SLOW_NOTICE = 10.0
#: Period of the liveness check [steady s].
CHECK_PERIOD = 0.25
#: A gap between two liveness checks above this [steady s] (4 periods) means the manager itself did not run
#: (stopped, starved of CPU): it listens for heartbeat_timeout before any heartbeat age counts again (stalled;
#: docs/modes.md, "The node side"). A shorter one adds at most 1 s to an age, within heartbeat_timeout (3 s)
#: less the 1-s heartbeat period.
SELF_STALL = 1.0
#: Why a managed node left active, by the state its event goes to from active (rcl_lifecycle's events carry
#: no transition id or label). The manager changes states only outside monitoring, so while it monitors
#: these came from elsewhere.
LEFT_ACTIVE = {State.TRANSITION_STATE_DEACTIVATING: "deactivated by a peer",
               State.TRANSITION_STATE_SHUTTINGDOWN: "shut down by a peer",
               State.TRANSITION_STATE_ERRORPROCESSING: "an error in the node"}
#: ``<node>/transition_event``: rcl_lifecycle publishes with rcl's default profile (reliable, volatile).
EVENT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class BringUpError(RuntimeError):
    """A managed node could not be brought up: one line naming it (exit status 2)."""


class ModeManager(Node):
    """The mode_manager node (plain, it manages): brings the flight nodes up via their lifecycle services, steps the mode logic on
    sensors/magnetic_field + sensors/attitude, publishes mode, serves set_mode, watches the /diagnostics heartbeats."""
    NODE_NAME = "mode_manager"
    START_ERRORS = (BringUpError,)

    def __init__(self):
        # no /clock: the manager's sim time is its samples' stamps (one message and one timer less per step)
        super().__init__(self.NODE_NAME, parameter_overrides=[Parameter("use_sim_time", value=False)])
        self.done = Future()
        v = parse_fields(self, MANAGER_FIELDS)
        bd = parse_fields(self, BDOT_FIELDS)
        try:
            self.logic = ModeLogic(ModeParams.from_mapping(declare_fields(self, MODE_FIELDS),
                                                           f"node '{self.get_name()}'"))
        except ConfigError as exc:
            raise param_error(exc) from None
        declare_overrides(self)
        self.ts_ns = sec_to_ns(v["ts"])
        self.nodes = list(v["managed_nodes"])
        self.heartbeat_timeout, self.transition_timeout = v["heartbeat_timeout"], v["transition_timeout"]
        self.bringup_limit = v["bringup_limit"]
        self.stale_ns = sec_to_ns(v["stale_timeout"])
        self.filter, self.fstate = FieldDerivativeFilter(v["ts"], bd["bdot_cutoff"]), FilterState()
        self.state = ModeState(v["initial_mode"], 0.0, "start")
        self.previous = self.state.mode
        self.last = None            # last Measurements
        self.b_prev = None          # last magnetometer sample (the frozen-sensor guard's |b_k - b_(k-1)|)
        self.beats: dict[str, float] = {}      # node -> steady time [s] its silence counts from (stalled)
        self.errors: dict[str, str] = {}       # node -> its ERROR status message (failed configure)
        self.heard: dict[str, float] = {}      # node -> steady time of its last heartbeat (bring-up's sign of life)
        self.events_at: dict[str, float] = {}  # node -> steady time of its last transition event
        self.silent: set[str] = set()          # nodes whose heartbeat is missing
        self.left: dict[str, str] = {}         # node -> why it left active (its transition event)
        self.why: dict[str, str] = {}          # node -> why it is lost (the ERROR status)
        self.lost: set[str] = set()            # silent or left: SAFE holds while not empty (step)
        self.unit_faults: dict[str, str] = {}  # unit -> the message of its active fault status (fault_notice)
        self.monitoring = False
        self.checked = time.monotonic()        # steady time of the last liveness check
        # stamps must increase; no age limit: a manager behind the world (it is outside the lockstep)
        # still steps the logic on every sample, in stamp order, so its decisions do not depend on its lag
        self.gate = StampGate(self, None, n=2)
        self.diag = Diagnostics(self, ["samples", "transitions", "requests", "rejected_nonfinite",
                                         "rejected_malformed", "rejected_stamp", "stale", "heartbeat_lost",
                                         "left_active", "self_stalls"],
                                  now_ns=lambda: max(0, *self.gate.last_ns))
        self.sync = PairSync(2)  # magnetometer, attitude (with the gyro) of t_k
        self.lagging = None  # (slot, its last stamp, newest stamp, steady time) of a lag not yet confirmed
        self.pub_mode = self.create_publisher(Mode, TOPIC_MODE, MODE_QOS)
        self.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self.on_diagnostics, DIAG_QOS)
        self.create_subscription(MagneticField, TOPIC_MAG, self.on_mag, LOCKSTEP_QOS, raw=True)
        self.create_subscription(Imu, TOPIC_ATTITUDE, self.on_attitude, LOCKSTEP_QOS, raw=True)
        self.create_service(SetMode, SERVICE_SET_MODE, self.on_set_mode)
        self.change = {n: self.create_client(ChangeState, f"{n}/change_state") for n in self.nodes}
        self.get_state = {n: self.create_client(GetState, f"{n}/get_state") for n in self.nodes}
        for n in self.nodes:  # matched long before bring-up ends; events count only while monitoring
            self.create_subscription(TransitionEvent, f"{n}/transition_event", partial(self.on_transition, n), EVENT_QOS)
        self.create_timer(CHECK_PERIOD, self.check_heartbeats, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.publish_mode()

    # ---------------------------------------------------------------- lifecycle of the managed nodes
    def spin(self, executor, stop) -> int:
        """Bring the nodes up, run until stopped, bring them down in reverse (run calls this)."""
        self.bring_up(executor, stop)
        while rclpy.ok() and not stop.is_set() and not self.done.done():
            executor.spin_until_future_complete(self.done, timeout_sec=0.1)
        self.bring_down(executor)
        return 0

    def _call(self, executor, client, request, timeout: float):
        """The response of one service call, or None (no service or no answer within ``timeout`` wall s)."""
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        fut = client.call_async(request)
        executor.spin_until_future_complete(fut, timeout_sec=timeout)
        return fut.result() if fut.done() else None

    def _transition(self, executor, node: str, tid: int, timeout: float) -> bool:
        r = self._call(executor, self.change[node], ChangeState.Request(transition=Transition(id=tid)), timeout)
        return bool(r and r.success)

    def bring_up(self, executor, stop) -> None:
        """Configure every node (in order), then activate each (in order), each waited for on its progress
        (:meth:`wait_transition`); BringUpError naming a node that failed, is silent or too slow."""
        end = time.monotonic() + self.bringup_limit  # the whole bring-up's limit
        for name, tid in (("configure", Transition.TRANSITION_CONFIGURE), ("activate", Transition.TRANSITION_ACTIVATE)):
            for n in self.nodes:
                self.wait_transition(executor, stop, n, name, tid, end)
        now = time.monotonic()
        self.beats = {n: max(self.beats.get(n, now), now) for n in self.nodes}
        self.monitoring = True

    def wait_transition(self, executor, stop, node: str, name: str, tid: int, end: float) -> None:
        """Ask ``node`` for one transition and wait on its progress (magtune_core.onboard.bringup: its replies,
        its state, its heartbeats and transition events) until the bring-up's steady deadline ``end``, not on a
        fixed wall time; BringUpError with one line."""
        t0 = time.monotonic()
        wait = TransitionWait(node, name, t0, self.transition_timeout, max(end - t0, 0.0))
        change, ask = self.change[node], self.get_state[node]
        pending = {}  # "change" / "state" -> future
        slow_logged = False
        while rclpy.ok() and not stop.is_set():
            now = time.monotonic()
            wait.alive(self.heard.get(node, wait.t0))
            if self.events_at.get(node, -1.0) > wait.started:
                wait.event(self.events_at[node])
            verdict, line = wait.verdict(now, self.errors.get(node))
            if verdict == DONE:
                self.get_logger().info(f"{node}: {wait.goal} after {now - wait.t0:.1f} s")
                return
            if verdict in (FAILED, SILENT, SLOW):
                raise BringUpError(f"{node}: {line}")
            # a new request or question replaces the one before: its reply may have been dropped (a service's
            # reply writer not yet matched: the first get_state of a clean-clone CI run never came back, and a
            # manager that waited for it asked nothing more for 300 s)
            if verdict == SEND and change.service_is_ready():
                self._replace(pending, "change", change, change.call_async(
                    ChangeState.Request(transition=Transition(id=tid))))
                wait.sending(now)
            elif verdict == ASK and ask.service_is_ready():
                self._replace(pending, "state", ask, ask.call_async(GetState.Request()))
                wait.asking(now)
            if not slow_logged and now - wait.t0 > SLOW_NOTICE:
                slow_logged = True
                self.get_logger().warning(f"{node}: {name} not done after {SLOW_NOTICE:g} s; waiting while it answers "
                                          f"(bringup_limit {self.bringup_limit:g} s)")
            executor.spin_once(timeout_sec=0.1)
            for key, fut in list(pending.items()):
                if fut.done():
                    del pending[key]
                    r = fut.result()
                    if r is not None and key == "change":
                        wait.reply(time.monotonic(), bool(r.success))
                    elif r is not None:
                        wait.answer(time.monotonic(), r.current_state.label)
        raise BringUpError(f"{node}: bring-up stopped before {name} was done")

    @staticmethod
    def _replace(pending: dict, key: str, client, fut) -> None:
        """``pending[key] = fut``, the client forgetting the request it replaces (no reply will be waited for)."""
        old = pending.get(key)
        if old is not None and not old.done():
            client.remove_pending_request(old)
        pending[key] = fut

    def bring_down(self, executor) -> None:
        """Deactivate the nodes in reverse order, then shut them down (best effort, 2 s per call)."""
        self.monitoring = False
        if not rclpy.ok():
            return
        for n in reversed(self.nodes):
            self._transition(executor, n, Transition.TRANSITION_DEACTIVATE, 2.0)
        for n in reversed(self.nodes):
            r = self._call(executor, self.get_state[n], GetState.Request(), 2.0)
            if r is None:
                continue
            tid = {State.PRIMARY_STATE_INACTIVE: Transition.TRANSITION_INACTIVE_SHUTDOWN,
                   State.PRIMARY_STATE_UNCONFIGURED: Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
                   State.PRIMARY_STATE_ACTIVE: Transition.TRANSITION_ACTIVE_SHUTDOWN}.get(r.current_state.id)
            if tid is not None:
                self._transition(executor, n, tid, 2.0)

    # ---------------------------------------------------------------- health
    def on_diagnostics(self, msg: DiagnosticArray):
        """Heartbeats: a status ``magtune/<node>`` of this namespace's managed node (steady receive time); a unit's
        fault status ``magtune/<node>/fdir`` (fault_notice)."""
        now = time.monotonic()
        for st in msg.status:
            node = st.name.removeprefix("magtune/")
            if node.endswith(FDIR_SUFFIX) and node.removesuffix(FDIR_SUFFIX) in self.change:
                self.fault_notice(st, stamp_to_ns(msg.header.stamp))
            if node not in self.change:
                continue
            ns = next((kv.value for kv in st.values if kv.key == "namespace"), None)
            if ns is not None and ns != self.get_namespace():
                continue
            self.beats[node] = max(now, self.beats.get(node, now))  # not before a listening period's end
            self.heard[node] = now
            if st.level == DiagnosticStatus.ERROR:
                self.errors[node] = printable(st.message, 500)  # a peer's string, printed on a failed bring-up
            if node in self.silent:
                self.silent.discard(node)
                self.regained(node, f"heartbeat of {node} back")

    def fault_notice(self, st: DiagnosticStatus, ns: int):
        """A managed node's fault status naming a unit (its ``hardware_id``): a new or changed WARN/ERROR, or the unit's
        OK after one, republishes the mode unchanged with the status' message as its reason, stamped at the detection
        (the status array's sim time), so the mode topic names the unit too (docs/modes.md); repeats are ignored."""
        unit, text = printable(st.hardware_id, 64), printable(st.message, 300)
        if st.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR):
            if self.unit_faults.get(unit) == text:
                return
            self.unit_faults[unit] = text
        elif self.unit_faults.pop(unit, None) is None:
            return
        self.get_logger().warning(f"t={ns * 1e-9:.1f} s: {text}")
        self.publish_mode(text, ns)

    def on_transition(self, node: str, msg: TransitionEvent):
        """``<node>/transition_event``: while monitoring, a node leaving active is lost (the cause from the state it
        goes to: LEFT_ACTIVE, else that state's label as one bounded line); entering active again, it is back.
        At bring-up, its time is the node's progress (wait_transition)."""
        self.events_at[node] = time.monotonic()
        if not self.monitoring:
            return
        active = State.PRIMARY_STATE_ACTIVE
        if msg.start_state.id == active and msg.goal_state.id != active and node not in self.left:
            self.left[node] = LEFT_ACTIVE.get(msg.goal_state.id, f"now {printable(msg.goal_state.label, 64)}")
            self.lose(node, f"{node} left active ({self.left[node]})", "left_active")
        elif msg.goal_state.id == active and node in self.left:
            del self.left[node]
            self.regained(node, f"{node} active again")

    def check_heartbeats(self):
        """Liveness on steady time, counting the manager's own running time only (``stalled``): a managed node
        silent for heartbeat_timeout s -> SAFE, named; and a sensor stream's lag waiting for its confirmation
        (check_stale)."""
        now = time.monotonic()
        gap, self.checked = now - self.checked, now
        if gap > SELF_STALL:
            self.stalled(now, gap)
        if self.lagging is not None:
            self.check_stale()
        if not self.monitoring:
            return
        for n in self.nodes:
            age = now - self.beats.get(n, now)
            if age > self.heartbeat_timeout and n not in self.silent:
                self.silent.add(n)
                self.lose(n, f"heartbeat of {n} missed for {age:.1f} s (heartbeat_timeout {self.heartbeat_timeout:g} s)",
                          "heartbeat_lost")

    def stalled(self, now: float, gap: float):
        """The manager itself did not run for ``gap`` steady seconds (this check came late). It first listens for
        heartbeat_timeout, taking in what the stall held back (DDS repairs a reliable stream's gap within a writer's
        heartbeat period: the controller's heartbeats came back 2.4 s after a 5-s stop), and every heartbeat age
        counts from the end of that; a stream lag's confirmation time leaves the stall out."""
        listen = now + self.heartbeat_timeout
        self.beats = {n: max(t, listen) for n, t in self.beats.items()}
        if self.lagging is not None and self.lagging[3] is not None:
            self.lagging = (*self.lagging[:3], min(now, self.lagging[3] + gap - CHECK_PERIOD))
        if self.monitoring:  # rare and telling: every one is logged
            self.diag.count("self_stalls")
            self.get_logger().warning(f"the manager did not run for {gap:.1f} s (liveness check gap): heartbeat ages "
                                      f"count from {self.heartbeat_timeout:g} s from now")

    def lose(self, node: str, reason: str, counter: str):
        """``node`` is lost (silent, or out of active): counted, ERROR on /diagnostics naming it, and SAFE with
        ``reason`` (hold=False: it recovers by itself once every node is back and the data fresh), stamped with the
        manager's sim time now (now_s: the newest sample stamp it holds)."""
        self.lost.add(node)
        self.why[node] = reason
        self.diag.count(counter, reason)
        self.show_lost()
        if self.state.mode != SAFE:
            self.apply(*self.logic.request(self.state, SAFE, self.now_s(), reason, hold=False))
        self.diag.publish()

    def regained(self, node: str, what: str):
        """One cause of ``node``'s loss is gone (logged ``what``); it is back once neither is left."""
        self.get_logger().warning(what)
        if node in self.silent or node in self.left:
            return
        self.lost.discard(node)
        self.why.pop(node, None)
        self.show_lost()

    def show_lost(self):
        """The lost nodes on /diagnostics: key ``lost`` and an ERROR status with the reason of each (None: none lost)."""
        self.diag.extra["lost"] = ",".join(sorted(self.lost))
        self.diag.status = (DiagnosticStatus.ERROR, "; ".join(self.why[n] for n in sorted(self.lost))) \
            if self.lost else None

    def check_stale(self):
        """Staleness on sim time, from the stamps: a sensor stream whose last stamp lags the newest
        stamp of the other by more than stale_timeout, and which has delivered nothing for
        STALE_CONFIRM steady seconds since (two subscriptions of a manager behind the world may be
        drained in bursts, one ahead of the other), -> the logic steps with ``stale`` at the stamp
        where the lag was seen."""
        last = self.gate.last_ns
        if min(last) < 0:
            return
        lag = max(last) - min(last)
        slot = last.index(min(last))
        if lag <= self.stale_ns:
            self.lagging = None
            return
        lg = self.lagging
        if lg is None or lg[0] != slot or lg[1] != last[slot]:  # a new lag: confirm it before acting
            self.lagging = (slot, last[slot], max(last), time.monotonic())
            return
        if lg[3] is not None and time.monotonic() - lg[3] < STALE_CONFIRM:
            return
        at = lg[2] if lg[3] is not None else max(last)  # the first step at the stamp the lag was seen
        self.lagging = (slot, last[slot], max(last), None)  # confirmed: later messages step at their stamp
        self.diag.count("stale", f"{STREAMS[slot]} {lag * 1e-9:.1f} s behind the other sensor stream")
        self.step(replace(self.last or Measurements(rate=math.nan), stale=True), at * 1e-9)

    def proven_silence(self, slot: int, ns: int):
        """A lag still waiting for STALE_CONFIRM is proven when the lagging stream delivers again past the stamp where
        the lag was seen, its last sample still the one the lag was seen against: a reliable stream is delivered in
        order, so the samples between were never sent (or lost to the manager's full history). The logic then steps
        ``stale`` at the stamp where the lag was seen, as check_stale does once confirmed. A run whose controller
        answers a missing field at once can end a dropout in less than STALE_CONFIRM of wall time."""
        lg = self.lagging
        if lg is None or lg[3] is None or lg[0] != slot or self.gate.last_ns[slot] != lg[1] or ns <= lg[2]:
            return
        self.lagging = None
        self.diag.count("stale", f"{STREAMS[slot]} silent from {lg[1] * 1e-9:.1f} s to {ns * 1e-9:.1f} s")
        self.step(replace(self.last or Measurements(rate=math.nan), stale=True), lg[2] * 1e-9)

    # ---------------------------------------------------------------- mode logic
    def on_mag(self, data: bytes):
        """sensors/magnetic_field (raw): rejects and counts a malformed or non-finite sample; else stamp-gated and paired with the attitude."""
        f = raw_magnetic_field(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/magnetic_field message")
        if not finite(*f[1]):
            return self.diag.count("rejected_nonfinite", "non-finite sensor sample")
        self._input(0, f[0], f[1])

    def on_attitude(self, data: bytes):
        """sensors/attitude (raw): rejects and counts a malformed or non-finite attitude/gyro sample; else stamp-gated and paired."""
        f = raw_imu(data)
        if f is None:
            return self.diag.count("rejected_malformed", "malformed sensors/attitude message")
        if not (finite(*f[1]) and finite(*f[2])):
            return self.diag.count("rejected_nonfinite", "non-finite sensor sample")
        self._input(1, f[0], f[1:])

    def _input(self, slot: int, ns: int, values):
        self.proven_silence(slot, ns)
        bad = self.gate.check(slot, ns)
        if bad:
            return self.diag.count(*bad)
        pair = self.sync.add(slot, ns, values)
        if pair:
            self.sample(ns, *pair)
        else:  # a stream ahead of the other: is the other one stale?
            self.check_stale()

    def sample(self, ns: int, b, att):
        """One sample t_k: the measured quantities (field b, attitude (q, gyro w, known)), then one step of the
        logic; an attitude not known (orientation_covariance[0] = -1: the estimator has no valid estimate) has
        no pointing error."""
        (qw, qx, qy, qz), (wx, wy, wz), known = att
        self.fstate, bdot = self.filter.step(self.fstate, b)
        qv = math.sqrt(qx * qx + qy * qy + qz * qz) / max(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-300)
        step = math.nan if self.b_prev is None else math.dist(b, self.b_prev)
        self.b_prev = b
        m = Measurements(rate=math.sqrt(wx * wx + wy * wy + wz * wz), bdot=float(np.linalg.norm(bdot)),
                         pointing_error=2.0 * math.asin(min(qv, 1.0)) if known else math.nan, field_step=step,
                         attitude_known=known)
        self.last = m
        self.diag.count("samples")
        self.step(m, ns * 1e-9)

    def step(self, m: Measurements, t: float):
        """One step of the mode logic at sim time ``t`` (``stale`` forced while a heartbeat is lost, so SAFE holds); applies the result."""
        if self.lost:  # a silent node: SAFE holds (the logic's only health input is ``stale``)
            m = replace(m, stale=True)
        state, tr = self.logic.step(self.state, m, t)
        self.apply(state, tr)

    def apply(self, state: ModeState, tr):
        """Adopt the logic's new state; on a transition: count it, log it and publish the mode."""
        self.state = state
        if tr is not None:
            self.previous = tr.source
            self.diag.count("transitions")
            self.get_logger().info(f"t={tr.t:.1f} s: {tr.source} -> {tr.target}: {tr.reason}")
            self.publish_mode()

    def publish_mode(self, notice: str | None = None, notice_ns: int = 0):
        """Publish the mode, the previous one and the reason on mode (MODE_QOS: transient-local), stamped with the mode's
        ``since``; a ``notice`` (a unit's fault) republishes it with the notice as its reason, stamped ``notice_ns``."""
        st = self.state
        msg = Mode(mode=MODES.index(st.mode), label=st.mode, previous=MODES.index(self.previous),
                   reason=st.reason if notice is None else notice)
        msg.header.stamp = ns_to_stamp(max(0, sec_to_ns(st.since)) if notice is None else notice_ns)
        self.diag.extra["mode"] = st.mode
        self.pub_mode.publish(msg)

    def on_set_mode(self, req: SetMode.Request, res: SetMode.Response):
        """set_mode service: the commanded mode goes through the logic (reason recorded as one bounded
        printable line, ``base.text.printable``: it reaches the log and the mode topic); an unknown id fails;
        answers the mode in force."""
        self.diag.count("requests")
        if req.mode >= len(MODES):
            res.success, res.message = False, f"unknown mode id {req.mode} (expected 0..{len(MODES) - 1}: " \
                                              f"{', '.join(MODES)})"
        else:
            self.apply(*self.logic.request(self.state, MODES[req.mode], self.now_s(),
                                           f"commanded: {printable(req.reason) or 'set_mode'}"))
            res.success, res.message = True, f"mode {self.state.mode}"
        res.mode = MODES.index(self.state.mode)
        return res

    def now_s(self) -> float:
        """The manager's sim time [s]: the newest stamp of its samples (0 before the first)."""
        return max(0, *self.gate.last_ns) * 1e-9

    def finish(self):
        """At shutdown (``main.run``): the last diagnostics (as ``lifecycle.ManagedNode.finish``)."""
        if self.context.ok():
            self.diag.publish()


def main(args=None):
    """Entry point of the mode_manager node (console script): run(ModeManager)'s exit status."""
    return run(ModeManager, args)


if __name__ == "__main__":
    raise SystemExit(main())
