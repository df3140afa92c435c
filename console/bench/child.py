"""Programs a benchmark starts, ended with it however it ends.

A benchmark killed outright (a timeout, Ctrl-C twice, `kill -9`) runs no
`finally`: the `rovlink demo` it started would keep running, with its
vehicle side, and load every measurement after it.  Linux ends a child whose
parent dies when the child asks for it (prctl PR_SET_PDEATHSIG); elsewhere
the `finally` of the benchmark is all there is.
"""

from __future__ import annotations

import ctypes
import signal
import subprocess
import sys

PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """For subprocess.Popen(preexec_fn=...): SIGTERM when the parent dies."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass


def end_child(proc: subprocess.Popen, *, first=signal.SIGTERM, grace_s: float = 30.0) -> None:
    """End a benchmark's child: `first` (SIGINT lets it shut down as after
    Ctrl-C), then SIGKILL when it has not ended within `grace_s`; reaped."""
    if proc.poll() is not None:
        return
    proc.send_signal(first)
    try:
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
