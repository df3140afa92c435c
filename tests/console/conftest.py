"""Fixtures for the console: the whole system (simulated ArduSub, ROV node,
emulated channel, Operator) and the web app served by uvicorn on a free
loopback port, all in one event loop on a background thread, the way
`rovlink demo` runs them.  Tests talk to it over real sockets.

The link runs at 19.2 kbit/s with 20 ms delay so that an image arrives in a
second or two instead of eleven (nothing in the web layer depends on the
rate), the ROV's failsafe waits 1 s instead of 3, and no bit is flipped.

`browser` and `open_page`: the operator page in headless Chromium against the
module's `live` console (a module with other needs keeps fixtures of its own).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import re
import socket
import threading
import time
from dataclasses import dataclass

import pytest

from rovlink.console.session.radio import Operator
from rovlink.console.stack import Stack, StackConfig

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port


def wait_for(predicate, timeout_s: float, period_s: float = 0.05):
    """Poll until predicate() is truthy; return its last value."""
    deadline = time.monotonic() + timeout_s
    value = predicate()
    while not value and time.monotonic() < deadline:
        time.sleep(period_s)
        value = predicate()
    return value


@dataclass
class LiveConsole:
    operator: Operator
    app: object
    url: str  # http://127.0.0.1:PORT
    loop: asyncio.AbstractEventLoop
    stack: Stack
    scene: object = None  # the ConsoleScene, when asked for

    @property
    def ws_url(self) -> str:
        return "ws" + self.url[len("http"):] + "/ws"

    def set_link_loss(self, loss: float) -> None:
        """Lose this fraction of the polls on their way to the ROV (1.0: the ROV hears nothing)."""
        channel = self.stack.channel

        def change() -> None:
            channel.params["a"] = dataclasses.replace(channel.params["a"], loss=loss)

        self.loop.call_soon_threadsafe(change)


def _listening_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind(("127.0.0.1", 0))
    sock.listen(64)
    return sock


@contextlib.contextmanager
def running_console(*, scene: bool = False, failsafe_s: float = 1.0, tracker: str | None = None,
                    start_depth_m: float = 2.0, arm_delay_s: float = 0.0, objects: bool = False):
    """The stack and the web app (and, with `scene`, the viser scene the
    page embeds, wired as `rovlink demo` wires it) in one event loop on a
    thread; yields the LiveConsole once the ROV has answered.  `objects`: the ROV recognises
    objects and tells them with its altitude (§11), over version 2 (a link key)."""
    from rovlink.console.web.app import create_app, serve

    ready = threading.Event()
    holder: dict = {}

    async def main() -> None:
        # No bit errors: a test that waits for one particular reply must get it.
        async with Stack(StackConfig(bitrate_bps=19200, delay_s=0.02, ber=0.0, failsafe_s=failsafe_s,
                                     tracker=tracker, start_depth_m=start_depth_m,
                                     arm_delay_s=arm_delay_s, objects=objects,
                                     key=bytes(range(32)) if objects else None)) as stack:
            view = None
            if scene:
                from rovlink.console.scene.app import ConsoleScene

                view = ConsoleScene(stack.operator, port=free_tcp_port()).start()
            try:
                app = create_app(stack.operator, viser_url=view.url if view else None, scene=view)
                sock = _listening_socket()
                port = sock.getsockname()[1]
                holder["console"] = LiveConsole(stack.operator, app, f"http://127.0.0.1:{port}",
                                                asyncio.get_running_loop(), stack, view)
                server = asyncio.create_task(serve(app, sock=sock))
                holder["task"] = asyncio.current_task()
                ready.set()
                await server
            finally:
                if view is not None:
                    view.stop()

    def run() -> None:
        try:
            asyncio.run(main())
        except asyncio.CancelledError:
            pass
        except BaseException as exc:  # noqa: BLE001 -- raised again by the fixture, not lost in the thread
            holder["error"] = exc
        finally:
            ready.set()

    thread = threading.Thread(target=run, name="live console", daemon=True)
    thread.start()
    assert ready.wait(60), "the stack did not start"
    if "error" in holder:
        raise holder["error"]
    console: LiveConsole = holder["console"]
    # The ROV has answered once: pose and link are live.
    assert wait_for(lambda: console.operator.last_reply is not None, 15), "no reply from the ROV"
    yield console
    console.loop.call_soon_threadsafe(holder["task"].cancel)
    thread.join(15)
    assert not thread.is_alive(), "the stack did not stop"
    if "error" in holder:
        raise holder["error"]


@pytest.fixture(scope="module")
def live():
    with running_console() as console:
        yield console


@pytest.fixture(scope="module")
def browser():
    """Debian's headless Chromium driven by Playwright (no browser download), one a module."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


def _viser_blob(message) -> bool:
    """A picture of the embedded 3-D scene replaced while it loaded: viser's client shows each
    image node from a blob URL it revokes when the node goes (the mosaic's pictures, the
    screen's), and Chromium says the load failed.  Viser's, not the page's: the page makes no
    blob URLs."""
    return (message.location or {}).get("url", "").startswith("blob:") and "ERR_FILE_NOT_FOUND" in message.text


def console_error(message) -> str | None:
    """A page's console error as the test reports it, with the address it is about (a
    resource that failed to load names it only there); None for what is not the page's."""
    if message.type != "error" or _viser_blob(message):
        return None
    url = (message.location or {}).get("url", "")
    return f"console: {message.text}" + (f" ({url})" if url else "")


_THUMBNAIL = re.compile(r"404 \(Not Found\) \(https?://[^/]+/api/images/(\d+)\.png\)$")


def not_dropped(errors: list[str], base: str) -> list[str]:
    """`errors` without the 404s of strip thumbnails whose pictures the console no longer
    keeps (it keeps the last IMAGE_HISTORY: on the test's fast link one goes every second or
    so, and a page that asked for two dozen thumbnails at once on a loaded machine can ask
    for the oldest after it went).  Checked, not assumed: such a picture must be gone now."""
    kept = {entry["n"] for entry in _get_json(base + "/api/images")}
    return [e for e in errors if not ((m := _THUMBNAIL.search(e)) and int(m.group(1)) not in kept)]


def _get_json(url: str):
    import json
    import urllib.request

    with urllib.request.urlopen(url, timeout=10) as resp:
        return json.loads(resp.read())


@pytest.fixture
def open_page(browser, live):
    """Opens operator pages on the module's `live` console, each in a context of its own;
    fails the test if a page logged a script error.  Without its 3-D scene (?scene=off)
    unless `scene`: drawn without a graphics card it costs Chromium a core, which the
    tests of the page itself starve the rest of the suite of (tests/console/test_scene*.py,
    test_cockpit.py, test_truth.py and the acoustic cockpit's test draw it)."""
    contexts, errors = [], []

    def open_(scene: bool = False):
        context = browser.new_context()
        contexts.append(context)
        page = context.new_page()
        page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
        page.on("console", lambda m: errors.append(text) if (text := console_error(m)) else None)
        page.goto(live.url + ("/" if scene else "/?scene=off"))
        page.wait_for_function("document.body.dataset.clientId !== undefined")
        return page

    yield open_
    for context in contexts:
        context.close()
    errors = not_dropped(errors, live.url)
    assert not errors, errors
