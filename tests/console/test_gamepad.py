"""The gamepad settings of the operator page (console/web/static/gamepad.js)
in headless Chromium against the whole running system, with the Gamepad API
faked by the page script below: deadzone and expo shape the wish the server
receives, a remapped and inverted stick axis drives the vehicle axis it was
given, the STOP button is the one the pilot chose (by pressing it or ticking
it), the gain buttons step the gain, the settings survive a reload (and bad
stored values fall back to defaults), and a pad that goes sends neutral.

One browser for the module; one page (a fresh browser context: an empty
localStorage) per test.  Expected wishes are worked out by hand from the
shaping rule in gamepad.js's header and rounded as console.js rounds them
(3 decimals).
"""

from __future__ import annotations

import json

import pytest

from ..helpers import needs_chromium
from .conftest import wait_for
from .pages import after_ticks

pytestmark = [pytest.mark.browser, needs_chromium]

NEUTRAL = {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}

# Headless Chromium has no gamepad: stand in for the Gamepad API.
FAKE_GAMEPAD = """(id) => {
  const pad = { id, index: 0, connected: true, mapping: "standard", axes: [0, 0, 0, 0],
                buttons: Array.from({ length: 17 }, () => ({ pressed: false, value: 0 })) };
  window.testPad = pad;
  navigator.getGamepads = () => [pad];
  window.dispatchEvent(Object.assign(new Event("gamepadconnected"), { gamepad: pad }));
}"""

# Every velocity message the page sends over its WebSocket, in order.
RECORD_SENT = """(() => {
  window.sentVelocity = [];
  const send = WebSocket.prototype.send;
  WebSocket.prototype.send = function (data) {
    try { const m = JSON.parse(data); if (m.type === "velocity") window.sentVelocity.push(m); } catch (e) {}
    return send.call(this, data);
  };
})();"""


@pytest.fixture
def pilot(browser, live):
    """A page in a fresh context holding control, with a fake pad, its gamepad
    settings open; the test fails if the page logged a script error."""
    context = browser.new_context()
    context.add_init_script(RECORD_SENT)
    errors: list[str] = []
    page = context.new_page()
    page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
    # Script errors only: a resource that failed to load (a picture, another module's file)
    # is test_browser's business; were gamepad.js missing, every test here would fail anyway.
    page.on("console", lambda m: errors.append(f"console: {m.text}")
            if m.type == "error" and not m.text.startswith("Failed to load resource") else None)
    ready(page, live)
    yield page
    context.close()
    assert not errors, errors


def ready(page, live, *, reload: bool = False) -> None:
    if reload:
        page.reload()
    else:
        page.goto(live.url + "/?scene=off")
    page.wait_for_function("document.body.dataset.clientId !== undefined")
    page.click("#take")
    page.wait_for_function("document.getElementById('control-text').textContent === 'You have control.'")
    page.evaluate(FAKE_GAMEPAD, "test pad")
    page.click("#gamepad-settings > summary")
    page.wait_for_function("document.getElementById('gp-live-id').textContent.startsWith('test pad')")


def server_wish(live) -> dict:
    return live.operator.state()["velocity_wish"]


def page_wish(page) -> dict | None:
    text = page.evaluate("document.body.dataset.wish")
    return json.loads(text) if text else None


def drives(page, live, expected: dict, timeout_s: float = 3) -> None:
    """The server's wish, and the page's echo of it, become `expected`."""
    assert wait_for(lambda: server_wish(live) == expected, timeout_s), (server_wish(live), expected)
    assert wait_for(lambda: page_wish(page) == expected, timeout_s), (page_wish(page), expected)


def sticks(page, axes) -> None:
    page.evaluate("(a) => { window.testPad.axes = a; }", list(axes))


def button(page, b: int, down: bool) -> None:
    page.evaluate("([b, d]) => { window.testPad.buttons[b] = { pressed: d, value: d ? 1 : 0 }; }", [b, down])


PRESSED = "(b) => (document.getElementById('gp-live-buttons').dataset.pressed || '').split(',').includes(String(b))"


