"""Issue 20, "Smaller ones": info on volumes with no level, --plot formats, post-processing
that empties a mesh, batch into its own input folder, and the contact sheet's counts."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from isoconvert.cli import main


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *needles):
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("isoconvert: error: ") and "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --- info on a volume without a level -----------------------------------------------------


def save(tmp_path, name, data):
    path = tmp_path / name
    np.save(path, data)
    return path


def numbers(text: str) -> list[float]:
    return [float(t) for t in re.findall(r"-?\d+(?:\.\d+)?(?:e[+-]?\d+)?", text)]


def test_info_on_an_all_nan_volume_invents_no_range(tmp_path, capsys):
    path = save(tmp_path, "nan.npy", np.full((4, 4, 4), np.nan, np.float32))
    code, out, _ = run(capsys, "info", path)
    assert code == 0
    assert "0 .. 1" not in out
    assert "no finite samples" in out and "64" in out
    # no row of a histogram (nothing to count) and no suggested levels
    assert "suggested levels:" not in out
    rows = out[out.index("histogram") :] if "histogram" in out else ""
    assert " .. " not in rows
    code, out, _ = run(capsys, "info", path, "--json")
    info = json.loads(out)
    assert info["min"] is None and info["max"] is None
    assert info["nonfinite"] == 64 and info["suggested_levels"] == {}
    assert "no finite samples" in info["no_levels_reason"]


@pytest.mark.parametrize("dtype", ["uint8", "int16", "float32", "float64"])
def test_info_on_a_constant_volume_suggests_no_level(tmp_path, capsys, dtype):
    path = save(tmp_path, "c.npy", np.full((4, 5, 6), 7, dtype))
    code, out, _ = run(capsys, "info", path)
    assert code == 0
    assert "all samples are 7: no isosurface at any level" in out
    assert "suggested levels:" not in out
    # the range is the samples' own, not a bin widened to 7 .. 8
    assert "range     7 .. 7" in out
    body = out[out.index("histogram") :]
    assert all(v == 7 or v == 120 for v in numbers(body)), body  # 7, and 120 samples
    code, out, _ = run(capsys, "info", path, "--json")
    info = json.loads(out)
    assert info["min"] == 7 and info["max"] == 7 and info["suggested_levels"] == {}
    assert info["no_levels_reason"] == "all samples are 7: no isosurface at any level"
    # and convert agrees there is none, with or without auto
    for level in ("7", "auto"):
        code, out, err = run(capsys, "convert", path, "-l", level, "-o", tmp_path / "c.ply")
        one_line_error(code, err, "no isosurface")
        assert "Otsu threshold" not in out + err


def test_info_on_a_constant_volume_with_nan_says_what_nan_as_could_do(tmp_path, capsys):
    data = np.full((4, 4, 4), 7.0, np.float32)
    data[0, 0, :2] = np.nan
    path = save(tmp_path, "cn.npy", data)
    code, out, _ = run(capsys, "info", path, "--json")
    info = json.loads(out)
    assert info["min"] == 7 and info["max"] == 7 and info["nonfinite"] == 2
    assert info["suggested_levels"] == {}
    reason = info["no_levels_reason"]
    assert "all 62 finite samples are 7" in reason and "2" in reason and "--nan-as" in reason
    code, out, _ = run(capsys, "info", path)
    assert code == 0 and reason in out and "suggested levels:" not in out
    # auto has nothing to pick either (it used to say "Otsu threshold 7.5", of a made-up 8)
    code, out, err = run(capsys, "convert", path, "-l", "auto", "-o", tmp_path / "c.ply")
    one_line_error(code, err, "cn.npy: --level auto: all 62 finite samples are 7")
    assert "7.5" not in out + err
    # with --nan-as 0, auto sees what extraction sees: 0 and 7, and picks a level between
    code, out, err = run(
        capsys, "convert", path, "-l", "auto", "--nan-as", "0", "-o", tmp_path / "c.ply"
    )
    assert code == 0, err
    level = float(re.search(r"Otsu threshold (\S+)", out + err).group(1))
    assert 0 < level <= 7


def test_convert_auto_on_an_all_nan_volume_invents_no_level(tmp_path, capsys):
    path = save(tmp_path, "nan.npy", np.full((4, 4, 4), np.nan))
    code, out, err = run(capsys, "convert", path, "-l", "auto", "-o", tmp_path / "n.ply")
    one_line_error(code, err, "nan.npy", "no finite samples")
    assert "Otsu threshold" not in out + err
    assert not (tmp_path / "n.ply").exists()


def two_valued(dtype, nan: bool) -> np.ndarray:
    """(5, 5, 5): 7 everywhere but one 8 (and, for floats, two NaN samples)."""
    data = np.full((5, 5, 5), 7, dtype)
    data[2, 2, 2] = 8
    if nan:
        data[0, 0, 0] = data[4, 4, 4] = np.nan
    return data


@pytest.mark.parametrize(
    "dtype, nan", [("uint8", False), ("int16", False), ("float32", False), ("float32", True)]
)
def test_every_suggested_level_is_one_convert_takes(tmp_path, capsys, dtype, nan):
    """A property: each suggested level lies in (min, max] of the finite samples, so
    convert makes a surface at it (here the closed surface around the one 8)."""
    path = save(tmp_path, "v.npy", two_valued(dtype, nan))
    code, out, _ = run(capsys, "info", path, "--json")
    info = json.loads(out)
    assert (info["min"], info["max"]) == (7, 8) and info["no_levels_reason"] is None
    levels = info["suggested_levels"]
    assert set(levels) == {"otsu", "p50", "p90", "p99"}
    for name, level in levels.items():
        assert 7 < level <= 8, (name, level)
        out_path = tmp_path / f"{name}.ply"
        extra = ["--nan-as", "0"] if nan else []
        code, _, err = run(capsys, "convert", path, "-l", repr(level), "-o", out_path, *extra)
        assert code == 0, err
        import trimesh

        mesh = trimesh.load(out_path, process=False)
        assert len(mesh.faces) > 0 and mesh.is_watertight


# --- info --plot writes the format its suffix names -----------------------------------------

SVG_NS = "{http://www.w3.org/2000/svg}"


def ball_npy(tmp_path, name="ball.npy"):
    from conftest import ball

    return save(tmp_path, name, ball(12, 4.0).astype(np.float32))


def test_info_plot_svg_is_svg(tmp_path, capsys):
    import xml.etree.ElementTree as ET

    pytest.importorskip("matplotlib")
    out = tmp_path / "p.svg"
    code, _, err = run(capsys, "info", ball_npy(tmp_path), "--plot", out)
    assert code == 0, err
    assert not out.read_bytes().startswith(b"\x89PNG")
    root = ET.parse(out).getroot()
    assert root.tag == SVG_NS + "svg"
    # drawn, not an empty frame: the slices are images, the contour paths
    assert root.findall(f".//{SVG_NS}image") and root.findall(f".//{SVG_NS}path")


def test_info_plot_pdf_and_png_are_what_they_say(tmp_path, capsys):
    from PIL import Image

    pytest.importorskip("matplotlib")
    volume = ball_npy(tmp_path)
    assert run(capsys, "info", volume, "--plot", tmp_path / "p.pdf")[0] == 0
    assert (tmp_path / "p.pdf").read_bytes().startswith(b"%PDF-")
    assert run(capsys, "info", volume, "--plot", tmp_path / "p.PNG")[0] == 0
    assert (tmp_path / "p.PNG").read_bytes().startswith(b"\x89PNG\r\n\x1a\n")
    with Image.open(tmp_path / "p.PNG") as image:
        assert image.format == "PNG" and image.size[0] == 1000


@pytest.mark.parametrize("name", ["p.jpg", "p.txt", "p"])
def test_info_plot_refuses_a_suffix_it_cannot_write(tmp_path, capsys, name):
    pytest.importorskip("matplotlib")
    volume = ball_npy(tmp_path)
    code, out, err = run(capsys, "info", volume, "--plot", tmp_path / name)
    one_line_error(code, err, ".png, .svg, .pdf")
    assert out == "" and sorted(p.name for p in tmp_path.iterdir()) == ["ball.npy"]


def test_info_plot_of_a_constant_volume_draws_it_without_contour(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from isoconvert import read_volume
    from isoconvert.infoplot import write_info_plot

    path = save(tmp_path, "c.npy", np.full((4, 5, 6), 7, np.uint8))
    code, out, err = run(capsys, "info", path, "--plot", tmp_path / "c.png")
    assert code == 0, err
    assert "all samples are 7: no isosurface at any level" in out
    plot = write_info_plot(read_volume(path), tmp_path / "d.png")
    assert plot.level is None and plot.marked == {} and set(plot.segments.values()) == {0}
    # asking for a level there is a one-line error naming why
    code, _, err = run(capsys, "info", path, "--plot", tmp_path / "e.png", "--level", "7")
    one_line_error(code, err, "no isosurface at any level")
    assert not (tmp_path / "e.png").exists()
    # and a volume without finite samples has nothing to draw
    nan = save(tmp_path, "nan.npy", np.full((4, 4, 4), np.nan))
    code, _, err = run(capsys, "info", nan, "--plot", tmp_path / "n.png")
    one_line_error(code, err, "no finite samples")
    assert not (tmp_path / "n.png").exists()


# --- post-processing that would leave nothing ------------------------------------------------

TWO_SPHERES = "sample_volumes/two_spheres.nrrd"


def two_sphere_parts():
    """trimesh's components of two_spheres.nrrd at 0.25 (independent of isoconvert.graph)."""
    import trimesh
    from conftest import SAMPLES

    from isoconvert import extract, read_volume

    mesh = extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.25)
    tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    return tm.split(only_watertight=False)


