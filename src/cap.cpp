// The cap on the grid's faces (isoconvert/post/cap.py, which describes the
// construction): each face cell's positive part triangulated from its case's
// table, its corners the face's positive samples and the surface's vertices on
// the cell's edges.
//
// Two calls, so that Python allocates the closed mesh's arrays once, at their
// final size (numpy backs large arrays with huge pages, whose first write is
// several times cheaper than in malloc's ordinary ones), and the surface is
// copied into them once:
//   cap_count  each face cell's group (its case; under the decider, whether it
//              joins an ambiguous cell's positive corners), how many of each,
//              and how many positive samples each boundary row holds;
//   cap_fill   the surface copied in, then the cap's triangles, vertices and
//              ids, each written once at a place those counts fix.
// Scratch memory is kept small, since on this kind of VM a first write to
// fresh pages costs far more than the work done on them: the surface's
// vertices on a face are found through a slot per bipolar edge of the face
// (numbered by a rank in a bit set of its edges, filled from the decoded edge
// ids: no hash, no sort), and a sample's vertex number is the count of
// positive boundary samples before it (rows of the boundary counted first,
// then a rank within the row: no bitmap of the grid, no table per sample).
//
// Output order: faces x0, x1, y0, y1, z0, z1; within a face, cells by case
// 1..15 (under the decider, the ambiguous cells it joins first), each case's
// cells in row-major (p, q) order; the samples the cap uses numbered after the
// surface's vertices in increasing linear index (x fastest). Every place is
// fixed by prefix sums before the parallel passes, so the output does not
// depend on the number of threads.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <vector>
#include <cstdlib>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

// The triangles of a cell case: slots 0-3 corners, 4-7 the vertices on edges 0-3.
struct Table {
  int count;
  int slots[4][3];
};

// A cell's group: its case, or under the decider 16 + (case == 10) for an
// ambiguous cell whose positive corners it joins. A face's groups are emitted
// in this order.
constexpr int kGroups = 18;
constexpr int kOrder[17] = {1, 2, 3, 4, 16, 5, 6, 7, 8, 9, 17, 10, 11, 12, 13, 14, 15};

// A face cell's slots (cap.py's numbering): corners 0-3 at (p, q) + (0, 0),
// (1, 0), (1, 1), (0, 1); 4 + c the crossing of the edge from corner c to
// c + 1: along p from (0, 0), along q from (1, 0), along p from (0, 1), along
// q from (0, 0). A sample's vertex number is the count of positive boundary
// samples before it in linear order (after the surface's vertices).

// Work per task: enough to pay for handing it out, little enough that two
// threads share one face (cells) or one plane of the boundary (samples).
constexpr i64 kTaskCells = 1 << 14;
constexpr i64 kTaskSamples = 1 << 13;
constexpr i64 kGrain = 1 << 15;  // vertices decoded, or rows copied, per task

// One face of the grid, f = 2 * axis + (1 on the far side). p and q are the
// other two axes in increasing order; its image is (np, nq), q fastest.
struct Face {
  int axis = 0, p = 0, q = 0;
  i64 side = 0, np = 0, nq = 0;
  bool reverse = false;
  const double *values = nullptr;
  i64 first_cell = 0;  // its cells' place in the groups, (np - 1) (nq - 1) of them
  bool has_cells() const { return np > 1 && nq > 1; }
};

struct Grid {
  i64 X, Y, Z;
  std::array<Face, 6> faces;
  i64 n_values = 0, n_cells = 0;
  struct CellTask {  // rows [p0, p1) of a face's cells
    int face;
    i64 p0, p1;
  };
  struct RowTask {  // boundary rows [r0, r1), r = j + Y k
    i64 r0, r1;
  };
  std::vector<CellTask> cell_tasks;
  std::vector<RowTask> row_tasks;

