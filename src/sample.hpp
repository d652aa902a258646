// Values and gradients of a grid at one point, by trilinear interpolation:
// what sample_points (sample.cpp: --normals, --values) does for each point,
// and what Marching Cubes' filling pass does for each vertex it places when
// asked for normals (cubes.cpp, EdgeNormals). One definition for both, so the
// two give the same bits.
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "common.hpp"

// The per-point functions below are forced inline: the sample_points loop and
// the filling pass are their only callers, and out of line (as GCC left Slab::at
// once it was shared by two files) the second pass took half as long again.
#if defined(__GNUC__) || defined(__clang__)
#define ISO_INLINE inline __attribute__((always_inline))
#else
#define ISO_INLINE inline
#endif

namespace iso {

// d/d(index) along one axis at a sample: central differences inside,
// one-sided on the grid's faces, 0 across a grid one sample thick.
ISO_INLINE void stencil(i64 p, i64 n, i64 &lo, i64 &hi, double &scale) {
  if (n < 2) {
    lo = hi = p;
    scale = 0.0;
  } else if (p == 0) {
    lo = 0, hi = 1, scale = 1.0;
  } else if (p == n - 1) {
    lo = n - 2, hi = n - 1, scale = 1.0;
  } else {
    lo = p - 1, hi = p + 1, scale = 0.5;
  }
}

// The index-space gradient at sample (i, j, k) of a grid S (a Slab or a
// WholeGrid: its samples by s.at(i, j, k), its size by nx, ny and depth).
template <class S>
ISO_INLINE void grid_gradient(const S &s, i64 i, i64 j, i64 k, double g[3]) {
  i64 lo, hi;
  double d;
  stencil(i, s.nx, lo, hi, d);
  g[0] = d == 0.0 ? 0.0 : d * (s.at(hi, j, k) - s.at(lo, j, k));
  stencil(j, s.ny, lo, hi, d);
  g[1] = d == 0.0 ? 0.0 : d * (s.at(i, hi, k) - s.at(i, lo, k));
  stencil(k, s.depth, lo, hi, d);
  g[2] = d == 0.0 ? 0.0 : d * (s.at(i, j, hi) - s.at(i, j, lo));
}

// A slab of layers k0 .. k0 + nz - 1 of a grid with `depth` layers in all.
template <class T>
struct Slab {
  const T *f;
  i64 nx, ny, nz, k0, depth;
  bool fill_nonfinite;
  double fill;
  // Set when a point needed a layer the slab does not hold: the caller's slab
  // was too thin, a bug to report, not a NaN to pass on (a NaN gradient would
  // silently become the triangles' normal, issue 20).
  std::atomic<bool> *missing;

  // The sample at (i, j) of global layer k; NaN (and `missing` set) when the
  // layer is not in the slab.
  ISO_INLINE double at(i64 i, i64 j, i64 k) const {
    const i64 local = k - k0;
    if (local < 0 || local >= nz) {
      missing->store(true, std::memory_order_relaxed);
      return std::numeric_limits<double>::quiet_NaN();
    }
    const double v = static_cast<double>(f[(local * ny + j) * nx + i]);
    return (fill_nonfinite && !std::isfinite(v)) ? fill : v;
  }

  ISO_INLINE void gradient(i64 i, i64 j, i64 k, double g[3]) const {
    grid_gradient(*this, i, j, k, g);
  }
};

// The samples of a grid held whole (no NaN/Inf among them: they were replaced
// before the kernels ran), read with no check: what a Slab of all its layers
// without fill reads, for the filling pass of Marching Cubes (cubes.cpp).
template <class T>
struct WholeGrid {
  const T *f;
  i64 nx, ny, depth;

