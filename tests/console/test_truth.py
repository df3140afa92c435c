"""What the pilot sees is true, and every order goes one way: headless Chromium
against the whole system (Stack, viser scene, web app) as `rovlink demo`
wires it, with operator pages that embed the scene.

- the link cut and restored: the banner, the alarm, the inferred FAILSAFE,
  the stale marks, and their recovery;
- the scene's keys do not latch, and a scene key after STOP (or after a
  change of pilot) does not resend an old surge: the sliders show the wish;
- STOP from inside the scene, also from a watcher's; a watcher's scene
  controls are disabled, not put back.
"""

from __future__ import annotations

import numpy as np
import pytest

from rovlink import debt

from ..helpers import CHROMIUM, CHROMIUM_ARGS, needs_chromium
from .conftest import running_console, wait_for
from .pages import after_ticks, after_updates, take_control, wish

pytestmark = [pytest.mark.browser, needs_chromium]

NEUTRAL = {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}


@pytest.fixture(scope="module")
def live():
    debt.decode(debt.encode(np.zeros((16, 16, 3), np.uint8), 100))  # compile the codec here, not in a wait
    with running_console(scene=True) as console:
        yield console


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                              args=CHROMIUM_ARGS + ["--autoplay-policy=no-user-gesture-required"])
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def open_page(browser, live):
    contexts = []

    def open_():
        context = browser.new_context(viewport={"width": 1400, "height": 900})
        contexts.append(context)
        page = context.new_page()
        page.goto(live.url)
        page.wait_for_function("document.body.dataset.clientId !== undefined")
        return page

    yield open_
    for context in contexts:
        context.close()
    # Nobody holds control between tests.
    wait_for(lambda: not live.app.state.desk.status()["held"], 10)


def scene_ready(page, live):
    """The page's embedded scene, connected, its panel built."""
    frame = page.frame_locator("#scene")
    # Embedded in the page, the scene's panel starts minimized (the 3-D view free): open it.
    frame.get_by_role("button", name="Expand panel").click(timeout=60000)
    frame.get_by_role("button", name="Apply image settings").wait_for(timeout=60000)
    return frame


def scene_may_order(page) -> None:
    """The page's scene has been told it may order (its enabled commands reached it first)."""
    page.frame_locator("#scene").get_by_text("You may order from this view.").wait_for(timeout=10000)


def focus_scene(page) -> None:
    """Click into the 3D view (the scene's canvas), as a pilot would before a key."""
    canvas = page.frame_locator("#scene").locator("canvas").first
    box = canvas.bounding_box()
    page.mouse.click(box["x"] + 40, box["y"] + box["height"] - 40)


def scene_panel(live, page):
    """The scene's panel for this page's viewer (by the page's scene key)."""
    key = page.evaluate("SCENE_KEY")
    scene = live.scene
    ids = [cid for cid in scene.panels if scene.viewer_key(cid) == key]
    return scene.panels[ids[0]] if ids else None


def test_a_cut_link_is_loud_the_rov_is_inferred_in_failsafe_and_all_recovers(open_page, live):
    page = open_page()
    # A working link first (up, or degraded by a late or lost reply in the last 5 s: on a
    # loaded machine a 5-s stretch without one may not come for a while).
    page.wait_for_function("['up', 'degraded'].includes(document.body.dataset.link)", timeout=30000)
    assert page.is_hidden("#link-banner")
    live.set_link_loss(1.0)
    try:
        page.wait_for_selector("#link-banner:visible", timeout=30000)
        assert page.text_content("#link-banner-title") == "LINK LOST"
        assert page.evaluate("+document.body.dataset.alerts") >= 1  # the alarm sounded
        assert "stale" in page.get_attribute("#pose-table", "class")
        assert "stale" in page.get_attribute("#image-frame", "class")
        assert page.text_content("#link-up") == "LINK LOST"
        # Past the ROV's failsafe time (3 s) it says so, with the time.
        page.wait_for_selector("#failsafe-inferred:visible", timeout=30000)
        text = page.text_content("#failsafe-inferred")
        assert text.startswith("ROV in FAILSAFE (inferred) since ") and len(text.split()[-1]) == 8
        # The prediction no longer flies on: two reads past the failsafe time agree.
        op = live.operator
        assert wait_for(lambda: op.odometry_age_s() > op.rov_failsafe_s + 0.2, 10)
        first, age = op.predicted_pose(), op.odometry_age_s()
        assert wait_for(lambda: op.odometry_age_s() > age + 1.0, 10)
        assert op.predicted_pose() == first
        assert op.pose_state()["uncertainty_m"] > op.rov_failsafe_s * 1.0
    finally:
        live.set_link_loss(0.0)
    page.wait_for_selector("#link-banner", state="hidden", timeout=30000)
    page.wait_for_function("!document.getElementById('pose-table').classList.contains('stale')")
    assert "stale" not in page.get_attribute("#image-frame", "class")
    assert page.text_content("#link-up").startswith(("link up", "link degraded"))


