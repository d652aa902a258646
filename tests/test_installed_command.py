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


def test_extraction_is_compiled_at_install_and_writes_no_cache(tmp_path):
    """The kernels are the compiled module built by `pip install .`: the first
    extraction compiles nothing, imports no JIT and writes nothing to the
    user's cache folder."""
    script = (
        "import sys, numpy as np, isoconvert; "
        "v = isoconvert.Volume.from_zyx(np.pad(np.ones((2, 2, 2), np.int8), 1)); "
        "m = isoconvert.extract(v, 0.5); "
        # a 2x2x2 block: 8 corner cubes x 1 triangle, 12 edge cubes x 2, 6 face cubes x 2
        "assert m.n_cells == 44, m.n_cells; "
        "assert 'numba' not in sys.modules, 'numba imported'; "
        "from isoconvert import _native; print(_native.__file__)"
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=tmp_path,
        env={**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).suffix in (".so", ".pyd")
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*"))
