"""The operator session against the whole in-process stack (real node, real
simulated ArduSub over MAVLink, real channel emulator), on a faster link so a
test takes seconds, then its recording replayed and plotted."""

from __future__ import annotations

import asyncio
import json
import math
import time

import numpy as np
import pytest

from rovlink import debt
from rovlink.console.recording import RecordingError, plot, series
from rovlink.console.replaycontrol import replay
from rovlink.console.session.radio import Operator, OrderError
from rovlink.console.stack import Stack, StackConfig


def fast_config(tmp_path, **kw):
    return StackConfig(**{"bitrate_bps": 19200, "delay_s": 0.02, "ber": 1e-5, "record": tmp_path / "session.jsonl",
                          **kw})


async def until(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.05)
    return True


def test_operator_session_end_to_end(tmp_path):
    async def main():
        async with Stack(fast_config(tmp_path)) as stack:
            op = stack.operator
            seen = []
            op.subscribe(lambda topic, payload: seen.append(topic))
            assert await until(lambda: op.last_reply is not None and op.last_reply.autopilot, 15)

            # An image arrives and refines: decoded prefixes grow, then it completes.
            decoded = []
            op.subscribe(lambda topic, p: decoded.append(p["decoded_bytes"]) if topic == "image" else None)
            assert await until(lambda: op.image.images_completed >= 1, 30)
            first_image = decoded[: next((i for i in range(1, len(decoded)) if decoded[i] < decoded[i - 1]),
                                         len(decoded))]
            assert len(set(first_image)) >= 3 and first_image == sorted(first_image)
            picture = op.picture()
            assert picture is not None and picture.dtype == np.uint8 and picture.shape[:2] == (240, 320)

            # Arm and drive forward: the received pose moves, the ghost leads it.
            op.arm(True)
            assert await until(lambda: op.last_reply.armed, 15)
            x0 = op.pose_state()["received"]["x_m"]
            op.set_velocity(0.8, 0.0, 0.0, 0.0)
            assert await until(lambda: op.pose_state()["received"]["x_m"] > x0 + 1.0, 20)
            state = op.pose_state()
            assert state["predicted"]["x_m"] > state["received"]["x_m"]  # dead reckoning runs ahead
            op.set_velocity(0, 0, 0, 0)

            # A supervised position order: preview first, nothing moves until sent.
            target = (state["received"]["x_m"] - 2.0, state["received"]["y_m"] + 1.0, 2.5)
            path = op.preview_path(*target, 0.0)
            assert len(path) > 3 and math.dist(path[-1], target) < 0.5
            assert not any(o["kind"] == "POSITION" for o in op.orders_state())
            op.send_position(*target, 0.0)
            assert await until(lambda: any(o["kind"] == "POSITION" and o["state"] == "acknowledged"
                                           for o in op.orders_state()), 15)
            def where():
                t = stack.sim.truth().state
                return (t.x_m, t.y_m, t.z_m)

            assert await until(lambda: math.dist(where(), target) < 0.4, 40)

            # Image settings with an ROI: acknowledged; the next image carries it.
            roi = (40, 30, 200, 150)
            op.set_image_settings(roi=roi, shift=5, budget_bytes=1200)
            done = op.image.images_completed
            assert await until(lambda: op.image.images_completed >= done + 2, 40)
            header = debt.unpack_header(op.image.stream)
            assert tuple(header.roi) == roi
            assert len(op.image.stream) <= 1200

            stop_id = op.stop()
            # Protocol 1.1: STOP is confirmed by a reply showing the hold.
            assert await until(lambda: any(o["id"] == stop_id and o["state"] == "acknowledged"
                                           for o in op.orders_state()), 15), op.orders_state()[-3:]
            link = op.link_state()
            assert link["sent"] > 20 and link["autopilot"] and not link["failsafe"]
            assert {"pose", "image", "order"} <= set(seen)
            return op

    op = asyncio.run(asyncio.wait_for(main(), 150))
    rec = tmp_path / "session.jsonl"
    kinds = {json.loads(line)["k"] for line in rec.read_text().splitlines()}
    assert {"meta", "tx", "rx", "wish", "order", "order_state", "pose", "image"} <= kinds

    # The recording replays into a fresh console and gives the same images.
    async def play():
        fresh = Operator(None)
        counts = await replay(fresh, rec, speed=50.0)
        return fresh, counts

    fresh, counts = asyncio.run(asyncio.wait_for(play(), 60))
    assert counts["rx"] > 20
    assert fresh.image.images_completed == op.image.images_completed
    assert fresh.last_reply.x_cm == pytest.approx(op.last_reply.x_cm, abs=30)

    s = series(rec)
    assert s.received and len(s.commanded) >= 3
    for png in plot(rec, tmp_path / "plots"):
        assert png.stat().st_size > 10_000


