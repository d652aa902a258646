"""The contact sheet of ``batch --previews``: thumbnails and index.html."""

from __future__ import annotations

import html
import json
import os
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import IsoconvertError, OutputError, utf8_text
from ..mesh import Mesh
from .marks import PROBLEMS
from .picture import PNG_KEY, render_preview, write_preview

#: Thumbnail size for ``batch --previews``.
THUMBNAIL_SIZE = (400, 300)
#: How a contact sheet's page starts its title: an ``index.html`` without it is
#: someone else's page, never replaced.
SHEET_TITLE = "<title>isoconvert previews</title>"
#: Statuses of a conversion that went wrong (a red frame on the sheet).
BAD_STATUSES = ("failed", "check-failed", "interrupted")


# --- the contact sheet ------------------------------------------------------------------------


def thumbnail_name(mesh_path: str | Path) -> Path:
    """Where ``batch --previews`` puts a mesh's thumbnail: beside it, ``NAME.png``."""
    return Path(mesh_path).with_suffix(".png")


def read_summary(png: str | Path) -> dict | None:
    """What a preview PNG records under :data:`PNG_KEY` (None when it is no preview)."""
    from PIL import Image

    try:
        with Image.open(png) as image:
            text = image.text.get(PNG_KEY)  # type: ignore[attr-defined]
    except (OSError, ValueError, AttributeError):
        return None
    try:
        return json.loads(text) if text else None
    except ValueError:
        return None


@dataclass
class SheetEntry:
    """One row of the contact sheet.

    Attributes
    ----------
    input, output : str
        The volume and the mesh file.
    status : str
        The batch status (ok, failed, check-failed, skipped, ...).
    level : float or None
    vertices, cells : int or None
    message : str
    """

    input: str
    output: str
    status: str
    level: float | None = None
    vertices: int | None = None
    cells: int | None = None
    message: str = ""


def status_counts(entries: Sequence[SheetEntry]) -> dict[str, int]:
    """Entries per status, in order of first appearance: the totals line that
    ``batch`` prints under its table, so that the sheet says the same.

    Parameters
    ----------
    entries : sequence of SheetEntry

    Returns
    -------
    dict of str to int
    """
    counts: dict[str, int] = {}
    for e in entries:
        counts[e.status] = counts.get(e.status, 0) + 1
    return counts


def _not_converted(entry: SheetEntry) -> bool:
    """A file batch skipped as no volume (no mesh of it was ever planned)."""
    return entry.status == "skipped" and not entry.output


