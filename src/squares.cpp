// Marching Squares slice by slice, on the rows of the volume (see rows.hpp).
//
// The squares of every slice direction lie on the rows of one cube row, so
// neither a transposed copy of the volume nor a pass per slice is needed:
//   across z: square (i, j) of slice k between rows (j, k), (j+1, k), at x = i, i+1;
//   across y: square (k, i) of slice j between rows (j, k), (j, k+1), at x = i, i+1;
//   across x: square (j, k) of slice i on rows (j, k), (j+1, k), (j, k+1), (j+1, k+1)
//             at x = i.
// Each slice is contoured in the plane (u, v) of the two axes that follow the
// slice axis cyclically (across z: (x, y); across y: (z, x); across x: (y,
// z)), so that (u, v, axis) is right-handed and a segment with the positive
// side on its left in (u, v) has it on its left seen from the positive end of
// the axis. A square's edges are bipolar only where its rows differ in sign,
// so the trim of its rows (rows.hpp) bounds the work; as in cubes.cpp, both
// passes then work on the RowScan's packed signs, 64 positions at a time: the
// counting pass reads no sample, the filling pass reads samples only where it
// places a vertex (and at the corners of ambiguous squares for the asymptotic
// decider).
//
// Vertex order: row by row (r = j + NY * k); within a row its bipolar in-plane
// edges by axis (across z: x then y; across y: x then z; across x: y then z),
// each by increasing x. Segments: by the lowest row of their square in the
// same order, by increasing x, in table order within a square. Both orders
// follow from the grid alone, whatever the number of threads.
#include "squares.hpp"

#include "scan.hpp"

namespace iso {

namespace {

// Per row starts of its vertices and of its squares' segments.
struct Starts {
  std::vector<i64> vertex, segment;
};

// The rule of one square: under the asymptotic decider, an ambiguous square
// (diagonal corners of equal sign) joins its positive corners when the saddle
// value of the bilinear interpolant is >= level (book section 2.2.5); f are
// the corner values in corner order.
inline int square_rule(int rule, unsigned config, double f0, double f1, double f2, double f3,
                       double level) {
  if (rule != ASYMPTOTIC) return rule;
  if (config != 6 && config != 9) return SEPARATE_POSITIVE;
  return asymptotic_joins_positive(f0, f1, f2, f3, level) ? SEPARATE_NEGATIVE : SEPARATE_POSITIVE;
}

// The bit masks of one word (64 positions x = 64 w + q) of a cube row, from
// the RowScan's packed signs: the bipolar in-plane edges starting at x (two
// runs of row 0's vertices, and the runs of other rows that its squares
// share), and the squares with corners of both signs.
//   across z (A = 2) and y (A = 1), with o the row (j+1, k), resp. (j, k+1):
//     run[0] x-edges of row 0, run[1] its edges towards o (y, resp. z), and
//     other = x-edges of o; the square at x has corners at x and x + 1;
//   across x (A = 0): run[0] y-edges of row 0, run[1] its z-edges, other =
//     y-edges of row 2, other2 = z-edges of row 1; the square at x is the
//     column of the four rows at x.
// A missing neighbour row is replaced by row 0 itself (rows_of), so edges
// towards it are never bipolar.
template <int A>
struct Word {
  std::uint64_t b[4], n[4];  // signs of the rows at x and x + 1
  std::uint64_t run[2], other, other2, squares;

  Word(const RowScan &s, const std::uint64_t *const (&rows)[4], i64 w, bool has_squares) {
    const std::uint64_t samples = below(s.nx, w), edges = below(s.nx - 1, w);
    for (int r = 0; r < 4; ++r) {
      b[r] = rows[r][w];
      n[r] = next_bits(rows[r], s.words, w);
    }
    if constexpr (A == 0) {
      run[0] = (b[0] ^ b[1]) & samples;
      run[1] = (b[0] ^ b[2]) & samples;
      other = (b[2] ^ b[3]) & samples;
      other2 = (b[1] ^ b[3]) & samples;
      squares = has_squares ? run[0] | run[1] | other : 0;
    } else {
      constexpr int o = A == 2 ? 1 : 2;
      run[0] = (b[0] ^ n[0]) & edges;
      run[1] = (b[0] ^ b[o]) & samples;
      other = (b[o] ^ n[o]) & edges;
      other2 = 0;
      squares = has_squares ? (run[0] | run[1] | other) & edges : 0;
    }
  }

  // The configuration of the square at bit q (corner c = u + 2v of its plane).
  unsigned config(int q) const {
    const auto bit = [q](std::uint64_t m) { return unsigned((m >> q) & 1u); };
    if constexpr (A == 0) {  // (u, v) = (y, z)
      return bit(b[0]) | bit(b[1]) << 1 | bit(b[2]) << 2 | bit(b[3]) << 3;
    } else if constexpr (A == 2) {  // (u, v) = (x, y)
      return bit(b[0]) | bit(n[0]) << 1 | bit(b[1]) << 2 | bit(n[1]) << 3;
    } else {  // (u, v) = (z, x)
      return bit(b[0]) | bit(b[2]) << 1 | bit(n[0]) << 2 | bit(n[2]) << 3;
    }
  }
};

// The bits of m below bit q.
inline int before(std::uint64_t m, int q) {
  return popcount(m & ((std::uint64_t(1) << q) - 1));
}

template <int A>
struct Walk {
  const RowScan &s;
  const SquareTable &table;

