# Wavelet transforms of DEBT: CDF 9/7 (floating point, for lossy coding) and
# LeGall 5/3 (integer, reversible, for lossless coding), both by lifting with
# whole-sample symmetric extension so that any length works, odd ones and 1
# included.
#
# Plan: one 1-D analysis/synthesis step along axis 0 of a 2-D array, vectorised
# with numpy slices (no Python loop over samples); the 2-D multilevel transform
# applies it to columns then rows of the low band, level after level (Mallat
# pyramid).  The coefficients are kept as a list of bands, coarsest first:
#     [LL_L, (LH_L, HL_L, HH_L), ..., (LH_1, HL_1, HH_1)]
# A length-n axis splits into ceil(n/2) low and floor(n/2) high samples, so an
# axis of length 1 is simply left alone (its high band is empty).
#
# The 9/7 steps are left unscaled (no K factor): the coder multiplies every
# band by the norm of its synthesis basis function instead (`band_weights`),
# which both normalises the gains and makes coefficient error stand for pixel
# error, the property bit-plane ordering relies on.

from __future__ import annotations

from functools import lru_cache

import numpy as np

# CDF 9/7 lifting constants (Daubechies & Sweldens factorisation).
_A = -1.586134342059924
_B = -0.052980118572961
_C = 0.882911075530934
_D = 0.443506852043971

MAX_LEVELS = 6


