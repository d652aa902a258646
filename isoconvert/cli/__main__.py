"""``python -m isoconvert.cli``."""

import sys

from ..memory import keep_freed_memory
from . import main

keep_freed_memory()
sys.exit(main())
