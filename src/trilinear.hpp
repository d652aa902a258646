// Marching Cubes with the topology of the trilinear interpolant
// (`--ambiguity trilinear`): the decisions one cube needs, on its 8 values.
//
// The argument, the tables and a Python reference of every step below are in
// isoconvert/extract/trilinear.py; the kernel reads the tables that module
// flattens (kernel_table()) and repeats its tests in the same operand order,
// so the two give the same pieces for the same values.
#pragma once

#include <algorithm>
#include <vector>

#include "common.hpp"

namespace iso {

// trilinear.kernel_table(), plus the cube's edges and faces it is built on.
struct TrilinearTable {
  std::uint8_t special[256];  // configurations that take the tests below
  std::vector<i32> entry;     // (256 * 64,) row of 64 * config + faces
  std::vector<i32> loops;     // (E,) loops on the cube's boundary
  std::vector<i32> corners;   // (E, 4, 2) positive, negative corner of each loop
  std::vector<i32> disk;      // (E, 4) piece spanning each loop
  std::vector<i32> tube;      // (E, 6) piece joining each loop pair (0,1), (0,2), ... (2,3)
  std::vector<i32> piece_tris, piece_inner;  // (P + 1,) starts into tris, inner
  std::vector<i32> tris;                     // (T, 3) cube edges, 12 + interior slot
  std::vector<i32> inner;                    // (I,) edge mask of each interior vertex
  i32 edges[12][2];                          // tables.CUBE_EDGES
  i32 face_corners[6][4];                    // trilinear.FACE_CORNERS (00, 10, 01, 11)
  // derived by fill_derived: per configuration, the bit mask of its
  // ambiguous faces; (E, 2, 8) per entry and sign, each corner's component on
  // the cube's boundary (boundary_labels)
  std::uint8_t ambiguous[256];
  std::vector<std::uint8_t> boundary;
};

// Whether face f's diagonal corners share signs in `config` (an ambiguous face).
inline bool ambiguous_face(const TrilinearTable &t, unsigned config, int f) {
  const i32 *c = t.face_corners[f];
  auto sign = [&](int q) { return (config >> c[q]) & 1; };
  return sign(0) == sign(3) && sign(1) == sign(2) && sign(0) != sign(1);
}

// Corners of sign s are joined in `label[s]` (a component's corners share a label).
inline void join_corners(std::uint8_t (&label)[2][8], int s, int a, int b) {
  const std::uint8_t keep = label[s][a], gone = label[s][b];
  if (keep == gone) return;
  for (auto &l : label[s]) {
    if (l == gone) l = keep;
  }
}

// The corners each sign joins on the cube's boundary under face decisions
// `faces`: along edges of one sign, and across ambiguous faces (a face bit
// set joins the positive diagonal, else the negative one).
inline void boundary_labels(const TrilinearTable &t, unsigned config, int faces,
                            std::uint8_t (&label)[2][8]) {
  auto sign = [&](int c) { return int((config >> c) & 1); };
  for (int c = 0; c < 8; ++c) label[0][c] = label[1][c] = std::uint8_t(c);
  for (const auto &edge : t.edges) {
    if (sign(edge[0]) == sign(edge[1])) join_corners(label, sign(edge[0]), edge[0], edge[1]);
  }
  for (int m = t.ambiguous[config]; m; m &= m - 1) {
    const int f = ctz(std::uint64_t(m));
    const i32 *c = t.face_corners[f];
    const int s = (faces >> f) & 1;  // the sign whose corners the face joins
    if (sign(c[0]) == s) {
      join_corners(label, s, c[0], c[3]);
    } else {
      join_corners(label, s, c[1], c[2]);
    }
  }
}

// Fill t.ambiguous, then t.boundary from t.entry (every entry's configuration and faces).
inline void fill_derived(TrilinearTable &t) {
  for (int c = 0; c < 256; ++c) {
    t.ambiguous[c] = 0;
    for (int f = 0; f < 6; ++f) t.ambiguous[c] |= std::uint8_t(ambiguous_face(t, c, f) << f);
  }
  t.boundary.assign(16 * t.loops.size(), 0);
  for (int key = 0; key < 256 * 64; ++key) {
    const i32 e = t.entry[key];
    if (e < 0) continue;
    std::uint8_t label[2][8];
    boundary_labels(t, unsigned(key >> 6), key & 63, label);
    std::copy(&label[0][0], &label[0][0] + 16, t.boundary.begin() + 16 * e);
  }
}

// Index of loop pair (i, j), i < j, in the order of trilinear.LOOP_PAIRS.
inline int loop_pair(int i, int j) { return i * (7 - i) / 2 + (j - i - 1); }

// The pieces (disks and tubes) of surface in one special cube, written to
// `pieces`; returns how many. v: the corner values by cube vertex
// (x + 2 y + 4 z); config: their signs (bit v: v[v] >= level).
inline int trilinear_pieces(const TrilinearTable &t, const double (&v)[8], unsigned config,
                            double level, int (&pieces)[4]) {
  // 1. faces: the asymptotic decider on each ambiguous face
  int faces = 0;
  for (int m = t.ambiguous[config]; m; m &= m - 1) {
    const int f = ctz(std::uint64_t(m));
    const i32 *c = t.face_corners[f];
    if (asymptotic_joins_positive(v[c[0]], v[c[1]], v[c[2]], v[c[3]], level)) faces |= 1 << f;
  }
  const i32 e = t.entry[64 * config + faces];
  const int n = t.loops[e];
  if (n == 1) {  // one loop is one disk, whatever the inside joins
    pieces[0] = t.disk[4 * e];
    return 1;
  }
  // 2. the corners each sign's set joins: on the boundary (as the table has
  // them for these face decisions), and through the inside (the z-sweep)
  std::uint8_t label[2][8];
  std::copy(t.boundary.begin() + 16 * e, t.boundary.begin() + 16 * e + 16, &label[0][0]);
  auto join = [&](int s, int a, int b) { join_corners(label, s, a, b); };
  double bottom[4], slope[4];
  for (int q = 0; q < 4; ++q) {
    bottom[q] = v[q] - level;
    slope[q] = (v[q + 4] - level) - bottom[q];
  }
  // plane heights where a z-edge changes sign: the intervals' ends
  double ts[6];
  int nts = 0;
  ts[nts++] = 0.0;
  for (int q = 0; q < 4; ++q) {
    const double top = v[q + 4] - level;
    if ((bottom[q] >= 0) != (top >= 0)) {
      const double x = bottom[q] / (bottom[q] - top);
      if (x > 0.0 && x < 1.0) ts[nts++] = x;
    }
  }
  ts[nts++] = 1.0;
  std::sort(ts, ts + nts);
  nts = int(std::unique(ts, ts + nts) - ts);
  for (int s = 0; s + 1 < nts; ++s) {
    const double lo = ts[s], hi = ts[s + 1], mid = 0.5 * (lo + hi);
    bool pos[4];
    for (int q = 0; q < 4; ++q) pos[q] = bottom[q] + mid * slope[q] >= 0;
    if (!(pos[0] == pos[3] && pos[1] == pos[2] && pos[0] != pos[1])) continue;
    const double sigma = pos[0] ? 1.0 : -1.0;
    const double *a = bottom, *b = slope;
    const double qa = a[0] * a[3] - a[1] * a[2];
    const double qb = a[0] * b[3] + a[3] * b[0] - a[1] * b[2] - a[2] * b[1];
    const double qc = b[0] * b[3] - b[1] * b[2];
    double hi_val = -std::numeric_limits<double>::infinity(), lo_val = -hi_val;
    auto at = [&](double x) {
      const double y = sigma * (qa + x * (qb + x * qc));
      hi_val = std::max(hi_val, y);
      lo_val = std::min(lo_val, y);
    };
    at(lo);
    at(hi);
    if (qc != 0.0) {
      const double vertex = -qb / (2.0 * qc);
      if (lo < vertex && vertex < hi) at(vertex);
    }
    // plane corner q stands for z-edge q; it holds one end of each sign
    auto corner = [&](int q, int sgn) { return ((bottom[q] >= 0) == (sgn == 1)) ? q : q + 4; };
    const int pa = pos[0] ? 0 : 1, pb = pos[0] ? 3 : 2;  // the positive diagonal
    const int na = pos[0] ? 1 : 0, nb = pos[0] ? 2 : 3;  // the negative one
    if (hi_val >= 0) join(1, corner(pa, 1), corner(pb, 1));
    if (lo_val < 0) join(0, corner(na, 0), corner(nb, 0));
  }
  // 3. loops that wall off the same (positive, negative) pair of pieces are
  // one surface: a tube for two, a disk for one (more never happens for a
  // trilinear level set; the disks are kept, as the reference does)
  const i32 *cs = t.corners.data() + 8 * e;
  int key[4], group[4], count = 0;
  for (int i = 0; i < n; ++i) key[i] = label[1][cs[2 * i]] + 8 * label[0][cs[2 * i + 1]];
  for (int i = 0; i < n; ++i) group[i] = -1;
  for (int i = 0; i < n; ++i) {
    if (group[i] >= 0) continue;
    int members[4], m = 0;
    for (int j = i; j < n; ++j) {
      if (key[j] == key[i]) members[m++] = j;
    }
    for (int q = 0; q < m; ++q) group[members[q]] = i;
    if (m == 2) {
      pieces[count++] = t.tube[6 * e + loop_pair(members[0], members[1])];
    } else {
      for (int q = 0; q < m; ++q) pieces[count++] = t.disk[4 * e + members[q]];
    }
  }
  return count;
}

}  // namespace iso
