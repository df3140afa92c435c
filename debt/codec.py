# DEBT's public functions: `encode(image, budget, ...) -> bytes` and
# `decode(data) -> image`, plus the stream header.
#
# Plan for encode: validate everything at the edge (one ValueError each), turn
# the image into components (grey, or YCbCr), transform each (CDF 9/7, or the
# integer 5/3 when a lossless stream might fit the budget), scale every band by
# the norm of its synthesis basis so that coefficient error stands for pixel
# error, raise the region of interest SHIFT planes (general scaling; the 9/7
# transform is then shape-adaptive, region and rest lifted apart, so that the
# region's coefficients describe it alone), and hand the magnitudes to
# the bit-plane coder, which stops at the byte budget.  decode reverses it from
# whatever prefix it gets, reconstructing each coefficient at the middle of the
# interval its decoded bits leave open.
#
# Header, most significant bit first, then padded to a byte with a check:
#     MAGIC:4 (1011)  COLOUR:1  REVERSIBLE:1  ROI:1  WIDTH:10  HEIGHT:10  TOP:6
#     if ROI:  SHIFT:4  X0:10  Y0:10  X1:10  Y1:10
#     CHECK: the remaining bits of the last byte (7 without ROI, 3 with),
#            the low bits of a CRC-8 of the header with CHECK zero
# so 5 bytes without a region of interest and 10 with one.  The decomposition
# depth follows from the size (`transform.levels_for`); TOP is the highest
# bit plane coded.

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from . import coder, kernels
from .transform import band_levels, band_shapes, band_weights, forward, inverse, levels_for

MAGIC = 0b1011
MAX_SIDE = 1023          # 10-bit sizes and ROI corners, as in the IMAGE order
MAX_SHIFT = 15
FRACTION_BITS = 4        # 9/7 magnitudes are coded down to 1/16 of a unit
FINE_BAND_FACTOR = {0: 1.1, 1: 1.12}  # empirical: plane alignment between bands, tuned on the samples
ROI_REACH = (1, 1)  # see _roi_ranges (5/3 streams only, sent when lossless; 9/7 ones: _sa_masks)
ROI_REACH_BY_LEVEL = {1: (0, 0)}  # finest details: only what lies over the ROI
KMAX = 11                # quadtree depth bound: 2**10 >= MAX_SIDE

# Irreversible colour transform (ITU-R BT.601 YCbCr, as JPEG 2000's ICT).
_ICT = np.array([[0.299, 0.587, 0.114],
                 [-0.168736, -0.331264, 0.5],
                 [0.5, -0.418688, -0.081312]])
_ICT_INV = np.linalg.inv(_ICT)
CHROMA = 1.0  # chroma weight beyond the RGB-error weighting (1.0 measured best)
# Weight of each component so that its error counts as it does in RGB squared
# error (norm of its column of the inverse over sqrt(3)); chroma then gets
# fewer bits simply because it holds less energy.
_COLOUR_WEIGHTS = np.sqrt((_ICT_INV ** 2).sum(axis=0) / 3.0) * np.array([1.0, CHROMA, CHROMA])


@dataclass(frozen=True)
class Header:
    width: int
    height: int
    colour: bool
    reversible: bool
    top: int
    roi: tuple[int, int, int, int] | None = None
    shift: int = 0

    @property
    def size(self) -> int:
        return header_size(self.roi is not None)


def header_size(has_roi: bool) -> int:
    return 10 if has_roi else 5


