# Everything about a stream that follows from its header alone, shared by the
# encoder and the decoder: the band layout and block trees of the coder, each
# band's scale (the norm of its synthesis basis, so that coefficient error
# stands for pixel error), the region of interest's coefficients, and the
# colour transform.  Cached per header: the ROV sends image after image of one
# size, and the console decodes prefix after prefix of one stream.

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .header import FRACTION_BITS, Header
from .transform import band_levels, band_shapes, band_weights, levels_for, mallat_origins, packet_weight

# Empirical: plane alignment between bands: the low band raised a little
# (tuned on the samples), the finest details at their synthesis norm.  On the
# 52 photograph variants of `rovlink bench debt`, the finest details at 1.0
# instead of 1.12: +0.004/+0.008/+0.007/+0.006/+0.018 dB mean at 500/1000/
# 2000/4000/8000 B (-0.003 at 250), brick/crop at 8000 B -0.05 -> +0.004 dB
# to JPEG 2000; 0.95 and 1.05 less, the low band at 1.0 or 1.2 less.  (It had
# been kept at 1.12 because PSNR stepped back byte by byte more often on small
# pictures; those steps are thousandths of a dB, see tests/debt.)
FINE_BAND_FACTOR = {0: 1.1, 1: 1.0}
ROI_REACH = (1, 1)  # see _roi_ranges (5/3 streams only, sent when lossless; 9/7 ones: sa_masks)
ROI_REACH_BY_LEVEL = {1: (0, 0)}  # finest details: only what lies over the ROI
COARSE_LEVEL = 4          # details this coarse or coarser share one context group
COARSE_GROUP = 4
KMAX = 11                # quadtree depth bound: 2**10 >= MAX_SIDE

# Irreversible colour transform (ITU-R BT.601 YCbCr, as JPEG 2000's ICT): its
# luma row is what a grey picture of a colour image shows (`mono`) and what the
# texture test looks at.  9/7 colour streams are coded in a rotation of RGB of
# their own (`codec.colour_rotation`), orthonormal, so each component's error
# counts as it does in RGB squared error: they need no per-component weight.
ICT = np.array([[0.299, 0.587, 0.114],
                 [-0.168736, -0.331264, 0.5],
                 [0.5, -0.418688, -0.081312]])


# ---------------------------------------------------------------- layout

@dataclass
class Layout:
    shapes: list            # per global band: (h, w)
    comp: list              # per global band: component index
    index: list             # per global band: band index within its component
    binfo: np.ndarray
    noff: np.ndarray
    nw: np.ndarray
    seg: np.ndarray
    ncoef: int
    nnodes: int


def context_group(level: int, orient: int) -> int:
    """The coder's band class within a component (0..7): which bands share
    their adaptive contexts.

    By orientation (LH, HL, HH) across the finer levels, the coarse details
    in one group, the low band alone.  Measured on scikit-image's photographs
    against one group per level (the first choice): +0.03 to +0.06 dB at
    every budget 250-8000 B; statistics differ more between orientations
    than between levels, and fewer groups learn faster at low rates."""
    if level == 0:
        return 0
    return COARSE_GROUP if level >= COARSE_LEVEL else orient


def band_orient(i: int) -> int:
    """Orientation of Mallat band i: 0 the low band, then 1 LH, 2 HL, 3 HH."""
    return 0 if i == 0 else (i - 1) % 3 + 1


