"""``python -m st_stereo``: the ``st-stereo`` command line."""

import sys

from st_stereo.cli import main

if __name__ == '__main__':      # spawned helper processes import this module too
    sys.exit(main())
