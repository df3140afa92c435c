"""The seabed generator's seeds, its truth JSON beside the PNG, and --seabed on the ROV side's commands."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rovlink.cli import main as rovlink_main
from rovlink.rov.camera import SimulatedCamera
from rovlink.rov.seabed import CLASSES, SEED, Seabed, SeabedError, generate, save


def test_another_seed_lays_isolated_objects_of_every_class_and_repeats_itself():
    a, b = generate(size=256, seed=5), generate(size=256, seed=5)
    assert a.objects == b.objects and np.array_equal(a.texture, b.texture)
    assert generate(size=256, seed=6).objects != a.objects
    assert {o.kind for o in a.objects} == set(CLASSES) - {"unknown"}
    for i, o in enumerate(a.objects):
        assert abs(o.x_m) + o.length_m / 2 < a.x_max_m and abs(o.y_m) + o.length_m / 2 < a.y_max_m
        for p in a.objects[i + 1:]:
            assert math.hypot(o.x_m - p.x_m, o.y_m - p.y_m) >= (o.length_m + p.length_m) / 2 + 0.99


def test_the_default_seed_keeps_the_committed_layout():
    committed = Seabed.load()
    assert generate(seed=SEED).objects == committed.objects


def test_the_truth_json_goes_beside_the_png_and_reads_back(tmp_path):
    seabed = generate(size=256, seed=3)
    meta_path = save(seabed, tmp_path / "scene.png")
    assert meta_path == tmp_path / "scene.json"
    meta = json.loads(meta_path.read_text())
    assert meta["texture"] == "scene.png"
    first = meta["objects"][0]
    assert first["class"] in CLASSES and {"x_m", "y_m", "length_m", "width_m", "heading_rad"} <= set(first)
    back = Seabed.from_png(tmp_path / "scene.png")
    assert back.objects == seabed.objects and np.array_equal(back.texture, seabed.texture)
    # The simulated camera sees the user's seabed, not the committed one.
    assert SimulatedCamera(seabed=back).seabed is back


@pytest.mark.parametrize("spoil, says", [
    (lambda png, js: png.write_bytes(b"not a png"), "not a readable image"),
    (lambda png, js: js.unlink(), "is missing"),
    (lambda png, js: js.write_text("{ nope"), "not valid JSON"),
    (lambda png, js: js.write_text(json.dumps({"depth_m": 8})), "x_min_m is missing"),
    (lambda png, js: _edit(js, lambda m: m["objects"][0].update({"class": "boat"})), "class 'boat'"),
    (lambda png, js: _edit(js, lambda m: m["objects"][1].update({"length_m": "long"})), "finite number"),
    (lambda png, js: _edit(js, lambda m: m.update({"depth_m": -1})), "depth_m must be above 0"),
])
def test_a_malformed_seabed_is_one_line(tmp_path, spoil, says):
    png = tmp_path / "scene.png"
    save(generate(size=64, seed=3), png)
    spoil(png, tmp_path / "scene.json")
    with pytest.raises(SeabedError, match=says):
        Seabed.from_png(png)


def _edit(path, change) -> None:
    meta = json.loads(path.read_text())
    change(meta)
    path.write_text(json.dumps(meta))


@pytest.mark.parametrize("command", [["sim"], ["rov", "--link", "udp://127.0.0.1:9?peer=127.0.0.1:9", "--insecure"],
                                     ["demo"]])
def test_rov_sim_and_demo_say_a_malformed_seabed_in_one_line_with_status_2(tmp_path, capsys, command):
    if command == ["demo"]:
        pytest.importorskip("fastapi")  # the console extra
    png = tmp_path / "scene.png"
    save(generate(size=64, seed=3), png)
    (tmp_path / "scene.json").write_text("[1, 2")
    assert rovlink_main([*command, "--seabed", str(png)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seabed" in err[0] and "not valid JSON" in err[0] and "Traceback" not in err[0]


def test_rovlink_seabed_writes_a_layout_from_a_seed(tmp_path, capsys):
    assert rovlink_main(["seabed", "--seed", "12", "--out", str(tmp_path / "s12.png")]) == 0
    seabed = Seabed.from_png(tmp_path / "s12.png")
    assert seabed.objects == generate(seed=12).objects
