"""`rovlink bench console`: the console's own costs.

- memory: a one-hour session on the emulated 1.9 kbit/s link, run in
  simulated time (the real Master, Slave, Channel and Operator, real DEBT
  images of the simulated camera, the pilot steering and sending orders all
  along, the session recorded to a file), with the Python heap measured by
  tracemalloc every five simulated minutes.  Flat means: the heap's peak in
  the second half is within `--flat-mb` of its peak in the first half.
- web load (unless `--no-load`): see console/bench/load.py: poll interval
  and lost replies of `rovlink demo` while 300 WebSocket readers and 5
  parallel 200 MB uploads hit its web server.
- steering (unless `--no-steering`): see console/bench/steering.py: a
  2000-byte picture's time while steering on version 2 and the wish's p95 to
  the ROV (JSON `steering_picture_s`, `wish_p95_s`), where each cycle's bytes
  go, and the floor a pose in every reply and the wish limit set.
- prediction (unless `--no-prediction`): see console/bench/prediction.py: the
  predicted pose's and the received pose's error against the vehicle model's
  truth by the pose's age, the pose's age while not steering, and the first
  wish after a pause at the ROV; on the clean link and under loss.
- page (unless `--no-page`): the real demo stack at 1.9 kbit/s, the web app and
  headless Chromium on the operator page: how often the page receives a new
  predicted pose, and how long a received trunk takes to show in the page
  (operator receipt to the page's handling of it, both on this machine's
  wall clock).  Needs Debian's chromium.
"""

from __future__ import annotations

import gc
import json
import random
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

from rovlink import debt
from rovlink.bench import emit, format_table
from rovlink.console.session.radio import Operator
from rovlink.link.emulators.channel import Channel, LinkParams
from rovlink.link.radio.master import Master
from rovlink.link.radio.sim import SimLink
from rovlink.link.radio.slave import Slave
from rovlink.rov.camera import SimulatedCamera


def _memory_session(duration_s: float, sample_every_s: float, seed: int) -> dict:
    camera = SimulatedCamera()
    rng = random.Random(seed)
    streams = {}

    def source(img, settings):
        key = (img, settings)
        if key not in streams:
            if len(streams) > 16:
                streams.clear()
            picture = camera.capture((rng.uniform(-5, 5), rng.uniform(-5, 5), 3.0, rng.uniform(-3, 3)))
            streams[key] = debt.encode(picture, settings.budget_bytes, roi=settings.roi,
                                       shift=settings.shift if settings.roi else 0, mono=settings.mono)
        return streams[key]

    master = Master(rng=random.Random(seed))
    slave = Slave(image_source=source)
    channel = Channel(LinkParams(bitrate_bps=1900, delay_s=0.085, ber=7e-6), seed=seed)
    sim: SimLink | None = None
    record = Path(tempfile.mkdtemp(prefix="rovlink-bench-")) / "session.jsonl"
    operator = Operator(None, master=master, clock=lambda: sim.now if sim else 0.0, record=record)
    operator.set_pilot_in_force(True)  # the random pilot below holds control

    def on_master(event, now):
        operator.handle_events([event], now)

    sim = SimLink(master, slave, channel, on_master_event=on_master)
    # The operator's loop records the bytes received; the simulated link does the
    # same through this tap (what was sent comes with the master's events).
    receive_bytes = master.receive_bytes

    def tapped_receive(data, now):
        operator.bytes_received(data, now)
        return receive_bytes(data, now)

    master.receive_bytes = tapped_receive  # type: ignore[method-assign]

    def pilot(now):
        if rng.random() < 0.6:
            operator.set_velocity(*(round(rng.uniform(-1, 1), 2) for _ in range(4)))
        else:
            operator.set_velocity(0, 0, 0, 0)
        sim.at(now + rng.uniform(0.5, 3.0), pilot)

    def orders(now):
        choice = rng.random()
        if choice < 0.4:
            operator.send_position(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(1, 6), rng.uniform(-180, 180))
        elif choice < 0.8:
            x0, y0 = rng.randrange(0, 200), rng.randrange(0, 150)
            operator.set_image_settings(roi=(x0, y0, x0 + 100, y0 + 80), shift=rng.randrange(0, 8),
                                        budget_bytes=rng.choice((1000, 2000, 3000)))
        else:
            operator.stop()
        operator.state()  # what the web page and the scene ask for, all the time
        operator.preview_path(1.0, 1.0, 2.0)
        sim.at(now + 60.0, orders)

    sim.at(0.0, pilot)
    sim.at(5.0, orders)
    # tracemalloc starts and stops only while no other thread runs DEBT.  Its
    # compiled kernels allocate through PyMem_RawMalloc (numba's runtime) with
    # the GIL released, and Python 3.11's tracemalloc.stop() races such
    # allocations (CPython gh-128679, fixed in 3.12.9 and 3.13.2): this
    # benchmark died with SIGSEGV about one run in fifteen while the console's
    # decode thread or DEBT's warm-up ran.  Between the two, the simulation
    # (this thread) is all that hands the decoder work.
    if not operator.wait_debt_idle():
        raise RuntimeError("DEBT's warm-up or a decode did not finish within 300 s")
    gc.collect()
    tracemalloc.start()
    samples = []
    wall0 = time.perf_counter()
    t = 0.0
    while t < duration_s:
        t = min(duration_s, t + sample_every_s)
        sim.run_until(t)
        operator.predicted_pose()
        gc.collect()
        current, _ = tracemalloc.get_traced_memory()
        samples.append((t, current / 2**20))
    wall = time.perf_counter() - wall0
    if not operator.wait_debt_idle():
        raise RuntimeError("a decode did not finish within 300 s")
    tracemalloc.stop()
    operator.close()
    size = record.stat().st_size
    record.unlink()
    return {
        "simulated_s": duration_s,
        "wall_s": wall,
        "samples_mb": [{"t_s": t, "heap_mb": round(mb, 3)} for t, mb in samples],
        "polls": master.stats.polls_sent,
        "images_completed": master.stats.images_completed,
        "recording_bytes": size,
    }


