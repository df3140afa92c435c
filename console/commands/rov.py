"""`rovlink rov`: the program on the ROV's companion computer."""

from __future__ import annotations

from .argtypes import positive


def add_parser(subparsers) -> None:
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
                   help="modem link: udp://HOST:PORT?peer=HOST:PORT or serial:///dev/tty...?baud=N[&crlf=1]")
    p.add_argument("--mavlink", metavar="URL",
                   help="ArduSub as pymavlink takes it (udpin:0.0.0.0:14550, tcp:127.0.0.1:5760, /dev/ttyACM0); "
                   "default: a simulated vehicle in-process")
    p.add_argument("--camera", default="sim", metavar="SPEC",
                   help="sim (default), a folder of images, folder:PATH, or opencv:N")
    p.add_argument("--failsafe", type=positive, default=3.0, metavar="S",
                   help="seconds without a valid poll before the vehicle stops (default 3)")
    p.add_argument("--system-id", type=int, default=255, metavar="N", help="our MAVLink system id (default 255)")
    p.add_argument("--budget", type=int, default=2000, metavar="BYTES",
                   help="image budget until the operator sets one (default 2000)")
    p.add_argument("--colour", action="store_true", help="colour images until the operator sets otherwise")
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("-v", "--verbose", action="store_true", help="log every order and failsafe")
    p.set_defaults(func=run)


def run(args) -> int:
    import asyncio
    import logging
    import sys

    from rovlink.console.cli import CommandError
    from rovlink.link.messages import ImageSettings, ProtocolError
    from rovlink.link.transport import TransportError, open_transport
    from rovlink.rov.autopilot import AutopilotBridge
    from rovlink.rov.camera import CameraError, open_camera
    from rovlink.rov.node import RovNode

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
    try:
        camera = open_camera(args.camera)
    except (CameraError, ValueError) as exc:
        raise CommandError(f"--camera: {exc}") from None

    sim = None
    mavlink = args.mavlink
    if mavlink is None:
        from rovlink.rov.simulator import SimulatedVehicle

        sim = SimulatedVehicle("udpin:127.0.0.1:0").start()
        mavlink = sim.bridge_url
    try:
        bridge = AutopilotBridge(mavlink, gcs_system_id=args.system_id)
    except ValueError as exc:
        if sim:
            sim.stop()
        raise CommandError(f"--mavlink: {exc}") from None
    bridge.start()

    async def main() -> None:
        try:
            await endpoint.start()
        except TransportError as exc:
            raise CommandError(str(exc)) from None
        node = RovNode(endpoint, bridge, camera.capture, failsafe_s=args.failsafe, default_settings=settings)
        print(f"rov: link {args.link}, autopilot {args.mavlink or 'simulated (' + mavlink + ')'}, "
              f"camera {args.camera}, failsafe {args.failsafe:g} s", file=sys.stderr, flush=True)
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
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    finally:
        bridge.stop()
        camera.close()
        if sim:
            sim.stop()
    return 0
