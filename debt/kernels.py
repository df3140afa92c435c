# Compiled array kernels of DEBT's lossy path: the CDF 9/7 transform in place
# on a Mallat-layout array, the max-pyramid of the block trees, and the
# reconstruction of coefficients from decoded bits.
#
# Why: the numpy versions in `transform` and `codec` spend most of their time
# in small temporary arrays; a decode at a few thousand bytes should cost
# about as much as the arithmetic decoding itself.  The numpy 9/7 in
# `transform` stays as the reference the tests compare these with.
#
# Layout: level after level the low region a[:h, :w] is split, columns first,
# into low rows [0, ceil(h/2)) and high rows below, then each row into low
# columns [0, ceil(w/2)) and high columns to the right.  Lifting works on the
# samples in natural order, with whole-sample symmetric extension
# (x[-1] = x[1], x[n] = x[n-2]), exactly as `transform`.

from __future__ import annotations

import numpy as np

from .jit import _jit as _jit_plain
from .jit import _jit_nrt as _jit
from .transform import _A, _B, _C, _D

# Where in its open interval a coefficient is shown (fraction of the interval
# above its known bits): right after its significance decision, and once
# refined.  Measured on the photographs (52 variants, 250-8000 B): 0.42 and
# 0.5 beat 0.375 and 0.45 (tuned on the synthetic samples) by +0.004 to
# +0.018 dB mean; exponential-density centroids estimated per class from the
# decoded refinement bits lost 0.002 to 0.02 dB to either.
DELTA_SIG = 0.42
DELTA_REF = 0.5


@_jit_plain
def _rows_step(a, s, e, x0, x1, start, coef):
    # Along columns x0..x1-1 of the row segment [s, e):
    # a[r] += coef * (a[r-1] + a[r+1]) for r = start, start+2, ... in it,
    # mirrored inside the segment (x[s-1] = x[s+1], x[e] = x[e-2]); a
    # one-sample segment has no neighbours and is left alone.
    if e - s < 2 or x0 >= x1:
        return
    r = s + ((start - s) & 1)
    while r < e:
        up = r - 1 if r - 1 >= s else r + 1
        dn = r + 1 if r + 1 < e else r - 1
        _lift_run(a[r, x0:x1], a[up, x0:x1], a[dn, x0:x1], coef)
        r += 2


@_jit_plain
def _lift_run(row, up, dn, coef):
    # row += coef * (up + dn).  The rows come as separate arrays and are
    # indexed from 0: the compiler then vectorises the loop (on one 2-D
    # array, or from an index it cannot prove non-negative, it did not:
    # 2.5x slower).
    for x in range(row.shape[0]):
        row[x] += coef * (up[x] + dn[x])


@_jit_plain
def _vertical(a, h, w, roi, start, coef):
    # One lifting step down the columns.  With a region (roi[0] < roi[2] and
    # roi[1] < roi[3]: x0, y0, x1, y1 at this level) its columns are lifted
    # in three segments, above, over and below it, so no filter crosses its
    # edge (shape-adaptive transform); the other columns whole.
    x0, y0, x1, y1 = roi[0], roi[1], roi[2], roi[3]
    if x0 < x1 and y0 < y1:
        _rows_step(a, 0, h, 0, x0, start, coef)
        _rows_step(a, 0, h, x1, w, start, coef)
        _rows_step(a, 0, y0, x0, x1, start, coef)
        _rows_step(a, y0, y1, x0, x1, start, coef)
        _rows_step(a, y1, h, x0, x1, start, coef)
    else:
        _rows_step(a, 0, h, 0, w, start, coef)


