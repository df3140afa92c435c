"""A pilot's bad day across restarts, with real processes (issue 21 of the held
stick): `rovlink rov` and `rovlink console --gcs` over real UDP with one key, a
pymavlink ground station streaming its joystick, and a page in headless
Chromium (its gamepad stood in for: headless Chromium has none).

- The console is killed while the stick is held forward; the ROV fails safe.
  The same console command starts again with the stick still forward: the
  vehicle does not move until the ground station's stick has been centred,
  and the ground station and the page are told "centre the sticks to drive".
- A page that takes control with its gamepad stick held forward: the same.
- The autopilot (`rovlink sim` as its own process) dies and comes back: the
  ground station's HEARTBEAT claims no mode meanwhile, and STATUSTEXT says so."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from rovlink.link.transports.transport import free_udp_port

from ..helpers import CHROMIUM, CHROMIUM_ARGS, free_tcp_port, get_json, needs_chromium, wait_until_up
from .pages import after_ticks

pytestmark = [pytest.mark.slow, pytest.mark.processes]
M = mavutil.mavlink
ROOT = Path(__file__).resolve().parents[2]


class Processes:
    """The ROV and a console joined by UDP; the console can be killed and started again."""

    def __init__(self, tmp_path: Path, *, mavlink: str | None = None, rov_args: tuple = ()) -> None:
        self.tmp = tmp_path
        self.key = tmp_path / "link.key"
        subprocess.run([sys.executable, "-m", "rovlink", "keygen", str(self.key)], check=True,
                       capture_output=True)
        self.console_udp, self.rov_udp = free_udp_port(), free_udp_port()
        self.gcs_port = free_udp_port()
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, object] = {}
        rov = [sys.executable, "-m", "rovlink", "rov", "--key", str(self.key), "--link",
               f"udp://127.0.0.1:{self.rov_udp}?peer=127.0.0.1:{self.console_udp}"]
        if mavlink:
            rov += ["--mavlink", mavlink]
        rov += list(rov_args)
        self._spawn("rov", rov)
        self.http = None
        self.start_console()

    def _spawn(self, name: str, argv: list[str]) -> None:
        log = open(self.tmp / f"{name}.log", "a")
        self.logs[name] = log
        self.procs[name] = subprocess.Popen(argv, cwd=ROOT, env=self.env, stdout=log, stderr=subprocess.STDOUT)

    def start_console(self) -> None:
        self.http = free_tcp_port()
        self._spawn("console", [sys.executable, "-m", "rovlink", "console", "--key", str(self.key), "--no-record",
                                "--port", str(self.http), "--viser-port", str(free_tcp_port()),
                                "--gcs", f"udpout:127.0.0.1:{self.gcs_port}", "--link",
                                f"udp://127.0.0.1:{self.console_udp}?peer=127.0.0.1:{self.rov_udp}"])

    def kill_console(self) -> None:
        p = self.procs["console"]
        p.send_signal(signal.SIGKILL)
        p.wait(10)

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.http}"

    def pose(self) -> dict:
        return get_json(self.base + "/api/pose")

    def logs_text(self) -> str:
        return "\n".join(f"--- {n}\n" + (self.tmp / f"{n}.log").read_text()[-2500:] for n in self.logs)

    def close(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        for p in self.procs.values():
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in self.logs.values():
            f.close()


class GroundStation:
    """A pymavlink ground station streaming MANUAL_CONTROL at 10 Hz from `stick_x`."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega",
                                               source_system=255, source_component=190)
        self.stick_x = 0
        self.stick_r = 0
        self.streaming = False
        self.texts: list[str] = []
        self.heartbeats: list = []
        self._lock = threading.Lock()
        self._running = True
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_send = 0.0
        while self._running:
            now = time.monotonic()
            # Once the gateway has been heard (udpin answers to its address).
            if self.streaming and now >= next_send and self.conn.clients:
                next_send = now + 0.1
                with self._lock:
                    self.conn.mav.manual_control_send(1, self.stick_x, 0, 500, self.stick_r, 0)
            m = self.conn.recv_match(blocking=True, timeout=0.05)
            if m is None:
                continue
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)
            elif m.get_type() == "HEARTBEAT":
                self.heartbeats.append((time.monotonic(), m.base_mode, m.custom_mode, m.system_status))

    def command(self, cmd: int, *params: float) -> None:
        with self._lock:
            self.conn.mav.command_long_send(1, 1, cmd, 0, *params, *([0] * (7 - len(params))))

    def close(self) -> None:
        self._running = False
        self._thread.join(2)
        self.conn.close()


