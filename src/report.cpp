// Kernels of the mesh report (isoconvert/report.py); see report.hpp.
#include "report.hpp"

#include "bind.hpp"
#include "corners.hpp"

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <atomic>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>

namespace iso::report {

namespace {

// --- small pieces ---------------------------------------------------------------------

// splitmix64's finalizer, as isoconvert.graph.mix64.
inline u64 mix64(u64 x) {
  x ^= x >> 30;
  x *= 0xBF58476D1CE4E5B9ULL;
  x ^= x >> 27;
  x *= 0x94D049BB133111EBULL;
  x ^= x >> 31;
  return x;
}

// The bits of a coordinate with -0.0 turned into 0.0 (x + 0.0 does that and
// nothing else, so the compiler keeps it).
inline u64 coordinate_bits(double x) {
  x += 0.0;
  u64 u;
  std::memcpy(&u, &x, sizeof u);
  return u;
}

// The hash isoconvert.graph.row_groups gives the row (x, y, z).
inline u64 position_hash(const double *p) {
  u64 h = mix64(coordinate_bits(p[0]));
  h = mix64(h ^ coordinate_bits(p[1]));
  return mix64(h ^ coordinate_bits(p[2]));
}

inline bool same_position(const double *xyz, i64 a, i64 b) {
  for (int k = 0; k < 3; ++k) {
    if (coordinate_bits(xyz[3 * a + k]) != coordinate_bits(xyz[3 * b + k])) return false;
  }
  return true;
}

// Per-chunk lists joined in chunk order: what parallel_for's chunks append
// comes out in the order of a serial loop, whichever thread ran them.
template <class T>
struct ChunkLists {
  std::vector<std::vector<T>> parts;
  explicit ChunkLists(i64 chunks) : parts(static_cast<size_t>(std::max<i64>(chunks, 0))) {}
  std::vector<T> &operator[](i64 chunk) { return parts[static_cast<size_t>(chunk)]; }
  std::vector<T> joined() {
    size_t n = 0;
    for (const auto &p : parts) n += p.size();
    std::vector<T> out;
    out.reserve(n);
    for (auto &p : parts) {
      out.insert(out.end(), p.begin(), p.end());
      std::vector<T>().swap(p);
    }
    return out;
  }
};

template <class T>
void append(std::vector<T> &to, std::vector<T> &from) {
  to.insert(to.end(), from.begin(), from.end());
  std::vector<T>().swap(from);
}

// --- merging positions --------------------------------------------------------------

// Keys by lexicographic order of the coordinates' bits (np.lexsort over
// x, y, z): what row_groups falls back to when two different positions
// share a hash, which almost never happens.
template <class I>
Merged merge_lexicographic(const double *xyz, i64 n, u64 *key, I *rep) {
  std::vector<i64> order(static_cast<size_t>(n));
  std::iota(order.begin(), order.end(), i64(0));
  std::sort(order.begin(), order.end(), [xyz](i64 a, i64 b) {
    for (int k = 0; k < 3; ++k) {
      const u64 x = coordinate_bits(xyz[3 * a + k]), y = coordinate_bits(xyz[3 * b + k]);
      if (x != y) return x < y;
    }
    return a < b;
  });
  i64 r = -1, first = 0;
  for (i64 q = 0; q < n; ++q) {
    const i64 i = order[q];
    if (q == 0 || !same_position(xyz, i, first)) {
      ++r;
      first = i;
    }
    key[i] = static_cast<u64>(r);
    rep[i] = static_cast<I>(first);
  }
  return {r + 1, true};
}

}  // namespace

// Equal positions have equal hashes: the vertices are split by the top bits
// of their hash into buckets of a few thousand (one counting pass, filled in
// index order), and each bucket finds its equal hashes in a small hash table
// that stays in cache. A sort of all n hashes, or one big hash table, would
// wait on memory for most of its steps.
template <class I>
Merged merge_positions(const double *xyz, i64 n, int threads, u64 *key, I *rep) {
  if (n == 0) return {};
  int bits = 0;
  while (bits < 24 && (i64(1) << (bits + 11)) < n) ++bits;
  const i64 nb = i64(1) << bits;
  auto bucket = [bits](u64 h) -> i64 { return bits ? i64(h >> (64 - bits)) : 0; };
  // parts: fixed slices of the vertices, one histogram each; a slice of less than
  // 32k vertices is not worth a thread (the float32 checks of label meshes hash a
  // few hundred vertices, where starting threads cost more than the hashing)
  const i64 parts = std::max<i64>(1, std::min<i64>({i64(threads), i64(16), (n + 32767) / 32768}));
  auto slice = [n, parts](i64 p) { return n * p / parts; };
  std::vector<i64> at(static_cast<size_t>(parts * nb), 0);
  // this pass reads every coordinate: it also finds the largest finite one,
  // which the flatness test needs (isoconvert.geometry.flat_bound)
  std::vector<double> largest(static_cast<size_t>(parts), 0.0);
  parallel_for(parts, threads, 1, [&](int, i64 p0, i64 p1) {
    for (i64 p = p0; p < p1; ++p) {
      i64 *count = at.data() + p * nb;
      double big = 0.0;
      for (i64 i = slice(p); i < slice(p + 1); ++i) {
        const u64 h = position_hash(xyz + 3 * i);
        key[i] = h;
        rep[i] = static_cast<I>(i);
        ++count[bucket(h)];
        for (int k = 0; k < 3; ++k) {
          const double a = std::fabs(xyz[3 * i + k]);
          big = a > big && a <= std::numeric_limits<double>::max() ? a : big;  // not NaN, inf
        }
      }
      largest[p] = big;
    }
  });
  const double magnitude = *std::max_element(largest.begin(), largest.end());
  // where each (bucket, part) run starts: buckets in order, parts in order
  // inside a bucket, so every bucket lists its vertices in index order
  std::vector<i64> start(static_cast<size_t>(nb + 1));
  i64 total = 0;
  for (i64 b = 0; b < nb; ++b) {
    start[b] = total;
    for (i64 p = 0; p < parts; ++p) {
      const i64 c = at[p * nb + b];
      at[p * nb + b] = total;
      total += c;
    }
  }
  start[nb] = total;
  std::vector<I> items(static_cast<size_t>(n));
  parallel_for(parts, threads, 1, [&](int, i64 p0, i64 p1) {
    for (i64 p = p0; p < p1; ++p) {
      i64 *cursor = at.data() + p * nb;
      for (i64 i = slice(p); i < slice(p + 1); ++i) {
        items[cursor[bucket(key[i])]++] = static_cast<I>(i);
      }
    }
  });
  std::vector<i64>().swap(at);
  std::atomic<bool> collided{false};
  std::atomic<i64> merged{0};
  std::vector<std::vector<I>> tables(static_cast<size_t>(std::max(threads, 1)));
  parallel_for(nb, threads, 16, [&](int worker, i64 b0, i64 b1) {
    auto &table = tables[worker];
    bool clash = false;
    i64 same = 0;
    for (i64 b = b0; b < b1; ++b) {
      const i64 size = start[b + 1] - start[b];
      size_t slots = 16;
      while (slots < size_t(2 * size)) slots *= 2;
      table.assign(slots, I(-1));
      const size_t mask = slots - 1;
      for (i64 q = start[b]; q < start[b + 1]; ++q) {
        const I i = items[q];
        const u64 h = key[i];
        // the bucket took the top bits; the slot comes from the bottom ones
        for (size_t s = size_t(h) & mask;; s = (s + 1) & mask) {
          const I j = table[s];
          if (j < 0) {
            table[s] = i;
            break;
          }
          if (key[j] != h) continue;
          if (same_position(xyz, i, j)) {
            rep[i] = j;  // j < i: the first vertex at this position
            ++same;
          } else {
            clash = true;
          }
          break;
        }
      }
    }
    merged += same;
    if (clash) collided = true;
  });
  Merged result{n - merged.load(), false, magnitude};
  if (collided) {
    result = merge_lexicographic(xyz, n, key, rep);
    result.magnitude = magnitude;
  }
  return result;
}

// --- triangles ------------------------------------------------------------------------

namespace {

// numpy's pairwise summation (DOUBLE_pairwise_sum in loops_utils.h.src), the
// sum of the values value(lo) ... value(lo + n - 1): below 8 values one by
// one, up to 128 in 8 interleaved sums, above that the two halves (the
// first a multiple of 8) summed apart and added. np.add.reduce of a
// contiguous float64 array is 0.0 + this over the whole array.
template <class Value>
double pairwise_sum(i64 lo, i64 n, Value &&value) {
  if (n < 8) {
    double res = 0.0;
    for (i64 i = 0; i < n; ++i) res += value(lo + i);
    return res;
  }
  if (n <= 128) {
    double r[8];
    for (int k = 0; k < 8; ++k) r[k] = value(lo + k);
    i64 i = 8;
    for (; i < n - n % 8; i += 8) {
      for (int k = 0; k < 8; ++k) r[k] += value(lo + i + k);
    }
    double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for (; i < n; ++i) res += value(lo + i);
    return res;
  }
  i64 n2 = n / 2;
  n2 -= n2 % 8;
  return pairwise_sum(lo, n2, value) + pairwise_sum(lo + n2, n - n2, value);
}

// The subtrees of that summation of at most `size` values, in order.
void subtrees(i64 lo, i64 n, i64 size, std::vector<std::pair<i64, i64>> &out) {
  if (n <= size) {
    out.emplace_back(lo, n);
    return;
  }
  i64 n2 = n / 2;
  n2 -= n2 % 8;
  subtrees(lo, n2, size, out);
  subtrees(lo + n2, n - n2, size, out);
}

// Adds the subtrees' sums as the summation does above them.
double join_subtrees(i64 n, i64 size, const double *sums, size_t &next) {
  if (n <= size) return sums[next++];
  i64 n2 = n / 2;
  n2 -= n2 % 8;
  const double a = join_subtrees(n2, size, sums, next);
  return a + join_subtrees(n - n2, size, sums, next);
}

}  // namespace

// Triangles are taken in the subtrees of numpy's pairwise summation (each
// subtree on one thread, its leaves of at most 128 triangles through a small
// buffer), so the total area is np.sum of numpy's |cross| values to the bit
// without an array of them.
template <class I, class C>
double triangle_pass(const C *cells, i64 nt, const I *rep, const double *xyz, double flat_below,
                     int threads, I *tv, TriangleLists &out) {
  const i64 size = 1 << 15;
  std::vector<std::pair<i64, i64>> parts;
  subtrees(0, nt, size, parts);
  const i64 chunks = i64(parts.size());
  ChunkLists<i64> repeated(chunks), flat(chunks), collapsed(chunks);
  std::vector<double> sums(parts.size(), 0.0);
  parallel_for(chunks, threads, 1, [&](int, i64 c0, i64 c1) {
    double norms[128];
    for (i64 chunk = c0; chunk < c1; ++chunk) {
      // |cross| of triangles t0 .. t1 - 1 into norms, and what else they show
      auto measure = [&](i64 t0, i64 t1) {
        for (i64 t = t0; t < t1; ++t) {
          const C *c = cells + 3 * t;
          const I r[3] = {rep[c[0]], rep[c[1]], rep[c[2]]};
          if (tv) {
            tv[3 * t] = r[0];
            tv[3 * t + 1] = r[1];
            tv[3 * t + 2] = r[2];
          }
          for (int j = 0; j < 3; ++j) {
            const int k = j == 2 ? 0 : j + 1;
            if (r[j] == r[k] && c[j] != c[k]) {
              collapsed[chunk].push_back(i64(std::min(c[j], c[k])));
              collapsed[chunk].push_back(i64(std::max(c[j], c[k])));
            }
          }
          // numpy's np.cross and np.linalg.norm, operation for operation
          // (the build has no FMA contraction): the same bits
          const double *p0 = xyz + 3 * i64(r[0]), *p1 = xyz + 3 * i64(r[1]),
                       *p2 = xyz + 3 * i64(r[2]);
          double a[3], b[3];
          for (int k = 0; k < 3; ++k) {
            const double o = p0[k] + 0.0;
            a[k] = (p1[k] + 0.0) - o;
            b[k] = (p2[k] + 0.0) - o;
          }
          const double x = a[1] * b[2] - a[2] * b[1];
          const double y = a[2] * b[0] - a[0] * b[2];
          const double z = a[0] * b[1] - a[1] * b[0];
          const double norm = std::sqrt((x * x + y * y) + z * z);
          norms[t - t0] = norm;
          if (r[0] == r[1] || r[1] == r[2] || r[0] == r[2]) {
            repeated[chunk].push_back(t);
          } else if (!(norm > flat_below)) {
            flat[chunk].push_back(t);
          }
        }
      };
      // the subtree's leaves are its runs of at most 128 values, met in
      // order: measure each run on first sight
      i64 run = -1, run_end = -1;
      const i64 lo = parts[chunk].first, n = parts[chunk].second;
      sums[chunk] = pairwise_sum(lo, n, [&](i64 t) {
        if (t >= run_end) {
          run = t;
          run_end = std::min(lo + n, t + 128);
          measure(run, run_end);
        }
        return norms[t - run];
      });
    }
  });
  out.repeated = repeated.joined();
  out.flat_candidates = flat.joined();
  out.collapsed = collapsed.joined();
  size_t next = 0;
  return 0.0 + (nt ? join_subtrees(nt, size, sums.data(), next) : 0.0);
}

// --- edges, fans, duplicates, components ------------------------------------------------

namespace {

// What a chunk of vertices found, joined in chunk order afterwards.
struct Found {
  std::vector<i64> boundary, non_manifold_edges, inconsistent, non_manifold_vertices, fans;
  std::vector<i64> dup_triangles, dup_sizes, all_edges, all_counts;
  i64 edges = 0, used = 0;
};

// One use of an edge {v, w} at v.
template <class I>
struct Use {
  I local;   // the corner of v
  I third;   // its triangle's third vertex
  i64 tri;   // its triangle
  bool out;  // the triangle runs v -> w
};

template <class I>
struct RingEntry {
  I other;  // a neighbour
  I at;     // place in the ring
};

// A worker's buffers, reused from vertex to vertex.
template <class I>
struct Scratch {
  std::vector<I> ring, up;
  std::vector<RingEntry<I>> entries;
  std::vector<Use<I>> uses;
  std::vector<std::pair<I, i64>> thirds;
};

// Everything the report asks about the corners around one vertex.
//
// Around v, corner q (of k) has a next vertex nx[q] and a previous one pv[q]:
// the other ends of its two edges at v, used v -> nx[q] ("out") and
// pv[q] -> v. An edge {v, w} is used once per corner listing w; it is
// counted, and its multiplicity judged, at its lower end. Corners joined by
// an edge used exactly twice belong to one fan.
template <class I, class C>
struct Around {
  static constexpr int kFast = 16;  // corners handled by the closed-fan path

