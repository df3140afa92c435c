"""The `rovlink` command: one entry point, one subcommand per program.

Each command lives beside its package and exposes `add_parser(subparsers)`
(see rovlink/command.py): `rovlink.rov.cli` (rov, sim), `rovlink.link.cli`
(keygen, channel), `rovlink.debt.cli` (debt encode/decode), and the
console's own under `rovlink.console.commands` (console, demo, replay,
plot); `rovlink bench` is a group of benchmarks, each beside what it
measures.

The dispatcher imports only the module that defines the command asked for
(`COMMANDS`, `BENCHMARKS`): `rovlink rov` on the ROV's base install never
imports the console, nor anything of its extra; the console's commands say
which install they lack.  `rovlink --help`, and a name no table knows (so
that argparse lists the choices), import every command module; those are
light, their heavy imports wait inside each command's `func`.

Errors: a wrong argument prints one line and exits with status 2; a command
that fails at run time prints one line and exits with status 1 (2 when an
optional part is missing); Ctrl-C exits with 130 and no traceback.
"""

from __future__ import annotations

import faulthandler
import importlib
import sys
from typing import Sequence

from rovlink.command import CommandError, Parser

BENCH = "bench"

# Each subcommand and the module that defines it, in the order `rovlink --help`
# lists them (a module's commands in its own order).  BENCH is the group below.
COMMANDS = {
    "rov": "rovlink.rov.cli",
    "sim": "rovlink.rov.cli",
    "seabed": "rovlink.rov.cli",
    "channel": "rovlink.link.cli",
    "keygen": "rovlink.link.cli",
    "debt": "rovlink.debt.cli",
    "console": "rovlink.console.commands.console",
    "demo": "rovlink.console.commands.demo",
    "replay": "rovlink.console.commands.replay",
    "plot": "rovlink.console.commands.replay",
    BENCH: __name__,
}

# `rovlink bench NAME`: each benchmark and its module, beside what it measures.
BENCHMARKS = {
    "link": "rovlink.link.bench",
    "console": "rovlink.console.bench.console",
    "debt": "rovlink.debt.bench",
    "camera": "rovlink.rov.camerabench",
    "roi": "rovlink.rov.roibench",
    "objects": "rovlink.rov.objectbench",
}


def _first_word(argv: Sequence[str]) -> str | None:
    return next((a for a in argv if not a.startswith("-")), None)


def _modules_for(table: dict[str, str], argv: Sequence[str]) -> list[str]:
    """The module of the command `argv` names, or every module of `table` (in order)."""
    word = _first_word(argv)
    if word in table:
        return [table[word]]
    return list(dict.fromkeys(table.values()))


def _add_bench(subparsers, argv: Sequence[str]) -> None:
    parser = subparsers.add_parser(
        BENCH,
        help="run a benchmark and print its figures",
        description="Benchmarks: each prints a table, or JSON with --json.",
    )
    inner = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", parser_class=Parser)
    inner.required = True
    for name in _modules_for(BENCHMARKS, argv):
        importlib.import_module(name).add_parser(inner)


def build_parser(argv: Sequence[str] = ()) -> Parser:
    """The parser for `argv`: with its command's arguments only (all for --help)."""
    parser = Parser(
        prog="rovlink",
        description=(
            "Teleoperate an underwater ROV over a narrow (~1.9 kbit/s) radio or "
            "acoustic link: link protocol, DEBT image codec, ROV node and console."
        ),
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    subparsers.required = True
    for name in _modules_for(COMMANDS, argv):
        if name == __name__:
            rest = argv[list(argv).index(BENCH) + 1:] if _first_word(argv) == BENCH else ()
            _add_bench(subparsers, rest)
        else:
            importlib.import_module(name).add_parser(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # A crash in compiled code (numba, a C extension) then leaves every
    # thread's Python stack on stderr instead of a bare "Segmentation fault".
    if not faulthandler.is_enabled():
        try:
            faulthandler.enable()
        except (ValueError, OSError, AttributeError):  # no usable stderr
            pass
    args = build_parser(argv).parse_args(argv)
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
