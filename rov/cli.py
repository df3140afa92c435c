"""`rovlink rov` and `rovlink sim`: the programs of the ROV side.

`rovlink rov` runs on the ROV's companion computer: it answers the operator's
polls on the modem link, drives ArduSub through MAVLink, sends DEBT images of
the camera, and stops the vehicle when the link falls silent.

`rovlink sim` is the simulated ArduSub alone, as a MAVLink endpoint: a
stand-in for the vehicle that any ground station can talk to (the ROV node,
QGroundControl, MAVProxy, a pymavlink script).  The default copies BlueOS:
the vehicle sends to a ground station listening on UDP 14550 of this
machine; `--mavlink tcpin:127.0.0.1:5760` copies ArduSub SITL.  Servers bind
to loopback unless told otherwise.

Both need only the base install (no console extra).

`rovlink rov` takes SIGTERM and SIGHUP (how systemd, docker and `kill` stop a
service, and a closed terminal) like Ctrl-C: the node stops, the bridge sends
neutral sticks to ArduSub and closes, the process exits 0.  Killed at once
instead, ArduSub kept the last forward input for its 3 s pilot-input failsafe
(the vehicle moved 1.8 m).
"""

from __future__ import annotations

import signal
import threading

from rovlink.command import CommandError, add_key_arguments, check_frame_size, link_key, positive

STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def handle_stop_signals() -> None:
    """SIGTERM and SIGHUP raise KeyboardInterrupt, so they end the program the way
    Ctrl-C does: through every `finally` (Python's default for them ends the process
    at once, with no cleanup at all)."""
    if threading.current_thread() is threading.main_thread():
        for signum in STOP_SIGNALS:
            signal.signal(signum, _interrupt)


def add_parser(subparsers) -> None:
    _add_rov(subparsers)
    _add_sim(subparsers)
    _add_seabed(subparsers)


SEABED_HELP = ("the simulated seabed: a PNG with its JSON of objects (the truth) beside it, as "
               "'rovlink seabed' writes them (default: the committed assets/seabed.png)")


def load_seabed(path):
    """--seabed PATH as a Seabed (None: the committed one); a bad PNG or JSON is one line, exit 2."""
    from rovlink.command import UsageError
    from rovlink.rov.seabed import Seabed, SeabedError

    if path is None:
        return Seabed.load()
    try:
        return Seabed.from_png(path)
    except SeabedError as exc:
        raise UsageError(f"--seabed: {exc}") from None


def _add_rov(subparsers) -> None:
    p = subparsers.add_parser(
        "rov",
        help="run the ROV node: link slave, ArduSub bridge, camera, DEBT encoder, failsafe",
        description=(
            "Run the ROV side: answer the operator's polls on the modem link, drive ArduSub "
            "through MAVLink, send DEBT images of the camera, and stop the vehicle when the "
            "link falls silent. Without --mavlink a simulated ArduSub runs in-process."
        ),
        epilog="example: rovlink rov --link serial:///dev/ttyUSB0?baud=9600&crlf=1 "
        "--mavlink udpin:0.0.0.0:14550 --camera sim",
    )
    p.add_argument("--link", required=True, metavar="URL",
                   help="modem link: udp://HOST:PORT?peer=HOST:PORT or serial:///dev/tty...?baud=N[&crlf=1]; "
                   "wlmodem:///dev/tty...?role=b&channel=4 runs the acoustic profile (docs/PROTOCOL.md §9)")
    p.add_argument("--mavlink", metavar="URL",
                   help="ArduSub as pymavlink takes it (udpin:0.0.0.0:14550, tcp:127.0.0.1:5760, /dev/ttyACM0); "
                   "default: a simulated vehicle in-process")
    p.add_argument("--camera", default="sim", metavar="SPEC",
                   help="sim (default), a folder of images, folder:PATH, or opencv:N")
    p.add_argument("--failsafe", type=positive, default=None, metavar="S",
                   help="seconds without a valid poll before the vehicle stops (default 3; acoustic: 60, "
                   "without an authentic packet from the operator)")
    p.add_argument("--failsafe-action", choices=("hold", "surface"), default="hold",
                   help="acoustic profile: what the failsafe does: hold position (default) or surface")
    p.add_argument("--system-id", type=int, default=255, metavar="N", help="our MAVLink system id (default 255)")
    p.add_argument("--budget", type=int, default=2000, metavar="BYTES",
                   help="image budget until the operator sets one (default 2000)")
    p.add_argument("--colour", action="store_true", help="colour images until the operator sets otherwise")
    p.add_argument("--tracker", choices=("klt", "ncc", "csrt", "kcf", "none"), default="klt",
                   help="the tracker behind FOLLOW, an ROI that follows its object (docs/PROTOCOL.md §10; "
                        "needs the 'tracking' extra); none: FOLLOW is refused (default klt)")
    p.add_argument("--camera-hz", type=positive, default=None, metavar="HZ",
                   help="camera frames a second the tracker follows (default 10; acoustic: 5)")
    p.add_argument("--seabed", metavar="PNG", help=SEABED_HELP + "; with --camera sim and no --mavlink")
    p.add_argument("--no-objects", action="store_true",
                   help="recognise no objects on the seabed (default: 2 looks a second, OpenCV from the "
                        "'tracking' extra; told to the operator as docs/PROTOCOL.md §11 records, link version 2)")
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    add_key_arguments(p)
    p.add_argument("-v", "--verbose", action="store_true", help="log every order and failsafe")
    p.set_defaults(func=run_rov)


