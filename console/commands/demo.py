"""`rovlink demo`: the whole system on this machine, one command."""

from __future__ import annotations

from rovlink.command import non_negative, positive, probability

from .serve import add_gcs_arguments, add_server_arguments


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="run everything here: simulated ROV, ROV node, emulated 1.9 kbit/s channel and the console",
        description=(
            "Start the simulated ArduSub vehicle, the ROV node, the emulated narrow channel "
            "(1.9 kbit/s, 85 ms delay, BER 7e-6 by default) and the operator console, and serve "
            "the operator page. The session is recorded to runs/ (see rovlink replay, rovlink plot)."
        ),
    )
    add_server_arguments(p)
    add_gcs_arguments(p)
    p.add_argument("--bitrate", type=positive, default=1900.0, metavar="BPS", help="channel bit/s (default 1900)")
    p.add_argument("--delay", type=non_negative, default=0.085, metavar="S", help="intrinsic delay, s (default 0.085)")
    p.add_argument("--ber", type=probability, default=7e-6, help="bit error rate (default 7e-6, the paper's 0.0007 %%)")
    p.add_argument("--seed", type=int, default=0, help="channel random seed (default 0)")
    p.add_argument("--camera", default="sim", metavar="SPEC", help="camera on the ROV: sim (default), DIR, opencv:N")
    p.add_argument("--insecure", action="store_true",
                   help="run the link's version 1.1, unauthenticated (default: version 2 with a throwaway key)")
    p.add_argument("--record", metavar="FILE", help="session recording (default runs/session-TIME.jsonl)")
    p.add_argument("--no-record", action="store_true", help="do not record the session")
    p.set_defaults(func=run)


def run(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    import asyncio

    from rovlink.command import CommandError
    from rovlink.console.stack import Stack, StackConfig

    from .serve import check_ports, default_record_path, serve_operator

    check_ports(args)  # before any banner, recording or link
    record = None if args.no_record else (args.record or default_record_path())
    import os

    # Both ends run here: a throwaway key for this session (docs/PROTOCOL.md §8).
    key = None if args.insecure else os.urandom(32)
    config = StackConfig(bitrate_bps=args.bitrate, delay_s=args.delay, ber=args.ber, seed=args.seed,
                         camera=args.camera, record=record, key=key,
                         channel_log=None if record is None else str(record).replace(".jsonl", "") + ".channel.jsonl")

    args.rov_failsafe = config.failsafe_s  # the page infers the ROV's failsafe from it

    async def main() -> None:
        stack = Stack(config)
        try:
            operator = await stack.start()
        except Exception as exc:
            await stack.stop()
            raise CommandError(f"could not start the demo: {exc}") from None
        try:
            await serve_operator(
                operator, args, link=stack.link,
                banner=(f"rovlink demo: simulated ROV over an emulated {args.bitrate:g} bit/s link "
                        f"({args.delay * 1000:g} ms delay, BER {args.ber:g}); "
                        + ("INSECURE: link version 1.1, frames not authenticated" if key is None else
                           "link version 2, every frame authenticated (a throwaway key for this session)")
                        + (f"; recording to {record}" if record else "")),
            )
        finally:
            await stack.stop()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0
