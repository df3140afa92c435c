# DEBT's public functions: `encode(image, budget, ...) -> bytes` and
# `decode(data) -> image`, plus the stream header.
#
# Plan for encode: validate everything at the edge (one ValueError each), turn
# the image into components (grey; colour: the picture's own rotation of RGB
# for the 9/7, `colour_rotation`, or the reversible RCT for 5/3), transform each (CDF 9/7, or the
# integer 5/3 when a lossless stream might fit the budget), scale every band by
# the norm of its synthesis basis so that coefficient error stands for pixel
# error, raise the region of interest SHIFT planes (general scaling; the 9/7
# transform is then shape-adaptive, region and rest lifted apart, so that the
# region's coefficients describe it alone), and hand the magnitudes to
# the bit-plane coder, which stops at the byte budget.  Without a region of
# interest, a 9/7 stream then gets a restoration filter fitted to its picture
# when that pays, the coefficients coded again in what the filter leaves of
# the budget (`_restored`, `restore`).  decode reverses it from whatever
# prefix it gets, reconstructing each coefficient at the middle of the
# interval its decoded bits leave open, and runs the filter over the picture.
#
# The stream header is in `header`, everything that follows from it alone
# (band layout, scales, region masks) in `plan`, the bit-plane coder in
# `coder` over the range coder of `rangecoder`, and the compiled transform in
# `kernels`.

from __future__ import annotations

import threading
from functools import lru_cache

import numpy as np

from . import coder, kernels, rangecoder, restore, twolevel
from .header import (
    MAX_SHIFT,
    MAX_SIDE,
    PACKET_TOP,
    RESIDUAL_TOP,
    TWO_LEVEL_TOP,
    Header,
    header_size,
    max_top,
    pack_header,
    unpack_header,
)
from .plan import ALONG_STEP, ICT, KMAX, along_splits, packet_tree, plan_for
from .transform import MAX_LEVELS, band_shapes, forward, inverse

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

# 9/7 colour pictures are coded in an orthonormal rotation of RGB of their
# own: the principal axes of their horizontal and vertical differences (a
# Karhunen-Loeve transform of the detail the wavelet codes) with a little of
# the pixels' own covariance (PIXEL_SHARE, each normalised by its trace: the
# low band matters at low rates), so that the second and third components
# carry as little as the picture allows.  Sent as three angles (Z-Y-X), a
# byte each, at the start of the payload.  Measured on the 16 colour
# photograph variants of `rovlink bench debt` against BT.601 YCbCr (the
# ICT, weighted to RGB error): the differences' axes alone +0.05/+0.06/+0.07/
# +0.10/+0.12/+0.16 dB mean at 250/500/1000/2000/4000/8000 B over all 52
# variants (+0.4 dB mean at 4000 B over the colour ones, up to +1.4 dB on
# rocket), the pixels' axes alone less above 1000 B; with PIXEL_SHARE 0.3 the
# colour ones +0.048/+0.038/+0.027/+0.009/+0.003/+0.005 dB more than with
# the differences' axes alone (1 and 3: more at 250-500 B, less above 2000).
PIXEL_SHARE = 0.3
ROTATION_BYTES = 3


GREY_AXIS_OUTER = np.full((3, 3), 1.0 / 3.0)   # (1, 1, 1)/sqrt(3), times itself


def colour_rotation(img: np.ndarray) -> bytes:
    """The rotation for an RGB picture, as its three angle bytes."""
    detail = np.zeros((3, 3))
    pixels = np.zeros((3, 3))
    total = np.zeros(3)
    kernels.colour_moments(np.ascontiguousarray(img), detail, pixels, total)
    n = max(img.shape[0] * img.shape[1], 1)
    pixels -= np.outer(total, total) / n          # about the mean
    cov = detail / max(np.trace(detail), 1e-9) + PIXEL_SHARE * pixels / max(np.trace(pixels), 1e-9)
    cov += 1e-6 * GREY_AXIS_OUTER   # a flat picture (no covariance at all): brightness first
    _values, vectors = np.linalg.eigh(cov)
    return rotation_bytes(vectors[:, ::-1].T)   # rows: the axes, most energy first


def rotation_bytes(axes: np.ndarray) -> bytes:
    """Three angle bytes for orthonormal `axes` (rows), signs made free."""
    r = np.array(axes, dtype=np.float64)
    for i in range(2):
        if r[i].sum() < 0:
            r[i] = -r[i]
    if np.linalg.det(r) < 0:
        r[2] = -r[2]
    # r = Rz(a) Ry(b) Rx(c)
    a = np.arctan2(r[1, 0], r[0, 0])
    b = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
    c = np.arctan2(r[2, 1], r[2, 2])
    return bytes([int(round(a / (2 * np.pi) * 256)) % 256,
                  int(round((b + np.pi / 2) / np.pi * 255)),
                  int(round(c / (2 * np.pi) * 256)) % 256])


