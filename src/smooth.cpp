// Mesh smoothing (isoconvert/post/smooth.py): the stencil, built once from
// the triangles, and the filters, every iteration in one call.
//
// The stencil. Around each vertex its corners' two edges, sorted by their
// other end, give each edge's multiplicity (triangles using it), the fans
// (corners joined across edges used exactly twice) and, through a shared
// union-find, the components. A vertex is fixed when it is in no triangle,
// on an edge used more than twice, on more than one fan, on other than zero
// or two open-boundary edges, on all three grid boundary planes, or in a
// component of fewer used vertices than `hold_below`. A vertex on two
// open-boundary edges (a curve vertex) averages its two boundary neighbours;
// any other free vertex all its neighbours (in the order of its corners at an
// interior vertex, else in ascending order). numpy's
// version of this (edge table, bincounts, argsort) took 0.25 s on a
// 1.26M-triangle surface.
//
// The filters. Each iteration is one pass over the vertices: the umbrella
// operator L x_i = x_i - mean(x_j) over the stencil, its component along a
// vertex's constrained index axes removed, and the filter's update (one step
// of the Chebyshev recurrence and its partial sum, or a Taubin/Laplacian
// step) fused with it. Positions are (V, 3) rows, so a neighbour's three
// coordinates are one read. The expressions are those numpy evaluated before
// (same operands, same order; -ffp-contract=off), so only the order of each
// vertex's neighbours in its sum changed.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "bind.hpp"
#include "common.hpp"
#include "corners.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;
using u8 = std::uint8_t;

// A vertex's code. Bits 0-2: it lies on a grid boundary plane of index axis
// 0, 1, 2 (index coordinate 0 or shape - 1); the others as named.
constexpr u8 kPlanes = 7, kUsed = 8, kFixed = 16, kCurve = 32, kSmall = 64;
constexpr double kHuge = std::numeric_limits<double>::infinity();

// One edge end around v: the neighbour and the corner of v using the edge.
template <class I>
struct RingEntry {
  I other;
  I corner;  // 0 .. k - 1, among v's corners
};

// Corner q of v (of k, cs its corner numbers) runs v -> nx[q] and pv[q] -> v.
template <class I, class C>
inline void corner_ends(const C *tv, const I *cs, i64 k, I *nx, I *pv) {
  for (i64 q = 0; q < k; ++q) {
    const i64 c = cs[q], t3 = c - c % 3, j = c - t3;
    nx[q] = static_cast<I>(tv[t3 + (j == 2 ? 0 : j + 1)]);
    pv[q] = static_cast<I>(tv[t3 + (j == 0 ? 2 : j - 1)]);
  }
}

constexpr int kFast = 16;  // corners handled by the closed-fan path

// The usual interior vertex of an oriented manifold: each corner's next vertex
// is the previous vertex of exactly one corner, and every corner is met so;
// then v's neighbours are its k next vertices, every edge at v is used twice,
// and the fans are the cycles of "the corner across the edge v -> nx[q]".
// Returns their number, or 0 for any other vertex. pv is padded to a multiple
// of 4 with a value no vertex has.
template <class I>
int closed_fans(const I *nx, const I *pv, int k) {
  const int groups = (k + 3) / 4;
  int across[kFast];
  unsigned hit = 0;
  for (int q = 0; q < k; ++q) {
    const unsigned as_prev = iso::matches(pv, nx[q], groups);
    if (as_prev == 0 || (as_prev & (as_prev - 1)) != 0) return 0;  // not once
    across[q] = iso::ctz(as_prev);
    hit |= as_prev;
  }
  if (hit != (1u << k) - 1) return 0;
  int fans = 0;
  unsigned seen = 0;
  for (int q = 0; q < k; ++q) {
    if (seen >> q & 1) continue;
    ++fans;
    for (int r = q; !(seen >> r & 1); r = across[r]) seen |= 1u << r;
  }
  return fans;
}

// Any vertex: its ring (two entries per corner) sorted by neighbour, then corner.
template <class I>
void sort_ring(const I *nx, const I *pv, i64 k, std::vector<RingEntry<I>> &ring) {
  ring.resize(size_t(2 * k));
  for (i64 q = 0; q < k; ++q) {
    ring[2 * q] = {nx[q], static_cast<I>(q)};
    ring[2 * q + 1] = {pv[q], static_cast<I>(q)};
  }
  std::sort(ring.begin(), ring.end(), [](const RingEntry<I> &a, const RingEntry<I> &b) {
    return a.other < b.other || (a.other == b.other && a.corner < b.corner);
  });
}