def run(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    mem = _memory_session(args.duration, args.sample_every, args.seed)
    samples = mem["samples_mb"]
    # The heap swings by a few MB with the image being decoded; a leak shows
    # as peaks that keep rising, so compare the peak of the second half with
    # the peak of the first (after a warm-up of a sixth of the session).
    half = args.duration / 2
    early = [s["heap_mb"] for s in samples if args.duration / 6 <= s["t_s"] <= half] or [samples[0]["heap_mb"]]
    late = [s["heap_mb"] for s in samples if s["t_s"] > half] or [samples[-1]["heap_mb"]]
    growth = max(late) - max(early)
    doc = {"memory": mem, "targets": {
        "memory_flat_over_one_hour": {"peak_first_half_mb": max(early), "peak_second_half_mb": max(late),
                                      "growth_mb": growth, "limit_mb": args.flat_mb,
                                      # The histories fill to their caps in the first half hour; a
                                      # shorter session says nothing about an hour.
                                      "met": (growth <= args.flat_mb) if args.duration >= 3600 else None},
    }}
    lines = [
        f"rovlink bench console: {args.duration / 60:g}-minute session at 1900 bit/s, 85 ms, BER 7e-6, in simulated "
        f"time ({mem['wall_s']:.1f} s of wall time); {mem['polls']} polls, {mem['images_completed']} images, "
        f"recording {mem['recording_bytes'] / 1e6:.2f} MB on disk",
        "",
        format_table(["minute", "Python heap MB"], [[round(s["t_s"] / 60, 1), s["heap_mb"]] for s in samples]),
    ]
    if not args.no_steering:
        from .steering import measure_steering, steering_lines, steering_targets

        steering = measure_steering(args.steering_seconds, args.seed + 2)
        doc["steering"] = steering
        # Issue 40's two figures, at the document's top.
        doc["steering_picture_s"] = steering["steering_picture_s"]
        doc["wish_p95_s"] = steering["wish_p95_s"]
        doc["targets"].update(steering_targets(steering))
        lines += ["", *steering_lines(steering)]
        if args.steering_processes_minutes > 0:
            from .steering import measure_steering_processes

            real = measure_steering_processes(args.steering_processes_minutes, args.seed + 2)
            doc["steering_processes"] = real
            lines += [f"with real processes (rov, channel, console; {real['minutes']:g} min, load average "
                      f"{real['load_average']:.1f} on {real['cpus']} CPUs): {real['pictures']} pictures of "
                      f"{real['picture_bytes_median']} bytes in {real['steering_picture_s']} s (median, first trunk "
                      f"to last); the wish at the ROV in {real['wish_p95_s']} s at p95 ({real['wishes_seen']} of "
                      f"{real['wishes']} wishes seen); frames that collided on the half-duplex channel: "
                      f"{real['collisions']}"]
    if not args.no_prediction:
        from .prediction import measure_prediction, prediction_lines, prediction_targets

        clean = measure_prediction(args.prediction_minutes * 60, args.seed)
        lossy = measure_prediction(args.prediction_minutes * 60, args.seed, ber=args.prediction_lossy_ber)
        doc["prediction"] = {"clean": clean, "lossy": lossy}
        doc["targets"].update(prediction_targets(clean, lossy))
        lines += ["", *prediction_lines(clean), "", *prediction_lines(lossy)[:2]]
    import os

    from rovlink.console.bench.page import CHROMIUM

    if not args.no_page and not os.path.exists(CHROMIUM):
        lines += ["", f"page: not measured: no Chromium at {CHROMIUM} (Debian package 'chromium')"]
    elif not args.no_page:
        page = _page_latency(args.page_seconds)
        doc["page"] = page
        doc["targets"]["predicted_pose_updates_ge_20hz"] = {"value_hz": page["pose_updates_hz"], "limit_hz": 20.0,
                                                            "met": page["pose_updates_hz"] >= 20.0}
        doc["targets"]["trunk_shown_within_100ms"] = {
            "median_ms": page["trunk_latency_ms_median"], "max_ms": page["trunk_latency_ms_max"], "limit_ms": 100.0,
            "met": page["trunk_latency_ms_max"] is not None and page["trunk_latency_ms_max"] <= 100.0}
        lines += ["", format_table(["page measure", "value"], [
            ["predicted pose updates /s", page["pose_updates_hz"]],
            ["trunks observed", page["trunks"]],
            ["trunk -> page ms, median", page["trunk_latency_ms_median"]],
            ["trunk -> page ms, max", page["trunk_latency_ms_max"]],
        ])]
    if not args.no_pilot and os.path.exists(CHROMIUM):
        from .pilot import measure_pilot, pilot_lines, pilot_target

        pilot = measure_pilot(args.pilot_minutes)
        doc["pilot"] = pilot
        doc["targets"]["no_link_lost_or_failsafe_with_a_pilot_on_the_page"] = pilot_target(pilot)
        lines += ["", *pilot_lines(pilot)]
    if not args.no_loaded and os.path.exists(CHROMIUM):
        from .loaded import loaded_lines, loaded_target, measure_loaded

        rows = [measure_loaded(args.loaded_minutes, burners=args.loaded_burners,
                               channel_nice=args.loaded_channel_nice)]
        # The first row printed at once: the comparison takes as long again.
        print(json.dumps({"loaded_row": rows[0]}), file=sys.stderr, flush=True)
        if args.loaded_compare:
            rows.append(measure_loaded(args.loaded_minutes, link_thread=True, burners=args.loaded_burners,
                                       channel_nice=args.loaded_channel_nice))
        doc["loaded"] = rows
        doc["targets"]["link_in_time_on_a_busy_machine"] = loaded_target(rows[0])
        lines += ["", *loaded_lines(rows)]
    if not args.no_load:
        from .load import measure_load

        load = measure_load(args.load_seconds, args.readers, args.uploads, args.load_ber)
        doc["load"] = load
        doc["targets"]["poll_interval_p95_under_load_lt_0.6s"] = {
            "p95_s": load["load"]["p95_s"], "limit_s": 0.6,
            "met": load["load"]["p95_s"] is not None and load["load"]["p95_s"] < 0.6}
        doc["targets"]["no_reply_lost_but_by_the_channel"] = {
            "replies_lost": load["replies_lost"], "channel_lost": load["channel_lost_total"],
            "met": load["replies_lost_not_by_channel"] == 0}
        ws, up = load["websocket"], load["uploads_result"]
        lines += ["", f"web load: demo at 1900 bit/s, BER {args.load_ber:g}, steering; {args.load_seconds:g} s "
                      f"without and {args.load_seconds:g} s with {args.readers} WebSocket readers and "
                      f"{args.uploads} parallel 200 MB uploads",
                  format_table(["phase", "polls", "interval median s", "p95 s", "max s"], [
                      [name, load[name]["polls"], load[name]["median_s"], load[name]["p95_s"], load[name]["max_s"]]
                      for name in ("idle", "load")]),
                  f"replies lost {load['replies_lost']}, frames the channel lost {load['channel_lost_total']} "
                  f"({', '.join(f'{k} {v}' for k, v in sorted(load['channel_losses'].items())) or 'none'}); "
                  f"WebSocket telemetry messages {ws['messages']}, refusals past the cap {ws['refused']}; "
                  f"uploads started {up['attempts']}: answered "
                  + (", ".join(f"{k[7:]} x{v}" for k, v in sorted(up.items()) if k.startswith("status_")) or "never")
                  + f", connection reset by the server x{up['reset']}"]
    lines += ["", "targets:"]
    for name, t in doc["targets"].items():
        verdict = "NOT JUDGED (too short to say)" if t["met"] is None else ("MET " if t["met"] else "MISSED")
        lines.append(f"  {verdict} {name}: "
                     + ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in t.items()
                                 if k != "met"))
    emit(doc, "\n".join(lines), args.json)
    return 0


