"""`rovlink bench link`: the protocol over the paper's link, in simulated time.

For each bit error rate and for three protocol modes ("rovlink": adaptive SIZE
classes and receiver-driven retransmission, version 1.1; "rovlink v2": the
same with every frame authenticated, docs/PROTOCOL.md §8, 9 bytes more per cycle
and a HELLO/SYNC to start; "paper": fixed 40-byte trunks and no
retransmission, one lost trunk losing the image) two sessions are run with
the real Master, Slave and Channel:

- idle: the pilot does nothing, images stream with the idle SIZE class;
- steering: the pilot's velocity wish changes every `change_s` (never neutral,
  but centred once when a reply shows the ROV holding, as after a failsafe: the
  page asks a pilot to, and the ROV takes no other wish until then).

Figures: seconds to deliver a 2000-byte image object (median, p95) beside the
physical floor 8 x bytes / bitrate; the poll interval while steering; the
latency from a new wish to its arrival at the ROV; images completed per image
finished (completed or abandoned).  Beside the targets, the floors no version 2
of this shape can beat on the link (`_bounds`, docs/PROTOCOL.md §8 and §8.1):
where a target lies below its floor, the bench says so with the numbers.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Callable

from rovlink.bench import emit, format_table, median, quantile
from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import ImageAbandoned, ImageComplete, ImageProgress, Master
from rovlink.link.radio.messages import VELOCITY_FULL
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import FailsafeEntered, Slave, VelocityCommanded, status_from_pose

BERS = (0.0, 7e-6, 1e-4, 1e-3)
OBJECT_BYTES = 2000
FIRST_BYTES = 500  # a picture already (every prefix of DEBT is one): its first look
# The vehicle the ROV reports while the pilot steers: full stick is 1 m/s
# forward or sideways, 0.8 m/s down, 60 deg/s of yaw (ArduSub measured about
# 0.7 m/s at 70 % and 36 deg/s at 60 %: rov/vehicle.py), reached with a 0.5 s
# time constant; roll and pitch lean with the thrust and tremble.
FULL_SPEED = (1.0, 1.0, 0.8, 60.0)  # m/s, m/s, m/s, deg/s
VEHICLE_STEP_S = 0.05


@dataclass
class Session:
    image_s: list[float] = field(default_factory=list)
    first_bytes_s: list[float] = field(default_factory=list)  # until FIRST_BYTES of a picture were in
    images_completed: int = 0
    images_abandoned: int = 0
    poll_times: list[float] = field(default_factory=list)
    wish_latency_s: list[float] = field(default_factory=list)
    wish_arrived_at: list[float] = field(default_factory=list)
    failsafe_at: list[float] = field(default_factory=list)
    replies_lost: int = 0
    polls: int = 0
    failsafes: int = 0
    velocity_lapses: int = 0
    hellos: int = 0




def run_session(mode: str, ber: float, steering: bool, duration_s: float, seed: int, *, bitrate: float = 1900.0,
                delay_s: float = 0.085, change_s: float = 1.0, loss: float = 0.0, burst: float = 1.0,
                tap: Callable[[str, bytes, float], None] | None = None) -> Session:
    """One session; `tap(side, frame_bytes, at)` sees every frame handed to the channel
    ("a": the operator's, "b": the ROV's), before the channel's errors."""
    rng = random.Random(seed)
    stream = rng.randbytes(OBJECT_BYTES - 2)
    if mode == "paper":
        master = Master(bitrate_bps=bitrate, delay_s=delay_s, retransmit=False, steering_size=1, idle_size=1,
                        rng=random.Random(seed))
        slave = Slave(image_source=lambda img, s: stream, trunk_cap=40)
    else:
        master = Master(bitrate_bps=bitrate, delay_s=delay_s, rng=random.Random(seed))
        slave = Slave(image_source=lambda img, s: stream)
    master_end, slave_end = master, slave  # what the link drives
    secure = None
    if mode == "rovlink v2":
        from rovlink.link.radio.secure import SecureMaster, SecureSlave

        key = random.Random(seed).randbytes(32)
        master_end, slave_end = secure, _ = SecureMaster(master, key), SecureSlave(slave, key)
    channel = Channel(LinkParams(bitrate_bps=bitrate, delay_s=delay_s, ber=ber, loss=loss, burst=burst), seed=seed)
    if tap is not None:
        send = channel.send

        def tapped_send(side: str, data: bytes, at: float) -> bool:
            tap(side, data, at)
            return send(side, data, at)

        channel.send = tapped_send  # type: ignore[method-assign]
    result = Session()
    pending_wish: list[tuple[float, tuple[int, int, int, int]]] = []
    first_counted: set[float] = set()

    def on_master(event, now):
        if isinstance(event, ImageComplete):
            result.images_completed += 1
            result.image_s.append(event.at - event.started_at)
        elif isinstance(event, ImageAbandoned):
            result.images_abandoned += 1
        elif isinstance(event, ImageProgress):
            started = master._image.started_at
            if event.received_bytes >= FIRST_BYTES and started is not None and started not in first_counted:
                first_counted.add(started)
                result.first_bytes_s.append(now - started)

    def on_slave(event, now):
        if isinstance(event, FailsafeEntered):
            result.failsafes += 1
            result.failsafe_at.append(now)
        if isinstance(event, VelocityCommanded) and pending_wish:
            v = event.velocity
            got = (v.vx, v.vy, v.vz, v.vyaw)
            # The newest wish that has arrived settles it and all older ones.
            for i in range(len(pending_wish) - 1, -1, -1):
                t, wish = pending_wish[i]
                if wish == got:
                    result.wish_latency_s.append(now - t)
                    result.wish_arrived_at.append(now)
                    del pending_wish[: i + 1]
                    break

    sim = SimLink(master_end, slave_end, channel, on_master_event=on_master, on_slave_event=on_slave)
    _fly(sim, slave, random.Random(seed + 7))
    original_next_poll = master_end.next_poll

    def next_poll(now):
        frame = original_next_poll(now)
        if frame is not None:
            result.poll_times.append(now)
        return frame

    master_end.next_poll = next_poll  # type: ignore[method-assign]

    if steering:
        def change(now):
            v, reply = master.velocity, master.last_reply
            if reply is not None and reply.hold and any((v.vx, v.vy, v.vz, v.vyaw)):
                # The ROV holds (after a failsafe): the pilot centres the sticks, as the
                # page asks, and steers again at the next change.
                master.set_velocity(0, 0, 0, 0, now)
                sim.at(now + change_s * rng.uniform(0.5, 1.5), change)
                return
            while True:
                wish = tuple(rng.randint(-VELOCITY_FULL, VELOCITY_FULL) for _ in range(4))
                if any(wish) and wish != (master.velocity.vx, master.velocity.vy, master.velocity.vz,
                                          master.velocity.vyaw):
                    break
            master.set_velocity(*wish, now)
            pending_wish.append((now, wish))
            # A pilot moves the sticks when he needs to, not on a beat: the next
            # change comes 0.5 to 1.5 change_s later (1 s on average).
            sim.at(now + change_s * rng.uniform(0.5, 1.5), change)

        # A pilot starts from centred sticks: the ROV ignores non-zero wishes
        # until a neutral one has arrived (HOLD at start, docs/PROTOCOL.md §5).
        sim.at(2.0, change)
    sim.run_until(duration_s)
    result.replies_lost = master.stats.replies_lost
    result.polls = master.stats.polls_sent
    result.velocity_lapses = slave.stats.velocity_lapses
    result.hellos = secure.stats2.hellos_sent if secure is not None else 0
    return result


