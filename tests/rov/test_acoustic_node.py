"""The ROV program on the acoustic link (rov/acoustic.py) over the real bridge and a
simulated ArduSub: what each order's RESULT says is what the vehicle did (§9.4)."""

from __future__ import annotations

import time

import pytest

from rovlink.link import acoustic as ac
from rovlink.rov.acoustic import SURFACE_DONE_M, AcousticNode
from rovlink.rov.autopilot import AutopilotBridge
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import VehicleState

from .conftest import wait_for

K = bytes(range(32))
CHALLENGE, BOOT, NONCE = bytes.fromhex("01020304"), bytes.fromhex("12345678"), bytes.fromhex("9abcdef0")
S = CHALLENGE + BOOT + NONCE


@pytest.fixture
def node():
    vehicle = SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=1.5))
    vehicle.start()
    bridge = AutopilotBridge(vehicle.bridge_url)
    bridge.start()
    try:
        assert wait_for(lambda: bridge.snapshot().position_valid, 5.0), "bridge never saw a position"
        n = AcousticNode(endpoint=None, bridge=bridge, grab=None, key=K, encode=lambda *a, **k: b"")
        n.machine = ac.AcousticRov(K, boot=BOOT, random_bytes=lambda k: NONCE)
        n._refresh_status()
        n._on_events(n.machine.tick(time.monotonic()), time.monotonic())
        n.machine.receive(ac.seal_hello(K, CHALLENGE), time.monotonic())
        n.machine.next_packet(0.0), n.machine.next_packet(0.0)  # the SYNC
        yield n, vehicle
    finally:
        bridge.stop()
        vehicle.stop()


def _send(n: AcousticNode, ctr: int, kind: int, body: bytes) -> None:
    now = time.monotonic()
    n._refresh_status()
    for i in range(0, len(frame := b"".join(ac.seal_control(K, ac.LABEL_UP, S, ctr, kind, body))), 8):
        n._on_events(n.machine.receive(frame[i:i + 8], now), now)


def _result(n: AcousticNode) -> int:
    n._refresh_status()
    n._check_tickets()
    return n.machine.result


def test_surface_runs_while_the_vehicle_rises_so_a_stop_aborts_it_and_is_done_at_the_surface(node):
    n, vehicle = node
    _send(n, 0, ac.UP_ORDER, ac.OrderBody(1, ac.OP_ARM).encode())
    assert wait_for(lambda: _result(n) == ac.R_DONE, 5.0)  # an arm is done when the autopilot arms
    _send(n, 1, ac.UP_ORDER, ac.OrderBody(2, ac.OP_SURFACE).encode())
    assert wait_for(lambda: _result(n) == ac.R_TAKEN and n._surfacing == 2, 5.0)  # the autopilot took SURFACE ...
    assert _result(n) == ac.R_TAKEN and n.bridge.snapshot().z_m > SURFACE_DONE_M  # ... and it rises
    _send(n, 2, ac.UP_STOP, ac.StopBody(1, 2).encode())
    assert n.machine.result == ac.R_ABORTED  # stopped on the way: not done
    assert wait_for(lambda: _result(n) == ac.R_ABORTED and n._surfacing is None, 1.0)
    _send(n, 3, ac.UP_ORDER, ac.OrderBody(3, ac.OP_SURFACE).encode())
    assert wait_for(lambda: _result(n) == ac.R_DONE, 15.0)  # at the surface
    assert n.bridge.snapshot().z_m <= SURFACE_DONE_M