struct GridPlanes {
  bool present = false;
  double origin[3], inverse[9], top[3], tolerance;
};

// Bits 0-2 of a vertex's code: the grid boundary planes it lies on.
inline u8 planes_of(const GridPlanes &g, const double *p) {
  if (!g.present) return 0;
  u8 bits = 0;
  const double d[3] = {p[0] - g.origin[0], p[1] - g.origin[1], p[2] - g.origin[2]};
  for (int a = 0; a < 3; ++a) {
    const double index = d[0] * g.inverse[3 * a] + d[1] * g.inverse[3 * a + 1] +
                         d[2] * g.inverse[3 * a + 2];
    if (std::abs(index) <= g.tolerance || std::abs(index - g.top[a]) <= g.tolerance) {
      bits |= u8(1u << a);
    }
  }
  return bits;
}

// A worker's buffers, reused from vertex to vertex.
template <class I>
struct Scratch {
  std::vector<I> nx, pv, up, row;
  std::vector<RingEntry<I>> ring;
  double lo[3] = {kHuge, kHuge, kHuge}, hi[3] = {-kHuge, -kHuge, -kHuge};
  i64 reach = 0;
  // rows longer than the table: vertex, where its rest starts in `rest`
  std::vector<std::pair<i64, i64>> long_rows;
  std::vector<I> rest;
};

// Positions with the zero row n the umbrella operator's missing slots read,
// normalized (x - center) / length; uninitialized but for that row unless x
// is given.
class Padded {
 public:
  Padded(i64 n, const double *x, const double *center, double length, int threads)
      : xyz_(3 * (n + 1), false, iso::Pages::huge) {
    std::fill(xyz_.data() + 3 * n, xyz_.data() + 3 * (n + 1), 0.0);
    if (!x) return;
    iso::parallel_for(n, threads, 1 << 14, [&](int, i64 begin, i64 end) {
      for (i64 i = begin; i < end; ++i) {
        for (int k = 0; k < 3; ++k) xyz_[3 * i + k] = (x[3 * i + k] - center[k]) / length;
      }
    });
  }
  double *data() { return xyz_.data(); }

 private:
  iso::Buffer<double> xyz_;
};

constexpr i64 kGrain = 8192;

// The stencil and the filters that run on it.
//
// Rows. The first kSlots neighbours of each vertex are kept in a padded
// table, the missing ones pointing at a zero row n of the positions: the
// number of neighbours varies from vertex to vertex, and a loop over them
// mispredicted its end at almost every vertex, which cost more than the sums
// (11 ns a vertex on one thread, against 7 now). The few vertices with more
// neighbours (0.6 % of a marching-cubes surface's) keep the rest in
// compressed rows of their own, found by binary search. Fixed vertices have
// no neighbours.
template <class I>
class SmoothingStencil {
 public:
  static constexpr int kSlots = 8;

  std::vector<u8> code;
  i64 small_components = 0;
  double lo[3], hi[3];  // the bounding box of the used vertices
  i64 reach = 0;        // no neighbour's index differs from its vertex's by more

  SmoothingStencil(const I *tv, i64 nt, const double *xyz, i64 nv, const GridPlanes &grid,
                   const double *affine, bool aligned, i64 hold_below, int threads)
      : n_(nv), count_(nv), slots_(kSlots * nv, false, iso::Pages::huge),
        aligned_(aligned) {
    std::copy(affine, affine + 9, affine_);
    std::copy(grid.inverse, grid.inverse + 9, inverse_);
    reciprocal_[0] = 0.0;
    for (int c = 1; c < 64; ++c) reciprocal_[c] = 1.0 / double(c);
    build(tv, nt, xyz, grid, hold_below, threads);
    code_ = code.data();
  }

  i64 vertices() const { return n_; }

  // The rows in compressed form (for tests): offsets (V + 1,), neighbours.
  void rows(std::vector<i64> &offsets, std::vector<I> &neighbours) const {
    offsets.assign(size_t(n_ + 1), 0);
    for (i64 v = 0; v < n_; ++v) offsets[v + 1] = offsets[v] + i64(count_[v]);
    neighbours.resize(size_t(offsets[n_]));
    for (i64 v = 0; v < n_; ++v) {
      I *row = neighbours.data() + offsets[v];
      const i64 count = count_[v];
      for (i64 e = 0; e < std::min<i64>(count, kSlots); ++e) row[e] = slots_[kSlots * v + e];
      if (count > kSlots) std::copy(rest_of(v), rest_of(v) + (count - kSlots), row + kSlots);
    }
  }

