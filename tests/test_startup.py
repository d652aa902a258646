"""Start-up (issue 9): the help, ``formats`` and ``methods`` import no numpy; ``info``
and ``check`` only what they use; the lazy tables agree with what they stand for.

Each command runs in a fresh interpreter, since this test process has imported
everything long ago. Timing is measured by hand (see the issue), not asserted.
"""

from __future__ import annotations

import importlib
import pickle
import subprocess
import sys

import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import Mesh, write_mesh
from isoconvert.lazy import LazyFunction, import_target
from isoconvert.readers import READERS
from isoconvert.registry import Registry
from isoconvert.writers import WRITERS

#: Never needed to print help or list formats and methods.
NOT_FOR_HELP = (
    "numpy",
    "numba",
    "trimesh",
    "meshio",
    "scipy",
    "tifffile",
    "PIL",
    "nrrd",
    "isoconvert.extract",
    "isoconvert.report",
)
#: Not needed to describe a volume or check a mesh file.
NOT_FOR_WORK = ("numba", "trimesh", "meshio", "scipy", "isoconvert.extract")


def modules_after(code: str, forbidden: tuple[str, ...]) -> list[str]:
    """Run ``code`` in a fresh interpreter; the ``forbidden`` modules it imported."""
    script = (
        "import contextlib, io, sys\n"
        f"{code}\n"
        f"print(' '.join(m for m in {forbidden!r} if m in sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()


def cli_modules(args: list[str], forbidden: tuple[str, ...]) -> list[str]:
    """The ``forbidden`` modules that ``isoconvert ARGS`` imports (it must succeed)."""
    code = (
        "from isoconvert.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = main({args!r})\n"
        "assert code == 0, code"
    )
    return modules_after(code, forbidden)


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["--version"],
        ["formats"],
        ["methods"],
        ["convert", "--help"],
        ["check", "--help"],
        ["info", "--help"],
        ["batch", "--help"],
    ],
    ids=" ".join,
)
def test_help_formats_and_methods_import_no_numpy(args):
    assert cli_modules(args, NOT_FOR_HELP) == []


def test_import_isoconvert_imports_no_numpy():
    assert modules_after("import isoconvert", NOT_FOR_HELP) == []


@pytest.mark.parametrize(
    "name, also_not",
    [
        ("sphere.nrrd", ("tifffile", "PIL")),
        ("sphere_40x40x40_uint8.raw", ("tifffile", "PIL", "nrrd")),
        ("sphere.tif", ("PIL", "nrrd")),
    ],
)
def test_info_imports_only_its_reader(name, also_not):
    assert cli_modules(["info", str(SAMPLES / name)], NOT_FOR_WORK + also_not) == []


def test_check_imports_no_kernels_and_no_mesh_libraries(tmp_path):
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    path = write_mesh(Mesh(corners, faces), tmp_path / "tetrahedron.ply")
    forbidden = NOT_FOR_WORK + ("tifffile", "PIL", "nrrd")
    assert cli_modules(["check", str(path)], forbidden) == []


@pytest.mark.parametrize(
    "first",
    ["import isoconvert.convert, isoconvert.extract.tables", "from isoconvert.cli import main"],
)
def test_public_functions_win_over_submodules_of_their_name(first):
    """``isoconvert.convert`` and ``isoconvert.extract`` are the functions, whatever
    imported the submodules of those names first."""
    code = (
        f"{first}\n"
        "import isoconvert\n"
        "from isoconvert import convert, extract\n"
        "assert callable(convert) and callable(extract), (convert, extract)\n"
        "assert isoconvert.convert is convert and isoconvert.extract is extract\n"
        "import isoconvert.extract.tables\n"
        "assert callable(isoconvert.extract)\n"
        "missing = [n for n in isoconvert.__all__ if not hasattr(isoconvert, n)]\n"
        "assert not missing, missing\n"
        "assert set(isoconvert.__all__) <= set(dir(isoconvert))"
    )
    assert modules_after(code, ()) == []


def test_unknown_public_name_is_an_attribute_error():
    import isoconvert

    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        isoconvert.nope  # noqa: B018


# --- the numpy-free tables say what the modules they stand for say -----------------------