def _crc8(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def pack_header(h: Header) -> bytes:
    fields = [(MAGIC, 4), (int(h.colour), 1), (int(h.reversible), 1), (int(h.roi is not None), 1),
              (h.width, 10), (h.height, 10), (h.top, 6)]
    if h.roi is not None:
        fields.append((h.shift, 4))
        fields.extend((v, 10) for v in h.roi)
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
        raise ValueError("empty DEBT stream")
    if data[0] >> 4 != MAGIC:
        raise ValueError("not a DEBT stream (bad magic)")
    has_roi = bool(data[0] & 0x02)
    size = header_size(has_roi)
    if len(data) < size:
        raise ValueError(f"DEBT stream of {len(data)} bytes is shorter than its {size}-byte header")
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
    if has_roi:
        shift = take(4)
        roi = (take(10), take(10), take(10), take(10))
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
    h = Header(width, height, colour, reversible, top, roi, shift)
    if top > _max_top(h):
        raise ValueError("corrupted DEBT header (bit-plane count out of range)")
    return h


def _max_top(h: Header) -> int:
    # Generous bound on the top plane a real image can produce.
    return 20 + FRACTION_BITS + h.shift + (3 if h.reversible else 0)


# ---------------------------------------------------------------- validation

def _as_image(image, mono) -> tuple[np.ndarray, bool]:
    """Validate the input image; return (uint8 array, colour?)."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, not {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"image must be uint8, not {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 3:
        colour = True
    elif image.ndim == 2:
        colour = False
    else:
        raise ValueError(f"image must be HxW (grey) or HxWx3 (RGB), not shape {image.shape}")
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        raise ValueError(f"image is empty (shape {image.shape})")
    if h > MAX_SIDE or w > MAX_SIDE:
        raise ValueError(f"image is {w}x{h}; DEBT codes images up to {MAX_SIDE} pixels a side")
    if mono is not None and not isinstance(mono, (bool, np.bool_)):
        raise ValueError(f"mono must be True, False or None, not {mono!r}")
    if colour and (mono is None or not mono):
        return image, True
    if colour:
        luma = image.astype(np.float64) @ _ICT[0]
        return np.clip(np.rint(luma), 0, 255).astype(np.uint8), False
    # A grey image is always coded as grey, whatever `mono` says.
    return image, False


def _as_roi(roi, shift, width, height):
    if isinstance(shift, bool) or not isinstance(shift, (int, np.integer)):
        raise ValueError(f"shift must be an integer 0..{MAX_SHIFT}, not {shift!r}")
    shift = int(shift)
    if not 0 <= shift <= MAX_SHIFT:
        raise ValueError(f"shift must be 0..{MAX_SHIFT}, not {shift}")
    if roi is None:
        return None, 0
    try:
        values = tuple(roi)
    except TypeError:
        raise ValueError(f"roi must be (x0, y0, x1, y1), not {roi!r}") from None
    if len(values) != 4 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                   for v in values):
        raise ValueError(f"roi must be four integers (x0, y0, x1, y1), not {roi!r}")
    x0, y0, x1, y1 = (int(v) for v in values)
    if (x0, y0, x1, y1) == (0, 0, 0, 0):
        return None, 0          # the IMAGE order's "no region of interest"
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise ValueError(f"roi {(x0, y0, x1, y1)} is not a non-empty rectangle inside the "
                         f"{width}x{height} image (x1, y1 exclusive)")
    if shift == 0:
        return None, 0          # no priority: the rectangle changes nothing
    return (x0, y0, x1, y1), shift


# ---------------------------------------------------------------- layout

@dataclass
class _Layout:
    shapes: list            # per global band: (h, w)
    comp: list              # per global band: component index
    index: list             # per global band: band index within its component
    binfo: np.ndarray
    noff: np.ndarray
    nw: np.ndarray
    seg: np.ndarray
    ncoef: int
    nnodes: int


def _layout(height: int, width: int, levels: int, ncomp: int) -> _Layout:
    shapes1 = band_shapes(height, width, levels)
    res = band_levels(levels)
    order = [(c, i) for i in range(len(shapes1)) for c in range(ncomp)]
    nb = len(order)
    binfo = np.zeros((nb, 7), dtype=np.int64)
    noff = np.zeros((nb, KMAX + 1), dtype=np.int64)
    nw = np.zeros((nb, KMAX + 1), dtype=np.int64)
    count = np.zeros(KMAX + 2, dtype=np.int64)
    off = 0
    noffset = 0
    for b, (c, i) in enumerate(order):
        h, w = shapes1[i]
        k_root = max(0, math.ceil(math.log2(max(h, w)))) if h and w else 0
        parent = (i - 3) * ncomp + c if i > 3 else -1
        binfo[b] = (off, h, w, k_root, (1 if c else 0) * 8 + res[i], 0 if i == 0 else (i - 1) % 3 + 1,
                    parent)
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
    return _Layout(
        [shapes1[i] for _, i in order], [c for c, _ in order], [i for _, i in order],
        binfo, noff, nw, seg, off, noffset,
    )


def _pyramid(values: np.ndarray, lay: _Layout, use_max: bool) -> np.ndarray:
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


def _sa_masks(h: Header, levels: int) -> list[np.ndarray]:
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


def _roi_masks(h: Header, levels: int) -> list[np.ndarray] | None:
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


# ---------------------------------------------------------------- components

def _components(img: np.ndarray, colour: bool, reversible: bool) -> list[np.ndarray]:
    if reversible:
        x = img.astype(np.int64)
        if not colour:
            return [x - 128]
        r, g, b = x[..., 0], x[..., 1], x[..., 2]
        return [((r + 2 * g + b) >> 2) - 128, b - g, r - g]
    x = img.astype(np.float64)
    if not colour:
        return [x - 128.0]
    ycc = x @ _ICT.T
    return [ycc[..., 0] - 128.0, ycc[..., 1].copy(), ycc[..., 2].copy()]


def _image(comps: list[np.ndarray], colour: bool, reversible: bool) -> np.ndarray:
    if reversible:
        if not colour:
            out = comps[0] + 128
        else:
            y, cb, cr = comps
            g = y + 128 - ((cb + cr) >> 2)
            out = np.stack([cr + g, g, cb + g], axis=-1)
        return np.clip(out, 0, 255).astype(np.uint8)
    if not colour:
        out = np.empty(comps[0].shape, dtype=np.uint8)
        kernels.to_uint8(np.ascontiguousarray(comps[0]), 128.0, out)
        return out
    else:
        ycc = np.stack([comps[0] + 128.0, comps[1], comps[2]], axis=-1)
        out = ycc @ _ICT_INV.T
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _scales(h: Header, levels: int, ncomp: int) -> list[float] | list[int]:
    """Per (component, band): the factor (9/7) or left shift (5/3) applied."""
    if h.reversible:
        w = band_weights(levels, "53")
        lo = min(w)
        shifts = [max(0, int(round(math.log2(v / lo)))) for v in w]
        return [[s for s in shifts] for _ in range(ncomp)]
    w = band_weights(levels, "97")
    res = band_levels(levels)
    w = [v * FINE_BAND_FACTOR.get(r, 1.0) for v, r in zip(w, res)]
    comp_w = _COLOUR_WEIGHTS if ncomp == 3 else [1.0]
    return [[v * comp_w[c] * 2.0 ** FRACTION_BITS for v in w] for c in range(ncomp)]


# ---------------------------------------------------------------- plan

@dataclass
class _Plan:
    """Everything that depends only on the header, shared by encode and decode."""
    levels: int
    lay: _Layout
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


@lru_cache(maxsize=8)
def _plan(height: int, width: int, ncomp: int, reversible: bool, roi, shift: int) -> _Plan:
    # Cached: the ROV sends image after image of one size, and the console
    # decodes prefix after prefix of one stream.
    levels = levels_for(height, width)
    probe = Header(width, height, ncomp == 3, reversible, 0, roi, shift)
    lay = _layout(height, width, levels, ncomp)
    if roi is None:
        masks = None
    else:
        masks = _roi_masks(probe, levels) if reversible else _sa_masks(probe, levels)
    scales = _scales(probe, levels, ncomp)
    n = max(lay.ncoef, 1)
    sizes = lay.binfo[:, 1] * lay.binfo[:, 2]
    ccls = np.zeros(n, dtype=np.uint8)
    if lay.ncoef:
        ccls[:] = np.repeat(lay.binfo[:, 4], sizes)
    cfloor = np.zeros(n, dtype=np.int64)
    plan = _Plan(levels, lay, ccls, cfloor, np.zeros(1, dtype=np.int64), masks, scales)
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
        hs, ws = [height], [width]
        for _ in range(levels):
            hs.append(-(-hs[-1] // 2))
            ws.append(-(-ws[-1] // 2))
        origins = [(0, 0)]
        for j in range(levels, 0, -1):
            origins += [(0, ws[j]), (hs[j], 0), (hs[j], ws[j])]
        pos = np.zeros(n, dtype=np.int64)
        scale = np.ones(n, dtype=np.float64)
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if not bh or not bw:
                continue
            c, i = lay.comp[b], lay.index[b]
            y0, x0 = origins[i]
            yy, xx = np.mgrid[0:bh, 0:bw]
            pos[off:off + bh * bw] = (c * height * width + (y0 + yy) * width + x0 + xx).ravel()
            sc = np.full((bh, bw), scales[c][i])
            if masks is not None:
                sc[masks[i]] *= 2.0 ** shift
            scale[off:off + bh * bw] = sc.ravel()
        plan.pos, plan.scale, plan.inv_scale = pos, scale, 1.0 / scale
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
    plan.node_def = _pyramid(cdef, lay, False).astype(np.uint8)
    plan.node_floor = (_pyramid(cfloor, lay, False) | (_pyramid(croi, lay, True) << 7)).astype(np.uint8)
    plan.cfloor8 = (cfloor | (croi << 7)).astype(np.uint8)
    return plan


# ---------------------------------------------------------------- encode

def _encode_payload(img: np.ndarray, colour: bool, reversible: bool, roi, shift: int,
                    limit: int):
    """Returns (header, payload bytes, complete?)."""
    height, width = img.shape[:2]
    ncomp = 3 if colour else 1
    plan = _plan(height, width, ncomp, reversible, roi, shift)
    lay = plan.lay
    n = max(lay.ncoef, 1)
    mag = np.zeros(n, dtype=np.int64)
    neg = np.zeros(n, dtype=np.uint8)
    comps = _components(img, colour, reversible)
    if reversible:
        comp_bands = [forward(c, plan.levels, "53") for c in comps]
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if not bh or not bw:
                continue
            band = comp_bands[lay.comp[b]][lay.index[b]]
            f = plan.cfloor[off:off + bh * bw].reshape(bh, bw)
            mag[off:off + bh * bw] = (np.abs(band) << f).ravel()
            neg[off:off + bh * bw] = (band < 0).ravel()
    else:
        flat = np.empty(ncomp * height * width, dtype=np.float64)
        for c, comp in enumerate(comps):
            a = np.ascontiguousarray(comp, dtype=np.float64)
            kernels.forward97(a, plan.levels, plan.roi)
            flat[c * height * width:(c + 1) * height * width] = a.ravel()
        kernels.gather97(flat, plan.pos, plan.scale, mag, neg)
    # Every coefficient must stay below its own ceiling, `cdef` planes under
    # the top (the coder does not test it above): raise the top to make room.
    nz = mag > 0
    top = 0
    if nz.any():
        bits = np.frexp(mag[nz].astype(np.float64))[1] - 1  # exact below 2**53
        top = max(int((bits + plan.cdef[nz]).max()), 0)
    header = Header(width, height, colour, reversible, top, roi, shift)
    node_max = np.zeros(max(lay.nnodes, 1), dtype=np.int64)
    kernels.max_pyramid(mag, lay.binfo, lay.noff, lay.nw, node_max)
    buf = np.zeros(limit + 64, dtype=np.uint8)
    st = coder.encoder_state(limit + 1)
    rec = np.zeros_like(mag)
    pk = np.full(n, -1, dtype=np.int8)
    sgn = np.zeros(n, dtype=np.uint8)
    complete = coder.run(0, mag, neg, plan.cfloor8, plan.ccls, node_max, plan.node_floor,
                         lay.binfo, lay.noff, lay.nw, lay.seg, KMAX, top, buf, st, rec, pk, sgn,
                         plan.cdef8, plan.node_def)
    if complete:
        n = coder.flush(st, buf)
        n = min(n, buf.shape[0])
        payload = bytes(buf[1:n])
        if len(payload) <= limit:
            return header, payload, True
    return header, bytes(buf[1:limit + 1]), False


def encode(image: np.ndarray, budget: int, roi=None, shift: int = 0, mono=None) -> bytes:
    """Code `image` into at most `budget` bytes of embedded DEBT stream.

    image: HxW uint8 (grey) or HxWx3 uint8 (RGB), at most 1023 px a side.
    roi: (x0, y0, x1, y1) pixel rectangle, (x1, y1) exclusive, raised `shift`
    bit planes (0..15) above the rest; (0, 0, 0, 0) or shift 0 mean none.
    mono: code luminance only (default True for grey, False for colour).
    The stream is exactly `budget` bytes unless the image is coded losslessly
    in fewer; every prefix holding the header decodes.
    """
    img, colour = _as_image(image, mono)
    height, width = img.shape[:2]
    roi, shift = _as_roi(roi, shift, width, height)
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)):
        raise ValueError(f"budget must be an integer number of bytes, not {budget!r}")
    budget = int(budget)
    hsize = header_size(roi is not None)
    if budget < hsize:
        raise ValueError(f"budget of {budget} bytes is below the {hsize}-byte DEBT header")
    limit = budget - hsize
    samples = img.size
    # Lossless (integer 5/3) only pays where the budget could hold it.
    if 8 * limit >= samples // 2:
        header, payload, complete = _encode_payload(img, colour, True, roi, shift, limit)
        if complete:
            return pack_header(header) + payload
    header, payload, complete = _encode_payload(img, colour, False, roi, shift, limit)
    if complete:
        # The 9/7 stream ran out of planes: a lossless one is smaller still.
        h2, p2, c2 = _encode_payload(img, colour, True, roi, shift, limit)
        if c2:
            return pack_header(h2) + p2
    return pack_header(header) + payload


# ---------------------------------------------------------------- decode

def decode(data) -> np.ndarray:
    """Decode a DEBT stream, or any prefix of one that holds its header."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValueError(f"data must be bytes, not {type(data).__name__}")
    data = bytes(data)
    h = unpack_header(data)
    ncomp = 3 if h.colour else 1
    plan = _plan(h.height, h.width, ncomp, h.reversible, h.roi, h.shift)
    lay = plan.lay
    n = max(lay.ncoef, 1)
    payload = np.frombuffer(data, dtype=np.uint8, offset=h.size).copy()
    st = coder.decoder_state(payload)
    buf = payload if payload.size else np.zeros(1, dtype=np.uint8)
    dummy = np.zeros(1, dtype=np.int64)
    rec = np.zeros(n, dtype=np.int64)
    pk = np.full(n, -1, dtype=np.int8)
    sgn = np.zeros(n, dtype=np.uint8)
    coder.run(1, dummy, np.zeros(1, dtype=np.uint8), plan.cfloor8, plan.ccls, dummy, plan.node_floor, lay.binfo,
              lay.noff, lay.nw, lay.seg, KMAX, h.top, buf, st, rec, pk, sgn,
              plan.cdef8, plan.node_def)
    if not h.reversible:
        hw = h.height * h.width
        flat = np.zeros(ncomp * hw, dtype=np.float64)
        kernels.reconstruct97(rec, pk, sgn, plan.pos, plan.inv_scale, flat)
        comps = []
        for c in range(ncomp):
            a = flat[c * hw:(c + 1) * hw].reshape(h.height, h.width)
            kernels.inverse97(a, plan.levels, plan.roi)
            comps.append(a)
        return _image(comps, h.colour, False)
    cfloor = plan.cfloor
    pk = pk.astype(np.int64)
    known = pk >= 0
    span = np.where(known & (pk > cfloor), (np.int64(1) << np.maximum(pk - cfloor, 0)) - 1, 0) >> 1
    mag = np.where(known, (rec >> cfloor) + span, 0)
    val = np.where(sgn == 1, -mag, mag)
    comp_bands = [[None] * len(band_shapes(h.height, h.width, plan.levels)) for _ in range(ncomp)]
    for b in range(len(lay.shapes)):
        off, bh, bw = lay.binfo[b, :3]
        comp_bands[lay.comp[b]][lay.index[b]] = val[off:off + bh * bw].reshape(bh, bw)
    comps = [inverse(bands, plan.levels, "53") for bands in comp_bands]
    return _image(comps, h.colour, True)


# ---------------------------------------------------------------- warm-up

def warm_up() -> None:
    """Compile every numba kernel DEBT uses (the first call takes seconds).

    Encodes and decodes tiny grey and colour images, lossy and lossless, with
    and without a region of interest, so that the first real image does not
    wait for the compiler.  Safe to call from any thread, any number of times."""
    rng = np.random.default_rng(0)
    for image in (rng.integers(0, 256, (16, 16), dtype=np.uint8),
                  rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)):
        for roi, shift in ((None, 0), ((0, 0, 8, 8), 4)):
            decode(encode(image, 60, roi=roi, shift=shift))     # 9/7
            decode(encode(image, 4000, roi=roi, shift=shift))   # lossless 5/3