  // out = sum_i c_i T_i(I - L / 2) x, filtered on (x - center) / length and
  // scaled back; x and out (V, 3).
  //
  // Two steps of the recurrence per sweep over memory where the mesh allows:
  // no neighbour is more than `reach` indices away, so a thread can run the
  // second step `reach` vertices behind the first, on rows still in cache.
  // Each thread takes one range of vertices; the second step at the `reach`
  // vertices next to either end of its range waits for a second pass, since
  // it reads (and, at the other end, must not yet overwrite) what the next
  // thread computes. The arithmetic is the same as one step per sweep.
  void sinc(const double *c, i64 nc, const double *x, const double *center, double length,
            int threads, double *out) const {
    const i64 n = n_;
    Padded a(n, x, center, length, threads), b(n, nullptr, center, length, threads);
    double *x0 = a.data(), *x1 = b.data();
    // T_0 x = x, T_1 x = x - L x / 2, T_{i+1} x = 2 (I - L / 2) T_i x - T_{i-1} x
    iso::parallel_for(n, threads, kGrain, [&](int, i64 begin, i64 end) {
      for (i64 i = begin; i < end; ++i) {
        double lap[3];
        at(x0, i, lap);
        for (int k = 0; k < 3; ++k) {
          const i64 p = 3 * i + k;
          x1[p] = x0[p] - 0.5 * lap[k];
          out[p] = c[0] * x0[p] + c[1] * x1[p];
        }
      }
    });
    const i64 parts = std::max<i64>(1, std::min<i64>(threads, n / kGrain));
    const bool paired = n / parts >= 4 * reach;
    auto first = [n, parts](i64 t) { return n * t / parts; };
    // x1 holds the latest T_i x, x0 the one before
    for (i64 m = 2; m < nc;) {
      if (paired && m + 1 < nc) {
        const double c1 = c[m], c2 = c[m + 1];
        iso::parallel_for(parts, threads, 1, [&](int, i64 t0, i64 t1) {
          for (i64 t = t0; t < t1; ++t) {
            const i64 begin = first(t), end = first(t + 1);
            for (i64 i = begin; i < end; ++i) {
              chebyshev_at(i, x1, x0, c1, out);
              const i64 k = i - reach;
              if (k >= begin + reach) chebyshev_at(k, x0, x1, c2, out);
            }
          }
        });
        iso::parallel_for(parts, threads, 1, [&](int, i64 t0, i64 t1) {
          for (i64 t = t0; t < t1; ++t) {
            const i64 begin = first(t), end = first(t + 1);
            for (i64 k = begin; k < begin + reach; ++k) chebyshev_at(k, x0, x1, c2, out);
            for (i64 k = end - reach; k < end; ++k) chebyshev_at(k, x0, x1, c2, out);
          }
        });
        m += 2;
      } else {
        const double cm = c[m];
        iso::parallel_for(n, threads, kGrain, [&](int, i64 begin, i64 end) {
          for (i64 i = begin; i < end; ++i) chebyshev_at(i, x1, x0, cm, out);
        });
        std::swap(x0, x1);
        m += 1;
      }
    }
    iso::parallel_for(n, threads, 1 << 14, [&](int, i64 begin, i64 end) {
      for (i64 p = 3 * begin; p < 3 * end; ++p) out[p] = out[p] * length + center[p % 3];
    });
  }

  // x -= f L x for each factor f in turn, on (x - center) / length, in
  // place; x (V, 3).
  void steps(const double *factors, i64 nf, double *x, const double *center, double length,
             int threads) const {
    const i64 n = n_;
    Padded a(n, x, center, length, threads), b(n, nullptr, center, length, threads);
    double *from = a.data(), *to = b.data();
    for (i64 s = 0; s < nf; ++s) {
      const double f = factors[s];
      iso::parallel_for(n, threads, kGrain, [&](int, i64 begin, i64 end) {
        for (i64 i = begin; i < end; ++i) {
          double lap[3];
          at(from, i, lap);
          for (int k = 0; k < 3; ++k) to[3 * i + k] = from[3 * i + k] - f * lap[k];
        }
      });
      std::swap(from, to);
    }
    iso::parallel_for(n, threads, 1 << 14, [&](int, i64 begin, i64 end) {
      for (i64 p = 3 * begin; p < 3 * end; ++p) x[p] = from[p] * length + center[p % 3];
    });
  }

