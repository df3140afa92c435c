"""The operator page in headless Chromium against the whole running system:
the page renders, link health updates, an image arrives and refines, a held
key moves the simulated ROV and letting go (or leaving the window) stops it,
and control passes between two pages only when asked.

Debian's /usr/bin/chromium driven by Playwright (no browser download).
"""

from __future__ import annotations

import itertools

import pytest

from ..helpers import get_json, needs_chromium
from .conftest import wait_for
from .pages import after_updates, take_control, wish

pytestmark = [pytest.mark.browser, needs_chromium]

NEUTRAL = {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}
# The first picture waits for the codec's JIT compilation, slow on a busy machine.
FIRST_IMAGE_MS = 90000

# Pixels of the shown <img>, summed with position weights: changes when the picture does.
PIXEL_CHECKSUM = """() => {
  const img = document.getElementById('image');
  const c = document.createElement('canvas');
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d');
  g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let sum = 0;
  for (let i = 0; i < d.length; i += 1) sum = (sum * 31 + d[i]) % 1000000007;
  return sum;
}"""


def x_m(live) -> float:
    return live.operator.state()["pose"]["received"]["x_m"]


def test_page_renders_with_link_health_that_updates(open_page, live):
    page = open_page()
    assert page.title() == "rovlink console"
    assert page.is_visible("#no-scene")  # no viser_url given
    # The mode box and the key map are built from GET /api/config.
    page.wait_for_function("document.body.dataset.configured === '1'")
    assert page.is_visible("text=surge forward")
    config = get_json(live.url + "/api/config")
    assert page.eval_on_selector_all("#mode-select option", "os => os.map(o => o.textContent)") == config["modes"]
    page.wait_for_function("document.getElementById('link-poll-rate').textContent.endsWith('Hz')")
    page.wait_for_function("document.body.dataset.link === 'up'")
    assert page.text_content("#link-up") == "link up"
    assert page.text_content("#autopilot") == "AUTOPILOT"
    sent = page.text_content("#link-bytes")
    # Bytes sent / received keep counting as the link runs.
    page.wait_for_function(f"document.getElementById('link-bytes').textContent !== {sent!r}")
    assert page.text_content("#link-rtt").endswith(" ms")
    assert float(page.text_content("#link-odo-age").split()[0]) >= 0.0
    assert "Watching" in page.text_content("#control-text")


def test_an_image_arrives_and_visibly_refines(open_page, live):
    page = open_page()
    page.wait_for_selector("#image[data-decoded-bytes]", state="visible", timeout=FIRST_IMAGE_MS)
    samples = []

    def refined() -> bool:
        # (image shown, its prefix bytes, image in progress, bytes received, of total, pixel checksum)
        shown = page.evaluate("""() => { const i = document.getElementById('image');
            const c = document.getElementById('image-card');
            return [i.dataset.img, +i.dataset.decodedBytes, c.dataset.img, +c.dataset.receivedBytes,
                    +c.dataset.totalBytes]; }""")
        samples.append((*shown, page.evaluate(PIXEL_CHECKSUM)))
        # Two pictures of the image in progress, the later from more bytes, and different.
        return any(a[0] == a[2] == b[0] == b[2] and b[1] > a[1] and b[3] > a[3] and b[5] != a[5]
                   for a, b in itertools.pairwise(samples))

    assert wait_for(refined, 30, period_s=0.05), f"no refinement seen in {samples[-5:]}"
    _, decoded, _, received, total, _ = next(b for a, b in itertools.pairwise(samples)
                                               if a[0] == a[2] == b[0] == b[2] and b[1] > a[1])
    assert 0 < decoded <= received <= total
    progress = page.evaluate("[document.getElementById('image-progress').value, "
                             "document.getElementById('image-progress').max]")
    assert 0 < progress[0] <= progress[1]


def test_a_held_key_moves_the_rov_and_letting_go_stops_it(open_page, live):
    page = open_page()
    take_control(page)
    page.click("#arm")
    page.wait_for_function("document.getElementById('armed').textContent === 'ARMED'", timeout=30000)
    start = x_m(live)

    page.keyboard.down("KeyW")
    assert wait_for(lambda: wish(live)["vx"] > 0, 5), "W sent no velocity"
    # Held past the server's 1 s dead man: the page repeats it, so it holds.
    assert wait_for(lambda: x_m(live) > start + 0.5, 15), "the ROV did not move forward"
    assert wish(live)["vx"] == pytest.approx(0.5)  # key strength 50 %
    page.keyboard.up("KeyW")
    assert wait_for(lambda: wish(live) == NEUTRAL, 3), "letting go did not send neutral"

    # Leaving the window while a key is held is letting go too.
    page.keyboard.down("KeyE")
    assert wait_for(lambda: wish(live)["vyaw"] > 0, 5)
    page.evaluate("window.dispatchEvent(new Event('blur'))")
    assert wait_for(lambda: wish(live) == NEUTRAL, 3), "blur did not send neutral"
    page.keyboard.up("KeyE")

    stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())  # (earlier tests' among them)
    page.keyboard.press("Space")
    assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) > stops, 3), \
        "Space is not STOP"
    # Disarm at once after STOP, as a pilot does: it goes once the STOP is confirmed (a CI run
    # saw it lapse unsent behind a STOP the loaded autopilot took over 3 s to confirm).
    page.click("#disarm")
    page.wait_for_function("document.getElementById('armed').textContent === 'DISARMED'", timeout=30000)


