"""The mode manager's wait for one lifecycle transition of a managed node: progress, not a fixed wall time.

The manager asks a node to configure (then activate) over ``<node>/change_state`` and waits. The reply alone
cannot tell a slow node from a failed one: it can be late (a node starting or configuring on a busy machine) or
lost (a DDS service answers before the client's response reader matched: rmw_fastrtps drops such a reply after
100 ms, ros2/rmw_fastrtps#390 and #467; a CI run reported "configure failed (node inactive)", a node that had
configured). The node's state (``get_state``) and its signs of life (its 1-Hz /diagnostics heartbeat, its
transition events, any lifecycle reply) can, so :class:`TransitionWait` decides on all of them:

==========================================================  ===================================================
observed                                                    verdict
==========================================================  ===================================================
the reply success, or the state is the goal                 DONE (whatever the reply said, or if none came)
the state back at the start after a reply "failed", or       FAILED: the node's one line (its ERROR status), else
the node's ERROR status with the state at the start          "<transition> failed (node <state>)"
the state still the start ``resend`` s after the request,   SEND again (the request was lost)
no transition event since
no sign of life for ``silence`` s                           SILENT: not answering (not started, hung)
alive but not at the goal after ``limit`` s                 SLOW: names the state and the limit to raise
==========================================================  ===================================================

Pure logic on the times the manager observed (steady seconds) and nothing else, so every row is tested without
ROS (tests/onboard/test_bringup.py); the node (magtune_ros.mode_manager) does the calls.
"""
from __future__ import annotations

from dataclasses import dataclass, field

#: Verdicts of :meth:`TransitionWait.verdict`.
WAIT, SEND, ASK, DONE, FAILED, SILENT, SLOW = "wait", "send", "ask", "done", "failed", "silent", "slow"
#: Seconds between two ``get_state`` questions while no reply came [steady s]: cheap (one small service call),
#: and a lost reply is found within this.
ASK_PERIOD = 2.0
#: The request is sent again when the node, asked after this long [steady s], is still in the start state with no
#: transition event since: the request did not arrive (a configure that started shows a transition event).
RESEND_AFTER = 5.0
#: After a reply "failed" and the state back at the start, the node's ERROR status (its one-line reason, published
#: before the reply on another topic) is waited for this long [steady s] before the generic line.
ERROR_GRACE = 3.0
#: The states a transition leaves and reaches (lifecycle_msgs labels), by transition name.
TRANSITIONS = {"configure": ("unconfigured", "inactive"), "activate": ("inactive", "active")}


