"""``python -m spotpde ...`` is the ``spotpde`` command."""

import sys

from .cli import main

sys.exit(main())
