"""A link process that runs but is slow to answer (a busy machine) is not a link
process that is down (issue 39's hostile-relay STOP "queued" for 20 s, the console's
half): an order handed to it is neither refused nor parked for a restart that never
comes; it stays queued and is followed under the master's id once the answer comes,
and what the master already said of that id (its events may come first) applies then.

The radio session here drives a real master behind the child's real command thread
over a real pipe (tests/link/test_link_process_parts.py `Served`); only the master's
slowness is the test's."""

from __future__ import annotations

import time

import pytest

from rovlink.console.session.fates import Fate
from rovlink.console.session.radio import Operator
from tests.link.test_link_process_parts import slow_master_served


def answers_read(link) -> None:
    """What the link loop does each turn, until the slow calls' answers are all in."""
    deadline = time.monotonic() + 10
    while link._late and time.monotonic() < deadline:
        link._read_late_answers()
        time.sleep(0.01)
    assert not link._late, link._late


@pytest.fixture
def slow(monkeypatch):
    link, master, served = slow_master_served(monkeypatch)
    operator = Operator(None, master=link, record=None)
    try:
        yield operator, link, master
    finally:
        master.go_on.set()
        served.end()
        operator._decoder.shutdown()


def test_a_stop_the_link_process_is_slow_to_take_is_kept_queued_then_followed(slow):
    operator, link, master = slow
    order_id = operator.stop()  # never refused, never an exception to the pilot
    order = operator.orders.get(order_id)
    assert order["state"] == Fate.QUEUED.value, order
    assert operator._stops_to_resend == []  # not parked for a restart: the process runs
    assert any("did not answer send_order" in e["text"] for e in operator.log_entries()), operator.log_entries()
    # The master's events may come before its answer: the poll that carried the STOP.
    operator.orders.sent_by_master_id(1, operator.now())
    assert operator.orders.get(order_id)["state"] == Fate.QUEUED.value
    master.go_on.set()
    answers_read(link)
    assert operator.orders.get(order_id)["state"] == Fate.SENT.value
    operator.orders.settled(1, Fate.ACKNOWLEDGED, operator.now())
    assert operator.orders.get(order_id)["state"] == Fate.ACKNOWLEDGED.value


def test_a_goto_the_link_process_is_slow_to_take_is_unknown_if_the_process_ends_first(slow):
    operator, link, master = slow
    order_id = operator.send_position(1.0, 2.0, 3.0, 0.0)
    assert operator.orders.get(order_id)["state"] == Fate.QUEUED.value
    link._lose_late("the link process ended before it answered")
    order = operator.orders.get(order_id)
    assert order["state"] == Fate.UNKNOWN.value and "ended before it answered" in order["reason"], order


def test_an_arm_the_link_process_is_slow_to_take_is_watched_not_refused(slow):
    operator, link, master = slow
    # request_arm does not wait on the test's slow send_order: make the process busy otherwise
    # by a STOP still waiting, whose call holds the machine's command thread.
    operator.stop()
    order_id = operator.arm(True)
    order = operator.orders.get(order_id)
    assert order["state"] == Fate.REQUESTED.value and order["outcome"] != "rejected", order
    master.go_on.set()
    answers_read(link)
    assert operator.orders.fate(order_id).pending  # followed when the vehicle shows it armed
