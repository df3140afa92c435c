# The embedded block-tree bit-plane coder of DEBT and its arithmetic coder.
#
# Goals: every coefficient's bits are sent from the most significant plane
# down, most useful first, so that any prefix of the stream is the best picture
# those bytes can buy; the decoder can stop at any byte; the hot loops run
# compiled (numba) because a stream holds tens of thousands of binary decisions.
#
# Plan
# - Set partitioning in the manner of SPECK: each subband is the root of a
#   quadtree of blocks (power-of-two aligned, clipped to the band).  Lists of
#   insignificant sets are kept per block size; in every bit plane the small
#   sets are tested before the big ones (single coefficients first), a
#   significant set splits into its four quadrants, a coefficient found
#   significant sends its sign, and then every coefficient already significant
#   sends its bit of this plane (refinement).  A block of four whose
#   neighbouring blocks are significant skips its set decision and tests its
#   members one by one (dense texture: the set would be significant anyway).
# - That order within a plane was measured against others (issue 40, the
#   order of decisions as the lever of rate-distortion optimised truncation:
#   the stream is cut inside a plane) and kept: none paid.  Mean PSNR change
#   over the `rovlink bench debt` photographs at 1000/2000/4000 B (held-out
#   pictures where given), each order coded by both sides alike:
#   refinement first -0.10/-0.13/-0.20 dB (horse/down at 2000 B -0.93),
#   refinement after the single coefficients and before the sets -0.03/
#   -0.07/-0.09 (held-out -0.05/-0.05/-0.12, retina-grey/bl at 4000 B -1.52;
#   8000 B -0.12): a refinement bit buys less than even the tests of sets
#   without significant neighbours here.  EBCOT's three passes (coefficients
#   and sets with a significant neighbour or parent, then refinement, then
#   the rest) -0.002/+0.001/+0.002 (clock/down at 1000 B -0.13); the same
#   split by the context's current chance of a 1 (1.5 % and up first)
#   +0.000/-0.030/+0.003 (horse/down at 2000 B -1.53).  With refinement last:
#   neighbourhood first +0.001/+0.002/+0.002 (8000 B +0.002, held-out +0.001/
#   +0.002/-0.001, retina-grey/bl at 4000 B -0.13: a hair, for a second scan
#   of every list in every plane); a chance of 3 % and up first -0.001/
#   -0.000/+0.004; the low band and the coarse details first -0.008/-0.003/
#   -0.002 dB, MS-SSIM +0.0005/+0.0002/+0.0001; the refinements of
#   coefficients new in the plane above first -0.002/+0.006/+0.000 (today's
#   refinement order is the order of significance, so those come last).
#   Even the best of six of these orders per stream, picked by the PSNR it
#   gives (an oracle), would add only +0.009 dB mean, for six encodes.
# - A coefficient may carry a "floor" plane below which its bits are known to be
#   zero (bands scaled up by a shift in the reversible mode, the region of
#   interest there); sets whose every member lies above the plane are skipped,
#   and so are sets in the top planes that their members cannot reach (each
#   coefficient has a "deficit": planes under the top it stays below, 0 in
#   the region of interest, up to SHIFT outside it).
# - One traversal routine serves both sides (`mode` 0 encodes, 1 decodes), so
#   encoder and decoder can never disagree about the order of decisions.
# - Binary decisions go through the adaptive binary range coder of
#   `rangecoder` with contexts: coefficient significance by band class and
#   number of significant neighbours, set significance by band class and block
#   size, sign, and refinement (first or later).  In the second and third
#   colour components, the first component at the same place says more: its
#   significance splits the significance and set contexts, and where it is
#   significant the sign is predicted from it and from how the two signs
#   relate at significant neighbours (+0.002/+0.005/+0.010/+0.017 dB mean
#   over the 52 photograph variants at 1000/2000/4000/8000 B, about three
#   times that on the 16 colour ones; the sign part a third of it; the set
#   contexts' split then +0.000/+0.002/+0.004/+0.005 dB more, -0.0007 at 250 B).
# - Significance and set decisions are split by their source (issue 40): a
#   set or coefficient retested from its list, or a quadrant of a set just
#   found significant, by how many siblings tested before it were
#   insignificant (0, 1, 2 or more: the more, the likelier this one) or after
#   one was significant (then the others seldom are: a point or a thin line
#   rarely fills a block).  Mean PSNR over the `rovlink bench debt` rows at
#   1000/2000/4000 B against the coder without them (priors refitted,
#   PRIOR_SEEN_DETAIL 1): photographs +0.065/+0.092/+0.109 dB with three
#   sources (list, split, split after a significant sibling), +0.073/+0.100/
#   +0.120 with five; held-out +0.083/+0.086/+0.095, +0.094/+0.098/+0.110;
#   no case lower.  Measured and left out: the same place in the two other
#   orientations of the level for a coefficient without significant
#   neighbours (+0.002 dB mean, +0.04 on hubble-grey/down at 4000 B, but the
#   grey scene's decode at 2000 B 1.34 -> 1.44 times OpenJPEG's; 1.40 when
#   only quadrants of a split set look), the members of a forced block of
#   four as a source of their own (-0.005 dB mean), the parent's
#   significance in every neighbourhood context (-0.006 to -0.010),
#   neighbours significant since an earlier plane apart from those just
#   found (-0.001 to -0.002), the parent's sign predicting a sign without
#   significant neighbours (-0.003 at 1000 B), no forced split at all
#   (-0.013 to -0.020).
# - The decoder reads a truncated stream with interval arithmetic: it tracks
#   the smallest and the largest code value the missing bytes allow and stops
#   at the first decision on which they disagree.  Every decision it makes is
#   therefore the encoder's, and a longer prefix yields a superset of them.
# - Speed (issue 40, decode within OpenJPEG's time): a grey 320x240 picture at
#   2000 B makes ~22k decisions (11k of them quadrants of split sets) in
#   ~0.6 ms, its profile flat (loads of neighbours, contexts and model, and
#   the branches on decided bits).  Measured and left out, the same streams
#   each: the decoder's step without branches on the bit (selects) 1 %
#   slower; the floor and deficit loads skipped when a plan has none (a 9/7
#   stream without a region) 2-5 % slower (the compiled loop laid out
#   worse); the traversal inlined once per mode, so each side's copy holds
#   only its own branches, numba would not inline it.

