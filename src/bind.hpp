// What the bindings of every kernel share (module.cpp, more.cpp): array types,
// the shape checks that keep a kernel inside its arrays, and the placement.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "placement.hpp"
#include "rows.hpp"

namespace iso::bind {

namespace nb = nanobind;

template <class T>
using Samples3 = nb::ndarray<const T, nb::ndim<3>, nb::c_contig, nb::device::cpu>;
using Int64s = nb::ndarray<const i64, nb::c_contig, nb::device::cpu>;
using Doubles = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;

// Output arrays are allocated by the caller (numpy backs large ones with huge
// pages, which makes their first write several times cheaper) and filled here.
template <class T>
using Out = nb::ndarray<T, nb::c_contig, nb::device::cpu>;

// A numpy array that owns `v` (moved to the heap): (n,) or (n / cols, cols).
template <class T, class A>
nb::object give(std::vector<T, A> &&v, size_t cols = 0) {
  auto *heap = new std::vector<T, A>(std::move(v));
  nb::capsule owner(heap, [](void *p) noexcept { delete static_cast<std::vector<T, A> *>(p); });
  const size_t shape[2] = {cols ? heap->size() / cols : heap->size(), cols};
  return nb::cast(nb::ndarray<nb::numpy, T>(heap->data(), cols ? 2 : 1, shape, owner));
}

template <class T>
void check_out(const Out<T> &a, i64 rows, i64 cols, const char *name) {
  const bool ok = cols ? (a.ndim() == 2 && i64(a.shape(0)) == rows && i64(a.shape(1)) == cols)
                       : (a.ndim() == 1 && i64(a.shape(0)) == rows);
  if (!ok) throw std::invalid_argument(std::string(name) + " has the wrong shape for the counts");
}

template <class T>
void check_shape(const Samples3<T> &f, const RowScan &s) {
  if (i64(f.shape(0)) != s.nz || i64(f.shape(1)) != s.ny || i64(f.shape(2)) != s.nx) {
    throw std::invalid_argument("samples and row scan have different shapes");
  }
  // the row trims (rows.hpp) take rows of at least two samples
  if (s.nx < 2) throw std::invalid_argument("rows need at least 2 samples along x");
}

inline Placement placement(const Doubles &affine, const Doubles &origin, const Int64s &index_origin,
                         const Int64s &id_dims, double offset, bool reverse) {
  if (affine.size() != 9 || origin.size() != 3 || index_origin.size() != 3 ||
      id_dims.size() != 2) {
    throw std::invalid_argument("placement: affine (3, 3), origin (3,), index_origin (3,), "
                                "id_dims (2,)");
  }
  Placement w;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) w.affine[a][b] = affine.data()[3 * a + b];
    w.origin[a] = origin.data()[a];
    w.index_origin[a] = index_origin.data()[a];
  }
  w.id_dims[0] = id_dims.data()[0];
  w.id_dims[1] = id_dims.data()[1];
  w.offset = offset;
  w.reverse = reverse;
  return w;
}

}  // namespace iso::bind