@dataclass
class TransitionWait:
    """One transition of one node, waited for on its progress (module docstring: the verdict table).

    Parameters
    ----------
    node : str
        The managed node's name (in the verdict lines).
    transition : str
        ``"configure"`` or ``"activate"`` (:data:`TRANSITIONS`).
    t0 : float
        Steady time the wait began [s].
    silence : float
        A node that gives no sign of life this long [s] is not answering (the manager's ``transition_timeout``).
    limit : float
        A node alive but not at the goal this long after ``t0`` [s] is too slow (what is left of the manager's
        ``bringup_limit``, a limit on the whole bring-up).
    """
    node: str
    transition: str
    t0: float
    silence: float
    limit: float
    seen: float = field(init=False)              # last sign of life [s]
    sent: float | None = field(default=None, init=False)   # when the request was last sent
    asked: float | None = field(default=None, init=False)  # when get_state was last asked
    state: str | None = field(default=None, init=False)    # the last state the node answered
    state_at: float = field(default=-1.0, init=False)      # when that answer was asked
    started: float = field(default=-1.0, init=False)       # the last transition event of this node
    refused: float | None = field(default=None, init=False)  # a reply success=false
    replied: bool = field(default=False, init=False)       # a reply success=true

    def __post_init__(self):
        if self.transition not in TRANSITIONS:
            raise ValueError(f"transition: expected one of {sorted(TRANSITIONS)}, got {self.transition!r}")
        self.seen = self.t0

    @property
    def start(self) -> str:
        """The state the transition leaves.

        Returns
        -------
        str
            Its lifecycle_msgs label (``unconfigured``, ``inactive``).
        """
        return TRANSITIONS[self.transition][0]

    @property
    def goal(self) -> str:
        """The state the transition reaches.

        Returns
        -------
        str
            Its lifecycle_msgs label (``inactive``, ``active``).
        """
        return TRANSITIONS[self.transition][1]

    # ---------------------------------------------------------------- what the manager observed
    def alive(self, t: float) -> None:
        """A sign of life of the node (its heartbeat on /diagnostics).

        Parameters
        ----------
        t : float
            Steady time it was received [s].
        """
        self.seen = max(self.seen, t)

    def sending(self, t: float) -> None:
        """The request was sent (again).

        Parameters
        ----------
        t : float
            Steady time [s].
        """
        self.sent = t

    def asking(self, t: float) -> None:
        """``get_state`` was asked (a question before it, unanswered, is forgotten).

        Parameters
        ----------
        t : float
            Steady time [s].
        """
        self.asked = t

    def event(self, t: float) -> None:
        """A transition event of the node: it is working on a transition.

        Parameters
        ----------
        t : float
            Steady time it was received [s].
        """
        self.started = t
        self.alive(t)

    def reply(self, t: float, success: bool) -> None:
        """The ``change_state`` reply.

        Parameters
        ----------
        t : float
            Steady time it was received [s].
        success : bool
            What it said.
        """
        self.alive(t)
        if success:
            self.replied = True
        else:
            self.refused = t

    def answer(self, t: float, state: str) -> None:
        """The ``get_state`` answer to the question asked last.

        Parameters
        ----------
        t : float
            Steady time it was received [s].
        state : str
            The state's label.
        """
        self.alive(t)
        self.state, self.state_at = state, self.asked if self.asked is not None else t

    # ---------------------------------------------------------------- the decision
    def verdict(self, t: float, error: str | None = None) -> tuple[str, str]:
        """What to do at steady time ``t`` (module docstring: the table), given the node's ERROR status line.

        Parameters
        ----------
        t : float
            Steady time now [s].
        error : str or None
            The node's last ERROR status message on /diagnostics (its one-line reason), if any.

        Returns
        -------
        tuple of str
            ``(verdict, line)``: one of WAIT, SEND, ASK (act and call again), DONE, FAILED, SILENT, SLOW
            (final); ``line`` says why for the final ones that are not DONE.
        """
        if self.replied or self.state == self.goal:
            return DONE, ""
        failed = self._failed(t, error)
        if failed:
            return FAILED, failed
        if t - self.seen > self.silence:
            return SILENT, (f"no answer for {t - self.seen:.0f} s (no lifecycle reply, no heartbeat on /diagnostics; "
                            f"transition_timeout {self.silence:g} s): is it running?")
        if t - self.t0 > self.limit:
            where = f"still {self.state}" if self.state else "no state reported"
            return SLOW, (f"{self.transition} not done after {t - self.t0:.0f} s ({where}, alive: it answers); "
                          "the bring-up's bringup_limit reached: raise it if the node is only slow")
        if self.sent is None or self._lost(t):
            return SEND, ""
        if self.refused is not None and (self.asked is None or self.asked < self.refused):
            return ASK, ""  # refused: the state decides (a resent request is refused once the first one is done)
        if self.asked is None or t - self.asked >= ASK_PERIOD:
            return ASK, ""
        return WAIT, ""

    def _failed(self, t: float, error: str | None) -> str:
        """The failure line when the node said it failed, else ''."""
        back = self.state == self.start and self.sent is not None and self.state_at >= self.sent
        if error and (back or self.refused is not None):
            return error.removeprefix("configure failed: ")
        if self.refused is not None and back and self.state_at >= self.refused and t - self.refused > ERROR_GRACE:
            return f"{self.transition} failed (node {self.state})"
        return ""

    def _lost(self, t: float) -> bool:
        """The request did not arrive: asked after it, the node is still at the start, no event since it was sent."""
        return (self.refused is None and self.state == self.start and self.state_at >= self.sent + RESEND_AFTER
                and self.started < self.sent and t - self.sent >= RESEND_AFTER)