def run_rov(args) -> int:
    import asyncio
    import logging
    import sys

    # First, so that every thread started after (link, failsafe, camera, simulated vehicle)
    # has it: a poll is answered within tens of milliseconds, and a busy companion computer's
    # other work takes whole time slices (the console's link process does the same).
    priority = _raise_priority()

    from rovlink.link.radio.messages import ImageSettings, ProtocolError
    from rovlink.link.transports.transport import TransportError
    from rovlink.link.transports.urls import open_transport
    from rovlink.rov.autopilot import AutopilotBridge
    from rovlink.rov.camera import CameraError, open_camera
    from rovlink.rov.node import RovNode

    handle_stop_signals()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s")
    try:
        settings = ImageSettings(mono=not args.colour, budget_bytes=args.budget)
    except ProtocolError as exc:
        raise CommandError(f"--budget: {exc}") from None
    if not 1 <= args.system_id <= 255:
        raise CommandError("--system-id must be 1..255")
    try:
        endpoint = open_transport(args.link)
    except TransportError as exc:
        raise CommandError(str(exc)) from None
    key = link_key(args)  # None: --insecure, protocol version 1.1
    acoustic = args.link.startswith("wlmodem:")
    if acoustic and key is None:
        raise CommandError("the acoustic profile is always authenticated: give --key FILE (no --insecure)")
    if not acoustic:
        check_frame_size(endpoint, key)
        if args.failsafe_action != "hold":
            raise CommandError("--failsafe-action is the acoustic profile's (a wlmodem:// link); "
                               "the radio profile's failsafe holds")
    failsafe = args.failsafe if args.failsafe is not None else (60.0 if acoustic else 3.0)
    if args.camera_hz is None:
        args.camera_hz = 5.0 if acoustic else 10.0
    seabed = load_seabed(args.seabed)
    try:
        camera = open_camera(args.camera, seabed=seabed)
    except (CameraError, ValueError) as exc:
        raise CommandError(f"--camera: {exc}") from None

    sim = None
    mavlink = args.mavlink
    if mavlink is None:
        from rovlink.rov.simulator import SimulatedVehicle

        sim = SimulatedVehicle("udpin:127.0.0.1:0", floor_depth_m=seabed.depth_m).start()
        mavlink = sim.bridge_url
    try:
        bridge = AutopilotBridge(mavlink, gcs_system_id=args.system_id)
    except ValueError as exc:
        if sim:
            sim.stop()
        raise CommandError(f"--mavlink: {exc}") from None

    geometry = None
    if not args.no_objects:
        from rovlink.rov.objects import CameraGeometry

        geometry = CameraGeometry.of(camera)

    async def main() -> None:
        try:
            await endpoint.start()
        except TransportError as exc:
            raise CommandError(str(exc)) from None
        if acoustic:
            from rovlink.rov.acoustic import AcousticNode

            follower, follow = _follower(args, camera)
            node = AcousticNode(endpoint, bridge, camera.capture, key, failsafe_s=failsafe,
                                failsafe_action=args.failsafe_action, follower=follower, camera_hz=args.camera_hz,
                                objects=geometry)
            version = ("acoustic profile (docs/PROTOCOL.md §9), every packet authenticated; failsafe: "
                       + ("hold position" if args.failsafe_action == "hold" else "surface") + f"; {follow}")
        else:
            follower, follow = _follower(args, camera)
            node = RovNode(endpoint, bridge, camera.capture, failsafe_s=failsafe, default_settings=settings, key=key,
                           follower=follower, camera_hz=args.camera_hz, objects=geometry)
            version = ("link version 2, every frame authenticated" if key is not None else
                       "INSECURE: link version 1.1, frames not authenticated") + f"; {follow}"
        print(f"rov: link {args.link}, autopilot {args.mavlink or 'simulated (' + mavlink + ')'}, "
              f"camera {args.camera}, failsafe {failsafe:g} s; {version}; {priority}", file=sys.stderr, flush=True)
        task = asyncio.create_task(node.run())
        try:
            if args.duration:
                await asyncio.sleep(args.duration)
            else:
                await task
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await endpoint.close()

    try:
        try:
            bridge.start()
            asyncio.run(main())
        except KeyboardInterrupt:  # Ctrl-C, SIGTERM, SIGHUP
            pass
        finally:
            bridge.stop()  # neutral sticks, then close
            camera.close()
            if sim:
                sim.stop()
    except KeyboardInterrupt:  # a second signal while cleaning up: give up the rest quietly
        pass
    return 0

