// The cap on the grid's faces (isoconvert/post/cap.py, which describes the
// construction): each face cell's positive part triangulated from its case's
// table, its corners the face's positive samples and the surface's vertices on
// the cell's edges, found by grid edge id. The tables and the face images come
// from Python; this does the per-cell work numpy did with a nonzero, a gather
// and a sort per case (and an argsort of every edge id of the surface): 0.11 s
// on a 256^3 gyroid, five times its extraction.
//
// Output order is numpy's: faces in the given order; within a face, cells by
// case 1..15 (under the decider, the ambiguous cells it joins first), each
// case's cells in row-major (p, q) order; the samples the cap uses numbered
// after the surface's vertices in increasing linear index.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

// A face: its axis, p and q (the other two axes, increasing), its sample
// plane along the axis, its image's size and whether its triangles turn.
struct Face {
  int axis, p, q;
  i64 side, np, nq;
  bool reverse;
  const double *values;  // (np, nq)
};

// The triangles of a cell case: slots 0-3 corners, 4-7 the vertices on edges 0-3.
struct Table {
  int count;
  int slots[4][3];
};

// Corners of a face cell in cyclic order, the lower end of each edge, and
// which edges run along q (cap.py's _CORNERS, _EDGE_LOW, _EDGE_AXIS).
constexpr int kCorner[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
constexpr int kEdgeLow[4][2] = {{0, 0}, {1, 0}, {0, 1}, {0, 0}};
constexpr bool kAlongQ[4] = {false, true, false, true};

// Open addressing from the grid edge ids of the surface's vertices on the
// grid's faces to the first such vertex.
class EdgeMap {
 public:
  EdgeMap(const i64 *ids, i64 n, const i64 shape[3], int threads) {
    const i64 grain = 1 << 15;
    std::vector<std::vector<i64>> found(static_cast<size_t>(iso::chunk_count(n, grain)));
    const Divider by_x(shape[0]), by_y(shape[1]);
    iso::parallel_for(n, threads, grain, [&](int, i64 begin, i64 end) {
      auto &mine = found[begin / grain];
      for (i64 v = begin; v < end; ++v) {
        if (ids[v] >= 0 && on_a_face(ids[v], shape, by_x, by_y)) mine.push_back(v);
      }
    });
    size_t total = 0;
    for (const auto &f : found) total += f.size();
    size_t size = 16;
    while (size < 2 * total) size *= 2;
    mask_ = size - 1;
    keys_.assign(size, -1);
    values_.assign(size, -1);
    for (const auto &f : found) {  // in vertex order: the first vertex of an id is kept
      for (i64 v : f) {
        size_t h = slot(ids[v]);
        while (keys_[h] >= 0 && keys_[h] != ids[v]) h = (h + 1) & mask_;
        if (keys_[h] < 0) {
          keys_[h] = ids[v];
          values_[h] = v;
        }
      }
    }
  }
  // The vertex on edge id e, or -1.
  i64 find(i64 e) const {
    for (size_t h = slot(e);; h = (h + 1) & mask_) {
      if (keys_[h] == e) return values_[h];
      if (keys_[h] < 0) return -1;
    }
  }

 private:
  // x / d and x % d for 0 <= x < 2^52 by a double division, corrected: a
  // 64-bit integer division per vertex was most of the kernel's time.
  struct Divider {
    i64 d;
    double inverse;
    explicit Divider(i64 d_) : d(d_), inverse(1.0 / double(d_)) {}
    i64 quotient(i64 x) const {
      i64 q = i64(double(x) * inverse);
      while (q * d > x) --q;
      while ((q + 1) * d <= x) ++q;
      return q;
    }
  };

  std::vector<i64> keys_, values_;
  size_t mask_ = 0;
  size_t slot(i64 e) const {
    std::uint64_t x = std::uint64_t(e) * 0x9E3779B97F4A7C15ULL;
    return size_t(x >> 20) & mask_;
  }
  // Whether the edge (3 low + axis) lies in a face of the grid.
  static bool on_a_face(i64 e, const i64 shape[3], const Divider &by_x, const Divider &by_y) {
    const i64 low = e / 3, axis = e - 3 * low;
    const i64 yz = by_x.quotient(low), z = by_y.quotient(yz);
    const i64 c[3] = {low - yz * shape[0], yz - z * shape[1], z};
    for (int b = 0; b < 3; ++b) {
      if (b != axis && (c[b] == 0 || c[b] == shape[b] - 1)) return true;
    }
    return false;
  }
};

struct Cap {
  std::vector<i64> triangles;  // (T, 3) vertex indices
  std::vector<i64> samples;    // the samples used, increasing linear index
  bool missing = false;        // a crossing the surface does not have
};

void grid_cap(const std::vector<Face> &faces, const i64 shape[3], double level,
              const Table tables[16], const Table joined[2], bool decided, const i64 *edge_ids,
              i64 n_vertices, int threads, Cap &out) {
  const i64 stride[3] = {1, shape[0], shape[0] * shape[1]};
  // Each cell's group: its case, or under the decider 16 + (case == 10) for an
  // ambiguous cell it joins; groups are emitted in the order 1, 2, 3, 4, 16, 5,
  // ..., 9, 17, 10, ..., 15.
  constexpr int kGroups = 18;
  constexpr int kOrder[15 + 2] = {1, 2, 3, 4, 16, 5, 6, 7, 8, 9, 17, 10, 11, 12, 13, 14, 15};
  auto table_of = [&](int g) -> const Table & { return g < 16 ? tables[g] : joined[g - 16]; };
  const i64 nf = i64(faces.size());
  std::vector<std::vector<std::uint8_t>> groups(static_cast<size_t>(nf));
  std::vector<std::array<i64, kGroups + 1>> counts(static_cast<size_t>(nf));
  // 1. each face's cells' groups, and how many of each
  iso::parallel_for(nf, threads, 1, [&](int, i64 f0, i64 f1) {
    for (i64 fi = f0; fi < f1; ++fi) {
      const Face &f = faces[fi];
      auto &count = counts[fi];
      count.fill(0);
      const i64 cp = f.np - 1, cq = f.nq - 1;
      if (cp <= 0 || cq <= 0) continue;
      const double *v = f.values;
      auto &group = groups[fi];
      group.resize(size_t(cp * cq));
      for (i64 p = 0; p < cp; ++p) {
        const double *r0 = v + p * f.nq, *r1 = r0 + f.nq;
        for (i64 q = 0; q < cq; ++q) {
          int c = int(r0[q] >= level) | int(r1[q] >= level) << 1 | int(r1[q + 1] >= level) << 2 |
                  int(r0[q + 1] >= level) << 3;
          // corners (00, 10, 01, 11) in (p, q), as the cubes read a face
          if (decided && (c == 5 || c == 10) &&
              iso::asymptotic_joins_positive(r0[q], r1[q], r0[q + 1], r1[q + 1], level)) {
            c = 16 + (c == 10);
          }
          group[p * cq + q] = std::uint8_t(c);
          ++count[c];
        }
      }
    }
  });
  // 2. where each face's keys go
  std::vector<i64> first(static_cast<size_t>(nf + 1), 0);
  for (i64 fi = 0; fi < nf; ++fi) {
    i64 n = 0;
    for (int g = 1; g < kGroups; ++g) n += 3 * counts[fi][g] * table_of(g).count;
    first[fi + 1] = first[fi] + n;
  }
  std::vector<i64> keys(static_cast<size_t>(first[nf]));  // edge ids, or -1 - sample
  // 3. the keys: cells by group, row-major within
  iso::parallel_for(nf, threads, 1, [&](int, i64 f0, i64 f1) {
    for (i64 fi = f0; fi < f1; ++fi) {
      const Face &f = faces[fi];
      const i64 cp = f.np - 1, cq = f.nq - 1;
      if (cp <= 0 || cq <= 0) continue;
      const auto &count = counts[fi];
      const auto &group = groups[fi];
      i64 at[kGroups];  // where each group's keys start
      i64 k = first[fi];
      for (int g : kOrder) {
        at[g] = k;
        k += 3 * count[g] * table_of(g).count;
      }
      for (i64 cell = 0; cell < cp * cq; ++cell) {
        const int g = group[cell];
        const Table &table = table_of(g);
        if (table.count == 0) continue;
        const i64 p = cell / cq, q = cell - p * cq;
        const i64 base = f.side * stride[f.axis] + p * stride[f.p] + q * stride[f.q];
        i64 slot[8];
        for (int c = 0; c < 4; ++c) {
          slot[c] = -1 - (base + kCorner[c][0] * stride[f.p] + kCorner[c][1] * stride[f.q]);
          const i64 low = base + kEdgeLow[c][0] * stride[f.p] + kEdgeLow[c][1] * stride[f.q];
          slot[4 + c] = 3 * low + (kAlongQ[c] ? f.q : f.p);
        }
        i64 *to = keys.data() + at[g];
        for (int t = 0; t < table.count; ++t) {
          const int *s = table.slots[t];
          to[3 * t] = slot[s[f.reverse ? 2 : 0]];
          to[3 * t + 1] = slot[s[1]];
          to[3 * t + 2] = slot[s[f.reverse ? 0 : 2]];
        }
        at[g] += 3 * table.count;
      }
    }
  });
  if (keys.empty()) return;

  // the samples used, numbered by increasing linear index: a bit per sample
  // of the grid, or (for a grid far larger than the cap) a sorted list
  const i64 n_samples = shape[0] * shape[1] * shape[2];
  const bool dense = n_samples / 64 <= 8 * i64(keys.size());
  std::vector<std::uint64_t> used(dense ? size_t((n_samples + 63) / 64) : 0, 0);
  std::vector<i64> rank(used.size() + 1, 0);
  if (dense) {
    for (i64 k : keys) {
      if (k < 0) used[(-1 - k) >> 6] |= std::uint64_t(1) << ((-1 - k) & 63);
    }
    for (size_t w = 0; w < used.size(); ++w) {
      rank[w + 1] = rank[w] + iso::popcount(used[w]);
      for (std::uint64_t bits = used[w]; bits; bits &= bits - 1) {
        out.samples.push_back(i64(w) * 64 + iso::ctz(bits));
      }
    }
  } else {
    for (i64 k : keys) {
      if (k < 0) out.samples.push_back(-1 - k);
    }
    std::sort(out.samples.begin(), out.samples.end());
    out.samples.erase(std::unique(out.samples.begin(), out.samples.end()), out.samples.end());
  }
  auto number = [&](i64 n) {
    if (!dense) {
      return i64(std::lower_bound(out.samples.begin(), out.samples.end(), n) -
                 out.samples.begin());
    }
    const i64 w = n >> 6;
    return rank[w] + iso::popcount(used[w] & ((std::uint64_t(1) << (n & 63)) - 1));
  };
  const EdgeMap edges(edge_ids, n_vertices, shape, threads);
  out.triangles.resize(keys.size());
  std::atomic<bool> missing{false};
  iso::parallel_for(i64(keys.size()), threads, 1 << 16, [&](int, i64 begin, i64 end) {
    for (i64 t = begin; t < end; ++t) {
      const i64 k = keys[t];
      if (k >= 0) {
        const i64 v = edges.find(k);
        if (v < 0) missing = true;
        out.triangles[t] = v;
      } else {
        out.triangles[t] = n_vertices + number(-1 - k);
      }
    }
  });
  out.missing = missing;
}

}  // namespace

