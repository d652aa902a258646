// Marching Cubes in the manner of Flying Edges (see rows.hpp).
//
// Vertex order: row by row (r = j + NY * k), and within a row its bipolar
// x-edges, then its y-edges, then its z-edges, each by increasing x, then (in
// the trilinear mode) the interior vertices of its cubes, by increasing x and
// in table order within a cube. Triangles:
// cube row by cube row in the same order, by increasing x within a row, in
// table order within a cube. Both orders follow from the grid alone, so they do
// not depend on the number of threads, and a z-slab of a volume numbers its
// rows in the same order as the whole volume.
#include "cubes.hpp"

#include "sample.hpp"
#include "scan.hpp"
#include "trilinear.hpp"

namespace iso {

namespace {

// Per row starts of its x-, y- and z-vertices and of its cubes' triangles.
struct Starts {
  std::vector<i64> vertex, triangle;
};

// The bit masks of one word (64 positions) of a cube row: which positions
// start a bipolar edge, and which cubes have corners of both signs.
struct Word {
  std::uint64_t b[4];  // signs of the four rows at positions 64 w + q
  std::uint64_t n[4];  // ... at positions 64 w + q + 1
  std::uint64_t x[4];  // bipolar x-edges of each row
  std::uint64_t y[2];  // bipolar y-edges of rows 0 and 2
  std::uint64_t z[2];  // bipolar z-edges of rows 0 and 1
  std::uint64_t cubes; // cubes with corners of both signs

  Word(const RowScan &s, const std::uint64_t *const (&rows)[4], i64 w) {
    const std::uint64_t samples = below(s.nx, w), edges = below(s.nx - 1, w);
    for (int r = 0; r < 4; ++r) {
      b[r] = rows[r][w];
      n[r] = next_bits(rows[r], s.words, w);
      x[r] = (b[r] ^ n[r]) & edges;
    }
    y[0] = (b[0] ^ b[1]) & samples;
    y[1] = (b[2] ^ b[3]) & samples;
    z[0] = (b[0] ^ b[2]) & samples;
    z[1] = (b[1] ^ b[3]) & samples;
    // a cube is all one sign when none of its x-edges is bipolar and its four
    // rows agree at its lower x
    cubes = (x[0] | x[1] | x[2] | x[3] | y[0] | z[0] | (b[0] ^ b[3])) & edges;
  }

  // The configuration of the cube at bit q (cube vertex v = x + 2y + 4z).
  unsigned config(int q) const {
    unsigned c = 0;
    for (int r = 0; r < 4; ++r) {
      c |= unsigned((b[r] >> q) & 1) << (2 * r);
      c |= unsigned((n[r] >> q) & 1) << (2 * r + 1);
    }
    return c;
  }
};

// The set bits of m below bit q.
inline int before(std::uint64_t m, int q) { return popcount(m & ((std::uint64_t(1) << q) - 1)); }

struct Walk {
  const RowScan &s;
  const CubeTable &table;
  const TrilinearTable *trilinear;  // null for a fixed ambiguity rule

  // Whether the cube of configuration `config` takes the trilinear tests.
  bool special(unsigned config) const { return trilinear && trilinear->special[config]; }

  // The values of the cube at x = i of the four rows p, by cube vertex.
  template <class T>
  static void corner_values(const T *const (&p)[4], i64 i, double (&v)[8]) {
    for (int r = 0; r < 4; ++r) {
      v[2 * r] = double(p[r][i]);
      v[2 * r + 1] = double(p[r][i + 1]);
    }
  }

  // The pieces of the special cube at x = i of the four rows p (see trilinear.hpp).
  template <class T>
  int pieces(const T *const (&p)[4], i64 i, unsigned config, int (&out)[4]) const {
    double v[8];
    corner_values(p, i, v);
    return trilinear_pieces(*trilinear, v, config, s.level, out);
  }

  // Up to 4 pieces (each < 2^15) and their number in one word, kept from the
  // counting pass for the filling pass: the tests run once per cube.
  static std::uint64_t pack_pieces(const int *piece, int n) {
    std::uint64_t code = std::uint64_t(n);
    for (int q = 0; q < n; ++q) code |= std::uint64_t(piece[q]) << (3 + 15 * q);
    return code;
  }
  static int unpack_pieces(std::uint64_t code, int (&piece)[4]) {
    for (int q = 0; q < 4; ++q) piece[q] = int((code >> (3 + 15 * q)) & 0x7fff);
    return int(code & 7);
  }

