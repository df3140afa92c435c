"""`rovlink demo` as a user runs it: one real process with the simulated ROV,
the ROV node, the emulated channel and the console, driven through the
operator page in headless Chromium (Debian's chromium, no download): the 3D
scene renders, an image refines, a held key moves the ROV, an ROI drag is
honoured by the next image, a previewed position order moves nothing until
sent and then the ROV goes there.

The link runs at 9600 bit/s here instead of 1900 so an image takes ~2 s, not
~11 s; everything else is the demo's default.  Then Ctrl-C stops it cleanly,
and the session it recorded plots.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

from rovlink import debt
from rovlink.link.transports.transport import free_udp_port

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from ..helpers import wait_until_up as wait_for

pytestmark = [pytest.mark.browser, needs_chromium]


def get(url: str):
    with urllib.request.urlopen(url, timeout=10) as r:
        body = r.read()
        return json.loads(body) if r.headers.get_content_type() == "application/json" else body



@pytest.fixture
def demo(tmp_path):
    port, viser_port = free_tcp_port(), free_tcp_port()
    record = tmp_path / "session.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rovlink", "demo", "--port", str(port), "--viser-port", str(viser_port),
         "--bitrate", "9600", "--record", str(record)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    base = f"http://127.0.0.1:{port}"
    try:
        # (A fresh checkout compiles the codec first: up to a minute or two on a loaded machine.)
        assert wait_for(lambda: get(base + "/api/state"), 240), "the demo did not come up"
        yield base, proc, record
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_demo_in_the_browser(demo, tmp_path):
    from playwright.sync_api import sync_playwright

    base, proc, record = demo
    errors = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(base)

        # The 3D scene renders in the page: viser's canvas inside the iframe draws something.
        page.wait_for_selector("#scene", state="visible", timeout=30000)
        frame = page.frame_locator("#scene")
        frame.locator("canvas").first.wait_for(timeout=60000)
        shot = tmp_path / "demo.png"
        from PIL import Image

        def drawn() -> bool:
            page.locator("#scene").screenshot(path=str(shot))
            return np.asarray(Image.open(shot).convert("L"), dtype=float).std() > 10

        assert wait_for(drawn, 60, 0.5), "the 3D view is blank"
        # ... drawn in a process of its own (another site: localhost beside the page's
        # 127.0.0.1), so that the page's own thread never waits on the scene's drawing.
        targets = browser.new_browser_cdp_session().send("Target.getTargets")["targetInfos"]
        assert any(t["type"] == "iframe" and t["url"].startswith("http://localhost:") and "/rovlink/" in t["url"]
                   for t in targets), [(t["type"], t["url"][:60]) for t in targets]

        # An image arrives and visibly refines.
        page.wait_for_selector("#image[data-decoded-bytes]", state="visible", timeout=90000)
        seen = set()
        assert wait_for(lambda: seen.add(page.get_attribute("#image", "data-decoded-bytes")) or len(seen) >= 3,
                        60, 0.05), f"the picture did not refine: {seen}"

        # A held key moves the ROV.
        page.click("#take")
        page.click("#arm")
        assert wait_for(lambda: get(base + "/api/state")["pose"]["armed"], 30)
        x0 = get(base + "/api/state")["pose"]["received"]["x_m"]
        page.locator("body").focus()
        page.keyboard.down("w")
        moved = wait_for(lambda: get(base + "/api/state")["pose"]["received"]["x_m"] > x0 + 0.3, 30)
        page.keyboard.up("w")
        assert moved, "a held key did not move the ROV"

        # An ROI dragged on the image is acknowledged by the ROV; the next image honours it.
        box = page.locator("#image").bounding_box()
        page.mouse.move(box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.3)
        page.mouse.down()
        page.mouse.move(box["x"] + box["width"] * 0.6, box["y"] + box["height"] * 0.7, steps=5)
        page.mouse.up()
        page.fill("#shift", "6")
        page.click("#apply-image")

        def image_order():
            orders = [o for o in get(base + "/api/orders") if o["kind"] == "IMAGE" and o.get("roi")]
            return orders[-1] if orders and orders[-1]["state"] == "acknowledged" else None

        order = wait_for(image_order, 30)
        assert order, "the ROI order was not acknowledged"
        roi = tuple(order["roi"])

        def honoured():
            stream = get(base + "/api/image/latest.debt")
            state = get(base + "/api/image")
            return state.get("complete") and tuple(debt.unpack_header(stream).roi or ()) == roi

        assert wait_for(honoured, 60), "no image with the requested ROI"

        # Supervised control: a previewed position order moves nothing until sent.
        start = get(base + "/api/state")["pose"]["received"]
        target = (round(start["x_m"] - 2.0, 2), round(start["y_m"] + 1.5, 2), 3.0)
        for field, value in zip(("#goto-x", "#goto-y", "#goto-z", "#goto-yaw"), (*target, 45)):
            page.fill(field, str(value))
        page.click("#goto-preview")
        # The preview's own answer (its points), not the target's telemetry, which may come first
        # and show the box with "previewed: not sent" before the points are known.
        page.wait_for_function("document.getElementById('goto-plan').dataset.previewed === '1'", timeout=30000)
        assert "not sent" in page.text_content("#goto-plan")
        assert int(page.get_attribute("#goto-plan", "data-points")) > 3
        time.sleep(3)
        assert not [o for o in get(base + "/api/orders") if o["kind"] == "POSITION"]
        now = get(base + "/api/state")["pose"]["received"]
        assert math.hypot(now["x_m"] - start["x_m"], now["y_m"] - start["y_m"]) < 0.3, "moved before Send"
        page.click("#goto-go")

        def arrived():
            p = get(base + "/api/state")["pose"]["received"]
            return math.dist((p["x_m"], p["y_m"], p["z_m"]), target) < 0.5

        assert wait_for(lambda: any(o["kind"] == "POSITION" and o["state"] == "acknowledged"
                                    for o in get(base + "/api/orders")), 20), (
            f"position order not acknowledged: page says {page.text_content('#goto-plan')!r}, "
            f"error {page.text_content('#error')!r}, orders {get(base + '/api/orders')}")
        assert wait_for(arrived, 60), "the ROV did not reach the target"
        browser.close()
    assert not errors, errors

    # Ctrl-C stops everything cleanly.
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    assert "http://127.0.0.1:" in out

    # The session was recorded and plots.
    plots = subprocess.run([sys.executable, "-m", "rovlink", "plot", str(record), "--out", str(tmp_path / "plots")],
                           capture_output=True, text=True, timeout=120)
    assert plots.returncode == 0, plots.stderr
    assert (tmp_path / "plots" / "fig4_link_timelapse.png").stat().st_size > 10_000
    assert (tmp_path / "plots" / "fig5_velocity.png").stat().st_size > 10_000


def test_demo_refuses_a_busy_port(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        record = tmp_path / "runs" / "session.jsonl"
        for which in ("--port", "--viser-port"):
            ports = {"--port": str(free_tcp_port()), "--viser-port": str(free_tcp_port()), which: str(busy)}
            out = subprocess.run([sys.executable, "-m", "rovlink", "demo", *[x for kv in ports.items() for x in kv],
                                  "--record", str(record)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
            assert out.returncode == 1
            # Said before anything starts: one line, no banner, nothing recorded.
            assert out.stderr.strip().splitlines() == [
                f"rovlink demo: error: {which} {busy}: cannot serve on 127.0.0.1:{busy} (Address already in use); "
                f"choose another with {which}"], out.stderr
            assert out.stdout == ""
            assert not record.exists() and not record.parent.exists()


def test_the_vehicle_side_says_when_its_udp_port_was_taken_and_exits_with_port_taken():
    """The demo chooses two free UDP ports and binds them a moment later: another
    program may take one meanwhile (it happened in CI).  The vehicle side then exits
    with PORT_TAKEN, which the demo takes as "choose new ports" (up to PORT_TRIES)."""
    import socket

    from rovlink.console.vehicleside import PORT_TAKEN

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        taken = s.getsockname()[1]
        out = subprocess.run([sys.executable, "-m", "rovlink.console.vehicleside", "--udp", str(taken),
                              "--peer", str(free_udp_port())], input="insecure\n", capture_output=True, text=True,
                             timeout=120)
    assert out.returncode == PORT_TAKEN, (out.returncode, out.stderr[-1500:])
    assert "Address already in use" in out.stderr and "Traceback" not in out.stderr
    assert "ready" not in out.stdout


def _children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the processes whose parent is `pid` (Linux /proc)."""
    from pathlib import Path

    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid:
                cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                out.append((int(stat.parent.name), cmdline))
        except (OSError, IndexError, ValueError):
            continue
    return out


