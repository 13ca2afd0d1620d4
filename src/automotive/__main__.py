"""``python -m automotive``: the same as the ``automotive`` command."""

import sys

from automotive.start import automotive

sys.exit(automotive())
