"""Pictures while steering (`rovlink bench console`, the steering rows; issue 40).

A version 2 session in simulated time with the real machines (`rovlink bench link`'s
steering session: Master and Slave behind SecureMaster/SecureSlave, the emulated
channel at 1900 bit/s, 85 ms each way, BER 7e-6, a pilot changing the wish every
0.5-1.5 s, the vehicle moving after it): the seconds a 2000-byte picture takes and the
wish's time to the ROV (p95), with every frame's bytes put down to what they carry
(framing, byte 0, the poll's request and wish, COUNT, the reply's status, its pose and
annex, the trunk, the tags: docs/PROTOCOL.md §8 and §8.1).

Beside it the floor: what no version 2 of this shape can beat for such a pilot, from
the link's numbers and the wire's.  A wish waits for the poll after the cycle in flight,
so its p95 is about 0.95 of a cycle plus the air time of a poll carrying it plus one
delay; the wish limit so caps the cycle, and a cycle carries at most what is left after
the smallest poll (a new wish in the share of polls the pilot changes it in) and the
smallest reply (byte 0, status, six one-byte pose differences, tag).
"""

from __future__ import annotations

import math

from rovlink.bench import format_table, median, quantile

WISH_LIMIT_S = 0.60  # issue 40: the wish at the ROV within this at p95
PICTURE_TARGET_S = 19.0  # issue 40: a 2000-byte picture while steering
STEERING_FROM_S = 2.0  # the bench's pilot starts here; before it the HELLO/SYNC
SMALLEST_POSE = 6  # six one-byte differences (§8.1)
WISH_BODY = 4  # a VELOCITY poll's four axes, without ARM/MODE (§8.1)
TURNAROUND_S = 0.002  # SimLink's, at each end: twice a cycle


def _varints_end(data: bytes, i: int, count: int) -> int:
    for _ in range(count):
        while data[i] & 0x80:
            i += 1
        i += 1
    return i


def cycle_bytes(polls: list[bytes], replies: list[bytes]) -> dict:
    """Mean bytes per steering cycle, by what they carry, from the frames as sent
    (version 2: `0x55 | LEN | contents`, the tag the contents' last bytes)."""
    from rovlink.link.radio.auth import TAG_BYTES
    from rovlink.link.radio.wire2 import (
        ANNEX_ALT,
        ANNEX_RECORD,
        DELTA_BIT,
        POSE_BYTES,
        REJECTED_BIT,
        V2_OVERHEAD,
        V2_REPLY_STATUS,
    )
    from rovlink.link.scene import record_length

    poll = {"framing": 0, "byte_0": 0, "request_and_order": 0, "count": 0, "tag": 0}
    wish_polls = 0
    for frame in polls:
        contents = frame[V2_OVERHEAD:]
        rest = len(contents) - 1 - 1 - TAG_BYTES
        poll["framing"] += V2_OVERHEAD
        poll["byte_0"] += 1
        poll["request_and_order"] += rest
        poll["count"] += 1
        poll["tag"] += TAG_BYTES
        wish_polls += rest >= WISH_BODY
    reply = {"framing": 0, "byte_0_and_status": 0, "pose": 0, "annex": 0, "trunk": 0, "tag": 0}
    for frame in replies:
        contents = frame[V2_OVERHEAD:]
        status = contents[1]
        i = V2_REPLY_STATUS
        i = _varints_end(contents, i, 6) if status & DELTA_BIT else i + POSE_BYTES
        pose_end = i
        if not status & REJECTED_BIT:
            i += bool(status & ANNEX_ALT)
            if status & ANNEX_RECORD:
                i += record_length(contents[i])
        reply["framing"] += V2_OVERHEAD
        reply["byte_0_and_status"] += V2_REPLY_STATUS
        reply["pose"] += pose_end - V2_REPLY_STATUS
        reply["annex"] += i - pose_end
        reply["trunk"] += len(contents) - i - TAG_BYTES
        reply["tag"] += TAG_BYTES
    n_polls, n_replies = max(1, len(polls)), max(1, len(replies))
    out = {"polls": len(polls), "replies": len(replies), "wish_poll_share": wish_polls / n_polls,
           "poll": {k: v / n_polls for k, v in poll.items()}, "reply": {k: v / n_replies for k, v in reply.items()}}
    out["poll_frame"] = sum(out["poll"].values())
    out["reply_frame"] = sum(out["reply"].values())
    out["cycle"] = out["poll_frame"] + out["reply_frame"]
    return out