  Grid(const i64 shape[3], const double *values, const i64 *reverse)
      : X(shape[0]), Y(shape[1]), Z(shape[2]) {
    for (int f = 0; f < 6; ++f) {
      Face &F = faces[f];
      F.axis = f / 2;
      F.p = F.axis == 0 ? 1 : 0;
      F.q = F.axis == 2 ? 1 : 2;
      F.side = f % 2 ? shape[F.axis] - 1 : 0;
      F.np = shape[F.p];
      F.nq = shape[F.q];
      F.reverse = reverse[f] != 0;
      F.values = values + n_values;
      F.first_cell = n_cells;
      n_values += F.np * F.nq;
      if (!F.has_cells()) continue;
      n_cells += (F.np - 1) * (F.nq - 1);
      const i64 rows = std::max<i64>(1, kTaskCells / (F.nq - 1));
      for (i64 p = 0; p < F.np - 1; p += rows) {
        cell_tasks.push_back({f, p, std::min(F.np - 1, p + rows)});
      }
    }
    // a plane of z faces in runs of rows, any other plane (two samples a row
    // but its first and last) whole
    const i64 rows = std::max<i64>(1, kTaskSamples / X);
    for (i64 k = 0; k < Z; ++k) {
      if (k == 0 || k == Z - 1) {
        for (i64 j = 0; j < Y; j += rows) {
          row_tasks.push_back({j + Y * k, std::min(Y, j + rows) + Y * k});
        }
      } else {
        row_tasks.push_back({Y * k, Y * (k + 1)});
      }
    }
  }

  // Whether row r = j + Y k of the boundary holds all its samples (it lies in
  // a y or z face) or only its first and last.
  bool full_row(i64 j, i64 k) const { return k == 0 || k == Z - 1 || j == 0 || j == Y - 1; }

  // A full row's samples: a face image that holds them all and its stride along x.
  const double *row_values(i64 j, i64 k, i64 &stride) const {
    if (k == 0 || k == Z - 1) {
      stride = Y;
      return faces[k == 0 ? 4 : 5].values + j;
    }
    stride = Z;
    return faces[j == 0 ? 2 : 3].values + k;
  }
};

// x / d for 0 <= x < 2^52 by a double division, corrected (the estimate is off
// by at most one): a 64-bit integer division per vertex was most of the time
// of decoding the surface's ids.
struct Divider {
  i64 d;
  double inverse;
  explicit Divider(i64 d_) : d(d_), inverse(1.0 / double(d_)) {}
  i64 quotient(i64 x) const {
    i64 q = i64(double(x) * inverse);
    q -= q * d > x;
    q += (q + 1) * d <= x;
    return q;
  }
};

// 1. Each face cell's group, counted per cell task; the positive samples of
// each boundary row.
void count(const Grid &g, double level, bool decided, std::uint8_t *groups, i64 *counts,
           i64 *row_counts, int threads) {
  const i64 nc = i64(g.cell_tasks.size()), nr = i64(g.row_tasks.size());
  iso::parallel_for(nc + nr, threads, 1, [&](int, i64 t0, i64 t1) {
    for (i64 t = t0; t < t1; ++t) {
      if (t >= nc) {
        const auto &task = g.row_tasks[t - nc];
        for (i64 r = task.r0; r < task.r1; ++r) {
          const i64 j = r % g.Y, k = r / g.Y;
          i64 positive = 0;
          if (g.full_row(j, k)) {
            i64 stride;
            const double *v = g.row_values(j, k, stride);
            for (i64 i = 0; i < g.X; ++i) positive += v[i * stride] >= level;
          } else {
            positive = (g.faces[0].values[j * g.Z + k] >= level) +
                       (g.X > 1 && g.faces[1].values[j * g.Z + k] >= level);
          }
          row_counts[r] = positive;
        }
        continue;
      }
      const auto &task = g.cell_tasks[t];
      const Face &f = g.faces[task.face];
      i64 *count = counts + kGroups * t;
      std::fill(count, count + kGroups, i64(0));
      const i64 cq = f.nq - 1;
      for (i64 p = task.p0; p < task.p1; ++p) {
        const double *r0 = f.values + p * f.nq, *r1 = r0 + f.nq;
        std::uint8_t *group = groups + f.first_cell + p * cq;
        for (i64 q = 0; q < cq; ++q) {
          int c = int(r0[q] >= level) | int(r1[q] >= level) << 1 | int(r1[q + 1] >= level) << 2 |
                  int(r0[q + 1] >= level) << 3;
          // corners (00, 10, 01, 11) in (p, q), as the cubes read a face
          if (decided && (c == 5 || c == 10) &&
              iso::asymptotic_joins_positive(r0[q], r1[q], r0[q + 1], r1[q + 1], level)) {
            c = 16 + (c == 10);
          }
          group[q] = std::uint8_t(c);
          ++count[c];
        }
      }
    }
  });
}

