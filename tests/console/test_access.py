"""Who may talk to the console: Host names (DNS rebinding), the access token
off loopback, WebSocket origins, on the app's port and the 3D scene's port.

Servers bind to 127.0.0.1 only; the token, which the console asks for when
bound to any other address, is switched on here by giving the policy one."""

from __future__ import annotations

import asyncio
import socket
import threading
import urllib.request

import pytest
import websockets

from rovlink.console.session.radio import Operator
from rovlink.console.web.app import create_app, serve
from rovlink.console.web.guard import TOKEN_COOKIE, AccessPolicy, guard_viser, host_name

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium


def _get(port: int, path: str = "/", headers: dict | None = None) -> tuple[int, dict, bytes]:
    """A GET with exactly these headers (Host included), over a raw socket."""
    head = f"GET {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall((head + "Connection: close\r\n\r\n").encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    status_line, _, rest = data.partition(b"\r\n")
    header_block, _, body = rest.partition(b"\r\n\r\n")
    fields = {}
    for line in header_block.decode("latin-1").split("\r\n"):
        name, _, value = line.partition(":")
        fields.setdefault(name.strip().lower(), value.strip())
    return int(status_line.split()[1]), fields, body


# ----------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------


@pytest.mark.parametrize("header,name", [("127.0.0.1:8000", "127.0.0.1"), ("[::1]:80", "::1"),
                                         ("LocalHost", "localhost"), ("evil.example", "evil.example"),
                                         ("", None), (None, None), ("a:b:c", None), ("x:99999", None)])
def test_host_names_are_read_from_the_header(header, name):
    assert host_name(header) == name


def test_only_our_names_pass_on_loopback():
    policy = AccessPolicy.for_server("127.0.0.1", ["rov-laptop.lan"])
    assert policy.token is None
    for ok in ("127.0.0.1:8000", "localhost:8080", "[::1]:8000", "rov-laptop.lan:8000", "ROV-LAPTOP.lan"):
        assert policy.host_allowed(ok), ok
    for bad in ("evil.example:8000", "127.0.0.1.evil.example", "", None, "rov-laptop.lan.evil.example"):
        assert not policy.host_allowed(bad), bad
    assert policy.origin_allowed(None) and policy.origin_allowed("http://localhost:8000")
    assert not policy.origin_allowed("http://evil.example") and not policy.origin_allowed("garbage")


def test_any_other_bind_address_asks_for_a_token():
    policy = AccessPolicy.for_server("0.0.0.0")
    assert policy.token and len(policy.token) >= 24
    assert AccessPolicy.for_server("0.0.0.0").token != policy.token  # new each start
    assert AccessPolicy.for_server("192.0.2.7").token
    assert AccessPolicy.for_server("::1").token is None and AccessPolicy.for_server("localhost").token is None
    headers = {"host": "127.0.0.1:8000"}
    assert policy.refusal(headers, "", websocket=False)[0] == 401
    assert policy.refusal(headers, "token=wrong", websocket=False)[0] == 401
    assert policy.refusal(headers, f"token={policy.token}", websocket=False) is None
    assert policy.token_given(f"token={policy.token}", None) == (True, True)
    cookie = {**headers, "cookie": f"other=1; {TOKEN_COOKIE}={policy.token}"}
    assert policy.refusal(cookie, "", websocket=True) is None
    assert policy.refusal({**headers, "cookie": "\x00;;=="}, "", websocket=False)[0] == 401


# ----------------------------------------------------------------------
# Both ports, served for real
# ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def served():
    """The web app and the 3D scene of one console, with a token, on loopback."""
    from rovlink.console.scene.app import ConsoleScene

    policy = AccessPolicy("127.0.0.1", ("rov-laptop.test",), token="t0ken-for-tests")
    guard_viser(policy)
    operator = Operator(None)
    scene = ConsoleScene(operator, port=free_tcp_port()).start()
    app = create_app(operator, viser_url=scene.url, scene=scene, policy=policy)
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    port = sock.getsockname()[1]
    loop = asyncio.new_event_loop()
    task = loop.create_task(serve(app, sock=sock))
    def run() -> None:
        try:
            loop.run_until_complete(task)
        except asyncio.CancelledError:
            pass

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    viser_port = int(scene.url.rstrip("/").rsplit(":", 1)[1])
    try:
        yield {"port": port, "viser_port": viser_port, "policy": policy}
    finally:
        loop.call_soon_threadsafe(task.cancel)
        thread.join(10)
        scene.stop()
        guard_viser(AccessPolicy())


