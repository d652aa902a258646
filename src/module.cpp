// isoconvert._native: the Python face of the kernels. Arrays come in already
// validated (isoconvert/extract/prepare.py); only shapes are re-checked here,
// since a wrong one would read out of bounds. The GIL is released while a
// kernel runs, so Python threads (batch jobs, Dask workers) run alongside.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <atomic>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "cubes.hpp"
#include "bind.hpp"
#include "scan.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

void bind_tetra_squares(nb::module_ &m);  // more.cpp
void bind_report(nb::module_ &m);         // report.cpp
void bind_sample(nb::module_ &m);         // sample.cpp
void bind_smooth(nb::module_ &m);         // smooth.cpp
void bind_labels(nb::module_ &m);         // labels.cpp
void bind_normals(nb::module_ &m);        // normals.cpp
void bind_distance(nb::module_ &m);       // distance.cpp
void bind_rays(nb::module_ &m);           // rays.cpp
void bind_graph(nb::module_ &m);          // graph.cpp
void bind_precision(nb::module_ &m);      // precision.cpp
void bind_cap(nb::module_ &m);            // cap.cpp

namespace {

using namespace iso::bind;

iso::CubeTable cube_table(const Int64s &counts, const Int64s &edges) {
  if (counts.ndim() != 1 || counts.shape(0) != 256 || edges.ndim() != 3 ||
      edges.shape(0) != 256 || edges.shape(2) != 3 || edges.shape(1) > 5) {
    throw std::invalid_argument("a cube table is (256,) counts and (256, <=5, 3) edges");
  }
  iso::CubeTable t;
  std::memset(&t, 0, sizeof t);
  const i64 per = edges.shape(1);
  for (int c = 0; c < 256; ++c) {
    const i64 n = counts.data()[c];
    if (n < 0 || n > per) throw std::invalid_argument("cube table count out of range");
    t.count[c] = static_cast<std::int8_t>(n);
    for (i64 q = 0; q < 3 * n; ++q) {
      const i64 e = edges.data()[c * per * 3 + q];
      if (e < 0 || e > 11) throw std::invalid_argument("cube table edge out of range");
      t.edges[c][q] = static_cast<std::int8_t>(e);
    }
  }
  return t;
}

using Int32s = nb::ndarray<const std::int32_t, nb::c_contig, nb::device::cpu>;

std::vector<iso::i32> int32s(const Int32s &a, const char *name, std::size_t size = 0) {
  if (size && a.size() != size) {
    throw std::invalid_argument(std::string("trilinear table: ") + name + " has the wrong size");
  }
  return std::vector<iso::i32>(a.data(), a.data() + a.size());
}

// A trilinear table from trilinear.kernel_table()'s arrays, checked so that
// the kernel, which trusts it, never reads outside it.
iso::TrilinearTable trilinear_table(const Int32s &special, const Int32s &entry,
                                    const Int32s &loops, const Int32s &corners,
                                    const Int32s &disk, const Int32s &tube,
                                    const Int32s &piece_tris, const Int32s &piece_inner,
                                    const Int32s &tris, const Int32s &inner,
                                    const Int32s &edges, const Int32s &face_corners) {
  auto bad = [](const char *what) {
    throw std::invalid_argument(std::string("trilinear table: ") + what);
  };
  iso::TrilinearTable t;
  const std::vector<iso::i32> sp = int32s(special, "special", 256);
  for (int c = 0; c < 256; ++c) t.special[c] = sp[c] != 0;
  t.entry = int32s(entry, "entry", 256 * 64);
  t.loops = int32s(loops, "loops");
  const std::size_t n = t.loops.size();
  t.corners = int32s(corners, "corners", 8 * n);
  t.disk = int32s(disk, "disk", 4 * n);
  t.tube = int32s(tube, "tube", 6 * n);
  t.piece_tris = int32s(piece_tris, "piece_tris");
  t.piece_inner = int32s(piece_inner, "piece_inner", t.piece_tris.size());
  t.tris = int32s(tris, "tris");
  t.inner = int32s(inner, "inner");
  const std::vector<iso::i32> ed = int32s(edges, "edges", 24);
  const std::vector<iso::i32> fc = int32s(face_corners, "faces", 24);
  for (int e = 0; e < 12; ++e) {
    t.edges[e][0] = ed[2 * e];
    t.edges[e][1] = ed[2 * e + 1];
    const int a = ed[2 * e], b = ed[2 * e + 1], x = a ^ b;
    if (a < 0 || a > 7 || b <= a || b > 7 || (x != 1 && x != 2 && x != 4)) bad("edges");
  }
  for (int f = 0; f < 6; ++f) {
    for (int q = 0; q < 4; ++q) {
      t.face_corners[f][q] = fc[4 * f + q];
      if (fc[4 * f + q] < 0 || fc[4 * f + q] > 7) bad("faces");
    }
  }
  for (const iso::i32 e : t.entry) {
    if (e < -1 || e >= iso::i32(n)) bad("entry out of range");
  }
  const iso::i64 pieces = iso::i64(t.piece_tris.size()) - 1;
  // the kernel packs 4 piece numbers of 15 bits in a word
  if (pieces < 0 || pieces >= (1 << 15) || t.piece_tris[0] != 0 || t.piece_inner[0] != 0) {
    bad("piece starts");
  }
  for (iso::i64 p = 0; p < pieces; ++p) {
    const iso::i32 t0 = t.piece_tris[p], t1 = t.piece_tris[p + 1];
    const iso::i32 i0 = t.piece_inner[p], i1 = t.piece_inner[p + 1];
    if (t1 < t0 || 3 * iso::i64(t1) > iso::i64(t.tris.size()) || i1 < i0 || i1 - i0 > 16 ||
        i1 > iso::i32(t.inner.size())) {
      bad("piece starts");
    }
    for (iso::i64 u = 3 * iso::i64(t0); u < 3 * iso::i64(t1); ++u) {
      if (t.tris[u] < 0 || t.tris[u] >= 12 + (i1 - i0)) bad("a triangle names no vertex");
    }
  }
  for (const iso::i32 mask : t.inner) {
    if (mask <= 0 || mask >= (1 << 12)) bad("interior vertex mask");
  }
  auto piece = [&](iso::i32 p) { return p >= 0 && p < pieces; };
  for (std::size_t e = 0; e < n; ++e) {
    const int l = t.loops[e];
    if (l < 1 || l > 4) bad("loops");
    for (int i = 0; i < l; ++i) {
      if (!piece(t.disk[4 * e + i])) bad("disk");
      for (int q = 0; q < 2; ++q) {
        if (t.corners[8 * e + 2 * i + q] < 0 || t.corners[8 * e + 2 * i + q] > 7) bad("corners");
      }
      for (int j = i + 1; j < l; ++j) {
        if (!piece(t.tube[6 * e + iso::loop_pair(i, j)])) bad("tube");
      }
    }
  }
  // (entries are in range by now) what the kernel reads beside them; then every
  // face decision a special configuration can take must have its entry
  iso::fill_derived(t);
  for (int c = 0; c < 256; ++c) {
    if (!t.special[c]) continue;
    for (int faces = 0; faces < 64; ++faces) {
      if (faces & ~int(t.ambiguous[c])) continue;
      const iso::i32 e = t.entry[64 * c + faces];
      if (e < 0 || e >= iso::i32(n)) bad("a reachable entry is missing");
    }
  }
  return t;
}

template <class T>
void bind_sample_type(nb::module_ &m) {
  m.def(
      "scan_rows",
      [](Samples3<T> f, double level, bool count_equal, double equal_to, int threads) {
        iso::RowScan s;
        nb::gil_scoped_release unlocked;
        iso::scan_rows<T>(f.data(), f.shape(0), f.shape(1), f.shape(2), level, count_equal,
                          equal_to, threads, s);
        return s;
      },
      "f"_a.noconvert(), "level"_a, "count_equal"_a, "equal_to"_a, "threads"_a);
  m.def(
      "count_cubes",
      [](Samples3<T> f, const iso::RowScan &s, Int64s counts, Int64s edges,
         const iso::TrilinearTable *trilinear, int threads) {
        check_shape(f, s);
        const iso::CubeTable table = cube_table(counts, edges);
        iso::CubesCount n;
        nb::gil_scoped_release unlocked;
        iso::count_cubes<T>(f.data(), s, table, trilinear, threads, n);
        return n;
      },
      "f"_a.noconvert(), "scan"_a, "counts"_a, "edges"_a, "trilinear"_a.none(), "threads"_a);
  m.def(
      "fill_cubes",
      [](Samples3<T> f, const iso::RowScan &s, const iso::CubesCount &n, Int64s counts,
         Int64s edges, const iso::TrilinearTable *trilinear, i64 inner_base, Doubles affine,
         Doubles origin, Int64s index_origin, Int64s id_dims, double offset, bool reverse,
         int threads, Out<double> verts, Out<i64> ids, Out<i64> tris, Doubles to_index,
         Doubles to_world, double sign, double slack, Out<float> normals, Samples3<T> halo,
         i64 halo_k0, i64 depth) {
        check_shape(f, s);
        if (i64(n.cy.size()) != s.rows()) {
          throw std::invalid_argument("counts are from another row scan");
        }
        if ((trilinear != nullptr) != (i64(n.found_at.size()) == s.rows()) && s.rows() > 0) {
          throw std::invalid_argument("counts were made with another ambiguity rule");
        }
        check_out(verts, n.vertices, 3, "verts");
        check_out(ids, n.vertices, 0, "ids");
        check_out(tris, n.triangles, 3, "tris");
        const iso::CubeTable table = cube_table(counts, edges);
        iso::Placement w = placement(affine, origin, index_origin, id_dims, offset, reverse);
        w.inner_base = inner_base;
        // normals: to_world (3, 3) asks for them (none: 0 values); their
        // stencils take the samples as the whole grid, so the block must be it
        iso::EdgeNormals edge_normals;
        std::atomic<i64> flat{0};
        std::atomic<bool> missing{false};
        const bool with_normals = to_world.size() != 0;
        if (with_normals) {
          check_out(normals, n.vertices, 3, "normals");
          if (to_index.size() != 9 || to_world.size() != 9) {
            throw std::invalid_argument("to_index and to_world are (3, 3)");
          }
          // a z-slab of the grid, inside its halo, inside the grid
          const i64 k0 = w.index_origin[2], layers = i64(halo.shape(0));
          if (w.index_origin[0] || w.index_origin[1] || w.id_dims[0] != s.nx ||
              w.id_dims[1] != s.ny || i64(halo.shape(1)) != s.ny ||
              i64(halo.shape(2)) != s.nx || halo_k0 < 0 || halo_k0 > k0 ||
              halo_k0 + layers < k0 + s.nz || halo_k0 + layers > depth) {
            throw std::invalid_argument("normals in the fill pass: a z-slab and its halo");
          }
          edge_normals.halo = halo.data();
          edge_normals.halo_layers = layers;
          edge_normals.halo_k0 = halo_k0;
          edge_normals.depth = depth;
          edge_normals.missing = &missing;
          for (int a = 0; a < 3; ++a) {
            edge_normals.map.origin[a] = origin.data()[a];
            for (int b = 0; b < 3; ++b) {
              edge_normals.map.to_index[a][b] = to_index.data()[3 * a + b];
              edge_normals.map.to_world[a][b] = to_world.data()[3 * a + b];
            }
          }
          edge_normals.map.sign = sign;
          edge_normals.map.normalize = true;
          edge_normals.slack = slack;
          edge_normals.out = normals.data();
          edge_normals.flat = &flat;
        }
        {
          nb::gil_scoped_release unlocked;
          iso::fill_cubes<T>(f.data(), s, table, trilinear, n, w, threads, verts.data(),
                             ids.data(), tris.data(), with_normals ? &edge_normals : nullptr);
        }
        if (missing.load()) {
          throw std::logic_error("fill_cubes: a normal's stencil left the slab's halo");
        }
        return flat.load();
      },
      "f"_a.noconvert(), "scan"_a, "n"_a, "counts"_a, "edges"_a, "trilinear"_a.none(),
      "inner_base"_a, "affine"_a, "origin"_a,
      "index_origin"_a, "id_dims"_a, "offset"_a, "reverse"_a, "threads"_a,
      "verts"_a.noconvert(), "ids"_a.noconvert(), "tris"_a.noconvert(), "to_index"_a,
      "to_world"_a, "sign"_a, "slack"_a, "normals"_a.noconvert(), "halo"_a.noconvert(),
      "halo_k0"_a, "depth"_a,
      "Fill the vertices, edge ids and triangles the counts call for. With to_index\n"
      "and to_world (3, 3) (empty for none; as sample_points takes them) also the\n"
      "unit normals (V, 3) float32 of the vertices on grid edges, as sample_points\n"
      "gives them at the vertices (0 where the gradient vanishes, NaN where it is\n"
      "not finite); interior vertices are left as they are. The stencils read `halo`,\n"
      "layers halo_k0.. of the grid's `depth` around the slab (f itself for the grid).\n"
      "Returns how many normals are 0 or NaN (0 without normals).");
}

}  // namespace