def tap(page, b: int) -> None:
    """Press and release, each seen by the page's live state (drawn every 100 ms, as console.js's
    tick, the 50 ms poll of gain buttons in between) and held a while longer: on a busy machine
    the page's timers may run late, never skipped."""
    button(page, b, True)
    page.wait_for_function(PRESSED, arg=b)
    after_ticks(page, 2)
    button(page, b, False)
    page.wait_for_function(f"(b) => !({PRESSED})(b)", arg=b)
    after_ticks(page, 2)


def set_number(page, selector: str, value: str) -> None:
    page.fill(selector, value)
    page.dispatch_event(selector, "change")


def stops(live) -> int:
    return sum(o["kind"] == "STOP" for o in live.operator.orders_state())


def test_deadzone_and_expo_shape_the_wish_and_a_resting_stick_gives_exactly_neutral(pilot, live):
    page = pilot
    # Defaults (the page's keymap text and test_browser rely on them).
    assert page.input_value("#gp-deadzone") == "0.12"
    assert page.input_value("#gp-expo") == "0"
    set_number(page, "#gp-deadzone", "0.2")
    set_number(page, "#gp-expo", "0.5")
    # Sway inside the deadzone; surge 0.7 forward: r = (0.7-0.2)/0.8 = 0.625,
    # 0.5*0.625 + 0.5*0.625^3 = 0.43457; heave 0.4: r = 0.25 -> 0.13281; yaw full left.
    sticks(page, [0.15, -0.7, -1.0, 0.4])
    drives(page, live, {"vx": 0.435, "vy": 0.0, "vz": 0.133, "vyaw": -1.0})
    # The live state shows the raw axis and the shaped output.
    page.wait_for_function("document.querySelector('#gp-raw-1 td:last-child').dataset.value === '-0.7'")
    page.wait_for_function("Math.abs(+document.querySelector('#gp-out-vx td:last-child').dataset.value"
                           " - 0.4345703125) < 1e-9")
    # Every stick resting inside the deadzone (one right on its edge): neutral, the dead man lets go.
    sticks(page, [0.19, -0.2, 0.1, -0.15])
    drives(page, live, NEUTRAL)
    assert page.evaluate("window.rovGamepad.wish()") == NEUTRAL
    # The curve through the public wish(): 0 up to the deadzone, continuous past it,
    # never decreasing, full at full stick and clamped beyond.
    curve = page.evaluate("""() => {
      const out = [];
      for (let i = 0; i <= 150; i += 1) {
        window.testPad.axes = [0, -i / 100, 0, 0];
        out.push(window.rovGamepad.wish().vx);
      }
      window.testPad.axes = [0, 1.7, 0, 0];
      out.push(window.rovGamepad.wish().vx);
      window.testPad.axes = [0, 0, 0, 0];
      return out;
    }""")
    assert curve[:21] == [0] * 21
    assert 0 < curve[21] < 0.02
    assert all(b >= a for a, b in zip(curve[:151], curve[1:151]))
    assert curve[100:151] == [1] * 51
    assert curve[151] == -1
    # The live state is drawn only while the settings are open.
    page.click("#gamepad-settings > summary")
    sticks(page, [0.0, 0.55, 0.0, 0.0])
    after_ticks(page, 4)
    assert page.get_attribute("#gp-raw-1 td:last-child", "data-value") != "0.55"
    page.click("#gamepad-settings > summary")
    page.wait_for_function("document.querySelector('#gp-raw-1 td:last-child').dataset.value === '0.55'")
    sticks(page, [0, 0, 0, 0])
    drives(page, live, NEUTRAL)


