"""The `rovlink` command: one entry point, one subcommand per program.

Each subcommand lives in its own module under `console.commands` (or
`console.bench` for benchmarks) and exposes `add_parser(subparsers)`, which
registers its arguments and sets `func` to the function that runs it.  Heavy
imports happen inside those functions so that `rovlink --help` stays fast.

Errors: a wrong argument prints one line and exits with status 2 (argparse's
convention); a command that fails at run time raises `CommandError`, printed
as one line with exit status 1.  Ctrl-C exits with 130 and no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# Modules that define subcommands, in the order `rovlink --help` lists them.
COMMAND_MODULES = [
    "rovlink.console.commands.channel",
    "rovlink.console.commands.bench",
    "rovlink.console.commands.rov",
    "rovlink.console.commands.sim",
    "rovlink.console.commands.console",
    "rovlink.console.commands.demo",
    "rovlink.console.commands.replay",
    "rovlink.console.commands.debt",
]


class CommandError(Exception):
    """A failure a user can act on; printed as one line, exit status 1."""


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, with a pointer to --help."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> Parser:
    parser = Parser(
        prog="rovlink",
        description=(
            "Teleoperate an underwater ROV over a narrow (~1.9 kbit/s) radio or "
            "acoustic link: link protocol, DEBT image codec, ROV node and console."
        ),
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    subparsers.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.func(args)
    except CommandError as exc:
        print(f"rovlink {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