@_jit
def forward97(a, levels, roi):
    """In-place multilevel CDF 9/7 analysis of a 2-D float64 array.

    roi: int64 (x0, y0, x1, y1); an empty rectangle means none.  With one,
    the region and the rest are transformed apart (shape-adaptive: every
    coefficient describes pixels of one side only), level after level on
    the region's low-pass samples, (ceil(x0/2), ceil(y0/2), ceil(x1/2),
    ceil(y1/2))."""
    h, w = a.shape
    lo = np.empty(max(h, w), dtype=np.float64)
    hi = np.empty(max(h, w), dtype=np.float64)
    rows = np.empty((h, w), dtype=np.float64)
    cur = roi.copy()
    for _ in range(levels):
        hl = (h + 1) // 2
        wl = (w + 1) // 2
        if h > 1:
            _vertical(a, h, w, cur, 1, _A)
            _vertical(a, h, w, cur, 0, _B)
            _vertical(a, h, w, cur, 1, _C)
            _vertical(a, h, w, cur, 0, _D)
            # De-interleave whole rows (contiguous copies, not columns): the
            # horizontal step reads the rows in their new order into `rows`.
            if w > 1:
                _forward_rows(a, rows, h, w, hl, wl, cur, lo, hi, True)
            else:
                for r in range(h):
                    rows[(r >> 1) if r % 2 == 0 else hl + (r >> 1), 0] = a[r, 0]
            for r in range(h):
                for x in range(w):
                    a[r, x] = rows[r, x]
        elif w > 1:
            _forward_rows(a, a, h, w, hl, wl, cur, lo, hi, False)
        h, w = hl, wl
        for i in range(4):
            cur[i] = (cur[i] + 1) // 2


@_jit_plain
def _lift_split(lo, hi, s, e, par, coef):
    # `_cols_step` over the column segment [s, e) of a row held split, its
    # even samples in `lo` and its odd ones in `hi`: the same operations in
    # the same order on the same values, so the same floating-point results,
    # but on contiguous runs of separate arrays (vectorised).  par 0 lifts
    # the even samples from their odd neighbours, 1 the odd from the even.
    if e - s < 2:
        return
    x = s + ((par - s) & 1)
    if x == s:
        if par == 0:
            lo[x >> 1] += 2.0 * coef * hi[x >> 1]
        else:
            hi[x >> 1] += 2.0 * coef * lo[(x >> 1) + 1]
        x += 2
    n = (e - x) // 2 if e > x else 0
    i0 = x >> 1
    if n > 0:
        if par == 0:
            _lift_run(lo[i0:i0 + n], hi[i0 - 1:i0 + n - 1], hi[i0:i0 + n], coef)
        else:
            _lift_run(hi[i0:i0 + n], lo[i0:i0 + n], lo[i0 + 1:i0 + n + 1], coef)
    x += 2 * n
    if x < e:
        if par == 0:
            lo[x >> 1] += 2.0 * coef * hi[(x >> 1) - 1]
        else:
            hi[x >> 1] += 2.0 * coef * lo[x >> 1]


@_jit_plain
def _region_rows(roi, h, hl):
    # Which rows of a level split into hl low rows then high ones a region
    # (x0, y0, x1, y1 of the level before the split) crosses: whether there is
    # one, then low rows ceil(y0/2) .. ceil(y1/2) and high rows hl + floor(y0/2)
    # .. hl + floor(y1/2) (a level one row high: its single row).  A row among
    # them is lifted in three segments, left of, over and right of the region.
    y0, y1 = roi[1], roi[3]
    has = roi[0] < roi[2] and y0 < y1
    if h <= 1:
        return has, 0, 1, 1, 1
    return has, (y0 + 1) // 2, (y1 + 1) // 2, hl + y0 // 2, hl + y1 // 2


@_jit_plain
def _inverse_row(lo, hi, s, e):
    # The four inverse lifting steps along one split row segment.
    _lift_split(lo, hi, s, e, 0, -_D)
    _lift_split(lo, hi, s, e, 1, -_C)
    _lift_split(lo, hi, s, e, 0, -_B)
    _lift_split(lo, hi, s, e, 1, -_A)


@_jit_plain
def _inverse_rows(a, out, h, w, hl, wl, roi, lo, hi):
    # Inverse horizontal step of one level, row by row (rows are
    # independent, so row by row equals step by step): the row's low and
    # high columns copied apart, the four lifting steps (`_lift_split`),
    # and the samples written interleaved into row r of `out` (the vertical
    # step's interleaving of rows: `_inverse_rows_split`).  With a region, its rows
    # (low rows ceil(y0/2) .. ceil(y1/2), high rows hl + floor(y0/2) ..
    # hl + floor(y1/2)) are lifted in three segments, left of, over and
    # right of it.
    x0, x1 = roi[0], roi[2]
    has, lo0, lo1, hi0, hi1 = _region_rows(roi, h, hl)
    nh = w - wl
    for r in range(h):
        for i in range(wl):
            lo[i] = a[r, i]
        for i in range(nh):
            hi[i] = a[r, wl + i]
        if has and (lo0 <= r < min(lo1, hl) or max(hi0, hl) <= r < hi1):
            _inverse_row(lo, hi, 0, x0)
            _inverse_row(lo, hi, x0, x1)
            _inverse_row(lo, hi, x1, w)
        else:
            _inverse_row(lo, hi, 0, w)
        dst = out[r]
        for i in range(nh):
            dst[2 * i] = lo[i]
            dst[2 * i + 1] = hi[i]
        if wl > nh:
            dst[2 * nh] = lo[nh]


