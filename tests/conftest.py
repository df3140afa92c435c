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


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the group marks
def pytest_collection_modifyitems(items):
    """With pytest-xdist (`-n 3 --dist loadgroup`, as .ci/run runs): the browser
    tests in two groups, so that at most two software-rendered Chromiums run at
    once on this 2-core machine, and every other module in a group of its own
    (its module-scoped fixtures start once).  The groups share the three
    workers; without xdist the marks do nothing.  The browser modules, in the
    order of their names, go to the two groups in turn.

    Most tests wait on the link's real time (the suite kept the two cores about
    40 % busy with two workers), so a third worker shortens the suite.  The marks
    must be on the items before xdist's hook turns them into groups (tryfirst):
    added after it, as they were until stop 31, they grouped nothing."""
    browser_modules = sorted({item.module.__name__ for item in items if item.get_closest_marker("browser")})
    for item in items:
        name = item.module.__name__
        if item.get_closest_marker("browser"):
            group = f"browser-{browser_modules.index(name) % 2 + 1}"
        else:
            group = name
        item.add_marker(pytest.mark.xdist_group(group))