def _why(procs: Processes) -> str:
    """What the console says now, in full (pytest cuts a dict short): for a failed wait."""
    import json

    try:
        state = get_json(procs.base + "/api/state")
        control = get_json(procs.base + "/api/control")
    except OSError as exc:
        return f"console unreachable: {exc}\n{procs.logs_text()}"
    pose = {k: v for k, v in state["pose"].items() if k not in ("trail", "path")}
    # Without the pictures' lines (three a second), which would hide everything else.
    log = [e["text"] for e in get_json(procs.base + "/api/log") if not e["text"].startswith("picture #")]
    return json.dumps({"pose": pose, "velocity_wish": state["velocity_wish"], "control": control,
                       "log": log[-12:]}, indent=1, default=str)


def _dead_man_since(procs: Processes, wall: float) -> bool:
    """Whether the console's dead man has neutralised the holder's streamed wish since `wall`."""
    return any("stopped arriving" in e["text"] and e["wall"] >= wall for e in get_json(procs.base + "/api/log"))


def _moved_m(a: dict, b: dict) -> float:
    return math.hypot(b["x_m"] - a["x_m"], b["y_m"] - a["y_m"])


def _fresh_pose(procs: Processes) -> dict:
    """The received pose, once a fresh one (under 1 s old) is there."""
    got = wait_until_up(lambda: (lambda p: p if p["received"] and (p["odometry_age_s"] or 9) < 1.0 else None)(
        procs.pose()), 30, 0.1)
    assert got, procs.logs_text()
    return got["received"]


def test_a_console_restarted_with_the_stick_held_does_not_drive_until_it_is_centred(tmp_path):
    procs = Processes(tmp_path)
    gcs = GroundStation(procs.gcs_port)
    try:
        assert wait_until_up(lambda: gcs.heartbeats and gcs.heartbeats[-1][3] != M.MAV_STATE_UNINIT, 120), \
            procs.logs_text()
        gcs.streaming = True  # sticks centred, streamed as a ground station does
        assert wait_until_up(lambda: get_json(procs.base + "/api/control")["holder"] == "ground station", 30)
        alt_hold = {v: k for k, v in mavutil.mode_mapping_sub.items()}["ALT_HOLD"]
        # Sent again when not followed, as a ground station does: on a loaded machine the
        # console may give a request up (not followed within 3 s) before the vehicle takes it.
        for _ in range(3):
            gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            gcs.command(M.MAV_CMD_DO_SET_MODE, 1, alt_hold)
            if wait_until_up(lambda: procs.pose()["armed"] and procs.pose()["mode"] == "DEPTH_HOLD", 20):
                break
        assert procs.pose()["armed"] and procs.pose()["mode"] == "DEPTH_HOLD", (_why(procs), procs.logs_text())
        start = _fresh_pose(procs)
        gcs.stick_x = 600
        assert wait_until_up(lambda: _moved_m(start, procs.pose()["received"]) > 1.0, 20), ("the stick drives", _why(procs))

        # The console dies with the stick forward; the ROV fails safe and holds.
        procs.kill_console()
        time.sleep(4.5)
        procs.start_console()
        assert wait_until_up(lambda: get_json(procs.base + "/api/link")["state"] == "up", 60), procs.logs_text()
        assert wait_until_up(lambda: get_json(procs.base + "/api/control")["holder"] == "ground station", 30)
        control = get_json(procs.base + "/api/control")
        assert control["centre_to_drive"], control
        held = _fresh_pose(procs)
        time.sleep(8.0)  # the stick still forward all along
        after = _fresh_pose(procs)
        assert _moved_m(held, after) < 0.5, (held, after)
        assert procs.pose()["hold"] is True  # nobody's neutral released no HOLD
        assert any("centre the sticks to drive" in t for t in gcs.texts), gcs.texts
        log = get_json(procs.base + "/api/log")
        assert any("centre the sticks to drive" in e["text"] for e in log)

        # Centred once, then forward: it drives.
        gcs.stick_x = 0
        assert wait_until_up(lambda: not get_json(procs.base + "/api/control")["centre_to_drive"], 10)
        time.sleep(1.0)
        gcs.stick_x = 600
        start = _fresh_pose(procs)
        assert wait_until_up(lambda: _moved_m(start, procs.pose()["received"]) > 1.0, 20), ("centred, then forward", _why(procs))
        gcs.stick_x = 0

        # The ghost does not jump when the stick moves: full yaw now changes nothing
        # before the wish can have reached the ROV, then the turn grows at the yaw rate.
        time.sleep(3.0)
        ghost = []
        t_end = time.monotonic() + 3.0
        gcs.stick_r = 1000
        while time.monotonic() < t_end:
            ghost.append((time.monotonic(), procs.pose()["predicted"]["yaw_deg"]))
            time.sleep(0.05)
        gcs.stick_r = 0
        steps = [abs((b - a + 180) % 360 - 180) / max(tb - ta, 0.05) for (ta, a), (tb, b) in zip(ghost, ghost[1:])]
        turned = abs((ghost[-1][1] - ghost[0][1] + 180) % 360 - 180)
        assert turned > 20, ghost  # it did turn
        # Between looks 50 ms apart: the turn at its rate (~62 deg/s) and the small corrections each
        # new pose brings, never the wish of now applied over the pose's whole age (a second or so of
        # full yaw at once, ~60 degrees: over 1000 deg/s between two looks).  Under a CI run's load a
        # look can come late and the next one early: a correction then read 339 deg/s once (the
        # limit was 300); a jump still reads well above 600.
        assert max(steps) < 600, (max(steps), ghost)
    finally:
        gcs.close()
        procs.close()


