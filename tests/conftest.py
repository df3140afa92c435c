"""Suite-wide set-up.

DEBT's coder is compiled by numba on first use and cached on disk; a cold
compile takes tens of seconds on this 2-core machine.  Compile it once here,
before any test, so that tests of the node, the console and the commands
(which wait on real images with timeouts) do not pay it inside their waits,
and so that their subprocesses find the cache ready.
"""

import pytest


@pytest.fixture(scope="session", autouse=True)
def debt_compiled():
    from rovlink import debt

    debt.warm_up()


# The browser tests whose time goes mostly in waiting on real processes and links (the
# acoustic modems, a demo started as a user starts it, a bench's children), not in a page
# the pilot drags or steers on: the second browser group.  Split by their measured times
# (`--durations=0`, about half of the browser tests' time each).
BROWSER_WAITING = {
    "tests.console.test_acoustic", "tests.console.test_acoustic_bad_day", "tests.console.test_bench_children",
    "tests.console.test_demo", "tests.console.test_restarts", "tests.console.test_port_down",
    "tests.console.test_link_process", "tests.console.test_objects_acoustic",
}


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the group marks
def pytest_collection_modifyitems(items):
    """With pytest-xdist (`-n 4 --dist loadgroup`, as .ci/run runs): the browser tests in
    two groups, so that at most two software-rendered Chromiums run at once, and only one
    of them on a page a test drags or steers on ("browser"; the other, "browser
    waiting", runs the tests that mostly wait on real processes and links); every other
    module in a group of its own (its module-scoped fixtures start once).  The two
    browser groups take a worker each from the start; the other two workers share the
    rest.  Without xdist the marks do nothing.

    Most tests wait on the link's real time (two workers kept the two cores about 40 %
    busy), hence four workers on two cores.  The marks must be on the items before
    xdist's hook turns them into groups (tryfirst): added after it, as they were until
    stop 31, they grouped nothing and the browser tests ran two at a time."""
    for item in items:
        module = item.module.__name__
        if item.get_closest_marker("browser"):
            group = "browser waiting" if module in BROWSER_WAITING else "browser"
        else:
            group = module
        item.add_marker(pytest.mark.xdist_group(group))
