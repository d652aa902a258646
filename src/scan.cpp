// The first pass: one read of every sample (see rows.hpp).
#include "scan.hpp"

#include "signs.hpp"

#include <cstdlib>
#include <limits>
#include <string>

// An AVX2 first pass for float32, chosen at run time (float_row_avx2 below)
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define ISO_SCAN_AVX2 1
#include <immintrin.h>
#else
#define ISO_SCAN_AVX2 0
#endif

namespace iso {

namespace {

struct Partial {
  double min = std::numeric_limits<double>::infinity();
  double max = -std::numeric_limits<double>::infinity();
  i64 nonfinite = 0, equal = 0;
};

// Range and NaN/Inf count of a row of floating-point samples; NaN stays out
// of lo and hi, +-Inf does not (the caller redoes such rows). (v - v) is 0
// for finite v and NaN otherwise.
inline void float_range(const float *p, i64 nx, float &lo, float &hi, i64 &bad) {
  i64 k = 0;
#if defined(__SSE2__)
  __m128 vlo = _mm_set1_ps(lo), vhi = _mm_set1_ps(hi);
  __m128i vbad = _mm_setzero_si128();
  for (; k + 4 <= nx; k += 4) {
    const __m128 v = _mm_loadu_ps(p + k), d = _mm_sub_ps(v, v);
    vlo = _mm_min_ps(v, vlo);  // the second operand wins when v is NaN
    vhi = _mm_max_ps(v, vhi);
    vbad = _mm_sub_epi32(vbad, _mm_castps_si128(_mm_cmpunord_ps(d, d)));
  }
  alignas(16) float l[4], h[4];
  alignas(16) std::int32_t c[4];
  _mm_store_ps(l, vlo);
  _mm_store_ps(h, vhi);
  _mm_store_si128(reinterpret_cast<__m128i *>(c), vbad);
  for (int q = 0; q < 4; ++q) {
    lo = std::min(lo, l[q]);
    hi = std::max(hi, h[q]);
    bad += c[q];
  }
#endif
  for (; k < nx; ++k) {
    const float v = p[k];
    bad += !((v - v) == 0.0f);
    lo = v < lo ? v : lo;
    hi = v > hi ? v : hi;
  }
}

inline void float_range(const double *p, i64 nx, double &lo, double &hi, i64 &bad) {
  i64 k = 0;
#if defined(__SSE2__)
  __m128d vlo = _mm_set1_pd(lo), vhi = _mm_set1_pd(hi);
  __m128i vbad = _mm_setzero_si128();
  for (; k + 2 <= nx; k += 2) {
    const __m128d v = _mm_loadu_pd(p + k), d = _mm_sub_pd(v, v);
    vlo = _mm_min_pd(v, vlo);
    vhi = _mm_max_pd(v, vhi);
    vbad = _mm_sub_epi64(vbad, _mm_castpd_si128(_mm_cmpunord_pd(d, d)));
  }
  alignas(16) double l[2], h[2];
  alignas(16) std::int64_t c[2];
  _mm_store_pd(l, vlo);
  _mm_store_pd(h, vhi);
  _mm_store_si128(reinterpret_cast<__m128i *>(c), vbad);
  for (int q = 0; q < 2; ++q) {
    lo = std::min(lo, l[q]);
    hi = std::max(hi, h[q]);
    bad += c[q];
  }
#endif
  for (; k < nx; ++k) {
    const double v = p[k];
    bad += !((v - v) == 0.0);
    lo = v < lo ? v : lo;
    hi = v > hi ? v : hi;
  }
}

// How many of a row's samples equal `value`. The plain loop is not kept in
// vector lanes by the compiler (its count widens to 64 bits), and on float32
// volumes cost as much as the rest of the pass: floats compare four or two at
// a time here.
template <class T>
i64 count_equal_in_row(const T *p, i64 nx, T value) {
  i64 n = 0, k = 0;
#if defined(__SSE2__)
  if constexpr (std::is_same_v<T, float>) {
    const __m128 v = _mm_set1_ps(value);
    for (; k + 16 <= nx; k += 16) {
      unsigned m = 0;
      for (int q = 0; q < 16; q += 4) {
        m |= unsigned(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(p + k + q), v))) << q;
      }
      n += popcount(m);
    }
  } else if constexpr (std::is_same_v<T, double>) {
    const __m128d v = _mm_set1_pd(value);
    for (; k + 16 <= nx; k += 16) {
      unsigned m = 0;
      for (int q = 0; q < 16; q += 2) {
        m |= unsigned(_mm_movemask_pd(_mm_cmpeq_pd(_mm_loadu_pd(p + k + q), v))) << q;
      }
      n += popcount(m);
    }
  }
#endif
  for (; k < nx; ++k) n += p[k] == value;
  return n;
}

