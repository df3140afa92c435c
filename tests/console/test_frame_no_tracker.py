""""Frame it" on a ROV without a tracker (issue 38, docs/PROTOCOL.md §10): the whole running
system (the simulated ROV recognising objects, version 2, no tracker), the page in headless
Chromium.  The link carries FOLLOW, so the first Frame it asks for it; the ROV rejects it
(it does not follow), and the console sends the ROI alone, from the same pilot, so the next
picture still frames the object.  Beside the button the pilot reads both orders' fates; the
log says it once; a later Frame it sends the ROI alone at once, saying why."""

from __future__ import annotations

import pytest

from rovlink.console.session.base import OrderError

from ..helpers import needs_chromium
from .acoustic_rig import get, wait_for
from .conftest import running_console
from .pages import take_control


@pytest.fixture(scope="module")
def live():
    # 3 m over the seabed, amphorae ahead: objects in view from the start.
    with running_console(objects=True, tracker=None, start_depth_m=5.0, failsafe_s=3.0) as console:
        yield console


@pytest.mark.browser
@needs_chromium
def test_frame_it_without_a_tracker_sends_the_roi_alone(open_page, live):
    base, op = live.url, live.operator
    page = open_page()
    take_control(page)
    # Held at its depth (disarmed, it rises, and the objects leave the picture within a minute).
    page.select_option("#mode-select", "DEPTH_HOLD")
    page.click("#set-mode")
    page.wait_for_function("document.getElementById('mode-fate').dataset.state === 'followed'", timeout=30000)
    page.click("#arm")
    page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'", timeout=30000)
    page.wait_for_selector("#objects li .object-frame", timeout=90000)

    def in_view() -> list | None:
        for o in op.world_state()["objects"]:
            try:
                op.object_frame(o["id"])  # (what Frame it would send; nothing is sent)
            except OrderError:
                continue
            return [o["id"]]  # (ids start at 0)
        return None

    found = wait_for(in_view, 30)
    assert found, ("no object in view to frame", op.world_state()["objects"], op.vehicle())
    oid = found[0]
    fate = f'#objects li[data-id="{oid}"] .object-frame-fate'

    def order(order_id: int) -> dict:
        return next(o for o in get(base + "/api/orders") if o["id"] == order_id)

    # The link carries FOLLOW: the first Frame it asks for it.  The ROV rejects it, and its
    # ROI goes alone, as an IMAGE order the ROV takes; the pilot reads both beside the button.
    page.click(f'#objects li[data-id="{oid}"] .object-frame')
    page.wait_for_function(f"document.querySelector('{fate}').textContent.includes('the ROI alone: order #')"
                           f" && document.querySelector('{fate}').dataset.outcome === 'done'", timeout=30000)
    follow_id = int(page.text_content(fate).split("order #")[1].split()[0])
    rejected = order(follow_id)
    assert rejected["state"] == "rejected" and rejected["follow"] and rejected["then"], rejected
    alone = order(rejected["then"])
    assert alone["state"] == "acknowledged" and not alone.get("follow"), alone
    roi = tuple(rejected["roi"])
    assert tuple(alone["roi"]) == roi and f"order #{alone['id']} acknowledged" in page.text_content(fate)
    asked = op.requested_settings
    assert tuple(asked.roi) == roi and not asked.follow, asked
    said = [e["text"] for e in get(base + "/api/log")]
    assert sum("the ROV does not follow" in t and "Frame it sends the ROI alone" in t for t in said) == 1, said
    assert any(f"alone on the next picture, order #{alone['id']}" in t for t in said), said

    # A picture is coded with that ROI: the ROV took it.
    def framed() -> dict | None:
        s = get(base + "/api/image")
        return s if s["complete"] and tuple((s["settings"] or {}).get("roi") or ()) == roi else None

    assert wait_for(framed, 60), get(base + "/api/image")

    # Frame it again: the ROI alone at once, saying why; no FOLLOW goes.
    page.click(f'#objects li[data-id="{oid}"] .object-frame')
    page.wait_for_function(f"document.querySelector('{fate}').textContent.includes('the ROV rejected FOLLOW')"
                           f" && document.querySelector('{fate}').dataset.outcome === 'done'", timeout=30000)
    again = order(int(page.text_content(fate).split("order #")[1].split()[0]))
    assert again["id"] > alone["id"] and again["state"] == "acknowledged" and not again.get("follow"), again
    assert "the ROI alone: order #" not in page.text_content(fate)
