// isoconvert._native: the Python face of the kernels. Arrays come in already
// validated (isoconvert/extract/prepare.py); only shapes are re-checked here,
// since a wrong one would read out of bounds. The GIL is released while a
// kernel runs, so Python threads (batch jobs, Dask workers) run alongside.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <cstring>
#include <stdexcept>
#include <string>

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
      [](Samples3<T> f, const iso::RowScan &s, Int64s counts, Int64s edges, int threads) {
        check_shape(f, s);
        const iso::CubeTable table = cube_table(counts, edges);
        iso::CubesCount n;
        nb::gil_scoped_release unlocked;
        iso::count_cubes<T>(f.data(), s, table, threads, n);
        return n;
      },
      "f"_a.noconvert(), "scan"_a, "counts"_a, "edges"_a, "threads"_a);
  m.def(
      "fill_cubes",
      [](Samples3<T> f, const iso::RowScan &s, const iso::CubesCount &n, Int64s counts,
         Int64s edges, Doubles affine, Doubles origin, Int64s index_origin, Int64s id_dims,
         double offset, bool reverse, int threads, Out<double> verts, Out<i64> ids,
         Out<i64> tris) {
        check_shape(f, s);
        if (i64(n.cy.size()) != s.rows()) {
          throw std::invalid_argument("counts are from another row scan");
        }
        check_out(verts, n.vertices, 3, "verts");
        check_out(ids, n.vertices, 0, "ids");
        check_out(tris, n.triangles, 3, "tris");
        const iso::CubeTable table = cube_table(counts, edges);
        const iso::Placement w = placement(affine, origin, index_origin, id_dims, offset, reverse);
        nb::gil_scoped_release unlocked;
        iso::fill_cubes<T>(f.data(), s, table, n, w, threads, verts.data(), ids.data(),
                           tris.data());
      },
      "f"_a.noconvert(), "scan"_a, "n"_a, "counts"_a, "edges"_a, "affine"_a, "origin"_a,
      "index_origin"_a, "id_dims"_a, "offset"_a, "reverse"_a, "threads"_a,
      "verts"_a.noconvert(), "ids"_a.noconvert(), "tris"_a.noconvert());
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

#define ISO_BIND(T) bind_sample_type<T>(m);
  ISO_FOR_EACH_SAMPLE_TYPE(ISO_BIND)
#undef ISO_BIND
  bind_tetra_squares(m);
  bind_report(m);
  bind_sample(m);
  bind_smooth(m);
  bind_labels(m);
  bind_normals(m);
}
