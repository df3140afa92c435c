"""The altitude above the seabed: the simulated vehicle's echosounder, and the bridge reading
ArduSub's RANGEFINDER / DISTANCE_SENSOR (an altitude unknown where no rangefinder reports)."""

from __future__ import annotations

import math
import time

from pymavlink import mavutil

from rovlink.rov.ardusub import mavlink
from rovlink.rov.autopilot import AutopilotBridge
from rovlink.rov.simulator import SimulatedVehicle
from rovlink.rov.telemetry import Telemetry
from rovlink.rov.vehicle import VehicleState

from .conftest import free_udp_port, wait_for


def test_the_bridge_reports_the_simulated_vehicles_altitude_above_its_seabed(sim, bridge):
    # The fixture's vehicle is 3 m deep over the 8 m seabed.
    assert wait_for(lambda: bridge.snapshot().altitude_m is not None, 5.0), "no rangefinder reading"
    assert math.isclose(bridge.snapshot().altitude_m, 5.0, abs_tol=0.05)
    sim.set_state(VehicleState(z_m=5.5))
    assert wait_for(lambda: abs((bridge.snapshot().altitude_m or 0) - 2.5) < 0.05, 3.0)


def test_without_a_rangefinder_the_altitude_is_unknown():
    with SimulatedVehicle("udpin:127.0.0.1:0", initial_state=VehicleState(z_m=3.0), has_rangefinder=False) as sim:
        with AutopilotBridge(sim.bridge_url) as bridge:
            assert wait_for(lambda: bridge.snapshot().attitude_valid, 5.0)
            assert not wait_for(lambda: bridge.snapshot().altitude_m is not None, 1.5)


def test_a_stale_or_out_of_bounds_range_is_no_altitude_and_tilt_is_compensated():
    t = Telemetry()
    t.on_heartbeat(1, False, 19, now=0.0)
    t.on_attitude(math.radians(20), 0.0, 0.0, 0.0, now=0.0)
    t.on_range(3.0, now=0.0)
    snap = t.snapshot(0.5, connected=True, failsafe=False)
    assert math.isclose(snap.altitude_m, 3.0 * math.cos(math.radians(20)))
    assert t.snapshot(1.2, connected=True, failsafe=False).altitude_m is None  # three 3 Hz readings missed
    t.on_range(math.nan, now=1.3)  # DISTANCE_SENSOR outside its own min..max
    assert t.snapshot(1.4, connected=True, failsafe=False).altitude_m is None


def test_only_a_downward_distance_sensor_is_an_altitude():
    """An autopilot of our own making (pymavlink, as ArduSub speaks): a forward sonar's
    DISTANCE_SENSOR is no altitude; a downward one is, in centimetres."""
    port = free_udp_port()
    vehicle = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1,
                                         dialect="ardupilotmega")
    with AutopilotBridge(f"udpout:127.0.0.1:{port}") as bridge:
        def say(orientation: int, cm: int) -> None:
            vehicle.mav.heartbeat_send(mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0x51, 19, 3)
            vehicle.mav.distance_sensor_send(0, 20, 5000, cm, 1, 0, orientation, 0)

        assert wait_for(lambda: vehicle.recv_match(blocking=False) is not None, 5.0)  # the bridge found: its address known
        for _ in range(10):
            say(mavlink.MAV_SENSOR_ROTATION_NONE, 77)
            time.sleep(0.05)
        assert bridge.snapshot().autopilot_alive and bridge.snapshot().altitude_m is None
        assert wait_for(lambda: (say(mavlink.MAV_SENSOR_ROTATION_PITCH_270, 312), bridge.snapshot().altitude_m)[1], 3.0)
        assert math.isclose(bridge.snapshot().altitude_m, 3.12)
    vehicle.close()
