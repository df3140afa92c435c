"""The acoustic session behind the radio console's own web app (issue 32: one
cockpit, one API, one control desk for both links).  Bad requests are turned
away with a clear answer (422, the field named); orders the link cannot take,
or not yet, with 409 and the reason (sticks, "next picture", before the ROV's
first status); an order from a client that does not hold control with 409;
STOP from anyone, at any time; a POST from another site's page with 403.  No
bad request ever queues an order or stops the app."""

from __future__ import annotations

import pytest

from rovlink.console.session.acoustic import AcousticSession
from rovlink.console.session.contract import VehicleSession
from rovlink.console.web.app import create_app

from ..helpers import local_test_client

KEY = bytes(range(32))
CLIENT = "X-Rovlink-Client"


@pytest.fixture
def api():
    session = AcousticSession(None, KEY)  # no link: the session as the web app sees it before any STATUS
    with local_test_client(create_app(session)) as client:
        holder = client.post("/api/control/take", json={"name": "pilot"}).json()["client_id"]
        yield client, session, {CLIENT: holder}
    session.close()


def test_it_is_a_session_of_the_one_contract_and_says_what_its_link_carries(api):
    client, session, _ = api
    assert isinstance(session, VehicleSession)
    caps = client.get("/api/config").json()["capabilities"]
    assert caps["profile"] == "acoustic" and caps["velocity"] is False and caps["picture"] == "thumbnail"
    assert caps["follow"] is True and caps["next_image"] is False  # FOLLOW rides in THUMB (§9.3)
    assert client.get("/api/config").json()["limits"]["budget_bytes"][1] == 439  # what a thumbnail request carries
    link = client.get("/api/link").json()
    assert link["profile"] == "acoustic" and link["version"] == "acoustic" and link["lost_after_s"] == 20.0
    pose = client.get("/api/pose").json()
    assert pose["received"] is None and pose["predicted"] is None  # nothing made up before a status


@pytest.mark.parametrize("path, body, status, words", [
    ("/api/orders/position", {"x_m": "north", "y_m": 0, "z_m": 1}, 422, "x_m"),
    ("/api/orders/position", {"y_m": 0, "z_m": 1}, 422, "x_m"),
    ("/api/orders/position", {"x_m": 1e9, "y_m": 0, "z_m": 1}, 422, "x_m"),
    ("/api/orders/mode", {"mode": "WARP"}, 422, "mode"),
    ("/api/orders/arm", {}, 422, "armed"),
    ("/api/image/settings", {"budget_bytes": 5}, 422, "budget"),
    ("/api/image/settings", {"budget_bytes": 2000}, 422, "439"),
    ("/api/image/settings", {"roi": [10, 10, 5, 5]}, 422, "roi"),
    ("/api/image/settings", {"roi": [0, 0, 300, 40]}, 422, "80x60"),
    ("/api/image/settings", {"shift": 99}, 422, "shift"),
    # Well formed, but not what this link carries: a conflict with the link, said so.
    ("/api/orders/velocity", {"vx": 0.5}, 409, "no sticks"),
    ("/api/image/next", None, 409, "on request"),
    ("/api/image/follow", {"roi": [10, 10, 90, 30], "img": 3, "keep": True}, 422, "80x60"),
    ("/api/image/follow", {"roi": [10, 10, 40, 30], "img": 256, "keep": True}, 422, "img"),
    ("/api/image/follow", {"img": 3}, 422, "roi"),
])
def test_a_bad_request_is_refused_with_its_reason_and_queues_nothing(api, path, body, status, words):
    client, session, holder = api
    r = client.post(path, json=body, headers=holder)
    assert r.status_code == status, (r.status_code, r.text)
    assert words in r.json()["message"], r.text
    assert session.op.orders_waiting == 0 and session.orders_state() == []


def test_a_good_order_before_any_status_is_refused_with_the_reason(api):
    client, session, holder = api
    r = client.post("/api/orders/position", json={"x_m": 1.0, "y_m": 2.0, "z_m": 3.0}, headers=holder)
    assert r.status_code == 409 and "no STATUS" in r.json()["message"], r.text
    assert client.post("/api/orders/arm", json={"armed": True}, headers=holder).status_code == 409
    assert session.op.orders_waiting == 0 and session.orders_state() == []


def test_only_the_holder_orders_and_stop_is_anyones_at_any_time(api):
    client, session, holder = api
    other = client.post("/api/control/take", json={"name": "watcher"})  # taking is always allowed ...
    assert other.status_code == 200
    # ... and the first page, no longer the holder, is refused.
    r = client.post("/api/orders/arm", json={"armed": True}, headers=holder)
    assert r.status_code == 409 and "held by watcher" in r.json()["message"], r.text
    r = client.post("/api/orders/stop", headers=holder)  # STOP from anyone
    assert r.status_code == 200, r.text
    stops = [o for o in client.get("/api/orders").json() if o["kind"] == "STOP"]
    assert stops and stops[-1]["state"] == "sent"  # pressed, not yet confirmed by the ROV
    assert session.stopping()
    assert client.get("/api/image/latest.png").status_code == 404  # no thumbnail yet
    assert "first status" in client.get("/api/image").json()["waiting"]


def test_a_post_from_another_sites_page_is_refused(api):
    """Any page the pilot has open could otherwise send a go-to, or STOP, through
    the pilot's browser to the console on this machine."""
    client, session, holder = api
    evil = {"Origin": "http://evil.example", **holder}
    for path, body in (("/api/orders/position", {"x_m": 1, "y_m": 0, "z_m": 1}), ("/api/orders/stop", None),
                       ("/api/orders/arm", {"armed": True}), ("/api/image/settings", {})):
        r = client.post(path, json=body, headers=evil)
        assert r.status_code == 403 and "cross-site" in r.json()["message"], (path, r.text)
    assert not session.stopping() and session.op.orders_waiting == 0
    assert client.post("/api/orders/stop", headers={"Origin": "http://127.0.0.1"}).status_code == 200  # its own page


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
        pump = asyncio.create_task(session.pump().pumping())
        await asyncio.sleep(0.3)
        assert session.link_state()["port_error"] is None
        port.is_up, port.stats.last_error = False, "no serial port /dev/ttyUSB0 (is the modem's USB serial adapter plugged in?)"
        await asyncio.sleep(0.3)
        down = session.link_state()
        port.is_up = True
        await asyncio.sleep(0.3)
        pump.cancel()
        return down

    down = asyncio.run(scenario())
    assert "no serial port /dev/ttyUSB0" in down["port_error"]
    lines = session.log_entries()
    texts = [(entry["level"], entry["text"]) for entry in lines]
    assert ("alert", "MODEM PORT DOWN: no serial port /dev/ttyUSB0 (is the modem's USB serial adapter plugged in?);"
                     " opening it again") in texts
    assert ("info", "modem port open again") in texts
    # The alert is marked cleared once the port is back, as on the radio console.
    assert [e for e in lines if e["text"].startswith("MODEM PORT DOWN")][0]["cleared_wall"] is not None
    assert session.link_state()["port_error"] is None
    assert port.sent  # the HELLOs went out while the port was up
    session.close()
