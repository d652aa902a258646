// The umbrella operator of mesh smoothing (isoconvert/post/smooth.py): for
// each vertex, its position minus the mean of its stencil's neighbours. The
// stencil comes in compressed rows (a vertex's neighbours are
// neighbours[offsets[i] .. offsets[i + 1]]), built once in Python; this runs
// once or twice per smoothing iteration, where numpy's gather-and-bincount
// cost about 60 ms per million vertices.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

void umbrella(const i64 *offsets, const i64 *neighbours, const double *inverse_count,
              const double *x, i64 n, int threads, double *out) {
  iso::parallel_for(n, threads, 8192, [&](int, i64 begin, i64 end) {
    for (i64 i = begin; i < end; ++i) {
      double sum[3] = {0.0, 0.0, 0.0};
      for (i64 e = offsets[i]; e < offsets[i + 1]; ++e) {
        const i64 j = neighbours[e];
        for (int k = 0; k < 3; ++k) sum[k] += x[k * n + j];
      }
      for (int k = 0; k < 3; ++k) out[k * n + i] = x[k * n + i] - inverse_count[i] * sum[k];
    }
  });
}

// One step of the windowed-sinc filter's Chebyshev recurrence, in place:
// x2 = 2 x1 - L x1 - x0 (lap holds L x1 and becomes x2), out += c x2.
void chebyshev_step(const double *x0, const double *x1, double *lap, double c, i64 n,
                    int threads, double *out) {
  iso::parallel_for(n, threads, 1 << 16, [&](int, i64 begin, i64 end) {
    for (i64 i = begin; i < end; ++i) {
      const double x2 = 2.0 * x1[i] - lap[i] - x0[i];
      lap[i] = x2;
      out[i] += c * x2;
    }
  });
}

}  // namespace

void bind_smooth(nb::module_ &m) {
  m.def(
      "chebyshev_step",
      [](Doubles x0, Doubles x1, Out<double> lap, double c, int threads, Out<double> out) {
        const i64 n = i64(x0.size());
        if (i64(x1.size()) != n || i64(lap.size()) != n || i64(out.size()) != n) {
          throw std::invalid_argument("chebyshev_step: x0, x1, lap and out of one size");
        }
        nb::gil_scoped_release unlocked;
        chebyshev_step(x0.data(), x1.data(), lap.data(), c, n, threads, out.data());
      },
      "x0"_a, "x1"_a, "lap"_a.noconvert(), "c"_a, "threads"_a, "out"_a.noconvert(),
      "x2 = 2 x1 - lap - x0 written over lap, and out += c x2 (arrays of one size).");
  m.def(
      "umbrella",
      [](Int64s offsets, Int64s neighbours, Doubles inverse_count, Doubles x, int threads,
         Out<double> out) {
        const i64 n = inverse_count.ndim() == 1 ? i64(inverse_count.shape(0)) : -1;
        if (n < 0 || offsets.ndim() != 1 || i64(offsets.shape(0)) != n + 1 ||
            neighbours.ndim() != 1 || x.ndim() != 2 || x.shape(0) != 3 ||
            i64(x.shape(1)) != n) {
          throw std::invalid_argument(
              "umbrella: offsets (V + 1,), neighbours (E,), inverse_count (V,), x (3, V)");
        }
        check_out(out, 3, n, "out");
        const i64 *o = offsets.data();
        const i64 e = i64(neighbours.shape(0));
        if (o[0] != 0 || o[n] != e) throw std::invalid_argument("umbrella: bad offsets");
        for (i64 i = 0; i < n; ++i) {
          if (o[i + 1] < o[i]) throw std::invalid_argument("umbrella: offsets must not decrease");
        }
        for (i64 k = 0; k < e; ++k) {
          if (neighbours.data()[k] < 0 || neighbours.data()[k] >= n) {
            throw std::invalid_argument("umbrella: a neighbour is not a vertex");
          }
        }
        nb::gil_scoped_release unlocked;
        umbrella(o, neighbours.data(), inverse_count.data(), x.data(), n, threads, out.data());
      },
      "offsets"_a, "neighbours"_a, "inverse_count"_a, "x"_a.noconvert(), "threads"_a,
      "out"_a.noconvert(),
      "out = x - inverse_count * (sum of x over each vertex's neighbours), x and out (3, V).");
}