def _fly(sim: SimLink, slave: Slave, rng: random.Random) -> None:
    """Move the vehicle the slave reports, after the velocity it applies, every 50 ms."""
    state = {"x": 0.0, "y": 0.0, "z": 5.0, "yaw": 0.0, "v": [0.0, 0.0, 0.0, 0.0]}

    def step(now: float) -> None:
        w = slave.velocity
        wish = [a / VELOCITY_FULL * full for a, full in zip((w.vx, w.vy, w.vz, w.vyaw), FULL_SPEED)]
        k = VEHICLE_STEP_S / 0.5
        v = state["v"] = [c + (t - c) * k for c, t in zip(state["v"], wish)]
        yaw = math.radians(state["yaw"])
        state["x"] += (v[0] * math.cos(yaw) - v[1] * math.sin(yaw)) * VEHICLE_STEP_S
        state["y"] += (v[0] * math.sin(yaw) + v[1] * math.cos(yaw)) * VEHICLE_STEP_S
        state["z"] = max(0.0, state["z"] + v[2] * VEHICLE_STEP_S)
        state["yaw"] = (state["yaw"] + v[3] * VEHICLE_STEP_S + 180.0) % 360.0 - 180.0
        slave.update_status(status_from_pose(
            x_m=state["x"], y_m=state["y"], z_m=state["z"],
            roll_deg=3.0 * v[1] + rng.gauss(0.0, 0.3), pitch_deg=-3.0 * v[0] + rng.gauss(0.0, 0.3),
            yaw_deg=state["yaw"] + rng.gauss(0.0, 0.2), armed=True, mode=1, autopilot=True,
            position_valid=True, attitude_valid=True))
        sim.at(now + VEHICLE_STEP_S, step)

    sim.at(0.0, step)


