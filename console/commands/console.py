"""`rovlink console`: the operator's side against a real modem or a remote ROV."""

from __future__ import annotations

from rovlink.command import add_key_arguments, non_negative, positive

from .serve import add_gcs_arguments, add_server_arguments


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "console",
        help="the operator console on a real link (modem or UDP)",
        description="Poll the ROV over LINK and serve the operator page and 3D scene.",
        epilog="example: rovlink console --link serial:///dev/ttyUSB0?baud=9600&crlf=1",
    )
    p.add_argument("--link", required=True, metavar="URL",
                   help="udp://HOST:PORT?peer=HOST:PORT or serial:///dev/tty...?baud=N[&crlf=1][&mtu=N]; "
                   "wlmodem:///dev/tty...?role=a&channel=4: the acoustic profile (docs/PROTOCOL.md §9)")
    add_server_arguments(p)
    add_gcs_arguments(p)
    p.add_argument("--bitrate", type=positive, default=1900.0, metavar="BPS",
                   help="the link's bit/s, for reply timeouts (default 1900)")
    p.add_argument("--delay", type=non_negative, default=0.085, metavar="S",
                   help="the link's intrinsic delay, s, for reply timeouts (default 0.085)")
    p.add_argument("--rov-failsafe", type=positive, default=3.0, metavar="S",
                   help="the ROV's failsafe time (its --failsafe): after this long without a reply the page says "
                        "the ROV is in FAILSAFE (default 3)")
    add_key_arguments(p)
    p.add_argument("--record", metavar="FILE", help="session recording (default runs/session-TIME.jsonl)")
    p.add_argument("--no-record", action="store_true", help="do not record the session")
    p.set_defaults(func=run)


def run(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    import asyncio

    from rovlink.command import CommandError, check_frame_size, link_key
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.operator import Operator
    from rovlink.link.transport import TransportError, open_transport

    from .serve import check_ports, default_record_path, serve_operator

    check_ports(args)  # before any banner, recording or link
    try:
        endpoint = open_transport(args.link)
    except TransportError as exc:
        raise CommandError(str(exc)) from None
    key = link_key(args)
    if args.link.startswith("wlmodem:"):
        return _run_acoustic(args, endpoint, key)
    check_frame_size(endpoint, key)
    record = None if args.no_record else (args.record or default_record_path())

    async def main() -> None:
        # The link runs in its own thread and loop: web traffic never delays a poll.
        link = LinkThread().start()
        try:
            await link.call(endpoint.start())
        except TransportError as exc:
            await link.stop()
            raise CommandError(str(exc)) from None
        operator = Operator(endpoint, bitrate_bps=args.bitrate, delay_s=args.delay, record=record)
        if key is not None:
            operator.authenticate(key)
        version = ("link version 2, every frame authenticated" if key is not None else
                   "INSECURE: link version 1.1, frames not authenticated")
        link.spawn(operator.run(), name="operator")
        try:
            await serve_operator(operator, args, banner=f"rovlink console on {args.link}; {version}", link=link)
        finally:
            await link.stop(endpoint.close())
            operator.close()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0


def _run_acoustic(args, endpoint, key) -> int:
    """The acoustic profile: supervisory orders, status and thumbnails (docs/PROTOCOL.md §9)."""
    import asyncio
    import sys

    from rovlink.command import CommandError
    from rovlink.console.acoustic.session import AcousticSession
    from rovlink.console.acoustic.web import create_acoustic_app
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.web.app import serve
    from rovlink.console.web.guard import AccessPolicy
    from rovlink.link.transport import TransportError

    from .serve import _stop_on_signals, default_record_path, public_host

    if key is None:
        raise CommandError("the acoustic profile is always authenticated: give --key FILE (no --insecure)")
    record = None if args.no_record else (args.record or default_record_path())

    async def main() -> None:
        link = LinkThread().start()
        try:
            await link.call(endpoint.start())
        except TransportError as exc:
            await link.stop()
            raise CommandError(str(exc)) from None
        session = AcousticSession(endpoint, key, record=record)
        link.spawn(session.run(), name="acoustic operator")
        policy = AccessPolicy.for_server(args.host, args.allow_host)
        app = create_acoustic_app(session, policy=policy)
        url = f"http://{public_host(args.host)}:{args.port}/" + (f"?token={policy.token}" if policy.token else "")
        gateway = None
        if args.gcs:
            from rovlink.console.acoustic.gcs import AcousticCommands, AcousticGcsView
            from rovlink.console.gcs import GcsGateway

            try:
                gateway = GcsGateway(args.gcs, AcousticGcsView(session), AcousticCommands(session),
                                     home=args.gcs_home).start()
            except (OSError, ValueError) as exc:
                await link.stop(endpoint.close())
                raise CommandError(f"--gcs: {exc}") from None
        print(f"rovlink console on {args.link}: acoustic profile, every packet authenticated\n"
              f"  operator page: {url}" + (f"\n  ground station: {', '.join(args.gcs)} (MAVLink 2, ArduSub; "
                                           "targets and STOP, no sticks)" if args.gcs else "")
              + (f"\n  recording: {record}" if record else "")
              + "\n  Ctrl-C stops.", flush=True)
        stop = _stop_on_signals()
        server = asyncio.create_task(serve(app, host=args.host, port=args.port))
        waiter = asyncio.create_task(stop.wait())
        try:
            await asyncio.wait([server, waiter], return_when=asyncio.FIRST_COMPLETED)
            if server.done() and server.exception() is not None:
                exc = server.exception()
                raise CommandError(f"cannot serve the page on port {args.port}: {exc}") from None
        finally:
            if gateway is not None:
                gateway.stop()
            server.cancel()
            await asyncio.gather(server, return_exceptions=True)
            await link.stop(endpoint.close())
            session.close()
        print("rovlink console: stopped", file=sys.stderr)

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0
