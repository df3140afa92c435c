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
    import numpy as np

    from rovlink import debt

    for image in (np.zeros((16, 16), np.uint8), np.zeros((16, 16, 3), np.uint8)):
        debt.decode(debt.encode(image, 200, roi=(0, 0, 8, 8), shift=4))