  // Triangles and interior vertices of the pieces `piece[0..n-1]`.
  void piece_sizes(const int *piece, int n, i32 &tris, i32 &inner) const {
    const TrilinearTable &t = *trilinear;
    for (int q = 0; q < n; ++q) {
      tris += t.piece_tris[piece[q] + 1] - t.piece_tris[piece[q]];
      inner += t.piece_inner[piece[q] + 1] - t.piece_inner[piece[q]];
    }
  }

  // The four rows of cube row (j, k): (j, k), (j+1, k), (j, k+1), (j+1, k+1).
  // On the last y or z row a missing neighbour is replaced by the row itself,
  // so its edges towards it are never bipolar and it makes no cubes.
  void rows_of(i64 j, i64 k, i64 (&r)[4], const std::uint64_t *(&bits)[4], bool &cubes) const {
    const bool has_y = j + 1 < s.ny, has_z = k + 1 < s.nz;
    r[0] = j + s.ny * k;
    r[1] = has_y ? r[0] + 1 : r[0];
    r[2] = has_z ? r[0] + s.ny : r[0];
    r[3] = has_z ? r[1] + s.ny : r[1];
    for (int b = 0; b < 4; ++b) bits[b] = s.row_bits(r[b]);
    cubes = has_y && has_z;
  }

  // Counting pass for row (j, k); the pieces of its special cubes are appended to `found`.
  template <class T>
  void count(const T *f, i64 j, i64 k, i32 &cy, i32 &cz, i32 &ct, i32 &ci,
             std::vector<std::uint64_t> &found) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool cubes;
    rows_of(j, k, r, bits, cubes);
    cy = cz = ct = ci = 0;
    i64 lo, hi;
    if (!trim(s, r, lo, hi)) return;
    const T *const p[4] = {f + r[0] * s.nx, f + r[1] * s.nx, f + r[2] * s.nx, f + r[3] * s.nx};
    if (trilinear && cubes) {
      // special cubes read their values: the next slice's rows are long out of
      // cache, so ask for their lines at once (as the filling pass does)
      for (i64 i = lo; i <= hi; i += 64 / sizeof(T)) {
        for (int b = 1; b < 4; ++b) __builtin_prefetch(p[b] + i);
      }
    }
    for (i64 w = lo >> 6; w <= hi >> 6; ++w) {
      const Word m(s, bits, w);
      cy += popcount(m.y[0]);
      cz += popcount(m.z[0]);
      if (!cubes) continue;
      for (std::uint64_t c = m.cubes; c; c &= c - 1) {
        const int q = ctz(c);
        const unsigned config = m.config(q);
        if (!special(config)) {
          ct += table.count[config];
          continue;
        }
        int piece[4];
        const int np = pieces(p, 64 * w + q, config, piece);
        piece_sizes(piece, np, ct, ci);
        found.push_back(pack_pieces(piece, np));
      }
    }
  }