def test_a_remapped_inverted_axis_drives_the_vehicle_axis_it_was_given(pilot, live):
    page = pilot
    # Surge from the right stick's Y (axis 3, pushed away is negative: inverted, as by default),
    # heave from the left stick's Y, yaw from nothing.
    page.select_option("#gp-axis-vx", "3")
    page.select_option("#gp-axis-vz", "1")
    page.select_option("#gp-axis-vyaw", "-1")
    assert page.is_checked("#gp-invert-vx")
    assert page.text_content("#gp-mapping-note") == ""
    sticks(page, [0.0, 0.9, 0.7, -0.5])
    # Surge: -(-0.5) -> (0.5-0.12)/0.88 = 0.432; heave: (0.9-0.12)/0.88 = 0.886.
    drives(page, live, {"vx": 0.432, "vy": 0.0, "vz": 0.886, "vyaw": 0.0})
    page.uncheck("#gp-invert-vx")
    drives(page, live, {"vx": -0.432, "vy": 0.0, "vz": 0.886, "vyaw": 0.0})
    page.check("#gp-invert-vz")
    drives(page, live, {"vx": -0.432, "vy": 0.0, "vz": -0.886, "vyaw": 0.0})
    # Two vehicle axes on one stick axis: allowed, and said.
    page.select_option("#gp-axis-vyaw", "3")
    assert page.text_content("#gp-mapping-note") == "axis 3 drives surge and yaw."
    drives(page, live, {"vx": -0.432, "vy": 0.0, "vz": -0.886, "vyaw": -0.432})
    sticks(page, [0, 0, 0, 0])
    drives(page, live, NEUTRAL)


def trigger(page, b: int, value: float) -> None:
    page.evaluate("([b, v]) => { window.testPad.buttons[b] = { pressed: v > 0.5, value: v }; }", [b, value])


def test_the_triggers_drive_an_axis_as_one(pilot, live):
    page = pilot
    # Heave from the triggers: RT (button 7) down, LT (button 6) up.
    page.select_option("#gp-axis-vz", "b7-6")
    assert page.text_content("#gp-mapping-note") == ""
    trigger(page, 7, 0.8)
    # (0.8 - 0.12) / 0.88 = 0.773
    drives(page, live, {"vx": 0.0, "vy": 0.0, "vz": 0.773, "vyaw": 0.0})
    trigger(page, 6, 0.8)                      # both pulled: they cancel
    drives(page, live, NEUTRAL)
    trigger(page, 7, 0.0)
    drives(page, live, {"vx": 0.0, "vy": 0.0, "vz": -0.773, "vyaw": 0.0})
    page.check("#gp-invert-vz")
    drives(page, live, {"vx": 0.0, "vy": 0.0, "vz": 0.773, "vyaw": 0.0})
    trigger(page, 6, 0.05)                     # resting triggers stay inside the deadzone
    drives(page, live, NEUTRAL)
    # Kept across a reload, and the right stick's Y drives nothing now.
    ready(page, live, reload=True)
    assert page.input_value("#gp-axis-vz") == "b7-6" and page.is_checked("#gp-invert-vz")
    sticks(page, [0.0, 0.0, 0.0, 0.9])
    trigger(page, 7, 1.0)
    drives(page, live, {"vx": 0.0, "vy": 0.0, "vz": -1.0, "vyaw": 0.0})
    # A button of a pair that is also STOP is said.
    page.select_option("#gp-axis-vyaw", "b5-4")
    assert page.text_content("#gp-mapping-note") == ""
    page.check('#gp-stop-buttons input[data-button="5"]')
    assert page.text_content("#gp-mapping-note") == "5 (RB) drives yaw and is also STOP."
    trigger(page, 7, 0.0)
    trigger(page, 6, 0.0)
    sticks(page, [0, 0, 0, 0])
    drives(page, live, NEUTRAL)


