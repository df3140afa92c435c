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
# The stream header is in `header`, everything that follows from it alone
# (band layout, scales, region masks) in `plan`, the bit-plane coder in
# `coder` over the range coder of `rangecoder`, and the compiled transform in
# `kernels`.

from __future__ import annotations

import numpy as np

from . import coder, kernels, rangecoder, twolevel
from .header import (MAX_SHIFT, MAX_SIDE, RESIDUAL_TOP, TWO_LEVEL_TOP, Header,  # noqa: F401 (re-exported)
                     header_size, pack_header, unpack_header)
from .plan import ICT, ICT_INV, KMAX, plan_for
from .transform import band_shapes, forward, inverse

_plan = plan_for  # the name older callers use


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
        luma = image.astype(np.float64) @ ICT[0]
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
    ycc = x @ ICT.T
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
        out = ycc @ ICT_INV.T
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------- encode

def _encode_payload(img: np.ndarray, colour: bool, reversible: bool, roi, shift: int,
                    limit: int, levels: int | None = None):
    """Returns (header, payload bytes, complete?)."""
    height, width = img.shape[:2]
    ncomp = 3 if colour else 1
    plan = plan_for(height, width, ncomp, reversible, roi, shift, levels)
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
    st = rangecoder.encoder_state(limit + 1)
    rec = np.zeros_like(mag)
    pk = np.full(n, -1, dtype=np.int8)
    sgn = np.zeros(n, dtype=np.uint8)
    complete = coder.run(0, mag, neg, plan.cfloor8, plan.ccls, node_max, plan.node_floor,
                         lay.binfo, lay.noff, lay.nw, lay.seg, KMAX, top, buf, st, rec, pk, sgn,
                         plan.cdef8, plan.node_def)
    if complete:
        n = rangecoder.flush(st, buf)
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
    near = None
    if roi is None:
        # Exactly two colours: the two-level mode, when the whole picture fits
        # (`twolevel` says why and when).
        found = twolevel.two_colours(img, colour)
        if found is not None:
            payload = twolevel.encode_payload(found, colour, limit)
            if payload is not None:
                return pack_header(Header(width, height, colour, True, TWO_LEVEL_TOP)) + payload
        near = twolevel.mostly_two_colours(img, colour)
    stream = _wavelet_stream(img, colour, roi, shift, limit)
    if near is not None:
        # Mostly two colours: a mask and its residual, where that gives the
        # better picture at this budget.
        other = _mask_and_residual_stream(img, colour, near, limit)
        if other is not None and _error(decode(other), img) < _error(decode(stream), img):
            return other
    return stream


def _error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


def _wavelet_stream(img: np.ndarray, colour: bool, roi, shift: int, limit: int,
                    levels: int | None = None) -> bytes:
    samples = img.size
    # Lossless (integer 5/3) only pays where the budget could hold it.
    if 8 * limit >= samples // 2:
        header, payload, complete = _encode_payload(img, colour, True, roi, shift, limit, levels)
        if complete:
            return pack_header(header) + payload
    header, payload, complete = _encode_payload(img, colour, False, roi, shift, limit, levels)
    if complete:
        # The 9/7 stream ran out of planes: a lossless one is smaller still.
        h2, p2, c2 = _encode_payload(img, colour, True, roi, shift, limit, levels)
        if c2:
            return pack_header(h2) + p2
    return pack_header(header) + payload


# The residual of a two-level mask lies along the mask's edges, a pixel or two
# wide: a transform would spread it.  Coded in the pixels themselves (0
# levels) or after one level, whichever decodes better.  Measured on the horse
# scaled down, residual after the soft mask, at 1000/2000/4000/8000 B: 0
# levels 35.3/45.0/57.5/exact dB, 1 level 35.1/41.0/49.4/61.9, 5 (the
# default for 320x240) 34.3/39.1/46.6/57.7.
RESIDUAL_LEVELS = (0, 1)


