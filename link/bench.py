"""`rovlink bench link`: the protocol over the paper's link, in simulated time.

For each bit error rate and for three protocol modes ("rovlink": adaptive SIZE
classes and receiver-driven retransmission, version 1.1; "rovlink v2": the
same with every frame authenticated, docs/PROTOCOL.md §8, 9 bytes more per cycle
and a HELLO/SYNC to start; "paper": fixed 40-byte trunks and no
retransmission, one lost trunk losing the image) two sessions are run with
the real Master, Slave and Channel:

- idle: the pilot does nothing, images stream with the idle SIZE class;
- steering: the pilot's velocity wish changes every `change_s` (never neutral).

Figures: seconds to deliver a 2000-byte image object (median, p95) beside the
physical floor 8 x bytes / bitrate; the poll interval while steering; the
latency from a new wish to its arrival at the ROV; images completed per image
finished (completed or abandoned).
"""

from __future__ import annotations

import random
import statistics
from dataclasses import dataclass, field

from rovlink.bench import emit, format_table
from rovlink.link.channel import Channel, LinkParams
from rovlink.link.master import ImageAbandoned, ImageComplete, Master
from rovlink.link.messages import VELOCITY_FULL
from rovlink.link.sim import SimLink
from rovlink.link.slave import Slave, VelocityCommanded

BERS = (0.0, 7e-6, 1e-4, 1e-3)
OBJECT_BYTES = 2000


@dataclass
class Session:
    image_s: list[float] = field(default_factory=list)
    images_completed: int = 0
    images_abandoned: int = 0
    poll_times: list[float] = field(default_factory=list)
    wish_latency_s: list[float] = field(default_factory=list)
    replies_lost: int = 0
    polls: int = 0


def _quantile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    values = sorted(values)
    k = min(len(values) - 1, max(0, int(round(q * (len(values) - 1)))))
    return values[k]


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def run_session(mode: str, ber: float, steering: bool, duration_s: float, seed: int, *, bitrate: float = 1900.0,
                delay_s: float = 0.085, change_s: float = 1.0) -> Session:
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
    if mode == "rovlink v2":
        from rovlink.link.secure import SecureMaster, SecureSlave

        key = random.Random(seed).randbytes(32)
        master_end, slave_end = SecureMaster(master, key), SecureSlave(slave, key)
    channel = Channel(LinkParams(bitrate_bps=bitrate, delay_s=delay_s, ber=ber), seed=seed)
    result = Session()
    pending_wish: list[tuple[float, tuple[int, int, int, int]]] = []

    def on_master(event, now):
        if isinstance(event, ImageComplete):
            result.images_completed += 1
            result.image_s.append(event.at - event.started_at)
        elif isinstance(event, ImageAbandoned):
            result.images_abandoned += 1

    def on_slave(event, now):
        if isinstance(event, VelocityCommanded) and pending_wish:
            v = event.velocity
            got = (v.vx, v.vy, v.vz, v.vyaw)
            # The newest wish that has arrived settles it and all older ones.
            for i in range(len(pending_wish) - 1, -1, -1):
                t, wish = pending_wish[i]
                if wish == got:
                    result.wish_latency_s.append(now - t)
                    del pending_wish[: i + 1]
                    break

    sim = SimLink(master_end, slave_end, channel, on_master_event=on_master, on_slave_event=on_slave)
    original_next_poll = master_end.next_poll

    def next_poll(now):
        frame = original_next_poll(now)
        if frame is not None:
            result.poll_times.append(now)
        return frame

    master_end.next_poll = next_poll  # type: ignore[method-assign]

    if steering:
        def change(now):
            while True:
                wish = tuple(rng.randint(-VELOCITY_FULL, VELOCITY_FULL) for _ in range(4))
                if any(wish) and wish != (master.velocity.vx, master.velocity.vy, master.velocity.vz,
                                          master.velocity.vyaw):
                    break
            master.set_velocity(*wish, now)
            pending_wish.append((now, wish))
            sim.at(now + change_s, change)

        # A pilot starts from centred sticks: the ROV ignores non-zero wishes
        # until a neutral one has arrived (HOLD at start, docs/PROTOCOL.md §5).
        sim.at(2.0, change)
    sim.run_until(duration_s)
    result.replies_lost = master.stats.replies_lost
    result.polls = master.stats.polls_sent
    return result