  const C *tv;      // the triangles' vertices (values below 2^31 when I is int32)
  const I *offset;  // v's corners are corner[offset[v]:offset[v + 1]]
  const I *corner;  // 3 t + j: corner j of triangle t
  SharedForest<I> forest;
  bool all_edges;
  u8 *used;
  I *lo_edges;  // edges whose lower end v is
  u8 *flags;    // 1: one of those is not used twice; 2: more than one fan at v

  void visit(I v, Found &f, Scratch<I> &s) const {
    const I *cs = corner + offset[v];
    const i64 k = offset[v + 1] - offset[v];
    used[v] = k > 0;
    if (k == 0) return;
    ++f.used;
    if (k > kFast || !closed_fan(v, cs, k, f)) general(v, cs, k, f, s);
  }

  // The usual interior vertex of an oriented manifold: each corner's next
  // vertex is the previous vertex of exactly one corner, and each corner is
  // found so once, so every edge at v is used twice, once each way, and "the
  // corner across the edge v -> nx[q]" is a permutation of the corners whose
  // cycles are the fans. Compares are on at most 16 values, 4 at a time.
  // Returns false, having changed nothing, for any other vertex.
  bool closed_fan(I v, const I *cs, i64 k, Found &f) const {
    // pv: 4 more for padding up to the next group of 4, with a value no vertex has
    alignas(16) I nx[kFast], pv[kFast + 4];
    const int groups = int((k + 3) / 4);
    for (int q = 0; q < k; ++q) {
      const I c = cs[q], t3 = c - c % 3, j = c - t3;
      nx[q] = static_cast<I>(tv[t3 + (j == 2 ? 0 : j + 1)]);
      pv[q] = static_cast<I>(tv[t3 + (j == 0 ? 2 : j - 1)]);
    }
    for (int p = 0; p < 4; ++p) pv[k + p] = -1;
    int across[kFast];
    unsigned higher = 0, hit = 0;  // corners whose next vertex is above v; corners met
    for (int q = 0; q < k; ++q) {
      const unsigned as_prev = matches(pv, nx[q], groups);
      if (as_prev == 0 || (as_prev & (as_prev - 1)) != 0) return false;  // not once
      across[q] = ctz(as_prev);
      hit |= as_prev;
      higher |= unsigned(nx[q] > v) << q;
    }
    // each next vertex met once among the previous ones, and every corner met
    // (so no next vertex twice): the edges at v are the k pairs (q, across[q])
    if (hit != (1u << k) - 1) return false;
    i64 fans = 1;
    int steps = 1;
    for (int r = across[0]; r != 0; r = across[r]) ++steps;
    if (steps < k) {  // more than one cycle: count them
      unsigned seen = 0;
      fans = 0;
      for (int q = 0; q < k; ++q) {
        if (seen >> q & 1) continue;
        ++fans;
        int r = q;
        do {
          seen |= 1u << r;
          r = across[r];
        } while (r != q);
      }
    }
    I top = v;
    for (unsigned m = higher; m; m &= m - 1) {
      const int q = ctz(m), r = across[q];
      const I w = nx[q], x = pv[q];  // the triangles (v, w, x) and (v, nx[r], w)
      if (all_edges) {
        f.all_edges.push_back(v);
        f.all_edges.push_back(w);
        f.all_counts.push_back(2);
      }
      if (x > w && x == nx[r]) {
        const i64 a = cs[q] / 3, b = cs[r] / 3;
        f.dup_triangles.push_back(std::min(a, b));
        f.dup_triangles.push_back(std::max(a, b));
        f.dup_sizes.push_back(2);
      }
      top = forest.join(top, w);
    }
    const I lower = static_cast<I>(popcount(higher));
    f.edges += lower;
    lo_edges[v] = lower;
    flags[v] = 0;
    if (fans > 1) {
      f.non_manifold_vertices.push_back(v);
      f.fans.push_back(fans);
      flags[v] = 2;
    }
    return true;
  }

