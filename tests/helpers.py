"""Small things several test modules need: the browser they drive, a
pseudo-terminal that can vanish and return (a serial port pulled), free
loopback ports, waiting for a condition, and reading the console's API."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import time
import tty
import urllib.request

import pytest

# Debian's chromium (installed by .ci/run); no browser is ever downloaded.
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
needs_chromium = pytest.mark.skipif(
    not os.path.exists(CHROMIUM),
    reason=f"Chromium is not installed at {CHROMIUM} (Debian package 'chromium'); "
           "the browser tests drive it and download no browser")


class FakeClock:
    """A clock a test sets by hand (`clock.t += 2.0`); callable like time.monotonic."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class Pty:
    """A pseudo-terminal reachable at a fixed path, which can vanish and return."""

    def __init__(self, path):
        self.path = path
        self.master_fd = None

    def up(self):
        master_fd, slave_fd = os.openpty()
        tty.setraw(slave_fd)
        name = os.ttyname(slave_fd)
        os.close(slave_fd)
        if os.path.lexists(self.path):
            os.unlink(self.path)
        os.symlink(name, self.path)
        self.master_fd = master_fd
        os.set_blocking(master_fd, False)

    def down(self):
        os.unlink(self.path)
        os.close(self.master_fd)
        self.master_fd = None

    def read(self):
        try:
            return os.read(self.master_fd, 4096)
        except BlockingIOError:
            return b""

    def write(self, data):
        os.write(self.master_fd, data)


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get_json(url: str):
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def wait_until_up(predicate, timeout_s: float, period_s: float = 0.2):
    """Poll predicate() until truthy; errors count as "not yet" (a server still starting)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            value = predicate()
        except Exception:
            value = None
        if value or time.monotonic() > deadline:
            return value
        time.sleep(period_s)


def local_test_client(app, **kwargs):
    """FastAPI's TestClient, but speaking to the app by one of its own names:
    the console refuses any other Host (DNS rebinding), and TestClient's
    default, "testserver", is none of them (its WebSockets use it always)."""
    from urllib.parse import urljoin

    from fastapi.testclient import TestClient

    class LocalTestClient(TestClient):
        def websocket_connect(self, url: str, *args, **kw):
            return super().websocket_connect(urljoin("ws://127.0.0.1", url), *args, **kw)

    return LocalTestClient(app, base_url="http://127.0.0.1", **kwargs)


def run_async(coro, timeout: float):
    """Run `coro` on a new event loop; a TimeoutError after `timeout` seconds."""
    return asyncio.run(asyncio.wait_for(coro, timeout))


async def until(cond, timeout: float, what: str = "condition") -> None:
    """Wait, on the running loop, until `cond()` is true; AssertionError
    naming `what` after `timeout` seconds."""
    deadline = asyncio.get_running_loop().time() + timeout
    while not cond():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)
