"""Third-party extractors through the ``isoconvert.extractors`` entry-point group."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES

from isoconvert import EXTRACTORS, IsoconvertError, extract, read_volume
from isoconvert.cli import main

PLUGIN = '''
"""A tiny extractor: the bounding box of the positive samples."""
import numpy as np
from isoconvert import Mesh
from isoconvert.extract import Extractor


def bbox(volume, level, *, flip, ambiguity, nan_as, on_status):
    """Bounding box of the samples >= level, as 12 outward triangles."""
    idx = np.argwhere(volume.data >= level)
    lo, hi = idx.min(axis=0).astype(float), idx.max(axis=0).astype(float)
    corners = np.array([[(hi if (v >> a) & 1 else lo)[a] for a in range(3)] for v in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    if flip:
        tris = tris[:, ::-1]
    return Mesh(volume.index_to_world(corners), tris, info={"method": "bbox", "level": level})


EXTRACTOR = Extractor("bbox", "bounding box of the positive samples", (3,), bbox)


def broken(volume, level, **kw):
    """Returns something that is not a mesh."""
    return "not a mesh"
'''


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    (tmp_path / "tinyplug.py").write_text(textwrap.dedent(PLUGIN))
    dist = tmp_path / "tinyplug-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tinyplug\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[isoconvert.extractors]\nbbox = tinyplug:EXTRACTOR\nbroken = tinyplug:broken\n"
        "missing = tinyplug_nowhere:run\ncubes = tinyplug:broken\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    EXTRACTORS.reload_plugins()
    yield
    monkeypatch.undo()
    EXTRACTORS.reload_plugins()


def test_plugin_is_listed_and_used(plugin, tmp_path, capsys):
    assert {"bbox", "broken", "missing"} <= set(EXTRACTORS.names())
    vol = read_volume(SAMPLES / "sphere.nrrd")
    mesh = extract(vol, 127.5, method="bbox")
    inside = np.argwhere(vol.data >= 127.5)
    assert np.allclose(mesh.vertices.min(axis=0), inside.min(axis=0))
    tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    assert tm.is_watertight and tm.volume > 0
    # from the command line too
    assert main(["methods"]) == 0
    assert "bbox" in capsys.readouterr().out
    out = tmp_path / "box.ply"
    assert (
        main(
            [
                "convert",
                str(SAMPLES / "sphere.nrrd"),
                "-l",
                "127.5",
                "--method",
                "bbox",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    assert len(trimesh.load(out, process=False).faces) == 12


def test_built_in_names_win_over_plugins(plugin):
    vol = read_volume(SAMPLES / "sphere.nrrd")
    assert extract(vol, 127.5, method="cubes").n_cells > 12


def test_broken_plugins_fail_with_one_line(plugin):
    vol = read_volume(SAMPLES / "sphere.nrrd")
    with pytest.raises(IsoconvertError, match="not a valid Mesh"):
        extract(vol, 127.5, method="broken")
    with pytest.raises(IsoconvertError, match="plugin 'missing'.*failed to load"):
        extract(vol, 127.5, method="missing")


def test_unknown_method_lists_the_choices():
    with pytest.raises(IsoconvertError, match="choose one of: cubes, tetra, squares"):
        extract(read_volume(SAMPLES / "sphere.nrrd"), 127.5, method="nope")


def test_convert_help_lists_the_plugin_methods(plugin, capsys):
    """--method's help names the installed methods, plugins included, though a run
    that shows no help never looks the plugins up (isoconvert.cli.options.METHOD_NAMES)."""
    assert main(["convert", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "cubes, tetra, squares" in out and "bbox" in out
    assert "<the extraction methods>" not in out


def test_a_run_looks_no_plugins_up(tmp_path):
    import subprocess
    import sys

    script = (
        "import sys\n"
        "from isoconvert.cli import main\n"
        f"code = main(['convert', {str(SAMPLES / 'sphere.nrrd')!r}, '-l', '127.5', '-q',\n"
        f"             '-o', {str(tmp_path / 's.ply')!r}])\n"
        "assert code == 0, code\n"
        "print('importlib.metadata' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False"]
