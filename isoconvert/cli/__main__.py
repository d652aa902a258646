"""``python -m isoconvert.cli``."""

import sys

from . import main

sys.exit(main())