  // Filling pass for row (j, k): its vertices, and its cubes' triangles.
  template <class T, class Grid>
  void fill(const T *f, i64 j, i64 k, const CubesCount &n, const Starts &at, const Placement &w,
            double *verts, i64 *ids, i64 *tris, const EdgeNormals *normals,
            const Grid &grid) const {
    i64 r[4];
    const std::uint64_t *bits[4];
    bool cubes;
    rows_of(j, k, r, bits, cubes);
    i64 lo, hi;
    if (!trim(s, r, lo, hi)) return;
    const T *const p[4] = {f + r[0] * s.nx, f + r[1] * s.nx, f + r[2] * s.nx, f + r[3] * s.nx};
    const T *p0 = p[0], *p1 = p[1], *p2 = p[2];
    // The next slice's row (p2) was last read by the first pass, long ago: ask
    // for all its lines at once, so their loads overlap instead of stalling one
    // bipolar edge at a time (this halved the pass on a dense surface).
    for (i64 i = lo; i <= hi; i += 64 / sizeof(T)) {
      __builtin_prefetch(p2 + i);
      __builtin_prefetch(p1 + i);
    }
    if (normals) {
      // the gradients' stencils reach a slice further each way, to rows
      // likewise long out of cache: two slices up (above a z-edge's upper
      // end) and the slice below (below the row and below a y-edge's upper
      // end). Asking for them at once halved the normals' added time on a
      // 384^3 gyroid.
      const i64 slice = s.nx * s.ny;
      // (in the slab's halo when it is not the whole grid)
      const i64 first = normals->halo_k0 - w.index_origin[2];  // local layer of halo[0]
      const i64 last = first + normals->halo_layers - 1;
      const T *up = k + 2 <= last ? p2 + slice : nullptr;
      const T *down = k - 1 >= first ? p0 - slice : nullptr;
      const T *down1 = k - 1 >= first ? p1 - slice : nullptr;
      for (i64 i = lo; i <= hi; i += 64 / sizeof(T)) {
        if (up) __builtin_prefetch(up + i);
        if (down) {
          __builtin_prefetch(down + i);
          __builtin_prefetch(down1 + i);
        }
      }
    }
    // starts of the x-vertices of the four rows, of the y-vertices of rows 0
    // and 2, of the z-vertices of rows 0 and 1
    i64 xs[4], ys[2], zs[2];
    for (int b = 0; b < 4; ++b) xs[b] = at.vertex[r[b]];
    ys[0] = xs[0] + s.cx[r[0]];
    ys[1] = xs[2] + s.cx[r[2]];
    zs[0] = ys[0] + n.cy[r[0]];
    zs[1] = xs[1] + s.cx[r[1]] + n.cy[r[1]];
    i64 vx = xs[0], vy = ys[0], vz = zs[0], t = at.triangle[r[0]];
    i64 vi = zs[0] + n.cz[r[0]];  // the row's interior vertices come after its z-vertices
    // the pieces of the row's special cubes, as the counting pass found them
    const std::uint64_t *found =
        trilinear ? n.found[n.found_by[r[0]]].data() + n.found_at[r[0]] : nullptr;
    std::size_t next_special = 0;
    // grid position of row 0 in the whole grid, for positions and ids
    const i64 gj = j + w.index_origin[1], gk = k + w.index_origin[2];
    const i64 id_row = w.id_dims[0] * (gj + w.id_dims[1] * gk);
    const double y = static_cast<double>(gj), z = static_cast<double>(gk);
    const double level = s.level;
    auto put = [&](i64 v, double px, double py, double pz, i64 id) {
      w.world(px, py, pz, verts + 3 * v);
      ids[v] = id;
    };
    // The normal of vertex v, once placed (see EdgeNormals): the samples the
    // stencils read are in cache, next to the edge's. Those left 0 (the
    // gradient vanishes) or NaN are counted, so that the caller looks for
    // them only when there are some.
    i64 flat = 0;
    auto normal = [&](i64 v) {
      if (normals) {
        float *o = normals->out + 3 * v;
        sample_point(grid, normals->map, verts + 3 * v, true, normals->slack, o);
        flat += (o[0] == 0.0f && o[1] == 0.0f && o[2] == 0.0f) || std::isnan(o[0]);
      }
    };

    for (i64 word = lo >> 6; word <= hi >> 6; ++word) {
      const Word m(s, bits, word);
      const i64 base = 64 * word;
      // row 0's vertices, in the order x-edges, y-edges, z-edges: each kind
      // has its own run of numbers, so they can be written word by word
      for (std::uint64_t e = m.x[0]; e; e &= e - 1) {
        const i64 i = base + ctz(e), gi = i + w.index_origin[0];
        const double d = edge_fraction(double(p0[i]), double(p0[i + 1]), level, w.offset);
        put(vx, double(gi) + d, y, z, 3 * (gi + id_row));
        normal(vx++);
      }
      for (std::uint64_t e = m.y[0]; e; e &= e - 1) {
        const i64 i = base + ctz(e), gi = i + w.index_origin[0];
        const double d = edge_fraction(double(p0[i]), double(p1[i]), level, w.offset);
        put(vy, double(gi), y + d, z, 3 * (gi + id_row) + 1);
        normal(vy++);
      }
      for (std::uint64_t e = m.z[0]; e; e &= e - 1) {
        const i64 i = base + ctz(e), gi = i + w.index_origin[0];
        const double d = edge_fraction(double(p0[i]), double(p2[i]), level, w.offset);
        put(vz, double(gi), y, z + d, 3 * (gi + id_row) + 2);
        normal(vz++);
      }
      if (cubes) {
        for (std::uint64_t c = m.cubes; c; c &= c - 1) {
          const int q = ctz(c);
          const unsigned config = m.config(q);
          const bool tests = special(config);
          const int nt = table.count[config];
          if (!nt && !tests) continue;
          // vertex numbers of the cube's 12 edges (tables.py numbering)
          i64 e[12];
          for (int b = 0; b < 4; ++b) e[b] = xs[b] + before(m.x[b], q);
          e[4] = ys[0] + before(m.y[0], q);
          e[5] = e[4] + ((m.y[0] >> q) & 1);
          e[6] = ys[1] + before(m.y[1], q);
          e[7] = e[6] + ((m.y[1] >> q) & 1);
          e[8] = zs[0] + before(m.z[0], q);
          e[9] = e[8] + ((m.z[0] >> q) & 1);
          e[10] = zs[1] + before(m.z[1], q);
          e[11] = e[10] + ((m.z[1] >> q) & 1);
          if (tests) {
            const i64 i = base + q, gi = i + w.index_origin[0];
            t = fill_special(p, i, found[next_special++], e, gi, y, z, 16 * (gi + id_row), w, vi,
                             t, verts, ids, tris);
            continue;
          }
          const std::int8_t *tri = table.edges[config];
          for (int u = 0; u < nt; ++u, ++t) {
            i64 *out = tris + 3 * t;
            const i64 a = e[tri[3 * u]], b = e[tri[3 * u + 1]], d = e[tri[3 * u + 2]];
            out[0] = w.reverse ? d : a;
            out[1] = b;
            out[2] = w.reverse ? a : d;
          }
        }
      }
      for (int b = 0; b < 4; ++b) xs[b] += popcount(m.x[b]);
      for (int b = 0; b < 2; ++b) {
        ys[b] += popcount(m.y[b]);
        zs[b] += popcount(m.z[b]);
      }
    }
    if (flat) normals->flat->fetch_add(flat, std::memory_order_relaxed);
  }

