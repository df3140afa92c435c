# The DEBT stream header: what the decoder must know before the first coded bit.
#
# Header, most significant bit first, then padded to a byte with a check:
#     MAGIC:4 (1000)  COLOUR:1  REVERSIBLE:1  ROI:1  WIDTH:10  HEIGHT:10  TOP:6
#     if ROI:  SHIFT:4  X0:10  Y0:10  X1:10  Y1:10
#     else:    FILTER:1 (a 9/7 stream with a restoration filter, `restore`)
#     CHECK: the remaining bits of the last byte (6 without ROI, 3 with),
#            the low bits of a CRC-8 of the header with CHECK zero
# so 5 bytes without a region of interest and 10 with one.  The decomposition
# depth follows from the size (`transform.levels_for`); TOP is the highest
# bit plane coded.
#
# TOP = 63 with REVERSIBLE = 1 and no ROI marks a two-level stream (`twolevel`:
# pictures of exactly two colours), TOP = 62 a two-level mask followed by a
# residual stream (pictures of mostly two colours), TOP = 61 a 9/7 stream with
# wavelet packets (its own top plane in the byte after the header, with the
# split it names; splits along the edges, named 0 there, say how many in
# one byte more: `codec._packet_stream`): plane counts the wavelet never
# reaches.

from __future__ import annotations

from dataclasses import dataclass

# The magic names the stream format: 1011 was format 1 (before colour
# pictures were coded in their own rotation of RGB and the finest bands at
# their synthesis norm, rovlink's DEBT before November 2026), 1010 format 2
# (before issue 40's contexts: significance and set decisions by where they
# come from, coder.py), 1001 format 3 (before the restoration filter and the
# header's FILTER bit, restore.py), 1000 is format 4.  A decoder refuses a format it does
# not speak with a clear error instead of showing a wrong picture (an old
# recording, or an ROV and a console of different versions).  No format may
# begin 0110: a picture's TRACK record does (docs/PROTOCOL.md §10).
MAGIC = 0b1000
OLD_FORMATS = {0b1011: 1, 0b1010: 2, 0b1001: 3}
FORMAT = 4


class IncompleteStream(ValueError):
    """The bytes do not yet hold the header: wait for more (not an error in the stream)."""
MAX_SIDE = 1023          # 10-bit sizes and ROI corners, as in the IMAGE order
MAX_SHIFT = 15
FRACTION_BITS = 4        # 9/7 magnitudes are coded down to 1/16 of a unit
TWO_LEVEL_TOP = 63       # see above
RESIDUAL_TOP = 62        # likewise: a two-level mask, then a residual stream
PACKET_TOP = 61          # likewise: a 9/7 stream with wavelet packets (codec._packet_stream)


@dataclass(frozen=True)
class Header:
    width: int
    height: int
    colour: bool
    reversible: bool
    top: int
    roi: tuple[int, int, int, int] | None = None
    shift: int = 0
    filtered: bool = False       # FILTER: never with a region of interest

    @property
    def two_level(self) -> bool:
        return self.reversible and self.roi is None and self.top == TWO_LEVEL_TOP

    @property
    def mask_and_residual(self) -> bool:
        return self.reversible and self.roi is None and self.top == RESIDUAL_TOP

    @property
    def packets(self) -> bool:
        return self.reversible and self.roi is None and self.top == PACKET_TOP

    @property
    def size(self) -> int:
        return header_size(self.roi is not None)


def header_size(has_roi: bool) -> int:
    return 10 if has_roi else 5


def _crc8_step(crc: int) -> int:
    # One byte's eight shifts of the CRC-8 (polynomial 0x07).
    for _ in range(8):
        crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


# The eight shifts of every value, looked up once a byte (every decode checks
# a header: 5.5 -> ~1 us in Python).
_CRC8_TABLE = tuple(_crc8_step(v) for v in range(256))


def _crc8(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc = _CRC8_TABLE[crc ^ byte]
    return crc


def pack_header(h: Header) -> bytes:
    fields = [(MAGIC, 4), (int(h.colour), 1), (int(h.reversible), 1), (int(h.roi is not None), 1),
              (h.width, 10), (h.height, 10), (h.top, 6)]
    if h.roi is not None:
        fields.append((h.shift, 4))
        fields.extend((v, 10) for v in h.roi)
    else:
        fields.append((int(h.filtered), 1))
    value = 0
    nbits = 0
    for v, n in fields:
        value = (value << n) | v
        nbits += n
    size = h.size
    check_bits = 8 * size - nbits
    value <<= check_bits
    raw = value.to_bytes(size, "big")
    check = _crc8(raw) & ((1 << check_bits) - 1)
    return (value | check).to_bytes(size, "big")


def unpack_header(data: bytes) -> Header:
    if len(data) < 1:
        raise IncompleteStream("empty DEBT stream")
    if data[0] >> 4 in OLD_FORMATS:
        raise ValueError(f"a DEBT stream of format {OLD_FORMATS[data[0] >> 4]} (an older rovlink's): "
                         f"this version decodes format {FORMAT} only")
    if data[0] >> 4 != MAGIC:
        raise ValueError("not a DEBT stream (bad magic)")
    has_roi = bool(data[0] & 0x02)
    size = header_size(has_roi)
    if len(data) < size:
        raise IncompleteStream(f"DEBT stream of {len(data)} bytes is shorter than its {size}-byte header")
    value = int.from_bytes(data[:size], "big")
    nbits = 8 * size

    pos = 0

    def take(n: int) -> int:
        nonlocal pos
        pos += n
        return (value >> (nbits - pos)) & ((1 << n) - 1)

    take(4)
    colour = bool(take(1))
    reversible = bool(take(1))
    take(1)
    width = take(10)
    height = take(10)
    top = take(6)
    roi = None
    shift = 0
    filtered = False
    if has_roi:
        shift = take(4)
        roi = (take(10), take(10), take(10), take(10))
    else:
        filtered = bool(take(1))
    check_bits = nbits - pos
    check = value & ((1 << check_bits) - 1)
    expected = _crc8((value & ~((1 << check_bits) - 1)).to_bytes(size, "big")) & ((1 << check_bits) - 1)
    if check != expected:
        raise ValueError("corrupted DEBT header (check bits do not match)")
    if width < 1 or height < 1:
        raise ValueError("corrupted DEBT header (zero image size)")
    if roi is not None:
        x0, y0, x1, y1 = roi
        if not (x0 < x1 <= width and y0 < y1 <= height) or not 1 <= shift <= MAX_SHIFT:
            raise ValueError("corrupted DEBT header (region of interest outside the image)")
    h = Header(width, height, colour, reversible, top, roi, shift, filtered)
    if filtered and reversible and not h.packets:
        raise ValueError("corrupted DEBT header (a restoration filter on a stream that has none)")
    if top > max_top(h) and not (h.two_level or h.mask_and_residual or h.packets):
        raise ValueError("corrupted DEBT header (bit-plane count out of range)")
    return h


def max_top(h: Header) -> int:
    # Generous bound on the top plane a real image can produce.
    return 20 + FRACTION_BITS + h.shift + (3 if h.reversible else 0)
