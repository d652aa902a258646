// Marching Tetrahedra in the manner of Flying Edges (see rows.hpp).
//
// Each cube is split into six tetrahedra around its diagonal from corner 0 to
// corner 7 (tables.py CUBE_TETRAHEDRA). Their edges run from a grid vertex
// along one of seven directions (tetra.hpp), and each joins two corners of one
// cube: a cube whose eight corners have one sign has no vertex and no
// triangle, so the trim of a cube row (rows.hpp) bounds all the work of that
// row exactly as for Marching Cubes. Seven directions and six tetrahedra make
// a cube cost several times a Marching Cubes one, so, as cubes.cpp does, both
// passes work on the RowScan's packed signs, 64 positions at a time (Word
// below): the counting pass reads no sample, and the filling pass visits only
// the cubes with corners of both signs and reads samples only where it places
// a vertex.
//
// Vertex order: row by row (r = j + NY * k); within a row, the bipolar edges
// starting on it by direction (x, y, z, xy, xz, yz, xyz), each direction by
// increasing x. Triangles: cube row by cube row in the same order, by
// increasing x within a row, and within a cube tetrahedron by tetrahedron in
// table order. Both orders follow from the grid alone, so they do not depend
// on the number of threads.
#include "tetra.hpp"

#include "scan.hpp"

namespace iso {

namespace {

// The directions whose edges exist from a row, given its neighbours.
inline unsigned directions(bool has_y, bool has_z) {
  unsigned m = 1u;
  if (has_y) m |= 1u << 1 | 1u << 3;
  if (has_z) m |= 1u << 2 | 1u << 4;
  if (has_y && has_z) m |= 1u << 5 | 1u << 6;
  return m;
}

// The edges of rows 1-3 of a cube row that its cubes use besides row 0's
// seven: row 1 along x and towards row 3 (z, xz), row 2 along x and towards
// row 3 (y, xy), row 3 along x.
constexpr int OTHER_EDGES = 7;
constexpr int OTHER_ROW[OTHER_EDGES] = {1, 1, 1, 2, 2, 2, 3};
constexpr int OTHER_DIR[OTHER_EDGES] = {0, 2, 4, 0, 1, 3, 0};

// Per row starts of its vertices and of its cubes' triangles.
struct Starts {
  std::vector<i64> vertex, triangle;
};

// The bit masks of one word (64 positions x = 64 w + q) of a cube row, from
// the RowScan's packed signs: the bipolar edges by row and direction (bit q:
// the edge starting at x), and the cubes with corners of both signs.
// Tetrahedron edges join corners of one cube, so no edge of the four rows is
// bipolar outside those cubes, except row 0's edges without x extent at the
// row's last sample, which starts no cube.
struct Word {
  std::uint64_t b[4];      // signs of the four rows at x
  std::uint64_t n[4];      // ... at x + 1
  std::uint64_t e[4][7];   // bipolar edges: all of row 0, OTHER_* of rows 1-3
  std::uint64_t cubes;     // cubes with corners of both signs

  // Row 0's edges (the directions in `allowed`) and the cut cubes.
  Word(const RowScan &s, const std::uint64_t *const (&rows)[4], i64 w, unsigned allowed,
       bool has_cubes) {
    for (int r = 0; r < 4; ++r) {
      b[r] = rows[r][w];
      n[r] = next_bits(rows[r], s.words, w);
    }
    const std::uint64_t samples = below(s.nx, w), edges = below(s.nx - 1, w);
    for (int d = 0; d < 7; ++d) e[0][d] = edge(0, d, samples, edges);
    // the seven directions join corner 0 to each other corner of the cube
    cubes = 0;
    if (has_cubes) {
      for (int d = 0; d < 7; ++d) cubes |= e[0][d];
      cubes &= edges;
    }
    for (int d = 0; d < 7; ++d) {
      if (!((allowed >> d) & 1u)) e[0][d] = 0;
    }
  }

  // The other rows' edges that the cubes use (all four rows exist then).
  void others(const RowScan &s, i64 w) {
    const std::uint64_t samples = below(s.nx, w), edges = below(s.nx - 1, w);
    for (int m = 0; m < OTHER_EDGES; ++m) {
      e[OTHER_ROW[m]][OTHER_DIR[m]] = edge(OTHER_ROW[m], OTHER_DIR[m], samples, edges);
    }
  }