def test_min_size_that_removes_everything_is_refused(tmp_path, capsys):
    from conftest import SAMPLES

    pieces = two_sphere_parts()
    largest = max(len(p.faces) for p in pieces)
    out = tmp_path / "t.ply"
    code, stdout, err = run(
        capsys, "convert", SAMPLES / "two_spheres.nrrd", "-l", "0.25", "-o", out,
        "--min-size", largest + 1,
    )  # fmt: skip
    line = one_line_error(
        code,
        err,
        f"--min-size {largest + 1} removed all {len(pieces)} components "
        f"(the largest has {largest:,} triangles); lower it",
        "two_spheres.nrrd",
    )
    assert "wrote" not in stdout and list(tmp_path.iterdir()) == [], line
    # one triangle less keeps the largest: written, as before
    code, _, err = run(
        capsys, "convert", SAMPLES / "two_spheres.nrrd", "-l", "0.25", "-o", out,
        "--min-size", largest,
    )  # fmt: skip
    assert code == 0 and out.is_file(), err


def test_min_volume_that_removes_everything_is_refused(tmp_path, capsys):
    from conftest import SAMPLES

    pieces = two_sphere_parts()
    assert all(p.is_watertight for p in pieces)
    biggest = max(abs(p.volume) for p in pieces)
    out = tmp_path / "t.ply"
    code, _, err = run(
        capsys, "convert", SAMPLES / "two_spheres.nrrd", "-l", "0.25", "-o", out,
        "--min-volume", 1e9,
    )  # fmt: skip
    line = one_line_error(code, err, f"--min-volume 1e+09 removed all {len(pieces)} components")
    said = float(re.search(r"the largest encloses ([0-9.e+-]+)", line).group(1))
    assert said == pytest.approx(biggest, rel=1e-5) and "lower it" in line
    assert list(tmp_path.iterdir()) == []