// Add a floating-point row's range and NaN/Inf count to `acc`. `lo` and `hi`
// came from a pass that keeps NaN out but lets +-Inf in: where the row has
// non-finite samples, the range is taken again from its finite ones.
template <class T>
void add_float_range(const T *p, i64 nx, T lo, T hi, i64 bad, Partial &acc) {
  if (bad) {
    lo = std::numeric_limits<T>::infinity();
    hi = -lo;
    for (i64 i = 0; i < nx; ++i) {
      const T v = p[i];
      if (std::isfinite(v)) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
  }
  acc.nonfinite += bad;
  acc.min = std::min(acc.min, static_cast<double>(lo));
  acc.max = std::max(acc.max, static_cast<double>(hi));
}

// Range, NaN/Inf and equal samples of one row; the loops are kept simple so
// that the compiler vectorizes them.
template <class T>
void row_values(const T *p, i64 nx, bool count_equal, T equal_to, Partial &acc) {
  if constexpr (std::is_floating_point_v<T>) {
    i64 bad = 0;
    T lo = std::numeric_limits<T>::infinity(), hi = -lo;
    float_range(p, nx, lo, hi, bad);
    add_float_range(p, nx, lo, hi, bad, acc);
  } else {
    T lo = p[0], hi = p[0];
    for (i64 i = 1; i < nx; ++i) {
      lo = std::min(lo, p[i]);
      hi = std::max(hi, p[i]);
    }
    acc.min = std::min(acc.min, static_cast<double>(lo));
    acc.max = std::max(acc.max, static_cast<double>(hi));
  }
  if (count_equal) acc.equal += count_equal_in_row(p, nx, equal_to);
}

// The signs of a row as bits (see RowScan::bits).
template <class T>
void pack_signs(const T *p, i64 nx, const Threshold<T> &pos, std::uint64_t *out) {
  const i64 full = nx / 64;
  for (i64 w = 0; w < full; ++w) {
    out[w] = pack64(p + 64 * w, pos);
  }
  if (full * 64 < nx) {
    std::uint64_t b = 0;
    for (i64 k = full * 64; k < nx; ++k) b |= std::uint64_t(pos(p[k])) << (k - full * 64);
    out[full] = b;
  }
}

#if ISO_SCAN_AVX2

// The whole first pass over a row of float32 samples (range, NaN/Inf count,
// equal samples and signs) in one loop of 8-sample AVX2 vectors, for CPUs that
// have them (chosen at run time): the SSE passes above are limited by
// instructions, not by memory, and this one takes about half their time.
// Same results bit for bit: it only compares.
__attribute__((target("avx2,popcnt"))) void float_row_avx2(const float *p, i64 nx,
                                                           float threshold, bool count_equal,
                                                           float equal_to, std::uint64_t *out,
                                                           Partial &acc) {
  const __m256 t = _mm256_set1_ps(threshold), e = _mm256_set1_ps(equal_to);
  __m256 vlo = _mm256_set1_ps(std::numeric_limits<float>::infinity());
  __m256 vhi = _mm256_set1_ps(-std::numeric_limits<float>::infinity());
  i64 bad = 0, equal = 0;
  const i64 full = nx / 64;
  for (i64 w = 0; w < full; ++w) {
    std::uint64_t signs = 0, nonfinite = 0, same = 0;
    for (int k = 0; k < 64; k += 8) {
      const __m256 v = _mm256_loadu_ps(p + 64 * w + k), d = _mm256_sub_ps(v, v);
      vlo = _mm256_min_ps(v, vlo);  // the second operand wins when v is NaN
      vhi = _mm256_max_ps(v, vhi);
      nonfinite |= std::uint64_t(_mm256_movemask_ps(_mm256_cmp_ps(d, d, _CMP_UNORD_Q))) << k;
      signs |= std::uint64_t(_mm256_movemask_ps(_mm256_cmp_ps(v, t, _CMP_GE_OQ))) << k;
      if (count_equal) {
        same |= std::uint64_t(_mm256_movemask_ps(_mm256_cmp_ps(v, e, _CMP_EQ_OQ))) << k;
      }
    }
    out[w] = signs;
    bad += __builtin_popcountll(nonfinite);
    equal += __builtin_popcountll(same);
  }
  alignas(32) float l[8], h[8];
  _mm256_store_ps(l, vlo);
  _mm256_store_ps(h, vhi);
  float lo = std::numeric_limits<float>::infinity(), hi = -lo;
  for (int q = 0; q < 8; ++q) {
    lo = std::min(lo, l[q]);
    hi = std::max(hi, h[q]);
  }
  std::uint64_t tail = 0;
  for (i64 k = full * 64; k < nx; ++k) {
    const float v = p[k];
    bad += !((v - v) == 0.0f);
    lo = v < lo ? v : lo;
    hi = v > hi ? v : hi;
    equal += count_equal && v == equal_to;
    tail |= std::uint64_t(v >= threshold) << (k - full * 64);
  }
  if (full * 64 < nx) out[full] = tail;
  acc.equal += equal;
  add_float_range(p, nx, lo, hi, bad, acc);
}

// ISOCONVERT_SIMD=sse2 keeps to the baseline passes (the tests compare both).
bool has_avx2() {
  static const bool yes = [] {
    const char *simd = std::getenv("ISOCONVERT_SIMD");
    return __builtin_cpu_supports("avx2") && !(simd && std::string(simd) == "sse2");
  }();
  return yes;
}
#endif

// The first pass over one row: range, NaN/Inf and equal counts into `acc`,
// signs into `out`.
template <class T>
void scan_row(const T *p, i64 nx, const Threshold<T> &pos, bool count_equal, T equal_to,
              std::uint64_t *out, Partial &acc) {
#if ISO_SCAN_AVX2
  if constexpr (std::is_same_v<T, float>) {
    if (has_avx2()) {
      float_row_avx2(p, nx, pos.value, count_equal, equal_to, out, acc);
      return;
    }
  }
#endif
  row_values(p, nx, count_equal, equal_to, acc);
  if (!pos.none) pack_signs(p, nx, pos, out);
}

}  // namespace