  // Any vertex: group the ring's 2k entries by neighbour (by scanning when
  // short, else by sorting) and judge each edge from its uses.
  void general(I v, const I *cs, i64 k, Found &f, Scratch<I> &s) const {
    const i64 n = 2 * k;
    auto &ring = s.ring;  // ring[2 q] = nx[q], ring[2 q + 1] = pv[q]
    ring.resize(static_cast<size_t>(n));
    for (i64 q = 0; q < k; ++q) {
      const I c = cs[q], t3 = c - c % 3, j = c - t3;
      ring[2 * q] = static_cast<I>(tv[t3 + (j == 2 ? 0 : j + 1)]);
      ring[2 * q + 1] = static_cast<I>(tv[t3 + (j == 0 ? 2 : j - 1)]);
    }
    auto &up = s.up;  // the fans: a union-find over v's corners
    up.resize(static_cast<size_t>(k));
    std::iota(up.begin(), up.end(), I(0));
    auto root = [&up](I x) {
      while (up[x] != x) x = up[x] = up[up[x]];
      return x;
    };
    i64 fans = k;
    I lower = 0, top = v;
    u8 flag = 0;
    // one edge {v, w} and its m uses at v, in ascending order of triangle
    auto edge = [&](I w, const Use<I> *use, i64 m) {
      if (m == 2) {
        const I a = root(use[0].local), b = root(use[1].local);
        if (a != b) {
          up[std::max(a, b)] = std::min(a, b);
          --fans;
        }
      }
      if (w < v) return;
      ++lower;
      if (all_edges) {
        f.all_edges.push_back(v);
        f.all_edges.push_back(w);
        f.all_counts.push_back(m);
      }
      if (m == 1) {
        f.boundary.push_back(v);
        f.boundary.push_back(w);
        flag |= 1;
      } else if (m == 2) {
        // used once each way unless both triangles run the same way
        if (use[0].out == use[1].out) {
          f.inconsistent.push_back(v);
          f.inconsistent.push_back(w);
        }
        if (use[0].third > w && use[0].third == use[1].third) {
          f.dup_triangles.push_back(use[0].tri);
          f.dup_triangles.push_back(use[1].tri);
          f.dup_sizes.push_back(2);
        }
      } else {
        f.non_manifold_edges.push_back(v);
        f.non_manifold_edges.push_back(w);
        flag |= 1;
        // triangles whose two lowest vertices are v < w: equal third
        // vertices make duplicates (so each group is found at one edge)
        auto &th = s.thirds;
        th.clear();
        for (i64 q = 0; q < m; ++q) {
          if (use[q].third > w) th.emplace_back(use[q].third, use[q].tri);
        }
        std::sort(th.begin(), th.end());
        for (size_t a = 0, b; a < th.size(); a = b) {
          for (b = a + 1; b < th.size() && th[b].first == th[a].first; ++b) {
          }
          if (b - a > 1) {
            for (size_t q = a; q < b; ++q) f.dup_triangles.push_back(th[q].second);
            f.dup_sizes.push_back(static_cast<i64>(b - a));
          }
        }
      }
      top = forest.join(top, w);
    };
    auto &use = s.uses;
    use.resize(static_cast<size_t>(n));
    auto use_at = [&](i64 p) -> Use<I> {
      const i64 q = p >> 1;
      return {static_cast<I>(q), ring[p ^ 1], i64(cs[q] / 3), (p & 1) == 0};
    };
    if (k <= kFast) {  // few corners: find each neighbour's uses by scanning
      for (i64 i = 0; i < n; ++i) {
        const I w = ring[i];
        bool seen = false;
        for (i64 p = 0; p < i; ++p) seen |= ring[p] == w;
        if (seen) continue;
        i64 m = 0;
        for (i64 p = i; p < n; ++p) {
          if (ring[p] == w) use[m++] = use_at(p);
        }
        edge(w, use.data(), m);
      }
    } else {  // many: sort the ring's entries by neighbour
      auto &e = s.entries;
      e.resize(static_cast<size_t>(n));
      for (i64 p = 0; p < n; ++p) e[p] = {ring[p], static_cast<I>(p)};
      std::sort(e.begin(), e.end(), [](const RingEntry<I> &a, const RingEntry<I> &b) {
        return a.other < b.other || (a.other == b.other && a.at < b.at);
      });
      for (i64 g0 = 0, g1; g0 < n; g0 = g1) {
        const I w = e[g0].other;
        for (g1 = g0; g1 < n && e[g1].other == w; ++g1) use[g1 - g0] = use_at(e[g1].at);
        edge(w, use.data(), g1 - g0);
      }
    }
    f.edges += lower;
    lo_edges[v] = lower;
    if (fans > 1) {
      f.non_manifold_vertices.push_back(v);
      f.fans.push_back(fans);
      flag |= 2;
    }
    flags[v] = flag;
  }
};

}  // namespace

template <class I, class C>
void topology(const C *tv, i64 nt, i64 nv, const u64 *key, int threads, bool all_edges, u8 *used,
              Topology &out) {
  out = Topology();
  if (nv == 0) return;

  // 1. corners by vertex
  Buffer<I> offset(nv + 1), corner(0);
  corners_by_vertex(tv, nt, nv, threads, offset, corner);
  out.kept = corner.size() / 3;

  // 2. around each vertex; components by a shared union-find
  Buffer<I> parent(nv), lo_edges(nv);
  Buffer<u8> flags(nv);
  parallel_for(nv, threads, 1 << 16, [&](int, i64 v0, i64 v1) {
    for (i64 v = v0; v < v1; ++v) parent[v] = static_cast<I>(v);
  });
  const i64 grain = 2048;
  std::vector<Found> found(static_cast<size_t>(chunk_count(nv, grain)));
  std::vector<Scratch<I>> scratch(static_cast<size_t>(std::max(threads, 1)));
  const Around<I, C> around{tv,        offset.data(), corner.data(),   {parent.data()},
                            all_edges, used,          lo_edges.data(), flags.data()};
  parallel_for(nv, threads, grain, [&](int worker, i64 v0, i64 v1) {
    Found &f = found[v0 / grain];
    Scratch<I> &s = scratch[worker];
    for (i64 v = v0; v < v1; ++v) around.visit(static_cast<I>(v), f, s);
  });
  std::free(corner.release());
  std::vector<i64> dup_sizes;
  for (auto &f : found) {
    out.edges += f.edges;
    out.used += f.used;
    append(out.boundary, f.boundary);
    append(out.non_manifold_edges, f.non_manifold_edges);
    append(out.inconsistent, f.inconsistent);
    append(out.non_manifold_vertices, f.non_manifold_vertices);
    append(out.fans, f.fans);
    append(out.dup_triangles, f.dup_triangles);
    append(dup_sizes, f.dup_sizes);
    append(out.all_edges, f.all_edges);
    append(out.all_counts, f.all_counts);
  }
  out.dup_starts.assign(1, 0);
  for (i64 size : dup_sizes) out.dup_starts.push_back(out.dup_starts.back() + size);

  // 3. components, numbered in order of their smallest vertex (their root)
  // a. every used vertex points at its root (a walk up; the pointers it
  //    meets only ever move to ancestors, so other threads' walks stay valid)
  const i64 cgrain = 1 << 14;
  const i64 cchunks = chunk_count(nv, cgrain);
  std::vector<i64> roots(static_cast<size_t>(cchunks + 1), 0);
  parallel_for(nv, threads, cgrain, [&](int, i64 v0, i64 v1) {
    i64 n = 0;
    for (i64 v = v0; v < v1; ++v) {
      if (!used[v]) continue;
      I r = static_cast<I>(v), p;
      while ((p = __atomic_load_n(&parent[r], __ATOMIC_RELAXED)) != r) r = p;
      __atomic_store_n(&parent[v], r, __ATOMIC_RELAXED);
      n += r == v;
    }
    roots[v0 / cgrain + 1] = n;
  });
  for (i64 c = 0; c < cchunks; ++c) roots[c + 1] += roots[c];
  const i64 n_comp = roots[cchunks];
  // b. a root's slot in parent takes its component's number, and flag 4 says
  //    so (the others keep pointing at their root)
  parallel_for(nv, threads, cgrain, [&](int, i64 v0, i64 v1) {
    i64 c = roots[v0 / cgrain];
    for (i64 v = v0; v < v1; ++v) {
      if (used[v] && parent[v] == v) {
        parent[v] = static_cast<I>(c++);
        flags[v] |= 4;
      }
    }
  });
  // c. sums per component, added once per run of vertices of one component
  //    (atomics: integer sums, minima and ORs come out the same in any order);
  //    a component's triangles are a third of its vertices' corners
  out.comp_vertices.assign(static_cast<size_t>(n_comp), 0);
  out.comp_edges.assign(static_cast<size_t>(n_comp), 0);
  out.comp_triangles.assign(static_cast<size_t>(n_comp), 0);
  out.comp_min_key.assign(static_cast<size_t>(n_comp), ~u64(0));
  out.comp_open.assign(static_cast<size_t>(n_comp), 0);
  out.comp_bad.assign(static_cast<size_t>(n_comp), 0);
  parallel_for(nv, threads, cgrain, [&](int, i64 v0, i64 v1) {
    i64 comp = -1, vertices = 0, edges = 0, corners = 0;
    u64 low = ~u64(0);
    u8 any = 0;
    auto flush = [&] {
      if (comp < 0) return;
      __atomic_fetch_add(&out.comp_vertices[comp], vertices, __ATOMIC_RELAXED);
      __atomic_fetch_add(&out.comp_edges[comp], edges, __ATOMIC_RELAXED);
      __atomic_fetch_add(&out.comp_triangles[comp], corners, __ATOMIC_RELAXED);
      u64 seen = __atomic_load_n(&out.comp_min_key[comp], __ATOMIC_RELAXED);
      while (low < seen && !__atomic_compare_exchange_n(&out.comp_min_key[comp], &seen, low, true,
                                                        __ATOMIC_RELAXED, __ATOMIC_RELAXED)) {
      }
      if (any & 1) __atomic_fetch_or(&out.comp_open[comp], u8(1), __ATOMIC_RELAXED);
      if (any & 2) __atomic_fetch_or(&out.comp_bad[comp], u8(1), __ATOMIC_RELAXED);
    };
    for (i64 v = v0; v < v1; ++v) {
      if (!used[v]) continue;
      const i64 c = (flags[v] & 4) ? parent[v] : parent[parent[v]];
      if (c != comp) {
        flush();
        comp = c;
        vertices = edges = corners = 0;
        low = ~u64(0);
        any = 0;
      }
      ++vertices;
      edges += lo_edges[v];
      corners += offset[v + 1] - offset[v];
      low = std::min(low, key[v]);
      any |= flags[v];
    }
    flush();
  });
  for (auto &n : out.comp_triangles) n /= 3;
}

template <class C>
double enclosed_volume(const double *xyz, const C *tv, i64 nt, const u8 *used, i64 nv,
                       int threads) {
  // partial sums over fixed chunks, added in chunk order: the same bits on
  // any number of threads
  const i64 grain = 65536;
  std::vector<double> part(static_cast<size_t>(3 * chunk_count(nv, grain)), 0.0);
  std::vector<i64> count(static_cast<size_t>(chunk_count(nv, grain)), 0);
  parallel_for(nv, threads, grain, [&](int, i64 v0, i64 v1) {
    double s[3] = {0.0, 0.0, 0.0};
    i64 n = 0;
    for (i64 v = v0; v < v1; ++v) {
      if (!used[v]) continue;
      ++n;
      for (int k = 0; k < 3; ++k) s[k] += xyz[3 * v + k] + 0.0;
    }
    const i64 c = v0 / grain;
    for (int k = 0; k < 3; ++k) part[3 * c + k] = s[k];
    count[c] = n;
  });
  double centre[3] = {0.0, 0.0, 0.0};
  i64 n_used = 0;
  for (size_t c = 0; c < count.size(); ++c) {
    for (int k = 0; k < 3; ++k) centre[k] += part[3 * c + k];
    n_used += count[c];
  }
  for (int k = 0; k < 3; ++k) centre[k] = n_used ? centre[k] / double(n_used) : 0.0;
  std::vector<double> sums(static_cast<size_t>(chunk_count(nt, grain)), 0.0);
  parallel_for(nt, threads, grain, [&](int, i64 t0, i64 t1) {
    double s = 0.0;
    for (i64 t = t0; t < t1; ++t) {
      const double *p0 = xyz + 3 * i64(tv[3 * t]), *p1 = xyz + 3 * i64(tv[3 * t + 1]),
                   *p2 = xyz + 3 * i64(tv[3 * t + 2]);
      double a[3], b[3], d[3];
      for (int k = 0; k < 3; ++k) {
        const double o = p0[k] + 0.0;
        a[k] = (p1[k] + 0.0) - o;
        b[k] = (p2[k] + 0.0) - o;
        d[k] = o - centre[k];
      }
      const double x = a[1] * b[2] - a[2] * b[1];
      const double y = a[2] * b[0] - a[0] * b[2];
      const double z = a[0] * b[1] - a[1] * b[0];
      s += (d[0] * x + d[1] * y) + d[2] * z;
    }
    sums[t0 / grain] = s;
  });
  double total = 0.0;
  for (double s : sums) total += s;
  return total / 6.0;
}

template Merged merge_positions<std::int32_t>(const double *, i64, int, u64 *, std::int32_t *);
template Merged merge_positions<i64>(const double *, i64, int, u64 *, i64 *);
#define ISO_TRIANGLE_PASS(I, C)                                                       \
  template double triangle_pass<I, C>(const C *, i64, const I *, const double *, double, int, \
                                      I *, TriangleLists &);
ISO_TRIANGLE_PASS(std::int32_t, std::int32_t)
ISO_TRIANGLE_PASS(std::int32_t, i64)
ISO_TRIANGLE_PASS(i64, std::int32_t)
ISO_TRIANGLE_PASS(i64, i64)
#undef ISO_TRIANGLE_PASS
#define ISO_TOPOLOGY(I, C)                                                                   \
  template void topology<I, C>(const C *, i64, i64, const u64 *, int, bool, u8 *, Topology &);
ISO_TOPOLOGY(std::int32_t, std::int32_t)
ISO_TOPOLOGY(std::int32_t, i64)
ISO_TOPOLOGY(i64, std::int32_t)
ISO_TOPOLOGY(i64, i64)
#undef ISO_TOPOLOGY
template double enclosed_volume<std::int32_t>(const double *, const std::int32_t *, i64,
                                              const u8 *, i64, int);
template double enclosed_volume<i64>(const double *, const i64 *, i64, const u8 *, i64, int);

}  // namespace iso::report

