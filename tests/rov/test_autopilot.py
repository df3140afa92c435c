"""The autopilot bridge against the simulated ArduSub over real UDP sockets."""

from __future__ import annotations

import math
import socket
import time

import pytest
from pymavlink import mavutil

from rovlink.rov.ardusub import protocol_mode, sub_mode
from rovlink.rov.autopilot import AutopilotBridge, Ticket
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.vehicle import PilotInput, SubMode, VehicleState

from .conftest import free_udp_port, wait_for


def arm_in(bridge: AutopilotBridge, mode: str) -> None:
    assert bridge.request_mode(mode).wait(3) == Ticket.ACCEPTED
    assert bridge.request_arm(True).wait(3) == Ticket.ACCEPTED


def test_snapshot_reports_heartbeat_state_and_odometry(sim, bridge):
    # The battery comes in SYS_STATUS, on its own schedule: on a loaded machine after the
    # position the fixture waited for.
    assert wait_for(lambda: bridge.snapshot().battery_v is not None, 5.0), "no SYS_STATUS"
    snap = bridge.snapshot()
    assert snap.autopilot_alive and snap.connected
    assert snap.custom_mode == SubMode.MANUAL and snap.mode == 1
    assert not snap.armed
    assert snap.z_m == pytest.approx(3.0, abs=0.3)
    assert snap.battery_v == pytest.approx(16.0)


def test_arming_is_reported_from_the_heartbeat(sim, bridge):
    ticket = bridge.request_arm(True)
    assert ticket.wait(3) == Ticket.ACCEPTED
    assert sim.truth().armed
    assert wait_for(lambda: bridge.snapshot().armed, 2.5)
    assert bridge.request_arm(False).wait(3) == Ticket.ACCEPTED
    assert wait_for(lambda: not bridge.snapshot().armed, 2.5)


def test_manual_forward_moves_the_vehicle_forward(sim, bridge):
    arm_in(bridge, "MANUAL")
    start = bridge.snapshot()
    bridge.set_velocity(0.7, 0.0, 0.0, 0.0)
    time.sleep(2.0)
    bridge.set_velocity(0.0, 0.0, 0.0, 0.0)
    moved = bridge.snapshot()
    assert moved.x_m - start.x_m > 0.8
    assert abs(moved.y_m - start.y_m) < 0.1
    assert wait_for(lambda: sim.truth().pilot.x == 0, 1.0)


def test_alt_hold_goes_down_on_the_stick_then_holds_depth(sim, bridge):
    arm_in(bridge, "DEPTH_HOLD")
    assert wait_for(lambda: bridge.snapshot().mode == 3, 2.5)
    start_z = bridge.snapshot().z_m
    bridge.set_velocity(0.0, 0.0, 0.7, 0.0)  # z down
    time.sleep(2.0)
    bridge.set_velocity(0.0, 0.0, 0.0, 0.0)
    time.sleep(1.0)  # brake and latch
    held_z = bridge.snapshot().z_m
    assert held_z - start_z > 0.8
    time.sleep(2.0)
    # The vehicle is buoyant: without the hold it would have risen.
    assert bridge.snapshot().z_m == pytest.approx(held_z, abs=0.1)


def test_guided_reaches_a_position_within_0_3_m(sim, bridge):
    bridge.request_arm(True).wait(3)
    ticket = bridge.goto(2.0, 1.0, 3.5, math.radians(30))
    assert ticket.wait(4) == Ticket.ACCEPTED
    assert wait_for(lambda: ticket.reached, 12.0, 0.1)
    snap = bridge.snapshot()
    assert math.dist((snap.x_m, snap.y_m, snap.z_m), (2.0, 1.0, 3.5)) < 0.3
    assert snap.mode == 5  # GUIDED
    assert snap.yaw_rad == pytest.approx(math.radians(30), abs=0.1)


