"""The console's own modem port pulled, as a pilot meets it: `rovlink rov` and
`rovlink console` as two processes on `serial://`, each on a pseudo-terminal at
a fixed path, the two joined by a relay thread as by a serial cable.  The pilot
has the page open in headless Chromium with the link up; the console's port
goes away (its USB serial adapter pulled): at once the page says MODEM PORT
DOWN, with the transport's reason, the badge says so and the alarm sounds, and
the API gives the reason.  Neither program falls over.  The port comes back at
the same path: the console opens it again by itself, the banner goes, the link
is up, and the log has the alert and the port's return."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from ..helpers import CHROMIUM, CHROMIUM_ARGS, Pty, free_tcp_port, needs_chromium
from .acoustic_rig import end_processes, get, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.processes, pytest.mark.slow, needs_chromium]
ROVLINK = [sys.executable, "-m", "rovlink"]


class Cable:
    """Bytes copied both ways between two pseudo-terminals' masters, as a serial cable
    would.  An end that is down (`Cable.down`) is skipped, and what was on its way to
    it dropped, until it is up again; the lock keeps a master from being closed (and
    its number reused) under the copying thread."""

    def __init__(self, a: Pty, b: Pty) -> None:
        self.ends = (a, b)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="serial cable", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def down(self, end: Pty) -> None:
        with self._lock:
            end.down()

    def up(self, end: Pty) -> None:
        with self._lock:
            end.up()

    @staticmethod
    def _read(end: Pty) -> bytes:
        if end.master_fd is None:
            return b""
        try:
            return end.read()
        except OSError:  # EIO: nobody has the terminal open (yet, or any more)
            return b""

    def _run(self) -> None:
        a, b = self.ends
        while not self._stop.is_set():
            with self._lock:
                for src, dst in ((a, b), (b, a)):
                    data = self._read(src)
                    if data and dst.master_fd is not None:
                        try:
                            dst.write(data)
                        except OSError:  # the far end's buffer full, or nobody there: lost on the wire
                            pass
            time.sleep(0.002)


@pytest.fixture
def radio_link(tmp_path):
    key = tmp_path / "link.key"
    subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
    rov_tty, console_tty = Pty(str(tmp_path / "ttyROV")), Pty(str(tmp_path / "ttyCONSOLE"))
    rov_tty.up()
    console_tty.up()
    cable = Cable(rov_tty, console_tty)
    cable.start()
    port = free_tcp_port()
    rov_out, console_out = open(tmp_path / "rov.log", "w"), open(tmp_path / "console.log", "w")
    rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"serial://{rov_tty.path}", "--key", str(key)],
                           stdout=rov_out, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    console = subprocess.Popen(ROVLINK + ["console", "--link", f"serial://{console_tty.path}", "--key", str(key),
                                          "--port", str(port), "--viser-port", str(free_tcp_port()), "--no-record"],
                               stdout=console_out, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    base = f"http://127.0.0.1:{port}"
    try:
        assert wait_for(lambda: get(base + "/api/state")["link"]["state"] == "up", 60), "no reply from the ROV over the cable"
        yield base, cable, console_tty, rov, console
    finally:
        end_processes(console, rov)
        cable.close()
        rov_out.close()
        console_out.close()
        for end in (rov_tty, console_tty):
            if end.master_fd is not None:
                end.down()
        for name in ("rov.log", "console.log"):  # shown by pytest when the test fails
            print(f"--- {name}\n" + (tmp_path / name).read_text()[-4000:])


def test_the_pilot_is_told_at_once_when_the_consoles_modem_port_goes_and_comes_back(radio_link):
    from playwright.sync_api import sync_playwright

    base, cable, console_tty, rov, console = radio_link
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1366, "height": 768})
            page.goto(base + "/?scene=off")
            page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
            assert page.is_hidden("#link-banner")
            alerts = page.evaluate("+document.body.dataset.alerts || 0")

            # The console's USB serial adapter pulled: said at once, long before the
            # replies have been missing for LINK LOST.
            cable.down(console_tty)
            page.wait_for_function("document.body.dataset.link === 'port down'", timeout=10000)
            assert page.is_visible("#link-banner")
            assert page.text_content("#link-banner-title") == "MODEM PORT DOWN"
            text = page.text_content("#link-banner-text")
            reason = text.split("; opening it again")[0]
            assert reason.strip() and "No poll reaches the ROV: it stops on its failsafe" in text, text
            assert page.text_content("#link-up") == "MODEM PORT DOWN"
            assert page.evaluate("+document.body.dataset.alerts") == alerts + 1  # the alarm sounds
            link = get(base + "/api/state")["link"]
            assert link["transport_up"] is False
            assert isinstance(link["port_error"], str) and link["port_error"], link
            assert rov.poll() is None and console.poll() is None

            # Plugged back in at the same path: the console opens it again by itself.
            time.sleep(1.0)  # a reopening or two fails meanwhile, as with a real adapter
            assert console.poll() is None
            cable.up(console_tty)
            page.wait_for_function("document.body.dataset.link === 'up'", timeout=40000)
            assert page.is_hidden("#link-banner")
            assert page.text_content("#link-up") == "link up"
            assert page.evaluate("page.alarmTimer") is None  # the alarm stopped
            link = get(base + "/api/state")["link"]
            assert link["transport_up"] is True and link["port_error"] is None, link
        finally:
            browser.close()

    texts = [line["text"] for line in get(base + "/api/log")]
    assert any(t.startswith("MODEM PORT DOWN: ") for t in texts), texts
    assert "modem port open again" in texts, texts
    assert rov.poll() is None and console.poll() is None
