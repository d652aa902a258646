// Marching Squares, of a 2D image or of every slice of a volume across one
// axis, in the manner of Flying Edges (see rows.hpp and squares.cpp).
#pragma once

#include "placement.hpp"
#include "rows.hpp"

namespace iso {

// A Marching Squares table for both fixed ambiguity rules (index 0: separate
// positive corners, 1: separate negative corners), from
// isoconvert/extract/tables.py: per configuration (bit c = square corner c =
// u + 2v positive) up to two segments as (start, end) square edges (0, 1 along
// u at v = 0, 1; 2, 3 along v at u = 0, 1), positive corners on their left.
// Both rules have the same number of segments per configuration.
struct SquareTable {
  std::int8_t count[16];
  std::int8_t edges[2][16][4];
};

// Ambiguity rules of fill_squares: the two of SquareTable, and the asymptotic
// decider (the saddle value of the bilinear interpolant decides per square).
enum SquareRule : int { SEPARATE_POSITIVE = 0, SEPARATE_NEGATIVE = 1, ASYMPTOTIC = 2 };

struct SquaresCount {
  int axis = 2;  // the slices are across x (0), y (1) or z (2)
  // per row r = j + NY * k: bipolar in-plane edges starting on it, first and
  // second group (across z: x then y; across y: x then z; across x: y then
  // z), and segments of the squares it is the lowest row of
  std::vector<i32> a, b, segments;
  i64 vertices = 0, total_segments = 0;
};

template <class T>
void count_squares(const T *f, const RowScan &s, const SquareTable &table, int axis, int threads,
                   SquaresCount &out);

// verts (V, 3), ids (V,), segs (C, 2), sized from `counts`. `planar`: f is a
// 2D image as (1, Y, X) (axis 2), and ids are 2 * (i + NX * j) + axis (x 0,
// y 1) instead of 3 * (i + NX * (j + NY * k)) + axis.
template <class T>
void fill_squares(const T *f, const RowScan &s, const SquareTable &table,
                  const SquaresCount &counts, int rule, bool planar, const Placement &where,
                  int threads, double *verts, i64 *ids, i64 *segs);

}  // namespace iso
