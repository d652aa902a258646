"""Print the import graph of the isoconvert package: each module, the package's
modules it imports, and the import cycles among them.

    python bench/import_graph.py [PACKAGE_FOLDER] [--cycles]

PACKAGE_FOLDER defaults to this checkout's ``isoconvert/`` (give another
checkout's, e.g. a ``git worktree`` of an older commit, to compare). With
``--cycles`` only the summary and the cycles are printed.

How the graph is read (tests/test_layers.py checks the same graph):

* Every ``import`` and ``from ... import`` of every module counts, wherever it
  stands: at the top, inside a function (marked ``lazy``) or under
  ``if TYPE_CHECKING:`` (marked ``typing``). Relative imports are resolved
  against the importing module's package.
* ``from P import name`` is an edge to the submodule ``P.name`` when there is
  one, else to ``P``. Importing ``P.sub`` is an edge to ``P.sub`` only: Python
  runs ``P/__init__.py`` first, but a package's ``__init__`` importing its own
  submodules while they import from it is how every package assembles itself,
  not a circle.
* Re-exports. A package ``__init__`` that imports a name from one of its own
  submodules and never uses it in its own code (a public name offered at the
  top, often under ``TYPE_CHECKING`` for a lazily imported name) re-exports
  it: that import is no edge of the ``__init__``, and a module importing the
  name from the package gets an edge to the module that defines it. So a
  cycle through an ``__init__`` is reported only when it is a real one: the
  ``__init__`` uses what it imports (a table built from its submodules'
  functions), or the importer takes a name the ``__init__`` defines itself.
* Imports by string (``importlib.import_module``, the registries' lazy
  ``"package.module:function"`` targets) are not followed: they are resolved on
  first use, once every module involved has finished importing.

A cycle is a strongly connected component of two or more modules (or a module
importing itself); for each, the modules and one shortest circle through each
of its modules are printed.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

#: Compiled extension modules of the package (built from src/ into the
#: installed package, so not found among the sources).
COMPILED = ("_native",)


@dataclass(frozen=True)
class Edge:
    """One import of a module of the package by another.

    Attributes
    ----------
    source, target : str
        Dotted module names (a package is its ``__init__``).
    line : int
        Of the import statement in ``source``.
    kind : str
        ``top`` (runs when ``source`` is imported), ``lazy`` (inside a function)
        or ``typing`` (under ``if TYPE_CHECKING:``, never run).
    """

    source: str
    target: str
    line: int
    kind: str


@dataclass
class Graph:
    """Modules of a package and the imports among them.

    Attributes
    ----------
    modules : dict of str to Path
        Dotted name -> source file (compiled modules map to None).
    packages : set of str
        Names of the modules that are packages.
    edges : list of Edge
    external : dict of str to set of str
        Module -> the top-level names of the packages outside this one it
        imports (``numpy``, ``dask``), of any kind.
    """

    modules: dict[str, Path | None]
    packages: set[str]
    edges: list[Edge] = field(default_factory=list)
    external: dict[str, set[str]] = field(default_factory=dict)

    def imports(self, kinds: tuple[str, ...] = ("top", "lazy", "typing")) -> dict[str, set[str]]:
        """Module -> the modules it imports (edges of the given kinds)."""
        out: dict[str, set[str]] = {name: set() for name in self.modules}
        for edge in self.edges:
            if edge.kind in kinds:
                out[edge.source].add(edge.target)
        return out

    def reachable(self, start: str) -> dict[str, list[str]]:
        """Modules ``start`` imports, directly or not -> a shortest import chain there."""
        graph = self.imports()
        paths = {start: [start]}
        queue = deque([start])
        while queue:
            name = queue.popleft()
            for target in sorted(graph[name]):
                if target not in paths:
                    paths[target] = [*paths[name], target]
                    queue.append(target)
        del paths[start]
        return paths


def _module_names(root: Path) -> tuple[dict[str, Path | None], set[str]]:
    package = root.name
    modules: dict[str, Path | None] = {}
    packages: set[str] = set()
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
            packages.add(".".join(parts))
        modules[".".join(parts)] = path
    for name in COMPILED:
        modules[f"{package}.{name}"] = None
    return modules, packages


class _Imports(ast.NodeVisitor):
    """The import statements of one module, with where they stand."""

    def __init__(self) -> None:
        self.found: list[tuple[ast.Import | ast.ImportFrom, str]] = []
        self._kind = ["top"]

    def visit_If(self, node: ast.If) -> None:
        test = node.test
        name = test.id if isinstance(test, ast.Name) else getattr(test, "attr", None)
        if name == "TYPE_CHECKING":
            self._kind.append("typing")
            for child in node.body:
                self.visit(child)
            self._kind.pop()
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    def _function(self, node: ast.AST) -> None:
        self._kind.append("typing" if self._kind[-1] == "typing" else "lazy")
        self.generic_visit(node)
        self._kind.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = visit_Lambda = _function

    def visit_Import(self, node: ast.Import) -> None:
        self.found.append((node, self._kind[-1]))

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        self.found.append((node, self._kind[-1]))


def _base(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module a ``from`` import names."""
    if not node.level:
        return node.module or ""
    parts = module.split(".")
    if not is_package:
        parts.pop()
    if node.level > 1:
        parts = parts[: len(parts) - (node.level - 1)]
    return ".".join([*parts, node.module] if node.module else parts)


