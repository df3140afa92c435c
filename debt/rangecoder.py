# DEBT's adaptive binary range coder (LZMA-style carry handling), on both
# sides.  The encoder stops at a byte limit; the decoder reads a truncated
# stream with interval arithmetic: it tracks the smallest and the largest code
# value the missing bytes allow and refuses (returns -1 for) the first decision
# on which they disagree, so every decision it makes is the encoder's.
#
# `_code` is inlined into the traversal so that the coder state (five scalars)
# stays in registers; `encoder_state`/`decoder_state` hold it between calls.

from __future__ import annotations

import numpy as np

from .jit import _inline, _jit

PROB_BITS = 15
PROB_ONE = 1 << PROB_BITS
# Adaptation speed per context as it sees more decisions: fast at first (few
# decisions at low budgets), then steadier.  Each context keeps two estimates,
# one that stops slowing down at FAST_CAP and one that follows RATE to the
# end, and codes with their mean: the statistics drift from plane to plane,
# and the mix tracks drift and settles noise both (measured on the
# photographs: +0.004 to +0.014 dB mean at 1000-8000 B over one estimate with
# RATE ending at 5; a single slower estimate lost 0.01 dB).
RATE = np.array([1, 2, 2, 3, 3, 3, 3] + [4] * 9 + [5] * 48 + [6] * 128 + [7] * 64, dtype=np.int64)
RATE_LAST = RATE.shape[0] - 1
FAST_CAP = 4


@_jit
def _shift_low(st, buf):
    low = st[0]
    if low < 0xFF000000 or low >= 0x100000000:
        carry = low >> 32
        temp = st[2]
        while True:
            pos = st[4]
            if pos < buf.shape[0]:
                buf[pos] = (temp + carry) & 0xFF
            st[4] = pos + 1
            temp = 0xFF
            st[3] -= 1
            if st[3] == 0:
                break
        st[2] = (low >> 24) & 0xFF
    st[3] += 1
    st[0] = (low & 0x00FFFFFF) << 8


@_inline
def _shift_low_t(low, cache, cache_size, pos, buf):
    # `_shift_low` on scalars, so that the coder state stays in registers.
    if low < 0xFF000000 or low >= 0x100000000:
        carry = low >> 32
        temp = cache
        while True:
            if pos < buf.shape[0]:
                buf[pos] = (temp + carry) & 0xFF
            pos += 1
            temp = 0xFF
            cache_size -= 1
            if cache_size == 0:
                break
        cache = (low >> 24) & 0xFF
    cache_size += 1
    low = (low & 0x00FFFFFF) << 8
    return low, cache, cache_size, pos


@_inline
def _rate(n):
    # RATE[n] without a memory access (on the decoder's critical path).
    return (1 + (1 if n >= 1 else 0) + (1 if n >= 3 else 0) + (1 if n >= 7 else 0) + (1 if n >= 16 else 0)
            + (1 if n >= 64 else 0) + (1 if n >= 192 else 0))


MODEL_INIT = (PROB_ONE // 2) | (PROB_ONE // 2) << 16


def new_model(ncontexts: int) -> np.ndarray:
    """Fresh adaptive state for `ncontexts` contexts, one int64 each: the fast
    estimate in bits 0-15, the slow one in bits 16-31, the decisions seen
    (up to RATE_LAST) from bit 32: one load and one store a decision."""
    return np.full(ncontexts, MODEL_INIT, dtype=np.int64)


def prior_model(zero_32nds: np.ndarray, seen: int) -> np.ndarray:
    """Adaptive state for one context per entry of `zero_32nds` (the chance of
    a 0, in 32nds): both estimates start there and, where it is not 16 (an
    even chance: no prior), as if `seen` decisions had been made, so that the
    first ones do not sweep the prior away."""
    p = np.asarray(zero_32nds, dtype=np.int64) << (PROB_BITS - 5)
    n = np.where(p != PROB_ONE // 2, seen, 0).astype(np.int64)
    return p | (p << 16) | (n << 32)


@_inline
def _code(mode, a0, a1, a2, a3, a4, lim, buf, model, ctx, bit):
    """Encode `bit` (mode 0) or decode one (mode 1) in context `ctx`.

    The coder state travels as scalars (five times faster than an array):
    encoder (low, range, cache, cache size, bytes out), decoder (range,
    lowest code, highest code, next byte, unused); `lim` is the encoder's
    byte limit or the number of bytes the decoder holds; `model` is
    `new_model`'s.  Returns the new state and the bit, or -1 when the
    encoder reached its byte limit or the decoder cannot be sure of the
    decision from the bytes it has."""
    m = model[ctx]
    pf = m & 0xFFFF
    ps = (m >> 16) & 0xFFFF
    p = (pf + ps) >> 1
    if mode == 0:
        if a4 >= lim:
            return a0, a1, a2, a3, a4, -1
        bound = (a1 >> PROB_BITS) * p
        if bit == 0:
            a1 = bound
        else:
            a0 += bound
            a1 -= bound
        while a1 < 0x1000000:
            a1 <<= 8
            a0, a2, a3, a4 = _shift_low_t(a0, a2, a3, a4, buf)
    else:
        bound = (a0 >> PROB_BITS) * p
        if a2 < bound:
            bit = 0
            a0 = bound
        elif a1 >= bound:
            bit = 1
            a1 -= bound
            a2 -= bound
            a0 -= bound
        else:
            return a0, a1, a2, a3, a4, -1
        while a0 < 0x1000000:
            a0 <<= 8
            if a3 < lim:
                byte = np.int64(buf[a3])
                a1 = (a1 << 8) | byte
                a2 = (a2 << 8) | byte
            else:
                a1 = a1 << 8
                a2 = (a2 << 8) | 0xFF
            a3 += 1
    n = m >> 32
    slow = _rate(n)
    fast = slow if slow < FAST_CAP else FAST_CAP
    if n < RATE_LAST:
        n += 1
    if bit == 0:
        pf += (PROB_ONE - pf) >> fast
        ps += (PROB_ONE - ps) >> slow
    else:
        pf -= pf >> fast
        ps -= ps >> slow
    pf = min(max(pf, 32), PROB_ONE - 32)     # kept off the ends (no branch)
    ps = min(max(ps, 32), PROB_ONE - 32)
    model[ctx] = pf | (ps << 16) | (n << 32)
    return a0, a1, a2, a3, a4, bit


@_jit
def _save(st, a0, a1, a2, a3, a4):
    st[0] = a0
    st[1] = a1
    st[2] = a2
    st[3] = a3
    st[4] = a4
    return 0


@_jit
def flush(st, buf):
    for _ in range(5):
        _shift_low(st, buf)
    return st[4]


def encoder_state(limit: int) -> np.ndarray:
    # [low, range, cache, cache size, bytes out, byte limit]
    return np.array([0, 0xFFFFFFFF, 0, 1, 0, limit], dtype=np.int64)


def decoder_state(data: np.ndarray) -> np.ndarray:
    # [range, lowest code, highest code, next byte, unused, bytes held]
    lo = 0
    hi = 0
    for i in range(4):
        byte = int(data[i]) if i < data.shape[0] else None
        lo = (lo << 8) | (0 if byte is None else byte)
        hi = (hi << 8) | (0xFF if byte is None else byte)
    rng = 0xFFFFFFFF
    hi = min(hi, rng - 1)
    return np.array([rng, lo, hi, 4, 0, data.shape[0]], dtype=np.int64)