  // A special cube's triangles from triangle t on, and its interior vertices
  // from vertex vi on (both advanced); e: vertex numbers of its 12 edges; (gi,
  // y, z): its lowest corner in the whole grid; cube_id: 16 times its linear
  // index there. Returns the next triangle.
  template <class T>
  i64 fill_special(const T *const (&p)[4], i64 i, std::uint64_t code, const i64 (&e)[12],
                   i64 gi, double y, double z, i64 cube_id, const Placement &w, i64 &vi, i64 t,
                   double *verts, i64 *ids, i64 *tris) const {
    const TrilinearTable &tt = *trilinear;
    int piece[4];
    const int np = unpack_pieces(code, piece);
    double v[8];
    for (int q = 0; q < np; ++q) {
      if (tt.piece_inner[piece[q] + 1] > tt.piece_inner[piece[q]]) {  // positions need values
        corner_values(p, i, v);
        break;
      }
    }
    int slot = 0;
    for (int q = 0; q < np; ++q) {
      const i64 first = vi;  // the piece's interior slot 0
      for (i32 u = tt.piece_inner[piece[q]]; u < tt.piece_inner[piece[q] + 1]; ++u, ++slot) {
        // the mean of the edge vertices the mask names, placed as they are
        double sum[3] = {0.0, 0.0, 0.0};
        int terms = 0;
        for (int edge = 0; edge < 12; ++edge) {
          if (!((tt.inner[u] >> edge) & 1)) continue;
          const i32 a = tt.edges[edge][0], b = tt.edges[edge][1];
          double at[3] = {double(gi + (a & 1)), y + double((a >> 1) & 1), z + double(a >> 2)};
          const int axis = (a ^ b) == 1 ? 0 : (a ^ b) == 2 ? 1 : 2;
          at[axis] += edge_fraction(v[a], v[b], s.level, w.offset);
          for (int c = 0; c < 3; ++c) sum[c] += at[c];
          ++terms;
        }
        w.world(sum[0] / terms, sum[1] / terms, sum[2] / terms, verts + 3 * vi);
        ids[vi++] = w.inner_base + cube_id + slot;
      }
      for (i32 u = tt.piece_tris[piece[q]]; u < tt.piece_tris[piece[q] + 1]; ++u, ++t) {
        i64 corner[3];
        for (int c = 0; c < 3; ++c) {
          const i32 x = tt.tris[3 * u + c];
          corner[c] = x < 12 ? e[x] : first + (x - 12);
        }
        i64 *out = tris + 3 * t;
        out[0] = w.reverse ? corner[2] : corner[0];
        out[1] = corner[1];
        out[2] = w.reverse ? corner[0] : corner[2];
      }
    }
    return t;
  }
};

void starts(const RowScan &s, const CubesCount &n, Starts &at) {
  const i64 rows = s.rows();
  at.vertex.resize(rows + 1);
  at.triangle.resize(rows + 1);
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    at.vertex[r] = v;
    at.triangle[r] = t;
    v += s.cx[r] + n.cy[r] + n.cz[r] + n.ci[r];
    t += n.ct[r];
  }
  at.vertex[rows] = v;
  at.triangle[rows] = t;
}

}  // namespace

