"""tools/build_wheel.sh: the Linux wheel, built, repaired, installed without a compiler.

The script compiles the kernels (one to three minutes on two cores), so this
test runs only when ISOCONVERT_TEST_WHEEL=1 is set:

    ISOCONVERT_TEST_WHEEL=1 python -m pytest tests/test_wheel.py -s

It checks the script's mesh of the bundled sphere, converted by the wheel's
``isoconvert`` from another folder, against a conversion of the same volume by
the package under test (trimesh reads both).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SAMPLES

pytestmark = [
    pytest.mark.skipif(
        os.environ.get("ISOCONVERT_TEST_WHEEL") != "1",
        reason="builds a wheel (minutes): set ISOCONVERT_TEST_WHEEL=1 to run it",
    ),
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the script builds on Linux"),
]

SCRIPT = ROOT / "tools" / "build_wheel.sh"


def ignored_paths() -> set[str]:
    """The repository's ignored files and folders (a folder as one entry), as git
    lists them, less the caches that Python and the test tools write."""
    listed = subprocess.run(
        ["git", "status", "--porcelain", "--ignored"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    caches = ("__pycache__/", ".pytest_cache/", ".hypothesis/", ".ruff_cache/")
    return {
        line[3:]
        for line in listed.splitlines()
        if line.startswith("!! ") and not line.endswith(caches)
    }


def test_build_wheel_script_installs_without_a_compiler_and_converts(tmp_path):
    import trimesh

    if shutil.which("bash") is None:
        pytest.skip("bash is not installed")
    out = tmp_path / "wheelhouse"
    before = ignored_paths()
    done = subprocess.run(
        ["bash", str(SCRIPT), str(out)], capture_output=True, text=True, timeout=1800
    )
    print(done.stdout)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    # The summary the script ends with (the numbers quoted in reports).
    size = int(re.search(r"^wheel size: (\d+) bytes", done.stdout, re.M).group(1))
    install = float(re.search(r"^install time: ([\d.]+) s", done.stdout, re.M).group(1))
    total = float(re.search(r"^total time: ([\d.]+) s", done.stdout, re.M).group(1))
    assert install > 0 and total >= install
    wheels = list(out.glob("isoconvert-*.whl"))
    assert len(wheels) == 1 and wheels[0].stat().st_size == size
    # auditwheel's repaired wheel: a manylinux tag, not the build's plain linux_x86_64.
    assert "manylinux" in wheels[0].name, wheels[0].name
    # The wheel's own module ran, from the fresh venv, not the repository's.
    module = re.search(r"^   module: (.+)$", done.stdout, re.M).group(1)
    assert "site-packages" in module and not module.startswith(str(ROOT))

    # The wheel's mesh equals the package's own conversion of the same volume.
    reference = tmp_path / "reference.ply"
    subprocess.run(
        [sys.executable, "-m", "isoconvert.cli", "convert", str(SAMPLES / "sphere.nrrd")]
        + ["--level", "127.5", "-o", str(reference)],
        check=True,
        capture_output=True,
        timeout=600,
    )
    wheel_mesh = trimesh.load(out / "sphere.ply", process=False)
    ref_mesh = trimesh.load(reference, process=False)
    assert wheel_mesh.is_watertight and wheel_mesh.is_winding_consistent
    assert len(wheel_mesh.faces) == len(ref_mesh.faces) > 0
    assert len(wheel_mesh.vertices) == len(ref_mesh.vertices)
    np.testing.assert_allclose(wheel_mesh.volume, ref_mesh.volume, rtol=1e-6)

    # No new build tree or output in the repository (the script wrote to
    # tmp_path; its CMake tree went to a temporary folder). Other work in the
    # tree changes tracked files meanwhile, so only ignored paths are compared.
    assert ignored_paths() <= before