def rotation_matrix(angles: bytes) -> np.ndarray:
    """The orthonormal 3x3 matrix (rows: component axes in RGB) of three angle bytes."""
    a = angles[0] * 2 * np.pi / 256
    b = angles[1] * np.pi / 255 - np.pi / 2
    c = angles[2] * 2 * np.pi / 256
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rz = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cc, -sc], [0.0, sc, cc]])
    return rz @ ry @ rx


SQRT3 = float(np.sqrt(3.0))


# Work arrays of an encode, kept per thread and reused by the next encode
# (`_work`): a camera picture's encode made ~20 arrays of 0.2-1.8 MB, and
# when the allocator handed their memory back to the system in between,
# every encode faulted its pages in anew (~2000 page faults, 2-3 ms of a
# 7 ms encode).  Only arrays that die within the call that takes them
# (nothing returned or kept refers to them); one a name and thread (so
# concurrent encodes never share one), grown when a bigger picture comes.
_WORK = threading.local()


def _work(name: str, shape, dtype) -> np.ndarray:
    """A per-thread work array `name` of `shape` and `dtype`, contents left
    over from its last use."""
    dtype = np.dtype(dtype)
    size = 1
    for n in (shape if isinstance(shape, tuple) else (shape,)):
        size *= int(n)    # (np.prod took 5 us of a ~1 ms decode)
    arrays = getattr(_WORK, "arrays", None)
    if arrays is None:
        arrays = _WORK.arrays = {}
    held = arrays.get(name)
    if held is None or held.dtype != dtype or held.size < size:
        held = arrays[name] = np.empty(max(size, 1), dtype=dtype)
    return held[:size].reshape(shape)


def _components(img: np.ndarray, colour: bool, reversible: bool, rotation: np.ndarray | None = None) -> list[np.ndarray]:
    if reversible:
        x = img.astype(np.int64)
        if not colour:
            return [x - 128]
        r, g, b = x[..., 0], x[..., 1], x[..., 2]
        return [((r + 2 * g + b) >> 2) - 128, b - g, r - g]
    x = img.astype(np.float64)
    if not colour:
        return [x - 128.0]
    # Divided by sqrt(3): the first axis of a grey-ish picture, (1, 1, 1)/sqrt(3),
    # then gives the luma's range (what the band scales are made for).
    y = (x - 128.0) @ (rotation.T / SQRT3)
    return [np.ascontiguousarray(y[..., i]) for i in range(3)]


def _components97_into(img: np.ndarray, colour: bool, rotation, out: np.ndarray) -> None:
    """`_components(img, colour, False, rotation)` written into `out`
    (components, height, width): grey exactly, colour in one compiled pass
    (`kernels.rotated_planes`, 0.09 ms against numpy's 0.34 on a camera
    picture; its sums of three products may differ from numpy's matmul in the
    last bit, which changed 0 of 1164 streams checked)."""
    if not colour:
        np.subtract(img, 128.0, out=out[0])        # img.astype(float64) - 128.0, exactly
        return
    kernels.rotated_planes(np.ascontiguousarray(img), np.ascontiguousarray(rotation.T / SQRT3), out)


def _image(comps: list[np.ndarray], colour: bool, reversible: bool, rotation: np.ndarray | None = None) -> np.ndarray:
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
    out = np.empty(comps[0].shape + (3,), dtype=np.uint8)
    kernels.to_rgb(*(np.ascontiguousarray(c) for c in comps), rotation * SQRT3, 128.0, out)
    return out


# ---------------------------------------------------------------- encode

def _packets(a: np.ndarray, plan, forward: bool) -> None:
    """Split (or merge back) the regions of plan.splits with one more 9/7
    level each, in place in the Mallat arrays `a` (components, height,
    width; see plan.packet_tree): coarse splits first when analysing, last
    when synthesising.  One compiled pass (`kernels.packets97`) over every
    region of every component."""
    if not plan.splits:
        return
    kernels.packets97(a, _split_table(plan.splits), forward)


@lru_cache(maxsize=16)
def _split_table(splits: tuple) -> np.ndarray:
    # plan.splits as int64 rows (y0, x0, height, width, kind), in their order.
    return np.array([(y0, x0, bh, bw, kind) for (y0, x0), (bh, bw), _depth, kind in splits],
                    dtype=np.int64).reshape(-1, 5)


