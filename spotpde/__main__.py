"""``python -m spotpde ...`` is the ``spotpde`` command."""

import sys

from .app.cli import main

sys.exit(main())