def test_cavities_filled_then_min_size_removing_the_rest_is_refused(tmp_path, capsys):
    from conftest import ball

    from isoconvert import Volume, extract
    from isoconvert.post.components import fill_cavities

    field = np.minimum(ball(24, 9.2), -ball(24, 4.3)).astype(np.float32)  # a hollow ball
    path = save(tmp_path, "hollow.npy", field)
    outer = fill_cavities(extract(Volume(field), 0.0))
    n = outer.n_cells  # the outer surface, which --fill-cavities keeps
    code, _, err = run(
        capsys, "convert", path, "-l", "0", "-o", tmp_path / "h.ply",
        "--fill-cavities", "--min-size", n + 1,
    )  # fmt: skip
    one_line_error(
        code, err, f"--min-size {n + 1} removed the only component (it has {n:,} triangles)"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hollow.npy"]


def test_batch_counts_a_file_emptied_by_min_size_as_failed(tmp_path, capsys):
    import shutil

    from conftest import SAMPLES, ball

    from isoconvert import Volume, extract

    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SAMPLES / "two_spheres.nrrd", src)
    big = ball(24, 9.0).astype(np.float32)  # one ball, larger than either of two_spheres
    save(src, "big.npy", big)
    largest = max(len(p.faces) for p in two_sphere_parts())
    assert extract(Volume(big), 0.25).n_cells > largest + 1
    code, out, err = run(
        capsys, "batch", src, "-o", tmp_path / "out", "-l", "0.25", "--min-size", largest + 1,
        "-j", "1",
    )  # fmt: skip
    assert code == 1
    assert f"--min-size {largest + 1} removed all 2 components" in err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["big.ply"]


