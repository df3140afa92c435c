# DEBT's restoration filter: a small symmetric 2-D filter the encoder fits to
# each picture by least squares against the original and sends in a few
# bytes, which the decoder runs over its 9/7 picture (in the manner of a
# video codec's loop restoration, without the loop): the ringing and blur a
# cut bit plane leaves beside thin lines and points are partly undone.
#
# The filter: out = x + sum_k c_k (x[p + o_k] + x[p - o_k] - 2 x[p]) over the
# 6 offsets o_k of half a cross 7 pixels wide and high (OFFSETS), so it is
# point-symmetric and keeps a flat area (and the picture's mean) as it is.
# Pixels go into classes by their activity (the mean absolute Laplacian over
# 3x3, cut at 1, 2, 4 and 8 grey levels into 5 bins; GROUPINGS join the bins
# into 1-3 classes), each class its own taps or none.  It works on the components before `codec._image`
# (floats: no rounding in between), each component its own filter.
#
# In the stream (a 9/7 stream without a region of interest whose header's
# FILTER bit is set, header.py): right after the header and the bytes naming a
# wavelet packet split, for each component a byte (bits 7-6: the grouping,
# bits 2-0: which of its classes have taps), then 6 signed bytes (taps in
# TAP_STEP units) for each class that has them.  A prefix that does not
# hold the whole filter shows its picture unfiltered (there is none yet but a
# flat one: the coefficients come after).
#
# The encoder (`codec._restored`) fits the taps on its own picture of the
# stream at the full budget (`fit`: normal equations per bin over every
# other pixel, a quincunx), keeps the classes whose fitted gain beats what
# their bytes would have bought in coefficients (COST_SLOPE), codes the
# coefficients again in the budget less the filter's bytes, and keeps the
# filtered stream only when its picture's squared error, reckoned exactly
# from its own state, is below the unfiltered stream's.
#
# Measured with `rovlink bench debt --budgets 1000,2000,4000` against the
# same code without the filter: on the photographs +0.088 dB PSNR mean
# (+0.054/+0.099/+0.112 at 1000/2000/4000 B), no case worse (the encoder's
# check), up to +0.63 (cell/crop at 4000 B); hubble_deep_field-grey/down at
# 4000 B 29.88 -> 30.19 dB (AVIF's worst margin -1.28 -> -0.97 dB), brick/down
# 38.06 -> 38.44; MS-SSIM +0.0007 mean, -0.0045 at worst (grass/down at
# 2000 B: the fit is for squared error).  On the held-out pictures +0.085 dB
# mean, rocket-grey/tr at 4000 B only +0.05 (45.43 -> 45.48: its thin lines
# want more than a cross of taps gives).  A decode of a 320x240 grey picture
# with a filter of three classes ~0.12 ms more (1.07 -> 1.20 ms, 1.10 ->
# 1.33 of OpenJPEG's time; ~0.10 ms since its rows pick a class's taps
# first and make the padded rows in a ring); an encode 2.5 -> 5.8 ms (the fit, ~0.7 ms a
# component, and the second pass of the coder).  Floats without fused
# multiply-adds, so that encoder and decoder round alike on any machine.
#
# Tried and left out: a 7x7 diamond of 12 taps (its classes cost twice the
# bytes and the time; 0.095 dB mean where the cross gave 0.115 in the same
# trial on 12 photographs); classes by the activity at the pixel alone
# (|horizontal| + |vertical second difference|, no 3x3: 0.06 dB mean, below
# one class's 0.075); the fit over a quarter of the pixels (rows alternating
# in brick at 1000 B fitted taps that failed on the rows left out); the taps
# fitted again on the picture of the shorter stream (-0.0005 dB mean);
# eight groupings instead of four (+0.0002 dB); COST_SLOPE 0.35 or 1.4
# instead of 0.7 (-0.0007, -0.0036 dB).

from __future__ import annotations

import threading

import numpy as np

from .jit import _jit

# A cross, three pixels along the row and three down the column each way
# (each offset stands for itself and its mirror).
OFFSETS = np.array([(0, 1), (0, 2), (0, 3), (1, 0), (2, 0), (3, 0)], dtype=np.int64)
NTAPS = 6
MARGIN = 3              # the cross's reach
# Activity: the mean absolute Laplacian (4 x[p] less its 4 neighbours) over
# a pixel's 3x3, in grey levels, cut at 1, 2, 4 and 8 into 5 bins (`_bin`).
NBINS = 5
# bin -> class, named by two bits in the stream.
GROUPINGS = np.array([(0, 0, 0, 0, 0),      # one class
                      (0, 0, 1, 1, 1),      # flat | active (2)
                      (0, 1, 1, 2, 2),      # flat | moderate | busy (1, 4)
                      (0, 0, 1, 1, 2)],     # (2, 8)
                     dtype=np.int64)
