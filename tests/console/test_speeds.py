"""Speeds measured from the received poses are right at any reply rate (issue 32):
on a fast link (udp:// with no channel emulator, a reply every ~20 ms) the page's
turn rate read 0.0 deg/s while the received yaw turned 51 deg/s, because the
speeds were differenced only between two fixes more than 50 ms apart.

First the odometry alone on reports made at 50 Hz, 10 Hz and 1 Hz; then
`rovlink rov` and `rovlink console` as real processes over loopback UDP, the
vehicle turned by a script through the REST API, and the turn rate the API
serves set against the rate the received yaw itself turns at."""

from __future__ import annotations

import json
import math
import time
import urllib.request

import pytest

from rovlink.console.session.odometry import Odometry
from rovlink.link.report import VehicleReport

from ..helpers import get_json, wait_until_up
from .test_restarts import Processes


def report(t: float, x: float, yaw: float, valid: bool = True) -> VehicleReport:
    # Quantised as the wire carries them: centimetres and centidegrees.
    yaw = (yaw + 180.0) % 360.0 - 180.0
    return VehicleReport(round(x * 100) / 100, 0.0, 2.0, 0.0, 0.0, round(yaw * 100) / 100, armed=True, mode=2,
                         failsafe=False, hold=False, autopilot=True, position_valid=valid, attitude_valid=True,
                         sampled_at=t - 0.1, arrived_at=t)


@pytest.mark.parametrize("period_s", [0.02, 0.1, 1.0])
def test_speeds_are_the_vehicles_at_any_reply_rate(period_s):
    odo = Odometry()
    forward_mps, turn_dps = 0.4, 51.0
    t = 10.0
    for _ in range(int(4.0 / period_s) + 2):
        odo.take(report(t, forward_mps * t, turn_dps * t), round_trip_s=period_s)
        t += period_s
    v = odo.fix.velocity
    assert v[3] == pytest.approx(turn_dps, rel=0.05), v
    assert v[0] == pytest.approx(forward_mps, rel=0.1), v


def test_a_report_without_a_position_keeps_the_turn_rate_its_attitude_gives():
    """A vehicle side starved for a moment reports its position as a second old (not
    valid) while its attitude is: the turn rate stands, the position's speeds restart
    (a loaded run of the suite showed a steady 25 deg/s turn as 0 for a second)."""
    odo = Odometry()
    t = 10.0
    for _ in range(60):
        odo.take(report(t, 0.4 * t, 25.0 * t), round_trip_s=0.05)
        t += 0.05
    odo.take(report(t, 0.4 * t, 25.0 * t, valid=False), round_trip_s=0.05)
    v = odo.fix.velocity
    assert v[3] == pytest.approx(25.0, rel=0.05) and v[:3] == (0.0, 0.0, 0.0), v
    for _ in range(5):  # back: the turn goes on being fitted, the position's window refills
        t += 0.05
        odo.take(report(t, 0.4 * t, 25.0 * t), round_trip_s=0.05)
    assert odo.fix.velocity[3] == pytest.approx(25.0, rel=0.05), odo.fix.velocity


def test_a_report_without_a_position_is_no_speed():
    odo = Odometry()
    odo.take(report(1.0, 0.0, 0.0, valid=False), None)
    # The first measured pose, far from the 0,0,0 of the unmeasured one: no speed.
    for i in range(5):
        odo.take(report(1.1 + 0.1 * i, 50.0, 10.0), None)
    assert odo.fix.velocity == (0.0, 0.0, 0.0, 0.0)


def _post(url: str, body: dict, client: str | None = None) -> dict:
    headers = {"Content-Type": "application/json", **({"X-Rovlink-Client": client} if client else {})}
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST", headers=headers)
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read() or b"{}")


@pytest.mark.slow
@pytest.mark.processes
def test_on_a_fast_link_the_turn_rate_shown_agrees_with_the_received_yaw(tmp_path):
    procs = Processes(tmp_path)  # rov and console over loopback UDP, no emulator between them
    try:
        base = procs.base
        assert wait_until_up(lambda: procs.pose()["received"], 120, 0.2), procs.logs_text()
        client = _post(base + "/api/control/take", {"name": "speed test"})["client_id"]
        _post(base + "/api/orders/arm", {"armed": True}, client)
        assert wait_until_up(lambda: procs.pose().get("armed"), 20, 0.2), procs.logs_text()
        _post(base + "/api/orders/velocity", {"vx": 0.0, "vy": 0.0, "vz": 0.0, "vyaw": 0.4}, client)
        # Replies come every few tens of milliseconds: check it is the fast link the issue saw.
        link0 = get_json(base + "/api/link")
        time.sleep(3.0)  # the turn settles to its steady rate
        link1 = get_json(base + "/api/link")
        assert link1["reports"] - link0["reports"] > 3.0 / 0.06, (link0, link1)
        samples = []  # (this test's clock, received yaw, shown yaw rate)
        for _ in range(30):
            p = procs.pose()
            samples.append((time.monotonic(), p["received"]["yaw_deg"], p["velocity"]["yaw_dps"]))
            time.sleep(0.1)
        _post(base + "/api/orders/stop", {}, client)
        turned = sum((b[1] - a[1] + 180.0) % 360.0 - 180.0 for a, b in zip(samples, samples[1:]))
        received_dps = turned / (samples[-1][0] - samples[0][0])
        shown_dps = sum(s[2] for s in samples) / len(samples)
        assert abs(received_dps) > 5.0, samples  # it does turn
        assert math.isclose(shown_dps, received_dps, rel_tol=0.2), (shown_dps, received_dps, samples[:5])
    finally:
        procs.close()
