"""The acoustic console's API turns bad requests away with a clear answer (422, the
field named), orders the link cannot take yet with 409 and the reason, and no bad
request ever queues an order or stops the app."""

from __future__ import annotations

import pytest

from rovlink.console.acoustic.session import AcousticSession
from rovlink.console.acoustic.web import create_acoustic_app

from ..helpers import local_test_client

KEY = bytes(range(32))


@pytest.fixture
def api():
    session = AcousticSession(None, KEY)  # no link: the session as the web app sees it before any STATUS
    with local_test_client(create_acoustic_app(session)) as client:
        yield client, session
    session.close()


@pytest.mark.parametrize("path, body, words", [
    ("/api/goto", {"x_m": "north", "y_m": 0, "z_m": 1}, "x_m"),
    ("/api/goto", {"y_m": 0, "z_m": 1}, "x_m"),
    ("/api/goto", {"x_m": 1e9, "y_m": 0, "z_m": 1}, "within"),
    ("/api/goto", {"x_m": 1, "y_m": 0, "z_m": 1, "yaw_deg": 500}, "yaw"),
    ("/api/goto", {"x_m": 1, "y_m": 0, "z_m": 1, "body": True}, "relative"),
    ("/api/order", {"order": "explode"}, "unknown order"),
    ("/api/order", {"order": "mode", "mode": "WARP"}, "mode must be"),
    ("/api/order", {"order": "mode"}, "mode must be"),
    ("/api/order", {}, "order"),
    ("/api/thumbnail", {"budget": 5}, "budget"),
    ("/api/thumbnail", {"budget": 100000}, "budget"),
    ("/api/thumbnail", {"roi": [10, 10, 5, 5]}, "thumbnail"),
    ("/api/thumbnail", {"roi": [-5, 0, 300, 40]}, "roi"),
    ("/api/thumbnail", {"roi": [0, 0, 40]}, "roi"),
    ("/api/thumbnail", {"shift": 99}, "shift"),
])
def test_a_bad_request_is_refused_with_its_field_named_and_queues_nothing(api, path, body, words):
    client, session = api
    r = client.post(path, json=body)
    assert r.status_code == 422, (r.status_code, r.text)
    assert words in r.text, r.text
    assert session.op.orders_waiting == 0 and session.orders == {}


def test_bodies_that_are_no_json_object_are_refused(api):
    client, session = api
    for raw in (b"NaN", b"[1, 2]", b"{", b"\xff\xfe"):
        r = client.post("/api/goto", content=raw, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, (raw, r.status_code)
    assert session.op.orders_waiting == 0


def test_a_good_order_before_any_status_is_refused_with_the_reason(api):
    client, session = api
    r = client.post("/api/goto", json={"x_m": 1.0, "y_m": 2.0, "z_m": 3.0})
    assert r.status_code == 409 and "no STATUS" in r.text
    r = client.post("/api/order", json={"order": "arm"})
    assert r.status_code == 409
    assert session.op.orders_waiting == 0


def test_stop_is_taken_at_any_time_and_the_state_says_so(api):
    client, session = api
    r = client.post("/api/stop")
    assert r.status_code == 200
    state = client.get("/api/state").json()
    assert state["stop"]["state"] not in ("none", "confirmed")   # pressed, not yet confirmed by the ROV
    assert state["status"] is None                               # nothing made up
    assert client.get("/api/thumbnail.png").status_code == 404   # no thumbnail yet


def test_a_post_from_another_sites_page_is_refused(api):
    """Any page the pilot has open could otherwise send a go-to, or STOP, through
    the pilot's browser to the console on this machine."""
    client, session = api
    evil = {"Origin": "http://evil.example"}
    for path, body in (("/api/goto", {"x_m": 1, "y_m": 0, "z_m": 1}), ("/api/stop", None),
                       ("/api/order", {"order": "arm"}), ("/api/thumbnail", {})):
        r = client.post(path, json=body, headers=evil)
        assert r.status_code == 403 and "cross-site" in r.json()["message"], (path, r.text)
    assert session.stop_state["state"] == "none" and session.op.orders_waiting == 0
    assert client.post("/api/stop", headers={"Origin": "http://127.0.0.1"}).status_code == 200  # its own page


class ModemPort:
    """The console's modem as the session sees it: up or down, with the
    transport's reason (link.transport.Endpoint's `is_up` and `stats.last_error`)."""

    def __init__(self) -> None:
        import types

        self.is_up = True
        self.stats = types.SimpleNamespace(last_error=None)
        self.sent: list[bytes] = []

    def send(self, packet: bytes) -> bool:
        if self.is_up:
            self.sent.append(packet)
        return self.is_up


def test_the_consoles_own_modem_port_going_down_is_said_at_once_and_its_return_too():
    import asyncio

    port = ModemPort()
    session = AcousticSession(port, KEY)

    async def scenario():
        pump = asyncio.create_task(session._pump())
        await asyncio.sleep(0.3)
        assert session.state()["link"]["port"] == "up"
        port.is_up, port.stats.last_error = False, "no serial port /dev/ttyUSB0 (is the modem's USB serial adapter plugged in?)"
        await asyncio.sleep(0.3)
        down = session.state()
        port.is_up = True
        await asyncio.sleep(0.3)
        pump.cancel()
        return down

    down = asyncio.run(scenario())
    assert down["link"]["port"] == "down" and "no serial port /dev/ttyUSB0" in down["link"]["port_error"]
    texts = [(entry["level"], entry["text"]) for entry in session.state()["log"]]
    assert ("alert", "MODEM PORT DOWN: no serial port /dev/ttyUSB0 (is the modem's USB serial adapter plugged in?);"
                     " opening it again") in texts
    assert ("info", "modem port open again") in texts
    assert session.state()["link"]["port"] == "up" and session.state()["link"]["port_error"] is None
    assert port.sent  # the HELLOs went out while the port was up
