// Surface Nets of label volumes (isoconvert/extract/labels.py, which documents
// the method and the rules for non-manifold configurations): the scan for the
// labels present, the net (quads, vertices split per sheet, smoothing) and the
// per-label meshes.
//
// The net is built per dual cell. A vertex is one sheet of the quads around a
// dual cell, and which quads form a sheet depends only on the cell's 2x2x2 block
// of samples (and on the rare "flipped" rings of the Python reference), so one
// sweep over the blocks finds every vertex, its sheet of quads and its stencil
// without sorting the quads' 4Q corners by dual edge. The outputs are the same
// arrays, in the same order, as the numpy formulation this replaced: quads in
// the order of np.nonzero over an (X, Y, Z) array (axis, then interior / low
// side / high side, then (i, j, k) lexicographically), vertices numbered by
// their first quad corner in that order, stencil neighbours summed in the
// order np.bincount summed them. Work is split by y ranges of dual cells,
// each writing places fixed beforehand by prefix sums: the output does not
// depend on the number of threads.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <stdexcept>
#include <utility>
#include <vector>

#include "bind.hpp"
#include "common.hpp"
#include "scan.hpp"

namespace nb = nanobind;
using namespace nb::literals;
using iso::i32;
using iso::i64;

namespace {

using namespace iso::bind;
using u8 = std::uint8_t;
using u16 = std::uint16_t;
using u32 = std::uint32_t;
using u64 = std::uint64_t;

// A std::vector that leaves its elements uninitialized on resize: the big
// arrays are filled by parallel passes, and zeroing them first would be a
// serial pass over the same memory.
template <class T>
struct NoInit : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = NoInit<U>;
  };
  NoInit() = default;
  template <class U>
  NoInit(const NoInit<U> &) {}
  template <class U>
  void construct(U *p) noexcept {
    ::new (static_cast<void *>(p)) U;
  }
  template <class U, class... A>
  void construct(U *p, A &&...a) {
    ::new (static_cast<void *>(p)) U(std::forward<A>(a)...);
  }
};
template <class T>
using Vec = std::vector<T, NoInit<T>>;

// Label values as int64 (float samples were checked to be whole numbers
// within +-2^53 in Python, so the conversion is exact).
template <class T>
inline i64 key(T v) {
  return static_cast<i64>(v);
}

// --- the labels present -------------------------------------------------------------------

// Presence of every value of a volume. For 8- and 16-bit samples a histogram
// (no sort); otherwise the range first and, when it is small enough, a table
// of it; `present` stays empty when the range is too wide (Python then sorts).
struct Presence {
  double min = 0, max = 0;
  i64 bad = 0;  // float samples that are not whole numbers or not finite
  bool listed = false;
  std::vector<i64> present;
};

constexpr i64 kTableLimit = i64(1) << 22;  // values spanned by a presence or index table

template <class T>
void label_presence(const T *f, i64 n, int threads, Presence &out) {
  const i64 grain = std::max<i64>(i64(1) << 18, n / (8 * std::max(threads, 1)) + 1);
  const int workers = std::max(1, threads);
  if constexpr (std::is_integral_v<T> && sizeof(T) <= 2) {
    constexpr i64 span = i64(1) << (8 * sizeof(T));
    std::vector<std::vector<u8>> seen(workers, std::vector<u8>(span, 0));
    iso::parallel_for(n, threads, grain, [&](int w, i64 b, i64 e) {
      u8 *s = seen[w].data();
      for (i64 i = b; i < e; ++i) s[i64(f[i]) - i64(std::numeric_limits<T>::min())] = 1;
    });
    for (i64 v = 0; v < span; ++v) {
      bool any = false;
      for (int w = 0; w < workers; ++w) any |= seen[w][v] != 0;
      if (any) out.present.push_back(v + i64(std::numeric_limits<T>::min()));
    }
    out.listed = true;
    if (!out.present.empty()) {
      out.min = double(out.present.front());
      out.max = double(out.present.back());
    }
    return;
  } else {
    std::vector<double> lo(workers, std::numeric_limits<double>::infinity());
    std::vector<double> hi(workers, -std::numeric_limits<double>::infinity());
    std::vector<i64> bad(workers, 0);
    iso::parallel_for(n, threads, grain, [&](int w, i64 b, i64 e) {
      double a = lo[w], z = hi[w];
      i64 wrong = 0;
      for (i64 i = b; i < e; ++i) {
        const double v = double(f[i]);
        if constexpr (std::is_floating_point_v<T>) {
          // NaN and +-Inf fail the first test, fractions the second
          if (!(std::abs(v) <= 9007199254740992.0) || v != std::round(v)) {
            ++wrong;
            continue;
          }
        }
        a = std::min(a, v);
        z = std::max(z, v);
      }
      bad[w] += wrong;
      lo[w] = a;
      hi[w] = z;
    });
    out.min = *std::min_element(lo.begin(), lo.end());
    out.max = *std::max_element(hi.begin(), hi.end());
    for (int w = 0; w < workers; ++w) out.bad += bad[w];
    if (out.bad || !(out.max - out.min < double(kTableLimit))) return;
    const i64 base = i64(out.min), span = i64(out.max) - base + 1;
    std::vector<std::vector<u8>> seen(workers, std::vector<u8>(span, 0));
    iso::parallel_for(n, threads, grain, [&](int w, i64 b, i64 e) {
      u8 *s = seen[w].data();
      for (i64 i = b; i < e; ++i) s[key(f[i]) - base] = 1;
    });
    for (i64 v = 0; v < span; ++v) {
      bool any = false;
      for (int w = 0; w < workers; ++w) any |= seen[w][v] != 0;
      if (any) out.present.push_back(v + base);
    }
    out.listed = true;
  }
}

// Each of 0..n-1 numbered in the order it first comes in v[0..count) (rank[i] stays
// -1 where it never does), and, with `renumbered`, each v[k] replaced by its rank
// there (it may be v itself): label_net's vertices by their first quad corner, and
// the slabs' merge (first_use_numbering). Serial, as the order is the first use; the
// rank of an index a few ahead is fetched meanwhile (the indices are scattered).
inline void first_use_ranks(const i64 *v, i64 count, i64 *rank, i64 *renumbered = nullptr) {
  constexpr i64 kAhead = 16;
  i64 next = 0;
  for (i64 k = 0; k < count; ++k) {
    if (k + kAhead < count) __builtin_prefetch(rank + v[k + kAhead], 1);
    i64 &r = rank[v[k]];
    if (r < 0) r = next++;
    if (renumbered) renumbered[k] = r;
  }
}

// --- blocks of 2x2x2 samples ------------------------------------------------------------------

// Sample o = ox + 2 oy + 4 oz of a dual cell's block is at (x - 1 + ox, ...).
// Face f = 4 a + ou + 2 ov lies across axis a between the samples at offsets
// (ou, ov) along the axes u = a + 1, v = a + 2 (mod 3) that follow a.
// Ring d = 2 b + side: the four samples at offset `side` along b around the
// dual edge along b (side 1: to the next dual cell, 0: from the previous one);
// its samples q00, q10, q11, q01 and gaps 0 (q00|q10), 1 (q10|q11),
// 2 (q11|q01), 3 (q01|q00), with q_st at offsets (s, t) along the two other
// axes, s < t: the numbering of the Python reference's pairing rule.
struct Tables {
  int face_lo[12], face_hi[12];
  int mid2[12][3];  // twice face f's centre, relative to the dual cell's centre: -1, 0, 1
  int gap_face[6][4];
  int ring[6][4];
};

