"""Issue 20: no output ever replaces a file being read; streams are written in place;
output names are checked before the work.

Each input format is written here file by file, so the test knows which files
make it up without asking the reader; every one of them is then given as
``-o ... --force`` and must be refused in one line with the file unchanged.
"""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys
from pathlib import Path

import nrrd
import numpy as np
import pytest
import tifffile
import trimesh
from conftest import SAMPLES, ball
from test_cli import assert_one_line_error, run
from test_readers_dicom import write_series

SPHERE = str(SAMPLES / "sphere.nrrd")


def field_zyx(n: int = 12) -> np.ndarray:
    """(n, n, n) uint8 ball, C order (z, y, x)."""
    return (np.clip(ball(n, n / 3), 0, 1) * 200).astype(np.uint8)


def _nhdr_numbered(folder: Path) -> tuple[Path, list[Path]]:
    zyx = field_zyx()
    parts = []
    for k in range(zyx.shape[0]):
        part = folder / f"quarter.{k + 1}"
        part.write_bytes(zyx[k].tobytes())
        parts.append(part)
    header = folder / "quarter.nhdr"
    n = zyx.shape[0]
    header.write_text(
        "NRRD0004\ntype: uint8\ndimension: 3\n"
        f"sizes: {n} {n} {n}\nencoding: raw\ndata file: quarter.%d 1 {n} 1\n"
    )
    return header, [header, *parts]


def _nhdr_single(folder: Path) -> tuple[Path, list[Path]]:
    zyx = field_zyx()
    data = folder / "vol.raw"
    data.write_bytes(zyx.tobytes())
    header = folder / "vol.nhdr"
    n = zyx.shape[0]
    header.write_text(
        "NRRD0004\ntype: uint8\ndimension: 3\n"
        f"sizes: {n} {n} {n}\nencoding: raw\ndata file: vol.raw\n"
    )
    return header, [header, data]


def _nrrd(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "vol.nrrd"
    nrrd.write(str(path), field_zyx().T.copy(order="F"), index_order="F")
    return path, [path]


def _raw(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "vol_12x12x12_uint8.raw"
    path.write_bytes(field_zyx().tobytes())
    return path, [path]


def _mhd(folder: Path) -> tuple[Path, list[Path]]:
    data = folder / "vol.raw"
    data.write_bytes(field_zyx().tobytes())
    header = folder / "vol.mhd"
    header.write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 12 12 12\nElementType = MET_UCHAR\n"
        "ElementSpacing = 1 1 1\nElementDataFile = vol.raw\n"
    )
    return header, [header, data]


def _mhd_numbered(folder: Path) -> tuple[Path, list[Path]]:
    zyx = field_zyx()
    parts = []
    for k in range(zyx.shape[0]):
        part = folder / f"slice{k + 1:03d}.raw"
        part.write_bytes(zyx[k].tobytes())
        parts.append(part)
    header = folder / "vol.mhd"
    header.write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 12 12 12\nElementType = MET_UCHAR\n"
        "ElementSpacing = 1 1 1\nElementDataFile = slice%03d.raw 1 12 1\n"
    )
    return header, [header, *parts]


