"""`rovlink bench ...`: benchmarks that print a table (and JSON with --json).

Each benchmark module exposes `add_parser(subparsers)`; add new ones to
BENCH_MODULES.
"""

from __future__ import annotations

import importlib

BENCH_MODULES = [
    "rovlink.console.bench.link",
    "rovlink.console.bench.console",
    "rovlink.console.bench.debt",
]


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench",
        help="run a benchmark and print its figures",
        description="Benchmarks: each prints a table, or JSON with --json.",
    )
    inner = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK", parser_class=type(parser))
    inner.required = True
    for name in BENCH_MODULES:
        importlib.import_module(name).add_parser(inner)
