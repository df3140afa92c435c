"""Fixtures for the ROV side: a simulated ArduSub on a free loopback UDP port and
the real bridge connected to it (pymavlink on both ends, never mocked)."""

from __future__ import annotations

import socket
import time

import pytest

from rovlink.rov.autopilot import AutopilotBridge
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import VehicleState


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_for(predicate, timeout_s: float, period_s: float = 0.02):
    """Poll until predicate() is truthy; return its last value."""
    deadline = time.monotonic() + timeout_s
    value = predicate()
    while not value and time.monotonic() < deadline:
        time.sleep(period_s)
        value = predicate()
    return value


@pytest.fixture
def sim():
    vehicle = SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=3.0))
    vehicle.start()
    yield vehicle
    vehicle.stop()


@pytest.fixture
def bridge(sim):
    b = AutopilotBridge(sim.bridge_url)
    b.start()
    assert wait_for(lambda: b.snapshot().position_valid, 5.0), "bridge never saw a position"
    yield b
    b.stop()
