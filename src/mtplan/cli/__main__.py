"""``python -m mtplan.cli``: the ``mtplan`` command."""

import sys

from mtplan.cli import main

sys.exit(main())
