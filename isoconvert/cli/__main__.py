"""``python -m isoconvert.cli``."""

import sys

from ..threads import prepare_process
from . import main

prepare_process()
sys.exit(main())
