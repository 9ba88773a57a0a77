"""``python -m safeswitch``: the command line."""

import sys

from safeswitch.cli import main

sys.exit(main())