@pytest.mark.parametrize("which", ["port", "viser_port"])
def test_a_foreign_host_name_is_refused_on_every_port(served, which):
    port = served[which]
    status, _, body = _get(port, "/?token=t0ken-for-tests", {"Host": f"evil.example:{port}"})
    assert status == 403 and b"evil.example" in body
    status, _, _ = _get(port, "/?token=t0ken-for-tests", {"Host": f"rov-laptop.test:{port}"})
    assert status == 200  # a name given with --allow-host


@pytest.mark.parametrize("which", ["port", "viser_port"])
def test_the_token_opens_the_page_and_the_cookie_keeps_it_open(served, which):
    port = served[which]
    host = {"Host": f"127.0.0.1:{port}"}
    assert _get(port, "/", host)[0] == 401
    assert _get(port, "/?token=nope", host)[0] == 401
    status, fields, _ = _get(port, "/?token=t0ken-for-tests", host)
    assert status == 200
    cookie = fields["set-cookie"]
    assert cookie.startswith(f"{TOKEN_COOKIE}=t0ken-for-tests") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert _get(port, "/", {**host, "Cookie": f"{TOKEN_COOKIE}=t0ken-for-tests"})[0] == 200


def test_the_api_and_its_websocket_need_the_token(served):
    port = served["port"]
    base = f"http://127.0.0.1:{port}"
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(f"{base}/api/state", timeout=10)
    assert refused.value.code == 401
    req = urllib.request.Request(f"{base}/api/state", headers={"Cookie": f"{TOKEN_COOKIE}=t0ken-for-tests"})
    with urllib.request.urlopen(req, timeout=10) as r:
        assert r.status == 200

    async def connect(headers) -> str:
        async with websockets.connect(f"ws://127.0.0.1:{port}/ws", additional_headers=headers, open_timeout=10) as ws:
            return (await asyncio.wait_for(ws.recv(), 10))[:40]

    assert '"hello"' in asyncio.run(connect({"Cookie": f"{TOKEN_COOKIE}=t0ken-for-tests"}))
    with pytest.raises(websockets.exceptions.InvalidStatus) as refused_ws:
        asyncio.run(connect({}))
    assert refused_ws.value.response.status_code == 403


def test_the_scene_websocket_refuses_other_origins_and_hosts(served):
    port = served["viser_port"]
    cookie = {"Cookie": f"{TOKEN_COOKIE}=t0ken-for-tests"}

    async def connect(url, headers) -> None:
        async with websockets.connect(url, additional_headers=headers, open_timeout=10,
                                      subprotocols=["viser-v1.1.1"]) as ws:
            await asyncio.wait_for(ws.recv(), 10)

    with pytest.raises(websockets.exceptions.InvalidStatus) as other_origin:
        asyncio.run(connect(f"ws://127.0.0.1:{port}/", {**cookie, "Origin": "http://evil.example"}))
    assert other_origin.value.response.status_code == 403
    with pytest.raises(websockets.exceptions.InvalidStatus) as no_token:
        asyncio.run(connect(f"ws://127.0.0.1:{port}/", {"Origin": f"http://127.0.0.1:{port}"}))
    assert no_token.value.response.status_code == 401


@pytest.mark.browser  # one Chromium at a time (tests/conftest.py's browser group)
@needs_chromium
def test_dns_rebinding_in_a_browser_meets_403_on_both_ports(served):
    """A name resolved to this machine (Chromium's host-resolver rule plays the
    attacker's DNS) gets nothing from either port; our own name gets the page."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM,
                                     args=[*CHROMIUM_ARGS, "--host-resolver-rules=MAP attacker.test 127.0.0.1"])
        try:
            page = browser.new_page()
            for port in (served["port"], served["viser_port"]):
                response = page.goto(f"http://attacker.test:{port}/?token=t0ken-for-tests")
                assert response.status == 403, port
            response = page.goto(f"http://127.0.0.1:{served['port']}/?token=t0ken-for-tests")
            assert response.status == 200
            # The cookie that answer set opens the API to the page itself.
            status = page.evaluate("fetch('/api/state').then(r => r.status)")
            assert status == 200
        finally:
            browser.close()
