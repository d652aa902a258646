// Distances from points to a triangle mesh, exact up to a radius: the
// measure behind decimation's bounds (isoconvert/post/decimate.py), where the
// numpy version took 9 s per pass on a 746k-triangle CT surface.
//
// A uniform grid of cubic buckets. Each triangle is listed in every bucket its
// bounding box, grown by the radius, touches; so every triangle within the
// radius of a point is listed in the point's own bucket, and one bucket is
// all a query reads. The buckets are compressed rows filled in triangle order,
// so the nearest triangle of a point (the first at the least distance) does
// not depend on the number of threads.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <cstdint>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <vector>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

struct Vec {
  double x, y, z;
};
inline Vec sub(const Vec &a, const Vec &b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline double dot(const Vec &a, const Vec &b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec cross(const Vec &a, const Vec &b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}

// Squared distance from p to the segment a-b (a point when a == b).
inline double segment_sq(const Vec &p, const Vec &a, const Vec &b) {
  const Vec ab = sub(b, a), ap = sub(p, a);
  const double denom = dot(ab, ab);
  double s = denom > 0.0 ? dot(ap, ab) / denom : 0.0;
  s = std::min(1.0, std::max(0.0, s));
  const Vec d = {ap.x - s * ab.x, ap.y - s * ab.y, ap.z - s * ab.z};
  return dot(d, d);
}

// Squared distance from p to the triangle a, b, c: to its plane when p
// projects inside it, else to the nearest edge (a degenerate triangle is its
// edges).
inline double triangle_sq(const Vec &p, const Vec &a, const Vec &b, const Vec &c) {
  const Vec ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
  const Vec n = cross(ab, ac);
  const double nn = dot(n, n);
  if (nn > 0.0) {
    const double v = dot(cross(ap, ac), n) / nn;
    const double w = dot(cross(ab, ap), n) / nn;
    if (v >= 0.0 && w >= 0.0 && v + w <= 1.0) {
      const double h = dot(ap, n);
      return h * h / nn;
    }
  }
  return std::min(std::min(segment_sq(p, a, b), segment_sq(p, b, c)), segment_sq(p, c, a));
}

// The farthest any point of the triangle is from its nearest corner: the
// circumradius of an acute or right triangle; for an obtuse one, where the
// perpendicular bisectors of its two shorter sides cross the longest, s / (2
// cos) of the angle between each shorter side s and the longest; half the
// longest side for a flat one.
inline double cover_radius(const Vec &p0, const Vec &p1, const Vec &p2) {
  const Vec side[3] = {sub(p2, p1), sub(p0, p2), sub(p1, p0)};  // side k opposite corner k
  double sq[3];
  for (int k = 0; k < 3; ++k) sq[k] = dot(side[k], side[k]);
  const int longest = sq[0] >= sq[1] ? (sq[0] >= sq[2] ? 0 : 2) : (sq[1] >= sq[2] ? 1 : 2);
  const double half_longest = 0.5 * std::sqrt(sq[longest]);
  const Vec n = cross(side[1], side[2]);
  const double area2 = std::sqrt(dot(n, n));
  if (!(area2 > 0.0)) return half_longest;
  double r;
  if (sq[longest] > sq[(longest + 1) % 3] + sq[(longest + 2) % 3]) {
    r = 0.0;
    for (int shift = 1; shift <= 2; ++shift) {
      const int i = (longest + shift) % 3, j = 3 - longest - i;
      const double s_i = sq[j];  // from corner i to the obtuse corner
      const double cos_i = (s_i + sq[longest] - sq[i]) / (2.0 * std::sqrt(s_i * sq[longest]));
      r = std::max(r, std::sqrt(s_i) / (2.0 * cos_i));
    }
  } else {
    r = std::sqrt(sq[0] * sq[1] * sq[2]) / (2.0 * area2);
  }
  return std::isfinite(r) ? r : half_longest;
}

// The distance and nearest triangle of the midpoints measured while one
// triangle is certified. Neighbouring pieces share their edges, so without it
// nearly every midpoint below the first split is measured twice: a piece's
// corners and midpoints are computed from its parent's by the same operations
// whichever piece asks, so equal points are equal bits and a point's entry is
// what measuring it again would give. Open addressing over the coordinate
// bits; `generation` empties the table for the next triangle without a pass.
class MidpointMemo {
 public:
  // A triangle split `depth` times has (2^depth + 1)(2^depth + 2) / 2 points:
  // room for twice as many, up to 2^16 slots (a deeper split than that
  // measures its further points again, which gives the same answers).
  explicit MidpointMemo(int depth) {
    const int d = std::min(depth, 7);
    const i64 points = ((i64(1) << d) + 1) * ((i64(1) << d) + 2) / 2;
    i64 size = 16;
    while (size < 2 * points) size *= 2;
    slots_.resize(size_t(size));
    mask_ = std::uint64_t(size - 1);
  }

  void clear() {
    ++generation_;
    used_ = 0;
  }

  // The entry of `m`, and whether it was there already (else the caller fills it).
  bool find(const Vec &m, double *&distance, i64 *&nearest) {
    std::uint64_t key[3];
    std::memcpy(key, &m, sizeof key);
    std::uint64_t h = key[0] * 0x9E3779B97F4A7C15ull;
    h = (h ^ key[1] ^ (h >> 29)) * 0xBF58476D1CE4E5B9ull;
    h = (h ^ key[2] ^ (h >> 32)) * 0x94D049BB133111EBull;
    for (std::uint64_t i = (h ^ (h >> 31)) & mask_;; i = (i + 1) & mask_) {
      Slot &s = slots_[i];
      if (s.generation != generation_) {
        if (2 * used_ >= slots_.size()) {  // full: measured, not kept
          distance = &spare_.distance;
          nearest = &spare_.nearest;
          return false;
        }
        ++used_;
        s.generation = generation_;
        std::memcpy(s.key, key, sizeof key);
        distance = &s.distance;
        nearest = &s.nearest;
        return false;
      }
      if (std::memcmp(s.key, key, sizeof key) == 0) {
        distance = &s.distance;
        nearest = &s.nearest;
        return true;
      }
    }
  }

 private:
  struct Slot {
    std::uint64_t key[3];
    double distance;
    i64 nearest;
    std::uint64_t generation = 0;
  };
  std::vector<Slot> slots_;
  Slot spare_;
  size_t used_ = 0;
  std::uint64_t mask_ = 0;
  std::uint64_t generation_ = 0;
};

// Triangle and vertex numbers as the grid keeps them: a mesh's index list is
// most of a grid's memory (decimation keeps its input's grid throughout), and no
// mesh that fits in memory has 2^32 triangles.
using Index = std::uint32_t;

struct Grid {
  Vec origin{};
  double size = 1.0;
  i64 dims[3] = {1, 1, 1};
  std::vector<i64> offsets;  // bucket b holds triangles[offsets[b] .. offsets[b + 1]]
  std::vector<Index> triangles;
};

// A coordinate as a float no larger (down) or no smaller (up): boxes kept in
// float32 still hold their triangles, so they only ever prune less.
inline float down(double x) {
  const float f = float(x);
  return double(f) > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
inline float up(double x) {
  const float f = float(x);
  return double(f) < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}

// Buckets half as large as the median grown triangle box: a few buckets
// per triangle and few triangles per bucket (measured on a CT surface:
// 0.8x the time of buckets as large as the box). Doubled while the grid would
// have far more buckets than triangles (any size gives the same answers).
// Points outside the grid are farther than the radius from every triangle.
// `box`: each triangle's bounding box (lower x, y, z, upper x, y, z).
Grid build_grid(const std::vector<float> &box, i64 n_tri, double radius) {
  Grid g;
  std::vector<double> extent(n_tri);
  double mn[3], mx[3];
  for (int k = 0; k < 3; ++k) {
    mn[k] = std::numeric_limits<double>::infinity();
    mx[k] = -mn[k];
  }
  for (i64 f = 0; f < n_tri; ++f) {
    double e = 0.0;
    for (int k = 0; k < 3; ++k) {
      e = std::max(e, box[6 * f + 3 + k] - box[6 * f + k] + 2.0 * radius);
      mn[k] = std::min(mn[k], box[6 * f + k] - radius);
      mx[k] = std::max(mx[k], box[6 * f + 3 + k] + radius);
    }
    extent[f] = e;
  }
  std::nth_element(extent.begin(), extent.begin() + n_tri / 2, extent.end());
  g.size = std::max(0.5 * extent[n_tri / 2], 1e-12);
  g.origin = {mn[0], mn[1], mn[2]};
  const double budget = std::max(8.0 * double(n_tri), double(1 << 20));
  for (;;) {
    double total = 1.0;
    for (int k = 0; k < 3; ++k) total *= std::floor((mx[k] - mn[k]) / g.size) + 2.0;
    if (total <= budget) break;
    g.size *= 2.0;
  }
  for (int k = 0; k < 3; ++k) g.dims[k] = i64(std::floor((mx[k] - mn[k]) / g.size)) + 2;
  auto each = [&](i64 f, auto &&emit) {
    i64 first[3], last[3];
    for (int k = 0; k < 3; ++k) {
      first[k] = i64(std::floor((box[6 * f + k] - radius - mn[k]) / g.size));
      last[k] = i64(std::floor((box[6 * f + 3 + k] + radius - mn[k]) / g.size));
    }
    for (i64 z = first[2]; z <= last[2]; ++z) {
      for (i64 y = first[1]; y <= last[1]; ++y) {
        for (i64 x = first[0]; x <= last[0]; ++x) emit(x + g.dims[0] * (y + g.dims[1] * z));
      }
    }
  };
  iso::fill_buckets(n_tri, g.dims[0] * g.dims[1] * g.dims[2], each, g.offsets, g.triangles);
  return g;
}

// A grid over one mesh, built once and queried many times (decimation asks
// for distances to its input after every collapse). It reads the mesh's
// arrays where they are, holding them (a copy was a quarter of a large
// mesh's grid, and decimation holds two).
class TriangleGrid {
 public:
  TriangleGrid(Doubles vertices, Int64s triangles, double radius)
      : vertices_(std::move(vertices)),
        triangles_(std::move(triangles)),
        v_(vertices_.data()),
        t_(triangles_.data()),
        n_tri_(i64(triangles_.shape(0))) {
    box_.resize(6 * n_tri_);
    for (i64 f = 0; f < n_tri_; ++f) {
      for (int k = 0; k < 3; ++k) {
        const double a = v_[3 * t_[3 * f] + k], b = v_[3 * t_[3 * f + 1] + k];
        const double c = v_[3 * t_[3 * f + 2] + k];
        box_[6 * f + k] = down(std::min(std::min(a, b), c));
        box_[6 * f + 3 + k] = up(std::max(std::max(a, b), c));
      }
    }
    if (n_tri_) g_ = build_grid(box_, n_tri_, radius);
  }

  // Squared distance from q to the nearest triangle and that triangle (inf
  // and -1 when no triangle's grown box holds q).
  double nearest_sq(const Vec &q, i64 &which) const {
    const Grid &g = g_;
    double best = std::numeric_limits<double>::infinity();
    which = -1;
    if (n_tri_ == 0) return best;
    const double c[3] = {q.x, q.y, q.z}, o[3] = {g.origin.x, g.origin.y, g.origin.z};
    i64 ijk[3];
    for (int k = 0; k < 3; ++k) {
      const double cell = std::floor((c[k] - o[k]) / g.size);
      if (!(cell >= 0.0 && cell < double(g.dims[k]))) return best;
      ijk[k] = i64(cell);
    }
    const i64 b = ijk[0] + g.dims[0] * (ijk[1] + g.dims[1] * ijk[2]);
    for (i64 e = g.offsets[b]; e < g.offsets[b + 1]; ++e) {
      const i64 f = g.triangles[e];
      // a triangle whose box is already farther than the best cannot be nearer
      const float *lo = &box_[6 * f], *hi = lo + 3;
      double box2 = 0.0;
      for (int k = 0; k < 3; ++k) {
        const double gap = std::max(std::max(lo[k] - c[k], c[k] - hi[k]), 0.0);
        box2 += gap * gap;
      }
      if (box2 >= best) continue;
      const double d2 = triangle_sq(q, corner(f, 0), corner(f, 1), corner(f, 2));
      if (d2 < best) {
        best = d2;
        which = f;
      }
    }
    return best;
  }

  void distances(const double *points, i64 n_points, int threads, double *out,
                 i64 *nearest) const {
    iso::parallel_for(n_points, threads, 4096, [&](int, i64 begin, i64 end) {
      for (i64 p = begin; p < end; ++p) {
        const Vec q = {points[3 * p], points[3 * p + 1], points[3 * p + 2]};
        out[p] = std::sqrt(nearest_sq(q, nearest[p]));
      }
    });
  }

  // Whether each triangle (over `v`) lies within `bound` of this mesh:
  // certified by the 1-Lipschitz distance (a triangle whose corners lie
  // within d lies within d + its cover radius), or by convexity (the distance
  // to one triangle of the mesh is convex, so a piece whose corners all lie
  // within the bound of the nearest triangle of one of them lies within it),
  // splitting uncertified ones into four at their edges' midpoints, at most
  // `depth` times. `reach`: the certified bound, or the largest distance
  // measured where it fails; `failed`: 1 where a point is farther than
  // `bound`, 2 where `depth` halvings did not certify it. `corner_distance`
  // (V,): each vertex's distance to this mesh, measured before.
  void certify(const double *v, const i64 *t, i64 n, const double *corner_distance,
               double bound, int depth, int threads, double *reach,
               std::uint8_t *failed) const {
    iso::parallel_for(n, threads, 256, [&](int, i64 begin, i64 end) {
      struct Piece {
        Vec p[3];
        double d[3];
        i64 near[3];  // the nearest triangle of each corner (-1: not known)
        int level;
      };
      std::vector<Piece> stack;
      MidpointMemo memo(depth);
      for (i64 f = begin; f < end; ++f) {
        memo.clear();
        Piece top;
        for (int q = 0; q < 3; ++q) {
          const double *c = v + 3 * t[3 * f + q];
          top.p[q] = {c[0], c[1], c[2]};
          top.d[q] = corner_distance[t[3 * f + q]];
          top.near[q] = -1;
        }
        top.level = 0;
        stack.assign(1, top);
        double worst = 0.0;
        std::uint8_t status = 0;
        while (!stack.empty() && !status) {
          Piece piece = stack.back();
          stack.pop_back();
          const double far = std::max(std::max(piece.d[0], piece.d[1]), piece.d[2]);
          const double r = far + cover_radius(piece.p[0], piece.p[1], piece.p[2]);
          if (r <= bound) {
            worst = std::max(worst, r);
            continue;
          }
          // the distance to one triangle of the mesh is convex, so the piece
          // lies within the largest distance of its corners to that triangle
          if (piece.level == 0) {
            for (int q = 0; q < 3; ++q) nearest_sq(piece.p[q], piece.near[q]);
          }
          double convex = std::numeric_limits<double>::infinity();
          for (int q = 0; q < 3; ++q) {
            const i64 g = piece.near[q];
            if (g < 0 || (q > 0 && g == piece.near[0]) || (q > 1 && g == piece.near[1])) continue;
            // a corner past the bound rules this triangle out (its value is then
            // never used: only a convex bound within the bound certifies)
            double most = 0.0;
            for (int k = 0; k < 3 && std::sqrt(most) <= bound; ++k) {
              most = std::max(most, triangle_sq(piece.p[k], corner(g, 0), corner(g, 1), corner(g, 2)));
            }
            if (std::sqrt(most) <= bound) convex = std::min(convex, std::sqrt(most));
          }
          if (convex <= bound) {
            worst = std::max(worst, convex);
            continue;
          }
          if (piece.level == depth) {
            status = 2;
            worst = std::max(worst, far);
            break;
          }
          Vec m[3];
          double dm[3];
          i64 nm[3];
          for (int q = 0; q < 3; ++q) {
            const Vec &a = piece.p[q], &b = piece.p[(q + 1) % 3];
            m[q] = {0.5 * (a.x + b.x), 0.5 * (a.y + b.y), 0.5 * (a.z + b.z)};
            double *known_distance;
            i64 *known_nearest;
            if (memo.find(m[q], known_distance, known_nearest)) {
              dm[q] = *known_distance;
              nm[q] = *known_nearest;
            } else {
              dm[q] = *known_distance = std::sqrt(nearest_sq(m[q], nm[q]));
              *known_nearest = nm[q];
            }
            if (dm[q] > bound) {
              status = 1;
              worst = std::max(worst, dm[q]);
            }
          }
          if (status) break;
          // m[0] on p0-p1, m[1] on p1-p2, m[2] on p2-p0
          const int lv = piece.level + 1;
          const Vec *p = piece.p;
          const double *d = piece.d;
          const i64 *e = piece.near;
          stack.push_back({{p[0], m[0], m[2]}, {d[0], dm[0], dm[2]}, {e[0], nm[0], nm[2]}, lv});
          stack.push_back({{m[0], p[1], m[1]}, {dm[0], d[1], dm[1]}, {nm[0], e[1], nm[1]}, lv});
          stack.push_back({{m[2], m[1], p[2]}, {dm[2], dm[1], d[2]}, {nm[2], nm[1], e[2]}, lv});
          stack.push_back({{m[0], m[1], m[2]}, {dm[0], dm[1], dm[2]}, {nm[0], nm[1], nm[2]}, lv});
        }
        reach[f] = worst;
        failed[f] = status;
      }
    });
  }

 private:
  Vec corner(i64 f, int q) const {
    const double *c = v_ + 3 * t_[3 * f + q];
    return Vec{c[0], c[1], c[2]};
  }

  Doubles vertices_;  // held: the Python arrays stay alive while the grid reads them
  Int64s triangles_;
  const double *v_;
  const i64 *t_;
  i64 n_tri_;
  Grid g_;
  std::vector<float> box_;  // per triangle: lower x, y, z, upper x, y, z (outwards)
};

}  // namespace

void bind_distance(nb::module_ &m) {
  nb::class_<TriangleGrid>(
      m, "TriangleGrid",
      "Distances from points to one triangle mesh, exact up to the radius it was built for.")
      .def(
          "__init__",
          [](TriangleGrid *self, Doubles vertices, Int64s triangles, double radius) {
            if (vertices.ndim() != 2 || vertices.shape(1) != 3 || triangles.ndim() != 2 ||
                triangles.shape(1) != 3) {
              throw std::invalid_argument("TriangleGrid: vertices (V, 3), triangles (T, 3)");
            }
            if (!(radius >= 0.0) || !std::isfinite(radius)) {
              throw std::invalid_argument("TriangleGrid: radius must be finite and >= 0");
            }
            const i64 n_vertices = i64(vertices.shape(0)), n_tri = i64(triangles.shape(0));
            if (n_vertices > i64(std::numeric_limits<Index>::max()) ||
                n_tri > i64(std::numeric_limits<Index>::max())) {
              throw std::invalid_argument("TriangleGrid: at most 2^32 - 1 vertices and triangles");
            }
            for (i64 k = 0; k < 3 * n_tri; ++k) {
              if (triangles.data()[k] < 0 || triangles.data()[k] >= n_vertices) {
                throw std::invalid_argument("TriangleGrid: a triangle index is not a vertex");
              }
            }
            for (i64 k = 0; k < 3 * n_vertices; ++k) {
              if (!(std::abs(vertices.data()[k]) <= 1e37)) {  // a float32 box holds it
                throw std::invalid_argument("TriangleGrid: vertices must be finite, within 1e37");
              }
            }
            nb::gil_scoped_release unlocked;
            new (self) TriangleGrid(std::move(vertices), std::move(triangles), radius);
          },
          "vertices"_a, "triangles"_a, "radius"_a)
      .def(
          "distances",
          [](const TriangleGrid &grid, Doubles points, int threads, Out<double> out,
             Out<i64> nearest) {
            if (points.ndim() != 2 || points.shape(1) != 3) {
              throw std::invalid_argument("TriangleGrid.distances: points (P, 3)");
            }
            const i64 n_points = i64(points.shape(0));
            check_out(out, n_points, 0, "out");
            check_out(nearest, n_points, 0, "nearest");
            nb::gil_scoped_release unlocked;
            grid.distances(points.data(), n_points, threads, out.data(), nearest.data());
          },
          "points"_a, "threads"_a, "out"_a.noconvert(), "nearest"_a.noconvert(),
          "Distance from each point to the nearest triangle (exact when at most the radius; "
          "inf when no triangle is within it), and that triangle (-1 for none).")
      .def(
          "certify",
          [](const TriangleGrid &grid, Doubles vertices, Int64s triangles,
             Doubles corner_distance, double bound, int depth, int threads, Out<double> reach,
             Out<std::uint8_t> failed) {
            if (vertices.ndim() != 2 || vertices.shape(1) != 3 || triangles.ndim() != 2 ||
                triangles.shape(1) != 3) {
              throw std::invalid_argument(
                  "TriangleGrid.certify: vertices (V, 3), triangles (T, 3)");
            }
            const i64 n_vertices = i64(vertices.shape(0)), n = i64(triangles.shape(0));
            if (corner_distance.ndim() != 1 || i64(corner_distance.shape(0)) != n_vertices) {
              throw std::invalid_argument("TriangleGrid.certify: corner_distance (V,)");
            }
            for (i64 k = 0; k < 3 * n; ++k) {
              if (triangles.data()[k] < 0 || triangles.data()[k] >= n_vertices) {
                throw std::invalid_argument("TriangleGrid.certify: a triangle index is not a vertex");
              }
            }
            if (depth < 0 || depth > 30) {
              throw std::invalid_argument("TriangleGrid.certify: depth must be in 0..30");
            }
            check_out(reach, n, 0, "reach");
            check_out(failed, n, 0, "failed");
            nb::gil_scoped_release unlocked;
            grid.certify(vertices.data(), triangles.data(), n, corner_distance.data(), bound,
                         depth, threads, reach.data(), failed.data());
          },
          "vertices"_a, "triangles"_a, "corner_distance"_a, "bound"_a, "depth"_a, "threads"_a,
          "reach"_a.noconvert(),
          "failed"_a.noconvert(),
          "Whether each triangle lies within bound of the mesh (see distance.cpp).");
}