def _mask_and_residual_stream(img: np.ndarray, colour: bool, near, limit: int) -> bytes | None:
    """The two-level mask of `near`, then the residual's wavelet stream (see
    `twolevel`), or None when the mask leaves no room for the residual."""
    height, width = img.shape[:2]
    cb = twolevel.colour_bytes(colour)
    mask = twolevel.encode_payload(near, colour, limit - 3)
    if mask is None or len(mask) - cb > 0xFFFF:
        return None
    room = limit - 3 - len(mask) - header_size(False)
    if room < 1:
        return None
    residual = twolevel.split_residual(img, near)
    best = None
    for levels in RESIDUAL_LEVELS:
        inner = _wavelet_stream(residual, colour, None, 0, room, levels)
        error = _error(_decode(inner, levels), residual)
        if best is None or error < best[0]:
            best = (error, levels, inner)
    _, levels, inner = best
    return (pack_header(Header(width, height, colour, True, RESIDUAL_TOP)) + mask[:cb]
            + (len(mask) - cb).to_bytes(2, "big") + bytes([levels]) + mask[cb:] + inner)


# ---------------------------------------------------------------- decode

def decode(data) -> np.ndarray:
    """Decode a DEBT stream, or any prefix of one that holds its header."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValueError(f"data must be bytes, not {type(data).__name__}")
    return _decode(bytes(data))


def _decode(data: bytes, levels: int | None = None) -> np.ndarray:
    h = unpack_header(data)
    if h.two_level:
        return twolevel.decode_payload(data[h.size:], h.height, h.width, h.colour)
    if h.mask_and_residual:
        return _decode_mask_and_residual(h, data[h.size:])
    ncomp = 3 if h.colour else 1
    plan = plan_for(h.height, h.width, ncomp, h.reversible, h.roi, h.shift, levels)
    lay = plan.lay
    n = max(lay.ncoef, 1)
    payload = np.frombuffer(data, dtype=np.uint8, offset=h.size).copy()
    st = rangecoder.decoder_state(payload)
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


def _decode_mask_and_residual(h: Header, body: bytes) -> np.ndarray:
    cb = twolevel.colour_bytes(h.colour)
    if len(body) < cb + 3:
        return twolevel.decode_payload(body[:cb], h.height, h.width, h.colour)  # flat grey
    n = int.from_bytes(body[cb:cb + 2], "big")
    levels = body[cb + 2]
    if levels not in RESIDUAL_LEVELS:
        raise ValueError(f"corrupted DEBT stream (its residual has {levels} levels)")
    mask_part = body[:cb] + body[cb + 3:cb + 3 + n]
    if len(body) < cb + 3 + n:
        return twolevel.decode_payload(mask_part, h.height, h.width, h.colour)  # the mask so far
    c0, c1, mask = twolevel.decode_mask(mask_part, h.height, h.width, h.colour)
    if mask is None:
        raise ValueError("corrupted DEBT stream (its two-level mask is incomplete)")
    rest = body[cb + 3 + n:]
    if len(rest) < header_size(False):
        return twolevel.mask_picture(c0, c1, mask).astype(np.uint8)
    inner = unpack_header(rest)
    if ((inner.width, inner.height, inner.colour) != (h.width, h.height, h.colour) or inner.roi is not None
            or inner.two_level or inner.mask_and_residual):
        raise ValueError("corrupted DEBT stream (its residual does not match the picture)")
    return twolevel.join_residual(c0, c1, mask, _decode(rest, levels))


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
        decode(encode(np.where(image >= 128, 255, 0).astype(np.uint8), 200))  # two-level
        soft = np.where(rng.random((16, 16)) < 0.4, 250, 5).astype(np.uint8)
        soft[3, :] = np.arange(16) * 16
        decode(encode(soft, 120))                                                # mask + residual


def warm_up_in_background(name: str = "debt-warm-up"):
    """Start `warm_up()` in a daemon thread and return the thread.

    The process may exit while it runs (a daemon thread does not hold it);
    `thread.join()` waits for the kernels when the caller needs them.  Errors
    are left to the first real encode or decode, which compiles anew."""
    import threading

    def _run():
        try:
            warm_up()
        except Exception:  # noqa: BLE001 - the first real call reports it
            pass

    thread = threading.Thread(target=_run, name=name, daemon=True)
    thread.start()
    return thread