def _analysed(img: np.ndarray, colour: bool, plan, shared: dict | None):
    """(rotation bytes, 9/7 coefficients of every component in one flat array,
    Mallat layout, before any wavelet packet split) of a picture.  With
    `shared` (one dict per picture) they are made once for every stream
    tried: the dyadic and the packet streams differ only after this."""
    key = (plan.levels, tuple(int(v) for v in plan.roi))
    if shared is not None and key in shared:
        return shared[key]
    height, width = img.shape[:2]
    hw = height * width
    rotation = b""
    if colour:
        rotation = colour_rotation(img)
    ncomp = 3 if colour else 1
    flat = np.empty(ncomp * hw, dtype=np.float64)
    _components97_into(img, colour, rotation_matrix(rotation) if rotation else None,
                       flat.reshape(ncomp, height, width))
    for c in range(ncomp):
        kernels.forward97(flat[c * hw:(c + 1) * hw].reshape(height, width), plan.levels, plan.roi)
    if shared is not None:
        shared[key] = (rotation, flat)
    return rotation, flat


def _encode_payload(img: np.ndarray, colour: bool, reversible: bool, roi, shift: int,
                    limit: int, levels: int | None = None, packets: tuple = (), errors: list | None = None,
                    shared: dict | None = None, views: list | None = None):
    """Returns (header, payload bytes, complete?).  With `errors` (9/7): appends
    the squared error the decoder's picture will have, summed, as the
    coefficients tell it (`_coefficient_error`); with `views` too, a function
    that makes the picture the decoder will show from the encoder's own state
    (`_picture97`, no decoding pass), or given a picture the squared error
    against it (`_squared_error97`, the picture not made).  `shared`: see
    `_analysed`."""
    height, width = img.shape[:2]
    ncomp = 3 if colour else 1
    plan = plan_for(height, width, ncomp, reversible, roi, shift, levels, packets)
    lay = plan.lay
    n = max(lay.ncoef, 1)
    rotation = b""
    room = limit
    flat = None
    if reversible:
        mag = np.zeros(n, dtype=np.int64)
        neg = np.zeros(n, dtype=np.uint8)
        comps = _components(img, colour, reversible)
        comp_bands = [forward(c, plan.levels, "53") for c in comps]
        for b in range(len(lay.shapes)):
            off, bh, bw = lay.binfo[b, :3]
            if not bh or not bw:
                continue
            band = comp_bands[lay.comp[b]][lay.index[b]]
            f = plan.cfloor[off:off + bh * bw].reshape(bh, bw)
            mag[off:off + bh * bw] = (np.abs(band) << f).ravel()
            neg[off:off + bh * bw] = (band < 0).ravel()
        # Every coefficient must stay below its own ceiling, `cdef` planes under
        # the top (the coder does not test it above): raise the top to make room.
        nz = mag > 0
        top = 0
        if nz.any():
            bits = np.frexp(mag[nz].astype(np.float64))[1] - 1  # exact below 2**53
            top = max(int((bits + plan.cdef[nz]).max()), 0)
    else:
        rotation, flat = _analysed(img, colour, plan, shared)
        if rotation:
            limit = max(limit - ROTATION_BYTES, 0)
        if plan.splits:
            split = _work("split", flat.shape, np.float64)
            split[...] = flat
            flat = split
            _packets(flat.reshape(ncomp, height, width), plan, forward=True)
        # gather97 sets every coefficient's magnitude and sign (all n of them
        # but for a picture without any: the one zero the coder still gets).
        mag = _work("mag", n, np.int64)
        neg = _work("neg", n, np.uint8)
        mag[plan.pos.shape[0]:] = 0
        neg[plan.pos.shape[0]:] = 0
        # The same top as the lossless path's, found in the gathering pass.
        top_by_def = np.zeros(MAX_SHIFT + 1, dtype=np.int64)
        kernels.gather97(flat, plan.pos, plan.scale, mag, neg, plan.cdef8, top_by_def)
        top = kernels.top_plane(top_by_def)
    header = Header(width, height, colour, reversible, top, roi, shift)
    node_max = _work("node_max", max(lay.nnodes, 1), np.int64)
    node_max[...] = 0
    kernels.max_pyramid(mag, lay.binfo, lay.noff, lay.nw, node_max)
    buf = np.zeros(limit + 64, dtype=np.uint8)
    st = rangecoder.encoder_state(limit + 1)
    rec = np.zeros(n, dtype=np.int64)    # kept by `views`: its own
    pk = np.full(n, -1, dtype=np.int8)
    sgn = np.zeros(n, dtype=np.uint8)
    complete = coder.run(0, mag, neg, plan.cfloor8, plan.ccls, node_max, plan.node_floor,
                         lay.binfo, lay.noff, lay.nw, lay.seg, KMAX, top, buf, st, rec, pk, sgn,
                         plan.cdef8, plan.node_def, prior=not reversible)
    if errors is not None and not reversible:
        errors.append(_coefficient_error(flat, plan, rec, pk))
    if views is not None and not reversible:
        angles = rotation_matrix(rotation) if rotation else None

        def view(against=None, components=False):
            comps = _components97(rec, pk, sgn, plan, height, width, colour)
            if components:
                return comps
            if against is None:
                return _image(comps, colour, False, angles)
            return _squared_error97(comps, angles, against)
        views.append(view)
    if complete:
        n = rangecoder.flush(st, buf)
        n = min(n, buf.shape[0])
        payload = rotation + bytes(buf[1:n])
        if len(payload) <= room:
            return header, payload, True
    return header, (rotation + bytes(buf[1:limit + 1]))[:room], False


