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

from .coder import _jit_nrt as _jit
from .transform import _A, _B, _C, _D

DELTA_SIG = 0.375
DELTA_REF = 0.45


@_jit
def _rows_step(a, h, w, start, coef):
    # a[r, :w] += coef * (a[r-1, :w] + a[r+1, :w]) for r = start, start+2, ...
    for r in range(start, h, 2):
        up = r - 1 if r >= 1 else 1
        dn = r + 1 if r + 1 < h else h - 2
        for x in range(w):
            a[r, x] += coef * (a[up, x] + a[dn, x])


@_jit
def _cols_step(a, h, w, start, coef):
    # The same along rows; the mirrored edges are taken out of the inner loop.
    for r in range(h):
        x = start
        if x == 0:
            a[r, 0] += 2.0 * coef * a[r, 1]
            x = 2
        while x + 1 < w:
            a[r, x] += coef * (a[r, x - 1] + a[r, x + 1])
            x += 2
        if x < w:
            a[r, x] += 2.0 * coef * a[r, x - 1]


@_jit
def forward97(a, levels):
    """In-place multilevel CDF 9/7 analysis of a 2-D float64 array."""
    h, w = a.shape
    tmp = np.empty(max(h, w), dtype=np.float64)
    rows = np.empty((h, w), dtype=np.float64)
    for _ in range(levels):
        hl = (h + 1) // 2
        wl = (w + 1) // 2
        if h > 1:
            _rows_step(a, h, w, 1, _A)
            _rows_step(a, h, w, 0, _B)
            _rows_step(a, h, w, 1, _C)
            _rows_step(a, h, w, 0, _D)
            # De-interleave whole rows (contiguous copies, not columns).
            for r in range(h):
                dst = (r >> 1) if r % 2 == 0 else hl + (r >> 1)
                for x in range(w):
                    rows[dst, x] = a[r, x]
            for r in range(h):
                for x in range(w):
                    a[r, x] = rows[r, x]
        if w > 1:
            _cols_step(a, h, w, 1, _A)
            _cols_step(a, h, w, 0, _B)
            _cols_step(a, h, w, 1, _C)
            _cols_step(a, h, w, 0, _D)
            for r in range(h):
                for x in range(w):
                    tmp[(x >> 1) if x % 2 == 0 else wl + (x >> 1)] = a[r, x]
                for x in range(w):
                    a[r, x] = tmp[x]
        h, w = hl, wl


@_jit
def inverse97(a, levels):
    """In-place inverse of `forward97`."""
    H, W = a.shape
    hs = np.empty(levels + 1, dtype=np.int64)
    ws = np.empty(levels + 1, dtype=np.int64)
    hs[0] = H
    ws[0] = W
    for j in range(levels):
        hs[j + 1] = (hs[j] + 1) // 2
        ws[j + 1] = (ws[j] + 1) // 2
    tmp = np.empty(max(H, W), dtype=np.float64)
    rows = np.empty((H, W), dtype=np.float64)
    for j in range(levels - 1, -1, -1):
        h = hs[j]
        w = ws[j]
        hl = hs[j + 1]
        wl = ws[j + 1]
        if w > 1:
            for r in range(h):
                for x in range(w):
                    tmp[x] = a[r, (x >> 1) if x % 2 == 0 else wl + (x >> 1)]
                for x in range(w):
                    a[r, x] = tmp[x]
            _cols_step(a, h, w, 0, -_D)
            _cols_step(a, h, w, 1, -_C)
            _cols_step(a, h, w, 0, -_B)
            _cols_step(a, h, w, 1, -_A)
        if h > 1:
            for r in range(h):
                src = (r >> 1) if r % 2 == 0 else hl + (r >> 1)
                for x in range(w):
                    rows[r, x] = a[src, x]
            for r in range(h):
                for x in range(w):
                    a[r, x] = rows[r, x]
            _rows_step(a, h, w, 0, -_D)
            _rows_step(a, h, w, 1, -_C)
            _rows_step(a, h, w, 0, -_B)
            _rows_step(a, h, w, 1, -_A)


@_jit
def max_pyramid(mag, binfo, noff, nw, out):
    """out[node] = max of `mag` over the node's block, every band and level."""
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
            for y in range(hk):
                for x in range(wk):
                    m = np.int64(0)
                    for dy in range(2):
                        yy = 2 * y + dy
                        if yy >= ph:
                            continue
                        for dx in range(2):
                            xx = 2 * x + dx
                            if xx >= pw:
                                continue
                            if k == 1:
                                v = mag[off + yy * w + xx]
                            else:
                                v = out[noff[b, k - 1] + yy * pw + xx]
                            if v > m:
                                m = v
                    out[base + y * wk + x] = m
            ph = hk
            pw = wk


@_jit
def reconstruct97(rec, pk, sgn, pos, inv_scale, out):
    """Coefficients at the middle of their open intervals, into Mallat arrays."""
    for c in range(rec.shape[0]):
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
def gather97(flat, pos, scale, mag, neg):
    """Scaled magnitudes and signs of the coefficients, in coding order."""
    for c in range(pos.shape[0]):
        v = flat[pos[c]]
        if v < 0:
            neg[c] = np.uint8(1)
            v = -v
        else:
            neg[c] = np.uint8(0)
        mag[c] = np.int64(np.floor(v * scale[c]))


@_jit
def to_uint8(a, offset, out):
    """out = clip(round(a + offset), 0, 255) in one pass (grey pictures)."""
    h, w = a.shape
    for r in range(h):
        for x in range(w):
            v = np.rint(a[r, x] + offset)
            out[r, x] = 0 if v < 0 else (255 if v > 255 else np.uint8(v))
