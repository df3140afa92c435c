"""Encoding made faster must code every stream byte for byte as before.

The kernels rewritten for it (issue 23) against the simple versions kept
here, bit for bit: the wavelet packets lifted where they lie against one
`forward97`/`inverse97` call per region on a copy, the colour moments
against pixel-by-pixel integer sums, the max-pyramid against its 2x2 loop,
the squared errors of the encoder's pictures against the pictures made and
compared in numpy, the two-colour test against numpy's count; and the
per-thread work arrays shared by no two threads.  The streams themselves:
the digests of test_decode_speed.py."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from rovlink.debt import codec, kernels, samples, twolevel
from rovlink.debt.plan import plan_for

NONE = np.zeros(4, dtype=np.int64)


def _split_one_by_one(a, splits, forward):
    want = a.copy()
    order = range(len(splits)) if forward else range(len(splits) - 1, -1, -1)
    for c in range(a.shape[0]):
        for i in order:
            y0, x0, bh, bw = (int(v) for v in splits[i])
            region = np.ascontiguousarray(want[c, y0:y0 + bh, x0:x0 + bw])
            (kernels.forward97 if forward else kernels.inverse97)(region, 1, NONE)
            want[c, y0:y0 + bh, x0:x0 + bw] = region
    return want


@pytest.mark.parametrize("forward", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_packets_lifted_in_place_are_one_call_per_region_on_a_copy(forward, seed):
    # Regions of every odd and tiny shape (one row, one column, one sample),
    # overlapping ones too (a later region works on the earlier's output).
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 40)), int(rng.integers(1, 40))
    splits = []
    for _ in range(int(rng.integers(1, 7))):
        y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
        splits.append((y0, x0, int(rng.integers(1, h - y0 + 1)), int(rng.integers(1, w - x0 + 1))))
    splits += [(0, 0, 1, w), (0, 0, h, 1), (0, 0, 1, 1), (0, 0, h, w)]
    table = np.array(splits, dtype=np.int64)
    a = rng.normal(size=(2, h, w)) * 60
    want = _split_one_by_one(a, table, forward)
    kernels.packets97(a, table, forward)
    assert np.array_equal(a.view(np.int64), want.view(np.int64)), splits


def _moments_pixel_by_pixel(img):
    x = img.astype(np.int64)
    d = np.concatenate(((x[1:] - x[:-1]).reshape(-1, 3), (x[:, 1:] - x[:, :-1]).reshape(-1, 3)))
    p = x.reshape(-1, 3)
    return (d.T @ d).astype(np.float64), (p.T @ p).astype(np.float64), p.sum(axis=0).astype(np.float64)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (9, 1), (2, 2), (17, 33), (240, 320)])
def test_colour_moments_are_the_exact_integer_sums(shape):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    img = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    detail, pixels, total = np.zeros((3, 3)), np.ones((3, 3)), np.zeros(3)
    kernels.colour_moments(img, detail, pixels, total)
    d, p, t = _moments_pixel_by_pixel(img)
    assert np.array_equal(detail, d)
    assert np.array_equal(pixels, p + 1.0)      # added to what they held
    assert np.array_equal(total, t)


def _max_pyramid_2x2(mag, binfo, noff, out):
    for b in range(binfo.shape[0]):
        off, h, w, kr = (int(v) for v in binfo[b, :4])
        if h == 0 or w == 0:
            continue
        ph, pw = h, w
        for k in range(1, kr + 1):
            hk, wk = (ph + 1) // 2, (pw + 1) // 2
            for y in range(hk):
                for x in range(wk):
                    m = 0
                    for yy in (2 * y, 2 * y + 1):
                        for xx in (2 * x, 2 * x + 1):
                            if yy < ph and xx < pw:
                                m = max(m, mag[off + yy * w + xx] if k == 1
                                        else out[noff[b, k - 1] + yy * pw + xx])
                    out[noff[b, k] + y * wk + x] = m
            ph, pw = hk, wk
    return out


@pytest.mark.parametrize("size", [(1, 1, 1), (5, 3, 1), (13, 22, 3), (31, 17, 1)])
def test_max_pyramid_is_the_2x2_maxima(size):
    h, w, ncomp = size
    plan = plan_for(h, w, ncomp, False, None, 0, None, ())
    lay = plan.lay
    rng = np.random.default_rng(h * w)
    mag = rng.integers(0, 1 << 20, max(lay.ncoef, 1)) * (rng.random(max(lay.ncoef, 1)) < 0.3)
    out = np.full(max(lay.nnodes, 1), -7, dtype=np.int64)     # a node never written stays
    want = _max_pyramid_2x2(mag, lay.binfo, lay.noff, out.copy())
    kernels.max_pyramid(mag, lay.binfo, lay.noff, lay.nw, out)
    assert np.array_equal(out, want)


@pytest.mark.parametrize("seed", range(4))
def test_squared_errors_are_those_of_the_pictures_made(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 30)), int(rng.integers(1, 30))
    comps = [rng.normal(0, 90, (h, w)) for _ in range(3)]
    m = rng.normal(0, 1, (3, 3))
    img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    out = np.empty((h, w, 3), dtype=np.uint8)
    kernels.to_rgb(*comps, m, 128.0, out)
    want = int(((out.astype(np.int64) - img) ** 2).sum())
    assert kernels.rgb_squared_error(*comps, m, 128.0, img) == want
    grey = np.empty((h, w), dtype=np.uint8)
    kernels.to_uint8(comps[0], 128.0, grey)
    assert kernels.grey_squared_error(comps[0], 128.0, img[..., 1].copy()) == int(
        ((grey.astype(np.int64) - img[..., 1]) ** 2).sum())


@pytest.mark.parametrize("colour", [False, True])
def test_the_encoders_views_give_the_squared_error_of_their_pictures(colour):
    # The view's picture and its squared error against a picture: one
    # order between streams with `codec._error` of the pictures made.
    img = samples.sample("colour-still-life" if colour else "grey-scene")
    for packets in ((), (1,), (1, 1, 2)):
        errors: list = []
        views: list = []
        if packets:
            codec._packet_stream(img, colour, packets, 900, errors, {}, views)
        else:
            codec._wavelet_stream(img, colour, None, 0, 900, errors=errors, shared={}, views=views)
        picture = views[-1]()
        assert views[-1](img) == int(((picture.astype(np.int64) - img) ** 2).sum())
        assert views[-1](img) / img.size == codec._error(picture, img)


def test_three_colours_is_numpys_count():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 5, 40):
        for palette in (1, 2, 3):
            colours = rng.integers(0, 256, (palette, 3), dtype=np.uint8)
            pixels = colours[rng.integers(0, palette, n)]
            want = np.unique(pixels, axis=0).shape[0] > 2
            assert twolevel.three_colours(pixels) == want, (n, palette)


def test_work_arrays_are_per_thread_and_streams_unchanged_by_them():
    img = samples.sample("seabed")
    alone = [codec.encode(img, b) for b in (700, 1500, 3000)]
    got: dict = {}
    arrays: dict = {}

    def run(i):
        got[i] = [codec.encode(img, b) for b in (700, 1500, 3000)]
        arrays[i] = codec._work("mag", 10, np.int64)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(got[i] == alone for i in range(3))
    assert len({id(a.base if a.base is not None else a) for a in arrays.values()}) == 3
    a = codec._work("test-array", (4, 5), np.float64)
    assert a.shape == (4, 5) and a.dtype == np.float64
    assert np.shares_memory(codec._work("test-array", 7, np.float64), a)     # reused
    assert codec._work("test-array", 50, np.float64).shape == (50,)           # grown