@_jit_plain
def _inverse_rows_split(a, out, h, w, hl, wl, roi):
    # `_inverse_rows` into the row of `out` (another array) the vertical
    # step's interleaving puts row r at, each row lifted
    # where it lies, its low columns a[r, :wl] and high ones a[r, wl:w]
    # (already apart, so no copy into work rows: 0.11 -> 0.088 ms of the
    # 0.15 of a 320x240 grey picture's inverse), then written interleaved
    # into `out`.  The same operations on the same values, so the same
    # results; `a`'s rows are left lifted, for the caller overwrites them.
    # Its lifting and interleaving are written out as `_inverse_rows`' are:
    # as one helper called from both, the inverse took 0.148 ms, not 0.121.
    x0, x1 = roi[0], roi[2]
    has, lo0, lo1, hi0, hi1 = _region_rows(roi, h, hl)
    nh = w - wl
    for r in range(h):
        lo = a[r, :wl]
        hi = a[r, wl:w]
        if has and (lo0 <= r < min(lo1, hl) or max(hi0, hl) <= r < hi1):
            _inverse_row(lo, hi, 0, x0)
            _inverse_row(lo, hi, x0, x1)
            _inverse_row(lo, hi, x1, w)
        else:
            _inverse_row(lo, hi, 0, w)
        dst = out[2 * r if r < hl else 2 * (r - hl) + 1]
        for i in range(nh):
            dst[2 * i] = lo[i]
            dst[2 * i + 1] = hi[i]
        if wl > nh:
            dst[2 * nh] = lo[nh]


@_jit_plain
def _forward_row(lo, hi, s, e):
    # The four analysis lifting steps along one split row segment.
    _lift_split(lo, hi, s, e, 1, _A)
    _lift_split(lo, hi, s, e, 0, _B)
    _lift_split(lo, hi, s, e, 1, _C)
    _lift_split(lo, hi, s, e, 0, _D)


@_jit_plain
def _forward_rows(a, out, h, w, hl, wl, roi, lo, hi, split):
    # Horizontal step of one analysis level, row by row, as `_inverse_rows`
    # undoes it: the row's even and odd samples copied apart, the four
    # lifting steps on them (`_lift_split`: what lifting the interleaved
    # row in place did, the same operations in the same order, so the same
    # values, but vectorised), written back low columns then high ones.
    # Rows are independent, and so are a region's three segments (no filter
    # crosses their edges): segment by segment equals step by step.  Row r
    # of `out` is made from row r of `a`, or with `split` from the row the
    # vertical step's de-interleaving puts there (`out` then another array).
    x0, x1 = roi[0], roi[2]
    has, lo0, lo1, hi0, hi1 = _region_rows(roi, h, hl)
    nh = w - wl
    for r in range(h):
        row = a[(2 * r if r < hl else 2 * (r - hl) + 1) if split else r]
        for i in range(nh):
            lo[i] = row[2 * i]
            hi[i] = row[2 * i + 1]
        if wl > nh:
            lo[nh] = row[2 * nh]
        if has and (lo0 <= r < min(lo1, hl) or max(hi0, hl) <= r < hi1):
            _forward_row(lo, hi, 0, x0)
            _forward_row(lo, hi, x0, x1)
            _forward_row(lo, hi, x1, w)
        else:
            _forward_row(lo, hi, 0, w)
        dst = out[r]
        for i in range(wl):
            dst[i] = lo[i]
        for i in range(nh):
            dst[wl + i] = hi[i]


