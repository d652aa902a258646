"""View geometry: parallel projections of the world onto the panels of a picture."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# --- views -------------------------------------------------------------------------------


@dataclass
class View:
    """One panel: a parallel projection of the world onto pixels.

    Attributes
    ----------
    name : str
        "top", "front", "side" or "oblique".
    toward : (3,) float64
        Unit vector from the object toward the camera.
    right, up : (3,) float64
        Unit screen directions in world coordinates (``right x up = toward``).
    center : (3,) float64
        World point drawn at ``pixel_center``.
    pixel_center : (2,) float64
        Image coordinates (x to the right, y down, pixel edges at integers).
    scale : float
        World units per pixel.
    box : (4,) int
        The panel's pixels: x0, y0, x1, y1 (exclusive).
    """

    name: str
    toward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    center: np.ndarray
    pixel_center: np.ndarray
    scale: float
    box: tuple[int, int, int, int]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Image coordinates of world points.

        Parameters
        ----------
        points : (N, 3) float

        Returns
        -------
        (N, 2) float64
            x (column) and y (row) in pixels, continuous: pixel (c, r) covers
            ``c <= x < c + 1``, ``r <= y < r + 1``.
        """
        d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.center
        x = self.pixel_center[0] + d @ self.right / self.scale
        y = self.pixel_center[1] - d @ self.up / self.scale
        return np.column_stack([x, y])


def _directions() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, toward, up) of the four views; right = up x toward."""
    oblique = np.array([1.0, -1.0, 1.0]) / math.sqrt(3.0)
    z = np.array([0.0, 0.0, 1.0])
    oblique_up = z - oblique * (z @ oblique)
    return [
        ("top", np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
        ("front", np.array([0.0, -1.0, 0.0]), z),
        ("side", np.array([1.0, 0.0, 0.0]), z),
        ("oblique", oblique, oblique_up / np.linalg.norm(oblique_up)),
    ]


@dataclass(frozen=True)
class Layout:
    """Where panels, titles and the footer go in a ``width x height`` image."""

    width: int
    height: int

    @property
    def footer(self) -> int:
        return max(18, round(self.height * 0.075))

    @property
    def panel(self) -> tuple[int, int]:
        return self.width // 2, (self.height - self.footer) // 2

    @property
    def title(self) -> int:
        return max(11, round(self.panel[1] * 0.07))

    @property
    def font(self) -> int:
        return max(9, round(self.title * 0.8))

    def panel_box(self, k: int) -> tuple[int, int, int, int]:
        pw, ph = self.panel
        x0, y0 = (k % 2) * pw, (k // 2) * ph
        return x0, y0, x0 + pw, y0 + ph

    def inner(self, k: int) -> tuple[float, float, float, float]:
        """The part of panel ``k`` the object is fitted into: x0, y0, x1, y1."""
        x0, y0, x1, y1 = self.panel_box(k)
        mx, my = 0.08 * (x1 - x0), 0.06 * (y1 - y0)
        return x0 + mx, y0 + self.title + my, x1 - mx, y1 - my


def make_views(bounds: np.ndarray, layout: Layout) -> list[View]:
    """The four views that fit a bounding box into the layout's panels.

    Parameters
    ----------
    bounds : (2, 3) float
        Lowest and highest corner of the object.
    layout : Layout

    Returns
    -------
    list of View
        One scale for all four: the largest any panel needs to hold the box.
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = 0.5 * (lo + hi)
    corners = np.array([[(lo, hi)[(i >> a) & 1][a] for a in range(3)] for i in range(8)])
    scale = 0.0
    directions = _directions()
    for k, (_, toward, up) in enumerate(directions):
        right = np.cross(up, toward)
        x0, y0, x1, y1 = layout.inner(k)
        d = corners - center
        scale = max(scale, np.ptp(d @ right) / (x1 - x0), np.ptp(d @ up) / (y1 - y0))
    if not scale > 0:  # a single point: any scale shows it
        scale = max(float(np.abs(center).max()), 1.0) * 1e-3
    views = []
    for k, (name, toward, up) in enumerate(directions):
        x0, y0, x1, y1 = layout.inner(k)
        views.append(
            View(
                name,
                toward,
                np.cross(up, toward),
                up,
                center,
                np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)]),
                float(scale),
                layout.panel_box(k),
            )
        )
    return views