struct Surface {
  const double *vertices;
  const i64 *cells, *ids;
  i64 n_vertices, n_cells;
};

struct Closed {
  double *vertices;  // (V + S, 3)
  i64 *cells;        // (C + T, 3)
  i64 *ids;          // (V + S,)
  double scale[3], shift[3];  // a sample's position: index * scale + shift, per axis
};

// Bits of a face: its positive samples by column (q), x order for the rows of
// the boundary that lie in y and z faces, and its bipolar edges, each with
// counts before every word (so the rank of a set bit is a look-up and a popcount).
struct Bits {
  std::vector<std::uint64_t> bits;
  std::vector<i64> before;  // set bits in the words before
  void resize(i64 n) {
    bits.assign(size_t((n + 63) / 64), 0);
    before.resize(bits.size() + 1);
  }
  void set_to(i64 b, bool on) { bits[size_t(b >> 6)] |= std::uint64_t(on) << (b & 63); }
  bool test(i64 b) const { return bits[size_t(b >> 6)] >> (b & 63) & 1; }
  void count() {
    before[0] = 0;
    for (size_t w = 0; w < bits.size(); ++w) before[w + 1] = before[w] + iso::popcount(bits[w]);
  }
  i64 rank(i64 b) const {  // set bits before b
    return before[size_t(b >> 6)] +
           iso::popcount(bits[size_t(b >> 6)] & ((std::uint64_t(1) << (b & 63)) - 1));
  }
  i64 total() const { return before.back(); }
};

struct FaceBits {
  i64 words = 0;  // per column
  Bits columns;   // positive samples, column q's bit p at q * 64 * words + p (y and z faces)
  // bipolar edges: along p from (p, q), bit p nq + q; along q from (p, q), bit p (nq - 1) + q
  Bits p_edges, q_edges;
  i64 first_slot = 0;  // its bipolar edges' place among all faces' (along p, then along q)
};

