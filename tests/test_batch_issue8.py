"""Batch, issue 8: safe output names, no empty folders, --jobs and empty inputs,
2D images and formats not read yet, non-ASCII paths, quiet workers."""

from __future__ import annotations

import json
import logging
import os
import warnings
from pathlib import Path

import nrrd
import numpy as np
import pytest
import tifffile
import trimesh

from isoconvert import ConvertOptions, readers
from isoconvert.batch import (
    IMAGE_REASON,
    UNKNOWN_REASON,
    BatchSettings,
    Found,
    Job,
    check_found,
    check_jobs,
    discover,
    make_folders,
    plan,
    remove_empty_folders,
    run_jobs,
    run_one,
    silence_third_party,
)
from isoconvert.cli import main
from isoconvert.errors import IsoconvertError

SETTINGS = BatchSettings(ConvertOptions(format="ply"))


def ball(n: int = 10, r: float = 3.0) -> np.ndarray:
    """(n, n, n) float32, r - distance from the centre: positive inside."""
    x, y, z = np.mgrid[:n, :n, :n]
    c = (n - 1) / 2
    return (r - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)


def write_raw(path: Path, n: int = 10) -> Path:
    """A float32 ball as ``path`` (name it ``*_NxNxN_float32.raw``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    np.ascontiguousarray(ball(n).T).tofile(path)
    return path


def files_under(folder: Path, but: Path | None = None) -> set[Path]:
    """Files and folders under ``folder``, except ``but`` and what it holds."""
    found = set(folder.rglob("*")) if folder.exists() else set()
    return {p for p in found if but is None or not p.is_relative_to(but)}


# --- a. output names never leave the output folder ------------------------------------------


@pytest.mark.parametrize(
    ("relative", "expected"),
    [
        ("../../evil/x.nrrd", "x.ply"),  # leaves: the file's own name, at the top
        ("a/../../x.nrrd", "x.ply"),
        ("/etc/x.nrrd", "x.ply"),  # absolute
        ("a/./b/../c.nrrd", "a/c.ply"),  # stays inside: mirrored, normalised
        ("..", "x.ply"),
    ],
)
def test_plan_keeps_outputs_inside_the_output_folder(tmp_path, relative, expected):
    out = tmp_path / "deep" / "out"
    src = str(tmp_path / "in" / "x.nrrd")
    jobs, done = plan([Found(src, Path(relative), 100)], out, ".ply", 0.5)
    assert not done
    (job,) = jobs
    assert Path(job.output) == out / expected
    assert Path(os.path.abspath(job.output)).is_relative_to(out)


def test_plan_does_not_follow_a_link_out_of_the_output_folder(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    os.symlink(elsewhere, out / "link")
    found = [Found(str(tmp_path / "x.nrrd"), Path("link/x.nrrd"), 1)]
    (job,), _ = plan(found, out, ".ply", 0.5)
    assert Path(job.output).resolve().is_relative_to(out.resolve())
    assert Path(job.output) == out / "x.ply"


def test_plan_gives_fallback_names_that_clash_distinct_outputs(tmp_path):
    found = [
        Found(str(tmp_path / "p" / "x.nrrd"), Path("../p/x.nrrd"), 1),
        Found(str(tmp_path / "q" / "x.nrrd"), Path("../q/x.nrrd"), 1),
        Found(str(tmp_path / "x.tif"), Path("x.tif"), 1),
    ]
    jobs, _ = plan(found, tmp_path / "out", ".ply", 0.5)
    outputs = [Path(j.output) for j in jobs]
    assert len(set(outputs)) == 3
    assert all(o.parent == tmp_path / "out" for o in outputs)


def test_a_glob_with_dot_dot_parts_writes_only_inside_the_output_folder(tmp_path):
    write_raw(tmp_path / "other" / "y_10x10x10_float32.raw")
    for sub in ("a", "b"):
        (tmp_path / "scans" / sub).mkdir(parents=True)
    pattern = str(tmp_path / "scans" / "*" / ".." / ".." / "other" / "*.raw")
    found, _ = discover([pattern])
    assert len(found) == 1  # reached through scans/a and scans/b: converted once
    out = tmp_path / "out"
    before = files_under(tmp_path, but=out)
    jobs, done = plan(found, out, ".ply", 0.5)
    assert not done
    outcomes = run_jobs(jobs, SETTINGS)
    assert [o.status for o in outcomes] == ["ok"]
    assert (out / "y_10x10x10_float32.ply").is_file()
    assert files_under(tmp_path, but=out) == before  # nothing written elsewhere
    assert files_under(out) == {out / "y_10x10x10_float32.ply"}


# --- b. a failed file leaves no empty folder ------------------------------------------------


def test_a_failed_file_removes_the_folders_it_created(tmp_path):
    bad = tmp_path / "bad.nrrd"
    bad.write_bytes(b"NRRD0004\ngarbage")
    out = tmp_path / "out"
    out.mkdir()
    outcome = run_one(Job(str(bad), str(out / "x" / "y" / "bad.ply"), 0.5), SETTINGS)
    assert outcome.status == "failed" and "bad.nrrd" in outcome.message
    assert list(out.iterdir()) == []
    # folders that were there before stay, even when empty
    (out / "kept").mkdir()
    run_one(Job(str(bad), str(out / "kept" / "new" / "bad.ply"), 0.5), SETTINGS)
    assert list(out.iterdir()) == [out / "kept"] and list((out / "kept").iterdir()) == []


@pytest.mark.parametrize("workers", [1, 2])
def test_failed_files_leave_no_empty_folders_in_a_batch(tmp_path, workers):
    inputs = tmp_path / "in"
    write_raw(inputs / "good" / "g_10x10x10_float32.raw")
    write_raw(inputs / "mixed" / "m_10x10x10_float32.raw")
    for where in ("bad/deeper", "mixed"):
        (inputs / where).mkdir(parents=True, exist_ok=True)
        (inputs / where / "broken.nrrd").write_bytes(b"NRRD0004\ngarbage")
    out = tmp_path / "out"
    created = make_folders(out)
    assert created == [out]
    found, _ = discover([str(inputs)], recursive=True)
    jobs, _ = plan(found, out, ".ply", 0.5)
    statuses = sorted(o.status for o in run_jobs(jobs, SETTINGS, workers=workers))
    assert statuses == ["failed", "failed", "ok", "ok"]
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "good",
        "good/g_10x10x10_float32.ply",
        "mixed",
        "mixed/m_10x10x10_float32.ply",
    ]
    remove_empty_folders(created)  # not empty: stays
    assert out.is_dir()


def test_the_top_output_folder_goes_when_every_file_failed(tmp_path):
    bad = tmp_path / "bad.nrrd"
    bad.write_bytes(b"NRRD0004\ngarbage")
    out = tmp_path / "new" / "out"
    created = make_folders(out)
    assert created == [tmp_path / "new", out]
    assert make_folders(out) == []  # there now: nothing created, nothing to remove later
    jobs, _ = plan([Found(str(bad), Path("sub/bad.nrrd"), 1)], out, ".ply", 0.5)
    assert [o.status for o in run_jobs(jobs, SETTINGS)] == ["failed"]
    remove_empty_folders(created)
    assert not (tmp_path / "new").exists()
    with pytest.raises(IsoconvertError, match="not a folder"):
        make_folders(bad / "sub")


# --- c. --jobs and inputs without volumes ----------------------------------------------------


def test_check_jobs_refuses_zero_and_negative():
    for bad in (0, -1, -8):
        with pytest.raises(IsoconvertError, match="--jobs") as info:
            check_jobs(bad)
        assert "\n" not in str(info.value)
    assert check_jobs(None) == (os.cpu_count() or 1)
    assert check_jobs(3) == 3
    assert check_jobs(8, files=2) == 2 and check_jobs(None, files=0) == 1


def test_inputs_without_volumes_are_an_error(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "a.csv").write_text("x")
    Image = pytest.importorskip("PIL.Image")
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "preview.png")
    found, skipped = discover([str(tmp_path)])
    assert found == []
    with pytest.raises(IsoconvertError) as info:
        check_found([str(tmp_path)], found, skipped)
    message = str(info.value)
    assert message.startswith(f"no volumes found in {tmp_path} (3 files skipped: ")
    assert f"2 files: {UNKNOWN_REASON} | 1 file: {IMAGE_REASON})" in message
    assert "\n" not in message
    check_found([str(tmp_path)], [Found("x", Path("x"), 1)], skipped)  # volumes: fine


# --- d. 2D images only when asked for -------------------------------------------------------


@pytest.fixture
def scan_folder(tmp_path):
    """scans/ with volumes (raw, 3D NRRD, multi-page TIFF, a slice stack) and 2D images
    (PNG, JPEG, a single-page TIFF, a 2D NRRD, an RGB 2D NRRD)."""
    Image = pytest.importorskip("PIL.Image")
    root = tmp_path / "scans"
    write_raw(root / "vol_10x10x10_float32.raw")
    nrrd.write(str(root / "vol3d.nrrd"), ball(), index_order="F")
    tifffile.imwrite(root / "multi.tif", np.ascontiguousarray(ball().T))
    (root / "stack").mkdir()
    for k in range(4):
        tifffile.imwrite(root / "stack" / f"s{k}.tif", ball()[:, :, k].T.copy())
    (root / "previews").mkdir()
    Image.fromarray(np.zeros((8, 8), np.uint8)).save(root / "previews" / "vol.png")
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(root / "photo.JPG")
    tifffile.imwrite(root / "single.tif", ball()[:, :, 5].T.copy())
    nrrd.write(str(root / "flat.nrrd"), ball()[:, :, 5], index_order="F")
    rgb = np.zeros((3, 8, 8), np.uint8)
    nrrd.write(str(root / "rgb.nrrd"), rgb, {"kinds": ["RGB-color", "domain", "domain"]})
    return root


def test_2d_images_are_skipped_unless_asked_for(scan_folder):
    found, skipped = discover([str(scan_folder)], recursive=True)
    volumes = sorted(str(f.relative) for f in found)
    assert volumes == ["multi.tif", "stack", "vol3d.nrrd", "vol_10x10x10_float32.raw"]
    images = sorted(Path(s.path).name for s in skipped if s.reason == IMAGE_REASON)
    assert images == ["flat.nrrd", "photo.JPG", "rgb.nrrd", "single.tif", "vol.png"]
    found, skipped = discover([str(scan_folder)], recursive=True, images=True)
    assert len(found) == 9 and not [s for s in skipped if s.reason == IMAGE_REASON]
    # a file named on its own is skipped too (and then no volume is found)
    found, skipped = discover([str(scan_folder / "previews" / "vol.png")])
    assert not found and [s.reason for s in skipped] == [IMAGE_REASON]


# --- e. formats not read yet ----------------------------------------------------------------


def dicom_bytes() -> bytes:
    """The start of a DICOM file: a 128-byte preamble and the DICM mark."""
    return bytes(128) + b"DICM" + b"\x02\x00\x00\x00UL\x04\x00" + bytes(8)


def expected_reason(path: Path) -> str:
    """What readers.unsupported_format says, where that exists, without the path."""
    check = getattr(readers, "unsupported_format", None)
    reason = check(path) if check else None
    return reason.removeprefix(f"{path}: ") if reason else UNKNOWN_REASON


# DICOM is read: the DICOM files of a folder are one volume (the folder).


def test_a_dicom_series_folder_is_one_volume(tmp_path):
    series = tmp_path / "scans" / "chest"
    series.mkdir(parents=True)
    for k in range(6):
        (series / f"IM{k:04d}").write_bytes(dicom_bytes())  # DICOM files often have no suffix
    (series / "extra.dcm").write_bytes(dicom_bytes())
    write_raw(tmp_path / "scans" / "v_10x10x10_float32.raw")
    found, skipped = discover([str(tmp_path / "scans")], recursive=True)
    assert sorted(str(f.relative) for f in found) == ["chest", "v_10x10x10_float32.raw"]
    (dicom,) = [f for f in found if f.spec == str(series)]
    assert dicom.size == 7 * len(dicom_bytes())
    assert not [s for s in skipped if Path(s.path).parent == series]
    # the folder alone: one volume, named after the folder
    found, skipped = discover([str(series)])
    assert [(f.spec, str(f.relative)) for f in found] == [(str(series), "chest")] and not skipped


def test_discovery_finds_dicom_and_gives_the_reason_readers_give_for_the_rest(tmp_path):
    (tmp_path / "series").mkdir()
    for k in range(3):
        (tmp_path / "series" / f"IM{k}").write_bytes(dicom_bytes())
    (tmp_path / "slice.dicom").write_bytes(bytes(8))  # named DICOM, without the magic
    (tmp_path / "notes.txt").write_text("x")
    found, skipped = discover([str(tmp_path)], recursive=True)
    reasons = {Path(s.path).name: s.reason for s in skipped}
    # a lone DICOM file is itself the volume; reading it says what is wrong with it
    assert sorted(Path(f.spec).name for f in found) == ["series", "slice.dicom"]
    assert readers.unsupported_format(tmp_path / "series") is None
    assert reasons == {"notes.txt": UNKNOWN_REASON}


def test_the_data_file_of_a_metaimage_header_counts_once(tmp_path):
    folder = tmp_path / "head"
    write_raw(folder / "head.raw")
    (folder / "head.mhd").write_text(
        "NDims = 3\nDimSize = 10 10 10\nElementType = MET_FLOAT\nElementDataFile = head.raw\n"
    )
    found, skipped = discover([str(folder)])
    if readers.READERS.by_suffix(".mhd") is None:
        assert found == []  # the raw data is not read without its header
        assert [Path(s.path).name for s in skipped] == ["head.mhd"]
        assert skipped[0].reason == expected_reason(folder / "head.mhd")
        # named on its own, the data file is still a raw file (with --shape/--dtype)
        found, _ = discover([str(folder / "head.raw")])
        assert [Path(f.spec).name for f in found] == ["head.raw"]
    else:
        assert [Path(f.spec).name for f in found] == ["head.mhd"]
        # named on its own, the data file is skipped: its header reads it (as for .nhdr)
        found, skipped = discover([str(folder / "head.raw")])
        assert found == []
        assert [(Path(s.path).name, s.reason) for s in skipped] == [
            ("head.raw", "the data of head.mhd; convert that header")
        ]


def test_real_dataset_folder_skips_previews_dicom_and_metaimage_data():
    from conftest import dataset

    root = dataset("MANIFEST.md").parent
    found, skipped = discover([str(root)], recursive=True)
    names = {Path(f.spec).name for f in found}
    assert "quarter.nhdr" in names and "engine_256x256x128_uint8.raw" in names
    assert "HeadMRVolume.raw" not in names  # MetaImage data: not a headerless volume
    assert not any(Path(f.spec).parent.name == "previews" for f in found)
    # a folder's DICOM files are one volume
    (dicom,) = [f for f in found if f.spec.endswith("ct_chest_LIDC-IDRI-0314_dicom")]
    assert str(dicom.relative) == "ct_chest_LIDC-IDRI-0314_dicom"
    assert not [f for f in found if f.spec.endswith(".dcm")]


# --- f. non-ASCII paths ---------------------------------------------------------------------


def test_non_ascii_paths_convert_to_every_format(tmp_path):
    folder = tmp_path / "données"
    folder.mkdir()
    n = 8
    x, y, z = np.mgrid[:n, :n, :n]
    c = (n - 1) / 2
    radius = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    mask = (radius < 2.5).astype(np.uint8) * 200  # a small ball, (x, y, z)
    np.ascontiguousarray(mask.T).tofile(folder / "Müller_8x8x8_uint8.raw")
    nrrd.write(str(folder / "tête_crâne.nrrd"), mask, index_order="F")
    problems = {}
    for fmt in ("ply", "obj", "stl"):
        out = tmp_path / f"résultats_{fmt}"
        summary = tmp_path / f"résumé_{fmt}.json"
        args = ["batch", str(folder), "-o", str(out), "-l", "100", "--format", fmt]
        code = main([*args, "-j", "1", "-q", "--summary", str(summary)])
        rows = json.loads(summary.read_text(encoding="utf-8"))["files"]
        made = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
        if code != 0 or made != [f"Müller_8x8x8_uint8.{fmt}", f"tête_crâne.{fmt}"]:
            problems[fmt] = (code, made, [r["message"] for r in rows])
            continue
        for p in out.iterdir():
            assert len(trimesh.load(p, file_type=fmt, process=False).faces) > 0
        assert {Path(r["output"]).name for r in rows} == set(made)
    assert not problems, problems


# --- g. quiet workers -----------------------------------------------------------------------


@pytest.fixture
def restore_logging_and_warnings():
    log = logging.getLogger("tifffile")
    handlers, propagate = list(log.handlers), log.propagate
    with warnings.catch_warnings():
        yield
    log.handlers[:] = handlers
    log.propagate = propagate


def test_silence_third_party_keeps_numpy_and_tifffile_off_stderr(
    restore_logging_and_warnings, capsys
):
    silence_third_party()
    silence_third_party()  # twice is harmless
    with warnings.catch_warnings(record=True) as caught:
        np.log(np.zeros(3))
        np.float64(1e308) * np.float64(10.0)
        np.nanmax(np.full(2, np.nan))
        warnings.warn("an isoconvert notice", UserWarning, stacklevel=1)
    assert [str(w.message) for w in caught] == ["an isoconvert notice"]
    logging.getLogger("tifffile").warning("tifffile: a noisy log line")
    assert "noisy" not in capsys.readouterr().err
    assert sum(isinstance(h, logging.NullHandler) for h in logging.getLogger("tifffile").handlers)


NOISY_PLUGIN = '''
import logging
import warnings

import numpy as np

from isoconvert.extract.cubes import marching_cubes


def run(volume, level, **kw):
    """Marching Cubes, after a numpy warning and a tifffile log line."""
    np.log(np.zeros(2))
    warnings.warn("numpy says so", np.exceptions.VisibleDeprecationWarning, stacklevel=1)
    logging.getLogger("tifffile").warning("NOISY-TIFFFILE-LINE")
    return marching_cubes(volume, level, **kw)
'''


def test_worker_processes_keep_numpy_and_tifffile_off_stderr(tmp_path, monkeypatch, capfd):
    from isoconvert import EXTRACTORS

    (tmp_path / "noisy.py").write_text(NOISY_PLUGIN)
    dist = tmp_path / "noisy-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: noisy\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[isoconvert.extractors]\nnoisy = noisy:run\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # spawned workers get the parent's sys.path
    EXTRACTORS.reload_plugins()
    try:
        for k in range(2):
            write_raw(tmp_path / "in" / f"b{k}_10x10x10_float32.raw")
        found, _ = discover([str(tmp_path / "in")])
        jobs, _ = plan(found, tmp_path / "out", ".ply", 0.5)
        capfd.readouterr()
        outcomes = run_jobs(
            jobs, BatchSettings(SETTINGS.options.updated(method="noisy")), workers=2
        )
        assert [o.status for o in outcomes] == ["ok", "ok"], [o.message for o in outcomes]
        err = capfd.readouterr().err
        assert "Warning" not in err and "NOISY-TIFFFILE-LINE" not in err, err
    finally:
        monkeypatch.undo()
        EXTRACTORS.reload_plugins()
