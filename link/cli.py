"""`rovlink channel`: the channel emulator as a process between two endpoints."""

from __future__ import annotations

from rovlink.command import CommandError, non_negative, positive, probability


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "channel",
        help="emulate a narrow wireless channel between two endpoints",
        description=(
            "Carry frames between endpoint A (the operator side) and endpoint B (the ROV side) "
            "through an emulated channel: bitrate, intrinsic and propagation delay, bit errors, "
            "packet loss, a finite transmit queue and half-duplex collisions. Every transmit, "
            "receive, drop and corruption can be logged as JSON lines."
        ),
        epilog="example: rovlink channel --a udp://127.0.0.1:7001?peer=127.0.0.1:7000 "
        "--b udp://127.0.0.1:7002?peer=127.0.0.1:7003 --bitrate 1900 --delay 0.085 --ber 7e-6",
    )
    p.add_argument("--a", required=True, metavar="URL", help="endpoint A (udp://, serial://)")
    p.add_argument("--b", required=True, metavar="URL", help="endpoint B (udp://, serial://)")
    p.add_argument("--bitrate", type=positive, default=1900.0, metavar="BPS", help="bits per second (default 1900)")
    p.add_argument("--delay", type=non_negative, default=0.085, metavar="S", help="intrinsic delay, s (default 0.085)")
    p.add_argument("--propagation", type=non_negative, default=0.0, metavar="S", help="propagation delay, s (default 0)")
    p.add_argument("--ber", type=probability, default=0.0, help="bit error rate (default 0)")
    p.add_argument("--loss", type=probability, default=0.0, help="packet loss rate (default 0)")
    p.add_argument("--queue", type=int, default=2048, metavar="BYTES", help="transmit queue per side (default 2048)")
    p.add_argument("--full-duplex", action="store_true", help="no half-duplex collisions")
    p.add_argument("--seed", type=int, default=0, help="random seed, for reproducible runs (default 0)")
    p.add_argument("--log", metavar="FILE", help="write every channel event as a JSON line to FILE")
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--quiet", action="store_true", help="no periodic status line")
    p.set_defaults(func=run)


def run(args) -> int:
    import asyncio
    import sys

    from rovlink.link.aio import run_channel
    from rovlink.link.channel import Channel, LinkParams
    from rovlink.link.transport import TransportError, open_transport

    if args.queue < 1:
        raise CommandError("--queue must be at least 1 byte")
    try:
        a, b = open_transport(args.a), open_transport(args.b)
    except TransportError as exc:
        raise CommandError(str(exc)) from None
    params = LinkParams(args.bitrate, args.delay, args.propagation, args.ber, args.loss, args.queue)
    log_file = open(args.log, "w", buffering=1) if args.log else None
    channel = Channel(params, half_duplex=not args.full_duplex, seed=args.seed, log=log_file)

    async def status() -> None:
        while True:
            await asyncio.sleep(10)
            c = channel.counters
            print(
                f"channel: sent {c.sent} delivered {c.delivered} corrupted {c.corrupted} lost {c.lost} "
                f"collisions {c.collisions} queue drops {c.dropped_queue}",
                file=sys.stderr,
            )

    async def main() -> None:
        try:
            await a.start()
            await b.start()
        except TransportError as exc:
            raise CommandError(str(exc)) from None
        print(
            f"channel: {args.a} <-> {args.b} at {args.bitrate:g} bit/s, delay {args.delay:g} s, BER {args.ber:g}",
            file=sys.stderr,
        )
        tasks = [asyncio.create_task(run_channel(channel, a, b))]
        if not args.quiet:
            tasks.append(asyncio.create_task(status()))
        try:
            if args.duration:
                await asyncio.sleep(args.duration)
            else:
                await asyncio.gather(*tasks)
        finally:
            for t in tasks:
                t.cancel()
            await a.close()
            await b.close()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    finally:
        if log_file:
            log_file.close()
        c = channel.counters
        print(
            f"channel: done: sent {c.sent} delivered {c.delivered} corrupted {c.corrupted} lost {c.lost} "
            f"collisions {c.collisions} queue drops {c.dropped_queue}",
            file=sys.stderr,
        )
    return 0
