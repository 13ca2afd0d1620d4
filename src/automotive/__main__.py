"""``python -m automotive``: the same as the ``automotive`` command."""

import sys

from automotive.command import main

sys.exit(main())
