"""`rovlink debt encode|decode` as a user meets it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from rovlink import debt
from rovlink.assets import ASSETS_DIR
from rovlink.cli import main

ASSETS = ASSETS_DIR / "images"


def test_encode_then_decode_a_prefix(tmp_path, capsys):
    out = tmp_path / "seabed.debt"
    assert main(["debt", "encode", str(ASSETS / "seabed.png"), str(out), "--bytes", "1500",
                 "--roi", "100,80,200,160", "--shift", "6"]) == 0
    data = out.read_bytes()
    assert len(data) == 1500
    assert debt.unpack_header(data).roi == (100, 80, 200, 160)
    png = tmp_path / "seabed.png"
    assert main(["debt", "decode", str(out), str(png), "--prefix", "600"]) == 0
    with Image.open(png) as im:
        assert im.size == (320, 240) and im.mode == "RGB"
    assert "1500 bytes" in capsys.readouterr().out


def test_grey_and_mono(tmp_path):
    out = tmp_path / "a.debt"
    assert main(["debt", "encode", str(ASSETS / "colour-still-life.png"), str(out),
                 "--bytes", "400", "--mono"]) == 0
    png = tmp_path / "a.png"
    assert main(["debt", "decode", str(out), str(png)]) == 0
    with Image.open(png) as im:
        assert im.mode == "L"
    grey = tmp_path / "g.png"
    Image.fromarray(np.full((7, 9), 50, dtype=np.uint8)).save(grey)
    assert main(["debt", "encode", str(grey), str(out), "--bytes", "100"]) == 0
    np.testing.assert_array_equal(debt.decode(out.read_bytes()), np.full((7, 9), 50))


@pytest.mark.parametrize("argv, message", [
    (["debt", "encode", "missing.png", "x.debt", "--bytes", "100"], "no such file"),
    (["debt", "decode", "missing.debt", "x.png"], "no such file"),
])
def test_missing_files_fail_with_one_line(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_undecodable_input_fails_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.debt"
    bad.write_bytes(b"not a debt stream")
    assert main(["debt", "decode", str(bad), str(tmp_path / "x.png")]) == 1
    assert "not a DEBT stream" in capsys.readouterr().err
    text = tmp_path / "text.png"
    text.write_text("hello")
    assert main(["debt", "encode", str(text), str(bad), "--bytes", "100"]) == 1


def test_budget_below_header_and_roi_outside(tmp_path, capsys):
    out = tmp_path / "x.debt"
    assert main(["debt", "encode", str(ASSETS / "seabed.png"), str(out), "--bytes", "3"]) == 1
    assert "header" in capsys.readouterr().err
    assert main(["debt", "encode", str(ASSETS / "seabed.png"), str(out), "--bytes", "300",
                 "--roi", "0,0,400,10"]) == 1
    assert "inside" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [["--roi", "1,2,3"], ["--shift", "16"], ["--bytes", "lots"]])
def test_bad_arguments_exit_2(tmp_path, extra):
    argv = ["debt", "encode", str(ASSETS / "seabed.png"), str(tmp_path / "x.debt")]
    if "--bytes" not in extra:
        argv += ["--bytes", "100"]
    with pytest.raises(SystemExit) as exc:
        main(argv + extra)
    assert exc.value.code == 2


def test_the_rovlink_command(tmp_path):
    out = tmp_path / "g.debt"
    run = subprocess.run([sys.executable, "-m", "rovlink", "debt", "encode",
                          str(ASSETS / "grey-scene.png"), str(out), "--bytes", "700"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert len(out.read_bytes()) == 700
