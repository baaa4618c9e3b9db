"""The bring-up's wait for one transition (magtune_core.onboard.bringup): every row of its verdict table, driven by
the observations the mode manager makes, in steady seconds. The real bring-up runs in every ``--modes`` SIL test
(tests/ros); a node that never answers is tests/ros/test_modes_sil.py's."""
from __future__ import annotations

import pytest

from magtune_core.onboard.bringup import ASK, ASK_PERIOD, DONE, ERROR_GRACE, FAILED, RESEND_AFTER, SEND, SILENT, SLOW, WAIT, TransitionWait

SILENCE, LIMIT = 30.0, 300.0


def sent(transition="configure", t0=0.0) -> TransitionWait:
    """A wait whose request went out at t0 (its first verdict is SEND)."""
    w = TransitionWait("attitude_estimator", transition, t0, SILENCE, LIMIT)
    assert w.verdict(t0) == (SEND, "")
    w.sending(t0)
    return w


def test_a_reply_success_is_done():
    w = sent()
    w.reply(0.2, True)
    assert w.verdict(0.2) == (DONE, "")


def test_a_lost_reply_is_found_by_the_state():
    """The CI failure: the node configured, its reply never came; the manager asks and finds it inactive."""
    w = sent()
    assert w.verdict(0.1) == (ASK, "")
    w.asking(0.1)
    assert w.verdict(0.2) == (WAIT, "")  # one question at a time, every ASK_PERIOD
    w.answer(0.3, "inactive")
    assert w.verdict(0.3) == (DONE, "")


def test_a_slow_configure_is_waited_for_beyond_the_old_fixed_timeout():
    """The node's executor is busy configuring for 40 s (no heartbeat, no answer) while its last heartbeat came at
    12 s: silent for 28 s < 30 s is still waiting; the reply at 40 s is done."""
    w = sent()
    w.alive(12.0)
    t = 0.1
    while t < 40.0:
        verdict, _ = w.verdict(t)
        assert verdict in (WAIT, ASK), (t, verdict)
        if verdict == ASK:
            w.asking(t)
        t += 0.1
    w.reply(40.0, True)
    assert w.verdict(40.0)[0] == DONE


def test_a_request_that_did_not_arrive_is_sent_again():
    w = sent()
    w.alive(1.0)
    for t in (0.25, 2.25, 4.25):  # asked every ASK_PERIOD, still unconfigured, no event: not yet RESEND_AFTER
        assert w.verdict(t)[0] == ASK
        w.asking(t)
        w.answer(t + 0.125, "unconfigured")
    assert w.verdict(4.5)[0] == WAIT
    t = 0.25 + 3 * ASK_PERIOD
    assert t >= RESEND_AFTER
    assert w.verdict(t)[0] == ASK
    w.asking(t)
    w.answer(t + 0.125, "unconfigured")
    assert w.verdict(t + 0.25)[0] == SEND


def test_a_started_transition_is_not_sent_again():
    """A transition event after the request: the node is working on it, the request arrived."""
    w = sent()
    w.event(0.5)
    for t in (0.25, 2.25, 4.25, 6.25, 8.25):
        assert w.verdict(t)[0] == ASK
        w.asking(t)
        w.answer(t + 0.125, "unconfigured")  # e.g. an answer queued before the transition ran
    assert w.verdict(8.5)[0] == WAIT


def test_a_resent_request_refused_after_the_first_was_done_is_done():
    w = sent()
    w.sending(6.0)           # sent again
    w.reply(6.5, False)      # refused: configure is not valid from inactive
    assert w.verdict(6.5)[0] == ASK  # the state decides, at once
    w.asking(6.5)
    w.answer(6.6, "inactive")
    assert w.verdict(6.6)[0] == DONE


def test_a_failed_configure_gives_the_nodes_line():
    w = sent()
    w.reply(0.5, False)
    line = "configure failed: parameter 'min_field': expected at most 1e-3 T"
    assert w.verdict(0.5, line) == (FAILED, "parameter 'min_field': expected at most 1e-3 T")


def test_a_failed_configure_without_its_line_is_named_after_the_grace():
    w = sent()
    w.reply(0.5, False)
    w.asking(0.5)
    w.answer(0.6, "unconfigured")
    assert w.verdict(0.6 + ERROR_GRACE - 0.1)[0] in (WAIT, ASK)  # its ERROR status may still come
    assert w.verdict(0.6 + ERROR_GRACE) == (FAILED, "configure failed (node unconfigured)")


def test_an_error_status_with_the_state_back_at_the_start_fails_even_without_a_reply():
    w = sent()
    w.asking(1.0)
    w.answer(1.1, "unconfigured")
    assert w.verdict(1.2, "configure failed: spacecraft file: no 'inertia'") == (FAILED, "spacecraft file: no 'inertia'")


def test_an_error_status_before_the_request_is_not_this_transitions():
    """The state answered before the request went out says nothing about it."""
    w = TransitionWait("controller", "configure", 0.0, SILENCE, LIMIT)
    w.asking(0.0)
    w.answer(0.1, "unconfigured")
    w.sending(0.5)
    assert w.verdict(0.6, "configure failed: old")[0] != FAILED


def test_a_node_that_never_answers_is_silent():
    w = TransitionWait("ghost", "configure", 0.0, SILENCE, LIMIT)
    t = 0.0
    while w.verdict(t)[0] == SEND:  # its service never appears: the request is never sent
        t += 0.5
    verdict, line = w.verdict(t)
    assert verdict == SILENT and t == pytest.approx(SILENCE + 0.5), t
    assert line.startswith("no answer for 30 s") and "transition_timeout 30 s" in line, line


def test_a_node_alive_past_the_limit_is_slow_and_says_its_state():
    w = sent("activate")
    t = 0.0
    while True:
        w.alive(t)  # heartbeats all along
        verdict, line = w.verdict(t)
        if verdict == ASK:
            w.asking(t)
            w.answer(t, "inactive")
        elif verdict not in (WAIT, SEND):
            break
        t += 1.0
    assert verdict == SLOW and t == pytest.approx(LIMIT + 1.0)
    assert line.startswith("activate not done after 301 s (still inactive") and "bringup_limit" in line, line


def test_an_unknown_transition_is_refused():
    with pytest.raises(ValueError, match="transition"):
        TransitionWait("controller", "cleanup", 0.0, SILENCE, LIMIT)


def test_an_unanswered_question_is_asked_again():
    """The reply to the first get_state can be dropped as the first change_state reply can (a clean-clone CI run:
    the reply writer not yet matched); the wait asks again every ASK_PERIOD, the node replacing the question."""
    w = sent()
    w.alive(0.0)
    asked = []
    for k in range(40):  # 10 s, no answer at all, heartbeats all along
        t = 0.25 * k
        w.alive(t)
        if w.verdict(t)[0] == ASK:
            w.asking(t)
            asked.append(t)
    assert asked == [0.0, 2.0, 4.0, 6.0, 8.0]
    w.answer(9.0, "inactive")
    assert w.verdict(9.0)[0] == DONE