def test_relative_body_goto_is_resolved_against_the_pose(sim, bridge):
    assert bridge.request_arm(True).wait(3) == Ticket.ACCEPTED
    sim.set_state(VehicleState(x_m=1.0, y_m=2.0, z_m=3.0, yaw_rad=math.pi / 2))
    time.sleep(0.3)
    ticket = bridge.goto(1.0, 0.0, 0.5, 0.0, relative=True, body=True)
    assert ticket.wait(4) == Ticket.ACCEPTED
    x, y, z, yaw = ticket.target
    # Facing east, one metre forward is one metre east.
    assert (x, y, z) == pytest.approx((1.0, 3.0, 3.5), abs=0.1)
    assert yaw == pytest.approx(math.pi / 2, abs=0.05)


def test_stop_cancels_the_goto_and_holds_position(sim, bridge):
    bridge.request_arm(True).wait(3)
    ticket = bridge.goto(5.0, 0.0, 3.0, None)
    assert ticket.wait(4) == Ticket.ACCEPTED
    bridge.set_velocity(0.5, 0, 0, 0)
    assert bridge.brake().wait(3) == Ticket.ACCEPTED
    assert sim.truth().mode == SubMode.POSHOLD and sim.truth().target is None
    assert wait_for(lambda: sim.truth().pilot.x == 0, 1.0)
    assert ticket.status == Ticket.ACCEPTED  # it had been accepted; it no longer drives


def test_failsafe_holds_neutral_until_cleared(sim, bridge):
    bridge.set_velocity(1.0, 0, 0, 0)
    bridge.failsafe(True)
    assert bridge.snapshot().failsafe
    bridge.set_velocity(1.0, 0, 0, 0)
    assert wait_for(lambda: sim.truth().mode == SubMode.POSHOLD, 3.0)
    time.sleep(0.3)
    assert sim.truth().pilot.x == 0
    bridge.failsafe(False)
    bridge.set_velocity(1.0, 0, 0, 0)
    assert wait_for(lambda: sim.truth().pilot.x == 1000, 1.0)


def test_simulator_disarms_3_s_after_pilot_input_stops():
    with SimulatedVehicle() as sim:
        gcs = mavutil.mavlink_connection(sim.bridge_url, source_system=255, dialect="ardupilotmega")
        try:
            gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
            assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=3) is not None
            gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=3)
            assert ack.command == 400 and ack.result == 0
            for _ in range(10):  # one second of pilot input, then silence
                gcs.mav.manual_control_send(1, 0, 0, 500, 0, 0)
                # The last input sent: the simulator took it no earlier.  (Read after the
                # sleep, as it was, a loaded machine's oversleep of 0.14 s or more made a
                # disarm on time read as early: 2.86 s.)
                stopped = time.monotonic()
                time.sleep(0.1)
            assert sim.truth().armed
            # Armed until 3 s after the last input, every look of `wait_for` (50 ms apart) says
            # so; then disarmed.
            assert wait_for(lambda: not sim.truth().armed, 4.5)
            assert time.monotonic() - stopped >= 2.9
            text = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=2)
            assert text is not None and "manual control" in text.text
        finally:
            gcs.close()


def test_the_bridge_keeps_the_vehicle_fed(sim, bridge):
    assert bridge.request_arm(True).wait(3) == Ticket.ACCEPTED
    sent = bridge.manual_controls_sent
    time.sleep(4.5)  # longer than ArduSub's 3 s pilot-input failsafe
    assert sim.truth().armed and bridge.snapshot().armed
    assert bridge.manual_controls_sent - sent >= 5 * 4  # at least 5 Hz