def _coefficient_error(flat: np.ndarray, plan, rec: np.ndarray, pk: np.ndarray) -> float:
    """The decoder's squared error, summed, reckoned on the coefficients: each
    is reconstructed as `kernels.reconstruct97` does it from what the encoder
    sent, and its error weighted back to pixels.  The 9/7 basis is nearly
    orthogonal, so this stands for the picture's error well enough to choose
    between streams (it spares decoding each: on brick at 2000 B the choice
    among four streams took 18 ms with decodes).  One compiled pass
    (`kernels.coefficient_error97`; numpy's took 5 ms on a colour picture)."""
    return float(kernels.coefficient_error97(flat, plan.pos, plan.scale, plan.err_weight, rec, pk))


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
    shared: dict = {}    # the transform, made once for every stream tried
    textured = roi is None and (_textured(img, colour)
                                or max(_along_gains(img, colour, shared)) >= np.log(ALONG_TEXTURE))
    errors: list = []
    views: list = []
    stream = _wavelet_stream(img, colour, roi, shift, limit, errors=errors if textured else None, shared=shared,
                             views=views)
    if roi is not None or unpack_header(stream).reversible:
        return stream           # an ROI's own order, or exact: nothing better to try
    view, packets = views[-1], ()
    if textured and errors[-1] > PACKETS_ABOVE_MSE * height * width:
        # A texture: its packet stream for this rate (PACKETS_BY_RATE), the
        # the one split along the edges (`_along_depths`) or the dyadic one, told apart by
        # their coefficients' error (`_coefficient_error`), off by a few per
        # cent, so the best two, when within CLOSE of each other, by the
        # pictures the decoder will show, made from the encoder's own state
        # (`_picture97`: no decoding pass; their squared errors summed
        # without making them, `_squared_error97`).
        tried = [(errors[-1], views[-1], stream, ())]
        for packets in (_packets_for(8.0 * limit / img.size), along_splits(*_along_depths(img, colour, shared),
                                                                             MAX_LEVELS)):
            packet_errors: list = []
            packet_views: list = []
            other = _packet_stream(img, colour, packets, limit, packet_errors, shared, packet_views)
            tried.append((packet_errors[-1], packet_views[-1], other, packets))
        tried.sort(key=lambda t: t[0])
        (a, view, stream, packets), (b, view_b, other, packets_b) = tried[:2]
        if b <= a * CLOSE and view_b(img) < view(img):
            view, stream, packets = view_b, other, packets_b
    stream = _restored(img, colour, stream, view, packets, limit, shared)
    if near is not None:
        # A mask and its residual are no wavelet: told apart by decoding.
        other = _mask_and_residual_stream(img, colour, near, limit)
        if other is not None and _error(decode(other), img) < _error(decode(stream), img):
            stream = other
    return stream


CLOSE = 1.08


def _restored(img: np.ndarray, colour: bool, stream: bytes, view, packets: tuple, limit: int,
              shared: dict) -> bytes:
    """`stream` (9/7, no region of interest; `view` makes its picture from
    the encoder's state) with a restoration filter when one pays (see
    `restore`): fitted on its picture, the coefficients coded again in the
    budget less the filter's bytes, kept when that picture, filtered, has
    less squared error than `stream`'s."""
    height, width = img.shape[:2]
    end = split_bytes_end(stream)
    if len(stream) < end + (ROTATION_BYTES if colour else 0) + 2:
        return stream           # no room for coefficients, let alone a filter
    angles = rotation_matrix(stream[end:end + ROTATION_BYTES]) if colour else None
    comps = [np.array(c) for c in view(components=True)]      # out of the work array
    unfiltered = _squared_error97(comps, angles, img)          # what view(img) gives, the picture made once
    if colour:
        origs = np.empty((3, height, width))
        _components97_into(img, True, angles, origs)
    else:
        origs = [img - 128.0]
    # Squared error in the components' units (colour: a third of RGB's).
    error = unfiltered / (3.0 if colour else 1.0)
    price = restore.COST_SLOPE * error / max(limit, 1)
    filters, net = restore.fit(comps, list(origs), price)
    if net <= restore.WORTH_TRYING * error:
        return stream
    filter_bytes = restore.section(filters)
    views: list = []
    room = limit - len(filter_bytes)
    if packets:
        other = _packet_stream(img, colour, packets, room, None, shared, views)
    else:
        other = _wavelet_stream(img, colour, None, 0, room, None, None, shared, views)
    h = unpack_header(other)
    if h.reversible and not h.packets:
        return stream
    filtered = restore.apply(views[-1](components=True), filters)
    if _squared_error97(filtered, angles, img) >= unfiltered:
        return stream
    end = split_bytes_end(other)
    return (pack_header(Header(h.width, h.height, h.colour, h.reversible, h.top, filtered=True)) + other[h.size:end]
            + filter_bytes + other[end:])
