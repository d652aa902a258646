// Shared pieces of the kernels: sample types, threads, interpolation.
//
// Kernels take arrays and scalars only; every check on the input happens in
// Python before they run (isoconvert/extract/prepare.py).
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <thread>
#include <type_traits>
#include <vector>

namespace iso {

using i64 = std::int64_t;
using i32 = std::int32_t;

// Where `level` lies between samples s0 and s1 (of opposite signs), as a
// fraction of the edge from s0, clamped to [offset, 1 - offset]
// (Wenger, Algorithm 1.1). Near the largest doubles s1 - s0 overflows; the
// same ratio is then taken at half scale.
inline double edge_fraction(double s0, double s1, double level, double offset) {
  const double d = s1 - s0;
  double t;
  if (std::isfinite(d)) {
    t = (level - s0) / d;
  } else {
    t = (0.5 * level - 0.5 * s0) / (0.5 * s1 - 0.5 * s0);
  }
  return std::min(std::max(t, offset), 1.0 - offset);
}

// The asymptotic decider (Nielson and Hamann 1991; book section 2.2.5): on a
// square with corner values f (00, 10, 01, 11: the lower in-plane axis first)
// whose diagonal corners share signs, the bilinear interpolant joins the
// positive corners when its saddle value is >= level. Marching Squares'
// `asymptotic` rule and Marching Cubes' `trilinear` faces both call this one
// test, in this operand order, so a slice and a cube cut a grid face alike.
inline bool asymptotic_joins_positive(double f00, double f10, double f01, double f11,
                                      double level) {
  const double saddle = (f00 * f11 - f10 * f01) / (f00 + f11 - f10 - f01);
  return saddle >= level;
}

inline int popcount(std::uint64_t x) { return __builtin_popcountll(x); }
inline int ctz(std::uint64_t x) { return __builtin_ctzll(x); }  // x != 0
inline int clz(std::uint64_t x) { return __builtin_clzll(x); }  // x != 0

// Run fn(worker, begin, end) over [0, n) in chunks of `grain`, on `threads`
// threads (the calling one included), handing out chunks as threads free up.
// Results must not depend on which thread ran which chunk: every kernel writes
// to places fixed beforehand by prefix sums.
template <class F>
void parallel_for(i64 n, int threads, i64 grain, F &&fn) {
  grain = std::max<i64>(grain, 1);
  const i64 chunks = (n + grain - 1) / grain;
  threads = static_cast<int>(std::max<i64>(1, std::min<i64>(threads, chunks)));
  if (threads == 1) {
    if (n > 0) fn(0, i64(0), n);
    return;
  }
  std::atomic<i64> next{0};
  auto work = [&](int worker) {
    for (;;) {
      const i64 begin = next.fetch_add(grain);
      if (begin >= n) break;
      fn(worker, begin, std::min(n, begin + grain));
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int w = 1; w < threads; ++w) pool.emplace_back(work, w);
  work(0);
  for (auto &t : pool) t.join();
}

// Compressed rows of items by bucket (the spatial grids of distance.cpp and
// rays.cpp): `each(item, emit)` calls `emit(bucket)` for every bucket the item
// is listed in, the same ones each time it is called; bucket b then holds
// entries[offsets[b] .. offsets[b + 1]], its items in increasing order.
template <class Each>
void fill_buckets(i64 n_items, i64 n_buckets, Each &&each, std::vector<i64> &offsets,
                  std::vector<i64> &entries) {
  offsets.assign(n_buckets + 1, 0);
  for (i64 k = 0; k < n_items; ++k) each(k, [&](i64 b) { ++offsets[b + 1]; });
  for (i64 b = 0; b < n_buckets; ++b) offsets[b + 1] += offsets[b];
  entries.resize(offsets[n_buckets]);
  std::vector<i64> fill(offsets.begin(), offsets.end() - 1);
  for (i64 k = 0; k < n_items; ++k) each(k, [&](i64 b) { entries[fill[b]++] = k; });
}

// A grid vertex is positive when its value is >= the level (Definition 2.1).
// For each sample type the test is done in that type against the smallest
// sample value that is >= level, which gives the same answer as comparing in
// float64 and lets the compiler vectorize the comparison.
template <class T>
struct Threshold {
  T value{};
  bool none = false;  // no sample of this type is >= level

  explicit Threshold(double level) {
    if constexpr (std::is_floating_point_v<T>) {
      const T v = static_cast<T>(level);  // round to nearest
      if (static_cast<double>(v) >= level) {
        value = v;
      } else {
        value = std::nextafter(v, std::numeric_limits<T>::infinity());
      }
    } else {
      const double up = std::ceil(level);
      if (up > static_cast<double>(std::numeric_limits<T>::max())) {
        none = true;
        value = std::numeric_limits<T>::max();
      } else if (up <= static_cast<double>(std::numeric_limits<T>::min())) {
        value = std::numeric_limits<T>::min();
      } else {
        value = static_cast<T>(up);
      }
    }
  }
  bool operator()(T v) const { return !none && v >= value; }
};

}  // namespace iso