def _mha(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "vol.mha"
    header = (
        "ObjectType = Image\nNDims = 3\nDimSize = 12 12 12\nElementType = MET_UCHAR\n"
        "ElementSpacing = 1 1 1\nElementDataFile = LOCAL\n"
    )
    path.write_bytes(header.encode() + field_zyx().tobytes())
    return path, [path]


def _png(folder: Path) -> tuple[Path, list[Path]]:
    from PIL import Image

    path = folder / "slice.png"
    Image.fromarray(field_zyx()[6]).save(path)
    return path, [path]


def _tiff_file(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "stack.tif"
    tifffile.imwrite(path, field_zyx())
    return path, [path]


def _tiff_folder(folder: Path) -> tuple[Path, list[Path]]:
    slices = folder / "slices"
    slices.mkdir()
    files = []
    for k, page in enumerate(field_zyx()):
        files.append(slices / f"img_{k:02d}.tif")
        tifffile.imwrite(files[-1], page)
    return slices, files


def _npy(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "vol.npy"
    np.save(path, field_zyx())
    return path, [path]


def _npz(folder: Path) -> tuple[Path, list[Path]]:
    path = folder / "vol.npz"
    np.savez_compressed(path, volume=field_zyx())
    return path, [path]


def _nifti(folder: Path) -> tuple[Path, list[Path]]:
    nib = pytest.importorskip("nibabel")
    path = folder / "vol.nii.gz"
    nib.save(nib.Nifti1Image(field_zyx().T.copy(), np.eye(4)), str(path))
    return path, [path]


def _dicom(folder: Path) -> tuple[Path, list[Path]]:
    pytest.importorskip("pydicom")
    series = folder / "series"
    series.mkdir()
    write_series(series, field_zyx()[:5].astype(np.int16))
    return series, sorted(series.iterdir())


INPUTS = {
    "nrrd": _nrrd,
    "nhdr-numbered": _nhdr_numbered,
    "nhdr-single": _nhdr_single,
    "raw": _raw,
    "metaimage": _mhd,
    "metaimage-numbered": _mhd_numbered,
    "metaimage-local": _mha,
    "image": _png,
    "tiff-file": _tiff_file,
    "tiff-folder": _tiff_folder,
    "npy": _npy,
    "npz": _npz,
    "nifti": _nifti,
    "dicom": _dicom,
}


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("kind", sorted(INPUTS))
def test_no_file_of_the_input_can_be_the_output(tmp_path, capsys, kind):
    source, files = INPUTS[kind](tmp_path)
    before = {f: digest(f) for f in files}
    for target in files:
        code, out, err = run(
            capsys, "convert", source, "-l", "100.5", "-o", target, "--format", "ply", "--force"
        )
        assert_one_line_error(code, err, str(target))
        assert "destroy" in err or "being read" in err, err
        assert {f: digest(f) for f in files} == before, target
    leftovers = [p for p in tmp_path.rglob("*") if p.name.startswith(".")]
    assert leftovers == []


@pytest.mark.parametrize("link", ["symlink", "hardlink"])
def test_a_link_to_a_data_file_is_refused_and_the_file_kept(tmp_path, capsys, link):
    header, files = _nhdr_numbered(tmp_path)
    data = files[3]
    data.chmod(0o444)  # read-only: as root, that alone never stopped the rename
    alias = tmp_path / "other" / "alias.ply"
    alias.parent.mkdir()
    if link == "symlink":
        alias.symlink_to(data)
    else:
        os.link(data, alias)
    before = digest(data)
    code, _, err = run(capsys, "convert", header, "-l", "100.5", "-o", alias, "--force")
    assert_one_line_error(code, err, str(alias), str(data))
    assert digest(data) == before
    assert os.path.islink(alias) == (link == "symlink")


def test_values_volume_files_are_inputs_too(tmp_path, capsys):
    values, files = _nhdr_single(tmp_path)
    before = digest(files[1])
    code, _, err = run(
        capsys,
        "convert",
        SPHERE,
        "-l",
        "127.5",
        "--values",
        values,
        "-o",
        files[1],
        "--format",
        "ply",
        "--force",
    )
    assert_one_line_error(code, err, str(files[1]))
    assert digest(files[1]) == before


def test_a_report_naming_the_input_is_refused_before_the_work(tmp_path, capsys):
    header, files = _nhdr_single(tmp_path)
    out = tmp_path / "mesh.ply"
    code, _, err = run(
        capsys, "convert", header, "-l", "100.5", "-o", out, f"--report={files[1]}", "--force"
    )
    assert_one_line_error(code, err, str(files[1]))
    assert not out.exists()


def test_check_report_onto_the_mesh_is_refused(tmp_path, capsys):
    mesh = tmp_path / "ball.ply"
    assert run(capsys, "convert", SPHERE, "-l", "127.5", "-o", mesh)[0] == 0
    before = digest(mesh)
    code, _, err = run(capsys, "check", mesh, "--report", mesh, "--force")
    assert_one_line_error(code, err, str(mesh), "destroy")
    assert digest(mesh) == before


def test_info_plot_onto_the_volume_is_refused(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    header, files = _nhdr_single(tmp_path)
    before = digest(files[1])
    code, _, err = run(capsys, "info", header, "--plot", files[1], "--force")
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert digest(files[1]) == before


def test_preview_onto_the_mesh_is_refused(tmp_path, capsys):
    pytest.importorskip("vtk")
    mesh = tmp_path / "ball.png"  # a PLY mesh named .png: the preview's name check passes
    assert run(capsys, "convert", SPHERE, "-l", "127.5", "-o", mesh, "--format", "ply")[0] == 0
    before = digest(mesh)
    code, _, err = run(capsys, "preview", mesh, "-o", mesh, "--force")
    assert code == 1 and digest(mesh) == before, err


def _command(*args) -> list[str]:
    return [sys.executable, "-m", "isoconvert", *map(str, args)]


def test_dev_stdout_reaches_the_redirected_file_and_stays_a_link(tmp_path):
    target = tmp_path / "redirected.ply"
    reference = tmp_path / "reference.ply"
    before = os.lstat("/dev/stdout")
    with open(target, "wb") as out:
        done = subprocess.run(
            _command("convert", SPHERE, "-l", "127.5", "-o", "/dev/stdout", "--format", "ply"),
            stdout=out,
            stderr=subprocess.PIPE,
            cwd=tmp_path,
            check=False,
        )
    assert done.returncode == 0, done.stderr
    assert b"wrote /dev/stdout" in done.stderr  # messages go to stderr, not into the mesh
    after = os.lstat("/dev/stdout")
    assert stat.S_ISLNK(after.st_mode) and after.st_ino == before.st_ino
    subprocess.run(_command("convert", SPHERE, "-l", "127.5", "-o", reference), check=True)
    assert target.read_bytes() == reference.read_bytes()


def test_dev_stdout_into_a_pipe_gives_the_same_mesh(tmp_path):
    done = subprocess.run(
        _command("convert", SPHERE, "-l", "127.5", "-o", "/dev/stdout", "--format", "stl"),
        capture_output=True,
        cwd=tmp_path,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    piped = tmp_path / "piped.stl"
    piped.write_bytes(done.stdout)
    mesh = trimesh.load(piped, process=True)
    assert mesh.is_watertight and len(mesh.faces) == 7388  # the sphere's count, as in test_cli
    assert os.listdir(tmp_path) == ["piped.stl"]


def test_a_block_device_is_never_written(tmp_path, capsys):
    devices = [Path("/dev") / n for n in ("loop0", "vda", "sda", "nvme0n1")]
    device = next((d for d in devices if d.exists() and stat.S_ISBLK(d.stat().st_mode)), None)
    if device is None:
        pytest.skip("no block device node to aim at")
    before = os.stat(device)
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", device, "--format", "ply",
                       "--force")  # fmt: skip
    assert_one_line_error(code, err, str(device), "not a regular file")
    assert os.stat(device).st_ino == before.st_ino


@pytest.mark.parametrize("length", [241, 250, 255])
def test_long_names_that_fit_are_written(tmp_path, capsys, length):
    out = tmp_path / ("é" * ((length - 4) // 2) + "x" * ((length - 4) % 2) + ".ply")
    assert len(os.fsencode(out.name)) == length
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", out)
    assert code == 0, err
    assert len(trimesh.load(out, process=False).faces) == 7388
    assert os.listdir(tmp_path) == [out.name]


def test_a_name_too_long_fails_before_the_work(tmp_path, capsys, monkeypatch):
    out = tmp_path / ("a" * 256 + ".ply")
    import importlib

    convert_module = importlib.import_module("isoconvert.convert")  # not the function

    def never(*args, **kwargs):
        raise AssertionError("the volume was read")

    monkeypatch.setattr(convert_module, "read_input", never)
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", out)
    assert_one_line_error(code, err, "260 bytes", "255")
    assert os.listdir(tmp_path) == []


def test_check_help_names_every_format_check_reads(capsys):
    from isoconvert.meshfile import MESH_SUFFIXES

    assert main_help(capsys, "check")
    text = capsys.readouterr().out
    for suffix in MESH_SUFFIXES:
        assert suffix[1:].upper() in text, suffix


def main_help(capsys, command: str) -> bool:
    from isoconvert.cli import main

    return main([command, "--help"]) == 0


@pytest.mark.parametrize("command", ["convert", "batch"])
def test_level_reads_as_a_number_in_help_and_a_word_is_a_usage_error(capsys, command):
    assert main_help(capsys, command)
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if "--level " in line and " -l " in line)
    assert "<number|auto>" in row and "list[" not in row  # no Python type for a user
    args = [command, SPHERE, "-o", "out", "-l", "abc"]
    code, _, err = run(capsys, *args)
    smooth_code, _, _ = run(capsys, command, SPHERE, "-o", "out", "-l", "1", "--smooth", "abc")
    assert code == smooth_code == 2  # a word where a number goes, like any other number option
    assert len(err.strip().splitlines()) == 1 and "'abc'" in err


def test_verbose_stage_times_add_up_and_bill_post_processing_to_itself(tmp_path, capsys,
                                                                      monkeypatch):  # fmt: skip
    import importlib
    import time

    convert_module = importlib.import_module("isoconvert.convert")
    real = convert_module.post_process

    def slow(*args, **kwargs):
        time.sleep(1.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(convert_module, "post_process", slow)
    out = tmp_path / "s.ply"
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", out, "--smooth", "5", "-v")
    assert code == 0, err
    times = {}
    for line in err.splitlines():
        seconds, _, stage = line.strip().partition(" s  ")
        if stage:
            times[stage] = float(seconds)
    assert list(times) == ["reading", "extracting", "post-processing", "writing", "in all"]
    assert times["post-processing"] >= 1.0 and times["writing"] < 1.0
    parts = sum(v for k, v in times.items() if k != "in all")
    assert abs(parts - times["in all"]) <= 0.01 * len(times)  # each line rounds to 0.01 s


def test_a_mesh_beside_the_slices_of_a_tiff_folder_may_be_replaced(tmp_path, capsys):
    slices, files = _tiff_folder(tmp_path)
    out = slices / "mesh.ply"
    for _ in range(2):  # the second run replaces its own earlier mesh, not a slice
        code, _, err = run(capsys, "convert", slices, "-l", "100.5", "-o", out, "--force")
        assert code == 0, err
    assert len(trimesh.load(out, process=False).faces) > 0


def test_a_file_inside_a_zarr_store_is_an_input(tmp_path, capsys):
    zarr = pytest.importorskip("zarr")
    store = tmp_path / "vol.zarr"
    array = zarr.create_array(store=str(store), shape=(12, 12, 12), chunks=(6, 6, 6), dtype="u1")
    array[:] = field_zyx()
    files = [p for p in store.rglob("*") if p.is_file()]
    before = {f: digest(f) for f in files}
    for target in files:
        code, _, err = run(
            capsys, "convert", store, "-l", "100.5", "-o", target, "--format", "ply", "--force"
        )
        assert_one_line_error(code, err, str(target), str(store))
    assert {f: digest(f) for f in files} == before


@pytest.mark.parametrize(
    "extra",
    [["-l", "127.5", "-l", "130"], ["--labels"]],
    ids=["two levels", "labels"],
)
@pytest.mark.parametrize("option", ["-o", "--report"])
def test_a_stream_never_names_several_files(tmp_path, capsys, extra, option):
    """Outputs named after -o (NAME_level130.ply, NAME_label3.ply) cannot be made
    from /dev/stdout: as root they were new files in /dev."""
    before = set(os.listdir("/dev"))
    args = ["convert", SPHERE, *extra, "--format", "ply", "--force"]
    if option == "-o":
        args += ["-o", "/dev/stdout"]
    else:
        args += ["-o", tmp_path / "m.ply", "--report=/dev/stdout"]
    code, _, err = run(capsys, *args)
    assert_one_line_error(code, err, "/dev/stdout", "stream")
    assert set(os.listdir("/dev")) == before
    assert os.listdir(tmp_path) == []


def test_batch_summary_never_replaces_the_levels_table(tmp_path, capsys):
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "sphere.nrrd").write_bytes(Path(SPHERE).read_bytes())
    table = tmp_path / "levels.csv"
    table.write_text("pattern,level\n*.nrrd,127.5\n")
    before = digest(table)
    args = ["batch", folder, "-o", tmp_path / "out", "--levels", table, "--summary", table]
    code, _, err = run(capsys, *args, "--force")
    assert_one_line_error(code, err, str(table), "destroy")
    assert digest(table) == before
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "names",
    [
        ["-o", "same.ply", "--report=same.ply"],
        ["-l", "130", "-o", "mm.ply", "--report=mm.ply"],  # NAME_levelL.ply for both
        ["-o", "m.ply", "--preview", "c.png", "--report=c.png"],
        ["-o", "/dev/stdout", "--format", "ply", "--report=/dev/stdout"],
        ["-o", "-", "--format", "ply", "--report=/dev/stdout"],
    ],
    ids=[
        "report is the mesh",
        "per-level names",
        "report is the preview",
        "one stream",
        "dash and stdout",
    ],  # fmt: skip
)
def test_two_outputs_never_share_a_name(tmp_path, capsys, monkeypatch, names):
    pytest.importorskip("vtk")
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "convert", SPHERE, "-l", "127.5", *names, "--force")
    assert_one_line_error(code, err, "two outputs")
    assert os.listdir(tmp_path) == [] and out == ""


@pytest.mark.parametrize(
    "args",
    [
        ["info", "LONG.nrrd"],
        ["check", "LONG.ply"],
        ["convert", SPHERE, "-l", "127.5", "-o", "LONG/x.ply"],
        ["batch", SPHERE, "-l", "127.5", "-o", "LONG"],
        ["convert", SPHERE, "-l", "127.5", "-o", "x.ply", "--values", "LONG.nrrd"],
        ["convert", SPHERE, "-l", "127.5", "-o", "x.ply", "--report=LONG/r.json"],
    ],
    ids=["info", "check", "output folder", "batch folder", "values", "report folder"],
)
def test_a_name_too_long_anywhere_is_one_line_not_an_internal_error(
    tmp_path, capsys, monkeypatch, args
):
    monkeypatch.chdir(tmp_path)
    long = "k" * 260
    code, _, err = run(capsys, *[a.replace("LONG", long) if isinstance(a, str) else a
                                 for a in args])  # fmt: skip
    assert_one_line_error(code, err, "too long")
    assert "internal error" not in err
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("summary", ["s.csv", "s.json"])
def test_a_file_name_that_is_not_utf8_is_summarised_and_linked(tmp_path, capsys, summary):
    pytest.importorskip("vtk")
    import json
    import re
    import urllib.parse

    folder = tmp_path / "in"
    folder.mkdir()
    name = os.fsdecode(b"bad\xffname.nrrd")  # a byte no UTF-8 decoder takes
    (folder / name).write_bytes(Path(SPHERE).read_bytes())
    out = tmp_path / "out"
    args = ["batch", folder, "-o", out, "-l", "127.5", "--summary", tmp_path / summary]
    code, _, err = run(capsys, *args, "--previews")
    assert code == 0, err
    text = (tmp_path / summary).read_bytes().decode("utf-8")  # valid UTF-8
    if summary.endswith(".json"):
        (row,) = json.loads(text)["files"]
        assert row["status"] == "ok" and "bad\ufffdname" in row["input"]
    else:
        assert "bad\ufffdname.nrrd" in text
    page = (out / "index.html").read_bytes().decode("utf-8")
    links = re.findall(r'href="([^"]+)"', page)
    assert links
    for link in links:  # each link, read back as the bytes it quotes, is a file
        target = os.fsdecode(urllib.parse.unquote_to_bytes(link))
        assert (out / target).is_file(), link


def test_dev_stderr_gets_the_mesh_and_no_notes(tmp_path):
    """Notes went to stderr as usual, so into the mesh sent there."""
    header, _ = _nhdr_single(tmp_path)  # no spacing in the header: a note says so
    reference = tmp_path / "reference.ply"
    subprocess.run(_command("convert", header, "-l", "100.5", "-o", reference), check=True)
    sent = tmp_path / "sent.ply"
    with open(sent, "wb") as err:
        done = subprocess.run(
            _command("convert", header, "-l", "100.5", "-o", "/dev/stderr", "--format", "ply"),
            stdout=subprocess.PIPE,
            stderr=err,
            cwd=tmp_path,
            check=False,
        )
    assert done.returncode == 0
    assert sent.read_bytes() == reference.read_bytes()


def test_a_part_file_left_by_a_killed_run_goes_with_the_next_write(tmp_path, capsys):
    """SIGKILL (or a power cut) leaves a hidden temporary file no handler could
    remove; the next write of that output removes it when its process, on this
    host, is gone, and never one still being written or another host's."""
    import socket

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process id that no longer runs
    host = "".join(c for c in socket.gethostname() if c.isalnum() or c == "-")[:32]
    stale = tmp_path / f".m.ply.{host}~{gone.pid}-k1ll3d.part"
    running = tmp_path / f".m.ply.{host}~{os.getpid()}-w0rk1n.part"
    elsewhere = tmp_path / f".m.ply.otherhost~{gone.pid}-n0tm1n.part"
    other = tmp_path / f".n.ply.{host}~{gone.pid}-0th3rs.part"
    for path in (stale, running, elsewhere, other):
        path.write_bytes(b"half a mesh")
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", tmp_path / "m.ply")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["m.ply", running.name, elsewhere.name, other.name]
    )


@pytest.mark.parametrize("command", ["convert", "batch"])
def test_a_word_for_max_memory_is_a_usage_error(tmp_path, capsys, command):
    code, _, err = run(capsys, command, SPHERE, "-l", "127.5", "-o", tmp_path / "o",
                       "--max-memory", "lots")  # fmt: skip
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "'lots'" in lines[0] and "--max-memory" in lines[0]


def test_batch_says_when_a_users_picture_keeps_a_thumbnail_out(tmp_path, capsys):
    pytest.importorskip("vtk")
    from PIL import Image

    folder = tmp_path / "in"
    folder.mkdir()
    (folder / "sphere.nrrd").write_bytes(Path(SPHERE).read_bytes())
    Image.new("RGB", (4, 4), (200, 10, 10)).save(folder / "sphere.png")
    before = digest(folder / "sphere.png")
    code, _, err = run(capsys, "batch", folder, "-o", folder, "-l", "127.5", "--previews")
    assert code == 0, err
    assert digest(folder / "sphere.png") == before
    (note,) = [line for line in err.splitlines() if line.startswith("note:")]
    assert "sphere.png" in note and "left as it is" in note


def test_formats_columns_line_up(capsys):
    from isoconvert.readers import READERS
    from isoconvert.writers import WRITERS

    code, out, _ = run(capsys, "formats")
    assert code == 0
    starts = set()
    for registry in (READERS, WRITERS):
        for name, entry in registry.items():
            (line,) = [ln for ln in out.splitlines() if ln.startswith(f"  {name} ")]
            starts.add(line.index(entry.summary))
    assert len(starts) == 1  # every summary starts in one column (metaimage, geojson did not)
