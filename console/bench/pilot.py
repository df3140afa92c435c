"""A pilot on the demo's page for some minutes (`rovlink bench console`'s pilot row).

`rovlink demo` is started as a user starts it (its own process, its vehicle
side in another, the default 1.9 kbit/s, 85 ms, BER 7e-6 link); headless
Chromium opens the operator page with its 3-D scene, takes control, arms,
and flies: held keys in turn on each axis, a previewed Go-to sent every
minute, new image settings every ninety seconds, a look back at a picture.
Meanwhile the link's state is read twice a second from the API; at the end
the session's log says how many times the link was lost and the ROV failed
safe.  The target (issue 25 of the pilot's page): neither, in ten minutes.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

from .child import die_with_parent, end_child
from .page import CHROMIUM, CHROMIUM_ARGS

KEYS = ("w", "d", "s", "a", "e", "q", "r", "f")


def _get(url: str):
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def holds_control(page, base: str, timeout_ms: float = 30000) -> None:
    """Until the page holds control (again: a connection that failed gives it back); if it
    does not, a RuntimeError saying what the page and the console said of its control."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    try:
        page.wait_for_function("document.body.classList.contains('holder')", timeout=timeout_ms)
    except PlaywrightTimeout:
        closes = page.evaluate("document.body.dataset.socketCloses || 'none'")
        said = [e["text"] for e in _get(base + "/api/log") if "control" in e["text"] or "WebSocket" in e["text"]]
        raise RuntimeError(f"the page does not hold control; its socket's closes: {closes}; "
                           f"the console's log: {said[-6:]}") from None


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure_pilot(minutes: float = 10.0) -> dict:
    from playwright.sync_api import sync_playwright

    port, viser_port = _free_port(), _free_port()
    base = f"http://127.0.0.1:{port}"
    workdir = tempfile.mkdtemp(prefix="rovlink-bench-pilot-")
    # Its output to a file: a pipe nobody reads for ten minutes could fill and stall it.
    log_path = os.path.join(workdir, "demo.log")
    log_file = open(log_path, "w")
    # Recorded: its channel log says which frames the emulated radio itself lost.
    record = os.path.join(workdir, "session.jsonl")
    demo = subprocess.Popen([sys.executable, "-m", "rovlink", "demo", "--port", str(port), "--viser-port",
                             str(viser_port), "--record", record], cwd=workdir,
                            stdout=log_file, stderr=subprocess.STDOUT, preexec_fn=die_with_parent)
    samples: list[tuple[str, float | None]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(0.5):
            try:
                link = _get(base + "/api/link")
                samples.append((link["state"], link.get("odometry_age_s")))
            except OSError:
                samples.append(("unreachable", None))

    try:
        deadline = time.monotonic() + 300  # a first run compiles the codec first
        while True:
            try:
                _get(base + "/api/state")
                break
            except OSError:
                if demo.poll() is not None or time.monotonic() > deadline:
                    with open(log_path) as f:
                        raise RuntimeError(f"the demo did not come up: {f.read()[-2000:]}") from None
                time.sleep(0.5)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1366, "height": 768})
            page.goto(base)
            page.wait_for_function("document.body.dataset.clientId !== undefined", timeout=60000)
            page.click("#take")
            page.wait_for_function("document.getElementById('control-text').textContent === 'You have control.'")
            page.click("#arm")
            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            start = time.monotonic()
            end = start + minutes * 60
            turn = 0
            next_goto, next_image = start + 60, start + 90
            while time.monotonic() < end:
                key = KEYS[turn % len(KEYS)]
                turn += 1
                page.keyboard.down(key)
                page.wait_for_timeout(1500)
                page.keyboard.up(key)
                page.wait_for_timeout(1500)
                now = time.monotonic()
                if now >= next_goto:
                    next_goto += 60
                    pose = _get(base + "/api/state")["pose"]["received"] or {"x_m": 0, "y_m": 0, "z_m": 2}
                    for field, value in (("#goto-x", pose["x_m"] + 2), ("#goto-y", pose["y_m"] - 1),
                                         ("#goto-z", max(1.0, pose["z_m"])), ("#goto-yaw", 30)):
                        page.fill(field, f"{value:.2f}")
                    page.click("#goto-preview")
                    page.click("#goto-go")
                if now >= next_image:
                    next_image += 90
                    page.fill("#budget", str(1500 if turn % 2 else 2500))
                    page.click("#apply-image")
                    thumbs = page.query_selector_all("#image-strip button")
                    if len(thumbs) > 2:
                        thumbs[2].click()
            alarms = int(page.evaluate("+document.body.dataset.alerts || 0"))
            closes = page.evaluate("document.body.dataset.socketCloses || ''")
            holds_control(page, base)
            page.click("#disarm")
            browser.close()
        stop.set()
        sampler.join(2)
        log = _get(base + "/api/log")
        link = _get(base + "/api/link")
    finally:
        stop.set()
        end_child(demo)
        log_file.close()
    from .load import _channel_losses

    channel = _channel_losses(record.replace(".jsonl", "") + ".channel.jsonl")
    states = [s for s, _ in samples]
    ages = sorted(a for _, a in samples if a is not None)
    share = {s: round(100.0 * states.count(s) / max(1, len(states)), 2) for s in ("up", "degraded", "lost")}
    return {
        "minutes": minutes,
        "samples": len(samples),
        "state_percent": share,
        "link_lost_alerts": sum(1 for e in log if e["level"] == "alert" and e["text"].startswith("LINK LOST")),
        "failsafe_alerts": sum(1 for e in log if e["level"] == "alert" and "FAILSAFE" in e["text"]),
        "page_alarms": alarms,
        # The page's WebSocket ending meanwhile (count and last code), "" if never.
        "page_socket_closes": closes,
        "odometry_age_s_median": round(statistics.median(ages), 3) if ages else None,
        "odometry_age_s_p95": round(ages[int(0.95 * (len(ages) - 1))], 3) if ages else None,
        "polls_sent": link["sent"],
        "replies_lost": link["reports_lost"],
        # A poll or reply the radio lost costs one reply; the rest were late: starved of CPU.
        "channel_losses": channel,
        "replies_lost_not_by_channel": max(0, link["reports_lost"] - sum(channel.values())),
        "cpu_count": os.cpu_count(),
    }


