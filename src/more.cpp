// Bindings of the Marching Tetrahedra and Marching Squares kernels (see
// module.cpp for the conventions: arrays come in validated, only shapes and
// tables are re-checked here, and the GIL is released while a kernel runs).
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <cstring>
#include <stdexcept>
#include <string>

#include "bind.hpp"
#include "scan.hpp"
#include "squares.hpp"
#include "tetra.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

bool has_shape(const Int64s &a, std::initializer_list<size_t> shape) {
  if (a.ndim() != shape.size()) return false;
  size_t d = 0;
  for (size_t n : shape) {
    if (a.shape(d++) != n) return false;
  }
  return true;
}

// The Marching Tetrahedra tables of isoconvert/extract/tables.py, checked
// against the conventions of tetra.hpp and folded into one table per cube
// configuration.
iso::TetraTable tetra_table(const Int64s &dirs, const Int64s &tets, const Int64s &counts,
                            const Int64s &triangles, const Int64s &edge_base,
                            const Int64s &edge_dir) {
  if (!has_shape(dirs, {7, 3}) || !has_shape(tets, {6, 4}) || !has_shape(counts, {96}) ||
      !has_shape(triangles, {96, 2, 3}) || !has_shape(edge_base, {19, 3}) ||
      !has_shape(edge_dir, {19})) {
    throw std::invalid_argument(
        "tetra tables: dirs (7, 3), tets (6, 4), counts (96,), triangles (96, 2, 3), "
        "edge_base (19, 3), edge_dir (19,)");
  }
  for (int d = 0; d < 7; ++d) {
    const i64 *v = dirs.data() + 3 * d;
    if (v[0] != iso::TETRA_DX[d] || v[1] != iso::TETRA_DY[d] || v[2] != iso::TETRA_DZ[d]) {
      throw std::invalid_argument("tetra directions are not x, y, z, xy, xz, yz, xyz");
    }
  }
  iso::TetraTable t;
  std::memset(&t, 0, sizeof t);
  for (int m = 0; m < 19; ++m) {
    const i64 d = edge_dir.data()[m];
    const i64 *b = edge_base.data() + 3 * m;
    if (d < 0 || d > 6) throw std::invalid_argument("tetra edge direction out of range");
    const i64 end[3] = {b[0] + iso::TETRA_DX[d], b[1] + iso::TETRA_DY[d],
                        b[2] + iso::TETRA_DZ[d]};
    for (int a = 0; a < 3; ++a) {
      if (b[a] < 0 || end[a] > 1) throw std::invalid_argument("tetra edge leaves the cube");
    }
    t.dir[m] = static_cast<std::int8_t>(d);
    t.row[m] = static_cast<std::int8_t>(b[1] + 2 * b[2]);
    t.dx[m] = static_cast<std::int8_t>(b[0]);
  }
  for (i64 q = 0; q < 24; ++q) {
    if (tets.data()[q] < 0 || tets.data()[q] > 7) {
      throw std::invalid_argument("tetrahedron corner out of range");
    }
  }
  for (int config = 0; config < 256; ++config) {
    int n = 0;
    for (int k = 0; k < 6; ++k) {
      int tc = 0;
      for (int q = 0; q < 4; ++q) tc |= ((config >> tets.data()[4 * k + q]) & 1) << q;
      const i64 entry = 16 * k + tc, nt = counts.data()[entry];
      if (nt < 0 || nt > 2) throw std::invalid_argument("tetra table count out of range");
      for (i64 q = 0; q < 3 * nt; ++q) {
        const i64 e = triangles.data()[6 * entry + q];
        if (e < 0 || e > 18) throw std::invalid_argument("tetra table edge out of range");
        t.edges[config][3 * n + q] = static_cast<std::int8_t>(e);
        t.used[config] |= std::uint32_t(1) << e;
      }
      n += static_cast<int>(nt);
    }
    t.count[config] = static_cast<std::int8_t>(n);
  }
  return t;
}

// The Marching Squares tables of both fixed rules.
iso::SquareTable square_table(const Int64s &counts, const Int64s &segments) {
  if (!has_shape(counts, {16}) || !has_shape(segments, {2, 16, 2, 2})) {
    throw std::invalid_argument("a squares table is (16,) counts and (2, 16, 2, 2) segments");
  }
  iso::SquareTable t;
  std::memset(&t, 0, sizeof t);
  for (int c = 0; c < 16; ++c) {
    const i64 n = counts.data()[c];
    if (n < 0 || n > 2) throw std::invalid_argument("squares table count out of range");
    t.count[c] = static_cast<std::int8_t>(n);
    for (int rule = 0; rule < 2; ++rule) {
      const i64 *q = segments.data() + 4 * (16 * rule + c);
      for (i64 m = 0; m < 4; ++m) {
        const bool used = m < 2 * n;
        if (used != (q[m] >= 0) || q[m] > 3) {
          throw std::invalid_argument("squares table edges do not match its counts");
        }
        t.edges[rule][c][m] = static_cast<std::int8_t>(used ? q[m] : 0);
      }
    }
  }
  return t;
}


