"""The web API: schema, state, orders, control ownership, errors, WebSocket.

Most tests use an Operator with no link (its commands still reach the link
master, and its state is real) through FastAPI's TestClient; the `live`
tests talk over real sockets to the whole system served by uvicorn.
"""

from __future__ import annotations

import asyncio
import io
import json
import math
import socket
import time

import httpx
import numpy as np
import pytest
from PIL import Image
from starlette.websockets import WebSocketDisconnect

from rovlink import debt
from rovlink.console.session.radio import Operator
from rovlink.console.web.app import create_app, serve

from ..helpers import local_test_client
from .conftest import wait_for

# The app refuses any Host but its own names (DNS rebinding).
TestClient = local_test_client

HEADER = "X-Rovlink-Client"


@pytest.fixture
def operator():
    op = Operator(None)
    yield op
    op.close()


@pytest.fixture
def client(operator):
    with TestClient(create_app(operator)) as c:
        yield c


def take(client, name: str = "test") -> dict:
    r = client.post("/api/control/take", json={"name": name})
    assert r.status_code == 200, r.text
    return {HEADER: r.json()["client_id"]}


def wish(operator) -> tuple:
    v = operator.state()["velocity_wish"]
    return v["vx"], v["vy"], v["vz"], v["vyaw"]


# ----------------------------------------------------------------------
# Schema, page, state
# ----------------------------------------------------------------------


def test_openapi_schema_documents_every_endpoint_and_body(client):
    schema = client.get("/openapi.json").json()
    assert set(schema["paths"]) >= {
        "/api/state", "/api/pose", "/api/orders", "/api/config", "/api/link", "/api/image", "/api/image/latest.png",
        "/api/image/latest.debt", "/api/image/settings", "/api/image/next", "/api/orders/velocity",
        "/api/orders/position", "/api/orders/stop", "/api/orders/arm", "/api/orders/mode", "/api/control",
        "/api/control/take", "/api/control/release"}
    models = schema["components"]["schemas"]
    assert {"VelocityOrder", "PositionOrder", "ArmOrder", "ModeOrder", "ImageSettingsOrder", "State", "LinkState",
            "ImageState", "ControlStatus", "ErrorBody"} <= set(models)
    velocity = schema["paths"]["/api/orders/velocity"]["post"]
    assert {"409", "422"} <= set(velocity["responses"])
    assert any(p["name"].lower() == "x-rovlink-client" for p in velocity["parameters"])
    assert models["VelocityOrder"]["properties"]["vx"]["maximum"] == 1.0


def test_page_embeds_scene_url_and_documents_the_keys(operator):
    with TestClient(create_app(operator, viser_url="http://127.0.0.1:8080")) as c:
        page = c.get("/")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        for text in ("STOP", "Link health", "/static/console.js", 'id="keymap"'):
            assert text in page.text
        # The key map the page shows is the console's one (from /api/config).
        assert set(c.get("/api/config").json()["keys"]) == set("WASDQERF")
        assert c.get("/static/console.js").status_code == 200
        assert c.get("/static/console.css").status_code == 200
        assert c.get("/api/config").json()["viser_url"] == "http://127.0.0.1:8080"


def test_state_holds_pose_link_image_wish_orders_log_and_control(client):
    state = client.get("/api/state").json()
    assert set(state) == {"pose", "image", "link", "velocity_wish", "orders", "world", "log", "replaying", "wall", "control",
                          "target"}
    assert state["control"] == {"held": False, "holder": None, "holder_kind": None, "held_for_s": None,
                                "you": False, "lease_s": 30.0, "unattended_s": None, "unattended_warning": False,
                                "disarm_unattended_s": None, "centre_to_drive": False}
    assert state["pose"]["received"] is None  # no link, no odometry
    assert client.get("/api/link").json()["sent"] == 0
    assert client.get("/api/image").json()["received_bytes"] == 0


def test_estimates_that_are_not_finite_are_sent_as_null(client, operator, monkeypatch):
    monkeypatch.setattr(operator.master, "estimated_ber", lambda: math.inf)
    assert client.get("/api/link").json()["radio"]["estimated_ber"] is None
    assert client.get("/api/state").json()["link"]["radio"]["estimated_ber"] is None
    with client.websocket_connect("/ws") as ws:
        # Browsers' JSON.parse refuses NaN and Infinity, so a strict parser here too.
        ws.receive_json()
        text = ws.receive_text()
        telemetry = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in telemetry"))
        assert telemetry["link"]["radio"]["estimated_ber"] is None


