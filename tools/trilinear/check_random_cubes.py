"""Check ``--ambiguity trilinear``'s reference against a fine resampling.

For random cubes whose topology needs the trilinear tests, compare the surface
:func:`isoconvert.extract.trilinear.trilinear_cube` builds with scikit-image's
Marching Cubes on the trilinear interpolant sampled finely inside the cube:
components, Euler characteristic and boundary loops (counted by trimesh). A
cube is skipped when two fine resolutions disagree (a saddle too near the
level to resolve).

    python tools/trilinear/check_random_cubes.py [cubes] [seed]
"""

from __future__ import annotations

import sys

import numpy as np
import trimesh
from skimage import measure

from isoconvert.extract import trilinear


def topology(vertices: np.ndarray, triangles: np.ndarray) -> tuple[int, int, int]:
    """(components, Euler characteristic, boundary loops) of a triangle mesh."""
    if not len(triangles):
        return (0, 0, 0)
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    components = len(trimesh.graph.connected_components(mesh.edges, nodes=np.unique(triangles)))
    return components, int(mesh.euler_number), len(mesh.outline().entities)


def reference(values: np.ndarray, level: float) -> tuple[int, int, int]:
    """Topology of the pieces ``trilinear_cube`` makes (at midpoint positions)."""
    vertices, triangles = [], []
    for tris, inner in trilinear.trilinear_cube(values, level):
        base = len(vertices)
        for vertex in list(range(trilinear.INNER)) + [
            trilinear.INNER + s for s in range(len(inner))
        ]:
            vertices.append(trilinear._position(vertex, inner))
        triangles += [[base + v for v in t] for t in tris]
    return topology(np.array(vertices), np.array(triangles, dtype=np.int64).reshape(-1, 3))


def resampled(values: np.ndarray, level: float, n: int) -> tuple[int, int, int]:
    """Topology of the level set of the cube's trilinear interpolant, sampled n^3."""
    x = np.linspace(0.0, 1.0, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = sum(
        values[c]
        * np.where(c & 1, X, 1 - X)
        * np.where(c >> 1 & 1, Y, 1 - Y)
        * np.where(c >> 2 & 1, Z, 1 - Z)
        for c in range(8)
    )
    if field.min() >= level or field.max() < level:
        return (0, 0, 0)
    verts, faces, _, _ = measure.marching_cubes(field, level, method="lorensen")
    return topology(verts, faces)


def main(cubes: int, seed: int) -> int:
    rng = np.random.default_rng(seed)
    tested = unresolved = wrong = 0
    for _ in range(cubes):
        values = rng.uniform(-1.0, 1.0, size=8)
        config = sum(1 << v for v in range(8) if values[v] >= 0.0)
        if not trilinear.needs_interior_test(config):
            continue
        coarse, fine = resampled(values, 0.0, 40), resampled(values, 0.0, 81)
        if coarse != fine:
            unresolved += 1
            continue
        tested += 1
        ours = reference(values, 0.0)
        if ours != fine:
            wrong += 1
            print("differs:", values.round(4).tolist(), "ours", ours, "resampled", fine)
    print(f"{tested} cubes compared, {wrong} differ, {unresolved} unresolved by resampling")
    return 1 if wrong else 0


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    sys.exit(main(*(args + [3000, 0][len(args) :])))
