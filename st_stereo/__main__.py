"""``python -m st_stereo``: the ``st-stereo`` command line."""

import sys

from st_stereo.cli import main

sys.exit(main())
