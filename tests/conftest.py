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