 private:
  i64 n_;
  iso::Buffer<I> count_, slots_;
  const u8 *code_ = nullptr;  // code's data
  std::vector<i64> long_vertices_, long_starts_;  // rows beyond the table, ascending
  std::vector<I> long_rest_;

  // The neighbours of a long row beyond the table.
  const I *rest_of(i64 v) const {
    const auto at = std::lower_bound(long_vertices_.begin(), long_vertices_.end(), v);
    return long_rest_.data() + long_starts_[at - long_vertices_.begin()];
  }
  double affine_[9], inverse_[9];
  bool aligned_;
  double reciprocal_[64];  // 1 / count for the usual counts

  void build(const I *tv, i64 nt, const double *xyz, const GridPlanes &grid, i64 hold_below,
             int threads);

  // L x at vertex i, x (V + 1, 3) with row V zero: x_i minus the mean of its
  // neighbours (0 for a vertex without any), less its component along the
  // index axes of the grid planes the vertex lies on.
  __attribute__((always_inline)) inline void at(const double *x, i64 i, double *lap) const {
    const i64 count = count_[i];
    if (count == 0) {
      lap[0] = lap[1] = lap[2] = 0.0;
      return;
    }
    const I *slot = slots_.data() + kSlots * i;
#if defined(__SSE2__)
    // a neighbour's first two coordinates in one 16-byte load and add
    __m128d s01 = _mm_setzero_pd();
    double s2 = 0.0;
    for (int t = 0; t < kSlots; ++t) {
      const double *y = x + 3 * i64(slot[t]);
      s01 = _mm_add_pd(s01, _mm_loadu_pd(y));
      s2 += y[2];
    }
    if (__builtin_expect(count > kSlots, 0)) add_rest(x, i, count, s01, s2);
    const double s0 = _mm_cvtsd_f64(s01), s1 = _mm_cvtsd_f64(_mm_unpackhi_pd(s01, s01));
#else
    double s0 = 0.0, s1 = 0.0, s2 = 0.0;
    for (int t = 0; t < kSlots; ++t) {
      const double *y = x + 3 * i64(slot[t]);
      s0 += y[0];
      s1 += y[1];
      s2 += y[2];
    }
    if (count > kSlots) add_rest(x, i, count, s0, s1, s2);
#endif
    const double w = count < 64 ? reciprocal_[count] : 1.0 / double(count);
    const double *xi = x + 3 * i;
    lap[0] = xi[0] - w * s0;
    lap[1] = xi[1] - w * s1;
    lap[2] = xi[2] - w * s2;
    const unsigned held = code_[i] & kPlanes;  // free vertices only have rows
    if (held) constrain(held, lap);
  }

  // The sums over a long row's neighbours beyond the table (kept out of line:
  // inlined, the search slowed every vertex's sums by a fifth).
#if defined(__SSE2__)
  __attribute__((noinline)) void add_rest(const double *x, i64 i, i64 count, __m128d &s01,
                                          double &s2) const {
    const I *rest = rest_of(i);
    for (i64 e = 0; e < count - kSlots; ++e) {
      const double *y = x + 3 * i64(rest[e]);
      s01 = _mm_add_pd(s01, _mm_loadu_pd(y));
      s2 += y[2];
    }
  }
#else
  __attribute__((noinline)) void add_rest(const double *x, i64 i, i64 count, double &s0,
                                          double &s1, double &s2) const {
    const I *rest = rest_of(i);
    for (i64 e = 0; e < count - kSlots; ++e) {
      const double *y = x + 3 * i64(rest[e]);
      s0 += y[0];
      s1 += y[1];
      s2 += y[2];
    }
  }
#endif