# The same classes as activity edges (a class from its edge up, in mean
# absolute Laplacians), for the decoder.
GROUP_EDGES = ((1e30, 1e30), (2.0, 1e30), (1.0, 4.0), (2.0, 8.0))
TAP_STEP = 1.0 / 64
# What a byte of coefficients buys: the squared error falls by about
# COST_SLOPE * error / payload bytes a byte (about 3 dB a doubling of the
# budget at these rates).  A class keeps its taps when their fitted gain
# beats its 6 bytes at this price.
COST_SLOPE = 0.7
# The stream is coded again with the filter (a second pass of the coder)
# only when the fit promises to take away more than this share of the
# squared error (0.01 dB).
WORTH_TRYING = 0.0023
# The fit counts half the pixels, a quincunx: a quarter (every other pixel of
# every other row) let a picture whose rows alternate (brick at 1000 B,
# packets along the edges) fit taps that failed on the rows left out.
SAMPLED = 2.0


@_jit
def _pad_row(a, out):
    # out = a (float32) with MARGIN copies of its end samples either side.
    w = a.shape[0]
    for j in range(w):
        out[j + MARGIN] = a[j]
    for j in range(MARGIN):
        out[j] = a[0]
        out[w + MARGIN + j] = a[w - 1]


@_jit
def _copy_row(a, out):
    for j in range(out.shape[0]):
        out[j] = a[j]


@_jit
def _laplacian_row(up, row, dn, out):
    # out[j] = |4 row[j+1] - row[j] - row[j+2] - up[j+1] - dn[j+1]|: every
    # index from 0, so that the compiler vectorises the loop.
    for j in range(out.shape[0]):
        c = row[j + 1]
        out[j] = abs(c + c + c + c - row[j] - row[j + 2] - up[j + 1] - dn[j + 1])


@_jit
def _three_row(a, out):
    for j in range(out.shape[0]):
        out[j] = a[j] + a[j + 1] + a[j + 2]


@_jit
def _padded(comp, x):
    h = comp.shape[0]
    for y in range(h):
        _pad_row(comp[y], x[y + MARGIN])
    for y in range(MARGIN):
        _copy_row(x[MARGIN], x[y])
        _copy_row(x[h + MARGIN - 1], x[h + MARGIN + y])


@_jit
def activity(comp, x, lap, hsum):
    """The float32 copy of `comp` (h x w) in `x`, MARGIN larger on every
    side with the edge pixels repeated there (a pixel near the border sees
    its neighbours clamped to the picture); then each pixel's activity,
    the sum of the absolute Laplacians over its 3x3, as three rows of
    `hsum` (h + 2 x w: row y + 1 holds row y's horizontal sums; `lap`:
    h + 2 x w + 2, the Laplacians from a pixel outside to one outside)."""
    _padded(comp, x)
    for y in range(comp.shape[0] + 2):
        r = y + MARGIN - 1
        _laplacian_row(x[r - 1, MARGIN - 2:], x[r, MARGIN - 2:], x[r + 1, MARGIN - 2:], lap[y])
        _three_row(lap[y], hsum[y])


@_jit
def _bin(a):
    # The activity bin of a pixel whose activity (`activity`) is `a`.
    return (a >= 9.0) + (a >= 18.0) + (a >= 36.0) + (a >= 72.0)


@_jit
def restoration_stats(x, orig, hsum, f, ata, atb, rr):
    """Normal equations of the taps per activity bin (ata: NBINS x 6 x 6,
    upper triangle; atb: NBINS x 6; rr: NBINS, the squared error
    unfiltered) over a quincunx of pixels (every other one, rows offset by
    one in turn) MARGIN inside the border (`f`: 6 work floats; hsum: `activity`'s)."""
    h, w = x.shape
    for y in range(MARGIN, h - MARGIN):
        for i in range(MARGIN + (y & 1), w - MARGIN, 2):
            c = x[y, i]
            c2 = 2.0 * c
            f[0] = x[y, i + 1] + x[y, i - 1] - c2
            f[1] = x[y, i + 2] + x[y, i - 2] - c2
            f[2] = x[y, i + 3] + x[y, i - 3] - c2
            f[3] = x[y + 1, i] + x[y - 1, i] - c2
            f[4] = x[y + 2, i] + x[y - 2, i] - c2
            f[5] = x[y + 3, i] + x[y - 3, i] - c2
            r = orig[y, i] - c
            b = _bin(hsum[y, i] + hsum[y + 1, i] + hsum[y + 2, i])
            rr[b] += r * r
            for k in range(NTAPS):
                fk = f[k]
                atb[b, k] += fk * r
                for m in range(k, NTAPS):
                    ata[b, k, m] += fk * f[m]


