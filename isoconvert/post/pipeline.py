"""The post-processing steps of a conversion, in order, and what they changed.

Order: close at the grid's faces (it needs the surface as extracted, with its
edge ids), clean up components (cheaper steps after it work on less), smooth,
then decimate (a smoothed surface decimates with a smaller error).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..volume import Volume
from .smooth import METHODS, SmoothOptions


class EmptyMeshError(IsoconvertError):
    """A post-processing step removed every triangle: there is nothing to write."""


@dataclass(frozen=True)
class PostOptions:
    """What happens to a surface after extraction (all off by default).

    Attributes
    ----------
    close : bool
        Cap the surface on the grid's faces (cubes only), as if the volume were
        padded with values below the level.
    keep : int or None
        Keep the ``keep`` largest components (by triangles); ``--largest`` is 1.
    min_size : int or None
        Drop components of fewer triangles.
    min_volume : float or None
        Drop closed components enclosing less (world units cubed; open ones,
        which enclose none, are kept).
    fill_cavities : bool
        Drop closed components inside another closed component.
    smooth : int
        Smoothing iterations (0: none).
    smooth_method : str
        "sinc" (windowed sinc), "taubin" or "laplacian" (shrinks).
    passband : float
        The smoothing filter's pass band, in (0, 2); smaller smooths more.
    decimate : float or None
        Fraction of triangles to remove, in [0, 1).
    max_error : float or None
        Largest distance (world units) between the decimated and the original
        surface, both ways (a Hausdorff bound); alone,
        decimates as far as it allows.
    """

    close: bool = False
    keep: int | None = None
    min_size: int | None = None
    min_volume: float | None = None
    fill_cavities: bool = False
    smooth: int = 0
    smooth_method: str = "sinc"
    passband: float = 0.1
    decimate: float | None = None
    max_error: float | None = None

    def __post_init__(self) -> None:
        if self.keep is not None and self.keep < 1:
            raise IsoconvertError(f"--keep takes a number of components >= 1, got {self.keep}")
        if self.min_size is not None and self.min_size < 1:
            raise IsoconvertError(f"--min-size takes a triangle count >= 1, got {self.min_size}")
        if self.min_volume is not None and not self.min_volume > 0:
            raise IsoconvertError(
                f"--min-volume takes a volume in world units cubed > 0, got {self.min_volume}"
            )
        if self.smooth_method not in METHODS:
            raise IsoconvertError(
                f"unknown --smooth-method {self.smooth_method!r}; choose from: {', '.join(METHODS)}"
            )
        if self.smooth:
            SmoothOptions(self.smooth, self.smooth_method, self.passband)  # checks them
        if self.decimate is not None and not 0.0 <= self.decimate < 1.0:
            raise IsoconvertError(
                f"--decimate takes the fraction of triangles to remove, 0 <= F < 1, got "
                f"{self.decimate}; e.g. --decimate 0.9 keeps about 10%"
            )
        if self.max_error is not None and not 0 < self.max_error < math.inf:
            raise IsoconvertError(
                f"--max-error takes a finite distance in world units > 0, got {self.max_error}; "
                "leave it out for no bound"
            )

    @property
    def steps(self) -> list[str]:
        """The steps that will run, in order."""
        steps = []
        if self.close:
            steps.append("close")
        if self.fill_cavities:
            steps.append("fill-cavities")
        if self.min_size is not None:
            steps.append(f"min-size {self.min_size}")
        if self.min_volume is not None:
            steps.append(f"min-volume {self.min_volume:g}")
        if self.keep is not None:
            steps.append("largest" if self.keep == 1 else f"keep {self.keep}")
        if self.smooth:
            steps.append(f"smooth {self.smooth} {self.smooth_method}")
        if self.decimate is not None or self.max_error is not None:
            steps.append("decimate")
        return steps

    def check_method(self, method: str) -> None:
        """Refuse steps that the extraction method cannot give them input for."""
        if self.close and method != "cubes":
            raise IsoconvertError(f"--close caps cubes surfaces; use --method cubes (got {method})")
        if self.steps and method == "squares":
            raise IsoconvertError(
                f"post-processing ({', '.join(self.steps)}) works on surfaces; squares gives "
                "contours"
            )


def post_process(
    mesh: Mesh,
    volume: Volume,
    options: PostOptions,
    *,
    ambiguity: str,
    flip: bool,
    nan_as: float | None,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Run the steps of ``options`` on a surface extracted from ``volume``.

    Parameters
    ----------
    mesh : Mesh
        As :func:`isoconvert.extract` returned it (``info["level"]`` included).
    volume : Volume
    options : PostOptions
    ambiguity, flip, nan_as
        As the extraction used them (the cap follows the same rules).
    on_status : callable or None
        Receives a line per step that changed the mesh.

    Returns
    -------
    Mesh
        With at least one triangle when ``mesh`` has one.

    Raises
    ------
    EmptyMeshError
        A step removed every triangle (a minimum above every component, say):
        an empty file helps nobody, so the message says by how much to lower it.
    """
    if options.close:
        from .cap import close_at_grid

        mesh = close_at_grid(
            mesh,
            volume,
            float(mesh.info["level"]),
            ambiguity=ambiguity,
            flip=flip,
            nan_as=nan_as,
        )
    small = options.min_size is not None or options.min_volume is not None
    if options.fill_cavities or small or options.keep is not None:
        from .components import drop_small, fill_cavities, keep_largest

        if options.fill_cavities:
            mesh = _not_emptied(fill_cavities(mesh), mesh, "--fill-cavities", volume)
        if small:
            flags = " and ".join(
                f"--{name} {value:g}"
                for name, value in (
                    ("min-size", options.min_size),
                    ("min-volume", options.min_volume),
                )
                if value is not None
            )
            mesh = _not_emptied(
                drop_small(mesh, min_triangles=options.min_size, min_volume=options.min_volume),
                mesh,
                flags,
                volume,
            )
        if options.keep is not None:
            mesh = _not_emptied(keep_largest(mesh, options.keep), mesh, "--keep", volume)
    if options.smooth:
        from .smooth import smooth

        mesh = smooth(mesh, options.smooth, options.smooth_method, passband=options.passband)
        held = mesh.info["smoothing"].get("held_small_components", 0)
        if held and on_status:
            from .smooth import MIN_COMPONENT_VERTICES

            on_status(
                f"note: smoothing held {held} components of fewer than "
                f"{MIN_COMPONENT_VERTICES} vertices as they were (a low-pass filter shrinks "
                "them to points); drop them with --min-size"
            )
    if options.decimate is not None or options.max_error is not None:
        from .decimate import decimate

        before = mesh.n_cells
        mesh = _not_emptied(
            decimate(mesh, options.decimate, options.max_error), mesh, "decimation", volume
        )
        removed = 1.0 - mesh.n_cells / before if before else 0.0
        asked = options.decimate
        if on_status and (asked is None and removed == 0 or asked and removed < asked - 0.01):
            why = (
                "within --max-error"
                if asked is None
                else "keeping the topology (thin walls, small components)"
            )
            on_status(
                f"note: decimation removed {removed:.1%} of the triangles, as many as it could "
                f"{why}"
            )
    return mesh


