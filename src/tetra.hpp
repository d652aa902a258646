// Marching Tetrahedra in the manner of Flying Edges (see rows.hpp and cubes.hpp).
#pragma once

#include <array>

#include "placement.hpp"
#include "rows.hpp"

namespace iso {

// The seven edge directions of the decomposition, in the order of
// TETRA_DIRECTIONS in isoconvert/extract/tables.py: x, y, z, xy, xz, yz, xyz.
// The edge ids (7 * (i + NX * (j + NY * k)) + direction) depend on this order.
constexpr int TETRA_DX[7] = {1, 0, 0, 1, 1, 0, 1};
constexpr int TETRA_DY[7] = {0, 1, 0, 1, 0, 1, 1};
constexpr int TETRA_DZ[7] = {0, 0, 1, 0, 1, 1, 1};

// The six tetrahedra of a cube folded into one table per cube configuration
// (bit v = corner v = x + 2y + 4z positive): the triangles of tetrahedron 0,
// then of tetrahedron 1, ..., as indices into the cube's 19 tetrahedron edges.
// Edge n starts at the cube corner in row `row[n]` (y + 2z of the corner, the
// numbering of a cube row's four rows) and x offset `dx[n]`, and runs along
// direction `dir[n]`.
struct TetraTable {
  std::int8_t count[256];      // <= 12: at most two triangles per tetrahedron
  std::int8_t edges[256][36];  // 3 per triangle
  std::uint32_t used[256];     // bit n: edge n is a corner of some triangle
  std::int8_t dir[19], row[19], dx[19];
};

struct TetraCount {
  // per row r = j + NY * k: bipolar edges starting on it in each direction
  // (index 0..6; direction 0 is RowScan::cx), and in [7] the triangles of the
  // cubes above and behind it (cube row (j, k))
  std::vector<std::array<i32, 8>> rows;
  i64 vertices = 0, triangles = 0;
};

template <class T>
void count_tetra(const T *f, const RowScan &s, const TetraTable &table, int threads,
                 TetraCount &out);

// verts (V, 3), ids (V,), tris (C, 3), sized from `counts`.
template <class T>
void fill_tetra(const T *f, const RowScan &s, const TetraTable &table, const TetraCount &counts,
                const Placement &where, int threads, double *verts, i64 *ids, i64 *tris);

}  // namespace iso
