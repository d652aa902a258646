// What rounding vertices to float32 could change (isoconvert/writers/precision.py):
// the triangles whose degeneracy it might. Every other triangle is provably as
// (non-)degenerate in float32 as in float64 (the bound is derived in
// precision.py's _candidates); this is the same arithmetic, in the same order,
// one triangle at a time instead of numpy's block-by-block temporaries, which
// took 4 ms per 15k-triangle mesh: most of writing 40 label meshes. And before
// it, which vertices rounding moves at all (moved_by_float32): on a label mesh
// the few split vertices, so every later test runs on a handful.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

constexpr double kU32 = 1.0 / 16777216.0;  // 2^-24, float32's unit roundoff
constexpr double kTiny32 = 1.401298464324817e-45;  // 2^-149
constexpr double kEps64 = 2.220446049250313e-16;   // 2^-52

// Appends to `near` (ascending) the triangles whose cross product is within the
// float32 rounding bound of zero, or with two corners in one float32 position
// group (group null: no two corners share one).
void candidates(const double *xyz, i64 nv, const i64 *cells, i64 nt, const i64 *group,
                int threads, std::vector<i64> &near) {
  std::vector<double> largest(static_cast<size_t>(nv));
  for (i64 v = 0; v < nv; ++v) {
    const double *p = xyz + 3 * v;
    largest[v] = std::max(std::max(std::abs(p[0]), std::abs(p[1])), std::abs(p[2]));
  }
  const i64 grain = 1 << 15;
  std::vector<std::vector<i64>> found(static_cast<size_t>(iso::chunk_count(nt, grain)));
  iso::parallel_for(nt, threads, grain, [&](int, i64 begin, i64 end) {
    std::vector<i64> &mine = found[begin / grain];
    for (i64 t = begin; t < end; ++t) {
      const i64 i0 = cells[3 * t], i1 = cells[3 * t + 1], i2 = cells[3 * t + 2];
      const double *p0 = xyz + 3 * i0, *p1 = xyz + 3 * i1, *p2 = xyz + 3 * i2;
      const double ax = p1[0] - p0[0], ay = p1[1] - p0[1], az = p1[2] - p0[2];
      const double bx = p2[0] - p0[0], by = p2[1] - p0[1], bz = p2[2] - p0[2];
      const double cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
      const double cross2 = cx * cx + cy * cy + cz * cz;
      const double longer = std::max(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz);
      const double longest = 2.0 * std::sqrt(longer);
      const double m = std::max(std::max(largest[i0], largest[i1]), largest[i2]);
      const double s = kU32 * m + kTiny32;
      const double rounding = 64.0 * kEps64 * (m + s) * (longest + 4.0 * s);
      const double bound = 2.0 * (rounding + 8.0 * longest * s + 16.0 * s * s);
      bool keep = cross2 <= bound * bound;
      if (group) {
        const i64 g0 = group[i0], g1 = group[i1], g2 = group[i2];
        keep |= g0 == g1 || g1 == g2 || g0 == g2;
      }
      if (keep) mine.push_back(t);
    }
  });
  for (const auto &f : found) near.insert(near.end(), f.begin(), f.end());
}

// A float32 position as a key that compares equal for equal positions
// (-0.0 and 0.0 alike; NaN never reaches it: NaN counts as moved).
struct Position32 {
  float x, y, z;
  bool operator==(const Position32 &o) const { return x == o.x && y == o.y && z == o.z; }
};

// Equal positions (-0.0 normalized to 0.0 beforehand) hash alike: a slot of a
// table of 2^bits from the high bits of a multiplicative hash, which depend on
// every bit of the three (grid positions have zero low mantissa bits).
inline size_t hash32(const Position32 &q, int bits) {
  std::uint32_t b[3];
  std::memcpy(b, &q, sizeof b);
  const std::uint64_t h = std::uint64_t(b[0]) * 0x9E3779B97F4A7C15ull +
                          std::uint64_t(b[1]) * 0xC2B2AE3D27D4EB4Full +
                          std::uint64_t(b[2]) * 0x165667B19E3779F9ull;
  return size_t(h >> (64 - bits));
}

inline bool moves(const double *p) {
  // NaN compares unequal to itself: it counts as moved, as numpy's != says
  return double(float(p[0])) != p[0] || double(float(p[1])) != p[1] ||
         double(float(p[2])) != p[2];
}