@_jit
def _restore_row(m3, m2, m1, r0, p1, p2, p3, h0, h1, h2, taps, e1, e2, out):
    # The filter along a row, added to `out`: the row and the six around it
    # start MARGIN pixels left of the first output, so that every index is
    # from 0 and the compiler vectorises the loop.  Each pixel's class by
    # its activity (h0 + h1 + h2; the classes' edges e1, e2): its class's
    # taps picked first (a class without taps has zeros), then one sum made
    # (the same products and sums as that class's alone, so the same float;
    # making all three classes' sums and keeping one took 0.068 ms of a
    # 320x240 picture against 0.056).
    a0, a1, a2, a3, a4, a5 = taps[0, 0], taps[0, 1], taps[0, 2], taps[0, 3], taps[0, 4], taps[0, 5]
    b0, b1, b2, b3, b4, b5 = taps[1, 0], taps[1, 1], taps[1, 2], taps[1, 3], taps[1, 4], taps[1, 5]
    c0, c1, c2, c3, c4, c5 = taps[2, 0], taps[2, 1], taps[2, 2], taps[2, 3], taps[2, 4], taps[2, 5]
    for j in range(out.shape[0]):
        act = h0[j] + h1[j] + h2[j]
        g1 = act >= e1
        g2 = act >= e2
        t0 = c0 if g2 else (b0 if g1 else a0)
        t1 = c1 if g2 else (b1 if g1 else a1)
        t2 = c2 if g2 else (b2 if g1 else a2)
        t3 = c3 if g2 else (b3 if g1 else a3)
        t4 = c4 if g2 else (b4 if g1 else a4)
        t5 = c5 if g2 else (b5 if g1 else a5)
        cc = r0[j + 3] + r0[j + 3]
        out[j] += (t0 * (r0[j + 4] + r0[j + 2] - cc) + t1 * (r0[j + 5] + r0[j + 1] - cc)
                   + t2 * (r0[j + 6] + r0[j] - cc) + t3 * (p1[j + 3] + m1[j + 3] - cc)
                   + t4 * (p2[j + 3] + m2[j + 3] - cc) + t5 * (p3[j + 3] + m3[j + 3] - cc))


@_jit
def _restore_row1(m3, m2, m1, r0, p1, p2, p3, taps, out):
    # `_restore_row` for a filter of one class.
    a0, a1, a2, a3, a4, a5 = taps[0, 0], taps[0, 1], taps[0, 2], taps[0, 3], taps[0, 4], taps[0, 5]
    for j in range(out.shape[0]):
        cc = r0[j + 3] + r0[j + 3]
        out[j] += (a0 * (r0[j + 4] + r0[j + 2] - cc) + a1 * (r0[j + 5] + r0[j + 1] - cc)
                   + a2 * (r0[j + 6] + r0[j] - cc) + a3 * (p1[j + 3] + m1[j + 3] - cc)
                   + a4 * (p2[j + 3] + m2[j + 3] - cc) + a5 * (p3[j + 3] + m3[j + 3] - cc))


RING = 8                # padded rows held (the cross's 7, and the next one's slot)


@_jit
def _ring_row(comp, y, ring):
    # Padded row y (`activity`'s x[y]: the picture's row y - MARGIN, clamped
    # into it) into its slot of the ring.
    h = comp.shape[0]
    _pad_row(comp[min(max(y - MARGIN, 0), h - 1)], ring[y & (RING - 1)])


@_jit
def _ring_hsum(ring, y, lap, hring):
    # `activity`'s hsum[y] (the horizontal sums of the absolute Laplacians of
    # the picture's row y - 1) from the padded rows y + 1 .. y + 3 in the ring.
    r = y + MARGIN - 1
    _laplacian_row(ring[(r - 1) & (RING - 1), MARGIN - 2:], ring[r & (RING - 1), MARGIN - 2:],
                   ring[(r + 1) & (RING - 1), MARGIN - 2:], lap)
    _three_row(lap, hring[y & 3])


