"""The MAVLink ground-station gateway (`--gcs`): a pymavlink ground station and
MAVProxy against `rovlink demo` as a real process, and the link's loss seen
from a ground station against the in-process stack."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
import time
import urllib.request

import pytest
from pymavlink import mavutil

from rovlink.console.gcs import DeskCommands, GcsGateway
from rovlink.link.transports.transport import free_udp_port

from ..helpers import free_tcp_port
from .conftest import running_console, wait_for

pytestmark = pytest.mark.slow
M = mavutil.mavlink


def _ground_station(port: int):
    return mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega",
                                      source_system=255, source_component=190)


def _ack(gcs, command: int, timeout_s: float = 15.0):
    """The final COMMAND_ACK of `command` (after IN_PROGRESS), every result seen, and
    the STATUSTEXTs that came meanwhile (for a failure's message)."""
    results, texts = [], []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = gcs.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=1)
        if m is not None and m.get_type() == "STATUSTEXT":
            texts.append(m.text)
        elif m is not None and m.command == command:
            results.append(m.result)
            if m.result != M.MAV_RESULT_IN_PROGRESS:
                return m.result, results, texts
    return None, results, texts


def _orders(web: str) -> list:
    """The console's orders with their fates (for a failure's message)."""
    try:
        return json.load(urllib.request.urlopen(f"{web}/api/orders", timeout=10))
    except OSError as exc:
        return [f"/api/orders unreadable: {exc}"]


