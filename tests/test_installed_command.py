"""The installed ``isoconvert`` command, run from outside the repository as a user does.

In CI (``.ci/run``) this runs after the README's two quick-start commands, in
that order, in one fresh virtual environment: the situation in which a folder
numba once left inside the installed package shadowed the editable install
and broke every later call.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, SAMPLES

import isoconvert


def installed_command() -> str:
    """Path of the ``isoconvert`` script beside this Python, or skip (outside CI)."""
    script = Path(sys.executable).parent / "isoconvert"
    found = str(script) if script.exists() else shutil.which("isoconvert")
    if found is None:
        if os.environ.get("CI"):
            pytest.fail("the isoconvert command is not installed in CI")
        pytest.skip("the isoconvert command is not installed (pip install -e .)")
    return found


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_version_from_another_folder(tmp_path):
    done = run([installed_command(), "--version"], tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == f"isoconvert {isoconvert.__version__}"


def test_convert_from_another_folder_with_a_non_ascii_path(tmp_path):
    """A convert from elsewhere, into a folder whose name is not ASCII; the mesh
    is read back by trimesh."""
    import trimesh

    out = tmp_path / "données" / "Müller sphère.ply"
    out.parent.mkdir()
    done = run(
        [
            installed_command(),
            "convert",
            str(SAMPLES / "sphere.nrrd"),
            "-l",
            "127.5",
            "-o",
            str(out),
        ],
        tmp_path,
    )
    assert done.returncode == 0, done.stderr
    mesh = trimesh.load(out, process=False)
    assert mesh.is_watertight and mesh.volume > 0


def test_the_package_is_imported_from_the_repository_or_its_install():
    """No stray folder shadows the package: it is a real package with a version."""
    done = run([sys.executable, "-c", "import isoconvert; print(isoconvert.__file__)"], Path("/"))
    assert done.returncode == 0, done.stderr
    location = Path(done.stdout.strip())
    assert location.name == "__init__.py"
    assert location.parent == ROOT / "isoconvert" or "site-packages" in str(location)


def test_numba_cache_is_not_written_into_the_package(tmp_path):
    """Compiled kernels go to the user's cache folder (here XDG_CACHE_HOME), never
    beside the kernel modules; NUMBA_CACHE_DIR, when set, wins."""
    import time

    start = time.time()
    script = (
        "import numpy as np, isoconvert; "
        "v = isoconvert.Volume.from_zyx(np.pad(np.ones((2, 2, 2), np.int8), 1)); "
        "isoconvert.extract(v, 0.5)"
    )
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    for name, extra, where in [
        ("user cache", {"XDG_CACHE_HOME": str(tmp_path / "xdg")}, tmp_path / "xdg" / "isoconvert"),
        ("NUMBA_CACHE_DIR", {"NUMBA_CACHE_DIR": str(tmp_path / "nb")}, tmp_path / "nb"),
    ]:
        done = subprocess.run(
            [sys.executable, "-c", script],
            cwd=tmp_path,
            env={**env, **extra},
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, done.stderr
        assert list(where.rglob("*.nbi")), f"nothing cached in the {name} folder {where}"
    package = Path(isoconvert.__file__).parent
    fresh = [p for p in package.rglob("*.nb[ic]") if p.stat().st_mtime >= start - 1]
    assert not fresh, f"numba wrote its cache into the package: {fresh[:3]}"


def test_kernels_are_recompiled_when_any_kernel_source_changes(tmp_path):
    """numba checks a cached kernel against its own file only, not against the
    helpers it inlines; the cache sub-folder is named by a hash of all kernel
    sources, so changing any of them starts a fresh cache."""
    import shutil

    from numba.core import config

    from isoconvert.extract import kernels

    assert Path(config.CACHE_DIR).name == kernels.source_stamp()
    copy = tmp_path / "kernels"
    shutil.copytree(
        Path(kernels.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__")
    )
    assert kernels.source_stamp(copy) == kernels.source_stamp()
    helper = copy / "interpolate.py"
    helper.write_text(helper.read_text() + "\n# changed\n")
    assert kernels.source_stamp(copy) != kernels.source_stamp()
