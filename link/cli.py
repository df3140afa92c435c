"""`rovlink channel`: the channel emulator as a process between two endpoints
(`--model m64`: two emulated Water Linked Modem-M64s on pseudo-terminals,
link/emulators/m64serial.py, for the wlmodem:// transport).
`rovlink keygen`: a new key for the authenticated link (docs/PROTOCOL.md §8)."""

from __future__ import annotations

import argparse

from rovlink.command import CommandError, UsageError, non_negative, positive, probability


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

    from rovlink.link.radio.auth import write_key_file

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


# The radio model's options and their defaults: refused with --model m64 when given otherwise.
RADIO_DEFAULTS = {"bitrate": 1900.0, "delay": 0.085, "propagation": 0.0, "ber": 0.0, "queue": 2048,
                  "full_duplex": False}
STATUS_EVERY_S = 10.0


def burst_length(text: str) -> float:
    """A mean loss burst, in packets: at least 1."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number of packets, got {text!r}") from None
    if not 1.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be at least 1 packet, got {text}")
    return value


def _add_channel(subparsers) -> None:
    p = subparsers.add_parser(
        "channel",
        help="emulate a narrow wireless channel between two endpoints",
        description=(
            "Carry frames between endpoint A (the operator side) and endpoint B (the ROV side) "
            "through an emulated channel: bitrate, intrinsic and propagation delay, bit errors, "
            "packet loss, a finite transmit queue and half-duplex collisions. Every transmit, "
            "receive, drop and corruption can be logged as JSON lines. With --model m64 the two "
            "ends are emulated Water Linked Modem-M64 acoustic modems on pseudo-terminals "
            "(--a pty:PATH --b pty:PATH), for wlmodem://PATH?role=a and ?role=b: 8-byte packets, "
            "one a second each way in turns, 1.5-2.5 s latency, loss in bursts."
        ),
        epilog="examples: rovlink channel --a udp://127.0.0.1:7001?peer=127.0.0.1:7000 "
        "--b udp://127.0.0.1:7002?peer=127.0.0.1:7003 --bitrate 1900 --delay 0.085 --ber 7e-6; "
        "rovlink channel --model m64 --a pty:/tmp/op-modem --b pty:/tmp/rov-modem --loss 0.1, then "
        "rovlink console --link 'wlmodem:///tmp/op-modem?role=a' and rovlink rov --link 'wlmodem:///tmp/rov-modem?role=b'",
    )
    p.add_argument("--model", choices=("radio", "m64"), default="radio",
                   help="radio (default): the narrow radio channel between two transport URLs; m64: two emulated "
                   "Modem-M64s on pseudo-terminals")
    p.add_argument("--a", required=True, metavar="URL",
                   help="endpoint A (udp://, serial://; with --model m64 pty:PATH, the operator's modem)")
    p.add_argument("--b", required=True, metavar="URL",
                   help="endpoint B (udp://, serial://; with --model m64 pty:PATH, the ROV's modem)")
    p.add_argument("--bitrate", type=positive, default=1900.0, metavar="BPS", help="bits per second (default 1900; radio)")
    p.add_argument("--delay", type=non_negative, default=0.085, metavar="S",
                   help="intrinsic delay, s (default 0.085; radio)")
    p.add_argument("--propagation", type=non_negative, default=0.0, metavar="S",
                   help="propagation delay, s (default 0; radio)")
    p.add_argument("--ber", type=probability, default=0.0, help="bit error rate (default 0; radio)")
    p.add_argument("--loss", type=probability, default=0.0, help="packet loss rate, each way (default 0)")
    p.add_argument("--burst", type=burst_length, default=1.0, metavar="N",
                   help="losses in bursts of N packets on average (default 1: independent losses)")
    p.add_argument("--queue", type=int, default=2048, metavar="BYTES", help="transmit queue per side (default 2048; radio)")
    p.add_argument("--full-duplex", action="store_true", help="no half-duplex collisions (radio)")
    p.add_argument("--seed", type=int, default=0, help="random seed, for reproducible runs (default 0)")
    p.add_argument("--log", metavar="FILE", help="write every channel event as a JSON line to FILE")
    p.add_argument("--duration", type=positive, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--quiet", action="store_true", help="no periodic status line")
    p.set_defaults(func=run)


def _open_log(path: str | None):
    if not path:
        return None
    try:
        return open(path, "w", buffering=1)
    except OSError as exc:
        raise CommandError(f"cannot write the log {path}: {exc.strerror}") from None


def run(args) -> int:
    if args.model == "m64":
        return run_m64(args)
    import asyncio
    import sys

    from rovlink.link.aio import run_channel
    from rovlink.link.emulators.channel import Channel, LinkParams
    from rovlink.link.transports.transport import TransportError
    from rovlink.link.transports.urls import open_transport

    if args.queue < 1:
        raise CommandError("--queue must be at least 1 byte")
    for option, url in (("--a", args.a), ("--b", args.b)):
        if url.startswith("pty:"):
            raise UsageError(f"{option} {url}: a pty:PATH endpoint is an emulated Modem-M64: use it with --model m64")
    try:
        params = LinkParams(bitrate_bps=args.bitrate, delay_s=args.delay, propagation_s=args.propagation, ber=args.ber,
                            loss=args.loss, burst=args.burst, queue_bytes=args.queue)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        a, b = open_transport(args.a), open_transport(args.b)
    except TransportError as exc:
        raise CommandError(str(exc)) from None
    log_file = _open_log(args.log)
    channel = Channel(params, half_duplex=not args.full_duplex, seed=args.seed, log=log_file)

    async def status() -> None:
        while True:
            await asyncio.sleep(STATUS_EVERY_S)
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


def _pty_path(option: str, url: str) -> str:
    """PATH of a `pty:PATH` endpoint (`pty:///tmp/x` too)."""
    if not url.startswith("pty:"):
        raise UsageError(f"{option} {url}: with --model m64 the endpoints are emulated modems on pseudo-terminals: "
                         f"{option} pty:PATH (e.g. pty:/tmp/op-modem)")
    path = url[len("pty:"):]
    if path.startswith("///"):
        path = path[2:]
    if not path or path.endswith("/"):
        raise UsageError(f"{option} {url}: pty: needs the path to create, e.g. pty:/tmp/op-modem")
    return path


def run_m64(args) -> int:
    """`rovlink channel --model m64`: two emulated Modem-M64s (link/emulators/m64serial.py)."""
    import logging
    import os
    import signal
    import sys
    import threading
    import time

    from rovlink.link.emulators.m64 import M64Loss
    from rovlink.link.emulators.m64serial import M64SerialError, M64SerialPair

    radio = [f"--{name.replace('_', '-')}" for name, default in RADIO_DEFAULTS.items() if getattr(args, name) != default]
    if radio:
        raise UsageError(f"{', '.join(radio)}: radio option{'s' if len(radio) > 1 else ''}, meaningless with --model m64 "
                         "(the modems' own timing: one 8-byte packet a second each way, 1.5-2.5 s latency); "
                         "it takes --loss, --burst, --seed, --log, --duration and --quiet")
    path_a, path_b = _pty_path("--a", args.a), _pty_path("--b", args.b)
    if os.path.abspath(path_a) == os.path.abspath(path_b):
        raise UsageError(f"--a and --b name the same path {path_a}: the two modems need one each")
    try:
        loss = M64Loss(args.loss, args.burst)
    except ValueError as exc:
        raise UsageError(f"--loss {args.loss:g} --burst {args.burst:g}: {exc}") from None
    log_file = _open_log(args.log)
    try:
        pair = M64SerialPair(path_a, path_b, a_to_b=loss, b_to_a=loss, seed=args.seed, log=log_file).start()
    except M64SerialError as exc:
        if log_file:
            log_file.close()
        raise CommandError(str(exc)) from None

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():  # SIGTERM and SIGHUP end it as Ctrl-C does
        for signum in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(signum, interrupt)
    print(f"channel: M64 emulator: modem A at {path_a}, modem B at {path_b} (one 8-byte packet a second each way, "
          f"latency 1.5-2.5 s, loss {args.loss:g} in bursts of {args.burst:g}); open them as "
          f"wlmodem://{path_a}?role=a and wlmodem://{path_b}?role=b", file=sys.stderr, flush=True)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("channel: %(message)s"))
    emulator_log = logging.getLogger("rovlink.link.emulators.m64serial")
    emulator_log.addHandler(handler)
    emulator_log.setLevel(logging.WARNING if args.quiet else logging.INFO)
    start = time.monotonic()
    next_status = start + STATUS_EVERY_S
    try:
        while True:
            now = time.monotonic()
            if args.duration and now >= start + args.duration:
                break
            if now >= next_status:
                if not args.quiet:
                    print(f"channel: {pair.status_line()}", file=sys.stderr, flush=True)
                next_status += STATUS_EVERY_S
            wait = next_status - now
            if args.duration:
                wait = min(wait, start + args.duration - now)
            time.sleep(max(0.0, wait))
    except KeyboardInterrupt:
        pass
    finally:
        pair.close()
        emulator_log.removeHandler(handler)
        if log_file:
            log_file.close()
        print(f"channel: done: {pair.status_line()}", file=sys.stderr, flush=True)
    return 0
