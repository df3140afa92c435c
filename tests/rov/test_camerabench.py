"""`rovlink bench camera` (rov/camerabench.py): DEBT beside OpenJPEG on the ROV's
simulated camera's pictures, its rows, targets, table and JSON (behaviour
only; never its milliseconds)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from rovlink.debt.bench import DECODE_TARGET, ENCODE_TARGET
from rovlink.rov import camerabench


@pytest.fixture(scope="module")
def sand():
    frames = camerabench.camera_frames()
    return {"sand 13 cm/grey": frames["sand 13 cm/grey"]}


def test_the_camera_pictures_are_every_pose_in_colour_and_grey():
    frames = camerabench.camera_frames()
    assert set(frames) == {f"{pose}/{kind}" for pose in camerabench.CAMERA_POSES for kind in ("colour", "grey")}
    for name, img in frames.items():
        assert img.shape == ((240, 320, 3) if name.endswith("/colour") else (240, 320)), name


def test_rows_report_ratios_and_targets(sand):
    rows = camerabench.camera_rows(1, budgets=(1000,), frames=sand)
    assert len(rows) == 2 and {bool(r["roi"]) for r in rows} == {False, True}
    for r in rows:
        for key in ("debt_encode_ms", "debt_decode_ms", "openjpeg_encode_ms", "openjpeg_decode_ms"):
            assert r[key] > 0
        assert r["encode_ratio"] == pytest.approx(r["debt_encode_ms"] / r["openjpeg_encode_ms"])
        assert r["decode_ratio"] == pytest.approx(r["debt_decode_ms"] / r["openjpeg_decode_ms"])
        assert r["debt_psnr"] > 30 and r["mode"]
    targets = camerabench.camera_targets(rows)
    assert targets["camera_encode_target_met"] == (max(r["encode_ratio"] for r in rows) <= ENCODE_TARGET)
    assert targets["camera_decode_target_met"] == (max(r["decode_ratio"] for r in rows) <= DECODE_TARGET)
    text = camerabench.render(dict(camera=rows, targets=targets))
    assert "simulated camera" in text and "camera target" in text
    assert ("MET" in text) and ("MISSED" in text or targets["camera_encode_target_met"])


def test_debt_is_timed_at_openjpegs_bytes_where_openjpeg_stops_short(sand):
    # Sand 13 cm below, grey, at 4000 B: OpenJPEG's whole codestream is
    # smaller than the budget, so DEBT is timed at the bytes OpenJPEG wrote
    # and its time at the full budget is kept beside.
    rows = camerabench.camera_rows(1, budgets=(4000,), frames=sand)
    for r in rows:
        assert r["openjpeg_short"] and r["openjpeg_bytes"] < 4000
        assert r["debt_bytes_timed"] == r["openjpeg_bytes"]
        assert r["debt_encode_ms_at_budget"] > 0 and r["encode_ratio_at_budget"] > 0
        if not r["roi"]:    # at equal bytes DEBT's picture is still the better one
            assert r["debt_psnr_timed"] > r["openjpeg_psnr"]
    targets = camerabench.camera_targets(rows)
    assert "camera_encode_ratio_worst_at_budget" in targets


def bench(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "rovlink", "bench", "camera", *args],
                          capture_output=True, text=True, timeout=timeout)


def test_the_command_prints_its_table():
    out = bench("--only", "sand 18 cm/colour", "--budgets", "1000", "--runs", "1")
    assert out.returncode == 0, out.stderr
    assert "bench camera: 1/1 measured (sand 18 cm/colour)" in out.stderr
    for heading in ("The simulated camera's pictures", "enc x", "dec x", "camera target", "Targets"):
        assert heading in out.stdout, heading
    rows = [line for line in out.stdout.splitlines() if line.startswith("sand 18 cm/colour")]
    assert len(rows) == 2 and sum(" roi " in line for line in rows) == 1    # without and with the ROI
    assert "MET" in out.stdout


def test_the_command_prints_json():
    out = bench("--only", "cruise 2 m/grey", "--budgets", "1000", "--runs", "1", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert [(r["image"], r["budget"], bool(r["roi"])) for r in result["camera"]] == [
        ("cruise 2 m/grey", 1000, False), ("cruise 2 m/grey", 1000, True)]
    for key in ("camera_encode_ratio_worst", "camera_decode_ratio_worst", "camera_encode_within_target",
                "camera_encode_target_met", "camera_decode_target_met", "camera_encode_ratio_worst_at_budget"):
        assert key in result["targets"], key


@pytest.mark.parametrize("args, words", [(["--budgets", "x"], "must be integers"),
                                         (["--runs", "0"], "at least 1"),
                                         (["--only", "nowhere"], "no camera picture")])
def test_the_command_refuses_bad_arguments_in_one_line(args, words):
    out = bench(*args)
    assert out.returncode in (1, 2)
    assert len(out.stderr.strip().splitlines()) == 1 and words in out.stderr, out.stderr


def test_camera_quality_sets_debt_beside_webp_and_avif_in_psnr_and_msssim(sand):
    from rovlink.debt import bench

    quality = camerabench.quality_rows(sand, budgets=(1000,))
    assert len(quality) == 1
    row = quality[0]
    for codec in ("debt", "jpeg2000", "webp", "avif"):
        assert 0 < row[codec]["msssim"] <= 1 and row[codec]["psnr"] > 20, codec
    margins = bench.margins(quality)
    assert margins["avif"]["worst_margin_msssim"] == pytest.approx(row["debt"]["msssim"] - row["avif"]["msssim"])
    text = bench.render_margins(dict(margins=margins, losses=bench.losses(quality, sand)))
    assert "DEBT minus each codec" in text and "msssim" in text
