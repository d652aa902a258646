"""``python -m isoconvert``."""

from .entry import run

run()
