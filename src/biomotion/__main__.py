"""``python -m biomotion``: the ``biomotion`` command."""

import sys

from biomotion.cli import main

sys.exit(main())