def _not_emptied(after: Mesh, before: Mesh, flags: str, volume: Volume) -> Mesh:
    """``after``, unless the step (``flags``, as typed) removed every triangle of ``before``.

    Raises
    ------
    EmptyMeshError
        ``after`` has no triangle and ``before`` had some; the message counts the
        components and, for a minimum, gives the largest component's size.
    """
    if after.n_cells or not before.n_cells:
        return after
    record = (after.info.get("cleanup") or [{}])[-1]
    n = int(record.get("components_before", 0))
    what = "the only component" if n == 1 else f"all {n:,} components"
    if flags == "decimation":  # it records no components
        what = "every triangle"
    largest = []
    if record.get("step") == "drop_small":
        count = int(record["largest_triangles"])
        if record.get("min_triangles") is not None:
            largest.append(
                f"it has {count:,} triangles" if n == 1 else f"the largest has {count:,} triangles"
            )
        enclosed = record.get("largest_volume")
        if record.get("min_volume") is not None and enclosed is not None:
            unit = f" {volume.unit}³" if volume.unit else ""
            closed = "it encloses" if n == 1 else "the largest encloses"
            largest.append(f"{closed} {enclosed:.6g}{unit}")
        fix = "lower them" if " and " in flags else "lower it"
    else:
        fix = "leave it out"
    detail = f" ({'; '.join(largest)})" if largest else ""
    raise EmptyMeshError(f"{volume.source}: {flags} removed {what}{detail}; {fix}")


