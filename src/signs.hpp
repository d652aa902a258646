// Packing the signs of 64 samples into one word (bit q: sample q >= level).
//
// On x86-64 the comparison runs on SSE2 vectors (part of every x86-64 CPU) and
// movemask gathers one bit per lane; elsewhere a plain loop does it. Integers
// are compared in the signed domain SSE2 has (unsigned ones after flipping
// their top bit), as "not (threshold > v)".
#pragma once

#include "common.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace iso {

template <class T>
inline std::uint64_t pack64_plain(const T *p, const Threshold<T> &pos) {
  std::uint64_t b = 0;
  for (int k = 0; k < 64; ++k) b |= std::uint64_t(p[k] >= pos.value) << k;
  return b;
}

#if defined(__SSE2__)

inline std::uint64_t pack64(const float *p, const Threshold<float> &pos) {
  const __m128 t = _mm_set1_ps(pos.value);
  std::uint64_t b = 0;
  for (int k = 0; k < 64; k += 4) {
    b |= std::uint64_t(_mm_movemask_ps(_mm_cmpge_ps(_mm_loadu_ps(p + k), t))) << k;
  }
  return b;
}

inline std::uint64_t pack64(const double *p, const Threshold<double> &pos) {
  const __m128d t = _mm_set1_pd(pos.value);
  std::uint64_t b = 0;
  for (int k = 0; k < 64; k += 2) {
    b |= std::uint64_t(_mm_movemask_pd(_mm_cmpge_pd(_mm_loadu_pd(p + k), t))) << k;
  }
  return b;
}

// 8-bit: v >= t exactly when max(v, t) == v (unsigned); signed ones shifted by 128
template <class T>
inline std::uint64_t pack64_bytes(const T *p, std::uint8_t t8, std::uint8_t flip) {
  const __m128i t = _mm_set1_epi8(static_cast<char>(t8)), f = _mm_set1_epi8(static_cast<char>(flip));
  std::uint64_t b = 0;
  for (int k = 0; k < 64; k += 16) {
    const __m128i v = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p + k)), f);
    b |= std::uint64_t(std::uint16_t(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(v, t), v))))
         << k;
  }
  return b;
}
inline std::uint64_t pack64(const std::uint8_t *p, const Threshold<std::uint8_t> &pos) {
  return pack64_bytes(p, pos.value, 0);
}
inline std::uint64_t pack64(const std::int8_t *p, const Threshold<std::int8_t> &pos) {
  return pack64_bytes(p, static_cast<std::uint8_t>(pos.value) ^ 0x80, 0x80);
}

// 16-bit: two vectors of "t > v" packed to bytes, then inverted
template <class T>
inline std::uint64_t pack64_shorts(const T *p, std::int16_t t16, std::uint16_t flip) {
  const __m128i t = _mm_set1_epi16(t16), f = _mm_set1_epi16(static_cast<short>(flip));
  std::uint64_t below = 0;
  for (int k = 0; k < 64; k += 16) {
    const __m128i a = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p + k)), f);
    const __m128i c =
        _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p + k + 8)), f);
    const __m128i m = _mm_packs_epi16(_mm_cmpgt_epi16(t, a), _mm_cmpgt_epi16(t, c));
    below |= std::uint64_t(std::uint16_t(_mm_movemask_epi8(m))) << k;
  }
  return ~below;
}
inline std::uint64_t pack64(const std::uint16_t *p, const Threshold<std::uint16_t> &pos) {
  return pack64_shorts(p, static_cast<std::int16_t>(pos.value ^ 0x8000), 0x8000);
}
inline std::uint64_t pack64(const std::int16_t *p, const Threshold<std::int16_t> &pos) {
  return pack64_shorts(p, pos.value, 0);
}

// 32-bit integers: "t > v" per lane, four bits at a time
template <class T>
inline std::uint64_t pack64_ints(const T *p, std::int32_t t32, std::uint32_t flip) {
  const __m128i t = _mm_set1_epi32(t32), f = _mm_set1_epi32(static_cast<int>(flip));
  std::uint64_t below = 0;
  for (int k = 0; k < 64; k += 4) {
    const __m128i v = _mm_xor_si128(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p + k)), f);
    below |= std::uint64_t(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmpgt_epi32(t, v)))) << k;
  }
  return ~below;
}
inline std::uint64_t pack64(const std::uint32_t *p, const Threshold<std::uint32_t> &pos) {
  return pack64_ints(p, static_cast<std::int32_t>(pos.value ^ 0x80000000u), 0x80000000u);
}
inline std::uint64_t pack64(const std::int32_t *p, const Threshold<std::int32_t> &pos) {
  return pack64_ints(p, pos.value, 0);
}

#else

template <class T>
inline std::uint64_t pack64(const T *p, const Threshold<T> &pos) {
  return pack64_plain(p, pos);
}

#endif

}  // namespace iso
