"""The `rovlink` command: one entry point, one subcommand per program.

Each command lives beside its package and exposes `add_parser(subparsers)`
(see rovlink/command.py): `rovlink.link.cli` (channel), `rovlink.debt.cli`
(debt encode/decode), `rovlink.rov.cli` (rov, sim), and the console's own
under `rovlink.console.commands` (console, demo, replay, plot, bench).  This
module only dispatches and imports nothing of the console's extra, so the
base install (what the ROV needs) runs `rovlink rov`, `sim`, `channel` and
`debt`; the others say which command installs what they lack.

Errors: a wrong argument prints one line and exits with status 2; a command
that fails at run time prints one line and exits with status 1 (2 when an
optional part is missing); Ctrl-C exits with 130 and no traceback.
"""

from __future__ import annotations

import importlib
import sys

from rovlink.command import CommandError, Parser

# Modules that define subcommands, in the order `rovlink --help` lists them.
COMMAND_MODULES = [
    "rovlink.rov.cli",
    "rovlink.link.cli",
    "rovlink.debt.cli",
    "rovlink.console.commands.console",
    "rovlink.console.commands.demo",
    "rovlink.console.commands.replay",
    "rovlink.console.commands.bench",
]


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
        return exc.exit_status
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
