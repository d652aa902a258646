// Inside-or-outside by ray parity, for --fill-cavities
// (isoconvert/post/components.py): how many of a few rays from each point
// cross its closed component an odd number of times. Numpy tested every
// triangle of the outer component against every point (200 s on a chest CT
// with a thousand specks inside one 700k-triangle bone surface); here the
// triangles of a component are bucketed, per ray, by their shadow on a plane
// across the ray, so a ray meets only the triangles whose shadow covers it.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

// Whether the ray o + t d (t > 0) crosses the triangle a, b, c
// (Moller-Trumbore, as the numpy version: a ray in the triangle's plane
// does not cross it).
inline bool crosses(const double *o, const double *d, const double *a, const double *b,
                    const double *c) {
  double e1[3], e2[3], s[3], p[3], q[3];
  for (int k = 0; k < 3; ++k) {
    e1[k] = b[k] - a[k];
    e2[k] = c[k] - a[k];
    s[k] = o[k] - a[k];
  }
  p[0] = d[1] * e2[2] - d[2] * e2[1];
  p[1] = d[2] * e2[0] - d[0] * e2[2];
  p[2] = d[0] * e2[1] - d[1] * e2[0];
  const double det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
  if (det == 0.0) return false;
  const double inv = 1.0 / det;
  const double u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) * inv;
  q[0] = s[1] * e1[2] - s[2] * e1[1];
  q[1] = s[2] * e1[0] - s[0] * e1[2];
  q[2] = s[0] * e1[1] - s[1] * e1[0];
  const double v = (q[0] * d[0] + q[1] * d[1] + q[2] * d[2]) * inv;
  const double t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) * inv;
  return u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0;
}

// Two unit vectors across d (d, u, w orthonormal).
void across(const double *d, double *u, double *w) {
  const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  const double n[3] = {d[0] / len, d[1] / len, d[2] / len};
  // the axis least along d, crossed with it
  int k = 0;
  for (int j = 1; j < 3; ++j)
    if (std::fabs(n[j]) < std::fabs(n[k])) k = j;
  double e[3] = {0.0, 0.0, 0.0};
  e[k] = 1.0;
  u[0] = n[1] * e[2] - n[2] * e[1];
  u[1] = n[2] * e[0] - n[0] * e[2];
  u[2] = n[0] * e[1] - n[1] * e[0];
  const double lu = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  for (int j = 0; j < 3; ++j) u[j] /= lu;
  w[0] = n[1] * u[2] - n[2] * u[1];
  w[1] = n[2] * u[0] - n[0] * u[2];
  w[2] = n[0] * u[1] - n[1] * u[0];
}

// votes[i]: how many of the rays from points[i] cross the triangles of
// component comps[i] an odd number of times. Triangles come grouped by
// component: component c's are order[starts[c] .. starts[c] + sizes[c]].
void ray_votes(const double *v, const i64 *cells, const i64 *order, const i64 *starts,
               const i64 *sizes, const double *points, const i64 *comps, i64 n_points,
               const double *rays, int n_rays, int threads, i64 *votes) {
  std::fill(votes, votes + n_points, i64(0));
  // queries grouped by component
  std::vector<i64> by(n_points);
  for (i64 i = 0; i < n_points; ++i) by[i] = i;
  std::stable_sort(by.begin(), by.end(), [&](i64 a, i64 b) { return comps[a] < comps[b]; });
  std::vector<i64> group_start;
  for (i64 i = 0; i < n_points; ++i) {
    if (i == 0 || comps[by[i]] != comps[by[i - 1]]) group_start.push_back(i);
  }
  const i64 n_groups = i64(group_start.size());
  group_start.push_back(n_points);
  iso::parallel_for(n_groups, threads, 1, [&](int, i64 g0, i64 g1) {
    std::vector<double> lo, hi;
    std::vector<i64> offsets, bucket;
    for (i64 g = g0; g < g1; ++g) {
      const i64 comp = comps[by[group_start[g]]];
      const i64 *tri = order + starts[comp];
      const i64 n_tri = sizes[comp];
      for (int r = 0; r < n_rays; ++r) {
        const double *d = rays + 3 * r;
        double u[3], w[3];
        across(d, u, w);
        // each triangle's shadow box in (u, w)
        lo.assign(2 * n_tri, 0.0);
        hi.assign(2 * n_tri, 0.0);
        double box[4] = {INFINITY, INFINITY, -INFINITY, -INFINITY};
        for (i64 k = 0; k < n_tri; ++k) {
          for (int a = 0; a < 2; ++a) {
            const double *axis = a ? w : u;
            double mn = INFINITY, mx = -INFINITY;
            for (int q = 0; q < 3; ++q) {
              const double *p = v + 3 * cells[3 * tri[k] + q];
              const double x = p[0] * axis[0] + p[1] * axis[1] + p[2] * axis[2];
              mn = std::min(mn, x);
              mx = std::max(mx, x);
            }
            // widened by far more than rounding, so that no triangle the exact
            // test would count falls outside its buckets
            const double pad = 1e-9 * (std::fabs(mn) + std::fabs(mx) + (mx - mn));
            mn -= pad;
            mx += pad;
            lo[2 * k + a] = mn;
            hi[2 * k + a] = mx;
            box[a] = std::min(box[a], mn);
            box[2 + a] = std::max(box[2 + a], mx);
          }
        }
        // a square grid of about two triangles per cell
        const i64 side = std::max<i64>(1, i64(std::sqrt(double(n_tri) / 2.0)));
        const double span[2] = {std::max(box[2] - box[0], 1e-300),
                                std::max(box[3] - box[1], 1e-300)};
        auto cell = [&](double x, int a) {
          // clamped as a double first: a flat shadow makes f huge
          const double f = std::floor((x - box[a]) / span[a] * double(side));
          return i64(std::min(double(side - 1), std::max(0.0, f)));
        };
        auto each = [&](i64 k, auto &&emit) {
          const i64 x0 = cell(lo[2 * k], 0), x1 = cell(hi[2 * k], 0);
          const i64 y0 = cell(lo[2 * k + 1], 1), y1 = cell(hi[2 * k + 1], 1);
          for (i64 y = y0; y <= y1; ++y) {
            for (i64 x = x0; x <= x1; ++x) emit(y * side + x);
          }
        };
        iso::fill_buckets(n_tri, side * side, each, offsets, bucket);
        for (i64 q = group_start[g]; q < group_start[g + 1]; ++q) {
          const i64 i = by[q];
          const double *o = points + 3 * i;
          const double pu = o[0] * u[0] + o[1] * u[1] + o[2] * u[2];
          const double pw = o[0] * w[0] + o[1] * w[1] + o[2] * w[2];
          if (!(pu >= box[0] && pu <= box[2] && pw >= box[1] && pw <= box[3])) continue;
          const i64 b = cell(pw, 1) * side + cell(pu, 0);
          i64 hits = 0;
          for (i64 e = offsets[b]; e < offsets[b + 1]; ++e) {
            const i64 k = bucket[e];
            if (pu < lo[2 * k] || pu > hi[2 * k] || pw < lo[2 * k + 1] || pw > hi[2 * k + 1]) {
              continue;
            }
            const i64 *c = cells + 3 * tri[k];
            hits += crosses(o, d, v + 3 * c[0], v + 3 * c[1], v + 3 * c[2]);
          }
          votes[i] += hits & 1;
        }
      }
    }
  });
}

}  // namespace

