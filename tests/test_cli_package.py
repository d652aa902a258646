"""The command line as a package (issue 21): ``isoconvert.cli`` and its modules are
the only ones importing typer, rich or click, its command modules never import the
package's ``__init__`` (it registers them, so the package cannot circle), and every
name the old single module offered to tests and scripts is still there.

The import graph is read from the sources by bench/import_graph.py, as in
tests/test_layers.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import load_import_graph

ROOT = Path(__file__).resolve().parents[1]
SHELL_LIBRARIES = {"typer", "rich", "click"}


@pytest.fixture(scope="module")
def graph():
    return load_import_graph().build(ROOT / "isoconvert")


def _in_cli(name: str) -> bool:
    return name == "isoconvert.cli" or name.startswith("isoconvert.cli.")


def test_only_the_cli_imports_typer_rich_or_click(graph):
    users = {name for name, names in graph.external.items() if names & SHELL_LIBRARIES}
    # the check sees them where they are: the app, the commands, the progress display
    assert {"isoconvert.cli", "isoconvert.cli.convert_cmd", "isoconvert.cli.display"} <= users
    assert "rich" in graph.external["isoconvert.cli.display"]
    assert sorted(name for name in users if not _in_cli(name)) == []


def test_the_cli_modules_never_import_the_cli_package(graph):
    """Only the entry points (the console script's, ``python -m``) import
    ``isoconvert.cli`` itself."""
    importers = sorted(e.source for e in graph.edges if e.target == "isoconvert.cli")
    assert importers == ["isoconvert.cli.__main__", "isoconvert.entry"]


def test_the_names_of_the_old_module_are_offered():
    import isoconvert.cli as cli

    for name in ("main", "run", "app", "gather_multi_values", "EXIT_CHECK_FAILED"):
        assert hasattr(cli, name), name
    assert cli.EXIT_CHECK_FAILED == 4
    assert callable(cli.run)
    # the console script's target: the light entry point, which then runs cli.main
    text = (ROOT / "pyproject.toml").read_text()
    assert 'isoconvert = "isoconvert.entry:run"' in text


def test_the_commands_are_registered_once_each_on_the_one_app():
    from typer.main import get_command

    from isoconvert.cli import app

    group = get_command(app)
    names = [c.callback.__name__ for c in app.registered_commands]
    assert len(names) == len(set(names))
    visible = [n for n in group.list_commands(None) if not group.commands[n].hidden]
    # the order --help lists them in (as before the split)
    assert visible == ["convert", "check", "preview", "batch", "info", "formats", "methods"]


def test_a_run_builds_and_imports_only_its_own_command():
    """``isoconvert convert ...`` needs neither batch's module nor the other commands'
    options; the help still lists every command."""
    import subprocess
    import sys

    from typer.main import get_command

    from isoconvert.cli import typer_app

    only = get_command(typer_app("convert"))
    assert only.list_commands(None) == ["convert"]
    code = (
        "import sys; from isoconvert.cli import main; "
        "code = main(['convert', 'no-such-file.npy', '--level', '1', '-o', 'x.ply']); "
        "print(code, 'isoconvert.cli.batch_cmd' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.split() == ["1", "False"], done.stderr
    assert "no-such-file.npy" in done.stderr  # the command did run: its one-line error
    code = "from isoconvert.cli import main; main(['--help'])"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    for name in ("convert", "check", "preview", "batch", "info", "formats", "methods"):
        assert f" {name} " in done.stdout, name
