"""`rovlink replay` and `rovlink plot`: recorded sessions."""

from __future__ import annotations

from rovlink.command import positive

from .serve import add_server_arguments

# As console/replaycontrol.py (not imported here: the CLI must start without the console extra).
MIN_SPEED, MAX_SPEED = 0.1, 64.0


def replay_speed(text: str) -> float:
    import argparse

    value = positive(text)
    if not MIN_SPEED <= value <= MAX_SPEED:
        raise argparse.ArgumentTypeError(f"must be within {MIN_SPEED:g}..{MAX_SPEED:g}, got {text!r}")
    return value


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("replay", help="play a recorded session back into the console, on a timeline",
                              description="Serve the console and play FILE's frames into it with their timing. "
                              "The page shows a timeline above its panel: pause and play, drag the slider to "
                              "go to any moment (back or forward), change the speed; scripts use GET /api/replay "
                              "and POST /api/replay/pause, /resume, /seek {t}, /speed {speed}. Nothing is sent "
                              "to any vehicle.")
    p.add_argument("file", metavar="FILE", help="a session recording (runs/session-*.jsonl)")
    p.add_argument("--speed", type=replay_speed, default=1.0,
                   help=f"playback speed factor, {MIN_SPEED:g}..{MAX_SPEED:g} (default 1; changeable on the timeline)")
    p.add_argument("--paused", action="store_true", help="start paused at the beginning (press play on the timeline)")
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
    from rovlink.console.recording import RecordingError, is_acoustic
    from rovlink.console.replaycontrol import ReplayController
    from rovlink.console.session.radio import Operator

    from .serve import serve_operator

    try:
        if is_acoustic(args.file):
            from rovlink.console.session.acoustic import AcousticSession

            operator = AcousticSession(None, None)  # no link, no key: what was recorded, shown as it was
        else:
            operator = Operator(None)
    except RecordingError as exc:
        raise CommandError(str(exc)) from None
    try:
        controller = ReplayController(operator, args.file, speed=args.speed, paused=args.paused)
    except RecordingError as exc:
        raise CommandError(str(exc)) from None

    async def play() -> None:
        controller.start()
        try:
            await asyncio.Event().wait()  # until the server stops
        finally:
            controller.close()

    async def main() -> None:
        state = "paused" if args.paused else f"at x{args.speed:g}"
        await serve_operator(operator, args, background=[play()],
                             banner=f"rovlink replay of {args.file} ({controller.duration:.1f} s) {state}: "
                                    "a timeline on the page to pause, seek and change speed")

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