def _hold_control(page) -> None:
    """The page holds control: taken again if its WebSocket dropped meanwhile (on this
    2-core machine, beside software WebGL and a picture every 0.15 s, Chromium 156's
    socket was seen to close abnormally, 1006: control goes with it, by design)."""
    if page.is_visible("#take"):
        page.wait_for_function("document.getElementById('connection').textContent === 'online'", timeout=30000)
        page.click("#take")
        page.wait_for_function("document.getElementById('control-text').textContent.startsWith('You have control')")


def _centre_then_forward(page, procs: Processes) -> bool:
    """The page's held pad centred (the page told "You have control."), then forward again:
    True once the vehicle has moved a metre, False if the console's dead man neutralised the
    stick first (the page's repeats stalled: it asks for the sticks to be centred again), or
    the page lost control with its socket."""
    _hold_control(page)
    page.evaluate("() => { window.testPad.axes[1] = 0; }")  # centred
    # (After a dead man the console asks for centring first, then logs it: this is our centring.)
    assert wait_until_up(lambda: not get_json(procs.base + "/api/control")["centre_to_drive"], 30), _why(procs)
    page.wait_for_function("document.getElementById('control-text').textContent === 'You have control.'")
    since = time.time()
    page.evaluate("() => { window.testPad.axes[1] = -0.8; }")  # forward again
    start = _fresh_pose(procs)
    assert wait_until_up(lambda: _moved_m(start, procs.pose()["received"]) > 1.0 or _dead_man_since(procs, since),
                         20), _why(procs)
    return _moved_m(start, procs.pose()["received"]) > 1.0


# Headless Chromium has no gamepad: stand in for the Gamepad API, stick forward from the start.
HELD_PAD = """() => {
  const pad = { id: "held pad", index: 0, connected: true, mapping: "standard", axes: [0, -0.8, 0, 0],
                buttons: Array.from({ length: 17 }, () => ({ pressed: false, value: 0 })) };
  window.testPad = pad;
  navigator.getGamepads = () => [pad];
  window.dispatchEvent(Object.assign(new Event("gamepadconnected"), { gamepad: pad }));
}"""