  void constrain(unsigned held, double *lap) const {
    if (aligned_) {  // index axes are world axes (scaled): zero those components
      for (int a = 0; a < 3; ++a) {
        if (held >> a & 1) lap[a] = 0.0;
      }
      return;
    }
    // the index step, without the held axes, back in world axes (an oblique
    // projection that keeps those index coordinates)
    double index[3];
    for (int a = 0; a < 3; ++a) {
      index[a] = (held >> a & 1) ? 0.0
                                 : lap[0] * inverse_[3 * a] + lap[1] * inverse_[3 * a + 1] +
                                       lap[2] * inverse_[3 * a + 2];
    }
    for (int a = 0; a < 3; ++a) {
      lap[a] = index[0] * affine_[3 * a] + index[1] * affine_[3 * a + 1] +
               index[2] * affine_[3 * a + 2];
    }
  }

  // One step of the Chebyshev recurrence at vertex i: x2 = 2 x1 - L x1 - x0,
  // written over x0 (only vertex i reads x0[i]), and out += c x2.
  __attribute__((always_inline)) inline void chebyshev_at(i64 i, const double *x1, double *x0,
                                                        double c, double *out) const {
    double lap[3];
    at(x1, i, lap);
    for (int k = 0; k < 3; ++k) {
      const i64 p = 3 * i + k;
      const double x2 = 2.0 * x1[p] - lap[k] - x0[p];
      x0[p] = x2;
      out[p] += c * x2;
    }
  }
};