def test_control_passes_between_pages_only_when_taken_and_leaves_with_its_page(open_page, live):
    pilot, watcher = open_page(), open_page()
    take_control(pilot)
    watcher.wait_for_function("document.getElementById('control-text').textContent.startsWith('Watching: browser')")
    assert watcher.is_disabled("#arm") and not pilot.is_disabled("#arm")

    # A watcher's keys do not drive.
    watcher.keyboard.down("KeyS")
    watcher.wait_for_selector("#error:has-text('Take control to drive')")
    assert wish(live) == NEUTRAL
    watcher.keyboard.up("KeyS")

    # The pilot drives; the watcher takes over: the pilot's motion ends with it.
    pilot.keyboard.down("KeyD")
    assert wait_for(lambda: wish(live)["vy"] > 0, 5)
    take_control(watcher)
    assert wait_for(lambda: wish(live) == NEUTRAL, 3)
    pilot.wait_for_function("document.getElementById('control-text').textContent.startsWith('Watching')")
    after_updates(pilot)  # the pilot still holds D: its page must not send it any more
    assert wish(live) == NEUTRAL
    pilot.keyboard.up("KeyD")

    # The holder leaves: control is free again.
    watcher.close()
    pilot.wait_for_function("document.getElementById('control-text').textContent === "
                            "'Watching: nobody has control.'")
    assert live.app.state.desk.status()["held"] is False


def test_a_region_dragged_on_the_image_and_a_goto_become_orders(open_page, live):
    page = open_page()
    take_control(page)
    page.wait_for_selector("#image[data-decoded-bytes]", state="visible", timeout=FIRST_IMAGE_MS)
    width, height = page.evaluate("[document.getElementById('image').naturalWidth, "
                                  "document.getElementById('image').naturalHeight]")
    box = page.locator("#image").bounding_box()
    page.mouse.move(box["x"] + box["width"] * 0.25, box["y"] + box["height"] * 0.25)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * 0.75, box["y"] + box["height"] * 0.5, steps=5)
    page.mouse.up()
    # Drafted, not sent: drawn dashed, never as the ROI the picture was coded with.
    assert page.get_attribute("#roi-text", "data-state") == "drafted"
    assert "not sent" in page.text_content("#roi-text")
    assert page.is_visible("#roi-draft") and not page.is_visible("#roi-box")
    page.fill("#shift", "4")
    page.click("#apply-image")
    assert wait_for(lambda: live.operator.requested_settings.roi is not None, 5), "no ROI order"
    settings = live.operator.requested_settings
    assert settings.shift == 4
    expected = (width * 0.25, height * 0.25, width * 0.75, height * 0.5)
    assert all(abs(got - want) <= 2 for got, want in zip(settings.roi, expected)), (settings.roi, expected)
    # Sent, then acknowledged, then in force once a picture coded with it arrives: only
    # then is it drawn solid on that picture (and the dashed draft gone from it).
    page.wait_for_function("['sent', 'acknowledged', 'in-force'].includes(document.getElementById('roi-text').dataset.state)")
    page.wait_for_function("document.getElementById('roi-text').dataset.state === 'in-force'", timeout=FIRST_IMAGE_MS)
    assert page.is_visible("#roi-box") and not page.is_visible("#roi-draft")
    coded = live.operator.image_state()["settings"]["roi"]
    assert coded == list(settings.roi), (coded, settings.roi)
    assert "in force (picture #" in page.text_content("#roi-text")

    page.click("#roi-clear")
    page.click("#apply-image")
    assert wait_for(lambda: live.operator.requested_settings.roi is None, 5)

    page.fill("#goto-x", "1.5")
    page.fill("#goto-y", "-0.5")
    page.fill("#goto-z", "2.5")
    page.click("#goto-go")
    assert wait_for(lambda: any(o["kind"] == "POSITION" and o["x_m"] == 1.5 and o["y_m"] == -0.5 and o["z_m"] == 2.5
                                for o in live.operator.orders_state()), 5), "no position order"
    live.operator.stop()  # the ROV need not go there for this test


