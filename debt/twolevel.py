# DEBT's two-level mode: pictures of exactly two colours (a silhouette, a
# bilevel scan, a binary sonar mask), coded exactly and progressively.
#
# Why: a wavelet spends most of its bits on the ringing of hard edges.  On
# scikit-image's horse silhouette (320x240 crop) the bit-plane coder reached
# 26.6 dB at 1000 B and was exact only at 8000 B, where AV1's palette mode
# (AVIF) is exact in 878 B.  A picture with two colours is a binary image, and
# binary images are best coded as such.
#
# Plan
# - The picture is a quadtree of blocks: level 0 the pixels, level lev blocks of
#   2^lev x 2^lev (clipped to the image), one root at level L.  A block is
#   uniform 0, uniform 1 or mixed.
# - Levels are coded from the root down, each in raster order.  A block whose
#   parent is uniform is known without a decision; under a mixed parent it
#   sends "mixed?" and, when uniform, its colour (a pixel sends its colour).
#   The last block of a mixed parent whose siblings are all uniform of one
#   colour cannot be uniform of that colour too: that decision is skipped.
# - Contexts: the block's left and upper neighbours at its level (decided),
#   its right and lower ones as far as their parents tell (uniform or not
#   known), and the level; a pixel looks at its 4 causal neighbours and the
#   right and lower ones its parents give away.
# - Binary decisions go through DEBT's range coder, so a truncated stream
#   decodes every decision it holds and stops at the first it cannot be sure
#   of.  A block not yet resolved is shown in the mean of the two colours:
#   each decision can only turn such a block exact, so quality never drops
#   as bytes arrive.
# - The encoder uses this mode only when the picture has exactly two colours,
#   has no region of interest (an ROI asks for its area first, which the
#   quadtree does not order), and the whole picture fits the budget: then the
#   stream is exact and far shorter than the wavelet's.  Otherwise the wavelet
#   stream it would have sent is sent.
#
# Stream: the 5-byte DEBT header with REVERSIBLE=1, no ROI, TOP=63 (a plane
# count the wavelet never produces), then the two colours (1 byte each for
# grey, 3 for colour; colour 0 is the top-left pixel's), then the range coder.

from __future__ import annotations

import numpy as np

from . import rangecoder
from .jit import _jit
from .rangecoder import _code, _save, new_model

NLEV_CTX = 8             # levels 1..7+ have contexts of their own
CTX_MIX = 0                                   # + min(lev, 7) * 256 + neighbours
CTX_VAL = CTX_MIX + NLEV_CTX * 256            # + min(lev, 3) * 256 + neighbours
CTX_PIX = CTX_VAL + 4 * 256                   # + 3**6 neighbour codes
NCTX = CTX_PIX + 729


def two_colours(img: np.ndarray, colour: bool):
    """(colour 0, colour 1, bits) when `img` holds exactly two colours, else None.

    Colour 0 is the top-left pixel's; bits is an HxW uint8 array of 0/1."""
    if colour and three_colours(img.reshape(-1, 3)):
        return None     # a photograph: a third colour within its first pixels
    if colour:
        flat = (img[..., 0].astype(np.uint32) << 16) | (img[..., 1].astype(np.uint32) << 8) | img[..., 2]
    else:
        flat = img
    first = flat.flat[0]
    other = flat != first
    if not other.any():
        return None
    idx = int(np.argmax(other))
    second = flat.flat[idx]
    if np.any(other & (flat != second)):
        return None
    if colour:
        c0 = tuple(int(v) for v in img.reshape(-1, 3)[0])
        c1 = tuple(int(v) for v in img.reshape(-1, 3)[idx])
    else:
        c0, c1 = (int(first),), (int(second),)
    return c0, c1, other.astype(np.uint8)


@_jit
def three_colours(pixels) -> bool:
    """True when `pixels` (rows of RGB) hold three colours or more, found in
    one pass that stops at the third (a photograph's first few pixels):
    what `two_colours` tests, without making the picture's colour array."""
    n = pixels.shape[0]
    second = -1
    for i in range(1, n):
        if pixels[i, 0] == pixels[0, 0] and pixels[i, 1] == pixels[0, 1] and pixels[i, 2] == pixels[0, 2]:
            continue
        if second < 0:
            second = i
        elif not (pixels[i, 0] == pixels[second, 0] and pixels[i, 1] == pixels[second, 1]
                  and pixels[i, 2] == pixels[second, 2]):
            return True
    return False


