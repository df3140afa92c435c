"""`rovlink bench debt` as a user runs it (a real process), on the project's
own samples (scikit-image's photographs are the `bench` extra's; CI has the
`test` extra only)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

MODES = {"wavelet", "lossless", "two-level", "mask+residual", "packets 1", "packets 1,2", "packets 1,1,2"}


def bench(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "rovlink", "bench", "debt", *args],
                          capture_output=True, text=True, timeout=timeout)


def test_bench_debt_prints_its_figures_as_json():
    out = bench("--images", "samples", "--budgets", "1000,2000", "--runs", "1", "--no-curve", "--json")
    assert out.returncode == 0, out.stderr
    # Progress on stderr, a line per image; stdout holds the JSON alone.
    assert "bench debt: 6/6 measured (seabed)" in out.stderr and "bench debt: 2/6" in out.stderr
    result = json.loads(out.stdout)
    rows = result["quality"]
    assert {r["image"] for r in rows} == {"grey-scene", "colour-still-life", "seabed"}
    assert {r["budget"] for r in rows} == {1000, 2000}
    for r in rows:
        assert r["debt"]["mode"] in MODES and r["debt"]["bytes"] <= r["budget"]
        assert 15 < r["debt"]["psnr"] < 60 and 0 < r["debt"]["ssim"] <= 1
        assert r["jpeg2000"]["bytes"] <= r["budget"]
    targets = result["targets"]
    for key in ("psnr_vs_jpeg2000_min_margin_db", "vs_webp_lowest_mean_db", "vs_avif_lowest_mean_db",
                "roi_shift6_1000B_gain_over_jpeg2000_min_db", "encode_ratio_vs_openjpeg"):
        assert key in targets
    assert {r["image"] for r in result["roi"]} == {"grey-scene", "colour-still-life", "seabed"}


def test_bench_debt_prints_a_table():
    out = bench("--images", "samples", "--budgets", "1000", "--runs", "1", "--no-curve")
    assert out.returncode == 0, out.stderr
    for heading in ("Whole-image quality", "mode", "ROI PSNR", "Milliseconds", "Targets"):
        assert heading in out.stdout, heading


@pytest.mark.parametrize("args, words", [(["--budgets", "x"], "must be integers"),
                                         (["--budgets", "1000,8"], "at least 16"),
                                         (["--runs", "0"], "at least 1")])
def test_bench_debt_refuses_bad_arguments_in_one_line(args, words):
    out = bench(*args)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and words in out.stderr, out.stderr