void bind_cap(nb::module_ &m) {
  m.def(
      "grid_cap",
      [](Doubles values, Int64s faces, Int64s shape, double level, Int64s tables,
         Int64s joined, bool decided, Int64s edge_ids, int threads) {
        if (shape.size() != 3 || faces.ndim() != 2 || faces.shape(1) != 6 ||
            tables.size() != 16 * 13 || joined.size() != 2 * 13) {
          throw std::invalid_argument(
              "grid_cap: faces (F, 6), shape (3,), tables (16, 13), joined (2, 13)");
        }
        const i64 s[3] = {shape.data()[0], shape.data()[1], shape.data()[2]};
        if (s[0] < 1 || s[1] < 1 || s[2] < 1) throw std::invalid_argument("grid_cap: bad shape");
        // face rows: axis, side, rows along p, along q, reverse, first value
        std::vector<Face> list;
        const i64 *fd = faces.data();
        for (size_t r = 0; r < faces.shape(0); ++r) {
          const i64 *d = fd + 6 * r;
          Face f;
          f.axis = int(d[0]);
          if (f.axis < 0 || f.axis > 2) throw std::invalid_argument("grid_cap: bad axis");
          f.p = f.axis == 0 ? 1 : 0;
          f.q = f.axis == 2 ? 1 : 2;
          f.side = d[1];
          f.np = d[2];
          f.nq = d[3];
          f.reverse = d[4] != 0;
          if (f.side < 0 || f.side >= s[f.axis] || f.np != s[f.p] || f.nq != s[f.q] || d[5] < 0 ||
              d[5] + f.np * f.nq > i64(values.size())) {
            throw std::invalid_argument("grid_cap: a face does not fit the grid or the values");
          }
          f.values = values.data() + d[5];
          list.push_back(f);
        }
        // table rows: the number of triangles, then 4 x 3 slots
        auto read = [](const i64 *row, Table &t) {
          t.count = int(row[0]);
          if (t.count < 0 || t.count > 4) throw std::invalid_argument("grid_cap: bad table");
          for (int k = 0; k < 12; ++k) {
            const i64 slot = row[1 + k];
            if (k < 3 * t.count && (slot < 0 || slot > 7)) {
              throw std::invalid_argument("grid_cap: bad table slot");
            }
            t.slots[k / 3][k % 3] = int(slot);
          }
        };
        Table t16[16], t2[2];
        for (int c = 0; c < 16; ++c) read(tables.data() + 13 * c, t16[c]);
        for (int c = 0; c < 2; ++c) read(joined.data() + 13 * c, t2[c]);
        Cap cap;
        {
          nb::gil_scoped_release unlocked;
          grid_cap(list, s, level, t16, t2, decided, edge_ids.data(), i64(edge_ids.size()),
                   threads, cap);
        }
        return nb::make_tuple(give(std::move(cap.triangles), 3), give(std::move(cap.samples)),
                              cap.missing);
      },
      "values"_a, "faces"_a, "shape"_a, "level"_a, "tables"_a, "joined"_a, "decided"_a,
      "edge_ids"_a, "threads"_a,
      "The cap's triangles (T, 3) as vertex indices (the samples after the surface's "
      "vertices), the samples used (ascending) and whether a crossing was missing.");
}