def test_any_step_that_empties_the_mesh_is_refused(monkeypatch):
    """Decimation cannot remove every triangle today; should a step ever do so,
    post_process refuses (rather than hand an empty mesh to the writer)."""
    from conftest import ball

    from isoconvert import Volume, extract
    from isoconvert.mesh import Mesh
    from isoconvert.post import decimate as decimation
    from isoconvert.post.pipeline import EmptyMeshError, PostOptions, post_process

    volume = Volume(ball(12, 4.0), source="b.npy")
    mesh = extract(volume, 0.0)

    def nothing(mesh, *args, **kwargs):
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), None, dict(mesh.info))

    monkeypatch.setattr(decimation, "decimate", nothing)
    with pytest.raises(EmptyMeshError, match=r"^b\.npy: decimation removed every triangle;"):
        post_process(mesh, volume, PostOptions(decimate=0.5), ambiguity="", flip=False, nan_as=None)


# --- batch into its own input folder ----------------------------------------------------------


def hashes(folder) -> dict:
    import hashlib

    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture
def scans(tmp_path):
    """in/ with two volumes and a note."""
    import shutil

    from conftest import SAMPLES

    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(SAMPLES / "sphere.nrrd", src)
    shutil.copy(SAMPLES / "torus.nrrd", src)
    (src / "notes.txt").write_text("not a volume")
    return src


def summary_rows(path) -> tuple[dict, dict]:
    data = json.loads(path.read_text())
    return {r["input"]: r for r in data["files"]}, data["totals"]


def test_batch_into_its_own_input_folder_converts_and_takes_no_output_for_input(
    scans, tmp_path, capsys
):
    before = hashes(scans)
    report = tmp_path / "s.json"
    code, out, err = run(
        capsys, "batch", scans, "-o", scans, "-l", "0.75", "-j", "1", "--summary", report
    )
    assert code == 0, err
    assert "no volumes found" not in err
    rows, totals = summary_rows(report)
    assert totals["ok"] == 2 and totals["skipped"] == 1  # notes.txt, honestly
    assert {p.name for p in scans.iterdir()} == {
        "sphere.nrrd", "torus.nrrd", "notes.txt", "sphere.ply", "torus.ply",
    }  # fmt: skip
    assert all(hashes(scans)[name] == h for name, h in before.items())  # inputs untouched
    # again: the meshes of the first run are outputs to replace, not inputs skipped
    code, out, err = run(
        capsys, "batch", scans, "-o", scans, "-l", "0.75", "-j", "1", "--force",
        "--summary", report, "--force",
    )  # fmt: skip
    assert code == 0, err
    rows, totals = summary_rows(report)
    assert sorted(rows) == sorted(
        str(scans / n) for n in ("sphere.nrrd", "torus.nrrd", "notes.txt")
    )
    assert totals["ok"] == 2 and totals["skipped"] == 1
    assert "sphere.ply" not in out and "torus.ply" not in out  # the table lists no outputs


def test_an_output_folder_inside_the_input_is_not_searched_and_says_so(scans, tmp_path, capsys):
    import shutil

    from isoconvert.batch import OUTPUT_FOLDER_REASON, discover

    meshes = scans / "meshes"
    code, _, err = run(capsys, "batch", scans, "-r", "-o", meshes, "-l", "0.75", "-j", "1")
    assert code == 0, err
    # a volume put into the output folder is not converted on the next run: it is skipped,
    # and the reason says why
    shutil.copy(scans / "sphere.nrrd", meshes / "copy.nrrd")
    found, skipped = discover([str(scans)], recursive=True, exclude=meshes)
    assert sorted(f.relative.name for f in found) == ["sphere.nrrd", "torus.nrrd"]
    entry = next(s for s in skipped if s.reason == OUTPUT_FOLDER_REASON)
    assert entry.path == str(meshes) and entry.files == 3  # sphere.ply, torus.ply, copy.nrrd
    # when the output folder holds the only volume, "no volumes found" says where it is
    lone = tmp_path / "lone"
    (lone / "meshes").mkdir(parents=True)
    shutil.copy(scans / "sphere.nrrd", lone / "meshes")
    code, _, err = run(capsys, "batch", lone, "-r", "-o", lone / "meshes", "-l", "0.75")
    one_line_error(code, err, "no volumes found", "1 file skipped: the output folder (-o)")