template <class T>
void count_cubes(const T *f, const RowScan &s, const CubeTable &table,
                 const TrilinearTable *trilinear, int threads, CubesCount &out) {
  const i64 rows = s.rows();
  out.cy.assign(rows, 0);
  out.cz.assign(rows, 0);
  out.ct.assign(rows, 0);
  out.ci.assign(rows, 0);
  out.found.assign(std::max(threads, 1), {});
  out.found_by.assign(trilinear ? rows : 0, 0);
  out.found_at.assign(trilinear ? rows : 0, 0);
  const Walk walk{s, table, trilinear};
  // as for_each_row, knowing the thread: each appends to its own buffer
  parallel_for(rows, threads, 32, [&](int worker, i64 begin, i64 end) {
    std::vector<std::uint64_t> &found = out.found[worker];
    for (i64 r = begin; r < end; ++r) {
      if (trilinear) {
        out.found_by[r] = worker;
        out.found_at[r] = i64(found.size());
      }
      walk.count(f, r % s.ny, r / s.ny, out.cy[r], out.cz[r], out.ct[r], out.ci[r], found);
    }
  });
  i64 v = 0, t = 0;
  for (i64 r = 0; r < rows; ++r) {
    v += s.cx[r] + out.cy[r] + out.cz[r] + out.ci[r];
    t += out.ct[r];
  }
  out.vertices = v;
  out.triangles = t;
}

template <class T>
void fill_cubes(const T *f, const RowScan &s, const CubeTable &table,
                const TrilinearTable *trilinear, const CubesCount &counts, const Placement &where,
                int threads, double *verts, i64 *ids, i64 *tris, const EdgeNormals *normals) {
  Starts at;
  starts(s, counts, at);
  const Walk walk{s, table, trilinear};
  if (!normals || (normals->halo == f && normals->halo_k0 == 0 && normals->depth == s.nz)) {
    // the whole grid: read with no checks
    const WholeGrid<T> grid{f, s.nx, s.ny, s.nz};
    for_each_row(s, threads, [&](i64 j, i64 k, i64) {
      walk.fill(f, j, k, counts, at, where, verts, ids, tris, normals, grid);
    });
    return;
  }
  // a slab and its halo, read as sample_points reads a slab (checked)
  const Slab<T> grid{static_cast<const T *>(normals->halo),
                     s.nx,
                     s.ny,
                     normals->halo_layers,
                     normals->halo_k0,
                     normals->depth,
                     false,
                     0.0,
                     normals->missing};
  for_each_row(s, threads, [&](i64 j, i64 k, i64) {
    walk.fill(f, j, k, counts, at, where, verts, ids, tris, normals, grid);
  });
}

#define ISO_CUBES(T)                                                                  \
  template void count_cubes<T>(const T *, const RowScan &, const CubeTable &,         \
                               const TrilinearTable *, int, CubesCount &);            \
  template void fill_cubes<T>(const T *, const RowScan &, const CubeTable &,          \
                              const TrilinearTable *, const CubesCount &,             \
                              const Placement &, int, double *, i64 *, i64 *,         \
                              const EdgeNormals *);
ISO_FOR_EACH_SAMPLE_TYPE(ISO_CUBES)
#undef ISO_CUBES

}  // namespace iso