def test_no_picture_yet_is_404_with_a_message(client):
    for path in ("/api/image/latest.png", "/api/image/latest.debt"):
        r = client.get(path)
        assert r.status_code == 404
        assert "no image" in r.json()["message"]


def test_a_kept_picture_that_cannot_be_decoded_is_422_saying_why(client, operator):
    # A picture kept from an ROV of an older rovlink (DEBT format 1).
    data = debt.encode(np.full((24, 32), 90, dtype=np.uint8), 200)
    with operator._lock:
        operator.images._history.append({"n": 7, "img": 1, "capture": None, "bytes": len(data),
                                        "total_bytes": len(data), "partial": False, "received_wall": 0.0,
                                        "seconds": 1.0, "settings": None,
                                        "stream": bytes([0xB0 | (data[0] & 0x0F)]) + data[1:]})
    for path in ("/api/images/7.png", "/api/images/7.json"):
        r = client.get(path)
        assert r.status_code == 422
        assert "cannot be decoded" in r.json()["message"] and "format 1" in r.json()["message"]
    assert client.get("/api/images").json()[0]["n"] == 7     # still listed


# ----------------------------------------------------------------------
# Control ownership
# ----------------------------------------------------------------------

ORDERS = [
    ("/api/orders/velocity", {"vx": 0.5}),
    ("/api/orders/position", {"x_m": 1, "y_m": 2, "z_m": 3}),
    ("/api/orders/arm", {"armed": True}),
    ("/api/orders/mode", {"mode": "DEPTH_HOLD"}),
    ("/api/image/settings", {"mono": True}),
    ("/api/image/next", None),
]


@pytest.mark.parametrize("path,body", ORDERS)
def test_orders_without_control_get_409_saying_how_to_take_it(client, path, body):
    r = client.post(path, json=body)
    assert r.status_code == 409
    assert "POST /api/control/take" in r.json()["message"]


@pytest.mark.parametrize("path,body", ORDERS)
def test_the_holder_orders(client, operator, path, body):
    r = client.post(path, json=body, headers=take(client))
    assert r.status_code in (200, 204), r.text


def test_take_over_is_explicit_and_the_old_holder_gets_409(client, operator):
    pilot = take(client, "pilot")
    assert client.post("/api/orders/velocity", json={"vx": 0.4, "vyaw": -0.2}, headers=pilot).status_code == 200
    assert wish(operator) == (0.4, 0.0, 0.0, -0.2)
    watcher = take(client, "watcher")
    # Taking over never inherits the previous pilot's motion.
    assert wish(operator) == (0.0, 0.0, 0.0, 0.0)
    r = client.post("/api/orders/velocity", json={"vx": 0.4}, headers=pilot)
    assert r.status_code == 409 and "held by watcher" in r.json()["message"]
    assert client.get("/api/control", headers=pilot).json()["you"] is False
    status = client.get("/api/control", headers=watcher).json()
    assert status["you"] is True and status["holder"] == "watcher" and status["holder_kind"] == "script"


def test_release_sets_velocity_neutral_and_only_the_holder_may(client, operator):
    pilot = take(client, "pilot")
    client.post("/api/orders/velocity", json={"vz": 0.3}, headers=pilot)
    other = {HEADER: client.post("/api/control/take").json()["client_id"]}
    take_back = client.post("/api/control/take", headers=pilot)
    assert take_back.json()["client_id"] == pilot[HEADER]
    assert client.post("/api/control/release", headers=other).status_code == 409
    client.post("/api/orders/velocity", json={"vz": 0.3}, headers=pilot)
    r = client.post("/api/control/release", headers=pilot)
    assert r.status_code == 200 and r.json()["held"] is False
    assert wish(operator) == (0.0, 0.0, 0.0, 0.0)
    assert any("control released by pilot" in e["text"] for e in client.get("/api/state").json()["log"])


