"""`rovlink rov`'s link key options, as a real process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from .conftest import free_udp_port

ROOT = Path(__file__).resolve().parents[2]


def rovlink(*args: str, timeout: float = 90) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "rovlink", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def link() -> str:
    return f"udp://127.0.0.1:{free_udp_port()}?peer=127.0.0.1:{free_udp_port()}"


def test_rov_without_a_key_or_insecure_exits_2_with_one_line():
    out = rovlink("rov", "--link", link())
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "rovlink keygen" in out.stderr and "--insecure" in out.stderr


def test_rov_with_a_key_runs_version_2_and_insecure_says_so(tmp_path):
    key = tmp_path / "link.key"
    assert rovlink("keygen", str(key)).returncode == 0
    secure = rovlink("rov", "--link", link(), "--key", str(key), "--budget", "0", "--duration", "1")
    assert secure.returncode == 0, secure.stderr
    assert "link version 2, every frame authenticated" in secure.stderr
    insecure = rovlink("rov", "--link", link(), "--insecure", "--budget", "0", "--duration", "1")
    assert insecure.returncode == 0, insecure.stderr
    assert "INSECURE: link version 1.1" in insecure.stderr


def test_rov_refuses_a_key_file_readable_by_others(tmp_path):
    key = tmp_path / "link.key"
    assert rovlink("keygen", str(key)).returncode == 0
    key.chmod(0o644)
    out = rovlink("rov", "--link", link(), "--key", str(key))
    assert out.returncode == 1 and out.stderr.count("\n") == 1, out.stderr


def test_rov_says_it_follows_and_names_the_missing_extra_when_opencv_is_not_installed(tmp_path):
    following = rovlink("rov", "--link", link(), "--insecure", "--budget", "0", "--duration", "1")
    assert following.returncode == 0, following.stderr
    assert "FOLLOW by the klt tracker at 10 frames/s" in following.stderr
    # A cv2 that cannot be imported, first on the path: as on an install without the extra.
    (tmp_path / "cv2").mkdir()
    (tmp_path / "cv2" / "__init__.py").write_text("raise ImportError('No module named cv2')\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path) + os.pathsep + str(ROOT))
    missing = subprocess.run([sys.executable, "-m", "rovlink", "rov", "--link", link(), "--insecure", "--budget", "0",
                              "--duration", "1"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=90)
    assert missing.returncode == 0, missing.stderr
    assert "FOLLOW refused: FOLLOW needs OpenCV's trackers: install rovlink with the 'tracking' extra" in missing.stderr
