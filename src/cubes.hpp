#pragma once

#include "placement.hpp"
#include "rows.hpp"

namespace iso {

// A Marching Cubes table: triangles per configuration and their cube edges
// (numbered as isoconvert/extract/tables.py: x-edges 0-3, y 4-7, z 8-11).
struct CubeTable {
  std::int8_t count[256];
  std::int8_t edges[256][15];
};

struct CubesCount {
  // per row: bipolar y- and z-edges, triangles of the cubes above and behind it
  std::vector<i32> cy, cz, ct;
  i64 vertices = 0, triangles = 0;
};

template <class T>
void count_cubes(const T *f, const RowScan &s, const CubeTable &table, int threads,
                 CubesCount &out);

// verts (V, 3), ids (V,), tris (C, 3), sized from `counts`.
template <class T>
void fill_cubes(const T *f, const RowScan &s, const CubeTable &table, const CubesCount &counts,
                const Placement &where, int threads, double *verts, i64 *ids, i64 *tris);

}  // namespace iso