@_jit
def inverse97(a, levels, roi):
    """In-place inverse of `forward97` (the same roi)."""
    H, W = a.shape
    hs = np.empty(levels + 1, dtype=np.int64)
    ws = np.empty(levels + 1, dtype=np.int64)
    rois = np.empty((levels + 1, 4), dtype=np.int64)
    hs[0] = H
    ws[0] = W
    rois[0] = roi
    for j in range(levels):
        hs[j + 1] = (hs[j] + 1) // 2
        ws[j + 1] = (ws[j] + 1) // 2
        for i in range(4):
            rois[j + 1, i] = (rois[j, i] + 1) // 2
    lo = np.empty(max(H, W), dtype=np.float64)
    hi = np.empty(max(H, W), dtype=np.float64)
    rows = np.empty((H, W), dtype=np.float64)
    for j in range(levels - 1, -1, -1):
        h = hs[j]
        w = ws[j]
        hl = hs[j + 1]
        wl = ws[j + 1]
        cur = rois[j]
        if h > 1:
            # Each row's inverse step written straight to where the columns'
            # interleaving puts it (in `rows`), then copied back once.
            if w > 1:
                _inverse_rows_split(a, rows, h, w, hl, wl, cur)
            else:
                for r in range(h):
                    rows[2 * r if r < hl else 2 * (r - hl) + 1, 0] = a[r, 0]
            for r in range(h):
                _copy_run(rows[r, :w], a[r, :w])
        elif w > 1:
            _inverse_rows(a, a, h, w, hl, wl, cur, lo, hi)
        if h > 1:
            _vertical(a, h, w, cur, 0, -_D)
            _vertical(a, h, w, cur, 1, -_C)
            _vertical(a, h, w, cur, 0, -_B)
            _vertical(a, h, w, cur, 1, -_A)


@_jit
def packets97(a, splits, forward):
    """Wavelet packets in place in Mallat arrays `a` (components, height,
    width): each region of `splits` (rows y0, x0, height, width, and
    optionally a kind: 0 or absent one more 9/7 level, 1 its column steps
    alone (low rows above, high below), 2 its row steps alone (low columns
    left, high right)) split once (`forward97`; `inverse97` when not
    `forward`, the regions in reverse order), the same operations in the
    same order as one call per region on a contiguous copy, so the same
    values.  Lifted where it lies (`_forward_region`, `_inverse_region`):
    one copy a region instead of five, and the work arrays made once."""
    n = splits.shape[0]
    side = 1
    for k in range(n):
        side = max(side, splits[k, 2], splits[k, 3])
    lo = np.empty(side, dtype=np.float64)
    hi = np.empty(side, dtype=np.float64)
    rows = np.empty((side, side), dtype=np.float64)
    for c in range(a.shape[0]):
        comp = a[c]
        for k in range(n):
            i = k if forward else n - 1 - k
            y0, x0, bh, bw = splits[i, 0], splits[i, 1], splits[i, 2], splits[i, 3]
            kind = splits[i, 4] if splits.shape[1] > 4 else 0
            if forward:
                _forward_region(comp, y0, x0, bh, bw, rows, lo, hi, kind != 2, kind != 1)
            else:
                _inverse_region(comp, y0, x0, bh, bw, rows, lo, hi, kind != 2, kind != 1)


@_jit_plain
def _split_row(src, w, wl, lo, hi):
    # A row's even samples into `lo`, its odd ones into `hi`.
    nh = w - wl
    for i in range(nh):
        lo[i] = src[2 * i]
        hi[i] = src[2 * i + 1]
    if wl > nh:
        lo[nh] = src[2 * nh]


@_jit_plain
def _forward_region(comp, y0, x0, h, w, rows, lo, hi, down, along):
    # One analysis level (`forward97`, levels 1, no region) of the block
    # comp[y0:y0+h, x0:x0+w], in place: the column steps on the block itself
    # (the same segments, mirrored at its edges), each row's step read in
    # the de-interleaved order into `rows`, copied back once.  Without
    # `down` no column steps (the rows stay in their order), without `along`
    # no row steps: a split in one direction only.
    hl = (h + 1) // 2
    wl = (w + 1) // 2
    down = down and h > 1
    along = along and w > 1
    if down:
        y1 = y0 + h
        x1 = x0 + w
        _rows_step(comp, y0, y1, x0, x1, y0 + 1, _A)
        _rows_step(comp, y0, y1, x0, x1, y0, _B)
        _rows_step(comp, y0, y1, x0, x1, y0 + 1, _C)
        _rows_step(comp, y0, y1, x0, x1, y0, _D)
        for r in range(h):
            src = comp[y0 + (2 * r if r < hl else 2 * (r - hl) + 1), x0:x1]
            dst = rows[r]
            if along:
                _split_row(src, w, wl, lo, hi)
                _forward_row(lo, hi, 0, w)
                for i in range(wl):
                    dst[i] = lo[i]
                for i in range(w - wl):
                    dst[wl + i] = hi[i]
            else:
                for i in range(w):
                    dst[i] = src[i]
        for r in range(h):
            _copy_run(rows[r, :w], comp[y0 + r, x0:x1])
    elif along:
        for r in range(h):
            row = comp[y0 + r, x0:x0 + w]
            _split_row(row, w, wl, lo, hi)
            _forward_row(lo, hi, 0, w)
            for i in range(wl):
                row[i] = lo[i]
            for i in range(w - wl):
                row[wl + i] = hi[i]