  // Edges of direction d from row r: towards row r + dy + 2 dz, at x + dx.
  std::uint64_t edge(int r, int d, std::uint64_t samples, std::uint64_t edges) const {
    const int to = r + TETRA_DY[d] + 2 * TETRA_DZ[d];
    return TETRA_DX[d] ? (b[r] ^ n[to]) & edges : (b[r] ^ b[to]) & samples;
  }

  // The configuration of the cube at bit q (cube corner v = x + 2y + 4z).
  unsigned config(int q) const {
    unsigned c = 0;
    for (int r = 0; r < 4; ++r) {
      c |= unsigned((b[r] >> q) & 1u) << (2 * r);
      c |= unsigned((n[r] >> q) & 1u) << (2 * r + 1);
    }
    return c;
  }
};

struct Walk {
  const RowScan &s;
  const TetraTable &table;

  // The four rows of cube row (j, k) as in cubes.cpp: a missing neighbour
  // (last y or z row) is replaced by a row that is there, which makes the
  // trim right; the directions towards it are masked by `directions`.
  void rows_of(i64 j, i64 k, i64 (&r)[4], const std::uint64_t *(&bits)[4], bool &has_y,
               bool &has_z) const {
    has_y = j + 1 < s.ny;
    has_z = k + 1 < s.nz;
    r[0] = j + s.ny * k;
    r[1] = has_y ? r[0] + 1 : r[0];
    r[2] = has_z ? r[0] + s.ny : r[0];
    r[3] = has_z ? r[1] + s.ny : r[1];
    for (int b = 0; b < 4; ++b) bits[b] = s.row_bits(r[b]);
  }

  // Counting pass for row (j, k), on the packed signs alone.
  void count(i64 j, i64 k, std::array<i32, 8> &out) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool has_y, has_z;
    rows_of(j, k, r, bits, has_y, has_z);
    out.fill(0);
    out[0] = s.cx[r[0]];
    i64 lo, hi;
    if (!trim(s, r, lo, hi)) return;
    const unsigned allowed = directions(has_y, has_z);
    const bool cubes = has_y && has_z;
    for (i64 w = lo >> 6; w <= hi >> 6; ++w) {
      const Word m(s, bits, w, allowed, cubes);
      for (int d = 1; d < 7; ++d) out[d] += popcount(m.e[0][d]);
      for (std::uint64_t c = m.cubes; c; c &= c - 1) out[7] += table.count[m.config(ctz(c))];
    }
  }

  // Filling pass for row (j, k): its vertices, and its cubes' triangles.
  template <class T>
  void fill(const T *f, i64 j, i64 k, const TetraCount &n, const Starts &at, const Placement &w,
            double *verts, i64 *ids, i64 *tris) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool has_y, has_z;
    rows_of(j, k, r, bits, has_y, has_z);
    i64 lo, hi;
    if (!trim(s, r, lo, hi)) return;
    const unsigned allowed = directions(has_y, has_z);
    const bool cubes = has_y && has_z;
    const T *p[4];
    for (int b = 0; b < 4; ++b) p[b] = f + r[b] * s.nx;
    // Rows 1-3 (rows 2 and 3 are in the next slice) were last read by the
    // first pass, long ago: ask for their lines at once, so that their loads
    // overlap instead of stalling at one bipolar edge at a time (as cubes.cpp).
    for (i64 i = lo; i <= hi; i += 64 / sizeof(T)) {
      for (int b = 1; b < 4; ++b) __builtin_prefetch(p[b] + i);
    }
    // start[b][d]: the number of the first vertex at x >= 64 w on the edges of
    // direction d starting in row b (none lies before lo)
    i64 start[4][7];
    for (int b = 0; b < (cubes ? 4 : 1); ++b) {
      i64 v = at.vertex[r[b]];
      for (int d = 0; d < 7; ++d) {
        start[b][d] = v;
        v += n.rows[r[b]][d];
      }
    }
    i64 t = at.triangle[r[0]];
    // grid position of row 0 in the whole grid, for positions and ids
    const i64 gj = j + w.index_origin[1], gk = k + w.index_origin[2];
    const i64 id_row = w.id_dims[0] * (gj + w.id_dims[1] * gk);
    const double y = static_cast<double>(gj), z = static_cast<double>(gk);
    const double level = s.level;