from __future__ import annotations

import numpy as np

from .jit import _inline, _jit
from .rangecoder import _code, _save, new_model, prior_model

# Context layout.  A band class is component class (0 luma/grey, 1 chroma)
# times 8 plus resolution level (0 = low band, j = level-j details), plus 16
# for sets and coefficients inside the region of interest.
NCLS = 32
# Where a decision comes from (its "source"): a set or coefficient retested
# from its list (SRC_LIST), or a quadrant of a set just found significant,
# before any of its siblings was (SRC_SPLIT) or after one was (SRC_SPLIT_SIG).
SRC_LIST = 0
SRC_SPLIT = 1      # + insignificant siblings tested before (0..2)
SRC_SPLIT_SIG = 4
NSRC = 5
# Significance: + (cls * NSRC + source) * 20 + neighbourhood context (0..9),
# + 10 beside a significant first component.  Sets: + (cls * NSRC + source) *
# 128 + min(k, 7) * 16 + set context (0..7), + 8 beside a significant first
# component.
NSIG_CTX = 10
CTX_SIG = 0
CTX_SET = CTX_SIG + NCLS * NSRC * 2 * NSIG_CTX
CTX_SIGN = CTX_SET + NCLS * NSRC * 128   # + cls * 7 + sign context (0..4; 5, 6 from the first component)
CTX_REF = CTX_SIGN + NCLS * 7    # + cls * 2 + (first refinement)
NCTX = CTX_REF + NCLS * 2
# A decoder stopped inside a pass forgets the unfinished group of new
# significance (SIG_GROUP coefficients) or refinements (REF_GROUP): one
# decision alone can make the picture a hair worse, a group practically never.
# The smallest groups that keep PSNR from dropping byte by byte on the tests'
# small images (1 or 2 do not; 4 and 16 pay over 8 and 32: +0.015/+0.008/
# +0.005/+0.002/+0.001/+0.001 dB mean on the photographs at 250-8000 B).
REF_GROUP = 16
# Set contexts (`_set_context`) in which a block of four skips its set
# decision and tests its members one by one: two or more significant
# neighbouring blocks (2), or the parent block significant (3-5).  Measured on
# the 52 photograph variants against two or more neighbours alone (2 and 5):
# +0.001/+0.003/+0.008/+0.009 dB mean at 1000/2000/4000/8000 B, brick/crop at
# 8000 B -0.087 -> -0.051 dB to JPEG 2000; also forcing blocks of 16 lost
# (-0.013 dB at 8000 B), and the other-orientation contexts (6, 7) gained less.
FORCE_SPLIT_CTXS = (2, 3, 4, 5)
SIG_GROUP = 4