  // The four rows of cube row (j, k) as in cubes.cpp; a missing neighbour is
  // replaced by row 0 or 1, so edges towards it are never bipolar. Whether
  // the row starts squares: across z it needs row (j+1, k), across y row
  // (j, k+1), across x both.
  void rows_of(i64 j, i64 k, i64 (&r)[4], const std::uint64_t *(&bits)[4],
               bool &squares) const {
    const bool has_y = j + 1 < s.ny, has_z = k + 1 < s.nz;
    r[0] = j + s.ny * k;
    r[1] = has_y ? r[0] + 1 : r[0];
    r[2] = has_z ? r[0] + s.ny : r[0];
    r[3] = has_z ? r[1] + s.ny : r[1];
    for (int b = 0; b < 4; ++b) bits[b] = s.row_bits(r[b]);
    squares = A == 2 ? has_y : A == 1 ? has_z : has_y && has_z;
  }

  // The stretch [lo, hi] of the row to visit (rows.hpp): of the two rows of
  // the plane across y or z, of the cube row across x.
  bool span(const i64 (&r)[4], i64 &lo, i64 &hi) const {
    if constexpr (A == 0) {
      return trim(s, r, lo, hi);
    } else {
      const i64 two[2] = {r[0], r[A == 2 ? 1 : 2]};
      return trim(s, two, lo, hi);
    }
  }

  // Counting pass for row (j, k), on the packed signs alone.
  void count(i64 j, i64 k, i32 &a, i32 &b, i32 &segs) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool squares;
    rows_of(j, k, r, bits, squares);
    a = A == 0 ? 0 : s.cx[r[0]];
    b = segs = 0;
    i64 lo, hi;
    if (!span(r, lo, hi)) return;
    for (i64 w = lo >> 6; w <= hi >> 6; ++w) {
      const Word<A> m(s, bits, w, squares);
      if constexpr (A == 0) a += popcount(m.run[0]);
      b += popcount(m.run[1]);
      for (std::uint64_t c = m.squares; c; c &= c - 1) segs += table.count[m.config(ctz(c))];
    }
  }

  // Filling pass for row (j, k): its vertices, and its squares' segments.
  template <class T>
  void fill(const T *f, i64 j, i64 k, const Placement &w, const SquaresCount &n,
            const Starts &at, int rule, i64 id_scale, double *verts, i64 *ids,
            i64 *segs) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool squares;
    rows_of(j, k, r, bits, squares);
    i64 lo, hi;
    if (!span(r, lo, hi)) return;
    const T *p[4];
    for (int b = 0; b < 4; ++b) p[b] = f + r[b] * s.nx;
    // The rows at the far ends of row 0's edges were last read by the first
    // pass, long ago: ask for their lines at once, so that their loads overlap
    // instead of stalling at one bipolar edge at a time (as cubes.cpp).
    for (i64 i = lo; i <= hi; i += 64 / sizeof(T)) {
      if constexpr (A != 1) __builtin_prefetch(p[1] + i);
      if constexpr (A != 2) __builtin_prefetch(p[2] + i);
    }
    // the axes of row 0's two runs, and where each run starts in the row
    constexpr int axis[2] = {A == 0 ? 1 : 0, A == 0 ? 2 : A == 2 ? 1 : 2};
    // the row at the other end of an edge of each run, and its x offset
    constexpr int to[2] = {A == 0 ? 1 : 0, A == 0 ? 2 : A == 2 ? 1 : 2};
    constexpr int dx[2] = {A == 0 ? 0 : 1, 0};
    i64 run[2] = {at.vertex[r[0]], at.vertex[r[0]] + n.a[r[0]]};
    // across y or z: the x-edges of row o; across x: the y-edges of row 2
    // and the z-edges of row 1 (none lies before lo)
    const int o = A == 2 ? 1 : 2;
    i64 other = at.vertex[r[A == 0 ? 2 : o]];
    i64 other2 = A == 0 ? at.vertex[r[1]] + n.a[r[1]] : 0;
    i64 t = at.segment[r[0]];
    const i64 gj = j + w.index_origin[1], gk = k + w.index_origin[2];
    const i64 lin_row = w.id_dims[0] * (gj + w.id_dims[1] * gk);
    const double level = s.level;