def fake_preview(path):
    """A PNG recording a preview summary, as isoconvert's previews do."""
    from PIL import Image, PngImagePlugin

    from isoconvert.preview.picture import PNG_KEY

    info = PngImagePlugin.PngInfo()
    info.add_text(PNG_KEY, json.dumps({"problems": {}}))
    Image.new("RGB", (8, 8), "white").save(path, pnginfo=info)


def test_previews_in_the_input_folder_are_not_taken_for_images(scans):
    from PIL import Image

    from isoconvert.batch import PREVIEW_REASON, discover

    fake_preview(scans / "sphere.png")
    Image.new("L", (8, 8), 5).save(scans / "photo.png")
    found, skipped = discover([str(scans)], images=True)
    assert sorted(f.relative.name for f in found) == ["photo.png", "sphere.nrrd", "torus.nrrd"]
    assert [s.reason for s in skipped if s.path.endswith("sphere.png")] == [PREVIEW_REASON]


def test_previews_never_replace_a_picture_that_is_not_one(scans, tmp_path, capsys):
    pytest.importorskip("vtkmodules")
    from PIL import Image

    from isoconvert.preview import RenderError, require_renderer

    try:
        require_renderer()
    except RenderError as why:
        pytest.skip(str(why))
    Image.new("L", (8, 8), 5).save(scans / "sphere.png")  # the user's picture of the scan
    before = hashes(scans)
    report = tmp_path / "s.json"
    # a glob of the volumes, writing beside them (as before this fix, too)
    volumes = str(scans / "*.nrrd")
    code, _, err = run(
        capsys, "batch", volumes, "-o", scans, "-l", "0.75", "-j", "1", "--previews",
        "--summary", report,
    )  # fmt: skip
    assert code == 0, err
    assert all(hashes(scans)[name] == h for name, h in before.items())
    rows, _ = summary_rows(report)
    assert "sphere.png exists and is not a preview" in rows[str(scans / "sphere.nrrd")]["message"]
    assert (scans / "torus.png").is_file()  # the other thumbnail is written
    # a page of the user's own named index.html is refused before any work
    (scans / "index.html").write_text("<html>my notes</html>")
    before = hashes(scans)
    code, _, err = run(
        capsys, "batch", volumes, "-o", scans, "-l", "0.75", "--previews", "--force"
    )  # fmt: skip
    one_line_error(code, err, "index.html", "not a contact sheet isoconvert wrote")
    assert hashes(scans) == before


# --- the contact sheet counts as batch does -----------------------------------------------------


class _Sheet:
    """What a contact sheet shows: its totals, its cards, the files listed as skipped."""

    def __init__(self, text: str) -> None:
        from html.parser import HTMLParser

        sheet = self
        self.totals: dict[str, int] = {}
        self.cards: list[dict] = []
        self.skipped: list[str] = []

        class Parser(HTMLParser):
            def __init__(self):
                super().__init__()
                self.stack: list[tuple[str, dict]] = []

            def handle_starttag(self, tag, attrs):
                attrs = dict(attrs)
                self.stack.append((tag, attrs))
                if tag == "figure":
                    sheet.cards.append({"class": attrs.get("class"), "text": ""})
                if tag == "li":
                    sheet.skipped.append("")

            def handle_endtag(self, tag):
                while self.stack and self.stack.pop()[0] != tag:
                    pass

            def handle_data(self, data):
                tags = [t for t, _ in self.stack]
                if self.stack and self.stack[-1][0] == "span":
                    status = self.stack[-1][1].get("data-status")
                    if status is not None:
                        sheet.totals[status] = int(data.split()[0].replace(",", ""))
                if "figure" in tags:
                    sheet.cards[-1]["text"] += data
                if "li" in tags:
                    sheet.skipped[-1] += data

        Parser().feed(text)


