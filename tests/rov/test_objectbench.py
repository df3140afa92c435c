"""`rovlink bench objects`: its scoring against the truth, and its JSON's sections."""

from __future__ import annotations

import pytest

pytest.importorskip("cv2")

from rovlink.link.scene import SeenObject  # noqa: E402
from rovlink.rov.objectbench import Run, measure, score  # noqa: E402
from rovlink.rov.seabed import SeabedObject  # noqa: E402


def test_the_score_matches_the_operators_objects_to_the_truth_in_view():
    truth = [SeabedObject("pipe", 0.0, 0.0, 4.0, 0.3, 0.0), SeabedObject("amphora", 5.0, 5.0, 0.9, 0.3, 0.5),
             SeabedObject("timber", -5.0, 5.0, 2.0, 0.3, 1.0)]
    run = Run("radio", 1, in_view_s={0: 3.0, 1: 0.5, 2: 1.0}, truth=truth)  # the amphora: half a second only
    run.told = {
        1: SeenObject(1, "pipe", 0.9, 0.2, 0.0, 4.4, 0.5, 10.0, True),  # 0.2 m off, 10 % long, 10 deg
        2: SeenObject(2, "timber", 0.9, 5.1, 5.0, 0.9, 0.3, 0.0, True),  # the amphora, wrongly classed
        3: SeenObject(3, "unknown", 0.5, 9.0, -9.0, 1.0, 0.3, 0.0, True),  # nothing there
    }
    s = score(run)
    assert (s["to_find"], s["found"], s["told"], s["true_told"]) == (2, 1, 3, 2)
    (row,) = s["rows"]
    assert abs(row["centre_err_m"] - 0.2) < 1e-9 and abs(row["length_err_pct"] - 10.0) < 1e-9
    assert abs(row["heading_err_deg"] - 10.0) < 1e-9 and row["class_ok"]


def test_the_bench_has_a_radio_and_an_acoustic_section_with_the_issues_keys():
    result = measure(seeds=(101,), seconds=12.0)
    for profile in ("radio", "acoustic"):
        section = result[profile]
        for key in ("recall", "precision", "class_accuracy", "centre_err_p95_m", "length_err_p90_pct",
                    "heading_err_p90_deg", "bytes_per_object_max", "first_object_s", "first_picture_s", "seeds"):
            assert key in section
        assert section["seeds"] == [101]
    assert result["radio"]["bytes_per_object_max"] in (None, 9)