def test_stop_is_accepted_from_anyone_and_stops_the_pilot(client, operator):
    pilot = take(client)
    client.post("/api/orders/velocity", json={"vx": 1.0}, headers=pilot)
    r = client.post("/api/orders/stop")
    assert r.status_code == 200 and r.json()["kind"] == "STOP"
    assert wish(operator) == (0.0, 0.0, 0.0, 0.0)
    assert client.get("/api/orders").json()[-1]["kind"] == "STOP"
    assert client.get("/api/control", headers=pilot).json()["you"] is True  # STOP does not take control


def test_image_settings_left_out_keep_their_value(client, operator):
    holder = take(client)
    assert client.post("/api/image/settings", json={"roi": [10, 20, 110, 90], "shift": 6},
                       headers=holder).status_code == 200
    assert client.post("/api/image/settings", json={"mono": True}, headers=holder).status_code == 200
    assert client.get("/api/orders").json()[-1] | {"id": 0, "t_queued": 0, "version": 0} == {
        "id": 0, "t_queued": 0, "version": 0, "kind": "IMAGE", "state": "queued", "reason": "", "text": "queued",
        "outcome": "pending", "roi": [10, 20, 110, 90], "shift": 6,
        "mono": True, "budget_bytes": operator.requested_settings.budget_bytes}
    client.post("/api/image/settings", json={"roi": None}, headers=holder)
    assert operator.requested_settings.roi is None and operator.requested_settings.shift == 6


def test_a_replay_takes_no_orders(client, operator):
    holder = take(client)
    operator.replaying = True
    for path, body in [*ORDERS, ("/api/orders/stop", None), ("/api/control/take", None)]:
        r = client.post(path, json=body, headers=holder)
        assert r.status_code == 409 and "replays a recording" in r.json()["message"], path
    assert operator.orders_state() == []
    assert client.get("/api/state").json()["replaying"] is True


def test_unknown_client_id_is_422(client):
    r = client.post("/api/control/take", headers={HEADER: "not-a-client"})
    assert r.status_code == 422
    assert "unknown client id" in r.json()["message"]


def test_a_silent_script_loses_control_and_its_velocity(operator):
    with TestClient(create_app(operator, lease_s=0.3)) as c:
        script = take(c, "script")
        c.post("/api/orders/velocity", json={"vx": 0.7}, headers=script)
        assert wish(operator) == (0.7, 0.0, 0.0, 0.0)
        assert wait_for(lambda: not c.get("/api/control").json()["held"], 5.0)
        assert wish(operator) == (0.0, 0.0, 0.0, 0.0)
        assert any("silent" in e["text"] for e in c.get("/api/state").json()["log"])


def test_other_sites_pages_cannot_order_through_the_pilots_browser(client, operator):
    evil = {"Origin": "http://evil.example", "Host": "127.0.0.1"}
    r = client.post("/api/control/take", headers=evil)
    assert r.status_code == 403 and "cross-site request from http://evil.example refused" in r.json()["message"]
    assert client.post("/api/orders/stop", headers=evil).status_code == 403
    assert client.get("/api/control").json()["held"] is False and operator.orders_state() == []
    # Our own page (same origin) and scripts (no Origin) are welcome.
    assert client.post("/api/control/take", headers={"Origin": "http://127.0.0.1"}).status_code == 200
    with pytest.raises(WebSocketDisconnect) as refused, \
            client.websocket_connect("/ws", headers={"Origin": "http://evil.example"}) as ws:
        ws.receive_json()
    assert refused.value.code == 1008
    with client.websocket_connect("/ws", headers={"Origin": "http://127.0.0.1"}) as ws:
        assert ws.receive_json()["type"] == "hello"


# ----------------------------------------------------------------------
# Bad requests
# ----------------------------------------------------------------------


