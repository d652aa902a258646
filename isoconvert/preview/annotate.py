"""Pillow annotations: problem marks, panel titles, axis arrows, legend and scale bar."""

from __future__ import annotations

import math

import numpy as np

from ..checks import CHECK_NAMES
from .marks import PROBLEMS, Marks
from .views import Layout, View

#: Names of the positive and negative axis directions per frame.
_AXIS_NAMES = {
    None: (("+x", "+y", "+z"), ("-x", "-y", "-z")),
    "LPS": (("L", "P", "S"), ("R", "A", "I")),
    "RAS": (("R", "A", "S"), ("L", "P", "I")),
}


# --- annotations ------------------------------------------------------------------------------


def _font(size: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _ink(background: tuple[int, int, int]) -> tuple[int, int, int]:
    """Black on light backgrounds, white on dark ones."""
    r, g, b = background
    return (0, 0, 0) if 0.299 * r + 0.587 * g + 0.114 * b > 128 else (255, 255, 255)


def _finite(points: np.ndarray) -> np.ndarray:
    return points[np.isfinite(points).all(axis=tuple(range(1, points.ndim)))]


def _draw_marks(draw, views: list[View], marks: Marks, layout: Layout) -> None:
    """Problems over the surface, clipped to each panel, in their flat colours."""
    width = max(1, round(min(layout.width, layout.height) / 350))
    radius = max(2, round(min(layout.width, layout.height) / 200))
    for view in views:
        x0, y0, x1, y1 = view.box
        for name, ends in marks.edges.items():
            ends = _finite(ends)
            if not len(ends):
                continue
            colour = PROBLEMS[name][1]
            xy = view.project(ends.reshape(-1, 3)).reshape(-1, 4)
            for a, b, c, d in xy.tolist():
                if max(a, c) < x0 or min(a, c) >= x1 or max(b, d) < y0 or min(b, d) >= y1:
                    continue
                draw.line([(a, b), (c, d)], fill=colour, width=width)
        for name, points in marks.points.items():
            points = _finite(points)
            if not len(points):
                continue
            colour = PROBLEMS[name][1]
            for a, b in view.project(points).tolist():
                if x0 <= a < x1 and y0 <= b < y1:
                    draw.ellipse([a - radius, b - radius, a + radius, b + radius], fill=colour)
        # a mark near a panel's edge must not spill into the neighbour
    return None


def _nice_length(most: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``most``."""
    if not most > 0:
        return 0.0
    power = 10.0 ** math.floor(math.log10(most))
    for step in (5.0, 2.0, 1.0):
        if step * power <= most:
            return step * power
    return power


def _axis_arrows(draw, view: View, layout: Layout, frame: str | None, ink, font) -> None:
    """Small labelled arrows for the world axes, in the panel's bottom-left corner."""
    x0, y0, x1, y1 = view.box
    length = 0.09 * min(x1 - x0, y1 - y0)
    ox, oy = x0 + 0.05 * (x1 - x0) + 4, y1 - 0.05 * (y1 - y0) - 4
    positive, _ = _AXIS_NAMES.get(frame, _AXIS_NAMES[None])
    for a in range(3):
        axis = np.zeros(3)
        axis[a] = 1.0
        sx, sy = axis @ view.right, -(axis @ view.up)
        if math.hypot(sx, sy) < 0.2:  # pointing at the viewer: not drawn
            continue
        tip = (ox + sx * length, oy + sy * length)
        draw.line([(ox, oy), tip], fill=ink, width=1)
        label = positive[a].lstrip("+")
        draw.text((tip[0] + 2 * sx, tip[1] + 2 * sy), label, fill=ink, font=font, anchor="mm")


def _view_title(view: View, frame: str | None) -> str:
    positive, negative = _AXIS_NAMES.get(frame, _AXIS_NAMES[None])
    if view.name == "oblique":
        return "oblique"
    a = int(np.argmax(np.abs(view.toward)))
    side = positive[a] if view.toward[a] > 0 else negative[a]
    return f"{view.name}, from {side}"


#: What the footer says when the report finds nothing wrong.
ALL_PASS = "no holes, non-manifold or zero-length edges found"


def footer_items(marks: Marks | None) -> list[tuple[tuple[int, int, int] | None, str]]:
    """The footer's legend: (swatch colour or None, text) per item, from the report.

    Vertices that are NaN or infinite first (not drawn), then each drawn problem
    with its count, then the checks the report fails; :data:`ALL_PASS` only
    when the report fails none, so the picture never calls a mesh fine that
    ``isoconvert check`` fails.
    """
    if marks is None:
        return []
    items: list[tuple[tuple[int, int, int] | None, str]] = []
    if marks.non_finite:
        n = marks.non_finite
        items.append(
            (None, f"{n:,} {'vertex is' if n == 1 else 'vertices are'} NaN/Inf: not drawn")
        )
    for name, (label, colour) in PROBLEMS.items():  # only what was found
        count = marks.counts.get(name, 0)
        if not count:
            continue
        shown = len(marks.edges.get(name, marks.points.get(name, ())))
        items.append(
            (colour, f"{label} {count:,}" + (f" ({shown:,} drawn)" if shown < count else ""))
        )
    if marks.failed and len(marks.failed) == len(CHECK_NAMES):
        items.append((None, "check fails every test"))
    elif marks.failed:
        items.append((None, "check fails " + ", ".join(marks.failed)))
    elif not items:
        items.append((None, ALL_PASS))
    return items


def _footer(draw, layout: Layout, marks: Marks | None, scale: float, unit: str, ink, font) -> None:
    """Legend (:func:`footer_items`) on the left, scale bar on the right."""
    top = layout.height - layout.footer
    mid = top + layout.footer / 2
    x = 6.0
    swatch = max(6, round(layout.font * 0.8))
    for colour, text in footer_items(marks):
        if colour is not None:
            draw.rectangle([x, mid - swatch / 2, x + swatch, mid + swatch / 2], fill=colour)
            x += swatch + 3
        draw.text((x, mid), text, fill=ink, font=font, anchor="lm")
        x += draw.textlength(text, font=font) + 10
    # scale bar: a round length of at most a fifth of a panel's width
    length = _nice_length(0.2 * layout.panel[0] * scale)
    if length > 0:
        pixels = length / scale
        label = f"{length:g} {unit}".strip()
        right = layout.width - 8
        left = right - pixels
        text_width = draw.textlength(label, font=font)
        if left - text_width - 6 > x:  # room beside the legend
            draw.line([(left, mid), (right, mid)], fill=ink, width=2)
            for end in (left, right):
                draw.line([(end, mid - 4), (end, mid + 4)], fill=ink, width=1)
            draw.text((left - 6, mid), label, fill=ink, font=font, anchor="rm")
