"""Shared by `rovlink demo`, `rovlink console` and `rovlink replay`: serve an
Operator through the viser scene and the web app until Ctrl-C."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from rovlink.command import port, positive


def add_server_arguments(p) -> None:
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve the page on (default 127.0.0.1, this machine only; 0.0.0.0 opens it)")
    p.add_argument("--port", type=port, default=8000, help="operator page and API port (default 8000)")
    p.add_argument("--viser-port", type=port, default=8080, help="3D scene (viser) port (default 8080)")
    p.add_argument("--unattended-warn", type=positive, default=60.0, metavar="S",
                   help="warn every page when the vehicle stays armed this long with nobody in control (default 60)")
    p.add_argument("--disarm-unattended", type=positive, default=None, metavar="S",
                   help="disarm the vehicle when it stays armed this long with nobody in control (default: never)")
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                   help="a further name the browser may reach the console by (its Host header), e.g. the "
                        "laptop's DNS name; requests naming any other host are refused (DNS rebinding). Repeatable")


def check_ports(args) -> None:
    """Before anything starts, prints a banner or writes a recording: the page's and
    the scene's ports must differ and be free on --host (a CommandError, one line)."""
    import socket

    from rovlink.command import CommandError

    if args.port == args.viser_port:
        raise CommandError("--port and --viser-port must differ")
    for name, number in (("--port", args.port), ("--viser-port", args.viser_port)):
        family = socket.AF_INET6 if ":" in args.host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((args.host, number))
            except OSError as exc:
                raise CommandError(f"{name} {number}: cannot serve on {args.host}:{number} "
                                   f"({exc.strerror or exc}); choose another with {name}") from None


