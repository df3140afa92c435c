"""`rovlink demo`: the whole system on this machine, one command."""

from __future__ import annotations

from rovlink.command import non_negative, positive, probability

from .serve import add_gcs_arguments, add_server_arguments

PORT_TRIES = 4  # fresh UDP ports this many times when one was taken before it was bound


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
    p.add_argument("--seabed", metavar="PNG", help="the simulated seabed: a PNG with its JSON of objects beside it "
                   "('rovlink seabed' writes them; default: the committed one)")
    p.add_argument("--insecure", action="store_true",
                   help="run the link's version 1.1, unauthenticated (default: version 2 with a throwaway key)")
    p.add_argument("--record", metavar="FILE", help="session recording (default runs/session-TIME.jsonl)")
    p.add_argument("--no-record", action="store_true", help="do not record the session")
    p.set_defaults(func=run)


def run(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    import asyncio
    import os
    import sys

    from rovlink.command import CommandError
    from rovlink.console.linkthread import LinkThread
    from rovlink.console.session.radio import Operator
    from rovlink.console.stack import StackConfig
    from rovlink.console.vehicleside import PORT_TAKEN
    from rovlink.link.process import MasterProcess
    from rovlink.link.transports.transport import TransportError, free_udp_port
    from rovlink.link.transports.urls import open_transport

    from .serve import check_ports, default_record_path, serve_operator

    if args.seabed:
        from rovlink.rov.cli import load_seabed

        load_seabed(args.seabed)  # a bad PNG or JSON: one line, before anything starts
    check_ports(args)  # before any banner, recording or link
    # Both ends run here: a throwaway key for this session (docs/PROTOCOL.md §8).
    key = None if args.insecure else os.urandom(32)
    config = StackConfig(bitrate_bps=args.bitrate, delay_s=args.delay, ber=args.ber, seed=args.seed,
                         camera=args.camera, key=key, seabed=args.seabed, objects=True)
    args.rov_failsafe = config.failsafe_s  # the page infers the ROV's failsafe from it
    compile_codec()
    record = None if args.no_record else (args.record or default_record_path())
    channel_log = None if record is None else str(record).replace(".jsonl", "") + ".channel.jsonl"
    # Two loopback UDP ports, chosen free and bound a moment later: another program
    # may take one in between (a CI run's other tests did).  This end is bound
    # before the vehicle side starts; either end finding its port taken means new
    # ports, a few times, then the error.
    link = LinkThread().start()
    for attempt in range(1, PORT_TRIES + 1):
        console_port, vehicle_port = free_udp_port(), free_udp_port()
        endpoint = open_transport(f"udp://127.0.0.1:{console_port}?peer=127.0.0.1:{vehicle_port}")
        try:
            link.call_sync(endpoint.start())
        except TransportError as exc:
            if "Address already in use" in str(exc) and attempt < PORT_TRIES:
                print(f"rovlink demo: UDP port {console_port} was taken meanwhile; trying others", file=sys.stderr)
                continue
            link.stop_sync()
            raise CommandError(f"could not start the demo: {exc}") from None
        # The vehicle side (simulated ArduSub, bridge, camera, ROV node, emulated channel) in a
        # process of its own, as on a real ROV: the page and the web server cannot starve it.
        vehicle = VehicleProcess(config, udp=vehicle_port, peer=console_port)
        try:
            vehicle.ready(channel_log)
            break
        except CommandError:
            taken = vehicle.exit_status() == PORT_TAKEN
            vehicle.stop()
            link.call_sync(endpoint.close())
            if taken and attempt < PORT_TRIES:
                print(f"rovlink demo: UDP port {vehicle_port} was taken meanwhile; trying others", file=sys.stderr)
                continue
            link.stop_sync()
            raise

    # The link (transport, master, its clock) in a process of its own (link/process.py), on the
    # port found free above: this process's page, scene and decoding never delay a poll.
    max_frame = endpoint.max_frame
    link.call_sync(endpoint.close())
    master = MasterProcess(f"udp://127.0.0.1:{console_port}?peer=127.0.0.1:{vehicle_port}",
                           bitrate_bps=config.bitrate_bps, delay_s=config.delay_s, max_frame=max_frame, t0=0.0)

    async def main() -> None:
        operator = Operator(None, master=master, bitrate_bps=config.bitrate_bps, delay_s=config.delay_s,
                            record=record, image_settings=config.image_settings)
        if key is not None:
            operator.authenticate(key)
        link.spawn(operator.run(), name="operator")
        try:
            await serve_operator(
                operator, args, link=link, sim_seabed=True,
                banner=(f"rovlink demo: simulated ROV (its own process) over an emulated {args.bitrate:g} bit/s "
                        f"link ({args.delay * 1000:g} ms delay, BER {args.ber:g}); "
                        + ("INSECURE: link version 1.1, frames not authenticated" if key is None else
                           "link version 2, every frame authenticated (a throwaway key for this session)")
                        + (f"; recording to {record}" if record else "")),
            )
        finally:
            await link.stop()
            operator.close()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.stop()
    return 0


def compile_codec(say_after_s: float = 30.0) -> None:
    """DEBT's kernels compiled (and cached on disk) before the link starts.

    On a fresh install numba compiles them on first use: half a minute to a minute
    on a 2-core machine, in both the vehicle side and the console at once, which
    starved the link (LINK LOST, then the ROV's FAILSAFE) and kept the first
    picture waiting.  Done here once, with progress said; later runs load the cache
    in half a second and say nothing.  Whether it compiles is known from the cache (a
    warm-up that ran to its end on these sources marks it, `debt.jit.warmed`), not
    guessed from the time: loading took 6 s on a loaded machine and read as a compile
    (a suite run's test_first_run).
    Uncached: said at once; cached but still at it after `say_after_s`: said then."""
    import sys
    import threading
    import time

    from rovlink import debt
    from rovlink.debt import jit

    started, cached = time.monotonic(), jit.warmed()
    worker = threading.Thread(target=debt.warm_up, name="debt-compile", daemon=True)
    worker.start()
    worker.join(say_after_s if cached else 0.0)
    if not worker.is_alive():
        return
    print("compiling the image codec for this machine (first run only; cached for the next)...",
          file=sys.stderr, flush=True)
    while worker.is_alive():
        worker.join(10.0)
        if worker.is_alive():
            print(f"  still compiling, {time.monotonic() - started:.0f} s", file=sys.stderr, flush=True)
    print(f"image codec ready in {time.monotonic() - started:.0f} s", file=sys.stderr, flush=True)


class VehicleProcess:
    """`python -m rovlink.console.vehicleside` as a child: started, told its key,
    waited for, stopped (closing its stdin; terminated if it lingers)."""

    def __init__(self, config, *, udp: int, peer: int) -> None:
        self.config, self.udp, self.peer = config, udp, peer
        self.proc = None

    def ready(self, channel_log: str | None, timeout_s: float = 120.0) -> None:
        import subprocess
        import sys
        from pathlib import Path

        from rovlink.command import CommandError

        c = self.config
        argv = [sys.executable, "-m", "rovlink.console.vehicleside", "--udp", str(self.udp), "--peer", str(self.peer),
                "--bitrate", repr(c.bitrate_bps), "--delay", repr(c.delay_s), "--ber", repr(c.ber),
                "--seed", str(c.seed), "--camera", c.camera, "--failsafe", repr(c.failsafe_s),
                "--start-depth", repr(c.start_depth_m)]
        if channel_log:
            argv += ["--channel-log", channel_log]
        if c.seabed:
            argv += ["--seabed", str(Path(c.seabed).resolve())]
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.proc.stdin.write(("insecure" if c.key is None else c.key.hex()) + "\n")
        self.proc.stdin.flush()
        line = _read_line(self.proc.stdout, timeout_s)
        if line != "ready":
            code = self.proc.poll()
            raise CommandError("the simulated vehicle side did not start"
                               + (f" (it exited with {code}; its error is above)" if code is not None else
                                  f" within {timeout_s:g} s"))

    def exit_status(self, wait_s: float = 10.0) -> int | None:
        """The vehicle side's exit status, waiting up to `wait_s` for it to end
        (it says its error, then exits); None while it runs."""
        import subprocess

        if self.proc is None:
            return None
        try:
            return self.proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self) -> None:
        import subprocess

        proc, self.proc = self.proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _read_line(stream, timeout_s: float) -> str | None:
    """One line of `stream` within `timeout_s`, stripped; None at its end or on timeout."""
    import threading

    out: list[str] = []
    reader = threading.Thread(target=lambda: out.append(stream.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    return out[0].strip() if out and out[0] else None