def test_gain_buttons_step_the_gain_once_per_press(pilot, live):
    page = pilot
    assert page.text_content("#gp-gain") == "100 %"
    sticks(page, [0.0, -1.0, 0.0, 0.0])
    drives(page, live, {"vx": 1.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    # D-pad down (13), held: one step, not one per poll.
    button(page, 13, True)
    drives(page, live, {"vx": 0.75, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    after_ticks(page, 4)
    assert page.text_content("#gp-gain") == "75 %"
    button(page, 13, False)
    after_ticks(page, 2)
    tap(page, 13)
    drives(page, live, {"vx": 0.5, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    assert page.text_content("#gamepad") == "Gamepad: test pad. Gain 50 %."
    tap(page, 12)
    drives(page, live, {"vx": 0.75, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    # Other buttons and other steps, chosen on the page.
    page.select_option("#gp-gain-down", "4")
    set_number(page, "#gp-gain-steps", "10 40 80")
    assert page.input_value("#gp-gain-steps") == "10, 40, 80"
    drives(page, live, {"vx": 0.8, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})   # nearest step to 75 %
    tap(page, 13)   # no longer a gain button
    tap(page, 4)
    drives(page, live, {"vx": 0.4, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    # A STOP button is refused as a gain button.
    page.select_option("#gp-gain-up", "1")
    assert page.input_value("#gp-gain-up") == "12"
    assert "STOP button" in page.text_content("#gp-msg")
    sticks(page, [0, 0, 0, 0])
    drives(page, live, NEUTRAL)


def test_settings_survive_a_reload_and_bad_stored_values_fall_back_to_defaults(pilot, live):
    page = pilot
    set_number(page, "#gp-deadzone", "0.3")
    page.select_option("#gp-axis-vy", "2")
    page.check("#gp-invert-vy")
    page.select_option("#gp-axis-vyaw", "0")
    tap(page, 13)
    ready(page, live, reload=True)
    assert page.input_value("#gp-deadzone") == "0.3"
    assert page.input_value("#gp-axis-vy") == "2"
    assert page.is_checked("#gp-invert-vy")
    assert page.text_content("#gp-gain") == "75 %"
    # Sway from axis 2 inverted: -(0.65-0.3)/0.7 * 0.75 = -0.375; yaw from axis 0: 0.
    sticks(page, [0.1, 0.0, 0.65, 0.0])
    drives(page, live, {"vx": 0.0, "vy": -0.375, "vz": 0.0, "vyaw": 0.0})
    sticks(page, [0, 0, 0, 0])
    drives(page, live, NEUTRAL)

    # Stored values that are not valid are ignored one by one, the valid ones kept.
    page.evaluate("""() => localStorage.setItem("rovlink.gamepad.v1", JSON.stringify({
      axes: { vx: { axis: 99, invert: "yes" }, vy: { axis: 2, invert: true } },
      deadzone: 7, expo: 0.3, gainSteps: [0, 50], gainStep: 9, gainUp: 1, stopButtons: [] }))""")
    ready(page, live, reload=True)
    assert page.input_value("#gp-deadzone") == "0.12"
    assert page.input_value("#gp-expo") == "0.3"
    assert page.input_value("#gp-axis-vx") == "1"
    assert page.is_checked("#gp-invert-vx")
    assert page.input_value("#gp-axis-vy") == "2"
    assert page.input_value("#gp-gain-steps") == "25, 50, 75, 100"
    assert page.text_content("#gp-gain") == "100 %"
    assert page.text_content("#gp-stop") == "1 (B)"
    assert page.input_value("#gp-gain-up") == "12"

    # Not JSON at all: the defaults, and no script error (the fixture checks).
    page.evaluate("() => localStorage.setItem('rovlink.gamepad.v1', '{not json')")
    ready(page, live, reload=True)
    assert page.input_value("#gp-axis-vy") == "0"
    page.click("#gp-reset")   # and Reset brings back the defaults too
    assert page.input_value("#gp-deadzone") == "0.12"
    stored = json.loads(page.evaluate("localStorage.getItem('rovlink.gamepad.v1')"))
    assert stored["deadzone"] == 0.12 and stored["stopButtons"] == [1]


def test_the_stop_button_is_the_pilots_choice_and_capture_drives_nothing(pilot, live):
    page = pilot
    sticks(page, [0.0, -0.8, 0.0, 0.0])
    drives(page, live, {"vx": 0.773, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    # While the page waits for the button, the pad drives nothing.
    page.click("#gp-capture-stop")
    assert page.evaluate("document.body.dataset.gamepadCapture") == "stop"
    drives(page, live, NEUTRAL)
    sticks(page, [0, 0, 0, 0])
    # ... and B, STOP until now, still stops.
    before = stops(live)
    button(page, 1, True)
    assert wait_for(lambda: stops(live) == before + 1, 3), "B did not stop during the capture"
    button(page, 1, False)
    page.wait_for_function("document.body.dataset.gamepadCapture === undefined")
    assert page.text_content("#gp-stop") == "1 (B)"
    # Choose Y (3) by pressing it: the press that chooses it is not a STOP.
    page.click("#gp-capture-stop")
    before = stops(live)
    button(page, 3, True)
    page.wait_for_function("document.getElementById('gp-stop').textContent === '3 (Y)'")
    assert page.evaluate("document.body.dataset.gamepadCapture") is None
    after_ticks(page, 4)
    button(page, 3, False)
    assert stops(live) == before
    # B no longer stops; Y does, once per press.
    tap(page, 1)
    after_ticks(page, 3)
    assert stops(live) == before
    button(page, 3, True)
    assert wait_for(lambda: stops(live) == before + 1, 3), "Y did not stop"
    after_ticks(page, 4)
    assert stops(live) == before + 1
    button(page, 3, False)
    # Ticked on the page: LB (4) as well; the last STOP button cannot be unticked.
    page.check("#gp-stop-buttons input[data-button='4']")
    page.uncheck("#gp-stop-buttons input[data-button='3']")
    assert page.text_content("#gp-stop") == "4 (LB)"
    page.click("#gp-stop-buttons input[data-button='4']")   # refused: stays ticked
    assert page.is_checked("#gp-stop-buttons input[data-button='4']")
    assert page.text_content("#gp-stop") == "4 (LB)"
    tap(page, 3)
    assert stops(live) == before + 1, "Y, unticked, still stops"
    button(page, 4, True)
    assert wait_for(lambda: stops(live) == before + 2, 3), "LB did not stop"
    button(page, 4, False)
    # Escape ends a capture with nothing changed; so does closing the settings, and the
    # status line says while the sticks are dead.
    page.click("#gp-capture-stop")
    assert page.text_content("#gamepad").startswith("Gamepad: waiting for the STOP button")
    page.keyboard.press("Escape")
    assert page.evaluate("document.body.dataset.gamepadCapture") is None
    assert page.text_content("#gamepad") == "Gamepad: test pad."
    page.click("#gp-capture-gainUp")
    page.click("#gamepad-settings > summary")
    page.wait_for_function("document.body.dataset.gamepadCapture === undefined")
    assert page.text_content("#gamepad") == "Gamepad: test pad."
    page.click("#gamepad-settings > summary")
    tap(page, 2)
    assert page.text_content("#gp-stop") == "4 (LB)"


def test_a_pad_that_goes_sends_neutral(pilot, live):
    page = pilot
    sticks(page, [0.5, -1.0, 0.0, 0.0])
    drives(page, live, {"vx": 1.0, "vy": 0.432, "vz": 0.0, "vyaw": 0.0})
    page.evaluate("""() => {
      window.sentVelocity = [];
      window.testPad.connected = false;
      window.dispatchEvent(Object.assign(new Event("gamepaddisconnected"), { gamepad: window.testPad }));
    }""")
    # The page itself sends neutral at once (not the server's dead man later).
    page.wait_for_function("window.sentVelocity.length > 0")
    first = page.evaluate("window.sentVelocity[0]")
    assert {k: first[k] for k in NEUTRAL} == NEUTRAL
    drives(page, live, NEUTRAL)
    assert page.text_content("#gamepad") == "No gamepad."
    assert page.evaluate("window.rovGamepad.wish()") is None
    # A pad that the browser stops listing, without any event: neutral too.
    page.evaluate(FAKE_GAMEPAD, "second pad")
    sticks(page, [0.0, -1.0, 0.0, 0.0])
    drives(page, live, {"vx": 1.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0})
    page.evaluate("() => { window.sentVelocity = []; navigator.getGamepads = () => []; }")
    page.wait_for_function("window.sentVelocity.length > 0")
    first = page.evaluate("window.sentVelocity[0]")
    assert {k: first[k] for k in NEUTRAL} == NEUTRAL
    drives(page, live, NEUTRAL)
    after_ticks(page, 3)
    assert all({k: m[k] for k in NEUTRAL} == NEUTRAL for m in page.evaluate("window.sentVelocity"))
    # Still listed but marked disconnected, without any event: neutral too.
    page.evaluate(FAKE_GAMEPAD, "third pad")
    sticks(page, [0.0, 0.0, 1.0, 0.0])
    drives(page, live, {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 1.0})
    page.evaluate("() => { window.sentVelocity = []; window.testPad.connected = false; }")
    page.wait_for_function("window.sentVelocity.length > 0")
    first = page.evaluate("window.sentVelocity[0]")
    assert {k: first[k] for k in NEUTRAL} == NEUTRAL
    drives(page, live, NEUTRAL)