// 2. The closed mesh: the surface copied in, then the cap. Returns whether a
// crossing of the faces has no vertex of the surface.
bool fill(const Grid &g, double level, const Table tables[kGroups], const std::uint8_t *groups,
          const i64 *counts, const i64 *row_counts, const Surface &s, const Closed &out,
          int threads) {
  const i64 X = g.X, Y = g.Y, Z = g.Z, V = s.n_vertices;
  const i64 nc = i64(g.cell_tasks.size()), nr = i64(g.row_tasks.size());
  // where each cell task's triangles of each group go (after the surface's)
  std::vector<std::array<i64, kGroups>> at(static_cast<size_t>(nc));
  for (i64 t = 0, k = s.n_cells; t < nc;) {
    i64 end = t;  // the tasks of one face
    while (end < nc && g.cell_tasks[end].face == g.cell_tasks[t].face) ++end;
    for (int grp : kOrder) {
      for (i64 u = t; u < end; ++u) {
        at[u][grp] = k;
        k += counts[kGroups * u + grp] * tables[grp].count;
      }
    }
    t = end;
  }
  // where each boundary row's samples go (after the surface's vertices)
  std::vector<i64> row_start(static_cast<size_t>(Y * Z));
  for (i64 r = 0, k = V; r < Y * Z; ++r) {
    row_start[r] = k;
    k += row_counts[r];
  }

  // a) each face's bits; the surface's cells copied alongside
  std::array<FaceBits, 6> fb;
  const i64 n_cells_copy = iso::chunk_count(s.n_cells, kGrain);
  iso::parallel_for(6 + n_cells_copy, threads, 1, [&](int, i64 t0, i64 t1) {
    for (i64 t = t0; t < t1; ++t) {
      if (t >= 6) {
        const i64 begin = (t - 6) * kGrain, end = std::min(s.n_cells, begin + kGrain);
        std::memcpy(out.cells + 3 * begin, s.cells + 3 * begin,
                    size_t(end - begin) * 3 * sizeof(i64));
        continue;
      }
      const Face &F = g.faces[t];
      FaceBits &b = fb[t];
      const i64 np = F.np, nq = F.nq;
      b.p_edges.resize((np - 1) * nq);
      b.q_edges.resize(np * (nq - 1));
      b.words = t >= 2 ? (np + 63) / 64 : 0;  // the x faces' rows are two samples
      b.columns.resize(nq * 64 * b.words);
      // without branches: signs change at random across a face
      for (i64 p = 0; p < np; ++p) {
        const double *v = F.values + p * nq;
        for (i64 q = 0; q < nq; ++q) {
          const bool positive = v[q] >= level;
          if (b.words) b.columns.set_to(q * 64 * b.words + p, positive);
          if (q + 1 < nq) b.q_edges.set_to(p * (nq - 1) + q, positive != (v[q + 1] >= level));
          if (p + 1 < np) b.p_edges.set_to(p * nq + q, positive != (v[q + nq] >= level));
        }
      }
      b.columns.count();
      b.p_edges.count();
      b.q_edges.count();
    }
  });
  i64 n_bipolar = 0;
  for (auto &b : fb) {
    b.first_slot = n_bipolar;
    n_bipolar += b.p_edges.total() + b.q_edges.total();
  }
  // 1 + the first vertex of the surface on each bipolar edge (0: none), zeroed
  // as allocated: a few hundred kB, where a pass of their own would cost the
  // decoding a wait for it
  std::unique_ptr<std::atomic<i64>[]> edge_slot(
      new std::atomic<i64>[size_t(std::max<i64>(n_bipolar, 1))]());

  // The surface's ids of vertices [begin, end) decoded onto the faces' bipolar edges.
  const i64 n_edge_ids = 3 * X * Y * Z;
  const Divider by_x(X), by_y(Y);
  auto decode = [&](i64 begin, i64 end) {
    // the row (j, k) of the last vertex: the surface's vertices come row by
    // row as extracted, so most need no division, and those of a row inside
    // the grid's y and z faces only two comparisons
    i64 row_first = 0, row_end = 0, j = 0, k = 0;  // its ids [row_first, row_end)
    bool row_on_a_face = false;
    for (i64 v = begin; v < end; ++v) {
      const i64 e = s.ids[v];
      if (e < 0 || e >= n_edge_ids) continue;  // not a grid edge (a cube's inner vertex)
      if (e < row_first || e >= row_end) {
        const i64 row = by_x.quotient(e / 3);
        k = by_y.quotient(row);
        j = row - k * Y;
        row_first = 3 * X * row;
        row_end = row_first + 3 * X;
        row_on_a_face = j == 0 || j == Y - 1 || k == 0 || k == Z - 1;
      }
      const i64 in_row = e - row_first;
      if (!row_on_a_face && in_row >= 3 && in_row < 3 * (X - 1)) continue;  // inside the grid
      const i64 i = in_row / 3, axis = in_row - 3 * i;
      const i64 c[3] = {i, j, k};
      for (int f = 0; f < 6; ++f) {
        const Face &F = g.faces[f];
        if (F.axis == axis || c[F.axis] != F.side) continue;
        const FaceBits &b = fb[f];
        i64 slot;
        if (axis == F.p) {
          const i64 at = c[F.p] * F.nq + c[F.q];
          if (c[F.p] >= F.np - 1 || !b.p_edges.test(at)) continue;  // leaves the grid, or not cut
          slot = b.first_slot + b.p_edges.rank(at);
        } else {
          const i64 at = c[F.p] * (F.nq - 1) + c[F.q];
          if (c[F.q] >= F.nq - 1 || !b.q_edges.test(at)) continue;
          slot = b.first_slot + b.p_edges.total() + b.q_edges.rank(at);
        }
        // the first vertex of an id is kept, whichever thread finds it first
        std::atomic<i64> &a = edge_slot[slot];
        i64 now = a.load(std::memory_order_relaxed);
        while ((now == 0 || v + 1 < now) &&
               !a.compare_exchange_weak(now, v + 1, std::memory_order_relaxed)) {
        }
      }
    }
  };

  // The cap's samples of a run of boundary rows: ids and positions.
  auto write_samples = [&](const Grid::RowTask &task) {
    i64 n = row_start[task.r0];
    auto put = [&](i64 i, i64 j, i64 k) {
      out.ids[n] = -1 - (i + X * (j + Y * k));
      double *v = out.vertices + 3 * n;
      v[0] = double(i) * out.scale[0] + out.shift[0];
      v[1] = double(j) * out.scale[1] + out.shift[1];
      v[2] = double(k) * out.scale[2] + out.shift[2];
      ++n;
    };
    for (i64 r = task.r0; r < task.r1; ++r) {
      const i64 j = r % Y, k = r / Y;
      if (g.full_row(j, k)) {  // a column of a z face or else of a y face
        const int f = k == 0 ? 4 : k == Z - 1 ? 5 : j == 0 ? 2 : 3;
        const FaceBits &b = fb[f];
        const std::uint64_t *w = b.columns.bits.data() + (f < 4 ? k : j) * b.words;
        for (i64 u = 0; u < b.words; ++u) {
          for (std::uint64_t m = w[u]; m; m &= m - 1) put(64 * u + iso::ctz(m), j, k);
        }
      } else {  // its first and last samples, in the x faces
        if (g.faces[0].values[j * Z + k] >= level) put(0, j, k);
        if (X > 1 && g.faces[1].values[j * Z + k] >= level) put(X - 1, j, k);
      }
    }
  };

  // b) the ids decoded, the cap's samples written, the vertices copied (last:
  //    chunks of plain copying even out the threads' shares)
  const i64 n_chunks = iso::chunk_count(V, kGrain);
  iso::parallel_for(n_chunks + nr + n_chunks, threads, 1, [&](int, i64 t0, i64 t1) {
    for (i64 t = t0; t < t1; ++t) {
      if (t < n_chunks) {
        decode(t * kGrain, std::min(V, (t + 1) * kGrain));
      } else if (t < n_chunks + nr) {
        write_samples(g.row_tasks[t - n_chunks]);
      } else {
        const i64 begin = (t - n_chunks - nr) * kGrain, end = std::min(V, begin + kGrain);
        std::memcpy(out.vertices + 3 * begin, s.vertices + 3 * begin,
                    size_t(end - begin) * 3 * sizeof(double));
        std::memcpy(out.ids + begin, s.ids + begin, size_t(end - begin) * sizeof(i64));
      }
    }
  });

  // c) the cap's triangles, cell task by cell task: first the vertex numbers
  //    of the task's samples and crossings in tables of its own (counted
  //    along, one rank per column or row of edges), then its cells sorted by
  //    group and each group's cells written with its one table
  std::atomic<bool> missing{false};
  struct Scratch {
    std::vector<i64> order, samples, p_edges, q_edges;
  };
  std::vector<Scratch> scratch(static_cast<size_t>(std::max(threads, 1)));
  iso::parallel_for(nc, threads, 1, [&](int worker, i64 t0, i64 t1) {
    Scratch &w = scratch[worker];
    for (i64 t = t0; t < t1; ++t) {
      const auto &task = g.cell_tasks[t];
      const int fi = task.face;
      const Face &f = g.faces[fi];
      const FaceBits &b = fb[fi];
      const i64 nq = f.nq, cq = nq - 1, p0 = task.p0, rows = task.p1 - p0;
      // samples of rows p0 .. p1 (the positive ones' vertex numbers)
      w.samples.resize(size_t((rows + 1) * nq));
      for (i64 q = 0; q < nq; ++q) {
        i64 *to = w.samples.data() + q;
        if (fi < 2) {  // (p, q) = (j, k): the first or last sample of its row
          for (i64 p = p0; p <= task.p1; ++p, to += nq) {
            const i64 r = p + Y * q;
            *to = row_start[r] + (f.side == 0 ? 0 : row_counts[r] - 1);
          }
          continue;
        }
        // column q is row (j, k) of the boundary, p = i along it
        const i64 r = fi < 4 ? f.side + Y * q : q + Y * f.side;
        const i64 start = q * 64 * b.words;
        i64 n = row_start[r] + b.columns.rank(start + p0) - b.columns.rank(start);
        for (i64 p = p0; p <= task.p1; ++p, to += nq) {
          *to = n;
          n += b.columns.test(start + p);
        }
      }
      // crossings of the edges along p of rows p0 .. p1 - 1, and along q of
      // rows p0 .. p1 (1 + the surface's vertex, 0 where it has none)
      auto crossings = [&](const Bits &bits, i64 base, i64 first, i64 n, std::vector<i64> &to) {
        to.resize(size_t(n));
        i64 slot = base + bits.rank(first);
        for (i64 e = 0; e < n; ++e) {
          const bool cut = bits.test(first + e);
          to[e] = cut ? edge_slot[slot].load(std::memory_order_relaxed) : 0;
          slot += cut;
        }
      };
      crossings(b.p_edges, b.first_slot, p0 * nq, rows * nq, w.p_edges);
      crossings(b.q_edges, b.first_slot + b.p_edges.total(), p0 * cq, (rows + 1) * cq,
                w.q_edges);

      const std::uint8_t *group = groups + f.first_cell + p0 * cq;
      const i64 n = rows * cq;
      std::array<i64, kGroups + 1> begin{};
      for (int grp = 0; grp < kGroups; ++grp) {
        begin[grp + 1] = begin[grp] + counts[kGroups * t + grp];
      }
      std::array<i64, kGroups> next;
      std::copy(begin.begin(), begin.end() - 1, next.begin());
      w.order.resize(size_t(n));
      for (i64 c = 0; c < n; ++c) w.order[next[group[c]]++] = c;
      bool lost = false;
      for (int grp : kOrder) {
        const Table &table = tables[grp];
        if (!table.count) continue;
        i64 *to = out.cells + 3 * at[t][grp];
        for (i64 u = begin[grp]; u < begin[grp + 1]; ++u) {
          const i64 c = w.order[u], p = c / cq, q = c - p * cq;  // p from p0
          // the vertex numbers of the slots: corners (the case uses its
          // positive ones), then crossings (-1 where the surface has none)
          const i64 *sample = w.samples.data() + p * nq + q;
          const i64 *along_p = w.p_edges.data() + p * nq + q;
          const i64 *along_q = w.q_edges.data() + p * cq + q;
          const i64 slot[8] = {sample[0],      sample[nq],         sample[nq + 1],
                               sample[1],      along_p[0] - 1,     along_q[cq] - 1,
                               along_p[1] - 1, along_q[0] - 1};
          for (int k = 0; k < table.count; ++k, to += 3) {
            const int *sl = table.slots[k];
            to[0] = slot[sl[f.reverse ? 2 : 0]];
            to[1] = slot[sl[1]];
            to[2] = slot[sl[f.reverse ? 0 : 2]];
            lost |= (to[0] < 0) | (to[1] < 0) | (to[2] < 0);
          }
        }
      }
      if (lost) missing = true;
    }
  });
  return missing;
}

}  // namespace