LOSSES = (0.05, 0.10, 0.20)
BURST = 3.0  # mean frames lost in a row in the bursty rows (Gilbert-Elliott)
# Version 1.1 as it was measured before issue 23 (300 s sessions, seed 1): it must be no worse.
V11_BEFORE = {"steering_image_s": 34.4, "poll_interval_s": 0.41, "wish_latency_s_p95": 0.533}


def _ratio(done: int, finished: int) -> str:
    return f"{done}/{finished}" if finished else "0/0"


def _target(value, limit, met) -> dict:
    return {"value": value, "limit": limit, "met": bool(met)}


def _le(value, limit) -> dict:
    return _target(value, limit, value is not None and value <= limit)


def _plots(out_dir: str, sessions: dict[str, Session]) -> list[str]:
    """Picture-time and poll-interval distributions as PNG files (matplotlib, the
    console extra); returns the files written, or says why none."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    import os

    os.makedirs(out_dir, exist_ok=True)
    written = []
    fig, ax = plt.subplots(figsize=(7, 4))
    every = [v for sess in sessions.values() for v in sess.image_s]
    lo, hi = (min(every), max(every)) if every else (0.0, 1.0)
    bins = [lo - 0.5 + (hi - lo + 1.0) * k / 80 for k in range(81)]  # the same bins for every protocol
    for name, sess in sessions.items():
        if sess.image_s:
            ax.hist(sess.image_s, bins=bins, alpha=0.6, label=f"{name} ({len(sess.image_s)} pictures)")
    ax.set_xlabel(f"seconds to deliver a {OBJECT_BYTES}-byte picture while steering (BER 7e-6)")
    ax.set_ylabel("pictures")
    ax.legend()
    fig.tight_layout()
    path = os.path.join(out_dir, "picture_time_steering.png")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    written.append(path)
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, sess in sessions.items():
        intervals = [b - a for a, b in zip(sess.poll_times, sess.poll_times[1:])]
        if intervals:
            ax.hist(intervals, bins=60, range=(0.3, 1.0), alpha=0.5, label=name)
    ax.set_xlabel("seconds between polls while steering (BER 7e-6)")
    ax.set_ylabel("polls")
    ax.legend()
    fig.tight_layout()
    path = os.path.join(out_dir, "poll_interval_steering.png")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    written.append(path)
    return written


def _bounds(args, five_bursts: dict) -> dict:
    """Floors under issue 23's two figures that version 2 misses, from the link's
    numbers and the wire's (docs/PROTOCOL.md §8.1), for any protocol that answers
    each poll with one frame carrying the pose (the mission's: odometry in every
    reply) and keeps the ROV's failsafe time:

    - idle: a reply carries at most MAX_TRUNK picture bytes (both versions' largest
      trunk, §2; with its status, the smallest pose of six one-byte differences and
      its tag it fits a V2_MAX_FRAME frame): they fix the fewest replies for one
      picture asked at a time; each reply costs at
      least the smallest poll, its own overhead and the two intrinsic delays;
    - failsafes: the ROV's failsafe comes when every poll of a failsafe time is
      lost; at the shortest cycle (smallest poll and reply, no margin at all) that
      is a run of n lost polls; a Gilbert-Elliott burst (mean `BURST` frames) runs
      at least n frames with probability (1 - 1/BURST)^(n-1), and bursts start at
      loss / BURST per poll sent."""
    from rovlink.link.radio.auth import TAG_BYTES
    from rovlink.link.radio.messages import FAILSAFE_S, MAX_TRUNK
    from rovlink.link.radio.wire2 import MIN_POLL_FRAME, V2_MAX_FRAME, V2_OVERHEAD, V2_REPLY_STATUS

    def air(nbytes: int) -> float:
        return 8.0 * nbytes / args.bitrate

    smallest_pose = 6  # six differences of one byte: a vehicle that did not move
    reply_overhead = V2_OVERHEAD + V2_REPLY_STATUS + smallest_pose + TAG_BYTES
    per_reply = min(V2_MAX_FRAME - reply_overhead, MAX_TRUNK)
    replies = math.ceil(OBJECT_BYTES / per_reply)
    cycle_overhead = air(MIN_POLL_FRAME + reply_overhead) + 2 * args.delay
    shortest_cycle = cycle_overhead  # a reply without picture, no margin
    n = math.floor(FAILSAFE_S / shortest_cycle)
    bursts = five_bursts["polls_per_hour"] * five_bursts["loss"] / BURST
    expected = bursts * (1.0 - 1.0 / BURST) ** (n - 1)
    return {
        "v2_idle_2000B": {
            "replies": replies, "picture_bytes_per_reply": per_reply,
            "seconds": air(OBJECT_BYTES) + replies * cycle_overhead,
            "picture_bytes_needed_for_one_fewer": math.ceil(OBJECT_BYTES / (replies - 1)),
        },
        "v2_failsafes_at_5%_bursts": {
            "shortest_cycle_s": shortest_cycle, "polls_in_failsafe_time": n, "bursts_per_hour": bursts,
            "expected_per_hour": expected, "chance_of_none_in_an_hour": math.exp(-expected),
        },
    }


def run(args) -> int:
    if args.profile == "acoustic":
        from rovlink.link.acoustic.bench import run as run_acoustic
        return run_acoustic(args)
    floor_s = 8 * OBJECT_BYTES / args.bitrate
    rows = []
    results = []
    steering_sessions: dict[str, Session] = {}
    for mode in ("rovlink", "rovlink v2", "paper"):
        for ber in BERS:
            idle = run_session(mode, ber, False, args.duration, args.seed, bitrate=args.bitrate, delay_s=args.delay)
            steer = run_session(mode, ber, True, args.duration, args.seed + 1, bitrate=args.bitrate,
                                delay_s=args.delay)
            if ber == 7e-6:
                steering_sessions[mode] = steer
            intervals = [b - a for a, b in zip(steer.poll_times, steer.poll_times[1:])]
            entry = {
                "mode": mode,
                "ber": ber,
                "floor_s": floor_s,
                "idle_image_s_median": median(idle.image_s),
                "idle_image_s_p95": quantile(idle.image_s, 0.95),
                "steering_image_s_median": median(steer.image_s),
                "steering_image_s_p95": quantile(steer.image_s, 0.95),
                "steering_first_500B_s_median": median(steer.first_bytes_s),
                "poll_interval_s_median": median(intervals),
                "poll_interval_s_p95": quantile(intervals, 0.95),
                "wish_latency_s_median": median(steer.wish_latency_s),
                "wish_latency_s_p95": quantile(steer.wish_latency_s, 0.95),
                "idle_images_completed": idle.images_completed,
                "idle_images_finished": idle.images_completed + idle.images_abandoned,
                "steering_images_completed": steer.images_completed,
                "steering_images_finished": steer.images_completed + steer.images_abandoned,
                "idle_replies_lost": idle.replies_lost,
                "idle_polls": idle.polls,
            }
            results.append(entry)
            rows.append([
                mode, f"{ber:g}",
                entry["idle_image_s_median"], entry["idle_image_s_p95"],
                None if entry["idle_image_s_median"] is None else entry["idle_image_s_median"] / floor_s,
                entry["steering_image_s_median"], entry["steering_image_s_p95"], entry["steering_first_500B_s_median"],
                entry["poll_interval_s_median"], entry["poll_interval_s_p95"],
                entry["wish_latency_s_median"], entry["wish_latency_s_p95"],
                _ratio(idle.images_completed, entry["idle_images_finished"]),
                _ratio(steer.images_completed, entry["steering_images_finished"]),
            ])

    # Steering under loss: an hour (--loss-duration) with a share of the frames lost, alone or in bursts.
    loss_rows, loss_results = [], []
    for loss in LOSSES:
        for burst in (1.0, BURST):
            for mode in ("rovlink", "rovlink v2"):
                sess = run_session(mode, 0.0, True, args.loss_duration, args.seed + 2, bitrate=args.bitrate,
                                   delay_s=args.delay, loss=loss, burst=burst)
                hours = args.loss_duration / 3600.0
                entry = {
                    "mode": mode, "loss": loss, "burst": burst, "hours": hours,
                    "failsafes_per_hour": sess.failsafes / hours,
                    "pictures_per_hour": sess.images_completed / hours,
                    "velocity_lapses_per_hour": sess.velocity_lapses / hours,
                    "hellos_per_hour": sess.hellos / hours,
                    "polls_per_hour": sess.polls / hours,
                    "replies_lost_share": sess.replies_lost / sess.polls if sess.polls else None,
                    "wish_latency_s_p95": quantile(sess.wish_latency_s, 0.95),
                }
                loss_results.append(entry)
                loss_rows.append([mode, f"{loss:.0%}", "bursts of 3" if burst > 1 else "independent",
                                  entry["failsafes_per_hour"], entry["pictures_per_hour"],
                                  entry["velocity_lapses_per_hour"], entry["hellos_per_hour"],
                                  entry["replies_lost_share"], entry["wish_latency_s_p95"]])

    def find(mode, ber):
        return next(r for r in results if r["mode"] == mode and r["ber"] == ber)

    def lossy(mode, loss, burst):
        return next(r for r in loss_results if r["mode"] == mode and r["loss"] == loss and r["burst"] == burst)

    r7, r3 = find("rovlink", 7e-6), find("rovlink", 1e-3)
    a7, a3 = find("rovlink v2", 7e-6), find("rovlink v2", 1e-3)

    def all_complete(r):
        return (r["idle_images_completed"] > 0 and r["idle_images_completed"] == r["idle_images_finished"]
                and r["steering_images_completed"] == r["steering_images_finished"])

    targets = {
        # Issue 23: pictures while steering, version 2 (BER 7e-6).
        "v2_steering_2000B_le_22s": _le(a7["steering_image_s_median"], 22.0),
        "v2_steering_first_500B_le_7s": _le(a7["steering_first_500B_s_median"], 7.0),
        "v2_steering_median_poll_interval_le_0.5s": _le(a7["poll_interval_s_median"], 0.5),
        "v2_wish_to_rov_p95_le_0.59s": _le(a7["wish_latency_s_p95"], 0.59),
        "v2_idle_2000B_le_1.25x_floor": _le(a7["idle_image_s_median"], 1.25 * floor_s),
        "v1.1_steering_no_worse": _le(r7["steering_image_s_median"], V11_BEFORE["steering_image_s"]),
        "v1.1_poll_interval_no_worse": _le(r7["poll_interval_s_median"], V11_BEFORE["poll_interval_s"]),
        "v1.1_wish_p95_no_worse": _le(r7["wish_latency_s_p95"], V11_BEFORE["wish_latency_s_p95"]),
        # Earlier targets, kept.
        "idle_2000B_le_1.4x_floor": _le(r7["idle_image_s_median"], 1.4 * floor_s),
        "every_image_completes_at_ber_1e-3": _target(f"{r3['idle_images_completed']}+{r3['steering_images_completed']}",
                                                     "all", all_complete(r3)),
        "v2_every_image_completes_at_ber_1e-3": _target(
            f"{a3['idle_images_completed']}+{a3['steering_images_completed']}", "all", all_complete(a3)),
    }
    for burst in (1.0, BURST):
        kind = "bursts" if burst > 1 else "independent"
        five = lossy("rovlink v2", 0.05, burst)
        targets[f"v2_no_failsafe_at_5%_{kind}"] = _target(five["failsafes_per_hour"], 0, five["failsafes_per_hour"] == 0)
        for loss, factor in ((0.05, 1.0), (0.10, 1.0), (0.20, 1.5)):
            v2, v11 = lossy("rovlink v2", loss, burst), lossy("rovlink", loss, burst)
            limit = factor * v11["failsafes_per_hour"]
            targets[f"v2_failsafes_le_{factor:g}x_v1.1_at_{loss:.0%}_{kind}"] = _target(
                v2["failsafes_per_hour"], limit, v2["failsafes_per_hour"] <= limit)

    bounds = _bounds(args, lossy("rovlink v2", 0.05, BURST))
    plots = _plots(args.out, steering_sessions) if args.out else []
    doc = {
        "link": {"bitrate_bps": args.bitrate, "delay_s": args.delay, "object_bytes": OBJECT_BYTES,
                 "session_s": args.duration, "loss_session_s": args.loss_duration, "seed": args.seed},
        "results": results,
        "under_loss": loss_results,
        "targets": targets,
        "bounds": bounds,
        "plots": plots,
    }
    headers = ["mode", "BER", "idle img s", "p95", "x floor", "steer img s", "p95", "first 500B s", "poll s", "p95",
               "wish->ROV s", "p95", "idle done", "steer done"]
    loss_headers = ["mode", "lost", "how", "failsafes/h", "pictures/h", "lapses/h", "HELLOs/h", "replies lost",
                    "wish p95 s"]
    lines = [
        f"rovlink bench link: {OBJECT_BYTES}-byte image objects over {args.bitrate:g} bit/s, {args.delay * 1000:g} ms "
        f"intrinsic delay; {args.duration:g} s simulated sessions (seed {args.seed}); floor 8 x bytes / bitrate = "
        f"{floor_s:.2f} s. Steering: a new wish every 0.5-1.5 s, the vehicle moving after it.",
        "",
        format_table(headers, rows),
        "",
        f"steering under loss ({args.loss_duration / 3600:g} h simulated each, BER 0, frames lost each way):",
        "",
        format_table(loss_headers, loss_rows),
        "",
        "targets:",
    ]
    for name, t in targets.items():
        value = f"{t['value']:.3g}" if isinstance(t["value"], float) else str(t["value"])
        limit = f"{t['limit']:.3g}" if isinstance(t["limit"], float) else str(t["limit"])
        lines.append(f"  {'MET   ' if t['met'] else 'MISSED'} {name}: {value} (limit {limit})")
    idle, fs = bounds["v2_idle_2000B"], bounds["v2_failsafes_at_5%_bursts"]
    lines += [
        "",
        "bounds (what no version 2 of this shape can beat on this link, docs/PROTOCOL.md §8 and §8.1):",
        f"  idle {OBJECT_BYTES} B, a pose in every reply: at least {idle['replies']} replies of at most "
        f"{idle['picture_bytes_per_reply']} picture bytes -> at least {idle['seconds']:.2f} s "
        f"({idle['seconds'] / floor_s:.2f}x floor); {idle['replies'] - 1} replies would need "
        f"{idle['picture_bytes_needed_for_one_fewer']} picture bytes each, a reply without status and pose",
        f"  failsafes at 5 % in bursts of {BURST:g}: even at the shortest cycle ({fs['shortest_cycle_s']:.3f} s, "
        f"no margin) {fs['polls_in_failsafe_time']} polls in a row must be lost; {fs['bursts_per_hour']:.0f} bursts "
        f"an hour start -> at least {fs['expected_per_hour']:.1f} an hour expected "
        f"(none in an hour: {fs['chance_of_none_in_an_hour']:.0%})",
    ]
    if args.out:
        lines.append("")
        lines.append(f"plots: {', '.join(plots)}" if plots else
                     "plots: none (matplotlib is not installed: pip install 'rovlink[console]')")
    emit(doc, "\n".join(lines), args.json)
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "link",
        help="image delivery, command cycle and loss over the paper's 1.9 kbit/s link",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--profile", choices=("radio", "acoustic"), default="radio",
                   help="radio (default): the paper's link; acoustic: docs/PROTOCOL.md §9 over the Modem-M64 emulator")
    p.add_argument("--duration", type=float, default=900.0, metavar="S", help="simulated seconds per session (900)")
    p.add_argument("--loss-duration", type=float, default=3600.0, metavar="S",
                   help="simulated seconds per steering session under loss (3600)")
    p.add_argument("--bitrate", type=float, default=1900.0, metavar="BPS", help="bit/s (default 1900)")
    p.add_argument("--delay", type=float, default=0.085, metavar="S", help="intrinsic delay, s (default 0.085)")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument("--out", default="rovlink-bench/link", metavar="DIR",
                   help="folder for the distribution plots (default rovlink-bench/link; '' for none)")
    p.set_defaults(func=run)
