// Shared pieces of the kernels: sample types, threads, interpolation.
//
// Kernels take arrays and scalars only; every check on the input happens in
// Python before they run (isoconvert/extract/prepare.py).
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <new>

#if defined(__linux__)
#include <sys/mman.h>
#endif
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

inline i64 chunk_count(i64 n, i64 grain) { return (n + grain - 1) / grain; }

// An uninitialized array (a std::vector would first write zeros over it, on
// one thread: as long as the parallel pass that fills it). Memory comes from
// malloc, in ordinary pages: where the kernel has to compact memory to find
// huge pages, as on the development machine busy with other work, a first
// write to 100 MB in huge pages took 0.1 to 0.2 s of system time, against
// about 0.05 s in ordinary pages.
//
// Pages::huge asks for transparent huge pages instead (as numpy does for its
// large arrays): for buffers that every pass of a loop rereads (the smoothing
// filters'), a first write in 4 kB pages, a fault every 4 kB, cost more than
// the work of a pass.
enum class Pages { ordinary, huge };

template <class T>
class Buffer {
 public:
  // zeroed: from calloc, whose fresh pages are zero without a pass over them
  explicit Buffer(i64 n, bool zeroed = false, Pages pages = Pages::ordinary) {
    allocate(n, zeroed, pages);
  }
  ~Buffer() { std::free(p_); }
  Buffer(const Buffer &) = delete;
  Buffer &operator=(const Buffer &) = delete;
  T *data() { return p_; }
  const T *data() const { return p_; }
  T &operator[](i64 i) { return p_[i]; }
  const T &operator[](i64 i) const { return p_[i]; }
  i64 size() const { return n_; }
  // Drops the contents and holds n uninitialized elements instead.
  void reset(i64 n, Pages pages = Pages::ordinary) {
    std::free(p_);
    p_ = nullptr;
    allocate(n, false, pages);
  }

  // Hands the memory over (to be freed with std::free).
  T *release() {
    T *p = p_;
    p_ = nullptr;
    return p;
  }

 private:
  T *p_ = nullptr;
  i64 n_ = 0;

  void allocate(i64 n, bool zeroed, Pages pages) {
    n_ = std::max<i64>(n, 0);
    const size_t bytes = std::max<size_t>(size_t(n_) * sizeof(T), 1);
#if defined(MADV_HUGEPAGE)
    constexpr size_t kHuge = size_t(1) << 21;
    if (pages == Pages::huge && !zeroed && bytes >= kHuge) {
      void *p = nullptr;
      if (posix_memalign(&p, kHuge, bytes) != 0) throw std::bad_alloc();
      madvise(p, bytes, MADV_HUGEPAGE);  // a hint: without it, ordinary pages
      p_ = static_cast<T *>(p);
      return;
    }
#else
    (void)pages;
#endif
    p_ = static_cast<T *>(zeroed ? std::calloc(bytes, 1) : std::malloc(bytes));
    if (!p_) throw std::bad_alloc();
  }
};

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
template <class Each, class Entry>
void fill_buckets(i64 n_items, i64 n_buckets, Each &&each, std::vector<i64> &offsets,
                  std::vector<Entry> &entries) {
  offsets.assign(n_buckets + 1, 0);
  for (i64 k = 0; k < n_items; ++k) each(k, [&](i64 b) { ++offsets[b + 1]; });
  for (i64 b = 0; b < n_buckets; ++b) offsets[b + 1] += offsets[b];
  entries.resize(offsets[n_buckets]);
  std::vector<i64> fill(offsets.begin(), offsets.end() - 1);
  for (i64 k = 0; k < n_items; ++k) each(k, [&](i64 b) { entries[fill[b]++] = Entry(k); });
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
