"""The operator page measured in headless Chromium (used by `rovlink bench console --page`).

The demo stack (simulated ROV, 1.9 kbit/s emulated channel) and the web app
run in this process; Chromium loads the operator page.  An init script in the
page timestamps (Date.now(), this machine's wall clock) every telemetry
message whose predicted pose changed, and every change of the image the page
shows (the `data-decoded-bytes` of #image, set when the new picture has
loaded).  In the server, an operator subscriber timestamps every trunk
received.  A trunk that completes the stream's first N bytes is shown when
the page first shows that image decoded from N bytes or more.  The pilot
steers during the measurement, so the predicted pose keeps changing.
"""

from __future__ import annotations

import asyncio
import socket
import statistics
import time

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]

INIT_SCRIPT = """
(() => {
  const rec = window.__rovlinkBench = {poses: [], shown: [], telemetry: []};
  const Native = window.WebSocket;
  window.WebSocket = function (...args) {
    const ws = new Native(...args);
    let last = null;
    ws.addEventListener("message", (ev) => {
      try {
        const msg = JSON.parse(ev.data);
        if (msg.type === "telemetry") rec.telemetry.push(Date.now());
        if (msg.type === "telemetry" && msg.pose && msg.pose.predicted) {
          const key = JSON.stringify(msg.pose.predicted);
          if (key !== last) { rec.poses.push(Date.now()); last = key; }
        }
      } catch (e) {}
    });
    return ws;
  };
  window.WebSocket.prototype = Native.prototype;
  Object.assign(window.WebSocket, Native);
  new MutationObserver((records) => {
    for (const r of records) {
      const el = r.target;
      if (el.id === "image" && r.attributeName === "data-decoded-bytes") {
        rec.shown.push([Date.now(), Number(el.dataset.img), Number(el.dataset.decodedBytes)]);
      }
    }
  }).observe(document, {attributes: true, subtree: true, attributeFilter: ["data-decoded-bytes"]});
})();
"""


def measure_page(seconds: float = 40.0, *, telemetry_hz: float = 25.0) -> dict:
    return asyncio.run(_measure(seconds, telemetry_hz))


async def _measure(seconds: float, telemetry_hz: float) -> dict:
    from playwright.async_api import async_playwright

    from rovlink.console.stack import Stack, StackConfig
    from rovlink.console.web.app import create_app, serve

    trunks: list[tuple[float, int, int]] = []  # (wall time, img, stream bytes held)
    async with Stack(StackConfig()) as stack:
        op = stack.operator

        def on_event(topic, payload):
            if topic == "image_progress":
                trunks.append((time.time(), payload["img"], max(0, payload["received_bytes"] - 2)))

        op.subscribe(on_event)
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        app = create_app(op, telemetry_hz=telemetry_hz)
        server = asyncio.create_task(serve(app, sock=sock))
        try:
            async with async_playwright() as pw:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
                page = await browser.new_page()
                await page.add_init_script(INIT_SCRIPT)
                await page.goto(f"http://127.0.0.1:{port}/")
                t0 = time.time()
                # Steer, so the dead-reckoned pose really changes between
                # telemetry messages (idle, it rightly stands still).
                # Through the command layer as a pilot: with nobody in control
                # the console keeps the wish neutral.
                from rovlink.console import control

                desk = app.state.desk
                pilot = control.Caller(desk.take(None, "bench").id)
                desk.submit(control.Arm(True), pilot)
                await asyncio.sleep(2.0)
                # Held as a pilot holds a stick: the wish again every second, so
                # that the desk's lease (a silent script loses control) holds.
                end = time.time() + max(0.0, seconds - 2.0)
                while time.time() < end:
                    desk.submit(control.Drive(0.4, 0.0, 0.0, 0.15), pilot)
                    await asyncio.sleep(min(1.0, max(0.0, end - time.time())))
                desk.submit(control.Drive(), pilot)
                rec = await page.evaluate("window.__rovlinkBench")
                await browser.close()
        finally:
            server.cancel()
            await asyncio.gather(server, return_exceptions=True)
    t1 = time.time()
    poses = [t / 1000 for t in rec["poses"] if t / 1000 >= t0 + 3.0]  # once steering
    span = max(1e-6, (t1 - (t0 + 3.0)))
    shown = [(t / 1000, img, n) for t, img, n in rec["shown"]]
    latencies = []
    for arrived, img, held in trunks:
        if arrived < t0 + 2.0 or held <= 0:
            continue  # the page was still loading
        # Shown: the first time the page shows this image decoded from at
        # least these bytes.
        first = next((t for t, i, n in shown if i == img and n >= held and t >= arrived), None)
        if first is not None:
            latencies.append((first - arrived) * 1000)
    return {
        "seconds": seconds,
        "telemetry_hz": telemetry_hz,
        "pose_updates_hz": len(poses) / span,
        "telemetry_messages_hz": len([t for t in rec["telemetry"] if t / 1000 >= t0 + 3.0]) / span,
        "trunks": len(trunks),
        "pictures_shown": len(rec["shown"]),
        "trunk_latency_ms_median": statistics.median(latencies) if latencies else None,
        "trunk_latency_ms_p95": sorted(latencies)[int(0.95 * (len(latencies) - 1))] if latencies else None,
        "trunk_latency_ms_max": max(latencies) if latencies else None,
        "trunk_latency_ms": [round(v, 1) for v in latencies],
    }