ROV_NICE = -10


def _raise_priority() -> str:
    """Ask for a scheduling priority above the computer's other work; what it got, in words."""
    import os

    try:
        os.setpriority(os.PRIO_PROCESS, 0, ROV_NICE)
    except OSError as exc:
        return f"priority not raised ({exc.strerror or exc}): a busy computer may delay its answers"
    return f"priority nice {os.getpriority(os.PRIO_PROCESS, 0)}"


def _follower(args, camera):
    """The ROV's follower for FOLLOW, or None, and what to say of it: a missing
    extra is said, and the ROV runs on, refusing FOLLOW with its reason."""
    from rovlink.rov.camera import FolderCamera

    if args.tracker == "none":
        return None, "FOLLOW refused (--tracker none)"
    if isinstance(camera, FolderCamera):
        # Its pictures step one a capture: at the camera's rate they would flash by.
        return None, "FOLLOW refused: a folder of pictures is no camera to track in"
    from rovlink.rov.follow import RoiFollower, TrackerMissing

    try:
        follower = RoiFollower(args.tracker)
    except TrackerMissing as exc:
        return None, f"FOLLOW refused: {exc}"
    return follower, f"FOLLOW by the {args.tracker} tracker at {args.camera_hz:g} frames/s"


DEFAULT_URL = "udpout:127.0.0.1:14550"


def _add_sim(subparsers) -> None:
    p = subparsers.add_parser(
        "sim",
        help="run the simulated ArduSub vehicle alone, as a MAVLink endpoint",
        description=(
            "Run the simulated BlueROV/ArduSub (4-DOF model, ArduSub modes, pilot-input "
            "failsafe) as a MAVLink endpoint in real time. Ground stations connect to it "
            "like to the real vehicle, e.g. 'rovlink rov --mavlink udpin:127.0.0.1:14550' "
            "with the default, or '--mavlink tcp:127.0.0.1:5760' with --mavlink tcpin:127.0.0.1:5760."
        ),
    )
    p.add_argument("--mavlink", default=DEFAULT_URL, metavar="URL",
                   help=f"where to serve (pymavlink syntax): udpout:HOST:PORT sends to a ground "
                        f"station, udpin:HOST:PORT and tcpin:HOST:PORT wait for one (default {DEFAULT_URL})")
    p.add_argument("--system-id", type=int, default=1, metavar="N", help="the vehicle's MAVLink system id (default 1)")
    p.add_argument("--depth", type=float, default=None, metavar="M",
                   help="starting depth in metres (default: 2 m above the simulated seabed)")
    p.add_argument("--seabed", metavar="PNG", help=SEABED_HELP + "; its depth is the vehicle's floor")
    p.add_argument("--no-position", action="store_true",
                   help="no position estimate (no DVL/GPS): GUIDED and POSHOLD are refused, no LOCAL_POSITION_NED")
    p.add_argument("--position-after", type=float, default=0.0, metavar="S",
                   help="the position estimate comes S seconds after start (ArduSub SITL: ~41 s; default 0)")
    p.add_argument("--pilot-timeout", type=float, default=3.0, metavar="S",
                   help="disarm after this long without MANUAL_CONTROL while armed (ArduSub: 3 s)")
    p.add_argument("--status-every", type=float, default=2.0, metavar="S",
                   help="print the vehicle's state every S seconds; 0 for never (default 2)")
    p.add_argument("-v", "--verbose", action="store_true", help="log every mode change, arming and refusal")
    p.set_defaults(func=run_sim)