@pytest.mark.parametrize("path,body,says", [
    ("/api/orders/velocity", {"vx": 1.5}, "body.vx: Input should be less than or equal to 1"),
    ("/api/orders/velocity", {"vy": -2}, "body.vy: Input should be greater than or equal to -1"),
    ("/api/orders/velocity", {"vx": "0.5"}, "body.vx: Input should be a valid number"),
    ("/api/orders/velocity", {"vx": True}, "body.vx: Input should be a valid number"),
    ("/api/orders/velocity", {"forward": 0.5}, "body.forward: Extra inputs are not permitted"),
    ("/api/orders/velocity", [0.1, 0, 0, 0], "body"),
    ("/api/orders/position", {"x_m": 1, "y_m": 2}, "body.z_m: Field required"),
    ("/api/orders/position", {"x_m": 400, "y_m": 0, "z_m": 1}, "body.x_m: Input should be less than or equal to 327.67"),
    ("/api/orders/position", {"x_m": 1e300, "y_m": 0, "z_m": 1}, "body.x_m: Input should be less than or equal to 327.67"),
    ("/api/orders/position", {"x_m": 0, "y_m": 0, "z_m": -5}, "z_m must be 0 or more"),
    ("/api/orders/position", {"x_m": 0, "y_m": 0, "z_m": 1, "yaw_deg": 400}, "yaw_deg: Input should be less than or equal to 360"),
    ("/api/orders/position", {"x_m": 1, "y_m": 0, "z_m": 1, "body": True}, "BODY is only allowed with RELATIVE"),
    ("/api/orders/arm", {"armed": "yes"}, "body.armed: Input should be a valid boolean"),
    ("/api/orders/arm", {}, "body.armed: Field required"),
    ("/api/orders/mode", {"mode": "ACRO"}, "body.mode: Input should be 'MANUAL'"),
    ("/api/image/settings", {"roi": [100, 100, 10, 10]}, "IMAGE ROI needs X0 < X1 and Y0 < Y1"),
    ("/api/image/settings", {"roi": [1, 2, 3]}, "body.roi.3: Field required"),
    ("/api/image/settings", {"budget_bytes": 100000}, "IMAGE BUDGET must be in 0..8189, got 100000"),  # the link's limit
    ("/api/image/settings", {"shift": -1}, "body.shift: Input should be greater than or equal to 0"),
])
def test_invalid_orders_get_422_saying_what_is_wrong(client, operator, path, body, says):
    before = (wish(operator), len(client.get("/api/orders").json()))
    r = client.post(path, json=body, headers=take(client))
    assert r.status_code == 422, r.text
    assert says in r.json()["message"]
    assert (wish(operator), len(client.get("/api/orders").json())) == before  # nothing was sent


def test_not_a_number_and_broken_json_are_422(client):
    holder = take(client)
    r = client.post("/api/orders/velocity", content=b'{"vx": NaN}',
                    headers={**holder, "Content-Type": "application/json"})
    assert r.status_code == 422 and "finite number" in r.json()["message"]
    r = client.post("/api/orders/velocity", content=b'{"vx": 0.5', headers={**holder, "Content-Type": "application/json"})
    assert r.status_code == 422 and "JSON" in r.json()["message"]


# ----------------------------------------------------------------------
# WebSocket (in process)
# ----------------------------------------------------------------------


def next_of(ws, kind: str, limit: int = 50) -> dict:
    for _ in range(limit):
        message = ws.receive_json()
        if message["type"] == kind:
            return message
    raise AssertionError(f"no {kind!r} message in {limit}")


def test_websocket_says_hello_then_streams_telemetry(client):
    with client.websocket_connect("/ws") as ws:
        hello = ws.receive_json()
        assert hello["type"] == "hello" and len(hello["client_id"]) >= 16
        assert hello["config"]["telemetry_hz"] == 10.0
        first, second = next_of(ws, "telemetry"), next_of(ws, "telemetry")
        for message in (first, second):
            assert {"pose", "link", "image", "velocity_wish", "orders", "log", "control"} <= set(message)
            assert message["control"]["you"] is False
        assert second["link"]["t"] > first["link"]["t"]


