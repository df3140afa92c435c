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


def pytest_collection_modifyitems(items):
    """With pytest-xdist (`-n 2 --dist loadgroup`, as .ci/run runs): every
    browser test in one group, so that two software-rendered Chromiums never
    compete for this 2-core machine (the tests that run the programs as
    processes with them), and every other module in a group of its
    own (its module-scoped fixtures start once).  The groups share the two
    workers; without xdist the marks do nothing."""
    for item in items:
        # Tests that run the programs as processes load the machine like a browser does:
        # they take their turns with the browser tests, never beside them.
        heavy = item.get_closest_marker("browser") or item.get_closest_marker("processes")
        group = "browser" if heavy else item.module.__name__
        item.add_marker(pytest.mark.xdist_group(group))