def _levels(height: int, width: int):
    """Level sizes (h_l, w_l), offsets into one flat array, and the top level L."""
    hs, ws = [height], [width]
    while hs[-1] > 1 or ws[-1] > 1:
        hs.append((hs[-1] + 1) // 2)
        ws.append((ws[-1] + 1) // 2)
    lh = np.array(hs, dtype=np.int64)
    lw = np.array(ws, dtype=np.int64)
    off = np.zeros(len(hs) + 1, dtype=np.int64)
    off[1:] = np.cumsum(lh * lw)
    return lh, lw, off, len(hs) - 1


def _pyramid(bits: np.ndarray, lh, lw, off) -> np.ndarray:
    """The true state of every block (0, 1 uniform; 2 mixed), level by level."""
    out = np.empty(int(off[-1]), dtype=np.int8)
    cur = bits.astype(np.int8)
    out[:cur.size] = cur.ravel()
    for lev in range(1, lh.shape[0]):
        h, w = cur.shape
        pad = np.full((2 * int(lh[lev]), 2 * int(lw[lev])), -1, dtype=np.int8)
        pad[:h, :w] = cur
        kids = np.stack([pad[0::2, 0::2], pad[0::2, 1::2], pad[1::2, 0::2], pad[1::2, 1::2]])
        all0 = np.all((kids == 0) | (kids == -1), axis=0)
        all1 = np.all((kids == 1) | (kids == -1), axis=0)
        cur = np.where(all0, 0, np.where(all1, 1, 2)).astype(np.int8)
        out[off[lev]:off[lev + 1]] = cur.ravel()
    return out


@_jit
def _known(dec, off, lh, lw, top, lev, y, x):
    """What the coder knows of block (y, x) at level lev: 0/1 uniform, 2 mixed,
    3 not known (or outside the picture)."""
    if y < 0 or x < 0 or y >= lh[lev] or x >= lw[lev]:
        return 3
    s = dec[off[lev] + y * lw[lev] + x]
    if s >= 0:
        return s
    if lev < top:
        ps = dec[off[lev + 1] + (y >> 1) * lw[lev + 1] + (x >> 1)]
        if ps == 0 or ps == 1:
            return ps
    return 3


@_jit
def _siblings(dec, off, lh, lw, lev, y, x):
    """For the last block of its parent: the one colour all its siblings are
    uniform in (0 or 1), or -1 when they are not, or when it is not the last."""
    py, px = y >> 1, x >> 1
    last_y = min(2 * py + 1, lh[lev] - 1)
    last_x = min(2 * px + 1, lw[lev] - 1)
    if y != last_y or x != last_x:
        return -1
    v = -1
    for cy in range(2 * py, last_y + 1):
        for cx in range(2 * px, last_x + 1):
            if cy == y and cx == x:
                continue
            s = dec[off[lev] + cy * lw[lev] + cx]
            if s != 0 and s != 1:
                return -1
            if v == -1:
                v = s
            elif s != v:
                return -1
    return v


@_jit
def _traverse(mode, truth, dec, off, lh, lw, top, buf, st, probs):
    a0, a1, a2, a3, a4, lim = st[0], st[1], st[2], st[3], st[4], st[5]
    for lev in range(top, -1, -1):
        for y in range(lh[lev]):
            for x in range(lw[lev]):
                i = off[lev] + y * lw[lev] + x
                if lev < top:
                    ps = dec[off[lev + 1] + (y >> 1) * lw[lev + 1] + (x >> 1)]
                    if ps != 2:
                        dec[i] = ps
                        continue
                left = _known(dec, off, lh, lw, top, lev, y, x - 1)
                up = _known(dec, off, lh, lw, top, lev, y - 1, x)
                right = _known(dec, off, lh, lw, top, lev, y, x + 1)
                down = _known(dec, off, lh, lw, top, lev, y + 1, x)
                forced = _siblings(dec, off, lh, lw, lev, y, x) if lev < top else -1
                if lev > 0:
                    nbr = ((left * 4 + up) * 4 + right) * 4 + down
                    bit = 0
                    if mode == 0:
                        bit = 1 if truth[i] == 2 else 0
                    a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                  CTX_MIX + min(lev, NLEV_CTX - 1) * 256 + nbr, bit)
                    if r < 0:
                        _save(st, a0, a1, a2, a3, a4)
                        return 0
                    if r == 1:
                        dec[i] = 2
                        continue
                    if forced >= 0:
                        dec[i] = 1 - forced
                        continue
                    if mode == 0:
                        bit = truth[i]
                    a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                  CTX_VAL + min(lev, 3) * 256 + nbr, bit)
                    if r < 0:
                        _save(st, a0, a1, a2, a3, a4)
                        return 0
                    dec[i] = r
                else:
                    if forced >= 0:
                        dec[i] = 1 - forced
                        continue
                    ul = _known(dec, off, lh, lw, top, 0, y - 1, x - 1)
                    ur = _known(dec, off, lh, lw, top, 0, y - 1, x + 1)
                    # At level 0 a known block is 0 or 1; "not known" is 2 here.
                    ctx = 0
                    for c in (left, up, ul, ur, right, down):
                        ctx = ctx * 3 + (c if c < 2 else 2)
                    bit = 0
                    if mode == 0:
                        bit = truth[i]
                    a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                  CTX_PIX + ctx, bit)
                    if r < 0:
                        _save(st, a0, a1, a2, a3, a4)
                        return 0
                    dec[i] = r
    _save(st, a0, a1, a2, a3, a4)
    return 1