def contact_sheet(entries: Sequence[SheetEntry], folder: str | Path) -> str:
    """An HTML page of thumbnails, openable from disk (links relative to ``folder``).

    A card per volume (converted, failed, or skipped because its mesh exists);
    the files skipped as no volume (notes, scripts) are listed apart, with
    their reasons, and are not failures. The totals line counts every entry
    by status, as ``batch``'s summary does (``<span class="count"
    data-status="ok">``).

    Parameters
    ----------
    entries : sequence of SheetEntry
    folder : str or Path
        Where the page goes; thumbnails and meshes are linked relative to it.

    Returns
    -------
    str
        The page: no script, no style sheet or font from the network.
    """
    folder = Path(folder)

    def relative(path: Path) -> str:
        try:
            rel = os.path.relpath(path, folder)
        except ValueError:  # another drive (Windows)
            rel = str(path.resolve())
        # a URL (# ? % and spaces in file names would be read as URL syntax), then
        # escaped for the attribute
        # quoted from the name's bytes, so a name that is not UTF-8 still links
        return html.escape(urllib.parse.quote(os.fsencode(Path(rel).as_posix()), safe="/"))

    cards = []
    for e in entries:
        if _not_converted(e):
            continue
        mesh = Path(e.output) if e.output else None
        thumb = thumbnail_name(mesh) if mesh else None
        summary = read_summary(thumb) if thumb and thumb.is_file() else None
        if summary is not None:
            picture = f'<a href="{relative(thumb)}"><img src="{relative(thumb)}" alt=""></a>'
        else:
            picture = '<div class="none">no preview</div>'
        problems = (summary or {}).get("problems") or {}
        found = [f"{PROBLEMS[k][0]} {v:,}" for k, v in problems.items() if v and k in PROBLEMS]
        # what the picture's own footer says, which is what check says (NaN vertices,
        # failed checks with nothing to mark: misorientation, an empty mesh)
        # (a surface the grid cuts open fails only watertight: its boundary is no hole,
        # and the card says so without a red frame)
        recorded = summary or {}
        broken = [c for c in recorded.get("failed_checks") or () if c != "watertight"]
        failing = bool(broken or recorded.get("non_finite_vertices"))
        if e.status not in ("ok", "check-failed"):
            report = ""
        elif summary is None:
            report = "not checked"
        elif summary.get("footer"):
            report = "; ".join(summary["footer"])
        else:
            report = "; ".join(found) if found else "no problems found"
        status = e.status + (f": {e.message}" if e.message and e.status != "ok" else "")
        name = html.escape(mesh.name if mesh else Path(e.input).name)
        link = f'<a href="{relative(mesh)}">{name}</a>' if mesh and mesh.is_file() else name
        facts = [
            f"from {html.escape(e.input)}",
            "" if e.level is None else f"level {e.level:g}",
            "" if e.vertices is None else f"{e.vertices:,} vertices, {e.cells or 0:,} triangles",
            f"report: {html.escape(report)}" if report else "",
        ]
        if e.status in BAD_STATUSES or found or failing:
            klass = "bad"
        else:
            klass = "skipped" if e.status == "skipped" else "good"
        cards.append(
            f'<figure class="{klass}">{picture}<figcaption><b>{link}</b><br>'
            + "<br>".join(f for f in facts if f)
            + f'<br><span class="status">{html.escape(status)}</span></figcaption></figure>'
        )
    totals = ", ".join(
        f'<span class="count" data-status="{html.escape(status, quote=True)}">'
        f"{n:,} {html.escape(status)}</span>"
        for status, n in status_counts(entries).items()
    )
    others = [e for e in entries if _not_converted(e)]
    listed = ""
    if others:
        items = "".join(
            f"<li>{html.escape(e.input)}: {html.escape(e.message or 'skipped')}</li>"
            for e in others
        )
        listed = (
            f"\n<h2>Not converted: {len(others):,} file{'s' if len(others) != 1 else ''} "
            f'skipped</h2>\n<ul class="skipped">{items}</ul>'
        )
    return (
        '<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
        f"{SHEET_TITLE}<style>"
        "body{font-family:sans-serif;margin:1em}"
        "figure{display:inline-block;vertical-align:top;width:410px;margin:6px;"
        "border:1px solid #ccc;padding:4px}"
        "figure.bad{border-color:#e00}figure.skipped{border-color:#999}img{width:400px}"
        ".none{width:400px;height:300px;background:#eee;line-height:300px;text-align:center}"
        "figcaption{font-size:13px;word-wrap:break-word}.status{color:#555}"
        "ul.skipped{color:#555;font-size:13px}"
        "</style></head><body>\n"
        "<h1>isoconvert previews</h1>\n"
        f'<p class="totals">{totals}</p>\n' + "\n".join(cards) + listed + "\n</body></html>\n"
    )


def check_contact_sheet(folder: str | Path, name: str = "index.html") -> Path:
    """Fail before a batch's work when ``folder/name`` is a file isoconvert did not
    write (a page of the user's own, in a batch into its input folder).

    Returns
    -------
    Path
        Where the sheet goes.

    Raises
    ------
    OutputError
        The file exists and is no contact sheet, or is no regular file.
    """
    path = Path(folder) / name
    if path.exists() or path.is_symlink():
        try:
            with open(path, "rb") as fh:
                head = fh.read(4096).decode("utf-8", errors="replace")
        except OSError:
            head = ""
        if not path.is_file() or SHEET_TITLE not in head:
            raise OutputError(
                f"{path}: exists and is not a contact sheet isoconvert wrote; the previews' "
                "index.html would replace it: move it, or choose another -o"
            )
    return path


def write_contact_sheet(
    entries: Sequence[SheetEntry], folder: str | Path, name: str = "index.html"
) -> Path:
    """Write :func:`contact_sheet` as ``folder/name`` (replacing an older sheet,
    never another file: :func:`check_contact_sheet`)."""
    from ..atomic import atomic_output

    path = check_contact_sheet(folder, name)
    with atomic_output(path, force=True) as fh:
        fh.write(utf8_text(contact_sheet(entries, folder)))
    return path


def batch_thumbnail(
    mesh: Mesh, checked: Mesh, output: str | Path, grid: dict | None, report=None
) -> str:
    """Write a batch job's thumbnail beside its mesh; returns "" or why it failed.

    Called in the worker that converted the mesh, so the mesh is not read again
    (nor checked again when ``report``, made with ``examples=MAX_MARKS``, is given).
    A file already at the thumbnail's name that is not a preview (a picture
    beside the scans, in a batch into its input folder) is left as it is.
    """
    thumb = thumbnail_name(output)
    if (thumb.exists() or thumb.is_symlink()) and read_summary(thumb) is None:
        return f"no preview: {thumb} exists and is not a preview isoconvert wrote; left as it is"
    try:
        preview = render_preview(
            mesh, size=THUMBNAIL_SIZE, checked=checked, grid=grid, report=report
        )
        write_preview(preview, thumb, force=True)
    except IsoconvertError as exc:
        return f"no preview: {exc}"
    return ""
