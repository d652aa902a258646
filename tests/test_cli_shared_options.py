"""convert and batch share their option groups (issue 21): the same options, with
the same help, type and default, turned into the same ConvertOptions."""

from __future__ import annotations

from dataclasses import replace
from importlib import import_module

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES
from typer.main import get_command

from isoconvert.cli import app, main
from isoconvert.errors import IsoconvertError

SPHERE = str(SAMPLES / "sphere.nrrd")
RAW = str(SAMPLES / "sphere_40x40x40_uint8.raw")

#: Options only convert has, and why batch has none.
CONVERT_ONLY = {
    "input": "one volume (batch: inputs)",
    "output": "-o: the mesh file (batch: out_dir, a folder)",
    "report": "one report per mesh (batch: --summary, and --require per file)",
    "examples": "goes with --report",
    "preview": "one picture at a name given (batch: --previews, one beside each mesh)",
    "values": "one volume sampled at the vertices of one mesh",
    "input_format": "batch picks each file's reader by its suffix as it finds the files",
    "series": "batch converts every series of a DICOM folder (a --levels entry may pick one)",
}
#: Options only batch has.
BATCH_ONLY = {
    "inputs": "files, folders and globs",
    "out_dir": "-o: the folder for the meshes",
    "levels": "a level mapping for many files",
    "recursive": "searching folders",
    "jobs": "worker processes",
    "skip_existing": "resuming a run",
    "summary": "the table of many results",
    "images": "whether 2D images among the inputs are contoured",
    "previews": "a thumbnail per mesh and a contact sheet",
}


def params(command: str) -> dict:
    """The click parameters of ``command``, by name."""
    return {p.name: p for p in get_command(app).commands[command].params}


def described(param) -> dict:
    """What a user sees of an option: flags, help, panel, type, default, and how it takes values."""
    return {
        "flags": (tuple(param.opts), tuple(param.secondary_opts)),
        "help": getattr(param, "help", None),
        "panel": getattr(param, "rich_help_panel", None),
        "type": param.type.to_info_dict() if hasattr(param, "type") else None,
        "default": param.default,
        "metavar": param.metavar,
        "flag": getattr(param, "is_flag", None),
        "multiple": param.multiple,
        "required": param.required,
    }


def test_convert_and_batch_declare_the_shared_options_alike():
    convert, batch = params("convert"), params("batch")
    assert set(convert) - set(batch) == set(CONVERT_ONLY)
    assert set(batch) - set(convert) == set(BATCH_ONLY)
    shared = sorted(set(convert) & set(batch))
    assert len(shared) > 40  # the groups: read, extract, mesh, post, memory, labels
    for name in shared:
        assert described(convert[name]) == described(batch[name]), name


def test_every_option_has_its_own_help_text():
    for command in ("convert", "batch"):
        for name, param in params(command).items():
            assert getattr(param, "help", None) or param.param_type_name == "argument", name


# --- the same ConvertOptions ----------------------------------------------------------------

#: Shared options with each command's own meaning: one file's blocks in convert,
#: the budget of all files running at once (and a task per file) in batch.
OWN_MEANING = {"max_memory", "scheduler"}
#: Shared options that are no conversion option.
NOT_CONVERSION = {"level", "force", "quiet", "verbose", "require", "help"}

#: Command lines of shared options (for a level, or a label volume).
CASES = [
    ["--method", "tetra", "--flip", "--ambiguity", "separate-negative", "--nan-as", "0"],
    ["--method", "squares", "--axis", "y", "--no-degenerate"],
    ["--exact-placement", "--ascii", "--normals", "--space", "ras"],
    ["--spacing", "1", "2", "3", "--origin", "4", "5", "6", "--channel", "1", "--scale", "2"],
    ["--key", "a", "--volume-index", "3", "--allow-outside-data", "--allow-missing-chunks"],
    ["--close", "--keep", "2", "--min-size", "3", "--min-volume", "1.5", "--fill-cavities"],
    ["--smooth", "4", "--smooth-method", "taubin", "--passband", "0.2", "--max-error", "0.1"],
    ["--largest", "--decimate", "0.5", "--block-size", "8"],
    ["--labels", "--label", "3,7", "--single-file", "--background", "2", "--smooth", "5"],
    ["--label", "4"],
    ["--labels", "--format", "precomputed", "--lods", "2", "--fragment-size", "32", "--sharded"],
    ["--labels", "--format", "precomputed", "--legacy-mesh", "--with-volume"],
    ["--shape", "40", "40", "40", "--dtype", "uint8", "--endian", "big", "--header-bytes", "0"],
]