def _heartbeat(gcs, predicate, timeout_s: float = 15.0, proc=None):
    """The first HEARTBEAT `predicate` takes, or None after `timeout_s` (or as soon
    as `proc`, the program sending them, has ended)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and (proc is None or proc.poll() is None):
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=2)
        if hb is not None and predicate(hb):
            return hb
    return None


@pytest.fixture(scope="module")
def demo():
    """`rovlink demo --gcs udpout:...` at 9600 bit/s, with a ground station listening."""
    port, web = free_udp_port(), free_tcp_port()
    gcs = _ground_station(port)
    proc = subprocess.Popen([sys.executable, "-m", "rovlink", "demo", "--port", str(web), "--viser-port",
                             str(free_tcp_port()), "--no-record", "--bitrate", "9600", "--gcs", f"udpout:127.0.0.1:{port}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        hb = _heartbeat(gcs, lambda hb: hb.system_status != M.MAV_STATE_UNINIT, 240,  # (a fresh checkout compiles
                        proc)                                                         # the codec first)
        assert hb is not None, "no HEARTBEAT with a vehicle state from the gateway"
        yield gcs, f"http://127.0.0.1:{web}"
    finally:
        proc.terminate()
        out = proc.communicate(timeout=30)[0]
        gcs.close()
        assert proc.returncode == 0, out[-2000:]


def test_the_ground_station_sees_an_ardusub_submarine(demo):
    gcs, _ = demo
    hb = _heartbeat(gcs, lambda hb: True)
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_SUBMARINE, M.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert mavutil.mode_mapping_sub[hb.custom_mode] in ("MANUAL", "ALT_HOLD", "STABILIZE", "POSHOLD")
    for kind in ("ATTITUDE", "VFR_HUD", "SYS_STATUS", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"):
        assert gcs.recv_match(type=kind, blocking=True, timeout=10) is not None, kind
    gcs.mav.param_request_list_send(1, 1)
    params = [gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=5) for _ in range(3)]
    assert all(params) and params[0].param_count == 3
    gcs.mav.mission_request_list_send(1, 1)
    count = gcs.recv_match(type="MISSION_COUNT", blocking=True, timeout=5)
    assert count is not None and count.count == 0


def test_arm_mode_and_drive_from_the_ground_station(demo):
    gcs, web = demo
    gcs.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    result, seen, texts = _ack(gcs, M.MAV_CMD_COMPONENT_ARM_DISARM)
    assert result == M.MAV_RESULT_ACCEPTED and seen[0] == M.MAV_RESULT_IN_PROGRESS, (seen, texts, _orders(web))
    assert _heartbeat(gcs, lambda hb: hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    alt_hold = {v: k for k, v in mavutil.mode_mapping_sub.items()}["ALT_HOLD"]
    gcs.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, alt_hold,
                              0, 0, 0, 0, 0)
    result, seen, texts = _ack(gcs, M.MAV_CMD_DO_SET_MODE)
    assert result == M.MAV_RESULT_ACCEPTED, (seen, texts, _orders(web))
    assert _heartbeat(gcs, lambda hb: hb.custom_mode == alt_hold)
    # The console says so too: one truth.
    state = json.load(urllib.request.urlopen(f"{web}/api/state", timeout=10))
    assert state["pose"]["armed"] is True and state["pose"]["mode"] == "DEPTH_HOLD"
    assert state["control"]["held"] and state["control"]["holder"] == "ground station"
    start = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=10)
    for _ in range(5):  # the sticks centred first, as a ground station streams them
        gcs.mav.manual_control_send(1, 0, 0, 500, 0, 0)
        time.sleep(0.1)
    until = time.monotonic() + 6
    while time.monotonic() < until:
        gcs.mav.manual_control_send(1, 700, 0, 500, 0, 0)
        time.sleep(0.1)
    end = None
    for _ in range(30):
        end = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=1) or end
    assert end.x - start.x > 1.5, (start, end)
    acro = {v: k for k, v in mavutil.mode_mapping_sub.items()}["ACRO"]
    gcs.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, acro, 0, 0, 0, 0, 0)
    assert _ack(gcs, M.MAV_CMD_DO_SET_MODE)[0] == M.MAV_RESULT_DENIED
    gcs.mav.command_long_send(1, 1, M.MAV_CMD_DO_PAUSE_CONTINUE, 0, 0, 0, 0, 0, 0, 0, 0)
    assert _ack(gcs, M.MAV_CMD_DO_PAUSE_CONTINUE, 20)[0] == M.MAV_RESULT_ACCEPTED


@pytest.mark.skipif(shutil.which("mavproxy.py") is None,
                    reason="MAVProxy is not installed (pip install MAVProxy; the test extra installs it)")
def test_mavproxy_arms_and_changes_mode():
    port, web = free_udp_port(), free_tcp_port()
    demo = subprocess.Popen([sys.executable, "-m", "rovlink", "demo", "--port", str(web), "--viser-port",
                             str(free_tcp_port()), "--no-record", "--bitrate", "9600", "--gcs", f"udpout:127.0.0.1:{port}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    mavproxy = subprocess.Popen(["mavproxy.py", f"--master=udpin:127.0.0.1:{port}", "--state-basedir",
                                 str(_tmp_dir())], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, bufsize=1)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(mavproxy.stdout), daemon=True).start()
    try:
        assert wait_for(lambda: any("online system 1" in line for line in lines), 240), "".join(lines)
        # The gateway's HEARTBEATs come before the link to the ROV is up; a pilot waits for
        # it (MAVProxy shows "link to ROV lost" until then; a loaded run's ARM went first
        # and was, rightly, TEMPORARILY_REJECTED).
        assert wait_for(lambda: _link_state(f"http://127.0.0.1:{web}") == "up", 120), "".join(lines)
        mavproxy.stdin.write("arm throttle\n")
        mavproxy.stdin.flush()
        assert wait_for(lambda: any("ARMED" in line for line in lines), 20), "".join(lines)
        mavproxy.stdin.write("mode ALT_HOLD\n")
        mavproxy.stdin.flush()
        assert wait_for(lambda: any("DO_SET_MODE: ACCEPTED" in line for line in lines), 20), "".join(lines)
        state = json.load(urllib.request.urlopen(f"http://127.0.0.1:{web}/api/state", timeout=10))
        assert state["pose"]["armed"] is True and state["pose"]["mode"] == "DEPTH_HOLD"
    finally:
        mavproxy.kill()  # MAVProxy's own threads outlive SIGTERM
        demo.terminate()
        mavproxy.wait(20)
        demo.wait(30)


def _link_state(web: str) -> str | None:
    try:
        return json.load(urllib.request.urlopen(f"{web}/api/link", timeout=5))["state"]
    except OSError:
        return None


def _tmp_dir():
    import tempfile

    return tempfile.mkdtemp(prefix="rovlink-mavproxy-")


def test_the_ground_station_sees_the_link_lost_and_restored():
    port = free_udp_port()
    gcs = _ground_station(port)
    with running_console() as live:
        gateway = GcsGateway([f"udpout:127.0.0.1:{port}"], live.operator,
                             DeskCommands(live.app.state.desk)).start()
        try:
            assert gcs.recv_match(type="ATTITUDE", blocking=True, timeout=15) is not None
            # A page holds control: the ground station is refused, with the reason.
            page = live.app.state.desk.connect("pilot's page")
            live.app.state.desk.take(page.id, "pilot")
            gcs.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert _ack(gcs, M.MAV_CMD_COMPONENT_ARM_DISARM)[0] == M.MAV_RESULT_DENIED
            live.app.state.desk.release(page.id)
            live.set_link_loss(1.0)
            lost = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=15,
                                  condition="'link to ROV lost' in STATUSTEXT.text")
            assert lost is not None and lost.severity == M.MAV_SEVERITY_CRITICAL
            assert _heartbeat(gcs, lambda hb: hb.system_status == M.MAV_STATE_CRITICAL, 5)
            # Stale data is not sent as current: no attitude while the link is lost.
            gcs.recv_match(type="ATTITUDE", blocking=False)
            assert gcs.recv_match(type="ATTITUDE", blocking=True, timeout=2) is None
            gcs.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert _ack(gcs, M.MAV_CMD_COMPONENT_ARM_DISARM)[0] == M.MAV_RESULT_TEMPORARILY_REJECTED
            live.set_link_loss(0.0)
            restored = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=20,
                                      condition="'restored' in STATUSTEXT.text")
            assert restored is not None
            assert gcs.recv_match(type="ATTITUDE", blocking=True, timeout=10) is not None
        finally:
            gateway.stop()
            gcs.close()


def test_bad_gcs_arguments_are_one_line_errors():
    for args, says in ((["--gcs", "carrier-pigeon:1"], "not a MAVLink URL"),
                       (["--gcs", "udpout:127.0.0.1:14550", "--gcs-home", "91,0"], "latitude")):
        out = subprocess.run([sys.executable, "-m", "rovlink", "demo", *args], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 2 and says in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