def test_contact_sheet_shows_skipped_files_apart_and_counts_as_batch(scans, tmp_path, capsys):
    pytest.importorskip("vtkmodules")
    from isoconvert.preview import RenderError, require_renderer

    try:
        require_renderer()
    except RenderError as why:
        pytest.skip(str(why))
    (scans / "MANIFEST.md").write_text("# scans\n")
    (scans / "make.py").write_text("print('hi')\n")
    out = tmp_path / "out"
    report = tmp_path / "s.json"
    code, stdout, err = run(
        capsys, "batch", scans, "-o", out, "-l", "0.75", "-j", "1", "--previews",
        "--summary", report,
    )  # fmt: skip
    assert code == 0, err
    _, totals = summary_rows(report)
    totals = {k: v for k, v in totals.items() if v}
    sheet = _Sheet((out / "index.html").read_text())
    assert sheet.totals == totals == {"ok": 2, "skipped": 3}
    # the printed table's last line says the same
    printed = dict(
        (status, int(n)) for n, status in re.findall(r"(\d+) ([\w-]+)", stdout.splitlines()[-1])
    )
    assert printed == totals
    # a card per volume, none of them a failure; the three other files listed apart
    assert len(sheet.cards) == 2 and {c["class"] for c in sheet.cards} == {"good"}
    assert sorted(s.split(":")[0] for s in sheet.skipped) == sorted(
        str(scans / n) for n in ("MANIFEST.md", "make.py", "notes.txt")
    )
    assert all("not a volume format" in s for s in sheet.skipped)


def test_labels_emptied_by_min_size_write_no_file_at_all(tmp_path, capsys):
    """Label 1 keeps its surface, label 2's is removed: no file is written (not label 1's
    alone), and the line names label 2."""
    data = np.zeros((20, 20, 20), np.uint8)
    data[2:15, 2:15, 2:15] = 1
    data[16:19, 16:19, 16:19] = 2  # a small cube
    path = save(tmp_path, "lab.npy", data)
    from isoconvert import read_volume
    from isoconvert.extract.labels import label_surfaces

    small = label_surfaces(read_volume(path))[2].n_cells
    code, _, err = run(
        capsys, "convert", path, "-o", tmp_path / "lab.ply", "--labels", "--min-size", small + 1
    )
    one_line_error(code, err, f"lab.npy: label 2: --min-size {small + 1} removed the only")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lab.npy"]


# --- a property of the suggested levels -------------------------------------------------------

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra.numpy import arrays  # noqa: E402

_FLOATS = st.one_of(
    st.sampled_from([np.nan, np.inf, -np.inf, 7.0, np.nextafter(7.0, 8.0), 0.0, -1e308, 1e308]),
    st.floats(allow_nan=False, allow_infinity=False, width=64),
)


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        arrays(np.float64, st.tuples(*[st.integers(1, 4)] * 3), elements=_FLOATS),
        arrays(np.uint8, st.tuples(*[st.integers(1, 4)] * 3)),
        arrays(np.int16, st.tuples(*[st.integers(1, 4)] * 3), elements=st.integers(-3, 3)),
    )
)
# found by hypothesis: a subnormal range overflowed Otsu's bin positions (IndexError)
@example(np.array([[[0.0, 2.22507386e-309]]]))
def test_suggested_levels_are_inside_the_finite_range_or_absent_with_a_reason(data):
    """Each suggested level splits the finite samples (some >= it, some below, the
    sign rule); there are none exactly when no level does, and then a reason."""
    from isoconvert.stats import histogram, no_levels_reason, suggested_levels

    hist = histogram(data)
    finite = data[np.isfinite(data)] if data.dtype.kind == "f" else data.ravel()
    levels = suggested_levels(hist)
    if finite.size == 0 or finite.min() == finite.max():
        assert levels == {} and no_levels_reason(hist)
        return
    assert (hist.low, hist.high) == (finite.min(), finite.max())
    assert no_levels_reason(hist) is None and set(levels) == {"otsu", "p50", "p90", "p99"}
    for value in levels.values():
        above = finite >= value
        assert above.any() and not above.all(), (value, hist.low, hist.high)


def test_a_constant_int64_volume_names_its_value_in_full(tmp_path, capsys):
    value = 2**62 + 2**40  # a float64 holds it exactly; 10 digits would not show it
    path = save(tmp_path, "big.npy", np.full((3, 3, 3), value, np.int64))
    code, out, _ = run(capsys, "info", path, "--json")
    assert json.loads(out)["no_levels_reason"] == (
        f"all samples are {value}: no isosurface at any level"
    )
