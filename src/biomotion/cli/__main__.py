"""``python -m biomotion.cli``: the ``biomotion`` command."""

import sys

from biomotion.cli import main

sys.exit(main())