@_jit_plain
def _inverse_region(comp, y0, x0, h, w, rows, lo, hi, down, along):
    # `inverse97` (levels 1, no region) of the block comp[y0:y0+h, x0:x0+w],
    # in place: each row's inverse step written interleaved into the row of
    # `rows` the columns' interleaving puts it at (or back into its own row
    # when there are no column steps), copied back once, the column steps on
    # the block itself.  `down`, `along`: as `_forward_region`.
    hl = (h + 1) // 2
    wl = (w + 1) // 2
    nh = w - wl
    x1 = x0 + w
    down = down and h > 1
    along = along and w > 1
    for r in range(h):
        src = comp[y0 + r, x0:x1]
        dst = src
        if down:
            dst = rows[2 * r if r < hl else 2 * (r - hl) + 1, :w]
        if along:
            for i in range(wl):
                lo[i] = src[i]
            for i in range(nh):
                hi[i] = src[wl + i]
            _inverse_row(lo, hi, 0, w)
            for i in range(nh):
                dst[2 * i] = lo[i]
                dst[2 * i + 1] = hi[i]
            if wl > nh:
                dst[2 * nh] = lo[nh]
        elif down:
            for i in range(w):
                dst[i] = src[i]
    if down:
        y1 = y0 + h
        for r in range(h):
            _copy_run(rows[r, :w], comp[y0 + r, x0:x1])
        _rows_step(comp, y0, y1, x0, x1, y0, -_D)
        _rows_step(comp, y0, y1, x0, x1, y0 + 1, -_C)
        _rows_step(comp, y0, y1, x0, x1, y0, -_B)
        _rows_step(comp, y0, y1, x0, x1, y0 + 1, -_A)


@_jit_plain
def _copy_run(src, dst):
    for x in range(src.shape[0]):
        dst[x] = src[x]


@_jit_plain
def max_pyramid(mag, binfo, noff, nw, out):
    """out[node] = max of `mag` over the node's block, every band and level
    (and of 0: an empty block is 0).  Level after level, each node the
    largest of its (up to) 2x2 children below, row pair by row pair.
    Without reference counting (it allocates nothing): with it, every row
    slice handed to `_max_rows` cost two atomic updates, and the camera's
    sand picture at 1000 B took 0.09 ms (dyadic) and 0.23 ms (packets, four
    times the rows) against 0.04 and 0.065."""
    for b in range(binfo.shape[0]):
        off = binfo[b, 0]
        h = binfo[b, 1]
        w = binfo[b, 2]
        kr = binfo[b, 3]
        if h == 0 or w == 0:
            continue
        ph = h
        pw = w
        for k in range(1, kr + 1):
            hk = (ph + 1) // 2
            wk = (pw + 1) // 2
            base = noff[b, k]
            below = off if k == 1 else noff[b, k - 1]
            src = mag if k == 1 else out
            for y in range(hk):
                r0 = below + 2 * y * pw
                dst = base + y * wk
                if 2 * y + 1 < ph:
                    _max_rows(src[r0:r0 + pw], src[r0 + pw:r0 + 2 * pw], out[dst:dst + wk])
                else:
                    _max_row(src[r0:r0 + pw], out[dst:dst + wk])
            ph = hk
            pw = wk


@_jit_plain
def _max_rows(a, b, out):
    # out[x] = max(0, a[2x], a[2x+1], b[2x], b[2x+1]), the odd last column alone.
    n = a.shape[0] // 2
    for x in range(n):
        out[x] = max(max(max(a[2 * x], a[2 * x + 1]), max(b[2 * x], b[2 * x + 1])), 0)
    if a.shape[0] > 2 * n:
        out[n] = max(max(a[2 * n], b[2 * n]), 0)


@_jit_plain
def _max_row(a, out):
    n = a.shape[0] // 2
    for x in range(n):
        out[x] = max(max(a[2 * x], a[2 * x + 1]), 0)
    if a.shape[0] > 2 * n:
        out[n] = max(a[2 * n], 0)