template <class I>
void SmoothingStencil<I>::build(const I *tv, i64 nt, const double *xyz, const GridPlanes &grid,
                                i64 hold_below, int threads) {
  const i64 nv = n_;
  iso::Buffer<I> first(nv + 1), corner(0);  // v's corners: corner[first[v] .. first[v + 1]]
  iso::corners_by_vertex(tv, nt, nv, threads, first, corner);

  // 1. around each vertex: its code (but for small components), its row and,
  //    by a shared union-find, the components
  code.assign(size_t(nv), 0);
  iso::Buffer<I> parent(nv);
  for (i64 v = 0; v < nv; ++v) parent[v] = static_cast<I>(v);
  const iso::SharedForest<I> forest{parent.data()};
  std::vector<Scratch<I>> scratch(static_cast<size_t>(std::max(threads, 1)));
  iso::parallel_for(nv, threads, 4096, [&](int worker, i64 v0, i64 v1) {
    Scratch<I> &s = scratch[worker];
    alignas(16) I nx[kFast], pv[kFast + 4];
    // v's row: the table's slots, then its own compressed row
    auto keep = [&](i64 v, const I *row, i64 count) {
      count_[v] = static_cast<I>(count);
      I *slot = slots_.data() + kSlots * v;
      for (int t = 0; t < kSlots; ++t) slot[t] = t < count ? row[t] : static_cast<I>(nv);
      for (i64 e = 0; e < count; ++e) s.reach = std::max(s.reach, std::abs(i64(row[e]) - v));
      if (count > kSlots) {
        s.long_rows.emplace_back(v, i64(s.rest.size()));
        s.rest.insert(s.rest.end(), row + kSlots, row + count);
      }
    };
    for (i64 v = v0; v < v1; ++v) {
      u8 vertex = planes_of(grid, xyz + 3 * v);
      const I *cs = corner.data() + first[v];
      const i64 k = first[v + 1] - first[v];
      if (k == 0) {
        code[v] = vertex | kFixed;
        keep(v, nullptr, 0);
        continue;
      }
      vertex |= kUsed;
      if ((vertex & kPlanes) == kPlanes) vertex |= kFixed;
      for (int a = 0; a < 3; ++a) {
        s.lo[a] = std::min(s.lo[a], xyz[3 * v + a]);
        s.hi[a] = std::max(s.hi[a], xyz[3 * v + a]);
      }
      I top = static_cast<I>(v);
      if (k <= kFast) {
        corner_ends(tv, cs, k, nx, pv);
        for (int p = 0; p < 4; ++p) pv[k + p] = -1;
        if (const int fans = closed_fans(nx, pv, int(k))) {
          for (i64 q = 0; q < k; ++q) {
            if (nx[q] > v) top = forest.join(top, nx[q]);
          }
          code[v] = fans > 1 ? (vertex | kFixed) : vertex;
          keep(v, nx, k);
          continue;
        }
      }
      s.nx.resize(size_t(k));
      s.pv.resize(size_t(k));
      corner_ends(tv, cs, k, s.nx.data(), s.pv.data());
      sort_ring(s.nx.data(), s.pv.data(), k, s.ring);
      auto &up = s.up;  // v's corners joined into fans
      up.resize(size_t(k));
      for (i64 q = 0; q < k; ++q) up[q] = static_cast<I>(q);
      auto root = [&up](I x) {
        while (up[x] != x) x = up[x] = up[up[x]];
        return x;
      };
      auto &row = s.row;
      row.clear();
      i64 fans = k, boundary = 0;
      I ends[2] = {0, 0};  // the first two boundary neighbours
      bool many = false;
      const auto &ring = s.ring;
      for (size_t a = 0, b; a < ring.size(); a = b) {
        const I w = ring[a].other;
        for (b = a + 1; b < ring.size() && ring[b].other == w; ++b) {
        }
        const i64 m = i64(b - a);
        row.push_back(w);
        if (m == 1) {
          if (boundary < 2) ends[boundary] = w;
          ++boundary;
        } else if (m == 2) {
          const I x = root(ring[a].corner), y = root(ring[a + 1].corner);
          if (x != y) {
            up[std::max(x, y)] = std::min(x, y);
            --fans;
          }
        } else {
          many = true;
        }
        if (w > v) top = forest.join(top, w);
      }
      if (many || fans > 1 || (boundary != 0 && boundary != 2)) {
        vertex |= kFixed;
      } else if (boundary == 2) {  // averages its two boundary neighbours only
        vertex |= kCurve;
        row.assign(ends, ends + 2);
      }
      code[v] = vertex;
      keep(v, row.data(), i64(row.size()));
    }
  });
  std::free(corner.release());

  // the long rows, by vertex; the bounding box; the reach
  std::vector<std::pair<i64, std::pair<int, i64>>> long_rows;  // vertex, (worker, start)
  for (int w = 0; w < int(scratch.size()); ++w) {
    for (const auto &[v, start] : scratch[w].long_rows) long_rows.push_back({v, {w, start}});
  }
  std::sort(long_rows.begin(), long_rows.end());
  for (const auto &[v, from] : long_rows) {
    const I *row = scratch[from.first].rest.data() + from.second;
    long_vertices_.push_back(v);
    long_starts_.push_back(i64(long_rest_.size()));
    long_rest_.insert(long_rest_.end(), row, row + (i64(count_[v]) - kSlots));
  }
  for (int a = 0; a < 3; ++a) {
    lo[a] = kHuge;
    hi[a] = -kHuge;
    for (const auto &w : scratch) {
      lo[a] = std::min(lo[a], w.lo[a]);
      hi[a] = std::max(hi[a], w.hi[a]);
    }
  }
  for (const auto &w : scratch) reach = std::max(reach, w.reach);

  // 2. components of fewer used vertices than hold_below are held; their
  //    roots are their smallest vertices, so one pass in increasing order
  //    resolves every vertex through an already resolved root
  std::vector<i64> size(size_t(nv), 0);
  for (i64 v = 0; v < nv; ++v) {
    parent[v] = parent[parent[v]];
    if (code[v] & kUsed) ++size[parent[v]];
  }
  for (i64 v = 0; v < nv; ++v) {
    if (parent[v] == v && size[v] > 0 && size[v] < hold_below) ++small_components;
  }
  // 3. fixed vertices have no neighbours
  for (i64 v = 0; v < nv; ++v) {
    u8 &vertex = code[v];
    if ((vertex & kUsed) && size[parent[v]] < hold_below) {
      vertex = (vertex | kFixed | kSmall) & ~kCurve;
    }
    if (vertex & kFixed) count_[v] = 0;
  }
}

template <class I>
using Indices = nb::ndarray<const I, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Positions =
    nb::ndarray<double, nb::ndim<2>, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;

template <class I>
void check_positions(const SmoothingStencil<I> &s, const Positions &x, const char *what) {
  if (i64(x.shape(0)) != s.vertices()) {
    throw std::invalid_argument(std::string(what) + ": positions (V, 3) for the stencil's V");
  }
}

inline void check_frame(const Doubles &center, double length) {
  if (center.size() != 3 || !(length > 0.0)) {
    throw std::invalid_argument("smoothing: center (3,) and a length > 0");
  }
}

