"""`rovlink bench roi` (rov/roibench.py): a short run as a real process, its JSON and
plot, and the arithmetic of its figures (behaviour only; never its milliseconds)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rovlink.rov import roibench
from rovlink.rov.roibench import Picture, Run

ROOT = Path(__file__).resolve().parents[2]


def test_a_short_run_prints_its_figures_as_json_and_writes_its_plot(tmp_path):
    plot = tmp_path / "roi.png"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-m", "rovlink", "bench", "roi", "--seconds", "70", "--no-compare", "--json",
                          "--out", str(plot)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=280)
    assert out.returncode == 0, out.stderr
    assert "bench roi: done" in out.stderr
    result = json.loads(out.stdout)
    for key in ("iou_half_fraction", "gain_over_fixed_db", "lost_said_after_pictures", "tracker_ms"):
        assert key in result and key in result["targets"]
    pictures = result["per_picture"]
    assert len(pictures) >= 5 and result["figures"]["pictures"] == len(pictures)
    in_view = [p for p in pictures if p["in_view"]]
    assert in_view and all(p["iou"] is not None and p["psnr_fixed"] is not None for p in in_view)
    assert all(p["state"] in ("HOLDS", "LOST", "DROPPED") for p in pictures)
    # The run ends with the vehicle turned away: the last pictures say the track is lost.
    assert not pictures[-1]["in_view"] and pictures[-1]["state"] in ("LOST", "DROPPED")
    assert result["iou_half_fraction"] == pytest.approx(sum(p["iou"] >= 0.5 for p in in_view) / len(in_view))
    assert result["gain_over_fixed_db"] == pytest.approx(
        sum(p["psnr_follow"] - p["psnr_fixed"] for p in in_view) / len(in_view))
    assert result["gain_over_fixed_db"] > 0  # the followed ROI's bytes went to the object
    assert result["tracker_ms"] > 0 and result["plot"] == str(plot)
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _picture(in_view: bool, state: str, iou=None, follow=None, fixed=None) -> Picture:
    return Picture(img=0, captured_at=0.0, received_at=0.0, debt_bytes=900, state=state, lost_for_s=0.0,
                   in_view=in_view, visible=1.0 if in_view else 0.0, iou=iou, psnr_follow=follow, psnr_fixed=fixed,
                   psnr_none=follow, centre_x=100.0 if in_view else None)


@pytest.mark.parametrize("states,said_after", [
    (["LOST", "LOST"], 0),  # said in the first picture without the object
    (["HOLDS", "LOST"], 1),
    (["HOLDS", "HOLDS"], None),  # never said
])
def test_lost_said_after_counts_pictures_from_the_first_without_the_object(states, said_after):
    run = Run(pictures=[_picture(True, "HOLDS", 0.8, 40.0, 30.0), *(_picture(False, s) for s in states)])
    fig = roibench.figures(run)
    assert fig["lost_said_after_pictures"] == said_after
    assert roibench.targets(fig)["lost_said_after_pictures"]["met"] == (said_after is not None and said_after <= 1)


def test_figures_count_only_the_pictures_with_the_object_in_view_and_say_why_a_target_is_missed():
    run = Run(pictures=[_picture(True, "HOLDS", 0.8, 40.0, 38.0), _picture(True, "HOLDS", 0.3, 35.0, 35.5),
                        _picture(False, "LOST")], tracker_ms=2.0)
    fig = roibench.figures(run)
    assert fig["iou_half_fraction"] == 0.5 and fig["gain_over_fixed_db"] == pytest.approx(0.75)
    why = roibench.why_missed(fig, run)
    assert any(line.startswith("IoU: 1 of 2 pictures") for line in why)
    assert any("gain:" in line and "0.75 dB" in line for line in why)
    assert any("pictures: 3 in the run" in line for line in why)
    assert fig["debt_bytes_mean"] == 900 and fig["picture_interval_s"] == 0.0