# The packet stream is not tried when the dyadic one already leaves less than
# this squared error per pixel (summed over the colour planes' weights as
# `_coefficient_error` counts it: about the picture's mean squared error per
# sample), i.e. above ~50 dB.  There the dyadic stream won every measured
# case: the camera's sand close-ups (`rovlink bench debt`, 22 of their 24
# pictures and budgets, by 3-31 % of the error) and brick cropped at 8000 B
# (1.6, 45.8 dB, already dyadic); below it brick and the sand at 1000 B in
# colour (1.1-1.3) still have both streams coded.  Spares a second encode
# (half of a textured picture's time).
PACKETS_ABOVE_MSE = 0.65

# Wavelet packets: the finer detail bands split further.  On textures
# (bricks, fabric, sand ripples) their energy sits in narrow frequency ranges
# that more splits gather.  Measured on scikit-image's brick scaled down to
# 320x240 (and cropped) at 1000/2000/4000/8000 B: dyadic 26.56/30.51/35.38/
# 42.26 dB (31.14/35.69/40.49/45.73); level 1 split 26.53/31.12/36.48/42.58
# (31.05/36.11/41.18/45.56); levels 1 and 2 27.33/30.99/36.11/41.84 (32.34/
# 36.32/40.85/45.24); level 1 twice and 2 once 27.28/31.40/36.08/41.41
# (32.31/36.54/40.78/44.79); deeper ones lost from 2000 B (the coder's
# contexts learn less in small leaves).  On smooth photographs (camera,
# coffee, hubble) every split loses 0.1-1.2 dB: packets only for textures
# (`_textured`).  The stream names its split by its index here (2 bits).
#
# Besides these, splits along the edges (`along_splits`, field 0): each
# LH band split more in one direction only, down its columns (its edges
# stand upright), and each HL band along its rows, each time its low half;
# HH bands whole.  An edge or line that runs on (mortar between bricks,
# planks, ripples) leaves coefficients of nearly one value along it in its
# band: the splits gather them into the low halves, where a 2-D split
# spreads them across the line's own frequencies too.  How many splits a
# picture's LH and HL bands get: `_along_depths`.  Measured with the coder
# on scikit-image's brick (scaled down; cropped) at 1000/2000/4000 B: 2 and
# 2 splits 28.31/32.23/37.72 (33.37/37.61/42.03) dB against the best 2-D
# split's 27.33/31.45/36.57 (32.40/36.58/41.23); 3 and 3 28.13/32.16/37.26
# (33.12/37.50/41.85); 3 and 1 28.77/32.68/37.82 (33.60/37.95/42.20); 2
# and 1, 4 and 1, 3 and 0 within 0.3 dB of it.  On smooth photographs they
# lose 0.1-1.1 dB (camera, coffee, page, grass, gravel crops): one more
# stream the texture's trial codes, chosen only where its error is the
# smaller.
MAX_ALONG = 4
PACKET_CHOICES = ((1,), (1, 2), (1, 1, 2))
# Which split by bits per sample (per pixel for grey, a third of it for
# colour, whose luma takes most of the bits): the deep one at low rates,
# level 1 alone above.  Trying them all and keeping the best took 24 ms on brick at 2000 B
# (four encodes), 3.3x OpenJPEG; by rate, 0.05 dB at most is lost there.
# The dyadic stream is always coded beside it: it stays the better on brick
# cropped at 8000 B (by 0.17 dB) and on noisier textures at any rate.
PACKETS_BY_RATE = ((0.3, (1, 1, 2)), (99.0, (1,)))


def _packets_for(bpp: float) -> tuple:
    return next(packets for below, packets in PACKETS_BY_RATE if bpp < below)


# A finest detail band whose split gathers its energy this much (arithmetic
# over geometric mean of the four sub-bands' variances, the split's coding
# gain) marks a texture worth the packet streams' trial (`rovlink bench
# debt` names it as a cause where DEBT is behind).  Luma of the 52
# photograph variants of `rovlink bench debt`: brick 3.75 (scaled down) and
# 2.43 (crop), where packets win; every other at most 1.94 (page), where
# they lose or gain < 0.1 dB.  Costs ~1 ms; the trial, three encodes and
# decodes more.
TEXTURE_GAIN = 2.2


