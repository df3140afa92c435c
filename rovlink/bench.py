"""What every `rovlink bench` benchmark prints: an aligned text table, or JSON
(the benchmarks live beside what they measure: link/bench.py, debt/bench.py,
console/bench/)."""

from __future__ import annotations

import json
import statistics
import sys
from typing import Any, Sequence


def quantile(values: Sequence[float], q: float) -> float | None:
    """The q-quantile of `values` (the nearest rank), None when there are none."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, int(round(q * (len(ordered) - 1)))))]


def median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    def cell(value: Any) -> str:
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
        return str(value)

    text_rows = [[cell(v) for v in row] for row in rows]
    widths = [len(h) for h in headers]
    for row in text_rows:
        widths = [max(w, len(c)) for w, c in zip(widths, row)]
    line = "  ".join(h.ljust(w) for h, w in zip(headers, widths))
    rule = "  ".join("-" * w for w in widths)
    body = ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in text_rows]
    return "\n".join([line, rule, *body])


def emit(result: dict[str, Any], table: str, as_json: bool) -> None:
    """Print either the table (with a title) or the JSON document."""
    if as_json:
        json.dump(result, sys.stdout, indent=2, sort_keys=False)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(table.rstrip("\n") + "\n")
