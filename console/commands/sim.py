"""`rovlink sim`: the simulated ArduSub alone, as a MAVLink endpoint.

Goal: a stand-in for the vehicle that any ground station can talk to — the ROV
node (`rovlink rov --mavlink ...`), QGroundControl, MAVProxy, a pymavlink script.
The default copies BlueOS: the vehicle sends to a ground station listening on
UDP 14550 of this machine.  `--mavlink tcpin:127.0.0.1:5760` copies ArduSub SITL.
Servers bind to loopback unless told otherwise.
"""

from __future__ import annotations

DEFAULT_URL = "udpout:127.0.0.1:14550"


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "sim",
        help="run the simulated ArduSub vehicle alone, as a MAVLink endpoint",
        description=(
            "Run the simulated BlueROV/ArduSub (4-DOF model, ArduSub modes, pilot-input "
            "failsafe) as a MAVLink endpoint in real time. Ground stations connect to it "
            "like to the real vehicle, e.g. 'rovlink rov --mavlink udpin:127.0.0.1:14550' "
            "with the default, or '--mavlink tcp:127.0.0.1:5760' with --mavlink tcpin:127.0.0.1:5760."
        ),
    )
    p.add_argument("--mavlink", default=DEFAULT_URL, metavar="URL",
                   help=f"where to serve (pymavlink syntax): udpout:HOST:PORT sends to a ground "
                        f"station, udpin:HOST:PORT and tcpin:HOST:PORT wait for one (default {DEFAULT_URL})")
    p.add_argument("--system-id", type=int, default=1, metavar="N", help="the vehicle's MAVLink system id (default 1)")
    p.add_argument("--depth", type=float, default=None, metavar="M",
                   help="starting depth in metres (default: 2 m above the simulated seabed)")
    p.add_argument("--no-position", action="store_true",
                   help="no position estimate (no DVL/GPS): GUIDED and POSHOLD are refused, no LOCAL_POSITION_NED")
    p.add_argument("--pilot-timeout", type=float, default=3.0, metavar="S",
                   help="disarm after this long without MANUAL_CONTROL while armed (ArduSub: 3 s)")
    p.add_argument("--status-every", type=float, default=2.0, metavar="S",
                   help="print the vehicle's state every S seconds; 0 for never (default 2)")
    p.add_argument("-v", "--verbose", action="store_true", help="log every mode change, arming and refusal")
    p.set_defaults(func=run)


def run(args) -> int:
    import logging
    import math
    import sys
    import time

    from rovlink.console.cli import CommandError
    from rovlink.rov.mavurl import parse_mavlink_url
    from rovlink.rov.scene import SEABED_DEPTH_M
    from rovlink.rov.simulator import START_STATE, SimulatedVehicle
    from rovlink.rov.vehicle import SubMode, VehicleState

    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        url = parse_mavlink_url(args.mavlink)
    except ValueError as exc:
        raise CommandError(f"--mavlink: {exc}") from None
    if url.kind in ("udpin", "tcpin") and url.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"sim: warning: listening on {url.host}, reachable from other machines", file=sys.stderr)
    if not 1 <= args.system_id <= 255:
        raise CommandError("--system-id must be 1..255")
    if args.pilot_timeout <= 0 or not math.isfinite(args.pilot_timeout):
        raise CommandError("--pilot-timeout must be a positive number of seconds")
    state = START_STATE
    if args.depth is not None:
        if not 0.0 <= args.depth < SEABED_DEPTH_M:
            raise CommandError(f"--depth must be within 0..{SEABED_DEPTH_M:g} m (the seabed)")
        state = VehicleState(z_m=args.depth)

    sim = SimulatedVehicle(
        args.mavlink,
        system_id=args.system_id,
        initial_state=state,
        has_position=not args.no_position,
        pilot_timeout_s=args.pilot_timeout,
    )
    try:
        sim.start()
    except OSError as exc:
        raise CommandError(f"cannot open {args.mavlink}: {exc}") from None
    print(f"sim: simulated ArduSub (system {args.system_id}) on {url.device.replace(':0', f':{sim.port}')}; "
          f"a ground station connects with --mavlink {sim.bridge_url}; Ctrl-C stops", file=sys.stderr, flush=True)
    try:
        while True:
            if args.status_every > 0:
                time.sleep(args.status_every)
                t = sim.truth()
                s = t.state
                try:
                    mode = SubMode(t.mode).name
                except ValueError:
                    mode = str(t.mode)
                print(f"sim: {'ARMED' if t.armed else 'disarmed'} {mode:9s} x {s.x_m:6.2f} y {s.y_m:6.2f} "
                      f"z {s.z_m:5.2f} m  yaw {math.degrees(s.yaw_rad):6.1f} deg  "
                      f"pilot x {t.pilot.x} y {t.pilot.y} z {t.pilot.z} r {t.pilot.r}", file=sys.stderr, flush=True)
            else:
                time.sleep(3600)
    finally:
        sim.stop()
    return 0
