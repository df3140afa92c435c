"""The acoustic link's bad day, as a pilot meets it (issue 24): `rovlink rov` and
`rovlink console` as processes on the real `wlmodem://` transport through two
emulated Modem-M64s (four times the modem's pace), two pages in headless
Chromium.  The water goes quiet for longer than the ROV's failsafe, then comes
back: the status is marked STALE meanwhile and the failsafe spell is told on
both pages afterwards.  It goes quiet again while the ROV process is killed and
started again: the link is shown LOST, loudly, on both pages, and when the water
clears the restart is told.  STOP pressed on the second page is confirmed on the
first: one console, one truth.  Last the modems' ports vanish (adapters pulled):
said at once on both pages.  The console's recording tells it all again."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from rovlink.link.m64 import M64Params

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, needs_chromium
from .acoustic_rig import HostileRadio, end_processes, get, wait_for

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

    from rovlink.link.m64serial import M64SerialPair

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
        assert wait_for(lambda: get(base + "/api/state")["status"], 120), "no status from the ROV over the modems"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            pages = [browser.new_page(viewport={"width": 1366, "height": 768}) for _ in range(2)]
            for page in pages:
                page.goto(base + "/")
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
                page.wait_for_function(f"document.getElementById('failsafe').textContent.includes('{FAILSAFE_S} s')",
                                       timeout=30000)
            first, second = pages

            # An order from the first page; its fate shows on both.
            first.click("button[data-order=arm]")
            for page in pages:
                page.wait_for_selector("#orders tr[data-state=done]", timeout=60000)

            # Quiet water, longer than the ROV's failsafe but short of the link's 20 s:
            # the status goes STALE on both pages; afterwards both tell the failsafe spell.
            radio.cut = True
            for page in pages:
                page.wait_for_function("document.getElementById('status-age').textContent.includes('STALE')",
                                       timeout=30000)
            # (STALE: 10 s without a status; the ROV's failsafe took 6 s of that silence.)
            radio.cut = False
            for page in pages:
                page.wait_for_function("document.getElementById('log').textContent.includes('ROV in FAILSAFE')",
                                       timeout=45000)
                page.wait_for_function("!document.getElementById('status-age').textContent.includes('STALE')",
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
                assert "lost" in page.get_attribute("#link", "class")
            radio.cut = False
            for page in pages:
                page.wait_for_function("document.getElementById('log').textContent.includes('ROV restarted')",
                                       timeout=60000)
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
            # The new ROV's status, once it gave the operator its last order number.
            assert wait_for(lambda: get(base + "/api/state")["status"] and not get(base + "/api/state")["status"]["stale"],
                            60)

            # STOP from the second page: confirmed, and the first page shows it confirmed too.
            second.click("#stop")
            for page in pages:
                page.wait_for_function("document.getElementById('stop-fate').dataset.state === 'confirmed'",
                                       timeout=60000)
            held = get(base + "/api/state")["status"]
            assert held["hold"]

            # The modems' USB adapters pulled out (the emulator and its ports gone): the
            # console's own port failing is said at once on both pages, not 20 s later.
            pair.close()
            for page in pages:
                page.wait_for_function("document.getElementById('link').textContent.includes('MODEM PORT DOWN')",
                                       timeout=15000)
                assert "no serial port" in page.text_content("#link") or "failed" in page.text_content("#link")
            browser.close()
        assert console.poll() is None and rov.poll() is None
        console.send_signal(signal.SIGINT)
        console.communicate(timeout=30)
        # The session's recording: every packet both ways, the statuses, the log, as the page told it.
        records = [json.loads(line) for line in (tmp_path / "session.jsonl").read_text().splitlines()]
        assert records[0]["k"] == "meta" and records[0]["profile"] == "acoustic"
        kinds = {r["k"] for r in records}
        assert {"tx", "rx", "status", "note"} <= kinds
        notes = [r["text"] for r in records if r["k"] == "note"]
        assert any("ROV in FAILSAFE" in n for n in notes) and any("ROV restarted" in n for n in notes)
        assert any(n.startswith("MODEM PORT DOWN") for n in notes)
        assert any(r["k"] == "status" and r["failsafe"] for r in records)
        assert all(len(bytes.fromhex(r["hex"])) == 8 for r in records if r["k"] in ("tx", "rx"))
        ts = [r["t"] for r in records[1:]]
        assert ts == sorted(ts) or max(a - b for a, b in zip(ts, ts[1:])) < 0.5
        # `rovlink plot` (and replay) read radio sessions: it says so instead of failing on the packets.
        out = subprocess.run(ROVLINK + ["plot", str(tmp_path / "session.jsonl"), "--out", str(tmp_path)],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode != 0 and "acoustic link" in out.stderr, out.stderr
    finally:
        end_processes(console, rov)
        pair.close()