def test_the_demos_vehicle_side_runs_in_a_process_of_its_own_and_ends_with_the_console(demo):
    """Issue 25 of the pilot's page: the browser and the web server share the console's
    process; the simulated ROV, its node and the emulated radio do not."""
    import os

    base, proc, _record = demo
    vehicle = [pid for pid, cmd in _children(proc.pid) if "rovlink.console.vehicleside" in cmd]
    assert len(vehicle) == 1, _children(proc.pid)
    assert get(base + "/api/link")["state"] in ("up", "degraded")
    # The console killed outright (no cleanup at all): its vehicle side sees its stdin
    # close and stops; no simulated ROV is left running.
    proc.kill()
    proc.communicate()
    assert wait_for(lambda: not os.path.exists(f"/proc/{vehicle[0]}") or
                    open(f"/proc/{vehicle[0]}/stat").read().rsplit(")", 1)[1].split()[0] == "Z", 20), \
        "the vehicle side outlived the console"


def test_the_demo_names_the_operator_page_first_and_viser_prints_no_box_of_its_own(demo):
    """A newcomer reads the first line for the address to open: the operator page's, not
    viser's watch-only scene in a box of its own."""
    base, proc, _record = demo
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert lines and lines[0] == f"operator page: {base}/", out
    assert lines[1].startswith("rovlink demo: simulated ROV"), out
    scene = [line for line in lines if "3D scene" in line]
    assert len(scene) == 1 and "watch only" in scene[0] and "http://127.0.0.1:" in scene[0], out
    assert scene[0].split()[-1] != f"{base}/"  # the scene's own address, not the page's again
    # viser's own banner (a box) and its "Server stopped" went nowhere.
    assert not [line for line in lines if "╭" in line or "│" in line or "(viser)" in line], out