def test_method_declarations_match_the_extractors():
    from isoconvert import methods

    # the subpackage (isoconvert.extract is the function of that name)
    extractors = importlib.import_module("isoconvert.extract")
    built_in = ["cubes", "tetra", "squares"]
    assert methods.EXTRACTORS.names()[:3] == built_in
    for name in built_in:
        assert methods.EXTRACTORS.summary(name) == extractors.EXTRACTORS.get(name).summary
    assert methods.PLUGIN_GROUP == extractors.PLUGIN_GROUP
    assert methods.NO_DEGENERATE_OFFSET == extractors.NO_DEGENERATE_OFFSET
    assert methods.SQUARE_AMBIGUITY_RULES == extractors.SQUARE_AMBIGUITY_RULES
    assert methods.AMBIGUITY_RULES == extractors.AMBIGUITY_RULES


def test_check_names_match_the_report():
    from isoconvert import checks, report

    assert checks.CHECK_NAMES == report.CHECK_NAMES
    assert checks.TRIANGLE_CHECKS == report.TRIANGLE_CHECKS
    assert checks.SEGMENT_CHECKS == report.SEGMENT_CHECKS


@pytest.mark.parametrize("table", [READERS, WRITERS], ids=["readers", "writers"])
def test_lazy_format_functions_name_real_functions(table):
    for name, entry in table.items():
        function = entry.read if table is READERS else entry.write
        assert isinstance(function, LazyFunction), name
        assert callable(import_target(function.target)), function


# --- the pieces ----------------------------------------------------------------------------


def test_lazy_function_imports_on_first_call_and_pickles_as_its_target():
    dumps = LazyFunction("json:dumps")
    assert dumps([1]) == "[1]"
    again = pickle.loads(pickle.dumps(dumps))
    assert again == dumps and again({"a": 1}) == '{"a": 1}'
    with pytest.raises(ValueError, match="module:attribute"):
        LazyFunction("json.dumps")
    with pytest.raises(ModuleNotFoundError):
        LazyFunction("isoconvert_nowhere:run")()


def test_declared_entries_are_listed_without_import_and_loaded_on_get():
    table = Registry("thing")
    table.declare("gone", "isoconvert_nowhere:THING", summary="never imported", suffixes=(".gn",))
    table.declare("json", "json:JSONDecoder", summary="the decoder", suffixes=(".json",))
    assert table.names() == ["gone", "json"]
    assert table.summary("gone") == "never imported"
    assert "gone" in table
    assert table.suffix_listing() == "gone (.gn), json (.json)"
    # a format no suffix names (a layer's folder) is listed with the flag that gives it
    table.declare("folder", "isoconvert_nowhere:FOLDER", summary="a folder", suffixes=())
    assert table.suffix_listing() == "gone (.gn), json (.json), folder (--format folder)"
    import json

    assert table.by_suffix(".JSON") == ("json", json.JSONDecoder)
    assert table.get("json") is json.JSONDecoder
    with pytest.raises(ModuleNotFoundError):  # a broken built-in is a bug, not a user error
        table.get("gone")
    with pytest.raises(ValueError, match="already registered"):
        table.declare("json", "json:dumps", summary="again")


KEPT = """
import sys
import numpy as np
from isoconvert.memory import keep_freed_memory

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096

took = keep_freed_memory() if sys.argv[1] == "keep" else None
before = rss()
a = np.ones(2_000_000)  # 16 MB: glibc maps it on its own by default
del a
print(took, (rss() - before) // 2**20)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_the_command_keeps_freed_memory_for_its_next_arrays():
    """keep_freed_memory (called by the isoconvert command): a freed 16 MB array's pages
    stay with the process for the next one instead of going back to the system."""
    out = {}
    for mode in ("keep", "default"):
        proc = subprocess.run([sys.executable, "-c", KEPT, mode], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        out[mode] = proc.stdout.split()
    if out["keep"][0] != "True":
        pytest.skip("not glibc: mallopt is not there")
    assert int(out["keep"][1]) >= 12  # kept
    assert out["default"][0] == "None" and int(out["default"][1]) < 4  # given back


BLAS = """
import os, sys
if sys.argv[1] == "prepared":
    from isoconvert.threads import prepare_process
    prepare_process()
import numpy
print(os.environ.get("OPENBLAS_NUM_THREADS"), len(os.listdir("/proc/self/task")))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/task")
def test_the_command_process_gives_numpy_blas_one_thread(monkeypatch):
    """prepare_process (the isoconvert command's start): OpenBLAS starts no threads of
    its own to spin against the kernels', unless the user asked for some."""
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)

    def run(mode):
        proc = subprocess.run([sys.executable, "-c", BLAS, mode], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        setting, threads = proc.stdout.split()
        return setting, int(threads)

    assert run("prepared") == ("1", 1)
    setting, threads = run("plain")
    assert setting == "None"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's own setting is kept
    assert run("prepared")[0] == "2"
