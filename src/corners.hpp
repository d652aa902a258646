// What the passes that walk around each vertex of a triangle mesh share (the
// report's topology in report.cpp, the smoothing stencil in smooth.cpp): the
// corners grouped by vertex, and a union-find threads can share.
#pragma once

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <utility>

#include "common.hpp"

namespace iso {

template <class C>
inline bool is_repeated(const C *c) {
  return c[0] == c[1] || c[1] == c[2] || c[0] == c[2];
}

// A union-find shared by threads: every link goes from a larger root to a
// smaller one (by compare-and-swap), so parent[x] <= x always holds, no
// cycle can form, and each component ends up rooted at its smallest vertex
// whatever the order of the unions. Path halving writes only ancestors.
template <class I>
struct SharedForest {
  I *parent;

  I find(I x) const {
    for (;;) {
      const I p = __atomic_load_n(parent + x, __ATOMIC_RELAXED);
      if (p == x) return x;
      const I g = __atomic_load_n(parent + p, __ATOMIC_RELAXED);
      if (g != p) __atomic_store_n(parent + x, g, __ATOMIC_RELAXED);
      x = g;
    }
  }

  // Unites the trees of a and b; returns the root of the union (at the
  // time). Passing a root as a (a vertex's last answer) saves a walk.
  I join(I a, I b) const {
    b = find(b);
    for (;;) {
      a = find(a);
      if (a == b) return a;
      if (a > b) std::swap(a, b);
      I expected = b;
      if (__atomic_compare_exchange_n(parent + b, &expected, a, false, __ATOMIC_RELAXED,
                                      __ATOMIC_RELAXED)) {
        return a;
      }
      b = find(b);
    }
  }
};

// Bit p of the result is set when a[p] == w, for p < 4 * groups (a padded).
template <class I>
inline unsigned matches(const I *a, I w, int groups) {
  unsigned m = 0;
  for (int p = 0; p < 4 * groups; ++p) m |= unsigned(a[p] == w) << p;
  return m;
}
#if defined(__SSE2__)
template <>
inline unsigned matches<std::int32_t>(const std::int32_t *a, std::int32_t w, int groups) {
  const __m128i x = _mm_set1_epi32(w);
  unsigned m = 0;
  for (int g = 0; g < groups; ++g) {
    const __m128i y = _mm_load_si128(reinterpret_cast<const __m128i *>(a + 4 * g));
    m |= unsigned(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(x, y)))) << (4 * g);
  }
  return m;
}
#endif

// Corners (3 t + j: corner j of triangle t) grouped by vertex, in compressed
// rows: v's corners are corner[offset[v] .. offset[v + 1]], in ascending
// order. Triangles with a repeated vertex are left out (they are no 2-cells).
// tv (nt, 3) holds vertices in 0..nv-1; I holds every vertex and corner
// number; offset has nv + 1 elements, corner is resized here.
template <class I, class C>
void corners_by_vertex(const C *tv, i64 nt, i64 nv, int threads, Buffer<I> &offset,
                       Buffer<I> &corner) {
  // The triangles are cut into a few parts, each counted by one thread into counters of its
  // own (no atomics, one read of the cells per pass); within a vertex the
  // parts' corners follow one another, so every vertex lists its corners in
  // ascending order whatever the number of threads.
  const i64 parts = std::max<i64>(1, std::min<i64>({i64(threads), i64(4), nt}));
  auto first_triangle = [nt, parts](i64 p) { return nt * p / parts; };
  Buffer<I> at(parts * nv, true);  // at[p * nv + v]: part p's corners at v, then where they go
  parallel_for(parts, threads, 1, [&](int, i64 p0, i64 p1) {
    for (i64 p = p0; p < p1; ++p) {
      I *count = at.data() + p * nv;
      for (i64 t = first_triangle(p); t < first_triangle(p + 1); ++t) {
        const C *c = tv + 3 * t;
        if (is_repeated(c)) continue;
        ++count[c[0]];
        ++count[c[1]];
        ++count[c[2]];
      }
    }
  });
  {
    i64 total = 0;
    for (i64 v = 0; v < nv; ++v) {
      offset[v] = static_cast<I>(total);
      for (i64 p = 0; p < parts; ++p) {
        const i64 n = at[p * nv + v];
        at[p * nv + v] = static_cast<I>(total);
        total += n;
      }
    }
    offset[nv] = static_cast<I>(total);
  }
  corner.reset(offset[nv]);
  parallel_for(parts, threads, 1, [&](int, i64 p0, i64 p1) {
    for (i64 p = p0; p < p1; ++p) {
      I *cursor = at.data() + p * nv;
      for (i64 t = first_triangle(p); t < first_triangle(p + 1); ++t) {
        const C *c = tv + 3 * t;
        if (is_repeated(c)) continue;
        for (int j = 0; j < 3; ++j) corner[cursor[c[j]]++] = static_cast<I>(3 * t + j);
      }
    }
  });
}

}  // namespace iso
