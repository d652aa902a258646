"""``python -m isoconvert.cli``."""

import sys

from ..entry import prepare_process
from . import main

prepare_process()
sys.exit(main())
