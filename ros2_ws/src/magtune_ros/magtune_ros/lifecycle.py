"""ManagedNode: the base of the magtune flight nodes with a life (rclpy.lifecycle).

It follows the ``ros2/demos`` ``lifecycle_py`` pattern (the transitions as ``on_*`` callbacks, each
calling the base class) with one difference, on purpose: the data publishers and subscriptions are
created in ``activate()`` and destroyed at deactivation instead of being lifecycle publishers made in
``on_configure``. A lockstep peer (the simulator waits for its subscribers and the controller's
command) must see the node only while it takes and sends data; an inactive lifecycle publisher
would still match and its readers would wait for data that never comes.

A second difference: ``~/change_state`` answers every request. rclpy's own callback asks rcl for the
requested transition without checking it first, and a transition the current state does not have
(``activate`` while unconfigured, an unknown id such as 99) raises "Transition is not registered" in
the executor: any peer on the domain could end a flight node with one request. ManagedNode checks the
request against the current state's transitions first (:meth:`ManagedNode.refused_transition`):
an invalid one is answered success=false, counted (``rejected_transition`` on /diagnostics, logged
first and every 100th time, the peer's label made one bounded line) and the node stays where it was.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.task import Future

from magtune_core.base.errors import ConfigError
from magtune_core.base.text import printable
from magtune_core.onboard.params import AUTOSTART

from .diagnostics import Diagnostics
from .params import ParamError, declare_field


def state_machine(node: LifecycleNode):
    """rclpy's lifecycle state machine of ``node``: ``current_state`` (id, label) and
    ``available_transitions`` (id, label, start id, start label, goal id, goal label) of that state.

    rclpy keeps it in the private ``LifecycleNodeMixin._state_machine`` and has no public reader of the
    current state or its transitions (a node's own ``get_state`` / ``get_available_transitions``
    services are name-mangled callbacks). This is the one place that reads it
    (tests/ros/test_lifecycle_interfaces.py fails if rclpy renames it or changes its shape).
    """
    return node._state_machine


class ManagedNode(LifecycleNode):
    """A magtune flight node with a life (``rclpy.lifecycle``): configure, activate, deactivate,
    cleanup, shutdown, driven through ``~/change_state`` (lifecycle_msgs) by the mode manager.

    Subclasses implement ``configure()`` (declare and validate the parameters, build the law:
    ParamError/ConfigError -> the transition fails, the node stays *unconfigured*, the one-line
    reason is logged, kept in ``config_error`` and published as an ERROR status on /diagnostics,
    where the manager reads it), ``activate()`` (create the data subscriptions and publishers) and
    ``deactivate()`` (destroy them). Data entities live only while *active* so a lockstep peer
    (the simulator waits for its subscribers) sees the node only once it takes and sends data.
    /diagnostics (the node's heartbeat, 1 Hz steady time, key ``state``) runs in every state.

    With parameter ``autostart`` true (default: a node started alone, or ``magtune sil`` without
    ``--modes``) :func:`run` configures and activates the node itself: a bad parameter prints the
    one line and exits 2 as a plain node does.
    """

    def __init__(self, name: str, counters):
        super().__init__(name)
        self.done = Future()
        self.config_error: str | None = None
        self.autostart_on = declare_field(self, AUTOSTART)
        self.diag = Diagnostics(self, [*counters, "rejected_transition"])
        self.diag.extra["state"] = "unconfigured"
        self.diag.extra["namespace"] = self.get_namespace()  # /diagnostics is shared by every satellite
        self._entities: list = []
        self._guard_change_state()

    # ~/change_state answers every request (module docstring)
    def _guard_change_state(self):
        """Put :meth:`refused_transition` in front of rclpy's ``~/change_state`` callback.

        The service is found among the node's public ``services`` by its type and its public
        ``callback`` attribute (what every executor calls) is wrapped; rclpy's callback still runs
        every valid request, so the transitions and their callbacks are rclpy's."""
        srv = next(s for s in self.services if s.srv_type is ChangeState)
        accept = srv.callback

        def change_state(req: ChangeState.Request, resp: ChangeState.Response):
            why = self.refused_transition(req.transition)
            if why is None:
                return accept(req, resp)
            self.diag.count("rejected_transition", why)
            resp.success = False
            return resp

        srv.callback = change_state

    def refused_transition(self, transition: Transition) -> str | None:
        """Why a peer's ``change_state`` request cannot run from the current state (one bounded line),
        or None when it can. The label decides when it is set (as in rclpy), else the id.

        Parameters
        ----------
        transition : lifecycle_msgs.msg.Transition
            The requested transition.

        Returns
        -------
        str or None
            The reason, naming the transition and the current state; None for a valid transition.
        """
        machine = state_machine(self)
        state = machine.current_state[1]
        valid = machine.available_transitions
        if transition.label:
            if any(t[1] == transition.label for t in valid):
                return None
            asked = f"label '{printable(transition.label, 64)}'"
        else:
            if any(t[0] == transition.id for t in valid):
                return None
            asked = f"id {transition.id}"
        allowed = ", ".join(f"{t[1]} ({t[0]})" for t in valid) or "none"
        return f"change_state refused: transition {asked} is not valid from state '{state}' (valid: {allowed})"

    # the transitions, as rclpy calls them; each calls the base class (lifecycle_py's pattern)
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """configure(): a bad parameter fails the transition (logged, on /diagnostics), the node stays unconfigured."""
        try:
            self.configure()
        except (ParamError, ConfigError) as exc:
            self.config_error = str(exc)
            self.diag.status = (DiagnosticStatus.ERROR, f"configure failed: {exc}")
            self.diag.publish()
            if not self.autostart_on:  # alone, run() prints the one line
                self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.config_error, self.diag.status = None, None
        return self._entered("inactive", super().on_configure(state))

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """activate(): the data topics appear."""
        self.activate()
        return self._entered("active", super().on_activate(state))

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The data topics disappear; parameters and laws stay."""
        self._destroy_entities()
        return self._entered("inactive", super().on_deactivate(state))

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Back to unconfigured: the next configure reads the parameters again."""
        self._destroy_entities()
        return self._entered("unconfigured", super().on_cleanup(state))

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Finalized: the process ends (status 0), as a lifecycle node's owner would end it."""
        self._destroy_entities()
        if not self.done.done():
            self.done.set_result(0)
        return self._entered("finalized", super().on_shutdown(state))

    def _entered(self, label: str, base: TransitionCallbackReturn) -> TransitionCallbackReturn:
        """The state label on /diagnostics once the base class accepted the transition."""
        if base == TransitionCallbackReturn.SUCCESS:
            self.diag.extra["state"] = label
        return base

    # entity bookkeeping of activate()
    def data_publisher(self, *args):
        """A publisher that exists while the node is active."""
        pub = self.create_publisher(*args)
        self._entities.append(pub)
        return pub

    def data_subscription(self, msg_type, topic, callback, *args, **kw):
        """A subscription that exists while the node is active (``raw=True``: the callback gets the bytes).

        The callback is skipped once the node left *active*: a message the executor took before a peer's
        deactivate was served would otherwise publish on a destroyed publisher (InvalidHandle: the node died).
        """
        def while_active(msg):
            if self._entities:
                callback(msg)

        sub = self.create_subscription(msg_type, topic, while_active, *args, **kw)
        self._entities.append(sub)
        return sub

    @property
    def data_active(self) -> bool:
        """The data topics exist (the node is *active*): timers that publish check it."""
        return bool(self._entities)

    def _destroy_entities(self):
        for e in self._entities:
            (self.destroy_publisher if hasattr(e, "publish") else self.destroy_subscription)(e)
        self._entities = []

    def autostart(self) -> bool:
        """With ``autostart``: configure then activate; False (reason in ``config_error``) if configure failed."""
        if not self.autostart_on:
            return True
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            return False
        self.trigger_activate()
        return True

    # what subclasses fill in
    def finish(self):
        """At shutdown (``run``): the last diagnostics, so /diagnostics ends with the final counters."""
        if self.context.ok():
            self.diag.publish()

    def configure(self):  # pragma: no cover - abstract
        """Declare and validate the parameters and build the node's models (on_configure); ParamError/ConfigError fails the transition."""
        raise NotImplementedError

    def activate(self):  # pragma: no cover - abstract
        """Create the data topics with data_publisher / data_subscription (on_activate); they are destroyed at deactivation."""
        raise NotImplementedError
