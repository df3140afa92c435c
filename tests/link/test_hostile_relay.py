"""Version 2 between real processes with a hostile radio in the middle (issue 16).

`rovlink rov` and `rovlink console` run as processes with one key; every
datagram between them passes a relay in this test over real UDP on loopback.
The relay reads what it carries (frames are authenticated, not encrypted) and
misbehaves as a radio can: it holds a reply back past the master's resend,
drops every poll carrying STOP for 4 s while HELLO and SYNC pass, or counts
frame sizes under an `mtu` cap.  The pilot's view is read from the console's
REST API, as the page reads it."""

from __future__ import annotations

import json
import os
import select
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from ..helpers import free_tcp_port, get_json, wait_until_up

ROOT = Path(__file__).resolve().parents[2]
STOP = 4
pytestmark = [pytest.mark.slow, pytest.mark.processes]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _poll_order(frame: bytes) -> int | None:
    """The ORDER of a version 2 poll (None for a HELLO)."""
    return None if len(frame) < 3 or frame[2] & 0x40 else frame[2] & 0x0F


class Relay:
    """Console <-> relay <-> ROV over UDP.  `console_side` is the console's peer,
    `rov_side` the ROV's."""

    def __init__(self, console_port: int, rov_port: int) -> None:
        self.a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the console
        self.a.bind(("127.0.0.1", 0))
        self.b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the ROV
        self.b.bind(("127.0.0.1", 0))
        self.console_addr = ("127.0.0.1", console_port)
        self.rov_addr = ("127.0.0.1", rov_port)
        self.lock = threading.Lock()
        self.drop_stop_until = 0.0  # monotonic time
        self.drop_stop_for_s: float | None = None  # armed: the window starts at the first STOP poll
        self.hold_next_reply_s: float | None = None
        self.held_at: float | None = None
        self.polls_since_held = 0  # a held reply goes only once the master has polled again (it is late)
        self.stop_polls_passed: list[float] = []
        self.stop_polls_dropped = 0
        self.sizes: list[int] = []
        self._delayed: list[tuple[float, bytes]] = []
        self._running = True
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def console_side(self) -> int:
        return self.a.getsockname()[1]

    @property
    def rov_side(self) -> int:
        return self.b.getsockname()[1]

    def _run(self) -> None:
        while self._running:
            now = time.monotonic()
            with self.lock:
                # Held past its time and past the master's next poll, whatever the machine's
                # load: then it is a late reply for certain (a loaded run once saw the master
                # poll again only after 1.5 s, and the held reply was then on time).
                due = [d for d in self._delayed if d[0] <= now and self.polls_since_held]
                self._delayed = [d for d in self._delayed if d not in due]
            for _, data in due:
                self.a.sendto(data, self.console_addr)
            ready, _, _ = select.select([self.a, self.b], [], [], 0.005)
            for sock in ready:
                data, _ = sock.recvfrom(4096)
                now = time.monotonic()
                self.sizes.append(len(data))
                if sock is self.a:
                    self._poll(data, now)
                else:
                    self._reply(data, now)

    def _poll(self, data: bytes, now: float) -> None:
        with self.lock:
            if self.held_at is not None:
                self.polls_since_held += 1
            if _poll_order(data) == STOP:
                if self.drop_stop_for_s is not None:
                    self.drop_stop_until, self.drop_stop_for_s = now + self.drop_stop_for_s, None
                if now < self.drop_stop_until:
                    self.stop_polls_dropped += 1
                    return
                self.stop_polls_passed.append(now)
        self.b.sendto(data, self.rov_addr)

    def _reply(self, data: bytes, now: float) -> None:
        with self.lock:
            if self.hold_next_reply_s is not None:
                self._delayed.append((now + self.hold_next_reply_s, data))
                self.hold_next_reply_s, self.held_at = None, now
                return
        self.a.sendto(data, self.console_addr)

    def close(self) -> None:
        self._running = False
        self._thread.join(2)
        self.a.close()
        self.b.close()