def pilot_lines(r: dict) -> list[str]:
    from rovlink.bench import format_table

    return [f"a pilot on the demo's page (headless Chromium, 1366x768, the 3-D scene embedded) for "
            f"{r['minutes']:g} min: keys held in turn, a Go-to a minute, image settings every 90 s",
            format_table(["pilot measure", "value"], [
                ["link up / degraded / lost, % of samples",
                 f"{r['state_percent']['up']} / {r['state_percent']['degraded']} / {r['state_percent']['lost']}"],
                ["LINK LOST alerts", r["link_lost_alerts"]],
                ["ROV FAILSAFE alerts", r["failsafe_alerts"]],
                ["page alarms sounded", r["page_alarms"]],
                ["page's WebSocket ended (times, last code)", r["page_socket_closes"] or "never"],
                ["odometry age s, median / p95", f"{r['odometry_age_s_median']} / {r['odometry_age_s_p95']}"],
                ["polls sent, replies lost", f"{r['polls_sent']}, {r['replies_lost']}"],
                ["  of which not by the radio (late)", r["replies_lost_not_by_channel"]],
            ])]


def pilot_target(r: dict) -> dict:
    clean = r["link_lost_alerts"] == 0 and r["failsafe_alerts"] == 0
    return {"link_lost_alerts": r["link_lost_alerts"], "failsafe_alerts": r["failsafe_alerts"],
            "minutes": r["minutes"], "met": clean if r["minutes"] >= 10 else None}
