"""DEBT's restoration filter (debt/restore.py): the kernel against a
step-by-step reference, its bytes, the header's FILTER bit, and what the
encoder does with it."""

from __future__ import annotations

import numpy as np
import pytest

from rovlink import debt
from rovlink.debt import codec, restore, samples
from rovlink.debt.header import Header, pack_header, unpack_header


def psnr(a, b) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0 ** 2 / max(mse, 1e-12))


def _reference(x: np.ndarray, f: restore.Filter) -> np.ndarray:
    """The filter pixel by pixel, as restore.py's comment says it: neighbours
    clamped to the picture, the activity the sum of absolute Laplacians over
    the 3x3 (themselves of clamped pixels), the class by its edges."""
    h, w = x.shape
    taps, e1, e2 = f.kernel_args()

    def at(y, i):
        return float(x[min(max(y, 0), h - 1), min(max(i, 0), w - 1)])

    def lap(y, i):
        return abs(4 * at(y, i) - at(y, i - 1) - at(y, i + 1) - at(y - 1, i) - at(y + 1, i))

    out = x.astype(np.float64).copy()
    for y in range(h):
        for i in range(w):
            c = at(y, i)
            act = sum(lap(y + dy, i + dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1))
            k = 0 if e1 >= 1e29 else int(act >= e1) + int(act >= e2)
            out[y, i] += sum(float(taps[k, n]) * (at(y + dy, i + dx) + at(y - dy, i - dx) - 2 * c)
                             for n, (dy, dx) in enumerate(restore.OFFSETS))
    return out


@pytest.mark.parametrize("shape", [(1, 1), (2, 9), (5, 4), (17, 23)])
@pytest.mark.parametrize("grouping", range(len(restore.GROUPINGS)))
def test_the_kernel_is_the_filter_pixel_by_pixel(shape, grouping):
    rng = np.random.default_rng(grouping * 100 + shape[0])
    x = np.cumsum(rng.normal(size=shape) * 6, axis=1) + rng.normal(size=shape)
    n = restore.classes_of(grouping)
    taps = [rng.integers(-60, 60, restore.NTAPS).astype(np.int8) for _ in range(n)]
    if n > 1:
        taps[0] = None                      # a class without taps is left alone
    f = restore.Filter(grouping, taps)
    got = restore.apply([x.copy()], [f])[0]
    # float32 arithmetic inside the kernel
    assert np.abs(got - _reference(x, f)).max() < 1e-3


def test_the_filter_keeps_a_flat_picture_and_its_bytes_round_trip():
    f = restore.Filter(2, [np.arange(6, dtype=np.int8), None, -np.arange(6, dtype=np.int8)])
    flat = np.full((9, 11), 37.5)
    assert (restore.apply([flat.copy()], [f])[0] == flat).all()
    data = b"\x00\x01" + restore.section([f, restore.Filter(0, [None])]) + b"rest"
    assert data[2] == 2 << 6 | 0b101 and data[2 + 1 + 12] == 0
    filters, end = restore.parse(data, 2, 2)
    assert data[end:] == b"rest"
    assert filters[0].grouping == 2 and filters[0].taps[1] is None
    assert (filters[0].taps[2] == -np.arange(6)).all() and not filters[1].active
    # A prefix that does not hold the whole filter: none yet.
    for n in range(2, end):
        assert restore.parse(data[:n], 2, 2)[0] is None
    with pytest.raises(ValueError, match="names a class it has not"):
        restore.parse(bytes([0 << 6 | 0b10]), 0, 1)


def test_the_fit_undoes_a_blur():
    rng = np.random.default_rng(3)
    orig = np.cumsum(rng.normal(size=(60, 80)) * 8, axis=1)
    blurred = orig.copy()
    blurred[:, 1:-1] = 0.25 * orig[:, :-2] + 0.5 * orig[:, 1:-1] + 0.25 * orig[:, 2:]
    filters, net = restore.fit([blurred.copy()], [orig], price=0.0)
    assert net > 0 and filters[0].active
    out = restore.apply([blurred.copy()], filters)[0]
    inner = np.s_[4:-4, 4:-4]
    assert np.mean((out - orig)[inner] ** 2) < 0.5 * np.mean((blurred - orig)[inner] ** 2)
    # At a price above what it gives back, no taps.
    filters, net = restore.fit([blurred.copy()], [orig], price=1e12)
    assert not filters[0].active


