// Rows of samples along x, the unit of work of every kernel (Flying Edges,
// Schroeder, Maynard and Geveci, IEEE LDAV 2015).
//
// A volume (Z, Y, X) is nz * ny rows; row r = j + ny * k holds samples
// (0..nx-1, j, k). The first pass (scan.cpp) reads every sample once: it finds,
// per row, how many of its x-edges are bipolar and the interval where they lie
// (the trim), and gathers the value range, NaN/Inf and samples equal to the
// level on the way. Later passes look at a group of neighbouring rows only
// between their trims, where anything can happen; outside it all rows are
// constant along x, so either every cube there is cut in the same way (the
// rows' signs differ; the trim then widens to the whole row) or none is.
#pragma once

#include <vector>

#include "common.hpp"

namespace iso {

struct RowScan {
  i64 nz = 0, ny = 0, nx = 0;
  double level = 0.0;
  // the sign of every sample, one bit each: row r's samples 64 w .. 64 w + 63
  // in bits[r * words + w], sample 64 w + q in bit q; bits past nx are 0
  i64 words = 0;
  std::vector<std::uint64_t> bits;
  // per row: first bipolar x-edge (nx - 1 when none), one past the last (0
  // when none), number of bipolar x-edges
  std::vector<i32> xl, xr, cx;
  // finite value range (min > max when no sample is finite), NaN/Inf samples,
  // samples equal to the level (when asked for)
  double min = 0.0, max = 0.0;
  i64 nonfinite = 0, equal = 0;

  i64 rows() const { return nz * ny; }
  const std::uint64_t *row_bits(i64 r) const { return bits.data() + r * words; }
  bool sign(i64 r, i64 i) const { return (row_bits(r)[i >> 6] >> (i & 63)) & 1; }
};

// Bit masks of word w of a row: positions that are samples (< nx), and
// positions that start an x-edge or a cube (< nx - 1).
inline std::uint64_t below(i64 n, i64 w) {
  const i64 m = n - 64 * w;
  return m >= 64 ? ~std::uint64_t(0) : m <= 0 ? 0 : (std::uint64_t(1) << m) - 1;
}

// Bits of word w shifted down by one: bit q tells the sign at position q + 1.
inline std::uint64_t next_bits(const std::uint64_t *row, i64 words, i64 w) {
  return (row[w] >> 1) | (w + 1 < words ? row[w + 1] << 63 : 0);
}

// The interval [lo, hi] of positions along x outside which N rows are constant and have equal signs: the
// union of their trims, widened to the row's end when their signs differ
// there. Returns false when the rows have no bipolar edge at all.
template <int N>
inline bool trim(const RowScan &s, const i64 (&rows)[N], i64 &lo, i64 &hi) {
  const i64 nx = s.nx;
  lo = nx - 1;
  hi = 0;
  const bool first = s.sign(rows[0], 0), last = s.sign(rows[0], nx - 1);
  bool same_first = true, same_last = true;
  for (int b = 0; b < N; ++b) {
    lo = std::min<i64>(lo, s.xl[rows[b]]);
    hi = std::max<i64>(hi, s.xr[rows[b]]);
    same_first = same_first && s.sign(rows[b], 0) == first;
    same_last = same_last && s.sign(rows[b], nx - 1) == last;
  }
  if (!same_first) lo = 0;
  if (!same_last) hi = nx - 1;
  return lo < hi;
}

// Run fn(j, k, r) for every row r = j + ny k, on `threads` threads. Rows go
// in chunks of 32: enough work per chunk, and neighbouring rows (which share
// samples) stay on one thread.
template <class F>
void for_each_row(const RowScan &s, int threads, F &&fn) {
  parallel_for(s.rows(), threads, 32, [&](int, i64 begin, i64 end) {
    for (i64 r = begin; r < end; ++r) fn(r % s.ny, r / s.ny, r);
  });
}

}  // namespace iso