def test_a_watchers_scene_has_its_order_controls_disabled_and_stop_works_from_inside(open_page, live):
    pilot, watcher = open_page(), open_page()
    take_control(pilot)
    pilot_frame, watcher_frame = scene_ready(pilot, live), scene_ready(watcher, live)
    arm = watcher_frame.get_by_role("button", name="Arm", exact=True)
    assert wait_for(lambda: arm.is_disabled(), 10), "the watcher's Arm is enabled"
    assert watcher_frame.get_by_role("button", name="Apply image settings").is_disabled()
    assert not watcher_frame.get_by_role("button", name="Stop", exact=True).is_disabled()
    assert wait_for(lambda: not pilot_frame.get_by_role("button", name="Arm", exact=True).is_disabled(), 10)

    # STOP from inside the watcher's 3D view: Space with the focus in the scene.
    stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())
    focus_scene(watcher)
    watcher.keyboard.press("Space")
    assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) > stops, 5), \
        "Space in the scene is not STOP"
    # The watcher's scene keys do not drive.
    watcher.keyboard.press("w")
    after_updates(watcher)
    assert wish(live) == NEUTRAL

    # Control passes: the watcher's scene is enabled, the old pilot's disabled.
    take_control(watcher)
    # Each viewer's panel follows the desk on the scene's next frame; a loaded
    # machine (two pages and their scenes in software rendering) can take seconds.
    assert wait_for(lambda: not arm.is_disabled(), 30)
    assert wait_for(lambda: pilot_frame.get_by_role("button", name="Arm", exact=True).is_disabled(), 30)


def test_scene_keys_do_not_latch_and_never_resend_an_old_surge_after_stop(open_page, live):
    page = open_page()
    take_control(page)
    scene_ready(page, live)
    scene_may_order(page)
    panel = wait_for(lambda: scene_panel(live, page), 10)
    assert panel is not None
    # The page drives forward, then STOP (Space on the page).
    page.keyboard.down("KeyW")
    assert wait_for(lambda: wish(live)["vx"] > 0, 5)
    assert wait_for(lambda: panel.sliders["vx"].value > 0, 5), "the scene's slider does not show the wish"
    page.keyboard.press("Space")
    page.keyboard.up("KeyW")
    assert wait_for(lambda: wish(live) == NEUTRAL, 5)
    assert wait_for(lambda: panel.sliders["vx"].value == 0.0, 5), "the slider kept the old surge"

    # A yaw key in the scene: yaw only, no old surge; and released, it does not latch.
    focus_scene(page)
    page.keyboard.press("e")
    assert wait_for(lambda: wish(live)["vyaw"] > 0, 5), "the scene's key did not drive"
    assert wish(live)["vx"] == 0.0 and wish(live)["vy"] == 0.0
    assert wait_for(lambda: wish(live) == NEUTRAL, 5), "the scene's key latched"


def test_the_next_pilot_never_sends_the_previous_pilots_surge(open_page, live):
    first, second = open_page(), open_page()
    take_control(first)
    # The page sends its sticks' neutral once on taking control (console.js sendVelocity):
    # let it go before the surge, or it lands after it and takes it back (a loaded
    # newcomer's run: the POST answered 200, the wish read 0).
    after_ticks(first)
    client = first.evaluate("page.clientId")
    # The first pilot's standing surge (REST, no dead man).
    status = first.evaluate("""async (id) => (await fetch('/api/orders/velocity', {method: 'POST',
        headers: {'Content-Type': 'application/json', 'X-Rovlink-Client': id},
        body: JSON.stringify({vx: 0.5})})).status""", client)
    assert status == 200 and wish(live)["vx"] == 0.5
    take_control(second)
    assert wait_for(lambda: wish(live) == NEUTRAL, 5), "a change of pilot kept the surge"
    scene_ready(second, live)
    scene_may_order(second)
    panel = wait_for(lambda: scene_panel(live, second), 10)
    assert wait_for(lambda: panel.sliders["vx"].value == 0.0, 5)
    refused = live.scene.orders_refused
    # A key press can be lost while the focus moves into the scene's frame
    # (headless Chromium): click and press again, a few times at most.
    seen = []
    for _ in range(3):
        focus_scene(second)
        second.keyboard.press("e")
        if wait_for(lambda: seen.append(dict(wish(live))) or seen[-1]["vyaw"] > 0, 3):
            break
    assert seen[-1]["vyaw"] > 0, "the scene's key did not drive"
    assert seen[-1]["vx"] == 0.0, "the previous pilot's surge came back"
    assert live.scene.orders_refused == refused
