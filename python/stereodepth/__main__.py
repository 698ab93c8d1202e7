"""``python -m stereodepth``: the same as the ``stereodepth`` command."""

import sys

from .cli import main

sys.exit(main())