def levels_for(height: int, width: int) -> int:
    """Decomposition depth used for an image: the low band ends near 8 px."""
    levels = 0
    big = max(height, width)
    while levels < MAX_LEVELS and -(-big // (1 << levels)) > 8:
        levels += 1
    return levels


def _next(s: np.ndarray, nd: int) -> np.ndarray:
    # s[n + 1] for n < nd, mirrored at the right edge (x[N] = x[N - 2]).
    if s.shape[0] > nd:
        return s[1:nd + 1]
    return np.concatenate([s[1:], s[-1:]])


def _prev_cur(d: np.ndarray, ns: int) -> np.ndarray:
    # d[n - 1] + d[n] for n < ns, mirrored at both edges (x[-1] = x[1]).
    prev = np.concatenate([d[:1], d[:-1]])
    cur = d
    if ns > d.shape[0]:
        prev = np.concatenate([d[:1], d])
        cur = np.concatenate([d, d[-1:]])
    return prev + cur


def _analyse97(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if x.shape[0] < 2:
        return x.copy(), x[:0].copy()
    s = x[0::2].astype(np.float64)
    d = x[1::2].astype(np.float64)
    ns, nd = s.shape[0], d.shape[0]
    d += _A * (s[:nd] + _next(s, nd))
    s += _B * _prev_cur(d, ns)
    d += _C * (s[:nd] + _next(s, nd))
    s += _D * _prev_cur(d, ns)
    return s, d


def _synthesise97(s: np.ndarray, d: np.ndarray) -> np.ndarray:
    if d.shape[0] == 0:
        return s.copy()
    s = s.copy()
    d = d.copy()
    ns, nd = s.shape[0], d.shape[0]
    s -= _D * _prev_cur(d, ns)
    d -= _C * (s[:nd] + _next(s, nd))
    s -= _B * _prev_cur(d, ns)
    d -= _A * (s[:nd] + _next(s, nd))
    out = np.empty((ns + nd,) + s.shape[1:], dtype=np.float64)
    out[0::2] = s
    out[1::2] = d
    return out


def _analyse53(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if x.shape[0] < 2:
        return x.copy(), x[:0].copy()
    s = x[0::2].astype(np.int64)
    d = x[1::2].astype(np.int64)
    ns, nd = s.shape[0], d.shape[0]
    d -= (s[:nd] + _next(s, nd)) >> 1
    s += (_prev_cur(d, ns) + 2) >> 2
    return s, d


def _synthesise53(s: np.ndarray, d: np.ndarray) -> np.ndarray:
    if d.shape[0] == 0:
        return s.copy()
    s = s.copy()
    d = d.copy()
    ns, nd = s.shape[0], d.shape[0]
    s -= (_prev_cur(d, ns) + 2) >> 2
    d += (s[:nd] + _next(s, nd)) >> 1
    out = np.empty((ns + nd,) + s.shape[1:], dtype=np.int64)
    out[0::2] = s
    out[1::2] = d
    return out


def _analyse53_linear(x):
    # The 5/3 without rounding: only used to measure synthesis norms.
    if x.shape[0] < 2:
        return x.copy(), x[:0].copy()
    s = x[0::2].astype(np.float64)
    d = x[1::2].astype(np.float64)
    ns, nd = s.shape[0], d.shape[0]
    d -= 0.5 * (s[:nd] + _next(s, nd))
    s += 0.25 * _prev_cur(d, ns)
    return s, d


def _synthesise53_linear(s, d):
    if d.shape[0] == 0:
        return s.copy()
    s = s.copy()
    d = d.copy()
    ns, nd = s.shape[0], d.shape[0]
    s -= 0.25 * _prev_cur(d, ns)
    d += 0.5 * (s[:nd] + _next(s, nd))
    out = np.empty((ns + nd,) + s.shape[1:], dtype=np.float64)
    out[0::2] = s
    out[1::2] = d
    return out


_FILTERS = {
    "97": (_analyse97, _synthesise97),
    "53": (_analyse53, _synthesise53),
    "53linear": (_analyse53_linear, _synthesise53_linear),
}


def forward(image: np.ndarray, levels: int, kind: str = "97") -> list[np.ndarray]:
    """Multilevel 2-D analysis; returns the bands, coarsest first."""
    analyse = _FILTERS[kind][0]
    low = image
    details = []
    for _ in range(levels):
        lo, hi = analyse(low)                  # along columns (vertical)
        ll, lh = (a.T for a in analyse(lo.T))  # then along rows
        hl, hh = (a.T for a in analyse(hi.T))
        details.append((lh, hl, hh))
        low = ll
    bands = [np.ascontiguousarray(low)]
    for trio in reversed(details):
        bands.extend(np.ascontiguousarray(b) for b in trio)
    return bands


def inverse(bands: list[np.ndarray], levels: int, kind: str = "97") -> np.ndarray:
    """Inverse of `forward`."""
    synthesise = _FILTERS[kind][1]
    low = bands[0]
    for j in range(levels):
        lh, hl, hh = bands[1 + 3 * j: 4 + 3 * j]
        lo = synthesise(low.T, lh.T).T
        hi = synthesise(hl.T, hh.T).T
        low = synthesise(lo, hi)
    return low


def band_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """Shapes of the bands `forward` returns for an image of this size."""
    h, w = height, width
    details = []
    for _ in range(levels):
        hl_, hh_ = -(-h // 2), h // 2
        wl, wh = -(-w // 2), w // 2
        details.append(((hl_, wh), (hh_, wl), (hh_, wh)))
        h, w = hl_, wl
    shapes = [(h, w)]
    for trio in reversed(details):
        shapes.extend(trio)
    return shapes


def mallat_origins(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """Where each band of `band_shapes` (coarsest first, LH/HL/HH per level)
    sits in the kernels' in-place array: low rows and columns first at every
    level."""
    hs, ws = [height], [width]
    for _ in range(levels):
        hs.append(-(-hs[-1] // 2))
        ws.append(-(-ws[-1] // 2))
    origins = [(0, 0)]
    for j in range(levels, 0, -1):
        origins += [(0, ws[j]), (hs[j], 0), (hs[j], ws[j])]
    return origins


def band_levels(levels: int) -> list[int]:
    """Resolution level of each band: 0 for the low band, j for level-j details."""
    out = [0]
    for j in range(levels, 0, -1):
        out.extend([j, j, j])
    return out


@lru_cache(maxsize=None)
def _norms_1d(levels: int, kind: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    # Norms of 1-D synthesis basis functions, measured on impulses placed far
    # from the edges: low[j] after j lowpass steps, high[j] for level-j details.
    n = 64 << levels
    analyse, synthesise = _FILTERS["53linear" if kind == "53" else kind]
    low = [1.0]
    high = [0.0]
    for j in range(1, levels + 1):
        for is_high in (False, True):
            lengths = []
            m = n
            for _ in range(j):
                lengths.append((-(-m // 2), m // 2))
                m = -(-m // 2)
            s = np.zeros((lengths[-1][0], 1))
            d = np.zeros((lengths[-1][1], 1))
            (d if is_high else s)[lengths[-1][1] // 2, 0] = 1.0
            x = synthesise(s, d)
            for k in range(j - 2, -1, -1):
                x = synthesise(x, np.zeros((lengths[k][1], 1)))
            (high if is_high else low).append(float(np.sqrt(np.sum(x * x))))
    return tuple(low), tuple(high)


@lru_cache(maxsize=None)
def _leaf_norm_1d(level: int, high: bool, steps: tuple) -> float:
    # 1-D 9/7 synthesis norm of a coefficient of the level-`level` low (or
    # high) part split further along `steps` (False: low half, True: high),
    # measured on an impulse far from the edges.
    synthesise = _FILTERS["97"][1]
    n = 64 << (level + len(steps) + 2)
    lens = [n]
    for _ in range(level):
        lens.append(-(-lens[-1] // 2))
    chain = [lens[level] if not high else lens[level - 1] // 2]
    for st in steps:
        chain.append(chain[-1] // 2 if st else -(-chain[-1] // 2))
    x = np.zeros((chain[-1], 1))
    x[chain[-1] // 2, 0] = 1.0
    for st, length in reversed(list(zip(steps, chain[:-1]))):
        lo, hi = np.zeros((-(-length // 2), 1)), np.zeros((length // 2, 1))
        if st:
            hi = x
        else:
            lo = x
        x = synthesise(lo, hi)
    if high:
        x = synthesise(np.zeros((lens[level], 1)), x)
    else:
        x = synthesise(x, np.zeros((lens[level - 1] // 2, 1)))
    for k in range(level - 1, 0, -1):
        x = synthesise(x, np.zeros((lens[k - 1] // 2, 1)))
    return float(np.sqrt(np.sum(x * x)))


def packet_weight(level: int, orient: int, path: tuple) -> float:
    """Synthesis-basis norm of the leaf `path` (sub-bands 0 low, 1 LH, 2 HL,
    3 HH at each split) of the level-`level` detail band of orientation
    `orient` (1 LH, 2 HL, 3 HH), over the band's own norm.  Separable: the
    product of the vertical and horizontal 1-D norms."""
    v_high = orient in (2, 3)       # HL, HH: high-pass down the columns
    h_high = orient in (1, 3)       # LH, HH: high-pass along the rows
    # Steps 4 and 5 (low, high half) split one way only: down the columns
    # for LH, along the rows for HL (plan.packet_tree's `along`).
    v_steps = tuple(s in (2, 3) if s < 4 else s == 5 for s in path if s < 4 or orient == 1)
    h_steps = tuple(s in (1, 3) if s < 4 else s == 5 for s in path if s < 4 or orient == 2)
    leaf = _leaf_norm_1d(level, v_high, v_steps) * _leaf_norm_1d(level, h_high, h_steps)
    band = _leaf_norm_1d(level, v_high, ()) * _leaf_norm_1d(level, h_high, ())
    return leaf / band


def band_weights(levels: int, kind: str = "97") -> list[float]:
    """Synthesis-basis norm of each band (coefficient error -> pixel error)."""
    low, high = _norms_1d(levels, kind)
    weights = [low[levels] ** 2]
    for j in range(levels, 0, -1):
        weights.extend([low[j] * high[j], high[j] * low[j], high[j] ** 2])
    return weights