class Stop(IsoconvertError):
    """Raised in place of the conversion, once its options are seen."""


def options_of(monkeypatch, tmp_path, command: str, args: list[str]):
    """The ConvertOptions ``isoconvert COMMAND VOLUME ... ARGS`` converts with (batch:
    those of its file, with the raw layout, which only raw files are given)."""
    seen = []

    def stop(input, output, levels, options, **kwargs):
        seen.append(options)
        raise Stop("stop")

    def record(work, settings, workers, budget, on_done):
        (job,) = work
        seen.append(settings.options.updated(**job.options))
        return []

    # the modules (the package's own names `convert` and `batch` are functions)
    monkeypatch.setattr(import_module("isoconvert.convert"), "convert_levels", stop)
    monkeypatch.setattr(import_module("isoconvert.label_convert"), "convert_labels", stop)
    monkeypatch.setattr(import_module("isoconvert.batch"), "run_jobs", record)
    level = [] if any(a.startswith("--label") for a in args) else ["-l", "127.5"]
    out = tmp_path / command / ("m.ply" if command == "convert" else "")
    volume = RAW if "--shape" in args else SPHERE
    code = main([command, volume, "-o", str(out), "--format", "ply", "-q", *level, *args])
    assert code == (1 if command == "convert" else 0)
    (options,) = seen
    return options


def test_the_cases_give_every_shared_conversion_option():
    given = {a[2:].replace("-", "_") for case in CASES for a in case if a.startswith("--")}
    shared = set(params("convert")) & set(params("batch"))
    # --format: batch gives it as a whole (the file name has no suffix); a case names it
    assert given - {"format"} == shared - OWN_MEANING - NOT_CONVERSION - {"format"}


@pytest.mark.parametrize("args", CASES, ids=" ".join)
def test_convert_and_batch_build_the_same_conversion_options(monkeypatch, tmp_path, args):
    by_convert = options_of(monkeypatch, tmp_path, "convert", args)
    by_batch = options_of(monkeypatch, tmp_path, "batch", args)
    assert by_convert.blocks.size == by_batch.blocks.size
    # the blocks' budget and scheduler are each command's own
    assert replace(by_convert, blocks=None) == replace(by_batch, blocks=None)
    # and the options said something
    plain = options_of(monkeypatch, tmp_path / "plain", "convert", [])
    assert replace(by_convert, blocks=None) != replace(plain, blocks=None) or (
        by_convert.blocks.size != plain.blocks.size
    )


# --- options batch shares now, at work ------------------------------------------------------


def noise_volume(tmp_path, nan: bool = False) -> str:
    """A 9^3 float32 volume of noise (many ambiguous faces), with NaNs if asked."""
    data = np.random.default_rng(21).random((9, 9, 9)).astype(np.float32)
    if nan:
        data[2:4, 3, 5] = np.nan
    path = tmp_path / "in" / "noise.npy"
    path.parent.mkdir()
    np.save(path, data)
    return str(path)


def mesh_arrays(path) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(path, process=False)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.mark.parametrize(
    "args",
    [
        ["--ambiguity", "separate-negative"],
        ["--nan-as", "0.75"],
        ["--origin", "1", "-2", "3", "--block-size", "3"],
    ],
    ids=" ".join,
)
def test_batch_converts_as_convert_does_with_the_options_it_gained(tmp_path, capsys, args):
    volume = noise_volume(tmp_path, nan="--nan-as" in args)
    alone = tmp_path / "alone.ply"
    assert main(["convert", volume, "-o", str(alone), "-l", "0.5", "-q", *args]) == 0
    assert main(["batch", volume, "-o", str(tmp_path / "out"), "-l", "0.5", "-q", *args]) == 0
    vertices, faces = mesh_arrays(alone)
    batch_vertices, batch_faces = mesh_arrays(tmp_path / "out" / "noise.ply")
    np.testing.assert_array_equal(batch_vertices, vertices)
    np.testing.assert_array_equal(batch_faces, faces)
    plain = tmp_path / "plain.ply"
    code = main(["convert", volume, "-o", str(plain), "-l", "0.5", "-q"])
    if "--origin" in args:  # the same mesh, moved by the origin (spacing 1)
        plain_vertices, plain_faces = mesh_arrays(plain)
        np.testing.assert_array_equal(plain_faces, faces)
        np.testing.assert_allclose(vertices, plain_vertices + [1, -2, 3], atol=1e-5)
    else:  # without the option, another mesh (or none at all, for NaN samples)
        assert code != 0 or not np.array_equal(mesh_arrays(plain)[1], faces)
    capsys.readouterr()