def test_bad_orders_are_refused_with_a_reason():
    op = Operator(None)
    with pytest.raises(OrderError, match="vx"):
        op.set_velocity(1.5, 0, 0, 0)
    with pytest.raises(OrderError, match="vyaw"):
        op.set_velocity(0, 0, 0, float("nan"))
    with pytest.raises(OrderError, match="unknown mode"):
        op.set_mode("TURBO")
    with pytest.raises(OrderError, match="finite"):
        op.send_position(float("inf"), 0, 0)
    with pytest.raises(OrderError):
        op.send_position(400.0, 0, 0)  # beyond the int16 centimetres of the wire
    with pytest.raises(OrderError, match="ROI"):
        op.set_image_settings(roi=(10, 10, 5, 5))
    with pytest.raises(OrderError, match="BUDGET"):
        op.set_image_settings(budget_bytes=9000)
    assert op.orders_state() == []  # nothing was queued


def test_failsafe_is_shown_when_the_link_drops(tmp_path):
    async def main():
        # No bit errors: the ROV says FAILSAFE in one reply, the one to the first poll
        # that returns (docs/PROTOCOL.md §5), and a bit error in it (1 run in a few
        # hundred at 1e-5 here: a newcomer's run) leaves nothing that could say it.
        # Without that reply the console says it only by inference, from an outage
        # longer than the ROV's failsafe time (3 s), longer than this one.
        cfg = fast_config(tmp_path, failsafe_s=1.0, ber=0.0)
        async with Stack(cfg) as stack:
            op = stack.operator
            assert await until(lambda: op.last_reply is not None, 15)
            stack.channel.params["a"] = type(stack.channel.params["a"])(  # the channel goes deaf
                bitrate_bps=19200, delay_s=0.02, loss=1.0)
            assert await until(lambda: stack.node.slave.failsafe, 10)
            assert op.link_state()["reports_lost"] > 0
            flagged = []
            op.subscribe(lambda topic, p: flagged.append(p["failsafe"]) if topic == "pose" else None)
            stack.channel.params["a"] = type(stack.channel.params["a"])(bitrate_bps=19200, delay_s=0.02)
            assert await until(lambda: True in flagged, 10), (flagged, op.link_state())  # the first reply back says FAILSAFE
            assert await until(lambda: not stack.node.slave.failsafe and flagged[-1] is False, 10)

    asyncio.run(asyncio.wait_for(main(), 60))


def test_pictures_of_another_debt_format_are_said_loudly_once_each(tmp_path):
    # An ROV running an older rovlink sends DEBT format 1: the console shows
    # no wrong picture, and says why once per picture, as an alert.
    async def main():
        async with Stack(fast_config(tmp_path)) as stack:
            op = stack.operator
            assert await until(lambda: op.image.images_completed >= 1, 30)

            def older_rov(image, budget, **kw):
                data = debt.encode(image, budget, **kw)
                return bytes([0xB0 | (data[0] & 0x0F)]) + data[1:]   # magic 1011: format 1

            stack.node._encode = older_rov
            done = op.image.images_completed
            assert await until(lambda: op.image.images_completed >= done + 3, 30)
            said = [e for e in op.log_entries() if "cannot be decoded" in e["text"]]
            assert said and all(e["level"] == "alert" and "format 1" in e["text"] for e in said)
            pictures = {e["text"].split()[1] for e in said}
            assert len(pictures) == len(said)            # once per picture
            assert len(said) <= op.image.images_completed - done + 1
            assert op.picture() is None                  # nothing wrong is shown

    asyncio.run(asyncio.wait_for(main(), 60))


def test_replay_refuses_files_that_are_not_recordings(tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text("hello\n")
    with pytest.raises(RecordingError, match="not a rovlink recording"):
        series(bad)
    with pytest.raises(RecordingError, match="no such file"):
        series(tmp_path / "missing.jsonl")


def test_bench_console_reports_the_heap_over_a_session():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "rovlink", "bench", "console", "--duration", "240",
                          "--sample-every", "60", "--no-page", "--no-load", "--no-pilot", "--no-loaded", "--json"],
                         capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    samples = doc["memory"]["samples_mb"]
    assert [s["t_s"] for s in samples] == [60.0, 120.0, 180.0, 240.0]
    assert all(s["heap_mb"] > 0 for s in samples)
    assert doc["memory"]["polls"] > 200 and doc["memory"]["images_completed"] >= 5
    assert "memory_flat_over_one_hour" in doc["targets"]


def test_the_consoles_own_modem_port_going_down_is_an_alert_with_its_reason_cleared_when_back():
    import types

    port = types.SimpleNamespace(is_up=True, max_frame=None, stats=types.SimpleNamespace(last_error=None))
    operator = Operator(port)
    try:
        operator._turn(0.0)
        port.is_up, port.stats.last_error = False, "serial read failed: [Errno 5] Input/output error"
        operator._turn(0.1)
        operator._turn(0.2)  # said once
        alerts = [e for e in operator.log_entries(20) if "MODEM PORT DOWN" in e["text"]]
        assert len(alerts) == 1 and alerts[0]["level"] == "alert"
        assert "Input/output error" in alerts[0]["text"] and alerts[0]["cleared_wall"] is None
        port.is_up = True
        operator._turn(0.3)
        entries = operator.log_entries(20)
        assert any(e["text"] == "modem port open again" for e in entries)
        assert [e for e in entries if "MODEM PORT DOWN" in e["text"]][0]["cleared_wall"] is not None
    finally:
        operator.close()
