#pragma once

#include "rows.hpp"

// The sample types the kernels are compiled for (Python converts bool to
// uint8 and 64-bit integers to float64 before calling them).
#define ISO_FOR_EACH_SAMPLE_TYPE(X) \
  X(std::uint8_t)                   \
  X(std::int8_t)                    \
  X(std::uint16_t)                  \
  X(std::int16_t)                   \
  X(std::uint32_t)                  \
  X(std::int32_t)                   \
  X(float)                          \
  X(double)

namespace iso {

// Fill `s` from the (nz, ny, nx) C-ordered samples `f`; see rows.hpp.
// `equal_to` is counted when `count_equal` (the caller knows it is a value of T).
template <class T>
void scan_rows(const T *f, i64 nz, i64 ny, i64 nx, double level, bool count_equal,
               double equal_to, int threads, RowScan &s);

}  // namespace iso
