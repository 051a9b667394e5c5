"""``python -m replicate``: the command line (``replicate.toolkit.cli``)."""

import sys

from replicate.toolkit.cli import main

sys.exit(main())