def steering_floor(*, bitrate_bps: float = 1900.0, delay_s: float = 0.085, wish_poll_share: float = 0.5,
                   pose_bytes: float = SMALLEST_POSE, object_bytes: int = 2000,
                   wish_limit_s: float = WISH_LIMIT_S, cycle_cap: int | None = None) -> dict:
    """The least time a picture of `object_bytes` takes while steering, a pose of
    `pose_bytes` in every reply, the wish within `wish_limit_s` at p95, with cycles of
    `cycle_cap` bytes (None: the longest the wish limit allows).  The arithmetic, step
    by step, in the dict."""
    from rovlink.link.radio.auth import TAG_BYTES
    from rovlink.link.radio.wire2 import MIN_POLL_FRAME, V2_OVERHEAD, V2_REPLY_STATUS

    def air(nbytes: float) -> float:
        return 8.0 * nbytes / bitrate_bps

    fixed_s = 2 * delay_s + 2 * TURNAROUND_S  # a cycle's time beyond its bytes' air time
    wish_poll = MIN_POLL_FRAME + WISH_BODY
    # p95 of the wish's time to the ROV: 0.95 of a cycle waited, the poll's air time, one delay.
    longest_cycle_s = (wish_limit_s - air(wish_poll) - delay_s) / 0.95
    longest_cycle_bytes = math.floor((longest_cycle_s - fixed_s) * bitrate_bps / 8.0)
    cycle = longest_cycle_bytes if cycle_cap is None else cycle_cap
    cycle_s = air(cycle) + fixed_s
    poll_bytes = MIN_POLL_FRAME + WISH_BODY * wish_poll_share
    reply_overhead = V2_OVERHEAD + V2_REPLY_STATUS + pose_bytes + TAG_BYTES
    trunk = cycle - poll_bytes - reply_overhead
    cycles = math.ceil(object_bytes / trunk) if trunk > 0 else None
    seconds = cycles * cycle_s if cycles else None
    # What the pose may cost for the picture to come in PICTURE_TARGET_S at this cycle.
    target_cycles = math.floor(PICTURE_TARGET_S / cycle_s)
    pose_for_target = (cycle - poll_bytes - (reply_overhead - pose_bytes) - object_bytes / target_cycles
                       if target_cycles else None)
    return {
        "cycle_bytes": cycle, "cycle_s": cycle_s, "wish_p95_s": 0.95 * cycle_s + air(wish_poll) + delay_s,
        "longest_cycle_bytes_for_the_wish_limit": longest_cycle_bytes,
        "poll_bytes": poll_bytes, "reply_overhead_bytes": reply_overhead, "pose_bytes": pose_bytes,
        "trunk_bytes": trunk, "cycles": cycles, "picture_s": seconds,
        "pose_bytes_for_19s": pose_for_target,
    }


def measure_steering(duration_s: float = 900.0, seed: int = 2) -> dict:
    from rovlink.link.bench import OBJECT_BYTES, run_session
    from rovlink.link.radio.wire2 import V2_CYCLE, V2_OVERHEAD

    polls: list[bytes] = []
    replies: list[bytes] = []
    after_hello = [False]

    def tap(side: str, data: bytes, at: float) -> None:
        # A HELLO (15 bytes of contents; the bench's pilot sends no POSITION, the only
        # other poll that long) and the SYNC after it are no steering cycle.
        if side == "a":
            after_hello[0] = len(data) == V2_OVERHEAD + 15
            if at >= STEERING_FROM_S and not after_hello[0]:
                polls.append(bytes(data))
        elif at >= STEERING_FROM_S and not after_hello[0]:
            replies.append(bytes(data))

    session = run_session("rovlink v2", 7e-6, True, duration_s, seed, tap=tap)
    intervals = [b - a for a, b in zip(session.poll_times, session.poll_times[1:]) if a >= STEERING_FROM_S]
    spent = cycle_bytes(polls, replies)
    share = spent["wish_poll_share"]
    floors = {
        "today_cycle_smallest_pose": steering_floor(wish_poll_share=share, object_bytes=OBJECT_BYTES,
                                                    cycle_cap=V2_CYCLE[0]),
        "today_cycle_measured_pose": steering_floor(wish_poll_share=share, object_bytes=OBJECT_BYTES,
                                                    cycle_cap=V2_CYCLE[0], pose_bytes=spent["reply"]["pose"]),
        "longest_cycle_smallest_pose": steering_floor(wish_poll_share=share, object_bytes=OBJECT_BYTES),
        "longest_cycle_measured_pose": steering_floor(wish_poll_share=share, object_bytes=OBJECT_BYTES,
                                                      pose_bytes=spent["reply"]["pose"]),
    }
    return {
        "simulated_s": duration_s, "seed": seed, "object_bytes": OBJECT_BYTES, "size0_cycle_bytes": V2_CYCLE[0],
        "pictures": len(session.image_s),
        "steering_picture_s": median(session.image_s),
        "steering_picture_s_p95": quantile(session.image_s, 0.95),
        "wish_p95_s": quantile(session.wish_latency_s, 0.95),
        "wish_median_s": median(session.wish_latency_s),
        "poll_interval_s": median(intervals),
        "bytes_per_cycle": spent,
        "floor": floors,
    }