def _textured(img: np.ndarray, colour: bool) -> bool:
    height, width = img.shape[:2]
    if height < 16 or width < 16:
        return False
    # The offset changes no variance.  (A colour picture's product is float64 already: no copy.)
    luma = np.asarray(img @ ICT[0], dtype=np.float64) if colour else img.astype(np.float64)
    none = np.zeros(4, dtype=np.int64)
    kernels.forward97(luma, 1, none)
    hl, wl = -(-height // 2), -(-width // 2)
    for y0, x0, bh, bw in ((0, wl, hl, width - wl), (hl, 0, height - hl, wl), (hl, wl, height - hl, width - wl)):
        band = np.ascontiguousarray(luma[y0:y0 + bh, x0:x0 + bw])
        kernels.forward97(band, 1, none)
        h2, w2 = -(-bh // 2), -(-bw // 2)
        v = np.array([band[:h2, :w2].var(), band[:h2, w2:].var(), band[h2:, :w2].var(), band[h2:, w2:].var()])
        if v.min() <= 0:
            continue
        if v.mean() / np.exp(np.log(v).mean()) >= TEXTURE_GAIN:
            return True
    return False


# How many splits along the edges a texture's LH and HL bands get: the
# orientation whose finest two levels gather more from one such split
# (arithmetic over geometric mean of its two halves' mean squares, the
# split's coding gain, their logarithms averaged over the two levels) by
# ALONG_RATIO or more gets ALONG_MAJOR and the other ALONG_MINOR, else both
# ALONG_EVEN.  Brick's edges run mostly one way, the mortar between courses
# short: LH 3.2/3.8 (scaled down, levels 1/2) and 2.4/3.9 (crop) against HL
# 1.7/2.2 and 1.3/1.9; its best depths by the coder 3 and 1 (see
# PACKET_CHOICES).
ALONG_RATIO = 1.3
ALONG_MAJOR, ALONG_MINOR, ALONG_EVEN = 3, 1, 2
# A picture whose LH or HL bands gather this much from a split along the
# edges (the gain above, of the orientation that gathers more) is a texture
# worth the packet streams' trial too, even where no 2-D split gathers
# enough (TEXTURE_GAIN).  The 52 photograph variants of `rovlink bench
# debt`: brick 2.85 (scaled down) and 2.35 (crop), clock 1.82 and 1.71 (its
# HL bands: blurred along the rows), every other at most 1.41 (rocket's
# crop).  Set just under clock scaled down, where the trial paid too (the
# 2-D split at 1000 B, +0.15 dB; nothing changed elsewhere).  A trial that
# does not pay costs time only: the streams are told apart by their error.
# The gain falls fast as the edges slant (synthetic upright seams: 2.4 at a
# slope of 0.04, 1.6 at 0.1, 1.4 at 0.2): the splits follow the columns and
# rows, not the edges' own direction.
ALONG_TEXTURE = 1.8


def _along_depths(img: np.ndarray, colour: bool, shared: dict | None) -> tuple[int, int]:
    """(LH, HL) splits along the edges for the picture (ALONG_RATIO)."""
    gains = _along_gains(img, colour, shared)
    if gains[0] - gains[1] >= np.log(ALONG_RATIO):
        return ALONG_MAJOR, ALONG_MINOR
    if gains[1] - gains[0] >= np.log(ALONG_RATIO):
        return ALONG_MINOR, ALONG_MAJOR
    return ALONG_EVEN, ALONG_EVEN


def _along_gains(img: np.ndarray, colour: bool, shared: dict | None) -> tuple[float, float]:
    """The logarithms of the LH and the HL bands' coding gains from one split
    along the edges, averaged over the two finest levels (ALONG_RATIO); the
    first component's analysis is `_analysed`'s, shared with its streams."""
    height, width = img.shape[:2]
    if height < 16 or width < 16:
        return 0.0, 0.0
    ncomp = 3 if colour else 1
    packets = along_splits(1, 1, 2)
    plan = plan_for(height, width, ncomp, False, None, 0, None, packets)
    _rotation, flat = _analysed(img, colour, plan, shared)
    first = _work("along", (1, height, width), np.float64)
    first[0] = flat[:height * width].reshape(height, width)
    _packets(first, plan, forward=True)
    squares: dict = {}
    bands, _splits = packet_tree(height, width, plan.levels, plan.packets)
    for _i, path, (bh, bw), (y0, x0), _level, orient in bands:
        if path and bh and bw:
            squares.setdefault(orient, []).append(float(np.mean(first[0, y0:y0 + bh, x0:x0 + bw] ** 2)))
    gains = {}
    for orient in (1, 2):
        logs = []
        for low, high in zip(squares.get(orient, [])[0::2], squares.get(orient, [])[1::2]):
            if low > 0 and high > 0:
                logs.append(np.log((low + high) / 2 / np.sqrt(low * high)))
        gains[orient] = float(np.mean(logs)) if logs else 0.0
    return gains[1], gains[2]


def _packet_stream(img: np.ndarray, colour: bool, packets: tuple, limit: int,
                   errors: list | None = None, shared: dict | None = None, views: list | None = None) -> bytes:
    """A 9/7 stream with wavelet packets at `packets` (one of PACKET_CHOICES,
    or `along_splits`): header TOP=61, then a byte (bits 7-6: 1 + the index
    of the split in PACKET_CHOICES, or 0 for splits along the edges; bits
    5-0: the stream's top plane, below max_top), for splits along the edges
    a byte more (bits 7-4: the LH bands' splits, 3-0: the HL bands', each
    at most MAX_ALONG), then the coder's bytes."""
    height, width = img.shape[:2]
    extra = packet_extra(packets)
    header, payload, _complete = _encode_payload(img, colour, False, None, 0, limit - 1 - len(extra), None, packets,
                                                 errors, shared, views)
    return (pack_header(Header(width, height, colour, True, PACKET_TOP))
            + bytes([packet_field(packets) << 6 | header.top]) + extra + payload)


def packet_field(packets: tuple) -> int:
    """The 2-bit field naming `packets` in a packet stream (`_packet_stream`)."""
    return PACKET_CHOICES.index(packets) + 1 if packets in PACKET_CHOICES else 0


def packet_extra(packets: tuple) -> bytes:
    """The byte after the field's for splits along the edges (none for the others)."""
    if packets in PACKET_CHOICES:
        return b""
    lh, hl = along_depths_of(packets)
    return bytes([lh << 4 | hl])


def along_depths_of(packets: tuple) -> tuple[int, int]:
    """(LH, HL) splits a level of `along_splits(lh, hl, ...)` holds."""
    return packets.count(-(ALONG_STEP + 1)), packets.count(-(2 * ALONG_STEP + 1))


def split_bytes_end(data: bytes) -> int:
    """Where a stream's header and the bytes naming its wavelet packet split end: the
    packet byte, and for a split along the edges (field 0) the byte after it."""
    h = unpack_header(data)
    if not h.packets or len(data) <= h.size:
        return h.size
    return h.size + (2 if data[h.size] >> 6 == 0 else 1)


def filter_bytes_end(data: bytes) -> int:
    """Where a stream's header, the bytes naming its wavelet packet split and
    its restoration filter (`restore`) end."""
    end = split_bytes_end(data)
    h = unpack_header(data)
    if h.filtered:
        _filters, end = restore.parse(data, end, 3 if h.colour else 1)
    return end


def packets_of(field: int, extra: int | None) -> tuple:
    """The split a packet stream names by its field and, for field 0, the
    byte after it (`_packet_stream`)."""
    if field:
        return PACKET_CHOICES[field - 1]
    lh, hl = extra >> 4, extra & 15
    if lh > MAX_ALONG or hl > MAX_ALONG:
        raise ValueError("corrupted DEBT stream (unknown wavelet packet split)")
    return along_splits(lh, hl, MAX_LEVELS)


def _error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


def _wavelet_stream(img: np.ndarray, colour: bool, roi, shift: int, limit: int,
                    levels: int | None = None, errors: list | None = None, shared: dict | None = None,
                    views: list | None = None) -> bytes:
    samples = img.size
    # Lossless (integer 5/3) only pays where the budget could hold it.
    if 8 * limit >= samples // 2:
        header, payload, complete = _encode_payload(img, colour, True, roi, shift, limit, levels)
        if complete:
            return pack_header(header) + payload
    header, payload, complete = _encode_payload(img, colour, False, roi, shift, limit, levels, (), errors, shared,
                                                views)
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


def _decode(data: bytes, levels: int | None = None, packets: tuple = ()) -> np.ndarray:
    h = unpack_header(data)
    if h.two_level:
        return twolevel.decode_payload(data[h.size:], h.height, h.width, h.colour)
    if h.mask_and_residual:
        return _decode_mask_and_residual(h, data[h.size:])
    start = h.size
    filtered = h.filtered
    if h.packets:
        if len(data) <= h.size:     # not even the packet byte: a flat picture
            shape = (h.height, h.width, 3) if h.colour else (h.height, h.width)
            return np.full(shape, 128, dtype=np.uint8)
        byte = data[h.size]
        start += 1
        extra = None
        if byte >> 6 == 0:
            if len(data) <= start:  # not even the splits' byte: a flat picture
                shape = (h.height, h.width, 3) if h.colour else (h.height, h.width)
                return np.full(shape, 128, dtype=np.uint8)
            extra = data[start]
            start += 1
        packets = packets_of(byte >> 6, extra)
        h = Header(h.width, h.height, h.colour, False, byte & 63)
        if h.top > max_top(h):
            raise ValueError("corrupted DEBT stream (bit-plane count out of range)")
    filters = None
    if filtered:
        filters, start = restore.parse(data, start, 3 if h.colour else 1)
    rotation = None
    if h.colour and not h.reversible:
        if len(data) < start + ROTATION_BYTES:      # not even the colour axes: a flat picture
            return np.full((h.height, h.width, 3), 128, dtype=np.uint8)
        rotation = rotation_matrix(data[start:start + ROTATION_BYTES])
        start += ROTATION_BYTES
    ncomp = 3 if h.colour else 1
    plan = plan_for(h.height, h.width, ncomp, h.reversible, h.roi, h.shift, levels, packets)
    lay = plan.lay
    n = max(lay.ncoef, 1)
    payload = np.frombuffer(data, dtype=np.uint8, offset=start).copy()
    st = rangecoder.decoder_state(payload)
    buf = payload if payload.size else np.zeros(1, dtype=np.uint8)
    dummy = np.zeros(1, dtype=np.int64)
    # A 9/7 decode reads rec only where pk >= 0, which the coder sets with it
    # (a coefficient's first bit), so it need not start at 0 (a 320x240
    # grey picture: 6 us; the integer path's numpy reads every entry).
    rec = np.zeros(n, dtype=np.int64) if h.reversible else np.empty(n, dtype=np.int64)
    pk = np.full(n, -1, dtype=np.int8)
    sgn = np.zeros(n, dtype=np.uint8)
    coder.run(1, dummy, np.zeros(1, dtype=np.uint8), plan.cfloor8, plan.ccls, dummy, plan.node_floor, lay.binfo,
              lay.noff, lay.nw, lay.seg, KMAX, h.top, buf, st, rec, pk, sgn,
              plan.cdef8, plan.node_def, prior=not h.reversible)
    if not h.reversible:
        return _picture97(rec, pk, sgn, plan, h.height, h.width, h.colour, rotation, filters)
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


def _picture97(rec, pk, sgn, plan, height: int, width: int, colour: bool, rotation,
               filters: list | None = None) -> np.ndarray:
    """The 9/7 picture of the coder's state: each coefficient at its
    reconstruction point (`kernels.reconstruct97`), the transform inverted,
    the restoration filter run (`restore`) when the stream has one."""
    comps = _components97(rec, pk, sgn, plan, height, width, colour)
    if filters is not None:
        comps = restore.apply(comps, filters)
    return _image(comps, colour, False, rotation)


def _components97(rec, pk, sgn, plan, height: int, width: int, colour: bool) -> list[np.ndarray]:
    # The picture's components (before `_image`) from the coder's state, in
    # the thread's work array "picture" (`_work`): used up by the caller.
    ncomp = 3 if colour else 1
    hw = height * width
    flat = _work("picture", ncomp * hw, np.float64)
    flat[...] = 0.0
    kernels.reconstruct97(rec, pk, sgn, plan.pos, plan.inv_scale, flat)
    _packets(flat.reshape(ncomp, height, width), plan, forward=False)
    comps = []
    for c in range(ncomp):
        a = flat[c * hw:(c + 1) * hw].reshape(height, width)
        kernels.inverse97(a, plan.levels, plan.roi)
        comps.append(a)
    return comps


def _squared_error97(comps: list[np.ndarray], rotation, img: np.ndarray) -> int:
    """The squared error, summed (an exact integer), of the picture `_image`
    makes of the 9/7 components `comps` against `img`, without making it
    (`kernels.rgb_squared_error`, `kernels.grey_squared_error`): `_error`
    times the samples, so the same order between pictures of one size."""
    img = np.ascontiguousarray(img)
    if img.ndim == 3:
        return int(kernels.rgb_squared_error(*comps, rotation * SQRT3, 128.0, img))
    return int(kernels.grey_squared_error(comps[0], 128.0, img))


def _decode_mask_and_residual(h: Header, body: bytes) -> np.ndarray:
    cb = twolevel.colour_bytes(h.colour)
    if len(body) < cb + 3:
        return twolevel.decode_payload(body[:cb], h.height, h.width, h.colour)  # no mask yet
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
    # A texture (its packet streams, their errors, the picture's squared
    # error) and pictures as the camera hands them: read-only arrays are a
    # type of their own to numba, compiled apart (found compiling during the
    # test suite, a process at a time, well after this warm-up).
    texture = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    for image in (texture, texture[..., 0].copy()):
        locked = image.copy()
        locked.setflags(write=False)
        for picture in (image, locked):
            decode(encode(picture, 700))
    restore.warm_up()
    from . import jit

    jit.mark_warmed()


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