def _work(height: int, width: int):
    lh, lw, off, top = _levels(height, width)
    dec = np.full(int(off[-1]), -1, dtype=np.int8)
    probs = new_model(NCTX)
    return lh, lw, off, top, dec, probs


def colour_bytes(colour: bool) -> int:
    return 6 if colour else 2


def encode_payload(found, colour: bool, limit: int) -> bytes | None:
    """The stream after the header for `found` (from two_colours), or None when
    it does not fit in `limit` bytes."""
    c0, c1, bits = found
    head = bytes(c0) + bytes(c1)
    room = limit - len(head)
    if room < 0:
        return None
    height, width = bits.shape
    lh, lw, off, top, dec, probs = _work(height, width)
    truth = _pyramid(bits, lh, lw, off)
    buf = np.zeros(room + 64, dtype=np.uint8)
    st = rangecoder.encoder_state(room + 1)
    if not _traverse(0, truth, dec, off, lh, lw, top, buf, st, probs):
        return None
    n = min(rangecoder.flush(st, buf), buf.shape[0])
    payload = bytes(buf[1:n])
    if len(payload) > room:
        return None
    return head + payload


def _decode_blocks(payload: bytes, height: int, width: int, colour: bool):
    """(colour 0, colour 1, every block's state as far as the bytes tell, all
    of them?, level layout) of a two-level payload (colours, then coded bits),
    or None before its colours."""
    nc = 3 if colour else 1
    if len(payload) < 2 * nc:
        return None
    data = np.frombuffer(payload, dtype=np.uint8, offset=2 * nc).copy()
    lh, lw, off, top, dec, probs = _work(height, width)
    st = rangecoder.decoder_state(data)
    buf = data if data.size else np.zeros(1, dtype=np.uint8)
    complete = _traverse(1, np.zeros(1, dtype=np.int8), dec, off, lh, lw, top, buf, st, probs)
    return tuple(payload[:nc]), tuple(payload[nc:2 * nc]), dec, complete, (lh, lw, off, top)


def decode_payload(payload: bytes, height: int, width: int, colour: bool) -> np.ndarray:
    """The picture a (possibly truncated) two-level payload holds."""
    nc = 3 if colour else 1
    found = _decode_blocks(payload, height, width, colour)
    if found is None:
        shape = (height, width, 3) if colour else (height, width)
        return np.full(shape, 128, dtype=np.uint8)    # not even the colours yet
    c0, c1, dec, _complete, (lh, lw, off, top) = found
    c0 = np.array(c0, dtype=np.int64)
    c1 = np.array(c1, dtype=np.int64)
    # Unresolved blocks in the mean of the two colours; every level that is
    # known uniform paints its colour, coarse to fine.
    state = np.full((height, width), 2, dtype=np.int8)
    for lev in range(top, -1, -1):
        s = dec[off[lev]:off[lev + 1]].reshape(int(lh[lev]), int(lw[lev]))
        if lev:
            s = np.repeat(np.repeat(s, 1 << lev, axis=0), 1 << lev, axis=1)[:height, :width]
        known = (s == 0) | (s == 1)
        state[known] = s[known]
    out = np.empty((height, width, nc), dtype=np.uint8)
    mid = (c0 + c1 + 1) // 2
    out[...] = mid
    out[state == 0] = c0
    out[state == 1] = c1
    return out if colour else out[..., 0]


# ---------------------------------------------------------------- nearly two colours
#
# A picture that is mostly two colours with soft edges (a silhouette scaled
# down, a scan) is still mostly a binary image: its mask (each pixel's nearer
# colour) in this mode, then what the mask misses, `picture - mask + 128`, as
# an ordinary DEBT stream of few or no transform levels (codec.RESIDUAL_LEVELS).
# Measured on scikit-image's horse scaled down to 320x240 (212 grey levels;
# the mask 345 B, shown with soft edges 30.6 dB): 35.3/45.0/57.5 dB and exact
# at 1000/2000/4000/8000 B, against the wavelet's 26.1/31.2/38.7/51.2 and
# AVIF's 37.8 at 2000 B, 51.8 at 4000, exact in 7632 B.
#
# Stream: the header with TOP = 62, the two colours, the mask's length (2
# bytes, big-endian), the residual's transform levels (1 byte), the mask,
# then the residual's own DEBT stream.  The encoder decides by the picture
# each stream gives at the budget.

