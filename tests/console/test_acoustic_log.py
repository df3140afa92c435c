"""The acoustic console's log tells what a STATUS changed, never what did not happen
(issue 33): a first STATUS without FAILSAFE is no way out of one."""

from __future__ import annotations

import dataclasses

from rovlink.console.session.acoustic import AcousticSession
from rovlink.link import acoustic as ac

K = bytes(range(32))
HOLDING = ac.StatusBody(hold=True, autopilot=True, uplink=True, mode=4)


def _texts(session: AcousticSession) -> list[str]:
    return [entry["text"] for entry in session.log_entries()]


def test_failsafe_is_logged_only_where_it_begins_and_ends():
    session = AcousticSession(None, K, clock=lambda: 100.0)
    session._handle([ac.StatusReceived(HOLDING, 97.0, 0)], 0.0)  # the first STATUS: no FAILSAFE
    assert not any("FAILSAFE" in t for t in _texts(session))
    session._handle([ac.StatusReceived(dataclasses.replace(HOLDING, failsafe=True), 99.0, 1)], 2.0)
    session._handle([ac.StatusReceived(HOLDING, 101.0, 2)], 4.0)
    assert [t.split(":")[0] for t in _texts(session) if "FAILSAFE" in t] == ["ROV in FAILSAFE", "ROV out of FAILSAFE"]
    session.close()
