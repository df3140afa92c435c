"""`python -m rovlink ...` is the `rovlink` command."""

import sys

from rovlink.console.cli import main

sys.exit(main())
