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
    """With pytest-xdist (`-n 3 --dist loadgroup`, as .ci/run runs): every
    browser test in one group, so that two software-rendered Chromiums never
    compete for this 2-core machine (a pilot's drag or held stick then lags),
    and every other module in a group of its own (its module-scoped fixtures
    start once).  The browser group takes one worker from the start and sets
    the suite's wall time; the other two workers share the rest.  Without
    xdist the marks do nothing.

    Most tests wait on the link's real time (two workers kept the two cores
    about 40 % busy), hence three workers.  The marks must be on the items
    before xdist's hook turns them into groups (tryfirst): added after it, as
    they were until stop 31, they grouped nothing and the browser tests ran
    two at a time."""
    for item in items:
        group = "browser" if item.get_closest_marker("browser") else item.module.__name__
        item.add_marker(pytest.mark.xdist_group(group))