MOSTLY = 0.6          # the two commonest colours cover at least this share


def mostly_two_colours(img: np.ndarray, colour: bool):
    """(colour 0, colour 1, mask) when the two commonest colours cover MOSTLY of
    the picture (mask: 1 where a pixel is nearer colour 1), else None."""
    if colour:
        # A photograph fails on every 13th pixel already (a whole count costs
        # 6 ms on 320x240, a sixth of an encode): those pixels' colours made
        # first, and the whole picture's only when they pass.
        sample = img.reshape(-1, 3)[::13].astype(np.int32)     # 24 bits: int32 sorts faster
        sample = (sample[:, 0] << 16) | (sample[:, 1] << 8) | sample[:, 2]
        _, few = np.unique(sample, return_counts=True)
        if few.shape[0] > 2 and np.sort(few)[-2:].sum() < (MOSTLY - 0.1) * sample.shape[0]:
            return None
        flat = ((img[..., 0].astype(np.int64) << 16) | (img[..., 1].astype(np.int64) << 8)
                | img[..., 2]).ravel()
        values, counts = np.unique(flat, return_counts=True)
    else:
        counts = np.bincount(img.ravel(), minlength=256)
        values = np.arange(256)
    if values.shape[0] < 3:
        return None
    order = np.argsort(counts)[::-1]
    if counts[order[0]] + counts[order[1]] < MOSTLY * img.shape[0] * img.shape[1]:
        return None
    v0, v1 = int(values[order[0]]), int(values[order[1]])
    if colour:
        c0 = np.array([(v0 >> 16) & 255, (v0 >> 8) & 255, v0 & 255], dtype=np.int64)
        c1 = np.array([(v1 >> 16) & 255, (v1 >> 8) & 255, v1 & 255], dtype=np.int64)
        x = img.astype(np.int64)
        mask = ((x - c1) ** 2).sum(-1) < ((x - c0) ** 2).sum(-1)
        return tuple(int(v) for v in c0), tuple(int(v) for v in c1), mask.astype(np.uint8)
    x = img.astype(np.int64)
    mask = np.abs(x - v1) < np.abs(x - v0)
    return (v0,), (v1,), mask.astype(np.uint8)


def mask_picture(c0, c1, mask: np.ndarray) -> np.ndarray:
    """The mask in its two colours, edges softened by a fixed 3x3 kernel
    (centre 40, sides 5, corners 1, over 64: a Gaussian of 0.5 px in integers,
    the same on both sides).  Soft edges are what such pictures have (a
    scaled-down or slightly blurred silhouette): on the horse scaled down the
    prediction reaches 30.6 dB against 27.6 with hard edges, and the picture
    with its residual +2.5/+2.7/+2.9/+2.3 dB at 1000/2000/4000/8000 B.  A
    least-squares 5x5 kernel fitted per picture did no better."""
    nc = len(c0)
    hard = np.where(mask[..., None] == 1, np.array(c1, np.int64), np.array(c0, np.int64))
    p = np.pad(hard, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = mask.shape
    side = p[0:h, 1:w + 1] + p[2:h + 2, 1:w + 1] + p[1:h + 1, 0:w] + p[1:h + 1, 2:w + 2]
    corner = p[0:h, 0:w] + p[0:h, 2:w + 2] + p[2:h + 2, 0:w] + p[2:h + 2, 2:w + 2]
    out = (40 * hard + 5 * side + corner + 32) >> 6
    return out if nc == 3 else out[..., 0]


def split_residual(img: np.ndarray, found) -> np.ndarray:
    """What the mask misses, as a uint8 picture around 128."""
    c0, c1, mask = found
    return np.clip(img.astype(np.int64) - mask_picture(c0, c1, mask) + 128, 0, 255).astype(np.uint8)


def join_residual(c0, c1, mask: np.ndarray, residual: np.ndarray) -> np.ndarray:
    return np.clip(mask_picture(c0, c1, mask) + residual.astype(np.int64) - 128, 0, 255).astype(np.uint8)


def decode_mask(payload: bytes, height: int, width: int, colour: bool):
    """(c0, c1, mask or None) of an exact mask payload (colours then its coded bits)."""
    c0, c1, dec, complete, _layout = _decode_blocks(payload, height, width, colour)
    if not complete:
        return c0, c1, None
    return c0, c1, dec[:height * width].reshape(height, width).astype(np.uint8)