@_jit
def restore(comp, ring, lap, hring, taps, e1, e2):
    """Run the filter over `comp` (float64) in place: each pixel by the taps
    (grey levels) of its class (3 x 6 float32, zero rows for a class
    without), the classes cut at activities e1 <= e2 (one class when e1 is
    1e30).  ring, lap, hring: `_ring_work`'s.

    Row by row down the picture, `activity`'s padded rows and sums made as
    they are needed, in rings of a few rows (RING padded rows, 4 rows of
    sums), not whole copies of the picture: the same values in the same
    operations, from 0.9 MB of work arrays to 20 kB for a 320x240 picture
    (a decode that follows an encode found them out of the cache).  A
    padded row is made before the rows it reads are filtered: row y + 6 at
    row y, from the picture's row y + 3 or above it, not yet written."""
    h = comp.shape[0]
    one = e1 >= 1e29
    for y in range(2 * MARGIN):
        _ring_row(comp, y, ring)
    if not one:
        _ring_hsum(ring, 0, lap, hring)
        _ring_hsum(ring, 1, lap, hring)
    for y in range(h):
        _ring_row(comp, y + 2 * MARGIN, ring)
        m3 = ring[y & (RING - 1)]
        m2 = ring[(y + 1) & (RING - 1)]
        m1 = ring[(y + 2) & (RING - 1)]
        r0 = ring[(y + 3) & (RING - 1)]
        p1 = ring[(y + 4) & (RING - 1)]
        p2 = ring[(y + 5) & (RING - 1)]
        p3 = ring[(y + 6) & (RING - 1)]
        if one:
            _restore_row1(m3, m2, m1, r0, p1, p2, p3, taps, comp[y])
        else:
            _ring_hsum(ring, y + 2, lap, hring)
            _restore_row(m3, m2, m1, r0, p1, p2, p3, hring[y & 3], hring[(y + 1) & 3], hring[(y + 2) & 3],
                         taps, e1, e2, comp[y])


# ---------------------------------------------------------------- the filter's bytes

class Filter:
    """One component's filter: its grouping, and the taps (int8, TAP_STEP
    units) of each class that has them (None for one that has not)."""

    __slots__ = ("grouping", "taps")

    def __init__(self, grouping: int, taps: list):
        self.grouping = grouping
        self.taps = taps

    @property
    def active(self) -> bool:
        return any(t is not None for t in self.taps)

    def to_bytes(self) -> bytes:
        mask = sum(1 << c for c, t in enumerate(self.taps) if t is not None)
        out = bytearray([self.grouping << 6 | mask])
        for t in self.taps:
            if t is not None:
                out += np.asarray(t, dtype=np.int8).tobytes()
        return bytes(out)

    def kernel_args(self) -> tuple[np.ndarray, np.float32, np.float32]:
        """(taps, 3 x 6 float32 in grey levels; the classes' edges) for `restore`."""
        taps = np.zeros((3, NTAPS), dtype=np.float32)
        for c, t in enumerate(self.taps):
            if t is not None:
                taps[c] = t
        taps *= np.float32(TAP_STEP)    # exact (a power of two), once for all three rows
        e1, e2 = GROUP_EDGES[self.grouping]
        return taps, np.float32(9 * e1), np.float32(9 * e2)


def classes_of(grouping: int) -> int:
    return int(GROUPINGS[grouping].max()) + 1


def section(filters: list) -> bytes:
    return b"".join(f.to_bytes() for f in filters)


def parse(data: bytes, start: int, ncomp: int) -> tuple[list | None, int]:
    """(the components' filters, where the section ends) from `data` at
    `start`; (None, its end so far) when the prefix does not hold it all."""
    filters = []
    pos = start
    for _ in range(ncomp):
        if pos >= len(data):
            return None, len(data)
        byte = data[pos]
        pos += 1
        grouping, mask = byte >> 6, byte & 63
        n = classes_of(grouping)
        if mask >> n:
            raise ValueError("corrupted DEBT stream (its filter names a class it has not)")
        taps = []
        for c in range(n):
            if mask >> c & 1:
                if pos + NTAPS > len(data):
                    return None, len(data)
                taps.append(np.frombuffer(data, dtype=np.int8, count=NTAPS, offset=pos).copy())
                pos += NTAPS
            else:
                taps.append(None)
        filters.append(Filter(grouping, taps))
    return filters, pos