def run(args) -> int:
    floor_s = 8 * OBJECT_BYTES / args.bitrate
    rows = []
    results = []
    for mode in ("rovlink", "rovlink v2", "paper"):
        for ber in BERS:
            idle = run_session(mode, ber, False, args.duration, args.seed, bitrate=args.bitrate, delay_s=args.delay)
            steer = run_session(mode, ber, True, args.duration, args.seed + 1, bitrate=args.bitrate,
                                delay_s=args.delay)
            intervals = [b - a for a, b in zip(steer.poll_times, steer.poll_times[1:])]
            entry = {
                "mode": mode,
                "ber": ber,
                "floor_s": floor_s,
                "idle_image_s_median": _median(idle.image_s),
                "idle_image_s_p95": _quantile(idle.image_s, 0.95),
                "steering_image_s_median": _median(steer.image_s),
                "poll_interval_s_median": _median(intervals),
                "poll_interval_s_p95": _quantile(intervals, 0.95),
                "wish_latency_s_median": _median(steer.wish_latency_s),
                "wish_latency_s_p95": _quantile(steer.wish_latency_s, 0.95),
                "idle_images_completed": idle.images_completed,
                "idle_images_finished": idle.images_completed + idle.images_abandoned,
                "steering_images_completed": steer.images_completed,
                "steering_images_finished": steer.images_completed + steer.images_abandoned,
                "idle_replies_lost": idle.replies_lost,
                "idle_polls": idle.polls,
            }
            results.append(entry)

            def ratio(done, finished):
                return f"{done}/{finished}" if finished else "0/0"

            rows.append([
                mode, f"{ber:g}",
                entry["idle_image_s_median"], entry["idle_image_s_p95"],
                None if entry["idle_image_s_median"] is None else entry["idle_image_s_median"] / floor_s,
                entry["steering_image_s_median"],
                entry["poll_interval_s_median"], entry["poll_interval_s_p95"],
                entry["wish_latency_s_median"], entry["wish_latency_s_p95"],
                ratio(idle.images_completed, entry["idle_images_finished"]),
                ratio(steer.images_completed, entry["steering_images_finished"]),
            ])

    def find(mode, ber):
        return next(r for r in results if r["mode"] == mode and r["ber"] == ber)

    r7 = find("rovlink", 7e-6)
    r3 = find("rovlink", 1e-3)
    targets = {
        "idle_2000B_at_ber_7e-6_le_1.4x_floor": {
            "value_s": r7["idle_image_s_median"], "limit_s": 1.4 * floor_s,
            "met": r7["idle_image_s_median"] is not None and r7["idle_image_s_median"] <= 1.4 * floor_s,
        },
        "steering_median_poll_interval_le_0.5s": {
            "value_s": r7["poll_interval_s_median"], "limit_s": 0.5,
            "met": r7["poll_interval_s_median"] is not None and r7["poll_interval_s_median"] <= 0.5,
        },
        "every_image_completes_at_ber_1e-3": {
            "completed": r3["idle_images_completed"] + r3["steering_images_completed"],
            "finished": r3["idle_images_finished"] + r3["steering_images_finished"],
            "met": r3["idle_images_completed"] > 0
            and r3["idle_images_completed"] == r3["idle_images_finished"]
            and r3["steering_images_completed"] == r3["steering_images_finished"],
        },
    }
    a7, a3 = find("rovlink v2", 7e-6), find("rovlink v2", 1e-3)
    targets.update({
        "v2_idle_2000B_at_ber_7e-6_le_1.45x_floor": {
            "value_s": a7["idle_image_s_median"], "limit_s": 1.45 * floor_s,
            "met": a7["idle_image_s_median"] is not None and a7["idle_image_s_median"] <= 1.45 * floor_s,
        },
        "v2_steering_median_poll_interval_lt_0.5s": {
            "value_s": a7["poll_interval_s_median"], "limit_s": 0.5,
            "met": a7["poll_interval_s_median"] is not None and a7["poll_interval_s_median"] < 0.5,
        },
        "v2_every_image_completes_at_ber_1e-3": {
            "completed": a3["idle_images_completed"] + a3["steering_images_completed"],
            "finished": a3["idle_images_finished"] + a3["steering_images_finished"],
            "met": a3["idle_images_completed"] > 0
            and a3["idle_images_completed"] == a3["idle_images_finished"]
            and a3["steering_images_completed"] == a3["steering_images_finished"],
        },
    })
    doc = {
        "link": {"bitrate_bps": args.bitrate, "delay_s": args.delay, "object_bytes": OBJECT_BYTES,
                 "session_s": args.duration, "seed": args.seed},
        "results": results,
        "targets": targets,
    }
    headers = ["mode", "BER", "idle img s", "p95", "x floor", "steer img s", "poll s", "p95", "wish->ROV s", "p95",
               "idle done", "steer done"]
    lines = [
        f"rovlink bench link: {OBJECT_BYTES}-byte image objects over {args.bitrate:g} bit/s, {args.delay * 1000:g} ms "
        f"intrinsic delay; {args.duration:g} s simulated sessions (seed {args.seed}); floor 8 x bytes / bitrate = "
        f"{floor_s:.2f} s",
        "",
        format_table(headers, rows),
        "",
        "targets:",
    ]
    for name, t in targets.items():
        lines.append(f"  {'MET ' if t['met'] else 'MISSED'} {name}: "
                     + ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                                 for k, v in t.items() if k != "met"))
    emit(doc, "\n".join(lines), args.json)
    return 0


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "link",
        help="image delivery, command cycle and loss over the paper's 1.9 kbit/s link",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--duration", type=float, default=900.0, metavar="S", help="simulated seconds per session (900)")
    p.add_argument("--bitrate", type=float, default=1900.0, metavar="BPS", help="bit/s (default 1900)")
    p.add_argument("--delay", type=float, default=0.085, metavar="S", help="intrinsic delay, s (default 0.085)")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.set_defaults(func=run)