def steering_targets(result: dict) -> dict:
    floor = result["floor"]["longest_cycle_smallest_pose"]["picture_s"]
    picture, wish = result["steering_picture_s"], result["wish_p95_s"]
    return {
        "steering_picture_le_19s": {"value_s": picture, "limit_s": PICTURE_TARGET_S, "floor_s": floor,
                                    "met": picture is not None and picture <= PICTURE_TARGET_S},
        "wish_to_rov_p95_le_0.60s": {"value_s": wish, "limit_s": WISH_LIMIT_S,
                                     "met": wish is not None and wish <= WISH_LIMIT_S},
    }


def steering_lines(result: dict) -> list[str]:
    b = result["bytes_per_cycle"]
    p, r = b["poll"], b["reply"]
    lines = [
        f"steering (version 2, simulated {result['simulated_s']:g} s, seed {result['seed']}; 1900 bit/s, 85 ms, "
        f"BER 7e-6; a new wish every 0.5-1.5 s): a {result['object_bytes']}-byte picture in "
        f"{result['steering_picture_s']:.2f} s (median of {result['pictures']}, p95 "
        f"{result['steering_picture_s_p95']:.2f}); the wish at the ROV in {result['wish_p95_s']:.3f} s at p95; "
        f"a poll every {result['poll_interval_s']:.4f} s; SIZE 0's cycle {result['size0_cycle_bytes']} bytes",
        "",
        "where a cycle's bytes go (mean per poll and per reply, as sent):",
        format_table(["frame", "framing", "byte 0 (+status)", "request/wish or pose", "COUNT or annex", "trunk",
                      "tag", "frame"], [
            ["poll", p["framing"], p["byte_0"], p["request_and_order"], p["count"], 0.0, p["tag"], b["poll_frame"]],
            ["reply", r["framing"], r["byte_0_and_status"], r["pose"], r["annex"], r["trunk"], r["tag"],
             b["reply_frame"]],
        ]),
        f"a cycle: {b['cycle']:.1f} bytes, {r['trunk']:.1f} of them picture; polls carrying a new wish: "
        f"{b['wish_poll_share']:.0%}",
        "",
        "floor (what no version 2 with a pose in every reply and 4-byte tags can beat for this pilot):",
    ]
    rows = []
    for name, f in result["floor"].items():
        rows.append([name.replace("_", " "), f["cycle_bytes"], f["cycle_s"], f["wish_p95_s"], f["poll_bytes"],
                     f["reply_overhead_bytes"], f["trunk_bytes"], f["cycles"], f["picture_s"], f["pose_bytes_for_19s"]])
    lines.append(format_table(["case", "cycle B", "cycle s", "wish p95 s", "poll B", "reply B w/o trunk",
                               "trunk B", "cycles", "picture s", "pose B for 19 s"], rows))
    longest = result["floor"]["longest_cycle_smallest_pose"]
    lines.append(
        f"  the wish within {WISH_LIMIT_S:.2f} s at p95 caps a cycle at {longest['cycle_bytes']} bytes "
        f"({longest['cycle_s']:.3f} s: 0.95 x cycle + the wish poll's air time + 85 ms); with the smallest pose "
        f"({SMALLEST_POSE} bytes) a picture takes at least {longest['picture_s']:.2f} s; 19 s needs a pose of "
        f"{longest['pose_bytes_for_19s']:.1f} bytes or fewer at that cycle")
    return lines