def test_the_header_says_whether_a_filter_follows():
    for filtered in (False, True):
        h = Header(320, 240, False, False, 20, filtered=filtered)
        assert unpack_header(pack_header(h)) == h
        packets = Header(320, 240, True, True, codec.PACKET_TOP, filtered=filtered)
        assert unpack_header(pack_header(packets)) == packets
    # No FILTER bit with a region of interest (its check bits are as before).
    roi = Header(320, 240, False, False, 20, (1, 2, 30, 40), 4)
    assert unpack_header(pack_header(roi)) == roi and pack_header(roi)[0] >> 4 == 0b1000
    # A lossless stream has no filter.
    with pytest.raises(ValueError, match="restoration filter"):
        unpack_header(pack_header(Header(320, 240, False, True, 10, filtered=True)))


@pytest.fixture(scope="module")
def grey():
    return samples.sample("grey-scene")


def test_a_filtered_stream_beats_the_unfiltered_one_and_its_prefixes_decode(grey, monkeypatch):
    data = debt.encode(grey, 2000)
    assert len(data) == 2000 and unpack_header(data).filtered
    end = codec.filter_bytes_end(data)
    assert end > codec.split_bytes_end(data)
    filtered = psnr(grey, debt.decode(data))
    # The filter's bytes shown without it: flat pictures until the coefficients come.
    for n in range(unpack_header(data).size, end + 1):
        assert (debt.decode(data[:n]) == 128).all()
    last = -1.0
    for n in range(end, len(data) + 1, 37):
        quality = psnr(grey, debt.decode(data[:n]))
        assert quality >= last - 0.05, n
        last = max(last, quality)
    monkeypatch.setattr(codec, "_restored", lambda img, colour, stream, *rest: stream)
    plain = debt.encode(grey, 2000)
    assert not unpack_header(plain).filtered
    assert filtered > psnr(grey, debt.decode(plain)) + 0.05


def test_colour_and_roi_streams(grey):
    colour = samples.sample("colour-still-life")
    data = debt.encode(colour, 3000)
    assert unpack_header(data).filtered
    filters, _end = restore.parse(data, codec.split_bytes_end(data), 3)
    assert len(filters) == 3
    assert debt.decode(data).shape == colour.shape
    roi = debt.encode(grey, 2000, roi=(100, 80, 200, 160), shift=4)
    assert not unpack_header(roi).filtered and unpack_header(roi).roi is not None


def test_the_encoder_keeps_the_unfiltered_stream_when_the_filter_does_not_pay(grey, monkeypatch):
    # The fit promising much, the filtered picture measured worse: the plain stream.
    def promise(comps, origs, price):
        return [restore.Filter(0, [np.full(restore.NTAPS, 127, dtype=np.int8)]) for _ in comps], 1e12

    monkeypatch.setattr(restore, "fit", promise)
    data = debt.encode(grey, 2000)
    assert not unpack_header(data).filtered


@pytest.mark.parametrize("grouping", range(len(restore.GROUPINGS)))
def test_the_rows_pick_the_class_as_the_three_sums_did_bit_for_bit(grouping):
    # The kernel once made every class's sum and kept one; it now picks the
    # class's taps first and makes one sum: the same float32 operations, so
    # the same picture to the last bit (streams and pictures must not move).
    rng = np.random.default_rng(grouping)
    h, w = 31, 45
    x = np.cumsum(rng.normal(size=(h, w)) * 9, axis=1) + rng.normal(size=(h, w)) * 3
    taps = [rng.integers(-90, 90, restore.NTAPS).astype(np.int8) for _ in range(restore.classes_of(grouping))]
    f = restore.Filter(grouping, taps)
    t, e1, e2 = f.kernel_args()
    pad, lap, hsum = (np.zeros_like(a) for a in restore._activity_work((h, w)))
    restore.activity(np.ascontiguousarray(x), pad, lap, hsum)
    m = restore.MARGIN
    want = x.copy()
    for y in range(h):
        rows = [pad[y + m + dy] for dy in range(-3, 4)]
        r0 = rows[3]
        cc = r0[m:m + w] + r0[m:m + w]
        d = [r0[m + k:m + k + w] + r0[m - k:m - k + w] - cc for k in (1, 2, 3)]
        d += [rows[3 + k][m:m + w] + rows[3 - k][m:m + w] - cc for k in (1, 2, 3)]
        sums = []
        for c in range(3):
            v = t[c, 0] * d[0]
            for k in range(1, restore.NTAPS):
                v = v + t[c, k] * d[k]
            sums.append(v)
        if e1 >= 1e29:
            v = sums[0]
        else:
            act = hsum[y] + hsum[y + 1] + hsum[y + 2]
            v = np.where(act >= e1, sums[1], sums[0])
            v = np.where(act >= e2, sums[2], v)
        want[y] += v.astype(np.float64)
    got = restore.apply([x.copy()], [f])[0]
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
