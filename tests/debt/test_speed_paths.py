"""The encoder's faster paths give what the slower ones gave: the compiled
gathering pass with its top plane, the compiled coefficient error, and the
transform made once per picture for every stream tried (behaviour only; the
milliseconds are `rovlink bench debt`'s)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlink import debt
from rovlink.debt import bench, codec, kernels
from rovlink.debt.plan import plan_for


@pytest.fixture(scope="module")
def frames():
    # Three of the simulated camera's pictures (`rovlink bench camera`'s, on the
    # ROV side): cruising height, and the sand a hand's breadth below, whose
    # ripples make the encoder try its packets.
    from rovlink.rov.camerabench import camera_frames

    every = camera_frames()
    return {name: every[name] for name in ("cruise 2 m/colour", "sand 13 cm/grey", "sand 18 cm/colour")}


@pytest.mark.parametrize("seed", range(4))
def test_gather_finds_the_top_plane_numpy_finds(seed):
    rng = np.random.default_rng(seed)
    n = 5000
    flat = rng.normal(0, 10.0 ** rng.uniform(0, 4), n)
    flat[rng.random(n) < 0.3] = 0.0
    pos = rng.permutation(n)
    scale = rng.uniform(0.1, 40, n)
    cdef = np.where(rng.random(n) < 0.5, 0, rng.integers(0, 16)).astype(np.uint8)
    mag = np.zeros(n, dtype=np.int64)
    neg = np.zeros(n, dtype=np.uint8)
    top_by_def = np.zeros(16, dtype=np.int64)
    kernels.gather97(flat, pos, scale, mag, neg, cdef, top_by_def)
    v = flat[pos]
    assert np.array_equal(mag, np.floor(np.abs(v) * scale).astype(np.int64))
    assert np.array_equal(neg, (v < 0).astype(np.uint8))
    nz = mag > 0
    bits = np.frexp(mag[nz].astype(np.float64))[1] - 1
    assert kernels.top_plane(top_by_def) == max(int((bits + cdef[nz]).max()), 0)


def test_top_plane_of_nothing_is_zero():
    assert kernels.top_plane(np.zeros(16, dtype=np.int64)) == 0
    one = np.zeros(16, dtype=np.int64)
    one[3] = 1
    assert kernels.top_plane(one) == 3


@pytest.mark.parametrize("colour", [False, True])
def test_coefficient_error_matches_its_numpy_definition(colour):
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (48, 64, 3) if colour else (48, 64), dtype=np.uint8)
    plan = plan_for(48, 64, 3 if colour else 1, False, None, 0, None, ())
    _rotation, flat = codec._analysed(img, colour, plan, None)
    n = plan.lay.ncoef
    pk = rng.integers(-1, 12, n).astype(np.int8)
    step = np.left_shift(np.int64(1), np.maximum(pk, 0).astype(np.int64))
    rec = np.where(pk >= 0, step * rng.integers(1, 4, n), 0)
    true = np.abs(flat[plan.pos]) * plan.scale
    delta = np.where(rec == step, kernels.DELTA_SIG, kernels.DELTA_REF)
    shown = np.where(pk >= 0, rec + delta * step, 0.0)
    expected = float(np.sum(((true - shown) * plan.err_weight) ** 2))
    assert codec._coefficient_error(flat, plan, rec, pk) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("budget", [1000, 2000, 4000])
def test_streams_sharing_one_transform_are_the_streams_made_alone(frames, budget):
    # The dyadic and the packet streams of one picture share the analysis;
    # each must come out byte for byte as when made alone, errors and all.
    for name, img in frames.items():
        colour = img.ndim == 3
        limit = budget - 5
        packets = codec._packets_for(8.0 * limit / img.size)
        shared: dict = {}
        e_shared, e_alone = [], []
        dyadic = codec._wavelet_stream(img, colour, None, 0, limit, errors=e_shared, shared=shared)
        packet = codec._packet_stream(img, colour, packets, limit, e_shared, shared)
        assert dyadic == codec._wavelet_stream(img, colour, None, 0, limit, errors=e_alone), name
        assert packet == codec._packet_stream(img, colour, packets, limit, e_alone), name
        assert e_shared == e_alone, name
        assert shared, "the analysis was not shared"


def test_the_camera_pictures_near_the_sand_are_the_textured_ones(frames):
    # What `rovlink bench camera` claims: the sand close by makes the
    # encoder try its packets; cruising height does not.
    assert codec._textured(frames["sand 13 cm/grey"], False)
    assert not codec._textured(frames["cruise 2 m/colour"], True)


@pytest.mark.parametrize("roi", [None, (110, 80, 210, 160)])
def test_every_prefix_of_a_camera_picture_is_a_picture(frames, roi):
    for name, img in frames.items():
        data = debt.encode(img, 2000, roi=roi, shift=6 if roi else 0)
        assert len(data) <= 2000
        header = codec.unpack_header(data).size
        last = -1.0
        for n in range(header, len(data) + 1, 97):
            picture = debt.decode(data[:n])
            assert picture.shape == img.shape, (name, n)
            if roi is None:
                quality = bench.psnr(img, picture)
            else:
                x0, y0, x1, y1 = roi
                quality = bench.psnr(img[y0:y1, x0:x1], picture[y0:y1, x0:x1])
            assert quality >= last - 1e-9, (name, n)
            last = quality


def test_the_encoders_view_is_the_picture_the_decoder_shows(frames):
    # The encoder tells two close streams apart by the picture its own state
    # makes (`_picture97`), not by decoding: it is the decoder's picture but
    # for the last few decisions the decoder cannot be sure of at the cut.
    wall = bench.load_samples()["seabed"]
    for img in (frames["sand 18 cm/colour"], frames["sand 13 cm/grey"], wall):
        colour = img.ndim == 3
        for budget in (600, 2000):
            limit = budget - codec.header_size(False)
            for packets in ((), (1,), (1, 1, 2)):
                errors: list = []
                views: list = []
                if packets:
                    data = codec._packet_stream(img, colour, packets, limit, errors, {}, views)
                else:
                    data = codec._wavelet_stream(img, colour, None, 0, limit, errors=errors, shared={}, views=views)
                view = views[-1]()
                assert view.shape == img.shape and view.dtype == np.uint8
                assert abs(bench.psnr(img, view) - bench.psnr(img, debt.decode(data))) < 0.2, (budget, packets)


def test_packets_are_not_tried_where_the_dyadic_stream_is_nearly_exact(frames, monkeypatch):
    # Sand 13 cm below at 2000 B: the dyadic stream leaves ~0.03 squared error
    # a pixel (under PACKETS_ABOVE_MSE), so the packet stream is not coded.
    img = frames["sand 13 cm/grey"]
    assert codec._textured(img, False)
    expected = codec._wavelet_stream(img, False, None, 0, 2000 - codec.header_size(False))

    def refuse(*args, **kwargs):
        raise AssertionError("the packet stream was coded")

    monkeypatch.setattr(codec, "_packet_stream", refuse)
    # (The restoration filter, tried after the choice, codes the dyadic stream again.)
    monkeypatch.setattr(codec, "_restored", lambda img, colour, stream, *rest: stream)
    assert debt.encode(img, 2000) == expected


def test_packets_are_still_tried_and_chosen_where_they_win():
    # Brick (below the threshold's error everywhere on the bench) keeps its
    # packet streams, as the bench measured them: split along its edges,
    # upright ones most (issue 40).
    pytest.importorskip("skimage", reason="scikit-image (the `test` extra) ships the brick photograph")
    brick = bench.load_photographs(names=("brick",))["brick/crop"]
    for budget in (1000, 4000, 8000):
        assert bench.debt_mode(debt.encode(brick, budget)) == "along 3,1", budget
