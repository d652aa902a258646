"""Header text shared by the writers and by :func:`isoconvert.meshfile.read_mesh`.

Provenance comments carry text from outside (an input path, a plugin's method
name), so every writer passes it through :func:`escape_comment`: a newline in a
path must not end a PLY or OBJ comment and start a header line of its own, a
PLY header is ASCII, an XML comment may not hold ``--``. The escapes are
Python's (``\\n``, ``\\xfc``, ``\\u00e9``, ``\\\\`` for a backslash), so
:func:`unescape_comment` gives the text back exactly.

The grid an extracted mesh came from (``mesh.info["grid"]``) is recorded as
one comment line, ``isoconvert grid {compact JSON}``, in PLY and OBJ headers.
"""

from __future__ import annotations

import json
import numbers
import re
import unicodedata

from ..geometry import normalized_grid
from ..mesh import Mesh

#: Comment text (after ``comment `` in PLY, ``# `` in OBJ) that starts the grid record.
GRID_PREFIX = "isoconvert grid "
#: Unicode categories that are escaped everywhere: control characters (newline,
#: carriage return, tab, NEL, ...), line and paragraph separators, surrogates
#: (undecodable bytes of a file name; invalid in UTF-8) and unassigned code points.
_ESCAPED_CATEGORIES = frozenset({"Cc", "Zl", "Zp", "Cs", "Cn"})
_SHORT_ESCAPES = {"\\": "\\\\", "\n": "\\n", "\r": "\\r", "\t": "\\t"}
_UNESCAPE = re.compile(r"\\(\\|n|r|t|x[0-9a-fA-F]{2}|u[0-9a-fA-F]{4}|U[0-9a-fA-F]{8})")


def _escape_char(char: str) -> str:
    if char in _SHORT_ESCAPES:
        return _SHORT_ESCAPES[char]
    code = ord(char)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def escape_comment(text: str, *, ascii: bool = False, xml: bool = False) -> str:
    """``text`` made safe for one comment line of a file header.

    Parameters
    ----------
    text : str
    ascii : bool
        Escape every non-ASCII character too (PLY headers are ASCII).
    xml : bool
        Also escape a ``-`` that follows another ``-`` or ends the text, so the
        text can sit inside ``<!-- ... -->`` (which may not contain ``--``).

    Returns
    -------
    str
        One line, no control characters, valid UTF-8 (ASCII with ``ascii``).
        Backslashes are doubled, so :func:`unescape_comment` inverts it.
    """
    out = []
    previous = ""
    for char in text:
        if (
            char == "\\"
            or (ascii and ord(char) > 0x7E)
            or unicodedata.category(char) in _ESCAPED_CATEGORIES
        ):
            out.append(_escape_char(char))
        elif xml and char == "-" and previous == "-":
            out.append("\\x2d")
        else:
            out.append(char)
        previous = char
    if xml and out and out[-1] == "-":
        out[-1] = "\\x2d"
    return "".join(out)


def unescape_comment(text: str) -> str:
    """The text :func:`escape_comment` was given.

    Parameters
    ----------
    text : str
        An escaped comment (other text with backslashes comes back with the
        recognized escapes decoded).

    Returns
    -------
    str
    """

    def decode(match: re.Match) -> str:
        code = match.group(1)
        if len(code) == 1:
            return {"\\": "\\", "n": "\n", "r": "\r", "t": "\t"}[code]
        return chr(int(code[1:], 16))

    return _UNESCAPE.sub(decode, text)


def provenance(mesh: Mesh) -> list[str]:
    """Comment lines saying what made the mesh, not yet escaped.

    Returns
    -------
    list of str
        ``made by isoconvert VERSION``, then ``source PATH``, ``method M
        level L``, ``ambiguity R``, ``frame LPS`` (or RAS), ``unit U``,
        ``normals FROM`` and ``values FROM`` when ``mesh.info`` has them.
    """
    info = mesh.info
    if not info:
        return ["made by isoconvert"]
    from .. import __version__

    lines = [f"made by isoconvert {__version__}"]
    if "source" in info:
        lines.append(f"source {info['source']}")
    if "method" in info:
        level = info.get("level", "?")
        level = f"{level:.17g}" if isinstance(level, numbers.Real) else str(level)
        lines.append(f"method {info['method']} level {level}")
    if "ambiguity" in info:
        lines.append(f"ambiguity {info['ambiguity']}")
    if "frame" in info:
        lines.append(f"frame {info['frame']}")
    if "unit" in info:
        lines.append(f"unit {info['unit']}")
    # where per-vertex attributes came from
    for attribute in ("normals", "values"):
        if attribute in info:
            lines.append(f"{attribute} {info[attribute]}")
    return lines


def grid_comment(grid: object) -> str | None:
    """The grid record, ``isoconvert grid {...}`` (compact JSON, floats as repr),
    or None when ``grid`` is not a usable grid (:func:`normalized_grid`)."""
    grid = normalized_grid(grid)
    if grid is None:
        return None
    return GRID_PREFIX + json.dumps(grid, separators=(",", ":"), allow_nan=False)


def parse_grid_comment(text: str) -> dict | None:
    """The grid of a comment :func:`grid_comment` made, or None.

    Parameters
    ----------
    text : str
        One comment's text (without ``comment `` or ``# ``).

    Returns
    -------
    dict or None
        None when the text is no grid record or a malformed one.
    """
    if not text.startswith(GRID_PREFIX):
        return None
    try:
        return normalized_grid(json.loads(text[len(GRID_PREFIX) :]))
    except (ValueError, RecursionError):
        return None


def header_comments(mesh: Mesh, *, ascii: bool) -> list[str]:
    """Every comment a PLY or OBJ header gets: provenance, then the grid.

    Parameters
    ----------
    mesh : Mesh
    ascii : bool
        Escape non-ASCII characters too (PLY).

    Returns
    -------
    list of str
        Escaped comment texts, one line each.
    """
    lines = [escape_comment(line, ascii=ascii) for line in provenance(mesh)]
    grid = grid_comment(mesh.info.get("grid"))
    if grid is not None:
        lines.append(grid)
    return lines
