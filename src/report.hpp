// Kernels of the mesh report (isoconvert/report.py).
//
// Three passes answer every question of the report on a triangle mesh:
//
// 1. merge_positions: vertices at bitwise-equal positions (after -0.0 -> 0.0)
//    share a representative, the smallest index among them, found by hash
//    buckets that stay in cache. Each vertex also gets a key that orders the
//    distinct positions as isoconvert.graph.row_groups does (by a 64-bit hash
//    of the position, or lexicographically when two positions share a hash):
//    the report orders its examples by it, as it always has.
// 2. triangle_pass: each triangle's representatives (only needed when some
//    positions merged: otherwise the cells are their own representatives),
//    the total of twice the areas, and the lists of repeated-position
//    triangles, possibly flat ones and zero-length edges.
// 3. topology: corners (triangle, vertex) grouped by vertex in a CSR table
//    (count, prefix sum, fill: O(n), no sort of the whole mesh). Around each
//    vertex the corners' two edges, grouped by their other end, give every
//    edge's multiplicity at its lower end, the orientation of each edge used
//    twice, duplicate triangles, the fans (corners joined across edges used
//    exactly twice) and the components (a concurrent union-find).
//
// Vertex ids are representatives (input indices), not merged numbers, so a
// mesh written in extraction order keeps its memory locality in every pass.
// The index type I is int32 when vertex and corner counts allow (half the
// memory traffic), else int64. Results never depend on the thread count:
// lists are gathered per fixed chunk and joined in chunk order, sums of
// floats are taken in a fixed order. Kernels take arrays and scalars; the
// cells' indices are checked in Python first.
#pragma once

#include <cstdint>
#include <vector>

#include "common.hpp"

namespace iso::report {

using u8 = std::uint8_t;
using u64 = std::uint64_t;

struct Merged {
  i64 unique = 0;              // number of distinct positions
  bool lexicographic = false;  // two positions shared a hash: keys are lexicographic ranks
  double magnitude = 0.0;      // the largest absolute finite coordinate (0 when none)
};

// key (n,): the position's hash (equal for equal positions), or its rank in
// lexicographic order when two different positions share a hash;
// rep (n,): the smallest index of a vertex at the same position.
template <class I>
Merged merge_positions(const double *xyz, i64 n, int threads, u64 *key, I *rep);

struct TriangleLists {
  std::vector<i64> repeated;         // triangles with a repeated position, ascending
  std::vector<i64> flat_candidates;  // other triangles with |cross| <= flat_below
  std::vector<i64> collapsed;        // (k, 2): input edges whose ends merged (lower index first)
};

// tv (nt, 3), unless null: representatives of each corner. Returns the sum of
// |(p1 - p0) x (p2 - p0)| (twice the area) over the triangles, each computed
// and all summed as numpy's cross, norm and sum do (same operations, same
// order), so to the bit.
template <class I, class C>
double triangle_pass(const C *cells, i64 nt, const I *rep, const double *xyz,
                     double flat_below, int threads, I *tv, TriangleLists &out);

struct Topology {
  i64 edges = 0, used = 0, kept = 0;
  // (k, 2) edges as (lower, higher) vertex, ordered by lower vertex (then as
  // met around it: the same order on any number of threads)
  std::vector<i64> boundary, non_manifold_edges, inconsistent;
  std::vector<i64> non_manifold_vertices, fans;  // ascending vertex
  // duplicate triangles: groups of triangles with the same three vertices,
  // ordered by their two lowest vertices, triangles ascending in a group;
  // group g is dup_triangles[dup_starts[g]:dup_starts[g + 1]]
  std::vector<i64> dup_triangles, dup_starts;
  // components of the used vertices, in order of their smallest vertex
  std::vector<i64> comp_vertices, comp_edges, comp_triangles;
  std::vector<u64> comp_min_key;
  std::vector<u8> comp_open, comp_bad;
  // every edge and its multiplicity, when asked for (tests, other tools)
  std::vector<i64> all_edges, all_counts;
};

// tv (nt, 3): the triangles' vertices, of type C (the input's cells when no
// positions merged, else representatives), in 0..nv-1; I, the index
// type inside, holds every vertex and corner number. Triangles with a
// repeated vertex are skipped (they are no 2-cells). used (nv,): 1 where a
// kept triangle uses the vertex. key (nv,) from merge_positions: each
// component's smallest key is reported.
template <class I, class C>
void topology(const C *tv, i64 nt, i64 nv, const u64 *key, int threads, bool all_edges, u8 *used,
              Topology &out);

// Sum over triangles of det[p0 - c, p1 - c, p2 - c] / 6, c the mean used position.
template <class C>
double enclosed_volume(const double *xyz, const C *tv, i64 nt, const u8 *used, i64 nv,
                       int threads);

}  // namespace iso::report
