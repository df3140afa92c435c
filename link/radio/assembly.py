"""One image object put together from its trunks (docs/PROTOCOL.md §4), written once
for the master and for a recording's replay.

The object is a two-byte big-endian length and the DEBT stream; trunks carry
OFFSET into it.  What is held is the contiguous prefix received: a trunk that
starts past its end is not taken (a conforming ROV never sends one, since each
poll asks for the next OFFSET), a trunk that overlaps it is taken from its
OFFSET on (a resend of a lost reply), and nothing is kept past the length the
object says it has.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .messages import OBJECT_LENGTH_BYTES as LENGTH_BYTES


@dataclass
class ImageAssembly:
    img: int
    started_at: float | None = None
    data: bytearray = field(default_factory=bytearray)

    @property
    def total(self) -> int | None:
        """The object's length (its length field and stream), once known."""
        if len(self.data) < LENGTH_BYTES:
            return None
        return LENGTH_BYTES + int.from_bytes(self.data[:LENGTH_BYTES], "big")

    @property
    def complete(self) -> bool:
        total = self.total
        return total is not None and len(self.data) >= total

    @property
    def stream(self) -> bytes:
        """The DEBT stream received so far (a prefix of it, or all of it)."""
        return bytes(self.data[LENGTH_BYTES:])

    def add(self, offset: int, trunk: bytes) -> bool:
        """Take a trunk; False when it starts past the prefix held (not taken)."""
        if offset > len(self.data):
            return False
        if offset + len(trunk) > len(self.data):
            self.data[offset:] = trunk
        total = self.total
        if total is not None and len(self.data) > total:
            del self.data[total:]
        return True
