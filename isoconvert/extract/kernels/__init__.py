"""numba kernels: plain arrays and scalars in, arrays out; no validation here.

This package imports numba, so import it only when extracting: ``--help``,
``info`` and ``check`` must not pay numba's start-up price.

Compiled code is cached in the user's cache folder (``NUMBA_CACHE_DIR`` when
set), never beside these modules: numba's default cache inside an installed
package survives ``pip uninstall`` as a ``__pycache__`` folder, which Python
then takes for an empty namespace package that shadows a later install.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def cache_folder() -> Path:
    """The folder under which numba caches isoconvert's compiled kernels (in a
    sub-folder per version of the kernel sources, see :func:`source_stamp`).

    ``NUMBA_CACHE_DIR`` when set; else ``isoconvert/numba`` in the user's cache
    folder (platformdirs), or in the temporary folder when that one cannot be
    written (a read-only home, as some CI runners and containers have).
    """
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        return Path(given)
    from platformdirs import user_cache_dir

    for base in (Path(user_cache_dir("isoconvert")), Path(tempfile.gettempdir()) / _per_user()):
        folder = base / "numba"
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK | os.X_OK):
            return folder
    return Path(tempfile.mkdtemp(prefix="isoconvert-numba-"))


def _per_user() -> str:
    uid = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return f"isoconvert-{uid}"


def source_stamp(folder: Path | None = None) -> str:
    """A hash of the kernel sources: the name of their cache sub-folder.

    numba checks a cached function against its own file only; a kernel that
    inlines a helper from another module (``interpolate.py``) would keep the
    helper's old code after the helper changed. One sub-folder per version of
    all kernel sources makes any change recompile everything.
    """
    import hashlib

    digest = hashlib.sha256()
    for source in sorted((folder or Path(__file__).parent).glob("*.py")):
        digest.update(source.name.encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()[:16]


def _use_cache_folder() -> None:
    # numba picks a function's cache locator when the function is decorated, so
    # this must run before the kernel modules are imported; CACHE_DIR set here
    # makes numba's user-provided locator win over its in-tree one.
    from numba.core import config

    config.CACHE_DIR = str(cache_folder() / source_stamp())


_use_cache_folder()
