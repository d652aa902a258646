"""Telling the user when numba compiles (first run), instead of going silent."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager


@contextmanager
def compile_notice(on_status: Callable[[str], None] | None, message: str) -> Iterator[None]:
    """Call ``on_status(message)`` once if numba compiles anything inside the block.

    numba fires its ``numba:compile`` event only on a cache miss (after the
    on-disk cache was tried), so a cached run stays quiet.
    """
    if on_status is None:
        yield
        return
    from numba.core import event

    class _Listener(event.Listener):
        said = False

        def on_start(self, ev: event.Event) -> None:
            if not self.said:
                self.said = True
                on_status(message)

        def on_end(self, ev: event.Event) -> None:
            pass

    listener = _Listener()
    event.register("numba:compile", listener)
    try:
        yield
    finally:
        event.unregister("numba:compile", listener)