template <class T>
void scan_rows(const T *f, i64 nz, i64 ny, i64 nx, double level, bool count_equal,
               double equal_to, int threads, RowScan &s) {
  s.nz = nz;
  s.ny = ny;
  s.nx = nx;
  s.level = level;
  const i64 rows = nz * ny;
  s.xl.assign(rows, static_cast<i32>(nx - 1));
  s.xr.assign(rows, 0);
  s.cx.assign(rows, 0);
  const Threshold<T> pos(level);
  const T eq = count_equal ? static_cast<T>(equal_to) : T(0);
  const i64 words = (nx + 63) / 64;
  s.words = words;
  s.bits.assign(rows * words, 0);
  std::vector<Partial> parts(std::max(threads, 1));
  parallel_for(rows, threads, 64, [&](int w, i64 begin, i64 end) {
    Partial &acc = parts[w];
    for (i64 r = begin; r < end; ++r) {
      const T *p = f + r * nx;
      std::uint64_t *out = s.bits.data() + r * words;
      scan_row(p, nx, pos, count_equal, eq, out, acc);
      if (pos.none) continue;
      i32 n = 0;
      i64 first = -1, last = -1;
      for (i64 q = 0; q < words; ++q) {
        const std::uint64_t x = (out[q] ^ next_bits(out, words, q)) & below(nx - 1, q);
        if (!x) continue;
        n += popcount(x);
        if (first < 0) first = 64 * q + ctz(x);
        last = 64 * q + 63 - clz(x);
      }
      if (n == 0) continue;
      s.cx[r] = n;
      s.xl[r] = static_cast<i32>(first);
      s.xr[r] = static_cast<i32>(last + 1);
    }
  });
  s.min = std::numeric_limits<double>::infinity();
  s.max = -s.min;
  s.nonfinite = s.equal = 0;
  for (const Partial &p : parts) {
    s.min = std::min(s.min, p.min);
    s.max = std::max(s.max, p.max);
    s.nonfinite += p.nonfinite;
    s.equal += p.equal;
  }
}

#define ISO_SCAN(T)                                                                     \
  template void scan_rows<T>(const T *, i64, i64, i64, double, bool, double, int, \
                             RowScan &);
ISO_FOR_EACH_SAMPLE_TYPE(ISO_SCAN)
#undef ISO_SCAN

}  // namespace iso
