"""`rovlink bench roi`: the ROI that follows its object (issue 34, docs/PROTOCOL.md §10),
against the truth of the simulated seabed.

The simulated vehicle is driven past an object on the seabed (the ladder by default),
then round it, turning to and fro, then away until it leaves the picture; its camera
runs at `camera_hz` and the ROV's follower (rov/follow.py) tracks the object in every
frame.  The pictures cross the published link (1900 bit/s, 85 ms, BER 7e-6) with the
real master, slave and channel in simulated time (link/radio/sim.py), version 2 by default:
the pilot drew the ROI round the object in the first picture and set it to follow.

Per picture the operator received: the IoU of the ROI it was coded with (its DEBT
header's) with the object's true box (`SimulatedCamera.object_box` at the capture's
pose); the PSNR inside the true box of that picture, of the same frame coded with the
first ROI left where it was drawn (fixed), and with no ROI, all three at the same DEBT
bytes; the track's state as the picture says it.  Figures: `iou_half_fraction` (the
pictures with the object in view whose ROI has IoU >= 0.5), `gain_over_fixed_db`
(follow minus fixed, averaged over the pictures with the object in view),
`lost_said_after_pictures` (pictures from the first without the object in view to the
first that says the track is lost: 0 is the same picture), `tracker_ms` (mean per
frame on this machine; a Raspberry Pi 4 estimate beside it).  Beside the run, every
tracker of rov/follow.py on the same camera frames: its IoU and its cost.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field

from rovlink.command import positive, positive_int

BITRATE = 1900.0
DELAY_S = 0.085
BER = 7e-6
TARGET_IOU_FRACTION = 0.9
TARGET_GAIN_DB = 3.0
TARGET_LOST_PICTURES = 1
TARGET_TRACKER_MS = 10.0
MIN_PICTURES = 30
# A Raspberry Pi 4's Cortex-A72 at 1.5 GHz against one core of this machine, for
# OpenCV's optical flow and warps: an estimate (about 5x, from single-core benchmark
# ratios of the two classes of CPU), not a measurement on a Pi.
PI4_FACTOR = 5.0
STANDOFF_M = 4.3  # the object this far ahead on the seabed lies at the picture's centre (camera tilted 35 deg, 3 m up)
HEIGHT_M = 3.0


def drive(obj, u: float) -> tuple[float, float, float, float]:
    """The vehicle's pose (x, y, z, yaw) at a fraction `u` of the run: past the object
    (it crosses the picture from right to left), round it by 60 deg turning to and fro,
    then turning away until it leaves the picture."""
    z = obj_depth(obj) - HEIGHT_M
    ox, oy = obj.x_m, obj.y_m
    if u < 0.35:
        a = u / 0.35
        return (ox - STANDOFF_M, oy - 2.5 + 5.0 * a, z, 0.0)
    if u < 0.8:
        a = (u - 0.35) / 0.45
        beta = math.radians(60) * a
        sway = math.radians(18) * math.sin(2 * math.pi * a)
        return (ox - STANDOFF_M * math.cos(beta), oy + 2.5 * (1 - a) - STANDOFF_M * math.sin(beta), z, beta + sway)
    a = min((u - 0.8) / 0.08, 1.0)
    beta = math.radians(60)
    return (ox - STANDOFF_M * math.cos(beta), oy - STANDOFF_M * math.sin(beta), z, beta + math.radians(100) * a)


def obj_depth(obj) -> float:
    from rovlink.rov.seabed import SEABED_DEPTH_M

    return SEABED_DEPTH_M


@dataclass
class Capture:
    img: int
    at: float
    pose: tuple
    frame: object
    roi: tuple | None  # the ROI the picture was coded with
    record: object  # its TRACK record


@dataclass
class Picture:
    img: int
    captured_at: float
    received_at: float
    debt_bytes: int
    state: str
    lost_for_s: float
    in_view: bool
    visible: float
    iou: float | None
    psnr_follow: float | None
    psnr_fixed: float | None
    psnr_none: float | None
    centre_x: float | None


@dataclass
class Run:
    pictures: list[Picture] = field(default_factory=list)
    trackers: dict = field(default_factory=dict)
    tracker_ms: float = 0.0
    tracker_worst_ms: float = 0.0
    frames: int = 0
    first_roi: tuple | None = None


def _psnr_in(box, reference, picture) -> float | None:
    import numpy as np

    if box is None:
        return None
    x0, y0 = max(int(math.floor(box[0])), 0), max(int(math.floor(box[1])), 0)
    x1, y1 = int(math.ceil(box[2])), int(math.ceil(box[3]))
    a = reference[y0:y1, x0:x1].astype(np.float64)
    b = picture[y0:y1, x0:x1].astype(np.float64)
    if a.size == 0:
        return None
    mse = float(np.mean((a - b) ** 2))
    return 99.0 if mse == 0 else 10 * math.log10(255.0**2 / mse)


def measure(*, seconds: float = 170.0, budget: int = 900, shift: int = 6, tracker: str = "klt", camera_hz: float = 10.0,
            kind: str = "ladder", seed: int = 1, version2: bool = True, compare: tuple = ("klt", "ncc", "csrt", "kcf"),
            progress=None) -> Run:
    from rovlink import debt
    from rovlink.debt.codec import _as_image
    from rovlink.link.emulators.channel import Channel, LinkParams
    from rovlink.link.radio.master import ImageComplete, Master
    from rovlink.link.radio.messages import FollowSettings, ImageSettings, TrackState, split_track
    from rovlink.link.radio.sim import SimLink
    from rovlink.link.radio.slave import OrderExecuted, Slave, status_from_pose
    from rovlink.rov.camera import SimulatedCamera, iou
    from rovlink.rov.follow import RoiFollower, make_tracker
    from rovlink.rov.seabed import Seabed

    seabed = Seabed.load()
    obj = next(o for o in seabed.objects if o.kind == kind)
    camera = SimulatedCamera(seabed=seabed)
    follower = RoiFollower(tracker)
    run = Run()
    first_pose = drive(obj, 0.0)
    first_frame = camera.capture(first_pose)
    first_box = camera.object_box(first_pose, obj).clipped
    run.first_roi = tuple(int(round(v)) for v in first_box)
    others = {}
    for name in compare:  # every tracker on the same frames, started where the pilot drew the ROI
        others[name] = {"tracker": make_tracker(name), "frames": 0, "seconds": 0.0, "in_view": 0, "half": 0, "lost": 0,
                        "shrink": None, "scale": 1.0}
    if "klt" in compare:
        # The acoustic ROV's tracker (rov/acoustic.py): the same frames, grey, as it keeps them.
        from .acoustic import FOLLOW_SIZE, follow_frame

        others[ACOUSTIC_ROW] = {"tracker": make_tracker("klt"), "frames": 0, "seconds": 0.0, "in_view": 0, "half": 0,
                                "lost": 0, "shrink": follow_frame,
                                "scale": FOLLOW_SIZE[0] / camera.width}
    for entry in others.values():
        frame = entry["shrink"](first_frame) if entry["shrink"] else first_frame
        entry["tracker"].init(frame, tuple(int(round(v * entry["scale"])) for v in run.first_roi))

    state = {"frame": first_frame, "at": 0.0, "pose": first_pose, "kept": [(0.0, first_frame)]}
    captures: dict[int, Capture] = {}
    master = Master(bitrate_bps=BITRATE, delay_s=DELAY_S, rng=random.Random(seed))
    mono = True

    def image_source(img: int, settings) -> bytes:
        frame, at, pose = state["frame"], state["at"], state["pose"]
        record = b""
        roi, track = settings.roi, None
        if settings.follow and follower.active:
            roi, track = follower.picture(at)
            record = track.encode()
        grey = _as_image(frame, mono)[0]
        stream = debt.encode(grey, settings.budget_bytes - len(record), roi=roi, shift=shift if roi else 0, mono=mono)
        captures[img] = Capture(img, at, pose, grey, roi, track)
        return record + stream

    slave = Slave(image_source=image_source, default_settings=ImageSettings(mono=True, budget_bytes=budget))
    slave.follows = True
    master_end, slave_end = master, slave
    if version2:
        from rovlink.link.radio.secure import SecureMaster, SecureSlave

        key = random.Random(seed).randbytes(32)
        master_end, slave_end = SecureMaster(master, key), SecureSlave(slave, key)
    channel = Channel(LinkParams(bitrate_bps=BITRATE, delay_s=DELAY_S, ber=BER), seed=seed)
    received: list[tuple[float, bytes, Capture | None]] = []

    def on_master(event, now):
        if isinstance(event, ImageComplete):  # of the ROV's newest capture under this IMG (IMGs wrap)
            received.append((now, event.data, captures.get(event.img)))

    def on_slave(event, now):
        if isinstance(event, OrderExecuted) and getattr(event.order, "follow", False):
            # The ROV starts on the frame the ROI was drawn on and catches up (rov/node.py does the same).
            kept = state["kept"]
            follower.start(kept[0][1], event.order.roi, event.order.keep, kept[0][0])
            for at, frame in kept[1:]:
                follower.frame(frame, at)
            state["kept"] = None

    sim = SimLink(master_end, slave_end, channel, on_master_event=on_master, on_slave_event=on_slave)
    period = 1.0 / camera_hz
    steps = int(seconds * camera_hz)

    def camera_frame(now: float) -> None:
        pose = drive(obj, min(now / seconds, 1.0))
        frame = camera.capture(pose)
        state.update(frame=frame, at=now, pose=pose)
        if state["kept"] is not None:
            state["kept"].append((now, frame))
        else:
            follower.frame(frame, now)
        truth = camera.object_box(pose, obj)
        for entry in others.values():
            seen = entry["shrink"](frame) if entry["shrink"] else frame
            t0 = time.perf_counter()
            box = entry["tracker"].update(seen)
            entry["seconds"] += time.perf_counter() - t0
            entry["frames"] += 1
            if truth.in_view:
                entry["in_view"] += 1
                entry["half"] += iou(box, tuple(v * entry["scale"] for v in truth.clipped)) >= 0.5
            entry["lost"] += box is None
        x, y, z, yaw = pose
        slave.update_status(status_from_pose(x_m=x, y_m=y, z_m=z, roll_deg=0.0, pitch_deg=0.0, yaw_deg=math.degrees(yaw),
                                             armed=True, mode=1, autopilot=True, position_valid=True, attitude_valid=True))
        step = int(round(now * camera_hz)) + 1
        if progress and step % int(10 * camera_hz) == 0:
            progress(now, seconds, len(received))
        if step <= steps:
            sim.at(step * period, camera_frame)

    sim.at(0.0, camera_frame)
    # The pilot drew the ROI round the object on the first picture (IMG 0) and set it to follow.
    master.send_order(FollowSettings(run.first_roi, shift, mono, budget, keep=True, drawn_on=0))
    sim.run_until(seconds)

    for now, data, capture in received:
        if capture is None or capture.record is None:
            continue  # captured before the FOLLOW was taken
        track, stream = split_track(data)
        truth = camera.object_box(capture.pose, obj)
        coded_roi = debt.unpack_header(stream).roi
        picture = debt.decode(stream)
        box = truth.clipped if truth.in_view else None
        fixed = debt.decode(debt.encode(capture.frame, len(stream), roi=run.first_roi, shift=shift, mono=mono))
        plain = debt.decode(debt.encode(capture.frame, len(stream), mono=mono))
        run.pictures.append(Picture(
            img=capture.img, captured_at=capture.at, received_at=now, debt_bytes=len(stream),
            state=TrackState(track.state).name if track is not None else "none",
            lost_for_s=track.lost_for_s if track is not None else 0.0,
            in_view=truth.in_view, visible=truth.visible_fraction,
            iou=iou(coded_roi, truth.clipped) if truth.in_view else None,
            psnr_follow=_psnr_in(box, capture.frame, picture), psnr_fixed=_psnr_in(box, capture.frame, fixed),
            psnr_none=_psnr_in(box, capture.frame, plain),
            centre_x=(truth.clipped[0] + truth.clipped[2]) / 2 if truth.in_view else None,
        ))
    run.frames = follower.stats.frames
    run.tracker_ms = follower.stats.mean_ms
    run.tracker_worst_ms = 1000.0 * follower.stats.worst_s
    for name, entry in others.items():
        run.trackers[name] = {
            "ms_per_frame": 1000.0 * entry["seconds"] / max(entry["frames"], 1),
            "iou_half_fraction_frames": entry["half"] / max(entry["in_view"], 1),
            "frames_lost": entry["lost"],
            "frames": entry["frames"],
        }
    return run


ACOUSTIC_ROW = "klt, acoustic (grey)"


def figures(run: Run, width: int = 320) -> dict:
    pics = run.pictures
    in_view = [p for p in pics if p.in_view]
    half = [p for p in in_view if p.iou is not None and p.iou >= 0.5]
    gains = [p.psnr_follow - p.psnr_fixed for p in in_view if p.psnr_follow is not None and p.psnr_fixed is not None]
    lost_after = None
    first_out = next((i for i, p in enumerate(pics) if not p.in_view and any(q.in_view for q in pics[:i])), None)
    if first_out is not None:
        said = next((i for i, p in enumerate(pics) if i >= first_out and p.state in ("LOST", "DROPPED")), None)
        lost_after = None if said is None else said - first_out
    xs = [p.centre_x for p in in_view if p.centre_x is not None]
    arrivals = [p.received_at for p in pics]
    return {
        "pictures": len(pics),
        "debt_bytes_mean": sum(p.debt_bytes for p in pics) / len(pics) if pics else 0.0,
        "picture_interval_s": (arrivals[-1] - arrivals[0]) / (len(arrivals) - 1) if len(arrivals) > 1 else 0.0,
        "pictures_in_view": len(in_view),
        "crossed_fraction": (max(xs) - min(xs)) / width if xs else 0.0,
        "iou_half_fraction": len(half) / len(in_view) if in_view else 0.0,
        "gain_over_fixed_db": sum(gains) / len(gains) if gains else 0.0,
        "gain_over_none_db": (sum(p.psnr_follow - p.psnr_none for p in in_view if p.psnr_follow and p.psnr_none)
                              / max(len(in_view), 1)),
        "lost_said_after_pictures": lost_after,
        "tracker_ms": run.tracker_ms,
        "tracker_worst_ms": run.tracker_worst_ms,
        "tracker_ms_pi4_estimate": run.tracker_ms * PI4_FACTOR,
    }


def targets(fig: dict) -> dict:
    def target(value, limit, met):
        return {"value": value, "limit": limit, "met": bool(met)}

    lost = fig["lost_said_after_pictures"]
    return {
        "iou_half_fraction": target(fig["iou_half_fraction"], TARGET_IOU_FRACTION, fig["iou_half_fraction"] >= TARGET_IOU_FRACTION),
        "gain_over_fixed_db": target(fig["gain_over_fixed_db"], TARGET_GAIN_DB, fig["gain_over_fixed_db"] >= TARGET_GAIN_DB),
        "lost_said_after_pictures": target(lost, TARGET_LOST_PICTURES, lost is not None and lost <= TARGET_LOST_PICTURES),
        "tracker_ms": target(fig["tracker_ms"], TARGET_TRACKER_MS, fig["tracker_ms"] <= TARGET_TRACKER_MS),
        "pictures": target(fig["pictures"], MIN_PICTURES, fig["pictures"] >= MIN_PICTURES),
        "crossed_fraction": target(fig["crossed_fraction"], 0.5, fig["crossed_fraction"] >= 0.5),
    }


def why_missed(fig: dict, run: Run) -> list[str]:
    """For each target missed, the arithmetic that shows why."""
    lines = []
    pics = [p for p in run.pictures if p.in_view]
    if fig["iou_half_fraction"] < TARGET_IOU_FRACTION and pics:
        low = [p for p in pics if p.iou is None or p.iou < 0.5]
        lines.append(f"IoU: {len(pics) - len(low)} of {len(pics)} pictures in view at 0.5 or more "
                     f"= {fig['iou_half_fraction']:.2f}; below: " + ", ".join(
                         f"IMG {p.img} at {p.captured_at:.0f} s ({p.state}, IoU {p.iou or 0:.2f})" for p in low[:6]))
    if fig["gain_over_fixed_db"] < TARGET_GAIN_DB and pics:
        overlapping = [p for p in pics if p.psnr_fixed is not None and p.psnr_follow is not None
                       and p.psnr_follow - p.psnr_fixed < 1.0]
        lines.append(f"gain: the fixed ROI still covers the object in {len(overlapping)} of {len(pics)} pictures "
                     f"(gain under 1 dB there); the mean {fig['gain_over_fixed_db']:.2f} dB "
                     f"= sum of gains / {len(pics)} pictures")
    if fig["lost_said_after_pictures"] is None:
        lines.append("lost: the object never left the view after being in it, or no picture said it lost")
    elif fig["lost_said_after_pictures"] > TARGET_LOST_PICTURES:
        lines.append(f"lost: said {fig['lost_said_after_pictures']} pictures after the object left the view")
    if fig["tracker_ms"] > TARGET_TRACKER_MS:
        lines.append(f"tracker: {fig['tracker_ms']:.1f} ms a frame over {run.frames} frames, above {TARGET_TRACKER_MS:g} ms")
    if fig["pictures"] < MIN_PICTURES:
        lines.append(f"pictures: {fig['pictures']} in the run (a longer --seconds brings {MIN_PICTURES})")
    return lines


def render(result: dict) -> str:
    from rovlink.bench import format_table

    rows = [(p["img"], round(p["captured_at"], 1), p["state"], p["lost_for_s"], round(p["visible"], 2), p["iou"],
             p["psnr_follow"], p["psnr_fixed"], p["psnr_none"], p["debt_bytes"]) for p in result["per_picture"]]
    table = format_table(("IMG", "captured s", "track", "lost for s", "in view", "IoU", "PSNR follow", "PSNR fixed",
                          "PSNR none", "DEBT B"), rows)
    fig, tgt = result["figures"], result["targets"]
    lines = [f"bench roi: the {result['object']} followed over {result['link']}, {result['seconds']:g} s, "
             f"{fig['pictures']} pictures ({fig['pictures_in_view']} with the object in view; it crossed "
             f"{100 * fig['crossed_fraction']:.0f} % of the picture's width)", "", table, ""]
    trackers = [(name, t["ms_per_frame"], t["iou_half_fraction_frames"], t["frames_lost"], t["frames"])
                for name, t in result["trackers"].items()]
    if trackers:
        from rovlink.bench import format_table as ft

        lines += ["trackers on the same camera frames (IoU >= 0.5 over frames with the object in view):",
                  ft(("tracker", "ms/frame", "IoU>=0.5", "frames lost", "frames"), trackers), ""]
    for name, t in tgt.items():
        value = t["value"]
        shown = "-" if value is None else (f"{value:.3g}" if isinstance(value, float) else str(value))
        lines.append(f"{name:26s} {shown:>8s}  target {'<=' if name in ('lost_said_after_pictures', 'tracker_ms') else '>='} "
                     f"{t['limit']:g}  {'met' if t['met'] else 'MISSED'}")
    lines.append(f"tracker on a Raspberry Pi 4 (estimate, x{PI4_FACTOR:g}): {fig['tracker_ms_pi4_estimate']:.1f} ms a frame "
                 f"(worst here {fig['tracker_worst_ms']:.1f} ms)")
    lines += result["why"]
    if result.get("plot"):
        lines.append(f"plot: {result['plot']}")
    return "\n".join(lines)


def plot(run: Run, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pics = run.pictures
    n = list(range(len(pics)))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, p in enumerate(pics):
        if not p.in_view:
            for ax in (top, bottom):
                ax.axvspan(i - 0.5, i + 0.5, color="0.85", lw=0)
    top.plot(n, [p.iou if p.iou is not None else float("nan") for p in pics], "o-", label="IoU of the followed ROI")
    top.axhline(0.5, color="0.4", ls="--", lw=1)
    top.set_ylim(0, 1)
    top.set_ylabel("IoU with the true box")
    top.legend(loc="lower left")
    for key, label in (("psnr_follow", "follow"), ("psnr_fixed", "fixed ROI"), ("psnr_none", "no ROI")):
        bottom.plot(n, [getattr(p, key) if getattr(p, key) is not None else float("nan") for p in pics], "o-", label=label)
    bottom.set_ylabel("PSNR inside the true box (dB)")
    bottom.set_xlabel("picture (grey: the object out of view)")
    bottom.legend(loc="lower left")
    fig.suptitle("rovlink bench roi")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "roi",
        help="the ROI that follows its object, over the published link, against the seabed's truth",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--out", metavar="PNG", help="write the plot of IoU and in-box PSNR per picture here")
    p.add_argument("--seconds", type=positive, default=170.0, metavar="S", help="the run's simulated length (default 170)")
    p.add_argument("--budget", type=positive_int, default=900, metavar="BYTES", help="picture BUDGET (default 900)")
    p.add_argument("--shift", type=int, default=6, choices=range(1, 16), metavar="N", help="ROI SHIFT (default 6)")
    p.add_argument("--tracker", choices=("klt", "ncc", "csrt", "kcf"), default="klt", help="the ROV's tracker (default klt)")
    p.add_argument("--camera-hz", type=positive, default=10.0, metavar="HZ", help="camera frames a second (default 10)")
    p.add_argument("--object", choices=("ladder", "pipe", "amphora"), default="ladder", help="what is followed")
    p.add_argument("--protocol", choices=("2", "1.1"), default="2", help="link version (default 2)")
    p.add_argument("--no-compare", action="store_true", help="leave out the other trackers on the same frames")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=run_bench)


def run_bench(args) -> int:
    import sys
    from dataclasses import asdict

    from rovlink.bench import emit
    from rovlink.command import CommandError
    from rovlink.rov.follow import TrackerMissing

    if args.budget > 8189 or args.budget < 64:
        raise CommandError("--budget must be 64..8189 bytes")

    def progress(now: float, total: float, pictures: int) -> None:
        print(f"bench roi: {now:.0f}/{total:.0f} s simulated, {pictures} pictures", file=sys.stderr, flush=True)

    compare = () if args.no_compare else ("klt", "ncc", "csrt", "kcf")
    try:
        run = measure(seconds=args.seconds, budget=args.budget, shift=args.shift, tracker=args.tracker,
                      camera_hz=args.camera_hz, kind=args.object, seed=args.seed, version2=args.protocol == "2",
                      compare=compare, progress=progress)
    except TrackerMissing as exc:
        raise CommandError(str(exc)) from None
    fig = figures(run)
    result = {
        "object": args.object,
        "link": f"version {args.protocol}, {BITRATE:g} bit/s, {1000 * DELAY_S:g} ms, BER {BER:g}",
        "seconds": args.seconds,
        "budget_bytes": args.budget,
        "shift": args.shift,
        "tracker": args.tracker,
        "camera_hz": args.camera_hz,
        "first_roi": list(run.first_roi),
        "iou_half_fraction": fig["iou_half_fraction"],
        "gain_over_fixed_db": fig["gain_over_fixed_db"],
        "lost_said_after_pictures": fig["lost_said_after_pictures"],
        "tracker_ms": fig["tracker_ms"],
        "figures": fig,
        "targets": targets(fig),
        "why": why_missed(fig, run),
        "trackers": run.trackers,
        "per_picture": [asdict(p) for p in run.pictures],
        "plot": None,
    }
    if args.out:
        try:
            plot(run, args.out)
        except ImportError:
            raise CommandError("the plot needs matplotlib: install rovlink with the 'console' extra") from None
        result["plot"] = args.out
    print("bench roi: done", file=sys.stderr, flush=True)
    emit(result, render(result), args.json)
    return 0
