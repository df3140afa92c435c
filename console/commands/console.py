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
    p.add_argument("--link-thread", action="store_true",
                   help="run the radio link in a thread of this process rather than a process of its own (as "
                        "before; for comparison: `rovlink bench console --loaded-compare`)")
    p.set_defaults(func=run)


def run(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    import asyncio

    from rovlink.command import CommandError, check_frame_size, link_key
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.session.radio import Operator
    from rovlink.link.process import STOP_AFTER_PARENT_S, MasterProcess
    from rovlink.link.transports.transport import TransportError
    from rovlink.link.transports.urls import open_transport

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

    PORT_WAIT_S = STOP_AFTER_PARENT_S + 3.0

    async def main() -> None:
        # The link (transport, master, its clock and deadlines) runs in a process of its own
        # (link/process.py), watched from a thread and loop of this one: neither web traffic
        # nor the page, the scene or picture decoding here delays a poll.
        link = LinkThread().start()
        # Opened here once, so that a wrong port is one line now, not a restart loop.  A
        # console that ended a moment ago may leave its link process on the port while it
        # sends its STOP (link/process.py): that is waited for, a few seconds.
        await _open_first(link, endpoint, args.link, PORT_WAIT_S, keep_open=args.link_thread)
        if args.link_thread:  # the link's loop in the link thread, on the transport opened above
            operator = Operator(endpoint, bitrate_bps=args.bitrate, delay_s=args.delay, record=record)
        else:
            master = MasterProcess(args.link, bitrate_bps=args.bitrate, delay_s=args.delay,
                                   max_frame=endpoint.max_frame, t0=0.0)
            operator = Operator(None, master=master, bitrate_bps=args.bitrate, delay_s=args.delay, record=record)
        if key is not None:
            operator.authenticate(key)
        version = ("link version 2, every frame authenticated" if key is not None else
                   "INSECURE: link version 1.1, frames not authenticated")
        link.spawn(operator.run(), name="operator")
        try:
            await serve_operator(operator, args, banner=f"rovlink console on {args.link}; {version}", link=link)
        finally:
            await link.stop(endpoint.close() if args.link_thread else None)
            operator.close()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0


def _run_acoustic(args, endpoint, key) -> int:
    """The acoustic profile (docs/PROTOCOL.md §9): the same cockpit, API, scene and
    gateway as the radio link's, over an `AcousticSession`."""
    import asyncio

    from rovlink.command import CommandError
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.session.acoustic import AcousticSession
    from rovlink.link.acoustic.process import STOP_AFTER_CONSOLE_S, AcousticLinkProcess

    from .serve import default_record_path, serve_operator

    PORT_WAIT_S = STOP_AFTER_CONSOLE_S + 3.0
    if key is None:
        raise CommandError("the acoustic profile is always authenticated: give --key FILE (no --insecure)")
    record = None if args.no_record else (args.record or default_record_path())

    async def main() -> None:
        # The machine, the modem and its pacing run in a process of their own
        # (link/acoustic/process.py), watched from a thread and loop of this one.  The modem is
        # opened here once first, so that a wrong port or a modem that refuses is one line now,
        # not a restart loop.
        link = LinkThread().start()
        # A console that ended a moment ago may leave its link process on the modem while it
        # sends its STOP (up to 15 s): its lock on the port is waited for, as on UDP.
        await _open_first(link, endpoint, args.link, PORT_WAIT_S, keep_open=False)
        link_process = AcousticLinkProcess(args.link, key)
        session = AcousticSession(None, key, record=record, link=link_process)
        link.spawn(session.run(), name="acoustic operator")
        try:
            await serve_operator(session, args, link=link,
                                 banner=f"rovlink console on {args.link}: acoustic profile (Modem-M64), every packet "
                                        "authenticated; targets, STOP and thumbnails, no sticks"
                                        + (f"\n  recording: {record}" if record else ""))
        finally:
            await link.stop()
            # The link process sends STOP as the console ends, then nothing more: waited for here.
            await asyncio.to_thread(link_process.close)
            session.close()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0


async def _open_first(link, endpoint, url: str, wait_s: float, *, keep_open: bool) -> None:
    """Open the link's port once, here, so that a wrong port is one line now and not a
    restart loop of the link process; closed again unless `keep_open` (the link process
    opens it in its own process).  A port another program holds (a UDP port in use, a
    serial port locked) may be a console that ended a moment ago, its link process still
    sending its STOP: that is waited for, `wait_s` at most, and said once."""
    import asyncio
    import sys
    import time

    from rovlink.command import CommandError
    from rovlink.link.transports.transport import PORT_LOCKED, TransportError

    waited = None
    while True:
        try:
            await link.call(endpoint.start())
            if not keep_open:
                await link.call(endpoint.close())
            return
        except TransportError as exc:
            busy = "Address already in use" in str(exc) or PORT_LOCKED in str(exc)
            if busy and (waited is None or time.monotonic() - waited < wait_s):
                if waited is None:
                    waited = time.monotonic()
                    print(f"rovlink console: {url} is in use (a console that ended may still be sending its STOP); "
                          f"waiting up to {wait_s:g} s", file=sys.stderr, flush=True)
                await asyncio.sleep(0.25)
                continue
            await link.stop()
            raise CommandError(str(exc)) from None