def _used_names(tree: ast.Module) -> set[str]:
    """Names the module's own code reads (not the strings of ``__all__``)."""
    return {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}


def build(root: str | Path) -> Graph:
    """The import graph of the package in folder ``root``."""
    root = Path(root).resolve()
    modules, packages = _module_names(root)
    parsed = {
        name: ast.parse(path.read_text(encoding="utf-8"), str(path))
        for name, path in modules.items()
        if path is not None
    }
    found = {}
    for name, tree in parsed.items():
        visitor = _Imports()
        visitor.visit(tree)
        found[name] = visitor.found

    # Re-exports: package -> {name offered: (module it comes from, its name there)}
    reexports: dict[str, dict[str, tuple[str, str]]] = {}
    for package in packages:
        used = _used_names(parsed[package])
        offered = reexports.setdefault(package, {})
        for node, _ in found[package]:
            if not isinstance(node, ast.ImportFrom):
                continue
            base = _base(package, True, node)
            if not base.startswith(package + "."):
                continue
            for alias in node.names:
                bound = alias.asname or alias.name
                if alias.name != "*" and bound not in used:
                    offered[bound] = (base, alias.name)

    def definer(base: str, name: str, seen: frozenset = frozenset()) -> str:
        """The module that ``from base import name`` really takes ``name`` from."""
        if f"{base}.{name}" in modules:
            return f"{base}.{name}"
        source = reexports.get(base, {}).get(name)
        if source is None or (base, name) in seen:
            return base
        return definer(*source, seen | {(base, name)})

    graph = Graph(modules, packages)
    for name, statements in found.items():
        offered = reexports.get(name, {})
        for node, kind in statements:
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = _base(name, name in packages, node)
                for alias in node.names:
                    bound = alias.asname or alias.name
                    if offered.get(bound) == (base, alias.name):
                        continue  # a re-export: not an edge of this __init__
                    targets.append(base if alias.name == "*" else definer(base, alias.name))
            for target in targets:
                if target.split(".")[0] != root.name:
                    graph.external.setdefault(name, set()).add(target.split(".")[0])
                    continue
                while target and target not in modules:  # a name, not a module
                    target = target.rpartition(".")[0]
                if target:
                    graph.edges.append(Edge(name, target, node.lineno, kind))
    return graph


def cycles(graph: Graph) -> list[list[str]]:
    """The strongly connected components of two or more modules (or with a
    self-import), each sorted, largest first (Tarjan's algorithm)."""
    edges = graph.imports()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        # iterative DFS: (node, iterator over its targets)
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, targets = work[-1]
            advanced = False
            for target in targets:
                if target not in index:
                    index[target] = low[target] = counter
                    counter += 1
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(edges[target]))))
                    advanced = True
                    break
                if target in on_stack:
                    low[node] = min(low[node], index[target])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in edges[node]:
                    found.append(sorted(component))
    return sorted(found, key=lambda c: (-len(c), c))


def shortest_cycle(graph: Graph, start: str, within: set[str]) -> list[str]:
    """A shortest circle of imports from ``start`` back to it, inside ``within``."""
    edges = graph.imports()
    paths = {start: [start]}
    queue = deque([start])
    while queue:
        name = queue.popleft()
        for target in sorted(edges[name] & within):
            if target == start:
                return [*paths[name], start]
            if target not in paths:
                paths[target] = [*paths[name], target]
                queue.append(target)
    return []


def _short(name: str, package: str) -> str:
    return name[len(package) + 1 :] if name.startswith(package + ".") else name


def describe(graph: Graph, only_cycles: bool = False) -> str:
    """The graph as text: modules and their imports, then the cycles."""
    package = min(graph.modules, key=len)
    lines = []
    if not only_cycles:
        by_source: dict[str, dict[str, set[str]]] = {name: {} for name in graph.modules}
        for edge in graph.edges:
            by_source[edge.source].setdefault(edge.target, set()).add(edge.kind)
        for name in sorted(graph.modules):
            targets = by_source[name]
            shown = [
                _short(t, package) + ("" if "top" in kinds else f" ({'/'.join(sorted(kinds))})")
                for t, kinds in sorted(targets.items())
            ]
            lines.append(f"{_short(name, package) or package} -> {', '.join(shown) or '-'}")
        lines.append("")
    found = cycles(graph)
    n_edges = len({(e.source, e.target) for e in graph.edges})
    lines.append(
        f"{len(graph.modules)} modules, {n_edges} imports between them, "
        f"{len(found)} import cycle(s)"
        + (f" joining {sum(map(len, found))} modules" if found else "")
    )
    for n, component in enumerate(found, 1):
        members = set(component)
        lines.append(f"cycle {n}: {len(component)} modules: {', '.join(component)}")
        circles = []
        for name in component:
            circle = shortest_cycle(graph, name, members)
            # the same circle from another start is the same circle
            key = frozenset(zip(circle, circle[1:], strict=False))
            if circle and key not in {k for k, _ in circles}:
                circles.append((key, circle))
        for _, circle in circles:
            lines.append("  " + " -> ".join(_short(m, package) for m in circle))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "package",
        nargs="?",
        default=str(Path(__file__).resolve().parents[1] / "isoconvert"),
        help="the package folder (default: this checkout's isoconvert/)",
    )
    parser.add_argument("--cycles", action="store_true", help="print only the cycles")
    args = parser.parse_args(argv)
    print(describe(build(args.package), args.cycles))
    return 0


if __name__ == "__main__":
    sys.exit(main())
