"""The 3D scene orders only for the page that holds control.

Every viewer of the viser scene shares one gizmo, so without a check a
watcher's embedded scene could drive the ROV; each viewer has its own panel,
whose order controls are disabled while it may not order.  The operator page
opens its scene with a random key in the scene's WebSocket path and gives
the same key on its own WebSocket; the control desk lets a viewer order
while the page with its key holds control.  STOP stays open to everyone.

Unit tests for the desk's rule and the key's path, then the whole thing in
headless Chromium: the system (Stack), the scene and the web app in one
event loop on a thread, as `rovlink demo` runs them, and two operator pages.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from rovlink import debt
from rovlink.console.control import ControlDesk
from rovlink.console.scene.app import scene_key_from_path
from rovlink.console.session.radio import Operator

from ..helpers import CHROMIUM, CHROMIUM_ARGS, FakeClock, needs_chromium
from .conftest import running_console, wait_for

KEY_A = "a" * 32
KEY_B = "b" * 32


def test_desk_lets_only_the_holders_scene_order():
    desk = ControlDesk(Operator(None), clock=FakeClock())  # no link: the desk only notes and sets wishes
    assert "nobody holds control" in desk.scene_refusal(KEY_A)
    pilot = desk.connect("pilot", scene_key=KEY_A)
    watcher = desk.connect("watcher", scene_key=KEY_B)
    desk.take(pilot.id)
    assert desk.scene_refusal(KEY_A) is None
    assert "held by pilot" in desk.scene_refusal(KEY_B)
    assert "only watch" in desk.scene_refusal(None)  # a scene opened on its own
    desk.take(watcher.id)
    assert desk.scene_refusal(KEY_B) is None and desk.scene_refusal(KEY_A) is not None
    desk.disconnect(watcher.id)
    assert "nobody holds control" in desk.scene_refusal(KEY_B)


@pytest.mark.parametrize("key", ["", "short", "x" * 65, "has space" + "x" * 20, "../../" + "x" * 20])
def test_a_malformed_scene_key_is_ignored(key):
    desk = ControlDesk(Operator(None), clock=FakeClock())
    client = desk.connect("page", scene_key=key)
    desk.take(client.id)
    assert client.scene_key is None
    assert desk.scene_refusal(key) is not None


def test_scene_key_is_read_from_the_websocket_path():
    assert scene_key_from_path(f"/rovlink/{KEY_A}") == KEY_A
    assert scene_key_from_path(f"/rovlink/{KEY_A}/?x=1") == KEY_A
    assert scene_key_from_path("/") is None
    assert scene_key_from_path("/rovlink/") is None
    assert scene_key_from_path(None) is None
    assert scene_key_from_path(f"/other/{KEY_A}") is None


# ----------------------------------------------------------------------
# The whole system in a browser
# ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def live():
    debt.decode(debt.encode(np.zeros((16, 16, 3), np.uint8), 100))  # compile the codec here, not in a wait
    with running_console(scene=True) as console:
        yield console


def image_orders(live) -> list[dict]:
    return [o for o in live.operator.orders_state() if o["kind"] == "IMAGE"]


def apply_button(page):
    return page.frame_locator("#scene").get_by_role("button", name="Apply image settings")


@pytest.mark.browser
@needs_chromium
def test_a_watchers_scene_cannot_order_and_the_holders_can(live):
    from playwright.sync_api import sync_playwright

    scene = live.scene
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            pages = []
            for _ in range(2):
                page = browser.new_context(viewport={"width": 1400, "height": 900}).new_page()
                page.goto(live.url)
                page.wait_for_function("document.body.dataset.clientId !== undefined")
                pages.append(page)
            pilot, watcher = pages
            # Both embedded scenes are connected, each with its page's key, each with its own panel.
            assert wait_for(lambda: len(scene.panels) >= 2, 30), "the scenes did not connect"
            def keys():
                return [scene.viewer_key(c) for c in scene.server.get_clients()]

            assert wait_for(lambda: sum(k is not None for k in keys()) >= 2, 10), keys()
            for page in pages:  # software WebGL on a shared machine: the panels take a while
                # Embedded in the page, the panel starts minimized (the 3-D view free): open it.
                page.frame_locator("#scene").get_by_role("button", name="Expand panel").click(timeout=90000)
                apply_button(page).wait_for(timeout=90000)

            # Nobody holds control: neither scene may order; its order controls are disabled.
            assert wait_for(lambda: apply_button(watcher).is_disabled() and apply_button(pilot).is_disabled(), 10)

            before = len(image_orders(live))
            pilot.click("#take")
            pilot.wait_for_function(
                "document.getElementById('control-text').textContent === 'You have control.'")
            # The pilot's scene orders; the watcher's stays disabled, its shared settings too.
            assert wait_for(lambda: not apply_button(pilot).is_disabled(), 10)
            assert apply_button(watcher).is_disabled()
            assert watcher.frame_locator("#scene").get_by_role("checkbox", name="Mono").is_disabled()
            apply_button(pilot).click(timeout=30000)
            assert wait_for(lambda: len(image_orders(live)) == before + 1, 10), "the holder's scene did not order"
            # A forced click on the watcher's disabled button orders nothing.
            apply_button(watcher).click(force=True, timeout=10000)
            time.sleep(0.5)
            assert len(image_orders(live)) == before + 1

            # STOP is anyone's.
            stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())
            watcher.frame_locator("#scene").get_by_role("button", name="Stop", exact=True).click(timeout=30000)
            assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) > stops, 10)

            # Control given back: the pilot's scene only watches again.
            pilot.click("#release")
            pilot.wait_for_function("document.getElementById('control-text').textContent !== 'You have control.'")
            assert wait_for(lambda: apply_button(pilot).is_disabled(), 10)
        finally:
            browser.close()


@pytest.mark.browser
@needs_chromium
def test_a_scene_opened_on_its_own_only_watches(live):
    from playwright.sync_api import sync_playwright

    desk = live.app.state.desk
    script = desk.take(None, "script")  # somebody holds control
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1400, "height": 900})
                before = len(live.scene.panels)
                page.goto(live.scene.url)
                assert wait_for(lambda: len(live.scene.panels) > before, 30)
                button = page.get_by_role("button", name="Apply image settings")
                button.wait_for(timeout=90000)
                assert wait_for(lambda: button.is_disabled(), 10)
                page.get_by_text("take control on the operator page").first.wait_for(timeout=10000)
                # Its STOP works.
                stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())
                page.get_by_role("button", name="Stop", exact=True).click(timeout=30000)
                assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) > stops, 10)
            finally:
                browser.close()
    finally:
        if desk.status(script.id)["you"]:  # a slow run may have outlived the script's lease
            desk.release(script.id)
