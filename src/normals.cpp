// Area-weighted vertex normals of a triangle mesh (Mesh.vertex_normals): the
// sum of the unnormalized cross products of the triangles around each vertex
// (|cross| is twice a triangle's area), made unit length. One pass, serial:
// triangles add into shared vertices, and a serial sum keeps the result the
// same bits on every machine.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <cmath>
#include <stdexcept>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

void bind_normals(nb::module_ &m) {
  using namespace iso::bind;
  m.def(
      "vertex_normals",
      [](Doubles vertices, Int64s cells, Out<double> out) {
        if (vertices.ndim() != 2 || vertices.shape(1) != 3 || cells.ndim() != 2 ||
            cells.shape(1) != 3) {
          throw std::invalid_argument("vertex_normals: vertices (V, 3), cells (C, 3)");
        }
        const i64 nv = i64(vertices.shape(0)), nc = i64(cells.shape(0));
        check_out(out, nv, 3, "out");
        const i64 *t = cells.data();
        for (i64 k = 0; k < 3 * nc; ++k) {
          if (t[k] < 0 || t[k] >= nv) throw std::invalid_argument("a cell refers to no vertex");
        }
        const double *v = vertices.data();
        double *n = out.data();
        nb::gil_scoped_release unlocked;
        for (i64 k = 0; k < 3 * nv; ++k) n[k] = 0.0;
        for (i64 c = 0; c < nc; ++c) {
          const double *a = v + 3 * t[3 * c], *b = v + 3 * t[3 * c + 1], *d = v + 3 * t[3 * c + 2];
          const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
          const double e2[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
          const double cross[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                                   e1[0] * e2[1] - e1[1] * e2[0]};
          for (int corner = 0; corner < 3; ++corner) {
            double *target = n + 3 * t[3 * c + corner];
            for (int a3 = 0; a3 < 3; ++a3) target[a3] += cross[a3];
          }
        }
        for (i64 i = 0; i < nv; ++i) {
          double *x = n + 3 * i;
          const double length = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
          if (length > 0.0) {
            for (int a3 = 0; a3 < 3; ++a3) x[a3] /= length;
          }
        }
      },
      "vertices"_a, "cells"_a, "out"_a.noconvert(),
      "Unit area-weighted vertex normals into out (V, 3); zero where no triangle has area.");
}