#: What :func:`changes` compares: (label, where in the report's dict).
_COMPARED = (
    ("triangles", ("counts", "triangles")),
    ("vertices", ("counts", "vertices")),
    ("components", ("topology", "components")),
    ("Euler characteristic", ("topology", "euler_characteristic")),
    ("holes (boundary edges inside)", ("problems", "boundary_edges_inside", "count")),
    ("boundary edges on the grid", ("problems", "boundary_edges_on_domain_boundary", "count")),
    ("non-manifold edges", ("problems", "non_manifold_edges", "count")),
    ("non-manifold vertices", ("problems", "non_manifold_vertices", "count")),
    ("area", ("measures", "area")),
    ("volume", ("measures", "volume")),
)


def changes(before: dict, after: dict) -> list[str]:
    """Lines saying what post-processing changed, from two reports' dicts
    (:meth:`~isoconvert.report.MeshReport.to_dict`): the compared measures, then
    each check that passed before and fails after, or the other way."""

    def get(report: dict, path: tuple[str, ...]):
        for key in path:
            if not isinstance(report, dict) or key not in report:
                return None
            report = report[key]
        return report

    unit = get(after, ("measures", "unit"))
    powers = {"area": "²", "volume": "³"}
    lines = []
    for label, path in _COMPARED:
        a, b = get(before, path), get(after, path)
        if a is None or b is None:
            continue
        if isinstance(a, float) or isinstance(b, float):
            if a == b:
                continue
            relative = f" ({(b - a) / abs(a):+.2%})" if a else ""
            suffix = f" {unit}{powers[label]}" if unit and label in powers else ""
            lines.append(f"{label}: {a:.6g} -> {b:.6g}{suffix}{relative}")
        elif a != b:
            lines.append(f"{label}: {a:,} -> {b:,}")
    for name, passed in (before.get("checks") or {}).items():
        now = (after.get("checks") or {}).get(name)
        if now is not None and now != passed:
            lines.append(f"{name}: {'PASS' if passed else 'FAIL'} -> {'PASS' if now else 'FAIL'}")
    return lines


def certified_bound(info: dict) -> dict | None:
    """The distance bound a decimation with ``max_error`` certified, from a
    post-processed mesh's ``info``: ``{"max_error", "input_to_result",
    "result_to_input", "unit"}`` (the report's ``post_processing.decimation``), or
    None without one. The bound is between decimation's input and output: after the
    steps before it (closing, clean-up, smoothing), not the extracted surface."""
    record = info.get("decimation") or {}
    names = ("max_error", "input_to_result", "result_to_input")
    if any(record.get(name) is None for name in names):
        return None
    return {**{name: float(record[name]) for name in names}, "unit": info.get("unit")}


def bound_lines(info: dict) -> list[str]:
    """:func:`certified_bound` as lines of the report (none without one)."""
    bound = certified_bound(info)
    if bound is None:
        return []
    unit = f" {bound['unit']}" if bound["unit"] else ""
    there, back = bound["input_to_result"], bound["result_to_input"]
    return [
        f"decimation: its input and its result within {bound['max_error']:g}{unit} of each "
        f"other, both ways (certified: input to result at most {there:.7g}, result to input "
        f"{back:.7g})"
    ]


__all__ = [
    "EmptyMeshError",
    "PostOptions",
    "bound_lines",
    "certified_bound",
    "changes",
    "post_process",
]
