// Values and gradients of a grid at arbitrary points, by trilinear
// interpolation: the per-vertex normals (--normals) and values of a second
// volume (--values).
//
// A vertex on a grid edge lies on a face of every cell around it, where
// trilinear interpolation reduces to linear interpolation along the edge. So
// the gradient interpolated here at an isosurface vertex is the one VTK's
// contour filters and scikit-image compute: central differences at the edge's
// two samples, mixed by the vertex's fraction of the edge. Elsewhere (vertices
// moved by smoothing or decimation) it is the trilinear gradient field. The
// per-point arithmetic is in sample.hpp, shared with Marching Cubes' filling
// pass, which computes the same normals for the vertices it places.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "bind.hpp"
#include "common.hpp"
#include "sample.hpp"
#include "scan.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;
using iso::PointMap;
using iso::Slab;

namespace {

using namespace iso::bind;

template <class T>
void sample_points(const Slab<T> &s, const PointMap &map, const double *points, i64 n,
                   bool gradient, double slack, int threads, float *out) {
  const int width = gradient ? 3 : 1;
  iso::parallel_for(n, threads, 4096, [&](int, i64 begin, i64 end) {
    for (i64 p = begin; p < end; ++p) {
      sample_point(s, map, points + 3 * p, gradient, slack, out + width * p);
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
