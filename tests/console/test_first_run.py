"""A fresh install's first `rovlink demo`: DEBT's coder is compiled by numba on
first use, before the link starts, with its progress said; the next start finds
it cached.  A process of its own with an empty numba cache, as on a fresh
install; no browser (it runs beside the browser tests, not in their turn)."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = [pytest.mark.slow]


def test_the_demo_compiles_the_codec_once_saying_so_before_the_link_starts(tmp_path):
    """A fresh install compiles DEBT on first use: the demo does it before the link
    starts (progress said), and a second start finds it cached and says nothing."""
    import os

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}  # as on a fresh install
    code = "from rovlink.console.commands.demo import compile_codec; compile_codec()"
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    lines = first.stderr.strip().splitlines()
    assert lines[0].startswith("compiling the image codec for this machine (first run only"), lines
    assert lines[-1].startswith("image codec ready in "), lines
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and again.stderr == "", again.stderr
