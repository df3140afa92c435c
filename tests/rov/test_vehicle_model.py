"""The pure vehicle model in simulated time: the ArduSub SITL facts, and the
behaviours the simulator and the console's prediction rely on."""

from __future__ import annotations

import math

import pytest

from rovlink.rov.vehicle import Controls, PilotInput, PositionTarget, SubMode, VehicleModel, VehicleState


def fly(model: VehicleModel, seconds: float, controls: Controls, dt_s: float = 0.05) -> VehicleState:
    for _ in range(round(seconds / dt_s)):
        model.step(dt_s, controls)
    return model.state


def armed(mode: SubMode, **pilot) -> Controls:
    return Controls(PilotInput(**pilot), mode, True)


def test_sitl_fact_5_5_m_forward_in_8_s_at_x_700_manual():
    model = VehicleModel(VehicleState(z_m=3.0))
    state = fly(model, 8.0, armed(SubMode.MANUAL, x=700))
    assert state.x_m == pytest.approx(5.5, abs=0.4)
    assert abs(state.y_m) < 1e-9


def test_sitl_fact_4_7_m_deeper_in_8_s_at_z_150_alt_hold_then_held():
    model = VehicleModel(VehicleState(z_m=2.0))
    state = fly(model, 8.0, armed(SubMode.ALT_HOLD, z=150))
    assert state.z_m - 2.0 == pytest.approx(4.7, abs=0.4)
    stopped = fly(model, 2.0, armed(SubMode.ALT_HOLD, z=500)).z_m
    later = fly(model, 20.0, armed(SubMode.ALT_HOLD, z=500)).z_m
    assert later == pytest.approx(stopped, abs=0.05)


@pytest.mark.parametrize("mode", [SubMode.MANUAL, SubMode.STABILIZE])
def test_sitl_fact_144_degrees_of_yaw_in_4_s_at_r_600(mode):
    model = VehicleModel(VehicleState(z_m=3.0))
    state = fly(model, 4.0, armed(mode, r=600))
    assert math.degrees(state.yaw_rad) % 360 == pytest.approx(144, abs=15)


def test_sitl_fact_guided_target_7_3_m_away_reached_within_0_14_m_in_15_s():
    model = VehicleModel(VehicleState(x_m=1.0, y_m=-2.0, z_m=3.0))
    target = PositionTarget(1.0 + 7.0, -2.0 + 2.0, 3.5, math.radians(45))
    assert math.dist((1, -2, 3), (target.x_m, target.y_m, target.z_m)) == pytest.approx(7.3, abs=0.03)
    state = fly(model, 15.0, Controls(PilotInput(), SubMode.GUIDED, True, target))
    assert math.dist((state.x_m, state.y_m, state.z_m), (target.x_m, target.y_m, target.z_m)) < 0.14
    assert state.yaw_rad == pytest.approx(math.radians(45), abs=math.radians(3))
    # and not there already halfway: the speed is limited like ArduSub's
    halfway = VehicleModel(VehicleState(x_m=1.0, y_m=-2.0, z_m=3.0))
    mid = fly(halfway, 7.5, Controls(PilotInput(), SubMode.GUIDED, True, target))
    assert math.dist((mid.x_m, mid.y_m, mid.z_m), (target.x_m, target.y_m, target.z_m)) > 2.0


def test_disarmed_vehicle_has_no_thrust_and_floats_up():
    model = VehicleModel(VehicleState(z_m=3.0))
    state = fly(model, 10.0, Controls(PilotInput(x=1000, z=0), SubMode.MANUAL, False))
    assert abs(state.x_m) < 1e-9
    assert state.z_m < 3.0


def test_surface_and_seabed_bound_the_depth():
    model = VehicleModel(VehicleState(z_m=0.5), floor_depth_m=4.0)
    assert fly(model, 5.0, armed(SubMode.MANUAL, z=1000)).z_m == 0.0
    bottom = fly(model, 15.0, armed(SubMode.MANUAL, z=0)).z_m
    assert bottom == pytest.approx(4.0 - model.floor_clearance_m)


def test_stabilize_holds_heading_after_a_turn():
    model = VehicleModel(VehicleState(z_m=3.0))
    fly(model, 1.0, armed(SubMode.STABILIZE, r=500))
    settled = fly(model, 2.0, armed(SubMode.STABILIZE)).yaw_rad
    later = fly(model, 5.0, armed(SubMode.STABILIZE, x=500)).yaw_rad
    assert later == pytest.approx(settled, abs=0.02)


def test_poshold_holds_position_when_sticks_are_neutral():
    model = VehicleModel(VehicleState(z_m=3.0))
    fly(model, 2.0, armed(SubMode.POSHOLD, x=600))
    fly(model, 3.0, armed(SubMode.POSHOLD))
    held = model.state
    later = fly(model, 10.0, armed(SubMode.POSHOLD))
    assert math.dist((later.x_m, later.y_m, later.z_m), (held.x_m, held.y_m, held.z_m)) < 0.1


def test_surface_mode_climbs_to_the_surface():
    model = VehicleModel(VehicleState(z_m=3.0))
    assert fly(model, 12.0, armed(SubMode.SURFACE)).z_m < 0.1


def test_sideways_and_turning_motion_is_in_the_body_frame():
    model = VehicleModel(VehicleState(z_m=3.0, yaw_rad=math.pi / 2))  # facing east
    state = fly(model, 3.0, armed(SubMode.STABILIZE, x=500))
    assert state.y_m > 0.5 and abs(state.x_m) < 0.05
    model = VehicleModel(VehicleState(z_m=3.0))  # facing north, sway right = east
    state = fly(model, 3.0, armed(SubMode.STABILIZE, y=500))
    assert state.y_m > 0.5 and abs(state.x_m) < 0.05


def test_step_size_does_not_change_the_outcome_much():
    fine = fly(VehicleModel(VehicleState(z_m=3.0)), 6.0, armed(SubMode.STABILIZE, x=600, r=300), dt_s=0.01)
    coarse = fly(VehicleModel(VehicleState(z_m=3.0)), 6.0, armed(SubMode.STABILIZE, x=600, r=300), dt_s=0.5)
    assert math.dist((fine.x_m, fine.y_m), (coarse.x_m, coarse.y_m)) < 0.1


def test_bad_steps_and_inputs_do_not_break_the_model():
    model = VehicleModel(VehicleState(z_m=3.0))
    for dt in (0.0, -1.0, float("nan"), float("inf")):
        assert model.step(dt, armed(SubMode.MANUAL, x=1000)) == VehicleState(z_m=3.0)
    state = fly(model, 1.0, Controls(PilotInput(x=99999, y=-99999, z=-5, r=4000), SubMode.MANUAL, True))
    assert all(math.isfinite(v) for v in (state.x_m, state.y_m, state.z_m, state.yaw_rad))


def test_velocity_wish_maps_onto_ardusub_ranges():
    assert PilotInput.from_velocity(0, 0, 0, 0) == PilotInput(0, 0, 500, 0)
    assert PilotInput.from_velocity(1, -1, 1, -1) == PilotInput(1000, -1000, 0, -1000)
    assert PilotInput.from_velocity(0.7, 0, -1, 0.6) == PilotInput(700, 0, 1000, 600)
    assert PilotInput.from_velocity(5, float("nan"), -7, 0) == PilotInput(1000, 0, 1000, 0)
