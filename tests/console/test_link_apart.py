"""The link loop runs apart from the web server, and the server refuses work
it should never do: request bodies over 64 KB, WebSocket clients past the cap.

All over real sockets against uvicorn serving the app (`running_console`)."""

from __future__ import annotations

import asyncio
import json
import socket
import time

import pytest
import websockets

from rovlink.console.session.radio import Operator
from rovlink.console.web.app import create_app
from rovlink.console.web.guard import MAX_BODY_BYTES

from .conftest import running_console, wait_for


def _raw_request(port: int, head: str, body_chunks=(), read_timeout_s: float = 10.0) -> bytes:
    """Send a request head (and optionally some body), return what the server answered."""
    with socket.create_connection(("127.0.0.1", port), timeout=read_timeout_s) as s:
        s.sendall(head.encode())
        for chunk in body_chunks:
            try:
                s.sendall(chunk)
            except (BrokenPipeError, ConnectionResetError):
                break
        data = b""
        try:
            while True:  # every answer here ends with the server closing the connection
                more = s.recv(65536)
                if not more:
                    break
                data += more
        except ConnectionResetError:
            pass
        return data


@pytest.fixture(scope="module")
def console():
    with running_console() as live:
        yield live


def test_a_huge_declared_body_gets_413_before_any_of_it_is_sent(console):
    port = int(console.url.rsplit(":", 1)[1])
    head = ("POST /api/orders/velocity HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            f"Content-Length: {200 * 1024 * 1024}\r\n\r\n")
    answer = _raw_request(port, head)  # not one byte of the body is sent
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert b"too large" in answer


def test_a_chunked_body_over_the_limit_gets_413(console):
    port = int(console.url.rsplit(":", 1)[1])
    head = ("POST /api/orders/velocity HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            "Transfer-Encoding: chunked\r\n\r\n")
    chunk = b"x" * 8192
    chunks = [b"%x\r\n" % len(chunk) + chunk + b"\r\n"] * ((MAX_BODY_BYTES // len(chunk)) + 4) + [b"0\r\n\r\n"]
    answer = _raw_request(port, head, chunks)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]


def test_a_body_within_the_limit_is_served(console):
    port = int(console.url.rsplit(":", 1)[1])
    body = json.dumps({"name": "x" * 100}).encode()
    head = (f"POST /api/control/take HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n")
    answer = _raw_request(port, head, [body])
    assert not answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert answer.startswith(b"HTTP/1.1 "), answer[:200]


def test_websocket_clients_past_the_cap_are_refused():
    from starlette.websockets import WebSocketDisconnect

    from ..helpers import local_test_client

    app = create_app(Operator(None), max_websockets=2)
    with local_test_client(app) as client:
        with client.websocket_connect("/ws") as first, client.websocket_connect("/ws") as second:
            assert first.receive_json()["type"] == "hello"
            assert second.receive_json()["type"] == "hello"
            with pytest.raises(WebSocketDisconnect) as refused:
                with client.websocket_connect("/ws") as third:
                    third.receive_json()
            assert refused.value.code == 1013
        # Once they have gone, a new one is let in.
        with client.websocket_connect("/ws") as again:
            assert again.receive_json()["type"] == "hello"


def test_a_blocked_web_server_does_not_delay_the_polls():
    """The server's loop is held for 2.5 s (a handler stuck on a huge body, say);
    the ROV's failsafe is 1 s.  The polls go on from the link's own loop, so the
    ROV never notices."""
    with running_console(failsafe_s=1.0) as live:
        node = live.stack.node
        assert wait_for(lambda: not node.slave.failsafe, 10)
        failsafes_before = node.stats.failsafes
        tx_before = sum(1 for e in list(live.operator.history.link_events) if e[1] == "tx")
        blocked = asyncio.run_coroutine_threadsafe(asyncio.to_thread(lambda: None), live.loop)
        blocked.result(10)  # the loop is alive before we block it
        live.loop.call_soon_threadsafe(time.sleep, 2.5)
        time.sleep(2.8)
        tx_after = sum(1 for e in list(live.operator.history.link_events) if e[1] == "tx")
        assert tx_after - tx_before >= 10, "polls stopped while the web server's loop was blocked"
        assert node.stats.failsafes == failsafes_before
        assert not node.slave.failsafe


def test_three_hundred_websocket_readers_get_refused_past_the_cap_and_polls_go_on(console):
    async def readers() -> tuple[int, int]:
        accepted = refused = 0
        everyone_answered = asyncio.Event()

        def answered() -> None:
            if accepted + refused == 300:
                everyone_answered.set()

        async def one() -> None:
            nonlocal accepted, refused
            try:
                async with websockets.connect(console.ws_url, open_timeout=30) as ws:
                    await asyncio.wait_for(ws.recv(), 30)
                    accepted += 1
                    answered()
                    # Hold the place until every other client has its answer.
                    await asyncio.wait_for(everyone_answered.wait(), 60)
            except websockets.exceptions.ConnectionClosed as exc:
                assert exc.rcvd is not None and exc.rcvd.code == 1013
                refused += 1
                answered()

        await asyncio.gather(*(one() for _ in range(300)))
        return accepted, refused

    tx_before = sum(1 for e in list(console.operator.history.link_events) if e[1] == "tx")
    accepted, refused = asyncio.run(readers())
    assert accepted + refused == 300
    assert 1 <= accepted <= 64 and refused >= 236
    tx_after = sum(1 for e in list(console.operator.history.link_events) if e[1] == "tx")
    assert tx_after > tx_before


def test_bench_console_measures_the_link_under_web_load():
    """`rovlink bench console` runs the demo as a process, loads its web server
    and reads the polls back from the demo's recording (a short, small run)."""
    import subprocess
    import sys

    # (The prediction and steering rows have tests of their own: not run again here.)
    out = subprocess.run([sys.executable, "-m", "rovlink", "bench", "console", "--duration", "60", "--sample-every",
                          "30", "--no-page", "--no-pilot", "--no-loaded", "--no-prediction", "--no-steering",
                          "--load-seconds", "6", "--readers", "80", "--uploads", "2", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    load = json.loads(out.stdout)["load"]
    assert load["idle"]["polls"] >= 5 and load["load"]["polls"] >= 5
    assert load["load"]["p95_s"] is not None and load["load"]["p95_s"] > 0
    assert load["websocket"]["messages"] > 0
    assert load["websocket"]["refused"] >= 80 - 64  # the cap held
    assert load["uploads_result"]["attempts"] >= 2
    assert load["uploads_result"].get("status_200", 0) == 0  # no 200 MB body was ever taken