FAKE_GAMEPAD = """() => {
  // Headless Chromium has no gamepad: stand in for the Gamepad API.
  const pad = { id: "test pad", index: 0, connected: true, axes: [0, 0, 0, 0],
                buttons: Array.from({ length: 17 }, () => ({ pressed: false, value: 0 })) };
  window.testPad = pad;
  navigator.getGamepads = () => [pad];
  window.dispatchEvent(Object.assign(new Event("gamepadconnected"), { gamepad: pad }));
}"""


def test_gamepad_sticks_drive_and_button_b_stops(open_page, live):
    page = open_page()
    take_control(page)
    page.evaluate(FAKE_GAMEPAD)
    assert page.text_content("#gamepad") == "Gamepad: test pad."
    # Left stick pushed forward and right, right stick left: surge, sway, yaw; the deadzone
    # (0.12 by default) is cut out and the rest rescaled, so output grows from 0 at its edge:
    # (0.8 - 0.12) / 0.88 = 0.773.  Heave's 0.05 lies inside it: exactly 0.
    page.evaluate("window.testPad.axes = [0.4, -0.8, -0.6, 0.05]")
    assert wait_for(lambda: wish(live) == {"vx": 0.773, "vy": 0.318, "vz": 0.0, "vyaw": -0.545}, 3), wish(live)
    page.evaluate("window.testPad.axes = [0, 0, 0, 0]")
    assert wait_for(lambda: wish(live) == NEUTRAL, 3), "stick released but still moving"
    stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())
    page.evaluate("window.testPad.buttons[1] = { pressed: true, value: 1 }")
    assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) == stops + 1, 3)


def test_a_dropped_link_shows_in_link_health_and_the_failsafe_stays_visible(open_page, live):
    page = open_page()
    page.wait_for_function("document.getElementById('link-odo-age').textContent.endsWith(' s')")
    lost_before = live.operator.link_state()["reports_lost"]
    live.set_link_loss(1.0)
    try:
        # Polls go unanswered: the page counts lost replies and ageing odometry.
        page.wait_for_function(f"+document.getElementById('link-lost').textContent.split(' / ')[1] > {lost_before}",
                               timeout=30000)
        page.wait_for_function("parseFloat(document.getElementById('link-odo-age').textContent) > 1.5",
                               timeout=30000)
        assert wait_for(lambda: live.stack.node.slave.failsafe, 10), "the ROV never went to failsafe"
        flagged = []
        unsubscribe = live.operator.subscribe(
            lambda topic, p: flagged.append(p["t"]) if topic == "pose" and p.get("failsafe") else None)
    finally:
        live.set_link_loss(0.0)
    # The first reply back says FAILSAFE; the ROV clears it at once, the page keeps showing it.
    try:
        assert wait_for(lambda: flagged, 30), "no reply with FAILSAFE reached the console"
    finally:
        unsubscribe()
    page.wait_for_selector("#failsafe:visible", timeout=30000)
    page.wait_for_function("document.getElementById('failsafe').textContent === 'FAILSAFE (cleared)'",
                           timeout=30000)
    assert page.is_visible("#failsafe")
    assert float(page.text_content("#link-odo-age").split()[0]) < 1.5


def test_typing_in_a_text_field_never_sends_stop_and_escape_is_stop_from_there(open_page, live):
    """Issue 20 of the pilot's page: "link lost" typed into the log filter stopped the vehicle."""
    page = open_page()
    take_control(page)

    def stops():
        return sum(o["kind"] == "STOP" for o in live.operator.orders_state())

    before = stops()
    page.click("#log-filter")
    page.keyboard.type("link lost")
    assert page.input_value("#log-filter") == "link lost"
    after_updates(page)  # a STOP would be on its way by now (the page sends at once)
    assert stops() == before, "typing a space in the filter sent STOP"
    page.keyboard.press("Escape")  # STOP from inside the field
    assert wait_for(lambda: stops() == before + 1, 3), "Escape in a field is not STOP"
    page.click("#disarm")


def test_the_mode_selector_shows_the_vehicles_mode_unless_the_pilot_is_choosing(open_page, live):
    """Issue 20 of the pilot's page: the selector read MANUAL on load while the vehicle held
    in POS_HOLD, and "Set mode" then sent a mode the pilot had not chosen."""
    pilot = open_page()
    take_control(pilot)
    pilot.select_option("#mode-select", "DEPTH_HOLD")
    pilot.click("#set-mode")
    assert wait_for(lambda: live.operator.state()["pose"]["mode"] == "DEPTH_HOLD", 15)
    watcher = open_page()  # a page opened now: its selector follows the vehicle
    watcher.wait_for_function("document.getElementById('mode-select').value === 'DEPTH_HOLD'")
    # The pilot choosing is not overwritten by the vehicle's mode meanwhile.
    pilot.select_option("#mode-select", "STABILIZE")
    after_updates(pilot, 15)  # pose updates arrive meanwhile: none overwrites the choice
    assert pilot.input_value("#mode-select") == "STABILIZE"
    # No picture element without a picture: never a broken-image icon.
    for page in (pilot, watcher):
        assert page.evaluate("[...document.querySelectorAll('#image, #image-done')]"
                             ".every((img) => img.hidden || !!img.getAttribute('src'))")
    pilot.click("#release")


