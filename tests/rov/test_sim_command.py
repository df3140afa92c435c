"""`rovlink sim` as a real subprocess, reached with pymavlink over loopback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from pymavlink import mavutil

from .conftest import free_udp_port

ROOT = Path(__file__).resolve().parents[2]


def rovlink(*args: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen(
        [sys.executable, "-m", "rovlink", *args],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def test_sim_answers_a_pymavlink_heartbeat_and_stops_on_ctrl_c():
    port = free_udp_port()
    proc = rovlink("sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--status-every", "0.5")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, dialect="ardupilotmega")
    try:
        heartbeat = None
        deadline = time.monotonic() + 20
        while heartbeat is None and time.monotonic() < deadline and proc.poll() is None:
            gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
            heartbeat = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert heartbeat is not None, proc.stderr.read() if proc.poll() is not None else "no heartbeat"
        assert heartbeat.type == 12 and heartbeat.autopilot == 3  # submarine, ArduPilot
        assert heartbeat.base_mode & 1 and heartbeat.custom_mode == 19  # MANUAL
        assert heartbeat.get_srcSystem() == 1
        gcs.mav.command_long_send(1, 1, 511, 0, 32, 100000, 0, 0, 0, 0, 0)  # LOCAL_POSITION_NED at 10 Hz
        position = gcs.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=3)
        assert position is not None and abs(position.z - 6.0) < 0.5  # 2 m above the seabed
        time.sleep(0.7)
    finally:
        gcs.close()
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 130
    assert "Traceback" not in err
    assert "sim: disarmed MANUAL" in err


def test_sim_refuses_bad_arguments_with_one_line():
    for args in (["--mavlink", "bogus"], ["--depth", "50"], ["--system-id", "0"]):
        proc = rovlink("sim", *args)
        _, err = proc.communicate(timeout=20)
        assert proc.returncode == 1, err
        assert err.count("\n") == 1 and err.startswith("rovlink sim: error:"), err