NB_MODULE(_native, m) {
  m.doc() = "Compiled extraction kernels of isoconvert (arrays in, arrays out).";

  nb::class_<iso::RowScan>(m, "RowScan", "Per-row trims and value statistics of a volume.")
      .def_ro("min", &iso::RowScan::min, "Smallest finite sample (inf when none).")
      .def_ro("max", &iso::RowScan::max, "Largest finite sample (-inf when none).")
      .def_ro("nonfinite", &iso::RowScan::nonfinite, "NaN and +-Inf samples.")
      .def_ro("equal", &iso::RowScan::equal, "Samples equal to the level, when counted.")
      .def_ro("level", &iso::RowScan::level);
  nb::class_<iso::CubesCount>(m, "CubesCount", "Per-row vertex and triangle counts.")
      .def_ro("vertices", &iso::CubesCount::vertices)
      .def_ro("triangles", &iso::CubesCount::triangles);

  nb::class_<iso::TrilinearTable>(
      m, "TrilinearTable",
      "The trilinear-topology cube table (isoconvert.extract.trilinear.kernel_table()).")
      .def_static("from_arrays", &trilinear_table, "special"_a, "entry"_a, "loops"_a,
                  "corners"_a, "disk"_a, "tube"_a, "piece_tris"_a, "piece_inner"_a, "tris"_a,
                  "inner"_a, "edges"_a, "face_corners"_a);

#define ISO_BIND(T) bind_sample_type<T>(m);
  ISO_FOR_EACH_SAMPLE_TYPE(ISO_BIND)
#undef ISO_BIND
  bind_tetra_squares(m);
  bind_report(m);
  bind_sample(m);
  bind_smooth(m);
  bind_labels(m);
  bind_normals(m);
  bind_distance(m);
  bind_rays(m);
  bind_graph(m);
  bind_precision(m);
  bind_cap(m);
}