def test_websocket_reads_on_while_an_order_waits_on_the_link_and_carries_out_the_newest_wish(client, operator,
                                                                                            monkeypatch):
    """A page's message waits on the link process at most 2 s (a busy machine): the socket
    goes on being read and written meanwhile (its keepalive pong is never stuck behind an
    order, which closed pages' sockets, and took their control), wishes that queue up
    meanwhile are carried out newest first, and a STOP drops the wishes before it."""
    import threading

    gate, entered = threading.Event(), threading.Event()
    carried: list[tuple] = []
    real = operator.set_velocity

    def slow_set_velocity(*values):
        if values != (0.0, 0.0, 0.0, 0.0) and not gate.is_set():
            entered.set()
            gate.wait(10)  # the link process is slow to answer this one
        carried.append(values)
        real(*values)

    monkeypatch.setattr(operator, "set_velocity", slow_set_velocity)
    with client.websocket_connect("/ws?name=pilot page") as ws:
        me = {HEADER: ws.receive_json()["client_id"]}
        assert client.post("/api/control/take", headers=me).status_code == 200
        ws.send_json({"type": "velocity"})  # neutral first: the page re-centred
        ws.send_json({"type": "velocity", "vx": 0.1})
        assert entered.wait(5)
        for vx in (0.2, 0.3, 0.4):  # waiting behind the slow one: only the newest counts
            ws.send_json({"type": "velocity", "vx": vx})
        # Telemetry keeps coming while the order waits: the loop is not held.
        first = next_of(ws, "telemetry")["link"]["t"]
        assert next_of(ws, "telemetry")["link"]["t"] > first
        gate.set()
        assert wait_for(lambda: wish(operator) == (0.4, 0.0, 0.0, 0.0), 5.0), carried
        assert (0.2, 0.0, 0.0, 0.0) not in carried and (0.3, 0.0, 0.0, 0.0) not in carried, carried
        # A STOP: what waited before it is not carried out after it.
        gate.clear()
        entered.clear()
        ws.send_json({"type": "velocity", "vx": 0.5})
        assert entered.wait(5)
        ws.send_json({"type": "velocity", "vx": 0.6})
        ws.send_json({"type": "stop"})
        gate.set()
        # (Nothing in the list until the STOP's turn in the worker comes, after the slow wish.)
        assert wait_for(lambda: [o["kind"] for o in client.get("/api/orders").json()][-1:] == ["STOP"], 5.0)
        assert wait_for(lambda: wish(operator) == (0.0, 0.0, 0.0, 0.0), 5.0)
        assert (0.6, 0.0, 0.0, 0.0) not in carried, carried


def test_websocket_velocity_only_from_the_holder_and_released_on_disconnect(client, operator):
    with client.websocket_connect("/ws?name=pilot page") as ws:
        me = {HEADER: ws.receive_json()["client_id"]}
        ws.send_json({"type": "velocity", "vx": 0.5})
        assert "nobody holds control" in next_of(ws, "error")["message"]
        assert wish(operator) == (0.0, 0.0, 0.0, 0.0)

        r = client.post("/api/control/take", headers=me)
        assert r.status_code == 200 and r.json()["control"]["holder_kind"] == "browser"
        assert next_of(ws, "control")["control"]["you"] is True
        ws.send_json({"type": "velocity"})  # the page's input right after taking: neutral
        ws.send_json({"type": "velocity", "vx": 0.5, "vyaw": -0.25})
        assert wait_for(lambda: wish(operator) == (0.5, 0.0, 0.0, -0.25), 2.0)
        # REST orders with the page's id work too.
        assert client.post("/api/orders/mode", json={"mode": "MANUAL"}, headers=me).status_code == 200
    assert wait_for(lambda: not client.get("/api/control").json()["held"], 2.0)
    assert wish(operator) == (0.0, 0.0, 0.0, 0.0)
    # The log says how the page left (here its socket closed normally), so that a page
    # dropped by a failed connection is told apart from one closed by its pilot.
    assert any("pilot page left (closed by the page, code 1000" in e["text"]
               for e in client.get("/api/state").json()["log"]), client.get("/api/state").json()["log"]


def test_websocket_velocity_falls_back_to_neutral_when_its_repeats_stop(operator):
    with TestClient(create_app(operator, velocity_deadman_s=0.3)) as c, c.websocket_connect("/ws") as ws:
        me = {HEADER: ws.receive_json()["client_id"]}
        c.post("/api/control/take", headers=me)
        ws.send_json({"type": "velocity"})  # the page's input right after taking: neutral
        ws.send_json({"type": "velocity", "vz": -0.8})
        assert wait_for(lambda: wish(operator) == (0.0, 0.0, -0.8, 0.0), 2.0)
        # No repeat: the dead man sets neutral, control stays.
        assert wait_for(lambda: wish(operator) == (0.0, 0.0, 0.0, 0.0), 3.0)
        assert c.get("/api/control", headers=me).json()["you"] is True
        assert any("stopped arriving" in e["text"] for e in c.get("/api/state").json()["log"])