void bind_rays(nb::module_ &m) {
  m.def(
      "ray_parity_votes",
      [](Doubles vertices, Int64s cells, Int64s order, Int64s starts, Int64s sizes,
         Doubles points, Int64s comps, Doubles rays, int threads, Out<i64> votes) {
        if (vertices.ndim() != 2 || vertices.shape(1) != 3 || cells.ndim() != 2 ||
            cells.shape(1) != 3 || points.ndim() != 2 || points.shape(1) != 3 ||
            rays.ndim() != 2 || rays.shape(1) != 3) {
          throw std::invalid_argument(
              "ray_parity_votes: vertices (V, 3), cells (C, 3), points (N, 3), rays (R, 3)");
        }
        const i64 n_vertices = i64(vertices.shape(0)), n_cells = i64(cells.shape(0));
        const i64 n_points = i64(points.shape(0)), n_comp = i64(starts.size());
        if (i64(order.size()) != n_cells || i64(sizes.size()) != n_comp ||
            i64(comps.size()) != n_points) {
          throw std::invalid_argument(
              "ray_parity_votes: order (C,), starts and sizes (K,), comps (N,)");
        }
        check_out(votes, n_points, 0, "votes");
        for (i64 k = 0; k < 3 * n_cells; ++k) {
          if (cells.data()[k] < 0 || cells.data()[k] >= n_vertices) {
            throw std::invalid_argument("ray_parity_votes: a cell index is not a vertex");
          }
        }
        for (i64 k = 0; k < n_cells; ++k) {
          if (order.data()[k] < 0 || order.data()[k] >= n_cells) {
            throw std::invalid_argument("ray_parity_votes: order must index the cells");
          }
        }
        for (i64 c = 0; c < n_comp; ++c) {
          if (starts.data()[c] < 0 || sizes.data()[c] < 0 ||
              starts.data()[c] + sizes.data()[c] > n_cells) {
            throw std::invalid_argument("ray_parity_votes: a component's range is outside order");
          }
        }
        for (i64 i = 0; i < n_points; ++i) {
          if (comps.data()[i] < 0 || comps.data()[i] >= n_comp) {
            throw std::invalid_argument("ray_parity_votes: a point's component does not exist");
          }
        }
        nb::gil_scoped_release unlocked;
        ray_votes(vertices.data(), cells.data(), order.data(), starts.data(), sizes.data(),
                  points.data(), comps.data(), n_points, rays.data(), int(rays.shape(0)),
                  threads, votes.data());
      },
      "vertices"_a, "cells"_a, "order"_a, "starts"_a, "sizes"_a, "points"_a, "comps"_a,
      "rays"_a, "threads"_a, "votes"_a.noconvert(),
      "How many of the rays from each point cross its component an odd number of times.");
}
