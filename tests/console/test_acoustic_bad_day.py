"""The acoustic link's bad day, as a pilot meets it (issue 24): `rovlink rov` and
`rovlink console` as processes on the real `wlmodem://` transport through two
emulated Modem-M64s (four times the modem's pace), two pages in headless
Chromium, the same cockpit as the radio link's.  The water goes quiet for longer
than the ROV's failsafe, then comes back: the status's age grows on both pages
meanwhile and the failsafe spell is told on both afterwards.  It goes quiet again while the ROV process is killed and
started again: the link is shown LOST, loudly, on both pages, and when the water
clears the restart is told.  STOP pressed on the second page is confirmed on the
first: one console, one truth.  Last the modems' ports vanish (adapters pulled):
said at once on both pages.  The console's recording tells it all again:
`rovlink plot` draws it and `rovlink replay` plays it back into the cockpit."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from rovlink.link.emulators.m64 import M64Params

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from .acoustic_rig import HostileRadio, end_processes, get, post_status, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.processes, pytest.mark.slow, needs_chromium]
ROVLINK = [sys.executable, "-m", "rovlink"]
FAST = M64Params(round_s=0.25, b_offset_s=0.125, latency_s=0.4, sync_s=1.0)
FAILSAFE_S = 6


def start_rov(tmp, key, n: int) -> subprocess.Popen:
    with open(tmp / f"rov-{n}.log", "w") as log:  # a file, not a pipe nobody reads while it runs
        return subprocess.Popen(ROVLINK + ["rov", "--link", f"wlmodem://{tmp}/rov-modem?role=b&channel=4",
                                           "--key", str(key), "--failsafe", str(FAILSAFE_S), "-v"],
                                stdout=subprocess.DEVNULL, stderr=log, text=True)


def test_quiet_water_a_failsafe_and_a_rov_restart_are_told_on_every_page(tmp_path):
    from playwright.sync_api import sync_playwright

    from rovlink.link.emulators.m64serial import M64SerialPair

    key = tmp_path / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    pair = M64SerialPair(str(tmp_path / "op-modem"), str(tmp_path / "rov-modem"), params=FAST, seed=5)
    radio = HostileRadio(pair.channel)
    pair.start()
    port = free_tcp_port()
    rov = start_rov(tmp_path, key, 1)
    console = subprocess.Popen(ROVLINK + ["console", "--link", f"wlmodem://{tmp_path}/op-modem?role=a&channel=4",
                                          "--key", str(key), "--port", str(port), "--viser-port", str(free_tcp_port()),
                                          "--record", str(tmp_path / "session.jsonl")],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    # (the console's stderr: read at the end by communicate(); it logs little at its default level)
    base = f"http://127.0.0.1:{port}"
    try:
        assert wait_for(lambda: get(base + "/api/pose")["received"], 120), "no status from the ROV over the modems"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            pages = [browser.new_page(viewport={"width": 1366, "height": 768}) for _ in range(2)]
            for page in pages:
                page.goto(base + "/?scene=off")
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
                # The ROV's own failsafe time, from its SYNC, in the log.
                page.wait_for_function(f"document.getElementById('log').textContent.includes('after {FAILSAFE_S} s')",
                                       timeout=30000)
            first, second = pages

            # An order from the first page (it takes control); its fate shows on both.
            first.click("#take")
            first.wait_for_function("document.getElementById('control-text').textContent.includes('You have')")
            first.click("#arm")
            for page in pages:
                page.wait_for_function("document.getElementById('arm-fate').dataset.state === 'followed'",
                                       timeout=60000)

            # Quiet water, longer than the ROV's failsafe but short of the link's 20 s: the
            # status shown grows old, its age said on both pages; afterwards both tell the
            # failsafe spell.
            radio.cut = True
            for page in pages:
                page.wait_for_function("parseFloat(document.getElementById('odometry-age').textContent) >= 10",
                                       timeout=30000)
            # (10 s without a status; the ROV's failsafe took 6 s of that silence.)
            radio.cut = False
            for page in pages:
                page.wait_for_function("document.getElementById('log').textContent.includes('ROV in FAILSAFE')",
                                       timeout=45000)
                page.wait_for_function("parseFloat(document.getElementById('odometry-age').textContent) < 10",
                                       timeout=45000)
            assert "FAILSAFE" in (tmp_path / "rov-1.log").read_text()

            # Quiet again, and the ROV process dies and starts anew meanwhile: LOST, loudly,
            # on both pages; when the water clears, the restart is told.
            radio.cut = True
            rov.send_signal(signal.SIGKILL)
            rov.wait(20)
            rov = start_rov(tmp_path, key, 1)
            for page in pages:
                page.wait_for_function("document.body.dataset.link === 'lost'", timeout=40000)
                assert "LINK LOST" in page.text_content("#link-up")
                assert not page.locator("#link-banner").is_hidden()
            radio.cut = False
            for page in pages:
                page.wait_for_function("document.getElementById('log').textContent.includes('ROV restarted')",
                                       timeout=60000)
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
            # The new ROV's status, once it gave the operator its last order number.
            assert wait_for(lambda: (get(base + "/api/pose")["odometry_age_s"] or 99) < 10, 60)

            # STOP from the second page (which does not hold control): confirmed, on both pages.
            second.click("#stop")
            assert wait_for(lambda: [o for o in get(base + "/api/orders") if o["kind"] == "STOP"
                                     and o["state"] == "acknowledged"], 60)
            for page in pages:
                page.wait_for_function("document.getElementById('log').textContent.includes('STOP confirmed')",
                                       timeout=20000)
            assert get(base + "/api/pose")["hold"]

            # The modems' USB adapters pulled out (the emulator and its ports gone): the
            # console's own port failing is said at once on both pages, not 20 s later.
            pair.close()
            for page in pages:
                page.wait_for_function("document.getElementById('link-up').textContent.includes('MODEM PORT DOWN')",
                                       timeout=15000)
                text = page.text_content("#link-banner")
                assert "no serial port" in text or "failed" in text, text
            browser.close()
        assert console.poll() is None and rov.poll() is None
        console.send_signal(signal.SIGINT)
        console.communicate(timeout=30)
        # The session's recording: every packet both ways, the statuses, the log, as the page told it.
        recording = tmp_path / "session.jsonl"
        records = [json.loads(line) for line in recording.read_text().splitlines()]
        assert records[0]["k"] == "meta" and records[0]["profile"] == "acoustic"
        kinds = {r["k"] for r in records}
        assert {"tx", "rx", "status", "note", "order", "order_state"} <= kinds
        notes = [r["text"] for r in records if r["k"] == "note"]
        assert any("ROV in FAILSAFE" in n for n in notes) and any("ROV restarted" in n for n in notes)
        assert any(n.startswith("MODEM PORT DOWN") for n in notes)
        assert any(r["k"] == "status" and r["failsafe"] for r in records)
        assert all(len(bytes.fromhex(r["hex"])) == 8 for r in records if r["k"] in ("tx", "rx"))
        ts = [r["t"] for r in records[1:]]
        assert ts == sorted(ts) or max(a - b for a, b in zip(ts, ts[1:])) < 0.5

        # `rovlink plot` draws it: the link's time-lapse, and the positions the statuses told.
        out = subprocess.run(ROVLINK + ["plot", str(recording), "--out", str(tmp_path)],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        assert (tmp_path / "fig4_link_timelapse.png").stat().st_size > 10000
        assert (tmp_path / "fig5_position.png").stat().st_size > 10000

        # `rovlink replay` plays it back into the same cockpit: at its end the last status,
        # the orders and their fates, the failsafe and restart in the log, as they were.
        replay_port = free_tcp_port()
        replay = subprocess.Popen(ROVLINK + ["replay", str(recording), "--speed", "64", "--port", str(replay_port),
                                             "--viser-port", str(free_tcp_port())],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
        try:
            rbase = f"http://127.0.0.1:{replay_port}"
            assert wait_for(lambda: get(rbase + "/api/replay")["ended"], 120), replay.stderr
            state = get(rbase + "/api/state")
            assert state["link"]["state"] == "replay" and state["link"]["profile"] == "acoustic"
            last = [r for r in records if r["k"] == "status"][-1]
            assert state["pose"]["received"]["x_m"] == pytest.approx(last["x_m"])
            assert state["pose"]["hold"] == last["hold"]
            kinds = {o["kind"]: o["state"] for o in get(rbase + "/api/orders")}
            assert kinds.get("ARM") == "followed" and kinds.get("STOP") == "acknowledged", kinds
            log = " ".join(e["text"] for e in get(rbase + "/api/log"))
            assert "ROV in FAILSAFE" in log and "ROV restarted" in log
            # A replay orders nothing: there is no ROV.
            r = post_status(rbase + "/api/orders/stop")
            assert r == 409
        finally:
            end_processes(replay)
    finally:
        end_processes(console, rov)
        pair.close()