def test_websocket_refuses_bad_messages_with_a_reason(client, operator):
    with client.websocket_connect("/ws") as ws:
        client.post("/api/control/take", headers={HEADER: ws.receive_json()["client_id"]})
        ws.send_text("not json")
        assert "JSON" in next_of(ws, "error")["message"]
        ws.send_bytes(b"\x00\x01")
        assert "binary messages" in next_of(ws, "error")["message"]
        ws.send_json({"type": "dance"})
        assert "unknown message type 'dance'" in next_of(ws, "error")["message"]
        ws.send_json({"type": "velocity", "vx": 3})
        assert "vx: Input should be less than or equal to 1" in next_of(ws, "error")["message"]
        ws.send_json({"type": "stop"})
        assert wait_for(lambda: any(o["kind"] == "STOP" for o in operator.orders_state()), 2.0)


def test_a_taken_over_page_is_told_at_once(client, operator):
    with client.websocket_connect("/ws") as pilot_ws:
        client.post("/api/control/take", headers={HEADER: pilot_ws.receive_json()["client_id"]})
        assert next_of(pilot_ws, "control")["control"]["you"] is True
        take(client, "co-pilot")
        # Within the next few control messages: one made before the take (a centring
        # told after the page's own take) may come first, never more than a few.
        for _ in range(5):
            told = next_of(pilot_ws, "control")["control"]
            if told["you"] is not True:
                break
        assert told["you"] is False and told["holder"] == "co-pilot", told


# ----------------------------------------------------------------------
# serve()
# ----------------------------------------------------------------------


def test_serve_reports_a_port_in_use_as_oserror(operator):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        with pytest.raises(OSError):
            asyncio.run(serve(create_app(operator), "127.0.0.1", port))


def test_serve_answers_on_loopback_only_and_stops_when_cancelled(operator):
    async def main() -> int:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        task = asyncio.create_task(serve(create_app(operator), port=port))  # default host
        async with httpx.AsyncClient() as http:
            for _ in range(100):
                try:
                    status = (await http.get(f"http://127.0.0.1:{port}/api/link")).status_code
                    break
                except httpx.ConnectError:
                    await asyncio.sleep(0.05)
            # Bound to 127.0.0.1, not to every address: another one (still
            # loopback on Linux, so the test leaves this machine alone) is refused.
            with pytest.raises(httpx.ConnectError):
                await http.get(f"http://127.0.0.2:{port}/api/link")
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        with socket.socket() as again:  # the port is free again
            again.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            again.bind(("127.0.0.1", port))
        return status

    assert asyncio.run(main()) == 200


# ----------------------------------------------------------------------
# The whole system, over real sockets
# ----------------------------------------------------------------------


def test_live_image_as_png_and_as_debt(live):
    with httpx.Client(base_url=live.url) as http:
        # The first picture waits for the codec's JIT compilation, slow on a busy machine.
        assert wait_for(lambda: http.get("/api/image").json()["decoded_bytes"] > 0, 90), "no picture decoded"
        png = http.get("/api/image/latest.png")
        assert png.status_code == 200 and png.headers["content-type"] == "image/png"
        picture = np.asarray(Image.open(io.BytesIO(png.content)))
        assert picture.size > 0 and picture.std() > 0  # a scene, not a blank
        raw = http.get("/api/image/latest.debt")
        assert raw.status_code == 200 and raw.headers["content-type"] == "application/octet-stream"
        assert int(raw.headers["X-Rovlink-Decoded-Bytes"]) == len(raw.content)
        decoded = debt.decode(raw.content)
        assert decoded.shape == picture.shape


def test_live_orders_reach_the_rov(live):
    with httpx.Client(base_url=live.url) as http:
        me = {HEADER: http.post("/api/control/take", json={"name": "api test"}).json()["client_id"]}
        assert http.post("/api/orders/arm", json={"armed": True}, headers=me).status_code == 200
        assert wait_for(lambda: http.get("/api/pose").json()["armed"], 10), "never armed"
        start = http.get("/api/pose").json()["received"]
        assert http.post("/api/orders/velocity", json={"vx": 0.8}, headers=me).status_code == 200
        assert wait_for(lambda: http.get("/api/pose").json()["received"]["x_m"] > start["x_m"] + 0.3, 10)
        stop = http.post("/api/orders/stop", headers=me).json()
        assert wait_for(lambda: next(o for o in http.get("/api/orders").json() if o["id"] == stop["id"])["state"]
                        == "acknowledged", 10)
        http.post("/api/orders/arm", json={"armed": False}, headers=me)
        assert wait_for(lambda: not http.get("/api/pose").json()["armed"], 10)
        http.post("/api/control/release", headers=me)