# Work arrays, one a name and thread, reused by the next picture (as
# `codec._work`'s: fresh ones each time faulted their pages in anew).
_WORK = threading.local()


def _work(name: str, shape: tuple[int, int], dtype) -> np.ndarray:
    # One dtype a name.
    arrays = getattr(_WORK, "arrays", None)
    if arrays is None:
        arrays = _WORK.arrays = {}
    size = shape[0] * shape[1]
    held = arrays.get(name)
    if held is None or held.size < size:
        held = arrays[name] = np.empty(max(size, 1), dtype=dtype)
    return held[:size].reshape(shape)


def _activity_work(shape) -> tuple:
    h, w = shape
    return (_work("single", (h + 2 * MARGIN, w + 2 * MARGIN), np.float32),
            _work("lap", (h + 2, w + 2), np.float32), _work("hsum", (h + 2, w), np.float32))


def apply(comps: list, filters: list) -> list:
    """The components (contiguous float64 arrays) filtered in place; returns them."""
    for comp, f in zip(comps, filters):
        if f.active:
            restore(comp, *_ring_work(comp.shape[1]), *f.kernel_args())
    return comps


# ---------------------------------------------------------------- the encoder's fit

def _stats(comp: np.ndarray, orig: np.ndarray):
    ata = np.zeros((NBINS, NTAPS, NTAPS))
    atb = np.zeros((NBINS, NTAPS))
    rr = np.zeros(NBINS)
    comp = np.ascontiguousarray(comp)
    x, lap, hsum = _activity_work(comp.shape)
    activity(comp, x, lap, hsum)
    restoration_stats(comp, np.ascontiguousarray(orig), hsum, np.zeros(NTAPS), ata, atb, rr)
    upper = np.triu(ata)
    ata = upper + np.transpose(np.triu(ata, 1), (0, 2, 1))
    return ata, atb, rr


def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """(quantised taps, the squared error they take away) for normal
    equations a, b."""
    ridge = 1e-4 * max(float(np.trace(a)), 1e-9) / NTAPS + 1e-9
    try:
        c = np.linalg.solve(a + ridge * np.eye(NTAPS), b)
    except np.linalg.LinAlgError:
        return np.zeros(NTAPS, dtype=np.int8), 0.0
    q = np.clip(np.rint(c / TAP_STEP), -128, 127)
    t = q * TAP_STEP
    return q.astype(np.int8), float(2.0 * t @ b - t @ a @ t)


def fit(comps: list, origs: list, price: float, sampled: float = SAMPLED) -> tuple[list, float]:
    """(each component's Filter, the squared error they are expected to take
    away net of their bytes at `price` a byte) for the components `comps`
    of the decoder's picture against the original's `origs`.  The normal
    equations count every `sampled`-th pixel: gains are scaled up by it."""
    filters = []
    net = 0.0
    for comp, orig in zip(comps, origs):
        ata, atb, _rr = _stats(comp, orig)
        best = (0.0, Filter(0, [None]))
        for g in range(len(GROUPINGS)):
            n = classes_of(g)
            taps = []
            total = -price           # the grouping's byte
            for c in range(n):
                sel = GROUPINGS[g] == c
                t, gain = _solve(ata[sel].sum(axis=0), atb[sel].sum(axis=0))
                gain *= sampled
                if gain > NTAPS * price and t.any():
                    taps.append(t)
                    total += gain - NTAPS * price
                else:
                    taps.append(None)
            if total > best[0]:
                best = (total, Filter(g, taps))
        net += best[0] if best[1].active else -price
        filters.append(best[1])
    return filters, net


def warm_up() -> None:
    """Compile the filter's kernels (`codec.warm_up` calls it)."""
    rng = np.random.default_rng(1)
    comp = rng.normal(size=(12, 12)) * 10
    filters, _net = fit([comp], [comp + rng.normal(size=comp.shape)], 0.0)
    apply([comp], [Filter(2, [np.ones(NTAPS, dtype=np.int8)] * 3)])


def _ring_work(width: int) -> tuple:
    return (_work("ring", (RING, width + 2 * MARGIN), np.float32), _work("ring_lap", (1, width + 2), np.float32)[0],
            _work("ring_hsum", (4, width), np.float32))
