"""What the pilot holds and sees (`rovlink bench console`, the prediction rows).

A pilot session in simulated time with the real machines: the operator
(version 2 master), the ROV's slave, the emulated 1.9 kbit/s channel (85 ms,
BER 7e-6) and, as the truth, the vehicle model (rov/vehicle.py, a BlueROV2
under ArduSub in ALT_HOLD) driven by what the slave applies.  The pilot holds
control and steers in spells of 1-4 s with pauses of 2-8 s between them.

Every 0.1 s of simulated time it compares with the truth at that instant
- the received pose (the last odometry, of some age), and
- the predicted pose (the ghost: the model run from that odometry under the
  wishes as they were sent),
by the pose's age; and it measures the pose's age while not steering, and how
long the first wish after a pause takes to be applied on the ROV.
"""

from __future__ import annotations

import math
import random

ROW_AGES = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 3.0), (3.0, math.inf))


def _percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    v = sorted(values)
    return v[min(len(v) - 1, max(0, math.ceil(q / 100 * len(v)) - 1))]


def measure_prediction(duration_s: float = 600.0, seed: int = 0, ber: float = 7e-6) -> dict:
    from rovlink.console.session.radio import Operator
    from rovlink.link.emulators.channel import Channel, LinkParams
    from rovlink.link.radio.messages import VELOCITY_FULL, Mode
    from rovlink.link.radio.secure import SecureSlave
    from rovlink.link.radio.sim import SimLink
    from rovlink.link.radio.slave import BrakeRequested, Slave, VelocityCommanded, status_from_pose
    from rovlink.rov.vehicle import Controls, PilotInput, SubMode, VehicleModel, VehicleState

    rng = random.Random(seed)
    key = bytes(rng.randrange(256) for _ in range(32))
    sim: SimLink | None = None

    def now() -> float:
        return sim.now if sim is not None else 0.0

    operator = Operator(None, clock=now)
    operator.authenticate(key)
    master = operator.master

    def source(img, settings):  # the link carries bytes: what they show does not matter here
        r = random.Random(img * 7919 + settings.budget_bytes)
        return bytes(r.randrange(256) for _ in range(settings.budget_bytes))

    slave = Slave(image_source=source)
    truth = VehicleModel(state=VehicleState(z_m=3.0), floor_depth_m=None)
    applied = {"pilot": PilotInput()}
    first_wish: list[float] = []
    pending_move: list[tuple[float, tuple]] = []  # (when the pilot moved after a pause, the wish)

    def on_slave(event, t):
        if isinstance(event, VelocityCommanded):
            v = event.velocity
            applied["pilot"] = PilotInput.from_velocity(*(axis / VELOCITY_FULL for axis in (v.vx, v.vy, v.vz, v.vyaw)))
            if pending_move and not v.is_neutral:
                moved_at, _ = pending_move.pop()
                first_wish.append(t - moved_at)
        elif isinstance(event, BrakeRequested):
            applied["pilot"] = PilotInput()

    def on_master(event, t):
        operator.handle_events([event], t)

    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, ber=ber), seed=seed)
    sim = SimLink(master, SecureSlave(slave, key), channel, on_master_event=on_master, on_slave_event=on_slave)

    def step_truth(t):
        s = truth.step(0.02, Controls(pilot=applied["pilot"], mode=SubMode.ALT_HOLD, armed=True))
        slave.update_status(status_from_pose(
            x_m=s.x_m, y_m=s.y_m, z_m=s.z_m, roll_deg=math.degrees(s.roll_rad), pitch_deg=math.degrees(s.pitch_rad),
            yaw_deg=math.degrees(s.yaw_rad), armed=True, mode=Mode.DEPTH_HOLD, autopilot=True,
            position_valid=True, attitude_valid=True))
        sim.at(t + 0.02, step_truth)

    # The pilot: holds control (as the console's desk says when a page takes it), centred.
    operator.set_attended(True)
    operator.set_pilot_in_force(True)
    operator.recentred()

    def steer(t):
        wish = tuple(round(rng.uniform(-1, 1), 2) if rng.random() < 0.5 else 0.0 for _ in range(4))
        if not any(wish):
            wish = (0.7, 0.0, 0.0, 0.0)
        operator.set_velocity(*wish)
        pending_move[:] = [(t, wish)]
        sim.at(t + rng.uniform(1.0, 4.0), pause)

    def pause(t):
        operator.set_velocity(0.0, 0.0, 0.0, 0.0)
        operator.recentred()
        pending_move.clear()
        sim.at(t + rng.uniform(2.0, 8.0), steer)

    samples = []  # (age, steering, received pos err, predicted pos err, received yaw err, predicted yaw err)

    def sample(t):
        reply = operator.vehicle()
        age = operator.odometry_age_s()
        if reply is not None and age is not None:
            s = truth.state
            predicted = operator.predicted_pose(t)
            rx, ry, ryaw = reply.x_m, reply.y_m, reply.yaw_deg
            truth_yaw = math.degrees(s.yaw_rad)

            def yaw_err(a):
                return abs((a - truth_yaw + 180.0) % 360.0 - 180.0)

            samples.append((age, master.master.steering(t),
                            math.hypot(rx - s.x_m, ry - s.y_m), math.hypot(predicted.x_m - s.x_m, predicted.y_m - s.y_m),
                            yaw_err(ryaw), yaw_err(predicted.yaw_deg)))
        sim.at(t + 0.1, sample)

    sim.at(0.0, step_truth)
    sim.at(5.0, steer)
    sim.at(6.0, sample)
    sim.run_until(duration_s)
    operator.close()

    rows = []
    for lo, hi in ROW_AGES:
        group = [x for x in samples if lo <= x[0] < hi]
        rows.append({
            "age_s": [lo, None if math.isinf(hi) else hi], "n": len(group),
            "received_pos_m": [_percentile([x[2] for x in group], 50), _percentile([x[2] for x in group], 95)],
            "predicted_pos_m": [_percentile([x[3] for x in group], 50), _percentile([x[3] for x in group], 95)],
            "received_yaw_deg": [_percentile([x[4] for x in group], 50), _percentile([x[4] for x in group], 95)],
            "predicted_yaw_deg": [_percentile([x[5] for x in group], 50), _percentile([x[5] for x in group], 95)],
        })
    idle_ages = [x[0] for x in samples if not x[1]]
    steer_ages = [x[0] for x in samples if x[1]]
    return {
        "simulated_s": duration_s,
        "ber": ber,
        "samples": len(samples),
        "by_age": rows,
        "all": {
            "received_pos_m": [_percentile([x[2] for x in samples], q) for q in (50, 95)],
            "predicted_pos_m": [_percentile([x[3] for x in samples], q) for q in (50, 95)],
            "received_yaw_deg": [_percentile([x[4] for x in samples], q) for q in (50, 95)],
            "predicted_yaw_deg": [_percentile([x[5] for x in samples], q) for q in (50, 95)],
        },
        "pose_age_not_steering_s": [_percentile(idle_ages, q) for q in (50, 95)],
        "pose_age_steering_s": [_percentile(steer_ages, q) for q in (50, 95)],
        "first_wish_after_pause_s": [_percentile(first_wish, q) for q in (50, 95)],
        "pauses": len(first_wish),
        "images_completed": master.master.stats.images_completed,
        "image_bytes": 2000,
    }


