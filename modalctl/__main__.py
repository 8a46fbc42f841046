"""``python -m modalctl``: the command line, as the ``modalctl`` script."""

import sys

from modalctl.cli import main

sys.exit(main())