def _start(tmp_path, *, mtu: int | None = None):
    key = tmp_path / "link.key"
    if not key.exists():
        subprocess.run([sys.executable, "-m", "rovlink", "keygen", str(key)], check=True, capture_output=True)
    console_udp, rov_udp = _free_udp_port(), _free_udp_port()
    relay = Relay(console_udp, rov_udp)
    cap = f"&mtu={mtu}" if mtu else ""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    http = free_tcp_port()
    logs = {name: open(tmp_path / f"{name}.log", "w") for name in ("rov", "console")}
    rov = subprocess.Popen([sys.executable, "-m", "rovlink", "rov", "--key", str(key), "--link",
                            f"udp://127.0.0.1:{rov_udp}?peer=127.0.0.1:{relay.rov_side}{cap}"],
                           cwd=ROOT, env=env, stdout=logs["rov"], stderr=subprocess.STDOUT)
    console = subprocess.Popen([sys.executable, "-m", "rovlink", "console", "--key", str(key), "--no-record",
                                "--port", str(http), "--viser-port", str(free_tcp_port()), "--link",
                                f"udp://127.0.0.1:{console_udp}?peer=127.0.0.1:{relay.console_side}{cap}"],
                               cwd=ROOT, env=env, stdout=logs["console"], stderr=subprocess.STDOUT)
    return relay, rov, console, f"http://127.0.0.1:{http}", logs


def _stop(relay, procs, logs):
    for p in procs:
        p.terminate()
    for p in procs:
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
    relay.close()
    for f in logs.values():
        f.close()


def _post(url: str, body: dict | None = None, client: str | None = None) -> dict:
    data = json.dumps(body or {}).encode()
    req = urllib.request.Request(url, data=data, method="POST", headers={"Content-Type": "application/json"})
    if client:
        req.add_header("X-Rovlink-Client", client)
    with urllib.request.urlopen(req, timeout=10) as r:
        text = r.read()
    return json.loads(text) if text else {}


def _order(base: str, order_id: int) -> dict:
    return next(o for o in get_json(base + "/api/orders") if o["id"] == order_id)


def _logs(tmp_path) -> str:
    return "\n".join(f"--- {n}\n" + (tmp_path / f"{n}.log").read_text()[-3000:] for n in ("rov", "console"))


def test_stop_is_never_shown_done_before_a_stop_poll_got_through(tmp_path):
    relay, rov, console, base, logs = _start(tmp_path)
    try:
        up = wait_until_up(lambda: get_json(base + "/api/link")["state"] == "up"
                           and get_json(base + "/api/pose")["autopilot"], 120)
        assert up, _logs(tmp_path)
        client = _post(base + "/api/control/take", {"name": "pilot"})["client_id"]
        # A first STOP passes: the vehicle brakes (POS_HOLD or DEPTH_HOLD) and sets HOLD.
        first = _post(base + "/api/orders/stop", client=client)["id"]
        assert wait_until_up(lambda: _order(base, first)["state"] == "acknowledged", 30), \
            (_order(base, first), _logs(tmp_path))
        # The stick held forward: HOLD stays up (the ROV ignores it), so every reply, SYNCs
        # included, now shows HOLD, AUTOPILOT and a hold mode: what confirms a STOP.
        _post(base + "/api/orders/velocity", {"vx": 0.6, "vy": 0, "vz": 0, "vyaw": 0}, client=client)
        time.sleep(1.0)
        # The radio holds the next reply back 1.5 s (past the master's resend) and drops every
        # poll carrying STOP for 4 s from the first one.
        with relay.lock:
            relay.drop_stop_for_s = 4.0
            relay.hold_next_reply_s = 1.5
        assert wait_until_up(lambda: relay.held_at is not None, 10)
        second = _post(base + "/api/orders/stop", client=client)["id"]
        shown_done_at = None
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            state = _order(base, second)["state"]
            if state == "acknowledged":
                shown_done_at = time.monotonic()
                break
            time.sleep(0.05)
        assert shown_done_at is not None, (_order(base, second), _logs(tmp_path))
        assert relay.stop_polls_dropped >= 2  # the window was real: HELLOs went out meanwhile
        passed_after = [t for t in relay.stop_polls_passed if t >= relay.drop_stop_until]
        assert passed_after and shown_done_at > passed_after[0], (
            f"STOP shown done at {shown_done_at:.3f}, first STOP poll through at "
            f"{passed_after[0] if passed_after else None}, window ended {relay.drop_stop_until:.3f}")
        assert get_json(base + "/api/link")["late_replies"] >= 1  # the held reply, counted, not used
    finally:
        _stop(relay, [console, rov], logs)


def test_with_mtu_64_on_both_ends_every_frame_fits_and_pictures_complete(tmp_path):
    relay, rov, console, base, logs = _start(tmp_path, mtu=64)
    try:
        done = wait_until_up(lambda: len(get_json(base + "/api/images")) >= 2, 180)
        assert done, (get_json(base + "/api/link"), _logs(tmp_path))
        assert relay.sizes and max(relay.sizes) <= 64
        assert max(relay.sizes) == 64  # the trunks fill the cap, tag included
    finally:
        _stop(relay, [console, rov], logs)