@lru_cache(maxsize=16)
def packet_tree(height: int, width: int, levels: int, packets=()) -> tuple[tuple, tuple]:
    """The bands of one component in coding order, and the splits that make them.

    Bands: (Mallat band index, path, shape, origin in the Mallat array,
    resolution level, orientation).  A detail band of level j is split (a
    wavelet packet) as many times as j appears in `packets`: once into its
    four sub-bands 0..3 (low, LH, HL, HH of that band), twice into the four of
    each of those.  path is () for an unsplit band, else the sub-band chosen
    at each split; the leaves are coded in the band's place, depth first.  A
    leaf's orientation is its last detail step's (the band's own when every
    step took the low half).

    An entry -(ALONG_STEP * orient + j) in `packets` splits the level-j
    detail band of that orientation (1 LH, 2 HL) once more in one direction
    only, along its edges (`along` below; HH bands are left whole), as many
    times as it appears (`along_splits`).

    Splits: (origin, shape, depth, kind) of every region split once more,
    coarse ones (depth 0) before the regions they hold; kind 0 both ways, 1
    down the columns only, 2 along the rows only (`kernels.packets97`)."""
    shapes = band_shapes(height, width, levels)
    res = band_levels(levels)
    origins = mallat_origins(height, width, levels)
    bands, splits = [], []

    def along(i, path, shape, origin, depth, orient):
        # A detail band split `depth` times in one direction, along its
        # edges (down the columns for LH, whose edges stand upright; along
        # the rows for HL), each time its low half again: path steps 4 (the
        # low half) and 5 (the high half), the low leaf first.
        if depth == 0 or orient not in (1, 2):
            bands.append((i, path, shape, origin, res[i], orient))
            return
        kind = 1 if orient == 1 else 2
        splits.append((origin, shape, len(path), kind))
        bh, bw = shape
        if kind == 1:
            low, high = (-(-bh // 2), bw), (bh // 2, bw)
            high_origin = (origin[0] + low[0], origin[1])
        else:
            low, high = (bh, -(-bw // 2)), (bh, bw // 2)
            high_origin = (origin[0], origin[1] + low[1])
        along(i, path + (4,), low, origin, depth - 1, orient)
        bands.append((i, path + (5,), high, high_origin, res[i], orient))

    def walk(i, path, shape, origin, depth, orient):
        if depth == 0:
            along(i, path, shape, origin, packets.count(-(ALONG_STEP * orient + res[i])) if i else 0, orient)
            return
        splits.append((origin, shape, len(path), 0))
        bh, bw = shape
        hl, wl = -(-bh // 2), -(-bw // 2)
        sub_origins = [(0, 0), (0, wl), (hl, 0), (hl, wl)]
        for sub, sub_shape in enumerate(band_shapes(bh, bw, 1)):
            walk(i, path + (sub,), sub_shape,
                 (origin[0] + sub_origins[sub][0], origin[1] + sub_origins[sub][1]),
                 depth - 1, orient if sub == 0 else sub)

    for i, shape in enumerate(shapes):
        walk(i, (), shape, origins[i], packets.count(res[i]) if i else 0, band_orient(i))
    return tuple(bands), tuple(sorted(splits, key=lambda s: s[2]))


ALONG_STEP = 16          # see packet_tree: -(ALONG_STEP * orient + level), a level below it


def along_splits(lh: int, hl: int, levels: int) -> tuple:
    """The `packets` of a layout whose LH bands are split `lh` times down
    their columns and HL bands `hl` times along their rows, at every level
    up to `levels`."""
    return tuple(-(ALONG_STEP * orient + j) for j in range(1, levels + 1)
                 for orient, depth in ((1, lh), (2, hl)) for _ in range(depth))


def packet_level(entry: int) -> int:
    """The level a `packets` entry splits (see packet_tree)."""
    return entry if entry > 0 else -entry % ALONG_STEP


def packet_bands(height: int, width: int, levels: int, packets=()) -> tuple:
    """The bands of `packet_tree`."""
    return packet_tree(height, width, levels, tuple(packets))[0]


PACKET_GROUP = 5          # context groups 5..7: the LH/HL/HH sub-bands of split bands


def packet_group(level: int, orient: int, path: tuple) -> int:
    """Context group of a band in a packet layout: a leaf whose steps all took
    the low half as the band itself, any other in groups 5-7 by its own
    orientation.  (Measured on brick, crop and scaled down, 1000-8000 B, one
    split: grouping them by the split band's orientation, with the dyadic
    groups, or all four with the split band: within +-0.04 dB.)"""
    if not any(s & 3 for s in path):
        return context_group(level, orient)
    return PACKET_GROUP + orient - 1


def layout_for(height: int, width: int, levels: int, ncomp: int, packets=()) -> Layout:
    """The coder's bands, in coding order (band by band, the components of
    each in turn), with their block trees.  binfo per band: offset, height,
    width, quadtree depth, context class, orientation, parent band (-1 for
    none), then where the other orientations of its level lie (first band,
    step: the same component's), and 1 when the parent is half its size (0:
    the same size, under wavelet packets), then for a colour component
    after the first the same band of the first (-1 otherwise).  (The coder once looked at
    b - (orient - 1) + 0..2 for the other orientations, for colour the other
    components' bands: the right ones gain +0.001 to +0.004 dB mean on the
    colour photographs.)"""
    bands = packet_bands(height, width, levels, packets)
    index = {(i, path): n for n, (i, path, *_rest) in enumerate(bands)}
    order = [(c, n) for n in range(len(bands)) for c in range(ncomp)]
    nb = len(order)
    binfo = np.zeros((nb, 11), dtype=np.int64)
    noff = np.zeros((nb, KMAX + 1), dtype=np.int64)
    nw = np.zeros((nb, KMAX + 1), dtype=np.int64)
    count = np.zeros(KMAX + 2, dtype=np.int64)
    off = 0
    noffset = 0
    for b, (c, n) in enumerate(order):
        i, path, (h, w), _origin, level, orient = bands[n]
        k_root = max(0, math.ceil(math.log2(max(h, w)))) if h and w else 0
        # Parent: the same leaf of the band one level coarser (half its size),
        # or, that band split once less, the leaf one step up (its size and
        # place: +0.07 to +0.23 dB on brick at 1000-8000 B over none); none
        # otherwise.
        parent = -1
        step = 1
        if i > 3:
            pn = index.get((i - 3, path))
            if pn is not None:
                parent = pn * ncomp + c
            elif path and (i - 3, path[:-1]) in index:
                parent = index[(i - 3, path[:-1])] * ncomp + c
                step = 0
        group = packet_group(level, orient, path)
        step_o = ncomp
        if any(s >= 4 for s in path):
            first, step_o = n, 0                # split one way: no other orientation at its place
        elif path and path[-1] >= 1:
            first = n - (path[-1] - 1)          # the other detail leaves of this split
        else:
            o = band_orient(i)
            first = index.get((i - (o - 1), path), n) if o else n
        binfo[b] = (off, h, w, k_root, (1 if c else 0) * 8 + group, orient, parent,
                    first * ncomp + c, step_o, step, b - c if c else -1)
        off += h * w
        if h and w:
            count[0] += h * w
            for k in range(1, k_root + 1):
                hk, wk = -(-h // (1 << k)), -(-w // (1 << k))
                noff[b, k] = noffset
                nw[b, k] = wk
                noffset += hk * wk
                count[k] += hk * wk
    seg = np.zeros(KMAX + 2, dtype=np.int64)
    seg[1:] = np.cumsum(count[:KMAX + 1])
    return Layout(
        [bands[n][2] for _, n in order], [c for c, _ in order], [n for _, n in order],
        binfo, noff, nw, seg, off, noffset,
    )


def pyramid(values: np.ndarray, lay: Layout, use_max: bool) -> np.ndarray:
    """Per quadtree node the max (or min) of `values` over its block."""
    out = np.zeros(max(lay.nnodes, 1), dtype=np.int64)
    pad = 0 if use_max else np.iinfo(np.int64).max
    reduce = np.maximum if use_max else np.minimum
    for b in range(len(lay.shapes)):
        off, h, w, k_root = lay.binfo[b, :4]
        if not h or not w:
            continue
        level = values[off:off + h * w].reshape(h, w)
        for k in range(1, k_root + 1):
            hh, ww = level.shape
            if hh % 2 or ww % 2:
                padded = np.full((hh + hh % 2, ww + ww % 2), pad, dtype=np.int64)
                padded[:hh, :ww] = level
                level = padded
            level = reduce(reduce(level[0::2, 0::2], level[0::2, 1::2]),
                           reduce(level[1::2, 0::2], level[1::2, 1::2]))
            start = lay.noff[b, k]
            out[start:start + level.size] = level.ravel()
    return out


def _roi_ranges(a: int, b: int, n: int, levels: int):
    # Per level, the low and high coefficient ranges whose synthesis basis
    # reaches pixels [a, b) within ROI_REACH samples: low coefficient m
    # shapes pixels 2m +- reach, high coefficient m pixels 2m + 1 +- reach.
    # (The full 9/7 supports are 3 and 4; the far tails weigh little and
    # would make every coarse coefficient part of the region.)
    out = []
    for level in range(levels):
        rl, rh = ROI_REACH_BY_LEVEL.get(level + 1, ROI_REACH)
        nl, nh = -(-n // 2), n // 2
        low = (max(0, -((rl - a) // 2)), min(nl, (b - 1 + rl) // 2 + 1))
        high = (max(0, -((1 + rh - a) // 2)), min(nh, (b - 2 + rh) // 2 + 1))
        if low[0] >= low[1]:
            low = (min(max(0, a // 2), nl - 1), min(max(0, a // 2), nl - 1) + 1)
        out.append((low, high))
        a, b, n = low[0], low[1], nl
    return out


def _rect_mask(shape, rows, cols) -> np.ndarray:
    m = np.zeros(shape, dtype=bool)
    m[rows[0]:rows[1], cols[0]:cols[1]] = True
    return m


def sa_masks(h: Header, levels: int) -> list[np.ndarray]:
    """Per band of one component, the 9/7 coefficients of the region.

    The 9/7 transform of a stream with an ROI is shape-adaptive
    (`kernels.forward97`): the rectangle and the rest are lifted apart, so
    every coefficient belongs wholly to one side and the region is exactly
    the coefficients at its positions, level after level on its low-pass
    samples.  (Before this, the transform ran across the edge and each
    coefficient was raised by the share of its energy inside: the wide
    coarse coefficients over the edge then carried the outside too, and the
    seabed's ROI at 1000 B SHIFT 6 was 0.75 dB below its crop coded alone.)"""
    shapes = band_shapes(h.height, h.width, levels)
    x0, y0, x1, y1 = h.roi
    if levels == 0:
        full = np.zeros(shapes[0], dtype=bool)
        full[y0:y1, x0:x1] = True
        return [full]
    details = []
    for _ in range(levels):
        if x0 < x1 and y0 < y1:
            lo_r, hi_r = ((y0 + 1) // 2, (y1 + 1) // 2), (y0 // 2, y1 // 2)
            lo_c, hi_c = ((x0 + 1) // 2, (x1 + 1) // 2), (x0 // 2, x1 // 2)
        else:
            lo_r = hi_r = lo_c = hi_c = (0, 0)
        details.append(((lo_r, hi_c), (hi_r, lo_c), (hi_r, hi_c)))  # LH, HL, HH
        x0, y0, x1, y1 = ((v + 1) // 2 for v in (x0, y0, x1, y1))
        last = (lo_r, lo_c)

    masks = [_rect_mask(shapes[0], *last)]
    for j, trio in enumerate(reversed(details)):
        masks.extend(_rect_mask(shapes[1 + 3 * j + k], *rc) for k, rc in enumerate(trio))
    return masks


def roi_masks(h: Header, levels: int) -> list[np.ndarray] | None:
    """Per band of one component, a boolean mask of ROI coefficients."""
    if h.roi is None:
        return None
    x0, y0, x1, y1 = h.roi
    rows = _roi_ranges(y0, y1, h.height, levels)
    cols = _roi_ranges(x0, x1, h.width, levels)
    shapes = band_shapes(h.height, h.width, levels)
    masks = []

    if levels == 0:
        full = np.zeros(shapes[0], dtype=bool)
        full[y0:y1, x0:x1] = True
        return [full]
    masks.append(_rect_mask(shapes[0], rows[-1][0], cols[-1][0]))
    for j in range(levels, 0, -1):
        r, c = rows[j - 1], cols[j - 1]
        i = 1 + 3 * (levels - j)
        masks.append(_rect_mask(shapes[i], r[0], c[1]))      # LH: low rows, high columns
        masks.append(_rect_mask(shapes[i + 1], r[1], c[0]))  # HL
        masks.append(_rect_mask(shapes[i + 2], r[1], c[1]))  # HH
    return masks


def scales_for(h: Header, levels: int, ncomp: int) -> list[float] | list[int]:
    """Per (component, band): the factor (9/7) or left shift (5/3) applied."""
    if h.reversible:
        w = band_weights(levels, "53")
        lo = min(w)
        shifts = [max(0, int(round(math.log2(v / lo)))) for v in w]
        return [[s for s in shifts] for _ in range(ncomp)]
    w = band_weights(levels, "97")
    res = band_levels(levels)
    w = [v * FINE_BAND_FACTOR.get(r, 1.0) for v, r in zip(w, res)]
    return [[v * 2.0 ** FRACTION_BITS for v in w] for _ in range(ncomp)]


@dataclass
class Plan:
    """Everything that depends only on the header, shared by encode and decode."""
    levels: int
    lay: Layout
    ccls: np.ndarray        # band class of each coefficient (contexts), uint8
    cfloor: np.ndarray      # lowest coded plane of each coefficient
    node_floor: np.ndarray  # min of cfloor over each quadtree node, uint8
    masks: list | None      # ROI mask per band of one component
    scales: list            # per component and band: factor (9/7) or shift (5/3)
    roi: np.ndarray | None = None        # 9/7: the kernels' (x0, y0, x1, y1), zeros for none
    pos: np.ndarray | None = None        # 9/7: index of each coefficient in the Mallat arrays
    scale: np.ndarray | None = None      # 9/7: its scale (band weight, ROI raise)
    inv_scale: np.ndarray | None = None
    cfloor8: np.ndarray | None = None    # cfloor as uint8, for the coder (small in cache)
    croi: np.ndarray | None = None       # coefficient raised as part of the ROI
    cdef: np.ndarray | None = None       # planes below the top it cannot reach
    cdef8: np.ndarray | None = None
    node_def: np.ndarray | None = None   # min of cdef over each quadtree node
    packets: tuple = ()                  # detail levels split once more (wavelet packets)
    splits: tuple = ()                   # 9/7: the regions split for them (packet_tree), coarse first
    err_weight: np.ndarray | None = None  # 9/7: scaled coefficient error -> RGB-weighted pixel error


@lru_cache(maxsize=8)
def plan_for(height: int, width: int, ncomp: int, reversible: bool, roi, shift: int,
             levels: int | None = None, packets: tuple = ()) -> Plan:
    # Cached: the ROV sends image after image of one size, and the console
    # decodes prefix after prefix of one stream.  `levels`: the decomposition
    # depth, by default the one the size gives (a residual of the two-level
    # mode is coded with fewer).  `packets`: detail levels split once more
    # (9/7 without an ROI only; see packet_tree).
    if levels is None:
        levels = levels_for(height, width)
    packets = tuple(j for j in packets if 1 <= packet_level(j) <= levels)
    if packets and (reversible or roi is not None):
        raise ValueError("wavelet packets are for 9/7 streams without a region of interest")
    probe = Header(width, height, ncomp == 3, reversible, 0, roi, shift)
    lay = layout_for(height, width, levels, ncomp, packets)
    plan_bands, splits = packet_tree(height, width, levels, packets)
    if roi is None:
        masks = None
    else:
        masks = roi_masks(probe, levels) if reversible else sa_masks(probe, levels)
    scales = scales_for(probe, levels, ncomp)
    n = max(lay.ncoef, 1)
    sizes = lay.binfo[:, 1] * lay.binfo[:, 2]
    ccls = np.zeros(n, dtype=np.uint8)
    if lay.ncoef:
        ccls[:] = np.repeat(lay.binfo[:, 4], sizes)
    cfloor = np.zeros(n, dtype=np.int64)
    plan = Plan(levels, lay, ccls, cfloor, np.zeros(1, dtype=np.int64), masks, scales, packets=packets,
                splits=splits)
    if reversible:
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if not bh or not bw:
                continue
            c, i = lay.comp[b], lay.index[b]
            f = np.full((bh, bw), scales[c][i], dtype=np.int64)
            if masks is not None:
                f[masks[i]] += shift
            cfloor[off:off + bh * bw] = f.ravel()
    else:
        pos = np.zeros(n, dtype=np.int64)
        scale = np.ones(n, dtype=np.float64)
        err_weight = np.ones(n, dtype=np.float64)
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if not bh or not bw:
                continue
            c, i = lay.comp[b], lay.index[b]
            i, path, _shape, (y0, x0), level, _orient = plan_bands[i]
            yy, xx = np.mgrid[0:bh, 0:bw]
            pos[off:off + bh * bw] = (c * height * width + (y0 + yy) * width + x0 + xx).ravel()
            # A leaf of a split band: its basis is the band's, split further.
            weight = packet_weight(level, band_orient(i), path) if path else 1.0
            sc = np.full((bh, bw), scales[c][i] * weight)
            err_weight[off:off + bh * bw] = 1.0 / (2.0 ** FRACTION_BITS * FINE_BAND_FACTOR.get(level, 1.0))
            if masks is not None:
                sc[masks[i]] *= 2.0 ** shift
            scale[off:off + bh * bw] = sc.ravel()
        plan.pos, plan.scale, plan.inv_scale = pos, scale, 1.0 / scale
        plan.err_weight = err_weight
        plan.roi = np.array(roi if masks is not None else (0, 0, 0, 0), dtype=np.int64)
    # The coder's floor bytes: lowest coded plane, plus 128 inside the ROI.
    croi = np.zeros(n, dtype=np.int64)
    if masks is not None:
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if bh and bw:
                croi[off:off + bh * bw] = masks[lay.index[b]].ravel()
    plan.croi = croi.astype(bool)
    # The background stays under the top less `shift` planes: the coder
    # does not test it there.
    cdef = np.where(plan.croi, 0, shift) if masks is not None else np.zeros(n, dtype=np.int64)
    plan.cdef = cdef
    plan.cdef8 = cdef.astype(np.uint8)
    plan.node_def = pyramid(cdef, lay, False).astype(np.uint8)
    plan.node_floor = (pyramid(cfloor, lay, False) | (pyramid(croi, lay, True) << 7)).astype(np.uint8)
    plan.cfloor8 = (cfloor | (croi << 7)).astype(np.uint8)
    return plan
