"""`python -m rovlink ...` is the `rovlink` command."""

import sys

from rovlink.cli import main

sys.exit(main())