def test_lost_heartbeat_clears_autopilot_and_the_bridge_reconnects():
    port = free_udp_port()
    sim = SimulatedVehicle(f"udpout:127.0.0.1:{port}").start()
    bridge = AutopilotBridge(f"udpin:127.0.0.1:{port}").start()
    try:
        assert wait_for(lambda: bridge.snapshot().autopilot_alive, 5.0)
        sim.stop()
        assert wait_for(lambda: not bridge.snapshot().autopilot_alive, 4.5)
        snap = bridge.snapshot()
        assert snap.mode == 0 and not snap.armed and not snap.position_valid
        assert wait_for(lambda: bridge.reconnects >= 1, 1.0)  # the connection is closed, to be reopened
        sim = SimulatedVehicle(f"udpout:127.0.0.1:{port}").start()
        assert wait_for(lambda: bridge.snapshot().position_valid, 8.0)
    finally:
        bridge.stop()
        sim.stop()


def test_bridge_survives_garbage_and_unreachable_endpoints(sim, bridge):
    # Garbage datagrams straight at the bridge's socket: bytes that are not MAVLink.
    port = bridge._conn.port.getsockname()[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for blob in (b"\xfe\xff" + bytes(300), b"\x55" * 40, bytes(range(256))):
            sock.sendto(blob, ("127.0.0.1", port))
    time.sleep(0.3)
    assert bridge.snapshot().autopilot_alive
    # Nothing listens on this TCP port: the bridge keeps retrying quietly.
    with AutopilotBridge(f"tcp:127.0.0.1:{free_udp_port()}") as lonely:
        time.sleep(0.5)
        snap = lonely.snapshot()
        assert not snap.autopilot_alive and not snap.connected
        assert lonely.request_arm(True).status == Ticket.PENDING
    # A serial device that is not there: same story.
    with AutopilotBridge("/dev/rovlink-no-such-device,57600") as unplugged:
        time.sleep(0.3)
        assert not unplugged.snapshot().connected
        refused = unplugged.goto(1, 2, 3, None)
        assert refused.status == Ticket.FAILED and refused.reject_reason == 1 and "autopilot" in refused.reason


def test_bad_inputs_are_refused_cleanly(sim, bridge):
    for url in ("", "bogus", "/usr/bin/python3", "udpin:127.0.0.1", "tcp:127.0.0.1:0", "udpout:host:99999"):
        with pytest.raises(ValueError):
            AutopilotBridge(url)
    with pytest.raises(ValueError):
        bridge.request_mode("WARP")
    with pytest.raises(ValueError):
        bridge.request_mode(7)
    bridge.set_velocity(float("nan"), 5.0, -9.0, "x")  # ignored, not a crash
    bridge.set_velocity(float("nan"), 5.0, -9.0, 0.0)  # NaN -> 0, clamped
    assert wait_for(lambda: sim.truth().pilot.y == 1000, 1.0)
    assert sim.truth().pilot.x == 0 and sim.truth().pilot.z == 1000
    assert bridge.goto(float("inf"), 0, 0, 0).status == Ticket.FAILED
    assert bridge.goto("x", 0, 0, 0).status == Ticket.FAILED
    assert bridge.snapshot().autopilot_alive


def test_mode_numbers_follow_the_protocol():
    assert [sub_mode(n) for n in range(1, 7)] == [
        SubMode.MANUAL, SubMode.STABILIZE, SubMode.ALT_HOLD, SubMode.POSHOLD, SubMode.GUIDED, SubMode.SURFACE,
    ]
    assert sub_mode("depth_hold") == SubMode.ALT_HOLD == 2
    assert protocol_mode(None) == 0 and protocol_mode(19) == 1 and protocol_mode(2) == 3
    assert protocol_mode(16) == 4 and protocol_mode(4) == 5 and protocol_mode(9) == 6 and protocol_mode(1) == 7


def test_bridge_over_tcp_like_ardusub_sitl():
    port = free_udp_port()  # the same number is very likely free for TCP too
    with SimulatedVehicle(f"tcpin:127.0.0.1:{port}") as sim:
        with AutopilotBridge(f"tcp:127.0.0.1:{port}") as bridge:
            assert wait_for(lambda: bridge.snapshot().position_valid, 6.0)
            assert bridge.request_arm(True).wait(3) == Ticket.ACCEPTED
            assert sim.truth().armed


def test_simulator_shrugs_off_bad_requests():
    with SimulatedVehicle(initial_state=VehicleState(z_m=3.0)) as sim:
        gcs = mavutil.mavlink_connection(sim.bridge_url, source_system=255, dialect="ardupilotmega")
        try:
            gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
            assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=3) is not None
            nan = float("nan")

            def ack_for(command: int, *params: float) -> int:
                gcs.mav.command_long_send(1, 1, command, 0, *(list(params) + [0.0] * (7 - len(params))))
                ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=3)
                assert ack is not None and ack.command == command
                return ack.result

            assert ack_for(400, nan) == 3  # arm with NaN: refused, not "disarm"
            assert ack_for(400, 0.5) == 3
            assert ack_for(176, 1, nan) == 4  # DO_SET_MODE with NaN mode
            assert ack_for(176, 1, 3) == 4  # AUTO: not simulated
            assert ack_for(176, 1, 12345) == 4
            assert ack_for(176, 0, 2) == 4  # without CUSTOM_MODE_ENABLED
            assert ack_for(511, 999, 1000) == 4  # a stream we do not offer
            assert ack_for(31000) == 3  # unknown command
            gcs.mav.set_mode_send(1, 1, 4)  # SET_MODE message: GUIDED
            ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=3)
            assert ack.command == 11 and ack.result == 0
            # Targets with NaN, in an unknown frame, or for another system are ignored.
            gcs.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0b100111111000, nan, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0)
            gcs.mav.set_position_target_local_ned_send(0, 1, 1, 42, 0b100111111000, 1, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0)
            gcs.mav.set_position_target_local_ned_send(0, 7, 1, 1, 0b100111111000, 1, 0, 3, 0, 0, 0, 0, 0, 0, 0, 0)
            gcs.mav.manual_control_send(9, 1000, 0, 500, 0, 0)  # for another vehicle
            gcs.mav.manual_control_send(1, 32767, -32768, 32767, 0, 0)  # far out of range: clamped
            time.sleep(0.3)
            truth = sim.truth()
            assert truth.target is None and truth.mode == SubMode.GUIDED and not truth.armed
            assert truth.pilot.x == 1000 and truth.pilot.y == -1000 and truth.pilot.z == 1000
            assert all(math.isfinite(v) for v in (truth.state.x_m, truth.state.z_m))
        finally:
            gcs.close()