def _page_latency(seconds: float) -> dict:
    from rovlink.console.bench.page import measure_page

    return measure_page(seconds)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("console", help="console memory over a one-hour session, page update rate and latency",
                              description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--duration", type=float, default=3600.0, metavar="S", help="simulated session seconds (3600)")
    p.add_argument("--sample-every", type=float, default=300.0, metavar="S", help="heap sample period (300)")
    p.add_argument("--flat-mb", type=float, default=2.0, metavar="MB",
                   help="largest rise of the heap peak from the first half to the second that counts as flat (2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-steering", action="store_true",
                   help="skip pictures while steering and where a cycle's bytes go (version 2, simulated time)")
    p.add_argument("--steering-seconds", type=float, default=900.0, metavar="S",
                   help="simulated seconds of the steering session (900)")
    p.add_argument("--steering-processes-minutes", type=float, default=0.0, metavar="MIN",
                   help="also steer with real processes (rovlink rov, channel and console) for MIN minutes "
                        "(0: not; real time, so meaningful only on a machine with a core to spare)")
    p.add_argument("--no-prediction", action="store_true",
                   help="skip the prediction and reaction measurement (simulated time, a few seconds)")
    p.add_argument("--prediction-minutes", type=float, default=10.0, metavar="MIN",
                   help="simulated minutes of the prediction session (10)")
    p.add_argument("--prediction-lossy-ber", type=float, default=3e-4, metavar="BER",
                   help="bit error rate of the second prediction session, which fills the older ages (3e-4)")
    p.add_argument("--no-page", action="store_true",
                   help="skip the operator page measurement (headless Chromium, about a minute)")
    p.add_argument("--page-seconds", type=float, default=40.0, metavar="S", help="page measurement time (40)")
    p.add_argument("--no-pilot", action="store_true",
                   help="skip the pilot on the demo's page (rovlink demo and headless Chromium, --pilot-minutes)")
    p.add_argument("--pilot-minutes", type=float, default=10.0, metavar="MIN",
                   help="minutes of the pilot on the demo's page; the target is judged from 10 (10)")
    p.add_argument("--no-loaded", action="store_true",
                   help="skip the busy machine's row (two CPU-bound processes and Chromium beside the console)")
    p.add_argument("--loaded-minutes", type=float, default=10.0, metavar="MIN",
                   help="minutes of the busy machine's row (10)")
    p.add_argument("--loaded-burners", type=int, default=2, metavar="N",
                   help="CPU-bound processes beside the console in the busy machine's row (2; the target is judged "
                        "with 2 or more)")
    p.add_argument("--loaded-channel-nice", type=int, default=0, metavar="N",
                   help="nice of the channel emulator in the busy machine's row (0; an outside run set it above "
                        "the vehicle side's, -5)")
    p.add_argument("--loaded-compare", action="store_true",
                   help="the busy machine's row also with the link in a thread of the console (as before issue 33)")
    p.add_argument("--no-load", action="store_true",
                   help="skip the web load measurement (rovlink demo under WebSocket readers and large uploads)")
    p.add_argument("--load-seconds", type=float, default=30.0, metavar="S", help="seconds per load phase (30)")
    p.add_argument("--readers", type=int, default=300, metavar="N", help="WebSocket readers under load (300)")
    p.add_argument("--uploads", type=int, default=5, metavar="N", help="parallel 200 MB uploads under load (5)")
    p.add_argument("--load-ber", type=float, default=7e-6, metavar="BER", help="channel bit error rate (7e-6)")
    p.set_defaults(func=run)
