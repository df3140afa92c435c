"""The acoustic link in a process of its own (issue 33; link/acoustic/process.py).

With real processes (`rovlink rov` and `rovlink console` on the real `wlmodem://`
transport, through two emulated Modem-M64s on pseudo-terminals at four times the
modem's pace):
- the link process killed outright: /api/link says so at once (link_process
  "down", with why), the console starts it again (a new pid), the log says both;
  an order it held is shown unknown, never done; a STOP pressed meanwhile is kept
  and confirmed through the next one; the console ended, the new one sends STOP;
- the console killed outright: its link process sends STOP, the ROV takes it (its
  log says so), then the link process sends nothing more and ends; the ROV's
  failsafe follows.
On its own, the session's side: what a link process's machine held when it ended."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest

from rovlink.console.session.fates import Fate
from rovlink.link.emulators.m64 import M64Params

from ..helpers import free_tcp_port
from .acoustic_rig import end_processes, get, post, wait_for

ROVLINK = [sys.executable, "-m", "rovlink"]
FAST = M64Params(round_s=0.25, b_offset_s=0.125, latency_s=0.4, sync_s=1.0)
FAILSAFE_S = 6
K = bytes(range(32))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a child not reaped yet is a zombie: ended all the same
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


class AcousticRig:
    """The emulated modem pair, `rovlink rov` (its log in rov.log) and `rovlink
    console` (its output, and its link process's, in console.log)."""

    def __init__(self, tmp) -> None:
        from rovlink.link.emulators.m64serial import M64SerialPair

        self.tmp = tmp
        key = tmp / "link.key"
        subprocess.run(ROVLINK + ["keygen", str(key)], check=True, capture_output=True, timeout=60)
        self.pair = M64SerialPair(str(tmp / "op-modem"), str(tmp / "rov-modem"), params=FAST, seed=7)
        self.pair.start()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        port = free_tcp_port()
        with open(tmp / "rov.log", "w") as rov_log, open(tmp / "console.log", "w") as console_log:
            self.rov = subprocess.Popen(ROVLINK + ["rov", "--link", f"wlmodem://{tmp}/rov-modem?role=b&channel=4",
                                                   "--key", str(key), "--failsafe", str(FAILSAFE_S), "-v"],
                                        stdout=subprocess.DEVNULL, stderr=rov_log, env=env)
            self.console = subprocess.Popen(
                ROVLINK + ["console", "--link", f"wlmodem://{tmp}/op-modem?role=a&channel=4", "--key", str(key),
                           "--port", str(port), "--viser-port", str(free_tcp_port()), "--no-record"],
                stdout=console_log, stderr=subprocess.STDOUT, env=env, cwd=tmp)
        self.base = f"http://127.0.0.1:{port}"

    def link(self) -> dict:
        return get(self.base + "/api/link")

    def order(self, order_id: int) -> dict | None:
        return next((o for o in get(self.base + "/api/orders") if o["id"] == order_id), None)

    def up(self) -> bool:
        link = self.link()
        return link["link_process"] == "up" and link["state"] == "up" and get(self.base + "/api/pose")["received"]

    def logs(self) -> str:
        return "\n".join(f"--- {name}\n" + (self.tmp / name).read_text()[-3000:] for name in ("console.log", "rov.log"))

    def close(self) -> None:
        # The console first: its link process sends STOP as it ends, which the ROV still takes.
        end_processes(self.console)
        end_processes(self.rov)
        self.pair.close()


@pytest.fixture
def rig(tmp_path):
    rig = AcousticRig(tmp_path)
    try:
        assert wait_for(rig.up, 120), rig.logs()
        yield rig
    finally:
        rig.close()


@pytest.mark.slow
@pytest.mark.processes
def test_the_acoustic_link_process_killed_is_said_at_once_started_again_and_nothing_it_held_is_shown_done(rig):
    first = rig.link()["link_process_pid"]
    assert first and first != rig.console.pid and _alive(first)
    me = {"X-Rovlink-Client": post(rig.base + "/api/control/take", {"name": "script"})["client_id"]}
    here = get(rig.base + "/api/pose")["received"]
    goto = post(rig.base + "/api/orders/position",
                {"x_m": here["x_m"] + 3.0, "y_m": here["y_m"], "z_m": here["z_m"]}, me)["id"]
    kill_t = rig.link()["t"]  # session time, as the orders' times
    os.kill(first, signal.SIGKILL)
    killed = time.monotonic()

    # Said at once, with why, before the console has started the next one.
    down = wait_for(lambda: (lambda link: link if link["link_process"] == "down" else None)(rig.link()), 10,
                    every_s=0.05)
    said_after = time.monotonic() - killed
    assert down and "killed (signal 9)" in down["link_process_reason"] and down["link_process_pid"] is None, down
    print(f"link_process down in /api/link {said_after:.2f} s after the kill")

    # STOP while there is no link process: kept, not refused.
    stop = post(rig.base + "/api/orders/stop", {}, me)["id"]
    assert rig.order(stop)["state"] not in (Fate.REFUSED, Fate.UNKNOWN), rig.order(stop)  # kept (or confirmed)

    # The go-to: taken and told before the kill, or unknown; never shown done by anything after it.
    g = rig.order(goto)
    if g["state"] == "unknown":
        assert "link process ended" in g["reason"], g
    else:
        at = g.get("t_" + g["state"])
        assert at is not None and at < kill_t, (g, kill_t)

    # Started again, with a new pid; the STOP is confirmed by the new one.
    assert wait_for(lambda: rig.link()["link_process"] == "up", 60), rig.logs()
    second = rig.link()["link_process_pid"]
    assert second not in (first, rig.console.pid) and _alive(second)
    assert wait_for(lambda: rig.order(stop)["state"] == "acknowledged", 90), (rig.order(stop), rig.logs())
    assert Fate(rig.order(goto)["state"]) not in (Fate.ARRIVED, Fate.DONE), rig.order(goto)

    log = get(rig.base + "/api/log")
    down_lines = [e for e in log if e["text"].startswith("LINK PROCESS DOWN: it was killed (signal 9)")]
    assert down_lines and down_lines[0]["level"] == "alert" and down_lines[0]["cause"] == "process", log
    assert down_lines[0]["cleared_wall"] is not None  # the alert cleared once it runs again
    assert any(re.fullmatch(rf"link process started again \(pid {second}\)", e["text"]) for e in log), log
    assert rig.link()["state"] == "up" and rig.link()["sent"] > 0

    # The console ended as a pilot ends it (SIGTERM): its link process, the second, sends STOP first.
    rig.console.terminate()
    rig.console.wait(40)
    assert not _alive(second)
    assert "STOP taken by the ROV; sending stopped" in (rig.tmp / "console.log").read_text(), rig.logs()


@pytest.mark.slow
@pytest.mark.processes
def test_the_console_killed_its_acoustic_link_process_sends_stop_then_nothing_and_the_rov_holds(rig):
    link_pid = rig.link()["link_process_pid"]
    assert link_pid and _alive(link_pid)
    rov_log = rig.tmp / "rov.log"
    stops_before = rov_log.read_text().count("STOP: brake")
    rig.console.send_signal(signal.SIGKILL)
    rig.console.wait(10)
    # The link process outlives the console only to stop the vehicle.
    assert wait_for(lambda: not _alive(link_pid), 40), rig.logs()
    console_log = (rig.tmp / "console.log").read_text()
    assert "the console is gone; sending STOP, then nothing more" in console_log, rig.logs()
    assert "STOP taken by the ROV; sending stopped" in console_log, rig.logs()
    # The ROV braked on that STOP, then heard nothing more: its failsafe (hold) engages.
    assert rov_log.read_text().count("STOP: brake") > stops_before, rig.logs()
    assert wait_for(lambda: "FAILSAFE: nothing from the operator" in rov_log.read_text(), 60), rig.logs()
    assert rig.rov.poll() is None


def test_what_an_acoustic_link_process_held_when_it_ended_is_unknown_but_a_stop_goes_again():
    """The session's side of a link process's end, on its own: the machines it
    calls are real `AcousticOperator`s in session with a simulated ROV
    (link/acoustic/sim.py), one per link process.  Orders the ROV had not answered
    are unknown, not sent again; a STOP unconfirmed when its process ended, and one
    pressed while none ran, are pressed again in the next one, under the same order,
    and confirmed there."""
    from rovlink.console.session.acoustic import AcousticSession
    from rovlink.console.session.radio import NotNow
    from rovlink.link import acoustic as ac
    from rovlink.link.acoustic.process import AcousticLinkProcess
    from rovlink.link.acoustic.sim import AcousticSim

    def machine() -> AcousticSim:  # what a link process brings: a machine that knows nothing yet
        sim = AcousticSim(K, seed=3)
        while not sim.operator.ready:
            sim.run_until(sim.now + 1.0)
            assert sim.now < 120, "no session"
        return sim

    session = AcousticSession(None, K)
    try:
        def states() -> dict:
            return {o["id"]: o["state"] for o in session.orders_state()}

        def process_up(sim: AcousticSim, pid: int) -> None:
            session.op = sim.operator
            session._link_process_up(pid)

        process_up(machine(), 4241)
        goto = session.send_position(3.0, 0.0, 1.0)
        arm = session.arm(True)
        session._mark_sending()  # the go-to's first packet went
        assert states()[goto] == "sent" and states()[arm] == "queued"
        session._link_process_down("it was killed (signal 9)")
        assert states()[goto] == "unknown" and states()[arm] == "unknown", states()
        reasons = {o["id"]: o["reason"] for o in session.orders_state()}
        assert reasons[goto] == reasons[arm] == "the link process ended before the ROV answered; not sent again"
        line = [e for e in session.log_entries() if e["text"].startswith("LINK PROCESS DOWN: it was killed")]
        assert line and line[0]["level"] == "alert" and line[0]["cause"] == "process"

        # No link process: orders are refused with why, a STOP is kept (and a second press joins it).
        session.op = AcousticLinkProcess("wlmodem:///dev/null?role=a", K)  # not running: every call says so
        with pytest.raises(NotNow, match="not running"):
            session.send_position(1.0, 0.0, 1.0)
        stop = session.stop()
        assert session.stop() == stop and states()[stop] == "queued" and session.stopping()

        sim = machine()
        process_up(sim, 4242)
        assert sim.operator.stop_active and states()[stop] == "sent"
        assert any(e["text"] == "link process started again (pid 4242)" for e in session.log_entries())
        assert line[0]["text"] in [e["text"] for e in session.log_entries() if e["cleared_wall"] is not None]

        # Its process ends before the ROV confirms it: the next one presses it again.
        session._link_process_down("it ended with exit code 3")
        assert states()[stop] == "queued" and session.stopping()
        sim = machine()
        process_up(sim, 4243)
        assert sim.operator.stop_active and states()[stop] == "sent"
        sim.run_until(sim.now + 20)
        taken = [e for _, e in sim.events(ac.StopTaken)]
        assert taken, "the ROV never took the STOP"
        session._handle(taken, session.now())
        assert states()[stop] == "acknowledged", states()
        assert not session.stopping()
        assert not {"done", "arrived", "followed"} & set(states().values()), states()
    finally:
        session.close()


def test_a_console_started_while_its_modem_is_held_waits_for_it_and_says_so(tmp_path, capsys):
    """A console started while the last one's link process still holds the modem (its
    STOP under way) waits for the port, saying so once, then opens it; one held longer
    than the wait is one clear line.  On the emulated Modem-M64's pty, locked by
    another program as a link process locks it."""
    import asyncio
    import threading

    import serial

    from rovlink.command import CommandError
    from rovlink.console.commands.console import _open_first
    from rovlink.console.linkthread import LinkThread
    from rovlink.link.emulators.m64serial import M64SerialPair
    from rovlink.link.transports.urls import open_transport

    pair = M64SerialPair(str(tmp_path / "op-modem"), str(tmp_path / "rov-modem"), params=FAST, seed=1)
    pair.start()
    url = f"wlmodem://{tmp_path}/op-modem?role=a&channel=4"

    def hold() -> serial.Serial:
        port = serial.Serial(exclusive=True)
        port.port = str(tmp_path / "op-modem")
        port.open()
        return port

    async def open_first(wait_s: float) -> None:
        link = LinkThread().start()
        try:
            await _open_first(link, open_transport(url), url, wait_s, keep_open=False)
        finally:
            await link.stop()

    try:
        holder = hold()
        threading.Timer(1.5, holder.close).start()  # the old link process ends
        asyncio.run(open_first(20.0))
        said = capsys.readouterr().err
        assert said.count(f"{url} is in use (a console that ended may still be sending its STOP); "
                          f"waiting up to 20 s") == 1, said
        holder = hold()  # held for good: one line, no console
        try:
            with pytest.raises(CommandError, match="is in use: another program holds it"):
                asyncio.run(open_first(1.0))
        finally:
            holder.close()
    finally:
        pair.close()
