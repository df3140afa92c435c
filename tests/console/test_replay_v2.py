"""Protocol version 2 in the console: the link says which version it runs,
sent polls are read through their tag (order fates, received velocity), and
a recorded session replays from the replies the master was given, never from
raw authenticated frames."""

from __future__ import annotations

import asyncio

from rovlink.console.recording import read_records, series
from rovlink.console.replaycontrol import replay
from rovlink.console.session.radio import Operator
from rovlink.console.stack import Stack, StackConfig

from .conftest import wait_for


def test_an_authenticated_session_records_what_replay_needs(tmp_path):
    record = tmp_path / "session.jsonl"

    async def session() -> dict:
        config = StackConfig(bitrate_bps=19200, delay_s=0.02, ber=0.0, key=bytes(range(32)), record=record)
        async with Stack(config) as stack:
            op = stack.operator
            assert op.link_state()["version"] == "2"
            ok = await asyncio.to_thread(wait_for, lambda: op.image_state()["images_completed"] >= 2, 60)
            assert ok, "no image over the authenticated link"
            op.set_velocity(0.5, 0.0, 0.0, 0.0)
            await asyncio.sleep(1.5)
            return op.link_state()

    link = asyncio.run(session())
    assert link["inauthentic_frames"] == 0
    kinds = [r.get("k") for r in read_records(record)]
    assert "link" in kinds and kinds.count("reply") > 10
    # The plots read the polls through their tag: the wish sent reached the ROV.
    assert any(v[0] > 0.4 for _, v in series(record).received)

    replayed = Operator(None)
    counts = asyncio.run(replay(replayed, record, speed=20.0))
    assert counts["replies"] > 10
    assert replayed.image_state()["images_completed"] >= 1
    assert replayed.last_reply is not None and replayed.last_reply.autopilot


def test_an_insecure_operator_says_so():
    assert Operator(None).link_state()["version"] == "1.1"