// --- bindings -------------------------------------------------------------------------------

namespace nb = nanobind;
using namespace nb::literals;
using iso::i64;
using iso::report::u64;
using iso::report::u8;
using iso::bind::give;

namespace {

template <class T>
using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;

template <class A>
void expect(const A &a, i64 rows, i64 cols, const char *name) {
  const bool ok = cols ? (a.ndim() == 2 && i64(a.shape(0)) == rows && i64(a.shape(1)) == cols)
                       : (a.ndim() == 1 && i64(a.shape(0)) == rows);
  if (!ok) throw std::invalid_argument(std::string(name) + " has the wrong shape");
}

// A kernel's output array, handed to numpy once filled (see Buffer).
template <class T>
class Output {
 public:
  explicit Output(i64 n, i64 cols = 0) : buffer_(n * (cols ? cols : 1)), n_(n), cols_(cols) {}
  T *data() { return buffer_.data(); }
  nb::object array() {
    T *p = buffer_.release();
    nb::capsule owner(p, [](void *q) noexcept { std::free(q); });
    const size_t shape[2] = {size_t(n_), size_t(cols_)};
    return nb::cast(nb::ndarray<nb::numpy, T>(p, cols_ ? 2 : 1, shape, owner));
  }

 private:
  iso::Buffer<T> buffer_;
  i64 n_, cols_;
};

template <class I>
void bind_index_type(nb::module_ &m, const char *suffix) {
  namespace r = iso::report;
  m.def(
      (std::string("merge_positions_") + suffix).c_str(),
      [](In<double> xyz, int threads) {
        const i64 n = xyz.ndim() == 2 ? i64(xyz.shape(0)) : -1;
        expect(xyz, n, 3, "vertices");
        Output<u64> key(n);
        Output<I> rep(n);
        r::Merged merged;
        {
          nb::gil_scoped_release unlocked;
          merged = r::merge_positions<I>(xyz.data(), n, threads, key.data(), rep.data());
        }
        return std::make_tuple(rep.array(), key.array(), merged.unique, merged.lexicographic,
                               merged.magnitude);
      },
      "vertices"_a.noconvert(), "threads"_a,
      "Merge the equal positions of (V, 3) float64 vertices. Returns (rep (V,): the "
      "smallest index at each vertex's position; key (V,) uint64: ordering the positions "
      "as isoconvert.graph.row_groups does; number of distinct positions; whether the keys "
      "are lexicographic ranks because two positions shared a hash; the largest absolute "
      "finite coordinate, 0 when none).");
}

// The per-triangle pass, for cells C and representatives I (int32 or int64).
template <class I, class C>
void bind_triangle_pass(nb::module_ &m) {
  namespace r = iso::report;
  m.def(
      "triangle_pass",
      [](In<C> cells, In<I> rep, In<double> xyz, double flat_below, int threads,
         bool representatives) {
        const i64 nv = xyz.ndim() == 2 ? i64(xyz.shape(0)) : -1;
        const i64 nt = cells.ndim() == 2 ? i64(cells.shape(0)) : -1;
        expect(xyz, nv, 3, "vertices");
        expect(rep, nv, 0, "rep");
        expect(cells, nt, 3, "cells");
        Output<I> tv(representatives ? nt : 0, 3);
        r::TriangleLists lists;
        double area2 = 0.0;
        {
          nb::gil_scoped_release unlocked;
          area2 = r::triangle_pass<I, C>(cells.data(), nt, rep.data(), xyz.data(), flat_below,
                                         threads, representatives ? tv.data() : nullptr, lists);
        }
        nb::object corners = representatives ? tv.array() : nb::object(nb::none());
        return std::make_tuple(corners, area2, give(std::move(lists.repeated)),
                               give(std::move(lists.flat_candidates)),
                               give(std::move(lists.collapsed), 2));
      },
      "cells"_a.noconvert(), "rep"_a.noconvert(), "vertices"_a.noconvert(), "flat_below"_a,
      "threads"_a, "representatives"_a,
      "One pass over (F, 3) int32 or int64 cells (indices checked before). Returns (tv "
      "(F, 3): each corner's rep, when asked for, else None; the sum of |cross| over the "
      "triangles, as np.sum of numpy's values; triangles with a repeated position; other "
      "triangles with |cross| <= flat_below; (K, 2) input edges whose ends merged, lower "
      "index first).");
}

// The triangles' vertex indices: int32 or int64.
template <class C>
void bind_cell_type(nb::module_ &m) {
  namespace r = iso::report;
  m.def(
      "topology",
      [](In<C> tv, i64 nv, In<u64> key, int threads, bool all_edges, bool wide) {
        const i64 nt = tv.ndim() == 2 ? i64(tv.shape(0)) : -1;
        expect(tv, nt, 3, "tv");
        expect(key, nv, 0, "key");
        Output<u8> used(nv);
        r::Topology t;
        {
          nb::gil_scoped_release unlocked;
          // int32 corner numbers and vertex indices where they fit
          if (!wide && nv <= INT32_MAX && 3 * nt <= INT32_MAX) {
            r::topology<std::int32_t, C>(tv.data(), nt, nv, key.data(), threads, all_edges,
                                         used.data(), t);
          } else {
            r::topology<i64, C>(tv.data(), nt, nv, key.data(), threads, all_edges, used.data(),
                                t);
          }
        }
        nb::dict d;
        d["used"] = used.array();
        d["edges"] = t.edges;
        d["used_vertices"] = t.used;
        d["kept"] = t.kept;
        d["boundary"] = give(std::move(t.boundary), 2);
        d["non_manifold_edges"] = give(std::move(t.non_manifold_edges), 2);
        d["inconsistent"] = give(std::move(t.inconsistent), 2);
        d["non_manifold_vertices"] = give(std::move(t.non_manifold_vertices));
        d["fans"] = give(std::move(t.fans));
        d["dup_triangles"] = give(std::move(t.dup_triangles));
        d["dup_starts"] = give(std::move(t.dup_starts));
        d["comp_vertices"] = give(std::move(t.comp_vertices));
        d["comp_edges"] = give(std::move(t.comp_edges));
        d["comp_triangles"] = give(std::move(t.comp_triangles));
        d["comp_min_key"] = give(std::move(t.comp_min_key));
        d["comp_open"] = give(std::move(t.comp_open));
        d["comp_bad"] = give(std::move(t.comp_bad));
        if (all_edges) {
          d["all_edges"] = give(std::move(t.all_edges), 2);
          d["all_counts"] = give(std::move(t.all_counts));
        }
        return d;
      },
      "tv"_a.noconvert(), "n_vertices"_a, "key"_a.noconvert(), "threads"_a, "all_edges"_a,
      "wide"_a = false,
      "Edges, orientation, fans, duplicates and components of the triangles tv (F, 3) "
      "(values in 0..n_vertices-1) that repeat no vertex; see src/report.hpp. Indices "
      "inside are int32 where they fit, unless wide.");
  m.def(
      "enclosed_volume",
      [](In<double> xyz, In<C> tv, In<u8> used, int threads) {
        const i64 nv = xyz.ndim() == 2 ? i64(xyz.shape(0)) : -1;
        const i64 nt = tv.ndim() == 2 ? i64(tv.shape(0)) : -1;
        expect(xyz, nv, 3, "vertices");
        expect(tv, nt, 3, "tv");
        expect(used, nv, 0, "used");
        nb::gil_scoped_release unlocked;
        return iso::report::enclosed_volume<C>(xyz.data(), tv.data(), nt, used.data(), nv,
                                               threads);
      },
      "vertices"_a.noconvert(), "tv"_a.noconvert(), "used"_a.noconvert(), "threads"_a,
      "Volume enclosed by the triangles tv (F, 3) of (V, 3) vertices, from the mean used "
      "position.");
}

}  // namespace

void bind_report(nb::module_ &m) {
  bind_index_type<std::int32_t>(m, "int32");
  bind_index_type<std::int64_t>(m, "int64");
  bind_triangle_pass<std::int32_t, std::int32_t>(m);
  bind_triangle_pass<std::int32_t, std::int64_t>(m);
  bind_triangle_pass<std::int64_t, std::int32_t>(m);
  bind_triangle_pass<std::int64_t, std::int64_t>(m);
  bind_cell_type<std::int32_t>(m);
  bind_cell_type<std::int64_t>(m);
}
