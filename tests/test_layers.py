"""One-way layers (issue 21): no import cycle among the package's modules, and the
lower layers never reach the jobs, the CLI or the Dask code.

The import graph is read from the sources with ``ast`` by bench/import_graph.py
(``python bench/import_graph.py`` prints it), whose docstring states the rules:
every import counts (top-level, inside functions, under ``TYPE_CHECKING``),
relative imports are resolved, and a package ``__init__`` that imports a name
from its own submodule without using it re-exports it (the importer depends on
the defining module, not on the ``__init__``). The first tests check that
reading on small packages written here, whose graphs are worked out by hand.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from conftest import load_import_graph

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "isoconvert"


ig = load_import_graph()

#: The lower layers (ARCHITECTURE.md, Layers) and what they must never reach.
LOWER = ("extract", "readers", "writers", "post", "meshfile", "report")
JOBS_AND_SHELL = ("cli", "batch", "convert", "label_convert", "distributed")
#: The runner's Dask code: extraction and the layers beside it reach a cluster
#: only through the engine-neutral isoconvert.runner.
DASK_CODE = ("runner.dask", "distributed")
#: What the task runner must know nothing of.
NOT_FOR_THE_RUNNER = (
    *JOBS_AND_SHELL,
    "extract",
    "volume",
    "grid",
    "readers",
    "writers",
    "post",
    "report",
)


def _in(name: str, parts: tuple[str, ...], package: str = "isoconvert") -> bool:
    """Whether module ``name`` is one of ``parts`` (a module or a package and its modules)."""
    return any(name == f"{package}.{p}" or name.startswith(f"{package}.{p}.") for p in parts)


@pytest.fixture(scope="module")
def graph():
    return ig.build(PACKAGE)


def _write(root: Path, files: dict[str, str]) -> Path:
    for relative, text in files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root / "pkg"


# --- the graph reader, on packages whose graphs are known ---------------------------------------


def test_every_kind_of_import_is_an_edge(tmp_path):
    root = _write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": """
                from typing import TYPE_CHECKING
                import numpy
                from . import b
                from .sub.c import thing
                if TYPE_CHECKING:
                    from .d import D
                def f():
                    from .sub import e
                    import pkg.sub.c
            """,
            "pkg/b.py": "",
            "pkg/d.py": "D = 1\n",
            "pkg/sub/__init__.py": "",
            "pkg/sub/c.py": "from ..b import x\nfrom .. import d\n",
            "pkg/sub/e.py": "from ...pkg import b\n",
        },
    )
    graph = ig.build(root)
    assert {(e.source, e.target, e.kind) for e in graph.edges} == {
        ("pkg.a", "pkg.b", "top"),  # a submodule named in "from . import"
        ("pkg.a", "pkg.sub.c", "top"),  # a name of pkg.sub.c
        ("pkg.a", "pkg.d", "typing"),
        ("pkg.a", "pkg.sub.e", "lazy"),
        ("pkg.a", "pkg.sub.c", "lazy"),  # "import pkg.sub.c" in a function
        ("pkg.sub.c", "pkg.b", "top"),
        ("pkg.sub.c", "pkg.d", "top"),
        ("pkg.sub.e", "pkg.b", "top"),  # three levels up, then down again
    }
    assert graph.external["pkg.a"] == {"typing", "numpy"}
    assert ig.cycles(graph) == []


def test_cycles_of_every_kind_are_found(tmp_path):
    root = _write(
        tmp_path,
        {
            "pkg/__init__.py": "",
            "pkg/a.py": "from .b import x\n",
            "pkg/b.py": "def x():\n    from .c import y\n",
            "pkg/c.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import z\n"
            ),
            "pkg/d.py": "from . import d\n",  # itself
            "pkg/e.py": "from .f import w\n",
            "pkg/f.py": "",
        },
    )
    graph = ig.build(root)
    assert ig.cycles(graph) == [["pkg.a", "pkg.b", "pkg.c"], ["pkg.d"]]
    assert ig.shortest_cycle(graph, "pkg.b", {"pkg.a", "pkg.b", "pkg.c"}) == [
        "pkg.b",
        "pkg.c",
        "pkg.a",
        "pkg.b",
    ]
    assert "2 import cycle(s) joining 4 modules" in ig.describe(graph, only_cycles=True)


def test_a_re_export_of_an_init_is_no_cycle_but_a_use_is(tmp_path):
    files = {
        # offers f (never used here) and uses g (a table built from it)
        "pkg/__init__.py": "from .low import f\nfrom .high import g\nTABLE = [g]\nVERSION = 1\n",
        "pkg/low.py": "def f():\n    pass\n",
        # takes f through the package: it depends on pkg.low, not on the __init__
        "pkg/high.py": "from . import f\ndef g():\n    pass\n",
        "pkg/other.py": "from pkg import VERSION, f\n",
    }
    graph = ig.build(_write(tmp_path / "one", files))
    edges = {(e.source, e.target) for e in graph.edges}
    assert edges == {
        ("pkg", "pkg.high"),  # used: a real import of the __init__
        ("pkg.high", "pkg.low"),
        ("pkg.other", "pkg"),  # VERSION is the __init__'s own
        ("pkg.other", "pkg.low"),
    }
    assert ig.cycles(graph) == []
    # the module the __init__ uses takes a name the __init__ defines: a real cycle
    files["pkg/high.py"] = "from . import VERSION\ndef g():\n    pass\n"
    graph = ig.build(_write(tmp_path / "two", files))
    assert ig.cycles(graph) == [["pkg", "pkg.high"]]


# --- the package --------------------------------------------------------------------------------


def test_the_package_has_no_import_cycle(graph):
    found = ig.cycles(graph)
    circles = [
        " -> ".join(ig.shortest_cycle(graph, component[0], set(component))) for component in found
    ]
    assert not found, "import cycles:\n" + "\n".join(circles)


def test_the_graph_sees_the_whole_package(graph):
    """A guard on the reader: the modules the layer tests name are all read."""
    for name in ("cli", "batch", "convert", "extract.blocks", "runner", "runner.dask", "report"):
        assert f"isoconvert.{name}" in graph.modules
    assert len(graph.edges) > 300  # every module imports a few others


@pytest.mark.parametrize("layer", LOWER)
def test_lower_layers_never_reach_jobs_or_the_cli(graph, layer):
    """Directly or through any chain of imports, of any kind."""
    bad = []
    for name in sorted(graph.modules):
        if _in(name, (layer,)):
            for target, chain in graph.reachable(name).items():
                if _in(target, JOBS_AND_SHELL):
                    bad.append(" -> ".join(chain))
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("layer", LOWER)
def test_lower_layers_import_no_dask_code(graph, layer):
    """Not the runner's Dask engine (only the engine-neutral runner), nor dask itself."""
    bad = [
        f"{e.source} -> {e.target} (line {e.line})"
        for e in graph.edges
        if _in(e.source, (layer,)) and _in(e.target, DASK_CODE)
    ]
    bad += [
        f"{name} -> {', '.join(sorted(names & {'dask', 'distributed'}))}"
        for name, names in graph.external.items()
        if _in(name, (layer,)) and names & {"dask", "distributed"}
    ]
    assert not bad, "\n".join(bad)


def test_the_runner_knows_no_volume_block_or_job(graph):
    bad = []
    for name in sorted(graph.modules):
        if _in(name, ("runner",)):
            for target, chain in graph.reachable(name).items():
                if _in(target, NOT_FOR_THE_RUNNER):
                    bad.append(" -> ".join(chain))
    assert not bad, "\n".join(bad)