# Where each context of a 9/7 stream starts (CABAC's initialisation tables,
# in DEBT's contexts): the chance of a 0, in 32nds, as the photographs leave
# it.  At 1000-4000 B a stream makes a few thousand decisions in ~900
# contexts, and a context that starts at an even chance spends its first
# decisions learning what every picture teaches alike (most sets stay
# insignificant, refinement bits lean to 0).  Measured as the coder's final
# estimates (weighted by decisions seen, up to 64) over the 52 photograph
# variants of `rovlink bench debt` at 1000/2000/3000/4000 B, pooled over
# band classes (luma and chroma apart for significance and sets; sets
# pooled over their sizes), then checked on the held-out pictures (`--images
# heldout`, never used for the table).  Against an even start, mean PSNR
# and MS-SSIM at 250/500/1000-4000/8000 B: photographs +0.074/+0.059/
# +0.034/+0.020 dB and +0.0031/+0.0021/+0.0005/+0.0001, held-out +0.092/
# +0.069/+0.039/+0.020 dB and +0.0034/+0.0024/+0.0005/+0.0001; no held-out
# case lower in PSNR, the worst photograph -0.015 dB (horse/down at 1000 B).
# PRIOR_SEEN: the prior counts as that many decisions already seen; more
# trusts it longer (1000-4000 B, photographs/held-out: 0 +0.008/+0.012, 1
# +0.034/+0.039, 2 +0.044/+0.049, 4 +0.046/+0.052 dB) but costs pictures
# unlike the photographs: a flat colour picture at 60 B shows a mean error
# of 0.70/1.45/2.01/3.09 at 0/1/2/4 (test_a_flat_colour_picture_takes_
# brightness_first asks for < 2).  One context per band class and size
# instead of the pooled table: +0.005 dB more, for 900 entries.  The table
# is per source (see the top), refitted the same way when the sources came
# (issue 40).  PRIOR_SEEN_DETAIL: the detail bands' significance and set
# contexts trust their prior longer, the low band (where a flat picture
# differs most from the photographs) as before.  Over PRIOR_SEEN_DETAIL 1,
# mean PSNR at 1000/2000/4000 B: photographs +0.027/+0.026/+0.022 dB,
# held-out +0.028/+0.025/+0.023 dB.  4 gained as much but put the seabed's
# 64x64 picture 0.41 dB back at its 41st byte (two groups of chroma
# low-band refinements, every bit 0, completed in one byte;
# test_psnr_byte_by_byte_on_small_images); 8 gained about 0.01 dB more
# than 4 and put a photograph 0.08 dB below the coder before issue 40's
# contexts.  At 3, against the coder before them, no case of the
# photographs, the held-out pictures or the samples at 250/500/1000-4000/
# 8000 B is lower (means at 250/500/8000 B: +0.083/+0.096/+0.137,
# +0.118/+0.111/+0.129, +0.093/+0.083/+0.156 dB), and the flat colour
# picture's error at 60 B is 1.67.
PRIOR_SIG = (((29, 26, 23, 24, 22, 21, 22, 19, 18, 27, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, list
              (23, 21, 20, 17, 18, 13, 15, 13, 17, 22, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 0
              (21, 21, 18, 16, 14, 13, 14, 11, 13, 21, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 1
              (16, 17, 16, 12, 12, 9, 11, 10, 16, 15, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 2+
              (16, 29, 27, 27, 24, 26, 25, 22, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16, 16)),  # luma, split sig
             ((30, 29, 27, 28, 27, 25, 26, 23, 19, 30, 26, 24, 21, 22, 21, 19, 20, 17, 16, 26),  # chroma, list
              (27, 29, 16, 23, 16, 17, 22, 16, 16, 26, 18, 17, 14, 15, 15, 10, 12, 9, 16, 17),  # chroma, split 0
              (27, 28, 16, 23, 16, 17, 21, 16, 16, 26, 16, 17, 16, 14, 16, 9, 12, 16, 16, 15),  # chroma, split 1
              (24, 26, 16, 21, 16, 15, 20, 16, 16, 23, 12, 13, 16, 11, 16, 7, 11, 16, 16, 11),  # chroma, split 2+
              (16, 31, 29, 30, 26, 29, 27, 27, 13, 16, 16, 27, 24, 24, 22, 23, 21, 20, 10, 16)))  # chroma, split sig
PRIOR_SET = (((29, 26, 20, 15, 11, 6, 22, 19, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, list
              (26, 20, 13, 15, 11, 8, 21, 16, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 0
              (25, 19, 13, 14, 10, 8, 20, 15, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 1
              (21, 16, 11, 11, 8, 6, 17, 13, 16, 16, 16, 16, 16, 16, 16, 16),  # luma, split 2+
              (30, 28, 20, 23, 19, 12, 27, 23, 16, 16, 16, 16, 16, 16, 16, 16)),  # luma, split sig
             ((31, 30, 30, 16, 22, 23, 29, 27, 29, 22, 16, 17, 10, 6, 17, 15),  # chroma, list
              (30, 27, 16, 21, 20, 16, 28, 16, 20, 16, 12, 12, 9, 7, 16, 14),  # chroma, split 0
              (30, 26, 16, 19, 21, 16, 26, 22, 20, 15, 16, 12, 8, 6, 16, 11),  # chroma, split 1
              (29, 25, 16, 17, 19, 16, 25, 16, 17, 16, 16, 10, 7, 5, 14, 12),  # chroma, split 2+
              (31, 31, 27, 28, 27, 20, 29, 28, 28, 25, 15, 20, 17, 10, 23, 20)))  # chroma, split sig
PRIOR_SIGN = (16, 15, 16, 15, 15, 24, 26)
PRIOR_REF = (19, 24)
PRIOR_SEEN = 1
PRIOR_SEEN_DETAIL = 3   # in the detail bands' significance and set contexts


def _prior_table() -> np.ndarray:
    zero = np.full(NCTX, 16, dtype=np.int64)
    for cls in range(NCLS):
        chroma = (cls % 16) // 8
        for src in range(NSRC):
            i = cls * NSRC + src
            zero[CTX_SIG + i * 2 * NSIG_CTX:CTX_SIG + (i + 1) * 2 * NSIG_CTX] = PRIOR_SIG[chroma][src]
            zero[CTX_SET + i * 128:CTX_SET + (i + 1) * 128] = np.tile(PRIOR_SET[chroma][src], 8)
        zero[CTX_SIGN + cls * 7:CTX_SIGN + (cls + 1) * 7] = PRIOR_SIGN
        zero[CTX_REF + cls * 2:CTX_REF + (cls + 1) * 2] = PRIOR_REF
    seen = np.full(NCTX, PRIOR_SEEN, dtype=np.int64)
    for cls in range(NCLS):
        if cls % 8 != 0:
            seen[CTX_SIG + cls * NSRC * 2 * NSIG_CTX:CTX_SIG + (cls + 1) * NSRC * 2 * NSIG_CTX] = PRIOR_SEEN_DETAIL
            seen[CTX_SET + cls * NSRC * 128:CTX_SET + (cls + 1) * NSRC * 128] = PRIOR_SEEN_DETAIL
    return prior_model(zero, seen)


PRIOR_MODEL = _prior_table()


def _sig_table_entry(orient: int, nh: int, nv: int, nd: int) -> int:
    # The significance context of a coefficient whose neighbours count nh
    # along its band's edges, nv across and nd diagonally: the EBCOT split.
    if orient == 1:  # high-pass across columns: edges run vertically
        nh, nv = nv, nh
    if orient == 3:
        hv = nh + nv
        if nd >= 3:
            return 8
        if nd == 2:
            return 7 if hv >= 1 else 6
        if nd == 1:
            return 5 if hv >= 2 else (4 if hv == 1 else 3)
        return 2 if hv >= 2 else (1 if hv == 1 else 0)
    if nh == 2:
        return 8
    if nh == 1:
        if nv >= 1:
            return 7
        return 6 if nd >= 1 else 5
    if nv == 2:
        return 4
    if nv == 1:
        return 3
    if nd >= 2:
        return 2
    return 1 if nd == 1 else 0


# `_sig_context` as a table (a lookup instead of a tree of unpredictable
# branches): by orientation (0..3), then nh (0..2), nv (0..2), nd (0..4).
SIG_TABLE = np.array([_sig_table_entry(o, nh, nv, nd) for o in range(4) for nh in range(3)
                      for nv in range(3) for nd in range(5)], dtype=np.int64)


def _sign_table_entry(hc: int, vc: int) -> int:
    # EBCOT's sign context (0..4) and prediction (flip) from the clamped
    # horizontal and vertical neighbour sums, as sctx * 2 + flip.
    flip = 0
    if hc < 0 or (hc == 0 and vc < 0):
        flip = 1
        hc = -hc
        vc = -vc
    if hc == 0:
        sctx = 0 if vc == 0 else 1
    else:
        sctx = 4 if vc == 1 else (3 if vc == 0 else 2)
    return sctx * 2 + flip


SIGN_TABLE = np.array([_sign_table_entry(hc, vc) for hc in (-1, 0, 1) for vc in (-1, 0, 1)], dtype=np.int64)


@_inline
def _node_at(leaf, pyramid, binfo, noff, nw, b, k, y, x):
    # A set's value: at level 0 the coefficient's own (leaf array), above it
    # the block node's (pyramid).  Used for magnitudes, floors and deficits
    # (planes below the top where no member can be significant: 0 inside the
    # region of interest, up to the shift outside it).
    if k == 0:
        return leaf[binfo[b, 0] + y * binfo[b, 2] + x]
    return pyramid[noff[b, k] + y * nw[b, k] + x]


@_inline
def _sig_context(sig, off, h, w, y, x, orient):
    # Significance context from the 8 neighbours, split as EBCOT does into
    # along-edge (h), across-edge (v) and diagonal (d) counts: in a band that
    # is high-pass horizontally, significant coefficients line up vertically.
    up = y > 0
    dn = y + 1 < h
    lf = x > 0
    rt = x + 1 < w
    row = off + y * w
    nh = 0
    nv = 0
    nd = 0
    if lf:
        nh += sig[row + x - 1]
    if rt:
        nh += sig[row + x + 1]
    if up:
        nv += sig[row - w + x]
        if lf:
            nd += sig[row - w + x - 1]
        if rt:
            nd += sig[row - w + x + 1]
    if dn:
        nv += sig[row + w + x]
        if lf:
            nd += sig[row + w + x - 1]
        if rt:
            nd += sig[row + w + x + 1]
    return SIG_TABLE[orient * 45 + nh * 15 + nv * 5 + nd]


@_inline
def _first_component(binfo, b, y, x):
    # The same coefficient of the first colour component, or -1.
    lb = binfo[b, 10]
    if lb < 0 or y >= binfo[lb, 1] or x >= binfo[lb, 2]:
        return -1
    return binfo[lb, 0] + y * binfo[lb, 2] + x


@_inline
def _first_block(nsig, sig, noff, nw, binfo, b, k, y, x):
    # 8 when the same block of the first colour component is significant.
    lb = binfo[b, 10]
    if lb < 0 or k > binfo[lb, 3]:
        return 0
    if y >= ((binfo[lb, 1] + (np.int64(1) << k) - 1) >> k) or x >= nw[lb, k]:
        return 0
    return 8 if nsig[noff[lb, k] + y * nw[lb, k] + x] else 0


@_inline
def _sig_context_parent(sig, binfo, b, off, h, w, y, x):
    # Plus NSIG_CTX when the first colour component is significant at this place.
    ctx = _sig_context_parent0(sig, binfo, b, off, h, w, y, x)
    lc = _first_component(binfo, b, y, x)
    if lc >= 0 and sig[lc]:
        return ctx + NSIG_CTX
    return ctx


@_inline
def _sig_context_parent0(sig, binfo, b, off, h, w, y, x):
    # With no significant neighbour, whether the parent (same orientation,
    # one level coarser) is significant still says much at low rates.
    ctx = _sig_context(sig, off, h, w, y, x, binfo[b, 5])
    if ctx == 0:
        pb = binfo[b, 6]
        if pb >= 0:
            py = y >> binfo[b, 9]
            px = x >> binfo[b, 9]
            if py < binfo[pb, 1] and px < binfo[pb, 2]:
                if sig[binfo[pb, 0] + py * binfo[pb, 2] + px]:
                    return 9
    return ctx


@_inline
def _set_context(nsig, sig, noff, nw, binfo, b, k, y, x):
    # Blocks next to blocks already found significant are likelier to be.
    # Returns 0..7; 2-5 force a split at k = 1 (FORCE_SPLIT_CTXS).
    base = noff[b, k]
    wk = nw[b, k]
    hk = (binfo[b, 1] + (np.int64(1) << k) - 1) >> k
    i = base + y * wk + x
    c = 0
    if x > 0:
        c += nsig[i - 1]
    if x + 1 < wk:
        c += nsig[i + 1]
    if y > 0:
        c += nsig[i - wk]
    if y + 1 < hk:
        c += nsig[i + wk]
    # The same block of the parent band (one level coarser, same orientation)
    # tells whether this region holds any detail, whatever the neighbours
    # say: 0-2 significant neighbours (capped), plus 3 when the parent block
    # is significant.  (Measured on the photographs: the parent beside the
    # neighbours +0.015 to +0.076 dB mean at 250-8000 B over the parent only
    # when no neighbour is significant; counts capped at 3 instead of 2 lost
    # 0.001-0.004 dB.)
    par = False
    pb = binfo[b, 6]
    if pb >= 0 and binfo[pb, 1] > 0 and binfo[pb, 2] > 0:
        pk_ = k - binfo[b, 9]
        if pk_ == 0:
            if y < binfo[pb, 1] and x < binfo[pb, 2]:
                if sig[binfo[pb, 0] + y * binfo[pb, 2] + x]:
                    par = True
        elif pk_ <= binfo[pb, 3]:
            if y < ((binfo[pb, 1] + (np.int64(1) << pk_) - 1) >> pk_) and x < nw[pb, pk_]:
                if nsig[noff[pb, pk_] + y * nw[pb, pk_] + x]:
                    par = True
    if par:
        return (c if c < 2 else 2) + 3
    if c <= 1:
        # Nor the parent: the same block of the two other orientations of
        # this level (+0.001 to +0.019 dB mean at 250-8000 B; also for two
        # neighbours, or for sets with the parent significant, less).
        o = binfo[b, 5]
        if o >= 1:
            for t in range(3):
                sb = binfo[b, 7] + t * binfo[b, 8]
                if sb == b or sb >= binfo.shape[0]:
                    continue
                if k == 0:
                    if y < binfo[sb, 1] and x < binfo[sb, 2]:
                        if sig[binfo[sb, 0] + y * binfo[sb, 2] + x]:
                            return 6 + c
                elif k <= binfo[sb, 3]:
                    if y < ((binfo[sb, 1] + (np.int64(1) << k) - 1) >> k) and x < nw[sb, k]:
                        if nsig[noff[sb, k] + y * nw[sb, k] + x]:
                            return 6 + c
    return c if c < 2 else 2


@_inline
def _sign_part(sig, sgn, i):
    # +1 for a significant positive neighbour, -1 for a negative one, 0 for
    # an insignificant one (without a branch: sig and sgn are 0 or 1).
    return np.int64(sig[i]) * (1 - 2 * np.int64(sgn[i]))


@_inline
def _new_significant(mode, a0, a1, a2, a3, a4, lim, buf, probs,  binfo, b, off, h, w, y, x, p,
                     cls, neg, sig, sgn, rec, pk, sigplane, lsp, nlsp):
    # A coefficient just found significant: its sign, then its state.  The
    # sign is predicted from the signs of the horizontal and vertical
    # neighbours (EBCOT's five contexts, the prediction folded in by XOR).
    c = off + y * w + x
    hc = 0
    vc = 0
    if x > 0:
        hc += _sign_part(sig, sgn, c - 1)
    if x + 1 < w:
        hc += _sign_part(sig, sgn, c + 1)
    if y > 0:
        vc += _sign_part(sig, sgn, c - w)
    if y + 1 < h:
        vc += _sign_part(sig, sgn, c + w)
    hc = max(-1, min(1, hc))
    vc = max(-1, min(1, vc))
    e = SIGN_TABLE[(hc + 1) * 3 + vc + 1]
    flip = e & 1
    sctx = e >> 1
    # A colour component after the first, where the first is significant:
    # the signs of the two relate the same way as at significant neighbours
    # where both are (local colour correlation): predicted by their votes.
    lc = _first_component(binfo, b, y, x)
    if lc >= 0 and sig[lc]:
        same = 0
        other = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                yy = y + dy
                xx = x + dx
                if (dy == 0 and dx == 0) or yy < 0 or xx < 0 or yy >= h or xx >= w:
                    continue
                n = off + yy * w + xx
                if not sig[n]:
                    continue
                ln = _first_component(binfo, b, yy, xx)
                if ln < 0 or not sig[ln]:
                    continue
                if sgn[n] == sgn[ln]:
                    same += 1
                else:
                    other += 1
        if same != other:
            flip = np.int64(sgn[lc]) if same > other else 1 - np.int64(sgn[lc])
            sctx = 6 if abs(same - other) >= 2 else 5
    # (`neg` is a placeholder of one element when decoding: never index it then.)
    nb = (neg[c] if mode == 0 else 0) ^ flip
    a0, a1, a2, a3, a4, s = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                  CTX_SIGN + cls * 7 + sctx, nb)
    if s < 0:
        return a0, a1, a2, a3, a4, -1
    s ^= flip
    sig[c] = 1
    sgn[c] = s
    rec[c] = np.int64(1) << p
    pk[c] = p
    sigplane[c] = p
    lsp[nlsp] = c
    return a0, a1, a2, a3, a4, nlsp + 1


@_jit
def _drop_unfinished(lsp, nbefore, nlsp, rec, pk):
    # The decoder stopped inside a sorting pass.  Coefficients found
    # significant are shown in groups: a single one can, through the overlap
    # of non-orthogonal basis functions, make the picture a hair worse; a few
    # together practically never do.  So forget the unfinished group.
    for m in range(nlsp - (nlsp - nbefore) % SIG_GROUP, nlsp):
        c = lsp[m]
        rec[c] = 0
        pk[c] = -1
    return 0


def run(mode, mag, neg, cfloor, ccls, node_max, node_floor, binfo, noff, nw, seg,
        kmax, top, buf, st, rec, pk, sgn, cdef, node_def, prior: bool = False):
    """Traverse the bit planes from `top` down to 0, coding every decision.

    prior: the contexts start from PRIOR_MODEL (9/7 streams, whose
    statistics it was measured on) instead of an even chance (the integer
    5/3 streams, whose bands hold exact integers shifted by their floors).

    Returns 1 when all planes were coded, 0 when the byte limit (encoder) or
    the end of the certain data (decoder) stopped it first."""
    ncoef = cfloor.shape[0]
    probs = PRIOR_MODEL.copy() if prior else new_model(NCTX)
    lis = np.empty(max(int(seg[kmax + 1]), 1), dtype=np.int64)
    lis_len = np.zeros(kmax + 1, dtype=np.int64)
    sig = np.zeros(ncoef, dtype=np.uint8)
    sigplane = np.zeros(ncoef, dtype=np.int8)
    lsp = np.empty(ncoef, dtype=np.int32)
    stack = np.empty((4 * (kmax + 2), 3), dtype=np.int64)
    cy4 = np.empty(4, dtype=np.int64)
    cx4 = np.empty(4, dtype=np.int64)
    cv4 = np.empty(4, dtype=np.int64)
    nsig = np.zeros(node_floor.shape[0], dtype=np.uint8)
    return _traverse(mode, mag, neg, cfloor, ccls, node_max, node_floor, binfo, noff, nw, seg,
                     kmax, top, buf, st, rec, pk, sgn, cdef, node_def, probs,  lis, lis_len,
                     sig, sigplane, lsp, stack, cy4, cx4, cv4, nsig)


@_jit
def _traverse(mode, mag, neg, cfloor, ccls, node_max, node_floor, binfo, noff, nw, seg,
              kmax, top, buf, st, rec, pk, sgn, cdef, node_def, probs,  lis, lis_len,
              sig, sigplane, lsp, stack, cy4, cx4, cv4, nsig):
    nb = binfo.shape[0]
    a0, a1, a2, a3, a4, lim = st[0], st[1], st[2], st[3], st[4], st[5]
    nlsp = 0
    for b in range(nb):
        if binfo[b, 1] == 0 or binfo[b, 2] == 0:
            continue
        kb = binfo[b, 3]
        lis[seg[kb] + lis_len[kb]] = b << 40
        lis_len[kb] += 1

    for p in range(top, -1, -1):
        thr = np.int64(1) << p
        nbefore = nlsp
        # Sorting pass: smallest sets first.
        for k in range(kmax + 1):
            base = seg[k]
            n = lis_len[k]
            j = 0
            for i in range(n):
                e = lis[base + i]
                b = e >> 40
                y = (e >> 20) & 0xFFFFF
                x = e & 0xFFFFF
                # Floor byte: lowest coded plane, plus 128 when the set
                # touches the region of interest (contexts).  Deficit: the
                # set cannot be significant in its top `dd` planes (lower
                # priority than the region), so it is not tested there.
                v = _node_at(cfloor, node_floor, binfo, noff, nw, b, k, y, x)
                dd = _node_at(cdef, node_def, binfo, noff, nw, b, k, y, x)
                if (v & 127) > p or p > top - dd:
                    lis[base + j] = e
                    j += 1
                    continue
                off = binfo[b, 0]
                h = binfo[b, 1]
                w = binfo[b, 2]
                bcls = binfo[b, 4]
                cls = bcls + (16 if v >= 128 else 0)
                bit = 0
                if mode == 0:
                    bit = 1 if _node_at(mag, node_max, binfo, noff, nw, b, k, y, x) >= thr else 0
                if k == 0:
                    c = off + y * w + x
                    ctx = CTX_SIG + cls * (NSRC * 2 * NSIG_CTX) + _sig_context_parent(sig, binfo, b, off, h, w, y, x)
                    a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                   ctx, bit)
                    if r < 0:
                        _save(st, a0, a1, a2, a3, a4)
                        return _drop_unfinished(lsp, nbefore, nlsp, rec, pk)
                    if r == 0:
                        lis[base + j] = e
                        j += 1
                        continue
                    a0, a1, a2, a3, a4, r = _new_significant(
                        mode, a0, a1, a2, a3, a4, lim, buf, probs,  binfo, b, off, h, w, y, x, p,
                        cls, neg, sig, sgn, rec, pk, sigplane, lsp, nlsp)
                    if r < 0:
                        _save(st, a0, a1, a2, a3, a4)
                        return _drop_unfinished(lsp, nbefore, nlsp, rec, pk)
                    nlsp = r
                    continue
                kk = k if k < 7 else 7
                sctx = _set_context(nsig, sig, noff, nw, binfo, b, k, y, x)
                # A block of four among significant blocks, or under a
                # significant parent block, is likely significant too: test
                # its members one by one instead (no set decision, and no
                # member implied).
                forced = k == 1 and FORCE_SPLIT_CTXS[0] <= sctx <= FORCE_SPLIT_CTXS[-1]
                if forced:
                    r = 1
                else:
                    ctx = CTX_SET + cls * (NSRC * 128) + kk * 16 + sctx + _first_block(nsig, sig, noff, nw, binfo, b, k, y, x)
                    a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                  ctx, bit)
                if r < 0:
                    _save(st, a0, a1, a2, a3, a4)
                    return _drop_unfinished(lsp, nbefore, nlsp, rec, pk)
                if r == 0:
                    lis[base + j] = e
                    j += 1
                    continue
                if not forced:
                    nsig[noff[b, k] + y * nw[b, k] + x] = 1
                # Significant set: split it, depth first, until every piece
                # is either an insignificant set (back in a list) or a
                # significant coefficient.
                depth = 1
                stack[0, 0] = k
                stack[0, 1] = y
                stack[0, 2] = x
                while depth > 0:
                    depth -= 1
                    pk_ = stack[depth, 0]
                    py = stack[depth, 1]
                    px = stack[depth, 2]
                    ck = pk_ - 1
                    hk = (h + (np.int64(1) << ck) - 1) >> ck
                    wk = (w + (np.int64(1) << ck) - 1) >> ck
                    nchild = 0
                    for t in range(4):
                        yy = 2 * py + (t >> 1)
                        xx = 2 * px + (t & 1)
                        if yy < hk and xx < wk:
                            cy4[nchild] = yy
                            cx4[nchild] = xx
                            nchild += 1
                    # The parent holds a significant member, and a child
                    # skipped here (below its floor, or background in the top
                    # planes) cannot be it: so when every tested child before
                    # the last one that can be tested was insignificant, that
                    # one is significant and costs no decision.
                    # (Each child's floor byte is kept in cv4, -1 when it
                    # is skipped, for the pass below.)
                    last = -1
                    for t in range(nchild):
                        v = _node_at(cfloor, node_floor, binfo, noff, nw, b, ck, cy4[t], cx4[t])
                        dd = _node_at(cdef, node_def, binfo, noff, nw, b, ck, cy4[t], cx4[t])
                        if (v & 127) > p or p > top - dd:
                            cv4[t] = -1
                        else:
                            cv4[t] = v
                            last = t
                    any_sig = False
                    nins = 0
                    for t in range(nchild):
                        yy = cy4[t]
                        xx = cx4[t]
                        packed = (b << 40) | (yy << 20) | xx
                        v = cv4[t]
                        if v < 0:
                            lis[seg[ck] + lis_len[ck]] = packed
                            lis_len[ck] += 1
                            continue
                        cls = bcls + (16 if v >= 128 else 0)
                        if t == last and not any_sig and not forced:
                            r = 1  # the parent is significant, so this one is
                        else:
                            cbit = 0
                            if mode == 0:
                                m = _node_at(mag, node_max, binfo, noff, nw, b, ck, yy, xx)
                                cbit = 1 if m >= thr else 0
                            src = SRC_LIST if forced else (SRC_SPLIT_SIG if any_sig else SRC_SPLIT + (nins if nins < 2 else 2))
                            if ck == 0:
                                ctx = CTX_SIG + (cls * NSRC + src) * (2 * NSIG_CTX) + _sig_context_parent(
                                    sig, binfo, b, off, h, w, yy, xx)
                            else:
                                kk = ck if ck < 7 else 7
                                ctx = CTX_SET + (cls * NSRC + src) * 128 + kk * 16 + _set_context(
                                    nsig, sig, noff, nw, binfo, b, ck, yy, xx) + _first_block(
                                    nsig, sig, noff, nw, binfo, b, ck, yy, xx)
                            a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                                           ctx, cbit)
                            if r < 0:
                                _save(st, a0, a1, a2, a3, a4)
                                return _drop_unfinished(lsp, nbefore, nlsp, rec, pk)
                        if r == 0:
                            lis[seg[ck] + lis_len[ck]] = packed
                            lis_len[ck] += 1
                            nins += 1
                            continue
                        any_sig = True
                        if forced:
                            nsig[noff[b, k] + y * nw[b, k] + x] = 1
                        if ck == 0:
                            c = off + yy * w + xx
                            a0, a1, a2, a3, a4, r = _new_significant(
                                mode, a0, a1, a2, a3, a4, lim, buf, probs,  binfo, b, off, h, w,
                                yy, xx, p, cls, neg, sig, sgn, rec, pk, sigplane, lsp, nlsp)
                            if r < 0:
                                _save(st, a0, a1, a2, a3, a4)
                                return _drop_unfinished(lsp, nbefore, nlsp, rec, pk)
                            nlsp = r
                        else:
                            nsig[noff[b, ck] + yy * nw[b, ck] + xx] = 1
                            stack[depth, 0] = ck
                            stack[depth, 1] = yy
                            stack[depth, 2] = xx
                            depth += 1
            # Splitting a set of this size only feeds smaller lists, so this
            # one did not grow while it was scanned.
            lis_len[k] = j
        # Refinement pass: coefficients significant before this plane.
        for i in range(nbefore):
            c = lsp[i]
            if (cfloor[c] & 127) > p:
                continue
            bit = 0
            if mode == 0:
                bit = (mag[c] >> p) & 1
            first = 1 if sigplane[c] == p + 1 else 0
            a0, a1, a2, a3, a4, r = _code(mode, a0, a1, a2, a3, a4, lim, buf, probs,
                                          CTX_REF + (np.int64(ccls[c]) + (16 if cfloor[c] >= 128 else 0)) * 2 + first, bit)
            if r < 0:
                # One refinement can move a value away from the truth; a group
                # of them almost never does.  Drop the unfinished group so that
                # a longer prefix never shows a worse picture.
                for m in range(i - i % REF_GROUP, i):
                    c = lsp[m]
                    if (cfloor[c] & 127) <= p:
                        rec[c] &= ~(np.int64(1) << p)
                        pk[c] = p + 1
                return _save(st, a0, a1, a2, a3, a4)
            rec[c] |= r << p
            pk[c] = p
    _save(st, a0, a1, a2, a3, a4)
    return 1