template <class T>
void bind_sample_type(nb::module_ &m) {
  m.def(
      "count_tetra",
      [](Samples3<T> f, const iso::RowScan &s, Int64s dirs, Int64s tets, Int64s counts,
         Int64s triangles, Int64s edge_base, Int64s edge_dir, int threads) {
        check_shape(f, s);
        const iso::TetraTable table =
            tetra_table(dirs, tets, counts, triangles, edge_base, edge_dir);
        iso::TetraCount n;
        nb::gil_scoped_release unlocked;
        iso::count_tetra<T>(f.data(), s, table, threads, n);
        return n;
      },
      "f"_a.noconvert(), "scan"_a, "dirs"_a, "tets"_a, "counts"_a, "triangles"_a,
      "edge_base"_a, "edge_dir"_a, "threads"_a);
  m.def(
      "fill_tetra",
      [](Samples3<T> f, const iso::RowScan &s, const iso::TetraCount &n, Int64s dirs,
         Int64s tets, Int64s counts, Int64s triangles, Int64s edge_base, Int64s edge_dir,
         Doubles affine, Doubles origin, Int64s index_origin, Int64s id_dims, double offset,
         bool reverse, int threads, Out<double> verts, Out<i64> ids, Out<i64> tris) {
        check_shape(f, s);
        if (i64(n.rows.size()) != s.rows()) {
          throw std::invalid_argument("counts are from another row scan");
        }
        const iso::TetraTable table =
            tetra_table(dirs, tets, counts, triangles, edge_base, edge_dir);
        const iso::Placement w = placement(affine, origin, index_origin, id_dims, offset, reverse);
        check_out(verts, n.vertices, 3, "verts");
        check_out(ids, n.vertices, 0, "ids");
        check_out(tris, n.triangles, 3, "tris");
        nb::gil_scoped_release unlocked;
        iso::fill_tetra<T>(f.data(), s, table, n, w, threads, verts.data(), ids.data(),
                           tris.data());
      },
      "f"_a.noconvert(), "scan"_a, "n"_a, "dirs"_a, "tets"_a, "counts"_a, "triangles"_a,
      "edge_base"_a, "edge_dir"_a, "affine"_a, "origin"_a, "index_origin"_a, "id_dims"_a,
      "offset"_a, "reverse"_a, "threads"_a, "verts"_a.noconvert(), "ids"_a.noconvert(),
      "tris"_a.noconvert());
  m.def(
      "count_squares",
      [](Samples3<T> f, const iso::RowScan &s, int axis, Int64s counts, Int64s segments,
         int threads) {
        check_shape(f, s);
        if (axis < 0 || axis > 2) throw std::invalid_argument("axis must be 0, 1 or 2");
        const iso::SquareTable table = square_table(counts, segments);
        iso::SquaresCount n;
        nb::gil_scoped_release unlocked;
        iso::count_squares<T>(f.data(), s, table, axis, threads, n);
        return n;
      },
      "f"_a.noconvert(), "scan"_a, "axis"_a, "counts"_a, "segments"_a, "threads"_a);
  m.def(
      "fill_squares",
      [](Samples3<T> f, const iso::RowScan &s, const iso::SquaresCount &n, int axis,
         Int64s counts, Int64s segments, int rule, bool planar, Doubles affine, Doubles origin,
         Int64s index_origin, Int64s id_dims, double offset, bool reverse, int threads,
         Out<double> verts, Out<i64> ids, Out<i64> segs) {
        check_shape(f, s);
        if (i64(n.a.size()) != s.rows() || n.axis != axis) {
          throw std::invalid_argument("counts are from another row scan or axis");
        }
        if (rule < 0 || rule > 2) throw std::invalid_argument("rule must be 0, 1 or 2");
        const iso::SquareTable table = square_table(counts, segments);
        const iso::Placement w = placement(affine, origin, index_origin, id_dims, offset, reverse);
        if (planar && (axis != 2 || s.nz != 1 || w.index_origin[2] != 0)) {
          throw std::invalid_argument("a planar image is one slice (1, Y, X) across z");
        }
        check_out(verts, n.vertices, 3, "verts");
        check_out(ids, n.vertices, 0, "ids");
        check_out(segs, n.total_segments, 2, "segs");
        nb::gil_scoped_release unlocked;
        iso::fill_squares<T>(f.data(), s, table, n, rule, planar, w, threads, verts.data(),
                             ids.data(), segs.data());
      },
      "f"_a.noconvert(), "scan"_a, "n"_a, "axis"_a, "counts"_a, "segments"_a, "rule"_a,
      "planar"_a, "affine"_a, "origin"_a, "index_origin"_a, "id_dims"_a, "offset"_a,
      "reverse"_a, "threads"_a, "verts"_a.noconvert(), "ids"_a.noconvert(),
      "segs"_a.noconvert());
}

}  // namespace

void bind_tetra_squares(nb::module_ &m) {
  nb::class_<iso::TetraCount>(m, "TetraCount", "Per-row vertex and triangle counts of tetra.")
      .def_ro("vertices", &iso::TetraCount::vertices)
      .def_ro("triangles", &iso::TetraCount::triangles);
  nb::class_<iso::SquaresCount>(m, "SquaresCount", "Per-row vertex and segment counts of squares.")
      .def_ro("axis", &iso::SquaresCount::axis)
      .def_ro("vertices", &iso::SquaresCount::vertices)
      .def_ro("segments", &iso::SquaresCount::total_segments);

#define ISO_BIND(T) bind_sample_type<T>(m);
  ISO_FOR_EACH_SAMPLE_TYPE(ISO_BIND)
#undef ISO_BIND
}
