// Where a kernel's output goes in the world and in the whole grid.
#pragma once

#include "common.hpp"

namespace iso {

// Where a block's vertices go: world = origin + A (index + index_origin), and
// the global grid those edge ids number (3 * (i + NX * (j + NY * k)) + axis).
struct Placement {
  double affine[3][3];
  double origin[3];
  i64 index_origin[3];  // (i0, j0, k0) of this block's first sample
  i64 id_dims[2];       // (NX, NY) of the whole grid
  double offset = 0.0;  // vertex offset (fraction of an edge kept from its ends)
  bool reverse = false; // write triangles in the opposite orientation
  // ids of vertices inside cubes (cubes' trilinear mode) start here, past every
  // edge id: 3 NX NY NZ; such a vertex of the cube with lowest corner (i, j, k)
  // is inner_base + 16 (i + NX (j + NY k)) + its slot in the cube
  i64 inner_base = 0;

  // Write the world position of grid point (px, py, pz) (whole-grid index
  // units) to out[0..2].
  void world(double px, double py, double pz, double *out) const {
    for (int a = 0; a < 3; ++a) {
      out[a] = affine[a][0] * px + affine[a][1] * py + affine[a][2] * pz + origin[a];
    }
  }
};

}  // namespace iso
