"""`python -m rovlink ...` is the `rovlink` command."""

import sys

from rovlink.cli import main

# Guarded: a process started with multiprocessing's spawn (the link process) imports the
# parent's main module again, and must not run the command a second time.
if __name__ == "__main__":
    sys.exit(main())