template <class I>
void bind_index_type(nb::module_ &m, const char *suffix) {
  using S = SmoothingStencil<I>;
  const std::string name = std::string("SmoothingStencil_") + suffix;
  nb::class_<S>(m, name.c_str(),
                "The smoothing stencil of a triangle mesh and the filters that run on it "
                "(src/smooth.cpp).")
      .def_prop_ro("code", [](const S &s) { return give(std::vector<u8>(s.code)); },
                   "(V,) uint8: grid planes (bits 0-2), used, fixed, curve, small.")
      .def_ro("small_components", &S::small_components)
      .def_ro("reach", &S::reach)
      .def_prop_ro("bounds",
                   [](const S &s) {
                     return nb::make_tuple(nb::make_tuple(s.lo[0], s.lo[1], s.lo[2]),
                                           nb::make_tuple(s.hi[0], s.hi[1], s.hi[2]));
                   },
                   "The used vertices' bounding box (lo, hi).")
      .def(
          "rows",
          [](const S &s) {
            std::vector<i64> offsets;
            std::vector<I> neighbours;
            s.rows(offsets, neighbours);
            return nb::make_tuple(give(std::move(offsets)), give(std::move(neighbours)));
          },
          "The rows as (offsets (V + 1,), neighbours (E,)).")
      .def(
          "sinc",
          [](const S &s, Doubles coefficients, Positions x, Doubles center, double length,
             int threads, Positions out) {
            check_positions(s, x, "sinc");
            check_positions(s, out, "sinc");
            check_frame(center, length);
            if (coefficients.ndim() != 1 || coefficients.shape(0) < 2) {
              throw std::invalid_argument("sinc: coefficients (N + 1,), N >= 1");
            }
            nb::gil_scoped_release unlocked;
            s.sinc(coefficients.data(), i64(coefficients.shape(0)), x.data(), center.data(),
                   length, threads, out.data());
          },
          "coefficients"_a, "x"_a, "center"_a, "length"_a, "threads"_a, "out"_a.noconvert(),
          "out = sum_i c_i T_i(I - L / 2) x on (x - center) / length, scaled back.")
      .def(
          "steps",
          [](const S &s, Doubles factors, Positions x, Doubles center, double length,
             int threads) {
            check_positions(s, x, "steps");
            check_frame(center, length);
            if (factors.ndim() != 1) throw std::invalid_argument("steps: factors (S,)");
            nb::gil_scoped_release unlocked;
            s.steps(factors.data(), i64(factors.shape(0)), x.data(), center.data(), length,
                    threads);
          },
          "factors"_a, "x"_a.noconvert(), "center"_a, "length"_a, "threads"_a,
          "x -= f L x for each factor f in turn, on (x - center) / length, in place.");
  m.def(
      (std::string("smoothing_stencil_") + suffix).c_str(),
      [](Indices<I> triangles, Doubles vertices, Doubles grid, Doubles affine, bool aligned,
         i64 hold_below, int threads) {
        const i64 nv = vertices.ndim() == 2 && vertices.shape(1) == 3 ? i64(vertices.shape(0))
                                                                        : -1;
        if (nv < 0 || triangles.shape(0) % 3 != 0 || (grid.size() != 0 && grid.size() != 16) ||
            affine.size() != 9) {
          throw std::invalid_argument(
              "smoothing_stencil: triangles (3 F,), vertices (V, 3), grid () or (16,), "
              "affine (3, 3)");
        }
        GridPlanes planes;
        if (grid.size() == 16) {  // origin, inverse affine, shape - 1, tolerance
          const double *g = grid.data();
          planes.present = true;
          std::copy(g, g + 3, planes.origin);
          std::copy(g + 3, g + 12, planes.inverse);
          std::copy(g + 12, g + 15, planes.top);
          planes.tolerance = g[15];
        } else {
          for (int a = 0; a < 9; ++a) planes.inverse[a] = a % 4 == 0 ? 1.0 : 0.0;
        }
        nb::gil_scoped_release unlocked;
        return new S(triangles.data(), i64(triangles.shape(0)) / 3, vertices.data(), nv, planes,
                     affine.data(), aligned, hold_below, threads);
      },
      "triangles"_a, "vertices"_a, "grid"_a, "affine"_a, "aligned"_a, "hold_below"_a,
      "threads"_a, nb::rv_policy::take_ownership,
      "The smoothing stencil of triangles (3 F,) in 0..V-1: grid () or its planes (16,): "
      "origin, inverse affine, shape - 1, tolerance.");
}

}  // namespace

void bind_smooth(nb::module_ &m) {
  bind_index_type<std::int32_t>(m, "int32");
  bind_index_type<i64>(m, "int64");
}