def reconstruct97(rec, pk, sgn, pos, inv_scale, out):
    """Coefficients at the middle of their open intervals, into Mallat arrays."""
    n8 = pk.shape[0] >> 3
    _reconstruct97(rec, pk, sgn, pos, inv_scale, out, np.ascontiguousarray(pk[:n8 << 3]).view(np.int64))


@_jit_plain
def _reconstruct97(rec, pk, sgn, pos, inv_scale, out, pk8):
    # Eight coefficients at a time (`pk8`: `pk` read 8 bytes at once) past
    # those never found significant (pk -1, every bit set): at a few
    # thousand bytes most are, in runs (the coding order is band by band;
    # a grey 320x240 picture at 2000 B: 88 % of its groups of eight), so
    # its 76800 coefficients took 0.041 ms and now 0.019 (without reference
    # counting, 0.029 of it).  Those left are made as before, each written
    # once: the same values.
    n = rec.shape[0]
    n8 = pk8.shape[0]
    for g in range(n8 + 1):
        if g < n8 and pk8[g] == -1:
            continue
        e = (g + 1) << 3
        if e > n:
            e = n
        for c in range(g << 3, e):
            p = pk[c]
            if p < 0:
                continue
            r = rec[c]
            step = np.int64(1) << np.int64(p)
            # Wavelet magnitudes fall off within an interval (Laplacian-like), so
            # the best guess sits below its middle, most of all right after the
            # significance decision.
            v = (r + (DELTA_SIG if r == step else DELTA_REF) * step) * inv_scale[c]
            out[pos[c]] = -v if sgn[c] else v


@_jit
def gather97(flat, pos, scale, mag, neg, cdef, top_by_def):
    """Scaled magnitudes and signs of the coefficients, in coding order; and
    per deficit d (cdef, 0..15) the largest magnitude among the coefficients
    with that deficit, into `top_by_def` (int64, 16 zeros), from which
    `top_plane` gives the stream's top (one pass instead of numpy's four)."""
    for c in range(pos.shape[0]):
        v = flat[pos[c]]
        if v < 0:
            neg[c] = np.uint8(1)
            v = -v
        else:
            neg[c] = np.uint8(0)
        m = np.int64(np.floor(v * scale[c]))
        mag[c] = m
        d = cdef[c]
        if m > top_by_def[d]:
            top_by_def[d] = m


@_jit
def top_plane(top_by_def):
    """The highest plane any coefficient reaches counted with its deficit:
    max over d of floor(log2(magnitude)) + d, 0 when all are zero."""
    top = 0
    for d in range(top_by_def.shape[0]):
        m = top_by_def[d]
        if m <= 0:
            continue
        bits = -1
        while m > 0:
            m >>= 1
            bits += 1
        if bits + d > top:
            top = bits + d
    return top


@_jit
def coefficient_error97(flat, pos, scale, err_weight, rec, pk):
    """The squared error, summed and weighted back to pixels, of the
    coefficients as `reconstruct97` shows them from (rec, pk) against the
    true ones (see codec._coefficient_error)."""
    total = 0.0
    for c in range(pos.shape[0]):
        true = abs(flat[pos[c]]) * scale[c]
        p = pk[c]
        shown = 0.0
        if p >= 0:
            r = rec[c]
            step = np.int64(1) << np.int64(p)
            shown = r + (DELTA_SIG if r == step else DELTA_REF) * step
        e = (true - shown) * err_weight[c]
        total += e * e
    return total


@_jit_plain
def _to_byte_row(a, offset, out):
    # clip(round(a + offset), 0, 255), branch-free (vectorised).
    for x in range(a.shape[0]):
        out[x] = np.uint8(min(max(np.rint(a[x] + offset), 0.0), 255.0))


@_jit_plain
def to_uint8(a, offset, out):
    """out = clip(round(a + offset), 0, 255) in one pass (grey pictures)."""
    for r in range(a.shape[0]):
        _to_byte_row(a[r], offset, out[r])


@_jit_plain
def _rgb_plane_row(a, b, c, ma, mb, mc, offset, out):
    # clip(round(a ma + b mb + c mc + offset), 0, 255) along one row.
    for x in range(a.shape[0]):
        out[x] = np.uint8(min(max(np.rint(a[x] * ma + b[x] * mb + c[x] * mc + offset), 0.0), 255.0))