    for (i64 word = lo >> 6; word <= hi >> 6; ++word) {
      const Word<A> m(s, bits, word, squares);
      const i64 base = 64 * word;
      // row 0's vertices, run by run
      for (int h = 0; h < 2; ++h) {
        const T *end = p[to[h]] + dx[h];
        i64 v = run[h];
        for (std::uint64_t e = m.run[h]; e; e &= e - 1, ++v) {
          const i64 i = base + ctz(e), gi = i + w.index_origin[0];
          const double d = edge_fraction(double(p[0][i]), double(end[i]), level, w.offset);
          double q[3] = {double(gi), double(gj), double(gk)};
          q[axis[h]] += d;
          w.world(q[0], q[1], q[2], verts + 3 * v);
          ids[v] = id_scale * (gi + lin_row) + axis[h];
        }
      }
      for (std::uint64_t c = m.squares; c; c &= c - 1) {
        const int q = ctz(c);
        const unsigned config = m.config(q);
        const int nseg = table.count[config];
        if (!nseg) continue;
        // the vertex numbers of the square's edges in table order
        i64 e[4];
        const i64 r0 = run[0] + before(m.run[0], q), r1 = run[1] + before(m.run[1], q);
        const i64 x = i64(base) + q;
        double v[4] = {0, 0, 0, 0};  // corner values, for the asymptotic decider
        if constexpr (A == 0) {
          e[0] = r0;
          e[1] = other + before(m.other, q);
          e[2] = r1;
          e[3] = other2 + before(m.other2, q);
          if (rule == ASYMPTOTIC) {
            for (int b = 0; b < 4; ++b) v[b] = double(p[b][x]);
          }
        } else {
          const i64 xo = other + before(m.other, q), w1 = r1 + ((m.run[1] >> q) & 1u);
          if constexpr (A == 2) {  // x-edges at x (rows 0, o), o-edges at x, x + 1
            e[0] = r0;
            e[1] = xo;
            e[2] = r1;
            e[3] = w1;
          } else {  // o-edges at x, x + 1, x-edges at x (rows 0, o)
            e[0] = r1;
            e[1] = w1;
            e[2] = r0;
            e[3] = xo;
          }
          if (rule == ASYMPTOTIC) {
            const double a0 = double(p[0][x]), a1 = double(p[0][x + 1]);
            const double b0 = double(p[o][x]), b1 = double(p[o][x + 1]);
            v[0] = a0;
            v[1] = A == 2 ? a1 : b0;
            v[2] = A == 2 ? b0 : a1;
            v[3] = b1;
          }
        }
        const int use = rule == ASYMPTOTIC
                            ? square_rule(rule, config, v[0], v[1], v[2], v[3], level)
                            : rule;
        const std::int8_t *ends = table.edges[use][config];
        for (int u = 0; u < nseg; ++u, ++t) {
          const i64 a = e[ends[2 * u]], b = e[ends[2 * u + 1]];
          segs[2 * t] = w.reverse ? b : a;
          segs[2 * t + 1] = w.reverse ? a : b;
        }
      }
      run[0] += popcount(m.run[0]);
      run[1] += popcount(m.run[1]);
      other += popcount(m.other);
      other2 += popcount(m.other2);
    }
  }
};

}  // namespace

template <class T>
void count_squares(const T *f, const RowScan &s, const SquareTable &table, int axis, int threads,
                   SquaresCount &out) {
  (void)f;  // the counting pass needs the signs only
  const i64 rows = s.rows();
  out.axis = axis;
  out.a.assign(rows, 0);
  out.b.assign(rows, 0);
  out.segments.assign(rows, 0);
  auto run = [&](auto walk) {
    for_each_row(s, threads, [&](i64 j, i64 k, i64 r) {
      walk.count(j, k, out.a[r], out.b[r], out.segments[r]);
    });
  };
  if (axis == 0) {
    run(Walk<0>{s, table});
  } else if (axis == 1) {
    run(Walk<1>{s, table});
  } else {
    run(Walk<2>{s, table});
  }
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    v += out.a[r] + out.b[r];
    t += out.segments[r];
  }
  out.vertices = v;
  out.total_segments = t;
}

template <class T>
void fill_squares(const T *f, const RowScan &s, const SquareTable &table,
                  const SquaresCount &counts, int rule, bool planar, const Placement &where,
                  int threads, double *verts, i64 *ids, i64 *segs) {
  const i64 rows = s.rows();
  Starts at;
  at.vertex.resize(rows + 1);
  at.segment.resize(rows + 1);
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    at.vertex[r] = v;
    at.segment[r] = t;
    v += counts.a[r] + counts.b[r];
    t += counts.segments[r];
  }
  at.vertex[rows] = v;
  at.segment[rows] = t;
  const i64 id_scale = planar ? 2 : 3;
  auto run = [&](auto walk) {
    for_each_row(s, threads, [&](i64 j, i64 k, i64) {
      walk.fill(f, j, k, where, counts, at, rule, id_scale, verts, ids, segs);
    });
  };
  if (counts.axis == 0) {
    run(Walk<0>{s, table});
  } else if (counts.axis == 1) {
    run(Walk<1>{s, table});
  } else {
    run(Walk<2>{s, table});
  }
}

#define ISO_SQUARES(T)                                                                        \
  template void count_squares<T>(const T *, const RowScan &, const SquareTable &, int, int,   \
                                 SquaresCount &);                                             \
  template void fill_squares<T>(const T *, const RowScan &, const SquareTable &,              \
                                const SquaresCount &, int, bool, const Placement &, int,      \
                                double *, i64 *, i64 *);
ISO_FOR_EACH_SAMPLE_TYPE(ISO_SQUARES)
#undef ISO_SQUARES

}  // namespace iso
