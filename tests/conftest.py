"""Suite-wide set-up.

DEBT's coder is compiled by numba on first use and cached on disk; a cold
compile takes tens of seconds on this 2-core machine.  Compile it once here,
before any test, so that tests of the node, the console and the commands
(which wait on real images with timeouts) do not pay it inside their waits,
and so that their subprocesses find the cache ready.
"""

import signal

import pytest

# A shell without job control starts a background job with SIGINT ignored, and its
# children inherit that: the tests that stop `rovlink sim`, `channel`, `rov` and
# `console` with Ctrl-C (SIGINT) then waited out their timeouts (a newcomer's run of
# `.ci/run &` under nohup: five failures, every time).  The suite's own processes take
# SIGINT as a terminal gives it, so the programs it starts do too.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def debt_compiled():
    from rovlink import debt

    debt.warm_up()


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the group marks
def pytest_collection_modifyitems(items):
    """With pytest-xdist (`-n 3 --dist loadgroup`, as .ci/run runs): the browser
    tests in two groups, and every other module in a group of its own (its
    module-scoped fixtures start once).  Each browser group runs one Chromium at a
    time, so at most two run at once: `browser-processes` (the tests that run the
    system as processes: rovlink rov and console, the benches' children) and
    `browser` (the page and the scene against an in-process console).  Until stop
    45 one group held them all, for fear of two software-rendered scenes on two
    cores; the scene is drawn now only by the tests about it (?scene=off for the
    rest: 0.4 of a core a page instead of 1.25), and the one group had become the
    suite's wall time (800 s of 820).  Without xdist the marks do nothing.

    Most tests wait on the link's real time, hence three workers on two cores.
    The marks must be on the items before xdist's hook turns them into groups
    (tryfirst): added after it, as they were until stop 31, they grouped
    nothing."""
    for item in items:
        if item.get_closest_marker("browser"):
            group = "browser-processes" if item.module.__name__.rsplit(".", 1)[-1] in BROWSER_PROCESSES else "browser"
        else:
            group = item.module.__name__
        item.add_marker(pytest.mark.xdist_group(group))


# The browser tests that run the system as processes (about half the browser tests' time;
# test_demo's, though it starts `rovlink demo`, goes with the others for the balance).
BROWSER_PROCESSES = {"test_acoustic_bad_day", "test_bench_children", "test_acoustic", "test_restarts",
                     "test_link_process", "test_port_down", "test_late_follow", "test_objects_acoustic"}
