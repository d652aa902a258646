// Connected components of a graph given as edge lists (isoconvert/graph.py):
// union-find, the larger root always linked under the smaller, so each root
// is the smallest node of its component. numpy's rounds of hooking and
// pointer jumping took 50 ms per call on a 300k-vertex surface, and the
// post-processing steps call it several times.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <stdexcept>
#include <vector>

#include "bind.hpp"
#include "common.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;

namespace {

using namespace iso::bind;

inline i64 find(i64 *parent, i64 x) {
  while (parent[x] != x) {
    parent[x] = parent[parent[x]];  // path halving
    x = parent[x];
  }
  return x;
}

void components(i64 n, const i64 *u, const i64 *v, i64 m, i64 *labels) {
  for (i64 i = 0; i < n; ++i) labels[i] = i;
  for (i64 e = 0; e < m; ++e) {
    const i64 a = find(labels, u[e]), b = find(labels, v[e]);
    if (a < b) {
      labels[b] = a;
    } else if (b < a) {
      labels[a] = b;
    }
  }
  // roots are smaller than every other node of their tree, so one pass in
  // increasing order resolves each node through an already resolved parent
  for (i64 i = 0; i < n; ++i) labels[i] = labels[labels[i]];
}

}  // namespace

void bind_graph(nb::module_ &m) {
  m.def(
      "connected_components",
      [](i64 n, Int64s u, Int64s v, Out<i64> labels) {
        if (n < 0 || u.ndim() != 1 || v.ndim() != 1 || u.shape(0) != v.shape(0)) {
          throw std::invalid_argument("connected_components: n >= 0, u and v (E,) alike");
        }
        check_out(labels, n, 0, "labels");
        const i64 e = i64(u.shape(0));
        for (i64 k = 0; k < e; ++k) {
          if (u.data()[k] < 0 || u.data()[k] >= n || v.data()[k] < 0 || v.data()[k] >= n) {
            throw std::invalid_argument("connected_components: an edge end is not a node");
          }
        }
        nb::gil_scoped_release unlocked;
        components(n, u.data(), v.data(), e, labels.data());
      },
      "n"_a, "u"_a, "v"_a, "labels"_a.noconvert(),
      "For each node, the smallest node of its component.");
}
