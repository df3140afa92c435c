"""The pilot's cockpit in headless Chromium, against the whole system as
`rovlink demo` wires it (Stack, viser scene, web app):

- at 1366x768 and 1920x1080 what a pilot acts on (STOP, arm/mode, control, link
  state, the instruments, the latest picture) is on screen without scrolling,
  nothing of it overlapping; the screenshots go to docs/ when ROVLINK_DOCS_SHOTS=1;
- the instruments follow the replies and go grey, marked old, on a cut link,
  and the log keeps the loss as an alert, apart and filterable;
- pictures: the last complete one stays up, with a capture window that holds
  the ROV's real capture time; older ones can be looked back at and saved
  (PNG + JSON sidecar);
- the wish is shown in m/s from the vehicle model.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rovlink import debt
from rovlink.rov.vehicle import BlueRovParams

from ..helpers import CHROMIUM, CHROMIUM_ARGS, needs_chromium
from .conftest import running_console, wait_for
from .pages import after_ticks, after_updates, take_control

pytestmark = [pytest.mark.browser, needs_chromium]

DOCS = Path(__file__).resolve().parents[2] / "docs"
SIZES = [(1366, 768), (1920, 1080)]
# What a pilot must reach without scrolling, and must not find covered by another of them.
MUST_SEE = ["#stop", "#arm", "#disarm", "#mode-select", "#set-mode", "#release", "#control-text", "#link-up", "#armed", "#mode",
            "#attitude-indicator", "#heading-tape", "#depth-tape", "#speed-forward", "#speed-vertical", "#wish",
            "#image-done", "#image-done-meta", "#image-save", "#scene"]


@pytest.fixture(scope="module")
def live():
    debt.decode(debt.encode(np.zeros((16, 16, 3), np.uint8), 100))  # compile the codec here, not in a wait
    with running_console(scene=True) as console:
        # The ROV's real capture times, to check the console's stamps against.
        node = console.stack.node
        grab = node.grab
        console.captures = []
        lock = threading.Lock()

        def recorded(snap):
            with lock:
                console.captures.append(time.time())
            return grab(snap)

        node.grab = recorded
        yield console


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def open_page(browser, live):
    contexts, errors = [], []

    def open_(width=1366, height=768, scene=False):
        # The scene drawn where the layout is the point; elsewhere off (?scene=off): drawn
        # without a graphics card it takes a core from the rest of the suite.
        context = browser.new_context(viewport={"width": width, "height": height}, accept_downloads=True)
        contexts.append(context)
        page = context.new_page()
        page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
        page.goto(live.url + ("/" if scene else "/?scene=off"))
        page.wait_for_function("document.body.dataset.clientId !== undefined")
        return page

    yield open_
    for context in contexts:
        context.close()
    wait_for(lambda: not live.app.state.desk.status()["held"], 10)
    assert not errors, errors


def complete_pictures(live, n: int, timeout_s: float = 60) -> list[dict]:
    import httpx

    def enough():
        kept = [e for e in httpx.get(live.url + "/api/images").json() if not e["partial"]]
        return kept if len(kept) >= n else None

    kept = wait_for(enough, timeout_s, 0.3)
    assert kept, "the pictures did not arrive"
    return kept


def boxes(page, selectors):
    return page.evaluate("""(sels) => sels.map((s) => {
        const el = document.querySelector(s);
        if (!el) return [s, null];
        const r = el.getBoundingClientRect();
        const style = getComputedStyle(el);
        const shown = style.display !== 'none' && style.visibility !== 'hidden' && !el.closest('[hidden]');
        return [s, shown ? [r.left, r.top, r.right, r.bottom] : null];
    })""", selectors)


def overlap(a, b) -> bool:
    return min(a[2], b[2]) - max(a[0], b[0]) > 0.5 and min(a[3], b[3]) - max(a[1], b[1]) > 0.5


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_everything_a_pilot_acts_on_is_on_screen_without_scrolling(open_page, live, size):
    width, height = size
    complete_pictures(live, 1)
    page = open_page(width, height, scene=True)
    take_control(page)
    page.wait_for_function("document.getElementById('image-done').naturalWidth > 0", timeout=30000)
    page.wait_for_function("document.getElementById('inst-attitude').dataset.valid === '1'")
    found = dict(boxes(page, MUST_SEE))
    for sel, box in found.items():
        assert box is not None, f"{sel} is not shown at {width}x{height}"
        left, top, right, bottom = box
        assert right - left >= 8 and bottom - top >= 8, f"{sel} is too small: {box}"
        assert left >= 0 and top >= 0 and right <= width + 0.5 and bottom <= height + 0.5, \
            f"{sel} at {box} is outside the {width}x{height} window"
    # Nothing of it covers another (the scene holds none of them).
    names = [s for s in MUST_SEE if s != "#scene"]
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not overlap(found[a], found[b]), f"{a} {found[a]} overlaps {b} {found[b]}"
        assert not overlap(found[a], found["#scene"]), f"{a} covers the 3D view"
    # Nothing the top bar says is cut, also with every badge it may show up at once (set and
    # measured in one go: the next telemetry puts the badges back as they are).
    cut = page.evaluate("""(() => {
        for (const id of ['failsafe', 'hold', 'stopping', 'attitude', 'replaying']) document.getElementById(id).hidden = false;
        const bar = document.getElementById('topbar').getBoundingClientRect();
        return [...document.querySelectorAll('#topbar > *, #topbar .group > *')]
          .filter((e) => !e.hidden && e.offsetParent !== null)
          .filter((e) => { const r = e.getBoundingClientRect();
                           return e.scrollWidth > e.clientWidth + 1 || r.right > window.innerWidth + 0.5 || r.left < 0
                             || r.bottom > bar.bottom + 0.5; })
          .map((e) => e.id || e.className);
    })()""")
    assert not cut, f"cut in the top bar at {width}x{height}: {cut}"
    # ...and the bar keeps its height whatever it shows: nothing below it moves when a badge comes.
    heights = page.evaluate("""(() => {
        const bar = document.getElementById('topbar'), ids = ['failsafe', 'hold', 'stopping', 'attitude', 'replaying'];
        const h = [];
        for (const hidden of [true, false, true]) {
          for (const id of ids) document.getElementById(id).hidden = hidden;
          h.push(bar.getBoundingClientRect().height);
        }
        return h;
    })()""")
    assert len(set(heights)) == 1, heights
    # The small picture says which picture it is (the next one's first bytes may not be decoded yet).
    page.wait_for_function("/^showing #\\d+ from \\d+ bytes$/.test(document.getElementById('image-decoded').textContent)")
    said, key = page.evaluate("[document.getElementById('image-decoded').textContent, "
                              "document.getElementById('image').dataset.key]")  # read together
    assert said.split()[1] == "#" + key.split(":")[0], (said, key)
    # The driving keys are in sight beside the instruments, not only at the panel's bottom.
    hint = page.locator("#key-hint")
    assert hint.is_visible() and "STOP" in hint.text_content() and "surge" in hint.text_content()
    box = hint.bounding_box()
    assert box["y"] + box["height"] <= height and box["x"] + box["width"] <= width, box
    # The page itself does not scroll; the 3D view keeps most of the width.
    assert page.evaluate("document.scrollingElement.scrollHeight <= window.innerHeight + 1")
    scene = found["#scene"]
    assert scene[2] - scene[0] >= 0.6 * width and scene[3] - scene[1] >= 0.5 * height, scene
    # STOP is where a hand finds it and works from this page at this size.
    stops = sum(o["kind"] == "STOP" for o in live.operator.orders_state())
    page.click("#stop")
    assert wait_for(lambda: sum(o["kind"] == "STOP" for o in live.operator.orders_state()) == stops + 1, 5)
    if os.environ.get("ROVLINK_DOCS_SHOTS"):
        # The README's pictures: the scene drawn, and viser's notice that WebGL
        # runs in software (true here, not on a pilot's laptop) closed, as a pilot would.
        page.wait_for_timeout(1500)
        notice = page.frame_locator("#scene").get_by_text("Software WebGL rendering detected")
        if notice.count():
            notice.locator("xpath=ancestor::div[contains(@class, 'Notification-root')][1]//button").first.click()
            page.wait_for_timeout(800)
        DOCS.mkdir(exist_ok=True)
        (DOCS / f"cockpit-{width}x{height}.png").write_bytes(page.screenshot())


def test_instruments_follow_the_replies_and_go_grey_on_a_cut_link(open_page, live):
    page = open_page()
    take_control(page)
    page.wait_for_function("document.getElementById('inst-depth').dataset.valid === '1'")
    reply_z = live.operator.pose_state()["received"]["z_m"]
    text = page.text_content("#depth-text")
    assert text.startswith(f"depth {reply_z:.1f} m") or text.startswith("depth "), text
    # Armed, turn right for a while: the heading shown follows the replies.
    page.click("#arm")
    page.wait_for_function("document.getElementById('armed').textContent === 'ARMED'", timeout=15000)
    page.keyboard.down("KeyE")
    page.wait_for_function("document.getElementById('speed-yaw').textContent !== '0 °/s'", timeout=10000)
    page.keyboard.up("KeyE")
    assert wait_for(lambda: live.operator.state()["velocity_wish"]["vyaw"] == 0, 3)

    def heading_shown_is_the_replys() -> bool:
        # (The vehicle may still be slowing its turn: the reply's heading is read each time.)
        yaw = live.operator.pose_state()["received"]["yaw_deg"] % 360
        shown = float(page.text_content("#heading-text")[len("heading "):].split("°")[0])
        return abs((shown - yaw + 180) % 360 - 180) <= 1.5

    assert wait_for(heading_shown_is_the_replys, 10), (page.text_content("#heading-text"),
                                                       live.operator.pose_state()["received"])
    try:
        live.set_link_loss(1.0)
        page.wait_for_function("document.body.dataset.link === 'lost'", timeout=15000)
        for inst in ("inst-attitude", "inst-heading", "inst-depth"):
            assert page.get_attribute(f"#{inst}", "data-valid") == "0"
            assert "stale" in page.get_attribute(f"#{inst}", "class")
        assert page.text_content("#speed-forward") == "—"
        assert "stale" in page.get_attribute("#image-done-frame", "class")
        # The loss is an alert in the log, shown apart, and the filter keeps only alerts.
        page.wait_for_function("[...document.querySelectorAll('#alerts li')].some((li) => li.textContent.includes('LINK LOST'))")
        page.select_option("#log-level", "alert")
        classes = page.eval_on_selector_all("#log li", "lis => lis.map((li) => li.className)")
        assert classes and all(c.split()[0] == "alert" for c in classes), classes
        # The loss: not cleared while it lasts (once seen cleared in a newcomer's run: the texts say which).
        assert "alert" in classes, (classes, page.eval_on_selector_all("#log li", "lis => lis.map((li) => li.textContent)"),
                                    [e["text"] for e in live.operator.state()["log"]][-8:])
        # Clock times, not session seconds.
        first = page.text_content("#log li")
        assert first[2] == ":" and first[5] == ":", first
    finally:
        live.set_link_loss(0.0)
    page.wait_for_function("document.body.dataset.link !== 'lost'", timeout=15000)
    page.wait_for_function("document.getElementById('inst-attitude').dataset.valid === '1'", timeout=10000)
    page.select_option("#log-level", "all")
    page.fill("#log-filter", "link")
    lines = page.eval_on_selector_all("#log li", "lis => lis.map((li) => li.textContent)")
    assert lines and all("link" in line.lower() for line in lines), lines
    assert any("link back" in line for line in lines), lines
    # The loss's alert, still at the top, is marked cleared with the time it ended.
    page.wait_for_function("[...document.querySelectorAll('#alerts li')].some((li) => li.textContent.includes('LINK LOST')"
                           " && li.classList.contains('cleared') && li.textContent.includes('cleared'))")
    assert not page.evaluate("[...document.querySelectorAll('#alerts li')].some((li) => li.textContent.includes('LINK LOST')"
                             " && !li.classList.contains('cleared'))")
    cleared = [e for e in live.operator.log_entries() if e["cause"] == "link"]
    assert cleared and all(e["cleared_wall"] is not None and e["cleared_wall"] >= e["wall"] for e in cleared), cleared


def test_pictures_keep_their_capture_and_can_be_looked_back_at_and_saved(open_page, live, tmp_path):
    from PIL import Image

    kept = complete_pictures(live, 3, 90)
    # Each capture window holds one of the ROV's real capture times.
    captures = list(live.captures)
    for entry in kept[1:]:
        c = entry["capture"]
        assert c["not_before_wall"] is not None and c["how"] in ("prefetch", "request"), c
        assert c["not_before_wall"] <= c["wall"] <= c["not_after_wall"]
        assert any(c["not_before_wall"] - 0.05 <= t <= c["not_after_wall"] + 0.05 for t in captures), (c, captures)
        assert c["pose"] is not None
    page = open_page()
    page.wait_for_function("document.querySelectorAll('#image-strip button').length >= 3", timeout=30000)
    # The large picture is the newest complete one: it catches up with the newest there is
    # now (they come every second or two here), and is the newest the page knows of.
    newest_now = complete_pictures(live, 3)[-1]["n"]
    page.wait_for_function(f"+document.getElementById('image-done').dataset.n >= {newest_now}", timeout=15000)
    shown = page.evaluate("""() => {
        const strip = [...document.querySelectorAll('#image-strip button:not(.partial)')].map((b) => +b.dataset.n);
        return [+document.getElementById('image-done').dataset.n, Math.max(...strip)];
    }""")
    assert shown[0] >= shown[1] or shown[1] - shown[0] <= 1, shown  # a new one may have come between the two reads
    meta = page.text_content("#image-done-meta")
    assert meta.startswith("captured ") and " ago at x " in meta and " B" in meta, meta
    # Look back at an earlier picture (not the oldest: here pictures come so fast that
    # the oldest kept is soon dropped).
    oldest = page.get_attribute("#image-strip button:nth-child(3)", "data-n")
    page.click(f'#image-strip button[data-n="{oldest}"]')
    page.wait_for_function(f"document.getElementById('image-done').dataset.n === '{oldest}'")
    assert page.is_visible("#image-latest")
    assert "looking back" in page.text_content("#image-done-id")
    # Save: a PNG and its JSON sidecar.
    downloads = []
    page.on("download", lambda dl: downloads.append(dl))
    page.click("#image-save")
    assert wait_for(lambda: page.wait_for_timeout(100) or len(downloads) >= 2, 10), downloads
    files = {}
    for dl in downloads:
        path = tmp_path / dl.suggested_filename
        dl.save_as(path)
        files[path.suffix] = path
    assert set(files) == {".png", ".json"}, files
    meta = json.loads(files[".json"].read_text())
    assert str(meta["n"]) == oldest and meta["picture"] == files[".png"].name
    # One picture number everywhere: the page says which went, the file is named by it,
    # its thumbnail shows it, and the log's line for it says it.
    assert page.get_attribute("#image-saved", "data-n") == oldest
    assert page.text_content("#image-saved").startswith(f"#{oldest} saved")
    assert f"-{oldest}-" in files[".png"].name
    assert page.text_content(f'#image-strip button[data-n="{oldest}"] .n') == f"#{oldest}"
    assert any(e["text"].startswith(f"picture #{oldest} complete") for e in live.operator.log_entries()), \
        [e["text"] for e in live.operator.log_entries() if "picture" in e["text"]][-5:]
    assert meta["bytes"] > 0 and "capture" in meta and "stream" not in meta
    with Image.open(files[".png"]) as im:
        assert im.size == (meta["width"], meta["height"]) == (320, 240)
        # The PNG carries its metadata too, should it travel without the sidecar.
        assert json.loads(im.text["rovlink"])["n"] == meta["n"]
    page.click("#image-latest")
    page.wait_for_function("document.getElementById('image-latest').hidden")


def steady_speed(fraction: float) -> float:
    p = BlueRovParams()
    thrust = p.thrust_surge_n * fraction
    return (-p.drag_lin_surge + math.sqrt(p.drag_lin_surge ** 2 + 4 * p.drag_quad_surge * thrust)) / (2 * p.drag_quad_surge)


def test_the_wish_is_shown_in_metres_per_second(open_page, live):
    page = open_page()
    take_control(page)
    gain = float(page.input_value("#gain"))
    page.keyboard.down("KeyW")
    try:
        page.wait_for_function("document.getElementById('wish').textContent.includes('forward')", timeout=5000)
        text = page.text_content("#wish")
    finally:
        page.keyboard.up("KeyW")
    assert text == f"≈ forward {steady_speed(gain):.2f} m/s", text
    page.wait_for_function("document.getElementById('wish').textContent === 'neutral'", timeout=5000)


def in_sight(page, selector: str) -> list[str]:
    """What keeps `selector` from being read where it is, the page unscrolled: outside the
    window, cut by itself or by a box it sits in (the panel's own scrolling included), or
    covered by something drawn over it. Empty when it reads whole."""
    return page.evaluate("""(sel) => {
        const el = document.querySelector(sel), why = [];
        if (!el) return [`${sel} missing`];
        const r = el.getBoundingClientRect();
        if (r.width < 1 || r.height < 1) return [`${sel} not shown`];
        if (r.left < 0 || r.top < 0 || r.right > innerWidth + 0.5 || r.bottom > innerHeight + 0.5)
          why.push(`${sel} at ${[r.left, r.top, r.right, r.bottom].map(Math.round)} is outside the window`);
        if (el.scrollWidth > el.clientWidth + 1 || el.scrollHeight > el.clientHeight + 1)
          why.push(`${sel} is cut (${el.scrollWidth}x${el.scrollHeight} in ${el.clientWidth}x${el.clientHeight})`);
        for (let a = el.parentElement; a; a = a.parentElement) {
          const s = getComputedStyle(a);
          if (s.overflowX === 'visible' && s.overflowY === 'visible') continue;
          const b = a.getBoundingClientRect();
          if (r.top < b.top - 0.5 || r.bottom > b.bottom + 0.5 || r.left < b.left - 0.5 || r.right > b.right + 0.5)
            why.push(`${sel} is cut by ${a.id || a.tagName}`);
          if (a.scrollTop) why.push(`${a.id || a.tagName} is scrolled`);
        }
        const hit = document.elementFromPoint((r.left + r.right) / 2, (r.top + r.bottom) / 2);
        if (!hit || !(el === hit || el.contains(hit))) why.push(`${sel} is covered by ${hit && (hit.id || hit.tagName)}`);
        if (document.scrollingElement.scrollTop) why.push('the page is scrolled');
        return why;
    }""", selector)


def test_every_orders_fate_is_read_beside_its_control_at_1366x768_without_scrolling(open_page, live):
    complete_pictures(live, 1)
    page = open_page(1366, 768, scene=True)
    take_control(page)
    page.wait_for_function("document.getElementById('image-done').naturalWidth > 0", timeout=30000)
    # Each control clicked where it is (a script's click, which scrolls nothing), then its fate read.
    orders = [("#arm", "#arm-fate", "followed"), ("#set-mode", "#mode-fate", "followed"),
              ("#apply-image", "#image-fate", "acknowledged"), ("#goto-go", "#goto-fate", "acknowledged arrived"),
              ("#stop", "#stop-fate", "acknowledged")]
    for control, fate, settled in orders:
        before = int(page.get_attribute(fate, "data-id") or 0)
        assert not in_sight(page, control), in_sight(page, control)
        page.evaluate("(sel) => document.querySelector(sel).click()", control)
        # Said at once, and read where it is until it settles.
        page.wait_for_function("([sel, before]) => +(document.querySelector(sel).dataset.id || 0) > before",
                               arg=[fate, before], timeout=15000)
        assert not in_sight(page, fate), (page.text_content(fate), in_sight(page, fate))
        page.wait_for_function("([sel, states]) => states.split(' ').includes(document.querySelector(sel).dataset.state)",
                               arg=[fate, settled], timeout=20000)
        problems = in_sight(page, fate)
        assert not problems, (page.text_content(fate), problems)
    assert page.text_content("#stop-fate").startswith("STOP ✓ holding in "), page.text_content("#stop-fate")
    # The top bar with its fates, every badge it may show and the longest control text: nothing cut.
    cut = page.evaluate("""(() => {
        for (const id of ['failsafe', 'hold', 'stopping', 'attitude', 'replaying', 'cancel-stop'])
          document.getElementById(id).hidden = false;
        document.getElementById('control-text').textContent = 'You have control: centre the sticks to drive.';
        const bar = document.getElementById('topbar').getBoundingClientRect();
        return [...document.querySelectorAll('#topbar > *, #topbar .group > *')]
          .filter((e) => !e.hidden && e.offsetParent !== null)
          .filter((e) => { const r = e.getBoundingClientRect();
                           return e.scrollWidth > e.clientWidth + 1 || r.right > window.innerWidth + 0.5 || r.left < 0
                             || r.bottom > bar.bottom + 0.5; })
          .map((e) => e.id || e.className);
    })()""")
    assert not cut, f"cut in the top bar: {cut}"


CENTRE = "document.getElementById('control-text').textContent"


def test_a_key_held_through_a_stop_or_a_failsafe_hold_is_told_to_centre(open_page, live):
    page = open_page()
    take_control(page)
    page.wait_for_function(f"{CENTRE} === 'You have control.'")
    page.keyboard.down("KeyW")
    try:
        assert wait_for(lambda: live.operator.state()["velocity_wish"]["vx"] > 0, 5)
        # STOP with the key still held: the held key is no drive, and the page says why.
        page.keyboard.press("Space")
        page.wait_for_function(f"{CENTRE} === 'You have control: centre the sticks to drive.'", timeout=10000)
        assert "centre-to-drive" in page.get_attribute("#control-text", "class")
        assert wait_for(lambda: live.operator.state()["velocity_wish"]["vx"] == 0, 5)
        after_ticks(page, 5)  # the key is still held, its wish still sent: still ignored, still said
        assert page.evaluate(CENTRE) == "You have control: centre the sticks to drive."
        assert live.operator.state()["velocity_wish"]["vx"] == 0
    finally:
        page.keyboard.up("KeyW")
    page.wait_for_function(f"{CENTRE} === 'You have control.'", timeout=10000)
    # A failsafe's HOLD: the key held while the link is cut and after it returns.
    page.keyboard.down("KeyW")
    try:
        assert wait_for(lambda: live.operator.state()["velocity_wish"]["vx"] > 0, 5)
        try:
            live.set_link_loss(1.0)
            page.wait_for_function("document.body.dataset.link === 'lost'", timeout=15000)
        finally:
            live.set_link_loss(0.0)
        page.wait_for_function("!document.getElementById('hold').hidden", timeout=15000)
        page.wait_for_function(f"{CENTRE} === 'You have control: centre the sticks to drive.'", timeout=10000)
        assert live.operator.pose_state()["hold"], "the ROV left its HOLD with the key held"
    finally:
        page.keyboard.up("KeyW")
    page.wait_for_function(f"{CENTRE} === 'You have control.'", timeout=10000)
    assert wait_for(lambda: not live.operator.pose_state()["hold"], 10), "centring did not release the HOLD"


def test_the_top_bars_chips_stay_long_enough_to_read(open_page, live):
    page = open_page()
    take_control(page)
    page.keyboard.down("KeyW")
    try:
        page.keyboard.press("Space")  # STOP, the key held: the ROV holds until it is let go
        page.wait_for_function("!document.getElementById('hold').hidden", timeout=10000)
        assert page.text_content("#hold") == "HOLD"
    finally:
        page.keyboard.up("KeyW")
    # Let go: the ROV leaves its HOLD at its next poll, but the chip stays, saying it has ended.
    assert wait_for(lambda: not live.operator.pose_state()["hold"], 10), "centring did not release the HOLD"
    # (Read in one go: the page shows the HOLD as ended, not gone with it.)
    page.wait_for_function("(() => { const c = document.getElementById('hold');"
                           " return !c.hidden && c.textContent === 'HOLD released'; })()", timeout=15000)
    # STOP's own fate stays beside it, settled, as long as no newer STOP supersedes it.
    after_updates(page, 20)
    assert page.get_attribute("#stop-fate", "data-state") == "acknowledged"
    assert page.is_visible("#stop-fate") and page.text_content("#stop-fate").startswith("STOP ✓ holding in ")
    # ...and the ended chip goes in the end.
    page.wait_for_function("document.getElementById('hold').hidden", timeout=30000)


def test_a_degraded_link_says_which_figure_crossed_which_threshold(open_page, live):
    page = open_page()
    try:
        live.set_link_loss(0.3)
        page.wait_for_function("document.getElementById('link-up').textContent.startsWith('link degraded: ')",
                               timeout=30000)
        badge, title, why = page.evaluate("['link-up', 'link-why'].map((id) => document.getElementById(id))"
                                          ".flatMap((e, i) => i ? [e.textContent] : [e.textContent, e.title])")
    finally:
        live.set_link_loss(0.0)
    assert badge.endswith("% lost"), badge
    assert " replies lost in the last 10 s (" in title and "degraded from 10%" in title, title
    assert why == title
    assert any(e["text"].startswith("link degraded: ") and "replies lost" in e["text"] for e in live.operator.log_entries())


def test_next_image_says_what_it_skipped_beside_the_button_and_the_log_says_the_pilot_skipped_it(open_page, live):
    import re

    import httpx
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    complete_pictures(live, 1)
    page = open_page(1366, 768, scene=True)
    take_control(page)
    # A picture part-way in (they come every second or two here): skip it.
    page.wait_for_function("(() => { const c = document.getElementById('image-card').dataset;"
                           " return +c.receivedBytes > 0 && +c.receivedBytes < +c.totalBytes; })()", timeout=30000)
    assert not in_sight(page, "#next-image"), in_sight(page, "#next-image")
    page.evaluate("document.getElementById('next-image').click()")
    page.wait_for_function("document.getElementById('next-image-fate').dataset.state === 'skipped'", timeout=15000)
    fate = page.text_content("#next-image-fate")
    assert not in_sight(page, "#next-image-fate"), (fate, in_sight(page, "#next-image-fate"))
    said = re.fullmatch(r"skipped (?:picture #(\d+) at (\d+)(?: of \d+)? B|a picture not yet shown at (\d+) B|"
                        r"before its first bytes came), next one coming \d\d:\d\d:\d\d", fate)
    assert said, fate
    lines = [e["text"] for e in live.operator.log_entries()]
    skipped = [t for t in lines if "skipped by the pilot" in t or t.startswith("the pilot skipped")]
    assert skipped and skipped[-1].endswith(": the next one is coming"), lines[-5:]
    if said.group(1):
        n = said.group(1)
        assert skipped[-1].startswith(f"picture #{n} skipped by the pilot at {said.group(2)}"), skipped
        # Kept as it was when skipped, and said so where it is looked back at.
        kept = {str(e["n"]): e for e in httpx.get(live.url + "/api/images").json()}
        assert n in kept and kept[n]["partial"] and kept[n]["skipped"], kept.get(n)
        try:
            page.wait_for_function(f"(document.querySelector('#image-strip button[data-n=\"{n}\"]') || {{}}).title"
                                   " ?.includes('(skipped by the pilot, partial)')", timeout=15000)
        except PlaywrightTimeout:  # (seen twice under a loaded suite, not alone: say what the page had)
            seen = page.evaluate("({key: page.historyKey, asked: historyAsked, shown: historyShown,"
                                 " history: (page.history || []).map((e) => [e.n, e.partial, e.skipped]).slice(-4),"
                                 " strip: [...document.querySelectorAll('#image-strip button')].slice(0, 4)"
                                 ".map((b) => b.title), telemetry: document.body.dataset.telemetry,"
                                 " closes: document.body.dataset.socketCloses})")
            kept_now = [[e["n"], e["partial"], e["skipped"]] for e in httpx.get(live.url + "/api/images").json()][-4:]
            pytest.fail(f"the strip never said #{n} skipped: page {seen}; console {kept_now}")
    assert not [t for t in lines if "good enough" in t], lines


def test_before_the_first_picture_the_page_shows_no_byte_count_of_nothing(open_page, live):
    import httpx

    assert "0 / ? bytes" not in httpx.get(live.url + "/").text
    page = open_page()
    # The image state as telemetry gives it before any byte of a picture has come.
    shown = page.evaluate("""() => {
        renderImageProgress({img: null, received_bytes: 0, total_bytes: null, complete: false, decoded_bytes: 0,
                             serial: 0, images_completed: 0, capture: null, settings: null});
        return document.getElementById('image-bytes').textContent;
    }""")
    assert shown == "", shown


def test_a_page_opened_with_scene_off_offers_the_scene_on_its_own_to_watch(open_page, live):
    """?scene=off: the 3-D scene is not drawn in the page (a laptop without a graphics card
    spends a core on it), only offered in a tab of its own, without the page's key (it
    watches); the rest of the cockpit is the same."""
    page = open_page()
    page.wait_for_function("document.body.dataset.scene === 'off'")
    assert page.is_hidden("#scene") and page.is_visible("#no-scene")
    assert "3-D scene is off" in page.text_content("#no-scene")
    href = page.get_attribute("#no-scene a", "href")
    port = live.scene.url.rsplit(":", 1)[1].strip("/")
    assert href == f"http://localhost:{port}/", href
    take_control(page)
    assert page.is_enabled("#arm")