def gcs_url(text: str) -> str:
    import argparse

    from rovlink.rov.mavurl import parse_mavlink_url

    try:
        parse_mavlink_url(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def lat_lon(text: str) -> tuple[float, float]:
    import argparse
    import math

    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be LAT,LON in degrees, got {text!r}") from None
    if not (math.isfinite(lat) and math.isfinite(lon) and -90 < lat < 90 and -180 <= lon <= 180):
        raise argparse.ArgumentTypeError(f"must be a latitude in -90..90 and a longitude in -180..180, got {text!r}")
    return lat, lon


def add_gcs_arguments(p) -> None:
    p.add_argument("--gcs", action="append", default=[], type=gcs_url, metavar="URL",
                   help="serve a MAVLink ground station (QGroundControl, Cockpit, MAVProxy) here, as an ArduSub "
                        "vehicle: udpout:127.0.0.1:14550 (QGroundControl's port), udpin:HOST:PORT, tcpin:HOST:PORT. "
                        "Repeatable")
    p.add_argument("--gcs-home", type=lat_lon, default=(0.0, 0.0), metavar="LAT,LON",
                   help="where the local NED origin lies on the ground station's map (default 0,0)")


def default_record_path() -> Path:
    import time

    return Path("runs") / f"session-{time.strftime('%Y%m%d-%H%M%S')}.jsonl"


def browser_host(host: str) -> str:
    """The address a browser on this machine reaches a server bound to `host` by."""
    return "127.0.0.1" if host in ("0.0.0.0", "::", "", "localhost") else host


def public_host(host: str) -> str:
    """The address to print for a server bound to `host`: for all interfaces,
    this machine's first address that is not loopback (else its name)."""
    import ipaddress
    import socket

    if host not in ("0.0.0.0", "::", ""):
        return f"[{host}]" if ":" in host else host
    name = socket.gethostname()
    try:
        addresses = [info[4][0] for info in socket.getaddrinfo(name, None, socket.AF_INET)]
    except OSError:
        addresses = []
    for address in addresses:
        if not ipaddress.ip_address(address).is_loopback:
            return address
    return name


async def serve_operator(operator, args, *, banner: str, background=(), link=None, sim_seabed: bool = False) -> None:
    """Start the scene and the web app for `operator`; return when the server stops.

    `background`: coroutines to run in this loop beside the server (a replay).
    `link`: the LinkThread whose loop drives the operator; the program stops
    with a one-line error if its link task fails."""
    from rovlink.command import CommandError
    from rovlink.console.scene.app import ConsoleScene
    from rovlink.console.web.app import create_app, serve
    from rovlink.console.web.guard import AccessPolicy, guard_viser

    if args.port == args.viser_port:
        raise CommandError("--port and --viser-port must differ")
    # Every port checks the Host (and, off loopback, the token) before anything else.
    policy = AccessPolicy.for_server(args.host, args.allow_host)
    guard_viser(policy)
    try:
        scene = ConsoleScene(operator, host=args.host, port=args.viser_port, sim_seabed=sim_seabed).start()
    except OSError as exc:
        raise CommandError(f"cannot serve the 3D scene on port {args.viser_port}: {exc}") from None
    # viser takes the next free port when the one asked for is busy: use the real one.
    from urllib.parse import urlsplit

    viser_port = urlsplit(scene.url).port or args.viser_port
    viser_url = f"http://{browser_host(args.host)}:{viser_port}"
    app = create_app(operator, viser_url=viser_url, scene=scene, telemetry_hz=25.0, policy=policy,
                     unattended_warn_s=args.unattended_warn, disarm_unattended_s=args.disarm_unattended,
                     # The radio ROV's failsafe is the pilot's to state; the acoustic ROV says its own (SYNC).
                     rov_failsafe_s=getattr(args, "rov_failsafe", None) if operator.capabilities.profile == "radio"
                     else None)
    tasks = [asyncio.create_task(coro) for coro in background]
    url = f"http://{public_host(args.host)}:{args.port}/" + (f"?token={policy.token}" if policy.token else "")
    if policy.token:
        viser_url = f"http://{public_host(args.host)}:{viser_port}/?token={policy.token}"
    stop = _stop_on_signals()
    server = asyncio.create_task(serve(app, host=args.host, port=args.port))
    access = (f"\n  bound to {args.host}: every request needs the access token in these URLs (keep it secret)"
              if policy.token else "")
    # The address to open comes first: it is what a newcomer looks for.
    print(f"operator page: {url}\n{banner}\n  3D scene alone, watch only (the page embeds it): {viser_url}"
          f"{access}\n  Ctrl-C stops.", flush=True)
    gateway = None
    if getattr(args, "gcs", None):
        from rovlink.console.gcs import DeskCommands, GcsGateway

        try:
            gateway = GcsGateway(args.gcs, operator, DeskCommands(app.state.desk),
                                 home=args.gcs_home).start()
        except (OSError, ValueError) as exc:
            server.cancel()
            scene.stop()
            raise CommandError(f"--gcs: {exc}") from None
        print("  ground station: " + ", ".join(args.gcs) + f" (MAVLink 2, ArduSub; pictures at {url.split('?')[0]}"
              "api/image/latest.png)", flush=True)
    waiter = asyncio.create_task(stop.wait())
    tasks.append(asyncio.create_task(_watch_link(link)))
    try:
        await asyncio.wait([server, waiter, tasks[-1]], return_when=asyncio.FIRST_COMPLETED)
        if server.done() and server.exception() is not None:
            exc = server.exception()
            if isinstance(exc, OSError):
                raise CommandError(f"cannot serve the page on port {args.port}: {exc}") from None
            raise exc
        if tasks[-1].done() and not tasks[-1].cancelled() and tasks[-1].exception() is not None:
            raise tasks[-1].exception()
    finally:
        print("stopping...", file=sys.stderr, flush=True)
        for t in (server, waiter, *tasks):
            t.cancel()
        await asyncio.gather(server, waiter, *tasks, return_exceptions=True)
        if gateway is not None:
            gateway.stop()
        scene.stop()
    print("stopped.", file=sys.stderr, flush=True)


async def _watch_link(link) -> None:
    """Return (with a CommandError) if a task of the link thread fails; never if there is none."""
    from rovlink.command import CommandError

    while True:
        await asyncio.sleep(0.5)
        failure = link.failed() if link is not None else None
        if failure is not None:
            raise CommandError(f"the link stopped: {failure!r}")


def _stop_on_signals() -> asyncio.Event:
    """SIGINT/SIGTERM set the returned event; a second one exits at once.

    Ours rather than uvicorn's: uvicorn re-raises the signal after its own
    shutdown, and the KeyboardInterrupt would cut the vehicle side's teardown
    (simulator, bridge threads) short and leave the process hanging.
    """
    import os
    import signal

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    def on_signal() -> None:
        if stop.is_set():
            print("forced exit", file=sys.stderr, flush=True)
            os._exit(130)
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, on_signal)
        except (NotImplementedError, RuntimeError):  # not the main thread, or no such signal here
            pass
    return stop
