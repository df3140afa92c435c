"""A fresh install's first `rovlink demo`: DEBT's coder is compiled by numba on
first use, before the link starts, with its progress said; the next start finds
it cached.  A process of its own with a numba cache of its own, not yet marked as
warmed up, as on a fresh install; no browser (it runs beside the browser tests,
not in their turn)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow]


def unmarked_cache(tmp_path: Path) -> Path:
    """A numba cache of its own for a child process, holding the kernels already compiled
    into the package's own cache (.ci/run's warm-up, on a clean clone, compiles them all
    from nothing) but not the mark of a warm-up that ran to its end: the demo cannot tell
    it from a fresh install's, and says so. Compiling all of them again here took 215 s
    of a core in a suite run, starving the tests beside it. (numba's layout of a cache
    named by NUMBA_CACHE_DIR: a folder per source folder. Laid otherwise in another
    numba, the kernels are compiled anew: slower, the same test.)"""
    from rovlink.debt import jit

    folder = os.path.dirname(os.path.abspath(jit.__file__))
    cache = tmp_path / "numba-cache"
    kernels = cache / f"{os.path.basename(folder)}_{hashlib.sha1(folder.encode()).hexdigest()}"
    kernels.mkdir(parents=True)
    own = Path(folder) / "__pycache__"
    for path in own.glob("*.nb[ic]"):
        shutil.copy2(path, kernels / path.name)
    return cache


def test_the_demo_compiles_the_codec_once_saying_so_before_the_link_starts(tmp_path):
    """A fresh install compiles DEBT on first use: the demo does it before the link
    starts (progress said), and a second start finds it cached and says nothing."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(unmarked_cache(tmp_path))}
    code = "from rovlink.console.commands.demo import compile_codec; compile_codec()"
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    lines = first.stderr.strip().splitlines()
    assert lines[0].startswith("compiling the image codec for this machine (first run only"), lines
    assert lines[-1].startswith("image codec ready in "), lines
    again = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and again.stderr == "", again.stderr