def prediction_targets(result: dict, lossy: dict | None = None) -> dict:
    """The held stick issue's targets, judged on `measure_prediction`'s results (the
    lossy run fills the older ages: the prediction must beat the received pose at each)."""
    rows = [r for res in (result, lossy) if res for r in res["by_age"] if r["n"] >= 20]
    better = all(r["predicted_pos_m"][1] <= r["received_pos_m"][1] and r["predicted_yaw_deg"][1] <= r["received_yaw_deg"][1]
                 for r in rows)
    age95 = result["pose_age_not_steering_s"][1]
    wish95 = result["first_wish_after_pause_s"][1]
    return {
        "prediction_p95_below_received_at_every_age": {"age_bins_judged": len(rows), "met": bool(rows) and better},
        "pose_age_not_steering_p95_le_1.5s": {"p95_s": age95, "limit_s": 1.5,
                                              "met": age95 is not None and age95 <= 1.5},
        "first_wish_after_pause_p95_le_0.59s": {"p95_s": wish95, "limit_s": 0.59,
                                                "met": wish95 is not None and wish95 <= 0.59},
    }


def prediction_lines(result: dict) -> list[str]:
    from rovlink.bench import format_table

    def pair(p):
        return "—" if p[0] is None else f"{p[0]:.2f} / {p[1]:.2f}"

    table = format_table(
        ["pose age s", "n", "received m p50/p95", "predicted m p50/p95", "received yaw° p50/p95",
         "predicted yaw° p50/p95"],
        [[f"{r['age_s'][0]:g}-{'' if r['age_s'][1] is None else format(r['age_s'][1], 'g')}", r["n"],
          pair(r["received_pos_m"]), pair(r["predicted_pos_m"]), pair(r["received_yaw_deg"]),
          pair(r["predicted_yaw_deg"])] for r in result["by_age"]]
        + [["all", result["samples"], pair(result["all"]["received_pos_m"]), pair(result["all"]["predicted_pos_m"]),
            pair(result["all"]["received_yaw_deg"]), pair(result["all"]["predicted_yaw_deg"])]])
    return [
        f"prediction: a pilot holding control, steering 1-4 s and pausing 2-8 s, {result['simulated_s'] / 60:g} "
        f"simulated minutes at 1900 bit/s, 85 ms, BER {result['ber']:g}, version 2; error against the vehicle "
        f"model's truth at the same instant",
        table,
        format_table(["reaction measure", "p50 s", "p95 s"], [
            ["pose age on the page, not steering", *result["pose_age_not_steering_s"]],
            ["pose age on the page, steering", *result["pose_age_steering_s"]],
            [f"first wish after a pause, at the ROV ({result['pauses']} pauses)", *result["first_wish_after_pause_s"]],
        ]),
        f"pictures completed meanwhile: {result['images_completed']} of {result['image_bytes']} B",
    ]