def test_a_position_order_ends_when_the_autopilot_leaves_guided(sim, bridge):
    assert bridge.request_arm(True).wait(3) == Ticket.ACCEPTED
    ticket = bridge.goto(1.0, 0.0, 3.0, None)
    assert ticket.wait(4) == Ticket.ACCEPTED
    assert wait_for(lambda: bridge.snapshot().mode == 5, 2.5)
    # Another ground station switches the vehicle to MANUAL behind the bridge's back.
    gcs = mavutil.mavlink_connection(sim.bridge_url, source_system=254, dialect="ardupilotmega")
    try:
        gcs.mav.set_mode_send(1, 1, int(SubMode.MANUAL))
        assert wait_for(lambda: bridge.snapshot().mode == 1, 2.5)
        assert wait_for(lambda: bridge._goto.active is None, 1.0)
    finally:
        gcs.close()


def test_stopping_the_bridge_leaves_the_sticks_neutral(sim):
    bridge = AutopilotBridge(sim.bridge_url).start()
    try:
        assert wait_for(lambda: bridge.snapshot().autopilot_alive, 5.0)
        bridge.set_velocity(0.8, 0.0, 0.0, 0.3)
        assert wait_for(lambda: sim.truth().pilot.x == 800, 1.0)
    finally:
        bridge.stop()
    assert wait_for(lambda: sim.truth().pilot == PilotInput(), 1.0)
