"""``python -m isoconvert.cli``."""

import sys

from ..signals import quiet_exit
from ..threads import prepare_process
from . import main

prepare_process()
code = main()
quiet_exit()
sys.exit(code)
