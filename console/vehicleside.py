"""`rovlink demo`'s vehicle side, in a process of its own, as on a real ROV.

Goal: the browser, the web server and the 3-D scene share the console's
process and its two cores' worth of Python; the ROV's answers, its failsafe
timer and the emulated radio must not wait for them.  In one process a page
loading made the link read "lost" and the ROV fail safe (issue 25 of the
pilot's page), so the demo runs the simulated vehicle, its bridge, camera, ROV
node and the emulated channel here, apart, and talks to it over loopback UDP
exactly as `rovlink console` talks to a remote ROV.

Protocol with the parent (console/commands/demo.py): the first line of stdin
is the link key in hex, or "insecure" (version 1.1); "ready" on stdout once the
parts run; the process stops when stdin closes (the console ended or died),
on SIGTERM, or on Ctrl-C.  Nothing else is read or written on those pipes.

Run as `python -m rovlink.console.vehicleside --udp PORT --peer PORT [...]`.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import threading

from rovlink.link.transports.transport import TransportError
from rovlink.link.transports.urls import open_transport

from .stack import StackConfig, VehicleSide

log = logging.getLogger("rovlink.console.vehicleside")



PORT_TAKEN = 98  # exit status: our UDP port was taken before we could bind it (EADDRINUSE)

def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m rovlink.console.vehicleside",
                                description="rovlink demo's simulated ROV side (started by `rovlink demo`)")
    p.add_argument("--udp", type=int, required=True, metavar="PORT", help="our loopback UDP port")
    p.add_argument("--peer", type=int, required=True, metavar="PORT", help="the console's loopback UDP port")
    p.add_argument("--bitrate", type=float, default=1900.0)
    p.add_argument("--delay", type=float, default=0.085)
    p.add_argument("--ber", type=float, default=7e-6)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--camera", default="sim")
    p.add_argument("--seabed", default=None)
    p.add_argument("--failsafe", type=float, default=3.0)
    p.add_argument("--start-depth", type=float, default=2.0)
    p.add_argument("--channel-log", default=None)
    return p.parse_args(argv)


def _read_key() -> bytes | None:
    line = sys.stdin.readline().strip()
    if line == "insecure":
        return None
    try:
        key = bytes.fromhex(line)
    except ValueError:
        key = b""
    if len(key) != 32:
        raise SystemExit("vehicle side: the first line of stdin must be a 32-byte key in hex, or 'insecure'")
    return key


async def _run(args: argparse.Namespace, key: bytes | None) -> None:
    loop = asyncio.get_running_loop()
    done = asyncio.Event()
    # The parent closing our stdin (or dying) ends us: nobody is left to poll.
    threading.Thread(target=lambda: (sys.stdin.read(), loop.call_soon_threadsafe(done.set)),
                     name="stdin-watch", daemon=True).start()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, done.set)
    try:
        endpoint = open_transport(f"udp://127.0.0.1:{args.udp}?peer=127.0.0.1:{args.peer}")
    except TransportError as exc:
        raise SystemExit(f"vehicle side: {exc}") from None
    config = StackConfig(bitrate_bps=args.bitrate, delay_s=args.delay, ber=args.ber, seed=args.seed,
                         failsafe_s=args.failsafe, camera=args.camera, seabed=args.seabed, channel_log=args.channel_log,
                         start_depth_m=args.start_depth, key=key, tracker="klt", objects=True)
    vehicle = VehicleSide(config, endpoint)
    try:
        try:
            await vehicle.start()
        except TransportError as exc:
            if "Address already in use" in str(exc):
                # Another program took the port the demo chose for us since: it
                # tries again with new ones (PORT_TAKEN says which failure this is).
                print(f"vehicle side: {exc}", file=sys.stderr, flush=True)
                raise SystemExit(PORT_TAKEN) from None
            raise
        print("ready", flush=True)
        await done.wait()
    finally:
        await vehicle.stop()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="vehicle side: %(name)s: %(message)s")
    key = _read_key()
    try:
        asyncio.run(_run(args, key))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
