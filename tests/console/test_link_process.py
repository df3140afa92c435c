"""The link in a process of its own (issue 33; link/process.py), with real processes:
`rovlink rov` and `rovlink console` over loopback UDP with one key.

- The link process killed outright: the page, in headless Chromium, says LINK
  PROCESS DOWN (a banner of its own, not "degraded"); the console starts it
  again; a go-to it held is shown unknown, never done; a STOP pressed while it is
  down is kept and confirmed by the next one.
- The console killed outright: its link process sends STOP, the ROV confirms it,
  then the link process stops polling and ends; the ROV fails safe."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest

from rovlink.console.session.fates import Fate

from ..helpers import CHROMIUM, CHROMIUM_ARGS, get_json, needs_chromium, wait_until_up
from .acoustic_rig import post
from .test_restarts import Processes, _why

pytestmark = [pytest.mark.slow, pytest.mark.processes]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A child the console has not reaped yet is a zombie: ended all the same.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _nice(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[16])


def _link(procs: Processes) -> dict:
    return get_json(procs.base + "/api/link")


def _order(procs: Processes, order_id: int) -> dict | None:
    return next((o for o in get_json(procs.base + "/api/orders") if o["id"] == order_id), None)


def _up(procs: Processes) -> bool:
    link = _link(procs)
    return link["state"] == "up" and link["link_process"] == "up"


@pytest.mark.browser
@needs_chromium
def test_the_link_process_killed_is_said_at_once_started_again_and_nothing_it_held_is_shown_done(tmp_path):
    from playwright.sync_api import sync_playwright

    procs = Processes(tmp_path, rov_args=("--budget", "0"))
    try:
        assert wait_until_up(lambda: _up(procs) and procs.pose()["autopilot"], 120), procs.logs_text()
        console_pid = procs.procs["console"].pid
        first = _link(procs)["link_process_pid"]
        assert first and first != console_pid and _alive(first)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_context(viewport={"width": 1366, "height": 768}).new_page()
                page.goto(procs.base + "/?scene=off")
                page.wait_for_function("document.body.dataset.configured === '1'", timeout=60000)
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)

                # A go-to the ROV has not answered yet, then the link process dies.
                client = post(procs.base + "/api/control/take", {"name": "script"})["client_id"]
                me = {"X-Rovlink-Client": client}
                here = procs.pose()["received"]
                goto = post(procs.base + "/api/orders/position",
                            {"x_m": here["x_m"] + 5.0, "y_m": here["y_m"], "z_m": here["z_m"]}, me)["id"]
                os.kill(first, 9)
                killed = time.monotonic()
                # Session time, as the orders' times: read after the kill, as nothing the dead
                # process said can be later (read before it, a reply that came between the read
                # and the kill on a loaded machine was taken for one after it).
                kill_t = get_json(procs.base + "/api/link")["t"]
                # What the page shows, read in one look (the console starts it again within a second
                # or two; the banner then says so for a while).  Down is said at once, "why is
                # being read" while the dead process is joined (longer on a loaded machine: the
                # full suite's run saw it first), then why: killed.
                shown = page.wait_for_function(
                    "(() => { const b = document.getElementById('link-banner');"
                    " const text = document.getElementById('link-banner-text').textContent;"
                    " return document.body.dataset.link === 'process down' && !b.hidden"
                    " && !text.includes('why is being read')"
                    " && [document.getElementById('link-banner-title').textContent, text]; })()",
                    timeout=10000).json_value()
                said_after = time.monotonic() - killed
                assert shown[0] == "LINK PROCESS DOWN" and "killed" in shown[1], shown
                print(f"LINK PROCESS DOWN on the page {said_after:.2f} s after the kill")

                # The go-to: taken before the kill (the ROV said so in time), or unknown; never
                # shown done by anything after the kill.
                # (Settled before it, it was rejected here: the vehicle is disarmed.)
                g = _order(procs, goto)
                if g["state"] == "unknown":
                    assert "link process ended" in g["reason"], g
                else:
                    at = g.get("t_" + g["state"])
                    assert at is not None and at < kill_t and "link process" not in (g.get("reason") or ""), \
                        (g["state"], kill_t, g)

                # STOP from the page while there is no link process: kept, not refused.
                page.keyboard.press("Escape")
                stop = wait_until_up(lambda: next((o for o in get_json(procs.base + "/api/orders")
                                                   if o["kind"] == "STOP"), None), 10)
                assert stop and stop["state"] not in (Fate.REFUSED, Fate.UNKNOWN), stop  # kept (or already confirmed)

                # Started again by the console, the banner goes; the STOP is confirmed by the new one.
                assert wait_until_up(lambda: _up(procs), 60), _why(procs)
                second = _link(procs)["link_process_pid"]
                assert second not in (first, console_pid) and _alive(second)
                page.wait_for_function("document.body.dataset.link === 'up'", timeout=30000)
                back = page.evaluate("[document.getElementById('link-banner').hidden,"
                                     " document.getElementById('link-banner-title').textContent]")
                assert back[0] or back[1] == "LINK PROCESS STARTED AGAIN", back
                page.wait_for_function("document.getElementById('link-banner').hidden", timeout=30000)
                confirmed = wait_until_up(lambda: _order(procs, stop["id"])["state"] == "acknowledged", 30)
                assert confirmed, _order(procs, stop["id"])

                log = [e["text"] for e in get_json(procs.base + "/api/log")]
                assert any(t.startswith("LINK PROCESS DOWN: it was killed") for t in log), log
                assert any(re.fullmatch(rf"link process started again \(pid {second}\)", t) for t in log), log
                # The counts go on across the restart (they are the session's).
                assert _link(procs)["sent"] > 0
            finally:
                browser.close()
    finally:
        procs.close()


def test_the_console_killed_its_link_process_sends_stop_then_stops_polling(tmp_path):
    procs = Processes(tmp_path, rov_args=("--budget", "0"))
    try:
        assert wait_until_up(lambda: _up(procs) and procs.pose()["autopilot"], 120), procs.logs_text()
        link_pid = _link(procs)["link_process_pid"]
        # It asks for a priority above the machine's other work; root may have it.
        from rovlink.link.process import LINK_NICE, LINK_RT_PRIORITY

        nice = _nice(link_pid)
        assert nice <= _nice(procs.procs["console"].pid)
        if os.geteuid() == 0:
            assert nice == LINK_NICE, nice
        # And real-time round-robin where this machine allows it (asked of a process of our own).
        probe = subprocess.run([sys.executable, "-c", "import os; os.sched_setscheduler(0, os.SCHED_RR, "
                                "os.sched_param(1))"], capture_output=True)
        if probe.returncode == 0:
            assert os.sched_getscheduler(link_pid) == os.SCHED_RR
            assert os.sched_getparam(link_pid).sched_priority == LINK_RT_PRIORITY
        else:
            assert os.sched_getscheduler(link_pid) == os.SCHED_OTHER
            assert "no real-time priority for the link process" in (tmp_path / "console.log").read_text()
        procs.kill_console()
        # The link process outlives the console only to stop the vehicle.
        assert wait_until_up(lambda: not _alive(link_pid), 20), procs.logs_text()
        console_log = (tmp_path / "console.log").read_text()
        assert "the console is gone; sending STOP, then no more polls" in console_log, console_log[-2000:]
        assert "STOP confirmed; polling stopped" in console_log, console_log[-2000:]
        # No poll after that: the ROV fails safe (it says so in its log).
        assert wait_until_up(lambda: "failsafe: neutral and brake" in (tmp_path / "rov.log").read_text(), 20), \
            procs.logs_text()
    finally:
        procs.close()


def test_what_a_link_process_held_when_it_ended_is_unknown_but_a_stop_goes_again():
    """The session's side of a link process's end, on its own: orders the master held
    and had not settled are unknown (not sent again), a request too; a STOP is kept
    for the next master, which confirms it under the same order id."""
    from rovlink.console.session.radio import Operator
    from rovlink.link.radio.master import StopConfirmed

    op = Operator(None)
    try:
        def next_master() -> None:  # what a new link process brings: a master that knows nothing
            op.master = type(op.master)(bitrate_bps=1900.0, delay_s=0.085, max_frame=op.master.max_frame)
            op.protocol_master = op.master

        goto = op.send_position(3.0, 0.0, 1.0)
        arm = op.arm(True)
        op._link_process_down("it was killed (signal 9)", op.now())
        states = {o["id"]: (o["state"], o["reason"]) for o in op.orders_state()}
        assert states[goto] == ("unknown", "the link process ended before the ROV answered; not sent again"), states
        assert states[arm] == ("unknown", "the link process ended before the ROV answered; not sent again"), states
        assert any(e["text"].startswith("LINK PROCESS DOWN: it was killed") and e["level"] == "alert"
                   for e in op.log_entries())
        next_master()
        op._link_process_up(4242, op.now())
        assert op.orders.last_master_id() is None  # nothing of the old master's is sent again

        # A STOP the next one held when it ended goes to the one after, and its
        # confirmation settles the pilot's STOP.
        stop = op.stop()
        op._link_process_down("it ended with exit code 1", op.now())
        assert {o["id"]: o["state"] for o in op.orders_state()}[stop] == "queued"
        next_master()
        op._link_process_up(4243, op.now())
        new_id = op.orders.last_master_id()
        assert new_id is not None and op.master.stopping
        op.handle_events([StopConfirmed(new_id, 2, op.now())], op.now())
        assert {o["id"]: o["state"] for o in op.orders_state()}[stop] == "acknowledged", op.orders_state()
    finally:
        op.close()
