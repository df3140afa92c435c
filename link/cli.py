"""`rovlink channel`: the channel emulator as a process between two endpoints.
`rovlink keygen`: a new key for the authenticated link (docs/PROTOCOL.md §8)."""

from __future__ import annotations

from rovlink.command import CommandError, non_negative, positive, probability


def add_parser(subparsers) -> None:
    _add_channel(subparsers)
    _add_keygen(subparsers)


def _add_keygen(subparsers) -> None:
    p = subparsers.add_parser(
        "keygen",
        help="write a new key for the authenticated link",
        description=(
            "Write 32 random bytes from the operating system's cryptographic source as 64 hex digits "
            "to a new file that only its owner may read (mode 0600). Copy it to the ROV and to the "
            "operator's laptop and give it to both with --key. An existing file is never overwritten."
        ),
        epilog="example: rovlink keygen ~/.config/rovlink/link.key",
    )
    p.add_argument("file", metavar="FILE", help="the key file to create")
    p.set_defaults(func=run_keygen)


def run_keygen(args) -> int:
    import os

    from rovlink.link.auth import write_key_file

    folder = os.path.dirname(os.path.abspath(args.file))
    if not os.path.isdir(folder):
        raise CommandError(f"no such folder: {folder}")
    try:
        write_key_file(args.file)
    except FileExistsError:
        raise CommandError(f"{args.file} exists already: a key is never overwritten (remove it first "
                           "if you mean to rotate the key; see SECURITY.md)") from None
    except OSError as exc:
        raise CommandError(f"cannot write {args.file}: {exc.strerror}") from None
    print(f"wrote a new link key to {args.file} (mode 0600)")
    return 0


def _add_channel(subparsers) -> None:
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
