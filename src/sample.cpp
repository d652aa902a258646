// Values and gradients of a grid at arbitrary points, by trilinear
// interpolation: the per-vertex normals (--normals) and values of a second
// volume (--values).
//
// A vertex on a grid edge lies on a face of every cell around it, where
// trilinear interpolation reduces to linear interpolation along the edge. So
// the gradient interpolated here at an isosurface vertex is the one VTK's
// contour filters and scikit-image compute: central differences at the edge's
// two samples, mixed by the vertex's fraction of the edge. Elsewhere (vertices
// moved by smoothing or decimation) it is the trilinear gradient field.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "bind.hpp"
#include "common.hpp"
#include "scan.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

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
  double at(i64 i, i64 j, i64 k) const {
    const i64 local = k - k0;
    if (local < 0 || local >= nz) {
      missing->store(true, std::memory_order_relaxed);
      return std::numeric_limits<double>::quiet_NaN();
    }
    const double v = static_cast<double>(f[(local * ny + j) * nx + i]);
    return (fill_nonfinite && !std::isfinite(v)) ? fill : v;
  }

  // d/d(index) along one axis at a sample: central differences inside,
  // one-sided on the grid's faces, 0 across a grid one sample thick.
  static void stencil(i64 p, i64 n, i64 &lo, i64 &hi, double &scale) {
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

  void gradient(i64 i, i64 j, i64 k, double g[3]) const {
    i64 lo, hi;
    double s;
    stencil(i, nx, lo, hi, s);
    g[0] = s == 0.0 ? 0.0 : s * (at(hi, j, k) - at(lo, j, k));
    stencil(j, ny, lo, hi, s);
    g[1] = s == 0.0 ? 0.0 : s * (at(i, hi, k) - at(i, lo, k));
    stencil(k, depth, lo, hi, s);
    g[2] = s == 0.0 ? 0.0 : s * (at(i, j, hi) - at(i, j, lo));
  }
};

// The cell corner below `x` along an axis of n samples, and the fraction
// across that cell; false when x lies outside [0, n - 1] by more than `slack`.
inline bool locate(double x, i64 n, double slack, i64 &c, double &t) {
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

template <class T>
void sample_points(const Slab<T> &s, const PointMap &map, const double *points, i64 n,
                   bool gradient, double slack, int threads, float *out) {
  const int width = gradient ? 3 : 1;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  iso::parallel_for(n, threads, 4096, [&](int, i64 begin, i64 end) {
    for (i64 p = begin; p < end; ++p) {
      double x[3];
      for (int b = 0; b < 3; ++b) {
        x[b] = 0.0;
        for (int a = 0; a < 3; ++a) x[b] += (points[3 * p + a] - map.origin[a]) * map.to_index[a][b];
      }
      float *o = out + width * p;
      i64 i, j, k;
      double u, v, w;
      if (!locate(x[0], s.nx, slack, i, u) || !locate(x[1], s.ny, slack, j, v) ||
          !locate(x[2], s.depth, slack, k, w)) {
        for (int c = 0; c < width; ++c) o[c] = nan;
        continue;
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
        continue;
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
  });
}

PointMap point_map(const Doubles &origin, const Doubles &to_index, const Doubles &to_world,
                   double sign, bool normalize) {
  if (origin.size() != 3 || to_index.size() != 9 || to_world.size() != 9) {
    throw std::invalid_argument("origin (3,), to_index (3, 3) and to_world (3, 3)");
  }
  PointMap map;
  for (int a = 0; a < 3; ++a) {
    map.origin[a] = origin.data()[a];
    for (int b = 0; b < 3; ++b) {
      map.to_index[a][b] = to_index.data()[3 * a + b];
      map.to_world[a][b] = to_world.data()[3 * a + b];
    }
  }
  map.sign = sign;
  map.normalize = normalize;
  return map;
}

template <class T>
void bind_sample_type(nb::module_ &m) {
  m.def(
      "sample_points",
      [](Samples3<T> f, i64 k0, i64 depth, Doubles points, Doubles origin, Doubles to_index,
         Doubles to_world, double sign, bool normalize, bool gradient, bool fill_nonfinite,
         double fill, double slack, int threads, Out<float> out) {
        const i64 n = points.ndim() == 2 ? i64(points.shape(0)) : -1;
        if (n < 0 || points.shape(1) != 3) throw std::invalid_argument("points must be (N, 3)");
        check_out(out, n, gradient ? 3 : 0, "out");
        if (k0 < 0 || k0 + i64(f.shape(0)) > depth) {
          throw std::invalid_argument("the slab's layers are not inside the grid");
        }
        const PointMap map = point_map(origin, to_index, to_world, sign, normalize);
        std::atomic<bool> missing{false};
        const Slab<T> s{f.data(), i64(f.shape(2)), i64(f.shape(1)), i64(f.shape(0)), k0,
                        depth,    fill_nonfinite,  fill,            &missing};
        {
          nb::gil_scoped_release unlocked;
          sample_points<T>(s, map, points.data(), n, gradient, slack, threads, out.data());
        }
        if (missing.load()) {
          throw std::logic_error(
              "sample_points: a point needs a grid layer outside the slab it was given");
        }
      },
      "f"_a.noconvert(), "k0"_a, "depth"_a, "points"_a.noconvert(), "origin"_a, "to_index"_a,
      "to_world"_a, "sign"_a, "normalize"_a, "gradient"_a, "fill_nonfinite"_a, "fill"_a,
      "slack"_a, "threads"_a, "out"_a.noconvert(),
      "Trilinear values (out (N,) float32) or world gradients (out (N, 3) float32) at\n"
      "world points (N, 3), from layers k0 .. k0 + nz - 1 of a grid of `depth` layers;\n"
      "NaN for points outside the grid by more than `slack` samples. Raises when a\n"
      "point needs a layer the slab does not hold (the caller's slab is too thin).");
}

}  // namespace

void bind_sample(nb::module_ &m) {
#define ISO_BIND(T) bind_sample_type<T>(m);
  ISO_FOR_EACH_SAMPLE_TYPE(ISO_BIND)
#undef ISO_BIND
}