@pytest.mark.browser
@needs_chromium
def test_a_page_taking_control_with_its_stick_held_drives_only_once_it_is_centred(tmp_path):
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import sync_playwright

    # Pictures off: on this fast link (no modem emulated) they came every 0.15 s, and a
    # page busy with them and the software-rendered scene on two cores lost its socket
    # (and control) within seconds; the held stick is what this test is about.
    procs = Processes(tmp_path, rov_args=("--budget", "0"))
    try:
        assert wait_until_up(lambda: get_json(procs.base + "/api/link")["state"] == "up"
                             and procs.pose()["autopilot"], 120), procs.logs_text()
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_context(viewport={"width": 1400, "height": 900}).new_page()
                page.goto(procs.base + "/?scene=off")  # (the held stick is what this is about)
                page.wait_for_function("document.body.dataset.configured === '1'", timeout=60000)
                page.evaluate(HELD_PAD)
                # The page's input loop reads the held pad before control is taken: a neutral
                # wish it sent before the pad existed, still on its way, must not be the first
                # input the desk sees from the new holder (it would count as centred).
                after_ticks(page, 3)
                page.click("#take")
                page.wait_for_function("document.getElementById('control-text').textContent"
                                       ".includes('centre the sticks to drive')")
                for _attempt in range(3):
                    _hold_control(page)  # (taken again, the stick still held, if the socket dropped)
                    assert "centre the sticks to drive" in page.text_content("#control-text")
                    try:
                        page.click("#arm", timeout=10000)
                        break
                    except PlaywrightTimeout:
                        continue  # control went with the socket before the click
                assert wait_until_up(lambda: procs.pose()["armed"], 30), procs.pose()
                held = _fresh_pose(procs)
                time.sleep(5.0)
                # Not one metre, whoever holds control now: the stick was never centred.
                assert _moved_m(held, _fresh_pose(procs)) < 0.5
                assert get_json(procs.base + "/api/state")["velocity_wish"] == {
                    "vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.0}
                # Centred, then forward again: it drives.  The page repeats the held stick every
                # 100 ms; on a loaded machine its input loop can stall for over the console's 1 s
                # dead man (measured: up to 2 s beside other browser tests on 2 cores), which then
                # neutralises the wish and, the stick's state unknown, asks for the sticks to be
                # centred again: as designed, and a pilot would be asked the same.  A CI run saw
                # no metre in 20 s so.  The pilot centres again then; any other stillness fails.
                for _attempt in range(4):
                    if _centre_then_forward(page, procs):
                        break
                else:
                    pytest.fail("the page's stick stalled past the dead man at every try:\n" + _why(procs))
                page.evaluate("() => { window.testPad.axes[1] = 0; }")
            finally:
                browser.close()
    finally:
        procs.close()


def test_the_ground_station_sees_the_autopilot_lost_and_back_without_a_made_up_mode(tmp_path):
    sim_port = free_udp_port()
    sim_log = open(tmp_path / "sim.log", "w")
    sim_argv = [sys.executable, "-m", "rovlink", "sim", "--mavlink", f"udpin:127.0.0.1:{sim_port}"]
    sim = subprocess.Popen(sim_argv, cwd=ROOT, stdout=sim_log, stderr=subprocess.STDOUT)
    procs = Processes(tmp_path, mavlink=f"udpout:127.0.0.1:{sim_port}")
    gcs = GroundStation(procs.gcs_port)
    try:
        assert wait_until_up(lambda: gcs.heartbeats and gcs.heartbeats[-1][1] & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                             and gcs.heartbeats[-1][3] != M.MAV_STATE_CRITICAL, 120), procs.logs_text()
        sim.send_signal(signal.SIGKILL)
        sim.wait(10)
        lost_at = time.monotonic()
        assert wait_until_up(lambda: any("autopilot lost" in t for t in gcs.texts), 30), gcs.texts
        assert wait_until_up(lambda: procs.pose()["autopilot"] is False, 10)
        time.sleep(2.5)
        during = [h for h in gcs.heartbeats if h[0] > time.monotonic() - 2.0]
        assert during and all(not h[1] & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and h[3] == M.MAV_STATE_CRITICAL
                              for h in during), during
        sim = subprocess.Popen(sim_argv, cwd=ROOT, stdout=sim_log, stderr=subprocess.STDOUT)
        assert wait_until_up(lambda: any("autopilot back" in t for t in gcs.texts), 60), gcs.texts
        assert wait_until_up(lambda: gcs.heartbeats[-1][1] & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 10)
        assert time.monotonic() - lost_at > 3
    finally:
        gcs.close()
        procs.close()
        if sim.poll() is None:
            sim.terminate()
            sim.wait(10)
        sim_log.close()