def run_sim(args) -> int:
    import logging
    import math
    import sys
    import time

    from rovlink.rov.mavurl import parse_mavlink_url
    from rovlink.rov.simulator import SimulatedVehicle
    from rovlink.rov.vehicle import SubMode, VehicleState

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        url = parse_mavlink_url(args.mavlink)
    except ValueError as exc:
        raise CommandError(f"--mavlink: {exc}") from None
    if url.kind in ("udpin", "tcpin") and url.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"sim: warning: listening on {url.host}, reachable from other machines", file=sys.stderr)
    if not 1 <= args.system_id <= 255:
        raise CommandError("--system-id must be 1..255")
    if args.position_after < 0 or not math.isfinite(args.position_after):
        raise CommandError("--position-after must be 0 or more seconds")
    if args.pilot_timeout <= 0 or not math.isfinite(args.pilot_timeout):
        raise CommandError("--pilot-timeout must be a positive number of seconds")
    seabed = load_seabed(args.seabed)
    state = VehicleState(z_m=max(0.0, seabed.depth_m - 2.0))
    if args.depth is not None:
        if not 0.0 <= args.depth < seabed.depth_m:
            raise CommandError(f"--depth must be within 0..{seabed.depth_m:g} m (the seabed)")
        state = VehicleState(z_m=args.depth)

    sim = SimulatedVehicle(
        args.mavlink,
        system_id=args.system_id,
        initial_state=state,
        floor_depth_m=seabed.depth_m,
        has_position=not args.no_position,
        position_after_s=args.position_after,
        pilot_timeout_s=args.pilot_timeout,
    )
    try:
        sim.start()
    except OSError as exc:
        raise CommandError(f"cannot open {args.mavlink}: {exc}") from None
    print(f"sim: simulated ArduSub (system {args.system_id}) on {url.device.replace(':0', f':{sim.port}')}; "
          f"a ground station connects with --mavlink {sim.bridge_url}; Ctrl-C stops", file=sys.stderr, flush=True)
    try:
        while True:
            if args.status_every > 0:
                time.sleep(args.status_every)
                t = sim.truth()
                s = t.state
                try:
                    mode = SubMode(t.mode).name
                except ValueError:
                    mode = str(t.mode)
                print(f"sim: {'ARMED' if t.armed else 'disarmed'} {mode:9s} x {s.x_m:6.2f} y {s.y_m:6.2f} "
                      f"z {s.z_m:5.2f} m  yaw {math.degrees(s.yaw_rad):6.1f} deg  "
                      f"pilot x {t.pilot.x} y {t.pilot.y} z {t.pilot.z} r {t.pilot.r}", file=sys.stderr, flush=True)
            else:
                time.sleep(3600)
    finally:  # only Ctrl-C (KeyboardInterrupt, which the dispatcher reports) ends the loop above
        sim.stop()


def _add_seabed(subparsers) -> None:
    p = subparsers.add_parser(
        "seabed",
        help="generate a simulated seabed from a seed: a PNG and its JSON of objects (the truth)",
        description=("Generate a seabed for the simulator: a PNG texture and, beside it, a JSON listing "
                     "its objects (class, centre north/east, length, width, heading of the long axis). "
                     "Any seed but the default lays isolated objects at random. Use it with "
                     "'rovlink rov/sim/demo --seabed PNG'."),
    )
    p.add_argument("--seed", type=int, required=True, metavar="N", help="the layout's seed")
    p.add_argument("--out", required=True, metavar="PNG", help="where to write the PNG (its JSON goes beside it)")
    p.set_defaults(func=run_seabed)


def run_seabed(args) -> int:
    from pathlib import Path

    from rovlink.rov.seabed import generate, save

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise CommandError("--out must name a .png file (its .json goes beside it)")
    if not out.parent.is_dir():
        raise CommandError(f"--out: no such folder {out.parent}")
    seabed = generate(seed=args.seed)
    meta = save(seabed, out)
    print(f"wrote {out} and {meta}: {len(seabed.objects)} objects (seed {args.seed})")
    return 0
