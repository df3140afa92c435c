"""DEBT's compiled kernels against the numpy reference (`debt.transform`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovlink import debt
from rovlink.debt import kernels
from rovlink.debt.transform import band_shapes, forward, inverse, levels_for, mallat_origins

NO_ROI = np.zeros(4, dtype=np.int64)


@settings(max_examples=80, deadline=None)
@given(h=st.integers(1, 70), w=st.integers(1, 70), levels=st.integers(0, 6), seed=st.integers(0, 2 ** 16))
def test_forward97_kernel_matches_numpy_reference(h, w, levels, seed):
    img = np.random.default_rng(seed).normal(size=(h, w)) * 60
    bands = forward(img, levels, "97")
    a = img.copy()
    kernels.forward97(a, levels, NO_ROI)
    for (y0, x0), band, shape in zip(mallat_origins(h, w, levels), bands, band_shapes(h, w, levels)):
        assert band.shape == shape
        np.testing.assert_allclose(a[y0:y0 + shape[0], x0:x0 + shape[1]], band, atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(h=st.integers(1, 70), w=st.integers(1, 70), levels=st.integers(0, 6), seed=st.integers(0, 2 ** 16))
def test_inverse97_kernel_matches_numpy_reference(h, w, levels, seed):
    rng = np.random.default_rng(seed)
    shapes = band_shapes(h, w, levels)
    bands = [rng.normal(size=s) * 30 for s in shapes]
    a = np.zeros((h, w))
    for (y0, x0), band in zip(mallat_origins(h, w, levels), bands):
        a[y0:y0 + band.shape[0], x0:x0 + band.shape[1]] = band
    kernels.inverse97(a, levels, NO_ROI)
    np.testing.assert_allclose(a, inverse(bands, levels, "97"), atol=1e-9)


@pytest.mark.parametrize("shape", [(240, 320), (17, 1), (1, 1), (63, 65)])
def test_round_trip_at_the_codec_depth(shape):
    h, w = shape
    img = np.random.default_rng(h * w).normal(size=shape) * 60
    a = img.copy()
    kernels.forward97(a, levels_for(h, w), NO_ROI)
    kernels.inverse97(a, levels_for(h, w), NO_ROI)
    np.testing.assert_allclose(a, img, atol=1e-9)


def test_warm_up_compiles_and_can_run_twice():
    debt.warm_up()
    debt.warm_up()


def test_warm_up_in_background_is_a_daemon_thread():
    # The node and the console start it and may exit before it ends.
    thread = debt.warm_up_in_background()
    assert thread.daemon
    thread.join(timeout=300)
    assert not thread.is_alive()


def test_a_process_exits_while_the_warm_up_runs(tmp_path):
    import subprocess
    import sys
    import time

    env = dict(__import__("os").environ, NUMBA_CACHE_DIR=str(tmp_path))  # a cold compile
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-c",
                          "from rovlink import debt; t = debt.warm_up_in_background(); "
                          "print(t.is_alive())"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "True"
    assert time.monotonic() - t0 < 60


def test_compiled_cache_goes_when_any_debt_source_changes(tmp_path):
    # numba keys a cached kernel by its own file; the traversal inlines the
    # range coder of another file, so DEBT drops its whole cache when any of
    # its sources differs from the stamp, and keeps it otherwise.
    from rovlink.debt import jit

    (tmp_path / "debt-sources.sha256").write_text("an older version")
    (tmp_path / "coder._traverse-260.py311.nbi").write_bytes(b"stale")
    (tmp_path / "rangecoder._code-60.py311.1.nbc").write_bytes(b"stale")
    (tmp_path / "someone_else.f-1.py311.nbi").write_bytes(b"not ours")
    jit._drop_stale_cache(str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["debt-sources.sha256", "someone_else.f-1.py311.nbi"]
    (tmp_path / "coder._traverse-260.py311.nbi").write_bytes(b"fresh")
    jit._drop_stale_cache(str(tmp_path))
    assert (tmp_path / "coder._traverse-260.py311.nbi").exists()


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 40), w=st.integers(1, 40), seed=st.integers(0, 2 ** 16))
def test_colour_moments_match_numpy(h, w, seed):
    img = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    detail, pixels, total = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3)
    kernels.colour_moments(img, detail, pixels, total)
    x = img.astype(np.float64)
    d = np.concatenate(((x[1:] - x[:-1]).reshape(-1, 3), (x[:, 1:] - x[:, :-1]).reshape(-1, 3)))
    p = x.reshape(-1, 3)
    np.testing.assert_allclose(detail, d.T @ d, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(pixels, p.T @ p, rtol=1e-12)
    np.testing.assert_allclose(total, p.sum(axis=0), rtol=1e-12)


@settings(max_examples=30, deadline=None)
@given(h=st.integers(1, 30), w=st.integers(1, 30), seed=st.integers(0, 2 ** 16))
def test_to_rgb_matches_numpy(h, w, seed):
    rng = np.random.default_rng(seed)
    comps = [rng.normal(0, 90, (h, w)) for _ in range(3)]
    m = rng.normal(0, 1, (3, 3))
    out = np.empty((h, w, 3), dtype=np.uint8)
    kernels.to_rgb(*comps, m, 128.0, out)
    want = np.clip(np.rint(np.stack(comps, axis=-1) @ m + 128.0), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(out, want)