def test_live_websocket_streams_link_health_and_pictures(live):
    from websockets.sync.client import connect

    with connect(live.ws_url, open_timeout=10) as ws:
        hello = json.loads(ws.recv(timeout=5))
        assert hello["type"] == "hello"
        telemetry, images = [], []
        deadline = time.monotonic() + 20
        while (len(telemetry) < 5 or not images) and time.monotonic() < deadline:
            message = json.loads(ws.recv(timeout=5))
            if message["type"] == "telemetry":
                telemetry.append(message)
            elif message["type"] == "image":
                images.append(message["image"])
        assert len(telemetry) >= 5 and images, "telemetry or image events missing"
        first, last = telemetry[0]["link"], telemetry[-1]["link"]
        assert last["sent"] > first["sent"] and last["link_up"]
        assert math.isfinite(last["poll_rate_hz"]) and last["poll_rate_hz"] > 0
        assert telemetry[-1]["pose"]["received"] is not None and telemetry[-1]["pose"]["predicted"] is not None
        assert images[-1]["decoded_bytes"] > 0

        with httpx.Client(base_url=live.url) as http:
            http.post("/api/control/take", headers={HEADER: hello["client_id"]})
            assert http.get("/api/control").json()["holder_kind"] == "browser"
    # Leaving released control.
    with httpx.Client(base_url=live.url) as http:
        assert wait_for(lambda: not http.get("/api/control").json()["held"], 5)


def test_live_a_page_whose_connection_fails_is_given_control_back_when_it_reconnects(live):
    """A page's socket dropped without a closing handshake (a network that fails, a
    keepalive that times out) releases control, then gives it back to the same page
    (its key) reconnecting; a page that closes its socket itself gets nothing back."""
    from websockets.sync.client import connect

    key = "p" * 32
    url = f"{live.ws_url}?name=pilot%20page&scene_key={key}"
    with httpx.Client(base_url=live.url) as http:
        ws = connect(url, open_timeout=10)
        hello = json.loads(ws.recv(timeout=5))
        assert http.post("/api/control/take", headers={HEADER: hello["client_id"]}).status_code == 200
        ws.socket.shutdown(socket.SHUT_RDWR)  # gone, no close frame
        ws.socket.close()
        assert wait_for(lambda: not http.get("/api/control").json()["held"], 5), "control outlived its socket"
        with connect(url, open_timeout=10) as again:
            assert json.loads(again.recv(timeout=5))["type"] == "hello"
            assert wait_for(lambda: http.get("/api/control").json()["holder"] == "pilot page", 5)
            texts = [e["text"] for e in http.get("/api/log").json()]
            assert any("given back if the page reconnects within" in t for t in texts), texts[-5:]
            assert "control given back to pilot page: its page reconnected" in texts, texts[-5:]
        # Closed by the page (1000): released, and not given back.
        assert wait_for(lambda: not http.get("/api/control").json()["held"], 5)
        with connect(url, open_timeout=10) as third:
            hello = json.loads(third.recv(timeout=5))
            time.sleep(0.3)
            assert not http.get("/api/control", headers={HEADER: hello["client_id"]}).json()["held"]


def test_live_a_value_json_cannot_write_never_cuts_a_page_off(live):
    """An event carrying NumPy numbers (a session part's slip) reaches the page as plain
    numbers; its socket stays open and telemetry goes on."""
    from websockets.sync.client import connect

    with connect(live.ws_url, open_timeout=10) as ws:
        assert json.loads(ws.recv(timeout=5))["type"] == "hello"
        live.operator.publish("target", {"x_m": np.float32(1.5), "points": np.arange(3), "n": np.int64(7)})
        target, telemetry_after = None, 0
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (target and telemetry_after >= 3):
            message = json.loads(ws.recv(timeout=5))
            if message["type"] == "target" and message["target"] and "n" in message["target"]:
                target = message["target"]
            elif message["type"] == "telemetry" and target:
                telemetry_after += 1
        assert target == {"x_m": 1.5, "points": [0, 1, 2], "n": 7}, target
        assert telemetry_after >= 3
