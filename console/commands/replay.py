"""`rovlink replay` and `rovlink plot`: recorded sessions."""

from __future__ import annotations

from rovlink.command import positive
from .serve import add_server_arguments


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("replay", help="play a recorded session back into the console",
                              description="Serve the console and play FILE's frames into it with their timing.")
    p.add_argument("file", metavar="FILE", help="a session recording (runs/session-*.jsonl)")
    p.add_argument("--speed", type=positive, default=1.0, help="playback speed factor (default 1)")
    add_server_arguments(p)
    p.set_defaults(func=run_replay)

    q = subparsers.add_parser("plot", help="write Fig. 4 and Fig. 5 style plots of a recorded session",
                              description="Write fig4_link_timelapse.png (link events) and fig5_velocity.png "
                              "(commanded vs received velocity) for FILE.")
    q.add_argument("file", metavar="FILE", help="a session recording (runs/session-*.jsonl)")
    q.add_argument("--out", default=".", metavar="DIR", help="folder for the PNG files (default .)")
    q.add_argument("--window", type=positive, metavar="S", help="plot only the first S seconds")
    q.set_defaults(func=run_plot)


def run_replay(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    import asyncio

    from rovlink.command import CommandError
    from rovlink.console.operator import Operator
    from rovlink.console.recording import RecordingError, read_records, replay

    from .serve import serve_operator

    try:
        next(iter(read_records(args.file)))
    except RecordingError as exc:
        raise CommandError(str(exc)) from None

    async def main() -> None:
        operator = Operator(None)
        await serve_operator(operator, args, banner=f"rovlink replay of {args.file} at x{args.speed:g}",
                             background=[replay(operator, args.file, speed=args.speed)])

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    return 0


def run_plot(args) -> int:
    from rovlink.command import require_console_extra

    require_console_extra()
    from rovlink.command import CommandError
    from rovlink.console.recording import RecordingError, plot

    try:
        paths = plot(args.file, args.out, window_s=args.window)
    except RecordingError as exc:
        raise CommandError(str(exc)) from None
    for path in paths:
        print(path)
    return 0
