"""What the acoustic tests share: the console's API read and written over HTTP,
waiting for a condition, and a hostile radio between the two emulated modems."""

from __future__ import annotations

import json
import subprocess
import threading
import time
import urllib.request

from rovlink.link.emulators.m64 import Delivery


def get(url: str):
    with urllib.request.urlopen(url, timeout=10) as r:
        body = r.read()
        return json.loads(body) if r.headers.get_content_type() == "application/json" else body


def post(url: str, body: dict | None = None, headers: dict | None = None):
    req = urllib.request.Request(url, data=json.dumps(body or {}).encode(), method="POST",
                                 headers={"Content-Type": "application/json", **(headers or {})})
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())


def post_status(url: str, body: dict | None = None) -> int:
    """POST, and the HTTP status it got (an error status too)."""
    import urllib.error

    try:
        post(url, body)
    except urllib.error.HTTPError as exc:
        return exc.code
    return 200


def wait_for(fn, timeout_s: float, every_s: float = 0.25):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            value = fn()
        except (OSError, ValueError, KeyError, TypeError):
            value = None
        if value:
            return value
        time.sleep(every_s)
    return None


class HostileRadio:
    """Between the two emulated modems: records what the operator's modem sends and,
    when asked, delivers recorded packets to the ROV's modem again."""

    def __init__(self, channel) -> None:
        self._deliver = channel.deliver
        channel.deliver = self.deliver
        self.uplink: list[bytes] = []
        self._lock = threading.Lock()
        self._replay: list[bytes] = []
        self.cut = False  # True: nothing gets through, either way (the modems still take turns)

    def deliver(self, now):
        out = self._deliver(now)
        with self._lock:
            if self.cut:
                return []
            self.uplink += [d.data for d in out if d.to == "b"]
            out += [Delivery("b", p, now) for p in self._replay]
            self._replay = []
        return out

    def goto_frame(self) -> list[bytes]:
        """The last GOTO frame the operator sent (KIND 4: its packet and the next)."""
        with self._lock:
            packets = list(self.uplink)
        for i in range(len(packets) - 2, -1, -1):
            if packets[i][0] & 0xF0 == 0x40:
                return packets[i:i + 2]
        return []

    def replay(self, packets: list[bytes]) -> None:
        with self._lock:
            self._replay += packets


def end_processes(*procs: subprocess.Popen) -> None:
    """SIGTERM to those still running, then their output read to the end (a pipe
    left full would hold them); SIGKILL for any that lingers 20 s."""
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