  ISO_INLINE double at(i64 i, i64 j, i64 k) const {
    return static_cast<double>(f[(k * ny + j) * nx + i]);
  }
  ISO_INLINE void gradient(i64 i, i64 j, i64 k, double g[3]) const {
    grid_gradient(*this, i, j, k, g);
  }
};

// The cell corner below `x` along an axis of n samples, and the fraction
// across that cell; false when x lies outside [0, n - 1] by more than `slack`.
ISO_INLINE bool locate(double x, i64 n, double slack, i64 &c, double &t) {
  if (!(x >= -slack && x <= double(n - 1) + slack)) return false;
  x = std::min(std::max(x, 0.0), double(n - 1));
  if (n < 2) {
    c = 0, t = 0.0;
    return true;
  }
  c = std::min<i64>(static_cast<i64>(std::floor(x)), n - 2);
  t = x - double(c);
  return true;
}

// Where the points are and what becomes of a gradient: world points go to
// grid indices by index = (world - origin) @ to_index (row vectors), and
// gradients to world space by g @ to_world, times `sign`, and are made unit
// length when `normalize` (zero stays zero: the caller fills those in).
struct PointMap {
  double origin[3];
  double to_index[3][3];
  double to_world[3][3];
  double sign;
  bool normalize;
};

// The trilinear value (o[0]) or the world gradient (o[0..2], times map.sign,
// unit length when map.normalize: zero stays zero, NaN stays NaN) of the grid
// `s` (a Slab or a WholeGrid) at world point `point`; NaN when the point lies outside the grid
// by more than `slack` samples.
//
// At a point on a grid edge (an isosurface vertex) the weights of the corners
// off the edge are 0 and are skipped, and this is the linear interpolation of
// the gradients at the edge's two samples; a point that the round trip
// through world coordinates puts a hair off the edge gives those corners
// weights of order 1e-16, as it does wherever it is computed.
template <class S>
ISO_INLINE void sample_point(const S &s, const PointMap &map, const double *point, bool gradient,
                         double slack, float *o) {
  const int width = gradient ? 3 : 1;
  double x[3];
  for (int b = 0; b < 3; ++b) {
    x[b] = 0.0;
    for (int a = 0; a < 3; ++a) x[b] += (point[a] - map.origin[a]) * map.to_index[a][b];
  }
  i64 i, j, k;
  double u, v, w;
  if (!locate(x[0], s.nx, slack, i, u) || !locate(x[1], s.ny, slack, j, v) ||
      !locate(x[2], s.depth, slack, k, w)) {
    for (int c = 0; c < width; ++c) o[c] = std::numeric_limits<float>::quiet_NaN();
    return;
  }
  double acc[3] = {0.0, 0.0, 0.0};
  for (int corner = 0; corner < 8; ++corner) {
    const int di = corner & 1, dj = (corner >> 1) & 1, dk = corner >> 2;
    const double weight = (di ? u : 1.0 - u) * (dj ? v : 1.0 - v) * (dk ? w : 1.0 - w);
    if (weight == 0.0) continue;  // also keeps corners beyond a 1-sample axis out
    if (gradient) {
      double g[3];
      s.gradient(i + di, j + dj, k + dk, g);
      for (int c = 0; c < 3; ++c) acc[c] += weight * g[c];
    } else {
      acc[0] += weight * s.at(i + di, j + dj, k + dk);
    }
  }
  if (!gradient) {
    o[0] = static_cast<float>(acc[0]);
    return;
  }
  // gradients are covectors: d/d(world) = d/d(index) @ inv(affine)
  double g[3];
  for (int b = 0; b < 3; ++b) {
    g[b] = 0.0;
    for (int a = 0; a < 3; ++a) g[b] += acc[a] * map.to_world[a][b];
    g[b] *= map.sign;
  }
  if (map.normalize) {
    const double length = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    const double scale = (length > 0.0 && std::isfinite(length)) ? 1.0 / length : 0.0;
    for (int c = 0; c < 3; ++c) g[c] *= scale;
  }
  for (int c = 0; c < 3; ++c) o[c] = static_cast<float>(g[c]);
}

}  // namespace iso