@_jit_plain
def _to_rgb_rows(c0, c1, c2, m, offset, out, t0, t1, t2):
    for r in range(c0.shape[0]):
        a = c0[r]
        b = c1[r]
        c = c2[r]
        _rgb_plane_row(a, b, c, m[0, 0], m[1, 0], m[2, 0], offset, t0)
        _rgb_plane_row(a, b, c, m[0, 1], m[1, 1], m[2, 1], offset, t1)
        _rgb_plane_row(a, b, c, m[0, 2], m[1, 2], m[2, 2], offset, t2)
        o = out[r]
        for x in range(c0.shape[1]):
            o[x, 0] = t0[x]
            o[x, 1] = t1[x]
            o[x, 2] = t2[x]


@_jit
def to_rgb(c0, c1, c2, m, offset, out):
    """out[..., j] = clip(round(c0 m[0, j] + c1 m[1, j] + c2 m[2, j] + offset), 0, 255)
    in one pass (colour pictures: components back to RGB).  Each plane of a
    row is made apart, branch-free (vectorised), then interleaved: 3x
    faster than pixel by pixel, the same values."""
    w = c0.shape[1]
    t0 = np.empty(w, dtype=np.uint8)
    t1 = np.empty(w, dtype=np.uint8)
    t2 = np.empty(w, dtype=np.uint8)
    _to_rgb_rows(c0, c1, c2, m, offset, out, t0, t1, t2)


@_jit
def rgb_squared_error(c0, c1, c2, m, offset, img):
    """The squared error, summed in integers, of the picture `to_rgb` makes
    of (c0, c1, c2, m, offset) against the RGB picture `img`, without making
    it: each row's planes made as `to_rgb` makes them (the same values), the
    differences squared and summed (exact)."""
    w = c0.shape[1]
    t0 = np.empty(w, dtype=np.uint8)
    t1 = np.empty(w, dtype=np.uint8)
    t2 = np.empty(w, dtype=np.uint8)
    total = np.int64(0)
    for r in range(c0.shape[0]):
        a = c0[r]
        b = c1[r]
        c = c2[r]
        _rgb_plane_row(a, b, c, m[0, 0], m[1, 0], m[2, 0], offset, t0)
        _rgb_plane_row(a, b, c, m[0, 1], m[1, 1], m[2, 1], offset, t1)
        _rgb_plane_row(a, b, c, m[0, 2], m[1, 2], m[2, 2], offset, t2)
        total += _rgb_row_error(t0, t1, t2, img[r])
    return total


@_jit_plain
def _rgb_row_error(t0, t1, t2, row):
    s = np.int64(0)
    for x in range(t0.shape[0]):
        d0 = np.int32(t0[x]) - np.int32(row[x, 0])
        d1 = np.int32(t1[x]) - np.int32(row[x, 1])
        d2 = np.int32(t2[x]) - np.int32(row[x, 2])
        s += np.int64(d0 * d0 + d1 * d1 + d2 * d2)
    return s


@_jit
def grey_squared_error(a, offset, img):
    """The squared error, summed in integers, of the picture `to_uint8`
    makes of (a, offset) against the grey picture `img`, without making it."""
    t = np.empty(a.shape[1], dtype=np.uint8)
    total = np.int64(0)
    for r in range(a.shape[0]):
        _to_byte_row(a[r], offset, t)
        row = img[r]
        s = np.int64(0)
        for x in range(t.shape[0]):
            d = np.int32(t[x]) - np.int32(row[x])
            s += np.int64(d * d)
        total += s
    return total


@_jit
def colour_moments(img, detail, pixels, total):
    """Second moments of an RGB picture in one pass: `detail` (3x3) of its
    horizontal and vertical neighbour differences, `pixels` (3x3) of the
    pixels, `total` (3) their sums (for the mean), added to what they hold.
    Every term is an integer and every sum stays below 2**53, so the sums are
    exact whatever their order: accumulated in integers, a row's planes
    copied apart first so that each sum runs over contiguous samples
    (vectorised: 4x faster than pixel by pixel)."""
    w = img.shape[1]
    acc = np.zeros(15, dtype=np.int64)
    _moment_rows(img, acc, np.empty((3, w), dtype=np.int32), np.empty((3, w), dtype=np.int32))
    for i in range(3):
        total[i] += np.float64(acc[i])
    k = 3
    for i in range(3):
        for j in range(i, 3):
            pixels[i, j] += np.float64(acc[k])
            detail[i, j] += np.float64(acc[k + 6])
            k += 1
    for m in (detail, pixels):
        m[1, 0] = m[0, 1]
        m[2, 0] = m[0, 2]
        m[2, 1] = m[1, 2]