void bind_cap(nb::module_ &m) {
  using Bytes = nb::ndarray<const std::uint8_t, nb::c_contig, nb::device::cpu>;
  // the fixed rule's 16 cases, then the decider's joined 5 and 10: rows of the
  // number of triangles, then 4 x 3 slots
  auto read_tables = [](const Int64s &tables, const Int64s &joined, Table (&t)[kGroups]) {
    if (tables.size() != 16 * 13 || joined.size() != 2 * 13) {
      throw std::invalid_argument("cap: tables (16, 13), joined (2, 13)");
    }
    for (int c = 0; c < kGroups; ++c) {
      const i64 *row = c < 16 ? tables.data() + 13 * c : joined.data() + 13 * (c - 16);
      t[c].count = int(row[0]);
      if (t[c].count < 0 || t[c].count > 4) throw std::invalid_argument("cap: bad table");
      for (int k = 0; k < 12; ++k) {
        const i64 slot = row[1 + k];
        if (k < 3 * t[c].count && (slot < 0 || slot > 7)) {
          throw std::invalid_argument("cap: bad table slot");
        }
        t[c].slots[k / 3][k % 3] = int(slot);
      }
    }
  };
  // face images x0, x1, y0, y1, z0, z1, one after the other; whether each one's
  // triangles turn
  auto grid = [](const Doubles &values, const Int64s &reverse, const Int64s &shape) {
    if (shape.size() != 3 || reverse.size() != 6) {
      throw std::invalid_argument("cap: shape (3,), reverse (6,)");
    }
    const i64 s[3] = {shape.data()[0], shape.data()[1], shape.data()[2]};
    if (s[0] < 1 || s[1] < 1 || s[2] < 1) throw std::invalid_argument("cap: bad shape");
    Grid g(s, values.data(), reverse.data());
    if (g.n_values != i64(values.size())) {
      throw std::invalid_argument("cap: the face images do not fit the grid");
    }
    return g;
  };
  m.def(
      "cap_count",
      [=](Doubles values, Int64s reverse, Int64s shape, double level, Int64s tables,
          Int64s joined, bool decided, int threads) {
        Table t[kGroups];
        read_tables(tables, joined, t);
        const Grid g = grid(values, reverse, shape);
        const i64 nc = i64(g.cell_tasks.size());
        std::vector<std::uint8_t> groups(static_cast<size_t>(g.n_cells));
        std::vector<i64> counts(static_cast<size_t>(nc * kGroups)), rows(size_t(g.Y * g.Z));
        {
          nb::gil_scoped_release unlocked;
          count(g, level, decided, groups.data(), counts.data(), rows.data(), threads);
        }
        i64 triangles = 0, samples = 0;
        for (i64 u = 0; u < nc * kGroups; ++u) triangles += counts[u] * t[u % kGroups].count;
        for (i64 r : rows) samples += r;
        return nb::make_tuple(give(std::move(groups)), give(std::move(counts), kGroups),
                              give(std::move(rows)), triangles, samples);
      },
      "values"_a, "reverse"_a, "shape"_a, "level"_a, "tables"_a, "joined"_a, "decided"_a,
      "threads"_a,
      "The face cells' groups, their counts per task (tasks, 18), the positive samples of "
      "each boundary row (Y Z,), and the cap's number of triangles and of samples.");
  m.def(
      "cap_fill",
      [=](Doubles values, Int64s reverse, Int64s shape, double level, Int64s tables,
          Int64s joined, Bytes groups, Int64s counts, Int64s rows, Doubles vertices,
          Int64s cells, Int64s ids, Doubles scale, Doubles shift, Out<double> out_vertices,
          Out<i64> out_cells, Out<i64> out_ids, int threads) {
        Table t[kGroups];
        read_tables(tables, joined, t);
        const Grid g = grid(values, reverse, shape);
        const i64 nc = i64(g.cell_tasks.size());
        if (i64(groups.size()) != g.n_cells || i64(counts.size()) != nc * kGroups ||
            i64(rows.size()) != g.Y * g.Z || scale.size() != 3 || shift.size() != 3) {
          throw std::invalid_argument(
              "cap_fill: groups, counts and rows are not cap_count's, or scale, shift not (3,)");
        }
        const i64 V = i64(ids.size()), C = cells.ndim() == 2 ? i64(cells.shape(0)) : -1;
        if (vertices.ndim() != 2 || i64(vertices.shape(0)) != V || vertices.shape(1) != 3 ||
            C < 0 || cells.shape(1) != 3) {
          throw std::invalid_argument("cap_fill: vertices (V, 3), cells (C, 3), ids (V,)");
        }
        i64 triangles = 0, samples = 0;
        for (i64 u = 0; u < nc * kGroups; ++u) {
          if (counts.data()[u] < 0) throw std::invalid_argument("cap_fill: bad counts");
          triangles += counts.data()[u] * t[u % kGroups].count;
        }
        for (i64 r = 0; r < g.Y * g.Z; ++r) {
          if (rows.data()[r] < 0) throw std::invalid_argument("cap_fill: bad rows");
          samples += rows.data()[r];
        }
        check_out(out_vertices, V + samples, 3, "out_vertices");
        check_out(out_cells, C + triangles, 3, "out_cells");
        check_out(out_ids, V + samples, 0, "out_ids");
        const Surface s{vertices.data(), cells.data(), ids.data(), V, C};
        Closed o{out_vertices.data(), out_cells.data(), out_ids.data(), {}, {}};
        for (int a = 0; a < 3; ++a) {
          o.scale[a] = scale.data()[a];
          o.shift[a] = shift.data()[a];
        }
        nb::gil_scoped_release unlocked;
        return fill(g, level, t, groups.data(), counts.data(), rows.data(), s, o, threads);
      },
      "values"_a, "reverse"_a, "shape"_a, "level"_a, "tables"_a, "joined"_a, "groups"_a,
      "counts"_a, "rows"_a, "vertices"_a, "cells"_a, "ids"_a, "scale"_a, "shift"_a,
      "out_vertices"_a, "out_cells"_a, "out_ids"_a, "threads"_a,
      "Writes the surface and then the cap into the out arrays (the cap's samples at index * "
      "scale + shift, their ids -1 - linear index); returns whether a crossing had no vertex.");
}