Tables make_tables() {
  Tables t{};
  auto sample = [](const int off[3]) { return off[0] + 2 * off[1] + 4 * off[2]; };
  auto face_of = [](int a, const int off[3]) {
    return 4 * a + off[(a + 1) % 3] + 2 * off[(a + 2) % 3];
  };
  for (int a = 0; a < 3; ++a) {
    for (int ov = 0; ov < 2; ++ov) {
      for (int ou = 0; ou < 2; ++ou) {
        int off[3];
        off[a] = 0;
        off[(a + 1) % 3] = ou;
        off[(a + 2) % 3] = ov;
        const int f = face_of(a, off);
        t.face_lo[f] = sample(off);
        t.face_hi[f] = sample(off) + (1 << a);
        for (int k = 0; k < 3; ++k) t.mid2[f][k] = k == a ? 0 : 2 * off[k] - 1;
      }
    }
  }
  for (int b = 0; b < 3; ++b) {
    const int s = b == 0 ? 1 : 0, u = b == 2 ? 1 : 2;  // the other axes, s < u
    for (int side = 0; side < 2; ++side) {
      const int d = 2 * b + side;
      const int qs[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
      for (int q = 0; q < 4; ++q) {
        int off[3];
        off[b] = side;
        off[s] = qs[q][0];
        off[u] = qs[q][1];
        t.ring[d][q] = sample(off);
      }
      // gap 0: across s at t = 0; 1: across t at s = 1; 2: across s at t = 1; 3: across t at s = 0
      const int across[4] = {s, u, s, u};
      const int at[4] = {0, 1, 1, 0};
      for (int g = 0; g < 4; ++g) {
        int off[3];
        off[b] = side;
        off[across[g]] = 0;
        off[across[g] == s ? u : s] = at[g];
        t.gap_face[d][g] = face_of(across[g], off);
      }
    }
  }
  return t;
}

const Tables kT = make_tables();

// The quads around one dual cell, grouped in sheets (one vertex each).
struct Cell {
  i32 x;
  u16 kept : 12;  // bit f: face f is a quad
  u16 pinched : 4;  // sheets where a label sees two of its own fans (see make_cell)
  u16 modes : 12;  // 2 bits per ring: 0 one group, 1 or 2 paired (see group())
  u16 pinched_out : 4;  // ... where the background or a label not extracted is
  u64 sheet_of;   // 4 bits per face: its sheet
  u32 nbcount;    // 4 bits per sheet: stencil entries (before the junction filter)
  u8 nsheets;
  u8 junction;    // bit s: sheet s is on a junction of three or more labels
  u8 paired_up;   // bit b: ring 2 b + 1 has two groups
  u8 both_up;     // bit b: ... and holds two labels diagonally
  i64 first;      // provisional index of sheet 0's vertex
  i64 nbfirst;    // its first stencil entry
  int sheet(int f) const { return int((sheet_of >> (4 * f)) & 15); }
  int mode(int d) const { return (modes >> (2 * d)) & 3; }
};

inline int group(int mode, int gap) {
  return mode == 0 ? 0 : mode == 1 ? gap >> 1 : ((gap + 1) & 3) >> 1;
}

// A gap of ring d in group g (the faces of a group share a sheet).
inline int gap_of_group(int mode, int g) { return mode == 0 ? -1 : mode == 1 ? 2 * g : g; }

// The sheets of a block: v its samples, w whether each is a wanted label,
// flips bit d: ring d is paired the other way. False when no face is a quad.
template <class T>
bool make_cell(const T v[8], const bool w[8], unsigned flips, Cell &c) {
  unsigned kept = 0;
  for (int f = 0; f < 12; ++f) {
    const int lo = kT.face_lo[f], hi = kT.face_hi[f];
    if (v[lo] != v[hi] && (w[lo] || w[hi])) kept |= 1u << f;
  }
  if (!kept) return false;
  c.kept = u16(kept);
  c.pinched = 0;
  c.modes = 0;
  c.pinched_out = 0;
  c.paired_up = c.both_up = 0;
  int parent[12];
  for (int f = 0; f < 12; ++f) parent[f] = f;
  auto find = [&](int f) {
    while (parent[f] != f) f = parent[f] = parent[parent[f]];
    return f;
  };
  auto unite = [&](int a, int b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  for (int d = 0; d < 6; ++d) {
    int n = 0;
    for (int g = 0; g < 4; ++g) n += (kept >> kT.gap_face[d][g]) & 1;
    if (n == 0) continue;
    int mode = 0;
    if (n == 4) {
      const int q00 = kT.ring[d][0], q10 = kT.ring[d][1], q11 = kT.ring[d][2],
                q01 = kT.ring[d][3];
      const bool diag_a = v[q00] == v[q11], diag_b = v[q10] == v[q01];
      if (diag_a && !diag_b) mode = 1;
      if (diag_b && !diag_a) mode = 2;
      if (diag_a && diag_b) {
        // two labels diagonally: the inside one's samples are separated
        const bool inside_is_a = w[q00] && (!w[q10] || v[q00] < v[q10]);
        mode = inside_is_a ? 2 : 1;
        if ((flips >> d) & 1) mode = 3 - mode;
        if (d & 1) c.both_up |= u8(1u << (d >> 1));
      }
      if (mode && (d & 1)) c.paired_up |= u8(1u << (d >> 1));
    }
    c.modes |= u16(mode << (2 * d));
    int head[2] = {-1, -1};
    for (int g = 0; g < 4; ++g) {
      const int f = kT.gap_face[d][g];
      if (!((kept >> f) & 1)) continue;
      const int k = group(mode, g);
      if (head[k] < 0) {
        head[k] = f;
      } else {
        unite(head[k], f);
      }
    }
  }
  // sheets numbered by their first face; junction where a sheet's quads do not
  // all separate the same two labels
  int sheet_of_root[12];
  T in_of[8], out_of[8];
  int ns = 0;
  u64 sheet_of = 0;
  unsigned junction = 0;
  for (int f = 0; f < 12; ++f) {
    if (!((kept >> f) & 1)) continue;
    const int r = find(f);
    const int lo = kT.face_lo[f], hi = kT.face_hi[f];
    const bool lo_inside = w[lo] && (!w[hi] || v[lo] < v[hi]);
    const T in = lo_inside ? v[lo] : v[hi], out = lo_inside ? v[hi] : v[lo];
    int s;
    if (r == f) {
      s = sheet_of_root[f] = ns++;
      in_of[s] = in;
      out_of[s] = out;
    } else {
      s = sheet_of_root[r];
      if (in != in_of[s] || out != out_of[s]) junction |= 1u << s;
    }
    sheet_of |= u64(s) << (4 * f);
  }
  c.sheet_of = sheet_of;
  c.nsheets = u8(ns);
  c.junction = u8(junction);
  u32 nbcount = 0;  // one stencil entry per group of each ring (see Net::fill)
  for (int d = 0; d < 6; ++d) {
    const int mode = c.mode(d);
    for (int g = 0; g < 4; ++g) {
      const int f = kT.gap_face[d][g];
      if (!((kept >> f) & 1) || (mode != 0 && gap_of_group(mode, group(mode, g)) != g)) continue;
      nbcount += 1u << (4 * c.sheet(f));
      if (mode == 0) break;
    }
  }
  c.nbcount = nbcount;
  // A label whose own faces in one sheet fall into two fans (its faces joined
  // only through another label's) is pinched at that vertex: when that other
  // label's fan holds faces of both, no split keeps both surfaces closed with
  // one vertex per quad corner. Counted, so the note can say so (rare). The
  // background's surface (judged in a --single-file mesh) is counted apart.
  unsigned pinched = 0, pinched_out = 0, done = 0;
  for (int o = 0; o < 8; ++o) {
    if ((done >> o) & 1) continue;
    unsigned mine = 0;
    for (int p = o; p < 8; ++p) mine |= unsigned(v[p] == v[o]) << p;
    done |= mine;
    if (!(mine & (mine - 1))) continue;  // one sample: its faces are one cone
    unsigned faces = 0;
    for (int f = 0; f < 12; ++f) {
      if (((kept >> f) & 1) && (((mine >> kT.face_lo[f]) ^ (mine >> kT.face_hi[f])) & 1)) {
        faces |= 1u << f;
      }
    }
    if (iso::popcount(u64(faces)) < 2) continue;
    for (int f = 0; f < 12; ++f) parent[f] = f;
    for (int d = 0; d < 6; ++d) {  // this label's faces that share a group of a ring
      const int mode = c.mode(d);
      int head[2] = {-1, -1};
      for (int g = 0; g < 4; ++g) {
        const int f = kT.gap_face[d][g];
        if (!((faces >> f) & 1)) continue;
        const int k = group(mode, g);
        if (head[k] < 0) {
          head[k] = f;
        } else {
          unite(head[k], f);
        }
      }
    }
    int root_of_sheet[12];
    unsigned twice = 0;
    for (int s = 0; s < ns; ++s) root_of_sheet[s] = -1;
    for (int f = 0; f < 12; ++f) {
      if (!((faces >> f) & 1)) continue;
      const int s = c.sheet(f), r = find(f);
      if (root_of_sheet[s] < 0) {
        root_of_sheet[s] = r;
      } else if (root_of_sheet[s] != r) {
        twice |= 1u << s;
      }
    }
    (w[o] ? pinched : pinched_out) += unsigned(iso::popcount(u64(twice)));
  }
  c.pinched = u16(std::min(pinched, 15u));
  c.pinched_out = u16(std::min(pinched_out, 15u));
  return true;
}

// The sorted wanted labels as a lookup: value -> index, or -1.
struct LabelIndex {
  const i64 *sorted = nullptr;
  i64 n = 0, lo = 0;
  std::vector<i32> table;

  LabelIndex(const i64 *s, i64 count, double vmin, double vmax) : sorted(s), n(count) {
    if (count && vmax - vmin < double(kTableLimit)) {
      lo = i64(vmin);
      table.assign(size_t(i64(vmax) - lo + 1), -1);
      for (i64 i = 0; i < count; ++i) {
        if (s[i] >= lo && s[i] - lo < i64(table.size())) table[size_t(s[i] - lo)] = i32(i);
      }
    }
  }
  i32 operator()(i64 k) const {
    if (!table.empty()) {
      const i64 at = k - lo;
      return at >= 0 && at < i64(table.size()) ? table[size_t(at)] : -1;
    }
    const i64 *p = std::lower_bound(sorted, sorted + n, k);
    return p != sorted + n && *p == k ? i32(p - sorted) : -1;
  }
};

struct Row {
  const Cell *begin = nullptr, *end = nullptr;
};

// A walk along one row of cells, x increasing.
struct Cursor {
  const Cell *at = nullptr, *end = nullptr;
  void reset(const Row &r) {
    at = r.begin;
    end = r.end;
  }
  const Cell *seek(i32 x) {
    while (at != end && at->x < x) ++at;
    return at != end && at->x == x ? at : nullptr;
  }
};

struct NetOptions {
  int iterations;
  double relaxation, constraint;
  bool reverse;
  int threads;
  // A z-slab of a larger volume (isoconvert/extract/label_blocks.py): its first
  // layer is the volume's layer z_offset, so positions are the volume's own (the
  // same bits as the whole volume's run wherever the slab reaches far enough),
  // and the counts (split, unresolved, outside) are of the dual cells of layers
  // count_lo <= z < count_hi only (slab-local; count_hi < 0: every layer).
  i64 z_offset = 0;
  i64 count_lo = 0, count_hi = -1;
  // Positions in world units when given: index position * scale + shift per
  // axis, the two roundings of Volume.index_to_world for an axis-aligned grid
  // (done here in the pass that writes them, not as two more passes in numpy).
  const double *scale = nullptr, *shift = nullptr;
};

// How far split copies start from their dual cell's centre, as a fraction of
// the way to the mean of their faces' centres (at most 0.71 voxel away): small,
// so the unsmoothed surface stays the voxel faces but at these corners (each copy
// moves at most 0.011 voxel and changes the volume by less than 0.05 voxel: it is
// linear in one vertex, a third of its triangles' area vectors, 12 faces at most),
// large enough to survive float32 coordinates up to ~10^4 voxels.
constexpr double kSplitStep = 1.0 / 64.0;

struct NetResult {
  Vec<double> positions;  // (V, 3)
  Vec<i64> dual_cells;    // (V,)
  Vec<u8> sheets;         // (V,): which sheet of its dual cell (numbered by first face)
  Vec<i64> corners;       // (Q, 4)
  Vec<i64> pairs;         // (Q, 2): inside, outside of each quad (both its triangles)
  Vec<i32> sides;         // (Q, 2): wanted-label index of inside, outside (-1)
  i64 split = 0;
  i64 unresolved = 0;  // places where a label's surface is still not manifold
  i64 outside = 0;     // ... where the background's is (see make_cell)
};

// The cells of every block of two values a (sample 0's) and b, by pattern: bits
// 0-7 the samples equal to a, 8 a wanted, 9 b wanted, 10 a < b. Built once (the
// sheets depend on nothing else), not per extraction.
const std::vector<Cell> &two_value_cells() {
  static const std::vector<Cell> table = [] {
    std::vector<Cell> two(2048);
    for (unsigned k = 1; k < 2048; k += 2) {
      int v[8];
      bool w[8];
      const bool lt = (k >> 10) & 1;
      for (int s = 0; s < 8; ++s) {
        const bool is_a = (k >> s) & 1;
        v[s] = is_a == lt ? 0 : 1;
        w[s] = is_a ? ((k >> 8) & 1) : ((k >> 9) & 1);
      }
      Cell c{};
      if (!make_cell(v, w, 0, c)) c.nsheets = 0;
      two[k] = c;
    }
    return two;
  }();
  return table;
}

template <class T>
class Net {
 public:
  Net(const T *f, i64 nz, i64 ny, i64 nx, T background, const LabelIndex &index,
      const NetOptions &o)
      : f_(f), X_(nx), Y_(ny), Z_(nz), bg_(background), index_(index), o_(o),
        two_(two_value_cells()) {}

  void run(NetResult &out) {
    const i64 cols = (X_ + 1) * (Y_ + 1);
    for (auto &c : count_) c.assign(size_t(cols), 0);
    rows_.assign(size_t((Y_ + 1) * (Z_ + 1)), Row{});
    // y ranges of dual cells: each owns its rows of cells and its columns (x, y) of quads
    const i64 per = std::max<i64>(1, (Y_ + 1) / (8 * std::max(o_.threads, 1)));
    for (i64 y = 0; y <= Y_; y += per) chunks_.push_back({y, std::min(Y_ + 1, y + per)});
    iso::parallel_for(i64(chunks_.size()), o_.threads, 1,
                      [&](int, i64 b, i64 e) {
                        for (i64 c = b; c < e; ++c) sweep(chunks_[size_t(c)]);
                      });
    resolve_flips();
    // provisional vertex and stencil numbering: chunk by chunk, cells in sweep order
    // (each chunk's own counts in parallel, then its cells from its offsets)
    const i64 nchunks = i64(chunks_.size());
    std::vector<i64> chunk_nv(size_t(nchunks + 1), 0), chunk_ne(size_t(nchunks + 1), 0);
    std::vector<std::vector<const Cell *>> chunk_split(static_cast<size_t>(nchunks));
    auto number = [&](bool assign) {
      iso::parallel_for(nchunks, o_.threads, 1, [&](int, i64 b, i64 e) {
        for (i64 h = b; h < e; ++h) {
          // totals from 0 (chunk_nv[h] is another chunk's to write), then from the offsets
          i64 v = assign ? chunk_nv[size_t(h)] : 0, n = assign ? chunk_ne[size_t(h)] : 0;
          for (auto &block : chunks_[size_t(h)].blocks) {
            for (auto &c : block) {
              if (assign) {
                c.first = v;
                c.nbfirst = n;
                if (c.nsheets > 1) chunk_split[size_t(h)].push_back(&c);
              }
              v += c.nsheets;
              for (int s = 0; s < c.nsheets; ++s) n += (c.nbcount >> (4 * s)) & 15;
            }
          }
          if (!assign) chunk_nv[size_t(h + 1)] = v, chunk_ne[size_t(h + 1)] = n;
        }
      });
    };
    number(false);  // each chunk's totals, from 0
    for (i64 h = 0; h < nchunks; ++h) {
      chunk_nv[size_t(h + 1)] += chunk_nv[size_t(h)];
      chunk_ne[size_t(h + 1)] += chunk_ne[size_t(h)];
    }
    number(true);
    const i64 nv = chunk_nv[size_t(nchunks)], ne = chunk_ne[size_t(nchunks)];
    if (nv > i64(std::numeric_limits<i32>::max()) || Z_ + o_.z_offset > (i64(1) << 30) ||
        X_ > (i64(1) << 30) || Y_ > (i64(1) << 30)) {
      // the stencil's and the centres' 32 bits (about 400 GB of net: never reached)
      throw std::invalid_argument("label_net: more than 2^31 - 1 vertices or 2^30 samples an axis");
    }
    std::vector<const Cell *> split_cells;  // cells of two or more vertices (few)
    for (auto &part : chunk_split) split_cells.insert(split_cells.end(), part.begin(), part.end());
    count_cells(out);
    unsplit_rings(out);
    const i64 nq = quad_offsets();
    Vec<i64> corners(static_cast<size_t>(4 * nq));
    Vec<u8> flip(static_cast<size_t>(nq));
    out.pairs.resize(size_t(2 * nq));
    out.sides.resize(size_t(2 * nq));
    Vec<i64> cell_of(static_cast<size_t>(nv));
    Vec<u8> sheet_of(static_cast<size_t>(nv));
    Vec<u8> junction(static_cast<size_t>(nv));
    // the smoothing stencil, only for smoothing (unsmoothed: 40 bytes a vertex less)
    const bool stencil = o_.iterations > 0;
    // (vertex numbers of one slab or volume: 32 bits, checked where the net is numbered)
    Vec<i32> nb(static_cast<size_t>(stencil ? ne : 0));
    Vec<i64> nboff(static_cast<size_t>(stencil ? nv + 1 : 0));
    iso::parallel_for(i64(chunks_.size()), o_.threads, 1, [&](int, i64 b, i64 e) {
      for (i64 c = b; c < e; ++c) {
        fill(chunks_[size_t(c)], corners.data(), flip.data(), out.pairs.data(), out.sides.data(),
             cell_of.data(), sheet_of.data(), junction.data(), stencil ? nb.data() : nullptr,
             stencil ? nboff.data() : nullptr);
      }
    });
    if (stencil) nboff[size_t(nv)] = ne;
    // the cells of two or more vertices (few), for the count below: smooth() gives
    // the cells back before its buffers are made
    std::vector<std::pair<i64, int>> split_vertices;
    for (const Cell *c : split_cells) split_vertices.emplace_back(c->first, c->nsheets);
    Vec<double> pos = smooth(cell_of, junction, nb, nboff, split_cells);
    // the stencil is not read again: its memory is the output's below
    Vec<i32>().swap(nb);
    Vec<i64>().swap(nboff);
    Vec<u8>().swap(junction);
    // copies that still coincide (none seen in tests): the note counts them
    const i64 layer = (X_ + 1) * (Y_ + 1);
    for (const auto &[first, nsheets] : split_vertices) {
      if (!counted(cell_of[size_t(first)] / layer)) continue;
      for (int s = 1; s < nsheets; ++s) {
        for (int t = 0; t < s; ++t) {
          const double *a = &pos[size_t(3 * (first + s))], *b = &pos[size_t(3 * (first + t))];
          out.unresolved += a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
        }
      }
    }
    // Final numbering: vertices in the order their first quad corner comes.
    std::vector<i64> rank(size_t(nv), -1);
    first_use_ranks(corners.data(), 4 * nq, rank.data(), corners.data());
    iso::parallel_for(nq, o_.threads, 1 << 16, [&](int, i64 b, i64 e) {
      for (i64 q = b; q < e; ++q) {
        i64 *c = &corners[size_t(4 * q)];
        if ((flip[size_t(q)] != 0) != o_.reverse) {
          std::swap(c[0], c[3]);
          std::swap(c[1], c[2]);
        }
      }
    });
    out.corners = std::move(corners);
    out.positions.resize(size_t(3 * nv));
    out.dual_cells.resize(size_t(nv));
    out.sheets.resize(size_t(nv));
    iso::parallel_for(nv, o_.threads, 1 << 16, [&](int, i64 b, i64 e) {
      for (i64 p = b; p < e; ++p) {
        const i64 r = rank[size_t(p)];
        out.dual_cells[size_t(r)] = cell_of[size_t(p)];
        out.sheets[size_t(r)] = sheet_of[size_t(p)];
        if (o_.scale) {
          for (int k = 0; k < 3; ++k) {
            out.positions[size_t(3 * r + k)] = pos[size_t(3 * p + k)] * o_.scale[k] + o_.shift[k];
          }
        } else {
          for (int k = 0; k < 3; ++k) out.positions[size_t(3 * r + k)] = pos[size_t(3 * p + k)];
        }
      }
    });
  }

 private:
  struct Chunk {
    i64 y0, y1;
    // the cells, in sweep order, in blocks that are never reallocated (the rows
    // point into them; a vector grown cell by cell would copy them all about
    // twice over, into fresh pages): a row never straddles two blocks
    std::vector<Vec<Cell>> blocks;
    std::vector<std::array<i64, 4>> rings;  // (x, y, z, b) of rings with two groups
  };

  // count_[0], [1]: quads across x, y per column (x, y); [2..4]: across z, at
  // z = 0 (the low side), inside, z = Z (the high side)
  std::vector<i64> count_[5];

  T sample(i64 x, i64 y, i64 z) const {
    if (x < 0 || y < 0 || z < 0 || x >= X_ || y >= Y_ || z >= Z_) return bg_;
    return f_[(z * Y_ + y) * X_ + x];
  }

  void block(i64 x, i64 y, i64 z, T v[8], bool w[8]) const {
    for (int o = 0; o < 8; ++o) {
      v[o] = sample(x - 1 + (o & 1), y - 1 + ((o >> 1) & 1), z - 1 + (o >> 2));
      w[o] = index_(key(v[o])) >= 0;
    }
  }

  // A row of samples padded by the background at both ends (index x + 1).
  void load(i64 y, i64 z, std::vector<T> &row) const {
    row[0] = row[size_t(X_ + 1)] = bg_;
    if (y < 0 || z < 0 || y >= Y_ || z >= Z_) {
      std::fill(row.begin(), row.end(), bg_);
    } else {
      std::memcpy(row.data() + 1, f_ + (z * Y_ + y) * X_, size_t(X_) * sizeof(T));
    }
  }

  void sweep(Chunk &ch) {
    std::vector<T> r[2][2];  // [oy][oz]: rows y - 1 + oy, z - 1 + oz
    for (auto &a : r) {
      for (auto &b : a) b.resize(size_t(X_ + 2));
    }
    std::vector<u8> same(static_cast<size_t>(X_ + 2)), mixed(static_cast<size_t>(X_ + 9), 0);
    const i64 cy = Y_ + 1;
    const size_t row_cells = size_t(X_ + 1), block_cells = std::max<size_t>(row_cells, 8192);
    for (i64 z = 0; z <= Z_; ++z) {
      for (i64 y = ch.y0; y < ch.y1; ++y) {
        if (y == ch.y0) {
          load(y - 1, z - 1, r[0][0]);
          load(y - 1, z, r[0][1]);
        } else {
          std::swap(r[0][0], r[1][0]);
          std::swap(r[0][1], r[1][1]);
        }
        load(y, z - 1, r[1][0]);
        load(y, z, r[1][1]);
        const T *a = r[0][0].data(), *b = r[1][0].data(), *c = r[0][1].data(),
                *d = r[1][1].data();
        // columns of four equal samples; a cell is uniform when two neighbouring
        // columns are, with the same value (most cells: skipped here)
        for (i64 i = 0; i < X_ + 2; ++i) {
          same[size_t(i)] = u8((a[i] == b[i]) & (a[i] == c[i]) & (a[i] == d[i]));
        }
        if (ch.blocks.empty() || ch.blocks.back().capacity() - ch.blocks.back().size() < row_cells) {
          ch.blocks.emplace_back();
          ch.blocks.back().reserve(block_cells);
        }
        Vec<Cell> &cells = ch.blocks.back();
        const size_t before = cells.size();
        for (i64 x = 0; x <= X_; ++x) {
          mixed[size_t(x)] = u8(!(same[size_t(x)] & same[size_t(x + 1)] & (a[x] == a[x + 1])));
        }
        for (i64 x0 = 0; x0 <= X_; x0 += 8) {
          u64 word = 0;
          std::memcpy(&word, &mixed[size_t(x0)], 8);  // `mixed` has 8 bytes of slack
          if (!word) continue;  // eight uniform cells
          for (i64 x = x0; x < std::min(x0 + 8, X_ + 1); ++x) {
          if (!mixed[size_t(x)]) continue;
          T v[8];
          for (int o = 0; o < 8; ++o) v[o] = r[(o >> 1) & 1][o >> 2][size_t(x + (o & 1))];
          Cell cell{};
          // Blocks of two values (most of them) by a table of their pattern; the
          // sheets only depend on which samples are equal, wanted, and smaller.
          unsigned m = 1, pair = 1;
          T other = v[0];
          for (int o = 1; o < 8; ++o) {
            if (v[o] == v[0]) {
              m |= 1u << o;
            } else if (other == v[0]) {
              other = v[o];
            } else if (v[o] != other) {
              pair = 0;
            }
          }
          if (pair) {
            const unsigned k = m | unsigned(index_(key(v[0])) >= 0) << 8 |
                               unsigned(index_(key(other)) >= 0) << 9 | unsigned(v[0] < other) << 10;
            if (!two_[k].nsheets) continue;
            cell = two_[k];
          } else {
            bool w[8];
            for (int o = 0; o < 8; ++o) w[o] = index_(key(v[o])) >= 0;
            if (!make_cell(v, w, 0, cell)) continue;
          }
          cell.x = i32(x);
          cells.push_back(cell);
          const i64 col = x * cy + y;
          if ((cell.kept >> 3) & 1) ++count_[0][size_t(col)];
          if ((cell.kept >> 7) & 1) ++count_[1][size_t(col)];
          if ((cell.kept >> 11) & 1) ++count_[z == 0 ? 2 : z == Z_ ? 4 : 3][size_t(col)];
          for (int bb = 0; bb < 3; ++bb) {
            if ((cell.paired_up >> bb) & 1) ch.rings.push_back({x, y, z, bb});
          }
          }
        }
        rows_[size_t(z * cy + y)] = Row{cells.data() + before, cells.data() + cells.size()};
      }
    }
  }

  Cell *find(i64 x, i64 y, i64 z) {
    if (x < 0 || y < 0 || z < 0 || x > X_ || y > Y_ || z > Z_) return nullptr;
    const Row &r = rows_[size_t(z * (Y_ + 1) + y)];
    const Cell *p = std::lower_bound(r.begin, r.end, i32(x),
                                     [](const Cell &c, i32 v) { return c.x < v; });
    return p != r.end && p->x == x ? const_cast<Cell *>(p) : nullptr;
  }

  i64 edge_id(i64 x, i64 y, i64 z, int b) const {
    return 3 * (x + (X_ + 1) * (y + (Y_ + 1) * z)) + b;
  }

  // Rings whose two copies still end on the same two vertices at both ends are
  // paired the other way, as the reference does: at most three more rounds.
  void resolve_flips() {
    std::vector<std::array<i64, 4>> rings;
    for (auto &ch : chunks_) rings.insert(rings.end(), ch.rings.begin(), ch.rings.end());
    if (rings.empty()) return;
    std::vector<i64> flipped;  // sorted dual edge ids
    auto is_flipped = [&](i64 id) {
      return std::binary_search(flipped.begin(), flipped.end(), id);
    };
    for (int round = 0; round < 4; ++round) {
      std::vector<i64> bad;
      std::vector<std::array<i64, 4>> turned;
      for (const auto &g : rings) {
        const i64 x = g[0], y = g[1], z = g[2];
        const int b = int(g[3]);
        const i64 id = edge_id(x, y, z, b);
        if (is_flipped(id)) continue;
        const Cell *lo = find(x, y, z);
        const Cell *hi = find(x + (b == 0), y + (b == 1), z + (b == 2));
        const int mode = lo->mode(2 * b + 1);
        const int g0 = gap_of_group(mode, 0), g1 = gap_of_group(mode, 1);
        const bool same_lo = lo->sheet(kT.gap_face[2 * b + 1][g0]) ==
                             lo->sheet(kT.gap_face[2 * b + 1][g1]);
        const bool same_hi =
            hi->sheet(kT.gap_face[2 * b][g0]) == hi->sheet(kT.gap_face[2 * b][g1]);
        if (same_lo && same_hi) {
          bad.push_back(id);
          if ((lo->both_up >> b) & 1) turned.push_back(g);
        }
      }
      if (bad.empty() || round == 3) break;
      std::vector<i64> merged;
      std::sort(bad.begin(), bad.end());
      std::set_union(flipped.begin(), flipped.end(), bad.begin(), bad.end(),
                     std::back_inserter(merged));
      flipped.swap(merged);
      for (const auto &g : turned) {
        const int b = int(g[3]);
        redo(g[0], g[1], g[2], is_flipped);
        redo(g[0] + (b == 0), g[1] + (b == 1), g[2] + (b == 2), is_flipped);
      }
    }
  }

  // Paired rings whose two copies still end on the same two vertices at both
  // ends, where a label sees all four quads: its surface has an edge in four
  // triangles there (a label touching itself along the edge, joined to itself at
  // both ends through another label's faces; see make_cell's pinched count).
  // Where only the background or a label not extracted sees all four: outside.
  void unsplit_rings(NetResult &out) {
    for (const auto &ch : chunks_) {
      for (const auto &g : ch.rings) {
        const i64 x = g[0], y = g[1], z = g[2];
        const int b = int(g[3]), d = 2 * b + 1;
        if (!counted(z)) continue;
        const Cell *lo = find(x, y, z);
        const Cell *hi = find(x + (b == 0), y + (b == 1), z + (b == 2));
        const int mode = lo->mode(d);
        if (mode == 0) continue;
        const int g0 = gap_of_group(mode, 0), g1 = gap_of_group(mode, 1);
        if (lo->sheet(kT.gap_face[d][g0]) != lo->sheet(kT.gap_face[d][g1]) ||
            hi->sheet(kT.gap_face[d - 1][g0]) != hi->sheet(kT.gap_face[d - 1][g1])) {
          continue;
        }
        T v[8];
        bool w[8];
        block(x, y, z, v, w);
        const int *q = kT.ring[d];
        const bool diag_a = v[q[0]] == v[q[2]], diag_b = v[q[1]] == v[q[3]];
        if ((diag_a && w[q[0]]) || (diag_b && w[q[1]])) {
          ++out.unresolved;
        } else {
          ++out.outside;
        }
      }
    }
  }

  bool counted(i64 z) const { return z >= o_.count_lo && (o_.count_hi < 0 || z < o_.count_hi); }

  // Vertices added by splits, and places left pinched, of the counted layers.
  void count_cells(NetResult &out) const {
    for (i64 z = 0; z <= Z_; ++z) {
      if (!counted(z)) continue;
      for (i64 y = 0; y <= Y_; ++y) {
        const Row &r = rows_[size_t(z * (Y_ + 1) + y)];
        for (const Cell *c = r.begin; c != r.end; ++c) {
          out.split += c->nsheets - 1;
          out.unresolved += c->pinched;
          out.outside += c->pinched_out;
        }
      }
    }
  }

  template <class Flipped>
  void redo(i64 x, i64 y, i64 z, const Flipped &is_flipped) {
    Cell *c = find(x, y, z);
    T v[8];
    bool w[8];
    block(x, y, z, v, w);
    unsigned flips = 0;
    for (int b = 0; b < 3; ++b) {
      if (is_flipped(edge_id(x, y, z, b))) flips |= 1u << (2 * b + 1);
      const i64 px = x - (b == 0), py = y - (b == 1), pz = z - (b == 2);
      if (px >= 0 && py >= 0 && pz >= 0 && is_flipped(edge_id(px, py, pz, b))) {
        flips |= 1u << (2 * b);
      }
    }
    Cell fresh{};
    make_cell(v, w, flips, fresh);
    fresh.x = c->x;
    *c = fresh;
  }

  // Quad positions: per axis the interior faces, then the low side, then the
  // high side; within each, lexicographic in (x, y, z) (np.nonzero's order).
  i64 quad_offsets() {
    const i64 cy = Y_ + 1;
    i64 at = 0;
    auto take = [&](i64 &c) {
      const i64 n = c;
      c = at;
      at += n;
    };
    for (i64 x = 1; x < X_; ++x) {
      for (i64 y = 0; y <= Y_; ++y) take(count_[0][size_t(x * cy + y)]);
    }
    for (i64 x : {i64(0), X_}) {
      for (i64 y = 0; y <= Y_; ++y) take(count_[0][size_t(x * cy + y)]);
    }
    for (i64 x = 0; x <= X_; ++x) {
      for (i64 y = 1; y < Y_; ++y) take(count_[1][size_t(x * cy + y)]);
    }
    for (i64 y : {i64(0), Y_}) {
      for (i64 x = 0; x <= X_; ++x) take(count_[1][size_t(x * cy + y)]);
    }
    for (int k : {3, 2, 4}) {
      for (i64 c = 0; c < (X_ + 1) * cy; ++c) take(count_[k][size_t(c)]);
    }
    return at;
  }

  void fill(Chunk &ch, i64 *corners, u8 *flip, i64 *pairs, i32 *sides, i64 *cell_of,
            u8 *sheet_of, u8 *junction, i32 *nb, i64 *nboff) {
    const i64 cy = Y_ + 1;
    auto row = [&](i64 y, i64 z) {
      return (y < 0 || z < 0 || y > Y_ || z > Z_) ? Row{} : rows_[size_t(z * cy + y)];
    };
    for (i64 z = 0; z <= Z_; ++z) {
      for (i64 y = ch.y0; y < ch.y1; ++y) {
        const Row self = row(y, z);
        if (self.begin == self.end) continue;
        Cursor up_y, up_z, up_yz, down_y, down_z;
        up_y.reset(row(y + 1, z));
        up_z.reset(row(y, z + 1));
        up_yz.reset(row(y + 1, z + 1));
        down_y.reset(row(y - 1, z));
        down_z.reset(row(y, z - 1));
        for (const Cell *c = self.begin; c != self.end; ++c) {
          const i32 x = c->x;
          const Cell *next_x = (c + 1 != self.end && c[1].x == x + 1) ? c + 1 : nullptr;
          const Cell *prev_x = (c != self.begin && c[-1].x == x - 1) ? c - 1 : nullptr;
          const Cell *ny_ = up_y.seek(x), *nz_ = up_z.seek(x), *nyz = up_yz.seek(x);
          const Cell *py_ = down_y.seek(x), *pz_ = down_z.seek(x);
          const i64 id = x + (X_ + 1) * (y + cy * z);
          i64 write[8];
          for (int s = 0, e = 0; s < c->nsheets; ++s) {
            cell_of[c->first + s] = id;
            sheet_of[c->first + s] = u8(s);
            junction[c->first + s] = u8((c->junction >> s) & 1);
            if (nboff) nboff[c->first + s] = c->nbfirst + e;
            write[s] = c->nbfirst + e;
            e += (c->nbcount >> (4 * s)) & 15;
          }
          // stencil: edges from this cell (b = 0, 1, 2), then edges into it from
          // the cells below along z, y, x: the order np.bincount summed them in
          const Cell *up[3] = {next_x, ny_, nz_};
          const Cell *down[3] = {prev_x, py_, pz_};
          for (int k = 0; nb && k < 6; ++k) {  // nb null: no stencil (no smoothing)
            const int b = k < 3 ? k : 5 - k;
            const int d = k < 3 ? 2 * b + 1 : 2 * b, other = k < 3 ? 2 * b : 2 * b + 1;
            const Cell *n = k < 3 ? up[b] : down[b];
            const int mode = c->mode(d);
            for (int g = 0; g < 4; ++g) {
              const int fc = kT.gap_face[d][g];
              if (!((c->kept >> fc) & 1)) continue;
              if (mode != 0 && gap_of_group(mode, group(mode, g)) != g) continue;
              nb[write[c->sheet(fc)]++] = i32(n->first + n->sheet(kT.gap_face[other][g]));
              if (mode == 0) break;
            }
          }
          // quads whose corner 0 is this cell
          for (int a = 0; a < 3; ++a) {
            if (!((c->kept >> (4 * a + 3)) & 1)) continue;
            i64 &slot = a == 0   ? count_[0][size_t(x * cy + y)]
                        : a == 1 ? count_[1][size_t(x * cy + y)]
                                 : count_[z == 0 ? 2 : z == Z_ ? 4 : 3][size_t(x * cy + y)];
            const i64 q = slot++;
            // corners (0, 0), (1, 0), (1, 1), (0, 1) along (u, v) = (a + 1, a + 2)
            const Cell *cc[4];
            cc[0] = c;
            if (a == 0) {
              cc[1] = ny_, cc[2] = nyz, cc[3] = nz_;
            } else if (a == 1) {
              cc[1] = nz_;
              cc[2] = nullptr;
              cc[3] = next_x;
            } else {
              cc[1] = next_x;
              cc[2] = nullptr;
              cc[3] = ny_;
            }
            if (a == 1) {  // (x + 1, y, z + 1)
              Cursor t;
              t.reset(row(y, z + 1));
              t.at = nz_ ? nz_ : t.at;
              cc[2] = t.seek(x + 1);
            } else if (a == 2) {  // (x + 1, y + 1, z)
              Cursor t;
              t.reset(row(y + 1, z));
              t.at = ny_ ? ny_ : t.at;
              cc[2] = t.seek(x + 1);
            }
            for (int k = 0; k < 4; ++k) {
              corners[4 * q + k] = cc[k]->first + cc[k]->sheet(4 * a + (k == 0   ? 3
                                                                         : k == 1 ? 2
                                                                         : k == 2 ? 0
                                                                                  : 1));
            }
            const T lo = sample(x - (a == 0), y - (a == 1), z - (a == 2));
            const T hi = sample(x, y, z);
            const i32 wl = index_(key(lo)), wh = index_(key(hi));
            const bool lo_inside = wl >= 0 && (wh < 0 || lo < hi);
            flip[q] = u8(!lo_inside);
            const i64 in = key(lo_inside ? lo : hi), out = key(lo_inside ? hi : lo);
            pairs[2 * q] = in;
            pairs[2 * q + 1] = out;
            sides[2 * q] = lo_inside ? wl : wh;
            sides[2 * q + 1] = lo_inside ? wh : wl;
          }
        }
      }
    }
  }

  // The copies of a split vertex start kSplitStep of the way from the centre
  // to the mean of their own faces' centres (where naive Surface Nets would put
  // them): towards their own side, so that they differ in position, not only in
  // index, and the surface does not touch itself there even unsmoothed. Out of
  // line: kept apart from the relaxation loops, which it must not slow down.
  [[gnu::noinline]] static void step_split_copies(const std::vector<const Cell *> &split_cells,
                                                  Vec<double> &pos) {
    for (const Cell *c : split_cells) {
      int sum[12][3] = {}, count[12] = {};
      for (int f = 0; f < 12; ++f) {
        if (!((c->kept >> f) & 1)) continue;
        const int s = c->sheet(f);
        ++count[s];
        for (int k = 0; k < 3; ++k) sum[s][k] += kT.mid2[f][k];
      }
      for (int s = 0; s < c->nsheets; ++s) {
        for (int k = 0; k < 3; ++k) {
          pos[size_t(3 * (c->first + s) + k)] +=
              kSplitStep * double(sum[s][k]) / double(2 * count[s]);
        }
      }
    }
  }

  // The cells, their rows and the column counts, which nothing reads once the
  // quads, the stencil and the starting positions are made: given back before
  // the smoothing's buffers are (a slab's peak is there).
  void release_cells() {
    std::vector<Chunk>().swap(chunks_);
    std::vector<Row>().swap(rows_);
    for (auto &c : count_) std::vector<i64>().swap(c);
  }

  // Constrained relaxation (Jacobi): see labels.py. Junction vertices follow
  // junction neighbours only and stay put where junction curves meet.
  Vec<double> smooth(const Vec<i64> &cell_of, const Vec<u8> &junction, Vec<i32> &nb,
                     const Vec<i64> &nboff, const std::vector<const Cell *> &split_cells) {
    const i64 nv = i64(cell_of.size());
    const i64 cx = X_ + 1, cy = Y_ + 1;
    // the centres (the boxes of the constraint) only for smoothing, each as twice
    // itself (2 c - 1 for grid coordinate c: a whole number, exact in 32 bits)
    Vec<double> pos(static_cast<size_t>(3 * nv));
    Vec<i32> centers(size_t(o_.iterations ? 3 * nv : 0));
    iso::parallel_for(nv, o_.threads, 1 << 15, [&](int, i64 b, i64 e) {
      for (i64 p = b; p < e; ++p) {
        const i64 id = cell_of[size_t(p)];
        const i64 c[3] = {id % cx, (id / cx) % cy, id / (cx * cy) + o_.z_offset};
        for (int k = 0; k < 3; ++k) {
          pos[size_t(3 * p + k)] = double(c[k]) - 0.5;
          if (o_.iterations) centers[size_t(3 * p + k)] = i32(2 * c[k] - 1);
        }
      }
    });
    step_split_copies(split_cells, pos);
    release_cells();
    if (o_.iterations == 0 || nb.empty()) return pos;
    std::vector<i32> degree(size_t(nv), 0);  // 0: the vertex stays put
    iso::parallel_for(nv, o_.threads, 1 << 15, [&](int, i64 b, i64 e) {
      for (i64 p = b; p < e; ++p) {
        i64 n = 0;
        const i64 from = nboff[size_t(p)], to = nboff[size_t(p + 1)];
        for (i64 k = from; k < to; ++k) {
          if (!junction[size_t(p)] || junction[size_t(nb[size_t(k)])]) nb[size_t(from + n++)] = nb[size_t(k)];
        }
        degree[size_t(p)] = (n > 0 && (!junction[size_t(p)] || n == 2)) ? i32(n) : 0;
      }
    });
    Vec<double> next(pos);
    const double relax = o_.relaxation, half = o_.constraint;
    for (int it = 0; it < o_.iterations; ++it) {
      // plain pointers and scalars copied into the loop: a store to `to` may not
      // alias them, so nothing is reloaded per vertex
      const double *from_pos = pos.data();
      const i32 *twice = centers.data();
      double *to = next.data();
      const i32 *deg = degree.data();
      const i64 *off = nboff.data();
      const i32 *nbr = nb.data();
      iso::parallel_for(nv, o_.threads, 1 << 14, [=](int, i64 b, i64 e) {
        const double r = relax, k_ = half;
        for (i64 p = b; p < e; ++p) {
          const i32 n = deg[p];
          if (n == 0) continue;  // stays at its start, in both buffers
          const i64 from = off[p];
          double t[3] = {0.0, 0.0, 0.0};
          for (i64 k = from; k < from + n; ++k) {
            const double *q = from_pos + 3 * nbr[k];
            t[0] += q[0];
            t[1] += q[1];
            t[2] += q[2];
          }
          const double d = double(n);
          for (int a = 0; a < 3; ++a) {
            const double x = from_pos[3 * p + a];
            const double moved = x + r * (t[a] / d - x);
            const double c = 0.5 * double(twice[3 * p + a]);
            to[3 * p + a] = std::min(std::max(moved, c - k_), c + k_);
          }
        }
      });
      pos.swap(next);
      // vertices that stay put hold the same value in both buffers
    }
    return pos;
  }

  const T *f_;
  i64 X_, Y_, Z_;
  T bg_;
  const LabelIndex &index_;
  NetOptions o_;
  std::vector<Chunk> chunks_;
  std::vector<Row> rows_;
  const std::vector<Cell> &two_;
};

// How each quad is cut into two triangles: along the shorter diagonal, 0-2 on
// ties (cut[q] = 1: along 1-3); triangle t of quad q is (2 q + t) of the mesh.
constexpr int kCutOrder[2][6] = {{0, 1, 2, 0, 2, 3}, {0, 1, 3, 1, 2, 3}};

void quad_cuts(const i64 *corners, i64 nq, const double *v, int threads, u8 *cut) {
  iso::parallel_for(nq, threads, 1 << 15, [&](int, i64 b, i64 e) {
    for (i64 q = b; q < e; ++q) {
      const i64 *c = corners + 4 * q;
      auto dist = [&](i64 i, i64 j) {
        const double dx = v[3 * i] - v[3 * j], dy = v[3 * i + 1] - v[3 * j + 1],
                     dz = v[3 * i + 2] - v[3 * j + 2];
        return dx * dx + dy * dy + dz * dz;
      };
      cut[q] = u8(dist(c[1], c[3]) < dist(c[0], c[2]) * (1 - 1e-9));
    }
  });
}

// Each wanted label's quads: those it is inside of, then those it is outside of,
// each in quad order (label l's are quads[off[l] .. off[l + 1]], the first
// inside[l] of them inside). Indices are int32 where every quad index fits.
template <class I>
void label_quads(const i32 *sides, i64 nq, i64 nlabels, Vec<I> &quads, std::vector<i64> &off,
                 std::vector<i64> &inside) {
  std::vector<i64> count(size_t(2 * nlabels), 0);
  for (i64 k = 0; k < 2 * nq; ++k) {
    if (sides[k] >= 0) ++count[size_t(2 * sides[k] + (k & 1))];
  }
  std::vector<i64> at(size_t(2 * nlabels));
  off.assign(size_t(nlabels + 1), 0);
  inside.assign(size_t(nlabels), 0);
  i64 total = 0;
  for (i64 k = 0; k < 2 * nlabels; ++k) {
    at[size_t(k)] = total;
    total += count[size_t(k)];
    if (k & 1) off[size_t(k / 2 + 1)] = total;
    else inside[size_t(k / 2)] = count[size_t(k)];
  }
  quads.resize(size_t(total));
  for (i64 k = 0; k < 2 * nq; ++k) {
    if (sides[k] >= 0) quads[size_t(at[size_t(2 * sides[k] + (k & 1))]++)] = I(k >> 1);
  }
}

// One label's surface from its quads (label_quads): the combined mesh's
// triangles it has (faces), its vertices (used, ascending) and their positions,
// and its triangles over them (those it is outside of reversed).
struct OneLabel {
  Vec<i64> faces, used, local;
  Vec<double> verts;
};

template <class I>
void label_mesh(const i64 *corners, const u8 *cut, const double *v, const I *quads, i64 n,
                i64 inside, OneLabel &out) {
  i64 lo = std::numeric_limits<i64>::max(), hi = -1;
  for (i64 k = 0; k < n; ++k) {
    const i64 *c = corners + 4 * i64(quads[k]);
    for (int j = 0; j < 4; ++j) {
      lo = std::min(lo, c[j]);
      hi = std::max(hi, c[j]);
    }
  }
  out.faces.resize(size_t(2 * n));
  out.local.resize(size_t(6 * n));
  if (n == 0) return;
  // its vertices as bits of a bitmap over lo..hi, listed in increasing order; a
  // vertex's new index is the number of bits before it (a word's prefix count
  // plus a popcount)
  const i64 w0 = lo >> 6, words = (hi >> 6) - w0 + 1;
  std::vector<u64> mark(size_t(words), 0);
  std::vector<i64> prefix(static_cast<size_t>(words));
  for (i64 k = 0; k < n; ++k) {
    const i64 *c = corners + 4 * i64(quads[k]);
    for (int j = 0; j < 4; ++j) mark[size_t((c[j] >> 6) - w0)] |= u64(1) << (c[j] & 63);
  }
  i64 nu = 0;
  for (i64 w = 0; w < words; ++w) {
    prefix[size_t(w)] = nu;
    nu += iso::popcount(mark[size_t(w)]);
  }
  out.used.resize(size_t(nu));
  out.verts.resize(size_t(3 * nu));
  for (i64 w = 0, k = 0; w < words; ++w) {
    for (u64 m = mark[size_t(w)]; m; m &= m - 1, ++k) {
      const i64 id = 64 * (w0 + w) + iso::ctz(m);
      out.used[size_t(k)] = id;
      for (int j = 0; j < 3; ++j) out.verts[size_t(3 * k + j)] = v[size_t(3 * id + j)];
    }
  }
  auto local = [&](i64 id) {
    const i64 w = (id >> 6) - w0;
    return prefix[size_t(w)] + iso::popcount(mark[size_t(w)] & ((u64(1) << (id & 63)) - 1));
  };
  for (i64 k = 0; k < n; ++k) {
    const i64 q = i64(quads[k]);
    const i64 *c = corners + 4 * q;
    const int *order = kCutOrder[cut[q]];
    out.faces[size_t(2 * k)] = 2 * q;
    out.faces[size_t(2 * k + 1)] = 2 * q + 1;
    // a label outside of the quad sees its triangles from the other side: reversed
    for (int t = 0; t < 2; ++t) {
      i64 *to = &out.local[size_t(6 * k + 3 * t)];
      for (int j = 0; j < 3; ++j) to[j] = local(c[order[3 * t + (k < inside ? j : 2 - j)]]);
    }
  }
}

template <class T>
void bind_label_type(nb::module_ &m) {
  m.def(
      "label_presence",
      [](Samples3<T> f, int threads) {
        Presence p;
        {
          nb::gil_scoped_release unlocked;
          label_presence<T>(f.data(), i64(f.size()), threads, p);
        }
        nb::object present = p.listed ? give(std::move(p.present)) : nb::none();
        return nb::make_tuple(p.min, p.max, p.bad, present);
      },
      "f"_a.noconvert(), "threads"_a,
      "(min, max, bad, present): the value range, float samples that are not whole numbers "
      "within +-2^53, and the sorted values present (None when their range is too wide).");
  m.def(
      "label_net",
      [](Samples3<T> f, Int64s wanted, double background, double vmin, double vmax,
         int iterations, double relaxation, double constraint, bool reverse, int threads,
         i64 z_offset, i64 count_lo, i64 count_hi, Doubles scale, Doubles shift) {
        if (wanted.ndim() != 1) throw std::invalid_argument("wanted labels: (L,) int64");
        // None: positions in index units
        const bool placed = scale.is_valid() || shift.is_valid();
        if (placed && !(scale.is_valid() && shift.is_valid() && scale.size() == 3 &&
                        shift.size() == 3)) {
          throw std::invalid_argument("scale and shift: (3,) each, or both None");
        }
        if (iterations < 0) throw std::invalid_argument("iterations must be >= 0");
        const bool fits = background >= double(std::numeric_limits<T>::lowest()) &&
                          background <= double(std::numeric_limits<T>::max());
        const T bg = fits ? static_cast<T>(background) : T(0);
        if (!fits || static_cast<double>(bg) != background) {
          throw std::invalid_argument("the background is not a value of the sample type");
        }
        NetResult r;
        {
          nb::gil_scoped_release unlocked;
          const LabelIndex index(wanted.data(), i64(wanted.shape(0)),
                                 std::min(vmin, background), std::max(vmax, background));
          Net<T> net(f.data(), i64(f.shape(0)), i64(f.shape(1)), i64(f.shape(2)), bg, index,
                     NetOptions{iterations, relaxation, constraint, reverse, threads, z_offset,
                                count_lo, count_hi, placed ? scale.data() : nullptr,
                                placed ? shift.data() : nullptr});
          net.run(r);
        }
        return nb::make_tuple(give(std::move(r.positions), 3), give(std::move(r.dual_cells)),
                              give(std::move(r.sheets)), give(std::move(r.corners), 4),
                              give(std::move(r.pairs), 2), give(std::move(r.sides), 2), r.split,
                              r.unresolved, r.outside);
      },
      "f"_a.noconvert(), "wanted"_a, "background"_a, "vmin"_a, "vmax"_a, "iterations"_a,
      "relaxation"_a, "constraint"_a, "reverse"_a, "threads"_a, "z_offset"_a = 0,
      "count_lo"_a = 0, "count_hi"_a = -1, "scale"_a.none() = nb::none(),
      "shift"_a.none() = nb::none(),
      "The surface net of a (Z, Y, X) label volume: (positions (V, 3) in index units "
      "(times scale plus shift, per axis, when given), "
      "dual_cells (V,), sheets (V,) uint8, corners (Q, 4), pairs (Q, 2), sides (Q, 2) int32, "
      "split, unresolved, outside). A slab of a larger volume: z_offset its first layer "
      "(positions in the volume's index units), counts of dual-cell layers "
      "count_lo <= z < count_hi only (count_hi < 0: all).");
}

}  // namespace

void bind_labels(nb::module_ &m) {
#define ISO_BIND(T) bind_label_type<T>(m);
  ISO_FOR_EACH_SAMPLE_TYPE(ISO_BIND)
#undef ISO_BIND
  m.def(
      "first_use_numbering",
      [](Int64s indices, i64 n) {
        if (indices.ndim() != 1 || n < 0) {
          throw std::invalid_argument("first_use_numbering: indices (N,), n >= 0");
        }
        const i64 *v = indices.data();
        const i64 count = i64(indices.shape(0));
        for (i64 k = 0; k < count; ++k) {
          if (v[k] < 0 || v[k] >= n) throw std::invalid_argument("first_use_numbering: index out of range");
        }
        Vec<i64> rank(static_cast<size_t>(n));
        {
          nb::gil_scoped_release unlocked;
          std::fill(rank.begin(), rank.end(), i64(-1));
          first_use_ranks(v, count, rank.data());
        }
        return give(std::move(rank));
      },
      "indices"_a, "n"_a,
      "rank (n,) int64: each of 0..n-1 numbered in the order it first comes in indices "
      "(-1 where it never does), as label_net numbers vertices by their first quad corner.");
  m.def(
      "label_quads",
      [](Int64s corners, Doubles vertices, nb::ndarray<const i32, nb::c_contig, nb::device::cpu> sides,
         i64 nlabels, int threads) {
        if (corners.ndim() != 2 || corners.shape(1) != 4 || vertices.ndim() != 2 ||
            vertices.shape(1) != 3 || sides.ndim() != 2 || sides.shape(1) != 2 ||
            sides.shape(0) != corners.shape(0) || nlabels < 0) {
          throw std::invalid_argument(
              "label_quads: corners (Q, 4), vertices (V, 3), sides (Q, 2), nlabels >= 0");
        }
        const i64 nq = i64(corners.shape(0)), nv = i64(vertices.shape(0));
        Vec<u8> cut(static_cast<size_t>(nq));
        Vec<i32> small;
        Vec<i64> large;
        std::vector<i64> off, inside;
        {
          nb::gil_scoped_release unlocked;
          // checked in parallel, without the GIL: a pass over every corner
          std::atomic<int> bad{0};
          iso::parallel_for(nq, threads, 1 << 16, [&](int, i64 b, i64 e) {
            int found = 0;
            for (i64 k = 4 * b; k < 4 * e; ++k) {
              found |= corners.data()[k] < 0 || corners.data()[k] >= nv;
            }
            for (i64 k = 2 * b; k < 2 * e; ++k) {
              found |= (sides.data()[k] < -1 || sides.data()[k] >= nlabels) << 1;
            }
            if (found) bad |= found;
          });
          if (bad & 1) throw std::invalid_argument("label_quads: a corner is not a vertex");
          if (bad & 2) throw std::invalid_argument("label_quads: a side is not a label index");
          quad_cuts(corners.data(), nq, vertices.data(), threads, cut.data());
          if (nq <= i64(std::numeric_limits<i32>::max())) {
            label_quads(sides.data(), nq, nlabels, small, off, inside);
          } else {
            label_quads(sides.data(), nq, nlabels, large, off, inside);
          }
        }
        nb::object quads = nq <= i64(std::numeric_limits<i32>::max()) ? give(std::move(small))
                                                                      : give(std::move(large));
        return nb::make_tuple(give(std::move(cut)), quads, give(std::move(off)),
                              give(std::move(inside)));
      },
      "corners"_a, "vertices"_a, "sides"_a, "nlabels"_a, "threads"_a,
      "(cut (Q,) uint8, quads, offsets (L + 1,), inside (L,)): how each quad is cut into "
      "triangles, and each label's quads (int32 or int64; those it is inside of first).");
  m.def(
      "label_triangles",
      [](Int64s corners, nb::ndarray<const u8, nb::ndim<1>, nb::c_contig, nb::device::cpu> cut,
         int threads) {
        if (corners.ndim() != 2 || corners.shape(1) != 4 || cut.shape(0) != corners.shape(0)) {
          throw std::invalid_argument("label_triangles: corners (Q, 4), cut (Q,)");
        }
        const i64 nq = i64(corners.shape(0));
        Vec<i64> cells(static_cast<size_t>(6 * nq));
        {
          nb::gil_scoped_release unlocked;
          const i64 *c = corners.data();
          const u8 *k = cut.data();
          iso::parallel_for(nq, threads, 1 << 15, [&](int, i64 b, i64 e) {
            for (i64 q = b; q < e; ++q) {
              for (int j = 0; j < 6; ++j) cells[size_t(6 * q + j)] = c[4 * q + kCutOrder[k[q] != 0][j]];
            }
          });
        }
        return give(std::move(cells), 3);
      },
      "corners"_a, "cut"_a, "threads"_a,
      "(2Q, 3) int64: the two triangles of each quad, cut as label_quads says.");
  auto one = [](Int64s corners, nb::ndarray<const u8, nb::ndim<1>, nb::c_contig, nb::device::cpu> cut,
                Doubles vertices, auto quads, i64 inside) {
    const i64 nq = i64(corners.shape(0)), nv = i64(vertices.shape(0)), n = i64(quads.shape(0));
    if (corners.ndim() != 2 || corners.shape(1) != 4 || cut.shape(0) != corners.shape(0) ||
        vertices.ndim() != 2 || vertices.shape(1) != 3 || inside < 0 || inside > n) {
      throw std::invalid_argument(
          "label_mesh: corners (Q, 4), cut (Q,), vertices (V, 3), 0 <= inside <= quads");
    }
    OneLabel r;
    {
      // checked with the GIL released: label files are written by several threads
      nb::gil_scoped_release unlocked;
      for (i64 k = 0; k < n; ++k) {
        const i64 q = i64(quads.data()[k]);
        if (q < 0 || q >= nq) throw std::invalid_argument("label_mesh: a quad index is out of range");
        for (int j = 0; j < 4; ++j) {
          const i64 c = corners.data()[4 * q + j];
          if (c < 0 || c >= nv) throw std::invalid_argument("label_mesh: a corner is not a vertex");
        }
      }
      label_mesh(corners.data(), cut.data(), vertices.data(), quads.data(), n, inside, r);
    }
    return nb::make_tuple(give(std::move(r.faces)), give(std::move(r.used)),
                          give(std::move(r.local), 3), give(std::move(r.verts), 3));
  };
  const char *one_doc =
      "(faces (2n,), used (U,), local (2n, 3), verts (U, 3)): one label's triangles of the "
      "combined mesh, its vertices, and its triangles over them, from its n quads of "
      "label_quads (the first `inside` of them it is inside of).";
  m.def(
      "label_mesh",
      [one](Int64s corners, nb::ndarray<const u8, nb::ndim<1>, nb::c_contig, nb::device::cpu> cut,
            Doubles vertices, nb::ndarray<const i32, nb::ndim<1>, nb::c_contig, nb::device::cpu> quads,
            i64 inside) { return one(corners, cut, vertices, quads, inside); },
      "corners"_a, "cut"_a, "vertices"_a, "quads"_a.noconvert(), "inside"_a, one_doc);
  m.def(
      "label_mesh",
      [one](Int64s corners, nb::ndarray<const u8, nb::ndim<1>, nb::c_contig, nb::device::cpu> cut,
            Doubles vertices, Int64s quads, i64 inside) {
        if (quads.ndim() != 1) throw std::invalid_argument("label_mesh: quads (n,)");
        return one(corners, cut, vertices, quads, inside);
      },
      "corners"_a, "cut"_a, "vertices"_a, "quads"_a, "inside"_a, one_doc);
}
