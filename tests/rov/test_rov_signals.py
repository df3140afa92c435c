"""`rovlink rov` as a real process, stopped the way services are stopped."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from rovlink.link.radio.frame import encode_frame
from rovlink.link.radio.messages import Poll, Velocity
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import PilotInput, VehicleState

from .conftest import free_udp_port, wait_for

ROOT = Path(__file__).resolve().parents[2]


class Pilot:
    """An operator reduced to its poll stream: VELOCITY polls at 10 Hz over UDP,
    neutral first (the ROV holds until the sticks are centred), then `vx`."""

    def __init__(self, rov_port: int, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.rov = ("127.0.0.1", rov_port)
        self.vx = 0
        self.replies = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            poll = Poll(order=Velocity(vx=self.vx))
            try:
                self.sock.sendto(encode_frame(poll.encode()), self.rov)
                self.sock.recvfrom(512)
                self.replies += 1
            except OSError:  # no reply yet (timeout), or the ROV's port is closed
                pass
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def steer_forward(pilot: Pilot, sim, proc, timeout_s: float = 40.0) -> bool:
    """Forward input reaches the vehicle.  A ROV process starved on a busy machine may
    fall into its failsafe, after which it waits for centred sticks: centre, try again."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        pilot.vx = 0
        time.sleep(0.5)
        pilot.vx = 100
        if wait_for(lambda: sim.truth().pilot.x > 500, 4.0):
            return True
    return False


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_leaves_the_vehicle_with_neutral_sticks_and_exits_0(signum):
    rov_port, pilot_port = free_udp_port(), free_udp_port()
    with SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=3.0)) as sim:
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        proc = subprocess.Popen(
            [sys.executable, "-m", "rovlink", "rov", "--link", f"udp://127.0.0.1:{rov_port}?peer=127.0.0.1:{pilot_port}",
             "--mavlink", sim.bridge_url, "--budget", "0", "--insecure"],
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        pilot = Pilot(rov_port, pilot_port)
        try:
            assert wait_for(lambda: pilot.replies >= 5 or proc.poll() is not None, 60.0, 0.1)
            assert proc.poll() is None, proc.communicate()[1]
            assert steer_forward(pilot, sim, proc), sim.truth().pilot
            proc.send_signal(signum)  # the pilot keeps polling: no failsafe, no lapse
            assert wait_for(lambda: sim.truth().pilot == PilotInput(), 10.0), sim.truth().pilot
            # The DEBT warm-up runs in a daemon thread: the exit never waits for the compiler.
            _, err = proc.communicate(timeout=30)
        finally:
            pilot.close()
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == 0, err
        assert "Traceback" not in err
        assert sim.truth().pilot == PilotInput()  # neutral: not the last forward input