// The vertices float32 rounding moves, with those that stay where one of them lands
// (ascending; every vertex when most move), and the cells with a moved corner.
void moved_by_float32(const double *xyz, i64 nv, const i64 *cells, i64 nc, int corners,
                      std::vector<i64> &some, std::vector<i64> &touched) {
  std::vector<unsigned char> moved(static_cast<size_t>(nv));
  i64 count = 0;
  for (i64 v = 0; v < nv; ++v) {
    moved[v] = moves(xyz + 3 * v);
    count += moved[v];
  }
  if (count == 0) return;
  if (2 * count >= nv) {
    some.resize(static_cast<size_t>(nv));
    for (i64 v = 0; v < nv; ++v) some[v] = v;
  } else {
    // where the moved vertices land, in an open-addressing set (a sorted list
    // searched once per vertex cost more than the rest of the pass)
    int bits = 4;
    while ((size_t(1) << bits) < 2 * size_t(count)) ++bits;
    const size_t size = size_t(1) << bits;
    std::vector<Position32> slot(size);
    std::vector<unsigned char> used(size, 0);
    auto find = [&](const Position32 &q) {
      size_t h = hash32(q, bits);
      while (used[h] && !(slot[h] == q)) h = (h + 1) & (size - 1);
      return h;
    };
    for (i64 v = 0; v < nv; ++v) {
      const double *p = xyz + 3 * v;  // + 0.0f: -0.0 lands where 0.0 does
      if (!moved[v] || std::isnan(p[0] + p[1] + p[2])) continue;  // no vertex stays at NaN
      const Position32 q{float(p[0]) + 0.0f, float(p[1]) + 0.0f, float(p[2]) + 0.0f};
      const size_t h = find(q);
      slot[h] = q;
      used[h] = 1;
    }
    for (i64 v = 0; v < nv; ++v) {
      bool keep = moved[v];
      if (!keep) {
        const double *p = xyz + 3 * v;
        const Position32 q{float(p[0]) + 0.0f, float(p[1]) + 0.0f, float(p[2]) + 0.0f};
        keep = used[find(q)] != 0;
      }
      if (keep) some.push_back(v);
    }
  }
  for (i64 c = 0; c < nc; ++c) {
    bool any = false;
    for (int k = 0; k < corners; ++k) any |= moved[cells[corners * c + k]] != 0;
    if (any) touched.push_back(c);
  }
}

}  // namespace

void bind_precision(nb::module_ &m) {
  m.def(
      "float32_candidates",
      [](Doubles vertices, Int64s cells, Int64s group, int threads) {
        const i64 nv = vertices.ndim() == 2 && vertices.shape(1) == 3 ? i64(vertices.shape(0))
                                                                        : -1;
        const i64 nt = cells.ndim() == 2 && cells.shape(1) == 3 ? i64(cells.shape(0)) : -1;
        if (nv < 0 || nt < 0 || (group.size() != 0 && i64(group.size()) != nv)) {
          throw std::invalid_argument(
              "float32_candidates: vertices (V, 3), cells (C, 3), group () or (V,)");
        }
        const i64 *c = cells.data();
        for (i64 k = 0; k < 3 * nt; ++k) {
          if (c[k] < 0 || c[k] >= nv) {
            throw std::invalid_argument("float32_candidates: a cell refers to no vertex");
          }
        }
        std::vector<i64> near;
        {
          nb::gil_scoped_release unlocked;
          candidates(vertices.data(), nv, c, nt, group.size() ? group.data() : nullptr,
                     threads, near);
        }
        return give(std::move(near));
      },
      "vertices"_a, "cells"_a, "group"_a, "threads"_a,
      "Triangles (ascending) whose degeneracy rounding the vertices to float32 could change.");
  m.def(
      "moved_by_float32",
      [](Doubles vertices, Int64s cells) {
        const i64 nv = vertices.ndim() == 2 && vertices.shape(1) == 3 ? i64(vertices.shape(0))
                                                                        : -1;
        const int corners = cells.ndim() == 2 ? int(cells.shape(1)) : 0;
        if (nv < 0 || (corners != 2 && corners != 3)) {
          throw std::invalid_argument("moved_by_float32: vertices (V, 3), cells (C, 3) or (C, 2)");
        }
        const i64 nc = i64(cells.shape(0));
        const i64 *c = cells.data();
        for (i64 k = 0; k < corners * nc; ++k) {
          if (c[k] < 0 || c[k] >= nv) {
            throw std::invalid_argument("moved_by_float32: a cell refers to no vertex");
          }
        }
        std::vector<i64> some, touched;
        {
          nb::gil_scoped_release unlocked;
          moved_by_float32(vertices.data(), nv, c, nc, corners, some, touched);
        }
        return nb::make_tuple(give(std::move(some)), give(std::move(touched)));
      },
      "vertices"_a, "cells"_a,
      "(vertices, cells): ascending indices of the vertices rounding to float32 moves, with\n"
      "those that stay where one of them lands (every vertex when most move; none when none\n"
      "moves), and of the cells with a moved corner.");
}
