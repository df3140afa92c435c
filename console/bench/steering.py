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


def measure_steering_processes(minutes: float = 4.0, seed: int = 2) -> dict:
    """The same with real processes: `rovlink rov` (its simulated vehicle and camera,
    2000-byte pictures, no objects: their records are another cost, §11.1), `rovlink
    channel` (1900 bit/s, 85 ms, BER 7e-6, its log) and `rovlink console` (version 2),
    a pilot on the REST API changing the wish every 0.5-1.5 s.  A picture's time is the
    console's (its first trunk to its last, /api/images).  A wish's time to the ROV runs
    from its POST to the arrival at the ROV's end of the channel of the first poll that
    left after it carrying a wish (§8.1: a VELOCITY poll of 12 bytes or more; the polls
    repeating a wish are 8)."""
    import json
    import os
    import random
    import subprocess
    import sys
    import tempfile
    import time

    from rovlink.link.transports.transport import free_udp_port

    from .child import die_with_parent, end_child
    from .load import _request
    from .pilot import _free_port

    rng = random.Random(seed)
    workdir = tempfile.mkdtemp(prefix="rovlink-bench-steering-")
    key = os.path.join(workdir, "link.key")
    subprocess.run([sys.executable, "-m", "rovlink", "keygen", key], check=True, capture_output=True)
    console_udp, chan_a, chan_b, rov_udp = (free_udp_port() for _ in range(4))
    http, viser = _free_port(), _free_port()
    base = f"http://127.0.0.1:{http}"
    channel_log = os.path.join(workdir, "channel.jsonl")
    py = [sys.executable, "-m", "rovlink"]
    procs, logs = [], []

    def start(name: str, argv: list[str]) -> subprocess.Popen:
        log = open(os.path.join(workdir, f"{name}.log"), "w")
        logs.append(log)
        p = subprocess.Popen(argv, cwd=workdir, stdout=log, stderr=subprocess.STDOUT, preexec_fn=die_with_parent)
        procs.append(p)
        return p

    posts: list[float] = []
    try:
        start("rov", py + ["rov", "--key", key, "--no-objects", "--budget", "2000",
                           "--link", f"udp://127.0.0.1:{rov_udp}?peer=127.0.0.1:{chan_b}"])
        start("channel", py + ["channel", "--a", f"udp://127.0.0.1:{chan_a}?peer=127.0.0.1:{console_udp}",
                               "--b", f"udp://127.0.0.1:{chan_b}?peer=127.0.0.1:{rov_udp}", "--bitrate", "1900",
                               "--delay", "0.085", "--ber", "7e-6", "--seed", str(seed), "--quiet",
                               "--log", channel_log])
        console = start("console", py + ["console", "--key", key, "--no-record", "--port", str(http),
                                         "--viser-port", str(viser),
                                         "--link", f"udp://127.0.0.1:{console_udp}?peer=127.0.0.1:{chan_a}"])
        deadline = time.monotonic() + 300
        while True:
            try:
                if _request(base + "/api/state")["pose"]["received"] is not None:
                    break
            except (OSError, KeyError, TypeError, ValueError):
                pass
            if console.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("the console did not come up: "
                                   + open(os.path.join(workdir, "console.log")).read()[-2000:])
            time.sleep(0.5)
        client = _request(base + "/api/control/take", "POST", {"name": "bench"})["client_id"]
        _request(base + "/api/orders/velocity", "POST", {"vx": 0, "vy": 0, "vz": 0, "vyaw": 0}, client)
        time.sleep(3.0)  # the centred sticks reach the ROV (HOLD at start), pictures start
        started_wall, started = time.time(), time.monotonic()
        end = started + minutes * 60
        while time.monotonic() < end:
            wish = {axis: round(rng.uniform(-1, 1), 2) for axis in ("vx", "vy", "vz", "vyaw")}
            at = time.monotonic()
            _request(base + "/api/orders/velocity", "POST", wish, client)
            posts.append(at)
            time.sleep(rng.uniform(0.5, 1.5))
        ended_wall = time.time()
        images = _request(base + "/api/images")
    finally:
        for p in reversed(procs):
            end_child(p)
        for f in logs:
            f.close()
    collisions = 0
    wish_polls = []  # (left, arrived at the ROV's end)
    left: list[float] = []
    with open(channel_log) as f:
        for line in f:
            try:
                r = json.loads(line)
            except ValueError:
                continue
            collisions += r.get("ev") == "collision"
            if r.get("dir") != "a>b":
                continue
            if r.get("ev") == "tx":
                left.append(r["t"] if r["bytes"] >= 12 else -1.0)
            elif r.get("ev") == "rx" and left and left[-1] >= 0:
                wish_polls.append((left[-1], r["t"] + r.get("late_s", 0.0)))
                left[-1] = -1.0
    latencies = []
    for at in posts:
        arrival = next((got for went, got in wish_polls if went >= at), None)
        if arrival is not None:
            latencies.append(arrival - at)
    done = [i for i in images if not i["partial"] and i["seconds"] is not None
            and started_wall <= i["received_wall"] <= ended_wall]
    return {
        "minutes": minutes, "pictures": len(done),
        "picture_bytes_median": median([i["bytes"] for i in done]),
        "steering_picture_s": median([i["seconds"] for i in done]),
        "steering_picture_s_p95": quantile([i["seconds"] for i in done], 0.95),
        "wishes": len(posts), "wishes_seen": len(latencies),
        "wish_p95_s": quantile(latencies, 0.95), "wish_median_s": median(latencies),
        # Real time: what else the machine ran says how far these figures are the link's.
        "collisions": collisions, "load_average": os.getloadavg()[0], "cpus": os.cpu_count(),
    }
