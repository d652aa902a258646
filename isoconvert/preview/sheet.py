"""The contact sheet of ``batch --previews``: thumbnails and index.html."""

from __future__ import annotations

import html
import json
import os
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import IsoconvertError
from ..mesh import Mesh
from .marks import PROBLEMS
from .picture import PNG_KEY, render_preview, write_preview

#: Thumbnail size for ``batch --previews``.
THUMBNAIL_SIZE = (400, 300)


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


def contact_sheet(entries: Sequence[SheetEntry], folder: str | Path) -> str:
    """An HTML page of thumbnails, openable from disk (links relative to ``folder``).

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
        return html.escape(urllib.parse.quote(Path(rel).as_posix(), safe="/"), quote=True)

    cards = []
    for e in entries:
        mesh = Path(e.output) if e.output else None
        thumb = thumbnail_name(mesh) if mesh else None
        summary = read_summary(thumb) if thumb and thumb.is_file() else None
        if summary is not None:
            picture = f'<a href="{relative(thumb)}"><img src="{relative(thumb)}" alt=""></a>'
        else:
            picture = '<div class="none">no preview</div>'
        problems = (summary or {}).get("problems") or {}
        found = [f"{PROBLEMS[k][0]} {v:,}" for k, v in problems.items() if v and k in PROBLEMS]
        if e.status not in ("ok", "check-failed"):
            report = ""
        elif summary is None:
            report = "not checked"
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
        klass = "bad" if (e.status != "ok" or found) else "good"
        cards.append(
            f'<figure class="{klass}">{picture}<figcaption><b>{link}</b><br>'
            + "<br>".join(f for f in facts if f)
            + f'<br><span class="status">{html.escape(status)}</span></figcaption></figure>'
        )
    return (
        '<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
        "<title>isoconvert previews</title><style>"
        "body{font-family:sans-serif;margin:1em}"
        "figure{display:inline-block;vertical-align:top;width:410px;margin:6px;"
        "border:1px solid #ccc;padding:4px}"
        "figure.bad{border-color:#e00}img{width:400px}"
        ".none{width:400px;height:300px;background:#eee;line-height:300px;text-align:center}"
        "figcaption{font-size:13px;word-wrap:break-word}.status{color:#555}"
        "</style></head><body>\n"
        f"<h1>isoconvert previews ({len(entries)} files)</h1>\n"
        + "\n".join(cards)
        + "\n</body></html>\n"
    )


def write_contact_sheet(
    entries: Sequence[SheetEntry], folder: str | Path, name: str = "index.html"
) -> Path:
    """Write :func:`contact_sheet` as ``folder/name`` (replacing an older one)."""
    from ..atomic import atomic_output

    path = Path(folder) / name
    with atomic_output(path, force=True) as fh:
        fh.write(contact_sheet(entries, folder).encode("utf-8"))
    return path


def batch_thumbnail(
    mesh: Mesh, checked: Mesh, output: str | Path, grid: dict | None, report=None
) -> str:
    """Write a batch job's thumbnail beside its mesh; returns "" or why it failed.

    Called in the worker that converted the mesh, so the mesh is not read again
    (nor checked again when ``report``, made with ``examples=MAX_MARKS``, is given).
    """
    try:
        preview = render_preview(
            mesh, size=THUMBNAIL_SIZE, checked=checked, grid=grid, report=report
        )
        write_preview(preview, thumbnail_name(output), force=True)
    except IsoconvertError as exc:
        return f"no preview: {exc}"
    return ""
