"""What every `rovlink` subcommand shares: its one-line errors and its
argument types.

A subcommand module exposes `add_parser(subparsers)`, which registers its
arguments and sets `func`.  Heavy imports happen inside `func`, so that
`rovlink --help` stays fast and so that the commands of the base install
(`rov`, `sim`, `channel`, `debt`) never import the console's extra.

Errors: a wrong argument is one line and exit status 2 (argparse's
convention); a command that fails at run time raises `CommandError`, printed
as one line with exit status 1; a command whose packages are not installed
raises `MissingExtra`: one line naming the install command, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib.util
import math


class CommandError(Exception):
    """A failure a user can act on; printed as one line, exit status 1."""

    exit_status = 1


class UsageError(CommandError):
    """Arguments that cannot run together (or a missing one), found after parsing: exit status 2."""

    exit_status = 2


def link_key(args):
    """The link key named by --key, None with --insecure (protocol version 1.1);
    `args` of a parser given `add_key_arguments`.

    Neither: a UsageError naming `rovlink keygen`; a key file that is missing,
    malformed or readable by others: a CommandError."""
    if args.key and args.insecure:
        raise UsageError("--key and --insecure exclude each other")
    if args.insecure:
        return None
    if not args.key:
        raise UsageError("the link needs a key: --key FILE (make one with: rovlink keygen FILE), "
                         "or --insecure to run protocol version 1.1 unauthenticated")
    from rovlink.link.radio.auth import KeyFileError, read_key_file

    try:
        return read_key_file(args.key)
    except KeyFileError as exc:
        raise CommandError(str(exc)) from None


def check_frame_size(endpoint, key) -> None:
    """Version 2 needs frames of at least a SYNC reply (docs/PROTOCOL.md §8): a
    smaller `mtu` is a CommandError before anything starts."""
    from rovlink.link.radio.secure import SYNC_FRAME_BYTES

    max_frame = endpoint.max_frame
    if key is not None and max_frame is not None and max_frame < SYNC_FRAME_BYTES:
        raise CommandError(f"mtu={max_frame}: link version 2 needs frames of at least {SYNC_FRAME_BYTES} bytes "
                           f"(a SYNC reply); raise the mtu, or use --insecure (version 1.1)")


def add_key_arguments(p) -> None:
    p.add_argument("--key", metavar="FILE",
                   help="the link key (rovlink keygen FILE): protocol version 2, every frame authenticated")
    p.add_argument("--insecure", action="store_true",
                   help="no key: protocol version 1.1, frames not authenticated (anyone in range can drive)")


class MissingExtra(CommandError):
    """The command needs an optional part of rovlink that is not installed."""

    exit_status = 2


# The packages of the `console` extra (pyproject.toml), by import name.
CONSOLE_EXTRA = ("viser", "fastapi", "uvicorn", "websockets", "trimesh", "matplotlib")


def require_console_extra() -> None:
    """Raise MissingExtra unless the console's packages can be imported."""
    missing = [name for name in CONSOLE_EXTRA if importlib.util.find_spec(name) is None]
    if missing:
        raise MissingExtra(
            f"needs the console extra ({', '.join(missing)} not installed): "
            "python3 -m pip install 'rovlink[console]'"
        )


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, with a pointer to --help."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def positive(text: str) -> float:
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def non_negative(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text}")
    return value


def probability(text: str) -> float:
    """A rate in [0, 1): bit error rate, packet loss."""
    value = _number(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text}")
    return value


def positive_int(text: str) -> int:
    """A whole number, at least 1: a count or a byte budget."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a port number, got {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port 1..65535, got {text}")
    return value
