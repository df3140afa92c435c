"""`bench console`'s busy-machine row: its children are started on the cores and at
the nice they are meant to run at (the outside run's set-up raised the channel)."""

from __future__ import annotations

import os
import subprocess
import sys

from rovlink.console.bench.loaded import _cores, _nice, _pinned


def test_a_child_runs_pinned_at_the_nice_it_was_given():
    vehicle_core, _ = _cores()
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"],
                         preexec_fn=_pinned(vehicle_core, 3))
    try:
        assert os.sched_getaffinity(p.pid) == vehicle_core
        assert _nice(p.pid) == os.nice(0) + 3
    finally:
        p.kill()
        p.wait()


def test_a_child_left_at_nice_zero_keeps_its_parents():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], preexec_fn=_pinned(set(os.sched_getaffinity(0))))
    try:
        assert _nice(p.pid) == os.nice(0)
    finally:
        p.kill()
        p.wait()
