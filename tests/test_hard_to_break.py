"""Broken inputs, a full disk, interrupts and fuzzed files: one clear line, nothing half-written."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
from conftest import SAMPLES
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from make_bad_inputs import _nrrd_header, make_bad_inputs

import isoconvert
from isoconvert import IsoconvertError, read_volume
from isoconvert.cli import main


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    return make_bad_inputs(tmp_path_factory.mktemp("bad"))


def one_line_error(capsys, code, *needles):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 1, err
    assert len(lines) == 1 and lines[0].startswith("isoconvert: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


CASE_NAMES = [
    "truncated_8x8x8_uint16.raw",
    "zero_dim.raw",
    "complex.raw",
    "strings.raw",
    "nan_4x4x4_float32.raw",
    "constant_4x4x4_uint8.raw",
    "truncated.nrrd",
    "truncated_gzip.nrrd",
    "lies_encoding.nrrd",
    "lies_sizes.nrrd",
    "unsupported_encoding.nrrd",
    "string_type.nrrd",
    "huge.nrrd",
    "zero_size.nrrd",
    "missing_data.nhdr",
    "not_nrrd.nrrd",
    "block_type.nrrd",
    "list_missing_part.nhdr",
    "outside_data.nhdr",
    "outside_absolute.nhdr",
    "outside_numbered.nhdr",
    "gzip_bomb.nrrd",
    "gzip_short.nrrd",
    "scan.nii.gz",
    "scan.nii",
    "cut.nii.gz",
    "head.mhd",
    "head.mha",
    "slice.dcm",
    "IM0001",
    "odd_page.tif",
    "truncated.tif",
    "complex.tif",
    "rgb.png",
    "rgb_stack.tif",
    "broken.png",
    "unknown.xyz",
]


@pytest.mark.parametrize("name", CASE_NAMES)
def test_each_bad_input_gives_one_line_and_no_output(corpus, tmp_path, capsys, name):
    case = corpus[name]
    before = case.path.read_bytes()
    out = tmp_path / "out.ply"
    code = main(["convert", str(case.path), "-l", "1.5", "-o", str(out), *case.args])
    line = one_line_error(capsys, code, *case.says)
    assert case.path.name in line, "the message names the file"
    assert list(tmp_path.iterdir()) == [], "no output, not even a partial one"
    assert case.path.read_bytes() == before, "the input is never modified"


def test_batch_converts_the_good_files_beside_the_bad(corpus, tmp_path, capsys):
    good = tmp_path / "in" / "ball_12x12x12_float32.raw"
    good.parent.mkdir()
    x, y, z = np.mgrid[:12, :12, :12]
    (4.0 - np.sqrt((x - 5.5) ** 2 + (y - 5.5) ** 2 + (z - 5.5) ** 2)).astype(np.float32).tofile(
        good
    )
    folder = next(iter(corpus.values())).path.parent
    out = tmp_path / "out"
    summary = tmp_path / "summary.json"
    code = main(
        [
            "batch",
            str(folder),
            str(good),
            "-o",
            str(out),
            "-l",
            "0.5",
            "--summary",
            str(summary),
            "-j",
            "1",
        ]
    )
    assert code == 1
    import json

    rows = {os.path.basename(r["input"]): r for r in json.loads(summary.read_text())["files"]}
    assert rows["ball_12x12x12_float32.raw"]["status"] == "ok"
    assert (out / "ball_12x12x12_float32.ply").exists()
    assert rows["unknown.xyz"]["status"] == "skipped"
    assert rows["truncated.nrrd"]["status"] == "failed"
    assert "cannot be read" in rows["truncated.nrrd"]["message"]
    leftovers = [p.name for p in out.iterdir() if p.name != "ball_12x12x12_float32.ply"]
    assert not [n for n in leftovers if n.endswith(".part")]
    err = capsys.readouterr().err
    assert "Traceback" not in err


def test_full_disk_leaves_nothing(tmp_path, capsys, monkeypatch):
    real_fdopen = os.fdopen

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    monkeypatch.setattr(os, "fdopen", lambda fd, mode: Full(real_fdopen(fd, mode)))
    code = main(
        ["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(tmp_path / "s.ply")]
    )
    one_line_error(capsys, code, "s.ply", "disk full at")
    assert list(tmp_path.iterdir()) == []


def test_interrupt_while_writing_leaves_nothing(tmp_path, capsys, monkeypatch):
    from isoconvert.writers import ply

    def interrupted(mesh, fh, ascii=False):
        fh.write(b"ply\nformat binary_little_endian 1.0\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(ply, "write_ply", interrupted)
    import dataclasses

    from isoconvert.writers import WRITERS

    monkeypatch.setitem(
        WRITERS._entries, "ply", dataclasses.replace(WRITERS.get("ply"), write=interrupted)
    )
    code = main(
        ["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(tmp_path / "s.ply")]
    )
    assert code == 130
    assert "interrupted" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_bool_volumes_are_masks(tmp_path):
    mask = np.zeros((8, 8, 8), bool)
    mask[2:6, 2:6, 2:6] = True
    vol = isoconvert.Volume(mask)
    mesh = isoconvert.extract(vol, 0.5)
    assert mesh.signed_volume() > 0 and mesh.n_cells > 0


# --- fuzzing the readers --------------------------------------------------------------------

VALID_NRRD = _nrrd_header() + (np.arange(48, dtype=np.int16)).tobytes()


def read_or_clear_error(path, **kw):
    try:
        read_volume(path, **kw)
    except IsoconvertError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    edits=st.lists(
        st.tuples(
            st.integers(0, len(VALID_NRRD) - 1),
            st.sampled_from(["flip", "cut", "insert"]),
            st.binary(min_size=1, max_size=4),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_fuzzed_nrrd_headers_never_crash(tmp_path, edits):
    data = bytearray(VALID_NRRD)
    for pos, kind, chunk in edits:
        pos = min(pos, len(data) - 1)
        if kind == "flip":
            data[pos : pos + len(chunk)] = chunk
        elif kind == "cut":
            del data[pos : pos + len(chunk)]
        else:
            data[pos:pos] = chunk
    path = tmp_path / "fuzz.nrrd"
    path.write_bytes(bytes(data))
    read_or_clear_error(path)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    blob=st.binary(max_size=300),
    suffix=st.sampled_from([".nrrd", ".tif", ".png", ".jpg", ".nhdr"]),
    prefix=st.sampled_from([b"", b"NRRD0004\n", b"II*\x00", b"MM\x00*", b"\x89PNG\r\n\x1a\n"]),
)
def test_random_bytes_never_crash_a_reader(tmp_path, blob, suffix, prefix):
    path = tmp_path / f"fuzz{suffix}"
    path.write_bytes(prefix + blob)
    read_or_clear_error(path)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    blob=st.binary(max_size=200),
    shape=st.lists(st.integers(-1, 6), min_size=1, max_size=4),
    dtype=st.sampled_from(["uint8", "int16", "float32", "float64", "bool", "complex64", ""]),
    header=st.integers(-2, 20),
)
def test_raw_with_any_layout_never_crashes(tmp_path, blob, shape, dtype, header):
    path = tmp_path / "fuzz.raw"
    path.write_bytes(blob)
    read_or_clear_error(path, shape=tuple(shape), dtype=dtype or None, header_bytes=header)
