#pragma once

#include "placement.hpp"
#include "rows.hpp"
#include "sample.hpp"
#include "trilinear.hpp"

namespace iso {

// A Marching Cubes table: triangles per configuration and their cube edges
// (numbered as isoconvert/extract/tables.py: x-edges 0-3, y 4-7, z 8-11).
struct CubeTable {
  std::int8_t count[256];
  std::int8_t edges[256][15];
};

struct CubesCount {
  // per row: bipolar y- and z-edges, triangles and interior vertices of the
  // cubes above and behind it
  std::vector<i32> cy, cz, ct, ci;
  // in the trilinear mode, for the filling pass: the pieces of each special
  // cube (a word of Walk::pack_pieces), row by row by increasing x, in the
  // buffer of the thread that counted the row; per row, that thread and where
  // its words start
  std::vector<std::vector<std::uint64_t>> found;
  std::vector<i32> found_by;
  std::vector<i64> found_at;
  i64 vertices = 0, triangles = 0;
};

// `trilinear`: null for a fixed ambiguity rule (`table` then decides every
// cube); else its special configurations take the trilinear tests instead.
template <class T>
void count_cubes(const T *f, const RowScan &s, const CubeTable &table,
                 const TrilinearTable *trilinear, int threads, CubesCount &out);

// Unit normals at the vertices on grid edges, filled in the same pass as the
// vertices (issue 23) instead of by a second pass over the volume: the
// gradient of the grid at each vertex's world position, sampled from the
// samples around it by sample.hpp's sample_point, the function sample_points
// (isoconvert.vertex_normals) runs, so they are the same bits. At a vertex on
// a grid edge that is the central-difference gradients at the edge's two
// samples mixed by the vertex's place on the edge, as VTK's Flying Edges
// computes them; it is taken from the vertex's position rather than from its
// edge fraction so that the rounding of the trip through world coordinates
// is the same too, which matters where the two gradients nearly cancel. The
// stencils reach one sample past an edge's ends, beyond a z-slab's overlap,
// and a vertex rounded into the next cell one more: a slab of a larger grid
// comes with up to 2 more layers each way (`halo`), read as sample_points
// reads a slab (a stencil that leaves them sets `missing`, a bug). Interior
// (trilinear) vertices are left alone.
struct EdgeNormals {
  PointMap map;               // the grid's placement, sign and normalize = true
  double slack;               // as sample_points' (the vertices are inside)
  float *out;                 // (V, 3)
  std::atomic<i64> *flat;     // counts the normals left 0 or NaN (for the caller)
  // the samples the stencils read: layers halo_k0 .. halo_k0 + halo_layers - 1
  // of the whole grid's `depth` (of the kernel's sample type); the slab itself
  // when it is the whole grid
  const void *halo;
  i64 halo_layers, halo_k0, depth;
  std::atomic<bool> *missing;
};

// verts (V, 3), ids (V,), tris (C, 3), sized from `counts`; `normals` null or
// as EdgeNormals says.
template <class T>
void fill_cubes(const T *f, const RowScan &s, const CubeTable &table,
                const TrilinearTable *trilinear, const CubesCount &counts, const Placement &where,
                int threads, double *verts, i64 *ids, i64 *tris,
                const EdgeNormals *normals = nullptr);

}  // namespace iso