@_jit_plain
def _moment_rows(img, acc, cur, nxt):
    # The rows of `colour_moments` into `acc`, without reference counting
    # (see `_rotated_rows`).
    h, w = img.shape[0], img.shape[1]
    if h > 0:
        _planes_of_row(img[0], cur)
    for y in range(h):
        _moments_of_row(cur[0], cur[1], cur[2], acc)
        _differences(cur[0, 1:], cur[1, 1:], cur[2, 1:], cur[0, :w - 1], cur[1, :w - 1], cur[2, :w - 1], acc)
        if y + 1 < h:
            _planes_of_row(img[y + 1], nxt)
            _differences(nxt[0], nxt[1], nxt[2], cur[0], cur[1], cur[2], acc)
            cur, nxt = nxt, cur


@_jit_plain
def _planes_of_row(row, out):
    for x in range(row.shape[0]):
        out[0, x] = np.int32(row[x, 0])
        out[1, x] = np.int32(row[x, 1])
        out[2, x] = np.int32(row[x, 2])


@_jit_plain
def _moments_of_row(r, g, b, acc):
    # Sums of one row's samples and of their products (acc[0:9]).
    t0 = t1 = t2 = np.int64(0)
    p00 = p01 = p02 = p11 = p12 = p22 = np.int64(0)
    for x in range(r.shape[0]):
        rr = r[x]
        gg = g[x]
        bb = b[x]
        t0 += rr
        t1 += gg
        t2 += bb
        p00 += rr * rr
        p01 += rr * gg
        p02 += rr * bb
        p11 += gg * gg
        p12 += gg * bb
        p22 += bb * bb
    acc[0] += t0
    acc[1] += t1
    acc[2] += t2
    acc[3] += p00
    acc[4] += p01
    acc[5] += p02
    acc[6] += p11
    acc[7] += p12
    acc[8] += p22


@_jit_plain
def _differences(r1, g1, b1, r0, g0, b0, acc):
    # Sums of the products of the differences (r1 - r0, ...) (acc[9:15]).
    d00 = d01 = d02 = d11 = d12 = d22 = np.int64(0)
    for x in range(r1.shape[0]):
        dr = r1[x] - r0[x]
        dg = g1[x] - g0[x]
        db = b1[x] - b0[x]
        d00 += dr * dr
        d01 += dr * dg
        d02 += dr * db
        d11 += dg * dg
        d12 += dg * db
        d22 += db * db
    acc[9] += d00
    acc[10] += d01
    acc[11] += d02
    acc[12] += d11
    acc[13] += d12
    acc[14] += d22


@_jit
def rotated_planes(img, m, out):
    """`out[i] = (img - 128) @ m[:, i]` for an RGB picture (uint8, rows of
    pixels) into three planes (`out`: 3 x height x width), in one pass: each
    row's planes apart first (`_centred_planes_of_row`), then each output
    plane as a sum of three scaled rows (vectorised)."""
    planes = np.empty((3, img.shape[1]), dtype=np.float64)
    _rotated_rows(img, m, out, planes)


@_jit_plain
def _rotated_rows(img, m, out, planes):
    # The rows of `rotated_planes`, without reference counting: in the
    # allocating kernel itself every row slice handed to a helper cost two
    # atomic updates (on the camera's 320x240 colour picture this kernel
    # took 0.093 ms, now 0.076-0.089; `colour_moments` 0.103, now 0.075).
    for y in range(img.shape[0]):
        _centred_planes_of_row(img[y], planes)
        for i in range(3):
            _rotate_row(planes[0], planes[1], planes[2], m[0, i], m[1, i], m[2, i], out[i, y])


@_jit_plain
def _centred_planes_of_row(row, out):
    for x in range(row.shape[0]):
        out[0, x] = np.float64(row[x, 0]) - 128.0
        out[1, x] = np.float64(row[x, 1]) - 128.0
        out[2, x] = np.float64(row[x, 2]) - 128.0


@_jit_plain
def _rotate_row(r, g, b, m0, m1, m2, out):
    for x in range(r.shape[0]):
        out[x] = r[x] * m0 + g[x] * m1 + b[x] * m2
