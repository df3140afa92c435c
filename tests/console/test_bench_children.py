"""A benchmark killed outright takes the programs it started with it (Linux):
a `rovlink demo` left running would load every measurement after it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from ..helpers import needs_chromium

PARENT = """
import subprocess, sys, time
from rovlink.console.bench.child import die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], preexec_fn=die_with_parent)
print(child.pid, flush=True)
time.sleep(120)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_child_of_a_benchmark_ends_when_the_benchmark_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    os.kill(parent.pid, signal.SIGKILL)  # no finally, no cleanup
    parent.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{child}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    break
        except FileNotFoundError:
            break
        time.sleep(0.05)
    else:
        os.kill(child, signal.SIGKILL)
        pytest.fail("the child outlived the benchmark that started it")


@pytest.mark.browser
@needs_chromium
def test_bench_console_measures_a_pilot_on_the_demos_page():
    """The pilot row: `rovlink demo` as a process, its page in headless Chromium, flown for
    a short while here; the link's state sampled, its alerts counted, its losses split."""
    import json

    out = subprocess.run([sys.executable, "-m", "rovlink", "bench", "console", "--duration", "30", "--sample-every",
                          "30", "--no-prediction", "--no-steering", "--no-page", "--no-load", "--no-loaded",
                          "--pilot-minutes", "0.5", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout)
    pilot = doc["pilot"]
    assert pilot["samples"] >= 30 and sum(pilot["state_percent"].values()) == pytest.approx(100, abs=0.1)
    assert pilot["polls_sent"] > 20 and pilot["odometry_age_s_median"] is not None
    assert pilot["replies_lost_not_by_channel"] <= pilot["replies_lost"]
    target = doc["targets"]["no_link_lost_or_failsafe_with_a_pilot_on_the_page"]
    assert target["met"] is None  # half a minute says nothing of ten


@pytest.mark.browser
@needs_chromium
def test_bench_console_measures_the_link_on_a_busy_machine_and_names_the_process_that_owns_it():
    """The busy machine's row, short and without its CPU-bound processes here (they would
    load the suite's other tests): `rovlink rov`, `rovlink channel` and `rovlink console`
    as processes, the page in headless Chromium, the API read 40 times a second; the polls
    counted, the link owned by a process that is not the console's."""
    import json

    out = subprocess.run([sys.executable, "-m", "rovlink", "bench", "console", "--duration", "30", "--sample-every",
                          "30", "--no-prediction", "--no-steering", "--no-page", "--no-load", "--no-pilot", "--loaded-minutes", "0.3",
                          "--loaded-burners", "0", "--json"], capture_output=True, text=True, timeout=400)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout)
    (row,) = doc["loaded"]
    assert row["link"] == "process of its own"
    assert row["link_process_pid"] and row["link_process_pid"] != row["console_pid"]
    assert row["polls"] >= 5 and 0 <= row["replies_not_in_time"] <= row["polls"]
    assert row["api_reads"] > 100
    target = doc["targets"]["link_in_time_on_a_busy_machine"]
    assert target["met"] is None and target["late_percent"] == row["late_percent"]