def test_every_orders_fate_shows_beside_its_control_with_its_time(open_page, live):
    """Issue 25 of the pilot's page: arming..., the mode followed, a Go-to's distance left,
    its arrival and its abort, image settings in force; the orders list with times."""
    page = open_page()
    take_control(page)

    def fate_id(element: str) -> int:
        return int(page.get_attribute(element, "data-id") or 0)

    def wait_fate(element: str, after: int, states: str, timeout: float = 15000) -> None:
        """Until `element` shows an order newer than `after` in one of `states` (a fate left
        there by an earlier test's order does not count)."""
        page.wait_for_function(
            f"(() => {{ const e = document.getElementById('{element[1:]}');"
            f" return +(e.dataset.id || 0) > {after} && {states!r}.split(' ').includes(e.dataset.state); }})()",
            timeout=timeout)

    before = fate_id("#arm-fate")
    page.click("#arm")
    # Arming: said at once beside Arm, then followed when the vehicle reports it.
    wait_fate("#arm-fate", before, "requested sent followed")
    wait_fate("#arm-fate", before, "followed")
    text = page.text_content("#arm-fate")
    assert text.startswith("armed ✓ ") and text[-3] == ":" and text[-6] == ":", text  # ... HH:MM:SS
    assert page.get_attribute("#arm-fate", "title").endswith("ARM: followed")
    before = fate_id("#mode-fate")
    page.select_option("#mode-select", "DEPTH_HOLD")
    page.click("#set-mode")
    wait_fate("#mode-fate", before, "followed")
    assert page.text_content("#mode-fate").startswith("DEPTH_HOLD ✓ ")

    # A Go-to a little way off: its preview's length and time stay while the target shows.
    here = live.operator.pose_state()["received"]
    for field, value in zip(("#goto-x", "#goto-y", "#goto-z", "#goto-yaw"),
                            (here["x_m"] + 1.5, here["y_m"], max(here["z_m"], 1.0), here["yaw_deg"])):
        page.fill(field, f"{value:.2f}")
    page.click("#goto-preview")
    page.wait_for_function("document.getElementById('goto-plan').textContent.startsWith('preview: ')")
    after_updates(page)  # the target event and telemetry came meanwhile
    assert page.text_content("#goto-plan").startswith("preview: ") and " m in about " in page.text_content("#goto-plan")
    before = fate_id("#goto-fate")
    page.click("#goto-go")
    wait_fate("#goto-fate", before, "queued sent acknowledged arrived")
    page.wait_for_function("/m to go/.test(document.getElementById('goto-fate').textContent)"
                           " || document.getElementById('goto-fate').dataset.state === 'arrived'", timeout=15000)
    wait_fate("#goto-fate", before, "arrived", 60000)
    shown = page.text_content("#goto-fate")  # read once: it must not change back after "arrived"
    assert shown.startswith("go-to #") and "arrived" in shown, shown
    page.wait_for_timeout(1500)  # more telemetry, made before and after the event: none takes it back
    assert "arrived" in page.text_content("#goto-fate"), page.text_content("#goto-fate")
    assert "done" in page.get_attribute("#goto-fate", "class")

    # Another, given up by STOP: aborted, not left "acknowledged" for good.
    page.fill("#goto-x", f"{here['x_m'] - 6:.2f}")
    before = fate_id("#goto-fate")
    page.click("#goto-go")
    wait_fate("#goto-fate", before, "acknowledged")
    page.click("#stop")
    page.wait_for_function("document.getElementById('goto-fate').textContent.includes('aborted: STOP')", timeout=10000)

    # Image settings: in force from the next picture once the ROV acknowledged them.
    page.fill("#budget", "1500")
    before = fate_id("#image-fate")
    page.click("#apply-image")
    wait_fate("#image-fate", before, "acknowledged")
    assert "in force from the next picture" in page.text_content("#image-fate")

    # The orders list: more than four, each with the time of its state.
    lines = page.eval_on_selector_all("#orders li", "lis => lis.map((li) => li.textContent)")
    assert len(lines) > 4, lines
    assert all(line[2] == ":" and line[5] == ":" for line in lines), lines
    assert any("POSITION (GUIDED): arrived" in line for line in lines), lines
    page.click("#disarm")