    for (i64 word = lo >> 6; word <= hi >> 6; ++word) {
      Word m(s, bits, word, allowed, cubes);
      const i64 base = 64 * word;
      // row 0's vertices, direction by direction: each has its own run of
      // numbers, so they can be written word by word
      for (int d = 0; d < 7; ++d) {
        const T *end = p[TETRA_DY[d] + 2 * TETRA_DZ[d]] + TETRA_DX[d];
        i64 v = start[0][d];
        for (std::uint64_t e = m.e[0][d]; e; e &= e - 1, ++v) {
          const i64 i = base + ctz(e), gi = i + w.index_origin[0];
          const double a = edge_fraction(double(p[0][i]), double(end[i]), level, w.offset);
          w.world(double(gi) + a * TETRA_DX[d], y + a * TETRA_DY[d], z + a * TETRA_DZ[d],
                  verts + 3 * v);
          ids[v] = 7 * (gi + id_row) + d;
        }
      }
      if (cubes) {
        m.others(s, word);
        for (std::uint64_t c = m.cubes; c; c &= c - 1) {
          const int q = ctz(c);
          const unsigned config = m.config(q);
          // the vertex numbers of the cube's edges that its triangles use:
          // the run's start plus the bipolar edges before it in the run (an
          // edge starting at x + 1 has dx = 1: those at x and x + 1 are before
          // it; at q = 63 the shift then wraps to 0 and the mask to all ones)
          i64 e[19];
          for (std::uint32_t u = table.used[config]; u; u &= u - 1) {
            const int g = ctz(u), b = table.row[g], d = table.dir[g];
            const std::uint64_t before = (std::uint64_t(1 + table.dx[g]) << q) - 1;
            e[g] = start[b][d] + popcount(m.e[b][d] & before);
          }
          const std::int8_t *tri = table.edges[config];
          for (int u = 0; u < 3 * table.count[config]; u += 3, ++t) {
            i64 *out = tris + 3 * t;
            const i64 a = e[tri[u]], b = e[tri[u + 1]], d = e[tri[u + 2]];
            out[0] = w.reverse ? d : a;
            out[1] = b;
            out[2] = w.reverse ? a : d;
          }
        }
        for (int u = 0; u < OTHER_EDGES; ++u) {
          start[OTHER_ROW[u]][OTHER_DIR[u]] += popcount(m.e[OTHER_ROW[u]][OTHER_DIR[u]]);
        }
      }
      for (int d = 0; d < 7; ++d) start[0][d] += popcount(m.e[0][d]);
    }
  }
};

void starts(const RowScan &s, const TetraCount &n, Starts &at) {
  const i64 rows = s.rows();
  at.vertex.resize(rows + 1);
  at.triangle.resize(rows + 1);
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    at.vertex[r] = v;
    at.triangle[r] = t;
    for (int d = 0; d < 7; ++d) v += n.rows[r][d];
    t += n.rows[r][7];
  }
  at.vertex[rows] = v;
  at.triangle[rows] = t;
}

}  // namespace

template <class T>
void count_tetra(const T *f, const RowScan &s, const TetraTable &table, int threads,
                 TetraCount &out) {
  const i64 rows = s.rows();
  out.rows.assign(rows, std::array<i32, 8>{});
  (void)f;  // the counting pass needs the signs only
  const Walk walk{s, table};
  for_each_row(s, threads, [&](i64 j, i64 k, i64 r) { walk.count(j, k, out.rows[r]); });
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    for (int d = 0; d < 7; ++d) v += out.rows[r][d];
    t += out.rows[r][7];
  }
  out.vertices = v;
  out.triangles = t;
}

template <class T>
void fill_tetra(const T *f, const RowScan &s, const TetraTable &table, const TetraCount &counts,
                const Placement &where, int threads, double *verts, i64 *ids, i64 *tris) {
  Starts at;
  starts(s, counts, at);
  const Walk walk{s, table};
  for_each_row(s, threads, [&](i64 j, i64 k, i64) {
    walk.fill(f, j, k, counts, at, where, verts, ids, tris);
  });
}

#define ISO_TETRA(T)                                                                       \
  template void count_tetra<T>(const T *, const RowScan &, const TetraTable &, int,        \
                               TetraCount &);                                              \
  template void fill_tetra<T>(const T *, const RowScan &, const TetraTable &,              \
                              const TetraCount &, const Placement &, int, double *, i64 *, \
                              i64 *);
ISO_FOR_EACH_SAMPLE_TYPE(ISO_TETRA)
#undef ISO_TETRA

}  // namespace iso
